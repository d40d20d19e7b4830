"""Building parts kept in files of their own: Overture Maps' ``building_part`` features.

Overture ships a city's buildings and their parts as two feature types (``overturemaps download
--type=building`` and ``--type=building_part``, GeoParquet or GeoJSON): a part names its building
by ``building_id``, the building's ``id``. Read as two inputs, each part would be a building of
its own beside its building's whole block. Among a run's inputs, :func:`pair` finds the files
whose features are parts (a ``building_id`` that is not the feature's own id) and the other
footprint files, and the reader (:attr:`meshsom.io.ReaderOptions.part_files`,
:attr:`~meshsom.io.ReaderOptions.building_files`) then reads them as one corpus:

- a building of a building file whose id a part names is read as its parts, as OpenStreetMap's
  building parts are (:func:`meshsom.osm.building_meshes`: BuildingParts of one Building, united
  in preprocessing; a part without a height takes its building's; a part that cannot be built is
  left out, noted);
- a part file yields only the parts whose building is in no building file, each a building of its
  own, noted: every part is read once, with its building or alone.

The parts and the building ids are read once per process (:func:`parts_index`,
:func:`building_ids`; a file's size and time of change in the key), so each read task of a large
building file (:func:`meshsom.gis.gis_ranges`) holds the parts, not the buildings. Parts are taken
to be in their building's CRS (Overture's: OGC:CRS84).
"""

from __future__ import annotations

import dataclasses
import functools
from pathlib import Path
from typing import Iterator, Sequence

#: The property by which a part names its building (Overture's ``building_part``).
BUILDING_ID = "building_id"
#: The property holding a building's own id where the feature has none (Overture's GeoParquet column).
OWN_ID = "id"
#: Rows (features) looked at to tell a part file from a building file.
SNIFF_FEATURES = 100
#: Bytes of a GeoJSON file looked through for :data:`BUILDING_ID` before it is parsed to be sure (a parts file names
#: it in its first feature; a run of thousands of GeoJSON tiles reads this much of each at planning).
SNIFF_BYTES = 1 << 16


def _kind(path: Path) -> str | None:
    """``"parquet"``, ``"gis"``, ``"inspire"`` (:mod:`meshsom.inspire`) or ``"geojson"`` for the footprint formats
    parts come in, else None."""
    from meshsom.gis import OGR_SUFFIXES, PARQUET_SUFFIXES
    from meshsom.io import format_name

    name = format_name(path)
    if name.endswith(PARQUET_SUFFIXES):
        return "parquet"
    if name.endswith(".gml"):
        from meshsom.inspire import is_inspire

        return "inspire" if is_inspire(path) else None
    if name.endswith(OGR_SUFFIXES):
        return "gis"
    if name.endswith((".geojson", ".json")) and not name.endswith(".city.json"):
        return "geojson"
    return None


def features(path: Path, options, limit: int | None = None) -> Iterator[tuple[str, dict, object]]:
    """(id, properties, geometry) of a footprint file's features in order, the id its ``id`` (a
    GeoJSON feature's, else the ``id`` property, else its number from 1), the geometry GeoJSON-like
    (a dict) or WKB bytes (GeoParquet); at most ``limit``."""
    import itertools

    path = Path(path)
    kind = _kind(path)
    if kind == "geojson":
        from meshsom.geojson import _feature_id, properties
        from meshsom.io import _parse_json, read_input_bytes

        document = _parse_json(read_input_bytes(path, options), str(path))
        found = [document] if isinstance(document, dict) and document.get("type") == "Feature" else (
            document.get("features") if isinstance(document, dict) else None)
        rows = ((_feature_id(f, k), properties(f), f.get("geometry")) for k, f in enumerate(found or [])
                if isinstance(f, dict))
    elif kind in ("parquet", "gis", "inspire"):
        from meshsom.gis import _chosen_layers, _records

        rows = ((str(props.get(OWN_ID, oid)) if props.get(OWN_ID) is not None else oid, props, geometry)
                for layer in _chosen_layers(path, options) for oid, props, geometry in _records(path, layer.name, None, 0, None))
    else:
        return
    yield from itertools.islice(rows, limit)


def holds_parts(path: Path, options) -> bool:
    """Whether a file's features are building parts: one names a building (:data:`BUILDING_ID`)
    other than itself, among all of a GeoParquet file's (two columns read), among the first
    :data:`SNIFF_FEATURES` of other files (a GeoJSON file only where its first :data:`SNIFF_BYTES`
    mention it). Files that cannot be read are not (their reader says why)."""
    if _kind(Path(path)) == "geojson" and not _mentions(Path(path), BUILDING_ID):
        return False  # not parsed whole at planning: most GeoJSON inputs hold no parts
    if _kind(Path(path)) == "inspire":
        from meshsom.inspire import holds_parts as inspire_parts

        return inspire_parts(Path(path))
    if _kind(Path(path)) == "parquet":  # two columns, read whole: parts after the buildings of one file are found
        try:
            import pyarrow.parquet as pq

            names = pq.ParquetFile(path).schema_arrow.names
            if BUILDING_ID not in names:
                return False
            table = pq.read_table(path, columns=[c for c in (OWN_ID, BUILDING_ID) if c in names])
            named = table.column(BUILDING_ID).to_pylist()
            own = table.column(OWN_ID).to_pylist() if OWN_ID in table.column_names else [None] * len(named)
            return any(n is not None and str(n) != str(o) for n, o in zip(named, own))
        except Exception:  # unreadable: read as any other input, which says why
            return False
    try:
        for oid, props, _ in features(path, options, SNIFF_FEATURES):
            named = props.get(BUILDING_ID)
            if named is not None and str(named) != str(props.get(OWN_ID, oid)):
                return True
    except Exception:  # unreadable: read as any other input, which says why
        return False
    return False


def _mentions(path: Path, key: str) -> bool:
    """Whether the first :data:`SNIFF_BYTES` of a (gzipped) text file hold ``"key"``."""
    import gzip

    try:
        with open(path, "rb") as fh:
            head = fh.read(2)
        with (gzip.open if head == b"\x1f\x8b" else open)(path, "rb") as fh:
            return f'"{key}"'.encode() in fh.read(SNIFF_BYTES)
    except (OSError, EOFError):
        return False


def pair(paths: Sequence[Path], options):
    """``options`` with :attr:`~meshsom.io.ReaderOptions.part_files` and
    :attr:`~meshsom.io.ReaderOptions.building_files` set from a run's input files: the files that
    hold parts, and every footprint file (GeoParquet, GIS, GeoJSON; a file may hold buildings and
    parts both); unchanged where none holds parts or the options name part files already."""
    if options.part_files:
        return options
    footprints = [Path(p) for p in paths if _kind(Path(p)) is not None]
    parts = [p for p in footprints if holds_parts(p, options)]
    if not parts:
        return options
    return dataclasses.replace(options, part_files=tuple(str(p) for p in parts),
                               building_files=tuple(str(p) for p in footprints))


def _stamp(paths: Sequence[str]) -> tuple:
    """The files with their size and time of change: the cache key of what is read from them."""
    out = []
    for p in paths:
        try:
            st = Path(p).stat()
            out.append((str(p), st.st_size, st.st_mtime_ns))
        except OSError:
            out.append((str(p), -1, -1))
    return tuple(out)


def parts_index(options) -> dict[str, list]:
    """The parts of :attr:`~meshsom.io.ReaderOptions.part_files` by the id of the building they
    name: lists of :class:`meshsom.osm._Area` (id, properties, GeoJSON-like geometry)."""
    return _parts_index(_stamp(options.part_files), _reading(options))


def building_ids(options) -> frozenset[str]:
    """The ids of the buildings of :attr:`~meshsom.io.ReaderOptions.building_files`."""
    return _building_ids(_stamp(options.building_files), _reading(options))


def inspire_buildings(options) -> frozenset[str]:
    """The ids of the buildings INSPIRE's building parts among :attr:`~meshsom.io.ReaderOptions.part_files` name
    (:func:`meshsom.inspire.part_building`): read from their parts."""
    return _inspire_buildings(_stamp(options.part_files), _reading(options))


@functools.lru_cache(maxsize=4)
def _inspire_buildings(stamped: tuple, options) -> frozenset[str]:
    from meshsom.gis import _attributes, _ogr_layers
    from meshsom.inspire import part_building

    ids = set()
    for path, _, _ in stamped:
        if _kind(Path(path)) == "inspire":
            ids.update(b for layer in _ogr_layers(Path(path)) for props in _attributes(Path(path), layer.name)
                       if (b := part_building(props.get("gml_id") or "")) is not None)
    return frozenset(ids)


def _reading(options):
    """The options that decide how the files are read (not the pairing): the cache's key."""
    return dataclasses.replace(options, part_files=(), building_files=())


@functools.lru_cache(maxsize=4)
def _parts_index(stamped: tuple, options) -> dict[str, list]:
    from meshsom.osm import _Area

    index: dict[str, list] = {}
    for path, _, _ in stamped:
        for oid, props, geometry in features(Path(path), options):
            named = props.get(BUILDING_ID)
            if named is not None and geometry is not None:
                index.setdefault(str(named), []).append(_Area(oid, props, as_geojson(geometry, f"{Path(path).name}#{oid}")))
    return index


@functools.lru_cache(maxsize=4)
def _building_ids(stamped: tuple, options) -> frozenset[str]:
    ids = set()
    for path, _, _ in stamped:
        kind = _kind(Path(path))
        if kind == "parquet":  # the id column alone
            import pyarrow.parquet as pq

            names = pq.ParquetFile(path).schema_arrow.names
            if OWN_ID in names:
                ids.update(str(v) for v in pq.read_table(path, columns=[OWN_ID]).column(OWN_ID).to_pylist() if v is not None)
                continue
        try:
            ids.update(oid for oid, _, _ in features(Path(path), options))
        except Exception:  # unreadable: its reader says why; its buildings are none
            continue
    return frozenset(ids)


def as_geojson(geometry, where: str) -> dict:
    """A geometry as :func:`meshsom.gis.fiona_polygons` reads it: GeoJSON-like as it is, WKB
    (GeoParquet) as a MultiPolygon of its polygons."""
    if isinstance(geometry, (bytes, bytearray, memoryview)):
        from meshsom.gis import wkb_polygons

        polygons, _, _ = wkb_polygons(geometry, where)
        return {"type": "MultiPolygon", "coordinates": [[ring.tolist() for ring in poly] for poly in polygons]}
    return geometry


def is_part_file(path, options) -> bool:
    """Whether ``path`` is one of :attr:`~meshsom.io.ReaderOptions.part_files`."""
    return bool(options.part_files) and Path(path).resolve() in {Path(p).resolve() for p in options.part_files}


class Placement:
    """Where the footprint features of one file go when parts come in files of their own: made once per read of
    the file (the files' sizes and times of change looked at once, the parts and building ids read once per
    process), asked per feature (:meth:`of`)."""

    def __init__(self, path, options):
        self.options = options
        self.is_part_file = is_part_file(path, options)
        self._parts: dict | None = None
        self._ids: frozenset | None = None
        self._inspire: frozenset | None = None

    def of(self, props: dict, oid: str) -> tuple[bool, list, str | None]:
        """Where one feature goes.

        Returns
        -------
        skip : bool
            A part whose building is in a building file: read with it, not here; an INSPIRE building whose parts
            are in a part file: read from them.
        parts : list of meshsom.osm._Area
            A building's parts (its ``id`` property, else ``oid``, named by them).
        alone : str or None
            A part of no building: the note that says it is read as a building of its own.
        """
        if not self.is_part_file and "gml_id" in props:  # INSPIRE: a building whose parts are an input's
            if self._inspire is None:
                self._inspire = inspire_buildings(self.options)
            if str(props["gml_id"]) in self._inspire:
                return True, [], None
        named = props.get(BUILDING_ID)
        if named is None and self.is_part_file and "gml_id" in props:
            return False, [], None  # INSPIRE's parts: grouped by their file's reader (meshsom.gis.part_grouping)
        if named is not None and self.is_part_file and str(named) != str(props.get(OWN_ID, oid)):
            if self._ids is None:
                self._ids = building_ids(self.options)
            if str(named) in self._ids:
                return True, [], None
            return False, [], ALONE.format(named)
        if self._parts is None:  # a building (of a building file, or among the parts of a file of both)
            self._parts = parts_index(self.options)
        own = props.get(OWN_ID)
        return False, self._parts.get(str(own) if own is not None else oid, self._parts.get(oid, [])), None


#: The note on a part read alone (its building's id after "; ": ingest counts the notes by what precedes it).
ALONE = "an Overture building_part whose building is in no input, read as a building of its own; building_id {}"
