"""Folds, ring templates, variations and standardization, against direct computation."""

from pathlib import Path

import numpy as np
import pytest
import trimesh

from conftest import box
from meshsom.errors import MeshError
from meshsom.folds import folds
from meshsom.generate import GeneratorParams, generate_block
from meshsom.polygons import extrude_polygon
from meshsom.preprocess import preprocess
from meshsom.rings import dims, encode_level, faces_in_walk, template
from meshsom.standardize import accumulate, destandardize, empty_accumulator, finalize, merge_accumulators, standardize
from meshsom.topology import adjacency

DELFT = Path(__file__).resolve().parents[1] / "data" / "real" / "delft-lod1-3dfier"
from meshsom.variations import apply, n_variations, variation_table


def encode(v, f, level, start=0, dtype=np.float64):
    adj = adjacency(f)
    return encode_level(folds(v, f, adj), adj, level, start=start, dtype=dtype)


def block(seed=3):
    b = generate_block(GeneratorParams(n_blocks=8, seed=seed), seed % 8)
    r = preprocess(b.vertices - b.vertices.mean(axis=0), b.faces)
    return r.vertices, r.faces


def icosphere():
    m = trimesh.creation.icosphere(subdivisions=2)
    return m.vertices, m.faces


def test_box_folds_are_right_angles_or_flat():
    v, f = box(2, 3, 5)
    fo = folds(v, f, adjacency(f))
    alpha = fo[..., 0]
    assert np.all(np.isclose(alpha, np.pi / 2) | np.isclose(alpha, np.pi))
    assert np.isclose(alpha, np.pi).sum() == 12  # each of the 6 diagonals from both sides
    assert (fo[..., 2] > 0).all()


def test_flat_grid_folds_are_pi():
    # A thin slab: its big faces are flat grids; only interior edges of the top are tested.
    m = trimesh.creation.box(extents=(10, 10, 1))
    v, f = trimesh.remesh.subdivide(*trimesh.remesh.subdivide(m.vertices, m.faces))
    fo = folds(v, f, adjacency(f))
    n = trimesh.Trimesh(v, f, process=False).face_normals
    top = np.isclose(n[:, 2], 1)
    nb = adjacency(f).neighbour
    inner = top[:, None] & top[nb]
    assert inner.sum() > 50
    assert np.allclose(fo[..., 0][inner], np.pi)


def test_concave_edge_of_l_block_has_alpha_above_pi():
    shell = np.array([[0, 0], [4, 0], [4, 1], [1, 1], [1, 3], [0, 3]], float)
    v, f = extrude_polygon(shell, [], 0, 2)
    fo = folds(v, f, adjacency(f))
    # the inner vertical edge at (1, 1): faces on it fold by 3 pi / 2
    p, q = v[f], v[np.roll(f, -1, axis=1)]
    inner = np.all(np.isclose(p[..., :2], [1, 1]), axis=-1) & np.all(np.isclose(q[..., :2], [1, 1]), axis=-1)
    assert inner.sum() == 2
    assert np.allclose(fo[..., 0][inner], 1.5 * np.pi)
    assert (fo[..., 0] <= np.pi + 1e-9).sum() == fo[..., 0].size - 2


def test_folds_invariant_to_rotation_translation_scale():
    v, f = block()
    fo = folds(v, f, adjacency(f))
    rot = trimesh.transformations.random_rotation_matrix(np.random.default_rng(1).random(3))[:3, :3]
    w = 3.7 * v @ rot.T + [100.0, -20.0, 7.0]
    assert np.abs(folds(w, f, adjacency(f)) - fo).max() < 1e-6


def test_not_closed_mesh_refused():
    v, f = box()
    with pytest.raises(MeshError, match="not a closed 2-manifold"):
        adjacency(f[:-1], source="open.obj")


@pytest.mark.parametrize("level", range(1, 9))
def test_template_sizes(level):
    tpl = template(level)
    assert tpl.dims == dims(level) == 9 * 4 ** (level - 1)
    assert tpl.n_faces() == faces_in_walk(level) == 3 * 2**level - 2


def test_level1_is_the_claw_in_order():
    v, f = block()
    adj = adjacency(f)
    fo = folds(v, f, adj)
    for k in range(3):
        x = encode(v, f, 1, start=k)
        assert np.array_equal(x, fo[:, [(k + j) % 3 for j in range(3)]].reshape(len(f), 9))


def test_level2_nests_back_edge_rings():
    v, f = icosphere()
    adj = adjacency(f)
    fo = folds(v, f, adj)
    x2 = encode(v, f, 2)
    t = 17
    expected = [fo[t, [0, 1, 2]]]
    for j in range(3):
        s, back = adj.neighbour[t, j], adj.back[t, j]
        expected.append(fo[s, [back, (back + 1) % 3, (back + 2) % 3]])
    assert np.array_equal(x2[t], np.concatenate(expected).reshape(-1))


@pytest.mark.parametrize("level", [1, 2, 3])
def test_rotation_variations_equal_direct_reencoding_from_other_start_leaves(level):
    v, f = block(5)
    x0 = encode(v, f, level)
    index, sign = variation_table(level, mirror=True)
    for k in range(3):
        direct = encode(v, f, level, start=k)
        assert np.array_equal(apply(x0, index, sign, k), direct)


@pytest.mark.parametrize("level", [1, 2, 3])
def test_mirrored_mesh_rings_equal_mirror_variation(level):
    v, f = block(6)
    x0 = encode(v, f, level)
    mirrored_v = v * [-1, 1, 1]
    mirrored_f = f[:, [1, 0, 2]]
    index, sign = variation_table(level, mirror=True)
    for k in range(3):
        direct = encode(mirrored_v, mirrored_f, level, start=k)
        assert np.abs(apply(x0, index, sign, 3 + k) - direct).max() < 1e-9


def test_cyclic_relabelling_gives_a_variation():
    v, f = block(7)
    x = encode(v, f, 3)
    relabelled = np.roll(f, 1, axis=1)
    y = encode(v, relabelled, 3)
    index, sign = variation_table(3)
    candidates = [apply(x, index, sign, k) for k in range(3)]
    assert any(np.abs(c - y).max() < 1e-12 for c in candidates)


def test_variation_counts():
    assert [n_variations(1), n_variations(2), n_variations(3), n_variations(2, mirror=True), n_variations(1, "default")] == [6, 3, 3, 6, 1]
    index, sign = variation_table(2, kernel="default")
    assert index.shape == (1, 36) and np.array_equal(index[0], np.arange(36)) and (sign == 1).all()


def test_standardization_per_component_type_commutes_with_variations_and_inverts():
    v, f = block(2)
    x = encode(v, f, 2)
    acc = merge_accumulators(accumulate(empty_accumulator(), x[:10]), accumulate(empty_accumulator(), x[10:]))
    st = finalize(acc, level=2)
    comps = x.reshape(-1, 3)
    assert np.allclose(st.mean, [comps[:, 0].mean(), 0.0, comps[:, 2].mean()])
    assert np.allclose(st.std, [comps[:, 0].std(), np.sqrt(np.mean(comps[:, 1] ** 2)), comps[:, 2].std()])
    z = standardize(x, st.to_dict())
    assert np.abs(destandardize(z, st) - x).max() < 1e-12
    index, sign = variation_table(2, mirror=True)
    for var in range(6):
        assert np.allclose(standardize(apply(x, index, sign, var), st), apply(z, index, sign, var))


def test_fold_statistics_of_a_box_written_to_the_store(tmp_path):
    import trimesh
    import zarr

    from conftest import box
    from meshsom.store import CleanMesh, create_store, read_fold_stats, write_meshes
    from pipelines.encode_cmd import encode_store

    v, f = box(2.0, 3.0, 5.0)
    group = create_store(tmp_path / "box.zarr")
    write_meshes(group, [CleanMesh("box", v, f, np.zeros(3))])
    encode_store(tmp_path / "box.zarr", [1, 2])
    # By hand: 12 triangles, 36 folds; 6 face diagonals (pi, both ways: 12 folds) and 12 box edges
    # (pi/2 both ways: 24 folds); v of every fold from the apex across each edge (trimesh).
    mesh = trimesh.Trimesh(v, f, process=False)
    group = zarr.open_group(str(tmp_path / "box.zarr"), mode="r")
    edges, apex = mesh.face_adjacency_edges, mesh.face_adjacency_unshared
    folds_v = []
    for k in (0, 1):  # both directions of every edge
        p0, p1, r = v[edges[:, 0]], v[edges[:, 1]], v[apex[:, 1 - k]]
        e = (p1 - p0) / np.linalg.norm(p1 - p0, axis=1, keepdims=True)
        d = (r - p0) - np.einsum("ij,ij->i", r - p0, e)[:, None] * e
        folds_v.append(np.linalg.norm(d, axis=1) / np.linalg.norm(p1 - p0, axis=1))
    folds_v = np.concatenate(folds_v)
    for level in (1, 2):
        s = read_fold_stats(group, level)
        mult = 4 ** (level - 1)
        assert s["folds"] == 36 and s["entries"] == 36 * mult
        alpha = np.array(s["alpha"])
        assert alpha[0] == pytest.approx(np.pi / 2) and alpha[-1] == pytest.approx(np.pi)
        assert s["alpha"][s["quantiles"].index(0.5)] == pytest.approx(np.pi / 2)  # 24 of 36 are pi/2
        assert s["flat_1e-3"] == 0 and s["flat_1deg"] == 0 and s["v_over_100"] == 0
        assert np.allclose(s["v"], np.quantile(folds_v, s["quantiles"]), rtol=1e-6)


def test_fold_statistics_equal_direct_numpy():
    from meshsom.standardize import QUANTILES, fold_statistics

    rng = np.random.default_rng(7)
    x = np.stack([rng.uniform(0, 2 * np.pi, 500), rng.normal(0, 2, 500), rng.lognormal(0, 2, 500)], axis=1)
    x[:3, 0] = [1e-4, 2 * np.pi - 1e-4, np.radians(0.5)]
    s = fold_statistics(x, level=3)
    assert np.allclose(s["alpha"], np.quantile(x[:, 0], QUANTILES))
    assert np.allclose(s["u"], np.quantile(x[:, 1], QUANTILES))
    assert np.allclose(s["v"], np.quantile(x[:, 2], QUANTILES))
    near = np.minimum(x[:, 0], 2 * np.pi - x[:, 0])
    assert s["flat_1e-3"] == 16 * (near < 1e-3).sum() == 32
    assert s["flat_1deg"] == 16 * (near < np.pi / 180).sum()
    assert s["v_over_100"] == 16 * (x[:, 2] > 100).sum()
    assert s["max_abs_u"] == np.abs(x[:, 1]).max()


def test_tail_shares_and_the_scale_hint():
    """u: 990 folds at +-0.5 and 10 at +-50 (a centimetre edge beside a half-metre face): the 10
    hold 10 x 2500 of the 10 x 2500 + 990 x 0.25 sum of squares (by hand). Normal folds: about 8.5 %
    (the top 1 % of a normal distribution beyond 2.576 sd: 2 (2.576 phi(2.576) + 0.005))."""
    from meshsom.standardize import describe_fold_statistics, fold_statistics, scale_hint

    rng = np.random.default_rng(5)
    u = np.concatenate([np.full(495, 0.5), np.full(495, -0.5), np.full(5, 50.0), np.full(5, -50.0)])
    x = np.stack([rng.normal(2.5, 0.5, 1000), u, np.full(1000, 0.5)], axis=1)
    x[0, 2] = 0.7  # v: one fold off the rest, which are all equal
    s = fold_statistics(x)
    assert s["tail_share"]["u"] == pytest.approx(25000 / (25000 + 990 * 0.25))
    far, near = 0.2 * 999 / 1000, 0.2 / 1000  # v: the one fold's and the others' distance from the mean
    assert s["tail_share"]["v"] == pytest.approx(far**2 / (far**2 + 999 * near**2))
    assert "the top 1 % hold" in describe_fold_statistics(s) and "99 % of u's spread" in describe_fold_statistics(s)
    hint = scale_hint(s)
    assert hint.startswith("hint: the top 1 % of folds set the standard deviation of u (99 % of its sum of squares) and v")
    assert scale_hint({**s, "tail_share": {"alpha": 0.0, "u": 0.7, "v": 0.62}}) is None  # the paper's corpus
    assert "encoding.scaling: robust" in hint
    assert scale_hint(s, "robust") is None
    normal = fold_statistics(rng.normal(0, 1, (200_000, 3)))
    phi = np.exp(-2.5758**2 / 2) / np.sqrt(2 * np.pi)
    assert normal["tail_share"]["u"] == pytest.approx(2 * (2.5758 * phi + 0.005), abs=0.005)
    assert scale_hint(normal) is None
    old = {k: v for k, v in s.items() if k != "tail_share"}  # a store written before tail shares
    assert scale_hint(old) is None and "top 1 %" not in describe_fold_statistics(old)


def test_ingest_and_encode_say_when_a_tail_sets_the_scale(tmp_path, capsys):
    """Delft's LoD1 blocks: the top 1 % of folds hold most of u's sum of squares; ingest and a
    standard encode say so, a robust encode does not."""
    from pipelines.cli import main

    store = tmp_path / "delft.zarr"
    assert main(["ingest", str(DELFT), "--out", str(store)]) == 0
    assert "hint: the top 1 % of folds set the standard deviation of u" in capsys.readouterr().out
    assert main(["encode", str(store), "--levels", "1"]) == 0
    assert "hint: the top 1 % of folds" in capsys.readouterr().out
    assert main(["encode", str(store), "--levels", "1", "--scaling", "robust"]) == 0
    assert "hint:" not in capsys.readouterr().out


def test_robust_scaling_equals_direct_numpy():
    from meshsom.standardize import robust_stats

    rng = np.random.default_rng(3)
    folds = np.stack([rng.uniform(0.5, 5.5, 900), rng.standard_t(2, 900), rng.lognormal(0, 1.5, 900)], axis=1)
    folds[:5, 2] = [500, 900, 1500, 2000, 3000]  # the tails of a centimetre edge
    st = robust_stats(folds, level=1, clip=4.0)
    # direct: median / IQR over 1.349; u centred at 0, its IQR over u and -u
    a, u, v = folds.T
    iqr = lambda z: np.subtract(*np.quantile(z, [0.75, 0.25]))  # noqa: E731
    centre = np.array([np.median(a), 0.0, np.median(v)])
    scale = np.array([iqr(a), iqr(np.concatenate([u, -u])), iqr(v)]) / 1.3489795003921634
    assert np.allclose(st.mean, centre) and np.allclose(st.std, scale)
    x = rng.normal(size=(20, 9)) * 50
    z = standardize(x, st.to_dict())
    direct = np.clip((x.reshape(20, 3, 3) - centre) / scale, -4.0, 4.0).reshape(20, 9)
    assert np.allclose(z, direct)
    inside = np.abs(direct) < 4.0
    assert np.allclose(destandardize(z, st)[inside], x[inside])
    # a mirror (sign flip of u) commutes with it
    mirror = np.tile([1.0, -1.0, 1.0], 3)
    assert np.allclose(standardize(x * mirror, st), z * mirror)
