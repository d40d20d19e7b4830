"""Reading a city: seconds and peak memory per container, for the same buildings.

    .venv/bin/python bench/read.py [--blocks 20000] [--seed 0]

Writes one synthetic city (``meshsom generate`` blocks with LoD2 roofs, on Swiss LV95 offsets) as
CityJSON, CityJSONSeq, CityGML, gzipped CityJSON / CityJSONSeq, as 3D GIS layers (each building
a MultiPolygon Z of its triangles, as the 3D BAG's GeoPackage layers hold them: GeoPackage written
by GDAL, GeoParquet by pyarrow), as DXF (a POLYFACE per building, by ezdxf; and an ACIS 3DSOLID per
building, its triangles the faces of the solid, placed by a block reference), as a Rhino model
(a mesh object per building, by openNURBS), as an FBX scene (a node per building, binary) and as a 3DS file (an
object per building), then reads every building of
each file with :func:`meshsom.io.read_file`, as ``meshsom ingest`` does, in a child process of its
own, and prints per container: file size, wall seconds (best of ``--repeat``), buildings per
second, and the peak memory the read allocates (``tracemalloc``: Python objects and NumPy arrays,
in a pass of its own). The reference for memory is the city's own vertex and face arrays
(float64 / int64), measured in the same run.

A second table is what one read task of the pipeline holds (it keeps its meshes until its shards
take them): the CityJSONSeq file read whole by one task, or in byte ranges (``dask.read_bytes``) of
a quarter and a sixteenth of the file, one task each.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

FORMATS = [("CityJSON", "city.city.json", "cityjson"), ("CityJSON, gzip", "city.city.json.gz", "cityjson"),
           ("CityJSONSeq", "city.city.jsonl", "cityjsonseq"), ("CityJSONSeq, gzip", "city.city.jsonl.gz", "cityjsonseq"),
           ("CityGML 2.0", "city.gml", "citygml"), ("GeoPackage, 3D", "city.gpkg", "gpkg"),
           ("GeoParquet, 3D", "city.parquet", "parquet"), ("DXF (a POLYFACE each)", "city.dxf", "dxf"),
           ("DXF R2018 (an ACIS 3DSOLID each)", "city_solids.dxf", "dxf-solids"), ("Rhino 8 (a mesh object each)", "city.3dm", "3dm"),
           ("FBX 7.4 binary (a node each)", "city.fbx", "fbx"), ("3DS (an object each)", "city.3ds", "3ds")]


def _multipolygon(mesh) -> dict:
    corners = mesh.vertices[mesh.faces]
    return {"type": "MultiPolygon", "coordinates": [[np.concatenate([c, c[:1]]).tolist()] for c in corners]}


def write_gpkg(path, meshes) -> None:
    """Each mesh a feature: MultiPolygon Z of its triangles, EPSG:2056, written by GDAL (fiona)."""
    import fiona

    schema = {"geometry": "3D MultiPolygon", "properties": {"id": "str"}}
    with fiona.open(path, "w", driver="GPKG", schema=schema, crs="EPSG:2056") as out:
        out.writerecords({"geometry": _multipolygon(m), "properties": {"id": str(m.id)}} for m in meshes)


def write_geoparquet(path, meshes) -> None:
    """The same as GeoParquet (WKB by GEOS, the "geo" metadata of GeoParquet 1.1)."""
    import pyarrow as pa
    import pyarrow.parquet as pq
    import pyproj
    import shapely

    wkb = [shapely.to_wkb(shapely.geometry.shape(_multipolygon(m))) for m in meshes]
    geo = {"version": "1.1.0", "primary_column": "geometry",
           "columns": {"geometry": {"encoding": "WKB", "geometry_types": [], "crs": pyproj.CRS("EPSG:2056").to_json_dict()}}}
    table = pa.table({"id": [str(m.id) for m in meshes], "geometry": wkb})
    pq.write_table(table.replace_schema_metadata({b"geo": json.dumps(geo).encode()}), path)


def write_dxf(path, meshes) -> None:
    """Each mesh a POLYFACE entity (ezdxf), in metres, on LV95 offsets (float64 in DXF's text)."""
    import ezdxf

    doc = ezdxf.new("R2010")
    doc.units = ezdxf.units.M
    space = doc.modelspace()
    for m in meshes:
        polyface = space.add_polyface()
        polyface.append_faces([[tuple(p) for p in m.vertices[f]] for f in m.faces])
        polyface.optimize()
    doc.saveas(path)


def write_dxf_solids(path, meshes) -> None:
    """Each mesh a 3DSOLID (R2018: SAB), its triangles the faces of an ACIS body (ezdxf's ``body_from_mesh``), in metres,
    about its own origin and placed by the body's transformation (SAB keeps doubles; ezdxf writes the transformation
    to 6 digits, so the offsets go in the insertion of a block per building instead)."""
    import ezdxf
    from ezdxf.acis import api as acis
    from ezdxf.render import MeshBuilder

    doc = ezdxf.new("R2018")
    doc.units = ezdxf.units.M
    space = doc.modelspace()
    for k, m in enumerate(meshes):
        origin = m.vertices.min(axis=0)
        builder = MeshBuilder()
        builder.vertices = [tuple(p) for p in (m.vertices - origin).tolist()]
        builder.faces = [tuple(f) for f in m.faces.tolist()]
        block = doc.blocks.new(f"B{k}")
        acis.export_dxf(block.add_3dsolid(), [acis.body_from_mesh(builder)])
        space.add_blockref(f"B{k}", tuple(origin))
    doc.saveas(path)


def write_3dm(path, meshes) -> None:
    """Each mesh a Rhino mesh object named by its id (openNURBS, double-precision vertices), in metres."""
    import rhino3dm

    model = rhino3dm.File3dm()
    model.Settings.ModelUnitSystem = rhino3dm.UnitSystem.Meters
    for m in meshes:
        mesh = rhino3dm.Mesh()
        mesh.Vertices.UseDoublePrecisionVertices = True
        for x, y, z in m.vertices.tolist():
            mesh.Vertices.Add(x, y, z)
        for a, b, c in m.faces.tolist():
            mesh.Faces.AddFace(a, b, c)
        attributes = rhino3dm.ObjectAttributes()
        attributes.Name = str(m.id)
        model.Objects.AddMesh(mesh, attributes)
    assert model.Write(str(path), 8)


def write_fbx(path, meshes) -> None:
    """Each mesh an FBX node named by its id, about its own origin and placed by its translation, in metres
    (``UnitScaleFactor`` 100), z up, binary with deflated arrays, as tests/scene_files.py writes exporters' files."""
    sys.path.insert(0, str(ROOT / "tests"))
    from scene_files import fbx_document, write_fbx_binary

    objects = []
    for m in meshes:
        origin = m.vertices.min(axis=0)
        objects.append((str(m.id), m.vertices - origin, m.faces.tolist(), tuple(origin), (0, 0, 0), (1, 1, 1)))
    write_fbx_binary(path, fbx_document(objects, "z-up", 100.0))


def write_3ds(path, meshes) -> None:
    """Each mesh a 3DS object named by its id (float32 world coordinates, as 3DS stores them: on LV95 offsets about
    0.1 m apart, so the timing, not the geometry, is what this row is for)."""
    sys.path.insert(0, str(ROOT / "tests"))
    from scene_files import write_3ds as write

    write(path, [(str(m.id)[:60], m.vertices, m.faces) for m in meshes])


def child(path: str, repeat: int) -> None:
    """Read every building of ``path``: ``repeat`` timed passes, then one under tracemalloc; print
    JSON with the best seconds and the peak traced allocation (Python objects and NumPy arrays)."""
    import tracemalloc

    from meshsom.io import RawMesh, read_file

    best, count = float("inf"), 0
    for _ in range(repeat):
        t0 = time.perf_counter()
        count = sum(isinstance(item, RawMesh) for item in read_file(Path(path)))
        best = min(best, time.perf_counter() - t0)
    tracemalloc.start()
    sum(1 for _ in read_file(Path(path)))
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    print(json.dumps({"seconds": best, "meshes": count, "peak_mb": peak / 2**20}))


def ranges_child(path: str, target: int) -> None:
    """What one read task of the pipeline holds (its list of meshes, :func:`pipelines.corpus.read_source`):
    the whole CityJSONSeq file in one task, or its byte ranges of about ``target`` bytes, one at a
    time; print JSON with the seconds (all ranges), the ranges, and the largest task's peak allocation."""
    import tracemalloc

    from meshsom.io import cityjsonseq_ranges
    from pipelines.corpus import read_source

    from meshsom.io import ReaderOptions

    t0 = time.perf_counter()
    ranges = cityjsonseq_ranges(Path(path), target) if target else None
    count = sum(len(read_source(path, ReaderOptions(), None, r)) for r in ranges or [None])
    seconds = time.perf_counter() - t0
    peak = 0
    for r in ranges or [None]:  # again, traced
        tracemalloc.start()
        items = read_source(path, ReaderOptions(), None, r)
        peak = max(peak, tracemalloc.get_traced_memory()[1])
        tracemalloc.stop()
        del items
    print(json.dumps({"seconds": seconds, "meshes": count, "ranges": len(ranges or [None]), "peak_mb": peak / 2**20}))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--blocks", type=int, default=20000)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--only", help="the containers to write and read, by kind, comma-separated (default: all): "
                    + ", ".join(dict.fromkeys(kind for _, _, kind in FORMATS)))
    ap.add_argument("--child", help=argparse.SUPPRESS)
    ap.add_argument("--ranges-child", nargs=2, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        child(args.child, args.repeat)
        return
    if args.ranges_child:
        ranges_child(args.ranges_child[0], int(args.ranges_child[1]))
        return
    from meshsom.citygml import write_citygml
    from meshsom.generate import BLOCK_FAMILIES, ROOF_FAMILIES, GeneratorParams, generate_corpus
    from meshsom.io import write_cityjson, write_cityjsonseq

    params = GeneratorParams(n_blocks=args.blocks, seed=args.seed, families=BLOCK_FAMILIES + ROOF_FAMILIES,
                             origin=(2600000.0, 1200000.0, 400.0))
    t0 = time.perf_counter()
    blocks = generate_corpus(params)
    arrays_mb = sum(b.vertices.nbytes + b.faces.nbytes for b in blocks) / 2**20
    print(f"{len(blocks)} buildings, {sum(len(b.faces) for b in blocks):,} triangles, generated in "
          f"{time.perf_counter() - t0:.1f} s; their vertex and face arrays: {arrays_mb:.1f} MB")
    writers = {"cityjson": write_cityjson, "cityjsonseq": write_cityjsonseq, "citygml": write_citygml, "gpkg": write_gpkg,
               "parquet": write_geoparquet, "dxf": write_dxf, "dxf-solids": write_dxf_solids, "3dm": write_3dm,
               "fbx": write_fbx, "3ds": write_3ds}
    with tempfile.TemporaryDirectory(prefix="meshsom-read-") as tmp:
        print("\n| container | file MB | read s | buildings/s | peak alloc MB | peak / arrays |")
        print("|---|---:|---:|---:|---:|---:|")
        for label, name, kind in FORMATS:
            if args.only and kind not in args.only.split(","):
                continue
            path = Path(tmp) / name
            writers[kind](path, blocks)
            out = subprocess.run([sys.executable, __file__, "--child", str(path), "--repeat", str(args.repeat)],
                                 capture_output=True, text=True, check=True, env={**os.environ, "PYTHONPATH": str(ROOT)})
            r = json.loads(out.stdout.strip().splitlines()[-1])
            assert r["meshes"] == len(blocks), (label, r)
            print(f"| {label} | {path.stat().st_size / 2**20:.1f} | {r['seconds']:.2f} | {r['meshes'] / r['seconds']:,.0f} | "
                  f"{r['peak_mb']:.0f} | {r['peak_mb'] / arrays_mb:.1f}x |")
        if args.only and "cityjsonseq" not in args.only.split(","):
            return
        # the pipeline's read tasks keep their meshes: one task for the whole file, or one per range
        path = Path(tmp) / "city.city.jsonl"
        size = path.stat().st_size
        print("\nOne pipeline read task (it keeps its meshes until its shards take them), CityJSONSeq:")
        print("\n| dask.read_bytes | read tasks | read s (all tasks, one after another) | largest task's peak alloc MB |")
        print("|---:|---:|---:|---:|")
        for target in (0, size // 4, size // 16):
            out = subprocess.run([sys.executable, __file__, "--ranges-child", str(path), str(target)],
                                 capture_output=True, text=True, check=True, env={**os.environ, "PYTHONPATH": str(ROOT)})
            r = json.loads(out.stdout.strip().splitlines()[-1])
            assert r["meshes"] == len(blocks), r
            what = "whole file" if not target else f"{target / 2**20:.1f} MB"
            print(f"| {what} | {r['ranges']} | {r['seconds']:.2f} | {r['peak_mb']:.0f} |")


if __name__ == "__main__":
    main()
