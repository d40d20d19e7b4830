"""``meshsom tune``: time the GPU layout's tilings on this machine's OpenCL device and keep the fastest.

See :mod:`meshsom.tuning`. Prints one line per candidate and workload, the geometric mean of each
candidate's time over the default's, and where the winner was saved; every later search on the
device (this process's, other processes', Dask workers' on this machine) uses it.
"""

from __future__ import annotations

import argparse


def _workload(text: str) -> tuple[int, int, int]:
    try:
        N, n, D = (int(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"--workload takes N,n,D (three whole numbers), received {text!r}") from None
    if min(N, n, D) < 1:
        raise argparse.ArgumentTypeError(f"--workload takes positive N,n,D, received {text!r}")
    return N, n, D


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--device", default=None,
                   help="OpenCL device: a 'platform:device' index pair or a name substring such as nvidia "
                        "(default: $PYOPENCL_CTX, else the first device)")
    p.add_argument("--workload", action="append", default=None, metavar="N,n,D", type=_workload,
                   help="a pass to time: rows, variations, dimension (repeatable; default the paper's level 2 and 3 "
                        "passes at a million rows and at 3,064)")
    p.add_argument("--quick", action="store_true", help="the workloads' rows divided by 50 (a check, not a tuning)")
    p.add_argument("--repeat", type=int, default=2, help="timed passes per candidate after the warm-up (best counts)")
    p.add_argument("--dry-run", action="store_true", help="time and print, save nothing")
    p.add_argument("--forget", action="store_true", help="delete the device's tuning (the default tiling again) and stop")


def run(args: argparse.Namespace) -> int:
    from meshsom import tuning
    from meshsom.bmu_opencl import device_name, get_context
    from meshsom.errors import MeshsomError

    if args.repeat < 1:
        raise MeshsomError(f"--repeat must be at least 1, received {args.repeat}")
    workloads = args.workload or None
    context = get_context(args.device)
    name = device_name(context)
    if args.forget:
        print(f"{name}: {'tuning deleted' if tuning.forget(context) else 'was not tuned'}")
        return 0
    print(f"tuning the '{tuning.LAYOUT}' layout on {name}: {len(tuning.CANDIDATES)} candidates, seconds per pass")
    def line(t: tuning.Timing) -> None:
        N, n, D = t.workload
        head = f"{N:>9} {f'{n}x{D}':>7} {tuning.candidate_name(tuning.CANDIDATES[t.candidate]):>36}"
        print(f"{head} {t.why}" if t.seconds is None else
              f"{head} {t.seconds:9.4f} s  {2.0 * N * n * tuning.UNITS * D / t.seconds / 1e9:9.1f} GFLOP/s")

    result = tuning.tune(context, workloads=workloads, repeat=args.repeat, quick=args.quick, report=line)
    if not result.ratios:
        raise MeshsomError(f"{name}: the default tiling did not run on any workload; nothing to compare "
                           "(see the lines above)")
    print("time over the default's (geometric mean over the workloads):")
    for c, ratio in sorted(result.ratios.items(), key=lambda item: item[1]):
        print(f"  {ratio:6.3f}  {tuning.candidate_name(result.candidates[c])}")
    winner = tuning.candidate_name(result.fields)
    if result.best == 0:
        print(f"the default stays (no candidate saves {100 * (1 - tuning.MIN_RATIO):.0f} % of its time)")
    else:
        print(f"fastest: {winner}, {result.ratios[result.best]:.3f} x the default's time")
    if args.dry_run or args.quick:
        print("not saved (" + ("--dry-run" if args.dry_run else "--quick") + ")")
        return 0
    path = tuning.save(context, result)
    print(f"saved for {name}: {path}")
    return 0
