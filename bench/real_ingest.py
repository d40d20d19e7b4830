"""The bundled real data through ``meshsom ingest``, with three reader settings; a table per setting.

    PYTHONPATH=. .venv/bin/python bench/real_ingest.py [--data data/real] [--out out/real_ingest] [--json F]

For every data set (each CityJSON file of ``data/real``) and every setting (default options,
``--extrude-lod1``, ``--parts separate``) it runs ``meshsom ingest`` in-process and prints: meshes in,
accepted (and of those, rebuilt under their roofs), rejected (with the reasons, counted), the accepted
meshes made of several closed shells,
and the total outer area and volume of the accepted meshes (from the stored triangles). Run it on two
versions of the code (PYTHONPATH pointing to each) and compare the JSON files to see what a change did.
"""

from __future__ import annotations

import argparse
import collections
import json
import re
import shutil
from pathlib import Path

import numpy as np
from scipy import sparse
from scipy.sparse.csgraph import connected_components

ROOT = Path(__file__).resolve().parents[1]
SETTINGS = {"default": [], "extrude-lod1": ["--extrude-lod1"], "parts-separate": ["--parts", "separate"]}


def shells(faces: np.ndarray) -> int:
    """Edge-connected components of a triangle mesh."""
    from meshsom.topology import edge_table

    _, edge_of, _ = edge_table(faces)
    order = np.argsort(edge_of, kind="stable")
    pairs = order.reshape(-1, 2) // 3 if len(order) % 2 == 0 else np.zeros((0, 2), np.int64)
    n = len(faces)
    g = sparse.coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    return int(connected_components(g, directed=False)[0])


def measure(store: Path) -> dict:
    """Counts, reasons, multi-shell meshes and totals of one store."""
    from meshsom.store import iter_meshes, mesh_table, open_store, read_manifest

    man = read_manifest(store)
    records = man["records"]
    reasons = collections.Counter(
        re.sub(r"\d+(\.\d+)?", "N", re.sub(r"part \S+ is", "part P is", r["reason"])) for r in records if r["status"] == "rejected"
    )
    out = {"inputs": len(records), "accepted": sum(r["status"] == "accepted" for r in records),
           "rejected": sum(r["status"] == "rejected" for r in records), "reasons": dict(reasons.most_common()),
           "rebuilt": sum(r["status"] == "accepted" and "envelope" in r for r in records),
           "multi_shell": 0, "area": 0.0, "volume": 0.0, "per_mesh": {}}
    if out["accepted"] == 0:
        return out
    group = open_store(store)
    ids = mesh_table(group).ids
    for i, v, f in iter_meshes(group):
        a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
        area = float(0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1).sum())
        volume = float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6)
        n_shells = shells(f)
        out["multi_shell"] += n_shells > 1
        out["area"] += area
        out["volume"] += volume
        out["per_mesh"][str(ids[i])] = [area, volume, n_shells]
    return out


def main(argv=None) -> int:
    from pipelines.cli import main as cli

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default=str(ROOT / "data" / "real"))
    ap.add_argument("--out", default=str(ROOT / "out" / "real_ingest"))
    ap.add_argument("--json", help="write the full results (per mesh too) here")
    args = ap.parse_args(argv)
    out = Path(args.out)
    files = sorted(Path(args.data).rglob("*.city.json"))
    results = {}
    for setting, flags in SETTINGS.items():
        for f in files:
            store = out / f"{f.stem}-{setting}.zarr"
            shutil.rmtree(store, ignore_errors=True)
            cli(["ingest", str(f), "--out", str(store), "--overwrite", *flags])
            r = measure(store)
            results[f"{f.name} {setting}"] = r
            print(f"{f.name:42s} {setting:15s} in {r['inputs']:4d} accepted {r['accepted']:4d} (rebuilt under "
                  f"roofs {r['rebuilt']:3d}) rejected {r['rejected']:3d} multi-shell {r['multi_shell']:3d} area {r['area']:12.1f} m2 "
                  f"volume {r['volume']:12.1f} m3")
            for reason, n in r["reasons"].items():
                print(f"    {n:4d} x {reason}")
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
