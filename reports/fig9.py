"""Figure 9 of the paper: domain maps with every building's thumbnail at its unit, per triangle map.

`python -m reports.fig9 [--tracking-uri URI] [--experiment paper | --run ID] [--out DIR]` reads, for
every map of the experiment's latest finished pipeline run (or of the run ``ID``), the placement of
each mesh on its domain map (``runs/<run>/domain/units`` in the store, DESIGN.md §5) and the cleaned
meshes, and writes ``DIR/fig9-<run>.png`` and ``.svg``. Every thumbnail is drawn at one common
scale (the caption gives it) with its short mesh id under it; where the corpus has labels (the
synthetic families), each thumbnail is framed in its family's colour. A map without a domain map is
skipped with a note.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from reports.runs import TrackedExperiment, add_common_arguments, load_from_args, run_main

__all__ = ["MAX_THUMBNAILS", "THUMB_SIZE", "figures", "main", "thumbnails", "write"]

#: Meshes drawn on one figure at most (the first ones of the store; a city is drawn by a sample).
MAX_THUMBNAILS = 400
#: Thumbnail side in pixels.
THUMB_SIZE = 96
DPI = 120


def thumbnails(group, n: int, size: int = THUMB_SIZE) -> tuple[list[np.ndarray], float]:
    """Rendered views of the first ``n`` meshes of a store, at one common scale.

    Returns
    -------
    images : list of (size, size, 4) uint8
    span : float
        Mesh units one image spans.
    """
    from meshsom.store import mesh_table, read_mesh
    from meshsom.thumbnails import render_thumbnails

    table = mesh_table(group)
    images, half = render_thumbnails([read_mesh(group, i, table) for i in range(n)], size=size)
    return images, 2.0 * half


def _has_labels(labels: np.ndarray) -> bool:
    return len(labels) > 1 and all(labels) and len(set(labels.tolist())) > 1


def figures(exp: TrackedExperiment) -> tuple[dict, list[str]]:
    """Build the domain-map figure of every map of the run that has a domain map.

    Returns
    -------
    figures : dict of str to matplotlib.figure.Figure
        By run name.
    missing : list of str
        Notes on maps skipped.
    """
    from meshsom.store import mesh_table, read_domain
    from meshsom.thumbnails import draw_domain_map

    group = exp.open_store()
    table = mesh_table(group)
    labels = np.asarray(table.labels)
    ids = np.asarray(table.ids)
    n_draw = min(len(table), MAX_THUMBNAILS)
    thumbs = None
    out, missing = {}, []
    for m in exp.maps.values():
        dom = read_domain(group, m.name)
        if dom is None:
            missing.append(f"{m.name}: no domain map in {exp.store}")
            continue
        units = dom["units"]
        rows, cols = int(dom["rows"]), int(dom["cols"])
        if thumbs is None:
            thumbs, span = thumbnails(group, n_draw)  # once for every map
        kind = "default kernel" if m.kernel == "default" else m.kernel
        sample = "" if n_draw == len(table) else f", first {n_draw} of {len(table)} drawn"
        out[m.name] = draw_domain_map(units[:n_draw], thumbs, rows, cols,
                                      title=f"Figure 9: domain map of level {m.level} ({kind}){sample}",
                                      labels=labels[:n_draw] if _has_labels(labels) else None,
                                      ids=ids[:n_draw], span=span)
    return out, missing


def write(exp: TrackedExperiment, out: Path) -> dict:
    """Write ``fig9-<run>.png`` and ``.svg`` for every map of the run that has a domain map.

    Returns
    -------
    dict
        ``figures``: run name -> PNG path (the SVG beside it); ``files``: every file written;
        ``missing``: notes on maps skipped.
    """
    from meshsom.figures import save_figure

    out.mkdir(parents=True, exist_ok=True)
    figs, missing = figures(exp)
    written, files = {}, []
    for name, fig in figs.items():
        png, svg = save_figure(fig, out / f"fig9-{name}.png", DPI)
        written[name] = png
        files += [png, svg]
    return {"figures": written, "files": files, "missing": missing}


def _main(argv) -> int:
    p = argparse.ArgumentParser(prog="python -m reports.fig9", description=__doc__.splitlines()[0])
    add_common_arguments(p)
    args = p.parse_args(argv)
    res = write(load_from_args(args), args.out)
    for path in res["figures"].values():
        print(f"wrote {path} (and .svg)")
    for note in res["missing"]:
        print(f"note: {note}")
    return 0


def main(argv: list[str] | None = None) -> int:
    """Write Figure 9 (see the module docstring); exit code 2 with a message when nothing is tracked."""
    return run_main(_main, argv, "python -m reports.fig9")


if __name__ == "__main__":
    sys.exit(main())
