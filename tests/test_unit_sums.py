"""Per-unit sums (a batch epoch's map step): the host reference against an independent loop, the
OpenCL kernel against the host bit for bit on every layout, and the engine's fallback."""

from __future__ import annotations

import logging

import numpy as np
import pytest

from meshsom.bmu_numpy import BMUResult, unit_order, unit_sums, varied
from tests.test_bmu import KERNEL_PARAMS, _opencl_context, block_table


@pytest.fixture(scope="module")
def ctx():
    return _opencl_context()


def table(D, n, seed=0):
    """A random variation table of n rows (row 0 the identity), ±1 signs."""
    rng = np.random.default_rng(seed)
    index = np.stack([np.arange(D)] + [rng.permutation(D) for _ in range(n - 1)]).astype(np.int64)
    sign = np.where(rng.random((n, D)) < 0.5, -1.0, 1.0).astype(np.float32)
    sign[0] = 1
    return index, sign


def winners(N, M, n, seed=0, skew=True):
    """Units (a few units win most rows, as flat walls do on real buildings; many win none) and variations."""
    rng = np.random.default_rng(seed)
    popular = rng.integers(0, M, 3)
    unit = np.where(rng.random(N) < 0.5, popular[rng.integers(0, 3, N)], rng.integers(0, M, N)) if skew \
        else rng.integers(0, M, N)
    return unit.astype(np.int64), rng.integers(0, n, N).astype(np.int64)


def loop_sums(X, unit, variation, index, sign, M):
    """Independent: one row at a time, in row order, in float64 from 0."""
    sums = np.zeros((M, X.shape[1]))
    for r in range(len(X)):
        v, u = variation[r], unit[r]
        sums[u] = sums[u] + np.array([np.float64(sign[v, k] * X[r, index[v, k]]) for k in range(X.shape[1])])
    return sums, np.bincount(unit, minlength=M).astype(np.float64)


def test_varied_is_the_signed_gather():
    rng = np.random.default_rng(1)
    X = rng.normal(size=(300, 12)).astype(np.float32)
    index, sign = table(12, 4)
    variation = rng.integers(0, 4, 300)
    expected = sign[variation] * X[np.arange(300)[:, None], index[variation]]
    np.testing.assert_array_equal(varied(X, index, sign, variation), expected)
    np.testing.assert_array_equal(varied(X, index, sign, 2), sign[2] * X[:, index[2]])
    with pytest.raises(ValueError, match="one entry per row of X \\(300\\), received 5"):
        varied(X, index, sign, variation[:5])


@pytest.mark.parametrize("M", [50, 70_000])
def test_unit_order_is_stable_by_unit(M):
    unit, _ = winners(5000, M, 1, seed=2)
    order, offsets = unit_order(unit, M)
    np.testing.assert_array_equal(order, np.argsort(unit, kind="stable"))
    np.testing.assert_array_equal(np.diff(offsets), np.bincount(unit, minlength=M))
    assert offsets[0] == 0 and offsets[-1] == len(unit)


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_host_sums_equal_a_row_by_row_loop(dtype):
    rng = np.random.default_rng(3)
    N, D, M, n = 400, 7, 40, 3
    X = rng.normal(size=(N, D)).astype(dtype)
    index, sign = table(D, n)
    sign = sign.astype(dtype)
    unit, variation = winners(N, M, n, seed=3)
    unit[unit == M - 1] = M - 2  # a unit that wins nothing
    sums, counts = unit_sums(X, unit, variation, index, sign, M)
    want, want_counts = loop_sums(X, unit, variation, index, sign, M)
    np.testing.assert_array_equal(counts, want_counts)
    assert sums.dtype == np.float64 and sums.tobytes() == want.tobytes()  # bit for bit
    assert not sums[M - 1].any()


def test_host_sums_of_no_rows():
    sums, counts = unit_sums(np.zeros((0, 4), np.float32), np.zeros(0, np.int64), np.zeros(0, np.int64),
                             *table(4, 1), 6)
    assert sums.shape == (6, 4) and not sums.any() and counts.shape == (6,) and not counts.any()


@pytest.fixture(params=["cpu", "gemm-gpu", "tiled-gpu"])
def params(request):
    """One program of each kernel variant (the sums kernel is the same text in each)."""
    from meshsom.bmu_opencl import KernelParams

    return KernelParams(name=request.param, **KERNEL_PARAMS[request.param])


@pytest.mark.parametrize("N, D, M, n, dtype, frozen", [
    (3000, 9, 300, 6, np.float32, True),
    (500, 144, 70, 3, np.float32, False),
    (700, 12, 40, 2, np.float64, True),
])
def test_device_sums_are_the_host_sums(ctx, params, N, D, M, n, dtype, frozen):
    """Every layout's program: the sums kernel gives the host's bits, resident rows or copied."""
    from meshsom.bmu_opencl import has_fp64, unit_sums_opencl

    if not has_fp64(ctx):
        pytest.skip("the OpenCL device has no float64")
    rng = np.random.default_rng(N)
    X = rng.normal(size=(N, D)).astype(dtype)
    X.flags.writeable = not frozen
    W = rng.normal(size=(M, D)).astype(dtype)
    index, sign = table(D, n, seed=N)
    unit, variation = winners(N, M, n, seed=N)
    bmu = BMUResult(unit, variation, np.zeros(N), unit)
    for _ in range(2):  # the second call reads the resident rows
        sums, counts = unit_sums_opencl(X, W, bmu, index, sign, context=ctx, params=params)
        want, want_counts = unit_sums(X, unit, variation, index, sign.astype(dtype), M)
        np.testing.assert_array_equal(counts, want_counts)
        assert sums.tobytes() == want.tobytes()


def test_engine_takes_the_sums_on_the_device(ctx, monkeypatch):
    """partial_sums with the OpenCL engine runs the device kernel (not the host) and equals NumPy's bits."""
    from meshsom import bmu, bmu_opencl
    from meshsom.som import partial_sums

    if not bmu_opencl.has_fp64(ctx):
        pytest.skip("the OpenCL device has no float64")
    host_calls = []
    real = bmu.unit_sums
    monkeypatch.setattr(bmu, "unit_sums", lambda *a: host_calls.append(1) or real(*a))
    rng = np.random.default_rng(9)
    X = rng.normal(size=(2000, 9)).astype(np.float32)
    X.flags.writeable = False
    W = rng.normal(size=(60, 9)).astype(np.float32)
    index, sign = block_table(9)
    engine = bmu.resolve_backend("opencl", context=ctx)
    sums, counts, found = partial_sums(X, W, index[:3], sign[:3], backend=engine)
    assert host_calls == [] and engine.sums_on_host == ""
    ref_sums, ref_counts, ref = partial_sums(X, W, index[:3], sign[:3], backend="numpy")
    np.testing.assert_array_equal(found.unit, ref.unit)
    np.testing.assert_array_equal(counts, ref_counts)
    assert sums.tobytes() == ref_sums.tobytes()


def test_engine_without_float64_sums_on_the_host_with_one_warning(ctx, monkeypatch, caplog):
    from meshsom import bmu, bmu_opencl
    from meshsom.som import partial_sums

    monkeypatch.setattr(bmu_opencl, "has_fp64", lambda context: False)
    rng = np.random.default_rng(10)
    X = rng.normal(size=(500, 9)).astype(np.float32)
    W = rng.normal(size=(30, 9)).astype(np.float32)
    engine = bmu.resolve_backend("opencl", context=ctx)
    with caplog.at_level(logging.WARNING, logger="meshsom.bmu"):
        for _ in range(3):
            sums, counts, _ = partial_sums(X, W, backend=engine)
    lines = [r.getMessage() for r in caplog.records if "per-unit sums" in r.getMessage()]
    assert len(lines) == 1 and "has no float64" in lines[0]
    assert "per-unit sums on the host" in engine.describe()["fallback"]
    ref_sums, ref_counts, _ = partial_sums(X, W, backend="numpy")
    assert sums.tobytes() == ref_sums.tobytes()
    np.testing.assert_array_equal(counts, ref_counts)
