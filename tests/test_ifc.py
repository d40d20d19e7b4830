"""IFC building models (meshsom.ifc): one envelope per IfcBuilding, from files IfcOpenShell writes as
BIM tools do (tests/ifc_models.py), checked against the sizes the models were written with."""

from __future__ import annotations

import gzip
import math
import zipfile

import numpy as np
import pytest

from ifc_models import (CRS_NAME, EASTINGS, GARAGE, GARAGE_AT, HEIGHT, HOUSE, NORTHINGS, ROTATION_DEG, write_house,
                        write_mitred_house)
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
        union = next(n for n in m.notes if n.startswith("IFC: the union of"))
        assert "IfcFurni" not in union and "IfcSpace" not in notes and "IfcOpening" not in notes
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


def _edited(path, out, edit):
    """A copy of an IFC file with ``edit(model)`` applied (as another exporter would have written it)."""
    import ifcopenshell

    model = ifcopenshell.open(str(path))
    edit(model)
    model.write(str(out))
    return out


def _centre(m):
    world = m.vertices + m.origin
    return (world.min(axis=0) + world.max(axis=0)) / 2


#: The house's bounding-box centre in the project's frame (its slabs from -0.3).
HOUSE_CENTRE = np.array([HOUSE[0] / 2, HOUSE[1] / 2, HOUSE[2] / 2 - 0.3])


def _house(meshes):
    return max(meshes, key=lambda m: signed_volume(m.vertices, m.faces))


def _turn(degrees):
    a = math.radians(degrees)
    return np.array([[math.cos(a), -math.sin(a), 0], [math.sin(a), math.cos(a), 0], [0, 0, 1]])


def test_a_map_conversion_in_a_millimetre_project_keeps_the_building_in_metres(models, tmp_path):
    """The test files are millimetre projects (IfcOpenShell's default) on a metre CRS. Written as
    the schema asks (Scale 0.001, the ratio of the units) or as exporters often do (Scale 1), the
    house keeps its size in metres at the eastings and northings; an x axis along the map's north
    (XAxisAbscissa 0, XAxisOrdinate 1) is a quarter turn, not an unturned axis; a grid scale of
    0.9996 over the unit ratio is applied."""
    import ifcopenshell.util.unit

    assert ifcopenshell.util.unit.calculate_unit_scale(ifcopenshell.open(str(models["IFC4"]))) == 0.001

    def quarter_turn(scale):
        def edit(model):
            c = model.by_type("IfcMapConversion")[0]
            c.XAxisAbscissa, c.XAxisOrdinate, c.Scale = 0.0, 1.0, scale
        return edit

    shift = np.array([EASTINGS, NORTHINGS, HEIGHT])
    for scale, grid in ((0.001, 1.0), (1.0, 1.0), (0.0009996, 0.9996)):
        path = _edited(models["IFC4"], tmp_path / f"turned_{scale}.ifc", quarter_turn(scale))
        house = _house(_meshes(path)[0])
        world = house.vertices + house.origin
        assert _centre(house) == pytest.approx(grid * (_turn(90) @ HOUSE_CENTRE) + shift, abs=0.01)
        size = world.max(axis=0) - world.min(axis=0)  # x along the map's north: length and width swap
        assert size == pytest.approx(grid * np.array([HOUSE[1], HOUSE[0], HOUSE[2]]) + 0.0, abs=0.02)
        notes = " | ".join(house.notes)
        assert "x axis turned 90 degrees" in notes and "in its CRS's unit (metre)" in notes, notes
        assert ("keeps its size in metres" in notes) == (scale == 1.0), notes


def test_an_ifc2x3_map_conversion_property_set_places_the_building(models, tmp_path):
    """IFC2X3 has no IfcMapConversion; buildingSMART's georeferencing guide puts its attributes in
    the project's ePSet_MapConversion and the CRS in ePSet_ProjectedCRS (here with its MapUnit
    named). Read like IFC4's; the file's site coordinates are then not used."""
    import ifcopenshell.api.pset

    def edit(model):
        project = model.by_type("IfcProject")[0]
        conversion = ifcopenshell.api.pset.add_pset(model, product=project, name="ePSet_MapConversion")
        a = math.radians(-40.0)
        ifcopenshell.api.pset.edit_pset(model, pset=conversion, properties={
            "Eastings": 1000.0 * EASTINGS, "Northings": 1000.0 * NORTHINGS, "OrthogonalHeight": 1000.0 * HEIGHT,
            "XAxisAbscissa": math.cos(a), "XAxisOrdinate": math.sin(a), "Scale": 1.0})
        crs = ifcopenshell.api.pset.add_pset(model, product=project, name="ePSet_ProjectedCRS")
        ifcopenshell.api.pset.edit_pset(model, pset=crs, properties={"Name": CRS_NAME, "MapUnit": "MILLIMETRE"})
        model.by_type("IfcSite")[0].RefLatitude = (52, 0, 0, 0)
        model.by_type("IfcSite")[0].RefLongitude = (5, 0, 0, 0)

    house = _house(_meshes(_edited(models["IFC2X3"], tmp_path / "pset.ifc", edit))[0])
    assert _centre(house) == pytest.approx(_turn(-40) @ HOUSE_CENTRE + [EASTINGS, NORTHINGS, HEIGHT], abs=0.01)
    notes = " | ".join(house.notes)
    assert "placed by its ePSet_MapConversion in EPSG:25832" in notes and "MapUnit 'MILLIMETRE'" in notes, notes
    assert "keeps its size" not in notes  # Scale 1: millimetres on millimetres


@pytest.mark.parametrize("latitude,longitude,north_deg", [
    ((49, 6, 1, 566000), (8, 26, 11, 540400), 0.0),      # FZK-Haus's site, true north along y
    ((41, 52, 27, 840000), (-87, -38, -21, -839999), 25.0),  # the Duplex's, true north turned
    ((-33, -55, 0), (18, 25, 0), -10.0),                  # the southern hemisphere
])
def test_a_site_reference_point_places_the_building_in_its_utm_zone(models, tmp_path, latitude, longitude, north_deg):
    """Most IFC files (and every IFC2X3 one without the property set) place the project only by
    its IfcSite's RefLatitude, RefLongitude and RefElevation, at the site's own origin, with true
    north in the model context. The house lands in WGS 84's UTM zone there: the site origin at the
    projected point, turned by the meridian convergence (pyproj's) less true north's turn."""
    import ifcopenshell.util.unit
    import pyproj

    def degrees(parts):
        sign = -1 if any(p < 0 for p in parts) else 1
        return sign * sum(abs(p) / u for p, u in zip(parts, (1, 60, 3600, 3600e6)))

    def edit(model):
        site = model.by_type("IfcSite")[0]
        site.RefLatitude, site.RefLongitude = latitude, longitude
        site.RefElevation = 110.0 / ifcopenshell.util.unit.calculate_unit_scale(model)  # in project units
        t = math.radians(north_deg)
        for context in model.by_type("IfcGeometricRepresentationContext", include_subtypes=False):
            context.TrueNorth = model.createIfcDirection((-math.sin(t), math.cos(t)))

    house = _house(_meshes(_edited(models["IFC2X3"], tmp_path / "site.ifc", edit))[0])
    lat, lon = degrees(latitude), degrees(longitude)
    zone = int((lon + 180) // 6) + 1
    epsg = (32600 if lat > 0 else 32700) + zone
    east, north = pyproj.Transformer.from_crs("EPSG:4326", f"EPSG:{epsg}", always_xy=True).transform(lon, lat)
    convergence = pyproj.Proj(f"EPSG:{epsg}").get_factors(lon, lat).meridian_convergence
    site_origin = np.array([0.0, 0.0, -0.8])  # where tests/ifc_models.py puts the site
    expected = _turn(convergence - north_deg) @ (HOUSE_CENTRE - site_origin) + [east, north, 110.0]
    assert _centre(house) == pytest.approx(expected, abs=0.01)
    assert any(f"(EPSG:{epsg})" in n and "reference point of IfcSite 'site'" in n for n in house.notes), house.notes


def test_a_site_at_latitude_and_longitude_zero_is_not_a_place(models, tmp_path):
    def edit(model):
        site = model.by_type("IfcSite")[0]
        site.RefLatitude, site.RefLongitude = (0, 0, 0), (0, 0, 0)

    house = _house(_meshes(_edited(models["IFC2X3"], tmp_path / "zero.ifc", edit))[0])
    assert _centre(house) == pytest.approx(HOUSE_CENTRE, abs=0.01)
    assert any("0, 0 (an exporter's default" in n and "project's own frame" in n for n in house.notes), house.notes


def test_hairline_gaps_between_elements_are_closed(tmp_path):
    """A roof slab 3 mm above the walls' tops (as BIM models leave them): with the default
    ``ifc_gap`` (1 cm) the house is one closed box (its volume plus the gap's); with 0 the rooms
    lead out through the gap, so no room is enclosed: the union is the walls, floor and roof
    alone, no envelope, and the building is a rejection saying so (it was accepted as that union,
    far less than the box)."""
    path = write_house(tmp_path / "gap.ifc", garage=False, roof_gap=0.003)
    closed, _ = _meshes(path)
    open_, (rejection,) = _meshes(path, ReaderOptions(ifc_gap=0.0))
    assert len(closed) == 1 and not open_
    box = HOUSE[0] * HOUSE[1] * (HOUSE[2] + 0.003)
    assert signed_volume(closed[0].vertices, closed[0].faces) == pytest.approx(box, rel=1e-4)
    assert "IfcBuilding 'house': its " in rejection.reason and "enclose no room" in rejection.reason
    assert "ifc_gap, 0 mm" in rejection.reason, rejection.reason


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
    is one mesh of all of them, id ``file#model``, noted with the elements it holds (a single covering or beam
    exported alone is such a file too: the note says what was read as a building)."""
    path = write_house(tmp_path / "nobuilding.ifc", garage=False, building=False)
    meshes, rejected = _meshes(path)
    assert not rejected and [m.id for m in meshes] == ["nobuilding.ifc#model"]
    assert signed_volume(meshes[0].vertices, meshes[0].faces) == pytest.approx(HOUSE_VOLUME, rel=1e-4)
    note = next(n for n in meshes[0].notes if n.startswith("the file has no IfcBuilding"))
    assert "element(s) read as one building" in note and "IfcWall" in note, note


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


def test_a_project_library_beside_the_project_keeps_the_building_in_metres(models, tmp_path):
    """IfcOpenShell's own test models declare an IfcProjectLibrary beside the IfcProject: its kernel then finds "not
    a single project or context" and leaves the millimetre coordinates unconverted. The reader scales them by the
    project's length unit, says so, and the house has the size it was written with."""
    def library(model):
        model.createIfcProjectLibrary(model.by_type("IfcProject")[0].GlobalId[:-1] + "L", None, "Library")

    plain = _house(_meshes(models["IFC4"])[0])
    path = _edited(models["IFC4"], tmp_path / "library.ifc", library)
    house = _house(_meshes(path)[0])
    size = np.ptp(house.vertices, axis=0)
    np.testing.assert_allclose(size, np.ptp(plain.vertices, axis=0), atol=1e-6)
    assert any("scaled to metres by its length unit (0.001 m)" in n for n in house.notes), house.notes
    assert signed_volume(house.vertices, house.faces) == pytest.approx(signed_volume(plain.vertices, plain.faces), rel=1e-9)


def test_the_union_of_many_elements_is_batched_and_bounded_in_time():
    """The elements are united UNION_BATCH at a time, then the batches' unions: 150 overlapping beams unite into
    their one volume; past the time allowed (checked between batches) the union stops with a MeshError saying so,
    where one batch union of a roof of 5,178 beams ran for hours."""
    from meshsom.ifc import UNION_BATCH, _united
    from meshsom.union import _manifold3d

    manifold3d = _manifold3d()
    beams = [manifold3d.Manifold.cube([10.0, 0.2, 0.3]).translate([0.05 * k, 0.1 * (k % 2), 0.0]) for k in range(150)]
    assert len(beams) > 2 * UNION_BATCH
    united = _united(beams, "roof.ifc#model", 0, manifold3d)
    # 0.3 m across where both rows of beams are, 0.2 m for the first and last 5 cm: (17.45 x 0.3 - 2 x 0.05 x 0.1) x 0.3 m
    assert united.volume() == pytest.approx(((10 + 0.05 * 149) * 0.3 - 2 * 0.05 * 0.1) * 0.3, rel=1e-9)
    with pytest.raises(MeshError, match=r"took more than 1e-09 s .* pieces left"):
        _united(beams, "roof.ifc#model", 1e-9, manifold3d)


def test_a_building_without_envelope_elements_is_a_rejection(tmp_path):
    """A second IfcBuilding holding only a space (a garage whose walls were not modelled, as BIM2SIM's ExampleHOM was
    probed with) was left out without a word, where the module says such buildings are rejected by name: it is a
    rejection naming the classes it holds; the other building is read as before."""
    import ifcopenshell
    import ifcopenshell.api.aggregate
    import ifcopenshell.api.root

    path = write_house(tmp_path / "two.ifc", garage=False)
    model = ifcopenshell.open(str(path))
    site = model.by_type("IfcSite")[0]
    garage = ifcopenshell.api.root.create_entity(model, ifc_class="IfcBuilding", name="Garage (no walls)")
    ifcopenshell.api.aggregate.assign_object(model, products=[garage], relating_object=site)
    space = ifcopenshell.api.root.create_entity(model, ifc_class="IfcSpace", name="Parking")
    ifcopenshell.api.aggregate.assign_object(model, products=[space], relating_object=garage)
    model.write(str(path))
    meshes, rejected = _meshes(path)
    assert len(meshes) == 1 and signed_volume(meshes[0].vertices, meshes[0].faces) == pytest.approx(HOUSE_VOLUME, rel=1e-4)
    (garage_rejection,) = rejected
    assert garage_rejection.id == f"two.ifc#{garage.GlobalId}"
    assert "IfcBuilding 'Garage (no walls)' holds no element of the envelope classes" in garage_rejection.reason
    assert "1 IfcSpace" in garage_rejection.reason


@pytest.mark.parametrize("gap", [0.0, 0.003])
def test_the_growth_is_undone_on_walls_that_meet_in_mitres(tmp_path, gap):
    """Walls joined in 45-degree mitres (as ArchiCAD's FZK-Haus joins them), grown by 5 mm and united, leave a
    chamfer at every corner whose planes meet far out: moving the union's vertices back along their own normals
    (limited to three distances) turned faces over, so the house stayed grown, 1.4 m3 (0.5 %) too large, as
    FZK-Haus stayed 616.78 m3 where its elements unite into 614.26. Each face moved back onto the plane of the
    element face it lies on gives the box as drawn (its roof ``gap`` above the walls closed), one valid shell."""
    size = (9.0, 7.0, 3.4)
    path = write_mitred_house(tmp_path / "mitred.ifc", size=size, gap=gap)
    (house,), rejected = _meshes(path)
    assert not rejected
    assert signed_volume(house.vertices, house.faces) == pytest.approx(size[0] * size[1] * (size[2] + gap), rel=1e-9)
    assert np.ptp(house.vertices, axis=0) == pytest.approx([size[0], size[1], size[2] + gap], abs=1e-9)
    assert validate(house.vertices, house.faces) is None and not house.parts
    assert not any("outside the elements' faces" in n for n in house.notes), house.notes


def test_a_structural_model_is_a_rejection_saying_so(tmp_path, monkeypatch):
    """A steel frame (Tekla's, cadwork's, GeometryGym's test models: beams, columns, members, plates and no wall,
    slab, roof, curtain wall or covering) encloses nothing: it was handed on as the union of its bars (thin steel
    grown by 5 mm, +84 %) and rejected by preprocessing for folds or edges of more than two faces, reasons that
    come from the hand-off. It is a rejection naming what it holds; with only framing classes asked for, the frame
    is read (as the union of its bars: volume by hand). It is told before its elements are triangulated."""
    from ifc_models import write_frame

    import meshsom.ifc

    path = write_frame(tmp_path / "frame.ifc", bays=2, span=6.0, height=4.0, section=0.3)
    triangulated = []
    real = meshsom.ifc._triangulated
    monkeypatch.setattr(meshsom.ifc, "_triangulated", lambda model, elements, ifc: triangulated.extend(elements)
                        or real(model, elements, ifc))
    meshes, (rejection,) = _meshes(path)
    assert triangulated == []  # told by its classes (Tekla's costmodell: 4,319 elements, 418 s of union before)
    monkeypatch.setattr(meshsom.ifc, "_triangulated", real)
    assert not meshes and rejection.id.startswith("frame.ifc#")
    assert "IfcBuilding 'hall frame': a structural model, 13 framing elements (7 IfcBeam, 6 IfcColumn)" in rejection.reason
    assert "no IfcWall, IfcSlab, IfcRoof, IfcCurtainWall, IfcCovering" in rejection.reason

    def unnamed(model):
        model.by_type("IfcBuilding")[0].Name = None

    (rejection,) = _meshes(_edited(path, tmp_path / "unnamed.ifc", unnamed))[1]  # was called "the model"
    assert rejection.reason.startswith("its IfcBuilding (no name): a structural model"), rejection.reason
    (frame,), _ = _meshes(path, ReaderOptions(ifc_classes=("IfcBeam", "IfcColumn")))
    columns = 6 * 0.3 * 0.3 * 4.0
    beams = 3 * 0.3 * 0.3 * 6.3 + 4 * 0.3 * 0.3 * 5.7
    assert signed_volume(frame.vertices, frame.faces) == pytest.approx(columns + beams, rel=1e-9)
    assert any("enclose no room" in n for n in frame.notes), frame.notes


def test_untyped_building_elements_are_read_and_what_is_left_out_is_noted(models, tmp_path):
    """cadwork writes insulation, battens and boards as instances of the abstract IfcBuildingElement; they were
    left out without a word (a house whose wall is one has a hole to its rooms). They are read as proxies, with a
    note saying so; the elements of other classes left out (the table) are counted in a note."""
    text = models["IFC2X3"].read_text()
    wall = next(line for line in text.splitlines() if "=IFCWALL(" in line and "'IfcWall'" in line)
    path = tmp_path / "untyped.ifc"
    path.write_text(text.replace(wall, wall.replace("=IFCWALL(", "=IFCBUILDINGELEMENT(")))
    meshes, rejected = _meshes(path)
    assert not rejected
    assert _volumes(meshes) == pytest.approx(sorted([HOUSE_VOLUME, GARAGE_VOLUME]), rel=1e-6)
    notes = " | ".join(_house(meshes).notes)
    assert "IFC: 1 elements of the abstract class IfcBuildingElement" in notes and "IfcBuildingElementProxy" in notes
    assert "1 IfcBuildingElement" in notes  # in the union's count
    assert "IFC: 1 elements not of the envelope classes left out (1 IfcFurnishingElement)" in notes, notes


def test_a_sliver_that_collapses_onto_a_line_is_not_a_fold():
    """Where grown elements meet flush (storeys stacked, BlenderBIM's ExampleHOM), the union has slivers 1e-7 m
    high along its edges; moved back, their corners meet on a line and rounding gives them either side. Counted
    as folds by their area (3 m long, 1e-6 m high: 1.5e-6 m2 over the old limit of (0.01 x 5 mm)^2), they kept
    ExampleHOM, b03 and 3rooms grown by 5 mm (+0.3 %); by their height they are not, and a face truly turned
    over (1 mm high) still is."""
    from meshsom.ifc import SLIVER_HEIGHT, _turned_over

    distance = 0.005
    v = np.array([[0.0, 0, 0], [3.0, 0, 0], [1.5, 1e-6, 0], [0, 0, 0], [3.0, 0, 0], [1.5, -1e-3, 0]])
    f = np.array([[0, 1, 2], [3, 4, 5]])
    before = np.array([[0.0, 0, 1], [0.0, 0, -1]])
    assert _turned_over(before, v, f, SLIVER_HEIGHT * distance).tolist() == [False, False]  # as they stood
    # both stood the other way before: the sliver (1e-6 m high) is no fold, the face 1 mm high is
    assert _turned_over(-before, v, f, SLIVER_HEIGHT * distance).tolist() == [False, True]
    area = np.linalg.norm(np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]]), axis=1) / 2
    assert area[0] == pytest.approx(1.5e-6) and area[0] > (0.01 * distance) ** 2  # the old criterion's fold


def test_a_shell_of_elements_drawn_flat_shrinks_to_nothing():
    """A sheet drawn without thickness (aalseth's Revit model has two) is a solid only once grown by the gap
    closing: moved back onto its planes nothing is left, and it is dropped (was: kept 5 mm grown, a flat box
    that preprocessing found folded). A sheet 2 mm thick comes back 2 mm thick."""
    from meshsom.ifc import _face_planes, _plane_groups, _shrunk
    from meshsom.union import _manifold3d

    manifold3d = _manifold3d()
    distance = 0.005
    for thickness, volume in ((0.0, 0.0), (0.002, 2.0 * 1.0 * 0.002)):
        v, f = _box([0, 0, 0], [2.0, 1.0, max(thickness, 1e-12)])
        v[:, 2] = np.where(v[:, 2] > 0, thickness, 0.0)
        normals, offsets, plane_of = _plane_groups([_face_planes(*_box([0, 0, 0], [2.0, 1.0, 1.0]))])
        # the drawn sheet's planes: its sides as the unit box's, its top at the thickness
        offsets = np.where(normals[:, 2] > 0.5, thickness, offsets)
        grown = mitered_offset(*_box([0, 0, 0], [2.0, 1.0, max(thickness, 1e-3)]), distance)
        grown[:, 2] = np.where(grown[:, 2] > 0, thickness + distance, -distance)
        done = _shrunk(grown, f, plane_of, normals, offsets, distance, manifold3d)
        assert not isinstance(done, str), done
        assert (len(done[1]) == 0) == (thickness == 0.0)
        if len(done[1]):
            assert signed_volume(*done) == pytest.approx(volume, rel=1e-9)


class _Element:
    """An IFC element as :func:`meshsom.ifc._envelope` sees it: an id and a class."""

    def __init__(self, number, cls):
        self.number, self.cls = number, cls

    def id(self):
        return self.number

    def is_a(self, cls=None):
        return self.cls if cls is None else self.cls == cls


def test_cavities_inside_walls_are_not_rooms():
    """cadwork's big_house (1,810 timber elements; no windows in the file, so its rooms lead outside) encloses 212
    cavities between the layers of its walls, none over 1 m3: counted as rooms by their share of the union (49 %),
    it went to preprocessing as 96 m3 of timber and was refused there for folds. A wall of two skins around a
    cavity of 3.8 x 0.1 x 2.3 m (0.874 m3) encloses no room: a rejection saying so, naming the largest cavity;
    the same wall read as elements alone (no IfcBuilding) is its solid, with a note."""
    from meshsom.ifc import _envelope

    parts = [([0, 0, 0], [4, 0.1, 2.5]), ([0, 0.2, 0], [4, 0.3, 2.5]), ([0, 0.1, 0], [4, 0.2, 0.1]),
             ([0, 0.1, 2.4], [4, 0.2, 2.5]), ([0, 0.1, 0.1], [0.1, 0.2, 2.4]), ([3.9, 0.1, 0.1], [4, 0.2, 2.4])]
    members = [_Element(k + 1, "IfcBuildingElement") for k in range(len(parts))]
    shapes = {k + 1: _box(lo, hi) for k, (lo, hi) in enumerate(parts)}
    # as grown by 5 mm: the wall 4.01 x 0.31 x 2.51 m, the cavity 3.79 x 0.09 x 2.29 m
    grown, cavity = f"{4.01 * 0.31 * 2.51:.4g}", f"{3.79 * 0.09 * 2.29:.3g}"
    with pytest.raises(MeshError) as err:
        _envelope(members, shapes, "wall.ifc#x", 0.01, rooms=True)
    assert (f"its 6 elements (6 IfcBuildingElement) enclose no room: their union is {grown} m3 of solid (grown by the "
            f"gap closing), its largest cavity {cavity} m3") in err.value.problem, err.value.problem
    vertices, faces, _, notes = _envelope(members, shapes, "wall.ifc#model", 0.01)
    assert signed_volume(vertices, faces) == pytest.approx(4 * 0.3 * 2.5, rel=1e-9)  # the cavity dropped, as a room
    assert any("enclose no room" in n and f"largest cavity {cavity} m3" in n for n in notes), notes


def test_a_massing_model_is_its_blocks_not_a_building_without_rooms(tmp_path):
    """An IfcBuilding of solid blocks (a massing: urban design tools and CityGML-to-IFC converters write
    IfcBuildingElementProxy blocks) has no cavity, and the rule that a union without a room is no envelope
    rejected it ('enclose no room'). Its blocks are thick (2 V / A of 3.8 m, where walls are a few decimetres):
    it is the union of its blocks, 20 x 10 x 9 + 10 x 6 x 15 = 2,700 m3 by hand, with a note."""
    from ifc_models import write_massing

    (mesh,), rejections = _meshes(write_massing(tmp_path / "massing.ifc"))
    assert not rejections
    assert signed_volume(mesh.vertices, mesh.faces) == pytest.approx(20 * 10 * 9 + 10 * 6 * 15, rel=1e-9)
    assert any("solid blocks (a massing" in n for n in mesh.notes), mesh.notes
