"""`meshsom run` when OpenCL misbehaves: the fallback chain on a real LocalCluster, recorded in MLflow
and in the store; failed and interrupted runs end their MLflow runs as FAILED and KILLED.

Failures are injected with the probe's test hook ``MESHSOM_KERNEL_INJECT`` (inherited by the Dask
worker processes); each test has its own verdict cache.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from pipelines.settings import load_config
from meshsom.errors import DeviceError
from meshsom.store import open_store
from pipelines.run import run_experiment

ROOT = Path(__file__).resolve().parents[1]
pytestmark = pytest.mark.usefixtures("fresh_verdicts")


@pytest.fixture
def chain():
    """A chain of three layouts that every CPU builds, whatever chain its own CPU would get (the
    first device's chain is two long where PoCL's kernel target has no AVX-512); skips without a
    CPU OpenCL device."""
    try:
        import pyopencl as cl

        from meshsom.bmu_opencl import CHAINS, get_context

        device = get_context(None).devices[0]
    except (DeviceError, ImportError) as err:
        pytest.skip(f"no OpenCL device: {err}")
    if not device.type & cl.device_type.CPU:
        pytest.skip(f"not a CPU device: {device.name}")
    return CHAINS["cpu"]


def small(tmp_path, name, **over):
    """configs/quick.yaml with one BMUofN map and no domain maps, tracked in a local SQLite store."""
    over = {
        "dask": {"workers": 2, "dashboard": False}, "store": {"path": str(tmp_path / f"{name}.zarr")},
        "train": [{"level": 1, "kernel": "bmuofn"}], "domain": {"enabled": False},
        "tracking": {"uri": f"sqlite:///{tmp_path / 'mlflow.db'}", "experiment": name},
    } | over
    return load_config(ROOT / "configs" / "quick.yaml", over)


def runs_of(cfg):
    from mlflow.tracking import MlflowClient

    client = MlflowClient(cfg.tracking.uri)
    exp = client.get_experiment_by_name(cfg.tracking.experiment)
    return client.search_runs([exp.experiment_id])


def test_run_completes_on_the_next_layout_with_that_layouts_results(tmp_path, monkeypatch, chain, capsys):
    from meshsom.probe import ENV_INJECT

    alone = small(tmp_path, "alone", opencl={"backend": "opencl", "layout": chain[2]})
    assert run_experiment(alone) == 0
    monkeypatch.setenv(ENV_INJECT, f"{chain[0]}=error,{chain[1]}=trap")
    fell = small(tmp_path, "fell", opencl={"backend": "opencl", "layout": ",".join(chain)})
    assert run_experiment(fell) == 0
    out = capsys.readouterr().out
    assert f"BMU search: opencl {chain[2]}" in out and f"kernel fallback: {chain[0]} -> {chain[1]}" in out

    a, b = open_store(alone.store.path)["runs"]["level1-bmuofn"], open_store(fell.store.path)["runs"]["level1-bmuofn"]
    np.testing.assert_array_equal(a["weights"][:], b["weights"][:])
    np.testing.assert_array_equal(a["bmu_unit"][:], b["bmu_unit"][:])
    assert a.attrs["metrics"] == b.attrs["metrics"]
    engine = b.attrs["engine"]
    assert engine["backend"] == "opencl" and engine["layout"] == chain[2]
    assert f"{chain[0]} -> {chain[1]}" in engine["fallback"] and "injected build failure" in engine["fallback"]
    assert f"{chain[1]} -> {chain[2]}" in engine["fallback"] and "killed its process" in engine["fallback"]
    assert a.attrs["engine"]["fallback"] == ""

    runs = {r.data.tags.get("map", "parent"): r for r in runs_of(fell)}
    child, parent = runs["level1-bmuofn"], runs["parent"]
    assert child.info.status == "FINISHED" and parent.info.status == "FINISHED"
    assert child.data.tags["kernel_layout"] == chain[2] and child.data.tags["backend"] == "opencl"
    assert child.data.tags["kernel_fallback"] == engine["fallback"]
    assert parent.data.tags["kernel_layouts"] == chain[2] and chain[0] in parent.data.tags["kernel_fallback"]
    assert runs_of(alone)[0].data.tags["kernel_fallback"] == "none"


def test_failing_run_leaves_failed_mlflow_runs(tmp_path, monkeypatch, chain):
    from meshsom.probe import ENV_INJECT

    monkeypatch.setenv(ENV_INJECT, ",".join(f"{name}=error" for name in chain))
    cfg = small(tmp_path, "failing", opencl={"backend": "opencl", "layout": ",".join(chain)})
    with pytest.raises(DeviceError, match="no BMUofN kernel layout works on .*--backend numpy"):
        run_experiment(cfg)
    runs = runs_of(cfg)
    assert {r.data.tags.get("map", "parent") for r in runs} == {"parent", "level1-bmuofn"}
    assert {r.info.status for r in runs} == {"FAILED"}


def test_interrupted_run_leaves_killed_mlflow_runs(tmp_path, monkeypatch):
    import pipelines.train as train

    real = train.train_spec

    def interrupted(client, job, resume=False, on_epoch=None, **kw):
        def stop(epoch, metrics):
            if epoch == 2:
                raise KeyboardInterrupt
        return real(client, job, resume, on_epoch=stop, **kw)

    monkeypatch.setattr(train, "train_spec", interrupted)
    cfg = small(tmp_path, "interrupted", opencl={"backend": "numpy"})
    with pytest.raises(KeyboardInterrupt):
        run_experiment(cfg)
    runs = runs_of(cfg)
    assert {r.data.tags.get("map", "parent") for r in runs} == {"parent", "level1-bmuofn"}
    assert {r.info.status for r in runs} == {"KILLED"}
    assert {r.data.tags.get("kernel_layout") for r in runs} == {None}


def test_without_an_opencl_device_the_fallback_is_said_once(tmp_path):
    """`meshsom run` on a machine without any OpenCL device says the NumPy fallback in one line:
    the client's, not once more by each LocalCluster worker (they logged it too, unformatted)."""
    import os
    import subprocess
    import sys

    env = {**os.environ, "POCL_DEVICES": "none", "OCL_ICD_VENDORS": str(tmp_path / "no-icd")}
    sets = ["som.epochs=2", "domain.enabled=false", "dask.workers=2", "dask.dashboard=false",
            f"store.path={tmp_path / 'q.zarr'}", f"tracking.uri=sqlite:///{tmp_path / 'mlflow.db'}"]
    out = subprocess.run([sys.executable, "-m", "pipelines.cli", "run", str(ROOT / "configs" / "quick.yaml"),
                          *[a for s in sets for a in ("--set", s)]],
                         capture_output=True, text=True, env=env, timeout=600)
    assert out.returncode == 0, out.stderr[-2000:]
    said = [line for line in (out.stdout + out.stderr).splitlines() if "no usable OpenCL device" in line]
    assert len(said) == 1 and said[0].startswith("WARNING meshsom.bmu: no usable OpenCL device"), said
    assert "BMU search: numpy" in out.stdout
