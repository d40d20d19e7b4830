"""Ingest + encode through Dask (pipelines/corpus.py): same store as one process, whatever the shard size;
every input accounted for; resume redoes only unfinished shards and equals an uninterrupted run."""

import json
import warnings
from pathlib import Path

import numpy as np
import pytest
import zarr
from distributed import Client, LocalCluster

from meshsom.config import build
from pipelines.settings import RunConfig
from meshsom.errors import MeshsomError, StoreError
from meshsom.io import ReaderOptions, read_file
from meshsom.store import mesh_table, open_store, read_manifest
from pipelines import corpus, ingest
from pipelines.cli import main

ZURICH = Path(__file__).resolve().parents[1] / "data" / "real" / "zurich-lod2-subset" / "zurich_subset_lod1_derived.city.json"
N_ZURICH, N_BLOCKS, CHUNK = 49, 12, 500


@pytest.fixture(scope="module")
def inputs(tmp_path_factory):
    """The bundled Zurich file, a file that cannot be read, a path that does not exist."""
    tmp = tmp_path_factory.mktemp("inputs")
    broken = tmp / "broken.city.json"
    broken.write_text('{"type": "CityJSON", "CityObjects": {')
    return [str(ZURICH), str(broken), str(tmp / "missing.obj")]


def config(inputs, shard_meshes, levels=(1, 2)):
    return build(RunConfig, {
        "corpus": {"paths": list(inputs), "generator": {"n_blocks": N_BLOCKS, "seed": 0}},
        "encoding": {"levels": list(levels)},
        "dask": {"shard_meshes": shard_meshes},
        "store": {"chunk_rows": CHUNK},
    })


@pytest.fixture(scope="module")
def cluster_client():
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=":0") as cluster, \
            Client(cluster) as client:
        yield client


@pytest.fixture(scope="module")
def local_client():
    with Client(processes=False, n_workers=1, threads_per_worker=1, dashboard_address=":0") as client:
        yield client


@pytest.fixture(scope="module")
def two_workers(cluster_client, inputs, tmp_path_factory):
    """Store made on 2 worker processes, 3 meshes per shard; and the progress calls."""
    store = tmp_path_factory.mktemp("dask") / "two.zarr"
    calls = []
    summary = corpus.run_corpus(cluster_client, config(inputs, 3), store, progress=lambda *a: calls.append(a))
    return store, summary, calls


@pytest.fixture(scope="module")
def in_process(local_client, inputs, tmp_path_factory):
    """Store made by an in-process client, 50 meshes per shard."""
    store = tmp_path_factory.mktemp("dask") / "one.zarr"
    corpus.run_corpus(local_client, config(inputs, 50), store)
    return store


@pytest.fixture(scope="module")
def cli_store(inputs, tmp_path_factory):
    """Store made in one process by `meshsom ingest` then `meshsom encode`."""
    store = tmp_path_factory.mktemp("cli") / "cli.zarr"
    assert main(["ingest", *inputs, "--generate", str(N_BLOCKS), "--seed", "0", "--out", str(store),
                 "--chunk-rows", str(CHUNK)]) == 0
    assert main(["encode", str(store), "--levels", "1", "2", "--json"]) == 0
    return store


def arrays(store) -> dict:
    """Every array of a store by path."""
    out = {}

    def walk(group, prefix):
        for name, node in group.members():
            if isinstance(node, zarr.Group):
                walk(node, prefix + name + "/")
            else:
                out[prefix + name] = node

    with warnings.catch_warnings():  # manifest.json is no zarr node
        warnings.simplefilter("ignore", zarr.errors.ZarrUserWarning)
        walk(zarr.open_group(str(store), mode="r"), "")
    return out


def stats(store) -> dict:
    return dict(zarr.open_group(str(store), mode="r")["rings/stats"].attrs)


def assert_same_store(a, b, exact_stats=True):
    """Same arrays (names, shapes, dtypes, chunks, values), root attributes, manifest and statistics."""
    xa, xb = arrays(a), arrays(b)
    assert sorted(xa) == sorted(xb)
    assert {"vertices", "faces", "face_mesh", "meshes/ids", "meshes/labels", "meshes/vertex_offsets",
            "meshes/face_offsets", "meshes/origins", "rings/level1", "rings/level2"} == set(xa)
    for name in xa:
        u, v = xa[name], xb[name]
        assert (u.shape, u.dtype, u.chunks) == (v.shape, v.dtype, v.chunks), name
        assert np.array_equal(np.asarray(u[:]), np.asarray(v[:])), name
    assert dict(zarr.open_group(str(a), mode="r").attrs) == dict(zarr.open_group(str(b), mode="r").attrs)
    ma, mb = read_manifest(a), read_manifest(b)
    assert ma["records"] == mb["records"]
    assert ma["summary"] == mb["summary"]
    sa, sb = stats(a), stats(b)
    assert sorted(sa) == sorted(sb) == ["folds_level1", "folds_level2", "level1", "level2"]
    for name in ("folds_level1", "folds_level2"):  # from the stored float32 folds: equal
        assert sa.pop(name) == sb.pop(name)
    for level in sa:
        if exact_stats:
            assert sa[level] == sb[level]
        else:  # the single-process encoder sums in other batches: float64 rounding apart
            assert sa[level]["count"] == sb[level]["count"]
            np.testing.assert_allclose(sa[level]["mean"], sb[level]["mean"], rtol=1e-12, atol=1e-15)
            np.testing.assert_allclose(sa[level]["std"], sb[level]["std"], rtol=1e-12)


def test_two_workers_equal_in_process_whatever_the_shard_size(two_workers, in_process):
    store, summary, calls = two_workers
    assert_same_store(store, in_process)
    assert not (store / corpus.STAGING).exists() and not (in_process / corpus.STAGING).exists()
    assert summary == read_manifest(store)["summary"]
    n_shards = -(-N_ZURICH // 3) + 1 + -(-N_BLOCKS // 3)
    assert ("encode", n_shards, n_shards) in calls and calls[-1][0] == "assemble" and calls[-1][1] == calls[-1][2]
    assert len(arrays(store)["faces"].shape) == 2 and arrays(store)["faces"].shape[0] > 2 * CHUNK  # several chunks


def test_equals_single_process_ingest_then_encode(two_workers, cli_store):
    assert_same_store(two_workers[0], cli_store, exact_stats=False)


def test_every_input_is_accounted_for(two_workers, inputs):
    store = two_workers[0]
    doc = read_manifest(store)
    s = doc["summary"]
    assert s["inputs"] == N_ZURICH + N_BLOCKS + 2 == s["accepted"] + s["rejected"] == len(doc["records"])
    rejected = {r["id"]: r["reason"] for r in doc["records"] if r["status"] == "rejected"}
    assert rejected[Path(inputs[1]).name].startswith("invalid JSON")  # read on a worker; id: the name given
    assert rejected[inputs[2]] == "no such file or folder"  # found missing by the client
    accepted = [r for r in doc["records"] if r["status"] == "accepted"]
    assert [r["index"] for r in accepted] == list(range(len(accepted)))
    ids = mesh_table(open_store(store)).ids
    assert list(ids) == [r["id"] for r in accepted]
    assert ids[0].startswith(ZURICH.name) and ids[-1] == f"synthetic#block-{N_BLOCKS - 1:05d}"


def test_resume_redoes_only_unfinished_shards(local_client, inputs, in_process, tmp_path, monkeypatch):
    store = tmp_path / "resumed.zarr"
    cfg = config(inputs, 10)  # zurich: 5 shards, broken file: 1, generator: 2
    zurich_ids = [m.id for m in read_file(ZURICH, ReaderOptions())]
    poison = {zurich_ids[25], "synthetic#block-00011"}  # in shards s0000-00000020 and s0002-00000010
    original = ingest.process_one
    seen = []

    def crashing(raw, params):
        if raw.id in poison:
            raise RuntimeError(f"worker lost while processing {raw.id}")
        return original(raw, params)

    monkeypatch.setattr(ingest, "process_one", crashing)
    with pytest.raises(MeshsomError, match=r"2 of 8 shards failed.*RuntimeError.*meshsom run --resume"):
        corpus.run_corpus(local_client, cfg, store)
    plan = zarr.open_group(str(store / corpus.STAGING), mode="r").attrs["plan"]
    names = [s["name"] for s in plan["shards"]]
    done = [n for n in names if corpus.shard_done(str(store), n)]
    assert sorted(set(names) - set(done)) == ["s0000-00000020", "s0002-00000010"]
    # A shard written but not yet marked (killed between write and mark) counts as unfinished.
    zarr.open_group(str(store / corpus.STAGING / "s0000-00000000"), mode="r+").attrs["done"] = False

    with pytest.raises(StoreError, match=str(store)):  # another configuration is refused
        corpus.run_corpus(local_client, config(inputs, 10, levels=(1,)), store, resume=True)

    def counting(raw, params):
        seen.append(raw.id)
        return original(raw, params)

    monkeypatch.setattr(ingest, "process_one", counting)
    summary = corpus.run_corpus(local_client, cfg, store, resume=True)
    assert sorted(seen) == sorted(zurich_ids[0:10] + zurich_ids[20:30] + ["synthetic#block-00010", "synthetic#block-00011"])
    assert_same_store(store, in_process)
    assert summary == read_manifest(in_process)["summary"]

    seen.clear()  # a finished corpus is not redone at all
    assert corpus.run_corpus(local_client, cfg, store, resume=True) == summary
    assert seen == []


def test_worker_functions_without_a_cluster(inputs, tmp_path):
    """The shard function alone: staging rows, metadata that is JSON, done mark, no recomputation."""
    from meshsom.preprocess import PreprocessParams
    from meshsom.store import create_store

    store = tmp_path / "s.zarr"
    create_store(store)
    items = corpus.generate_items(build(RunConfig, {"corpus": {"generator": {"n_blocks": 2}}}).corpus.generator, 0, 2)
    items += corpus.read_source(inputs[1], ReaderOptions())
    shard = corpus.Shard("s0000-00000", 0, 0, 3)
    meta = corpus.process_shard(str(store), shard, items, PreprocessParams(), [1, 2], CHUNK)
    assert json.loads(json.dumps(meta)) == meta
    assert [r["status"] for r in meta["records"]] == ["accepted", "accepted", "rejected"]
    g = zarr.open_group(str(store / corpus.STAGING / shard.name), mode="r")
    assert g.attrs["done"] and g["faces"].shape[0] == sum(meta["n_faces"]) == g["level2"].shape[0]
    assert np.asarray(g["faces"][:]).max() == sum(meta["n_vertices"]) - 1
    assert np.array_equal(np.asarray(g["face_mesh"][:]), np.repeat([0, 1], meta["n_faces"]))
    assert np.asarray(meta["acc"]["1"]).shape == (2, 3, 3)
    assert corpus.process_shard(str(store), shard, [], PreprocessParams(), [1, 2], CHUNK) == meta  # done: kept


def test_ingest_then_encode_is_bitwise_the_corpus_stage_of_run(two_workers, local_client, inputs, tmp_path):
    """`meshsom ingest` + `meshsom encode` (several encode shards) against `run_corpus`, the corpus stage of
    `meshsom run`: every array bitwise, the statistics exactly, for standard and robust scaling."""
    store = tmp_path / "cli.zarr"
    assert main(["ingest", *inputs, "--generate", str(N_BLOCKS), "--seed", "0", "--out", str(store),
                 "--chunk-rows", str(CHUNK)]) == 0
    assert main(["encode", str(store), "--levels", "1", "2", "--batch-faces", "300", "--json"]) == 0
    assert_same_store(two_workers[0], store, exact_stats=True)

    robust = tmp_path / "robust.zarr"
    cfg = build(RunConfig, {
        "corpus": {"paths": [], "generator": {"n_blocks": N_BLOCKS, "seed": 3}},
        "encoding": {"levels": [1, 2], "scaling": "robust", "robust_clip": 4.0},
        "dask": {"shard_meshes": 5}, "store": {"chunk_rows": 128},
    })
    corpus.run_corpus(local_client, cfg, robust)
    assert main(["ingest", "--generate", str(N_BLOCKS), "--seed", "3", "--out", str(tmp_path / "r2.zarr"),
                 "--chunk-rows", "128"]) == 0
    assert main(["encode", str(tmp_path / "r2.zarr"), "--levels", "2", "1", "--batch-faces", "100",
                 "--scaling", "robust", "--robust-clip", "4", "--json"]) == 0
    assert_same_store(robust, tmp_path / "r2.zarr", exact_stats=True)
    assert stats(robust)["level1"]["scaling"] == "robust" and stats(robust)["level1"]["clip"] == 4.0


def test_a_large_cityjsonseq_file_is_read_by_several_tasks(cluster_client, tmp_path):
    """A city in one CityJSONSeq file: read in byte ranges by tasks of their own (no worker holds
    the whole city), the store is the one a single reader of the file gives. A building repeated
    far from its first copy (another range) is still a rejection of its own; so is a bad line."""
    from cityjson_samples import to_cityjsonseq, write_lines

    lines = to_cityjsonseq(json.loads(ZURICH.read_text()))
    seq = tmp_path / "city.city.jsonl"
    write_lines(seq, lines[:20] + ["{not json"] + lines[20:] + [lines[3]])
    stores, reads = {}, {}
    for read_bytes in (1 << 30, 3000):
        cfg = build(RunConfig, {"corpus": {"paths": [str(seq)]}, "encoding": {"levels": [1, 2]},
                                "dask": {"shard_meshes": 7, "read_bytes": read_bytes}, "store": {"chunk_rows": CHUNK}})
        stores[read_bytes] = store = tmp_path / f"r{read_bytes}.zarr"
        calls = []
        corpus.run_corpus(cluster_client, cfg, store, progress=lambda *a: calls.append(a))
        reads[read_bytes] = {total for stage, _, total in calls if stage == "read"}
    whole, ranged = stores[1 << 30], stores[3000]
    assert reads[1 << 30] == {1} and min(reads[3000]) > 10  # read tasks: one, or one per range
    a, b = read_manifest(whole)["records"], read_manifest(ranged)["records"]
    assert [(r["id"], r["status"]) for r in a] == [(r["id"], r["status"]) for r in b]
    assert len(a) == N_ZURICH + 2
    repeat = a[-1]["id"]
    assert repeat.endswith(" (2)") and a[-1]["status"] == "rejected"
    assert a[-1]["reason"].startswith(f"line {len(lines) + 2}: object id repeated (first on line 4)")  # + the bad line
    assert b[-1]["reason"].startswith("id repeated: an earlier object of the file has the id")  # found across ranges
    assert [r for r in a if r["id"] != repeat] == [r for r in b if r["id"] != repeat]
    for name, array in arrays(whole).items():
        assert np.array_equal(np.asarray(array[:]), np.asarray(arrays(ranged)[name][:])), name


def test_a_large_cityjson_file_is_split_and_read_by_several_tasks(cluster_client, tmp_path):
    """A city in one CityJSON file (its objects sharing one vertex list: it cannot be read in pieces) of twice
    dask.read_bytes or more: split into a CityJSONSeq in the store's staging group (meshsom.cityjson_split), read in
    byte ranges by tasks of their own; the store is the one a single reader of the file gives, records naming the
    file as their source, and the sequence is gone with the staging group once the run is done."""
    import shutil

    city = tmp_path / "zurich.city.json"
    shutil.copy(ZURICH, city)
    stores, reads = {}, {}
    for read_bytes in (1 << 30, 8_000):
        cfg = build(RunConfig, {"corpus": {"paths": [str(city)]}, "encoding": {"levels": [1, 2]},
                                "dask": {"shard_meshes": 7, "read_bytes": read_bytes}, "store": {"chunk_rows": CHUNK}})
        stores[read_bytes] = store = tmp_path / f"r{read_bytes}.zarr"
        calls = []
        corpus.run_corpus(cluster_client, cfg, store, progress=lambda *a: calls.append(a))
        reads[read_bytes] = {total for stage, _, total in calls if stage == "read"}
        assert not (store / corpus.STAGING).exists()
    whole, split = stores[1 << 30], stores[8_000]
    assert reads[1 << 30] == {1} and min(reads[8_000]) >= 5  # read tasks: one, or one per range
    a, b = read_manifest(whole)["records"], read_manifest(split)["records"]
    assert len(a) == N_ZURICH and a == b
    assert {r["source"] for r in b} == {str(city)}
    for name, array in arrays(whole).items():
        assert np.array_equal(np.asarray(array[:]), np.asarray(arrays(split)[name][:])), name


def test_a_zip_archive_is_read_by_a_task_per_file_and_range(cluster_client, tmp_path, monkeypatch):
    """A download zipped (a CityJSON city, a GeoPackage layer, a CityGML tile, a zip inside it, a damaged file): the
    planner extracts it into the store's staging group and its files are read by tasks of their own (the CityJSON
    split, the layer in ranges); the records (ids, sources naming the archive's members, reasons) are those the
    archive read whole by one task gives (meshsom.archives.read_zip), and the staging group is gone afterwards; where
    the store's disk has no room for the files extracted, one task reads the archive, as before."""
    import shutil
    import zipfile

    import fiona

    from footprints import L_SHAPE, closed
    from meshsom.preprocess import PreprocessParams
    from pipelines.ingest import process_one
    from test_citygml import to_citygml

    folder = tmp_path / "download"
    (folder / "tiles").mkdir(parents=True)
    shutil.copy(ZURICH, folder / "tiles" / "zurich.city.json")
    (folder / "tiles" / "tile.gml").write_text(to_citygml(json.loads(ZURICH.read_text())))
    schema = {"geometry": "Polygon", "properties": {"id": "str", "height": "float"}}
    with fiona.open(folder / "footprints.gpkg", "w", driver="GPKG", layer="pand", schema=schema, crs="EPSG:28992") as out:
        out.writerecords({"geometry": {"type": "Polygon", "coordinates": [closed(
            [(84600 + x + 30 * (k % 10), 447400 + y + 30 * (k // 10)) for x, y in L_SHAPE])]},
            "properties": {"id": f"p{k}", "height": 3.0 + k % 4 if k % 9 else None}} for k in range(60))
    (folder / "broken.city.json").write_text('{"type": "CityJSON", "version": "2.0", "CityObjects": {')
    with zipfile.ZipFile(folder / "inner.zip", "w") as inner:
        inner.writestr("x.obj", "v 0 0 0\n")
    archive = tmp_path / "in" / "download.zip"
    archive.parent.mkdir()
    with zipfile.ZipFile(archive, "w", zipfile.ZIP_DEFLATED) as z:
        for f in sorted(folder.rglob("*")):
            if f.is_file():
                z.write(f, f.relative_to(folder).as_posix())
    cfg = build(RunConfig, {"corpus": {"paths": [str(archive.parent)]}, "encoding": {"levels": [1]},
                            "dask": {"shard_meshes": 16, "read_features": 20, "read_bytes": 8_000},
                            "store": {"chunk_rows": CHUNK}})
    store = tmp_path / "z.zarr"
    calls = []
    corpus.run_corpus(cluster_client, cfg, store, progress=lambda *a: calls.append(a))
    assert max(total for stage, _, total in calls if stage == "read") >= 3 + 5 + 1  # the layer's, the city's, ...
    assert ("unpack", 1, 1) in calls and ("plan", 4, 4) in calls  # progress: the archive, then its four files to read
    assert not (store / corpus.STAGING).exists()
    got = {r["id"]: r for r in read_manifest(store)["records"]}
    whole = {}
    for item in read_file(archive, cfg.corpus.reader):
        record, _ = process_one(item, PreprocessParams())
        whole[record["id"]] = record
    assert sorted(got) == sorted(whole) and len(got) == N_ZURICH * 2 + 60 + 2
    for key, record in whole.items():
        mine = got[key]
        assert (mine["status"], mine["source"], mine.get("reason")) == (
            record["status"], record["source"], record.get("reason")), key
        assert mine["source"].startswith(f"{archive}!/"), mine["source"]
        if record["status"] == "accepted":
            assert mine["faces_out"] == record["faces_out"] and mine["volume"] == pytest.approx(record["volume"]), key
    monkeypatch.setattr(corpus, "UNZIP_DISK_SHARE", 0.0)  # no room to extract beside the store: one task reads it
    calls = []
    corpus.run_corpus(cluster_client, cfg, tmp_path / "one.zarr", progress=lambda *a: calls.append(a))
    assert {total for stage, _, total in calls if stage == "read"} == {1}
    assert {r["id"]: (r["status"], r["source"]) for r in read_manifest(tmp_path / "one.zarr")["records"]} == {
        k: (r["status"], r["source"]) for k, r in got.items()}


def test_split_cityjson_writes_what_the_document_reads_as(tmp_path):
    """meshsom.cityjson_split.split_cityjson: the sequence it writes reads as the document (ids, labels, parts,
    LoDs, coordinates, faces), for the bundled Delft (1.0, 3dfier) and Zürich (1.1, parts) files; a document whose
    boundaries name a vertex it lacks, and a GeoJSON file, are not split (read whole, their reader says why)."""
    from meshsom.cityjson_split import split_cityjson

    real = Path(__file__).resolve().parents[1] / "data" / "real"
    for original in (real / "delft-lod1-3dfier" / "delft.city.json", real / "zurich-lod2-subset" / "zurich_subset_lod2.city.json"):
        out = tmp_path / f"{original.stem}.city.jsonl"
        count = split_cityjson(original, out, ReaderOptions())
        assert count and len(out.read_text().splitlines()) == count + 1
        want = list(read_file(original))
        got = list(read_file(out, ReaderOptions(), original.name))
        assert [m.id for m in got] == [m.id for m in want] and len(want) > 40
        for a, b in zip(want, got):
            assert type(a) is type(b) and (getattr(a, "label", None), getattr(a, "lod", None)) == (
                getattr(b, "label", None), getattr(b, "lod", None)), a.id
            if hasattr(a, "faces"):
                assert a.parts == b.parts and np.array_equal(a.faces, b.faces), a.id
                assert np.allclose(a.vertices + a.origin, b.vertices + b.origin, rtol=0, atol=1e-9), a.id
    broken = json.loads(ZURICH.read_text())
    first = next(iter(broken["CityObjects"].values()))
    first["geometry"][0]["boundaries"] = [[[len(broken["vertices"]) + 5, 0, 1]]]
    (tmp_path / "broken.city.json").write_text(json.dumps(broken))
    assert split_cityjson(tmp_path / "broken.city.json", tmp_path / "b.city.jsonl", ReaderOptions()) is None
    (tmp_path / "f.geojson").write_text(json.dumps({"type": "FeatureCollection", "features": []}))
    assert split_cityjson(tmp_path / "f.geojson", tmp_path / "f.city.jsonl", ReaderOptions()) is None
    assert not (tmp_path / "b.city.jsonl").exists() and not (tmp_path / "f.city.jsonl").exists()


def test_large_gzipped_sequences_and_collections_are_read_in_ranges(cluster_client, tmp_path):
    """A gzipped CityJSONSeq and a gzipped GeoJSON FeatureCollection (gzip cannot be entered mid-stream): the planner
    decompresses each into the store's staging group and tasks read them in ranges; the stores are the ones one
    task per file gives, the records naming the gzipped files as their sources; a truncated one is read whole, its
    reader saying what is wrong."""
    import gzip

    from cityjson_samples import to_cityjsonseq, write_lines
    from test_geojson import _big_collection

    seq = tmp_path / "in" / "city.city.jsonl"
    seq.parent.mkdir()
    write_lines(seq, to_cityjsonseq(json.loads(ZURICH.read_text())))
    (tmp_path / "in" / "city.city.jsonl.gz").write_bytes(gzip.compress(seq.read_bytes()))
    seq.unlink()
    (tmp_path / "in" / "footprints.geojson.gz").write_bytes(gzip.compress(_big_collection(120).encode()))
    (tmp_path / "in" / "cut.geojson.gz").write_bytes(gzip.compress(_big_collection(120).encode())[:-2000])
    stores, reads = {}, {}
    for read_bytes, read_features in ((1 << 30, 10**6), (8_000, 25)):
        cfg = build(RunConfig, {"corpus": {"paths": [str(tmp_path / "in")]}, "encoding": {"levels": [1]},
                                "dask": {"shard_meshes": 16, "read_bytes": read_bytes, "read_features": read_features},
                                "store": {"chunk_rows": CHUNK}})
        stores[read_bytes] = store = tmp_path / f"g{read_bytes}.zarr"
        calls = []
        corpus.run_corpus(cluster_client, cfg, store, progress=lambda *a: calls.append(a))
        reads[read_bytes] = max(total for stage, _, total in calls if stage == "read")
        assert not (store / corpus.STAGING).exists()
    assert reads[1 << 30] == 3 and reads[8_000] >= 1 + 5 + 3
    a, b = read_manifest(stores[1 << 30])["records"], read_manifest(stores[8_000])["records"]
    assert sorted(a, key=lambda r: r["id"]) == sorted(b, key=lambda r: r["id"])
    assert {r["source"] for r in b} == {str(tmp_path / "in" / n) for n in ("city.city.jsonl.gz", "footprints.geojson.gz",
                                                                         "cut.geojson.gz")}
    (cut,) = [r for r in b if r["source"].endswith("cut.geojson.gz")]
    assert cut["status"] == "rejected" and "ends early" in cut["reason"], cut


def test_a_large_osm_bz2_is_made_pbf_once_and_read_in_ranges(cluster_client, tmp_path, monkeypatch):
    """A bzip2-compressed OpenStreetMap extract read in ranges: the planner writes it as PBF into the store's staging
    group once (each range's task would convert it again), the tasks read the PBF; the records equal those of one task
    reading the .bz2, naming it as their source."""
    import bz2
    import sys

    from meshsom import osm

    sys.path.insert(0, str(Path(__file__).parent))
    from test_osm import _district

    xml, _ = _district(tmp_path / "d.osm")
    (tmp_path / "in").mkdir()
    (tmp_path / "in" / "d.osm.bz2").write_bytes(bz2.compress(xml.read_bytes()))
    converted = []
    convert = osm.bzip2_as_pbf
    monkeypatch.setattr(osm, "bzip2_as_pbf", lambda *a: converted.append(a[0]) or convert(*a))
    records, reads = {}, {}
    for read_features in (10**6, 2):
        cfg = build(RunConfig, {"corpus": {"paths": [str(tmp_path / "in")], "reader": {"default_height": 9.0}},
                                "encoding": {"levels": [1]}, "store": {"chunk_rows": CHUNK},
                                "dask": {"shard_meshes": 16, "read_features": read_features}})
        store = tmp_path / f"o{read_features}.zarr"
        calls = []
        corpus.run_corpus(cluster_client, cfg, store, progress=lambda *a: calls.append(a))
        reads[read_features] = max(total for stage, _, total in calls if stage == "read")
        records[read_features] = sorted(read_manifest(store)["records"], key=lambda r: r["id"])
        assert not (store / corpus.STAGING).exists()
    assert reads[10**6] == 1 and reads[2] > 2 and converted == [tmp_path / "in" / "d.osm.bz2"]
    assert records[2] == records[10**6] and len(records[2]) == 10
    assert {r["source"] for r in records[2]} == {str(tmp_path / "in" / "d.osm.bz2")}


def test_repeated_ids_across_ranges_get_the_next_free_number():
    sources = [{"path": "a", "range": [0, 1, 2]}, {"path": "a", "range": [1, 2, 3]}, {"path": "b"}]
    ids = [["x", "x (2)", "y"], ["x", "z", "y"], ["x"]]
    assert corpus.repeated_ids(sources, ids) == [{}, {"0": "x (3)", "2": "y (2)"}, {}]


def test_a_file_read_in_ranges_that_holds_no_building_is_listed(cluster_client, tmp_path):
    from cityjson_samples import write_lines

    road = {"type": "CityJSONFeature", "id": "r", "CityObjects": {"r": {"type": "Road", "geometry": []}}, "vertices": []}
    header = {"type": "CityJSON", "version": "2.0", "transform": {"scale": [0.001] * 3, "translate": [0, 0, 0]},
              "CityObjects": {}, "vertices": []}
    seq = tmp_path / "roads.city.jsonl"
    write_lines(seq, [header] + [{**road, "id": f"r{k}", "CityObjects": {f"r{k}": road["CityObjects"]["r"]}} for k in range(200)])
    cfg = build(RunConfig, {"corpus": {"paths": [str(seq)]}, "encoding": {"levels": [1]},
                            "dask": {"read_bytes": 1000}, "store": {"chunk_rows": CHUNK}})
    corpus.run_corpus(cluster_client, cfg, tmp_path / "roads.zarr")
    (record,) = read_manifest(tmp_path / "roads.zarr")["records"]
    assert record["id"] == "roads.city.jsonl" and record["status"] == "rejected"
    assert record["reason"] == "holds no object of the types Building"


def test_a_large_gis_file_is_read_by_several_tasks(cluster_client, tmp_path):
    """A GeoPackage of two layers and a GeoParquet file, read in feature ranges (the ids of a layer
    decided once): the store is the one a single reader of each file gives."""
    import fiona
    import shapely

    from footprints import L_SHAPE, closed, write_geoparquet

    def footprint(k):
        return {"type": "Polygon", "coordinates": [closed([(84600 + x + 30 * (k % 20), 447400 + y + 30 * (k // 20)) for x, y in L_SHAPE])]}

    gpkg = tmp_path / "city.gpkg"
    schema = {"geometry": "Polygon", "properties": {"id": "str", "height": "float"}}
    for layer, n in (("a", 130), ("b", 40)):
        with fiona.open(gpkg, "w", driver="GPKG", layer=layer, schema=schema, crs="EPSG:28992") as out:
            out.writerecords({"geometry": footprint(k), "properties": {"id": f"{layer}{k}", "height": 3.0 + k % 5 if k % 17 else None}}
                             for k in range(n))
    rows = [(f"p{k}", footprint(k), {"height": 4.0 + k % 3}) for k in range(130)]
    write_geoparquet(tmp_path / "city.parquet", rows, crs=None, wkb=[shapely.to_wkb(shapely.geometry.shape(g)) for _, g, _ in rows])
    stores, reads = {}, {}
    for read_features in (10**6, 50):
        cfg = build(RunConfig, {"corpus": {"paths": [str(gpkg), str(tmp_path / "city.parquet")]}, "encoding": {"levels": [1]},
                                "dask": {"shard_meshes": 16, "read_features": read_features}, "store": {"chunk_rows": CHUNK}})
        stores[read_features] = store = tmp_path / f"f{read_features}.zarr"
        calls = []
        corpus.run_corpus(cluster_client, cfg, store, progress=lambda *a: calls.append(a))
        reads[read_features] = {total for stage, _, total in calls if stage == "read"}
    whole, ranged = stores[10**6], stores[50]
    assert reads[10**6] == {2} and reads[50] == {3 + 1 + 3}
    a, b = read_manifest(whole)["records"], read_manifest(ranged)["records"]
    assert a == b and len(a) == 130 + 40 + 130
    assert a[0]["id"] == "city.gpkg#a/a0" and a[130]["id"] == "city.gpkg#b/b0" and a[-1]["id"] == "city.parquet#p129"
    assert sum(r["status"] == "rejected" for r in a) == len([k for k in range(130) if k % 17 == 0]) + len(
        [k for k in range(40) if k % 17 == 0])  # no height
    for name, array in arrays(whole).items():
        assert np.array_equal(np.asarray(array[:]), np.asarray(arrays(ranged)[name][:])), name


def test_a_large_feature_collection_is_read_by_several_tasks(cluster_client, tmp_path):
    """A city's footprints in one GeoJSON FeatureCollection: read by one task, or by a task per range of features
    (dask.read_features; meshsom.geojson.geojson_ranges), so that no worker holds the whole city; the stores are
    the same."""
    from test_geojson import _big_collection

    path = tmp_path / "city.geojson"
    path.write_text(_big_collection(120))
    stores, reads = {}, {}
    for read_features in (10**6, 25):
        cfg = build(RunConfig, {"corpus": {"paths": [str(path)]}, "encoding": {"levels": [1]},
                                "dask": {"shard_meshes": 16, "read_features": read_features}, "store": {"chunk_rows": CHUNK}})
        stores[read_features] = store = tmp_path / f"f{read_features}.zarr"
        calls = []
        corpus.run_corpus(cluster_client, cfg, store, progress=lambda *a: calls.append(a))
        reads[read_features] = {total for stage, _, total in calls if stage == "read"}
    assert reads[10**6] == {1} and reads[25] == {5}
    a, b = read_manifest(stores[10**6])["records"], read_manifest(stores[25])["records"]
    assert a == b and len(a) == 120 and sum(r["status"] == "accepted" for r in a) == 119
    for name, array in arrays(stores[10**6]).items():
        assert np.array_equal(np.asarray(array[:]), np.asarray(arrays(stores[25])[name][:])), name


def test_a_large_osm_extract_is_read_by_several_tasks(cluster_client, tmp_path):
    """An OpenStreetMap extract planned as several read tasks (each parses the file and builds
    the meshes of its range of buildings, parts with their building): the store is the one a
    single reader gives, and a file of no buildings is one rejection however many tasks read it."""
    from test_osm import OsmWriter, _district

    from meshsom.osm import osm_ranges

    path, _ = _district(tmp_path / "d.osm")
    density_ranges = osm_ranges(path, 1, None)
    assert density_ranges is not None and len(density_ranges) > 3  # a few kilobytes, one building per task asked
    stores, reads = {}, {}
    for read_features in (10**6, 2):
        cfg = build(RunConfig, {"corpus": {"paths": [str(path)], "reader": {"default_height": 6.0}}, "encoding": {"levels": [1]},
                                "dask": {"shard_meshes": 4, "read_features": read_features}, "store": {"chunk_rows": CHUNK}})
        stores[read_features] = store = tmp_path / f"o{read_features}.zarr"
        calls = []
        corpus.run_corpus(cluster_client, cfg, store, progress=lambda *a: calls.append(a))
        reads[read_features] = {total for stage, _, total in calls if stage == "read"}
    assert reads[10**6] == {1} and reads[2] == {len(osm_ranges(path, 2, None))} and len(osm_ranges(path, 2, None)) > 1
    a, b = read_manifest(stores[10**6])["records"], read_manifest(stores[2])["records"]
    assert a == b and len(a) == 10 and all(r["status"] == "accepted" for r in a[:8])
    assert [r["id"].split("#")[1] for r in a[8:]] == ["node/9000", "way/91"]  # no outline: rejected, once
    for name, array in arrays(stores[10**6]).items():
        assert np.array_equal(np.asarray(array[:]), np.asarray(arrays(stores[2])[name][:])), name
    park = OsmWriter()
    for k in range(40):
        park.way(k + 1, (20 * k, 0, 20 * k + 10, 10), landuse="grass")
    (tmp_path / "park.osm").write_text(park.text())
    cfg = build(RunConfig, {"corpus": {"paths": [str(tmp_path / "park.osm")]}, "encoding": {"levels": [1]},
                            "dask": {"read_features": 1}, "store": {"chunk_rows": CHUNK}})
    corpus.run_corpus(cluster_client, cfg, tmp_path / "park.zarr")
    (record,) = read_manifest(tmp_path / "park.zarr")["records"]
    assert record["status"] == "rejected" and "holds no building" in record["reason"], record


def test_overture_parts_files_on_a_cluster_read_in_ranges(cluster_client, tmp_path):
    """Overture's two downloads (20 buildings, 3 parts) on 2 worker processes, the buildings' file read as one task
    or in ranges of 2 features (10 tasks, each holding the parts): the same store; the church of its parts, the lone
    part noted, no part read twice."""
    from test_part_files import BUILDINGS, PARTS

    from footprints import write_geoparquet

    others = [(f"x{k:02d}", BUILDINGS[1][1], {"height": 6.0}) for k in range(18)]
    write_geoparquet(tmp_path / "buildings.parquet", BUILDINGS + others, extra=("has_parts",))
    write_geoparquet(tmp_path / "parts.parquet", PARTS, extra=("building_id",))
    stores, reads = {}, {}
    for read_features in (10**6, 2):
        cfg = build(RunConfig, {"corpus": {"paths": [str(tmp_path / "buildings.parquet"), str(tmp_path / "parts.parquet")]},
                                "encoding": {"levels": [1]}, "dask": {"shard_meshes": 4, "read_features": read_features},
                                "store": {"chunk_rows": CHUNK}})
        stores[read_features] = store = tmp_path / f"ov{read_features}.zarr"
        calls = []
        corpus.run_corpus(cluster_client, cfg, store, progress=lambda *a: calls.append(a))
        reads[read_features] = {total for stage, _, total in calls if stage == "read"}
    assert reads[10**6] == {2} and reads[2] == {11}  # 10 ranges of the buildings' file, the parts' file whole
    a, b = read_manifest(stores[10**6])["records"], read_manifest(stores[2])["records"]
    assert a == b and len(a) == 21 and all(r["status"] == "accepted" for r in a)
    assert sum(r["id"].endswith("#p3") for r in a) == 1 and not any(r["id"].endswith(("#p1", "#p2")) for r in a)
    church = next(r for r in a if r["id"].endswith("#b1"))
    assert church["volume"] == pytest.approx(1600, rel=1e-5)


def test_a_large_citygml_file_plain_or_gzipped_is_read_in_ranges(cluster_client, tmp_path):
    """A city's CityGML file (members of every kind, Buildings without gml:id) plain, and as a gzipped WFS answer
    (decompressed by the planner): tasks read each in ranges of whole members, and the store is the one a task per
    file gives, its records naming the files as their sources."""
    import gzip

    from test_citygml import _large_citygml

    (tmp_path / "in").mkdir()
    (tmp_path / "in" / "city.gml").write_text(_large_citygml("2.0", "core:cityObjectMember"))
    (tmp_path / "in" / "wfs.gml.gz").write_bytes(gzip.compress(_large_citygml("2.0", "wfs:member", 5).encode()))
    stores, reads = {}, {}
    for read_bytes in (1 << 30, 300_000):
        cfg = build(RunConfig, {"corpus": {"paths": [str(tmp_path / "in")]}, "encoding": {"levels": [1]},
                                "dask": {"shard_meshes": 64, "read_bytes": read_bytes}, "store": {"chunk_rows": CHUNK}})
        stores[read_bytes] = store = tmp_path / f"c{read_bytes}.zarr"
        calls = []
        corpus.run_corpus(cluster_client, cfg, store, progress=lambda *a: calls.append(a))
        reads[read_bytes] = max(total for stage, _, total in calls if stage == "read")
        assert not (store / corpus.STAGING).exists()
    assert reads[1 << 30] == 2 and reads[300_000] >= 2 * 6
    a, b = read_manifest(stores[1 << 30])["records"], read_manifest(stores[300_000])["records"]
    assert len(a) > 300 and [r["id"] for r in a] == [r["id"] for r in b] and a == b
    assert {r["source"] for r in b} == {str(tmp_path / "in" / n) for n in ("city.gml", "wfs.gml.gz")}
    assert sum(r["id"].split("#")[1].startswith("building-") for r in b) > 50
    for name in ("faces", "vertices", "rings/level1"):
        assert np.array_equal(open_store(stores[1 << 30])[name][:], open_store(stores[300_000])[name][:]), name
