"""Stores on object storage: ``store.path: s3://bucket/name.zarr`` end to end.

A real S3-compatible server (moto's server mode) runs on a free loopback port for this module
and is stopped at its end; credentials and endpoint reach every process (the test, the Dask
workers) through the standard ``AWS_*`` environment, as on a cloud cluster. The quick config
(fewer epochs) runs once with a local store and twice with an ``s3://`` store, on a LocalCluster
and on an external scheduler (there interrupted in its second map and resumed), and every array,
attribute and tracked metric must be the same; then the report reads the remote store through
the ``store`` tag of its MLflow run.
"""

from __future__ import annotations

import logging
import os
from pathlib import Path

import numpy as np
import pytest

from pipelines.settings import load_config
from meshsom.errors import StoreError
from meshsom.store import (
    BMU_ARRAYS, create_store, figures_dir, list_runs, open_store, probe_writable, read_domain, read_manifest,
    remove_store, store_exists,
)
from pipelines.run import run_experiment

ROOT = Path(__file__).resolve().parents[1]
BUCKET = "meshsom-test"
#: Epochs of the triangle maps here (the quick config has 8): the comparison needs the same
#: training on both stores, not a long one.
EPOCHS = 3
CORPUS_ARRAYS = ("vertices", "faces", "face_mesh", "meshes/ids", "meshes/labels", "meshes/face_offsets",
                 "meshes/vertex_offsets", "meshes/origins", "rings/level1", "rings/level2")
ENV = {
    "AWS_ACCESS_KEY_ID": "meshsom-test", "AWS_SECRET_ACCESS_KEY": "meshsom-test", "AWS_DEFAULT_REGION": "us-east-1",
    # what pipelines.cluster gives its own workers; the external cluster started here inherits it
    "POCL_MAX_PTHREAD_COUNT": "1", "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1",
}


@pytest.fixture(scope="module")
def s3(tmp_path_factory):
    """A loopback S3 server with one bucket; yields ``{"endpoint", "tmp"}``; the environment names
    the endpoint and the credentials and the working directory is a temporary folder (figures of
    a remote store go there) until the module ends."""
    import boto3
    from moto.server import ThreadedMotoServer

    logging.getLogger("werkzeug").setLevel(logging.ERROR)  # one log line per request otherwise
    tmp = tmp_path_factory.mktemp("s3")
    server = ThreadedMotoServer(ip_address="127.0.0.1", port=0, verbose=False)
    server.start()
    host, port = server.get_host_and_port()
    endpoint = f"http://{host}:{port}"
    try:
        with pytest.MonkeyPatch.context() as mp:
            for k, v in {**ENV, "AWS_ENDPOINT_URL": endpoint}.items():
                mp.setenv(k, v)
            mp.chdir(tmp)
            boto3.client("s3", endpoint_url=endpoint).create_bucket(Bucket=BUCKET)
            yield {"endpoint": endpoint, "tmp": tmp}
    finally:
        server.stop()


def quick(tmp: Path, store: str, experiment: str, **over):
    """The quick config with ``store``, SQLite tracking under ``tmp``, 2 local workers, fewer epochs."""
    over = {
        "store": {"path": store},
        "tracking": {"uri": f"sqlite:///{tmp / 'mlflow.db'}", "experiment": experiment},
        "dask": {"workers": 2, "dashboard": False},
        "som": {"epochs": EPOCHS},
    } | over
    return load_config(ROOT / "configs" / "quick.yaml", over)


@pytest.fixture(scope="module")
def runs(s3):
    """The quick run with a local store and with an ``s3://`` store (both on a LocalCluster): their configs."""
    tmp = s3["tmp"]
    local = quick(tmp, str(tmp / "local" / "quick.zarr"), "s3-test-local")
    remote = quick(tmp, f"s3://{BUCKET}/quick.zarr", "s3-test-remote")
    for cfg in (local, remote):
        assert run_experiment(cfg, ROOT / "configs" / "quick.yaml") == 0
    return {"local": local, "remote": remote}


def _objects(endpoint: str, prefix: str) -> set[str]:
    """Object keys under ``prefix`` in the bucket, listed with boto3 (not through meshsom or fsspec)."""
    import boto3

    pages = boto3.client("s3", endpoint_url=endpoint).get_paginator("list_objects_v2").paginate(
        Bucket=BUCKET, Prefix=prefix)
    return {o["Key"] for page in pages for o in page.get("Contents", [])}


def assert_same_stores(a: str, b: str) -> None:
    """Two stores hold the same corpus, manifest, statistics, maps, BMUs and domain maps."""
    ga, gb = open_store(a), open_store(b)
    ma, mb = read_manifest(a), read_manifest(b)
    assert ma["summary"] == mb["summary"] and ma["records"] == mb["records"]
    assert ma["summary"]["accepted"] == 24 and ma["summary"]["inputs"] == 24
    for name in CORPUS_ARRAYS:
        np.testing.assert_array_equal(np.asarray(ga[name][:]), np.asarray(gb[name][:]), err_msg=name)
    assert dict(ga["rings"]["stats"].attrs) == dict(gb["rings"]["stats"].attrs)
    assert {k: ga.attrs[k] for k in ("n_meshes", "n_faces", "n_vertices")} == \
        {k: gb.attrs[k] for k in ("n_meshes", "n_faces", "n_vertices")}
    assert list_runs(ga) == list_runs(gb) == ["level1-bmuofn", "level1-default", "level2-bmuofn"]
    for run in list_runs(ga):
        ra, rb = ga["runs"][run], gb["runs"][run]
        np.testing.assert_array_equal(ra["weights"][:], rb["weights"][:], err_msg=run)
        for name in BMU_ARRAYS.values():
            np.testing.assert_array_equal(ra[name][:], rb[name][:], err_msg=f"{run}/{name}")
        assert ra.attrs["metrics"] == rb.attrs["metrics"] and ra.attrs["history"] == rb.attrs["history"]
        assert ra.attrs["epoch_done"] == rb.attrs["epoch_done"] == EPOCHS
        da, db = read_domain(ga, run), read_domain(gb, run)
        np.testing.assert_array_equal(da["units"], db["units"])
        assert da["metrics"] == db["metrics"]


def _tracked(uri: str, experiment: str) -> tuple[dict, dict]:
    """(parent tags, {child name: (params, metrics)}) of the one finished pipeline run of an experiment."""
    from mlflow.tracking import MlflowClient

    client = MlflowClient(tracking_uri=uri)
    exp = client.get_experiment_by_name(experiment)
    found = client.search_runs([exp.experiment_id])
    parents = [r for r in found if "mlflow.parentRunId" not in r.data.tags]
    assert len(parents) == 1 and parents[0].info.status == "FINISHED"
    children = {r.data.tags["map"]: (dict(r.data.params), dict(r.data.metrics)) for r in found
                if r.data.tags.get("mlflow.parentRunId") == parents[0].info.run_id}
    return dict(parents[0].data.tags), children


def test_s3_store_gives_the_results_of_a_local_store(s3, runs):
    local, remote = runs["local"].store.path, runs["remote"].store.path
    keys = _objects(s3["endpoint"], "quick.zarr/")
    # the store really is in the bucket: layout, manifest, chunks of every stage; no staging left
    assert {"quick.zarr/zarr.json", "quick.zarr/manifest.json", "quick.zarr/rings/level2/zarr.json",
            "quick.zarr/runs/level2-bmuofn/weights/zarr.json",
            "quick.zarr/runs/level1-bmuofn/domain/units/zarr.json"} <= keys
    assert any(k.startswith("quick.zarr/rings/level1/c/") for k in keys)
    assert not any(k.startswith("quick.zarr/staging/") or ".meshsom-probe-" in k for k in keys)
    assert not (s3["tmp"] / "s3:").exists()  # no local folder named after the URL
    assert_same_stores(local, remote)

    # tracked: the same final metrics; the parent names the URL, the codebook param is the run inside it
    uri = runs["remote"].tracking.uri
    tags_l, maps_l = _tracked(uri, "s3-test-local")
    tags_r, maps_r = _tracked(uri, "s3-test-remote")
    assert tags_r["store"] == remote and tags_l["store"] == str(Path(local).resolve())
    assert set(maps_l) == set(maps_r) == {"level1-default", "level1-bmuofn", "level2-bmuofn"}
    for name, (params, metrics) in maps_r.items():
        assert params["codebook"] == f"runs/{name}"  # inside the store the parent's store tag names
        for key in ("t_error", "q_error", "qc_error"):
            assert metrics[key] == maps_l[name][1][key]
            assert metrics[key] == pytest.approx(open_store(remote)["runs"][name].attrs["metrics"][key])
        # figures of a remote store: ./quick-figures in the working directory
        assert (s3["tmp"] / "quick-figures" / f"umatrix-{name}.png").stat().st_size > 0
        assert (s3["tmp"] / "quick-figures" / f"domain-{name}.png").stat().st_size > 0


def test_s3_store_on_an_external_scheduler_interrupted_and_resumed(s3, runs, monkeypatch):
    from distributed import LocalCluster

    import pipelines.train as train

    real = train.train_spec

    def interrupt_second_map(client, job, resume=False, on_epoch=None, **kw):
        if job.run == "level1-bmuofn" and not resume:
            def stop(epoch, metrics):
                if epoch == 1:
                    raise KeyboardInterrupt
            return real(client, job, resume, on_epoch=stop, **kw)
        return real(client, job, resume, on_epoch=on_epoch, **kw)

    # an external cluster: its worker processes get the S3 endpoint and credentials from their own
    # environment (inherited here), as workers on other machines get theirs
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                      dashboard_address=None, silence_logs=logging.WARNING) as cluster:
        cfg = quick(s3["tmp"], f"s3://{BUCKET}/external.zarr", "s3-test-external",
                    dask={"scheduler": cluster.scheduler_address, "dashboard": False})
        monkeypatch.setattr(train, "train_spec", interrupt_second_map)
        with pytest.raises(KeyboardInterrupt):
            run_experiment(cfg)
        monkeypatch.setattr(train, "train_spec", real)
        assert run_experiment(cfg, resume=True) == 0
        # the corpus and training tasks ran on that cluster
        keys = {str(t[0]) for t in cluster.scheduler.transition_log}
        assert any(k.startswith("corpus-shard-") for k in keys) and any(k.startswith("corpus-copy-") for k in keys)
    keys = _objects(s3["endpoint"], "external.zarr/")
    assert "external.zarr/manifest.json" in keys and not any(k.startswith("external.zarr/staging/") for k in keys)
    assert open_store(cfg.store.path)["runs"]["level1-bmuofn"].attrs["result"]["resumed_from"] == 2
    assert_same_stores(runs["local"].store.path, cfg.store.path)


def test_report_reads_the_remote_store(s3, runs, tmp_path):
    from reports.report import make_report

    cfg = runs["remote"]
    res = make_report(cfg.tracking.uri, cfg.tracking.experiment, tmp_path, clustering_experiment=cfg.tracking.experiment,
                      also=(), log=lambda *_: None)
    names = {Path(f).name for f in res["files"]}
    assert {"table2.md", "fig8.png", "clustering.md", "report.md"} <= names
    assert {f"fig9-{r}.png" for r in ("level1-default", "level1-bmuofn", "level2-bmuofn")} <= names
    assert f"s3://{BUCKET}/quick.zarr" in (tmp_path / "report.md").read_text()


def test_store_functions_on_s3(s3):
    url = f"s3://{BUCKET}/functions.zarr"
    assert not store_exists(url)
    with pytest.raises(StoreError, match=f"{url}: no zarr store here"):
        open_store(url)
    create_store(url)
    assert store_exists(url) and open_store(url).attrs["created_by"] == "meshsom"
    with pytest.raises(StoreError, match=f"{url}: already exists"):
        create_store(url)
    probe_writable(url)  # leaves nothing behind
    assert _objects(s3["endpoint"], "functions.zarr/") == {"functions.zarr/zarr.json"}
    import boto3

    boto3.client("s3", endpoint_url=s3["endpoint"]).put_object(Bucket=BUCKET, Key="functions.zarr-old/keep", Body=b"1")
    remove_store(url)
    assert not store_exists(url) and not _objects(s3["endpoint"], "functions.zarr/")
    assert _objects(s3["endpoint"], "functions.zarr-old/") == {"functions.zarr-old/keep"}  # a prefix, not a folder
    remove_store(url)  # nothing there is fine
    with pytest.raises(StoreError, match="s3://no-such-bucket/x.zarr: cannot write there"):
        probe_writable("s3://no-such-bucket/x.zarr")
    assert figures_dir(url, create=False) == Path.cwd() / "functions-figures"
    assert figures_dir(url + "/", create=False) == Path.cwd() / "functions-figures"


def test_a_missing_fsspec_backend_is_named():
    with pytest.raises(StoreError, match="no-such-protocol://x/y.zarr"):
        store_exists("no-such-protocol://x/y.zarr")


def test_single_process_commands_on_s3(s3, tmp_path, capsys):
    """`meshsom ingest`, `encode` and `train` with an s3:// STORE write what they write locally."""
    from pipelines.cli import main

    stores = {"local": str(tmp_path / "cli.zarr"), "remote": f"s3://{BUCKET}/cli.zarr"}
    for store in stores.values():
        assert main(["ingest", "--generate", "4", "--out", store, "--json"]) == 0
        assert main(["encode", store, "--levels", "1", "2", "--json"]) == 0
        assert main(["train", store, "--level", "2", "--map", "4x5", "--epochs", "2", "--backend", "numpy",
                     "--json"]) == 0
    assert "cli.zarr/rings/level2/zarr.json" in _objects(s3["endpoint"], "cli.zarr/")
    a, b = open_store(stores["local"]), open_store(stores["remote"])
    assert read_manifest(stores["local"])["records"] == read_manifest(stores["remote"])["records"]
    for name in ("faces", "rings/level1", "rings/level2", "runs/level2-bmuofn/weights", "runs/level2-bmuofn/bmu_unit"):
        np.testing.assert_array_equal(a[name][:], b[name][:], err_msg=name)
    capsys.readouterr()
    assert main(["ingest", "--generate", "4", "--out", stores["remote"]]) == 2
    assert f"meshsom ingest: error: s3://{BUCKET}/cli.zarr: already exists" in capsys.readouterr().err
