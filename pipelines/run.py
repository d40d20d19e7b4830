"""``meshsom run CONFIG``: the whole experiment from one YAML file.

Stages, in order: ingest (read, clean, store), then encode and train as they
are configured. Results land in the zarr store named by ``store.path``.
"""

from __future__ import annotations

import argparse
import time


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("config", help="experiment YAML (see configs/)")
    p.add_argument("--store", help="override store.path")
    p.add_argument("--overwrite", action="store_true", help="replace an existing store")


def run(args: argparse.Namespace) -> int:
    from meshsom.config import load_config
    from pipelines.ingest import ingest

    overrides = {"store": {"path": args.store}} if args.store else None
    cfg = load_config(args.config, overrides)
    t0 = time.perf_counter()
    print(f"[1/2] ingest -> {cfg.store.path}")
    result = ingest(
        cfg.corpus.paths, cfg.store.path, cfg.corpus.reader, cfg.preprocess, cfg.corpus.generator,
        overwrite=args.overwrite, chunk_rows=cfg.store.chunk_rows,
    )
    s = result.summary
    print(f"      {s['inputs']} meshes: {s['accepted']} accepted, {s['rejected']} rejected "
          f"({s['faces_out']} triangles) in {time.perf_counter() - t0:.1f} s")
    if not s["accepted"]:
        return 1
    from pipelines.encode_cmd import encode_store

    t1 = time.perf_counter()
    print(f"[2/2] encode levels {list(cfg.encoding.levels)}")
    enc = encode_store(cfg.store.path, cfg.encoding.levels, cfg.store.chunk_rows, progress=True)
    for level, info in enc.levels.items():
        print(f"      rings/level{level}: {enc.faces} x {info['dims']}")
    print(f"      in {time.perf_counter() - t1:.1f} s")
    print(f"results: {cfg.store.path} (manifest: {cfg.store.path}/manifest.json)")
    print("next: `meshsom train STORE --level L --kernel bmuofn` per level (the distributed pipeline is issue 6)")
    return 0
