"""The zarr (v3) store layout: the one place that knows array names and attributes.

Layout (DESIGN.md §7; other tools read it, so it is a contract)::

    STORE.zarr/
      manifest.json          one record per input mesh: id, source, status
                             (accepted|rejected), reason, faces_in, faces_out,
                             label, lod, repairs, index (row in meshes/*)
      meshes/ids (n,) str    meshes/labels (n,) str ('' where unknown)
      meshes/vertex_offsets (n+1,) int64   meshes/face_offsets (n+1,) int64
      meshes/origins (n, 3) float64        world position of each mesh's local origin
      vertices (V, 3) float64  re-centred per mesh
      faces (F, 3) int64       indices into ``vertices`` (global rows)
      face_mesh (F,) int32     mesh index of every face
      rings/level{L} (F, 9*4^(L-1)) float32   raw folds, start leaf k = 0
      rings/stats              attributes: ``level{L}``, the scaling of that level
                               (meshsom.standardize.Stats.to_dict: scaling standard|
                               robust, mean (or median) and std (or IQR/1.349) per
                               component type alpha, u, v, clip); ``folds_level{L}``,
                               the fold statistics of that level
                               (meshsom.standardize.fold_statistics: quantiles of
                               alpha, u, v; entries within 1e-3 rad and 1 degree of
                               0/2 pi; entries with v > 100; max |u|)
      runs/<run>/...           codebooks, BMUs, variations, domain vectors

Root attributes: ``meshsom_layout`` (layout version), ``created_by``.
"""

from __future__ import annotations

import json
import os
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


def _path(path: str | os.PathLike) -> Path:
    return Path(path)


def create_store(path: str | os.PathLike, overwrite: bool = False) -> zarr.Group:
    """Create an empty store; refuse to overwrite an existing one unless asked.

    Raises
    ------
    StoreError
        When ``path`` exists and ``overwrite`` is false, or cannot be written.
    """
    p = _path(path)
    if p.exists() and not overwrite:
        raise StoreError(f"{p}: already exists; pass overwrite=True (--overwrite) to replace it")
    try:
        group = zarr.open_group(str(p), mode="w")
    except OSError as err:
        raise StoreError(f"{p}: cannot be created ({err.strerror or err})") from None
    group.attrs.update({"meshsom_layout": LAYOUT_VERSION, "created_by": "meshsom"})
    return group


def open_store(path: str | os.PathLike, mode: str = "r") -> zarr.Group:
    """Open an existing store.

    Raises
    ------
    StoreError
        When there is no meshsom store at ``path``.
    """
    p = _path(path)
    if not (p / "zarr.json").is_file():
        raise StoreError(f"{p}: no zarr store here (expected a folder made by `meshsom ingest`)")
    group = zarr.open_group(str(p), mode=mode)
    if group.attrs.get("meshsom_layout") != LAYOUT_VERSION:
        raise StoreError(
            f"{p}: store layout {group.attrs.get('meshsom_layout')!r}, expected {LAYOUT_VERSION} (made by another meshsom version?)"
        )
    return group


def store_path(group: zarr.Group) -> Path:
    """Folder of a local store group."""
    return Path(str(group.store.root)) if hasattr(group.store, "root") else Path(str(group.store))


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
    foff = np.concatenate([[0], np.cumsum(nf)]).astype(np.int64)
    vertices = np.concatenate([m.vertices for m in meshes]) if n else np.zeros((0, 3))
    faces = (
        np.concatenate([m.faces + voff[i] for i, m in enumerate(meshes)]) if n else np.zeros((0, 3), np.int64)
    )
    face_mesh = np.repeat(np.arange(n, dtype=np.int32), nf)
    origins = np.array([m.origin for m in meshes], np.float64).reshape(n, 3)
    ids = np.array([m.id for m in meshes], dtype=STRING)
    labels = np.array([m.label or "" for m in meshes], dtype=STRING)

    meshes_group = group.require_group("meshes")
    _put(meshes_group, "ids", ids, max(n, 1))
    _put(meshes_group, "labels", labels, max(n, 1))
    _put(meshes_group, "vertex_offsets", voff, max(n + 1, 1))
    _put(meshes_group, "face_offsets", foff, max(n + 1, 1))
    _put(meshes_group, "origins", origins, max(n, 1))
    _put(group, "vertices", vertices.astype(np.float64), chunk_rows)
    _put(group, "faces", faces.astype(np.int64), chunk_rows)
    _put(group, "face_mesh", face_mesh, chunk_rows)
    group.attrs.update({"n_meshes": int(n), "n_faces": int(foff[-1]), "n_vertices": int(voff[-1])})


def _put(group: zarr.Group, name: str, data: np.ndarray, chunk_rows: int) -> zarr.Array:
    chunks = (max(1, min(chunk_rows, max(len(data), 1))),) + tuple(data.shape[1:])
    arr = group.create_array(name, shape=data.shape, dtype=data.dtype, chunks=chunks, overwrite=True)
    if data.size:
        arr[...] = data
    return arr


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
    target = _path(path) / MANIFEST
    tmp = target.with_suffix(".json.tmp")
    with open(tmp, "w") as fh:
        json.dump(doc, fh, indent=1)
    os.replace(tmp, target)
    return doc


def read_manifest(path: str | os.PathLike) -> dict:
    """Read ``manifest.json`` of a store folder."""
    target = _path(path) / MANIFEST
    if not target.is_file():
        raise StoreError(f"{_path(path)}: has no {MANIFEST}")
    with open(target) as fh:
        return json.load(fh)


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
    rings = np.asarray(rings, np.float32)
    return _put(group.require_group("rings"), rings_name(level), rings, chunk_rows)


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
