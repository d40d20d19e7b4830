"""``meshsom encode STORE --levels 1 2 3``: fold vectors of every cleaned face into the store.

Writes ``rings/level{L}`` (F x 9*4^(L-1) float32, chunked by rows, start leaf 0, raw values), the
scaling statistics (``--scaling standard|robust``) and the fold statistics of each level into
``rings/stats`` (DESIGN.md §7), and prints both. The work is done by the encoding driver of the
corpus stage (:func:`pipelines.corpus.encode_corpus`) on an in-process Dask client, in shards of
whole meshes (every face's neighbours belong to its own mesh); memory is bounded by the shard
(``--batch-faces``), not by the corpus.
"""

from __future__ import annotations

import argparse
import json
from dataclasses import dataclass

import numpy as np

from pipelines.corpus import DEFAULT_BATCH_FACES


@dataclass
class EncodeResult:
    store: str
    faces: int
    levels: dict  # level -> {"dims", "seconds", "stats", "folds"}


def encode_store(store, levels, chunk_rows: int | None = None, batch_faces: int = DEFAULT_BATCH_FACES,
                 progress: bool = False, scaling: str = "standard", robust_clip: float = 5.0) -> EncodeResult:
    """Encode every face of an ingested store at the given levels (:func:`pipelines.corpus.encode_corpus`).

    Parameters
    ----------
    store : path
        A store written by ``meshsom ingest``.
    levels : iterable of int
    chunk_rows : int, optional
        Row chunk of the ring arrays (default: the store's faces chunking).
    batch_faces : int
        Faces per shard of whole meshes.
    progress : bool
        Show progress bars.
    scaling : str
        ``standard`` (mean, std) or ``robust`` (median, IQR, clipped): config ``encoding.scaling``.
    robust_clip : float
        Config ``encoding.robust_clip``.
    """
    from meshsom.store import mesh_table, open_store
    from pipelines.cluster import connect_serial
    from pipelines.corpus import encode_corpus
    from pipelines.ingest import progress_bars

    report, close = progress_bars(progress)
    try:
        with connect_serial() as client:
            out = encode_corpus(client, store, levels, chunk_rows, batch_faces, scaling, robust_clip, report)
    finally:
        close()
    return EncodeResult(store=str(store), faces=int(mesh_table(open_store(store)).face_offsets[-1]), levels=out)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("store", help="a store written by `meshsom ingest`")
    p.add_argument("--levels", type=int, nargs="+", default=[1, 2, 3], help="ring levels (default: 1 2 3)")
    p.add_argument("--chunk-rows", type=int, help="row chunk of the ring arrays")
    p.add_argument("--batch-faces", type=int, default=DEFAULT_BATCH_FACES, help="faces per batch of meshes")
    p.add_argument("--scaling", choices=("standard", "robust"), default="standard",
                   help="standard: mean/std; robust: median/IQR, clipped to +-ROBUST_CLIP (default %(default)s)")
    p.add_argument("--robust-clip", type=float, default=5.0, help="clip of --scaling robust (default %(default)s)")
    p.add_argument("--json", action="store_true", help="print one JSON object")


def run(args: argparse.Namespace) -> int:
    try:
        result = encode_store(args.store, args.levels, args.chunk_rows, args.batch_faces, progress=not args.json,
                              scaling=args.scaling, robust_clip=args.robust_clip)
    except ValueError as err:
        from meshsom.errors import StoreError

        raise StoreError(f"{args.store}: {err}") from None
    if args.json:
        print(json.dumps({"store": result.store, "faces": result.faces, "levels": {str(k): v for k, v in result.levels.items()}}))
    else:
        from meshsom.standardize import describe_fold_statistics, scale_hint

        for level, info in result.levels.items():
            s = info["stats"]
            rate = result.faces / info["seconds"] if info["seconds"] else float("inf")
            centre, scale = ("median", "IQR/1.349") if s["scaling"] == "robust" else ("mean", "std")
            print(f"level {level}: {result.faces} x {info['dims']} -> rings/level{level} "
                  f"({rate:,.0f} triangles/s); {s['scaling']} scaling: {centre} {np.round(s['mean'], 4).tolist()}, "
                  f"{scale} {np.round(s['std'], 4).tolist()}" + (f", clip {s['clip']:g}" if s["clip"] else ""))
            print(f"  {describe_fold_statistics(info['folds'])}")
            hint = scale_hint(info["folds"], s["scaling"])
            if hint:
                print(f"  {hint}")
    return 0
