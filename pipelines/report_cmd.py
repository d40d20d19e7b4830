"""``meshsom report``: every table and figure of the paper's Results section, from tracked runs.

A thin wrapper around :func:`reports.report.make_report` (see :mod:`reports.report`).
"""

from __future__ import annotations

import argparse


def add_arguments(p: argparse.ArgumentParser) -> None:
    from reports.report import add_arguments as report_arguments

    report_arguments(p)


def run(args: argparse.Namespace) -> int:
    from reports.report import claims_text, make_report

    res = make_report(args.tracking_uri, args.experiment, args.out, args.clustering_experiment,
                      None if args.also is None else tuple(args.also), runs=tuple(args.runs))
    print(claims_text(res["claims"]), end="")  # report.md keeps the Markdown table
    print(f"\nfull report: {res['report']}")
    return 0
