"""Roofs on footprints: milliseconds per building for each roof shape, and how often it is built.

    .venv/bin/python bench/roofs.py [--footprints 200] [--seed 7] [--repeat 3]

Footprints of the kind city models hold (unions of 1 to 4 rectangles of 3 to 10 m, turned, in
longitude and latitude as OpenStreetMap and Overture give them), the same for every shape. For
each shape :data:`meshsom.roofs.SHAPES`, :func:`meshsom.roofs.roof_faces` builds the block with
its roof on every footprint (after a warm-up pass; best of ``--repeat``), and the table prints
milliseconds per footprint, the share built (the rest is modelled flat, noted), and the faces per
building. The reference, measured in the same run, is the flat block of the same footprints
(:func:`meshsom.geojson.footprint_solid` without a roof shape).
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def turned_unions(count: int, seed: int) -> list[np.ndarray]:
    """``count`` simple footprints ((K, 2) metres, not closed): unions of 1 to 4 rectangles of 3 to 10 m
    without courtyards, each turned by a random angle (tests/test_roofs.py builds every shape on them)."""
    import shapely
    from shapely.geometry import box

    rng = np.random.default_rng(seed)
    out = []
    while len(out) < count:
        rects = [box(x, y, x + w, y + h) for x, y, w, h in rng.integers([0, 0, 3, 3], [10, 10, 10, 10], (rng.integers(1, 5), 4))]
        union = shapely.union_all(rects)
        if union.geom_type != "Polygon" or len(union.interiors):
            continue
        ring = np.asarray(shapely.simplify(union, 0).exterior.coords)[:-1]
        turn = rng.uniform(0, 2 * np.pi)
        ring = ring @ np.array([[math.cos(turn), -math.sin(turn)], [math.sin(turn), math.cos(turn)]]).T
        out.append(ring)
    return out


def footprints(count: int, seed: int) -> list[np.ndarray]:
    """:func:`turned_unions` in longitude and latitude about Zürich ((K, 2) each)."""
    scale = np.array([75_000.0, 111_000.0])  # metres per degree there, near enough
    return [ring / scale + np.array([8.54, 47.37]) for ring in turned_unions(count, seed)]


def main(argv=None) -> int:
    from meshsom.geojson import FeatureVertices, footprint_solid, roof_scale
    from meshsom.crs import coordinate_system
    from meshsom.io import ReaderOptions
    from meshsom.roofs import SHAPES, roof_faces

    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--footprints", type=int, default=200)
    p.add_argument("--seed", type=int, default=7)
    p.add_argument("--repeat", type=int, default=3)
    args = p.parse_args(argv)
    rings = footprints(args.footprints, args.seed)
    crs = coordinate_system("OGC:CRS84h")
    scales = [roof_scale(r, crs) for r in rings]
    corners = np.mean([len(r) for r in rings])
    print(f"{len(rings)} footprints (unions of rectangles in lon/lat), {corners:.1f} corners on average; eaves 6 m, top 9 m")

    def timed(run) -> tuple[float, list]:
        run()  # warm-up
        best, result = math.inf, None
        for _ in range(args.repeat):
            t = time.perf_counter()
            result = run()
            best = min(best, time.perf_counter() - t)
        return best, result

    options = ReaderOptions()
    flat, _ = timed(lambda: [footprint_solid([[r.tolist()]], {"height": 9}, "bench", options, FeatureVertices(), crs=crs)
                             for r in rings])
    print(f"{'shape':12s} {'ms / footprint':>15s} {'x flat block':>13s} {'built':>7s} {'faces':>6s}")
    print(f"{'(flat block)':12s} {1e3 * flat / len(rings):15.3f} {1.0:13.1f} {'100 %':>7s} {'':>6s}")
    for shape in SHAPES:
        seconds, built = timed(lambda: [roof_faces(r, 0.0, 6.0, 9.0, shape, s) for r, s in zip(rings, scales)])
        done = [f for f in built if f is not None]
        faces = np.mean([len(f) for f in done]) if done else float("nan")
        print(f"{shape:12s} {1e3 * seconds / len(rings):15.3f} {seconds / flat:13.1f} "
              f"{100 * len(done) / len(rings):6.0f} % {faces:6.1f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
