/* Per-unit sums of the winning varied vectors, in float64: the reduce input of a batch epoch,
 * computed next to the resident rows so that only the (M, D) sums come back, not N rows.
 *
 * The same bits as meshsom.bmu_numpy.unit_sums: per (unit u, dimension k) the varied values
 * sign[v, k] * X[r, index[v, k]] of the rows r that u won (v: each row's winning variation),
 * converted to double and added one after another to 0 in row order. The rows of each unit
 * come from a stable counting order made on the host (order, offsets:
 * meshsom.bmu_numpy.unit_order). One work-item per (u, k), k fastest, so that the work-items
 * of one unit read one row together.
 *
 * Appended to every BMUofN program (meshsom.bmu_opencl.kernel_source) and compiled where the
 * device has float64 (-DUNIT_SUMS=1), so that the layout's probe builds and checks it too.
 * Needs the defines REAL and D.
 */

#if UNIT_SUMS
#pragma OPENCL EXTENSION cl_khr_fp64 : enable

__kernel void unit_sums(__global const REAL *X,        /* (N, D) */
                        __global const int *index,     /* (NV, D) */
                        __global const REAL *sign,     /* (NV, D) */
                        __global const int *variation, /* (N,) winning variation of each row */
                        __global const int *order,     /* (N,) rows grouped by unit, ascending within one */
                        __global const int *offsets,   /* (M + 1,) unit u: order[offsets[u] .. offsets[u + 1]) */
                        const int M,
                        __global double *sums)         /* (M, D) */
{
    const int g = get_global_id(0);
    if (g >= M * D)
        return;
    const int u = g / D, k = g % D;
    const int p0 = offsets[u], p1 = offsets[u + 1];
    double s = 0.0;
    for (int p = p0; p < p1; ++p) {
        const int r = order[p], v = variation[r];
        s += (double)(sign[v * D + k] * X[(size_t)r * D + index[v * D + k]]);
    }
    sums[g] = s;
}
#endif
