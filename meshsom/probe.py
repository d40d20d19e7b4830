"""Kernel verdicts: does a BMUofN kernel layout build and give right answers on a device?

OpenCL compilers can take the whole process down: PoCL 3.0 with LLVM 14 aborts (``LLVM ERROR``,
SIGABRT) on some kernels for CPUs LLVM does not know, and no Python ``try`` catches that. So
before a kernel is built in the user's process for the first time, :func:`check` builds it in a
*child* process, runs it on a small known answer (random rows against a small codebook, with
random variations, compared with a float64 NumPy search; where the device has float64, the
program's per-unit sums kernel too, compared bit for bit with :func:`meshsom.bmu_numpy.unit_sums`,
its per-row errors, topographic errors and update kernels, compared with the host's)
and reports a :class:`Verdict`; a compiler abort or a hang then kills only the child.

Verdicts are cached on disk, one JSON file per key, so the probe costs once per machine and
Dask workers on it share the answer. The key covers everything the build depends on: the
platform and its version, the device, its driver version, the kernel source text and the
compile defines (sizes, widths, data type). The cache folder is ``$MESHSOM_CACHE_DIR`` (else
``$XDG_CACHE_HOME/meshsom``, else ``~/.cache/meshsom``), sub-folder ``kernel-verdicts``;
deleting it forces new probes. A probe that failed for want of memory (another process holds
the GPU: :data:`SHORTAGE_MARKERS`) is no verdict: it is tried again, and never cached.

Test hook (never set it otherwise): ``MESHSOM_KERNEL_INJECT="cpu=error,cpu-narrow=trap"`` makes
the named layouts fail to build (``error``: a ``#error`` directive) or kill their process on
first launch (``trap``: ``__builtin_trap()``); ``epoch-error`` fails only the build of the epoch's
kernels (``kernels/epoch_sums.cl``), see :func:`injected_defines`.

The child is this module run as a script: ``python -m meshsom.probe SPEC_JSON``.
"""

from __future__ import annotations

import fcntl
import functools
import hashlib
import json
import logging
import os
import re
import signal
import subprocess
import sys
import time
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np

log = logging.getLogger(__name__)

#: Bumped when the probe's check changes, so old verdicts are not reused.
PROBE_VERSION = 3
#: Seconds a probe child may take (build + check) before it is killed and the layout rejected.
PROBE_TIMEOUT_S = 300.0
#: How the reason of a probe that hung begins.
HANG_REASON = "no answer within"
#: Rows and extra units of the known-answer check (units: two whole tiles plus this, so the
#: padding path runs), and the seed of its random data.
PROBE_ROWS = 67
PROBE_EXTRA_UNITS = 5
PROBE_SEED = 12345
#: Relative tolerance between the kernel's winning distance and the float64 minimum.
PROBE_RTOL = 1e-4
#: Relative tolerance between the per-row Q / QC distances of the device and of the host (the
#: same order of operations; a device may fuse a square and its add).
PROBE_ERRORS_RTOL = 1e-12
#: Relative tolerance between the codebook an update on the device makes and the host's
#: :func:`meshsom.som.batch_update` (smoothing sums added in another order), per data type; of
#: each value and of the codebook's largest.
PROBE_UPDATE_RTOL = {"float": 1e-6, "double": 1e-12}
#: Rows of the grid the update check smooths on (its columns: as many as the probe's units allow).
PROBE_UPDATE_ROWS = 4
#: Radius of that smoothing, in cells.
PROBE_UPDATE_SIGMA = 1.5
#: Workload of the optional throughput figure (``meshsom doctor``): rows, units, variations, D.
TIMING_WORKLOAD = (4096, 2048, 3, 36)
#: Timed runs of that workload after a warm-up (the best counts).
TIMING_REPEAT = 3

#: What a probe's failure says when the device or the host ran short of memory at that moment
#: (other processes hold the device: a GPU shared by Dask workers or test workers), which is no
#: verdict on the layout: such a probe is tried again, and its failure is neither cached on disk
#: nor kept in memory. (OUT_OF_RESOURCES is not among them: NVIDIA's driver says so for a kernel
#: that faults or asks more than a compute unit has, which are verdicts.)
SHORTAGE_MARKERS = ("OUT_OF_HOST_MEMORY", "MEM_OBJECT_ALLOCATION_FAILURE")
#: Tries of a probe that ran short, and the wait before the first retry (doubled after each).
SHORTAGE_TRIES = 3
SHORTAGE_WAIT_S = 2.0
#: What the reason of a probe that ran short on every try ends with.
SHORTAGE_NOTE = "(the device or host ran short of memory: no verdict on the layout, not cached)"

#: Signals a probe child dies of when something outside stopped it (a user's Ctrl-C, a job
#: scheduler, a cluster shutting down, a ``kill``): no verdict on the layout, so tried again like a
#: shortage and never cached (a device's own crash is SIGSEGV, SIGABRT, SIGILL, SIGBUS or SIGFPE).
OUTSIDE_SIGNALS = ("SIGTERM", "SIGINT", "SIGHUP")
#: What the reason of a probe stopped from outside on every try starts and ends with.
OUTSIDE_REASON = "the probe's process was stopped from outside"
OUTSIDE_NOTE = "(no verdict on the layout, not cached)"

ENV_INJECT = "MESHSOM_KERNEL_INJECT"
ENV_TIMEOUT = "MESHSOM_PROBE_TIMEOUT"
#: Injected failures (test hook): name -> define added to the layout's build.
INJECTIONS = {"error": "MESHSOM_INJECT_BUILD_ERROR", "trap": "MESHSOM_INJECT_TRAP",
              "epoch-error": "MESHSOM_INJECT_EPOCH_ERROR", "sigterm": "MESHSOM_INJECT_SIGTERM"}


@dataclass(frozen=True)
class Verdict:
    """The outcome of one probe.

    Attributes
    ----------
    ok : bool
        The layout built and gave the known answer.
    layout : str
        Layout name (a key of :data:`meshsom.bmu_opencl.DEFAULT_PARAMS`, or "custom").
    device : str
        "platform / device".
    reason : str
        Empty when ok; else one line: what failed and the compiler's first error line.
    seconds : float
        Wall time of the probe (child start, build, check).
    key : str
        Cache key (hex).
    gflops : float or None
        Throughput of a short timed run (only when asked for, as ``meshsom doctor`` does).
    cached : bool
        Read from the disk cache (or this process's memory) rather than probed now.
    """

    ok: bool
    layout: str
    device: str
    reason: str
    seconds: float
    key: str
    gflops: float | None = None
    cached: bool = False


_MEMO: dict[str, Verdict] = {}


def cache_dir() -> Path:
    """Folder of the verdict files (in :func:`meshsom.caches.meshsom_cache_root`: a private
    temporary folder where the user's cannot be written)."""
    from meshsom.caches import meshsom_cache_root

    return meshsom_cache_root() / "kernel-verdicts"


def injected_defines(layout: str) -> dict[str, int]:
    """Defines the test hook ``$MESHSOM_KERNEL_INJECT`` adds to a layout's build (usually none).

    Raises
    ------
    ValueError
        A malformed value (the message shows the expected form).
    """
    text = os.environ.get(ENV_INJECT, "").strip()
    if not text:
        return {}
    out = {}
    for item in text.split(","):
        name, _, what = item.strip().partition("=")
        if what not in INJECTIONS:
            raise ValueError(f"{ENV_INJECT} must look like 'cpu=error,cpu-narrow=trap' (failures: "
                             f"{', '.join(INJECTIONS)}), received {text!r}")
        if name == layout:
            out[INJECTIONS[what]] = 1
    return out


def device_identity(device) -> dict[str, str]:
    """What a verdict depends on besides the kernel: platform, device, driver and the kernel target
    CPU (:func:`meshsom.pocl_target.kernel_target`, which a process may have set)."""
    from meshsom.pocl_target import kernel_target

    platform = device.platform
    return {
        "kernel_target": str(kernel_target(device)),
        "platform": platform.name.strip(), "platform_version": platform.version.strip(),
        "device": device.name.strip(), "vendor": device.vendor.strip(),
        "driver": device.driver_version.strip(), "device_version": device.version.strip(),
    }


@functools.lru_cache(maxsize=None)
def _host_code() -> str:
    """Hash of the Python that builds, launches and checks kernels (a new meshsom version probes again)."""
    here = Path(__file__).resolve().parent
    text = b"".join((here / name).read_bytes() for name in ("probe.py", "bmu_opencl.py", "bmu_numpy.py"))
    return hashlib.sha256(text).hexdigest()


def verdict_key(device, defines: dict, source: str, options: list[str]) -> str:
    """Cache key: device identity, kernel source, defines, build options and the host code (sha256 hex)."""
    blob = json.dumps({
        "probe": PROBE_VERSION, "host": _host_code(), "device": device_identity(device), "source": hashlib.sha256(source.encode()).hexdigest(),
        "defines": {k: str(v) for k, v in sorted(defines.items())}, "options": list(options),
    }, sort_keys=True)
    return hashlib.sha256(blob.encode()).hexdigest()


def _timeout() -> float:
    text = os.environ.get(ENV_TIMEOUT)
    if not text:
        return PROBE_TIMEOUT_S
    try:
        return float(text)
    except ValueError:
        raise ValueError(f"{ENV_TIMEOUT} must be a number of seconds, received {text!r}") from None


def _read(path: Path) -> Verdict | None:
    try:
        data = json.loads(path.read_text())
        return Verdict(**{**data, "cached": True})
    except (OSError, ValueError, TypeError):
        return None


def _write(path: Path, verdict: Verdict) -> None:
    tmp = path.with_suffix(f".{os.getpid()}.tmp")
    tmp.write_text(json.dumps({**asdict(verdict), "cached": False}, indent=1))
    os.replace(tmp, path)


def check(device, selector: str, defines: dict, source: str, options: list[str], layout: str = "custom",
          timing: bool = False) -> Verdict:
    """The verdict of one kernel build on one device: from memory, the disk cache, or a child probe.

    Parameters
    ----------
    device : pyopencl.Device
    selector : str
        ``"P:D"`` of the device (the child opens the same one).
    defines : dict
        Compile defines (as :func:`meshsom.bmu_opencl.get_kernel` takes them; ``KERNEL`` names the variant).
    source : str
        Kernel source text (part of the key).
    options : list of str
        Build options (part of the key).
    layout : str
        Layout name for messages.
    timing : bool
        Also time a short run (GFLOP/s); always probes anew.

    Returns
    -------
    Verdict
    """
    key = verdict_key(device, defines, source, options)
    if not timing and key in _MEMO:
        return _MEMO[key]
    folder = cache_dir()
    path = folder / f"{key}.json"
    if not timing:
        cached = _read(path)
        if cached is not None:
            _MEMO[key] = cached
            return cached
    folder.mkdir(parents=True, exist_ok=True)
    with open(folder / f"{key}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # another process probing the same key: wait for its verdict
        cached = None if timing else _read(path)
        if cached is None:
            name = f"{device.platform.name.strip()} / {device.name.strip()}"
            sizes = ", ".join(f"{k}={defines[k]}" for k in ("D", "NV", "REAL") if k in defines)
            log.info("checking BMUofN kernel layout %r on %s (%s) in a child process", layout, name, sizes)
            wait = SHORTAGE_WAIT_S
            for attempt in range(SHORTAGE_TRIES):
                verdict, keep = _probe_child(selector, defines, layout, name, key, timing)
                if not short_of_memory(verdict) and not stopped_from_outside(verdict):
                    break
                log.warning("probe of layout %r on %s %s (try %d of %d): %s", layout, name,
                            "ran short of memory" if short_of_memory(verdict) else "was stopped from outside",
                            attempt + 1, SHORTAGE_TRIES, verdict.reason)
                if attempt + 1 < SHORTAGE_TRIES:
                    time.sleep(wait)
                    wait *= 2
            log.info("layout %r on %s: %s in %.1f s", layout, name, "ok" if verdict.ok else "FAILED", verdict.seconds)
            if short_of_memory(verdict):
                return replace(verdict, reason=f"{verdict.reason} {SHORTAGE_NOTE}")
            if stopped_from_outside(verdict):
                return replace(verdict, reason=f"{verdict.reason} {OUTSIDE_NOTE}")
            if keep:
                _write(path, verdict)
        else:
            verdict = cached
    _MEMO[key] = verdict
    return verdict


def short_of_memory(verdict: Verdict) -> bool:
    """The probe failed for want of memory at that moment (:data:`SHORTAGE_MARKERS`), not for the layout."""
    return not verdict.ok and any(marker in verdict.reason for marker in SHORTAGE_MARKERS)


def stopped_from_outside(verdict: Verdict) -> bool:
    """The probe's child was stopped by one of :data:`OUTSIDE_SIGNALS`, not by the layout."""
    return not verdict.ok and verdict.reason.startswith(OUTSIDE_REASON)


#: What a compiler's or driver's message line starts with or holds, most telling first.
ERROR_MARKERS = ("llvm error", "error:", "fatal", "error", "warning:")


def first_error_line(text: str) -> str:
    """The most telling line of a build's or child's output, without temporary file paths.

    In order: an ``LLVM ERROR`` line, a compiler ``error:``, a fatal error, any error, a
    compiler warning; never a line of a Python traceback (pyopencl repeats source lines there).
    """
    lines = [re.sub(r"\S+\.cl:\d+:\d+: ", "", ln.strip()) for ln in text.splitlines() if ln.strip()]
    lines = [ln for ln in lines if not ln.startswith(("File \"", "Traceback", "lambda", "^", "~"))]
    for marker in ERROR_MARKERS:
        for ln in lines:
            if marker in ln.lower():
                return ln[:300]
    return lines[-1][:300] if lines else "no message"


def _probe_child(selector: str, defines: dict, layout: str, name: str, key: str, timing: bool) -> tuple[Verdict, bool]:
    """Run the probe child; the verdict, and whether to keep it on disk.

    Verdicts about the device (it built and answered, failed to build, answered wrongly, died or
    hung) are kept; a child that failed in Python before it could judge (an import error, say)
    gives a failed verdict for this process only.
    """
    spec = json.dumps({"selector": selector, "defines": defines, "timing": timing})
    t0 = time.perf_counter()
    try:
        proc = subprocess.run([sys.executable, "-m", "meshsom.probe", spec], capture_output=True, text=True,
                              timeout=_timeout())
    except subprocess.TimeoutExpired:
        return Verdict(False, layout, name, f"{HANG_REASON} {_timeout():g} s (build or first run hung)",
                       time.perf_counter() - t0, key), True
    seconds = time.perf_counter() - t0
    if proc.returncode == 0:
        try:
            out = json.loads(proc.stdout.strip().splitlines()[-1])
        except (ValueError, IndexError):
            return Verdict(False, layout, name, f"probe printed no verdict: {first_error_line(proc.stderr)}",
                           seconds, key), False
        return Verdict(bool(out["ok"]), layout, name, out.get("reason", ""), seconds, key, out.get("gflops")), True
    if proc.returncode < 0:
        try:
            sig = signal.Signals(-proc.returncode).name
        except ValueError:
            sig = f"signal {-proc.returncode}"
        if sig in OUTSIDE_SIGNALS:
            return Verdict(False, layout, name, f"{OUTSIDE_REASON} ({sig})", seconds, key), False
        reason = f"the build or first run killed its process ({sig}): {first_error_line(proc.stderr + proc.stdout)}"
        return Verdict(False, layout, name, reason, seconds, key), True
    reason = f"the probe exited with status {proc.returncode}: {first_error_line(proc.stderr + proc.stdout)}"
    return Verdict(False, layout, name, reason, seconds, key), "Traceback" not in proc.stderr


# ----------------------------------------------------------------------------- the child


def known_answer(defines: dict) -> tuple[np.ndarray, ...]:
    """The probe's data for a build: rows, codebook and a random variation table.

    Returns
    -------
    X : (PROBE_ROWS, D) float32 or float64
    W : (M, D), M two tiles plus :data:`PROBE_EXTRA_UNITS`
    index : (n, D) int64, row 0 the identity
    sign : (n, D) of ±1
    """
    D, n = int(defines["D"]), int(defines["NV"])
    dtype = np.float64 if defines["REAL"] == "double" else np.float32
    rng = np.random.default_rng(PROBE_SEED)
    tile = int(defines.get("TN", int(defines.get("VW", 4)) * int(defines.get("UB", 1))))
    M = 2 * tile + PROBE_EXTRA_UNITS
    W = rng.normal(size=(M, D)).astype(dtype)
    X = rng.normal(size=(PROBE_ROWS, D)).astype(dtype)
    index = np.stack([np.arange(D)] + [rng.permutation(D) for _ in range(n - 1)]).astype(np.int64)
    sign = np.where(rng.random((n, D)) < 0.5, -1.0, 1.0).astype(dtype)
    sign[0] = 1
    return X, W, index, sign


def compare(X, W, index, sign, unit, variation) -> str:
    """Empty when every row's (unit, variation) is a nearest one within :data:`PROBE_RTOL`; else why not."""
    M, n = len(W), len(index)
    if unit.min() < 0 or unit.max() >= M or variation.min() < 0 or variation.max() >= n:
        return f"wrong answer: unit or variation out of range (units {unit.min()}..{unit.max()} of {M})"
    Xd, Wd = X.astype(np.float64), W.astype(np.float64)
    xv = sign[:, None, :].astype(np.float64) * Xd[:, index].transpose(1, 0, 2)  # (n, N, D)
    d = ((xv[:, :, None, :] - Wd[None, None]) ** 2).sum(-1)  # (n, N, M)
    best = d.min(axis=(0, 2))
    got = d[variation, np.arange(len(X)), unit]
    bad = np.flatnonzero(got > best + PROBE_RTOL * (1 + best))
    if len(bad):
        r = int(bad[0])
        return (f"wrong answer on {len(bad)} of {len(X)} rows (row {r}: distance {got[r]:.6g}, "
                f"the nearest is {best[r]:.6g})")
    return ""


def compare_sums(context, queue, defines, X, index, sign, unit, variation, M: int) -> str:
    """Empty when the program's per-unit sums kernel gives the host's sums bit for bit, its per-row
    errors kernel the host's distances to :data:`PROBE_ERRORS_RTOL` and its update kernels the
    host's codebook (:func:`compare_update`); else why not."""
    from meshsom import bmu_opencl
    from meshsom.bmu_numpy import BMUResult, unit_sums
    from meshsom.metrics import row_errors

    # the program is built (the search's, unguarded, in this child): its other kernels come from it
    half = -(-len(X) // 2)
    blocks = [(0, half), (half, len(X))]  # two row blocks (the device's order), added in order
    sums, counts = bmu_opencl.launch_unit_sums(context, queue, defines, X, index, sign, unit, variation, M, blocks,
                                               order_on_device=True)
    want, want_counts = unit_sums(X, unit, variation, index, sign, M, blocks)
    if not np.array_equal(counts, want_counts):
        return "wrong per-unit counts"
    bad = np.flatnonzero((sums != want).any(axis=1))
    if len(bad):
        u = int(bad[0])
        return f"wrong per-unit sums on {len(bad)} of {M} units (unit {u}: {sums[u][:3]} ..., host {want[u][:3]} ...)"
    W = known_answer(defines)[1]
    kernel = bmu_opencl.get_kernel(context, defines, bmu_opencl.ROW_ERRORS, guard=False)
    found = bmu_opencl.launch_row_errors(context, queue, kernel, X, W, index, sign, unit, variation)
    bmu = BMUResult(unit, variation, np.zeros(len(X)), unit)
    for name, got, ref in zip(("Q", "QC"), found, row_errors(X, W, bmu, index, sign)):
        if not np.allclose(got, ref, rtol=PROBE_ERRORS_RTOL, atol=0, equal_nan=True):
            r = int(np.flatnonzero(~np.isclose(got, ref, rtol=PROBE_ERRORS_RTOL, atol=0, equal_nan=True))[0])
            return f"wrong per-row {name} distances (row {r}: {got[r]:.17g}, host {ref[r]:.17g})"
    return (compare_topographic(context, queue, defines, X, index, sign, unit, variation, W)
            or compare_update(context, queue, defines, X, index, sign, unit, variation, W))


def compare_topographic(context, queue, defines, X, index, sign, unit, variation, W) -> str:
    """Empty when the program's topographic errors kernel flags the rows the host flags
    (:func:`meshsom.metrics.topographic_errors` with the tie rule); else why not.

    The units are folded onto a :data:`PROBE_UPDATE_ROWS`-row toroidal grid, each row's second-best
    unit is the nearest other unit (float64), and one row's best unit gets a neighbour tied with its
    second, so that both a tie and a near miss are decided."""
    from meshsom import bmu_opencl
    from meshsom.bmu_numpy import BMUResult
    from meshsom.metrics import (TIE_RTOL, are_neighbours, neighbour_units, tied_with_neighbour, topographic_errors,
                                 winning_vectors)

    rows = PROBE_UPDATE_ROWS
    cols = len(W) // rows
    M = rows * cols
    best = unit % M
    W = np.array(W[:M])
    xv = winning_vectors(X, variation, index, sign)
    d = ((xv[:, None, :] - W[None].astype(np.float64)) ** 2).sum(-1)
    d[np.arange(len(best)), best] = np.inf
    second = d.argmin(axis=1)
    far = np.flatnonzero(~are_neighbours(best, second, rows, cols))
    if len(far):
        W[neighbour_units(best[far[:1]], rows, cols)[0, 0]] = W[second[far[0]]]  # a tie
    bmu = BMUResult(best, variation, np.zeros(len(best)), second)
    kernel = bmu_opencl.get_kernel(context, defines, bmu_opencl.TOPOGRAPHIC_ERRORS, guard=False)
    got = bmu_opencl.launch_topographic_errors(context, queue, kernel, X, W, index, sign, best, variation, second,
                                               rows, cols, "toroidal", 8, TIE_RTOL)
    want = topographic_errors(best, second, rows, cols, "toroidal", 8,
                              tied_with_neighbour(X, W, bmu, rows, cols, "toroidal", index, sign))
    if not np.array_equal(got, want):
        r = int(np.flatnonzero(got != want)[0])
        return f"wrong topographic errors on {int((got != want).sum())} of {len(X)} rows (row {r}: {got[r]}, host {want[r]})"
    return ""


def compare_update(context, queue, defines, X, index, sign, unit, variation, W) -> str:
    """Empty when the program's update kernels (sums kept on the device, smoothed and divided there)
    give the host's :func:`meshsom.som.batch_update` to :data:`PROBE_UPDATE_RTOL`; else why not.

    The units are folded onto a :data:`PROBE_UPDATE_ROWS`-row toroidal grid of the first units,
    so that some units win nothing and others several rows."""
    from meshsom import bmu_opencl
    from meshsom.bmu_numpy import unit_sums
    from meshsom.som import MIN_WEIGHT, batch_update, gaussian_kernel_1d

    rows = PROBE_UPDATE_ROWS
    cols = len(W) // rows
    M = rows * cols
    folded = unit % M
    sums, counts = bmu_opencl.launch_unit_sums(context, queue, defines, X, index, sign, folded, variation, M,
                                               keep=True, layout="probe")
    W = np.ascontiguousarray(W[:M])
    got = bmu_opencl.batch_update_opencl(W, sums, counts, gaussian_kernel_1d(rows, PROBE_UPDATE_SIGMA),
                                         gaussian_kernel_1d(cols, PROBE_UPDATE_SIGMA), MIN_WEIGHT, queue)
    want = batch_update(W, *unit_sums(X, folded, variation, index, sign, M), PROBE_UPDATE_SIGMA, rows, cols)
    rtol = PROBE_UPDATE_RTOL[defines["REAL"]]
    # relative to the codebook's scale too: a smoothed sum of terms of both signs can cancel
    close = np.isclose(got, want, rtol=rtol, atol=rtol * float(np.abs(want).max()))
    if not close.all():
        u, k = np.argwhere(~close)[0]
        return f"wrong codebook from the update on the device (unit {u}, dimension {k}: {got[u, k]!r}, host {want[u, k]!r})"
    return ""


def _child(spec: dict) -> dict:
    from meshsom import bmu_opencl

    cl = bmu_opencl._cl()
    defines = spec["defines"]
    if int(defines.get(INJECTIONS["sigterm"], 0)):  # test hook: as if a user or scheduler stopped it
        os.kill(os.getpid(), signal.SIGTERM)
    context = cl.Context([bmu_opencl.select_device(spec["selector"])])
    queue = cl.CommandQueue(context)
    X, W, index, sign = known_answer(defines)
    try:
        kernel = bmu_opencl.get_kernel(context, defines, guard=False)
        unit, variation = bmu_opencl.launch(context, queue, kernel, X, W, index, sign, defines)[:2]
    except bmu_opencl.KernelLayoutError as err:
        return {"ok": False, "reason": first_error_line(err.reason)}
    except bmu_opencl.DeviceError as err:
        return {"ok": False, "reason": first_error_line(str(err))}
    reason = compare(X, W, index, sign, unit, variation)
    if not reason and bmu_opencl.has_fp64(context) and int(defines.get("EPOCH", 1)):
        reason = compare_sums(context, queue, defines, X, index, sign, unit, variation, len(W))
    out = {"ok": not reason, "reason": reason}
    if spec.get("timing") and not reason:
        N, M, n, D = TIMING_WORKLOAD
        if (int(defines["D"]), int(defines["NV"])) == (D, n):
            rng = np.random.default_rng(PROBE_SEED)
            Xt = rng.normal(size=(N, D)).astype(X.dtype)
            Wt = rng.normal(size=(M, D)).astype(X.dtype)
            bmu_opencl.launch(context, queue, kernel, Xt, Wt, index, sign, defines)  # warm-up
            times = []
            for _ in range(TIMING_REPEAT):
                t0 = time.perf_counter()
                bmu_opencl.launch(context, queue, kernel, Xt, Wt, index, sign, defines)
                times.append(time.perf_counter() - t0)
            out["gflops"] = 2.0 * N * n * M * D / min(times) / 1e9
    return out


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    print(json.dumps(_child(json.loads(argv[0]))), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
