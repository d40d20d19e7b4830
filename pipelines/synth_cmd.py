"""``meshsom synth``: triangle patches synthesized from ring vectors or map prototypes.

Sources: rows of an encoded store's ``rings/level{L}`` (``--faces``), or the prototypes of a
trained map saved in the store (``--run RUN --units ...``; standardized weights are
de-standardized with the level's stored statistics). For each vector it writes the patch
synthesized with ``--level-by`` (``lsq``: least-squares leveling over every entry of the vector,
the default; ``none``: the unfolding from first copies; :mod:`meshsom.synthesis`) as a mesh file,
a contact sheet (PNG and SVG), and prints the re-translation error (QC-error between the vector and the
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


#: Pixels per patch image on the contact sheet, and patches per row at most.
SHEET_PIXELS, SHEET_COLS = 200, 6
#: Colours of the root triangle and of the other faces on the contact sheet.
ROOT_COLOUR, FACE_COLOUR = (0.85, 0.25, 0.15), (0.35, 0.55, 0.85)


def _crop(image: np.ndarray, margin: int = 4) -> np.ndarray:
    """An RGBA image cut to its opaque pixels plus ``margin`` (the empty border removed)."""
    rows, cols = np.nonzero(image[..., 3])
    if not len(rows):
        return image
    r0, c0 = max(rows.min() - margin, 0), max(cols.min() - margin, 0)
    return image[r0:rows.max() + margin + 1, c0:cols.max() + margin + 1]


def contact_sheet(patches: list, names: list[str], errors: dict, level: int, level_by: str, path: Path) -> tuple[str, str]:
    """One image per synthesized patch, cropped to the patch, named and with its errors; PNG and SVG.

    Parameters
    ----------
    patches : list of Patch
    names : list of str
        ``unit12`` or ``face7`` per patch.
    errors : dict of str to (n,) float
        Re-translation QC-error per method (``none``, ``lsq``), standardized units.
    level, level_by
        Named in the title.
    path : Path
        The PNG; the SVG is written beside it.

    Returns
    -------
    (png, svg) : str
    """
    from meshsom.figures import fit_text, new_figure, save_figure
    from meshsom.thumbnails import render_thumbnail

    n = len(patches)
    cols = min(n, SHEET_COLS)
    rows = -(-n // cols)
    width = max(2.0 * cols, 5.5)
    fig = new_figure((width, 2.1 * rows + 1.5))
    axes = np.atleast_1d(fig.subplots(rows, cols, squeeze=False)).ravel()
    for ax in axes:
        ax.set_axis_off()
    for i, (ax, patch, name) in enumerate(zip(axes, patches, names)):
        colours = np.tile(FACE_COLOUR, (len(patch.faces), 1))
        colours[0] = ROOT_COLOUR
        ax.imshow(_crop(render_thumbnail(patch.vertices, patch.faces, size=SHEET_PIXELS, colours=colours,
                                         edges="black")))
        ax.set_title(f"{name}\n{errors['none'][i]:.3g} -> {errors['lsq'][i]:.3g}", fontsize=8)
    method = "least-squares leveling" if level_by == "lsq" else "no leveling (unfolding from first copies)"
    fig.suptitle(fit_text(f"Level-{level} patches synthesized with {method}", width - 0.3, 11), fontsize=11)
    fig.supxlabel(fit_text("Red: the root triangle. Under each name: the re-translation QC-error (standardized "
                           "units; QC-error between the vector and the re-encoding of its patch) without -> with "
                           "least-squares leveling. Each patch is drawn at its own scale.", width - 0.3, 8),
                  fontsize=8)
    return save_figure(fig, path)


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
    records, patches = [], []
    for i, name in enumerate(names):
        patch = Patch(chosen[i], topo.faces.copy(), list(topo.slots), topo.adjacency, level)
        path = out / f"level{level}_{name}_{args.level_by}.{args.format}"
        write_patch(patch, path)
        records.append({"name": name, "level": level, "level_by": args.level_by, "files": [str(path)],
                        **{f"retranslation_{m}": float(errors[m][i]) for m in LEVEL_BY}})
        patches.append(patch)
    sheet, sheet_svg = contact_sheet(patches, names, errors, level, args.level_by, out / f"level{level}_contact_sheet.png")
    if args.json:
        print(json.dumps({"level": level, "level_by": args.level_by, "patches": records, "contact_sheet": sheet,
                          "contact_sheet_svg": sheet_svg}))
    else:
        for r in records:
            print(f"{r['name']}: re-translation QC-error {r['retranslation_none']:.4g} unleveled, "
                  f"{r['retranslation_lsq']:.4g} leveled (lsq)")
        print(f"{len(records)} patch files ({args.level_by}) and {Path(sheet).name} (and .svg) in {out}")
    return 0
