"""Variations of ring vectors: start leaves and mirror images as a signed gather (DESIGN.md §3).

Changing the start leaf ``k`` rotates a ring; mirroring the mesh walks every offset the other
way and negates ``u``. Both are fixed per level, so a variation is a gather index plus a sign
per dimension, computed once from the ring template (never per triangle)::

    x_v = sign[v] * x[index[v]]        x: (D,) ring from start leaf 0

Variation order: ``k = 0, 1, 2`` (variation 0 is the identity), then, where mirrors are
included, the mirror image with ``k = 0, 1, 2``. The mirror with ``k = 0`` is the ring that
the mirrored mesh (vertices reflected, faces ``(a1, a0, a2)``) has at the same triangle.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from meshsom.rings import template

__all__ = ["KERNELS", "apply", "n_variations", "variation_table"]

#: Kernel names: the paper's "default" (one variation, raw order) and BMUofN.
KERNELS = ("default", "bmuofn")


def n_variations(level: int, kernel: str = "bmuofn", mirror: bool = False) -> int:
    """Number of variations: 1 for the default kernel; 6 at level 1, 3 above (6 with ``mirror``)."""
    if kernel not in KERNELS:
        raise ValueError(f"kernel must be one of {', '.join(KERNELS)}; received {kernel!r}")
    if kernel == "default":
        return 1
    return 6 if (level == 1 or mirror) else 3


@lru_cache(maxsize=None)
def _table(level: int, mirror: bool) -> tuple[np.ndarray, np.ndarray]:
    tpl = template(level)
    first: dict = {}
    for r, key in enumerate(tpl.keys()):
        first.setdefault(key, r)
    rows, signs = [], []
    comp = np.arange(3)
    for m in ([False, True] if mirror else [False]):
        for k in range(3):
            ref = np.array([first[key] for key in tpl.keys(start=k, mirror=m)], np.int64)
            rows.append((3 * ref[:, None] + comp[None, :]).reshape(-1))
            s = np.ones((len(ref), 3), np.float32)
            if m:
                s[:, 1] = -1.0  # u changes sign in a mirror image
            signs.append(s.reshape(-1))
    index, sign = np.array(rows), np.array(signs)
    index.setflags(write=False)
    sign.setflags(write=False)
    return index, sign


def variation_table(level: int, mirror: bool = False, kernel: str = "bmuofn") -> tuple[np.ndarray, np.ndarray]:
    """Gather index and sign of every variation of a level.

    Parameters
    ----------
    level : int
    mirror : bool
        Include mirror images at levels >= 2 too (level 1 always has them, as in the paper).
    kernel : {"default", "bmuofn"}
        "default" returns the identity alone.

    Returns
    -------
    index : (n, D) int64
    sign : (n, D) float32
        Read-only; ``n`` is :func:`n_variations`.
    """
    n = n_variations(level, kernel, mirror)
    index, sign = _table(int(level), n == 6)
    return index[:n], sign[:n]


def apply(x: np.ndarray, index: np.ndarray, sign: np.ndarray, v: int | np.ndarray) -> np.ndarray:
    """Variation(s) ``v`` of ring vectors.

    Parameters
    ----------
    x : (N, D) or (D,) float
    index, sign : (n, D)
    v : int or (N,) int64

    Returns
    -------
    varied : same shape as ``x``
    """
    x = np.asarray(x)
    if x.ndim == 1:
        return sign[v] * x[index[v]]
    v = np.broadcast_to(np.asarray(v), (len(x),))
    return sign[v] * np.take_along_axis(x, index[v], axis=1)
