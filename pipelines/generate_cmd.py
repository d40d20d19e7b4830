"""``meshsom generate``: a seeded synthetic corpus of labelled building blocks."""

from __future__ import annotations

import argparse
from pathlib import Path

from tqdm import tqdm

from meshsom.errors import ConfigError
from meshsom.generate import BLOCK_FAMILIES, ROOF_FAMILIES, GeneratorParams, generate_corpus
from meshsom.citygml import write_citygml
from meshsom.io import write_cityjson, write_cityjsonseq, write_mesh_folder

#: --format choices written to one file, by their writer.
FILE_WRITERS = {"cityjson": write_cityjson, "cityjsonseq": write_cityjsonseq, "citygml": write_citygml}


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", required=True, help="output: a .city.json, .city.jsonl or .gml file (a final .gz compresses it), "
                   "or a folder for --format obj/ply")
    p.add_argument("-n", "--blocks", type=int, default=GeneratorParams.n_blocks, help="number of buildings (default %(default)s)")
    p.add_argument("--seed", type=int, default=GeneratorParams.seed, help="random seed (default %(default)s)")
    p.add_argument(
        "--families", nargs="+", default=None, metavar="FAMILY",
        help=f"families to draw from (default: the LoD1 blocks {', '.join(BLOCK_FAMILIES)}; roofs: {', '.join(ROOF_FAMILIES)})",
    )
    p.add_argument("--roofs", action="store_true", help="add the LoD2 roof families (gabled, hipped, shed)")
    p.add_argument("--origin", type=float, nargs=3, default=None, metavar=("X", "Y", "Z"), help="world offset (e.g. 2600000 1200000 400)")
    p.add_argument("--format", choices=(*FILE_WRITERS, "obj", "ply"), default="cityjson", help="output format (default %(default)s)")


def run(args: argparse.Namespace) -> int:
    families = tuple(args.families) if args.families else BLOCK_FAMILIES
    if args.roofs:
        families = families + tuple(f for f in ROOF_FAMILIES if f not in families)
    kwargs = dict(n_blocks=args.blocks, seed=args.seed, families=families)
    if args.origin:
        kwargs["origin"] = tuple(args.origin)
    try:
        params = GeneratorParams(**kwargs)
    except ValueError as err:
        raise ConfigError(f"meshsom generate: {err}") from None
    with tqdm(total=params.n_blocks, desc="generate", unit="block", disable=None) as bar:
        blocks = generate_corpus(params, progress=bar.update)
    out = Path(args.out)
    if args.format in FILE_WRITERS:
        out.parent.mkdir(parents=True, exist_ok=True)
        FILE_WRITERS[args.format](out, blocks)
    else:
        write_mesh_folder(out, blocks, suffix=f".{args.format}")
    n_faces = sum(len(b.faces) for b in blocks)
    counts = {f: sum(b.label == f for b in blocks) for f in families}
    print(f"wrote {len(blocks)} blocks ({n_faces} triangles) to {out}")
    print("families: " + ", ".join(f"{k} {v}" for k, v in counts.items()))
    return 0
