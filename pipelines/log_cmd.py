"""``meshsom log STORE [--tracking-uri URI]``: send a run's results from the store to MLflow.

Every result of ``meshsom run`` is written to the store first (per-epoch errors in the run's
attributes, final errors, domain-map metrics). When the tracking server was unreachable for part
of a run, this command logs what MLflow is missing: it reopens the runs recorded in the store
(same URI) or creates new ones, and writes only the metric steps MLflow does not have yet, so it
can be repeated safely.
"""

from __future__ import annotations

import argparse

METRICS = ("t_error", "q_error", "qc_error")


def log_store(store, uri: str | None = None, experiment: str | None = None) -> dict:
    """Log the store's finished maps to MLflow; returns ``{"parent": id, "children": {run: id}, "logged": n}``."""
    from meshsom.errors import StoreError
    from meshsom.store import list_runs, open_store, read_domain, read_tracking, run_attrs, store_url, write_tracking
    from pipelines.settings import TrackingConfig
    from pipelines.tracking import Tracker, TrackingError, new_short_id, run_name

    group = open_store(store, mode="r+")
    info = read_tracking(group)
    uri = uri or info.get("uri")
    if not uri:
        raise StoreError(f"{store}: records no tracking URI; pass --tracking-uri")
    experiment = experiment or info.get("experiment") or "meshsom"
    tracker = Tracker(TrackingConfig(uri=uri, experiment=experiment))
    tracker.open()
    same = info.get("uri") == uri and info.get("experiment", experiment) == experiment
    name = info.get("name", "meshsom")
    short_id = info.get("short_id") or new_short_id()
    parent = tracker.start(run_name(name, short_id), {}, {"store": store_url(store), "logged_by": "meshsom log"},
                           run_id=info.get("parent") if same else None)
    children = dict(info.get("children", {})) if same else {}
    logged = 0
    for run in list_runs(group):
        attrs = run_attrs(group, run)
        if not attrs.get("final_done"):
            continue
        job, result = attrs["job"], attrs["result"]
        if job.get("source"):
            continue  # a streamed domain map: its metrics go with its triangle map's run
        params = {"level": job["level"], "kernel": job["kernel"], "dims": result["dims"], "map_rows": job["rows"],
                  "map_cols": job["cols"], "topology": job["topology"], "epochs": job["epochs"], "seed": job["seed"],
                  "codebook": f"runs/{run}"}
        rid = children.get(run)
        rid = tracker.start(run_name(name, short_id, run), params if rid is None else {}, {"map": run},
                            parent=parent, run_id=rid)
        children[run] = rid
        have = {m.step for m in tracker.client.get_metric_history(rid, "q_error")}
        for h in result["history"]:
            if h["epoch"] not in have:
                tracker.log_metrics(rid, {k: h[k] for k in METRICS}, step=h["epoch"])
                logged += 1
        if job["epochs"] not in have:
            final = dict(result["metrics"])
            final.update((read_domain(group, run) or {}).get("metrics", {}))
            tracker.log_metrics(rid, final, step=job["epochs"])
            logged += 1
        tracker.finish(rid)
    tracker.finish(parent)
    info.update(uri=uri, experiment=experiment, parent=parent, children=children, short_id=short_id)
    write_tracking(group, info)
    if tracker.failed:
        raise TrackingError(f"MLflow at {uri}: {len(tracker.failed)} writes failed again: {tracker.failed[0]['error']}")
    return {"parent": parent, "children": children, "logged": logged}


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("store", help="a store written by `meshsom run`")
    p.add_argument("--tracking-uri", help="MLflow URI (default: the one the run used)")
    p.add_argument("--experiment", help="MLflow experiment (default: the one the run used)")


def run(args: argparse.Namespace) -> int:
    out = log_store(args.store, args.tracking_uri, args.experiment)
    print(f"logged {out['logged']} metric steps of {len(out['children'])} maps to MLflow (parent run {out['parent']})")
    return 0
