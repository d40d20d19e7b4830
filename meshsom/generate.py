"""Seeded synthetic corpus of labelled building blocks.

Families of LoD1 blocks (extruded footprints) and, optionally, LoD2 houses with
roofs on rectangular footprints. Every block carries its family label so that
clustering quality can be measured against it. Proportions are drawn from
ranges given in :class:`GeneratorParams`; every random choice comes from the
seed.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np
import shapely
from scipy.spatial import ConvexHull

from meshsom.polygons import extrude_polygon, triangulate_polygon_2d

#: LoD1 footprint families.
BLOCK_FAMILIES = ("rectangle", "L", "U", "T", "courtyard", "cross", "stepped_tower")
#: LoD2 roof families (on rectangular footprints).
ROOF_FAMILIES = ("gabled", "hipped", "shed")


@dataclass(frozen=True)
class GeneratorParams:
    """What the synthetic corpus looks like.

    Attributes
    ----------
    n_blocks : int
        Number of buildings.
    seed : int
        Seed of every random choice.
    families : tuple of str
        Families to draw from, uniformly and in turn (block i gets family
        ``families[i % len(families)]``, so every family is represented).
    width_range, depth_range, height_range : (float, float)
        Footprint bounding-box width and depth, and eave height, in metres.
    roof_height_range : (float, float)
        Roof rise above the eaves for the roof families, in metres.
    spacing : float
        Distance between the centres of neighbouring blocks on the site grid, metres.
    origin : (float, float, float)
        World offset of the site (for example Swiss LV95: (2.6e6, 1.2e6, 400.0)).
    rotate : bool
        Rotate every block by a random angle about the vertical axis.
    """

    n_blocks: int = 48
    seed: int = 0
    families: tuple[str, ...] = BLOCK_FAMILIES
    width_range: tuple[float, float] = (12.0, 40.0)
    depth_range: tuple[float, float] = (10.0, 30.0)
    height_range: tuple[float, float] = (6.0, 30.0)
    roof_height_range: tuple[float, float] = (2.0, 8.0)
    spacing: float = 80.0
    origin: tuple[float, float, float] = (0.0, 0.0, 0.0)
    rotate: bool = True

    def __post_init__(self):
        valid = BLOCK_FAMILIES + ROOF_FAMILIES
        if self.n_blocks < 1:
            raise ValueError(f"n_blocks must be >= 1, received {self.n_blocks}")
        if not self.families:
            raise ValueError(f"families must not be empty; valid: {', '.join(valid)}")
        for fam in self.families:
            if fam not in valid:
                raise ValueError(f"unknown family {fam!r}; valid: {', '.join(valid)}")
        for name in ("width_range", "depth_range", "height_range", "roof_height_range"):
            lo, hi = getattr(self, name)
            if not 0 < lo <= hi:
                raise ValueError(f"{name} must satisfy 0 < low <= high, received ({lo}, {hi})")
        if self.spacing <= 0:
            raise ValueError(f"spacing must be > 0, received {self.spacing}")


@dataclass(frozen=True)
class Block:
    """One synthetic building.

    Attributes
    ----------
    id : str
    label : str
        The family.
    vertices : (V, 3) float64
        World coordinates.
    faces : (F, 3) int64
        Counter-clockwise seen from outside.
    lod : str
        "1" for extruded blocks, "2" for roofed houses.
    """

    id: str
    label: str
    vertices: np.ndarray = field(repr=False)
    faces: np.ndarray = field(repr=False)
    lod: str = "1"


def _footprint(family: str, w: float, d: float, rng: np.random.Generator) -> shapely.Polygon:
    """Footprint polygon of a family inside the box [0, w] x [0, d]."""
    box = shapely.box
    f = lambda lo, hi: float(rng.uniform(lo, hi))  # noqa: E731
    if family == "rectangle":
        return box(0, 0, w, d)
    if family == "L":
        return box(0, 0, w, d).difference(box(w * f(0.35, 0.65), d * f(0.35, 0.65), w, d))
    if family == "U":
        a, b = w * f(0.2, 0.35), w * f(0.65, 0.8)
        return box(0, 0, w, d).difference(box(a, d * f(0.3, 0.6), b, d))
    if family == "T":
        stem = w * f(0.25, 0.45)
        bar = d * f(0.3, 0.5)
        return shapely.union(box(0, d - bar, w, d), box((w - stem) / 2, 0, (w + stem) / 2, d))
    if family == "courtyard":
        mx, my = w * f(0.2, 0.3), d * f(0.2, 0.3)
        return box(0, 0, w, d).difference(box(mx, my, w - mx, d - my))
    if family == "cross":
        sx, sy = w * f(0.25, 0.45), d * f(0.25, 0.45)
        return shapely.union(box((w - sx) / 2, 0, (w + sx) / 2, d), box(0, (d - sy) / 2, w, (d + sy) / 2))
    raise ValueError(f"no footprint for family {family!r}")


def _polygon_rings(poly: shapely.Polygon) -> tuple[np.ndarray, list[np.ndarray]]:
    poly = shapely.normalize(shapely.simplify(poly, 0.0))
    shell = np.asarray(poly.exterior.coords)[:-1]
    holes = [np.asarray(r.coords)[:-1] for r in poly.interiors]
    return shell, holes


def _stepped_tower(w, d, h, rng) -> tuple[np.ndarray, np.ndarray]:
    """A podium of height h and a tower of 1.5-3 h on a smaller rectangle inside it."""
    tw, td = w * rng.uniform(0.3, 0.6), d * rng.uniform(0.3, 0.6)
    x0, y0 = rng.uniform(0.1 * w, 0.9 * w - tw), rng.uniform(0.1 * d, 0.9 * d - td)
    h2 = h * rng.uniform(1.5, 3.0)
    base = np.array([[0, 0], [w, 0], [w, d], [0, d]], float)
    tower = np.array([[x0, y0], [x0 + tw, y0], [x0 + tw, y0 + td], [x0, y0 + td]], float)
    # Rings: base at 0, base at h, tower at h, tower at h2.
    v = np.concatenate([
        np.column_stack([base, np.zeros(4)]), np.column_stack([base, np.full(4, h)]),
        np.column_stack([tower, np.full(4, h)]), np.column_stack([tower, np.full(4, h2)]),
    ])
    faces = []
    faces += [[0, 2, 1], [0, 3, 2]]  # floor, facing down
    ring = np.arange(4)
    nxt = (ring + 1) % 4
    for lo, hi in ((0, 4), (8, 12)):
        faces += np.column_stack([lo + ring, lo + nxt, hi + nxt]).tolist()
        faces += np.column_stack([lo + ring, hi + nxt, hi + ring]).tolist()
    pts, tri = triangulate_polygon_2d(base, [tower[::-1]])  # podium roof with the tower as a hole
    # pts = base (-> vertices 4..7) then the reversed tower ring (-> vertices 11..8).
    to_vertex = np.array([4, 5, 6, 7, 11, 10, 9, 8])
    faces += to_vertex[tri].tolist()
    faces += [[12, 13, 14], [12, 14, 15]]  # tower roof
    return v, np.asarray(faces, np.int64)


def _roofed_house(family, w, d, h, r, rng) -> tuple[np.ndarray, np.ndarray]:
    """A convex house: rectangle w x d, eaves at h, roof rising by r."""
    floor = [[0, 0, 0], [w, 0, 0], [w, d, 0], [0, d, 0]]
    if family == "gabled":
        top = [[0, 0, h], [w, 0, h], [w, d, h], [0, d, h], [0, d / 2, h + r], [w, d / 2, h + r]]
    elif family == "hipped":
        inset = min(w / 2, d / 2) * rng.uniform(0.5, 0.9)
        top = [[0, 0, h], [w, 0, h], [w, d, h], [0, d, h], [inset, d / 2, h + r], [w - inset, d / 2, h + r]]
    elif family == "shed":
        top = [[0, 0, h], [w, 0, h], [w, d, h + r], [0, d, h + r]]
    else:
        raise ValueError(f"no roof for family {family!r}")
    v = np.asarray(floor + top, np.float64)
    hull = ConvexHull(v)
    faces = hull.simplices.astype(np.int64)
    # Orient outward: each face normal must point away from the centroid.
    c = v.mean(axis=0)
    a, b, cc = v[faces[:, 0]], v[faces[:, 1]], v[faces[:, 2]]
    n = np.cross(b - a, cc - a)
    flip = np.einsum("ij,ij->i", n, a - c) < 0
    faces[flip] = faces[flip][:, ::-1]
    return v, faces


def make_block(family: str, rng: np.random.Generator, params: GeneratorParams) -> tuple[np.ndarray, np.ndarray, str]:
    """One block of ``family`` in local coordinates (footprint in [0, w] x [0, d], base z = 0).

    Returns
    -------
    vertices : (V, 3) float64
    faces : (F, 3) int64
    lod : str
    """
    w = rng.uniform(*params.width_range)
    d = rng.uniform(*params.depth_range)
    h = rng.uniform(*params.height_range)
    if family in ROOF_FAMILIES:
        r = rng.uniform(*params.roof_height_range)
        v, f = _roofed_house(family, w, d, h, r, rng)
        return v, f, "2"
    if family == "stepped_tower":
        v, f = _stepped_tower(w, d, h, rng)
        return v, f, "1"
    shell, holes = _polygon_rings(_footprint(family, w, d, rng))
    v, f = extrude_polygon(shell, holes, 0.0, h)
    return v, f, "1"


def generate_block(params: GeneratorParams, index: int) -> Block:
    """Block number ``index`` of the corpus (independent of every other block).

    Each block draws from its own stream ``default_rng([seed, index])``, so
    shards of a corpus can be generated in parallel and give the same blocks.
    """
    if not 0 <= index < params.n_blocks:
        raise IndexError(f"block index {index} out of range 0..{params.n_blocks - 1}")
    rng = np.random.default_rng([params.seed, index])
    side = int(np.ceil(np.sqrt(params.n_blocks)))
    width = max(len(str(params.n_blocks - 1)), 5)
    family = params.families[index % len(params.families)]
    v, f, lod = make_block(family, rng, params)
    v = v - np.array([v[:, 0].mean(), v[:, 1].mean(), 0.0])
    if params.rotate:
        a = rng.uniform(0, 2 * np.pi)
        rot = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])
        v = v @ rot.T
    cell = np.array([(index % side) * params.spacing, (index // side) * params.spacing, 0.0])
    v = v + cell + np.asarray(params.origin, np.float64)
    return Block(id=f"block-{index:0{width}d}", label=family, vertices=v, faces=f, lod=lod)


def generate_corpus(
    params: GeneratorParams, progress: Callable[[int], None] | None = None, indices: range | None = None
) -> list[Block]:
    """Generate the labelled synthetic corpus (or the blocks ``indices`` of it).

    Parameters
    ----------
    params : GeneratorParams
    progress : callable, optional
        Called with 1 after each block (for progress bars).
    indices : range, optional
        A slice of the corpus (default: all ``params.n_blocks`` blocks).

    Returns
    -------
    blocks : list of Block
        Placed on a square site grid around ``params.origin``, ids
        ``block-00000``, ``block-00001``, ...
    """
    blocks = []
    for i in indices if indices is not None else range(params.n_blocks):
        blocks.append(generate_block(params, i))
        if progress is not None:
            progress(1)
    return blocks
