"""Shared helpers of the benchmarks: workloads, the SGEMM yardstick, timing, the machine note."""

from __future__ import annotations

import os
import platform
import time

import numpy as np

#: The paper's map.
MAP = (120, 150)
#: (N, n, D): the paper-sized workloads, then the city-sized ones.
WORKLOADS = [(3064, 1, 9), (3064, 6, 9), (3064, 3, 36), (3064, 3, 144), (100_000, 3, 36), (100_000, 1, 36)]
#: --quick: small N for the city-sized ones.
QUICK_WORKLOADS = [(3064, 1, 9), (3064, 6, 9), (3064, 3, 36), (3064, 3, 144), (10_000, 3, 36), (10_000, 1, 36)]


def block_table(n: int, D: int) -> tuple[np.ndarray, np.ndarray]:
    """A fold-like variation table: rotations of 3 blocks, then mirrors (sign flips), n rows."""
    b = D // 3
    blocks = np.arange(D).reshape(3, b)
    rows, signs = [], []
    for mirror in (False, True):
        for r in range(3):
            order = blocks[::-1] if mirror else blocks
            rows.append(np.roll(order, -r, axis=0).ravel())
            s = np.ones(D, np.float32)
            if mirror:
                s[::3] = -1
            signs.append(s)
    return np.array(rows[:n], np.int64), np.array(signs[:n], np.float32)


def data(N: int, D: int, M: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Random standardized-like data and codebook, float32."""
    rng = np.random.default_rng(seed)
    return rng.normal(size=(N, D)).astype(np.float32), rng.normal(size=(M, D)).astype(np.float32)


#: Code that defines ``peak_mb()``: the peak resident memory (MB) of the process's own memory (Linux's VmHWM, reset by
#: exec; elsewhere getrusage's maxrss, which keeps a forking parent's), pasted into the fresh processes a benchmark
#: measures.
PEAK_MB = """
def peak_mb():
    try:
        for line in open("/proc/self/status"):
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) / 1024
    except OSError:  # no /proc (macOS): getrusage's, which may count the forking parent's
        pass
    import resource
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
"""


def best_time(fn, repeat: int = 3, min_total: float = 0.0) -> float:
    """Best wall time of ``repeat`` calls (at least one)."""
    best = float("inf")
    for _ in range(max(1, repeat)):
        t = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t)
    return best


def best_warm(fn, repeat: int) -> float:
    """The best of ``repeat`` calls after a warm-up call."""
    fn()
    return best_time(fn, repeat)


#: A fresh process reading one source as a read task of ``meshsom ingest`` does: its items held.
READ_SOURCE = """
import sys, time, json
{peak}sys.path.insert(0, {root!r})
from meshsom.io import ReaderOptions
from pipelines.corpus import read_source
rng = json.loads({range!r})
t = time.perf_counter()
n = len(read_source({path!r}, ReaderOptions(), None, rng))
print(json.dumps({{"items": n, "seconds": time.perf_counter() - t, "peak_mb": peak_mb()}}))
"""


def fresh_read(path, byte_range) -> dict:
    """``{"items", "seconds", "peak_mb"}`` of a fresh process reading ``path`` (its ``byte_range``: None for the
    whole file) with :func:`pipelines.corpus.read_source`, its items held, as a read task of a plan does."""
    import json
    import subprocess
    import sys
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    code = READ_SOURCE.format(root=str(root), path=str(path), range=json.dumps(byte_range), peak=PEAK_MB)
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def print_reads(path, byte_range) -> None:
    """A table of a fresh process's read of the whole file and of one of its ranges (:func:`fresh_read`)."""
    whole, one = fresh_read(path, None), fresh_read(path, byte_range)
    print()
    print("| read, fresh process | items | seconds | peak RSS MB |")
    print("|---|---|---|---|")
    print(f"| whole file | {whole['items']:,} | {whole['seconds']:.1f} | {whole['peak_mb']:.0f} |")
    print(f"| one range | {one['items']:,} | {one['seconds']:.1f} | {one['peak_mb']:.0f} |")


def sgemm_gflops(size: int = 4096, repeat: int = 3) -> float:
    """numpy float32 size^3 matmul rate."""
    rng = np.random.default_rng(0)
    a = rng.normal(size=(size, size)).astype(np.float32)
    b = rng.normal(size=(size, size)).astype(np.float32)
    a @ b
    return 2 * size**3 / best_time(lambda: a @ b, repeat) / 1e9


def machine_note() -> str:
    """CPU, cores, BLAS and the OpenBLAS variables that slow it."""
    lines = [f"python {platform.python_version()}, numpy {np.__version__}, {os.cpu_count()} cores, {platform.processor() or platform.machine()}"]
    try:
        from threadpoolctl import threadpool_info

        for info in threadpool_info():
            if info.get("user_api") == "blas":
                lines.append(f"BLAS: {info.get('internal_api')} {info.get('version')} {info.get('architecture')} "
                             f"threads={info.get('num_threads')}")
    except ImportError:
        lines.append("BLAS: threadpoolctl not installed")
    for var in ("OPENBLAS_CORETYPE", "OPENBLAS_L2_SIZE", "POCL_MAX_PTHREAD_COUNT", "PYOPENCL_CTX"):
        if os.environ.get(var):
            lines.append(f"note: {var}={os.environ[var]} is set"
                         + (" (slows numpy: run under `env -u OPENBLAS_CORETYPE -u OPENBLAS_L2_SIZE`)"
                            if var.startswith("OPENBLAS") else ""))
    return "\n".join(lines)
