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
