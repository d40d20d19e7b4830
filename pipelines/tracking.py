"""MLflow tracking: the only module that writes to MLflow.

One parent run per pipeline run; one child run per (level, kernel) with params,
per-epoch metrics (``step=epoch``), final metrics, artifacts and tags. Uses
``MlflowClient`` with explicit run ids (no global active-run state), so a
resumed pipeline continues the same runs.

Conventions (what ``meshsom run`` writes):

- Run names (:func:`run_name`): parent ``quick/ab12cd`` (config name, short id), child
  ``quick/level1-bmuofn/ab12cd``; the short id is drawn once per store and kept on resume.
- Tags: MLflow's own ``mlflow.source.name``, ``mlflow.source.type``, ``mlflow.source.git.commit``,
  ``mlflow.source.git.branch`` (:func:`source_tags`); on the parent ``store`` (a URL as given, a
  local store as its path) and ``dataset_fingerprint``; on a child ``map`` (its name in the store,
  ``runs/<map>``) and the engine tags (backend, device, kernel layout, fallback).
- Params: the parent holds the configuration as run (file, options and ``--set``, defaults
  filled in; paths as written), flattened (``som.epochs``), and as the artifact
  ``config/config.yaml``; a child holds its map's settings and ``codebook`` = ``runs/<map>``,
  relative to the store. No param holds a local absolute path the config did not give.
- Metrics: a child's ``t_error``, ``q_error``, ``qc_error`` per epoch at ``step=epoch`` and the final
  errors at ``step=epochs``, each step logged once (a resumed run skips the steps MLflow has);
  ``wall_seconds``, ``seconds_per_epoch``, ``triangles_per_second`` at ``step=epochs``. The parent
  has the summary: ``<map>.t_error`` (and q, qc), ``<map>.seconds``, ``total_seconds``.

Metrics are always written to the store first; when the tracking server
cannot be reached mid-run, the failures are collected (``Tracker.failed``) and
the pipeline reports them; ``meshsom log`` can send them later from the store.
"""

from __future__ import annotations

import logging
import os
import subprocess
import urllib.error
import urllib.request
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from meshsom.errors import MeshsomError
from pipelines.settings import TrackingConfig

log = logging.getLogger(__name__)

#: Seconds to wait for a tracking server's health check before giving up.
HEALTH_TIMEOUT_S = 5.0
#: MLflow HTTP client limits set (unless the user set them) for a remote server.
HTTP_LIMITS = {"MLFLOW_HTTP_REQUEST_MAX_RETRIES": "1", "MLFLOW_HTTP_REQUEST_TIMEOUT": "10",
               "MLFLOW_HTTP_REQUEST_BACKOFF_FACTOR": "1"}


class TrackingError(MeshsomError, RuntimeError):
    """The tracking server cannot be reached or refused a request."""


def resolve_uri(config: TrackingConfig) -> str:
    """The tracking URI in force: the config's, else MLflow's own default."""
    if config.uri:
        return config.uri
    import mlflow

    return mlflow.get_tracking_uri()


def check_reachable(uri: str) -> None:
    """Raise TrackingError, naming the URI, when an HTTP tracking server does not answer.

    Local stores (``sqlite:``, ``file:``, plain paths) are checked for writability.
    """
    if uri.startswith(("http://", "https://")):
        url = uri.rstrip("/") + "/health"
        try:
            with urllib.request.urlopen(url, timeout=HEALTH_TIMEOUT_S) as resp:
                if resp.status != 200:
                    raise TrackingError(f"MLflow tracking server {uri} answered {resp.status} to {url}")
        except (urllib.error.URLError, OSError) as err:
            reason = getattr(err, "reason", err)
            raise TrackingError(f"cannot reach the MLflow tracking server at {uri}: {reason}") from None
        return
    if uri.startswith("sqlite:///"):
        path = Path(uri[len("sqlite:///"):])
        folder = path.parent if str(path.parent) else Path(".")
        folder.mkdir(parents=True, exist_ok=True)
        if not os.access(folder, os.W_OK):
            raise TrackingError(f"MLflow store {uri}: cannot write into {folder}")


def _git(*args: str) -> str:
    """Output of a git command in the source tree, or '' (no git, not a checkout)."""
    try:
        out = subprocess.run(["git", *args], capture_output=True, text=True, timeout=5,
                             cwd=Path(__file__).resolve().parents[1])
    except (OSError, subprocess.SubprocessError):
        return ""
    return out.stdout.strip() if out.returncode == 0 else ""


def source_tags(name: str) -> dict[str, str]:
    """MLflow's own source tags (``mlflow.source.*``) for a run started by ``name`` (``meshsom run quick.yaml``).

    Gives ``mlflow.source.name``, ``mlflow.source.type`` (LOCAL) and, where the source tree is a
    git checkout, ``mlflow.source.git.commit``, ``mlflow.source.git.branch`` and
    ``mlflow.source.git.repoURL`` (the ``origin`` remote).
    """
    tags = {"mlflow.source.name": name, "mlflow.source.type": "LOCAL"}
    commit = _git("rev-parse", "HEAD")
    if commit:
        tags["mlflow.source.git.commit"] = commit
        branch = _git("rev-parse", "--abbrev-ref", "HEAD")
        if branch and branch != "HEAD":
            tags["mlflow.source.git.branch"] = branch
        remote = _git("remote", "get-url", "origin")
        if remote:
            tags["mlflow.source.git.repoURL"] = remote
    return tags


#: Hex digits of the short id that makes run names unique (``quick/ab12cd``).
SHORT_ID_LEN = 6


def new_short_id() -> str:
    """A fresh random short id for the run names of one pipeline run."""
    import uuid

    return uuid.uuid4().hex[:SHORT_ID_LEN]


def run_name(config_name: str, short_id: str, map_name: str | None = None) -> str:
    """``quick/ab12cd`` (a pipeline run), ``quick/level1-bmuofn/ab12cd`` (one of its maps)."""
    return f"{config_name}/{map_name}/{short_id}" if map_name else f"{config_name}/{short_id}"


def _param_value(v: Any) -> str:
    s = str(v)
    return s if len(s) <= 500 else s[:497] + "..."


class Tracker:
    """Writes one pipeline run to MLflow.

    Parameters
    ----------
    config : TrackingConfig
    """

    def __init__(self, config: TrackingConfig):
        self.config = config
        self.uri = resolve_uri(config)
        self.enabled = config.enabled
        self.failed: list[dict] = []
        self.offline = False  # set at the first failed write: later writes are only recorded
        self._client = None
        self.experiment_id = None
        self.open_runs: list[str] = []  # started or reopened, not finished yet

    @property
    def client(self):
        if self._client is None:
            from mlflow.tracking import MlflowClient

            self._client = MlflowClient(tracking_uri=self.uri)
        return self._client

    def open(self) -> None:
        """Check the server and get the experiment; raises TrackingError before any heavy work."""
        if not self.enabled:
            return
        if self.uri.startswith(("http://", "https://")):
            # fail fast when the server goes away mid-run (the results are in the store anyway)
            for key, value in HTTP_LIMITS.items():
                os.environ.setdefault(key, value)
        check_reachable(self.uri)
        try:
            exp = self.client.get_experiment_by_name(self.config.experiment)
            self.experiment_id = exp.experiment_id if exp else self.client.create_experiment(self.config.experiment)
        except Exception as err:  # MLflow raises its own and requests' errors
            raise TrackingError(f"MLflow at {self.uri}: cannot open experiment {self.config.experiment!r}: {err}") from None

    def start(self, name: str, params: dict, tags: dict, parent: str | None = None, run_id: str | None = None) -> str | None:
        """Start (or, with ``run_id``, reopen) a run; returns its id."""
        if not self.enabled:
            return None
        if run_id:
            try:
                self.client.update_run(run_id, status="RUNNING")
                self.open_runs.append(run_id)
                return run_id
            except Exception as err:
                log.warning("cannot reopen MLflow run %s (%s); starting a new one", run_id, err)
        all_tags = {"mlflow.runName": name, **{k: str(v) for k, v in tags.items()}}
        if parent:
            all_tags["mlflow.parentRunId"] = parent
        if self.offline:
            self.failed.append({"what": "start", "run_id": None, "name": name, "error": "tracking server unreachable"})
            return None
        try:
            run = self.client.create_run(self.experiment_id, tags=all_tags, run_name=name)
        except Exception as err:
            self.failed.append({"what": "start", "run_id": None, "name": name, "error": f"{type(err).__name__}: {err}"})
            log.warning("MLflow: cannot start run %s: %s; later writes are skipped", name, err)
            self.offline = True
            return None
        rid = run.info.run_id
        self.open_runs.append(rid)
        self.log_params(rid, params)
        return rid

    def _safe(self, what: str, run_id: str | None, fn, **record) -> None:
        if not self.enabled or run_id is None:
            return
        if self.offline:
            self.failed.append({"what": what, "run_id": run_id, "error": "tracking server unreachable", **record})
            return
        try:
            fn()
        except Exception as err:
            self.failed.append({"what": what, "run_id": run_id, "error": f"{type(err).__name__}: {err}", **record})
            log.warning("MLflow %s failed for run %s: %s; later writes are skipped (`meshsom log` sends them "
                        "from the store)", what, run_id, err)
            self.offline = True

    def log_params(self, run_id: str | None, params: dict) -> None:
        from mlflow.entities import Param

        items = [Param(k, _param_value(v)) for k, v in params.items()]
        for i in range(0, len(items), 100):
            chunk = items[i:i + 100]
            self._safe("params", run_id, lambda c=chunk: self.client.log_batch(run_id, params=c))

    def log_metrics(self, run_id: str | None, metrics: dict[str, float], step: int | None = None) -> None:
        import time

        from mlflow.entities import Metric

        ts = int(time.time() * 1000)
        items = [Metric(k, float(v), ts, int(step or 0)) for k, v in metrics.items()]
        if not items:
            return
        self._safe("metrics", run_id, lambda: self.client.log_batch(run_id, metrics=items), metrics=dict(metrics), step=step)

    def logged_steps(self, run_id: str | None, key: str) -> set[int]:
        """Steps of metric ``key`` that run ``run_id`` has already (empty when off or unreachable)."""
        if not self.enabled or run_id is None or self.offline:
            return set()
        try:
            return {m.step for m in self.client.get_metric_history(run_id, key)}
        except Exception as err:  # MLflow raises its own and requests' errors
            log.warning("MLflow: cannot read the history of %s of run %s: %s", key, run_id, err)
            return set()

    def set_tags(self, run_id: str | None, tags: dict) -> None:
        from mlflow.entities import RunTag

        items = [RunTag(k, str(v)) for k, v in tags.items()]
        self._safe("tags", run_id, lambda: self.client.log_batch(run_id, tags=items))

    def log_artifact(self, run_id: str | None, path: str | Path, folder: str | None = None) -> None:
        self._safe("artifact", run_id, lambda: self.client.log_artifact(run_id, str(path), folder), path=str(path))

    def log_text(self, run_id: str | None, text: str, artifact_file: str) -> None:
        """Write ``text`` as artifact ``artifact_file`` (``config/config.yaml``) of a run."""
        self._safe("artifact", run_id, lambda: self.client.log_text(run_id, text, artifact_file), path=artifact_file)

    def finish(self, run_id: str | None, status: str = "FINISHED") -> None:
        if run_id in self.open_runs:
            self.open_runs.remove(run_id)
        self._safe("finish", run_id, lambda: self.client.set_terminated(run_id, status))

    def end_open(self, status: str) -> None:
        """End every run still open (children first) with ``status``: "FAILED" or "KILLED"."""
        for run_id in reversed(list(self.open_runs)):
            self.finish(run_id, status)

    @contextmanager
    def run(self, name: str, params: dict, tags: dict, parent: str | None = None, run_id: str | None = None):
        """Context manager around :meth:`start` / :meth:`finish` (FAILED on an exception)."""
        rid = self.start(name, params, tags, parent, run_id)
        try:
            yield rid
        except BaseException:
            self.finish(rid, "FAILED")
            raise
        self.finish(rid)

    def log_model(self, run_id: str | None, group, run: str, step: int = 0) -> str | None:
        """Log a trained map of the store as the MLflow pyfunc model ``model`` of run ``run_id``.

        The model packs the codebook, the level's standardization statistics, the variation
        table and the map's geometry, with the code that predicts (:mod:`pipelines.model`), a
        signature and an input example; it never refers to the store or any other local path.
        The run gets the tag ``model_uri``.

        Parameters
        ----------
        run_id : str or None
        group : zarr.Group
            The store root.
        run : str
            The map under ``runs/``.
        step : int
            Step of the run's metrics that MLflow links to the model (the final errors').

        Returns
        -------
        str or None
            The model's URI (``models:/<id>``), or None when tracking is off or the write failed
            (recorded in :attr:`failed`, like every other write).
        """
        if not self.enabled or run_id is None:
            return None
        if self.offline:  # recorded like every write after the server went away; nothing packed
            self._safe("model", run_id, lambda: None, name=run)
            return None
        import tempfile
        import warnings

        with warnings.catch_warnings():  # MLflow asks every PythonModel subclass for type hints
            warnings.simplefilter("ignore", UserWarning)
            from pipelines.model import MapModel, pack_map, packing_folder, pip_requirements

        with tempfile.TemporaryDirectory(prefix=".meshsom-model-", dir=packing_folder()) as tmp:
            try:
                package = pack_map(group, run, tmp)
            except (MeshsomError, OSError, ValueError) as err:  # the store, not the server: stay online
                self.failed.append({"what": "model", "run_id": run_id, "name": run, "error": f"{type(err).__name__}: {err}"})
                log.warning("cannot pack map %s as an MLflow model: %s", run, err)
                return None
            info: dict = {}

            def write():
                import mlflow.pyfunc
                from mlflow.models import Model, infer_signature
                from mlflow.tracking._tracking_service.utils import _use_tracking_uri

                # the model belongs to the run's experiment (Model.log alone would file it under the
                # default one) and carries the map's description as params
                experiment = self.client.get_run(run_id).info.experiment_id
                created = self.client.create_logged_model(
                    experiment, name="model", source_run_id=run_id, model_type="meshsom-triangle-map",
                    params={k: _param_value(v) for k, v in package.meta.items() if k not in ("stats", "metrics")},
                )
                with _keep_tracking_env(), _use_tracking_uri(self.uri), warnings.catch_warnings(), _quiet_mlflow():
                    warnings.simplefilter("ignore", UserWarning)  # integer columns in the signature
                    model = Model.log(
                        artifact_path=None, name="model", flavor=mlflow.pyfunc, run_id=run_id, step=int(step),
                        model_id=created.model_id, python_model=MapModel(), artifacts=package.artifact_uris(),
                        code_paths=package.code_paths, input_example=package.input_example,
                        signature=infer_signature(package.input_example, package.output_example),
                        pip_requirements=pip_requirements(),
                    )
                self.client.finalize_logged_model(created.model_id, "READY")
                info["uri"] = model.model_uri
                self.client.set_tag(run_id, "model_uri", model.model_uri)

            self._safe("model", run_id, write, name=run)
        return info.get("uri")


@contextmanager
def _quiet_mlflow():
    """MLflow's model-logging chatter (pickling advice, signature checks, download bars) off, then back."""
    names = ("mlflow.pyfunc", "mlflow.models", "mlflow.models.model")
    levels = {n: logging.getLogger(n).level for n in names}
    bar = os.environ.get("MLFLOW_ENABLE_ARTIFACTS_PROGRESS_BAR")
    os.environ["MLFLOW_ENABLE_ARTIFACTS_PROGRESS_BAR"] = "false"
    for n in names:
        logging.getLogger(n).setLevel(logging.ERROR)
    try:
        yield
    finally:
        for n, level in levels.items():
            logging.getLogger(n).setLevel(level)
        if bar is None:
            os.environ.pop("MLFLOW_ENABLE_ARTIFACTS_PROGRESS_BAR", None)
        else:
            os.environ["MLFLOW_ENABLE_ARTIFACTS_PROGRESS_BAR"] = bar


@contextmanager
def _keep_tracking_env():
    """Restore ``MLFLOW_TRACKING_URI`` on exit: MLflow's ``_use_tracking_uri`` unsets it when it
    restores a global URI that was never set, and the user's next run would fall back to the default."""
    before = os.environ.get("MLFLOW_TRACKING_URI")
    try:
        yield
    finally:
        if before is None:
            os.environ.pop("MLFLOW_TRACKING_URI", None)
        else:
            os.environ["MLFLOW_TRACKING_URI"] = before
