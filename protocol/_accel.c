/* Optional C accelerator for the two hot decode paths; see protocol/accel.py.
 *
 * It only ever answers the common case. Each function either returns exactly what the
 * pure-Python decoder would have built, or hands the input back for Python to handle (a line
 * as bytes, a frame as a 1-tuple, or None for a whole chunk), so every drop reason, counter and
 * limit stays defined in one place: the Python decoders. tests/test_accel.py holds both paths
 * to the same output on random and mutated input.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <stdint.h>
#include <string.h>

/* ---- CRC-16/CCITT-FALSE (poly 0x1021, MSB first), slice-by-8 ------------------------------ */

static uint16_t crc_table[8][256];

static void crc_init(void)
{
    for (int i = 0; i < 256; i++) {
        uint16_t c = (uint16_t)(i << 8);
        for (int k = 0; k < 8; k++)
            c = (uint16_t)((c & 0x8000) ? (c << 1) ^ 0x1021 : c << 1);
        crc_table[0][i] = c;
    }
    /* crc_table[t][i]: byte i followed by t zero bytes */
    for (int t = 1; t < 8; t++)
        for (int i = 0; i < 256; i++) {
            uint16_t p = crc_table[t - 1][i];
            crc_table[t][i] = (uint16_t)((p << 8) ^ crc_table[0][p >> 8]);
        }
}

static uint16_t crc16(const uint8_t *p, Py_ssize_t n, uint16_t crc)
{
    while (n >= 8) {
        crc = crc_table[7][p[0] ^ (crc >> 8)] ^ crc_table[6][p[1] ^ (crc & 0xFF)]
            ^ crc_table[5][p[2]] ^ crc_table[4][p[3]] ^ crc_table[3][p[4]]
            ^ crc_table[2][p[5]] ^ crc_table[1][p[6]] ^ crc_table[0][p[7]];
        p += 8;
        n -= 8;
    }
    while (n-- > 0)
        crc = (uint16_t)((crc << 8) ^ crc_table[0][(crc >> 8) ^ *p++]);
    return crc;
}

static PyObject *py_crc16(PyObject *self, PyObject *arg)
{
    Py_buffer buf;
    if (PyObject_GetBuffer(arg, &buf, PyBUF_SIMPLE) < 0)
        return NULL;
    uint16_t crc = crc16(buf.buf, buf.len, 0xFFFF);
    PyBuffer_Release(&buf);
    return PyLong_FromLong(crc);
}

/* a + b as a new bytes object: the held tail joined to the new chunk */
static PyObject *concat(const void *a, Py_ssize_t an, const void *b, Py_ssize_t bn)
{
    PyObject *joined = PyBytes_FromStringAndSize(NULL, an + bn);
    if (joined != NULL) {
        memcpy(PyBytes_AS_STRING(joined), a, an);
        memcpy(PyBytes_AS_STRING(joined) + an, b, bn);
    }
    return joined;
}

/* ---- +UUDF lines -------------------------------------------------------------------------- */

#define MAX_LINE 512
#define MAX_STRING 30

typedef struct {
    const char *p;
    const char *end;
} cursor;

/* A decimal integer exactly as printf %d writes it, within [lo, hi], then `stop` (or the end
 * of the line when stop is 0). */
static int take_int(cursor *c, long long lo, long long hi, char stop, long long *out)
{
    const char *p = c->p;
    int neg = 0;
    if (p < c->end && *p == '-') {
        neg = 1;
        p++;
    }
    const char *digits = p;
    long long v = 0;
    while (p < c->end && *p >= '0' && *p <= '9' && p - digits < 11)
        v = v * 10 + (*p++ - '0');
    Py_ssize_t nd = p - digits;
    if (nd == 0 || nd > 10 || (digits[0] == '0' && (nd > 1 || neg)))
        return 0;
    if (neg)
        v = -v;
    if (v < lo || v > hi)
        return 0;
    if (stop) {
        if (p >= c->end || *p != stop)
            return 0;
        p++;
    }
    else if (p != c->end)
        return 0;
    c->p = p;
    *out = v;
    return 1;
}

static int take_quoted(cursor *c, const char **s, Py_ssize_t *n)
{
    const char *p = c->p;
    if (p >= c->end || *p != '"')
        return 0;
    const char *start = ++p;
    while (p < c->end && *p != '"') {
        if (*p == 0 || (unsigned char)*p > 127)
            return 0;
        p++;
    }
    if (p >= c->end || p - start > MAX_STRING || p + 1 >= c->end || p[1] != ',')
        return 0;
    *s = start;
    *n = p - start;
    c->p = p + 2;
    return 1;
}

static PyObject *ascii_str(const char *s, Py_ssize_t n)
{
    PyObject *u = PyUnicode_New(n, 127);
    if (u != NULL && n)
        memcpy(PyUnicode_1BYTE_DATA(u), s, n);
    return u;
}

static int is_hex(char ch)
{
    return (ch >= '0' && ch <= '9') || (ch >= 'A' && ch <= 'F') || (ch >= 'a' && ch <= 'f');
}

/* 1 and *out set: an event; 0: not the common case (Python decides); -1: exception. */
static int parse_angle_event(const char *line, Py_ssize_t n, PyTypeObject *cls, PyObject **out)
{
    if (n < 6 || memcmp(line, "+UUDF:", 6) != 0)
        return 0;
    cursor c = {line + 6, line + n};
    if (c.end - c.p < 13 || c.p[12] != ',')
        return 0;
    for (int i = 0; i < 12; i++)
        if (!is_hex(c.p[i]))
            return 0;
    const char *id = c.p;
    c.p += 13;
    long long rssi1, az, el, rssi2, ch, ts, seq = -1, az_raw = 0, el_raw = 0;
    const char *anchor, *user;
    Py_ssize_t anchor_n, user_n;
    if (!take_int(&c, -127, 20, ',', &rssi1) || !take_int(&c, -90, 90, ',', &az)
        || !take_int(&c, -90, 90, ',', &el) || !take_int(&c, -127, 20, ',', &rssi2)
        || !take_int(&c, 0, 39, ',', &ch) || !take_quoted(&c, &anchor, &anchor_n)
        || !take_quoted(&c, &user, &user_n))
        return 0;
    cursor probe = c;
    int nfields = 9;
    if (take_int(&probe, -2147483648LL, 2147483647LL, 0, &ts))
        c = probe;
    else if (take_int(&c, -2147483648LL, 2147483647LL, ',', &ts)) {
        probe = c;
        if (take_int(&probe, 0, 65535, 0, &seq))
            nfields = 10;
        else if (take_int(&c, 0, 65535, ',', &seq) && take_int(&c, -90, 90, ',', &az_raw)
                 && take_int(&c, -90, 90, 0, &el_raw))
            nfields = 12;
        else
            return 0;
    }
    else
        return 0;

    PyObject *ev = cls->tp_alloc(cls, 12);
    if (ev == NULL)
        return -1;
    PyObject *items[12] = {
        ascii_str(id, 12),
        PyLong_FromLongLong(rssi1),
        PyLong_FromLongLong(az),
        PyLong_FromLongLong(el),
        PyLong_FromLongLong(rssi2),
        PyLong_FromLongLong(ch),
        ascii_str(anchor, anchor_n),
        ascii_str(user, user_n),
        PyLong_FromLongLong(ts),
        nfields >= 10 ? PyLong_FromLongLong(seq) : Py_NewRef(Py_None),
        nfields == 12 ? PyLong_FromLongLong(az_raw) : Py_NewRef(Py_None),
        nfields == 12 ? PyLong_FromLongLong(el_raw) : Py_NewRef(Py_None),
    };
    int failed = 0;
    for (int i = 0; i < 12; i++) {
        if (items[i] == NULL)
            failed = 1;
        PyTuple_SET_ITEM(ev, i, items[i]);
    }
    if (failed) {
        Py_DECREF(ev);
        return -1;
    }
    *out = ev;
    return 1;
}

/* scan_uudf(rest: bytes, data: buffer, cls) -> (items, angles, rest) | None
 *
 * `rest` is the held unfinished line, `data` the new chunk. Every complete non-blank line
 * becomes a `cls` event when it is an ordinary +UUDF line, else its bytes for Python to
 * classify; `angles` counts the events. None: the held line would pass MAX_LINE (Python's
 * overlong handling takes the chunk). */
static PyObject *scan_uudf(PyObject *self, PyObject *const *args, Py_ssize_t nargs)
{
    if (nargs != 3 || !PyBytes_Check(args[0]) || !PyType_Check(args[2])) {
        PyErr_SetString(PyExc_TypeError, "scan_uudf(rest: bytes, data, cls: type)");
        return NULL;
    }
    PyTypeObject *cls = (PyTypeObject *)args[2];
    if (!PyType_IsSubtype(cls, &PyTuple_Type)) {
        PyErr_SetString(PyExc_TypeError, "cls must be a tuple subclass");
        return NULL;
    }
    Py_buffer buf;
    if (PyObject_GetBuffer(args[1], &buf, PyBUF_SIMPLE) < 0)
        return NULL;
    const char *data = buf.buf;
    Py_ssize_t n = buf.len;
    const char *rest = PyBytes_AS_STRING(args[0]);
    Py_ssize_t rest_n = PyBytes_GET_SIZE(args[0]);
    PyObject *result = NULL, *items = NULL, *tail = NULL, *joined = NULL;

    Py_ssize_t cut = n;
    while (cut > 0 && data[cut - 1] != '\n' && data[cut - 1] != '\r')
        cut--;
    if (cut == 0) {
        if (rest_n + n > MAX_LINE) {
            PyBuffer_Release(&buf);
            Py_RETURN_NONE;
        }
        tail = concat(rest, rest_n, data, n);
        items = PyList_New(0);
        if (tail != NULL && items != NULL)
            result = Py_BuildValue("(OiO)", items, 0, tail);
        goto done;
    }

    const char *seg = data;
    Py_ssize_t seg_n = cut;
    if (rest_n) {
        if ((joined = concat(rest, rest_n, data, cut)) == NULL)
            goto done;
        seg = PyBytes_AS_STRING(joined);
        seg_n = rest_n + cut;
    }
    items = PyList_New(0);
    if (items == NULL)
        goto done;
    int angles = 0;
    const char *p = seg, *end = seg + seg_n;
    while (p < end) {
        const char *q = p;
        while (q < end && *q != '\n' && *q != '\r')
            q++;
        Py_ssize_t len = q - p;
        if (len) {
            PyObject *item = NULL;
            int ok = parse_angle_event(p, len, cls, &item);
            if (ok < 0)
                goto done;
            if (ok)
                angles++;
            else if ((item = PyBytes_FromStringAndSize(p, len)) == NULL)
                goto done;
            int failed = PyList_Append(items, item);
            Py_DECREF(item);
            if (failed)
                goto done;
        }
        p = (q + 1 < end && q[0] == '\r' && q[1] == '\n') ? q + 2 : q + 1;
    }
    tail = PyBytes_FromStringAndSize(data + cut, n - cut);
    if (tail != NULL)
        result = Py_BuildValue("(OiO)", items, angles, tail);
done:
    Py_XDECREF(joined);
    Py_XDECREF(items);
    Py_XDECREF(tail);
    PyBuffer_Release(&buf);
    return result;
}

/* ---- COBS frames -------------------------------------------------------------------------- */

#define MIN_INNER 11   /* 9-byte header + CRC */
#define MAX_INNER 1024 /* records.MAX_INNER; a longer frame goes back to Python, which drops it */

/* COBS-decode `n` bytes (no zero among them) into `out`; the decoded length, or -1 when the
 * encoding is invalid. `out` holds at least n bytes. Same rules as the cobs package. */
static Py_ssize_t cobs_decode(const uint8_t *in, Py_ssize_t n, uint8_t *out)
{
    Py_ssize_t i = 0, o = 0;
    while (i < n) {
        uint8_t code = in[i++];
        Py_ssize_t stop = i + code - 1;
        if (code == 0 || stop > n)
            return -1;
        memcpy(out + o, in + i, stop - i);
        o += stop - i;
        i = stop;
        if (i < n && code < 0xFF)
            out[o++] = 0;
    }
    return o;
}

/* 1: good frame appended as its inner bytes; 0: appended as (raw,) for Python; -1: error. */
static int take_frame(PyObject *items, const uint8_t *frame, Py_ssize_t n, Py_ssize_t max_encoded,
                      uint8_t *scratch)
{
    PyObject *item;
    Py_ssize_t inner_n = n <= max_encoded ? cobs_decode(frame, n, scratch) : -1;
    int good = inner_n >= MIN_INNER && inner_n <= MAX_INNER
               && crc16(scratch, inner_n - 2, 0xFFFF)
                      == (scratch[inner_n - 2] | (scratch[inner_n - 1] << 8));
    if (good)
        item = PyBytes_FromStringAndSize((const char *)scratch, inner_n);
    else
        item = Py_BuildValue("(y#)", (const char *)frame, n);
    if (item == NULL)
        return -1;
    int failed = PyList_Append(items, item);
    Py_DECREF(item);
    return failed ? -1 : good;
}

/* scan_frames(rest: bytes, data: buffer, max_encoded: int) -> (items, rest) | None
 *
 * Splits rest + data on zero bytes. Each complete non-empty frame becomes its inner bytes
 * (header | body | crc) when COBS decoding, the length (11..MAX_INNER) and the CRC pass, else the 1-tuple
 * (raw frame,) for Python to drop with the exact reason. None: the unfinished frame would
 * pass max_encoded (Python's oversize handling takes the chunk). */
static PyObject *scan_frames(PyObject *self, PyObject *const *args, Py_ssize_t nargs)
{
    if (nargs != 3 || !PyBytes_Check(args[0]) || !PyLong_Check(args[2])) {
        PyErr_SetString(PyExc_TypeError, "scan_frames(rest: bytes, data, max_encoded: int)");
        return NULL;
    }
    Py_ssize_t max_encoded = PyLong_AsSsize_t(args[2]);
    if (max_encoded < 0 || max_encoded > 1 << 16) {
        if (!PyErr_Occurred())
            PyErr_SetString(PyExc_ValueError, "max_encoded must be in 0..65536");
        return NULL;
    }
    Py_buffer buf;
    if (PyObject_GetBuffer(args[1], &buf, PyBUF_SIMPLE) < 0)
        return NULL;
    const uint8_t *data = buf.buf;
    Py_ssize_t n = buf.len;
    const uint8_t *rest = (const uint8_t *)PyBytes_AS_STRING(args[0]);
    Py_ssize_t rest_n = PyBytes_GET_SIZE(args[0]);
    PyObject *result = NULL, *items = NULL, *tail = NULL;
    uint8_t *scratch = NULL;

    const uint8_t *last = data + n;
    while (last > data && last[-1] != 0)
        last--;
    if (last == data) { /* no zero: the frame goes on */
        if (rest_n + n > max_encoded) {
            PyBuffer_Release(&buf);
            Py_RETURN_NONE;
        }
        tail = concat(rest, rest_n, data, n);
        items = PyList_New(0);
        if (tail != NULL && items != NULL)
            result = PyTuple_Pack(2, items, tail);
        goto done;
    }
    last--; /* the last zero */
    Py_ssize_t tail_n = data + n - (last + 1);
    if (tail_n > max_encoded) {
        PyBuffer_Release(&buf);
        Py_RETURN_NONE;
    }
    scratch = PyMem_Malloc((size_t)max_encoded + 1);
    items = PyList_New(0);
    if (scratch == NULL || items == NULL) {
        if (scratch == NULL)
            PyErr_NoMemory();
        goto done;
    }
    const uint8_t *p = data;
    if (rest_n) { /* the frame held from earlier chunks ends at the first zero */
        const uint8_t *z = memchr(data, 0, n);
        PyObject *first = concat(rest, rest_n, data, z - data);
        if (first == NULL)
            goto done;
        int taken = take_frame(items, (const uint8_t *)PyBytes_AS_STRING(first),
                               PyBytes_GET_SIZE(first), max_encoded, scratch);
        Py_DECREF(first);
        if (taken < 0)
            goto done;
        p = z + 1;
    }
    while (p <= last) {
        const uint8_t *q = memchr(p, 0, last + 1 - p);
        if (q > p && take_frame(items, p, q - p, max_encoded, scratch) < 0)
            goto done;
        p = q + 1;
    }
    tail = PyBytes_FromStringAndSize((const char *)last + 1, tail_n);
    if (tail != NULL)
        result = PyTuple_Pack(2, items, tail);
done:
    PyMem_Free(scratch);
    Py_XDECREF(items);
    Py_XDECREF(tail);
    PyBuffer_Release(&buf);
    return result;
}

/* ---- module ------------------------------------------------------------------------------- */

static PyMethodDef methods[] = {
    {"crc16", py_crc16, METH_O, "crc16(data) -> int: CRC-16/CCITT-FALSE (init 0xFFFF)."},
    {"scan_uudf", (PyCFunction)(void (*)(void))scan_uudf, METH_FASTCALL,
     "scan_uudf(rest, data, cls) -> (items, angles, rest) | None; see protocol/accel.py."},
    {"scan_frames", (PyCFunction)(void (*)(void))scan_frames, METH_FASTCALL,
     "scan_frames(rest, data, max_encoded) -> (items, rest) | None; see protocol/accel.py."},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {
    PyModuleDef_HEAD_INIT, "protocol._accel",
    "C fast paths for the u-connectLocate and frame decoders (optional).", -1, methods,
};

PyMODINIT_FUNC PyInit__accel(void)
{
    crc_init();
    return PyModule_Create(&module);
}
