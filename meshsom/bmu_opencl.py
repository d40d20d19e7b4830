"""BMUofN on OpenCL: the fused kernel, same answers as :mod:`meshsom.bmu_numpy`.

The kernel never materialises the N x M distance matrix: each work-item keeps the best
and second-best unit of its rows per SIMD lane while it sweeps the codebook, and applies
the variations (gather + sign) on the fly. It comes in two layouts of the same arithmetic
(:data:`KERNELS`): ``kernels/bmu_cpu.cl`` for CPU devices (cache- and register-blocked,
the varied vectors of a panel of rows gathered once into private memory),
``kernels/bmu_gpu.cl`` for GPUs (a register-tiled GEMM micro-kernel over virtual rows
``row * n + v`` with a fused best/second epilogue, then a reduction kernel over unit splits
and variations) and ``kernels/bmu.cl`` (the earlier GPU layout: codebook tiles in local
memory); the device type picks one (:data:`DEFAULT_PARAMS`), ``params`` overrides it. Sizes are compiled in as ``-D`` defines; the
built program is memoised per (context, defines). The context is injected by the caller
or made from a device selector: the ``device`` argument, else ``PYOPENCL_CTX``, else the
first device of the first platform. ``create_some_context`` is never called, so nothing
ever prompts.

Device selectors: ``"P:D"`` (platform and device numbers, as ``PYOPENCL_CTX``), ``"P"``,
or a case-insensitive substring of a platform or device name (``"pocl"``, ``"nvidia"``).

Resident rows: a row array that cannot change (``X.flags.writeable`` False, and so is every
array it is a view of, see :func:`immutable`) keeps its device copy, with the int32 variation
index and the sign table, between searches on the same context (:class:`ResidentRows`), so
that an epoch loop over cached chunks sends only the codebook and its norms to the device.
The copies are keyed by the array's identity, checked through a weak reference (a new array
at a freed one's address never matches), and held within a byte budget per context
(:data:`RESIDENT_MEMORY_FRACTION` of the device's global memory), least recently used out
first. Writable arrays are copied every call, as before. The promise a caller makes by
passing a read-only array is that its values do not change while it lives (do not set it
writable again and write to it).

Device epochs: an epoch's per-unit sums can stay on the device (:class:`DeviceArray`, from
:func:`launch_unit_sums` with ``keep``), the update smooths and divides them there
(:func:`batch_update_opencl`, ``kernels/batch_update.cl``), and the new codebook it brings back
keeps its device copy (:class:`ResidentCodebooks`), so that the next search does not send it up
again: an epoch then moves the winners, the per-row errors and the float32 codebook, not the
(M, D) float64 sums.
"""

from __future__ import annotations

import logging
import math
import os
import threading
import weakref
from collections import OrderedDict
from dataclasses import dataclass, replace
from importlib import resources

import numpy as np

from meshsom.bmu_numpy import BMUResult, exact_dist2, fma_norms, unit_order, validate
from meshsom.metrics import COMPONENT
from meshsom.errors import DeviceError
from meshsom.pocl_target import AVX512_CPUS, NON_AVX512_CPUS
from meshsom.probe import injected_defines

log = logging.getLogger(__name__)

#: Environment variable read when no device selector is given (pyopencl's own).
ENV_SELECTOR = "PYOPENCL_CTX"


#: Local memory a "gemm" work-group may take: what NVIDIA's OpenCL gives one (48 KB), or a
#: device's own where less (:func:`layout_params`). The whole row tile
#: (:attr:`KernelParams.whole_row_tile`) is staged only where it fits.
GEMM_LOCAL_LIMIT = 48 * 1024


@dataclass(frozen=True)
class KernelParams:
    """Which kernel and its tiling.

    Three variants of the one BMUofN kernel exist, with the same arithmetic and answers:
    ``"cpu"`` (``kernels/bmu_cpu.cl``: a work-item owns a panel of rows and sweeps the codebook
    in L2-sized blocks with a register-blocked outer product, no barriers), ``"gemm"``
    (``kernels/bmu_gpu.cl``: an SGEMM-style register-tiled work-group tile of varied vectors
    x units, operands staged through local memory along D, double-buffered; for GPUs) and
    ``"tiled"`` (``kernels/bmu.cl``: a work-group stages codebook tiles in local memory, few
    registers per work-item; the earlier GPU layout).

    Attributes
    ----------
    kernel : {"cpu", "gemm", "tiled"}
    name : str
        Layout name for messages, MLflow and the probe's test hook (a key of :data:`DEFAULT_PARAMS`,
        or "custom").
    vector_width : int
        SIMD lanes per accumulator vector (VW): 2, 4, 8 or 16 (halved for float64). "gemm": the
        width of the local-memory operand loads; rows and units per work-item are multiples of it.
    unit_blocks : int
        Vectors of units per step (UB); a codebook tile holds ``vector_width * unit_blocks`` units.
    max_rows : int
        "tiled": varied vectors per work-item (R = RX * n is at most this, RX at least 1).
        "cpu": varied vectors per register block (RS).
    use_local : bool
        "tiled": stage the codebook tile in local memory.
    work_group : int
        "tiled": work-items per group ("cpu" runs groups of one).
    max_dt : int
        "tiled": most dimensions per local tile (DT is the largest divisor of D not above this).
    panel : int
        "cpu": varied vectors per work-item (P * n, rounded to whole register blocks).
    panel_bytes : int
        "cpu": most bytes of staged varied vectors per work-item (caps the panel at large D).
    cache_tiles : int
        "cpu": codebook tiles per cache block (UBLK).
    tile_rows : int
        "gemm": varied vectors (virtual rows) per work-group tile (TM).
    tile_units : int
        "gemm": units per work-group tile (TN).
    group_rows : int
        "gemm": work-items of a group along the rows (WGM); each holds TM / WGM rows.
    group_units : int
        "gemm": work-items of a group along the units (WGN); each holds TN / WGN units, so a
        work-item keeps (TM / WGM) x (TN / WGN) accumulators in registers.
    max_kt : int
        "gemm": most dimensions per local-memory chunk (halved for float64; KT: the largest
        divisor of D not above this when it is at least half of it, else this, with D
        zero-padded to a multiple).
    staged_kt : int
        "gemm": ``max_kt`` where the row tile is staged per chunk (not whole, see
        ``whole_row_tile``); 0: ``max_kt``.
    local_limit : int
        "gemm": bytes of local memory a work-group may take (:data:`GEMM_LOCAL_LIMIT`, capped by the
        device's in :func:`layout_params`); decides where the whole row tile fits.
    unit_splits : int
        "gemm": ranges the units are split into (S; one work-group per row tile and range,
        partial best/second per range, folded by the reduction kernel). 0: chosen from the
        device's compute units (:func:`unit_splits`).
    groups_per_cu : int
        "gemm", ``unit_splits=0``: work-groups a compute unit runs at once; a wave of the
        automatic splits' cost model is this many per compute unit (:func:`unit_splits`).
    whole_row_tile : bool
        "gemm": gather the row tile's varied vectors into local memory once, for all of D (XRES),
        staging only the codebook per chunk, where that fits ``local_limit`` beside the codebook's
        chunks (:func:`gemm_whole_row_tile`); else, or False, X is staged per chunk as W is.
    prefetch : bool
        "gemm": double-buffer the local-memory chunks along D (PF: the next chunk's loads in
        flight while one is multiplied); False: load, then multiply (fewer registers).
    max_registers : int
        "gemm" on NVIDIA's OpenCL (``cl_nv_compiler_options``): the compiler's register cap per
        work-item (``-cl-nv-maxrregcount``), trading spills for more work-groups per compute
        unit; 0: the compiler's choice. Ignored by other drivers.
    smooth_outputs : int
        Outputs per work-item of the update's smoothing kernel (``SMOOTH_RJ`` of
        ``kernels/batch_update.cl``): each value it reads serves this many outputs.
    epoch_kernels : bool
        Build the epoch's kernels (``kernels/epoch_sums.cl``, ``kernels/batch_update.cl``) into the
        program where the device has float64; False: the search alone (what an engine falls back
        to when they fail their probe and the search does not, :meth:`meshsom.bmu.Engine.search`).
    """

    kernel: str = "tiled"
    name: str = "custom"
    vector_width: int = 16
    unit_blocks: int = 2
    max_rows: int = 8
    use_local: bool = True
    work_group: int = 8
    max_dt: int = 144
    panel: int = 192
    panel_bytes: int = 262_144
    cache_tiles: int = 16
    tile_rows: int = 128
    tile_units: int = 128
    group_rows: int = 16
    group_units: int = 16
    max_kt: int = 16
    unit_splits: int = 0
    groups_per_cu: int = 2
    staged_kt: int = 0
    local_limit: int = GEMM_LOCAL_LIMIT
    whole_row_tile: bool = False
    prefetch: bool = True
    max_registers: int = 0
    smooth_outputs: int = 1
    epoch_kernels: bool = True

    def __post_init__(self):
        if self.kernel not in KERNELS:
            raise ValueError(f"kernel must be one of {', '.join(KERNELS)}, received {self.kernel!r}")
        if self.vector_width not in (2, 4, 8, 16):
            raise ValueError(f"vector_width must be 2, 4, 8 or 16, received {self.vector_width}")
        for name in ("unit_blocks", "max_rows", "work_group", "max_dt", "panel", "panel_bytes", "cache_tiles",
                     "tile_rows", "tile_units", "group_rows", "group_units", "max_kt", "groups_per_cu",
                     "smooth_outputs", "local_limit"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be >= 1, received {getattr(self, name)}")
        if self.staged_kt < 0:
            raise ValueError(f"staged_kt must be >= 0 (0: max_kt), received {self.staged_kt}")
        if self.max_registers < 0:
            raise ValueError(f"max_registers must be >= 0 (0: the compiler's choice), received {self.max_registers}")
        if self.unit_splits < 0:
            raise ValueError(f"unit_splits must be >= 0 (0: automatic), received {self.unit_splits}")
        for tile, group in (("tile_rows", "group_rows"), ("tile_units", "group_units")):
            size, items = getattr(self, tile), getattr(self, group)
            if self.kernel == "gemm" and (size % items or (size // items) % self.vector_width):
                raise ValueError(f"{tile} / {group} must be a whole multiple of vector_width {self.vector_width}, "
                                 f"received {tile}={size}, {group}={items}")


#: Kernel variant -> (source file under ``kernels/``, kernel function).
KERNELS = {"cpu": ("bmu_cpu.cl", "bmu_of_n_cpu"), "gemm": ("bmu_gpu.cl", "bmu_of_n_gemm"),
           "tiled": ("bmu.cl", "bmu_of_n")}
#: The second kernel of the "gemm" variant: folds unit splits and variations into the outputs.
GEMM_REDUCE = "bmu_of_n_gemm_reduce"
#: The "gemm" program's kernel that pads the codebook to (MP, DP) for its staging.
GEMM_PAD = "pad_codebook"
#: Work-group size of the "gemm" reduction kernel (one work-item per row).
REDUCE_GROUP = 64
#: The kernels of an epoch's reductions (``kernels/epoch_sums.cl``), part of every layout's
#: program where the device has float64: per-unit sums, per-row Q / QC distances and per-row
#: topographic errors (with the tie rule).
UNIT_SUMS = "unit_sums"
ROW_ERRORS = "row_errors"
TOPOGRAPHIC_ERRORS = "topographic_errors"
#: The kernels of the stable order of rows by unit (:func:`device_unit_order`) and their
#: work-group size (``ORDER_GROUP`` of ``kernels/epoch_sums.cl``).
UNIT_COUNTS = "unit_counts"
EXCLUSIVE_SCAN = "exclusive_scan"
STABLE_ORDER = "stable_unit_order"
UNIT_TOTALS = "unit_totals"
ORDER_GROUP = 64
#: Work-group size of those kernels (one work-item per unit and dimension, or per row).
SUMS_GROUP = 64
#: The kernels of an epoch's update on the device (``kernels/batch_update.cl``, built with the
#: epoch's reductions): a Gaussian sum along one grid axis, and the division into the codebook.
SMOOTH_AXIS = "smooth_axis"
DIVIDE_CODEBOOK = "divide_codebook"
#: Codebooks an update on the device leaves resident per context (the newest ones).
CODEBOOKS_KEPT = 2

#: The layouts: kernel and tiling. "cpu": the cache-blocked kernel with 2 x 16 units against 8
#: varied vectors in registers (16 zmm accumulators), 192 varied vectors per work-item and 16
#: tiles (512 units) per L2 block; measured on a 2-core AVX-512 Xeon (bench/bmu.py).
#: "cpu-narrow": CPUs (or kernel targets) without 512-bit vectors. "gpu": the SGEMM-style "gemm"
#: kernel, tuned on an NVIDIA H200 (bench/gpu.py --autotune, 2026-11-30: 14, then 9 candidates):
#: 64 varied vectors x 128 units per group of 16 x 16 work-items, 4 x 8 accumulators each, the
#: whole row tile gathered into local memory once where it fits (float32 D up to 152: the
#: paper's 9, 36 and 144, the codebook's chunks then 8 dimensions where 16 do not fit; beyond, D
#: staged 8 at a time, 4 in float64: 0.73x the time of 16 at 1e6 x 3 x 144, measured before the
#: whole tile reached D = 144), the codebook double-buffered; 121 registers against 195 for 128 x 128 tiles
#: (one group per compute unit), 0.91x its time (geometric mean of 1e6 x 3 x 36 and
#: 3,064 x 3 x 144).
#: "tiled": the local-memory kernel with small vectors (the earlier GPU layout), the last OpenCL
#: layout of every chain.
DEFAULT_PARAMS = {
    "cpu": KernelParams(kernel="cpu", name="cpu", vector_width=16, unit_blocks=2, max_rows=8, panel=192,
                        cache_tiles=16),
    # CPUs whose preferred float vector is narrower than 16 (AVX2: 16 ymm registers): 6 x 2 x 8
    # accumulators, the shape of the usual AVX2 SGEMM micro-kernel (untimed here: no such CPU)
    "cpu-narrow": KernelParams(kernel="cpu", name="cpu-narrow", vector_width=8, unit_blocks=2, max_rows=6, panel=192,
                               cache_tiles=32),
    "gpu": KernelParams(kernel="gemm", name="gpu", vector_width=4, tile_rows=64, tile_units=128, group_rows=16,
                        group_units=16, max_kt=16, staged_kt=8, whole_row_tile=True, smooth_outputs=4),
    "tiled": KernelParams(kernel="tiled", name="tiled", vector_width=4, unit_blocks=2, max_rows=4, use_local=True,
                          work_group=64, max_dt=64),
}

#: Fallback chains: the layouts tried in order on a device type until one passes its probe
#: (:mod:`meshsom.probe`); after the last, the NumPy/BLAS backend.
CHAINS = {"cpu": ("cpu", "cpu-narrow", "tiled"), "cpu-narrow": ("cpu-narrow", "tiled"), "gpu": ("gpu", "tiled")}

#: Build options of every kernel.
BUILD_OPTIONS = ["-cl-mad-enable"]


def _cl():
    try:
        import pyopencl as cl
    except ImportError as err:  # pragma: no cover - pyopencl is a dependency
        raise DeviceError(f"pyopencl is not importable ({err}); install pyopencl (and pocl-binary-distribution)") from None
    return cl


def list_devices() -> list[tuple[str, str, object]]:
    """Every OpenCL device: (selector "P:D", "platform / device" name, device)."""
    from meshsom.caches import ensure_user_cache
    from meshsom.pocl_target import retarget

    cl = _cl()
    ensure_user_cache()  # PoCL shows no device where its kernel cache cannot be written
    try:
        platforms = cl.get_platforms()
    except cl.Error:
        return []
    out = []
    for p, platform in enumerate(platforms):
        try:
            devices = platform.get_devices()
        except cl.Error:
            continue
        for d, device in enumerate(devices):
            retarget(device)  # before anything is built on it (PoCL whose LLVM does not know the CPU)
            out.append((f"{p}:{d}", f"{platform.name.strip()} / {device.name.strip()}", device))
    return out


def select_device(selector: str | None = None):
    """The OpenCL device a selector names.

    Parameters
    ----------
    selector : str or None
        ``"P:D"``, ``"P"`` or a name substring; None: ``$PYOPENCL_CTX``, else the first device.

    Raises
    ------
    DeviceError
        No device at all, or none matching the selector (the message lists those found).
    """
    devices = list_devices()
    if not devices:
        raise DeviceError("no OpenCL device found (install an ICD such as pocl-binary-distribution)")
    if selector is None:
        selector = os.environ.get(ENV_SELECTOR) or None
    if selector is None or selector == "":
        return devices[0][2]
    text = str(selector).strip()
    found = "; ".join(f"{s} = {name}" for s, name, _ in devices)
    parts = text.split(":")
    if all(p.isdigit() for p in parts if p) and len(parts) <= 2:
        p = int(parts[0]) if parts[0] else 0
        d = int(parts[1]) if len(parts) > 1 and parts[1] else 0
        for s, _, device in devices:
            if s == f"{p}:{d}":
                return device
        raise DeviceError(f"OpenCL device {text!r} does not exist; devices found: {found}")
    for _, name, device in devices:  # names, and the platform's version ("PoCL", "CUDA")
        if text.lower() in f"{name} {device.platform.version}".lower():
            return device
    raise DeviceError(f"no OpenCL device matches {text!r}; devices found: {found}")


_CONTEXTS: dict[str, object] = {}
_PROGRAMS: "weakref.WeakKeyDictionary" = weakref.WeakKeyDictionary()


def get_context(selector: str | None = None):
    """A context for the selected device, made once per selector and reused."""
    cl = _cl()
    key = str(selector if selector is not None else os.environ.get(ENV_SELECTOR, ""))
    if key not in _CONTEXTS:
        device = select_device(selector)
        try:
            _CONTEXTS[key] = cl.Context([device])
        except cl.Error as err:
            raise DeviceError(f"cannot open an OpenCL context on {device.name.strip()}: {err}") from None
    return _CONTEXTS[key]


def device_name(context) -> str:
    """"platform / device" of a context's first device."""
    device = context.devices[0]
    return f"{device.platform.name.strip()} / {device.name.strip()}"


def kernel_source(kernel: str = "gemm") -> str:
    """Text of a kernel variant's program: ``kernels/bmu_common.cl``, its own ``.cl`` file (see
    :data:`KERNELS`), then ``kernels/epoch_sums.cl`` (:data:`UNIT_SUMS`, :data:`ROW_ERRORS`) and
    ``kernels/batch_update.cl`` (:data:`SMOOTH_AXIS`, :data:`DIVIDE_CODEBOOK`), both built where the
    device has float64."""
    kernels = resources.files("meshsom").joinpath("kernels")
    return "\n".join(kernels.joinpath(name).read_text()
                     for name in ("bmu_common.cl", KERNELS[kernel][0], "epoch_sums.cl", "batch_update.cl"))


def _largest_divisor(D: int, cap: int) -> int:
    for dt in range(min(D, cap), 0, -1):
        if D % dt == 0:
            return dt
    return 1


def kernel_target_cpu(device) -> str | None:
    """The LLVM CPU name PoCL compiles kernels for (:func:`meshsom.pocl_target.kernel_target`:
    the HSTR's, or the one :func:`meshsom.pocl_target.retarget` set); None on other devices.

    LLVM's name for the host can lag the hardware (LLVM 14 calls AMD Zen 4 ``znver3``), and
    kernels get only that CPU's features, whatever vector widths the device reports.
    """
    from meshsom.pocl_target import kernel_target

    return kernel_target(device)


def target_vector_width(cpu_name: str | None, reported_width: int) -> int:
    """Float lanes to compile for: the device's reported width, capped at 8 where the kernel
    target CPU is a known LLVM x86 name without AVX-512 (:data:`NON_AVX512_CPUS`).

    PoCL reports the width from the host's cpuid flags but compiles for LLVM's name of the
    host, which can lack AVX-512 (LLVM 14 on AMD Zen 4: "znver3"); 16 lanes then cost two
    registers each and the "cpu" register block spills. Names in :data:`AVX512_CPUS`, unknown
    names and None (not PoCL, or another architecture) keep the reported width.
    """
    if cpu_name is None:
        return reported_width
    name = cpu_name.strip().lower()
    if name in AVX512_CPUS or name not in NON_AVX512_CPUS:
        return reported_width
    return min(reported_width, 8)


def layout_chain(device) -> tuple[str, ...]:
    """The layouts to try on an OpenCL device, fastest first (:data:`CHAINS`).

    CPUs start with "cpu" where the device prefers 16-float vectors and its kernel target CPU has
    them (:func:`target_vector_width`), else with "cpu-narrow"; other devices with "gpu" (where a
    gemm work-group fits). Each layout is probed (:mod:`meshsom.probe`) before its first use.
    """
    cl = _cl()
    if device.type & cl.device_type.CPU:
        width = target_vector_width(kernel_target_cpu(device), device.preferred_vector_width_float)
        return CHAINS["cpu" if width >= 16 else "cpu-narrow"]
    gemm = DEFAULT_PARAMS["gpu"]
    if (gemm.group_rows * gemm.group_units > device.max_work_group_size
            or gemm_local_bytes(gemm, np.float32) > device.local_mem_size):
        return CHAINS["gpu"][1:]  # the device cannot hold a gemm work-group
    return CHAINS["gpu"]


def layout_params(device, name: str, tuned: bool = True) -> KernelParams:
    """The tiling of layout ``name`` fitted to a device (work-group size and local memory capped by the device's);
    the ``gpu`` layout with the device's tuning where ``meshsom tune`` saved one (:mod:`meshsom.tuning`;
    ``tuned=False``: the default).

    Raises
    ------
    ValueError
        Unknown layout name (the message lists the known ones).
    """
    if name not in DEFAULT_PARAMS:
        raise ValueError(f"unknown kernel layout {name!r}; known layouts: {', '.join(DEFAULT_PARAMS)}")
    params = DEFAULT_PARAMS[name]
    if tuned and name == "gpu":
        from meshsom.tuning import tuned_fields

        params = replace(params, **tuned_fields(device))
    params = replace(params, work_group=min(params.work_group, device.max_work_group_size))
    if params.kernel == "gemm":
        params = replace(params, local_limit=min(params.local_limit, int(device.local_mem_size)))
    return params


def device_params(device) -> KernelParams:
    """Kernel and tiling of the first layout of a device's chain (:func:`layout_chain`)."""
    return layout_params(device, layout_chain(device)[0])


def _max_kt(params: KernelParams, dtype, staged: bool = False) -> int:
    """``max_kt`` (``staged_kt`` for a row tile staged per chunk, where set), halved for float64
    (the local tiles keep their bytes)."""
    cap = params.staged_kt if staged and params.staged_kt else params.max_kt
    return max(1, cap // 2) if np.dtype(dtype) == np.float64 else cap


def _chunk(D: int, cap: int) -> int:
    """KT for a cap: the largest divisor of D not above it when that is at least half of it, else the cap."""
    kt = _largest_divisor(D, cap)
    return kt if 2 * kt >= min(D, cap) else cap


def gemm_kt(D: int, params: KernelParams, dtype=np.float32) -> int:
    """Dimensions per local-memory chunk of the "gemm" kernel (KT, see :class:`KernelParams`)."""
    return _gemm_plan(params, dtype, D)[0]


def _gemm_plan(params: KernelParams, dtype, D: int) -> tuple[int, bool]:
    """(KT, whole row tile) of the "gemm" kernel at D: the whole row tile at the ``max_kt`` chunk
    where it fits ``params.local_limit``, else at the ``staged_kt`` chunk (smaller codebook
    buffers: float32 D = 144 fits 48 KB so), else the row tile staged per ``staged_kt`` chunk."""
    kt, staged = _chunk(D, _max_kt(params, dtype)), _chunk(D, _max_kt(params, dtype, staged=True))
    if params.whole_row_tile:
        for k in (kt, staged):
            if _gemm_bytes(params, dtype, k, D) <= params.local_limit:
                return k, True
    return staged, False


def _gemm_bytes(params: KernelParams, dtype, kt: int, whole_D: int | None) -> int:
    """Local memory of one "gemm" work-group at chunk ``kt``: W's two buffers, the row fold, and X's
    two buffers, or its whole row tile at ``whole_D`` (D padded to whole chunks; its rows not padded,
    kernels/bmu_gpu.cl XSTRIDE)."""
    size = np.dtype(dtype).itemsize
    vw = params.vector_width // 2 if size == 8 and params.vector_width > 2 else params.vector_width
    x = 2 * kt * (params.tile_rows + vw) if whole_D is None else -(-whole_D // kt) * kt * params.tile_rows
    return (2 * kt * (params.tile_units + vw) + x) * size + params.tile_rows * 2 * (size + 4)


def gemm_local_bytes(params: KernelParams, dtype, D: int | None = None) -> int:
    """Local memory of one "gemm" work-group: two buffers of X and W at the largest chunk, the row fold.

    About 33 KB with the GPU default, float32 and float64 alike, under the 48 KB that NVIDIA's
    OpenCL gives a work-group. With ``D``: at that D's chunk, and the whole row tile instead of
    X's two buffers where :func:`gemm_whole_row_tile` says so.
    """
    if D is None:
        return _gemm_bytes(params, dtype, _max_kt(params, dtype), None)
    kt, whole = _gemm_plan(params, dtype, D)
    return _gemm_bytes(params, dtype, kt, D if whole else None)


def gemm_whole_row_tile(params: KernelParams, dtype, D: int) -> bool:
    """Whether the "gemm" kernel stages the whole row tile at this D (XRES): asked for, and it fits
    ``params.local_limit`` beside the codebook's two chunks and the row fold (:func:`_gemm_plan`)."""
    return _gemm_plan(params, dtype, D)[1]


#: Automatic unit splits of the "gemm" kernel: the fixed work of one work-group (gathering its row
#: tile, folding and writing its rows), in unit tiles, in the cost model of :func:`unit_splits`.
SPLIT_OVERHEAD_TILES = 2


def unit_splits(rows: int, unit_tiles: int, params: KernelParams, compute_units: int) -> tuple[int, int]:
    """Ranges of unit tiles for the "gemm" kernel: (S, tiles per range).

    Automatic (``params.unit_splits`` 0): the S of least modelled time, waves x (tiles per range +
    :data:`SPLIT_OVERHEAD_TILES`), where a wave is ``compute_units x groups_per_cu`` work-groups
    (row tiles x S in all): few row tiles (small N) get enough ranges to fill the device, and a
    number that fills its last wave, not 288 work-groups on 264 places (the second wave nearly
    empty, as 3,064 rows had at S = 2); many row tiles get S = 1. Ties: the fewest ranges.

    Parameters
    ----------
    rows : int
        Virtual rows, N * n.
    unit_tiles : int
        Codebook tiles of ``tile_units`` units.
    params : KernelParams
        ``unit_splits`` (0: automatic) and ``groups_per_cu``.
    compute_units : int
        The device's compute units.

    Returns
    -------
    splits : int
        S, at most ``unit_tiles``; none of the ranges is empty.
    per_split : int
        Unit tiles per range (the last range may hold fewer).
    """
    row_tiles = -(-rows // params.tile_rows)
    if params.unit_splits:
        per_split = -(-unit_tiles // max(1, min(params.unit_splits, unit_tiles)))
        return -(-unit_tiles // per_split), per_split
    per_split = -(-unit_tiles // np.arange(1, unit_tiles + 1))  # every distinct range size
    splits = -(-unit_tiles // per_split)
    wave = max(1, compute_units * params.groups_per_cu)
    waves = -(-(row_tiles * splits) // wave)
    best = int(np.argmin(waves * (per_split + SPLIT_OVERHEAD_TILES)))  # the first: fewest ranges
    return int(splits[best]), int(per_split[best])


def default_params(context) -> KernelParams:
    """Kernel and tiling for a context's first device (:func:`device_params`)."""
    return device_params(context.devices[0])


def device_selector(device) -> str:
    """The ``"P:D"`` selector of a device (what a child process opens to reach the same one)."""
    for selector, _, other in list_devices():
        if other == device:
            return selector
    raise DeviceError(f"{device.name.strip()}: not among the OpenCL devices of this process")


def _defines(D: int, n: int, dtype, params: KernelParams) -> dict[str, int | str]:
    double = dtype == np.float64
    vw = params.vector_width // 2 if double and params.vector_width > 2 else params.vector_width
    rs = params.max_rows
    step = rs // math.gcd(rs, n)  # rows per panel come in steps that fill whole register blocks
    staged = n * D * (8 if double else 4)  # bytes of one row's varied vectors
    # the CPU kernel stages at least one step of rows in private memory (the thread's stack);
    # where even that exceeds panel_bytes (D in the thousands, ring levels >= 6) the tiled
    # kernel, which tiles D through local memory, runs with the same vector tiling
    common = {
        **injected_defines(params.name),
        "REAL": "double" if double else "float",
        "IREAL": "long" if double else "int",
        "VW": vw,
        "UB": params.unit_blocks,
        "D": D,
        "NV": n,
        "EPOCH": int(params.epoch_kernels),
        "SMOOTH_RJ": params.smooth_outputs,
    }
    if params.kernel == "cpu" and step * staged <= params.panel_bytes:
        rows = max(step, min(params.panel // n, params.panel_bytes // staged) // step * step)
        return {"KERNEL": "cpu", **common, "P": rows, "RS": rs, "UBLK": params.cache_tiles}
    if params.kernel == "gemm":
        kt = gemm_kt(D, params, dtype)
        return {"KERNEL": "gemm", **common, "TM": params.tile_rows, "TN": params.tile_units,
                "XRES": int(gemm_whole_row_tile(params, dtype, D)),
                "WGM": params.group_rows, "WGN": params.group_units, "KT": kt, "DP": -(-D // kt) * kt,
                "US": params.unit_splits, "GPC": params.groups_per_cu, "PF": int(params.prefetch),
                "MAXREG": params.max_registers}
    return {
        "KERNEL": "tiled", **common,
        "DT": _largest_divisor(D, params.max_dt) if params.use_local else D,
        "RX": max(1, params.max_rows // n),
        "USE_LOCAL": int(params.use_local),
        "WG": params.work_group,
    }


def probe_layout(context, name: str, D: int, n: int, dtype=np.float32, epoch_kernels: bool = True):
    """The probe verdict (:func:`meshsom.probe.check`) of layout ``name`` for a workload, building nothing here.

    Parameters
    ----------
    context : pyopencl.Context
    name : str
        A key of :data:`DEFAULT_PARAMS`.
    D, n : int
        Dimension and variations.
    dtype : numpy dtype
    epoch_kernels : bool
        With the epoch's kernels (:attr:`KernelParams.epoch_kernels`).

    Returns
    -------
    meshsom.probe.Verdict
    """
    from meshsom.probe import check

    device = context.devices[0]
    defines = _defines(int(D), int(n), np.dtype(dtype), replace(layout_params(device, name), epoch_kernels=epoch_kernels))
    return check(device, device_selector(device), defines, kernel_source(defines["KERNEL"]), BUILD_OPTIONS, layout=name)


class KernelLayoutError(DeviceError):
    """A kernel layout failed its probe or its launch on a device.

    Attributes
    ----------
    layout : str
    device : str
    reason : str
        One line: what failed, with the compiler's first error line.
    cached : bool
        The verdict came from the disk cache (the process that probed it has reported it).
    """

    def __init__(self, layout: str, device: str, reason: str, cached: bool = False):
        self.layout, self.device, self.reason, self.cached = layout, device, reason, cached
        super().__init__(f"BMUofN kernel layout {layout!r} does not work on {device}: {reason}")

    def __reduce__(self):  # picklable across Dask: plain strings only
        return (type(self), (self.layout, self.device, self.reason, self.cached))


def has_fp64(context) -> bool:
    """Whether a context's first device computes in float64 (cl_khr_fp64)."""
    return "cl_khr_fp64" in context.devices[0].extensions


def get_kernel(context, defines: dict, function: str | None = None, guard: bool = True, layout: str = "custom"):
    """A kernel of the program ``defines["KERNEL"]`` names, built for ``defines`` once per context.

    Parameters
    ----------
    context : pyopencl.Context
    defines : dict
        From :func:`_defines`.
    function : str or None
        The kernel function; None: the variant's main one (:data:`KERNELS`).
    guard : bool
        Build only what passed its probe (:func:`meshsom.probe.check`, in a child process, cached
        on disk); the probe child itself builds with ``guard=False``.
    layout : str
        Layout name for messages.

    Raises
    ------
    KernelLayoutError
        The probe rejected the build, or the build failed here.
    """
    cl = _cl()
    cache = _PROGRAMS.setdefault(context, {})
    key = _program_key(context, defines)
    source, main = KERNELS[defines["KERNEL"]]
    if key not in cache:
        text = kernel_source(defines["KERNEL"])
        # the key's last items: kernels/epoch_sums.cl and batch_update.cl are built where the device has
        # float64 (and the layout asks for them: EPOCH)
        options = build_options(context, defines)
        device = context.devices[0]
        if guard:
            from meshsom.probe import check

            verdict = check(device, device_selector(device), defines, text, BUILD_OPTIONS, layout=layout)
            if not verdict.ok:
                raise KernelLayoutError(layout, device_name(context), verdict.reason, verdict.cached)
        log.info("building BMUofN kernel layout %r on %s (D=%s, n=%s)", layout, device_name(context),
                 defines["D"], defines["NV"])
        try:
            cache[key] = (cl.Program(context, text).build(options=options), {})
        except cl.Error as err:
            from meshsom.probe import first_error_line

            raise KernelLayoutError(layout, device_name(context),
                                    f"kernels/{source} failed to build: {first_error_line(str(err))}") from None
    program, kernels = cache[key]
    function = function or main
    if function not in kernels:
        try:
            kernels[function] = cl.Kernel(program, function)
        except cl.Error as err:
            raise KernelLayoutError(layout, device_name(context),
                                    f"kernel {function} is not in the program of kernels/{source} ({err})") from None
    return kernels[function]


def _program_key(context, defines: dict) -> tuple:
    """What a built program depends on: the defines, whether the epoch's kernels are in it, the component."""
    return tuple(sorted(defines.items())) + (("EPOCH_SUMS", int(has_fp64(context) and bool(defines.get("EPOCH", 1)))),
                                             ("COMPONENT", COMPONENT))


def build_options(context, defines: dict) -> list[str]:
    """The build options of the program :func:`get_kernel` builds for ``defines`` on a context's device."""
    cl = _cl()
    options = [f"-D{k}={v}" for k, v in _program_key(context, defines) if k != "KERNEL"] + BUILD_OPTIONS
    device = context.devices[0]
    options += target_options(device)
    if defines["KERNEL"] == "gemm":  # see kernels/bmu_gpu.cl: unrolled epilogue on GPUs only, EXACT
        options.append(f"-DUNROLL_EPILOGUE={int(not device.type & cl.device_type.CPU)}")
        options.append(f"-DEXACT={'double' if has_fp64(context) else defines['REAL']}")
        options += register_cap_options(device, defines.get("MAXREG", 0))
    return options


def target_options(device) -> list[str]:
    """A define naming the kernel target CPU where :mod:`meshsom.pocl_target` set it: PoCL keys its
    kernel cache by source and options, not by that CPU, so binaries built for another stay apart."""
    from meshsom.pocl_target import retargeted

    name = retargeted(device)
    return [f"-DMESHSOM_TARGET_CPU={''.join(c if c.isalnum() else '_' for c in name)}"] if name else []


def register_cap_options(device, registers: int) -> list[str]:
    """The build option capping registers per work-item, where the driver takes it (NVIDIA's
    ``cl_nv_compiler_options``); none for a cap of 0 or another driver."""
    if registers and "cl_nv_compiler_options" in device.extensions:
        return [f"-cl-nv-maxrregcount={int(registers)}"]
    return []


def _run_gemm(cl, context, queue, defines, kernel, bufs, outs, N, n, M, MP):
    """Enqueue the "gemm" kernel over (unit splits, row tiles) and its reduction kernel.

    ``bufs``: X, W (M, D), wnorm (MP,), index, sign; ``outs``: unit, variation, dist2, second.
    """
    rows = N * n
    params = KernelParams(kernel="gemm", vector_width=defines["VW"], tile_rows=defines["TM"], tile_units=defines["TN"],
                          group_rows=defines["WGM"], group_units=defines["WGN"], unit_splits=defines["US"],
                          groups_per_cu=defines["GPC"])
    splits, per_split = unit_splits(rows, MP // defines["TN"], params, context.devices[0].max_compute_units)
    itemsize = 8 if defines["REAL"] == "double" else 4
    parts = [scratch(context, rows * splits * size) for size in (itemsize, 4, itemsize, 4)]
    row_tiles = -(-rows // defines["TM"])
    group = min(REDUCE_GROUP, context.devices[0].max_work_group_size)
    # the codebook zero-padded to (MP, DP) on the device: the kernel's staging reads it with no bounds
    padded = MP * defines["DP"]
    wp = scratch(context, padded * itemsize)
    pad = get_kernel(context, defines, GEMM_PAD, guard=False)  # one program: built with the main kernel
    pad(queue, (-(-padded // group) * group,), (group,), bufs[1], np.int32(M), wp, np.int32(MP))
    kernel(queue, (splits * defines["WGN"], row_tiles * defines["WGM"]), (defines["WGN"], defines["WGM"]),
           bufs[0], np.int32(N), wp, bufs[2], np.int32(MP), bufs[3], bufs[4], np.int32(per_split), *parts)
    reduce = get_kernel(context, defines, GEMM_REDUCE, guard=False)
    reduce(queue, (-(-N // group) * group,), (group,),
           bufs[0], np.int32(N), bufs[1], np.int32(MP), bufs[3], bufs[4], np.int32(splits), *parts, *outs)


#: Share of a device's global memory that the resident row buffers of one context may hold; the
#: rest is left to the codebook, the outputs and the "gemm" partial results of each call.
RESIDENT_MEMORY_FRACTION = 0.5
#: The resident budget in bytes, overriding the fraction (None: the fraction; tests set it small).
RESIDENT_BYTES: int | None = None


def upload(context, host: np.ndarray):
    """A read-only device buffer holding a copy of ``host`` (every host-to-device copy of a search goes here).

    Parameters
    ----------
    host : ndarray
        C-contiguous.
    """
    cl = _cl()
    return cl.Buffer(context, cl.mem_flags.READ_ONLY | cl.mem_flags.COPY_HOST_PTR, hostbuf=host)


def immutable(X: np.ndarray) -> bool:
    """Whether X is read-only and so is every array it views (its values cannot change through numpy).

    A read-only view of a writable array changes with it, so it is not immutable; nor is an
    array over a writable buffer of another kind (a ``bytearray``). One over a read-only buffer
    (``bytes``, a read-only ``mmap``) is.
    """
    a = X
    while isinstance(a, np.ndarray):
        if a.flags.writeable:
            return False
        a = a.base
    if a is None:
        return True
    try:
        return memoryview(a).readonly
    except TypeError:  # not a buffer: nothing known about who else writes to it
        return False


def _table_key(index: np.ndarray, sign: np.ndarray) -> tuple:
    """A variation table's identity by value: (shape, sign dtype, index bytes, sign bytes)."""
    return index.shape, sign.dtype.str, index.tobytes(), sign.tobytes()


@dataclass
class _Resident:
    """One resident row array: a weak reference to it, its device copy and its tables' copies."""

    ref: weakref.ref
    shape: tuple
    dtype: np.dtype
    rows: object
    tables: dict
    nbytes: int


class ResidentRows:
    """Device copies of read-only row arrays on one context, least recently used out first.

    Keyed by ``id(X)``; an entry matches only while its weak reference still returns X itself,
    so an array freed and a new one at the same address never share a copy (the entry of a
    freed array is dropped at the next call). Each entry also holds the int32 index and the
    sign tables searched with those rows, keyed by value.

    Parameters
    ----------
    budget : int
        Most bytes of device copies held; an array larger than this is never held.

    Attributes
    ----------
    hits, misses, evictions : int
        Searches that found their rows on the device, that copied them there (and kept them),
        and entries dropped for the budget.
    """

    def __init__(self, budget: int):
        self.budget = int(budget)
        self.hits = self.misses = self.evictions = 0
        self._entries: "OrderedDict[int, _Resident]" = OrderedDict()
        self._dead: list = []  # ids whose arrays were freed: dropped at the next call
        self._lock = threading.Lock()

    @property
    def nbytes(self) -> int:
        """Bytes of device copies held now."""
        with self._lock:
            self._purge()
            return sum(e.nbytes for e in self._entries.values())

    def __len__(self) -> int:
        with self._lock:
            self._purge()
            return len(self._entries)

    def __contains__(self, X) -> bool:
        with self._lock:
            self._purge()
            entry = self._entries.get(id(X))
            return entry is not None and entry.ref() is X

    def _purge(self) -> None:
        while self._dead:
            key, ref = self._dead.pop()
            entry = self._entries.get(key)
            if entry is not None and entry.ref is ref:
                del self._entries[key]

    def discard(self, X) -> None:
        """Drop X's device copy, if held."""
        with self._lock:
            entry = self._entries.get(id(X))
            if entry is not None and entry.ref() is X:
                del self._entries[id(X)]

    def buffers(self, context, X: np.ndarray, index32: np.ndarray, sign: np.ndarray) -> tuple:
        """Device buffers of rows and tables: held ones where X is resident, else copied (and held).

        Parameters
        ----------
        X : (N, D) float32 or float64
            C-contiguous; held only where :func:`immutable`.
        index32 : (n, D) int32
        sign : (n, D) X's dtype

        Returns
        -------
        rows, index, sign : pyopencl.Buffer
        """
        if not immutable(X):
            return upload(context, X), upload(context, index32), upload(context, sign)
        table = _table_key(index32, sign)
        with self._lock:
            self._purge()
            entry = self._entries.get(id(X))
            if entry is not None and (entry.ref() is not X or entry.shape != X.shape or entry.dtype != X.dtype):
                del self._entries[id(X)]  # a freed array's entry, or X was reshaped in place
                entry = None
            if entry is not None:
                self._entries.move_to_end(id(X))
                self.hits += 1
                if table in entry.tables:
                    return (entry.rows, *entry.tables[table])
        if entry is None:
            if X.nbytes > self.budget:
                return upload(context, X), upload(context, index32), upload(context, sign)
            rows = upload(context, X)
        else:
            rows = entry.rows
        tables = (upload(context, index32), upload(context, sign))
        with self._lock:
            if entry is None:
                # the callback may run inside any call (garbage collection): it only notes the id
                ref = weakref.ref(X, lambda r, key=id(X), dead=self._dead: dead.append((key, r)))
                entry = _Resident(ref, X.shape, X.dtype, rows, {}, X.nbytes)
                self._entries[id(X)] = entry
                self.misses += 1
            entry.tables[table] = tables
            entry.nbytes += index32.nbytes + sign.nbytes
            self._entries.move_to_end(id(X))
            while sum(e.nbytes for e in self._entries.values()) > self.budget and len(self._entries) > 1:
                self._entries.popitem(last=False)
                self.evictions += 1
        return (rows, *tables)


_RESIDENT: "weakref.WeakKeyDictionary" = weakref.WeakKeyDictionary()


def resident_budget(context) -> int:
    """Bytes the resident rows of a context may hold: :data:`RESIDENT_BYTES`, else
    :data:`RESIDENT_MEMORY_FRACTION` of its first device's global memory."""
    if RESIDENT_BYTES is not None:
        return int(RESIDENT_BYTES)
    return int(RESIDENT_MEMORY_FRACTION * context.devices[0].global_mem_size)


def resident_rows(context) -> ResidentRows:
    """The :class:`ResidentRows` of a context (made on first use, with :func:`resident_budget`)."""
    if context not in _RESIDENT:
        _RESIDENT[context] = ResidentRows(resident_budget(context))
    return _RESIDENT[context]


class ResidentCodebooks:
    """Device copies of the codebooks an update on the device made, on one context (the newest
    :data:`CODEBOOKS_KEPT`), so that the next search reads the copy instead of sending W up again.

    Keyed by the array's identity through a weak reference, as :class:`ResidentRows`; only
    :func:`immutable` arrays are held (the update returns its codebook read-only).

    Attributes
    ----------
    hits : int
        Searches (and error passes) that found their codebook on the device.
    """

    def __init__(self, keep: int = CODEBOOKS_KEPT):
        self.keep = int(keep)
        self.hits = 0
        self._entries: "OrderedDict[int, tuple]" = OrderedDict()
        self._lock = threading.Lock()

    def __contains__(self, W) -> bool:
        with self._lock:
            entry = self._entries.get(id(W))
            return entry is not None and entry[0]() is W

    def add(self, W: np.ndarray, buffer) -> None:
        """Hold ``buffer`` as the device copy of the read-only codebook W."""
        if not immutable(W):
            raise ValueError("only a read-only codebook can stay on the device; received a writable array")
        with self._lock:
            self._entries[id(W)] = (weakref.ref(W), buffer, W.shape, W.dtype)
            self._entries.move_to_end(id(W))
            while len(self._entries) > self.keep:
                self._entries.popitem(last=False)

    def buffer(self, context, W: np.ndarray):
        """W's device copy where it is held, else a fresh copy (:func:`upload`)."""
        with self._lock:
            entry = self._entries.get(id(W))
            if entry is not None and entry[0]() is W and entry[2:] == (W.shape, W.dtype):
                self.hits += 1
                return entry[1]
        return upload(context, np.ascontiguousarray(W))


_CODEBOOKS: "weakref.WeakKeyDictionary" = weakref.WeakKeyDictionary()


def resident_codebooks(context) -> ResidentCodebooks:
    """The :class:`ResidentCodebooks` of a context (made on first use)."""
    if context not in _CODEBOOKS:
        _CODEBOOKS[context] = ResidentCodebooks()
    return _CODEBOOKS[context]


@dataclass(frozen=True)
class DeviceArray:
    """An array held in a device buffer: an epoch's per-unit sums kept next to the rows, for the
    update on the device (:func:`batch_update_opencl`). ``np.asarray`` (or :meth:`get`) copies it
    to the host.

    Attributes
    ----------
    buffer : pyopencl.Buffer
    shape : tuple
    dtype : numpy dtype
    context : pyopencl.Context
    defines : dict
        The program that made it (:func:`_defines`): the update runs in the same program.
    layout : str
        That program's layout name.
    """

    buffer: object
    shape: tuple
    dtype: np.dtype
    context: object
    defines: dict
    layout: str

    def get(self) -> np.ndarray:
        """A host copy.

        Raises
        ------
        DeviceError
            The copy failed (a lost device), as one readable line.
        """
        cl = _cl()
        host = np.empty(self.shape, self.dtype)
        try:
            cl.enqueue_copy(_queue(self.context), host, self.buffer)
        except cl.Error as err:
            raise DeviceError(f"{device_name(self.context)}: copying {self.shape} sums to the host failed ({err})") from None
        return host

    def __array__(self, dtype=None, copy=None):
        host = self.get()
        return host if dtype is None else host.astype(dtype)


def row_buffers(context, X: np.ndarray, index: np.ndarray, sign: np.ndarray) -> tuple:
    """Device buffers of X, the int32 index and the sign table (see :meth:`ResidentRows.buffers`).

    Parameters
    ----------
    X : (N, D) float32 or float64
    index : (n, D) integer
    sign : (n, D)

    Returns
    -------
    rows, index, sign : pyopencl.Buffer
    """
    return resident_rows(context).buffers(context, np.ascontiguousarray(X), np.ascontiguousarray(index, np.int32),
                                          np.ascontiguousarray(sign, X.dtype))


def launch(context, queue, kernel, X, W, index, sign, defines: dict) -> tuple[np.ndarray, ...]:
    """Run a built kernel on validated arrays: the raw outputs, int32/REAL.

    Parameters
    ----------
    X : (N, D), W : (M, D), index : (n, D) int64, sign : (n, D)
        As :func:`meshsom.bmu_numpy.validate` returns them (same dtype for X, W and sign). A
        read-only X (:func:`immutable`) stays resident on the device with its tables
        (:func:`row_buffers`); W's norms go up every call, and W too unless the "gemm" layout
        finds it resident (:class:`ResidentCodebooks`).

    Returns
    -------
    unit, variation : (N,) int32
    dist2 : (N,) REAL or float64
        As the kernel computed it (``||x_v||^2 + ||w||^2 - 2 x_v.w``); the "gemm" layout recomputes
        the winners' distances directly, in float64 where the device has it.
    second : (N,) int32

    Raises
    ------
    DeviceError
        An OpenCL error (out of resources, a lost device ...), as one readable line.
    """
    cl = _cl()
    N, D = X.shape
    M = len(W)
    n = len(index)
    tile = defines["TN"] if defines["KERNEL"] == "gemm" else defines["VW"] * defines["UB"]
    MP = -(-M // tile) * tile
    wnorm = np.full(MP, np.inf, X.dtype)
    wnorm[:M] = fma_norms(W)
    if defines["KERNEL"] == "gemm":
        WT = W  # read as it is: the kernel zero-pads its local tiles (no host transpose, kernels/bmu_gpu.cl)
    elif defines["KERNEL"] == "cpu":
        # tiled codebook (MP / tile, D, tile): one tile's D x tile block is contiguous
        padded = np.zeros((MP, D), X.dtype)
        padded[:M] = W
        WT = np.ascontiguousarray(padded.reshape(MP // tile, tile, D).transpose(0, 2, 1))
        wg = 1
        global_size = -(-N // defines["P"])
    else:
        WT = np.zeros((D, MP), X.dtype)
        WT[:, :M] = W.T
        items = -(-N // defines["RX"])
        wg = defines["WG"]
        global_size = -(-items // wg) * wg
    unit = np.empty(N, np.int32)
    variation = np.empty(N, np.int32)
    dist2 = np.empty(N, np.float64 if defines["KERNEL"] == "gemm" and has_fp64(context) else X.dtype)
    second = np.empty(N, np.int32)
    try:
        xbuf, ibuf, sbuf = row_buffers(context, X, index, sign)
        # gemm reads W itself: a codebook an update on the device made is already there
        wbuf = resident_codebooks(context).buffer(context, W) if WT is W else upload(context, WT)
        bufs = [xbuf, wbuf, upload(context, wnorm), ibuf, sbuf]
        outs = [scratch(context, a.nbytes) for a in (unit, variation, dist2, second)]
        if defines["KERNEL"] == "gemm":
            _run_gemm(cl, context, queue, defines, kernel, bufs, outs, N, n, M, MP)
        else:
            kernel(queue, (global_size,), (wg,),
                   bufs[0], np.int32(N), bufs[1], bufs[2], np.int32(MP), bufs[3], bufs[4], *outs)
        for host, buf in zip((unit, variation, dist2, second), outs):
            cl.enqueue_copy(queue, host, buf, is_blocking=False)  # one wait for all four
        queue.finish()
    except cl.Error as err:
        raise _launch_failed(context, X, "BMUofN kernel launch", err) from None
    return unit, variation, dist2, second


def _launch_failed(context, X, what: str, err) -> DeviceError:
    """The error of a failed launch on rows X, as one readable line (pyopencl's error records do not
    pickle); X's resident copy is dropped, so that a later try copies the rows afresh (None: no rows)."""
    if X is not None:
        resident_rows(context).discard(X)
    first = str(err).splitlines()[0] if str(err) else type(err).__name__
    return DeviceError(f"{device_name(context)}: {what} failed ({type(err).__name__}: {first})")


def bmu_opencl(X, W, index=None, sign=None, context=None, device: str | None = None,
               params: KernelParams | None = None, queue=None) -> BMUResult:
    """BMUofN with the fused OpenCL kernel; same signature and answers as :func:`bmu_numpy`.

    Parameters
    ----------
    X : (N, D) float32 or float64
    W : (M, D) float32 or float64
    index : (n, D) int64 or None
    sign : (n, D) float32 or None
    context : pyopencl.Context or None
        None: :func:`get_context` of ``device``.
    device : str or None
        Device selector when no context is given.
    params : KernelParams or None
        Tiling; None: :data:`DEFAULT_PARAMS` of the device type.
    queue : pyopencl.CommandQueue or None

    Returns
    -------
    BMUResult
        ``dist2`` recomputed directly in float64 for the winners, as the NumPy backend does
        (the "gemm" layout does it on the device where the device has float64: on the host it
        costs more than the whole search at a million rows).

    Raises
    ------
    DeviceError
        No device, or the kernel does not build.
    """
    X, W, index, sign = validate(X, W, index, sign)
    context = context or get_context(device)
    params = params or default_params(context)
    N, D = X.shape
    if N == 0:
        empty = np.zeros(0, np.int64)
        return BMUResult(empty, empty, np.zeros(0), empty)
    defines = _defines(D, len(index), X.dtype, params)
    kernel = get_kernel(context, defines, layout=params.name)
    queue = queue or _queue(context)
    unit, variation, dist2, second = launch(context, queue, kernel, X, W, index, sign, defines)
    unit = unit.astype(np.int64)
    variation = variation.astype(np.int64)
    if dist2.dtype != np.float64:  # the gemm layout computes the winners' dist2 in float64 where it can
        dist2 = exact_dist2(X, W, index, sign, unit, variation)
    return BMUResult(unit, variation, dist2, second.astype(np.int64))


def uniform_block_rows(blocks, N: int) -> int | None:
    """The rows per block where ``blocks`` are :func:`meshsom.som.row_blocks` of N rows (every block
    that long but the last; None: one block of all rows); None where they are anything else."""
    if blocks is None:
        return N if N else None
    if not N or not len(blocks):
        return None
    size = int(blocks[0][1]) - int(blocks[0][0])
    expected = [(a, min(N, a + size)) for a in range(0, N, size)] if size > 0 else None
    return size if expected == [(int(a), int(b)) for a, b in blocks] else None


def device_unit_order(context, queue, defines: dict, unit: np.ndarray, M: int, blocks=None, layout: str = "custom"):
    """The stable order of rows by (block, unit) of :func:`meshsom.bmu_numpy.unit_order`, made on the
    device (``kernels/epoch_sums.cl``: counts, a scan, a stable scatter per block), so that the host
    sorts nothing and sends up only the units.

    Parameters
    ----------
    unit : (N,) int
        Units in 0..M-1.
    blocks : list of (start, stop) or None
        As :func:`meshsom.bmu_numpy.unit_order`; uniform blocks only (:func:`uniform_block_rows`).

    Returns
    -------
    (order, offsets, B, counts) or None
        Device buffers of ``order`` (N,) and ``offsets`` (B * M + 1,) int32, the number of blocks and
        the (M,) float64 counts per unit; None where the blocks are not uniform or the device's
        work-groups are smaller than :data:`ORDER_GROUP` (the host's order then).
    """
    cl = _cl()
    N = len(unit)
    size = uniform_block_rows(blocks, N)
    if size is None or context.devices[0].max_work_group_size < ORDER_GROUP:
        return None
    B = -(-N // size)
    counts_k, scan_k, order_k, totals_k = (get_kernel(context, defines, name, layout=layout)
                                           for name in (UNIT_COUNTS, EXCLUSIVE_SCAN, STABLE_ORDER, UNIT_TOTALS))
    ubuf = upload(context, np.ascontiguousarray(unit, np.int32))
    per = scratch(context, B * M * 4)
    cl.enqueue_fill_buffer(queue, per, np.int32(0), 0, B * M * 4)
    group = min(SUMS_GROUP, context.devices[0].max_work_group_size)
    counts_k(queue, (-(-N // group) * group,), (group,), ubuf, np.int32(N), np.int32(size), np.int32(M), per)
    offsets = scratch(context, (B * M + 1) * 4)
    scan_k(queue, (ORDER_GROUP,), (ORDER_GROUP,), per, np.int32(B * M), offsets)
    cursor = scratch(context, B * M * 4)
    cl.enqueue_copy(queue, cursor, offsets, byte_count=B * M * 4)
    order = scratch(context, max(N, 1) * 4)
    order_k(queue, (B * ORDER_GROUP,), (ORDER_GROUP,), ubuf, np.int32(N), np.int32(size), np.int32(M), cursor, order)
    totals = scratch(context, M * 4)
    totals_k(queue, (-(-M // group) * group,), (group,), offsets, np.int32(B), np.int32(M), totals)
    counts = np.empty(M, np.int32)
    cl.enqueue_copy(queue, counts, totals)
    return order, offsets, B, counts.astype(np.float64)


def unit_order_opencl(unit, M: int, blocks=None, context=None, device: str | None = None,
                      params: KernelParams | None = None, D: int = 1, n: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """:func:`device_unit_order` brought to the host: the same (order, offsets) as
    :func:`meshsom.bmu_numpy.unit_order` (int64), for checks; the host's where the device's does not apply.

    ``D`` and ``n`` pick the program (any workload's program holds the order kernels).
    """
    cl = _cl()
    context = context or get_context(device)
    params = params or default_params(context)
    if not has_fp64(context):
        raise DeviceError(f"{device_name(context)} has no float64 (cl_khr_fp64): the epoch's kernels are not built")
    queue = _queue(context)
    made = device_unit_order(context, queue, _defines(D, n, np.dtype(np.float32), params), np.asarray(unit), M, blocks,
                             params.name)
    if made is None:
        return unit_order(unit, M, blocks)
    order_buf, offsets_buf, B, _ = made
    order = np.empty(max(len(unit), 1), np.int32)
    offsets = np.empty(B * M + 1, np.int32)
    cl.enqueue_copy(queue, order, order_buf)
    cl.enqueue_copy(queue, offsets, offsets_buf)
    return order[:len(unit)].astype(np.int64), offsets.astype(np.int64)


def launch_unit_sums(context, queue, defines: dict, X, index, sign, unit, variation, M: int,
                     blocks=None, init=None, keep: bool = False, layout: str = "custom",
                     order_on_device: bool | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Run the per-unit sums kernel of the program ``defines`` on validated arrays (the rows resident
    where X is read-only).

    Takes and returns what :func:`meshsom.bmu_numpy.unit_sums` does, with X, index and sign as
    :func:`meshsom.bmu_numpy.validate` returns them; the (M, D) float64 sums and (M,) counts are
    the host's, bit for bit. ``init`` may be a :class:`DeviceArray` (the sums of an earlier pass kept
    on the device).

    Parameters
    ----------
    order_on_device : bool or None
        Make the order of the rows by unit on the device (:func:`device_unit_order`, uniform blocks
        only) rather than on the host; None: on GPUs (on a CPU device the host's radix sort is
        faster: 19-29 ms against 48 ms at 1e6 rows on PoCL here).
    keep : bool
        Keep the sums on the device and return them as a :class:`DeviceArray` (for
        :func:`batch_update_opencl`); False: copy them to the host.
    layout : str
        The program's layout name (messages, and the DeviceArray).

    Raises
    ------
    ValueError
        A unit outside 0..M-1.
    DeviceError
        An OpenCL error, as one readable line.
    """
    cl = _cl()
    N, D = X.shape
    unit = np.asarray(unit)
    if N and (unit.min() < 0 or unit.max() >= M):
        raise ValueError(f"units must lie in 0..{M - 1}, received {unit.min()}..{unit.max()}")
    on_device = isinstance(init, DeviceArray)
    if not on_device and init is not None:
        init = np.ascontiguousarray(init, np.float64)
    if not N and not keep:
        counts = np.zeros(M)
        return (np.zeros((M, D)) if init is None else np.array(init, np.float64)), counts
    try:
        if order_on_device is None:
            order_on_device = not context.devices[0].type & cl.device_type.CPU
        made = device_unit_order(context, queue, defines, unit, M, blocks, layout) if N and order_on_device else None
        if made is None:
            order, offsets = unit_order(unit, M, blocks)
            counts = np.diff(offsets).reshape(-1, M).sum(axis=0).astype(np.float64)
            order_buf, offsets_buf = upload(context, order.astype(np.int32)), upload(context, offsets.astype(np.int32))
            B = (len(offsets) - 1) // M
        else:
            order_buf, offsets_buf, B, counts = made
        # no earlier passes: the kernel starts from 0 (no (M, D) zeros sent up)
        ibuf = init.buffer if on_device else None if init is None else upload(context, init)
        if not N:
            out = ibuf if ibuf is not None else upload(context, np.zeros((M, D)))
        else:
            xbuf, xibuf, sbuf = row_buffers(context, X, index, sign)
            out = scratch(context, M * D * 8)
            group = min(SUMS_GROUP, context.devices[0].max_work_group_size)
            kernel = get_kernel(context, defines, UNIT_SUMS, layout=layout)
            kernel(queue, (-(-M * D // group) * group,), (group,), xbuf, xibuf, sbuf,
                   upload(context, np.ascontiguousarray(variation, np.int32)), order_buf, offsets_buf, np.int32(M),
                   np.int32(B), out if ibuf is None else ibuf, np.int32(ibuf is not None), out)
        if keep:
            queue.finish()
            return DeviceArray(out, (M, D), np.dtype(np.float64), context, defines, layout), counts
        sums = np.empty((M, D), np.float64)
        cl.enqueue_copy(queue, sums, out)
        queue.finish()
    except cl.Error as err:
        raise _launch_failed(context, X, "per-unit sums kernel", err) from None
    return sums, counts


def unit_sums_opencl(X, W, bmu: BMUResult, index=None, sign=None, context=None, device: str | None = None,
                     params: KernelParams | None = None, queue=None, blocks=None,
                     init=None, keep: bool = False, order_on_device: bool | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Per-unit sums and counts of a search's winners on the device: same bits as
    :func:`meshsom.bmu_numpy.unit_sums`.

    The kernel is part of the layout's program (:func:`kernel_source`), so it is built, and
    probed, with the search; where X is read-only its resident device copy is read
    (:class:`ResidentRows`), so a training epoch sends the rows to the device once and brings
    back only the (M, D) sums (or, with ``keep``, nothing: the update runs on the device).

    Parameters
    ----------
    X : (N, D) float32 or float64
    W : (M, D)
    bmu : BMUResult
        The winners of X against W (:func:`bmu_opencl` or any backend).
    index, sign : (n, D) or None
        The variation table the winners were found with.
    context, device, params, queue
        As :func:`bmu_opencl`.
    blocks : list of (start, stop) or None
        Row blocks whose sums are added in order (one launch for all); None: one block.
    init : (M, D) float64, DeviceArray or None
        Running sums of earlier passes the blocks are added to (None: zeros).
    keep : bool
        Leave the sums on the device: ``sums`` is then a :class:`DeviceArray`.
    order_on_device : bool or None
        Where the order of the rows by unit is made (:func:`launch_unit_sums`; None: on GPUs).

    Returns
    -------
    sums : (M, D) float64 (or DeviceArray)
    counts : (M,) float64

    Raises
    ------
    DeviceError
        The device has no float64, or the build or the kernel failed.
    """
    X, W, index, sign, context, _, defines, layout = _epoch_kernel(UNIT_SUMS, X, W, index, sign, context, device,
                                                                    params)
    return launch_unit_sums(context, queue or _queue(context), defines, X, index, sign, bmu.unit, bmu.variation, len(W),
                            blocks, init, keep=keep, layout=layout, order_on_device=order_on_device)


def launch_row_errors(context, queue, kernel, X, W, index, sign, unit, variation) -> tuple[np.ndarray, np.ndarray]:
    """Run the built per-row errors kernel on validated arrays (the rows resident where X is read-only).

    Takes and returns what :func:`meshsom.metrics.row_errors` does (with the program's
    :data:`meshsom.metrics.COMPONENT`), the same to rounding.

    Raises
    ------
    DeviceError
        An OpenCL error, as one readable line.
    """
    cl = _cl()
    N = len(X)
    q = np.empty(N, np.float64)
    qc = np.empty(N, np.float64)
    if N:
        try:
            xbuf, ibuf, sbuf = row_buffers(context, X, index, sign)
            outs = [scratch(context, a.nbytes) for a in (q, qc)]
            group = min(SUMS_GROUP, context.devices[0].max_work_group_size)
            kernel(queue, (-(-N // group) * group,), (group,), xbuf, np.int32(N), ibuf, sbuf,
                   upload(context, np.ascontiguousarray(variation, np.int32)),
                   upload(context, np.ascontiguousarray(unit, np.int32)),
                   resident_codebooks(context).buffer(context, W), *outs)
            for host, buf in zip((q, qc), outs):
                cl.enqueue_copy(queue, host, buf)
            queue.finish()
        except cl.Error as err:
            raise _launch_failed(context, X, "per-row errors kernel", err) from None
    return q, qc


def _epoch_kernel(function, X, W, index, sign, context, device, params):
    """Validated arrays, context, a built kernel of ``kernels/epoch_sums.cl`` (see :func:`unit_sums_opencl`),
    the program's defines and its layout name."""
    X, W, index, sign = validate(X, W, index, sign)
    context = context or get_context(device)
    if not has_fp64(context):
        raise DeviceError(f"{device_name(context)} has no float64 (cl_khr_fp64): per-unit sums and errors "
                          f"are taken on the host")
    params = params or default_params(context)
    defines = _defines(X.shape[1], len(index), X.dtype, params)
    return X, W, index, sign, context, get_kernel(context, defines, function, layout=params.name), defines, params.name


def row_errors_opencl(X, W, bmu: BMUResult, index=None, sign=None, context=None, device: str | None = None,
                      params: KernelParams | None = None, queue=None) -> tuple[np.ndarray, np.ndarray]:
    """Per-row Q- and QC-distances of a search's winners on the device: :func:`meshsom.metrics.row_errors`
    (component :data:`meshsom.metrics.COMPONENT`), the same to rounding.

    Parameters and errors as :func:`unit_sums_opencl`.

    Returns
    -------
    q, qc : (N,) float64
    """
    X, W, index, sign, context, kernel = _epoch_kernel(ROW_ERRORS, X, W, index, sign, context, device, params)[:6]
    return launch_row_errors(context, queue or _queue(context), kernel, X, W, index, sign, bmu.unit, bmu.variation)


def launch_topographic_errors(context, queue, kernel, X, W, index, sign, unit, variation, second, rows: int,
                              cols: int, topology: str, neighbourhood: int, tie_rtol: float) -> np.ndarray:
    """Run the built per-row topographic errors kernel on validated arrays (the rows resident where X is
    read-only, the codebook where an update on the device left it).

    Takes and returns what :func:`meshsom.metrics.topographic_errors` with
    :func:`meshsom.metrics.tied_with_neighbour` does, the same to rounding.

    Returns
    -------
    (N,) bool

    Raises
    ------
    DeviceError
        An OpenCL error, as one readable line.
    """
    from meshsom.metrics import _check_neighbourhood, _check_topology

    _check_topology(topology)
    _check_neighbourhood(neighbourhood)
    cl = _cl()
    N = len(X)
    bad = np.zeros(N, np.uint8)
    if N:
        try:
            xbuf, ibuf, sbuf = row_buffers(context, X, index, sign)
            out = scratch(context, bad.nbytes)
            group = min(SUMS_GROUP, context.devices[0].max_work_group_size)
            kernel(queue, (-(-N // group) * group,), (group,), xbuf, np.int32(N), ibuf, sbuf,
                   *(upload(context, np.ascontiguousarray(a, np.int32)) for a in (variation, unit, second)),
                   resident_codebooks(context).buffer(context, W), np.int32(rows), np.int32(cols),
                   np.int32(topology == "toroidal"), np.int32(neighbourhood), np.float64(tie_rtol), out)
            cl.enqueue_copy(queue, bad, out)
            queue.finish()
        except cl.Error as err:
            raise _launch_failed(context, X, "per-row topographic errors kernel", err) from None
    return bad.astype(bool)


def topographic_errors_opencl(X, W, bmu: BMUResult, index=None, sign=None, context=None, device: str | None = None,
                              params: KernelParams | None = None, queue=None, rows: int = 0, cols: int = 0,
                              topology: str = "toroidal", neighbourhood: int = 8, tie_rtol: float | None = None
                              ) -> np.ndarray:
    """Per row, whether it is a topographic error (its second-best unit is no grid neighbour of its
    best, and no neighbour ties with it) on the device: :func:`meshsom.metrics.topographic_errors`
    with :func:`meshsom.metrics.tied_with_neighbour`, the same to rounding.

    Parameters and errors as :func:`unit_sums_opencl`; ``rows``, ``cols``, ``topology`` and
    ``neighbourhood`` describe the map, ``tie_rtol`` None: :data:`meshsom.metrics.TIE_RTOL`.

    Returns
    -------
    (N,) bool
    """
    from meshsom.metrics import TIE_RTOL

    if rows * cols != len(W):
        raise ValueError(f"a {rows} x {cols} map has {rows * cols} units; received W with {len(W)}")
    X, W, index, sign, context, kernel = _epoch_kernel(TOPOGRAPHIC_ERRORS, X, W, index, sign, context, device,
                                                       params)[:6]
    return launch_topographic_errors(context, queue or _queue(context), kernel, X, W, index, sign, bmu.unit,
                                     bmu.variation, bmu.second, rows, cols, topology, neighbourhood,
                                     TIE_RTOL if tie_rtol is None else tie_rtol)


def batch_update_opencl(W, sums: DeviceArray, counts, row_kernel, col_kernel, min_weight: float,
                        queue=None) -> np.ndarray:
    """The update of a batch epoch on the device where its sums are (``kernels/batch_update.cl``):
    :func:`meshsom.som.batch_update`, the same to rounding.

    The sums are smoothed along the columns and then the rows, the counts likewise, and divided
    into the new codebook there; it comes back read-only and keeps its device copy
    (:class:`ResidentCodebooks`), so the next search on this context does not send it up.

    Parameters
    ----------
    W : (M, D) float32 or float64
        The prototypes before the update (the dtype of the sums' program).
    sums : DeviceArray
        (M, D) float64, from :func:`unit_sums_opencl` with ``keep``.
    counts : (M,) float64
    row_kernel : (rows, rows) float64
    col_kernel : (cols, cols) float64
        Gaussian weights between the cells of each grid axis (:func:`meshsom.som.gaussian_kernel_1d`).
    min_weight : float
        Units whose smoothed count is not above this keep their prototype.
    queue : pyopencl.CommandQueue or None

    Returns
    -------
    (M, D) W's dtype, read-only

    Raises
    ------
    DeviceError
        The shapes disagree with the program, or an OpenCL error (as one readable line).
    """
    cl = _cl()
    context = sums.context
    rows, cols = len(row_kernel), len(col_kernel)
    M, D = sums.shape
    W = np.ascontiguousarray(W)
    real = np.float64 if sums.defines["REAL"] == "double" else np.float32
    if W.shape != (M, D) or W.dtype != real or np.shape(counts) != (M,) or rows * cols != M:
        raise DeviceError(f"{device_name(context)}: the update on the device expects W ({M}, {D}) {np.dtype(real).name}, "
                          f"counts ({M},) and a {rows} x {cols} grid of {M} units; received W {W.shape} {W.dtype}, "
                          f"counts {np.shape(counts)}, grid {rows} x {cols}")
    smooth = get_kernel(context, sums.defines, SMOOTH_AXIS, layout=sums.layout)
    divide = get_kernel(context, sums.defines, DIVIDE_CODEBOOK, layout=sums.layout)
    queue = queue or _queue(context)
    group = min(SUMS_GROUP, context.devices[0].max_work_group_size)

    rj = int(sums.defines.get("SMOOTH_RJ", 1))

    def along(src, A, L, B, kern, dst):  # one work-item per run of SMOOTH_RJ outputs along the axis
        items = A * -(-L // rj) * B
        smooth(queue, (-(-items // group) * group,), (group,), src, np.int32(A), np.int32(L), np.int32(B), kern, dst)

    new = np.empty((M, D), real)
    try:
        rk = upload(context, np.ascontiguousarray(row_kernel, np.float64))
        ck = upload(context, np.ascontiguousarray(col_kernel, np.float64))
        half, num = (scratch(context, M * D * 8) for _ in range(2))
        along(sums.buffer, rows, cols, D, ck, half)
        along(half, 1, rows, cols * D, rk, num)
        once, den = (scratch(context, M * 8) for _ in range(2))
        along(upload(context, np.ascontiguousarray(counts, np.float64)), rows, cols, 1, ck, once)
        along(once, 1, rows, cols, rk, den)
        out = scratch(context, new.nbytes)
        divide(queue, (-(-M * D // group) * group,), (group,), num, den, resident_codebooks(context).buffer(context, W),
               np.int32(M), np.float64(min_weight), out)
        cl.enqueue_copy(queue, new, out)
        queue.finish()
    except cl.Error as err:
        raise _launch_failed(context, None, "the update on the device", err) from None
    new.flags.writeable = False
    resident_codebooks(context).add(new, out)
    return new


_QUEUES: "weakref.WeakKeyDictionary" = weakref.WeakKeyDictionary()
_POOLS: "weakref.WeakKeyDictionary" = weakref.WeakKeyDictionary()


def scratch(context, nbytes: int):
    """A device buffer of ``nbytes`` for one call's intermediate or output values (read and written
    on the device), from the context's memory pool (``pyopencl.tools.MemoryPool``).

    A search and an epoch make about fifteen such buffers; on a GPU each allocation and each
    release is a driver call (NVIDIA: cuMemAlloc, and cuMemFree, which waits for the device),
    about as long as a whole small pass. Released buffers go back to the pool and serve later
    calls of the same size class; the pool keeps them until the context goes.
    """
    if context not in _POOLS:
        from pyopencl.tools import ImmediateAllocator, MemoryPool

        _POOLS[context] = MemoryPool(ImmediateAllocator(_queue(context)))
    return _POOLS[context].allocate(max(int(nbytes), 1))


def _queue(context):
    """One command queue per context."""
    cl = _cl()
    if context not in _QUEUES:
        try:
            _QUEUES[context] = cl.CommandQueue(context)
        except cl.Error as err:
            raise DeviceError(f"{device_name(context)}: cannot open a command queue ({err})") from None
    return _QUEUES[context]
