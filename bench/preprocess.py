"""Preprocessing throughput on a synthetic city: `python bench/preprocess.py [--blocks 1000] [--subdivide 1]`.

Generates a seeded city of LoD1/LoD2 blocks (meshsom.generate), optionally subdivides every
triangle (so that each planar region arrives as many coplanar triangles, like real exports),
and times meshsom.preprocess.preprocess on every block. Prints total seconds, buildings/s and
input triangles/s, and the split between generation, subdivision and preprocessing.
Run with `env -u OPENBLAS_CORETYPE -u OPENBLAS_L2_SIZE` on this machine (see README).
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import trimesh

from meshsom.generate import GeneratorParams, generate_corpus
from meshsom.preprocess import PreprocessParams, preprocess


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--blocks", type=int, default=1000)
    p.add_argument("--subdivide", type=int, default=1, help="rounds of 1-to-4 subdivision of each input")
    p.add_argument("--seed", type=int, default=0)
    args = p.parse_args(argv)

    t0 = time.perf_counter()
    blocks = generate_corpus(GeneratorParams(n_blocks=args.blocks, seed=args.seed))
    t1 = time.perf_counter()
    meshes = []
    for b in blocks:
        v, f = b.vertices - b.vertices.mean(axis=0), b.faces
        for _ in range(args.subdivide):
            v, f = trimesh.remesh.subdivide(v, f)
        meshes.append((v, f))
    t2 = time.perf_counter()
    params = PreprocessParams()
    faces_in = faces_out = 0
    for v, f in meshes:
        r = preprocess(v, f, params)
        faces_in += len(f)
        faces_out += len(r.faces)
    t3 = time.perf_counter()
    secs = t3 - t2
    print(f"preprocess: {len(meshes)} buildings, {faces_in} triangles in -> {faces_out} out")
    print(f"  generate {t1 - t0:.2f} s, subdivide {t2 - t1:.2f} s, preprocess {secs:.2f} s")
    print(f"  {len(meshes) / secs:.0f} buildings/s, {faces_in / secs:,.0f} input triangles/s (one process, one core)")


if __name__ == "__main__":
    main()
