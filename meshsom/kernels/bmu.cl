/* BMUofN: best-matching unit of n variations, fused (no distance matrix).
 *
 * Every work-item owns RX rows of X and all NV variations of each, i.e. R = RX * NV
 * varied vectors, and sweeps the codebook in tiles of TILE_M = UB * VW units. For each
 * dimension k it gathers the varied values sign[v, k] * x[index[v, k]] on the fly and
 * accumulates R x UB vector dot products (a register-blocked outer product) against the
 * transposed codebook tile, which is staged in local memory when USE_LOCAL is 1.
 * The distance expansion ||w||^2 - 2 x_v.w is tracked per SIMD lane (best and second, in
 * ascending unit order per lane) and reduced across lanes with the (distance, unit)
 * lexicographic order, so ties go to the lowest unit; across variations a later
 * variation wins when strictly closer (||x_v||^2 added) or equally close at a lower unit:
 * ties go to the lowest unit, then the lowest variation (DESIGN.md section 4).
 *
 * Compile-time sizes (-D):
 *   REAL, IREAL  float/int or double/long (IREAL: the mask type of REAL comparisons)
 *   VW           SIMD lanes per vector (2, 4, 8 or 16)
 *   UB           vectors of units per work-item step; TILE_M = UB * VW
 *   D            dimension;  DT: dimensions per local tile (DT divides D)
 *   NV           variations;  RX: X rows per work-item
 *   USE_LOCAL    1: stage the codebook tile (DT x TILE_M) in local memory
 *   WG           work-group size (USE_LOCAL needs it for the cooperative load)
 */

#define TILE_M (UB * VW)
#define R (RX * NV)

__kernel
#if USE_LOCAL
__attribute__((reqd_work_group_size(WG, 1, 1)))
#endif
void bmu_of_n(__global const REAL *X,        /* (N, D) */
              const int N,
              __global const REAL *WT,       /* (D, MP): transposed codebook, zero-padded */
              __global const REAL *wnorm,    /* (MP,): ||w||^2, +inf on padding */
              const int MP,                  /* padded unit count, a multiple of TILE_M */
              __global const int *index,     /* (NV, D) */
              __global const REAL *sign,     /* (NV, D) */
              __global int *out_unit,        /* (N,) */
              __global int *out_var,         /* (N,) */
              __global REAL *out_dist2,      /* (N,) */
              __global int *out_second)      /* (N,) */
{
    INJECTED_TRAP();
    const int row0 = get_global_id(0) * RX;
    int rows[RX];
    for (int j = 0; j < RX; ++j)
        rows[j] = min(row0 + j, N - 1);      /* clamp: extra rows compute but never write */

    realv bd[R], sd[R];
    irealv bu[R], su[R];
    for (int r = 0; r < R; ++r) {
        bd[r] = (realv)(INFINITY);
        sd[r] = (realv)(INFINITY);
        bu[r] = (irealv)(MP);
        su[r] = (irealv)(MP);
    }

#if USE_LOCAL
    __local REAL Wl[DT * TILE_M];
    const int lid = get_local_id(0);
#endif

    for (int m0 = 0; m0 < MP; m0 += TILE_M) {
        realv acc[R][UB];
        for (int r = 0; r < R; ++r)
            for (int b = 0; b < UB; ++b)
                acc[r][b] = (realv)(0);

        for (int k0 = 0; k0 < D; k0 += DT) {
#if USE_LOCAL
            barrier(CLK_LOCAL_MEM_FENCE);
            for (int t = lid; t < DT * TILE_M; t += WG)
                Wl[t] = WT[(k0 + t / TILE_M) * MP + m0 + t % TILE_M];
            barrier(CLK_LOCAL_MEM_FENCE);
#endif
            for (int kk = 0; kk < DT; ++kk) {
                const int k = k0 + kk;
                realv w[UB];
                for (int b = 0; b < UB; ++b) {
#if USE_LOCAL
                    LOAD_V(w[b], Wl + kk * TILE_M + b * VW);
#else
                    LOAD_V(w[b], WT + k * MP + m0 + b * VW);
#endif
                }
                for (int v = 0; v < NV; ++v) {
                    const int ix = index[v * D + k];
                    const REAL s = sign[v * D + k];
                    for (int j = 0; j < RX; ++j) {
                        const realv xv = (realv)(s * X[rows[j] * D + ix]);
                        for (int b = 0; b < UB; ++b)
                            acc[j * NV + v][b] = xv * w[b] + acc[j * NV + v][b];  /* contracted to an FMA */
                    }
                }
            }
        }

        for (int b = 0; b < UB; ++b) {
            realv wn;
            LOAD_V(wn, wnorm + m0 + b * VW);
            const irealv u = (irealv)(m0 + b * VW) + LANES;
            for (int r = 0; r < R; ++r) {
                const realv d = wn - (REAL)2 * acc[r][b];
                const irealv better = d < bd[r];
                const irealv second = d < sd[r];
                /* operators, not the fma/select builtins: PoCL may leave those as calls */
                sd[r] = better ? bd[r] : (second ? d : sd[r]);
                su[r] = better ? bu[r] : (second ? u : su[r]);
                bd[r] = better ? d : bd[r];
                bu[r] = better ? u : bu[r];
            }
        }
    }

    if (row0 >= N)
        return;
    for (int j = 0; j < RX; ++j) {
        if (row0 + j >= N)
            break;
        REAL xnorm[NV];
        for (int v = 0; v < NV; ++v) {
            REAL xn = 0;
            for (int k = 0; k < D; ++k) {
                const REAL xv = sign[v * D + k] * X[rows[j] * D + index[v * D + k]];
                xn = fma(xv, xv, xn);
            }
            xnorm[v] = xn;
        }
        finish_row(bd + j * NV, bu + j * NV, sd + j * NV, su + j * NV, xnorm, NV, MP, row0 + j,
                   out_unit, out_var, out_dist2, out_second);
    }
}
