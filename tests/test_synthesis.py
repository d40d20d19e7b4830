"""Synthesis: unfolding reproduces vectors; least-squares leveling keeps exact vectors and lowers
the error of noisy ones; vectorised encodings against the per-mesh encoder; CLI round trip."""

import numpy as np
import pytest
import trimesh

from meshsom.rings import template
from meshsom.synthesis import (
    Patch, decode, encode_patches, entry_depth, level_patches, nearest_mapped, patch_topology, qc_distance,
    reencode, retranslation_error, synthesize, unfold, write_patch,
)
from meshsom.topology import adjacency
from pipelines.cli import main
from test_encoding import block, encode


def flat_grid_vector(level):
    m = trimesh.creation.box(extents=(10, 10, 1))
    v, f = m.vertices, m.faces
    for _ in range(4):
        v, f = trimesh.remesh.subdivide(v, f)
    x = encode(v, f, level)
    centre = v[f].mean(axis=1)
    t = int(np.argmin(np.linalg.norm(centre - [0.3, 0.2, 0.5], axis=1)))  # deep inside the top
    assert np.allclose(x[t].reshape(-1, 3)[:, 0], np.pi)
    return x[t]


@pytest.mark.parametrize("level", [1, 2, 3])
def test_round_trip_on_flat_grid(level):
    x = flat_grid_vector(level)
    y = reencode(decode(x, level))
    assert np.abs(y - x).max() < 1e-5
    patch = decode(x, level)
    assert np.allclose(patch.vertices[:, 2], 0)  # a flat ring unfolds flat


@pytest.mark.parametrize("level", [1, 2, 3])
@pytest.mark.parametrize("seed", [1, 4])
def test_round_trip_on_building_blocks(level, seed):
    x = encode(*block(seed), level)
    for t in range(0, len(x), max(1, len(x) // 15)):
        for level_by in ("none", "lsq"):
            assert np.abs(reencode(decode(x[t], level, level_by)) - x[t]).max() < 1e-5


def test_level3_patch_has_22_faces_and_level1_equilateral_root():
    x3 = encode(*block(2), 3)[0]
    assert len(decode(x3, 3).faces) == 22
    p1 = decode(encode(*block(2), 1)[0], 1)
    root = p1.vertices[p1.faces[0]]
    sides = np.linalg.norm(root - np.roll(root, 1, axis=0), axis=1)
    assert np.allclose(sides, 1.0)


def _mesh_corners(v, f, level, root):
    """Mesh vertex of every corner of a level's patch at face ``root``, walked independently."""
    adj = adjacency(f)
    rows = []
    for path in patch_topology(level).slots:
        face, start = root, 0
        for o in path:
            e = (start + o) % 3
            face, start = adj.neighbour[face, e], adj.back[face, e]
        rows.append(f[face, (start + np.arange(3)) % 3])
    return v[np.array(rows)]  # (S, 3, 3)


def _similarity_residual(A, B):
    """Largest distance after the best similarity A -> B (Umeyama), relative to B's size."""
    a, b = A - A.mean(axis=0), B - B.mean(axis=0)
    U, S, Vt = np.linalg.svd(b.T @ a)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    R = U @ D @ Vt
    s = np.trace(np.diag(S) @ D) / (a**2).sum()
    return np.linalg.norm(s * a @ R.T - b, axis=1).max() / np.linalg.norm(b, axis=1).max()


def test_vectorised_encoding_equals_the_mesh_encoder():
    rng = np.random.default_rng(0)
    for level in (1, 2, 3):
        V = unfold(encode(*block(2), level)[:6], level) + rng.normal(0, 0.05, (6, patch_topology(level).n_vertices, 3))
        topo = patch_topology(level)
        direct = np.array([reencode(Patch(v, topo.faces, list(topo.slots), topo.adjacency, level)) for v in V])
        assert np.allclose(encode_patches(V, level), direct, atol=1e-12)


def test_entry_depth_is_the_depth_of_each_folds_face():
    tpl = template(3)
    expected = np.array([len(slot) for slot in tpl.slots_of_refs()])
    assert np.array_equal(entry_depth(3), expected)
    assert np.bincount(entry_depth(3)).tolist() == [12, 18, 18]  # the root's one-ring 4 times of 16


@pytest.mark.parametrize("seed", [1, 3])
def test_leveling_exact_vectors_returns_the_patch_up_to_a_similarity(seed):
    v, f = block(seed)
    x = encode(v, f, 3)
    roots = np.arange(0, len(x), max(1, len(x) // 8))
    V, info = level_patches(x[roots], 3)
    assert np.abs(encode_patches(V, 3) - x[roots]).max() < 1e-5
    assert np.abs(np.array([reencode(Patch(p, patch_topology(3).faces, [], patch_topology(3).adjacency, 3))
                            for p in V]) - x[roots]).max() < 1e-5
    faces = patch_topology(3).faces
    for p, r in zip(V, roots):
        assert _similarity_residual(p[faces].reshape(-1, 3), _mesh_corners(v, f, 3, r).reshape(-1, 3)) < 1e-6
    assert (info["cost"] <= info["cost_start"]).all()


def test_leveling_lowers_the_error_of_noisy_vectors_and_is_deterministic():
    from meshsom.standardize import accumulate, empty_accumulator, finalize, standardize

    v, f = block(5)
    x = encode(v, f, 3)
    stats = finalize(accumulate(empty_accumulator(), x), 3)
    rng = np.random.default_rng(7)
    noisy = x + rng.normal(0, 0.05, x.shape) * np.tile(stats.std, x.shape[1] // 3)
    noisy[:, 2::3] = np.abs(noisy[:, 2::3])

    def err(V):  # QC against the clean vector, standardized, computed on the meshes' own encoder
        topo = patch_topology(3)
        y = np.array([reencode(Patch(p, topo.faces, [], topo.adjacency, 3)) for p in V])
        d = (standardize(x, stats) - standardize(y, stats)).reshape(len(x), -1, 3)
        return np.linalg.norm(d, axis=-1).mean(axis=1)

    none = err(synthesize(noisy, 3, "none", stats))
    lsq = synthesize(noisy, 3, "lsq", stats)
    assert err(lsq).mean() < 0.8 * none.mean(), (err(lsq).mean(), none.mean())
    assert (err(lsq) < none).mean() > 0.8
    assert np.array_equal(lsq, synthesize(noisy, 3, "lsq", stats))  # deterministic
    assert np.array_equal(lsq[3:4], synthesize(noisy[3:4], 3, "lsq", stats))  # independent of the batch
    assert retranslation_error(noisy[0], 3, "lsq", stats) < retranslation_error(noisy[0], 3, "none", stats)
    with pytest.raises(ValueError, match="lsq"):
        synthesize(noisy, 3, "average")


def test_nearest_mapped_matches_a_loop():
    rng = np.random.default_rng(3)
    unit = rng.integers(0, 9, 200)
    dist2 = rng.integers(0, 20, 200).astype(float)  # ties on purpose: the lowest row wins
    expected = np.full(12, -1)
    for u in range(12):
        rows = np.flatnonzero(unit == u)
        if len(rows):
            expected[u] = rows[np.argmin(dist2[rows])]
    assert np.array_equal(nearest_mapped(unit, dist2, 12), expected)
    assert qc_distance(np.ones(6), np.ones(6)) == 0


def test_patch_export_opens_in_trimesh(tmp_path):
    patch = decode(encode(*block(1), 2)[3], 2)
    for ext in ("obj", "ply", "glb"):
        write_patch(patch, tmp_path / f"p.{ext}")
        loaded = trimesh.load(tmp_path / f"p.{ext}", force="mesh", process=False)
        assert len(loaded.faces) == len(patch.faces)


def test_encode_and_synth_commands_on_an_ingested_store(tmp_path):
    import json

    from meshsom.folds import folds
    from meshsom.rings import encode_level
    from meshsom.store import iter_meshes, open_store, read_stats, rings_array
    from meshsom.topology import adjacency

    city = tmp_path / "c.city.json"
    assert main(["generate", "--out", str(city), "-n", "6", "--seed", "3"]) == 0
    store = tmp_path / "s.zarr"
    assert main(["ingest", str(city), "--out", str(store)]) == 0
    assert main(["encode", str(store), "--levels", "1", "2", "3", "--batch-faces", "100"]) == 0
    g = open_store(store)
    expected = {1: [], 2: [], 3: []}
    for _, v, f in iter_meshes(g):
        adj = adjacency(f)
        fo = folds(v, f, adj)
        for level in expected:
            expected[level].append(encode_level(fo, adj, level))
    for level, parts in expected.items():
        direct = np.concatenate(parts)
        stored = np.asarray(rings_array(g, level)[:])
        assert stored.dtype == np.float32 and np.array_equal(stored, direct)
        comps = direct.astype(np.float64).reshape(-1, 3)
        st = read_stats(g, level)
        assert np.allclose(st["mean"], [comps[:, 0].mean(), 0, comps[:, 2].mean()])
        assert np.allclose(st["std"][0], comps[:, 0].std())
    out = tmp_path / "synth"
    assert main(["synth", str(store), "--level", "2", "--faces", "3", "10", "--out", str(out), "--json"]) == 0
    patch = trimesh.load(out / "level2_face3_lsq.obj", force="mesh", process=False)
    assert len(patch.faces) == 10
    assert main(["synth", str(store), "--level", "2", "--faces", "3", "--out", str(out), "--level-by", "none"]) == 0
    assert (out / "level2_face3_none.obj").exists()
    assert (out / "level2_contact_sheet.png").stat().st_size > 1000
    # the written patch re-encodes to its source ring
    x = np.asarray(rings_array(g, 2)[3], np.float64)
    assert np.abs(reencode(decode(x, 2)) - x).max() < 1e-4
