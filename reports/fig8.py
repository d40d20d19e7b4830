"""Figure 8 of the paper: U-matrices of the triangle maps (level 1 default kernel, level 1 BMUofN, 2, 3).

`python -m reports.fig8 [--tracking-uri URI] [--experiment paper | --run ID] [--out DIR]` reads the
codebooks of the experiment's latest finished pipeline run (or of the run ``ID``) from its store and
writes ``DIR/fig8.png`` (a 2 x 2 panel) and ``DIR/fig8-<run>.png`` (one U-matrix each,
:func:`meshsom.umatrix.render_map`), each also as ``.svg``.

The panels are compared, so they share one colour scale: the U-matrix divided by the square root of
the vector's dimension (the mean distance to the neighbours per vector entry, standardized units,
comparable across levels), its colours spanning the 1st-99th percentile of all four panels. On a
toroidal map each panel shows a thin faint band of the wrapped continuation around the map (dashed
frame). A panel whose map was not trained says so.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from reports.runs import TrackedExperiment, add_common_arguments, load_from_args, run_main

__all__ = ["PANELS", "figure", "main", "write"]

#: The four panels of Figure 8: (level, kernel, title).
PANELS = (
    (1, "default", "level 1* (default kernel)"),
    (1, "bmuofn", "level 1 (BMUofN)"),
    (2, "bmuofn", "level 2 (BMUofN)"),
    (3, "bmuofn", "level 3 (BMUofN)"),
)
#: Colour map of the U-matrices.
CMAP = "viridis"
#: Size of the 2 x 2 panel figure in inches, and its resolution.
FIGSIZE = (11.0, 9.5)
DPI = 120
#: Label of the shared colour bar.
SCALE_LABEL = "U-matrix / sqrt(dims): mean distance to neighbours per vector entry (standardized units)"


def figure(exp: TrackedExperiment) -> tuple:
    """Build the 2 x 2 panel of Figure 8.

    Returns
    -------
    fig : matplotlib.figure.Figure
    codebooks : dict of str to Codebook
        The maps drawn, by run name (for the single U-matrices).
    missing : list of str
        Notes on panels whose map was not trained.
    """
    from meshsom.codebook import load_codebook
    from meshsom.figures import PERCENTILES, clip_note, fit_text, new_figure, robust_limits
    from meshsom.metrics import u_matrix
    from meshsom.umatrix import draw_u_matrix, wrap_cells

    group = exp.open_store()
    drawn, missing = [], []
    for level, kernel, title in PANELS:
        m = exp.find(level, kernel)
        if m is None:
            missing.append(f"{title}: not trained in run {exp.run_id} of experiment {exp.experiment!r}")
            drawn.append((title, None, None, None))
            continue
        cb = load_codebook(group, m.name)
        umat = u_matrix(cb.weights, cb.rows, cb.cols, cb.topology) / np.sqrt(cb.weights.shape[1])
        drawn.append((title, m, cb, umat))
    values = [d[3] for d in drawn if d[3] is not None]
    vmin, vmax = robust_limits(np.concatenate([u.ravel() for u in values]) if values else [])
    fig = new_figure(FIGSIZE)
    axes = fig.subplots(2, 2)
    image, shape = None, None
    for ax, (title, m, cb, umat) in zip(axes.ravel(), drawn):
        if m is None:
            ax.text(0.5, 0.5, f"{title}\nnot trained in this run", ha="center", va="center", transform=ax.transAxes)
            ax.set_axis_off()
            continue
        image = draw_u_matrix(ax, umat, cb.topology, CMAP, vmin=vmin, vmax=vmax, frame_width=1.0)
        shape = (cb.rows, cb.cols, cb.topology)
        ax.set_title(f"{title}, {m.params.get('dims', '')}", fontsize=10)
        ax.set_xticks([])
        ax.set_yticks([])
    if image is not None:
        fig.colorbar(image, ax=axes, extend="both", shrink=0.85, aspect=30,
                     label=fit_text(f"{SCALE_LABEL}; one scale for all panels, {clip_note(PERCENTILES)}",
                                    0.8 * FIGSIZE[1], 9))
    sub = ""
    if shape is not None:
        rows, cols, topology = shape
        w = wrap_cells(rows, cols)
        sub = (f"\n{rows} x {cols} torus; faint band and dashed frame: {w} wrapped cell{'s' if w > 1 else ''} "
               "per side" if topology == "toroidal" else f"\n{rows} x {cols} planar")
    fig.suptitle(fit_text(f"Figure 8: U-matrices of the triangle maps (experiment {exp.experiment}){sub}",
                          FIGSIZE[0] - 0.5, 12), fontsize=12)
    return fig, {d[1].name: d[2] for d in drawn if d[1] is not None}, missing


def write(exp: TrackedExperiment, out: Path) -> dict:
    """Write ``fig8.png`` and ``fig8-<run>.png`` into ``out``, each with its ``.svg``.

    Returns
    -------
    dict
        ``figure``: the panel's PNG; ``svg``: its SVG; ``singles``: run name -> PNG path (SVG beside
        it); ``files``: every file written; ``missing``: notes on panels whose map was not trained.
    """
    from meshsom.figures import save_figure
    from meshsom.umatrix import render_map

    out.mkdir(parents=True, exist_ok=True)
    fig, codebooks, missing = figure(exp)
    png, svg = save_figure(fig, out / "fig8.png", DPI)
    files, singles = [png, svg], {}
    titles = {exp.find(level, kernel).name: title for level, kernel, title in PANELS if exp.find(level, kernel)}
    for name, cb in codebooks.items():
        single = render_map(cb.weights, cb.rows, cb.cols, out / f"fig8-{name}.png", topology=cb.topology,
                            title=f"U-matrix, {titles[name]}, {exp.maps[name].params.get('dims', '')}")
        singles[name] = single
        files += [single, str(Path(single).with_suffix(".svg"))]
    return {"figure": png, "svg": svg, "singles": singles, "missing": missing, "files": files}


def _main(argv) -> int:
    p = argparse.ArgumentParser(prog="python -m reports.fig8", description=__doc__.splitlines()[0])
    add_common_arguments(p)
    args = p.parse_args(argv)
    res = write(load_from_args(args), args.out)
    print(f"wrote {res['figure']} (and .svg) and {len(res['singles'])} single U-matrices")
    for note in res["missing"]:
        print(f"note: {note}")
    return 0


def main(argv: list[str] | None = None) -> int:
    """Write Figure 8 (see the module docstring); exit code 2 with a message when nothing is tracked."""
    return run_main(_main, argv, "python -m reports.fig8")


if __name__ == "__main__":
    sys.exit(main())
