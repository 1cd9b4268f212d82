/* Buffer-protocol helpers shared by the compiled modules (models/_fastmetrics.c, models/_fastgraph.c):
 * arrays come in as C-contiguous buffers of a given item size, all taken or none. */
#ifndef MAGNET_BUFFERS_H
#define MAGNET_BUFFERS_H

#ifndef PY_SSIZE_T_CLEAN
#define PY_SSIZE_T_CLEAN
#endif
#include <Python.h>

#define N8(b) ((int64_t)((b).len / 8)) /* items of an 8-byte buffer */

static inline int get_buf(PyObject *o, Py_buffer *b, int writable, const char *name, Py_ssize_t itemsize) {
    int flags = PyBUF_C_CONTIGUOUS | PyBUF_FORMAT | (writable ? PyBUF_WRITABLE : 0);
    if (PyObject_GetBuffer(o, b, flags) < 0) return -1;
    if (b->itemsize != itemsize) {
        PyErr_Format(PyExc_TypeError, "%s: wrong item size", name);
        PyBuffer_Release(b);
        return -1;
    }
    return 0;
}

/* all n buffers (item size sizes[i], or 8 without sizes; writable where wr[i]), or none: on a
 * failure the ones taken are released and -1 returned with the exception set */
static inline int get_bufs(PyObject *const *objs, Py_buffer *const *all, int n, const char *const *names,
                           const Py_ssize_t *sizes, const int *wr) {
    for (int got = 0; got < n; got++)
        if (get_buf(objs[got], all[got], wr[got], names[got], sizes ? sizes[got] : 8) < 0) {
            for (int i = 0; i < got; i++) PyBuffer_Release(all[i]);
            return -1;
        }
    return 0;
}

static inline void release_bufs(Py_buffer *const *all, int n) {
    for (int i = 0; i < n; i++) PyBuffer_Release(all[i]);
}

#define MAX_ARRAYS 16

/* a call's arguments, all arrays: their n buffers into b[0..n-1] (as get_bufs), or -1 with the
 * exception set */
static inline int parse_bufs(PyObject *args, int n, const char *fname, const char *const *names,
                             const Py_ssize_t *sizes, const int *wr, Py_buffer *b) {
    if (n > MAX_ARRAYS || !PyTuple_Check(args) || PyTuple_GET_SIZE(args) != n) {
        PyErr_Format(PyExc_TypeError, "%s() takes %d arrays", fname, n);
        return -1;
    }
    PyObject *objs[MAX_ARRAYS];
    Py_buffer *all[MAX_ARRAYS];
    for (int i = 0; i < n; i++) {
        objs[i] = PyTuple_GET_ITEM(args, i);
        all[i] = b + i;
    }
    return get_bufs(objs, all, n, names, sizes, wr);
}

/* release b[0..n-1] */
static inline void release_arr(Py_buffer *b, int n) {
    for (int i = 0; i < n; i++) PyBuffer_Release(b + i);
}

#endif
