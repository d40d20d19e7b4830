"""A zipped download of city tiles through the pipeline: one read task for the archive, or one per tile.

    .venv/bin/python bench/zip_read.py [--tiles 16] [--workers 2] [--repeat 1]

Writes ``--tiles`` CityJSON tiles (copies of the bundled Zürich LoD 2 file, each object renamed) into one zip archive,
as a state's LoD 2 download comes, then builds the store of ``meshsom ingest`` (reading, preprocessing, the level-1
encoding) on a LocalCluster of ``--workers`` single-threaded workers two ways, in the same run, after a warm-up:

- the reference: the archive read by one task (:func:`meshsom.archives.read_zip`, as before, and as now where the
  store's disk has no room for its files: ``pipelines.corpus.UNZIP_DISK_SHARE`` set to 0);
- the planner extracting it into the store's staging group, each tile then read by a task of its own.

It prints the seconds of each (best of ``--repeat``), their ratio, and checks that the two stores hold the same records.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
import zipfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
ZURICH = ROOT / "data" / "real" / "zurich-lod2-subset" / "zurich_subset_lod2.city.json"


def write_archive(path: Path, tiles: int) -> int:
    """``tiles`` renamed copies of the Zürich file zipped; the number of objects."""
    base = json.loads(ZURICH.read_text())
    objects = 0
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as archive:
        for k in range(tiles):
            renamed = {f"{oid}-{k}": {**obj, **{key: [f"{c}-{k}" for c in obj[key]] for key in ("children", "parents")
                                                  if key in obj}} for oid, obj in base["CityObjects"].items()}
            archive.writestr(f"tiles/{k:03d}.city.json", json.dumps({**base, "CityObjects": renamed}))
            objects += len(renamed)
    return objects


def main(argv=None) -> int:
    from distributed import Client, LocalCluster

    from meshsom.config import build
    from meshsom.store import read_manifest
    from pipelines import corpus
    from pipelines.settings import RunConfig

    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--tiles", type=int, default=16)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--repeat", type=int, default=1)
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory() as folder, LocalCluster(n_workers=args.workers, threads_per_worker=1,
                                                              processes=True, dashboard_address=None) as cluster, \
            Client(cluster) as client:
        archive = Path(folder) / "download.zip"
        objects = write_archive(archive, args.tiles)
        cfg = build(RunConfig, {"corpus": {"paths": [str(archive)]}, "encoding": {"levels": [1]}})
        times, records = {}, {}
        for way, share in (("one task (reference)", 0.0), ("a task per tile", corpus.UNZIP_DISK_SHARE)):
            corpus.UNZIP_DISK_SHARE = share
            best = float("inf")
            for k in range(args.repeat + 1):  # the first: a warm-up
                store = Path(folder) / f"s{k}.zarr"
                t = time.perf_counter()
                corpus.run_corpus(client, cfg, store)
                if k:
                    best = min(best, time.perf_counter() - t)
            times[way] = best
            records[way] = sorted((r["id"], r["status"], r.get("volume")) for r in read_manifest(store)["records"])
        same = len(set(map(json.dumps, records.values()))) == 1
        print(f"{args.tiles} tiles zipped ({objects:,} objects), {args.workers} workers; the stores' records alike: {same}")
        print("| read | seconds | ratio to one task |")
        print("|---|---|---|")
        reference = times["one task (reference)"]
        for way, seconds in times.items():
            print(f"| {way} | {seconds:.1f} | {seconds / reference:.2f} |")
    return 0 if same else 1


if __name__ == "__main__":
    raise SystemExit(main())
