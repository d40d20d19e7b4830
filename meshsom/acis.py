"""ACIS solids as triangle meshes: the boundary representation inside DXF 3DSOLID and BODY entities.

AutoCAD, BricsCAD and the other CAD programs with a solid modeller store a 3D solid as ACIS data
(SAT text in DXF R2000-R2010, SAB binary from R2013): a body of lumps, each of shells, each of faces
bounded by loops of coedges, which run along edges between vertices. ezdxf parses both encodings into
that graph but knows only the plane and the straight line of its geometry. This module adds the
curved kinds building massing models are made of, the ``ellipse-curve`` (a circular or elliptical
edge), the ``cone-surface`` (a cylindrical or conical face: a curved facade, a round tower, a spire)
and the ``sphere-surface`` (a dome), and tessellates a body:

- **Edges** are sampled once each, so the two faces that share an edge share its points and the mesh
  is watertight: a straight edge is its two vertices; an elliptical arc is split into equal steps of
  its parameter whose chords stay within ``flatten`` (a length) of the arc where it bends most. Tolerant modelling's ``tedge``,
  ``tvertex`` and ``tcoedge`` are read as their plain kinds.
- **A planar face**: its loops (outer boundary and holes: the largest is the boundary) triangulated
  in its plane (:func:`meshsom.polygons.triangulate_polygon_3d`, constrained Delaunay, no new points).
- **A cylindrical or conical face** (circular or elliptical): its loops unrolled onto (angle x
  radius, height along the axis) and triangulated there. A face that goes all the way round is
  read in each of ACIS's forms: one loop running up a seam edge and back down (AutoCAD's CYLINDER),
  two loops that each wrap round the axis (cut here along a seam between them, placed away from any
  hole), a cone's loop running up a seam to an apex vertex and back (AutoCAD's CONE), or a cone
  bounded by its base alone (its apex where the surface closes, from the half angle). Triangles
  whose edges span more than :data:`INSIDE_SPAN_STEPS` of the arcs' angle step would cut through
  the solid: they are split (longest-edge bisection) with points placed on the surface; edges from
  an apex are generators and never split. So is a triangle turned more than
  :data:`MAX_TILT_DEGREES` from the surface (three points of one loop, lying across the face).
- **A spherical face** (a dome, a cupola, a spherical cap): mapped to the plane by the azimuthal
  equidistant projection about the sphere's pole nearer to it (a cap round its pole is a disk, a band
  an annulus: no seam to cut), triangulated there, and refined the same way by chord length in space;
  AutoCAD's meridian seam up to a pole vertex and back is a slit there and is left out.
- **Orientation**: ACIS runs a loop's coedges with the face on their left seen from outside the
  solid; each face's triangles are turned to run its first edge the same way, so a closed body comes
  out with outward normals whatever the face's sense. The body's transformation is applied (a
  mirroring one reverses the triangles).

Not tessellated, each raising :class:`AcisError` that names them: tori, spline surfaces and spline
edges (fillets, free forms), and whole balls (a sphere without edges). Such bodies are converted to a
mesh in the CAD program (MESHSMOOTH) or exported as STL or OBJ.
"""

from __future__ import annotations

from collections import Counter

import numpy as np

__all__ = ["AcisError", "AcisMesh", "acis_mesh"]

#: The fewest segments of a whole ellipse, however coarse ``flatten`` is against it.
MIN_SEGMENTS_PER_TURN = 8
#: Two vertex positions closer than this fraction of the body's extent are one point (an edge that
#: starts where it ends is a whole ellipse).
SAME_POINT_REL = 1e-9
#: An edge inside a curved face may span this many of its arcs' angle steps before it is split (its
#: chord then stays within about this number squared times ``flatten`` of the surface; 1 would split
#: every edge whose ends are out of phase with the arcs, a cascade of thin triangles).
INSIDE_SPAN_STEPS = 2.0
#: A triangle of a curved face turned more than this from the surface (its normal against the surface's
#: at its centre) is split, however short its edges: it lies across the surface, not along it.
MAX_TILT_DEGREES = 30.0
#: The most passes of edge splitting on one curved face (each pass splits many edges at once; a face
#: needs about log2 of its widest triangle's angle over the step).
MAX_REFINE_PASSES = 256
#: How SAT text from ASM (AutoCAD 2013 and later) ends.
END_OF_ASM_DATA = "End-of-ASM-data"
#: Names of the topology entities, whose tolerant kinds (``tvertex-vertex``, ...) are read as the plain
#: kind named after the last hyphen.
_TOPOLOGY = ("body", "lump", "shell", "face", "loop", "coedge", "edge", "vertex", "point", "transform")


class AcisError(ValueError):
    """ACIS data that cannot be read or tessellated; the message, a predicate (``"has faces of ..."``), says why
    and the caller names the entity and the file."""


class AcisMesh:
    """The triangles of one ACIS entity's bodies.

    Attributes
    ----------
    vertices : (V, 3) float64
        Drawing units, world (the bodies' transformations applied).
    triangles : (T, 3) int64
        Outward for a closed body.
    faces : Counter
        Faces read, by surface kind (``plane``, ``cylindrical``, ``conical``).
    dropped : int
        Triangles left out where a face's loops cross themselves or each other.
    """

    def __init__(self, vertices: np.ndarray, triangles: np.ndarray, faces: Counter, dropped: int):
        self.vertices, self.triangles, self.faces, self.dropped = vertices, triangles, faces, dropped


def acis_mesh(data, flatten_rel: float) -> AcisMesh:
    """Tessellate the ACIS data of a DXF entity (as the module says).

    Parameters
    ----------
    data : list of str or bytes
        SAT lines (DXF R2000-R2010: ezdxf's ``entity.sat``) or SAB bytes (R2013 and later: ``entity.sab``).
    flatten_rel : float
        The largest distance of a chord from its arc, as a fraction of the entity's extent.

    Returns
    -------
    AcisMesh

    Raises
    ------
    AcisError
        The data cannot be parsed, holds no solid, or has faces or edges of kinds not tessellated here.
    """
    from ezdxf.acis.const import AcisException

    try:
        bodies = _loader(data).bodies_read()
    except (AcisException, ValueError, TypeError, IndexError, KeyError, AttributeError, UnicodeError,
            RecursionError) as err:
        raise AcisError(f"has ACIS data that cannot be read ({type(err).__name__}: {err})") from None
    if not bodies:
        raise AcisError("holds no ACIS body")
    try:
        return _Tessellation(bodies, flatten_rel).run()
    except AcisError:
        raise
    except (AttributeError, TypeError, ValueError, IndexError, ZeroDivisionError) as err:
        # a NONE reference where a face, loop or vertex must be: a damaged graph
        raise AcisError(f"is not a whole boundary representation ({type(err).__name__}: {err})") from None


# --------------------------------------------------------------------------------------------
# Parsing: ezdxf's loaders with the two curved kinds added
# --------------------------------------------------------------------------------------------

def _curved_classes():
    from ezdxf.acis import entities as acis
    from ezdxf.acis.const import AcisException

    acis_errors = (AcisException, ValueError, IndexError, TypeError)

    class Ellipse(acis.Curve):
        """``ellipse-curve``: P(t) = center + major cos t + ratio (normal x major) sin t."""

        type = "ellipse-curve"

        def restore_data(self, loader) -> None:
            self.center = np.array(loader.read_vec3(), np.float64)
            self.normal = np.array(loader.read_vec3(), np.float64)
            self.major = np.array(loader.read_vec3(), np.float64)
            self.ratio = float(loader.read_double())

        def evaluate(self, param: float):
            return self.center + self.major * np.cos(param) + self.ratio * np.cross(self.normal, self.major) * np.sin(param)

    class Cone(acis.Surface):
        """``cone-surface``: its base ellipse (origin, axis, major axis, ratio); the half angle is not needed to
        unroll it."""

        type = "cone-surface"

        def restore_data(self, loader) -> None:
            self.origin = np.array(loader.read_vec3(), np.float64)
            self.axis = np.array(loader.read_vec3(), np.float64)
            self.major = np.array(loader.read_vec3(), np.float64)
            self.ratio = float(loader.read_double())
            self.sine = self.cosine = None  # the half angle's: sine 0 for a cylinder; after the base ellipse's range
            try:
                for _ in range(2):
                    loader.read_interval()
            except acis_errors:
                pass
            try:
                self.sine = float(loader.read_double())
                self.cosine = float(loader.read_double())
            except acis_errors:
                self.sine = self.cosine = None

        def evaluate(self, u: float, v: float):  # not used: faces are tessellated from their edges
            raise NotImplementedError

    class Sphere(acis.Surface):
        """``sphere-surface``: centre, radius (negative: its normals point in), origin of longitude, pole."""

        type = "sphere-surface"

        def restore_data(self, loader) -> None:
            self.center = np.array(loader.read_vec3(), np.float64)
            self.radius = float(loader.read_double())
            self.uv_origin = np.array(loader.read_vec3(), np.float64)
            self.pole = np.array(loader.read_vec3(), np.float64)

        def evaluate(self, u: float, v: float):  # not used: faces are tessellated from their edges
            raise NotImplementedError

    return {"ellipse-curve": Ellipse, "cone-surface": Cone, "sphere-surface": Sphere}


def _loader(data):
    from ezdxf.acis import entities as acis

    curved = _curved_classes()

    class Factory:
        def entity_factory(self, raw):
            uid = id(raw)
            entity = self.entities.get(uid)
            if entity is None:
                name = str(raw.name)
                cls = curved.get(name) or acis.ENTITY_TYPES.get(name)
                last = name.rsplit("-", 1)[-1]
                if cls is None and last in _TOPOLOGY:
                    cls = acis.ENTITY_TYPES.get(last)
                entity = (cls or acis.AcisEntity)()
                entity.acis_name = name
                self.entities[uid] = entity
            return entity

        def bodies_read(self):
            self.load_entities()
            return self.bodies()

    if isinstance(data, (bytes, bytearray)):
        return type("SabLoader", (Factory, acis.SabLoader), {})(data)
    lines = [data] if isinstance(data, str) else list(data)
    if len(lines) == 1:
        lines = lines[0].splitlines()
    for k, line in enumerate(lines):  # ASM's end marker (AutoCAD 2013 and later), which ezdxf's SAT parser reads as a record
        if line.startswith(END_OF_ASM_DATA):
            lines = lines[:k]
            break
    return type("SatLoader", (Factory, acis.SatLoader), {})(lines)


# --------------------------------------------------------------------------------------------
# Tessellation
# --------------------------------------------------------------------------------------------

def _walk(first, link: str) -> list:
    """The entities of a linked list from ``first`` along attribute ``link`` (until a NONE or a repeat)."""
    out, seen, item = [], set(), first
    while not item.is_none and id(item) not in seen:
        seen.add(id(item))
        out.append(item)
        item = getattr(item, link)
    return out


def _name(entity) -> str:
    return getattr(entity, "acis_name", entity.type)


class _Tessellation:
    def __init__(self, bodies: list, flatten_rel: float):
        self.bodies = bodies
        self.flatten_rel = float(flatten_rel)
        self.points: list[np.ndarray] = []
        self.vertex_index: dict[int, int] = {}
        self.edge_index: dict[int, np.ndarray] = {}
        self.kinds: Counter = Counter()
        self.dropped = 0

    def run(self) -> AcisMesh:
        faces = [(body, face) for body in self.bodies for lump in _walk(body.lump, "next_lump")
                 for shell in _walk(lump.shell, "next_shell") for face in _walk(shell.face, "next_face")]
        if not faces:
            raise AcisError("has ACIS bodies of no faces (a wire or an empty solid)")
        unknown = Counter(_name(face.surface) for _, face in faces
                          if face.surface.type not in ("plane-surface", "cone-surface", "sphere-surface"))
        if unknown:
            raise AcisError(f"has faces of curved kinds not tessellated here ({_kinds(unknown)}: fillets, free "
                            "forms); convert it to a mesh in the CAD program (MESHSMOOTH) or export it as STL/OBJ")
        extent = self._extent(faces)
        self.flatten, self.same = self.flatten_rel * extent, SAME_POINT_REL * extent
        out, placed = [np.zeros((0, 3), np.int64)], []
        for body in self.bodies:
            first_point = len(self.points)
            mine = [self._face(face) for owner, face in faces if owner is body]
            matrix = _matrix(body)
            if matrix is not None:
                placed.append((first_point, len(self.points), matrix))
                if np.linalg.det(matrix[:3, :3]) < 0:  # mirrored: the triangles keep their side
                    mine = [t[:, ::-1] for t in mine]
            out.extend(mine)
        vertices = np.asarray(self.points, np.float64).reshape(-1, 3)
        for start, stop, m in placed:
            vertices[start:stop] = vertices[start:stop] @ m[:3, :3] + m[3, :3]
        return AcisMesh(vertices, np.concatenate(out).astype(np.int64), self.kinds, self.dropped)

    # ---- geometry of the body -------------------------------------------------------------

    def _extent(self, faces: list) -> float:
        pts = []
        for _, face in faces:
            for loop in _walk(face.loop, "next_loop"):
                for coedge in _walk(loop.coedge, "next_coedge"):
                    edge = coedge.edge
                    pts.append(_location(edge.start_vertex))
                    curve = edge.curve
                    if curve.type == "ellipse-curve":  # its circle's box: r sqrt(1 - n_i^2) about the centre
                        normal = curve.normal / np.linalg.norm(curve.normal)
                        half = float(np.linalg.norm(curve.major)) * np.sqrt(np.clip(1.0 - normal ** 2, 0.0, 1.0))
                        pts.extend([curve.center - half, curve.center + half])
        if not pts:
            raise AcisError("has no edges: a closed surface without a boundary (a whole sphere or torus), not "
                            "tessellated here")
        pts = np.asarray(pts, np.float64)
        extent = float(np.linalg.norm(np.ptp(pts, axis=0)))
        if not np.isfinite(extent):
            raise AcisError("has coordinates that are not finite numbers")
        return extent or 1.0

    def _vertex(self, vertex) -> int:
        key = id(vertex)
        if key not in self.vertex_index:
            self.vertex_index[key] = len(self.points)
            self.points.append(_location(vertex))
        return self.vertex_index[key]

    def _edge(self, edge) -> np.ndarray:
        """Indices of the edge's points, from its start vertex to its end vertex."""
        key = id(edge)
        if key in self.edge_index:
            return self.edge_index[key]
        a, b = self._vertex(edge.start_vertex), self._vertex(edge.end_vertex)
        curve = edge.curve
        kind = curve.type
        if kind == "straight-curve" or curve.is_none:
            idx = np.array([a, b], np.int64)
        elif kind == "ellipse-curve":
            inner = self._arc(curve, self.points[a], self.points[b], bool(edge.sense), a == b)
            idx = np.concatenate([[a], np.arange(len(self.points), len(self.points) + len(inner)), [b]]).astype(np.int64)
            self.points.extend(inner)
        else:
            raise AcisError(f"has edges of kinds not tessellated here ({_name(curve)}: a spline or an intersection "
                            "curve); convert it to a mesh in the CAD program (MESHSMOOTH) or export it as STL/OBJ")
        self.edge_index[key] = idx
        return idx

    def _arc(self, curve, start: np.ndarray, end: np.ndarray, reversed_: bool, closed: bool) -> list:
        """The inner points of an elliptical arc from ``start`` to ``end`` (the curve's direction, or against it)."""
        r = float(np.linalg.norm(curve.major))
        normal = curve.normal / np.linalg.norm(curve.normal)
        u = curve.major / r
        v = np.cross(normal, u)
        minor = r * curve.ratio

        def angle(p):
            d = p - curve.center
            return float(np.arctan2(d @ v / minor, d @ u / r))

        t0, t1 = angle(start), angle(end)
        turn = 2.0 * np.pi
        if closed or np.linalg.norm(start - end) <= self.same:
            sweep = -turn if reversed_ else turn
        elif reversed_:
            sweep = -((t0 - t1) % turn)
        else:
            sweep = (t1 - t0) % turn
        step = self._step(r) * min(1.0, abs(curve.ratio))  # an ellipse's sharpest bend: radius r ratio^2
        n = max(1, int(np.ceil(abs(sweep) / step - 1e-9)))
        t = t0 + sweep * np.arange(1, n) / n
        return list(curve.center + np.outer(np.cos(t), u * r) + np.outer(np.sin(t), v * minor))

    # ---- faces -----------------------------------------------------------------------------

    def _loops(self, face) -> list[np.ndarray]:
        """Each loop of ``face`` as point indices in its coedges' order (not closed); loops of fewer than 3
        distinct points (an apex, a degenerate seam) left out."""
        loops = []
        for loop in _walk(face.loop, "next_loop"):
            ring = []
            for coedge in _walk(loop.coedge, "next_coedge"):
                idx = self._edge(coedge.edge)
                ring.append((idx[::-1] if coedge.sense else idx)[:-1])
            if ring:
                ring = np.concatenate(ring)
                if len(np.unique(ring)) >= 3:
                    loops.append(ring)
        return loops

    def _face(self, face) -> np.ndarray:
        loops = self._loops(face)
        if not loops:
            return np.zeros((0, 3), np.int64)
        surface = face.surface
        if surface.type == "plane-surface":
            self.kinds["plane"] += 1
            tri = self._planar(surface, loops)
        elif surface.type == "sphere-surface":
            self.kinds["spherical"] += 1
            tri = self._spherical(surface, loops)
        else:
            self.kinds[_Revolved(surface).kind] += 1
            tri = self._unrolled(surface, loops)
        return _oriented(tri, loops[0])

    def _planar(self, surface, loops: list[np.ndarray]) -> np.ndarray:
        from meshsom.polygons import plane_frame, triangulate_polygon_3d

        if len(loops) == 1 and len(loops[0]) == 3:  # a triangle (a mesh turned into a solid is made of them)
            return loops[0][None, :].astype(np.int64)
        pts = np.asarray(self.points, np.float64)
        if len(loops) > 1:  # the boundary first: the loop of the largest area in the plane
            frame = plane_frame(np.array(tuple(surface.normal), np.float64))
            areas = [_signed_area((pts[r] - pts[r].mean(axis=0)) @ frame.T) for r in loops]
            loops = [loops[k] for k in np.argsort(-np.abs(areas), kind="stable")]
        rings = loops
        tri = triangulate_polygon_3d([pts[r] for r in rings])
        expected = sum(len(r) for r in rings) - 2 + 2 * (len(rings) - 1)  # n + 2 holes - 2
        self.dropped += max(0, expected - len(tri))
        return np.concatenate(rings)[tri].reshape(-1, 3)

    def _unrolled(self, surface, loops: list[np.ndarray]) -> np.ndarray:
        from meshsom.polygons import triangulate_polygon_2d

        pts = np.asarray(self.points, np.float64)
        shape = _Revolved(surface)
        origin, axis, u, w = shape.origin, shape.axis, shape.u, shape.w
        turn = 2.0 * np.pi
        unrolled, wraps, through_apex = [], [], None
        for k, ring in enumerate(loops):
            d = pts[ring] - origin
            at_apex = np.linalg.norm(np.cross(d, axis), axis=1) <= self.same
            if at_apex.sum() == 1 and through_apex is None:  # AutoCAD's cone: a seam up to the apex and back
                last = int(np.flatnonzero(at_apex)[0])
                loops[k] = ring = np.roll(ring, -(last + 1))  # the apex last
                d = np.roll(d, -(last + 1), axis=0)
                theta = np.unwrap(np.arctan2(d[:-1] @ w, d[:-1] @ u))
                through_apex = k
                wraps.append(0)
                height = float(d[-1] @ axis)  # the loop's path, then its apex at both ends' angles
                unrolled.append(np.concatenate([np.stack([theta, d[:-1] @ axis], axis=1),
                                                [[theta[-1], height], [theta[0], height]]]))
                continue
            theta = np.unwrap(np.arctan2(d @ w, d @ u)[np.arange(len(ring) + 1) % len(ring)])  # round and back to the start
            wraps.append(int(np.rint((theta[-1] - theta[0]) / turn)))
            unrolled.append(np.stack([theta[:-1], d @ axis], axis=1))
        radius = float(np.mean(np.linalg.norm(np.cross(pts[np.concatenate(loops)] - origin, axis), axis=1))) or 1.0
        wrapping = [k for k, n in enumerate(wraps) if n]
        holes = [k for k, n in enumerate(wraps) if not n]
        closing = shape.closing_height() if len(wrapping) == 1 else None
        if through_apex is not None:
            if wrapping:
                raise AcisError(f"has a {shape.kind} face bounded both by a seam to its apex and by a loop going round "
                                "its axis (not tessellated here); convert it to a mesh in the CAD program (MESHSMOOTH) "
                                "or export it as STL/OBJ")
            shell = unrolled[through_apex]
            centre = 0.5 * (shell[:, 0].min() + shell[:, 0].max())
            others = [k for k in holes if k != through_apex]
            flat = [shell] + [_shifted(unrolled[k], centre) for k in others]
            apex_index = loops[through_apex][-1]
            index = np.concatenate([loops[through_apex][:-1], [apex_index, apex_index]] + [loops[k] for k in others])
        elif not wrapping:
            areas = [_signed_area(p) for p in unrolled]
            outer = int(np.argmax(np.abs(areas)))
            centre = unrolled[outer][:, 0].mean()
            rings = [outer] + [k for k in holes if k != outer]
            flat = [_shifted(unrolled[k], centre) for k in rings]
            index = np.concatenate([loops[k] for k in rings])
        elif len(wrapping) == 2:
            (a, b), others = wrapping, holes
            hole_angles = np.concatenate([unrolled[k][:, 0] for k in others]) if others else np.zeros(0)
            shell, index = _seam_polygon(unrolled[a], loops[a], wraps[a], unrolled[b], loops[b], wraps[b], hole_angles)
            centre = shell[:, 0].min() + np.pi
            flat = [shell] + [_shifted(unrolled[k], centre) for k in others]
            index = np.concatenate([index] + [loops[k] for k in others])
        elif closing is not None:  # a cone closing in its apex
            (a,), others = wrapping, holes
            hole_angles = np.concatenate([unrolled[k][:, 0] for k in others]) if others else np.zeros(0)
            shell, index = _apex_polygon(unrolled[a], loops[a], wraps[a], closing, len(self.points), hole_angles)
            self.points.append(origin + closing * axis)
            pts = np.asarray(self.points, np.float64)
            centre = shell[:, 0].min() + np.pi
            flat = [shell] + [_shifted(unrolled[k], centre) for k in others]
            index = np.concatenate([index] + [loops[k] for k in others])
            loops = loops + [np.array([len(self.points) - 1])]
        else:
            raise AcisError(f"has a {shape.kind} face bounded by {len(wrapping)} loop{'s' * (len(wrapping) != 1)} going "
                            "round its axis (not tessellated here); convert it to a mesh in the CAD program (MESHSMOOTH) "
                            "or export it as STL/OBJ")
        scale = np.array([radius, 1.0])
        scaled = [p * scale for p in flat]
        points, tri = triangulate_polygon_2d(scaled[0], scaled[1:])
        keep = (tri < len(index)).all(axis=1)
        expected = sum(len(p) for p in flat) - 2 + 2 * (len(flat) - 1)
        self.dropped += max(0, expected - int(keep.sum()))
        # triangles whose edges span more than the arcs' steps cut through the solid: split them
        shape.fit(pts[np.concatenate(loops)])
        apexes = np.linalg.norm(np.cross(pts[index] - origin, axis), axis=1) <= self.same
        limit = INSIDE_SPAN_STEPS * self._step(shape.largest_radius) * shape.sharpness

        known = pts[index]

        def too_long(points2: np.ndarray, ends: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            # straight along the generators: what counts is the angle; an apex's edges are generators
            span = np.abs(points2[ends[..., 0], 0] - points2[ends[..., 1], 0])
            pinned = np.zeros(len(points2), bool)
            pinned[: len(apexes)] = apexes
            corners = np.concatenate([known, shape.placed(points2[len(known):])])[ends[..., 0]]
            tilted = _tilted(corners, shape.normal(corners.mean(axis=1)))
            return ((span > limit * (1.0 + 1e-9)) | tilted[:, None]) & ~pinned[ends].any(axis=-1), span

        unrolled_points, tri = _refined(points[: len(index)] / scale, tri[keep], too_long)
        new = unrolled_points[len(index):]
        if len(new):
            index = np.concatenate([index, np.arange(len(self.points), len(self.points) + len(new))])
            self.points.extend(shape.placed(new))
        tri = index[tri]
        return tri[(tri[:, 0] != tri[:, 1]) & (tri[:, 1] != tri[:, 2]) & (tri[:, 0] != tri[:, 2])]

    def _spherical(self, surface, loops: list[np.ndarray]) -> np.ndarray:
        """A face on a sphere (a dome), mapped to the plane by the azimuthal equidistant projection about the pole
        nearer to it (so a cap round its pole is a disk, a band an annulus: no seam), triangulated there and refined
        until no chord inside is longer than the arcs' allow, new points placed back on the sphere. A seam edge run
        up and back within one loop (AutoCAD's meridian to a pole vertex) is a slit in the plane: it is left out."""
        from meshsom.polygons import triangulate_polygon_2d

        loops = [ring for ring in (_without_spurs(r) for r in loops) if len(np.unique(ring)) >= 3]
        if not loops:
            return np.zeros((0, 3), np.int64)
        pts = np.asarray(self.points, np.float64)
        centre, radius = surface.center, abs(surface.radius)
        pole = surface.pole / np.linalg.norm(surface.pole)
        if float(np.mean((pts[np.concatenate(loops)] - centre) @ pole)) < 0:
            pole = -pole
        u = np.cross(pole, [1.0, 0.0, 0.0] if abs(pole[0]) < 0.9 else [0.0, 1.0, 0.0])
        u /= np.linalg.norm(u)
        w = np.cross(pole, u)

        def project(p: np.ndarray) -> np.ndarray:
            d = (p - centre) / radius
            arc = np.arccos(np.clip(d @ pole, -1.0, 1.0)) * radius
            theta = np.arctan2(d @ w, d @ u)
            return np.stack([arc * np.cos(theta), arc * np.sin(theta)], axis=1)

        def placed(q: np.ndarray) -> np.ndarray:
            rho = np.linalg.norm(q, axis=1)
            across = np.where(rho[:, None] > 0, q / np.where(rho > 0, rho, 1.0)[:, None], [1.0, 0.0])
            angle = rho / radius
            return centre + radius * (np.cos(angle)[:, None] * pole + np.sin(angle)[:, None] * (
                across[:, :1] * u + across[:, 1:] * w))

        flat = [project(pts[r]) for r in loops]
        outer = int(np.argmax([abs(_signed_area(f)) for f in flat]))
        order = [outer] + [k for k in range(len(loops)) if k != outer]
        index = np.concatenate([loops[k] for k in order])
        points, tri = triangulate_polygon_2d(flat[outer], [flat[k] for k in order[1:]])
        keep = (tri < len(index)).all(axis=1)
        expected = len(index) - 2 + 2 * (len(loops) - 1)
        self.dropped += max(0, expected - int(keep.sum()))
        known = pts[index]
        longest = 2.0 * radius * np.sin(INSIDE_SPAN_STEPS * self._step(radius) / 2.0) * (1.0 + 1e-9)

        def too_long(points2: np.ndarray, ends: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            where = np.concatenate([known, placed(points2[len(known):])])
            length = np.linalg.norm(where[ends[..., 0]] - where[ends[..., 1]], axis=-1)
            corners = where[ends[..., 0]]
            tilted = _tilted(corners, corners.mean(axis=1) - centre)
            return (length > longest) | tilted[:, None], length

        flat_points, tri = _refined(points[: len(index)], tri[keep], too_long)
        new = flat_points[len(index):]
        if len(new):
            index = np.concatenate([index, np.arange(len(self.points), len(self.points) + len(new))])
            self.points.extend(placed(new))
        return index[tri]

    def _step(self, r: float) -> float:
        """The angle of an arc of radius ``r`` whose chord stays within ``flatten`` of it."""
        turn = 2.0 * np.pi
        step = 2.0 * np.arccos(max(-1.0, 1.0 - self.flatten / r)) if r > 0 else turn
        return min(step, turn / MIN_SEGMENTS_PER_TURN)


def _refined(points: np.ndarray, tri: np.ndarray, too_long) -> tuple[np.ndarray, np.ndarray]:
    """Split the triangles of an unrolled face until no edge inside the face is too long.

    Longest-edge bisection (Rivara): each pass splits, at its midpoint, every edge that both its
    triangles pick as their longest (by the measure ``too_long`` gives, then by key) of the edges to
    split, so the mesh stays conforming; the face's boundary edges are never split (its neighbours
    share them).

    Parameters
    ----------
    points : (P, 2) float64
        (angle, height) of the face's points.
    tri : (T, 3) int64
    too_long : callable
        ``too_long(points, ends)`` with ``ends`` (T, 3, 2) point indices: ((T, 3) bool, the edges to split;
        (T, 3) float, their lengths in its measure).

    Returns
    -------
    points : (P + Q, 2) float64
        ``points`` followed by the Q midpoints added.
    tri : (T', 3) int64
    """
    points = np.asarray(points, np.float64)
    for _ in range(MAX_REFINE_PASSES):
        if not len(tri):
            break
        n = len(points)
        ends = np.stack([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]], axis=1)  # (T, 3, 2)
        key = ends.min(axis=2) * n + ends.max(axis=2)
        split_these, span = too_long(points, ends)
        keys, inverse, counts = np.unique(key, return_inverse=True, return_counts=True)
        inverse = inverse.reshape(key.shape)
        marked = np.zeros(len(keys), bool)  # an edge one of its triangles wants split is split for both
        marked[inverse[split_these]] = True
        long = (counts[inverse] == 2) & marked[inverse]
        if not long.any():
            break
        edge_span = np.zeros(len(keys))
        edge_span[inverse.reshape(-1)] = span.reshape(-1)
        rank = np.empty(len(keys), np.int64)
        rank[np.lexsort((keys, edge_span))] = np.arange(len(keys))
        choice = np.where(long, rank[inverse], -1)
        local = np.argmax(choice, axis=1)
        rows = np.flatnonzero(choice[np.arange(len(tri)), local] >= 0)
        picked = inverse[rows, local[rows]]
        edges, picks = np.unique(picked, return_counts=True)
        split = edges[picks == 2]
        go = np.isin(picked, split)
        rows, picked = rows[go], picked[go]
        local = local[rows]
        turned = tri[rows[:, None], (local[:, None] + np.arange(3)) % 3]  # the edge to split first
        a, b = turned[:, 0], turned[:, 1]
        mid_of = np.full(len(keys), -1, np.int64)
        mid_of[split] = n + np.arange(len(split))
        first = {}
        for e, p, q in zip(picked.tolist(), a.tolist(), b.tolist()):
            first.setdefault(e, (p, q))
        ends_of = np.array([first[e] for e in split.tolist()], np.int64).reshape(-1, 2)
        points = np.concatenate([points, 0.5 * (points[ends_of[:, 0]] + points[ends_of[:, 1]])])
        m = mid_of[picked]
        halves = np.concatenate([np.stack([a, m, turned[:, 2]], axis=1), np.stack([m, b, turned[:, 2]], axis=1)])
        kept = np.ones(len(tri), bool)
        kept[rows] = False
        tri = np.concatenate([tri[kept], halves])
    return points, tri


def _location(vertex) -> np.ndarray:
    return np.array(tuple(vertex.point.location), np.float64)


def _matrix(body) -> np.ndarray | None:
    transform = body.transform
    if transform.is_none:
        return None
    m = np.array(list(transform.matrix), np.float64).reshape(4, 4)
    return None if np.allclose(m, np.eye(4), rtol=0.0, atol=0.0) else m


class _Revolved:
    """A cone or cylinder as the faces on it are unrolled: its frame (``origin``, unit ``axis``, ``u`` and ``w`` across
    it), its kind, how to place a point of (angle, height along the axis) on it."""

    def __init__(self, surface):
        self.surface = surface
        self.origin, self.ratio = surface.origin, abs(surface.ratio) or 1.0
        self.axis = surface.axis / np.linalg.norm(surface.axis)
        u = surface.major - (surface.major @ self.axis) * self.axis
        self.u = u / np.linalg.norm(u)
        self.w = np.cross(self.axis, self.u)
        self.sharpness = min(1.0, self.ratio)  # an ellipse bends most at its major vertices: radius r ratio^2
        self.scale = self.slope = self.mean_height = self.largest_radius = 0.0

    @property
    def kind(self) -> str:
        """``cylindrical`` (the half angle's sine 0) or ``conical`` (also where the angle was not read)."""
        sine = getattr(self.surface, "sine", None)
        return "cylindrical" if sine is not None and abs(sine) < 1e-12 else "conical"

    def _shape(self, theta: np.ndarray) -> np.ndarray:
        """The base ellipse's radius at angle ``theta``, its major radius 1."""
        return 1.0 / np.sqrt(np.cos(theta) ** 2 + (np.sin(theta) / self.ratio) ** 2)

    def fit(self, boundary: np.ndarray) -> None:
        """A cone's radius along its axis, fitted to points on it (its faces' loops): linear."""
        d = boundary - self.origin
        radii = np.linalg.norm(np.cross(d, self.axis), axis=1)
        self.largest_radius = float(radii.max())
        heights = d @ self.axis
        scales = radii / self._shape(np.arctan2(d @ self.w, d @ self.u))
        self.mean_height, self.scale = float(heights.mean()), float(scales.mean())
        self.slope = 0.0 if np.ptp(heights) <= 1e-12 * max(1.0, self.scale) else float(np.polyfit(heights, scales, 1)[0])

    def placed(self, unrolled: np.ndarray) -> np.ndarray:
        """(K, 3) points on the surface of (K, 2) (angle, height along the axis)."""
        theta, h = unrolled[:, 0], unrolled[:, 1]
        r = (self.scale + self.slope * (h - self.mean_height)) * self._shape(theta)
        return (self.origin + h[:, None] * self.axis
                + r[:, None] * (np.cos(theta)[:, None] * self.u + np.sin(theta)[:, None] * self.w))

    def normal(self, p: np.ndarray) -> np.ndarray:
        """(K, 3) directions across the surface at points (K, 3) near it (unnormalised; either side): the gradient of
        sqrt(x^2 + y^2 / ratio^2) - s(h), s the fitted scale along the axis (away from the axis for a circular cylinder,
        tilted by the slope for a cone, towards the minor axis's ends for an elliptical one)."""
        d = p - self.origin
        x, y = d @ self.u, d @ self.w
        across = x[:, None] * self.u + (y / self.ratio ** 2)[:, None] * self.w
        across /= np.maximum(np.hypot(x, y / self.ratio), 1e-300)[:, None]
        return across - self.slope * self.axis

    def closing_height(self) -> float | None:
        """Where a cone bounded by one loop going round its axis closes, along the axis: its apex, -r cos / sin (r its
        base's major radius; ACIS's sine and cosine of its half angle); None for a cylinder or unknown angles."""
        sine, cosine = getattr(self.surface, "sine", None), getattr(self.surface, "cosine", None)
        if sine is None or cosine is None or abs(sine) < 1e-12:
            return None
        return -float(np.linalg.norm(self.surface.major)) * cosine / sine


def _kinds(counter: Counter) -> str:
    return ", ".join(f"{n} {kind}" for kind, n in counter.most_common())


def _signed_area(p: np.ndarray) -> float:
    x, y = p[:, 0], p[:, 1]
    return 0.5 * float(np.dot(x, np.roll(y, -1)) - np.dot(np.roll(x, -1), y))


def _shifted(p: np.ndarray, centre: float) -> np.ndarray:
    """``p`` (K, 2) moved by whole turns in angle so that its mean angle is nearest ``centre``."""
    turns = np.rint((centre - p[:, 0].mean()) / (2.0 * np.pi))
    return p + np.array([turns * 2.0 * np.pi, 0.0])


def _seam_polygon(pa, ia, wa, pb, ib, wb, hole_angles):
    """The unrolled polygon of a face going round its axis between wrapping loops a and b, cut along a seam.

    Returns the polygon's (P, 2) points and their (P,) point indices (the seam's two ends repeated,
    one turn apart).
    """
    turn = 2.0 * np.pi

    def ascending(p, idx, w):
        return (p, idx) if w > 0 else (p[::-1], idx[::-1])

    pa, ia = ascending(pa, ia, wa)
    pb, ib = ascending(pb, ib, wb)
    # the seam starts at the point of loop a farthest (in angle) from every hole
    if len(hole_angles):
        gap = np.abs(np.angle(np.exp(1j * (pa[:, 0][:, None] - hole_angles[None, :])))).min(axis=1)
        s = int(np.argmax(gap))
    else:
        s = 0
    pa, ia = _rolled(pa, ia, s)
    theta = pa[0, 0]
    nearest = np.abs(np.angle(np.exp(1j * (pb[:, 0] - theta))))
    pb, ib = _rolled(pb, ib, int(np.argmin(nearest)))
    pb = pb + np.array([np.rint((theta - pb[0, 0]) / turn) * turn, 0.0])
    a_end = pa[0] + np.array([turn, 0.0])
    b_end = pb[0] + np.array([turn, 0.0])
    shell = np.concatenate([pa, [a_end], [b_end], pb[::-1]])
    index = np.concatenate([ia, [ia[0]], [ib[0]], ib[::-1]])
    return shell, index


def _apex_polygon(pa, ia, wa, height: float, apex: int, hole_angles):
    """The unrolled polygon of a cone's face from its one wrapping loop up to its apex (index ``apex``), repeated at
    both ends of the turn (the triangle between the two copies has no area on the cone and is dropped)."""
    turn = 2.0 * np.pi
    if wa < 0:
        pa, ia = pa[::-1], ia[::-1]
    if len(hole_angles):
        gap = np.abs(np.angle(np.exp(1j * (pa[:, 0][:, None] - hole_angles[None, :])))).min(axis=1)
        pa, ia = _rolled(pa, ia, int(np.argmax(gap)))
    else:
        pa, ia = _rolled(pa, ia, 0)
    theta = pa[0, 0]
    shell = np.concatenate([pa, [[theta + turn, pa[0, 1]]], [[theta + turn, height]], [[theta, height]]])
    index = np.concatenate([ia, [ia[0]], [apex, apex]])
    return shell, index


def _tilted(corners: np.ndarray, normal: np.ndarray) -> np.ndarray:
    """(T,) bool: triangles (T, 3, 3) whose plane is turned more than :data:`MAX_TILT_DEGREES` from the surface, whose
    normal (T, 3) near them is given: a triangle of three points of one boundary loop lying in the loop's plane (an
    ear the face beyond that loop may make too, where the two would overlap)."""
    n = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    cos = np.abs(np.einsum("ij,ij->i", n, normal)) / np.maximum(
        np.linalg.norm(n, axis=1) * np.linalg.norm(normal, axis=1), 1e-300)
    return cos < np.cos(np.radians(MAX_TILT_DEGREES))


def _without_spurs(ring: np.ndarray) -> np.ndarray:
    """A loop without the spurs it runs out and back along (a seam edge used twice: ..., a, b, a, ... -> ..., a, ...)."""
    ring = list(ring)
    changed = True
    while changed and len(ring) >= 3:
        changed = False
        for k in range(len(ring)):
            if ring[k - 1] == ring[(k + 1) % len(ring)]:
                drop = {k, (k + 1) % len(ring)}
                ring = [p for j, p in enumerate(ring) if j not in drop]
                changed = True
                break
    return np.asarray(ring, np.int64)


def _rolled(p: np.ndarray, idx: np.ndarray, start: int):
    """A loop's points from ``start`` on, their angles continuous (ascending by a turn at most)."""
    p = np.roll(p, -start, axis=0).copy()
    idx = np.roll(idx, -start)
    p[:, 0] = np.unwrap(p[:, 0])
    return p, idx


def _oriented(tri: np.ndarray, ring: np.ndarray) -> np.ndarray:
    """``tri`` turned, all together, to run the loop's first edge ring[0] -> ring[1] as the loop does."""
    if not len(tri):
        return tri
    a, b = int(ring[0]), int(ring[1])
    for k in range(3):
        if ((tri[:, k] == a) & (tri[:, (k + 1) % 3] == b)).any():
            return tri
        if ((tri[:, k] == b) & (tri[:, (k + 1) % 3] == a)).any():
            return tri[:, ::-1].copy()
    return tri
