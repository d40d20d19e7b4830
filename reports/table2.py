"""Table 2 of the paper: map, dimensions and T/Q/QC-errors per level and kernel, from MLflow.

`python -m reports.table2 [--tracking-uri URI] [--experiment paper] [--out DIR]` reads the final
metrics of every triangle map of the experiment's latest finished pipeline run and writes
``DIR/table2.md``, our numbers next to the paper's (DESIGN.md §4). A level the run did not train
is listed with a note instead of numbers.

Our errors are measured on standardized fold vectors (z-scores per component type), the paper's on
its own scaling, so the absolute values are not comparable; the relations between rows are
(:mod:`reports.report` checks them).
"""

from __future__ import annotations

import argparse
import sys

from reports.runs import TrackedExperiment, add_common_arguments, load_experiment, run_main

__all__ = ["ERRORS", "PAPER_TABLE2", "format_markdown", "format_value", "main", "rows"]

#: The paper's Table 2 (48 LoD1 blocks of Zürich Altstetten, 3064 triangles), by (level, kernel).
PAPER_TABLE2 = {
    (1, "default"): {"map": "120x150", "dims": "1x9", "t_error": 0.32735, "q_error": 0.00581, "qc_error": 0.00286},
    (1, "bmuofn"): {"map": "120x150", "dims": "6x9", "t_error": 0.06560, "q_error": 0.00141, "qc_error": 0.00064},
    (2, "bmuofn"): {"map": "120x150", "dims": "3x36", "t_error": 0.28949, "q_error": 0.04733, "qc_error": 0.00885},
    (3, "bmuofn"): {"map": "120x150", "dims": "3x144", "t_error": 0.37794, "q_error": 0.14427, "qc_error": 0.01230},
}
#: Metric name -> column title.
ERRORS = {"t_error": "T-error", "q_error": "Q-error", "qc_error": "QC-error"}
#: Significant digits printed for our errors (the test parses them back).
DIGITS = 6


def format_value(x: float | None) -> str:
    """A metric as printed in the table (``DIGITS`` significant digits), or an em dash when absent."""
    return "—" if x is None else f"{x:.{DIGITS}g}"


def _level_name(level: int, kernel: str) -> str:
    return f"{level}*" if kernel == "default" else str(level)


def rows(exp: TrackedExperiment) -> list[dict]:
    """Table 2's rows: every map of the run and every row of the paper, in the paper's order.

    Parameters
    ----------
    exp : TrackedExperiment

    Returns
    -------
    list of dict
        Keys ``level``, ``kernel``, ``name`` (``1*`` for the default kernel), ``run`` (the map's
        run name or None when not trained), ``map`` and ``dims`` (ours, None when not trained),
        ``ours`` (metric -> float or None), ``paper`` (the paper's row, or None).
    """
    keys = list(PAPER_TABLE2)
    keys += [(m.level, m.kernel) for m in exp.maps.values() if (m.level, m.kernel) not in PAPER_TABLE2]
    keys.sort(key=lambda k: (k[0], k[1] != "default"))
    out = []
    for level, kernel in keys:
        m = exp.find(level, kernel)
        out.append({
            "level": level, "kernel": kernel, "name": _level_name(level, kernel),
            "run": m.name if m else None,
            "map": f"{m.params.get('map_rows')}x{m.params.get('map_cols')}" if m else None,
            "dims": m.params.get("dims") if m else None,
            "ours": {k: (m.metrics.get(k) if m else None) for k in ERRORS},
            "paper": PAPER_TABLE2.get((level, kernel)),
        })
    return out


def format_markdown(table: list[dict], exp: TrackedExperiment) -> str:
    """Table 2 as Markdown: ours and the paper's, side by side, with the run it was read from."""
    head = ["level", "kernel", "map", "dims"] + list(ERRORS.values()) + ["paper map", "paper dims"]
    head += [f"paper {t}" for t in ERRORS.values()]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * 2 + "---|---|" + "---:|" * 3 + "---|---|" + "---:|" * 3]
    notes = []
    for r in table:
        p = r["paper"] or {}
        ours = [format_value(r["ours"][k]) for k in ERRORS]
        if r["run"] is None:
            notes.append(f"level {r['name']} ({r['kernel']}): not trained in this run")
        lines.append("| " + " | ".join(
            [r["name"], r["kernel"], r["map"] or "not trained", r["dims"] or "—"] + ours
            + [p.get("map", "—"), p.get("dims", "—")] + [f"{p[k]:.5f}" if k in p else "—" for k in ERRORS]) + " |")
    from meshsom.store import corpus_counts

    attrs = {k: ("?" if v is None else v) for k, v in corpus_counts(exp.open_store()).items()}
    lines += [
        "",
        f"Ours: {attrs['n_meshes']} meshes, {attrs['n_faces']} triangles; MLflow experiment "
        f"`{exp.experiment}` at `{exp.uri}`, pipeline run `{exp.run_id}` (store `{exp.store}`); final metrics (step = epochs) of each map's child run, on standardized "
        "vectors. Paper: Table 2, 48 LoD1 blocks of Zürich Altstetten (3064 triangles), its own scaling: "
        "compare relations between rows, not absolute values. `1*` is the default kernel (one variation).",
    ]
    lines += [f"- {n}" for n in notes]
    return "\n".join(lines) + "\n"


def write(exp: TrackedExperiment, out) -> tuple[str, list[dict]]:
    """Write ``out/table2.md``; returns its text and rows."""
    table = rows(exp)
    text = format_markdown(table, exp)
    out.mkdir(parents=True, exist_ok=True)
    (out / "table2.md").write_text(text)
    return text, table


def _main(argv) -> int:
    p = argparse.ArgumentParser(prog="python -m reports.table2", description=__doc__.splitlines()[0])
    add_common_arguments(p)
    args = p.parse_args(argv)
    text, _ = write(load_experiment(args.tracking_uri, args.experiment), args.out)
    print(text, end="")
    return 0


def main(argv: list[str] | None = None) -> int:
    """Write ``table2.md`` (see the module docstring); exit code 2 with a message when nothing is tracked."""
    return run_main(_main, argv, "python -m reports.table2")


if __name__ == "__main__":
    sys.exit(main())
