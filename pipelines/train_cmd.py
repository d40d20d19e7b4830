"""``meshsom train STORE --level L --kernel default|bmuofn``: train one level's triangle map.

Reads ``rings/level{L}`` of an encoded store, standardizes it with the stored statistics,
trains the SOM (default kernel: the identity variation only; bmuofn: the level's variation
table), prints the T-, Q- and QC-errors (or one JSON object with ``--json``) and saves the
map in ``runs/level{L}-{kernel}`` of the store.
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from meshsom.config import BACKENDS, KERNELS, LAYOUTS, TOPOLOGIES, SOMConfig, parse_layouts


def _map_size(text: str) -> tuple[int, int]:
    try:
        rows, cols = (int(p) for p in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"--map must look like ROWSxCOLS (e.g. 120x150), received {text!r}") from None
    if rows < 2 or cols < 2:
        raise argparse.ArgumentTypeError(f"--map must be at least 2x2, received {text!r}")
    return rows, cols


def _layouts(text: str) -> str:
    try:
        return ",".join(parse_layouts(text))
    except ValueError as err:
        raise argparse.ArgumentTypeError(str(err)) from None


def add_arguments(parser: argparse.ArgumentParser) -> None:
    defaults = SOMConfig()
    parser.add_argument("store", help="encoded zarr store (made by `meshsom ingest` + encode)")
    parser.add_argument("--level", type=int, required=True, help="ring level to train (1..8)")
    parser.add_argument("--kernel", choices=KERNELS, default="bmuofn",
                        help="default: raw vertex order only; bmuofn: best of the level's variations")
    parser.add_argument("--map", type=_map_size, default=(defaults.rows, defaults.cols), metavar="ROWSxCOLS",
                        help=f"map size (default {defaults.rows}x{defaults.cols})")
    parser.add_argument("--topology", choices=TOPOLOGIES, default=defaults.topology)
    parser.add_argument("--epochs", type=int, default=defaults.epochs)
    parser.add_argument("--seed", type=int, default=defaults.seed)
    parser.add_argument("--sigma-start", type=float, default=defaults.sigma_start,
                        help="first neighbourhood radius in cells (default max(rows, cols) / 4)")
    parser.add_argument("--sigma-end", type=float, default=defaults.sigma_end)
    parser.add_argument("--init", choices=("random", "pca"), default=defaults.init)
    parser.add_argument("--backend", choices=BACKENDS, default="auto")
    parser.add_argument("--device", default=None, help="OpenCL device selector (\"0:0\", \"pocl\", ...)")
    parser.add_argument("--layout", type=_layouts, default=None,
                        help=f"OpenCL kernel layouts to try in order instead of the device's chain, comma-separated "
                             f"(of {', '.join(LAYOUTS)}; `meshsom doctor` shows which work)")
    parser.add_argument("--mirror", action="store_true", help="add mirror variations (levels >= 2)")
    parser.add_argument("--run", default=None, help="run name (default level{L}-{kernel})")
    parser.add_argument("--json", action="store_true", help="print one JSON object")


def load_level(group, level: int) -> np.ndarray:
    """Standardized fold vectors of a level, read chunk by chunk.

    Returns
    -------
    (F, D) float32
    """
    from meshsom.standardize import standardize
    from meshsom.store import iter_row_chunks, read_stats, rings_array

    rings = rings_array(group, level)
    stats = read_stats(group, level)
    parts = [np.asarray(standardize(np.asarray(rings[a:b]), stats), np.float32) for a, b in iter_row_chunks(rings)]
    return np.concatenate(parts) if parts else np.zeros((0,) + tuple(rings.shape[1:]), np.float32)


def run(args: argparse.Namespace) -> int:
    from meshsom.codebook import save_codebook
    from meshsom.errors import StoreError
    from meshsom.som import SOM
    from meshsom.store import open_store
    from meshsom.variations import variation_table

    group = open_store(args.store, mode="r+")
    X = load_level(group, args.level)
    if len(X) == 0:
        raise StoreError(f"{args.store}: rings/level{args.level} holds no vectors")
    index, sign = variation_table(args.level, mirror=args.mirror)
    if args.kernel == "default":
        index, sign = index[:1], sign[:1]
    rows, cols = args.map
    som = SOM(rows=rows, cols=cols, topology=args.topology, epochs=args.epochs, sigma_start=args.sigma_start,
              sigma_end=args.sigma_end, init=args.init, random_state=args.seed, backend=args.backend,
              device=args.device, layout=args.layout)
    t0 = time.perf_counter()
    som.fit(X, index, sign)
    seconds = time.perf_counter() - t0
    bmu = som.transform(X)
    from meshsom.metrics import q_error, qc_error, t_error

    metrics = {
        "t_error": t_error(bmu.unit, bmu.second, rows, cols, args.topology),
        "q_error": q_error(X, som.weights_, bmu, index, sign),
        "qc_error": qc_error(X, som.weights_, bmu, index, sign) if X.shape[1] % 3 == 0 else float("nan"),
    }
    run_name = args.run or f"level{args.level}-{args.kernel}"
    engine = som.engine_.describe(X.shape[1], len(index), X.dtype)
    save_codebook(group, run_name, som.weights_, rows, cols, args.topology, level=args.level, kernel=args.kernel,
                  metrics=metrics, bmu=bmu,
                  extra={"epochs": args.epochs, "seed": args.seed, **engine, "mirror": bool(args.mirror), "n_variations": int(len(index)), "seconds": seconds})
    report = {
        **metrics, **engine, "level": args.level, "kernel": args.kernel,
        "map_rows": rows, "map_cols": cols, "epochs": args.epochs, "seconds": seconds,
        "n_vectors": int(len(X)), "dims": f"{len(index)}x{X.shape[1]}", "run": run_name,
    }
    if args.json:
        print(json.dumps(report))
    else:
        print(f"level {args.level} ({args.kernel}, {len(index)}x{X.shape[1]}) on a {rows}x{cols} {args.topology} map, "
              f"{args.epochs} epochs, {len(X)} vectors, {seconds:.2f} s on {som.backend_} ({som.device_}"
              + (f", kernel layout {engine['layout']})" if som.backend_ == "opencl" else ")"))
        if engine["fallback"]:
            print(f"kernel fallback: {engine['fallback']}")
        print(f"T-error {metrics['t_error']:.5f}  Q-error {metrics['q_error']:.5f}  QC-error {metrics['qc_error']:.5f}")
        print(f"saved runs/{run_name}")
    return 0
