/* Compiled cost volume of the global search (module courtloc.localizer._search_kernel).
 *
 * search.CoarseSearch.costs sums, for every yaw step and every selected hit, a shifted window of the padded
 * coarse distance field into that yaw's (rows, cols) slab of translations. The numpy twin in search.py does one
 * array add per (yaw, hit): ~3,600 Python-level adds a frame, 10-14 ms here, which made a searching frame of
 * the infer stage longer than a 30 fps frame interval. This loop does the same float32 additions in the same
 * order per output cell (hits in the order given), so the two results are bit-identical
 * (tests/test_localizer_search_kernel.py); a compiler may vectorise across the cells of a row, which does not
 * reorder any cell's sum.
 *
 * Pure C99 + the CPython C API and buffer protocol (no numpy headers); single-threaded.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>

#include <string.h>

#define BLOCK 16 /* cells summed in registers at a time: four SSE / NEON vectors */

static int get_buffer(PyObject *obj, Py_buffer *view, const char *fmt, Py_ssize_t count, int writable,
                      const char *name)
{
    if (PyObject_GetBuffer(obj, view, PyBUF_C_CONTIGUOUS | PyBUF_FORMAT | (writable ? PyBUF_WRITABLE : 0)) < 0)
        return -1;
    if (view->format == NULL || strcmp(view->format, fmt) != 0 || (count >= 0 && view->len != count * view->itemsize)) {
        PyErr_Format(PyExc_ValueError, "%s: expected %zd C-contiguous items of format '%s'", name, count, fmt);
        PyBuffer_Release(view);
        return -1;
    }
    return 0;
}

/* out[k] += each hit's window, for every yaw k (accumulate() checked the windows lie inside the field). */
static void sum_windows(const float *v, Py_ssize_t nx, const int *ox, const int *oy, Py_ssize_t n_yaw,
                        Py_ssize_t n_pts, Py_ssize_t i0, Py_ssize_t j0, Py_ssize_t h, Py_ssize_t w, float *o)
{
    /* A block of BLOCK cells of one row at a time, every hit into it: the block's sums stay in registers
     * while the hits' windows stream past (adding each window into the whole slab, as numpy does, loads and
     * stores every sum once per hit: 1.5x slower here). Each cell still adds the hits in their order. What is
     * left is reading the windows from the L2 cache (~170 MB a frame at 60 yaws x 60 hits; AVX2 gained nothing). */
    for (Py_ssize_t k = 0; k < n_yaw; k++) {
        const int *kx = ox + k * n_pts, *ky = oy + k * n_pts;
        for (Py_ssize_t i = 0; i < h; i++) {
            float *row = o + (k * h + i) * w;
            const float *base = v + (i0 + i) * nx + j0;
            Py_ssize_t j = 0;
            for (; j + BLOCK <= w; j += BLOCK) {
                float acc[BLOCK];
                memcpy(acc, row + j, sizeof acc);
                for (Py_ssize_t p = 0; p < n_pts; p++) {
                    const float *s = base + ky[p] * nx + kx[p] + j;
                    for (int b = 0; b < BLOCK; b++)
                        acc[b] += s[b];
                }
                memcpy(row + j, acc, sizeof acc);
            }
            for (; j < w; j++) {
                float acc = row[j];
                for (Py_ssize_t p = 0; p < n_pts; p++)
                    acc += base[ky[p] * nx + kx[p] + j];
                row[j] = acc;
            }
        }
    }
}

/* accumulate(values, ny, nx, dx, dy, n_yaw, n_pts, i0, i1, j0, j1, out):
 *   out[k, i - i0, j - j0] += values[i + dy[k, p], j + dx[k, p]] for every yaw k and hit p, i in [i0, i1),
 *   j in [j0, j1); values float32 (ny, nx), dx/dy int32 (n_yaw, n_pts), out float32 (n_yaw, i1 - i0, j1 - j0). */
static PyObject *kernel_accumulate(PyObject *module, PyObject *const *args, Py_ssize_t nargs)
{
    (void)module;
    if (nargs != 12) {
        PyErr_SetString(PyExc_TypeError, "accumulate() takes 12 arguments");
        return NULL;
    }
    Py_ssize_t ny, nx, n_yaw, n_pts, i0, i1, j0, j1;
    Py_ssize_t *ints[8] = {&ny, &nx, &n_yaw, &n_pts, &i0, &i1, &j0, &j1};
    const int at[8] = {1, 2, 5, 6, 7, 8, 9, 10};
    for (int k = 0; k < 8; k++) {
        *ints[k] = PyLong_AsSsize_t(args[at[k]]);
        if (*ints[k] == -1 && PyErr_Occurred())
            return NULL;
    }
    if (ny <= 0 || nx <= 0 || n_yaw < 0 || n_pts < 0 || i0 < 0 || j0 < 0 || i1 <= i0 || j1 <= j0) {
        PyErr_SetString(PyExc_ValueError, "accumulate(): empty or negative extents");
        return NULL;
    }
    const Py_ssize_t h = i1 - i0, w = j1 - j0;
    Py_buffer values, dx, dy, out;
    if (get_buffer(args[0], &values, "f", ny * nx, 0, "values") < 0)
        return NULL;
    if (get_buffer(args[3], &dx, "i", n_yaw * n_pts, 0, "dx") < 0) {
        PyBuffer_Release(&values);
        return NULL;
    }
    if (get_buffer(args[4], &dy, "i", n_yaw * n_pts, 0, "dy") < 0) {
        PyBuffer_Release(&values);
        PyBuffer_Release(&dx);
        return NULL;
    }
    if (get_buffer(args[11], &out, "f", n_yaw * h * w, 1, "out") < 0) {
        PyBuffer_Release(&values);
        PyBuffer_Release(&dx);
        PyBuffer_Release(&dy);
        return NULL;
    }
    const float *v = (const float *)values.buf;
    const int *ox = (const int *)dx.buf, *oy = (const int *)dy.buf;
    float *o = (float *)out.buf;
    int bad = 0;
    /* Every window must lie inside the field (numpy would fail on a short slice; here it would read outside). */
    for (Py_ssize_t q = 0; q < n_yaw * n_pts; q++) {
        if (i0 + oy[q] < 0 || i1 + oy[q] > ny || j0 + ox[q] < 0 || j1 + ox[q] > nx) {
            bad = 1;
            break;
        }
    }
    if (!bad) {
        Py_BEGIN_ALLOW_THREADS
        sum_windows(v, nx, ox, oy, n_yaw, n_pts, i0, j0, h, w, o);
        Py_END_ALLOW_THREADS
    }
    PyBuffer_Release(&values);
    PyBuffer_Release(&dx);
    PyBuffer_Release(&dy);
    PyBuffer_Release(&out);
    if (bad) {
        PyErr_SetString(PyExc_ValueError, "accumulate(): a hit's window lies outside the padded field");
        return NULL;
    }
    Py_RETURN_NONE;
}

static PyMethodDef methods[] = {
    {"accumulate", (PyCFunction)(void (*)(void))kernel_accumulate, METH_FASTCALL,
     "accumulate(values, ny, nx, dx, dy, n_yaw, n_pts, i0, i1, j0, j1, out): out[k] += the field's window at "
     "each hit's offset, for every yaw k"},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module_def = {
    PyModuleDef_HEAD_INIT, "_search_kernel", "Compiled cost volume of the global pose search (see search.py).",
    -1, methods, NULL, NULL, NULL, NULL,
};

PyMODINIT_FUNC PyInit__search_kernel(void)
{
    return PyModule_Create(&module_def);
}
