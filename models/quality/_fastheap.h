/* A max-heap on a struct's double field U, for the best-first searches of _fastmetrics.c (3D) and
 * _fastcircle.c (2D): MAX_HEAP(Heap, Cell, prefix) defines the type Heap (a growing array of Cell)
 * and prefix_push(Heap *, Cell) -> 0, or -1 out of memory; prefix_pop(Heap *) -> the largest U. */
#ifndef MAGNET_FASTHEAP_H
#define MAGNET_FASTHEAP_H

#include <stdint.h>
#include <stdlib.h>

#define MAX_HEAP(HeapT, CellT, prefix)                                            \
    typedef struct {                                                             \
        CellT *a;                                                                \
        int64_t n, cap;                                                          \
    } HeapT;                                                                     \
                                                                                 \
    static int prefix##_push(HeapT *H, CellT c) {                                \
        if (H->n >= H->cap) {                                                    \
            int64_t cap = H->cap ? 2 * H->cap : 256;                             \
            CellT *na = (CellT *)realloc(H->a, (size_t)cap * sizeof(CellT));     \
            if (!na) return -1;                                                  \
            H->a = na;                                                           \
            H->cap = cap;                                                        \
        }                                                                        \
        int64_t i = H->n++;                                                      \
        while (i > 0) {                                                          \
            int64_t p = (i - 1) / 2;                                             \
            if (H->a[p].U >= c.U) break;                                         \
            H->a[i] = H->a[p];                                                   \
            i = p;                                                               \
        }                                                                        \
        H->a[i] = c;                                                             \
        return 0;                                                                \
    }                                                                            \
                                                                                 \
    static CellT prefix##_pop(HeapT *H) {                                        \
        CellT top = H->a[0];                                                     \
        CellT last = H->a[--H->n];                                               \
        int64_t i = 0;                                                           \
        for (;;) {                                                               \
            int64_t l = 2 * i + 1, r = l + 1, b = i;                             \
            double bu = last.U;                                                  \
            if (l < H->n && H->a[l].U > bu) { b = l; bu = H->a[l].U; }           \
            if (r < H->n && H->a[r].U > bu) b = r;                               \
            if (b == i) break;                                                   \
            H->a[i] = H->a[b];                                                   \
            i = b;                                                               \
        }                                                                        \
        if (H->n) H->a[i] = last;                                                \
        return top;                                                              \
    }

#endif
