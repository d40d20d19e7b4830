"""BMUofN on OpenCL: the fused kernel, same answers as :mod:`meshsom.bmu_numpy`.

The kernel never materialises the N x M distance matrix: each work-item keeps the best
and second-best unit of its rows per SIMD lane while it sweeps the codebook, and applies
the variations (gather + sign) on the fly. It comes in two layouts of the same arithmetic
(:data:`KERNELS`): ``kernels/bmu_cpu.cl`` for CPU devices (cache- and register-blocked,
the varied vectors of a panel of rows gathered once into private memory) and
``kernels/bmu.cl`` for GPUs (codebook tiles in local memory); the device type picks one
(:data:`DEFAULT_PARAMS`), ``params`` overrides it. Sizes are compiled in as ``-D`` defines; the
built program is memoised per (context, defines). The context is injected by the caller
or made from a device selector: the ``device`` argument, else ``PYOPENCL_CTX``, else the
first device of the first platform. ``create_some_context`` is never called, so nothing
ever prompts.

Device selectors: ``"P:D"`` (platform and device numbers, as ``PYOPENCL_CTX``), ``"P"``,
or a case-insensitive substring of a platform or device name (``"pocl"``, ``"nvidia"``).
"""

from __future__ import annotations

import math
import os
import weakref
from dataclasses import dataclass, replace
from importlib import resources

import numpy as np

from meshsom.bmu_numpy import BMUResult, exact_dist2, validate
from meshsom.errors import DeviceError

#: Environment variable read when no device selector is given (pyopencl's own).
ENV_SELECTOR = "PYOPENCL_CTX"


@dataclass(frozen=True)
class KernelParams:
    """Which kernel and its tiling.

    Two variants of the one BMUofN kernel exist, with the same arithmetic and answers:
    ``"cpu"`` (``kernels/bmu_cpu.cl``: a work-item owns a panel of rows and sweeps the codebook
    in L2-sized blocks with a register-blocked outer product, no barriers) and ``"tiled"``
    (``kernels/bmu.cl``: a work-group stages codebook tiles in local memory, few registers
    per work-item, for GPUs).

    Attributes
    ----------
    kernel : {"cpu", "tiled"}
    vector_width : int
        SIMD lanes per accumulator vector (VW): 2, 4, 8 or 16 (halved for float64).
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
    """

    kernel: str = "tiled"
    vector_width: int = 16
    unit_blocks: int = 2
    max_rows: int = 8
    use_local: bool = True
    work_group: int = 8
    max_dt: int = 144
    panel: int = 192
    panel_bytes: int = 262_144
    cache_tiles: int = 16

    def __post_init__(self):
        if self.kernel not in KERNELS:
            raise ValueError(f"kernel must be one of {', '.join(KERNELS)}, received {self.kernel!r}")
        if self.vector_width not in (2, 4, 8, 16):
            raise ValueError(f"vector_width must be 2, 4, 8 or 16, received {self.vector_width}")
        for name in ("unit_blocks", "max_rows", "work_group", "max_dt", "panel", "panel_bytes", "cache_tiles"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be >= 1, received {getattr(self, name)}")


#: Kernel variant -> (source file under ``kernels/``, kernel function).
KERNELS = {"cpu": ("bmu_cpu.cl", "bmu_of_n_cpu"), "tiled": ("bmu.cl", "bmu_of_n")}

#: Kernel and tiling per OpenCL device type. CPUs (PoCL): the cache-blocked kernel with
#: 2 x 16 units against 8 varied vectors in registers (16 zmm accumulators), 192 varied
#: vectors per work-item and 16 tiles (512 units) per L2 block; measured on a 2-core
#: AVX-512 Xeon (bench/bmu.py). GPUs: few registers per work-item and larger groups.
DEFAULT_PARAMS = {
    "cpu": KernelParams(kernel="cpu", vector_width=16, unit_blocks=2, max_rows=8, panel=192, cache_tiles=16),
    # CPUs whose preferred float vector is narrower than 16 (AVX2: 16 ymm registers): 6 x 2 x 8
    # accumulators, the shape of the usual AVX2 SGEMM micro-kernel (untimed here: no such CPU)
    "cpu-narrow": KernelParams(kernel="cpu", vector_width=8, unit_blocks=2, max_rows=6, panel=192, cache_tiles=32),
    "gpu": KernelParams(kernel="tiled", vector_width=4, unit_blocks=2, max_rows=4, use_local=True, work_group=64,
                        max_dt=64),
}


def _cl():
    try:
        import pyopencl as cl
    except ImportError as err:  # pragma: no cover - pyopencl is a dependency
        raise DeviceError(f"pyopencl is not importable ({err}); install pyopencl (and pocl-binary-distribution)") from None
    return cl


def list_devices() -> list[tuple[str, str, object]]:
    """Every OpenCL device: (selector "P:D", "platform / device" name, device)."""
    cl = _cl()
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
    for _, name, device in devices:
        if text.lower() in name.lower():
            return device
    raise DeviceError(f"no OpenCL device matches {text!r}; devices found: {found}")


_CONTEXTS: dict[str, object] = {}
_PROGRAMS: "weakref.WeakKeyDictionary" = weakref.WeakKeyDictionary()


def get_context(selector: str | None = None):
    """A context for the selected device, made once per selector and reused."""
    cl = _cl()
    key = str(selector if selector is not None else os.environ.get(ENV_SELECTOR, ""))
    if key not in _CONTEXTS:
        _CONTEXTS[key] = cl.Context([select_device(selector)])
    return _CONTEXTS[key]


def device_name(context) -> str:
    """"platform / device" of a context's first device."""
    device = context.devices[0]
    return f"{device.platform.name.strip()} / {device.name.strip()}"


def kernel_source(kernel: str = "tiled") -> str:
    """Text of a kernel variant: ``kernels/bmu_common.cl`` then its own ``.cl`` file (see :data:`KERNELS`)."""
    kernels = resources.files("meshsom").joinpath("kernels")
    return kernels.joinpath("bmu_common.cl").read_text() + "\n" + kernels.joinpath(KERNELS[kernel][0]).read_text()


def _largest_divisor(D: int, cap: int) -> int:
    for dt in range(min(D, cap), 0, -1):
        if D % dt == 0:
            return dt
    return 1


#: LLVM x86 CPU names (LLVM 14 to 19) with avx512f: 16 float lanes are one zmm register.
AVX512_CPUS = frozenset({
    "knl", "knm", "skylake-avx512", "skx", "cascadelake", "cooperlake", "cannonlake",
    "icelake-client", "icelake-server", "rocketlake", "tigerlake", "sapphirerapids",
    "graniterapids", "graniterapids-d", "emeraldrapids", "znver4", "znver5", "x86-64-v4",
})

#: LLVM x86 CPU names (LLVM 14 to 19) without avx512f: 16 float lanes take two registers or more.
#: LLVM 14 and 15 call AMD Zen 4 (AVX-512) "znver3", so a Zen 4 host lands here with them.
NON_AVX512_CPUS = frozenset({
    "generic", "x86-64", "x86-64-v2", "x86-64-v3",
    "i386", "i486", "i586", "i686", "pentium", "pentium-mmx", "pentiumpro", "pentium2", "pentium3",
    "pentium3m", "pentium-m", "pentium4", "pentium4m", "prescott", "nocona", "yonah", "lakemont",
    "core2", "penryn", "bonnell", "atom", "silvermont", "slm", "goldmont", "goldmont-plus", "tremont",
    "nehalem", "corei7", "westmere", "sandybridge", "corei7-avx", "ivybridge", "core-avx-i",
    "haswell", "core-avx2", "broadwell", "skylake", "alderlake", "raptorlake", "meteorlake",
    "gracemont", "arrowlake", "arrowlake-s", "lunarlake", "pantherlake", "sierraforest",
    "grandridge", "clearwaterforest",
    "k6", "k6-2", "k6-3", "athlon", "athlon-tbird", "athlon-4", "athlon-xp", "athlon-mp", "k8",
    "athlon64", "athlon-fx", "opteron", "k8-sse3", "athlon64-sse3", "opteron-sse3", "amdfam10",
    "barcelona", "btver1", "btver2", "bdver1", "bdver2", "bdver3", "bdver4",
    "znver1", "znver2", "znver3",
    "geode", "winchip-c6", "winchip2", "c3", "c3-2",
})


#: Last part of a target triple before PoCL's CPU name in ``<driver>-<triple>-<cpu>``.
_TRIPLE_ENDS = ("gnu", "gnueabihf", "gnueabi", "gnux32", "musl", "android", "eabi", "elf",
                "linux", "darwin", "windows", "msvc", "freebsd")


def kernel_target_cpu(device) -> str | None:
    """The LLVM CPU name PoCL compiles kernels for, from its version strings; None elsewhere.

    PoCL's CPU devices name their kernel target as ``<driver>-<triple>-<cpu>`` (its "HSTR"),
    e.g. ``pthread-x86_64-unknown-linux-gnu-icelake-client``: PoCL 3.0 ends the device version
    with ``HSTR: ...``, other releases put it in the driver version. The CPU is what follows the
    triple's last part (``-gnu-``, ``-linux-``, ...). LLVM's name for the host can lag the
    hardware (LLVM 14 calls AMD Zen 4 ``znver3``), and kernels get only that CPU's features,
    whatever vector widths the device reports. Non-PoCL devices give None.
    """
    tokens = []
    for attribute in ("driver_version", "version"):
        try:
            text = getattr(device, attribute)
        except Exception:  # a fake or failing device: nothing to read
            continue
        if not isinstance(text, str):
            continue
        if "HSTR:" in text:
            tokens[:0] = text.split("HSTR:", 1)[1].split()[:1]  # the named one first
        tokens.extend(text.split())
    for token in tokens:
        parts = token.split("-")
        ends = [i for i, part in enumerate(parts[:-1]) if part in _TRIPLE_ENDS]
        if len(parts) >= 4 and ends:
            return "-".join(parts[max(ends) + 1:])
    return None


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


def device_params(device) -> KernelParams:
    """Kernel and tiling for an OpenCL device: its type and, on CPUs, the float vector width it
    prefers, capped at 8 where PoCL's kernel target CPU has no AVX-512 (:func:`target_vector_width`)."""
    cl = _cl()
    if device.type & cl.device_type.CPU:
        width = target_vector_width(kernel_target_cpu(device), device.preferred_vector_width_float)
        params = DEFAULT_PARAMS["cpu" if width >= 16 else "cpu-narrow"]
    else:
        params = DEFAULT_PARAMS["gpu"]
    return replace(params, work_group=min(params.work_group, device.max_work_group_size))


def default_params(context) -> KernelParams:
    """Kernel and tiling for a context's first device (:func:`device_params`)."""
    return device_params(context.devices[0])


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
        "REAL": "double" if double else "float",
        "IREAL": "long" if double else "int",
        "VW": vw,
        "UB": params.unit_blocks,
        "D": D,
        "NV": n,
    }
    if params.kernel == "cpu" and step * staged <= params.panel_bytes:
        rows = max(step, min(params.panel // n, params.panel_bytes // staged) // step * step)
        return {"KERNEL": "cpu", **common, "P": rows, "RS": rs, "UBLK": params.cache_tiles}
    return {
        "KERNEL": "tiled", **common,
        "DT": _largest_divisor(D, params.max_dt) if params.use_local else D,
        "RX": max(1, params.max_rows // n),
        "USE_LOCAL": int(params.use_local),
        "WG": params.work_group,
    }


def get_kernel(context, defines: dict):
    """The kernel ``defines["KERNEL"]`` names, built for ``defines``, memoised per context."""
    cl = _cl()
    cache = _PROGRAMS.setdefault(context, {})
    key = tuple(sorted(defines.items()))
    if key not in cache:
        source, function = KERNELS[defines["KERNEL"]]
        options = [f"-D{k}={v}" for k, v in key if k != "KERNEL"] + ["-cl-mad-enable"]
        try:
            program = cl.Program(context, kernel_source(defines["KERNEL"])).build(options=options)
            cache[key] = cl.Kernel(program, function)
        except cl.RuntimeError as err:
            raise DeviceError(f"{device_name(context)}: kernels/{source} failed to build with {options}: {err}") from None
    return cache[key]


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
        ``dist2`` recomputed directly in float64 for the winners, as the NumPy backend does.

    Raises
    ------
    DeviceError
        No device, or the kernel does not build.
    """
    cl = _cl()
    X, W, index, sign = validate(X, W, index, sign)
    context = context or get_context(device)
    params = params or default_params(context)
    queue = queue or cl.CommandQueue(context)
    N, D = X.shape
    M = len(W)
    n = len(index)
    if N == 0:
        empty = np.zeros(0, np.int64)
        return BMUResult(empty, empty, np.zeros(0), empty)
    defines = _defines(D, n, X.dtype, params)
    tile = defines["VW"] * defines["UB"]
    MP = -(-M // tile) * tile
    wnorm = np.full(MP, np.inf, X.dtype)
    wnorm[:M] = np.einsum("ij,ij->i", W, W)
    if defines["KERNEL"] == "cpu":
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

    mf = cl.mem_flags
    ro = mf.READ_ONLY | mf.COPY_HOST_PTR
    bufs = [
        cl.Buffer(context, ro, hostbuf=X),
        cl.Buffer(context, ro, hostbuf=WT),
        cl.Buffer(context, ro, hostbuf=wnorm),
        cl.Buffer(context, ro, hostbuf=index.astype(np.int32)),
        cl.Buffer(context, ro, hostbuf=sign),
    ]
    unit = np.empty(N, np.int32)
    variation = np.empty(N, np.int32)
    dist2 = np.empty(N, X.dtype)
    second = np.empty(N, np.int32)
    outs = [cl.Buffer(context, mf.WRITE_ONLY, a.nbytes) for a in (unit, variation, dist2, second)]
    kernel = get_kernel(context, defines)
    kernel(queue, (global_size,), (wg,),
           bufs[0], np.int32(N), bufs[1], bufs[2], np.int32(MP), bufs[3], bufs[4], *outs)
    for host, buf in zip((unit, variation, dist2, second), outs):
        cl.enqueue_copy(queue, host, buf)
    queue.finish()
    unit = unit.astype(np.int64)
    variation = variation.astype(np.int64)
    return BMUResult(unit, variation, exact_dist2(X, W, index, sign, unit, variation), second.astype(np.int64))
