/* Shared by both BMUofN kernels (kernels/bmu.cl and kernels/bmu_cpu.cl): the loader
 * (meshsom.bmu_opencl.kernel_source) puts this text in front of each.
 *
 * Needs the defines REAL, IREAL, VW and D. Builtins (fma, select, any, vload) are kept
 * out of the hot loops of the kernels: PoCL may leave them as out-of-line calls, one call
 * per vector operation; the operators below always inline.
 *
 * finish_row (every layout) and kernels/bmu_cpu.cl call no builtin that takes or returns a
 * realv / irealv by value (no VSTORE, no VLOAD), so that VW = 16 builds on any CPU: how a
 * 512-bit vector (float16, int16, double8, long8) is passed depends on avx512f, and PoCL
 * can build the kernel for a CPU name without it while linking its AVX-512 builtin library.
 * PoCL 3.0 with LLVM 14 does so on AMD Zen 4: LLVM 14 names the host "znver3" (no AVX-512)
 * while the cpuid flags pick the library compiled for "skylake-avx512" and a preferred float
 * width of 16. Clang then passes the float16 of vstore16 through memory (warning "AVX vector
 * argument ... without 'avx512f' enabled changes the ABI"), the library's vstore16 takes it
 * in a register, PoCL links the call to the mismatched definition, and code generation
 * aborts the process: "LLVM ERROR: Do not know how to scalarize this operator's operand!".
 * finish_row reads the lanes through unions instead.
 *
 * Test hooks (meshsom.probe, MESHSOM_KERNEL_INJECT; never defined otherwise): a build that
 * fails, and a kernel that kills its process on its first launch.
 */

#ifdef MESHSOM_INJECT_BUILD_ERROR
#error "injected build failure (MESHSOM_KERNEL_INJECT test hook)"
#endif
#ifdef MESHSOM_INJECT_TRAP
#define INJECTED_TRAP() __builtin_trap()
#else
#define INJECTED_TRAP()
#endif

#define CAT_(a, b) a##b
#define CAT(a, b) CAT_(a, b)
typedef CAT(REAL, VW) realv;
typedef CAT(IREAL, VW) irealv;
#define VLOAD CAT(vload, VW)
#define VSTORE CAT(vstore, VW)

/* the lanes of a vector as an array (see above: no vstore) */
typedef union { realv v; REAL s[VW]; } realv_lanes;
typedef union { irealv v; IREAL s[VW]; } irealv_lanes;

/* Loads and stores of vectors of 8 or more lanes (512 bits and more at VW 16 with float, VW 8 with
 * double, and float8) go lane by lane through the union, never through vloadN / vstoreN: those
 * are calls into PoCL's builtin library, with the ABI mismatch above on AMD Zen 4. There vload16
 * in kernels/bmu.cl built, and returned wrong lanes (units out of range); LLVM merges the lane
 * copies into one vector move where the target has one. Narrower vectors use the builtins. */
#if VW >= 8
#define LOAD_V(dst, p)                                               \
    do {                                                             \
        realv_lanes l_;                                              \
        for (int i_ = 0; i_ < VW; ++i_)                              \
            l_.s[i_] = (p)[i_];                                      \
        (dst) = l_.v;                                                \
    } while (0)
#define STORE_V(v, p)                                                \
    do {                                                             \
        realv_lanes l_;                                              \
        l_.v = (v);                                                  \
        for (int i_ = 0; i_ < VW; ++i_)                              \
            (p)[i_] = l_.s[i_];                                      \
    } while (0)
#else
#define LOAD_V(dst, p) ((dst) = VLOAD(0, (p)))
#define STORE_V(v, p) VSTORE((v), 0, (p))
#endif

#if VW == 2
#define LANES ((irealv)(0, 1))
#define ANY(m) (((m).s0 | (m).s1) != 0)
#elif VW == 4
#define LANES ((irealv)(0, 1, 2, 3))
#define ANY(m) ((((m).s01 | (m).s23).s0 | ((m).s01 | (m).s23).s1) != 0)
#elif VW == 8
#define LANES ((irealv)(0, 1, 2, 3, 4, 5, 6, 7))
#define ANY4(m) ((((m).s01 | (m).s23).s0 | ((m).s01 | (m).s23).s1) != 0)
#define ANY(m) ANY4((m).lo | (m).hi)
#else
#define LANES ((irealv)(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15))
#define ANY4(m) ((((m).s01 | (m).s23).s0 | ((m).s01 | (m).s23).s1) != 0)
#define ANY8(m) ANY4((m).lo | (m).hi)
#define ANY(m) ANY8((m).lo | (m).hi)
#endif

/* Insert candidate (d, u) into (b, bu) <= (s, su), lexicographic (distance, unit). */
#define INSERT(d, u, b, bu, s, su)                                   \
    if ((d) < (b) || ((d) == (b) && (u) < (bu))) {                   \
        s = b; su = bu; b = d; bu = u;                               \
    } else if ((d) < (s) || ((d) == (s) && (u) < (su))) {            \
        s = d; su = u;                                               \
    }

/* Fold the per-lane best / second best (distance ||w||^2 - 2 x_v.w, unit; ascending units
 * per lane) of one row's nv varied vectors into its answer: across lanes the (distance,
 * unit) order; across variations ||x_v||^2 (xnorm[v]) is added and a later variation
 * wins when strictly closer, or equally close at a lower unit. Writes the row's outputs. */
inline void finish_row(const realv *bd, const irealv *bu, const realv *sd, const irealv *su,
                       const REAL *xnorm, const int nv, const int MP, const int row,
                       __global int *out_unit, __global int *out_var, __global REAL *out_dist2,
                       __global int *out_second)
{
    REAL best_total = INFINITY;
    int best_v = 0, best_u = 0, best_s = 0;
    for (int v = 0; v < nv; ++v) {
        realv_lanes lb, ls;
        irealv_lanes lbu, lsu;
        lb.v = bd[v];
        ls.v = sd[v];
        lbu.v = bu[v];
        lsu.v = su[v];
        REAL B = INFINITY, S = INFINITY;
        IREAL BU = MP, SU = MP;
        for (int l = 0; l < VW; ++l) {
            INSERT(lb.s[l], lbu.s[l], B, BU, S, SU);
            INSERT(ls.s[l], lsu.s[l], B, BU, S, SU);
        }
        const REAL total = B + xnorm[v];
        if (total < best_total || (total == best_total && (int)BU < best_u)) {
            best_total = total;
            best_v = v;
            best_u = (int)BU;
            best_s = (int)SU;
        }
    }
    out_unit[row] = best_u;
    out_var[row] = best_v;
    out_dist2[row] = best_total;
    out_second[row] = best_s;
}
