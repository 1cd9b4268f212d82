/* The read stage's face check (in the _fastmesh module; see _fastmesh.c): is any face met twice in
 * the same direction once each cell is flipped by its sign? The faces' directed keys (_fastmesh.h
 * cell_face_keys) bucketed by their smallest node (a counting sort over the points), then compared
 * within each bucket; a hash table where point ids pass 2^30. The scratch arena kept between calls.
 *
 *   consistent        orientation._consistent on a face array (CSR)
 *   fixed_consistent  the same for cells of one type, their faces from the type's template
 *   faces_consistent, buckets_once, face_scratch: what fixed_validate and cells_validate's staged
 *                     check (_fastmesh.c) share with them
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include "_buffers.h"
#include "_fastmesh.h"
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#include <sys/mman.h>

/* consistent(offsets, nodes, cell, flip) -> bool
 *   faces in CSR (offsets (F+1,), nodes), cell (F,) their cells, flip (C,) uint8. A face's directed
 *   key: (smallest node, the node after it, the node before it, min(size, 7)), after and before
 *   swapped where its cell is flipped. False when a key is met twice. */
typedef struct {
    int64_t m, nx, pv, s;
} Key;

static inline uint64_t mix(uint64_t h) {
    h ^= h >> 33;
    h *= 0xff51afd7ed558ccdULL;
    h ^= h >> 33;
    h *= 0xc4ceb9fe1a85ec53ULL;
    h ^= h >> 33;
    return h;
}

/* consistent's answer by a hash table of the directed keys (any point ids): 1 no key met twice, 0
 * one met twice, -1 out of memory. Called with the GIL released. */
static int consistent_hash(const int64_t *off, const int64_t *nodes, const int64_t *cell, const uint8_t *flip,
                           int64_t F, int64_t nc) {
    uint64_t cap = 16;
    while (cap < 2 * (uint64_t)F) cap <<= 1;
    Key *table = malloc(cap * sizeof(Key));
    if (table == NULL) return -1;
    int ok = 1;
    for (uint64_t i = 0; i < cap; i++) table[i].s = -1;
    for (int64_t f = 0; f < F && ok; f++) {
        int64_t a = off[f], s = off[f + 1] - a;
        if (s < 1 || cell[f] < 0 || cell[f] >= nc) continue; /* not a face: left to the full path */
        int64_t j = 0;
        for (int64_t q = 1; q < s; q++)
            if (nodes[a + q] < nodes[a + j]) j = q; /* first of the smallest (argmin) */
        Key key = {nodes[a + j], nodes[a + (j + 1) % s], nodes[a + (j + s - 1) % s], s < 7 ? s : 7};
        if (flip[cell[f]]) {
            int64_t t = key.nx;
            key.nx = key.pv;
            key.pv = t;
        }
        uint64_t h = mix((uint64_t)key.m * 0x9E3779B97F4A7C15ULL ^ mix((uint64_t)key.nx) ^
                         (mix((uint64_t)key.pv) << 1) ^ (uint64_t)key.s) & (cap - 1);
        for (;;) {
            Key *e = table + h;
            if (e->s < 0) {
                *e = key;
                break;
            }
            if (e->m == key.m && e->nx == key.nx && e->pv == key.pv && e->s == key.s) {
                ok = 0;
                break;
            }
            h = (h + 1) & (cap - 1);
        }
    }
    free(table);
    return ok;
}

/* Is a key met twice in sorted[lo..hi) (one bucket: the faces of one smallest node)? Small buckets
 * pairwise; larger ones (tetrahedra: ~24 faces a point) by chains of the keys of the same next
 * node: head[n] the last position of the bucket whose key has next node n (UINT32_MAX or a position
 * before lo: none), prev[x] the one before x. 1: a key met twice; -1: a next node out of range. */
static int bucket_has_twice(const uint64_t *sorted, uint32_t lo, uint32_t hi, int64_t P, uint32_t *head,
                            uint32_t *prev) {
    if (hi - lo <= 8 || head == NULL) {
        for (uint32_t x = lo; x < hi; x++)
            for (uint32_t y = x + 1; y < hi; y++)
                if (sorted[x] == sorted[y]) return 1;
        return 0;
    }
    for (uint32_t x = lo; x < hi; x++)
        if ((int64_t)(sorted[x] >> 33) >= P) return -1;
    for (uint32_t x = lo; x < hi; x++) {
        uint64_t n = sorted[x] >> 33;
        uint32_t y = head[n];
        prev[x] = y != NONE32 && y >= lo ? y : NONE32;
        for (uint32_t z = prev[x]; z != NONE32; z = prev[z])
            if (sorted[z] == sorted[x]) return 1;
        head[n] = x;
    }
    return 0;
}

/* 1 when no key is met twice in any bucket p of plo..phi-1 (sorted[start[p]..start[p+1]): small
 * buckets pairwise, inline (the common case), larger ones by bucket_has_twice's chains (prev: scratch
 * by position, one entry per key of these buckets; *head: chain heads, P entries, made at the first
 * large bucket and kept for the caller's later ranges (positions only grow from one range to the next
 * of one caller: an old head is never taken for this bucket's); without memory for it, pairwise); 0
 * otherwise. The caller frees *head. */
int buckets_once(const uint64_t *sorted, const uint32_t *start, int64_t plo, int64_t phi, int64_t P,
                        uint32_t *prev, uint32_t **head) {
    int ok = 1;
    for (int64_t p = plo; p < phi && ok; p++) {
        uint32_t lo = start[p], hi = start[p + 1];
        if (hi - lo <= 8) {
            for (uint32_t x = lo; x < hi && ok; x++)
                for (uint32_t y = x + 1; y < hi; y++)
                    if (sorted[x] == sorted[y]) {
                        ok = 0;
                        break;
                    }
            continue;
        }
        if (*head == NULL) {
            *head = malloc((size_t)P * sizeof(uint32_t));
            if (*head) memset(*head, 0xff, (size_t)P * sizeof(uint32_t)); /* NONE32 */
        }
        int r = bucket_has_twice(sorted, lo, hi, P, *head, prev);
        if (r < 0) r = bucket_has_twice(sorted, lo, hi, P, NULL, NULL);
        if (r) ok = 0;
    }
    return ok;
}

/* The face check's scratch (Scratch: keys, sorted keys, smallest nodes, chains, bucket starts and
 * per-thread counts) in one block. Blocks up to ARENA_MAX come from one arena kept between calls
 * (taken and given back with the GIL held; a call while it is taken, or a larger mesh, mallocs):
 * freshly mapped pages fault one by one on first touch, and on this kind of machine that cost as
 * much as the check itself (10^4 hexahedra: ~500 faults, ~0.6 ms of a 1 ms build). The arena is on
 * transparent huge pages where the kernel allows it (madvise), and stays mapped for the process's
 * life (at most ARENA_MAX: the scratch of ~400,000 hexahedra). */
#define ARENA_MAX ((size_t)64 << 20)
static char *arena = NULL;
static size_t arena_cap = 0;
static int arena_busy = 0;

static void *scratch_take(size_t n) {
    if (n == 0) n = 1;
    if (arena_busy || n > ARENA_MAX) return malloc(n);
    if (arena_cap < n) {
        size_t cap = (n + ((size_t)2 << 20) - 1) & ~(((size_t)2 << 20) - 1); /* whole 2 MiB pages */
        void *p = mmap(NULL, cap, PROT_READ | PROT_WRITE, MAP_PRIVATE | MAP_ANONYMOUS, -1, 0);
        if (p == MAP_FAILED) return malloc(n);
#ifdef MADV_HUGEPAGE
        madvise(p, cap, MADV_HUGEPAGE);
#endif
        if (arena) munmap(arena, arena_cap);
        arena = p;
        arena_cap = cap;
    }
    arena_busy = 1;
    return arena;
}

void scratch_give(void *p) {
    if (p != NULL && p == (void *)arena)
        arena_busy = 0;
    else
        free(p);
}


/* The scratch of F faces over P points: keys, sorted keys, smallest nodes, bucket starts; with R > 0
 * (fixed_validate's staged check) also the chains and R ranges' counts. .block NULL when out of
 * memory. GIL held. */
Scratch face_scratch(int64_t F, int64_t P, int64_t R) {
    Scratch s = {0};
    if (F < 1) F = 1;
    if (P < 0) P = 0;
    size_t n = (size_t)F * (2 * sizeof(uint64_t) + sizeof(uint32_t)) + ((size_t)P + 2) * sizeof(uint32_t);
    if (R > 0) n += (size_t)F * sizeof(uint32_t) + (size_t)R * (size_t)P * sizeof(uint32_t);
    char *b = scratch_take(n);
    if (!b) return s;
    s.block = b;
    s.keys = (uint64_t *)b;
    s.sorted = s.keys + F;
    s.mins = (uint32_t *)(s.sorted + F);
    s.start = s.mins + F;
    if (R > 0) {
        s.prev = s.start + P + 2;
        s.cnt = s.prev + F;
    }
    return s;
}

/* The check fixed_consistent and fixed_validate share, on the faces' smallest nodes (mins, in
 * 0..P-1) and packed keys (F of each): the keys bucketed by smallest node (a counting sort over the
 * points: cache-friendly, unlike a hash table of every face), then compared within each bucket.
 * mins is scratch afterwards; start: P + 2 entries of scratch. 1: no key met twice (consistent);
 * 0: one met twice, or a mesh too large for the packed keys (P >= 2^30 or F >= 2^32: the full path
 * decides). */
int faces_consistent(uint32_t *mins, const uint64_t *keys, uint64_t *sorted, int64_t F, int64_t P,
                            uint32_t *start) {
    if (P >= KEY_ID_LIMIT || F >= (int64_t)NONE32) return 0;
    int ok;
    memset(start, 0, ((size_t)P + 2) * sizeof(uint32_t));
    for (int64_t f = 0; f < F; f++) start[mins[f] + 2]++;
    for (int64_t p = 2; p < P + 2; p++) start[p] += start[p - 1];
    for (int64_t f = 0; f < F; f++) sorted[start[mins[f] + 1]++] = keys[f];
    uint32_t *head = NULL;
    ok = buckets_once(sorted, start, 0, P, P, mins, &head); /* mins is free now: the chains' prev */
    free(head);
    return ok;
}

/* consistent() by the counting sort of faces_consistent (the faces' smallest nodes bucketed, the
 * packed keys compared): the hash table's answer, with less memory touched. The hash table serves
 * meshes whose point ids do not fit the packed keys (2^30 and more, or a negative one). */
PyObject *py_consistent(PyObject *self, PyObject *args) {
    static const char *const names[] = {"offsets", "nodes", "cell", "flip"};
    static const Py_ssize_t sizes[] = {8, 8, 8, 1};
    static const int wr[] = {0, 0, 0, 0};
    Py_buffer b[4];
    if (parse_bufs(args, 4, "consistent", names, sizes, wr, b) < 0) return NULL;
    const int64_t *off = b[0].buf, *nodes = b[1].buf, *cell = b[2].buf;
    const uint8_t *flip = b[3].buf;
    int64_t F = N8(b[0]) - 1, nn = N8(b[1]), nc = (int64_t)b[3].len, P = 0;
    if (F < 0 || N8(b[2]) != F || (F > 0 && off[F] > nn)) {
        release_arr(b, 4);
        PyErr_SetString(PyExc_ValueError, "consistent: inconsistent array sizes");
        return NULL;
    }
    int packed = 1; /* the packed keys hold these faces: CSR offsets, point ids in 0..2^30 */
    for (int64_t f = 0; packed && f < F; f++) packed = off[f] >= 0 && off[f + 1] >= off[f];
    for (int64_t j = 0; packed && j < (F > 0 ? off[F] : 0); j++) {
        if (nodes[j] < 0) packed = 0;
        else if (nodes[j] >= P) P = nodes[j] + 1;
    }
    packed = packed && P < KEY_ID_LIMIT && F < (int64_t)NONE32;
    Scratch sc = packed ? face_scratch(F, P, 0) : (Scratch){0};
    int ok = -1;
    Py_BEGIN_ALLOW_THREADS
    if (!packed) {
        ok = consistent_hash(off, nodes, cell, flip, F, nc);
    } else if (sc.block) {
        int64_t G = 0; /* the faces keyed (a face of no node, or of no cell, is left to the full path) */
        for (int64_t f = 0; f < F; f++) {
            int64_t a = off[f], s = off[f + 1] - a;
            if (s < 1 || cell[f] < 0 || cell[f] >= nc) continue;
            int64_t j = 0;
            for (int64_t q = 1; q < s; q++)
                if (nodes[a + q] < nodes[a + j]) j = q; /* first of the smallest (argmin) */
            uint64_t nx = (uint64_t)nodes[a + (j + 1) % s], pv = (uint64_t)nodes[a + (j + s - 1) % s];
            if (flip[cell[f]]) {
                uint64_t t = nx;
                nx = pv;
                pv = t;
            }
            sc.mins[G] = (uint32_t)nodes[a + j];
            sc.keys[G++] = nx << 33 | pv << 3 | (uint64_t)(s < 7 ? s : 7);
        }
        ok = faces_consistent(sc.mins, sc.keys, sc.sorted, G, P, sc.start);
    }
    Py_END_ALLOW_THREADS
    if (sc.block) scratch_give(sc.block);
    release_arr(b, 4);
    if (ok < 0) return PyErr_NoMemory();
    return PyBool_FromLong(ok);
}

/* fixed_consistent(conn, tmpl, tsize, flip, npts) -> bool
 *   consistent() for cells of one type with a fixed node count, their faces taken from the
 *   template (as measure_cell) instead of a face array; npts (1,) the number of points
 *   (< 2^60). The faces' smallest nodes and keys here, then faces_consistent. */
PyObject *py_fixed_consistent(PyObject *self, PyObject *args) {
    static const char *const names[] = {"conn", "tmpl", "tsize", "flip", "npts"};
    static const Py_ssize_t sizes[] = {8, 8, 8, 1, 8};
    static const int wr[] = {0, 0, 0, 0, 0};
    Py_buffer b[5];
    if (parse_bufs(args, 5, "fixed_consistent", names, sizes, wr, b) < 0) return NULL;
    const int64_t *conn = b[0].buf, *tmpl = b[1].buf, *tsize = b[2].buf, *npts = b[4].buf;
    const uint8_t *flip = b[3].buf;
    int64_t C = (int64_t)b[3].len, nf = N8(b[2]), nt = N8(b[1]);
    int64_t k = C ? N8(b[0]) / C : 0, sum = 0;
    for (int64_t f = 0; f < nf; f++) sum += tsize[f];
    if (N8(b[4]) != 1 || npts[0] < 0 || npts[0] >= ((int64_t)1 << 60) || (C && k * C != N8(b[0])) || sum != nt ||
        nf > 64) {
        release_arr(b, 5);
        PyErr_SetString(PyExc_ValueError, "fixed_consistent: inconsistent array sizes");
        return NULL;
    }
    int64_t P = npts[0], F = C * nf;
    Scratch s = face_scratch(F, P, 0);
    uint64_t *keys = s.keys;
    uint32_t *mins = s.mins;
    int ok = 1, err = !s.block;
    Py_BEGIN_ALLOW_THREADS
    if (!err)
        for (int64_t i = 0; i < C; i++) /* every face's smallest node and key */
            if (cell_face_keys(conn + i * k, tmpl, tsize, nf, 0, flip[i], P, mins + i * nf, keys + i * nf) == 1) {
                err = 2;
                break;
            }
    if (!err) ok = faces_consistent(mins, keys, s.sorted, F, P, s.start);
    Py_END_ALLOW_THREADS
    scratch_give(s.block);
    release_arr(b, 5);
    if (err == 1) return PyErr_NoMemory();
    if (err) {
        PyErr_SetString(PyExc_ValueError, "fixed_consistent: a point id is out of range");
        return NULL;
    }
    return PyBool_FromLong(ok);
}
