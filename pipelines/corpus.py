"""Ingest + encode as a Dask graph, with region writes and resumable shards.

The result is the same store, array for array, as ``meshsom ingest`` followed by
``meshsom encode`` in one process (layout: :mod:`meshsom.store`, DESIGN.md §7).

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
import shutil
import uuid
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

log = logging.getLogger(__name__)

#: Group of the per-shard results while a run is under way (removed at the end).
STAGING = "staging"
#: Per-face arrays of a shard, besides the ring levels.
FACE_ARRAYS = ("faces", "face_mesh")


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


def read_source(path: str, reader, name: str | None = None) -> list:
    """Every RawMesh / Rejection of one file, in the reader's order.

    Parameters
    ----------
    path : str
    reader : meshsom.io.ReaderOptions
    name : str, optional
        The start of the mesh ids (``meshsom.io.InputFile.name``).

    Returns
    -------
    items : list of RawMesh or Rejection
        A file that cannot be opened at all is one Rejection.
    """
    from meshsom.io import Rejection, read_file

    try:
        return list(read_file(path, reader, name))
    except OSError as err:
        return [Rejection(name or str(path), str(path), f"cannot be read ({err.strerror or err})")]


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


def slice_items(items: list, start: int, stop: int) -> list:
    """Items ``start..stop`` of a source's list."""
    return items[start:stop]


def shard_done(store: str, name: str) -> bool:
    """Whether ``staging/<name>`` of a store is marked done."""
    import zarr

    try:
        group = zarr.open_group(str(Path(store) / STAGING / name), mode="r")
    except (FileNotFoundError, zarr.errors.GroupNotFoundError):
        return False
    return bool(group.attrs.get("done"))


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
    import zarr

    from meshsom.errors import MeshError
    from meshsom.rings import dims, encode_mesh
    from meshsom.standardize import accumulate, empty_accumulator
    from pipelines import ingest

    group_path = str(Path(store) / STAGING / shard.name)
    if shard_done(store, shard.name):
        return dict(zarr.open_group(group_path, mode="r").attrs["meta"])
    levels = [int(lv) for lv in levels]
    records, meshes, rings = [], [], {lv: [] for lv in levels}
    for raw in items:
        record, mesh = ingest.process_one(raw, params)
        if mesh is not None:
            try:
                encoded = encode_mesh(mesh.vertices, mesh.faces, levels, source=mesh.id)
            except MeshError as err:
                record.update(status="rejected", reason=f"encoding: {err.problem}", faces_out=0)
                record.pop("volume", None)
                mesh = None
            else:
                for lv in levels:
                    rings[lv].append(encoded[lv])
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
    acc = {}
    for lv in levels:
        arrays[f"level{lv}"] = (np.concatenate(rings[lv]).astype(np.float32) if meshes
                                else np.zeros((0, dims(lv)), np.float32))
        acc[str(lv)] = [accumulate(empty_accumulator(), x).tolist() for x in rings[lv]]

    # A fresh group: leftovers of a half-written attempt are dropped.
    group = zarr.open_group(group_path, mode="w")
    for name, data in arrays.items():
        chunks = (max(1, min(chunk_rows, len(data))),) + data.shape[1:]
        arr = group.create_array(name, shape=data.shape, dtype=data.dtype, chunks=chunks)
        if data.size:
            arr[...] = data
    meta = {
        "records": records,
        "ids": [m.id for m in meshes],
        "labels": [m.label or "" for m in meshes],
        "origins": [np.asarray(m.origin, np.float64).tolist() for m in meshes],
        "n_vertices": nv,
        "n_faces": nf,
        "acc": acc,
    }
    group.attrs.update({"meta": meta, "done": True})  # last: only now the shard counts as finished
    return meta


def copy_rows(store: str, target: str, start: int, stop: int, pieces: list) -> int:
    """Fill rows ``start..stop`` of array ``target`` from shard arrays.

    Parameters
    ----------
    store : str
    target : str
        Path of the final array in the store (``faces``, ``rings/level2``).
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
    import zarr

    root = zarr.open_group(store, mode="r+")
    arr = root[target]
    block = np.empty((stop - start,) + tuple(arr.shape[1:]), arr.dtype)
    row = 0
    for shard, name, a, b, add in pieces:
        src = np.asarray(root[f"{STAGING}/{shard}/{name}"][a:b])
        block[row:row + (b - a)] = src + add if add else src
        row += b - a
    if row != stop - start:
        raise RuntimeError(f"{store}: {target} rows {start}..{stop}: pieces cover {row} rows")
    arr[start:stop] = block
    return stop - start


# ----------------------------------------------------------------------------- client side


def _fingerprint(cfg) -> dict:
    """What a resumed run must share with the interrupted one (JSON form)."""
    from meshsom.config import to_dict

    doc = {
        "paths": list(cfg.corpus.paths),
        "generator": to_dict(cfg.corpus.generator),
        "reader": to_dict(cfg.corpus.reader),
        "preprocess": to_dict(cfg.preprocess),
        "levels": [int(lv) for lv in cfg.encoding.levels],
        "shard_meshes": int(cfg.dask.shard_meshes),
        "chunk_rows": int(cfg.store.chunk_rows),
    }
    return json.loads(json.dumps(doc))


def _finished_summary(path: Path, levels: Sequence[int]) -> dict | None:
    """The manifest summary of a finished store at ``path``, or None if it is unfinished."""
    from meshsom.errors import StoreError
    from meshsom.store import MANIFEST, open_store, read_manifest, rings_name

    if not (path / MANIFEST).is_file() or (path / STAGING).exists():
        return None
    root = open_store(path)
    have = set(root["rings"].array_keys()) if "rings" in root else set()
    missing = [lv for lv in levels if rings_name(lv) not in have]
    if missing:
        raise StoreError(
            f"{path}: a finished store without rings for level(s) {missing}; run without resume to rebuild it"
        )
    return read_manifest(path)["summary"]


def _rejection_record(rejection, params) -> dict:
    from pipelines import ingest

    return ingest.process_one(rejection, params)[0]


def run_corpus(client, cfg, store, resume: bool = False,
               progress: Callable[[str, int, int], None] | None = None) -> dict:
    """Ingest and encode the configured corpus into ``store`` on a Dask client.

    Parameters
    ----------
    client : distributed.Client
    cfg : meshsom.config.ExperimentConfig
        Uses ``corpus`` (paths, generator, reader), ``preprocess``,
        ``encoding.levels``, ``dask.shard_meshes`` and ``store.chunk_rows``.
    store : path
        The zarr store. Without ``resume`` it is created afresh (anything at
        ``store`` is replaced: the caller checks ``--overwrite``).
    resume : bool
        Continue an interrupted run: shards marked done are not recomputed, and
        a finished store is returned as it is. The config must be the one of
        the interrupted run.
    progress : callable, optional
        Called as ``progress(stage, done, total)`` with stage ``"read"``,
        ``"encode"`` (shards) or ``"assemble"`` (chunk copies).

    Returns
    -------
    summary : dict
        The manifest summary (inputs, accepted, rejected, faces_in, faces_out,
        reader, preprocess, generator), as ``meshsom ingest`` writes it.

    Raises
    ------
    StoreError
        When a resumed store was made with another configuration.
    MeshsomError
        When shards fail; the others are finished and kept, so a resumed run
        only redoes the failed ones.
    """
    from distributed import as_completed

    from meshsom.errors import MeshsomError, StoreError
    from meshsom.io import expand_inputs
    from meshsom.store import create_store, open_store

    path = Path(store)
    levels = sorted({int(lv) for lv in cfg.encoding.levels})
    chunk = int(cfg.store.chunk_rows)
    fingerprint = _fingerprint(cfg)
    run_id = uuid.uuid4().hex[:8]
    report = progress or (lambda stage, done, total: None)

    root = None
    if resume and path.exists():
        summary = _finished_summary(path, levels)
        if summary is not None:
            log.info("%s: finished already; nothing to resume", path)
            return summary
        root = open_store(path, mode="r+")
    if root is None:
        root = create_store(path, overwrite=True)
    staging = root.require_group(STAGING)

    # ---- plan: sources and their shards, kept in the store for a resumed run
    plan = staging.attrs.get("plan")
    if plan is not None and plan["fingerprint"] != fingerprint:
        raise StoreError(
            f"{path}: was started with another configuration (corpus, preprocessing, levels, shard size or "
            f"chunk rows differ); run without resume to start again"
        )
    read_futures = {}
    if plan is None:
        files, missing = expand_inputs(list(cfg.corpus.paths))
        sources = [{"kind": "file", "path": str(f.path), "name": f.name} for f in files]
        for i, src in enumerate(sources):
            read_futures[i] = client.submit(read_source, src["path"], cfg.corpus.reader, src["name"], pure=False,
                                            key=f"corpus-read-{run_id}-{i}")
        counts = {}
        for k, (i, n) in enumerate(zip(read_futures, client.gather([client.submit(len, f, pure=False)
                                                                      for f in read_futures.values()])), 1):
            counts[i] = int(n)
            report("read", k, len(read_futures))
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
            "sources": sources,
            "shards": [asdict(s) for s in shards],
            "missing": [_rejection_record(r, cfg.preprocess) for r in missing],
        }
        staging.attrs["plan"] = plan
    sources = plan["sources"]
    shards = [Shard(**s) for s in plan["shards"]]

    # ---- shards: preprocess + encode + staging write, done ones skipped
    metas: dict[str, dict] = {}
    futures = {}
    for sh in shards:
        if shard_done(str(path), sh.name):
            metas[sh.name] = dict(staging[sh.name].attrs["meta"])
            continue
        src = sources[sh.source]
        if src["kind"] == "generator":
            items = client.submit(generate_items, cfg.corpus.generator, sh.start, sh.stop, pure=False,
                                  key=f"corpus-generate-{run_id}-{sh.name}")
        else:
            if sh.source not in read_futures:
                read_futures[sh.source] = client.submit(read_source, src["path"], cfg.corpus.reader, src.get("name"), pure=False,
                                                        key=f"corpus-read-{run_id}-{sh.source}")
            items = client.submit(slice_items, read_futures[sh.source], sh.start, sh.stop, pure=False,
                                  key=f"corpus-slice-{run_id}-{sh.name}")
        fut = client.submit(process_shard, str(path), sh, items, cfg.preprocess, levels, chunk, pure=False,
                            key=f"corpus-shard-{run_id}-{sh.name}")
        futures[fut.key] = (sh, fut)
    read_futures.clear()  # the shard tasks hold what they need; memory is freed as they finish
    items = fut = None
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
    futures.clear()
    if failed:
        sh, err = failed[0]
        src = sources[sh.source]
        what = src.get("path", "generator")
        raise MeshsomError(
            f"{path}: {len(failed)} of {len(shards)} shards failed (first: {sh.name}, items {sh.start}..{sh.stop} "
            f"of {what}: {type(err).__name__}: {err}); the others are kept, rerun with resume to finish"
        ) from err

    _assemble(client, root, path, shards, metas, plan, cfg, levels, chunk, run_id, report)
    shutil.rmtree(path / STAGING)
    from meshsom.store import read_manifest

    return read_manifest(path)["summary"]


def _create_rows(group, name: str, shape: tuple, dtype, chunk_rows: int):
    """An empty per-row array chunked as :func:`meshsom.store.write_meshes` chunks it."""
    chunks = (max(1, min(chunk_rows, max(shape[0], 1))),) + tuple(shape[1:])
    return group.create_array(name, shape=shape, dtype=dtype, chunks=chunks, overwrite=True)


def _assemble(client, root, path: Path, shards, metas, plan, cfg, levels, chunk, run_id, report) -> None:
    """Final arrays by chunk-aligned copies, then tables, statistics, root attributes and manifest."""
    from distributed import as_completed

    from meshsom.rings import dims
    from meshsom.standardize import merge_accumulators
    # _put is the helper write_meshes uses: the per-mesh tables get exactly its chunking.
    from meshsom.store import STRING, _put, rings_name, write_manifest
    from pipelines import ingest
    from pipelines.encode_cmd import level_statistics

    ordered = [metas[sh.name] for sh in shards]
    seen: dict[str, str] = {}  # ids unique before anything is written (expand_inputs checked the files already)
    for r in [*plan["missing"], *(r for m in ordered for r in m["records"])]:
        ingest.check_unique_id(seen, r["id"], r["source"])
    nv_shard = [sum(m["n_vertices"]) for m in ordered]
    nf_shard = [sum(m["n_faces"]) for m in ordered]
    nm_shard = [len(m["ids"]) for m in ordered]
    v_off = np.concatenate([[0], np.cumsum(nv_shard, dtype=np.int64)]).astype(np.int64)
    f_off = np.concatenate([[0], np.cumsum(nf_shard, dtype=np.int64)]).astype(np.int64)
    m_off = np.concatenate([[0], np.cumsum(nm_shard, dtype=np.int64)]).astype(np.int64)
    n_vertices, n_faces, n_meshes = int(v_off[-1]), int(f_off[-1]), int(m_off[-1])

    # Per-mesh tables (small): exactly as write_meshes writes them.
    nv = np.array([n for m in ordered for n in m["n_vertices"]], np.int64)
    nf = np.array([n for m in ordered for n in m["n_faces"]], np.int64)
    meshes = root.require_group("meshes")
    _put(meshes, "ids", np.array([i for m in ordered for i in m["ids"]], dtype=STRING), max(n_meshes, 1))
    _put(meshes, "labels", np.array([s for m in ordered for s in m["labels"]], dtype=STRING), max(n_meshes, 1))
    _put(meshes, "vertex_offsets", np.concatenate([[0], np.cumsum(nv)]).astype(np.int64), max(n_meshes + 1, 1))
    _put(meshes, "face_offsets", np.concatenate([[0], np.cumsum(nf)]).astype(np.int64), max(n_meshes + 1, 1))
    _put(meshes, "origins", np.array([o for m in ordered for o in m["origins"]], np.float64).reshape(n_meshes, 3),
         max(n_meshes, 1))

    # Per-row arrays: created here, filled chunk by chunk on the workers.
    rings = root.require_group("rings")
    targets = [  # (target path, group, name, shape, dtype, staging name, offsets of rows, value offsets)
        ("vertices", root, "vertices", (n_vertices, 3), np.float64, "vertices", v_off, None),
        ("faces", root, "faces", (n_faces, 3), np.int64, "faces", f_off, v_off),
        ("face_mesh", root, "face_mesh", (n_faces,), np.int32, "face_mesh", f_off, m_off),
    ] + [
        (f"rings/{rings_name(lv)}", rings, rings_name(lv), (n_faces, dims(lv)), np.float32, f"level{lv}", f_off, None)
        for lv in levels
    ]
    copies = []
    for target, group, name, shape, dtype, staged, row_off, add_off in targets:
        _create_rows(group, name, shape, dtype, chunk)
        for start in range(0, shape[0], chunk):
            stop = min(shape[0], start + chunk)
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

    # Statistics: per-mesh accumulators merged in mesh order, whatever the sharding; fold
    # statistics (and robust scaling) from the assembled rings.
    if n_faces == 0:
        log.warning("%s: no accepted mesh; no statistics", path)
    else:
        accs = {lv: merge_accumulators(*[np.asarray(a, np.float64) for m in ordered for a in m["acc"][str(lv)]])
                for lv in levels}
        level_statistics(root, levels, accs, cfg.encoding.scaling, cfg.encoding.robust_clip)
    root.attrs.update({"n_meshes": n_meshes, "n_faces": n_faces, "n_vertices": n_vertices})

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
