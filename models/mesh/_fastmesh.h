/* What _fastmesh.c, _fastfaces.c and _fastpoly.c (one module) share. */
#ifndef MAGNET_FASTMESH_H
#define MAGNET_FASTMESH_H

/* One triangle (a, b, c) of a cell's surface, its corners relative to the cell's vertex mean (the
 * numpy path's a - o, b - o, c - o): six times its volume, einsum(a, cross(b, c)) (summed x, z, y),
 * into v_sum, and that times (a + b + c) / 4 into g_sum[3] (both in the caller's scope); one
 * division by 6 per cell afterwards. */
#define TRI(A, B, CC)                                                                              \
    do {                                                                                           \
        double a0 = (A)[0], a1 = (A)[1], a2 = (A)[2];                                              \
        double b0 = (B)[0], b1 = (B)[1], b2 = (B)[2];                                              \
        double c0 = (CC)[0], c1 = (CC)[1], c2 = (CC)[2];                                           \
        double x0 = b1 * c2 - b2 * c1, x1 = b2 * c0 - b0 * c2, x2 = b0 * c1 - b1 * c0;             \
        double t0 = a0 * x0, t1 = a1 * x1, t2 = a2 * x2;                                           \
        double v = (t0 + t2) + t1;                                                                 \
        v_sum += v;                                                                                \
        g_sum[0] += v * (((a0 + b0) + c0) * 0.25);                                                 \
        g_sum[1] += v * (((a1 + b1) + c1) * 0.25);                                                 \
        g_sum[2] += v * (((a2 + b2) + c2) * 0.25);                                                 \
    } while (0)

#include <stdint.h>

/* A face's directed key less its smallest node, packed in one 64-bit word: the node after it (bits
 * 33..62), the node before it (bits 3..32), min(size, 7) (bits 0..2), the cell's flip applied
 * (after and before swapped). Exact for point ids < 2^30 (the callers take the check only then);
 * an id out of range can only make two keys look alike: a contradiction where there is none, which
 * sends the caller to the full path, never the reverse. */
#define KEY_ID_LIMIT ((int64_t)1 << 30)

/* One cell's faces: each face's smallest node (mins) and its packed key (keys), in template order;
 * S > 0: every face has S nodes (a constant the compiler unrolls), else tsize says. 1: a smallest
 * node out of 0..P-1; 2: all keyed, but a face has a node repeated (a collapsed cell). */
static inline __attribute__((always_inline)) int cell_face_keys(const int64_t *c, const int64_t *tmpl,
                                                                const int64_t *tsize, int64_t nf, int64_t S,
                                                                int fl, int64_t P, uint32_t *mins,
                                                                uint64_t *keys) {
    int64_t pos = 0;
    int collapsed = 0;
    for (int64_t f = 0; f < nf; f++) {
        int64_t s = S > 0 ? S : tsize[f], j = 0;
        const int64_t *t = tmpl + pos;
        pos += s;
        for (int64_t q = 1; q < s; q++)
            if (c[t[q]] < c[t[j]]) j = q; /* first of the smallest (argmin) */
        int64_t m = c[t[j]];
        if (m < 0 || m >= P) return 1;
        for (int64_t q = 0; q < s; q++) /* a node repeated along the face: a collapsed cell */
            if (c[t[q]] == c[t[q + 1 == s ? 0 : q + 1]]) collapsed = 1;
        uint64_t nx = (uint64_t)c[t[j + 1 == s ? 0 : j + 1]], pv = (uint64_t)c[t[j == 0 ? s - 1 : j - 1]];
        if (fl) {
            uint64_t x = nx;
            nx = pv;
            pv = x;
        }
        mins[f] = (uint32_t)m;
        keys[f] = nx << 33 | pv << 3 | (uint64_t)(s < 7 ? s : 7);
    }
    return collapsed ? 2 : 0;
}


/* "none" in the face check's uint32 chains and positions */
#define NONE32 UINT32_MAX

/* The face check's scratch (_fastfaces.c face_scratch): keys, sorted keys, smallest nodes, chains,
 * bucket starts and per-thread counts, in one block. */
typedef struct {
    uint64_t *keys, *sorted;
    uint32_t *mins, *prev, *start, *cnt;
    void *block;
} Scratch;

/* _fastfaces.c: the face check's scratch, its bucket comparison, and the counting-sort check */
Scratch face_scratch(int64_t F, int64_t P, int64_t R);
void scratch_give(void *p);
int buckets_once(const uint64_t *sorted, const uint32_t *start, int64_t plo, int64_t phi, int64_t P,
                 uint32_t *prev, uint32_t **head);
int faces_consistent(uint32_t *mins, const uint64_t *keys, uint64_t *sorted, int64_t F, int64_t P,
                     uint32_t *start);

#endif
