"""Standardization of ring vectors per component type (alpha, u, v), with an exact inverse.

"Standardized, not normalized" (DESIGN.md §3): one mean and one standard deviation per component
type over the whole corpus, not per dimension, so that every variation (a signed permutation
that keeps component types in place) commutes with it. ``u`` is only scaled, about 0 (its
scale is the root mean square), so that a mirror stays a pure sign flip.

Statistics are accumulated chunk by chunk (count, sum, sum of squares per type) so that a
distributed encoder can merge partial results; they are stored with the corpus as a plain dict::

    {"level": L, "components": ["alpha", "u", "v"], "mean": [..3..], "std": [..3..], "count": n}
"""

from __future__ import annotations

import numpy as np

from meshsom.folds import COMPONENTS

__all__ = ["Stats", "accumulate", "destandardize", "empty_accumulator", "finalize", "merge_accumulators", "standardize"]


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

    def __init__(self, mean, std, count: int = 0, level: int | None = None):
        self.mean = np.asarray(mean, np.float64).reshape(3)
        self.std = np.asarray(std, np.float64).reshape(3)
        if not (self.std > 0).all():
            raise ValueError(f"standard deviations must be > 0, received {self.std.tolist()}")
        self.count = int(count)
        self.level = level

    def to_dict(self) -> dict:
        return {
            "level": self.level, "components": list(COMPONENTS), "mean": self.mean.tolist(),
            "std": self.std.tolist(), "count": self.count,
        }

    @classmethod
    def from_dict(cls, d: dict) -> "Stats":
        return cls(d["mean"], d["std"], d.get("count", 0), d.get("level"))

    def __repr__(self) -> str:
        return f"Stats(level={self.level}, mean={self.mean.tolist()}, std={self.std.tolist()}, count={self.count})"


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
    return z.reshape(shape).astype(dtype, copy=False)


def destandardize(z: np.ndarray, stats) -> np.ndarray:
    """Exact inverse of :func:`standardize` (in float64)."""
    s = _stats(stats)
    z = np.asarray(z, np.float64)
    shape = z.shape
    return (z.reshape(*shape[:-1], -1, 3) * s.std + s.mean).reshape(shape)
