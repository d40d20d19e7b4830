"""A real multi-process cluster (`dask scheduler` + two `dask worker` processes) and faults.

- `meshsom run --scheduler tcp://127.0.0.1:PORT` gives the same store as a LocalCluster run;
- a worker killed with SIGKILL during encoding and during training: the run completes with the
  results of an undisturbed run;
- the client killed mid-run: `meshsom run --resume` completes with the same results.
Every process is started here and stopped by PID.
"""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from meshsom.store import open_store
from pipelines.cli import main
from pipelines.cluster import WORKER_ENV

BIN = Path(sys.executable).parent
ROOT = Path(__file__).resolve().parents[1]
#: Seconds any wait in this file may take before the test fails.
WAIT_S = 120

CONFIG = """
name: faults
corpus:
  generator: {n_blocks: 96, seed: 5}
encoding: {levels: [1, 2]}
train:
  - {level: 1, kernel: bmuofn}
  - {level: 2, kernel: bmuofn}
som: {rows: 16, cols: 20, epochs: 25, sigma_end: 0.8, seed: 1}
domain: {rows: 4, cols: 5, epochs: 5}
dask: {shard_meshes: 4, dashboard: false}
tracking: {enabled: false}
store: {path: unused.zarr}
"""


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _wait(predicate, what: str, timeout: float = WAIT_S, step: float = 0.02):
    deadline = time.time() + timeout
    while not predicate():
        if time.time() > deadline:
            pytest.fail(f"timed out waiting for {what}")
        time.sleep(step)


def _stop(procs):
    for p in procs:
        if p.poll() is None:
            p.terminate()
    for p in procs:
        try:
            p.wait(timeout=20)
        except subprocess.TimeoutExpired:
            p.kill()


@pytest.fixture(scope="module")
def cluster(tmp_path_factory):
    """Scheduler and two single-threaded workers as separate processes on loopback."""
    from distributed import Client

    tmp = tmp_path_factory.mktemp("cluster")
    port = _free_port()
    address = f"tcp://127.0.0.1:{port}"
    env = {**os.environ, **WORKER_ENV}
    log = open(tmp / "cluster.log", "w")
    procs = [subprocess.Popen([str(BIN / "dask"), "scheduler", "--host", "127.0.0.1", "--port", str(port), "--no-dashboard"],
                              stdout=log, stderr=subprocess.STDOUT, env=env, cwd=tmp)]
    for i in range(2):
        procs.append(subprocess.Popen(
            [str(BIN / "dask"), "worker", address, "--nthreads", "1", "--nworkers", "1", "--no-dashboard",
             "--host", "127.0.0.1", "--memory-limit", "3GB", "--name", f"w{i}"],
            stdout=log, stderr=subprocess.STDOUT, env=env, cwd=tmp))
    try:
        deadline = time.time() + WAIT_S
        while True:
            try:
                with Client(address, timeout="5s") as c:
                    if len(c.scheduler_info()["workers"]) == 2:
                        break
            except OSError:
                pass
            if time.time() > deadline or any(p.poll() is not None for p in procs):
                pytest.fail(f"cluster did not start: {(tmp / 'cluster.log').read_text()[-3000:]}")
            time.sleep(0.5)
        yield address
    finally:
        _stop(procs)


@pytest.fixture(scope="module")
def config(tmp_path_factory):
    p = tmp_path_factory.mktemp("cfg") / "faults.yaml"
    p.write_text(CONFIG)
    return p


@pytest.fixture(scope="module")
def reference(tmp_path_factory, config):
    """The undisturbed result, on a LocalCluster."""
    store = tmp_path_factory.mktemp("ref") / "ref.zarr"
    assert main(["run", str(config), "--store", str(store), "--workers", "2"]) == 0
    return store


def _assert_same(a: Path, b: Path):
    ga, gb = open_store(a), open_store(b)
    for name in ("vertices", "faces", "face_mesh"):
        assert np.array_equal(ga[name][:], gb[name][:]), name
    for level in (1, 2):
        assert np.array_equal(ga["rings"][f"level{level}"][:], gb["rings"][f"level{level}"][:])
    for run in ("level1-bmuofn", "level2-bmuofn"):
        for arr in ("weights", "bmu_unit", "bmu_variation"):
            assert np.array_equal(ga["runs"][run][arr][:], gb["runs"][run][arr][:]), (run, arr)
        assert ga["runs"][run].attrs["metrics"] == gb["runs"][run].attrs["metrics"]


def _worker_pids(address):
    from distributed import Client

    with Client(address, timeout="10s") as c:
        return sorted(c.run(os.getpid).values())


def test_external_cluster_run_equals_local_cluster_run(cluster, config, reference, tmp_path):
    store = tmp_path / "ext.zarr"
    assert main(["run", str(config), "--store", str(store), "--scheduler", cluster]) == 0
    _assert_same(reference, store)


def _run_in_thread(args):
    result = {}

    def target():
        try:
            result["rc"] = main(args)
        except BaseException as err:  # reported by the test below
            result["error"] = err

    t = threading.Thread(target=target, daemon=True)
    t.start()
    return t, result


@pytest.mark.parametrize("stage", ["encoding", "training"])
def test_worker_killed_during_a_stage_run_completes_with_same_results(cluster, config, reference, tmp_path, stage):
    store = tmp_path / f"kill-{stage}.zarr"
    before = _worker_pids(cluster)
    t, result = _run_in_thread(["run", str(config), "--store", str(store), "--scheduler", cluster])

    def started():
        if not (store / "zarr.json").exists():
            return False
        try:
            g = open_store(store)
        except Exception:
            return False
        if stage == "encoding":
            return "staging" in g and any(s.attrs.get("done") for _, s in g["staging"].groups())
        return "runs" in g and "level1-bmuofn" in g["runs"] and g["runs"]["level1-bmuofn"].attrs.get("epoch_done", 0) >= 2

    _wait(started, f"the {stage} stage to start")
    victim = before[0]
    os.kill(victim, signal.SIGKILL)
    t.join(WAIT_S * 2)
    assert not t.is_alive(), "the run did not finish after a worker was killed"
    assert "error" not in result, result.get("error")
    assert result["rc"] == 0
    _assert_same(reference, store)
    _wait(lambda: len(_worker_pids(cluster)) == 2, "the nanny to restart the killed worker")
    assert victim not in _worker_pids(cluster)


def test_client_killed_mid_run_then_resume(cluster, config, reference, tmp_path):
    store = tmp_path / "client.zarr"
    proc = subprocess.Popen([str(BIN / "meshsom"), "run", str(config), "--store", str(store), "--scheduler", cluster],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, cwd=ROOT)

    def mid_training():
        try:
            g = open_store(store)
            return g["runs"]["level2-bmuofn"].attrs.get("epoch_done", 0) >= 3
        except Exception:
            return False

    try:
        _wait(mid_training, "training of the second map")
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=30)
    attrs = open_store(store)["runs"]["level2-bmuofn"].attrs
    assert not attrs.get("final_done")
    first_map = dict(open_store(store)["runs"]["level1-bmuofn"].attrs["result"])
    assert main(["run", str(config), "--store", str(store), "--scheduler", cluster, "--resume"]) == 0
    g = open_store(store)
    assert g["runs"]["level2-bmuofn"].attrs["result"]["resumed_from"] >= 3
    assert dict(g["runs"]["level1-bmuofn"].attrs["result"]) == first_map  # finished before: not recomputed
    _assert_same(reference, store)
