"""Pipeline settings: where the work runs (``dask:``) and where it is tracked (``tracking:``).

The library's :class:`meshsom.config.ExperimentConfig` holds what a result depends on;
:class:`RunConfig` adds the two pipeline sections, and is what ``meshsom run`` loads from
the same YAML files (validated by :func:`meshsom.config.build`, so errors read the same).

Paths in a config file are relative to the file's folder: :func:`resolve_paths` turns
``corpus.paths``, a relative ``store.path`` and a relative ``sqlite:///`` tracking URI into
absolute ones for the run, while the config as written (after overrides) is what MLflow
records, so that no local absolute path lands in the params.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path
from typing import Iterable

from meshsom.config import ExperimentConfig
from meshsom.config import load_config as _load_config


@dataclass(frozen=True)
class DaskConfig:
    """Where the work runs.

    Attributes
    ----------
    scheduler : str or None
        Address of an existing scheduler (``tcp://host:8786``); None starts a LocalCluster.
    workers : int
        Local worker processes (0: one per core).
    memory_limit : str
        Memory limit per local worker (Dask syntax, e.g. "4GB").
    shard_meshes : int
        Meshes per ingest/encode task.
    read_bytes : int
        A CityJSONSeq file (not gzipped) of more than twice this many bytes is read by several
        tasks in parallel, each about this many bytes of whole lines, so that no worker holds a
        whole city's meshes (:func:`meshsom.io.cityjsonseq_ranges`).
    read_features : int
        A GIS layer (GeoPackage, FileGDB, GeoParquet, ...) of more than twice this many features
        is read by several tasks in parallel, each this many features (:func:`meshsom.gis.gis_ranges`);
        so is an OpenStreetMap extract of, by its size, more than twice this many buildings, each
        task parsing the file and building the meshes of its range (:func:`meshsom.osm.osm_ranges`).
    dashboard : bool
        Serve the Dask dashboard (bokeh pages) of a LocalCluster on a free loopback port, and
        print its link; false: no dashboard is served.
    """

    scheduler: str | None = None
    workers: int = 0
    memory_limit: str = "4GB"
    shard_meshes: int = 64
    read_bytes: int = 256 << 20
    read_features: int = 20_000
    dashboard: bool = True

    def __post_init__(self):
        if self.workers < 0:
            raise ValueError(f"workers must be >= 0 (0: one per core), received {self.workers}")
        if self.shard_meshes < 1:
            raise ValueError(f"shard_meshes must be >= 1, received {self.shard_meshes}")
        if self.read_bytes < 1:
            raise ValueError(f"read_bytes must be >= 1, received {self.read_bytes}")
        if self.read_features < 1:
            raise ValueError(f"read_features must be >= 1, received {self.read_features}")
        if self.scheduler is not None and "://" not in self.scheduler:
            raise ValueError(f"scheduler must be an address like tcp://host:8786, received {self.scheduler!r}")


@dataclass(frozen=True)
class TrackingConfig:
    """MLflow tracking.

    Attributes
    ----------
    uri : str or None
        Tracking URI (``http://127.0.0.1:5000``, ``sqlite:///mlflow.db``: a relative SQLite path is
        relative to the config file's folder); None: MLflow's default (``MLFLOW_TRACKING_URI`` or a
        local SQLite store).
    experiment : str
    enabled : bool
    """

    uri: str | None = None
    experiment: str = "meshsom"
    enabled: bool = True


@dataclass(frozen=True)
class RunConfig(ExperimentConfig):
    """An experiment as ``meshsom run`` runs it: the experiment plus its cluster and tracking.

    Attributes
    ----------
    dask : DaskConfig
    tracking : TrackingConfig
        (and every section of :class:`meshsom.config.ExperimentConfig`)
    """

    dask: DaskConfig = DaskConfig()
    tracking: TrackingConfig = TrackingConfig()


def load_config(path: str | Path, overrides: dict | None = None, sets: Iterable[str] = ()) -> RunConfig:
    """Load and validate a run config (``configs/quick.yaml``), with overrides.

    Parameters
    ----------
    path : path
    overrides : dict, optional
        Nested mapping merged over the file (options such as ``--store``).
    sets : iterable of str
        ``--set KEY=VALUE`` items, merged last (:func:`meshsom.config.parse_sets`).

    Raises
    ------
    meshsom.errors.ConfigError
        Naming the file (or ``--set``) and the key.
    """
    return _load_config(path, overrides, sets, cls=RunConfig)


def _resolve(path: str, base: Path) -> str:
    if "://" in path:
        return path  # a URL (s3://, gs://, ...)
    p = Path(path).expanduser()
    return str(p if p.is_absolute() else (base / p).resolve())


def resolve_paths(cfg: RunConfig, base: str | Path) -> RunConfig:
    """``cfg`` with its relative paths made absolute against ``base`` (the config file's folder).

    Resolved: every ``corpus.paths`` entry, ``store.path`` and a ``sqlite:///`` tracking URI with a
    relative path. URLs and absolute paths stay as they are.
    """
    base = Path(base).resolve()
    corpus = dataclasses.replace(cfg.corpus, paths=tuple(_resolve(p, base) for p in cfg.corpus.paths))
    store = dataclasses.replace(cfg.store, path=_resolve(cfg.store.path, base))
    tracking = cfg.tracking
    prefix = "sqlite:///"
    if tracking.uri and tracking.uri.startswith(prefix) and not tracking.uri[len(prefix):].startswith("/"):
        tracking = dataclasses.replace(tracking, uri=prefix + _resolve(tracking.uri[len(prefix):], base))
    return dataclasses.replace(cfg, corpus=corpus, store=store, tracking=tracking)
