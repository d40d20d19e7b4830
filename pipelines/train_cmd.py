"""``meshsom train STORE --level L --kernel default|bmuofn``: train one level's triangle map.

Reads ``rings/level{L}`` of an encoded store, standardizes it with the stored statistics,
trains the SOM (default kernel: the identity variation only; bmuofn: the level's variation
table), prints the T-, Q- and QC-errors (or one JSON object with ``--json``) and saves the
map in ``runs/level{L}-{kernel}`` of the store. It runs the training of ``meshsom run``
(:func:`pipelines.train.train_spec`) on an in-process executor, so the same settings give the
same codebook and errors as the corresponding map of ``meshsom run``.
"""

from __future__ import annotations

import argparse
import json

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


def run(args: argparse.Namespace) -> int:
    from meshsom.errors import StoreError
    from meshsom.som import default_sigma_start
    from meshsom.store import open_store, rings_array
    from pipelines.cluster import connect_serial
    from pipelines.train import TrainJob, train_spec

    group = open_store(args.store, mode="r+")
    if rings_array(group, args.level).shape[0] == 0:
        raise StoreError(f"{args.store}: rings/level{args.level} holds no vectors")
    rows, cols = args.map
    job = TrainJob(
        store=str(args.store), level=args.level, kernel=args.kernel, mirror=bool(args.mirror), rows=rows, cols=cols,
        topology=args.topology, epochs=args.epochs,
        sigma_start=float(args.sigma_start if args.sigma_start is not None else default_sigma_start(rows, cols)),
        sigma_end=float(args.sigma_end), init=args.init, seed=args.seed, backend=args.backend, device=args.device,
        layout=args.layout, name=args.run,
    )
    with connect_serial() as client:
        result = train_spec(client, job)
    metrics = result["metrics"]
    engine = {k: result[k] for k in ("backend", "device", "layout", "fallback")}
    report = {
        **metrics, **engine, "level": args.level, "kernel": args.kernel,
        "map_rows": rows, "map_cols": cols, "epochs": args.epochs, "seconds": result["seconds"],
        "n_vectors": result["n_vectors"], "dims": result["dims"], "run": job.run,
    }
    if args.json:
        print(json.dumps(report))
    else:
        print(f"level {args.level} ({args.kernel}, {result['dims']}) on a {rows}x{cols} {args.topology} map, "
              f"{args.epochs} epochs, {result['n_vectors']} vectors, {result['seconds']:.2f} s on {engine['backend']} "
              f"({engine['device']}" + (f", kernel layout {engine['layout']})" if engine["backend"] == "opencl" else ")"))
        if engine["fallback"]:
            print(f"kernel fallback: {engine['fallback']}")
        print(f"T-error {metrics['t_error']:.5f}  Q-error {metrics['q_error']:.5f}  QC-error {metrics['qc_error']:.5f}")
        print(f"saved runs/{job.run}")
    return 0
