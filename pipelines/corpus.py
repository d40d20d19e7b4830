"""Ingest + encode as a Dask graph, with region writes and resumable shards.

The drivers of ``meshsom run`` (:func:`run_corpus`: read, preprocess and encode), ``meshsom
ingest`` (:func:`run_corpus` with no levels) and ``meshsom encode`` (:func:`encode_corpus`: encode
an ingested store); the single-process commands run them on an in-process client
(:func:`pipelines.cluster.connect_serial`). Both drivers encode every mesh with
:func:`encode_meshes`, stage per-shard rows, assemble them with :func:`copy_rows` and merge the
per-mesh statistics in mesh order (:func:`corpus_statistics`), so ``ingest`` + ``encode`` gives
the store of ``run``, array for array (layout: :mod:`meshsom.store`, DESIGN.md §7).

1. Plan: the inputs are expanded (``meshsom.io.expand_inputs``); one task per
   file reads its meshes (RawMesh or Rejection), the client counts them and
   cuts every source into shards of ``cfg.dask.shard_meshes`` items: files in
   input order, then the generator's blocks. The plan is kept in the store
   (``staging`` attributes) so that a resumed run cuts the same shards.
2. Shards: each task preprocesses and encodes its meshes and writes its rows
   into ``staging/<shard>/`` (vertices, faces with shard-local vertex indices,
   face_mesh with shard-local mesh indices, level{L}), then marks the shard
   done together with its metadata (write first, mark after: a half-written
   shard is never taken as finished). A resumed run skips done shards.
3. Assembly: the client computes every shard's row offsets and creates the
   final arrays; tasks then fill chunk-aligned row ranges of ``vertices``,
   ``faces``, ``face_mesh`` and ``rings/level{L}`` from the shards, so no two
   tasks write the same zarr chunk. The client writes the small per-mesh
   tables, the standardization statistics and the manifest, then removes
   ``staging``.

Workers receive paths, plain data and library objects, never Dask objects;
every function submitted here is a module-level function (picklable).
"""

from __future__ import annotations

import json
import logging
import time
import uuid
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

from meshsom.store import STAGING  # noqa: F401  (the staging group: tests and tools name it from here)

log = logging.getLogger(__name__)

#: Faces per shard of ``meshsom encode`` (whole meshes; a mesh larger than this is a shard of its own).
DEFAULT_BATCH_FACES = 500_000


@dataclass(frozen=True)
class Shard:
    """A slice of one source.

    Attributes
    ----------
    name : str
        Stable name (source index and start), also the staging group.
    source : int
        Index into the plan's sources.
    start, stop : int
        Item range in that source.
    """

    name: str
    source: int
    start: int
    stop: int


# ----------------------------------------------------------------------------- worker side


def read_source(path: str, reader, name: str | None = None, byte_range: Sequence[int] | None = None,
                feature_range: Sequence | None = None, rename: Sequence[str] | None = None,
                fetch: Sequence | None = None) -> list:
    """Every RawMesh / Rejection of one file (or of a byte range of a CityJSONSeq file, or of a
    feature range of a GIS file), in the reader's order.

    Parameters
    ----------
    path : str
    reader : meshsom.io.ReaderOptions
    name : str, optional
        The start of the mesh ids (``meshsom.io.InputFile.name``).
    byte_range : (start, stop, first_line), optional
        :func:`meshsom.io.cityjsonseq_ranges`; or :func:`meshsom.geojson.geojson_ranges`' five; or
        :func:`meshsom.citygml.citygml_ranges`' six.
    feature_range : list, optional
        :func:`meshsom.gis.gis_ranges` or :func:`meshsom.osm.osm_ranges`.
    rename : (written, original), optional
        Where ``path`` was written by the planner from an input (a member of a zip archive extracted:
        :func:`_unzipped`; a CityJSON file split into a CityJSONSeq: :func:`_split_cityjson`): the items' sources,
        and the reasons of rejections, name the original where they named the written path (a prefix of it).
    fetch : list of dict, optional
        The files on object storage that reading ``path`` needs (:class:`meshsom.mirror.Copy` fields: an input named
        by a URL, or what the planner wrote, with a store on object storage), copied to this machine first where it
        lacks them (:func:`meshsom.mirror.fetch`).

    Returns
    -------
    items : list of RawMesh or Rejection
        A file that cannot be opened at all is one Rejection.
    """
    from meshsom.errors import InputFileError
    from meshsom.io import Rejection, read_file
    from meshsom.mirror import fetch as fetch_copies

    try:
        fetch_copies(fetch or [])
    except InputFileError as err:
        return [Rejection(name or _renamed(str(path), rename), _renamed(str(path), rename),
                          f"needs {err.source}, which {err.problem}")]
    try:
        items = list(read_file(path, reader, name, None if byte_range is None else tuple(byte_range),
                               None if feature_range is None else list(feature_range)))
    except OSError as err:
        items = [Rejection(name or str(path), str(path), f"cannot be read ({err.strerror or err})")]
    if rename is not None:
        import dataclasses

        written, original = rename
        items = [dataclasses.replace(item, source=_renamed(item.source, rename), **(
            {"reason": item.reason.replace(written, original)} if isinstance(item, Rejection) else {}))
            for item in items]
    return items


def _renamed(text: str, rename: Sequence[str] | None) -> str:
    """A path as the input names it: ``rename``'s original where it starts with its written path."""
    if not rename or not text.startswith(rename[0]):
        return text
    return rename[1] + text[len(rename[0]):]


def generate_items(generator, start: int, stop: int) -> list:
    """RawMesh items of synthetic blocks ``start..stop`` (as ``meshsom ingest --generate`` makes them).

    Parameters
    ----------
    generator : meshsom.generate.GeneratorParams
    start, stop : int
    """
    from meshsom.generate import generate_corpus
    from meshsom.io import RawMesh, recentre

    out = []
    for block in generate_corpus(generator, indices=range(start, stop)):
        local, origin = recentre(block.vertices)
        out.append(RawMesh(f"synthetic#{block.id}", f"generator(seed={generator.seed})", local, block.faces, origin,
                           block.label, block.lod))
    return out


def slice_items(items: list, start: int, stop: int, repeats: dict | None = None) -> list:
    """Items ``start..stop`` of a source's list; those listed in ``repeats`` (``{str(index): new
    id}``, :func:`repeated_ids`) as rejections of a repeated id."""
    from meshsom.io import repeated

    repeats = repeats or {}
    return [repeated(item, repeats[str(k)]) if str(k) in repeats else item
            for k, item in zip(range(start, stop), items[start:stop])]


def item_ids(items: list) -> list[str]:
    """The ids of a source's items."""
    return [item.id for item in items]


def repeated_ids(sources: list[dict], ids: list[list[str]]) -> list[dict[str, str]]:
    """Ids that an earlier range of the same file has (each range's reader saw only its own).

    Parameters
    ----------
    sources : list of dict
        The plan's sources (``path``, and ``range`` for a range of a file).
    ids : list of list of str
        Every source's item ids, in order.

    Returns
    -------
    list of dict
        Per source, ``{str(index): new id}`` of its items to be rejected as repeats: the new id is
        ``"<id> (k)"`` with the smallest k >= 2 that no item of the file has.
    """
    from meshsom.io import free_id

    taken: dict[str, set] = {}
    for src, source_ids in zip(sources, ids):
        taken.setdefault(src.get("path", ""), set()).update(source_ids)
    seen: dict[str, set] = {}
    out = []
    for src, source_ids in zip(sources, ids):
        file_seen, file_taken = seen.setdefault(src.get("path", ""), set()), taken.get(src.get("path", ""), set())
        renames = {}
        for k, item_id in enumerate(source_ids):
            if item_id in file_seen and "range" in src:
                renames[str(k)] = free_id(item_id, file_taken)
                file_taken.add(renames[str(k)])
            file_seen.add(item_id)
        out.append(renames)
    return out


def shard_done(store: str, name: str) -> bool:
    """Whether ``staging/<name>`` of a store is marked done."""
    from meshsom.store import shard_meta

    return shard_meta(store, name) is not None


def encode_meshes(meshes: Sequence[tuple[str, np.ndarray, np.ndarray]], levels: Sequence[int],
                  seconds: dict | None = None) -> tuple[dict, dict]:
    """Ring vectors of whole meshes, one mesh at a time, and the per-mesh standardization accumulators.

    Parameters
    ----------
    meshes : sequence of (id, vertices (V, 3) float64, faces (F, 3) int64)
        Closed meshes; the id is named in errors.
    levels : sequence of int
    seconds : dict, optional
        Level -> seconds, increased by the time spent encoding each level.

    Returns
    -------
    rings : dict
        Level -> (sum F, dims(level)) float32, the meshes' rows in order.
    acc : dict
        ``str(level)`` -> list (one per mesh) of accumulators as nested lists (JSON-able).

    Raises
    ------
    MeshError
        A mesh that is not a closed, consistently oriented 2-manifold (the first one).
    """
    from meshsom.folds import folds
    from meshsom.rings import dims, encode_level
    from meshsom.standardize import accumulate, empty_accumulator
    from meshsom.topology import adjacency

    parts = {lv: [] for lv in levels}
    for mesh_id, vertices, faces in meshes:
        adj = adjacency(faces, source=mesh_id)
        fo = folds(vertices, faces, adj)
        for lv in levels:
            t = time.perf_counter()
            parts[lv].append(encode_level(fo, adj, lv, dtype=np.float32))
            if seconds is not None:
                seconds[lv] = seconds.get(lv, 0.0) + time.perf_counter() - t
    rings = {lv: np.concatenate(x) if x else np.zeros((0, dims(lv)), np.float32) for lv, x in parts.items()}
    acc = {str(lv): [accumulate(empty_accumulator(), x).tolist() for x in parts[lv]] for lv in levels}
    return rings, acc


def process_shard(store: str, shard: Shard, items: list, params, levels: Sequence[int], chunk_rows: int) -> dict:
    """Preprocess and encode one shard's meshes and write them to ``staging/<shard>``.

    A shard already marked done is not recomputed (its metadata is returned).

    Parameters
    ----------
    store : str
        Path of the zarr store (made by :func:`meshsom.store.create_store`).
    shard : Shard
    items : list of RawMesh or Rejection
        The shard's inputs, in order.
    params : meshsom.preprocess.PreprocessParams
    levels : sequence of int
    chunk_rows : int
        Row chunk of the staging arrays.

    Returns
    -------
    meta : dict
        JSON-able, also stored as the group's ``meta`` attribute: ``records``
        (manifest records, without ``index``), ``ids``, ``labels``, ``origins``,
        ``n_vertices``, ``n_faces`` (per accepted mesh) and ``acc`` (per level,
        the standardization accumulator of every accepted mesh as a nested list).
    """
    from meshsom.errors import MeshError
    from meshsom.store import shard_meta, write_shard
    from pipelines import ingest

    done = shard_meta(store, shard.name)
    if done is not None:
        return done
    levels = [int(lv) for lv in levels]
    records, meshes, rings, acc = [], [], {lv: [] for lv in levels}, {str(lv): [] for lv in levels}
    for raw in items:
        record, mesh = ingest.process_one(raw, params)
        if mesh is not None:
            try:
                x, a = encode_meshes([(mesh.id, mesh.vertices, mesh.faces)], levels)
            except MeshError as err:
                record.update(status="rejected", reason=f"encoding: {err.problem}", faces_out=0)
                record.pop("volume", None)
                mesh = None
            else:
                for lv in levels:
                    rings[lv].append(x[lv])
                    acc[str(lv)] += a[str(lv)]
                meshes.append(mesh)
        records.append(record)

    nv = [int(len(m.vertices)) for m in meshes]
    nf = [int(len(m.faces)) for m in meshes]
    voff = np.concatenate([[0], np.cumsum(nv, dtype=np.int64)]).astype(np.int64)
    arrays = {
        "vertices": np.concatenate([m.vertices for m in meshes]).astype(np.float64) if meshes else np.zeros((0, 3)),
        "faces": (np.concatenate([m.faces + voff[i] for i, m in enumerate(meshes)]).astype(np.int64)
                  if meshes else np.zeros((0, 3), np.int64)),
        "face_mesh": np.repeat(np.arange(len(meshes), dtype=np.int32), nf),
    }
    for lv in levels:
        arrays[f"level{lv}"] = np.concatenate(rings[lv]) if meshes else encode_meshes([], [lv])[0][lv]
    meta = {
        "records": records,
        "ids": [m.id for m in meshes],
        "labels": [m.label or "" for m in meshes],
        "origins": [np.asarray(m.origin, np.float64).tolist() for m in meshes],
        "n_vertices": nv,
        "n_faces": nf,
        "acc": acc,
    }
    write_shard(store, shard.name, arrays, meta, chunk_rows)  # a fresh group; marked done last
    return meta


def encode_shard(store: str, shard: Shard, levels: Sequence[int], chunk_rows: int) -> dict:
    """Encode meshes ``shard.start..shard.stop`` of an ingested store into ``staging/<shard>``.

    Returns
    -------
    meta : dict
        JSON-able: ``n_faces`` (per mesh), ``acc`` (as :func:`process_shard`), ``seconds`` (per level).
    """
    from meshsom.store import open_store, read_meshes, write_shard

    meshes = read_meshes(open_store(store), shard.start, shard.stop)
    seconds: dict = {}
    rings, acc = encode_meshes(meshes, [int(lv) for lv in levels], seconds)
    meta = {"n_faces": [len(f) for _, _, f in meshes], "acc": acc, "seconds": {str(k): v for k, v in seconds.items()}}
    write_shard(store, shard.name, {f"level{lv}": x for lv, x in rings.items()}, meta, chunk_rows)
    return meta


def copy_rows(store: str, target: str, start: int, stop: int, pieces: list) -> int:
    """Fill rows ``start..stop`` of array ``target`` from shard arrays.

    Parameters
    ----------
    store : str
    target : str
        Path of the final array in the store (``faces``, ``rings/level2``), as
        :func:`meshsom.store.create_corpus_arrays` and :func:`meshsom.store.create_rings` name it.
    start, stop : int
        A chunk-aligned row range of ``target`` (no other task writes it).
    pieces : list of (shard, name, row0, row1, add)
        In target order, rows ``row0..row1`` of ``staging/<shard>/<name>``,
        with ``add`` added to the values (vertex or mesh offsets); together
        they cover ``start..stop`` exactly.

    Returns
    -------
    rows : int
    """
    from meshsom.store import open_store, shard_array

    root = open_store(store, mode="r+")
    arr = root[target]
    block = np.empty((stop - start,) + tuple(arr.shape[1:]), arr.dtype)
    row = 0
    for shard, name, a, b, add in pieces:
        src = np.asarray(shard_array(root, shard, name)[a:b])
        block[row:row + (b - a)] = src + add if add else src
        row += b - a
    if row != stop - start:
        raise RuntimeError(f"{store}: {target} rows {start}..{stop}: pieces cover {row} rows")
    arr[start:stop] = block
    return stop - start


# ----------------------------------------------------------------------------- client side


def _fingerprint(cfg, levels: Sequence[int]) -> dict:
    """What a resumed run must share with the interrupted one (JSON form)."""
    from meshsom.config import to_dict

    doc = {
        "paths": list(cfg.corpus.paths),
        "generator": to_dict(cfg.corpus.generator),
        "reader": to_dict(cfg.corpus.reader),
        "preprocess": to_dict(cfg.preprocess),
        "levels": [int(lv) for lv in levels],
        "shard_meshes": int(cfg.dask.shard_meshes),
        "read_bytes": int(cfg.dask.read_bytes),
        "read_features": int(cfg.dask.read_features),
        "chunk_rows": int(cfg.store.chunk_rows),
    }
    return json.loads(json.dumps(doc))


def _finished_summary(path: str, levels: Sequence[int]) -> dict | None:
    """The manifest summary of a finished store at ``path``, or None if it is unfinished."""
    from meshsom.errors import StoreError
    from meshsom.store import has_manifest, open_store, read_manifest, ring_levels, staging_exists

    if not has_manifest(path) or staging_exists(path):
        return None
    missing = sorted(set(levels) - set(ring_levels(open_store(path))))
    if missing:
        raise StoreError(
            f"{path}: a finished store without rings for level(s) {missing}; run without resume to rebuild it"
        )
    return read_manifest(path)["summary"]


#: Where in a local store the planner writes what it makes of inputs (a large CityJSON file's CityJSONSeq:
#: :func:`_split_cityjson`; a zip archive's files: :func:`_unzipped`): in its staging group, deleted with it when
#: the run is done.
SPLIT_FOLDER = "inputs"
#: The most of the store's free disk what the planner writes of one input may take (:func:`_room_for`: a zip archive's
#: files, a decompressed or split file); a larger input is read by one task, as it is.
UNZIP_DISK_SHARE = 0.5
#: Bytes of a JSON input looked at for ``"CityJSON"`` (its type, which writers put first) before it is split.
CITYJSON_SNIFF_BYTES = 1 << 16


def _split_cityjson(f, k: int, staging: Path, cfg) -> str | None:
    """A CityJSON input of twice ``dask.read_bytes`` or more written as a CityJSONSeq in the ``staging`` folder
    (:func:`_staging_folder`; :func:`meshsom.cityjson_split.split_cityjson`), so that tasks read it in ranges; the
    path, or None where it is smaller or not CityJSON (read whole)."""
    from meshsom.cityjson_split import split_cityjson

    try:
        size = Path(f.path).stat().st_size
        if size < 2 * int(cfg.dask.read_bytes) or not _is_cityjson(Path(f.path), cfg) or not _room_for(size, staging):
            return None
    except Exception:  # unreadable: its reader says why
        return None
    out = staging / f"split-{k:05d}-{Path(f.path).name.removesuffix('.gz')}l"
    count = split_cityjson(Path(f.path), out, cfg.corpus.reader)
    if not count:
        return None
    log.info("%s: a CityJSON file of %d first-level objects, split into %s to be read in ranges", f.path, count, out)
    return str(out)


def _gunzipped(f, k: int, staging: Path, cfg, kind: str) -> str | None:
    """A large gzipped CityJSONSeq, CityJSON, GeoJSON or CityGML input (gzip cannot be entered mid-stream) decompressed into
    the ``staging`` folder (:func:`_staging_folder`), so that tasks read it in ranges: the path, or None where it is
    not gzip, its content is too small to be split (:func:`_content_bytes` under twice ``dask.read_bytes``; a GeoJSON
    collection: under twice ``dask.read_features`` features of
    :data:`meshsom.geojson.MIN_FEATURE_BYTES`), or would take more than :data:`UNZIP_DISK_SHARE` of the free disk."""
    import shutil

    from meshsom.geojson import MIN_FEATURE_BYTES
    from meshsom.io import GZIP_MAGIC, open_input

    try:
        with open(f.path, "rb") as fh:
            if fh.read(2) != GZIP_MAGIC:
                return None
        size = _content_bytes(Path(f.path))
        least = 2 * int(cfg.dask.read_bytes) if kind in ("cityjsonseq", "citygml") or _is_cityjson(Path(f.path), cfg) else \
            2 * int(cfg.dask.read_features) * MIN_FEATURE_BYTES
        if size < least or not _room_for(size, staging):
            return None
    except Exception:  # unreadable: read whole by one task, whose reader says why
        return None
    out = staging / f"gunzip-{k:05d}-{Path(f.path).name.removesuffix('.gz')}"
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        with open_input(Path(f.path), cfg.corpus.reader) as stream, open(out, "wb") as dst:
            shutil.copyfileobj(stream, dst, 1 << 20)
    except Exception:  # truncated, a gzip bomb: read whole by one task, whose reader says why
        out.unlink(missing_ok=True)
        return None
    log.info("%s: gzipped, %d bytes decompressed into %s to be read in ranges", f.path, size, out)
    return str(out)


def _bzip2_pbf(f, k: int, staging: Path) -> str | None:
    """A large ``.osm.bz2`` input written as PBF into the ``staging`` folder by libosmium
    (:func:`meshsom.osm.bzip2_as_pbf`), once, so that its read tasks each read the PBF rather than convert it again:
    the path, or None where it cannot be converted (read by its tasks, whose reader says why) or the disk lacks room
    for about its size (a PBF extract is smaller than its bzip2 XML)."""
    from meshsom.errors import InputFileError
    from meshsom.osm import bzip2_as_pbf

    try:
        if not _room_for(Path(f.path).stat().st_size, staging, f.path):
            return None
        out = staging / f"pbf-{k:05d}-{Path(f.path).name.removesuffix('.bz2')}.pbf"
        out.parent.mkdir(parents=True, exist_ok=True)
        bzip2_as_pbf(Path(f.path), out)
    except (InputFileError, OSError):
        return None
    log.info("%s: bzip2-compressed OpenStreetMap XML written as %s to be read in ranges", f.path, out)
    return str(out)


def _is_cityjson(path: Path, cfg) -> bool:
    """Whether a JSON input (plain or gzipped) is CityJSON: its first :data:`CITYJSON_SNIFF_BYTES` name the type."""
    from meshsom.io import open_input

    with open_input(path, cfg.corpus.reader) as stream:
        return b'"CityJSON"' in stream.read(CITYJSON_SNIFF_BYTES)


def _room_for(size: int, staging: Path, what=None) -> bool:
    """Whether ``size`` bytes the planner would write into ``staging`` take at most :data:`UNZIP_DISK_SHARE` of the
    disk free there (``what``: the input, logged where they do not)."""
    import shutil

    folder = Path(staging)
    while not folder.exists() and folder != folder.parent:
        folder = folder.parent
    free = shutil.disk_usage(folder).free
    if size <= UNZIP_DISK_SHARE * free:
        return True
    if what is not None:
        log.warning("%s: expands to %d bytes, more than %.0f%% of the %d free beside the staging folder: read by one task",
                    what, size, 100 * UNZIP_DISK_SHARE, free)
    return False


def _content_bytes(path: Path) -> int:
    """A gzip file's content size as its trailer says it (modulo 4 GiB: the larger of that and the file's size)."""
    with open(path, "rb") as fh:
        fh.seek(-4, 2)
        trailer = int.from_bytes(fh.read(4), "little")
    return max(trailer, path.stat().st_size)


def _unzipped(f, k: int, staging: Path, cfg) -> tuple[list, Path] | None:
    """A zip input extracted into the ``staging`` folder (:func:`_staging_folder`;
    :func:`meshsom.archives.extract_archive`), so that its files are read by tasks of their own (a state's LoD 2
    tiles, a city's footprints zipped): the files and the folder; None where the archive cannot be extracted, or its
    files would take too much of the disk (read whole, by one task, whose reader says why)."""
    import shutil

    from meshsom.archives import expanded_size, extract_archive
    from meshsom.errors import InputFileError

    folder = staging / f"zip-{k:05d}-{Path(f.path).name}"
    try:
        if not _room_for(expanded_size(Path(f.path)), staging, f.path):  # a task extracts and reads it whole
            return None
        return extract_archive(Path(f.path), folder, cfg.corpus.reader), folder
    except (InputFileError, OSError):
        shutil.rmtree(folder, ignore_errors=True)
        return None


def mirror_folder(cfg, store: str) -> Path:
    """The run's mirror folder (:mod:`meshsom.mirror`): ``corpus.mirror`` (default: ``meshsom-mirror`` in the temporary
    folder), in it a folder named after the store (runs into two stores do not share one; a resumed run finds its)."""
    import hashlib
    import tempfile

    from meshsom.store import store_url

    base = Path(cfg.corpus.mirror) if cfg.corpus.mirror else Path(tempfile.gettempdir()) / "meshsom-mirror"
    return base / hashlib.sha1(store_url(store).encode()).hexdigest()[:12]


def _range_fetch(source: dict, kind: str, byte_range, ranges: list) -> list:
    """A range's files to copy (``source["fetch"]``) with only the bytes its reader reads of the file it reads
    (:attr:`meshsom.mirror.Copy.spans`): a CityJSONSeq's header line and the range's lines; a GeoJSON collection's
    members before and after its features and the range's features; a CityGML file's head and tail and the range's
    members. The others whole."""
    size = next(c["size"] for c in source["fetch"] if c["local"] == source["path"])
    r = [int(v) for v in byte_range]
    if kind == "citygml":
        spans = [[0, r[3]], [r[0], r[1]], [r[4], size]]
    elif kind == "cityjson" and len(r) == 5:  # a GeoJSON FeatureCollection's range
        spans = [[0, r[3] + 1], [r[0], r[1]], [r[4], size]]
    else:  # a CityJSONSeq's: its header line (before the first range) and the range's lines
        spans = [[0, int(ranges[0][0])], [r[0], r[1]]]
    return _with_spans(source, spans)


def _feature_fetch(source: dict, feature_range) -> list:
    """A GIS range's files to copy (``source["fetch"]``): of a GeoParquet file, only the bytes its rows' task reads
    (:func:`meshsom.gis.parquet_spans`: its first row group's, its rows' and the footer); other files whole (GDAL
    reads them at random)."""
    from meshsom.gis import parquet_spans

    spans = parquet_spans(Path(source["path"]), int(feature_range[4]), int(feature_range[5]))
    return source["fetch"] if spans is None else _with_spans(source, spans)


def _with_spans(source: dict, spans: list) -> list:
    """``source["fetch"]`` with ``spans`` (:attr:`meshsom.mirror.Copy.spans`) on the copy of the file it reads."""
    return [{**c, "spans": spans} if c["local"] == source["path"] else c for c in source["fetch"]]


def _staging_folder(store: str, mirror: Path) -> Path:
    """Where the planner writes what it makes of large inputs (a CityJSON file's split, a gzipped file's content, a
    zip's files): the staging group of a local store; with a store on object storage, the mirror folder, from which
    they are copied into the store's staging group for the workers (:func:`_uploaded`)."""
    from meshsom.store import is_remote

    return mirror / STAGING / SPLIT_FOLDER if is_remote(store) else Path(store) / STAGING / SPLIT_FOLDER


def _uploaded(files: list[Path], store: str, mirror: Path) -> dict:
    """With a store on object storage, the files the planner wrote into :func:`_staging_folder` copied into the
    store's staging group, for the workers to copy back (:func:`meshsom.mirror.fetch`): ``{local path: Copy}``;
    nothing with a local store (the workers share its disk)."""
    from meshsom.mirror import Copy
    from meshsom.store import filesystem, is_remote, location

    if not is_remote(store):
        return {}
    fs, _ = filesystem(store)
    out = {}
    for file in files:
        url = "/".join([location(store), STAGING, SPLIT_FOLDER,
                        Path(file).relative_to(_staging_folder(store, mirror)).as_posix()])
        fs.put_file(str(file), filesystem(url)[1])
        out[str(file)] = Copy(url, str(file), Path(file).stat().st_size)
    return out


def _files_of_no_buildings(sources: list[dict], counts: dict, reader) -> list:
    """A Rejection for each file read in ranges that gave nothing at all (no range holds a
    building): read whole, such a file is a rejection that says what it holds instead."""
    from meshsom.io import Rejection

    by_file: dict[str, list] = {}
    for i, src in enumerate(sources):
        if "range" in src:
            by_file.setdefault(_renamed(src["path"], src.get("rename")), [src["name"], 0])[1] += counts[i]
    return [Rejection(name, path, f"holds no object of the types {', '.join(reader.object_types)}")
            for path, (name, n) in by_file.items() if n == 0]


def _rejection_record(rejection, params) -> dict:
    from pipelines import ingest

    return ingest.process_one(rejection, params)[0]


def _run_shards(client, path: str, shards: list, submit: Callable, report: Callable) -> tuple[dict, list]:
    """Run the shards not done yet; returns (metadata by shard name, failed (shard, exception) pairs)."""
    from distributed import as_completed

    from meshsom.store import shard_meta

    metas: dict[str, dict] = {}
    futures = {}
    for sh in shards:
        meta = shard_meta(path, sh.name)
        if meta is not None:
            metas[sh.name] = meta
        else:
            fut = submit(sh)
            futures[fut.key] = (sh, fut)
    if metas:
        log.info("%s: %d of %d shards done already", path, len(metas), len(shards))
    report("encode", len(metas), len(shards))
    failed = []
    for fut in as_completed([f for _, f in futures.values()]):
        sh, _ = futures[fut.key]
        if fut.status == "error":
            failed.append((sh, fut.exception()))
        else:
            metas[sh.name] = fut.result()
        report("encode", len(metas) + len(failed), len(shards))
    return metas, failed


def _shards_failed(path: str, shards: list, failed: list, what: Callable) -> None:
    from meshsom.errors import MeshsomError

    if failed:
        sh, err = failed[0]
        raise MeshsomError(
            f"{path}: {len(failed)} of {len(shards)} shards failed (first: {sh.name}, items {sh.start}..{sh.stop} "
            f"of {what(sh)}: {type(err).__name__}: {err}); the others are kept: `meshsom run --resume` goes on from them "
            f"(`meshsom ingest` starts afresh)"
        ) from err


def run_corpus(client, cfg, store, resume: bool = False,
               progress: Callable[[str, int, int], None] | None = None, levels: Sequence[int] | None = None) -> dict:
    """Ingest and encode the configured corpus into ``store`` on a Dask client.

    Parameters
    ----------
    client : distributed.Client
    cfg : meshsom.config.ExperimentConfig
        Uses ``corpus`` (paths, generator, reader), ``preprocess``,
        ``encoding`` (levels, scaling, robust_clip), ``dask.shard_meshes`` and ``store.chunk_rows``.
    store : path
        The zarr store. Without ``resume`` it is created afresh (anything at
        ``store`` is replaced: the caller checks ``--overwrite``).
    resume : bool
        Continue an interrupted run: shards marked done are not recomputed, and
        a finished store is returned as it is. The config must be the one of
        the interrupted run.
    progress : callable, optional
        Called as ``progress(stage, done, total)`` with stage ``"copy"`` (inputs on object storage copied),
        ``"unpack"`` (zip archives), ``"plan"`` (inputs), ``"read"``, ``"encode"`` (shards) or ``"assemble"``
        (chunk copies).
    levels : sequence of int, optional
        Ring levels to encode (default ``cfg.encoding.levels``); empty: ingest only (``meshsom ingest``).

    Returns
    -------
    summary : dict
        The manifest summary (inputs, accepted, rejected, faces_in, faces_out,
        reader, preprocess, generator).

    Raises
    ------
    InputFileError
        Two inputs with one name, before anything is written.
    StoreError
        When a resumed store was made with another configuration.
    MeshsomError
        When shards fail; the others are finished and kept, so a resumed run
        only redoes the failed ones.
    """
    from distributed import as_completed

    from meshsom.errors import InputFileError, StoreError
    from meshsom.archives import NESTED, is_nested_archive
    from meshsom.citygml import citygml_ranges
    from meshsom.geojson import geojson_ranges
    from meshsom.gis import gis_ranges
    from meshsom.io import GZIP_MAGIC, Rejection, cityjsonseq_ranges, expand_inputs, input_kind
    from meshsom.osm import BZIP2_SUFFIX, osm_ranges
    from meshsom.gis import parquet_planned_spans, planner_columns
    from meshsom.mirror import (
        HEAD_SUFFIXES, Copies, as_url, columns_from, companions, fetch, heads_from, is_partial, mirror_inputs,
        remove_mirror, unopened_below, url_rename,
    )
    from meshsom.part_files import pair
    from meshsom.store import (
        create_store, location, open_store, read_manifest, read_plan, remove_staging, store_exists, write_plan,
    )

    path = location(store)
    levels = sorted({int(lv) for lv in (cfg.encoding.levels if levels is None else levels)})
    chunk = int(cfg.store.chunk_rows)
    fingerprint = _fingerprint(cfg, levels)
    mirror = mirror_folder(cfg, path)
    run_id = uuid.uuid4().hex[:8]
    report = progress or (lambda stage, done, total: None)

    root = plan = None
    if resume and store_exists(path):
        summary = _finished_summary(path, levels)
        if summary is not None:
            log.info("%s: finished already; nothing to resume", path)
            return summary
        root = open_store(path, mode="r+")
        plan = read_plan(root)
    if plan is not None and plan["fingerprint"] != fingerprint:
        raise StoreError(
            f"{path}: was started with another configuration (corpus, preprocessing, levels, shard size or "
            f"chunk rows differ); run without resume to start again"
        )

    # ---- plan: sources and their shards, kept in the store for a resumed run
    read_futures = {}
    if plan is None:
        unopened = unopened_below(2 * int(cfg.dask.read_bytes))  # tiles too small to cut: placeholders
        columnar = columns_from(2 * int(cfg.dask.read_bytes))  # large GeoParquet: placeholders, then the planner's spans
        mirrored = mirror_inputs(list(cfg.corpus.paths), mirror, lambda done, total: report("copy", done, total),
                                 lambda c: unopened(c) or columnar(c),
                                 heads_from(2 * int(cfg.dask.read_bytes)))  # large CityGML: its head; its ranges streamed
        files, missing = expand_inputs(mirrored.paths)  # before the store: a name clash writes nothing
        streamed, lost = {}, set()  # a large CityGML file on object storage: its URL, its ranges found by streaming it
        for f in files:
            c = mirrored.copies.get(str(f.path))
            if c is not None and is_partial(f.path) and columnar(c):  # only the bytes the planner reads (its footer
                try:  # says which), or the whole file where it cannot be read as Parquet (its reader says why)
                    fetch([replace(c, spans=parquet_planned_spans(c.url, c.size, planner_columns(cfg.corpus.reader)))])
                except InputFileError as err:
                    missing.append(Rejection(c.url, c.url, err.problem))
                    lost.add(str(f.path))
                continue
            if c is None or not is_partial(f.path) or not f.path.name.lower().endswith(HEAD_SUFFIXES):
                continue
            with open(f.path, "rb") as head:
                gzipped = head.read(2) == GZIP_MAGIC
            if input_kind(f.path) == "citygml" and not gzipped:
                streamed[str(f.path)] = c.url
                continue
            try:  # INSPIRE's GML footprints (GDAL reads them whole), gzip data: copied whole for the planner to read
                fetch([c])
            except InputFileError as err:
                missing.append(Rejection(c.url, c.url, err.problem))
                lost.add(str(f.path))
        files = [f for f in files if str(f.path) not in lost]
        missing = [replace(r, id=as_url(r.id, mirrored.urls), source=as_url(r.source, mirrored.urls)) for r in missing] + [
            Rejection(url, url, why) for url, why in mirrored.missing]
        root = root or create_store(path, overwrite=True)
        staging = _staging_folder(path, mirror)
        staged = Copies()  # with a store on object storage: what the planner wrote, copied into its staging group
        inputs = []  # (file to read, the start of its ids, (written, original) where the planner wrote it or copied it)
        archives = [k for k, f in enumerate(files) if input_kind(f.path) == "zip"]
        for k, f in enumerate(files):  # a zip archive: its files read by tasks of their own
            unzipped = _unzipped(f, k, staging, cfg) if k in archives else None
            if k in archives:
                report("unpack", archives.index(k) + 1, len(archives))
            if unzipped is None:
                inputs.append((f, f.name, url_rename(f.path, mirrored.urls)))
                continue
            members, folder = unzipped
            staged.update(_uploaded([m.path for m in members], path, mirror))
            for m in members:
                member = m.path.relative_to(folder).as_posix()
                if is_nested_archive(m.path):
                    missing.append(Rejection(f"{f.name}/{member}", f"{as_url(str(f.path), mirrored.urls)}!/{member}", NESTED))
                else:
                    inputs.append((m, f"{f.name}/{m.name}", (str(folder), f"{as_url(str(f.path), mirrored.urls)}!")))
        reader = pair([f.path for f, _, _ in inputs], cfg.corpus.reader)  # Overture's parts, in files of their own
        if reader.part_files:
            log.info("building parts in %s: each read with its building, where an input holds it",
                     ", ".join(as_url(p, mirrored.urls) for p in reader.part_files))
        shared = [asdict(c) for p in sorted({*reader.part_files, *reader.building_files})  # every read task opens
                  for c in companions(Path(p), mirrored.copies)]  # these: kept once in the plan
        sources = []
        for k, (f, name, rename) in enumerate(inputs):  # a large file: a source per range, read in parallel
            kind = input_kind(f.path)
            copies = [asdict(c) for c in companions(f.path, mirrored.copies)] if rename is not None else []
            plain = _gunzipped(f, k, staging, cfg, kind) if kind in ("cityjson", "cityjsonseq", "citygml") else None
            if kind == "osm" and f.path.name.lower().endswith(BZIP2_SUFFIX) and osm_ranges(
                    f.path, int(cfg.dask.read_features), cfg.corpus.reader):  # read in ranges: made PBF once, here
                try:
                    if is_partial(f.path) and str(f.path) in mirrored.copies:  # on object storage: a placeholder so far
                        fetch([mirrored.copies[str(f.path)]])
                    plain = _bzip2_pbf(f, k, staging)
                except InputFileError:  # not copied: its tasks copy it, or say why they cannot
                    plain = None
            if plain:  # a large gzipped sequence or collection, a large .osm.bz2: ranges of its plain form
                rename, f = (plain, _renamed(str(f.path), rename)), replace(f, path=Path(plain))
            split = _split_cityjson(f, k, staging, cfg) if kind == "cityjson" else None  # a city in one CityJSON file
            if split:  # the sequence's items named as the file's
                rename = (split, _renamed(str(f.path), rename))
            if plain or split:  # written by the planner: with a remote store, copied from the store's staging group
                staged.update(_uploaded([Path(split or f.path)], path, mirror))
            if Path(split or f.path).is_relative_to(staging):
                copies = [asdict(c) for c in companions(Path(split or f.path), staged)]
            ranges = (cityjsonseq_ranges(Path(split or f.path), int(cfg.dask.read_bytes), cfg.corpus.reader)
                      if kind == "cityjsonseq" or split else
                      geojson_ranges(f.path, int(cfg.dask.read_features), cfg.corpus.reader) if kind == "cityjson" else
                      citygml_ranges(f.path, int(cfg.dask.read_bytes), cfg.corpus.reader, streamed.get(str(f.path)))
                      if kind == "citygml" else None)
            features = (gis_ranges(f.path, int(cfg.dask.read_features), cfg.corpus.reader) if kind == "gis" else
                        osm_ranges(f.path, int(cfg.dask.read_features), cfg.corpus.reader) if kind == "osm" else None)
            base = {"kind": "file", "path": split or str(f.path), "name": name, **({"rename": list(rename)} if rename else {}),
                    **({"fetch": copies} if copies else {})}
            if ranges:
                sources += [{**base, "range": list(r), **({"fetch": _range_fetch(base, kind, r, ranges)} if copies else {})}
                            for r in ranges]
            elif features:
                whole = {*reader.part_files, *reader.building_files}  # every read task opens those whole
                sources += [{**base, "features": r, **({"fetch": _feature_fetch(base, r)}
                                                       if copies and str(f.path) not in whole else {})}
                            for r in features]
            else:
                sources.append(base)
            report("plan", k + 1, len(inputs))  # large files split, decompressed or scanned for their ranges
        for i, src in enumerate(sources):
            read_futures[i] = client.submit(read_source, src["path"], reader, src["name"], src.get("range"),
                                            src.get("features"), src.get("rename"), src.get("fetch", []) + shared,
                                            pure=False,
                                            key=f"corpus-read-{run_id}-{i}")
        ids = [None] * len(sources)
        id_futures = {client.submit(item_ids, f, pure=False): i for i, f in read_futures.items()}
        for k, future in enumerate(as_completed(id_futures), 1):
            ids[id_futures[future]] = future.result()
            report("read", k, len(read_futures))
        counts = {i: len(source_ids) for i, source_ids in enumerate(ids)}
        for src, renames in zip(sources, repeated_ids(sources, ids)):
            if renames:
                src["repeats"] = renames
        missing += _files_of_no_buildings([s for s in sources if s["path"] not in reader.part_files], counts,
                                          cfg.corpus.reader)
        size = int(cfg.dask.shard_meshes)
        shards = [Shard(f"s{i:04d}-{a:08d}", i, a, min(counts[i], a + size))
                  for i in range(len(sources)) for a in range(0, counts[i], size)]
        if cfg.corpus.generator is not None:
            g = len(sources)
            sources.append({"kind": "generator"})
            n = cfg.corpus.generator.n_blocks
            shards += [Shard(f"s{g:04d}-{a:08d}", g, a, min(n, a + size)) for a in range(0, n, size)]
        plan = {
            "fingerprint": fingerprint,
            "parts": {"part_files": list(reader.part_files), "building_files": list(reader.building_files),
                      **({"fetch": shared} if shared else {})},
            "sources": sources,
            "shards": [asdict(s) for s in shards],
            "missing": [_rejection_record(r, cfg.preprocess) for r in missing],
        }
        write_plan(root, plan)
    sources = plan["sources"]
    shards = [Shard(**s) for s in plan["shards"]]
    parts = plan.get("parts", {})
    reader = replace(cfg.corpus.reader, part_files=tuple(parts.get("part_files", ())),
                     building_files=tuple(parts.get("building_files", ())))
    shared = parts.get("fetch", [])  # files on object storage every read task opens (building parts' files)

    # ---- shards: preprocess + encode + staging write, done ones skipped
    def submit(sh):
        src = sources[sh.source]
        if src["kind"] == "generator":
            items = client.submit(generate_items, cfg.corpus.generator, sh.start, sh.stop, pure=False,
                                  key=f"corpus-generate-{run_id}-{sh.name}")
        else:
            if sh.source not in read_futures:
                read_futures[sh.source] = client.submit(read_source, src["path"], reader, src.get("name"),
                                                        src.get("range"), src.get("features"), src.get("rename"),
                                                        src.get("fetch", []) + shared, pure=False,
                                                        key=f"corpus-read-{run_id}-{sh.source}")
            items = client.submit(slice_items, read_futures[sh.source], sh.start, sh.stop, src.get("repeats"), pure=False,
                                  key=f"corpus-slice-{run_id}-{sh.name}")
        return client.submit(process_shard, str(path), sh, items, cfg.preprocess, levels, chunk, pure=False,
                             key=f"corpus-shard-{run_id}-{sh.name}")

    metas, failed = _run_shards(client, path, shards, submit, report)
    read_futures.clear()
    _shards_failed(path, shards, failed,
                   lambda sh: _renamed(sources[sh.source].get("path", "generator"), sources[sh.source].get("rename")))

    _assemble(client, root, path, shards, metas, plan, cfg, levels, chunk, run_id, report)
    remove_staging(path)
    if shared or any("fetch" in src for src in sources):  # the copies of inputs named by URLs, here and on workers
        client.run(remove_mirror, str(mirror))
        remove_mirror(mirror)
    return read_manifest(path)["summary"]


def _fill(client, path: str, targets: list, shards: list, chunk: int, run_id: str, report: Callable) -> None:
    """Fill final per-row arrays from the staged shards by chunk-aligned copies on the workers.

    Parameters
    ----------
    targets : list of (target path, n rows, staged name, row offsets per shard (n_shards+1,),
        value offsets per shard or None)
    """
    from distributed import as_completed

    copies = []
    for target, n_rows, staged, row_off, add_off in targets:
        for start in range(0, n_rows, chunk):
            stop = min(n_rows, start + chunk)
            pieces = []
            for k, sh in enumerate(shards):
                a, b = max(start, int(row_off[k])), min(stop, int(row_off[k + 1]))
                if a < b:
                    add = int(add_off[k]) if add_off is not None else 0
                    pieces.append((sh.name, staged, a - int(row_off[k]), b - int(row_off[k]), add))
            copies.append(client.submit(copy_rows, str(path), target, start, stop, pieces, pure=False,
                                        key=f"corpus-copy-{run_id}-{target}-{start}"))
    report("assemble", 0, len(copies))
    for k, fut in enumerate(as_completed(copies), 1):
        fut.result()  # a failed copy raises here; a resumed run redoes the assembly
        report("assemble", k, len(copies))


def _offsets(counts) -> np.ndarray:
    return np.concatenate([[0], np.cumsum(counts, dtype=np.int64)]).astype(np.int64)


def _ring_targets(root, levels: Sequence[int], f_off: np.ndarray, chunk: int) -> list:
    from meshsom.store import create_rings, rings_name

    create_rings(root, levels, int(f_off[-1]), chunk)
    return [(f"rings/{rings_name(lv)}", int(f_off[-1]), f"level{lv}", f_off, None) for lv in levels]


def corpus_statistics(root, levels: Sequence[int], ordered: list, scaling: str, robust_clip: float) -> dict:
    """Scaling and fold statistics of every level into ``rings/stats``, from the shards' per-mesh accumulators.

    The accumulators are merged in mesh order, whatever the sharding; the fold statistics (and
    robust scaling) come from the assembled rings.

    Returns
    -------
    dict
        Level -> {"stats": scaling statistics, "folds": fold statistics}.
    """
    from meshsom.standardize import SCALINGS, finalize, fold_statistics, merge_accumulators, robust_stats
    from meshsom.store import read_folds, write_fold_stats, write_stats

    if scaling not in SCALINGS:
        raise ValueError(f"scaling must be one of {list(SCALINGS)}, received {scaling!r}")
    folds = read_folds(root, min(levels)).astype(np.float64)  # the same folds at every level
    out = {}
    for lv in levels:
        if scaling == "robust":
            stats = robust_stats(folds, lv, robust_clip).to_dict()
        else:
            acc = merge_accumulators(*[np.asarray(a, np.float64) for m in ordered for a in m["acc"][str(lv)]])
            stats = finalize(acc, lv).to_dict()
        fstats = fold_statistics(folds, lv)
        write_stats(root, lv, stats)
        write_fold_stats(root, lv, fstats)
        out[lv] = {"stats": stats, "folds": fstats}
    return out


def _assemble(client, root, path: str, shards, metas, plan, cfg, levels, chunk, run_id, report) -> None:
    """Final arrays by chunk-aligned copies, then tables, statistics, root attributes and manifest."""
    from meshsom.store import create_corpus_arrays, write_manifest, write_mesh_tables
    from pipelines import ingest

    ordered = [metas[sh.name] for sh in shards]
    seen: dict[str, str] = {}  # ids unique before anything is written (expand_inputs checked the files already)
    for r in [*plan["missing"], *(r for m in ordered for r in m["records"])]:
        ingest.check_unique_id(seen, r["id"], r["source"])
    v_off = _offsets([sum(m["n_vertices"]) for m in ordered])
    f_off = _offsets([sum(m["n_faces"]) for m in ordered])
    m_off = _offsets([len(m["ids"]) for m in ordered])

    write_mesh_tables(root, [i for m in ordered for i in m["ids"]], [s for m in ordered for s in m["labels"]],
                      [n for m in ordered for n in m["n_vertices"]], [n for m in ordered for n in m["n_faces"]],
                      [o for m in ordered for o in m["origins"]])
    create_corpus_arrays(root, int(v_off[-1]), int(f_off[-1]), chunk)
    targets = [("vertices", int(v_off[-1]), "vertices", v_off, None), ("faces", int(f_off[-1]), "faces", f_off, v_off),
               ("face_mesh", int(f_off[-1]), "face_mesh", f_off, m_off)]
    _fill(client, path, targets + _ring_targets(root, levels, f_off, chunk), shards, chunk, run_id, report)
    if f_off[-1] == 0:
        log.warning("%s: no accepted mesh; no statistics", path)
    elif levels:
        corpus_statistics(root, levels, ordered, cfg.encoding.scaling, cfg.encoding.robust_clip)

    records = list(plan["missing"])
    index = 0
    for m in ordered:
        for r in m["records"]:
            if r["status"] == "accepted":
                r["index"] = index
                index += 1
            records.append(r)
    extra = {
        "faces_in": sum(r["faces_in"] for r in records),
        "faces_out": sum(r["faces_out"] for r in records),
        "reader": asdict(cfg.corpus.reader),
        "preprocess": asdict(cfg.preprocess),
        "generator": asdict(cfg.corpus.generator) if cfg.corpus.generator is not None else None,
    }
    write_manifest(path, records, extra)  # last: a store with a manifest and no staging is finished


def mesh_batches(face_offsets: np.ndarray, batch_faces: int) -> list[tuple[int, int]]:
    """Consecutive mesh ranges ``(first, stop)`` holding at most ``batch_faces`` faces (or one mesh)."""
    batches, first = [], 0
    n = len(face_offsets) - 1
    while first < n:
        stop = first + 1
        while stop < n and face_offsets[stop + 1] - face_offsets[first] <= batch_faces:
            stop += 1
        batches.append((first, stop))
        first = stop
    return batches


def encode_corpus(client, store, levels: Sequence[int], chunk_rows: int | None = None,
                  batch_faces: int = DEFAULT_BATCH_FACES, scaling: str = "standard", robust_clip: float = 5.0,
                  progress: Callable[[str, int, int], None] | None = None) -> dict:
    """Encode every mesh of an ingested store on a Dask client (``meshsom encode``).

    Shards of whole meshes (at most ``batch_faces`` faces each, or one mesh) are encoded on the
    workers with :func:`encode_meshes` into ``staging``, then assembled into ``rings/level{L}`` and
    their statistics exactly as :func:`run_corpus` assembles them: the same store as ``meshsom run``.

    Parameters
    ----------
    client : distributed.Client
    store : path
        A store written by ``meshsom ingest``; its ``rings/level{L}`` of ``levels`` are replaced.
    levels : sequence of int
    chunk_rows : int, optional
        Row chunk of the ring arrays (default: the store's faces chunking).
    batch_faces : int
    scaling, robust_clip
        Config ``encoding.scaling`` (standard|robust) and ``encoding.robust_clip``.
    progress : callable, optional
        ``progress(stage, done, total)``, stages ``"encode"`` (shards) and ``"assemble"``.

    Returns
    -------
    dict
        Level -> {"dims", "seconds" (encoding time summed over the shards), "stats", "folds"}.

    Raises
    ------
    StoreError
        No store, no meshes, or no faces to encode.
    MeshsomError
        When shards fail (a mesh that cannot be encoded is named).
    """
    from meshsom.errors import StoreError
    from meshsom.rings import dims, template
    from meshsom.store import corpus_chunk_rows, location, mesh_table, open_store, remove_staging

    path = location(store)
    levels = sorted({int(lv) for lv in levels})
    for lv in levels:
        template(lv)  # validates
    root = open_store(path, mode="r+")
    table = mesh_table(root)
    if int(table.face_offsets[-1]) == 0:
        raise StoreError(f"{path}: the store has no faces to encode")
    chunk = int(chunk_rows or corpus_chunk_rows(root))
    run_id = uuid.uuid4().hex[:8]
    report = progress or (lambda stage, done, total: None)
    remove_staging(path)  # an interrupted encode is redone
    shards = [Shard(f"e{a:08d}", 0, a, b) for a, b in mesh_batches(table.face_offsets, batch_faces)]

    def submit(sh):
        return client.submit(encode_shard, str(path), sh, levels, chunk, pure=False, key=f"encode-{run_id}-{sh.name}")

    metas, failed = _run_shards(client, path, shards, submit, report)
    _shards_failed(path, shards, failed, lambda sh: "meshes")
    ordered = [metas[sh.name] for sh in shards]
    f_off = _offsets([sum(m["n_faces"]) for m in ordered])
    _fill(client, path, _ring_targets(root, levels, f_off, chunk), shards, chunk, run_id, report)
    stats = corpus_statistics(root, levels, ordered, scaling, robust_clip)
    remove_staging(path)
    return {lv: {"dims": dims(lv), "seconds": sum(m["seconds"].get(str(lv), 0.0) for m in ordered), **stats[lv]}
            for lv in levels}
