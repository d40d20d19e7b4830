"""BMUofN: NumPy reference vs a per-vector brute force, OpenCL vs NumPy, ties, planted variations."""

from __future__ import annotations

import logging

import numpy as np
import pytest

from meshsom import bmu as bmu_module
from meshsom.bmu import find_bmus, resolve_backend
from meshsom.bmu_numpy import bmu_numpy, identity_table
from meshsom.errors import DeviceError


def brute_force(X, W, index, sign):
    """Per-vector Python reference in float64: among equal best distances the lowest unit, then
    the lowest variation; second = next unit of the winning variation in (distance, unit) order."""
    X = np.asarray(X, np.float64)
    W = np.asarray(W, np.float64)
    out = []
    for x in X:
        best = None
        for v in range(len(index)):
            xv = sign[v] * x[index[v]]
            d = ((W - xv) ** 2).sum(axis=1)
            order = np.lexsort((np.arange(len(W)), d))
            u, s = order[0], order[1]
            if best is None or d[u] < best[0] or (d[u] == best[0] and u < best[1]):
                best = (d[u], u, v, s)
        out.append(best)
    d, u, v, s = map(np.array, zip(*out))
    return u, v, d, s


def random_table(rng, n, D):
    """Identity first, then random signed permutations."""
    index = np.stack([np.arange(D)] + [rng.permutation(D) for _ in range(n - 1)]).astype(np.int64)
    sign = np.where(rng.random((n, D)) < 0.3, -1.0, 1.0).astype(np.float32)
    sign[0] = 1.0
    return index, sign


def block_table(D, mirror=True):
    """Rotations of 3 blocks of D/3 values (and their mirrors with a sign flip): the fold-like table."""
    b = D // 3
    blocks = np.arange(D).reshape(3, b)
    rows, signs = [], []
    for r in range(3):
        rows.append(np.roll(blocks, -r, axis=0).ravel())
        signs.append(np.ones(D))
    if mirror:
        for r in range(3):
            rows.append(np.roll(blocks[::-1], -r, axis=0).ravel())
            s = np.ones(D)
            s[::3] = -1
            signs.append(s)
    return np.array(rows, np.int64), np.array(signs, np.float32)


def separated(X, W, index, sign, rel=1e-4, chunk=64):
    """Rows whose best, second and third (variation, unit) distances are separated beyond float32 rounding."""
    X = np.asarray(X, np.float64)
    W = np.asarray(W, np.float64)
    out = []
    for start in range(0, len(X), chunk):
        x = X[start:start + chunk]
        xv = np.stack([sign[v] * x[:, index[v]] for v in range(len(index))], axis=1)  # (c, n, D)
        d = ((xv[:, :, None, :] - W[None, None]) ** 2).sum(-1)  # (c, n, M)
        flat = np.sort(d.reshape(len(x), -1), axis=1)
        scale = 1.0 + np.abs(flat[:, :1])
        ok = (flat[:, 1] - flat[:, 0]) > rel * scale[:, 0]
        v = d.reshape(len(x), -1).argmin(1) // W.shape[0]
        dv = np.sort(d[np.arange(len(x)), v], axis=1)
        ok &= (dv[:, 1] - dv[:, 0]) > rel * scale[:, 0]
        ok &= (dv[:, 2] - dv[:, 1]) > rel * scale[:, 0]
        out.append(ok)
    return np.concatenate(out)


@pytest.mark.parametrize("n,D", [(1, 9), (3, 9), (6, 9), (3, 12)])
def test_numpy_matches_brute_force_float64(n, D):
    rng = np.random.default_rng(n * 100 + D)
    X = rng.normal(size=(60, D))
    W = rng.normal(size=(17, D))
    index, sign = random_table(rng, n, D)
    got = bmu_numpy(X, W, index, sign.astype(np.float64), chunk_rows=7)
    u, v, d, s = brute_force(X, W, index, sign)
    np.testing.assert_array_equal(got.unit, u)
    np.testing.assert_array_equal(got.variation, v)
    np.testing.assert_array_equal(got.second, s)
    np.testing.assert_allclose(got.dist2, d, rtol=1e-10, atol=1e-12)


def test_numpy_float32_matches_float64_reference_where_separated():
    rng = np.random.default_rng(5)
    X = rng.normal(size=(200, 36)).astype(np.float32)
    W = rng.normal(size=(50, 36)).astype(np.float32)
    index, sign = random_table(rng, 3, 36)
    check_against_brute_force(bmu_numpy(X, W, index, sign), X, W, index, sign, min_separated=0.9, rtol=1e-5)


def check_against_brute_force(got, X, W, index, sign, min_separated, rtol, atol=0.0):
    """Units, variations and seconds equal to the float64 brute force on the rows separated
    beyond float32 rounding (at least ``min_separated`` of them), dist2 close everywhere."""
    u, v, d, s = brute_force(X, W, index, sign)
    ok = separated(X, W, index, sign)
    assert ok.mean() > min_separated
    np.testing.assert_array_equal(got.unit[ok], u[ok])
    np.testing.assert_array_equal(got.variation[ok], v[ok])
    np.testing.assert_array_equal(got.second[ok], s[ok])
    np.testing.assert_allclose(got.dist2, d, rtol=rtol, atol=atol)


def planted_ties(rng, D=9):
    """Small-integer data (exact in float32 whatever the summation order) with duplicated
    codebook vectors and vectors symmetric under a variation: exact ties of both kinds."""
    index, sign = block_table(D, mirror=False)
    W = rng.integers(-3, 4, size=(12, D)).astype(np.float32)
    W[7] = W[2]  # duplicated units: 2 must win over 7
    W[11] = W[2]
    block = rng.integers(-3, 4, size=D // 3)
    symmetric = np.tile(block, 3).astype(np.float32)  # every rotation gives the same vector
    X = np.concatenate([
        W[[2, 7, 11]],  # exact hits of a duplicated unit
        W[[2]] + 1,  # near it
        symmetric[None],  # all variations tie
        rng.integers(-3, 4, size=(20, D)).astype(np.float32),
    ])
    return X, W, index, sign


def check_ties(result, X, W, index, sign):
    u, v, d, s = brute_force(X, W, index, sign)
    np.testing.assert_array_equal(result.unit, u)
    np.testing.assert_array_equal(result.variation, v)
    np.testing.assert_array_equal(result.second, s)
    assert list(result.unit[:3]) == [2, 2, 2] and list(result.second[:3]) == [7, 7, 7]
    assert result.variation[4] == 0


def test_numpy_ties_lowest_unit_then_lowest_variation():
    X, W, index, sign = planted_ties(np.random.default_rng(1))
    check_ties(bmu_numpy(X, W, index, sign), X, W, index, sign)


def planted_variations(rng, D, mirror=True, N=40, M=30):
    """Data made as inverse-varied copies of codebook vectors: P_v x = w_u exactly."""
    index, sign = block_table(D, mirror)
    W = rng.normal(size=(M, D)).astype(np.float32)
    u = rng.integers(0, M, N)
    v = rng.integers(0, len(index), N)
    X = np.zeros((N, D), np.float32)
    X[np.arange(N)[:, None], index[v]] = sign[v] * W[u]  # sign[v] * x[index[v]] = w_u
    return X, W, index, sign, u, v


def test_numpy_finds_planted_variation():
    X, W, index, sign, u, v = planted_variations(np.random.default_rng(2), 9)
    got = bmu_numpy(X, W, index, sign)
    np.testing.assert_array_equal(got.unit, u)
    np.testing.assert_array_equal(got.variation, v)
    np.testing.assert_allclose(got.dist2, 0, atol=1e-10)


def test_default_kernel_is_identity_row():
    rng = np.random.default_rng(3)
    X = rng.normal(size=(30, 9)).astype(np.float32)
    W = rng.normal(size=(20, 9)).astype(np.float32)
    a = bmu_numpy(X, W)
    b = bmu_numpy(X, W, *identity_table(9))
    np.testing.assert_array_equal(a.unit, b.unit)
    assert (a.variation == 0).all()


def test_validation_messages():
    X = np.zeros((3, 9), np.float32)
    with pytest.raises(ValueError, match="X has 9 columns but W has 8"):
        bmu_numpy(X, np.zeros((4, 8), np.float32))
    with pytest.raises(ValueError, match="index values must lie in 0..8"):
        bmu_numpy(X, np.zeros((4, 9), np.float32), np.full((1, 9), 9), np.ones((1, 9), np.float32))
    with pytest.raises(ValueError, match="backend must be one of"):
        find_bmus(X, np.zeros((4, 9), np.float32), backend="cuda")


# ----------------------------------------------------------------------------- OpenCL


def _opencl_context():
    try:
        from meshsom.bmu_opencl import get_context

        return get_context(None)
    except (DeviceError, ImportError) as err:
        pytest.skip(f"no OpenCL device: {err}")


@pytest.fixture(scope="module")
def ctx():
    return _opencl_context()


#: The kernel variants and tilings run on PoCL: the CPU kernel as the CPU default, the GEMM
#: layout with the GPU default tiling (64 x 128 tiles, 16 x 16 work-items, the whole row tile in
#: local memory up to D of about 110, staged 8 dimensions at a time beyond: the tests' N and M
#: give partial tiles) and with small tiles, vectors of 2, a D-chunk that pads D, three unit
#: splits (several row and unit tiles, partial ones, the split reduction) and one local buffer
#: (no prefetch),
#: the earlier local-memory kernel with its GPU tiling and with wide vectors.
KERNEL_PARAMS = {
    "cpu": {"kernel": "cpu"},
    "cpu-narrow": {"kernel": "cpu", "vector_width": 8, "unit_blocks": 2, "max_rows": 6, "cache_tiles": 32},
    "gemm-gpu": {"kernel": "gemm", "vector_width": 4, "tile_rows": 64, "tile_units": 128, "group_rows": 16,
                 "group_units": 16, "max_kt": 16, "staged_kt": 8, "whole_row_tile": True,
                 "smooth_outputs": 4},
    "gemm-split": {"kernel": "gemm", "vector_width": 2, "tile_rows": 16, "tile_units": 24, "group_rows": 4,
                   "group_units": 4, "max_kt": 8, "unit_splits": 3, "prefetch": False},
    "tiled-gpu": {"kernel": "tiled", "vector_width": 4, "unit_blocks": 2, "max_rows": 4, "work_group": 64, "max_dt": 64},
    "tiled-wide": {"kernel": "tiled", "vector_width": 16, "unit_blocks": 2, "max_rows": 8, "work_group": 8},
}


def test_gpu_default_is_the_gemm_tiling_tested_here():
    from meshsom.bmu_opencl import DEFAULT_PARAMS, KernelParams

    assert DEFAULT_PARAMS["gpu"] == KernelParams(name="gpu", **KERNEL_PARAMS["gemm-gpu"])


@pytest.fixture(params=list(KERNEL_PARAMS))
def kernel_params(request):
    from meshsom.bmu_opencl import KernelParams

    return KernelParams(**KERNEL_PARAMS[request.param])


def test_cpu_kernel_panels_and_cache_blocks(ctx):
    """Several panels (the last one partial) and several cache blocks (the last one partial)
    of the CPU kernel, with a small panel and small blocks to have many of both."""
    from meshsom.bmu_opencl import KernelParams, _defines, bmu_opencl

    rng = np.random.default_rng(5)
    N, M, D = 1013, 1100, 36
    X = rng.normal(size=(N, D)).astype(np.float32)
    W = rng.normal(size=(M, D)).astype(np.float32)
    index, sign = random_table(rng, 3, D)
    ref = bmu_numpy(X, W, index, sign)
    ok = separated(X, W, index, sign)
    assert ok.mean() > 0.8
    for params in (KernelParams(kernel="cpu"), KernelParams(kernel="cpu", panel=24, cache_tiles=3)):
        defines = _defines(D, 3, np.float32, params)
        assert defines["P"] * 3 % defines["RS"] == 0
        got = bmu_opencl(X, W, index, sign, context=ctx, params=params)
        np.testing.assert_array_equal(got.unit[ok], ref.unit[ok])
        np.testing.assert_array_equal(got.variation[ok], ref.variation[ok])
        np.testing.assert_array_equal(got.second[ok], ref.second[ok])
    assert _defines(2304, 6, np.float32, KernelParams(kernel="cpu"))["P"] * 6 * 2304 * 4 <= 262_144


def test_cpu_kernel_falls_back_to_tiled_at_large_dimension(ctx):
    """Where one register block of varied vectors exceeds panel_bytes the tiled kernel runs."""
    from meshsom.bmu_opencl import KernelParams, _defines, bmu_opencl

    params = KernelParams(kernel="cpu", panel_bytes=8 * 3 * 144 * 4 - 1)
    assert _defines(144, 3, np.float32, params)["KERNEL"] == "tiled"
    assert _defines(144, 3, np.float32, KernelParams(kernel="cpu"))["KERNEL"] == "cpu"
    assert _defines(9 * 4**5, 1, np.float32, KernelParams(kernel="cpu"))["KERNEL"] == "tiled"
    X, W, index, sign, u, v = planted_variations(np.random.default_rng(12), 144, N=20, M=40)
    got = bmu_opencl(X, W, index, sign, context=ctx, params=params)
    np.testing.assert_array_equal(got.unit, u)
    np.testing.assert_array_equal(got.variation, v)


def test_default_params_pick_a_cpu_layout_on_pocl(ctx):
    """PoCL gets a CPU layout, the first of its chain; doctor names that layout's register block
    (which block depends on the CPU: no test may assume one machine's); GPUs get the gemm layout."""
    import pyopencl as cl

    from meshsom.bmu_opencl import CHAINS, default_params, layout_chain
    from pipelines.doctor import opencl_devices

    if not ctx.devices[0].type & cl.device_type.CPU:
        assert default_params(ctx).kernel == "gemm"
        pytest.skip(f"not a CPU device: {ctx.devices[0].name}")
    params = default_params(ctx)
    assert params.kernel == "cpu" and layout_chain(ctx.devices[0]) in (CHAINS["cpu"], CHAINS["cpu-narrow"])
    assert params.name == layout_chain(ctx.devices[0])[0]
    pocl = [d for d in opencl_devices() if "Portable Computing Language" in d.get("platform", "")]
    assert pocl and pocl[0]["bmu_kernel"] == (
        f"kernels/bmu_cpu.cl (CPU layout), register block {params.max_rows} varied vectors x "
        f"{params.unit_blocks} x {params.vector_width} units")


class FakeDevice:
    """Just the attributes device_params, kernel_target_cpu and the tuning key read; no OpenCL needed."""

    def __init__(self, version="", driver_version="", width=16, cpu=True):
        import types

        self.version = version
        self.driver_version = driver_version
        self.name, self.vendor = "fake device", "fake vendor"
        self.platform = types.SimpleNamespace(name="fake platform", version="OpenCL 3.0 fake")
        self.preferred_vector_width_float = width
        self.cpu = cpu
        self.max_work_group_size = 4096
        self.local_mem_size = 48 * 1024  # NVIDIA's OpenCL work-group limit

    @property
    def type(self):
        import pyopencl as cl

        return cl.device_type.CPU if self.cpu else cl.device_type.GPU


POCL_3 = "OpenCL 3.0 PoCL HSTR: pthread-x86_64-unknown-linux-gnu-{}"


@pytest.mark.parametrize(
    "version,driver_version,cpu",
    [
        (POCL_3.format("znver3"), "3.0-rc2", "znver3"),
        (POCL_3.format("icelake-client"), "3.0-rc2", "icelake-client"),
        (POCL_3.format("haswell"), "3.0-rc2", "haswell"),
        ("OpenCL 3.0 PoCL", "pthread-x86_64-unknown-linux-gnu-znver3", "znver3"),
        ("OpenCL 3.0 PoCL", "pthread-x86_64-unknown-linux-gnu-icelake-client", "icelake-client"),
        ("OpenCL 3.0 PoCL", "6.0 HSTR: cpu-x86_64-pc-linux-gnu-skylake-avx512", "skylake-avx512"),
        ("OpenCL 3.0 PoCL HSTR: pthread-aarch64-unknown-linux-gnu-cortex-a72", "3.0", "cortex-a72"),
        ("OpenCL 3.0 CUDA", "560.35.03", None),
        ("OpenCL 1.2 AMD-APP (3444.0)", "3444.0 (PAL,LC)", None),
        ("OpenCL 3.0 PoCL HSTR:", "", None),
    ],
)
def test_kernel_target_cpu_from_pocl_hstr(version, driver_version, cpu):
    from meshsom.bmu_opencl import kernel_target_cpu

    assert kernel_target_cpu(FakeDevice(version, driver_version)) == cpu


def test_kernel_target_cpu_without_version_attributes():
    from meshsom.bmu_opencl import kernel_target_cpu

    assert kernel_target_cpu(object()) is None


@pytest.mark.parametrize(
    "cpu,reported,width",
    [
        ("znver3", 16, 8),  # LLVM 14's name for AMD Zen 4, whose cpuid flags give 16
        ("znver4", 16, 16),
        ("icelake-client", 16, 16),
        ("skylake-avx512", 16, 16),
        ("x86-64-v4", 16, 16),
        ("haswell", 8, 8),
        ("haswell", 16, 8),
        ("x86-64-v3", 16, 8),
        ("skylake", 16, 8),
        ("ZNVER3", 16, 8),
        ("some-future-cpu", 16, 16),  # unknown: the reported width stands
        ("cortex-a72", 4, 4),
        (None, 16, 16),
        ("znver3", 4, 4),  # a cap, never a raise
    ],
)
def test_target_vector_width(cpu, reported, width):
    from meshsom.bmu_opencl import target_vector_width

    assert target_vector_width(cpu, reported) == width


def test_avx512_and_plain_cpu_tables_are_disjoint():
    from meshsom.bmu_opencl import AVX512_CPUS, NON_AVX512_CPUS

    assert not AVX512_CPUS & NON_AVX512_CPUS


@pytest.mark.parametrize(
    "version,width,layout",
    [
        (POCL_3.format("znver3"), 16, "cpu-narrow"),
        (POCL_3.format("znver4"), 16, "cpu"),
        (POCL_3.format("icelake-client"), 16, "cpu"),
        (POCL_3.format("haswell"), 8, "cpu-narrow"),
        ("OpenCL 3.0 SomeVendor", 16, "cpu"),  # not PoCL: the reported width stands
    ],
)
def test_device_params_caps_the_width_at_the_kernel_target(version, width, layout):
    pytest.importorskip("pyopencl")
    from meshsom.bmu_opencl import DEFAULT_PARAMS, device_params

    assert device_params(FakeDevice(version, width=width)) == DEFAULT_PARAMS[layout]


def test_device_params_gpu_ignores_the_cpu_name():
    pytest.importorskip("pyopencl")
    from meshsom.bmu_opencl import DEFAULT_PARAMS, device_params

    gpu = FakeDevice("OpenCL 3.0 CUDA", "560.35.03", width=1, cpu=False)
    assert device_params(gpu) == DEFAULT_PARAMS["gpu"]
    small = FakeDevice("OpenCL 3.0 CUDA", "560.35.03", width=1, cpu=False)
    small.local_mem_size = 16 * 1024  # cannot hold a gemm work-group: the chain starts at "tiled"
    assert device_params(small) == DEFAULT_PARAMS["tiled"]


def test_whole_row_tile_fits_the_devices_local_memory():
    """The whole row tile is staged where it fits the device's local memory (capped at NVIDIA's 48 KB),
    at the codebook's smaller chunk where the larger one does not fit: on NVIDIA up to D = 152
    (D = 144: 46.3 KB with 8-dimension chunks), on a 32 KB device up to D = 90 (30.4 KB), beyond
    staged per chunk; every choice within the device's limit."""
    pytest.importorskip("pyopencl")
    from meshsom.bmu_opencl import GEMM_LOCAL_LIMIT, _defines, device_params, gemm_local_bytes

    nvidia = device_params(FakeDevice("OpenCL 3.0 CUDA", "560.35.03", width=1, cpu=False))
    small = FakeDevice("OpenCL 3.0", "1", width=1, cpu=False)
    small.local_mem_size = 32 * 1024
    small = device_params(small)
    assert (nvidia.local_limit, small.local_limit) == (GEMM_LOCAL_LIMIT, 32 * 1024)
    for D, on_nvidia, on_small in ((36, 1, 1), (90, 1, 1), (110, 1, 0), (144, 1, 0), (160, 0, 0)):
        assert (_defines(D, 3, np.float32, nvidia)["XRES"], _defines(D, 3, np.float32, small)["XRES"]) == (
            on_nvidia, on_small), D
        assert gemm_local_bytes(small, np.float32, D) <= 32 * 1024
        assert gemm_local_bytes(nvidia, np.float32, D) <= GEMM_LOCAL_LIMIT
    # the local arrays as kernels/bmu_gpu.cl declares them, summed independently: D = 144, KT = 8
    assert gemm_local_bytes(nvidia, np.float32, 144) == (144 * 64 + 2 * 8 * (128 + 4)) * 4 + 64 * 2 * 8


@pytest.mark.parametrize(
    "n,D,M",
    [(1, 9, 300), (3, 9, 300), (6, 9, 300), (1, 36, 250), (3, 36, 250), (6, 36, 250),
     (1, 144, 120), (3, 144, 120), (6, 144, 120), (3, 576, 70)],
)
def test_opencl_matches_numpy(ctx, kernel_params, n, D, M):
    from meshsom.bmu_opencl import bmu_opencl

    rng = np.random.default_rng(n * 1000 + D)
    N = 150
    X = rng.normal(size=(N, D)).astype(np.float32)
    W = rng.normal(size=(M, D)).astype(np.float32)
    index, sign = random_table(rng, n, D)
    ref = bmu_numpy(X, W, index, sign)
    got = bmu_opencl(X, W, index, sign, context=ctx, params=kernel_params)
    ok = separated(X, W, index, sign)
    assert ok.mean() > 0.8
    np.testing.assert_array_equal(got.unit[ok], ref.unit[ok])
    np.testing.assert_array_equal(got.variation[ok], ref.variation[ok])
    np.testing.assert_array_equal(got.second[ok], ref.second[ok])
    np.testing.assert_allclose(got.dist2, ref.dist2, rtol=1e-4, atol=1e-4)


def test_opencl_large_dimension_level5(ctx, kernel_params):
    """D = 9 * 4^4 = 2304 (the codebook is tiled over D in local memory)."""
    from meshsom.bmu_opencl import bmu_opencl

    rng = np.random.default_rng(11)
    X, W, index, sign, u, v = planted_variations(rng, 2304, mirror=False, N=12, M=37)
    got = bmu_opencl(X, W, index, sign, context=ctx, params=kernel_params)
    np.testing.assert_array_equal(got.unit, u)
    np.testing.assert_array_equal(got.variation, v)


def test_opencl_float64_exact(ctx, kernel_params):
    from meshsom.bmu_opencl import bmu_opencl

    if "fp64" not in ctx.devices[0].extensions:
        pytest.skip("device has no fp64")
    rng = np.random.default_rng(7)
    X = rng.normal(size=(80, 36))
    W = rng.normal(size=(90, 36))
    index, sign = random_table(rng, 3, 36)
    got = bmu_opencl(X, W, index, sign.astype(np.float64), context=ctx, params=kernel_params)
    u, v, d, s = brute_force(X, W, index, sign)
    np.testing.assert_array_equal(got.unit, u)
    np.testing.assert_array_equal(got.variation, v)
    np.testing.assert_array_equal(got.second, s)


def test_opencl_ties(ctx, kernel_params):
    from meshsom.bmu_opencl import bmu_opencl

    X, W, index, sign = planted_ties(np.random.default_rng(1))
    got = bmu_opencl(X, W, index, sign, context=ctx, params=kernel_params)
    check_ties(got, X, W, index, sign)
    ref = bmu_numpy(X, W, index, sign)
    for name in ("unit", "variation", "second"):
        np.testing.assert_array_equal(getattr(got, name), getattr(ref, name))


def test_opencl_planted_variation_with_mirrors(ctx, kernel_params):
    from meshsom.bmu_opencl import bmu_opencl

    X, W, index, sign, u, v = planted_variations(np.random.default_rng(4), 36)
    got = bmu_opencl(X, W, index, sign, context=ctx, params=kernel_params)
    np.testing.assert_array_equal(got.unit, u)
    np.testing.assert_array_equal(got.variation, v)


def _gemm(**fields):
    from meshsom.bmu_opencl import KernelParams

    return KernelParams(**{**KERNEL_PARAMS["gemm-split"], **fields})


@pytest.mark.parametrize("splits", [1, 2, 5, 0])
@pytest.mark.parametrize("N,n", [(1, 1), (1, 3), (37, 6), (203, 3)])
def test_gemm_unit_splits_and_partial_tiles(ctx, N, n, splits):
    """Row counts from one row to several partial row tiles (TM = 16 virtual rows), M = 301
    units in 13 tiles of 24 (the last partial), 1 to 5 unit ranges and the automatic choice
    (one range per unit tile at N = 1); compared with the float64 brute force."""
    from meshsom.bmu_numpy import exact_dist2
    from meshsom.bmu_opencl import _defines, bmu_opencl, has_fp64, unit_splits

    rng = np.random.default_rng(N * 10 + n + splits)
    D, M = 11, 301
    X = rng.normal(size=(N, D)).astype(np.float32)
    W = rng.normal(size=(M, D)).astype(np.float32)
    index, sign = random_table(rng, n, D)
    params = _gemm(unit_splits=splits)
    assert _defines(D, n, np.float32, params)["DP"] == 16  # D padded to whole chunks of KT = 8
    S, per = unit_splits(N * n, 13, params, ctx.devices[0].max_compute_units)
    assert S == (splits or S) and (S - 1) * per < 13 <= S * per
    got = bmu_opencl(X, W, index, sign, context=ctx, params=params)
    check_against_brute_force(got, X, W, index, sign, min_separated=0.8, rtol=1e-4, atol=1e-4)
    # dist2 of the winners, recomputed on the device in float64 (where it has it) as on the host
    exact = exact_dist2(X, W, index, sign, got.unit, got.variation)
    np.testing.assert_allclose(got.dist2, exact, rtol=1e-12 if has_fp64(ctx) else 1e-5)


@pytest.mark.parametrize("whole,prefetch", [(False, False), (True, True), (True, False)])
def test_gemm_staging_variants(ctx, whole, prefetch):
    """The ways the gemm kernel stages operands (the whole row tile once or X per chunk, two local
    buffers or one) give the brute force's answers, at a D of several padded chunks and at a D
    whose whole row tile does not fit (staged per chunk after all). The GPU default (whole row
    tile, two buffers) runs in every test above too, staged per chunk above D = 152 (a few D to 165 aside)."""
    from meshsom.bmu_opencl import _defines, bmu_opencl

    rng = np.random.default_rng(7)
    for D, fits in ((21, True), (1200, False)):
        params = _gemm(unit_splits=2, whole_row_tile=whole, prefetch=prefetch)
        assert _defines(D, 3, np.float32, params)["XRES"] == int(whole and fits)
        X = rng.normal(size=(90, D)).astype(np.float32)
        W = rng.normal(size=(61, D)).astype(np.float32)
        index, sign = random_table(rng, 3, D)
        got = bmu_opencl(X, W, index, sign, context=ctx, params=params)
        check_against_brute_force(got, X, W, index, sign, min_separated=0.8, rtol=1e-4, atol=1e-4)


def test_gemm_ties_across_unit_splits(ctx):
    """The duplicated units 2, 7 and 11 of the planted ties lie in three different unit ranges
    (tiles of 4 units, one tile per range): the lowest unit still wins, the next is second."""
    from meshsom.bmu_opencl import bmu_opencl

    X, W, index, sign = planted_ties(np.random.default_rng(1))
    params = _gemm(tile_units=4, group_units=2, unit_splits=3, tile_rows=8, group_rows=4)
    for p in (params, _gemm(tile_units=4, group_units=2, unit_splits=1)):
        got = bmu_opencl(X, W, index, sign, context=ctx, params=p)
        check_ties(got, X, W, index, sign)


def test_gemm_unit_splits_choice():
    """Automatic S: the least waves x (tiles per range + overhead), against a plain search over every S;
    the paper's small N fills its waves (not 288 groups on 264 places), a million rows take S = 1."""
    from meshsom.bmu_opencl import SPLIT_OVERHEAD_TILES, KernelParams, unit_splits

    gpu = KernelParams(**KERNEL_PARAMS["gemm-gpu"])
    for rows, units, cus in ((3064, 141, 132), (9192, 141, 132), (18384, 141, 132), (100_000, 141, 132),
                             (1, 141, 132), (700, 37, 2), (50, 7, 60)):
        row_tiles = -(-rows // gpu.tile_rows)
        best = None
        for S in range(1, units + 1):
            per = -(-units // S)
            real = -(-units // per)
            cost = (-(-(row_tiles * real) // (cus * gpu.groups_per_cu)), per + SPLIT_OVERHEAD_TILES)
            if best is None or cost[0] * cost[1] < best[0]:
                best = (cost[0] * cost[1], real, per)
        assert unit_splits(rows, units, gpu, cus) == best[1:], rows
    assert unit_splits(3064, 141, gpu, 132) == (11, 13)  # 48 row tiles x 11 = 528 groups: two full waves of 264
    rows = 3064 * 6  # 288 row tiles: S = 1 would be 288 groups on 264 places
    S, _ = unit_splits(rows, 141, gpu, 132)
    groups = -(-rows // 64) * S
    assert groups / (-(-groups // 264) * 264) > 0.85
    assert unit_splits(3_000_000, 141, gpu, 132) == (1, 141)
    assert unit_splits(1, 141, gpu, 132) == (141, 1)
    assert unit_splits(1, 5, _gemm(unit_splits=9), 2) == (5, 1)
    with pytest.raises(ValueError, match="tile_rows / group_rows must be a whole multiple of vector_width 4"):
        KernelParams(kernel="gemm", vector_width=4, tile_rows=96, group_rows=16)


def test_program_memoised(ctx):
    from meshsom.bmu_opencl import _defines, default_params, get_kernel

    defines = _defines(9, 3, np.float32, default_params(ctx))
    assert get_kernel(ctx, defines) is get_kernel(ctx, defines)


def test_device_selector_errors(ctx):
    from meshsom.bmu_opencl import select_device

    with pytest.raises(DeviceError, match="no OpenCL device matches 'no-such-device'"):
        select_device("no-such-device")
    with pytest.raises(DeviceError, match="does not exist"):
        select_device("9:9")
    assert select_device("0:0") is not None


def test_auto_falls_back_with_one_warning(monkeypatch, caplog):
    from meshsom import bmu_opencl

    def no_device(selector=None):
        raise DeviceError("no OpenCL device found (test)")

    monkeypatch.setattr(bmu_opencl, "get_context", no_device)
    monkeypatch.setattr(bmu_module, "_FELL_BACK", [])
    rng = np.random.default_rng(0)
    X = rng.normal(size=(10, 9)).astype(np.float32)
    W = rng.normal(size=(5, 9)).astype(np.float32)
    with caplog.at_level(logging.WARNING, logger="meshsom.bmu"):
        for _ in range(3):
            result, engine = find_bmus(X, W, backend="auto")
    assert engine.backend == "numpy"
    assert len([r for r in caplog.records if "NumPy/BLAS backend" in r.message]) == 1
    with pytest.raises(DeviceError):
        resolve_backend("opencl")


def test_tie_across_variations_goes_to_the_lowest_unit_then_variation():
    """x equals unit 5 as it is and unit 3 as its variation 1: unit 3 (variation 1) wins."""
    rng = np.random.default_rng(4)
    index, sign = block_table(9, mirror=False)
    W = rng.integers(-3, 4, size=(8, 9)).astype(np.float32)
    x = W[5].copy()
    W[3] = sign[1] * x[index[1]]
    got = bmu_numpy(x[None], W, index, sign)
    assert (got.unit[0], got.variation[0]) == (3, 1)
    from meshsom.bmu_opencl import bmu_opencl, get_context
    from meshsom.errors import DeviceError

    try:
        ctx = get_context(None)
    except DeviceError:  # no OpenCL device here: the NumPy half still ran
        return
    got = bmu_opencl(x[None], W, index, sign, context=ctx)
    assert (got.unit[0], got.variation[0]) == (3, 1)


@pytest.mark.parametrize("D,whole,kt", [(150, 1, 6), (152, 1, 8), (153, 0, 8)])
def test_gpu_default_at_the_edge_of_the_whole_row_tile(ctx, D, whole, kt):
    """The GPU tiling where the whole row tile last fits NVIDIA's 48 KB (D = 150 in 6-dimension chunks of
    the codebook, D = 152 in 8: 48,384 bytes) and where it no longer does (D = 153, staged in chunks of
    8, padded to 160): two unit tiles, the second partial; the brute force's answers."""
    from meshsom.bmu_opencl import KernelParams, _defines, bmu_opencl

    params = KernelParams(name="gpu", **KERNEL_PARAMS["gemm-gpu"])
    d = _defines(D, 3, np.float32, params)
    assert (d["XRES"], d["KT"], d["DP"]) == (whole, kt, -(-D // kt) * kt)
    rng = np.random.default_rng(D)
    X = rng.normal(size=(70, D)).astype(np.float32)
    W = rng.normal(size=(130, D)).astype(np.float32)
    index, sign = random_table(rng, 3, D)
    got = bmu_opencl(X, W, index, sign, context=ctx, params=params)
    check_against_brute_force(got, X, W, index, sign, min_separated=0.8, rtol=1e-4, atol=1e-4)
