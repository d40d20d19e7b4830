"""Synthesis: unfolding reproduces vectors; leveling lowers re-translation error; CLI round trip."""

import numpy as np
import pytest
import trimesh

from meshsom.synthesis import decode, level_vector, qc_distance, reencode, retranslation_error, write_patch
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
        for leveling in (False, True):
            assert np.abs(reencode(decode(x[t], level, leveling)) - x[t]).max() < 1e-5


def test_level3_patch_has_22_faces_and_level1_equilateral_root():
    x3 = encode(*block(2), 3)[0]
    assert len(decode(x3, 3).faces) == 22
    p1 = decode(encode(*block(2), 1)[0], 1)
    root = p1.vertices[p1.faces[0]]
    sides = np.linalg.norm(root - np.roll(root, 1, axis=0), axis=1)
    assert np.allclose(sides, 1.0)


def test_leveling_averages_copies_and_keeps_exact_vectors():
    x = encode(*block(3), 3)[4]
    assert np.abs(level_vector(x, 3) - x).max() < 1e-12  # every copy already agrees
    noisy = x + np.random.default_rng(0).normal(0, 0.1, x.shape)
    lev = level_vector(noisy, 3)
    assert np.abs(level_vector(lev, 3) - lev).max() < 1e-12  # idempotent


def test_leveling_lowers_retranslation_error_with_noise():
    rng = np.random.default_rng(7)
    x = encode(*block(5), 3)
    raw, lev = [], []
    for t in range(len(x)):
        y = x[t] + rng.normal(0, 0.05, x.shape[1])
        y.reshape(-1, 3)[:, 2] = np.abs(y.reshape(-1, 3)[:, 2])
        raw.append(retranslation_error(y, 3))
        lev.append(retranslation_error(y, 3, leveling=True))
    reduction = 1 - np.mean(lev) / np.mean(raw)
    assert reduction > 0.15, reduction
    assert qc_distance(x[0], x[0]) == 0


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
    patch = trimesh.load(out / "level2_face3_raw.obj", force="mesh", process=False)
    assert len(patch.faces) == 10
    assert (out / "level2_contact_sheet.png").stat().st_size > 1000
    # the written patch re-encodes to its source ring
    x = np.asarray(rings_array(g, 2)[3], np.float64)
    assert np.abs(reencode(decode(x, 2)) - x).max() < 1e-4
