// fishfmu replay, the page: decodes the run packed by fishfmu/replay.py (see decodeInts), keeps the
// time, the camera and the controls, and hands each picture to ReplayRender (render.js).  Works
// offline from file://.  Frame: x along the line, y across, z up; metres.
"use strict";
(function () {

const header = JSON.parse(document.getElementById("replay-header").textContent);
const canvas = document.getElementById("view");
const ui = {
  play: document.getElementById("play"), time: document.getElementById("time"),
  clock: document.getElementById("clock"), speed: document.getElementById("speed"),
  status: document.getElementById("status"), title: document.getElementById("title"),
  legend: document.getElementById("legend"), sim: document.getElementById("toggle-sim"),
  layers: document.getElementById("layers"),
};
const state = { time: 0, playing: false, speed: 1, lastNow: null, dirty: true, showSim: true, showMeasured: true,
               sliderHeld: false, draws: 0 };
let data = null;      // decoded arrays (see loadData)
let renderer = null;
const camera = { yaw: -1.2, pitch: 0.55, dist: 6, target: [3, 0, 0], fovY: 0.7 };

// ------------------------------------------------------------------------------------ the data
async function inflate(base64) {
  const text = atob(base64);
  const bytes = new Uint8Array(text.length);
  for (let i = 0; i < text.length; i++) bytes[i] = text.charCodeAt(i);
  const stream = new Blob([bytes]).stream().pipeThrough(new DecompressionStream("deflate"));
  return new Uint8Array(await new Response(stream).arrayBuffer());
}

// Inverse of replay.py's encode_ints: 4 byte planes -> zig-zag -> running sum along each row
// (int32 wrap-around, as the encoder's deltas) -> times the array's unit.
function decodeInts(raw, entry, ArrayType) {
  const n = entry.rows * entry.cols, o = entry.offset, out = new ArrayType(n);
  for (let r = 0; r < entry.rows; r++) {
    let acc = 0;
    for (let c = 0; c < entry.cols; c++) {
      const i = r * entry.cols + c;
      const z = (raw[o + i] | raw[o + n + i] << 8 | raw[o + 2 * n + i] << 16 | raw[o + 3 * n + i] << 24) >>> 0;
      acc = (acc + ((z >>> 1) ^ -(z & 1))) | 0;
      out[i] = acc * entry.unit;
    }
  }
  return out;
}

async function loadData() {
  const raw = await inflate(document.getElementById("replay-data").textContent.trim());
  const a = {};
  for (const [name, entry] of Object.entries(header.arrays)) {
    a[name] = decodeInts(raw, entry, name === "t" || name === "m_t" ? Float64Array : Float32Array);
  }
  if (header.live) return liveData(a);
  return {
    t: a.t, frames: a.t.length, pos: a.pos, quat: a.quat, status: a.status,
    bodies: header.fish.body_fish.length, bodyFish: header.fish.body_fish,
    beltTravel: a.belt_travel, beltSpeed: a.belt_speed,
    deviceP: a.device_p || null,   // (D, F) each device's position p, 0 home .. 1 end; none: all at home
    sections: { body: a.sec_body, x: a.sec_x, hh: a.sec_half_height, hw: a.sec_half_width },
    measured: header.measured ? { t: a.m_t, xy: a.m_xy, yaw: a.m_yaw, fish: header.measured.fish } : null,
  };
}

// A live page (fishfmu serve --live): one frame, overwritten by each frame the server sends (applyFrame); the
// arrays are laid out as a recorded run of one frame, so everything below draws it unchanged.
function liveData(a) {
  const B = header.fish.body_fish.length, D = (header.devices || []).length;
  const quat = new Float32Array(4 * B);
  for (let b = 0; b < B; b++) quat[4 * b] = 1;
  return {
    t: new Float64Array(1), frames: 1, pos: new Float32Array(3 * B), quat,
    status: new Float32Array(header.fish.ids.length), bodies: B, bodyFish: header.fish.body_fish,
    beltTravel: new Float32Array(header.line.conveyors.length), beltSpeed: new Float32Array(header.line.conveyors.length),
    deviceP: D ? new Float32Array(D) : null,
    sections: { body: a.sec_body, x: a.sec_x, hh: a.sec_half_height, hw: a.sec_half_width },
    measured: null, blocked: {}, frame: null, lost: null,
  };
}

// A frame of the server (fishfmu/serve/live.py, frame_of): poses (w, x, y, z quaternions), fish status, belts,
// devices, photo-eyes and the run's status.  A frame of another page (a reset changed the fish): load it anew.
// The same step in the same state again (a line in lockstep between steps, paused, ended) is not drawn again: a
// browser on the line's own machine takes no more of its CPU than the line's motion needs.
function applyFrame(f) {
  if (f.page !== header.live.page) { location.reload(); return; }
  const last = data.frame;
  if (last && !data.lost && last.step === f.step && last.run.run_state === f.run.run_state) return;
  data.pos.set(f.pos); data.quat.set(f.quat); data.status.set(f.status);
  data.beltTravel.set(f.belt_travel); data.beltSpeed.set(f.belt_speed);
  if (data.deviceP) data.deviceP.set(f.device_p);
  data.t[0] = f.t_s; data.blocked = f.blocked; data.frame = f; data.lost = null;
  state.time = f.t_s; state.dirty = true;
}

// The frame at or before t and the fraction towards the next one.
function frameAt(t) {
  const T = data.t, n = data.frames;
  if (n === 0 || t <= T[0]) return { k: 0, k1: 0, a: 0 };
  if (t >= T[n - 1]) return { k: n - 1, k1: n - 1, a: 0 };
  let lo = 0, hi = n - 1;
  while (hi - lo > 1) { const mid = (lo + hi) >> 1; if (T[mid] <= t) lo = mid; else hi = mid; }
  return { k: lo, k1: hi, a: (t - T[lo]) / (T[hi] - T[lo]) };
}

// Every body's position (x, y, z, visible) and orientation (x, y, z, w) at time t, interpolated.
function bodyPoses(t) {
  const { k, k1, a } = frameAt(t), F = data.frames, B = data.bodies;
  const near = a < 0.5 ? k : k1;
  const pos = new Float32Array(4 * B), rot = new Float32Array(4 * B);
  for (let b = 0; b < B; b++) {
    for (let c = 0; c < 3; c++) {
      const row = (3 * b + c) * F;
      pos[4 * b + c] = data.pos[row + k] * (1 - a) + data.pos[row + k1] * a;
    }
    pos[4 * b + 3] = data.status[data.bodyFish[b] * F + near] === 1 ? 1 : 0;
    const q = [0, 0, 0, 0];   // w, x, y, z; signs were made continuous when packed, so lerp + normalise
    for (let c = 0; c < 4; c++) {
      const row = (4 * b + c) * F;
      q[c] = data.quat[row + k] * (1 - a) + data.quat[row + k1] * a;
    }
    const norm = Math.hypot(q[0], q[1], q[2], q[3]) || 1;
    rot[4 * b] = q[1] / norm; rot[4 * b + 1] = q[2] / norm; rot[4 * b + 2] = q[3] / norm; rot[4 * b + 3] = q[0] / norm;
  }
  return { pos, rot };
}

function beltAt(t) {
  const { k, k1, a } = frameAt(t), F = data.frames, C = header.line.conveyors.length;
  const travel = [], speed = [];
  for (let c = 0; c < C; c++) {
    travel.push(data.beltTravel[c * F + k] * (1 - a) + data.beltTravel[c * F + k1] * a);
    speed.push(data.beltSpeed[c * F + k] * (1 - a) + data.beltSpeed[c * F + k1] * a);
  }
  return { travel, speed };
}

// Each device's position p at t (one per header.devices), interpolated: the pose is linear in p.
function devicePositions(t) {
  const devices = header.devices || [];
  if (!data.deviceP) return devices.map(() => 0);
  const { k, k1, a } = frameAt(t), F = data.frames;
  return devices.map((d, i) => data.deviceP[i * F + k] * (1 - a) + data.deviceP[i * F + k1] * a);
}

function photoeyesBlocked(t, eyes = header.photoeyes) {
  if (header.live && eyes === header.photoeyes) return Object.assign({}, data.blocked);
  const out = {};
  for (const [id, intervals] of Object.entries(eyes)) {
    out[id] = intervals.some(([on, off]) => t >= on && t < off);
  }
  return out;
}

// The measured beams at t, or null when the page has none.
function measuredPhotoeyesBlocked(t) {
  const eyes = header.measured && header.measured.photoeyes;
  return eyes ? photoeyesBlocked(t, eyes) : null;
}

const MAX_TRACK_GAP_S = 0.5;   // a measured fish is hidden in tracking gaps longer than this

// Measured fish at time t: mid-point and heading interpolated between the samples around t.
function measuredAt(t) {
  const m = data.measured, out = [];
  if (!m) return out;
  for (const f of m.fish) {
    const s = f.start, e = f.start + f.count - 1;
    if (f.count === 0 || t < m.t[s] - 0.02 || t > m.t[e] + 0.02) continue;
    let lo = s, hi = e;
    while (hi - lo > 1) { const mid = (lo + hi) >> 1; if (m.t[mid] <= t) lo = mid; else hi = mid; }
    if (m.t[lo] > t) hi = lo;
    if (m.t[hi] - m.t[lo] > MAX_TRACK_GAP_S) continue;
    const a = hi === lo ? 0 : Math.min(1, Math.max(0, (t - m.t[lo]) / (m.t[hi] - m.t[lo])));
    const n = m.t.length, lerp = (arr, off) => arr[off + lo] * (1 - a) + arr[off + hi] * a;
    out.push({ id: f.id, x: lerp(m.xy, 0), y: lerp(m.xy, n), yaw: lerp(m.yaw, 0),
               length_m: f.length_m, height_m: f.height_m, width_m: f.width_m });
  }
  return out;
}

// ----------------------------------------------------------------------------------- drawing
function viewProjection() {
  return ReplayRender.viewProjection(camera, canvas.clientWidth / Math.max(1, canvas.clientHeight));
}

function project(p, vp = viewProjection()) {
  return ReplayRender.project(p, vp, canvas.clientWidth, canvas.clientHeight);
}

function draw() {
  const t = state.time, belts = beltAt(t);
  const showMeasured = state.showMeasured && data.measured !== null;
  renderer.draw({ vp: viewProjection(), belts, blocked: photoeyesBlocked(t), poses: bodyPoses(t),
                  devices: devicePositions(t),
                  showSim: state.showSim, measured: showMeasured ? measuredAt(t) : [],
                  measuredBlocked: showMeasured ? measuredPhotoeyesBlocked(t) : null });
  updateText(belts);
  state.dirty = false;
  state.draws++;
}

function liveText(belts) {
  const f = data.frame, r = f ? f.run : null, ms = (s) => (s === null ? "–" : `${(1000 * s).toFixed(1)} ms`);
  const speeds = header.line.conveyors.map((c, i) => `${c.id} ${belts.speed[i].toFixed(2)}`).join(", ");
  ui.status.textContent = data.lost ? `no answer from the server: ${data.lost}` : !r ? "waiting for the first frame" :
    `${r.run_state} · t = ${f.t_s.toFixed(2)} s · lag ${ms(r.lag_s)} (max ${ms(r.lag_max_s)}) · ${r.late_steps} late steps` +
    ` · x${(r.realtime_factor_reached || 0).toFixed(2)} reached · fish: ${r.fish_on_line} on the line, ${r.fish_waiting}` +
    ` waiting, ${r.fish_left} left, ${r.fish_rejected} rejected · belts (m/s): ${speeds}`;
  ui.clock.textContent = f ? `${f.t_s.toFixed(2)} s · step ${f.step}` : "";
}

function updateText(belts) {
  if (header.live) { liveText(belts); return; }
  const t = state.time, { k } = frameAt(t), F = data.frames;
  let onLine = 0;
  for (let n = 0; n < header.fish.ids.length; n++) if (data.status[n * F + k] === 1) onLine++;
  const speeds = header.line.conveyors.map((c, i) => `${c.id} ${belts.speed[i].toFixed(2)}`).join(", ");
  const tracked = header.measured ? ` (simulated), ${measuredAt(t).length} tracked (measured)` : "";
  ui.status.textContent = `${onLine} of ${header.fish.ids.length} fish on the line${tracked} · belts (m/s): ${speeds}`;
  ui.clock.textContent = `${t.toFixed(2)} s / ${header.duration_s.toFixed(2)} s`;
  if (!state.sliderHeld) ui.time.value = t;
  ui.play.innerHTML = state.playing ? "&#10074;&#10074;" : "&#9654;";
}

// ---------------------------------------------------------------------------- time and camera
// Which runs are drawn: "sim", "measured" or "both" (a page without a measured run has only "sim").
function setShow(mode) {
  state.showSim = mode !== "measured";
  state.showMeasured = mode !== "sim";
  syncLayerControls();
  state.dirty = true;
}

function showMode() {
  return state.showSim && state.showMeasured ? "both" : state.showMeasured ? "measured" : state.showSim ? "sim" : "none";
}

function syncLayerControls() {   // the buttons of a page with a measured run (others have the checkbox only)
  for (const b of ui.layers.querySelectorAll("button")) b.setAttribute("aria-pressed", String(b.dataset.show === showMode()));
}

function setTime(t) { state.time = Math.min(Math.max(t, 0), header.duration_s); state.dirty = true; }
function play() { if (state.time >= header.duration_s) setTime(0); state.playing = true; state.lastNow = null; state.dirty = true; }
function pause() { state.playing = false; state.dirty = true; }

function tick(now) {
  if (state.playing) {
    if (state.lastNow !== null) setTime(state.time + (now - state.lastNow) / 1000 * state.speed);
    state.lastNow = now;
    if (state.time >= header.duration_s) pause();
  }
  if (state.dirty) draw();
  requestAnimationFrame(tick);
}

function setView(name) {
  const ext = ReplayRender.lineExtent(header.line), length = ext.x1 - ext.x0;
  const aspect = canvas.clientWidth / Math.max(1, canvas.clientHeight);
  const halfFovX = Math.atan(Math.tan(camera.fovY / 2) * aspect);
  camera.target = [(ext.x0 + ext.x1) / 2, 0, (ext.zTop + ext.zLow) / 2];
  const fit = (0.55 * length + 0.3) / Math.tan(halfFovX);   // the whole line across the window
  if (name === "top") Object.assign(camera, { yaw: -Math.PI / 2, pitch: 1.5, dist: fit });
  else if (name === "side") Object.assign(camera, { yaw: -Math.PI / 2, pitch: 0.08, dist: fit });
  else Object.assign(camera, { yaw: -Math.PI / 2 - 0.35, pitch: 0.55, dist: 1.0 * fit });
  state.dirty = true;
}

function setupInput() {
  const pointers = new Map();
  let pinch = null;
  canvas.addEventListener("contextmenu", (e) => e.preventDefault());
  canvas.addEventListener("pointerdown", (e) => {
    canvas.setPointerCapture(e.pointerId);
    pointers.set(e.pointerId, { x: e.clientX, y: e.clientY, pan: e.button === 2 || e.shiftKey });
    pinch = null;
  });
  const release = (e) => { pointers.delete(e.pointerId); pinch = null; };
  canvas.addEventListener("pointerup", release);
  canvas.addEventListener("pointercancel", release);
  canvas.addEventListener("pointermove", (e) => {
    const p = pointers.get(e.pointerId);
    if (!p) return;
    const dx = e.clientX - p.x, dy = e.clientY - p.y;
    p.x = e.clientX; p.y = e.clientY;
    if (pointers.size === 2) {          // two fingers: pinch to zoom
      const [a, b] = [...pointers.values()], span = Math.hypot(a.x - b.x, a.y - b.y);
      if (pinch) camera.dist *= pinch / Math.max(span, 1);
      pinch = span;
    } else if (p.pan) {
      panCamera(dx, dy);
    } else {
      camera.yaw -= dx * 0.006;
      camera.pitch = Math.min(1.55, Math.max(-0.2, camera.pitch + dy * 0.006));
    }
    state.dirty = true;
  });
  canvas.addEventListener("wheel", (e) => {
    e.preventDefault();
    camera.dist = Math.min(100, Math.max(0.2, camera.dist * Math.exp(e.deltaY * 0.001)));
    state.dirty = true;
  }, { passive: false });
  canvas.addEventListener("dblclick", () => setView("3d"));
  ui.play.addEventListener("click", () => (state.playing ? pause() : play()));
  ui.time.addEventListener("input", () => setTime(parseFloat(ui.time.value)));
  ui.time.addEventListener("pointerdown", () => { state.sliderHeld = true; });
  for (const type of ["pointerup", "pointercancel", "change"]) ui.time.addEventListener(type, () => { state.sliderHeld = false; });
  ui.speed.addEventListener("change", () => { state.speed = parseFloat(ui.speed.value); });
  for (const name of ["3d", "top", "side"]) document.getElementById(`view-${name}`).addEventListener("click", () => setView(name));
  ui.sim.addEventListener("change", () => { state.showSim = ui.sim.checked; state.dirty = true; });
  for (const b of ui.layers.querySelectorAll("button")) b.addEventListener("click", () => setShow(b.dataset.show));
  window.addEventListener("resize", () => { state.dirty = true; });
  window.addEventListener("keydown", (e) => {
    if (e.target instanceof HTMLInputElement || e.target instanceof HTMLSelectElement) return;
    if (e.key === " ") { e.preventDefault(); state.playing ? pause() : play(); }
    if (e.key === "ArrowRight") setTime(state.time + 0.04);
    if (e.key === "ArrowLeft") setTime(state.time - 0.04);
    if (e.key === "Home") setTime(0);
    if ((e.key === "m" || e.key === "M") && header.measured) setShow({ both: "sim", sim: "measured" }[showMode()] || "both");
  });
}

function panCamera(dx, dy) {
  const scale = camera.dist * 0.0015, c = Math.cos(camera.yaw), s = Math.sin(camera.yaw);
  camera.target[0] += (s * dx - c * dy * Math.sin(camera.pitch)) * scale;   // minus right * dx, plus up * dy
  camera.target[1] += (-c * dx - s * dy * Math.sin(camera.pitch)) * scale;
  camera.target[2] += dy * Math.cos(camera.pitch) * scale;
}

// --------------------------------------------------------------------- the page and its API
function describe() {
  const m = header.measured;
  ui.title.textContent = `${header.name} · run ${header.run_id} · ${header.fish.ids.length} fish` +
                         (m ? " · measured and simulated" : "");
  let legend = '<span class="swatch" style="background:#8a7"></span>simulated fish (a colour each)';
  if (m) legend += '<span class="swatch ghost"></span>measured fish: pale ghost, same colour, dark edge';
  if ((header.devices || []).length) legend += '<span class="swatch" style="background:#f5bd14"></span>gates, pushers, diverters';
  legend += `<span class="swatch" style="background:#2a5"></span>photo-eye clear<span class="swatch" style="background:#e21"></span>blocked${m ? " (simulated)" : ""}`;
  if (m && m.photoeyes) legend += '<span class="swatch lamp"></span>lamp on top: measured beam blocked';
  ui.legend.innerHTML = legend;
  if (header.live) {   // the line runs on the server: no time to choose, nothing to play
    ui.title.textContent = `${header.name} · live · ${header.fish.ids.length} fish`;
    for (const el of [ui.play, ui.time, ui.speed.parentElement]) el.hidden = true;
  }
  ui.time.max = header.duration_s;
  ui.time.step = 0.01;
  ui.layers.hidden = !m;
  document.getElementById("toggle-sim-label").hidden = !!m;
}

// For tests and scripts: the state, and where things are drawn (CSS pixels from the canvas' top-left).
const api = {
  ready: null,
  duration: () => header.duration_s,
  time: () => state.time,
  setTime: (t) => { setTime(t); draw(); },
  play, pause,
  playing: () => state.playing,
  speed: () => state.speed,
  render: () => draw(),
  draws: () => state.draws,   // pictures drawn so far
  setLayer: (name, on) => { state[name === "measured" ? "showMeasured" : "showSim"] = on; syncLayerControls(); draw(); },
  show: (mode) => { setShow(mode); draw(); },
  showing: () => showMode(),
  camera: () => JSON.parse(JSON.stringify(camera)),
  setCamera: (c) => { Object.assign(camera, c); draw(); },
  setView: (name) => { setView(name); draw(); },
  viewProjection: () => Array.from(viewProjection()),
  project: (p) => project(p),
  canvasSize: () => [canvas.clientWidth, canvas.clientHeight],
  bodyWorldPositions: () => {
    const { pos } = bodyPoses(state.time), out = [];
    for (let b = 0; b < data.bodies; b++) out.push([pos[4 * b], pos[4 * b + 1], pos[4 * b + 2], pos[4 * b + 3]]);
    return out;
  },
  fishScreenPositions: () => {
    const { pos } = bodyPoses(state.time), vp = viewProjection();
    return header.fish.ids.map((id, n) => {
      const bodies = [];
      data.bodyFish.forEach((f, b) => { if (f === n) bodies.push(project([pos[4 * b], pos[4 * b + 1], pos[4 * b + 2]], vp)); });
      const first = data.bodyFish.indexOf(n);
      return { id, visible: first >= 0 && pos[4 * first + 3] === 1 && state.showSim, bodies };
    });
  },
  photoeyesBlocked: () => photoeyesBlocked(state.time),
  // A live page: apply a frame of the server, the last one applied (null before the first), connection lost.
  applyFrame: (f) => applyFrame(f),   // drawn at the next animation frame
  frame: () => (data && data.frame ? { step: data.frame.step, t_s: data.frame.t_s, run: data.frame.run } : null),
  lost: (why) => { if (data.lost !== why) { data.lost = why; state.dirty = true; } },
  beltTravel: () => beltAt(state.time).travel,
  measuredFish: () => measuredAt(state.time),
  measuredDrawn: () => (state.showMeasured ? measuredAt(state.time) : []),
  measuredPhotoeyesBlocked: () => measuredPhotoeyesBlocked(state.time),
  guideY: (x) => ReplayRender.guideY(header.line, x),
  // The devices (header.devices' order) at the current time: id, kind and the recorded position p.
  devicePositions: () => (header.devices || []).map((d, i) => ({ id: d.id, kind: d.kind, p: devicePositions(state.time)[i] })),
  // Device i as drawn in the last picture: its position p, its body -> line matrix (column-major 4x4) and its
  // triangles' corners in the line frame (null if the last picture did not draw it).
  devicePose: (i) => {
    const drawn = renderer.drawnDevices()[i];
    if (!drawn) return null;
    const local = header.devices[i].triangles, corners = [];
    for (let c = 0; c < local.length; c += 3) corners.push(ReplayRender.transformPoint(drawn.matrix, local.slice(c, c + 3)));
    return { id: drawn.id, p: drawn.p, matrix: drawn.matrix, corners };
  },
};
window.replay = api;

api.ready = (async function start() {
  describe();
  try {
    data = await loadData();
    renderer = ReplayRender.createRenderer(canvas, header, data);
    setupInput();
    setView("3d");
    draw();
    requestAnimationFrame(tick);
    if (header.live) window.ReplayLive.follow(api, header.live);
    document.body.dataset.ready = "1";
  } catch (err) {
    ui.status.textContent = `cannot show the replay: ${err.message}`;
    document.body.dataset.ready = "error";
    window.replayError = String(err && err.stack || err);
    throw err;
  }
})();
})();
