/* The radial scan's per-frame loop in C: white test of every ray pixel, then the neighbour comparison.
 *
 * Why C: the numpy path spends most of its time in per-call overhead and in gathers that numpy does one
 * element at a time; here the whole frame is two loops with no allocation. The white test is a lookup in
 * a bit table over all 2^24 BGR colours that Python builds with OpenCV itself (white_lut.py), so this file
 * holds no colour arithmetic and cannot disagree with cv2.cvtColor + cv2.inRange.
 *
 * Buffers come through the buffer protocol (numpy arrays, bytes), so building needs only Python's headers.
 * Every index is bounds-checked: a bad table raises ValueError instead of reading outside a buffer.
 * The GIL is released for the loops, so Zenoh's callback thread keeps running meanwhile.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <stdint.h>

#define LUT_BYTES ((Py_ssize_t)1 << 21) /* 2^24 colours, one bit each */

static int check_sizes(const Py_buffer *offsets, const Py_buffer *sample_pixel, const Py_buffer *has_pred,
                       const Py_buffer *lut, const Py_buffer *white, const Py_buffer *bright, const Py_buffer *out) {
    if (offsets->len % 4 || sample_pixel->len % 4) {
        PyErr_SetString(PyExc_ValueError, "pixel_offsets and sample_pixel must be int32 arrays");
        return -1;
    }
    Py_ssize_t n_pixels = offsets->len / 4, n_samples = sample_pixel->len / 4;
    if (lut->len != LUT_BYTES) {
        PyErr_Format(PyExc_ValueError, "white table has %zd bytes, expected %zd", lut->len, LUT_BYTES);
        return -1;
    }
    if (white->len < n_pixels || bright->len < n_pixels || has_pred->len < n_samples || out->len < 4 * n_samples) {
        PyErr_SetString(PyExc_ValueError, "scratch or output buffer too small for the ray table");
        return -1;
    }
    return 0;
}

/* The darkest brightness of sample s and the span - 1 samples after it on the same ray. */
static int lowest_after(const uint8_t *bright, const int32_t *sample, const uint8_t *pred, Py_ssize_t s,
                        Py_ssize_t n_samples, Py_ssize_t n_pixels, int span, int *lowest) {
    int low = bright[sample[s]];
    for (Py_ssize_t k = s + 1; k < s + span && k < n_samples && pred[k]; ++k) {
        int32_t r = sample[k];
        if (r < 0 || r >= n_pixels) return -1;
        if (bright[r] < low) low = bright[r];
    }
    *lowest = low;
    return 0;
}

/* scan_hits(frame, pixel_offsets, sample_pixel, has_pred, lut, white_scratch, bright_scratch, out,
 *           min_drop, span) -> n
 *   frame: uint8 BGR bytes; pixel_offsets: int32 byte offset of each ray pixel (raster order);
 *   sample_pixel: int32 index into pixel_offsets of each sample (ray then d order);
 *   has_pred: uint8, 1 where the sample's predecessor is on the same ray; lut: the 2 MiB bit table;
 *   white_scratch, bright_scratch: writable uint8, >= number of pixels; out: writable int32, >= samples;
 *   min_drop (0..255): a hit also needs the previous sample's brightness (HSV V = max(B, G, R)) to exceed
 *   the darkest of this sample and the span - 1 after it on the ray by at least this much (0: off).
 * Writes the indices of the hit samples (previous sample white, this one not) to out, returns how many.
 */
static PyObject *scan_hits(PyObject *self, PyObject *args) {
    Py_buffer frame, offsets, sample_pixel, has_pred, lut, white, bright_buf, out;
    int min_drop = 0, span = 1;
    (void)self;
    if (!PyArg_ParseTuple(args, "y*y*y*y*y*w*w*w*ii", &frame, &offsets, &sample_pixel, &has_pred, &lut, &white,
                          &bright_buf, &out, &min_drop, &span))
        return NULL;
    Py_ssize_t n_hits = 0;
    int error = check_sizes(&offsets, &sample_pixel, &has_pred, &lut, &white, &bright_buf, &out);
    if (error == 0 && (min_drop < 0 || min_drop > 255 || span < 1)) {
        PyErr_SetString(PyExc_ValueError, "min_drop must be 0..255 and span >= 1");
        error = -1;
    }
    if (error == 0) {
        const uint8_t *pixels = (const uint8_t *)frame.buf, *table = (const uint8_t *)lut.buf;
        const uint8_t *pred = (const uint8_t *)has_pred.buf;
        const int32_t *offset = (const int32_t *)offsets.buf, *sample = (const int32_t *)sample_pixel.buf;
        uint8_t *is_white = (uint8_t *)white.buf, *bright = (uint8_t *)bright_buf.buf;
        int32_t *hit = (int32_t *)out.buf;
        Py_ssize_t n_pixels = offsets.len / 4, n_samples = sample_pixel.len / 4, frame_len = frame.len;
        Py_BEGIN_ALLOW_THREADS
        for (Py_ssize_t p = 0; p < n_pixels; ++p) {
            int32_t o = offset[p];
            if (o < 0 || (Py_ssize_t)o + 2 >= frame_len) { error = 1; break; }
            uint8_t b = pixels[o], g = pixels[o + 1], r = pixels[o + 2];
            uint32_t key = ((uint32_t)b << 16) | ((uint32_t)g << 8) | r;
            is_white[p] = (table[key >> 3] >> (key & 7)) & 1;
            uint8_t v = b > g ? b : g;
            bright[p] = v > r ? v : r;
        }
        uint8_t previous = 0;
        for (Py_ssize_t s = 0; error == 0 && s < n_samples; ++s) {
            int32_t q = sample[s];
            if (q < 0 || q >= n_pixels) { error = 2; break; }
            uint8_t value = is_white[q];
            if (previous && !value && pred[s]) {
                int lowest = 0;
                /* sample[s - 1] was checked on the previous iteration (pred[s] implies s >= 1) */
                if (min_drop == 0) hit[n_hits++] = (int32_t)s;
                else if (lowest_after(bright, sample, pred, s, n_samples, n_pixels, span, &lowest) < 0) error = 2;
                else if ((int)bright[sample[s - 1]] - lowest >= min_drop) hit[n_hits++] = (int32_t)s;
            }
            previous = value;
        }
        Py_END_ALLOW_THREADS
        if (error == 1) PyErr_SetString(PyExc_ValueError, "a pixel offset lies outside the frame");
        if (error == 2) PyErr_SetString(PyExc_ValueError, "a sample refers to a pixel outside the table");
    }
    PyBuffer_Release(&frame);
    PyBuffer_Release(&offsets);
    PyBuffer_Release(&sample_pixel);
    PyBuffer_Release(&has_pred);
    PyBuffer_Release(&lut);
    PyBuffer_Release(&white);
    PyBuffer_Release(&bright_buf);
    PyBuffer_Release(&out);
    if (error) return NULL;
    return PyLong_FromSsize_t(n_hits);
}

static PyMethodDef methods[] = {
    {"scan_hits", scan_hits, METH_VARARGS, "Hit sample indices of one frame (see scan_kernel.c)."},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {
    PyModuleDef_HEAD_INIT, "_scan_kernel", "Radial scan inner loop.", -1, methods, NULL, NULL, NULL, NULL,
};

PyMODINIT_FUNC PyInit__scan_kernel(void) { return PyModule_Create(&module); }
