"""PoCL's kernel target CPU, read from the device and set where its LLVM does not know the host.

PoCL compiles every kernel for the CPU LLVM names for the host (``llvm::sys::getHostCPUName``)
and shows that name in its device version (the "HSTR" ``<driver>-<triple>-<cpu>``). An LLVM
older than the CPU cannot name it and says ``"generic"``, which PoCL passes on to its compiler;
that compiler rejects it (``error: unknown target CPU 'generic'``, pocl/pocl#1049) and no kernel
builds. PoCL 3.0 with LLVM 14 (pyopencl's wheels) does this on AMD Zen 5 (CPU family 0x1a, the
EPYC 9005 series), and on any CPU whose vendor or family LLVM 14 does not list.

:func:`retarget` sets such a device's kernel target to the LLVM 14 CPU that matches the kernel
library PoCL itself picks from the host's features (:data:`DISTRO_TARGETS`, the "distro" build
of pyopencl's PoCL: ``avx512`` on an AVX-512 host, compiled for ``skylake-avx512``), so the
kernels and PoCL's built-in functions agree. The same mismatch, milder, is a CPU LLVM names
without AVX-512 while PoCL picks its AVX-512 library (LLVM 14 and 15 call AMD Zen 4 ``znver3``):
kernels then build only with 8 lanes (16 abort the compiler, see ``kernels/bmu_common.cl``), so
such a device is retargeted too, to ``skylake-avx512``.

PoCL 3.0 reads no setting for its target (later releases read ``POCL_LLVM_CPU_NAME``), so the
name is written into the device's ``llvm_cpu`` field, in this process, before anything is built
on it: the field is found as the pointer to the HSTR's CPU name right after the pointer to its
triple, and the device is left alone unless exactly one such
pair is found. ``POCL_LLVM_CPU_NAME``, where set, names the CPU instead (on any PoCL CPU device,
as later PoCL releases do). Every kernel is still probed before use (:mod:`meshsom.probe`), so a
target that builds wrong code is a rejected layout, never a wrong answer.
"""

from __future__ import annotations

import ctypes
import logging
import multiprocessing
import os
import platform
import sys

log = logging.getLogger(__name__)

#: The CPU name an LLVM too old for the host gives, which PoCL's compiler rejects.
UNKNOWN_CPU = "generic"
#: Environment variable naming the kernel target CPU (PoCL 4 and later read it themselves).
ENV_CPU = "POCL_LLVM_CPU_NAME"
#: Bytes of PoCL's device structure searched for the triple and CPU name pointers (PoCL 3.0
#: keeps them at bytes 632 and 640).
DEVICE_STRUCT_BYTES = 1024
#: Longest C string read through a pointer while searching.
MAX_NAME_BYTES = 64

#: PoCL's kernel library variants for x86-64 in the order it tries them (PoCL 3.0's
#: ``getX86KernelLibName``: the last whose features the host has wins), each with the host
#: features it needs (``/proc/cpuinfo`` flag names) and the LLVM 14 CPU compiled for (the
#: CPU whose features the variant was built with). ``skylake-avx512`` also needs the AVX-512
#: subsets Skylake has; a host with ``avx512f`` alone (Xeon Phi, which LLVM 14 names) gets none.
DISTRO_TARGETS = (
    ("sse2", frozenset({"sse2"}), "x86-64"),
    ("ssse3", frozenset({"ssse3", "cx16"}), "core2"),
    ("sse41", frozenset({"sse4_1", "cx16"}), "penryn"),
    ("avx", frozenset({"avx", "cx16", "popcnt"}), "sandybridge"),
    ("avx_f16c", frozenset({"avx", "cx16", "popcnt", "f16c"}), "ivybridge"),
    ("avx_fma4", frozenset({"avx", "cx16", "popcnt", "xop", "fma4"}), "bdver1"),
    ("avx2", frozenset({"avx", "avx2", "cx16", "popcnt", "abm", "f16c", "fma", "bmi1", "bmi2"}), "haswell"),
    ("avx512", frozenset({"avx512f"}), "skylake-avx512"),
)
#: What ``skylake-avx512`` compiles to beyond ``avx512f``: the host must have these too.
SKYLAKE_AVX512 = frozenset({"avx512f", "avx512cd", "avx512bw", "avx512dq", "avx512vl", "avx2", "fma", "bmi2"})

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

#: Devices retargeted in this process: device pointer -> CPU name written.
_RETARGETED: dict[int, str] = {}
#: Devices looked at and left alone: device pointer -> why (for doctor).
_LEFT: dict[int, str] = {}


def hstr_target(device) -> tuple[str, str] | None:
    """(triple, CPU) of PoCL's kernel target from its version strings; None on other devices.

    PoCL's CPU devices name their kernel target ``<driver>-<triple>-<cpu>`` (its "HSTR"),
    e.g. ``pthread-x86_64-unknown-linux-gnu-icelake-client``: PoCL 3.0 ends the device version
    with ``HSTR: ...``, other releases put it in the driver version. The CPU is what follows the
    triple's last part (``-gnu-``, ``-linux-``, ...).
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
            cut = max(ends) + 1
            return "-".join(parts[1:cut]), "-".join(parts[cut:])
    return None


def kernel_target(device) -> str | None:
    """The LLVM CPU PoCL builds this device's kernels for: the name :func:`retarget` wrote, else
    the HSTR's (:func:`hstr_target`); None on devices that are not PoCL's."""
    pointer = _pointer(device)
    if pointer is not None and pointer in _RETARGETED:
        return _RETARGETED[pointer]
    found = hstr_target(device)
    return found[1] if found else None


def retargeted(device) -> str | None:
    """The CPU name :func:`retarget` wrote for this device in this process, else None."""
    pointer = _pointer(device)
    return _RETARGETED.get(pointer) if pointer is not None else None


def left_alone(device) -> str | None:
    """Why :func:`retarget` left a device PoCL cannot build for as it was, else None."""
    pointer = _pointer(device)
    return _LEFT.get(pointer) if pointer is not None else None


def cpu_flags(cpuinfo: str) -> frozenset[str]:
    """The feature flags of the first processor in ``/proc/cpuinfo`` text (empty where none)."""
    for line in cpuinfo.splitlines():
        key, _, value = line.partition(":")
        if key.strip() == "flags":
            return frozenset(value.split())
    return frozenset()


def distro_cpu(flags: frozenset[str]) -> str | None:
    """The LLVM 14 CPU of the kernel library variant PoCL picks for a host's flags
    (:data:`DISTRO_TARGETS`); None where the host cannot run that CPU's code (``avx512f``
    without Skylake's other AVX-512 subsets) or has not even SSE2."""
    chosen = None
    for _, needs, cpu in DISTRO_TARGETS:
        if needs <= flags:
            chosen = cpu
    if chosen == "skylake-avx512" and not SKYLAKE_AVX512 <= flags:
        return None
    return chosen


def _pointer(device) -> int | None:
    try:
        return int(device.int_ptr)
    except Exception:  # a fake device
        return None


def _is_pocl_cpu(device) -> bool:
    try:
        import pyopencl as cl

        return bool(device.type & cl.device_type.CPU) and "pocl" in device.platform.version.lower()
    except Exception:  # a fake or failing device
        return False


def _readable_spans() -> list[tuple[int, int]]:
    """Readable address ranges of this process (``/proc/self/maps``)."""
    spans = []
    with open("/proc/self/maps") as maps:
        for line in maps:
            fields = line.split()
            if len(fields) >= 2 and fields[1].startswith("r"):
                low, high = (int(x, 16) for x in fields[0].split("-"))
                spans.append((low, high))
    return spans


def _c_string(address: int, spans: list[tuple[int, int]]) -> bytes | None:
    """The NUL-terminated string at ``address`` (at most :data:`MAX_NAME_BYTES`), None where the
    address is not readable or no NUL ends it in time."""
    for low, high in spans:
        if low <= address < high:
            raw = ctypes.string_at(address, min(MAX_NAME_BYTES, high - address))
            end = raw.find(b"\0")
            return raw[:end] if end >= 0 else None
    return None


def cpu_field(device, triple: str, cpu: str) -> int | None:
    """Address of the device's ``llvm_cpu`` pointer: the one word of PoCL's device structure that
    points to ``cpu`` right after a word pointing to ``triple``; None unless exactly one is found."""
    base, spans = _pointer(device), _readable_spans()
    if base is None:
        return None
    word = ctypes.sizeof(ctypes.c_void_p)
    want = (triple.encode(), cpu.encode())
    found = []
    for offset in range(0, DEVICE_STRUCT_BYTES - word, word):
        address = base + offset
        if not any(low <= address and address + 2 * word <= high for low, high in spans):
            break
        first = ctypes.c_void_p.from_address(address).value
        second = ctypes.c_void_p.from_address(address + word).value
        if first and second and (_c_string(first, spans), _c_string(second, spans)) == want:
            found.append(address + word)
    return found[0] if len(found) == 1 else None


def _host_flags() -> frozenset[str]:
    try:
        with open("/proc/cpuinfo") as text:
            return cpu_flags(text.read())
    except OSError:
        return frozenset()


def retarget(device) -> str | None:
    """Point a PoCL CPU device whose LLVM calls the host ``"generic"``, or names a CPU without the
    AVX-512 of the kernel library PoCL picks for the host, at that library's CPU (or at
    ``$POCL_LLVM_CPU_NAME``); the name written, else None.

    Idempotent per device and process; logs one line when it writes (a warning in a main process, INFO
    in a worker process that ``multiprocessing`` started). Does nothing on
    devices that are not PoCL's CPU devices, off Linux x86-64, or where the host CPU is known.
    """
    pointer = _pointer(device)
    if pointer is None:
        return None
    if pointer in _RETARGETED:
        return _RETARGETED[pointer]
    if pointer in _LEFT or not _is_pocl_cpu(device):
        return None
    target = hstr_target(device)
    if target is None:
        return None
    triple, cpu = target
    wanted = os.environ.get(ENV_CPU, "").strip()
    library = None if wanted or cpu == UNKNOWN_CPU else distro_cpu(_host_flags())
    short = library == "skylake-avx512" and cpu.lower() in NON_AVX512_CPUS
    if not (wanted or cpu == UNKNOWN_CPU or short):
        return None
    if not sys.platform.startswith("linux") or platform.machine().lower() not in ("x86_64", "amd64"):
        _LEFT[pointer] = f"kernel target {cpu!r} left as it is off Linux x86-64"
        return None
    if wanted:
        why = f"set {ENV_CPU}"
    elif short:
        why = (f"PoCL's LLVM names this CPU {cpu!r}, without the AVX-512 of the builtin library PoCL "
               f"picks from its flags (LLVM 14 and 15 on AMD Zen 4)")
    else:
        why = f"PoCL's LLVM does not know this CPU (it calls it {cpu!r})"
    name = wanted or library or distro_cpu(_host_flags())
    if not name:
        _LEFT[pointer] = f"{why}, and no LLVM CPU matches its features; set {ENV_CPU} to one"
        log.warning("OpenCL: %s", _LEFT[pointer])
        return None
    if name == cpu:
        return None
    try:
        field = cpu_field(device, triple, cpu)
    except OSError:  # no /proc/self/maps to read (a sandbox): the structure is not searched
        field = None
    if field is None:
        _LEFT[pointer] = f"{why}; its kernel target field was not found, so kernels cannot be retargeted to {name}"
        log.warning("OpenCL: %s", _LEFT[pointer])
        return None
    libc = ctypes.CDLL(None)
    libc.malloc.restype, libc.malloc.argtypes = ctypes.c_void_p, [ctypes.c_size_t]
    raw = name.encode() + b"\0"
    copy = libc.malloc(len(raw))  # PoCL's own allocator: PoCL may free the field's string
    if not copy:
        return None
    ctypes.memmove(copy, raw, len(raw))
    ctypes.c_void_p.from_address(field).value = copy  # the old string (8 bytes) is left as it was
    _RETARGETED[pointer] = name
    # one line where the user looks: the main process warns; its worker processes (Dask's) say it at INFO
    level = logging.WARNING if multiprocessing.parent_process() is None else logging.INFO
    log.log(level, "OpenCL: %s; kernels are built for %s%s", why, name,
            "" if wanted else f" (the CPU of PoCL's kernel library for this host; {ENV_CPU} picks another)")
    return name
