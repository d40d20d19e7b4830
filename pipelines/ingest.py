"""``meshsom ingest``: read, preprocess and store a corpus, accounting for every input.

Every mesh the readers are asked for ends up in the manifest, either accepted
(and stored) or rejected with its reason: accepted + rejected = inputs. The work is done by the
corpus driver of ``meshsom run`` (:func:`pipelines.corpus.run_corpus`, without encoding) on an
in-process Dask client.
"""

from __future__ import annotations

import argparse
import logging
import os
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Iterable, Iterator

import numpy as np

from meshsom.errors import ConfigError, MeshError, StoreError
from meshsom.io import HEIGHT_UNITS, MESH_UNITS

log = logging.getLogger(__name__)


#: What to try for the commonest rejections, by how their reason starts (:func:`rejection_kinds`).
REJECTION_HINTS = (
    ("open boundary", "--repair fills holes with pymeshlab; --extrude-lod1 makes closed blocks of footprints"),
    ("non-manifold", "--repair (pymeshlab's non-manifold repair)"),
    ("holds no Building", "files of other city objects (terrain, roads, furniture): nothing to ingest; a type "
                          "that is a building here (GenericCityObject, say) is read with corpus.reader.object_types"),
    ("has no geometry at LoD", "--lod highest, or one of the LoDs the building has"),
    ("has no surface or solid geometry", "--lod: the building may have volumes at another LoD"),
    ("its coordinates look like degrees", "--crs with the data's CRS (EPSG:4979 for WGS 84 latitude, longitude, height)"),
)
#: Rejection kinds printed by ``meshsom ingest`` (the most frequent first), and single rejections after them.
KINDS_SHOWN = 8
REJECTIONS_SHOWN = 5


def rejection_kinds(records: Iterable[dict]) -> list[tuple[str, int, str | None]]:
    """The rejected records grouped by the kind of their reason, the most frequent first.

    A reason's kind is its first clause with its numbers written ``N`` (and a CityJSONSeq line
    number and the object types a file holds instead of buildings dropped), so "open boundary: 17
    edges ..." and "open boundary: 23 edges ..." are one.

    Returns
    -------
    list of (kind, count, hint)
        ``hint``: what to try (:data:`REJECTION_HINTS`), or None.
    """
    import re
    from collections import Counter

    kinds = Counter()
    for r in records:
        if r.get("status") == "rejected":
            first = re.sub(r"^line \d+: ", "", str(r.get("reason") or "no reason given"))
            first = re.sub(r" \(found [^)]*\)$", "", first.split("; ")[0])  # the object types a file holds instead
            kinds[_kind(first, _NUMBER)] += 1
    return [(kind, n, next((h for start, h in REJECTION_HINTS if kind.startswith(start)), None))
            for kind, n in kinds.most_common()]


#: A number of a reason or note, written ``N`` in its kind (not digits of a word: "i3dm", "3D").
_NUMBER = r"(?<![A-Za-z])\d[\d,.]*(?![A-Za-z\d])"
#: The same, but a group in parentheses (a CRS's name: "WGS 84", "JGD2011") kept whole.
_NUMBER_OUTSIDE_GROUPS = r"\([^()]*(?:\([^()]*\)[^()]*)*\)|\b\d[\d,.]*"


def _kind(text: str, pattern: str) -> str:
    """``text`` with what ``pattern`` matches written ``N`` (groups in parentheses it matches kept)."""
    import re

    return re.sub(pattern, lambda m: m.group(0) if m.group(0).startswith("(") else "N", text).strip()


def note_kinds(records: Iterable[dict]) -> list[tuple[str, int]]:
    """The reader's notes of the records (coordinates converted, heights from storeys, polygons
    dropped...) grouped as :func:`rejection_kinds` groups reasons, the most frequent first."""
    from collections import Counter

    return Counter(_kind(str(n).split("; ")[0], _NUMBER_OUTSIDE_GROUPS)
                   for r in records for n in r.get("notes") or ()).most_common()


@dataclass(frozen=True)
class IngestResult:
    """What an ingestion did.

    Attributes
    ----------
    store : str
    records : list of dict
        The manifest records, one per input mesh.
    summary : dict
        Counts (inputs, accepted, rejected, ...).
    """

    store: str
    records: list
    summary: dict

    @property
    def accepted(self) -> int:
        return self.summary["accepted"]

    @property
    def rejected(self) -> int:
        return self.summary["rejected"]


def iter_raw_meshes(paths: Iterable[str], reader, generator=None) -> Iterator:
    """Every RawMesh or Rejection of the inputs, files first, then the generator's blocks."""
    from meshsom.io import expand_inputs, read_file
    from pipelines.corpus import generate_items

    files, missing = expand_inputs(list(paths))
    yield from missing
    for f in files:
        yield from read_file(f.path, reader, f.name)
    if generator is not None:
        yield from generate_items(generator, 0, generator.n_blocks)


def process_one(raw, params) -> tuple[dict, object | None]:
    """Preprocess one read mesh into a manifest record and, when accepted, a CleanMesh
    (:func:`_process_one`), within ``params.max_seconds`` (:mod:`meshsom.time_limit`): a mesh that
    takes longer is rejected, and its reason names the limit and the stage it stopped in; one that
    runs out of memory, or on which a library fails (GEOS's TopologyException), is rejected too, and
    its shard goes on.
    """
    from meshsom.time_limit import TimeLimitExceeded, time_limit

    try:
        with time_limit(getattr(params, "max_seconds", 0)):
            return _process_one(raw, params)
    except TimeLimitExceeded as err:
        reason = f"preprocessing {err} (preprocess.max_seconds; raise it, or 0 for no limit)"
    except MemoryError as err:  # one mesh too large for this worker: its rejection, not the end of its shard
        reason = (f"preprocessing ran out of memory ({err or 'MemoryError'}) on its {len(raw.faces):,} triangles; "
                  f"give the workers more memory, or split the mesh")
    except Exception as err:  # a library's error on one mesh (GEOS's TopologyException): its rejection, not its shard's
        reason = (f"preprocessing failed on it ({type(err).__name__}: {str(err).splitlines()[0][:300] if str(err) else ''}): "
                  f"an error of meshsom or a library it uses on this mesh; please report it with the file")
    record = {"id": raw.id, "source": raw.source, "status": "rejected", "reason": reason,
              "faces_in": int(len(raw.faces)), "faces_out": 0, "label": raw.label, "lod": raw.lod, "repairs": []}
    if raw.notes:
        record["notes"] = list(raw.notes)
    return record, None


def _process_one(raw, params) -> tuple[dict, object | None]:
    """Preprocess one read mesh into a manifest record and, when accepted, a CleanMesh.

    A mesh of several CityJSON objects (a Building and its parts) is first united into its outer
    surface (:func:`meshsom.union.unite`) and each shell of the union preprocessed; the
    record's ``union`` says what the union did (parts, shells before and after, area removed) or
    why it failed, in which case the parts' triangles are preprocessed together as they are (faces
    shared by two parts go as internal walls). A mesh that still cannot be closed is rebuilt as the
    solid under its roofs (:func:`meshsom.envelope.rebuild_under_roofs`, unless the preprocess
    parameters' ``roof_envelope`` is off); the record's ``envelope`` says so, from what, and
    ``because`` of what. The reader's ``notes`` are recorded, and a mesh rejected as open says so
    when the reader dropped polygons of it.
    """
    from meshsom.io import Rejection
    from meshsom.preprocess import preprocess
    from meshsom.store import CleanMesh
    from meshsom.envelope import rebuild_under_roofs
    from meshsom.union import unite

    if isinstance(raw, Rejection):
        return {
            "id": raw.id, "source": raw.source, "status": "rejected", "reason": raw.reason,
            "faces_in": raw.faces_in, "faces_out": 0, "label": raw.label, "lod": None, "repairs": [],
        }, None
    record = {"id": raw.id, "source": raw.source, "faces_in": int(len(raw.faces)), "label": raw.label, "lod": raw.lod}
    if raw.notes:
        record["notes"] = list(raw.notes)
    result = None
    union_repairs: list[str] = []
    if raw.face_part is not None and len(raw.parts) > 1:
        try:
            united, result = unite(raw.vertices, raw.faces, raw.face_part, params, raw.id, raw.parts)
        except MeshError as err:
            record["union"] = {"status": "failed", "parts": len(raw.parts), "reason": err.problem}
        else:
            record["union"] = united.record()
            union_repairs = united.repairs + [
                f"united {united.parts} parts ({united.shells_before} shells) into {united.shells_after} "
                f"shell(s), removing {united.area_removed:.6g} of {united.area_in:.6g} square units of surface"
            ]
    try:
        if result is None:
            result = preprocess(raw.vertices, raw.faces, params, source=raw.id)
    except MeshError as err:
        reason = err.problem
        dropped = [n for n in raw.notes if "dropped" in n]
        if reason.startswith("open boundary") and dropped:
            reason = f"{reason}; {'; '.join(dropped)}"
        if record.get("union", {}).get("status") == "failed":
            reason = f"{reason}; the union of its parts failed too ({record['union']['reason']})"
        if params.roof_envelope and _readable(raw):
            try:
                envelope, result = rebuild_under_roofs(raw.vertices, raw.faces, params, raw.id)
            except MeshError as again:
                reason = f"{reason}; rebuilding it as the solid under its roofs failed too ({again.problem})"
            else:
                record["envelope"] = {**envelope.record(), "because": reason}
                union_repairs = [f"{envelope.describe()}, because it could not be closed as it is ({reason})"]
        if result is None:
            record.update(status="rejected", reason=reason, faces_out=0, repairs=[])
            return record, None
    record.update(
        status="accepted", reason="", faces_out=int(len(result.faces)), repairs=union_repairs + list(result.repairs),
        volume=float(result.volume_out),
    )
    return record, CleanMesh(raw.id, result.vertices, result.faces, raw.origin, raw.label)


def rebuilt_under_roofs(records: Iterable[dict]) -> int:
    """How many accepted records were rebuilt as the solid under their roofs (their ``envelope``)."""
    return sum(1 for r in records if r.get("status") == "accepted" and "envelope" in r)


def _readable(raw) -> bool:
    """Whether a mesh's arrays pass :func:`meshsom.preprocess.check_input` (else its rejection says why)."""
    from meshsom.preprocess import check_input

    try:
        check_input(raw.vertices, raw.faces, raw.id)
    except MeshError:
        return False
    return True


def check_unique_id(seen: dict, mesh_id: str, source: str) -> None:
    """Refuse a mesh whose id an earlier mesh has.

    Parameters
    ----------
    seen : dict
        Id -> source of the meshes so far; this one is added.
    mesh_id, source : str
        The mesh's id and the file it comes from.

    Raises
    ------
    InputFileError
        Naming both sources.
    """
    from meshsom.errors import InputFileError

    if mesh_id in seen:
        raise InputFileError(source, f"mesh id {mesh_id!r} is also the id of a mesh from {seen[mesh_id]}; ids must be unique")
    seen[mesh_id] = source


#: Rough size of one input triangle in a mesh or CityJSON file, for the disk-space estimate.
BYTES_PER_INPUT_TRIANGLE = 40
#: Triangles per synthetic block, for the disk-space estimate.
TRIANGLES_PER_BLOCK = 60
#: Stored bytes per triangle besides its rings: faces (3 x int64), face_mesh, ~1.5 vertices (3 x float64).
BYTES_PER_TRIANGLE = 3 * 8 + 4 + 36


def estimate_store_bytes(paths: Iterable[str], generator=None, levels: Iterable[int] = ()) -> int:
    """Upper-end estimate of a store's size from its inputs (file sizes, generated blocks, ring levels); an input on
    object storage by its listing (:func:`meshsom.mirror.remote_files`; one that cannot be listed counts nothing here,
    and is a rejection of the run)."""
    from meshsom.errors import InputFileError
    from meshsom.mirror import is_url, remote_files
    from meshsom.rings import dims

    size = 0
    for p in paths:
        if is_url(p):
            try:
                size += sum(c.size for c in remote_files(str(p))[1])
            except InputFileError:
                pass
            continue
        p = Path(p)
        if p.is_file():
            size += p.stat().st_size
        elif p.is_dir():
            size += sum(f.stat().st_size for f in p.rglob("*") if f.is_file())
    triangles = size // BYTES_PER_INPUT_TRIANGLE + (generator.n_blocks * TRIANGLES_PER_BLOCK if generator else 0)
    return int(triangles * (BYTES_PER_TRIANGLE + 4 * sum(dims(level) for level in levels)))


def check_writable(path: str | os.PathLike, overwrite: bool, needed_bytes: int = 0) -> None:
    """Fail before any work when the store cannot be written (exists, read-only, or too little space).

    ``path`` is a local folder or a remote URL (:func:`meshsom.store.probe_writable` says how each
    is probed; free space is checked locally only).
    """
    from meshsom.store import location, probe_writable, store_exists

    if store_exists(path) and not overwrite:
        raise StoreError(f"{location(path)}: already exists; pass --overwrite to replace it")
    probe_writable(path, needed_bytes)


def ingest(
    paths: Iterable[str],
    out: str | os.PathLike,
    reader=None,
    params=None,
    generator=None,
    overwrite: bool = False,
    chunk_rows: int | None = None,
    progress: bool | None = None,
) -> IngestResult:
    """Ingest a corpus into a new store, with the corpus driver of ``meshsom run`` on an in-process client.

    Parameters
    ----------
    paths : iterable of str
        Files and folders.
    out : path
        The zarr store to create.
    reader : ReaderOptions, optional
    params : PreprocessParams, optional
    generator : GeneratorParams, optional
        Synthetic blocks added after the files.
    overwrite : bool
    chunk_rows : int, optional
    progress : bool or None
        Show progress bars (None: only on a terminal).
    """
    from meshsom.config import CorpusConfig, StoreConfig
    from pipelines.settings import RunConfig
    from meshsom.io import ReaderOptions
    from meshsom.preprocess import PreprocessParams
    from meshsom.store import DEFAULT_CHUNK_ROWS, mesh_table, open_store, read_manifest, read_meshes
    from pipelines.cluster import connect_serial
    from pipelines.corpus import run_corpus

    from meshsom.store import location

    out = location(out)
    check_writable(out, overwrite)
    cfg = RunConfig(
        corpus=CorpusConfig(tuple(str(p) for p in paths), generator, reader or ReaderOptions()),
        preprocess=params or PreprocessParams(),
        store=StoreConfig(path=str(out), chunk_rows=chunk_rows or DEFAULT_CHUNK_ROWS),
    )
    report, close = progress_bars(progress)
    try:
        with connect_serial() as client:
            summary = run_corpus(client, cfg, out, progress=report, levels=())
    finally:
        close()
    group = open_store(out)
    meshes = read_meshes(group, 0, len(mesh_table(group)))
    # Printed, not stored: the store's fold statistics are written by `meshsom encode` (rings/stats).
    return IngestResult(str(out), read_manifest(out)["records"], {**summary, "folds": corpus_fold_statistics(meshes)})


def progress_bars(enabled: bool | None) -> tuple:
    """A ``progress(stage, done, total)`` callback drawing one bar per stage, and the function that closes them.

    Parameters
    ----------
    enabled : bool or None
        None: only on a terminal.
    """
    from tqdm import tqdm

    bars: dict = {}

    def report(stage: str, done: int, total: int) -> None:
        bar = bars.get(stage)
        if bar is None:
            bar = bars[stage] = tqdm(total=total, desc=stage, unit="task", disable=None if enabled is None else not enabled)
        bar.update(done - bar.n)

    def close() -> None:
        for bar in bars.values():
            bar.close()

    return report, close


def corpus_fold_statistics(meshes) -> dict | None:
    """Fold statistics (:func:`meshsom.standardize.fold_statistics`) of the cleaned meshes, None if there are none.

    Parameters
    ----------
    meshes : list of (id, vertices (V, 3) float64, faces (F, 3) int64)
    """
    from meshsom.folds import folds
    from meshsom.standardize import fold_statistics
    from meshsom.topology import adjacency

    if not meshes:
        return None
    parts = [folds(v, f, adjacency(f, source=mesh_id)).reshape(-1, 3) for mesh_id, v, f in meshes]
    return fold_statistics(np.concatenate(parts), level=1)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("inputs", nargs="*", metavar="INPUT",
                   help="CityJSON(Seq), CityGML, GeoJSON, GIS (GeoPackage, Shapefile, FileGDB, GeoParquet, ...), "
                        "OpenStreetMap (.osm, .osm.pbf), 3D Tiles, scene layer packages, IFC, Rhino (.3dm), DXF, FBX, "
                        "3DS, mesh or zip files, or folders of them; or URLs of them (s3://bucket/city/, a glob)")
    p.add_argument("--out", required=True, help="zarr store to create (e.g. out/city.zarr)")
    p.add_argument("--config", help="experiment YAML: its corpus.reader and preprocess sections are used")
    p.add_argument("--lod", help="CityJSON LoD: highest, lowest or a value such as 2.2")
    p.add_argument("--parts", choices=("merge", "separate"), help="BuildingParts merged into their Building, or kept apart")
    p.add_argument("--extrude-lod1", action="store_true", default=None, help="replace each building by its extruded footprint (LoD1 block)")
    p.add_argument("--crs", help="CRS of inputs that declare none, e.g. EPSG:4979 (degrees are converted to metres)")
    p.add_argument("--up", choices=("auto", "z", "y"),
                   help="up axis of mesh files (many OBJ exports: y); default auto: glTF y, as its specification says "
                        "(z where trimesh wrote it), other mesh files z")
    p.add_argument("--unit", choices=tuple(MESH_UNITS),
                   help="unit of mesh files that name none (OBJ, PLY, STL, OFF, glTF, COLLADA without <unit>): CAD "
                        "exports are often mm; default m")
    p.add_argument("--layer", help="GIS files (GeoPackage, FileGDB, ...): the layer to read; default every layer")
    p.add_argument("--split-components", action="store_true", default=None,
                   help="mesh files, Rhino objects, DXF meshes: each connected piece is a building (a city exported as "
                        "one STL, PLY or mesh object)")
    p.add_argument("--height-attribute", action="append", metavar="NAME",
                   help="footprints: a property holding the building's height above the ground, tried before the "
                        "defaults (height, measuredHeight, building:height); may be given more than once")
    p.add_argument("--levels-attribute", action="append", metavar="NAME",
                   help="footprints: a property holding the building's count of storeys above the ground, tried "
                        "before the defaults (building:levels, num_floors, ...); times corpus.reader.storey_height; "
                        "may be given more than once")
    p.add_argument("--height-unit", choices=tuple(HEIGHT_UNITS),
                   help="footprints: the unit of their height properties (New York's footprints as GeoJSON: ft); "
                        "default the CRS's vertical unit, metres for degrees")
    p.add_argument("--default-height", type=float, metavar="M",
                   help="footprints with neither a height nor a storey count (most of OpenStreetMap): extruded to M "
                        "metres, noted; default: listed as rejections")
    p.add_argument("--flat-roofs", action="store_true", default=None,
                   help="footprints: extrude every one flat, whatever its roof attributes (roof:shape, roof_shape) say")
    p.add_argument("--repair", action="store_true", default=None, help="try a pymeshlab repair before rejecting a mesh")
    p.add_argument("--generate", type=int, metavar="N", help="add N synthetic blocks (seed from --seed)")
    p.add_argument("--seed", type=int, default=0, help="seed of --generate (default %(default)s)")
    p.add_argument("--overwrite", action="store_true", help="replace an existing store")
    p.add_argument("--chunk-rows", type=int, help="rows per chunk of the per-face arrays")
    p.add_argument("--json", action="store_true", help="print the summary as JSON")


#: Skipped files listed on the terminal before the rest are counted.
SKIPPED_SHOWN = 10


def print_skipped(skipped: list[tuple[str, str]], indent: str = "      ") -> None:
    """The files in input folders that are not read (:func:`meshsom.io.expand_inputs`): a few by
    name, the rest counted by type, and the readable types once."""
    from collections import Counter

    for path, why in skipped[:SKIPPED_SHOWN]:
        print(f"{indent}skipped: {Path(path).name} ({why.split(';')[0]})")  # the list of types once, below
    if len(skipped) > SKIPPED_SHOWN:
        kinds = Counter(Path(path).suffix or "(no extension)" for path, _ in skipped[SKIPPED_SHOWN:])
        print(f"{indent}skipped: {len(skipped) - SKIPPED_SHOWN} more files "
              f"({', '.join(f'{n} x {suffix}' for suffix, n in kinds.most_common())})")
    if any(why.startswith("unknown file type") for _, why in skipped):
        import textwrap

        from meshsom.io import readable_types

        print(textwrap.fill(f"(readable: {readable_types()})", width=80, initial_indent=indent,
                            subsequent_indent=indent + " "))


def run(args: argparse.Namespace) -> int:
    import json

    from pipelines.settings import RunConfig
    from meshsom.generate import GeneratorParams
    from meshsom.io import ReaderOptions
    from pipelines.settings import load_config, resolve_paths

    if args.config:
        cfg = resolve_paths(load_config(args.config), Path(args.config).parent)
        reader, params, chunk_rows = cfg.corpus.reader, cfg.preprocess, cfg.store.chunk_rows
        paths = list(args.inputs) or list(cfg.corpus.paths)
        generator = cfg.corpus.generator if not args.inputs else None
    else:
        cfg = RunConfig(corpus=_placeholder_corpus())
        reader, params, chunk_rows = ReaderOptions(), cfg.preprocess, cfg.store.chunk_rows
        paths, generator = list(args.inputs), None
    try:
        given = (("lod", args.lod), ("parts", args.parts), ("extrude_lod1", args.extrude_lod1), ("crs", args.crs),
                 ("up_axis", args.up), ("unit", args.unit), ("layer", args.layer), ("split_components", args.split_components),
                 ("default_height", args.default_height), ("roofs", False if args.flat_roofs else None),
                 ("height_unit", args.height_unit))
        changes = {k: v for k, v in given if v is not None}
        for given_names, field in ((args.height_attribute, "height_attributes"), (args.levels_attribute, "levels_attributes")):
            if given_names:
                changes[field] = tuple(given_names) + tuple(a for a in getattr(reader, field) if a not in given_names)
        reader = replace(reader, **changes)
        if args.repair:
            params = replace(params, repair=True)
        if args.generate:
            generator = GeneratorParams(n_blocks=args.generate, seed=args.seed)
    except ValueError as err:
        raise ConfigError(f"meshsom ingest: {err}") from None
    if not paths and generator is None:
        raise ConfigError("meshsom ingest: no inputs; give files or folders, --generate N, or --config with corpus.paths")
    from meshsom.io import expand_inputs

    skipped: list[tuple[str, str]] = []
    expand_inputs(list(paths), skipped)  # the files of input folders that are not read, said below
    result = ingest(paths, args.out, reader, params, generator, args.overwrite, args.chunk_rows or chunk_rows)
    s = result.summary
    if args.json:
        print(json.dumps({k: s[k] for k in ("inputs", "accepted", "rejected", "faces_in", "faces_out")} | {"store": result.store}))
    else:
        print(f"{s['inputs']} meshes: {s['accepted']} accepted, {s['rejected']} rejected; "
              f"{s['faces_in']} triangles in, {s['faces_out']} out -> {result.store}")
        if s.get("folds"):
            from meshsom.standardize import describe_fold_statistics, scale_hint

            print(f"  {describe_fold_statistics(s['folds'])}")
            hint = scale_hint(s["folds"])
            if hint:
                print(f"  {hint}")
        if skipped:
            print_skipped(skipped, "  ")
        rebuilt = rebuilt_under_roofs(result.records)
        if rebuilt:
            print(f"  {rebuilt} rebuilt as the solid under their roofs, not closed as they are (each record's "
                  f"envelope says why; preprocess.roof_envelope: false rejects them instead)")
        noted = note_kinds(result.records)
        if noted:
            print("  read with notes (each record's own in its notes):")
            for kind, n in noted[:KINDS_SHOWN]:
                print(f"    {n:6,d} x {kind}")
        rejected = [r for r in result.records if r["status"] == "rejected"]
        if rejected:
            print(f"  rejected, by kind of reason (each record, with its whole reason, in {result.store}/manifest.json):")
            kinds = rejection_kinds(rejected)
            for kind, n, hint in kinds[:KINDS_SHOWN]:
                print(f"    {n:6,d} x {kind}")
                if hint:
                    print(f"             hint: {hint}")
            if len(kinds) > KINDS_SHOWN:
                print(f"    ({len(kinds) - KINDS_SHOWN} more kinds)")
        for r in rejected[:REJECTIONS_SHOWN]:
            print(f"  rejected {r['id']}: {r['reason']}")
        if len(rejected) > REJECTIONS_SHOWN:
            print(f"  ... {len(rejected) - REJECTIONS_SHOWN} more")
    return 0 if s["accepted"] > 0 else 1


def _placeholder_corpus():
    from meshsom.config import CorpusConfig

    return CorpusConfig(paths=("(command line)",))
