/* Compiled helpers of models/quality/ (each has a numpy twin there: the fallback and the
 * reference in the tests; MAGNET_NO_COMPILED=1 switches them off):
 *   inscribed        the 3D largest-inscribed-ball search (below); inscribed2d the 2D one
 *                    (_fastcircle.c, in this module);
 *   fan3d            _prepare's 3D geometry in one pass per element (triangles in Morton order,
 *                    neighbours across edges, distinct vertices, boxes, area, volume);
 *   farthest_pairs   diameters; locally_convex: convex elements without hulls; tri_table: the
 *                    per-triangle constants; enclosing_balls: exact smallest enclosing balls;
 *   partition_stats  cut, volumes and components of a symmetric CSR (union-find).
 *
 * Largest inscribed balls of 3D polyhedral elements: certified best-first branch and bound. Each
 * element's boundary is a closed set of triangles (outward normals when the element is positively
 * oriented); its largest inscribed ball is centred at the maximum over the element of f(x) =
 * distance from x to the boundary.
 *
 * Per element: an AABB tree over its (Morton-ordered) triangles, then best-first branch and bound
 * over an octree of its bounding cube. Every evaluated cell centre gets its exact distance to the
 * boundary and, when it matters, an exact inside/outside status (side of the closest triangle,
 * edge pseudo-normal, else winding number). A cell's upper bound U of max f over (cell n element):
 *   - 1-Lipschitz: (+-centre distance) + half-diagonal;
 *   - convex combination: for any weights mu on triangles t_i, f <= sum mu_i dist(., t_i), which is
 *     convex, so its maximum over the cell is at a corner; the best mu over the triangles that can
 *     be the nearest somewhere in the cell (within d + 2 rho of its centre, the K_NEAR nearest of
 *     them) comes from a small linear program (a matrix game: corners x triangles) solved by dense
 *     simplex. Exact for planar contacts (ridges, plateaus between parallel walls), second order at
 *     edges and corners.
 * The LP's dual (corner weights) points at the maximiser of that bound; its exact distance, when
 * it is certified inside, raises the lower bound early. A cell is dropped when U <= best + eps,
 * eps = rel_tol * diameter; the search ends when the largest U in the queue is below that, so
 *   r_true - eps <= r <= r_true
 * with r an exact distance from a certified interior point (0 and NaN centre if none was needed).
 *
 * Arrays come through the buffer protocol (no numpy headers at build time).
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include "_buffers.h"
#include "_fastheap.h"
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#ifndef K_NEAR
#define K_NEAR 32 /* nearest triangles found for the LP bound */
#endif
#ifndef K_LP
#define K_LP 32   /* ... of which the LP takes the nearest K_LP */
#endif
#define N_CORNER 8
#ifndef LEAF_SIZE
#define LEAF_SIZE 4
#endif
#define INTERIOR_MARGIN 1e-9
#define MAX_PIVOTS 60

typedef struct {
    double lo[3], hi[3];
    int64_t i0, i1;   /* triangle range (local) */
    int64_t c1, c2;   /* children, -1 for a leaf */
} Node;

typedef struct {
    double U, c[3], half;
    int64_t near;  /* closest triangle of the centre (local id) */
    int64_t list;  /* its K_NEAR nearest triangles in the pool (cells with an LP bound), or -1 */
} Cell;


typedef struct {
    double *T;           /* (m, 16) this element's triangles: a, e0, e1, n, d00, d01, d11, inv */
    int64_t capT;
    const int64_t *adj;  /* (S, 3) */
    int64_t p0, m;       /* first triangle, count */
    Node *nodes;
    int64_t n_nodes, cap_nodes;
    int orient;          /* 1: outward normals */
} Elem;

/* ---------------------------------------------------------------------------------------------- */
/* point - triangle */

static inline double dot3(const double *a, const double *b) { return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]; }

/* constants of triangle P (3 corners) in metrics._prim_table's layout */
static void fill_table(const double *P, double *o) {
    const double *a = P, *b = P + 3, *c = P + 6;
    double e0[3] = {b[0] - a[0], b[1] - a[1], b[2] - a[2]};
    double e1[3] = {c[0] - a[0], c[1] - a[1], c[2] - a[2]};
    double nx = e0[1] * e1[2] - e0[2] * e1[1], ny = e0[2] * e1[0] - e0[0] * e1[2], nz = e0[0] * e1[1] - e0[1] * e1[0];
    double nn = sqrt(nx * nx + ny * ny + nz * nz);
    double inv_n = nn > 0 ? 1.0 / nn : 1.0;
    double d00 = dot3(e0, e0), d01 = dot3(e0, e1), d11 = dot3(e1, e1);
    double det = d00 * d11 - d01 * d01;
    memcpy(o, a, 24);
    memcpy(o + 3, e0, 24);
    memcpy(o + 6, e1, 24);
    o[9] = nx * inv_n; o[10] = ny * inv_n; o[11] = nz * inv_n;
    o[12] = d00; o[13] = d01; o[14] = d11;
    o[15] = det > 1e-14 * d00 * d11 ? 1.0 / det : 0.0;
}

/* the element's table (grown as needed); -1 when out of memory */
static int load_table(double **buf, int64_t *cap, const double *prim, int64_t p0, int64_t m) {
    if (m > *cap) {
        double *nb = (double *)realloc(*buf, (size_t)m * 16 * sizeof(double));
        if (!nb) return -1;
        *buf = nb;
        *cap = m;
    }
    for (int64_t t = 0; t < m; t++) fill_table(prim + 9 * (p0 + t), *buf + 16 * t);
    return 0;
}

/* squared distance from q to the segment s0 + t e, t in [0, 1] (ee = e.e) */
static inline double seg_d2(const double *q, const double *s0, const double *e, double ee) {
    double w0 = q[0] - s0[0], w1 = q[1] - s0[1], w2 = q[2] - s0[2];
    double t = (w0 * e[0] + w1 * e[1] + w2 * e[2]) / (ee > 1e-300 ? ee : 1e-300);
    t = t < 0 ? 0 : (t > 1 ? 1 : t);
    w0 -= t * e[0]; w1 -= t * e[1]; w2 -= t * e[2];
    return w0 * w0 + w1 * w1 + w2 * w2;
}

/* squared distance only. Outside the triangle's projection, the closest point lies on an edge
 * that faces the projected point (negative barycentric coordinate opposite it); a degenerate
 * triangle (inv = 0) tries all three edges. */
static double tri_d2(const double *T, const double *q) {
    double v[3] = {q[0] - T[0], q[1] - T[1], q[2] - T[2]};
    double d20 = dot3(v, T + 3), d21 = dot3(v, T + 6);
    double d00 = T[12], d01 = T[13], d11 = T[14], inv = T[15];
    double bv = (d11 * d20 - d01 * d21) * inv;
    double bw = (d00 * d21 - d01 * d20) * inv;
    double bu = 1.0 - bv - bw;
    if (inv > 0 && bv >= 0 && bw >= 0 && bu >= 0) {
        double h = dot3(v, T + 9);
        return h * h;
    }
    int all = !(inv > 0);
    double best = INFINITY, dd;
    if (all || bw < 0) { dd = seg_d2(q, T, T + 3, d00); if (dd < best) best = dd; }
    if (all || bv < 0) { dd = seg_d2(q, T, T + 6, d11); if (dd < best) best = dd; }
    if (all || bu < 0) {
        double b[3] = {T[0] + T[3], T[1] + T[4], T[2] + T[5]};
        double e[3] = {T[6] - T[3], T[7] - T[4], T[8] - T[5]};
        dd = seg_d2(q, b, e, d00 - 2 * d01 + d11);
        if (dd < best) best = dd;
    }
    return best;
}

/* squared distance with flags: loc 0 interior / 1 rim; edge index on the rim (-1 at a corner);
 * vec = q - closest point; side = q below the plane (h < 0). Same rules as metrics._prim_distance /
 * _rim_closest. */
/* the closest point of the triangle's rim (its three edges, metrics._rim_closest): squared
 * distance, vec = q minus that point, and the edge (0: corners 0-1, 1: 0-2, 2: 1-2) when the point
 * lies strictly inside it (-1 at a corner); the first edge wins ties */
static double rim_closest(const double *T, const double *q, int *edge, double *vec) {
    const double m = INTERIOR_MARGIN;
    double best = INFINITY;
    *edge = -1;
    for (int k = 0; k < 3; k++) {
        double s0[3], e[3], w[3];
        if (k == 0) { memcpy(s0, T, 24); memcpy(e, T + 3, 24); }
        else if (k == 1) { memcpy(s0, T, 24); memcpy(e, T + 6, 24); }
        else { for (int i = 0; i < 3; i++) { s0[i] = T[i] + T[3 + i]; e[i] = T[6 + i] - T[3 + i]; } }
        for (int i = 0; i < 3; i++) w[i] = q[i] - s0[i];
        double ee = dot3(e, e);
        double t = dot3(w, e) / (ee > 1e-300 ? ee : 1e-300);
        double tc = t < 0 ? 0 : (t > 1 ? 1 : t);
        for (int i = 0; i < 3; i++) w[i] -= tc * e[i];
        double dd = dot3(w, w);
        if (dd < best) { best = dd; *edge = (t > m && t < 1 - m) ? k : -1; memcpy(vec, w, 24); }
    }
    return best;
}

static double tri_d2_full(const double *T, const double *q, int *loc, int *edge, double *vec, int *side) {
    double v[3] = {q[0] - T[0], q[1] - T[1], q[2] - T[2]};
    double d20 = dot3(v, T + 3), d21 = dot3(v, T + 6);
    double d00 = T[12], d01 = T[13], d11 = T[14], inv = T[15];
    double bv = (d11 * d20 - d01 * d21) * inv;
    double bw = (d00 * d21 - d01 * d20) * inv;
    double h = dot3(v, T + 9);
    *side = h < 0;
    *edge = -1;
    vec[0] = vec[1] = vec[2] = 0.0;
    const double m = INTERIOR_MARGIN;
    *loc = 1;
    if (!(inv > 0 && bv >= 0 && bw >= 0 && bv + bw <= 1)) return rim_closest(T, q, edge, vec);
    double bu = 1.0 - bv - bw;
    if (bu > m && bv > m && bw > m) {
        *loc = 0;
        for (int i = 0; i < 3; i++) vec[i] = h * T[9 + i];
    } else {  /* on the rim within the margin: the rim's closest point decides */
        rim_closest(T, q, edge, vec);
    }
    return h * h;
}

/* ---------------------------------------------------------------------------------------------- */
/* per-element AABB tree over consecutive (Morton-ordered) triangles */

static int64_t build_node(Elem *E, int64_t i0, int64_t i1) {
    if (E->n_nodes >= E->cap_nodes) {
        int64_t cap = E->cap_nodes ? 2 * E->cap_nodes : 64;
        Node *nn = (Node *)realloc(E->nodes, (size_t)cap * sizeof(Node));
        if (!nn) return -1;
        E->nodes = nn;
        E->cap_nodes = cap;
    }
    int64_t id = E->n_nodes++;
    Node *N = &E->nodes[id];
    for (int k = 0; k < 3; k++) { N->lo[k] = INFINITY; N->hi[k] = -INFINITY; }
    for (int64_t t = i0; t < i1; t++) {
        const double *T = E->T + 16 * (t);
        for (int k = 0; k < 3; k++) {
            double a = T[k], b = T[k] + T[3 + k], c = T[k] + T[6 + k];
            double lo = a < b ? a : b, hi = a > b ? a : b;
            lo = lo < c ? lo : c; hi = hi > c ? hi : c;
            if (lo < N->lo[k]) N->lo[k] = lo;
            if (hi > N->hi[k]) N->hi[k] = hi;
        }
    }
    N->i0 = i0; N->i1 = i1; N->c1 = N->c2 = -1;
    if (i1 - i0 > LEAF_SIZE) {
        int64_t mid = (i0 + i1) / 2;
        int64_t a = build_node(E, i0, mid);
        if (a < 0) return -1;
        int64_t b = build_node(E, mid, i1);
        if (b < 0) return -1;
        E->nodes[id].c1 = a;  /* E->nodes may have moved: index, not the old pointer */
        E->nodes[id].c2 = b;
    }
    return id;
}

static inline double box_d2(const Node *N, const double *q) {
    double s = 0;
    for (int k = 0; k < 3; k++) {
        double d = 0;
        if (q[k] < N->lo[k]) d = N->lo[k] - q[k];
        else if (q[k] > N->hi[k]) d = q[k] - N->hi[k];
        s += d * d;
    }
    return s;
}

typedef struct {
    int n;
    double d2[K_NEAR];
    int64_t t[K_NEAR];
} KBest;

/* the K_NEAR nearest triangles of a cell's centre; every other triangle lies at least R from it */
typedef struct {
    double R;
    int n;
    int64_t t[K_NEAR];
} List;

typedef struct {
    List *a;
    int64_t n, cap;
} Pool;

static int64_t pool_add(Pool *P, const KBest *B, double R) {
    if (P->n >= P->cap) {
        int64_t cap = P->cap ? 2 * P->cap : 256;
        List *na = (List *)realloc(P->a, (size_t)cap * sizeof(List));
        if (!na) return -1;
        P->a = na;
        P->cap = cap;
    }
    List *L = &P->a[P->n];
    L->R = R;
    L->n = B->n;
    memcpy(L->t, B->t, (size_t)B->n * sizeof(int64_t));
    return P->n++;
}

static inline void kbest_push(KBest *B, int k, double d2, int64_t t) {
    if (B->n == k && d2 >= B->d2[k - 1]) return;
    int i = B->n < k ? B->n++ : k - 1;
    while (i > 0 && B->d2[i - 1] > d2) { B->d2[i] = B->d2[i - 1]; B->t[i] = B->t[i - 1]; i--; }
    B->d2[i] = d2; B->t[i] = t;
}

/* the k nearest triangles (local ids) of q, by squared distance */
/* the k nearest triangles (local ids) of q within sqrt(r2max), by squared distance */
static void knearest(const Elem *E, const double *q, int k, KBest *B, double r2max) {
    int64_t stack[128];
    double sd[128];  /* the nodes' box distances (squared), computed once */
    int sp = 0;
    stack[0] = 0;
    sd[0] = box_d2(&E->nodes[0], q);
    sp = 1;
    while (sp) {
        sp--;
        double lim = B->n == k ? B->d2[k - 1] : r2max;
        if (sd[sp] > lim) continue;
        const Node *N = &E->nodes[stack[sp]];
        if (N->c1 < 0) {
            for (int64_t t = N->i0; t < N->i1; t++) {
                const double *T = E->T + 16 * (t);
                /* the distance to the triangle's plane bounds it from below */
                double h = (q[0] - T[0]) * T[9] + (q[1] - T[1]) * T[10] + (q[2] - T[2]) * T[11];
                if (h * h > lim) continue;
                double d2 = tri_d2(T, q);
                if (d2 <= r2max) kbest_push(B, k, d2, t);
                lim = B->n == k ? B->d2[k - 1] : r2max;
            }
        } else {
            int64_t a = N->c1, b = N->c2;
            double da = box_d2(&E->nodes[a], q), db = box_d2(&E->nodes[b], q);
            if (sp + 2 > 128) continue; /* cannot happen for depth < 64 */
            if (da < db) {
                if (db <= lim) { stack[sp] = b; sd[sp++] = db; }
                if (da <= lim) { stack[sp] = a; sd[sp++] = da; }
            } else {
                if (da <= lim) { stack[sp] = a; sd[sp++] = da; }
                if (db <= lim) { stack[sp] = b; sd[sp++] = db; }
            }
        }
    }
}

/* ---------------------------------------------------------------------------------------------- */
/* inside / outside */

static int winding_inside(const Elem *E, const double *q) {
    double w = 0;
    for (int64_t t = 0; t < E->m; t++) {
        const double *T = E->T + 16 * (t);
        double A[3], B[3], C[3];
        for (int i = 0; i < 3; i++) {
            A[i] = T[i] - q[i];
            B[i] = T[i] + T[3 + i] - q[i];
            C[i] = T[i] + T[6 + i] - q[i];
        }
        double la = sqrt(dot3(A, A)), lb = sqrt(dot3(B, B)), lc = sqrt(dot3(C, C));
        double bc[3] = {B[1] * C[2] - B[2] * C[1], B[2] * C[0] - B[0] * C[2], B[0] * C[1] - B[1] * C[0]};
        double num = dot3(A, bc);
        double den = la * lb * lc + dot3(A, B) * lc + dot3(A, C) * lb + dot3(B, C) * la;
        w += 2.0 * atan2(num, den);
    }
    return fabs(w) > 2.0 * M_PI;
}

/* +1 inside / -1 outside for q whose closest triangle is t (local id), see metrics._classify */
static int classify(const Elem *E, const double *q, int64_t t) {
    const double *T = E->T + 16 * (t);
    int loc, edge, side;
    double vec[3];
    double d2 = tri_d2_full(T, q, &loc, &edge, vec, &side);
    if (loc == 0) return (side == E->orient) ? 1 : -1;
    if (edge >= 0) {
        int64_t other = E->adj[3 * (E->p0 + t) + edge];
        if (other >= 0) {
            const double *T2 = E->T + 16 * (other - E->p0);
            double ns[3] = {T[9] + T2[9], T[10] + T2[10], T[11] + T2[11]};
            double s = dot3(vec, ns);
            if (fabs(s) > 1e-9 * sqrt(d2) * sqrt(dot3(ns, ns))) {
                int e = s < 0 ? 1 : -1;
                return E->orient ? e : -e;
            }
        }
    }
    return winding_inside(E, q) ? 1 : -1;
}

/* ---------------------------------------------------------------------------------------------- */
/* LP bound: min over mu in the simplex of max_j sum_i mu_i A[j][i] (corners j, triangles i) */

/* A (nc x k) with positive entries; returns the bound (already valid: recomputed from mu) and the
 * corner weights lambda (dual) in lam[nc]. */
static double game_bound(const double *A, int nc, int k, double *lam) {
    /* maximise sum y s.t. A y <= 1, y >= 0; tableau rows nc, columns k + nc + 1 */
    double tab[N_CORNER + 1][K_LP + N_CORNER + 1];
    int basis[N_CORNER];
    int ncol = k + nc;
    for (int j = 0; j < nc; j++) {
        for (int i = 0; i < k; i++) tab[j][i] = A[j * k + i];
        for (int s = 0; s < nc; s++) tab[j][k + s] = (s == j);
        tab[j][ncol] = 1.0;
        basis[j] = k + j;
    }
    for (int i = 0; i < ncol; i++) tab[nc][i] = i < k ? -1.0 : 0.0;
    tab[nc][ncol] = 0.0;
    for (int it = 0; it < MAX_PIVOTS; it++) {
        int pc = -1;
        double most = -1e-12;
        for (int i = 0; i < ncol; i++)
            if (tab[nc][i] < most) { most = tab[nc][i]; pc = i; }
        if (pc < 0) break;
        int pr = -1;
        double ratio = INFINITY;
        for (int j = 0; j < nc; j++)
            if (tab[j][pc] > 1e-12) {
                double r = tab[j][ncol] / tab[j][pc];
                if (r < ratio) { ratio = r; pr = j; }
            }
        if (pr < 0) break; /* unbounded cannot happen with positive A */
        double p = tab[pr][pc];
        for (int i = 0; i <= ncol; i++) tab[pr][i] /= p;
        for (int j = 0; j <= nc; j++) {
            if (j == pr) continue;
            double f = tab[j][pc];
            if (f != 0.0)
                for (int i = 0; i <= ncol; i++) tab[j][i] -= f * tab[pr][i];
        }
        basis[pr] = pc;
    }
    double y[K_LP] = {0};
    double sy = 0;
    for (int j = 0; j < nc; j++)
        if (basis[j] < k && tab[j][ncol] > 0) y[basis[j]] = tab[j][ncol];
    for (int i = 0; i < k; i++) sy += y[i];
    double sl = 0;
    for (int j = 0; j < nc; j++) { lam[j] = tab[nc][k + j] > 0 ? tab[nc][k + j] : 0; sl += lam[j]; }
    for (int j = 0; j < nc; j++) lam[j] = sl > 0 ? lam[j] / sl : 1.0 / nc;
    if (sy <= 0) return INFINITY;
    double bound = 0;
    for (int j = 0; j < nc; j++) {
        double s = 0;
        for (int i = 0; i < k; i++) s += A[j * k + i] * y[i];
        s /= sy;
        if (s > bound) bound = s;
    }
    return bound;
}

/* ---------------------------------------------------------------------------------------------- */
/* best-first branch and bound for one element */

MAX_HEAP(Heap, Cell, heap)

typedef struct {
    double best, best_pt[3], eps, diam;
    int64_t evals, max_cells, lps;
    int failed;
} State;

/* exact distance and status at q; updates the best interior point */
static double probe(const Elem *E, State *S, const double *q, KBest *B, int k, int *status) {
    knearest(E, q, k, B, INFINITY);  /* B may come seeded (B->n = 1: a triangle and its distance) */
    double d = sqrt(B->d2[0]);
    S->evals++;
    *status = 0;
    return d;
}

static void take(const Elem *E, State *S, const double *q, double d, const KBest *B, int *status) {
    if (*status == 0) *status = classify(E, q, B->t[0]);
    if (*status == 1 && d > S->best) {
        S->best = d;
        memcpy(S->best_pt, q, 24);
    }
}

static const double CORNERS[8][3] = {{-1, -1, -1}, {-1, -1, 1}, {-1, 1, -1}, {-1, 1, 1},
                                     {1, -1, -1},  {1, -1, 1},  {1, 1, -1},  {1, 1, 1}};

/* upper bound of the cell from the LP over its corners; may raise the best via the dual point */
static double lp_bound(const Elem *E, State *S, const double *c, double half, const KBest *B) {
    int k = B->n < K_LP ? B->n : K_LP;
    double A[N_CORNER * K_LP], lam[N_CORNER];
    double shift = 1e-6 * S->diam + 1e-300;
    for (int j = 0; j < N_CORNER; j++) {
        double q[3] = {c[0] + half * CORNERS[j][0], c[1] + half * CORNERS[j][1], c[2] + half * CORNERS[j][2]};
        for (int i = 0; i < k; i++) A[j * k + i] = sqrt(tri_d2(E->T + 16 * (B->t[i]), q)) + shift;
    }
    double U = game_bound(A, N_CORNER, k, lam) - shift;
    U += 1e-12 * S->diam;  /* rounding */
    if (U > S->best + S->eps) {
        /* the maximiser of the bound's game: a candidate interior point */
        double x[3] = {0, 0, 0};
        for (int j = 0; j < N_CORNER; j++)
            for (int a = 0; a < 3; a++) x[a] += lam[j] * (c[a] + half * CORNERS[j][a]);
        KBest B2;
        int st;
        B2.n = 0;
        double d = probe(E, S, x, &B2, 1, &st);
        if (d > S->best) take(E, S, x, d, &B2, &st);
    }
    return U;
}

static int search(Elem *E, State *S, const double *lo, const double *hi, Heap *H, Pool *P) {
    double c0[3], side = 0;
    for (int a = 0; a < 3; a++) {
        c0[a] = 0.5 * (lo[a] + hi[a]);
        double s = hi[a] - lo[a];
        if (s > side) side = s;
    }
    side *= 1 + 1e-9;
    H->n = 0;
    P->n = 0;
    Cell root = {INFINITY, {c0[0], c0[1], c0[2]}, 0.5 * side, -1, -1};
    if (heap_push(H, root)) return -1;
    const double sq3 = sqrt(3.0);
    int64_t cells = 0;
    while (H->n) {
        Cell cur = heap_pop(H);
        if (cur.U <= S->best + S->eps) break;
        double h = 0.5 * cur.half;
        double rho = sq3 * h;
        for (int ch = 0; ch < 8; ch++) {
            double q[3] = {cur.c[0] + h * CORNERS[ch][0], cur.c[1] + h * CORNERS[ch][1], cur.c[2] + h * CORNERS[ch][2]};
            KBest B;
            int st;
            B.n = 0;
            double d;
            if (cur.list >= 0) {
                /* the parent's nearest triangles: the nearest of them bounds the distance from
                 * above, and is the nearest of all when nothing unlisted can be nearer */
                const List *L = &P->a[cur.list];
                double best2 = INFINITY;
                int64_t bt = L->t[0];
                for (int i = 0; i < L->n; i++) {
                    const double *T = E->T + 16 * (L->t[i]);
                    double hh = (q[0] - T[0]) * T[9] + (q[1] - T[1]) * T[10] + (q[2] - T[2]) * T[11];
                    if (hh * hh >= best2) continue;
                    double d2 = tri_d2(T, q);
                    if (d2 < best2) { best2 = d2; bt = L->t[i]; }
                }
                d = sqrt(best2);
                if (d + rho <= S->best + S->eps) continue;
                B.n = 1; B.d2[0] = best2; B.t[0] = bt;
                if (!(d <= L->R - rho)) d = probe(E, S, q, &B, 1, &st);
                else st = 0;
            } else {
                if (cur.near >= 0) {  /* the parent's closest triangle bounds the distance from above */
                    double dh2 = tri_d2(E->T + 16 * (cur.near), q);
                    if (sqrt(dh2) + rho <= S->best + S->eps) continue;
                    B.n = 1; B.d2[0] = dh2; B.t[0] = cur.near;
                }
                d = probe(E, S, q, &B, 1, &st);
            }
            if (d + rho <= S->best + S->eps) continue;
            take(E, S, q, d, &B, &st);
            double U = (st == 1 ? d : -d) + rho;
            if (U <= S->best + S->eps) continue;
            int64_t li = -1;
            double listR = INFINITY;
            if (rho < d) {
                /* the triangles that can be the nearest somewhere in the cell (within d + 2 rho
                 * of its centre): the others never help the bound */
                double reach = d + 2.0 * rho;
                reach *= 1 + 1e-12;
                B.n = 0;
                knearest(E, q, K_NEAR, &B, reach * reach);
                listR = B.n == K_NEAR ? sqrt(B.d2[K_NEAR - 1]) : reach;
                S->lps++;
                double U2 = lp_bound(E, S, q, h, &B);
                if (U2 < U) U = U2;
                if (U <= S->best + S->eps) continue;
                li = pool_add(P, &B, listR);
                if (li < 0) return -1;
            }
            Cell c = {U, {q[0], q[1], q[2]}, h, B.t[0], li};
            if (heap_push(H, c)) return -1;
            if (++cells > S->max_cells) { S->failed = 1; return 0; }
        }
    }
    return 0;
}

/* ---------------------------------------------------------------------------------------------- */
/* Python entry */

static PyObject *py_inscribed(PyObject *self, PyObject *args) {
    PyObject *oT, *oadj, *optr, *oel, *odiam, *olo, *ohi, *oor, *ocen, *orad, *oev;
    double rel_tol;
    long long max_cells;
    if (!PyArg_ParseTuple(args, "OOOOOOOOdLOOO", &oT, &oadj, &optr, &oel, &odiam, &olo, &ohi, &oor,
                          &rel_tol, &max_cells, &ocen, &orad, &oev))
        return NULL;
    Py_buffer bT, badj, bptr, bel, bdiam, blo, bhi, bor, bcen, brad, bev;
    Py_buffer *all[11] = {&bT, &badj, &bptr, &bel, &bdiam, &blo, &bhi, &bor, &bcen, &brad, &bev};
    PyObject *objs[11] = {oT, oadj, optr, oel, odiam, olo, ohi, oor, ocen, orad, oev};
    const char *names[11] = {"prim", "tri_adj", "prim_ptr", "elems", "diameter", "bbox_lo", "bbox_hi",
                             "orient", "centres", "radius", "evals"};
    Py_ssize_t sizes[11] = {8, 8, 8, 8, 8, 8, 8, 1, 8, 8, 8};
    int wr[11] = {0, 0, 0, 0, 0, 0, 0, 0, 1, 1, 1};
    if (get_bufs(objs, all, 11, names, sizes, wr) < 0) return NULL;
    const double *prim = (const double *)bT.buf;
    const int64_t *adj = (const int64_t *)badj.buf;
    const int64_t *ptr = (const int64_t *)bptr.buf;
    const int64_t *el = (const int64_t *)bel.buf;
    const double *diam = (const double *)bdiam.buf;
    const double *lo = (const double *)blo.buf, *hi = (const double *)bhi.buf;
    const uint8_t *orient = (const uint8_t *)bor.buf;
    double *cen = (double *)bcen.buf, *rad = (double *)brad.buf;
    int64_t *ev = (int64_t *)bev.buf;
    Py_ssize_t n = bel.len / 8;
    int err = 0;
    Elem E = {NULL, 0, adj, 0, 0, NULL, 0, 0, 1};
    Heap H = {NULL, 0, 0};
    Pool P = {NULL, 0, 0};
    Py_BEGIN_ALLOW_THREADS
    for (Py_ssize_t i = 0; i < n && !err; i++) {
        int64_t e = el[i];
        E.p0 = ptr[e];
        E.m = ptr[e + 1] - ptr[e];
        E.orient = orient[e] != 0;
        E.n_nodes = 0;
        State S = {0.0, {NAN, NAN, NAN}, rel_tol * diam[e], diam[e], 0, max_cells, 0, 0};
        if (E.m > 0 && diam[e] > 0) {
            if (load_table(&E.T, &E.capT, prim, E.p0, E.m) < 0) { err = 1; break; }
            if (build_node(&E, 0, E.m) < 0) { err = 1; break; }
            if (search(&E, &S, lo + 3 * e, hi + 3 * e, &H, &P) < 0) { err = 1; break; }
        }
        if (S.failed) {
            ev[e] = -1;
            continue;
        }
        rad[e] = S.best;
        for (int a = 0; a < 3; a++) cen[3 * e + a] = S.best_pt[a];
        ev[e] = S.evals + (S.lps << 32);
    }
    Py_END_ALLOW_THREADS
    free(E.nodes);
    free(E.T);
    free(H.a);
    free(P.a);
    release_bufs(all, 11);
    if (err) return PyErr_NoMemory();
    Py_RETURN_NONE;
}

/* farthest pair of each point set (rows v_ptr[e]..v_ptr[e+1] of pts (n, 3)): brute force over
 * pairs, which the hot loop does in a few ns each (a few hundred boundary points per element) */
static PyObject *py_farthest_pairs(PyObject *self, PyObject *args) {
    PyObject *op, *optr, *oi, *oj, *od;
    if (!PyArg_ParseTuple(args, "OOOOO", &op, &optr, &oi, &oj, &od)) return NULL;
    Py_buffer bp, bptr, bi, bj, bd;
    Py_buffer *all[5] = {&bp, &bptr, &bi, &bj, &bd};
    PyObject *objs[5] = {op, optr, oi, oj, od};
    const char *names[5] = {"points", "v_ptr", "first", "second", "diameter"};
    int wr[5] = {0, 0, 1, 1, 1};
    if (get_bufs(objs, all, 5, names, NULL, wr) < 0) return NULL;
    const double *P = (const double *)bp.buf;
    const int64_t *ptr = (const int64_t *)bptr.buf;
    int64_t *fi = (int64_t *)bi.buf, *fj = (int64_t *)bj.buf;
    double *dd = (double *)bd.buf;
    Py_ssize_t n = bptr.len / 8 - 1;
    Py_BEGIN_ALLOW_THREADS
    for (Py_ssize_t e = 0; e < n; e++) {
        int64_t a = ptr[e], b = ptr[e + 1], bi_ = a, bj_ = a;
        double best = -1.0;
        for (int64_t i = a; i < b; i++) {
            double x = P[3 * i], y = P[3 * i + 1], z = P[3 * i + 2];
            for (int64_t j = i + 1; j < b; j++) {
                double dx = P[3 * j] - x, dy = P[3 * j + 1] - y, dz = P[3 * j + 2] - z;
                double d2 = dx * dx + dy * dy + dz * dz;
                if (d2 > best) { best = d2; bi_ = i; bj_ = j; }
            }
        }
        fi[e] = bi_ - a;
        fj[e] = bj_ - a;
        dd[e] = best > 0 ? sqrt(best) : 0.0;
    }
    Py_END_ALLOW_THREADS
    release_bufs(all, 5);
    Py_RETURN_NONE;
}

/* locally convex elements: every edge shared (tri_adj >= 0) and the neighbour's corners on the
 * inner side of each triangle's plane (outward = sign * normal), to tol[e] */
static PyObject *py_locally_convex(PyObject *self, PyObject *args) {
    PyObject *oT, *oadj, *optr, *osg, *otol, *oout;
    if (!PyArg_ParseTuple(args, "OOOOOO", &oT, &oadj, &optr, &osg, &otol, &oout)) return NULL;
    Py_buffer bT, badj, bptr, bsg, btol, bout;
    Py_buffer *all[6] = {&bT, &badj, &bptr, &bsg, &btol, &bout};
    PyObject *objs[6] = {oT, oadj, optr, osg, otol, oout};
    const char *names[6] = {"prim", "tri_adj", "prim_ptr", "sign", "tol", "out"};
    Py_ssize_t sizes[6] = {8, 8, 8, 8, 8, 1};
    int wr[6] = {0, 0, 0, 0, 0, 1};
    if (get_bufs(objs, all, 6, names, sizes, wr) < 0) return NULL;
    const double *T = (const double *)bT.buf;
    const int64_t *adj = (const int64_t *)badj.buf, *ptr = (const int64_t *)bptr.buf;
    const double *sg = (const double *)bsg.buf, *tol = (const double *)btol.buf;
    uint8_t *out = (uint8_t *)bout.buf;
    Py_ssize_t n = bptr.len / 8 - 1;
    Py_BEGIN_ALLOW_THREADS
    for (Py_ssize_t e = 0; e < n; e++) {
        int ok = ptr[e + 1] > ptr[e];
        for (int64_t t = ptr[e]; t < ptr[e + 1] && ok; t++) {
            double A[16];
            fill_table(T + 9 * t, A);
            double nx = sg[e] * A[9], ny = sg[e] * A[10], nz = sg[e] * A[11];
            double off = nx * A[0] + ny * A[1] + nz * A[2];
            for (int k = 0; k < 3 && ok; k++) {
                int64_t o = adj[3 * t + k];
                if (o < 0) { ok = 0; break; }
                const double *B = T + 9 * o;  /* the neighbour's corners */
                for (int c = 0; c < 3; c++)
                    if (nx * B[3 * c] + ny * B[3 * c + 1] + nz * B[3 * c + 2] - off > tol[e]) { ok = 0; break; }
            }
        }
        out[e] = (uint8_t)ok;
    }
    Py_END_ALLOW_THREADS
    release_bufs(all, 6);
    Py_RETURN_NONE;
}

/* per-triangle constants (metrics._prim_table's layout) of prim (S, 3, 3) */
static PyObject *py_tri_table(PyObject *self, PyObject *args) {
    PyObject *op, *ot;
    if (!PyArg_ParseTuple(args, "OO", &op, &ot)) return NULL;
    Py_buffer bp, bt;
    Py_buffer *all[2] = {&bp, &bt};
    PyObject *objs[2] = {op, ot};
    const char *names[2] = {"prim", "table"};
    int wr[2] = {0, 1};
    if (get_bufs(objs, all, 2, names, NULL, wr) < 0) return NULL;
    const double *P = (const double *)bp.buf;
    double *T = (double *)bt.buf;
    Py_ssize_t S = bp.len / 72;
    Py_BEGIN_ALLOW_THREADS
    for (Py_ssize_t t = 0; t < S; t++) fill_table(P + 9 * t, T + 16 * t);
    Py_END_ALLOW_THREADS
    release_bufs(all, 2);
    Py_RETURN_NONE;
}

typedef struct {
    int64_t lo, hi;  /* the edge's node ids (lo < hi), lo = -1: empty */
    int64_t s1, s2;  /* the first two half-edges (3 * triangle + edge) */
    int count, f1, f2;
} EdgeSlot;

/* metrics._triangle_neighbours for one element: the triangle across edge k (0: corners 0-1, 1:
 * 0-2, 2: 1-2) when exactly two consistently oriented triangles of the element share it, else -1.
 * tn (m, 3): the element's triangles' node ids, written to adj rows s0.. with global ids s0 + r.
 * The edges go into an open-addressing hash table (linear probing), grown as needed. */
static int edge_neighbours(const int64_t *tn, int64_t m, int64_t s0, int64_t *adj, EdgeSlot **tab, int64_t *cap) {
    static const int EU[3] = {0, 0, 1}, EV[3] = {1, 2, 2}, FWD[3] = {1, -1, 1};
    int64_t hs = 16;
    while (hs < 4 * m) hs *= 2;  /* ~1.5 edges a triangle: load below 0.4 */
    if (hs > *cap) {
        EdgeSlot *nt = (EdgeSlot *)realloc(*tab, (size_t)hs * sizeof(EdgeSlot));
        if (!nt) return -1;
        *tab = nt;
        *cap = hs;
    }
    EdgeSlot *T = *tab;
    for (int64_t i = 0; i < hs; i++) T[i].lo = -1;
    uint64_t mask = (uint64_t)hs - 1;
    for (int64_t r = 0; r < m; r++) {
        int64_t tg = s0 + r;
        for (int k = 0; k < 3; k++) {
            int64_t u = tn[3 * r + EU[k]], v = tn[3 * r + EV[k]];
            int64_t lo = u < v ? u : v, hi = u < v ? v : u;
            int f = u < v ? FWD[k] : -FWD[k];
            adj[3 * tg + k] = -1;
            uint64_t h = ((uint64_t)lo * 0x9E3779B97F4A7C15ULL) ^ ((uint64_t)hi * 0xC2B2AE3D27D4EB4FULL);
            h ^= h >> 29;
            uint64_t j = h & mask;
            while (T[j].lo >= 0 && (T[j].lo != lo || T[j].hi != hi)) j = (j + 1) & mask;
            EdgeSlot *E = &T[j];
            if (E->lo < 0) {
                E->lo = lo; E->hi = hi; E->count = 1; E->s1 = 3 * tg + k; E->f1 = f;
            } else {
                if (E->count == 1) { E->s2 = 3 * tg + k; E->f2 = f; }
                E->count++;
            }
        }
    }
    for (int64_t i = 0; i < hs; i++) {
        EdgeSlot *E = &T[i];
        if (E->lo >= 0 && E->count == 2 && E->f1 != E->f2) {
            adj[E->s1] = E->s2 / 3;
            adj[E->s2] = E->s1 / 3;
        }
    }
    return 0;
}

/* ball through the k+1 points q[0..k] (k <= 3) with its centre in their affine hull: metrics.
 * _circumballs for one set; returns 0 when they are affinely dependent */
static int circumball(const double (*q)[3], int k, double *c, double *r2) {
    if (k == 0) { memcpy(c, q[0], 24); *r2 = 0; return 1; }
    double A[3][3], G[3][3], rhs[3], lam[3] = {0, 0, 0};
    for (int i = 0; i < k; i++)
        for (int a = 0; a < 3; a++) A[i][a] = q[i + 1][a] - q[0][a];
    double scale = 1;
    for (int i = 0; i < k; i++) {
        for (int j = 0; j < k; j++) G[i][j] = dot3(A[i], A[j]);
        rhs[i] = 0.5 * G[i][i];
        scale *= G[i][i];
    }
    double det;
    if (k == 1) {
        det = G[0][0];
        if (!(fabs(det) > 1e-12 * scale)) return 0;
        lam[0] = rhs[0] / G[0][0];
    } else if (k == 2) {
        det = G[0][0] * G[1][1] - G[0][1] * G[1][0];
        if (!(fabs(det) > 1e-12 * scale)) return 0;
        lam[0] = (rhs[0] * G[1][1] - G[0][1] * rhs[1]) / det;
        lam[1] = (G[0][0] * rhs[1] - G[1][0] * rhs[0]) / det;
    } else {
        double c00 = G[1][1] * G[2][2] - G[1][2] * G[2][1];
        double c01 = G[1][2] * G[2][0] - G[1][0] * G[2][2];
        double c02 = G[1][0] * G[2][1] - G[1][1] * G[2][0];
        det = G[0][0] * c00 + G[0][1] * c01 + G[0][2] * c02;
        if (!(fabs(det) > 1e-12 * scale)) return 0;
        /* Cramer's rule */
        double M[3][3];
        for (int col = 0; col < 3; col++) {
            memcpy(M, G, sizeof(M));
            for (int r = 0; r < 3; r++) M[r][col] = rhs[r];
            double d = M[0][0] * (M[1][1] * M[2][2] - M[1][2] * M[2][1]) -
                       M[0][1] * (M[1][0] * M[2][2] - M[1][2] * M[2][0]) +
                       M[0][2] * (M[1][0] * M[2][1] - M[1][1] * M[2][0]);
            lam[col] = d / det;
        }
    }
    double off[3] = {0, 0, 0};
    for (int i = 0; i < k; i++)
        for (int a = 0; a < 3; a++) off[a] += lam[i] * A[i][a];
    for (int a = 0; a < 3; a++) c[a] = q[0][a] + off[a];
    *r2 = dot3(off, off);
    return 1;
}

/* exact smallest enclosing balls (metrics._enclosing_balls: pivoting from the first two points,
 * each step the smallest ball of the support and the farthest point outside, found by
 * enumerating supports of the <= 5 points), then the radius as the farthest point's distance */
static PyObject *py_enclosing_balls(PyObject *self, PyObject *args) {
    PyObject *op, *optr, *oc, *or_;
    if (!PyArg_ParseTuple(args, "OOOO", &op, &optr, &oc, &or_)) return NULL;
    Py_buffer bp, bptr, bc, br;
    Py_buffer *all[4] = {&bp, &bptr, &bc, &br};
    PyObject *objs[4] = {op, optr, oc, or_};
    const char *names[4] = {"points", "ptr", "centre", "radius"};
    int wr[4] = {0, 0, 1, 1};
    if (get_bufs(objs, all, 4, names, NULL, wr) < 0) return NULL;
    const double *P = (const double *)bp.buf;
    const int64_t *ptr = (const int64_t *)bptr.buf;
    double *C = (double *)bc.buf, *R = (double *)br.buf;
    Py_ssize_t ne = bptr.len / 8 - 1;
    Py_BEGIN_ALLOW_THREADS
    for (Py_ssize_t e = 0; e < ne; e++) {
        int64_t a = ptr[e], n = ptr[e + 1] - ptr[e];
        const double (*X)[3] = (const double (*)[3])(P + 3 * a);
        if (n == 0) { C[3 * e] = C[3 * e + 1] = C[3 * e + 2] = 0; R[e] = 0; continue; }
        double sup[4][3], c[3], rr;
        int ns;
        if (n > 1) {
            memcpy(sup[0], X[0], 24); memcpy(sup[1], X[1], 24); ns = 2;
            for (int k = 0; k < 3; k++) c[k] = 0.5 * (X[0][k] + X[1][k]);
        } else {
            memcpy(sup[0], X[0], 24); ns = 1;
            memcpy(c, X[0], 24);
        }
        double d0[3] = {X[0][0] - c[0], X[0][1] - c[1], X[0][2] - c[2]};
        rr = dot3(d0, d0);
        for (int it = 0; it < 1000; it++) {
            int64_t j = -1;
            double far = -1;
            for (int64_t i = 0; i < n; i++) {
                double v[3] = {X[i][0] - c[0], X[i][1] - c[1], X[i][2] - c[2]};
                double dd = dot3(v, v);
                if (dd > far) { far = dd; j = i; }
            }
            if (!(far > rr * (1 + 1e-10) + 1e-300)) break;
            /* smallest ball of T = support + the new point, over all supports (subsets of T) */
            double T[5][3];
            int nt = ns + 1;
            for (int i = 0; i < ns; i++) memcpy(T[i], sup[i], 24);
            memcpy(T[ns], X[j], 24);
            double bc_[3] = {0, 0, 0}, br2 = INFINITY;
            int bmask = 0;
            for (int mask = 1; mask < (1 << nt); mask++) {
                int cnt = __builtin_popcount(mask);
                if (cnt > 4) continue;
                double q[4][3], cc[3], r2;
                int w = 0;
                for (int i = 0; i < nt; i++)
                    if (mask & (1 << i)) memcpy(q[w++], T[i], 24);
                if (!circumball((const double (*)[3])q, cnt - 1, cc, &r2)) continue;
                if (!(r2 < br2)) continue;
                int valid = 1;
                for (int i = 0; i < nt && valid; i++) {
                    double v[3] = {T[i][0] - cc[0], T[i][1] - cc[1], T[i][2] - cc[2]};
                    if (dot3(v, v) > r2 * (1 + 1e-12) + 1e-300) valid = 0;
                }
                if (valid) { memcpy(bc_, cc, 24); br2 = r2; bmask = mask; }
            }
            if (!(br2 < INFINITY)) break; /* cannot happen: a single point is always a ball */
            ns = 0;
            for (int i = 0; i < nt; i++)
                if (bmask & (1 << i)) memcpy(sup[ns++], T[i], 24);
            memcpy(c, bc_, 24);
            rr = br2;
        }
        double far = 0;
        for (int64_t i = 0; i < n; i++) {
            double v[3] = {X[i][0] - c[0], X[i][1] - c[1], X[i][2] - c[2]};
            double dd = dot3(v, v);
            if (dd > far) far = dd;
        }
        memcpy(C + 3 * e, c, 24);
        R[e] = sqrt(far);
    }
    Py_END_ALLOW_THREADS
    release_bufs(all, 4);
    Py_RETURN_NONE;
}

static int cmp_i64(const void *x, const void *y) {
    int64_t a = *(const int64_t *)x, b = *(const int64_t *)y;
    return (a > b) - (a < b);
}

typedef struct {
    int64_t code, idx;
} CodeIdx;

static int cmp_code(const void *x, const void *y) {
    const CodeIdx *a = (const CodeIdx *)x, *b = (const CodeIdx *)y;
    if (a->code != b->code) return a->code < b->code ? -1 : 1;
    return (a->idx > b->idx) - (a->idx < b->idx);
}

static int64_t spread3(int64_t v) { /* bit b of v -> bit 3 b */
    int64_t r = 0;
    for (int b = 0; b < 10; b++) r |= ((v >> b) & 1) << (3 * b);
    return r;
}

/* metrics._prepare's 3D geometry in one pass per element: the faces fanned into triangles,
 * ordered along a Morton curve of the element's box (stable, as numpy's argsort), their corners,
 * centroids and edge neighbours; surface area and signed volume; the element's distinct boundary
 * vertices (sorted by node id) and box. Returns the number of vertex rows written. */
static PyObject *py_fan3d(PyObject *self, PyObject *args) {
    PyObject *o[14];
    if (!PyArg_ParseTuple(args, "OOOOOOOOOOOOOO", &o[0], &o[1], &o[2], &o[3], &o[4], &o[5], &o[6], &o[7],
                          &o[8], &o[9], &o[10], &o[11], &o[12], &o[13]))
        return NULL;
    const char *names[14] = {"points", "elem_offsets", "loop_offsets", "loop_nodes", "prim", "centre",
                             "prim_ptr", "tri_adj", "size", "signed", "vpts", "v_ptr", "bbox_lo", "bbox_hi"};
    int wr[14] = {0, 0, 0, 0, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1};
    Py_buffer b[14], *all[14];
    for (int i = 0; i < 14; i++) all[i] = &b[i];
    if (get_bufs(o, all, 14, names, NULL, wr) < 0) return NULL;
    const double *pts = (const double *)b[0].buf;
    const int64_t *eo = (const int64_t *)b[1].buf, *lo = (const int64_t *)b[2].buf, *nodes = (const int64_t *)b[3].buf;
    double *prim = (double *)b[4].buf, *cen = (double *)b[5].buf;
    int64_t *pptr = (int64_t *)b[6].buf, *adj = (int64_t *)b[7].buf;
    double *size = (double *)b[8].buf, *sgn = (double *)b[9].buf, *vp = (double *)b[10].buf;
    int64_t *vptr = (int64_t *)b[11].buf;
    double *blo = (double *)b[12].buf, *bhi = (double *)b[13].buf;
    Py_ssize_t ne = b[1].len / 8 - 1, np_ = b[0].len / 24;
    int err = 0;
    int64_t nv = 0;
    Py_BEGIN_ALLOW_THREADS
    int64_t *stamp = (int64_t *)malloc((size_t)(np_ > 0 ? np_ : 1) * sizeof(int64_t));
    int64_t *vb = NULL, *tn = NULL, *tn2 = NULL;
    CodeIdx *ci = NULL;
    EdgeSlot *tab = NULL;
    int64_t capv = 0, capt = 0, cape = 0;
    if (!stamp) err = 1;
    for (Py_ssize_t i = 0; i < np_ && !err; i++) stamp[i] = -1;
    int64_t S = 0;
    pptr[0] = 0;
    for (Py_ssize_t e = 0; e < ne && !err; e++) {
        /* distinct vertices and the triangle count */
        int64_t k0 = nv, m = 0;
        for (int64_t l = eo[e]; l < eo[e + 1]; l++) {
            int64_t len = lo[l + 1] - lo[l];
            if (len > 2) m += len - 2;
            for (int64_t q = lo[l]; q < lo[l + 1]; q++) {
                int64_t v = nodes[q];
                if (stamp[v] == e) continue;
                stamp[v] = e;
                if (nv - k0 >= capv) {
                    int64_t cap = capv ? 2 * capv : 256;
                    int64_t *nb = (int64_t *)realloc(vb, (size_t)cap * sizeof(int64_t));
                    if (!nb) { err = 1; break; }
                    vb = nb;
                    capv = cap;
                }
                vb[nv - k0] = v;
                nv++;
            }
            if (err) break;
        }
        if (err) break;
        int64_t cnt = nv - k0;
        qsort(vb, (size_t)cnt, sizeof(int64_t), cmp_i64);
        double L[3] = {NAN, NAN, NAN}, H[3] = {NAN, NAN, NAN};
        for (int64_t i = 0; i < cnt; i++) {
            const double *x = pts + 3 * vb[i];
            memcpy(vp + 3 * (k0 + i), x, 24);
            for (int a = 0; a < 3; a++) {
                if (i == 0 || x[a] < L[a]) L[a] = x[a];
                if (i == 0 || x[a] > H[a]) H[a] = x[a];
            }
        }
        vptr[e] = k0;
        vptr[e + 1] = nv;
        memcpy(blo + 3 * e, L, 24);
        memcpy(bhi + 3 * e, H, 24);
        /* triangles in face order: codes, area, volume */
        if (m > capt) {
            CodeIdx *nc = (CodeIdx *)realloc(ci, (size_t)m * sizeof(CodeIdx));
            if (nc) ci = nc;
            int64_t *nt = (int64_t *)realloc(tn, (size_t)m * 3 * sizeof(int64_t));
            if (nt) tn = nt;
            int64_t *nt2 = (int64_t *)realloc(tn2, (size_t)m * 3 * sizeof(int64_t));
            if (nt2) tn2 = nt2;
            if (!nc || !nt || !nt2) { err = 1; break; }
            capt = m;
        }
        double span[3];
        for (int a = 0; a < 3; a++) {
            span[a] = H[a] - L[a];
            if (!(span[a] > 1e-300)) span[a] = 1e-300;
        }
        double area = 0, vol = 0;
        int64_t t = 0;
        for (int64_t l = eo[e]; l < eo[e + 1]; l++) {
            int64_t base = lo[l], len = lo[l + 1] - lo[l];
            for (int64_t j = 0; j + 2 < len; j++, t++) {
                int64_t n0 = nodes[base], n1 = nodes[base + j + 1], n2 = nodes[base + j + 2];
                tn[3 * t] = n0; tn[3 * t + 1] = n1; tn[3 * t + 2] = n2;
                const double *A = pts + 3 * n0, *B = pts + 3 * n1, *C = pts + 3 * n2;
                double u[3] = {B[0] - A[0], B[1] - A[1], B[2] - A[2]}, w[3] = {C[0] - A[0], C[1] - A[1], C[2] - A[2]};
                double cr[3] = {u[1] * w[2] - u[2] * w[1], u[2] * w[0] - u[0] * w[2], u[0] * w[1] - u[1] * w[0]};
                area += 0.5 * sqrt(cr[0] * cr[0] + cr[1] * cr[1] + cr[2] * cr[2]);
                double bc[3] = {B[1] * C[2] - B[2] * C[1], B[2] * C[0] - B[0] * C[2], B[0] * C[1] - B[1] * C[0]};
                vol += A[0] * bc[0] + A[1] * bc[1] + A[2] * bc[2];
                int64_t code = 0;
                for (int a = 0; a < 3; a++) {
                    double c = (A[a] + B[a] + C[a]) / 3.0;
                    double x = (c - L[a]) / span[a] * 1023.0;
                    int64_t ic = (int64_t)x;
                    if (ic < 0) ic = 0;
                    if (ic > 1023) ic = 1023;
                    code |= spread3(ic) << a;
                }
                ci[t].code = code;
                ci[t].idx = t;
            }
        }
        size[e] = area;
        sgn[e] = vol / 6.0;
        qsort(ci, (size_t)m, sizeof(CodeIdx), cmp_code);
        for (int64_t r = 0; r < m; r++) {
            int64_t src = ci[r].idx;
            double *P = prim + 9 * (S + r);
            for (int v = 0; v < 3; v++) memcpy(P + 3 * v, pts + 3 * tn[3 * src + v], 24);
            for (int a = 0; a < 3; a++) cen[3 * (S + r) + a] = (P[a] + P[3 + a] + P[6 + a]) / 3.0;
        }
        /* edge neighbours (global triangle ids), the triangles' nodes in the sorted order */
        for (int64_t r = 0; r < m; r++) memcpy(tn2 + 3 * r, tn + 3 * ci[r].idx, 3 * sizeof(int64_t));
        if (edge_neighbours(tn2, m, S, adj, &tab, &cape) < 0) { err = 1; break; }
        S += m;
        pptr[e + 1] = S;
    }
    free(stamp); free(vb); free(tn); free(tn2); free(ci); free(tab);
    Py_END_ALLOW_THREADS
    release_bufs(all, 14);
    if (err) return PyErr_NoMemory();
    return PyLong_FromLongLong((long long)nv);
}

static int64_t uf_find(int64_t *par, int64_t x) {
    while (par[x] != x) {
        par[x] = par[par[x]];
        x = par[x];
    }
    return x;
}

/* metrics.partition_statistics of a symmetric CSR pattern with strictly increasing rows (every
 * undirected edge twice, no duplicates): per part the volume (sum of degrees, self loops left out)
 * and the cut edges; returns (cut, connected components of the graph without the cut edges), the
 * components by union-find. Returns None when a row is not strictly increasing. */
static PyObject *py_partition_stats(PyObject *self, PyObject *args) {
    PyObject *o[5];
    if (!PyArg_ParseTuple(args, "OOOOO", &o[0], &o[1], &o[2], &o[3], &o[4])) return NULL;
    const char *names[5] = {"indptr", "indices", "part", "volume", "cut_per_part"};
    int wr[5] = {0, 0, 0, 1, 1};
    Py_buffer b[5], *all[5];
    for (int i = 0; i < 5; i++) all[i] = &b[i];
    if (get_bufs(o, all, 5, names, NULL, wr) < 0) return NULL;
    const int64_t *ip = (const int64_t *)b[0].buf, *ix = (const int64_t *)b[1].buf, *part = (const int64_t *)b[2].buf;
    double *vol = (double *)b[3].buf, *cuti = (double *)b[4].buf;
    Py_ssize_t n = b[0].len / 8 - 1;
    int64_t cut2 = 0, comps = 0;
    int err = 0, sorted = 1;
    Py_BEGIN_ALLOW_THREADS
    int64_t *par = (int64_t *)malloc((size_t)(n > 0 ? n : 1) * sizeof(int64_t));
    if (!par) err = 1;
    for (Py_ssize_t u = 0; u < n && !err; u++) par[u] = u;
    for (Py_ssize_t u = 0; u < n && !err && sorted; u++) {
        int64_t pu = part[u], deg = 0;
        for (int64_t k = ip[u]; k < ip[u + 1]; k++) {
            int64_t v = ix[k];
            if (k > ip[u] && v <= ix[k - 1]) { sorted = 0; break; }
            if (v == u) continue;
            deg++;
            if (part[v] != pu) {
                cut2++;
                cuti[pu] += 1;
            } else if (v > u) {
                int64_t a = uf_find(par, u), c = uf_find(par, v);
                if (a != c) par[a < c ? c : a] = a < c ? a : c;
            }
        }
        vol[pu] += (double)deg;
    }
    if (!err && sorted)
        for (Py_ssize_t u = 0; u < n; u++)
            if (uf_find(par, u) == u) comps++;
    free(par);
    Py_END_ALLOW_THREADS
    release_bufs(all, 5);
    if (err) return PyErr_NoMemory();
    if (!sorted) Py_RETURN_NONE;
    return Py_BuildValue("(LL)", (long long)(cut2 / 2), (long long)comps);
}

PyObject *py_inscribed2d(PyObject *self, PyObject *args); /* _fastcircle.c */

static PyMethodDef methods[] = {
    {"inscribed2d", py_inscribed2d, METH_VARARGS,
     "inscribed2d(prim, prim_ptr, elems, diameter, bbox_lo, bbox_hi, rel_tol, max_cells, centres, radius, "
     "evals): largest inscribed circles of the 2D elements `elems` (see _fastcircle.c)."},
    {"inscribed", py_inscribed, METH_VARARGS,
     "inscribed(table, tri_adj, prim_ptr, elems, diameter, bbox_lo, bbox_hi, orient, rel_tol, "
     "max_cells, centres, radius, evals): largest inscribed balls of the 3D elements `elems` "
     "(written into centres / radius; evals[e] = -1 where the cell budget ran out)."},
    {"farthest_pairs", py_farthest_pairs, METH_VARARGS,
     "farthest_pairs(points, v_ptr, first, second, diameter): the farthest pair (positions within "
     "each set) and its distance, per point set."},
    {"locally_convex", py_locally_convex, METH_VARARGS,
     "locally_convex(table, tri_adj, prim_ptr, sign, tol, out): 1 where every edge of the element is "
     "shared and convex (to tol), else 0."},
    {"tri_table", py_tri_table, METH_VARARGS,
     "tri_table(prim, table): per-triangle constants."},
    {"enclosing_balls", py_enclosing_balls, METH_VARARGS,
     "enclosing_balls(points, ptr, centre, radius): the smallest enclosing ball of each point set."},
    {"fan3d", py_fan3d, METH_VARARGS,
     "fan3d(points, elem_offsets, loop_offsets, loop_nodes, prim, centre, prim_ptr, tri_adj, size, "
     "signed, vpts, v_ptr, bbox_lo, bbox_hi): metrics._prepare's 3D geometry; returns the vertex rows."},
    {"partition_stats", py_partition_stats, METH_VARARGS,
     "partition_stats(indptr, indices, part, volume, cut_per_part): (cut, components) of a symmetric "
     "CSR with strictly increasing rows, or None when a row is not."},
    {NULL, NULL, 0, NULL}};

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "_fastmetrics",
                                    "Compiled helpers of models.metrics (see models/_fastmetrics.c).", -1,
                                    methods};

PyMODINIT_FUNC PyInit__fastmetrics(void) { return PyModule_Create(&module); }
