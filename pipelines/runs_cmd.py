"""``meshsom runs``: the tracked triangle maps side by side, read from MLflow.

One line per map run (a child run with a ``level`` param): the experiment's config name, the run's
name, level, kernel, backend, final T-, Q- and QC-errors, epochs, seconds and start time, newest
first. The table fits an 80-column terminal (``--wide``: every column, untruncated); ``--json``
prints the records.
"""

from __future__ import annotations

import argparse
import json
import shutil
import textwrap
from datetime import datetime

#: Terminal width the default table fits.
WIDTH = 80
#: Runs read at most (newest first) unless --limit says otherwise.
DEFAULT_LIMIT = 100
#: Columns: key, header, right-aligned, shown in the 80-column table (every one with --wide).
COLUMNS = (
    ("config", "config", False, True),
    ("run", "run", False, False),
    ("level", "L", True, True),
    ("kernel", "kernel", False, True),
    ("backend", "backend", False, True),
    ("t_error", "T", True, True),
    ("q_error", "Q", True, True),
    ("qc_error", "QC", True, True),
    ("epochs", "ep", True, True),
    ("seconds", "s", True, True),
    ("start", "started", False, True),
    ("status", "status", False, False),
    ("run_id", "run id", False, False),
)
#: Columns that give way (truncated, in this order) when a table is wider than the terminal.
SHRINK = ("config", "run", "backend", "kernel")
#: Shortest a shrunk column gets.
MIN_WIDTH = 4
METRICS = ("t_error", "q_error", "qc_error")
#: Metric holding a map's training time, where the run logged one.
SECONDS_METRIC = "wall_seconds"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--tracking-uri", help="MLflow tracking URI (default: as `meshsom run`, MLFLOW_TRACKING_URI or "
                   "MLflow's local default)")
    p.add_argument("--experiment", action="append", help="experiment name (repeatable; default: every experiment)")
    p.add_argument("--limit", type=int, default=DEFAULT_LIMIT, help=f"newest map runs to show (default {DEFAULT_LIMIT})")
    out = p.add_mutually_exclusive_group()
    out.add_argument("--wide", action="store_true", help="every column, nothing truncated (wider than 80 columns)")
    out.add_argument("--json", action="store_true", help="print the records as JSON")


def collect_runs(uri: str, experiments: list[str] | None = None, limit: int = DEFAULT_LIMIT) -> list[dict]:
    """The map runs of a tracking store, newest first.

    Parameters
    ----------
    uri : str
        MLflow tracking URI.
    experiments : list of str or None
        Experiment names; None: every experiment.
    limit : int

    Returns
    -------
    list of dict
        ``experiment``, ``config`` (the parent run's config name), ``run``, ``run_id``, ``status``,
        ``level``, ``kernel``, ``backend`` (what computed it, else the configured one), ``t_error``,
        ``q_error``, ``qc_error`` (latest values, None where missing), ``epochs``, ``seconds``
        (the ``seconds`` metric, else the run's wall time), ``start`` (ISO time), ``model_uri``.

    Raises
    ------
    MeshsomError
        An experiment name the store does not have (the message lists those it has).
    """
    from mlflow.tracking import MlflowClient

    from meshsom.errors import MeshsomError

    client = MlflowClient(tracking_uri=uri)
    known = {e.name: e for e in client.search_experiments()}
    if experiments:
        missing = [name for name in experiments if name not in known]
        if missing:
            raise MeshsomError(f"MLflow at {uri}: no experiment {', '.join(map(repr, missing))}; "
                               f"it has {', '.join(sorted(known)) or 'none'}")
        chosen = [known[name] for name in experiments]
    else:
        chosen = list(known.values())
    if not chosen:
        return []
    names = {e.experiment_id: e.name for e in chosen}
    runs = client.search_runs(list(names), filter_string="params.level != ''", max_results=max(1, limit),
                              order_by=["attributes.start_time DESC"])
    parents: dict = {}
    records = []
    for r in runs:
        parent_id = r.data.tags.get("mlflow.parentRunId")
        if parent_id and parent_id not in parents:
            try:
                parents[parent_id] = client.get_run(parent_id)
            except Exception:  # a deleted parent: the row stays, without a config name
                parents[parent_id] = None
        parent = parents.get(parent_id)
        records.append(_record(r, parent, names.get(r.info.experiment_id, "")))
    return records


def _record(run, parent, experiment: str) -> dict:
    p, m, t, info = run.data.params, run.data.metrics, run.data.tags, run.info
    seconds = m.get(SECONDS_METRIC)
    if seconds is None and info.end_time and info.start_time:
        seconds = (info.end_time - info.start_time) / 1000.0
    config = ""
    if parent is not None:
        config = parent.data.params.get("name") or parent.info.run_name or ""
    return {
        "experiment": experiment, "config": config, "run": info.run_name, "run_id": info.run_id,
        "status": info.status, "level": _int(p.get("level")), "kernel": p.get("kernel", ""),
        "backend": t.get("backend") or p.get("backend", ""),
        **{k: m.get(k) for k in METRICS},
        "epochs": _int(p.get("epochs")), "seconds": seconds,
        "start": datetime.fromtimestamp(info.start_time / 1000).isoformat(timespec="seconds") if info.start_time else None,
        "model_uri": t.get("model_uri"),
    }


def _int(value):
    try:
        return int(value)
    except (TypeError, ValueError):
        return value


def _cell(key: str, value, wide: bool) -> str:
    if value is None:
        return "-"
    if key in METRICS:
        return f"{value:.5f}" if wide else f"{value:.4f}"
    if key == "seconds":
        return f"{value:.1f}"
    if key == "start" and not wide:
        return value[5:16].replace("T", " ")  # MM-DD HH:MM
    return str(value)


def format_table(headers: list[str], rows: list[list[str]], right: list[bool], width: int | None = WIDTH,
                 shrink: list[int] = (), gap: str = "  ") -> str:
    """A plain-text table; with ``width``, the ``shrink`` columns are truncated (with ``~``) to fit.

    Parameters
    ----------
    headers : list of str
    rows : list of list of str
    right : list of bool
        Right-align that column (numbers).
    width : int or None
        Terminal width to fit; None: no limit.
    shrink : list of int
        Columns that may be truncated, in the order they give way.
    """
    widths = [max([len(h)] + [len(r[i]) for r in rows]) for i, h in enumerate(headers)]
    if width is not None:
        for i in shrink:
            over = sum(widths) + len(gap) * (len(widths) - 1) - width
            if over <= 0:
                break
            widths[i] = max(MIN_WIDTH, len(headers[i]), widths[i] - over)

    def fit(text: str, w: int, r: bool) -> str:
        text = text if len(text) <= w else text[: w - 1] + "~"
        return text.rjust(w) if r else text.ljust(w)

    lines = [gap.join(fit(c, w, r) for c, w, r in zip(line, widths, right)).rstrip() for line in [headers, *rows]]
    lines.insert(1, gap.join("-" * w for w in widths))
    return "\n".join(lines)


def render_runs(records: list[dict], wide: bool = False, width: int = WIDTH) -> str:
    """The table of :func:`collect_runs` records (80 columns unless ``wide``)."""
    cols = [c for c in COLUMNS if wide or c[3]]
    keys = [c[0] for c in cols]
    rows = [[_cell(k, rec.get(k), wide) for k in keys] for rec in records]
    return format_table([c[1] for c in cols], rows, [c[2] for c in cols], None if wide else width,
                        [keys.index(k) for k in SHRINK if k in keys])


def run(args: argparse.Namespace) -> int:
    from pipelines.settings import TrackingConfig
    from pipelines.tracking import resolve_uri

    uri = resolve_uri(TrackingConfig(uri=args.tracking_uri))
    records = collect_runs(uri, args.experiment, args.limit)
    if args.json:
        print(json.dumps(records, indent=1))
        return 0
    if not records:
        print(f"no map runs in MLflow at {uri}" + (f", experiment {', '.join(args.experiment)}" if args.experiment else ""))
        return 0
    width = min(WIDTH, shutil.get_terminal_size((WIDTH, 24)).columns)
    print(render_runs(records, wide=args.wide, width=width))
    if not args.wide:
        print(textwrap.fill(f"{len(records)} map runs in {uri}; T, Q, QC: final errors; --wide adds run names "
                            f"and ids", width))
    return 0
