/* Compiled helpers of the read stage's validation (models/mesh/geometry.py and orientation.py; each
 * has a numpy twin there: the fallback and the reference in the tests; MAGNET_NO_COMPILED=1 switches
 * them off). Same results bit for bit: the same floating-point operations in the same order as the
 * numpy code (built with -ffp-contract=off, no fast-math).
 *
 *   (measures)      signed volume and centroid of cells of a fixed node count (measure_cell), by the
 *                   divergence theorem on their faces as geometry._measures_and_centroids does it:
 *                   triangles as they are, a face of 4+ nodes fanned from the mean of its nodes,
 *                   every triangle relative to the cell's vertex mean, six times its volume summed and
 *                   divided by 6 once per cell;
 *   fixed_validate  the read stage's validation of cells of one fixed-size type in one pass per cell
 *                   (threads over ranges of cells): measure_cell's volume and centroid (tetrahedra in
 *                   closed form, as geometry._tetra_measures), the own-sign flip and the face keys of
 *                   fixed_consistent, then one bucket pass: is flipping each cell by its sign consistent?
 *   cells_validate  fixed_validate for cells in CSR: mixed template types in 3D, polygons in 2D
 *                   (measure_polygon and their directed edges); measures only on request
 *   bounds          each coordinate's minimum and maximum in one pass (build._bounds)
 *
 * In the same module: the face check (_fastfaces.c: consistent, fixed_consistent, and the counting
 * sort and scratch the staged check here shares), ascii_values (_fastascii.c: a legacy VTK ASCII
 * section's numbers) and the polyhedra's helpers (_fastpoly.c).
 *
 * Arrays come through the buffer protocol (no numpy headers at build time); point ids are trusted
 * (build.mesh_from_cells checked them before).
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include "_buffers.h"
#include "_fastmesh.h"
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#include <pthread.h>
#include <sched.h>
#include <stdatomic.h>


/* One cell's signed volume and centroid, its k nodes c[0..k-1]: the same float
 * operations in the same order as geometry._measures_and_centroids. The cell's coordinates are
 * gathered once (x), every node relative to the vertex mean o once (rel). */
static inline __attribute__((always_inline)) void measure_cell(const double *P, const int64_t *c, int64_t k,
                                                               const int64_t *tmpl, const int64_t *tsize,
                                                               int64_t nf, double *vol, double *cen) {
    double x[64][3], rel[64][3];
    double o[3] = {0.0, 0.0, 0.0};
    for (int64_t j = 0; j < k; j++)
        for (int d = 0; d < 3; d++) {
            x[j][d] = P[3 * c[j] + d];
            o[d] += x[j][d];
        }
    if (k == 8)
        for (int d = 0; d < 3; d++) o[d] *= 0.125; /* exact, as / 8 */
    else
        for (int d = 0; d < 3; d++) o[d] /= (double)k;
    for (int64_t j = 0; j < k; j++)
        for (int d = 0; d < 3; d++) rel[j][d] = x[j][d] - o[d];
    double v_sum = 0.0, g_sum[3] = {0.0, 0.0, 0.0};
    /* TRI (_fastmesh.h): one triangle into v_sum and g_sum */
    int64_t pos = 0;
    for (int64_t f = 0; f < nf; f++) {
        int64_t s = tsize[f];
        const int64_t *t = tmpl + pos;
        pos += s;
        if (s == 3) {
            TRI(rel[t[0]], rel[t[1]], rel[t[2]]);
            continue;
        }
        double m[3] = {0.0, 0.0, 0.0};
        for (int64_t j = 0; j < s; j++)
            for (int d = 0; d < 3; d++) m[d] += x[t[j]][d];
        if (s == 4) /* x / 4 and x * 0.25 are the same number (a power of two): no division */
            for (int d = 0; d < 3; d++) m[d] = m[d] * 0.25 - o[d];
        else
            for (int d = 0; d < 3; d++) m[d] = m[d] / (double)s - o[d];
        for (int64_t j = 0; j < s; j++) TRI(m, rel[t[j]], rel[t[j + 1 == s ? 0 : j + 1]]);
    }
    *vol = v_sum / 6.0;
    for (int d = 0; d < 3; d++) cen[d] = g_sum[d] / v_sum + o[d];
}

/* Four hexahedra at once (c: their 4 * 8 nodes; tmpl: 6 faces of 4 nodes), measure_cell's float
 * operations in its order in each lane of a 4-double vector: the same numbers bit for bit (no
 * reassociation across lanes, -ffp-contract=off: no fused multiply-add). Built for AVX2 and for
 * the baseline (two SSE2 halves), picked at load time (target_clones). */
typedef double v4d __attribute__((vector_size(32)));

__attribute__((target_clones("avx2", "default"))) static void measure_hex4(const double *P, const int64_t *c,
                                                                           const int64_t *tmpl, double *vol,
                                                                           double *cen) {
    v4d x[8][3], rel[8][3];
    v4d o[3] = {{0.0, 0.0, 0.0, 0.0}, {0.0, 0.0, 0.0, 0.0}, {0.0, 0.0, 0.0, 0.0}};
    for (int j = 0; j < 8; j++)
        for (int d = 0; d < 3; d++) {
            v4d v = {P[3 * c[j] + d], P[3 * c[8 + j] + d], P[3 * c[16 + j] + d], P[3 * c[24 + j] + d]};
            x[j][d] = v;
            o[d] += v;
        }
    for (int d = 0; d < 3; d++) o[d] *= 0.125;
    for (int j = 0; j < 8; j++)
        for (int d = 0; d < 3; d++) rel[j][d] = x[j][d] - o[d];
    v4d v_sum = {0.0, 0.0, 0.0, 0.0}, g0 = v_sum, g1 = v_sum, g2 = v_sum;
    for (int f = 0; f < 6; f++) {
        const int64_t *t = tmpl + 4 * f;
        v4d m[3];
        for (int d = 0; d < 3; d++) {
            v4d z = {0.0, 0.0, 0.0, 0.0};
            for (int j = 0; j < 4; j++) z += x[t[j]][d];
            m[d] = z * 0.25 - o[d];
        }
        for (int j = 0; j < 4; j++) {
            const v4d *b = rel[t[j]], *cc = rel[t[(j + 1) & 3]];
            v4d x0 = b[1] * cc[2] - b[2] * cc[1], x1 = b[2] * cc[0] - b[0] * cc[2], x2 = b[0] * cc[1] - b[1] * cc[0];
            v4d v = (m[0] * x0 + m[2] * x2) + m[1] * x1;
            v_sum += v;
            g0 += v * (((m[0] + b[0]) + cc[0]) * 0.25);
            g1 += v * (((m[1] + b[1]) + cc[1]) * 0.25);
            g2 += v * (((m[2] + b[2]) + cc[2]) * 0.25);
        }
    }
    v4d vv = v_sum / 6.0, c0 = g0 / v_sum + o[0], c1 = g1 / v_sum + o[1], c2 = g2 / v_sum + o[2];
    for (int q = 0; q < 4; q++) {
        vol[q] = vv[q];
        cen[3 * q] = c0[q];
        cen[3 * q + 1] = c1[q];
        cen[3 * q + 2] = c2[q];
    }
}

/* The template is six faces of four nodes (hexahedra): measure_hex4 applies. */
static int hex_template(int64_t k, int64_t nf, const int64_t *tsize) {
    if (k != 8 || nf != 6) return 0;
    for (int f = 0; f < 6; f++)
        if (tsize[f] != 4) return 0;
    return 1;
}

/* A tetrahedron in closed form, as geometry._tetra_measures: a, b, c = p1 - p0, p2 - p0, p3 - p0;
 * volume a . (b x c) / 6 (summed x, z, y), centroid p0 + ((a + b) + c) / 4. */
static inline __attribute__((always_inline)) void measure_tet(const double *P, const int64_t *c, double *vol,
                                                              double *cen) {
    const double *p0 = P + 3 * c[0], *p1 = P + 3 * c[1], *p2 = P + 3 * c[2], *p3 = P + 3 * c[3];
    double a[3], b[3], e[3];
    for (int d = 0; d < 3; d++) {
        a[d] = p1[d] - p0[d];
        b[d] = p2[d] - p0[d];
        e[d] = p3[d] - p0[d];
    }
    double x0 = b[1] * e[2] - b[2] * e[1], x1 = b[2] * e[0] - b[0] * e[2], x2 = b[0] * e[1] - b[1] * e[0];
    double v = a[0] * x0;
    v += a[2] * x2;
    v += a[1] * x1;
    *vol = v / 6.0;
    for (int d = 0; d < 3; d++) cen[d] = p0[d] + ((a[d] + b[d]) + e[d]) / 4.0;
}

/* fixed_validate(points, conn, tmpl, tsize, vol, cen, flip, npts, nthreads) -> bool
 *   The read stage's validation of cells of one type with a fixed node count in one pass per cell:
 *   measure_cell's signed volume and centroid (tetrahedra: measure_tet, closed form, as
 *   geometry._tetra_measures), flip[i] = vol[i] < 0 (uint8), and every face's smallest node and
 *   directed key as fixed_consistent makes them with those flips (sharing the gathered nodes).
 *   Then the keys are bucketed by their smallest node (a counting sort over R ranges of faces, the
 *   positions in (point, range) order: the sequential pass's order, bucket for bucket) and compared
 *   in each bucket: True when no face is met twice in the same direction (flipping every cell by
 *   its own sign is consistent), False otherwise (the caller takes the full path), and False where
 *   a face has a node repeated (a collapsed cell: a wedge written as a hexahedron, say).
 *   The work is cut into chunks (cells, ranges of faces, ranges of points) in five stages; the
 *   calling thread and up to nthreads - 1 helpers claim chunks from a counter, and no one starts a
 *   stage before the one before is done. The caller never waits for a helper to start: on a virtual
 *   machine whose other core is idle a new thread may start milliseconds late (measured here: 0.6-4 ms
 *   after a sleep, 45 us otherwise), and then the caller does the chunks itself (the sequential
 *   time, not twice it); a helper that comes late finds nothing left and ends. */
typedef struct {
    const double *P;
    const int64_t *conn, *tmpl, *tsize;
    int64_t k, nf, lo, hi, npts;
    double *vol, *cen;
    uint8_t *flip;
    uint32_t *mins;
    uint64_t *keys;
    int bad, collapsed;
    /* cells_validate's general layout (coff NULL: one fixed type, cell i at conn + i * k, its faces
     * at i * nf): cell i's nodes conn[coff[i]..coff[i + 1]), its faces' keys from foff[i]; 3D: its
     * VTK type types[i], whose row of ttab is (k, nf, template start, sizes start); 2D (dim2):
     * polygons of (P, 2) points, their faces their edges (foff = coff) */
    const int64_t *coff, *foff, *ttab;
    const uint8_t *types;
    int dim2;
    int measure_only; /* measures and flips only: no keys, no face check (the answer is 0) */
} Job;

static void *validate_range(void *arg) {
    Job *J = arg;
    const int64_t k = J->k, nf = J->nf, *tmpl = J->tmpl, *tsize = J->tsize;
    const int hex = hex_template(k, nf, tsize);
    for (int64_t i = J->lo; i < J->hi; i++) {
        const int64_t *c = J->conn + i * k;
        if (hex && (i - J->lo) % 4 == 0 && i + 4 <= J->hi) /* hexahedra four at a time */
            measure_hex4(J->P, c, tmpl, J->vol + i, J->cen + 3 * i);
        else if (hex && i + 4 - (i - J->lo) % 4 <= J->hi)
            ; /* measured with its block of four */
        else if (k == 4 && nf == 4)
            measure_tet(J->P, c, J->vol + i, J->cen + 3 * i);
        else if (k == 8 && nf == 6) /* hexahedra: the constants let the compiler unroll */
            measure_cell(J->P, c, 8, tmpl, tsize, 6, J->vol + i, J->cen + 3 * i);
        else
            measure_cell(J->P, c, k, tmpl, tsize, nf, J->vol + i, J->cen + 3 * i);
        int fl = J->vol[i] < 0.0;
        J->flip[i] = (uint8_t)fl;
        if (J->measure_only) continue;
        int bad;
        if (hex) /* the constants let the compiler unroll */
            bad = cell_face_keys(c, tmpl, tsize, 6, 4, fl, J->npts, J->mins + i * 6, J->keys + i * 6);
        else if (k == 4 && nf == 4) /* tetrahedra (checked by the caller: four triangles) */
            bad = cell_face_keys(c, tmpl, tsize, 4, 3, fl, J->npts, J->mins + i * 4, J->keys + i * 4);
        else
            bad = cell_face_keys(c, tmpl, tsize, nf, 0, fl, J->npts, J->mins + i * nf, J->keys + i * nf);
        if (bad == 2) /* measured and keyed, but the caller takes the full path */
            J->collapsed = 1;
        else if (bad) {
            J->bad = 1;
            return NULL;
        }
    }
    return NULL;
}

/* A polygon's signed area and centroid (cells_validate in 2D), geometry._polygon_measures' float
 * operations in its order: a triangle in closed form (u = p1 - p0, v = p2 - p0, area
 * (u0 v1 - u1 v0) / 2, centroid ((p0 + p1) + p2) / 3); any other polygon relative to its first
 * node o: the cross products of consecutive nodes, and the centroid's terms, summed in cycle order
 * from the first (numpy's cumsum), the centroid divided by 6 * area, plus o. */
static inline void measure_polygon(const double *P, const int64_t *c, int64_t s, double *area, double *cen) {
    if (s == 3) {
        const double *p0 = P + 2 * c[0], *p1 = P + 2 * c[1], *p2 = P + 2 * c[2];
        double u0 = p1[0] - p0[0], u1 = p1[1] - p0[1], v0 = p2[0] - p0[0], v1 = p2[1] - p0[1];
        *area = 0.5 * (u0 * v1 - u1 * v0);
        cen[0] = ((p0[0] + p1[0]) + p2[0]) / 3.0;
        cen[1] = ((p0[1] + p1[1]) + p2[1]) / 3.0;
        return;
    }
    const double ox = P[2 * c[0]], oy = P[2 * c[0] + 1];
    double a = 0.0, cx = 0.0, cy = 0.0;
    for (int64_t j = 0; j < s; j++) {
        const double *pa = P + 2 * c[j], *pb = P + 2 * c[j + 1 == s ? 0 : j + 1];
        double xa = pa[0] - ox, ya = pa[1] - oy, xb = pb[0] - ox, yb = pb[1] - oy;
        double cr = xa * yb - xb * ya, tx = (xa + xb) * cr, ty = (ya + yb) * cr;
        if (j == 0) {
            a = cr, cx = tx, cy = ty;
        } else {
            a += cr, cx += tx, cy += ty;
        }
    }
    a = 0.5 * a;
    double d = 6.0 * a;
    *area = a;
    cen[0] = cx / d + ox;
    cen[1] = cy / d + oy;
}

/* A polygon's directed edges as faces of two nodes: the smaller node (mins) and, packed, the other
 * (bits 33..62), the direction (bit 3: 1 where the edge runs from the larger node to the smaller,
 * the cell's flip applied) and the size 2. 0, 1 (a node out of range) or 2 (an edge from a node to
 * itself: a repeated node), as cell_face_keys. */
static inline int polygon_edge_keys(const int64_t *c, int64_t s, int fl, int64_t P, uint32_t *mins,
                                    uint64_t *keys) {
    int collapsed = 0;
    for (int64_t j = 0; j < s; j++) {
        int64_t a = c[j], b = c[j + 1 == s ? 0 : j + 1];
        int64_t m = a < b ? a : b, o = a < b ? b : a;
        if (m < 0 || o >= P) return 1;
        collapsed |= a == b;
        mins[j] = (uint32_t)m;
        keys[j] = (uint64_t)o << 33 | (uint64_t)((a > b) ^ fl) << 3 | 2;
    }
    return collapsed ? 2 : 0;
}

/* validate_range for the general layout (Job.coff): each cell measured (3D: measure_cell from its
 * type's template, as geometry._fixed_measures; 2D: measure_polygon), flipped by its sign, keyed. */
static void validate_cells(Job *J) {
    for (int64_t i = J->lo; i < J->hi; i++) {
        const int64_t *c = J->conn + J->coff[i];
        int bad, fl;
        if (J->dim2) {
            int64_t s = J->coff[i + 1] - J->coff[i];
            measure_polygon(J->P, c, s, J->vol + i, J->cen + 2 * i);
            fl = J->vol[i] < 0.0;
            bad = J->measure_only ? 0 : polygon_edge_keys(c, s, fl, J->npts, J->mins + J->coff[i], J->keys + J->coff[i]);
        } else {
            const int64_t *e = J->ttab + 4 * J->types[i], *tm = J->tmpl + e[2], *ts = J->tsize + e[3];
            uint32_t *mins = J->mins + (J->measure_only ? 0 : J->foff[i]);
            uint64_t *keys = J->keys + (J->measure_only ? 0 : J->foff[i]);
            if (J->types[i] == 10) { /* tetrahedra, hexahedra: constants the compiler unrolls */
                measure_cell(J->P, c, 4, tm, ts, 4, J->vol + i, J->cen + 3 * i);
                fl = J->vol[i] < 0.0;
                bad = J->measure_only ? 0 : cell_face_keys(c, tm, ts, 4, 3, fl, J->npts, mins, keys);
            } else if (J->types[i] == 12) {
                measure_cell(J->P, c, 8, tm, ts, 6, J->vol + i, J->cen + 3 * i);
                fl = J->vol[i] < 0.0;
                bad = J->measure_only ? 0 : cell_face_keys(c, tm, ts, 6, 4, fl, J->npts, mins, keys);
            } else {
                measure_cell(J->P, c, e[0], tm, ts, e[1], J->vol + i, J->cen + 3 * i);
                fl = J->vol[i] < 0.0;
                bad = J->measure_only ? 0 : cell_face_keys(c, tm, ts, e[1], 0, fl, J->npts, mins, keys);
            }
        }
        J->flip[i] = (uint8_t)fl;
        if (bad == 2)
            J->collapsed = 1;
        else if (bad) {
            J->bad = 1;
            return;
        }
    }
}

enum { ST_MEASURE, ST_COUNT, ST_PREFIX, ST_SCATTER, ST_COMPARE, ST_N };
#define MEASURE_CHUNK 2048 /* cells (a multiple of 4: hexahedra four at a time) */
#define COMPARE_CHUNK 8192 /* points */

typedef struct {
    atomic_int refs;  /* the caller and each helper started: the last one frees this */
    atomic_int bad;   /* a point id out of range (measuring) */
    atomic_int twice; /* a key met twice (comparing) */
    atomic_int collapsed; /* a face with a node repeated (measuring: every cell is still measured) */
    atomic_long next[ST_N], done[ST_N];
    long n[ST_N];
    Job job; /* the measuring pass's arrays (lo, hi per chunk) */
    Scratch s;
    int64_t C, F, Pn, R;
} Stages;

static void stage_chunk(Stages *S, int st, long c, uint32_t **head) {
    Scratch *s = &S->s;
    int64_t F = S->F, Pn = S->Pn, R = S->R;
    if (st == ST_MEASURE) {
        Job j = S->job;
        j.lo = (int64_t)c * MEASURE_CHUNK;
        j.hi = j.lo + MEASURE_CHUNK < S->C ? j.lo + MEASURE_CHUNK : S->C;
        j.bad = j.collapsed = 0;
        if (j.coff)
            validate_cells(&j);
        else
            validate_range(&j);
        if (j.bad) atomic_store(&S->bad, 1);
        if (j.collapsed) atomic_store(&S->collapsed, 1);
    } else if (st == ST_COUNT) {
        uint32_t *cnt = s->cnt + c * Pn;
        memset(cnt, 0, (size_t)Pn * sizeof(uint32_t));
        for (int64_t f = F * c / R; f < F * (c + 1) / R; f++) cnt[s->mins[f]]++;
    } else if (st == ST_PREFIX) { /* positions in (point, range) order */
        uint32_t pos = 0;
        for (int64_t p = 0; p < Pn; p++) {
            s->start[p] = pos;
            for (int64_t r = 0; r < R; r++) {
                uint32_t n = s->cnt[r * Pn + p];
                s->cnt[r * Pn + p] = pos;
                pos += n;
            }
        }
        s->start[Pn] = pos;
    } else if (st == ST_SCATTER) {
        uint32_t *cnt = s->cnt + c * Pn;
        for (int64_t f = F * c / R; f < F * (c + 1) / R; f++) s->sorted[cnt[s->mins[f]]++] = s->keys[f];
    } else {
        int64_t lo = (int64_t)c * COMPARE_CHUNK, hi = lo + COMPARE_CHUNK < Pn ? lo + COMPARE_CHUNK : Pn;
        if (!buckets_once(s->sorted, s->start, lo, hi, Pn, s->prev, head)) atomic_store(&S->twice, 1);
    }
}

/* Every stage in order: claim chunks until none is left, then wait until the stage's chunks are
 * done (those other threads claimed), then the next stage. After a bad point id or a key met
 * twice the remaining chunks are counted done without work. */
static void run_stages(Stages *S) {
    uint32_t *head = NULL;
    for (int st = 0; st < ST_N; st++) {
        long c;
        while ((c = atomic_fetch_add(&S->next[st], 1)) < S->n[st]) {
            if (!atomic_load(&S->bad) && !atomic_load(&S->twice)) stage_chunk(S, st, c, &head);
            atomic_fetch_add_explicit(&S->done[st], 1, memory_order_release);
        }
        for (int spin = 0; atomic_load_explicit(&S->done[st], memory_order_acquire) < S->n[st]; spin++)
            if (spin > 256) sched_yield();
    }
    free(head);
}

static void stages_drop(Stages *S) {
    if (atomic_fetch_sub(&S->refs, 1) == 1) free(S);
}

static void *stage_helper(void *arg) {
    run_stages(arg);
    stages_drop(arg);
    return NULL;
}

/* The staged validation of job j's C cells and F faces over Pn points in up to nthreads threads
 * (j's mins and keys are set here, in the scratch): 1 consistent, 0 not (a key met twice, a
 * collapsed face, or a mesh too large for the packed keys), -1 a point id out of range, -2 out of
 * memory. Called with the GIL held; releases it while the work runs. */
static int validate_job(Job j, int64_t C, int64_t F, int64_t Pn, int64_t nthreads) {
    int64_t T = nthreads < 1 ? 1 : nthreads > 64 ? 64 : nthreads;
    if (T > 1 && C / T < 4096) T = C / 4096 > 1 ? C / 4096 : 1; /* threads only for large arrays */
    int faces = Pn < KEY_ID_LIMIT && F < (int64_t)NONE32; /* else the packed keys cannot hold them */
    if (j.measure_only) faces = 0, F = 0, Pn = 0;
    Stages *S = calloc(1, sizeof(Stages));
    Scratch s = face_scratch(F, Pn, T);
    int ok = 0, err = !s.block || !S;
    if (!err) {
        j.mins = s.mins;
        j.keys = s.keys;
        j.lo = j.hi = 0;
        j.bad = j.collapsed = 0;
        S->job = j;
        S->s = s;
        S->C = C, S->F = F, S->Pn = Pn, S->R = T;
        S->n[ST_MEASURE] = (long)((C + MEASURE_CHUNK - 1) / MEASURE_CHUNK);
        S->n[ST_COUNT] = S->n[ST_SCATTER] = faces ? (long)T : 0;
        S->n[ST_PREFIX] = faces ? 1 : 0;
        S->n[ST_COMPARE] = faces ? (long)((Pn + COMPARE_CHUNK - 1) / COMPARE_CHUNK) : 0;
        atomic_init(&S->refs, 1);
    }
    Py_BEGIN_ALLOW_THREADS
    if (!err) {
        pthread_attr_t attr;
        int attr_ok = pthread_attr_init(&attr) == 0 && pthread_attr_setdetachstate(&attr, PTHREAD_CREATE_DETACHED) == 0;
        for (int64_t t = 1; t < T && attr_ok; t++) {
            pthread_t tid;
            atomic_fetch_add(&S->refs, 1);
            if (pthread_create(&tid, &attr, stage_helper, S) != 0) {
                atomic_fetch_sub(&S->refs, 1);
                break;
            }
        }
        if (attr_ok) pthread_attr_destroy(&attr);
    }
    if (!err) {
        run_stages(S); /* every chunk done when it returns: a helper still running touches only S */
        if (atomic_load(&S->bad))
            err = 2;
        else
            ok = faces && !atomic_load(&S->twice) && !atomic_load(&S->collapsed);
    }
    Py_END_ALLOW_THREADS
    if (S) stages_drop(S);
    scratch_give(s.block);
    return err == 1 ? -2 : err ? -1 : ok;
}

static PyObject *validate_answer(int r, const char *fname) {
    if (r == -2) return PyErr_NoMemory();
    if (r == -1) {
        PyErr_Format(PyExc_ValueError, "%s: a point id is out of range", fname);
        return NULL;
    }
    return PyLong_FromLong(r);
}

static PyObject *py_fixed_validate(PyObject *self, PyObject *args) {
    static const char *const names[] = {"points", "conn", "tmpl", "tsize", "vol",
                                        "cen",    "flip", "npts", "nthreads"};
    static const Py_ssize_t sizes[] = {8, 8, 8, 8, 8, 8, 1, 8, 8};
    static const int wr[] = {0, 0, 0, 0, 1, 1, 1, 0, 0};
    Py_buffer b[9];
    if (parse_bufs(args, 9, "fixed_validate", names, sizes, wr, b) < 0) return NULL;
    const double *P = b[0].buf;
    const int64_t *conn = b[1].buf, *tmpl = b[2].buf, *tsize = b[3].buf, *npts = b[7].buf, *nth = b[8].buf;
    double *vol = b[4].buf, *cen = b[5].buf;
    uint8_t *flip = b[6].buf;
    int64_t C = N8(b[4]), nf = N8(b[3]), nt = N8(b[2]), k = C ? N8(b[1]) / C : 0, sum = 0;
    for (int64_t f = 0; f < nf; f++) sum += tsize[f];
    int tet = 1;
    if (nf == 4 && nt == 12)
        for (int64_t f = 0; f < 4; f++) tet &= tsize[f] == 3;
    if (N8(b[7]) != 1 || N8(b[8]) != 1 || npts[0] < 0 || npts[0] >= ((int64_t)1 << 60) || C * 3 != N8(b[5]) || (int64_t)b[6].len != C ||
        (C && k * C != N8(b[1])) || k > 64 || nf > 64 || sum != nt || (k == 4 && nf == 4 && !tet)) {
        release_arr(b, 9);
        PyErr_SetString(PyExc_ValueError, "fixed_validate: inconsistent array sizes");
        return NULL;
    }
    Job j = {P, conn, tmpl, tsize, k, nf, 0, 0, npts[0], vol, cen, flip, NULL, NULL, 0, 0, NULL, NULL, NULL, NULL, 0, 0};
    int r = validate_job(j, C, C * nf, npts[0], nth[0]);
    release_arr(b, 9);
    if (r < 0) return validate_answer(r, "fixed_validate");
    return PyBool_FromLong(r);
}

/* cells_validate(points, offsets, conn, types, ttab, tmpl, tsize, vol, cen, flip, npts, nthreads, mode) -> int
 *   fixed_validate for cells of any layout: C cells in CSR (offsets (C + 1,), conn) of the VTK
 *   types `types` (uint8; 3D: each a type with a row (k, nf, start in tmpl, start in tsize) in
 *   ttab (256 * 4), k 0 for a type without a template), or in 2D (cen (C * 2): polygons of any
 *   size, points (npts * 2)) node cycles whose faces are their edges. 1: consistent (flipping every
 *   cell by its own sign orients all of them); 0: not (the caller takes the full path); -1: a
 *   layout taken elsewhere (a cell without nodes, a type without a template or of another node
 *   count, offsets that do not fit conn): nothing was written. Cells of one type in rows of k
 *   (offsets k * i) take fixed_validate's path (tetrahedra in closed form, hexahedra four at a
 *   time); others measure_cell's or measure_polygon's. mode (1,): 0 all that, 1 the measures and flips
 *   only (no face check; 0 returned): geometry._fixed_measures in threads. */
static PyObject *py_cells_validate(PyObject *self, PyObject *args) {
    static const char *const names[] = {"points", "offsets", "conn", "types", "ttab",     "tmpl", "tsize",
                                        "vol",    "cen",     "flip", "npts",  "nthreads", "mode"};
    static const Py_ssize_t sizes[] = {8, 8, 8, 1, 8, 8, 8, 8, 8, 1, 8, 8, 8};
    static const int wr[] = {0, 0, 0, 0, 0, 0, 0, 1, 1, 1, 0, 0, 0};
    Py_buffer b[13];
    if (parse_bufs(args, 13, "cells_validate", names, sizes, wr, b) < 0) return NULL;
    const double *P = b[0].buf;
    const int64_t *off = b[1].buf, *conn = b[2].buf, *ttab = b[4].buf, *tmpl = b[5].buf, *tsize = b[6].buf;
    const int64_t *npts = b[10].buf, *nth = b[11].buf, *mode = b[12].buf;
    const uint8_t *types = b[3].buf;
    double *vol = b[7].buf, *cen = b[8].buf;
    uint8_t *flip = b[9].buf;
    int64_t C = N8(b[7]), nconn = N8(b[2]), ntm = N8(b[5]), nts = N8(b[6]);
    int dim2 = C > 0 && N8(b[8]) == 2 * C;
    if (N8(b[10]) != 1 || N8(b[11]) != 1 || npts[0] < 0 || npts[0] >= ((int64_t)1 << 60) || N8(b[1]) != C + 1 ||
        (int64_t)b[3].len != C || (int64_t)b[9].len != C || N8(b[4]) != 4 * 256 || N8(b[12]) != 1 || N8(b[8]) != (dim2 ? 2 : 3) * C ||
        N8(b[0]) != (dim2 ? 2 : 3) * npts[0]) {
        release_arr(b, 13);
        PyErr_SetString(PyExc_ValueError, "cells_validate: inconsistent array sizes");
        return NULL;
    }
    for (int t = 0; t < 256 && !dim2; t++) { /* every template row within tmpl and tsize */
        const int64_t *e = ttab + 4 * t;
        int64_t sum = 0;
        if (e[0] == 0) continue;
        int fits = e[0] > 0 && e[0] <= 64 && e[1] > 0 && e[1] <= 64 && e[2] >= 0 && e[3] >= 0 && e[3] + e[1] <= nts;
        for (int64_t f = 0; fits && f < e[1]; f++) sum += tsize[e[3] + f] > 0 ? tsize[e[3] + f] : 1 << 20;
        if (!fits || e[2] + sum > ntm) {
            release_arr(b, 13);
            PyErr_SetString(PyExc_ValueError, "cells_validate: a template row does not fit its arrays");
            return NULL;
        }
    }
    int64_t *foff = dim2 ? NULL : malloc((size_t)(C + 1) * sizeof(int64_t));
    int fits = dim2 || foff != NULL, uniform = C > 0 && !dim2;
    int64_t k0 = C > 0 && !dim2 ? ttab[4 * types[0]] : 0;
    Py_BEGIN_ALLOW_THREADS
    fits = fits && C > 0 && off[0] == 0 && off[C] <= nconn;
    if (foff) foff[0] = 0;
    for (int64_t i = 0; i < C && fits; i++) { /* the layout, and the faces' offsets (3D) */
        int64_t s = off[i + 1] - off[i];
        if (dim2) {
            fits = s >= 1;
            continue;
        }
        const int64_t *e = ttab + 4 * types[i];
        fits = e[0] > 0 && s == e[0];
        foff[i + 1] = foff[i] + e[1];
        uniform = uniform && types[i] == types[0] && off[i] == i * k0;
    }
    Py_END_ALLOW_THREADS
    int r = -3;
    if (fits) {
        const int64_t *e = dim2 ? NULL : ttab + 4 * types[0];
        Job j = {P, conn, tmpl, tsize, 0, 0, 0, 0, npts[0], vol, cen, flip, NULL, NULL, 0, 0, off, foff, ttab, types, dim2, mode[0] == 1};
        if (uniform) { /* one type in rows of k: fixed_validate's path */
            j.tmpl = tmpl + e[2], j.tsize = tsize + e[3], j.k = e[0], j.nf = e[1];
            j.coff = j.foff = NULL;
        }
        r = validate_job(j, C, dim2 ? off[C] : foff[C], npts[0], nth[0]);
    }
    free(foff);
    release_arr(b, 13);
    if (r == -3) return PyLong_FromLong(-1);
    return validate_answer(r, "cells_validate");
}


/* bounds(points, lo, hi)
 *   points (P * d) float64, lo and hi (d,): each coordinate's minimum and maximum, NaN where the
 *   coordinate has a NaN (as numpy's min and max), one pass over the points (numpy's reductions
 *   over the rows of a (P, 3) array are slow; build._bounds). */
static PyObject *py_bounds(PyObject *self, PyObject *args) {
    static const char *const names[] = {"points", "lo", "hi"};
    static const int wr[] = {0, 1, 1};
    Py_buffer b[3];
    if (parse_bufs(args, 3, "bounds", names, NULL, wr, b) < 0) return NULL;
    const double *P = b[0].buf;
    double *lo = b[1].buf, *hi = b[2].buf;
    int64_t d = N8(b[1]), n = d > 0 ? N8(b[0]) / d : 0;
    if (d < 1 || d > 3 || N8(b[2]) != d || n * d != N8(b[0]) || n < 1) {
        release_arr(b, 3);
        PyErr_SetString(PyExc_ValueError, "bounds: inconsistent array sizes");
        return NULL;
    }
    Py_BEGIN_ALLOW_THREADS
    double mn[3], mx[3];
    int nan[3] = {0, 0, 0};
    for (int64_t j = 0; j < d; j++) mn[j] = mx[j] = P[j];
    for (int64_t i = 0; i < n; i++)
        for (int64_t j = 0; j < d; j++) {
            double v = P[i * d + j];
            mn[j] = v < mn[j] ? v : mn[j];
            mx[j] = v > mx[j] ? v : mx[j];
            nan[j] |= v != v;
        }
    for (int64_t j = 0; j < d; j++) {
        lo[j] = nan[j] ? (double)NAN : mn[j];
        hi[j] = nan[j] ? (double)NAN : mx[j];
    }
    Py_END_ALLOW_THREADS
    release_arr(b, 3);
    Py_RETURN_NONE;
}

PyObject *py_ascii_values(PyObject *self, PyObject *args); /* _fastascii.c */
PyObject *py_consistent(PyObject *self, PyObject *args); /* _fastfaces.c */
PyObject *py_fixed_consistent(PyObject *self, PyObject *args);
PyObject *py_poly_distinct(PyObject *self, PyObject *args); /* _fastpoly.c */
PyObject *py_poly_agree(PyObject *self, PyObject *args);
PyObject *py_poly_measures(PyObject *self, PyObject *args);

static PyMethodDef methods[] = {
    {"ascii_values", py_ascii_values, METH_VARARGS,
     "ascii_values(data, pos, out, kind) -> int: the next len(out) numbers of ASCII text into out, "
     "correctly rounded; the position after them, or -1."},
    {"fixed_validate", py_fixed_validate, METH_VARARGS,
     "fixed_validate(points, conn, tmpl, tsize, vol, cen, flip, npts, nthreads) -> bool: measures, "
     "centroids, own-sign flips and the consistency check of cells of one type in one pass."},
    {"poly_distinct", py_poly_distinct, METH_VARARGS,
     "poly_distinct(cface_off, face_off, face_nodes, sizes, nodes) -> int: each polyhedron's distinct nodes."},
    {"poly_agree", py_poly_agree, METH_VARARGS,
     "poly_agree(cface_off, face_off, face_nodes, open) -> int: 0 when every polyhedron's faces agree."},
    {"poly_measures", py_poly_measures, METH_VARARGS,
     "poly_measures(points, cnode_off, cnodes, cface_off, face_off, face_nodes, vol, cen) -> int: measures."},
    {"bounds", py_bounds, METH_VARARGS,
     "bounds(points, lo, hi): each coordinate's minimum and maximum (NaN where it has one), one pass."},
    {"cells_validate", py_cells_validate, METH_VARARGS,
     "cells_validate(points, offsets, conn, types, ttab, tmpl, tsize, vol, cen, flip, npts, nthreads, mode) -> int: "
     "fixed_validate for cells in CSR: mixed 3D types, or 2D polygons; -1 where it does not apply."},
    {"fixed_consistent", py_fixed_consistent, METH_VARARGS,
     "fixed_consistent(conn, tmpl, tsize, flip, npts) -> bool: consistent() for cells of one type."},
    {"consistent", py_consistent, METH_VARARGS,
     "consistent(offsets, nodes, cell, flip) -> bool: orientation._consistent (counting sort; hash table past 2^30 ids)."},
    {NULL, NULL, 0, NULL}};

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "_fastmesh",
                                    "Compiled helpers of the read stage (see models/mesh/_fastmesh.c).", -1,
                                    methods};

PyMODINIT_FUNC PyInit__fastmesh(void) { return PyModule_Create(&module); }
