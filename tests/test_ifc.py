"""IFC building models (meshsom.ifc): one envelope per IfcBuilding, from files IfcOpenShell writes as
BIM tools do (tests/ifc_models.py), checked against the sizes the models were written with."""

from __future__ import annotations

import gzip
import math
import zipfile

import numpy as np
import pytest

from ifc_models import CRS_NAME, EASTINGS, GARAGE, GARAGE_AT, HEIGHT, HOUSE, NORTHINGS, ROTATION_DEG, write_house
from meshsom.errors import MeshError
from meshsom.ifc import winding_number
from meshsom.io import RawMesh, ReaderOptions, Rejection, read_file
from meshsom.offset import mitered_offset
from meshsom.preprocess import close_surface, preprocess, validate
from meshsom.topology import edge_table, signed_volume

pytest.importorskip("ifcopenshell")


def _meshes(path, options=ReaderOptions()):
    items = list(read_file(path, options))
    return [m for m in items if isinstance(m, RawMesh)], [m for m in items if isinstance(m, Rejection)]


def _volumes(meshes):
    return sorted(round(signed_volume(m.vertices, m.faces), 6) for m in meshes)


HOUSE_VOLUME = math.prod(HOUSE)
GARAGE_VOLUME = math.prod(GARAGE)


@pytest.fixture(scope="module")
def models(tmp_path_factory):
    folder = tmp_path_factory.mktemp("ifc")
    return {schema: write_house(folder / f"house_{schema}.ifc", schema=schema) for schema in ("IFC4", "IFC2X3")}


@pytest.mark.parametrize("schema", ["IFC4", "IFC2X3"])
def test_each_building_is_the_closed_envelope_of_its_walls_slabs_and_roof(models, schema):
    """Two IfcBuildings, two meshes: the house is its outer box (walls, floor and roof slabs; the
    windows and the door in their openings), without its rooms (an inner shell, dropped), the
    free-standing column inside, the table and the IfcSpace (not envelope classes), or the
    site's terrain; the garage likewise. Volumes as written, each a single closed shell."""
    meshes, rejected = _meshes(models[schema])
    assert not rejected and len(meshes) == 2
    assert _volumes(meshes) == pytest.approx(sorted([HOUSE_VOLUME, GARAGE_VOLUME]), rel=1e-4)
    for m in meshes:
        assert m.id.startswith(f"house_{schema}.ifc#") and len(m.id.split("#")[1]) == 22  # GlobalId
        _, _, counts = edge_table(m.faces)
        assert (counts == 2).all() and validate(m.vertices, m.faces) is None
        notes = " | ".join(m.notes)
        assert "shells inside the envelope not kept" in notes, notes
        assert "IfcFurni" not in notes and "IfcSpace" not in notes and "IfcOpening" not in notes
        r = preprocess(m.vertices, m.faces)
        assert r.volume_out == pytest.approx(signed_volume(m.vertices, m.faces), rel=1e-4)
    house = max(meshes, key=lambda m: signed_volume(m.vertices, m.faces))
    assert "IfcWindow" in " ".join(house.notes) and "IfcColumn" in " ".join(house.notes)
    assert "1 shells inside" not in " ".join(house.notes)  # the rooms and the column: 2 (or more)


def test_a_map_conversion_places_the_buildings_in_its_crs(models):
    """IFC4's IfcMapConversion: the project's x axis turned by the given angle, moved to eastings,
    northings and height; the CRS named in the notes. The IFC2X3 file stays in its own frame."""
    a = math.radians(ROTATION_DEG)
    turn = np.array([[math.cos(a), -math.sin(a), 0], [math.sin(a), math.cos(a), 0], [0, 0, 1]])
    shift = np.array([EASTINGS, NORTHINGS, HEIGHT])
    local_centres = {  # bounding-box centres in the project's frame (slabs from -0.3 or -0.2)
        round(HOUSE_VOLUME, 6): np.array([HOUSE[0] / 2, HOUSE[1] / 2, HOUSE[2] / 2 - 0.3]),
        round(GARAGE_VOLUME, 6): np.array([GARAGE_AT[0] + GARAGE[0] / 2, GARAGE_AT[1] + GARAGE[1] / 2, GARAGE[2] / 2 - 0.2]),
    }
    for schema, placed in (("IFC4", True), ("IFC2X3", False)):
        meshes, _ = _meshes(models[schema])
        for m in meshes:
            local = local_centres[min(local_centres, key=lambda k: abs(k - signed_volume(m.vertices, m.faces)))]
            world = m.vertices + m.origin
            centre = (world.min(axis=0) + world.max(axis=0)) / 2
            if placed:
                corners = np.array(np.meshgrid(*[[-1, 1]] * 3)).reshape(3, -1).T  # the turned box's extent
                half = np.array(HOUSE if local[0] < 8 else GARAGE) / 2
                extent = np.abs((corners * half) @ turn.T).max(axis=0)
                assert centre == pytest.approx(turn @ local + shift, abs=0.01)  # within the gap closed
                assert (world.max(axis=0) - world.min(axis=0)) / 2 == pytest.approx(extent, abs=0.01)
                assert any(CRS_NAME in n and "30 degrees" in n for n in m.notes), m.notes
            else:
                assert centre == pytest.approx(local, abs=0.01)
                assert any("no IfcMapConversion" in n for n in m.notes)


def test_hairline_gaps_between_elements_are_closed(tmp_path):
    """A roof slab 3 mm above the walls' tops (as BIM models leave them): with the default
    ``ifc_gap`` (1 cm) the house is one closed box (its volume plus the gap's); with 0 the rooms
    lead out through the gap, so no room is dropped and the envelope is the walls, floor and roof
    as separate walls around empty rooms: far less volume."""
    path = write_house(tmp_path / "gap.ifc", garage=False, roof_gap=0.003)
    closed, _ = _meshes(path)
    open_, _ = _meshes(path, ReaderOptions(ifc_gap=0.0))
    assert len(closed) == len(open_) == 1
    box = HOUSE[0] * HOUSE[1] * (HOUSE[2] + 0.003)
    assert signed_volume(closed[0].vertices, closed[0].faces) == pytest.approx(box, rel=1e-4)
    assert signed_volume(open_[0].vertices, open_[0].faces) < 0.5 * box
    assert not any("inside the envelope" in n for n in open_[0].notes)


def test_gzipped_and_zipped_ifc_read_alike(models, tmp_path):
    plain = models["IFC4"].read_bytes()
    (tmp_path / "house.ifc.gz").write_bytes(gzip.compress(plain))
    with zipfile.ZipFile(tmp_path / "house.ifczip", "w") as z:
        z.writestr("model/house.ifc", plain)
    ref = _volumes(_meshes(models["IFC4"])[0])
    assert _volumes(_meshes(tmp_path / "house.ifc.gz")[0]) == ref
    assert _volumes(_meshes(tmp_path / "house.ifczip")[0]) == ref


def test_bad_ifc_files_are_rejected_with_reasons(tmp_path, models):
    (tmp_path / "notes.ifc").write_text("Revit export failed\n")
    (tmp_path / "cut.ifc").write_bytes(models["IFC4"].read_bytes()[:3000])
    with zipfile.ZipFile(tmp_path / "two.ifczip", "w") as z:
        z.writestr("a.ifc", "x")
        z.writestr("b.ifc", "y")
    reasons = {p: [r.reason for r in _meshes(tmp_path / p)[1]] for p in ("notes.ifc", "cut.ifc", "two.ifczip")}
    assert "not an IFC file" in reasons["notes.ifc"][0] and "ISO-10303-21" in reasons["notes.ifc"][0]
    assert reasons["cut.ifc"][0].startswith("truncated: an IFC file ends with 'END-ISO-10303-21'")
    assert "must hold one .ifc file; it holds 2" in reasons["two.ifczip"][0]
    # only furniture and spaces: no envelope, the classes it holds named
    only = _meshes(models["IFC4"], ReaderOptions(ifc_classes=("IfcRailing",)))[1]
    assert len(only) == 1 and "without elements of the envelope classes (IfcRailing)" in only[0].reason
    assert "IfcWall" in only[0].reason  # what the file does hold


def test_elements_under_no_building_are_one_model(tmp_path):
    """A file whose elements stand in a storey of no IfcBuilding (tools that write storeys only)
    is one mesh of all of them, id ``file#model``."""
    path = write_house(tmp_path / "nobuilding.ifc", garage=False, building=False)
    meshes, rejected = _meshes(path)
    assert not rejected and [m.id for m in meshes] == ["nobuilding.ifc#model"]
    assert signed_volume(meshes[0].vertices, meshes[0].faces) == pytest.approx(HOUSE_VOLUME, rel=1e-4)


def test_ifc_through_ingest(models, tmp_path):
    """``meshsom ingest`` stores both buildings of each file, with the reader's notes."""
    import json

    from pipelines.cli import main

    assert main(["ingest", str(models["IFC4"]), str(models["IFC2X3"]), "--out", str(tmp_path / "s.zarr")]) == 0
    manifest = json.loads((tmp_path / "s.zarr" / "manifest.json").read_text())
    accepted = [r for r in manifest["records"] if r["status"] == "accepted"]
    assert len(accepted) == 4, manifest["records"]
    assert all(any(n.startswith("IFC: the union of") for n in r["notes"]) for r in accepted)


# ----------------------------------------------------------------------------- the offset, the winding number

def _box(lo, hi):
    from conftest import box

    v, f = box(*(np.asarray(hi, float) - lo))
    return v + lo, f


def test_mitered_offset_moves_every_plane_by_the_distance():
    """A box turned about two axes, offset by d: a box d larger on every side (its volume by
    formula); by -d back to the start; a thin plate shrunk by more than half its thickness turns
    over (the reader checks for that)."""
    v, f = _box([0, 0, 0], [3, 2, 1])
    a, b = 0.4, 1.1
    turn = np.array([[math.cos(a), -math.sin(a), 0], [math.sin(a), math.cos(a), 0], [0, 0, 1]]) @ np.array(
        [[1, 0, 0], [0, math.cos(b), -math.sin(b)], [0, math.sin(b), math.cos(b)]])
    v = v @ turn.T + [100.0, -50.0, 7.0]
    d = 0.01
    grown = mitered_offset(v, f, d)
    assert signed_volume(grown, f) == pytest.approx(3.02 * 2.02 * 1.02, rel=1e-12)
    assert mitered_offset(grown, f, -d) == pytest.approx(v, abs=1e-9)
    plate, pf = _box([0, 0, 0], [1, 1, 0.004])
    assert signed_volume(mitered_offset(plate, pf, -0.003), pf) < 0


def test_mitered_offset_of_a_sharp_tip_is_limited():
    """A needle-like pyramid: its tip's exact offset point runs far out; it moves at most three
    distances (the miter limit), the base corners (three planes) exactly."""
    base = np.array([[0, 0, 0], [0.1, 0, 0], [0.1, 0.1, 0], [0, 0.1, 0]], float)
    v = np.vstack([base, [[0.05, 0.05, 10.0]]])
    f = np.array([[0, 2, 1], [0, 3, 2], [0, 1, 4], [1, 2, 4], [2, 3, 4], [3, 0, 4]])
    moved = mitered_offset(v, f, 0.01)
    assert np.linalg.norm(moved[4] - v[4]) == pytest.approx(0.03)
    assert moved[0, 2] == pytest.approx(-0.01)


def test_winding_number_inside_and_outside():
    v, f = _box([0, 0, 0], [2, 2, 2])
    assert winding_number(np.array([1.0, 1, 1]), v, f) == pytest.approx(1.0)
    assert winding_number(np.array([3.0, 1, 1]), v, f) == pytest.approx(0.0, abs=1e-12)
    assert winding_number(np.array([1.0, 1, 1]), v, f[:, ::-1]) == pytest.approx(-1.0)


def test_close_surface_closes_without_cleaning_folds():
    """The element check (steps 1-4 only): a box without its floor is capped; a mesh that cannot
    be closed is a MeshError."""
    v, f = _box([0, 0, 0], [1, 1, 1])
    floor = [k for k in range(len(f)) if (v[f[k], 2] == 0).all()]
    cv, cf = close_surface(v, np.delete(f, floor, axis=0))
    assert signed_volume(cv, cf) == pytest.approx(1.0)
    with pytest.raises(MeshError):
        close_surface(v, f[:3])
