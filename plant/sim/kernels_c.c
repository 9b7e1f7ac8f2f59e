/* The plant's per-step arithmetic on small arrays, in one pass each (plant.sim.kernels says why and what).
 *
 * Every function repeats, element by element, the floating-point operations of its numpy reference in the
 * same order (including the order in which numpy's einsum sums three products, (p0 + p2) + p1), so that
 * it gives the same numbers to the bit: tests/test_kernels.py holds each to its reference.  Compiled
 * without contraction into fused multiply-adds (setup: -ffp-contract=off), which would round differently.
 * Arrays come through the buffer protocol (C-contiguous float64, int64 or bool), no numpy headers. */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <math.h>
#include <stdint.h>
#include <string.h>

typedef struct {
    Py_buffer view;
    int held;
} Arg;

/* The buffer of `obj`, C-contiguous, of item `format` ('d', 'q' or '?'), `ndim` dimensions with the
 * given sizes (-1: any). */
static int get_array(PyObject *obj, Arg *arg, const char *name, char format, int ndim, const Py_ssize_t *shape,
                     int writable) {
    int flags = PyBUF_C_CONTIGUOUS | PyBUF_FORMAT | (writable ? PyBUF_WRITABLE : 0);
    if (PyObject_GetBuffer(obj, &arg->view, flags) < 0) {
        PyErr_Format(PyExc_TypeError, "%s: a C-contiguous%s array is needed", name, writable ? " writable" : "");
        return -1;
    }
    arg->held = 1;
    const char *f = arg->view.format;
    if (f[0] == '<' || f[0] == '=' || f[0] == '@') f++;
    char want = format;
    int ok_format = (f[0] == want && f[1] == '\0') || (want == 'q' && (f[0] == 'l') && f[1] == '\0'
                                                       && arg->view.itemsize == 8);
    if (!ok_format || arg->view.ndim != ndim) {
        PyErr_Format(PyExc_TypeError, "%s: expected %d dimensions of '%c', got %d of '%s'", name, ndim, format,
                     arg->view.ndim, arg->view.format);
        return -1;
    }
    for (int i = 0; i < ndim; i++) {
        if (shape[i] >= 0 && arg->view.shape[i] != shape[i]) {
            PyErr_Format(PyExc_ValueError, "%s: dimension %d is %zd, expected %zd", name, i, arg->view.shape[i],
                         shape[i]);
            return -1;
        }
    }
    return 0;
}

static void release(Arg *args, int n) {
    for (int i = 0; i < n; i++) {
        if (args[i].held) PyBuffer_Release(&args[i].view);
        args[i].held = 0;
    }
}

#define D(a) ((double *)(a).view.buf)
#define Q(a) ((int64_t *)(a).view.buf)
#define B(a) ((unsigned char *)(a).view.buf)
#define LEN(a) ((a).view.shape[0])

/* True when joint j's bodies are among the nb bodies; an IndexError naming them otherwise. */
static int joint_in_range(Py_ssize_t j, int64_t ia, int64_t ib, Py_ssize_t nb) {
    if (ia >= 0 && ia < nb && ib >= 0 && ib < nb) return 1;
    PyErr_Format(PyExc_IndexError, "joint %zd joins body %lld and %lld of %zd", j, (long long)ia, (long long)ib, nb);
    return 0;
}

/* numpy's einsum over three products: two lanes, (p0 + p2) + p1 */
static inline double sum3(double p0, double p1, double p2) { return (p0 + p2) + p1; }

static inline double np_sign(double x) { return x > 0.0 ? 1.0 : (x < 0.0 ? -1.0 : (x == 0.0 ? 0.0 : x)); }

static inline double np_max(double a, double b) { return (a >= b || a != a) ? a : b; }

static inline double np_clip(double x, double lo, double hi) {
    double y = (x >= lo || x != x) ? x : lo; /* np.clip: maximum, then minimum */
    return (y <= hi || y != y) ? y : hi;
}

/* rotation_matrices(coords (n, m), column, out (n, 3, 3)): Rodrigues' formula for the rotation vectors in
 * coords[:, column:column + 3] (plant.sim.rotations.rotvec_to_matrix). */
static PyObject *rotation_matrices(PyObject *self, PyObject *args) {
    PyObject *o_coords, *o_out;
    Py_ssize_t column;
    if (!PyArg_ParseTuple(args, "OnO", &o_coords, &column, &o_out)) return NULL;
    Arg a[2] = {{0}};
    Py_ssize_t any2[2] = {-1, -1};
    if (get_array(o_coords, &a[0], "coords", 'd', 2, any2, 0) < 0) goto fail;
    Py_ssize_t n = LEN(a[0]), m = a[0].view.shape[1];
    Py_ssize_t s_out[3] = {n, 3, 3};
    if (get_array(o_out, &a[1], "out", 'd', 3, s_out, 1) < 0) goto fail;
    if (column < 0 || column + 3 > m) {
        PyErr_SetString(PyExc_ValueError, "column: the three columns are not in coords");
        goto fail;
    }
    const double *c = D(a[0]);
    double *r = D(a[1]);
    for (Py_ssize_t i = 0; i < n; i++, r += 9) {
        double x = c[i * m + column], y = c[i * m + column + 1], z = c[i * m + column + 2];
        double th2 = sum3(x * x, y * y, z * z);
        double th = sqrt(th2), sa, sb;
        if (th < 1e-6) {
            sa = 1.0 - th2 / 6.0;
            sb = 0.5 - th2 / 24.0;
        } else {
            sa = sin(th) / th;
            sb = (1.0 - cos(th)) / (th * th);
        }
        double xx = x * x, yy = y * y, zz = z * z;
        double ax = sa * x, ay = sa * y, az = sa * z;
        double bx = sb * x;
        double bxy = bx * y, bxz = bx * z, byz = sb * y * z;
        r[0] = 1.0 - sb * (yy + zz);
        r[4] = 1.0 - sb * (xx + zz);
        r[8] = 1.0 - sb * (xx + yy);
        r[1] = bxy - az;
        r[3] = bxy + az;
        r[2] = bxz + ay;
        r[6] = bxz - ay;
        r[5] = byz - ax;
        r[7] = byz + ax;
    }
    release(a, 2);
    Py_RETURN_NONE;
fail:
    release(a, 2);
    return NULL;
}

/* joint_cosines(rot (nb, 3, 3), joint_bodies (J, 2), rel (J, 3, 3) out, cos (J,) out): each joint's relative
 * rotation rot_a^T rot_b (einsum "nji,njk->nik": summed in order j = 0, 1, 2) and the cosine of its angle,
 * clipped to [-1, 1] (the first half of plant.sim.rotations.matrix_to_rotvec; numpy's arccos comes between). */
static PyObject *joint_cosines(PyObject *self, PyObject *args) {
    PyObject *o_rot, *o_jb, *o_rel, *o_cos;
    if (!PyArg_ParseTuple(args, "OOOO", &o_rot, &o_jb, &o_rel, &o_cos)) return NULL;
    Arg a[4] = {{0}};
    Py_ssize_t s_rot[3] = {-1, 3, 3}, s_jb[2] = {-1, 2};
    if (get_array(o_rot, &a[0], "rot", 'd', 3, s_rot, 0) < 0 || get_array(o_jb, &a[1], "joint_bodies", 'q', 2, s_jb, 0) < 0)
        goto fail;
    Py_ssize_t nb = LEN(a[0]), nj = LEN(a[1]);
    Py_ssize_t s_rel[3] = {nj, 3, 3}, s_cos[1] = {nj};
    if (get_array(o_rel, &a[2], "rel", 'd', 3, s_rel, 1) < 0 || get_array(o_cos, &a[3], "cos", 'd', 1, s_cos, 1) < 0)
        goto fail;
    const double *rot = D(a[0]);
    const int64_t *jb = Q(a[1]);
    double *rel = D(a[2]), *cs = D(a[3]);
    for (Py_ssize_t j = 0; j < nj; j++) {
        int64_t ia = jb[2 * j], ib = jb[2 * j + 1];
        if (!joint_in_range(j, ia, ib, nb)) goto fail;
        const double *ra = rot + 9 * ia, *rb = rot + 9 * ib;
        double *r = rel + 9 * j;
        for (int i = 0; i < 3; i++)
            for (int k = 0; k < 3; k++)
                r[3 * i + k] = ra[i] * rb[k] + ra[3 + i] * rb[3 + k] + ra[6 + i] * rb[6 + k];
        cs[j] = np_clip((r[0] + r[4] + r[8] - 1.0) / 2.0, -1.0, 1.0);
    }
    release(a, 4);
    Py_RETURN_NONE;
fail:
    release(a, 4);
    return NULL;
}

/* One joint's law on one axis at |theta| = v: phi and its slope (plant.sim.joints._phi). */
static inline void phi_slope(double v, double lo, double hi, double limit, double w4, double w2, double *phi,
                             double *slope) {
    double dz = v - lo;
    if (v >= hi) {
        *phi = v - limit;
        *slope = 1.0;
    } else if (v > lo) {
        *phi = dz * dz / w4;
        *slope = dz / w2;
    } else {
        *phi = 0.0;
        *slope = 0.0;
    }
}

/* joint_springs(...): the rest of plant.sim.joints.relinearized for every joint, given rel and th = arccos(cos)
 * from joint_cosines:
 *   (rel (J,3,3), th (J,), velocities (nb, m), column of the body-frame angular velocity in them,
 *    joint_bodies (J,2), active (J,) bool, dt_s,
 *    laws (8, J, 3): limit, k_soft, k_limit, zone start, zone end, 4 w, 2 w, soft_until,
 *    k_now (J,3), offset_now (J,3), changed (J,) bool out, k_new (J,3) out, offset_new (J,3) out) -> bool
 * Returns False (and leaves the outputs unset) when a joint's angle is near pi, where the rotation vector is taken
 * from the symmetric part: the caller then uses the reference. */
static PyObject *joint_springs(PyObject *self, PyObject *args) {
    PyObject *o[11];
    double dt;
    Py_ssize_t column;
    if (!PyArg_ParseTuple(args, "OOOnOOdOOOOOO", &o[0], &o[1], &o[2], &column, &o[3], &o[4], &dt, &o[5], &o[6], &o[7],
                          &o[8], &o[9], &o[10]))
        return NULL;
    Arg a[11] = {{0}};
    Py_ssize_t s_rel[3] = {-1, 3, 3};
    if (get_array(o[0], &a[0], "rel", 'd', 3, s_rel, 0) < 0) goto fail;
    Py_ssize_t nj = LEN(a[0]);
    Py_ssize_t s_th[1] = {nj}, s_om[2] = {-1, -1}, s_jb[2] = {nj, 2}, s_laws[3] = {8, nj, 3}, s_j3[2] = {nj, 3};
    if (get_array(o[1], &a[1], "th", 'd', 1, s_th, 0) < 0 || get_array(o[2], &a[2], "omega", 'd', 2, s_om, 0) < 0
        || get_array(o[3], &a[3], "joint_bodies", 'q', 2, s_jb, 0) < 0
        || get_array(o[4], &a[4], "active", '?', 1, s_th, 0) < 0
        || get_array(o[5], &a[5], "laws", 'd', 3, s_laws, 0) < 0
        || get_array(o[6], &a[6], "k_now", 'd', 2, s_j3, 0) < 0
        || get_array(o[7], &a[7], "offset_now", 'd', 2, s_j3, 0) < 0
        || get_array(o[8], &a[8], "changed", '?', 1, s_th, 1) < 0
        || get_array(o[9], &a[9], "k_new", 'd', 2, s_j3, 1) < 0
        || get_array(o[10], &a[10], "offset_new", 'd', 2, s_j3, 1) < 0)
        goto fail;
    const double *rel = D(a[0]), *th = D(a[1]), *om = D(a[2]), *laws = D(a[5]), *k_now = D(a[6]),
                 *off_now = D(a[7]);
    const int64_t *jb = Q(a[3]);
    const unsigned char *active = B(a[4]);
    unsigned char *changed = B(a[8]);
    double *k_new = D(a[9]), *off_new = D(a[10]);
    Py_ssize_t nb = LEN(a[2]), m = a[2].view.shape[1], plane = nj * 3;
    if (column < 0 || column + 3 > m) {
        PyErr_SetString(PyExc_ValueError, "column: the angular velocity's three columns are not in omega");
        goto fail;
    }
    const double *limit = laws, *k_soft = laws + plane, *k_limit = laws + 2 * plane, *lo = laws + 3 * plane,
                 *hi = laws + 4 * plane, *w4 = laws + 5 * plane, *w2 = laws + 6 * plane, *soft_until = laws + 7 * plane;
    const double near_pi = M_PI - 1e-3;
    for (Py_ssize_t j = 0; j < nj; j++)
        if (th[j] > near_pi) {
            release(a, 11);
            Py_RETURN_FALSE;
        }
    for (Py_ssize_t j = 0; j < nj; j++) {
        const double *r = rel + 9 * j;
        int64_t ia = jb[2 * j], ib = jb[2 * j + 1];
        if (!joint_in_range(j, ia, ib, nb)) goto fail;
        /* the rotation vector (matrix_to_rotvec's second half) */
        double sn = sin(th[j]);
        double scale = sn < 1e-6 ? 0.5 + th[j] * th[j] / 12.0 : th[j] / (2.0 * sn);
        double w[3] = {r[7] - r[5], r[2] - r[6], r[3] - r[1]};
        double theta[3], next[3];
        const double *oa = om + m * ia + column, *ob = om + m * ib + column;
        int near = 0;
        for (int c = 0; c < 3; c++) {
            theta[c] = w[c] * scale;
            double w_b_in_a = sum3(r[3 * c] * ob[0], r[3 * c + 1] * ob[1], r[3 * c + 2] * ob[2]);
            next[c] = theta[c] + (w_b_in_a - oa[c]) * dt;
        }
        for (int c = 0; c < 3; c++) {
            Py_ssize_t e = 3 * j + c;
            near |= (fabs(theta[c]) > soft_until[e]) | (fabs(next[c]) > soft_until[e]);
        }
        near &= active[j] != 0;
        int moved = 0;
        for (int c = 0; c < 3; c++) {
            Py_ssize_t e = 3 * j + c;
            double k, off;
            if (near) { /* plant.sim.joints.linearize */
                double gap = k_limit[e] - k_soft[e], phi0, slope0, phi1, slope1;
                phi_slope(fabs(theta[c]), lo[e], hi[e], limit[e], w4[e], w2[e], &phi0, &slope0);
                phi_slope(fabs(next[c]), lo[e], hi[e], limit[e], w4[e], w2[e], &phi1, &slope1);
                k = np_max(k_soft[e] + gap * slope0, k_soft[e] + gap * slope1);
                off = theta[c] - (k_soft[e] * theta[c] + gap * phi0 * np_sign(theta[c])) / k;
            } else {
                k = k_soft[e];
                off = 0.0;
            }
            k_new[e] = k;
            off_new[e] = off;
            moved |= (fabs(k - k_now[e]) > 0.02 * k_now[e]) | (fabs(off - off_now[e]) > 0.005);
        }
        changed[j] = (unsigned char)moved;
    }
    release(a, 11);
    Py_RETURN_TRUE;
fail:
    release(a, 11);
    return NULL;
}

/* beams_blocked(pos (nb,3), rot (nb,3,3), body_on (nb,) bool, reach (nb,) [the outline's reach + 1e-9],
 *               section_body (S,), section_x (S,), half_len (S,), radius (S,), beams_xz (P,2), span (P,2),
 *               blocked (P,) bool out): plant.sim.sensors.beams_blocked after its reach is known, one pass. */
static PyObject *beams_blocked(PyObject *self, PyObject *args) {
    PyObject *o[11];
    if (!PyArg_ParseTuple(args, "OOOOOOOOOOO", &o[0], &o[1], &o[2], &o[3], &o[4], &o[5], &o[6], &o[7], &o[8], &o[9],
                          &o[10]))
        return NULL;
    Arg a[11] = {{0}};
    Py_ssize_t s_pos[2] = {-1, 3};
    if (get_array(o[0], &a[0], "pos", 'd', 2, s_pos, 0) < 0) goto fail;
    Py_ssize_t nb = LEN(a[0]);
    Py_ssize_t s_rot[3] = {nb, 3, 3}, s_nb[1] = {nb}, s_any[1] = {-1};
    if (get_array(o[1], &a[1], "rot", 'd', 3, s_rot, 0) < 0 || get_array(o[2], &a[2], "body_on", '?', 1, s_nb, 0) < 0
        || get_array(o[3], &a[3], "reach", 'd', 1, s_nb, 0) < 0
        || get_array(o[4], &a[4], "section_body", 'q', 1, s_any, 0) < 0)
        goto fail;
    Py_ssize_t ns = LEN(a[4]);
    Py_ssize_t s_s[1] = {ns}, s_p2[2] = {-1, 2};
    if (get_array(o[5], &a[5], "section_x", 'd', 1, s_s, 0) < 0 || get_array(o[6], &a[6], "half_len", 'd', 1, s_s, 0) < 0
        || get_array(o[7], &a[7], "radius", 'd', 1, s_s, 0) < 0 || get_array(o[8], &a[8], "beams_xz", 'd', 2, s_p2, 0) < 0)
        goto fail;
    Py_ssize_t np_ = LEN(a[8]);
    Py_ssize_t s_span[2] = {np_, 2}, s_p[1] = {np_};
    if (get_array(o[9], &a[9], "span", 'd', 2, s_span, 0) < 0 || get_array(o[10], &a[10], "blocked", '?', 1, s_p, 1) < 0)
        goto fail;
    const double *pos = D(a[0]), *rot = D(a[1]), *reach = D(a[3]), *sx = D(a[5]), *hl = D(a[6]), *rad = D(a[7]),
                 *beams = D(a[8]), *span = D(a[9]);
    const unsigned char *on = B(a[2]);
    const int64_t *sb = Q(a[4]);
    unsigned char *blocked = B(a[10]);
    memset(blocked, 0, (size_t)np_);
    for (Py_ssize_t s = 0; s < ns; s++) {
        int64_t b = sb[s];
        if (b < 0 || b >= nb || !on[b]) continue;
        const double *p = pos + 3 * b, *r = rot + 9 * b;
        double cx = p[0] + r[0] * sx[s], cy = p[1] + r[3] * sx[s], cz = p[2] + r[6] * sx[s];
        double ux = r[1], uy = r[4], uz = r[7]; /* the body's dorsal direction: the cross-section's axis */
        for (Py_ssize_t k = 0; k < np_; k++) {
            if (blocked[k]) continue;
            double bx = beams[2 * k], bz = beams[2 * k + 1];
            if (!(fabs(p[0] - bx) < reach[b]) || !(fabs(cx - bx) < hl[s] + rad[s] + 1e-9)) continue;
            /* plant.sim.sensors.capsules_cut */
            double dx = cx - bx, dz = cz - bz;
            double uu = ux * ux + uz * uz;
            double t = -(dx * ux + dz * uz) / (uu > 1e-12 ? uu : 1.0);
            t = np_clip(t, -hl[s], hl[s]);
            double ex = dx + t * ux, ez = dz + t * uz, y = cy + t * uy;
            if ((ex * ex + ez * ez < rad[s] * rad[s]) && (y < span[2 * k] + rad[s]) && (y > span[2 * k + 1] - rad[s]))
                blocked[k] = 1;
        }
    }
    release(a, 11);
    Py_RETURN_NONE;
fail:
    release(a, 11);
    return NULL;
}


/* all_clear(pos (n,3), velocities (n,m), column of the velocity in them, body_on (n,) bool, x_from, x_guides_to,
 * x_belts_to, y_low, y_high, z_low, speed2_max) -> bool: plant.sim.health._all_clear over the bodies on the line:
 * every one finite and slower than the limit (its squared speed summed as numpy's einsum does); from x_from to
 * x_guides_to inside y_low < y < y_high, and before x_belts_to above z_low. */
static PyObject *all_clear(PyObject *self, PyObject *args) {
    PyObject *o_pos, *o_vel, *o_on;
    Py_ssize_t column;
    double x_from, x_guides_to, x_belts_to, y_low, y_high, z_low, speed2_max;
    if (!PyArg_ParseTuple(args, "OOnOddddddd", &o_pos, &o_vel, &column, &o_on, &x_from, &x_guides_to, &x_belts_to,
                          &y_low, &y_high, &z_low, &speed2_max))
        return NULL;
    Arg a[3] = {{0}};
    Py_ssize_t s_pos[2] = {-1, 3};
    if (get_array(o_pos, &a[0], "pos", 'd', 2, s_pos, 0) < 0) goto fail;
    Py_ssize_t n = LEN(a[0]);
    Py_ssize_t s_vel[2] = {n, -1}, s_on[1] = {n};
    if (get_array(o_vel, &a[1], "velocities", 'd', 2, s_vel, 0) < 0 || get_array(o_on, &a[2], "body_on", '?', 1, s_on, 0) < 0)
        goto fail;
    Py_ssize_t m = a[1].view.shape[1];
    if (column < 0 || column + 3 > m) {
        PyErr_SetString(PyExc_ValueError, "column: the velocity's three columns are not in velocities");
        goto fail;
    }
    const double *pos = D(a[0]), *vel = D(a[1]);
    const unsigned char *on = B(a[2]);
    int clear = 1;
    for (Py_ssize_t i = 0; i < n && clear; i++) {
        if (!on[i]) continue;
        const double *p = pos + 3 * i, *v = vel + m * i + column;
        clear = isfinite(p[0]) && isfinite(p[1]) && isfinite(p[2])
                && sum3(v[0] * v[0], v[1] * v[1], v[2] * v[2]) < speed2_max;
        if (clear && p[0] >= x_from && p[0] <= x_guides_to)
            clear = p[1] > y_low && p[1] < y_high && (p[0] >= x_belts_to || p[2] > z_low);
    }
    release(a, 3);
    return PyBool_FromLong(clear);
fail:
    release(a, 3);
    return NULL;
}

static PyMethodDef methods[] = {
    {"rotation_matrices", rotation_matrices, METH_VARARGS, "Rodrigues' formula for coords[:, column:column+3]."},
    {"joint_cosines", joint_cosines, METH_VARARGS, "Each joint's relative rotation and the cosine of its angle."},
    {"joint_springs", joint_springs, METH_VARARGS, "The joints' linear springs for the coming step."},
    {"beams_blocked", beams_blocked, METH_VARARGS, "The photo-eye beams cut by the outlines of fish on the line."},
    {"all_clear", all_clear, METH_VARARGS, "No body on the line can fail the health check."},
    {NULL, NULL, 0, NULL}};

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "kernels_c",
                                    "The plant's per-step arithmetic in one pass each (plant.sim.kernels).", -1,
                                    methods};

PyMODINIT_FUNC PyInit_kernels_c(void) { return PyModule_Create(&module); }
