"""Roof shapes on footprints, as OpenStreetMap's Simple 3D Buildings scheme (S3DB) tags them.

A footprint with a height is a flat-roofed block; S3DB adds ``roof:shape``, ``roof:height`` (else
``roof:levels`` or ``roof:angle``) and ``roof:direction`` / ``roof:orientation``. The fold encoding
sees a gabled house and a flat block as different shapes, so the commonest shapes are built:

- ``pyramidal``: walls to the eaves, a triangle from each wall's top to an apex over the
  footprint's centroid (star-shaped footprints: convex ones, and most others);
- ``skillion``: one sloping plane, lowest at the side ``roof:direction`` (degrees clockwise from
  north, the way the roof faces) points to, the walls up to it;
- ``gabled`` and ``hipped`` (four-cornered convex footprints): a ridge along the longer sides
  (across them with ``roof:orientation=across``) between the short sides' midpoints, gable walls
  of five corners; a hipped roof's ridge is shortened by half the short side at each end (a
  pyramid where that leaves none).

The functions take a footprint ring in any planar coordinates (longitude and latitude included:
every point they place is an affine combination of the corners, computed in those coordinates) and
the metres per unit of each axis, for the lengths and directions that decide the shape.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["SHAPES", "roof_faces", "roof_height"]

#: The roof shapes built (others are modelled flat by the caller).
SHAPES = ("pyramidal", "skillion", "gabled", "hipped")
#: The pitch of a roof whose height is not tagged (degrees): a common pitched roof.
DEFAULT_PITCH_DEG = 30.0
#: Corners of the footprints a gabled or hipped roof is built on.
QUAD = 4


def roof_height(shape: str, ring: np.ndarray, scale: tuple[float, float], tags: dict, storey_height: float,
                number) -> float:
    """The roof's height (metres from eaves to top): ``roof:height``, else ``roof:levels`` x
    ``storey_height``, else the height of a roof pitched at ``roof:angle`` (else
    :data:`DEFAULT_PITCH_DEG`) over half the footprint's width (its whole width for a skillion).

    Parameters
    ----------
    ring : (K, 2) float64
        The footprint, not closed.
    scale : (2,)
        Metres per unit of x and y.
    number : callable
        Reads a tag value as a number (``meshsom.geojson._number``), None where it is none.
    """
    height = number(tags.get("roof:height"))
    if height is not None:
        return max(float(height), 0.0)
    levels = number(tags.get("roof:levels"))
    if levels is not None:
        return max(float(levels), 0.0) * storey_height
    angle = number(tags.get("roof:angle"))
    pitch = math.radians(float(angle) if angle is not None and 0 < angle < 90 else DEFAULT_PITCH_DEG)
    metric = ring * np.asarray(scale, np.float64)
    width = _width(metric)
    return math.tan(pitch) * (width if shape == "skillion" else width / 2)


def _width(metric: np.ndarray) -> float:
    """The footprint's width: its extent across the direction of its longest edge (metres)."""
    edges = np.roll(metric, -1, axis=0) - metric
    longest = edges[np.argmax(np.linalg.norm(edges, axis=1))]
    across = np.array([-longest[1], longest[0]]) / max(float(np.linalg.norm(longest)), 1e-12)
    return float(np.ptp(metric @ across))


def roof_faces(ring: np.ndarray, z0: float, z_eaves: float, z_top: float, shape: str, scale: tuple[float, float],
               direction_deg: float | None = None, across: bool = False) -> list[np.ndarray] | None:
    """The faces of a block of footprint ``ring`` from ``z0`` to its eaves with a roof of ``shape``
    up to ``z_top``: each (n, 3) float64, counter-clockwise seen from outside; None where the shape
    cannot be built on this footprint (the caller models it flat).

    Parameters
    ----------
    ring : (K, 2) float64
        The footprint's outer ring, not closed, either orientation, no holes.
    z0, z_eaves, z_top : float
        Its base, eaves and top, ``z0 < z_eaves <= z_top``.
    shape : str
        One of :data:`SHAPES`.
    scale : (2,)
        Metres per unit of x and y.
    direction_deg : float, optional
        Skillion: the way the roof faces, degrees clockwise from north (default: across the
        longest edge, down towards it).
    across : bool
        Gabled, hipped: the ridge across the longer sides.
    """
    ring = np.asarray(ring, np.float64)[:, :2]
    if len(ring) >= 2 and np.array_equal(ring[0], ring[-1]):
        ring = ring[:-1]
    if len(ring) < 3 or not z0 < z_eaves <= z_top:
        return None
    metric = ring * np.asarray(scale, np.float64)
    area = 0.5 * float(np.sum(metric[:, 0] * np.roll(metric[:, 1], -1) - np.roll(metric[:, 0], -1) * metric[:, 1]))
    if area == 0:
        return None
    if area < 0:  # counter-clockwise seen from above
        ring, metric = ring[::-1].copy(), metric[::-1].copy()
    if shape == "skillion":
        return _skillion(ring, metric, z0, z_eaves, z_top, direction_deg)
    if shape == "pyramidal":
        return _pyramid(ring, metric, z0, z_eaves, z_top)
    if shape in ("gabled", "hipped"):
        if len(ring) != QUAD or not _convex(metric):
            return None
        return _ridged(ring, metric, z0, z_eaves, z_top, shape == "hipped", across)
    return None


def _floor_and_walls(ring: np.ndarray, z0: float, tops: np.ndarray) -> list[np.ndarray]:
    """The floor (facing down) and a wall under each edge up to the corners' ``tops``."""
    n = len(ring)
    faces = [np.column_stack([ring[::-1], np.full(n, z0)])]
    for i in range(n):
        j = (i + 1) % n
        faces.append(np.array([[*ring[i], z0], [*ring[j], z0], [*ring[j], tops[j]], [*ring[i], tops[i]]]))
    return faces


def _convex(metric: np.ndarray) -> bool:
    d = np.roll(metric, -1, axis=0) - metric
    cross = d[:, 0] * np.roll(d, -1, axis=0)[:, 1] - d[:, 1] * np.roll(d, -1, axis=0)[:, 0]
    return bool((cross > 0).all())


def _pyramid(ring, metric, z0, z_eaves, z_top) -> list[np.ndarray] | None:
    apex = ring.mean(axis=0)
    m_apex = metric.mean(axis=0)
    d = np.roll(metric, -1, axis=0) - metric
    if not ((d[:, 0] * (m_apex[1] - metric[:, 1]) - d[:, 1] * (m_apex[0] - metric[:, 0])) > 0).all():
        return None  # the apex does not see every wall: not star-shaped about it
    faces = _floor_and_walls(ring, z0, np.full(len(ring), z_eaves))
    n = len(ring)
    faces += [np.array([[*ring[i], z_eaves], [*ring[(i + 1) % n], z_eaves], [*apex, z_top]]) for i in range(n)]
    return faces


def _skillion(ring, metric, z0, z_eaves, z_top, direction_deg) -> list[np.ndarray]:
    if direction_deg is None:  # down towards the longest edge, across it
        d = np.roll(metric, -1, axis=0) - metric
        k = int(np.argmax(np.linalg.norm(d, axis=1)))
        down = np.array([d[k, 1], -d[k, 0]])  # outward of a counter-clockwise ring
    else:
        angle = math.radians(direction_deg)
        down = np.array([math.sin(angle), math.cos(angle)])
    down = down / max(float(np.linalg.norm(down)), 1e-12)
    along = metric @ down
    span = float(np.ptp(along))
    tops = z_top - (z_top - z_eaves) * ((along - along.min()) / span if span > 0 else 0.0)
    faces = _floor_and_walls(ring, z0, tops)
    faces.append(np.column_stack([ring, tops]))
    return faces


def _ridged(ring, metric, z0, z_eaves, z_top, hipped: bool, across: bool) -> list[np.ndarray]:
    lengths = np.linalg.norm(np.roll(metric, -1, axis=0) - metric, axis=1)
    short_first = lengths[0] + lengths[2] <= lengths[1] + lengths[3]  # edges 0-1 and 2-3 are the short sides
    if across:
        short_first = not short_first
    k = 0 if short_first else 1  # the short sides are edges k and k + 2
    order = [(k + i) % QUAD for i in range(QUAD)]
    c, m = ring[order], metric[order]  # short sides c0-c1 and c2-c3
    r0, r1 = (c[0] + c[1]) / 2, (c[2] + c[3]) / 2
    walls = _floor_and_walls(c, z0, np.full(QUAD, z_eaves))
    if hipped:
        m0, m1 = (m[0] + m[1]) / 2, (m[2] + m[3]) / 2
        run = float(np.linalg.norm(m1 - m0))
        inset = 0.5 * float(np.linalg.norm(m[1] - m[0]) + np.linalg.norm(m[3] - m[2])) / 2
        if run <= 2 * inset:
            return _pyramid(c, m, z0, z_eaves, z_top)
        t = inset / run
        a, b = r0 + t * (r1 - r0), r1 - t * (r1 - r0)
        roof = [np.array([[*c[0], z_eaves], [*c[1], z_eaves], [*a, z_top]]),
                np.array([[*c[1], z_eaves], [*c[2], z_eaves], [*b, z_top], [*a, z_top]]),
                np.array([[*c[2], z_eaves], [*c[3], z_eaves], [*b, z_top]]),
                np.array([[*c[3], z_eaves], [*c[0], z_eaves], [*a, z_top], [*b, z_top]])]
        return walls + roof
    # gabled: the short walls rise to the ridge (five corners); the roof is two planes
    floor, w0, w1, w2, w3 = walls
    w0 = np.array([[*c[0], z0], [*c[1], z0], [*c[1], z_eaves], [*r0, z_top], [*c[0], z_eaves]])
    w2 = np.array([[*c[2], z0], [*c[3], z0], [*c[3], z_eaves], [*r1, z_top], [*c[2], z_eaves]])
    roof = [np.array([[*c[1], z_eaves], [*c[2], z_eaves], [*r1, z_top], [*r0, z_top]]),
            np.array([[*c[3], z_eaves], [*c[0], z_eaves], [*r0, z_top], [*r1, z_top]])]
    return [floor, w0, w1, w2, w3] + roof
