"""Domain vectors, clustering quality, the D2 baseline, thumbnails and the domain-map figure."""

from __future__ import annotations

import numpy as np
from sklearn.metrics import adjusted_rand_score
import pytest

from meshsom import domain
from meshsom.descriptors import d2_histogram
from meshsom.generate import GeneratorParams, generate_block
from meshsom.thumbnails import domain_map_figure, render_thumbnail
from conftest import box


def direct_blob(unit: int, rows: int, cols: int, sigma: float, toroidal: bool = True) -> np.ndarray:
    """``exp(-d^2 / (2 sigma^2))`` around ``unit`` over the whole grid, divided by its sum.

    This is how :func:`domain.domain_vectors` normalises: each unit's mass is spread by a
    kernel of total 1, so a one-unit histogram becomes this blob. Computed cell by cell,
    without any separable trick.
    """
    r0, c0 = divmod(unit, cols)
    out = np.empty(rows * cols)
    for j in range(rows * cols):
        r, c = divmod(j, cols)
        dr, dc = abs(r - r0), abs(c - c0)
        if toroidal:
            dr, dc = min(dr, rows - dr), min(dc, cols - dc)
        out[j] = np.exp(-(dr**2 + dc**2) / (2 * sigma**2))
    return out / out.sum()


# ---------------------------------------------------------------------- histograms and domain vectors
ROWS, COLS, SIGMA = 6, 8, 1.3
# mesh 0: 5 triangles, all on unit 7 (row 0, last column: its blob wraps over two edges)
# mesh 1: 4 triangles, 2 on unit 0 and 2 on unit 20
FACE_MESH = np.array([0, 1, 0, 0, 1, 0, 1, 0, 1])
UNITS = np.array([7, 0, 7, 7, 20, 7, 0, 7, 20])


def test_histograms_are_shares_summing_to_one():
    hist = domain.bmu_histograms(FACE_MESH, UNITS, 2, ROWS * COLS)
    assert hist.shape == (2, ROWS * COLS) and hist.dtype == np.float64
    np.testing.assert_allclose(hist.sum(axis=1), 1.0)
    assert hist[0, 7] == 1.0
    assert hist[1, 0] == hist[1, 20] == 0.5
    assert np.count_nonzero(hist) == 3


def test_one_unit_mesh_gives_a_wrapped_gaussian_blob():
    hist = domain.bmu_histograms(FACE_MESH, UNITS, 2, ROWS * COLS)
    vec = domain.domain_vectors(hist, ROWS, COLS, SIGMA)
    assert vec.shape == (2, ROWS * COLS) and vec.dtype == np.float32
    expected = direct_blob(7, ROWS, COLS, SIGMA)
    np.testing.assert_allclose(vec[0], expected, rtol=1e-5, atol=1e-7)
    grid = vec[0].reshape(ROWS, COLS)
    assert np.argmax(vec[0]) == 7
    # across the torus edges: row 5 touches row 0, column 0 touches column 7
    assert grid[ROWS - 1, 7] == pytest.approx(grid[1, 7])
    assert grid[0, 0] == pytest.approx(grid[0, 6])
    assert grid[ROWS - 1, 0] == pytest.approx(grid[1, 6])
    assert grid[0, 0] > 10 * grid[3, 3]
    # linear in the histogram; mass conserved
    np.testing.assert_allclose(vec[1], 0.5 * direct_blob(0, ROWS, COLS, SIGMA) + 0.5 * direct_blob(20, ROWS, COLS, SIGMA),
                               rtol=1e-5, atol=1e-7)
    np.testing.assert_allclose(vec.sum(axis=1), 1.0, rtol=1e-5)


def test_planar_smoothing_does_not_wrap_and_keeps_mass():
    hist = domain.bmu_histograms(FACE_MESH, UNITS, 2, ROWS * COLS)
    vec = domain.domain_vectors(hist, ROWS, COLS, SIGMA, topology="planar")
    np.testing.assert_allclose(vec[0], direct_blob(7, ROWS, COLS, SIGMA, toroidal=False), rtol=1e-5, atol=1e-7)
    assert vec[0].reshape(ROWS, COLS)[0, 0] < 1e-3
    np.testing.assert_allclose(vec.sum(axis=1), 1.0, rtol=1e-5)


def test_histogram_and_vector_errors_say_what_was_received():
    with pytest.raises(ValueError, match=r"meshes \[1\] have none"):
        domain.bmu_histograms([0, 0, 2], [1, 2, 3], 3, 4)
    with pytest.raises(ValueError, match=r"units\[1\] = 9 lies outside 0..3"):
        domain.bmu_histograms([0, 0], [1, 9], 1, 4)
    with pytest.raises(ValueError, match="same length"):
        domain.bmu_histograms([0, 0], [1], 1, 4)
    with pytest.raises(ValueError, match=r"shape \(n_meshes, 48\)"):
        domain.domain_vectors(np.ones((2, 47)), ROWS, COLS, SIGMA)
    with pytest.raises(ValueError, match="topology must be one of"):
        domain.domain_vectors(np.ones((2, 48)), ROWS, COLS, SIGMA, topology="hex")


# ---------------------------------------------------------------------- clustering quality
def test_knn_agreement_on_a_hand_made_4x4_map():
    # m0 at (0, 0) and m1 at (0, 3) are torus neighbours (label a); m2 at (2, 2), m3 at (1, 1) (label b).
    units = np.array([0, 3, 10, 5])
    labels = np.array(["a", "a", "b", "b"])
    # k=1 torus: m0 -> m1 (1), m1 -> m0 (1), m2 -> m3 (sqrt 2), m3 -> tie m0/m2 at sqrt 2, lower index m0 (a): 3/4
    assert domain.knn_label_agreement(units, labels, 4, 4, k=1) == pytest.approx(0.75)
    # planar: m0 -> m3, m1 -> tie m2/m3 (sqrt 5) -> m2, m2 -> m3, m3 -> m0: only m2 agrees
    assert domain.knn_label_agreement(units, labels, 4, 4, k=1, topology="planar") == pytest.approx(0.25)
    # k=2 torus: {m1, m3}, {m0, m2 (tie with m3 at sqrt 5)}, {m3, m1}, {m0, m2}: each 1/2
    assert domain.knn_label_agreement(units, labels, 4, 4, k=2) == pytest.approx(0.5)
    with pytest.raises(ValueError, match="k must lie in 1..3"):
        domain.knn_label_agreement(units, labels, 4, 4, k=4)
    assert domain.label_agreement_chance(labels) == pytest.approx(1 / 3)


def test_map_regions_recover_separated_prototypes():
    rows, cols = 4, 6
    col = np.arange(rows * cols) % cols
    truth = (col >= 3).astype(int)
    W = np.where(truth[:, None] == 1, 10.0, 0.0) + np.random.default_rng(1).normal(0, 0.1, (rows * cols, 5))
    regions = domain.map_regions(W, rows, cols, 2, seed=0)
    assert regions.shape == (rows * cols,)
    assert adjusted_rand_score(regions, truth) == 1.0
    np.testing.assert_array_equal(regions, domain.map_regions(W, rows, cols, 2, seed=0))
    with pytest.raises(ValueError, match=r"shape \(24, D\)"):
        domain.map_regions(W[:-1], rows, cols, 2, seed=0)


# ---------------------------------------------------------------------- D2 baseline
def test_d2_is_scale_invariant_and_shape_sensitive():
    v, f = box()
    h = d2_histogram(v, f, seed=3)
    assert h.shape == (64,) and h.dtype == np.float64
    assert h.sum() == pytest.approx(1.0)
    np.testing.assert_allclose(d2_histogram(v * 10.0 + 5.0, f, seed=3), h, atol=2 / 4096)
    np.testing.assert_array_equal(d2_histogram(v, f, seed=3), h)
    assert np.abs(d2_histogram(v, f, seed=4) - h).sum() > 0  # a different sample
    lv, lf = box(1.0, 1.0, 8.0)
    assert np.abs(d2_histogram(lv, lf, seed=3) - h).sum() > 0.5


def test_d2_domain_map_groups_families_above_chance():
    # 30 blocks of these families sit at chance (~0.36 vs 0.31): D2 is dominated by the
    # blocks' proportions, and 10 per family is too sparse; 300 blocks separate them.
    params = GeneratorParams(n_blocks=300, seed=0, families=("rectangle", "L", "courtyard"))
    blocks = [generate_block(params, i) for i in range(params.n_blocks)]
    labels = np.array([b.label for b in blocks])
    X = np.stack([d2_histogram(b.vertices, b.faces, n_pairs=4096, bins=64, seed=0) for b in blocks])
    som = domain.train_domain_map(X, 10, 10, epochs=30, seed=0)
    units = domain.place(X, som)
    assert units.shape == (300,) and units.max() < 100
    agreement = domain.knn_label_agreement(units, labels, 10, 10, k=5)
    chance = domain.label_agreement_chance(labels)
    rng = np.random.default_rng(0)
    null = [domain.knn_label_agreement(units, rng.permutation(labels), 10, 10, k=5) for _ in range(20)]
    assert agreement > chance + 0.1
    assert agreement > max(null) + 0.08
    regions = domain.map_regions(som.weights_, 10, 10, 3, seed=0)[units]
    assert -0.1 < adjusted_rand_score(regions, labels) <= 1.0


# ---------------------------------------------------------------------- thumbnails and figure
def test_thumbnail_is_rgba_shaded_and_not_blank():
    v, f = box(2.0, 1.0, 1.5)
    img = render_thumbnail(v, f, size=48)
    assert img.shape == (48, 48, 4) and img.dtype == np.uint8
    opaque = img[..., 3] > 0
    assert 0.05 < opaque.mean() < 0.95  # the mesh covers part of a transparent background
    grey = img[..., :3][opaque].mean(axis=1)
    assert grey.max() - grey.min() > 40  # faces facing the light differ from the others


def test_domain_map_figure_is_written(tmp_path):
    v, f = box()
    lv, lf = box(1.0, 1.0, 3.0)
    thumbs = [render_thumbnail(v, f, size=32), render_thumbnail(lv, lf, size=32)] * 3
    units = np.array([0, 0, 0, 5, 11, 11])  # three meshes share unit 0: a mosaic
    path = domain_map_figure(units, thumbs, 3, 4, tmp_path / "fig9.png", title="test",
                             labels=["cube", "tall", "cube", "tall", "cube", "tall"])
    data = (tmp_path / "fig9.png").read_bytes()
    assert path == str(tmp_path / "fig9.png")
    assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 2000
    with pytest.raises(ValueError, match=r"one thumbnail per mesh \(6\), received 5"):
        domain_map_figure(units, thumbs[:5], 3, 4, tmp_path / "bad.png")


def _random_bmus(rng, n_meshes, rows, cols, per_mesh=(1, 30)):
    sizes = rng.integers(per_mesh[0], per_mesh[1] + 1, n_meshes)
    face_mesh = np.repeat(np.arange(n_meshes), sizes)
    # clustered units: each mesh around a random centre, so meshes share units
    centre = rng.integers(0, rows * cols, n_meshes)[face_mesh]
    units = (centre + rng.integers(-3, 4, len(face_mesh)) * cols + rng.integers(-2, 3, len(face_mesh))) % (rows * cols)
    return face_mesh, units


@pytest.mark.parametrize("topology", ["toroidal", "planar"])
def test_sparse_domain_vectors_equal_the_dense_ones(topology):
    """Every product the sparse form gives equals the same product on domain_vectors' dense rows."""
    rng = np.random.default_rng(3)
    rows, cols, n = 9, 11, 60
    face_mesh, units = _random_bmus(rng, n, rows, cols)
    dense = domain.domain_vectors(domain.bmu_histograms(face_mesh, units, n, rows * cols), rows, cols, 1.5, topology)
    sv = domain.SparseDomainVectors(face_mesh, units, n, rows, cols, 1.5, topology)
    V = sv.dense()
    np.testing.assert_allclose(V, dense, rtol=1e-6, atol=1e-9)  # dense is float32
    np.testing.assert_allclose(sv.sq_norms(), (V**2).sum(axis=1), rtol=1e-12)
    W = rng.random((7, rows * cols))
    np.testing.assert_allclose(sv.dot(W), V @ W.T, rtol=1e-12)
    win = rng.integers(0, 7, n)
    expect = np.zeros((7, rows * cols))
    np.add.at(expect, win, V)
    np.testing.assert_allclose(sv.group_sums(win, 7), expect, rtol=1e-12, atol=1e-15)
    # small pair chunks (one mesh or a few per chunk) and the dense route for meshes with many
    # non-zeros give the same norms
    for limit in (1, 30, 100, 400):
        old = domain.PAIRS_PER_CHUNK
        try:
            domain.PAIRS_PER_CHUNK = limit
            np.testing.assert_allclose(sv.sq_norms(), (V**2).sum(axis=1), rtol=1e-12)
        finally:
            domain.PAIRS_PER_CHUNK = old


@pytest.mark.parametrize("init, exact_dims", [("random", 4096), ("pca", 4096), ("pca", 100), ("pca", 10)])
def test_sparse_domain_map_equals_the_dense_som(monkeypatch, init, exact_dims):
    """In-memory and streamed domain maps start from the same initialisation and agree, with each
    PCA solver (covariance: 180 dims <= 4096; Gram of 300 rows: dims > 100; Lanczos: both > 10)."""
    from meshsom import som as som_module
    from meshsom.som import SOM, init_weights, pca_codebook

    monkeypatch.setattr(som_module, "PCA_EXACT_DIMS", exact_dims)
    rng = np.random.default_rng(4)
    rows, cols, n = 12, 15, 300
    face_mesh, units = _random_bmus(rng, n, rows, cols)
    vectors = domain.domain_vectors(domain.bmu_histograms(face_mesh, units, n, rows * cols), rows, cols, 2.0)
    sv = domain.SparseDomainVectors(face_mesh, units, n, rows, cols, 2.0)
    start = init_weights(vectors, 5, 6, init, seed=2)
    if init == "pca":
        np.testing.assert_allclose(pca_codebook(*sv.pca(), 5, 6), start, rtol=1e-5, atol=1e-8)
        monkeypatch.setattr(som_module, "PCA_EXACT_DIMS", 4096)  # the reference: the covariance solver
        np.testing.assert_allclose(init_weights(vectors, 5, 6, init, seed=2), start, rtol=1e-5, atol=1e-8)
        monkeypatch.setattr(som_module, "PCA_EXACT_DIMS", exact_dims)
    got = domain.train_domain_map_sparse(sv, 5, 6, epochs=8, seed=2, init=init)
    som = SOM(rows=5, cols=6, epochs=8, sigma_end=1.0, init=init, random_state=2, backend="numpy").fit(vectors)
    np.testing.assert_allclose(got["weights"], som.weights_, atol=1e-6)
    assert (got["units"] == som.predict(vectors)).mean() > 0.98
    ev = som.evaluate(vectors)
    assert got["q_error"] == pytest.approx(ev["q_error"], rel=1e-4)
    assert got["t_error"] == pytest.approx(ev["t_error"], abs=0.01)


def test_sparse_domain_vectors_errors_name_the_problem():
    with pytest.raises(ValueError, match="units\\[1\\] = 99 lies outside 0..19"):
        domain.SparseDomainVectors([0, 0], [1, 99], 1, 4, 5, 1.0)
    with pytest.raises(ValueError, match="meshes \\[1\\] have none"):
        domain.SparseDomainVectors([0, 0], [1, 2], 2, 4, 5, 1.0)
    with pytest.raises(ValueError, match="sigma must be > 0"):
        domain.SparseDomainVectors([0], [1], 1, 4, 5, 0.0)
