"""Figure 10 of the paper: re-translation error of level-3 prototypes, before and after leveling.

`python -m reports.fig10 [--tracking-uri URI] [--experiment paper] [--out DIR] [--sample N] [--seed S]`
takes the level-3 map prototypes of the experiment's latest finished pipeline run (a seeded sample
of ``N`` units, or all of a smaller map), de-standardizes them with the level's statistics, clips
the ``v`` entries to at least ``V_MIN`` (an apex must lie off its edge), synthesizes each into a
triangle patch with and without leveling (:mod:`meshsom.synthesis`) and measures the
re-translation QC-error (standardized units) between the vector and the re-encoding of its patch.

The reduction is ``100 * (1 - mean(leveled) / mean(raw))`` over the sample. The paper reports
30-40 % at level 3 (DESIGN.md §3). A second measurement perturbs every entry of the same
prototypes independently (seeded Gaussian noise of ``NOISE_SIGMA`` standardized units), so that
the copies of each quantity disagree, which is the situation leveling is made for.

Writes ``DIR/fig10.png`` (per-component deviation of a representative prototype, the one of median
raw error, before and after leveling, and the distributions over the sample, for both
measurements). Without level 3, the highest trained level >= 2 is used, with a note.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from reports.runs import ReportError, TrackedExperiment, add_common_arguments, load_experiment, run_main

__all__ = ["COPY_TOL", "NOISE_SIGMA", "copy_disagreement", "format_pct", "reduction_pct", "SAMPLE", "V_MIN", "main", "prototypes", "retranslation_errors", "write"]

#: Level of the paper's Figure 10.
LEVEL = 3
#: Prototypes measured at most (a seeded sample of the map's units).
SAMPLE = 300
#: Seed of the sample and of the noise.
SEED = 0
#: Smallest ``v`` (apex distance from its edge, in edge lengths) of a de-standardized prototype.
V_MIN = 1e-3
#: Standard deviation of the independent perturbation, in standardized units.
NOISE_SIGMA = 0.1
#: Values per fold (alpha, u, v).
FOLD = 3
#: Largest difference (raw units) between copies of the same quantity for a vector to count as level.
COPY_TOL = 1e-3
#: Histogram bins of the distribution panels.
BINS = 30
FIGSIZE = (13.0, 9.0)
DPI = 120


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


def prototypes(group, run: str, level: int, sample: int = SAMPLE, seed: int = SEED) -> tuple[np.ndarray, np.ndarray, dict]:
    """De-standardized prototypes of a map, a seeded sample of them, ``v`` clipped to ``V_MIN``.

    Parameters
    ----------
    group : zarr.Group
        The store.
    run : str
        Map run name (``level3-bmuofn``).
    level : int
    sample : int
        Units at most; a map with fewer units is taken whole.
    seed : int

    Returns
    -------
    units : (n,) int64
        The units measured, ascending.
    X : (n, D) float64
        Their raw prototypes.
    stats : dict
        The level's standardization statistics.
    """
    from meshsom.codebook import load_codebook
    from meshsom.standardize import destandardize
    from meshsom.store import read_stats

    cb = load_codebook(group, run)
    stats = read_stats(group, level)
    m = len(cb.weights)
    units = np.arange(m) if m <= sample else np.sort(np.random.default_rng(seed).choice(m, sample, replace=False))
    X = destandardize(cb.weights[units], stats)
    v = X[:, 2::FOLD]
    X[:, 2::FOLD] = np.maximum(v, V_MIN)
    return units.astype(np.int64), X, stats


def perturb(X: np.ndarray, stats: dict, sigma: float = NOISE_SIGMA, seed: int = SEED) -> np.ndarray:
    """Raw vectors with independent Gaussian noise of ``sigma`` standardized units on every entry.

    Returns
    -------
    (n, D) float64
        ``v`` clipped to ``V_MIN``.
    """
    from meshsom.standardize import destandardize, standardize

    z = standardize(np.asarray(X, np.float64), stats)
    Y = destandardize(z + np.random.default_rng(seed).normal(0.0, sigma, z.shape), stats)
    Y[:, 2::FOLD] = np.maximum(Y[:, 2::FOLD], V_MIN)
    return Y


def retranslation_errors(X: np.ndarray, level: int, stats: dict) -> tuple[np.ndarray, np.ndarray]:
    """Re-translation QC-error (standardized units) of every vector, without and with leveling.

    Returns
    -------
    raw, leveled : (n,) float64
    """
    from meshsom.synthesis import retranslation_error

    raw = np.array([retranslation_error(x, level, False, stats) for x in X])
    lev = np.array([retranslation_error(x, level, True, stats) for x in X])
    return raw, lev


def component_deviation(x: np.ndarray, level: int, leveling: bool, stats: dict) -> np.ndarray:
    """Per fold entry, the distance (standardized units) between a vector and its re-translation.

    Returns
    -------
    (D / 3,) float64
        In walk order: the root's one-ring first.
    """
    from meshsom.standardize import standardize
    from meshsom.synthesis import decode, reencode

    y = reencode(decode(x, level, leveling))
    d = standardize(np.asarray(x, np.float64), stats) - standardize(y, stats)
    return np.linalg.norm(d.reshape(-1, FOLD), axis=1)


def format_pct(x: float) -> str:
    """A percentage with one decimal; values that round to zero print as ``0.0 %`` (never ``-0.0 %``)."""
    return f"{0.0 if abs(x) < 0.05 else x:.1f} %"


def reduction_pct(raw: np.ndarray, lev: np.ndarray) -> float:
    """``100 * (1 - mean(lev) / mean(raw))``: how much leveling lowers the mean error, in percent."""
    return float(100.0 * (1.0 - np.mean(lev) / np.mean(raw)))


def copy_disagreement(X: np.ndarray, level: int) -> np.ndarray:
    """Per vector, the largest change leveling makes: max |level_vector(x) - x| (raw units).

    Returns
    -------
    (n,) float64
        0 (up to rounding) where every copy of every quantity already agrees.
    """
    from meshsom.synthesis import level_vector

    return np.array([np.abs(level_vector(x, level) - x).max() for x in X])


def _measure(X, level, stats) -> dict:
    raw, lev = retranslation_errors(X, level, stats)
    disagree = copy_disagreement(X, level)
    rep = int(np.argsort(raw)[len(raw) // 2])  # the prototype of median raw error
    return {
        "raw": raw, "leveled": lev, "raw_mean": float(raw.mean()), "leveled_mean": float(lev.mean()),
        "reduction_pct": reduction_pct(raw, lev), "representative": rep,
        "disagreeing": int((disagree > COPY_TOL).sum()),
        "deviation_raw": component_deviation(X[rep], level, False, stats),
        "deviation_leveled": component_deviation(X[rep], level, True, stats),
    }


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _plot(res: dict, path: Path, title: str) -> None:
    plt = _pyplot()
    fig, axes = plt.subplots(2, 2, figsize=FIGSIZE)
    for col, (key, what) in enumerate((("prototypes", "trained prototypes"),
                                       ("perturbed", f"prototypes + noise (sigma {res['noise_sigma']:g})"))):
        r = res[key]
        unit = res["units"][r["representative"]]
        ax = axes[0, col]
        idx = np.arange(len(r["deviation_raw"]))
        ax.bar(idx - 0.2, r["deviation_raw"], width=0.4, label=f"before leveling (QC {r['deviation_raw'].mean():.4f})")
        ax.bar(idx + 0.2, r["deviation_leveled"], width=0.4,
               label=f"after leveling (QC {r['deviation_leveled'].mean():.4f})")
        ax.set_xlabel("fold entry of the ring vector (walk order: root's one-ring first)")
        ax.set_ylabel("deviation (standardized)")
        ax.set_title(f"{what}: unit {unit} (median raw error)", fontsize=10)
        ax.legend(fontsize=8)
        ax = axes[1, col]
        hi = float(max(r["raw"].max(), r["leveled"].max()))
        bins = np.linspace(0.0, hi if hi > 0 else 1.0, BINS + 1)
        ax.hist(r["raw"], bins=bins, alpha=0.6, label=f"before: mean {r['raw_mean']:.4f}")
        ax.hist(r["leveled"], bins=bins, alpha=0.6, label=f"after: mean {r['leveled_mean']:.4f}")
        ax.set_xlabel("re-translation QC-error (standardized)")
        ax.set_ylabel("prototypes")
        ax.set_title(f"{what}, {len(r['raw'])} prototypes: {format_pct(r['reduction_pct'])} lower with leveling", fontsize=10)
        ax.legend(fontsize=8)
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=DPI)
    plt.close(fig)


def write(exp: TrackedExperiment, out: Path, sample: int = SAMPLE, seed: int = SEED,
          noise_sigma: float = NOISE_SIGMA) -> dict:
    """Measure and plot; writes ``out/fig10.png`` unless no level >= 2 was trained.

    Returns
    -------
    dict
        ``level`` (None when skipped), ``note``, ``run``, ``units`` (n,) the units measured,
        ``prototypes`` and ``perturbed`` (each: ``raw``, ``leveled`` (n,) errors, their means,
        ``reduction_pct``, ``representative``), ``noise_sigma``, ``figure`` (path or None).
    """
    level, note = choose_level(exp)
    res = {"level": level, "note": note, "figure": None, "noise_sigma": noise_sigma}
    if level is None:
        return res
    run = exp.find(level).name
    group = exp.open_store()
    units, X, stats = prototypes(group, run, level, sample, seed)
    if not len(units):
        raise ReportError(f"experiment {exp.experiment!r}: map {run} has no prototypes")
    res.update(run=run, units=units, prototypes=_measure(X, level, stats),
               perturbed=_measure(perturb(X, stats, noise_sigma, seed), level, stats))
    out.mkdir(parents=True, exist_ok=True)
    path = out / "fig10.png"
    _plot(res, path, f"Figure 10: level-{level} re-translation before and after leveling "
                     f"(experiment {exp.experiment}, {run})")
    res["figure"] = str(path)
    return res


def summary(res: dict) -> str:
    """One paragraph with the numbers."""
    if res["level"] is None:
        return f"Figure 10 skipped: {res['note']}"
    p, q = res["prototypes"], res["perturbed"]
    text = (f"level {res['level']} ({res['run']}), {len(res['units'])} prototypes: mean re-translation QC-error "
            f"{p['raw_mean']:.5f} before leveling, {p['leveled_mean']:.5f} after: {format_pct(p['reduction_pct'])} lower; "
            f"{p['disagreeing']} of them have copies that disagree by more than {COPY_TOL:g} (the rest are level "
            "already). "
            f"With independent noise (sigma {res['noise_sigma']:g} standardized): {q['raw_mean']:.5f} -> "
            f"{q['leveled_mean']:.5f}, {format_pct(q['reduction_pct'])} lower.")
    return text + (f" Note: {res['note']}" if res["note"] else "")


def _main(argv) -> int:
    p = argparse.ArgumentParser(prog="python -m reports.fig10", description=__doc__.splitlines()[0])
    add_common_arguments(p)
    p.add_argument("--sample", type=int, default=SAMPLE, help=f"prototypes measured at most (default {SAMPLE})")
    p.add_argument("--seed", type=int, default=SEED, help=f"seed of the sample and the noise (default {SEED})")
    p.add_argument("--noise-sigma", type=float, default=NOISE_SIGMA,
                   help=f"noise of the second measurement, standardized units (default {NOISE_SIGMA})")
    args = p.parse_args(argv)
    if args.sample < 1 or not args.noise_sigma >= 0:
        p.error(f"--sample must be >= 1 and --noise-sigma >= 0, received {args.sample} and {args.noise_sigma}")
    res = write(load_experiment(args.tracking_uri, args.experiment), args.out, args.sample, args.seed, args.noise_sigma)
    print(summary(res))
    if res["figure"]:
        print(f"wrote {res['figure']}")
    return 0


def main(argv: list[str] | None = None) -> int:
    """Write Figure 10 and print the reduction (see the module docstring); exit code 2 when nothing is tracked."""
    return run_main(_main, argv, "python -m reports.fig10")


if __name__ == "__main__":
    sys.exit(main())
