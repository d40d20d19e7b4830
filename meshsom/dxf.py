"""Reading DXF drawings: the 3D block and roof models cities publish as CAD files, one mesh per building.

Swiss and German cities publish their 3D models as DXF (Zürich's 3D-Blockmodell and Dachmodell,
swissBUILDINGS3D), and CAD users exchange massing models in it. An ASCII DXF file is read with ezdxf's
plain loader and audited (ezdxf's recovering reader, :func:`ezdxf.recover.read`, where that fails:
damaged files are repaired as far as they can be), a binary one by ezdxf's loader and then audited; plain or gzipped, under
:attr:`meshsom.io.ReaderOptions.max_bytes`. Only model space is read (paper space layouts are sheets
of a drawing, not the model).

- **Meshes**: each POLYFACE mesh (a POLYLINE with the polyface flag: vertices, then face records of
  up to four 1-based vertex indices), each POLYGON MESH (an M x N POLYLINE grid of vertices, closed
  in M or N where its flags say so) and each MESH entity (its control cage: the vertices and faces
  of subdivision level 0, noted when the file asks for smoothing) is one building, id
  ``name#<handle>``.
- **Block references**: each INSERT is one building of all the faces of its block (3DFACE, POLYFACE,
  POLYGON MESH, MESH, nested INSERTs to :data:`MAX_BLOCK_DEPTH` levels) moved by the insert's
  transformation (:meth:`ezdxf.entities.Insert.matrix44`: the block's base point, scale, rotation
  and extrusion / OCS), id ``name#<block name>@<handle>``. A MINSERT (an INSERT with rows and columns)
  is one building per copy at a distinct position, id ``name#<block name>@<handle>/r<row>c<column>``
  (from 1). A mirroring insert (negative determinant) has its faces' corners reversed, so that
  they keep their side. An INSERT of a block of 2D drawing only (a tree symbol, a north arrow) is
  not a building: it is counted with the 2D entities.
- **One mesh of a district**: with :attr:`meshsom.io.ReaderOptions.split_components` each connected
  piece of a POLYFACE, MESH or INSERT is a building (``...#cN``), as for mesh files.
- **2.5D outlines**: a closed LWPOLYLINE or 2D POLYLINE (flagged closed, or ending where it starts,
  as GIS exports write a ring), a CIRCLE, or a SOLID or TRACE (a filled triangle or quadrilateral),
  with a thickness (how older block models draw a building: its outline at its base elevation, the
  thickness its height) is the prism it draws: the outline (bulges and circles flattened within :data:`FLATTEN_REL` of its
  extent) extruded by the thickness along its extrusion direction, id ``name#<handle>`` (in a
  block, part of the INSERT's building). An open polyline with a thickness (a wall, a fence) and a
  closed one without are 2D.
- **Loose 3DFACEs**: the 3DFACEs of model space are grouped by layer, their corners merged within
  :data:`WELD_REL` times the layer's extent, and each layer's faces split into connected pieces
  (faces joined through corners), one building each, id ``name#<layer>/c<k>`` (k from 1, in the
  order of the pieces' first faces). A 3DFACE whose fourth corner equals its third (or its first)
  is a triangle; a real quad is two triangles.
- **Faces**: a quad is split along a diagonal that keeps both triangles on the quad's side (the
  shorter one where both do); a face of more corners (a MESH's) is triangulated as a planar polygon
  (:func:`meshsom.polygons.triangulate_polygon_3d`). Faces of zero area (corners repeated or on a
  line, within :data:`DEGENERATE_REL`) are dropped and counted in a note; corners within
  :data:`WELD_REL` times a building's extent are one vertex.
- **Units**: the header's ``$INSUNITS`` (:data:`INSUNITS`): coordinates are scaled to metres and the
  unit noted; a drawing of no units (0, or a code not in the table) is read as metres, noted.
  Coordinates stay float64 and are re-centred per building (LV95's 2.6e6 m offsets keep their
  precision); a CRS (:attr:`meshsom.io.ReaderOptions.crs`, DXF declares none) applies as for mesh files.
- **Labels**: :attr:`meshsom.io.ReaderOptions.label_attribute`: ``"layer"`` labels every building
  by its layer (an INSERT's own layer, not its block's contents'); any other name labels an INSERT
  by the text of its ATTRIB of that tag (tags compared without case: AutoCAD writes them in upper
  case); otherwise no label.

- **ACIS solids**: each 3DSOLID and BODY (AutoCAD's solid modeller: EXTRUDE, PRESSPULL, UNION,
  SUBTRACT) is one building, id ``name#<handle>`` (in a block, part of the INSERT's building),
  tessellated from its ACIS boundary representation by :func:`meshsom.acis.acis_mesh` (SAT text in
  DXF R2000-R2010, SAB from R2013): planar faces with their holes, cylindrical and conical faces
  (curved facades, round towers) and spherical ones (domes), arcs within :data:`FLATTEN_REL` of the
  solid's extent; a block's solid is tessellated once for all its references. A solid with toroidal
  or spline faces (fillets, free forms) is a rejection saying so (in a block, noted, the rest of the
  block read).

Not read, each said: ACIS sheets (REGION, SURFACE and its kinds: not solids) are a rejection each;
a building's faces that cannot be read, or more
vertices than :attr:`~meshsom.io.ReaderOptions.max_vertices`, are a rejection; 2D entities (LINE,
LWPOLYLINE, TEXT, HATCH, ...) are counted by type in a note on every mesh of the file, and a file
with nothing 3D in its model space is refused (:class:`meshsom.errors.InputFileError`) saying what
it holds instead.
"""

from __future__ import annotations

import io
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterator

import numpy as np

from meshsom.acis import AcisError
from meshsom.errors import InputFileError

__all__ = ["INSUNITS", "read_dxf"]

#: How a binary DXF file starts.
BINARY_SENTINEL = b"AutoCAD Binary DXF\r\n\x1a\x00"

#: ``$INSUNITS`` codes: (name, metres per unit). 0 is "unitless"; codes not listed read as metres too.
INSUNITS = {
    1: ("inches", 0.0254), 2: ("feet", 0.3048), 3: ("miles", 1609.344), 4: ("millimetres", 1e-3),
    5: ("centimetres", 1e-2), 6: ("metres", 1.0), 7: ("kilometres", 1e3), 8: ("microinches", 2.54e-8),
    9: ("mils", 2.54e-5), 10: ("yards", 0.9144), 11: ("ångströms", 1e-10), 12: ("nanometres", 1e-9),
    13: ("micrometres", 1e-6), 14: ("decimetres", 0.1), 15: ("decametres", 10.0), 16: ("hectometres", 100.0),
    17: ("gigametres", 1e9), 18: ("astronomical units", 149_597_870_700.0), 19: ("light years", 9.460_730_472_580_8e15),
    20: ("parsecs", 3.085_677_581_491_367e16), 21: ("US survey feet", 1200 / 3937), 22: ("US survey inches", 100 / 3937),
    23: ("US survey yards", 3600 / 3937), 24: ("US survey miles", 6_336_000 / 3937),
}
METRES = 6
#: Corners closer than this times the extent (bounding-box diagonal) of a building, or of a layer's
#: loose 3DFACEs, are one vertex: equal positions written with float noise.
WELD_REL = 1e-9
#: A triangle whose doubled area is below this times its longest edge squared has zero area (its
#: corners on a line: the sine of its largest angle's supplement, about).
DEGENERATE_REL = 1e-10
#: Levels of nested block references followed at most (a block that refers to itself is corrupt).
MAX_BLOCK_DEPTH = 32
#: ACIS solids, tessellated from their boundary representation (:mod:`meshsom.acis`).
SOLID_TYPES = ("3DSOLID", "BODY")
#: ACIS entities that are sheets, not solids (a flat region, a surface): not buildings.
SHEET_TYPES = ("REGION", "SURFACE", "EXTRUDEDSURFACE", "LOFTEDSURFACE", "REVOLVEDSURFACE", "SWEPTSURFACE",
               "PLANESURFACE", "NURBSURFACE")
ACIS_TYPES = SOLID_TYPES + SHEET_TYPES
#: What to do with an ACIS sheet, in its rejection.
ACIS_ADVICE = ("a sheet, not a solid: not a building; make a solid of it in the CAD program (THICKEN, SURFSCULPT) "
               "or export the model as STL/OBJ")
#: Entities in a block that are no geometry (attribute definitions): not counted as left out.
NOT_GEOMETRY = ("ATTDEF",)
#: POLYLINE flags (group code 70): closed in M, polygon mesh, closed in N, polyface mesh.
M_CLOSED, POLYGON_MESH, N_CLOSED, POLYFACE = 1, 16, 32, 64
#: Quad corners, split along the 0-2 or the 1-3 diagonal (both keep the quad's winding).
SPLIT_02 = np.array([[0, 1, 2], [0, 2, 3]])
SPLIT_13 = np.array([[0, 1, 3], [1, 2, 3]])

_3D_WORDS = ("3D faces (3DFACE, POLYFACE, POLYGON MESH, MESH, closed polylines, circles, SOLIDs or TRACEs with a "
             "thickness, INSERT of them)")
#: Entities that are prisms where they have a thickness (2.5D block models): closed outlines, and the filled
#: triangles and quadrilaterals of SOLID and TRACE (AutoCAD shows them as prisms).
PRISM_TYPES = ("LWPOLYLINE", "POLYLINE", "CIRCLE", "SOLID", "TRACE")
#: The largest distance of a flattened arc (a polyline's bulge, a circle) from the arc, as a
#: fraction of the outline's extent (1 mm on a 10 m tower).
FLATTEN_REL = 1e-4


def read_dxf(path: Path, options, name: str | None = None) -> Iterator:
    """Read a DXF file's buildings (as the module says): RawMesh or Rejection items.

    Parameters
    ----------
    path : Path
        A DXF file (ASCII or binary), possibly gzipped.
    options : ReaderOptions
    name : str, optional
        The id's prefix (default the file's name).

    Yields
    ------
    RawMesh or Rejection
        Meshes and entities' rejections in model-space order, then the pieces of loose 3DFACEs, layer by
        layer (layers in the order of their first 3DFACE).

    Raises
    ------
    InputFileError
        The file is larger than ``options.max_bytes``, is not DXF or cannot be read, or its model
        space holds no 3D faces and no ACIS entities.
    """
    from meshsom.io import Rejection, file_crs

    name = name or path.name
    source = str(path)
    doc, repaired = _document(path, options)
    to_metres, unit_note = _units(doc)
    crs = file_crs(None, options)
    if crs[0] is not None and to_metres != 1.0:  # a CRS given: coordinates are in its units, scaled by it
        unit_note = f"{unit_note.split(',')[0]} not applied: coordinates read in the units of the CRS given ({crs[0].name})"
        to_metres = 1.0
    blocks = _Blocks(doc)
    jobs: list = []  # (kind, entity) in model-space order
    loose: dict[str, list] = {}  # layer -> [(4, 3) corners]
    flat: Counter = Counter()  # 2D entity types (and INSERTs of 2D blocks)
    for entity in doc.modelspace():
        kind = entity.dxftype()
        if kind == "3DFACE":
            loose.setdefault(entity.dxf.layer, []).append(_face_corners(entity))
        elif kind == "MESH" or (kind == "POLYLINE" and entity.dxf.flags & (POLYFACE | POLYGON_MESH)) or _is_prism(entity):
            jobs.append(("mesh", entity))
        elif kind in ("INSERT", "MINSERT"):
            held = blocks.holds(entity.dxf.name)
            if blocks.elsewhere(entity.dxf.name):
                jobs.append(("elsewhere", entity))
            elif held == "2d":
                flat["INSERT (of a 2D block)"] += 1
            else:
                jobs.append((held, entity))
        elif kind in SOLID_TYPES:
            jobs.append(("solid", entity))
        elif kind in SHEET_TYPES:
            jobs.append(("sheet", entity))
        else:
            flat["3D polyline (POLYLINE)" if kind == "POLYLINE" and entity.is_3d_polyline else kind] += 1
    if not jobs and not loose:
        raise InputFileError(source, f"holds no {_3D_WORDS}: " + _what_instead(doc, flat))
    notes = [unit_note] + ([repaired] if repaired else [])
    if flat:
        notes.append(f"2D drawing entities (not buildings) not read: {_counts(flat)}")
    if crs[1]:
        notes.append(crs[1])
    pieces, empty = [], []
    for layer, corners in loose.items():
        found, dropped = _loose_pieces(np.stack(corners) * to_metres)
        if not found:  # nothing of the layer to note it on
            empty.append((layer, len(corners)))
        elif dropped:
            notes.append(f"{dropped} 3DFACE entities of zero area on layer {layer!r} dropped")
        pieces.extend((f"{name}#{layer}/c{k}", layer, v, faces) for k, (v, faces) in enumerate(found, 1))
    ids: set[str] = set()

    def unique(mesh_id: str) -> str:
        k, out = 1, mesh_id
        while out in ids:  # a layer or block name that spells another's id
            k += 1
            out = f"{mesh_id}~{k}"
        ids.add(out)
        return out

    for kind, entity in jobs:
        handle = entity.dxf.handle
        layer_label = entity.dxf.layer if options.label_attribute == "layer" else None
        if kind == "sheet":
            yield Rejection(unique(f"{name}#{handle}"), source,
                            f"an ACIS {_acis_words(entity.dxftype())} ({entity.dxftype()}): {ACIS_ADVICE}", 0, layer_label)
            continue
        if kind in ("mesh", "solid"):
            mesh_id = unique(f"{name}#{handle}")
            try:
                part = _entity_part(entity, None) if kind == "mesh" else blocks.solid(entity)
            except AcisError as err:
                yield Rejection(mesh_id, source, f"an ACIS solid ({entity.dxftype()}) that {err}", 0, layer_label)
                continue
            except _ENTITY_ERRORS as err:
                yield Rejection(mesh_id, source, f"its {_type_words(entity)} cannot be read ({type(err).__name__}: {err})",
                                0, layer_label)
                continue
            yield from _building(mesh_id, source, [part], to_metres, crs, notes + part.notes, layer_label, options)
            continue
        label = layer_label if options.label_attribute == "layer" else _attrib_label(entity, options.label_attribute)
        block = entity.dxf.name
        if kind == "elsewhere":
            yield Rejection(unique(f"{name}#{block}@{handle}"), source, blocks.elsewhere(block), 0, label)
            continue
        for suffix, matrix in _copies(entity):
            mesh_id = unique(f"{name}#{block}@{handle}{suffix}")
            if kind == "acis":
                yield Rejection(mesh_id, source, f"its block {block!r} holds only ACIS sheets "
                                f"({_counts(blocks.content(block)[1])}): {ACIS_ADVICE}", 0, label)
                continue
            try:
                parts, acis, flat_in = blocks.parts(block, matrix)
            except _ENTITY_ERRORS as err:
                yield Rejection(mesh_id, source, f"its block {block!r} cannot be read ({type(err).__name__}: {err})", 0, label)
                continue
            if not parts and acis:
                yield Rejection(mesh_id, source, f"its block {block!r} holds no faces that can be read: "
                                f"{_acis_left_out(acis)}", 0, label)
                continue
            more = []
            if acis:
                more.append(f"ACIS entities in its block not read: {_acis_left_out(acis)}")
            if flat_in:
                more.append(f"entities of its block that hold no faces (2D drawing) not read: {_counts(flat_in)}")
            more.extend(dict.fromkeys(n for p in parts for n in p.notes))
            yield from _building(mesh_id, source, parts, to_metres, crs, notes + more, label, options)
    for layer, n in empty:
        yield Rejection(unique(f"{name}#{layer}"), source, f"its {n} loose 3DFACE entities all have zero area (or "
                        "coordinates that are not finite numbers)", n, layer if options.label_attribute == "layer" else None)
    for mesh_id, layer, v, faces in pieces:
        label = layer if options.label_attribute == "layer" else None
        yield _finished(unique(mesh_id), source, v, faces, crs, list(notes), label, options)


# --------------------------------------------------------------------------------------------
# The document
# --------------------------------------------------------------------------------------------

def _document(path: Path, options):
    """The DXF document of a file, read by ezdxf's recovering reader, and a note of what it repaired
    (None when nothing).

    Raises
    ------
    InputFileError
        Larger than ``options.max_bytes``, empty, not DXF, or damaged beyond repair.
    """
    from ezdxf import recover

    from meshsom.io import read_input_bytes

    content = bytes(read_input_bytes(path, options))
    try:
        if content.startswith(BINARY_SENTINEL):  # ezdxf's recovering reader reads ASCII DXF only
            from ezdxf.document import Drawing
            from ezdxf.lldxf.tagger import binary_tags_loader

            doc = Drawing.load(binary_tags_loader(content))
            auditor = doc.audit()
        else:
            try:  # ezdxf's plain loader, then its audit: three times as fast as the recovering reader
                doc = _plain(content)
                auditor = doc.audit()
            except Exception:  # a damaged file (DXFStructureError and others): the recovering reader
                doc, auditor = recover.read(io.BytesIO(content))
    except Exception as err:  # ezdxf raises many types for files that are not DXF (DXFStructureError most)
        raise InputFileError(str(path), f"cannot be read as DXF ({type(err).__name__}: {err}); expected a DXF drawing "
                                        "(ASCII or binary)") from None
    problems = len(auditor.fixes) + len(auditor.errors)
    return doc, f"damaged DXF: ezdxf's audit found {problems} problems (repaired where it could)" if problems else None


def _plain(content: bytes):
    """An ASCII DXF document loaded by ezdxf's plain loader, decoded as its header says
    (``$DWGCODEPAGE``; UTF-8 from R2007 on), as :func:`ezdxf.decode_base64` does.

    Raises
    ------
    Exception
        Whatever ezdxf raises for a file it cannot load plainly (a damaged one: read it with
        :mod:`ezdxf.recover`).
    """
    import ezdxf
    from ezdxf.filemanagement import dxf_stream_info

    text = content.replace(b"\r\n", b"\n")
    info = dxf_stream_info(io.StringIO(text.decode("utf-8", errors="ignore")))
    return ezdxf.read(io.StringIO(text.decode(info.encoding, errors="surrogateescape")))


def _units(doc) -> tuple[float, str]:
    """Metres per drawing unit (``$INSUNITS``), and a note saying which."""
    code = doc.header.get("$INSUNITS", 0)
    try:
        code = int(code)
    except (TypeError, ValueError):
        code = -1
    if code == METRES:
        return 1.0, "drawing units: metres"
    if code in INSUNITS:
        unit, metres = INSUNITS[code]
        return metres, f"drawing units: {unit}, scaled to metres"
    if code == 0:
        return 1.0, "drawing units not declared ($INSUNITS 0, unitless): read as metres"
    return 1.0, f"drawing units unknown ($INSUNITS {code}): read as metres"


def _what_instead(doc, flat: Counter) -> str:
    """What a model space of nothing 3D holds, in words (and where the paper space holds entities)."""
    said = f"only 2D drawing entities ({_counts(flat)})" if flat else "model space is empty"
    paper = sum(len(layout) for layout in doc.layouts if not layout.is_modelspace)
    if paper:
        said += f"; paper space layouts hold {paper} {'entity' if paper == 1 else 'entities'} (not read: only model space is)"
    return said


def _counts(counter: Counter) -> str:
    """``LINE x 40, TEXT x 3``: the commonest first."""
    return ", ".join(f"{kind} x {n}" for kind, n in sorted(counter.items(), key=lambda kv: (-kv[1], kv[0])))


def _acis_left_out(acis: Counter) -> str:
    """What a block's ACIS entities left out were: sheets (counted by type) and solids (by why)."""
    sheets = Counter({k: n for k, n in acis.items() if k in SHEET_TYPES})
    why = [f"{n} ACIS solid{'s' * (n != 1)} that {k}" for k, n in acis.items() if k not in SHEET_TYPES]
    return "; ".join(([f"{_counts(sheets)}: {ACIS_ADVICE}"] if sheets else []) + why)


def _acis_words(kind: str) -> str:
    return {"3DSOLID": "solid", "BODY": "body", "REGION": "region"}.get(kind, "surface")


def _type_words(entity) -> str:
    if entity.dxftype() == "MESH":
        return "MESH"
    return "POLYFACE mesh" if entity.dxf.flags & POLYFACE else "POLYGON MESH"


def _attrib_label(insert, tag: str) -> str | None:
    """The text of an INSERT's ATTRIB whose tag is ``tag`` (without case), else None."""
    wanted = tag.casefold()
    for attrib in insert.attribs:
        if str(attrib.dxf.tag).casefold() == wanted:
            return str(attrib.dxf.text)
    return None


# --------------------------------------------------------------------------------------------
# Entities' faces
# --------------------------------------------------------------------------------------------

#: What ezdxf raises for an entity whose data is inconsistent (a face record's index out of range, a
#: block that refers to itself, a polygon mesh of fewer vertices than M x N).
_ENTITY_ERRORS = (IndexError, ValueError, TypeError, KeyError, AttributeError, RecursionError)


@dataclass
class _Part:
    """Faces of one entity, in the world (block references applied), in drawing units.

    Attributes
    ----------
    vertices : (V, 3) float64
    faces : list of (F_k, k) int64
        Faces of k corners, indices into ``vertices``.
    notes : list of str
    """

    vertices: np.ndarray
    faces: list
    notes: list = field(default_factory=list)

    def transformed(self, matrix: np.ndarray | None) -> "_Part":
        """Moved by ``matrix`` ((4, 4), row vectors, as ezdxf's Matrix44), corners reversed where it mirrors."""
        if matrix is None:
            return self
        v = self.vertices @ matrix[:3, :3] + matrix[3, :3]
        faces = [f[:, ::-1] for f in self.faces] if np.linalg.det(matrix[:3, :3]) < 0 else self.faces
        return _Part(v, faces, self.notes)


def _face_corners(face) -> np.ndarray:
    """A 3DFACE's four corners, (4, 3) float64 (a triangle repeats its third)."""
    dxf = face.dxf
    return np.array([dxf.vtx0, dxf.vtx1, dxf.vtx2, dxf.get("vtx3", dxf.vtx2)], np.float64)


def _is_prism(entity) -> bool:
    """Whether ``entity`` is a closed outline with a thickness: a closed LWPOLYLINE or 2D POLYLINE (flagged closed,
    or ending where it starts: GIS exports write a ring so), a CIRCLE, a SOLID or a TRACE (an open polyline with a
    thickness is a wall or a fence, not a building)."""
    kind = entity.dxftype()
    if kind not in PRISM_TYPES or not float(entity.dxf.get("thickness", 0.0) or 0.0):
        return False
    if kind in ("CIRCLE", "SOLID", "TRACE"):
        return True
    if kind == "POLYLINE" and (entity.dxf.flags & (POLYFACE | POLYGON_MESH) or entity.is_3d_polyline):
        return False
    if entity.closed if kind == "LWPOLYLINE" else entity.is_closed:
        return True
    points = np.asarray([tuple(p)[:2] for p in (entity.vertices() if kind == "LWPOLYLINE" else entity.points())],
                        np.float64).reshape(-1, 2)
    if len(points) < 4:
        return False
    extent = float(np.linalg.norm(np.ptp(points, axis=0)))
    return extent > 0 and bool(np.linalg.norm(points[0] - points[-1]) <= FLATTEN_REL * extent * 1e-3)


def _prism_part(entity) -> _Part:
    """A closed outline with a thickness as the prism it draws: the outline (bulges and circles
    flattened within :data:`FLATTEN_REL` of its extent) extruded by the thickness along its
    extrusion direction (its OCS z axis), from its elevation."""
    from ezdxf import path as ezdxf_path
    from ezdxf.math import OCS

    from meshsom.polygons import extrude_polygon

    ocs = OCS(entity.dxf.get("extrusion", (0.0, 0.0, 1.0)))
    outline = ezdxf_path.make_path(entity)
    box = np.asarray([tuple(p) for p in outline.control_vertices()], np.float64).reshape(-1, 3)
    if len(box) < 2:
        raise ValueError(f"a {entity.dxftype()} of {len(box)} vertices outlines nothing")
    extent = float(np.linalg.norm(np.ptp(box, axis=0))) or 1.0
    wcs = np.asarray([tuple(p) for p in outline.flattening(FLATTEN_REL * extent)], np.float64).reshape(-1, 3)
    local = np.asarray([tuple(ocs.from_wcs(p)) for p in wcs], np.float64).reshape(-1, 3)
    if len(local) > 1 and np.allclose(local[0], local[-1], rtol=0.0, atol=FLATTEN_REL * extent * 1e-3):
        local = local[:-1]
    thickness = float(entity.dxf.thickness)
    z0 = float(np.median(local[:, 2]))
    try:
        v, f = extrude_polygon(local[:, :2], [], min(z0, z0 + thickness), max(z0, z0 + thickness))
    except Exception as err:  # GEOS on an outline that crosses itself, NumPy on a degenerate one
        raise ValueError(f"its outline cannot be triangulated ({type(err).__name__}: {err})") from None
    axes = np.array([tuple(ocs.ux), tuple(ocs.uy), tuple(ocs.uz)], np.float64)
    kind = entity.dxftype()
    note = f"a {'closed ' if kind in ('LWPOLYLINE', 'POLYLINE') else ''}{kind} with a thickness, read as the prism it draws (2.5D)"
    return _Part(v @ axes, [f], [note])


def _solid_part(entity) -> _Part:
    """A 3DSOLID's or BODY's ACIS data tessellated (:func:`meshsom.acis.acis_mesh`, arcs within
    :data:`FLATTEN_REL` of its extent).

    Raises
    ------
    AcisError
    """
    from meshsom.acis import acis_mesh

    if entity.doc is not None and entity.doc.dxfversion < "AC1015":
        raise AcisError("is in a drawing older than DXF R2000, whose ACIS data is not read")
    data = entity.sab if entity.has_binary_data else entity.sat
    mesh = acis_mesh(data, FLATTEN_REL)
    notes = []
    curved = {k: n for k, n in mesh.faces.items() if k != "plane"}
    if curved:
        kinds = ", ".join(f"{n} {k}" for k, n in curved.items())
        notes.append(f"curved faces of ACIS solids ({kinds}) tessellated, chords within {FLATTEN_REL:g} of the solid's extent")
    if mesh.dropped:
        notes.append(f"{mesh.dropped} triangles of an ACIS solid's faces left out (face boundaries that cross)")
    return _Part(mesh.vertices, [mesh.triangles], notes)


def _entity_part(entity, matrix: np.ndarray | None) -> _Part:
    """The faces of a 3DFACE, POLYFACE, POLYGON MESH or MESH entity, or of a closed outline with a
    thickness (:func:`_prism_part`), moved by ``matrix``."""
    kind = entity.dxftype()
    if _is_prism(entity):
        return _prism_part(entity).transformed(matrix)
    if kind == "3DFACE":
        return _Part(_face_corners(entity), [np.arange(4).reshape(1, 4)]).transformed(matrix)
    if kind == "MESH":
        v = np.asarray([tuple(p) for p in entity.vertices], np.float64).reshape(-1, 3)
        part = _Part(v, _grouped([tuple(f) for f in entity.faces], len(v)))
        levels = int(entity.dxf.get("subdivision_levels", 0) or 0)
        if levels:
            part.notes.append(f"MESH read as its control cage (subdivision level 0; the file asks for {levels} levels of smoothing)")
        return part.transformed(matrix)
    if entity.dxf.flags & POLYFACE:
        corners, records = entity.indexed_faces()
        v = np.asarray([tuple(c.dxf.location) for c in corners], np.float64).reshape(-1, 3)
        return _Part(v, _grouped([face.indices for face in records], len(v), base=1)).transformed(matrix)
    return _polygon_mesh(entity).transformed(matrix)


def _polygon_mesh(entity) -> _Part:
    """An M x N POLYGON MESH's quads (wrapping round where it is closed in M or N)."""
    m, n = int(entity.dxf.m_count), int(entity.dxf.n_count)
    v = np.asarray([tuple(p.dxf.location) for p in entity.vertices], np.float64).reshape(-1, 3)
    if m < 1 or n < 1 or len(v) != m * n:
        raise ValueError(f"a {m} x {n} polygon mesh holds {len(v)} vertices, expected {m * n}")
    flags = entity.dxf.flags
    rows = np.arange(m if flags & M_CLOSED and m > 2 else m - 1)
    cols = np.arange(n if flags & N_CLOSED and n > 2 else n - 1)
    i, j = np.meshgrid(rows, cols, indexing="ij")
    i, j = i.reshape(-1), j.reshape(-1)
    i1, j1 = (i + 1) % m, (j + 1) % n
    quads = np.stack([i * n + j, i * n + j1, i1 * n + j1, i1 * n + j], axis=1).astype(np.int64)
    part = _Part(v, [quads])
    if entity.dxf.get("smooth_type", 0):
        part.notes.append("POLYGON MESH read as its control vertices (its smooth surface is not evaluated)")
    return part


def _grouped(faces: list, n_vertices: int, base: int = 0) -> list:
    """Faces (sequences of 0-based vertex indices) grouped by corner count: a list of (F_k, k) int64
    arrays. ``base`` is the file's first index (1 for a POLYFACE's face records), for the message.

    Raises
    ------
    IndexError
        A face refers to a vertex that is not there.
    """
    by_size: dict[int, list] = {}
    for face in faces:
        by_size.setdefault(len(face), []).append(face)
    out = [np.asarray(group, np.int64).reshape(len(group), k) for k, group in sorted(by_size.items())]
    for f in out:
        if f.size and (f.min() < 0 or f.max() >= n_vertices):
            bad = int(f.max() if f.max() >= n_vertices else f.min())
            raise IndexError(f"a face refers to vertex {bad + base}, expected {base} to {n_vertices - 1 + base}")
    return out


class _Blocks:
    """The blocks of a document: what each holds (memoised), and the faces of a reference to one."""

    def __init__(self, doc):
        self.doc = doc
        self._held: dict[str, str] = {}
        self._solids: dict[str, object] = {}  # handle -> _Part or AcisError: a block's solid, tessellated once

    def solid(self, entity) -> "_Part":
        """The triangles of a 3DSOLID or BODY (:func:`meshsom.acis.acis_mesh`), in its own coordinates; memoised
        per entity (a block's solids are placed by every INSERT of it).

        Raises
        ------
        AcisError
        """
        handle = entity.dxf.handle
        if handle not in self._solids:
            try:
                self._solids[handle] = _solid_part(entity)
            except AcisError as err:
                self._solids[handle] = err
        found = self._solids[handle]
        if isinstance(found, AcisError):
            raise found
        return found

    def elsewhere(self, name: str) -> str | None:
        """Why the faces of block ``name`` are not in this drawing (an external reference, a block
        it lacks), or None."""
        block = self.doc.blocks.get(name)
        if block is None:
            return f"refers to block {name!r}, which the drawing does not hold (a damaged file?)"
        if block.block.is_xref:
            return (f"refers to an external drawing (xref {name!r}: {block.block.dxf.get('xref_path', '?')!r}), "
                    "which is not read through it; read that file on its own")
        return None

    def content(self, name: str, depth: int = 0) -> tuple[bool, Counter, Counter]:
        """Whether block ``name`` holds faces (itself or in nested blocks), its ACIS entities, its 2D ones."""
        faces, acis, flat = False, Counter(), Counter()
        block = self.doc.blocks.get(name)
        if block is None or depth > MAX_BLOCK_DEPTH:
            return faces, acis, flat
        for entity in block:
            kind = entity.dxftype()
            if kind in ("3DFACE", "MESH") + SOLID_TYPES or (
                    kind == "POLYLINE" and entity.dxf.flags & (POLYFACE | POLYGON_MESH)) or _is_prism(entity):
                faces = True
            elif kind in ("INSERT", "MINSERT"):
                held = self.holds(entity.dxf.name, depth + 1)
                faces |= held == "3d"
                if held == "acis":
                    acis.update(self.content(entity.dxf.name, depth + 1)[1])
            elif kind in SHEET_TYPES:
                acis[kind] += 1
            elif kind not in NOT_GEOMETRY:
                flat[kind] += 1
        return faces, acis, flat

    def holds(self, name: str, depth: int = 0) -> str:
        """``"3d"`` (faces or ACIS solids), ``"acis"`` (ACIS sheets and no faces) or ``"2d"`` (neither): block
        ``name``'s content."""
        if name not in self._held:
            self._held[name] = "2d"  # while it is looked at: a block that refers to itself holds nothing more
            faces, acis, _ = self.content(name, depth)
            self._held[name] = "3d" if faces else "acis" if acis else "2d"
        return self._held[name]

    def parts(self, name: str, matrix: np.ndarray, depth: int = 0) -> tuple[list, Counter, Counter]:
        """The faces of block ``name`` moved by ``matrix`` (4, 4), and the ACIS entities (sheets by type, solids by
        why) and 2D entities left out."""
        if depth > MAX_BLOCK_DEPTH:
            raise RecursionError(f"block references nested more than {MAX_BLOCK_DEPTH} deep (a block that refers to itself?)")
        parts, acis, flat = [], Counter(), Counter()
        faces_at: dict[int, list] = {}  # the block's 3DFACEs, read at once
        block = self.doc.blocks.get(name)
        if block is None:
            raise KeyError(f"the drawing has no block {name!r}")
        for entity in block:
            kind = entity.dxftype()
            if kind == "3DFACE":
                faces_at.setdefault(0, []).append(_face_corners(entity))
            elif kind == "MESH" or (kind == "POLYLINE" and entity.dxf.flags & (POLYFACE | POLYGON_MESH)) or _is_prism(entity):
                parts.append(_entity_part(entity, matrix))
            elif kind in ("INSERT", "MINSERT"):
                if self.elsewhere(entity.dxf.name):
                    flat["INSERT of an external drawing (xref) or a missing block"] += 1
                elif self.holds(entity.dxf.name) != "2d":
                    for _, inner in _copies(entity):
                        found, more_acis, more_flat = self.parts(entity.dxf.name, inner @ matrix, depth + 1)
                        parts += found
                        acis.update(more_acis)
                        flat.update(more_flat)
                else:
                    flat["INSERT (of a 2D block)"] += 1
            elif kind in SOLID_TYPES:
                try:
                    parts.append(self.solid(entity).transformed(matrix))
                except AcisError as err:
                    acis[str(err)] += 1
            elif kind in SHEET_TYPES:
                acis[kind] += 1
            elif kind not in NOT_GEOMETRY:
                flat[kind] += 1
        if faces_at:
            corners = np.stack(faces_at[0])
            quads = np.arange(4 * len(corners)).reshape(-1, 4)
            parts.append(_Part(corners.reshape(-1, 3), [quads]).transformed(matrix))
        return parts, acis, flat


def _copies(insert) -> list[tuple[str, np.ndarray]]:
    """An INSERT's placements: (id suffix, (4, 4) matrix), one, or one per distinct position of a MINSERT's grid."""
    base = np.array(list(insert.matrix44()), np.float64).reshape(4, 4)
    dxf = insert.dxf
    rows, cols = int(dxf.get("row_count", 1) or 1), int(dxf.get("column_count", 1) or 1)
    if rows * cols <= 1:
        return [("", base)]
    from ezdxf.math import Vec3

    ocs = insert.ocs()
    out, seen = [], set()
    for row in range(rows):
        for col in range(cols):
            # as AutoCAD places them: spacings in the OCS, turned by the rotation, not scaled
            offset = Vec3(col * dxf.get("column_spacing", 0.0), row * dxf.get("row_spacing", 0.0))
            if offset in seen:  # a spacing of 0: copies on top of each other are one building
                continue
            seen.add(offset)
            moved = base.copy()
            moved[3, :3] += np.array(tuple(ocs.to_wcs(offset.rotate_deg(dxf.get("rotation", 0.0)))), np.float64)
            out.append((f"/r{row + 1}c{col + 1}", moved))
    return out


# --------------------------------------------------------------------------------------------
# Triangles and buildings
# --------------------------------------------------------------------------------------------

def _triangles(vertices: np.ndarray, faces: list) -> tuple[np.ndarray, np.ndarray]:
    """Triangulate faces of any corner count.

    Parameters
    ----------
    vertices : (V, 3) float64
    faces : list of (F_k, k) int64
        Every face counted once, in the order given (faces of fewer than 3 corners too).

    Returns
    -------
    triangles : (T, 3) int64
        Possibly degenerate (see :func:`_degenerate`).
    face_of : (T,) int64
        The face (counting through ``faces``) each triangle is of.
    """
    from meshsom.polygons import triangulate_polygon_3d

    tris, owner = [np.zeros((0, 3), np.int64)], [np.zeros(0, np.int64)]
    start = 0
    for f in faces:
        k = f.shape[1]
        ids = np.arange(start, start + len(f))
        start += len(f)
        if k == 3:
            tris.append(f)
            owner.append(ids)
        elif k == 4:
            tris.append(_split_quads(vertices, f).reshape(-1, 3))
            owner.append(np.repeat(ids, 2))
        elif k > 4:  # a MESH's n-gons: rare, one at a time
            for face, fid in zip(f, ids):
                t = triangulate_polygon_3d([vertices[face]])
                tris.append(face[t])
                owner.append(np.full(len(t), fid))
    return np.concatenate(tris).astype(np.int64), np.concatenate(owner).astype(np.int64)


def _split_quads(vertices: np.ndarray, quads: np.ndarray) -> np.ndarray:
    """Split quads into two triangles each, along a diagonal whose two triangles face the same side
    (the shorter diagonal when both do, as for a flat convex quad).

    Parameters
    ----------
    vertices : (V, 3) float64
    quads : (Q, 4) int64

    Returns
    -------
    (Q, 2, 3) int64
    """
    a, b, c, d = (vertices[quads[:, i]] for i in range(4))
    a0 = a  # differences taken about each quad's first corner (precise at national-grid offsets)
    ok02 = np.einsum("ij,ij->i", np.cross(b - a0, c - a0), np.cross(c - a0, d - a0)) > 0
    ok13 = np.einsum("ij,ij->i", np.cross(b - a0, d - a0), np.cross(c - b, d - b)) > 0
    shorter02 = np.einsum("ij,ij->i", c - a, c - a) <= np.einsum("ij,ij->i", d - b, d - b)
    use02 = np.where(ok02 == ok13, shorter02, ok02)
    return np.where(use02[:, None, None], quads[:, SPLIT_02], quads[:, SPLIT_13])


def _degenerate(vertices: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """(T,) bool: triangles with a corner repeated, or corners on a line (:data:`DEGENERATE_REL`)."""
    t = triangles
    repeated = (t[:, 0] == t[:, 1]) | (t[:, 1] == t[:, 2]) | (t[:, 0] == t[:, 2])
    p = vertices[t]
    e = np.stack([p[:, 1] - p[:, 0], p[:, 2] - p[:, 1], p[:, 0] - p[:, 2]], axis=1)
    longest = (e**2).sum(axis=2).max(axis=1)
    area2 = np.linalg.norm(np.cross(e[:, 0], -e[:, 2]), axis=1)
    return repeated | ~(area2 > DEGENERATE_REL * longest)


def _welded_triangles(vertices: np.ndarray, faces: list) -> tuple[np.ndarray, np.ndarray, int]:
    """Merge corners within :data:`WELD_REL` of the extent, triangulate, drop zero-area triangles.

    Parameters
    ----------
    vertices : (V, 3) float64, finite
    faces : list of (F_k, k) int64

    Returns
    -------
    vertices : (W, 3) float64
        The merged corners (some possibly unused).
    triangles : (T, 3) int64
    dropped : int
        Faces left with no triangle (of zero area).
    """
    from meshsom.preprocess import weld

    extent = float(np.linalg.norm(np.ptp(vertices, axis=0))) if len(vertices) else 0.0
    welded, remap = weld(vertices, WELD_REL * extent)
    faces = [remap[f] for f in faces]
    tri, face_of = _triangles(welded, faces)
    n_faces = sum(len(f) for f in faces)
    keep = ~_degenerate(welded, tri) if len(tri) else np.zeros(0, bool)
    return welded, tri[keep], n_faces - len(np.unique(face_of[keep]))


def _building(mesh_id: str, source: str, parts: list, to_metres: float, crs, notes: list, label, options) -> list:
    """One building of ``parts`` (drawing units, world positions): [RawMesh or Rejection], or one per
    connected piece with :attr:`meshsom.io.ReaderOptions.split_components`."""
    from meshsom.io import Rejection

    n_faces = sum(len(f) for p in parts for f in p.faces)
    if not n_faces:
        return [Rejection(mesh_id, source, "holds no faces", 0, label)]
    offsets = np.cumsum([0] + [len(p.vertices) for p in parts])
    vertices = np.concatenate([p.vertices for p in parts]) * to_metres
    faces = [f + o for p, o in zip(parts, offsets) for f in p.faces]
    if not np.isfinite(vertices).all():
        return [Rejection(mesh_id, source, "has coordinates that are not finite numbers", n_faces, label)]
    v, tri, dropped = _welded_triangles(vertices, faces)
    if dropped:
        notes = notes + [f"{dropped} of its {n_faces} faces have zero area, dropped"]
    if not len(tri):
        return [Rejection(mesh_id, source, f"its {n_faces} faces all have zero area", n_faces, label)]
    if options.split_components:  # a district drawn as one mesh: a building per connected piece
        from meshsom.io import _connected_pieces

        split = _connected_pieces(mesh_id, v, tri, label)
        if len(split) > 1:
            more = [f"one of {len(split)} connected pieces of its entity (split_components)"]
            return [_finished(i, source, pv, pf, crs, notes + more, label, options) for i, pv, pf, _ in split]
    return [_finished(mesh_id, source, v, tri, crs, notes, label, options, n_faces)]


def _finished(mesh_id: str, source: str, vertices: np.ndarray, triangles: np.ndarray, crs, notes: list, label, options,
              n_faces: int | None = None):
    """RawMesh of the used ``vertices`` (metres, world) re-centred, or a Rejection (too many vertices,
    coordinates that look like degrees)."""
    from meshsom.io import RawMesh, Rejection, _in_metres, recentre

    n_faces = len(triangles) if n_faces is None else n_faces
    used, faces = np.unique(triangles, return_inverse=True)
    if len(used) > options.max_vertices:
        return Rejection(mesh_id, source, f"has {len(used):,} vertices, more than {options.max_vertices:,} "
                                          "(ReaderOptions.max_vertices)", n_faces, label)
    local, origin = recentre(vertices[used])
    try:
        local, more = _in_metres(mesh_id, local, origin, crs)
    except InputFileError as err:
        return Rejection(mesh_id, source, err.problem, n_faces, label)
    return RawMesh(mesh_id, source, local, faces.reshape(-1, 3).astype(np.int64), origin, label, None,
                   notes=tuple(notes + more))


def _loose_pieces(corners: np.ndarray) -> tuple[list, int]:
    """The connected pieces of one layer's loose 3DFACEs.

    Parameters
    ----------
    corners : (N, 4, 3) float64
        Metres, world positions.

    Returns
    -------
    pieces : list of (vertices (W, 3) float64, triangles (T, 3) int64)
        In the order of their first faces; each piece's triangles index the layer's merged corners
        ``vertices`` (shared by the pieces).
    dropped : int
        3DFACEs of zero area (or of coordinates that are not finite numbers).
    """
    from scipy import sparse
    from scipy.sparse.csgraph import connected_components

    finite = np.isfinite(corners).all(axis=(1, 2))
    good = corners[finite]
    quads = np.arange(4 * len(good)).reshape(-1, 4)
    v, tri, dropped = _welded_triangles(good.reshape(-1, 3), [quads])
    dropped += int((~finite).sum())
    if not len(tri):
        return [], dropped
    n = len(v)
    edges = np.concatenate([tri[:, [0, 1]], tri[:, [1, 2]]])
    graph = sparse.coo_matrix((np.ones(len(edges), np.int8), (edges[:, 0], edges[:, 1])), shape=(n, n))
    _, component = connected_components(graph, directed=False)
    of_tri = component[tri[:, 0]]
    _, first = np.unique(of_tri, return_index=True)
    order = np.argsort(first, kind="stable")  # pieces in the order of their first triangles
    rank = np.empty(len(first), np.int64)
    rank[order] = np.arange(len(first))
    piece = rank[np.searchsorted(np.unique(of_tri), of_tri)]
    sort = np.argsort(piece, kind="stable")
    bounds = np.cumsum(np.bincount(piece))[:-1]
    return [(v, t) for t in np.split(tri[sort], bounds)], dropped
