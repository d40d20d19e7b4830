"""Grid distances, T/Q/QC-errors and the U-matrix by hand; cross-check against MiniSom."""

from __future__ import annotations

import numpy as np
import pytest

from meshsom.bmu_numpy import BMUResult, bmu_numpy
from meshsom.metrics import are_neighbours, grid_distance, q_error, qc_error, t_error, u_matrix

ROWS, COLS = 4, 5  # unit j at (j // 5, j % 5)


@pytest.mark.parametrize(
    "a,b,torus,plane",
    [
        (0, 1, 1.0, 1.0),  # (0,0)-(0,1)
        (0, 4, 1.0, 4.0),  # (0,0)-(0,4): across the column wrap
        (0, 15, 1.0, 3.0),  # (0,0)-(3,0): across the row wrap
        (0, 19, np.sqrt(2), 5.0),  # (0,0)-(3,4): diagonal across both wraps
        (0, 12, np.sqrt(8), np.sqrt(8)),  # (0,0)-(2,2)
        (6, 13, np.sqrt(5), np.sqrt(5)),  # (1,1)-(2,3)
        (3, 3, 0.0, 0.0),
    ],
)
def test_grid_distance_by_hand(a, b, torus, plane):
    assert grid_distance(a, b, ROWS, COLS, "toroidal") == pytest.approx(torus)
    assert grid_distance(a, b, ROWS, COLS, "planar") == pytest.approx(plane)


def test_neighbourhoods_by_hand():
    assert are_neighbours(0, 19, ROWS, COLS, "toroidal", 8)
    assert not are_neighbours(0, 19, ROWS, COLS, "toroidal", 4)
    assert are_neighbours(0, 4, ROWS, COLS, "toroidal", 4)
    assert not are_neighbours(0, 4, ROWS, COLS, "planar", 8)
    assert not are_neighbours(7, 7, ROWS, COLS, "toroidal", 8)


def test_t_error_by_hand():
    unit = np.array([0, 0, 0, 6, 6, 2, 9, 10])
    second = np.array([1, 4, 19, 12, 13, 12, 5, 15])
    # torus, 8: 0-1 yes, 0-4 yes (wrap), 0-19 yes (wrap diag), 6-12 yes (diag), 6-13 no, 2-12 no, 9-5 yes, 10-15 yes
    assert t_error(unit, second, ROWS, COLS, "toroidal", 8) == pytest.approx(2 / 8)
    # torus, 4: additionally 0-19 and 6-12 (diagonals) and 9-5 ((1,4)-(1,0) wrap: rook step) ...
    assert t_error(unit, second, ROWS, COLS, "toroidal", 4) == pytest.approx(4 / 8)
    # planar, 8: 0-4, 0-19, 9-5 stop being neighbours
    assert t_error(unit, second, ROWS, COLS, "planar", 8) == pytest.approx(5 / 8)
    with pytest.raises(ValueError, match="neighbourhood must be one of"):
        t_error(unit, second, ROWS, COLS, "toroidal", 6)


def test_q_and_qc_error_by_hand():
    X = np.array([[3.0, 4, 0, 0, 0, 0], [0, 0, 0, 1, 0, 0]])
    W = np.zeros((2, 6))
    bmu = BMUResult(np.array([0, 1]), np.array([0, 0]), np.array([25.0, 1.0]), np.array([1, 0]))
    assert q_error(X, W, bmu) == pytest.approx((5 + 1) / 2)
    assert qc_error(X, W, bmu) == pytest.approx(((5 + 0) / 2 + (0 + 1) / 2) / 2)


def test_q_error_uses_winning_variation():
    index = np.array([[0, 1, 2], [2, 0, 1]])
    sign = np.array([[1, 1, 1], [-1, 1, 1]], np.float32)
    X = np.array([[1.0, 2.0, 3.0]])
    W = np.array([[-3.0, 1.0, 2.0], [9, 9, 9]])  # = variation 1 of x
    bmu = bmu_numpy(X, W, index, sign)
    assert bmu.variation[0] == 1 and bmu.unit[0] == 0
    assert q_error(X, W, bmu, index, sign) == pytest.approx(0.0)
    assert q_error(X, W, bmu) > 1  # without the table the raw vector is compared


def test_u_matrix_known_answer():
    W = np.zeros((9, 1))
    W[4] = 3.0  # 3 x 3 map, a bump in the centre
    torus = u_matrix(W, 3, 3, "toroidal", 8)
    expected = np.full((3, 3), 3 / 8)  # on a 3 x 3 torus everyone neighbours everyone
    expected[1, 1] = 3.0
    np.testing.assert_allclose(torus, expected)
    plane = u_matrix(W, 3, 3, "planar", 4)
    np.testing.assert_allclose(plane, [[0, 1, 0], [1, 3, 1], [0, 1, 0]])
    plane8 = u_matrix(W, 3, 3, "planar", 8)
    np.testing.assert_allclose(plane8, [[1, 3 / 5, 1], [3 / 5, 3, 3 / 5], [1, 3 / 5, 1]])


def test_u_matrix_png(tmp_path):
    from meshsom.umatrix import render_map

    rng = np.random.default_rng(0)
    W = rng.normal(size=(6 * 8, 3))
    for topology in ("toroidal", "planar"):
        path = render_map(W, 6, 8, tmp_path / f"{topology}.png", topology=topology, title="test")
        assert open(path, "rb").read(8) == b"\x89PNG\r\n\x1a\n"


def test_errors_match_minisom_on_planar_map():
    minisom = pytest.importorskip("minisom")
    rng = np.random.default_rng(3)
    rows, cols, D = 7, 9, 6
    X = rng.normal(size=(400, D))
    # a smooth-ish codebook: a trained-like gradient plus noise, so T-error is neither 0 nor 1
    grid = np.stack(np.meshgrid(np.linspace(-2, 2, rows), np.linspace(-2, 2, cols), indexing="ij"), -1)
    W = np.concatenate([grid, np.zeros((rows, cols, D - 2))], -1).reshape(rows * cols, D)
    W = W + rng.normal(scale=0.6, size=W.shape)
    som = minisom.MiniSom(rows, cols, D, topology="rectangular", random_seed=0)
    som._weights = W.reshape(rows, cols, D).copy()  # MiniSom indexes (x, y) row-major like us
    bmu = bmu_numpy(X, W)
    ours_t = t_error(bmu.unit, bmu.second, rows, cols, "planar", 8)
    assert 0.02 < ours_t < 0.98
    assert q_error(X, W, bmu) == pytest.approx(som.quantization_error(X), rel=1e-12)
    assert ours_t == pytest.approx(som.topographic_error(X), abs=1e-12)
    winners = np.array([np.ravel_multi_index(som.winner(x), (rows, cols)) for x in X[:50]])
    np.testing.assert_array_equal(bmu.unit[:50], winners)


# ---------------------------------------------------------------------- T-error tie rule
def _brute_force_t_bad(X, W, rows, cols, topology="toroidal"):
    """Independent reference: x is an error iff no unit tied for second place is a neighbour of
    the best unit (all distances in float64, the tie tolerance of the rule)."""
    from meshsom.metrics import TIE_RTOL

    X64, W64 = X.astype(np.float64), W.astype(np.float64)
    bad = []
    for x in X64:
        d = ((W64 - x) ** 2).sum(axis=1)
        best = int(np.argmin(d))
        rest = d.copy()
        rest[best] = np.inf
        second = int(np.argmin(rest))
        tol = TIE_RTOL * (x @ x + W64[second] @ W64[second])
        tied = np.flatnonzero(rest <= rest[second] + tol)
        bad.append(not any(are_neighbours(best, t, rows, cols, topology) for t in tied))
    return np.array(bad)


@pytest.mark.parametrize("topology", ["toroidal", "planar"])
def test_t_error_tie_rule_on_duplicated_prototypes(topology):
    from meshsom.bmu_numpy import bmu_numpy
    from meshsom.metrics import error_sums, errors_of, tied_with_neighbour

    rows, cols = 4, 4
    rng = np.random.default_rng(0)
    W = rng.normal(0, 1, (16, 6)).astype(np.float32) * 10
    p = rng.normal(0, 1, 6).astype(np.float32)
    # units 0 (0,0) and 10 (2,2) share a prototype, far apart; 5 (1,1) is a neighbour of 0 with the same
    # prototype up to float32 rounding; 12 and 13 share one, and are neighbours
    W[0] = W[10] = p
    W[5] = p * np.float32(1 + 2e-7)
    W[12] = W[13] = p + 3
    X = np.stack([p, p + 3, p + 0.01, W[7]]).astype(np.float32)
    bmu = bmu_numpy(X, W)
    assert {int(bmu.unit[0]), int(bmu.second[0])} <= {0, 5, 10}  # the search reports arbitrary tied units
    tied = tied_with_neighbour(X, W, bmu, rows, cols, topology)
    want = _brute_force_t_bad(X, W, rows, cols, topology)
    got = ~are_neighbours(bmu.unit, bmu.second, rows, cols, topology) & ~tied
    np.testing.assert_array_equal(got, want)
    assert not want[0]  # a neighbour (5) ties for second place: not a topographic error
    assert not want[1]  # 12 and 13 are equal neighbours
    assert t_error(bmu.unit, bmu.second, rows, cols, topology, tied=tied) == pytest.approx(want.mean())
    assert errors_of(error_sums(X, W, bmu, rows, cols, topology))["t_error"] == pytest.approx(want.mean())
    # without the near-duplicate neighbour, 0 and 10 are far apart duplicates: a real topographic error
    W2 = W.copy()
    W2[5] = p + 5
    bmu2 = bmu_numpy(X[:1], W2)
    assert bmu2.second[0] == 10
    assert errors_of(error_sums(X[:1], W2, bmu2, rows, cols, topology))["t_error"] == 1.0


def test_t_error_ties_on_a_map_of_identical_vectors():
    """Many identical vectors (extruded blocks): the plateau of equal prototypes is no topology error."""
    from meshsom.som import SOM

    rng = np.random.default_rng(0)
    base = rng.normal(size=(4, 9)).astype(np.float32)
    X = base[rng.integers(0, 4, 2000)]
    som = SOM(12, 15, epochs=8, sigma_end=0.8, init="pca", backend="numpy").fit(X)
    bmu = som.transform(X)
    naive = t_error(bmu.unit, bmu.second, 12, 15)
    want = _brute_force_t_bad(X, som.weights_, 12, 15).mean()
    assert som.evaluate(X)["t_error"] == pytest.approx(want)
    # the ties make a quarter of the vectors look like errors: the lowest of equal prototypes wins and
    # the next lowest, often not a neighbour, is second
    assert naive > 0.2 and want < 0.05
