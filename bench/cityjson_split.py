"""A city in one CityJSON file, split into a CityJSONSeq for ranged reading: seconds and memory.

    .venv/bin/python bench/cityjson_split.py [--copies 60] [--repeat 2]

Writes one CityJSON document of ``--copies`` copies of the bundled Zürich LoD 2 file side by side (objects
renamed, vertices shifted, one shared vertex list, as a city's file is), then prints, best of ``--repeat`` after a
warm-up: :func:`meshsom.cityjson_split.split_cityjson` against the reference measured in the same run, ``json.loads``
of the document (what any whole read parses first), in MB/s; and the peak memory (RSS) of a fresh process that
splits it.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from bench.common import PEAK_MB, best_warm  # noqa: E402
ZURICH = ROOT / "data" / "real" / "zurich-lod2-subset" / "zurich_subset_lod2.city.json"

SPLIT = """
import sys
{peak}sys.path.insert(0, {root!r})
from pathlib import Path
from meshsom.cityjson_split import split_cityjson
from meshsom.io import ReaderOptions
n = split_cityjson(Path({path!r}), Path({out!r}), ReaderOptions())
print(n, peak_mb())
"""


def write_city(path: Path, copies: int) -> int:
    """``copies`` of the Zürich file in one document; its number of objects."""
    base = json.loads(ZURICH.read_text())
    objects, vertices = {}, []
    shift = 2_000_000  # 2 km in the file's integer units (scale 0.001), the copies side by side
    for k in range(copies):
        offset = len(vertices)
        vertices += [[x + shift * (k % 8), y + shift * (k // 8), z] for x, y, z in base["vertices"]]

        def moved(b):
            return [moved(c) for c in b] if isinstance(b, list) else b + offset

        for oid, obj in base["CityObjects"].items():
            copy = dict(obj)
            copy["geometry"] = [{**g, "boundaries": moved(g["boundaries"])} for g in obj.get("geometry", [])]
            for key in ("children", "parents"):
                if key in obj:
                    copy[key] = [f"{c}-{k}" for c in obj[key]]
            objects[f"{oid}-{k}"] = copy
    document = {**{k: v for k, v in base.items() if k not in ("CityObjects", "vertices", "appearance")},
                "CityObjects": objects, "vertices": vertices}
    path.write_text(json.dumps(document, separators=(",", ":")))
    return len(objects)


def main(argv=None) -> int:
    from meshsom.cityjson_split import split_cityjson
    from meshsom.io import ReaderOptions

    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--copies", type=int, default=60)
    parser.add_argument("--repeat", type=int, default=2)
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory() as folder:
        path, out = Path(folder) / "city.city.json", Path(folder) / "city.city.jsonl"
        n = write_city(path, args.copies)
        mb = path.stat().st_size / 1e6
        parse = best_warm(lambda: json.loads(path.read_bytes()), args.repeat)
        split = best_warm(lambda: split_cityjson(path, out, ReaderOptions()), args.repeat)
        features = len(out.read_text().splitlines()) - 1
        done = subprocess.run([sys.executable, "-c", SPLIT.format(root=str(ROOT), path=str(path), out=str(out), peak=PEAK_MB)],
                              capture_output=True, text=True, check=True).stdout.split()
        print(f"{n:,} objects ({features:,} features), {mb:.1f} MB")
        print("| step | seconds | MB/s | ratio to json.loads |")
        print("|---|---|---|---|")
        print(f"| json.loads of the document (reference) | {parse:.2f} | {mb / parse:.0f} | 1.00 |")
        print(f"| split_cityjson | {split:.2f} | {mb / split:.0f} | {split / parse:.2f} |")
        print(f"\npeak memory of a fresh process splitting it: {float(done[1]):.0f} MB ({float(done[1]) / mb:.1f}x the file)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
