"""``meshsom run CONFIG``: the whole experiment from one YAML file, on a Dask cluster, tracked in MLflow.

Stages:

1. corpus: read, preprocess and encode every input in shards (:mod:`pipelines.corpus`), into the
   zarr store named by ``store.path``;
2. maps: one triangle map per ``train`` entry (level, kernel), epochs as map-reduce over row chunks
   (:mod:`pipelines.train`), each a child MLflow run with per-epoch and final T/Q/QC-errors and its
   U-matrix;
3. domain maps per level, where the library provides them (:mod:`meshsom.domain`).

The tracking server and the inputs are checked before any heavy work and before a store is
created. ``--resume`` continues an interrupted run: finished shards and epochs are not recomputed,
and the MLflow runs of the first attempt are continued (no metric step is logged twice).

Configuration: the YAML file, then the options (``--store``, ``--backend``, ...), then ``--set
KEY=VALUE`` items, validated together (:func:`pipelines.settings.load_config`). Relative paths in
the config are relative to the config file's folder (``--store`` to the working directory). MLflow
records this configuration, defaults filled in, as the parent's params and as
``config/config.yaml``; the conventions of names, tags and metrics are in :mod:`pipelines.tracking`.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
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
    p.add_argument("--store", help="override store.path (relative to the working directory)")
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
    p.add_argument("--set", dest="sets", action="append", default=[], metavar="KEY=VALUE",
                   help="override any config key (dotted path, YAML value), validated like the file; repeatable: "
                        "--set som.epochs=4 --set encoding.levels=[1,2]")


def dataset_fingerprint(manifest: dict) -> str:
    """Short hash of what was ingested (ids, statuses, face counts)."""
    rows = sorted((r["id"], r["status"], r.get("faces_out", 0)) for r in manifest["records"])
    return hashlib.sha256(json.dumps(rows).encode()).hexdigest()[:12]


def _overrides(args) -> dict:
    over: dict = {}
    if args.store:
        store = args.store
        if "://" not in store and not Path(store).is_absolute():
            # relative to the working directory, written relative to the config's folder like every config path
            store = os.path.relpath(Path(store).resolve(), Path(args.config).resolve().parent)
        over["store"] = {"path": store}
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
    from pipelines.settings import load_config

    cfg = load_config(args.config, _overrides(args) or None, getattr(args, "sets", ()))
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
    """Run every stage of an experiment; returns the exit code.

    Parameters
    ----------
    cfg : pipelines.settings.RunConfig
        As loaded: relative paths are resolved here, against the folder of ``config_path`` (the
        working directory without one); MLflow records ``cfg`` itself.
    config_path : Path, optional
        The config file (its folder anchors relative paths; its name is the run's source).
    """
    from tqdm import tqdm

    import yaml

    from meshsom.config import flatten, to_dict
    from meshsom.errors import StoreError
    from meshsom.store import MANIFEST, local_copy, location, open_store, read_manifest, read_tracking, \
        remove_store, store_exists, store_url, write_tracking
    from pipelines.cluster import connect
    from pipelines.corpus import run_corpus
    from pipelines.ingest import check_writable
    from pipelines.settings import resolve_paths
    from pipelines.tracking import Tracker, new_short_id, run_name, source_tags

    given = cfg  # what MLflow records: paths as written, relative to the config's folder
    cfg = resolve_paths(cfg, config_path.parent if config_path is not None else Path.cwd())
    store = location(cfg.store.path)  # a local folder or a URL (s3://bucket/name.zarr)
    if store_exists(store) and not (overwrite or resume):
        raise StoreError(f"{store}: already exists; pass --overwrite to replace it or --resume to continue it")
    from pipelines.ingest import estimate_store_bytes

    # every check before any work (and before an old store is removed or a new one created)
    skipped = check_inputs(given, cfg, config_path)
    check_writable(store, overwrite=True, needed_bytes=estimate_store_bytes(
        cfg.corpus.paths, cfg.corpus.generator, cfg.encoding.levels))
    tracker = Tracker(cfg.tracking)
    tracker.open()  # fails here, naming the URI
    existed = store_exists(store)
    if overwrite and existed:
        remove_store(store)
    t_start = time.perf_counter()
    with_domain = cfg.domain.enabled and _domain_available()
    stages = 2 + (1 if with_domain else 0)
    try:
        with connect(cfg.dask) as client:
            # ------------------------------------------------------------------ 1. corpus
            print(f"[1/{stages}] ingest + encode levels {list(cfg.encoding.levels)} -> {_shown(store)}")
            from pipelines.ingest import print_skipped

            print_skipped(skipped)
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
            print(f"      {summary['inputs']} meshes: {summary['accepted']} accepted, {summary['rejected']} "
                  f"rejected ({summary.get('faces_out', 0)} triangles) in {time.perf_counter() - t0:.1f} s")
            if not summary["accepted"]:
                _nothing_ingested(store, remove=not (resume and existed))
            group = open_store(store, mode="r+")
            manifest = read_manifest(store)
            _print_rejection_kinds(manifest["records"])
            _print_rebuilt(manifest["records"])
            _print_note_kinds(manifest["records"])
            _print_scale_hint(group, cfg)
            fingerprint = dataset_fingerprint(manifest)
            ids = read_tracking(group) if resume else {}
            if ids.get("uri") not in (None, tracker.uri):
                ids = {}  # a different tracking server: start new runs
            short_id = ids.get("short_id") or new_short_id()
            tags = {**source_tags(f"meshsom run {config_path.name}" if config_path is not None else "meshsom run"),
                    "dataset_fingerprint": fingerprint, "store": store_url(store)}
            parent = tracker.start(run_name(cfg.name, short_id), flatten(to_dict(given)), tags,
                                   run_id=ids.get("parent"))
            ids = {"uri": tracker.uri, "experiment": cfg.tracking.experiment, "name": cfg.name, "parent": parent,
                   "short_id": short_id, "children": dict(ids.get("children", {}))}
            write_tracking(group, ids)
            tracker.log_text(parent, yaml.safe_dump(to_dict(given), sort_keys=False), CONFIG_ARTIFACT)
            with tempfile.TemporaryDirectory() as tmp:  # a remote store's manifest is copied here first
                tracker.log_artifact(parent, local_copy(store, MANIFEST, tmp), "manifest")

            # ------------------------------------------------------------------ 2. triangle maps
            print(f"[2/{stages}] {len(cfg.train)} triangle maps, {cfg.som.rows} x {cfg.som.cols}, "
                  f"{cfg.som.epochs} epochs")
            results = []
            for spec in cfg.train:
                results.append(_train_one(client, cfg, spec, store, tracker, parent, ids, group, resume, fingerprint))
            print(f"      BMU search: {'; '.join(sorted({_engine(r) for r in results}))}")
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
    seconds = time.perf_counter() - t_start
    _log_once(tracker, parent, {**summary_metrics(results), "total_seconds": seconds}, step=0)
    tracker.finish(parent)
    _print_summary(results, store, tracker, seconds)
    return 0


#: Artifact path of the resolved configuration on the parent run.
CONFIG_ARTIFACT = "config/config.yaml"


def summary_metrics(results: list[dict]) -> dict[str, float]:
    """The parent run's summary: every map's final errors, ``level1-bmuofn.qc_error``, and its seconds."""
    out = {}
    for r in results:
        for k in ("t_error", "q_error", "qc_error"):
            out[f"{r['run']}.{k}"] = float(r["metrics"][k])
        out[f"{r['run']}.seconds"] = float(r["seconds"])
    return out


def _log_once(tracker, run_id, metrics: dict, step: int) -> None:
    """Log the metrics that run ``run_id`` does not have at ``step`` yet (a resumed run repeats none)."""
    fresh = {k: v for k, v in metrics.items() if step not in tracker.logged_steps(run_id, k)}
    tracker.log_metrics(run_id, fresh, step=step)


def check_inputs(given, cfg, config_path: Path | None) -> list[tuple[str, str]]:
    """Check ``corpus.paths`` before anything is created; returns the files in folders that are skipped.

    Parameters
    ----------
    given, cfg : RunConfig
        As written, and with paths resolved.
    config_path : Path or None

    Returns
    -------
    list of (path, why)

    Raises
    ------
    meshsom.errors.ConfigError
        Naming the config file, each input that does not exist or holds nothing readable (a folder
        without a mesh or CityJSON file, a file of an unknown type), and where it was looked for.
    """
    from meshsom.errors import ConfigError, InputFileError
    from meshsom.io import expand_inputs
    from meshsom.mirror import is_url, remote_files

    skipped: list[tuple[str, str]] = []
    _, rejected = expand_inputs([p for p in cfg.corpus.paths if not is_url(p)], skipped)
    roots = dict(zip(cfg.corpus.paths, given.corpus.paths))
    bad = [f"{roots[r.source]!r} ({r.source}): {r.reason}" for r in rejected if r.source in roots]
    for url in (p for p in cfg.corpus.paths if is_url(p)):  # on object storage: listed (copied when the run plans)
        try:
            if not remote_files(url.rstrip("/"))[0]:
                bad.append(f"{url!r}: no such file or folder (nothing under this URL)")
        except InputFileError as err:
            bad.append(f"{url!r}: {err.problem}")
    if bad:
        where = config_path or "the config"
        raise ConfigError(f"{where}: corpus.paths (relative to the config file's folder): "
                          + "; ".join(bad) + "; nothing was created")
    return skipped


#: Kinds of rejection reasons ``meshsom run`` prints after its ingest line (``meshsom inspect`` shows more).
RUN_KINDS_SHOWN = 3


def _print_rejection_kinds(records) -> None:
    """The most frequent kinds of rejection reasons (:func:`pipelines.ingest.rejection_kinds`), one
    line each, cut to 80 columns."""
    from pipelines.ingest import rejection_kinds

    kinds = rejection_kinds(records)
    _print_kinds([(kind, n) for kind, n, _ in kinds], "")
    if len(kinds) > RUN_KINDS_SHOWN:
        print(f"        ({len(kinds) - RUN_KINDS_SHOWN} more kinds: meshsom inspect)")


def _print_scale_hint(group, cfg) -> None:
    """The hint of :func:`meshsom.standardize.scale_hint` for the first level's folds, if any."""
    from meshsom.errors import StoreError
    from meshsom.standardize import scale_hint
    from meshsom.store import read_fold_stats

    try:
        hint = scale_hint(read_fold_stats(group, min(cfg.encoding.levels)), cfg.encoding.scaling)
    except StoreError:  # a store encoded before fold statistics were kept
        return
    if hint:
        print(f"      {hint}")


def _print_rebuilt(records) -> None:
    """How many meshes were rebuilt under their roofs (:func:`pipelines.ingest.rebuilt_under_roofs`)."""
    from pipelines.ingest import rebuilt_under_roofs

    n = rebuilt_under_roofs(records)
    if n:
        print(f"        {n:5,d} x rebuilt as the solid under its roofs (record: envelope)")


def _print_note_kinds(records) -> None:
    """The most frequent kinds of the reader's notes (:func:`pipelines.ingest.note_kinds`: coordinates
    converted from a CRS, heights from storeys), one line each, cut to 80 columns."""
    from pipelines.ingest import note_kinds

    _print_kinds(note_kinds(records), "read: ")


def _print_kinds(kinds: list[tuple[str, int]], prefix: str) -> None:
    """The first :data:`RUN_KINDS_SHOWN` ``(kind, count)``, one line each, cut to 80 columns."""
    for kind, n in kinds[:RUN_KINDS_SHOWN]:
        line = f"        {n:5,d} x {prefix}{kind}"
        print(line if len(line) <= 80 else line[:79] + "~")


def _nothing_ingested(store: str, remove: bool) -> None:
    """Every input was rejected: say why (the first few reasons) and remove the new store."""
    from meshsom.errors import InputFileError
    from meshsom.store import read_manifest

    records = [r for r in read_manifest(store)["records"] if r["status"] != "accepted"]
    reasons = "; ".join(f"{r.get('source') or r['id']}: {r.get('reason', '?')}" for r in records[:3])
    more = f" (and {len(records) - 3} more)" if len(records) > 3 else ""
    if remove:
        from meshsom.store import remove_store

        remove_store(store)
    raise InputFileError(str(store), f"nothing could be ingested; every input was rejected: {reasons}{more}"
                         + ("; the store was removed" if remove else ""))


def _shown(path) -> str:
    """``path`` relative to the working directory when it lies below it (shorter on the terminal); a URL as it is."""
    from meshsom.store import is_remote

    if is_remote(path):
        return str(path)
    try:
        return str(Path(path).resolve().relative_to(Path.cwd()))
    except ValueError:
        return str(path)


def _engine(result: dict) -> str:
    return result["backend"] if result["backend"] == "numpy" else f"opencl {result['layout']}"


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
    from meshsom.store import figures_dir, write_tracking
    from meshsom.variations import n_variations
    from meshsom.rings import dims
    from meshsom.som import default_sigma_start
    from pipelines.tracking import run_name
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
        "backend": cfg.opencl.backend, "codebook": f"runs/{job.run}",  # relative to the parent's store tag
    }
    previous = ids["children"].get(job.run)
    child = tracker.start(run_name(cfg.name, ids["short_id"], job.run), params,
                          {"dataset_fingerprint": fingerprint, "map": job.run}, parent=parent, run_id=previous)
    ids["children"][job.run] = child
    write_tracking(group, ids)
    logged = tracker.logged_steps(child, "q_error") if previous else set()  # steps an earlier attempt logged
    bar = tqdm(total=som.epochs, desc=f"      {job.run}", unit="epoch", leave=False, disable=None)
    every = max(1, -(-som.epochs // EPOCH_LINES))
    t_map = time.perf_counter()

    def on_epoch(epoch, metrics):
        if epoch not in logged:  # the history at step=epoch, the final errors at step=epochs: each once
            tracker.log_metrics(child, metrics, step=epoch)
            logged.add(epoch)
        bar.update(1)
        done = epoch + 1
        if bar.disable and (done % every == 0 or done == som.epochs):
            # no progress bar (stdout is not a terminal): a line every few epochs
            elapsed = time.perf_counter() - t_map
            print(f"      {job.run}: epoch {done}/{som.epochs}, {elapsed:.1f} s, about "
                  f"{elapsed / done * (som.epochs - done):.0f} s left, QC {metrics['qc_error']:.4f}", flush=True)

    result = train_spec(client, job, resume=resume, on_epoch=on_epoch)
    bar.close()
    if som.epochs not in logged:  # finished in an earlier attempt, but MLflow missed its final errors
        tracker.log_metrics(child, result["metrics"], step=som.epochs)
        logged.add(som.epochs)
    cb = load_codebook(group, job.run)
    png = figures_dir(store) / f"umatrix-{job.run}.png"
    render_map(cb.weights, cb.rows, cb.cols, png, topology=cb.topology,
               title=f"U-matrix, level {spec.level} ({spec.kernel} kernel, {result['dims']})")
    for figure in (png, png.with_suffix(".svg")):
        tracker.log_artifact(child, figure, "figures")
    tracker.log_model(child, group, job.run, step=som.epochs)  # the map as a pyfunc model (pipelines.model)
    trained = som.epochs - min(int(result["resumed_from"]), som.epochs)  # epochs computed in this attempt
    if trained and result["seconds"] > 0:
        tracker.log_metrics(child, {
            "wall_seconds": time.perf_counter() - t_map,
            "seconds_per_epoch": result["seconds"] / trained,
            "triangles_per_second": result["n_vectors"] * trained / result["seconds"],
        }, step=som.epochs)
    tracker.set_tags(child, engine_tags(result))
    tracker.finish(child)
    m = result["metrics"]
    print(f"      {job.run:14s} {result['dims']:>5s}  T {m['t_error']:.5f}  Q {m['q_error']:.5f}  "
          f"QC {m['qc_error']:.5f}  {result['seconds']:6.1f} s")
    if result.get("fallback"):
        print(f"      {job.run}: kernel fallback: {result['fallback']}")
    return {**result, "level": spec.level, "kernel": spec.kernel, "umatrix": str(png)}


def engine_tags(result: dict) -> dict:
    """MLflow tags that say what computed a map: backend, device, kernel layout and any fallback."""
    return {"backend": result["backend"], "opencl_device": result["device"],
            "kernel_layout": result.get("layout") or "", "kernel_fallback": result.get("fallback") or "none"}


def _print_summary(results, store, tracker, seconds) -> None:
    from meshsom.store import figures_dir

    figures = figures_dir(store)
    print(f"done in {seconds:.1f} s")
    print(f"  store:   {_shown(store)} (manifest.json, runs/)")
    print(f"  figures: {_shown(figures)}")
    if tracker.enabled:
        print(f"  MLflow:  experiment {tracker.config.experiment!r} at {tracker.uri}")
        print(f"           side by side: mlflow ui --backend-store-uri {tracker.uri}")
    if tracker.failed:
        print(f"warning: {len(tracker.failed)} MLflow writes failed; every result is in the store.")
        print(f"  send them later with: meshsom log {store} --tracking-uri {tracker.uri}")
        for f in tracker.failed[:5]:
            print(f"  {f['what']} ({f.get('name') or f['run_id']}): {f['error']}"[:80])
