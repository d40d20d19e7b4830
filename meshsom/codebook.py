"""Save and load a trained map in a store's ``runs/<run>`` group.

The layout of ``runs/<run>`` (weights, BMU arrays, attributes) is defined in :mod:`meshsom.store`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import zarr

from meshsom.bmu_numpy import BMUResult
from meshsom.errors import StoreError
from meshsom.store import (  # noqa: F401  (BMU_ARRAYS: re-exported for the callers that import it from here)
    BMU_ARRAYS, read_bmus, read_weights, run_group, store_path, write_bmus, write_run_header, write_weights,
)


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
    write_weights(g, weights)
    if bmu is not None:
        write_bmus(g, bmu)
    write_run_header(g, rows, cols, topology, level, kernel)
    g.attrs.update({"metrics": {k: float(v) for k, v in (metrics or {}).items()}, **(extra or {})})
    return g


def load_codebook(group: zarr.Group, run: str) -> Codebook:
    """Read a map written by :func:`save_codebook`.

    Raises
    ------
    StoreError
        No such run, or it holds no ``weights``.
    """
    g = run_group(group, run, create=False)
    weights = read_weights(g)
    if weights is None:
        raise StoreError(f"{store_path(group)}: run {run!r} has no weights array")
    attrs = dict(g.attrs)
    bmus = read_bmus(g)
    bmu = None if bmus is None else BMUResult(**bmus)
    return Codebook(
        weights=weights,
        rows=int(attrs["rows"]), cols=int(attrs["cols"]), topology=str(attrs["topology"]),
        level=attrs.get("level"), kernel=attrs.get("kernel"), metrics=dict(attrs.get("metrics", {})),
        bmu=bmu, attrs=attrs,
    )
