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
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Callable, Iterable

import numpy as np

from meshsom.bmu import Engine, find_bmus, resolve_backend
from meshsom.bmu_numpy import BMUResult, identity_table, varied
from meshsom.metrics import TOPOLOGIES, q_error, qc_error, t_error

INITS = ("random", "pca")
TRAININGS = ("batch", "online")
DECAYS = ("exponential", "linear")


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
        Per unit, the sum of the winning varied vectors ``sign[v] * x[index[v]]``.
    counts : (M,) float64
        Per unit, how many vectors it won.
    bmu : BMUResult
    """
    X = np.asarray(X)
    W = np.asarray(W)
    bmu, _ = find_bmus(X, W, index, sign, backend=backend, device=device)
    if index is None:
        index, sign = identity_table(X.shape[1])
    xv = varied(X, np.asarray(index, np.int64), np.asarray(sign, X.dtype), bmu.variation)
    # per-unit sums in O(N * D): rows sorted by unit (stable: row order within a unit), one
    # segmented sum per winning unit
    order = np.argsort(bmu.unit, kind="stable")
    units = bmu.unit[order]
    starts = np.flatnonzero(np.r_[True, units[1:] != units[:-1]]) if len(units) else np.zeros(0, np.int64)
    sums = np.zeros((len(W), X.shape[1]))
    if len(units):
        sums[units[starts]] = np.add.reduceat(xv[order].astype(np.float64), starts, axis=0)
    counts = np.bincount(bmu.unit, minlength=len(W)).astype(np.float64)
    return sums, counts, bmu


def batch_update(W, sums, counts, sigma: float, rows: int, cols: int, topology: str = "toroidal",
                 min_weight: float = 1e-12) -> np.ndarray:
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
    """
    W = np.asarray(W)
    M = rows * cols
    if W.shape[0] != M or np.shape(sums) != W.shape or np.shape(counts) != (M,):
        raise ValueError(
            f"expected W and sums of shape ({M}, D) and counts of shape ({M},) for a {rows} x {cols} map; "
            f"received {W.shape}, {np.shape(sums)}, {np.shape(counts)}"
        )
    num = smooth(sums, sigma, rows, cols, topology)
    den = smooth(counts, sigma, rows, cols, topology)
    keep = den <= min_weight
    out = num / np.where(keep, 1.0, den)[:, None]
    out[keep] = W[keep]
    return out.astype(W.dtype)


def init_weights(X, rows: int, cols: int, init: str, rng: np.random.Generator) -> np.ndarray:
    """Initial prototypes.

    ``random``: seeded samples of X (with replacement when X has fewer rows than the map
    has units). ``pca``: the mean plus a grid over the first two principal components,
    spanning +-sqrt(eigenvalue) along rows and columns.

    Returns
    -------
    (rows*cols, D) float32
    """
    X = np.asarray(X)
    M = rows * cols
    if init == "random":
        pick = rng.choice(len(X), size=M, replace=len(X) < M)
        return X[pick].astype(np.float32)
    if init == "pca":
        X64 = X.astype(np.float64)
        mean = X64.mean(axis=0)
        _, s, vt = np.linalg.svd(X64 - mean, full_matrices=False)
        scale = s / np.sqrt(max(len(X) - 1, 1))
        comps = np.zeros((2, X.shape[1]))
        k = min(2, len(scale))
        comps[:k] = vt[:k] * scale[:k, None]
        a = np.linspace(-1, 1, rows)
        b = np.linspace(-1, 1, cols)
        grid = a[:, None, None] * comps[0] + b[None, :, None] * comps[1]
        return (mean + grid.reshape(M, -1)).astype(np.float32)
    raise ValueError(f"init must be one of {', '.join(INITS)}; received {init!r}")


@dataclass(frozen=True)
class EpochInfo:
    """What a callback receives after each epoch (with the epoch number and the SOM).

    Attributes
    ----------
    epoch : int
        0-based.
    sigma : float
        Radius used in this epoch.
    bmu : BMUResult or None
        The BMUs found in this epoch, against the prototypes *before* its update
        (None in online training).
    q_error : float
        Mean BMU distance of that search (NaN in online training).
    seconds : float
        Wall time of the epoch.
    """

    epoch: int
    sigma: float
    bmu: BMUResult | None
    q_error: float
    seconds: float


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
    """

    def __init__(self, rows: int = 120, cols: int = 150, topology: str = "toroidal", epochs: int = 20,
                 sigma_start: float | None = None, sigma_end: float = 1.0, init: str = "random",
                 training: str = "batch", learning_rate: float = 0.5, learning_rate_end: float = 0.01,
                 decay: str = "exponential", random_state: int | None = 0, backend: str = "auto",
                 device: str | None = None, layout: str | None = None):
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

    def __getstate__(self) -> dict:
        """Pickle without the resolved engine (its OpenCL context belongs to this process);
        an unpickled map resolves ``backend_`` again on its first search."""
        state = dict(self.__dict__)
        state.pop("engine_", None)
        return state

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
        return float(self.sigma_start if self.sigma_start is not None else max(self.rows, self.cols) / 4)

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
            after every epoch.

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
        for epoch in range(self.epochs):
            t0 = time.perf_counter()
            sigma = sigma_schedule(epoch, self.epochs, self.sigma_start_, self.sigma_end, self.decay)
            if self.training == "batch":
                sums, counts, bmu = partial_sums(X, W, index, sign, backend=engine)
                W = batch_update(W, sums, counts, sigma, self.rows, self.cols, self.topology)
                qe = float(np.mean(np.sqrt(bmu.dist2)))
            else:
                lr = sigma_schedule(epoch, self.epochs, self.learning_rate, self.learning_rate_end, self.decay)
                W = self._online_epoch(X, W, index, sign, sigma, lr, rng)
                bmu, qe = None, float("nan")
            self.weights_ = W
            self.n_iter_ = epoch + 1
            info = EpochInfo(epoch, sigma, bmu, qe, time.perf_counter() - t0)
            for callback in callbacks:
                callback(epoch, self, info)
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
            ``t_error``, ``q_error``, ``qc_error`` (NaN when D is not a multiple of 3).
        """
        if index is None:
            self._check_fitted()
            index, sign = self.index_, self.sign_
        bmu = self.transform(X, index, sign)
        X = self._validate_X(X, self.n_features_in_)
        D = X.shape[1]
        return {
            "t_error": t_error(bmu.unit, bmu.second, self.rows, self.cols, self.topology, neighbourhood),
            "q_error": q_error(X, self.weights_, bmu, index, sign),
            "qc_error": qc_error(X, self.weights_, bmu, index, sign) if D % 3 == 0 else float("nan"),
        }
