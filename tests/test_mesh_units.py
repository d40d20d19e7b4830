"""Mesh files in other units (corpus.reader.unit, --unit) and the plausibility bound on a building's extent.

Independent values: box volumes by hand (10 x 8 x 6 m = 480 m3), spans by hand."""
import numpy as np
import pytest
import trimesh

from meshsom.config import load_config
from meshsom.errors import ConfigError
from meshsom.io import MAX_BUILDING_EXTENT_M, MESH_UNITS, RawMesh, ReaderOptions, Rejection, read_file
from pipelines.cli import build_parser


def _read(path, **opts):
    out = list(read_file(path, ReaderOptions(**opts)))
    return [r for r in out if isinstance(r, RawMesh)], [r for r in out if isinstance(r, Rejection)]


def _house(per_metre, offset=(0.0, 0.0, 0.0)):
    """A 10 x 8 x 6 m box written in a unit of ``per_metre`` units a metre."""
    return trimesh.creation.box(bounds=(np.array([[0, 0, 0], [10, 8, 6]]) + offset) * per_metre)


@pytest.mark.parametrize("suffix", ["obj", "stl", "ply", "off", "glb"])
def test_a_house_in_millimetres_is_refused_as_metres_and_read_with_unit_mm(tmp_path, suffix):
    path = tmp_path / f"house.{suffix}"
    _house(1000).export(path)
    ok, rej = _read(path, up_axis="z")
    assert ok == [] and len(rej) == 1
    assert rej[0].reason.startswith("spans 10 km: not one building in metres (a file in millimetres? --unit mm")
    ok, rej = _read(path, up_axis="z", unit="mm")
    assert rej == [] and trimesh.Trimesh(ok[0].vertices, ok[0].faces).volume == pytest.approx(480.0)
    assert np.ptp(ok[0].vertices, axis=0) == pytest.approx([10, 8, 6])
    assert "coordinates read in mm" in ok[0].notes[-1]


@pytest.mark.parametrize("unit", ["dm", "cm", "ft", "in"])
def test_other_units_scale_to_metres(tmp_path, unit):
    path = tmp_path / "house.obj"
    _house(1 / MESH_UNITS[unit]).export(path)
    ok, _ = _read(path, unit=unit)
    assert np.ptp(ok[0].vertices, axis=0) == pytest.approx([10, 8, 6])


def test_a_collada_unit_is_the_files_not_the_options(tmp_path):
    """COLLADA names its unit: --unit does not apply; a COLLADA without <unit> is read in --unit."""
    path = tmp_path / "house.dae"
    text = trimesh.exchange.dae.export_collada(_house(1000)).decode()
    assert "<unit" not in text  # trimesh writes no <unit>: read in --unit
    path.write_text(text)
    ok, rej = _read(path, unit="mm")
    assert rej == [] and trimesh.Trimesh(ok[0].vertices, ok[0].faces).volume == pytest.approx(480.0)
    path.write_text(text.replace("<asset>", '<asset><unit meter="1" name="meter"/>'))  # a 10 km "house" in metres
    for unit in (None, "mm"):
        ok, rej = _read(path, unit=unit)
        assert ok == [] and "not one building in the unit its file declares" in rej[0].reason


def test_a_district_in_one_mesh_is_judged_building_by_building_when_split(tmp_path):
    """Two houses 6 km apart in one mesh span more than any building; split, each is one."""
    path = tmp_path / "district.stl"
    trimesh.util.concatenate([_house(1), _house(1, (6000, 0, 0))]).export(path)
    assert 6010 > MAX_BUILDING_EXTENT_M
    _, rej = _read(path)
    assert "spans 6.01 km" in rej[0].reason and "--split-components" in rej[0].reason
    ok, rej = _read(path, split_components=True)
    assert rej == [] and [trimesh.Trimesh(m.vertices, m.faces).volume for m in ok] == pytest.approx([480, 480])


def test_unit_in_config_and_cli(tmp_path):
    p = tmp_path / "c.yaml"
    p.write_text("corpus: {paths: [a], reader: {unit: mm}}\n")
    assert load_config(p).corpus.reader.unit == "mm"
    p.write_text("corpus: {paths: [a], reader: {unit: furlong}}\n")
    with pytest.raises(ConfigError, match="unit must be one of m, dm, cm, mm, ft, in or null"):
        load_config(p)
    args = build_parser().parse_args(["ingest", "x.obj", "--out", "s.zarr", "--unit", "mm"])
    assert args.unit == "mm"
