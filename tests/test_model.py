"""Every trained map as an MLflow pyfunc model: a tracked quick run, then the models answer like the store."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from tracked_quick import ROOT, tracked_quick_run

pytestmark = pytest.mark.timeout(900)


@pytest.fixture(scope="module")
def quick_run(tmp_path_factory):
    return tracked_quick_run(tmp_path_factory.mktemp("tracked"))


@pytest.fixture(scope="module")
def children(quick_run):
    """The map runs of the quick run: run name in the store -> MLflow run."""
    from mlflow.tracking import MlflowClient

    from meshsom.store import open_store

    client = MlflowClient(quick_run.uri)
    exp = client.get_experiment_by_name(quick_run.experiment)
    ids = dict(open_store(quick_run.store).attrs["mlflow"])["children"]
    assert set(ids) == {"level1-default", "level1-bmuofn", "level2-bmuofn"}
    return {name: client.get_run(rid) for name, rid in ids.items()} | {"_experiment": exp}


def _store_map(store, run):
    from meshsom.codebook import load_codebook
    from meshsom.store import open_store, read_stats, rings_array

    group = open_store(store)
    cb = load_codebook(group, run)
    return cb, np.asarray(rings_array(group, cb.level)[:]), read_stats(group, cb.level)


@pytest.mark.parametrize("run", ["level1-default", "level1-bmuofn", "level2-bmuofn"])
def test_child_model_predicts_the_stores_bmus_from_raw_vectors(quick_run, children, run):
    import mlflow

    mlflow.set_tracking_uri(quick_run.uri)
    child = children[run]
    cb, raw, _ = _store_map(quick_run.store, run)
    assert raw.dtype == np.float32 and len(raw) == len(cb.bmu.unit)
    for uri in (f"runs:/{child.info.run_id}/model", child.data.tags["model_uri"]):
        model = mlflow.pyfunc.load_model(uri)
        out = model.predict(raw)
        assert list(out.columns) == ["unit", "variation", "row", "col", "dist2", "second"]
        np.testing.assert_array_equal(out["unit"].to_numpy(), cb.bmu.unit)
        np.testing.assert_array_equal(out["variation"].to_numpy(), cb.bmu.variation)
        np.testing.assert_array_equal(out["second"].to_numpy(), cb.bmu.second)
        np.testing.assert_allclose(out["dist2"].to_numpy(), cb.bmu.dist2, rtol=1e-6, atol=1e-9)
        np.testing.assert_array_equal(out["row"] * cb.cols + out["col"], out["unit"])
        assert out["row"].between(0, cb.rows - 1).all() and out["col"].between(0, cb.cols - 1).all()
    # a DataFrame of the same float32 columns answers the same
    framed = model.predict(pd.DataFrame(raw))
    np.testing.assert_array_equal(framed["unit"].to_numpy(), cb.bmu.unit)


@pytest.mark.parametrize("run", ["level1-bmuofn", "level2-bmuofn"])
def test_prediction_equals_an_independent_search_over_every_variation(quick_run, children, run):
    """Brute force from the store: standardize by hand, every variation, every unit, full distance matrix."""
    import mlflow

    from meshsom.variations import variation_table

    mlflow.set_tracking_uri(quick_run.uri)
    cb, raw, stats = _store_map(quick_run.store, run)
    x = raw[:200].astype(np.float64).reshape(min(200, len(raw)), -1, 3)
    z = ((x - np.array(stats["mean"])) / np.array(stats["std"])).reshape(len(x), -1)
    index, sign = variation_table(cb.level, mirror=False, kernel=cb.kernel)
    varied = sign[None, :, :] * z[:, index]  # (N, n, D)
    d2 = ((varied[:, :, None, :] - cb.weights.astype(np.float64)[None, None]) ** 2).sum(-1)  # (N, n, M)
    best = d2.reshape(len(z), -1).argmin(axis=1)
    out = mlflow.pyfunc.load_model(f"runs:/{children[run].info.run_id}/model").predict(raw[:200])
    flat_best = out["variation"].to_numpy() * len(cb.weights) + out["unit"].to_numpy()
    # the same minimum distance (float32 search vs float64 brute force: ties may pick another pair)
    np.testing.assert_allclose(d2.reshape(len(z), -1)[np.arange(len(z)), flat_best],
                               d2.reshape(len(z), -1)[np.arange(len(z)), best], rtol=1e-4, atol=1e-5)
    assert (flat_best == best).mean() > 0.97


def test_model_packs_what_it_needs_and_no_local_path(quick_run, children):
    import mlflow
    from mlflow.artifacts import download_artifacts

    from meshsom.variations import variation_table

    mlflow.set_tracking_uri(quick_run.uri)
    run = "level2-bmuofn"
    cb, raw, stats = _store_map(quick_run.store, run)
    local = Path(download_artifacts(children[run].data.tags["model_uri"], tracking_uri=quick_run.uri))
    files = {p.relative_to(local).as_posix() for p in local.rglob("*") if p.is_file()}
    assert {"MLmodel", "python_model.pkl", "input_example.json", "requirements.txt", "artifacts/weights.npy",
            "artifacts/variation_index.npy", "artifacts/variation_sign.npy", "artifacts/map.json",
            "code/pipelines/model.py", "code/meshsom/bmu_numpy.py", "code/meshsom/standardize.py"} <= files
    meta = json.loads((local / "artifacts" / "map.json").read_text())
    assert (meta["rows"], meta["cols"], meta["topology"]) == (cb.rows, cb.cols, cb.topology)
    assert (meta["level"], meta["kernel"], meta["dims"], meta["variations"]) == (2, "bmuofn", 36, 3)
    assert meta["stats"] == stats
    np.testing.assert_array_equal(np.load(local / "artifacts" / "weights.npy"), cb.weights)
    index, sign = variation_table(2, mirror=False, kernel="bmuofn")
    np.testing.assert_array_equal(np.load(local / "artifacts" / "variation_index.npy"), index)
    np.testing.assert_array_equal(np.load(local / "artifacts" / "variation_sign.npy"), sign)
    # signature: raw float32 ring vectors of the level; the input example is the store's first rows
    model = mlflow.pyfunc.load_model(children[run].data.tags["model_uri"])
    assert model.metadata.signature.inputs.to_dict() == [
        {"type": "tensor", "tensor-spec": {"dtype": "float32", "shape": (-1, 36)}}]
    assert model.metadata.get_input_schema() is not None
    example = json.loads((local / "input_example.json").read_text())
    np.testing.assert_allclose(np.array(example["inputs"] if isinstance(example, dict) else example), raw[:5])
    # nothing names the store, the run's folder or the temporary packing folder (but MLmodel's
    # artifact_path: where the tracking server's artifact store keeps the model, local here)
    text = "\n".join((local / f).read_text(errors="replace") for f in files if not f.endswith((".npy", ".pkl")))
    text = "\n".join(line for line in text.splitlines() if not line.startswith("artifact_path: "))
    import tempfile

    for forbidden in (str(quick_run.folder), str(quick_run.store), tempfile.gettempdir() + "/", str(ROOT)):
        assert forbidden not in text, forbidden
    assert str(quick_run.folder).encode() not in (local / "python_model.pkl").read_bytes()


def test_model_loads_without_the_store_or_the_repository(quick_run, children, tmp_path):
    """A fresh interpreter that cannot import this checkout (as on a colleague's machine), store moved away."""
    run = "level1-bmuofn"
    cb, raw, _ = _store_map(quick_run.store, run)
    np.save(tmp_path / "raw.npy", raw)
    moved = quick_run.store.with_name("moved-away.zarr")
    script = f"""
import sys
from pathlib import Path
repo = Path({str(ROOT)!r}).resolve()
sys.path = [p for p in sys.path if p not in ('', '.') and Path(p).resolve() != repo]
sys.meta_path = [f for f in sys.meta_path if '__editable__' not in getattr(f, '__module__', '')]
try:
    import meshsom
    raise SystemExit('meshsom importable before loading: ' + meshsom.__file__)
except ModuleNotFoundError:
    pass
import numpy as np, mlflow
mlflow.set_tracking_uri({quick_run.uri!r})
out = mlflow.pyfunc.load_model('runs:/{children[run].info.run_id}/model').predict(np.load('raw.npy'))
import meshsom, pipelines.model
assert 'code' in Path(meshsom.__file__).parts and not Path(meshsom.__file__).resolve().is_relative_to(repo)
np.save('units.npy', out['unit'].to_numpy())
"""
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "MLFLOW_TRACKING_URI")}
    quick_run.store.rename(moved)
    try:
        proc = subprocess.run([sys.executable, "-c", script], cwd=tmp_path, env=env, capture_output=True, text=True,
                              timeout=300)
    finally:
        moved.rename(quick_run.store)
    assert proc.returncode == 0, proc.stderr[-3000:]
    np.testing.assert_array_equal(np.load(tmp_path / "units.npy"), cb.bmu.unit)


def test_logging_the_model_links_final_metrics_without_repeating_steps(quick_run, children):
    from mlflow.tracking import MlflowClient

    client = MlflowClient(quick_run.uri)
    for run in ("level1-default", "level1-bmuofn", "level2-bmuofn"):
        rid = children[run].info.run_id
        for key in ("t_error", "q_error", "qc_error"):
            steps = [m.step for m in client.get_metric_history(rid, key)]
            assert len(steps) == len(set(steps)), (run, key, steps)
        model = client.get_logged_model(children[run].data.tags["model_uri"].split("/")[-1])
        assert model.source_run_id == rid and model.experiment_id == children["_experiment"].experiment_id
        assert str(model.status).endswith("READY")
        linked = {m.key: m.value for m in model.metrics or []}
        assert linked.get("q_error") == pytest.approx(children[run].data.metrics["q_error"])


def test_log_model_failures_are_recorded_not_raised(quick_run, tmp_path):
    from pipelines.settings import TrackingConfig
    from meshsom.store import open_store
    from pipelines.tracking import Tracker

    tracker = Tracker(TrackingConfig(uri=f"sqlite:///{tmp_path / 'other.db'}", experiment="x"))
    tracker.open()
    group = open_store(quick_run.store)
    # a map the store does not have: recorded, and the tracker stays online
    assert tracker.log_model("0" * 32, group, "no-such-map") is None
    assert tracker.failed[-1]["what"] == "model" and "no-such-map" in tracker.failed[-1]["error"]
    assert not tracker.offline
    # a run MLflow does not know: recorded like every failed write
    assert tracker.log_model("0" * 32, group, "level1-bmuofn") is None
    assert tracker.failed[-1]["what"] == "model" and tracker.offline


def test_predict_units_rejects_vectors_of_another_level():
    from pipelines.model import predict_units

    weights = np.zeros((4, 9), np.float32)
    stats = {"mean": [3.0, 0.0, 1.0], "std": [1.0, 1.0, 1.0]}
    index, sign = np.arange(9)[None], np.ones((1, 9), np.float32)
    with pytest.raises(ValueError, match=r"shape \(N, 9\), received \(2, 36\)"):
        predict_units(np.zeros((2, 36)), weights, stats, index, sign, cols=2)
