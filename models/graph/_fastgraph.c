/* Compiled graph helpers of models/partition/rtree.py and models/polytope/merge.py (each has a numpy twin
 * there: the fallback and the reference in the tests; MAGNET_NO_COMPILED=1 switches them off). Same
 * results bit for bit: the same floating-point operations in the same order as the numpy code.
 *
 *   cut_prepare  one halving step of split_counts, first half: per active part its cut axis (the
 *                longest extent of its centroids), its cells along that axis, their measures' running
 *                sum over all active parts (np.cumsum's order), each cell's middle measure, and each
 *                part's measure before it and its own measure;
 *   cut_apply    second half, after rtree.py computed every part's count split and target measure
 *                (numpy's power there): the cut position (quantile, or the tightest boxes within
 *                the slack window as _tight_cut finds it), then the stable partition of every axis
 *                order of the part (side 0 first);
 *   pieces       connected pieces of the parts of a labelling (edges inside a part only), over all
 *                nodes or a subset of whole parts, numbered by their first node (scipy's numbering);
 *   cross_edges  the entries of a graph between different parts (_quotient's input to scipy);
 *   loops        merge_2d's boundary loops: each edge's successor by a hash table, loops numbered by
 *                their smallest edge (merge._pair_edges + merge._list_rank);
 *   local_pieces the pieces a set falls into without one node, searched from its neighbours (the
 *                3D repair's exact checks near the unit a move changes: models/hierarchy/repair.py).
 *
 * Arrays come through the buffer protocol (no numpy headers at build time). The axis orders P that
 * the cut functions take are trusted (rtree._Segments makes them: a permutation of 0..n-1 per axis);
 * everything else is checked.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include "_buffers.h"
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#define AHEAD 32 /* gathers prefetch this many entries ahead (random reads into arrays of a few MB) */
#define PREFETCH(p) __builtin_prefetch((p), 0, 1)
#define PREFETCHW(p) __builtin_prefetch((p), 1, 1)

/* ---------------------------------------------------------------------------------------------- */
/* cut_prepare(P, x, w, a_start, a_size, axis, length, chosen, mid, base, vol)
 *   P (dim * n) int64: the cells in (part, coordinate, id) order, axis by axis; x (n, dim) centroids;
 *   w (n,) measures; a_start / a_size (na,): the active parts' ranges.
 * Out: axis / length (na,): the longest extent of each part's centroids (first of the largest) and
 * its length; chosen / mid (>= tot): the active parts' cells along their axis, one part after the
 * other, and each cell's middle measure (running sum - half its own); base / vol (na,). */
static PyObject *py_cut_prepare(PyObject *self, PyObject *args) {
    Py_buffer b[11];
    const char *names[11] = {"P", "x", "w", "a_start", "a_size", "axis", "length", "chosen", "mid", "base", "vol"};
    int wr[11] = {0, 0, 0, 0, 0, 1, 1, 1, 1, 1, 1};
    if (parse_bufs(args, 11, "cut_prepare", names, NULL, wr, b) < 0) return NULL;
    const int64_t *P = b[0].buf;
    const double *x = b[1].buf, *w = b[2].buf;
    const int64_t *a_start = b[3].buf, *a_size = b[4].buf;
    int64_t *axis = b[5].buf;
    double *length = b[6].buf;
    int64_t *chosen = b[7].buf;
    double *mid = b[8].buf, *base = b[9].buf, *vol = b[10].buf;
    int64_t n = N8(b[2]), na = N8(b[3]);
    int64_t dim = n > 0 ? N8(b[0]) / n : 0;
    int bad = n <= 0 || dim < 1 || dim > 3 || N8(b[0]) != dim * n || N8(b[1]) != dim * n || N8(b[4]) != na ||
              N8(b[5]) < na || N8(b[6]) < na || N8(b[9]) < na || N8(b[10]) < na;
    int64_t tot = 0;
    for (int64_t i = 0; i < na && !bad; i++) {
        if (a_start[i] < 0 || a_size[i] < 1 || a_start[i] + a_size[i] > n) bad = 1;
        tot += a_size[i];
    }
    if (bad || N8(b[7]) < tot || N8(b[8]) < tot) {
        release_arr(b, 11);
        PyErr_SetString(PyExc_ValueError, "cut_prepare: inconsistent array sizes");
        return NULL;
    }
    Py_BEGIN_ALLOW_THREADS
    double cum = 0.0;
    int64_t s = 0;
    for (int64_t i = 0; i < na; i++) {
        int64_t first = a_start[i], last = first + a_size[i] - 1;
        int64_t ax = 0;
        double best = 0.0;
        for (int64_t d = 0; d < dim; d++) {
            double e = x[P[d * n + last] * dim + d] - x[P[d * n + first] * dim + d];
            if (d == 0 || e > best) { best = e; ax = d; }
        }
        axis[i] = ax;
        length[i] = best;
        const int64_t *src = P + ax * n + first;
        int64_t sz = a_size[i];
        double ws0 = 0.0;
        for (int64_t j = 0; j < sz; j++) {
            if (j + AHEAD < sz) PREFETCH(w + src[j + AHEAD]);
            int64_t c = src[j];
            double wc = w[c];
            chosen[s + j] = c;
            cum = j == 0 && s == 0 ? wc : cum + wc;  /* np.cumsum: the first entry is the first weight */
            mid[s + j] = cum - 0.5 * wc;
            if (j == 0) {
                ws0 = wc;
                base[i] = cum - ws0;
            }
        }
        vol[i] = cum - base[i];
        s += sz;
    }
    Py_END_ALLOW_THREADS
    release_arr(b, 11);
    return PyLong_FromLongLong(tot);
}

/* first index in [lo, hi) with a[i] >= t (right = 0) or a[i] > t (right = 1); hi when none */
static inline int64_t bound(const double *a, int64_t lo, int64_t hi, double t, int right) {
    while (lo < hi) {
        int64_t m = lo + ((hi - lo) >> 1);
        if (right ? a[m] <= t : a[m] < t)
            lo = m + 1;
        else
            hi = m;
    }
    return lo;
}

/* cut_apply(P, lh, chosen, mid, a_start, a_size, axis, target, window, m1, m, slack, n0, side, tmp, fscr)
 *   lh: the cells' bounds (dim * n pairs: lower, upper; axis d of cell c at pair d * n + c), or an
 *   empty array for plain quantile cuts (then window is ignored); scratch, made once by the caller
 *   (fresh memory costs page faults at every step): side (n,) uint8 zeros, tmp (>= max(part size,
 *   2 na)) int64, fscr (>= 2 tot + max part size) float64.
 * Out: n0 (na,) int64, the cells of each part's side 0; P's ranges of the parts partitioned stably. */
static PyObject *py_cut_apply(PyObject *self, PyObject *args) {
    PyObject *o[15];
    double slack;
    if (!PyArg_ParseTuple(args, "OOOOOOOOOOOdOOOO", o, o + 1, o + 2, o + 3, o + 4, o + 5, o + 6, o + 7, o + 8,
                          o + 9, o + 10, &slack, o + 11, o + 12, o + 13, o + 14))
        return NULL;
    Py_buffer b[15];
    Py_buffer *all[15];
    for (int i = 0; i < 15; i++) all[i] = b + i;
    const char *names[15] = {"P", "lh", "chosen", "mid", "a_start", "a_size", "axis", "target", "window",
                             "m1", "m", "n0", "side", "tmp", "fscr"};
    Py_ssize_t sizes[15] = {8, 8, 8, 8, 8, 8, 8, 8, 8, 8, 8, 8, 1, 8, 8};
    int wr[15] = {1, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 1, 1, 1, 1};
    if (get_bufs(o, all, 15, names, sizes, wr) < 0) return NULL;
    int64_t *P = b[0].buf;
    const double *lh = b[1].buf;
    const int64_t *chosen = b[2].buf;
    const double *mid = b[3].buf;
    const int64_t *a_start = b[4].buf, *a_size = b[5].buf, *axis = b[6].buf;
    const double *target = b[7].buf, *window = b[8].buf;
    const int64_t *m1 = b[9].buf, *m = b[10].buf;
    int64_t *n0 = b[11].buf;
    uint8_t *side = b[12].buf;
    int64_t *tmp = b[13].buf;
    double *vb = b[14].buf;
    int64_t n = (int64_t)b[12].len, na = N8(b[4]);
    int64_t dim = n > 0 ? N8(b[0]) / n : 0;
    int tight = b[1].len > 0;
    int64_t tot = 0, big_part = 0;
    int bad = n <= 0 || dim < 1 || dim > 3 || N8(b[0]) != dim * n || (tight && N8(b[1]) != 2 * dim * n) ||
              N8(b[5]) != na || N8(b[6]) < na || N8(b[7]) < na || (tight && N8(b[8]) < na) || N8(b[9]) < na ||
              N8(b[10]) < na || N8(b[11]) < na;
    for (int64_t i = 0; i < na && !bad; i++) {
        if (a_start[i] < 0 || a_size[i] < 1 || a_start[i] + a_size[i] > n || axis[i] < 0 || axis[i] >= dim)
            bad = 1;
        tot += a_size[i];
        if (a_size[i] > big_part) big_part = a_size[i];
    }
    if (bad || N8(b[2]) < tot || N8(b[3]) < tot || N8(b[13]) < big_part || N8(b[13]) < 2 * na ||
        (tight && N8(b[14]) < 2 * tot + big_part)) {
        release_bufs(all, 15);
        PyErr_SetString(PyExc_ValueError, "cut_apply: inconsistent array sizes");
        return NULL;
    }
    Py_BEGIN_ALLOW_THREADS
    /* the quantile cut of each part: cells whose middle lies below the target */
    int64_t s0 = 0, W = 0;
    int64_t *wl = tmp, *wh = tmp + na;  /* the windows, before tmp serves the partitions */
    for (int64_t i = 0; i < na; i++) {
        int64_t e1 = s0 + a_size[i] - 1;
        n0[i] = bound(mid, s0, e1 + 1, target[i], 0) - s0;
        if (tight) {
            int64_t l = bound(mid, s0, e1 + 1, target[i] - window[i], 0);
            int64_t h = bound(mid, s0, e1 + 1, target[i] + window[i], 1);
            wl[i] = l;
            wh[i] = h < e1 ? h : e1;
            if (wh[i] > wl[i]) W += wh[i] - wl[i];
        }
        s0 = e1 + 1;
    }
    if (tight && W > 0) {
        /* the active cells' extents along their part's axis; span and lowest bound over all of them */
        double *smin = vb + 2 * tot;
        double vmin = INFINITY, vmax = -INFINITY;
        s0 = 0;
        for (int64_t i = 0; i < na; i++) {
            const double *lhd = lh + 2 * axis[i] * n;
            for (int64_t j = s0; j < s0 + a_size[i]; j++) {
                if (j + AHEAD < tot) PREFETCH(lhd + 2 * chosen[j + AHEAD]);
                const double *q = lhd + 2 * chosen[j];
                double lo = q[0], hi = q[1];
                vb[2 * j] = lo;
                vb[2 * j + 1] = hi;
                if (lo < vmin) vmin = lo;
                if (hi > vmax) vmax = hi;
            }
            s0 += a_size[i];
        }
        double span = vmax - vmin;
        if (!(span >= 1e-300)) span = 1e-300;
        double big = 4.0 * span + 1.0, c9 = 1e-9 * span;
        s0 = 0;
        for (int64_t i = 0; i < na; i++) {
            int64_t e1 = s0 + a_size[i] - 1, l = wl[i], h = wh[i];
            if (h > l) {
                double pre = -INFINITY, post = INFINITY;
                for (int64_t j = s0; j < l; j++)
                    if (vb[2 * j + 1] > pre) pre = vb[2 * j + 1];
                for (int64_t j = h + 1; j <= e1; j++)
                    if (vb[2 * j] < post) post = vb[2 * j];
                double off = (double)i * big;
                double dn = window[i] / slack;
                if (!(dn >= 1e-300)) dn = 1e-300;
                /* suffix minima of the lower bounds after each cut position (raw; the numpy code's
                 * offset transform is monotone, so it commutes with the minimum) */
                double run = INFINITY;
                for (int64_t j = h; j > l; j--) {
                    if (vb[2 * j] < run) run = vb[2 * j];
                    smin[j - l - 1] = run;
                }
                double pmaxr = -INFINITY, best = INFINITY;
                int64_t arg = -1;
                for (int64_t j = l; j < h; j++) {
                    if (vb[2 * j + 1] > pmaxr) pmaxr = vb[2 * j + 1];
                    double pm = (((pmaxr - vmin) + off) - off) + vmin;
                    if (!(pm >= pre)) pm = pre;
                    double sm = (((smin[j - l] - vmin) + off) - off) + vmin;
                    if (!(sm <= post)) sm = post;
                    double ov = pm - sm;
                    if (!(ov >= 0.0)) ov = 0.0;
                    double cost = ov + c9 * (fabs(mid[j] - target[i]) / dn);
                    if (cost < best) { best = cost; arg = j; }
                }
                if (arg >= 0) n0[i] = arg - s0 + 1;
            }
            s0 = e1 + 1;
        }
    }
    /* both sides keep at least as many cells as parts; then the stable partition of every other
     * axis order (the part's own axis is already in that order) */
    s0 = 0;
    for (int64_t i = 0; i < na; i++) {
        int64_t sz = a_size[i], lo = m1[i], hi = sz - (m[i] - m1[i]);
        int64_t c = n0[i] < lo ? lo : n0[i];
        c = c > hi ? hi : c;
        n0[i] = c;
        for (int64_t j = s0 + c; j < s0 + sz; j++) {
            if (j + AHEAD < s0 + sz) PREFETCHW(side + chosen[j + AHEAD]);
            side[chosen[j]] = 1;
        }
        for (int64_t d = 0; d < dim; d++) {
            if (d == axis[i]) continue;
            int64_t *r = P + d * n + a_start[i];
            int64_t k0 = 0, k1 = 0;
            for (int64_t j = 0; j < sz; j++) {
                if (j + AHEAD < sz) PREFETCH(side + r[j + AHEAD]);
                int64_t v = r[j];
                if (side[v]) tmp[k1++] = v;
                else r[k0++] = v;
            }
            memcpy(r + k0, tmp, (size_t)k1 * sizeof(int64_t));
        }
        for (int64_t j = s0 + c; j < s0 + sz; j++) side[chosen[j]] = 0;
        s0 += sz;
    }
    Py_END_ALLOW_THREADS
    release_bufs(all, 15);
    Py_RETURN_NONE;
}

/* ---------------------------------------------------------------------------------------------- */
/* pieces(indptr, indices, labels, cells, comp) -> number of pieces
 *   the connected pieces of the parts `labels` (an edge joins two nodes of the same label) over all
 *   nodes (cells empty) or over the nodes `cells` (increasing, whole parts: the rows of cells only,
 *   neighbours outside them ignored); comp (len(cells) or n,) int32: each node's piece, pieces
 *   numbered in the order of their first node. */
static inline int64_t find(int64_t *up, int64_t a) {
    while (up[a] != a) {
        up[a] = up[up[a]];
        a = up[a];
    }
    return a;
}

static PyObject *py_pieces(PyObject *self, PyObject *args) {
    Py_buffer b[5];
    const char *names[5] = {"indptr", "indices", "labels", "cells", "comp"};
    Py_ssize_t sizes[5] = {8, 8, 8, 8, 4};
    int wr[5] = {0, 0, 0, 0, 1};
    if (parse_bufs(args, 5, "pieces", names, sizes, wr, b) < 0) return NULL;
    const int64_t *ptr = b[0].buf, *nb = b[1].buf, *lab = b[2].buf, *cells = b[3].buf;
    int32_t *comp = b[4].buf;
    int64_t n = N8(b[2]), nnz = N8(b[1]), mc = N8(b[3]);
    int sub = mc > 0;
    int64_t m = sub ? mc : n;
    int bad = N8(b[0]) != n + 1 || (int64_t)(b[4].len / 4) != m || (n > 0 && (ptr[0] != 0 || ptr[n] != nnz));
    for (int64_t i = 0; i < n && !bad; i++)
        if (ptr[i + 1] < ptr[i]) bad = 1;
    for (int64_t k = 0; k < mc && !bad; k++)
        if (cells[k] < 0 || cells[k] >= n || (k > 0 && cells[k] <= cells[k - 1])) bad = 1;
    if (bad) {
        release_arr(b, 5);
        PyErr_SetString(PyExc_ValueError,
                        "pieces: inconsistent arrays (indptr n+1 non-decreasing, comp n or len(cells), cells increasing)");
        return NULL;
    }
    int64_t nc = 0;
    int err = 0;
    Py_BEGIN_ALLOW_THREADS
    int64_t *up = malloc((size_t)(m > 0 ? m : 1) * sizeof(int64_t));
    int64_t *loc = sub ? malloc((size_t)(n > 0 ? n : 1) * sizeof(int64_t)) : NULL;
    if (!up || (sub && !loc)) err = 1;
    if (!err) {
        if (sub) {
            memset(loc, 0xff, (size_t)n * sizeof(int64_t));
            for (int64_t k = 0; k < m; k++) loc[cells[k]] = k;
        }
        for (int64_t k = 0; k < m; k++) up[k] = k;
        for (int64_t k = 0; k < m; k++) {
            int64_t c = sub ? cells[k] : k;
            int64_t lc = lab[c];
            for (int64_t e = ptr[c]; e < ptr[c + 1]; e++) {
                int64_t v = nb[e];
                if (v < 0 || v >= n || lab[v] != lc) continue;
                int64_t lv = sub ? loc[v] : v;
                if (lv < 0) continue;
                int64_t ra = find(up, k), rb = find(up, lv);
                if (ra != rb) {
                    if (ra < rb) up[rb] = ra;
                    else up[ra] = rb;
                }
            }
        }
        /* roots are the smallest node of their piece (unions keep the smaller root): one pass numbers
         * the pieces by their first node */
        for (int64_t k = 0; k < m; k++) {
            int64_t r = find(up, k);
            comp[k] = r == k ? (int32_t)nc++ : comp[r];
        }
    }
    free(up);
    free(loc);
    Py_END_ALLOW_THREADS
    release_arr(b, 5);
    if (err) return PyErr_NoMemory();
    return PyLong_FromLongLong(nc);
}

/* ---------------------------------------------------------------------------------------------- */
/* cross_edges(indptr, indices, weights, labels, rows, cols, w) -> count
 *   the entries of a CSR graph between different parts of `labels` (< 2^31), in CSR order: their
 *   parts (int32 rows / cols) and weights, written to the first `count` entries of the outputs. */
static PyObject *py_cross_edges(PyObject *self, PyObject *args) {
    Py_buffer b[7];
    const char *names[7] = {"indptr", "indices", "weights", "labels", "rows", "cols", "w"};
    Py_ssize_t sizes[7] = {8, 8, 8, 8, 4, 4, 8};
    int wr[7] = {0, 0, 0, 0, 1, 1, 1};
    if (parse_bufs(args, 7, "cross_edges", names, sizes, wr, b) < 0) return NULL;
    const int64_t *ptr = b[0].buf, *nb = b[1].buf, *lab = b[3].buf;
    const double *wt = b[2].buf;
    int32_t *rows = b[4].buf, *cols = b[5].buf;
    double *wo = b[6].buf;
    int64_t n = N8(b[3]), nnz = N8(b[1]);
    int bad = N8(b[0]) != n + 1 || N8(b[2]) != nnz || (int64_t)(b[4].len / 4) < nnz ||
              (int64_t)(b[5].len / 4) < nnz || N8(b[6]) < nnz || (n > 0 && (ptr[0] != 0 || ptr[n] != nnz));
    for (int64_t i = 0; i < n && !bad; i++)
        if (lab[i] < 0 || lab[i] > INT32_MAX || ptr[i + 1] < ptr[i]) bad = 1;
    for (int64_t e = 0; e < nnz && !bad; e++)
        if (nb[e] < 0 || nb[e] >= n) bad = 1;
    if (bad) {
        release_arr(b, 7);
        PyErr_SetString(PyExc_ValueError, "cross_edges: inconsistent arrays");
        return NULL;
    }
    int64_t c = 0;
    Py_BEGIN_ALLOW_THREADS
    for (int64_t i = 0; i < n; i++) {
        int64_t li = lab[i];
        for (int64_t e = ptr[i]; e < ptr[i + 1]; e++) {
            int64_t lv = lab[nb[e]];
            if (lv == li) continue;
            rows[c] = (int32_t)li;
            cols[c] = (int32_t)lv;
            wo[c++] = wt[e];
        }
    }
    Py_END_ALLOW_THREADS
    release_arr(b, 7);
    return PyLong_FromLongLong(c);
}

/* ---------------------------------------------------------------------------------------------- */
/* loops(key_start, want, nxt, cyc, pos) -> number of loops, or -1
 *   merge_2d's boundary loops: edge i goes on with the edge j whose key_start[j] == want[i] (keys:
 *   element * n_points + vertex). Loops are numbered in the order of their smallest edge and pos
 *   counts from that edge (merge._pair_edges + merge._list_rank). -1 when a start key repeats, a
 *   wanted key is missing or two edges would go on with the same edge: the numpy path decides. */
static PyObject *py_loops(PyObject *self, PyObject *args) {
    Py_buffer b[5];
    const char *names[5] = {"key_start", "want", "nxt", "cyc", "pos"};
    int wr[5] = {0, 0, 1, 1, 1};
    if (parse_bufs(args, 5, "loops", names, NULL, wr, b) < 0) return NULL;
    const int64_t *ks = b[0].buf, *want = b[1].buf;
    int64_t *nxt = b[2].buf, *cyc = b[3].buf, *pos = b[4].buf;
    int64_t m = N8(b[0]);
    if (N8(b[1]) != m || N8(b[2]) != m || N8(b[3]) != m || N8(b[4]) != m) {
        release_arr(b, 5);
        PyErr_SetString(PyExc_ValueError, "loops: arrays of different lengths");
        return NULL;
    }
    int64_t nl = 0;
    int err = 0;
    Py_BEGIN_ALLOW_THREADS
    int64_t cap = 16;
    int bits = 4;
    while (cap < 2 * m) { cap <<= 1; bits++; }
    int64_t *tk = malloc((size_t)cap * 2 * sizeof(int64_t));
    if (!tk) {
        err = 1;
    } else {
        int64_t *tv = tk + cap, mask = cap - 1;
        for (int64_t h = 0; h < cap; h++) tv[h] = -1;
        /* a hash table key_start -> edge (open addressing, linear probing) */
        for (int64_t i = 0; i < m && nl >= 0; i++) {
            uint64_t h = ((uint64_t)ks[i] * 0x9E3779B97F4A7C15ull) >> (64 - bits);  /* the top bits */
            for (;; h++) {
                int64_t s = (int64_t)(h & (uint64_t)mask);
                if (tv[s] < 0) { tk[s] = ks[i]; tv[s] = i; break; }
                if (tk[s] == ks[i]) { nl = -1; break; }  /* a start key repeats */
            }
        }
        for (int64_t i = 0; i < m && nl >= 0; i++) {
            uint64_t h = ((uint64_t)want[i] * 0x9E3779B97F4A7C15ull) >> (64 - bits);
            int64_t j = -1;
            for (;; h++) {
                int64_t s = (int64_t)(h & (uint64_t)mask);
                if (tv[s] < 0) break;
                if (tk[s] == want[i]) { j = tv[s]; break; }
            }
            if (j < 0) nl = -1;  /* an open boundary */
            nxt[i] = j;
            cyc[i] = -1;
        }
        /* every edge the successor of exactly one: a permutation (tv reused as the counts) */
        for (int64_t i = 0; i < m && nl >= 0; i++) tv[i] = 0;
        for (int64_t i = 0; i < m && nl >= 0; i++)
            if (tv[nxt[i]]++) nl = -1;
        for (int64_t i = 0; i < m && nl >= 0; i++) {
            if (cyc[i] >= 0) continue;
            /* i is the smallest edge not yet in a loop, so the smallest of its own loop */
            int64_t j = i, p = 0;
            do {
                cyc[j] = nl;
                pos[j] = p++;
                j = nxt[j];
            } while (j != i);
            nl++;
        }
        free(tk);
    }
    Py_END_ALLOW_THREADS
    release_arr(b, 5);
    if (err) return PyErr_NoMemory();
    return PyLong_FromLongLong(nl);
}

/* ---------------------------------------------------------------------------------------------- */
/* local_pieces(indptr, indices, lab, mark, queue, ku, u, elem, same, budget, epoch, count) -> pieces
 *   The repair's exact checks near one unit (models/hierarchy/repair.py Repair._near): the pieces
 *   of a set X less the node u that hold u's neighbours in X. X: the nodes v < ku with
 *   (lab[v] == elem) == same and, where same == 0, every node >= ku (the outside and the cavities:
 *   reached, never searched from; pieces that reach the same one are one).
 *   u's neighbours in X each start a piece; a breadth-first search from all of them at once joins
 *   pieces where they meet, and a piece whose search has nothing left to visit, and that reached
 *   no node >= ku, is complete (no other can reach it). The answer: the number of pieces, once all
 *   but one are complete or joined (0: u has no neighbour in X); count == 0: 2 as soon as one piece
 *   is complete beside another (two or more, enough to say "in pieces"); -1 where the search passed
 *   `budget` nodes, or ended with two pieces or more that reached nodes >= ku (they may meet through
 *   those: the caller checks the whole graph). budget < 0: u's neighbours in X counted, no search.
 *   mark (n,): epoch << 24 | piece where reached in this call (the caller passes a new epoch each
 *   call, so nothing is cleared; mark starts at -1); queue (n,): scratch. */
static PyObject *py_local_pieces(PyObject *self, PyObject *args) {
    PyObject *o[5];
    long long ku, u, elem, same, budget, epoch, count;
    if (!PyArg_ParseTuple(args, "OOOOOLLLLLLL", &o[0], &o[1], &o[2], &o[3], &o[4], &ku, &u, &elem, &same, &budget,
                          &epoch, &count))
        return NULL;
    Py_buffer b[5];
    Py_buffer *all[5] = {b, b + 1, b + 2, b + 3, b + 4};
    const char *names[5] = {"indptr", "indices", "lab", "mark", "queue"};
    const Py_ssize_t sizes[5] = {8, 8, 8, 8, 8};
    const int wr[5] = {0, 0, 0, 1, 1};
    if (get_bufs(o, all, 5, names, sizes, wr) < 0) return NULL;
    const int64_t *ptr = b[0].buf, *nb = b[1].buf, *lab = b[2].buf;
    int64_t *mark = b[3].buf, *queue = b[4].buf;
    int64_t n = N8(b[0]) - 1, nnz = N8(b[1]);
    if (n < 1 || N8(b[3]) != n || N8(b[4]) != n || ku < 0 || ku > n || N8(b[2]) < ku || u < 0 || u >= n ||
        epoch < 1 || epoch >= ((int64_t)1 << 38)) {
        release_arr(b, 5);
        PyErr_SetString(PyExc_ValueError, "local_pieces: inconsistent arrays or arguments");
        return NULL;
    }
    const int64_t tag = (int64_t)epoch << 24, low = ((int64_t)1 << 24) - 1;
#define IN_X(v) ((v) < ku ? ((lab[v] == elem) == (same != 0)) : (same == 0))
#define ROW_OK(v) ((v) >= 0 && (v) < n && ptr[v] >= 0 && ptr[v] <= ptr[(v) + 1] && ptr[(v) + 1] <= nnz)
#define ROOT(x) ({ int64_t r_ = (x); while (up[r_] != r_) r_ = up[r_] = up[up[r_]]; r_; })
    int64_t result = -1, deg = ROW_OK(u) ? ptr[u + 1] - ptr[u] : -1;
    /* per piece: its parent (union-find), nodes queued and not yet searched from, reached a node >= ku */
    int64_t *up = deg >= 0 ? malloc((size_t)(deg + 1) * 2 * sizeof(int64_t)) : NULL;
    uint8_t *far = deg >= 0 ? calloc((size_t)(deg + 1), 1) : NULL;
    int bad = deg < 0 || !up || !far || deg >= low;
    if (!bad) {
        int64_t *pend = up + deg + 1;
        int64_t g = 0, tail = 0;
        for (int64_t e = ptr[u]; e < ptr[u + 1]; e++) { /* a piece per neighbour in X */
            int64_t v = nb[e];
            if (v < 0 || v >= n) {
                bad = 1;
                break;
            }
            if (v == u || !IN_X(v) || (mark[v] & ~low) == tag) continue;
            mark[v] = tag | g;
            up[g] = g;
            pend[g] = v < ku;
            far[g] = v >= ku;
            if (v < ku) queue[tail++] = v;
            g++;
        }
        int64_t active = g, done = 0; /* pieces still searched; pieces complete */
        if (budget < 0 || active <= 1) result = active;
        for (int64_t head = 0; !bad && result < 0 && head < tail; head++) {
            int64_t v = queue[head];
            if (!ROW_OK(v)) {
                bad = 1;
                break;
            }
            int64_t gv = ROOT(mark[v] & low);
            pend[gv]--;
            for (int64_t e = ptr[v]; e < ptr[v + 1]; e++) {
                int64_t w = nb[e];
                if (w < 0 || w >= n) {
                    bad = 1;
                    break;
                }
                if (w == u || !IN_X(w)) continue;
                if ((mark[w] & ~low) == tag) { /* reached before: its piece and ours are one */
                    int64_t gw = ROOT(mark[w] & low);
                    if (gw != gv) {
                        int64_t lo = gw < gv ? gw : gv, hi = gw < gv ? gv : gw;
                        up[hi] = lo;
                        pend[lo] += pend[hi];
                        far[lo] |= far[hi];
                        gv = lo;
                        active--;
                    }
                    continue;
                }
                mark[w] = tag | gv;
                if (w >= ku) {
                    far[gv] = 1; /* reached, not searched from */
                    continue;
                }
                if (tail >= budget) {
                    result = -2; /* over budget */
                    break;
                }
                queue[tail++] = w;
                pend[gv]++;
            }
            if (result == -2 || bad) break;
            if (pend[gv] == 0 && !far[gv]) { /* nothing left to visit: a whole piece */
                done++;
                active--;
                far[gv] = 1; /* (never counted again) */
            }
            if (active <= 1)
                result = done + active;
            else if (!count && done)
                result = 2;
        }
        if (result == -2)
            result = -1;
        else if (result < 0 && !bad) /* the search ended: every piece left reached a node >= ku */
            result = active <= 1 ? done + active : -1;
    }
#undef IN_X
#undef ROW_OK
#undef ROOT
    int oom = !bad ? 0 : (deg >= 0 && (!up || !far));
    free(up);
    free(far);
    release_arr(b, 5);
    if (oom) return PyErr_NoMemory();
    if (bad) {
        PyErr_SetString(PyExc_ValueError, "local_pieces: a node id out of range");
        return NULL;
    }
    return PyLong_FromLongLong(result);
}

static PyMethodDef methods[] = {
    {"cut_prepare", py_cut_prepare, METH_VARARGS,
     "cut_prepare(P, x, w, a_start, a_size, axis, length, chosen, mid, base, vol) -> active cells: "
     "the first half of one halving step of rtree.split_counts."},
    {"cut_apply", py_cut_apply, METH_VARARGS,
     "cut_apply(P, lh, chosen, mid, a_start, a_size, axis, target, window, m1, m, slack, n0, side, tmp, fscr): "
     "the cuts of one halving step and the stable partition of the axis orders."},
    {"pieces", py_pieces, METH_VARARGS,
     "pieces(indptr, indices, labels, cells, comp) -> number: connected pieces of the parts of labels, "
     "numbered by their first node."},
    {"cross_edges", py_cross_edges, METH_VARARGS,
     "cross_edges(indptr, indices, weights, labels, rows, cols, w) -> count: the entries between "
     "different parts, with their parts and weights."},
    {"local_pieces", py_local_pieces, METH_VARARGS,
     "local_pieces(indptr, indices, lab, mark, queue, ku, u, elem, same, budget, epoch, count) -> pieces of a "
     "set less u holding u's neighbours, or -1 (unknown): the repair's local checks."},
    {"loops", py_loops, METH_VARARGS,
     "loops(key_start, want, nxt, cyc, pos) -> number of loops, or -1: merge_2d's boundary loops."},
    {NULL, NULL, 0, NULL}};

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "_fastgraph",
                                    "Compiled helpers of models.partitioners.rtree (see models/_fastgraph.c).",
                                    -1, methods};

PyMODINIT_FUNC PyInit__fastgraph(void) { return PyModule_Create(&module); }
