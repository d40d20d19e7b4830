"""One training epoch on the paper's 120 x 150 map: meshsom (default kernel and BMUofN, per
backend) against MiniSom (``train_batch``, planar), XPySom (numpy, planar) and somoclu
(dense CPU, toroid) where importable (a printed note otherwise).

Run (timings without the OpenBLAS variables that slow a current numpy):

    env -u OPENBLAS_CORETYPE -u OPENBLAS_L2_SIZE .venv/bin/python bench/epoch.py [--quick]

A meshsom epoch is one ``partial_sums`` (the BMU search and per-unit sums) plus one
``batch_update`` (the O(M * D * (rows + cols)) separable smoothing). --quick runs the
paper-sized workloads only and skips MiniSom where it takes over 10 s an epoch.

Everything is timed in steady state, as meshsom is: a warm-up call first (MiniSom and XPySom
train once before the timed calls), and somoclu, whose ``train`` also initialises the map and
computes the U-matrix each call (seconds of fixed cost), per epoch as T(2 epochs) - T(1 epoch).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.common import MAP, best_time, block_table, data, machine_note  # noqa: E402
from meshsom.bmu_numpy import identity_table  # noqa: E402
from meshsom.som import batch_update, partial_sums  # noqa: E402

#: (N, n, D) of the BMUofN runs; the default kernel runs the same (N, D) with n = 1.
EPOCH_WORKLOADS = [(3064, 6, 9), (3064, 3, 36), (3064, 3, 144), (100_000, 3, 36)]
#: MiniSom epochs estimated above this many seconds are skipped in --quick.
QUICK_PEER_LIMIT = 10.0


def meshsom_epoch(X, W, index, sign, engine, rows, cols, sigma=5.0):
    sums, counts, _ = partial_sums(X, W, index, sign, backend=engine)
    return batch_update(W, sums, counts, sigma, rows, cols, "toroidal")


def somoclu_epoch(somoclu, X, rows, cols, repeat):
    """somoclu seconds per epoch: T(2 epochs) - T(1 epoch), each the best of ``repeat`` after a
    warm-up, so that its per-call initialisation and U-matrix are not counted."""
    def train(epochs):
        som = somoclu.Somoclu(cols, rows, kerneltype=0, maptype="toroid", initialization="random")
        som.train(X, epochs=epochs)

    train(1)  # warm-up
    return best_time(lambda: train(2), repeat) - best_time(lambda: train(1), repeat)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true", help="paper-sized workloads only; skip slow MiniSom epochs")
    parser.add_argument("--repeat", type=int, default=1)
    parser.add_argument("--device", default=None, help="OpenCL device selector")
    args = parser.parse_args(argv)
    rows, cols = MAP
    M = rows * cols
    print(machine_note())

    from meshsom.bmu import resolve_backend

    engines = [resolve_backend("numpy")]
    try:
        engines.append(resolve_backend("opencl", args.device))
        print(f"OpenCL device: {engines[-1].device}")
    except Exception as err:  # noqa: BLE001 - a benchmark reports and goes on
        print(f"OpenCL skipped: {err}")

    peers = {}
    try:
        from minisom import MiniSom

        peers["MiniSom train_batch (planar)"] = "minisom"
    except ImportError:
        print("note: MiniSom not importable (pip install minisom): skipped")
    try:
        import numpy as np
        from xpysom import XPySom

        peers["XPySom numpy (planar)"] = "xpysom"
    except ImportError:
        print("note: XPySom not importable (pip install xpysom): skipped")
    try:
        import somoclu

        peers["somoclu dense CPU (toroid)"] = "somoclu"
    except ImportError:
        print("note: somoclu not importable (CUDAHOME=/nonexistent pip install --no-build-isolation somoclu): skipped")

    workloads = [w for w in EPOCH_WORKLOADS if not (args.quick and w[0] > 10_000)]
    print(f"\nmap {rows}x{cols} (M = {M}); seconds per epoch")
    print(f"{'N':>7} {'D':>4} {'what':>34} {'s/epoch':>9} {'x best default':>15}")
    for N, n, D in workloads:
        X, W = data(N, D, M)
        index, sign = block_table(n, D)
        results = {}
        for engine in engines:
            ident = identity_table(D)
            meshsom_epoch(X[:64], W, *ident, engine, rows, cols)
            meshsom_epoch(X[:64], W, index, sign, engine, rows, cols)
            results[f"meshsom default 1x{D} {engine.backend}"] = best_time(
                lambda: meshsom_epoch(X, W, *ident, engine, rows, cols), args.repeat)
            results[f"meshsom BMUofN {n}x{D} {engine.backend}"] = best_time(
                lambda: meshsom_epoch(X, W, index, sign, engine, rows, cols), args.repeat)
        best_default = min(t for k, t in results.items() if "default" in k)
        for label, peer in peers.items():
            if peer == "minisom":
                som = MiniSom(rows, cols, D, sigma=5.0, learning_rate=0.5, random_seed=0)
                if args.quick:
                    probe = max(1, N // 20)
                    t = best_time(lambda: som.train_batch(X[:probe], probe), 1) * N / probe
                    if t > QUICK_PEER_LIMIT:
                        results[label] = float("nan")
                        print(f"{N:>7} {D:>4} {label:>34} {'skipped':>9}  (estimated {t:.0f} s; run without --quick)")
                        continue
                som.train_batch(X, N)  # warm-up
                results[label] = best_time(lambda: som.train_batch(X, N), args.repeat)
            elif peer == "xpysom":
                som = XPySom(rows, cols, D, sigma=5.0, random_seed=0, xp=np)
                som.train(X, 1)  # warm-up
                results[label] = best_time(lambda: som.train(X, 1), args.repeat)
            elif peer == "somoclu":
                results[label] = somoclu_epoch(somoclu, X, rows, cols, args.repeat)
        for label, t in results.items():
            if t == t:  # not NaN
                print(f"{N:>7} {D:>4} {label:>34} {t:9.3f} {t / best_default:15.2f}")
        sys.stdout.flush()
    return 0


if __name__ == "__main__":
    sys.exit(main())
