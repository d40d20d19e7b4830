"""``meshsom doctor``: what meshsom will run with on this machine."""

from __future__ import annotations

import argparse
import importlib.metadata
import os
import platform
import sys
from dataclasses import replace

PACKAGES = (
    "meshsom", "numpy", "scipy", "trimesh", "shapely", "pyproj", "fiona", "pyarrow", "pymeshlab", "zarr", "dask",
    "distributed", "pyopencl", "pocl-binary-distribution", "mlflow", "matplotlib", "pyyaml", "tqdm", "plyfile",
    "pycollada", "ifcopenshell", "DracoPy", "rhino3dm", "ezdxf", "assimp-py", "osmium", "s3fs",
)
ENV_VARS = (
    "PYOPENCL_CTX", "MESHSOM_OPENCL_DEVICE", "POCL_MAX_PTHREAD_COUNT", "POCL_LLVM_CPU_NAME", "OCL_ICD_VENDORS",
    "DASK_SCHEDULER_ADDRESS", "MLFLOW_TRACKING_URI", "MLFLOW_EXPERIMENT_NAME",
    "OPENBLAS_CORETYPE", "OPENBLAS_L2_SIZE", "OMP_NUM_THREADS",
)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--json", action="store_true", help="print one JSON object instead of text")
    p.add_argument("--no-kernels", action="store_true",
                   help="skip building and timing the BMUofN kernel layouts (a few seconds per layout and device)")


#: How doctor names the BMUofN kernel layouts of meshsom.bmu_opencl.KERNELS.
KERNELS_DOC = {"cpu": "kernels/bmu_cpu.cl (CPU layout)", "gemm": "kernels/bmu_gpu.cl (GPU GEMM layout)",
               "tiled": "kernels/bmu.cl (earlier GPU layout)"}


def kernel_verdicts(device) -> list[dict]:
    """Build, check and time every BMUofN kernel layout on one device, each in a child process.

    Returns
    -------
    list of dict
        Per layout: ``layout``, ``ok``, ``reason``, ``gflops`` (a short run of the workload
        :data:`meshsom.probe.TIMING_WORKLOAD`), ``seconds`` (probe wall time), ``chain`` (the
        position in the device's fallback chain, None when not in it), ``search_only`` (the program
        failed with the epoch's kernels and passed without: ``reason`` says why).
    """
    import numpy as np

    from meshsom.bmu_opencl import (BUILD_OPTIONS, DEFAULT_PARAMS, _defines, device_selector, kernel_source,
                                    layout_chain, layout_params)
    from meshsom.probe import HANG_REASON, TIMING_WORKLOAD, check

    _, _, n, D = TIMING_WORKLOAD
    chain = layout_chain(device)
    out = []
    for name in DEFAULT_PARAMS:
        def probe(epoch_kernels: bool, name=name):
            defines = _defines(D, n, np.dtype(np.float32), replace(layout_params(device, name), epoch_kernels=epoch_kernels))
            return check(device, device_selector(device), defines, kernel_source(defines["KERNEL"]), BUILD_OPTIONS,
                         layout=name, timing=True)

        v = probe(True)
        entry = {"layout": name, "ok": v.ok, "reason": v.reason, "gflops": v.gflops, "seconds": round(v.seconds, 2),
                 "chain": chain.index(name) if name in chain else None, "search_only": False}
        if not v.ok and not v.reason.startswith(HANG_REASON):
            alone = probe(False)  # as meshsom.bmu.Engine does: the search without the epoch's kernels
            if alone.ok:
                entry.update(ok=True, gflops=alone.gflops, search_only=True,
                             seconds=round(v.seconds + alone.seconds, 2))
        out.append(entry)
    return out


def opencl_devices(kernels: bool = False) -> list[dict]:
    """Every OpenCL platform and device found (empty when there is none or no ICD loader).

    With ``kernels``, each device's entry also holds its layouts' verdicts (:func:`kernel_verdicts`).
    """
    try:
        import pyopencl as cl

        from meshsom.caches import ensure_user_cache

        ensure_user_cache()  # PoCL shows no device where its kernel cache cannot be written
        platforms = cl.get_platforms()
    except Exception as err:  # no ICD, no platform: doctor reports, never fails
        return [{"error": f"{type(err).__name__}: {err}"}]
    out = []
    for pi, plat in enumerate(platforms):
        try:
            devices = plat.get_devices()
        except Exception as err:
            out.append({"platform": plat.name, "error": str(err)})
            continue
        for di, dev in enumerate(devices):
            from meshsom.pocl_target import left_alone, retarget, retargeted

            retarget(dev)  # as meshsom.bmu_opencl.list_devices does, before anything is built
            try:
                from meshsom.bmu_opencl import device_params

                params = device_params(dev)
                if params.kernel == "gemm":
                    kernel = (f"{KERNELS_DOC[params.kernel]}, tile {params.tile_rows} varied vectors x "
                              f"{params.tile_units} units on {params.group_rows} x {params.group_units} work-items")
                else:
                    kernel = (f"{KERNELS_DOC[params.kernel]}, register block {params.max_rows} varied vectors x "
                              f"{params.unit_blocks} x {params.vector_width} units")
            except Exception as err:  # doctor reports, never fails
                kernel = f"unknown ({err})"
            out.append({
                "id": f"{pi}:{di}",
                "platform": plat.name,
                "platform_version": plat.version,
                "device": dev.name.strip(),
                "type": _device_type(dev.type),
                "compute_units": dev.max_compute_units,
                "global_mem_mb": dev.global_mem_size // 2**20,
                "local_mem_kb": dev.local_mem_size // 2**10,
                "max_work_group_size": dev.max_work_group_size,
                "bmu_kernel": kernel,
                "epoch_sums": ("device (float64)" if "cl_khr_fp64" in dev.extensions
                               else "host (the device has no float64)"),
                "epoch_update": ("host (no float64)" if "cl_khr_fp64" not in dev.extensions
                                 else "host (SOM update='auto' on a CPU device; 'device' runs it there)"
                                 if dev.type & cl.device_type.CPU else "device (SOM update='auto' on a GPU)"),
                "driver": dev.driver_version.strip(),
                "kernel_target": _kernel_target(dev),
                "kernel_target_note": (f"set by meshsom: PoCL's LLVM calls this CPU "
                                       f"{hstr_cpu(dev)!r}" if retargeted(dev) else left_alone(dev)),
                "gpu_tuning": _tuning(dev),
            })
            if kernels:
                try:
                    out[-1]["layouts"] = kernel_verdicts(dev)
                except Exception as err:  # doctor reports, never fails
                    out[-1]["layouts_error"] = f"{type(err).__name__}: {err}"
    return out


def _tuning(device) -> str:
    """What ``meshsom tune`` saved for the device's ``gpu`` layout, in words."""
    try:
        from meshsom.tuning import candidate_name, tuned_fields

        found = tuned_fields(device)
    except Exception as err:  # doctor reports, never fails
        return f"unknown ({err})"
    return f"tuned: {candidate_name(found)}" if found else "default tiling (not tuned: meshsom tune)"


def hstr_cpu(device) -> str | None:
    """The CPU name PoCL itself shows for a device (before meshsom set another)."""
    from meshsom.pocl_target import hstr_target

    found = hstr_target(device)
    return found[1] if found else None


def _kernel_target(device) -> str | None:
    """PoCL's LLVM CPU name for kernels (what the vector width is capped by), None elsewhere."""
    from meshsom.bmu_opencl import kernel_target_cpu

    return kernel_target_cpu(device)


def _device_type(t: int) -> str:
    import pyopencl as cl

    names = [n for n, v in (("CPU", cl.device_type.CPU), ("GPU", cl.device_type.GPU), ("ACCELERATOR", cl.device_type.ACCELERATOR)) if t & v]
    return "|".join(names) or str(t)


def report(kernels: bool = True) -> dict:
    versions = {}
    for name in PACKAGES:
        try:
            versions[name] = importlib.metadata.version(name)
        except importlib.metadata.PackageNotFoundError:
            versions[name] = None
    import dask

    try:
        import mlflow

        tracking_uri = mlflow.get_tracking_uri()
    except Exception as err:
        tracking_uri = f"unavailable ({err})"
    return {
        "python": sys.version.split()[0],
        "platform": platform.platform(),
        "cpus": os.cpu_count(),
        "packages": versions,
        "opencl": opencl_devices(kernels),
        "dask": {
            "scheduler": dask.config.get("scheduler", None) or "distributed (LocalCluster unless an address is given)",
            "scheduler_address": dask.config.get("scheduler-address", None) or os.environ.get("DASK_SCHEDULER_ADDRESS"),
            "worker_threads_default": 1,
            "temporary_directory": dask.config.get("temporary-directory", None),
        },
        "mlflow": {"tracking_uri": tracking_uri, "experiment": os.environ.get("MLFLOW_EXPERIMENT_NAME")},
        "environment": {k: os.environ[k] for k in ENV_VARS if k in os.environ},
    }


def run(args: argparse.Namespace) -> int:
    info = report(kernels=not args.no_kernels)
    if args.json:
        import json

        print(json.dumps(info, indent=1))
        return 0
    print(f"python    {info['python']} on {info['platform']} ({info['cpus']} CPUs)")
    print("packages")
    for name, ver in info["packages"].items():
        print(f"  {name:26s} {ver or 'not installed'}")
    print("OpenCL")
    devices = info["opencl"]
    if not devices:
        print("  no OpenCL platform found: the NumPy backend will be used")
    for d in devices:
        if "error" in d:
            print(f"  {d.get('platform', '')} error: {d['error']}")
        else:
            print(
                f"  [{d['id']}] {d['platform']} ({d['platform_version']}): {d['device']} "
                f"{d['type']}, {d['compute_units']} CU, {d['global_mem_mb']} MB, local {d['local_mem_kb']} KB"
            )
            target = f", kernel target CPU {d['kernel_target']}" if d.get("kernel_target") else ""
            print(f"        driver {d['driver']}{target}; BMUofN kernel: {d['bmu_kernel']}")
            if d.get("kernel_target_note"):
                print(f"        kernel target CPU {d['kernel_target_note']}")
            print(f"        gpu layout: {d['gpu_tuning']}")
            print(f"        per-unit sums and per-row errors of an epoch: on the {d['epoch_sums']}")
            print(f"        SOM.fit's epoch update: on the {d['epoch_update']}; the pipeline's: on the client's host")
            for v in d.get("layouts", []):
                where = "not in this device's chain" if v["chain"] is None else f"chain position {v['chain'] + 1}"
                if v["ok"]:
                    rate = f"{v['gflops']:.1f} GFLOP/s" if v["gflops"] else "untimed"
                    print(f"        layout {v['layout']:10s} ok      {rate:>16s}  ({where}; checked in {v['seconds']} s)")
                    if v.get("search_only"):
                        print(f"          search only: its epoch kernels fail ({v['reason']}); sums, errors and "
                              f"updates on the host")
                else:
                    print(f"        layout {v['layout']:10s} FAILED  ({where}): {v['reason']}")
            if "layouts_error" in d:
                print(f"        layouts not checked: {d['layouts_error']}")
    print("Dask")
    for k, v in info["dask"].items():
        print(f"  {k:24s} {v}")
    print("MLflow")
    for k, v in info["mlflow"].items():
        print(f"  {k:24s} {v}")
    if info["environment"]:
        print("environment")
        for k, v in info["environment"].items():
            print(f"  {k}={v}")
    return 0
