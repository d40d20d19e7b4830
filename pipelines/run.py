"""``meshsom run CONFIG``: the whole experiment from one YAML file, on a Dask cluster, tracked in MLflow.

Stages:

1. corpus: read, preprocess and encode every input in shards (:mod:`pipelines.corpus`), into the
   zarr store named by ``store.path``;
2. maps: one triangle map per ``train`` entry (level, kernel), epochs as map-reduce over row chunks
   (:mod:`pipelines.train`), each a child MLflow run with per-epoch and final T/Q/QC-errors and its
   U-matrix;
3. domain maps per level, where the library provides them (:mod:`meshsom.domain`).

The tracking server is checked before any heavy work. ``--resume`` continues an interrupted run:
finished shards and epochs are not recomputed, and the MLflow runs of the first attempt are
continued.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import signal
import tempfile
import threading
import time
from pathlib import Path

from meshsom.config import BACKENDS, LAYOUTS

#: Epoch progress lines per map when stdout is not a terminal (no progress bar there).
EPOCH_LINES = 5
#: Seconds between progress lines of a corpus stage when stdout is not a terminal (and one at its end).
PROGRESS_INTERVAL_S = 10.0


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("config", help="experiment YAML (see configs/)")
    p.add_argument("--store", help="override store.path")
    mode = p.add_mutually_exclusive_group()
    mode.add_argument("--overwrite", action="store_true", help="replace an existing store")
    mode.add_argument("--resume", action="store_true", help="continue an interrupted run in the existing store")
    p.add_argument("--tracking-uri", help="MLflow tracking URI (overrides tracking.uri), e.g. http://127.0.0.1:5000")
    p.add_argument("--no-tracking", action="store_true", help="do not write to MLflow")
    p.add_argument("--scheduler", help="address of an existing Dask scheduler (overrides dask.scheduler)")
    p.add_argument("--workers", type=int, help="local Dask workers (overrides dask.workers)")
    p.add_argument("--backend", choices=BACKENDS, help="BMU search backend (overrides opencl.backend): auto tries "
                   "OpenCL and falls back to NumPy/BLAS, numpy never touches OpenCL, opencl fails without it")
    p.add_argument("--device", help="OpenCL device selector, e.g. 0:0, pocl, nvidia (overrides opencl.device)")
    p.add_argument("--layout", help=f"OpenCL kernel layouts to try in order instead of the device's chain, "
                   f"comma-separated (of {', '.join(LAYOUTS)}; overrides opencl.layout; `meshsom doctor` shows which work)")


def dataset_fingerprint(manifest: dict) -> str:
    """Short hash of what was ingested (ids, statuses, face counts)."""
    rows = sorted((r["id"], r["status"], r.get("faces_out", 0)) for r in manifest["records"])
    return hashlib.sha256(json.dumps(rows).encode()).hexdigest()[:12]


def _overrides(args) -> dict:
    over: dict = {}
    if args.store:
        over["store"] = {"path": args.store}
    if args.tracking_uri or args.no_tracking:
        over["tracking"] = {**({"uri": args.tracking_uri} if args.tracking_uri else {}),
                            **({"enabled": False} if args.no_tracking else {})}
    opencl = {k: getattr(args, k) for k in ("backend", "device", "layout") if getattr(args, k, None)}
    if opencl:
        over["opencl"] = opencl
    if args.scheduler or args.workers:
        over["dask"] = {**({"scheduler": args.scheduler} if args.scheduler else {}),
                        **({"workers": args.workers} if args.workers else {})}
    return over


def run(args: argparse.Namespace) -> int:
    from meshsom.config import load_config

    cfg = load_config(args.config, _overrides(args) or None)
    main = threading.current_thread() is threading.main_thread()  # handlers can only be set there
    previous = signal.getsignal(signal.SIGTERM)
    if main:
        signal.signal(signal.SIGTERM, _terminated)  # a killed run ends its MLflow runs as KILLED
    try:
        return run_experiment(cfg, Path(args.config), overwrite=args.overwrite, resume=args.resume)
    finally:
        if main:
            signal.signal(signal.SIGTERM, previous)


def _terminated(signum, frame):
    raise KeyboardInterrupt(f"signal {signal.Signals(signum).name}")


def run_experiment(cfg, config_path: Path | None = None, overwrite: bool = False, resume: bool = False) -> int:
    """Run every stage of an experiment; returns the exit code."""
    from tqdm import tqdm

    from meshsom.config import flatten, to_dict
    from meshsom.errors import StoreError
    from meshsom.store import MANIFEST, local_copy, location, open_store, read_manifest, remove_store, \
        store_exists, store_url
    from pipelines.cluster import connect
    from pipelines.corpus import run_corpus
    from pipelines.ingest import check_writable
    from pipelines.tracking import Tracker, git_commit

    store = location(cfg.store.path)  # a local folder or a URL (s3://bucket/name.zarr)
    if store_exists(store) and not (overwrite or resume):
        raise StoreError(f"{store}: already exists; pass --overwrite to replace it or --resume to continue it")
    from pipelines.ingest import estimate_store_bytes

    # every check before any work (and before an old store is removed)
    check_writable(store, overwrite=True, needed_bytes=estimate_store_bytes(
        cfg.corpus.paths, cfg.corpus.generator, cfg.encoding.levels))
    tracker = Tracker(cfg.tracking)
    tracker.open()  # fails here, naming the URI
    if overwrite:
        remove_store(store)
    t_start = time.perf_counter()
    with_domain = cfg.domain.enabled and _domain_available()
    stages = 2 + (1 if with_domain else 0)
    try:
        with connect(cfg.dask) as client:
            # ------------------------------------------------------------------ 1. corpus
            print(f"[1/{stages}] ingest + encode levels {list(cfg.encoding.levels)} -> {store}")
            bars: dict = {}

            def progress(stage, done, total):
                bar = bars.get(stage)
                if bar is None:
                    bar = bars[stage] = tqdm(total=total, desc=f"      {stage}", unit="task", leave=False, disable=None)
                    bar.last = time.perf_counter()  # of the last progress line (no terminal)
                bar.update(done - bar.n)
                if bar.disable and (done == total or time.perf_counter() - bar.last >= PROGRESS_INTERVAL_S):
                    bar.last = time.perf_counter()
                    elapsed = time.perf_counter() - t0
                    left = elapsed / max(done, 1) * (total - done)
                    print(f"      {stage}: {done}/{total} tasks, {elapsed:.1f} s elapsed, about {left:.0f} s left",
                          flush=True)

            t0 = time.perf_counter()
            summary = run_corpus(client, cfg, str(store), resume=resume, progress=progress)
            for bar in bars.values():
                bar.close()
            print(f"      {summary['inputs']} meshes: {summary['accepted']} accepted, {summary['rejected']} rejected "
                  f"({summary.get('faces_out', 0)} triangles) in {time.perf_counter() - t0:.1f} s")
            if not summary["accepted"]:
                print("nothing could be ingested; see the manifest for the reasons")
                return 1
            group = open_store(store, mode="r+")
            manifest = read_manifest(store)
            fingerprint = dataset_fingerprint(manifest)
            ids = dict(group.attrs.get("mlflow", {})) if resume else {}
            if ids.get("uri") not in (None, tracker.uri):
                ids = {}  # a different tracking server: start new runs
            parent = tracker.start(
                cfg.name, flatten(to_dict(cfg)),
                {"git_commit": git_commit(), "dataset_fingerprint": fingerprint, "store": store_url(store)},
                run_id=ids.get("parent"),
            )
            ids = {"uri": tracker.uri, "experiment": cfg.tracking.experiment, "name": cfg.name, "parent": parent,
                   "children": dict(ids.get("children", {}))}
            group.attrs["mlflow"] = ids
            if config_path is not None and config_path.exists():
                tracker.log_artifact(parent, config_path, "config")
            with tempfile.TemporaryDirectory() as tmp:  # a remote store's manifest is copied here first
                tracker.log_artifact(parent, local_copy(store, MANIFEST, tmp), "manifest")

            # ------------------------------------------------------------------ 2. triangle maps
            print(f"[2/{stages}] triangle maps: {', '.join(s.name for s in cfg.train)} ({cfg.som.rows} x {cfg.som.cols}, "
                  f"{cfg.som.epochs} epochs)")
            results = []
            for spec in cfg.train:
                results.append(_train_one(client, cfg, spec, store, tracker, parent, ids, group, resume, fingerprint))
            # ------------------------------------------------------------------ 3. domain maps
            if with_domain:
                print(f"[3/{stages}] domain maps")
                from pipelines.domain_stage import run_domain_stage

                run_domain_stage(cfg, store, tracker, ids, results, client)
    except KeyboardInterrupt:
        tracker.end_open("KILLED")  # the parent and every map run still open
        raise
    except BaseException:
        tracker.end_open("FAILED")
        raise
    tracker.set_tags(parent, {
        "backends": ",".join(sorted({r["backend"] for r in results})),
        "kernel_layouts": ",".join(sorted({x for r in results for x in r.get("layout", "").split(",") if x})),
        "kernel_fallback": "; ".join(r["fallback"] for r in results if r.get("fallback")) or "none",
    })
    tracker.finish(parent)
    _print_summary(results, store, tracker, time.perf_counter() - t_start)
    return 0


def _domain_available() -> bool:
    try:
        import pipelines.domain_stage  # noqa: F401
    except ImportError:
        return False
    return True


def _train_one(client, cfg, spec, store, tracker, parent, ids, group, resume, fingerprint) -> dict:
    from tqdm import tqdm

    from meshsom.umatrix import render_map
    from meshsom.codebook import load_codebook
    from meshsom.store import figures_dir, store_url
    from meshsom.variations import n_variations
    from meshsom.rings import dims
    from meshsom.som import default_sigma_start
    from pipelines.train import TrainJob, train_spec

    som = cfg.som
    job = TrainJob(
        store=str(store), level=spec.level, kernel=spec.kernel, mirror=som.mirror_higher, rows=som.rows, cols=som.cols,
        topology=som.topology, epochs=som.epochs,
        sigma_start=float(som.sigma_start if som.sigma_start is not None else default_sigma_start(som.rows, som.cols)),
        sigma_end=float(som.sigma_end), init=som.init, seed=som.seed, backend=cfg.opencl.backend, device=cfg.opencl.device,
        layout=cfg.opencl.layout,
    )
    n_var = n_variations(spec.level, spec.kernel, som.mirror_higher)
    params = {
        "level": spec.level, "kernel": spec.kernel, "variations": n_var, "dims": f"{n_var}x{dims(spec.level)}",
        "map_rows": som.rows, "map_cols": som.cols, "topology": som.topology, "epochs": som.epochs,
        "sigma_start": job.sigma_start, "sigma_end": job.sigma_end, "init": som.init, "seed": som.seed,
        "backend": cfg.opencl.backend, "codebook": f"{store_url(store)}/runs/{job.run}",
    }
    child = tracker.start(job.run, params, {"dataset_fingerprint": fingerprint}, parent=parent,
                          run_id=ids["children"].get(job.run))
    ids["children"][job.run] = child
    group.attrs["mlflow"] = ids
    bar = tqdm(total=som.epochs, desc=f"      {job.run}", unit="epoch", leave=False, disable=None)
    every = max(1, -(-som.epochs // EPOCH_LINES))
    t_map = time.perf_counter()

    def on_epoch(epoch, metrics):
        tracker.log_metrics(child, metrics, step=epoch)
        bar.update(1)
        done = epoch + 1
        if bar.disable and (done % every == 0 or done == som.epochs):
            # no progress bar (stdout is not a terminal): a line every few epochs
            elapsed = time.perf_counter() - t_map
            print(f"      {job.run}: epoch {done}/{som.epochs}, {elapsed:.1f} s elapsed, about "
                  f"{elapsed / done * (som.epochs - done):.0f} s left (QC {metrics['qc_error']:.4f})", flush=True)

    result = train_spec(client, job, resume=resume, on_epoch=on_epoch)
    bar.close()
    if result["resumed_from"] < som.epochs:  # a finished map's final errors were logged by its first attempt
        tracker.log_metrics(child, result["metrics"], step=som.epochs)
    cb = load_codebook(group, job.run)
    png = figures_dir(store) / f"umatrix-{job.run}.png"
    render_map(cb.weights, cb.rows, cb.cols, png, topology=cb.topology,
               title=f"U-matrix, level {spec.level} ({spec.kernel} kernel, {result['dims']})")
    tracker.log_artifact(child, png, "figures")
    tracker.set_tags(child, engine_tags(result))
    tracker.finish(child)
    m = result["metrics"]
    where = result["backend"] if result["backend"] == "numpy" else f"opencl {result['layout']}"
    print(f"      {job.run:16s} {result['dims']:>7s}  T {m['t_error']:.5f}  Q {m['q_error']:.5f}  "
          f"QC {m['qc_error']:.5f}  ({where}, {result['seconds']:.1f} s)")
    if result.get("fallback"):
        print(f"      {job.run}: kernel fallback: {result['fallback']}")
    return {**result, "level": spec.level, "kernel": spec.kernel, "umatrix": str(png)}


def engine_tags(result: dict) -> dict:
    """MLflow tags that say what computed a map: backend, device, kernel layout and any fallback."""
    return {"backend": result["backend"], "opencl_device": result["device"],
            "kernel_layout": result.get("layout") or "", "kernel_fallback": result.get("fallback") or "none"}


def _print_summary(results, store, tracker, seconds) -> None:
    from meshsom.store import figures_dir

    print(f"done in {seconds:.1f} s. results: {store} (manifest.json, runs/), figures: {figures_dir(store)}")
    if tracker.enabled:
        print(f"MLflow: {tracker.uri}, experiment {tracker.config.experiment!r} "
              f"(look at them side by side: mlflow ui --backend-store-uri {tracker.uri})")
    if tracker.failed:
        print(f"warning: {len(tracker.failed)} MLflow writes failed; every result is in the store. "
              f"Send them later with: meshsom log {store} --tracking-uri {tracker.uri}")
        for f in tracker.failed[:5]:
            print(f"  {f['what']} ({f.get('name') or f['run_id']}): {f['error']}")
