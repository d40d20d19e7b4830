/* The reduce step of a batch epoch on the device (meshsom.som.batch_update), so that an epoch's
 * (M, D) float64 sums never leave the device and only the new float32 codebook comes back.
 *
 * smooth_axis: a Gaussian neighbourhood sum along one axis of a row-major (A, L, B) float64 grid,
 * out[a, j, b] = sum over i of kern[j, i] * in[a, i, b], the terms added in i order from 0. The
 * host runs it twice, as meshsom.som.smooth does: along the columns ((rows, cols, K): A = rows,
 * L = cols, B = K) and then along the rows (A = 1, L = rows, B = cols * K), for the sums (K = D)
 * and for the counts (K = 1). One work-item per run of SMOOTH_RJ outputs along the axis (the
 * layout's KernelParams.smooth_outputs: 4 on GPUs, where each value read from in then serves 4
 * outputs; 1 on CPUs), b fastest, so that neighbouring work-items read neighbouring values and
 * share one kernel weight. Each output adds its terms in i order whatever SMOOTH_RJ is. About
 * 2 * M * D * (rows + cols) flops (1.4 GFLOP on the paper's 120 x 150 map at D = 144): work for a
 * GPU; on a CPU device the host's BLAS is much faster (measured on PoCL: 0.3 to 0.7 s against 26 to
 * 34 ms), so "auto" keeps the update there.
 *
 * divide_codebook: out[u, k] = num[u, k] / den[u] rounded to REAL, or W[u, k] where den[u] <=
 * min_weight (a unit nobody near won keeps its prototype).
 *
 * The same as the host's to rounding: the host smooths with BLAS products, whose order of
 * additions is its own, and a compiler may fuse a product and its add (-cl-mad-enable); the
 * float32 codebook that comes back is nearly always the host's bit for bit (tests/test_device_update.py).
 *
 * Appended to every BMUofN program with kernels/epoch_sums.cl (meshsom.bmu_opencl.kernel_source),
 * built where the device has float64 (-DEPOCH_SUMS=1), so that the layout's probe builds and
 * checks it. Needs the defines REAL, D and SMOOTH_RJ.
 */

#if EPOCH_SUMS
#pragma OPENCL EXTENSION cl_khr_fp64 : enable

__kernel void smooth_axis(__global const double *in,   /* (A, L, B) */
                          const int A,
                          const int L,
                          const int B,
                          __global const double *kern, /* (L, L) Gaussian weights between the cells of the axis */
                          __global double *out)        /* (A, L, B) */
{
    /* one work-item per (a, run of SMOOTH_RJ outputs j along the axis, b), b fastest */
    const size_t g = get_global_id(0);
    const int JB = (L + SMOOTH_RJ - 1) / SMOOTH_RJ;
    const size_t LB = (size_t)L * B;
    if (g >= (size_t)A * JB * B)
        return;
    const size_t b = g % B, a = g / ((size_t)JB * B);
    const int j0 = (int)((g / B) % JB) * SMOOTH_RJ;
    __global const double *src = in + a * LB + b;
#if SMOOTH_RJ == 1
    __global const double *w = kern + (size_t)j0 * L;
    double s = 0.0;
    for (int i = 0; i < L; ++i)
        s += w[i] * src[(size_t)i * B];
    out[a * LB + (size_t)j0 * B + b] = s;
#else
    double s[SMOOTH_RJ];
    for (int r = 0; r < SMOOTH_RJ; ++r)
        s[r] = 0.0;
    for (int i = 0; i < L; ++i) {
        const double x = src[(size_t)i * B]; /* read once for SMOOTH_RJ outputs */
        for (int r = 0; r < SMOOTH_RJ; ++r)
            s[r] += kern[(size_t)min(j0 + r, L - 1) * L + i] * x;
    }
    for (int r = 0; r < SMOOTH_RJ && j0 + r < L; ++r)
        out[a * LB + (size_t)(j0 + r) * B + b] = s[r];
#endif
}

__kernel void divide_codebook(__global const double *num, /* (M, D) smoothed sums */
                              __global const double *den, /* (M,) smoothed counts */
                              __global const REAL *W,     /* (M, D) prototypes before the update */
                              const int M,
                              const double min_weight,
                              __global REAL *out)         /* (M, D) */
{
    const size_t g = get_global_id(0);
    if (g >= (size_t)M * D)
        return;
    const double d = den[g / D];
    out[g] = d <= min_weight ? W[g] : (REAL)(num[g] / d);
}
#endif
