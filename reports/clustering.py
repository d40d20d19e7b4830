"""Clustering quality of the domain maps on a labelled corpus, against Osada's D2 baseline.

`python -m reports.clustering [--tracking-uri URI] [--experiment synthetic] [--out DIR]` reads, for
every triangle map of the experiment's latest finished pipeline run, how well its domain map groups
the corpus's labels (the synthetic families), as the pipeline measured it (MLflow metrics of the
map's run): the k-NN label agreement (share of each mesh's k nearest meshes on the domain map that
share its family) with its chance level, and the adjusted Rand index of map regions (k-means on the
domain prototypes, one region per family) against the families.

The baseline is a classic global shape descriptor: Osada et al.'s D2 shape distribution of every
mesh in the store (:func:`meshsom.descriptors.d2_histograms`), fed to the same domain SOM (same
size, epochs and seed, from the run's config) and scored by the same two measures. Writes
``DIR/clustering.md``.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from meshsom.domain import KNN
from reports.runs import ReportError, TrackedExperiment, add_common_arguments, load_experiment, run_main

__all__ = ["DEFAULT_EXPERIMENT", "d2_baseline", "format_markdown", "main", "rows", "write"]

#: The labelled synthetic corpus (configs/synthetic.yaml).
DEFAULT_EXPERIMENT = "synthetic"
#: Metric names the pipeline logs for a labelled corpus.
KNN_METRIC, CHANCE_METRIC, ARI_METRIC = "knn_label_agreement", "knn_label_chance", "ari_regions_vs_labels"


def labels_of(group, exp: TrackedExperiment) -> np.ndarray:
    """The store's mesh labels; ReportError when the corpus is not labelled (two families at least)."""
    from meshsom.store import mesh_table

    labels = np.asarray(mesh_table(group).labels)
    if len(labels) < 2 or not all(labels) or len(set(labels.tolist())) < 2:
        raise ReportError(f"experiment {exp.experiment!r} at {exp.uri}: store {exp.store} has no labels on every mesh "
                          f"with at least two families ({len(set(labels.tolist()))} distinct of {len(labels)} meshes); "
                          "clustering quality needs a labelled corpus such as configs/synthetic.yaml")
    return labels


def d2_baseline(group, exp: TrackedExperiment, labels: np.ndarray) -> dict:
    """D2 of every mesh, the same domain SOM, the same two measures.

    Returns
    -------
    dict
        ``knn_label_agreement``, ``knn_label_chance``, ``ari_regions_vs_labels``, ``units`` (n,) int64.
    """
    from sklearn.metrics import adjusted_rand_score

    from meshsom.descriptors import d2_histograms
    from meshsom.domain import (
        knn_label_agreement, label_agreement_chance, map_regions, place, train_domain_map,
    )
    from meshsom.store import iter_meshes

    rows, cols = exp.param("domain.rows", int), exp.param("domain.cols", int)
    epochs, seed = exp.param("domain.epochs", int), exp.param("domain.seed", int)
    vectors = d2_histograms([(v, f) for _, v, f in iter_meshes(group)], seed=seed).astype(np.float32)
    som = train_domain_map(vectors, rows, cols, epochs, seed)
    units = place(vectors, som)
    regions = map_regions(som.weights_, rows, cols, len(set(labels.tolist())), seed)
    return {
        KNN_METRIC: knn_label_agreement(units, labels, rows, cols, k=min(KNN, len(labels) - 1)),
        CHANCE_METRIC: label_agreement_chance(labels),
        ARI_METRIC: adjusted_rand_score(regions[units], labels),
        "units": units,
    }


def _domain_metrics(group, exp: TrackedExperiment, m) -> dict:
    """A map's clustering metrics: MLflow's, else those stored with its domain map."""
    if KNN_METRIC in m.metrics:
        return m.metrics
    from meshsom.store import read_domain

    return dict((read_domain(group, m.name) or {}).get("metrics", {}))


def rows(exp: TrackedExperiment, group, labels: np.ndarray) -> list[dict]:
    """One row per triangle map with clustering metrics, then the D2 baseline.

    Returns
    -------
    list of dict
        Keys ``name`` (``level 1* (default)``, ``level 2 (bmuofn)``, ``D2 baseline``), ``run`` (or
        None for the baseline), ``level``, ``kernel``, and the three metrics (None where absent).
    """
    out = []
    for m in exp.maps.values():
        met = _domain_metrics(group, exp, m)
        star = "*" if m.kernel == "default" else ""
        out.append({"name": f"level {m.level}{star} ({m.kernel})", "run": m.name, "level": m.level, "kernel": m.kernel,
                    **{k: met.get(k) for k in (KNN_METRIC, CHANCE_METRIC, ARI_METRIC)}})
    base = d2_baseline(group, exp, labels)
    out.append({"name": "D2 baseline (Osada et al. 2002)", "run": None, "level": None, "kernel": None,
                **{k: base[k] for k in (KNN_METRIC, CHANCE_METRIC, ARI_METRIC)}})
    return out


def _fmt(x) -> str:
    return "—" if x is None else f"{x:.3f}"


def format_markdown(table: list[dict], exp: TrackedExperiment, labels: np.ndarray) -> str:
    """The clustering table as Markdown, with how it was measured."""
    fams, counts = np.unique(labels, return_counts=True)
    lines = [
        "| domain vectors from | k-NN label agreement | chance | ARI regions vs families |",
        "|---|---:|---:|---:|",
    ]
    for r in table:
        lines.append(f"| {r['name']} | {_fmt(r[KNN_METRIC])} | {_fmt(r[CHANCE_METRIC])} | {_fmt(r[ARI_METRIC])} |")
    rows_, cols = exp.param("domain.rows"), exp.param("domain.cols")
    lines += [
        "",
        f"Corpus: {len(labels)} meshes of {len(fams)} families ("
        + ", ".join(f"{f} {c}" for f, c in zip(fams, counts)) + f"); store `{exp.store}`.",
        f"Domain maps: {rows_} x {cols} torus, k = {min(KNN, len(labels) - 1)} nearest meshes on the map "
        f"(toroidal grid distance); regions: k-means on the domain prototypes, one region per family. "
        f"MLflow experiment `{exp.experiment}` at `{exp.uri}`, pipeline run `{exp.run_id}`. The D2 baseline "
        "is Osada's D2 shape distribution of every mesh (scale-normalised pair distances, 64 bins) on the same "
        "domain SOM (size, epochs, seed).",
    ]
    return "\n".join(lines) + "\n"


def write(exp: TrackedExperiment, out: Path) -> tuple[str, list[dict]]:
    """Write ``out/clustering.md``; returns its text and rows."""
    group = exp.open_store()
    labels = labels_of(group, exp)
    table = rows(exp, group, labels)
    text = format_markdown(table, exp, labels)
    out.mkdir(parents=True, exist_ok=True)
    (out / "clustering.md").write_text(text)
    return text, table


def _main(argv) -> int:
    p = argparse.ArgumentParser(prog="python -m reports.clustering", description=__doc__.splitlines()[0])
    add_common_arguments(p, experiment=DEFAULT_EXPERIMENT)
    args = p.parse_args(argv)
    text, _ = write(load_experiment(args.tracking_uri, args.experiment), args.out)
    print(text, end="")
    return 0


def main(argv: list[str] | None = None) -> int:
    """Write ``clustering.md`` (see the module docstring); exit code 2 when nothing is tracked or labelled."""
    return run_main(_main, argv, "python -m reports.clustering")


if __name__ == "__main__":
    sys.exit(main())
