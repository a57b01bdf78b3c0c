/* Compiled per-frame path of the geometric localizer (module courtloc.localizer._fit_kernel):
 *   hit_geometry: scan hits -> floor points (the package's per-pixel table) -> the fit's per-hit geometry
 *                 (projection.HitGeometry.from_points);
 *   fit:          the whole robust pose fit of fit.fit_poses (all starts, all iterations, quality numbers).
 *
 * The numpy code in projection.py / fit.py is the reference: this file follows it operation by operation
 * (same formulas, float32 arithmetic where numpy does it in float32) so the two agree to rounding;
 * tests/test_localizer_kernel.py holds them together. Deliberate differences, all at rounding level:
 * sums run in another order than numpy's BLAS, sqrt(x^2 + y^2) and one reciprocal replace hypot and two
 * divisions, v * v * v for pow(v, 3), and the tilted floor point uses cot = 1 / tan(depression) (by the tangent
 * addition formula from the untilted one, 1 / sin^2 = 1 + cot^2) instead of tan and sin per evaluation.
 * At ~110 hits a numpy fit costs its per-call overhead (~75 calls per residual evaluation); this removes it.
 *
 * Pure C99 + the CPython C API and buffer protocol (no numpy headers); single-threaded.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>

#include <math.h>
#include <stdlib.h>
#include <string.h>

#define NOUT 20 /* per start: params[5], cost, n_in, rms, pos_std, yaw_std, cov[9], cov_ok */
/* Packed hit geometry, one row of HS doubles per hit (projection.PACKED_COLUMNS says the same):
 * point x, y | ray dir x, y | sigma along, across (m per pixel) | view dir x, y | range | depression |
 * tan(azimuth) | floor metres per scan step (0: unknown) */
#define HS 12
#define H_PX 0
#define H_RX 2
#define H_SIG 4
#define H_VX 6
#define H_RANGE 8
#define H_DEP 9
#define H_TAN 10
#define H_STEP 11
#define MAX_KNOTS 16 /* config.FitConfig's band-bias knots */

static const double PI = 3.141592653589793; /* math.pi */

#if defined(__GNUC__) || defined(__clang__)
#define PREFETCH(p) __builtin_prefetch(p)
#else
#define PREFETCH(p) ((void)0)
#endif

static int get_buffer(PyObject *obj, Py_buffer *view, const char *fmt, Py_ssize_t count, int writable,
                      const char *name)
{
    if (PyObject_GetBuffer(obj, view, PyBUF_C_CONTIGUOUS | PyBUF_FORMAT | (writable ? PyBUF_WRITABLE : 0)) < 0)
        return -1;
    if (view->format == NULL || strcmp(view->format, fmt) != 0 || (count >= 0 && view->len != count * view->itemsize)
        || view->len % view->itemsize != 0) {
        PyErr_Format(PyExc_ValueError, "%s: expected C-contiguous items of format '%s' (count %zd)", name, fmt, count);
        PyBuffer_Release(view);
        return -1;
    }
    return 0;
}

/* ---------------------------------------------------------------- the field: grids held once */

typedef struct {
    PyObject_HEAD
    Py_buffer values;
    Py_buffer half;
    int has_values, has_half;
    Py_ssize_t nx, ny;
    double x0, y0, res;
} FieldObject;

static int Field_init(FieldObject *self, PyObject *args, PyObject *kwds)
{
    PyObject *values, *half;
    if (self->has_values) {
        PyErr_SetString(PyExc_TypeError, "Field: already initialised");
        return -1;
    }
    if (!PyArg_ParseTuple(args, "OOnnddd:Field", &values, &half, &self->ny, &self->nx, &self->x0, &self->y0,
                          &self->res))
        return -1;
    if (self->nx < 2 || self->ny < 2 || !(self->res > 0.0)) {
        PyErr_SetString(PyExc_ValueError, "Field: grid must be at least 2 x 2 with a positive resolution");
        return -1;
    }
    if (get_buffer(values, &self->values, "f", self->nx * self->ny, 0, "values") < 0)
        return -1;
    self->has_values = 1;
    if (half != Py_None) {
        if (get_buffer(half, &self->half, "f", self->nx * self->ny, 0, "half_width") < 0)
            return -1;
        self->has_half = 1;
    }
    return 0;
}

static void Field_dealloc(FieldObject *self)
{
    if (self->has_values)
        PyBuffer_Release(&self->values);
    if (self->has_half)
        PyBuffer_Release(&self->half);
    Py_TYPE(self)->tp_free((PyObject *)self);
}

static PyTypeObject FieldType = {
    PyVarObject_HEAD_INIT(NULL, 0)
    .tp_name = "courtloc.localizer._fit_kernel.Field",
    .tp_doc = "Field(values, half_width_or_None, ny, nx, x0, y0, resolution): the court field's float32 grids, "
              "held (not copied) for fit()",
    .tp_basicsize = sizeof(FieldObject),
    .tp_flags = Py_TPFLAGS_DEFAULT,
    .tp_new = PyType_GenericNew,
    .tp_init = (initproc)Field_init,
    .tp_dealloc = (destructor)Field_dealloc,
};

/* ---------------------------------------------------------------- hits -> per-hit geometry */

static double as_double(PyObject *o, int *err)
{
    double v = PyFloat_AsDouble(o);
    if (v == -1.0 && PyErr_Occurred())
        *err = 1;
    return v;
}

/* hit_geometry(table f32 (H*W, 2), steps f32 (H*W), height, width, hits int16 (N, 4), cam_x, cam_y, cam_h,
 *              origin_x, origin_y, k_along, k_across, out f64 (N, 12)) -> number of rows written (hits seeing
 *              floor, in order).
 * As the ONNX graph (onnx_graph.py: pixels outside the image or NaN in the table give no point) followed by
 * projection.HitGeometry.from_points. */
static PyObject *kernel_hit_geometry(PyObject *module, PyObject *const *args, Py_ssize_t nargs)
{
    if (nargs != 13) {
        PyErr_SetString(PyExc_TypeError, "hit_geometry() takes 13 arguments");
        return NULL;
    }
    Py_buffer table, steps, hits, out;
    int err = 0;
    const Py_ssize_t height = PyLong_AsSsize_t(args[2]), width = PyLong_AsSsize_t(args[3]);
    const double cam_x = as_double(args[5], &err), cam_y = as_double(args[6], &err), h = as_double(args[7], &err);
    const double ox = as_double(args[8], &err), oy = as_double(args[9], &err);
    const double k_along = as_double(args[10], &err), k_across = as_double(args[11], &err);
    if (err || PyErr_Occurred())
        return NULL;
    if (height < 1 || width < 1) {
        PyErr_SetString(PyExc_ValueError, "hit_geometry(): empty frame");
        return NULL;
    }
    if (get_buffer(args[0], &table, "f", 2 * height * width, 0, "table") < 0)
        return NULL;
    if (get_buffer(args[1], &steps, "f", height * width, 0, "steps") < 0) {
        PyBuffer_Release(&table);
        return NULL;
    }
    if (get_buffer(args[4], &hits, "h", -1, 0, "hits") < 0) {
        PyBuffer_Release(&table);
        PyBuffer_Release(&steps);
        return NULL;
    }
    const Py_ssize_t n = hits.len / (4 * hits.itemsize);
    if (hits.len != n * 4 * hits.itemsize || get_buffer(args[12], &out, "d", n * HS, 1, "out") < 0) {
        if (!PyErr_Occurred())
            PyErr_SetString(PyExc_ValueError, "hits: expected (N, 4) int16");
        PyBuffer_Release(&table);
        PyBuffer_Release(&steps);
        PyBuffer_Release(&hits);
        return NULL;
    }
    const float *tab = table.buf, *stp = steps.buf;
    const short *hv = hits.buf;
    double *o = out.buf;
    Py_ssize_t m = 0;
    for (Py_ssize_t i = 0; i < n; i++) {
        const Py_ssize_t r = hv[4 * i], c = hv[4 * i + 1];
        if (r < 0 || r >= height || c < 0 || c >= width)
            continue;
        const double px = tab[2 * (r * width + c)], py = tab[2 * (r * width + c) + 1];
        if (!isfinite(px) || !isfinite(py))
            continue;
        double *row = o + HS * m++;
        const double relx = px - cam_x, rely = py - cam_y;
        const double rng = hypot(relx, rely);
        const double rng_safe = rng > 1e-9 ? rng : 1e-9;
        const double vx = relx / rng_safe, vy = rely / rng_safe;
        double rx = px - ox, ry = py - oy;
        double rn = hypot(rx, ry);
        rn = rn > 1e-9 ? rn : 1e-9;
        rx /= rn;
        ry /= rn;
        row[H_PX] = px;
        row[H_PX + 1] = py;
        row[H_RX] = rx;
        row[H_RX + 1] = ry;
        row[H_SIG] = (rng * rng) * k_along;
        row[H_SIG + 1] = rng * k_across;
        row[H_VX] = vx;
        row[H_VX + 1] = vy;
        row[H_RANGE] = rng;
        row[H_DEP] = atan2(h, rng);
        double t = vy / (vx > 1e-3 ? vx : 1e-3);
        row[H_TAN] = t < -3.0 ? -3.0 : (t > 3.0 ? 3.0 : t);
        const double step = stp[r * width + c];
        row[H_STEP] = isfinite(step) ? step : 0.0;
    }
    PyBuffer_Release(&table);
    PyBuffer_Release(&steps);
    PyBuffer_Release(&hits);
    PyBuffer_Release(&out);
    return PyLong_FromSsize_t(m);
}

/* ---------------------------------------------------------------- the fit */

typedef struct {
    Py_ssize_t n;
    const double *h; /* packed hits (N, HS) */
    double cam_x, cam_y, cam_h;
    /* per-frame terms (fit.py _FrameTerms) */
    double *sig_al, *sig_ac, *floor2, *dpd, *tan0;
    double *scratch;  /* 6 N: grid positions of one evaluation */
    double *weighted; /* 7 N: weights and weighted Jacobian rows */
} Frame;

typedef struct {
    double pixel_sigma, floor_sigma, range_sigma, prior, tukey_c, huber_c, max_res, gate_cos, step_tol,
        inlier_sigmas;
    long huber_iterations, max_iterations;
    int tilt;
    int n_knots; /* band bias (band_bias.py): expected offset in steps at band widths in steps; 0: off */
    double knot_w[MAX_KNOTS], knot_v[MAX_KNOTS];
    double thin_half_width; /* bands at least twice this wide have no band bias */
} Config;

/* numpy.interp(w, knot_w, knot_v): clamped at both ends, linear between knots */
static double band_offset(const Config *cfg, double w)
{
    const int k = cfg->n_knots;
    if (!(w > cfg->knot_w[0]))
        return cfg->knot_v[0];
    if (w >= cfg->knot_w[k - 1])
        return cfg->knot_v[k - 1];
    int a = 0;
    while (w >= cfg->knot_w[a + 1])
        a++;
    const double slope = (cfg->knot_v[a + 1] - cfg->knot_v[a]) / (cfg->knot_w[a + 1] - cfg->knot_w[a]);
    return slope * (w - cfg->knot_w[a]) + cfg->knot_v[a];
}

/* Python's (numpy's) floor-division remainder: the result has the sign of b. */
static double py_mod(double a, double b)
{
    double m = fmod(a, b);
    if (m != 0.0) {
        if ((b < 0) != (m < 0))
            m += b;
    } else {
        m = copysign(0.0, b);
    }
    return m;
}

/* Residuals of one pose (fit.py _residuals for one start): d (N), Jacobian rows and z (6 x N), usable (N). */
static void residuals(const FieldObject *f, const Frame *fr, const double *p, int use_tilt, double *d_out,
                      double *j, unsigned char *usable, const Config *cfg)
{
    const Py_ssize_t n = fr->n, nx = f->nx, ny = f->ny;
    const double *hh = fr->h;
    const float *grid = (const float *)f->values.buf;
    const float *half = f->has_half ? (const float *)f->half.buf : NULL;
    const double inv_res = 1.0 / f->res;
    const double c = cos(p[2]), s = sin(p[2]);
    const double rr = c * inv_res, ri = s * inv_res; /* rot * inv_res */
    const double ox = (p[0] - f->x0) * inv_res, oy = (p[1] - f->y0) * inv_res;
    const double fx_max = (double)nx - 1.001, fy_max = (double)ny - 1.001;
    double *sc_rg = fr->scratch, *sc_t = fr->scratch + 2 * n, *sc_dpd = fr->scratch + 4 * n;
    Py_ssize_t *sc_cell = (Py_ssize_t *)(fr->scratch + 5 * n);
    /* Pass 1: where each hit falls on the grid, its cache lines requested ahead of pass 2 (the field is
     * ~7 MB: the loads then overlap instead of waiting one after another). */
    for (Py_ssize_t i = 0; i < n; i++) {
        const double *hi = hh + HS * i;
        double lx, ly, dpd;
        if (use_tilt) {
            const double delta = p[3] + p[4] * hi[H_TAN];
            double dep = (hi[H_DEP] + p[3]) + p[4] * hi[H_TAN], cot;
            if (dep >= 1e-3 && fabs(delta) < 0.01) {
                /* tan(dep0 + delta) by the addition formula, tan(delta) by its series (error < delta^9 / 40,
                 * below an ulp here): no tan call per hit and evaluation, only one per hit and frame */
                const double d2 = delta * delta;
                const double td = delta * (1.0 + d2 * (1.0 / 3.0 + d2 * (2.0 / 15.0 + d2 * (17.0 / 315.0))));
                cot = (1.0 - fr->tan0[i] * td) / (fr->tan0[i] + td);
            } else {
                if (!(dep >= 1e-3))
                    dep = 1e-3;
                cot = 1.0 / tan(dep);
            }
            const double r = fr->cam_h * cot;
            lx = fr->cam_x + hi[H_VX] * r;
            ly = fr->cam_y + hi[H_VX + 1] * r;
            dpd = -fr->cam_h * (1.0 + cot * cot);
        } else {
            lx = hi[H_PX];
            ly = hi[H_PX + 1];
            dpd = fr->dpd[i];
        }
        const double rgx = lx * rr - ly * ri, rgy = lx * ri + ly * rr;
        double fx = rgx + ox, fy = rgy + oy;
        /* court_field.lookup_grid: clamped to the grid (NaN to 0, so memory stays in bounds) */
        if (!(fx > 0.0))
            fx = 0.0;
        if (fx > fx_max)
            fx = fx_max;
        if (!(fy > 0.0))
            fy = 0.0;
        if (fy > fy_max)
            fy = fy_max;
        const Py_ssize_t ix = (Py_ssize_t)fx, iy = (Py_ssize_t)fy;
        const Py_ssize_t cell = iy * nx + ix;
        PREFETCH(grid + cell);
        PREFETCH(grid + cell + nx + 1);
        sc_rg[2 * i] = rgx;
        sc_rg[2 * i + 1] = rgy;
        sc_t[2 * i] = fx - (double)ix;
        sc_t[2 * i + 1] = fy - (double)iy;
        sc_dpd[i] = dpd;
        sc_cell[i] = cell;
    }
    /* Pass 2: bilinear value with its exact gradient, the error model and the Jacobian rows. */
    for (Py_ssize_t i = 0; i < n; i++) {
        const double *hi = hh + HS * i;
        const double rgx = sc_rg[2 * i], rgy = sc_rg[2 * i + 1], tx = sc_t[2 * i], ty = sc_t[2 * i + 1];
        const Py_ssize_t cell = sc_cell[i];
        const float v00 = grid[cell], v01 = grid[cell + 1], v10 = grid[cell + nx], v11 = grid[cell + nx + 1];
        const float dx_top = v01 - v00, dx_bot = v11 - v10, dx_diff = dx_bot - dx_top; /* float32, as numpy */
        const double upper = (double)v00 + (double)dx_top * tx;
        const double lower = (double)v10 + (double)dx_bot * tx;
        double gy = lower - upper;
        double d = upper + gy * ty;
        double gx = (double)dx_top + (double)dx_diff * ty;
        const double inv_norm = 1.0 / (sqrt(gx * gx + gy * gy) + 1e-12);
        const double nxv = gx * inv_norm, nyv = gy * inv_norm;
        const double vx0 = hi[H_VX], vy0 = hi[H_VX + 1];
        const double vx = vx0 * c - vy0 * s, vy = vx0 * s + vy0 * c;
        /* the edge normal against the view direction splits the pixel error into along / across parts */
        const double q_along = nxv * vx + nyv * vy;
        const double q_across = nyv * vx - nxv * vy;
        const double a = q_along * fr->sig_al[i], b = q_across * fr->sig_ac[i];
        double sig2 = a * a + b * b;
        sig2 += fr->floor2[i];
        const double inv = 1.0 / sqrt(sig2);
        const double rx0 = hi[H_RX], ry0 = hi[H_RX + 1];
        const double ray_cos = nxv * (rx0 * c - ry0 * s) + nyv * (rx0 * s + ry0 * c);
        const int inside = d < 0;
        const Py_ssize_t near = cell + (tx >= 0.5) + (ty >= 0.5) * nx;
        if (half != NULL && inside && ray_cos < 0) {
            /* the band's far edge: (2 * half-width - depth) further along, gradient flipped */
            d = -d - 2.0 * (double)half[near];
            gx = -gx;
            gy = -gy;
        }
        if (half != NULL && cfg->n_knots > 0) {
            /* a band under a few scan steps wide puts its hits further out (band_bias.py) */
            const double hw = (double)half[near], step = hi[H_STEP];
            if (hw > 0.0 && hw < cfg->thin_half_width && step > 0.0) {
                const double s_n = step * fabs(ray_cos);
                d -= band_offset(cfg, 2.0 * hw / (s_n > 1e-9 ? s_n : 1e-9)) * s_n;
            }
        }
        usable[i] = (inside || ray_cos >= cfg->gate_cos) && fabs(d) < cfg->max_res;
        const double inv_m = inv * inv_res;
        const double along = ((gx * vx + gy * vy) * sc_dpd[i]) * inv_m;
        j[i] = gx * inv_m;
        j[n + i] = gy * inv_m;
        j[2 * n + i] = (gy * rgx - gx * rgy) * inv;
        j[3 * n + i] = along;
        j[4 * n + i] = along * hi[H_TAN];
        j[5 * n + i] = d * inv;
        d_out[i] = d;
    }
}

/* numpy's pairwise summation (np.sum / np.mean along a contiguous axis), for the same rounding. */
static double pairwise_sum(const double *a, Py_ssize_t n)
{
    if (n < 8) {
        double res = 0.0;
        for (Py_ssize_t i = 0; i < n; i++)
            res += a[i];
        return res;
    }
    if (n <= 128) {
        double r[8];
        Py_ssize_t i;
        for (int k = 0; k < 8; k++)
            r[k] = a[k];
        for (i = 8; i < n - (n % 8); i += 8)
            for (int k = 0; k < 8; k++)
                r[k] += a[i + k];
        double res = ((r[0] + r[1]) + (r[2] + r[3])) + ((r[4] + r[5]) + (r[6] + r[7]));
        for (; i < n; i++)
            res += a[i];
        return res;
    }
    Py_ssize_t n2 = n / 2;
    n2 -= n2 % 8;
    return pairwise_sum(a, n2) + pairwise_sum(a + n2, n - n2);
}

static double dot(const double *a, const double *b, Py_ssize_t n)
{
    double s0 = 0.0, s1 = 0.0, s2 = 0.0, s3 = 0.0;
    Py_ssize_t i = 0;
    for (; i + 4 <= n; i += 4) {
        s0 += a[i] * b[i];
        s1 += a[i + 1] * b[i + 1];
        s2 += a[i + 2] * b[i + 2];
        s3 += a[i + 3] * b[i + 3];
    }
    for (; i < n; i++)
        s0 += a[i] * b[i];
    return (s0 + s1) + (s2 + s3);
}

/* m[a][b] = sum_i (J[rows[a], i] * w[i]) * J[rows[b], i] for a, b < nr: numpy's (J * w) @ J.T, the same
 * products summed in another order. wj: nr * n scratch. */
static void normal_matrix(const double *j, const double *w, const int *rows, int nr, Py_ssize_t n, double *wj,
                          double m[6][6])
{
    for (int a = 0; a < nr; a++) {
        const double *ja = j + rows[a] * n;
        double *out = wj + a * n;
        for (Py_ssize_t i = 0; i < n; i++)
            out[i] = ja[i] * w[i];
    }
    for (int a = 0; a < nr; a++)
        for (int b = a; b < nr; b++)
            m[a][b] = m[b][a] = dot(wj + a * n, j + rows[b] * n, n);
}

/* LU with partial pivoting (k <= 5); returns 0 when a pivot is exactly zero (numpy: LinAlgError). */
static int lu(double *a, int k, int *piv)
{
    for (int col = 0; col < k; col++) {
        int p = col;
        for (int r = col + 1; r < k; r++)
            if (fabs(a[r * k + col]) > fabs(a[p * k + col]))
                p = r;
        piv[col] = p;
        if (a[p * k + col] == 0.0)
            return 0;
        if (p != col)
            for (int q = 0; q < k; q++) {
                double t = a[col * k + q];
                a[col * k + q] = a[p * k + q];
                a[p * k + q] = t;
            }
        for (int r = col + 1; r < k; r++) {
            const double m = a[r * k + col] / a[col * k + col];
            a[r * k + col] = m;
            for (int q = col + 1; q < k; q++)
                a[r * k + q] -= m * a[col * k + q];
        }
    }
    return 1;
}

static void lu_solve(const double *a, int k, const int *piv, double *b)
{
    for (int col = 0; col < k; col++) {
        if (piv[col] != col) {
            double t = b[col];
            b[col] = b[piv[col]];
            b[piv[col]] = t;
        }
    }
    for (int r = 0; r < k; r++)
        for (int q = 0; q < r; q++)
            b[r] -= a[r * k + q] * b[q];
    for (int r = k - 1; r >= 0; r--) {
        for (int q = r + 1; q < k; q++)
            b[r] -= a[r * k + q] * b[q];
        b[r] /= a[r * k + r];
    }
}

/* fit(field, hits f64 (N, 12), cam_x, cam_y, cam_h, starts f64 (S, 3), out f64 (S, 20), config 16-tuple)
 * -> None: every start refined as fit.fit_poses does, results written into out (layout: fit_kernel.py). */
static PyObject *kernel_fit(PyObject *module, PyObject *const *args, Py_ssize_t nargs)
{
    if (nargs != 8) {
        PyErr_SetString(PyExc_TypeError, "fit() takes 8 arguments");
        return NULL;
    }
    if (!PyObject_TypeCheck(args[0], &FieldType) || !((FieldObject *)args[0])->has_values) {
        PyErr_SetString(PyExc_TypeError, "fit(): the first argument must be an initialised Field");
        return NULL;
    }
    const FieldObject *field = (const FieldObject *)args[0];
    Py_buffer bufs[3];
    int nbuf = 0;
    PyObject *result = NULL;
    double *work = NULL;
    Frame fr;
    Config cfg;
    int err = 0;

    PyObject *ct = args[7];
    if (!PyTuple_Check(ct) || PyTuple_GET_SIZE(ct) != 16) {
        PyErr_SetString(PyExc_TypeError, "fit(): config must be a 16-tuple");
        return NULL;
    }
    cfg.thin_half_width = as_double(PyTuple_GET_ITEM(ct, 15), &err);
    PyObject *kw = PyTuple_GET_ITEM(ct, 13), *kv = PyTuple_GET_ITEM(ct, 14);
    if (!PyTuple_Check(kw) || !PyTuple_Check(kv) || PyTuple_GET_SIZE(kw) != PyTuple_GET_SIZE(kv)
        || PyTuple_GET_SIZE(kw) > MAX_KNOTS || PyTuple_GET_SIZE(kw) == 1) {
        PyErr_SetString(PyExc_ValueError, "fit(): band-bias knots must be two tuples of equal length, 0 or 2..16");
        return NULL;
    }
    cfg.n_knots = (int)PyTuple_GET_SIZE(kw);
    for (int a = 0; a < cfg.n_knots; a++) {
        cfg.knot_w[a] = as_double(PyTuple_GET_ITEM(kw, a), &err);
        cfg.knot_v[a] = as_double(PyTuple_GET_ITEM(kv, a), &err);
        if (a > 0 && !(cfg.knot_w[a] > cfg.knot_w[a - 1])) {
            PyErr_SetString(PyExc_ValueError, "fit(): band-bias widths must increase");
            return NULL;
        }
    }
    cfg.pixel_sigma = as_double(PyTuple_GET_ITEM(ct, 0), &err);
    cfg.floor_sigma = as_double(PyTuple_GET_ITEM(ct, 1), &err);
    cfg.range_sigma = as_double(PyTuple_GET_ITEM(ct, 2), &err);
    cfg.prior = as_double(PyTuple_GET_ITEM(ct, 3), &err);
    cfg.tukey_c = as_double(PyTuple_GET_ITEM(ct, 4), &err);
    cfg.huber_c = as_double(PyTuple_GET_ITEM(ct, 5), &err);
    cfg.huber_iterations = PyLong_AsLong(PyTuple_GET_ITEM(ct, 6));
    cfg.max_iterations = PyLong_AsLong(PyTuple_GET_ITEM(ct, 7));
    cfg.max_res = as_double(PyTuple_GET_ITEM(ct, 8), &err);
    cfg.gate_cos = as_double(PyTuple_GET_ITEM(ct, 9), &err);
    cfg.step_tol = as_double(PyTuple_GET_ITEM(ct, 10), &err);
    cfg.inlier_sigmas = as_double(PyTuple_GET_ITEM(ct, 11), &err);
    cfg.tilt = PyObject_IsTrue(PyTuple_GET_ITEM(ct, 12));
    fr.cam_x = as_double(args[2], &err);
    fr.cam_y = as_double(args[3], &err);
    fr.cam_h = as_double(args[4], &err);
    if (err || PyErr_Occurred() || cfg.tilt < 0)
        return NULL;

    if (get_buffer(args[1], &bufs[0], "d", -1, 0, "hits") < 0)
        return NULL;
    nbuf = 1;
    const Py_ssize_t n = bufs[0].len / (8 * HS);
    if (bufs[0].len != n * 8 * HS) {
        PyErr_SetString(PyExc_ValueError, "hits: expected (N, 12) float64");
        goto done;
    }
    fr.n = n;
    fr.h = bufs[0].buf;
    if (get_buffer(args[5], &bufs[1], "d", -1, 0, "starts") < 0)
        goto done;
    nbuf++;
    const Py_ssize_t n_starts = bufs[1].len / 24;
    if (bufs[1].len != n_starts * 24) {
        PyErr_SetString(PyExc_ValueError, "starts: expected (S, 3) float64");
        goto done;
    }
    const double *starts = bufs[1].buf;
    if (get_buffer(args[6], &bufs[2], "d", n_starts * NOUT, 1, "out") < 0)
        goto done;
    nbuf++;
    double *out = bufs[2].buf;
    if (n < 3 || n_starts < 1 || cfg.max_iterations < 1) {
        PyErr_SetString(PyExc_ValueError, "fit(): needs >= 3 hits, >= 1 start and >= 1 iteration");
        goto done;
    }

    /* workspace: frame terms 5N, scratch 6N, weighted 7N; per start params 5 + d N + rows 6N; then flags */
    const Py_ssize_t per_start = 7 * n + 5;
    work = malloc(sizeof(double) * (18 * n + n_starts * per_start) + (size_t)n_starts * (n + 1));
    if (work == NULL) {
        PyErr_NoMemory();
        goto done;
    }
    fr.sig_al = work;
    fr.sig_ac = work + n;
    fr.floor2 = work + 2 * n;
    fr.dpd = work + 3 * n;
    fr.tan0 = work + 4 * n;
    fr.scratch = work + 5 * n;
    fr.weighted = work + 11 * n;
    double *sdata = work + 18 * n;
    unsigned char *flags = (unsigned char *)(sdata + n_starts * per_start);
    unsigned char *done_flag = flags + n_starts * n;
    /* From here to the results only plain memory is touched: other Python threads may run meanwhile. */
    Py_BEGIN_ALLOW_THREADS
    for (Py_ssize_t i = 0; i < n; i++) {
        const double *hi = fr.h + HS * i;
        fr.sig_al[i] = hi[H_SIG] * cfg.pixel_sigma;
        fr.sig_ac[i] = hi[H_SIG + 1] * cfg.pixel_sigma;
        const double fl = cfg.range_sigma != 0.0 ? cfg.floor_sigma + cfg.range_sigma * hi[H_RANGE] : cfg.floor_sigma;
        fr.floor2[i] = fl * fl;
        const double sd = sin(hi[H_DEP]);
        fr.dpd[i] = -fr.cam_h / (sd * sd); /* d(point) / d(depression) at zero tilt */
        fr.tan0[i] = tan(hi[H_DEP]);
    }
#define P(s) (sdata + (s) * per_start)
#define D(s) (sdata + (s) * per_start + 5)
#define J(s) (sdata + (s) * per_start + 5 + n)
#define U(s) (flags + (s) * n)
    for (Py_ssize_t s = 0; s < n_starts; s++) {
        double *p = P(s);
        p[0] = starts[3 * s];
        p[1] = starts[3 * s + 1];
        p[2] = starts[3 * s + 2];
        p[3] = p[4] = 0.0;
        done_flag[s] = 0;
    }
    const int k = cfg.tilt ? 5 : 3;
    int rows[6];
    for (int a = 0; a < k; a++)
        rows[a] = a;
    rows[k] = 5; /* z: the normal matrix's last column is the gradient */
    const double prior[5] = {0, 0, 0, cfg.tilt ? cfg.prior : 0.0, cfg.tilt ? cfg.prior : 0.0};
    for (long it = 0; it <= cfg.max_iterations; it++) {
        int all_done = 1, any_tilt = 0;
        for (Py_ssize_t s = 0; s < n_starts; s++) {
            all_done &= done_flag[s];
            any_tilt |= P(s)[3] != 0.0 || P(s)[4] != 0.0;
        }
        /* numpy evaluates every start with the tilted model once any start has a tilt: the same here */
        const int final = all_done || it == cfg.max_iterations;
        for (Py_ssize_t s = 0; s < n_starts; s++)
            if (final || !done_flag[s]) /* a finished start's residuals are only needed at the end */
                residuals(field, &fr, P(s), cfg.tilt && any_tilt, D(s), J(s), U(s), &cfg);
        if (final)
            break;
        for (Py_ssize_t s = 0; s < n_starts; s++) {
            double *p = P(s);
            double step[5] = {0, 0, 0, 0, 0};
            if (!done_flag[s]) {
                const double *j = J(s), *z = j + 5 * n;
                const unsigned char *u = U(s);
                double *w = fr.weighted, m[6][6];
                for (Py_ssize_t i = 0; i < n; i++) {
                    if (it < cfg.huber_iterations) {
                        double az = fabs(z[i]);
                        if (!(az >= 1e-9))
                            az = 1e-9;
                        const double wi = cfg.huber_c / az;
                        w[i] = wi <= 1.0 ? wi : 1.0;
                    } else {
                        const double q = z[i] / cfg.tukey_c;
                        double v = 1.0 - q * q;
                        if (!(v >= 0.0))
                            v = 0.0;
                        w[i] = v * v;
                    }
                    w[i] *= u[i];
                }
                normal_matrix(j, w, rows, k + 1, n, fr.weighted + n, m);
                double h[25], g[5];
                int piv[5];
                for (int a = 0; a < k; a++) {
                    for (int b = 0; b < k; b++)
                        h[a * k + b] = m[a][b] + (a == b ? prior[a] : 0.0);
                    g[a] = m[a][k] + prior[a] * p[a];
                }
                if (h[0] + h[k + 1] <= 0.0) {
                    done_flag[s] = 1;
                } else {
                    /* tiny damping keeps a degenerate (parallel lines only) system solvable */
                    const double damp = 1e-6 * (h[0] + h[k + 1] + h[2 * k + 2]) + 1e-12;
                    for (int a = 0; a < k; a++)
                        h[a * k + a] += damp;
                    if (lu(h, k, piv)) {
                        lu_solve(h, k, piv, g);
                        for (int a = 0; a < k; a++)
                            step[a] = -g[a];
                    } else {
                        done_flag[s] = 1;
                    }
                }
            }
            for (int a = 0; a < k; a++)
                p[a] += step[a];
            p[2] = py_mod(p[2] + PI, 2.0 * PI) - PI; /* numpy wraps every start, finished ones too */
            if (hypot(step[0], step[1]) < cfg.step_tol && fabs(step[2]) < cfg.step_tol / 5.0)
                done_flag[s] = 1;
        }
    }
    /* quality numbers at the final poses */
    const double c = cfg.tukey_c, full_loss = c * c / 6.0;
    double *scratch = fr.weighted, *inl = fr.weighted + n;
    for (Py_ssize_t s = 0; s < n_starts; s++) {
        const double *p = P(s), *d = D(s), *j = J(s), *z = j + 5 * n;
        const unsigned char *u = U(s);
        double *o = out + s * NOUT;
        Py_ssize_t n_in = 0;
        for (Py_ssize_t i = 0; i < n; i++) {
            inl[i] = (double)(u[i] && fabs(z[i]) < cfg.inlier_sigmas);
            n_in += inl[i] != 0.0;
            if (u[i]) {
                const double q = z[i] / c;
                double v = 1.0 - q * q;
                if (!(v >= 0.0))
                    v = 0.0;
                scratch[i] = (c * c / 6.0) * (1.0 - v * v * v); /* numpy: pow(v, 3), equal to an ulp */
            } else {
                scratch[i] = full_loss;
            }
        }
        const double cost = pairwise_sum(scratch, n) / (double)n;
        for (Py_ssize_t i = 0; i < n; i++)
            scratch[i] = (d[i] * d[i]) * inl[i];
        const double rms = sqrt(pairwise_sum(scratch, n) / (double)(n_in > 1 ? n_in : 1));
        /* covariance from the inliers' normal matrix at unit weight, tilt marginalised (the inverse's
         * pose block) */
        double hh[25], inv[25], mm[6][6];
        static const int seq[6] = {0, 1, 2, 3, 4, 5};
        normal_matrix(j, inl, seq, k, n, fr.weighted + 2 * n, mm);
        for (int a = 0; a < k; a++)
            for (int b = 0; b < k; b++)
                hh[a * k + b] = a == b ? mm[a][b] + (prior[a] + 1e-12) : mm[a][b];
        int piv[5];
        const int ok = lu(hh, k, piv);
        if (ok) {
            for (int col = 0; col < k; col++) {
                double e[5] = {0, 0, 0, 0, 0};
                e[col] = 1.0;
                lu_solve(hh, k, piv, e);
                for (int r = 0; r < k; r++)
                    inv[r * k + col] = e[r];
            }
            const double a = inv[0], b = inv[1], cc = inv[k + 1];
            const double disc = 0.25 * ((a - cc) * (a - cc)) + b * b;
            const double worst = 0.5 * (a + cc) + sqrt(disc > 0.0 ? disc : 0.0); /* larger 2x2 eigenvalue */
            o[8] = sqrt(worst > 0.0 ? worst : 0.0);
            o[9] = sqrt(inv[2 * k + 2] > 0.0 ? inv[2 * k + 2] : 0.0);
            for (int r = 0; r < 3; r++)
                for (int q = 0; q < 3; q++)
                    o[10 + 3 * r + q] = inv[r * k + q];
        } else {
            o[8] = o[9] = HUGE_VAL;
            for (int r = 0; r < 9; r++)
                o[10 + r] = 0.0;
        }
        for (int a = 0; a < 5; a++)
            o[a] = p[a];
        o[5] = cost;
        o[6] = (double)n_in;
        o[7] = n_in ? rms : HUGE_VAL;
        o[19] = ok;
    }
    Py_END_ALLOW_THREADS
    result = Py_None;
    Py_INCREF(result);
#undef P
#undef D
#undef J
#undef U
done:
    free(work);
    for (int b = 0; b < nbuf; b++)
        PyBuffer_Release(&bufs[b]);
    return result;
}

static PyMethodDef methods[] = {
    {"fit", (PyCFunction)(void (*)(void))kernel_fit, METH_FASTCALL,
     "fit(field, hits, cam_x, cam_y, cam_h, starts, out, config): the whole robust fit of every start; "
     "results written into out (S, 20)"},
    {"hit_geometry", (PyCFunction)(void (*)(void))kernel_hit_geometry, METH_FASTCALL,
     "hit_geometry(table, steps, height, width, hits, cam_x, cam_y, cam_h, origin_x, origin_y, k_along, k_across, "
     "out) "
     "-> rows written: hits -> floor points -> the fit's packed per-hit geometry"},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module_def = {
    PyModuleDef_HEAD_INIT, "_fit_kernel", "Compiled per-frame path of the geometric localizer (see fit_kernel.py).",
    -1, methods,
};

PyMODINIT_FUNC PyInit__fit_kernel(void)
{
    if (PyType_Ready(&FieldType) < 0)
        return NULL;
    PyObject *m = PyModule_Create(&module_def);
    if (m == NULL)
        return NULL;
    if (PyModule_AddObjectRef(m, "Field", (PyObject *)&FieldType) < 0) {
        Py_DECREF(m);
        return NULL;
    }
    return m;
}
