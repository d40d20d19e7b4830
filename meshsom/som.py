"""Self-organizing map on a toroidal (or planar) rectangular grid, with BMUofN.

The estimator follows scikit-learn conventions: parameters in the constructor, ``fit``
returns ``self``, learned attributes end in ``_``. Batch training (the default) is built
from pure functions so that a distributed pipeline can map-reduce an epoch:

1. :func:`partial_sums` on each row chunk: BMUs (with the winning variation), per-unit sums
   of the *varied* vectors and per-unit counts;
2. add the chunks' sums and counts;
3. :func:`batch_update`: smooth sums and counts with the Gaussian neighbourhood of radius
   :func:`sigma_schedule` on the grid (separable: one rows x rows and one cols x cols
   kernel, wrapped on a torus), divide; units with (numerically) zero smoothed count keep
   their prototype.

The update costs ``O(M * D * (rows + cols))`` per epoch, independent of N; the only
``O(N * M * D)`` work is the BMU search.

One driver, :func:`train_batch`, runs every batch map of the project: it owns the radius
schedule, the update and the epoch callbacks, and takes the epoch's map step as a function
``step(W) -> sums`` (:func:`block_sums` added over blocks). :class:`SOM` passes an in-memory step,
:mod:`pipelines.train` a Dask fan-out over zarr row blocks (checkpointing in a callback), and
:func:`meshsom.domain.train_domain_map_sparse` the search over sparse domain vectors. Rows are
always reduced in the same blocks (:func:`row_blocks`) and in block order, so a map trained in
memory and one trained on a cluster are bitwise equal. Initialisation is shared the same way:
:func:`random_pick` draws the seeded sample rows, :func:`pca_codebook` spans the first two
principal axes, with one sign rule, whether the moments come from memory, from zarr blocks or
from sparse domain vectors.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Callable, Iterable

import numpy as np

from meshsom.bmu import UPDATES, find_bmus, resolve_backend
from meshsom.bmu_numpy import BMUResult, identity_table
from meshsom.metrics import TOPOLOGIES, error_sums, errors_of

INITS = ("random", "pca")
TRAININGS = ("batch", "online")
DECAYS = ("exponential", "linear")
#: Rows per block of a batch epoch: the unit of work of a cluster task and of the order in which
#: per-unit sums are added (the same everywhere, so that every entry point gives the same codebook).
BLOCK_ROWS = 16384
#: PCA solves the D x D covariance when D is at most this, else the n x n Gram matrix of the
#: centred rows when n is at most this, else the first axes by Lanczos iteration (same axes).
PCA_EXACT_DIMS = 4096
#: The first radius, in cells, when none is given: this share of the longer map side.
SIGMA_START_SHARE = 0.25


def default_sigma_start(rows: int, cols: int) -> float:
    """The radius of the first epoch when none is configured: ``max(rows, cols) / 4`` cells."""
    return float(max(rows, cols) * SIGMA_START_SHARE)


def row_blocks(n: int, block_rows: int = BLOCK_ROWS) -> list[tuple[int, int]]:
    """Row ranges ``[(start, stop), ...]`` of the blocks an epoch reduces, in order.

    Parameters
    ----------
    n : int
        Rows.
    block_rows : int
        Rows per block (the last block may be shorter).
    """
    if block_rows < 1:
        raise ValueError(f"block_rows must be >= 1, received {block_rows}")
    return [(a, min(n, a + block_rows)) for a in range(0, n, block_rows)]


def sigma_schedule(epoch: int, epochs: int, sigma_start: float, sigma_end: float,
                   decay: str = "exponential") -> float:
    """Neighbourhood radius (in cells) of an epoch.

    ``exponential``: ``sigma_start * (sigma_end / sigma_start) ** t``; ``linear``:
    ``sigma_start + (sigma_end - sigma_start) * t``, with ``t = epoch / (epochs - 1)``
    (``t = 0`` when there is one epoch), so the first epoch uses ``sigma_start`` and the
    last ``sigma_end``. The same function schedules the online learning rate.

    Parameters
    ----------
    epoch : int
        0-based, ``0 <= epoch < epochs``.
    """
    if decay not in DECAYS:
        raise ValueError(f"decay must be one of {', '.join(DECAYS)}; received {decay!r}")
    if not 0 <= epoch < max(epochs, 1):
        raise ValueError(f"epoch must lie in 0..{epochs - 1}, received {epoch}")
    t = epoch / (epochs - 1) if epochs > 1 else 0.0
    if decay == "exponential":
        return float(sigma_start * (sigma_end / sigma_start) ** t)
    return float(sigma_start + (sigma_end - sigma_start) * t)


def gaussian_kernel_1d(length: int, sigma: float, topology: str = "toroidal") -> np.ndarray:
    """Gaussian weights between the cells of one grid axis.

    Returns
    -------
    (length, length) float64
        ``exp(-d^2 / (2 sigma^2))``, ``d`` the (wrapped, on a torus) cell offset.
    """
    if topology not in TOPOLOGIES:
        raise ValueError(f"topology must be one of {', '.join(TOPOLOGIES)}; received {topology!r}")
    if sigma <= 0:
        raise ValueError(f"sigma must be > 0, received {sigma}")
    i = np.arange(length)
    d = np.abs(i[:, None] - i[None, :])
    if topology == "toroidal":
        d = np.minimum(d, length - d)
    return np.exp(-(d.astype(np.float64) ** 2) / (2.0 * sigma**2))


def smooth(values: np.ndarray, sigma: float, rows: int, cols: int, topology: str = "toroidal") -> np.ndarray:
    """Gaussian neighbourhood sum ``sum_i h(i, j) values[i]`` over the grid, separably.

    The 2-D Gaussian of the (wrapped) cell distance factorises into a row and a column
    kernel, so two small matrix products give it exactly.

    Parameters
    ----------
    values : (rows*cols, ...) float

    Returns
    -------
    (rows*cols, ...) float64
    """
    values = np.asarray(values, np.float64)
    tail = values.shape[1:]
    grid = values.reshape(rows, cols, -1)
    k = grid.shape[2]
    kr = gaussian_kernel_1d(rows, sigma, topology)
    kc = gaussian_kernel_1d(cols, sigma, topology)
    # along columns: one (cols x cols) @ (cols x rows*k) product (not rows small batched ones)
    out = kc @ grid.transpose(1, 0, 2).reshape(cols, rows * k)
    out = np.ascontiguousarray(out.reshape(cols, rows, k).transpose(1, 0, 2)).reshape(rows, cols * k)
    out = kr @ out  # along rows
    return out.reshape((rows * cols,) + tail)


def partial_sums(X, W, index=None, sign=None, backend="auto", device: str | None = None
                 ) -> tuple[np.ndarray, np.ndarray, BMUResult]:
    """The map step of a batch epoch on one row chunk.

    Parameters
    ----------
    X : (N, D) float32
    W : (M, D) float32
    index, sign : (n, D) or None
        Variation table (None: identity, the default kernel).
    backend : str or Engine
    device : str or None

    Returns
    -------
    sums : (M, D) float64
        Per unit, the sum of the winning varied vectors ``sign[v] * x[index[v]]``, in row order
        (:func:`meshsom.bmu_numpy.unit_sums`; on an OpenCL device with float64 the same sums are
        taken on the device, bit for bit, next to the rows: :meth:`meshsom.bmu.Engine.unit_sums`).
    counts : (M,) float64
        Per unit, how many vectors it won.
    bmu : BMUResult
    """
    engine = resolve_backend(backend, device)
    bmu = engine.search(X, W, index, sign)
    sums, counts = engine.unit_sums(X, W, bmu, index, sign)
    return sums, counts, bmu


def block_sums(X, W, rows: int, cols: int, topology: str = "toroidal", index=None, sign=None,
               backend="auto") -> dict:
    """The whole map step of a batch epoch on one block of rows: per-unit sums and error sums.

    Parameters
    ----------
    X : (N, D) float32
    W : (M, D) float32
    index, sign : (n, D) or None
        Variation table (None: identity).
    backend : str or Engine

    Returns
    -------
    dict
        ``sums`` (M, D) float64 and ``counts`` (M,) float64 (:func:`partial_sums`), the error sums
        of :func:`meshsom.metrics.error_sums` (``n``, ``t_bad``, ``q_sum``, ``qc_sum``) and ``bmu``
        (:class:`BMUResult` of the block).
    """
    return blocks_sums(X, W, rows, cols, topology, index, sign, backend, block_rows=max(1, len(X)))


#: Most bytes of rows that one pass of :meth:`SOM.fit`'s epoch searches at once (whole row blocks,
#: at least one): keeps each device buffer under the allocation limit of common GPUs (NVIDIA's
#: OpenCL allows a quarter of the device memory in one buffer).
PASS_BYTES = 1 << 30

#: The scalar error sums of :func:`block_sums`.
ERROR_KEYS = ("n", "t_bad", "q_sum", "qc_sum")


def pass_ranges(n: int, row_bytes: int, block_rows: int = BLOCK_ROWS, pass_bytes: int | None = None
                ) -> list[tuple[int, int]]:
    """Row ranges of whole row blocks (:func:`row_blocks`) of at most ``pass_bytes`` (one block at least).

    Parameters
    ----------
    n : int
        Rows.
    row_bytes : int
        Bytes of one row.
    pass_bytes : int or None
        None: :data:`PASS_BYTES`.
    """
    pass_bytes = PASS_BYTES if pass_bytes is None else pass_bytes
    per = max(1, pass_bytes // max(1, row_bytes * block_rows)) * block_rows
    return [(a, min(n, a + per)) for a in range(0, n, per)]


def blocks_sums(X, W, rows: int, cols: int, topology: str = "toroidal", index=None, sign=None, backend="auto",
                block_rows: int = BLOCK_ROWS, total: dict | None = None, keep: bool = False) -> dict:
    """:func:`block_sums` of every row block of X (:func:`row_blocks`) added in block order
    (:func:`add_sums`) to ``total``: the same bits, in one search, one per-unit sums pass, one
    per-row Q / QC distances pass and one topographic errors pass (the tie rule) over the whole of X
    (one launch each on an OpenCL device, over rows that stay resident there when X is read-only).

    Parameters
    ----------
    X : (N, D) float32
        Rows of whole blocks (the blocks of an epoch, or a pass of them: :func:`pass_ranges`).
    W : (M, D) float32
    index, sign : (n, D) or None
    backend : str or Engine
    block_rows : int
    total : dict or None
        What earlier passes of the same epoch returned (None: the first pass).
    keep : bool
        Leave the per-unit sums on the device where the engine takes them there
        (:meth:`meshsom.bmu.Engine.unit_sums`): ``sums`` is then a
        :class:`meshsom.bmu_opencl.DeviceArray`, for :meth:`meshsom.bmu.Engine.batch_update`.

    Returns
    -------
    dict
        As :func:`block_sums`, summed over the blocks (and ``total``); ``bmu`` of every row so far.
    """
    engine = resolve_backend(backend)
    blocks = row_blocks(len(X), block_rows) or [(0, 0)]  # no rows: one empty block, zero sums
    bmu = engine.search(X, W, index, sign)
    sums, counts = engine.unit_sums(X, W, bmu, index, sign, blocks=blocks,
                                    init=None if total is None else total["sums"], keep=keep)
    q, qc = engine.row_errors(X, W, bmu, index, sign)
    bad = engine.topographic_errors(X, W, bmu, rows, cols, topology, index, sign)
    errors = None if total is None else {key: total[key] for key in ERROR_KEYS}
    for a, b in blocks:
        part = error_sums(X[a:b], W, bmu.rows(a, b), rows, cols, topology, index, sign, distances=(q[a:b], qc[a:b]),
                          bad=bad[a:b])
        errors = {key: part[key] if errors is None else errors[key] + part[key] for key in ERROR_KEYS}
    return {"sums": sums, "counts": counts if total is None else total["counts"] + counts, **errors,
            "bmu": bmu if total is None else BMUResult.concatenate([total["bmu"], bmu])}


#: Keys of :func:`block_sums` that add over blocks.
SUM_KEYS = ("sums", "counts", *ERROR_KEYS)


def add_sums(total: dict | None, part: dict) -> dict:
    """Add one block's :func:`block_sums` to a running total (None: the first block), in place.

    Only :data:`SUM_KEYS` are added; other keys keep the first block's value.
    """
    if total is None:
        return {k: (v.copy() if isinstance(v, np.ndarray) else v) for k, v in part.items() if k != "bmu"}
    for k in SUM_KEYS:
        total[k] += part[k]
    return total


#: Units whose smoothed count is not above this keep their prototype in :func:`batch_update`.
MIN_WEIGHT = 1e-12


def check_update_shapes(W, sums_shape: tuple, counts, rows: int, cols: int) -> None:
    """Raise ValueError unless W and sums are (rows*cols, D) and counts (rows*cols,)."""
    M = rows * cols
    if np.shape(W)[0] != M or tuple(sums_shape) != np.shape(W) or np.shape(counts) != (M,):
        raise ValueError(
            f"expected W and sums of shape ({M}, D) and counts of shape ({M},) for a {rows} x {cols} map; "
            f"received {np.shape(W)}, {tuple(sums_shape)}, {np.shape(counts)}"
        )


def batch_update(W, sums, counts, sigma: float, rows: int, cols: int, topology: str = "toroidal",
                 min_weight: float = MIN_WEIGHT) -> np.ndarray:
    """The reduce step of a batch epoch: smoothed sums over smoothed counts.

    Parameters
    ----------
    W : (M, D) float
        Current prototypes.
    sums : (M, D) float64
    counts : (M,) float64
        Summed over all chunks (see :func:`partial_sums`).
    sigma : float
        Neighbourhood radius in cells.
    min_weight : float
        Units whose smoothed count is not above this keep their prototype.

    Returns
    -------
    (M, D) same dtype as W

    See Also
    --------
    meshsom.bmu.Engine.batch_update : the same where an OpenCL device kept the sums.
    """
    W = np.asarray(W)
    check_update_shapes(W, np.shape(sums), counts, rows, cols)
    num = smooth(sums, sigma, rows, cols, topology)
    den = smooth(counts, sigma, rows, cols, topology)
    keep = den <= min_weight
    out = num / np.where(keep, 1.0, den)[:, None]
    out[keep] = W[keep]
    return out.astype(W.dtype)


def random_pick(n: int, units: int, seed) -> np.ndarray:
    """Rows the ``random`` initialisation copies: a seeded sample, with replacement only when
    there are fewer rows than units.

    Parameters
    ----------
    seed : int, None or numpy.random.Generator

    Returns
    -------
    (units,) int64
    """
    rng = seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)
    return np.asarray(rng.choice(n, size=units, replace=n < units), np.int64)


def moments(X) -> dict:
    """Sums behind the mean and the scatter matrix of one block of rows (add with :func:`add_moments`).

    Parameters
    ----------
    X : (N, D) float

    Returns
    -------
    dict
        ``n``, ``sum`` (D,) float64, ``gram`` (D, D) float64 (``X.T @ X``).
    """
    X64 = np.asarray(X, np.float64)
    return {"n": len(X64), "sum": X64.sum(axis=0), "gram": X64.T @ X64}


def add_moments(total: dict | None, part: dict) -> dict:
    """Add one block's :func:`moments` to a running total (None: the first block)."""
    if total is None:
        return {k: (v.copy() if isinstance(v, np.ndarray) else v) for k, v in part.items()}
    for k in ("n", "sum", "gram"):
        total[k] += part[k]
    return total


def block_moments(X, block_rows: int = BLOCK_ROWS) -> dict:
    """:func:`moments` of X added over :func:`row_blocks` in order (as a cluster adds them)."""
    total = None
    for a, b in row_blocks(len(X), block_rows):
        total = add_moments(total, moments(X[a:b]))
    return total


def orient_axes(axes: np.ndarray) -> np.ndarray:
    """The sign rule of principal axes: each axis's entry of largest magnitude is positive.

    An eigen- or singular-vector solver may return any sign; a flipped axis mirrors the map
    without changing any error, so every PCA initialisation goes through this rule.

    Parameters
    ----------
    axes : (k, D) float

    Returns
    -------
    (k, D) float64
    """
    axes = np.array(axes, np.float64)
    if axes.size:
        lead = axes[np.arange(len(axes)), np.argmax(np.abs(axes), axis=1)]
        axes *= np.where(lead < 0, -1.0, 1.0)[:, None]
    return axes


def principal_axes(mom: dict, components: int = 2) -> tuple[np.ndarray, np.ndarray]:
    """Mean and the first principal axes, scaled by their standard deviations, from moments.

    Parameters
    ----------
    mom : dict
        :func:`moments` (added over blocks): ``n``, ``sum`` (D,), ``gram`` (D, D).
    components : int

    Returns
    -------
    mean : (D,) float64
    axes : (components, D) float64
        ``sqrt(eigenvalue) * eigenvector`` of the sample covariance (zero rows where D is smaller),
        oriented by :func:`orient_axes`.
    """
    n = int(mom["n"])
    if n < 1:
        raise ValueError("PCA needs at least one row, received 0")
    mean = mom["sum"] / n
    cov = (mom["gram"] - n * np.outer(mean, mean)) / max(n - 1, 1)
    vals, vecs = np.linalg.eigh((cov + cov.T) / 2)
    order = np.argsort(vals)[::-1][:components]
    axes = np.zeros((components, len(mean)))
    axes[: len(order)] = (vecs[:, order] * np.sqrt(np.maximum(vals[order], 0.0))).T
    return mean, orient_axes(axes)


def principal_axes_dual(gram: np.ndarray, project: Callable, components: int = 2) -> tuple[np.ndarray, np.ndarray]:
    """:func:`principal_axes` from the n x n Gram matrix of the rows (for n smaller than D).

    Parameters
    ----------
    gram : (n, n) float64
        ``X @ X.T`` (not centred).
    project : callable
        ``project(U) -> X.T @ U`` for (n, k) U, (D, k) float64.

    Returns
    -------
    mean : (D,) float64
    axes : (components, D) float64
    """
    n = len(gram)
    if n < 1:
        raise ValueError("PCA needs at least one row, received 0")
    r = gram.sum(axis=1) / n  # X @ mean
    centred = gram - r[:, None] - r[None, :] + r.sum() / n
    vals, vecs = np.linalg.eigh((centred + centred.T) / 2)
    order = np.argsort(vals)[::-1][:components]
    U = np.column_stack([vecs[:, order], np.ones(n)])
    P = project(U)  # (D, k + 1): X.T @ u for each axis, and X.T @ 1
    mean = P[:, -1] / n
    axes = np.zeros((components, P.shape[0]))
    # Xc.T @ u = X.T @ u - mean * sum(u): the covariance axis scaled by its standard deviation
    axes[: len(order)] = ((P[:, :-1] - np.outer(mean, U[:, :-1].sum(axis=0))) / np.sqrt(max(n - 1, 1))).T
    return mean, orient_axes(axes)


def principal_axes_lanczos(apply: Callable, project: Callable, n: int, D: int, mean: np.ndarray,
                           components: int = 2) -> tuple[np.ndarray, np.ndarray]:
    """:func:`principal_axes` by Lanczos iteration on the centred rows (many rows and dimensions).

    Parameters
    ----------
    apply : callable
        ``apply(V) -> X @ V`` for (D, k) V, (n, k).
    project : callable
        ``project(U) -> X.T @ U`` for (n, k) U, (D, k).
    mean : (D,) float64

    Returns
    -------
    mean : (D,) float64
    axes : (components, D) float64
    """
    from scipy.sparse.linalg import LinearOperator, svds

    mean = np.asarray(mean, np.float64)

    def matmat(v):
        v = np.asarray(v, np.float64).reshape(D, -1)
        return apply(v) - (mean @ v)[None, :]

    def rmatmat(u):
        u = np.asarray(u, np.float64).reshape(n, -1)
        return project(u) - np.outer(mean, u.sum(axis=0))

    op = LinearOperator((n, D), matvec=matmat, rmatvec=rmatmat, matmat=matmat, rmatmat=rmatmat, dtype=np.float64)
    v0 = np.random.default_rng(0).standard_normal(min(n, D))  # fixed: the axes do not depend on a seed
    _, s, vt = svds(op, k=components, v0=v0, tol=0, solver="arpack")
    order = np.argsort(s)[::-1]
    return mean, orient_axes(vt[order] * (s[order] / np.sqrt(max(n - 1, 1)))[:, None])


def pca_codebook(mean, axes, rows: int, cols: int) -> np.ndarray:
    """The ``pca`` initialisation: the mean plus a grid spanning ``-1..1`` times the first
    principal axis along rows and the second along columns.

    Parameters
    ----------
    mean : (D,) float
    axes : (2, D) float
        :func:`principal_axes`.

    Returns
    -------
    (rows*cols, D) float32
    """
    a = np.linspace(-1, 1, rows)
    b = np.linspace(-1, 1, cols)
    grid = a[:, None, None] * axes[0] + b[None, :, None] * axes[1]
    return (np.asarray(mean) + grid.reshape(rows * cols, -1)).astype(np.float32)


def rows_pca(X, block_rows: int = BLOCK_ROWS) -> tuple[np.ndarray, np.ndarray]:
    """Mean and principal axes of rows in memory, by the rule of :data:`PCA_EXACT_DIMS`
    (the covariance from moments added over :func:`row_blocks`, as on a cluster).

    Parameters
    ----------
    X : (N, D) float

    Returns
    -------
    mean : (D,) float64
    axes : (2, D) float64
    """
    X = np.asarray(X)
    n, D = X.shape
    X64 = X.astype(np.float64) if D > PCA_EXACT_DIMS else None
    return pca_by_shape(n, D, moments=lambda: block_moments(X, block_rows), gram=lambda: X64 @ X64.T,
                        project=lambda U: X64.T @ U, apply=lambda V: X64 @ V, mean=lambda: X64.mean(axis=0))


def pca_by_shape(n: int, D: int, moments: Callable, gram: Callable, project: Callable, apply: Callable,
                 mean: Callable) -> tuple[np.ndarray, np.ndarray]:
    """The one PCA of every initialisation, for rows held in any form: the solver by the rule of
    :data:`PCA_EXACT_DIMS`, each given as a callable so that only the one used is computed.

    Parameters
    ----------
    n, D : int
        Rows and dimensions.
    moments : callable
        ``moments() -> dict`` (:func:`moments` of all rows).
    gram : callable
        ``gram() -> (n, n) X @ X.T``.
    project, apply : callable
        ``project(U) -> X.T @ U``, ``apply(V) -> X @ V``.
    mean : callable
        ``mean() -> (D,)``.

    Returns
    -------
    mean : (D,) float64
    axes : (2, D) float64
    """
    if D <= PCA_EXACT_DIMS:
        return principal_axes(moments())
    if n <= PCA_EXACT_DIMS:
        return principal_axes_dual(gram(), project)
    return principal_axes_lanczos(apply, project, n, D, mean())


def init_weights(X, rows: int, cols: int, init: str, seed=None, block_rows: int = BLOCK_ROWS) -> np.ndarray:
    """Initial prototypes from rows in memory.

    ``random``: the rows :func:`random_pick` draws. ``pca``: :func:`pca_codebook` of
    :func:`rows_pca`.

    Parameters
    ----------
    X : (N, D) float
    seed : int, None or numpy.random.Generator

    Returns
    -------
    (rows*cols, D) float32
    """
    X = np.asarray(X)
    if init == "random":
        return X[random_pick(len(X), rows * cols, seed)].astype(np.float32)
    if init == "pca":
        return pca_codebook(*rows_pca(X, block_rows), rows, cols)
    raise ValueError(f"init must be one of {', '.join(INITS)}; received {init!r}")


def train_batch(W, step: Callable[[np.ndarray], dict], rows: int, cols: int, epochs: int, sigma_start: float,
                sigma_end: float, topology: str = "toroidal", decay: str = "exponential", start_epoch: int = 0,
                callbacks: Iterable[Callable] = (), update: Callable = None) -> np.ndarray:
    """The batch-SOM driver: radius schedule, map step, update and callbacks, epoch by epoch.

    Parameters
    ----------
    W : (rows*cols, D) float32
        The codebook to start from (an initialisation, or a checkpoint at ``start_epoch``).
    step : callable
        ``step(W) -> dict`` with at least ``sums`` (M, D), ``counts`` (M,) and the error sums
        ``n``, ``t_bad``, ``q_sum``, ``qc_sum``: :func:`block_sums` added over row blocks, in
        memory or on a cluster.
    start_epoch : int
        First epoch to run (a resumed run).
    callbacks : iterable of callables
        Each called as ``callback(info, W)`` after every epoch with an :class:`EpochInfo` (the
        errors of the search against the codebook before the update) and the updated codebook.
    update : callable or None
        ``update(W, sums, counts, sigma, rows, cols, topology) -> W``; None: :func:`batch_update`
        (:meth:`meshsom.bmu.Engine.batch_update` updates where the step kept its sums on a device).

    Returns
    -------
    (rows*cols, D) float32
        The codebook after the last epoch.
    """
    callbacks = tuple(callbacks)
    update = update or batch_update
    for epoch in range(start_epoch, epochs):
        t0 = time.perf_counter()
        sigma = sigma_schedule(epoch, epochs, sigma_start, sigma_end, decay)
        part = step(W)
        W = update(W, part["sums"], part["counts"], sigma, rows, cols, topology)
        info = EpochInfo(epoch, sigma, part.get("bmu"), errors_of(part), time.perf_counter() - t0, part)
        for callback in callbacks:
            callback(info, W)
    return W


@dataclass(frozen=True)
class EpochInfo:
    """What an epoch callback receives.

    Attributes
    ----------
    epoch : int
        0-based.
    sigma : float
        Radius used in this epoch.
    bmu : BMUResult or None
        The BMUs found in this epoch, against the prototypes *before* its update (None where
        the step does not return them, as on a cluster, or in online training).
    errors : dict
        ``t_error``, ``q_error``, ``qc_error`` of that search (NaN in online training).
    seconds : float
        Wall time of the epoch.
    sums : dict or None
        What the step returned (sums, counts, error sums, and anything the step adds, such as
        the engine that computed it).
    """

    epoch: int
    sigma: float
    bmu: BMUResult | None
    errors: dict
    seconds: float
    sums: dict | None = None

    @property
    def q_error(self) -> float:
        """Mean BMU distance of the epoch's search."""
        return float(self.errors["q_error"])


class SOM:
    """Toroidal/planar rectangular SOM with the BMUofN search.

    Parameters
    ----------
    rows, cols : int
        Map size (the paper: 120 x 150).
    topology : {"toroidal", "planar"}
    epochs : int
    sigma_start : float or None
        Radius of the first epoch in cells; None: ``max(rows, cols) / 4``.
    sigma_end : float
        Radius of the last epoch.
    init : {"random", "pca"}
    training : {"batch", "online"}
        Online is the sequential Kohonen rule (one Python step per sample; for fidelity
        checks on small data).
    learning_rate : float
        Online training: rate of the first epoch.
    learning_rate_end : float
        Online training: rate of the last epoch.
    decay : {"exponential", "linear"}
        Schedule of the radius and the learning rate (:func:`sigma_schedule`).
    random_state : int or None
    backend : {"auto", "numpy", "opencl"}
    device : str or None
        OpenCL device selector.
    layout : str or None
        OpenCL kernel layouts to try in order, comma-separated (one name: that layout alone);
        None: the device's fallback chain.
    update : {"auto", "host", "device"}
        Where a batch epoch's update runs (:meth:`meshsom.bmu.Engine.update_on_device`). On the
        device the per-unit sums never leave it and the new codebook stays there for the next
        search; the codebook equals the host's to rounding, not bit for bit (so ``"auto"`` uses
        the device on GPUs only, and ``"host"`` keeps a map bitwise equal to the pipeline's).

    Attributes
    ----------
    weights_ : (rows*cols, D) float32
    n_iter_ : int
        Epochs run.
    n_features_in_ : int
    index_, sign_ : (n, D)
        The variation table used in ``fit``.
    backend_, device_ : str
        Which BMU backend and device ran.
    engine_ : meshsom.bmu.Engine
        The resolved backend; ``engine_.describe()`` also names the kernel layouts and fallbacks.
    update_ : str
        Where the last epoch's update ran in batch training: "device" or "host".
    """

    def __init__(self, rows: int = 120, cols: int = 150, topology: str = "toroidal", epochs: int = 20,
                 sigma_start: float | None = None, sigma_end: float = 1.0, init: str = "random",
                 training: str = "batch", learning_rate: float = 0.5, learning_rate_end: float = 0.01,
                 decay: str = "exponential", random_state: int | None = 0, backend: str = "auto",
                 device: str | None = None, layout: str | None = None, update: str = "auto"):
        self.rows = rows
        self.cols = cols
        self.topology = topology
        self.epochs = epochs
        self.sigma_start = sigma_start
        self.sigma_end = sigma_end
        self.init = init
        self.training = training
        self.learning_rate = learning_rate
        self.learning_rate_end = learning_rate_end
        self.decay = decay
        self.random_state = random_state
        self.backend = backend
        self.device = device
        self.layout = layout
        self.update = update

    def __getstate__(self) -> dict:
        """Pickle without the resolved engine (its OpenCL context belongs to this process);
        an unpickled map resolves ``backend_`` again on its first search."""
        state = dict(self.__dict__)
        state.pop("engine_", None)
        return state

    def __setstate__(self, state: dict) -> None:
        """Unpickle; a map pickled before a parameter existed gets its default."""
        self.__dict__.update({"update": "auto", **state})

    # ------------------------------------------------------------------ validation
    def _validate_params(self) -> None:
        for name, valid in (("topology", TOPOLOGIES), ("init", INITS), ("training", TRAININGS), ("decay", DECAYS)):
            if getattr(self, name) not in valid:
                raise ValueError(f"{name} must be one of {', '.join(valid)}; received {getattr(self, name)!r}")
        if self.rows < 2 or self.cols < 2:
            raise ValueError(f"map must be at least 2 x 2, received {self.rows} x {self.cols}")
        if self.epochs < 1:
            raise ValueError(f"epochs must be >= 1, received {self.epochs}")
        for name in ("sigma_end", "learning_rate", "learning_rate_end"):
            if getattr(self, name) <= 0:
                raise ValueError(f"{name} must be > 0, received {getattr(self, name)}")
        if self.sigma_start is not None and self.sigma_start <= 0:
            raise ValueError(f"sigma_start must be > 0 or None, received {self.sigma_start}")
        if self.update not in UPDATES:
            raise ValueError(f"update must be one of {', '.join(UPDATES)}; received {self.update!r}")

    @staticmethod
    def _validate_X(X, D: int | None = None) -> np.ndarray:
        X = np.asarray(X)
        if X.ndim != 2 or len(X) == 0:
            raise ValueError(f"X must be a non-empty (N, D) array, received shape {X.shape}")
        if not np.issubdtype(X.dtype, np.number):
            raise TypeError(f"X must hold numbers, received dtype {X.dtype}")
        if D is not None and X.shape[1] != D:
            raise ValueError(f"X has {X.shape[1]} features, the map was fitted with {D}")
        return np.ascontiguousarray(X, np.float32)

    @property
    def sigma_start_(self) -> float:
        """The resolved first radius."""
        return float(self.sigma_start if self.sigma_start is not None else default_sigma_start(self.rows, self.cols))

    # ------------------------------------------------------------------ training
    def fit(self, X, index=None, sign=None, callbacks: Iterable[Callable] = ()) -> "SOM":
        """Train the map.

        Parameters
        ----------
        X : (N, D) float
            On OpenCL a read-only float32 X (or one converted here) stays on the device between
            epochs (:class:`meshsom.bmu_opencl.ResidentRows`); a writable float32 X is copied up
            every epoch.
        index : (n, D) int64 or None
            Variation table (None: identity, the default kernel).
        sign : (n, D) float32 or None
        callbacks : iterable of callables
            Each called as ``callback(epoch, som, info)`` with an :class:`EpochInfo`
            after every epoch (``som.weights_`` is then read-only where the update ran on a
            device; after ``fit`` it is the codebook's own writable array).

        Returns
        -------
        self
        """
        self._validate_params()
        given = X
        X = self._validate_X(X)
        if X is not given and X.base is None:  # a converted copy of fit's own: resident on OpenCL
            X.flags.writeable = False
        D = X.shape[1]
        if index is None:
            index, sign = identity_table(D)
        index = np.asarray(index, np.int64)
        sign = np.ones(index.shape, np.float32) if sign is None else np.asarray(sign, np.float32)
        if index.ndim != 2 or index.shape[1] != D or sign.shape != index.shape:
            raise ValueError(f"index and sign must both have shape (n, {D}), received {index.shape} and {sign.shape}")
        rng = np.random.default_rng(self.random_state)
        engine = resolve_backend(self.backend, self.device, layout=self.layout)
        self.backend_, self.device_ = engine.backend, engine.device
        self.engine_ = engine
        self.index_, self.sign_ = index, sign
        self.n_features_in_ = D
        W = init_weights(X, self.rows, self.cols, self.init, rng)
        callbacks = tuple(callbacks)

        def report(info: EpochInfo, W) -> None:
            self.weights_ = W
            self.n_iter_ = info.epoch + 1
            for callback in callbacks:
                callback(info.epoch, self, info)

        if self.training == "batch":
            # the row blocks of the pipeline, reduced in passes of whole blocks (one for up to PASS_BYTES
            # of rows); the pass views are made once, so that they stay resident on an OpenCL device
            passes = [X[a:b] for a, b in pass_ranges(len(X), X.shape[1] * X.itemsize)]
            on_device = engine.update_on_device(self.update)

            def step(W):
                total = None
                for part in passes:
                    total = blocks_sums(part, W, self.rows, self.cols, self.topology, index, sign, backend=engine,
                                        total=total, keep=on_device)
                return total

            train_batch(W, step, self.rows, self.cols, self.epochs, self.sigma_start_, self.sigma_end,
                        self.topology, self.decay, callbacks=(report,),
                        update=engine.batch_update if on_device else batch_update)
            # only an update on the device returns its codebook read-only (it keeps the device copy)
            self.update_ = "host" if self.weights_.flags.writeable else "device"
            if self.update_ == "device":  # the map's own, writable copy
                self.weights_ = self.weights_.copy()
            return self
        for epoch in range(self.epochs):
            t0 = time.perf_counter()
            sigma = sigma_schedule(epoch, self.epochs, self.sigma_start_, self.sigma_end, self.decay)
            lr = sigma_schedule(epoch, self.epochs, self.learning_rate, self.learning_rate_end, self.decay)
            W = self._online_epoch(X, W, index, sign, sigma, lr, rng)
            nan = float("nan")
            report(EpochInfo(epoch, sigma, None, {"t_error": nan, "q_error": nan, "qc_error": nan},
                             time.perf_counter() - t0), W)
        return self

    def _online_epoch(self, X, W, index, sign, sigma, lr, rng) -> np.ndarray:
        """One Kohonen pass over X in a seeded random order (sequential by nature)."""
        W = W.astype(np.float64)
        coords = np.stack(np.divmod(np.arange(self.rows * self.cols), self.cols), axis=1)
        wnorm = np.einsum("ij,ij->i", W, W)
        size = np.array([self.rows, self.cols])
        for i in rng.permutation(len(X)):
            xv = sign * X[i][index]  # (n, D)
            d = wnorm[None, :] - 2.0 * (xv @ W.T) + np.einsum("ij,ij->i", xv, xv)[:, None]
            v, unit = divmod(int(np.argmin(d)), len(W))  # row-major: lowest variation, then unit
            delta = np.abs(coords - coords[unit])
            if self.topology == "toroidal":
                delta = np.minimum(delta, size - delta)
            h = np.exp(-(delta**2).sum(axis=1) / (2.0 * sigma**2))
            W += (lr * h)[:, None] * (xv[v] - W)
            wnorm = np.einsum("ij,ij->i", W, W)
        return W.astype(np.float32)

    # ------------------------------------------------------------------ inference
    def _check_fitted(self) -> None:
        if not hasattr(self, "weights_"):
            raise ValueError("this SOM is not fitted yet; call fit(X) first")

    def transform(self, X, index=None, sign=None) -> BMUResult:
        """BMUs (unit, variation, squared distance, second-best unit) of every row.

        Parameters
        ----------
        X : (N, D) float
        index, sign : (n, D) or None
            None: the table used in ``fit``.
        """
        self._check_fitted()
        X = self._validate_X(X, self.n_features_in_)
        if index is None:
            index, sign = self.index_, self.sign_
        engine = getattr(self, "engine_", None) or self.backend_
        bmu, _ = find_bmus(X, self.weights_, index, sign, backend=engine, device=self.device)
        return bmu

    def predict(self, X, index=None, sign=None) -> np.ndarray:
        """Best-matching unit of every row.

        Returns
        -------
        (N,) int64
        """
        return self.transform(X, index, sign).unit

    def evaluate(self, X, index=None, sign=None, neighbourhood: int = 8) -> dict:
        """T-, Q- and QC-errors of X on the fitted map (one BMU search).

        Returns
        -------
        dict
            ``t_error`` (with the tie rule of :mod:`meshsom.metrics`), ``q_error``, ``qc_error``
            (NaN when D is not a multiple of 3).
        """
        if index is None:
            self._check_fitted()
            index, sign = self.index_, self.sign_
        bmu = self.transform(X, index, sign)
        X = self._validate_X(X, self.n_features_in_)
        engine = resolve_backend(getattr(self, "engine_", None) or self.backend_, self.device)
        distances = engine.row_errors(X, self.weights_, bmu, index, sign)  # where training took them
        bad = engine.topographic_errors(X, self.weights_, bmu, self.rows, self.cols, self.topology, index, sign,
                                        neighbourhood)
        return errors_of(error_sums(X, self.weights_, bmu, self.rows, self.cols, self.topology, index, sign,
                                    neighbourhood, distances=distances, bad=bad))
