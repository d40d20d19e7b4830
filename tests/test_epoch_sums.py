"""Per-unit sums (a batch epoch's map step): the host reference against an independent loop, the
OpenCL kernel against the host bit for bit on every layout, and the engine's fallback; per-row Q / QC
distances likewise (to rounding on the device)."""

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
@pytest.mark.parametrize("order_on_device", [False, True])
def test_device_sums_are_the_host_sums(ctx, params, N, D, M, n, dtype, frozen, order_on_device):
    """Every layout's program: the sums kernel gives the host's bits, resident rows or copied, with
    the order of the rows by unit made on the host or on the device."""
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
        blocks = [(a, min(N, a + 400)) for a in range(0, N, 400)]
        sums, counts = unit_sums_opencl(X, W, bmu, index, sign, context=ctx, params=params, blocks=blocks,
                                        order_on_device=order_on_device)
        want, want_counts = unit_sums(X, unit, variation, index, sign.astype(dtype), M, blocks)
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
    assert "per-unit sums and errors on the host" in engine.describe()["fallback"]
    ref_sums, ref_counts, _ = partial_sums(X, W, backend="numpy")
    assert sums.tobytes() == ref_sums.tobytes()
    np.testing.assert_array_equal(counts, ref_counts)


# ----------------------------------------------------------------------------- per-row errors


def loop_errors(X, W, unit, variation, index, sign, component):
    """Independent: one row and one value at a time, in the documented order."""
    N, D = X.shape
    q, qc = np.empty(N), np.full(N, np.nan)
    for r in range(N):
        v, u = variation[r], unit[r]
        d = [np.float64(sign[v, k] * X[r, index[v, k]]) - np.float64(W[u, k]) for k in range(D)]
        total = 0.0
        for x in d:
            total += x * x
        q[r] = np.sqrt(total)
        if D % component == 0:
            norms = 0.0
            for j in range(D // component):
                part = 0.0
                for x in d[j * component:(j + 1) * component]:
                    part += x * x
                norms += np.sqrt(part)
            qc[r] = norms / (D // component)
    return q, qc


@pytest.mark.parametrize("D, component", [(9, 3), (12, 4), (10, 3)])
def test_row_errors_follow_the_documented_order(D, component, monkeypatch):
    from meshsom import metrics

    monkeypatch.setattr(metrics, "ROW_ERRORS_BLOCK", 70)  # several blocks
    rng = np.random.default_rng(D)
    N, M, n = 300, 25, 3
    X = rng.normal(size=(N, D)).astype(np.float32)
    W = rng.normal(size=(M, D)).astype(np.float32)
    index, sign = table(D, n, seed=D)
    unit, variation = winners(N, M, n, seed=D)
    q, qc = metrics.row_errors(X, W, BMUResult(unit, variation, np.zeros(N), unit), index, sign, component)
    want_q, want_qc = loop_errors(X, W, unit, variation, index, sign, component)
    assert q.tobytes() == want_q.tobytes()
    np.testing.assert_array_equal(qc, want_qc)  # NaN where component does not divide D
    assert np.isnan(qc).all() == bool(D % component)


def test_q_and_qc_errors_are_the_textbook_formulas():
    """Against the plain formulas: mean ||d||, and the mean over slices of the slice norms."""
    from meshsom.metrics import q_error, qc_error

    rng = np.random.default_rng(4)
    X = rng.normal(size=(200, 9)).astype(np.float32)
    W = rng.normal(size=(15, 9)).astype(np.float32)
    index, sign = table(9, 2, seed=4)
    unit, variation = winners(200, 15, 2, seed=4)
    bmu = BMUResult(unit, variation, np.zeros(200), unit)
    d = (sign[variation] * X[np.arange(200)[:, None], index[variation]]).astype(np.float64) - W[unit]
    assert q_error(X, W, bmu, index, sign) == pytest.approx(np.linalg.norm(d, axis=1).mean(), rel=1e-14)
    assert qc_error(X, W, bmu, index, sign) == pytest.approx(
        np.linalg.norm(d.reshape(200, 3, 3), axis=2).mean(), rel=1e-14)


@pytest.mark.parametrize("N, D, M, n, dtype", [(3000, 9, 300, 6, np.float32), (500, 144, 70, 3, np.float32),
                                               (400, 10, 30, 1, np.float32), (300, 12, 20, 2, np.float64)])
def test_device_row_errors_are_the_host_row_errors(ctx, N, D, M, n, dtype):
    from meshsom.bmu_opencl import has_fp64, layout_params, row_errors_opencl
    from meshsom.metrics import row_errors

    if not has_fp64(ctx):
        pytest.skip("the OpenCL device has no float64")
    rng = np.random.default_rng(N + D)
    X = rng.normal(size=(N, D)).astype(dtype)
    X.flags.writeable = False
    W = rng.normal(size=(M, D)).astype(dtype)
    index, sign = table(D, n, seed=N)
    unit, variation = winners(N, M, n, seed=N)
    bmu = BMUResult(unit, variation, np.zeros(N), unit)
    for layout in ("cpu", "gpu"):
        q, qc = row_errors_opencl(X, W, bmu, index, sign, context=ctx, params=layout_params(ctx.devices[0], layout))
        want_q, want_qc = row_errors(X, W, bmu, index, sign.astype(dtype))
        np.testing.assert_allclose(q, want_q, rtol=1e-12, atol=0)
        np.testing.assert_allclose(qc, want_qc, rtol=1e-12, atol=0)  # NaN for D = 10


def test_block_sums_take_the_errors_on_the_device(ctx, monkeypatch):
    """block_sums with the OpenCL engine: per-row errors and the tie check from the device kernels, the
    NumPy engine's sums."""
    from meshsom import bmu, bmu_opencl
    from meshsom.som import block_sums

    if not bmu_opencl.has_fp64(ctx):
        pytest.skip("the OpenCL device has no float64")
    host_calls = []
    for name in ("row_errors", "tie_ruled_errors"):
        real = getattr(bmu, name)
        monkeypatch.setattr(bmu, name, lambda *a, real=real, **k: host_calls.append(1) or real(*a, **k))
    rng = np.random.default_rng(11)
    X = rng.normal(size=(2500, 36)).astype(np.float32)
    X.flags.writeable = False
    W = rng.normal(size=(48, 36)).astype(np.float32)
    index, sign = block_table(36)
    engine = bmu.resolve_backend("opencl", context=ctx)
    got = block_sums(X, W, 6, 8, "toroidal", index[:3], sign[:3], backend=engine)
    assert host_calls == []
    ref = block_sums(X, W, 6, 8, "toroidal", index[:3], sign[:3], backend="numpy")
    assert host_calls == [1, 1]
    assert got["n"] == ref["n"] and got["t_bad"] == ref["t_bad"] > 0
    assert got["q_sum"] == pytest.approx(ref["q_sum"], rel=1e-13)
    assert got["qc_sum"] == pytest.approx(ref["qc_sum"], rel=1e-13)
    assert got["sums"].tobytes() == ref["sums"].tobytes()


# ----------------------------------------------------------------------------- a whole epoch's blocks


def test_unit_order_by_block():
    unit = np.array([2, 0, 2, 1, 0, 2, 2])
    order, offsets = unit_order(unit, 3, [(0, 3), (3, 7)])
    np.testing.assert_array_equal(order, [1, 0, 2, 4, 3, 5, 6])
    np.testing.assert_array_equal(offsets, [0, 1, 1, 3, 4, 5, 7])
    with pytest.raises(ValueError, match="cover the 7 rows"):
        unit_order(unit, 3, [(0, 3)])


@pytest.mark.parametrize("backend", ["numpy", "opencl"])
@pytest.mark.parametrize("n", [1, 3])
def test_blocks_sums_equal_the_block_by_block_reduction(ctx, backend, n):
    """One pass over all blocks gives the bits of block_sums per block added in order (the pipeline's
    reduction), errors included."""
    from meshsom.bmu import resolve_backend
    from meshsom.som import add_sums, block_sums, blocks_sums, row_blocks

    rng = np.random.default_rng(12 + n)
    N, D, rows, cols = 700, 9, 5, 6
    X = (rng.normal(size=(N, D)) * 10.0 ** rng.uniform(-8, 8, size=(N, 1))).astype(np.float32)  # sums round
    X.flags.writeable = False
    W = rng.normal(size=(rows * cols, D)).astype(np.float32)
    index, sign = block_table(D)
    index, sign = (index[:n], sign[:n]) if n > 1 else (None, None)
    engine = resolve_backend(backend, context=ctx if backend == "opencl" else None)
    got = blocks_sums(X, W, rows, cols, "toroidal", index, sign, backend=engine, block_rows=97)
    total = None
    for a, b in row_blocks(N, 97):
        total = add_sums(total, block_sums(X[a:b], W, rows, cols, "toroidal", index, sign, backend=engine))
    assert got["sums"].tobytes() == total["sums"].tobytes()
    assert got["counts"].tobytes() == total["counts"].tobytes()
    for key in ("n", "t_bad", "q_sum", "qc_sum"):
        assert got[key] == total[key], key
    assert len(got["bmu"]) == N
    if backend == "opencl":
        from meshsom.bmu_opencl import has_fp64

        assert engine.sums_on_host == "" or not has_fp64(ctx)  # the blocked kernel ran
    # one block of all rows: the same sums to rounding, and for these rows the blocks matter (with
    # these winners, or, where they happen to sum alike, with each row on unit row % M)
    one = blocks_sums(X, W, rows, cols, "toroidal", index, sign, backend=engine, block_rows=N)
    np.testing.assert_allclose(one["sums"], got["sums"], rtol=1e-12)
    if one["sums"].tobytes() == got["sums"].tobytes():
        from meshsom.bmu_numpy import unit_sums

        unit, variation = np.arange(N) % (rows * cols), np.zeros(N, np.int64)
        whole = unit_sums(X, unit, variation, *block_table(D), rows * cols, blocks=[(0, N)])[0]
        blocked = unit_sums(X, unit, variation, *block_table(D), rows * cols, blocks=row_blocks(N, 97))[0]
        assert whole.tobytes() != blocked.tobytes()


@pytest.mark.parametrize("backend", ["numpy", "opencl"])
def test_passes_chained_through_total_equal_one_pass(ctx, backend):
    """Blocks reduced in passes (each pass adds to the running total) give the bits of one pass."""
    from meshsom.bmu import resolve_backend
    from meshsom.som import blocks_sums

    rng = np.random.default_rng(13)
    N, D, rows, cols = 600, 36, 4, 5
    # magnitudes over 16 decades: float64 sums of float32 values round (small ones are exact, so
    # the order of additions would not show)
    X = (rng.normal(size=(N, D)) * 10.0 ** rng.uniform(-8, 8, size=(N, 1))).astype(np.float32)
    X.flags.writeable = False
    W = rng.normal(size=(rows * cols, D)).astype(np.float32)
    index, sign = block_table(D)
    engine = resolve_backend(backend, context=ctx if backend == "opencl" else None)
    one = blocks_sums(X, W, rows, cols, "toroidal", index[:3], sign[:3], backend=engine, block_rows=97)
    total = None
    for a, b in [(0, 194), (194, 485), (485, N)]:  # whole blocks of 97 rows per pass
        total = blocks_sums(X[a:b], W, rows, cols, "toroidal", index[:3], sign[:3], backend=engine, block_rows=97,
                            total=total)
    for key in ("sums", "counts"):
        assert total[key].tobytes() == one[key].tobytes(), key
    for key in ("n", "t_bad", "q_sum", "qc_sum"):
        assert total[key] == one[key], key
    np.testing.assert_array_equal(total["bmu"].unit, one["bmu"].unit)


def test_pass_ranges_are_whole_blocks():
    from meshsom.som import pass_ranges

    assert pass_ranges(1000, 40, block_rows=100, pass_bytes=8000) == [(0, 200), (200, 400), (400, 600), (600, 800),
                                                                         (800, 1000)]
    assert pass_ranges(250, 40, block_rows=100, pass_bytes=10) == [(0, 100), (100, 200), (200, 250)]
    assert pass_ranges(250, 40, block_rows=100) == [(0, 250)]


@pytest.mark.parametrize("backend", ["numpy", "opencl"])
def test_fit_in_passes_equals_fit_in_one(ctx, backend, monkeypatch):
    """SOM.fit with one row block per pass (as on a device with little memory) trains the same codebook."""
    from meshsom import som as som_module
    from meshsom.som import BLOCK_ROWS, SOM, pass_ranges

    rng = np.random.default_rng(14)
    X = (rng.normal(size=(2 * BLOCK_ROWS + 500, 9)) * 10.0 ** rng.uniform(-8, 8, size=(2 * BLOCK_ROWS + 500, 1))
         ).astype(np.float32)  # magnitudes over 16 decades: the order of float64 additions shows
    index, sign = block_table(9)
    kwargs = dict(rows=4, cols=5, epochs=3, backend=backend, random_state=0)
    one = SOM(**kwargs).fit(X, index[:3], sign[:3])
    monkeypatch.setattr(som_module, "PASS_BYTES", 1)
    assert len(pass_ranges(len(X), 36)) == 3
    split = SOM(**kwargs).fit(X, index[:3], sign[:3])
    assert split.weights_.tobytes() == one.weights_.tobytes()


# ----------------------------------------------------------------------------- topographic errors


def loop_topographic(X, W, bmu, index, sign, rows, cols, topology, neighbourhood, rtol):
    """Independent: one row at a time, from grid coordinates, with the tie rule written out."""
    steps = [(a, b) for a in (-1, 0, 1) for b in (-1, 0, 1)
             if (a, b) != (0, 0) and (neighbourhood == 8 or a == 0 or b == 0)]
    out = np.zeros(len(X), bool)
    for r in range(len(X)):
        (ur, uc), (sr, sc) = divmod(int(bmu.unit[r]), cols), divmod(int(bmu.second[r]), cols)
        dr, dc = abs(ur - sr), abs(uc - sc)
        if topology == "toroidal":
            dr, dc = min(dr, rows - dr), min(dc, cols - dc)
        if (max(dr, dc) if neighbourhood == 8 else dr + dc) == 1:
            continue
        v = bmu.variation[r]
        xv = np.array([np.float64(sign[v, k] * X[r, index[v, k]]) for k in range(X.shape[1])])
        w2 = W[bmu.second[r]].astype(np.float64)
        d_second = ((xv - w2) ** 2).sum()
        near = []
        for a, b in steps:
            nr, nc = ur + a, uc + b
            if topology == "toroidal":
                nr, nc = nr % rows, nc % cols
            elif not (0 <= nr < rows and 0 <= nc < cols):
                continue
            near.append(((xv - W[nr * cols + nc].astype(np.float64)) ** 2).sum())
        out[r] = not min(near) <= d_second + rtol * (xv @ xv + w2 @ w2)
    return out


@pytest.mark.parametrize("topology, neighbourhood, dtype", [
    ("toroidal", 8, np.float32), ("planar", 8, np.float32), ("toroidal", 4, np.float64), ("planar", 4, np.float32),
])
def test_device_topographic_errors_are_the_tie_rule(ctx, params, topology, neighbourhood, dtype):
    """Every layout's program: the flags of an independent row-by-row check, on a map where some units
    share a prototype with a distant unit (ties for second place, as on extruded blocks)."""
    from meshsom.bmu_numpy import bmu_numpy
    from meshsom.bmu_opencl import has_fp64, topographic_errors_opencl
    from meshsom.metrics import TIE_RTOL, tied_with_neighbour, topographic_errors

    if not has_fp64(ctx):
        pytest.skip("the OpenCL device has no float64")
    rows, cols, D, n = 6, 8, 9, 3
    rng = np.random.default_rng(neighbourhood + rows)
    W = rng.normal(size=(rows * cols, D))
    hubs = np.array([20, 28, 36, 44])
    W[hubs + 1] = W[hubs] + rng.normal(scale=0.3, size=(4, D))  # a hub's right neighbour is near it ...
    W[hubs - 17] = W[hubs + 1]  # ... and shares its prototype with a unit two rows up (reported second)
    W = W.astype(dtype)
    at_hub = rng.random(800) < 0.5
    near = np.where(at_hub, rng.choice(hubs, 800), rng.integers(0, rows * cols, 800))
    X = (W[near] + rng.normal(size=(800, D)) * np.where(at_hub, 0.02, 0.3)[:, None]).astype(dtype)
    index, sign = table(D, n, seed=4)
    sign = sign.astype(dtype)
    bmu = bmu_numpy(X, W, index, sign)
    got = topographic_errors_opencl(X, W, bmu, index, sign, context=ctx, params=params, rows=rows, cols=cols,
                                    topology=topology, neighbourhood=neighbourhood)
    want = loop_topographic(X, W, bmu, index, sign, rows, cols, topology, neighbourhood, TIE_RTOL)
    host = topographic_errors(bmu.unit, bmu.second, rows, cols, topology, neighbourhood,
                              tied_with_neighbour(X, W, bmu, rows, cols, topology, index, sign, neighbourhood))
    np.testing.assert_array_equal(host, want)
    np.testing.assert_array_equal(got, want)
    assert 0 < want.sum() < len(X)
    assert want.sum() < topographic_errors(bmu.unit, bmu.second, rows, cols, topology, neighbourhood).sum()  # ties


# ----------------------------------------------------------------------------- the order on the device


def test_uniform_block_rows():
    from meshsom.bmu_opencl import uniform_block_rows

    assert uniform_block_rows(None, 10) == 10 and uniform_block_rows(None, 0) is None
    assert uniform_block_rows([(0, 4), (4, 8), (8, 10)], 10) == 4
    assert uniform_block_rows([(0, 10)], 10) == 10
    assert uniform_block_rows([(0, 4), (4, 10)], 10) is None  # the last is longer
    assert uniform_block_rows([(0, 3), (4, 10)], 10) is None  # a gap
    assert uniform_block_rows([(0, 0)], 0) is None


@pytest.mark.parametrize("N, M, block", [(1000, 50, 300), (5000, 70_000, 1000), (3000, 40, 3000), (129, 7, 64),
                                          (20_000, 300, 16384)])
def test_device_unit_order_is_the_host_order(ctx, params, N, M, block):
    """The stable order of rows by (block, unit) made on the device: the host's, row for row (units
    skewed, as flat walls make them; blocks of whole chunks and not; M above 16 bits)."""
    from meshsom.bmu_opencl import has_fp64, unit_order_opencl
    from meshsom.som import row_blocks

    if not has_fp64(ctx):
        pytest.skip("the OpenCL device has no float64: no epoch kernels")
    unit, _ = winners(N, M, 1, seed=N + M)
    blocks = row_blocks(N, block)
    order, offsets = unit_order_opencl(unit, M, blocks, context=ctx, params=params)
    want, want_offsets = unit_order(unit, M, blocks)
    np.testing.assert_array_equal(offsets, want_offsets)
    np.testing.assert_array_equal(order, want)
