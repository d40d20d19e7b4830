"""Save and load a trained map in a store's ``runs/<run>`` group.

Layout of ``runs/<run>`` (the group itself comes from :func:`meshsom.store.run_group`):

- ``weights``: (rows*cols, D) float32, the prototypes, row-major over the grid;
- ``bmu_unit``, ``bmu_variation``, ``bmu_second``: (N,) int64, optional, per input vector;
- ``bmu_dist2``: (N,) float64, optional;
- attributes: ``rows``, ``cols``, ``topology``, ``level``, ``kernel``, ``metrics`` (a dict
  of floats) and any ``extra`` attributes given.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import zarr

from meshsom.bmu_numpy import BMUResult
from meshsom.errors import StoreError
from meshsom.store import run_group, store_path

BMU_ARRAYS = {"unit": "bmu_unit", "variation": "bmu_variation", "dist2": "bmu_dist2", "second": "bmu_second"}


@dataclass(frozen=True)
class Codebook:
    """A trained map as stored.

    Attributes
    ----------
    weights : (rows*cols, D) float32
    rows, cols : int
    topology : str
    level : int or None
    kernel : str or None
    metrics : dict
    bmu : BMUResult or None
    attrs : dict
        Every attribute of the group.
    """

    weights: np.ndarray = field(repr=False)
    rows: int
    cols: int
    topology: str
    level: int | None = None
    kernel: str | None = None
    metrics: dict = field(default_factory=dict)
    bmu: BMUResult | None = field(default=None, repr=False)
    attrs: dict = field(default_factory=dict, repr=False)


def _put(group: zarr.Group, name: str, data: np.ndarray) -> None:
    chunks = (max(1, min(len(data), 1 << 16)),) + tuple(data.shape[1:])
    arr = group.create_array(name, shape=data.shape, dtype=data.dtype, chunks=chunks, overwrite=True)
    if data.size:
        arr[...] = data


def save_codebook(group: zarr.Group, run: str, weights, rows: int, cols: int, topology: str,
                  level: int | None = None, kernel: str | None = None, metrics: dict | None = None,
                  bmu: BMUResult | None = None, extra: dict | None = None) -> zarr.Group:
    """Write a map into ``runs/<run>`` (replacing what was there).

    Parameters
    ----------
    group : zarr.Group
        The store root.
    weights : (rows*cols, D) float
    bmu : BMUResult or None
        Per-vector BMUs to keep alongside.
    extra : dict or None
        More JSON-serialisable attributes.

    Returns
    -------
    zarr.Group
        ``runs/<run>``.
    """
    weights = np.asarray(weights, np.float32)
    if weights.ndim != 2 or len(weights) != rows * cols:
        raise ValueError(f"weights must have shape ({rows * cols}, D) for a {rows} x {cols} map, received {weights.shape}")
    g = run_group(group, run)
    _put(g, "weights", weights)
    if bmu is not None:
        for attr, name in BMU_ARRAYS.items():
            a = getattr(bmu, attr)
            _put(g, name, np.asarray(a, np.float64 if attr == "dist2" else np.int64))
    g.attrs.update({
        "rows": int(rows), "cols": int(cols), "topology": str(topology),
        "level": None if level is None else int(level), "kernel": kernel,
        "metrics": {k: float(v) for k, v in (metrics or {}).items()},
        **(extra or {}),
    })
    return g


def load_codebook(group: zarr.Group, run: str) -> Codebook:
    """Read a map written by :func:`save_codebook`.

    Raises
    ------
    StoreError
        No such run, or it holds no ``weights``.
    """
    g = run_group(group, run, create=False)
    if "weights" not in g:
        raise StoreError(f"{store_path(group)}: run {run!r} has no weights array")
    attrs = dict(g.attrs)
    bmu = None
    if all(name in g for name in BMU_ARRAYS.values()):
        bmu = BMUResult(**{attr: np.asarray(g[name][:]) for attr, name in BMU_ARRAYS.items()})
    return Codebook(
        weights=np.asarray(g["weights"][:]),
        rows=int(attrs["rows"]), cols=int(attrs["cols"]), topology=str(attrs["topology"]),
        level=attrs.get("level"), kernel=attrs.get("kernel"), metrics=dict(attrs.get("metrics", {})),
        bmu=bmu, attrs=attrs,
    )
