"""Resident rows: a read-only X stays on the device between searches, with the same answers."""

from __future__ import annotations

import gc
import weakref

import numpy as np
import pytest

from meshsom.bmu import resolve_backend
from meshsom.bmu_numpy import bmu_numpy
from tests.test_bmu import KERNEL_PARAMS, _opencl_context, block_table

#: One tiling of each kernel layout (cpu, cpu-narrow, the gemm GPU default and a split gemm, tiled).
LAYOUTS = ["cpu", "cpu-narrow", "gemm-gpu", "gemm-split", "tiled-gpu"]
#: Host-to-device copies of a search whose rows are resident: the codebook and its norms.
CODEBOOK_UPLOADS = 2
#: Copies of a search that sends everything: rows, codebook, norms, index and sign tables.
ALL_UPLOADS = 5


@pytest.fixture(scope="module")
def ctx():
    return _opencl_context()


@pytest.fixture
def uploads(ctx, monkeypatch):
    """Every host-to-device copy of the searches in a test, as (nbytes, array id); a fresh resident store."""
    from meshsom import bmu_opencl

    monkeypatch.setattr(bmu_opencl, "_RESIDENT", weakref.WeakKeyDictionary())
    seen = []
    real = bmu_opencl.upload

    def counted(context, host):
        seen.append((host.nbytes, id(host)))
        return real(context, host)

    monkeypatch.setattr(bmu_opencl, "upload", counted)
    return seen


def frozen(a):
    a = np.array(a, copy=True)
    a.flags.writeable = False
    return a


def workload(seed=0, N=150, D=9, M=70, n=3):
    rng = np.random.default_rng(seed)
    X = frozen(rng.normal(size=(N, D)).astype(np.float32))
    W = rng.normal(size=(M, D)).astype(np.float32)
    index, sign = block_table(D)
    return X, W, index[:n], sign[:n]


def assert_same(a, b):
    for field in ("unit", "variation", "dist2", "second"):
        np.testing.assert_array_equal(getattr(a, field), getattr(b, field), err_msg=field)


@pytest.mark.parametrize("layout", LAYOUTS)
def test_read_only_rows_go_up_once(ctx, uploads, layout):
    from meshsom.bmu_opencl import KernelParams, bmu_opencl, resident_rows

    params = KernelParams(**KERNEL_PARAMS[layout])
    X, W, index, sign = workload()
    first = bmu_opencl(X, W, index, sign, context=ctx, params=params)
    assert len(uploads) == ALL_UPLOADS
    assert X in resident_rows(ctx)
    del uploads[:]
    W2 = W + np.float32(0.25)  # the next epoch's codebook
    again = bmu_opencl(X, W2, index, sign, context=ctx, params=params)
    assert len(uploads) == CODEBOOK_UPLOADS
    assert X.nbytes not in [size for size, _ in uploads]
    fresh = bmu_opencl(np.array(X), W2, index, sign, context=ctx, params=params)  # writable: all copied
    assert_same(again, fresh)
    assert_same(first, bmu_opencl(np.array(X), W, index, sign, context=ctx, params=params))
    ref = bmu_numpy(X, W2, index, sign)
    np.testing.assert_array_equal(again.unit, ref.unit)
    np.testing.assert_array_equal(again.variation, ref.variation)
    np.testing.assert_allclose(again.dist2, ref.dist2, rtol=1e-5)


def test_new_table_with_resident_rows(ctx, uploads):
    """Rows stay; a table not searched with them yet goes up (and then stays too)."""
    from meshsom.bmu_opencl import DEFAULT_PARAMS, bmu_opencl

    X, W, index, sign = workload(n=6)
    bmu_opencl(X, W, index[:3], sign[:3], context=ctx, params=DEFAULT_PARAMS["tiled"])
    del uploads[:]
    got = bmu_opencl(X, W, index, sign, context=ctx, params=DEFAULT_PARAMS["tiled"])
    assert len(uploads) == CODEBOOK_UPLOADS + 2  # the codebook, its norms, the new index and sign
    del uploads[:]
    bmu_opencl(X, W, index, sign, context=ctx, params=DEFAULT_PARAMS["tiled"])
    assert len(uploads) == CODEBOOK_UPLOADS
    np.testing.assert_array_equal(got.unit, bmu_numpy(X, W, index, sign).unit)


def test_rows_shared_by_the_layouts_of_a_context(ctx, uploads):
    """The fallback chain's layouts search one device copy of the rows."""
    from meshsom.bmu_opencl import KernelParams, bmu_opencl

    X, W, index, sign = workload(seed=1)
    for layout in ("cpu", "tiled-gpu", "gemm-gpu"):
        bmu_opencl(X, W, index, sign, context=ctx, params=KernelParams(**KERNEL_PARAMS[layout]))
    assert [size for size, _ in uploads].count(X.nbytes) == 1


def test_writable_rows_are_never_held(ctx, uploads):
    from meshsom.bmu_opencl import DEFAULT_PARAMS, bmu_opencl, immutable, resident_rows

    X, W, index, sign = workload(seed=2)
    writable = np.array(X)
    view = writable[:]
    view.flags.writeable = False  # read-only, but it changes with the array it views
    assert not immutable(view) and not immutable(writable) and immutable(X) and immutable(X[1:])
    over_bytearray = np.frombuffer(bytearray(X.tobytes()), X.dtype)
    over_bytearray.flags.writeable = False  # the bytearray can still change
    assert not immutable(over_bytearray) and immutable(np.frombuffer(X.tobytes(), X.dtype))
    for rows in (writable, view):
        for _ in range(2):
            bmu_opencl(rows, W, index, sign, context=ctx, params=DEFAULT_PARAMS["tiled"])
    assert len(uploads) == 4 * ALL_UPLOADS
    assert len(resident_rows(ctx)) == 0
    writable[0] += 1.0  # the next search sees the new values
    got = bmu_opencl(view, W, index, sign, context=ctx, params=DEFAULT_PARAMS["tiled"])
    np.testing.assert_array_equal(got.unit, bmu_numpy(writable, W, index, sign).unit)


def test_freed_rows_never_match_a_new_array(ctx, uploads):
    """A freed array's entry is dropped, and an entry whose weak reference does not return X
    itself (what a new array at a freed one's address finds) is never used."""
    from meshsom.bmu_opencl import DEFAULT_PARAMS, bmu_opencl, resident_rows

    params = DEFAULT_PARAMS["tiled"]
    X, W, index, sign = workload(seed=3)
    bmu_opencl(X, W, index, sign, context=ctx, params=params)
    store = resident_rows(ctx)
    old = id(X)
    del X
    gc.collect()
    assert len(store) == 0
    # a new array at the same address where the allocator gives one (CPython usually does)
    for attempt in range(100):
        Y = frozen(np.random.default_rng(attempt).normal(size=(150, 9)).astype(np.float32))
        if id(Y) == old:
            break
    del uploads[:]
    got = bmu_opencl(Y, W, index, sign, context=ctx, params=params)
    assert [size for size, _ in uploads].count(Y.nbytes) == 1
    np.testing.assert_array_equal(got.unit, bmu_numpy(Y, W, index, sign).unit)
    # the same id, forced: Z's key holds Y's entry, which must not serve Z
    Z = frozen(Y[::-1])
    with store._lock:
        store._entries[id(Z)] = store._entries.pop(id(Y))
    del uploads[:]
    got = bmu_opencl(Z, W, index, sign, context=ctx, params=params)
    assert [size for size, _ in uploads].count(Z.nbytes) == 1
    np.testing.assert_array_equal(got.unit, bmu_numpy(Z, W, index, sign).unit)
    assert Z in store and Y not in store


def test_least_recently_used_out_at_the_budget(ctx, uploads, monkeypatch):
    from meshsom import bmu_opencl as bo

    X, W, index, sign = workload(seed=4)
    A, B, C = X, frozen(X + 1), frozen(X - 1)
    tables = index.nbytes // 2 + sign.nbytes  # int32 index, float32 sign
    monkeypatch.setattr(bo, "RESIDENT_BYTES", 2 * (X.nbytes + tables) + X.nbytes // 2)
    params = bo.DEFAULT_PARAMS["tiled"]
    for rows in (A, B, C):
        bo.bmu_opencl(rows, W, index, sign, context=ctx, params=params)
    store = bo.resident_rows(ctx)
    assert store.budget == bo.RESIDENT_BYTES
    assert A not in store and B in store and C in store and store.evictions == 1
    assert store.nbytes <= store.budget
    bo.bmu_opencl(B, W, index, sign, context=ctx, params=params)  # B becomes the most recent
    del uploads[:]
    bo.bmu_opencl(A, W, index, sign, context=ctx, params=params)
    assert [size for size, _ in uploads].count(X.nbytes) == 1
    assert A in store and B in store and C not in store
    big = frozen(np.concatenate([X] * 3))  # over the whole budget: searched, never held
    got = bo.bmu_opencl(big, W, index, sign, context=ctx, params=params)
    assert big not in store and A in store and B in store
    np.testing.assert_array_equal(got.unit, bmu_numpy(big, W, index, sign).unit)


def test_engine_chain_keeps_rows_resident(ctx, uploads, monkeypatch):
    """Through Engine.search: a layout that fails falls back to the next, which keeps the rows."""
    from meshsom import bmu_opencl as bo

    real = bo.get_kernel

    def failing(context, defines, function=None, guard=True, layout="custom"):
        if layout == "cpu":
            raise bo.KernelLayoutError(layout, bo.device_name(context), "injected by the test")
        return real(context, defines, function, guard, layout)

    monkeypatch.setattr(bo, "get_kernel", failing)
    engine = resolve_backend("opencl", context=ctx)
    engine.layouts = ("cpu", "tiled")
    X, W, index, sign = workload(seed=5)
    first = engine.search(X, W, index, sign)
    del uploads[:]
    again = engine.search(X, W, index, sign)
    assert len(uploads) == CODEBOOK_UPLOADS
    assert engine.describe()["layout"] == "tiled"
    assert_same(first, again)
    np.testing.assert_array_equal(again.unit, bmu_numpy(X, W, index, sign).unit)


def clustered(seed, N, D, M, spread=10.0, noise=0.01):
    """Rows near M well-separated random centres (BMUs unambiguous in float32), and a codebook
    of the centres moved a little."""
    rng = np.random.default_rng(seed)
    centres = rng.normal(scale=spread, size=(M, D))
    X = centres[rng.integers(0, M, N)] + rng.normal(scale=noise, size=(N, D))
    W = centres + rng.normal(scale=spread / 20, size=(M, D))
    return frozen(X.astype(np.float32)), W.astype(np.float32)


@pytest.mark.parametrize("n", [1, 3])
def test_partial_sums_over_epochs_match_numpy(ctx, uploads, n):
    """Several batch epochs on resident rows: the OpenCL engine's sums, counts and BMUs are the NumPy engine's."""
    from meshsom.som import batch_update, partial_sums

    rows, cols, D, epochs, sigma = 4, 5, 9, 4, 0.5
    X, W0 = clustered(6, 400, D, rows * cols)
    index, sign = block_table(D)
    index, sign = index[:n], sign[:n]
    engines = {"opencl": resolve_backend("opencl", context=ctx), "numpy": resolve_backend("numpy")}
    history = {}
    for name, engine in engines.items():
        W, out = W0, []
        for _ in range(epochs):
            sums, counts, bmu = partial_sums(X, W, index, sign, backend=engine)
            out.append((sums, counts, bmu))
            W = batch_update(W, sums, counts, sigma, rows, cols)
        history[name] = out
    for (s, c, b), (s_ref, c_ref, b_ref) in zip(history["opencl"], history["numpy"]):
        np.testing.assert_array_equal(b.unit, b_ref.unit)
        np.testing.assert_array_equal(b.variation, b_ref.variation)
        np.testing.assert_array_equal(c, c_ref)
        assert s.tobytes() == s_ref.tobytes()  # the sums are taken on the device, bit for bit the host's
    assert [size for size, _ in uploads].count(X.nbytes) == 1  # every epoch after the first: the codebook only


def test_som_fit_keeps_its_converted_copy_resident(ctx, uploads):
    """SOM.fit on float64 rows converts them once, read-only: they go up in the first epoch only;
    the caller's array is left writable."""
    from meshsom.som import SOM

    X, _ = clustered(7, 200, 9, 12)
    given = np.array(X, np.float64)
    som = SOM(rows=3, cols=4, epochs=3, backend="opencl", layout="tiled").fit(given)
    rows_up = X.nbytes  # float32 on the device
    assert [size for size, _ in uploads].count(rows_up) == 1
    assert given.flags.writeable
    ref = SOM(rows=3, cols=4, epochs=3, backend="numpy").fit(given)
    np.testing.assert_allclose(som.weights_, ref.weights_, rtol=1e-5, atol=1e-5)
