/* The legacy VTK ASCII number parser of the read stage (models/mesh/legacy.py), a part of the
 * models.mesh._fastmesh module (its method table is in _fastmesh.c). */
#define _GNU_SOURCE /* strtod_l */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <stdint.h>
#include <string.h>
#include <stdlib.h>

/* ascii_values(data, pos, out, kind) -> int
 *   The next len(out) whitespace-separated numbers of legacy VTK ASCII text from data[pos:]
 *   (models/mesh/legacy.py): kind 0 integers into int64, 1 decimals into float64, 2 decimals into
 *   float32, each correctly rounded (the value strtod / strtof give, as VTK's reader reads them:
 *   the exact fast path where the digits and the power of ten are exact doubles, strtod_l in the C
 *   locale otherwise). Returns the position after the last one, or -1 for anything else (a word
 *   that is not a plain number: letters, nan, inf, hex, a sign alone, over 18 integer digits, a
 *   word over 63 bytes; too few numbers): the caller then leaves the file to VTK's reader. */
#include <locale.h>
static locale_t c_locale;

static inline int is_space(unsigned char ch) { return ch <= ' ' && (ch == ' ' || ch == '\n' || ch == '\r' || ch == '\t'); }

static const double pow10_exact[23] = {1e0,  1e1,  1e2,  1e3,  1e4,  1e5,  1e6,  1e7,  1e8,  1e9,  1e10, 1e11,
                                       1e12, 1e13, 1e14, 1e15, 1e16, 1e17, 1e18, 1e19, 1e20, 1e21, 1e22};

/* One decimal word w[0..n): 0 and the value in *out, or -1 where it is not [+-]digits[.digits][(e|E)[+-]digits]
 * (at least one digit before or after the point). */
static int parse_decimal(const unsigned char *w, int64_t n, int kind, double *dv, float *fv) {
    int64_t i = 0;
    int neg = 0;
    if (i < n && (w[i] == '+' || w[i] == '-')) neg = w[i++] == '-';
    uint64_t m = 0;
    int digits = 0, sig = 0, frac = 0, any = 0, exact = 1;
    for (; i < n && w[i] >= '0' && w[i] <= '9'; i++, any++) {
        if (m == 0 && w[i] == '0') continue; /* leading zeros: not significant */
        if (sig < 19) m = m * 10 + (w[i] - '0'), sig++;
        else exact = 0, digits++; /* dropped digit: strtod decides */
    }
    if (i < n && w[i] == '.') {
        i++;
        for (; i < n && w[i] >= '0' && w[i] <= '9'; i++, any++) {
            if (m == 0 && w[i] == '0') {
                frac++;
                continue;
            }
            if (sig < 19) m = m * 10 + (w[i] - '0'), sig++, frac++;
            else exact = 0;
        }
    }
    if (!any) return -1;
    int64_t e = 0;
    if (i < n && (w[i] == 'e' || w[i] == 'E')) {
        i++;
        int eneg = 0;
        if (i < n && (w[i] == '+' || w[i] == '-')) eneg = w[i++] == '-';
        if (i >= n) return -1;
        for (; i < n && w[i] >= '0' && w[i] <= '9'; i++)
            if (e < 100000) e = e * 10 + (w[i] - '0');
        if (eneg) e = -e;
    }
    if (i != n) return -1;
    int64_t p = e - frac + digits; /* value = m * 10^p */
    if (kind == 1 && exact && m <= ((uint64_t)1 << 53) && p >= -22 && p <= 22) {
        double v = (double)m; /* exact; one correctly rounded operation on exact operands */
        v = p < 0 ? v / pow10_exact[-p] : v * pow10_exact[p];
        *dv = neg ? -v : v;
        return 0;
    }
    if (kind == 2 && exact && m <= ((uint64_t)1 << 24) && p >= -10 && p <= 10) {
        float v = (float)m, t = (float)pow10_exact[p < 0 ? -p : p]; /* 10^10 and below: exact floats */
        v = p < 0 ? v / t : v * t;
        *fv = neg ? -v : v;
        return 0;
    }
    char buf[64];
    memcpy(buf, w, (size_t)n);
    buf[n] = 0;
    char *end;
    if (kind == 1)
        *dv = strtod_l(buf, &end, c_locale);
    else
        *fv = strtof_l(buf, &end, c_locale);
    return end == buf + n ? 0 : -1;
}

PyObject *py_ascii_values(PyObject *self, PyObject *args) {
    Py_buffer d, o;
    Py_ssize_t pos;
    int kind;
    if (!PyArg_ParseTuple(args, "y*nw*i", &d, &pos, &o, &kind)) return NULL;
    Py_ssize_t item = kind == 2 ? 4 : 8;
    if (kind < 0 || kind > 2 || o.len % item || pos < 0 || pos > d.len) {
        PyBuffer_Release(&d);
        PyBuffer_Release(&o);
        PyErr_SetString(PyExc_ValueError, "ascii_values: bad arguments");
        return NULL;
    }
    if (kind && !c_locale) c_locale = newlocale(LC_ALL_MASK, "C", (locale_t)0);
    const unsigned char *s = d.buf;
    int64_t n = d.len, count = o.len / item, at = pos, got = 0;
    int bad = kind && !c_locale;
    Py_BEGIN_ALLOW_THREADS
    if (kind == 0) /* integers: one pass over each word */
        for (; got < count; got++) {
            while (at < n && is_space(s[at])) at++;
            int64_t v = 0, neg = 0, w;
            if (at < n && (s[at] == '-' || s[at] == '+')) neg = s[at++] == '-';
            for (w = at; at < n; at++) {
                unsigned d9 = (unsigned)s[at] - '0';
                if (d9 > 9 || at - w >= 18) break; /* a 19th digit: declined below */
                v = v * 10 + d9;
            }
            if (at == w || (at < n && !is_space(s[at]))) {
                bad = 1;
                break;
            }
            ((int64_t *)o.buf)[got] = neg ? -v : v;
        }
    else
        for (; got < count; got++) {
            while (at < n && is_space(s[at])) at++;
            int64_t w = at;
            while (at < n && !is_space(s[at])) at++;
            if (at == w || at - w > 63 ||
                parse_decimal(s + w, at - w, kind, (double *)o.buf + got, (float *)o.buf + got) < 0) {
                bad = 1;
                break;
            }
        }
    Py_END_ALLOW_THREADS
    PyBuffer_Release(&d);
    PyBuffer_Release(&o);
    return PyLong_FromSsize_t(bad || got < count ? -1 : (Py_ssize_t)at);
}
