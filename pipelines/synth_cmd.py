"""``meshsom synth``: triangle patches synthesized from ring vectors or map prototypes.

Sources: rows of an encoded store's ``rings/level{L}`` (``--faces``), or the prototypes of a
trained map saved in the store (``--run RUN --units ...``; standardized weights are
de-standardized with the level's stored statistics). For each vector it writes the patch
synthesized with ``--level-by`` (``lsq``: least-squares leveling over every entry of the vector,
the default; ``none``: the unfolding from first copies; :mod:`meshsom.synthesis`) as a mesh file,
a contact-sheet PNG, and prints the re-translation error (QC-error between the vector and the
re-encoding of its patch, standardized units) of both methods.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

FORMATS = ("obj", "ply", "glb", "stl", "off")
LEVEL_BY = ("lsq", "none")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("store", help="an encoded store")
    p.add_argument("--level", type=int, help="ring level (default: the run's level)")
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--faces", type=int, nargs="+", help="face rows of rings/level{L} to decode")
    src.add_argument("--run", help="a trained map saved in the store (runs/RUN)")
    p.add_argument("--units", type=int, nargs="+", help="map units of --run (default: every unit of a map of <= 64 units, else 16 spread ones)")
    p.add_argument("--out", required=True, help="output folder")
    p.add_argument("--format", choices=FORMATS, default="obj")
    p.add_argument("--level-by", choices=LEVEL_BY, default="lsq",
                   help="lsq: least-squares leveling over every entry (default); none: unfold from first copies")
    p.add_argument("--json", action="store_true", help="print one JSON object")


def _contact_sheet(patches: list, titles: list[str], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    n = len(patches)
    cols = min(n, 6)
    rows = (n + cols - 1) // cols
    fig = plt.figure(figsize=(2.4 * cols, 2.4 * rows))
    for i, (patch, title) in enumerate(zip(patches, titles)):
        ax = fig.add_subplot(rows, cols, i + 1, projection="3d")
        tris = patch.vertices[patch.faces]
        shade = 0.35 + 0.6 * np.abs(np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0])[:, 2]) / (
            np.linalg.norm(np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0]), axis=1) + 1e-12)
        colors = [(0.2, 0.4 + 0.4 * s, 0.8, 0.9) for s in shade]
        colors[0] = (0.9, 0.3, 0.2, 1.0)  # the root
        ax.add_collection3d(Poly3DCollection(tris, facecolors=colors, edgecolors="k", linewidths=0.3))
        lo, hi = patch.vertices.min(axis=0), patch.vertices.max(axis=0)
        c, r = (lo + hi) / 2, (hi - lo).max() / 2 + 1e-9
        ax.set_xlim(c[0] - r, c[0] + r)
        ax.set_ylim(c[1] - r, c[1] + r)
        ax.set_zlim(c[2] - r, c[2] + r)
        ax.set_axis_off()
        ax.set_title(title, fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def run(args: argparse.Namespace) -> int:
    from meshsom.errors import StoreError
    from meshsom.standardize import destandardize
    from meshsom.store import open_store, read_stats, rings_array
    from meshsom.standardize import standardize
    from meshsom.synthesis import Patch, clip_v, encode_patches, entry_deviation, patch_topology, synthesize, write_patch

    group = open_store(args.store)
    if args.run:
        from meshsom.codebook import load_codebook

        cb = load_codebook(group, args.run)
        level = args.level or cb.level
        if level is None:
            raise StoreError(f"{args.store}: run {args.run!r} does not record its level; pass --level")
        m = cb.rows * cb.cols
        units = args.units or (list(range(m)) if m <= 64 else np.linspace(0, m - 1, 16).astype(int).tolist())
        bad = [u for u in units if not 0 <= u < m]
        if bad:
            raise StoreError(f"{args.store}: run {args.run!r} has {m} units; received unit(s) {bad}")
        stats = read_stats(group, level)
        vectors = destandardize(cb.weights[units], stats)
        names = [f"unit{u}" for u in units]
    else:
        if not args.level:
            raise StoreError(f"{args.store}: --faces needs --level")
        level = args.level
        arr = rings_array(group, level)
        bad = [i for i in args.faces if not 0 <= i < arr.shape[0]]
        if bad:
            raise StoreError(f"{args.store}: rings/level{level} has {arr.shape[0]} rows; received face(s) {bad}")
        stats = read_stats(group, level)
        vectors = np.asarray(arr.oindex[sorted(set(args.faces))] if hasattr(arr, "oindex") else arr[:][args.faces], np.float64)
        names = [f"face{i}" for i in sorted(set(args.faces))]
    # v must stay positive for a triangle to exist
    vectors = clip_v(vectors)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    topo = patch_topology(level)
    z = standardize(vectors, stats)
    errors = {}
    for method in LEVEL_BY:
        V = synthesize(vectors, level, method, stats)
        errors[method] = entry_deviation(z, encode_patches(V, level), stats).mean(axis=1)
        if method == args.level_by:
            chosen = V
    records, patches, titles = [], [], []
    for i, name in enumerate(names):
        patch = Patch(chosen[i], topo.faces.copy(), list(topo.slots), topo.adjacency, level)
        path = out / f"level{level}_{name}_{args.level_by}.{args.format}"
        write_patch(patch, path)
        records.append({"name": name, "level": level, "level_by": args.level_by, "files": [str(path)],
                        **{f"retranslation_{m}": float(errors[m][i]) for m in LEVEL_BY}})
        patches.append(patch)
        titles.append(f"{name}: {errors[args.level_by][i]:.3g}")
    sheet = out / f"level{level}_contact_sheet.png"
    _contact_sheet(patches, titles, sheet)
    if args.json:
        print(json.dumps({"level": level, "level_by": args.level_by, "patches": records, "contact_sheet": str(sheet)}))
    else:
        for r in records:
            print(f"{r['name']}: re-translation QC-error {r['retranslation_none']:.4g} unleveled, "
                  f"{r['retranslation_lsq']:.4g} leveled (lsq)")
        print(f"{len(records)} patch files ({args.level_by}) and {sheet} in {out}")
    return 0
