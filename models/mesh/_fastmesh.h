/* What _fastmesh.c and _fastpoly.c (one module) share. */
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

#endif
