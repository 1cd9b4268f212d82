/* Largest inscribed circles of 2D polygonal elements (part of models.quality._fastmetrics; the numpy
 * twin is models/quality/distance.py: _inscribed_bnb, method="bnb-numpy").
 *
 * Each element's boundary is a set of segments (its outer loop and any hole loops, any orientation);
 * the largest inscribed circle is centred at the maximum over the element of f(x) = distance from x
 * to the boundary. Best-first branch and bound over a quadtree of the element's bounding square:
 * every evaluated cell centre gets its exact distance to every segment of the element (brute force:
 * elements hold tens to a few thousand segments) and its inside status by the crossing number over
 * the same segments (even-odd, so holes are outside). A cell's upper bound U of max f over
 * (cell n element) is the smaller of
 *   - 1-Lipschitz: (+-centre distance) + half-diagonal;
 *   - convex combination: for any mu in [0, 1] and two segments s, t, f <= mu d(., s) + (1 - mu) d(., t)
 *     inside the element, a convex function whose maximum over the cell is at a corner; the best mu
 *     for each pair of the K_NEAR segments nearest to the centre (and each single one) is found
 *     exactly (the minimax of four lines in mu). Exact for channels between parallel walls, where
 *     the Lipschitz bound keeps every cell along the ridge.
 * A cell is dropped when U <= best + eps, eps = rel_tol * diameter / 4; the search ends when the
 * largest U in the queue is below that, so
 *   r_true - eps <= r <= r_true
 * (a quarter of the tolerance asked: best-first search stops as soon as the bound allows, where the
 * numpy twin's level-by-level search lands nearer the optimum; at a quarter it is nearer than that,
 * for 12% more time)
 * with r an exact distance from a certified interior point (0 and a NaN centre if none was found:
 * then r_true <= eps).
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include "_buffers.h"
#include "_fastheap.h"
#include <math.h>
#include <stdint.h>
#include <stdlib.h>

#define K_NEAR 4

typedef struct {
    double U, c[2], half, f;
    int32_t near[K_NEAR];
    int nn;
} Cell2;

MAX_HEAP(Heap2, Cell2, heap2)

/* one element's segments: a (x, y), b (x, y) rows of prim (S, 2, 2) from p0, m of them */
typedef struct {
    const double *s; /* (m, 4) */
    int64_t m;
} Segs;

static inline double seg_d2(const double *s, double qx, double qy) {
    double ax = s[0], ay = s[1], dx = s[2] - ax, dy = s[3] - ay;
    double px = qx - ax, py = qy - ay;
    double l2 = dx * dx + dy * dy;
    double t = l2 > 0 ? (px * dx + py * dy) / l2 : 0.0;
    if (t < 0) t = 0;
    else if (t > 1) t = 1;
    double ex = px - t * dx, ey = py - t * dy;
    return ex * ex + ey * ey;
}

/* signed distance at q (positive inside) and its K_NEAR nearest segments (nearest first) */
static double evaluate(const Segs *G, double qx, double qy, int32_t *near, int *nn) {
    double kd[K_NEAR];
    int k = 0, cross = 0;
    for (int64_t i = 0; i < G->m; i++) {
        const double *s = G->s + 4 * i;
        double d2 = seg_d2(s, qx, qy);
        if (k < K_NEAR || d2 < kd[k - 1]) {
            int j = k < K_NEAR ? k++ : K_NEAR - 1;
            while (j > 0 && kd[j - 1] > d2) {
                kd[j] = kd[j - 1];
                near[j] = near[j - 1];
                j--;
            }
            kd[j] = d2;
            near[j] = (int32_t)i;
        }
        double ay = s[1], by = s[3];
        if ((ay > qy) != (by > qy)) {
            double x = s[0] + (qy - ay) * (s[2] - s[0]) / (by - ay);
            if (qx < x) cross ^= 1;
        }
    }
    *nn = k;
    double d = k ? sqrt(kd[0]) : 0.0;
    return cross ? d : -d;
}

/* min over mu in [0, 1] of max_c (mu a_c + (1 - mu) b_c): the lower envelope's minimum of the upper
 * envelope of four lines, at an end or where two lines cross */
static double minimax4(const double *a, const double *b) {
    double best = INFINITY;
    double cand[2 + 6];
    int nc = 0;
    cand[nc++] = 0.0;
    cand[nc++] = 1.0;
    for (int i = 0; i < 4; i++)
        for (int j = i + 1; j < 4; j++) {
            double den = (a[i] - b[i]) - (a[j] - b[j]);
            if (den != 0) {
                double mu = (b[j] - b[i]) / den;
                if (mu > 0 && mu < 1) cand[nc++] = mu;
            }
        }
    for (int c = 0; c < nc; c++) {
        double mu = cand[c], v = -INFINITY;
        for (int i = 0; i < 4; i++) {
            double x = mu * a[i] + (1 - mu) * b[i];
            if (x > v) v = x;
        }
        if (v < best) best = v;
    }
    return best;
}

/* the smallest corner bound over the single nearest segments and their pairs; *pi, *pj the pair
 * with the smallest bound (-1 with fewer than two segments) */
static double pair_bound(const Segs *G, const Cell2 *c, int *pi, int *pj) {
    static const double CX[4] = {-1, 1, -1, 1}, CY[4] = {-1, -1, 1, 1};
    double d[K_NEAR][4];
    double best = INFINITY;
    *pi = *pj = -1;
    for (int j = 0; j < c->nn; j++) {
        double v = 0;
        for (int q = 0; q < 4; q++) {
            d[j][q] = sqrt(seg_d2(G->s + 4 * (int64_t)c->near[j], c->c[0] + CX[q] * c->half, c->c[1] + CY[q] * c->half));
            if (d[j][q] > v) v = d[j][q];
        }
        if (v < best) best = v;
    }
    double pbest = INFINITY;
    for (int i = 0; i < c->nn; i++)
        for (int j = i + 1; j < c->nn; j++) {
            double v = minimax4(d[i], d[j]);
            if (v < pbest) {
                pbest = v;
                *pi = i;
                *pj = j;
            }
        }
    return pbest < best ? pbest : best;
}

static void closest_on(const double *s, double qx, double qy, double *out) {
    double ax = s[0], ay = s[1], dx = s[2] - ax, dy = s[3] - ay;
    double l2 = dx * dx + dy * dy;
    double t = l2 > 0 ? ((qx - ax) * dx + (qy - ay) * dy) / l2 : 0.0;
    if (t < 0) t = 0;
    else if (t > 1) t = 1;
    out[0] = ax + t * dx;
    out[1] = ay + t * dy;
}

typedef struct {
    double best, best_pt[2], eps;
    int64_t evals, max_cells;
} State2;

static void probe(const Segs *G, State2 *S, double x, double y) {
    int32_t near[K_NEAR];
    int nn;
    double f = evaluate(G, x, y, near, &nn);
    S->evals++;
    if (f > S->best) {
        S->best = f;
        S->best_pt[0] = x;
        S->best_pt[1] = y;
    }
}

/* the cell's centre evaluated, the best interior point raised, its bound set; 1 to keep it. Where
 * a pair of segments bounds the cell (a channel between two walls), the point halfway between
 * their closest points (on the ridge between them) is tried too: the lower bound then reaches the
 * ridge's height at once, and the cells along the ridge are dropped instead of refined to eps. */
static int make_cell(const Segs *G, State2 *S, Cell2 *c, double x, double y, double half) {
    c->c[0] = x;
    c->c[1] = y;
    c->half = half;
    c->f = evaluate(G, x, y, c->near, &c->nn);
    S->evals++;
    if (c->f > S->best) {
        S->best = c->f;
        S->best_pt[0] = x;
        S->best_pt[1] = y;
    }
    c->U = c->f + half * M_SQRT2;
    if (c->U <= S->best + S->eps) return 0;
    int pi, pj;
    double u2 = pair_bound(G, c, &pi, &pj);
    if (u2 < c->U) c->U = u2;
    if (pi >= 0 && c->U > S->best + S->eps) {
        double a[2], b[2];
        closest_on(G->s + 4 * (int64_t)c->near[pi], x, y, a);
        closest_on(G->s + 4 * (int64_t)c->near[pj], x, y, b);
        probe(G, S, 0.5 * (a[0] + b[0]), 0.5 * (a[1] + b[1]));
    }
    return c->U > S->best + S->eps;
}

/* 0 done, 1 budget spent, -1 out of memory */
static int search2(const Segs *G, State2 *S, const double *lo, const double *hi, const double *guess, Heap2 *H) {
    H->n = 0;
    Cell2 c;
    if (guess) probe(G, S, guess[0], guess[1]);
    double w = hi[0] - lo[0], h = hi[1] - lo[1];
    double half = 0.5 * (w > h ? w : h) * (1 + 1e-9);
    if (make_cell(G, S, &c, 0.5 * (lo[0] + hi[0]), 0.5 * (lo[1] + hi[1]), half))
        if (heap2_push(H, c) < 0) return -1;
    while (H->n) {
        Cell2 top = heap2_pop(H);
        if (top.U <= S->best + S->eps) break; /* every other cell bounds below it */
        if (S->evals >= S->max_cells) return 1;
        double q = 0.5 * top.half;
        for (int k = 0; k < 4; k++) {
            double x = top.c[0] + ((k & 1) ? q : -q), y = top.c[1] + ((k & 2) ? q : -q);
            if (make_cell(G, S, &c, x, y, q))
                if (heap2_push(H, c) < 0) return -1;
        }
    }
    return 0;
}

/* the area centroid of the element's loops (a first guess; any point will do) */
static int centroid(const Segs *G, double *out) {
    double a = 0, cx = 0, cy = 0, ox = G->s[0], oy = G->s[1];
    for (int64_t i = 0; i < G->m; i++) {
        const double *s = G->s + 4 * i;
        double x0 = s[0] - ox, y0 = s[1] - oy, x1 = s[2] - ox, y1 = s[3] - oy;
        double cr = x0 * y1 - x1 * y0;
        a += cr;
        cx += (x0 + x1) * cr;
        cy += (y0 + y1) * cr;
    }
    if (a == 0 || !isfinite(a)) return 0;
    out[0] = ox + cx / (3 * a);
    out[1] = oy + cy / (3 * a);
    return 1;
}

PyObject *py_inscribed2d(PyObject *self, PyObject *args) {
    PyObject *oP, *optr, *oel, *odiam, *olo, *ohi, *ocen, *orad, *oev;
    double rel_tol;
    long long max_cells;
    if (!PyArg_ParseTuple(args, "OOOOOOdLOOO", &oP, &optr, &oel, &odiam, &olo, &ohi, &rel_tol, &max_cells,
                          &ocen, &orad, &oev))
        return NULL;
    Py_buffer bP, bptr, bel, bdiam, blo, bhi, bcen, brad, bev;
    Py_buffer *all[9] = {&bP, &bptr, &bel, &bdiam, &blo, &bhi, &bcen, &brad, &bev};
    PyObject *objs[9] = {oP, optr, oel, odiam, olo, ohi, ocen, orad, oev};
    const char *names[9] = {"prim", "prim_ptr", "elems", "diameter", "bbox_lo", "bbox_hi",
                            "centres", "radius", "evals"};
    int wr[9] = {0, 0, 0, 0, 0, 0, 1, 1, 1};
    if (get_bufs(objs, all, 9, names, NULL, wr) < 0) return NULL;
    const double *prim = (const double *)bP.buf;
    const int64_t *ptr = (const int64_t *)bptr.buf;
    const int64_t *el = (const int64_t *)bel.buf;
    const double *diam = (const double *)bdiam.buf;
    const double *lo = (const double *)blo.buf, *hi = (const double *)bhi.buf;
    double *cen = (double *)bcen.buf, *rad = (double *)brad.buf;
    int64_t *ev = (int64_t *)bev.buf;
    Py_ssize_t n = bel.len / 8;
    int err = 0;
    Heap2 H = {NULL, 0, 0};
    Py_BEGIN_ALLOW_THREADS
    for (Py_ssize_t i = 0; i < n && !err; i++) {
        int64_t e = el[i];
        Segs G = {prim + 4 * ptr[e], ptr[e + 1] - ptr[e]};
        State2 S = {0.0, {NAN, NAN}, 0.25 * rel_tol * diam[e], 0, max_cells};
        int rc = 0;
        if (G.m > 0 && diam[e] > 0) {
            double g[2];
            rc = search2(&G, &S, lo + 2 * e, hi + 2 * e, centroid(&G, g) ? g : NULL, &H);
            if (rc < 0) { err = 1; break; }
        }
        if (rc == 1) {
            ev[e] = -1;
            continue;
        }
        rad[e] = S.best;
        cen[2 * e] = S.best_pt[0];
        cen[2 * e + 1] = S.best_pt[1];
        ev[e] = S.evals;
    }
    Py_END_ALLOW_THREADS
    free(H.a);
    release_bufs(all, 9);
    if (err) return PyErr_NoMemory();
    Py_RETURN_NONE;
}
