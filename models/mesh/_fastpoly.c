/* Compiled helpers of the read stage for polyhedra (VTK type 42, prisms of 5 and 6 sides), a part of
 * the models.mesh._fastmesh module (its method table is in _fastmesh.c). Each has a numpy twin, the
 * fallback and the reference in tests/test_fastmesh.py; the same results bit for bit.
 *
 *   poly_distinct  each polyhedron's distinct nodes, ascending (cells.distinct_nodes);
 *   poly_agree     whether every edge of each polyhedron's faces is walked once each way by the two
 *                  faces that share it (polyfaces.agree_faces' test before it colours anything), and
 *                  the polyhedra not closed (an edge walked by one face of the cell only);
 *   poly_measures  signed volume and centroid of polyhedra given by their faces, the float
 *                  operations of geometry._measures_and_centroids in its order: the cell's vertex
 *                  mean o, its faces of 3 nodes as triangles, then its other faces fanned from the
 *                  mean of their nodes, six times each triangle's volume relative to o summed, one
 *                  division by 6 per cell.
 *
 * A polyhedron's faces: cface_off (Q + 1) into the faces, face_off (F + 1) into face_nodes. Node
 * ids are trusted (checked by the caller). */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include "_buffers.h"
#include "_fastmesh.h"
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

static int cmp_i64(const void *a, const void *b) {
    int64_t x = *(const int64_t *)a, y = *(const int64_t *)b;
    return (x > y) - (x < y);
}

/* The offsets are CSR: from 0, never decreasing, the last one the next array's size. */
static int csr_ok(const int64_t *off, int64_t n, int64_t size) {
    if (n < 0 || off[0] != 0 || off[n] != size) return 0;
    for (int64_t i = 0; i < n; i++)
        if (off[i + 1] < off[i]) return 0;
    return 1;
}

/* poly_distinct(cface_off, face_off, face_nodes, sizes, nodes) -> int
 *   sizes (Q,) each polyhedron's number of distinct nodes, nodes (at least len(face_nodes)) those
 *   nodes ascending, cell after cell; returns how many were written, -1 for offsets that are not
 *   CSR. */
PyObject *py_poly_distinct(PyObject *self, PyObject *args) {
    static const char *const names[] = {"cface_off", "face_off", "face_nodes", "sizes", "nodes"};
    static const int wr[] = {0, 0, 0, 1, 1};
    Py_buffer b[5];
    if (parse_bufs(args, 5, "poly_distinct", names, NULL, wr, b) < 0) return NULL;
    const int64_t *cf = b[0].buf, *fo = b[1].buf, *fn = b[2].buf;
    int64_t *sizes = b[3].buf, *out = b[4].buf;
    int64_t Q = N8(b[0]) - 1, F = N8(b[1]) - 1, nn = N8(b[2]);
    int64_t written = -1;
    if (Q >= 0 && F >= 0 && N8(b[3]) == Q && N8(b[4]) >= nn) {
        Py_BEGIN_ALLOW_THREADS
        if (csr_ok(cf, Q, F) && csr_ok(fo, F, nn)) {
            written = 0;
            for (int64_t q = 0; q < Q; q++) {
                int64_t lo = fo[cf[q]], hi = fo[cf[q + 1]], *here = out + written;
                memcpy(here, fn + lo, (size_t)(hi - lo) * sizeof(int64_t));
                if (hi - lo > 64)
                    qsort(here, (size_t)(hi - lo), sizeof(int64_t), cmp_i64);
                else /* the usual polyhedron: an insertion sort, no calls */
                    for (int64_t j = 1; j < hi - lo; j++) {
                        int64_t v = here[j], i = j;
                        for (; i > 0 && here[i - 1] > v; i--) here[i] = here[i - 1];
                        here[i] = v;
                    }
                int64_t k = 0;
                for (int64_t j = 0; j < hi - lo; j++)
                    if (k == 0 || here[j] != here[k - 1]) here[k++] = here[j];
                sizes[q] = k;
                written += k;
            }
        }
        Py_END_ALLOW_THREADS
    }
    release_arr(b, 5);
    return PyLong_FromLongLong(written);
}

typedef struct {
    int64_t lo, hi;
    int fwd;
} Edge;

/* poly_agree(cface_off, face_off, face_nodes, open) -> int
 *   open (Q,) uint8: 1 for a polyhedron with an edge walked by one of its faces only. Returns 0
 *   when, in every polyhedron, the faces that share an edge walk it opposite ways (the faces
 *   agree), 1 where two walk one the same way (the caller colours the faces: agree_faces), -1 for
 *   offsets that are not CSR, -2 out of memory. As agree_faces: the edges of a cell sorted by
 *   (smaller node, larger node), in their order in face_nodes on a tie; consecutive equal edges
 *   are a pair; an edge in no pair is alone. */
PyObject *py_poly_agree(PyObject *self, PyObject *args) {
    static const char *const names[] = {"cface_off", "face_off", "face_nodes", "open"};
    static const Py_ssize_t sizes[] = {8, 8, 8, 1};
    static const int wr[] = {0, 0, 0, 1};
    Py_buffer b[4];
    if (parse_bufs(args, 4, "poly_agree", names, sizes, wr, b) < 0) return NULL;
    const int64_t *cf = b[0].buf, *fo = b[1].buf, *fn = b[2].buf;
    uint8_t *open = b[3].buf;
    int64_t Q = N8(b[0]) - 1, F = N8(b[1]) - 1, nn = N8(b[2]);
    int r = -1;
    if (Q >= 0 && F >= 0 && (int64_t)b[3].len == Q) {
        Py_BEGIN_ALLOW_THREADS
        if (csr_ok(cf, Q, F) && csr_ok(fo, F, nn)) {
            int64_t cap = 64;
            Edge *e = malloc((size_t)cap * sizeof(Edge));
            r = e ? 0 : -2;
            for (int64_t q = 0; q < Q && r >= 0; q++) {
                int64_t m = fo[cf[q + 1]] - fo[cf[q]], n = 0;
                if (m > cap) {
                    free(e);
                    cap = m;
                    e = malloc((size_t)cap * sizeof(Edge));
                    if (!e) {
                        r = -2;
                        break;
                    }
                }
                for (int64_t f = cf[q]; f < cf[q + 1]; f++)
                    for (int64_t j = fo[f]; j < fo[f + 1]; j++) {
                        int64_t a = fn[j], c = fn[j + 1 < fo[f + 1] ? j + 1 : fo[f]];
                        Edge x = {a < c ? a : c, a < c ? c : a, a < c};
                        int64_t i = n++; /* insertion sort: stable, as numpy's lexsort */
                        while (i > 0 && (e[i - 1].lo > x.lo || (e[i - 1].lo == x.lo && e[i - 1].hi > x.hi))) {
                            e[i] = e[i - 1];
                            i--;
                        }
                        e[i] = x;
                    }
                int alone_any = 0;
                for (int64_t i = 0; i < n; i++) {
                    int prev = i > 0 && e[i - 1].lo == e[i].lo && e[i - 1].hi == e[i].hi;
                    int next = i + 1 < n && e[i + 1].lo == e[i].lo && e[i + 1].hi == e[i].hi;
                    if (!prev && !next) alone_any = 1;
                    if (next && e[i].fwd == e[i + 1].fwd) r = 1;
                }
                open[q] = (uint8_t)alone_any;
            }
            free(e);
        }
        Py_END_ALLOW_THREADS
    }
    release_arr(b, 4);
    if (r == -2) return PyErr_NoMemory();
    return PyLong_FromLong(r);
}

/* poly_measures(points, cnode_off, cnodes, cface_off, face_off, face_nodes, vol, cen) -> int
 *   points (P * 3); each polyhedron's vertices cnodes[cnode_off[q]..] (its vertex mean o) and faces;
 *   out: vol (Q,), cen (Q * 3). 0, or -1 for offsets that are not CSR. */
PyObject *py_poly_measures(PyObject *self, PyObject *args) {
    static const char *const names[] = {"points", "cnode_off", "cnodes", "cface_off",
                                        "face_off", "face_nodes", "vol", "cen"};
    static const int wr[] = {0, 0, 0, 0, 0, 0, 1, 1};
    Py_buffer b[8];
    if (parse_bufs(args, 8, "poly_measures", names, NULL, wr, b) < 0) return NULL;
    const double *P = b[0].buf;
    const int64_t *co = b[1].buf, *cn = b[2].buf, *cf = b[3].buf, *fo = b[4].buf, *fn = b[5].buf;
    double *vol = b[6].buf, *cen = b[7].buf;
    int64_t Q = N8(b[6]), F = N8(b[4]) - 1, nn = N8(b[5]);
    int r = -1;
    if (N8(b[1]) == Q + 1 && N8(b[3]) == Q + 1 && N8(b[7]) == 3 * Q && F >= 0) {
        Py_BEGIN_ALLOW_THREADS
        if (csr_ok(co, Q, N8(b[2])) && csr_ok(cf, Q, F) && csr_ok(fo, F, nn)) {
            r = 0;
            for (int64_t q = 0; q < Q; q++) {
                double o[3] = {0.0, 0.0, 0.0};
                for (int64_t j = co[q]; j < co[q + 1]; j++)
                    for (int d = 0; d < 3; d++) o[d] += P[3 * cn[j] + d];
                for (int d = 0; d < 3; d++) o[d] /= (double)(co[q + 1] - co[q]);
                double v_sum = 0.0, g_sum[3] = {0.0, 0.0, 0.0};
#define REL(ID, OUT)                                                                               \
    do {                                                                                           \
        for (int d = 0; d < 3; d++) (OUT)[d] = P[3 * (ID) + d] - o[d];                              \
    } while (0)
                for (int pass = 0; pass < 2; pass++) /* the triangles first, then the fans */
                    for (int64_t f = cf[q]; f < cf[q + 1]; f++) {
                        int64_t lo = fo[f], s = fo[f + 1] - lo;
                        if ((s == 3) != (pass == 0)) continue;
                        if (s == 3) {
                            double a[3], bb[3], c[3];
                            REL(fn[lo], a);
                            REL(fn[lo + 1], bb);
                            REL(fn[lo + 2], c);
                            TRI(a, bb, c);
                            continue;
                        }
                        double m[3] = {0.0, 0.0, 0.0};
                        for (int64_t j = 0; j < s; j++)
                            for (int d = 0; d < 3; d++) m[d] += P[3 * fn[lo + j] + d];
                        for (int d = 0; d < 3; d++) m[d] = m[d] / (double)(s > 0 ? s : 1) - o[d];
                        for (int64_t j = 0; j < s; j++) {
                            double bb[3], c[3];
                            REL(fn[lo + j], bb);
                            REL(fn[lo + (j + 1 == s ? 0 : j + 1)], c);
                            TRI(m, bb, c);
                        }
                    }
#undef REL
                vol[q] = v_sum / 6.0;
                for (int d = 0; d < 3; d++) cen[3 * q + d] = g_sum[d] / v_sum + o[d];
            }
        }
        Py_END_ALLOW_THREADS
    }
    release_arr(b, 8);
    return PyLong_FromLong(r);
}
