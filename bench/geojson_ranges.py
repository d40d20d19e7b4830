"""A city's footprints in one GeoJSON FeatureCollection: finding its features' byte ranges, and the memory of a read.

    .venv/bin/python bench/geojson_ranges.py [--buildings 100000] [--range 10000] [--repeat 2]

Writes ``--buildings`` L-shaped footprints in longitude and latitude with a height, one feature per line as city
portals export them, then prints, best of ``--repeat`` after a warm-up:

- the scan that finds every feature's bytes (:func:`meshsom.geojson.geojson_ranges`), in MB/s, against the
  reference measured in the same run: ``json.loads`` of the whole file (what a whole read parses first);
- the peak memory (RSS) of a fresh process that reads the file whole as one read task of ``meshsom ingest`` does
  (:func:`pipelines.corpus.read_source`: its items held, to be shipped to the shards), and of one that reads one
  range of ``--range`` features (a read task of a ranged plan), and their seconds.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from bench.common import best_warm, print_reads  # noqa: E402

#: Metres per degree of longitude and latitude about Delft, near enough for a synthetic city.
METRES_PER_DEGREE = np.array([68_600.0, 111_250.0])
ORIGIN = np.array([4.3571, 52.0116])
L_SHAPE = np.array([(0, 0), (12, 0), (12, 4), (4, 4), (4, 10), (0, 10), (0, 0)], float)

def write_city(path: Path, n: int) -> None:
    side = int(np.ceil(np.sqrt(n)))
    with open(path, "w") as out:
        out.write('{"type": "FeatureCollection", "name": "city", "features": [\n')
        for k in range(n):
            ring = ORIGIN + (L_SHAPE + 16 * np.array([k % side, k // side])) / METRES_PER_DEGREE
            feature = {"type": "Feature", "id": f"b{k}", "properties": {"height": 3.0 + k % 9, "use": "residential"},
                       "geometry": {"type": "Polygon", "coordinates": [np.round(ring, 7).tolist()]}}
            out.write(json.dumps(feature) + (",\n" if k < n - 1 else "\n"))
        out.write("]}\n")


def main(argv=None) -> int:
    from meshsom.geojson import geojson_ranges
    from meshsom.io import ReaderOptions

    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--buildings", type=int, default=100_000)
    parser.add_argument("--range", type=int, default=10_000)
    parser.add_argument("--repeat", type=int, default=2)
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "city.geojson"
        write_city(path, args.buildings)
        mb = path.stat().st_size / 1e6
        ranges = geojson_ranges(path, args.range, ReaderOptions())
        assert ranges is not None and len(ranges) == -(-args.buildings // args.range)
        scan = best_warm(lambda: geojson_ranges(path, args.range, ReaderOptions()), args.repeat)
        parse = best_warm(lambda: json.loads(path.read_bytes()), args.repeat)
        print(f"{args.buildings:,} footprints, {mb:.1f} MB, {len(ranges)} ranges of {args.range:,}")
        print("| step | seconds | MB/s | ratio to json.loads |")
        print("|---|---|---|---|")
        print(f"| json.loads of the whole file (reference) | {parse:.2f} | {mb / parse:.0f} | 1.00 |")
        print(f"| geojson_ranges (the scan) | {scan:.2f} | {mb / scan:.0f} | {scan / parse:.2f} |")
        print_reads(path, ranges[len(ranges) // 2])
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
