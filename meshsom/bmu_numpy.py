"""Best-matching units of n variations (BMUofN), NumPy/BLAS reference.

A *variation* of a vector ``x`` is a signed gather ``sign[v] * x[index[v]]``
(row 0 of the table is usually the identity; the default kernel uses it alone).
For every vector and every variation the unit minimising the squared Euclidean
distance to the varied vector is found through the expansion
``||x_v||^2 - 2 x_v . W^T + ||W||^2``, chunked over rows so that at most
``chunk_rows x M`` distances exist at any time (never ``N x M x n``).

Ties (DESIGN.md §4): the lowest unit, then the lowest variation (a later variation
replaces the winner when strictly closer, or equally close at a lower unit); the winners of the
variations are compared by their distances computed directly in float64 (:func:`exact_dist2`). A BLAS need not
give equal columns of ``X @ W.T`` equal bits (OpenBLAS's blocked kernels round a column by
where it falls in a tile), so units with the same prototype, which a random initialisation
draws from repeated rows, are resolved by their identity, not their rounding
(:func:`duplicate_units`): the lowest of them wins and the next lowest is second.

This module is the reference that :mod:`meshsom.bmu_opencl` is tested against.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: Rows of ``X`` handled per chunk: bounds the distance block to chunk_rows x M (128 x 18,000
#: float32 = 9 MB; 64-256 rows measured about 25 % faster than 512 on the paper's map).
DEFAULT_CHUNK_ROWS = 128


@dataclass(frozen=True)
class BMUResult:
    """The answer of a BMUofN search.

    Attributes
    ----------
    unit : (N,) int64
        Best-matching unit of the winning variation.
    variation : (N,) int64
        Winning variation (row of the variation table).
    dist2 : (N,) float64
        Squared distance ``||sign[v] * x[index[v]] - W[unit]||^2``, recomputed
        directly (not by the expansion) for the winner.
    second : (N,) int64
        Second-best unit of the winning variation (may be equidistant with ``unit``).
    """

    unit: np.ndarray
    variation: np.ndarray
    dist2: np.ndarray
    second: np.ndarray

    def __len__(self) -> int:
        return len(self.unit)

    def rows(self, start: int, stop: int) -> "BMUResult":
        """The results of rows ``start..stop`` (views)."""
        return type(self)(self.unit[start:stop], self.variation[start:stop], self.dist2[start:stop],
                          self.second[start:stop])

    @classmethod
    def concatenate(cls, parts) -> "BMUResult":
        """The results of consecutive row blocks as one."""
        parts = list(parts)
        return cls(*(np.concatenate([getattr(p, f) for p in parts]) for f in ("unit", "variation", "dist2", "second")))


def identity_table(D: int) -> tuple[np.ndarray, np.ndarray]:
    """The one-row variation table of the default kernel.

    Returns
    -------
    index : (1, D) int64
    sign : (1, D) float32
    """
    return np.arange(D, dtype=np.int64)[None, :], np.ones((1, D), np.float32)


def validate(X, W, index=None, sign=None) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Check and normalise the inputs of a BMU search (shared by every backend).

    Parameters
    ----------
    X : (N, D) float
    W : (M, D) float
    index : (n, D) int or None
        None: the identity (one variation).
    sign : (n, D) float or None
        None: all ones.

    Returns
    -------
    X, W : float32 arrays, or float64 when either input is float64
    index : (n, D) int64
    sign : (n, D) same dtype as X

    Raises
    ------
    TypeError, ValueError
        Wrong dtypes, shapes, or indices outside ``0..D-1``.
    """
    X = np.asarray(X)
    W = np.asarray(W)
    for name, a in (("X", X), ("W", W)):
        if a.ndim != 2:
            raise ValueError(f"{name} must be a 2-D array, received shape {a.shape}")
        if not (np.issubdtype(a.dtype, np.floating) or np.issubdtype(a.dtype, np.integer)):
            raise TypeError(f"{name} must hold real numbers, received dtype {a.dtype}")
    if X.shape[1] != W.shape[1]:
        raise ValueError(f"X has {X.shape[1]} columns but W has {W.shape[1]}; expected the same dimension D")
    if W.shape[0] < 2:
        raise ValueError(f"W must hold at least 2 units (for the second-best unit), received {W.shape[0]}")
    dtype = np.float64 if np.float64 in (X.dtype, W.dtype) else np.float32
    D = X.shape[1]
    if index is None:
        index, default_sign = identity_table(D)
        sign = default_sign if sign is None else sign
    index = np.asarray(index)
    if sign is None:
        sign = np.ones(index.shape, dtype)
    sign = np.asarray(sign)
    if index.ndim != 2 or index.shape[1] != D:
        raise ValueError(f"index must have shape (n, {D}), received {index.shape}")
    if sign.shape != index.shape:
        raise ValueError(f"sign must have the shape of index {index.shape}, received {sign.shape}")
    if not np.issubdtype(index.dtype, np.integer):
        raise TypeError(f"index must be integer, received dtype {index.dtype}")
    if index.shape[0] < 1:
        raise ValueError("index must hold at least one variation, received 0 rows")
    if index.size and (index.min() < 0 or index.max() >= D):
        raise ValueError(f"index values must lie in 0..{D - 1}, received {index.min()}..{index.max()}")
    return (
        np.ascontiguousarray(X, dtype),
        np.ascontiguousarray(W, dtype),
        np.ascontiguousarray(index, np.int64),
        np.ascontiguousarray(sign, dtype),
    )


def is_identity(index: np.ndarray, sign: np.ndarray, v: int = 0) -> bool:
    """Whether variation ``v`` of the table leaves vectors unchanged (index 0..D-1, all signs +1)."""
    return bool(np.array_equal(index[v], np.arange(index.shape[1])) and np.all(sign[v] == 1))


def varied(X: np.ndarray, index: np.ndarray, sign: np.ndarray, variation) -> np.ndarray:
    """The varied vectors ``sign[v] * X[i, index[v]]`` for one variation per row.

    Gathers the rows of each variation together and permutes their columns with one ``take``
    (an (N, D) fancy index of int64 would cost more than the search at a million rows).

    Parameters
    ----------
    X : (N, D) float
    index : (n, D) int64
    sign : (n, D) float
    variation : (N,) int or int
        Variation of each row, or one for all.

    Returns
    -------
    (N, D) float, dtype of X
    """
    X = np.asarray(X)
    if len(index) == 1 and is_identity(index, sign):
        return X  # the default kernel: no gather
    if np.ndim(variation) == 0:
        v = int(variation)
        return (np.take(X, index[v], axis=1) * sign[v]).astype(X.dtype, copy=False)
    variation = np.asarray(variation, np.int64)
    if len(variation) != len(X):
        raise ValueError(f"variation must hold one entry per row of X ({len(X)}), received {len(variation)}")
    out = np.empty_like(X)
    for v in range(len(index)):
        rows = np.flatnonzero(variation == v)
        if len(rows) == len(X):
            out[:] = np.take(X, index[v], axis=1) * sign[v]
        elif len(rows):
            out[rows] = np.take(X[rows], index[v], axis=1) * sign[v]
    return out


def unit_order(unit: np.ndarray, M: int, blocks=None) -> tuple[np.ndarray, np.ndarray]:
    """Rows grouped by (block, unit), in row order within a group (a stable counting order).

    Parameters
    ----------
    unit : (N,) int
        Units in 0..M-1.
    M : int
    blocks : list of (start, stop) or None
        Consecutive row ranges covering 0..N (:func:`meshsom.som.row_blocks`); None: one block.

    Returns
    -------
    order : (N,) int64
        Row numbers, block after block, sorted by unit within a block, ascending within a unit.
    offsets : (B * M + 1,) int64
        Rows of unit u in block b are ``order[offsets[b * M + u]:offsets[b * M + u + 1]]``.
    """
    unit = np.asarray(unit)
    blocks = [(0, len(unit))] if blocks is None else blocks
    orders, counts = [], []
    for a, b in blocks:
        part = unit[a:b]
        key = part.astype(np.uint16) if M <= 1 << 16 else part  # 16-bit keys: NumPy sorts stably by radix
        orders.append(np.argsort(key, kind="stable") + a)
        counts.append(np.bincount(part, minlength=M))
    offsets = np.zeros(len(blocks) * M + 1, np.int64)
    if blocks:
        np.cumsum(np.concatenate(counts), out=offsets[1:])
    order = np.concatenate(orders) if orders else np.zeros(0, np.int64)
    if len(order) != len(unit):
        raise ValueError(f"blocks must cover the {len(unit)} rows once, received {blocks[:3]}...")
    return order, offsets


def unit_sums(X, unit, variation, index, sign, M: int, blocks=None, init=None) -> tuple[np.ndarray, np.ndarray]:
    """Per unit, the sum of the varied vectors it won, and how many it won: the reference of the
    OpenCL ``unit_sums`` kernel (``kernels/epoch_sums.cl``), which gives the same bits.

    Each block's sum is taken in float64 from 0, adding one vector after another in row order (a
    sparse (M, N) one-hot matrix in :func:`unit_order`'s order times the varied vectors: SciPy's
    CSR product adds each row's entries in that order); the blocks' sums are then added in block
    order to ``init``, as an epoch reduces row blocks (:func:`meshsom.som.add_sums`).

    Parameters
    ----------
    X : (N, D) float
    unit, variation : (N,) int
        The winners (:class:`BMUResult`).
    index : (n, D) int64
    sign : (n, D) float
        The variation table the winners were found with.
    M : int
        Units.
    blocks : list of (start, stop) or None
        Consecutive row ranges covering 0..N; None: one block.
    init : (M, D) float64 or None
        The running sums of earlier rows to add to (None: zeros); counts start from 0.

    Returns
    -------
    sums : (M, D) float64
    counts : (M,) float64
    """
    from scipy.sparse import csr_matrix

    X = np.asarray(X)
    N, D = X.shape
    unit, variation = np.asarray(unit), np.asarray(variation)
    sums = np.zeros((M, D)) if init is None else np.array(init, np.float64)
    counts = np.zeros(M)
    for a, b in [(0, N)] if blocks is None else blocks:
        order, offsets = unit_order(unit[a:b], M)
        counts += np.diff(offsets)
        if b > a:
            xv = varied(X[a:b], np.asarray(index, np.int64), np.asarray(sign, X.dtype), variation[a:b])
            one_hot = csr_matrix((np.ones(b - a), order, offsets), shape=(M, b - a))
            sums += one_hot @ xv.astype(np.float64, copy=False)
    return sums, counts


#: Rows per block of :func:`exact_dist2` (bounds its float64 temporaries to this many rows x D).
EXACT_BLOCK = 16384


def exact_dist2(X, W, index, sign, unit, variation) -> np.ndarray:
    """Squared distance of each varied vector to its unit, computed directly in float64
    (:data:`EXACT_BLOCK` rows at a time).

    Returns
    -------
    (N,) float64
    """
    out = np.empty(len(X))
    for a in range(0, len(X), EXACT_BLOCK):
        b = min(len(X), a + EXACT_BLOCK)
        diff = varied(X[a:b], index, sign, variation[a:b]).astype(np.float64) - W[unit[a:b]].astype(np.float64)
        out[a:b] = np.einsum("ij,ij->i", diff, diff)
    return out


def fma_norms(W: np.ndarray) -> np.ndarray:
    """Squared norms of the codebook's rows as the kernels take a row's dot products: one
    accumulator, ``fma(w[k], w[k], acc)`` for k = 0..D-1, rounded to float32 at every step.

    A varied vector equal to a prototype then has distance ``wn - 2 acc + ||x_v||^2`` exactly 0 in
    every variation (the three sums are the same chain), so equal prototypes reached by several
    variations tie exactly and the tie rule, not rounding, picks the winner. :func:`bmu_numpy`
    takes the same norms, so that the two searches differ only in the order of the dot products'
    sums. float32 products are exact in float64, so each step is
    the float32 fma but for a double rounding (about one step in 2^29). float64 codebooks: NumPy's
    sums.

    Parameters
    ----------
    W : (M, D) float32 or float64

    Returns
    -------
    (M,) W.dtype
    """
    if W.dtype != np.float32:
        return np.einsum("ij,ij->i", W, W)
    wide = W.astype(np.float64)
    acc = np.zeros(len(W), np.float32)
    for k in range(W.shape[1]):
        acc = (acc + wide[:, k] * wide[:, k]).astype(np.float32)
    return acc


def duplicate_units(W: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """Units whose prototypes are equal bit for bit, resolved as the tie rule asks.

    Parameters
    ----------
    W : (M, D) float
        Codebook.

    Returns
    -------
    (first, next) or None
        ``first`` (M,) int64: the lowest unit with the same prototype as each unit (itself where
        unique); ``next`` (M,) int64: the second lowest such unit, -1 where the prototype is
        unique. None where every prototype is unique.
    """
    rows = np.ascontiguousarray(W).view(np.dtype((np.void, W.dtype.itemsize * W.shape[1]))).ravel()
    _, group, counts = np.unique(rows, return_inverse=True, return_counts=True)
    if len(counts) == len(W):
        return None
    group = group.ravel()
    order = np.lexsort((np.arange(len(W)), group))  # units by prototype, lowest unit first
    starts = np.concatenate(([0], np.cumsum(counts)[:-1]))
    lowest = order[starts]
    second = np.where(counts > 1, order[np.minimum(starts + 1, len(W) - 1)], -1)
    return lowest[group].astype(np.int64), second[group].astype(np.int64)


def bmu_numpy(X, W, index=None, sign=None, chunk_rows: int = DEFAULT_CHUNK_ROWS) -> BMUResult:
    """BMUofN by BLAS distance expansion, chunked over rows.

    Parameters
    ----------
    X : (N, D) float32 or float64
        Data vectors.
    W : (M, D) float32 or float64
        Codebook (M >= 2).
    index : (n, D) int64 or None
        Variation gathers; None: the identity only.
    sign : (n, D) float32 or None
        Variation signs; None: all +1.
    chunk_rows : int
        Rows per chunk; the working memory is about ``chunk_rows * M`` distances.

    Returns
    -------
    BMUResult
    """
    if chunk_rows < 1:
        raise ValueError(f"chunk_rows must be >= 1, received {chunk_rows}")
    X, W, index, sign = validate(X, W, index, sign)
    N = len(X)
    n = len(index)
    wnorm = fma_norms(W)
    Wt2 = np.ascontiguousarray((-2 * W).T)  # exact scaling: -2 is a power of two
    unit = np.zeros(N, np.int64)
    variation = np.zeros(N, np.int64)
    second = np.zeros(N, np.int64)
    dist2 = np.zeros(N)
    identity = [is_identity(index, sign, v) for v in range(n)]
    duplicates = duplicate_units(W)
    for start in range(0, N, chunk_rows):
        stop = min(N, start + chunk_rows)
        rows = np.arange(stop - start)
        xc = X[start:stop]
        best_d = np.full(stop - start, np.inf)
        best_u = np.zeros(stop - start, np.int64)
        best_v = np.zeros(stop - start, np.int64)
        best_s = np.zeros(stop - start, np.int64)
        for v in range(n):
            xv = xc if identity[v] else sign[v] * xc[:, index[v]]
            g = xv @ Wt2
            g += wnorm
            u = np.argmin(g, axis=1)
            g[rows, u] = np.inf
            s = np.argmin(g, axis=1)
            if duplicates is not None:  # equal prototypes: by identity, not by BLAS rounding
                first, following = duplicates
                s = np.where(following[u] >= 0, following[u], first[s])
                u = first[u]
            # variations are ranked by their winners' direct distances: two variations that reach
            # equal prototypes (a symmetric triangle's) tie exactly, whatever the expansion rounded
            d = exact_dist2(xc, W, index, sign, u, np.full(len(u), v))
            better = (d < best_d) | ((d == best_d) & (u < best_u))
            best_d = np.where(better, d, best_d)
            best_u = np.where(better, u, best_u)
            best_v = np.where(better, v, best_v)
            best_s = np.where(better, s, best_s)
        unit[start:stop] = best_u
        variation[start:stop] = best_v
        second[start:stop] = best_s
        dist2[start:stop] = best_d  # the winners' direct distances, as exact_dist2 gives them
    return BMUResult(unit, variation, dist2, second)
