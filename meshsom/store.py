"""The zarr (v3) store layout: the one module that knows array names, chunking and attributes.

Every group, array and attribute of a store is created and read here; pipelines, reports and
the library call these functions and never open a zarr path themselves. The layout (DESIGN.md
§7) is a contract that bench scripts, reports and other tools read:

    STORE.zarr/                           root attributes: ``meshsom_layout`` (LAYOUT_VERSION),
                                          ``created_by`` ("meshsom"); ``n_meshes``, ``n_faces``,
                                          ``n_vertices`` once meshes are written; ``mlflow``
                                          (tracking ids: uri, experiment, name, parent, children)
      manifest.json                       not a zarr node: ``summary`` (inputs = accepted +
                                          rejected, faces_in, faces_out, reader, preprocess,
                                          generator) and ``records``, one per input mesh: id,
                                          source, status (accepted|rejected), reason, faces_in,
                                          faces_out, label, lod, repairs, index (its row in
                                          meshes/*, accepted only), volume, notes, union
      meshes/ids (n,) str                 meshes/labels (n,) str ('' where unknown)
      meshes/vertex_offsets (n+1,) int64  meshes/face_offsets (n+1,) int64
      meshes/origins (n, 3) float64       world position of each mesh's local origin
      vertices (V, 3) float64             re-centred per mesh
      faces (F, 3) int64                  indices into ``vertices`` (global rows)
      face_mesh (F,) int32                mesh index of every face
      rings/level{L} (F, 9*4^(L-1)) float32   raw folds, start leaf k = 0
      rings/stats                         a group with attributes only: ``level{L}``, the scaling
                                          of that level (meshsom.standardize.Stats.to_dict:
                                          scaling standard|robust, mean (or median) and std (or
                                          IQR/1.349) per component type alpha, u, v, count,
                                          clip); ``folds_level{L}``, the fold statistics
                                          (meshsom.standardize.fold_statistics)
      runs/<run>/                         one trained map (a triangle map ``level{L}-{kernel}``,
                                          or a map a user saved under any name)
        weights (rows*cols, D) float32    prototypes, row-major over the grid
        bmu_unit, bmu_variation, bmu_second (N,) int64, bmu_dist2 (N,) float64
                                          per training vector (:data:`BMU_ARRAYS`), those of the
                                          search of epoch ``bmu_epoch`` (= epochs: the final pass)
        attributes                        rows, cols, topology, level, kernel, metrics (final
                                          t/q/qc errors); a map trained by pipelines/train.py also
                                          has fingerprint, job (the TrainJob), epoch_done,
                                          history (per-epoch errors), bmu_epoch, and when
                                          finished result, final_done, engine
        domain/                           the domain map of this triangle map (DESIGN.md §5)
          weights (dr*dc, rows*cols) float32, units (n,) int64, vectors (n, rows*cols) float32
          attributes                      rows, cols, sigma, metrics
      staging/                            only while ``meshsom run``/``ingest``/``encode`` works;
                                          attribute ``plan``; staging/<shard>/ holds a shard's rows
                                          (vertices, faces, face_mesh, level{L}) and, written
                                          last, attributes ``meta`` and ``done``
    STORE-figures/                        beside a local store (not in it): U-matrix and domain-map
                                          PNGs; for a remote store ``./STORE-figures`` in the
                                          working directory (:func:`figures_dir`)

Chunking: every per-row array is chunked by rows only, ``min(chunk_rows, max(n, 1))`` rows per
chunk (:func:`chunk_of`), ``chunk_rows`` from ``store.chunk_rows`` (default
:data:`DEFAULT_CHUNK_ROWS`); the per-mesh tables are one chunk; the BMU arrays of a run are
chunked as the training tasks write them (:func:`create_bmu_arrays`); domain vectors written by
tasks are chunked by the task's meshes; the other domain arrays are one chunk.

Where a store lives: ``path`` is a local folder or any fsspec URL (``s3://bucket/name.zarr``,
``gs://...``, ``memory://...``; :func:`is_remote`). A remote store is read and written through
zarr's fsspec store with :data:`REMOTE_OPTIONS`; ``manifest.json``, the existence, removal and
writability checks go through fsspec too. Credentials and the endpoint come from the
filesystem's own configuration, read by every process that opens the store (so every Dask
worker reads them itself): for S3 the standard ``AWS_ACCESS_KEY_ID``, ``AWS_SECRET_ACCESS_KEY``,
``AWS_ENDPOINT_URL`` (or ``~/.aws``), or fsspec's ``FSSPEC_S3_<KWARG>`` variables (e.g.
``FSSPEC_S3_ENDPOINT_URL``) and config files. None of it is in the experiment YAML, so no
secret reaches MLflow params. Figures are files for people and for MLflow artifacts, so those of
a remote store are written to a local folder (:func:`figures_dir`).
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
import uuid
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterable, Iterator, Sequence

import numpy as np
import zarr

from meshsom.errors import StoreError

LAYOUT_VERSION = 1
MANIFEST = "manifest.json"
#: Rows per chunk of the per-face arrays, unless the caller says otherwise.
DEFAULT_CHUNK_ROWS = 65_536
#: Variable-length UTF-8 strings (zarr v3 "string" data type).
STRING = np.dtypes.StringDType()


@dataclass(frozen=True)
class CleanMesh:
    """A preprocessed mesh ready for the store.

    Attributes
    ----------
    id : str
    vertices : (V, 3) float64
        Local coordinates (re-centred).
    faces : (F, 3) int64
        Indices into ``vertices``.
    origin : (3,) float64
    label : str or None
    """

    id: str
    vertices: np.ndarray = field(repr=False)
    faces: np.ndarray = field(repr=False)
    origin: np.ndarray = field(repr=False)
    label: str | None = None


# ----------------------------------------------------------------------------- where a store lives

#: fsspec options of every remote store: no cached directory listings (Dask workers in other
#: processes write the store too, so a listing cached in this process could be stale).
REMOTE_OPTIONS = {"use_listings_cache": False}
#: What to install for the usual protocols (a missing fsspec backend is named in the error).
BACKEND_PACKAGES = {"s3": "s3fs (pip install 'meshsom[s3]')", "gs": "gcsfs", "gcs": "gcsfs", "az": "adlfs",
                    "abfs": "adlfs", "http": "aiohttp (pip install 'meshsom[s3]' brings it)", "https": "aiohttp"}


def location(path: str | os.PathLike) -> str:
    """The canonical form of a store's path: a URL without trailing ``/``, or a local path (``file://`` dropped)."""
    s = os.fspath(path)
    if s.startswith("file://"):
        return s[len("file://"):]
    return s.rstrip("/") if "://" in s else s


def is_remote(path: str | os.PathLike) -> bool:
    """Whether ``path`` is an fsspec URL of a non-local filesystem (``s3://bucket/name.zarr``)."""
    return "://" in location(path)


def store_url(path: str | os.PathLike) -> str:
    """The store as anyone can name it: the URL of a remote store, the absolute path of a local one."""
    loc = location(path)
    return loc if is_remote(loc) else str(Path(loc).resolve())


def filesystem(path: str | os.PathLike):
    """``(filesystem, path inside it)`` of a remote store (or of an input on object storage: :mod:`meshsom.mirror`)."""
    from fsspec.core import url_to_fs

    loc = location(path)
    try:
        return url_to_fs(loc, **REMOTE_OPTIONS)
    except ImportError as err:
        protocol = loc.split("://", 1)[0]
        raise StoreError(f"{loc}: protocol {protocol!r} needs an fsspec backend that is not installed "
                         f"({BACKEND_PACKAGES.get(protocol, err)})") from None
    except ValueError as err:  # unknown protocol
        raise StoreError(f"{loc}: not a local path nor a URL fsspec knows ({err})") from None


def _join(path: str | os.PathLike, *parts: str) -> str:
    loc = location(path)
    return "/".join([loc, *parts]) if is_remote(loc) else str(Path(loc).joinpath(*parts))


def _open_group(path: str, mode: str) -> zarr.Group:
    """A zarr v3 group (v3 said outright: no probing for v2 metadata, which costs requests remotely)."""
    if is_remote(path):
        return zarr.open_group(path, mode=mode, zarr_format=3, storage_options=dict(REMOTE_OPTIONS))
    return zarr.open_group(path, mode=mode, zarr_format=3)


def store_exists(path: str | os.PathLike) -> bool:
    """Whether anything (a store, a file, any object under the prefix) is at ``path``."""
    if not is_remote(path):
        return Path(location(path)).exists()
    fs, root = filesystem(path)
    return bool(fs.exists(root))


def remove_store(path: str | os.PathLike) -> None:
    """Delete a store (a local folder, or every object under a remote prefix); nothing there is fine."""
    if not is_remote(path):
        shutil.rmtree(location(path), ignore_errors=True)
        return
    fs, root = filesystem(path)
    if fs.exists(root):
        fs.rm(root, recursive=True)


def probe_writable(path: str | os.PathLike, needed_bytes: int = 0) -> None:
    """Fail unless a store can be written at ``path`` (and, locally, ``needed_bytes`` are free).

    Locally a file is created and removed in the nearest existing folder (permissions alone say
    nothing for root or on a read-only mount); remotely a small object is written under the
    store's prefix and removed (a missing bucket, bad credentials or an unreachable endpoint
    fail here, before any work). Free space is not checked remotely.

    Raises
    ------
    StoreError
        Naming the path and what failed.
    """
    loc = location(path)
    if is_remote(loc):
        fs, root = filesystem(loc)
        probe = f"{root}/.meshsom-probe-{uuid.uuid4().hex[:8]}"
        try:
            fs.pipe_file(probe, b"meshsom")
            fs.rm(probe)
        except Exception as err:  # noqa: BLE001 - fsspec backends raise their own types (botocore, aiohttp, ...)
            raise StoreError(f"{loc}: cannot write there ({type(err).__name__}: {err})") from None
        return
    p = Path(loc)
    probe_dir = p.parent if str(p.parent) else Path(".")
    while not probe_dir.exists():
        probe_dir = probe_dir.parent
    try:
        with tempfile.NamedTemporaryFile(dir=probe_dir, prefix=".meshsom-probe-"):
            pass
    except OSError as err:
        raise StoreError(f"{loc}: cannot write into {probe_dir} ({err.strerror or err})") from None
    if needed_bytes:
        free = shutil.disk_usage(probe_dir).free
        if free < needed_bytes:
            raise StoreError(
                f"{loc}: needs about {needed_bytes / 1e6:,.0f} MB, but only {free / 1e6:,.0f} MB are free on its disk"
            )


def create_store(path: str | os.PathLike, overwrite: bool = False) -> zarr.Group:
    """Create an empty store (a local folder or a remote URL); refuse to overwrite an existing one unless asked.

    Raises
    ------
    StoreError
        When ``path`` exists and ``overwrite`` is false, or cannot be written.
    """
    loc = location(path)
    if store_exists(loc) and not overwrite:
        raise StoreError(f"{loc}: already exists; pass overwrite=True (--overwrite) to replace it")
    try:
        group = _open_group(loc, mode="w")
    except OSError as err:
        raise StoreError(f"{loc}: cannot be created ({err.strerror or err})") from None
    group.attrs.update({"meshsom_layout": LAYOUT_VERSION, "created_by": "meshsom"})
    return group


def open_store(path: str | os.PathLike, mode: str = "r") -> zarr.Group:
    """Open an existing store (a local folder or a remote URL).

    Raises
    ------
    StoreError
        When there is no meshsom store at ``path``.
    """
    loc = location(path)
    missing = StoreError(f"{loc}: no zarr store here (expected a store made by `meshsom ingest` or `meshsom run`)")
    if not is_remote(loc) and not Path(loc, "zarr.json").is_file():
        raise missing
    try:
        group = _open_group(loc, mode=mode)
    except (FileNotFoundError, zarr.errors.GroupNotFoundError):
        raise missing from None
    if group.attrs.get("meshsom_layout") != LAYOUT_VERSION:
        raise StoreError(
            f"{loc}: store layout {group.attrs.get('meshsom_layout')!r}, expected {LAYOUT_VERSION} (made by another meshsom version?)"
        )
    return group


def store_path(group: zarr.Group) -> str:
    """Where a store group lives: its local folder, or the URL of a remote store."""
    store = group.store
    if hasattr(store, "fs"):  # zarr's FsspecStore
        return store.fs.unstrip_protocol(store.path)
    return str(store.root) if hasattr(store, "root") else str(store)


def chunk_of(n_rows: int, chunk_rows: int) -> int:
    """Rows per chunk of a per-row array of ``n_rows`` rows: ``chunk_rows``, at most ``n_rows``, at least 1."""
    return max(1, min(int(chunk_rows), max(int(n_rows), 1)))


def create_rows(group: zarr.Group, name: str, shape: tuple, dtype, chunk_rows: int) -> zarr.Array:
    """An empty per-row array (replacing one of that name), chunked by :func:`chunk_of` rows."""
    chunks = (chunk_of(shape[0], chunk_rows),) + tuple(shape[1:])
    return group.create_array(name, shape=tuple(shape), dtype=dtype, chunks=chunks, overwrite=True)


def put_rows(group: zarr.Group, name: str, data: np.ndarray, chunk_rows: int = DEFAULT_CHUNK_ROWS) -> zarr.Array:
    """Write a whole per-row array (replacing one of that name), chunked by :func:`chunk_of` rows.

    Parameters
    ----------
    data : (n, ...) array
        Stored with its own dtype.
    """
    data = np.asarray(data)
    arr = create_rows(group, name, data.shape, data.dtype, chunk_rows)
    if data.size:
        arr[...] = data
    return arr


def write_mesh_tables(group: zarr.Group, ids: Sequence[str], labels: Sequence[str | None], n_vertices,
                      n_faces, origins) -> None:
    """Write the per-mesh tables ``meshes/*`` and the root counts.

    Parameters
    ----------
    group : zarr.Group
        The store root.
    ids, labels : sequence of str
        Per mesh; a label None is stored as ''.
    n_vertices, n_faces : (n,) int
        Vertices and faces per mesh, in order.
    origins : (n, 3) float
    """
    n = len(ids)
    voff = np.concatenate([[0], np.cumsum(np.asarray(n_vertices, np.int64))]).astype(np.int64)
    foff = np.concatenate([[0], np.cumsum(np.asarray(n_faces, np.int64))]).astype(np.int64)
    meshes = group.require_group("meshes")
    put_rows(meshes, "ids", np.array(list(ids), dtype=STRING), max(n, 1))
    put_rows(meshes, "labels", np.array([s or "" for s in labels], dtype=STRING), max(n, 1))
    put_rows(meshes, "vertex_offsets", voff, max(n + 1, 1))
    put_rows(meshes, "face_offsets", foff, max(n + 1, 1))
    put_rows(meshes, "origins", np.array(origins, np.float64).reshape(n, 3), max(n, 1))
    group.attrs.update({"n_meshes": int(n), "n_faces": int(foff[-1]), "n_vertices": int(voff[-1])})


#: Per-row arrays of the corpus besides the rings: name -> (columns, dtype).
CORPUS_ARRAYS = {"vertices": ((3,), np.float64), "faces": ((3,), np.int64), "face_mesh": ((), np.int32)}


def corpus_counts(group: zarr.Group) -> dict:
    """``n_meshes``, ``n_faces``, ``n_vertices`` of the stored corpus (the root attributes; None where absent)."""
    return {k: group.attrs.get(k) for k in ("n_meshes", "n_faces", "n_vertices")}


def create_corpus_arrays(group: zarr.Group, n_vertices: int, n_faces: int, chunk_rows: int) -> dict[str, zarr.Array]:
    """Empty ``vertices``, ``faces`` and ``face_mesh`` arrays, to be filled by row ranges.

    Returns
    -------
    dict
        Array path in the store -> array.
    """
    rows = {"vertices": n_vertices, "faces": n_faces, "face_mesh": n_faces}
    return {name: create_rows(group, name, (int(rows[name]),) + cols, dtype, chunk_rows)
            for name, (cols, dtype) in CORPUS_ARRAYS.items()}


def corpus_chunk_rows(group: zarr.Group) -> int:
    """Rows per chunk of a store's per-face arrays (those of ``faces``)."""
    return int(group["faces"].chunks[0])


def write_meshes(group: zarr.Group, meshes: Sequence[CleanMesh], chunk_rows: int = DEFAULT_CHUNK_ROWS) -> None:
    """Write the cleaned meshes (replaces any meshes already there).

    Parameters
    ----------
    group : zarr.Group
        The store root.
    meshes : sequence of CleanMesh
    chunk_rows : int
        Rows per chunk of the per-vertex and per-face arrays.
    """
    n = len(meshes)
    nv = np.array([len(m.vertices) for m in meshes], np.int64)
    nf = np.array([len(m.faces) for m in meshes], np.int64)
    voff = np.concatenate([[0], np.cumsum(nv)]).astype(np.int64)
    write_mesh_tables(group, [m.id for m in meshes], [m.label for m in meshes], nv, nf,
                      [m.origin for m in meshes])
    arrays = create_corpus_arrays(group, int(voff[-1]), int(nf.sum()), chunk_rows)
    if n:
        arrays["vertices"][...] = np.concatenate([m.vertices for m in meshes]).astype(np.float64)
    if nf.sum():
        arrays["faces"][...] = np.concatenate([m.faces + voff[i] for i, m in enumerate(meshes)]).astype(np.int64)
        arrays["face_mesh"][...] = np.repeat(np.arange(n, dtype=np.int32), nf)


@dataclass(frozen=True)
class MeshTable:
    """The per-mesh index of a store.

    Attributes
    ----------
    ids : (n,) str
    labels : (n,) str
    vertex_offsets : (n+1,) int64
    face_offsets : (n+1,) int64
    origins : (n, 3) float64
    """

    ids: np.ndarray
    labels: np.ndarray
    vertex_offsets: np.ndarray
    face_offsets: np.ndarray
    origins: np.ndarray

    def __len__(self) -> int:
        return len(self.ids)


def mesh_table(group: zarr.Group) -> MeshTable:
    """Read the per-mesh index."""
    if "meshes" not in group:
        raise StoreError(f"{store_path(group)}: has no meshes/ (run `meshsom ingest` first)")
    g = group["meshes"]
    return MeshTable(
        ids=np.asarray(g["ids"][:]).astype(object).astype(str),
        labels=np.asarray(g["labels"][:]).astype(object).astype(str),
        vertex_offsets=np.asarray(g["vertex_offsets"][:]),
        face_offsets=np.asarray(g["face_offsets"][:]),
        origins=np.asarray(g["origins"][:]),
    )


def read_mesh(group: zarr.Group, index: int, table: MeshTable | None = None) -> tuple[np.ndarray, np.ndarray]:
    """One cleaned mesh.

    Returns
    -------
    vertices : (V, 3) float64
        Local (re-centred) coordinates.
    faces : (F, 3) int64
        Indices into ``vertices``.
    """
    table = table or mesh_table(group)
    if not 0 <= index < len(table):
        raise IndexError(f"mesh index {index} out of range; the store has {len(table)} meshes")
    v0, v1 = table.vertex_offsets[index], table.vertex_offsets[index + 1]
    f0, f1 = table.face_offsets[index], table.face_offsets[index + 1]
    return np.asarray(group["vertices"][v0:v1]), np.asarray(group["faces"][f0:f1]) - v0


def read_meshes(group: zarr.Group, start: int, stop: int,
                table: MeshTable | None = None) -> list[tuple[str, np.ndarray, np.ndarray]]:
    """Meshes ``start..stop`` as (id, vertices, faces), read in one slice of each array.

    Returns
    -------
    list of (str, (V, 3) float64, (F, 3) int64)
        Faces index the mesh's own vertices.
    """
    table = table or mesh_table(group)
    v0, f0 = int(table.vertex_offsets[start]), int(table.face_offsets[start])
    vertices = np.asarray(group["vertices"][v0:int(table.vertex_offsets[stop])])
    faces = np.asarray(group["faces"][f0:int(table.face_offsets[stop])]) - v0
    vo, fo = table.vertex_offsets[start:stop + 1] - v0, table.face_offsets[start:stop + 1] - f0
    return [(str(table.ids[i]), vertices[vo[k]:vo[k + 1]], faces[fo[k]:fo[k + 1]] - vo[k])
            for k, i in enumerate(range(start, stop))]


def iter_meshes(group: zarr.Group) -> Iterator[tuple[int, np.ndarray, np.ndarray]]:
    """Every mesh in order, as (index, vertices, faces)."""
    table = mesh_table(group)
    vertices = np.asarray(group["vertices"][:])
    faces = np.asarray(group["faces"][:])
    for i in range(len(table)):
        v0, v1 = table.vertex_offsets[i], table.vertex_offsets[i + 1]
        f0, f1 = table.face_offsets[i], table.face_offsets[i + 1]
        yield i, vertices[v0:v1], faces[f0:f1] - v0


# ----------------------------------------------------------------------------- manifest


def write_manifest(path: str | os.PathLike, records: list[dict], extra: dict | None = None) -> dict:
    """Write ``manifest.json`` into the store folder; returns the document.

    The summary counts ``accepted`` and ``rejected`` records; ``inputs`` is
    their sum, by construction.
    """
    accepted = sum(r["status"] == "accepted" for r in records)
    rejected = sum(r["status"] == "rejected" for r in records)
    doc = {
        "summary": {"inputs": len(records), "accepted": accepted, "rejected": rejected, **(extra or {})},
        "records": records,
    }
    if is_remote(path):  # one object PUT: atomic on object storage
        fs, root = filesystem(path)
        fs.pipe_file(f"{root}/{MANIFEST}", json.dumps(doc, indent=1).encode())
        return doc
    target = Path(location(path)) / MANIFEST
    tmp = target.with_suffix(".json.tmp")
    with open(tmp, "w") as fh:
        json.dump(doc, fh, indent=1)
    os.replace(tmp, target)
    return doc


def has_manifest(path: str | os.PathLike) -> bool:
    """Whether a store has its ``manifest.json`` (written last by ingest: the corpus is finished)."""
    if is_remote(path):
        fs, root = filesystem(path)
        return bool(fs.isfile(f"{root}/{MANIFEST}"))
    return (Path(location(path)) / MANIFEST).is_file()


def read_manifest(path: str | os.PathLike) -> dict:
    """Read ``manifest.json`` of a store (local or remote)."""
    if not has_manifest(path):
        raise StoreError(f"{location(path)}: has no {MANIFEST}")
    if is_remote(path):
        fs, root = filesystem(path)
        return json.loads(fs.cat_file(f"{root}/{MANIFEST}"))
    with open(Path(location(path)) / MANIFEST) as fh:
        return json.load(fh)


def local_copy(path: str | os.PathLike, name: str, folder: str | os.PathLike) -> Path:
    """A file of a store (``manifest.json``) as a local file, e.g. to log it to MLflow.

    Returns
    -------
    pathlib.Path
        The file itself in a local store; for a remote store a copy written into ``folder``.
    """
    if not is_remote(path):
        return Path(location(path)) / name
    fs, root = filesystem(path)
    target = Path(folder) / name
    target.write_bytes(fs.cat_file(f"{root}/{name}"))
    return target


# ----------------------------------------------------------------------------- rings


def rings_name(level: int) -> str:
    """Array name of a ring level inside ``rings/``."""
    return f"level{int(level)}"


def write_rings(group: zarr.Group, level: int, rings: np.ndarray, chunk_rows: int = DEFAULT_CHUNK_ROWS) -> zarr.Array:
    """Write one level's raw fold vectors, float32, chunked by rows.

    Parameters
    ----------
    rings : (F, D) float
    """
    return put_rows(group.require_group("rings"), rings_name(level), np.asarray(rings, np.float32), chunk_rows)


def create_rings(group: zarr.Group, levels: Iterable[int], n_faces: int, chunk_rows: int) -> dict[str, zarr.Array]:
    """Empty ``rings/level{L}`` arrays (F, dims(L)) float32, to be filled by row ranges.

    Returns
    -------
    dict
        Array path in the store (``rings/level{L}``) -> array.
    """
    from meshsom.rings import dims

    rings = group.require_group("rings")
    return {f"rings/{rings_name(lv)}": create_rows(rings, rings_name(lv), (int(n_faces), dims(lv)), np.float32, chunk_rows)
            for lv in levels}


def ring_levels(group: zarr.Group) -> list[int]:
    """Levels with a ``rings/level{L}`` array, ascending."""
    if "rings" not in group:
        return []
    return sorted(int(name[len("level"):]) for name in group["rings"].array_keys() if name.startswith("level"))


def rings_array(group: zarr.Group, level: int) -> zarr.Array:
    """The (F, D) float32 ring array of a level (lazy; slice it by rows)."""
    name = rings_name(level)
    if "rings" not in group or name not in group["rings"]:
        raise StoreError(f"{store_path(group)}: has no rings/{name} (run `meshsom encode --levels {level}`)")
    return group["rings"][name]


def write_stats(group: zarr.Group, level: int, stats: dict) -> None:
    """Store the standardization statistics of a level (a plain dict of lists)."""
    rings = group.require_group("rings")
    s = rings.require_group("stats")
    s.attrs[rings_name(level)] = stats


def read_stats(group: zarr.Group, level: int) -> dict:
    """Standardization statistics of a level as stored by :func:`write_stats`."""
    try:
        return dict(group["rings"]["stats"].attrs[rings_name(level)])
    except KeyError:
        raise StoreError(f"{store_path(group)}: has no rings/stats for level {level}") from None


def fold_stats_name(level: int) -> str:
    """Attribute name of a level's fold statistics inside ``rings/stats``."""
    return f"folds_{rings_name(level)}"


def write_fold_stats(group: zarr.Group, level: int, stats: dict) -> None:
    """Store the fold statistics of a level (:func:`meshsom.standardize.fold_statistics`)."""
    group.require_group("rings").require_group("stats").attrs[fold_stats_name(level)] = stats


def read_fold_stats(group: zarr.Group, level: int) -> dict:
    """Fold statistics of a level as stored by :func:`write_fold_stats`."""
    try:
        return dict(group["rings"]["stats"].attrs[fold_stats_name(level)])
    except KeyError:
        raise StoreError(f"{store_path(group)}: has no fold statistics for level {level} (encode it again)") from None


def read_folds(group: zarr.Group, level: int) -> np.ndarray:
    """The distinct folds of the corpus, read from the first 9 columns of ``rings/level{L}``.

    Every level-L ring starts with the level-1 ring of its root (DESIGN.md §3), so these columns
    of any level hold every face's three folds, start leaf 0.

    Returns
    -------
    folds : (3F, 3) float32
        ``(alpha, u, v)`` per fold.
    """
    array = rings_array(group, level)
    parts = [np.asarray(array[a:b, :9]) for a, b in iter_row_chunks(array)]
    return (np.concatenate(parts) if parts else np.zeros((0, 9), np.float32)).reshape(-1, 3)


def iter_row_chunks(array: zarr.Array, chunk_rows: int | None = None) -> Iterator[tuple[int, int]]:
    """(start, stop) row ranges aligned to the array's chunks."""
    n = array.shape[0]
    step = chunk_rows or array.chunks[0]
    for start in range(0, n, step):
        yield start, min(n, start + step)


# ----------------------------------------------------------------------------- runs


def run_group(group: zarr.Group, run: str, create: bool = True) -> zarr.Group:
    """The group ``runs/<run>`` of a store."""
    runs = group.require_group("runs") if create else group.get("runs")
    if runs is None or (not create and run not in runs):
        raise StoreError(f"{store_path(group)}: has no run {run!r}")
    return runs.require_group(run) if create else runs[run]


def list_runs(group: zarr.Group) -> list[str]:
    """Names of the runs saved in a store."""
    if "runs" not in group:
        return []
    return sorted(name for name, _ in group["runs"].groups())


#: Per-vector BMU arrays of a run: attribute of meshsom.bmu_numpy.BMUResult -> array name.
BMU_ARRAYS = {"unit": "bmu_unit", "variation": "bmu_variation", "dist2": "bmu_dist2", "second": "bmu_second"}


def _bmu_dtype(attr: str):
    return np.float64 if attr == "dist2" else np.int64


def reset_run(group: zarr.Group, run: str) -> zarr.Group:
    """``runs/<run>`` emptied for a fresh training: its arrays and sub-groups deleted, its attributes cleared."""
    g = run_group(group, run)
    for name in [*g.array_keys(), *g.group_keys()]:
        del g[name]
    g.attrs.clear()
    return g


def write_run_header(run_group: zarr.Group, rows: int, cols: int, topology: str, level: int | None,
                     kernel: str | None, fingerprint: str | None = None, job: dict | None = None) -> None:
    """The attributes that say what map a run holds (written before its first epoch)."""
    run_group.attrs.update({
        "rows": int(rows), "cols": int(cols), "topology": str(topology),
        "level": None if level is None else int(level), "kernel": kernel,
        **({} if fingerprint is None else {"fingerprint": fingerprint}), **({} if job is None else {"job": job}),
    })


def map_shape(run_group: zarr.Group) -> tuple[int, int, str]:
    """``(rows, cols, topology)`` of the map in a run group."""
    a = run_group.attrs
    return int(a["rows"]), int(a["cols"]), str(a["topology"])


def create_bmu_arrays(run_group: zarr.Group, n: int, chunk_rows: int) -> dict[str, zarr.Array]:
    """The (n,) BMU arrays of a run (:data:`BMU_ARRAYS`), chunked by ``chunk_rows``.

    Arrays already there with that shape and chunking are kept (a resumed training rewrites
    them); others are replaced.

    Returns
    -------
    dict
        Array name -> array.
    """
    chunks = (max(1, int(chunk_rows)),)
    out = {}
    for attr, name in BMU_ARRAYS.items():
        if name in run_group and run_group[name].shape == (n,) and run_group[name].chunks == chunks \
                and run_group[name].dtype == _bmu_dtype(attr):
            out[name] = run_group[name]
        else:
            out[name] = run_group.create_array(name, shape=(int(n),), dtype=_bmu_dtype(attr), chunks=chunks,
                                               overwrite=True)
    return out


def write_bmu_rows(run_group: zarr.Group, bmu, start: int) -> None:
    """Write one row block's BMUs into the arrays of :func:`create_bmu_arrays`, from row ``start``
    (a block aligned with their chunks: tasks never share a chunk)."""
    for attr, name in BMU_ARRAYS.items():
        run_group[name][start:start + len(bmu.unit)] = np.asarray(getattr(bmu, attr), _bmu_dtype(attr))


def write_bmus(run_group: zarr.Group, bmu, chunk_rows: int = DEFAULT_CHUNK_ROWS) -> None:
    """Write whole BMU arrays from a :class:`meshsom.bmu_numpy.BMUResult` (replacing any there)."""
    for attr, name in BMU_ARRAYS.items():
        put_rows(run_group, name, np.asarray(getattr(bmu, attr), _bmu_dtype(attr)), chunk_rows)


def read_bmus(run_group: zarr.Group) -> dict | None:
    """The BMU arrays of a run as ``{attr: array}`` (BMUResult fields), or None when it has none."""
    if not all(name in run_group for name in BMU_ARRAYS.values()):
        return None
    return {attr: np.asarray(run_group[name][:]) for attr, name in BMU_ARRAYS.items()}


def write_weights(run_group: zarr.Group, weights: np.ndarray) -> None:
    """Write a run's prototypes ``weights (rows*cols, D)`` as float32, in place when the shape is unchanged."""
    weights = np.asarray(weights, np.float32)
    if "weights" in run_group and run_group["weights"].shape == weights.shape:
        run_group["weights"][...] = weights
    else:
        put_rows(run_group, "weights", weights)


def read_weights(run_group: zarr.Group) -> np.ndarray | None:
    """A run's prototypes (rows*cols, D) float32, or None when it has none."""
    return np.asarray(run_group["weights"][:]) if "weights" in run_group else None


def write_checkpoint(run_group: zarr.Group, weights: np.ndarray, epoch_done: int, history: list,
                     bmu_epoch: int) -> None:
    """Checkpoint a finished epoch: the weights first, then the attributes that mark the epoch done.

    A run killed between the two resumes from the previous epoch, never from half-written weights.

    Parameters
    ----------
    weights : (rows*cols, D) float
        The codebook after the epoch's update.
    epoch_done : int
        Epochs finished (the epoch's index + 1).
    history : list of dict
        Per-epoch errors so far.
    bmu_epoch : int
        Epoch whose search the BMU arrays on disk hold.
    """
    write_weights(run_group, weights)
    run_group.attrs.update({"epoch_done": int(epoch_done), "history": list(history), "bmu_epoch": int(bmu_epoch)})


def read_checkpoint(run_group: zarr.Group) -> dict | None:
    """The last checkpoint of a run, or None when no epoch is done (or no weights are stored).

    Returns
    -------
    dict or None
        ``epoch_done`` (int), ``history`` (list, its first ``epoch_done`` entries), ``weights``
        ((rows*cols, D) float32), ``fingerprint`` (str or None), ``final_done`` (bool),
        ``result`` (dict or None).
    """
    a = dict(run_group.attrs)
    done = int(a.get("epoch_done", 0) or 0)
    if done <= 0 or "weights" not in run_group:
        return None
    return {
        "epoch_done": done, "history": list(a.get("history", []))[:done], "weights": read_weights(run_group),
        "fingerprint": a.get("fingerprint"), "final_done": bool(a.get("final_done", False)),
        "result": a.get("result"),
    }


def write_run_result(run_group: zarr.Group, metrics: dict, result: dict, engine: dict,
                     epochs: int | None = None) -> None:
    """Mark a run finished: final ``metrics``, the ``result`` record, the ``engine`` that ran it.

    The BMU arrays on disk are then those of the final pass: ``bmu_epoch`` = ``epochs`` (default:
    the run's ``epoch_done``).
    """
    epochs = int(run_group.attrs.get("epoch_done", len(result.get("history", [])))) if epochs is None else int(epochs)
    run_group.attrs.update({"metrics": {k: float(v) for k, v in metrics.items()}, "result": result,
                            "final_done": True, "bmu_epoch": epochs, "engine": engine})


def run_attrs(group: zarr.Group, run: str) -> dict:
    """Every attribute of ``runs/<run>`` (StoreError when there is no such run)."""
    return dict(run_group(group, run, create=False).attrs)


# ----------------------------------------------------------------------------- domain maps

#: Sub-group of a run holding its domain map.
DOMAIN = "domain"


def write_domain(group: zarr.Group, run: str, arrays: dict, attrs: dict) -> zarr.Group:
    """Write the domain map of ``runs/<run>`` (each array one chunk) and its attributes.

    Parameters
    ----------
    arrays : dict
        ``weights`` (dr*dc, rows*cols) float32, ``units`` (n,) int64 and, unless tasks wrote
        them already (:func:`create_domain_vectors`), ``vectors`` (n, rows*cols) float32.
    attrs : dict
        ``rows``, ``cols``, ``sigma``, ``metrics``.
    """
    dtypes = {"weights": np.float32, "units": np.int64, "vectors": np.float32}
    g = run_group(group, run).require_group(DOMAIN)
    for name, data in arrays.items():
        data = np.asarray(data, dtypes.get(name))
        put_rows(g, name, data, max(len(data), 1) if data.ndim else 1)
    g.attrs.update(attrs)
    return g


def create_domain_vectors(group: zarr.Group, run: str, n: int, units: int, chunk_meshes: int) -> zarr.Array:
    """An empty ``runs/<run>/domain/vectors`` (n, units) float32, chunked by ``chunk_meshes`` meshes."""
    g = run_group(group, run).require_group(DOMAIN)
    return g.create_array("vectors", shape=(int(n), int(units)), dtype=np.float32,
                          chunks=(max(1, int(chunk_meshes)), int(units)), overwrite=True)


def domain_vectors_array(group: zarr.Group, run: str) -> zarr.Array:
    """``runs/<run>/domain/vectors`` (lazy; tasks write their meshes' rows)."""
    return run_group(group, run, create=False)[DOMAIN]["vectors"]


def read_domain(group: zarr.Group, run: str) -> dict | None:
    """The domain map of a run: ``units`` (n,) int64 and the attributes (rows, cols, sigma, metrics); None if absent."""
    runs = group.get("runs")
    if runs is None or run not in runs or DOMAIN not in runs[run]:
        return None
    g = runs[run][DOMAIN]
    return {**dict(g.attrs), "units": np.asarray(g["units"][:]) if "units" in g else None}


# ----------------------------------------------------------------------------- beside and around the store


def figures_dir(path: str | os.PathLike, create: bool = True) -> Path:
    """The local folder of a store's figures.

    ``STORE-figures`` beside a local ``STORE.zarr``; for a remote store (``s3://bucket/STORE.zarr``)
    ``STORE-figures`` in the working directory: figures are files for people and for MLflow
    artifacts, not part of the store.
    """
    loc = location(path)
    if is_remote(loc):
        name = loc.rsplit("/", 1)[-1]
        out = Path.cwd() / f"{name[:-len('.zarr')] if name.endswith('.zarr') else name}-figures"
    else:
        p = Path(loc)
        out = p.parent / f"{p.stem}-figures"
    if create:
        out.mkdir(parents=True, exist_ok=True)
    return out


def read_tracking(group: zarr.Group) -> dict:
    """The MLflow ids recorded in the root (``mlflow`` attribute; {} when none)."""
    return dict(group.attrs.get("mlflow", {}))


def write_tracking(group: zarr.Group, ids: dict) -> None:
    """Record MLflow ids (uri, experiment, name, parent, children) in the root."""
    group.attrs["mlflow"] = ids


# ----------------------------------------------------------------------------- staging

#: Group of the per-shard results while a corpus is ingested or encoded (removed at the end).
STAGING = "staging"


def staging_exists(path: str | os.PathLike) -> bool:
    """Whether a store has a ``staging`` group (work under way or interrupted)."""
    return store_exists(_join(path, STAGING))


def remove_staging(path: str | os.PathLike) -> None:
    """Delete the ``staging`` group of a store, if any."""
    remove_store(_join(path, STAGING))


def read_plan(group: zarr.Group) -> dict | None:
    """The shard plan kept in ``staging`` (None when there is none)."""
    return group[STAGING].attrs.get("plan") if STAGING in group else None


def write_plan(group: zarr.Group, plan: dict) -> None:
    """Keep a shard plan in ``staging`` (so that a resumed run cuts the same shards)."""
    group.require_group(STAGING).attrs["plan"] = plan


def write_shard(path: str | os.PathLike, name: str, arrays: dict, meta: dict, chunk_rows: int) -> None:
    """Write ``staging/<name>`` afresh: its arrays, then ``meta`` and the done mark (last).

    A half-written shard (killed before the mark) is never taken as finished.
    """
    g = _open_group(_join(path, STAGING, name), mode="w")
    for key, data in arrays.items():
        put_rows(g, key, data, chunk_rows)
    g.attrs.update({"meta": meta, "done": True})


def shard_meta(path: str | os.PathLike, name: str) -> dict | None:
    """The metadata of ``staging/<name>`` when it is marked done, else None."""
    try:
        g = _open_group(_join(path, STAGING, name), mode="r")
    except (FileNotFoundError, zarr.errors.GroupNotFoundError):
        return None
    return dict(g.attrs["meta"]) if g.attrs.get("done") else None


def shard_array(group: zarr.Group, shard: str, name: str) -> zarr.Array:
    """Array ``name`` of ``staging/<shard>``."""
    return group[f"{STAGING}/{shard}/{name}"]
