"""Domain maps of a pipeline run (DESIGN.md §5): one per trained triangle map.

For every triangle map of the run: per-mesh BMU histograms (from the map's saved BMUs), smoothed
on the torus into domain vectors, a small domain SOM placing every mesh, the figure with every
building's thumbnail at its unit (the paper's Figure 9), and, where the corpus has labels, how
well the map groups them (k-nearest-neighbour label agreement, adjusted Rand index of map regions).
Results go to ``runs/<run>/domain/`` and to the map's MLflow child run.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

#: Meshes drawn on a domain-map figure at most (a city-sized corpus is drawn by a sample).
MAX_THUMBNAILS = 400
#: Above this many bytes of domain vectors (meshes x triangle-map units x 4) the stage writes them
#: to the store on the workers and trains the domain map on their sparse form on the client.
IN_MEMORY_BYTES = 256 << 20
#: Meshes per task (and per zarr chunk) of streamed domain vectors.
MESHES_PER_TASK = 256
#: Meshes in the seeded sample the label measures use on a streamed (city-sized) corpus (they are O(n^2)).
LABEL_SAMPLE = 2000


def domain_chunk(store: str, run: str, m0: int, m1: int, f0: int, f1: int, sigma: float) -> int:
    """Worker task: domain vectors of meshes ``m0..m1`` (faces ``f0..f1``) into ``runs/<run>/domain/vectors``."""
    from meshsom.domain import bmu_histograms, domain_vectors
    from meshsom.store import domain_vectors_array, map_shape, open_store, run_group

    group = open_store(store, mode="r+")
    g = run_group(group, run, create=False)
    rows, cols, topology = map_shape(g)
    face_mesh = np.asarray(group["face_mesh"][f0:f1]) - m0
    units = np.asarray(g["bmu_unit"][f0:f1])
    hist = bmu_histograms(face_mesh, units, m1 - m0, rows * cols)
    domain_vectors_array(group, run)[m0:m1] = domain_vectors(hist, rows, cols, sigma, topology)
    return m1 - m0


def domain_streamed(client, cfg, store: Path, run: str) -> tuple[np.ndarray, np.ndarray, dict]:
    """City-sized corpus: domain vectors written by worker tasks, domain map trained on their sparse form.

    The dense vectors (meshes x triangle-map units) go to ``runs/<run>/domain/vectors`` as the
    store layout asks, chunk by chunk on the workers; meanwhile the client trains the domain map
    on the per-mesh BMU histograms (:class:`meshsom.domain.SparseDomainVectors`: the smoothing is
    linear, so distances, norms and sums come from a few megabytes, never from the dense vectors).
    Same algorithm as the in-memory SOM with ``init="random"`` (tested equal).

    Returns
    -------
    units : (n_meshes,) int64
    weights : (rows*cols, M) float32
    metrics : dict
    """
    from meshsom.domain import SparseDomainVectors, train_domain_map_sparse
    from meshsom.store import create_domain_vectors, map_shape, mesh_table, open_store, run_group

    group = open_store(store, mode="r+")
    offsets = mesh_table(group).face_offsets  # read once here, not by every task
    n = len(offsets) - 1
    g = run_group(group, run, create=False)
    rows, cols, topology = map_shape(g)
    create_domain_vectors(group, run, n, rows * cols, MESHES_PER_TASK)
    tasks = []
    for a in range(0, n, MESHES_PER_TASK):
        b = min(n, a + MESHES_PER_TASK)
        tasks.append(client.submit(domain_chunk, str(store), run, a, b, int(offsets[a]), int(offsets[b]),
                                   cfg.domain.sigma, pure=False))
    d = cfg.domain
    vectors = SparseDomainVectors(np.asarray(group["face_mesh"][:]), np.asarray(g["bmu_unit"][:]), n, rows, cols,
                                  d.sigma, topology)
    res = train_domain_map_sparse(vectors, d.rows, d.cols, d.epochs, d.seed)  # as train_domain_map in memory
    client.gather(tasks)
    metrics = {"domain_q_error": res["q_error"], "domain_t_error": res["t_error"]}
    return res["units"], res["weights"], metrics


def thumbnails_of(group, n_meshes: int, size: int = 64) -> list:
    """Thumbnails of the first ``n_meshes`` meshes of a store (RGBA arrays), all at one scale."""
    from meshsom.store import mesh_table, read_mesh
    from meshsom.thumbnails import render_thumbnails

    table = mesh_table(group)
    return render_thumbnails([read_mesh(group, i, table) for i in range(n_meshes)], size=size)[0]


def domain_for_run(cfg, store: Path, run: str, thumbs=None, client=None) -> dict:
    """Domain map of one triangle map; writes ``runs/<run>/domain`` and the figure.

    Returns
    -------
    dict
        ``units`` (n_meshes,), ``figure`` path, ``metrics`` (domain Q-error, and with labels the
        k-NN agreement, its chance level and the ARI of map regions vs labels).
    """
    from sklearn.metrics import adjusted_rand_score

    from meshsom.codebook import load_codebook
    from meshsom.domain import (
        KNN, bmu_histograms, domain_vectors, knn_label_agreement, label_agreement_chance, map_regions, place,
        train_domain_map,
    )
    from meshsom.store import figures_dir, mesh_table, open_store, write_domain
    from meshsom.thumbnails import domain_map_figure

    group = open_store(store, mode="r+")
    cb = load_codebook(group, run)
    table = mesh_table(group)
    d = cfg.domain
    streamed = client is not None and len(table) * cb.rows * cb.cols * 4 > IN_MEMORY_BYTES
    if streamed:
        units, weights, metrics = domain_streamed(client, cfg, store, run)
        vectors = None
    else:
        face_mesh = np.asarray(group["face_mesh"][:])
        hist = bmu_histograms(face_mesh, cb.bmu.unit, len(table), cb.rows * cb.cols)
        vectors = domain_vectors(hist, cb.rows, cb.cols, d.sigma, cb.topology)
        som = train_domain_map(vectors, d.rows, d.cols, d.epochs, d.seed)
        units = place(vectors, som)
        weights = som.weights_
        ev = som.evaluate(vectors)
        metrics = {"domain_q_error": float(ev["q_error"]), "domain_t_error": float(ev["t_error"])}
    labels = np.asarray(table.labels)
    has_labels = len(labels) > 1 and all(labels) and len(set(labels)) > 1
    if has_labels:
        sample = np.arange(len(labels))
        if len(sample) > LABEL_SAMPLE:
            sample = np.sort(np.random.default_rng(d.seed).choice(len(labels), LABEL_SAMPLE, replace=False))
        metrics["knn_label_agreement"] = knn_label_agreement(units[sample], labels[sample], d.rows, d.cols,
                                                             k=min(KNN, len(sample) - 1))
        metrics["knn_label_chance"] = label_agreement_chance(labels[sample])
        regions = map_regions(weights, d.rows, d.cols, len(set(labels)), d.seed)
        metrics["ari_regions_vs_labels"] = adjusted_rand_score(regions[units], labels)
    arrays = {"weights": weights, "units": units} | ({} if vectors is None else {"vectors": vectors})
    write_domain(group, run, arrays, {"rows": d.rows, "cols": d.cols, "sigma": d.sigma, "metrics": metrics})
    path = figures_dir(store) / f"domain-{run}.png"
    n_draw = min(len(table), MAX_THUMBNAILS)
    if thumbs is None:
        thumbs = thumbnails_of(group, n_draw)
    domain_map_figure(units[:n_draw], thumbs[:n_draw], d.rows, d.cols, path,
                      title=f"Domain map from {run}",
                      labels=labels[:n_draw] if has_labels else None, ids=np.asarray(table.ids)[:n_draw])
    return {"units": units, "figure": str(path), "metrics": metrics}


def run_domain_stage(cfg, store: Path, tracker, ids: dict, results: list[dict], client=None) -> list[dict]:
    """Domain maps for every trained map of the run, logged to its MLflow child run."""
    from meshsom.store import mesh_table, open_store

    group = open_store(store)
    n_draw = min(len(mesh_table(group)), MAX_THUMBNAILS)
    thumbs = thumbnails_of(group, n_draw)
    out = []
    for res in results:
        run = res["run"]
        dom = domain_for_run(cfg, store, run, thumbs, client)
        child = ids["children"].get(run)
        tracker.log_metrics(child, dom["metrics"], step=cfg.som.epochs)
        for figure in (dom["figure"], str(Path(dom["figure"]).with_suffix(".svg"))):
            tracker.log_artifact(child, figure, "figures")
        m = dom["metrics"]
        extra = (f", k-NN label agreement {m['knn_label_agreement']:.3f} (chance {m['knn_label_chance']:.3f}), "
                 f"ARI {m['ari_regions_vs_labels']:.3f}") if "knn_label_agreement" in m else ""
        print(f"      {run:16s} domain map {cfg.domain.rows} x {cfg.domain.cols}: Q {m['domain_q_error']:.4f}{extra}")
        out.append({**dom, "run": run})
    return out
