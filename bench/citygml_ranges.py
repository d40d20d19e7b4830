"""A city in one CityGML file: finding its members' byte ranges, and the time and memory of a read task.

    .venv/bin/python bench/citygml_ranges.py [--copies 40] [--ranges 10] [--repeat 2]

Writes the bundled Delft buildings ``--copies`` times side by side (each copy moved 2 km east) into one CityGML 2.0
file (:func:`meshsom.citygml.write_citygml`: a ``cityObjectMember`` per Building, a line each, as city portals'
exports are), then prints, best of ``--repeat`` after a warm-up:

- the scan that finds every member's bytes (:func:`meshsom.citygml.citygml_ranges`), in MB/s, against the reference
  measured in the same run: ``xml.etree.ElementTree.iterparse`` over the whole file, each member cleared once parsed
  (the least a whole read parses);
- the seconds and peak memory (RSS) of a fresh process that reads the file whole as one read task of ``meshsom
  ingest`` does (:func:`pipelines.corpus.read_source`: its items held, to be shipped to the shards), and of one that
  reads one of ``--ranges`` ranges (a read task of a ranged plan).
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import tempfile
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from bench.common import best_warm, print_reads  # noqa: E402

DELFT = ROOT / "data" / "real" / "delft-lod1-3dfier" / "delft.city.json"
#: How far each copy of the buildings is moved east, metres.
STEP = 2000.0

def write_city(path: Path, copies: int) -> int:
    """Delft's buildings ``copies`` times in one CityGML file; the Buildings written."""
    from meshsom.citygml import write_citygml
    from meshsom.io import RawMesh, read_file

    buildings = [m for m in read_file(DELFT) if isinstance(m, RawMesh)]

    def meshes():
        for c in range(copies):
            for m in buildings:
                yield dataclasses.replace(m, id=f"{m.id.split('#')[1]}-{c}",
                                          vertices=m.vertices + m.origin + np.array([STEP * c, 0.0, 0.0]))

    write_citygml(path, meshes())
    return copies * len(buildings)


def iterparse(path: Path) -> int:
    """The members of a file, parsed by ElementTree and let go (the reference)."""
    n = 0
    for _, element in ET.iterparse(path):
        if element.tag.endswith("}cityObjectMember"):
            n += 1
            element.clear()
    return n


def main(argv=None) -> int:
    from meshsom.citygml import citygml_ranges
    from meshsom.io import ReaderOptions

    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--copies", type=int, default=40)
    parser.add_argument("--ranges", type=int, default=10)
    parser.add_argument("--repeat", type=int, default=2)
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "city.gml"
        n = write_city(path, args.copies)
        size = path.stat().st_size
        mb = size / 1e6
        target = -(-size // args.ranges)
        ranges = citygml_ranges(path, target, ReaderOptions())
        assert ranges is not None and iterparse(path) == n
        scan = best_warm(lambda: citygml_ranges(path, target, ReaderOptions()), args.repeat)
        parse = best_warm(lambda: iterparse(path), args.repeat)
        print(f"{n:,} buildings, {mb:.1f} MB of CityGML 2.0, {len(ranges)} ranges")
        print("| step | seconds | MB/s | ratio to iterparse |")
        print("|---|---|---|---|")
        print(f"| ElementTree iterparse of the whole file (reference) | {parse:.2f} | {mb / parse:.0f} | 1.00 |")
        print(f"| citygml_ranges (the scan) | {scan:.2f} | {mb / scan:.0f} | {scan / parse:.2f} |")
        print_reads(path, ranges[len(ranges) // 2])
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
