"""``meshsom encode STORE --levels 1 2 3``: fold vectors of every cleaned face into the store.

Writes ``rings/level{L}`` (F x 9*4^(L-1) float32, chunked by rows, start leaf 0, raw values), the
scaling statistics (``--scaling standard|robust``) and the fold statistics of each level into
``rings/stats`` (DESIGN.md §7), and prints both. Meshes are
processed in batches of whole meshes (every face's neighbours belong to its own mesh), each batch
vectorised; memory is bounded by the batch, not by the corpus.
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import dataclass

import numpy as np

#: Faces per batch of whole meshes (a mesh larger than this is one batch of its own).
DEFAULT_BATCH_FACES = 500_000


@dataclass
class EncodeResult:
    store: str
    faces: int
    levels: dict  # level -> {"dims", "seconds", "stats"}


def mesh_batches(face_offsets: np.ndarray, batch_faces: int) -> list[tuple[int, int]]:
    """Consecutive mesh ranges ``(first, stop)`` holding at most ``batch_faces`` faces (or one mesh)."""
    batches, first = [], 0
    n = len(face_offsets) - 1
    while first < n:
        stop = first + 1
        while stop < n and face_offsets[stop + 1] - face_offsets[first] <= batch_faces:
            stop += 1
        batches.append((first, stop))
        first = stop
    return batches


def level_statistics(group, levels, accs: dict, scaling: str = "standard", robust_clip: float = 5.0) -> dict:
    """Write every level's scaling and fold statistics into ``rings/stats``; return them.

    Parameters
    ----------
    group : zarr.Group
        The store root, with ``rings/level{L}`` written.
    levels : list of int
    accs : dict
        Level -> standardization accumulator (:func:`meshsom.standardize.accumulate`).
    scaling : str
        ``standard`` or ``robust`` (:data:`meshsom.standardize.SCALINGS`).
    robust_clip : float

    Returns
    -------
    out : dict
        Level -> {"stats": scaling statistics, "folds": fold statistics}.
    """
    from meshsom.standardize import SCALINGS, finalize, fold_statistics, robust_stats
    from meshsom.store import read_folds, write_fold_stats, write_stats

    if scaling not in SCALINGS:
        raise ValueError(f"scaling must be one of {list(SCALINGS)}, received {scaling!r}")
    folds = read_folds(group, min(levels)).astype(np.float64)  # the same folds at every level
    out = {}
    for level in levels:
        if scaling == "robust":
            stats = robust_stats(folds, level, robust_clip).to_dict()
        else:
            stats = finalize(accs[level], level).to_dict()
        fstats = fold_statistics(folds, level)
        write_stats(group, level, stats)
        write_fold_stats(group, level, fstats)
        out[level] = {"stats": stats, "folds": fstats}
    return out


def encode_store(store, levels, chunk_rows: int | None = None, batch_faces: int = DEFAULT_BATCH_FACES,
                 progress: bool = False, scaling: str = "standard", robust_clip: float = 5.0) -> EncodeResult:
    """Encode every face of an ingested store at the given levels.

    Parameters
    ----------
    store : path
        A store written by ``meshsom ingest``.
    levels : iterable of int
    chunk_rows : int, optional
        Row chunk of the ring arrays (default: the store's faces chunking).
    batch_faces : int
    progress : bool
        Show a progress bar.
    scaling : str
        ``standard`` (mean, std) or ``robust`` (median, IQR, clipped): config ``encoding.scaling``.
    robust_clip : float
        Config ``encoding.robust_clip``.
    """
    from tqdm import tqdm

    from meshsom.folds import folds
    from meshsom.rings import dims, encode_level, template
    from meshsom.standardize import accumulate, empty_accumulator
    from meshsom.store import mesh_table, open_store, rings_name
    from meshsom.topology import adjacency

    levels = sorted({int(level) for level in levels})
    for level in levels:
        template(level)  # validates
    group = open_store(store, mode="r+")
    table = mesh_table(group)
    n_faces = int(table.face_offsets[-1])
    chunk_rows = chunk_rows or int(group["faces"].chunks[0])
    rings = group.require_group("rings")
    arrays = {
        level: rings.create_array(rings_name(level), shape=(n_faces, dims(level)), dtype=np.float32,
                                  chunks=(max(1, min(chunk_rows, max(n_faces, 1))), dims(level)), overwrite=True)
        for level in levels
    }
    accs = {level: empty_accumulator() for level in levels}
    seconds = {level: 0.0 for level in levels}
    vertices_all, faces_all = group["vertices"], group["faces"]
    bar = tqdm(total=n_faces, unit="tri", desc="encode", disable=not progress)
    for first, stop in mesh_batches(table.face_offsets, batch_faces):
        v0, v1 = table.vertex_offsets[first], table.vertex_offsets[stop]
        f0, f1 = table.face_offsets[first], table.face_offsets[stop]
        if f1 == f0:
            continue
        v = np.asarray(vertices_all[v0:v1])
        f = np.asarray(faces_all[f0:f1]) - v0
        adj = adjacency(f, source=f"{store} meshes {first}..{stop - 1}")
        fo = folds(v, f, adj)
        for level in levels:
            t = time.perf_counter()
            x = encode_level(fo, adj, level)
            seconds[level] += time.perf_counter() - t
            arrays[level][f0:f1] = x
            accs[level] = accumulate(accs[level], x)
        bar.update(int(f1 - f0))
    bar.close()
    if n_faces == 0:
        raise ValueError("the store has no faces to encode")
    stats = level_statistics(group, levels, accs, scaling, robust_clip)
    out = {level: {"dims": dims(level), "seconds": seconds[level], **stats[level]} for level in levels}
    return EncodeResult(store=str(store), faces=n_faces, levels=out)


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
        from meshsom.standardize import describe_fold_statistics

        for level, info in result.levels.items():
            s = info["stats"]
            rate = result.faces / info["seconds"] if info["seconds"] else float("inf")
            centre, scale = ("median", "IQR/1.349") if s["scaling"] == "robust" else ("mean", "std")
            print(f"level {level}: {result.faces} x {info['dims']} -> rings/level{level} "
                  f"({rate:,.0f} triangles/s); {s['scaling']} scaling: {centre} {np.round(s['mean'], 4).tolist()}, "
                  f"{scale} {np.round(s['std'], 4).tolist()}" + (f", clip {s['clip']:g}" if s["clip"] else ""))
            print(f"  {describe_fold_statistics(info['folds'])}")
    return 0
