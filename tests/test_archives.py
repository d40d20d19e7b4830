"""Zip archives (meshsom.archives): read as the folder they hold, every mesh the same as read from
the files themselves; names that climb out, zip bombs and zips in zips are refused or listed."""

from __future__ import annotations

import json
import subprocess
import sys
import tempfile
import zipfile
from pathlib import Path

import fiona
import numpy as np

from meshsom.io import RawMesh, ReaderOptions, Rejection, read_file

from footprints import L_SHAPE, closed, lonlat

ROOT = Path(__file__).resolve().parents[1]
DELFT = ROOT / "data/real/delft-lod1-3dfier/delft.city.json"


def _district(folder: Path) -> Path:
    """A download's content: CityJSON, a shapefile with its sidecars, a labels table and a readme."""
    folder.mkdir(parents=True)
    (folder / "tiles").mkdir()
    (folder / "tiles" / "delft.city.json").write_bytes(DELFT.read_bytes())
    schema = {"geometry": "Polygon", "properties": {"id": "str", "height": "float"}}
    with fiona.open(folder / "footprints.shp", "w", driver="ESRI Shapefile", schema=schema, crs="EPSG:4326") as out:
        for k in range(3):
            out.write({"geometry": {"type": "Polygon", "coordinates": [closed(lonlat([(x + 30 * k, y) for x, y in L_SHAPE]))]},
                       "properties": {"id": f"b{k}", "height": 6.0 + k}})
    (folder / "README.txt").write_text("licence: CC BY 4.0")
    return folder


def _zip(folder: Path, target: Path, extra: dict[str, bytes] | None = None) -> Path:
    with zipfile.ZipFile(target, "w", zipfile.ZIP_DEFLATED) as z:
        for p in sorted(folder.rglob("*")):
            if p.is_file():
                z.write(p, p.relative_to(folder).as_posix())
        for name, data in (extra or {}).items():
            z.writestr(name, data)
    return target


def _temp_folders() -> set[str]:
    return {p.name for p in Path(tempfile.gettempdir()).glob("meshsom-zip-*")}


def test_a_zip_reads_as_the_folder_it_holds(tmp_path):
    folder = _district(tmp_path / "district")
    archive = _zip(folder, tmp_path / "download.zip")
    before = _temp_folders()
    got = list(read_file(archive))
    assert _temp_folders() == before  # extracted, read and removed
    want = [i for f in ("footprints.shp", "tiles/delft.city.json") for i in read_file(folder / f, ReaderOptions(), f)]
    assert [i.id for i in got] == [f"download.zip/{i.id}" for i in want]
    for a, b in zip(got, want):
        assert type(a) is type(b)
        assert a.source == f"{archive}!/{Path(b.source).relative_to(folder).as_posix()}"
        if isinstance(a, RawMesh):
            assert np.array_equal(a.vertices, b.vertices) and np.array_equal(a.faces, b.faces)
            assert np.array_equal(a.origin, b.origin) and a.notes == b.notes
        else:
            assert a.reason == b.reason
    assert sum(isinstance(i, RawMesh) for i in got) > 100


def test_climbing_names_bombs_and_zips_in_zips(tmp_path):
    folder = _district(tmp_path / "district")
    cube = "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 0 0 1\nv 1 0 1\nv 1 1 1\nv 0 1 1\n" + "".join(
        f"f {a} {b} {c}\n" for a, b, c in [(1, 3, 2), (1, 4, 3), (5, 6, 7), (5, 7, 8), (1, 2, 6), (1, 6, 5),
                                           (2, 3, 7), (2, 7, 6), (3, 4, 8), (3, 8, 7), (4, 1, 5), (4, 5, 8)])
    inner = _zip(folder, tmp_path / "inner.zip")
    archive = _zip(folder, tmp_path / "a.zip", {"../../../climbed.obj": cube.encode(), "/abs/rooted.obj": cube.encode(),
                                                 "nested/inner.zip": inner.read_bytes()})
    got = {i.id: i for i in read_file(archive)}
    assert not (tmp_path.parent / "climbed.obj").exists() and not Path("/abs/rooted.obj").exists()
    assert isinstance(got["a.zip/climbed.obj"], RawMesh) and isinstance(got["a.zip/abs/rooted.obj"], RawMesh)  # kept inside
    assert "zip inside a zip" in got["a.zip/nested/inner.zip"].reason
    # a bomb: refused from its sizes, before anything is extracted
    with zipfile.ZipFile(tmp_path / "bomb.zip", "w", zipfile.ZIP_DEFLATED) as z:
        z.writestr("city.city.json", b" " * (64 << 20))
    (bomb,) = read_file(tmp_path / "bomb.zip")
    assert isinstance(bomb, Rejection) and "zip bomb" in bomb.reason
    (big,) = read_file(archive, ReaderOptions(max_bytes=1000))
    assert isinstance(big, Rejection) and "more than max_bytes" in big.reason
    # nothing readable, or not a zip at all
    with zipfile.ZipFile(tmp_path / "docs.zip", "w") as z:
        z.writestr("README.txt", "nothing here")
    (docs,) = read_file(tmp_path / "docs.zip")
    assert "holds no file that meshsom reads (it holds README.txt)" in docs.reason
    (tmp_path / "fake.zip").write_bytes(b"PK\x03\x04 not really")
    (fake,) = read_file(tmp_path / "fake.zip")
    assert "cannot be read as a zip archive" in fake.reason


def test_zips_through_meshsom_ingest(tmp_path):
    folder = _district(tmp_path / "district")
    inputs = tmp_path / "in"
    inputs.mkdir()
    _zip(folder, inputs / "download.zip")
    out = subprocess.run([sys.executable, "-m", "pipelines.cli", "ingest", str(inputs), "--out", str(tmp_path / "z.zarr")],
                         capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    records = json.loads((tmp_path / "z.zarr" / "manifest.json").read_text())["records"]
    assert {r["source"].split("!")[0] for r in records} == {str(inputs / "download.zip")}
    assert [r["id"] for r in records if r["id"].startswith("download.zip/footprints.shp#")] == [
        f"download.zip/footprints.shp#b{k}" for k in range(3)]
    assert all(r["status"] == "accepted" for r in records if "footprints" in r["id"])
