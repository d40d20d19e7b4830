/* BMUofN for CPU devices (PoCL): cache-blocked, register-blocked, no barriers.
 *
 * One work-item owns a panel of P rows of X, i.e. PV = P * NV varied vectors. It first
 * stages the varied vectors sign[v, k] * x[index[v, k]] of its panel in private memory
 * (the gather happens once per row and variation, never in the inner loop), then sweeps
 * the codebook in cache blocks of UBLK tiles. A tile is TILE = UB * VW units stored
 * contiguously as (D, TILE) (the host lays the codebook out as (MP / TILE, D, TILE)), so a
 * cache block of UBLK tiles stays in L2 while every register block of RS varied vectors
 * of the panel runs over it: per dimension k, UB vector loads of the tile feed RS * UB
 * vector FMAs (an outer product, as in a GEMM micro-kernel).
 *
 * The distance expansion ||w||^2 - 2 x_v.w is kept per SIMD lane (best and second best,
 * in ascending unit order per lane) and reduced across lanes with the (distance, unit)
 * lexicographic order, so ties go to the lowest unit; across variations a later
 * variation wins when strictly closer (||x_v||^2 added) or equally close at a lower unit:
 * ties go to the lowest unit, then the lowest variation (DESIGN.md section 4). The
 * arithmetic (fma over k = 0..D-1, then wn - 2 acc) is the one of kernels/bmu.cl.
 *
 * Compile-time sizes (-D):
 *   REAL, IREAL  float/int or double/long (IREAL: the mask type of REAL comparisons)
 *   VW           SIMD lanes per vector (2, 4, 8 or 16);  UB: vectors per tile
 *   D            dimension;  NV: variations
 *   P            rows per work-item (P * NV is a multiple of RS)
 *   RS           varied vectors per register block
 *   UBLK         tiles per cache block
 */

#define TILE (UB * VW)
#define PV (P * NV)

__kernel void bmu_of_n_cpu(__global const REAL *X,        /* (N, D) */
                           const int N,
                           __global const REAL *WB,       /* (MP / TILE, D, TILE): tiled codebook */
                           __global const REAL *wnorm,    /* (MP,): ||w||^2, +inf on padding */
                           const int MP,                  /* padded unit count, a multiple of TILE */
                           __global const int *index,     /* (NV, D) */
                           __global const REAL *sign,     /* (NV, D) */
                           __global int *out_unit,        /* (N,) */
                           __global int *out_var,         /* (N,) */
                           __global REAL *out_dist2,      /* (N,) */
                           __global int *out_second)      /* (N,) */
{
    INJECTED_TRAP();
    const int row0 = get_global_id(0) * P;
    if (row0 >= N)
        return;

    /* the panel's varied vectors, r = j * NV + v; rows past N repeat row N - 1 */
    REAL xs[PV * D];
    for (int j = 0; j < P; ++j) {
        const int row = min(row0 + j, N - 1);
        for (int v = 0; v < NV; ++v)
            for (int k = 0; k < D; ++k)
                xs[(j * NV + v) * D + k] = sign[v * D + k] * X[row * D + index[v * D + k]];
    }

    realv bd[PV], sd[PV];
    irealv bu[PV], su[PV];
    for (int r = 0; r < PV; ++r) {
        bd[r] = (realv)(INFINITY);
        sd[r] = (realv)(INFINITY);
        bu[r] = (irealv)(MP);
        su[r] = (irealv)(MP);
    }

    const int ntiles = MP / TILE;
    for (int t0 = 0; t0 < ntiles; t0 += UBLK) {
        const int t1 = min(t0 + UBLK, ntiles);
        for (int r0 = 0; r0 < PV; r0 += RS) {
            const REAL *xr = xs + r0 * D;
            for (int t = t0; t < t1; ++t) {
                __global const REAL *wt = WB + (size_t)t * (D * TILE);
                realv acc[RS][UB];
#pragma unroll
                for (int r = 0; r < RS; ++r)
#pragma unroll
                    for (int b = 0; b < UB; ++b)
                        acc[r][b] = (realv)(0);
                for (int k = 0; k < D; ++k) {
                    realv w[UB];
#pragma unroll
                    for (int b = 0; b < UB; ++b)
                        w[b] = *(__global const realv *)(wt + k * TILE + b * VW);
#pragma unroll
                    for (int r = 0; r < RS; ++r) {
                        const realv xv = (realv)(xr[r * D + k]);
#pragma unroll
                        for (int b = 0; b < UB; ++b)
                            acc[r][b] = xv * w[b] + acc[r][b];  /* contracted to an FMA */
                    }
                }
#pragma unroll
                for (int b = 0; b < UB; ++b) {
                    const int m0 = t * TILE + b * VW;
                    const realv wn = *(__global const realv *)(wnorm + m0);
                    const irealv u = (irealv)(m0) + LANES;
#pragma unroll
                    for (int r = 0; r < RS; ++r) {
                        const realv d = wn - (REAL)2 * acc[r][b];
                        const irealv second = d < sd[r0 + r];
                        if (!ANY(second))
                            continue;
                        const irealv better = d < bd[r0 + r];
                        sd[r0 + r] = better ? bd[r0 + r] : (second ? d : sd[r0 + r]);
                        su[r0 + r] = better ? bu[r0 + r] : (second ? u : su[r0 + r]);
                        bd[r0 + r] = better ? d : bd[r0 + r];
                        bu[r0 + r] = better ? u : bu[r0 + r];
                    }
                }
            }
        }
    }

    for (int j = 0; j < P; ++j) {
        if (row0 + j >= N)
            break;
        REAL xnorm[NV];
        for (int v = 0; v < NV; ++v) {
            REAL xn = 0;
            for (int k = 0; k < D; ++k) {
                const REAL xv = xs[(j * NV + v) * D + k];
                xn = fma(xv, xv, xn);
            }
            xnorm[v] = xn;
        }
        finish_row(bd + j * NV, bu + j * NV, sd + j * NV, su + j * NV, xnorm, NV, MP, row0 + j,
                   out_unit, out_var, out_dist2, out_second);
    }
}
