"""How far the NumPy/BLAS and OpenCL backends differ on trained maps (BMUofN near-ties).

Both backends compute ||x_v - w||^2 in float32 as ||w||^2 - 2 x_v.w (+ ||x_v||^2), but sum the
dot products in different orders (BLAS blocks, the kernel a sequential FMA), so where two
(unit, variation) candidates lie within float32 rounding of each other they can pick different
winners. This script runs every OpenCL layout that works on the device and the NumPy backend on
every trained map of a store (``meshsom run configs/paper.yaml`` first), and prints, per map and
layout: the rows whose unit or variation differ, and for those rows the largest gap between the
two winners' exact (float64) distances, relative to the distance.

    python bench/backends.py out/paper.zarr [--device pocl]
"""

from __future__ import annotations

import argparse

import numpy as np


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("store", help="a store with trained maps (runs/level*-*)")
    p.add_argument("--device", default=None, help="OpenCL device selector")
    args = p.parse_args(argv)

    from meshsom.bmu_numpy import bmu_numpy, exact_dist2
    from meshsom.bmu_opencl import DEFAULT_PARAMS, bmu_opencl, get_context, layout_chain, layout_params, probe_layout
    from meshsom.codebook import load_codebook
    from meshsom.store import open_store
    from meshsom.variations import variation_table
    from pipelines.train import load_level

    group = open_store(args.store)
    context = get_context(args.device)
    device = context.devices[0]
    chain = layout_chain(device)
    print(f"device: {device.platform.name.strip()} / {device.name.strip()}; layouts {', '.join(chain)}")
    print(f"{'map':16s} {'rows':>7s} {'layout':10s} {'unit differs':>13s} {'variation differs':>18s} "
          f"{'max rel. gap':>13s}")
    for run in sorted(group["runs"].group_keys()):
        cb = load_codebook(group, run)
        if cb.level is None or "source" in (cb.attrs.get("job") or {}) and cb.attrs["job"].get("source"):
            continue
        X = load_level(group, int(cb.level))
        index, sign = variation_table(int(cb.level), mirror=bool((cb.attrs.get("job") or {}).get("mirror", False)),
                                      kernel=cb.kernel)
        ref = bmu_numpy(X, cb.weights, index, sign)
        for name in DEFAULT_PARAMS:
            if name not in chain or not probe_layout(context, name, X.shape[1], len(index)).ok:
                continue
            got = bmu_opencl(X, cb.weights, index, sign, context=context, params=layout_params(device, name))
            unit = got.unit != ref.unit
            var = got.variation != ref.variation
            differ = unit | var
            d_ref = exact_dist2(X, cb.weights, index, sign, ref.unit, ref.variation)
            d_got = exact_dist2(X, cb.weights, index, sign, got.unit, got.variation)
            gap = np.abs(d_got - d_ref)[differ] / np.maximum(d_ref[differ], 1e-30)
            print(f"{run:16s} {len(X):7d} {name:10s} {int(unit.sum()):6d} ({unit.mean():6.3%}) "
                  f"{int(var.sum()):8d} ({var.mean():6.3%}) {gap.max() if len(gap) else 0.0:13.2e}", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
