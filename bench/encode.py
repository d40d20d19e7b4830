"""Encoding throughput on a synthetic city: `python bench/encode.py [--blocks 600] [--quick]`.

Builds one big closed mesh from a seeded synthetic city (meshsom.generate): every block is
re-centred, preprocessed (meshsom.preprocess), then subdivided 1-to-4 ``--subdivide`` times
(subdivision keeps a mesh closed and oriented, so it is not preprocessed again), and all blocks
are concatenated. On that mesh it times, separately:

- adjacency: meshsom.topology.adjacency(faces)
- folds: meshsom.folds.folds(vertices, faces, adj)
- per level: meshsom.rings.encode_level in row chunks of ``--chunk`` faces, written into a
  preallocated float32 output, so that the memory is bounded by the output,

and prints seconds, triangles/s and the peak RSS after each stage (the per-level ring template,
built once and cached, is timed apart). One process; the encoding is NumPy gathers, which run
on one core. Target (issue): level 3 >= 200,000 triangles/s on one core.
Run with `env -u OPENBLAS_CORETYPE -u OPENBLAS_L2_SIZE` on this machine (see README).
"""

from __future__ import annotations

import argparse
import os
import platform
import resource
import sys
import time
from pathlib import Path

import numpy as np
import trimesh

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from meshsom.errors import MeshError  # noqa: E402
from meshsom.folds import folds  # noqa: E402
from meshsom.generate import GeneratorParams, generate_corpus  # noqa: E402
from meshsom.preprocess import preprocess  # noqa: E402
from meshsom.rings import dims, encode_level, template  # noqa: E402
from meshsom.topology import adjacency  # noqa: E402

#: Default number of blocks (enough for >= MIN_TRIANGLES after two subdivisions).
BLOCKS = 600
#: --quick: blocks.
QUICK_BLOCKS = 60
#: 1-to-4 subdivision rounds after preprocessing.
SUBDIVIDE = 2
#: Faces encoded per chunk.
CHUNK = 65_536
#: Levels timed.
LEVELS = (1, 2, 3)
#: The issue's size of a city-scale run; a smaller mesh is reported as such.
MIN_TRIANGLES = 200_000
#: The issue's target rate at level 3, triangles/s on one core.
TARGET_LEVEL3 = 200_000
#: ru_maxrss is in KiB on Linux.
RSS_UNIT = 1024
MIB = 2**20


def cpu_model() -> str:
    """The CPU's model name from /proc/cpuinfo (or the platform's description)."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def peak_rss_mib() -> float:
    """Peak resident set size of this process so far, MiB."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * RSS_UNIT / MIB


def city(n_blocks: int, seed: int, subdivide: int) -> tuple[np.ndarray, np.ndarray, int, int]:
    """One closed mesh of a preprocessed, subdivided synthetic city.

    Parameters
    ----------
    n_blocks : int
    seed : int
    subdivide : int
        1-to-4 subdivision rounds per block, after preprocessing.

    Returns
    -------
    vertices : (V, 3) float64
        Blocks re-centred at the origin (they overlap; the encoding does not care).
    faces : (F, 3) int64
    kept : int
        Blocks in the mesh.
    rejected : int
        Blocks that preprocessing refused.
    """
    verts, faces = [], []
    offset = rejected = 0
    for b in generate_corpus(GeneratorParams(n_blocks=n_blocks, seed=seed)):
        try:
            r = preprocess(b.vertices - b.vertices.mean(axis=0), b.faces, source=b.id)
        except MeshError:
            rejected += 1
            continue
        v, f = r.vertices, r.faces
        for _ in range(subdivide):
            v, f = trimesh.remesh.subdivide(v, f)
        verts.append(v)
        faces.append(np.asarray(f, np.int64) + offset)
        offset += len(v)
    return np.concatenate(verts), np.concatenate(faces), len(verts), rejected


def encode_chunked(fo: np.ndarray, adj, level: int, chunk: int) -> np.ndarray:
    """All ring vectors of one level, encoded ``chunk`` faces at a time into one float32 array.

    Parameters
    ----------
    fo : (F, 3, 3) float64
    adj : Adjacency
    level : int
    chunk : int

    Returns
    -------
    rings : (F, dims(level)) float32
    """
    n = len(fo)
    out = np.empty((n, dims(level)), np.float32)
    for i in range(0, n, chunk):
        rows = np.arange(i, min(i + chunk, n), dtype=np.int64)
        out[i:i + len(rows)] = encode_level(fo, adj, level, faces=rows)
    return out


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--blocks", type=int, default=None, help=f"synthetic buildings (default {BLOCKS})")
    p.add_argument("--quick", action="store_true", help=f"{QUICK_BLOCKS} blocks (a smoke test)")
    p.add_argument("--subdivide", type=int, default=SUBDIVIDE, help="1-to-4 subdivision rounds per block")
    p.add_argument("--chunk", type=int, default=CHUNK, help="faces encoded per chunk")
    p.add_argument("--seed", type=int, default=0)
    args = p.parse_args(argv)
    n_blocks = args.blocks if args.blocks is not None else (QUICK_BLOCKS if args.quick else BLOCKS)

    print(f"encode bench: {os.cpu_count()} cores, {cpu_model()}, python {platform.python_version()}, "
          f"numpy {np.__version__}")
    for var in ("OPENBLAS_CORETYPE", "OPENBLAS_L2_SIZE"):
        if os.environ.get(var):
            print(f"note: {var}={os.environ[var]} is set (run under `env -u OPENBLAS_CORETYPE -u OPENBLAS_L2_SIZE`)")

    t0 = time.perf_counter()
    vertices, faces, kept, rejected = city(n_blocks, args.seed, args.subdivide)
    n = len(faces)
    print(f"city: {kept} blocks ({rejected} rejected by preprocessing), {args.subdivide} subdivisions, "
          f"{n:,} triangles, {len(vertices):,} vertices; built in {time.perf_counter() - t0:.1f} s")
    if n < MIN_TRIANGLES:
        print(f"note: fewer than {MIN_TRIANGLES:,} triangles (raise --blocks for a city-scale figure)")
    print(f"peak RSS after building: {peak_rss_mib():.0f} MiB")

    t = time.perf_counter()
    adj = adjacency(faces)
    secs = time.perf_counter() - t
    print(f"adjacency: {secs:.3f} s, {n / secs:,.0f} triangles/s, peak RSS {peak_rss_mib():.0f} MiB")
    t = time.perf_counter()
    fo = folds(vertices, faces, adj)
    secs = time.perf_counter() - t
    print(f"folds:     {secs:.3f} s, {n / secs:,.0f} triangles/s, peak RSS {peak_rss_mib():.0f} MiB")

    for level in LEVELS:
        t = time.perf_counter()
        template(level)  # built once per level and cached; timed apart from the encoding
        print(f"level {level} template: {time.perf_counter() - t:.3f} s (once per process)")
        t = time.perf_counter()
        out = encode_chunked(fo, adj, level, args.chunk)
        secs = time.perf_counter() - t
        note = ""
        if level == LEVELS[-1] == 3:
            note = f" (target >= {TARGET_LEVEL3:,}: {'met' if n / secs >= TARGET_LEVEL3 else 'NOT met'})"
        print(f"level {level}: {secs:.3f} s, {n / secs:,.0f} triangles/s, output {out.nbytes / MIB:.0f} MiB "
              f"({dims(level)} float32 per triangle), peak RSS {peak_rss_mib():.0f} MiB{note}")
        del out


if __name__ == "__main__":
    main()
