"""Figure 9 of the paper: domain maps with every building's thumbnail at its unit, per triangle map.

`python -m reports.fig9 [--tracking-uri URI] [--experiment paper] [--out DIR]` reads, for every map of
the experiment's latest finished pipeline run, the placement of each mesh on its domain map
(``runs/<run>/domain/units`` in the store, DESIGN.md §5) and the cleaned meshes, and writes
``DIR/fig9-<run>.png``. Where the corpus has labels (the synthetic families), each thumbnail is
framed in its family's colour. A map without a domain map is skipped with a note.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from reports.runs import TrackedExperiment, add_common_arguments, load_experiment, run_main

__all__ = ["MAX_THUMBNAILS", "THUMB_SIZE", "main", "thumbnails", "write"]

#: Meshes drawn on one figure at most (the first ones of the store; a city is drawn by a sample).
MAX_THUMBNAILS = 400
#: Thumbnail side in pixels.
THUMB_SIZE = 64


def thumbnails(group, n: int, size: int = THUMB_SIZE) -> list[np.ndarray]:
    """Rendered views of the first ``n`` meshes of a store.

    Returns
    -------
    list of (size, size, 4) uint8
    """
    from meshsom.store import mesh_table, read_mesh
    from meshsom.thumbnails import render_thumbnail

    table = mesh_table(group)
    return [render_thumbnail(*read_mesh(group, i, table), size=size) for i in range(n)]


def _has_labels(labels: np.ndarray) -> bool:
    return len(labels) > 1 and all(labels) and len(set(labels.tolist())) > 1


def write(exp: TrackedExperiment, out: Path) -> dict:
    """Write ``fig9-<run>.png`` for every map of the run that has a domain map.

    Returns
    -------
    dict
        ``figures``: run name -> path; ``missing``: notes on maps skipped.
    """
    from meshsom.store import mesh_table, read_domain
    from meshsom.thumbnails import domain_map_figure

    out.mkdir(parents=True, exist_ok=True)
    group = exp.open_store()
    table = mesh_table(group)
    labels = np.asarray(table.labels)
    n_draw = min(len(table), MAX_THUMBNAILS)
    thumbs = None
    figures, missing = {}, []
    for m in exp.maps.values():
        dom = read_domain(group, m.name)
        if dom is None:
            missing.append(f"{m.name}: no domain map in {exp.store}")
            continue
        units = dom["units"]
        rows, cols = int(dom["rows"]), int(dom["cols"])
        if thumbs is None:
            thumbs = thumbnails(group, n_draw)  # once for every map
        path = out / f"fig9-{m.name}.png"
        kind = "default kernel" if m.kernel == "default" else m.kernel
        sample = "" if n_draw == len(table) else f", first {n_draw} drawn"
        domain_map_figure(units[:n_draw], thumbs, rows, cols, path,
                          title=f"Figure 9: domain map of level {m.level} ({kind}){sample}",
                          labels=labels[:n_draw] if _has_labels(labels) else None)
        figures[m.name] = str(path)
    return {"figures": figures, "missing": missing}


def _main(argv) -> int:
    p = argparse.ArgumentParser(prog="python -m reports.fig9", description=__doc__.splitlines()[0])
    add_common_arguments(p)
    args = p.parse_args(argv)
    res = write(load_experiment(args.tracking_uri, args.experiment), args.out)
    for path in res["figures"].values():
        print(f"wrote {path}")
    for note in res["missing"]:
        print(f"note: {note}")
    return 0


def main(argv: list[str] | None = None) -> int:
    """Write Figure 9 (see the module docstring); exit code 2 with a message when nothing is tracked."""
    return run_main(_main, argv, "python -m reports.fig9")


if __name__ == "__main__":
    sys.exit(main())
