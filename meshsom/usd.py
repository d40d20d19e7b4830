"""Reading USD stages (``.usd``, ``.usda``, ``.usdc``, ``.usdz``): ArcGIS Pro's "Export 3D Objects" writes multipatch
buildings as USDC, NVIDIA Omniverse city digital twins are USD, and Apple's USDZ is a zip of one.

The stage is opened by Pixar's ``usd-core`` (module ``pxr``), its layers, references and instances composed as USD
composes them. Then:

- **Meshes**: every ``UsdGeom.Mesh`` is read at the stage's first time (``points``, ``faceVertexCounts``,
  ``faceVertexIndices``), its polygons triangulated in their own plane (L- and U-shaped faces too:
  :func:`meshsom.io.polygon_faces`, as PLY polygons are), its ``holeIndices`` faces left out, a
  ``leftHanded`` mesh's faces turned. A subdivision surface (``subdivisionScheme`` other than ``none``; USD's
  fallback is ``catmullClark``) is read as its control cage, noted. A ``UsdGeom.Cube`` (massing models) is read as its
  12 triangles.
- **Placement**: each mesh stands where its world transform puts it (``ComputeLocalToWorldTransform``: every
  ``xformOp`` of its ancestors); a mirroring transform keeps the faces' sides (their order is turned).
- **Instancing**: instanceable prims are read through their instance proxies, each instance where it stands; a
  ``PointInstancer``'s instances are placed by its ``positions``, ``orientations`` and ``scales`` with their
  prototype root's own transform (as ``ComputeInstanceTransformsAtTime`` composes them), instances its
  ``invisibleIds`` hide left out.
- **Buildings**: a mesh belongs to the nearest model of kind ``component`` above it (USD's model hierarchy: a leaf
  asset, as a building of a city assembly is); in a stage without kinds, to the prim that holds it (as the node
  that holds meshes is one building in FBX and glTF), or is one itself where it stands directly under the stage's
  root (its default prim, or its only root prim). A ``PointInstancer`` outside any component gives one building per
  instance. Id ``<file>#<prim path>`` (the path less its leading ``/``; ``<instancer path>[i]`` for an instance).
- **Units**: ``metersPerUnit`` (USD's fallback: 0.01, centimetres, noted where the stage does not author it).
- **Axes**: ``upAxis`` Y (USD's fallback, noted where not authored; ``corpus.reader.up_axis`` says which where it is
  not) is turned a quarter about x to z up, (x, y, z) -> (x, -z, y), noted, as glTF is; Z is read as it is.
- **Left out, noted**: invisible prims (``visibility = invisible``, inherited), ``guide`` purpose, ``proxy``
  purpose where the building has ``render`` meshes; gprims other than meshes and cubes (NURBS patches, curves,
  points, spheres, cylinders, cones, capsules): a building of only those is a rejection saying so.
- **Labels**: ``labels.csv`` beside the file (``file`` ``<name>`` or ``<name>#<prim path>``), as for OBJ.
"""

from __future__ import annotations

import dataclasses
import re
from pathlib import Path
from typing import Iterator

import numpy as np

from meshsom.errors import InputFileError

#: USD's metres per unit where a stage authors none (its ``metersPerUnit`` fallback: centimetres).
DEFAULT_METERS_PER_UNIT = 0.01
#: The model kind of one building (a leaf asset of USD's model hierarchy); its subkinds count too.
BUILDING_KIND = "component"
#: Purposes never drawn in a final render: left out.
GUIDE_PURPOSES = ("guide",)
#: The most characters of USD's own error messages quoted in a rejection.
ERROR_CHARS = 400
#: The C++ namespace pxr writes before its class names (``pxrInternal_v0_26_11__pxrReserved__::``).
_PXR_NAMESPACE = re.compile(r"pxrInternal_v[0-9_]+__pxrReserved__::")
#: The 12 triangles of a cube's 8 corners (``(x, y, z)`` for z, y, x in (-1, 1)), counter-clockwise seen from
#: outside.
CUBE_TRIANGLES = np.array([[0, 2, 3], [0, 3, 1], [4, 5, 7], [4, 7, 6], [0, 1, 5], [0, 5, 4], [2, 6, 7], [2, 7, 3],
                           [0, 4, 6], [0, 6, 2], [1, 3, 7], [1, 7, 5]], np.int64)
#: Gprims read: meshes, and cubes (massing models) as their 12 triangles.
READ_GPRIMS = ("Mesh", "Cube")
#: A quarter turn about x: y up -> z up (a proper rotation: faces keep their side), as for glTF.
Y_UP_TO_Z_UP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])


@dataclasses.dataclass
class _Building:
    """What one building gathers: its pieces ``(purpose, world vertices (V, 3) float64, faces (F, 3) int64)``, the
    gprims of it that are not read (type name -> count) and notes."""

    pieces: list = dataclasses.field(default_factory=list)
    unread: dict = dataclasses.field(default_factory=dict)
    notes: dict = dataclasses.field(default_factory=dict)  # ordered set
    error: str | None = None


def read_usd(path: Path, options, name: str | None = None) -> Iterator:
    """The buildings of a USD stage: a RawMesh per building (or a Rejection), as the module says.

    Parameters
    ----------
    path : Path
    options : ReaderOptions
    name : str, optional
        The start of the ids (default: the file name).

    Raises
    ------
    InputFileError
        usd-core is not installed, the file is larger than ``options.max_bytes``, USD cannot open it, or it holds
        no mesh.
    """
    from meshsom.io import library_input, read_decompressed

    _, gzipped = library_input(path, options, "USD", "pxr", "usd-core")
    if gzipped:  # USD opens files: the content, decompressed, in a temporary one
        yield from read_decompressed(path, options, name, read_usd)
        return
    yield from _stage_buildings(path, options, name or path.name)


def _open(path: Path):
    """The stage of ``path``, every payload loaded; InputFileError where USD cannot open it."""
    from pxr import Usd

    try:
        stage = Usd.Stage.Open(str(path), Usd.Stage.LoadAll)
    except Exception as err:  # pxr.Tf.ErrorException: what the file format plugin could not parse
        raise InputFileError(str(path), f"cannot be read as USD ({_usd_errors(_exception_text(err))})") from None
    if stage is None:
        raise InputFileError(str(path), "cannot be read as USD (the stage did not open)")
    return stage


def _exception_text(err: Exception) -> str:
    """What a ``pxr.Tf.ErrorException`` says; its text cannot be made where USD quotes bytes of the file that are not
    UTF-8 (a damaged or binary file read as text), and then says that."""
    try:
        return str(err)
    except UnicodeDecodeError:
        return "Error in 'parse' : 'the file holds bytes that are not UTF-8 text where USD's text syntax was expected'"


def _usd_errors(text: str) -> str:
    """The messages of a ``pxr.Tf.ErrorException`` (``Error in '<function>' at line N in file F : '<message>'``,
    one or more), less the C++ places, at most :data:`ERROR_CHARS` characters."""
    said = [part.split(" : ", 1)[1].strip().strip("'").strip() for part in " ".join(text.split()).split("Error in ")
            if " : " in part]
    said = [_PXR_NAMESPACE.sub("", m) for m in said if m]
    joined = "; ".join(dict.fromkeys(said)) or " ".join(text.split())
    return joined if len(joined) <= ERROR_CHARS else joined[:ERROR_CHARS - 3] + "..."


def stage_frame(stage, options) -> tuple[float, np.ndarray | None, list[str]]:
    """Metres per unit, the turn to z up (None for z up) and the notes of a stage (:func:`read_usd`'s units and
    axes)."""
    from pxr import UsdGeom

    notes = []
    metres = float(UsdGeom.GetStageMetersPerUnit(stage))
    if not UsdGeom.StageHasAuthoredMetersPerUnit(stage):
        metres = DEFAULT_METERS_PER_UNIT
        notes.append(f"the stage authors no metersPerUnit: read as {DEFAULT_METERS_PER_UNIT:g} m per unit "
                     f"(centimetres, USD's fallback)")
    if not (np.isfinite(metres) and metres > 0):
        raise InputFileError(str(stage.GetRootLayer().realPath), f"metersPerUnit is {metres!r}, expected a number > 0")
    if stage.HasAuthoredMetadata(UsdGeom.Tokens.upAxis):
        up = str(UsdGeom.GetStageUpAxis(stage)).upper()
    elif options.up_axis in ("y", "z"):
        up = options.up_axis.upper()
    else:
        up = "Y"
        notes.append("the stage authors no upAxis: read y up, USD's fallback (corpus.reader.up_axis: z, or --up z, "
                     "reads it z up)")
    if up == "Y":
        notes.append("upAxis Y: turned to z up")
        return metres, Y_UP_TO_Z_UP, notes
    return metres, None, notes


def _scene_roots(stage) -> set:
    """The paths of the prims whose children are a stage's top-level nodes: the pseudo-root, and the default prim
    (else the only root prim)."""
    roots = {stage.GetPseudoRoot().GetPath()}
    default = stage.GetDefaultPrim()
    children = stage.GetPseudoRoot().GetChildren()
    if default:
        roots.add(default.GetPath())
    elif len(children) == 1:
        roots.add(children[0].GetPath())
    return roots


def _component(prim):
    """The nearest prim at or above ``prim`` whose model kind is :data:`BUILDING_KIND` (or one of its subkinds), or
    None."""
    from pxr import Kind, Usd

    while prim and not prim.IsPseudoRoot():
        kind = Usd.ModelAPI(prim).GetKind()
        if kind and Kind.Registry.IsA(kind, BUILDING_KIND):
            return prim
        prim = prim.GetParent()
    return None


def _building_of(prim, roots: set):
    """The prim whose building a mesh prim belongs to (the module's rule)."""
    component = _component(prim)
    if component is not None:
        return component
    parent = prim.GetParent()
    return prim if parent.GetPath() in roots else parent


def _key(prim_path) -> str:
    return str(prim_path).lstrip("/")


def _stage_buildings(path: Path, options, name: str) -> Iterator:
    """The buildings of an uncompressed USD file."""
    from pxr import Tf, Usd, UsdGeom

    from meshsom.io import Rejection, _labels_beside, building_meshes, file_crs

    stage = _open(path)
    metres, turn, frame_notes = stage_frame(stage, options)
    time = Usd.TimeCode.EarliestTime()
    cache = UsdGeom.XformCache(time)
    roots = _scene_roots(stage)
    buildings: dict[str, _Building] = {}
    triangulated: dict = {}  # a mesh's (prototype's) path -> (points, faces, notes): an instance's read once
    try:
        hidden = _gather(stage, roots, time, cache, path, options, buildings, triangulated)
    except Tf.ErrorException as err:  # a value of the file that USD cannot unpack (a damaged crate file)
        raise InputFileError(str(path), f"cannot be read as USD ({_usd_errors(_exception_text(err))})") from None
    if not buildings:
        raise InputFileError(str(path), "holds no mesh (a USD stage of no UsdGeom.Mesh, or only invisible or guide "
                                        "prims)" + (f"; {hidden} invisible prims left out" if hidden else ""))
    labels = _labels_beside(path)
    label = labels.get(path.name)
    crs = file_crs(None, options)
    if hidden:
        frame_notes.append(f"{hidden} invisible prims of the stage left out (visibility = invisible)")
    for key, building in buildings.items():
        mesh_id = f"{name}#{key}"
        item_label = labels.get(f"{path.name}#{key}", label)
        pieces, notes = _drawn(building)
        if building.error is not None:
            yield Rejection(mesh_id, str(path), building.error, 0, item_label)
            continue
        if not pieces:
            kinds = ", ".join(f"{n} {k}" for k, n in building.unread.items())
            yield Rejection(mesh_id, str(path), f"holds no UsdGeom.Mesh or Cube (only {kinds}: gprims that are not "
                                                f"read; convert them to meshes)" if kinds else
                            "holds no UsdGeom.Mesh or Cube (its PointInstancer's prototypes hold none)",
                            0, item_label)
            continue
        vertices, faces = _joined(pieces)
        with np.errstate(over="ignore", invalid="ignore"):
            vertices = vertices * metres
        if not np.isfinite(vertices).all():
            yield Rejection(mesh_id, str(path), f"its coordinates times metersPerUnit ({metres:g}) are beyond "
                                                f"float64's range", 0, item_label)
            continue
        if turn is not None:
            vertices = vertices @ turn.T
        yield from building_meshes(mesh_id, str(path), vertices, faces, item_label, crs,
                                   tuple(frame_notes) + tuple(notes), options)


def _gather(stage, roots: set, time, cache, path: Path, options, buildings: dict, triangulated: dict) -> int:
    """Each drawn prim of the stage into its building of ``buildings`` (key -> :class:`_Building`); the number of
    invisible prims left out. A mesh whose values USD cannot unpack is its building's rejection."""
    from pxr import Tf, Usd, UsdGeom

    hidden = 0
    walk = iter(Usd.PrimRange.Stage(stage, Usd.TraverseInstanceProxies(Usd.PrimDefaultPredicate)))
    for prim in walk:
        imageable = UsdGeom.Imageable(prim)
        if not imageable:
            continue
        if imageable.GetVisibilityAttr().Get(time) == UsdGeom.Tokens.invisible:
            hidden += 1
            walk.PruneChildren()
            continue
        purpose = str(imageable.ComputePurpose())
        if purpose in GUIDE_PURPOSES:
            walk.PruneChildren()
            continue
        if prim.IsA(UsdGeom.PointInstancer):
            walk.PruneChildren()  # its prototypes are drawn by its instances only
            try:
                _point_instances(prim, roots, time, cache, str(path), options, triangulated, buildings)
            except InputFileError as err:  # the instancer's buildings (or its component) are not read
                owner = buildings.setdefault(_key((_component(prim) or prim).GetPath()), _Building())
                owner.error = owner.error or err.problem
            continue
        if not prim.IsA(UsdGeom.Gprim):
            continue
        owner = buildings.setdefault(_key(_building_of(prim, roots).GetPath()), _Building())
        if str(prim.GetTypeName()) not in READ_GPRIMS:
            kind = str(prim.GetTypeName())
            owner.unread[kind] = owner.unread.get(kind, 0) + 1
            continue
        try:
            points, faces, notes = _mesh(prim, time, str(path), options, triangulated)
            world = np.asarray(cache.GetLocalToWorldTransform(prim), np.float64)
        except InputFileError as err:  # its building is not read, the others are
            owner.error = owner.error or f"{err.source}: {err.problem}"
            continue
        except Tf.ErrorException as err:  # a damaged value
            owner.error = owner.error or (f"{path}: mesh {prim.GetPath()} cannot be read "
                                          f"({_usd_errors(_exception_text(err))})")
            continue
        owner.pieces.append((purpose, *_placed(points, faces, world)))
        owner.notes.update(dict.fromkeys(notes))
    return hidden


def _drawn(building: _Building) -> tuple[list, list[str]]:
    """A building's pieces as a final render draws them (``proxy`` ones only where it has no ``render`` ones) and
    its notes."""
    notes = list(building.notes)
    purposes = {p for p, _, _ in building.pieces}
    pieces = building.pieces
    if "render" in purposes and "proxy" in purposes:
        pieces = [p for p in pieces if p[0] != "proxy"]
        notes.append("its proxy-purpose meshes left out (it has render-purpose ones)")
    if building.unread and pieces:
        kinds = ", ".join(f"{n} {k}" for k, n in building.unread.items())
        notes.append(f"left out: {kinds} (gprims other than meshes and cubes are not read)")
    return [(v, f) for _, v, f in pieces], notes


def _joined(pieces: list) -> tuple[np.ndarray, np.ndarray]:
    """One mesh of a building's pieces ``(vertices (V, 3), faces (F, 3))``: vertices at the same place one vertex
    (the meshes of one building meet at their edges)."""
    from meshsom.fbx import _united

    return _united(pieces)


def _placed(points: np.ndarray, faces: np.ndarray, matrix: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``points (V, 3)`` moved by a USD matrix (4 x 4, row vectors: ``p @ M[:3, :3] + M[3, :3]``) and ``faces
    (F, 3)``, turned where the matrix mirrors."""
    vertices = points @ matrix[:3, :3] + matrix[3, :3]
    if np.linalg.det(matrix[:3, :3]) < 0:
        faces = faces[:, ::-1]
    return vertices, np.ascontiguousarray(faces)


def _mesh(prim, time, where: str, options, triangulated: dict) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """``(points (V, 3) float64, faces (F, 3) int64, notes)`` of a UsdGeom.Mesh in its own frame, read once per
    prototype (an instance proxy's mesh is its prototype's)."""
    key = prim.GetPrimInPrototype().GetPath() if prim.IsInstanceProxy() else prim.GetPath()
    if key not in triangulated:
        triangulated[key] = _triangles(prim, time, f"{where}: mesh {prim.GetPath()}", options)
    return triangulated[key]


def _values(attribute, time, dtype, width: int, where: str) -> np.ndarray:
    """An array attribute's values at ``time`` as ``(N, width)`` (``(N,)`` for width 1) ``dtype``; InputFileError
    where it holds something else (a single value, another type)."""
    value = attribute.Get(time)
    if value is None:  # not authored: no points, no faces
        return np.zeros((0, width) if width > 1 else 0, dtype)
    try:
        array = np.asarray(value, dtype)
    except (TypeError, ValueError):
        array = None
    if array is None or array.ndim != (1 if width == 1 else 2) or (width > 1 and len(array) and array.shape[1] != width):
        raise InputFileError(where, f"its {attribute.GetName()} holds {str(value)[:60]!r} ("
                                    f"{type(value).__name__}), expected an array of " +
                                    (f"{width}-vectors" if width > 1 else "integers"))
    if array.dtype.kind == "f" and not np.isfinite(array).all():
        raise InputFileError(where, f"its {attribute.GetName()} hold a value that is not a finite number (NaN or inf)")
    return array.reshape(-1, width) if width > 1 else array


def _cube(prim, time, where: str) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """The 8 corners and 12 outward triangles of a UsdGeom.Cube of its ``size`` (edge length; 2 by default), centred
    on its origin."""
    from pxr import UsdGeom

    size = UsdGeom.Cube(prim).GetSizeAttr().Get(time)
    if not (isinstance(size, (int, float)) and np.isfinite(size) and size > 0):
        raise InputFileError(where, f"its size is {size!r}, expected a number > 0")
    corners = np.array([(x, y, z) for z in (-1, 1) for y in (-1, 1) for x in (-1, 1)], np.float64) * (size / 2)
    return corners, CUBE_TRIANGLES.copy(), []


def _triangles(prim, time, where: str, options) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """The triangles of a UsdGeom.Mesh (:func:`_mesh`); InputFileError (naming the file and the mesh) for counts
    and indices that do not agree."""
    from pxr import UsdGeom

    from meshsom.io import polygon_faces

    if prim.IsA(UsdGeom.Cube):
        return _cube(prim, time, where)
    mesh = UsdGeom.Mesh(prim)
    points = _values(mesh.GetPointsAttr(), time, np.float64, 3, where)
    counts = _values(mesh.GetFaceVertexCountsAttr(), time, np.int64, 1, where)
    indices = _values(mesh.GetFaceVertexIndicesAttr(), time, np.int64, 1, where)
    notes = []
    if len(points) > options.max_vertices:
        raise InputFileError(where, f"has {len(points):,} points, more than max_vertices ({options.max_vertices:,})")
    if (counts < 0).any() or counts.sum() != len(indices):
        raise InputFileError(where, f"faceVertexCounts add up to {int(counts.sum())}, and there are {len(indices)} "
                                    f"faceVertexIndices")
    if len(indices) and (indices.min() < 0 or indices.max() >= len(points)):
        bad = int(indices[(indices < 0) | (indices >= len(points))][0])
        raise InputFileError(where, f"a face refers to point {bad}, and the mesh has {len(points)} points")
    if not np.isfinite(points).all():
        raise InputFileError(where, "has points that are not finite numbers")
    face = np.repeat(np.arange(len(counts)), counts)
    keep = counts >= 3
    holes = np.asarray(mesh.GetHoleIndicesAttr().Get(time) or [], np.int64)
    holes = holes[(holes >= 0) & (holes < len(counts))]
    if len(holes):
        keep[holes] = False
        notes.append(f"{len(holes)} faces its holeIndices name left out")
    if (counts < 3).any():
        notes.append(f"{int((counts < 3).sum())} faces of fewer than 3 vertices left out")
    scheme = mesh.GetSubdivisionSchemeAttr().Get(time)
    if scheme != UsdGeom.Tokens.none:
        said = "" if mesh.GetSubdivisionSchemeAttr().HasAuthoredValue() else " (USD's fallback)"
        notes.append(f"subdivisionScheme {scheme}{said}: its control cage is read, not the limit surface")
    counts, indices = counts[keep], indices[keep[face]]
    faces, dropped = polygon_faces(indices, counts, points) if len(counts) else (np.zeros((0, 3), np.int64), 0)
    if dropped:
        notes.append(f"{dropped} self-crossing polygons lost the triangles that would need the crossing point")
    if mesh.GetOrientationAttr().Get(time) == UsdGeom.Tokens.leftHanded:
        faces = faces[:, ::-1]
    return points, np.ascontiguousarray(faces, np.int64), notes


def _point_instances(prim, roots: set, time, cache, where: str, options, triangulated: dict, buildings: dict) -> None:
    """Add a PointInstancer's instances to ``buildings``: each one a building of its own (``<instancer>[i]``), or
    part of the component it stands in."""
    from pxr import Usd, UsdGeom

    instancer = UsdGeom.PointInstancer(prim)
    targets = instancer.GetPrototypesRel().GetTargets()
    proto_index = np.asarray(instancer.GetProtoIndicesAttr().Get(time) or [], np.int64)
    transforms = instancer.ComputeInstanceTransformsAtTime(time, time, UsdGeom.PointInstancer.IncludeProtoXform,
                                                           UsdGeom.PointInstancer.IgnoreMask)
    mask = instancer.ComputeMaskAtTime(time) or [True] * len(proto_index)
    if len(proto_index) and (proto_index.min() < 0 or proto_index.max() >= len(targets)):
        raise InputFileError(f"{where}: PointInstancer {prim.GetPath()}",
                             f"protoIndices name prototype {int(proto_index.max())}, and it has {len(targets)}")
    stage = prim.GetStage()
    prototypes = []  # per prototype: its meshes' (purpose, points, faces, notes, matrix relative to the prototype),
    unread = []  # and its gprims that are not read, by type
    for target in targets:
        root = stage.GetPrimAtPath(target)
        inside = np.linalg.inv(np.asarray(cache.GetLocalToWorldTransform(root), np.float64))
        meshes, skipped = [], {}
        walk = iter(Usd.PrimRange(root, Usd.TraverseInstanceProxies(Usd.PrimDefaultPredicate)))
        for part in walk:
            imageable = UsdGeom.Imageable(part)
            if part != root and imageable and imageable.GetVisibilityAttr().Get(time) == UsdGeom.Tokens.invisible:
                walk.PruneChildren()
                continue
            purpose = str(imageable.GetPurposeAttr().Get(time)) if imageable else "default"
            if purpose in GUIDE_PURPOSES or not part.IsA(UsdGeom.Gprim):
                continue
            if str(part.GetTypeName()) not in READ_GPRIMS:
                skipped[str(part.GetTypeName())] = skipped.get(str(part.GetTypeName()), 0) + 1
                continue
            relative = np.asarray(cache.GetLocalToWorldTransform(part), np.float64) @ inside
            meshes.append((purpose, *_mesh(part, time, where, options, triangulated), relative))
        prototypes.append(meshes)
        unread.append(skipped)
    component = _component(prim)
    world = np.asarray(cache.GetLocalToWorldTransform(prim), np.float64)
    for i, (k, matrix) in enumerate(zip(proto_index.tolist(), transforms)):
        if not mask[i]:
            continue
        key = _key(component.GetPath()) if component is not None else f"{_key(prim.GetPath())}[{i}]"
        owner = buildings.setdefault(key, _Building())
        placed = np.asarray(matrix, np.float64) @ world
        for kind, n in unread[k].items():
            owner.unread[kind] = owner.unread.get(kind, 0) + n
        for purpose, points, faces, notes, relative in prototypes[k]:
            owner.pieces.append((purpose, *_placed(points, faces, relative @ placed)))
            owner.notes.update(dict.fromkeys(notes))
