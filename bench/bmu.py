"""One BMUofN pass per backend on the paper's 120 x 150 map; GFLOP/s against SGEMM and plain BLAS.

Run (timings without the OpenBLAS variables that slow a current numpy):

    env -u OPENBLAS_CORETYPE -u OPENBLAS_L2_SIZE .venv/bin/python bench/bmu.py [--quick]

Columns: backend, seconds per pass (best of --repeat), GFLOP/s with 2 * N * n * M * D flops
per pass, that rate as % of numpy's float32 SGEMM measured in the same run, and the pass
time over n plain NumPy/BLAS n = 1 passes on the same data (< 1: BMUofN is cheaper than n
separate searches).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.common import MAP, QUICK_WORKLOADS, WORKLOADS, best_time, block_table, data, machine_note, sgemm_gflops  # noqa: E402
from meshsom.bmu_numpy import bmu_numpy, identity_table  # noqa: E402


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true", help="small N for the city-sized workloads, SGEMM 2048^3")
    parser.add_argument("--repeat", type=int, default=2)
    parser.add_argument("--device", default=None, help="OpenCL device selector")
    parser.add_argument("--no-opencl", action="store_true")
    parser.add_argument("--kernel", action="append", choices=["cpu", "gemm", "tiled"], default=None,
                        help="OpenCL kernel variant(s) to time (repeatable); default: the device type's default")
    args = parser.parse_args(argv)

    rows, cols = MAP
    M = rows * cols
    print(machine_note())
    gemm_size = 2048 if args.quick else 4096
    sgemm = sgemm_gflops(gemm_size)
    print(f"SGEMM numpy float32 {gemm_size}^3: {sgemm:.1f} GFLOP/s")

    backends = [("numpy", None)]
    if not args.no_opencl:
        try:
            from meshsom.bmu_opencl import DEFAULT_PARAMS, bmu_opencl, default_params, device_name, get_context

            ctx = get_context(args.device)
            print(f"OpenCL device: {device_name(ctx)}")
            if args.kernel is None:
                params = default_params(ctx)
                backends.append(("opencl", (ctx, params)))
                print(f"OpenCL kernel: {params}")
            for kernel in args.kernel or ():
                params = DEFAULT_PARAMS[{"cpu": "cpu", "gemm": "gpu", "tiled": "tiled"}[kernel]]
                backends.append((f"cl-{kernel}", (ctx, params)))
                print(f"OpenCL kernel {kernel}: {params}")
        except Exception as err:  # noqa: BLE001 - a benchmark reports and goes on
            print(f"OpenCL skipped: {err}")

    print(f"\nmap {rows}x{cols} (M = {M})")
    header = f"{'N':>7} {'n x D':>7} {'backend':>8} {'s/pass':>8} {'GFLOP/s':>8} {'%SGEMM':>7} {'vs n BLAS':>9}"
    print(header)
    print("-" * len(header))
    for N, n, D in (QUICK_WORKLOADS if args.quick else WORKLOADS):
        X, W = data(N, D, M)
        index, sign = block_table(n, D)
        plain = best_time(lambda: bmu_numpy(X, W, *identity_table(D)), args.repeat)
        flops = 2.0 * N * n * M * D
        print(f"{N:>7} {f'{n}x{D}':>7} {'BLAS n=1':>8} {plain:8.3f} {2.0 * N * M * D / plain / 1e9:8.1f} "
              f"{100 * 2.0 * N * M * D / plain / 1e9 / sgemm:6.1f}% {'':>9}")
        for name, setup in backends:  # setup: None (NumPy) or (context, kernel params)
            if name == "numpy":
                fn = lambda: bmu_numpy(X, W, index, sign)  # noqa: E731
            else:
                context, params = setup
                fn = lambda: bmu_opencl(X, W, index, sign, context=context, params=params)  # noqa: E731
                bmu_opencl(X[:64], W, index, sign, context=context, params=params)  # build outside the timing
            t = best_time(fn, args.repeat)
            rate = flops / t / 1e9
            print(f"{N:>7} {f'{n}x{D}':>7} {name:>8} {t:8.3f} {rate:8.1f} {100 * rate / sgemm:6.1f}% {t / (n * plain):9.2f}")
        sys.stdout.flush()
    return 0


if __name__ == "__main__":
    sys.exit(main())
