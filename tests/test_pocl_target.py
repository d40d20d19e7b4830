"""PoCL's kernel target CPU where its LLVM does not know the host (meshsom.pocl_target).

The search for the device's ``llvm_cpu`` field and the write run on a structure laid out here
with ctypes; the end-to-end tests run in fresh processes on the real PoCL device: a CPU name its
compiler rejects must come back in the build error (so the write reaches PoCL's compiler,
whatever the host), and the host's kernel library CPU must give the NumPy answers.
"""

from __future__ import annotations

import ctypes
import json
import os
import platform
import subprocess
import sys
import types

import pytest

from meshsom import pocl_target
from meshsom.pocl_target import cpu_field, cpu_flags, distro_cpu, hstr_target, retarget

#: /proc/cpuinfo flags of real hosts (trimmed to what matters plus a few others).
ZEN5_EPYC = ("fpu vme de pse tsc msr pae mce cx8 apic sep mtrr pge sse sse2 ht syscall nx mmxext lm pni pclmulqdq "
             "ssse3 fma cx16 sse4_1 sse4_2 movbe popcnt aes xsave avx f16c rdrand hypervisor lahf_lm cmp_legacy abm "
             "sse4a misalignsse 3dnowprefetch bmi1 avx2 smep bmi2 erms invpcid avx512f avx512dq rdseed adx smap "
             "avx512ifma clflushopt clwb avx512cd sha_ni avx512bw avx512vl xsaveopt xsavec xgetbv1 xsaves avx512_bf16 "
             "avx512vbmi umip pku avx512_vbmi2 gfni vaes vpclmulqdq avx512_vnni avx512_bitalg avx512_vpopcntdq")
HASWELL = ("fpu vme de pse tsc msr pae mce cx8 apic sep mtrr pge sse sse2 ss ht syscall nx lm pni pclmulqdq ssse3 "
           "fma cx16 sse4_1 sse4_2 movbe popcnt aes xsave avx f16c rdrand lahf_lm abm bmi1 avx2 smep bmi2 erms")
BULLDOZER = "fpu sse sse2 ht syscall nx lm pni pclmulqdq ssse3 cx16 sse4_1 sse4_2 popcnt aes xsave avx xop fma4 abm"
XEON_PHI = HASWELL + " avx512f avx512pf avx512er avx512cd"
OLD_SSE2 = "fpu vme de pse tsc msr pae mce cx8 apic sep mtrr pge mmx fxsr sse sse2 syscall nx lm"


@pytest.fixture(autouse=True)
def own_registry(monkeypatch):
    """Each test its own record of retargeted devices (fake structures reuse freed addresses); the
    process's record of its real devices comes back afterwards."""
    monkeypatch.setattr(pocl_target, "_RETARGETED", {})
    monkeypatch.setattr(pocl_target, "_LEFT", {})


def cpuinfo(flags: str) -> str:
    return f"processor\t: 0\nvendor_id\t: AuthenticAMD\nmodel name\t: AMD EPYC\nflags\t\t: {flags}\nbogomips\t: 4800\n"


@pytest.mark.parametrize("flags,cpu", [
    (ZEN5_EPYC, "skylake-avx512"),
    (HASWELL, "haswell"),
    (BULLDOZER, "bdver1"),
    (HASWELL.replace(" bmi2", ""), "ivybridge"),  # AVX2 without BMI2: PoCL's avx_f16c library
    (OLD_SSE2, "x86-64"),
    (XEON_PHI, None),  # avx512f without Skylake's subsets: no safe target
    ("", None),
])
def test_the_target_is_the_cpu_of_the_kernel_library_pocl_picks(flags, cpu):
    assert distro_cpu(cpu_flags(cpuinfo(flags))) == cpu


def test_cpu_flags_read_the_first_processor_and_nothing_else():
    text = cpuinfo("sse sse2 avx") + "\n" + cpuinfo("sse sse2 avx avx2 avx512f")
    assert cpu_flags(text) == {"sse", "sse2", "avx"}
    assert cpu_flags("processor : 0\nvendor_id : x\n") == frozenset()


@pytest.mark.parametrize("hstr,parsed", [
    ("OpenCL 3.0 PoCL HSTR: pthread-x86_64-unknown-linux-gnu-generic", ("x86_64-unknown-linux-gnu", "generic")),
    ("OpenCL 3.0 PoCL HSTR: pthread-x86_64-unknown-linux-gnu-skylake-avx512",
     ("x86_64-unknown-linux-gnu", "skylake-avx512")),
    ("OpenCL 3.0 PoCL HSTR: pthread-aarch64-unknown-linux-gnu-cortex-a72", ("aarch64-unknown-linux-gnu", "cortex-a72")),
    ("OpenCL 3.0 CUDA", None),
])
def test_hstr_gives_triple_and_cpu(hstr, parsed):
    assert hstr_target(types.SimpleNamespace(version=hstr, driver_version="3.0-rc2")) == parsed


class FakeStruct:
    """A device structure in this process's memory: words, two of them pointing at a triple and a CPU name."""

    def __init__(self, pairs=((80, "x86_64-unknown-linux-gnu", "generic"),), words=pocl_target.DEVICE_STRUCT_BYTES // 8):
        self.words = (ctypes.c_void_p * words)()
        self.strings = []
        for offset, triple, cpu in pairs:
            for k, text in enumerate((triple, cpu)):
                buffer = ctypes.create_string_buffer(text.encode())
                self.strings.append(buffer)
                self.words[offset // 8 + k] = ctypes.addressof(buffer)
        self.int_ptr = ctypes.addressof(self.words)

    def word(self, offset: int) -> bytes:
        return ctypes.string_at(self.words[offset // 8])


class FakePoclDevice(FakeStruct):
    def __init__(self, cpu="generic", **kw):
        import pyopencl as cl

        super().__init__(((80, "x86_64-unknown-linux-gnu", cpu),), **kw)
        self.type = cl.device_type.CPU
        self.platform = types.SimpleNamespace(version="OpenCL 3.0 PoCL 3.0-rc2  Linux, Release, LLVM 14.0.6, DISTRO")
        self.version = f"OpenCL 3.0 PoCL HSTR: pthread-x86_64-unknown-linux-gnu-{cpu}"
        self.driver_version = "3.0-rc2"


def test_the_cpu_field_is_the_one_after_the_triple():
    fake = FakeStruct()
    assert cpu_field(fake, "x86_64-unknown-linux-gnu", "generic") == fake.int_ptr + 88
    assert cpu_field(fake, "x86_64-unknown-linux-gnu", "znver3") is None
    assert cpu_field(fake, "aarch64-unknown-linux-gnu", "generic") is None


def test_two_candidate_fields_leave_the_device_alone():
    fake = FakeStruct(((80, "x86_64-unknown-linux-gnu", "generic"), (200, "x86_64-unknown-linux-gnu", "generic")))
    assert cpu_field(fake, "x86_64-unknown-linux-gnu", "generic") is None


only_x86_linux = pytest.mark.skipif(not sys.platform.startswith("linux") or platform.machine() != "x86_64",
                                    reason="PoCL retargeting is for Linux x86-64")


def host(monkeypatch, flags: str) -> None:
    """This process as if on a host with these cpuinfo flags, with no POCL_LLVM_CPU_NAME."""
    monkeypatch.delenv(pocl_target.ENV_CPU, raising=False)
    monkeypatch.setattr(pocl_target, "_host_flags", lambda: cpu_flags(cpuinfo(flags)))


@only_x86_linux
def test_retarget_writes_the_kernel_library_cpu_once(monkeypatch, caplog):
    host(monkeypatch, ZEN5_EPYC)
    fake = FakePoclDevice()
    with caplog.at_level("WARNING", logger="meshsom.pocl_target"):
        assert retarget(fake) == "skylake-avx512"
        assert retarget(fake) == "skylake-avx512"
    assert fake.word(88) == b"skylake-avx512" and fake.word(80) == b"x86_64-unknown-linux-gnu"
    assert len(caplog.records) == 1 and "does not know this CPU (it calls it 'generic')" in caplog.text
    from meshsom.bmu_opencl import kernel_target_cpu, layout_chain, target_options

    assert kernel_target_cpu(fake) == "skylake-avx512" and pocl_target.retargeted(fake) == "skylake-avx512"
    assert target_options(fake) == ["-DMESHSOM_TARGET_CPU=skylake_avx512"]
    fake.preferred_vector_width_float = 16
    assert layout_chain(fake)[0] == "cpu"  # 16 lanes: skylake-avx512 has AVX-512


@only_x86_linux
def test_a_known_cpu_is_left_alone_and_the_setting_overrides_it(monkeypatch):
    host(monkeypatch, HASWELL)
    known = FakePoclDevice("znver3")
    assert retarget(known) is None and known.word(88) == b"znver3"
    host(monkeypatch, ZEN5_EPYC)
    avx512 = FakePoclDevice("icelake-client")
    assert retarget(avx512) is None and avx512.word(88) == b"icelake-client"
    monkeypatch.setenv(pocl_target.ENV_CPU, "haswell")
    chosen = FakePoclDevice("znver3")
    assert retarget(chosen) == "haswell" and chosen.word(88) == b"haswell"


@only_x86_linux
def test_zen4_named_without_avx512_gets_the_avx512_library_cpu(monkeypatch, caplog):
    """LLVM 14 calls AMD Zen 4 "znver3" (no AVX-512) while PoCL picks its AVX-512 library from the
    flags: 16-lane kernels abort the compiler there, so the target becomes the library's CPU."""
    host(monkeypatch, ZEN5_EPYC)  # Zen 4 and Zen 5 share the AVX-512 flags that matter
    zen4 = FakePoclDevice("znver3")
    with caplog.at_level("WARNING", logger="meshsom.pocl_target"):
        assert retarget(zen4) == "skylake-avx512"
    assert zen4.word(88) == b"skylake-avx512" and "names this CPU 'znver3'" in caplog.text
    from meshsom.bmu_opencl import layout_chain

    zen4.preferred_vector_width_float = 16
    assert layout_chain(zen4)[0] == "cpu"


@only_x86_linux
def test_no_matching_cpu_or_no_field_is_said_and_left_alone(monkeypatch, caplog):
    host(monkeypatch, XEON_PHI)
    phi = FakePoclDevice()
    with caplog.at_level("WARNING", logger="meshsom.pocl_target"):
        assert retarget(phi) is None
    assert phi.word(88) == b"generic" and "no LLVM CPU matches its features" in pocl_target.left_alone(phi)
    host(monkeypatch, HASWELL)
    lost = FakePoclDevice()
    lost.words[10] = None  # no triple pointer before the CPU name
    assert retarget(lost) is None and "field was not found" in pocl_target.left_alone(lost)
    assert caplog.text.count("OpenCL:") == 2


@only_x86_linux
def test_no_readable_memory_map_leaves_the_device_alone(monkeypatch):
    host(monkeypatch, ZEN5_EPYC)

    def unreadable():
        raise PermissionError("/proc/self/maps")

    monkeypatch.setattr(pocl_target, "_readable_spans", unreadable)
    fake = FakePoclDevice()
    assert retarget(fake) is None and fake.word(88) == b"generic"
    assert "field was not found" in pocl_target.left_alone(fake)


def test_other_devices_are_never_touched():
    import pyopencl as cl

    gpu = FakePoclDevice()
    gpu.type = cl.device_type.GPU
    assert retarget(gpu) is None and gpu.word(88) == b"generic"
    assert retarget(types.SimpleNamespace()) is None


CHILD = r"""
import json, sys
import numpy as np
from meshsom import bmu_opencl, bmu_numpy
from meshsom.pocl_target import hstr_target
pocl = [d for s, name, d in bmu_opencl.list_devices() if "Portable Computing Language" in name]
if not pocl:
    print(json.dumps({"skip": "no PoCL device"})); sys.exit()
device = pocl[0]
import pyopencl as cl
context = cl.Context([device])
out = {"target": bmu_opencl.kernel_target_cpu(device), "hstr": hstr_target(device)[1]}
try:
    program = cl.Program(context, "__kernel void twice(__global float *a) { a[get_global_id(0)] *= 2.0f; }")
    program.build(options=bmu_opencl.target_options(device))
    out["built"] = True
except cl.Error as err:
    out["built"], out["error"] = False, str(err)
if sys.argv[1] == "search":
    rng = np.random.default_rng(4)
    X, W = rng.normal(size=(300, 36)).astype(np.float32), rng.normal(size=(70, 36)).astype(np.float32)
    got = bmu_opencl.bmu_opencl(X, W, context=context)
    want = bmu_numpy.bmu_numpy(X, W)
    out["same_units"] = bool(np.array_equal(got.unit, want.unit))
print(json.dumps(out))
"""


def child(tmp_path, what: str, cpu: str | None) -> dict:
    env = {**os.environ, "MESHSOM_CACHE_DIR": str(tmp_path / "meshsom"), "POCL_CACHE_DIR": str(tmp_path / "pocl")}
    env.pop(pocl_target.ENV_CPU, None)
    if cpu:
        env[pocl_target.ENV_CPU] = cpu
    done = subprocess.run([sys.executable, "-c", CHILD, what], env=env, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-2000:]
    out = json.loads(done.stdout.strip().splitlines()[-1])
    if "skip" in out:
        pytest.skip(out["skip"])
    return out


@only_x86_linux
def test_the_written_name_reaches_pocls_compiler(tmp_path):
    out = child(tmp_path, "build", "no-such-cpu")
    assert out["target"] == "no-such-cpu" and not out["built"]
    assert "unknown target CPU 'no-such-cpu'" in out["error"]


@only_x86_linux
def test_the_kernel_library_cpu_gives_the_numpy_answers(tmp_path):
    with open("/proc/cpuinfo") as text:
        cpu = distro_cpu(cpu_flags(text.read()))
    if cpu is None:
        pytest.skip("no kernel library CPU for this host")
    out = child(tmp_path, "search", cpu)
    assert out["target"] == cpu and out["built"] and out["same_units"]


@only_x86_linux
def test_no_pocl_device_is_left_with_a_cpu_its_compiler_rejects(tmp_path):
    out = child(tmp_path, "build", None)
    assert out["target"] != pocl_target.UNKNOWN_CPU and out["built"], out
