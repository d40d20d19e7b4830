"""The experiment pipeline end to end: a real MLflow server, a 2-worker LocalCluster, resume, errors."""

import os
import socket
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

import numpy as np
import pytest

from pipelines.settings import load_config
from meshsom.errors import ConfigError, MeshsomError
from meshsom.store import open_store
from pipelines.run import run_experiment

ROOT = Path(__file__).resolve().parents[1]


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def start_mlflow(tmp: Path, db: Path) -> tuple[subprocess.Popen, str]:
    """Start a real `mlflow server` (SQLite backend ``db``) on a free loopback port; wait for /health."""
    port = _free_port()
    mlflow_bin = Path(sys.executable).with_name("mlflow")
    log = open(tmp / f"server-{port}.log", "w")
    proc = subprocess.Popen(
        [str(mlflow_bin), "server", "--host", "127.0.0.1", "--port", str(port),
         "--backend-store-uri", f"sqlite:///{db}", "--artifacts-destination", str(tmp / "artifacts"),
         "--workers", "1"],
        stdout=log, stderr=subprocess.STDOUT, cwd=tmp,
    )
    uri = f"http://127.0.0.1:{port}"
    deadline = time.time() + 120
    while True:
        try:
            with urllib.request.urlopen(uri + "/health", timeout=2) as r:
                if r.status == 200:
                    return proc, uri
        except OSError:
            pass
        if proc.poll() is not None or time.time() > deadline:
            proc.kill()
            pytest.fail(f"mlflow server did not start: {(tmp / f'server-{port}.log').read_text()[-2000:]}")
        time.sleep(0.5)


def stop(proc: subprocess.Popen) -> None:
    """Stop a server started here, by PID (its gunicorn/uvicorn children go with its process group)."""
    proc.terminate()
    try:
        proc.wait(timeout=20)
    except subprocess.TimeoutExpired:
        proc.kill()


@pytest.fixture(scope="module")
def mlflow_server(tmp_path_factory):
    """A real `mlflow server` (SQLite backend) on a loopback port, stopped by PID at the end."""
    tmp = tmp_path_factory.mktemp("mlflow")
    proc, uri = start_mlflow(tmp, tmp / "mlflow.db")
    yield uri
    stop(proc)


def quick(tmp_path, **over):
    over = {"dask": {"workers": 2, "dashboard": False}, "store": {"path": str(tmp_path / "q.zarr")}} | over
    return load_config(ROOT / "configs" / "quick.yaml", over)


def test_quick_config_against_a_real_mlflow_server(tmp_path, mlflow_server):
    import mlflow

    cfg = quick(tmp_path, tracking={"uri": mlflow_server, "experiment": "it-quick"})
    assert run_experiment(cfg, ROOT / "configs" / "quick.yaml") == 0
    mlflow.set_tracking_uri(mlflow_server)
    runs = mlflow.search_runs(experiment_names=["it-quick"])
    parent = runs[runs["tags.mlflow.parentRunId"].isna()]
    children = runs[runs["tags.mlflow.parentRunId"].notna()]
    assert len(parent) == 1
    assert sorted(children["tags.map"]) == ["level1-bmuofn", "level1-default", "level2-bmuofn"]
    assert (children["tags.mlflow.parentRunId"] == parent["run_id"].iloc[0]).all()
    g = open_store(cfg.store.path)
    for _, child in children.iterrows():
        name = child["tags.map"]
        assert child["tags.mlflow.runName"] == f"quick/{name}/{g.attrs['mlflow']['short_id']}"
        final = g["runs"][name].attrs["metrics"]
        for k in ("t_error", "q_error", "qc_error"):
            assert child[f"metrics.{k}"] == pytest.approx(final[k])
        assert child["params.map_rows"] == "12" and child["params.kernel"] == name.split("-")[1]
        history = mlflow.tracking.MlflowClient(mlflow_server).get_metric_history(child["run_id"], "q_error")
        assert len(history) == cfg.som.epochs + 1  # one per epoch, and the final value
    # BMUofN beats the default kernel at level 1 on Q-error (the paper's first claim)
    by = {r["tags.map"]: r for _, r in children.iterrows()}
    assert by["level1-bmuofn"]["metrics.q_error"] < by["level1-default"]["metrics.q_error"]


def test_unreachable_tracking_server_stops_before_any_work(tmp_path):
    cfg = quick(tmp_path, tracking={"uri": f"http://127.0.0.1:{_free_port()}"})
    with pytest.raises(MeshsomError, match="cannot reach the MLflow tracking server at http://127.0.0.1"):
        run_experiment(cfg)
    assert not Path(cfg.store.path).exists()


def test_resume_after_interrupted_training_equals_uninterrupted(tmp_path, monkeypatch):
    import pipelines.train as train

    full = quick(tmp_path / "a", tracking={"enabled": False})
    assert run_experiment(full) == 0
    cut = quick(tmp_path / "b", tracking={"enabled": False})
    real = train.train_spec

    def crash_in_second_map(client, job, resume=False, on_epoch=None, **kw):
        if job.run == "level1-bmuofn" and not resume:
            def boom(epoch, metrics):
                if epoch == 3:
                    raise KeyboardInterrupt
            return real(client, job, resume, on_epoch=boom, **kw)
        return real(client, job, resume, on_epoch=on_epoch, **kw)

    monkeypatch.setattr(train, "train_spec", crash_in_second_map)
    with pytest.raises(KeyboardInterrupt):
        run_experiment(cut)
    monkeypatch.setattr(train, "train_spec", real)
    assert run_experiment(cut, resume=True) == 0
    a, b = open_store(full.store.path), open_store(cut.store.path)
    for name in ("level1-default", "level1-bmuofn", "level2-bmuofn"):
        assert np.array_equal(a["runs"][name]["weights"][:], b["runs"][name]["weights"][:])
        assert np.array_equal(a["runs"][name]["bmu_unit"][:], b["runs"][name]["bmu_unit"][:])
    assert b["runs"]["level1-bmuofn"].attrs["result"]["resumed_from"] == 4


@pytest.mark.parametrize("text, key", [("som: {rows: -3}", "som"), ("som: {rwos: 3}", "rwos"), ("dask: {workers: -1}", "dask")])
def test_config_errors_fail_fast_naming_the_key(tmp_path, text, key):
    p = tmp_path / "bad.yaml"
    p.write_text(text)
    with pytest.raises(ConfigError, match=key):
        load_config(p)


def test_mlflow_server_stopping_mid_run_then_meshsom_log(tmp_path, capsys):
    """Results stay in the store, the run says what could not be logged, `meshsom log` sends it later."""
    import threading

    import mlflow

    from pipelines.cli import main

    db = tmp_path / "mlflow.db"
    proc, uri = start_mlflow(tmp_path, db)
    cfg = quick(tmp_path, tracking={"uri": uri, "experiment": "outage"}, som={"rows": 12, "cols": 15, "epochs": 30})
    out = {}
    t = threading.Thread(target=lambda: out.update(rc=run_experiment(cfg)), daemon=True)
    t.start()

    def first_map_done():
        try:
            return open_store(cfg.store.path)["runs"]["level1-default"].attrs.get("final_done", False)
        except Exception:
            return False

    deadline = time.time() + 120
    while not first_map_done():
        assert time.time() < deadline and t.is_alive(), "the first map did not finish"
        time.sleep(0.02)
    stop(proc)
    t.join(300)
    assert out.get("rc") == 0
    said = capsys.readouterr().out
    assert "MLflow writes failed" in said and f"meshsom log {cfg.store.path} --tracking-uri" in said
    g = open_store(cfg.store.path)
    for name in ("level1-default", "level1-bmuofn", "level2-bmuofn"):
        assert g["runs"][name].attrs["final_done"]  # every result is in the store
    proc, uri2 = start_mlflow(tmp_path, db)  # the same database behind a new server
    try:
        assert main(["log", cfg.store.path, "--tracking-uri", uri2]) == 0
        assert main(["log", cfg.store.path, "--tracking-uri", uri2]) == 0  # idempotent
        client = mlflow.tracking.MlflowClient(uri2)
        children = open_store(cfg.store.path).attrs["mlflow"]["children"]
        assert sorted(children) == ["level1-bmuofn", "level1-default", "level2-bmuofn"]
        for name, rid in children.items():
            history = client.get_metric_history(rid, "q_error")
            assert sorted(m.step for m in history) == list(range(31)), name
            final = [m.value for m in history if m.step == 30][0]
            assert final == pytest.approx(g["runs"][name].attrs["metrics"]["q_error"])
    finally:
        stop(proc)


def test_read_only_output_path_fails_before_work(tmp_path):
    cfg = quick(tmp_path, tracking={"enabled": False}, store={"path": "/proc/meshsom-test.zarr"})
    with pytest.raises(MeshsomError, match="cannot write into /proc"):
        run_experiment(cfg)


def test_too_little_disk_space_fails_before_work(tmp_path, monkeypatch):
    import shutil
    from collections import namedtuple

    usage = namedtuple("usage", "total used free")
    monkeypatch.setattr(shutil, "disk_usage", lambda p: usage(10**9, 10**9 - 1000, 1000))
    cfg = quick(tmp_path, tracking={"enabled": False})
    with pytest.raises(MeshsomError, match=r"needs about .* MB, but only 0 MB are free"):
        run_experiment(cfg)
    assert not Path(cfg.store.path).exists()
