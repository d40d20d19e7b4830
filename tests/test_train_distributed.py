"""Distributed batch training equals single-process SOM training; resume equals an uninterrupted run."""

import numpy as np
import pytest
from distributed import Client, LocalCluster

from meshsom import domain
from meshsom.codebook import load_codebook
from meshsom.som import SOM
from meshsom.store import open_store
from meshsom.variations import variation_table
from pipelines.cli import main
from pipelines.train import TrainJob, train_spec
from pipelines.train import load_level


@pytest.fixture(scope="module")
def client():
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cluster, Client(cluster) as c:
        yield c


@pytest.fixture(scope="module")
def store(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("train")
    city = tmp / "c.city.json"
    assert main(["generate", "--out", str(city), "-n", "10", "--seed", "2"]) == 0
    s = tmp / "s.zarr"
    assert main(["ingest", str(city), "--out", str(s), "--chunk-rows", "64"]) == 0
    assert main(["encode", str(s), "--levels", "1", "2"]) == 0
    return str(s)


def job(store, **kw):
    base = dict(store=store, level=1, kernel="bmuofn", mirror=False, rows=6, cols=8, topology="toroidal", epochs=6,
                sigma_start=2.0, sigma_end=0.5, init="random", seed=3, backend="numpy")
    return TrainJob(**(base | kw))


@pytest.mark.parametrize("level, kernel, init", [(1, "bmuofn", "random"), (1, "default", "pca"), (2, "bmuofn", "pca")])
def test_distributed_training_equals_single_process(client, store, level, kernel, init):
    """Same blocks, same order of the sums, same initialisation: bitwise the same codebook."""
    j = job(store, level=level, kernel=kernel, init=init)
    result = train_spec(client, j)
    X = load_level(open_store(store), level)
    index, sign = variation_table(level, kernel=kernel)
    som = SOM(rows=6, cols=8, epochs=6, sigma_start=2.0, sigma_end=0.5, init=init, random_state=3,
              backend="numpy").fit(X, index, sign)
    cb = load_codebook(open_store(store), j.run)
    assert np.array_equal(cb.weights, som.weights_)
    assert result["metrics"] == som.evaluate(X)
    assert np.array_equal(cb.bmu.unit, som.transform(X).unit)
    assert len(result["history"]) == 6


def test_resume_after_a_crash_equals_uninterrupted_run(client, store):
    j = job(store, epochs=5, seed=11)
    full = train_spec(client, j)
    w_full = load_codebook(open_store(store), j.run).weights.copy()

    class Crash(Exception):
        pass

    def crash(epoch, metrics):
        if epoch == 2:
            raise Crash

    with pytest.raises(Crash):
        train_spec(client, j, on_epoch=crash)
    g = open_store(store)
    assert g["runs"][j.run].attrs["epoch_done"] == 3 and not g["runs"][j.run].attrs.get("final_done")
    # the BMUs of the last finished epoch's search are on disk too
    assert g["runs"][j.run].attrs["bmu_epoch"] == 2
    units = g["runs"][j.run]["bmu_unit"][:]
    assert units.shape == (g["rings"]["level1"].shape[0],) and 0 <= units.min() and units.max() < 48
    seen = []
    resumed = train_spec(client, j, resume=True, on_epoch=lambda e, m: seen.append(e))
    assert resumed["resumed_from"] == 3 and seen == [3, 4]  # epochs 0-2 were not recomputed
    assert np.array_equal(load_codebook(open_store(store), j.run).weights, w_full)
    assert resumed["metrics"] == full["metrics"]


def test_streamed_domain_stage_equals_in_memory_computation(client, store):
    """City-sized path: domain vectors written by tasks, domain SOM trained on their sparse form."""
    from dataclasses import replace
    from pathlib import Path

    from pipelines.settings import load_config
    from meshsom.domain import bmu_histograms, domain_vectors
    from meshsom.store import mesh_table
    from pipelines.domain_stage import domain_streamed

    j = job(store, epochs=3, seed=5)
    train_spec(client, j)
    cfg = load_config(Path(__file__).resolve().parents[1] / "configs" / "quick.yaml")
    cfg = replace(cfg, domain=replace(cfg.domain, rows=3, cols=3))
    units, weights, metrics = domain_streamed(client, cfg, Path(store), j.run)
    g = open_store(store)
    cb = load_codebook(g, j.run)
    hist = bmu_histograms(np.asarray(g["face_mesh"][:]), cb.bmu.unit, len(mesh_table(g)), 48)
    vectors = domain_vectors(hist, 6, 8, cfg.domain.sigma)
    assert np.allclose(g["runs"][j.run]["domain"]["vectors"][:], vectors, atol=1e-7)
    d = cfg.domain
    som = domain.train_domain_map(vectors, d.rows, d.cols, d.epochs, d.seed)  # the in-memory path: PCA too
    assert np.allclose(weights, som.weights_, atol=1e-5)
    assert np.array_equal(units, som.predict(vectors))
    ev = som.evaluate(vectors)
    assert metrics["domain_q_error"] == pytest.approx(ev["q_error"], rel=1e-4)
    assert metrics["domain_t_error"] == pytest.approx(ev["t_error"])


def test_won_unit_sums_add_like_dense_sums():
    """What a training task sends (the sums of the units its block won) adds, block after block,
    to the bits of add_sums over the blocks' dense sums."""
    from meshsom.som import add_sums, block_sums, row_blocks
    from pipelines.train import add_won_sums

    rng = np.random.default_rng(21)
    N, D, rows, cols = 900, 9, 6, 8
    X = (rng.normal(size=(N, D)) * 10.0 ** rng.uniform(-8, 8, size=(N, 1))).astype(np.float32)
    W = (rng.normal(size=(rows * cols, D)) * 1e3).astype(np.float32)  # many units win nothing
    index, sign = variation_table(1, kernel="bmuofn")
    dense = won = None
    for a, b in row_blocks(N, 128):
        part = block_sums(X[a:b], W, rows, cols, "toroidal", index, sign, backend="numpy")
        part.pop("bmu")
        dense = add_sums(dense, part)
        keep = np.flatnonzero(part["counts"])
        assert len(keep) < rows * cols
        won = add_won_sums(won, {**part, "won": keep.astype(np.int32), "sums": part["sums"][keep]})
    for key in ("sums", "counts"):
        assert won[key].tobytes() == dense[key].tobytes(), key
    for key in ("n", "t_bad", "q_sum", "qc_sum"):
        assert won[key] == dense[key], key


def test_each_block_runs_on_one_worker_every_epoch(client, store, monkeypatch):
    """Each row block goes to the same worker every epoch, so each worker reads, standardizes (and, on
    OpenCL, uploads) only its own blocks; left to the scheduler, blocks wander and every worker ends
    up holding every block."""
    from meshsom import som as som_module
    from pipelines.train import block_workers

    n = load_level(open_store(store), 1).shape[0]
    block = -(-n // 6)  # six blocks
    real = som_module.row_blocks
    monkeypatch.setattr(som_module, "BLOCK_ROWS", block)  # the BMU arrays' chunks: one per block
    monkeypatch.setattr(som_module, "row_blocks", lambda n, block_rows=block: real(n, block_rows))
    ranges = real(n, block)
    assert len(ranges) == 6
    result = train_spec(client, job(store, name="placed", epochs=5))
    assert len(result["history"]) == 5

    def held(store=store):
        from pipelines.train import _CHUNKS

        return sorted((k[3], k[4]) for k in _CHUNKS if k[0] == store and k[1] == 1)

    where = {r: [w for w, rs in client.run(held).items() if r in rs] for r in ranges}
    homes = block_workers(client, len(ranges))
    assert all(where[r] == [home] for r, home in zip(ranges, homes)), where
    assert len(set(homes)) == 2
    # every block wrote its BMUs: the final codebook's own answer for every row
    from meshsom.bmu_numpy import bmu_numpy

    cb = load_codebook(open_store(store), "placed")
    index, sign = variation_table(1, kernel="bmuofn")
    np.testing.assert_array_equal(cb.bmu.unit, bmu_numpy(load_level(open_store(store), 1), cb.weights, index, sign).unit)


def test_a_block_pinned_to_a_worker_that_left_raises_worker_lost(client, monkeypatch):
    """A block pinned to a worker that is no longer in the cluster would wait forever: the pass
    notices (every PLACEMENT_CHECK_S) and raises WorkerLost, which runs the pass again."""
    import operator

    from pipelines import train

    monkeypatch.setattr(train, "PLACEMENT_CHECK_S", 0.2)
    gone = "tcp://127.0.0.1:9"  # no worker there
    fut = client.submit(operator.add, 1, 2, workers=[gone], pure=False)
    with pytest.raises(train.WorkerLost, match="left the cluster"):
        train._result(client, fut, gone)
    client.cancel(fut)
    home = sorted(client.nthreads())[0]
    assert train._result(client, client.submit(operator.add, 1, 2, workers=[home], pure=False), home) == 3
