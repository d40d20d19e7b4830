"""Reading meshes: every format trimesh reads, CityJSON 1.0 to 2.0, CityJSONSeq, CityGML
(:mod:`meshsom.citygml`) and GeoJSON / JSON-FG (:mod:`meshsom.geojson`), plain or gzipped; GIS files
(GeoPackage, Shapefile, FileGDB, FlatGeobuf, GeoJSONSeq, GeoParquet: :mod:`meshsom.gis`), 3D Tiles
(:mod:`meshsom.tiles3d`) and zip archives of any (:mod:`meshsom.archives`); every building in
metres, whatever its file's CRS (:mod:`meshsom.crs`).

A reader turns one input file into a stream of :class:`RawMesh` (one per
building or mesh object) and :class:`Rejection` (an object, or the whole file,
that could not be read, with the reason). Nothing is dropped silently: every
object the reader is asked for comes out as one or the other.

Coordinates are re-centred per mesh in float64 *before* anything else: a mesh's
``vertices`` are relative to its ``origin``, so national grids (Swiss LV95 has
2.6e6 m offsets) keep millimetre precision when later cast to float32. For
CityJSON the centre is taken on the integer grid, so the re-centring is exact.

Why our own CityJSON reader rather than cjio: cjio builds a full object model
of the city (Python objects per surface and vertex) and pulls in its own
dependency set; ingestion needs only the building boundaries as index arrays,
which a direct walk of the JSON gives with one NumPy gather per building. The
reader follows the CityJSON 1.0, 1.1 and 2.0 specifications for the parts it
uses (transform, Solid, MultiSolid, CompositeSolid, MultiSurface, GeometryInstance,
CompositeSurface, holes, LoD, BuildingPart parents/children), and CityJSON Text
Sequences (CityJSONSeq, ``.city.jsonl``: a header line, then one CityJSONFeature per
line, read a line at a time so a whole city never sits in memory at once).

Any input may be gzip-compressed (``tile.city.json.gz``, the form the 3D BAG serves its
tiles in; ``.obj.gz``): it is recognised by its content, and decompressed under the size
guards of :class:`ReaderOptions`.
"""

from __future__ import annotations

import contextlib
import csv
import dataclasses
import gzip
import io
import json
import math
import os
import re
import zlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Iterator
from urllib.parse import urlparse

import numpy as np

from meshsom.errors import InputFileError
from meshsom.gltf_compression import decompress_glb, needs_rewriting
from meshsom.polygons import extrude_polygon, triangulate_polygon_3d, triangulate_polygons_3d

if TYPE_CHECKING:
    from meshsom.crs import CoordinateSystem

#: Up axes of mesh files (:attr:`ReaderOptions.up_axis`).
UP_AXES = ("auto", "z", "y")
#: The header comments of the OBJ exporters that write y up by default (Blender's: Forward -Z, Up Y; SketchUp's:
#: "Swap YZ coordinates"), in the file's first :data:`OBJ_HEADER_BYTES` (:func:`up_axis_note`).
_OBJ_Y_UP_WRITERS = re.compile(rb"^#[ \t]*(?:Exported from )?(Blender|SketchUp)\b", re.MULTILINE)
OBJ_HEADER_BYTES = 1024
#: A glTF document's ``"generator": "..."`` (:func:`gltf_generator`).
_GLTF_GENERATOR = re.compile(rb'"generator"\s*:\s*"((?:[^"\\]|\\.)*)"')
#: The note on a glTF file turned to z up by its specification's axes (``up_axis: auto``).
GLTF_Y_UP_NOTE = ("glTF is y up by its specification: turned to z up (corpus.reader.up_axis: z, or --up z, reads it "
                  "as it is)")
#: Units a footprint's height attributes may be given in (:attr:`ReaderOptions.height_unit`): metres per unit
#: (the international foot; the US survey foot; centimetres as San Francisco's ``hgt_maxcm``).
HEIGHT_UNITS = {"m": 1.0, "ft": 0.3048, "us-ft": 1200 / 3937, "dm": 0.1, "cm": 0.01, "mm": 0.001}

#: Metres per unit of the units a mesh file that names none may be in (:attr:`ReaderOptions.unit`): CAD and BIM
#: tools (Revit, Rhino, SketchUp's model units, cjio's STL of CityJSON's integer millimetres) often write mm.
MESH_UNITS = {"m": 1.0, "dm": 0.1, "cm": 0.01, "mm": 0.001, "ft": 0.3048, "in": 0.0254}

#: Mesh files that name no unit (COLLADA without ``<unit>`` too): read in :attr:`ReaderOptions.unit`, metres when
#: unset. glTF is metres by its specification, yet CAD tools write millimetres in it too: counted here.
UNITLESS_MESH_TYPES = ("obj", "ply", "stl", "off", "glb", "gltf")

#: The largest extent (metres, along any axis) of one building: a mesh that spans more is refused as no building
#: in metres (a file in millimetres read as metres spans 1,000 times its size; a district in one mesh). The
#: largest buildings on earth stay under it: the tallest, Burj Khalifa, is 828 m; the longest, Prora on Rugen
#: (eight blocks in a row), 4.5 km, the largest footprints (Boeing's Everett factory, airport terminals) 1 to 2 km;
#: a house of 5 m or more written in millimetres exceeds it.
MAX_BUILDING_EXTENT_M = 5000.0
#: IFC element classes (with their subclasses) whose solids make a building's envelope
#: (:mod:`meshsom.ifc`; ``ReaderOptions.ifc_classes``). Classes a file's schema lacks (``IfcChimney``
#: in IFC2X3) are passed over.
IFC_ENVELOPE_CLASSES = (
    "IfcWall", "IfcSlab", "IfcRoof", "IfcCurtainWall", "IfcPlate", "IfcMember", "IfcWindow", "IfcDoor",
    "IfcColumn", "IfcBeam", "IfcCovering", "IfcChimney", "IfcBuildingElementProxy", "IfcStair",
    "IfcStairFlight", "IfcRamp", "IfcRampFlight", "IfcShadingDevice",
)
#: IFC files: STEP physical files (``.ifc``, gzipped too) and IFC-ZIP archives.
IFC_SUFFIXES = (".ifc", ".ifczip")
#: File name endings read by trimesh.
TRIMESH_SUFFIXES = (".obj", ".ply", ".stl", ".off", ".glb", ".gltf", ".dae")
#: File name endings read as CityJSON (a ``.json`` holding a GeoJSON / JSON-FG Feature or
#: FeatureCollection is read as :mod:`meshsom.geojson`).
CITYJSON_SUFFIXES = (".city.json", ".json", ".cityjson", ".geojson")
#: File name endings read as CityGML (:mod:`meshsom.citygml`).
CITYGML_SUFFIXES = (".gml", ".citygml")
#: XML files read as CityGML where they declare its namespace (some states save their CityGML tiles as ``.xml``).
XML_SUFFIX = ".xml"
#: A 3D Tiles tileset's file name: in a folder, the content under its folder (and nested
#: tilesets) is read through it, not on its own.
TILESET_NAME = "tileset.json"
TILES_CONTENT_SUFFIXES = (".b3dm", ".glb", ".gltf", ".pnts", ".i3dm", ".cmpt", ".subtree", ".bin")
#: The files that come with a shapefile (``x.shp``), read with it.
SHAPEFILE_SIDECARS = (".dbf", ".shx", ".prj", ".cpg", ".qix", ".sbn", ".sbx", ".qmd")
#: The files a MapInfo table (``.tab``) or interchange file (``.mif``) is read with.
MAPINFO_SIDECARS = {".dat": ".tab", ".map": ".tab", ".id": ".tab", ".ind": ".tab", ".mid": ".mif"}
#: File name endings read as CityJSON Text Sequences (CityJSONSeq).
CITYJSONSEQ_SUFFIXES = (".city.jsonl", ".jsonl")
#: A readable name followed by this is a gzip-compressed input (gzip data is recognised by its
#: content whatever the name).
GZIP_SUFFIX = ".gz"
#: Rhino models (:mod:`meshsom.rhino`) and DXF drawings (:mod:`meshsom.dxf`).
RHINO_SUFFIX = ".3dm"
DXF_SUFFIX = ".dxf"
#: FBX scenes (:mod:`meshsom.fbx`) and 3D Studio files (:mod:`meshsom.three_ds`).
FBX_SUFFIX = ".fbx"
THREE_DS_SUFFIX = ".3ds"
#: USD stages (:mod:`meshsom.usd`): either encoding (.usd), text (.usda), crate (.usdc), zipped (.usdz).
USD_SUFFIXES = (".usd", ".usda", ".usdc", ".usdz")
#: 3MF packages (:mod:`meshsom.threemf`).
THREEMF_SUFFIX = ".3mf"
#: X3D (XML and classic encodings) and VRML97 scenes (:mod:`meshsom.x3d`), and their gzipped names (.x3dz, .x3dvz,
#: .wrz: gzip is recognised by the content, as for any input).
X3D_SUFFIXES = (".x3d", ".x3dv", ".wrl", ".x3dz", ".x3dvz", ".wrz")
#: OpenStreetMap extracts (:mod:`meshsom.osm`).
OSM_SUFFIXES = (".osm", ".osm.pbf", ".osm.bz2")
GZIP_MAGIC = b"\x1f\x8b"
#: Bytes decompressed per read of a gzip input (the size guards are checked between reads).
GZIP_CHUNK_BYTES = 1 << 20
#: Decompressed bytes a gzip input may always reach, whatever its compression ratio
#: (:attr:`ReaderOptions.max_expansion` applies above this).
GZIP_FREE_BYTES = 1 << 20
SUPPORTED_CITYJSON_VERSIONS = ("1.0", "1.1", "2.0")
#: CityJSON's drafts (2017-2019; the Munich and Rotterdam samples of its specification, 3DBAG's and
#: cities' early exports), read as 1.0: their geometry is encoded the same way (boundaries, Solid,
#: MultiSurface, "lod" a number, "transform"). Up to 0.2 the document's "type" is "CityModel" and
#: its "version" a URL (``http://www.cityjson.org/version/0.1``) or missing.
DRAFT_CITYJSON_VERSIONS = ("0.1", "0.2", "0.3", "0.4", "0.5", "0.6", "0.7", "0.8", "0.9")
#: Largest integer CityJSON coordinate taken (exact in float64, no int64 overflow in re-centring).
MAX_GRID_COORDINATE = 2**53
LOD_CHOICES = ("highest", "lowest")
PARTS_CHOICES = ("merge", "separate")
SURFACE_TYPES = ("MultiSurface", "CompositeSurface")
SOLID_TYPES = ("Solid",)
MULTISOLID_TYPES = ("MultiSolid", "CompositeSolid")
#: CityJSON's semantic surface types of a building's openings (a geometry's ``semantics.surfaces[values...]``): their
#: polygons (frames, glass, recessed panes; a window body flush with its wall) are not the envelope. They are left out,
#: counted in a note (:func:`meshsom.citygml.openings_note`, CityGML's ``bldg:Window`` / ``bldg:Door`` are left out
#: alike), and the holes they fill are closed by preprocessing's planar caps where the walls leave them open.
OPENING_SURFACES = ("Window", "Door")


@dataclass(frozen=True)
class ReaderOptions:
    """How inputs are read.

    Attributes
    ----------
    lod : str
        "highest", "lowest", or an exact LoD such as "1", "2" or "2.2" (CityJSON). "highest" and
        "lowest" choose among a building's LoDs of 1 and above when it has any (LoD 0 is a
        footprint, not a volume); LoD 0 is read when asked for by name ("0").
    parts : str
        "merge": one mesh per Building with its BuildingParts merged in;
        "separate": one mesh per Building geometry and one per BuildingPart.
    extrude_lod1 : bool
        Replace each building by the extrusion of its footprint (union of all
        its polygons seen from above) from its lowest to its highest point: a
        closed LoD1 block from LoD2 data, or from LoD1 data that is open.
    label_attribute : str
        CityJSON attribute holding a label (the synthetic corpus's family).
    object_types : tuple of str
        CityJSON object types taken as buildings.
    footprint_grid : float
        Grid (metres) on which the footprint union is computed (GEOS snap-rounding): edges of
        roof polygons that miss each other by less than this are joined, so seams leave no
        slivers or pin-holes. A footprint polygon narrower than the grid vanishes; anything wider
        (a 2 m² shed) is kept. The default is the millimetre grid of most CityJSON files.
    footprint_seam_width : float
        A hole of the footprint union narrower than this (metres; mean width, 2 x area /
        perimeter) is a seam between roof polygons that miss each other, not a courtyard, and is
        filled. Real courtyards are metres wide; the seams of real LoD2 data are below 1 mm.
    footprint_simplify : float
        Tolerance (metres) with which extruded footprints are simplified.
    max_vertices : int
        Refuse a file declaring more vertices than this (memory guard); in a CityJSONSeq file,
        a feature declaring more.
    max_bytes : int
        Refuse a file whose content (decompressed) is larger than this (memory guard: a CityJSON
        file is parsed whole, about 10 times its size in memory). A CityJSONSeq file is read a
        line at a time, so only a single line is held to this.
    max_expansion : float
        Refuse a gzip input that decompresses to more than this many times its compressed size
        (plus :data:`GZIP_FREE_BYTES`): real CityJSON and meshes compress 5 to 30 times, a
        decompression bomb a thousand times. Checked as it decompresses, so a bomb is refused
        having allocated at most this many times its compressed size (a CityJSONSeq file: one
        line's worth).
    crs : str or None
        The CRS of inputs that declare none (OBJ, PLY, a CityJSON file without
        ``metadata.referenceSystem``, GML without ``srsName``), as pyproj reads it (``"EPSG:4979"``,
        ``"EPSG:2263"``). A CRS a file declares is used for that file. Geographic coordinates are
        converted to metres about each building's centre, feet to metres (:mod:`meshsom.crs`).
    height_attributes : tuple of str
        GeoJSON footprints (:mod:`meshsom.geojson`): the properties that may hold a building's
        height (of its top, metres above the ground), the first present used.
    base_attributes : tuple of str
        The properties that may hold the height of its bottom above the ground (0 when absent; a
        building on stilts, a bridge's deck). The ground is the footprint's lowest z, else 0.
    levels_attributes : tuple of str
        The properties that may hold a storey count, used (times ``storey_height``) where no
        height is given.
    min_levels_attributes : tuple of str
        The properties that may hold the storeys below its bottom (OpenStreetMap's
        ``building:min_level``, Overture's ``min_floor``: a bridge's deck, an overhang), used
        (times ``storey_height``) where no base height is given.
    height_unit : str or None
        The unit of the height attributes (height, base, ``roof:height``) of footprints: one of
        :data:`HEIGHT_UNITS` (``"ft"`` for New York's building footprints as GeoJSON, whose
        ``heightroof`` is in feet while their coordinates are degrees); None (the default): the
        CRS's vertical unit (feet for EPSG:2263), metres for geographic and unknown CRSs. A value
        written with its unit (``"40 ft"``, ``"12 m"``) is read in that unit.
    storey_height : float
        Metres per storey.
    default_height : float or None
        Footprints (GeoJSON, GIS files, OpenStreetMap, KML; CityJSON / CityGML buildings of a LoD 0
        footprint only) with neither a height nor a storey count (a storey count of 0 is no storey):
        extruded to this many metres above their base, noted (OpenStreetMap maps most buildings
        without either); None (the default) lists them as rejections naming the properties.
    roofs : bool
        Footprints (GeoJSON, GIS files, OpenStreetMap): build the roof their roof attributes
        describe (OpenStreetMap's ``roof:shape``, ``roof:height``, ...; Overture's ``roof_shape``,
        ``roof_height``, ...; :mod:`meshsom.roofs`) on the block, up to the building's height
        (default True); False extrudes every footprint flat (LoD 1).
    part_files : tuple of str
        Files of building parts whose buildings are in :attr:`building_files` (Overture's
        ``building_part``, naming its building by ``building_id``; :mod:`meshsom.part_files`): a
        building with parts there is read as its parts, and a part file yields only the parts of
        no building. Set by ``meshsom ingest`` / ``meshsom run`` from the inputs
        (:func:`meshsom.part_files.pair`); default none.
    building_files : tuple of str
        The footprint files whose buildings the parts of :attr:`part_files` belong to.
    layer : str or None
        GIS files (:mod:`meshsom.gis`: GeoPackage, FileGDB, ...): the layer to read; None reads
        every layer with geometry.
    id_attributes : tuple of str
        GIS files: the properties that may hold a building's id, the first whose values are given
        and unique over the layer used (else GDAL's feature id).
    up_axis : str
        The up axis of mesh files (OBJ, PLY, STL, OFF, glTF), which do not say it: "z" (as city
        models are), or "y" (glTF by its specification, and many OBJ exports from Blender, SketchUp
        or game tools): their coordinates are then turned a quarter about x, (x, y, z) -> (x, -z, y),
        so that z is up. "auto" (the default): glTF files y (their specification's axes, as Blender,
        CityEngine, FME and Sketchfab write them), noted, but for those trimesh wrote (its
        ``asset.generator``: trimesh writes the coordinates it is given, z up); OBJ files Blender or
        SketchUp wrote (their header comment) y, noted, as their exporters write by default; other
        mesh files z (:func:`up_axis_note`).
    unit : str or None
        The unit of mesh files that name none (OBJ, PLY, STL, OFF, glTF, COLLADA without ``<unit>``): one of
        :data:`MESH_UNITS` (``"mm"`` for CAD exports in millimetres); their coordinates are scaled to metres,
        noted. None (the default): metres. Any building spanning more than :data:`MAX_BUILDING_EXTENT_M` is
        refused, with a hint at this option where its file names no unit.
    split_components : bool
        Mesh files (OBJ, PLY, STL, OFF, glTF), Rhino objects and DXF meshes and blocks (not a
        Rhino group, which is one building by its maker's choice): each mesh (object, node) is split into its connected
        pieces (faces joined through vertices at the same position), one building each, as a city
        exported as one mesh (an STL or PLY of a district) needs; a piece gets the id ``mesh#cN``
        (N from 1, in the order of its first face). Default False: a file or object is one
        building, whatever its pieces (an annex that does not touch the house stays its shell).
    ifc_classes : tuple of str
        IFC files (:mod:`meshsom.ifc`): the element classes, with their subclasses, whose solids
        are united into each IfcBuilding's envelope (default :data:`IFC_ENVELOPE_CLASSES`: walls,
        slabs, roofs, curtain walls, windows, doors, columns, beams, stairs, ...; never spaces,
        furniture, building services or the site).
    ifc_gap : float
        IFC files: gaps between elements narrower than this (metres) are closed (each element is
        grown by half of it before the union, the union shrunk back by as much); 0 keeps every
        gap (a hairline between a wall and the roof then leads into the attic).
    """

    lod: str = "highest"
    parts: str = "merge"
    extrude_lod1: bool = False
    label_attribute: str = "family"
    object_types: tuple[str, ...] = ("Building",)
    footprint_grid: float = 0.001
    footprint_seam_width: float = 0.01
    footprint_simplify: float = 0.01
    max_vertices: int = 50_000_000
    max_bytes: int = 4 << 30
    max_expansion: float = 200.0
    crs: str | None = None
    height_attributes: tuple[str, ...] = ("height", "measuredHeight", "building:height")
    base_attributes: tuple[str, ...] = ("min_height", "building:min_height")
    levels_attributes: tuple[str, ...] = ("building:levels", "num_floors", "storeysAboveGround", "numberOfFloorsAboveGround")
    min_levels_attributes: tuple[str, ...] = ("building:min_level", "min_floor")
    height_unit: str | None = None
    storey_height: float = 3.0
    default_height: float | None = None
    roofs: bool = True
    part_files: tuple[str, ...] = ()
    building_files: tuple[str, ...] = ()
    layer: str | None = None
    id_attributes: tuple[str, ...] = ("id", "gml_id", "identificatie", "osm_id")
    up_axis: str = "auto"
    unit: str | None = None
    split_components: bool = False
    ifc_classes: tuple[str, ...] = IFC_ENVELOPE_CLASSES
    ifc_gap: float = 0.01

    def __post_init__(self):
        if self.parts not in PARTS_CHOICES:
            raise ValueError(f"parts must be one of {', '.join(PARTS_CHOICES)}; received {self.parts!r}")
        if self.lod not in LOD_CHOICES:
            try:
                float(self.lod)
            except (TypeError, ValueError):
                raise ValueError(
                    f"lod must be one of {', '.join(LOD_CHOICES)} or a LoD number like '2.2'; received {self.lod!r}"
                ) from None
        if self.footprint_simplify < 0:
            raise ValueError(f"footprint_simplify must be >= 0, received {self.footprint_simplify}")
        if not self.footprint_seam_width >= 0:
            raise ValueError(f"footprint_seam_width must be >= 0 (metres), received {self.footprint_seam_width}")
        if not self.footprint_grid >= 0:
            raise ValueError(f"footprint_grid must be >= 0 (metres; 0 computes the union in full precision), received {self.footprint_grid}")
        if self.up_axis not in UP_AXES:
            raise ValueError(f"up_axis must be one of {', '.join(UP_AXES)}; received {self.up_axis!r}")
        if self.unit is not None and self.unit not in MESH_UNITS:
            raise ValueError(f"unit must be one of {', '.join(MESH_UNITS)} or null (metres), received {self.unit!r}")
        if self.height_unit is not None and self.height_unit not in HEIGHT_UNITS:
            raise ValueError(f"height_unit must be one of {', '.join(HEIGHT_UNITS)} or null (the CRS's vertical unit), "
                             f"received {self.height_unit!r}")
        if not self.storey_height > 0:
            raise ValueError(f"storey_height must be > 0 (metres), received {self.storey_height}")
        if self.default_height is not None and not (isinstance(self.default_height, (int, float)) and 0 < self.default_height < math.inf):
            raise ValueError(f"default_height must be a height > 0 (metres) or null, received {self.default_height!r}")
        if not isinstance(self.roofs, bool):
            raise ValueError(f"roofs must be true or false, received {self.roofs!r}")
        for name in ("part_files", "building_files"):
            value = getattr(self, name)
            if not (isinstance(value, tuple) and all(isinstance(v, str) for v in value)):
                raise ValueError(f"{name} must be a list of file paths, received {value!r}")
        if self.layer is not None and not (isinstance(self.layer, str) and self.layer.strip()):
            raise ValueError(f"layer must be a layer's name (or null for every layer), received {self.layer!r}")
        if not self.max_bytes > 0:
            raise ValueError(f"max_bytes must be > 0, received {self.max_bytes}")
        if self.crs is not None:
            from meshsom.crs import UnknownCRS, coordinate_system

            try:
                coordinate_system(self.crs)
            except UnknownCRS as err:
                raise ValueError(f"crs: {err}") from None
        if not self.ifc_classes or not all(isinstance(c, str) and c.lower().startswith("ifc") for c in self.ifc_classes):
            raise ValueError(f"ifc_classes must be a non-empty list of IFC class names such as IfcWall, "
                             f"received {self.ifc_classes!r}")
        if not (self.ifc_gap >= 0 and math.isfinite(self.ifc_gap)):
            raise ValueError(f"ifc_gap must be >= 0 (metres), received {self.ifc_gap}")
        if not self.max_expansion >= 1:
            raise ValueError(f"max_expansion must be >= 1 (decompressed / compressed size), received {self.max_expansion}")


@dataclass(frozen=True)
class RawMesh:
    """A mesh as read, before preprocessing.

    Attributes
    ----------
    id : str
        Stable id: the file's path relative to the input root (the folder given, or the file's
        own folder for a file given by name), plus ``#object`` for objects inside a file.
    source : str
        The file it came from.
    vertices : (V, 3) float64
        Coordinates relative to ``origin``.
    faces : (F, 3) int64
    origin : (3,) float64
        World position of the local origin.
    label : str or None
    lod : str or None
    parts : tuple of str
        The CityJSON objects (Building, BuildingParts) whose geometry the mesh holds, when more
        than one: preprocessing unites them (:mod:`meshsom.union`). Empty otherwise.
    face_part : (F,) int64 or None
        Index into ``parts`` of every face's object; None when ``parts`` is empty.
    notes : tuple of str
        What the reader changed or left out, in words (recorded in the manifest).
    """

    id: str
    source: str
    vertices: np.ndarray = field(repr=False)
    faces: np.ndarray = field(repr=False)
    origin: np.ndarray = field(repr=False)
    label: str | None = None
    lod: str | None = None
    parts: tuple[str, ...] = ()
    face_part: np.ndarray | None = field(default=None, repr=False)
    notes: tuple[str, ...] = ()


@dataclass(frozen=True)
class Rejection:
    """An input that could not be read, and why."""

    id: str
    source: str
    reason: str
    faces_in: int = 0
    label: str | None = None


def recentre(vertices: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Move a mesh's bounding-box centre to the origin, in float64.

    Parameters
    ----------
    vertices : (V, 3) float64

    Returns
    -------
    local : (V, 3) float64
    origin : (3,) float64
    """
    vertices = np.asarray(vertices, np.float64)
    if len(vertices) == 0:
        return vertices.reshape(0, 3), np.zeros(3)
    finite = np.isfinite(vertices).all(axis=1)
    if not finite.any():
        return vertices, np.zeros(3)
    origin = (vertices[finite].min(axis=0) + vertices[finite].max(axis=0)) / 2
    return vertices - origin, origin


def format_name(path: Path) -> str:
    """The file name that says its format: the name, less a final ``.gz``, in lower case."""
    name = path.name.lower()
    return name[: -len(GZIP_SUFFIX)] if name.endswith(GZIP_SUFFIX) else name


def input_kind(path: Path) -> str:
    """'cityjson', 'cityjsonseq', 'citygml', 'gis', 'b3dm', 'zip', 'kml', 'slpk', '3dm', 'dxf', 'osm', 'ifc', 'fbx', '3ds', 'usd',
    '3mf', 'x3d' or 'trimesh' by file name (a final ``.gz`` aside); InputFileError for anything else."""
    from meshsom.gis import CSV_GEOMETRY_COLUMNS, CSV_SUFFIX, GIS_SUFFIXES, csv_geometry_column
    from meshsom.tiles3d import B3DM_SUFFIXES

    name = format_name(path)
    if name.endswith(GIS_SUFFIXES):
        return "gis"
    if name.endswith(CSV_SUFFIX):  # footprints as WKT (Google's Open Buildings), else not an input (labels.csv)
        try:
            if csv_geometry_column(path) is not None:
                return "gis"
        except InputFileError:
            return "gis"  # damaged gzip data: an input that its reader refuses, saying why
        raise InputFileError(str(path), f"is a CSV file without a geometry column (one named "
                                        f"{', '.join(CSV_GEOMETRY_COLUMNS)}, any case, holding footprints as WKT) "
                                        f"or lines of GeoJSON features")
    if name.endswith(B3DM_SUFFIXES):
        return "b3dm"
    if name.endswith((".zip", ".kmz")):  # a KMZ: a zip of a KML placemark and its COLLADA models
        return "zip"
    if name.endswith(".kml") and name == path.name.lower():  # a KML beside the models it places
        return "kml"
    if name.endswith(".slpk"):  # an Esri scene layer package (I3S)
        return "slpk"
    if name.endswith(RHINO_SUFFIX):
        return "3dm"
    if name.endswith(DXF_SUFFIX):
        return "dxf"
    if name.endswith(OSM_SUFFIXES):
        return "osm"
    if name.endswith(CITYJSONSEQ_SUFFIXES):
        return "cityjsonseq"
    if name.endswith(CITYJSON_SUFFIXES):
        return "cityjson"
    if name.endswith(TRIMESH_SUFFIXES):
        return "trimesh"
    if name.endswith(FBX_SUFFIX):
        return "fbx"
    if name.endswith(THREE_DS_SUFFIX):
        return "3ds"
    if name.endswith(USD_SUFFIXES):
        return "usd"
    if name.endswith(THREEMF_SUFFIX):
        return "3mf"
    if name.endswith(X3D_SUFFIXES):
        return "x3d"
    if name.endswith(IFC_SUFFIXES):
        return "ifc"
    if name.endswith(CITYGML_SUFFIXES):
        from meshsom.inspire import is_inspire, is_ogr_gml

        # INSPIRE's and GDAL's own GML (ogr2ogr -f GML): footprints, through GDAL
        return "gis" if name.endswith(".gml") and (is_inspire(path) or is_ogr_gml(path)) else "citygml"
    if name.endswith(XML_SUFFIX):  # CityGML saved as .xml (Hamburg's LoD 2 tiles), by its namespace
        from meshsom.inspire import CITYGML, SNIFF_BYTES, _head

        if CITYGML.search(_head(path)):
            return "citygml"
        raise InputFileError(str(path), f"is an XML file that is not CityGML (no CityGML namespace in its first "
                                        f"{SNIFF_BYTES // 1024} kB: metadata, or another format); expected CityGML")
    suffix = Path(name).suffix + (GZIP_SUFFIX if name != path.name.lower() else "")
    way = CONVERSIONS.get(Path(name).suffix)
    raise InputFileError(str(path), f"unknown file type {suffix or '(no extension)'!r}{f' ({way})' if way else ''}; "
                                    f"expected one of {readable_types()}")


def readable_types() -> str:
    """The file types meshsom reads, in words (rejections of unknown types, lists of skipped files)."""
    from meshsom.gis import GIS_SUFFIXES
    from meshsom.tiles3d import B3DM_SUFFIXES

    readable = TRIMESH_SUFFIXES + (".city.json", ".json", ".city.jsonl", ".geojson") + CITYGML_SUFFIXES + (
        ".xml (CityGML)",) + B3DM_SUFFIXES + (
        ".zip", ".kmz", ".kml", ".slpk", RHINO_SUFFIX, DXF_SUFFIX, FBX_SUFFIX, THREE_DS_SUFFIX) + USD_SUFFIXES + (
        THREEMF_SUFFIX,) + X3D_SUFFIXES + OSM_SUFFIXES + IFC_SUFFIXES
    return (f"{', '.join(readable)}, each possibly followed by {GZIP_SUFFIX}, or a GIS file: {', '.join(GIS_SUFFIXES)}, "
            f".csv (footprints as WKT, also gzipped)")


def _gzip_limit(path: Path, compressed: int, options: ReaderOptions) -> int:
    return int(min(options.max_bytes, options.max_expansion * compressed + GZIP_FREE_BYTES))


def _too_large(path: Path, limit: int, compressed: int | None, options: ReaderOptions, what: str = "content") -> InputFileError:
    if compressed is not None and limit < options.max_bytes:
        return InputFileError(
            str(path), f"gzip data expands to more than {limit:,} bytes, over {options.max_expansion:g} times its "
            f"{compressed:,} compressed bytes (a decompression bomb?; ReaderOptions.max_expansion)")
    return InputFileError(str(path), f"{what} is larger than {options.max_bytes:,} bytes (ReaderOptions.max_bytes)"
                          + ("; CityJSONSeq (.city.jsonl, e.g. from `cjseq cat`) is read a line at a time" if what == "content" else ""))


def _gzip_error(path: Path, err: Exception) -> InputFileError:
    if isinstance(err, EOFError):
        return InputFileError(str(path), "gzip data ends early (a truncated download?)")
    return InputFileError(str(path), f"is not valid gzip data ({type(err).__name__}: {err})")


def read_input_bytes(path: Path, options: ReaderOptions = ReaderOptions()) -> bytearray:
    """The whole content of an input file, decompressed when it is gzip data (:func:`open_input`).

    Raises
    ------
    InputFileError
        The file is empty, larger than ``options.max_bytes`` (decompressed), expands more than
        ``options.max_expansion`` times, or is corrupt or truncated gzip data.
    """
    if path.stat().st_size > options.max_bytes:
        raise _too_large(path, options.max_bytes, None, options)
    data = bytearray()
    with open_input(path, options) as stream:
        while chunk := stream.read(GZIP_CHUNK_BYTES):
            data += chunk
            if len(data) > options.max_bytes:
                raise _too_large(path, options.max_bytes, None, options)
    if not data:
        raise InputFileError(str(path), "file is empty (gzip data of no bytes)")
    return data


class _GuardedStream(io.RawIOBase):
    """A binary stream over gzip data that refuses to expand beyond ``limit`` bytes (see
    :attr:`ReaderOptions.max_expansion`)."""

    def __init__(self, stream, path: Path, limit: int, compressed: int, options: ReaderOptions):
        self.stream, self.path, self.limit, self.compressed, self.options = stream, path, limit, compressed, options
        self.total = 0

    def readable(self) -> bool:
        return True

    def readinto(self, buffer) -> int:
        try:
            data = self.stream.read(min(len(buffer), GZIP_CHUNK_BYTES))
        except (OSError, EOFError, zlib.error) as err:
            raise _gzip_error(self.path, err) from None
        self.total += len(data)
        if self.total > self.limit:
            raise _too_large(self.path, self.limit, self.compressed, self.options)
        buffer[:len(data)] = data
        return len(data)


@contextlib.contextmanager
def open_input(path: Path, options: ReaderOptions = ReaderOptions()) -> Iterator[io.BufferedIOBase]:
    """A binary stream of an input file's content, decompressed when it is gzip data (by its first
    bytes), for readers that parse as they read (nothing is held whole).

    Raises
    ------
    InputFileError
        The file is empty; while reading, gzip data that expands more than
        ``options.max_expansion`` times, or is corrupt or truncated.
    """
    size = path.stat().st_size
    if size == 0:
        raise InputFileError(str(path), "file is empty")
    with open(path, "rb") as fh:
        compressed = fh.read(2) == GZIP_MAGIC
        fh.seek(0)
        if not compressed:
            yield fh
            return
        with gzip.GzipFile(fileobj=fh, mode="rb") as gz:
            yield io.BufferedReader(_GuardedStream(gz, path, _gzip_limit(path, size, options), size, options))


def input_lines(path: Path, options: ReaderOptions = ReaderOptions(),
                byte_range: tuple[int, int, int] | None = None) -> Iterator[tuple[int, bytes | None]]:
    """The lines of an input file, numbered from 1, read one at a time (gzip data decompressed).

    A line longer than ``options.max_bytes`` is passed over without being held, and given as None.

    Parameters
    ----------
    path : Path
    options : ReaderOptions
    byte_range : (start, stop, first_line), optional
        Only the lines that start at byte offsets ``start <= offset < stop`` of a file that is not
        gzip (``start`` a line's start, as :func:`cityjsonseq_ranges` gives it), numbered from
        ``first_line``.

    Raises
    ------
    InputFileError
        The file is empty, gzip data expands more than ``options.max_expansion`` times in all, or
        is corrupt or truncated.
    """
    if byte_range is None:
        with open_input(path, options) as stream:
            yield from _numbered_lines(stream, options, 1, None)
        return
    start, stop, first = byte_range
    with open(path, "rb") as stream:
        stream.seek(start)
        yield from _numbered_lines(stream, options, first, stop - start)


def _numbered_lines(stream, options: ReaderOptions, first: int, left: int | None) -> Iterator[tuple[int, bytes | None]]:
    number = first - 1
    while left is None or left > 0:  # a line in pieces, so that neither a long line nor a bomb is held whole
        pieces, length = [], 0
        while piece := stream.readline(GZIP_CHUNK_BYTES):
            length += len(piece)
            if length <= options.max_bytes:
                pieces.append(piece)
            else:
                pieces = None
            if piece.endswith(b"\n"):
                break
        if not length:
            return
        if left is not None:
            left -= length
        number += 1
        yield number, None if pieces is None else b"".join(pieces)


#: A ``.jsonl`` file up to this size (on disk) whose first line is not JSON is tried as one JSON
#: document written across lines (:func:`_one_json_document`).
ONE_DOCUMENT_BYTES = 64 << 20
#: Bytes read at a time when :func:`cityjsonseq_ranges` counts lines.
COUNT_CHUNK_BYTES = 16 << 20


def cityjsonseq_ranges(path: Path, target_bytes: int, options: ReaderOptions = ReaderOptions()
                       ) -> list[tuple[int, int, int]] | None:
    """Split a large CityJSONSeq file into byte ranges of whole lines, each for one read task.

    Parameters
    ----------
    path : Path
    target_bytes : int
        About the size of a range (a range ends at the first line end past it).
    options : ReaderOptions

    Returns
    -------
    list of (start, stop, first_line) or None
        Ranges covering every line after the header line once, in order, for
        :func:`read_file` (``byte_range``); None when the file is smaller than twice
        ``target_bytes``, gzip (not seekable), or does not start with its header line.
    """
    size = path.stat().st_size
    if target_bytes < 1 or size < 2 * target_bytes:
        return None
    with open(path, "rb") as fh:
        if fh.read(2) == GZIP_MAGIC:
            return None
        fh.seek(0)
        header = fh.readline(options.max_bytes + 1)
        if not header.strip() or not header.endswith(b"\n"):
            return None
        starts = [fh.tell()]
        while starts[-1] + target_bytes < size:
            fh.seek(starts[-1] + target_bytes - 1)
            fh.readline()  # to the end of the line that holds the target
            if fh.tell() >= size:
                break
            starts.append(fh.tell())
    numbers = line_numbers(path, starts)
    stops = starts[1:] + [size]
    return [(a, b, n) for a, b, n in zip(starts, stops, numbers)]


def holds_match(path: Path, pattern: re.Pattern, step: int) -> bool:
    """Whether a file's bytes (gzip data decompressed: :func:`open_input`) hold a match of ``pattern`` (of at most 256
    bytes): one pass, ``step`` bytes at a time, matches across their joins found; False where it cannot be read (its
    reader says why)."""
    try:
        tail = b""
        with open_input(Path(path)) as stream:
            while chunk := stream.read(step):
                if pattern.search(tail + chunk):
                    return True
                tail = chunk[-256:]
    except (OSError, InputFileError):
        pass
    return False


def line_numbers(path: Path, offsets: list[int]) -> list[int]:
    """The line (from 1) each of a file's byte ``offsets`` (ascending) is on: one pass counting line ends."""
    numbers, counted, offset = [], 0, 0
    with open(path, "rb") as fh:
        for start in offsets:
            while offset < start:
                chunk = fh.read(min(COUNT_CHUNK_BYTES, start - offset))
                if not chunk:
                    break
                counted += chunk.count(b"\n")
                offset += len(chunk)
            numbers.append(counted + 1)
    return numbers


@dataclass(frozen=True)
class InputFile:
    """A file to read and the name its mesh ids start with.

    Attributes
    ----------
    path : Path
    name : str
        The path relative to the input root, with ``/`` separators: relative to the folder that
        was given (``sub/folder/file.city.json``), or the file name for a file given by itself.
    """

    path: Path
    name: str


def expand_inputs(inputs: list[str | os.PathLike],
                  skipped: list[tuple[str, str]] | None = None) -> tuple[list[InputFile], list[Rejection]]:
    """Turn files and folders into the list of files to read, each with its id prefix.

    Folders are searched recursively for known file types (other files in them
    are not read: with ``skipped``, each is listed there with the reason; so is a tileset's content
    and a model a KML file of the folder places, both read through the file that holds or places
    them: :func:`meshsom.kml.read_kml`). A path that does not
    exist, a file named explicitly with an unknown type, or a file in a folder
    that is a link to somewhere outside that folder, is a rejection.

    Parameters
    ----------
    inputs : list of path
    skipped : list, optional
        Receives ``(path, why)`` for every file in a folder that is not read.

    Returns
    -------
    files : list of InputFile
        Sorted within each folder, in input order otherwise.
    rejections : list of Rejection

    Raises
    ------
    InputFileError
        When two files would give their meshes the same ids (the same name relative to their
        input roots, e.g. ``a/x.obj`` and ``b/x.obj`` given as two files, or one file given
        twice), naming both.
    """
    files: list[InputFile] = []
    rejected: list[Rejection] = []
    for item in inputs:
        p = Path(item)
        if p.is_dir() and not _is_gdb(p):
            found = []
            root = p.resolve()
            tilesets = sorted((t.parent for t in p.rglob(TILESET_NAME)), key=lambda t: (len(t.parts), t))  # outermost first
            entries = sorted(p.rglob("*"))
            placed = _kml_models(entries)
            read_through = {model: f"placed by a KML Model of {kml}" for model, kml in placed.items()}
            read_through.update({twin: f"the glTF twin of a COLLADA model placed by {kml}" for model, kml in placed.items()
                                 for twin in _gltf_twins(model) if twin not in read_through})
            read_through.update({scene: f"inlined by the scene {by}" for scene, by in _inlined_scenes(entries).items()
                                 if scene not in read_through})
            for q in entries:
                if any(_is_gdb(p / d) for d in q.relative_to(p).parents if d != Path(".")):
                    continue  # inside a File Geodatabase: the folder is read as one input
                owner = next((t for t in tilesets if q.is_relative_to(t) and q != t / TILESET_NAME), None)
                if owner is not None and (q.suffix.lower() in TILES_CONTENT_SUFFIXES or q.name == TILESET_NAME):
                    if skipped is not None:
                        skipped.append((str(q), f"content of the 3D Tiles tileset {owner / TILESET_NAME}, read through it"))
                    continue
                if q.is_file() and q.resolve() in read_through:
                    if skipped is not None:
                        skipped.append((str(q), f"{read_through[q.resolve()]}, read through it"))
                    continue
                if q.is_file() or _is_gdb(q):
                    try:
                        input_kind(q)
                    except InputFileError as err:
                        if skipped is not None:
                            table = MAPINFO_SIDECARS.get(q.suffix.lower())
                            why = ("mesh labels, read with the meshes" if q.name == "labels.csv" else
                                   f"read with the shapefile {q.with_suffix('.shp').name}" if (
                                       q.suffix.lower() in SHAPEFILE_SIDECARS and q.with_suffix(".shp").is_file())
                                   else f"read with the MapInfo file {q.with_suffix(table).name}" if (
                                       table and (q.with_suffix(table).is_file() or q.with_suffix(table.upper()).is_file()))
                                   else err.problem)
                            skipped.append((str(q), why))
                        continue
                    if not q.resolve().is_relative_to(root):
                        rejected.append(Rejection(str(q), str(q), f"is a link to {q.resolve()}, outside the folder {p}; not followed"))
                        continue
                    found.append(InputFile(q, q.relative_to(p).as_posix()))
            if not found:
                rejected.append(Rejection(str(p), str(p), "folder holds no readable mesh or CityJSON file"))
            files.extend(found)
        elif p.is_file() or _is_gdb(p):
            try:
                input_kind(p)
            except InputFileError as err:
                rejected.append(Rejection(str(p), str(p), err.problem))
                continue
            files.append(InputFile(p, p.name))
        else:
            rejected.append(Rejection(str(p), str(p), "no such file or folder"))
    first: dict[str, Path] = {}
    for f in files:
        if f.name in first:
            raise InputFileError(
                str(f.path), f"its mesh ids would start with {f.name!r}, as those of {first[f.name]} do; ids must be "
                f"unique (give the folder that holds both, so ids carry the sub-folders, or rename one)",
            )
        first[f.name] = f.path
    return files, rejected


def _kml_models(entries: list[Path]) -> dict[Path, str]:
    """The files of a folder that its KML files place (:func:`meshsom.kml.linked_models`), resolved,
    each with the path of the (first) KML that places it: they are read through the KML."""
    from meshsom.kml import KML_SUFFIX, linked_models

    found: dict[Path, str] = {}
    for kml in entries:
        if kml.suffix.lower() == KML_SUFFIX and kml.is_file():
            for model in linked_models(kml):
                found.setdefault(model, str(kml))
    return found


#: The suffixes of the glTF files 3DCityDB writes beside each COLLADA model of a KML/COLLADA/glTF export.
GLTF_TWIN_SUFFIXES = (".gltf", ".glb")


def _gltf_twins(model: Path) -> list[Path]:
    """The glTF files of the same stem beside a COLLADA model (3DCityDB's export writes a ``.gltf`` beside each
    ``.dae`` its KML places: the same building, listed as skipped rather than read, or refused as glTF 1.0, again)."""
    if model.suffix.lower() != ".dae":
        return []
    return [twin.resolve() for twin in (model.with_suffix(s) for s in GLTF_TWIN_SUFFIXES) if twin.is_file()]


def _inlined_scenes(entries: list[Path]) -> dict[Path, str]:
    """The files of a folder that its X3D and VRML scenes inline (:func:`meshsom.x3d.inlined_files`), resolved, each
    with the path of the (first) scene that inlines it: they are read through that scene. A scene inlined by
    another scene that is itself inlined is read through the outermost one only."""
    from meshsom.x3d import inlined_files

    found: dict[Path, str] = {}
    for scene in entries:
        if scene.is_file() and format_name(scene).endswith(X3D_SUFFIXES):
            for inlined in inlined_files(scene, ReaderOptions()):
                if inlined != scene.resolve():
                    found.setdefault(inlined, str(scene))
    cyclic = set()
    for inlined in found:  # scenes that inline each other are each read (their reading refuses the loop), not lost
        seen, by = {inlined}, Path(found[inlined]).resolve()
        while by in found and by not in seen:
            seen.add(by)
            by = Path(found[by]).resolve()
        if by == inlined:
            cyclic.add(inlined)
    return {inlined: by for inlined, by in found.items() if inlined not in cyclic}


def _is_gdb(path: Path) -> bool:
    """Whether ``path`` is an Esri File Geodatabase: a folder named ``*.gdb``, read as one input."""
    return path.name.lower().endswith(".gdb") and path.is_dir()


def read_file(
    path: str | os.PathLike, options: ReaderOptions = ReaderOptions(), name: str | None = None,
    byte_range: tuple[int, int, int] | None = None, feature_range: list | None = None,
) -> Iterator[RawMesh | Rejection]:
    """Read every mesh of one file.

    A file that cannot be read at all yields one Rejection whose id is ``name``
    (the path when no name is given); a CityJSON object that cannot be read
    yields a Rejection for that object and the reader goes on with the others.

    Ids are unique: an object whose id an earlier one of the file has (a building repeated in a
    CityJSONSeq made of overlapping tiles, a ``gml:id`` given twice) is a Rejection with the id
    ``"<id> (2)"`` (:func:`free_id`: the next number no earlier item has) and that reason; the
    first is read.

    Parameters
    ----------
    path : path
    options : ReaderOptions
    name : str, optional
        The start of the mesh ids (:attr:`InputFile.name`); default: the file name.
    byte_range : (start, stop, first_line), optional
        A CityJSONSeq file only: read the features on the lines of this range
        (:func:`cityjsonseq_ranges`), ids unique within it; a range without buildings yields nothing.
        For a GeoJSON FeatureCollection, ``(start, stop, first, open, close)`` of
        :func:`meshsom.geojson.geojson_ranges`: the features of that range. For a CityGML file, the six of
        :func:`meshsom.citygml.citygml_ranges`: the Buildings of that range's members.
    feature_range : list, optional
        A GIS file only: read the features of this range (:func:`meshsom.gis.gis_ranges`).
    """
    seen: set[str] = set()
    for item in _read_file(Path(path), options, name, byte_range, feature_range):
        if item.id in seen:
            item = repeated(item, free_id(item.id, seen))
        seen.add(item.id)
        yield item


def free_id(item_id: str, taken: set) -> str:
    """``"<item_id> (k)"`` with the smallest k >= 2 that is not in ``taken``: the id of a repeat."""
    k = 2
    while f"{item_id} ({k})" in taken:
        k += 1
    return f"{item_id} ({k})"


def repeated(item: RawMesh | Rejection, new_id: str) -> Rejection:
    """The Rejection of an object whose id an earlier object of its file has, under ``new_id``."""
    reason = item.reason if isinstance(item, Rejection) else (
        f"id repeated: an earlier object of the file has the id {item.id!r}; the later one is not read")
    return Rejection(new_id, item.source, reason, 0, item.label)


def _read_file(path: Path, options: ReaderOptions, name: str | None, byte_range, feature_range=None
               ) -> Iterator[RawMesh | Rejection]:
    try:
        kind = input_kind(path)
        if kind == "cityjson" and byte_range is not None:  # a range of a large GeoJSON FeatureCollection
            from meshsom.geojson import read_geojson_range

            yield from read_geojson_range(path, options, name, byte_range)
        elif kind == "cityjson":
            yield from read_cityjson(path, options, name)
        elif kind == "cityjsonseq":
            yield from read_cityjsonseq(path, options, name, byte_range)
        elif kind == "citygml":
            from meshsom.citygml import read_citygml

            yield from read_citygml(path, options, name, byte_range)
        elif kind == "gis":
            from meshsom.gis import read_gis

            yield from read_gis(path, options, name, feature_range)
        elif kind == "b3dm":
            from meshsom.tiles3d import read_b3dm

            yield from read_b3dm(path, options, name)
        elif kind == "ifc":
            from meshsom.ifc import read_ifc

            yield from read_ifc(path, options, name)
        elif kind == "zip":
            from meshsom.archives import read_zip

            yield from read_zip(path, options, name)
        elif kind == "kml":
            from meshsom.kml import read_kml

            yield from read_kml(path, options, name)
        elif kind == "slpk":
            from meshsom.i3s import read_slpk

            yield from read_slpk(path, options, name)
        elif kind == "3dm":
            from meshsom.rhino import read_3dm

            yield from read_3dm(path, options, name)
        elif kind == "dxf":
            from meshsom.dxf import read_dxf

            yield from read_dxf(path, options, name)
        elif kind == "osm":
            from meshsom.osm import read_osm

            yield from read_osm(path, options, name, feature_range)
        elif kind == "fbx":
            from meshsom.fbx import read_fbx

            yield from read_fbx(path, options, name)
        elif kind == "3ds":
            from meshsom.three_ds import read_3ds

            yield from read_3ds(path, options, name)
        elif kind == "usd":
            from meshsom.usd import read_usd

            yield from read_usd(path, options, name)
        elif kind == "3mf":
            from meshsom.threemf import read_3mf

            yield from read_3mf(path, options, name)
        elif kind == "x3d":
            from meshsom.x3d import read_x3d

            yield from read_x3d(path, options, name)
        else:
            yield from read_trimesh(path, name, options)
    except InputFileError as err:
        yield Rejection(name or str(path), str(path), err.problem)


def library_input(path: Path, options: ReaderOptions, what: str, module: str, package: str) -> tuple[object, bool]:
    """The library ``module`` that reads a file of ``what`` format by opening it itself, and whether the file is
    gzipped (then :func:`read_decompressed`).

    Raises
    ------
    InputFileError
        The library is not installed (naming the ``package`` to install), or the file is larger than
        ``options.max_bytes``.
    """
    import importlib

    try:
        library = importlib.import_module(module)
    except ImportError:
        raise InputFileError(str(path), f"reading {what} needs {package} (pip install {package}), which is not "
                                        f"installed") from None
    size = path.stat().st_size
    if size > options.max_bytes:
        raise InputFileError(str(path), f"is {size:,} bytes, more than max_bytes ({options.max_bytes:,})")
    with open(path, "rb") as fh:
        return library, fh.read(len(GZIP_MAGIC)) == GZIP_MAGIC


def read_decompressed(path: Path, options: ReaderOptions, name: str | None, reader) -> Iterator[RawMesh | Rejection]:
    """The items of a gzipped file read by ``reader(plain, options, name)``, a reader that opens files itself (USD,
    assimp): its content, decompressed under the guards of :func:`read_input_bytes`, in a temporary file of its name
    less ``.gz`` (removed afterwards); each item's source is ``path``, and a rejection's reason names ``path`` where
    it named the temporary file."""
    import tempfile

    with tempfile.TemporaryDirectory() as folder:
        plain = Path(folder) / path.name.removesuffix(GZIP_SUFFIX).removesuffix(GZIP_SUFFIX.upper())
        plain.write_bytes(read_input_bytes(path, options))
        for item in reader(plain, options, name or path.name):
            yield dataclasses.replace(item, source=str(path), **(
                {"reason": item.reason.replace(str(plain), str(path))} if isinstance(item, Rejection) else {}))


def _labels_beside(path: Path) -> dict[str, str]:
    table = path.parent / "labels.csv"
    if not table.is_file():
        return {}
    try:
        with open(table, newline="", encoding="utf-8-sig") as fh:
            return {
                str(row["file"]): str(row["label"])
                for row in csv.DictReader(fh)
                if row.get("file") is not None and row.get("label") is not None
            }
    except (UnicodeDecodeError, csv.Error) as err:
        raise InputFileError(
            str(path), f"the {table.name} beside it is not a readable CSV table of file,label ({type(err).__name__}: {err})"
        ) from None


#: Why a glTF 1.0 file (COLLADA2GLTF before 2.0, 3DCityDB's glTF export) is refused.
GLTF_1_PROBLEM = ("is glTF 1.0, which is not read: convert it to glTF 2.0 (gltf-pipeline -i f.gltf -o f.glb), or read "
                  "the COLLADA beside it (3DCityDB writes both)")
#: The first bytes of a glTF JSON file searched for its ``asset.version`` (writers put ``asset`` first or last: a
#: file whose asset comes later is left to trimesh, which refuses version 1 in its own words).
GLTF_VERSION_BYTES = 1 << 20
_GLTF_1_DICTIONARIES = re.compile(rb'"(?:accessors|bufferViews|meshes|nodes)"\s*:\s*\{')
_GLTF_ASSET_VERSION = re.compile(rb'"asset"\s*:\s*\{[^{}]*?"version"\s*:\s*"?(\d+)')


def _gltf_1(head: bytes) -> bool:
    """Whether a glTF JSON file is version 1.0 by its first bytes: its ``asset.version`` is 1, or (no version found)
    its accessors, buffer views, meshes or nodes are dictionaries (1.0's ids), as 2.0's arrays never are."""
    found = _GLTF_ASSET_VERSION.search(head)
    return found.group(1) == b"1" if found else bool(_GLTF_1_DICTIONARIES.search(head))


def _compressed_gltf(content: bytes) -> bool:
    """Whether a glTF JSON file declares Draco or meshopt compression (read by packing it into a GLB:
    :func:`meshsom.gltf_compression.pack_gltf`); False for JSON that cannot be read (trimesh says what is wrong)."""
    try:
        document = json.loads(content.decode("utf-8-sig"))
    except (ValueError, UnicodeDecodeError):
        return False
    return needs_rewriting(document) if isinstance(document, dict) else False


def read_trimesh(path: Path, name: str | None = None, options: ReaderOptions = ReaderOptions()) -> Iterator[RawMesh]:
    """Read OBJ, PLY, STL, OFF, GLB or glTF through trimesh (gzipped or not: ``house.obj.gz``).

    A scene yields one mesh per geometry node, with the node's transform
    applied, id ``name#node`` (``name`` defaults to the file name; a glTF node's mesh of several
    primitives, one per material, is one mesh); so does an OBJ of several
    objects (``o`` lines: a city's buildings), one mesh per object, and an OBJ of several groups
    (``g``) and no objects when every group is closed on its own (:func:`_closed_groups`). Objects of one name that
    are versions of one building (the LoDs ``cjio export obj`` / ``export glb`` write under a building's id: each
    closed, each overlapping the most detailed; :mod:`meshsom.mesh_versions`) are read as the one
    :attr:`ReaderOptions.lod` asks for, noted; a glTF node of no name is named by its mesh. Coordinates are in
    :attr:`ReaderOptions.unit` (metres by default; COLLADA's ``<unit>`` where it says one), and a mesh spanning more
    than :data:`MAX_BUILDING_EXTENT_M` is refused (:func:`extent_problem`). Labels come from a
    ``labels.csv`` (columns ``file``, ``label``; ``file#node`` for one object of a file) in the
    same folder, when there is one.

    Materials and textures are not loaded (only geometry is used), and the
    external files a glTF names (buffers) are looked up by :class:`FolderResolver`,
    inside the file's own folder only.
    """
    import trimesh

    from meshsom.gltf_compression import quantum_in_frame
    from meshsom.tiles3d import DRACO_WELD_NOTE

    file_type = Path(format_name(path)).suffix.lstrip(".")
    # In memory: a length field claiming more than the file holds (a GLB chunk of 4 GB) then
    # reads what there is, where a read from the file would first allocate the claimed size.
    content = read_input_bytes(path, options)
    if file_type != "glb" and content.startswith(UTF8_BOM):  # Windows tools start text with one: not a vertex line
        content = content[len(UTF8_BOM):]
    up_notes = () if options.up_axis != "auto" else up_axis_note(file_type, bytes(content[:1 << 20]))
    turn_up = options.up_axis == "y" or bool(up_notes)  # y up, said or seen (auto)
    if file_type == "obj":
        if _OBJ_ZERO_INDEX.search(content):  # trimesh would take vertex 0 for the last one
            said = _bad_vertex_reference(bytes(content), "obj") or "a face refers to vertex 0 (OBJ counts from 1)"
            raise InputFileError(str(path), f"{said} (a 0-based export?)")
        content = triangulated_obj(bytes(content)) or content
    elif file_type == "off":
        content = triangulated_off(bytes(content)) or content
    elif file_type == "ply":
        content = triangulated_ply(bytes(content)) or content
    elif file_type == "glb":  # Draco, meshopt: plain accessors (meshsom.gltf_compression)
        content = decompress_glb(bytes(content), str(path))
    elif file_type == "gltf" and _compressed_gltf(bytes(content)):  # packed with its buffers into a GLB, decoded
        from meshsom.gltf_compression import pack_gltf

        content = decompress_glb(pack_gltf(bytes(content), FolderResolver(path.parent, str(path)), str(path)), str(path))
        file_type = "glb"
    if file_type == "gltf" and _gltf_1(bytes(content[:GLTF_VERSION_BYTES])):  # a GLB of version 1: decompress_glb
        raise InputFileError(str(path), GLTF_1_PROBLEM)
    if file_type in ("glb", "gltf"):
        from meshsom.tiles3d import content_meshes, is_tile_content

        if is_tile_content(bytes(content), str(path)):  # 3D Tiles content saved as a file: by batch, RTC centre
            if file_type == "gltf":
                from meshsom.gltf_compression import pack_gltf

                content = pack_gltf(bytes(content), FolderResolver(path.parent, str(path)), str(path))
            yield from content_meshes(bytes(content), str(path), f"{name or path.name}#", options, b3dm=False)
            return
        from meshsom.tiles3d import instanced_gltf  # EXT_mesh_gpu_instancing: a node per instance

        content, file_type, _ = instanced_gltf(content, file_type, FolderResolver(path.parent, str(path)), str(path))
    data = io.BytesIO(content)
    try:
        # an OBJ of a city holds one object ("o") per building: one mesh each, whatever the
        # materials (a building's roof and walls often have their own)
        per_object = {"split_objects": True, "group_material": False} if file_type == "obj" else {}
        loaded = trimesh.load(
            data, file_type=file_type, resolver=FolderResolver(path.parent, str(path)),
            process=False, force=None, skip_materials=True, **per_object,
        )
        if file_type == "obj" and isinstance(loaded, trimesh.Trimesh):
            loaded = _closed_groups(data, loaded)
    except InputFileError:
        raise
    except Exception as err:  # trimesh raises many types for corrupt files (MemoryError and RecursionError included)
        reference = _bad_vertex_reference(bytes(content), file_type) if isinstance(err, (IndexError, ValueError)) else None
        raise InputFileError(str(path), reference or f"cannot be read as .{file_type} ({type(err).__name__}: {err})") from None
    labels = _labels_beside(path)
    label = labels.get(path.name)
    name = name or path.name
    crs = file_crs(None, options)
    mesh_named = _gltf_mesh_names(bytes(content), file_type) if file_type in ("glb", "gltf") else {}
    welded: dict[str, int] = {}
    if isinstance(loaded, trimesh.Scene):
        items, quanta = [], []
        collada_ids = set(re.findall(rb'<geometry\b[^>]*\bid="([^"]+)"', data.getvalue())) if file_type == "dae" else set()
        collada_ids = {i.decode("utf-8", "replace") for i in collada_ids}
        for node in loaded.graph.nodes_geometry:
            transform, geom_name = loaded.graph[node]
            geom = loaded.geometry[geom_name]
            if not isinstance(geom, trimesh.Trimesh):
                continue
            v = trimesh.transformations.transform_points(np.asarray(geom.vertices, np.float64), transform)
            if geom.metadata.get("from_gltf_primitive"):  # one primitive (a material) of a glTF node's mesh: the node's
                node = loaded.graph.transforms.parents.get(node, node)
            elif file_type == "dae":  # trimesh names a COLLADA geometry's primitives (a material each) id, id_1, ...
                node = _collada_geometry(str(node), collada_ids)
            node = mesh_named.get(node, node)
            items.append((f"{name}#{node}", v, np.asarray(geom.faces, np.int64), labels.get(f"{path.name}#{node}", label)))
            quanta.append(quantum_in_frame(getattr(geom, "vertex_attributes", None) or {}, transform))
        items, welded = _joined_by_id(items, quanta)
        if not items:
            raise InputFileError(str(path), "holds no triangle mesh (only points, lines or nothing)")
        if file_type == "obj":  # objects of no faces (only points or lines) are not in the scene
            found = {node for node in loaded.graph.nodes_geometry}
            for obj_name in dict.fromkeys(re.findall(rb"^o[ \t]+(.+?)[ \t]*\r?$", data.getvalue(), re.M)):
                text = obj_name.decode("utf-8", "replace")
                if text not in found:
                    items.append((f"{name}#{text}", np.zeros((0, 3)), np.zeros((0, 3), np.int64), labels.get(f"{path.name}#{text}", label)))
    elif isinstance(loaded, trimesh.Trimesh):
        items = [(name, np.asarray(loaded.vertices, np.float64), np.asarray(loaded.faces, np.int64), label)]
    else:
        raise InputFileError(str(path), f"holds a {type(loaded).__name__}, expected a triangle mesh")
    items, version_notes = _versions_read(items, bytes(content), file_type, name, options)
    unitless = file_type in UNITLESS_MESH_TYPES
    if file_type == "dae":  # COLLADA says its unit and up axis (SketchUp: inches, z up; others: y up)
        to_metres, turn = _collada_frame(data.getvalue())
        unitless = not re.search(rb"<unit\b", data.getvalue()[:1 << 16])
        items = [(i, (v * to_metres) @ turn.T, f, lab) for i, v, f, lab in items]
    unit_notes = ()
    if unitless and options.unit not in (None, "m"):
        items = [(i, np.asarray(v, np.float64) * MESH_UNITS[options.unit], f, lab) for i, v, f, lab in items]
        unit_notes = (f"coordinates read in {options.unit} (corpus.reader.unit, --unit): scaled to metres",)
    land = _3dfier_land(data.getvalue()) if file_type == "obj" else {}
    if land:
        kinds = [land.get(item[0][len(name) + 1:]) for item in items]  # by object name
        for (mesh_id, _, f, item_label), kind in zip(items, kinds):
            if kind is not None:
                yield Rejection(mesh_id, str(path), f"is a 3dfier {kind} object (its material says so), not a building",
                                int(len(f)), item_label)
        items = [item for item, kind in zip(items, kinds) if kind is None]
    if options.split_components:
        items = [piece for item in items for piece in _connected_pieces(*item)]
    for mesh_id, v, f, item_label in items:
        if len(f) == 0:
            if len(items) == 1:
                raise InputFileError(str(path), "holds no faces")
            yield Rejection(mesh_id, str(path), "holds no faces", 0, item_label)
            continue
        if turn_up and file_type != "dae":  # a quarter turn about x: y up -> z up (orientation kept)
            v = np.column_stack([v[:, 0], -v[:, 2], v[:, 1]])
        whole = mesh_id if mesh_id in version_notes or mesh_id in welded else mesh_id.rpartition("#c")[0]
        notes = up_notes + unit_notes + version_notes.get(whole, ())
        if welded.get(whole):
            notes += (DRACO_WELD_NOTE.format(joined=f"{welded[whole]} vertices"),)
        yield placed_mesh(mesh_id, str(path), v, f.reshape(-1, 3), item_label, crs, notes, options, unitless)


#: What a glTF file's ``asset.generator`` says when ``cjio export glb`` wrote it (every LoD of a building in its mesh).
CJIO_GLTF_GENERATOR = "cjio"


def _versions_read(items: list, content: bytes, file_type: str, name: str, options: ReaderOptions
                   ) -> tuple[list, dict[str, tuple[str, ...]]]:
    """Items (id, vertices, faces, label) of a mesh file of which those holding several versions of one building
    (the LoDs of a multi-LoD export: an OBJ's ``o`` blocks of one name, a cjio glTF mesh's runs of closed faces;
    :mod:`meshsom.mesh_versions`) are each replaced by the version :attr:`ReaderOptions.lod` asks for, with the notes
    saying so by id; parts of a building written under one name stay joined."""
    from meshsom.mesh_versions import closed_runs, obj_repeated_objects, one_version

    if file_type == "obj":
        blocks = obj_repeated_objects(content)
        if not blocks:
            return items, {}
        single = len(items) == 1 and len(blocks) == 1 and "#" not in items[0][0][len(name):]
        runs = {(items[0][0] if single else f"{name}#{obj}"): list(np.cumsum(c)) for obj, c in blocks.items()}
        writer = "an OBJ object written once per version: a multi-LoD export, e.g. cjio's"
    elif file_type in ("glb", "gltf") and CJIO_GLTF_GENERATOR in (gltf_generator(content[:1 << 20]) or "").lower():
        runs = {item[0]: closed_runs(item[1], item[2]) for item in items}
        writer = "cjio's glTF export writes every LoD of a building in its mesh"
    else:
        return items, {}
    out, notes = [], {}
    for mesh_id, v, f, lab in items:
        chosen = one_version(np.asarray(v), f, [int(e) for e in runs[mesh_id]], options.lod, writer) \
            if mesh_id in runs else None
        if chosen is None:
            out.append((mesh_id, v, f, lab))
            continue
        out.append((mesh_id, chosen[0], chosen[1], lab))
        notes[mesh_id] = (chosen[2],)
    return out, notes


def _gltf_mesh_names(content: bytes, file_type: str) -> dict[str, str]:
    """trimesh's names of the glTF nodes that have no name of their own (their index) mapped to their mesh's name,
    where that name is given and no other node's (``cjio export glb`` names meshes by building id, not nodes)."""
    try:
        if file_type == "glb":
            length = int.from_bytes(content[12:16], "little")
            document = json.loads(content[20:20 + length].decode("utf-8"))
        else:
            document = json.loads(content.decode("utf-8-sig"))
        nodes, meshes = document.get("nodes") or [], document.get("meshes") or []
        named = {}
        for i, node in enumerate(nodes):
            mesh = node.get("mesh") if isinstance(node, dict) and not node.get("name") else None
            if isinstance(mesh, int) and 0 <= mesh < len(meshes) and isinstance(meshes[mesh], dict):
                mesh_name = meshes[mesh].get("name")
                if isinstance(mesh_name, str) and mesh_name.strip():
                    named[str(i)] = mesh_name
    except (ValueError, UnicodeDecodeError, AttributeError, TypeError):
        return {}
    taken = {n.get("name") for n in nodes if isinstance(n, dict)}
    counts: dict[str, int] = {}
    for mesh_name in named.values():
        counts[mesh_name] = counts.get(mesh_name, 0) + 1
    return {node: mesh_name for node, mesh_name in named.items() if counts[mesh_name] == 1 and mesh_name not in taken
            and mesh_name not in named}


def _collada_geometry(name: str, ids: set) -> str:
    """The COLLADA ``<geometry>`` id of a trimesh geometry named for it (``id``, or ``id_N`` for its N-th material's
    primitive, where ``id_N`` is no geometry id of its own); the name as it is otherwise."""
    base, _, number = name.rpartition("_")
    return base if number.isdigit() and base in ids and name not in ids else name


#: The note on a building of a mesh file whose Draco primitives were welded (:func:`_joined_by_id`).
def _joined_by_id(items: list, quanta: list | None = None) -> tuple[list, dict[str, int]]:
    """Items (id, vertices, faces, label) of one id joined into one, in the order of their first: the primitives of
    a glTF mesh or of a COLLADA geometry (trimesh gives each material's its own geometry) are one building, as the
    node or geometry that holds them.

    Where some of the primitives joined were Draco-quantized (``quanta``, each item's grid step or None;
    :func:`meshsom.gltf_compression.quantum_in_frame`), each on its own grid, their vertices are welded within half a quantum of each
    (:func:`meshsom.tiles3d.weld_quantized`), as the 3D Tiles reader welds a batch's: a building whose floor, roof and
    walls are separate primitives closes again. Returns the items and, by id, the vertices so joined."""
    joined: dict[str, list] = {}
    for item, quantum in zip(items, quanta or [None] * len(items)):
        joined.setdefault(item[0], []).append((item, quantum))
    out, welded = [], {}
    for mesh_id, group in joined.items():
        if len(group) == 1:
            out.append(group[0][0])
            continue
        # each primitive's own vertices only: trimesh gives every primitive the whole vertex accessor they share
        # (Cesium's tiles: 29 primitives of one 44,268-vertex accessor made 1.3 million vertices to weld)
        from meshsom.tiles3d import joined_welded

        pieces = []
        for (_, v, f, _), quantum in group:
            used, inverse = np.unique(np.asarray(f, np.int64), return_inverse=True)
            pieces.append((np.asarray(v)[used], inverse.reshape(-1, 3), quantum))
        v, f, merged = joined_welded(pieces)
        if merged:
            welded[mesh_id] = merged
        out.append((mesh_id, v, f, group[0][0][3]))
    return out, welded


def up_axis_note(file_type: str, head: bytes) -> tuple[str, ...]:
    """Under ``up_axis: auto``, the note on a mesh file that is y up by what wrote it (its first bytes say), else
    nothing (z up): glTF by its specification, but for trimesh's (:func:`gltf_generator`); an OBJ file Blender or
    SketchUp wrote (their header comment), whose exporters write y up by default."""
    if file_type in ("glb", "gltf"):
        return () if "trimesh" in (gltf_generator(head) or "").lower() else (GLTF_Y_UP_NOTE,)
    if file_type == "obj":
        found = _OBJ_Y_UP_WRITERS.search(head[:OBJ_HEADER_BYTES])
        if found:
            writer = found.group(1).decode("ascii", "replace").strip()
            return (f"an OBJ file {writer} wrote: y up, as its exporter writes by default: turned to z up "
                    f"(corpus.reader.up_axis: z, or --up z, reads it as it is)",)
    return ()


def gltf_generator(head: bytes) -> str | None:
    """The ``asset.generator`` of a glTF file (GLB, or glTF JSON) from its first bytes (writers put ``asset`` first;
    a text search, so that a file cut short, or one of megabytes of embedded buffers, still says it); None where it
    names none."""
    found = _GLTF_GENERATOR.search(head)
    return found.group(1).decode("utf-8", "replace") if found else None


def placed_mesh(mesh_id: str, source: str, vertices: np.ndarray, faces: np.ndarray, label, crs, notes=(),
                options: ReaderOptions | None = None, unitless: bool = False) -> "RawMesh | Rejection":
    """A mesh of a file in world coordinates (``vertices (V, 3)``, ``faces (F, 3)``) recentred and in metres in the
    file's CRS (:func:`file_crs`; :func:`_in_metres`), with ``notes``; a Rejection where its coordinates cannot be
    placed, or where it spans more than :data:`MAX_BUILDING_EXTENT_M` (:func:`extent_problem`; ``unitless``: its file
    names no unit, ``options`` the reader's)."""
    local, origin = recentre(vertices)
    try:
        local, crs_notes = _in_metres(mesh_id, local, origin, crs)
    except InputFileError as err:
        return Rejection(mesh_id, source, err.problem, 0, label)
    problem = extent_problem(local, unitless, options or ReaderOptions())
    if problem:
        return Rejection(mesh_id, source, problem, int(len(faces)), label)
    return RawMesh(mesh_id, source, local, faces, origin, label, None, notes=tuple(notes) + tuple(crs_notes))


def extent_problem(local: np.ndarray, unitless: bool, options: ReaderOptions) -> str | None:
    """Why a mesh (``local (V, 3)``, metres) is no building in metres: it spans more than :data:`MAX_BUILDING_EXTENT_M`
    along an axis, with a hint at what it may be (a file in millimetres where ``unitless``, its file naming no unit;
    a district in one mesh where :attr:`ReaderOptions.split_components` is off); None where it does not."""
    if len(local) == 0:
        return None
    span = float(np.max(np.ptp(local, axis=0)))
    if not span > MAX_BUILDING_EXTENT_M:
        return None
    said = f"{span / 1000:,.3g} km" if span < 1e8 else f"{span / 1000:,.0f} km"
    hints = []
    if unitless and options.unit in (None, "m"):
        what, hints = "not one building in metres", ["a file in millimetres? --unit mm"]
    elif unitless:
        what, hints = f"not one building in {options.unit} (--unit)", ["another unit? --unit"]
    else:
        what, hints = "not one building in the unit its file declares", ["a unit declared wrong?"]
    if not options.split_components:
        hints.append("a district in one mesh? --split-components")
    return f"spans {said}: {what} ({'; '.join(hints)}; the largest building spans under {MAX_BUILDING_EXTENT_M / 1000:g} km)"


def building_meshes(mesh_id: str, source: str, vertices: np.ndarray, faces: np.ndarray, label, crs, notes,
                    options: ReaderOptions) -> Iterator[RawMesh | Rejection]:
    """One building of a scene file in world coordinates (``vertices (V, 3)`` metres, ``faces (F, 3)``) as
    :func:`placed_mesh` places it, or its connected pieces (:func:`_connected_pieces`) under
    :attr:`ReaderOptions.split_components`; a Rejection where it has no faces."""
    items = _connected_pieces(mesh_id, vertices, faces, label) if options.split_components else [
        (mesh_id, vertices, faces, label)]
    for piece_id, v, f, piece_label in items:
        if len(f) == 0:
            yield Rejection(piece_id, source, "holds no faces (no polygon of 3 or more vertices)", 0, piece_label)
            continue
        yield placed_mesh(piece_id, source, v, f, piece_label, crs, notes, options)


#: COLLADA's up axes, as the rotation that turns each to z up (proper rotations: faces keep their side).
COLLADA_UP = {"Z": np.eye(3), "Y": np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]]),
              "X": np.array([[0, 0, -1.0], [0, 1, 0], [1, 0, 0]])}


def _collada_frame(text: bytes) -> tuple[float, np.ndarray]:
    """The metres per unit and the turn to z up of a COLLADA document, from its ``<asset>``'s
    ``<unit meter>`` (1 when absent) and ``<up_axis>`` (Y_UP when absent, as the specification says)."""
    head = text[: text.find(b"</asset>") + 8] if b"</asset>" in text else text[:1 << 16]
    unit = re.search(rb"<unit\b[^>]*\bmeter\s*=\s*[\"']([^\"']+)[\"']", head)
    up = re.search(rb"<up_axis>\s*([XYZ])_UP\s*</up_axis>", head)
    try:
        metres = float(unit.group(1)) if unit else 1.0
    except ValueError:
        metres = 1.0
    if not (math.isfinite(metres) and metres > 0):
        metres = 1.0
    return metres, COLLADA_UP[up.group(1).decode() if up else "Y"]


def _connected_pieces(mesh_id: str, vertices: np.ndarray, faces: np.ndarray, label):
    """The connected pieces of one mesh (:attr:`ReaderOptions.split_components`): faces joined
    through vertices at the same position (:func:`meshsom.topology.vertex_pieces`), each piece
    ``(mesh_id#cN, vertices, faces, label)`` with its own vertices, N from 1 in the order of the pieces' first faces;
    the mesh as it is when it is one piece (its id unchanged)."""
    from meshsom.topology import vertex_pieces

    faces = np.asarray(faces, np.int64).reshape(-1, 3)
    if len(faces) == 0:
        return [(mesh_id, vertices, faces, label)]
    _, at = np.unique(np.asarray(vertices), axis=0, return_inverse=True)
    pieces = vertex_pieces(vertices, faces, joined_by=at.reshape(-1)[faces])
    if len(pieces) == 1:
        return [(mesh_id, vertices, faces, label)]
    return [(f"{mesh_id}#c{p + 1}", v, f, label) for p, (v, f) in enumerate(pieces)]


def _closed_groups(data: io.BytesIO, whole):
    """An OBJ of no objects (``o``) but several groups (``g``), split into one mesh per group when
    every group is closed on its own (a SketchUp export of a district: a group per building);
    else ``whole``. A single building's groups (its roof, its walls) are each open, so a building
    is never cut into pieces.
    """
    import trimesh

    text = data.getvalue()
    if re.search(rb"^[ \t]*o[ \t]", text, re.M) or len(set(re.findall(rb"^[ \t]*g[ \t]+(.+?)[ \t]*\r?$", text, re.M))) < 2:
        return whole
    data.seek(0)
    groups = trimesh.load(data, file_type="obj", process=False, force=None, skip_materials=True,
                          split_groups=True, group_material=False)
    if not isinstance(groups, trimesh.Scene) or len(groups.geometry) < 2:
        return whole
    for geom in groups.geometry.values():
        if not isinstance(geom, trimesh.Trimesh) or len(geom.faces) == 0:
            return whole
        _, at = np.unique(np.asarray(geom.vertices), axis=0, return_inverse=True)
        f = at.reshape(-1)[np.asarray(geom.faces)]
        edges = np.sort(np.stack([f, np.roll(f, -1, axis=1)], axis=2).reshape(-1, 2), axis=1)
        if (np.unique(edges, axis=0, return_counts=True)[1] != 2).any():
            return whole
    return groups


#: The first token of an OFF file (``OFF``, ``COFF``, ``NOFF``, ``STOFF``...; 3D only), and the
#: counts some writers glue to it (ModelNet's ``OFF490 518 0``).
_OFF_HEADER = re.compile(rb"^(?:ST)?C?N?OFF(?=\d|$)")


def triangulated_off(data: bytes) -> bytes | None:
    """An OFF file as a plain OFF of triangles: every polygon face triangulated in its own plane
    (:func:`meshsom.polygons.triangulate_polygon_3d`); None when the file is not one this reads
    (then trimesh judges it).

    trimesh fans OFF polygons from their first vertex (wrong for an L-shaped roof) and fails on
    face lines with trailing blanks, as val3dity's and CGAL's files have them. Comments (``#``),
    colours after the vertex indices, extra vertex columns (COFF, NOFF) and counts glued to the
    header are read. A degenerate polygon (no area) is dropped.
    """
    from meshsom.polygons import triangulate_polygon_3d

    lines = [line.split(b"#", 1)[0].split() for line in data.splitlines()]
    lines = [t for t in lines if t]
    if not lines or not _OFF_HEADER.match(lines[0][0]):
        return None
    head = _OFF_HEADER.match(lines[0][0])
    rest = ([lines[0][0][head.end():]] if head.end() < len(lines[0][0]) else []) + lines[0][1:]
    body = lines[1:]
    if len(rest) < 2:
        if not body:
            return None
        rest, body = body[0], body[1:]
    try:
        n_vertices, n_faces = int(rest[0]), int(rest[1])
        if n_vertices < 0 or n_faces < 0 or len(body) < n_vertices + n_faces:
            return None  # counts that the file does not hold: trimesh says what is wrong
        vertices = np.array([[float(x) for x in t[:3]] for t in body[:n_vertices]], np.float64).reshape(-1, 3)
        faces = [[int(i) for i in t[1:1 + int(t[0])]] for t in body[n_vertices:n_vertices + n_faces]]
    except (ValueError, IndexError):
        return None
    if any(len(f) < 3 or min(f) < 0 or max(f) >= n_vertices for f in faces) or not np.isfinite(vertices).all():
        return None
    triangles = []
    for f in faces:
        if len(f) == 3:
            triangles.append(f)
        else:
            triangles += np.asarray(f)[triangulate_polygon_3d([vertices[f]])].tolist()
    out = [b"OFF", b"%d %d 0" % (n_vertices, len(triangles))]
    out += [b" ".join(t[:3]) for t in body[:n_vertices]]
    out += [b"3 %d %d %d" % tuple(t) for t in triangles]
    return b"\n".join(out) + b"\n"


def triangulated_ply(data: bytes) -> bytes | None:
    """A PLY file of polygon faces as a binary PLY of triangles, every polygon triangulated in its
    own plane (as :func:`triangulated_off`); None when every face is a triangle already or the file
    is not one this reads (then trimesh reads it, or says what is wrong).

    trimesh fans PLY polygons from their first vertex, which folds an L-shaped roof over itself.
    Only the geometry is kept (x, y, z and the faces' ``vertex_indices``).
    """
    from plyfile import PlyData, PlyElement, PlyListProperty

    try:
        header = PlyData._parse_header(io.BytesIO(data))
    except Exception:  # plyfile raises its own and ValueError / IndexError for bad headers
        return None
    elements = {e.name: e for e in header.elements}
    if "vertex" not in elements or "face" not in elements or sum(e.count for e in header.elements) > len(data):
        return None  # not a mesh, or counts the file cannot hold
    face = elements["face"]
    index_list = next((q for q in face.properties if isinstance(q, PlyListProperty)
                       and q.name in ("vertex_indices", "vertex_index")), None)
    if index_list is None or not _ply_polygons(data, header, face, index_list):
        return None
    try:
        ply = PlyData.read(io.BytesIO(data))
        vertex = ply["vertex"].data
        local = np.column_stack([np.asarray(vertex[c], np.float64) for c in ("x", "y", "z")])
        lists = [np.asarray(f, np.int64) for f in ply["face"].data[index_list.name]]
    except Exception:
        return None
    if not lists or not np.isfinite(local).all() or any(len(f) < 3 or f.min() < 0 or f.max() >= len(local) for f in lists):
        return None
    faces, _, _ = _triangulate_polygons([[f] for f in lists], np.concatenate(lists), local)
    out = io.BytesIO()
    vertices = np.empty(len(local), [("x", "f8"), ("y", "f8"), ("z", "f8")])
    vertices["x"], vertices["y"], vertices["z"] = local.T
    triangles = np.empty(len(faces), [("vertex_indices", "i4", (3,))])
    triangles["vertex_indices"] = faces
    PlyData([PlyElement.describe(vertices, "vertex"), PlyElement.describe(triangles, "face")]).write(out)
    return out.getvalue()


def _ply_polygons(data: bytes, header, face, index_list) -> bool:
    """Whether a PLY's faces include any of more than three vertices, read without parsing the
    whole file where the layout allows (ASCII, or binary faces of the index list alone)."""
    from plyfile import PlyListProperty

    start = data.find(b"end_header")
    if start < 0:
        return False
    body = data[data.find(b"\n", start) + 1:]
    before = header.elements[:[e.name for e in header.elements].index("face")]
    if header.text:
        lines = [line for line in body.split(b"\n") if line.strip()]
        skip = sum(e.count for e in before)
        column = [q.name for q in face.properties].index(index_list.name)  # list first: its count is column 0
        if column != 0:
            return True  # let the full parse decide
        return any(line.split()[0] != b"3" for line in lines[skip:skip + face.count])
    sizes = []
    for e in before:
        if any(isinstance(q, PlyListProperty) for q in e.properties):
            return True
        sizes.append(e.count * sum(np.dtype(q.val_dtype.lstrip("<>=")).itemsize for q in e.properties))
    if len(face.properties) != 1:
        return True
    order = "<" if header.byte_order in ("<", "=") else ">"
    count_type = np.dtype(order + index_list.len_dtype.lstrip("<>="))
    index_size = np.dtype(index_list.val_dtype.lstrip("<>=")).itemsize
    record = count_type.itemsize + 3 * index_size
    offset = sum(sizes)
    if offset + record * face.count > len(body):
        return True
    counts = np.ndarray((face.count,), count_type, buffer=body, offset=offset, strides=(record,))
    return bool((counts != 3).any())


#: An OBJ face line of four or more vertices.
_OBJ_POLYGON = re.compile(rb"^[ \t]*f(?:[ \t]+\S+){4,}", re.M)
#: The way into meshsom for the building formats it does not read, named in their rejection.
CONVERSIONS = {
    ".skp": "SketchUp: export it as OBJ (one object per building, two-sided faces are fine)",
    ".dwg": "DWG: save it as DXF (SAVEAS or DXFOUT in AutoCAD, or the ODA File Converter), which is read",
    ".las": "a point cloud: not read (reconstruct buildings first, e.g. with 3dfier or geoflow)",
    ".laz": "a point cloud: not read (reconstruct buildings first, e.g. with 3dfier or geoflow)",
    ".pnts": "a 3D Tiles point cloud: not read",
    ".i3dm": "3D Tiles instances: not read",
    ".ifcxml": "IFC-XML: IfcOpenShell reads IFC as STEP; export the model as .ifc from its authoring tool",
    ".ifcjson": "IFC-JSON: IfcOpenShell reads IFC as STEP; export the model as .ifc from its authoring tool",
    ".x3db": "binary X3D: not read; save it in the XML (.x3d) or classic (.x3dv) encoding, which are read",
}
#: Ladybug Tools' building-energy models (JSON of ``"type": "Model"``), in words: what they are and the way out.
LADYBUG_MODELS = {
    "dragonfly": ("a Dragonfly model (Ladybug Tools: floor plates and storey heights, not surfaces), which is not "
                  "read: export its buildings as GeoJSON footprints with their heights (Dragonfly writes URBANopt "
                  "GeoJSON) or translate it to Honeybee and export the rooms as OBJ or IFC from its host (Rhino, "
                  "Revit, SketchUp)"),
    "honeybee": ("a Honeybee model (Ladybug Tools: rooms of planar faces for energy simulation), which is not read: "
                 "export the rooms as OBJ or IFC from its host (Rhino, Revit, SketchUp)"),
}
CONVERSIONS[".dfjson"], CONVERSIONS[".hbjson"] = LADYBUG_MODELS["dragonfly"], LADYBUG_MODELS["honeybee"]
#: The UTF-8 byte order mark that Windows tools put before text (JSON, OBJ); dropped before parsing.
UTF8_BOM = b"\xef\xbb\xbf"
#: A face line of an OBJ text with a vertex reference 0 (OBJ counts from 1).
_OBJ_ZERO_INDEX = re.compile(rb"^[ \t]*f[ \t][^\n]*?(?<=[ \t])[-+]?0+(?=[/ \t\r\n]|$)", re.M)


def _bad_vertex_reference(data: bytes, file_type: str) -> str | None:
    """The first face of an OBJ or OFF text that refers to a vertex the file does not have, said
    with its line and the vertices there are (what trimesh's IndexError does not say); None if no
    face does (or another format)."""
    lines = data.splitlines()
    if file_type == "obj":
        count = 0
        for number, line in enumerate(lines, 1):
            head = line.lstrip()[:2]
            if head in (b"v ", b"v\t"):
                count += 1
            elif head in (b"f ", b"f\t"):
                for ref in line.split()[1:]:
                    try:
                        k = int(ref.split(b"/")[0])
                    except ValueError:
                        continue
                    if k == 0 or k > count or -k > count:
                        return (f"the face on line {number} refers to vertex {k}, and the file has {count} vertices "
                                f"before it (OBJ counts from 1; negative: back from the last)")
        return None
    if file_type == "off":
        rows = [(n, ln.split(b"#")[0].split()) for n, ln in enumerate(lines, 1)]
        rows = [(n, r) for n, r in rows if r]
        if rows and rows[0][1][0].upper().endswith(b"OFF"):
            rows[0] = (rows[0][0], rows[0][1][1:])
            if not rows[0][1]:
                rows = rows[1:]
        try:
            n_vertices = int(rows[0][1][0])
        except (IndexError, ValueError):
            return None
        for number, row in rows[1 + n_vertices:]:
            try:
                refs = [int(x) for x in row[1:1 + int(row[0])]]
            except ValueError:
                continue
            bad = [k for k in refs if not 0 <= k < n_vertices]
            if bad:
                return (f"the face on line {number} refers to vertex {bad[0]}, and the file has {n_vertices} vertices "
                        f"(OFF counts from 0)")
    return None


#: The classes of 3dfier's OBJ tiles, as the materials of their objects name them (``usemtl Terrain``, ``usemtl
#: BuildingWall``): in a tile of them, only a Building object is a building.
THREEDFIER_CLASSES = ("Building", "Terrain", "Forest", "Water", "Road", "Separation", "Bridge")
_OBJ_OBJECT_OR_MATERIAL = re.compile(rb"^(o|usemtl)[ \t]+(.+?)[ \t]*\r?$", re.M)


def _3dfier_land(data: bytes) -> dict[str, str]:
    """The objects of a 3dfier OBJ tile that are no building (terrain, roads, water...): their class, by object name.

    A file is taken for 3dfier's where every material its objects use is one of :data:`THREEDFIER_CLASSES` (or
    ``<class>Wall``); an object with no Building material in it is land. Any other OBJ: nothing."""
    classes: dict[str, set[str]] = {}
    current = None
    for kind, value in _OBJ_OBJECT_OR_MATERIAL.findall(data):
        text = value.decode("utf-8", "replace")
        if kind == b"o":
            current = classes.setdefault(text, set())
            continue
        found = text[:-4] if text.endswith("Wall") else text
        if found not in THREEDFIER_CLASSES or current is None:
            return {}
        current.add(found)
    if not any(classes.values()) or all("Building" in c for c in classes.values() if c):
        return {}
    return {name: sorted(c)[0] for name, c in classes.items() if c and "Building" not in c}


def triangulated_obj(data: bytes) -> bytes | None:
    """OBJ text whose non-convex polygon faces (``f`` lines of four or more vertices) are
    triangulated in their own plane (:func:`meshsom.polygons.triangulate_polygon_3d`); None when
    it has none.

    trimesh splits every polygon into a fan from its first vertex, right for a convex polygon and
    wrong for any other: the L- or U-shaped roofs and floors that CAD and Blender exports keep as
    one polygon would fold over themselves (and leave the mesh open). Convex polygons are left to
    trimesh; texture and normal references of a replaced face are dropped (only geometry is read).
    """
    from meshsom.polygons import newell_normal, plane_frame, triangulate_polygon_3d

    if not _OBJ_POLYGON.search(data):
        return None
    out, vertices, changed = [], [], False
    for line in data.splitlines():
        head = line.lstrip()[:2]
        if head == b"v " or head == b"v\t":
            try:
                vertices.append([float(x) for x in line.split()[1:4]])
            except ValueError:
                vertices.append([math.nan] * 3)
        elif head in (b"f ", b"f\t"):
            refs = line.split()[1:]
            if len(refs) >= 4:
                try:
                    ids = [int(r.split(b"/")[0]) for r in refs]
                    ids = [i - 1 if i > 0 else len(vertices) + i for i in ids]
                    points = np.array([vertices[i] for i in ids], np.float64)
                except (ValueError, IndexError):
                    points = None  # left for trimesh to judge
                normal = None
                if points is not None and len(points[0]) == 3 and np.isfinite(points).all():
                    normal = newell_normal(points - points.mean(axis=0))
                if normal is not None and np.linalg.norm(normal) > 0:  # a degenerate polygon is left to trimesh
                    flat = (points - points.mean(axis=0)) @ plane_frame(normal).T
                    d1 = np.roll(flat, -1, axis=0) - flat
                    d2 = np.roll(d1, -1, axis=0)
                    turns = d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0]
                    if not ((turns > 0).all() or (turns < 0).all()):
                        tri = triangulate_polygon_3d([points])
                        if len(tri):
                            out += [b"f %d %d %d" % tuple(ids[k] + 1 for k in t) for t in tri.tolist()]
                            changed = True
                            continue
        out.append(line)
    return b"\n".join(out) + b"\n" if changed else None


class FolderResolver:
    """Files a mesh file refers to (glTF buffers, materials), looked up in its own folder only.

    trimesh calls ``get(name)`` (or ``resolver[name]``) for each external file. A name that is a
    URL (``http:``, ``file:``, any scheme), an absolute path, contains ``..``, or resolves (through
    symbolic links) to a file outside the folder is refused with an :class:`InputFileError` naming
    the input; nothing outside the folder is opened and the network is never used.

    Parameters
    ----------
    folder : path
        The input file's folder.
    source : str
        The input file, named in errors.
    """

    def __init__(self, folder: str | os.PathLike, source: str):
        self.folder = Path(folder).resolve()
        self.source = source

    def _path(self, name) -> Path:
        if not isinstance(name, str) or not name.strip():
            raise InputFileError(self.source, f"refers to an external file with an invalid name {name!r}")
        name = name.strip()
        parts = name.replace("\\", "/").split("/")
        if urlparse(name).scheme or name.startswith(("/", "\\", "~")) or ".." in parts or os.path.isabs(name):
            raise InputFileError(
                self.source, f"refers to {name!r}, outside its own folder; only files beside it are read"
            )
        path = (self.folder / name).resolve()
        if not path.is_relative_to(self.folder):
            raise InputFileError(self.source, f"refers to {name!r}, which resolves to {path}, outside its own folder")
        if not path.is_file():
            raise InputFileError(self.source, f"refers to {name!r}, which is not a file in {self.folder}")
        return path

    def get(self, name) -> bytes:
        """The bytes of the file ``name`` beside the input."""
        with open(self._path(name), "rb") as fh:
            return fh.read()

    def __getitem__(self, name) -> bytes:
        return self.get(name)

    def __contains__(self, name) -> bool:
        try:
            self._path(name)
        except InputFileError:
            return False
        return True

    def get_base(self) -> bytes:
        raise InputFileError(self.source, "has no base file to resolve")

    def namespaced(self, namespace: str) -> "FolderResolver":
        """A resolver for a sub-folder, still confined to this one."""
        sub = FolderResolver(self.folder, self.source)
        sub.folder = self._path_dir(namespace)
        return sub

    def _path_dir(self, namespace) -> Path:
        path = (self.folder / str(namespace)).resolve()
        if not path.is_relative_to(self.folder) or not path.is_dir():
            raise InputFileError(self.source, f"refers to folder {namespace!r}, outside its own folder")
        return path

    def keys(self) -> Iterator[str]:
        """Names of the files directly in the folder."""
        return (p.name for p in sorted(self.folder.iterdir()) if p.is_file())

    def write(self, name, data):
        raise InputFileError(self.source, f"reading it tried to write {name!r}; meshsom never writes beside an input")

    __setitem__ = write


# ----------------------------------------------------------------------------- CityJSON


def _lod_key(lod) -> float:
    try:
        return float(lod)
    except (TypeError, ValueError):
        return math.nan


#: Levels of lists above the polygons in a geometry's "boundaries".
_NESTING = {**dict.fromkeys(SURFACE_TYPES, 0), **dict.fromkeys(SOLID_TYPES, 1), **dict.fromkeys(MULTISOLID_TYPES, 2)}


def _polygons_of(geom: dict, mesh_id: str) -> list[list[list[int]]]:
    """Every polygon (list of rings of vertex indices) of a surface or solid geometry.

    The nesting is checked (lists down to the rings) so malformed boundaries are an
    InputFileError naming the object; polygons with no ring are dropped.
    """
    return [poly for shell in _shells_of(geom, mesh_id) for poly in shell]


def _shells_of(geom: dict, mesh_id: str) -> list[list[list[list[int]]]]:
    """The polygons of a surface or solid geometry, by shell: a Solid's shells (exterior, then interiors), every
    shell of each solid of a CompositeSolid or MultiSolid, or a surface geometry's polygons as one shell.

    The nesting is checked (lists down to the rings) so malformed boundaries are an InputFileError naming the
    object; polygons with no ring are dropped, and shells left without a polygon.
    """
    return _envelope_shells(geom, mesh_id, openings=False)[0]


def _envelope_shells(geom: dict, mesh_id: str, openings: bool = True) -> tuple[list[list[list[list[int]]]], int, int]:
    """:func:`_shells_of`, less (``openings``) the polygons whose semantic surface is a window or a door
    (:data:`OPENING_SURFACES`).

    Returns
    -------
    shells : list of shells, each a list of polygons (lists of rings of vertex indices)
    polygons : int
        Polygons left out as openings.
    surfaces : int
        Semantic surfaces (windows, doors) they are.
    """
    gtype = geom.get("type")
    if gtype not in _NESTING:
        return [], 0, 0
    items, values = [geom.get("boundaries", [])], [_opening_values(geom) if openings else None]
    for _ in range(_NESTING[gtype]):
        if not all(isinstance(x, list) for x in items):
            break
        # semantics' values nest as the boundaries less the rings; null (or a list cut short) at any level: none
        values = [y for x, v in zip(items, values)
                  for y in (v[:len(x)] + [None] * (len(x) - len(v)) if isinstance(v, list) else [None] * len(x))]
        items = [y for x in items for y in x]
    else:
        if all(isinstance(shell, list) and all(isinstance(poly, list) and all(isinstance(ring, list) for ring in poly)
                                               for poly in shell) for shell in items):
            shells, dropped = [], []
            for shell, v in zip(items, values):
                v = v if isinstance(v, list) else []
                kept = []
                for p, poly in enumerate(shell):
                    mark = v[p] if p < len(v) else None
                    if poly and isinstance(mark, int):
                        dropped.append(mark)
                    elif poly:
                        kept.append(poly)
                if kept:
                    shells.append(kept)
            return shells, len(dropped), len(set(dropped))
    raise InputFileError(mesh_id, f"{gtype} boundaries must be nested lists down to rings of vertex indices")


def _opening_values(geom: dict) -> list | None:
    """A geometry's semantics ``values`` with each index of a window or door surface (:data:`OPENING_SURFACES`) kept
    and every other (another type, null, malformed) None; None where the geometry has no opening (or no semantics)."""
    semantics = geom.get("semantics")
    surfaces = semantics.get("surfaces") if isinstance(semantics, dict) else None
    if not isinstance(surfaces, list):
        return None
    opening = {k for k, s in enumerate(surfaces) if isinstance(s, dict) and s.get("type") in OPENING_SURFACES}
    if not opening:
        return None

    def kept(node):
        if isinstance(node, list):
            return [kept(x) for x in node]
        return node if isinstance(node, int) and not isinstance(node, bool) and node in opening else None

    values = kept(semantics.get("values"))
    return values if isinstance(values, list) else None


def _ids(value) -> list[str]:
    """The object ids of a "children" or "parents" member (anything but a list of strings counts as none)."""
    return [v for v in value if isinstance(v, str)] if isinstance(value, list) else []


def _type(obj) -> str:
    otype = obj.get("type") if isinstance(obj, dict) else None
    return otype if isinstance(otype, str) else ""


def _parse_json(data: bytes, where: str):
    """``json.loads`` of UTF-8 bytes (after a byte order mark, if any); InputFileError naming ``where``
    for anything unreadable."""
    try:
        return json.loads(data.decode("utf-8-sig"))  # a leading byte order mark (Windows tools write one) is not JSON
    except json.JSONDecodeError as err:
        raise InputFileError(where, f"invalid JSON at line {err.lineno}, column {err.colno}: {err.msg}") from None
    except UnicodeDecodeError as err:
        raise InputFileError(where, f"is not UTF-8 text ({err.reason} at byte {err.start})") from None
    except ValueError as err:  # e.g. an integer literal of more than 4300 digits
        raise InputFileError(where, f"invalid JSON ({err})") from None
    except RecursionError:
        raise InputFileError(where, "invalid JSON: arrays or objects nested too deeply") from None


def _ladybug_model(cj) -> str | None:
    """"dragonfly" or "honeybee" where a JSON document is a Ladybug Tools model (``"type": "Model"`` with Dragonfly's
    ``buildings`` or Honeybee's ``rooms``), else None."""
    if not (isinstance(cj, dict) and cj.get("type") == "Model"):
        return None
    return "dragonfly" if "buildings" in cj else "honeybee" if "rooms" in cj or "orphaned_faces" in cj else None


def _check_cityjson_header(cj, where: str, options: ReaderOptions, seq: bool = False
                           ) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
    """The vertices, scale and translate of a CityJSON document (or a CityJSONSeq header line)."""
    kind, version = (cj.get("type"), str(cj.get("version", ""))) if isinstance(cj, dict) else (None, "")
    major_minor = ".".join(version.rstrip("/").rsplit("/", 1)[-1].split(".")[:2])  # 0.1's is a URL
    draft = not seq and (major_minor in DRAFT_CITYJSON_VERSIONS or (not version and kind == "CityModel"))
    if kind not in (("CityJSON", "CityModel") if draft else ("CityJSON",)):
        what = "its first line is not a CityJSON header" if seq else "is JSON but not CityJSON"
        found = cj.get("type") if isinstance(cj, dict) else type(cj).__name__
        ladybug = _ladybug_model(cj)
        if ladybug and not seq:
            raise InputFileError(where, f"is {LADYBUG_MODELS[ladybug]}")
        raise InputFileError(where, f"{what} (expected \"type\": \"CityJSON\", found {found!r})")
    if major_minor not in SUPPORTED_CITYJSON_VERSIONS and not draft:
        raise InputFileError(
            where, f"CityJSON version {version!r} is not supported; expected one of "
                   f"{', '.join(SUPPORTED_CITYJSON_VERSIONS)} (or a draft, {DRAFT_CITYJSON_VERSIONS[0]}-"
                   f"{DRAFT_CITYJSON_VERSIONS[-1]})"
        )
    verts = cj.get("vertices", [] if seq else None)
    if not isinstance(verts, list):
        raise InputFileError(where, "has no \"vertices\" array")
    if len(verts) > options.max_vertices:
        raise InputFileError(where, f"declares {len(verts)} vertices, more than the limit of {options.max_vertices}")
    if not isinstance(cj.get("CityObjects", {} if seq else None), dict):
        raise InputFileError(where, "has no \"CityObjects\" object")
    transform = cj.get("transform")
    scale = translate = None
    if transform is None:
        # CityJSON 1.1 and 2.0 require one, but files without it exist (cjio's own test data):
        # their vertices are read as coordinates, as in CityJSON 1.0
        pass
    else:
        try:
            scale = np.asarray(transform["scale"], np.float64).reshape(3)
            translate = np.asarray(transform["translate"], np.float64).reshape(3)
        except (KeyError, TypeError, ValueError):
            raise InputFileError(where, "\"transform\" must hold \"scale\" and \"translate\", three numbers each") from None
        if not (np.isfinite(scale).all() and np.isfinite(translate).all() and (scale > 0).all()):
            raise InputFileError(where, f"\"transform\" has invalid values: scale {scale.tolist()}, translate {translate.tolist()}")
    return _vertex_array(verts, where, scale is not None, options), scale, translate


def _vertex_array(verts, where: str, integer: bool, options: ReaderOptions) -> np.ndarray:
    """(V, 3) int64 (with a transform) or float64 vertices of a "vertices" member."""
    if not isinstance(verts, list):
        raise InputFileError(where, "has no \"vertices\" array")
    if len(verts) > options.max_vertices:
        raise InputFileError(where, f"declares {len(verts)} vertices, more than the limit of {options.max_vertices}")
    try:
        vertices = np.asarray(verts, dtype=np.int64 if integer else np.float64).reshape(-1, 3) if verts else np.zeros((0, 3))
        if len(verts) and (not isinstance(verts[0], list) or len(vertices) != len(verts)):
            raise ValueError
    except (TypeError, ValueError, OverflowError):
        kind = "integers" if integer else "numbers"
        raise InputFileError(where, f"\"vertices\" must be a list of [x, y, z] {kind}") from None
    return vertices


def read_cityjson(
    path: Path, options: ReaderOptions = ReaderOptions(), name: str | None = None
) -> Iterator[RawMesh | Rejection]:
    """Read the buildings of a CityJSON 1.0, 1.1 or 2.0 file (gzipped or not).

    One mesh per Building (BuildingParts merged in, or kept apart with
    ``options.parts == "separate"``), from the geometries at the chosen LoD.
    Polygons (with holes) are triangulated in their own plane. Mesh ids are
    ``name#objectid`` (``name`` defaults to the file name).

    A merged Building whose geometry comes from several objects (the Building
    and its BuildingParts) lists them in ``RawMesh.parts`` and tags every face
    with its object (``RawMesh.face_part``), for the union in preprocessing.

    Raises
    ------
    InputFileError
        The file cannot be read, is not CityJSON, or holds no object of ``options.object_types``
        (naming the types it holds).
    """
    yield from _document_items(_parse_json(read_input_bytes(path, options), str(path)), path, options, name)


def _document_items(cj, path: Path, options: ReaderOptions, name: str | None) -> Iterator[RawMesh | Rejection]:
    """The items of a parsed JSON document (:func:`read_cityjson`): CityJSON, CityJSONFeatures,
    GeoJSON / JSON-FG or a 3D Tiles tileset."""
    from meshsom.geojson import is_esri_json, is_geojson, read_geojson

    if is_esri_json(cj):  # an ArcGIS REST query's answer (f=json): through GDAL's ESRIJSON driver
        from meshsom.gis import read_gis

        yield from read_gis(path, options, name)
        return
    if isinstance(cj, dict) and set(cj) == {"error"} and isinstance(cj["error"], dict):
        raise InputFileError(str(path), f"is an ArcGIS REST error response, not data (code {cj['error'].get('code')}: "
                                        f"{str(cj['error'].get('message'))[:200]})")
    if _is_feature_collection(cj):
        yield from _feature_collection(cj, path, options, name)
        return
    from meshsom.overpass import is_overpass_json, read_overpass

    if is_overpass_json(cj):  # an Overpass API answer: the OpenStreetMap extract it stands for
        yield from read_overpass(cj, path, options, name)
        return
    if is_geojson(cj):
        found = False
        for item in read_geojson(cj, path, options, name):
            found = True
            yield item
        if not found:
            from meshsom.part_files import is_part_file

            if is_part_file(path, options):
                return  # every part read with its building
            raise InputFileError(str(path), "is a GeoJSON FeatureCollection of no features")
        return
    from meshsom.tiles3d import is_tileset, read_tileset

    if is_tileset(cj):
        yield from read_tileset(cj, path, options, name)
        return
    vertices, scale, translate = _check_cityjson_header(cj, str(path), options)
    objects: dict = cj["CityObjects"]
    found = False
    templates = Templates.of(cj)
    crs = file_crs(_reference_system(cj), options)
    for item in _object_meshes(objects, vertices, scale, translate, options, name or path.name, str(path), templates, crs):
        found = True
        yield item
    if not found:
        raise _no_buildings(path, options, {_type(o) for o in objects.values()})


def _reference_system(cj: dict):
    """A CityJSON document's ``metadata.referenceSystem`` (1.0: ``"urn:ogc:def:crs:EPSG::7415"``;
    1.1 and 2.0: ``"https://www.opengis.net/def/crs/EPSG/0/7415"``), or None."""
    metadata = cj.get("metadata")
    return metadata.get("referenceSystem") if isinstance(metadata, dict) else None


def _no_buildings(path: Path, options: ReaderOptions, types: set) -> InputFileError:
    types = sorted(t or "(no type)" for t in types)
    return InputFileError(
        str(path), f"holds no {' or '.join(options.object_types)} object (found "
        f"{', '.join(types[:8]) + (f' and {len(types) - 8} more types' if len(types) > 8 else '') if types else 'no objects'})")


def read_cityjsonseq(
    path: Path, options: ReaderOptions = ReaderOptions(), name: str | None = None,
    byte_range: tuple[int, int, int] | None = None,
) -> Iterator[RawMesh | Rejection]:
    """Read the buildings of a CityJSON Text Sequence (CityJSONSeq, ``.city.jsonl``; gzipped or not).

    The first line is a CityJSON object (version, ``transform``, usually no objects and no
    vertices); every further line is a CityJSONFeature: a Building with its BuildingParts and
    their own vertices, under the header's transform. Lines are read one at a time. Meshes are
    as :func:`read_cityjson` makes them from the same objects (same ids, coordinates and faces).

    A line that cannot be read (bad JSON, not a CityJSONFeature, bad vertices) is a Rejection
    with id ``name#featureid`` (``name:line N`` when it has no id) and the reason, and the reader
    goes on; an object id seen on an earlier line is a Rejection too. Blank lines are skipped.

    With ``byte_range`` (:func:`cityjsonseq_ranges`) only the features on the lines of that range
    are read (the header line is read first), and a range without buildings yields nothing.

    Raises
    ------
    InputFileError
        The file or its header cannot be read, or it holds no object of ``options.object_types``.
    """
    def lines():
        if byte_range is not None:
            with contextlib.closing(input_lines(path, options)) as head:
                yield next(((n, line) for n, line in head if line is None or line.strip()), (1, b""))
        yield from input_lines(path, options, byte_range)

    document = _one_json_document(path, options) if byte_range is None else None
    if document is not None:
        yield from _document_items(document, path, options, name)  # a pretty-printed document named .jsonl
        return
    yield from _sequence_items(lines(), path, options, name, partial=byte_range is not None)


def _one_json_document(path: Path, options: ReaderOptions) -> dict | None:
    """A ``.jsonl`` file that is one JSON object written across lines (its first line is not JSON,
    the whole file is), parsed; None for a sequence of one object per line."""
    if path.stat().st_size > ONE_DOCUMENT_BYTES:
        return None
    with contextlib.closing(input_lines(path, options)) as head:
        first = next((line for _, line in head if line is None or line.strip()), None)
    if first is None:
        return None
    try:
        json.loads(first)
        return None
    except ValueError:
        pass
    try:
        document = json.loads(read_input_bytes(path, options))
    except (ValueError, InputFileError):
        return None
    return document if isinstance(document, dict) else None


def _sequence_items(lines, path: Path, options: ReaderOptions, name: str | None, partial: bool = False
                    ) -> Iterator[RawMesh | Rejection]:
    """The items of a CityJSON header and its CityJSONFeatures, given as ``(line number, bytes)``
    (:func:`read_cityjsonseq`; ``partial``: a byte range, where no building is no error)."""
    name = name or path.name
    source = str(path)
    header = None
    first_line: dict[str, int] = {}
    types: set = set()
    found = False
    for number, line in lines:
        if line is None:
            long = f"line {number}: is longer than {options.max_bytes:,} bytes (ReaderOptions.max_bytes); not read"
            if header is None:
                raise InputFileError(source, long)
            yield Rejection(f"{name}:line {number}", source, long)
            continue
        if not line.strip():
            continue
        where = f"{path} line {number}"
        if header is None:
            cj = _parse_json(line, where)
            header = _check_cityjson_header(cj, where, options, seq=True)
            objects, vertices = cj.get("CityObjects") or {}, header[0]
            templates = Templates.of(cj)
            crs = file_crs(_reference_system(cj), options)
        else:
            fid = None
            try:
                feature = _parse_json(line, where)
                if isinstance(feature, dict) and isinstance(feature.get("id"), str):
                    fid = feature["id"]
                if not isinstance(feature, dict) or feature.get("type") != "CityJSONFeature":
                    found_type = feature.get("type") if isinstance(feature, dict) else type(feature).__name__
                    raise InputFileError(where, f"is not a CityJSONFeature (\"type\": {found_type!r})")
                objects = feature.get("CityObjects")
                if not isinstance(objects, dict):
                    raise InputFileError(where, "has no \"CityObjects\" object")
                vertices = _vertex_array(feature.get("vertices"), where, header[1] is not None, options)
            except InputFileError as err:
                yield Rejection(f"{name}#{fid}" if fid else f"{name}:line {number}", source, f"line {number}: {err.problem}")
                continue
        types.update(_type(o) for o in objects.values())
        for item in _object_meshes(objects, vertices, header[1], header[2], options, name, source, templates, crs):
            found = True
            first = first_line.setdefault(item.id, number)
            if first != number:
                yield Rejection(item.id, source, f"line {number}: object id repeated (first on line {first}); "
                                "the later one is not read")
            elif isinstance(item, Rejection):
                yield dataclasses.replace(item, reason=f"line {number}: {item.reason}")
            else:
                yield item
    if header is None:
        raise InputFileError(source, "holds only blank lines (expected a CityJSON header line, then CityJSONFeatures)")
    if not found and not partial:
        raise _no_buildings(path, options, types)


def _feature_collection(cj: dict, path: Path, options: ReaderOptions, name: str | None) -> Iterator[RawMesh | Rejection]:
    """A JSON document of CityJSONFeatures, read as the CityJSONSeq it stands for: a page of an
    OGC API - Features server of CityJSON (the 3D BAG's: ``{"type": "FeatureCollection",
    "metadata": {"transform": ...}, "features": [CityJSONFeature, ...]}``), or a single
    CityJSONFeature that carries its ``transform``.
    """
    features = cj.get("features") if cj.get("type") == "FeatureCollection" else [cj]
    meta = cj.get("metadata") if isinstance(cj.get("metadata"), dict) else {}
    transform = cj.get("transform") or meta.get("transform")
    if transform is None:
        raise InputFileError(str(path), "holds CityJSONFeatures without the transform of their CityJSON header (give "
                                        "them as a CityJSONSeq, .city.jsonl, with the header as its first line)")
    version = str(cj.get("version", "2.0"))  # CityJSONFeature is 2.0's; an API page may say which
    header = {"type": "CityJSON", "version": version if version in SUPPORTED_CITYJSON_VERSIONS else "2.0",
              "transform": transform, "CityObjects": {}, "vertices": []}
    if meta:
        header["metadata"] = {k: v for k, v in meta.items() if k != "transform"}
    lines = [(1, json.dumps(header).encode())] + [(k, json.dumps(f).encode()) for k, f in enumerate(features, 2)]
    yield from _sequence_items(iter(lines), path, options, name)


def _is_feature_collection(cj) -> bool:
    """Whether a parsed document holds CityJSONFeatures (a CityJSON API page, or one feature)."""
    if not isinstance(cj, dict):
        return False
    if cj.get("type") == "CityJSONFeature":
        return True
    features = cj.get("features")
    return cj.get("type") == "FeatureCollection" and isinstance(features, list) and bool(features) and all(
        isinstance(f, dict) and f.get("type") == "CityJSONFeature" for f in features)


def file_crs(declared, options: ReaderOptions) -> tuple["CoordinateSystem | None", str | None]:
    """The CRS a file's buildings are in: the one it declares, else ``options.crs``.

    Returns
    -------
    crs : CoordinateSystem or None
        None when there is none, or the declared one is unknown (coordinates then read as metres).
    note : str or None
        Says that a declared CRS is unknown (recorded with every mesh of the file).
    """
    from meshsom.crs import UnknownCRS, coordinate_system

    reference = declared if isinstance(declared, str) and declared.strip() else options.crs
    if reference is None:
        return None, None
    try:
        return coordinate_system(reference), None
    except UnknownCRS as err:
        return None, f"{err}; its coordinates are read as metres"


def _in_metres(mesh_id: str, local: np.ndarray, origin: np.ndarray, crs: tuple) -> tuple[np.ndarray, list[str]]:
    """A building's local coordinates in metres (:func:`meshsom.crs.to_metres`), and notes.

    Raises
    ------
    InputFileError
        The coordinates look like degrees (:func:`meshsom.crs.looks_geographic`) where no CRS is known or a
        projected one is declared; a geographic CRS's lie beyond +/-90 and +/-180.
    """
    from meshsom.crs import NotDegrees, looks_geographic, to_metres

    system, unknown = crs
    if system is None:
        why = looks_geographic(local, origin)
        if why is not None:
            raise InputFileError(mesh_id, why)
        return local, [unknown] if unknown else []
    if not system.geographic and looks_geographic(local, origin) is not None:
        span = max(np.ptp(local[:, 0]), np.ptp(local[:, 1]))
        raise InputFileError(mesh_id, f"its coordinates look like degrees of latitude and longitude (x and y span "
                                      f"{span:.2g}, z spans {np.ptp(local[:, 2]):.3g}), though the file declares the "
                                      f"projected CRS {system.name}: the declaration is wrong")
    try:
        local, note = to_metres(local, origin, system)
    except NotDegrees as err:
        raise InputFileError(mesh_id, str(err)) from None
    return local, [note] if note else []


def _object_meshes(objects: dict, vertices, scale, translate, options: ReaderOptions, name: str, source: str,
                   templates: "Templates | None" = None, crs: tuple = (None, None)) -> Iterator[RawMesh | Rejection]:
    """The meshes (or rejections) of the buildings among ``objects``: one per Building with its
    parts merged, or one per Building geometry and BuildingPart (``options.parts``)."""
    groups: list[tuple[str, list[str]]] = []
    for oid, obj in objects.items():
        if not isinstance(obj, dict):
            continue
        otype = _type(obj)
        if options.parts == "merge":
            # a building whose "parents" are no building (a CityObjectGroup's members name the group so) is one of
            # its own; only parts (BuildingPart) are merged into their parents
            if otype in options.object_types and not (otype.endswith("Part") and obj.get("parents")):
                members = [oid]
                seen = {oid}
                stack = _ids(obj.get("children"))
                while stack:
                    child = stack.pop()
                    if child in seen:
                        continue  # a part listed twice, or a cycle of children
                    seen.add(child)
                    cobj = objects.get(child)
                    if _type(cobj).endswith("Part"):
                        members.append(child)
                        stack.extend(_ids(cobj.get("children")))
                groups.append((oid, members))
        else:
            own = bool(obj.get("geometry"))
            if own and otype in options.object_types and options.lod in LOD_CHOICES and _footprint_only(obj) \
                    and any(_type(objects.get(c)).endswith("Part") and objects[c].get("geometry")
                            for c in _ids(obj.get("children"))):
                continue  # the 3D BAG's building: a LoD 0 footprint beside its parts' solids, which stand for it
            if (otype in options.object_types and (own or not obj.get("children"))) or otype.endswith("Part") and any(
                _type(objects.get(p)) in options.object_types for p in _ids(obj.get("parents"))
            ):
                groups.append((oid, [oid]))
    for oid, members in groups:
        mesh_id = f"{name}#{oid}"
        attrs = objects[oid].get("attributes") or {}
        label = attrs.get(options.label_attribute) if isinstance(attrs, dict) else None
        label = None if label is None else str(label)
        try:
            yield _building_mesh(mesh_id, source, members, objects, vertices, scale, translate, options, label, templates, crs)
        except InputFileError as err:
            yield Rejection(mesh_id, source, err.problem, 0, label)


@dataclass(frozen=True)
class Templates:
    """A CityJSON document's ``geometry-templates``: the template geometries and their vertices.

    Attributes
    ----------
    geometries : list of dict
    vertices : (T, 3) float64
        ``vertices-templates``, real coordinates (no transform applies to them).
    problem : str or None
        Why the templates cannot be used (malformed), said by each building that uses them.
    """

    geometries: list
    vertices: np.ndarray = field(repr=False)
    problem: str | None = None

    @classmethod
    def of(cls, cj: dict) -> "Templates | None":
        """The templates of a parsed CityJSON document (or CityJSONSeq header); None without any."""
        member = cj.get("geometry-templates")
        if member is None:
            return None
        geometries = member.get("templates") if isinstance(member, dict) else None
        verts = member.get("vertices-templates") if isinstance(member, dict) else None
        try:
            if not isinstance(geometries, list) or not isinstance(verts, list):
                raise ValueError
            vertices = np.asarray(verts, np.float64).reshape(-1, 3) if verts else np.zeros((0, 3))
            if len(verts) and (not isinstance(verts[0], list) or len(vertices) != len(verts)):
                raise ValueError
        except (TypeError, ValueError, OverflowError):
            return cls([], np.zeros((0, 3)), "\"geometry-templates\" must hold \"templates\" (a list of geometries) and "
                       "\"vertices-templates\" (a list of [x, y, z] numbers)")
        if not np.isfinite(vertices).all():
            return cls([], np.zeros((0, 3)), "\"vertices-templates\" holds NaN or infinite coordinates")
        return cls(geometries, vertices)


def _nested_plus(node, offset: int):
    """``boundaries`` with ``offset`` added to every vertex index (non-integers left for the checks after)."""
    if isinstance(node, list):
        return [_nested_plus(x, offset) for x in node]
    return node + offset if isinstance(node, int) and not isinstance(node, bool) else node


def _placed_instances(mesh_id: str, geoms: list, vertices: np.ndarray, scale, translate, templates: "Templates | None"
                      ) -> tuple[list, np.ndarray]:
    """Every GeometryInstance of ``geoms`` replaced by its template, placed: each template vertex
    ``t`` goes to ``M[:3, :3] t + M[:3, 3] + p`` (CityJSON: the 4 x 4 row-major
    ``transformationMatrix`` M, the reference point p, a vertex of the file). The placed vertices
    are appended to ``vertices`` (on the file's integer grid, rounded to it, when there is a
    transform) and the template's boundaries renumbered to them.

    Returns
    -------
    geoms : list of dict
    vertices : (V', 3) array, same dtype as ``vertices``
    """
    out, blocks, n = [], [vertices], len(vertices)
    for g in geoms:
        if g.get("type") != "GeometryInstance":
            out.append(g)
            continue
        if templates is None:
            raise InputFileError(mesh_id, "has GeometryInstance geometry but the file has no \"geometry-templates\"")
        if templates.problem:
            raise InputFileError(mesh_id, f"has GeometryInstance geometry; {templates.problem}")
        k, ref = g.get("template"), g.get("boundaries")
        if not (isinstance(k, int) and 0 <= k < len(templates.geometries)):
            raise InputFileError(mesh_id, f"GeometryInstance template {k!r} is not one of the file's "
                                 f"{len(templates.geometries)} templates")
        if not (isinstance(ref, list) and len(ref) == 1 and isinstance(ref[0], int) and 0 <= ref[0] < len(vertices)):
            raise InputFileError(mesh_id, f"GeometryInstance boundaries must be [index of the reference point] "
                                 f"(one of {len(vertices)} vertices), received {str(ref)[:60]}")
        try:
            matrix = np.asarray(g.get("transformationMatrix"), np.float64).reshape(4, 4)
        except (TypeError, ValueError):
            matrix = None
        if matrix is None or not np.isfinite(matrix).all():
            raise InputFileError(mesh_id, "GeometryInstance transformationMatrix must be 16 finite numbers (4 x 4, row-major)")
        template = templates.geometries[k]
        if not isinstance(template, dict) or template.get("type") not in SURFACE_TYPES + SOLID_TYPES + MULTISOLID_TYPES:
            found = template.get("type") if isinstance(template, dict) else type(template).__name__
            raise InputFileError(mesh_id, f"GeometryInstance template {k} is a {found!r}, not a surface or solid geometry")
        flat = _indices(mesh_id, [i for poly in _polygons_of(template, mesh_id) for ring in poly for i in ring])
        bad = (flat < 0) | (flat >= len(templates.vertices))
        if bad.any():
            raise InputFileError(mesh_id, f"GeometryInstance template {k} uses vertex {flat[bad][0]} of "
                                 f"{len(templates.vertices)} vertices-templates")
        point = vertices[ref[0]].astype(np.float64)
        if scale is not None:
            point = point * scale + translate
        with np.errstate(over="ignore", invalid="ignore"):
            placed = templates.vertices @ matrix[:3, :3].T + matrix[:3, 3] + point
            if scale is not None:
                placed = np.round((placed - translate) / scale)
        if not np.isfinite(placed).all() or (scale is not None and np.abs(placed).max(initial=0) > MAX_GRID_COORDINATE):
            raise InputFileError(mesh_id, f"GeometryInstance of template {k} is placed beyond the coordinate range")
        blocks.append(placed.astype(vertices.dtype))
        out.append({**template, "boundaries": _nested_plus(template.get("boundaries", []), n)})
        n += len(placed)
    return out, np.concatenate(blocks) if len(blocks) > 1 else vertices


def _building_mesh(mesh_id, source, members, objects, vertices, scale, translate, options, label,
                   templates: "Templates | None" = None, crs: tuple = (None, None)) -> RawMesh:
    geoms, geom_member = [], []
    for k, m in enumerate(members):
        member_geoms = objects[m].get("geometry", [])
        for g in member_geoms if isinstance(member_geoms, list) else []:
            if isinstance(g, dict):
                geoms.append(g)
                geom_member.append(k)
    if not geoms:
        raise InputFileError(mesh_id, "has no geometry")
    if any(g.get("type") == "GeometryInstance" for g in geoms):
        geoms, vertices = _placed_instances(mesh_id, geoms, vertices, scale, translate, templates)
    usable_at = [i for i, g in enumerate(geoms) if g.get("type") in SURFACE_TYPES + SOLID_TYPES + MULTISOLID_TYPES]
    usable = [geoms[i] for i in usable_at]
    if not usable:
        types = sorted({str(g.get("type")) for g in geoms})
        raise InputFileError(mesh_id, f"has no surface or solid geometry (found {', '.join(types)})")
    lods = sorted({str(g.get("lod")) for g in usable}, key=_lod_key)
    # LoD 0 is a footprint or roof outline, never a volume: "highest" and "lowest" pass it over
    # where a building has anything else (the 3D BAG gives every Building a LoD 0 footprint
    # beside its LoD 1.2, 1.3 and 2.2 solids)
    volumes = [lo for lo in lods if not _lod_key(lo) < 1] or lods
    passed_over = []
    if options.lod in LOD_CHOICES and len(volumes) > 1:
        flat = _flat_lods(volumes, geoms, usable_at, vertices, scale, mesh_id)
        if flat and len(flat) < len(volumes):
            passed_over = [lo for lo in volumes if lo in flat]
            volumes = [lo for lo in volumes if lo not in flat]
    if options.lod == "highest":
        want = volumes[-1]
    elif options.lod == "lowest":
        want = volumes[0]
    else:
        matches = [lo for lo in lods if lo == options.lod or _lod_key(lo) == _lod_key(options.lod)]
        if not matches:
            raise InputFileError(mesh_id, f"has no geometry at LoD {options.lod} (available: {', '.join(lods)})")
        want = matches[0]
    lift = None
    if _lod_key(want) < 1 and options.lod in LOD_CHOICES:  # a footprint alone: extruded by its height, if it has one
        lift = _footprint_height(mesh_id, objects[members[0]], want, options)
    polygons, poly_member, poly_shell = [], [], []
    openings = [0, 0]  # polygons, surfaces (windows, doors) left out
    for i in usable_at:
        if str(geoms[i].get("lod")) == want:
            shells, *left = _envelope_shells(geoms[i], mesh_id)
            openings = [a + b for a, b in zip(openings, left)]
            for shell in shells:
                polygons += shell
                poly_member += [geom_member[i]] * len(shell)
                # a solid's shells are each a shell; a member's surfaces are one
                poly_shell += [len(poly_shell) if geoms[i].get("type") not in SURFACE_TYPES else -1 - geom_member[i]] * len(shell)
    if not polygons:
        besides = f" but {openings[0]} of windows and doors (not the envelope)" if openings[0] else ""
        raise InputFileError(mesh_id, f"has no polygons at LoD {want}{besides}")
    with_volume = {geom_member[i] for i in usable_at if not _lod_key(geoms[i].get("lod")) < 1}
    left_out = sorted(with_volume - set(poly_member))
    flat = _indices(mesh_id, [i for poly in polygons for ring in poly for i in ring])
    if len(flat) == 0:
        raise InputFileError(mesh_id, f"has only empty rings at LoD {want}")
    n_vertices = len(vertices)
    bad = (flat < 0) | (flat >= n_vertices)
    if bad.any():
        raise InputFileError(
            mesh_id, f"vertex index {flat[bad][0]} out of range (the file has {n_vertices} vertices)"
        )
    flat = flat.astype(np.int64)
    used, inverse = np.unique(flat, return_inverse=True)
    grid = vertices[used]
    # Exact re-centring: on the integer grid when there is a transform.
    if scale is not None:
        beyond = (grid > MAX_GRID_COORDINATE) | (grid < -MAX_GRID_COORDINATE)
        if beyond.any():
            raise InputFileError(
                mesh_id, f"integer vertex coordinate {int(grid[beyond][0])} beyond +/-2^53 (not exact in float64)"
            )
        centre = (grid.min(axis=0) + grid.max(axis=0)) // 2
        with np.errstate(over="ignore", invalid="ignore"):
            local = (grid - centre).astype(np.float64) * scale
            origin = centre.astype(np.float64) * scale + translate
    else:
        if not np.isfinite(grid).all():
            raise InputFileError(mesh_id, f"{int((~np.isfinite(grid).all(axis=1)).sum())} vertices have NaN or infinite coordinates")
        with np.errstate(over="ignore", invalid="ignore"):
            local, origin = recentre(grid)
    if not (np.isfinite(local).all() and np.isfinite(origin).all()):
        raise InputFileError(mesh_id, "coordinates overflow float64 after the transform or re-centring")
    import shapely.errors

    local, notes = _in_metres(mesh_id, local, origin, crs)
    if openings[0]:
        from meshsom.citygml import openings_note

        notes.append(openings_note(openings[1], openings[0]))
    if passed_over:
        notes.append(f"its LoD {', '.join(passed_over)} geometry is flat (polygons in one horizontal plane, no volume): "
                     f"LoD {want} read")
    if left_out and lift is None:
        shown = ", ".join(members[k] for k in left_out[:3]) + (", ..." if len(left_out) > 3 else "")
        notes.append(f"{len(left_out)} of its {len(members)} objects ({shown}) have no geometry at LoD {want}: left out "
                     f"(--lod names another LoD)")
    try:
        faces, face_poly, dropped = _triangulate_polygons(polygons, inverse, local)
        if dropped:
            notes.append(
                f"the reader dropped {dropped} polygon(s) at LoD {want} that cannot be triangulated from their own "
                f"vertices (self-crossing rings, e.g. a twisted wall quad), leaving holes there"
            )
        lod = want
        if len(faces) and lift is not None:
            local, faces, note = _extrude_footprint(mesh_id, local, faces, options, height=lift[1])
            notes += [lift[0]] + note
            lod = f"1 (extruded from {want})"
        elif len(faces) and options.extrude_lod1:
            local, faces, note = _extrude_footprint(mesh_id, local, faces, options)
            notes += note
            lod = f"1 (extruded from {want})"
    except shapely.errors.GEOSException as err:
        raise InputFileError(mesh_id, f"a polygon cannot be triangulated (GEOS: {err})") from None
    n_in = sum(len(p) for p in polygons)
    if len(faces) == 0:
        raise InputFileError(mesh_id, f"all {n_in} polygons at LoD {want} are degenerate")
    parts, face_part = (), None
    if not options.extrude_lod1 and lift is None:
        parts, face_part = _parts(local, faces, np.asarray(poly_member, np.int64)[face_poly],
                                  np.asarray(poly_shell, np.int64)[face_poly], members)
    return RawMesh(mesh_id, source, local, faces, origin, label, lod, parts, face_part, tuple(notes))


def _parts(local: np.ndarray, faces: np.ndarray, face_member: np.ndarray, face_shell: np.ndarray, members: list
           ) -> tuple[tuple[str, ...], np.ndarray | None]:
    """The parts that preprocessing unites (:mod:`meshsom.union`): each object's, and each shell of an object's
    solids that is no cavity.

    The solids of a CompositeSolid share faces, those of a MultiSolid may touch or overlap, and a Solid's
    interior shells are written for pieces beside its exterior (the windows of IFC exports: 7 shells of one
    Solid); preprocessed together, faces where they touch are fins and walls inside, not their union. A shell
    is a cavity where all its corners lie strictly inside another shell
    (:func:`meshsom.preprocess.cavity_shells`); it stays with the shell that encloses it, in its part
    (:func:`_cavity_hosts`), and the union keeps it a cavity of that part.

    Parameters
    ----------
    local : (V, 3) float64
    faces : (F, 3) int64
    face_member : (F,) int64
        Each face's object, an index into ``members``.
    face_shell : (F,) int64
        Each face's shell (numbered across the objects), or a negative number for an object's surfaces.
    members : list of str

    Returns
    -------
    parts : tuple of str
        The object ids, with `` shell k`` where an object has several shells; empty for one part.
    face_part : (F,) int64 or None
        Each face's part; None for one part.
    """
    from meshsom.preprocess import cavity_shells

    used_members, by_member = np.unique(face_member, return_inverse=True)
    by_member = by_member.reshape(-1).astype(np.int64)
    shells, by_shell = np.unique(face_shell, return_inverse=True)
    by_shell = by_shell.reshape(-1).astype(np.int64)
    shell_member = np.zeros(len(shells), np.int64)
    shell_member[by_shell] = by_member
    per_member = np.bincount(shell_member, minlength=len(used_members))
    surfaces = np.zeros(len(used_members), bool)
    surfaces[shell_member[shells < 0]] = True  # an object's surfaces beside its solids: its shells are not split
    split = (per_member > 1)[shell_member] & ~surfaces[shell_member]  # the solid shells of an object of several
    host = np.arange(len(shells))  # the shell whose part each shell joins: itself, or a cavity's enclosing shell
    if split.any():
        cavity = cavity_shells(local, faces, by_shell)
        host = _cavity_hosts(local, faces, by_shell, shell_member, cavity)
        solids = np.bincount(shell_member[host == np.arange(len(shells))], minlength=len(used_members))
        split &= (solids > 1)[shell_member] & ~np.isin(shell_member, shell_member[host < 0])
    if not split.any():
        if len(used_members) < 2:
            return (), None
        return tuple(members[k] for k in used_members), by_member
    # a part per shell of the objects split (a cavity in its enclosing shell's), one per other object
    key = np.where(split, len(used_members) + host, shell_member)
    part_keys, part_of_shell = np.unique(key, return_inverse=True)
    part_of_shell = part_of_shell.reshape(-1)
    rank = np.zeros(len(shells), np.int64)
    order = np.lexsort((np.arange(len(shells)), shell_member))
    first = np.searchsorted(shell_member[order], shell_member[order])
    rank[order] = np.arange(len(shells)) - first
    names = [None] * len(part_keys)
    for s_, p_ in enumerate(part_of_shell):
        member = members[used_members[shell_member[s_]]]
        names[p_] = f"{member} shell {rank[host[s_]] + 1}" if split[s_] else member
    return tuple(names), part_of_shell[by_shell].astype(np.int64)


def _cavity_hosts(local: np.ndarray, faces: np.ndarray, by_shell: np.ndarray, shell_member: np.ndarray,
                  cavity: np.ndarray) -> np.ndarray:
    """For each shell, the shell whose part it joins: itself, or for a cavity the smallest other shell of its object
    that encloses it (all its corners strictly inside, :func:`meshsom.preprocess.cavity_shells` of the pair); -1 for
    a cavity that no shell of its object encloses alone (one inside the object's shells only together).

    Parameters
    ----------
    local : (V, 3) float64
        The vertices, about the building's origin.
    faces : (F, 3) int64
    by_shell : (F,) int64
        Each face's shell, 0 .. S-1.
    shell_member : (S,) int64
        Each shell's object.
    cavity : (S,) bool

    Returns
    -------
    (S,) int64
    """
    from meshsom.preprocess import cavity_shells

    host = np.arange(len(shell_member))
    if not cavity.any():
        return host
    for c in np.flatnonzero(cavity):
        host[c] = -1
        mates = np.flatnonzero((shell_member == shell_member[c]) & ~cavity)
        size = [np.ptp(local[faces[by_shell == s]].reshape(-1, 3), axis=0).prod() for s in mates]
        for s in mates[np.argsort(size, kind="stable")]:  # the smallest shell first (its bounding box)
            pair = (by_shell == s) | (by_shell == c)
            if cavity_shells(local, faces[pair], (by_shell[pair] == c).astype(np.int64))[1]:
                host[c] = s
                break
    return host


def _footprint_only(obj: dict) -> bool:
    """Whether every geometry of a city object is of a LoD below 1 (a footprint or roof outline)."""
    geoms = obj.get("geometry")
    return isinstance(geoms, list) and all(isinstance(g, dict) and _lod_key(g.get("lod")) < 1 for g in geoms)


def _flat_lods(lods: list, geoms: list, usable_at: list, vertices: np.ndarray, scale, mesh_id: str) -> set:
    """The LoDs among ``lods`` whose polygons lie in one horizontal plane (a LoD 3 of a ground polygon alone beside a
    LoD 2 solid): no volume, passed over by "highest" and "lowest"."""
    flat = set()
    for lod in lods:
        idx = _indices(mesh_id, [i for k in usable_at if str(geoms[k].get("lod")) == lod
                                 for poly in _polygons_of(geoms[k], mesh_id) for ring in poly for i in ring])
        idx = idx[(idx >= 0) & (idx < len(vertices))].astype(np.int64)
        if len(idx) == 0:
            continue
        with np.errstate(over="ignore", invalid="ignore"):
            points = vertices[idx].astype(np.float64) * (1.0 if scale is None else np.asarray(scale, np.float64))
            extent = np.ptp(points, axis=0)
        if np.isfinite(extent).all() and extent[2] <= 1e-9 * max(extent[0], extent[1]):
            flat.add(lod)
    return flat


def _indices(mesh_id: str, values: list) -> np.ndarray:
    """The boundaries' vertex indices as an integer array; InputFileError if any is not an integer.

    Returns
    -------
    flat : (N,) int64 or uint64
        uint64 only when an index is beyond the int64 range (then out of range anyway).
    """
    try:
        flat = np.array(values) if values else np.zeros(0, np.int64)
    except (TypeError, ValueError, OverflowError):
        flat = None
    if flat is None or flat.ndim != 1 or flat.dtype.kind not in "iu":
        found = "mixed or nested values" if flat is None or flat.ndim != 1 else str(flat.dtype)
        raise InputFileError(mesh_id, f"boundaries must hold integer vertex indices (found {found})")
    return flat


def _triangulate_polygons(polygons, inverse: np.ndarray, local: np.ndarray, triangulate=None
                          ) -> tuple[np.ndarray, np.ndarray, int]:
    """Triangles of every polygon, as indices into ``local``.

    Triangles without holes (most of a triangulated city model) are taken as
    they are, in one vectorised step; plain convex quads (walls) too (:func:`_split_quads`); the
    other polygons are triangulated by ``triangulate``: :func:`meshsom.polygons.triangulate_polygons_3d`
    (one GEOS call for those of one ring), or :func:`_triangulate_one_by_one`, the reference.

    Returns
    -------
    faces : (F, 3) int64
    face_poly : (F,) int64
        The polygon every face comes from.
    dropped : int
        Polygons that are not degenerate (their vertices span a plane) but could not be
        triangulated whole from their own vertices: self-crossing rings, whose triangles would
        need the crossing point, lose those triangles.
    """
    triangulate = triangulate or triangulate_polygons_3d
    sizes = np.array([len(ring) for poly in polygons for ring in poly], np.int64)
    rings_per_poly = np.array([len(poly) for poly in polygons], np.int64)
    ring_start = np.concatenate([[0], np.cumsum(sizes)])
    poly_first_ring = np.concatenate([[0], np.cumsum(rings_per_poly)])[:-1]
    simple_tri = (rings_per_poly == 1) & (sizes[poly_first_ring] == 3)
    tri_starts = ring_start[poly_first_ring[simple_tri]]
    out = [inverse[tri_starts[:, None] + np.arange(3)]]
    out_poly = [np.flatnonzero(simple_tri)]
    if simple_tri.all():  # a triangulated model (most city files): nothing more to do
        return out[0].astype(np.int64).reshape(-1, 3), out_poly[0].astype(np.int64), 0
    quads = np.flatnonzero((rings_per_poly == 1) & (sizes[poly_first_ring] == 4))
    quad_tri, done = _split_quads(inverse[ring_start[poly_first_ring[quads]][:, None] + np.arange(4)], local)
    out.append(quad_tri.reshape(-1, 3))
    out_poly.append(np.repeat(quads[done], 2))
    rest = np.ones(len(polygons), bool)
    rest[simple_tri] = False
    rest[quads[done]] = False
    dropped = 0
    kept = []
    for p in np.flatnonzero(rest):
        r0 = poly_first_ring[p]
        rings_idx = [inverse[ring_start[r]:ring_start[r + 1]] for r in range(r0, r0 + rings_per_poly[p])]
        rings_idx = [_drop_spikes(_drop_closing_vertex(r), local) for r in rings_idx]
        if len(rings_idx[0]) < 3:
            continue  # a polygon collapsed to a line or point: nothing to triangulate
        kept.append((p, rings_idx[:1] + [r for r in rings_idx[1:] if len(r) >= 3]))
    # one GEOS call for the polygons of one ring (a footprint's floor and roof), as one by one
    triangulated = triangulate([[local[r] for r in rings_idx] for _, rings_idx in kept])
    for (p, rings_idx), tri in zip(kept, triangulated):
        ids = np.concatenate(rings_idx)
        # A polygon of n vertices and h holes has n + 2h - 2 triangles; fewer means a part of
        # it was left out, unless it is degenerate (all its vertices on one line).
        if len(tri) < len(ids) + 2 * (len(rings_idx) - 1) - 2:
            p3 = local[ids] - local[ids].mean(axis=0)
            # ... nor where the triangles cover the polygon's area (a vertex on a side's line, none missing)
            dropped += int(np.linalg.matrix_rank(p3) >= 2 and len(np.unique(ids)) == len(ids)
                           and not _covered(local, rings_idx, ids[tri] if len(tri) else np.zeros((0, 3), np.int64)))
        if len(tri):
            out.append(ids[tri])
            out_poly.append(np.full(len(tri), p, np.int64))
    faces = [f.astype(np.int64).reshape(-1, 3) for f in out]
    order = np.argsort(np.concatenate(out_poly[1:]), kind="stable")  # after the plain triangles, in polygon order
    faces = np.concatenate([faces[0], np.concatenate(faces[1:])[order]])
    return faces, np.concatenate([out_poly[0], np.concatenate(out_poly[1:])[order]]).astype(np.int64), dropped


def polygon_faces(flat: np.ndarray, lengths: np.ndarray, local: np.ndarray) -> tuple[np.ndarray, int]:
    """Triangles of polygons given as one index array (a scene format's face lists: USD's faceVertexIndices, X3D's
    coordIndex less its -1 separators): the triangles taken as they are, in one step, the other polygons
    triangulated in their own plane (:func:`_triangulate_polygons`: convex quads at once, concave polygons such as an
    L-shaped roof by GEOS).

    Parameters
    ----------
    flat : (N,) int64
        Every polygon's vertex indices into ``local``, one polygon after the other.
    lengths : (P,) int64
        The vertices of each polygon (3 or more; they add up to N).
    local : (V, 3) float64

    Returns
    -------
    faces : (F, 3) int64
        The triangles first, then the other polygons' triangles.
    dropped : int
        Self-crossing polygons that lost the triangles that would need the crossing point.
    """
    starts = np.cumsum(lengths) - lengths
    triangles = flat[starts[lengths == 3][:, None] + np.arange(3)].reshape(-1, 3)
    other = np.flatnonzero(lengths != 3)
    if len(other) == 0:
        return triangles.astype(np.int64), 0
    rings = [flat[a:a + n] for a, n in zip(starts[other].tolist(), lengths[other].tolist())]
    faces, _, dropped = _triangulate_polygons([[r] for r in rings], np.concatenate(rings), local)
    return np.concatenate([triangles, faces]).astype(np.int64), dropped


def _triangulate_one_by_one(polygons: list) -> list:
    """The reference for :func:`meshsom.polygons.triangulate_polygons_3d`: each polygon by
    :func:`meshsom.polygons.triangulate_polygon_3d` alone (``polygons``: lists of (K, 3) float64 rings)."""
    return [triangulate_polygon_3d(rings) for rings in polygons]


def _covered(local: np.ndarray, rings: list, faces: np.ndarray) -> bool:
    """Whether triangles ``faces`` (T, 3) cover a planar polygon's area (its ``rings`` of vertex indices into ``local``,
    the exterior first): their areas sum to the polygon's (Newell's, holes taken off) within 1e-6."""
    normal = sum(np.cross(local[r], local[np.roll(r, -1)]).sum(axis=0) for r in rings[:1])
    length = np.linalg.norm(normal)
    if not length > 0:
        return False
    unit = normal / length
    area = sum(abs(float(np.cross(local[r], local[np.roll(r, -1)]).sum(axis=0) @ unit)) * (1 if k == 0 else -1)
               for k, r in enumerate(rings)) / 2
    a, b, c = (local[faces[:, k]] for k in range(3))
    covered = float(np.abs(np.cross(b - a, c - a) @ unit).sum()) / 2
    return area > 0 and abs(covered - area) <= 1e-6 * area


#: A quad this close (relative) to being not convex or to having a spike is split one by one, as any
#: other polygon; diagonals this close to equal are measured as that path measures them: the
#: vectorised split decides exactly as the one-by-one path does.
QUAD_TIE_TOL = 1e-9


def _split_quads(quads: np.ndarray, local: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two triangles for each plain convex quad, all at once, as :func:`triangulate_polygon_3d` splits it.

    Parameters
    ----------
    quads : (Q, 4) int64
        The vertex indices of one-ring polygons of four vertices.
    local : (V, 3) float64

    Returns
    -------
    triangles : (D, 2, 3) int64
        Vertex indices, for the quads split here.
    done : (Q,) bool
        The quads split here; the others (repeated vertices, spikes, not convex, degenerate, or
        within :data:`QUAD_TIE_TOL` of those) are left to the one-by-one path.
    """
    if len(quads) == 0:
        return np.zeros((0, 2, 3), np.int64), np.zeros(0, bool)
    p = local[quads]
    # np.roll along the 4 corners and np.cross, written out (the same products and differences, in the
    # same order: the same bits); per call they cost more than the arithmetic of a building's walls
    prev, nxt = [3, 0, 1, 2], [1, 2, 3, 0]
    distinct = (quads != quads[:, prev]).all(axis=1)
    d_in = p - p[:, prev]
    d_out = p[:, nxt] - p
    norms = np.linalg.norm(d_in, axis=2) * np.linalg.norm(d_out, axis=2)
    cos = np.einsum("qij,qij->qi", d_in, d_out) / np.where(norms > 0, norms, 1.0)
    centred = p - p.mean(axis=1, keepdims=True)
    normal = _cross(centred, centred[:, nxt]).sum(axis=1)
    size = np.linalg.norm(normal, axis=1)
    n = normal / np.where(size > 0, size, 1.0)[:, None]
    helper = np.where((np.abs(n[:, 0]) < 0.9)[:, None], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0])
    e1 = _cross(helper, n)
    e1 /= np.where(np.linalg.norm(e1, axis=1) > 0, np.linalg.norm(e1, axis=1), 1.0)[:, None]
    e2 = _cross(n, e1)
    flat = np.stack([np.einsum("qij,qj->qi", centred, e1), np.einsum("qij,qj->qi", centred, e2)], axis=2)
    d1 = flat[:, nxt] - flat
    d2 = d1[:, nxt]
    cross = d1[:, :, 0] * d2[:, :, 1] - d1[:, :, 1] * d2[:, :, 0]
    scale = np.einsum("qij,qij->q", d1, d1)
    convex = ((cross > 0).all(axis=1) | (cross < 0).all(axis=1)) & (np.abs(cross).min(axis=1) > QUAD_TIE_TOL * scale)
    v02, v13 = p[:, 0] - p[:, 2], p[:, 1] - p[:, 3]
    d02, d13 = np.linalg.norm(v02, axis=1), np.linalg.norm(v13, axis=1)
    short02 = d02 <= d13
    # near a tie (every rectangle: a wall), the diagonals measured as the one-by-one path does
    ties = np.flatnonzero(np.abs(d02 - d13) <= QUAD_TIE_TOL * np.maximum(d02, d13))
    short02[ties] = [math.sqrt(a.dot(a)) <= math.sqrt(b.dot(b)) for a, b in zip(v02[ties], v13[ties])]
    done = distinct & (cos > -0.9999 + QUAD_TIE_TOL).all(axis=1) & (size > 0) & convex
    short02 = short02[done]
    q = quads[done]
    tri = np.where(short02[:, None, None], q[:, [[0, 1, 2], [0, 2, 3]]], q[:, [[0, 1, 3], [1, 2, 3]]])
    return tri.astype(np.int64), done


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``np.cross(a, b)`` of (..., 3) float64 arrays, the same bits (each component ``a_i b_j - a_j b_i``, as
    NumPy computes it), without its per-call overhead."""
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    return np.stack([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0], axis=-1)


def _drop_spikes(ring: np.ndarray, local: np.ndarray, cos_tol: float = -0.9999) -> np.ndarray:
    """Drop spike vertices, where a ring goes out and comes back along the same line.

    A footprint with a spike is not a simple polygon (the ring touches itself); without its tip
    it is. The walls extruded along the spike overlap and are removed in preprocessing.
    """
    while len(ring) > 3:
        p = local[ring]
        d_in = np.diff(p, axis=0, prepend=p[-1:])  # p - np.roll(p, 1, axis=0)
        d_out = np.diff(p, axis=0, append=p[:1])  # np.roll(p, -1, axis=0) - p
        norms = np.linalg.norm(d_in, axis=1) * np.linalg.norm(d_out, axis=1)
        cos = np.einsum("ij,ij->i", d_in, d_out) / np.where(norms > 0, norms, 1.0)
        spikes = np.flatnonzero(cos < cos_tol)
        if len(spikes) == 0:
            break
        # Tips at least 3 apart do not change each other's neighbours: drop them together, so a
        # ring of n spikes (a hostile zig-zag) costs a few passes, not n.
        ring = np.delete(ring, _spaced(spikes, len(ring), 3)[: len(ring) - 3])
        ring = ring[ring != np.roll(ring, 1)]
    return ring


def _spaced(positions: np.ndarray, n: int, gap: int) -> list[int]:
    """Greedy subset of sorted ring positions that are pairwise at least ``gap`` apart on a ring of ``n``."""
    out: list[int] = []
    for i in positions.tolist():
        if not out or (i - out[-1] >= gap and out[0] + n - i >= gap):
            out.append(i)
    return out


def _drop_closing_vertex(ring: np.ndarray) -> np.ndarray:
    """Drop repeated consecutive vertices (cyclically), the closing one included."""
    if len(ring) < 2:
        return ring
    return ring[ring != np.roll(ring, 1)]


def _footprint_height(mesh_id: str, obj: dict, lod: str, options: ReaderOptions) -> tuple[str, float]:
    """The height (metres, added to coordinates already in metres) a LoD 0 footprint alone is extruded by:
    its first height attribute (:attr:`ReaderOptions.height_attributes`, CityGML's
    ``measuredHeight``), else a storey count times :attr:`ReaderOptions.storey_height`; and a note.

    Raises
    ------
    InputFileError
        It has neither: a footprint is no volume.
    """
    from meshsom.geojson import first_number, no_height

    attributes = obj.get("attributes") if isinstance(obj.get("attributes"), dict) else {}
    height = first_number(attributes, options.height_attributes)
    if height is not None and height[1] > 0:
        unit = HEIGHT_UNITS[options.height_unit] if options.height_unit else 1.0
        return (f"extruded from its LoD {lod} footprint by {height[0]} = {height[1]:g}"
                + (f" {options.height_unit}" if options.height_unit else ""), height[1] * unit)
    levels = first_number(attributes, options.levels_attributes)
    if levels is not None and levels[1] > 0:
        return (f"extruded from its LoD {lod} footprint by {levels[0]} = {levels[1]:g} storeys x {options.storey_height:g} m",
                levels[1] * options.storey_height)
    if levels is not None and levels[1] == 0:  # nothing above the ground: not raised to the default height
        raise InputFileError(mesh_id, f"has only a LoD {lod} footprint and {levels[0]} = 0: no storey above the ground")
    if options.default_height is not None:
        return (f"extruded from its LoD {lod} footprint to the default {options.default_height:g} m "
                f"(corpus.reader.default_height): it has no height or storey count", float(options.default_height))
    raise InputFileError(mesh_id, f"has only a LoD {lod} footprint{no_height(options)[len('is a footprint'):]}")


def _extrude_footprint(mesh_id: str, vertices: np.ndarray, faces: np.ndarray, options: ReaderOptions,
                       height: float | None = None):
    """Closed LoD1 block: the union of the triangles seen from above, extruded over the z-range
    (or from the lowest z by ``height``).

    The union is exact up to ``options.footprint_grid`` (GEOS snap-rounding), with no buffer that
    could erase a small polygon; holes narrower than ``options.footprint_seam_width`` (seams
    between roof polygons) are filled; every polygon of the union is extruded (a footprint of
    disjoint polygons gives a mesh of several shells, said in the notes).

    Parameters
    ----------
    mesh_id : str
    vertices : (V, 3) float64
    faces : (F, 3) int64
    options : ReaderOptions
    height : float, optional
        Extrude from the lowest z by this (a footprint's height), not to the highest z.

    Returns
    -------
    vertices : (W, 3) float64
    faces : (G, 3) int64
    notes : list of str
    """
    import shapely

    tris = vertices[faces][:, :, :2]
    area2 = (tris[:, 1, 0] - tris[:, 0, 0]) * (tris[:, 2, 1] - tris[:, 0, 1]) - (
        tris[:, 1, 1] - tris[:, 0, 1]
    ) * (tris[:, 2, 0] - tris[:, 0, 0])
    tris = tris[area2 != 0]  # vertical faces add nothing seen from above
    if len(tris) == 0:
        raise InputFileError(mesh_id, "has no footprint (every polygon is vertical)")
    z0, z1 = float(vertices[:, 2].min()), float(vertices[:, 2].max())
    if height is not None:
        z1 = z0 + height
    if not z1 > z0:
        raise InputFileError(mesh_id, "has zero height; cannot extrude a LoD1 block")
    polys = shapely.polygons(np.concatenate([tris, tris[:, :1]], axis=1))
    footprint = shapely.union_all(polys, grid_size=options.footprint_grid or None)
    parts, seams = [], 0
    for p in shapely.get_parts(footprint):
        if p.geom_type != "Polygon" or not p.area > 0:
            continue
        holes = [r for r in p.interiors if 2 * abs(shapely.Polygon(r).area) > options.footprint_seam_width * r.length]
        seams += len(p.interiors) - len(holes)
        parts.append(shapely.Polygon(p.exterior, holes) if len(holes) < len(p.interiors) else p)
    if options.footprint_simplify > 0:
        parts = [p.simplify(options.footprint_simplify) for p in parts]
    parts = sorted((p for p in parts if p.geom_type == "Polygon" and p.area > 0), key=lambda p: -p.area)
    if not parts:
        raise InputFileError(
            mesh_id, f"footprint is empty: every polygon seen from above is narrower than footprint_grid "
            f"({options.footprint_grid} m)"
        )
    out_v, out_f = [], []
    offset = 0
    for p in parts:
        shell = np.asarray(p.exterior.coords)[:-1]
        holes = [np.asarray(r.coords)[:-1] for r in p.interiors]
        v, f = extrude_polygon(shell, holes, z0, z1)
        out_v.append(v)
        out_f.append(f + offset)
        offset += len(v)
    notes = [f"filled {seams} seam(s) between roof polygons in the footprint"] if seams else []
    if len(parts) > 1:
        areas = ", ".join(f"{p.area:.3g}" for p in parts)
        notes.append(f"footprint of {len(parts)} disjoint polygons ({areas} m2), each extruded: {len(parts)} shells")
    return np.concatenate(out_v), np.concatenate(out_f).astype(np.int64), notes


# ----------------------------------------------------------------------------- writing


def _quantised(meshes, scale: float):
    """Each mesh's vertices on one integer grid (``translate`` the floor of the smallest
    coordinate), as the CityJSON writers store them."""
    allv = np.concatenate([m.vertices for m in meshes])
    translate = np.floor(allv.min(axis=0))
    return translate, [np.round((m.vertices - translate) / scale).astype(np.int64) for m in meshes]


def _building_object(m, offset: int, label_attribute: str) -> dict:
    shell = [[[int(a) + offset, int(b) + offset, int(c) + offset]] for a, b, c in m.faces]
    return {
        "type": "Building",
        "attributes": {label_attribute: m.label} if m.label is not None else {},
        "geometry": [{"type": "Solid", "lod": str(m.lod or "1"), "boundaries": [shell]}],
    }


def write_cityjsonseq(path: str | os.PathLike, meshes, scale: float = 0.001, label_attribute: str = "family") -> None:
    """Write meshes as CityJSONSeq (a CityJSON 2.0 header line, then one CityJSONFeature per mesh:
    a Building with a Solid, its own vertices); gzip-compressed when ``path`` ends in ``.gz``.

    Parameters
    ----------
    path : path
    meshes : iterable of objects with ``id``, ``vertices (V, 3) float64`` (world coordinates),
        ``faces (F, 3) int64``, ``label`` and ``lod``.
    scale : float
        Vertex quantisation (metres per integer unit).
    label_attribute : str
    """
    meshes = list(meshes)
    translate, grids = _quantised(meshes, scale)
    header = {"type": "CityJSON", "version": "2.0", "transform": {"scale": [scale] * 3, "translate": translate.tolist()},
              "CityObjects": {}, "vertices": [], "metadata": {"title": "meshsom synthetic corpus"}}
    opener = gzip.open if str(path).endswith(GZIP_SUFFIX) else open
    with opener(path, "wt", encoding="utf-8") as fh:
        fh.write(json.dumps(header, separators=(",", ":")) + "\n")
        for m, grid in zip(meshes, grids):
            feature = {"type": "CityJSONFeature", "id": m.id, "CityObjects": {m.id: _building_object(m, 0, label_attribute)},
                       "vertices": grid.tolist()}
            fh.write(json.dumps(feature, separators=(",", ":")) + "\n")


def write_cityjson(path: str | os.PathLike, meshes, scale: float = 0.001, label_attribute: str = "family") -> None:
    """Write meshes as a CityJSON 2.0 file (one Building with a Solid each); gzip-compressed when
    ``path`` ends in ``.gz``.

    Parameters
    ----------
    path : path
    meshes : iterable of objects with ``id``, ``vertices (V, 3) float64`` (world
        coordinates), ``faces (F, 3) int64``, ``label`` and ``lod``.
    scale : float
        Vertex quantisation (metres per integer unit).
    label_attribute : str
        Attribute the label is written to.
    """
    meshes = list(meshes)
    translate, all_int = _quantised(meshes, scale)
    objects = {}
    offset = 0
    for m, vi in zip(meshes, all_int):
        objects[m.id] = _building_object(m, offset, label_attribute)
        offset += len(vi)
    doc = {
        "type": "CityJSON",
        "version": "2.0",
        "transform": {"scale": [scale] * 3, "translate": translate.tolist()},
        "CityObjects": objects,
        "vertices": np.concatenate(all_int).tolist(),
        "metadata": {"title": "meshsom synthetic corpus"},
    }
    with (gzip.open if str(path).endswith(GZIP_SUFFIX) else open)(path, "wt", encoding="utf-8") as fh:
        json.dump(doc, fh, separators=(",", ":"))


def write_mesh_folder(folder: str | os.PathLike, meshes, suffix: str = ".obj") -> None:
    """Write one mesh file per mesh plus ``labels.csv`` (columns file, label)."""
    import trimesh

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    rows = []
    for m in meshes:
        fname = f"{m.id}{suffix}"
        trimesh.Trimesh(m.vertices, m.faces, process=False).export(str(folder / fname))
        rows.append({"file": fname, "label": m.label or ""})
    with open(folder / "labels.csv", "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=["file", "label"])
        w.writeheader()
        w.writerows(rows)
