import json

import numpy as np
import pytest

from meshsom.errors import StoreError
from meshsom.store import (
    CleanMesh, create_store, iter_meshes, iter_row_chunks, mesh_table, open_store, read_manifest, read_mesh,
    read_stats, rings_array, write_manifest, write_meshes, write_rings, write_stats,
)


def _meshes(cube):
    v, f = cube
    return [
        CleanMesh("a#1", v, f, np.array([2.6e6, 1.2e6, 400.0]), "box"),
        CleanMesh("b#2", v[:4].copy(), np.array([[0, 1, 2], [0, 2, 3]]), np.zeros(3), None),
    ]


def test_meshes_round_trip_with_global_indices(tmp_path, cube):
    g = create_store(tmp_path / "s.zarr")
    write_meshes(g, _meshes(cube), chunk_rows=5)
    g = open_store(tmp_path / "s.zarr")
    t = mesh_table(g)
    assert list(t.ids) == ["a#1", "b#2"] and list(t.labels) == ["box", ""]
    assert t.vertex_offsets.tolist() == [0, 8, 12] and t.face_offsets.tolist() == [0, 12, 14]
    assert g["faces"][12:].tolist() == [[8, 9, 10], [8, 10, 11]]  # indices into the global vertex table
    assert g["face_mesh"][:].tolist() == [0] * 12 + [1] * 2
    assert g["vertices"].chunks == (5, 3)
    v, f = read_mesh(g, 1, t)
    assert f.tolist() == [[0, 1, 2], [0, 2, 3]] and np.array_equal(v, cube[0][:4])
    assert [i for i, _, _ in iter_meshes(g)] == [0, 1]
    assert np.array_equal(t.origins[0], [2.6e6, 1.2e6, 400.0])


def test_refuses_overwrite_and_missing_store(tmp_path):
    create_store(tmp_path / "s.zarr")
    with pytest.raises(StoreError, match="already exists"):
        create_store(tmp_path / "s.zarr")
    with pytest.raises(StoreError, match="no zarr store here"):
        open_store(tmp_path / "nothing.zarr")


def test_rings_stats_and_row_chunks(tmp_path):
    g = create_store(tmp_path / "s.zarr")
    x = np.arange(70 * 9, dtype=np.float64).reshape(70, 9)
    write_rings(g, 1, x, chunk_rows=32)
    a = rings_array(g, 1)
    assert a.dtype == np.float32 and a.shape == (70, 9)
    assert list(iter_row_chunks(a)) == [(0, 32), (32, 64), (64, 70)]
    assert np.array_equal(a[:], x.astype(np.float32))
    write_stats(g, 1, {"mean": [1.0, 0.0, 2.0], "std": [0.5, 1.0, 1.5]})
    assert read_stats(open_store(tmp_path / "s.zarr"), 1)["std"] == [0.5, 1.0, 1.5]
    with pytest.raises(StoreError, match="meshsom encode --levels 2"):
        rings_array(g, 2)


def test_manifest_counts_add_up(tmp_path):
    recs = [{"id": "a", "status": "accepted"}, {"id": "b", "status": "rejected", "reason": "x"}]
    doc = write_manifest(tmp_path, recs, {"faces_in": 3})
    assert doc["summary"] == {"inputs": 2, "accepted": 1, "rejected": 1, "faces_in": 3}
    assert read_manifest(tmp_path) == json.loads((tmp_path / "manifest.json").read_text())


def test_run_group_checkpoints_read_back_as_train_wrote_them(tmp_path):
    import zarr

    from meshsom.codebook import load_codebook
    from meshsom.store import (
        BMU_ARRAYS, create_bmu_arrays, read_checkpoint, reset_run, run_group, write_checkpoint, write_run_header,
        write_run_result,
    )

    root = create_store(tmp_path / "s.zarr")
    g = reset_run(root, "level1-bmuofn")
    assert read_checkpoint(g) is None and dict(g.attrs) == {} and list(g.array_keys()) == []
    write_run_header(g, 2, 3, "toroidal", 1, "bmuofn", "fp0", {"epochs": 2})
    arrays = create_bmu_arrays(g, 10, 4)
    assert sorted(arrays) == sorted(BMU_ARRAYS.values())
    assert {n: (a.shape, a.chunks, a.dtype) for n, a in arrays.items()} == {
        "bmu_unit": ((10,), (4,), np.int64), "bmu_variation": ((10,), (4,), np.int64),
        "bmu_second": ((10,), (4,), np.int64), "bmu_dist2": ((10,), (4,), np.float64)}
    arrays["bmu_unit"][:] = np.arange(10)
    assert create_bmu_arrays(g, 10, 4)["bmu_unit"][:].tolist() == list(range(10))  # same shape + chunks: kept
    assert create_bmu_arrays(g, 10, 5)["bmu_unit"].chunks == (5,)  # other chunks: replaced
    create_bmu_arrays(g, 10, 4)["bmu_unit"][:] = np.arange(10)[::-1]

    w1 = np.arange(6 * 9, dtype=np.float64).reshape(6, 9) / 7
    history = [{"epoch": 0, "t_error": 0.5}, {"epoch": 1, "t_error": 0.25}]
    write_checkpoint(g, w1, 1, history[:1], 0)
    cp = read_checkpoint(run_group(root, "level1-bmuofn"))
    assert cp["epoch_done"] == 1 and cp["history"] == history[:1] and cp["fingerprint"] == "fp0"
    assert cp["weights"].dtype == np.float32 and np.array_equal(cp["weights"], w1.astype(np.float32))
    assert cp["final_done"] is False and cp["result"] is None
    write_checkpoint(g, w1 * 2, 2, history, 1)
    write_run_result(g, {"t_error": 0.25, "q_error": 1, "qc_error": 0.5}, {"run": "level1-bmuofn", "history": history},
                     {"backend": "numpy"})
    a = dict(zarr.open_group(str(tmp_path / "s.zarr"), mode="r")["runs/level1-bmuofn"].attrs)
    # the attribute names pipelines/train.py has always written (existing stores read the same)
    assert {k: a[k] for k in ("rows", "cols", "topology", "level", "kernel", "fingerprint", "epoch_done",
                              "bmu_epoch", "final_done")} == {
        "rows": 2, "cols": 3, "topology": "toroidal", "level": 1, "kernel": "bmuofn", "fingerprint": "fp0",
        "epoch_done": 2, "bmu_epoch": 2, "final_done": True}
    assert a["metrics"] == {"t_error": 0.25, "q_error": 1.0, "qc_error": 0.5} and a["engine"] == {"backend": "numpy"}
    assert a["history"] == history and a["job"] == {"epochs": 2}
    cb = load_codebook(root, "level1-bmuofn")
    assert np.array_equal(cb.weights, (w1 * 2).astype(np.float32)) and cb.bmu.unit.tolist() == list(range(10))[::-1]
    assert read_checkpoint(g)["final_done"] and reset_run(root, "level1-bmuofn").attrs.get("epoch_done") is None


def test_checkpoint_of_a_store_written_before_store_owned_it(tmp_path):
    """A run group laid out by hand as train.py wrote it reads back through read_checkpoint."""
    from meshsom.store import read_checkpoint, run_group

    root = create_store(tmp_path / "s.zarr")
    g = run_group(root, "level2-bmuofn")
    w = np.ones((4, 36), np.float32)
    g.create_array("weights", shape=w.shape, dtype=w.dtype, chunks=w.shape)[...] = w
    g.attrs.update({"fingerprint": "abc", "epoch_done": 3, "history": [{"epoch": e} for e in range(5)], "bmu_epoch": 2})
    cp = read_checkpoint(g)
    assert cp["epoch_done"] == 3 and [h["epoch"] for h in cp["history"]] == [0, 1, 2] and np.array_equal(cp["weights"], w)


def test_domain_maps_tables_staging_and_figures(tmp_path, cube):
    from meshsom.store import (
        create_domain_vectors, domain_vectors_array, figures_dir, read_domain, read_meshes, shard_meta,
        write_domain, write_mesh_tables, write_shard,
    )

    root = create_store(tmp_path / "s.zarr")
    assert read_domain(root, "level1-bmuofn") is None
    vec = create_domain_vectors(root, "level1-bmuofn", 5, 12, 2)
    assert (vec.shape, vec.chunks, vec.dtype) == ((5, 12), (2, 12), np.float32)
    domain_vectors_array(root, "level1-bmuofn")[2:4] = 1.0
    write_domain(root, "level1-bmuofn", {"weights": np.zeros((4, 12)), "units": np.array([3, 0, 1, 1, 2])},
                 {"rows": 2, "cols": 2, "sigma": 1.5, "metrics": {"domain_q_error": 0.1}})
    d = read_domain(open_store(tmp_path / "s.zarr"), "level1-bmuofn")
    assert d["units"].tolist() == [3, 0, 1, 1, 2] and d["units"].dtype == np.int64
    assert (d["rows"], d["cols"], d["sigma"], d["metrics"]) == (2, 2, 1.5, {"domain_q_error": 0.1})
    assert domain_vectors_array(root, "level1-bmuofn")[:, 0].tolist() == [0, 0, 1, 1, 0]  # tasks' rows kept
    assert figures_dir(tmp_path / "s.zarr") == tmp_path / "s-figures" and (tmp_path / "s-figures").is_dir()

    # write_meshes = the per-mesh tables + the per-row arrays; tables alone from counts
    write_meshes(root, _meshes(cube), chunk_rows=5)
    t = mesh_table(root)
    other = create_store(tmp_path / "t.zarr")
    write_mesh_tables(other, ["a#1", "b#2"], ["box", None], [8, 4], [12, 2], t.origins)
    t2 = mesh_table(other)
    for name in ("ids", "labels", "vertex_offsets", "face_offsets", "origins"):
        assert np.array_equal(getattr(t, name), getattr(t2, name)), name
    assert dict(other.attrs) == dict(root.attrs) | {"n_meshes": 2, "n_faces": 14, "n_vertices": 12}
    (i0, v0, f0), (i1, v1, f1) = read_meshes(root, 0, 2)
    assert (i0, i1) == ("a#1", "b#2") and np.array_equal(f0, cube[1]) and f1.tolist() == [[0, 1, 2], [0, 2, 3]]

    assert shard_meta(tmp_path / "s.zarr", "x") is None
    write_shard(tmp_path / "s.zarr", "x", {"level1": np.ones((3, 9), np.float32)}, {"n": 3}, 2)
    assert shard_meta(tmp_path / "s.zarr", "x") == {"n": 3}
