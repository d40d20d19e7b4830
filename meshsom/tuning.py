"""Per-device tuning of the GPU layout (``gpu``: the "gemm" kernel, kernels/bmu_gpu.cl).

The default tiling was chosen on an NVIDIA H200; the GPU a user rents (an A100, an L4, an AMD or
Intel card) has other registers, local memory and schedulers, and the fastest tiling there is
found by timing, not by reasoning (CLBlast tunes the same way). :func:`tune` times the
:data:`CANDIDATES` (fields of :class:`meshsom.bmu_opencl.KernelParams` over the layout's default)
on the device itself, one BMUofN pass each over :data:`WORKLOADS` (seeded random rows against
the paper's 120 x 150 map, random variations), after a warm-up, best of ``repeat``; the candidate
of least geometric-mean time relative to the default wins when it saves at least
``1 - MIN_RATIO`` of it. :func:`save` keeps the winner's fields in a JSON file per device
(platform, device, driver) and kernel source, beside the probe's verdicts
(``$MESHSOM_CACHE_DIR``, else ``~/.cache/meshsom``; sub-folder ``tuned``), and
:func:`meshsom.bmu_opencl.layout_params` uses them on that device from then on: every search of
every process and Dask worker there. A new driver or kernel source (another meshsom version)
does not find the file: tune again. The tuned layout still passes its probe before it is used.

Run it with ``meshsom tune`` (``--quick`` for small workloads); ``bench/gpu.py --autotune``
prints the same candidates' times with the compilers' register reports.
"""

from __future__ import annotations

import functools
import hashlib
import json
import logging
import time
from dataclasses import dataclass, fields, replace
from pathlib import Path
from typing import Callable

import numpy as np

log = logging.getLogger(__name__)

#: Bumped when what a tuning means changes, so older files are not used.
TUNING_VERSION = 1
#: The layout tuned.
LAYOUT = "gpu"
#: Candidates: "gemm" KernelParams fields over the layout's default (64 x 128 tiles, the whole row
#: tile where it fits, 8-dimension chunks beyond). Tilings (4 x 8, 8 x 8, 4 x 4 or 2 x 8
#: accumulators per work-item, 128 or 256 work-items), chunks along D, one local buffer or two
#: (prefetch), NVIDIA's register cap (128 keeps two groups of 256 on a compute unit, 80 with one
#: buffer three; bench/gpu_sass.py: no spills in the chunk loop), the row tile staged per chunk
#: where it fits whole, more unit splits for small N; the earlier default (128 x 128, X staged 16
#: dimensions at a time) among them. The first is the default. On an H200 (2026-11-30) the default
#: won against the earlier one by 0.91x, and 8-dimension chunks beat 16 at D = 144 by 0.73x.
CANDIDATES: list[dict] = [
    {},
    {"prefetch": False},
    {"tile_rows": 128, "whole_row_tile": False, "staged_kt": 0},
    {"tile_rows": 128},
    {"prefetch": False, "max_registers": 80},
    {"staged_kt": 0},
    {"max_registers": 128},
    {"tile_units": 64},
    {"tile_rows": 32, "group_rows": 8},
    {"whole_row_tile": False},
    {"groups_per_cu": 8},
    {"max_kt": 8},
]
#: Passes timed, (N, n, D): a million virtual rows at the paper's levels 2 and 3, and the paper's
#: corpus size at level 3; ``quick`` divides N by :data:`QUICK_DIVISOR`.
WORKLOADS = [(1_000_000, 3, 36), (1_000_000, 3, 144), (3064, 3, 144)]
QUICK_DIVISOR = 50
#: Units of the map the passes search (the paper's 120 x 150).
UNITS = 18_000
#: A candidate replaces the default when its geometric-mean time is at most this share of the default's.
MIN_RATIO = 0.97
#: Seed of the random rows, codebook and variation tables.
SEED = 2026


def candidate_name(fields_: dict) -> str:
    """A candidate's fields as one short text (``default`` for none)."""
    return ", ".join(f"{k}={v}" for k, v in fields_.items()) or "default"


def tuning_dir() -> Path:
    """Folder of the tuning files (beside :func:`meshsom.probe.cache_dir`)."""
    from meshsom.probe import cache_dir

    return cache_dir().parent / "tuned"


@functools.lru_cache(maxsize=1)
def _source_hash() -> str:
    from meshsom.bmu_opencl import kernel_source

    return hashlib.sha256(kernel_source("gemm").encode()).hexdigest()


def tuning_key(device) -> str:
    """What a tuning holds for: the device (platform, device, driver) and the gemm kernel's source (sha256 hex)."""
    from meshsom.probe import device_identity

    blob = json.dumps({"version": TUNING_VERSION, "device": device_identity(device), "source": _source_hash()},
                      sort_keys=True)
    return hashlib.sha256(blob.encode()).hexdigest()


def _path(device) -> Path:
    return tuning_dir() / f"{tuning_key(device)}.json"


def _valid(found: dict) -> dict:
    """The fields of a tuning that make a valid KernelParams over the layout's default (ValueError otherwise)."""
    from meshsom.bmu_opencl import DEFAULT_PARAMS, KernelParams

    known = {f.name for f in fields(KernelParams)} - {"kernel", "name"}
    if not isinstance(found, dict) or set(found) - known:
        raise ValueError(f"fields {sorted(set(found) - known) if isinstance(found, dict) else found!r} are not tiling fields")
    replace(DEFAULT_PARAMS[LAYOUT], **found)  # validates
    return dict(found)


_READ: dict[Path, tuple[int, dict]] = {}  # path -> (modification time, fields): a file read once per change


def tuned_fields(device) -> dict:
    """The tuned fields of a device's ``gpu`` layout ({} where it was not tuned, or its file is unusable)."""
    path = _path(device)
    try:
        stamp = path.stat().st_mtime_ns
    except OSError:
        return {}
    if path in _READ and _READ[path][0] == stamp:
        return dict(_READ[path][1])
    try:
        found = _valid(json.loads(path.read_text())["fields"])
    except (OSError, ValueError, KeyError, TypeError) as err:
        log.warning("ignoring the tuning %s: %s", path, err)
        found = {}
    _READ[path] = (stamp, found)
    return dict(found)


@dataclass(frozen=True)
class Timing:
    """One candidate on one workload: seconds per pass (None: skipped or failed, with why)."""

    workload: tuple[int, int, int]
    candidate: int
    seconds: float | None
    why: str = ""  # "skipped: ..." or "failed: ..." where seconds is None


@dataclass(frozen=True)
class TuningResult:
    """What :func:`tune` measured and chose."""

    device: str
    candidates: list[dict]
    timings: list[Timing]
    ratios: dict[int, float]  # candidate -> geometric mean of its time over the default's (complete ones)
    best: int  # index into candidates; 0: the default stays

    @property
    def fields(self) -> dict:
        return dict(self.candidates[self.best])


def _data(N: int, n: int, D: int, units: int, rng) -> tuple:
    X = rng.normal(size=(N, D)).astype(np.float32)
    W = rng.normal(size=(units, D)).astype(np.float32)
    index = np.array([rng.permutation(D) for _ in range(n)], np.int64)
    sign = rng.choice(np.array([-1.0, 1.0], np.float32), size=(n, D))
    index[0], sign[0] = np.arange(D), 1.0  # the identity first, as every variation table has it
    return X, W, index, sign


def tune(context, workloads=None, candidates=None, repeat: int = 2, quick: bool = False, units: int = UNITS,
         report: Callable[[Timing], None] | None = None) -> TuningResult:
    """Time the candidates on a context's device (as the module says).

    Parameters
    ----------
    context : pyopencl.Context
    workloads : list of (N, n, D), optional
        Default :data:`WORKLOADS`.
    candidates : list of dict, optional
        Default :data:`CANDIDATES`; the first is the baseline the others are compared with.
    repeat : int
        Timed passes after the warm-up; the best counts.
    quick : bool
        N divided by :data:`QUICK_DIVISOR` (at least 64).
    units : int
        Units of the map searched (default the paper's).
    report : callable, optional
        Receives each :class:`Timing` as it is measured (``meshsom tune`` and ``bench/gpu.py
        --autotune`` print them their way).
    """
    from meshsom.bmu_opencl import bmu_opencl, device_name, gemm_local_bytes, layout_params

    say = report or (lambda timing: None)
    candidates = CANDIDATES if candidates is None else candidates
    device = context.devices[0]
    base = replace(layout_params(device, LAYOUT, tuned=False), name=LAYOUT)
    rng = np.random.default_rng(SEED)
    timings: list[Timing] = []
    for N, n, D in workloads or WORKLOADS:
        if quick:
            N = max(64, N // QUICK_DIVISOR)
        X, W, index, sign = _data(N, n, D, units, rng)
        for c, extra in enumerate(candidates):
            p = replace(base, **extra)
            local = gemm_local_bytes(p, np.float32, D)
            if local > device.local_mem_size:
                timing = Timing((N, n, D), c, None,
                                f"skipped: {local} bytes of local memory, the device has {device.local_mem_size}")
            else:
                try:
                    bmu_opencl(X, W, index, sign, context=context, params=p)  # warm-up: build, probe, copies
                    best = np.inf
                    for _ in range(repeat):
                        t0 = time.perf_counter()
                        bmu_opencl(X, W, index, sign, context=context, params=p)
                        best = min(best, time.perf_counter() - t0)
                    timing = Timing((N, n, D), c, best)
                except Exception as err:  # noqa: BLE001 - a candidate the device cannot run is reported, not fatal
                    timing = Timing((N, n, D), c, None, f"failed: {str(err).splitlines()[0][:160]}")
            timings.append(timing)
            say(timing)
    ratios = _ratios(timings, len(candidates))
    best = min(ratios, key=lambda c: (ratios[c], c)) if ratios else 0
    if best != 0 and ratios[best] > MIN_RATIO:
        best = 0
    return TuningResult(device_name(context), list(candidates), timings, ratios, best)


def _ratios(timings: list[Timing], count: int) -> dict[int, float]:
    """Geometric mean of each candidate's time over the baseline's, for the candidates that ran every
    workload the baseline ran."""
    by_workload: dict[tuple, dict[int, float]] = {}
    for t in timings:
        if t.seconds is not None:
            by_workload.setdefault(t.workload, {})[t.candidate] = t.seconds
    complete = [times for times in by_workload.values() if 0 in times]
    if not complete:
        return {}
    out = {}
    for c in range(count):
        if all(c in times for times in complete):
            out[c] = float(np.exp(np.mean([np.log(times[c] / times[0]) for times in complete])))
    return out


def save(context, result: TuningResult) -> Path:
    """Keep a tuning's winner for the context's device (the file :func:`tuned_fields` reads)."""
    device = context.devices[0]
    path = _path(device)
    path.parent.mkdir(parents=True, exist_ok=True)
    doc = {"version": TUNING_VERSION, "device": result.device, "fields": _valid(result.fields),
           "ratio": result.ratios.get(result.best, 1.0), "tuned": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
           "timings": [{"workload": list(t.workload), "candidate": candidate_name(result.candidates[t.candidate]),
                        "seconds": t.seconds, "why": t.why} for t in result.timings]}
    tmp = path.with_suffix(".tmp")
    tmp.write_text(json.dumps(doc, indent=1))
    tmp.replace(path)  # atomic: a worker never reads half a file
    return path


def forget(context) -> bool:
    """Delete the context's device tuning (the default tiling again); whether there was one."""
    path = _path(context.devices[0])
    if path.is_file():
        path.unlink()
        return True
    return False
