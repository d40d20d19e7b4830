"""Milliseconds per footprint read from a GeoJSON of footprints, flat roofs (no roof attributes read).

Times the reader as it is (the floors and roofs of a file's footprints triangulated with one GEOS call per
footprint, :func:`meshsom.polygons.triangulate_polygons_3d`) against the reference path (each polygon by
:func:`meshsom.polygons.triangulate_polygon_3d` alone, :func:`meshsom.io._triangulate_one_by_one`), in the same
run, after a warm-up, the best of ``--repeat`` reads; and checks that both give the same meshes.

    python bench/footprints.py path/to/footprints.geojson --default-height 10
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

import meshsom.io as io


def read(path: Path, options: io.ReaderOptions, reference: bool) -> list:
    fast = io.triangulate_polygons_3d
    if reference:
        io.triangulate_polygons_3d = io._triangulate_one_by_one
    try:
        return list(io.read_file(path, options))
    finally:
        io.triangulate_polygons_3d = fast


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("path", type=Path)
    parser.add_argument("--default-height", type=float, default=10.0)
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args()
    options = io.ReaderOptions(default_height=args.default_height, roofs=False)
    meshes = {}
    for reference in (True, False):
        read(args.path, options, reference)  # warm-up: imports, caches
    best = {True: np.inf, False: np.inf}
    for _ in range(args.repeat):
        for reference in (True, False):
            start = time.perf_counter()
            meshes[reference] = read(args.path, options, reference)
            best[reference] = min(best[reference], time.perf_counter() - start)
    n = len(meshes[False])
    same = len(meshes[True]) == n and all(
        np.array_equal(a.vertices, b.vertices) and np.array_equal(a.faces, b.faces)
        for a, b in zip(meshes[True], meshes[False]))
    for reference, name in ((True, "reference (one by one)"), (False, "batched")):
        print(f"{name:24s} {best[reference] / n * 1e3:7.3f} ms per footprint ({n} footprints)")
    print("identical meshes:", same)


if __name__ == "__main__":
    main()
