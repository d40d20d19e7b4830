import numpy as np
import pytest
import trimesh

from meshsom.generate import BLOCK_FAMILIES, ROOF_FAMILIES, GeneratorParams, generate_corpus


def test_every_family_is_closed_outward_and_labelled():
    params = GeneratorParams(n_blocks=30, seed=3, families=BLOCK_FAMILIES + ROOF_FAMILIES)
    blocks = generate_corpus(params)
    assert [b.label for b in blocks[:10]] == list(BLOCK_FAMILIES + ROOF_FAMILIES)
    for b in blocks:
        m = trimesh.Trimesh(b.vertices, b.faces, process=False)
        assert m.is_watertight, b.label
        assert m.is_winding_consistent, b.label
        assert m.volume > 0, b.label
        lo, hi = params.height_range
        assert lo <= b.vertices[:, 2].max() - b.vertices[:, 2].min()


def test_same_seed_same_corpus_other_seed_differs():
    a = generate_corpus(GeneratorParams(n_blocks=5, seed=1))
    b = generate_corpus(GeneratorParams(n_blocks=5, seed=1))
    c = generate_corpus(GeneratorParams(n_blocks=5, seed=2))
    assert all(np.array_equal(x.vertices, y.vertices) for x, y in zip(a, b))
    assert not all(np.array_equal(x.vertices, y.vertices) for x, y in zip(a, c) if x.vertices.shape == y.vertices.shape)


def test_courtyard_has_a_hole_and_l_block_has_six_corners():
    blocks = generate_corpus(GeneratorParams(n_blocks=5, seed=0, rotate=False, families=("courtyard", "L")))
    court = next(b for b in blocks if b.label == "courtyard")
    m = trimesh.Trimesh(court.vertices, court.faces, process=True)
    assert m.euler_number == 0  # a torus: genus 1
    l_block = next(b for b in blocks if b.label == "L")
    assert len(l_block.vertices) == 12 and len(l_block.faces) == 20


def test_invalid_parameters_name_the_field():
    with pytest.raises(ValueError, match="unknown family 'igloo'"):
        GeneratorParams(families=("igloo",))
    with pytest.raises(ValueError, match="height_range"):
        GeneratorParams(height_range=(5.0, 1.0))


def test_a_slice_of_the_corpus_equals_the_same_blocks_of_the_whole():
    params = GeneratorParams(n_blocks=12, seed=5)
    whole = generate_corpus(params)
    part = generate_corpus(params, indices=range(7, 12))
    assert [b.id for b in part] == [b.id for b in whole[7:]]
    assert all(np.array_equal(a.vertices, b.vertices) for a, b in zip(part, whole[7:]))
