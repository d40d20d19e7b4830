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
  in preprocessing; a part with neither a height nor storeys takes its building's; a part that cannot be built is
  left out, noted);
- a part file yields only the parts whose building is in no building file, each a building of its
  own, noted: every part is read once, with its building or alone.

OpenStreetMap's building parts saved as a file of their own (an Overpass query for ``building:part``
beside one for ``building``, each saved by QuickOSM or Overpass turbo; a GDAL conversion's areas
split by tag) are found the same way (:func:`holds_osm_parts`: every feature looked at is tagged
``building:part`` and not ``building``), and grouped as OpenStreetMap's parts are within one file
(:func:`osm_parts`): each part goes to the smallest building outline of the building files that
holds a point inside it, its geometry in that file's CRS; a part inside no outline is a building of
its own, noted (:data:`meshsom.osm.STRAY`).

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

import numpy as np

#: The property by which a part names its building (Overture's ``building_part``).
BUILDING_ID = "building_id"
#: The property holding a building's own id where the feature has none (Overture's GeoParquet column).
OWN_ID = "id"
#: OpenStreetMap's key of a building part (files of parts alone: :func:`holds_osm_parts`).
OSM_PART = "building:part"
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
    """Whether a file's features are building parts: Overture's (:func:`holds_overture_parts`), or
    OpenStreetMap's in a file of their own (:func:`holds_osm_parts`)."""
    return holds_overture_parts(path, options) or holds_osm_parts(path, options)


def holds_osm_parts(path: Path, options) -> bool:
    """Whether a footprint file is OpenStreetMap's building parts alone: each of its first :data:`SNIFF_FEATURES`
    features with a geometry tagged ``building:part`` and not ``building`` (a GeoJSON file only where its first
    :data:`SNIFF_BYTES` mention it). A file of buildings and parts both groups its own (:mod:`meshsom.gis`,
    :mod:`meshsom.geojson`). Files that cannot be read are not (their reader says why)."""
    from meshsom.geojson import _is_part_feature

    path = Path(path)
    kind = _kind(path)
    if kind not in ("geojson", "gis", "parquet") or kind == "geojson" and not _mentions(path, OSM_PART):
        return False
    found = False
    try:
        if kind == "geojson":
            rows = (props for _, props, geometry in features(path, options, SNIFF_FEATURES) if geometry is not None)
        else:  # the attributes alone
            import itertools

            from meshsom.gis import _attributes, _chosen_layers

            rows = itertools.islice((props for layer in _chosen_layers(path, options)
                                     for props in _attributes(path, layer.name)), SNIFF_FEATURES)
        for props in rows:
            if not _is_part_feature(props):
                return False
            found = True
    except Exception:  # unreadable: read as any other input, which says why
        return False
    return found


def holds_overture_parts(path: Path, options) -> bool:
    """Whether a file's features are Overture's building parts: one with an id of its own (:data:`OWN_ID`) names a
    building (:data:`BUILDING_ID`) other than itself, among all of a GeoParquet file's (two columns read), among the first
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
            if BUILDING_ID not in names or OWN_ID not in names:
                return False  # without an id of its own, a building_id is the feature's own (LINZ's outlines)
            table = pq.read_table(path, columns=[c for c in (OWN_ID, BUILDING_ID) if c in names])
            named = table.column(BUILDING_ID).to_pylist()
            own = table.column(OWN_ID).to_pylist() if OWN_ID in table.column_names else [None] * len(named)
            return any(n is not None and str(n) != str(o) for n, o in zip(named, own))
        except Exception:  # unreadable: read as any other input, which says why
            return False
    try:
        for oid, props, _ in features(path, options, SNIFF_FEATURES):
            named = props.get(BUILDING_ID)  # a part has an id of its own too: LINZ's outlines name theirs building_id
            if named is not None and props.get(OWN_ID) is not None and str(named) != str(props[OWN_ID]):
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
    """The ids of the buildings INSPIRE's building parts among :attr:`~meshsom.io.ReaderOptions.part_files` belong
    to (:func:`meshsom.inspire.building_of`: linked from a building of
    :attr:`~meshsom.io.ReaderOptions.building_files`, or named by the part's id): read from their parts."""
    return _inspire_buildings(_stamp(options.part_files), _stamp(options.building_files), _reading(options))


@functools.lru_cache(maxsize=4)
def _inspire_buildings(stamped: tuple, building_stamps: tuple, options) -> frozenset[str]:
    from meshsom.gis import _attributes, _ogr_layers
    from meshsom.inspire import building_of, part_links

    links: dict[str, str] = {}
    for path, _, _ in building_stamps:
        if _kind(Path(path)) == "inspire":
            links.update(part_links(Path(path)))
    ids = set()
    for path, _, _ in stamped:
        if _kind(Path(path)) == "inspire":
            ids.update(b for layer in _ogr_layers(Path(path)) if layer.name == "BuildingPart"
                       for props in _attributes(Path(path), layer.name) if (b := building_of(props, links)) is not None)
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


@dataclasses.dataclass(frozen=True)
class OsmParts:
    """OpenStreetMap's building parts of the part files that hold them alone (:func:`holds_osm_parts`) and the
    buildings of the building files they belong to (:func:`osm_parts`). Keys are (resolved file, feature id as its
    reader names it).

    Attributes
    ----------
    parts_of : dict of (str, str) to list of meshsom.osm._Area
        A building's parts, each GeoJSON-like in its building's file's CRS, in file order.
    owned : frozenset of (str, str)
        The parts read with a building.
    strays : frozenset of (str, str)
        The parts inside no building outline: each read as a building of its own, noted.
    """

    parts_of: dict = dataclasses.field(default_factory=dict)
    owned: frozenset = frozenset()
    strays: frozenset = frozenset()


def osm_parts(options) -> OsmParts:
    """OpenStreetMap's building parts in files of their own among :attr:`~meshsom.io.ReaderOptions.part_files`,
    grouped with the buildings of :attr:`~meshsom.io.ReaderOptions.building_files` (:class:`OsmParts`)."""
    return _osm_parts(_stamp(options.part_files), _stamp(options.building_files), _reading(options))


def _key(path) -> str:
    return str(Path(path).resolve())


@functools.lru_cache(maxsize=4)
def _osm_parts(part_stamps: tuple, building_stamps: tuple, options) -> OsmParts:
    from shapely.geometry import mapping

    from meshsom.geojson import _is_part_feature
    from meshsom.osm import _Area, _said, osm_row, owners

    part_paths = [Path(p) for p, _, _ in part_stamps if holds_osm_parts(Path(p), options)]
    if not part_paths:
        return OsmParts()
    mine = {_key(p) for p in part_paths}
    parts, outlines = [], []  # (file, id, props, shapely geometry, crs)
    for path in part_paths:
        parts += [(_key(path), *row) for row in _footprints_as_read(path, options) if _is_part_feature(row[1])]
    for path, _, _ in building_stamps:
        if _key(path) in mine:
            continue
        outlines += [(_key(path), *row) for row in _footprints_as_read(Path(path), options)
                     if not _is_part_feature(row[1]) and (not osm_row(row[1]) or _said(row[1], "building"))]
    frame = next((crs for *_, crs in parts if crs), None)  # the parts' CRS: where outlines and parts are compared
    found = owners(np.array([_in_crs(g, crs, frame) for *_, g, crs in outlines], dtype=object),
                   np.array([_in_crs(g, crs, frame) for *_, g, crs in parts], dtype=object))
    parts_of: dict = {}
    owned, strays = set(), set()
    for (path, oid, props, geometry, crs), b in zip(parts, found.tolist()):
        if b < 0:
            strays.add((path, oid))
            continue
        building_path, building, _, _, building_crs = outlines[b]
        parts_of.setdefault((building_path, building), []).append(
            _Area(oid, props, mapping(_in_crs(geometry, crs, building_crs))))
        owned.add((path, oid))
    return OsmParts(parts_of, frozenset(owned), frozenset(strays))


def _in_crs(geometry, crs: str | None, target: str | None):
    """A shapely geometry in ``crs`` moved to ``target`` (x = easting or longitude); as it is where either is
    unknown or they are one."""
    move = _transformer(crs, target) if crs and target and crs != target else None
    if move is None:
        return geometry
    import shapely

    return shapely.transform(geometry, lambda xy: np.column_stack(move.transform(xy[:, 0], xy[:, 1])))


@functools.lru_cache(maxsize=16)
def _transformer(crs: str, target: str):
    """pyproj's transformer from one CRS to another, x = easting or longitude; None where they are one (axis order
    and a third dimension aside)."""
    import pyproj

    a, b = pyproj.CRS.from_user_input(crs), pyproj.CRS.from_user_input(target)
    if a.equals(b, ignore_axis_order=True) or (a.is_geographic and b.is_geographic and a.datum == b.datum):
        return None
    return pyproj.Transformer.from_crs(a, b, always_xy=True)


def _footprints_as_read(path: Path, options) -> Iterator[tuple]:
    """(id, properties, shapely (Multi)Polygon, CRS) of a footprint file's features with an area footprint, the ids
    as its reader names them (:func:`meshsom.gis.read_gis`, :func:`meshsom.geojson.read_geojson`); a feature that
    cannot be read is left out (its reader says why)."""
    from shapely.geometry import shape

    from meshsom.osm import area_geometry

    def polygon(geometry):
        try:
            g = shape(area_geometry(as_geojson(geometry, str(path)) if isinstance(geometry, (bytes, bytearray, memoryview))
                                    else geometry))
        except Exception:  # damaged
            return None
        return g if g.geom_type in ("Polygon", "MultiPolygon") and g.is_valid and g.area > 0 else None

    try:
        if _kind(path) == "geojson":
            from meshsom.geojson import _feature_id, _reference, declared_crs, properties
            from meshsom.io import _parse_json, read_input_bytes

            document = _parse_json(read_input_bytes(path, options), str(path))
            if not isinstance(document, dict):
                return
            found = [document] if document.get("type") == "Feature" else document.get("features") or []
            collection_crs, old_crs = _reference(document.get("coordRefSys")), _reference(document.get("crs"))
            for k, f in enumerate(found):
                if isinstance(f, dict) and isinstance(f.get("geometry"), dict) and (g := polygon(f["geometry"])):
                    yield _feature_id(f, k), properties(f), g, declared_crs(f, collection_crs, old_crs, options)
            return
        from meshsom.gis import _chosen_layers, _id_field, _records

        layers = _chosen_layers(path, options)
        for layer in layers:
            prefix = f"{layer.name}/" if len(layers) > 1 else ""
            for oid, props, geometry in _records(path, layer.name, _id_field(path, layer.name, options), 0, None):
                if geometry is not None and not isinstance(geometry, Exception) and (g := polygon(geometry)):
                    yield f"{prefix}{oid}", props, g, options.crs or layer.crs
    except Exception:  # unreadable: its reader says why
        return


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
        self.path = _key(path)
        self.is_part_file = is_part_file(path, options)
        self._osm: OsmParts | None = None
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
        from meshsom.osm import STRAY

        if self._osm is None:  # OpenStreetMap's parts in files of their own
            self._osm = osm_parts(self.options)
        if (self.path, oid) in self._osm.owned:
            return True, [], None
        if (self.path, oid) in self._osm.strays:
            return False, [], STRAY
        osm_own = self._osm.parts_of.get((self.path, oid), [])
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
        return False, self._parts.get(str(own) if own is not None else oid, self._parts.get(oid, [])) + osm_own, None


#: The note on a part read alone (its building's id after "; ": ingest counts the notes by what precedes it).
ALONE = "an Overture building_part whose building is in no input, read as a building of its own; building_id {}"
