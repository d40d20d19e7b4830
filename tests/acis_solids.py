"""Writing ACIS solids for tests: extruded profiles of lines and circular arcs, as AutoCAD's EXTRUDE makes them.

A profile is a list of loops (the first the outline, counter-clockwise seen from above; the others
holes, clockwise); a loop is a list of segments ``("line", (x, y))`` or ``("arc", (x, y), (cx, cy))``
(to the point, the arc about the centre; counter-clockwise where its turn is positive, ``ccw``), or one
``("circle", (cx, cy), r)``. :func:`extrusion_body` builds the ACIS graph with ezdxf's entity classes
plus the two curved kinds (``ellipse-curve``, ``cone-surface``) written in AutoCAD's record layout, and
:func:`sat_lines` / :func:`sab_bytes` / :func:`add_solid` encode it (SAT text for DXF R2000-R2010, SAB
for R2013 and later), so the reader is tested on both encodings. Independent geometry (areas,
volumes) is computed here from the profile, not from any mesh.
"""

from __future__ import annotations

import math

import numpy as np
from ezdxf.acis import entities as acis
from ezdxf.math import Matrix44, Vec3


class Ellipse(acis.Curve):
    type = "ellipse-curve"

    def __init__(self, center, normal, major, ratio=1.0):
        self.center, self.normal, self.major, self.ratio = Vec3(center), Vec3(normal), Vec3(major), float(ratio)

    def write_common(self, exporter) -> None:
        super().write_common(exporter)

    def write_data(self, exporter) -> None:
        exporter.write_loc_vec3(self.center)
        exporter.write_dir_vec3(self.normal)
        exporter.write_dir_vec3(self.major)
        exporter.write_double(self.ratio)
        super().write_data(exporter)

    def evaluate(self, param):
        raise NotImplementedError


class Cone(acis.Surface):
    """A cylinder (sine 0) or cone, as AutoCAD writes it: base ellipse, its range, sine, cosine, scale, sense."""

    type = "cone-surface"

    def __init__(self, origin, axis, major, sine=0.0, cosine=1.0, ratio=1.0):
        self.origin, self.axis, self.major = Vec3(origin), Vec3(axis), Vec3(major)
        self.sine, self.cosine, self.ratio = float(sine), float(cosine), float(ratio)

    def write_common(self, exporter) -> None:
        super().write_common(exporter)

    def write_data(self, exporter) -> None:
        exporter.write_loc_vec3(self.origin)
        exporter.write_dir_vec3(self.axis)
        exporter.write_dir_vec3(self.major)
        exporter.write_double(self.ratio)
        exporter.write_interval(math.inf)
        exporter.write_interval(math.inf)
        exporter.write_double(self.sine)
        exporter.write_double(self.cosine)
        exporter.write_double(self.major.magnitude)
        exporter.write_bool(False, "reversed", "forward")
        super().write_data(exporter)

    def evaluate(self, u, v):
        raise NotImplementedError


class Sphere(acis.Surface):
    """A sphere (a dome), which the reader does not tessellate."""

    type = "sphere-surface"

    def __init__(self, centre, radius):
        self.centre, self.radius = Vec3(centre), float(radius)

    def write_common(self, exporter) -> None:
        super().write_common(exporter)

    def write_data(self, exporter) -> None:
        exporter.write_loc_vec3(self.centre)
        exporter.write_double(self.radius)
        exporter.write_dir_vec3(Vec3(1, 0, 0))
        exporter.write_dir_vec3(Vec3(0, 0, 1))
        exporter.write_bool(False, "reverse_v", "forward_v")
        super().write_data(exporter)

    def evaluate(self, u, v):
        raise NotImplementedError


class Torus(acis.Surface):
    """A torus (a fillet, a ring), which the reader does not tessellate."""

    type = "torus-surface"

    def __init__(self, centre, major: float, minor: float):
        self.centre, self.major, self.minor = Vec3(centre), float(major), float(minor)

    def write_common(self, exporter) -> None:
        super().write_common(exporter)

    def write_data(self, exporter) -> None:
        exporter.write_loc_vec3(self.centre)
        exporter.write_dir_vec3(Vec3(0, 0, 1))
        exporter.write_double(self.major)
        exporter.write_double(self.minor)
        exporter.write_dir_vec3(Vec3(1, 0, 0))
        exporter.write_bool(False, "reverse_v", "forward_v")
        super().write_data(exporter)

    def evaluate(self, u, v):
        raise NotImplementedError


def _vertex(p) -> acis.Vertex:
    v = acis.Vertex()
    v.point = acis.Point()
    v.point.location = Vec3(p)
    return v


class _Builder:
    def __init__(self):
        self.shell = acis.Shell()
        self.faces: list = []

    def edge(self, v0, v1, curve, sense=False) -> acis.Edge:
        e = acis.Edge()
        e.start_vertex, e.end_vertex, e.curve, e.sense = v0, v1, curve, sense
        for v in (v0, v1):
            if v.edge.is_none:
                v.edge = e
        return e

    def face(self, surface, loops, sense=False) -> acis.Face:
        """``loops``: lists of (edge, coedge reversed?) in the loop's order."""
        face = acis.Face()
        face.surface, face.sense, face.shell = surface, sense, self.shell
        for ring in loops:
            loop = acis.Loop()
            coedges = []
            for edge, rev in ring:
                c = acis.Coedge()
                c.edge, c.sense, c.loop = edge, rev, loop
                if edge.coedge.is_none:
                    edge.coedge = c
                else:
                    c.partner_coedge, edge.coedge.partner_coedge = edge.coedge, c
                coedges.append(c)
            for k, c in enumerate(coedges):
                c.next_coedge = coedges[(k + 1) % len(coedges)]
                c.prev_coedge = coedges[k - 1]
            loop.coedge = coedges[0]
            face.append_loop(loop)
        self.faces.append(face)
        return face

    def body(self, transform: Matrix44 | None = None) -> acis.Body:
        for a, b in zip(self.faces, self.faces[1:]):
            a.next_face = b
        self.shell.face = self.faces[0]
        lump = acis.Lump()
        lump.shell, self.shell.lump = self.shell, lump
        body = acis.Body()
        body.lump, lump.body = lump, body
        if transform is not None:
            t = acis.Transform()
            t.matrix = transform
            body.transform = t
        return body


def _plane(origin, normal) -> acis.Plane:
    p = acis.Plane()
    p.origin, p.normal = Vec3(origin), Vec3(normal).normalize()
    p.u_dir = Vec3(1, 0, 0) if abs(p.normal.x) < 0.9 else Vec3(0, 1, 0)
    p.u_dir = (p.u_dir - p.normal * p.u_dir.dot(p.normal)).normalize()
    p.update_v_dir()
    return p


def extrusion_body(profile: list, z0: float, z1: float, transform: Matrix44 | None = None) -> acis.Body:
    """The ACIS body of ``profile`` (as the module says) extruded from height ``z0`` to ``z1``."""
    b = _Builder()
    top_loops, bottom_loops, sides = [], [], []
    for loop in profile:
        if loop[0][0] == "circle":
            (cx, cy), r = loop[0][1], loop[0][2]
            ccw = loop[0][3] if len(loop[0]) > 3 else True
            v0, v1 = _vertex((cx + r, cy, z0)), _vertex((cx + r, cy, z1))
            e0 = b.edge(v0, v0, Ellipse((cx, cy, z0), (0, 0, 1), (r, 0, 0)), sense=not ccw)
            e1 = b.edge(v1, v1, Ellipse((cx, cy, z1), (0, 0, 1), (r, 0, 0)), sense=not ccw)
            top_loops.append([(e1, False)])
            bottom_loops.append([(e0, True)])
            sides.append((Cone((cx, cy, z0), (0, 0, 1), (r, 0, 0)), [[(e0, False)], [(e1, True)]]))
            continue
        pts = [seg[1] for seg in loop]
        n = len(pts)
        starts = [pts[k - 1] for k in range(n)]  # segment k runs from pts[k-1] to pts[k]
        low = [_vertex((x, y, z0)) for x, y in starts]
        high = [_vertex((x, y, z1)) for x, y in starts]
        up = [b.edge(low[k], high[k], acis.StraightCurve()) for k in range(n)]
        for k, (e_up) in enumerate(up):
            e_up.curve.origin, e_up.curve.direction = low[k].point.location, Vec3(0, 0, 1)
        top, bottom = [], []
        for k, seg in enumerate(loop):
            a, c = starts[k], pts[k]
            nxt = (k + 1) % n
            if seg[0] == "line":
                curves = [acis.StraightCurve(), acis.StraightCurve()]
                for curve, z in zip(curves, (z0, z1)):
                    curve.origin = Vec3(a[0], a[1], z)
                    curve.direction = Vec3(c[0] - a[0], c[1] - a[1], 0).normalize()
                d = np.array([c[0] - a[0], c[1] - a[1], 0.0])
                outward = np.cross(d, [0.0, 0.0, 1.0])
                surface = _plane((a[0], a[1], z0), outward)
                sense = (False, False)
            else:
                _, _, (cx, cy) = seg[:3]
                ccw = seg[3] if len(seg) > 3 else True
                r = math.hypot(a[0] - cx, a[1] - cy)
                major = (a[0] - cx, a[1] - cy, 0)
                curves = [Ellipse((cx, cy, z), (0, 0, 1), major) for z in (z0, z1)]
                surface = Cone((cx, cy, z0), (0, 0, 1), major)
                sense = (not ccw, not ccw)
                assert abs(math.hypot(c[0] - cx, c[1] - cy) - r) < 1e-9 * max(1.0, r)
            e_low = b.edge(low[k], low[nxt], curves[0], sense[0])
            e_high = b.edge(high[k], high[nxt], curves[1], sense[1])
            top.append((e_high, False))
            bottom.append((e_low, True))
            sides.append((surface, [[(e_low, False), (up[nxt], False), (e_high, True), (up[k], True)]]))
        top_loops.append(top)
        bottom_loops.append(bottom[::-1])
    b.face(_plane((0, 0, z1), (0, 0, 1)), top_loops)
    b.face(_plane((0, 0, z0), (0, 0, -1)), bottom_loops)
    for surface, loops in sides:
        b.face(surface, loops)
    return b.body(transform)


def sat_lines(bodies: list, version: int = 20800) -> list[str]:
    """SAT text (as ezdxf's ``entity.sat`` holds it) of ``bodies``, ACIS ``version`` (700: R2000; 20800: with the asm header of R2004-R2010)."""
    return acis.export_sat(bodies, version)


def sab_bytes(bodies: list, version: int = 21800) -> bytes:
    """SAB data (DXF R2013 and later) of ``bodies``."""
    return acis.export_sab(bodies, version)


def add_solid(layout, bodies: list, dxftype: str = "3DSOLID"):
    """A 3DSOLID (or BODY) in ``layout`` holding ``bodies``."""
    from ezdxf.acis import api

    entity = layout.add_3dsolid() if dxftype == "3DSOLID" else layout.add_body()
    api.export_dxf(entity, bodies)
    return entity


def profile_area(profile: list) -> float:
    """The exact area of ``profile`` (outline less holes), arcs as arcs."""
    total = 0.0
    for loop in profile:
        if loop[0][0] == "circle":
            ccw = loop[0][3] if len(loop[0]) > 3 else True
            total += (1 if ccw else -1) * math.pi * loop[0][2] ** 2
            continue
        pts = [seg[1] for seg in loop]
        for k, seg in enumerate(loop):
            a, c = pts[k - 1], pts[k]
            total += 0.5 * (a[0] * c[1] - c[0] * a[1])  # the chord's share (shoelace)
            if seg[0] == "arc":
                cx, cy = seg[2]
                ccw = seg[3] if len(seg) > 3 else True
                r = math.hypot(a[0] - cx, a[1] - cy)
                t0, t1 = math.atan2(a[1] - cy, a[0] - cx), math.atan2(c[1] - cy, c[0] - cx)
                sweep = (t1 - t0) % (2 * math.pi) if ccw else -((t0 - t1) % (2 * math.pi))
                total += 0.5 * r * r * (sweep - math.sin(sweep))  # the circular segment beyond the chord
    return total


def tower_with_window_body(centre, r: float, z0: float, z1: float, window: tuple, ratio: float = 1.0) -> acis.Body:
    """A round (or, with ``ratio`` < 1, elliptical: radius ``r`` along x, ``r ratio`` along y) tower whose wall is two
    faces on one cylinder: the wall with a hole, and the patch that fills it (``window``: the ellipse's parameters
    a0 < a1 in radians, heights h0 < h1). Closed, of the tower's volume; the wall's face is bounded by two loops going
    round the axis and a hole."""
    cx, cy = centre
    a0, a1, h0, h1 = window
    b = _Builder()
    major = (r, 0, 0)
    v0, v1 = _vertex((cx + r, cy, z0)), _vertex((cx + r, cy, z1))
    e0 = b.edge(v0, v0, Ellipse((cx, cy, z0), (0, 0, 1), major, ratio))
    e1 = b.edge(v1, v1, Ellipse((cx, cy, z1), (0, 0, 1), major, ratio))

    def at(a, z):
        return (cx + r * math.cos(a), cy + r * ratio * math.sin(a), z)

    w = [_vertex(at(a0, h0)), _vertex(at(a1, h0)), _vertex(at(a1, h1)), _vertex(at(a0, h1))]
    low = b.edge(w[0], w[1], Ellipse((cx, cy, h0), (0, 0, 1), major, ratio))
    high = b.edge(w[3], w[2], Ellipse((cx, cy, h1), (0, 0, 1), major, ratio))
    right = b.edge(w[1], w[2], acis.StraightCurve())
    left = b.edge(w[0], w[3], acis.StraightCurve())
    for e, p in ((right, w[1]), (left, w[0])):
        e.curve.origin, e.curve.direction = p.point.location, Vec3(0, 0, 1)
    cone = Cone((cx, cy, z0), (0, 0, 1), major, ratio=ratio)
    b.face(_plane((cx, cy, z1), (0, 0, 1)), [[(e1, False)]])
    b.face(_plane((cx, cy, z0), (0, 0, -1)), [[(e0, True)]])
    window_loop = [(low, False), (right, False), (high, True), (left, True)]
    b.face(cone, [[(e0, False)], [(e1, True)], [(e, not rev) for e, rev in window_loop[::-1]]])
    b.face(cone, [window_loop])
    return b.body()


def sphere_body(centre, radius: float) -> acis.Body:
    """A whole sphere: one face, no loops (a ball: no edges at all)."""
    b = _Builder()
    b.face(Sphere(centre, radius), [])
    return b.body()


def torus_body(centre, major: float, minor: float) -> acis.Body:
    """A whole torus: one face, no loops."""
    b = _Builder()
    b.face(Torus(centre, major, minor), [])
    return b.body()


def ring_fillet_body(centre, r: float, z0: float, z1: float) -> acis.Body:
    """A tower whose wall meets its roof in a torus (a fillet): a face of a kind the reader does not tessellate."""
    cx, cy = centre
    b = _Builder()
    v0, v1 = _vertex((cx + r, cy, z0)), _vertex((cx + r, cy, z1))
    e0 = b.edge(v0, v0, Ellipse((cx, cy, z0), (0, 0, 1), (r, 0, 0)))
    e1 = b.edge(v1, v1, Ellipse((cx, cy, z1), (0, 0, 1), (r, 0, 0)))
    b.face(_plane((cx, cy, z0), (0, 0, -1)), [[(e0, True)]])
    b.face(Torus((cx, cy, z1), r, 1.0), [[(e0, False)], [(e1, True)]])
    return b.body()


def dome_body(centre, r: float, z0: float, drum: float = 0.0, seam: bool = False,
              transform: Matrix44 | None = None) -> acis.Body:
    """A hemispherical dome of radius ``r`` on a round drum of height ``drum`` (none: the dome on the ground), its base
    at ``z0``. The dome's face is bounded by its springing circle alone (the pole where the sphere closes), or, with
    ``seam``, also by a meridian edge up to a pole vertex, run up and back down; ``transform`` places it."""
    cx, cy = centre
    b = _Builder()
    spring = z0 + drum
    v0 = _vertex((cx + r, cy, z0))
    e0 = b.edge(v0, v0, Ellipse((cx, cy, z0), (0, 0, 1), (r, 0, 0)))
    b.face(_plane((cx, cy, z0), (0, 0, -1)), [[(e0, True)]])
    if drum:
        v1 = _vertex((cx + r, cy, spring))
        e1 = b.edge(v1, v1, Ellipse((cx, cy, spring), (0, 0, 1), (r, 0, 0)))
        b.face(Cone((cx, cy, z0), (0, 0, 1), (r, 0, 0)), [[(e0, False)], [(e1, True)]])
    else:
        v1, e1 = v0, e0
    sphere = Sphere((cx, cy, spring), r)
    if seam:
        pole = _vertex((cx, cy, spring + r))
        meridian = b.edge(v1, pole, Ellipse((cx, cy, spring), (0, -1, 0), (r, 0, 0)))
        b.face(sphere, [[(e1, False), (meridian, False), (meridian, True)]])
    else:
        b.face(sphere, [[(e1, False)]])
    return b.body(transform)


def seam_cylinder_body(centre, r: float, z0: float, z1: float) -> acis.Body:
    """A round tower as AutoCAD's CYLINDER makes it: the wall one face of one loop, its two circles joined by a seam
    edge that the loop runs up and back down."""
    cx, cy = centre
    b = _Builder()
    v0, v1 = _vertex((cx + r, cy, z0)), _vertex((cx + r, cy, z1))
    e0 = b.edge(v0, v0, Ellipse((cx, cy, z0), (0, 0, 1), (r, 0, 0)))
    e1 = b.edge(v1, v1, Ellipse((cx, cy, z1), (0, 0, 1), (r, 0, 0)))
    seam = b.edge(v0, v1, acis.StraightCurve())
    seam.curve.origin, seam.curve.direction = v0.point.location, Vec3(0, 0, 1)
    b.face(_plane((cx, cy, z1), (0, 0, 1)), [[(e1, False)]])
    b.face(_plane((cx, cy, z0), (0, 0, -1)), [[(e0, True)]])
    b.face(Cone((cx, cy, z0), (0, 0, 1), (r, 0, 0)), [[(e0, False), (seam, False), (e1, True), (seam, True)]])
    return b.body()


def cone_body(centre, r: float, z0: float, z1: float, seam: bool) -> acis.Body:
    """A cone (a conical roof as a solid) of base radius ``r`` at ``z0``, its apex at ``z1`` above the centre. Its
    curved face is bounded by the base circle alone (``seam=False``: the apex is where the surface closes), or, as
    AutoCAD's CONE makes it, also by a seam edge from the base to an apex vertex, run up and back down."""
    cx, cy = centre
    b = _Builder()
    height = z1 - z0
    slant = math.hypot(r, height)
    v0 = _vertex((cx + r, cy, z0))
    e0 = b.edge(v0, v0, Ellipse((cx, cy, z0), (0, 0, 1), (r, 0, 0)))
    surface = Cone((cx, cy, z0), (0, 0, 1), (r, 0, 0), sine=r / slant, cosine=-height / slant)
    b.face(_plane((cx, cy, z0), (0, 0, -1)), [[(e0, True)]])
    if seam:
        top = _vertex((cx, cy, z1))
        line = b.edge(v0, top, acis.StraightCurve())
        line.curve.origin, line.curve.direction = v0.point.location, (top.point.location - v0.point.location).normalize()
        b.face(surface, [[(e0, False), (line, False), (line, True)]])
    else:
        b.face(surface, [[(e0, False)]])
    return b.body()
