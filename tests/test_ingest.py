"""Ingestion end to end: readers + preprocessing + store + manifest, through the CLI."""


import numpy as np
import pytest

from cityjson_samples import CUBE_VERTS, cube_solid, doc, write
from meshsom.store import mesh_table, open_store, read_manifest, read_mesh
from pipelines.cli import main


def _summary(store):
    return read_manifest(store)["summary"]


def _volume(v, f):
    a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    return np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6


def test_derived_zurich_lod1_ingests_49_of_49(tmp_path, data_dir):
    store = tmp_path / "z.zarr"
    rc = main(["ingest", str(data_dir / "zurich-lod2-subset" / "zurich_subset_lod1_derived.city.json"), "--out", str(store)])
    assert rc == 0
    s = _summary(store)
    assert (s["inputs"], s["accepted"], s["rejected"]) == (49, 49, 0)
    # 8 blocks had fins or notches (fold angle 0 or 2 pi): 6 rebuilt by manifold3d, 2 exact fins removed
    repairs = [" ".join(r["repairs"]) for r in read_manifest(store)["records"]]
    assert sum("rebuilt with manifold3d" in r for r in repairs) == 6
    assert sum("zero-thickness fins" in r for r in repairs) == 2
    g = open_store(store)
    t = mesh_table(g)
    assert len(t) == 49 and t.ids[0].startswith("zurich_subset_lod1_derived.city.json#")
    # LV95 origins, local coordinates small.
    assert (t.origins[:, 0] > 2.6e6).all()
    assert np.abs(g["vertices"][:]).max() < 500
    for i in range(len(t)):
        v, f = read_mesh(g, i, t)
        assert _volume(v, f) > 0


@pytest.mark.parametrize(
    "folder, name, n",
    [
        ("delft-lod1-3dfier", "delft.city.json", 160),
        ("zurich-lod2-subset", "zurich_subset_lod2.city.json", 49),
        ("3dbag-multilod", "multi_lod.city.json", 10),
    ],
)
def test_every_real_building_is_accounted_for(tmp_path, data_dir, folder, name, n):
    store = tmp_path / "r.zarr"
    main(["ingest", str(data_dir / folder / name), "--out", str(store)])
    m = read_manifest(store)
    s = m["summary"]
    assert s["inputs"] == n == s["accepted"] + s["rejected"]
    assert len({r["id"] for r in m["records"]}) == n
    for r in m["records"]:
        assert r["status"] in ("accepted", "rejected")
        assert (r["status"] == "rejected") == bool(r["reason"])
    if folder == "delft-lod1-3dfier":  # open floors are capped: all accepted, repair recorded
        assert s["accepted"] == 160
        assert all(any("capped" in x for x in r["repairs"]) for r in m["records"])
    if folder == "3dbag-multilod":
        assert s["accepted"] == 10


def test_zurich_lod2_extruded_all_accepted(tmp_path, data_dir):
    store = tmp_path / "x.zarr"
    main(["ingest", str(data_dir / "zurich-lod2-subset" / "zurich_subset_lod2.city.json"), "--extrude-lod1", "--out", str(store)])
    assert _summary(store)["accepted"] == 49  # 3 thin spikes or notches repaired by manifold3d


def test_generate_then_ingest_48_blocks_with_labels(tmp_path):
    city = tmp_path / "synth.city.json"
    assert main(["generate", "--out", str(city), "-n", "48", "--seed", "1", "--roofs"]) == 0
    store = tmp_path / "s.zarr"
    assert main(["ingest", str(city), "--out", str(store)]) == 0
    s = _summary(store)
    assert (s["inputs"], s["accepted"]) == (48, 48)
    labels = set(mesh_table(open_store(store)).labels)
    assert {"L", "U", "T", "courtyard", "gabled", "hipped", "shed"} <= labels


def test_mixed_folder_with_bad_files_keeps_going_and_counts_add_up(tmp_path, cube):
    import trimesh

    folder = tmp_path / "in"
    folder.mkdir()
    v, f = cube
    trimesh.Trimesh(v, f, process=False).export(folder / "good.obj")
    trimesh.Trimesh(v, f[[0, 1, 2, 3, 4, 5, 7, 8, 10, 11]], process=False).export(folder / "open.obj")  # a bent hole
    (folder / "empty.ply").write_bytes(b"")
    (folder / "broken.city.json").write_text('{"type": "CityJSON", ')
    nan_v = v.copy()
    nan_v[3, 1] = np.nan
    (folder / "nan.obj").write_text("".join(f"v {a} {b} {c}\n" for a, b, c in nan_v) + "".join(f"f {a+1} {b+1} {c+1}\n" for a, b, c in f))
    inside_out = f[:, ::-1]
    trimesh.Trimesh(v, inside_out, process=False).export(folder / "inverted.obj")
    bad_idx = doc({"X": {"type": "Building", "geometry": [cube_solid()]}}, CUBE_VERTS[:5])
    write(folder / "idx.city.json", bad_idx)
    store = tmp_path / "mixed.zarr"
    rc = main(["ingest", str(folder), "--out", str(store)])
    assert rc == 0
    m = read_manifest(store)
    by_id = {r["id"].split("/")[-1]: r for r in m["records"]}
    assert m["summary"]["inputs"] == 7 == m["summary"]["accepted"] + m["summary"]["rejected"]
    assert by_id["good.obj"]["status"] == "accepted"
    assert by_id["inverted.obj"]["status"] == "accepted"
    assert any("flip" in x for x in by_id["inverted.obj"]["repairs"])
    # the cube with two wall triangles missing (a bent hole, not capped) is rebuilt under its roof:
    # the cube again
    assert by_id["open.obj"]["status"] == "accepted" and "boundary" in by_id["open.obj"]["envelope"]["because"]
    assert by_id["open.obj"]["volume"] == pytest.approx(1.0)
    assert by_id["empty.ply"]["reason"] == "file is empty"
    assert "invalid JSON" in by_id["broken.city.json"]["reason"]
    assert "NaN" in by_id["nan.obj"]["reason"]
    assert "out of range" in by_id["idx.city.json#X"]["reason"]


def test_nothing_ingested_exits_non_zero(tmp_path):
    (tmp_path / "empty.obj").write_bytes(b"")
    rc = main(["ingest", str(tmp_path / "empty.obj"), "--out", str(tmp_path / "e.zarr")])
    assert rc == 1
    assert _summary(tmp_path / "e.zarr") == {**_summary(tmp_path / "e.zarr"), "inputs": 1, "accepted": 0, "rejected": 1}


def test_existing_store_refused_before_work(tmp_path, capsys):
    (tmp_path / "s.zarr").mkdir()
    rc = main(["ingest", "--generate", "2", "--out", str(tmp_path / "s.zarr")])
    assert rc == 2
    assert "already exists; pass --overwrite" in capsys.readouterr().err


def test_ids_carry_sub_folders_and_collisions_are_errors(tmp_path, capsys):
    for sub in ("a", "b"):
        (tmp_path / "in" / sub).mkdir(parents=True)
        write(tmp_path / "in" / sub / "x.city.json", doc({"X": {"type": "Building", "geometry": [cube_solid()]}}, CUBE_VERTS))
    store = tmp_path / "ids.zarr"
    assert main(["ingest", str(tmp_path / "in"), "--out", str(store)]) == 0
    records = read_manifest(store)["records"]
    assert sorted(r["id"] for r in records) == ["a/x.city.json#X", "b/x.city.json#X"]
    assert sorted(mesh_table(open_store(store)).ids) == ["a/x.city.json#X", "b/x.city.json#X"]
    # The same two files given one by one: both would be x.city.json#X; an error naming both, before any work.
    rc = main(["ingest", str(tmp_path / "in" / "a" / "x.city.json"), str(tmp_path / "in" / "b" / "x.city.json"),
               "--out", str(tmp_path / "clash.zarr")])
    err = capsys.readouterr().err
    assert rc == 2 and str(tmp_path / "in" / "a" / "x.city.json") in err and str(tmp_path / "in" / "b" / "x.city.json") in err
    assert not (tmp_path / "clash.zarr").exists()


def test_an_id_repeated_within_a_file_is_a_rejection_not_a_failed_run(tmp_path):
    """A CityJSONSeq made of overlapping tiles repeats the buildings on their borders; a CityGML
    file may give one gml:id twice. The first is read, the repeat is listed as rejected (the run
    used to fail on the id check of the assembly)."""
    from cityjson_samples import to_cityjsonseq, write_lines
    from test_citygml import to_citygml

    folder = tmp_path / "in"
    folder.mkdir()
    two = doc({"A": {"type": "Building", "geometry": [cube_solid()]},
               "B": {"type": "Building", "geometry": [cube_solid(8)]}}, CUBE_VERTS + [[x + 3000, y, z] for x, y, z in CUBE_VERTS])
    lines = to_cityjsonseq(two)
    write_lines(folder / "tiles.city.jsonl", lines + [lines[1]])  # A again, as the next tile has it
    gml = to_citygml(two)
    (folder / "twice.gml").write_text(gml.replace('gml:id="B"', 'gml:id="A"'))
    store = tmp_path / "dup.zarr"
    assert main(["ingest", str(folder), "--out", str(store)]) == 0
    by_id = {r["id"]: r for r in read_manifest(store)["records"]}
    assert sorted(by_id) == ["tiles.city.jsonl#A", "tiles.city.jsonl#A (2)", "tiles.city.jsonl#B",
                             "twice.gml#A", "twice.gml#A (2)"]
    assert [by_id[k]["status"] for k in sorted(by_id)] == ["accepted", "rejected", "accepted", "accepted", "rejected"]
    assert by_id["tiles.city.jsonl#A (2)"]["reason"] == "line 4: object id repeated (first on line 2); the later one is not read"
    assert by_id["twice.gml#A (2)"]["reason"].startswith("id repeated: an earlier object of the file has the id 'twice.gml#A'")
    assert sorted(mesh_table(open_store(store)).ids) == ["tiles.city.jsonl#A", "tiles.city.jsonl#B", "twice.gml#A"]


def test_union_recorded_in_the_manifest(tmp_path):
    from cityjson_samples import building_of_parts

    path = write(tmp_path / "pair.city.json", building_of_parts([((0, 0, 0), (10000, 8000, 6000)), ((10000, 0, 0), (16000, 8000, 6000))]))
    store = tmp_path / "u.zarr"
    assert main(["ingest", str(path), "--out", str(store)]) == 0
    (r,) = read_manifest(store)["records"]
    assert r["union"]["status"] == "united" and r["union"]["shells_after"] == 1
    assert r["union"]["area_removed"] == pytest.approx(2 * 8 * 6)
    v, f = read_mesh(open_store(store), 0)
    assert _volume(v, f) == pytest.approx(16 * 8 * 6) and len(v) == 8


def test_ingest_says_which_files_of_a_folder_it_does_not_read(tmp_path, capsys):
    """`meshsom ingest folder` lists the files it passes over (`meshsom run` did; ingest said
    nothing of val3dity's 100 .poly files): ten by name, the rest counted by type, and what it reads."""
    folder = tmp_path / "in"
    folder.mkdir()
    write(folder / "cube.city.json", doc({"a": {"type": "Building", "geometry": [cube_solid()]}}, CUBE_VERTS))
    for k in range(12):
        (folder / f"shape{k:02d}.poly").write_text("0 3 0 0\n")
    (folder / "notes.txt").write_text("x")
    assert main(["ingest", str(folder), "--out", str(tmp_path / "s.zarr")]) == 0
    out = capsys.readouterr().out
    named = [line.strip() for line in out.splitlines() if line.strip().startswith("skipped: ") and "more files" not in line]
    assert len(named) == 10 and named[0] == "skipped: notes.txt (unknown file type '.txt')", named
    assert "  skipped: 3 more files (3 x .poly)" in out
    assert out.count("(readable: .obj, .ply") == 1 and ".gpkg" in out
    assert all(len(line) <= 80 for line in out.splitlines() if "skipped" in line or ".gz" in line or ".gpkg" in line)
    assert "1 meshes: 1 accepted, 0 rejected" in out
