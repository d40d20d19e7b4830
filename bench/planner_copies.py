"""What the planner and a range's task copy of a large GeoParquet file on object storage, in bytes.

    .venv/bin/python bench/planner_copies.py [--buildings 400000] [--row-group 50000] [--range 100000]

Writes ``--buildings`` footprints laid out as Overture Maps' buildings are (a GERS-like ``id``, the WKB geometry in
longitude and latitude, ``bbox``, ``version``, ``sources`` as a list of structs, ``names``, ``subtype``, ``class``,
``height``, ``num_floors``, ``roof_shape``), in row groups of ``--row-group`` rows, zstd-compressed as Overture's
are, then prints:

- the bytes the planner copies of it (:func:`meshsom.gis.parquet_planned_spans`: its first row groups, its id
  columns, its footer) and the bytes one read task of a range of ``--range`` rows copies
  (:func:`meshsom.gis.parquet_spans`), each as a share of the file (the reference: the whole copy both made before);
- the planning on a copy holding only the planner's bytes (:func:`meshsom.gis.gis_ranges`: the layer, the id column
  checked unique over every row), in seconds, against the same on the whole file, best of 2 after a warm-up.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def write_overture(path: Path, n: int, row_group: int, seed: int = 0) -> None:
    import json

    import pyarrow as pa
    import pyarrow.parquet as pq
    import shapely

    rng = np.random.default_rng(seed)
    side = int(np.ceil(np.sqrt(n)))
    k = np.arange(n)
    x0 = 4.3 + (k % side) * 2.4e-4 + rng.uniform(0, 5e-5, n)
    y0 = 52.0 + (k // side) * 1.5e-4 + rng.uniform(0, 5e-5, n)
    w, d = rng.uniform(8e-5, 2e-4, n), rng.uniform(5e-5, 1.2e-4, n)
    boxes = shapely.box(x0, y0, x0 + w, y0 + d)
    datasets = ["OpenStreetMap", "Microsoft ML Buildings", "Google Open Buildings", "Esri Community Maps"]
    table = pa.table({
        "id": [rng.bytes(16).hex() for _ in range(n)],
        "geometry": shapely.to_wkb(boxes),
        "bbox": pa.array([{"xmin": a, "xmax": a + b, "ymin": c, "ymax": c + e} for a, b, c, e in zip(x0, w, y0, d)]),
        "version": pa.array(rng.integers(0, 4, n), pa.int32()),
        "sources": pa.array([[{"property": "", "dataset": datasets[int(rng.integers(4))],
                               "record_id": f"w{int(rng.integers(1e9))}@{int(rng.integers(1, 9))}",
                               "update_time": f"2024-0{int(rng.integers(1, 10))}-1{int(rng.integers(0, 10))}T00:00:00Z",
                               "confidence": None}] for _ in range(n)]),
        "names": pa.array([{"primary": f"Building {int(rng.integers(1e6))}"} if rng.random() < 0.05 else None
                           for _ in range(n)]),
        "subtype": pa.array([("residential", "commercial", None)[int(rng.integers(3))] for _ in range(n)]),
        "class": pa.array([("house", "apartments", None, None)[int(rng.integers(4))] for _ in range(n)]),
        "height": pa.array(np.where(rng.random(n) < 0.6, rng.uniform(3, 30, n), np.nan)),
        "num_floors": pa.array(rng.integers(1, 9, n), pa.int32()),
        "roof_shape": pa.array([("gabled", "flat", "hipped", None)[int(rng.integers(4))] for _ in range(n)]),
    }).replace_schema_metadata({b"geo": json.dumps({"version": "1.1.0", "primary_column": "geometry",
                                                    "columns": {"geometry": {"encoding": "WKB"}}}).encode()})
    pq.write_table(table, path, row_group_size=row_group, compression="zstd")


def sparse_copy(path: Path, spans, target: Path) -> Path:
    with open(path, "rb") as src, open(target, "wb") as out:
        out.truncate(path.stat().st_size)
        for a, b in spans:
            src.seek(a)
            out.seek(a)
            out.write(src.read(b - a))
    return target


def main(argv=None) -> None:
    from meshsom.gis import gis_ranges, parquet_planned_spans, parquet_spans, planner_columns
    from meshsom.io import ReaderOptions

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--buildings", type=int, default=400_000)
    ap.add_argument("--row-group", type=int, default=50_000)
    ap.add_argument("--range", type=int, default=100_000)
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "buildings.parquet"
        write_overture(path, args.buildings, args.row_group)
        size = path.stat().st_size
        planned = parquet_planned_spans(path, size, planner_columns(ReaderOptions()))
        task = parquet_spans(path, args.range, 2 * args.range)
        copied = sum(b - a for a, b in planned)
        print(f"{args.buildings:,} Overture-like buildings, {size / 1e6:.1f} MB in row groups of {args.row_group:,}")
        print(f"  the planner copies  {copied / 1e6:8.2f} MB  {100 * copied / size:5.1f} % of the file "
              f"(before: all of it)")
        print(f"  a task of {args.range:,} rows {sum(b - a for a, b in task) / 1e6:8.2f} MB  "
              f"{100 * sum(b - a for a, b in task) / size:5.1f} %")
        sparse = sparse_copy(path, planned, Path(tmp) / "planned.parquet")
        times = {}
        for name, p in (("whole file", path), ("planner's copy", sparse)):
            gis_ranges(p, args.range, ReaderOptions())
            best = []
            for _ in range(2):
                t = time.perf_counter()
                ranges = gis_ranges(p, args.range, ReaderOptions())
                best.append(time.perf_counter() - t)
            times[name] = min(best)
            print(f"  planning on the {name:15s} {times[name]:.3f} s  ({len(ranges)} ranges, ids {ranges[0][3]!r})")


if __name__ == "__main__":
    main()
