"""Figure 10 of the paper: re-translation error of level-3 prototypes, before and after leveling.

`python -m reports.fig10 [--tracking-uri URI] [--experiment paper | --run ID] [--out DIR] [--sample N] [--seed S]`
takes the level-3 map of the experiment's latest finished pipeline run and, for every unit that
training vectors are mapped to (or a seeded sample of ``N`` of them), its *original*: the training
vector, in its winning variation, nearest to the prototype among those mapped to it (DESIGN.md §3;
:func:`meshsom.synthesis.nearest_mapped`). Each prototype is de-standardized, its ``v`` entries
raised to at least ``V_MIN``, and synthesized without leveling (the unfolding from first copies) and
with it (least squares over every entry, :func:`meshsom.synthesis.level_patches`). The patch is
re-encoded and compared, in standardized units:

- with the original: the paper's re-translation QC-error, per fold entry and per ring depth (0: the
  root's folds, 1: the first ring's, ...);
- with the prototype itself.

The reduction is ``100 * (1 - mean(leveled) / mean(unleveled))`` over the prototypes. The paper
reports 30-40 % at level 3, "especially small in close neighborhood to the root triangle".

Writes ``DIR/fig10.png`` and ``.svg``: the per-entry deviation of one sample prototype (the one of median
unleveled error) from its original, before (top) and after (bottom) leveling, as the paper's grid of
``GRID_COLS`` values a row, coloured as a heat-map on one shared scale; the distribution of the error over all measured
prototypes; the mean error per ring depth. ``DIR/fig10-grid.md`` holds the two grids as numbers in
the paper's format. Without level 3, the highest trained level >= 2 is used, with a note.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from meshsom.synthesis import V_MIN
from reports.runs import ReportError, TrackedExperiment, add_common_arguments, load_from_args, run_main

__all__ = ["GRID_COLS", "LEVEL", "SAMPLE", "V_MIN", "change_text", "figure", "format_pct", "main", "measure",
           "reduction_pct", "summary", "write"]

#: Level of the paper's Figure 10.
LEVEL = 3
#: Prototypes measured at most (a seeded sample of the units with an original); None: all of them.
SAMPLE = None
#: Seed of the sample.
SEED = 0
#: Values per row of the grid: the paper prints a level-3 vector (144 entries) as 12 rows of 12.
GRID_COLS = 12
#: Leveling methods compared: before, after.
METHODS = ("none", "lsq")
#: Histogram bins of the distribution panel.
BINS = 40
FIGSIZE = (16.0, 11.0)
DPI = 120
#: Font size of the numbers in the grid cells.
CELL_FONT = 5.5


def choose_level(exp: TrackedExperiment, level: int = LEVEL) -> tuple[int | None, str | None]:
    """The level to measure: ``level`` if trained with BMUofN, else the highest trained level >= 2.

    Returns
    -------
    level : int or None
        None when no level >= 2 was trained.
    note : str or None
        Why another level (or none) is used.
    """
    if exp.find(level) is not None:
        return level, None
    higher = [lv for lv in exp.levels if lv >= 2 and exp.find(lv) is not None]
    if not higher:
        return None, (f"experiment {exp.experiment!r} trained no map of level >= 2 (levels {exp.levels}); "
                      "leveling needs repeated quantities, so Figure 10 is skipped")
    return max(higher), (f"experiment {exp.experiment!r} has no level-{level} map; "
                         f"Figure 10 uses level {max(higher)} instead")


def format_pct(x: float) -> str:
    """A percentage with one decimal; values that round to zero print as ``0.0 %`` (never ``-0.0 %``)."""
    return f"{0.0 if abs(x) < 0.05 else x:.1f} %"


def reduction_pct(raw: np.ndarray, lev: np.ndarray) -> float:
    """``100 * (1 - mean(lev) / mean(raw))``: how much leveling lowers the mean error, in percent."""
    return float(100.0 * (1.0 - np.mean(lev) / np.mean(raw)))


def originals(group, run: str, level: int, sample: int | None = SAMPLE, seed: int = SEED) -> dict:
    """Prototypes of a map and their originals, standardized.

    Parameters
    ----------
    group : zarr.Group
        The store.
    run : str
        Map run name (``level3-bmuofn``); it must hold the BMUs of its training vectors.
    level : int
    sample : int or None
        Units at most (seeded); None: every unit with an original.
    seed : int

    Returns
    -------
    dict
        ``units`` (n,) int64 ascending, ``rows`` (n,) int64 (rows of ``rings/level{L}``), ``Z`` (n, D)
        float64 the standardized originals in their winning variations, ``W`` (n, D) float64 the
        standardized prototypes, ``stats`` (dict), ``n_units`` (map size).
    """
    from meshsom.bmu_numpy import varied
    from meshsom.codebook import load_codebook
    from meshsom.standardize import standardize
    from meshsom.store import read_stats, rings_array
    from meshsom.synthesis import nearest_mapped
    from meshsom.variations import variation_table

    cb = load_codebook(group, run)
    if cb.bmu is None:
        raise ReportError(f"map {run} holds no BMUs of its training vectors; rerun training to keep them")
    job = dict(cb.attrs.get("job", {}))
    stats = read_stats(group, level)
    orig = nearest_mapped(cb.bmu.unit, cb.bmu.dist2, len(cb.weights))
    units = np.flatnonzero(orig >= 0)
    if sample is not None and len(units) > sample:
        units = np.sort(np.random.default_rng(seed).choice(units, sample, replace=False))
    rows = orig[units]
    arr = rings_array(group, level)
    order = np.argsort(rows)
    X = np.empty((len(rows), arr.shape[1]), np.float64)
    X[order] = np.asarray(arr.oindex[rows[order]] if hasattr(arr, "oindex") else arr[:][rows[order]], np.float64)
    index, sign = variation_table(level, mirror=bool(job.get("mirror", False)), kernel=cb.kernel or "bmuofn")
    Z = varied(standardize(X, stats), index, sign, cb.bmu.variation[rows]).astype(np.float64)
    return {"units": units, "rows": rows, "Z": Z, "W": np.asarray(cb.weights[units], np.float64), "stats": stats,
            "n_units": len(cb.weights)}


def measure(Z: np.ndarray, W: np.ndarray, level: int, stats) -> dict:
    """Re-translation errors of prototypes ``W`` against their originals ``Z``, without and with leveling.

    Parameters
    ----------
    Z : (n, D) float
        Standardized originals.
    W : (n, D) float
        Standardized prototypes.
    level : int
    stats : Stats or dict

    Returns
    -------
    dict
        Per method (``none``, ``lsq``): ``entries`` (n, D/3) deviation from the original per fold
        entry, ``original`` (n,) the QC-errors against it, ``prototype`` (n,) those against the
        prototype, ``by_depth`` and ``by_depth_prototype`` (level,) the mean entry deviation per ring
        depth from the original and from the prototype, ``original_circular`` (n,) the QC-errors
        against the original with alpha compared on the circle, ``abs`` (n, D)
        per-value deviation from the original. Also ``depth`` (D/3,) int64, ``reduction_pct``,
        ``reduction_prototype_pct``, ``reduction_circular_pct``, ``reduction_by_depth_pct`` (level,).
    """
    from meshsom.standardize import destandardize, standardize
    from meshsom.synthesis import clip_v, encode_patches, entry_depth, entry_deviation, synthesize

    X = clip_v(destandardize(W, stats))
    depth = entry_depth(level)
    res: dict = {"depth": depth}
    for method in METHODS:
        Y = encode_patches(synthesize(X, level, method, stats), level)
        e, ep = entry_deviation(Z, Y, stats), entry_deviation(W, Y, stats)
        res[method] = {
            "entries": e, "original": e.mean(axis=1), "prototype": ep.mean(axis=1),
            "original_circular": entry_deviation(Z, Y, stats, circular=True).mean(axis=1),
            "by_depth": np.array([e[:, depth == d].mean() for d in range(level)]),
            "by_depth_prototype": np.array([ep[:, depth == d].mean() for d in range(level)]),
            "abs": np.abs(np.asarray(Z, np.float64) - standardize(Y, stats)),
        }
    a, b = res["none"], res["lsq"]
    res["reduction_pct"] = reduction_pct(a["original"], b["original"])
    res["reduction_prototype_pct"] = reduction_pct(a["prototype"], b["prototype"])
    res["reduction_circular_pct"] = reduction_pct(a["original_circular"], b["original_circular"])
    res["reduction_by_depth_pct"] = 100.0 * (1.0 - b["by_depth"] / a["by_depth"])
    return res


def _grid(values: np.ndarray) -> np.ndarray:
    """Per-value deviations as the paper's grid: rows of ``GRID_COLS`` (the last padded with NaN)."""
    n = -(-len(values) // GRID_COLS) * GRID_COLS
    return np.concatenate([values, np.full(n - len(values), np.nan)]).reshape(-1, GRID_COLS)


def _cell(v: float) -> str:
    """A value as the paper prints it: one significant digit, ``9.E-04``."""
    if not np.isfinite(v):
        return ""
    m, e = f"{v:.0E}".split("E")
    return f"{m}.E{e}"


def grid_text(res: dict) -> str:
    """The sample prototype's two grids (before, then after leveling) as a markdown table."""
    lines = []
    for method, what in zip(METHODS, ("before leveling", "after leveling")):
        g = _grid(res["sample_abs"][method])
        lines += [f"**{what}** (mean {np.nanmean(g):.2E})", "",
                  "| " + " | ".join(str(c) for c in range(GRID_COLS)) + " |", "|" + "---|" * GRID_COLS]
        lines += ["| " + " | ".join(_cell(v) for v in row) + " |" for row in g]
        lines.append("")
    return "\n".join(lines)


def change_text(pct: float) -> str:
    """A relative change as words, never a double negative: ``6.3 % lower``, ``6.3 % higher``, ``unchanged``.

    Parameters
    ----------
    pct : float
        Reduction in percent (:func:`reduction_pct`): positive when the second value is lower.
    """
    if abs(pct) < 0.05:
        return "unchanged (0.0 %)"
    return f"{format_pct(abs(pct))} {'lower' if pct > 0 else 'higher'}"


#: Colours of the two methods (before, after leveling), used by every panel.
COLOURS = {"none": "tab:orange", "lsq": "tab:blue"}
WHAT = {"none": "before leveling", "lsq": "after leveling"}


def figure(res: dict, title: str):
    """Build Figure 10 from :func:`write`'s measurements.

    Left: the sample prototype's per-value deviation grids before (top) and after (bottom) leveling,
    on one shared, percentile-clipped colour scale. Right, top: the distribution of the error over
    all prototypes, both methods as outlined histograms with a legend; bottom: the mean error per
    ring depth.

    Returns
    -------
    matplotlib.figure.Figure
    """
    from meshsom.figures import PERCENTILES, clip_note, fit_text, new_figure, robust_limits

    m = res["measure"]
    fig = new_figure(FIGSIZE)
    gs = fig.add_gridspec(2, 2, width_ratios=(1.25, 1.0))
    grids = [_grid(res["sample_abs"][k]) for k in METHODS]
    vmin, vmax = robust_limits(np.concatenate([g.ravel() for g in grids]), (0.0, PERCENTILES[1]))
    vmin = 0.0
    unit = int(res["units"][res["sample"]])
    grid_axes = []
    for i, (g, k) in enumerate(zip(grids, METHODS)):
        ax = fig.add_subplot(gs[i, 0])
        grid_axes.append(ax)
        im = ax.imshow(g, cmap="magma_r", vmin=vmin, vmax=vmax, aspect="auto")
        for (r, c), v in np.ndenumerate(g):
            ax.text(c, r, _cell(v), ha="center", va="center", fontsize=CELL_FONT,
                    color="white" if np.isfinite(v) and v > 0.6 * vmax else "black")
        ax.set_xticks(range(GRID_COLS))
        ax.set_yticks(range(len(g)))
        ax.set_xlabel("entry within the row", fontsize=8)
        ax.set_ylabel(f"row of {GRID_COLS} entries", fontsize=8)
        ax.set_title(f"unit {unit}, {WHAT[k]}: QC-error {m[k]['original'][res['sample']]:.4f}", fontsize=10)
    fig.colorbar(im, ax=grid_axes, extend="max", fraction=0.04,
                 label=fit_text(f"|original - re-encoding| per value (standardized units); one scale for both "
                                f"grids, {clip_note((0.0, PERCENTILES[1]))}", 0.8 * FIGSIZE[1], 9))
    ax = fig.add_subplot(gs[0, 1])
    both = np.concatenate([m[k]["original"] for k in METHODS])
    lo = float(both[both > 0].min()) if (both > 0).any() else 1e-12
    bins = np.geomspace(lo, max(float(both.max()), 2.0 * lo), BINS + 1)
    ax.set_xscale("log")
    for k, style in zip(METHODS, ("-", "--")):
        ax.hist(np.maximum(m[k]["original"], lo), bins=bins, histtype="step", linewidth=1.6, linestyle=style,
                color=COLOURS[k], label=f"{WHAT[k]}: mean {m[k]['original'].mean():.4f}")
    ax.set_xlabel("re-translation QC-error against the original (standardized units)")
    ax.set_ylabel("prototypes")
    ax.set_title(fit_text(f"{len(res['units'])} prototypes: mean error {change_text(m['reduction_pct'])} "
                          "with leveling", 6.0, 10), fontsize=10)
    ax.legend(fontsize=8)
    ax = fig.add_subplot(gs[1, 1])
    d = np.arange(res["level"])
    w = 0.2
    for j, (ref, k) in enumerate((ref, k) for ref in ("original", "prototype") for k in METHODS):
        vals = m[k]["by_depth"] if ref == "original" else m[k]["by_depth_prototype"]
        ax.bar(d + (j - 1.5) * w, vals, width=w, color=COLOURS[k], hatch="" if ref == "original" else "//",
               edgecolor="black", linewidth=0.5, label=f"vs {ref}, {WHAT[k]}")
    ax.set_xticks(d, ["root"] + [f"ring {i}" for i in range(1, res["level"])])
    ax.set_xlabel("ring depth of the face a fold belongs to")
    ax.set_ylabel("mean deviation per fold entry\n(standardized units)")
    ax.set_title("error by ring depth", fontsize=10)
    ax.legend(fontsize=8)
    fig.suptitle(fit_text(title, FIGSIZE[0] - 0.5, 12), fontsize=12)
    return fig


def write(exp: TrackedExperiment, out: Path, sample: int | None = SAMPLE, seed: int = SEED) -> dict:
    """Measure and plot; writes ``out/fig10.png``, ``.svg`` and ``out/fig10-grid.md`` unless no level >= 2 was trained.

    Returns
    -------
    dict
        ``level`` (None when skipped), ``note``, ``run``, ``units`` (n,) the units measured,
        ``n_units``, ``measure`` (:func:`measure`'s result), ``sample``
        (index into ``units`` of the prototype drawn as a grid), ``sample_abs`` (per method, (D,)
        its per-value deviations), ``figure``, ``svg`` and ``grid`` (paths or None), ``files``.
    """
    level, note = choose_level(exp)
    res = {"level": level, "note": note, "figure": None, "svg": None, "grid": None, "files": []}
    if level is None:
        return res
    run = exp.find(level).name
    o = originals(exp.open_store(), run, level, sample, seed)
    if not len(o["units"]):
        raise ReportError(f"experiment {exp.experiment!r}: map {run} has no unit with a mapped vector")
    m = measure(o["Z"], o["W"], level, o["stats"])
    res.update(run=run, units=o["units"], n_units=o["n_units"], measure=m)
    rep = int(np.argsort(m["none"]["original"], kind="stable")[len(o["units"]) // 2])  # median unleveled error
    res["sample"] = rep
    res["sample_abs"] = {k: m[k]["abs"][rep] for k in METHODS}
    from meshsom.figures import save_figure

    out.mkdir(parents=True, exist_ok=True)
    fig = figure(res, f"Figure 10: level-{level} re-translation before and after leveling "
                      f"(experiment {exp.experiment}, {run})")
    res["figure"], res["svg"] = save_figure(fig, out / "fig10.png", DPI)
    (out / "fig10-grid.md").write_text(f"# Figure 10: unit {int(o['units'][rep])} of {run}\n\n" + grid_text(res))
    res["grid"] = str(out / "fig10-grid.md")
    res["files"] = [res["figure"], res["svg"], res["grid"]]
    return res


def summary(res: dict) -> str:
    """One paragraph with the numbers."""
    if res["level"] is None:
        return f"Figure 10 skipped: {res['note']}"
    m = res["measure"]
    a, b = m["none"], m["lsq"]
    depth = ", ".join(f"{'root' if d == 0 else f'ring {d}'} {x:.4f} -> {y:.4f} ({change_text(p)})"
                      for d, (x, y, p) in enumerate(zip(a["by_depth"], b["by_depth"], m["reduction_by_depth_pct"])))
    text = (f"level {res['level']} ({res['run']}), {len(res['units'])} prototypes with an original (of "
            f"{res['n_units']} units): re-translation QC-error against the original {a['original'].mean():.5f} "
            f"without leveling, {b['original'].mean():.5f} with least-squares leveling: "
            f"{change_text(m['reduction_pct'])}. By ring depth: {depth}. Against the prototype itself: "
            f"{a['prototype'].mean():.5f} -> {b['prototype'].mean():.5f} ({change_text(m['reduction_prototype_pct'])}). "
            f"Against the original, alpha on the circle: {a['original_circular'].mean():.5f} -> "
            f"{b['original_circular'].mean():.5f} ({change_text(m['reduction_circular_pct'])}). "
            f"Grid of unit {int(res['units'][res['sample']])} (median unleveled error): "
            f"{res['measure']['none']['original'][res['sample']]:.4f} -> {res['measure']['lsq']['original'][res['sample']]:.4f}.")
    return text + (f" Note: {res['note']}" if res["note"] else "")


def _main(argv) -> int:
    p = argparse.ArgumentParser(prog="python -m reports.fig10", description=__doc__.splitlines()[0])
    add_common_arguments(p)
    p.add_argument("--sample", type=int, default=SAMPLE, help="prototypes measured at most (default: every unit with an original)")
    p.add_argument("--seed", type=int, default=SEED, help=f"seed of the sample (default {SEED})")
    args = p.parse_args(argv)
    if args.sample is not None and args.sample < 1:
        p.error(f"--sample must be >= 1, received {args.sample}")
    res = write(load_from_args(args), args.out, args.sample, args.seed)
    print(summary(res))
    if res["figure"]:
        print(f"wrote {res['figure']}, {res['svg']} and {res['grid']}")
    return 0


def main(argv: list[str] | None = None) -> int:
    """Write Figure 10 and print the reduction (see the module docstring); exit code 2 when nothing is tracked."""
    return run_main(_main, argv, "python -m reports.fig10")


if __name__ == "__main__":
    sys.exit(main())
