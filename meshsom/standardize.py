"""Standardization of ring vectors per component type (alpha, u, v), with an exact inverse.

"Standardized, not normalized" (DESIGN.md §3): one mean and one standard deviation per component
type over the whole corpus, not per dimension, so that every variation (a signed permutation
that keeps component types in place) commutes with it. ``u`` is only scaled, about 0 (its
scale is the root mean square), so that a mirror stays a pure sign flip.

Statistics are accumulated chunk by chunk (count, sum, sum of squares per type) so that a
distributed encoder can merge partial results; they are stored with the corpus as a plain dict::

    {"level": L, "components": ["alpha", "u", "v"], "mean": [..3..], "std": [..3..], "count": n,
     "scaling": "standard"|"robust", "clip": None|c}

Robust scaling (``encoding.scaling: robust``): ``mean`` holds the median and ``std`` the
interquartile range / :data:`IQR_PER_SD` of each component type (u: centre 0, scale from the IQR
of ``u`` and ``-u`` together, so that a mirror stays a sign flip); standardized values are then
clipped to ``[-clip, clip]``. The quantiles are exact (``numpy.quantile``, linear) over the
distinct folds of the corpus (the level-1 entries: every fold appears equally often at every level
of a closed mesh, :func:`fold_statistics`); de-standardizing is exact for unclipped values.

Fold statistics (:func:`fold_statistics`) describe the raw folds: quantiles of alpha, u and v,
folds within :data:`FLAT_RAD` and within :data:`FLAT_DEG` degrees of 0 or 2 pi, and folds with
``v >`` :data:`LARGE_V`; their layout in the store is :mod:`meshsom.store`'s.
"""

from __future__ import annotations

import numpy as np

from meshsom.folds import COMPONENTS

__all__ = [
    "SCALINGS", "Stats", "accumulate", "destandardize", "empty_accumulator", "finalize", "fold_statistics",
    "describe_fold_statistics", "merge_accumulators", "robust_stats", "scale_hint", "standardize",
]

#: Scalings of :func:`standardize`, by config name.
SCALINGS = ("standard", "robust")
#: Interquartile range of a normal distribution in standard deviations (2 x 0.67449): robust
#: scales are IQR / IQR_PER_SD, comparable to a standard deviation.
IQR_PER_SD = 1.3489795003921634
#: Quantiles reported by :func:`fold_statistics`.
QUANTILES = (0.0, 0.001, 0.01, 0.25, 0.5, 0.75, 0.99, 0.999, 1.0)
#: Folds within this many radians of 0 or 2 pi are counted as ``flat_1e-3``.
FLAT_RAD = 1e-3
#: Folds within this many degrees of 0 or 2 pi are counted as ``flat_1deg``.
FLAT_DEG = 1.0
#: Folds with v above this are counted as ``v_over_100`` (an apex 100 edge lengths away).
LARGE_V = 100.0
#: The tail of :func:`fold_statistics`' ``tail_share``: the folds beyond this quantile of each
#: component's distance from its centre.
TAIL_QUANTILE = 0.99
#: A ``tail_share`` above this says that the tail, not the bulk, sets a component's standard
#: deviation (:func:`scale_hint`). Measured: Zürich's LoD2 roof models u 0.96, v 0.76; Delft's LoD1
#: blocks u 0.88; Zürich's LoD1 blocks (the paper's corpus) u 0.43, v 0.62.
TAIL_DOMINATES = 0.75


class Stats:
    """Mean and standard deviation per component type.

    Attributes
    ----------
    mean : (3,) float64
        ``mean[1]`` (u) is 0.
    std : (3,) float64
    count : int
        Values per component type that went into them.
    level : int or None
    """

    def __init__(self, mean, std, count: int = 0, level: int | None = None, scaling: str = "standard",
                 clip: float | None = None):
        self.mean = np.asarray(mean, np.float64).reshape(3)
        self.std = np.asarray(std, np.float64).reshape(3)
        if not (self.std > 0).all():
            raise ValueError(f"standard deviations must be > 0, received {self.std.tolist()}")
        if scaling not in SCALINGS:
            raise ValueError(f"scaling must be one of {list(SCALINGS)}, received {scaling!r}")
        if clip is not None and not clip > 0:
            raise ValueError(f"clip must be > 0 or None, received {clip!r}")
        self.count = int(count)
        self.level = level
        self.scaling = scaling
        self.clip = None if clip is None else float(clip)

    def to_dict(self) -> dict:
        return {
            "level": self.level, "components": list(COMPONENTS), "mean": self.mean.tolist(),
            "std": self.std.tolist(), "count": self.count, "scaling": self.scaling, "clip": self.clip,
        }

    @classmethod
    def from_dict(cls, d: dict) -> "Stats":
        return cls(d["mean"], d["std"], d.get("count", 0), d.get("level"), d.get("scaling", "standard"), d.get("clip"))

    def __repr__(self) -> str:
        return (f"Stats(level={self.level}, scaling={self.scaling!r}, mean={self.mean.tolist()}, std={self.std.tolist()}, "
                f"count={self.count}, clip={self.clip})")


def empty_accumulator() -> np.ndarray:
    """Zeroed accumulator: (3, 3) float64, rows (count, sum, sum of squares), columns alpha, u, v."""
    return np.zeros((3, 3), np.float64)


def accumulate(acc: np.ndarray, rings: np.ndarray) -> np.ndarray:
    """Add a chunk of ring vectors to an accumulator (returns a new one).

    Parameters
    ----------
    acc : (3, 3) float64
    rings : (n, D) float
    """
    x = np.asarray(rings, np.float64).reshape(len(rings), -1, 3)
    out = acc.copy()
    out[0] += x.shape[0] * x.shape[1]
    out[1] += x.sum(axis=(0, 1))
    out[2] += np.square(x).sum(axis=(0, 1))
    return out


def merge_accumulators(*accs: np.ndarray) -> np.ndarray:
    """Sum of accumulators."""
    return np.sum(accs, axis=0) if accs else empty_accumulator()


def finalize(acc: np.ndarray, level: int | None = None, eps: float = 1e-12) -> Stats:
    """Statistics from an accumulator; ``u`` centred at 0 (scale = root mean square).

    A component with no spread (a corpus of one flat plane has every alpha = pi) gets std 1, so
    standardizing stays invertible.
    """
    count = acc[0]
    if not (count > 0).all():
        raise ValueError("no values accumulated: cannot standardize an empty corpus")
    mean = acc[1] / count
    var = np.maximum(acc[2] / count - mean**2, 0.0)
    mean[1] = 0.0
    var[1] = acc[2][1] / count[1]
    std = np.sqrt(var)
    std[std <= eps] = 1.0
    return Stats(mean, std, int(count[0]), level)


def _stats(stats) -> Stats:
    return stats if isinstance(stats, Stats) else Stats.from_dict(stats)


def standardize(x: np.ndarray, stats) -> np.ndarray:
    """z-scores per component type.

    Parameters
    ----------
    x : (..., D) float
        D a multiple of 3, components interleaved (alpha, u, v, alpha, ...).
    stats : Stats or dict

    Returns
    -------
    z : (..., D) same float type as ``x`` (float32 stays float32)
    """
    s = _stats(stats)
    x = np.asarray(x)
    dtype = x.dtype if np.issubdtype(x.dtype, np.floating) else np.float64
    shape = x.shape
    z = (x.reshape(*shape[:-1], -1, 3) - s.mean) / s.std
    if s.clip is not None:
        z = np.clip(z, -s.clip, s.clip)
    return z.reshape(shape).astype(dtype, copy=False)


def destandardize(z: np.ndarray, stats) -> np.ndarray:
    """Exact inverse of :func:`standardize` (in float64; values clipped by a robust scaling come back clipped)."""
    s = _stats(stats)
    z = np.asarray(z, np.float64)
    shape = z.shape
    return (z.reshape(*shape[:-1], -1, 3) * s.std + s.mean).reshape(shape)


def _fold_columns(folds: np.ndarray) -> np.ndarray:
    x = np.asarray(folds, np.float64).reshape(-1, 3)
    if len(x) == 0:
        raise ValueError("no folds: cannot compute fold statistics of an empty corpus")
    return x


def robust_stats(folds: np.ndarray, level: int | None = None, clip: float = 5.0) -> Stats:
    """Robust scaling statistics: median and IQR / :data:`IQR_PER_SD` per component type.

    Parameters
    ----------
    folds : (n, 3) float or (F, 9) float
        The distinct folds of the corpus, ``(alpha, u, v)`` (level-1 ring vectors reshape to it).
    level : int, optional
    clip : float
        Standardized values are clipped to ``[-clip, clip]``.

    Returns
    -------
    Stats
        ``scaling="robust"``; ``mean = (median alpha, 0, median v)``; ``std`` the IQRs / 1.349, u's
        from the IQR of ``u`` and ``-u`` together; a zero IQR falls back to the standard deviation
        (and to 1 if that is 0 too), so standardizing stays invertible.
    """
    x = _fold_columns(folds)
    u_sym = np.concatenate([x[:, 1], -x[:, 1]])
    q = np.stack([np.quantile(x[:, 0], [0.25, 0.5, 0.75]), np.quantile(u_sym, [0.25, 0.5, 0.75]),
                  np.quantile(x[:, 2], [0.25, 0.5, 0.75])])
    centre = q[:, 1].copy()
    centre[1] = 0.0
    scale = (q[:, 2] - q[:, 0]) / IQR_PER_SD
    sd = np.array([x[:, 0].std(), np.sqrt(np.mean(x[:, 1] ** 2)), x[:, 2].std()])
    scale = np.where(scale > 0, scale, np.where(sd > 0, sd, 1.0))
    return Stats(centre, scale, len(x), level, scaling="robust", clip=clip)


def fold_statistics(folds: np.ndarray, level: int = 1) -> dict:
    """Quantiles and tail counts of the raw folds, as stored per level (:func:`meshsom.store.write_fold_stats`).

    Parameters
    ----------
    folds : (n, 3) float or (F, 9) float
        The distinct folds of the corpus, ``(alpha, u, v)``.
    level : int
        Ring level the statistics describe: a level-L ring array holds every fold ``4**(L-1)``
        times (a closed mesh), so its quantiles are those of the folds and its counts are the
        fold counts times ``4**(L-1)``.

    Returns
    -------
    stats : dict
        ``level``, ``folds`` (distinct folds), ``entries`` (fold entries at this level),
        ``quantiles`` (the levels :data:`QUANTILES`), ``alpha``/``u``/``v`` (their values),
        ``max_abs_u``, ``flat_1e-3`` and ``flat_1deg`` (entries within :data:`FLAT_RAD` rad or
        :data:`FLAT_DEG` degrees of 0 or 2 pi), ``v_over_100`` (entries with v > :data:`LARGE_V`)
        and ``v_over_100_fraction``; ``tail_share`` (per component: the share of its sum of
        squares about its centre, as standard scaling measures it, held by the folds beyond the
        :data:`TAIL_QUANTILE` quantile of their distance from it: 0.085 for normally distributed
        folds, 0.96-0.98 on LoD2 roof models, where centimetre edges beside metre faces set it).
    """
    x = _fold_columns(folds)
    mult = 4 ** (int(level) - 1)
    alpha, u, v = x[:, 0], x[:, 1], x[:, 2]
    near = np.minimum(alpha, 2 * np.pi - alpha)
    quantiles = list(QUANTILES)
    tail = {}
    for name, values, centre in (("alpha", alpha, alpha.mean()), ("u", u, 0.0), ("v", v, v.mean())):
        d2 = (np.asarray(values, np.float64) - centre) ** 2
        total = d2.sum()
        tail[name] = float(d2[d2 > np.quantile(d2, TAIL_QUANTILE)].sum() / total) if total > 0 else 0.0
    return {
        "level": int(level),
        "folds": int(len(x)),
        "entries": int(len(x) * mult),
        "quantiles": quantiles,
        "alpha": np.quantile(alpha, quantiles).tolist(),
        "u": np.quantile(u, quantiles).tolist(),
        "v": np.quantile(v, quantiles).tolist(),
        "max_abs_u": float(np.abs(u).max()),
        "flat_1e-3": int((near < FLAT_RAD).sum()) * mult,
        "flat_1deg": int((near < np.radians(FLAT_DEG)).sum()) * mult,
        "v_over_100": int((v > LARGE_V).sum()) * mult,
        "v_over_100_fraction": float((v > LARGE_V).mean()),
        "tail_share": tail,
    }


def describe_fold_statistics(stats: dict) -> str:
    """One line of :func:`fold_statistics` for the command line."""
    q = stats["quantiles"]
    i50, i999, i100 = q.index(0.5), q.index(0.999), q.index(1.0)
    return (
        f"folds: alpha median {stats['alpha'][i50]:.4g} [{stats['alpha'][0]:.4g}, {stats['alpha'][i100]:.4g}], "
        f"|u| max {stats['max_abs_u']:.4g}, v median {stats['v'][i50]:.4g} q99.9 {stats['v'][i999]:.4g} "
        f"max {stats['v'][i100]:.4g}; within 1e-3 rad of 0/2pi: {stats['flat_1e-3']}, within 1 deg: "
        f"{stats['flat_1deg']}; v > 100: {stats['v_over_100']} of {stats['entries']} entries "
        f"({stats['v_over_100_fraction']:.2e})"
        + ("; the top 1 % hold " + ", ".join(f"{100 * stats['tail_share'][c]:.0f} % of {c}'s spread" for c in COMPONENTS)
           if "tail_share" in stats else "")
    )


def scale_hint(stats: dict, scaling: str = "standard") -> str | None:
    """A line saying that standard scaling would be set by a few extreme folds, or None.

    Parameters
    ----------
    stats : dict
        :func:`fold_statistics` (stores written before ``tail_share`` existed give None).
    scaling : str
        The scaling in use (:data:`SCALINGS`): robust scaling needs no hint.
    """
    shares = stats.get("tail_share")
    if scaling != "standard" or not shares:
        return None
    heavy = [c for c in COMPONENTS if shares.get(c, 0.0) > TAIL_DOMINATES]
    if not heavy:
        return None
    said = " and ".join(f"{c} ({100 * shares[c]:.0f} % of its sum of squares)" for c in heavy)
    return (f"hint: the top 1 % of folds set the standard deviation of {said}, so standard scaling squeezes the "
            f"other 99 % together (short edges beside large faces); "
            f"encoding.scaling: robust (median and IQR, clipped) keeps them apart")
