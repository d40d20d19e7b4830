"""The ``meshsom`` command line.

Each subcommand lives in its own module of ``pipelines`` that defines
``add_arguments(parser)`` and ``run(args) -> int``; this file only dispatches.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import sys

from meshsom.errors import MeshsomError

#: subcommand -> (module, one-line help)
COMMANDS = {
    "doctor": ("pipelines.doctor", "print versions, OpenCL platforms and devices, Dask and MLflow settings"),
    "generate": ("pipelines.generate_cmd", "write a seeded synthetic corpus of labelled building blocks"),
    "ingest": ("pipelines.ingest", "read, clean and store buildings (city models, BIM (IFC), GIS files, 3D Tiles, meshes, zips, folders)"),
    "encode": ("pipelines.encode_cmd", "encode every cleaned face into nested N-ring fold vectors (rings/level{L})"),
    "synth": ("pipelines.synth_cmd", "synthesize triangle patches from ring vectors or map prototypes (mesh files + contact sheet)"),
    "log": ("pipelines.log_cmd", "send a run's results from the store to MLflow (after the server was unreachable)"),
    "run": ("pipelines.run", "run a whole experiment from a YAML config (configs/paper.yaml)"),
    "report": ("pipelines.report_cmd", "regenerate the paper's tables and figures and check its claims (report.md)"),
    "runs": ("pipelines.runs_cmd", "list the tracked maps side by side: config, level, kernel, backend, T/Q/QC-errors"),
    "inspect": ("pipelines.inspect_cmd", "summarize a store: manifest, arrays, trained maps, fold statistics"),
    "train": ("pipelines.train_cmd", "train one level's triangle map (default or BMUofN kernel) and print T/Q/QC-errors"),
    "tune": ("pipelines.tune_cmd", "time the GPU kernel's tilings on this machine's OpenCL device and keep the fastest"),
}


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="meshsom",
        description="Unsupervised symmetric polygon-mesh mapping: fold encoding, BMUofN SOMs, domain maps.",
    )
    parser.add_argument("-v", "--verbose", action="store_true", help="log debug messages")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name, (module, help_text) in COMMANDS.items():
        p = sub.add_parser(name, help=help_text, description=help_text)
        importlib.import_module(module).add_arguments(p)
        p.set_defaults(_module=module)
    return parser


#: Libraries whose INFO messages the commands do not show (their warnings they do).
QUIET_LOGGERS = ("trimesh", "matplotlib")


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if hasattr(sys.stdout, "reconfigure"):
        sys.stdout.reconfigure(line_buffering=True)  # progress lines appear at once in logs and pipes
    logging.basicConfig(
        level=logging.DEBUG if args.verbose else logging.INFO,
        format="%(levelname)s %(name)s: %(message)s",
    )
    for name in QUIET_LOGGERS:  # their INFO lines ("triangulating faces" per OBJ polygon file) are not news
        logging.getLogger(name).setLevel(logging.WARNING)
    from meshsom.caches import ensure_user_cache

    ensure_user_cache()  # before any worker or child starts: they inherit a writable cache folder
    try:
        return int(importlib.import_module(args._module).run(args) or 0)
    except MeshsomError as err:
        print(f"meshsom {args.command}: error: {err}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"meshsom {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
