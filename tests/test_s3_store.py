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

import dataclasses
import logging
import os
import shutil
from pathlib import Path

import numpy as np
import pytest

from pipelines.settings import load_config
from meshsom.errors import ConfigError, StoreError
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


# ----------------------------------------------------------------------------- inputs on object storage

ZURICH_LOD1 = ROOT / "data" / "real" / "zurich-lod2-subset" / "zurich_subset_lod1_derived.city.json"


@pytest.fixture(scope="module")
def s3_cluster(s3):
    """A LocalCluster of 2 worker processes started with the S3 environment (as a cloud cluster's workers are)."""
    from distributed import Client, LocalCluster

    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=":0") as cluster, \
            Client(cluster) as client:
        yield client


def _city_folder(folder: Path) -> Path:
    """A city's inputs of the kinds that need more than their own file, or that the planner cuts: a CityJSON file,
    a shapefile with its sidecars, OBJ files with ``labels.csv`` beside them, a zip of a CityJSON file, a large
    gzipped CityGML file (decompressed by the planner and read in ranges), and Overture's buildings with their parts
    in a file of their own (each read task opens both)."""
    import gzip
    import sys
    import zipfile

    import fiona

    sys.path.insert(0, str(ROOT / "tests"))
    from footprints import closed
    from test_citygml import _large_citygml
    from test_part_files import _geoparquet_pair

    from meshsom.generate import GeneratorParams, generate_corpus
    from meshsom.io import write_mesh_folder

    folder.mkdir(parents=True)
    (folder / "zurich.city.json").write_bytes(ZURICH_LOD1.read_bytes())
    schema = {"geometry": "Polygon", "properties": {"id": "str", "height": "float"}}
    with fiona.open(folder / "footprints.shp", "w", driver="ESRI Shapefile", schema=schema, crs="EPSG:28992") as out:
        for k in range(6):
            x, y = 84600 + 30 * k, 447400
            out.write({"geometry": {"type": "Polygon", "coordinates": [closed([(x, y), (x + 12, y), (x + 12, y + 9), (x, y + 9)])]},
                       "properties": {"id": f"f{k}", "height": 6.0 + k}})
    write_mesh_folder(folder / "objs", [b for b in generate_corpus(GeneratorParams(n_blocks=3, seed=1))])
    with zipfile.ZipFile(folder / "tiles.zip", "w") as z:
        z.write(ZURICH_LOD1, "tile/zurich.city.json")
    (folder / "big.gml.gz").write_bytes(gzip.compress(_large_citygml("2.0", "core:cityObjectMember").encode()))
    (folder / "overture").mkdir()
    _geoparquet_pair(folder / "overture")  # Overture's buildings and their parts, in two files: read paired
    return folder


def _upload(folder: Path, url: str) -> None:
    from meshsom.store import filesystem

    fs, path = filesystem(url)
    for file in sorted(p for p in folder.rglob("*") if p.is_file()):
        fs.put_file(str(file), f"{path}/{file.relative_to(folder).as_posix()}")


def _corpus_config(paths, store, mirror):
    from meshsom.config import build
    from pipelines.settings import RunConfig

    return build(RunConfig, {"corpus": {"paths": [str(p) for p in paths], "mirror": str(mirror)}, "encoding": {"levels": [1]},
                             "dask": {"shard_meshes": 64, "read_bytes": 300_000}, "store": {"path": store, "chunk_rows": 500}})


def test_inputs_on_object_storage_read_as_the_same_files_on_disk(s3, s3_cluster, tmp_path, monkeypatch):
    """A city's folder on S3 (``s3://bucket/city``), one of its files by URL, and a glob, read by ``run_corpus`` on a
    cluster into a local store and into a store on S3: the same records (sources and reasons naming the URLs) and
    arrays as the folder read from disk; every kind of input read (the shapefile with its sidecars, the OBJ files'
    labels, the zip's tile, the CityGML file in ranges); nothing left in the mirror folder or the store's staging."""
    from meshsom.mirror import Copy, unopened_below
    from pipelines import corpus

    local = _city_folder(tmp_path / "city")
    url = f"s3://{BUCKET}/inputs/city"
    _upload(local, url)
    mirror = tmp_path / "mirror"
    uploaded = []  # what the planner wrote, copied into the store's staging group for the workers
    upload = corpus._uploaded
    monkeypatch.setattr(corpus, "_uploaded", lambda *a: uploaded.append(upload(*a)) or uploaded[-1])
    runs = {}
    for key, paths, store in (
            ("disk", [local], str(tmp_path / "disk.zarr")),
            ("s3", [url], str(tmp_path / "s3.zarr")),
            ("s3-store", [url], f"s3://{BUCKET}/inputs-store.zarr"),
            ("one", [f"{url}/footprints.shp", f"{url}/objs/*.obj", f"s3://{BUCKET}/inputs/nothing-here"],
             str(tmp_path / "one.zarr"))):
        calls = []
        corpus.run_corpus(s3_cluster, _corpus_config(paths, store, mirror), store, progress=lambda *a: calls.append(a))
        runs[key] = (read_manifest(store)["records"], open_store(store),
                     max(total for stage, _, total in calls if stage == "read"),
                     [(done, total) for stage, done, total in calls if stage == "copy"])
        assert not mirror.exists() or not any(mirror.rglob("*.*")), list(mirror.rglob("*"))
    disk, on_s3, s3_store, one = (runs[k][0] for k in ("disk", "s3", "s3-store", "one"))
    assert runs["disk"][2] == runs["s3"][2] > 5 + 4  # a task per file, the CityGML file in ranges
    placeholder = unopened_below(2 * 300_000)  # the OBJ files, the small CityJSON file: placeholders
    files = sum(1 for f in local.rglob("*") if f.is_file() and not placeholder(Copy("", str(f), f.stat().st_size)))
    assert 0 < files < sum(1 for f in local.rglob("*") if f.is_file()) - 3
    assert runs["disk"][3] == [] and runs["s3"][3][-1] == (files, files) and runs["s3-store"][3][-1] == (files, files)
    assert {r["source"].split("!")[0].split(".gml.gz")[0].rsplit("/", 1)[0] for r in on_s3} >= {url, f"{url}/objs"}
    as_url = [{**r, "source": r["source"].replace(str(local), url), "reason": r.get("reason", "").replace(str(local), url)}
              for r in disk]
    assert [{**r, "reason": r.get("reason", "")} for r in on_s3] == as_url
    assert on_s3 == s3_store
    accepted = {r["source"].rsplit("/", 1)[-1] for r in on_s3 if r["status"] == "accepted"}
    assert {"zurich.city.json", "footprints.shp", "big.gml.gz", "zurich.city.json"} <= accepted
    assert any(r["source"].endswith("tiles.zip!/tile/zurich.city.json") for r in on_s3 if r["status"] == "accepted")
    assert {r["label"] for r in on_s3 if r["source"].endswith(".obj")} - {None, ""}, "labels.csv beside the OBJ files"
    overture = sorted(r["id"].split("#")[1] for r in on_s3 if "/overture/" in r["source"])
    assert overture == ["b1", "b2", "p3"], overture  # b1 is its parts, p1 and p2
    for name in ("faces", "vertices", "rings/level1", "meshes/ids"):
        np.testing.assert_array_equal(runs["disk"][1][name][:], runs["s3"][1][name][:], err_msg=name)
        np.testing.assert_array_equal(runs["s3"][1][name][:], runs["s3-store"][1][name][:], err_msg=name)
    staged = sorted(c.url.split("/staging/inputs/")[1] for found in uploaded for c in found.values())
    assert len(staged) == 2 and staged[0].startswith("gunzip-") and staged[0].endswith("-big.gml"), staged
    assert staged[1].startswith("zip-") and staged[1].endswith("-tiles.zip/tile/zurich.city.json"), staged
    assert not _objects(s3["endpoint"], "inputs-store.zarr/staging/")
    by_source = {}
    for r in one:
        by_source.setdefault(r["source"].rsplit("/", 1)[-1], []).append(r)
    assert [r["status"] for r in by_source["footprints.shp"]] == ["accepted"] * 6  # its sidecars copied beside it
    assert len(by_source) == 1 + 3 + 1 and by_source["nothing-here"][0]["status"] == "rejected"
    assert "nothing under this URL" in by_source["nothing-here"][0]["reason"]


def test_the_planner_streams_a_large_citygml_file_and_copies_only_its_head(s3, s3_cluster, tmp_path, monkeypatch):
    """A large plain CityGML file on S3 is cut into ranges by streaming it from its URL: the planner copies its head
    only (its kind), never the whole file, and each range's task copies its own bytes; a large INSPIRE GML file
    (GDAL reads it whole) is copied whole once its head says what it is; an OpenStreetMap extract is a placeholder
    (its ranges planned by its size), copied by its read task. The records and arrays equal those of the folder
    read from disk, the CityGML file in the same ranges."""
    import json as jsonlib

    from meshsom import citygml, mirror as mirroring
    from meshsom.io import ReaderOptions
    from pipelines import corpus
    from test_citygml import _large_citygml
    from test_inspire import HEADER, _feature, _floors

    local = tmp_path / "city"
    local.mkdir()
    (local / "big.gml").write_text(_large_citygml("2.0", "core:cityObjectMember"))
    (local / "bu.gml").write_text(HEADER + "".join(_feature("Building", f"ES.B{k}", (20 * k, 0, 10, 8), _floors(1 + k % 4))
                                                   for k in range(420)) + "</gml:FeatureCollection>\n")
    from test_osm import _district

    _district(local / "district.osm")  # OpenStreetMap: planned by its size alone, a placeholder for the planner
    import pyarrow.parquet as pq
    import shapely
    from footprints import write_geoparquet

    write_geoparquet(tmp_path / "plain.parquet", [(f"r{k}", shapely.geometry.mapping(shapely.box(3 * k, 0, 3 * k + 2, 2)),
                                                   {"height": 3.0 + k % 5}) for k in range(400)], crs="EPSG:28992")
    pq.write_table(pq.read_table(tmp_path / "plain.parquet"), local / "blocks.parquet", row_group_size=50)  # in ranges
    limit = 2 * 300_000  # twice the config's read_bytes
    assert (local / "bu.gml").stat().st_size > limit and (local / "big.gml").stat().st_size > limit
    url = f"s3://{BUCKET}/streamed/city"
    _upload(local, url)
    mirrored = mirroring.mirror_inputs([url], tmp_path / "heads", heads=mirroring.heads_from(limit))
    big = Path(mirrored.paths[0]) / "big.gml"
    extract = Path(mirrored.paths[0]) / "district.osm"
    assert extract.read_bytes().strip(b"\0") == b"" and extract.stat().st_size == (local / "district.osm").stat().st_size
    assert jsonlib.loads(Path(f"{big}{mirroring.SPANS_SUFFIX}").read_text()) == [[0, mirroring.HEAD_BYTES]]
    data = big.read_bytes()
    assert data[:mirroring.HEAD_BYTES] == (local / "big.gml").read_bytes()[:mirroring.HEAD_BYTES]
    assert data[mirroring.HEAD_BYTES:].strip(b"\0") == b""
    assert citygml.citygml_ranges(big, 300_000, ReaderOptions(), f"{url}/big.gml") == citygml.citygml_ranges(
        local / "big.gml", 300_000, ReaderOptions())
    fetched, scanned = [], []
    fetch, spans = mirroring.fetch, citygml._member_spans
    monkeypatch.setattr(mirroring, "fetch", lambda copies: fetched.extend(c.url for c in copies) or fetch(copies))
    monkeypatch.setattr(citygml, "_member_spans", lambda source: scanned.append(str(source)) or spans(source))
    runs = {}
    for key, paths, store in (("disk", [local], str(tmp_path / "disk.zarr")), ("s3", [url], str(tmp_path / "s3.zarr"))):
        calls = []
        cfg = _corpus_config(paths, store, tmp_path / "mirror")
        cfg = dataclasses.replace(cfg, dask=dataclasses.replace(cfg.dask, read_features=150))  # the GeoParquet: 3 ranges
        corpus.run_corpus(s3_cluster, cfg, store, progress=lambda *a: calls.append(a))
        runs[key] = (read_manifest(store)["records"], open_store(store),
                     max(total for stage, _, total in calls if stage == "read"))
    assert fetched == [f"{url}/bu.gml"]  # the planner's whole copies: the INSPIRE file only
    assert scanned == [str(local / "big.gml"), f"{url}/big.gml"]
    assert runs["disk"][2] == runs["s3"][2] > 1 + 4 + 3  # the CityGML file and the GeoParquet file in ranges
    disk, on_s3 = runs["disk"][0], runs["s3"][0]
    assert [{**r, "source": r["source"].replace(str(local), url), "reason": r.get("reason", "").replace(str(local), url)}
            for r in disk] == [{**r, "reason": r.get("reason", "")} for r in on_s3]
    assert sum(r["status"] == "accepted" and r["source"].endswith("bu.gml") for r in on_s3) == 420
    assert sum(r["status"] == "accepted" and r["source"].endswith("district.osm") for r in on_s3) == 7
    assert sum(r["status"] == "accepted" and r["source"].endswith("blocks.parquet") for r in on_s3) == 400
    for name in ("faces", "vertices", "rings/level1", "meshes/ids"):
        np.testing.assert_array_equal(runs["disk"][1][name][:], runs["s3"][1][name][:], err_msg=name)


def test_the_planner_copies_of_a_large_geoparquet_file_only_what_it_reads(s3, s3_cluster, tmp_path, monkeypatch):
    """Large GeoParquet files on S3 (Overture-like buildings; a query's WKB column without metadata, its first
    footprints empty): the planner copies of each only the bytes its footer says the planner reads (the first row
    groups, the id columns, the footer: no later row group's other columns), never the whole file, and each range's
    task its own row groups; the records and arrays equal those of the folder read from
    disk, in the same ranges."""
    import pyarrow.parquet as pq

    from meshsom import mirror as mirroring
    from meshsom.gis import PLANNER_ROWS, _chunk_span
    from pipelines import corpus
    from test_gis import _overture_like

    local = tmp_path / "city"
    local.mkdir()
    _overture_like(local / "buildings.parquet", 2500, 100)
    _overture_like(local / "query.parquet", 1500, 100, null_geometries=200, geo=False)
    limit = 2 * 300_000  # twice the config's read_bytes
    assert all(f.stat().st_size > limit for f in local.iterdir())
    url = f"s3://{BUCKET}/columnar/city"
    _upload(local, url)
    fetched = []
    fetch = mirroring.fetch
    monkeypatch.setattr(mirroring, "fetch", lambda copies: fetched.extend(copies) or fetch(copies))
    runs = {}
    for key, paths, store in (("disk", [local], str(tmp_path / "disk.zarr")), ("s3", [url], str(tmp_path / "s3.zarr"))):
        calls = []
        cfg = _corpus_config(paths, store, tmp_path / "mirror")
        cfg = dataclasses.replace(cfg, dask=dataclasses.replace(cfg.dask, read_features=500))
        corpus.run_corpus(s3_cluster, cfg, store, progress=lambda *a: calls.append(a))
        runs[key] = (read_manifest(store)["records"], open_store(store),
                     max(total for stage, _, total in calls if stage == "read"))
    assert sorted(c.url for c in fetched) == [f"{url}/buildings.parquet", f"{url}/query.parquet"]
    for c in fetched:  # the planner's copies: its spans only, none of the sources of the row groups past the first
        path = local / c.url.rsplit("/", 1)[1]
        meta, k = pq.ParquetFile(path).metadata, pq.read_schema(path).names.index("sources")
        assert c.spans is not None and c.spans[-1][1] == path.stat().st_size, c.spans
        later = [meta.row_group(g).column(k) for g in range(PLANNER_ROWS // 100 + 1, meta.num_row_groups)]
        assert len(later) >= 3 and not any(a < _chunk_span(s)[1] and _chunk_span(s)[0] < b
                                           for s in later for a, b in c.spans), c.spans
    assert runs["disk"][2] == runs["s3"][2] == 5 + 3  # in ranges of 500 rows
    disk, on_s3 = runs["disk"][0], runs["s3"][0]
    assert [{**r, "source": r["source"].replace(str(local), url), "reason": r.get("reason", "").replace(str(local), url)}
            for r in disk] == [{**r, "reason": r.get("reason", "")} for r in on_s3]
    assert sum(r["status"] == "accepted" and r["source"].endswith("buildings.parquet") for r in on_s3) == 2500
    assert sum(r["status"] == "accepted" and r["source"].endswith("query.parquet") for r in on_s3) == 1300
    for name in ("faces", "vertices", "rings/level1", "meshes/ids"):
        np.testing.assert_array_equal(runs["disk"][1][name][:], runs["s3"][1][name][:], err_msg=name)


def test_a_worker_without_the_copies_fetches_them(s3, tmp_path):
    """What a read task of another machine does: the planner's copies are not there, so the task copies its files
    (the shapefile and its sidecars) from their URLs to the same paths, once, and reads them as the planner would;
    a file that is gone is a rejection naming its URL."""
    from meshsom.io import ReaderOptions
    from meshsom.mirror import companions, mirror_inputs
    from pipelines.corpus import read_source

    local = _city_folder(tmp_path / "city")
    url = f"s3://{BUCKET}/fetch/city"
    _upload(local, url)
    mirrored = mirror_inputs([f"{url}/footprints.shp"], tmp_path / "mirror")
    (shp,) = mirrored.paths
    fetch = [dataclasses.asdict(c) for c in companions(Path(shp), mirrored.copies)]
    assert sorted(Path(c["local"]).suffix for c in fetch) == [".cpg", ".dbf", ".prj", ".shp", ".shx"]
    want = read_source(shp, ReaderOptions(), "footprints.shp", rename=(shp, mirrored.urls[shp]))
    shutil.rmtree(tmp_path / "mirror")
    got = read_source(shp, ReaderOptions(), "footprints.shp", rename=(shp, mirrored.urls[shp]), fetch=fetch)
    assert len(got) == 6 and [g.id for g in got] == [w.id for w in want]
    assert all(np.array_equal(g.vertices, w.vertices) and g.source == f"{url}/footprints.shp" for g, w in zip(got, want))
    shutil.rmtree(tmp_path / "mirror")
    from meshsom.store import filesystem

    fs, path = filesystem(f"{url}/footprints.dbf")
    fs.rm(path)
    (gone,) = read_source(shp, ReaderOptions(), "footprints.shp", rename=(shp, mirrored.urls[shp]), fetch=fetch)
    assert gone.source == f"{url}/footprints.shp" and f"{url}/footprints.dbf" in gone.reason + gone.id, gone


def test_commands_take_inputs_on_object_storage(s3, tmp_path, capsys):
    """`meshsom ingest URL` reads a file on S3 as the same file on disk (sources naming the URL); `meshsom run`
    checks its URL inputs before anything is created, naming one under which there is nothing."""
    from pipelines.cli import main
    from pipelines.run import check_inputs

    url = f"s3://{BUCKET}/cmd/{ZURICH_LOD1.name}"
    _upload(ZURICH_LOD1.parent, f"s3://{BUCKET}/cmd")
    assert main(["ingest", url, "--out", str(tmp_path / "url.zarr"), "--json"]) == 0
    assert main(["ingest", str(ZURICH_LOD1), "--out", str(tmp_path / "disk.zarr"), "--json"]) == 0
    a, b = read_manifest(tmp_path / "url.zarr")["records"], read_manifest(tmp_path / "disk.zarr")["records"]
    assert len(a) == 49 and {r["source"] for r in a} == {url}
    assert a == [{**r, "source": url} for r in b]
    cfg = quick(tmp_path, str(tmp_path / "q.zarr"), "check", corpus={"paths": [url, f"s3://{BUCKET}/cmd/none/"]})
    with pytest.raises(ConfigError, match=f"'s3://{BUCKET}/cmd/none/': no such file or folder"):
        check_inputs(cfg, cfg, None)
    cfg = quick(tmp_path, str(tmp_path / "q.zarr"), "check", corpus={"paths": [url]})
    assert check_inputs(cfg, cfg, None) == []


@pytest.mark.parametrize("kind", ["cityjsonseq", "geojson", "citygml"])
def test_a_worker_copies_only_the_bytes_of_its_range(s3, tmp_path, kind):
    """A large file on S3 read in ranges by workers without the planner's copies: each range's task copies only its
    reader's bytes (the file's head, tail and the range) into a sparse file, listed beside it, and reads the range's
    items as from the whole file; a later task of another range adds its bytes; a task wanting the whole file copies
    it whole. Bytes no task asked for stay zeros (a sparse file: holes)."""
    import json as jsonlib

    from meshsom.citygml import citygml_ranges
    from meshsom.generate import GeneratorParams, generate_corpus
    from meshsom.geojson import geojson_ranges
    from meshsom.io import ReaderOptions, cityjsonseq_ranges, read_file, write_cityjsonseq
    from meshsom.mirror import SPANS_SUFFIX, mirror_inputs
    from pipelines.corpus import _range_fetch, read_source
    from test_citygml import _large_citygml
    from test_geojson import _big_collection

    name = {"cityjsonseq": "city.city.jsonl", "geojson": "city.geojson", "citygml": "city.gml"}[kind]
    local = tmp_path / "in" / name
    local.parent.mkdir()
    if kind == "cityjsonseq":
        write_cityjsonseq(local, generate_corpus(GeneratorParams(n_blocks=60, seed=3)))
    elif kind == "geojson":
        local.write_text(_big_collection(120))
    else:
        local.write_text(_large_citygml("2.0", "core:cityObjectMember"))
    url = f"s3://{BUCKET}/ranges/{kind}/{name}"
    _upload(local.parent, f"s3://{BUCKET}/ranges/{kind}")
    mirrored = mirror_inputs([url], tmp_path / "mirror")
    (path,) = mirrored.paths
    ranges = (cityjsonseq_ranges(Path(path), local.stat().st_size // 5) if kind == "cityjsonseq" else
              geojson_ranges(Path(path), 25, ReaderOptions()) if kind == "geojson" else
              citygml_ranges(Path(path), local.stat().st_size // 5, ReaderOptions()))
    assert ranges is not None and len(ranges) >= 4
    whole = [i for r in ranges for i in read_file(path, byte_range=r)]
    source = {"path": path, "fetch": [dataclasses.asdict(c) for c in mirrored.copies.values()]}
    shutil.rmtree(tmp_path / "mirror")
    got, copied = [], Path(f"{path}{SPANS_SUFFIX}")
    for k in (1, 3, 0):
        fetch = _range_fetch(source, "cityjson" if kind == "geojson" else kind, ranges[k], ranges)
        items = read_source(path, ReaderOptions(), name, ranges[k], None, (path, url), fetch)
        got.append(items)
        assert copied.exists() and Path(path).stat().st_size == local.stat().st_size
    listed = jsonlib.loads(copied.read_text())
    data, original = Path(path).read_bytes(), local.read_bytes()
    for a, b in listed:
        assert data[a:b] == original[a:b]
    untouched = ranges[2][0], ranges[2][1]  # no task asked for range 2: zeros where the file holds text
    assert data[untouched[0]:untouched[1]].strip(b"\0") == b"" and original[untouched[0]:untouched[1]].strip()
    probe = tmp_path / "probe"  # holes take no disk, where the filesystem has holes (most local ones do)
    with open(probe, "wb") as out:
        out.truncate(1 << 20)
    if probe.stat().st_blocks * 512 < 1 << 20:
        assert Path(path).stat().st_blocks * 512 < len(original)
    want = {k: [i for i in read_file(local, ReaderOptions(), name, tuple(ranges[k]))] for k in (1, 3, 0)}
    for items, k in zip(got, (1, 3, 0)):
        assert [i.id for i in items] == [w.id for w in want[k]] and len(items) > 0
        assert all(i.source == url for i in items)
    assert len(whole) >= sum(len(v) for v in want.values())
    read_source(path, ReaderOptions(), name, None, None, (path, url), source["fetch"])  # the whole file: copied whole
    assert Path(path).read_bytes() == original and not copied.exists()


def test_a_worker_copies_only_the_row_groups_of_its_geoparquet_range(s3, tmp_path):
    """A GeoParquet file on S3 read in feature ranges by workers without the planner's copy: each task copies only
    its first row group, its rows' row groups and the footer into a sparse file, and reads its rows as from the
    whole file; row groups no task asked for stay zeros. A file whose rows are grouped across it (OpenStreetMap ids)
    is copied whole."""
    import json as jsonlib

    import pyarrow as pa
    import pyarrow.parquet as pq
    import shapely

    from meshsom.gis import gis_ranges, parquet_spans
    from meshsom.io import ReaderOptions, read_file
    from meshsom.mirror import SPANS_SUFFIX, mirror_inputs
    from pipelines.corpus import _feature_fetch, read_source
    from footprints import write_geoparquet

    local = tmp_path / "in" / "city.parquet"
    local.parent.mkdir()
    rows = [(f"r{k}", shapely.geometry.mapping(shapely.box(3 * k, 0, 3 * k + 2, 2)), {"height": 3.0 + k % 5})
            for k in range(1000)]
    write_geoparquet(tmp_path / "plain.parquet", rows, crs="EPSG:28992")
    pq.write_table(pq.read_table(tmp_path / "plain.parquet"), local, row_group_size=97)
    url = f"s3://{BUCKET}/parquet/city"
    _upload(local.parent, url)
    mirrored = mirror_inputs([url], tmp_path / "mirror")
    path = str(Path(mirrored.paths[0]) / "city.parquet")
    ranges = gis_ranges(Path(path), 300, ReaderOptions())
    assert [r[4:] for r in ranges] == [[0, 300], [300, 600], [600, 900], [900, 1000]]
    source = {"path": path, "fetch": [dataclasses.asdict(c) for c in mirrored.copies.values()]}
    fetches = {k: _feature_fetch(source, ranges[k]) for k in (2, 3)}  # the planner's, from its copy
    shutil.rmtree(tmp_path / "mirror")
    for k, fetch in fetches.items():
        got = read_source(path, ReaderOptions(), "city.parquet", None, ranges[k], (path, f"{url}/city.parquet"), fetch)
        want = list(read_file(local, ReaderOptions(), "city.parquet", feature_range=ranges[k]))
        assert [g.id for g in got] == [w.id for w in want] and len(got) == ranges[k][5] - ranges[k][4]
        assert all(np.array_equal(g.vertices, w.vertices) for g, w in zip(got, want))
    data, original = Path(path).read_bytes(), local.read_bytes()
    for a, b in jsonlib.loads(Path(f"{path}{SPANS_SUFFIX}").read_text()):
        assert data[a:b] == original[a:b]
    meta = pq.ParquetFile(local).metadata
    untouched = meta.row_group(3).column(0)  # rows 291-387: range 1's alone, which no task read
    a = untouched.dictionary_page_offset or untouched.data_page_offset
    assert data[a:a + untouched.total_compressed_size].strip(b"\0") == b""
    assert sum(b - a for a, b in parquet_spans(local, 600, 900)) < 0.6 * len(original)
    table = pq.read_table(local)  # OpenStreetMap ids in a column: read across the file, so copied whole
    pq.write_table(table.append_column("osm_way_id", pa.array([str(k) for k in range(1000)])), tmp_path / "osm.parquet")
    assert parquet_spans(tmp_path / "osm.parquet", 0, 300) is None


def test_the_planner_copies_placeholders_of_the_files_it_never_opens(s3, tmp_path):
    """Meshes (OBJ, glTF, CAD models) are opened by their read tasks only: the planner's copy of such a file is a
    placeholder of its size, no bytes copied, listed as such, and the read task copies it whole; a footprint file,
    which the planner reads to plan, is copied; a CityJSON file is a placeholder where it is too small to split."""
    from meshsom.io import ReaderOptions, read_file
    from meshsom.mirror import SPANS_SUFFIX, companions, mirror_inputs, unopened_below
    from pipelines.corpus import read_source

    local = _city_folder(tmp_path / "city")
    url = f"s3://{BUCKET}/placeholders/city"
    _upload(local, url)
    mirrored = mirror_inputs([url], tmp_path / "mirror")
    (root,) = mirrored.paths
    obj = next(Path(root).glob("objs/*.obj"))
    original = local / "objs" / obj.name
    assert obj.stat().st_size == original.stat().st_size and obj.read_bytes().strip(b"\0") == b""
    assert Path(f"{obj}{SPANS_SUFFIX}").read_text() == "[]"
    for name in ("zurich.city.json", "footprints.shp", "footprints.dbf", "objs/labels.csv"):
        assert (Path(root) / name).read_bytes() == (local / name).read_bytes(), name
    fetch = [dataclasses.asdict(c) for c in companions(obj, mirrored.copies)]
    got = read_source(str(obj), ReaderOptions(), f"objs/{obj.name}", rename=(root, url), fetch=fetch)
    want = list(read_file(original, ReaderOptions(), f"objs/{obj.name}"))
    assert obj.read_bytes() == original.read_bytes() and not Path(f"{obj}{SPANS_SUFFIX}").exists()
    assert [g.id for g in got] == [w.id for w in want] and got[0].label == want[0].label is not None
    # the pipeline's test: a CityJSON tile too small to split or cut is a placeholder too; a larger one is copied
    for limit, placeholder in ((100_000, True), (1_000, False)):
        shutil.rmtree(tmp_path / "mirror")
        root = mirror_inputs([f"{url}/zurich.city.json"], tmp_path / "mirror", unopened=unopened_below(limit)).paths[0]
        assert Path(f"{root}{SPANS_SUFFIX}").exists() == placeholder
        assert (Path(root).read_bytes() == (local / "zurich.city.json").read_bytes()) != placeholder
