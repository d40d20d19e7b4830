"""Reading tracked experiments: a finished pipeline run, its map runs and its store.

Every report script reads the same things (DESIGN.md §7): a *finished* parent run of an MLflow
experiment (a pipeline run: no ``mlflow.parentRunId`` tag, its ``store`` tag the absolute path of
its zarr store or its URL on object storage), either the experiment's latest (:func:`load_experiment`) or one chosen by its run
id (:func:`load_run`); its child runs (one per triangle map, named ``level1-default``,
``level1-bmuofn``, ``level2-bmuofn``, ...); and the store. Reports never write to MLflow.

The command-line options shared by every script are added by :func:`add_common_arguments`.
"""

from __future__ import annotations

import argparse
import re
import sys
from dataclasses import dataclass, field
from pathlib import Path

from meshsom.errors import MeshsomError

__all__ = [
    "DEFAULT_EXPERIMENT", "MapRun", "ReportError", "TrackedExperiment", "add_common_arguments", "load_experiment",
    "load_from_args", "load_run", "resolve_uri", "run_main",
]

#: Experiment read when none is named: the paper's (configs/paper.yaml).
DEFAULT_EXPERIMENT = "paper"
#: MLflow tag naming a child run's parent.
PARENT_TAG = "mlflow.parentRunId"
#: Tag of a pipeline run holding the absolute path of its store (or its URL: ``s3://bucket/name.zarr``).
STORE_TAG = "store"
#: Most runs of one experiment looked at when searching for the latest pipeline run.
MAX_RUNS = 5000
#: Child run names: ``level<L>-<kernel>``.
RUN_NAME = re.compile(r"^level(\d+)-(\w+)$")


class ReportError(MeshsomError, RuntimeError):
    """What a report needs is not tracked: no such experiment, no finished run, no store."""


@dataclass(frozen=True)
class MapRun:
    """One triangle map of a pipeline run (an MLflow child run).

    Attributes
    ----------
    name : str
        ``level<L>-<kernel>``, also the run's folder ``runs/<name>`` in the store.
    run_id : str
    level : int
    kernel : str
    params : dict of str to str
    metrics : dict of str to float
        The latest value of every metric (the final one: step = epochs).
    """

    name: str
    run_id: str
    level: int
    kernel: str
    params: dict = field(repr=False)
    metrics: dict = field(repr=False)


@dataclass(frozen=True)
class TrackedExperiment:
    """The latest finished pipeline run of an experiment.

    Attributes
    ----------
    uri : str
        Tracking URI it was read from.
    experiment : str
    run_id : str
        The parent run.
    params : dict of str to str
        The flattened config (``som.rows``, ``domain.rows``, ...).
    tags : dict of str to str
    store : str
        From the ``store`` tag: a local path or a URL (:func:`meshsom.store.open_store` takes both).
    maps : dict of str to MapRun
        Child runs by name, in training order (level, then default before BMUofN).
    """

    uri: str
    experiment: str
    run_id: str
    params: dict = field(repr=False)
    tags: dict = field(repr=False)
    store: str
    maps: dict = field(repr=False)

    def find(self, level: int, kernel: str = "bmuofn") -> MapRun | None:
        """The map of a level and kernel, or None when this run did not train it."""
        return self.maps.get(f"level{level}-{kernel}")

    @property
    def levels(self) -> list[int]:
        """Levels with at least one trained map, ascending."""
        return sorted({m.level for m in self.maps.values()})

    def open_store(self):
        """The run's zarr store (read only).

        Raises
        ------
        ReportError
            When the store named by the ``store`` tag is gone.
        """
        from meshsom.store import open_store

        try:
            return open_store(self.store, mode="r")
        except MeshsomError as err:
            raise ReportError(f"experiment {self.experiment!r} at {self.uri}, run {self.run_id}: "
                              f"its store {self.store} cannot be read ({err})") from None

    def param(self, key: str, cast=str):
        """A flattened config value (``domain.rows``), cast; ReportError naming the key when absent."""
        if key not in self.params:
            raise ReportError(f"experiment {self.experiment!r} at {self.uri}, run {self.run_id}: "
                              f"has no param {key!r}")
        return cast(self.params[key])


def resolve_uri(uri: str | None) -> str:
    """The tracking URI to read: ``uri``, else MLflow's default (``MLFLOW_TRACKING_URI`` or ./mlflow.db)."""
    if uri:
        return uri
    import mlflow

    return mlflow.get_tracking_uri()


def _sort_key(name: str) -> tuple:
    m = RUN_NAME.match(name)
    return (int(m.group(1)), m.group(2) != "default", name) if m else (1 << 30, True, name)


def _client(uri: str | None):
    from mlflow.tracking import MlflowClient

    uri = resolve_uri(uri)
    return uri, MlflowClient(tracking_uri=uri)


def _tracked(client, uri: str, experiment: str, parent, runs=None) -> TrackedExperiment:
    """A pipeline run and its map runs; ``runs``: the experiment's runs already searched, or None."""
    pid = parent.info.run_id
    if STORE_TAG not in parent.data.tags:
        raise ReportError(f"MLflow at {uri}, experiment {experiment!r}: run {pid} has no {STORE_TAG!r} tag "
                          "(was it made by `meshsom run`?)")
    if runs is None:
        runs = client.search_runs([parent.info.experiment_id], filter_string=f"tags.`{PARENT_TAG}` = '{pid}'",
                                  max_results=MAX_RUNS)
    maps: dict = {}
    for r in sorted(runs, key=lambda r: r.info.start_time):  # later attempts replace earlier ones
        if r.data.tags.get(PARENT_TAG) != pid:
            continue
        name = r.data.tags.get("map") or r.info.run_name or r.data.tags.get("mlflow.runName", "")  # map: its store name
        params = dict(r.data.params)
        m = RUN_NAME.match(name)
        level = int(params.get("level", m.group(1) if m else 0))
        kernel = params.get("kernel", m.group(2) if m else "")
        maps[name] = MapRun(name, r.info.run_id, level, kernel, params, dict(r.data.metrics))
    maps = {k: maps[k] for k in sorted(maps, key=_sort_key)}
    return TrackedExperiment(uri, experiment, pid, dict(parent.data.params), dict(parent.data.tags),
                             parent.data.tags[STORE_TAG], maps)


def load_experiment(uri: str | None, experiment: str) -> TrackedExperiment:
    """Read the latest finished pipeline run of ``experiment`` and its map runs.

    Parameters
    ----------
    uri : str or None
        Tracking URI; None: MLflow's default.
    experiment : str
        MLflow experiment name (``tracking.experiment`` of the config).

    Returns
    -------
    TrackedExperiment

    Raises
    ------
    ReportError
        No such experiment, no finished pipeline run in it, or the run has no ``store`` tag;
        the message names the URI and the experiment.
    """
    uri, client = _client(uri)
    try:
        exp = client.get_experiment_by_name(experiment)
    except Exception as err:  # MLflow and its HTTP client raise many types
        raise ReportError(f"cannot read MLflow at {uri}: {type(err).__name__}: {err}") from None
    if exp is None:
        raise ReportError(f"MLflow at {uri} has no experiment {experiment!r} "
                          f"(run `meshsom run configs/<config>.yaml` with tracking.experiment: {experiment} first)")
    runs = client.search_runs([exp.experiment_id], filter_string="attributes.status = 'FINISHED'",
                              order_by=["attributes.start_time DESC"], max_results=MAX_RUNS)
    parents = [r for r in runs if PARENT_TAG not in r.data.tags]
    if not parents:
        raise ReportError(f"MLflow at {uri}, experiment {experiment!r}: no finished pipeline run "
                          f"(a run without a parent, status FINISHED); found {len(runs)} finished runs in all")
    return _tracked(client, uri, experiment, parents[0], runs)


def load_run(uri: str | None, run_id: str) -> TrackedExperiment:
    """Read one pipeline run by its MLflow run id, and its map runs.

    Parameters
    ----------
    uri : str or None
        Tracking URI; None: MLflow's default.
    run_id : str
        The parent run's id (``meshsom run`` prints it; ``mlflow ui`` shows it).

    Returns
    -------
    TrackedExperiment
        ``experiment`` is the name of the experiment the run belongs to.

    Raises
    ------
    ReportError
        No run with this id, the run is a map run (a child) rather than a pipeline run, it has not
        finished, or it has no ``store`` tag; the message names the id and the URI.
    """
    uri, client = _client(uri)
    try:
        run = client.get_run(run_id)
    except Exception as err:  # MlflowException (RESOURCE_DOES_NOT_EXIST), or the server is unreachable
        if "RESOURCE_DOES_NOT_EXIST" in str(getattr(err, "error_code", "")) or "not found" in str(err).lower():
            raise ReportError(f"MLflow at {uri} has no run with id {run_id!r} "
                              "(give the id of a pipeline run: `mlflow ui` or `meshsom run`'s output show it)") from None
        raise ReportError(f"cannot read run {run_id!r} from MLflow at {uri}: {type(err).__name__}: {err}") from None
    experiment = client.get_experiment(run.info.experiment_id).name
    parent = run.data.tags.get(PARENT_TAG)
    if parent:
        raise ReportError(f"MLflow at {uri}: run {run_id!r} ({run.info.run_name}) is a map run of pipeline run "
                          f"{parent!r} in experiment {experiment!r}; give the pipeline run's id")
    if run.info.status != "FINISHED":
        raise ReportError(f"MLflow at {uri}, experiment {experiment!r}: run {run_id!r} has status "
                          f"{run.info.status}, expected FINISHED")
    return _tracked(client, uri, experiment, run)


def add_common_arguments(p: argparse.ArgumentParser, experiment: str = DEFAULT_EXPERIMENT) -> None:
    """``--tracking-uri``, ``--experiment`` and ``--out DIR``, as every report script takes them."""
    p.add_argument("--tracking-uri", help="MLflow tracking URI (default: MLFLOW_TRACKING_URI or ./mlflow.db)")
    p.add_argument("--experiment", default=experiment,
                   help=f"MLflow experiment whose latest finished pipeline run is read (default: {experiment})")
    p.add_argument("--run", dest="run_id", metavar="ID",
                   help="MLflow id of the pipeline run to read (instead of the experiment's latest)")
    p.add_argument("--out", type=Path, default=Path("."), help="folder to write into (created; default: .)")


def load_from_args(args: argparse.Namespace) -> TrackedExperiment:
    """The run chosen by :func:`add_common_arguments`' options: ``--run ID``, else ``--experiment``'s latest."""
    if getattr(args, "run_id", None):
        return load_run(args.tracking_uri, args.run_id)
    return load_experiment(args.tracking_uri, args.experiment)


def run_main(fn, argv, prog: str) -> int:
    """Call a report's body and turn a ReportError into a message on stderr and exit code 2."""
    try:
        return int(fn(argv) or 0)
    except ReportError as err:
        print(f"{prog}: error: {err}", file=sys.stderr)
        return 2
