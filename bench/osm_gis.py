"""OpenStreetMap converted to GIS files: seconds per 1,000 buildings, against the extract itself and plain footprints.

    .venv/bin/python bench/osm_gis.py [--buildings 5000] [--parts 0.2] [--seed 0] [--repeat 2]

Writes one synthetic district in longitude and latitude: ``--buildings`` rectangles tagged
``building`` with a ``height``, a share ``--parts`` of them drawn as two ``building:part`` areas
(one raised on ``min_height``), and one park per 50 buildings. The same district as:

- the extract (``.osm`` XML), read by :func:`meshsom.osm.read_osm` (GDAL's OSM driver);
- ``ogr2ogr`` of it to a GeoPackage (the ``multipolygons`` layer with meshsom's osmconf.ini: the
  tags in ``other_tags``), read by :func:`meshsom.gis.read_gis`, the parts grouped
  (:func:`meshsom.gis.part_grouping`);
- the reference, measured in the same run: the buildings (no parts, no park) as a GeoPackage of
  plain columns (``height``), as national footprint layers are.

Each file is read whole by :func:`meshsom.io.read_file` (after a warm-up read; best of
``--repeat``): the table prints seconds, milliseconds per building, and the ratio to the reference.
The grouping's own pass (a fresh process's first read builds it) is timed apart.
"""

from __future__ import annotations

import argparse
import bz2
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

#: Metres per degree of longitude and latitude about Zürich, near enough for a synthetic district.
METRES_PER_DEGREE = np.array([75_000.0, 111_000.0])
ORIGIN = np.array([8.54, 47.37])


def district(buildings: int, parts: float, seed: int) -> list[tuple[str, list, dict]]:
    """(kind, ring in lon/lat (closed), tags) of every area: buildings on a 25 m grid, some drawn as two parts
    (``building:part``) inside their outline, and parks."""
    rng = np.random.default_rng(seed)
    side = int(np.ceil(np.sqrt(buildings)))
    areas = []
    for k in range(buildings):
        x, y = 25.0 * (k % side), 25.0 * (k // side)
        w, d, h = rng.uniform(8, 18), rng.uniform(6, 12), rng.uniform(4, 30)
        ring = [(x, y), (x + w, y), (x + w, y + d), (x, y + d), (x, y)]
        areas.append(("building", ring, {"building": "yes", "height": f"{h:.1f}"}))
        if rng.random() < parts:
            half = x + w / 2
            areas.append(("part", [(x, y), (half, y), (half, y + d), (x, y + d), (x, y)], {"building:part": "yes"}))
            areas.append(("part", [(half, y), (x + w, y), (x + w, y + d), (half, y + d), (half, y)],
                          {"building:part": "yes", "height": f"{h + 6:.1f}", "min_height": "3"}))
        if k % 50 == 49:
            areas.append(("park", [(x, y + 13), (x + 20, y + 13), (x + 20, y + 24), (x, y + 24), (x, y + 13)],
                          {"leisure": "park"}))
    return [(kind, (np.asarray(ring) / METRES_PER_DEGREE + ORIGIN).round(7).tolist(), tags) for kind, ring, tags in areas]


def write_osm(path: Path, areas) -> None:
    nodes, ways, next_id = [], [], 1
    for way_id, (_, ring, tags) in enumerate(areas, 1):
        refs = []
        for lon, lat in ring[:-1]:
            nodes.append(f'<node id="{next_id}" version="1" lat="{lat:.7f}" lon="{lon:.7f}"/>')
            refs.append(next_id)
            next_id += 1
        nds = "".join(f'<nd ref="{n}"/>' for n in refs + refs[:1])
        ways.append(f'<way id="{way_id}" version="1">{nds}' + "".join(f'<tag k="{k}" v="{v}"/>' for k, v in tags.items())
                    + "</way>")
    path.write_text('<?xml version="1.0" encoding="UTF-8"?>\n<osm version="0.6">\n' + "\n".join(nodes + ways) + "\n</osm>\n")


def write_converted(osm: Path, out: Path) -> None:
    """``ogr2ogr out.gpkg osm multipolygons`` with meshsom's osmconf.ini, as fiona (GDAL) does it."""
    import fiona
    from fiona.drvsupport import supported_drivers

    from meshsom.osm import CONFIG

    supported_drivers.setdefault("OSM", "r")
    with fiona.Env(OSM_CONFIG_FILE=str(CONFIG)), fiona.open(str(osm), layer="multipolygons") as src:
        features, schema, crs = list(src), src.schema, src.crs
    with fiona.open(str(out), "w", driver="GPKG", schema=schema, crs=crs, layer="multipolygons") as dst:
        dst.writerecords(features)


def write_overpass(osm: Path, out: Path) -> None:
    """The extract as the Overpass API answers ``[out:json]; ...; out geom;``: each way's node ids and corners, no
    untagged nodes."""
    import json
    import xml.etree.ElementTree as ET

    root = ET.parse(osm).getroot()
    nodes = {n.get("id"): {"lat": float(n.get("lat")), "lon": float(n.get("lon"))} for n in root.findall("node")}
    elements = []
    for w in root.findall("way"):
        refs = [nd.get("ref") for nd in w.findall("nd")]
        elements.append({"type": "way", "id": int(w.get("id")), "nodes": [int(r) for r in refs],
                         "geometry": [nodes[r] for r in refs], "tags": {t.get("k"): t.get("v") for t in w.findall("tag")}})
    out.write_text(json.dumps({"version": 0.6, "generator": "Overpass API 0.7.62.1", "elements": elements}))


def write_plain(out: Path, areas) -> None:
    import fiona

    schema = {"geometry": "Polygon", "properties": {"id": "str", "height": "float"}}
    with fiona.open(str(out), "w", driver="GPKG", schema=schema, crs="EPSG:4326") as dst:
        dst.writerecords({"geometry": {"type": "Polygon", "coordinates": [ring]},
                          "properties": {"id": str(k), "height": float(tags["height"])}}
                         for k, (kind, ring, tags) in enumerate(areas) if kind == "building")


def timed(path: Path, repeat: int) -> tuple[float, int]:
    """Best seconds of reading every item of a file (after a warm-up read), and the meshes read."""
    from meshsom.io import RawMesh, read_file

    meshes = sum(isinstance(i, RawMesh) for i in read_file(path))  # warm-up: GDAL opened, caches filled
    best = float("inf")
    for _ in range(repeat):
        start = time.perf_counter()
        for _item in read_file(path):
            pass
        best = min(best, time.perf_counter() - start)
    return best, meshes


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--buildings", type=int, default=5000)
    p.add_argument("--parts", type=float, default=0.2, help="share of buildings drawn as two parts")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--repeat", type=int, default=2)
    args = p.parse_args(argv)

    from meshsom.gis import _chosen_layers, _part_grouping, part_grouping
    from meshsom.io import ReaderOptions

    areas = district(args.buildings, args.parts, args.seed)
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        write_osm(tmp / "d.osm", areas)
        write_converted(tmp / "d.osm", tmp / "d.gpkg")
        write_plain(tmp / "plain.gpkg", areas)
        write_overpass(tmp / "d.osm", tmp / "answer.json")
        (tmp / "d.osm.bz2").write_bytes(bz2.compress((tmp / "d.osm").read_bytes()))
        _part_grouping.cache_clear()
        start = time.perf_counter()
        grouping = part_grouping(tmp / "d.gpkg", _chosen_layers(tmp / "d.gpkg", ReaderOptions()), ReaderOptions())
        grouped = time.perf_counter() - start
        rows = [("GeoPackage, plain columns (reference)", tmp / "plain.gpkg"), ("the extract (.osm, GDAL's OSM driver)", tmp / "d.osm"),
                ("ogr2ogr GeoPackage (other_tags, parts grouped)", tmp / "d.gpkg"),
                ("Overpass API JSON (out geom), written out as OSM XML", tmp / "answer.json"),
                ("the extract bzip2-compressed (.osm.bz2, written as PBF by libosmium)", tmp / "d.osm.bz2")]
        results = [(label, *timed(path, args.repeat)) for label, path in rows]
    owners = len(grouping.parts_of) if grouping else 0
    print(f"{args.buildings:,} buildings, {owners:,} of them of two parts, {len(areas) - args.buildings - 2 * owners:,} "
          f"parks; best of {args.repeat} after a warm-up read\n")
    print("| Input | Buildings read | Seconds | ms per building | vs reference |\n|---|---|---|---|---|")
    reference = results[0][1] / max(results[0][2], 1)
    for label, seconds, meshes in results:
        per = seconds / max(meshes, 1)
        print(f"| {label} | {meshes:,} | {seconds:.2f} | {1000 * per:.2f} | {per / reference:.2f}x |")
    print(f"\nThe parts' grouping (one pass over the layer, once per process and file): {grouped:.2f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
