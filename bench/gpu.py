"""The two tables of issue 13 on one OpenCL device (a GPU): a BMUofN pass, and whole epochs.

Run on the GPU machine (see bench/gpu_device.sh), or anywhere with --quick:

    python bench/gpu.py --device nvidia [--autotune] [--quick]

(a) One BMUofN pass on the paper's 120 x 150 map (M = 18,000), random data, the fold-like
variation tables of bench/common.py: meshsom ``bmu_opencl`` with the device's default layout
(and the earlier "tiled" layout beside it), best of --repeat calls after a warm-up call,
host/device copies included; TFLOP/s = 2 N n M D / t and that rate as % of PyTorch's FP32
GEMM (8192^3, TF32 off) measured in the same run; the PyTorch baseline (per variation gather
+ sign, ``addmm(||w||^2, x_v, W^T, alpha=-2)``, min over units, keep the best variation;
rows in chunks of 65,536; TF32 off) with the data already on the GPU and with the copies;
and whether units and variations agree with PyTorch on every row.

(b) Seconds per epoch: meshsom's search, per-unit sums and update with the OpenCL engine (the
default kernel and BMUofN with n variations, as bench/epoch.py) on resident rows: X is
read-only, as the training pipeline's cached chunks are, so after the warm-up epoch only the
codebook's norms (and the codebook, unless the update ran on the device and left it there) go
to the device (:class:`meshsom.bmu_opencl.ResidentRows`); the update runs where ``SOM(update=
"auto")`` runs it (on a GPU with float64: on the device, the sums never leaving it), each epoch
starting from the codebook the one before made; beside it the default kernel on a writable X,
copied to the device every epoch, with the host's update (as before); and
XPySom with its CuPy backend (planar map, construction and host-to-device copy included),
each timed in steady state: best of the repeats after a warm-up call; and where the default
epoch's time goes (search, per-unit sums, the update, each on the device or the host). Table (a) keeps writable X: its
passes include the row copies, as the PyTorch "with copies" column does.

(c) Training epochs as the pipeline runs them (``SOM.fit``: the search, the per-unit sums and
the T / Q / QC error sums of every epoch, the update), seconds per epoch in steady state (the
median of the epochs after the first): the paper config's four maps (120 x 150, its levels and
kernels), and a 1,000,000-row level-3 map (the paper's level-3 rows repeated with a little seeded
noise, BMUofN). Each row says where the per-unit sums and errors were taken and where the update
ran (device or host); the paper maps' rows also time the host's update and print the trained map's
T / Q / QC, which on a CPU are exactly ``meshsom run configs/paper.yaml``'s (0.0069 / 0.0041 / 0.0021,
0.0021 / 0.0032 / 0.0016, 0.0007 / 0.0224 / 0.0045, 0.0035 / 0.0709 / 0.0064): a GPU run prints
the same to these digits unless rounding moved a winner.
The standardized level vectors come from a store of ``meshsom run configs/paper.yaml``,
exported once where the pipeline's dependencies are installed:

    python bench/gpu.py --export-levels out/paper.zarr .gpu/paper-levels.npz

and read with ``--levels .gpu/paper-levels.npz`` (the GPU machine has no zarr); without it the
table is skipped.

--autotune times the "gemm" candidates (:data:`AUTOTUNE_CANDIDATES`: tilings, chunks, prefetch,
NVIDIA's register cap) on two large (1e6 x 3 x 36 and x 144) and one small (3,064 x 3 x 144) pass, prints
the best, and runs the tables with the best overall (least geometric mean of its time over the
default's) as the "gpu" layout, unless --keep-default; with --registers also what NVIDIA's
compiler says of each candidate (registers, spills). --memory-report prints the device memory one
pass of each layout leaves held by its context, and stops; --diagnose DIR times the "gpu" layout's
pass with its epilogue or its staging left out and writes its program binary (PTX) to DIR, and
stops. Anything not importable (torch, CuPy, XPySom)
prints n/a.
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import replace
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np  # noqa: E402

from bench.common import MAP, best_time, block_table, data  # noqa: E402
from bench.epoch import meshsom_epoch  # noqa: E402
from meshsom.bmu_numpy import identity_table  # noqa: E402
from meshsom.tuning import CANDIDATES, WORKLOADS  # noqa: E402

#: (N, n, D) of the BMU table (issue 13).
BMU_WORKLOADS = [(3064, 1, 9), (3064, 6, 9), (3064, 3, 36), (3064, 3, 144), (100_000, 3, 36), (100_000, 1, 36),
                 (1_000_000, 6, 9), (1_000_000, 3, 36), (1_000_000, 3, 144)]
#: (N, n, D) of the epoch table: the default kernel with the same (N, D), BMUofN with n.
EPOCH_WORKLOADS = [(3064, 6, 9), (3064, 3, 36), (3064, 3, 144), (100_000, 3, 36), (1_000_000, 3, 36),
                   (1_000_000, 3, 144)]
#: --quick (PoCL, a laptop): N divided by this for the city-sized workloads (N > 10,000).
QUICK_DIVISOR = 100
#: Rows at or above this get one timed repetition (after the warm-up): keeps the whole run short.
LARGE_N = 1_000_000
#: Rows per PyTorch chunk (the baseline of issue 13).
TORCH_CHUNK = 65_536
#: Side of the PyTorch FP32 GEMM yardstick.
GEMM_SIZE = 8192
#: Candidates timed by --autotune: meshsom tune's (meshsom.tuning.CANDIDATES, the first the default;
#: a copy, which --candidates replaces).
AUTOTUNE_CANDIDATES = list(CANDIDATES)
#: The workloads --autotune times: (N, n, D), meshsom tune's.
AUTOTUNE_WORKLOADS = WORKLOADS
#: The paper config's maps (configs/paper.yaml): (level, kernel), trained for PAPER_EPOCHS.
PAPER_MAPS = [(1, "default"), (1, "bmuofn"), (2, "bmuofn"), (3, "bmuofn")]
PAPER_EPOCHS = 20
#: The large training map: level-3 rows repeated to this many, BMUofN, for LARGE_EPOCHS epochs.
LARGE_ROWS = 1_000_000
LARGE_EPOCHS = 3
#: Standard deviation of the noise added to the repeated rows (standardized units) and its seed.
LARGE_NOISE = 0.01
LARGE_SEED = 0


def say(text: str = "") -> None:
    print(text, flush=True)


def workloads(rows, quick: bool):
    return [(N // QUICK_DIVISOR if quick and N > 10_000 else N,) + tuple(w[1:]) for w in rows for N in (w[0],)]


# ----------------------------------------------------------------------------- PyTorch


def torch_cuda():
    """torch with a CUDA device and TF32 off, or None."""
    try:
        import torch
    except ImportError:
        return None
    if not torch.cuda.is_available():
        return None
    torch.backends.cuda.matmul.allow_tf32 = False
    torch.backends.cudnn.allow_tf32 = False
    return torch


def torch_gemm_tflops(torch, size: int = GEMM_SIZE, repeat: int = 3) -> float:
    """FP32 (TF32 off) size^3 matmul rate on the GPU."""
    a = torch.randn(size, size, device="cuda")
    b = torch.randn(size, size, device="cuda")

    def run():
        a @ b
        torch.cuda.synchronize()

    run()
    return 2 * size**3 / best_time(run, repeat) / 1e12


def torch_bmu(torch, X, W, index, sign):
    """The baseline: per variation gather + sign, addmm(||w||^2, x_v, W^T, alpha=-2), min over
    units, keep the best variation (strictly closer); X, W on the device. Returns (unit, variation)."""
    wn = (W * W).sum(1)
    units, variations = [], []
    for start in range(0, len(X), TORCH_CHUNK):
        x = X[start:start + TORCH_CHUNK]
        best_d = best_u = best_v = None
        for v in range(len(index)):
            xv = x[:, index[v]] * sign[v]
            d, u = torch.addmm(wn, xv, W.T, alpha=-2).min(1)
            d = d + (xv * xv).sum(1)
            if best_d is None:
                best_d, best_u, best_v = d, u, torch.zeros_like(u)
            else:
                better = d < best_d
                best_d = torch.where(better, d, best_d)
                best_u = torch.where(better, u, best_u)
                best_v = torch.where(better, torch.full_like(u, v), best_v)
        units.append(best_u)
        variations.append(best_v)
    return torch.cat(units), torch.cat(variations)


def torch_pass(torch, X, W, index, sign, copies: bool, device_data=None):
    """One timed baseline pass: from host arrays (copies) or from device_data (Xg, Wg, idx, sgn)."""
    if copies:
        Xg, Wg = torch.from_numpy(X).cuda(), torch.from_numpy(W).cuda()
        idx, sgn = torch.from_numpy(index).cuda(), torch.from_numpy(sign).cuda()
    else:
        Xg, Wg, idx, sgn = device_data
    u, v = torch_bmu(torch, Xg, Wg, idx, sgn)
    if copies:
        u, v = u.cpu().numpy(), v.cpu().numpy()
    torch.cuda.synchronize()
    return u, v


# ----------------------------------------------------------------------------- tables


def bmu_table(args, ctx, torch, gemm):
    from meshsom.bmu_opencl import DEFAULT_PARAMS, bmu_opencl, default_params

    rows, cols = MAP
    M = rows * cols
    params = default_params(ctx)
    layouts = [("new", params)]
    if not args.no_old:
        layouts.append(("old", DEFAULT_PARAMS["tiled"]))
    say(f"\n(a) one BMUofN pass, map {rows}x{cols} (M = {M}); new layout: {params}")
    say(f"{'N':>9} {'n x D':>7} {'new s':>8} {'TFLOP/s':>8} {'%GEMM':>7} {'old s':>8} "
        f"{'torch s':>8} {'torch+cp s':>10} {'agree':>6}")
    for N, n, D in workloads(BMU_WORKLOADS, args.quick):
        X, W = data(N, D, M)
        index, sign = block_table(n, D)
        repeat = 1 if N >= LARGE_N else args.repeat
        times, results = {}, {}
        for name, p in layouts:
            def run(p=p):
                return bmu_opencl(X, W, index, sign, context=ctx, params=p)
            results[name] = run()  # warm-up: builds the program
            times[name] = best_time(run, repeat)
        flops = 2.0 * N * n * M * D
        rate = flops / times["new"] / 1e12
        share = f"{100 * rate / gemm:6.1f}%" if gemm else f"{'n/a':>7}"
        old = f"{times['old']:8.4f}" if "old" in times else f"{'n/a':>8}"
        if torch is not None:
            device_data = (torch.from_numpy(X).cuda(), torch.from_numpy(W).cuda(),
                           torch.from_numpy(index).cuda(), torch.from_numpy(sign).cuda())
            u, v = torch_pass(torch, X, W, index, sign, False, device_data)  # warm-up
            t_dev = best_time(lambda: torch_pass(torch, X, W, index, sign, False, device_data), repeat)
            t_cp = best_time(lambda: torch_pass(torch, X, W, index, sign, True), repeat)
            u, v = u.cpu().numpy(), v.cpu().numpy()
            new = results["new"]
            agree = np.mean((u == new.unit) & (v == new.variation))
            agree_text = "yes" if agree == 1 else f"{100 * agree:.3f}%"
            torch_text = f"{t_dev:8.4f} {t_cp:10.4f} {agree_text:>6}"
            del device_data
        else:
            torch_text = f"{'n/a':>8} {'n/a':>10} {'n/a':>6}"
        say(f"{N:>9} {f'{n}x{D}':>7} {times['new']:8.4f} {rate:8.2f} {share} {old} {torch_text}")


def xpysom_epoch(cupy, XPySom, X, rows, cols):
    """One XPySom epoch with the CuPy backend, construction and host-to-device copy included."""
    som = XPySom(rows, cols, X.shape[1], sigma=5.0, random_seed=0, xp=cupy)
    som.train(X, 1)
    cupy.cuda.Device().synchronize()


def device_epoch(X, W, index, sign, engine, rows, cols, sigma=5.0, update="auto"):
    """One epoch as ``SOM.fit`` runs it without the error sums: the search, the per-unit sums and the
    update, the sums kept on the device and updated there where ``update`` says so."""
    on_device = engine.update_on_device(update)
    bmu = engine.search(X, W, index, sign)
    sums, counts = engine.unit_sums(X, W, bmu, index, sign, keep=on_device)
    return engine.batch_update(W, sums, counts, sigma, rows, cols, "toroidal")


def chained(epoch, W):
    """A callable running ``epoch(W)`` from the codebook the previous call made (as training does)."""
    state = [W]

    def run():
        state[0] = epoch(state[0])
    return run


def epoch_table(args, ctx):
    from meshsom.bmu import resolve_backend

    rows, cols = MAP
    M = rows * cols
    engine = resolve_backend("opencl", context=ctx)
    try:
        import cupy
        from xpysom import XPySom
    except ImportError as err:
        cupy = XPySom = None
        say(f"note: XPySom + CuPy not importable ({err}): n/a")
    where = "device" if engine.update_on_device(args.update) else "host"
    say(f"\n(b) seconds per epoch, map {rows}x{cols}; meshsom: search + per-unit sums + update (on the {where}), "
        f"OpenCL engine, rows resident (read-only X) unless 'copied' (copied: host update)")
    say(f"{'N':>9} {'D':>4} {'default':>9} {'BMUofN (n)':>14} {'copied':>9} {'XPySom+CuPy':>12} "
        f"{'xpysom/default':>15}  default epoch: search / sums / update ms")
    for N, n, D in workloads(EPOCH_WORKLOADS, args.quick):
        X, W = data(N, D, M)
        index, sign = block_table(n, D)
        ident = identity_table(D)
        repeat = 1 if N >= LARGE_N else args.repeat
        meshsom_epoch(X, W, *ident, engine, rows, cols)  # warm-up: builds the program
        t_copied = best_time(lambda: meshsom_epoch(X, W, *ident, engine, rows, cols), repeat)  # writable X
        X.flags.writeable = False  # X owns its rows: from now on they stay on the device
        default = chained(lambda W: device_epoch(X, W, *ident, engine, rows, cols, update=args.update), W)
        default()  # warm-up: sends the rows
        t_default = best_time(default, repeat)
        varied = chained(lambda W: device_epoch(X, W, index, sign, engine, rows, cols, update=args.update), W)
        varied()
        t_n = best_time(varied, repeat)
        if XPySom is not None:
            xpysom_epoch(cupy, XPySom, X, rows, cols)  # warm-up: CuPy compiles its kernels
            t_x = best_time(lambda: xpysom_epoch(cupy, XPySom, X, rows, cols), repeat)
            peer = f"{t_x:12.4f} {t_x / t_default:15.2f}"
        else:
            peer = f"{'n/a':>12} {'n/a':>15}"
        parts = epoch_parts(X, W, ident, engine, rows, cols, repeat, args.update)
        say(f"{N:>9} {D:>4} {t_default:9.4f} {f'{t_n:.4f} ({n})':>14} {t_copied:9.4f} {peer}  {parts}")
        del X  # frees the rows' device copy too


def epoch_parts(X, W, table, engine, rows, cols, repeat, update="auto") -> str:
    """Where a default-kernel epoch's time goes (resident rows): the search, the per-unit sums and
    the update (each on the device or the host, as :func:`device_epoch` takes them), each the best
    of ``repeat`` after the epochs timed before; the search against a codebook the update left on
    the device."""
    index, sign = table
    on_device = engine.update_on_device(update)
    bmu = engine.search(X, W, index, sign)
    sums, counts = engine.unit_sums(X, W, bmu, index, sign, keep=on_device)
    new = engine.batch_update(W, sums, counts, 5.0, rows, cols, "toroidal")
    t_search = best_time(lambda: engine.search(X, new, index, sign), repeat)
    t_sums = best_time(lambda: engine.unit_sums(X, W, bmu, index, sign, keep=on_device), repeat)
    t_update = best_time(lambda: engine.batch_update(W, sums, counts, 5.0, rows, cols, "toroidal"), repeat)
    where = "host" if engine.sums_on_host else "device"
    updated = "device" if on_device and not engine.update_on_host else "host"
    return f"{1e3 * t_search:.2f} / {1e3 * t_sums:.2f} ({where}) / {1e3 * t_update:.2f} ({updated})"


def export_levels(store: str, out: str) -> None:
    """Write the standardized vectors of every ring level of a store, and the variation tables of
    PAPER_MAPS, to an .npz (keys ``X<level>``, ``index_<level>_<kernel>``, ``sign_<level>_<kernel>``)."""
    from meshsom.store import open_store, ring_levels
    from meshsom.variations import variation_table
    from pipelines.train import load_level

    group = open_store(store)
    arrays = {f"X{level}": load_level(group, level) for level in ring_levels(group)}
    for level, kernel in PAPER_MAPS:
        index, sign = variation_table(level, mirror=False, kernel=kernel)
        arrays[f"index_{level}_{kernel}"], arrays[f"sign_{level}_{kernel}"] = index, sign
    Path(out).parent.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(out, **arrays)
    say(f"wrote {out}: " + ", ".join(f"{k} {v.shape}" for k, v in arrays.items()))


def fit_epochs(X, index, sign, epochs: int, device, update: str = "auto", evaluate: bool = False):
    """SOM.fit on the paper's map with the OpenCL engine (the paper config's SOM settings): the median
    seconds of the epochs after the first, where the per-unit sums and errors and the update ran, and
    (``evaluate``) the trained map's T / Q / QC-errors on X, as ``meshsom run`` reports them."""
    from meshsom.som import SOM

    rows, cols = MAP
    seconds = []
    som = SOM(rows, cols, epochs=epochs, backend="opencl", device=device, random_state=0, update=update)
    som.fit(X, index, sign, callbacks=[lambda epoch, som, info: seconds.append(info.seconds)])
    engine = som.engine_
    where = f"host ({engine.sums_on_host})" if engine.sums_on_host else "device"
    where += f"; update on the {som.update_}" + (f" ({engine.update_on_host})" if engine.update_on_host else "")
    errors = som.evaluate(X, index, sign) if evaluate else None
    return float(np.median(seconds[1:] if len(seconds) > 1 else seconds)), where, errors


def training_table(args) -> None:
    levels = np.load(args.levels)
    rows, cols = MAP
    say(f"\n(c) training epochs (SOM.fit: search, per-unit sums, T/Q/QC error sums, update), map {rows}x{cols}, "
        f"OpenCL engine; median seconds of the epochs after the first, with the update where --update "
        f"({args.update}) puts it and on the host; the trained map's T / Q / QC (the paper maps: configs/paper.yaml's "
        f"settings)")
    say(f"{'map':>22} {'N':>9} {'n x D':>7} {'epochs':>6} {'s/epoch':>9} {'host upd.':>9} {'T / Q / QC':>22}  "
        f"sums and errors on; update")
    for level, kernel in PAPER_MAPS:
        X = levels[f"X{level}"]
        index, sign = levels[f"index_{level}_{kernel}"], levels[f"sign_{level}_{kernel}"]
        epochs = 3 if args.quick else PAPER_EPOCHS
        t, where, e = fit_epochs(X, index, sign, epochs, args.device, update=args.update, evaluate=True)
        t_host = fit_epochs(X, index, sign, epochs, args.device, update="host")[0]
        errors = f"{e['t_error']:.4f} / {e['q_error']:.4f} / {e['qc_error']:.4f}"
        say(f"{f'paper level {level} {kernel}':>22} {len(X):>9} {f'{len(index)}x{X.shape[1]}':>7} {epochs:>6} "
            f"{t:9.4f} {t_host:9.4f} {errors:>22}  {where}")
    X3 = levels["X3"]
    N = LARGE_ROWS // QUICK_DIVISOR if args.quick else LARGE_ROWS
    rng = np.random.default_rng(LARGE_SEED)
    X = X3[np.arange(N) % len(X3)] + rng.normal(scale=LARGE_NOISE, size=(N, X3.shape[1])).astype(np.float32)
    index, sign = levels["index_3_bmuofn"], levels["sign_3_bmuofn"]
    t, where, _ = fit_epochs(X, index, sign, LARGE_EPOCHS, args.device, update=args.update)
    say(f"{'level 3 x 1e6 bmuofn':>22} {N:>9} {f'{len(index)}x{X.shape[1]}':>7} {LARGE_EPOCHS:>6} {t:9.4f} "
        f"{'':>9} {'':>22}  {where}")


def candidate_name(fields: dict) -> str:
    """A candidate's fields, short: "default" for none."""
    short = {"tile_rows": "tm", "tile_units": "tn", "group_rows": "gm", "group_units": "gn", "max_kt": "kt",
             "vector_width": "vw", "prefetch": "pf", "max_registers": "reg", "groups_per_cu": "gpc",
             "whole_row_tile": "whole", "staged_kt": "skt"}
    return " ".join(f"{short[k]}={int(v)}" for k, v in fields.items()) or "default"


def register_report(ctx, params, D: int, n: int) -> str:
    """What NVIDIA's compiler says of a layout's program (``-cl-nv-verbose``: registers, spills, local
    memory per work-item) and the kernel's private memory; "" where the driver says nothing."""
    import pyopencl as cl

    from meshsom.bmu_opencl import KERNELS, _defines, build_options, kernel_source

    device = ctx.devices[0]
    defines = _defines(D, n, np.float32, params)
    options = build_options(ctx, defines)
    if "cl_nv_compiler_options" in device.extensions:
        options.append("-cl-nv-verbose")
    program = cl.Program(ctx, kernel_source(defines["KERNEL"])).build(options=options)
    log = program.get_build_info(device, cl.program_build_info.LOG)
    main = KERNELS[defines["KERNEL"]][1]
    lines = [ln.strip() for ln in log.splitlines() if "ptxas" in ln and ("registers" in ln or "spill" in ln
                                                                        or main in ln)]
    kernel = cl.Kernel(program, main)
    private = kernel.get_work_group_info(cl.kernel_work_group_info.PRIVATE_MEM_SIZE, device)
    return f"private {private} B/work-item; " + " | ".join(lines[-3:])


def autotune(args, ctx):
    """meshsom tune's timing (meshsom.tuning.tune) of AUTOTUNE_CANDIDATES, printed with bench's short
    names, TFLOP/s and (--registers) the compiler's report; the overall best as the 'gpu' layout."""
    from meshsom.bmu_opencl import layout_params
    from meshsom.tuning import tune

    rows, cols = MAP
    M = rows * cols
    base = layout_params(ctx.devices[0], "gpu", tuned=False)  # the built-in default, whatever meshsom tune saved
    say(f"\nautotune: gemm candidates over {base}, seconds per pass")
    chosen = [tuple(int(v) for v in w.split(",")) for w in args.tune_workload] if args.tune_workload else None
    passes = workloads(chosen or AUTOTUNE_WORKLOADS, args.quick)

    def line(t):
        N, n, D = t.workload
        fields = AUTOTUNE_CANDIDATES[t.candidate]
        head = f"{N:>9} {f'{n}x{D}':>7} {candidate_name(fields):>36}"
        if t.seconds is None:
            say(f"{head} {t.why}")
            return
        report = ""
        if t.workload == passes[0] and args.registers:
            try:
                report = "  " + register_report(ctx, replace(base, **fields), D, n)
            except Exception as err:  # noqa: BLE001 - the report is a diagnosis only
                report = f"  (no register report: {str(err)[:80]})"
        say(f"{head} {t.seconds:8.4f} {2.0 * N * n * M * D / t.seconds / 1e12:6.2f} TFLOP/s{report}")

    result = tune(ctx, passes, AUTOTUNE_CANDIDATES, repeat=2, units=M, report=line)
    for workload in dict.fromkeys(t.workload for t in result.timings):
        timed = [(t.seconds, t.candidate) for t in result.timings if t.workload == workload and t.seconds is not None]
        if timed:
            seconds, c = min(timed)
            say(f"best for N, n, D = {workload}: {candidate_name(AUTOTUNE_CANDIDATES[c])} ({seconds:.4f} s)")
    if not result.ratios:
        return None
    c = min(result.ratios, key=result.ratios.get)  # the least geometric mean over the default's
    say(f"overall best: {candidate_name(AUTOTUNE_CANDIDATES[c])}, {result.ratios[c]:.3f} x the default's time "
        "(geometric mean)")
    return replace(base, name="gpu", **AUTOTUNE_CANDIDATES[c])


#: Workloads of --diagnose's stage timing: (N, n, D).
DIAGNOSE_WORKLOADS = [(1_000_000, 3, 36), (1_000_000, 3, 144)]
#: Stages --diagnose leaves out (the kernel's MESHSOM_ABLATE bits, kernels/bmu_gpu.cl).
ABLATIONS = {0: "whole pass", 1: "without the epilogue's comparisons", 2: "without staging after the first tile",
             3: "without both"}


def diagnose(args, ctx, folder: str) -> None:
    """Where the "gpu" layout's pass spends its time, for the next round of tuning: the program's
    binary (PTX on NVIDIA) at D = 36 and 144 written to ``folder``, and the pass timed with a stage
    left out (:data:`ABLATIONS`; wrong answers, so built without the probe and never used otherwise)."""
    import pyopencl as cl

    from meshsom.bmu_numpy import validate
    from meshsom.bmu_opencl import _defines, _queue, default_params, get_kernel, launch

    out = Path(folder)
    out.mkdir(parents=True, exist_ok=True)
    params = default_params(ctx)
    rows, cols = MAP
    M = rows * cols
    say(f"\ndiagnose: {params}")
    queue = _queue(ctx)
    for N, n, D in workloads(DIAGNOSE_WORKLOADS, args.quick):
        X, W = data(N, D, M)
        index, sign = block_table(n, D)
        X, W, index, sign = validate(X, W, index, sign)
        base = None
        for ablate, what in ABLATIONS.items():
            defines = {**_defines(D, n, X.dtype, params), "MESHSOM_ABLATE": ablate}
            kernel = get_kernel(ctx, defines, guard=False, layout=f"ablate-{ablate}")
            if ablate == 0:
                binary = kernel.get_info(cl.kernel_info.PROGRAM).get_info(cl.program_info.BINARIES)[0]
                (out / f"gemm-D{D}.ptx").write_bytes(binary)
            launch(ctx, queue, kernel, X, W, index, sign, defines)
            t = best_time(lambda: launch(ctx, queue, kernel, X, W, index, sign, defines), 2)
            base = base or t
            say(f"{N:>9} {f'{n}x{D}':>7} {what:>40} {t:8.4f} s  {t / base:6.2f} of the pass")
    say(f"program binaries in {out}")


def memory_report(ctx) -> None:
    """Device memory a context holds after one launch of each layout (torch's free-memory reading):
    NVIDIA reserves a kernel's private (spilled) memory for every resident work-item."""
    torch = torch_cuda()
    if torch is None:
        say("memory report: n/a (torch with CUDA not importable)")
        return
    from meshsom.bmu_opencl import DEFAULT_PARAMS, bmu_opencl

    X, W = data(3064, 36, 300)
    index, sign = block_table(3, 36)
    say("\nmemory held on the device after one pass of each layout (3,064 x 3 x 36, 300 units)")
    for name in ("gpu", "tiled", "cpu", "cpu-narrow"):
        before = torch.cuda.mem_get_info()[0]
        try:
            bmu_opencl(X, W, index, sign, context=ctx, params=DEFAULT_PARAMS[name])
            report = register_report(ctx, DEFAULT_PARAMS[name], 36, 3)
        except Exception as err:  # noqa: BLE001 - reported
            say(f"  {name:>10}: failed: {str(err)[:160]}")
            continue
        after = torch.cuda.mem_get_info()[0]
        say(f"  {name:>10}: {(before - after) / 2**20:9.1f} MiB more held; {report}")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--device", default=None, help="OpenCL device selector (e.g. nvidia); default $PYOPENCL_CTX")
    parser.add_argument("--repeat", type=int, default=3, help="timed calls after the warm-up (1 at N >= 1e6)")
    parser.add_argument("--quick", action="store_true", help=f"N / {QUICK_DIVISOR} for the city-sized workloads")
    parser.add_argument("--no-old", action="store_true", help="skip the earlier 'tiled' layout")
    parser.add_argument("--no-epoch", action="store_true", help="skip the epoch table")
    parser.add_argument("--autotune", action="store_true", help="time a few gemm tilings and print the best")
    parser.add_argument("--tune-workload", action="append", default=None, metavar="N,n,D",
                        help="with --autotune: time this workload instead of the two default ones (repeatable)")
    parser.add_argument("--tune-only", action="store_true", help="with --autotune: stop after it")
    parser.add_argument("--candidates", default=None, metavar="JSON",
                        help="with --autotune: a JSON list of field overrides instead of AUTOTUNE_CANDIDATES "
                             "(the first is the reference)")
    parser.add_argument("--registers", action="store_true",
                        help="with --autotune: NVIDIA's register and spill report of every candidate")
    parser.add_argument("--diagnose", default=None, metavar="DIR",
                        help="write the gpu layout's program binaries (PTX on NVIDIA) to DIR, time its pass "
                             "with stages left out, and stop")
    parser.add_argument("--memory-report", action="store_true",
                        help="the device memory one pass of each layout leaves held, with its register report, "
                             "and stop (its own process: the 'cpu' layouts can hold half an H200)")
    parser.add_argument("--keep-default", action="store_true",
                        help="with --autotune: run the tables with the default tiling, not the tuned one")
    parser.add_argument("--levels", default=None, help="an .npz of --export-levels: table (c), training epochs")
    parser.add_argument("--update", default="auto", choices=["auto", "host", "device"],
                        help="where meshsom's epochs update in tables (b) and (c) (SOM's update; 'auto': "
                             "on a GPU with float64)")
    parser.add_argument("--only-training", action="store_true", help="table (c) alone")
    parser.add_argument("--export-levels", nargs=2, metavar=("STORE", "NPZ"),
                        help="write a paper store's level vectors and variation tables for --levels, and stop")
    args = parser.parse_args(argv)
    if args.candidates:
        import json

        AUTOTUNE_CANDIDATES[:] = json.loads(args.candidates)
    if args.export_levels:
        export_levels(*args.export_levels)
        return 0
    started = time.perf_counter()

    from meshsom.bmu_opencl import device_name, get_context

    ctx = get_context(args.device)
    device = ctx.devices[0]
    say(f"OpenCL device: {device_name(ctx)} ({device.max_compute_units} compute units, "
        f"{device.local_mem_size // 1024} KB local memory, driver {device.driver_version})")
    torch = torch_cuda()
    gemm = None
    if torch is None:
        say("note: torch with CUDA not importable: the PyTorch columns and % of GEMM are n/a")
    else:
        gemm = torch_gemm_tflops(torch)
        say(f"torch {torch.__version__} on {torch.cuda.get_device_name()}: FP32 GEMM {GEMM_SIZE}^3 "
            f"(TF32 off) {gemm:.1f} TFLOP/s")
    if args.memory_report:
        memory_report(ctx)
        return 0
    if args.diagnose:
        diagnose(args, ctx, args.diagnose)
        return 0
    if args.autotune and not args.only_training:
        tuned = autotune(args, ctx)
        if args.tune_only:
            return 0
        if tuned is not None and not args.keep_default:
            from meshsom import bmu_opencl

            say(f"tables (a)-(c) run with the tuned tiling as the 'gpu' layout: {tuned}")
            bmu_opencl.DEFAULT_PARAMS["gpu"] = tuned
    if not args.only_training:
        bmu_table(args, ctx, torch, gemm)
    if args.levels:  # before (b): short, and item 2 of issue 13 asks for it
        training_table(args)
    else:
        say("\n(c) training epochs: skipped (no --levels; see --export-levels)")
    if not args.no_epoch and not args.only_training:
        epoch_table(args, ctx)
    say(f"\ntotal {time.perf_counter() - started:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
