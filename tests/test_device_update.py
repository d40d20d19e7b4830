"""A batch epoch's update on the device (kernels/batch_update.cl): the sums kept there, smoothed and
divided into the codebook, which stays there for the next search. Checked against an independent
dense Gaussian on the torus, against the host's batch_update, in SOM.fit, and for its fallbacks."""

from __future__ import annotations

import logging
from types import SimpleNamespace

import numpy as np
import pytest

from meshsom.bmu_numpy import BMUResult, unit_sums
from tests.test_bmu import KERNEL_PARAMS, _opencl_context, block_table
from tests.test_epoch_sums import table, winners


@pytest.fixture(scope="module")
def ctx():
    context = _opencl_context()
    from meshsom.bmu_opencl import has_fp64

    if not has_fp64(context):
        pytest.skip("the OpenCL device has no float64: updates run on the host")
    return context


@pytest.fixture(params=["cpu", "gemm-gpu", "tiled-gpu"])
def params(request):
    """One program of each kernel variant (the update kernels are the same text in each)."""
    from meshsom.bmu_opencl import KernelParams

    return KernelParams(name=request.param, **KERNEL_PARAMS[request.param])


def dense_update(W, sums, counts, sigma, rows, cols, topology, min_weight=1e-12):
    """Independent: the M x M Gaussian of the 2-D cell distance (wrapped on a torus), one product."""
    r, c = np.divmod(np.arange(rows * cols), cols)
    dr = np.abs(r[:, None] - r[None, :])
    dc = np.abs(c[:, None] - c[None, :])
    if topology == "toroidal":
        dr, dc = np.minimum(dr, rows - dr), np.minimum(dc, cols - dc)
    H = np.exp(-(dr**2 + dc**2) / (2.0 * sigma**2))
    num, den = H @ sums, H @ counts
    out = np.where((den > min_weight)[:, None], num / np.where(den > min_weight, den, 1.0)[:, None], W)
    return out.astype(W.dtype)


def kept_sums(ctx, params, X, W, unit, variation, index, sign, blocks=None, init=None):
    from meshsom.bmu_opencl import unit_sums_opencl

    bmu = BMUResult(unit, variation, np.zeros(len(X)), unit)
    return unit_sums_opencl(X, W, bmu, index, sign, context=ctx, params=params, blocks=blocks, init=init, keep=True)


@pytest.mark.parametrize("rows, cols, D, dtype, topology, sigma", [
    (6, 9, 9, np.float32, "toroidal", 2.0),
    (7, 5, 36, np.float32, "planar", 0.8),
    (5, 8, 12, np.float64, "toroidal", 1.3),
    (4, 6, 9, np.float32, "toroidal", 0.05),  # the neighbours' weights underflow: units that won nothing keep W
])
def test_update_on_the_device_is_the_dense_gaussian(ctx, params, rows, cols, D, dtype, topology, sigma):
    from meshsom import bmu_opencl
    from meshsom.som import batch_update, gaussian_kernel_1d

    M = rows * cols
    rng = np.random.default_rng(M + D)
    X = rng.normal(size=(900, D)).astype(dtype)
    X.flags.writeable = False
    W = rng.normal(size=(M, D)).astype(dtype)
    index, sign = table(D, 3, seed=D)
    sign = sign.astype(dtype)
    unit, variation = winners(len(X), M, 3, seed=M)
    unit[unit == 1] = 2  # unit 1 wins nothing
    sums, counts = kept_sums(ctx, params, X, W, unit, variation, index, sign)
    assert isinstance(sums, bmu_opencl.DeviceArray) and sums.shape == (M, D)
    host_sums, host_counts = unit_sums(X, unit, variation, index, sign, M)
    assert np.asarray(sums).tobytes() == host_sums.tobytes()  # kept, not changed
    np.testing.assert_array_equal(counts, host_counts)
    got = bmu_opencl.batch_update_opencl(W, sums, counts, gaussian_kernel_1d(rows, sigma, topology),
                                         gaussian_kernel_1d(cols, sigma, topology), 1e-12)
    assert got.dtype == W.dtype and not got.flags.writeable
    want = dense_update(W, host_sums, host_counts, sigma, rows, cols, topology)
    rtol = 1e-6 if dtype == np.float32 else 1e-12
    scale = rtol * np.abs(want).max()  # smoothed sums of both signs can cancel
    np.testing.assert_allclose(got, want, rtol=rtol, atol=scale)
    host = batch_update(W, host_sums, host_counts, sigma, rows, cols, topology)
    np.testing.assert_allclose(got, host, rtol=rtol, atol=scale)
    if sigma < 0.1:
        assert got[1].tobytes() == W[1].tobytes()  # kept its prototype, bit for bit


def test_kept_sums_chain_over_passes_on_the_device(ctx):
    """A pass's kept sums are the next pass's start (init), on the device: the host's chained bits."""
    from meshsom.bmu_opencl import KernelParams

    params = KernelParams(name="cpu", **KERNEL_PARAMS["cpu"])
    rng = np.random.default_rng(5)
    N, D, M = 600, 9, 30
    X = (rng.normal(size=(N, D)) * 10.0 ** rng.uniform(-8, 8, size=(N, 1))).astype(np.float32)
    X.flags.writeable = False
    W = rng.normal(size=(M, D)).astype(np.float32)
    index, sign = table(D, 2)
    unit, variation = winners(N, M, 2, seed=5)
    first, _ = kept_sums(ctx, params, X[:250], W, unit[:250], variation[:250], index, sign, blocks=[(0, 100), (100, 250)])
    chained, _ = kept_sums(ctx, params, X[250:], W, unit[250:], variation[250:], index, sign, init=first)
    host, _ = unit_sums(X[:250], unit[:250], variation[:250], index, sign, M, [(0, 100), (100, 250)])
    host, _ = unit_sums(X[250:], unit[250:], variation[250:], index, sign, M, init=host)
    assert np.asarray(chained).tobytes() == host.tobytes()


def test_the_new_codebook_stays_on_the_device_for_the_next_search(ctx):
    from meshsom import bmu_opencl
    from meshsom.bmu import resolve_backend
    from meshsom.som import batch_update, blocks_sums

    rows, cols, D = 5, 6, 9
    rng = np.random.default_rng(8)
    X = rng.normal(size=(1200, D)).astype(np.float32)
    X.flags.writeable = False
    W = rng.normal(size=(rows * cols, D)).astype(np.float32)
    index, sign = block_table(D)
    engine = resolve_backend("opencl", context=ctx)
    part = blocks_sums(X, W, rows, cols, "toroidal", index[:3], sign[:3], backend=engine, keep=True)
    new = engine.batch_update(W, part["sums"], part["counts"], 2.0, rows, cols)
    cache = bmu_opencl.resident_codebooks(ctx)
    assert new in cache and not new.flags.writeable
    np.testing.assert_allclose(new, batch_update(W, np.asarray(part["sums"]), part["counts"], 2.0, rows, cols),
                               rtol=1e-6)
    hits = cache.hits
    found = engine.search(X, new, index[:3], sign[:3])
    q, qc = engine.row_errors(X, new, found, index[:3], sign[:3])
    assert cache.hits >= hits + 1  # read the device copy (the row errors at least; the gemm search too)
    copy = new.copy()  # writable: never resident, sent up
    assert copy not in cache
    with pytest.raises(ValueError, match="read-only"):
        cache.add(copy, None)
    again = engine.search(X, copy, index[:3], sign[:3])
    ref = engine.search(X, copy, index[:3], sign[:3])
    np.testing.assert_array_equal(found.unit, again.unit)
    np.testing.assert_array_equal(found.unit, ref.unit)
    q2, qc2 = engine.row_errors(X, copy, again, index[:3], sign[:3])
    assert q.tobytes() == q2.tobytes() and qc.tobytes() == qc2.tobytes()


def test_the_gemm_search_reads_a_resident_codebook(ctx):
    from meshsom import bmu_opencl
    from meshsom.bmu_opencl import KernelParams, bmu_opencl as search

    params = KernelParams(name="gemm-gpu", **KERNEL_PARAMS["gemm-gpu"])
    rng = np.random.default_rng(4)
    X = rng.normal(size=(700, 9)).astype(np.float32)
    W = rng.normal(size=(40, 9)).astype(np.float32)
    index, sign = block_table(9)
    W.flags.writeable = False
    # a codebook "made on the device" whose buffer holds -W (the same norms), so reading it shows
    cache = bmu_opencl.resident_codebooks(ctx)
    cache.add(W, bmu_opencl.upload(ctx, np.ascontiguousarray(-W)))
    hits = cache.hits
    got = search(X, W, index[:3], sign[:3], context=ctx, params=params)
    assert cache.hits == hits + 1
    want = search(X, -W, index[:3], sign[:3], context=ctx, params=params)
    np.testing.assert_array_equal(got.unit, want.unit)  # the kernel read the device copy
    assert not np.array_equal(got.unit, search(X, W.copy(), index[:3], sign[:3], context=ctx, params=params).unit)


@pytest.mark.parametrize("passes", [1, 3])
def test_fit_with_the_update_on_the_device(ctx, passes, monkeypatch):
    """SOM.fit, update="device": the host's map to rounding (here bit for bit: few terms); in passes
    the same bits as in one."""
    from meshsom import som as som_module
    from meshsom.bmu import resolve_backend
    from meshsom.som import BLOCK_ROWS, SOM

    rng = np.random.default_rng(21)
    N = 2 * BLOCK_ROWS + 300 if passes > 1 else 3000
    X = rng.normal(size=(N, 9)).astype(np.float32)
    index, sign = block_table(9)
    engine = resolve_backend("opencl", context=ctx)
    kwargs = dict(rows=6, cols=7, epochs=4, random_state=0, backend=engine)
    host = SOM(update="host", **kwargs).fit(X, index[:3], sign[:3])
    seen = []
    device = SOM(update="device", **kwargs).fit(X, index[:3], sign[:3],
                                                callbacks=[lambda e, som, info: seen.append(type(info.sums["sums"]))])
    assert host.update_ == "host" and device.update_ == "device"
    assert seen and all(t.__name__ == "DeviceArray" for t in seen)
    assert device.weights_.flags.writeable  # the map's own array after fit
    np.testing.assert_allclose(device.weights_, host.weights_, rtol=1e-5, atol=1e-6)
    np.testing.assert_array_equal(device.predict(X), host.predict(X))
    if passes > 1:
        monkeypatch.setattr(som_module, "PASS_BYTES", 1)
        split = SOM(update="device", **kwargs).fit(X, index[:3], sign[:3])
        assert split.weights_.tobytes() == device.weights_.tobytes()


def test_update_policy(ctx, caplog):
    from meshsom.bmu import resolve_backend

    numpy_engine = resolve_backend("numpy")
    assert not numpy_engine.update_on_device("auto") and not numpy_engine.update_on_device("host")
    with caplog.at_level(logging.WARNING, logger="meshsom.bmu"):
        assert not numpy_engine.update_on_device("device")
        assert not numpy_engine.update_on_device("device")
    lines = [r.getMessage() for r in caplog.records if "epoch updates" in r.getMessage()]
    assert len(lines) == 1 and "NumPy/BLAS backend has no device" in lines[0]
    assert "epoch update on the host" in numpy_engine.describe()["fallback"]
    with pytest.raises(ValueError, match="update must be one of auto, host, device; received 'gpu'"):
        numpy_engine.update_on_device("gpu")
    engine = resolve_backend("opencl", context=ctx)
    is_cpu = bool(ctx.devices[0].type & __import__("pyopencl").device_type.CPU)
    assert engine.update_on_device("auto") is (not is_cpu)  # auto: GPUs only
    assert engine.update_on_device("device") and not engine.update_on_device("host")
    from meshsom.som import SOM

    with pytest.raises(ValueError, match="update must be one of"):
        SOM(4, 4, update="gpu").fit(np.zeros((10, 3), np.float32))


def test_a_failing_update_falls_back_to_the_host_with_one_warning(ctx, monkeypatch, caplog):
    from meshsom import bmu_opencl
    from meshsom.bmu import resolve_backend
    from meshsom.errors import DeviceError
    from meshsom.som import SOM

    def broken(*args, **kwargs):
        raise DeviceError("test device: the update on the device failed (clEnqueueNDRangeKernel: OUT_OF_RESOURCES)")

    monkeypatch.setattr(bmu_opencl, "batch_update_opencl", broken)
    rng = np.random.default_rng(2)
    X = rng.normal(size=(800, 9)).astype(np.float32)
    engine = resolve_backend("opencl", context=ctx)
    with caplog.at_level(logging.WARNING, logger="meshsom.bmu"):
        som = SOM(5, 5, epochs=3, backend=engine, update="device").fit(X)
    lines = [r.getMessage() for r in caplog.records if "epoch updates" in r.getMessage()]
    assert len(lines) == 1 and "OUT_OF_RESOURCES" in lines[0]
    assert som.update_ == "host" and "epoch update on the host" in engine.describe()["fallback"]
    ref = SOM(5, 5, epochs=3, backend=resolve_backend("opencl", context=ctx), update="host").fit(X)
    assert som.weights_.tobytes() == ref.weights_.tobytes()  # the host's update from the first epoch on


def test_a_map_pickled_before_the_update_parameter_trains_again():
    import pickle

    from meshsom.som import SOM

    X = np.random.default_rng(3).normal(size=(200, 3)).astype(np.float32)
    som = SOM(3, 4, epochs=2, backend="numpy").fit(X)
    state = som.__getstate__()
    del state["update"]  # as a map pickled by an earlier meshsom
    old = SOM.__new__(SOM)
    old.__setstate__(state)
    assert old.update == "auto"
    again = pickle.loads(pickle.dumps(old)).fit(X)
    assert again.weights_.tobytes() == som.weights_.tobytes() and again.update_ == "host"


def test_update_says_host_where_the_search_fell_back_to_numpy(ctx, monkeypatch):
    """update="device" on an engine whose layouts all fail: NumPy search, host sums, host update."""
    from meshsom import bmu_opencl
    from meshsom.bmu import resolve_backend
    from meshsom.som import SOM

    def no_layout(*args, **kwargs):
        raise bmu_opencl.KernelLayoutError("cpu", "test device", "injected")

    monkeypatch.setattr(bmu_opencl, "bmu_opencl", no_layout)
    monkeypatch.setattr(bmu_opencl, "probe_layout", lambda *a, **k: SimpleNamespace(ok=False))
    X = np.random.default_rng(4).normal(size=(300, 9)).astype(np.float32)
    engine = resolve_backend("auto", context=ctx)
    som = SOM(4, 5, epochs=2, backend=engine, update="device").fit(X)
    assert engine.describe()["layout"] == "numpy" and som.update_ == "host"
    ref = SOM(4, 5, epochs=2, backend="numpy").fit(X)
    assert som.weights_.tobytes() == ref.weights_.tobytes()
