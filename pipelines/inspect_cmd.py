"""``meshsom inspect STORE``: what a store holds, read through :mod:`meshsom.store`.

Four sections, each fitting an 80-column terminal: the manifest (accepted and rejected inputs,
the most frequent rejection reasons), the arrays (name, shape, dtype, chunks, stored size), the
trained maps (map size, level, kernel, epochs done, final T/Q/QC-errors, engine) and the fold
statistics of every ring level. ``--json`` prints the same as one document.
"""

from __future__ import annotations

import argparse
import json
import textwrap
import warnings

#: Rejection reasons listed (the most frequent first).
REASONS_SHOWN = 5
#: Characters of a rejection reason shown in the table.
REASON_CHARS = 60


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("store", help="a store written by `meshsom run`, `ingest` or `encode`")
    p.add_argument("--json", action="store_true", help="print everything as one JSON document")


def describe_store(path) -> dict:
    """Everything ``meshsom inspect`` shows, as plain data.

    Returns
    -------
    dict
        ``store``, ``manifest`` (``summary``, ``reasons``: [kind of reason, count] most frequent
        first (:func:`pipelines.ingest.rejection_kinds`),
        ``first_rejections``: [id, reason], ``notes``: [kind of the reader's note, count] most
        frequent first (:func:`pipelines.ingest.note_kinds`)), ``arrays`` (``name``, ``shape``, ``dtype``,
        ``chunks``, ``bytes`` stored), ``runs`` (``name``, ``rows``, ``cols``, ``topology``,
        ``level``, ``kernel``, ``epochs``, ``epochs_done``, ``t_error``, ``q_error``,
        ``qc_error``, ``engine``, ``domain``), ``levels`` (``level``, ``stats``: the scaling,
        ``folds``: the fold statistics or None).
    """
    from meshsom.errors import StoreError
    from meshsom.store import (
        list_runs, open_store, read_domain, read_fold_stats, read_manifest, read_stats, ring_levels, run_attrs,
    )

    group = open_store(path)
    try:
        manifest = read_manifest(path)
    except StoreError:
        manifest = {"summary": {}, "records": []}
    rejected = [r for r in manifest.get("records", []) if r.get("status") == "rejected"]
    from pipelines.ingest import note_kinds, rebuilt_under_roofs, rejection_kinds

    reasons = rejection_kinds(rejected)
    out = {
        "store": str(path),
        "manifest": {
            "summary": dict(manifest.get("summary", {})),
            "reasons": [[kind, n] for kind, n, _ in reasons],
            "first_rejections": [[r.get("id"), r.get("reason")] for r in rejected[:REASONS_SHOWN]],
            "notes": [[kind, n] for kind, n in note_kinds(manifest.get("records", []))],
            "rebuilt_under_roofs": rebuilt_under_roofs(manifest.get("records", [])),
        },
        "arrays": _arrays(group),
        "runs": [],
        "levels": [],
    }
    for name in list_runs(group):
        attrs = run_attrs(group, name)
        metrics = dict(attrs.get("metrics", {}))
        engine = dict(attrs.get("engine", {}))
        job = dict(attrs.get("job", {}))
        domain = read_domain(group, name)
        if domain is not None:
            domain.pop("units", None)
        out["runs"].append({
            "name": name, "rows": attrs.get("rows"), "cols": attrs.get("cols"), "topology": attrs.get("topology"),
            "level": attrs.get("level"), "kernel": attrs.get("kernel"), "epochs": job.get("epochs"),
            "epochs_done": attrs.get("epoch_done"), "finished": bool(attrs.get("final_done")),
            **{k: metrics.get(k) for k in ("t_error", "q_error", "qc_error")},
            "engine": engine, "domain": domain,
        })
    for level in ring_levels(group):
        try:
            stats = read_stats(group, level)
        except StoreError:
            stats = None
        try:
            folds = read_fold_stats(group, level)
        except StoreError:
            folds = None
        out["levels"].append({"level": level, "stats": stats, "folds": folds})
    return out


def _arrays(group) -> list[dict]:
    rows = []
    with warnings.catch_warnings():  # manifest.json is no zarr node
        warnings.simplefilter("ignore")
        members = sorted(group.members(max_depth=None), key=lambda m: m[0])
    for name, node in members:
        if not hasattr(node, "shape"):
            continue
        try:
            stored = int(node.nbytes_stored())
        except (AttributeError, NotImplementedError, OSError):
            stored = None
        dtype = "str" if "StringDType" in str(node.dtype) else str(node.dtype)
        rows.append({"name": name, "shape": list(node.shape), "dtype": dtype, "chunks": list(node.chunks),
                     "bytes": stored})
    return rows


def _size(n) -> str:
    if n is None:
        return "-"
    for unit in ("B", "kB", "MB", "GB", "TB"):
        if n < 1000 or unit == "TB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1000.0
    return "-"


def _num(v, digits: int = 4) -> str:
    return "-" if v is None else f"{v:.{digits}f}"


def render(info: dict, width: int = 80) -> str:
    """The four sections of ``meshsom inspect`` as text (fits ``width`` columns)."""
    from meshsom.standardize import describe_fold_statistics
    from pipelines.runs_cmd import format_table

    out = [f"store {info['store']}"]
    s = info["manifest"]["summary"]
    out.append(f"\nmanifest: {s.get('inputs', 0)} inputs, {s.get('accepted', 0)} accepted, "
               f"{s.get('rejected', 0)} rejected")
    for reason, n in info["manifest"]["reasons"][:REASONS_SHOWN]:
        text = reason if len(reason) <= REASON_CHARS else reason[: REASON_CHARS - 1] + "~"
        out.append(f"  {n:5d} x {text}")
    for mesh, reason in info["manifest"]["first_rejections"][:1]:
        out.append(textwrap.fill(f"first rejected: {mesh}: {reason}", width, initial_indent="  ",
                                 subsequent_indent="    "))
    if info["manifest"].get("rebuilt_under_roofs"):
        out.append(f"  {info['manifest']['rebuilt_under_roofs']:5d} x accepted, rebuilt as the solid under its roofs")
    for note, n in info["manifest"].get("notes", [])[:REASONS_SHOWN]:
        text = f"read: {note}"
        out.append(f"  {n:5d} x {text if len(text) <= REASON_CHARS else text[: REASON_CHARS - 1] + '~'}")

    rows = [[a["name"], " x ".join(map(str, a["shape"])), a["dtype"], " x ".join(map(str, a["chunks"])),
             _size(a["bytes"])] for a in info["arrays"]]
    out.append(f"\narrays ({len(rows)}):")
    out.append(format_table(["name", "shape", "dtype", "chunks", "stored"], rows, [False, True, False, True, True],
                            width, [0, 3]))

    out.append(f"\ntrained maps ({len(info['runs'])}):")
    if info["runs"]:
        rows = []
        for r in info["runs"]:
            engine = r["engine"].get("backend", "-")
            if r["engine"].get("layout") and engine != "numpy":
                engine += f" {r['engine']['layout']}"
            done = f"{r['epochs_done'] or 0}/{r['epochs'] or '?'}" + ("" if r["finished"] else " (unfinished)")
            rows.append([r["name"], f"{r['rows']}x{r['cols']}", str(r["level"] or "-"), str(r["kernel"] or "-"), done,
                         _num(r["t_error"]), _num(r["q_error"]), _num(r["qc_error"]), engine])
        out.append(format_table(["run", "map", "L", "kernel", "epochs", "T", "Q", "QC", "engine"], rows,
                                [False, True, True, False, True, True, True, True, False], width, [0, 8, 3]))
    out.append("\nfold statistics:")
    if not info["levels"]:
        out.append("  no ring levels encoded")
    for lv in info["levels"]:
        st = lv["stats"]
        scale = "-" if st is None else (f"{st.get('scaling', 'standard')} scaling, mean "
                                        f"{', '.join(f'{x:.4g}' for x in st['mean'])}, std "
                                        f"{', '.join(f'{x:.4g}' for x in st['std'])}")
        out.append(textwrap.fill(f"level {lv['level']}: {scale}", width, initial_indent="  ", subsequent_indent="    "))
        if lv["folds"] is not None:
            out.append(textwrap.fill(describe_fold_statistics(lv["folds"]), width, initial_indent="    ",
                                     subsequent_indent="    "))
    return "\n".join(out)


def run(args: argparse.Namespace) -> int:
    info = describe_store(args.store)
    print(json.dumps(info, indent=1) if args.json else render(info))
    return 0
