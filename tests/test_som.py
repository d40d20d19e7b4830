"""SOM training: fast batch update vs an O(M^2) reference, determinism, clusters, schedules, codebook I/O."""

from __future__ import annotations

import numpy as np
import pytest
import zarr
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from meshsom.bmu_numpy import bmu_numpy
from meshsom.metrics import grid_distance, q_error
from meshsom.som import SOM, batch_update, partial_sums, sigma_schedule


def reference_update(W, sums, counts, sigma, rows, cols, topology):
    """Direct O(M^2): w_j = sum_i h_ij s_i / sum_i h_ij c_i with h the Gaussian of the cell distance."""
    M = rows * cols
    units = np.arange(M)
    d = grid_distance(units[:, None], units[None, :], rows, cols, topology)
    h = np.exp(-(d**2) / (2 * sigma**2))
    num = h @ sums
    den = h @ counts
    out = np.where(den[:, None] > 1e-12, num / np.where(den > 1e-12, den, 1)[:, None], W)
    return out


@pytest.mark.parametrize("topology", ["toroidal", "planar"])
@pytest.mark.parametrize("sigma", [0.7, 2.5, 9.0])
def test_batch_update_matches_direct_reference(topology, sigma):
    rng = np.random.default_rng(1)
    rows, cols, D = 6, 11, 4
    W = rng.normal(size=(rows * cols, D)).astype(np.float32)
    counts = rng.integers(0, 3, rows * cols).astype(np.float64)
    sums = rng.normal(size=(rows * cols, D)) * counts[:, None]
    got = batch_update(W, sums, counts, sigma, rows, cols, topology)
    want = reference_update(W, sums, counts, sigma, rows, cols, topology)
    np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-6)


def test_batch_update_keeps_units_with_zero_smoothed_count():
    W = np.arange(40, dtype=np.float32).reshape(20, 2)
    counts = np.zeros(20)
    counts[0] = 1
    sums = np.zeros((20, 2))
    sums[0] = [100, 100]
    got = batch_update(W, sums, counts, 0.05, 4, 5, "toroidal")  # neighbours' weight underflows to 0
    np.testing.assert_allclose(got[0], [100, 100])
    np.testing.assert_array_equal(got[12], W[12])


def test_partial_sums_add_the_varied_vector():
    index = np.array([[0, 1, 2], [2, 0, 1]])
    sign = np.array([[1, 1, 1], [-1, 1, 1]], np.float32)
    W = np.array([[-3.0, 1, 2], [10, 10, 10], [20, 20, 20]], np.float32)
    X = np.array([[1.0, 2, 3], [1.1, 2, 3], [10, 10, 10]], np.float32)
    sums, counts, bmu = partial_sums(X, W, index, sign, backend="numpy")
    np.testing.assert_array_equal(bmu.variation[:2], [1, 1])
    np.testing.assert_allclose(sums[0], [-3 - 3, 1 + 1.1, 2 + 2], rtol=1e-6)
    np.testing.assert_array_equal(counts, [2, 1, 0])
    # map-reduce over chunks gives the same sums
    s1, c1, _ = partial_sums(X[:1], W, index, sign, backend="numpy")
    s2, c2, _ = partial_sums(X[1:], W, index, sign, backend="numpy")
    np.testing.assert_allclose(s1 + s2, sums)
    np.testing.assert_array_equal(c1 + c2, counts)


def test_sigma_schedule():
    assert sigma_schedule(0, 10, 8.0, 1.0) == pytest.approx(8.0)
    assert sigma_schedule(9, 10, 8.0, 1.0) == pytest.approx(1.0)
    assert sigma_schedule(3, 7, 8.0, 1.0) == pytest.approx(8.0 * (1 / 8) ** 0.5)
    assert sigma_schedule(3, 7, 8.0, 1.0, "linear") == pytest.approx(4.5)
    assert sigma_schedule(0, 1, 8.0, 1.0) == pytest.approx(8.0)
    with pytest.raises(ValueError, match="decay must be one of"):
        sigma_schedule(0, 2, 1, 1, "cosine")


def clusters(rng, k=4, per=60, D=9, spread=0.3):
    """k well-separated clusters, each a flat 2-D patch (so a 2-D map region can unfold it)."""
    centres = rng.normal(scale=3.0, size=(k, D))
    parts = []
    for c in centres:
        basis = np.linalg.qr(rng.normal(size=(D, 2)))[0].T
        parts.append(c + rng.uniform(-spread, spread, size=(per, 2)) @ basis)
    return np.concatenate(parts).astype(np.float32), np.repeat(np.arange(k), per), centres


def test_training_decreases_q_error():
    rng = np.random.default_rng(0)
    X = rng.normal(size=(300, 9)).astype(np.float32)
    som = SOM(8, 10, epochs=1, sigma_start=4.0, backend="numpy").fit(X)
    first = som.evaluate(X)["q_error"]
    som = SOM(8, 10, epochs=8, sigma_start=4.0, sigma_end=0.5, backend="numpy").fit(X)
    assert som.evaluate(X)["q_error"] < 0.8 * first


@pytest.mark.parametrize("backend", ["numpy", "opencl"])
def test_same_seed_same_codebook(backend):
    if backend == "opencl":
        from meshsom.errors import DeviceError
        from meshsom.bmu_opencl import get_context

        try:
            get_context(None)
        except DeviceError as err:
            pytest.skip(f"no OpenCL device: {err}")
    rng = np.random.default_rng(1)
    X = rng.normal(size=(200, 36)).astype(np.float32)
    index = np.stack([np.roll(np.arange(36), 12 * r) for r in range(3)])
    sign = np.ones((3, 36), np.float32)
    a = SOM(6, 7, epochs=4, random_state=5, backend=backend).fit(X, index, sign)
    b = SOM(6, 7, epochs=4, random_state=5, backend=backend).fit(X, index, sign)
    c = SOM(6, 7, epochs=4, random_state=6, backend=backend).fit(X, index, sign)
    np.testing.assert_array_equal(a.weights_, b.weights_)
    assert not np.array_equal(a.weights_, c.weights_)
    assert a.backend_ == backend


def components_on_torus(units, rows, cols):
    """Connected-component label of each unit of a set (8-neighbourhood on the torus)."""
    d = grid_distance(units[:, None], units[None, :], rows, cols, "toroidal")
    return connected_components(coo_matrix(d < 1.5), directed=False)[1]


@pytest.mark.parametrize("init", ["random", "pca"])
def test_clusters_land_in_contiguous_regions(init):
    rng = np.random.default_rng(0)
    X, labels, centres = clusters(rng)
    rows, cols = 10, 12
    som = SOM(rows, cols, epochs=15, sigma_start=4.0, sigma_end=0.8, init=init, backend="numpy").fit(X)
    metrics = som.evaluate(X)
    assert metrics["t_error"] < 0.05
    # each unit belongs to the cluster its prototype is nearest to; a cluster's vectors all
    # land in one connected region of its units (interpolating units between clusters aside)
    owner = np.argmin(((som.weights_[:, None, :] - centres[None]) ** 2).sum(-1), axis=1)
    units = som.predict(X)
    for k in range(len(centres)):
        region = np.flatnonzero(owner == k)
        hits = units[labels == k]
        assert np.isin(hits, region).all()
        label = components_on_torus(region, rows, cols)
        assert len(np.unique(label[np.searchsorted(region, hits)])) == 1


def test_online_training_and_callbacks():
    rng = np.random.default_rng(3)
    X, _, _ = clusters(rng, k=3, per=30, D=6)
    seen = []
    som = SOM(5, 6, epochs=3, training="online", sigma_start=2.0, backend="numpy")
    som.fit(X, callbacks=[lambda epoch, s, info: seen.append((epoch, s.n_iter_, info.sigma))])
    assert [e for e, _, _ in seen] == [0, 1, 2] and seen[-1][1] == 3
    assert seen[0][2] == pytest.approx(2.0) and seen[-1][2] == pytest.approx(1.0)
    assert som.weights_.shape == (30, 6)
    init_q = q_error(X, X[:30], bmu_numpy(X, X[:30]))
    assert som.evaluate(X)["q_error"] < init_q + 1.0


def test_batch_callback_gets_bmus():
    rng = np.random.default_rng(4)
    X = rng.normal(size=(50, 9)).astype(np.float32)
    infos = []
    SOM(4, 5, epochs=2, backend="numpy").fit(X, callbacks=[lambda e, s, info: infos.append(info)])
    assert len(infos) == 2 and len(infos[0].bmu) == 50 and np.isfinite(infos[1].q_error)


def test_validation():
    X = np.zeros((10, 9), np.float32)
    with pytest.raises(ValueError, match="topology must be one of toroidal, planar; received 'hex'"):
        SOM(4, 4, topology="hex").fit(X)
    with pytest.raises(ValueError, match="not fitted"):
        SOM(4, 4).predict(X)
    som = SOM(4, 4, epochs=1, backend="numpy").fit(X + np.arange(9, dtype=np.float32))
    with pytest.raises(ValueError, match="X has 8 features, the map was fitted with 9"):
        som.predict(np.zeros((3, 8), np.float32))


def test_codebook_round_trip(tmp_path):
    from meshsom.codebook import load_codebook, save_codebook
    from meshsom.errors import StoreError
    from meshsom.store import create_store

    group = create_store(tmp_path / "s.zarr")
    rng = np.random.default_rng(0)
    W = rng.normal(size=(12, 9)).astype(np.float32)
    X = rng.normal(size=(20, 9)).astype(np.float32)
    bmu = bmu_numpy(X, W)
    save_codebook(group, "level1-default", W, 3, 4, "toroidal", level=1, kernel="default",
                  metrics={"t_error": 0.25, "q_error": 1.5}, bmu=bmu, extra={"epochs": 3})
    cb = load_codebook(zarr.open_group(str(tmp_path / "s.zarr"), mode="r"), "level1-default")
    np.testing.assert_array_equal(cb.weights, W)
    assert (cb.rows, cb.cols, cb.topology, cb.level, cb.kernel) == (3, 4, "toroidal", 1, "default")
    assert cb.metrics == {"t_error": 0.25, "q_error": 1.5} and cb.attrs["epochs"] == 3
    np.testing.assert_array_equal(cb.bmu.unit, bmu.unit)
    np.testing.assert_array_equal(cb.bmu.second, bmu.second)
    with pytest.raises(StoreError, match="has no run 'nope'"):
        load_codebook(group, "nope")


def test_train_command_json(tmp_path, capsys):
    """`meshsom train` end to end on a tiny encoded store, both kernels."""
    variations = pytest.importorskip("meshsom.variations")
    standardize = pytest.importorskip("meshsom.standardize")
    import json

    from pipelines.cli import main
    from meshsom.codebook import load_codebook
    from meshsom.store import create_store, open_store, write_rings, write_stats

    group = create_store(tmp_path / "s.zarr")
    index, _ = variations.variation_table(1)
    rng = np.random.default_rng(0)
    rings = np.concatenate([rng.uniform(0, np.pi, (150, 1)), rng.normal(size=(150, 2))], 1)
    rings = np.tile(rings, (1, index.shape[1] // 3)) + rng.normal(scale=0.1, size=(150, index.shape[1]))
    write_rings(group, 1, rings, chunk_rows=64)
    acc = standardize.accumulate(standardize.empty_accumulator(), rings)
    write_stats(group, 1, standardize.finalize(acc, level=1).to_dict())
    for kernel in ("default", "bmuofn"):
        rc = main(["train", str(tmp_path / "s.zarr"), "--level", "1", "--kernel", kernel, "--map", "5x6",
                   "--epochs", "3", "--seed", "1", "--backend", "numpy", "--json"])
        assert rc == 0
        report = json.loads(capsys.readouterr().out)
        for key in ("t_error", "q_error", "qc_error", "backend", "device", "level", "kernel", "map_rows",
                    "map_cols", "epochs", "seconds"):
            assert key in report
        assert report["backend"] == "numpy" and report["kernel"] == kernel
        cb = load_codebook(open_store(tmp_path / "s.zarr"), f"level1-{kernel}")
        assert cb.weights.shape == (30, index.shape[1]) and cb.metrics["q_error"] == pytest.approx(report["q_error"])
        assert len(cb.bmu.unit) == 150
