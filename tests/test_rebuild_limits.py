"""Limits of the rebuild under the roofs (meshsom.envelope.rebuild_under_roofs).

Its time budget (``envelope_max_seconds``, nested in the mesh's own ``max_seconds``), and the refusal of
sheets that say nothing of where the ground is (a roof alone, a floor piece), against roofs over a ground
plate, whose volume is checked against the prism by hand.
"""

import time
from pathlib import Path

import numpy as np
import pytest

import meshsom.envelope as envelope
from meshsom.config import build
from meshsom.errors import MeshError
from meshsom.io import RawMesh, read_file
from meshsom.preprocess import PreprocessParams
from meshsom.time_limit import TimeLimitExceeded, time_limit
from pipelines.ingest import process_one

DATA = Path(__file__).resolve().parent / "data" / "rebuild_limits"

#: A gable roof over a 10 x 10 m plan: eaves along y = 0 and y = 10 at z = EAVE, ridge along y = 5 at z = EAVE + 3.
EAVE = 3.0
ROOF_VERTICES = [[0, 0, EAVE], [10, 0, EAVE], [10, 5, EAVE + 3], [0, 5, EAVE + 3], [0, 10, EAVE], [10, 10, EAVE]]
ROOF_FACES = [[0, 1, 2], [0, 2, 3], [3, 2, 5], [3, 5, 4]]
#: The ground plate under it at z = 0, facing down.
PLATE_VERTICES = [[0, 0, 0], [10, 0, 0], [10, 10, 0], [0, 10, 0]]
PLATE_FACES = [[6, 8, 7], [6, 9, 8]]


def _roof_and_plate() -> tuple[np.ndarray, np.ndarray]:
    """Roofs and a ground plate, no walls (open on every side), (10, 3) and (6, 3)."""
    return np.array(ROOF_VERTICES + PLATE_VERTICES, float), np.array(ROOF_FACES + PLATE_FACES, np.int64)


def _raw(vertices, faces, mesh_id="house") -> RawMesh:
    return RawMesh(mesh_id, "test", np.asarray(vertices, float), np.asarray(faces, np.int64), np.zeros(3))


#: By hand: the block under the eaves (10 x 10 x EAVE) and the gable's triangular prism (10 wide, 3 high, 10 long).
PRISM_VOLUME = 10 * 10 * EAVE + 0.5 * 10 * 3 * 10


def test_roofs_over_a_ground_plate_without_walls_rebuild_to_the_prism_by_hand():
    vertices, faces = _roof_and_plate()
    env, result = envelope.rebuild_under_roofs(vertices, faces, PreprocessParams(), "house")
    assert env.base == 0.0 and env.wall_faces == 0
    assert env.volume == pytest.approx(PRISM_VOLUME, rel=1e-9)
    assert result.volume_out == pytest.approx(PRISM_VOLUME, rel=1e-9)
    record, _ = process_one(_raw(vertices, faces), PreprocessParams())
    assert record["status"] == "accepted" and record["volume"] == pytest.approx(450.0, rel=1e-9)


@pytest.mark.parametrize("eave", [EAVE, 0.0])
def test_a_roof_alone_is_refused_as_saying_nothing_of_the_ground(eave):
    """The probe's roof_sheet_only.obj (eave 0) was accepted as 150 m3, standing on its own eaves."""
    vertices = np.array(ROOF_VERTICES, float) - [0, 0, EAVE - eave]
    with pytest.raises(MeshError, match="only roof faces: no wall or floor says where the ground is: its 4 faces are "
                                        "all roofs, none within 5 degrees of vertical and none lying on its lowest "
                                        r"vertex \(within preprocess.envelope_tol, 0.002 m\); a roof or floor sheet"):
        envelope.rebuild_under_roofs(vertices, np.array(ROOF_FACES), PreprocessParams(), "roof")
    record, clean = process_one(_raw(vertices, ROOF_FACES, "roof"), PreprocessParams())
    assert record["status"] == "rejected" and clean is None
    assert "rebuilding it as the solid under its roofs failed too (only roof faces" in record["reason"]


def test_a_wall_says_where_the_ground_is():
    """A roof with one gable wall down to z = 0 (and no plate): the wall says where the ground is."""
    vertices = np.array(ROOF_VERTICES + [[0, 0, 0], [0, 10, 0]], float)
    faces = np.array(ROOF_FACES + [[6, 0, 3], [6, 3, 7], [7, 3, 4]], np.int64)  # the west gable, 10 m wide
    env, _ = envelope.rebuild_under_roofs(vertices, faces, PreprocessParams(), "house")
    assert env.wall_faces == 3 and env.volume == pytest.approx(PRISM_VOLUME, rel=1e-9)


def test_the_probes_floor_piece_is_refused():
    """A Draco floor primitive of pg2b3dm's Delaware tile, tilted in its tile's frame: was 1,285 m3."""
    (raw,) = [m for m in read_file(DATA / "delaware_b0_floor_piece.obj") if isinstance(m, RawMesh)]
    record, clean = process_one(raw, PreprocessParams())
    assert record["status"] == "rejected" and clean is None
    assert "only roof faces: no wall or floor says where the ground is" in record["reason"]


def test_a_tiny_budget_rejects_a_normal_rebuild_naming_the_limit():
    vertices, faces = _roof_and_plate()
    with pytest.raises(MeshError, match=r"took more than 1e-09 s \(preprocess.envelope_max_seconds; raise it"):
        envelope.rebuild_under_roofs(vertices, faces, PreprocessParams(envelope_max_seconds=1e-9), "house")
    record, _ = process_one(_raw(vertices, faces), PreprocessParams(envelope_max_seconds=1e-9))
    assert record["status"] == "rejected"
    assert "; rebuilding it as the solid under its roofs failed too (took more than 1e-09 s" in record["reason"]
    # no budget: rebuilt
    envelope.rebuild_under_roofs(vertices, faces, PreprocessParams(envelope_max_seconds=0), "house")


def _slow_unite(monkeypatch, seconds, fail=False):
    unite = envelope._unite

    def slow(*args, **kwargs):
        time.sleep(seconds)
        if fail:
            raise MeshError("house", "non-manifold: 3 edges are shared by more than two faces")
        return unite(*args, **kwargs)

    monkeypatch.setattr(envelope, "_unite", slow)


def test_the_budget_ends_a_slow_rebuild_as_a_rejection(monkeypatch):
    _slow_unite(monkeypatch, 0.5)
    vertices, faces = _roof_and_plate()
    record, _ = process_one(_raw(vertices, faces), PreprocessParams(envelope_max_seconds=0.2, max_seconds=60))
    assert record["status"] == "rejected"
    assert "failed too (took more than 0.2 s (preprocess.envelope_max_seconds" in record["reason"]
    assert "0 of 8 ways of uniting its roof prisms tried" in record["reason"]


def test_the_meshs_own_max_seconds_wins_where_it_is_earlier(monkeypatch):
    _slow_unite(monkeypatch, 1.0)
    vertices, faces = _roof_and_plate()
    with time_limit(0.3), pytest.raises(TimeLimitExceeded) as err:
        envelope.rebuild_under_roofs(vertices, faces, PreprocessParams(envelope_max_seconds=30), "house")
    assert err.value.seconds == 0.3
    record, _ = process_one(_raw(vertices, faces), PreprocessParams(envelope_max_seconds=30, max_seconds=0.3))
    assert record["status"] == "rejected"
    assert record["reason"].startswith("preprocessing took more than 0.3 s")
    assert record["reason"].endswith("(preprocess.max_seconds; raise it, or 0 for no limit)")


def test_a_way_is_not_started_that_would_not_end_within_the_budget(monkeypatch):
    """Each way fails after 0.3 s: the ways stop where the next would run past the 1 s budget."""
    _slow_unite(monkeypatch, 0.3, fail=True)
    vertices, faces = _roof_and_plate()
    start = time.monotonic()
    with pytest.raises(MeshError, match=r"would take more than 1 s \(preprocess.envelope_max_seconds.*: [2-3] of 8 ways "
                                        r"of uniting its roof prisms tried in .* as each took up to 0.3 s; the first "
                                        r"failed: non-manifold: 3 edges"):
        envelope.rebuild_under_roofs(vertices, faces, PreprocessParams(envelope_max_seconds=1.0), "house")
    assert time.monotonic() - start < 1.0 + 0.3


@pytest.mark.parametrize("value", [-1, float("inf"), True, "10"])
def test_the_budget_is_validated(value):
    with pytest.raises(ValueError, match="envelope_max_seconds must be a finite number >= 0"):
        PreprocessParams(envelope_max_seconds=value)


def test_the_budget_comes_from_the_config():
    params = build(PreprocessParams, {"envelope_max_seconds": 12.5}, "preprocess")
    assert params.envelope_max_seconds == 12.5 and PreprocessParams().envelope_max_seconds == 90.0
