// fishfmu replay, the drawing: a small WebGL2 renderer of our own for the line and the fish (no
// libraries).  replay.js decodes the data and runs the page; this file only draws what it is given.
// Frame: x along the line, y across (positive to the left looking downstream), z up; metres.
"use strict";
const ReplayRender = (function () {
let gl = null, canvas = null, header = null, data = null, scene = null;

// ----------------------------------------------------------------------------------- small maths
function mat4Multiply(a, b) {   // column-major, as WebGL reads them
  const out = new Float32Array(16);
  for (let c = 0; c < 4; c++) for (let r = 0; r < 4; r++) {
    let s = 0;
    for (let i = 0; i < 4; i++) s += a[i * 4 + r] * b[c * 4 + i];
    out[c * 4 + r] = s;
  }
  return out;
}

function perspective(fovY, aspect, near, far) {
  const f = 1 / Math.tan(fovY / 2), nf = 1 / (near - far);
  return new Float32Array([f / aspect, 0, 0, 0, 0, f, 0, 0, 0, 0, (far + near) * nf, -1, 0, 0, 2 * far * near * nf, 0]);
}

function lookAt(eye, target, up) {
  const sub = (p, q) => [p[0] - q[0], p[1] - q[1], p[2] - q[2]];
  const cross = (p, q) => [p[1] * q[2] - p[2] * q[1], p[2] * q[0] - p[0] * q[2], p[0] * q[1] - p[1] * q[0]];
  const unit = (p) => { const l = Math.hypot(...p) || 1; return [p[0] / l, p[1] / l, p[2] / l]; };
  const dot = (p, q) => p[0] * q[0] + p[1] * q[1] + p[2] * q[2];
  const z = unit(sub(eye, target)), x = unit(cross(up, z)), y = cross(z, x);
  return new Float32Array([x[0], y[0], z[0], 0, x[1], y[1], z[1], 0, x[2], y[2], z[2], 0,
                           -dot(x, eye), -dot(y, eye), -dot(z, eye), 1]);
}

// The orbit camera: eye at `dist` from `target`, turned by `yaw` about z and raised by `pitch`.
function cameraEye(camera) {
  const c = Math.cos(camera.pitch);
  return [camera.target[0] + camera.dist * c * Math.cos(camera.yaw),
          camera.target[1] + camera.dist * c * Math.sin(camera.yaw),
          camera.target[2] + camera.dist * Math.sin(camera.pitch)];
}

function viewProjection(camera, aspect) {
  const near = Math.max(0.01, camera.dist / 200);
  return mat4Multiply(perspective(camera.fovY, aspect, near, camera.dist * 20 + 20),
                      lookAt(cameraEye(camera), camera.target, [0, 0, 1]));
}

// A device's body -> line frame at its position p (0 home .. 1 end), as plant/contract/devices.py's
// DeviceShape.pose: a rotation by p * travel about `axis` through `origin_m` (gate, diverter), or a
// translation by p * travel along `axis` (pusher).  -> column-major 4x4, as WebGL reads them.
function deviceMatrix(device, p) {
  const [kx, ky, kz] = device.axis, o = device.origin_m, m = new Float32Array(16);
  m[15] = 1;
  if (device.rotates) {
    const a = p * device.travel, c = Math.cos(a), s = Math.sin(a), v = 1 - c;   // Rodrigues, |axis| = 1
    const r = [[c + kx * kx * v, kx * ky * v - kz * s, kx * kz * v + ky * s],
               [ky * kx * v + kz * s, c + ky * ky * v, ky * kz * v - kx * s],
               [kz * kx * v - ky * s, kz * ky * v + kx * s, c + kz * kz * v]];
    for (let row = 0; row < 3; row++) for (let col = 0; col < 3; col++) m[col * 4 + row] = r[row][col];
    m[12] = o[0]; m[13] = o[1]; m[14] = o[2];
  } else {
    m[0] = m[5] = m[10] = 1;
    m[12] = o[0] + kx * p * device.travel; m[13] = o[1] + ky * p * device.travel; m[14] = o[2] + kz * p * device.travel;
  }
  return m;
}

function transformPoint(m, p) {
  return [0, 1, 2].map((r) => m[r] * p[0] + m[4 + r] * p[1] + m[8 + r] * p[2] + m[12 + r]);
}

// World point -> [x, y] in CSS pixels from the top-left of a canvas width x height, and the clip depth.
function project(p, vp, width, height) {
  const x = vp[0] * p[0] + vp[4] * p[1] + vp[8] * p[2] + vp[12];
  const y = vp[1] * p[0] + vp[5] * p[1] + vp[9] * p[2] + vp[13];
  const z = vp[2] * p[0] + vp[6] * p[1] + vp[10] * p[2] + vp[14];
  const w = vp[3] * p[0] + vp[7] * p[1] + vp[11] * p[2] + vp[15];
  return [(x / w * 0.5 + 0.5) * width, (0.5 - y / w * 0.5) * height, z / w];
}

// ------------------------------------------------------------------------------------ shaders
const LIGHTING = `
vec3 shade(vec3 base, vec3 n) {
  vec3 light = normalize(vec3(0.35, -0.45, 1.0));
  float diffuse = abs(dot(normalize(n), light));       // two-sided: thin parts are seen from both sides
  return base * (0.42 + 0.62 * diffuse);
}`;

const FISH_VS = `#version 300 es
precision highp float;
in vec3 aLocal; in vec3 aNormal; in float aBody; in vec3 aColor;
uniform highp sampler2D uPose;   // per body: texel (col, 2 row) = position + visible, (col, 2 row + 1) = quaternion
uniform mat4 uViewProj; uniform int uPoseWidth;
out vec3 vNormal; out vec3 vColor;
vec3 rotate(vec4 q, vec3 v) { return v + 2.0 * cross(q.xyz, cross(q.xyz, v) + q.w * v); }
void main() {
  int b = int(aBody + 0.5);
  ivec2 at = ivec2(b % uPoseWidth, 2 * (b / uPoseWidth));
  vec4 p = texelFetch(uPose, at, 0);
  vec4 q = texelFetch(uPose, at + ivec2(0, 1), 0);
  if (p.w < 0.5) { gl_Position = vec4(2.0, 2.0, 2.0, 1.0); return; }   // not on the line: outside the clip box
  vNormal = rotate(q, aNormal);
  vColor = aColor;
  gl_Position = uViewProj * vec4(p.xyz + rotate(q, aLocal), 1.0);
}`;

const FISH_FS = `#version 300 es
precision highp float;
in vec3 vNormal; in vec3 vColor; out vec4 outColor;
${LIGHTING}
void main() { outColor = vec4(shade(vColor, vNormal), 1.0); }`;

const SCENE_VS = `#version 300 es
precision highp float;
in vec3 aPos; in vec3 aNormal;
uniform mat4 uViewProj;
out vec3 vNormal; out vec3 vWorld;
void main() { vNormal = aNormal; vWorld = aPos; gl_Position = uViewProj * vec4(aPos, 1.0); }`;

// A device: its triangles in its body's frame, placed by uModel (deviceMatrix) every picture.
const DEVICE_VS = `#version 300 es
precision highp float;
in vec3 aPos; in vec3 aNormal;
uniform mat4 uViewProj; uniform mat4 uModel;
out vec3 vNormal; out vec3 vWorld;
void main() {
  vec4 world = uModel * vec4(aPos, 1.0);
  vNormal = mat3(uModel) * aNormal; vWorld = world.xyz; gl_Position = uViewProj * world;
}`;

const STRIPE_SPACING_M = 0.15;   // marks across each belt, moving with it: a person sees the belt speed
// uPattern 1: belt top, the marks (uOffset = how far the belt has moved); 2: floor grid every 0.5 m.
const SCENE_FS = `#version 300 es
precision highp float;
in vec3 vNormal; in vec3 vWorld; out vec4 outColor;
uniform vec4 uColor; uniform int uPattern; uniform float uOffset; uniform bool uLit;
${LIGHTING}
void main() {
  vec3 base = uColor.rgb;
  if (uPattern == 1 && vNormal.z > 0.5 && fract((vWorld.x - uOffset) / ${STRIPE_SPACING_M.toFixed(3)}) < 0.16) base = base * 1.9 + 0.05;
  if (uPattern == 2 && (fract(vWorld.x / 0.5 + 0.01) < 0.02 || fract(vWorld.y / 0.5 + 0.01) < 0.02)) base *= 0.85;
  outColor = vec4(uLit ? shade(base, vNormal) : base, uColor.a);
}`;

function compile(vsSource, fsSource) {
  const program = gl.createProgram();
  for (const [type, source] of [[gl.VERTEX_SHADER, vsSource], [gl.FRAGMENT_SHADER, fsSource]]) {
    const shader = gl.createShader(type);
    gl.shaderSource(shader, source);
    gl.compileShader(shader);
    if (!gl.getShaderParameter(shader, gl.COMPILE_STATUS)) throw new Error(gl.getShaderInfoLog(shader));
    gl.attachShader(program, shader);
  }
  gl.linkProgram(program);
  if (!gl.getProgramParameter(program, gl.LINK_STATUS)) throw new Error(gl.getProgramInfoLog(program));
  const uniforms = {};
  for (let i = 0; i < gl.getProgramParameter(program, gl.ACTIVE_UNIFORMS); i++) {
    const name = gl.getActiveUniform(program, i).name;
    uniforms[name] = gl.getUniformLocation(program, name);
  }
  return { program, uniforms, attrib: (name) => gl.getAttribLocation(program, name) };
}

function vertexArray(program, attributes, indices) {   // attributes: {name: [Float32Array, size]}
  const vao = gl.createVertexArray();
  gl.bindVertexArray(vao);
  const buffers = {};
  for (const [name, [array, size]] of Object.entries(attributes)) {
    const loc = program.attrib(name), buffer = gl.createBuffer();
    gl.bindBuffer(gl.ARRAY_BUFFER, buffer);
    gl.bufferData(gl.ARRAY_BUFFER, array, gl.STATIC_DRAW);
    if (loc >= 0) { gl.enableVertexAttribArray(loc); gl.vertexAttribPointer(loc, size, gl.FLOAT, false, 0, 0); }
    buffers[name] = buffer;
  }
  if (indices) { gl.bindBuffer(gl.ELEMENT_ARRAY_BUFFER, gl.createBuffer()); gl.bufferData(gl.ELEMENT_ARRAY_BUFFER, indices, gl.STATIC_DRAW); }
  gl.bindVertexArray(null);
  return { vao, buffers };
}

// ------------------------------------------------------------------------------------ geometry
function boxTriangles(x0, x1, y0, y1, z0, z1) {   // -> {pos, normal} of 12 triangles
  const pos = [], normal = [];
  const face = (corners, n) => {
    for (const i of [0, 1, 2, 0, 2, 3]) { pos.push(...corners[i]); normal.push(...n); }
  };
  face([[x0, y0, z1], [x1, y0, z1], [x1, y1, z1], [x0, y1, z1]], [0, 0, 1]);
  face([[x0, y0, z0], [x0, y1, z0], [x1, y1, z0], [x1, y0, z0]], [0, 0, -1]);
  face([[x0, y0, z0], [x1, y0, z0], [x1, y0, z1], [x0, y0, z1]], [0, -1, 0]);
  face([[x0, y1, z0], [x0, y1, z1], [x1, y1, z1], [x1, y1, z0]], [0, 1, 0]);
  face([[x0, y0, z0], [x0, y0, z1], [x0, y1, z1], [x0, y1, z0]], [-1, 0, 0]);
  face([[x1, y0, z0], [x1, y1, z0], [x1, y1, z1], [x1, y0, z1]], [1, 0, 0]);
  return { pos, normal };
}

function sceneObject(program, boxes, color, options = {}) {
  const pos = [], normal = [];
  for (const b of boxes) { const t = boxTriangles(...b); pos.push(...t.pos); normal.push(...t.normal); }
  const { vao } = vertexArray(program, { aPos: [new Float32Array(pos), 3], aNormal: [new Float32Array(normal), 3] });
  return { vao, count: pos.length / 3, color, pattern: options.pattern || 0, conveyor: options.conveyor,
           photoeye: options.photoeye, measuredEye: options.measuredEye, transparent: color[3] < 1 };
}

function meshObject(program, corners, color) {   // corners: flat x, y, z of each triangle's three corners
  const normal = [];
  for (let i = 0; i < corners.length; i += 9) {
    const u = [0, 1, 2].map((k) => corners[i + 3 + k] - corners[i + k]), v = [0, 1, 2].map((k) => corners[i + 6 + k] - corners[i + k]);
    const n = [u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0]];
    const l = Math.hypot(...n) || 1;
    for (let k = 0; k < 3; k++) normal.push(n[0] / l, n[1] / l, n[2] / l);
  }
  const { vao } = vertexArray(program, { aPos: [new Float32Array(corners), 3], aNormal: [new Float32Array(normal), 3] });
  return { vao, count: corners.length / 3, color, pattern: 0, transparent: color[3] < 1 };
}

function lineExtent(line) {
  const cs = line.conveyors;
  return { x0: cs[0].x_start_m, x1: cs[cs.length - 1].x_start_m + cs[cs.length - 1].length_m,
           zTop: Math.max(...cs.map((c) => Math.max(c.z_top_m, zEnd(c)))),
           zLow: Math.min(...cs.map((c) => Math.min(c.z_top_m, zEnd(c)))) };
}

// An inclined belt's top at its downstream end (length_m is along x).
function zEnd(c) {
  return c.z_top_m + c.length_m * Math.tan(((c.incline_deg || 0) * Math.PI) / 180);
}

// The side guides' y at x: straight at +-guide_width_m/2, or along the guides' polylines (straight on beyond them).
function guideY(line, x) {
  const at = (pts) => {
    if (x <= pts[0][0]) return pts[0][1];
    for (let i = 1; i < pts.length; i++) {
      if (x <= pts[i][0]) return pts[i - 1][1] + (pts[i][1] - pts[i - 1][1]) * (x - pts[i - 1][0]) / (pts[i][0] - pts[i - 1][0]);
    }
    return pts[pts.length - 1][1];
  };
  return line.guides ? [at(line.guides.left), at(line.guides.right)] : [line.guide_width_m / 2, -line.guide_width_m / 2];
}

// Belts (moving stripes), frames and legs, floor, side guides, photo-eye beams and their heads, cameras.
function buildLine(program) {
  const line = header.line, ext = lineExtent(line), g = line.guide_width_m / 2;
  const floorZ = ext.zLow - 0.75, objects = [];
  objects.push(sceneObject(program, [[ext.x0 - 1, ext.x1 + 1, -1.5, 1.5, floorZ - 0.02, floorZ]], [0.78, 0.8, 0.8, 1], { pattern: 2 }));
  line.conveyors.forEach((c, i) => {
    const x0 = c.x_start_m, x1 = c.x_start_m + c.length_m, w = c.width_m / 2;
    const slope = (zEnd(c) - c.z_top_m) / c.length_m, zAt = (x) => c.z_top_m + slope * (x - x0);
    const pieces = slope ? Math.ceil(c.length_m / 0.02) : 1, belt = [], frame = [];  // an incline as 2 cm steps
    for (let k = 0; k < pieces; k++) {
      const a = x0 + (k * (x1 - x0)) / pieces, b = x0 + ((k + 1) * (x1 - x0)) / pieces, z = zAt((a + b) / 2);
      belt.push([a, b, -w, w, z - 0.03, z]);
      frame.push([a, b, -w - 0.03, -w, z - 0.12, z - 0.005], [a, b, w, w + 0.03, z - 0.12, z - 0.005]);
    }
    objects.push(sceneObject(program, belt, [0.22, 0.25, 0.29, 1], { pattern: 1, conveyor: i }));
    for (const x of [x0 + 0.05, x1 - 0.09]) for (const y of [-w - 0.03, w - 0.01]) frame.push([x, x + 0.04, y, y + 0.04, floorZ, zAt(x) - 0.12]);
    objects.push(sceneObject(program, frame, [0.55, 0.58, 0.62, 1]));
  });
  const measuredEyes = header.measured && header.measured.photoeyes;
  line.photoeyes.forEach((pe) => {
    const [yl, yr] = guideY(line, pe.x_m), reach = yl + 0.06, rreach = yr - 0.06;
    objects.push(sceneObject(program, [[pe.x_m - 0.003, pe.x_m + 0.003, rreach, reach, pe.z_m - 0.003, pe.z_m + 0.003],
                                        [pe.x_m - 0.02, pe.x_m + 0.02, rreach - 0.03, rreach, pe.z_m - 0.05, pe.z_m + 0.05],
                                        [pe.x_m - 0.02, pe.x_m + 0.02, reach, reach + 0.03, pe.z_m - 0.05, pe.z_m + 0.05]],
                             [0.2, 0.7, 0.3, 1], { photoeye: pe.id }));
    if (measuredEyes) {   // a lamp on each head: the measured beam (the heads show the simulated one)
      const lamp = (y0, y1) => [pe.x_m - 0.014, pe.x_m + 0.014, y0, y1, pe.z_m + 0.055, pe.z_m + 0.09];
      objects.push(sceneObject(program, [lamp(rreach - 0.03, rreach), lamp(reach, reach + 0.03)],
                               MEASURED_EYE_CLEAR, { measuredEye: pe.id }));
    }
  });
  const top = ext.zTop + 0.15, walls = [];
  for (const side of [1, -1]) {   // each guide, left then right, but where a device opens it
    for (const [a, b] of guideStretches(ext.x0, ext.x1, side)) {
      const step = line.guides ? 0.02 : b - a;   // a polyline drawn in 2 cm pieces
      for (let x = a; x < b - 1e-9; x += step) {
        const x1 = Math.min(x + step, b), y = guideY(line, (x + x1) / 2)[side > 0 ? 0 : 1];
        walls.push(side > 0 ? [x, x1, y, y + 0.004, ext.zLow - 0.01, top] : [x, x1, y - 0.004, y, ext.zLow - 0.01, top]);
      }
    }
  }
  for (const [side, a, b, depth] of header.chutes || []) {   // a pusher's chute: a plate out from each end of its opening
    for (const x of [a, b]) {
      const y = guideY(line, x)[side > 0 ? 0 : 1], y1 = y + side * depth;
      walls.push([x - 0.002, x + 0.002, Math.min(y, y1), Math.max(y, y1), ext.zLow - 0.01, top]);
    }
  }
  objects.push(sceneObject(program, walls, [0.55, 0.7, 0.85, 0.22]));
  if (header.parts && header.parts.length) objects.push(meshObject(program, header.parts, [0.62, 0.66, 0.7, 1]));
  (line.cameras || []).forEach((cam) => {   // its field of view as a faint pane above the line, and the camera
    const xm = (cam.x_start_m + cam.x_end_m) / 2, h = ext.zTop + 0.6;
    objects.push(sceneObject(program, [[cam.x_start_m, cam.x_end_m, -g, g, h - 0.002, h]], [0.95, 0.8, 0.3, 0.15]));
    objects.push(sceneObject(program, [[xm - 0.05, xm + 0.05, -0.04, 0.04, h, h + 0.06]], [0.15, 0.15, 0.18, 1]));
  });
  return objects;
}

// x0..x1 without the openings a pusher or diverter makes in the guide on `side` (+1 left, -1 right).
function guideStretches(x0, x1, side) {
  let out = [[x0, x1]];
  for (const [s, a, b] of header.guide_openings || []) {
    if (s !== side) continue;
    out = out.flatMap(([u, v]) => [[u, Math.min(v, a)], [Math.max(u, b), v]]).filter(([u, v]) => v - u > 1e-9);
  }
  return out;
}

// The devices: one mesh each, in its body's frame (drawn with deviceMatrix at its position p).
const DEVICE_COLOR = [0.96, 0.74, 0.08, 1];   // safety yellow: the moving machinery
function buildDevices(program) {
  return (header.devices || []).map((d) => ({ ...meshObject(program, d.triangles, DEVICE_COLOR), device: d }));
}

// One mesh for all fish: each body a tube through its outline's cross-sections (a stadium of
// half-height hh along local y, half-width hw along local z), capped at both ends; vertices carry
// their body index, and the vertex shader places them with that body's pose.
function buildFish(program) {
  const RING = 16, sec = data.sections, S = sec.body.length;
  const pos = [], normal = [], body = [], color = [], index = [];
  const colours = header.fish.colours;
  let s = 0;
  while (s < S) {
    let e = s;
    while (e < S && sec.body[e] === sec.body[s]) e++;
    const b = sec.body[s], base = colours[data.bodyFish[b]];
    const spacing = e - s > 1 ? (sec.x[e - 1] - sec.x[s]) / (e - s - 1) : 0.01;
    const rings = [[sec.x[s] - spacing / 2, s]];
    for (let i = s; i < e; i++) rings.push([sec.x[i], i]);
    rings.push([sec.x[e - 1] + spacing / 2, e - 1]);
    const first = pos.length / 3;
    for (const [x, i] of rings) {
      const hw = sec.hw[i], half = Math.max(sec.hh[i] - hw, 0);
      for (let j = 0; j < RING; j++) {
        const th = 2 * Math.PI * (j + 0.5) / RING, c = Math.cos(th), sn = Math.sin(th);
        pos.push(x, Math.sign(c) * half + hw * c, hw * sn);
        normal.push(0, c, sn);
        const shade = c > 0 ? 1 - 0.45 * c : 1 + 0.12 * -c;     // darker back (+y), light belly
        color.push(base[0] * shade, base[1] * shade, base[2] * shade);
        body.push(b);
      }
    }
    for (let r = 0; r + 1 < rings.length; r++) {
      for (let j = 0; j < RING; j++) {
        const a0 = first + r * RING + j, a1 = first + r * RING + (j + 1) % RING;
        index.push(a0, a1, a0 + RING, a1, a1 + RING, a0 + RING);
      }
    }
    for (const [end, r, dir] of [[rings[0][0], 0, -1], [rings[rings.length - 1][0], rings.length - 1, 1]]) {
      const centre = pos.length / 3;
      pos.push(end, 0, 0); normal.push(dir, 0, 0); color.push(...base); body.push(b);
      for (let j = 0; j < RING; j++) index.push(centre, first + r * RING + j, first + r * RING + (j + 1) % RING);
    }
    s = e;
  }
  const mesh = vertexArray(program, {
    aLocal: [new Float32Array(pos), 3], aNormal: [new Float32Array(normal), 3],
    aBody: [new Float32Array(body), 1], aColor: [new Float32Array(color), 3],
  }, new Uint32Array(index));
  const width = Math.max(1, Math.min(data.bodies, 1024)), height = 2 * Math.ceil(Math.max(1, data.bodies) / width);
  const texture = gl.createTexture();
  gl.bindTexture(gl.TEXTURE_2D, texture);
  gl.texImage2D(gl.TEXTURE_2D, 0, gl.RGBA32F, width, height, 0, gl.RGBA, gl.FLOAT, null);
  for (const p of [gl.TEXTURE_MIN_FILTER, gl.TEXTURE_MAG_FILTER]) gl.texParameteri(gl.TEXTURE_2D, p, gl.NEAREST);
  return { vao: mesh.vao, count: index.length, texture, width, height, pixels: new Float32Array(width * height * 4) };
}

// A measured fish seen from above: a salmon's side profile (it lies on its side), snout (u = 0) to tail fin.
const OUTLINE_U = [0, 0.04, 0.12, 0.3, 0.55, 0.78, 0.86, 0.9, 0.97, 1];
const OUTLINE_H = [0, 0.45, 0.8, 1, 0.85, 0.4, 0.28, 0.38, 0.7, 0.72];
// The measured run's look: a ghost (pale, translucent, unlit) of its fish's colour, its edges dark
// and drawn through everything; photo-eye lamps orange while the measured beam was blocked.
const GHOST_FILL_WHITE = 0.55, GHOST_FILL_ALPHA = 0.42, GHOST_EDGE_DARK = 0.45;
const MEASURED_EYE_BLOCKED = [1.0, 0.55, 0.05, 1], MEASURED_EYE_CLEAR = [0.92, 0.92, 0.86, 1];

function conveyorTopAt(x) {
  const cs = header.line.conveyors;
  for (const c of cs) if (x <= c.x_start_m + c.length_m + 0.005) return c.z_top_m;
  return cs[cs.length - 1].z_top_m;
}

// Each measured fish as a slab: its outline seen from above (length x height), extruded from just
// above the belt by its thickness (width).  -> fill triangles (top and sides) and edge segments
// (top ring: `edge`, bottom ring: `base`), world coordinates, in the colour of the simulated fish
// of the same id.
function measuredOutlines(fish) {
  const fill = [], edge = [], base = [], fillColor = [], edgeColor = [];
  const colourOf = (id) => {
    const i = header.fish.ids.indexOf(id);
    return i >= 0 ? header.fish.colours[i] : [0.95, 0.5, 0.1];
  };
  for (const f of fish) {
    const dx = Math.cos(f.yaw), dy = Math.sin(f.yaw), rgb = colourOf(f.id);
    const z0 = conveyorTopAt(f.x) + 0.002, z1 = z0 + Math.max(f.width_m || 0.22 * f.height_m, 0.01);
    const pale = rgb.map((c) => c * (1 - GHOST_FILL_WHITE) + GHOST_FILL_WHITE), side = pale.map((c) => 0.85 * c);
    const dark = rgb.map((c) => c * GHOST_EDGE_DARK);
    const left = [], right = [];
    OUTLINE_U.forEach((u, i) => {
      const along = (0.5 - u) * f.length_m, half = OUTLINE_H[i] * f.height_m / 2;
      left.push([f.x + along * dx - half * dy, f.y + along * dy + half * dx]);
      right.push([f.x + along * dx + half * dy, f.y + along * dy - half * dx]);
    });
    const at = (p, z) => [p[0], p[1], z];
    const tri = (corners, colour) => { for (const c of corners) { fill.push(...c); fillColor.push(...colour); } };
    for (let i = 0; i + 1 < left.length; i++) {
      tri([at(left[i], z1), at(right[i], z1), at(left[i + 1], z1), at(right[i], z1), at(right[i + 1], z1), at(left[i + 1], z1)], pale);
    }
    const ring = left.concat(right.slice().reverse());
    for (let i = 0; i < ring.length; i++) {
      const a = ring[i], b = ring[(i + 1) % ring.length];
      tri([at(a, z0), at(b, z0), at(b, z1), at(a, z0), at(b, z1), at(a, z1)], side);
      edge.push(...at(a, z1), ...at(b, z1));
      base.push(...at(a, z0), ...at(b, z0));
      edgeColor.push(...dark, ...dark);
    }
  }
  return { fill, edge, base, fillColor, edgeColor };
}

// ------------------------------------------------------------------------------------- drawing
function setupGL() {
  gl = canvas.getContext("webgl2", { antialias: true, preserveDrawingBuffer: true });
  if (!gl) throw new Error("this browser has no WebGL2");
  const sceneProgram = compile(SCENE_VS, SCENE_FS), fishProgram = compile(FISH_VS, FISH_FS);
  const deviceProgram = compile(DEVICE_VS, SCENE_FS);
  const overlayProgram = compile(SCENE_VS.replace("in vec3 aNormal;", "in vec3 aNormal; in vec3 aColor; out vec3 vColor;")
                                   .replace("vWorld = aPos;", "vWorld = aPos; vColor = aColor;"),
                                 `#version 300 es
precision highp float;
in vec3 vColor; in vec3 vNormal; in vec3 vWorld; out vec4 outColor; uniform float uAlpha;
void main() { outColor = vec4(vColor, uAlpha); }`);
  const overlay = vertexArray(overlayProgram, { aPos: [new Float32Array(0), 3], aColor: [new Float32Array(0), 3] });
  scene = { sceneProgram, fishProgram, overlayProgram, overlay, line: buildLine(sceneProgram), fish: buildFish(fishProgram),
            deviceProgram, devices: buildDevices(deviceProgram), drawnDevices: [] };
}

function resize() {
  const dpr = window.devicePixelRatio || 1;
  const w = Math.round(canvas.clientWidth * dpr), h = Math.round(canvas.clientHeight * dpr);
  if (canvas.width !== w || canvas.height !== h) { canvas.width = w; canvas.height = h; }
}

// `blocked`: the simulated beams (the heads' colour); `measuredBlocked`: the measured ones (the
// lamps' colour; null: no lamps).
function drawSceneObjects(vp, belts, blocked, measuredBlocked, transparent) {
  const p = scene.sceneProgram;
  gl.useProgram(p.program);
  gl.uniformMatrix4fv(p.uniforms.uViewProj, false, vp);
  gl.uniform1i(p.uniforms.uLit, 1);
  for (const o of scene.line) {
    if (o.transparent !== transparent) continue;
    let color = o.color;
    if (o.photoeye !== undefined) color = blocked[o.photoeye] ? [0.95, 0.1, 0.08, 1] : [0.2, 0.62, 0.3, 1];
    if (o.measuredEye !== undefined) {
      if (!measuredBlocked) continue;
      color = measuredBlocked[o.measuredEye] ? MEASURED_EYE_BLOCKED : MEASURED_EYE_CLEAR;
    }
    gl.uniform4fv(p.uniforms.uColor, color);
    gl.uniform1i(p.uniforms.uPattern, o.pattern);
    gl.uniform1f(p.uniforms.uOffset, o.conveyor !== undefined ? belts.travel[o.conveyor] % STRIPE_SPACING_M : 0);
    gl.bindVertexArray(o.vao);
    gl.drawArrays(gl.TRIANGLES, 0, o.count);
  }
}

// Each device at its position p (`positions`, one per header.devices); keeps the matrices it drew with.
function drawDevices(vp, positions) {
  const p = scene.deviceProgram;
  scene.drawnDevices = [];
  if (scene.devices.length === 0) return;
  gl.useProgram(p.program);
  gl.uniformMatrix4fv(p.uniforms.uViewProj, false, vp);
  gl.uniform1i(p.uniforms.uLit, 1);
  gl.uniform1i(p.uniforms.uPattern, 0);
  gl.uniform1f(p.uniforms.uOffset, 0);
  scene.devices.forEach((o, i) => {
    const model = deviceMatrix(o.device, positions[i] || 0);
    gl.uniformMatrix4fv(p.uniforms.uModel, false, model);
    gl.uniform4fv(p.uniforms.uColor, o.color);
    gl.bindVertexArray(o.vao);
    gl.drawArrays(gl.TRIANGLES, 0, o.count);
    scene.drawnDevices.push({ id: o.device.id, p: positions[i] || 0, matrix: Array.from(model) });
  });
}

// The devices as last drawn: id, position p and body -> line matrix (column-major) of each.
function drawnDevices() {
  return scene.drawnDevices.map((d) => ({ ...d, matrix: d.matrix.slice() }));
}

function drawFish(vp, poses, showSim) {
  const f = scene.fish, p = scene.fishProgram, px = f.pixels;
  for (let b = 0; b < data.bodies; b++) {
    const at = 4 * ((2 * Math.floor(b / f.width)) * f.width + (b % f.width)), at1 = at + 4 * f.width;
    for (let c = 0; c < 4; c++) { px[at + c] = poses.pos[4 * b + c]; px[at1 + c] = poses.rot[4 * b + c]; }
    if (!showSim) px[at + 3] = 0;
  }
  gl.useProgram(p.program);
  gl.activeTexture(gl.TEXTURE0);
  gl.bindTexture(gl.TEXTURE_2D, f.texture);
  gl.texSubImage2D(gl.TEXTURE_2D, 0, 0, 0, f.width, f.height, gl.RGBA, gl.FLOAT, px);
  gl.uniform1i(p.uniforms.uPose, 0);
  gl.uniform1i(p.uniforms.uPoseWidth, f.width);
  gl.uniformMatrix4fv(p.uniforms.uViewProj, false, vp);
  gl.bindVertexArray(f.vao);
  gl.drawElements(gl.TRIANGLES, f.count, gl.UNSIGNED_INT, 0);
}

function drawMeasured(vp, fish) {
  if (fish.length === 0) return;
  const o = measuredOutlines(fish), p = scene.overlayProgram, buffers = scene.overlay.buffers;
  gl.useProgram(p.program);
  gl.uniformMatrix4fv(p.uniforms.uViewProj, false, vp);
  gl.bindVertexArray(scene.overlay.vao);
  const pass = (positions, colours, mode, alpha) => {
    gl.bindBuffer(gl.ARRAY_BUFFER, buffers.aPos); gl.bufferData(gl.ARRAY_BUFFER, new Float32Array(positions), gl.DYNAMIC_DRAW);
    gl.bindBuffer(gl.ARRAY_BUFFER, buffers.aColor); gl.bufferData(gl.ARRAY_BUFFER, new Float32Array(colours), gl.DYNAMIC_DRAW);
    gl.uniform1f(p.uniforms.uAlpha, alpha);
    gl.drawArrays(mode, 0, positions.length / 3);
  };
  pass(o.fill, o.fillColor, gl.TRIANGLES, GHOST_FILL_ALPHA);
  pass(o.base, o.edgeColor, gl.LINES, 0.6);
  gl.disable(gl.DEPTH_TEST);          // the ghost's top edge shows through the simulated fish inside it
  pass(o.edge, o.edgeColor, gl.LINES, 0.95);
  gl.enable(gl.DEPTH_TEST);
}

// One picture: `frame` holds the camera matrix and everything that moves (see replay.js, draw).
function draw(frame) {
  resize();
  gl.viewport(0, 0, canvas.width, canvas.height);
  gl.clearColor(0.87, 0.9, 0.92, 1);
  gl.clear(gl.COLOR_BUFFER_BIT | gl.DEPTH_BUFFER_BIT);
  gl.enable(gl.DEPTH_TEST);
  gl.disable(gl.BLEND);
  drawSceneObjects(frame.vp, frame.belts, frame.blocked, frame.measuredBlocked, false);
  drawDevices(frame.vp, frame.devices || []);
  drawFish(frame.vp, frame.poses, frame.showSim);
  gl.enable(gl.BLEND);
  gl.blendFunc(gl.SRC_ALPHA, gl.ONE_MINUS_SRC_ALPHA);
  gl.depthMask(false);
  drawMeasured(frame.vp, frame.measured);
  drawSceneObjects(frame.vp, frame.belts, frame.blocked, frame.measuredBlocked, true);
  gl.depthMask(true);
}

// The renderer of one page: `pageHeader` is the page's header, `pageData` its decoded arrays.
function createRenderer(pageCanvas, pageHeader, pageData) {
  canvas = pageCanvas;
  header = pageHeader;
  data = pageData;
  setupGL();
  return { draw, drawnDevices };
}

return { createRenderer, viewProjection, project, lineExtent, guideY, deviceMatrix, transformPoint };
})();
