/* BMUofN for GPUs: a register-tiled GEMM micro-kernel with a fused best/second epilogue.
 *
 * The varied vectors are virtual rows: virtual row q = row * NV + v is the vector
 * sign[v, k] * x[row, index[v, k]], k = 0..D-1 (NR = N * NV of them). As in an SGEMM
 * (CLBlast's layout), a work-group of WGN x WGM work-items computes a tile of TM virtual
 * rows x TN units: every work-item accumulates RM = TM / WGM rows x RN = TN / WGN units in
 * registers. The row tile of X is gathered with the signs (zero past D) into local memory
 * once for all of D where it fits (XRES: it is the same for every unit tile), else per chunk;
 * the codebook, padded with zeros to (MP, DP) on the device (pad_codebook: the staging needs
 * no bounds), is staged through local memory in chunks of KT dimensions, double-buffered (PF): the
 * global loads of chunk c + 1 are in flight (in registers) while chunk c is multiplied, those
 * of the next unit tile's first chunk during a tile's last chunk and its epilogue (no load
 * waited for at a tile's start), with one barrier per chunk.
 *
 * A work-item owns the rows (i * WGM + ty) * VW + l and the units (j * WGN + tx) * VW + l
 * (i < RM / VW, j < RN / VW, l < VW): its operands are VW-wide vector loads from local
 * memory, consecutive work-items reading consecutive vectors (no bank conflicts).
 *
 * Arithmetic, the same as kernels/bmu.cl and kernels/bmu_cpu.cl: per (virtual row, unit)
 * one accumulator, a sequential fma over k = 0..D-1 (the zero padding past D adds exact
 * zeros), then d = ||w||^2 - 2 acc. The epilogue keeps, per row, the best and second
 * best (d, unit) in the lexicographic order of INSERT over the work-item's units and unit
 * tiles (the common case, none of a row's RN distances of a tile below its second, costs one
 * comparison each and one branch per row); the WGN work-items sharing a row are folded in
 * local memory, and every
 * work-group writes the best and second of its TM rows over its range of unit tiles (its
 * split s of S) to the partial arrays (NR, S). bmu_of_n_gemm_reduce then folds the splits
 * (INSERT again) and the variations (||x_v||^2 added; a later variation wins when strictly
 * closer, or equally close at a lower unit; DESIGN.md section 4) into the four outputs.
 *
 * Compile-time sizes (-D), besides those of bmu_common.cl (REAL, IREAL, VW, D):
 *   NV           variations
 *   TM, TN       virtual rows and units per work-group tile
 *   WGM, WGN     work-items along rows (local id 1) and along units (local id 0)
 *   KT           dimensions per local-memory chunk;  DP: D rounded up to a multiple of KT
 *   XRES         1: the row tile's varied vectors gathered into local memory once, for all
 *                of D (DP x TM), only W staged per chunk; 0: X staged per chunk like W
 *   PF           1: double-buffered chunks (the loads of the next chunk, of this unit tile or
 *                the next, in flight while one is multiplied, one barrier per chunk); 0: one
 *                buffer, load then multiply (two
 *                barriers per chunk, the load registers free during the products: fewer
 *                registers, more work-groups per compute unit)
 *   EXACT        type of the winners' direct squared distance: double where the device has
 *                it, else REAL
 *   MESHSOM_ABLATE   timing hook of bench/gpu.py --diagnose, never set otherwise (the answers are
 *                wrong with it): bit 1 drops the epilogue's comparisons (each distance is only
 *                added to a sink that is written out), bit 2 stages the codebook's chunks of
 *                the first unit tile only (no global loads or local stores after it); the
 *                time saved is the share of that stage
 *   UNROLL_EPILOGUE  1: unroll the loops over the running best and second and the staging
 *                loops (GPUs: keeps them in registers); 0 on CPU devices, where PoCL compiles
 *                the unrolled branches about 3x slower for no gain (meshsom.bmu_opencl.get_kernel)
 * TM / WGM and TN / WGN are multiples of VW; TM * KT and TN * KT need not be multiples of
 * the work-group size.
 */

#define WGS (WGM * WGN)
#define RM (TM / WGM)           /* virtual rows per work-item */
#define RN (TN / WGN)           /* units per work-item */
#define XVEC (RM / VW)          /* row vectors per work-item */
#define WVEC (RN / VW)          /* unit vectors per work-item */
#if XRES
#define XSTRIDE TM              /* the whole row tile, stored once: not padded (float32 D = 144 fits 48 KB) */
#else
#define XSTRIDE (TM + VW)       /* local X row of one dimension, padded: fewer bank conflicts on the stores */
#endif
#define WSTRIDE (TN + VW)       /* local W row of one dimension, likewise */
#define XLOADS ((TM * KT + WGS - 1) / WGS)  /* X elements each work-item stages per chunk */
#define WLOADS ((TN * KT + WGS - 1) / WGS)  /* W elements each work-item stages per chunk */
#define NCHUNK (DP / KT)
#define XFULL ((TM * KT) % WGS == 0)   /* every work-item stages XLOADS elements of X, none past the chunk */
#define WFULL ((TN * KT) % WGS == 0)   /* likewise for W */
#ifndef MESHSOM_ABLATE
#define MESHSOM_ABLATE 0
#endif
#define ABLATE_EPILOGUE (MESHSOM_ABLATE & 1)
#define ABLATE_STAGING (MESHSOM_ABLATE & 2)
/* the staging and epilogue loops are unrolled on GPUs only (UNROLL_EPILOGUE): PoCL compiles them slower */
#if UNROLL_EPILOGUE
#define UNROLL_GPU _Pragma("unroll")
#else
#define UNROLL_GPU
#endif

/* Global loads of chunk k0 into registers (the macros' locals are named apart from the
 * kernel's variables that k0 and b may mention): X gathered with signs (zero outside the rows or
 * past D), W from the padded codebook Wp (MP, DP), no bounds. Consecutive work-items take
 * consecutive dimensions of one row of X and of one unit of W. */
#define LOAD_X(k0)                                                                       \
    UNROLL_GPU                                                                           \
    for (int e = 0; e < XLOADS; ++e) {                                                   \
        const int t = lid + e * WGS;                                                     \
        const int kx = (k0) + t % KT, q = q0 + t / KT;                                   \
        xreg[e] = 0;                                                                     \
        if ((XFULL || t < TM * KT) && q < NR && kx < D) {                                \
            const int v = q % NV;                                                        \
            xreg[e] = sign[v * D + kx] * X[(size_t)(q / NV) * D + index[v * D + kx]];    \
        }                                                                                \
    }
#define LOAD_W(m, k0)                                                                    \
    UNROLL_GPU                                                                           \
    for (int e = 0; e < WLOADS; ++e) {                                                   \
        const int t = lid + e * WGS;                                                     \
        if (WFULL || t < TN * KT)                                                        \
            wreg[e] = Wp[(size_t)((m) + t / KT) * DP + (k0) + t % KT];                   \
    }

/* Registers to local buffer b. */
#define STORE_X(b)                                                                       \
    UNROLL_GPU                                                                           \
    for (int e = 0; e < XLOADS; ++e) {                                                   \
        const int t = lid + e * WGS;                                                     \
        if (XFULL || t < TM * KT)                                                        \
            Xs[(b) * KT * XSTRIDE + (t % KT) * XSTRIDE + t / KT] = xreg[e];              \
    }
#define STORE_W(b)                                                                       \
    UNROLL_GPU                                                                           \
    for (int e = 0; e < WLOADS; ++e) {                                                   \
        const int t = lid + e * WGS;                                                     \
        if (WFULL || t < TN * KT)                                                        \
            Ws[(b) * KT * WSTRIDE + (t % KT) * WSTRIDE + t / KT] = wreg[e];              \
    }

/* XRES: the row tile's varied vectors are gathered into local memory once, for all of D, and
 * only the codebook is staged per chunk; chunk c of X is then at c, not at a buffer. */
#if XRES
#define STAGE_LOAD(m, k0) LOAD_W(m, k0)
#define STAGE_STORE(b) STORE_W(b)
#define X_CHUNK(c, b) (c)
#define X_LOCAL (DP * XSTRIDE / VW)
#else
#define STAGE_LOAD(m, k0) LOAD_X(k0) LOAD_W(m, k0)
#define STAGE_STORE(b) STORE_X(b) STORE_W(b)
#define X_CHUNK(c, b) (b)
#define X_LOCAL (2 * KT * XSTRIDE / VW)
#endif
/* chunk k0 of the unit tile that starts at unit m: global loads, then the store to buffer b */
#if ABLATE_STAGING
#define LOAD_CHUNK(m, k0) if ((m) == tile0 * TN) { STAGE_LOAD(m, k0) }
#define STORE_CHUNK(m, b) if ((m) == tile0 * TN) { STAGE_STORE(b) }
#else
#define LOAD_CHUNK(m, k0) STAGE_LOAD(m, k0)
#define STORE_CHUNK(m, b) STAGE_STORE(b)
#endif

/* The outer products of X chunk xc and W buffer b: per dimension, RM rows x WVEC unit
 * vectors of fma. */
#define MULTIPLY_CHUNK(xc, b)                                                            \
    {                                                                                    \
        __local const realv *xb = Xv + (xc) * (KT * XSTRIDE / VW);                       \
        __local const realv *wb = Wv + (b) * (KT * WSTRIDE / VW);                        \
        _Pragma("unroll")                                                                \
        for (int kk = 0; kk < KT; ++kk) {                                                \
            REAL xr[RM];                                                                 \
            realv w[WVEC];                                                               \
            _Pragma("unroll")                                                            \
            for (int i = 0; i < XVEC; ++i)                                               \
                STORE_V(xb[kk * (XSTRIDE / VW) + i * WGM + ty], xr + i * VW);            \
            _Pragma("unroll")                                                            \
            for (int j = 0; j < WVEC; ++j)                                               \
                w[j] = wb[kk * (WSTRIDE / VW) + j * WGN + tx];                           \
            _Pragma("unroll")                                                            \
            for (int i = 0; i < RM; ++i)                                                 \
                _Pragma("unroll")                                                        \
                for (int j = 0; j < WVEC; ++j)                                           \
                    acc[i][j] = fma((realv)(xr[i]), w[j], acc[i][j]);                    \
        }                                                                                \
    }

#define ZERO_ACC                                                                         \
    _Pragma("unroll")                                                                    \
    for (int i = 0; i < RM; ++i)                                                         \
        _Pragma("unroll")                                                                \
        for (int j = 0; j < WVEC; ++j)                                                   \
            acc[i][j] = (realv)(0);

#if ABLATE_EPILOGUE
#define EPILOGUE_SINK                                                                    \
            UNROLL_GPU                                                                   \
            for (int l = 0; l < RN; ++l)                                                 \
                sink += d[l];                                                            \
            enters = 0;
#else
#define EPILOGUE_SINK
#endif

/* The epilogue of the unit tile at m0: running best and second of each row over its units.
 * The RN distances of a row are first only compared with its second (no branch, one
 * predicate): in the common case none can enter and the row costs RN fma and RN comparisons;
 * else INSERT takes them in ascending unit order, as one at a time would. The norms are read
 * as aligned vectors (m0 and the work-item's units are multiples of VW, MP of TN). */
#define EPILOGUE(m0)                                                                     \
    {                                                                                    \
        REAL wn[RN];                                                                     \
        UNROLL_GPU                                                                       \
        for (int j = 0; j < WVEC; ++j)                                                   \
            STORE_V(((__global const realv *)wnorm)[((m0) / VW) + j * WGN + tx], wn + j * VW); \
        UNROLL_GPU                                                                       \
        for (int i = 0; i < RM; ++i) {                                                   \
            REAL d[RN], a[RN];                                                           \
            UNROLL_GPU                                                                   \
            for (int j = 0; j < WVEC; ++j)                                               \
                STORE_V(acc[i][j], a + j * VW);                                          \
            int enters = 0;                                                              \
            UNROLL_GPU                                                                   \
            for (int l = 0; l < RN; ++l) {                                               \
                d[l] = wn[l] - (REAL)2 * a[l];                                           \
                enters |= d[l] <= sd[i];                                                 \
            }                                                                            \
            EPILOGUE_SINK                                                                \
            if (enters) {                                                                \
                UNROLL_GPU                                                               \
                for (int l = 0; l < RN; ++l) {                                           \
                    const int u = (m0) + ((l / VW) * WGN + tx) * VW + l % VW;            \
                    INSERT(d[l], u, bd[i], bu[i], sd[i], su[i]);                         \
                }                                                                        \
            }                                                                            \
        }                                                                                \
    }

__kernel __attribute__((reqd_work_group_size(WGN, WGM, 1)))
void bmu_of_n_gemm(__global const REAL *X,        /* (N, D) */
                   const int N,
                   __global const REAL *Wp,       /* (MP, DP) codebook, zero-padded (pad_codebook) */
                   __global const REAL *wnorm,    /* (MP,): ||w||^2, +inf on padding */
                   const int MP,                  /* padded unit count, a multiple of TN */
                   __global const int *index,     /* (NV, D) */
                   __global const REAL *sign,     /* (NV, D) */
                   const int tiles_per_split,     /* unit tiles of TN per split */
                   __global REAL *part_best,      /* (NR, S) */
                   __global int *part_unit,       /* (NR, S) */
                   __global REAL *part_second,    /* (NR, S) */
                   __global int *part_second_unit)/* (NR, S) */
{
    INJECTED_TRAP();
    const int tx = get_local_id(0), ty = get_local_id(1);
    const int lid = ty * WGN + tx;
    const int split = get_group_id(0), S = get_num_groups(0);
    const int NR = N * NV;
    const int q0 = get_group_id(1) * TM;
    const int tile0 = split * tiles_per_split;
    const int tile1 = min(tile0 + tiles_per_split, MP / TN);

    __local realv Xv[X_LOCAL];
    __local realv Wv[2 * KT * WSTRIDE / VW];
    __local REAL *Xs = (__local REAL *)Xv;
    __local REAL *Ws = (__local REAL *)Wv;
    __local REAL run_best[TM], run_second[TM];
    __local int run_unit[TM], run_second_unit[TM];

    REAL bd[RM], sd[RM];
    int bu[RM], su[RM];
#if UNROLL_EPILOGUE
#pragma unroll
#endif
    for (int i = 0; i < RM; ++i) {
        bd[i] = INFINITY;
        sd[i] = INFINITY;
        bu[i] = MP;
        su[i] = MP;
    }

    REAL xreg[XLOADS], wreg[WLOADS];
#if ABLATE_EPILOGUE
    REAL sink = 0;
#endif
#if XRES
    for (int t = lid; t < TM * DP; t += WGS) {
        const int kx = t % DP, q = q0 + t / DP;
        REAL x = 0;
        if (q < NR && kx < D) {
            const int v = q % NV;
            x = sign[v * D + kx] * X[(size_t)(q / NV) * D + index[v * D + kx]];
        }
        Xs[kx * XSTRIDE + t / DP] = x;
    }
    barrier(CLK_LOCAL_MEM_FENCE);
#endif
    realv acc[RM][WVEC];
    ZERO_ACC
#if PF
    /* double-buffered chunks, pipelined across unit tiles: the global loads of the next chunk are
     * in flight while one is multiplied, and during a tile's last chunk (and its epilogue) those
     * of the next tile's first; one barrier per chunk */
    LOAD_CHUNK(tile0 * TN, 0)
    STORE_CHUNK(tile0 * TN, 0)
    barrier(CLK_LOCAL_MEM_FENCE);
    int b = 0;
    for (int tile = tile0; tile < tile1; ++tile) {
        const int m0 = tile * TN;
        for (int c = 0; c < NCHUNK - 1; ++c) {
            LOAD_CHUNK(m0, (c + 1) * KT)
            MULTIPLY_CHUNK(X_CHUNK(c, b), b)
            STORE_CHUNK(m0, 1 - b)
            barrier(CLK_LOCAL_MEM_FENCE);
            b ^= 1;
        }
        const bool more = tile + 1 < tile1;
        if (more) {
            LOAD_CHUNK(m0 + TN, 0)
        }
        MULTIPLY_CHUNK(X_CHUNK(NCHUNK - 1, b), b)
        EPILOGUE(m0)
        ZERO_ACC
        if (more) {
            STORE_CHUNK(m0 + TN, 1 - b)
        }
        barrier(CLK_LOCAL_MEM_FENCE);
        b ^= 1;
    }
#else
    for (int tile = tile0; tile < tile1; ++tile) {
        const int m0 = tile * TN;
        for (int c = 0; c < NCHUNK; ++c) {
            LOAD_CHUNK(m0, c * KT)
            STORE_CHUNK(m0, 0)
            barrier(CLK_LOCAL_MEM_FENCE);
            MULTIPLY_CHUNK(X_CHUNK(c, 0), 0)
            barrier(CLK_LOCAL_MEM_FENCE);
        }
        EPILOGUE(m0)
        ZERO_ACC
    }
#endif

#if ABLATE_EPILOGUE
    bd[0] = sink;  /* keeps the products alive */
#endif
    /* fold the WGN work-items of each row into local memory, one column of work-items
     * (tx) per round: in a round every row has exactly one writer */
    for (int r = lid; r < TM; r += WGS) {
        run_best[r] = INFINITY;
        run_second[r] = INFINITY;
        run_unit[r] = MP;
        run_second_unit[r] = MP;
    }
    barrier(CLK_LOCAL_MEM_FENCE);
    for (int t = 0; t < WGN; ++t) {
        if (tx == t) {
#if UNROLL_EPILOGUE
#pragma unroll
#endif
            for (int i = 0; i < RM; ++i) {
                const int r = ((i / VW) * WGM + ty) * VW + i % VW;
                INSERT(bd[i], bu[i], run_best[r], run_unit[r], run_second[r], run_second_unit[r]);
                INSERT(sd[i], su[i], run_best[r], run_unit[r], run_second[r], run_second_unit[r]);
            }
        }
        barrier(CLK_LOCAL_MEM_FENCE);
    }
    for (int r = lid; r < TM && q0 + r < NR; r += WGS) {
        const size_t o = (size_t)(q0 + r) * S + split;
        part_best[o] = run_best[r];
        part_unit[o] = run_unit[r];
        part_second[o] = run_second[r];
        part_second_unit[o] = run_second_unit[r];
    }
}

/* The codebook W (M, D) copied into Wp (MP, DP) with zeros past M and past D, so that the
 * staging of bmu_of_n_gemm reads whole chunks with no bounds; one work-item per element. */
__kernel void pad_codebook(__global const REAL *W,   /* (M, D) */
                           const int M,
                           __global REAL *Wp,        /* (MP, DP) */
                           const int MP)
{
    const size_t g = get_global_id(0);
    if (g >= (size_t)MP * DP)
        return;
    const int u = (int)(g / DP), k = (int)(g % DP);
    Wp[g] = u < M && k < D ? W[(size_t)u * D + k] : (REAL)0;
}

/* One work-item per row: fold the S splits of each variation (INSERT), add ||x_v||^2
 * (sequential fma over k, as kernels/bmu.cl) and keep the best variation; then the squared
 * distance of the winner computed directly, sum_k (x_v[k] - w[k])^2, in EXACT (double where
 * the device has it, as meshsom.bmu_numpy.exact_dist2 does on the host). */
__kernel void bmu_of_n_gemm_reduce(__global const REAL *X,        /* (N, D) */
                                   const int N,
                                   __global const REAL *W,        /* (M, D) */
                                   const int MP,
                                   __global const int *index,     /* (NV, D) */
                                   __global const REAL *sign,     /* (NV, D) */
                                   const int S,
                                   __global const REAL *part_best,      /* (N * NV, S) */
                                   __global const int *part_unit,
                                   __global const REAL *part_second,
                                   __global const int *part_second_unit,
                                   __global int *out_unit,        /* (N,) */
                                   __global int *out_var,         /* (N,) */
                                   __global EXACT *out_dist2,     /* (N,) */
                                   __global int *out_second)      /* (N,) */
{
    const int row = get_global_id(0);
    if (row >= N)
        return;
    REAL best_total = INFINITY;
    int best_v = 0, best_u = 0, best_s = 0;
    for (int v = 0; v < NV; ++v) {
        REAL B = INFINITY, Sd = INFINITY;
        int BU = MP, SU = MP;
        const size_t o = ((size_t)row * NV + v) * S;
        for (int s = 0; s < S; ++s) {
            INSERT(part_best[o + s], part_unit[o + s], B, BU, Sd, SU);
            INSERT(part_second[o + s], part_second_unit[o + s], B, BU, Sd, SU);
        }
        REAL xn = 0;
        for (int k = 0; k < D; ++k) {
            const REAL xv = sign[v * D + k] * X[(size_t)row * D + index[v * D + k]];
            xn = fma(xv, xv, xn);
        }
        const REAL total = B + xn;
        if (total < best_total || (total == best_total && BU < best_u)) {
            best_total = total;
            best_v = v;
            best_u = BU;
            best_s = SU;
        }
    }
    EXACT dist2 = 0;
    for (int k = 0; k < D; ++k) {
        const EXACT diff = (EXACT)(sign[best_v * D + k] * X[(size_t)row * D + index[best_v * D + k]])
                           - (EXACT)W[(size_t)best_u * D + k];
        dist2 = fma(diff, diff, dist2);
    }
    out_unit[row] = best_u;
    out_var[row] = best_v;
    out_dist2[row] = dist2;
    out_second[row] = best_s;
}
