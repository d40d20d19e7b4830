"""City scale: ingest + encode + triangle maps on >= 1,000,000 triangles, with peak memory per process.

    env -u OPENBLAS_CORETYPE -u OPENBLAS_L2_SIZE .venv/bin/python bench/city.py [--blocks 37000] [--epochs 2]

Builds a synthetic city (``meshsom generate`` blocks; ~27 triangles per block after preprocessing)
plus the bundled real data, runs the pipeline stages on a LocalCluster (one thread per worker)
and prints, per stage: wall time, triangles per second, the Dask task costs, and an estimate of
the same stage on 10 and 100 workers from the measured per-task costs:

    T(w) ~ serial + max(sum(task seconds) / w, longest task)

where ``serial`` is the client-side part (wall time minus the parallel part on the measured
workers). Peak RSS is read from every process (client: the process running this script, which
also hosts the scheduler; workers: each worker process) with ``getrusage``.
The domain stage streams its vectors (meshes x map units) through the store when they are large.
"""

from __future__ import annotations

import argparse
import os
import platform
import resource
import shutil
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
REAL = ["data/real/zurich-lod2-subset/zurich_subset_lod1_derived.city.json", "data/real/delft-lod1-3dfier"]


def peak_rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def estimate(wall: float, task_seconds: list[float], workers: int, targets=(10, 100)) -> dict:
    total = sum(task_seconds)
    longest = max(task_seconds, default=0.0)
    serial = max(0.0, wall - max(total / workers, longest))
    return {w: serial + max(total / w, longest) for w in targets}


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--blocks", type=int, default=37_000, help="synthetic blocks (~27 triangles each)")
    p.add_argument("--no-real", action="store_true", help="leave out the bundled real data")
    p.add_argument("--levels", type=int, nargs="+", default=[1, 2, 3])
    p.add_argument("--map", default="120x150")
    p.add_argument("--epochs", type=int, default=2, help="epochs per map (each epoch is one BMU pass over all rows)")
    p.add_argument("--workers", type=int, default=os.cpu_count() or 2)
    p.add_argument("--backend", default="auto", choices=["numpy", "opencl", "auto"])
    p.add_argument("--shard-meshes", type=int, default=500)
    p.add_argument("--domain-epochs", type=int, default=5)
    p.add_argument("--store", default=str(ROOT / "out" / "city.zarr"))
    args = p.parse_args(argv)

    from distributed import get_task_stream

    from pipelines.settings import load_config
    from meshsom.store import open_store
    from pipelines.cluster import connect
    from pipelines.corpus import run_corpus
    from pipelines.domain_stage import domain_for_run
    from meshsom.som import default_sigma_start
    from pipelines.train import TrainJob, train_spec

    rows, cols = (int(x) for x in args.map.lower().split("x"))
    cfg_path = ROOT / "out" / "city-bench.yaml"
    cfg_path.parent.mkdir(parents=True, exist_ok=True)
    cfg_path.write_text("name: city\n")
    cfg = load_config(cfg_path, {
        "corpus": {"paths": [] if args.no_real else [str(ROOT / r) for r in REAL],
                   "generator": {"n_blocks": args.blocks, "seed": 0}},
        "encoding": {"levels": args.levels},
        "som": {"rows": rows, "cols": cols, "epochs": args.epochs},
        "domain": {"epochs": args.domain_epochs},
        "dask": {"workers": args.workers, "shard_meshes": args.shard_meshes, "dashboard": False},
        "opencl": {"backend": args.backend},
        "tracking": {"enabled": False},
        "store": {"path": args.store},
    })
    store = Path(args.store)
    if store.exists():
        shutil.rmtree(store)
    print(f"city bench: {platform.processor() or platform.machine()}, {os.cpu_count()} cores, "
          f"{args.workers} workers x 1 thread, backend {args.backend}; {args.blocks} synthetic blocks"
          f"{'' if args.no_real else ' + bundled real data'}; levels {args.levels}; map {rows}x{cols}, {args.epochs} epochs")
    stages = []
    with connect(cfg.dask, quiet=True) as client:
        t0 = time.perf_counter()
        with get_task_stream(client) as ts:
            summary = run_corpus(client, cfg, str(store))
        wall = time.perf_counter() - t0
        tasks = [sum(s["stop"] - s["start"] for s in t["startstops"] if s["action"] == "compute") for t in ts.data]
        tri = int(open_store(store).attrs.get("n_faces", summary.get("faces_out", 0)))
        stages.append(("ingest+encode", wall, tri, tasks))
        print(f"corpus: {summary['inputs']} meshes ({summary['accepted']} accepted), {tri:,} triangles")
        from pipelines.domain_stage import MAX_THUMBNAILS, thumbnails_of

        t0 = time.perf_counter()
        thumbs = thumbnails_of(open_store(store), min(summary["accepted"], MAX_THUMBNAILS))
        print(f"thumbnails: {len(thumbs)} in {time.perf_counter() - t0:.1f} s")
        for level in args.levels:
            job = TrainJob(store=str(store), level=level, kernel="bmuofn", mirror=False, rows=rows, cols=cols,
                           topology="toroidal", epochs=args.epochs, sigma_start=default_sigma_start(rows, cols), sigma_end=1.0,
                           init="random", seed=0, backend=args.backend)
            t0 = time.perf_counter()
            with get_task_stream(client) as ts:
                res = train_spec(client, job)
            wall = time.perf_counter() - t0
            tasks = [sum(s["stop"] - s["start"] for s in t["startstops"] if s["action"] == "compute") for t in ts.data]
            # each epoch and the final pass visit every row once
            stages.append((f"map level {level} ({res['dims']}, {args.epochs + 1} passes)", wall, tri * (args.epochs + 1), tasks))
            m = res["metrics"]
            print(f"level {level}: T {m['t_error']:.4f} Q {m['q_error']:.4f} QC {m['qc_error']:.4f}")
            t0 = time.perf_counter()
            with get_task_stream(client) as ts:
                dom = domain_for_run(cfg, store, job.run, thumbs=thumbs, client=client)
            wall = time.perf_counter() - t0
            tasks = [sum(s["stop"] - s["start"] for s in t["startstops"] if s["action"] == "compute") for t in ts.data]
            stages.append((f"domain map level {level}", wall, tri, tasks))
            print(f"level {level} domain map: {dom['metrics']}")
        worker_rss = client.run(lambda: resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0)
    print()
    print(f"{'stage':44s} {'wall s':>8s} {'tri/s':>12s} {'tasks':>6s} {'task s':>8s} {'est. 10 w':>10s} {'est. 100 w':>10s}")
    for name, wall, n, tasks in stages:
        est = estimate(wall, tasks, args.workers)
        print(f"{name:44s} {wall:8.1f} {n / wall:12,.0f} {len(tasks):6d} {sum(tasks):8.1f} {est[10]:10.1f} {est[100]:10.1f}")
    print()
    print(f"peak RSS: client (with scheduler) {peak_rss_mb():,.0f} MB; workers "
          + ", ".join(f"{v:,.0f} MB" for v in worker_rss.values()))
    size = sum(f.stat().st_size for f in store.rglob("*") if f.is_file())
    print(f"store: {store} ({size / 1e6:,.0f} MB on disk)")


if __name__ == "__main__":
    main()
