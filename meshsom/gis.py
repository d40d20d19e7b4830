"""Reading buildings from GIS files: GeoPackage, Shapefile, FlatGeobuf, Esri File Geodatabase,
GeoJSONSeq, MapInfo (``.tab``, ``.mif``), SpatiaLite (``.sqlite``) and CSV (footprints as WKT: Google's Open Buildings) through GDAL (fiona), GeoParquet
through pyarrow.

Footprint layers with heights (national cadastres, OpenStreetMap extracts, Overture Maps' and
Microsoft's building footprints) and 3D layers (the 3D BAG's ``lod22_3d``, Esri multipatches, 3D
shapefiles) come in these formats. Each feature becomes a CityJSON-like Building over its own
vertices, read as :mod:`meshsom.geojson` reads a GeoJSON feature, so the same properties, LoD
choice, triangulation, CRS handling and rejections apply:

- **Footprints**: a 2D geometry, or a 3D one whose polygons all lie within
  :data:`FOOTPRINT_TILT_DEG` of horizontal (footprints draped on the terrain), with a height
  property (:attr:`meshsom.io.ReaderOptions.height_attributes`; a storey count otherwise) is
  extruded from its lowest z (:func:`meshsom.geojson.footprint_solid`), with the roof its roof
  columns describe (Overture's ``roof_shape``, ``roof_height``, ...). Without either it is a
  rejection that names the properties looked for.
- **OpenStreetMap data converted by GDAL** (``ogr2ogr`` of an extract: its ``other_tags``,
  :func:`meshsom.osm.osm_properties`) or by QuackOSM (GeoParquet) is read as the extract is (:func:`meshsom.osm.building_meshes`,
  the extract's ids); a row not tagged as a building is a rejection naming its first tag.
- **Building parts in the same file** (:func:`part_grouping`), tagged as OpenStreetMap tags them (a
  ``building:part`` column, or in ``other_tags``): a building with parts is its parts, a part in no
  building's outline a building of its own, noted; closed lines (GDAL's ``lines`` layer) are areas.
- **Rows of one OpenStreetMap id** (``ogr2ogr -explodecollections`` writes each polygon of a multipolygon as a
  row, :func:`osm_pieces`): read as one building, by the first row, noted; where they are not all polygons,
  each row is read as a feature of its own (``<id>@2`` and on).
- **Building parts in files of their own** (Overture's ``building_part`` downloads, paired with
  the buildings' file by :func:`meshsom.part_files.pair`): a building with parts is its parts, a
  part of no building a building of its own, noted.
- **3D surfaces**: a ``PolyhedralSurface``, ``TIN``, or 3D ``(Multi)Polygon`` with faces that are
  not horizontal (walls) is read as a MultiSurface of its polygons (LoD ``"2"``), closed or refused
  by preprocessing like any other building. Geometry collections are read through.
- Any other geometry (points, lines) is a rejection saying what it holds. Curves (arcs) come from
  GDAL as segments (fiona asks it for the linear geometry); in GeoParquet's WKB, whose
  specification has no curves, they are a rejection.
- **Layers**: every layer with geometry is read, or only :attr:`meshsom.io.ReaderOptions.layer`.
  Ids are ``name#<id>``, or ``name#<layer>/<id>`` when the file has several layers with geometry;
  ``<id>`` is the first property of :attr:`meshsom.io.ReaderOptions.id_attributes` whose values
  are given and unique over the layer, else the feature id (GDAL's FID; a GeoParquet row from 1).
- **CSV** (:data:`CSV_SUFFIX`, also gzipped) whose lines are GeoJSON features (Microsoft's global release): read
  as GeoJSONSeq. Whose header names a WKT column (:data:`CSV_GEOMETRY_COLUMNS`): read by GDAL's CSV driver; declaring no CRS, with its first footprint within +/-180 and +/-90, it is
  read as WGS 84 longitude, latitude (:data:`CSV_DEGREES_CRS`), noted, unless
  :attr:`meshsom.io.ReaderOptions.crs` is set.
- **CRS**: the layer's (GDAL's) or the GeoParquet column's (``crs`` absent means OGC:CRS84, as
  the GeoParquet specification says; ``null`` means unknown); else
  :attr:`meshsom.io.ReaderOptions.crs`. GDAL and GeoParquet give x = easting or longitude
  whatever the CRS's own axis order, and heights in the CRS's vertical unit (feet for EPSG:2263).

GDAL's geometries come through fiona, which gives TINs, polyhedral surfaces and Esri multipatches
as (collections of) MultiPolygons (pyogrio, GDAL's faster binding, refuses layers of those types).
GeoParquet's WKB is decoded here (:func:`wkb_polygons`), as GEOS (shapely) has no polyhedral
surfaces or TINs. Features are streamed (GeoParquet in batches of :data:`BATCH_FEATURES`): a file
of millions of footprints is not held.
"""

from __future__ import annotations

import dataclasses
import functools
import json
import math
import struct
import warnings
from pathlib import Path
from typing import Iterator, Sequence

import numpy as np

from meshsom.errors import InputFileError

#: File name endings read through GDAL (fiona). ``.gdb`` is a folder (Esri File Geodatabase);
#: ``.shz`` and ``.shp.zip`` are zipped shapefiles.
OGR_SUFFIXES = (".gpkg", ".shp", ".shz", ".shp.zip", ".fgb", ".gdb", ".geojsonl", ".geojsons", ".geojsonseq",
                ".tab", ".mif", ".sqlite")
#: CSV files of footprints written as WKT (Google's Open Buildings, QGIS's "CSV, geometry AS_WKT"), plain or gzipped:
#: read through GDAL's CSV driver where a column named as one of :data:`CSV_GEOMETRY_COLUMNS` (any case) holds them.
CSV_SUFFIX = ".csv"
CSV_GEOMETRY_COLUMNS = ("geometry", "wkt", "the_geom", "geom", "wkb_geometry")
#: What :func:`csv_geometry_column` says of a ``.csv`` file whose lines are GeoJSON features.
GEOJSON_LINES = "(GeoJSON lines)"
#: Bytes of a CSV file looked through for its header line.
CSV_HEADER_BYTES = 1 << 16
#: The CRS of a CSV file that declares none (no ``.prj`` beside it) whose first footprint lies within +/-180 and
#: +/-90: WGS 84 longitude, latitude, as Google's Open Buildings (and most CSV exports of footprints) are written.
CSV_DEGREES_CRS = "OGC:CRS84"
CSV_DEGREES_NOTE = ("the CSV file declares no CRS (no .prj beside it): its coordinates, within +/-180 and +/-90, are "
                    "read as WGS 84 longitude, latitude (--crs names another)")
PARQUET_DEGREES_NOTE = ("the Parquet file declares no CRS (a WKB column without GeoParquet metadata): its coordinates, "
                        "within +/-180 and +/-90, are read as WGS 84 longitude, latitude (--crs names another)")
NO_CRS_NOTE = ("the file declares no CRS (no .prj, no GeoParquet metadata): its coordinates, beyond +/-180 or +/-90, "
               "are read as metres (--crs names the CRS, and converts feet)")
#: File name endings read as GeoParquet (through pyarrow).
PARQUET_SUFFIXES = (".parquet", ".geoparquet")
GIS_SUFFIXES = OGR_SUFFIXES + PARQUET_SUFFIXES
#: Features decoded at a time.
BATCH_FEATURES = 4096
#: A polygon whose normal is within this many degrees of vertical is horizontal: a geometry of
#: only such polygons is a footprint (perhaps draped on the terrain), one with any steeper (a
#: wall) is a 3D surface.
FOOTPRINT_TILT_DEG = 45.0
#: WKB collections nested deeper than this are refused.
MAX_WKB_DEPTH = 16
#: GeoParquet 1.1's native geometry encodings (GeoArrow), read besides WKB.
GEOARROW_ENCODINGS = ("point", "linestring", "polygon", "multipoint", "multilinestring", "multipolygon")
#: The CRS of GeoParquet geometry whose column metadata has no ``crs`` member.
GEOPARQUET_DEFAULT_CRS = "OGC:CRS84"

_WKB_NAMES = {1: "Point", 2: "LineString", 3: "Polygon", 4: "MultiPoint", 5: "MultiLineString", 6: "MultiPolygon",
              7: "GeometryCollection", 8: "CircularString", 9: "CompoundCurve", 10: "CurvePolygon",
              11: "MultiCurve", 12: "MultiSurface", 13: "Curve", 14: "Surface", 15: "PolyhedralSurface", 16: "TIN",
              17: "Triangle"}
_WKB_COLLECTIONS = {4, 5, 6, 7, 11, 12, 15, 16}
_WKB_POLYGONS = {3, 17}
_SOLID_KINDS = {"PolyhedralSurface", "TIN", "Triangle"}
_SURFACE_KINDS = {"Polygon", "MultiPolygon", "GeometryCollection", "MultiSurface"} | _SOLID_KINDS


def wkb_polygons(data: bytes, where: str) -> tuple[list[list[np.ndarray]], set[str], bool]:
    """The polygons of a WKB geometry, however nested.

    Reads ISO WKB (type codes 1000 + n for Z, 2000 + n for M, 3000 + n for ZM), extended WKB
    (PostGIS flags and SRID) and either byte order, at every nesting level.

    Parameters
    ----------
    data : bytes
    where : str
        Names the feature in errors.

    Returns
    -------
    polygons : list of list of ndarray
        Each polygon's rings (the outer first), each an (n, 2) or (n, 3) float64 array of its
        positions (x, y and z where the geometry has z; m dropped). Polygons of Polygon,
        MultiPolygon, Triangle, PolyhedralSurface, TIN and of any collection of them.
    kinds : set of str
        The geometry types met (``"TIN"``, ``"LineString"``, ...).
    has_z : bool

    Raises
    ------
    InputFileError
        The bytes are not WKB, end early, nest deeper than :data:`MAX_WKB_DEPTH`, or hold a curve.
    """
    polygons: list[list[np.ndarray]] = []
    kinds: set[str] = set()
    state = {"z": False}
    buf = memoryview(bytes(data))
    end = _wkb_geometry(buf, 0, 0, polygons, kinds, state, where)
    if end != len(buf):
        raise InputFileError(where, f"its WKB geometry has {len(buf) - end} bytes after its end")
    return polygons, kinds, state["z"]


def _wkb_need(buf, pos: int, size: int, where: str) -> None:
    if size < 0 or pos + size > len(buf):
        raise InputFileError(where, f"its WKB geometry ends early (needs {size} bytes at byte {pos} of {len(buf)})")


def _wkb_geometry(buf, pos: int, depth: int, polygons: list, kinds: set, state: dict, where: str) -> int:
    """Read one WKB geometry at ``pos``; returns the position after it."""
    if depth > MAX_WKB_DEPTH:
        raise InputFileError(where, f"its WKB geometry nests deeper than {MAX_WKB_DEPTH} collections")
    _wkb_need(buf, pos, 5, where)
    if buf[pos] not in (0, 1):
        raise InputFileError(where, f"is not WKB (byte order marker {buf[pos]} at byte {pos}; expected 0 or 1)")
    order = "<" if buf[pos] == 1 else ">"
    code = struct.unpack_from(order + "I", buf, pos + 1)[0]
    pos += 5
    z, m = bool(code & 0x80000000), bool(code & 0x40000000)
    if code & 0x20000000:  # extended WKB: an SRID follows
        _wkb_need(buf, pos, 4, where)
        pos += 4
    code &= 0x0FFFFFFF
    base, dims_code = code % 1000, code // 1000
    z, m = z or dims_code in (1, 3), m or dims_code in (2, 3)
    name = _WKB_NAMES.get(base)
    if name is None or dims_code > 3:
        raise InputFileError(where, f"its WKB geometry has the unknown type code {code}")
    kinds.add(name)
    state["z"] = state["z"] or z
    dims = 2 + z + m
    keep = 3 if z else 2

    def count(at: int) -> tuple[int, int]:
        _wkb_need(buf, at, 4, where)
        return struct.unpack_from(order + "I", buf, at)[0], at + 4

    if base == 1:
        _wkb_need(buf, pos, 8 * dims, where)
        return pos + 8 * dims
    if base == 2:
        n, pos = count(pos)
        _wkb_need(buf, pos, 8 * dims * n, where)
        return pos + 8 * dims * n
    if base in _WKB_POLYGONS:
        n_rings, pos = count(pos)
        rings = []
        for _ in range(n_rings):
            n, pos = count(pos)
            _wkb_need(buf, pos, 8 * dims * n, where)
            ring = np.frombuffer(buf, dtype=order + "f8", count=n * dims, offset=pos).reshape(n, dims)
            rings.append(np.array(ring[:, :keep], np.float64))
            pos += 8 * dims * n
        if rings:
            polygons.append(rings)
        return pos
    if base in _WKB_COLLECTIONS:
        n, pos = count(pos)
        _wkb_need(buf, pos, 5 * n, where)  # each member at least its header
        for _ in range(n):
            pos = _wkb_geometry(buf, pos, depth + 1, polygons, kinds, state, where)
        return pos
    raise InputFileError(where, f"holds a {name} (a curved geometry); expected polygons (write it with its arcs "
                                f"as segments, e.g. ogr2ogr -nlt CONVERT_TO_LINEAR)")


def horizontal(polygons: list[list[np.ndarray]]) -> bool:
    """Whether every polygon's plane is within :data:`FOOTPRINT_TILT_DEG` of horizontal.

    Parameters
    ----------
    polygons : list of list of (n, 2 or 3) ndarray
        As :func:`wkb_polygons` gives them; 2D polygons are horizontal.

    Returns
    -------
    bool
        Polygons with no area (no normal) do not count.
    """
    outer = [poly[0] for poly in polygons if poly[0].shape[1] == 3 and len(poly[0])]
    if not outer:
        return True
    ring = np.concatenate(outer)
    sizes = np.array([len(r) for r in outer])
    starts = np.concatenate([[0], np.cumsum(sizes)[:-1]])
    following = np.arange(1, len(ring) + 1)
    following[starts + sizes - 1] = starts  # each ring's last vertex is followed by its first
    nxt = ring[following]
    terms = np.stack([  # Newell's normal: exact for planar rings, a best fit for others
        (ring[:, 1] - nxt[:, 1]) * (ring[:, 2] + nxt[:, 2]),
        (ring[:, 2] - nxt[:, 2]) * (ring[:, 0] + nxt[:, 0]),
        (ring[:, 0] - nxt[:, 0]) * (ring[:, 1] + nxt[:, 1]),
    ], axis=1)
    normal = np.add.reduceat(terms, starts, axis=0)
    size = np.linalg.norm(normal, axis=1)
    steep = (size > 0) & (np.abs(normal[:, 2]) < math.cos(math.radians(FOOTPRINT_TILT_DEG)) * size)
    return not steep.any()


def fiona_polygons(geometry, where: str) -> tuple[list[list[np.ndarray]], set[str], bool]:
    """The polygons of a geometry as fiona gives it (GeoJSON-like: ``type``, ``coordinates``,
    ``geometries``), as :func:`wkb_polygons` returns them."""
    polygons: list[list[np.ndarray]] = []
    kinds: set[str] = set()
    has_z = False
    stack = [(geometry, 0)]
    while stack:
        g, depth = stack.pop()
        if depth > MAX_WKB_DEPTH:
            raise InputFileError(where, f"its geometry nests deeper than {MAX_WKB_DEPTH} collections")
        kind = g["type"]
        kinds.add(kind)
        if kind == "GeometryCollection":
            stack.extend((member, depth + 1) for member in reversed(list(g["geometries"] or [])))
            continue
        if kind not in ("Polygon", "MultiPolygon"):
            continue
        coords = g["coordinates"] or []
        for poly in ([coords] if kind == "Polygon" else coords):
            rings = []
            for ring in poly:
                try:
                    array = np.asarray(ring, np.float64)
                except (TypeError, ValueError):
                    raise InputFileError(where, "a ring's positions are not all of the same dimension") from None
                if array.ndim != 2 or array.shape[1] not in (2, 3):
                    raise InputFileError(where, f"a ring must be positions of 2 or 3 numbers; received shape {array.shape}")
                has_z = has_z or array.shape[1] == 3
                rings.append(array)
            if rings:
                polygons.append(rings)
    return polygons, kinds, has_z


def feature_object(polygons: list[list[np.ndarray]], kinds: set[str], has_z: bool, props: dict, where: str,
                   options, crs=None) -> tuple[dict, np.ndarray, list[str]]:
    """One feature as a CityJSON-like Building object over its own vertices (as the module says).

    Parameters
    ----------
    polygons, kinds, has_z
        As :func:`wkb_polygons` or :func:`fiona_polygons` give them.
    props : dict
        The feature's properties.
    where : str
    options : ReaderOptions
    crs : CoordinateSystem or None
        The layer's CRS (x = easting or longitude), for the lengths that decide a footprint's roof
        (:func:`meshsom.geojson.footprint_solid`); None: metres.

    Returns
    -------
    obj : dict
    vertices : (V, 3) float64
    notes : list of str

    Raises
    ------
    InputFileError
        No polygons, or a footprint without a height.
    """
    from meshsom.geojson import FeatureVertices, building, footprint_solid, no_height, surfaces

    if not polygons:
        other = sorted(kinds - _SURFACE_KINDS)
        raise InputFileError(where, f"holds a {', '.join(other)}, not a building's polygons or solid" if other else
                             "has no geometry (it is empty)")
    verts = FeatureVertices()
    if not has_z or (not kinds & _SOLID_KINDS and horizontal(polygons)):
        solid, notes = footprint_solid([[ring.tolist() for ring in poly] for poly in polygons], props, where, options, verts,
                                       crs=crs)
        if solid is None:
            raise InputFileError(where, no_height(options, notes, props=props))
    else:
        solid, notes = surfaces(polygons, where, verts), []
    return building(solid, props, options), verts.array(), notes


@dataclasses.dataclass(frozen=True)
class Layer:
    """A layer of a GIS file.

    Attributes
    ----------
    name : str
    crs : str or None
        As GDAL or the GeoParquet metadata give it (``"EPSG:28992"``, WKT, PROJJSON); None when
        unknown.
    features : int
        The feature count (-1 where the driver cannot tell without reading them all).
    degrees : bool
        No CRS is declared and the first feature lies within +/-180 and +/-90 (a CSV file: read as
        :data:`CSV_DEGREES_CRS` unless :attr:`meshsom.io.ReaderOptions.crs` is set).
    """

    name: str
    crs: str | None
    features: int
    degrees: bool = False


@dataclasses.dataclass(frozen=True)
class PartGrouping:
    """The building parts among a GIS file's features, tagged as OpenStreetMap tags them (a ``building:part``
    column, or GDAL's ``other_tags``: an extract converted by ``ogr2ogr``, or a QuickOSM export), and the
    buildings they belong to (:func:`part_grouping`). Ids are the features' as :func:`read_gis` gives them
    (``<layer>/<id>`` where several layers are read).

    Attributes
    ----------
    owned : frozenset of str
        The parts read with their building.
    parts_of : dict of str to list of meshsom.osm._Area
        A building's parts (GeoJSON-like geometry), in file order.
    strays : frozenset of str
        The parts inside no building outline: each read as a building of its own, noted.
    named : dict of str to str
        Where a building is no feature of the file (INSPIRE's parts, :mod:`meshsom.inspire`): its first part's id
        (a key of ``parts_of``) to the building's id, which the mesh takes.
    linked : frozenset of str
        INSPIRE buildings of the file whose parts (``parts_of``) are theirs by the building's links or the parts' ids,
        not by their outline.
    tags : dict of str to dict
        Where a building of ``named`` is a feature of another file that links its parts: its properties (what its
        parts inherit), by its first part's id.
    what : str
        What its parts are, in the notes of the buildings of ``named``.
    contained : frozenset of str
        Buildings of ``linked`` some of whose parts are theirs by their outline alone (INSPIRE parts neither linked
        nor named), said in their notes.
    """

    owned: frozenset
    parts_of: dict
    strays: frozenset
    named: dict = dataclasses.field(default_factory=dict)
    linked: frozenset = frozenset()
    tags: dict = dataclasses.field(default_factory=dict)
    what: str = "INSPIRE BuildingParts"
    contained: frozenset = frozenset()

    def __contains__(self, oid: str) -> bool:
        return oid in self.owned or oid in self.parts_of or oid in self.strays


def part_grouping(path: Path, layers: list[Layer], options) -> PartGrouping | None:
    """The building parts of a GIS file's ``layers`` and their buildings (:class:`PartGrouping`), as OpenStreetMap
    extracts are read (:func:`meshsom.osm.building_meshes`): each part goes to the smallest building outline (a
    feature of any of the layers not itself a part) holding a point inside it. None where no feature is a part
    (a scan of the columns that say it, where a layer has them). Read once per process and file (its size and
    time of change in the key): each read task of a large file (:func:`gis_ranges`) holds the parts, not the
    buildings."""
    try:
        st = Path(path).stat()
    except OSError:
        return None
    keyed = tuple(layer.name for layer in layers)
    from meshsom.inspire import inline_parts

    if _is_gml(path) and (INSPIRE_PARTS in keyed or INSPIRE_BUILDINGS[0] in keyed and inline_parts(path)):
        from meshsom.part_files import _stamp  # INSPIRE's building parts: grouped by the building that links them, or
        # that their ids name, or that holds them

        linking = _stamp(list(dict.fromkeys(str(p) for p in (path, *options.building_files) if _is_gml(Path(p)))))
        return _inspire_grouping(str(path), st.st_size, st.st_mtime_ns, keyed, tuple(options.id_attributes), linking)
    if any(_bag2d_columns(path, name) for name in keyed):  # the 3D BAG's 2D layers: roof planes by building
        return _bag2d_grouping(str(path), st.st_size, st.st_mtime_ns, keyed, tuple(options.id_attributes))
    if not any(_has_part_columns(path, name) for name in keyed):
        return None
    return _part_grouping(str(path), st.st_size, st.st_mtime_ns, keyed, tuple(options.id_attributes))


#: The 3D BAG's 2D layers (``lod12_2d``, ``lod13_2d``, ``lod22_2d``; its WFS): a row per roof plane, the ground's
#: elevation and the roof's (percentiles of its points, NAP metres) in these columns (new names, then the 2021 ones).
BAG2D_GROUND = ("b3_h_maaiveld", "h_maaiveld")
BAG2D_ROOF = ("b3_h_dak_70p", "h_dak_70p", "b3_h_dak_50p", "h_dak_50p")


def _bag2d_columns(path: Path, layer: str) -> tuple[str, str] | None:
    """The ground and roof elevation columns of a 3D BAG 2D layer (:data:`BAG2D_GROUND`, :data:`BAG2D_ROOF`), else
    None."""
    try:
        if _is_parquet(path):
            import pyarrow.parquet as pq

            names = set(pq.read_schema(path).names)
        else:
            with _open(path, layer) as collection:
                names = set(collection.schema["properties"])
    except Exception:  # unreadable: its reading says why
        return None
    ground = next((c for c in BAG2D_GROUND if c in names), None)
    roof = next((c for c in BAG2D_ROOF if c in names), None)
    return (ground, roof) if ground and roof else None


@functools.lru_cache(maxsize=4)
def _bag2d_grouping(path: str, size: int, mtime: int, layers: tuple, id_attributes: tuple) -> PartGrouping:
    """The roof planes of a 3D BAG 2D layer grouped by their building (``fid``, else ``identificatie``), each a part
    extruded from the ground to its roof (as docs.3dbag.nl says LoD 1.2 and 1.3 are rebuilt from them: the roof's
    elevation less the ground's, :data:`BAG2D_ROOF`, :data:`BAG2D_GROUND`); the building takes its
    ``identificatie`` and its ``pand`` attributes (its labels), as from the 3D layers. A plane without them is read as a feature of its own."""
    from meshsom.osm import _Area

    groups: dict[tuple, list] = {}
    for name in layers:
        columns = _bag2d_columns(Path(path), name)
        if columns is None:
            continue
        ground, roof = columns
        prefix = f"{name}/" if len(layers) > 1 else ""
        for oid, props, geometry in _records(Path(path), name, _id_field_of(Path(path), name, id_attributes), 0, None):
            key = props.get(BAG3D_KEY) if props.get(BAG3D_KEY) is not None else props.get(BAG3D_ID)
            try:
                footprint = _footprint(geometry, f"{path}#{prefix}{oid}") if geometry is not None else None
                rise = float(props[roof]) - float(props[ground])
            except (InputFileError, KeyError, TypeError, ValueError):
                continue
            if key is None or footprint is None or not rise > 0:
                continue
            groups.setdefault((name, str(key)), []).append(_Area(f"{prefix}{oid}", {**props, "height": rise}, footprint))
    pand = _pand_of(path, size, mtime) if _bag3d_layers(Path(path)) else {}  # a 3D BAG GeoPackage's buildings
    parts_of = {parts[0].oid: parts for parts in groups.values()}
    owned = {part.oid for parts in groups.values() for part in parts[1:]}
    named = {parts[0].oid: str(pand.get(key, {}).get(BAG3D_ID) or parts[0].tags.get(BAG3D_ID) or key)
             for (_, key), parts in groups.items()}
    return PartGrouping(frozenset(owned), parts_of, frozenset(), named, frozenset(),
                        {parts[0].oid: {**pand.get(key, {}), **parts[0].tags} for (_, key), parts in groups.items()},
                        "3D BAG roof planes, each from the ground to its roof")


#: The layer GDAL's GML driver gives INSPIRE's building parts (:mod:`meshsom.inspire`), and the layers of buildings
#: (any other, such as Catastro's OtherConstruction, is refused by name).
INSPIRE_PARTS = "BuildingPart"
INSPIRE_BUILDINGS = ("Building", INSPIRE_PARTS)
#: Columns that can say a feature is a building part (OpenStreetMap's key; GDAL's OSM driver's tags; QuackOSM's).
PART_COLUMNS = ("building:part", "other_tags", "tags")


def _has_part_columns(path: Path, layer: str) -> bool:
    if _is_parquet(path):
        import pyarrow.parquet as pq

        return bool(set(PART_COLUMNS) & set(pq.read_schema(path).names))
    try:
        with _open(path, layer) as collection:
            return bool(set(PART_COLUMNS) & set(collection.schema["properties"]))
    except _gdal_errors():
        return False  # the read says why


@functools.lru_cache(maxsize=4)
def _part_grouping(path: str, size: int, mtime: int, layers: tuple, id_attributes: tuple) -> PartGrouping | None:
    from shapely.geometry import mapping, shape

    from meshsom.geojson import _is_part_feature
    from meshsom.osm import _Area, _said, area_geometry, osm_row, owners

    if not any(_is_part_feature(props) for name in layers for props in _attributes(Path(path), name)):
        return None
    outline_ids, outlines, part_ids, parts = [], [], [], []
    for name in layers:
        id_field = _id_field_of(Path(path), name, id_attributes)
        prefix = f"{name}/" if len(layers) > 1 else ""
        for oid, props, geometry in _records(Path(path), name, id_field, 0, None):
            part = _is_part_feature(props)
            if geometry is None or not part and osm_row(props) and not _said(props, "building"):
                continue
            try:
                footprint = _footprint(area_geometry(geometry), f"{path}#{prefix}{oid}")
                polygon = shape(footprint) if footprint is not None else None
            except Exception:  # damaged geometry: its own reading says so
                continue
            if polygon is None or not polygon.is_valid or polygon.area <= 0:
                continue
            if part:  # named in notes by its OpenStreetMap id (unique across layers) where it has one
                part_ids.append((f"{prefix}{oid}", oid if osm_row(props) else f"{prefix}{oid}", props, mapping(polygon)))
                parts.append(polygon)
            else:
                outline_ids.append(f"{prefix}{oid}")
                outlines.append(polygon)
    found = owners(np.array(outlines, dtype=object), np.array(parts, dtype=object))
    parts_of: dict[str, list] = {}
    owned, strays = set(), set()
    for (oid, child, props, geometry), b in zip(part_ids, found.tolist()):
        if b >= 0:
            parts_of.setdefault(outline_ids[b], []).append(_Area(child, props, geometry))
            owned.add(oid)
        else:
            strays.add(oid)
    return PartGrouping(frozenset(owned), parts_of, frozenset(strays))


@functools.lru_cache(maxsize=4)
def _inspire_grouping(path: str, size: int, mtime: int, layers: tuple, id_attributes: tuple,
                      linking: tuple = ()) -> PartGrouping:
    """INSPIRE's building parts (:data:`INSPIRE_PARTS` layer) grouped by their building
    (:func:`meshsom.inspire.building_of`): one that links them (``bu-core2d:parts``) in any of the GML files of
    ``linking`` (this one, and a run's other building files: :func:`meshsom.part_files._stamp`), else the one their
    ``gml_id`` names. A building of this file is read as its parts (``linked``); one elsewhere takes its first part's
    place (``named``). A part neither linked nor named goes to the smallest Building of this file whose outline holds a
    point inside it (``contained``), as OpenStreetMap's parts do; a part of no building, or whose footprint cannot be
    read, is read as a feature of its own. Parts written inside their building (:func:`meshsom.inspire.inline_parts`)
    are that building's."""
    from shapely.geometry import shape

    from meshsom.inspire import building_of, inline_parts, linking_buildings, part_links
    from meshsom.osm import _Area, owners

    links: dict[str, str] = {}
    for other, _, _ in linking:
        links.update(part_links(Path(other)))
    groups: dict[str, list] = {}
    loose = []  # parts neither linked nor named: to the outline that holds them
    for name in layers:
        if name != INSPIRE_PARTS:
            continue
        prefix = f"{name}/" if len(layers) > 1 else ""
        for oid, props, geometry in _records(Path(path), name, _id_field_of(Path(path), name, id_attributes), 0, None):
            building = building_of({**props, "gml_id": props.get("gml_id") or oid}, links)
            try:
                footprint = _footprint(geometry, f"{path}#{prefix}{oid}") if geometry is not None else None
            except InputFileError:  # damaged: its own reading says so
                footprint = None
            if building is not None and footprint is not None:
                groups.setdefault(building, []).append(_Area(f"{prefix}{oid}", props, footprint))
            elif footprint is not None:
                loose.append(_Area(f"{prefix}{oid}", props, footprint))
    contained = set()
    if loose and INSPIRE_BUILDINGS[0] in layers:
        outlines = []
        for oid, props, geometry in _records(Path(path), INSPIRE_BUILDINGS[0], None, 0, None):
            try:
                footprint = _footprint(geometry, f"{path}#{oid}") if geometry is not None else None
                outline = shape(footprint) if footprint is not None else None
            except Exception:  # damaged: its own reading says so
                outline = None
            if outline is not None and outline.is_valid and outline.area > 0:
                outlines.append((str(props.get("gml_id") or oid), outline))
        found = owners(np.array([o for _, o in outlines], dtype=object),
                       np.array([shape(part.geometry) for part in loose], dtype=object))
        for part, b in zip(loose, found.tolist()):
            if b >= 0:
                groups.setdefault(outlines[b][0], []).append(part)
                contained.add(outlines[b][0])
    if INSPIRE_BUILDINGS[0] in layers:
        for building, oid, props, geometry in inline_parts(Path(path)):  # a part without a footprint: noted as left
            try:  # out by its building's reading
                footprint = _footprint(geometry, f"{path}#{oid}") if geometry is not None else None
            except InputFileError:
                footprint = None
            if building is not None:
                groups.setdefault(building, []).append(_Area(f"{INSPIRE_PARTS}/{oid}", props, footprint or geometry))
    here = {}  # the buildings of this file its parts belong to: gml_id -> id as read
    if groups and INSPIRE_BUILDINGS[0] in layers:
        prefix = f"{INSPIRE_BUILDINGS[0]}/" if len(layers) > 1 else ""
        for oid, props, _ in _records(Path(path), INSPIRE_BUILDINGS[0], _id_field_of(
                Path(path), INSPIRE_BUILDINGS[0], id_attributes), 0, None):
            if str(props.get("gml_id") or oid) in groups:
                here[str(props.get("gml_id") or oid)] = f"{prefix}{oid}"
    parts_of, named, owned, linked, tags, within = {}, {}, set(), set(), {}, set()
    for building, parts in groups.items():
        if building in here:  # read from its own feature, as its parts
            parts_of[here[building]] = parts
            owned.update(part.oid for part in parts)
            linked.add(here[building])
            if building in contained:
                within.add(here[building])
        else:  # its first part read as it, named by it, with its attributes where another file links it
            parts_of[parts[0].oid] = parts
            owned.update(part.oid for part in parts[1:])
            named[parts[0].oid] = building
            for other, _, _ in linking:
                if building in (found := linking_buildings(Path(other))):
                    tags[parts[0].oid] = found[building]
    return PartGrouping(frozenset(owned), parts_of, frozenset(), named, frozenset(linked), tags,
                        contained=frozenset(within))


def _attributes(path: Path, layer: str, osm: bool = False) -> Iterator[dict]:
    """The properties of a layer's features (no geometry decoded), with GDAL's OSM tags read in; only the columns
    that can say a feature is a part, and ``building`` (``osm``: and those that name an OpenStreetMap element), of a
    GeoParquet file."""
    from meshsom.osm import EXPORT_ID, EXPORT_TYPE, GDAL_ID, QUICKOSM_TYPE, osm_properties

    if _is_parquet(path):
        import pyarrow.parquet as pq

        names = pq.read_schema(path).names
        ids = (GDAL_ID, EXPORT_ID, EXPORT_TYPE, QUICKOSM_TYPE) if osm else ()
        wanted = [c for c in (*PART_COLUMNS, "building", "osm_way_id", "feature_id", *ids) if c in names]
        for values in pq.read_table(path, columns=wanted).to_pylist():
            yield osm_properties(values)
        return
    try:
        with _open(path, layer, ignore_geometry=True) as collection:
            for feature in collection:
                yield osm_properties(dict(feature.properties))
    except _gdal_errors() as err:
        raise _gdal_error(path, err) from None


#: The 3D BAG's GeoPackage (docs.3dbag.nl, Data Layers): a building's attributes in ``pand`` (its ``fid`` the key),
#: its 3D models by LoD in these layers (a row per part above the terrain, ``fid`` naming its building), and their 2D
#: projections beside them (``lod22_2d``, ...: a row per roof plane).
BAG3D_LAYERS = {"1.2": "lod12_3d", "1.3": "lod13_3d", "2.2": "lod22_3d"}
BAG3D_PAND, BAG3D_KEY, BAG3D_ID = "pand", "fid", "identificatie"


@dataclasses.dataclass(frozen=True)
class Bag3D:
    """A 3D BAG GeoPackage as it is read (:func:`bag3d`): one of its 3D layers, the others being other forms of the
    same buildings.

    Attributes
    ----------
    layer : str
        The 3D layer read (by :attr:`meshsom.io.ReaderOptions.lod`: the highest, the lowest or the one named).
    lod : str
        Its LoD (``"2.2"``), the meshes'.
    others : tuple of str
        The file's other layers, not read.
    pand : dict of str to dict
        A building's ``pand`` attributes by its ``fid``; a mesh's id is its ``identificatie``.
    """

    layer: str
    lod: str
    others: tuple
    pand: dict

    def note(self, parts: int) -> str:
        return (f"a 3D BAG GeoPackage: its LoD {self.lod} layer read ({self.layer}; {', '.join(self.others)} are other "
                f"forms of the same buildings: --layer reads one)"
                + (f"; {parts} parts above the terrain (rows of one fid), read as one building" if parts > 1 else ""))


def bag3d(path: Path, options) -> Bag3D | None:
    """The 3D BAG layout of a GeoPackage (:data:`BAG3D_LAYERS`), read as :class:`Bag3D` says: the layer
    :attr:`meshsom.io.ReaderOptions.layer` names where it is a 3D one, else that of the LoD asked for
    (:attr:`~meshsom.io.ReaderOptions.lod`); None for any other file, or another layer named.

    Raises
    ------
    InputFileError
        No layer named, and no 3D layer of the LoD asked for.
    """
    names = _bag3d_layers(path)
    if names is None:
        return None
    present = [lod for lod, name in BAG3D_LAYERS.items() if name in names]
    wanted = str(options.lod)
    if options.layer is not None:
        lod = next((lod for lod in present if BAG3D_LAYERS[lod] == options.layer), None)
    else:
        lod = present[-1] if wanted == "highest" else present[0] if wanted == "lowest" else (
            wanted if wanted in present else None)
    if lod is None:
        if options.layer is None:
            raise InputFileError(str(path), f"is a 3D BAG GeoPackage of LoD {', '.join(present)} (layers "
                                            f"{', '.join(BAG3D_LAYERS[p] for p in present)}); LoD {wanted} is none of "
                                            "them (--lod, or --layer to read one layer as it is)")
        return None
    st = Path(path).stat()
    return Bag3D(BAG3D_LAYERS[lod], lod, tuple(n for n in names if n != BAG3D_LAYERS[lod]),
                 _pand_of(str(path), st.st_size, st.st_mtime_ns))


@dataclasses.dataclass(frozen=True)
class _Named:
    """Options that name a layer (and ask for no LoD): :func:`bag3d` of a layer being read."""

    layer: str
    lod: str = "highest"


def _bag3d_layers(path: Path) -> list[str] | None:
    """A GeoPackage's layer names where they are the 3D BAG's (``pand`` and a 3D layer), else None."""
    if not str(path).lower().endswith(".gpkg"):
        return None
    try:
        names = [layer.name for layer in _ogr_layers(Path(path))]
    except (InputFileError, OSError):
        return None
    return names if BAG3D_PAND in names and any(name in names for name in BAG3D_LAYERS.values()) else None


@functools.lru_cache(maxsize=4)
def _pand_of(path: str, size: int, mtime: int) -> dict:
    """The ``pand`` layer's attributes by its feature id (the GeoPackage's ``fid``)."""
    try:
        with _open(Path(path), BAG3D_PAND, ignore_geometry=True) as collection:
            return {str(feature.id): dict(feature.properties) for feature in collection}
    except _gdal_errors() as err:
        raise _gdal_error(Path(path), err) from None


def _chosen_layers(path: Path, options) -> list[Layer]:
    """The layers a read takes: every layer with geometry, or the one ``options.layer`` names; of a 3D BAG
    GeoPackage, the 3D layer of the LoD asked for (:func:`bag3d`)."""
    if path.is_file() and not is_csv(path) and not _is_gml(path) and not _is_json(path):
        with open(path, "rb") as fh:
            if fh.read(2) == b"\x1f\x8b":
                raise InputFileError(str(path), "is gzip-compressed; GIS files are read uncompressed (gunzip it first)")
    layers = _parquet_layers(path) if _is_parquet(path) else _ogr_layers(path)
    if not layers:
        raise InputFileError(str(path), "holds no layer with geometry")
    found = bag3d(path, options) if options.layer is None else None
    if found is not None:
        return [layer for layer in layers if layer.name == found.layer]
    if options.layer is not None:
        chosen = [layer for layer in layers if layer.name == options.layer]
        if not chosen:
            raise InputFileError(str(path), f"has no layer {options.layer!r}; its layers with geometry are "
                                            f"{', '.join(repr(layer.name) for layer in layers)}")
        layers = chosen
    return layers


def _is_parquet(path: Path) -> bool:
    return path.name.lower().endswith(PARQUET_SUFFIXES)


def gis_ranges(path: Path, target_features: int, options) -> list[list] | None:
    """Split a large GIS file into feature ranges, each for one read task.

    Parameters
    ----------
    path : Path
    target_features : int
        Features per range.
    options : ReaderOptions

    Returns
    -------
    list of ["features", layer, prefix, id_field, start, stop] or None
        Ranges covering every feature of the layers read once, in order, for :func:`read_gis`
        (``feature_range``; JSON, for a pipeline's plan): ``prefix`` starts the ids (the layer's
        name and a slash where several layers are read), ``id_field`` is the property the ids
        come from (None: feature ids), decided here once for the whole layer. None when no
        layer has more than twice ``target_features`` features (or a count is unknown), or the
        file cannot be read (its reader then says why).
    """
    try:
        layers = _chosen_layers(path, options)
    except InputFileError:
        return None
    if target_features < 1 or not any(layer.features > 2 * target_features for layer in layers) or any(
            layer.features < 0 for layer in layers):
        return None
    ranges = []
    for layer in layers:
        prefix = f"{layer.name}/" if len(layers) > 1 else ""
        id_field = _id_field(path, layer.name, options)
        for start in range(0, layer.features, target_features):
            ranges.append(["features", layer.name, prefix, id_field, start, min(start + target_features, layer.features)])
    return ranges


def read_gis(path: Path, options, name: str | None = None, feature_range: Sequence | None = None) -> Iterator:
    """Read the buildings of a GIS file: RawMesh or Rejection items, as :func:`meshsom.io.read_cityjson`.

    Parameters
    ----------
    path : Path
    options : ReaderOptions
    name : str, optional
    feature_range : sequence, optional
        One of :func:`gis_ranges`: only those features (a range of no features yields nothing).

    Raises
    ------
    InputFileError
        The file cannot be opened, is gzip-compressed, has no layer with geometry (or not the
        layer asked for), or holds no features.
    """
    from meshsom.part_files import Placement

    name = name or path.name
    layers = _chosen_layers(path, options)
    placement = Placement(path, options) if options.part_files else None  # Overture's parts, in files of their own
    grouping = part_grouping(path, layers, options)  # OpenStreetMap's building:part, INSPIRE's BuildingPart
    if feature_range is not None:
        _, layer_name, prefix, id_field, start, stop = feature_range
        (layer,) = [layer for layer in layers if layer.name == layer_name]
        for oid, props, geometry in _records(path, layer.name, id_field, int(start), int(stop)):
            yield from _feature_meshes(path, name, f"{prefix}{oid}", props, geometry, layer, options, placement,
                                       grouping)
        return
    found = False
    for layer in layers:
        prefix = f"{layer.name}/" if len(layers) > 1 else ""
        for oid, props, geometry in _records(path, layer.name, _id_field(path, layer.name, options), 0, None):
            found = True
            yield from _feature_meshes(path, name, f"{prefix}{oid}", props, geometry, layer, options, placement,
                                       grouping)
    if not found:
        raise InputFileError(str(path), "holds no features" + (f" in layer {options.layer!r}" if options.layer else ""))


def _feature_meshes(path: Path, name: str, oid: str, props: dict, geometry, layer: Layer, options,
                    placement=None, grouping: "PartGrouping | None" = None) -> Iterator:
    from meshsom.io import Rejection, _object_meshes, file_crs
    from meshsom.osm import STRAY, _Area, area_geometry, building_meshes, osm_row, no_outline, not_a_building

    mesh_id = f"{name}#{oid}"
    if isinstance(geometry, InputFileError):  # a GeoArrow geometry that cannot be read (_parquet_records)
        yield Rejection(mesh_id, str(path), geometry.problem, 0, None)
        return
    assumed = layer.crs is None and layer.degrees and options.crs is None  # a CSV file in degrees, declaring no CRS
    system, unknown = file_crs(CSV_DEGREES_CRS if assumed else layer.crs, options)
    file_notes = [(PARQUET_DEGREES_NOTE if _is_parquet(path) else CSV_DEGREES_NOTE)] if assumed else []
    if layer.crs is None and not assumed and options.crs is None:  # projected data written without a CRS
        file_notes.append(NO_CRS_NOTE)
    if system is not None and system.geographic:
        system = dataclasses.replace(system, latitude_first=False)  # GDAL and GeoParquet: longitude first
    if placement is not None and geometry is not None:  # Overture's building parts, in files of their own
        from meshsom.part_files import as_geojson

        skip, own, alone = placement.of(props, oid)
        if skip:
            return  # read with its building
        if own or alone:
            try:
                area = _Area(oid, props, as_geojson(geometry, mesh_id))
            except InputFileError as err:
                yield Rejection(mesh_id, str(path), err.problem, 0, None)
                return
            yield from building_meshes(area, own, alone, options, name, str(path), (system, unknown), file_notes)
            return
    from meshsom.inspire import is_ogr_gml

    if _is_gml(path) and layer.name not in INSPIRE_BUILDINGS and not is_ogr_gml(path):  # Catastro's
        # otherconstruction.gml: pools, sheds' roofs (GDAL's own GML, ogr2ogr's: any layer is footprints)
        yield Rejection(mesh_id, str(path), f"is an INSPIRE {layer.name}, not a building ({' or '.join(INSPIRE_BUILDINGS)})")
        return
    osm = osm_row(props)  # a row of an OpenStreetMap extract converted by ogr2ogr: read as the extract's reader does
    if osm and geometry is not None and (reason := not_a_building(props)) is not None:
        label = props.get(options.label_attribute)
        yield Rejection(mesh_id, str(path), reason, 0, None if label is None else str(label))
        return
    if geometry is not None and (osm or grouping is not None and oid in grouping):
        if grouping is not None and oid in grouping.owned:
            return  # read with its building
        shape = area_geometry(geometry)  # a closed way of GDAL's lines layer: an area
        try:
            area = _footprint(shape, mesh_id)
        except InputFileError as err:
            yield Rejection(mesh_id, str(path), err.problem, 0, None)
            return
        if area is None and osm and (reason := no_outline(props, shape)) is not None:
            yield Rejection(mesh_id, str(path), reason, 0, None)
            return
        if area is not None:  # else not a footprint: said below
            own = grouping.parts_of.get(oid, []) if grouping is not None else []
            stray = STRAY if grouping is not None and oid in grouping.strays else None
            building = grouping.named.get(oid) if grouping is not None else None  # INSPIRE: the building its parts name
            how = (f"{len(own)} {grouping.what} of {building}, read as its parts" if building else
                   f"{len(own)} INSPIRE BuildingParts of it, read as its parts"
                   + (" (parts neither linked nor naming a building go to the outline holding them)"
                      if oid in grouping.contained else "")
                   if grouping is not None and oid in grouping.linked else None)
            united = osm_pieces(path, layer.name).note(oid.removeprefix(f"{layer.name}/")) if osm else None
            tags = props if building is None else grouping.tags.get(oid, {})  # INSPIRE: the linking building's
            yield from building_meshes(_Area(building or oid, tags, area), own, stray,
                                       options, name, str(path), (system, unknown),
                                       file_notes + ([united] if united else []), how=how)
            return
    try:
        if geometry is None:
            raise InputFileError(mesh_id, "has no geometry" + (" (its WKT is empty, or not WKT GDAL can read)"
                                                               if is_csv(path) else ""))
        polygons, kinds, has_z = (wkb_polygons(geometry, mesh_id) if isinstance(geometry, (bytes, bytearray, memoryview))
                                  else fiona_polygons(geometry, mesh_id))
        obj, vertices, notes = feature_object(polygons, kinds, has_z, props, mesh_id, options, system)
        bag = bag3d(path, _Named(layer.name)) if layer.name in BAG3D_LAYERS.values() else None
        if bag is not None:  # a 3D BAG building: of its layer's LoD, its parts (rows of its fid) one building
            for geometry in obj["geometry"]:
                geometry["lod"] = bag.lod
            notes = [bag.note(osm_pieces(path, layer.name, BAG3D_KEY).rows.get(str(props.get(BAG3D_KEY)), 1))] + notes
    except InputFileError as err:
        label = props.get(options.label_attribute)
        yield Rejection(mesh_id, str(path), err.problem, 0, None if label is None else str(label))
        return
    notes = notes + file_notes
    for item in _object_meshes({oid: obj}, vertices, None, None, options, name, str(path), crs=(system, unknown)):
        if notes and not isinstance(item, Rejection):
            item = dataclasses.replace(item, notes=tuple(notes) + item.notes)
        yield item


def _footprint(geometry, where: str) -> dict | None:
    """A 2D (Multi)Polygon as a GeoJSON-like dict (WKB decoded); None for any other geometry."""
    if isinstance(geometry, (bytes, bytearray, memoryview)):
        polygons, kinds, has_z = wkb_polygons(geometry, where)
        if not polygons or not kinds <= {"Polygon", "MultiPolygon"} or has_z and not horizontal(polygons):
            return None
        return {"type": "MultiPolygon", "coordinates": [[ring.tolist() for ring in poly] for poly in polygons]}
    try:
        kind = geometry["type"]
    except (KeyError, TypeError):
        return None
    return geometry if kind in ("Polygon", "MultiPolygon") else None


def _gdal_error(path: Path, err: Exception) -> InputFileError:
    if isinstance(err, InputFileError):
        return err  # said already (an InputFileError is a ValueError too)
    text = " ".join(str(err).split())
    return InputFileError(str(path), f"cannot be read through GDAL ({type(err).__name__}: {text[:200]})")


def _gdal_errors():
    import fiona.errors

    return (fiona.errors.FionaError, fiona.errors.DriverError, OSError, RuntimeError, ValueError)


def is_csv(path: Path) -> bool:
    """Whether a file is named as a CSV file (``.csv``, ``.csv.gz``)."""
    from meshsom.io import format_name

    return format_name(Path(path)).endswith(CSV_SUFFIX)


def csv_geometry_column(path: Path) -> str | None:
    """How a CSV file (plain or gzipped) holds its geometry: the name of its WKT column (the first of its header's
    names that is one of :data:`CSV_GEOMETRY_COLUMNS`, any case), or :data:`GEOJSON_LINES` where its lines are GeoJSON
    features (Microsoft's global building footprints, shipped as ``.csv.gz``); None where neither (or the file
    cannot be opened).

    Raises
    ------
    InputFileError
        It is empty, or gzip data that is damaged or ends early (:func:`meshsom.io.open_input`).
    """
    import csv
    import io

    from meshsom.io import open_input

    try:
        with open_input(Path(path)) as stream:
            text = stream.read(CSV_HEADER_BYTES).decode("utf-8-sig", errors="replace")
    except OSError:
        return None
    if text.lstrip().startswith("{"):
        return GEOJSON_LINES
    try:
        header = next(csv.reader(io.StringIO(text.splitlines()[0] if text else "")), [])
    except csv.Error:
        return None
    names = {name.strip().lower(): name.strip() for name in header}
    return next((names[c] for c in CSV_GEOMETRY_COLUMNS if c in names), None)


def _gzipped(path: Path) -> bool:
    with open(path, "rb") as fh:
        return fh.read(2) == b"\x1f\x8b"


def _source(path: Path) -> str:
    """What GDAL opens for a file: its path, or through /vsigzip/ where it is gzip data (a CSV or GML file)."""
    return f"/vsigzip/{Path(path).resolve()}" if _gzipped(path) else str(path)


def _is_json(path: Path) -> bool:
    from meshsom.io import format_name

    return format_name(Path(path)).endswith(".json")


def _is_gml(path: Path) -> bool:
    from meshsom.io import format_name

    return format_name(Path(path)).endswith(".gml")


def _open(path: Path, layer: str | None = None, **kwargs):
    """fiona's collection of a layer of a GIS file; a CSV file's (gzipped: through GDAL's /vsigzip/) with its WKT
    column as the geometry (GDAL's CSV open options), or read as GeoJSONSeq; a GML file's (INSPIRE buildings,
    :mod:`meshsom.inspire`) without GDAL's ``.gfs`` file written beside it."""
    import fiona

    if _is_gml(path):
        return fiona.open(_source(path), layer=layer, WRITE_GFS="NO", **kwargs)
    if _is_json(path):  # Esri JSON (meshsom.geojson.is_esri_json), plain or gzipped
        return fiona.open(_source(path), layer=layer, driver="ESRIJSON", **kwargs)
    if not is_csv(path):
        return fiona.open(path, layer=layer, **kwargs)
    column = csv_geometry_column(path)
    if column == GEOJSON_LINES:
        return fiona.open(f"GeoJSONSeq:{_source(path)}", layer=layer, **kwargs)
    return fiona.open(_source(path), layer=layer, GEOM_POSSIBLE_NAMES=column, KEEP_GEOM_COLUMNS="NO", **kwargs)


def _ogr_layers(path: Path) -> list[Layer]:
    """The layers of a GDAL file, looked at once per process (the file's size and time of change in the key: a CSV
    file's features are counted by reading them all)."""
    st = Path(path).stat()
    return list(_ogr_layers_of(str(path), st.st_size, st.st_mtime_ns))


@functools.lru_cache(maxsize=16)
def _ogr_layers_of(path: str, size: int, mtime: int) -> tuple[Layer, ...]:
    import fiona
    import fiona.errors

    path = Path(path)
    try:
        layers = []
        names = [None] if is_csv(path) or _is_json(path) else (
            fiona.listlayers(_source(path), WRITE_GFS="NO") if _is_gml(path) else fiona.listlayers(path))
        for layer_name in names:
            with _open(path, layer_name) as collection:
                try:
                    if collection.schema.get("geometry") in (None, "None"):
                        continue  # an attribute table
                except fiona.errors.UnsupportedGeometryTypeError:
                    pass  # a multipatch ('3D Unknown'): its features are read all the same
                crs = collection.crs
                degrees = False
                if not crs and is_csv(path):
                    first = next(iter(collection), None)
                    degrees = first is not None and first.geometry is not None and _within_degrees(first.geometry)
                try:
                    count = len(collection)
                except TypeError:  # a driver that cannot count (MapInfo's MIF): read by one task
                    count = -1
                layers.append(Layer(str(layer_name or collection.name), crs.to_string() if crs else None, count, degrees))
        return tuple(layers)
    except _gdal_errors() as err:
        raise _gdal_error(path, err) from None


def _within_degrees(geometry) -> bool:
    """Whether a (GeoJSON-like) geometry's x lie within +/-180 and its y within +/-90."""
    from shapely.geometry import shape

    try:
        x0, y0, x1, y1 = shape(geometry).bounds
    except Exception:  # no shape: no evidence of degrees
        return False
    return -180 <= x0 <= x1 <= 180 and -90 <= y0 <= y1 <= 90


def _unique_column(values: list) -> bool:
    return all(v is not None and str(v) != "" for v in values) and len({str(v) for v in values}) == len(values)


def _id_field(path: Path, layer: str, options) -> str | None:
    """The first of ``options.id_attributes`` whose values are given and unique over the layer."""
    return _id_field_of(path, layer, tuple(options.id_attributes))


def _id_field_of(path: Path, layer: str, id_attributes: tuple) -> str | None:
    if not id_attributes:
        return None
    if _is_parquet(path):
        import pyarrow.parquet as pq

        column, _ = _parquet_geo(path)
        names = pq.read_schema(path).names
        for candidate in id_attributes:
            if candidate in names and candidate != column and _unique_column(
                    pq.read_table(path, columns=[candidate]).column(0).to_pylist()):
                return candidate
        return None
    values: dict[str, list] = {c: [] for c in id_attributes}
    try:
        with _open(path, layer, ignore_geometry=True) as collection:
            for feature in collection:
                props = dict(feature.properties)
                for candidate, column in values.items():
                    column.append(props.get(candidate))
    except _gdal_errors() as err:
        raise _gdal_error(path, err) from None
    return next((c for c, column in values.items() if column and _unique_column(column)), None)


def _records(path: Path, layer: str, id_field: str | None, start: int, stop: int | None
             ) -> Iterator[tuple[str, dict, object]]:
    """(id, properties, geometry) of features ``start`` to ``stop`` of a layer, streamed: fiona's
    geometry (GeoJSON-like) or GeoParquet's WKB; the properties of GDAL's OSM driver with the tags of
    its ``other_tags`` read in, and its ids as :mod:`meshsom.osm` gives them (``way/<id>``)."""
    from meshsom.osm import osm_row_id, osm_properties

    if _is_parquet(path):
        yield from _parquet_records(path, id_field, start, stop)
        return
    from meshsom.inspire import inspire_properties

    gml = _is_gml(path)
    bag = bag3d(path, _Named(layer)) if layer in BAG3D_LAYERS.values() else None  # a 3D BAG layer: its buildings
    try:
        with _open(path, layer) as collection:
            with warnings.catch_warnings():  # a CSV file has no fast feature count: a range is read from its start
                warnings.filterwarnings("ignore", "Layer does not support OLC_FASTFEATURECOUNT", RuntimeWarning)
                features = collection.filter(start, stop)
            pieces = None
            for index, feature in enumerate(features, start):
                props = osm_properties(dict(feature.properties))
                if gml:  # INSPIRE's heightAboveGround
                    props = inspire_properties(props)
                oid = osm_row_id(props, layer)
                geometry = feature.geometry
                if bag is not None and props.get(BAG3D_KEY) is not None:  # a 3D BAG building's parts: one building
                    pieces = osm_pieces(path, layer, BAG3D_KEY) if pieces is None else pieces
                    if index in pieces.later:
                        continue
                    key = str(props[BAG3D_KEY])
                    oid = str(bag.pand.get(key, {}).get(BAG3D_ID) or props.get(BAG3D_ID) or key)
                    yield oid, {**bag.pand.get(key, {}), **props}, pieces.united.get(index, geometry)
                    continue
                if oid is not None:  # an exploded multipolygon's rows: read as one building, by its first row
                    pieces = osm_pieces(path, layer) if pieces is None else pieces
                    if index in pieces.later:
                        continue
                    geometry = pieces.united.get(index, geometry)
                    oid = f"{oid}@{pieces.named[index]}" if index in pieces.named else oid
                yield oid or str(props.get(id_field) if id_field else feature.id), props, geometry
    except _gdal_errors() as err:
        raise _gdal_error(path, err) from None


@dataclasses.dataclass(frozen=True)
class OsmPieces:
    """The rows of a converted OpenStreetMap layer that share an element id (``ogr2ogr -explodecollections`` writes
    each polygon of a multipolygon as a row of its own, with the element's tags): found once per process and file
    (:func:`osm_pieces`), so that every read task of the layer reads them alike.

    Attributes
    ----------
    later : frozenset of int
        Rows (from 0) read with the first row of their id: not read again.
    united : dict of int to object
        The first row of such an id -> the polygons of all its rows as one MultiPolygon (GeoJSON-like for a GDAL
        layer, WKB for GeoParquet): read as one building.
    rows : dict of str to int
        Such an id -> its number of rows (said in its building's notes).
    named : dict of int to int
        Rows of an id whose rows are not all polygons (so not one area): row -> k, the row read as ``<id>@k``.
    """

    later: frozenset = frozenset()
    united: dict = dataclasses.field(default_factory=dict)
    rows: dict = dataclasses.field(default_factory=dict)
    named: dict = dataclasses.field(default_factory=dict)

    def note(self, oid: str) -> str | None:
        """The note of a building read from several rows of one id (None for a row of its own)."""
        n = self.rows.get(oid)
        return None if n is None else (f"{n} rows of one OpenStreetMap id (a multipolygon split into its polygons, as "
                                       f"ogr2ogr -explodecollections writes it), read as one building")


def osm_pieces(path: Path, layer: str, column: str | None = None) -> OsmPieces:
    """The rows of a converted OpenStreetMap layer that share an element id (:class:`OsmPieces`); with ``column``,
    those of any layer that share its value (the parts of a 3D BAG building: :class:`Bag3D`)."""
    st = Path(path).stat()
    return _osm_pieces_of(str(path), st.st_size, st.st_mtime_ns, layer, column)


@functools.lru_cache(maxsize=8)
def _osm_pieces_of(path: str, size: int, mtime: int, layer: str, column: str | None) -> OsmPieces:
    from meshsom.osm import osm_row_id

    rows_of: dict[str, list[int]] = {}
    for index, props in enumerate(_attributes(Path(path), layer, osm=column is None)):
        oid = osm_row_id(props, layer) if column is None else (None if props.get(column) is None else
                                                                  str(props[column]))
        if oid is not None:
            rows_of.setdefault(oid, []).append(index)
    repeated = {oid: rows for oid, rows in rows_of.items() if len(rows) > 1}
    if not repeated:
        return OsmPieces()
    parquet = _is_parquet(Path(path))
    shapes = _row_shapes(Path(path), layer, {i for rows in repeated.values() for i in rows})
    later, united, counts, named = set(), {}, {}, {}
    for oid, rows in repeated.items():
        polygons = _polygons_of([shapes.get(i) for i in rows])
        if polygons is None:  # not all areas: each row read as a feature of its own
            named.update({i: k for k, i in enumerate(rows[1:], 2)})
            continue
        import shapely
        from shapely.geometry import mapping

        whole = shapely.MultiPolygon(polygons)
        united[rows[0]] = shapely.to_wkb(whole) if parquet else mapping(whole)
        later.update(rows[1:])
        counts[oid] = len(rows)
    return OsmPieces(frozenset(later), united, counts, named)


def _row_shapes(path: Path, layer: str, wanted: set[int]) -> dict[int, object]:
    """Shapely geometries of some rows (from 0) of a layer; a row whose geometry cannot be read is left out."""
    import shapely
    from shapely.geometry import shape

    found = {}
    if _is_parquet(path):
        import pyarrow.parquet as pq

        column, meta = _parquet_geo(path)
        encoding = str(meta.get("encoding", "WKB"))
        values = pq.read_table(path, columns=[column]).column(0).to_pylist()
        for i in sorted(wanted):
            try:
                wkb = values[i] if encoding.upper() == "WKB" else _geoarrow_wkb(values[i], encoding, str(path))
                found[i] = shapely.from_wkb(wkb) if wkb is not None else None
            except (InputFileError, shapely.errors.GEOSException):
                continue
        return found
    try:
        with _open(path, layer) as collection:
            for index, feature in enumerate(collection):
                if index in wanted:
                    try:
                        found[index] = shape(feature.geometry) if feature.geometry is not None else None
                    except Exception:  # damaged: the piece's own reading says so
                        continue
    except _gdal_errors() as err:
        raise _gdal_error(path, err) from None
    return found


def _polygons_of(shapes: list) -> list | None:
    """The polygons of some geometries, where each is a non-empty (Multi)Polygon; else None."""
    polygons = []
    for g in shapes:
        if g is None or g.is_empty or g.geom_type not in ("Polygon", "MultiPolygon"):
            return None
        polygons.extend([g] if g.geom_type == "Polygon" else list(g.geoms))
    return polygons


def _parquet_geo(path: Path) -> tuple[str, dict]:
    """The primary geometry column of a GeoParquet file and its metadata."""
    import pyarrow.parquet as pq

    try:
        schema = pq.read_schema(path)
    except (OSError, ValueError) as err:
        raise InputFileError(str(path), f"cannot be read as Parquet ({type(err).__name__}: {str(err)[:200]})") from None
    raw = (schema.metadata or {}).get(b"geo")
    if raw is None:  # Parquet's own geometry type, or a query's WKB column
        found = _parquet_native_geometry(path) or _parquet_wkb_column(path, schema)
        if found is None:
            raise InputFileError(str(path), "is Parquet without geometry: no GeoParquet metadata (a \"geo\" key), no "
                                            "column of Parquet's GEOMETRY or GEOGRAPHY type, and no binary column named "
                                            f"{', '.join(WKB_COLUMNS)} holding WKB")
        return found
    try:
        geo = json.loads(raw)
        column = geo["primary_column"]
        meta = geo["columns"][column]
    except (ValueError, KeyError, TypeError):
        raise InputFileError(str(path), "has GeoParquet metadata without a primary column's entry") from None
    encoding = str(meta.get("encoding", "WKB"))
    if encoding.upper() != "WKB" and encoding.lower() not in GEOARROW_ENCODINGS:
        raise InputFileError(str(path), f"stores its geometry as {encoding!r}; GeoParquet is read with WKB or a "
                                        f"native (GeoArrow) encoding: {', '.join(GEOARROW_ENCODINGS)}")
    return column, meta


#: Names of a WKB column in Parquet that declares no geometry (a query's output: DuckDB's ``ST_AsWKB(geometry)``),
#: looked for in this order.
WKB_COLUMNS = ("geometry", "geom", "wkb_geometry", "the_geom", "wkb", "geometry_wkb")


@functools.lru_cache(maxsize=16)
def _native_geometry_of(path: str, size: int, mtime: int) -> tuple | None:
    import pyarrow.parquet as pq

    pf = pq.ParquetFile(path)
    for i in range(len(pf.schema)):
        column = pf.schema.column(i)
        text = str(column.logical_type)
        if column.max_repetition_level or "." in column.path or not text.startswith(("Geometry(", "Geography(")):
            continue
        crs = text[text.index("(crs=") + 5:-1]
        if text.startswith("Geography("):
            crs = crs.rsplit(", algorithm=", 1)[0]
        if crs.startswith("srid:"):
            crs = f"EPSG:{crs[5:]}"
        elif crs.startswith("projjson:"):  # a key of the file's metadata holds it
            crs = ((pf.metadata.metadata or {}).get(crs[9:].encode()) or b"").decode() or None
        meta = {"encoding": "WKB"}
        if crs:
            meta["crs"] = crs  # else OGC:CRS84, as Parquet's specification says
        return column.path, meta
    return None


def _parquet_native_geometry(path: Path) -> tuple[str, dict] | None:
    """The first top-level column of Parquet's own GEOMETRY or GEOGRAPHY logical type (Parquet 2.11, GeoParquet 2.0:
    WKB with the CRS in the type, ``srid:<code>``, PROJJSON, ``projjson:<key>`` of the file's metadata, or none:
    OGC:CRS84), as :func:`_parquet_geo` gives it; None where there is none."""
    st = Path(path).stat()
    return _native_geometry_of(str(path), st.st_size, st.st_mtime_ns)


def _parquet_wkb_column(path: Path, schema) -> tuple[str, dict] | None:
    """A binary column of :data:`WKB_COLUMNS` whose first value (among the first :data:`PLANNER_ROWS`) is WKB (shapely
    reads it), as :func:`_parquet_geo` gives it, its CRS unknown (``degrees``: its first footprint lies within +/-180
    and +/-90, so it is read as WGS 84, noted: :func:`_parquet_layers`); None where there is none. Looked for once
    per process and file."""
    import pyarrow as pa

    binary = tuple(name for name in schema.names
                   if pa.types.is_binary(schema.field(name).type) or pa.types.is_large_binary(schema.field(name).type))
    st = Path(path).stat()
    return _wkb_column_of(str(path), st.st_size, st.st_mtime_ns, binary)


@functools.lru_cache(maxsize=16)
def _wkb_column_of(path: str, size: int, mtime: int, binary: tuple) -> tuple[str, dict] | None:
    import pyarrow.parquet as pq
    import shapely
    from shapely.geometry import mapping

    by_name = {name.lower(): name for name in binary}
    for wanted in WKB_COLUMNS:
        name = by_name.get(wanted)
        if name is None:
            continue
        first, rows = None, 0  # within the first rows, which a copy of a file on object storage holds
        for batch in pq.ParquetFile(path).iter_batches(batch_size=PLANNER_ROWS, columns=[name]):
            first = next((v for v in batch.column(0).to_pylist()[:PLANNER_ROWS - rows] if v is not None), None)
            rows += batch.num_rows
            if first is not None or rows >= PLANNER_ROWS:
                break
        try:
            shape = shapely.from_wkb(first) if first is not None else None
        except shapely.errors.GEOSException:
            continue
        if shape is not None:
            return name, {"encoding": "WKB", "crs": None, "degrees": _within_degrees(mapping(shape))}
    return None


def _geoarrow_wkb(value, encoding: str, where: str) -> bytes | None:
    """A GeoParquet 1.1 native (GeoArrow) geometry as pyarrow gives a row of it (nested lists of coordinates, each
    a struct ``{x, y[, z]}`` or an interleaved list ``[x, y[, z]]``) as WKB; None for a null."""
    import shapely

    if value is None:
        return None

    def xyz(c):
        if isinstance(c, dict):
            return (c["x"], c["y"], c["z"]) if c.get("z") is not None else (c["x"], c["y"])
        return tuple(c)

    def ring(r):
        return [xyz(c) for c in r]

    try:
        kind = encoding.lower()
        if kind == "point":
            geometry = shapely.Point(xyz(value))
        elif kind == "linestring":
            geometry = shapely.LineString(ring(value))
        elif kind == "polygon":
            geometry = shapely.Polygon(ring(value[0]), [ring(r) for r in value[1:]]) if value else shapely.Polygon()
        elif kind == "multipoint":
            geometry = shapely.MultiPoint([xyz(c) for c in value])
        elif kind == "multilinestring":
            geometry = shapely.MultiLineString([ring(r) for r in value])
        else:
            geometry = shapely.MultiPolygon([(ring(p[0]), [ring(r) for r in p[1:]]) for p in value if p])
    except (KeyError, IndexError, TypeError, ValueError, shapely.errors.GEOSException) as err:
        raise InputFileError(where, f"its {encoding} geometry (GeoArrow) cannot be read ({type(err).__name__}: "
                                    f"{str(err)[:80]})") from None
    return shapely.to_wkb(geometry)


def _parquet_layers(path: Path) -> list[Layer]:
    import pyarrow.parquet as pq

    column, meta = _parquet_geo(path)
    if "crs" not in meta:
        crs = GEOPARQUET_DEFAULT_CRS
    elif meta["crs"] is None:
        crs = None
    else:
        crs = meta["crs"] if isinstance(meta["crs"], str) else json.dumps(meta["crs"])
    # a WKB column of no declared CRS (_parquet_wkb_column): WGS 84 where its first footprint is in degrees
    return [Layer(Path(path.name).stem, crs, int(pq.ParquetFile(path).metadata.num_rows), bool(meta.get("degrees")))]


#: Columns whose rows are read across a whole file, not by range (OpenStreetMap's element ids, whose rows a
#: multipolygon's pieces share; building parts; the 3D BAG's roof planes): a GeoParquet file with one is copied whole.
WHOLE_FILE_COLUMNS = PART_COLUMNS + BAG2D_GROUND + ("osm_way_id", "osm_id", "feature_id", "@id", "@type", "element",
                                                     "element_type", "osm_type", "full_id")


def parquet_spans(path: Path, start: int, stop: int) -> list[list[int]] | None:
    """The byte spans of a GeoParquet file that a task reading rows ``start`` to ``stop`` reads: the column chunks of
    its first row groups (of :data:`PLANNER_ROWS` rows, where a file that does not declare its geometry says it by its
    first footprint, :func:`_declares_geometry`) and of the row groups that hold those rows, and everything after the last row group (page indexes, the footer); None where a range task reads more of
    it (not Parquet, or a file with a column of :data:`WHOLE_FILE_COLUMNS`) or it cannot be read.

    Returns
    -------
    list of [int, int] or None
        Byte spans ``[from, to)``, ascending.
    """
    if not _is_parquet(Path(path)):
        return None
    try:
        st = Path(path).stat()
        groups, size = _parquet_groups(str(path), st.st_size, st.st_mtime_ns)
    except Exception:  # unreadable: its reader says why
        return None
    if groups is None:
        return None
    groups, declared = groups
    spans, firsts = [], 0
    for g, (begin, end, rows) in enumerate(groups):
        if firsts < PLANNER_ROWS and not declared or firsts < stop and firsts + rows > start:
            spans.append([begin, end])
        firsts += rows
    return spans + [[max([end for _, end, _ in groups] + [0]), size]]


@functools.lru_cache(maxsize=8)
def _parquet_groups(path: str, size: int, mtime: int) -> tuple[tuple | None, int]:
    """A Parquet file's row groups as (first byte, end, rows), and whether it declares its geometry
    (:func:`_declares_geometry`), read once per process and file (the planner asks once per range); None where it has
    a column of :data:`WHOLE_FILE_COLUMNS`."""
    import pyarrow.parquet as pq

    pf = pq.ParquetFile(path)
    if set(pf.schema_arrow.names) & set(WHOLE_FILE_COLUMNS):
        return None, size
    return (_row_group_spans(pf.metadata), _declares_geometry(pf)), size


def _declares_geometry(pf) -> bool:
    """Whether a Parquet file's metadata says which its geometry column is and its CRS (GeoParquet metadata, a
    column of Parquet's GEOMETRY or GEOGRAPHY type): else its first footprint is read to find them
    (:func:`_parquet_wkb_column`)."""
    return b"geo" in (pf.metadata.metadata or {}) or any(
        str(pf.schema.column(k).logical_type).startswith(("Geometry(", "Geography(")) for k in range(len(pf.schema)))


def _chunk_span(chunk) -> tuple[int, int]:
    """A column chunk's bytes ``[from, to)``: from its dictionary page where it has one."""
    begin = chunk.dictionary_page_offset if chunk.has_dictionary_page and chunk.dictionary_page_offset else \
        chunk.data_page_offset
    return int(begin), int(begin + chunk.total_compressed_size)


def _row_group_spans(meta) -> tuple:
    """(first byte, end, rows) of each row group of a Parquet file's metadata."""
    groups = []
    for g in range(meta.num_row_groups):
        group = meta.row_group(g)
        spans = [_chunk_span(group.column(k)) for k in range(group.num_columns)]
        begin = min([a for a, _ in spans] or [0])
        groups.append((begin, max([begin] + [b for _, b in spans]), int(group.num_rows)))
    return tuple(groups)


#: Rows of a GeoParquet file without GeoParquet metadata whose WKB column (:data:`WKB_COLUMNS`) the planner may read,
#: to find its first footprint (:func:`_parquet_wkb_column`): its first row groups'.
PLANNER_ROWS = 1024


def planner_columns(options) -> tuple[str, ...]:
    """The columns of a GeoParquet file the planner reads in every row: the candidate ids
    (:attr:`meshsom.io.ReaderOptions.id_attributes`: which is unique, :func:`gis_ranges`), and those that say a
    file holds building parts (:func:`meshsom.part_files.pair`: Overture's ``id`` and ``building_id``, OpenStreetMap's
    part tags)."""
    from meshsom.part_files import BUILDING_ID, OWN_ID

    return tuple(dict.fromkeys((*options.id_attributes, OWN_ID, BUILDING_ID, *PART_COLUMNS, "building", "osm_way_id",
                                "feature_id")))


def parquet_planned_spans(source, size: int, columns: Sequence[str]) -> list[list[int]] | None:
    """The byte spans of a GeoParquet file that the planner reads, found from its footer alone (a file on object
    storage: a range request or two, :func:`meshsom.mirror.open_bytes`): its magic number, the column chunks of
    ``columns`` in every row group, those of a WKB column (:data:`WKB_COLUMNS`) in its first row groups (at least
    :data:`PLANNER_ROWS` rows) where no metadata says which its geometry is, and everything after the last row
    group (page indexes, the footer). A column is named by its top-level name (its nested columns follow it).

    Parameters
    ----------
    source : str or Path
        The file, or its URL.
    size : int
        Its size in bytes.
    columns : sequence of str
        :func:`planner_columns`.

    Returns
    -------
    list of [int, int] or None
        Byte spans ``[from, to)``, ascending and merged; None where it cannot be read as Parquet (copied whole: its
        reader says why).
    """
    import pyarrow.parquet as pq

    from meshsom.mirror import HEAD_BYTES, open_bytes

    try:
        with open_bytes(source, HEAD_BYTES) as fh:
            pf = pq.ParquetFile(fh)
            meta, declared = pf.metadata, _declares_geometry(pf)
    except Exception:  # not Parquet, damaged, gone: copied whole, and read or refused as any input
        return None
    groups = _row_group_spans(meta)
    spans, rows = [[0, 4]], 0  # the magic number, which says its kind

    def named(path: str, names) -> bool:
        return any(path.lower() == w.lower() or path.lower().startswith(f"{w.lower()}.") for w in names)

    for g in range(len(groups)):
        wanted = tuple(columns) + (WKB_COLUMNS if rows < PLANNER_ROWS and not declared else ())
        group = meta.row_group(g)
        spans += [list(_chunk_span(c)) for c in (group.column(k) for k in range(group.num_columns))
                  if named(c.path_in_schema, wanted)]
        rows += group.num_rows
    spans.append([max([end for _, end, _ in groups] + [4]), size])
    merged = []
    for a, b in sorted(spans):
        if merged and a <= merged[-1][1]:
            merged[-1][1] = max(merged[-1][1], b)
        else:
            merged.append([a, b])
    return merged


def _parquet_records(path: Path, id_field: str | None, start: int, stop: int | None
                     ) -> Iterator[tuple[str, dict, bytes | None]]:
    """Rows ``start`` to ``stop`` (from 0) of a GeoParquet file, read from the row group that holds
    ``start`` on (a range task does not decode the rows before it)."""
    import pyarrow.parquet as pq

    from meshsom.osm import osm_row_id, osm_properties

    column, meta = _parquet_geo(path)
    encoding = str(meta.get("encoding", "WKB"))
    native = encoding.lower() in GEOARROW_ENCODINGS
    stem = Path(path.name).stem  # the layer's name
    pf = pq.ParquetFile(path)
    sizes = [pf.metadata.row_group(g).num_rows for g in range(pf.metadata.num_row_groups)]
    firsts = np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64)
    group = max(int(np.searchsorted(firsts, start, side="right")) - 1, 0)
    if group >= len(sizes):
        return
    row = int(firsts[group])  # rows counted from 0; ids from 1
    pieces = None
    end = len(sizes) if stop is None else max(int(np.searchsorted(firsts, stop, side="left")), group + 1)
    for batch in pf.iter_batches(batch_size=BATCH_FEATURES, row_groups=range(group, min(end, len(sizes)))):
        first = row
        row += batch.num_rows
        if row <= start:
            continue
        skip = max(start - first, 0)
        if stop is not None:
            batch = batch.slice(0, max(min(stop - first, batch.num_rows), 0))
        for k, values in enumerate(batch.slice(skip).to_pylist(), first + skip + 1):
            wkb = values.pop(column, None)
            values = osm_properties(values)
            oid = osm_row_id(values, stem)
            native_row = native  # a row's own GeoArrow value (a united one is WKB)
            if oid is not None:  # an exploded multipolygon's rows: read as one building, by its first row
                pieces = osm_pieces(path, stem) if pieces is None else pieces
                if k - 1 in pieces.later:
                    continue
                if k - 1 in pieces.united:
                    wkb, native_row = pieces.united[k - 1], False
                oid = f"{oid}@{pieces.named[k - 1]}" if k - 1 in pieces.named else oid
            oid = oid or str(values.get(id_field) if id_field else k)
            if native_row:
                try:
                    wkb = _geoarrow_wkb(wkb, encoding, f"{path.name}#{oid}")
                except InputFileError as err:
                    wkb = err  # refused by its reading (_feature_meshes), with the problem
            yield oid, values, wkb
        if stop is not None and row >= stop:
            return
