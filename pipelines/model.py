"""A trained triangle map as an MLflow pyfunc model: raw ring vectors in, units and variations out.

What the model holds (MLflow artifacts, relative to the model folder; nothing points at the store
or at any other local path)::

    artifacts/weights.npy          (rows*cols, D) float32  the codebook, row-major over the grid
    artifacts/variation_index.npy  (n, D) int64            gather of every variation (meshsom.variations)
    artifacts/variation_sign.npy   (n, D) float32          sign of every variation
    artifacts/map.json             geometry (rows, cols, topology), level, kernel, mirror, dims,
                                   the map's final errors, and the standardization statistics of
                                   its level (meshsom.standardize.Stats.to_dict)
    code/meshsom/                  the numerical library (standardize, bmu_numpy)
    code/pipelines/model.py        this module (the pyfunc class)

``mlflow.pyfunc.load_model(uri).predict(X)`` takes raw (unstandardized) ring vectors ``X`` of the
map's level, ``(N, D)`` float32 as stored in ``rings/level{L}`` (a NumPy array or a DataFrame of
float32 columns; the signature says so), standardizes them with the packed statistics and finds
BMUofN with the NumPy/BLAS reference (:func:`meshsom.bmu_numpy.bmu_numpy`), so any machine with
MLflow and NumPy gets the store's answer without OpenCL or the store.

This module imports nothing from MLflow at its top but the pyfunc base class; the MLflow writes
themselves are :meth:`pipelines.tracking.Tracker.log_model`'s.
"""

from __future__ import annotations

import json
import os
import shutil
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from mlflow.pyfunc import PythonModel

#: Version of the packed layout (``map.json`` ``format``).
MODEL_FORMAT = 1
#: Rows of the input example logged with every model.
EXAMPLE_ROWS = 5
#: Artifact names -> file names inside the model's ``artifacts/`` folder.
ARTIFACTS = {"weights": "weights.npy", "variation_index": "variation_index.npy",
             "variation_sign": "variation_sign.npy", "map": "map.json"}
#: Columns of a prediction, in order.
COLUMNS = ("unit", "variation", "row", "col", "dist2", "second")
#: Distributions a loaded model needs (pinned to the versions that logged it).
REQUIREMENTS = ("mlflow", "numpy", "pandas")
#: Files and folders never shipped with the model code.
CODE_IGNORE = ("__pycache__", "*.pyc")


@dataclass
class MapPackage:
    """Everything :meth:`pipelines.tracking.Tracker.log_model` logs for one map.

    Attributes
    ----------
    name : str
        The map's run name (``level1-bmuofn``).
    artifacts : dict of str -> str
        Artifact name -> file in a temporary folder (copied into the model by MLflow).
    code_paths : list of str
        Folders shipped as the model's code (``meshsom``, ``pipelines`` with this module only).
    input_example : (EXAMPLE_ROWS, D) float32
        Raw ring vectors of the store.
    output_example : pandas.DataFrame
        The prediction for ``input_example`` (for the signature).
    meta : dict
        Contents of ``map.json``.
    folder : Path
        The temporary folder holding ``artifacts`` and the staged code; :meth:`cleanup` removes it.
    """

    name: str
    artifacts: dict
    code_paths: list
    input_example: np.ndarray = field(repr=False)
    output_example: object = field(repr=False)
    meta: dict = field(repr=False)
    folder: Path

    def cleanup(self) -> None:
        shutil.rmtree(self.folder, ignore_errors=True)

    def artifact_uris(self) -> dict:
        """``artifacts`` as paths relative to the working directory, where the folder lies inside it.

        MLflow records each artifact's source URI in the model's ``MLmodel`` (it reads only the
        copies inside the model): relative paths keep absolute local paths out of it.
        """
        here = Path.cwd().resolve()
        return {k: os.path.relpath(Path(v).resolve(), here) if Path(v).resolve().is_relative_to(here) else v
                for k, v in self.artifacts.items()}


def packing_folder() -> Path | None:
    """Where to pack a model: the working directory when it is writable (see
    :meth:`MapPackage.artifact_uris`), else None (the system's temporary folder)."""
    return Path.cwd() if os.access(Path.cwd(), os.W_OK) else None


def as_ring_vectors(X, dims: int) -> np.ndarray:
    """Raw ring vectors as the (N, D) float32 array the store holds.

    Parameters
    ----------
    X : (N, D) array-like or pandas.DataFrame
    dims : int
        D of the map's level.

    Raises
    ------
    ValueError
        Not two-dimensional, or another number of columns.
    """
    x = np.asarray(X.to_numpy() if hasattr(X, "to_numpy") else X)
    if x.ndim == 1 and x.size == dims:
        x = x[None, :]
    if x.ndim != 2 or x.shape[1] != dims:
        raise ValueError(f"ring vectors of this map must have shape (N, {dims}), received {x.shape}")
    if not (np.issubdtype(x.dtype, np.floating) or np.issubdtype(x.dtype, np.integer)):
        raise TypeError(f"ring vectors must hold real numbers, received dtype {x.dtype}")
    return x.astype(np.float32, copy=False)


def predict_units(X, weights: np.ndarray, stats: dict, index: np.ndarray, sign: np.ndarray, cols: int):
    """Best-matching unit and winning variation of raw ring vectors, as a table.

    The same arithmetic as training (:func:`pipelines.train.load_chunk` then BMUofN): float32
    raw vectors, standardized per component type, searched against the codebook over every
    variation.

    Parameters
    ----------
    X : (N, D) array-like or pandas.DataFrame
        Raw (unstandardized) ring vectors.
    weights : (rows*cols, D) float32
    stats : dict
        Standardization statistics of the level (:meth:`meshsom.standardize.Stats.to_dict`).
    index : (n, D) int64
    sign : (n, D) float32
    cols : int
        Grid columns (units are row-major).

    Returns
    -------
    pandas.DataFrame
        ``unit``, ``variation``, ``row``, ``col``, ``second`` (int64) and ``dist2`` (float64,
        squared distance in standardized units), one row per vector.
    """
    import pandas as pd

    from meshsom.bmu_numpy import bmu_numpy
    from meshsom.standardize import standardize

    x = as_ring_vectors(X, weights.shape[1])
    z = standardize(x, stats).astype(np.float32, copy=False)
    bmu = bmu_numpy(z, weights, index, sign)
    unit = np.asarray(bmu.unit, np.int64)
    return pd.DataFrame({
        "unit": unit, "variation": np.asarray(bmu.variation, np.int64), "row": unit // cols, "col": unit % cols,
        "dist2": np.asarray(bmu.dist2, np.float64), "second": np.asarray(bmu.second, np.int64),
    }, columns=list(COLUMNS))


class MapModel(PythonModel):
    """The pyfunc model of one triangle map (its state is read from the artifacts when loaded)."""

    # predict takes a table or an array (no type hint MLflow validates fits both; the logged
    # signature describes the input): without this, every process that defines the class (the
    # run, and each that loads the model) prints MLflow's advice to add type hints
    _skip_type_hint_validation = True

    def load_context(self, context) -> None:
        with open(context.artifacts["map"]) as fh:
            self.meta = json.load(fh)
        self.weights = np.load(context.artifacts["weights"])
        self.index = np.load(context.artifacts["variation_index"])
        self.sign = np.load(context.artifacts["variation_sign"])

    def predict(self, context, model_input, params=None):
        """Units and variations of raw ring vectors (see :func:`predict_units`)."""
        return predict_units(model_input, self.weights, self.meta["stats"], self.index, self.sign, self.meta["cols"])


def pip_requirements() -> list[str]:
    """The model's pip requirements: :data:`REQUIREMENTS` at the installed versions."""
    from importlib.metadata import version

    return [f"{name}=={version(name)}" for name in REQUIREMENTS]


def _stage_code(folder: Path) -> list[str]:
    """Copy the code a loaded model imports into ``folder``: ``meshsom/`` and ``pipelines/model.py``."""
    import meshsom

    here = Path(__file__).resolve()
    lib = folder / "meshsom"
    shutil.copytree(Path(meshsom.__file__).resolve().parent, lib, ignore=shutil.ignore_patterns(*CODE_IGNORE))
    pkg = folder / "pipelines"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("")
    shutil.copy2(here, pkg / here.name)
    return [str(lib), str(pkg)]


def pack_map(group, run: str, folder: str | Path) -> MapPackage:
    """Gather a trained map of a store into a folder, ready to be logged as a model.

    Parameters
    ----------
    group : zarr.Group
        The store root (:func:`meshsom.store.open_store`).
    run : str
        A triangle map under ``runs/`` (trained on ``rings/level{L}``).
    folder : str or Path
        An empty or missing folder; it receives ``artifacts/`` and ``code/``.

    Returns
    -------
    MapPackage

    Raises
    ------
    StoreError
        No such run, no weights, no statistics of its level, or a map trained on another array
        (a domain map).
    """
    from meshsom.codebook import load_codebook
    from meshsom.errors import StoreError
    from meshsom.store import read_stats, rings_array, store_path
    from meshsom.variations import variation_table

    cb = load_codebook(group, run)
    job = dict(cb.attrs.get("job", {}))
    if job.get("source") or cb.level is None or cb.kernel is None:
        raise StoreError(f"{store_path(group)}: run {run!r} is not a triangle map of a ring level "
                         f"(level {cb.level!r}, kernel {cb.kernel!r}, source {job.get('source')!r})")
    level, kernel, mirror = int(cb.level), str(cb.kernel), bool(job.get("mirror", False))
    stats = read_stats(group, level)
    index, sign = variation_table(level, mirror=mirror, kernel=kernel)
    weights = np.asarray(cb.weights, np.float32)
    rings = rings_array(group, level)
    if rings.shape[1] != weights.shape[1]:
        raise StoreError(f"{store_path(group)}: run {run!r} has {weights.shape[1]}-dimensional prototypes, "
                         f"rings/level{level} has {rings.shape[1]} columns")
    example = np.asarray(rings[:EXAMPLE_ROWS], np.float32)

    folder = Path(folder)
    art = folder / "artifacts"
    art.mkdir(parents=True, exist_ok=True)
    meta = {
        "format": MODEL_FORMAT, "run": run, "level": level, "kernel": kernel, "mirror": mirror,
        "rows": cb.rows, "cols": cb.cols, "topology": cb.topology, "units": cb.rows * cb.cols,
        "dims": int(weights.shape[1]), "variations": int(len(index)), "columns": list(COLUMNS),
        "metrics": {k: float(v) for k, v in cb.metrics.items()}, "stats": stats,
    }
    np.save(art / ARTIFACTS["weights"], weights)
    np.save(art / ARTIFACTS["variation_index"], np.asarray(index, np.int64))
    np.save(art / ARTIFACTS["variation_sign"], np.asarray(sign, np.float32))
    with open(art / ARTIFACTS["map"], "w") as fh:
        json.dump(meta, fh, indent=1)
    code = folder / "code"
    code.mkdir(exist_ok=True)
    return MapPackage(
        name=run, artifacts={k: str(art / v) for k, v in ARTIFACTS.items()}, code_paths=_stage_code(code),
        input_example=example, output_example=predict_units(example, weights, stats, index, sign, cb.cols),
        meta=meta, folder=folder,
    )
