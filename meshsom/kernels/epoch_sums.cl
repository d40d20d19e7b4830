/* The reductions of a batch epoch's map step, next to the resident rows, in float64: per-unit
 * sums of the winning varied vectors (the reduce input) and per-row Q / QC distances (the
 * errors), so that only (M, D) sums and two (N,) columns come back, not N x D residuals.
 *
 * unit_sums: the same bits as meshsom.bmu_numpy.unit_sums. Per (unit u, dimension k) and per row
 * block, the varied values sign[v, k] * X[r, index[v, k]] of the block's rows r that u won (v: each
 * row's winning variation), converted to double and added one after another to 0 in row order;
 * the blocks' sums then added in block order to the running total of earlier passes, init (an
 * epoch's reduction of row blocks, one launch for all the blocks of a pass). The rows of each (block, unit) come from a stable counting order
 * (order, offsets: meshsom.bmu_numpy.unit_order, or the same made here by stable_unit_order). One work-item per (u, k), k fastest, so that the
 * work-items of one unit read one row together.
 *
 * row_errors: meshsom.metrics.row_errors. Per row, the residual d_k = x_v[k] - w_u[k] in double;
 * q = sqrt of the d_k^2 added in k order from 0; qc = the mean over the D / COMPONENT slices of
 * the slice's sqrt (squares added in order within the slice; slice norms added in order), NaN
 * when COMPONENT does not divide D. The same to rounding: a compiler may fuse d * d + s into
 * one fma (FP_CONTRACT is asked off, -cl-mad-enable allows it back).
 *
 * topographic_errors: meshsom.metrics.topographic_errors with the tie rule of
 * meshsom.metrics.tied_with_neighbour. Per row: 0 where its second-best unit is a grid neighbour of
 * its best unit (8 or 4 neighbours, offsets wrapped on a torus); else the squared distances of the
 * varied row to the second-best unit and to every neighbour of the best unit, in double (squares
 * added in dimension order), and 0 where the nearest neighbour lies within tie_rtol * (||x_v||^2 +
 * ||w_second||^2) of the second-best distance (a tie), 1 otherwise. On the host this check costs
 * 9 float64 distances per row whose second-best is not a neighbour (16 s an epoch at 1e6 rows of
 * D = 144 on 2 cores when most are not); here it runs next to the resident rows. The same to
 * rounding: a tie that lies within rounding of its threshold may be decided otherwise.
 *
 * Appended to every BMUofN program (meshsom.bmu_opencl.kernel_source) and compiled where the
 * device has float64 (-DEPOCH_SUMS=1; COMPONENT: meshsom.metrics.COMPONENT), so that the layout's probe builds and checks them too.
 * Needs the defines REAL, D and COMPONENT.
 */

#if EPOCH_SUMS
#pragma OPENCL EXTENSION cl_khr_fp64 : enable
#pragma OPENCL FP_CONTRACT OFF

#ifdef MESHSOM_INJECT_EPOCH_ERROR /* test hook (MESHSOM_KERNEL_INJECT "<layout>=epoch-error"): these kernels fail */
#error "injected build failure of the epoch kernels (MESHSOM_KERNEL_INJECT test hook)"
#endif

/* The stable order of rows by (block, unit) that unit_sums reads, made on the device (the same as
 * meshsom.bmu_numpy.unit_order, for blocks of block_rows rows): unit_counts counts the rows of each
 * (block, unit) (counts zeroed by the host), exclusive_scan turns the counts into offsets (one
 * work-group), stable_unit_order writes each row at its unit's cursor (a copy of the offsets), one
 * work-group per block walking its rows in chunks of ORDER_GROUP in row order: a row's place is
 * the cursor plus the rows of the same unit before it in the chunk, so rows stay in row order
 * within a unit; unit_totals adds each unit's counts over the blocks. */
#define ORDER_GROUP 64

__kernel void unit_counts(__global const int *unit, const int N, const int block_rows, const int M,
                          __global int *counts)         /* (B * M), zeroed */
{
    const int r = get_global_id(0);
    if (r < N)
        atomic_inc(&counts[(r / block_rows) * M + unit[r]]);
}

__kernel __attribute__((reqd_work_group_size(ORDER_GROUP, 1, 1)))
void exclusive_scan(__global const int *counts, const int n, __global int *offsets) /* (n + 1) */
{
    __local int part[ORDER_GROUP];
    const int lid = get_local_id(0);
    const int seg = (n + ORDER_GROUP - 1) / ORDER_GROUP, a = min(n, lid * seg), b = min(n, a + seg);
    int s = 0;
    for (int i = a; i < b; ++i)
        s += counts[i];
    part[lid] = s;
    barrier(CLK_LOCAL_MEM_FENCE);
    if (lid == 0) {
        int acc = 0;
        for (int i = 0; i < ORDER_GROUP; ++i) {
            const int t = part[i];
            part[i] = acc;
            acc += t;
        }
        offsets[n] = acc;
    }
    barrier(CLK_LOCAL_MEM_FENCE);
    int acc = part[lid];
    for (int i = a; i < b; ++i) {
        offsets[i] = acc;
        acc += counts[i];
    }
}

__kernel __attribute__((reqd_work_group_size(ORDER_GROUP, 1, 1)))
void stable_unit_order(__global const int *unit, const int N, const int block_rows, const int M,
                       __global int *cursor,            /* (B * M): offsets[:-1], advanced here */
                       __global int *order)             /* (N,) */
{
    __local int chunk[ORDER_GROUP];
    const int lid = get_local_id(0), b = get_group_id(0);
    const int r0 = b * block_rows, r1 = min(N, r0 + block_rows);
    for (int c = r0; c < r1; c += ORDER_GROUP) {
        const int r = c + lid;
        const int u = r < r1 ? unit[r] : -1;
        chunk[lid] = u;
        barrier(CLK_LOCAL_MEM_FENCE);
        int rank = 0, last = 1;
        for (int j = 0; j < ORDER_GROUP; ++j) {
            const int same = chunk[j] == u;
            rank += same && j < lid;
            last &= !(same && j > lid);
        }
        if (u >= 0)
            order[cursor[b * M + u] + rank] = r;
        barrier(CLK_GLOBAL_MEM_FENCE | CLK_LOCAL_MEM_FENCE);
        if (u >= 0 && last)
            cursor[b * M + u] += rank + 1;
        barrier(CLK_GLOBAL_MEM_FENCE | CLK_LOCAL_MEM_FENCE);
    }
}

__kernel void unit_totals(__global const int *offsets, const int B, const int M, __global int *totals) /* (M,) */
{
    const int u = get_global_id(0);
    if (u >= M)
        return;
    int t = 0;
    for (int b = 0; b < B; ++b)
        t += offsets[b * M + u + 1] - offsets[b * M + u];
    totals[u] = t;
}

__kernel void unit_sums(__global const REAL *X,        /* (N, D) */
                        __global const int *index,     /* (NV, D) */
                        __global const REAL *sign,     /* (NV, D) */
                        __global const int *variation, /* (N,) winning variation of each row */
                        __global const int *order,     /* (N,) rows grouped by (block, unit), ascending within one */
                        __global const int *offsets,   /* (B * M + 1,) unit u of block b: order[offsets[b * M + u] ..
                                                          offsets[b * M + u + 1]) */
                        const int M,
                        const int B,                   /* row blocks */
                        __global const double *init,   /* (M, D) running total of earlier passes */
                        const int has_init,            /* 0: no earlier passes (init is not read) */
                        __global double *sums)         /* (M, D) */
{
    const int g = get_global_id(0);
    if (g >= M * D)
        return;
    const int u = g / D, k = g % D;
    double total = has_init ? init[g] : 0.0;
    for (int b = 0; b < B; ++b) {
        const int p0 = offsets[b * M + u], p1 = offsets[b * M + u + 1];
        double s = 0.0;
        for (int p = p0; p < p1; ++p) {
            const int r = order[p], v = variation[r];
            s += (double)(sign[v * D + k] * X[(size_t)r * D + index[v * D + k]]);
        }
        total += s;
    }
    sums[g] = total;
}

__kernel void row_errors(__global const REAL *X,        /* (N, D) */
                         const int N,
                         __global const int *index,     /* (NV, D) */
                         __global const REAL *sign,     /* (NV, D) */
                         __global const int *variation, /* (N,) */
                         __global const int *unit,      /* (N,) */
                         __global const REAL *W,        /* (M, D) */
                         __global double *q,            /* (N,) */
                         __global double *qc)           /* (N,) */
{
    const int r = get_global_id(0);
    if (r >= N)
        return;
    const int v = variation[r];
    const size_t x0 = (size_t)r * D, w0 = (size_t)unit[r] * D;
    double q2 = 0.0, c = 0.0;
    int k = 0;
    for (int j = 0; j < D / COMPONENT; ++j) {
        double s2 = 0.0;
        for (int i = 0; i < COMPONENT; ++i, ++k) {
            const double d = (double)(sign[v * D + k] * X[x0 + index[v * D + k]]) - (double)W[w0 + k];
            const double dd = d * d;
            s2 += dd;
            q2 += dd;
        }
        c += sqrt(s2);
    }
    for (; k < D; ++k) {
        const double d = (double)(sign[v * D + k] * X[x0 + index[v * D + k]]) - (double)W[w0 + k];
        q2 += d * d;
    }
    q[r] = sqrt(q2);
    qc[r] = D % COMPONENT ? NAN : c / (D / COMPONENT);
}

/* squared distance of row r's varied vector (variation v) to prototype w, in double, dimension order */
inline double varied_dist2(__global const REAL *X, const size_t x0, __global const int *index,
                           __global const REAL *sign, const int v, __global const REAL *W, const size_t w0)
{
    double s = 0.0;
    for (int k = 0; k < D; ++k) {
        const double d = (double)(sign[v * D + k] * X[x0 + index[v * D + k]]) - (double)W[w0 + k];
        s += d * d;
    }
    return s;
}

/* Python's divmod for a possibly negative unit number */
inline int floor_div(const int a, const int b) { return a / b - (a % b != 0 && (a < 0) != (b < 0)); }

__kernel void topographic_errors(__global const REAL *X,        /* (N, D) */
                                 const int N,
                                 __global const int *index,     /* (NV, D) */
                                 __global const REAL *sign,     /* (NV, D) */
                                 __global const int *variation, /* (N,) */
                                 __global const int *unit,      /* (N,) */
                                 __global const int *second,    /* (N,) */
                                 __global const REAL *W,        /* (M, D) */
                                 const int rows,
                                 const int cols,
                                 const int toroidal,            /* 1: offsets wrap */
                                 const int neighbourhood,       /* 8 or 4 */
                                 const double tie_rtol,
                                 __global uchar *bad)           /* (N,) */
{
    const int r = get_global_id(0);
    if (r >= N)
        return;
    const int u = unit[r], s = second[r];
    const int ur = floor_div(u, cols), uc = u - ur * cols, sr = floor_div(s, cols), sc = s - sr * cols;
    int dr = abs(ur - sr), dc = abs(uc - sc);
    if (toroidal) {
        dr = min(dr, rows - dr);
        dc = min(dc, cols - dc);
    }
    if ((neighbourhood == 8 ? max(dr, dc) : dr + dc) == 1) {
        bad[r] = 0;
        return;
    }
    if (s < 0) {
        bad[r] = 1;
        return;
    }
    const int v = variation[r];
    const size_t x0 = (size_t)r * D, s0 = (size_t)s * D;
    const double d_second = varied_dist2(X, x0, index, sign, v, W, s0);
    double xx = 0.0, ww = 0.0;
    for (int k = 0; k < D; ++k) {
        const double x = (double)(sign[v * D + k] * X[x0 + index[v * D + k]]), w = (double)W[s0 + k];
        xx += x * x;
        ww += w * w;
    }
    double d_nbr = INFINITY;
    for (int di = -1; di <= 1; ++di)
        for (int dj = -1; dj <= 1; ++dj) {
            if ((di == 0 && dj == 0) || (neighbourhood == 4 && di != 0 && dj != 0))
                continue;
            int nr = ur + di, nc = uc + dj;
            if (toroidal) {
                nr = (nr + rows) % rows;
                nc = (nc + cols) % cols;
            } else if (nr < 0 || nr >= rows || nc < 0 || nc >= cols) {
                continue;
            }
            d_nbr = fmin(d_nbr, varied_dist2(X, x0, index, sign, v, W, (size_t)(nr * cols + nc) * D));
        }
    bad[r] = !(d_nbr <= d_second + tie_rtol * (xx + ww));
}
#endif
