"""Exact ties in BMUofN: equal prototypes, and equal prototypes reached by several variations.

DESIGN.md section 4: ties go to the lowest unit, then the lowest variation. A random
initialisation draws prototypes from the rows, and building meshes repeat triangles, so in the
first epoch many rows sit exactly on several equal prototypes. A BLAS does not give equal
columns of ``X @ W.T`` equal bits (OpenBLAS's Haswell kernels round a column by where it falls in
a tile), so the NumPy search must resolve those ties by identity; the kernels take ``||w||^2`` in
the chain of their dot products (``meshsom.bmu_numpy.fma_norms``, which the NumPy search takes too), so that a row equal to a
prototype is at distance exactly 0 in every variation. The expected answers here come from
the construction, not from either search.
"""

from __future__ import annotations

from fractions import Fraction

import numpy as np
import pytest

from meshsom.bmu_numpy import bmu_numpy, duplicate_units
from tests.test_bmu import KERNEL_PARAMS, _opencl_context

D = 144
M = 3000


def test_duplicate_units_name_the_lowest_and_the_next():
    W = np.arange(12, dtype=np.float32).reshape(6, 2)
    assert duplicate_units(W) is None
    W[4] = W[1]
    W[5] = W[1]
    W[3] = W[0]
    first, following = duplicate_units(W)
    np.testing.assert_array_equal(first, [0, 1, 2, 0, 1, 1])
    np.testing.assert_array_equal(following, [3, 4, -1, 3, 4, 4])


def case(seed: int = 7):
    """Random prototypes with groups of equal ones scattered over the codebook (lowest members known),
    rows equal to a group's prototype, and a second variation (a reversal) under which row 0 lands
    exactly on a lower unit than its identity does."""
    rng = np.random.default_rng(seed)
    W = rng.normal(size=(M, D)).astype(np.float32)
    groups = [np.sort(rng.choice(np.arange(10, M), size=s, replace=False)) for s in (2, 3, 5, 8)]
    for g in groups:
        W[g] = W[g[0]]
    X = np.stack([W[g[0]] for g in groups for _ in range(3)])
    index = np.stack([np.arange(D), np.arange(D)[::-1]]).astype(np.int64)
    sign = np.ones((2, D), np.float32)
    low = 3  # below every group: row 0 reversed equals it exactly
    W[low] = X[0][index[1]]
    want_unit = np.array([g[0] for g in groups for _ in range(3)])
    want_second = np.array([g[1] for g in groups for _ in range(3)])
    want_unit[:3], want_var = low, np.zeros(len(X), np.int64)
    want_var[:3] = 1
    return X, W, index, sign, want_unit, want_var, want_second


def assert_follows_tie_rule(result, want_unit, want_var, want_second):
    np.testing.assert_array_equal(result.unit, want_unit)
    np.testing.assert_array_equal(result.variation, want_var)
    np.testing.assert_array_equal(result.dist2, 0.0)
    # the second of a row that wins through its identity: the next member of its group
    identity = want_var == 0
    np.testing.assert_array_equal(np.asarray(result.second)[identity], want_second[identity])


@pytest.mark.parametrize("chunk_rows", [1, 5, 128])
def test_numpy_resolves_exact_ties_by_the_rule(chunk_rows):
    X, W, index, sign, unit, var, second = case()
    assert_follows_tie_rule(bmu_numpy(X, W, index, sign, chunk_rows=chunk_rows), unit, var, second)


@pytest.mark.parametrize("layout", list(KERNEL_PARAMS))
def test_every_kernel_layout_resolves_exact_ties_by_the_rule(layout):
    from meshsom.bmu_opencl import KernelParams, bmu_opencl

    context = _opencl_context()
    X, W, index, sign, unit, var, second = case()
    got = bmu_opencl(X, W, index, sign, context=context, params=KernelParams(**KERNEL_PARAMS[layout]))
    assert_follows_tie_rule(got, unit, var, second)


def round_to_float32(q: Fraction) -> np.float32:
    """The float32 nearest an exact rational (ties to even)."""
    c = np.float32(float(q))
    near = [np.nextafter(c, np.float32(-np.inf)), c, np.nextafter(c, np.float32(np.inf))]
    return min(near, key=lambda f: (abs(Fraction(float(f)) - q), int(np.float32(f).view(np.int32)) & 1))


def test_fma_norms_are_the_sequential_float32_fma_chain():
    from meshsom.bmu_numpy import fma_norms

    rng = np.random.default_rng(3)
    W = rng.normal(size=(50, 37)).astype(np.float32)
    want = np.zeros(50, np.float32)
    for k in range(37):  # one float32 fma per step: the exact value, rounded once
        want = np.array([round_to_float32(Fraction(float(a)) + Fraction(float(w)) ** 2)
                         for a, w in zip(want, W[:, k])], np.float32)
    np.testing.assert_array_equal(fma_norms(W), want)
    W64 = W.astype(np.float64)
    np.testing.assert_array_equal(fma_norms(W64), np.einsum("ij,ij->i", W64, W64))


def test_numpy_dist2_is_the_winners_direct_distance():
    """The distances the variations were ranked by are the ones returned: exact_dist2's bits."""
    from meshsom.bmu_numpy import exact_dist2

    rng = np.random.default_rng(5)
    X, W = rng.normal(size=(300, D)).astype(np.float32), rng.normal(size=(200, D)).astype(np.float32)
    index = np.stack([np.arange(D), np.arange(D)[::-1], np.roll(np.arange(D), 3)]).astype(np.int64)
    sign = np.ones((3, D), np.float32)
    got = bmu_numpy(X, W, index, sign, chunk_rows=64)
    np.testing.assert_array_equal(got.dist2, exact_dist2(X, W, index, sign, got.unit, got.variation))
