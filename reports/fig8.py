"""Figure 8 of the paper: U-matrices of the triangle maps (level 1 default kernel, level 1 BMUofN, 2, 3).

`python -m reports.fig8 [--tracking-uri URI] [--experiment paper] [--out DIR]` reads the codebooks of
the experiment's latest finished pipeline run from its store and writes ``DIR/fig8.png`` (a 2 x 2
panel) and ``DIR/fig8-<run>.png`` (one U-matrix each, :func:`meshsom.umatrix.render_map`). On a
toroidal map each panel shows the map with half a map of wrap on every side, faint, so clusters that
cross the edge are seen whole. A panel whose map was not trained says so.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from reports.runs import TrackedExperiment, add_common_arguments, load_experiment, run_main

__all__ = ["PANELS", "main", "write"]

#: The four panels of Figure 8: (level, kernel, title).
PANELS = (
    (1, "default", "level 1* (default kernel)"),
    (1, "bmuofn", "level 1 (BMUofN)"),
    (2, "bmuofn", "level 2 (BMUofN)"),
    (3, "bmuofn", "level 3 (BMUofN)"),
)
#: Opacity of the wrapped copies on a toroidal panel.
FAINT_ALPHA = 0.35
#: Colour map of the U-matrices.
CMAP = "viridis"
#: Size of the 2 x 2 panel figure in inches, and its resolution.
FIGSIZE = (12.0, 10.0)
DPI = 120


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def write(exp: TrackedExperiment, out: Path) -> dict:
    """Write ``fig8.png`` and ``fig8-<run>.png`` into ``out``.

    Returns
    -------
    dict
        ``figure``: the panel's path; ``singles``: run name -> path; ``missing``: notes on panels
        whose map was not trained.
    """
    from meshsom.codebook import load_codebook
    from meshsom.metrics import u_matrix
    from meshsom.umatrix import draw_u_matrix, render_map

    plt = _pyplot()
    out.mkdir(parents=True, exist_ok=True)
    group = exp.open_store()
    fig, axes = plt.subplots(2, 2, figsize=FIGSIZE)
    singles, missing = {}, []
    for ax, (level, kernel, title) in zip(axes.ravel(), PANELS):
        m = exp.find(level, kernel)
        if m is None:
            missing.append(f"{title}: not trained in run {exp.run_id} of experiment {exp.experiment!r}")
            ax.text(0.5, 0.5, f"{title}\nnot trained in this run", ha="center", va="center", transform=ax.transAxes)
            ax.set_axis_off()
            continue
        cb = load_codebook(group, m.name)
        dims = m.params.get("dims", "")
        image = draw_u_matrix(ax, u_matrix(cb.weights, cb.rows, cb.cols, cb.topology), cb.topology, CMAP,
                              FAINT_ALPHA, frame_width=1.0)
        ax.set_title(f"{title}, {dims}\n{cb.rows} x {cb.cols} {cb.topology}", fontsize=10)
        ax.set_xticks([])
        ax.set_yticks([])
        fig.colorbar(image, ax=ax, shrink=0.8)
        single = out / f"fig8-{m.name}.png"
        render_map(cb.weights, cb.rows, cb.cols, single, topology=cb.topology,
                   title=f"U-matrix, {title}, {dims}")
        singles[m.name] = str(single)
    fig.suptitle(f"Figure 8: U-matrices of the triangle maps (experiment {exp.experiment})")
    fig.tight_layout()
    path = out / "fig8.png"
    fig.savefig(path, dpi=DPI)
    plt.close(fig)
    return {"figure": str(path), "singles": singles, "missing": missing}


def _main(argv) -> int:
    p = argparse.ArgumentParser(prog="python -m reports.fig8", description=__doc__.splitlines()[0])
    add_common_arguments(p)
    args = p.parse_args(argv)
    res = write(load_experiment(args.tracking_uri, args.experiment), args.out)
    print(f"wrote {res['figure']} and {len(res['singles'])} single U-matrices")
    for note in res["missing"]:
        print(f"note: {note}")
    return 0


def main(argv: list[str] | None = None) -> int:
    """Write Figure 8 (see the module docstring); exit code 2 with a message when nothing is tracked."""
    return run_main(_main, argv, "python -m reports.fig8")


if __name__ == "__main__":
    sys.exit(main())
