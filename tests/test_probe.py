"""The OpenCL guard: probes in child processes, the verdict cache, the fallback chain, clean errors.

Failures are injected with the test hook ``MESHSOM_KERNEL_INJECT`` (a ``#error`` build failure,
or a ``__builtin_trap()`` that kills the process on the first launch); every test uses its own
verdict cache folder.
"""

from __future__ import annotations

import logging
import pickle
import re
import subprocess
from types import SimpleNamespace

import numpy as np
import pytest

from meshsom.bmu import find_bmus, resolve_backend
from meshsom.bmu_numpy import bmu_numpy
from meshsom.errors import DeviceError

pytestmark = pytest.mark.usefixtures("fresh_verdicts")


@pytest.fixture
def ctx():
    try:
        from meshsom.bmu_opencl import get_context

        return get_context(None)
    except (DeviceError, ImportError) as err:
        pytest.skip(f"no OpenCL device: {err}")


@pytest.fixture
def forget_programs(monkeypatch):
    """Built programs are memoised per context: start from none, so the guard runs again."""
    import weakref

    from meshsom import bmu_opencl

    monkeypatch.setattr(bmu_opencl, "_PROGRAMS", weakref.WeakKeyDictionary())


#: What a probe says of the injected trap: PoCL's process dies (SIGILL/SIGTRAP); NVIDIA's driver
#: survives it and fails the launch (OUT_OF_RESOURCES when the results are read).
TRAPPED = "killed its process|kernel launch failed"


def data(D=9, n=6, N=300, M=70, seed=0):
    rng = np.random.default_rng(seed)
    X = rng.normal(size=(N, D)).astype(np.float32)
    W = rng.normal(size=(M, D)).astype(np.float32)
    index = np.stack([np.arange(D)] + [rng.permutation(D) for _ in range(n - 1)]).astype(np.int64)
    sign = np.where(rng.random((n, D)) < 0.3, -1.0, 1.0).astype(np.float32)
    sign[0] = 1
    return X, W, index, sign


def test_layout_names_of_the_config_are_the_kernel_layouts():
    pytest.importorskip("pyopencl")
    from meshsom.bmu_opencl import CHAINS, DEFAULT_PARAMS
    from meshsom.config import LAYOUTS

    assert LAYOUTS == tuple(DEFAULT_PARAMS)
    assert all(name in DEFAULT_PARAMS for chain in CHAINS.values() for name in chain)
    assert all(chain[-1] == "tiled" for chain in CHAINS.values())


def test_injection_hook_parses_and_rejects_nonsense(monkeypatch):
    from meshsom.probe import ENV_INJECT, injected_defines

    monkeypatch.setenv(ENV_INJECT, "cpu=error, cpu-narrow=trap")
    assert injected_defines("cpu") == {"MESHSOM_INJECT_BUILD_ERROR": 1}
    assert injected_defines("cpu-narrow") == {"MESHSOM_INJECT_TRAP": 1}
    assert injected_defines("tiled") == {}
    monkeypatch.setenv(ENV_INJECT, "cpu=explode")
    with pytest.raises(ValueError, match="MESHSOM_KERNEL_INJECT must look like"):
        injected_defines("cpu")


def test_verdict_key_covers_device_driver_source_and_defines():
    from meshsom.probe import verdict_key

    def device(driver="3.0", name="cpu"):
        platform = SimpleNamespace(name="PoCL", version="OpenCL 3.0 PoCL")
        return SimpleNamespace(platform=platform, name=name, vendor="x", driver_version=driver, version="OpenCL 3.0")

    base = verdict_key(device(), {"D": 9, "NV": 6}, "src", ["-cl-mad-enable"])
    assert base == verdict_key(device(), {"NV": 6, "D": 9}, "src", ["-cl-mad-enable"])
    assert base != verdict_key(device(driver="3.1"), {"D": 9, "NV": 6}, "src", ["-cl-mad-enable"])
    assert base != verdict_key(device(name="gpu"), {"D": 9, "NV": 6}, "src", ["-cl-mad-enable"])
    assert base != verdict_key(device(), {"D": 36, "NV": 6}, "src", ["-cl-mad-enable"])
    assert base != verdict_key(device(), {"D": 9, "NV": 6}, "src2", ["-cl-mad-enable"])
    assert base != verdict_key(device(), {"D": 9, "NV": 6}, "src", [])


def test_known_answer_check_rejects_a_wrong_unit():
    """The probe's comparison is itself able to fail: a deliberately wrong winner is caught."""
    from meshsom.probe import compare, known_answer

    X, W, index, sign = known_answer({"D": 9, "NV": 3, "REAL": "float", "VW": 16, "UB": 2})
    ref = bmu_numpy(X, W, index, sign)
    assert compare(X, W, index, sign, ref.unit, ref.variation) == ""
    wrong = ref.unit.copy()
    wrong[5] = (wrong[5] + 1) % len(W)
    assert "wrong answer on 1 of" in compare(X, W, index, sign, wrong, ref.variation)
    assert "out of range" in compare(X, W, index, sign, ref.unit + len(W), ref.variation)


def test_probe_passes_and_is_cached_on_disk(ctx, fresh_verdicts, monkeypatch):
    from meshsom import probe
    from meshsom.bmu_opencl import probe_layout

    first = probe_layout(ctx, "tiled", 9, 6)
    assert first.ok and not first.cached and first.reason == ""
    assert len(list(fresh_verdicts.glob("*.json"))) == 1
    # a new process (no memo) reads the verdict from disk and starts no child
    monkeypatch.setattr(probe, "_MEMO", {})

    def no_child(*args, **kwargs):
        raise AssertionError("a cached verdict must not start a probe child")

    monkeypatch.setattr(subprocess, "run", no_child)
    again = probe_layout(ctx, "tiled", 9, 6)
    assert again.ok and again.cached and again.key == first.key


def test_probe_reports_a_build_error_and_a_process_killed_at_launch(ctx, monkeypatch):
    from meshsom.bmu_opencl import probe_layout
    from meshsom.probe import ENV_INJECT

    monkeypatch.setenv(ENV_INJECT, "cpu=error,tiled=trap")
    built = probe_layout(ctx, "cpu", 9, 6)
    assert not built.ok and "failed to build" in built.reason and "injected build failure" in built.reason
    killed = probe_layout(ctx, "tiled", 9, 6)
    assert not killed.ok and re.search(TRAPPED, killed.reason)


def test_a_probe_short_of_memory_is_tried_again_and_never_cached(ctx, fresh_verdicts, monkeypatch):
    """A probe that failed for want of memory (a GPU shared by other processes: NVIDIA's
    OUT_OF_HOST_MEMORY at launch or context creation) is no verdict: it is retried, and where every
    try ran short the failure says so and is kept neither on disk nor in memory."""
    from meshsom import probe
    from meshsom.bmu_opencl import probe_layout

    monkeypatch.setattr(probe, "SHORTAGE_WAIT_S", 0.0)
    real = probe._probe_child
    calls = []

    def short_then_real(selector, defines, layout, name, key, timing):
        calls.append(layout)
        if len(calls) <= shortages:
            reason = "pyopencl._cl.RuntimeError: Context failed: OUT_OF_HOST_MEMORY"
            return probe.Verdict(False, layout, name, reason, 0.1, key), True
        return real(selector, defines, layout, name, key, timing)

    monkeypatch.setattr(probe, "_probe_child", short_then_real)
    shortages = 2  # the third try answers
    verdict = probe_layout(ctx, "tiled", 9, 6)
    assert verdict.ok and len(calls) == 3 and len(list(fresh_verdicts.glob("*.json"))) == 1

    calls.clear()
    shortages = probe.SHORTAGE_TRIES  # every try short
    monkeypatch.setattr(probe, "_MEMO", {})
    verdict = probe_layout(ctx, "tiled", 36, 3)
    assert not verdict.ok and len(calls) == probe.SHORTAGE_TRIES
    assert "OUT_OF_HOST_MEMORY" in verdict.reason and verdict.reason.endswith(probe.SHORTAGE_NOTE)
    assert len(list(fresh_verdicts.glob("*.json"))) == 1 and verdict.key not in probe._MEMO
    # the next use probes again, and a real answer is kept
    shortages = 0
    again = probe_layout(ctx, "tiled", 36, 3)
    assert again.ok and not again.cached and len(list(fresh_verdicts.glob("*.json"))) == 2
    # a launch that ran out of resources (NVIDIA: a fault) is a verdict
    assert not probe.short_of_memory(probe.Verdict(False, "gpu", "d", "clEnqueueReadBuffer failed: OUT_OF_RESOURCES", 0, ""))


def test_a_probe_stopped_from_outside_is_tried_again_and_never_cached(ctx, fresh_verdicts, monkeypatch, caplog):
    """A probe child killed by SIGTERM (a user, a scheduler, a cluster shutting down) says nothing
    about the layout: it is tried again, and where every try was stopped the failure says so and is
    kept neither on disk nor in memory (a cached 'killed' verdict would disable a working layout)."""
    from meshsom import probe
    from meshsom.bmu_opencl import probe_layout

    monkeypatch.setattr(probe, "SHORTAGE_WAIT_S", 0.0)
    monkeypatch.setenv(probe.ENV_INJECT, "tiled=sigterm")
    with caplog.at_level(logging.WARNING, logger="meshsom.probe"):
        verdict = probe_layout(ctx, "tiled", 9, 6)
    assert not verdict.ok and verdict.reason == f"{probe.OUTSIDE_REASON} (SIGTERM) {probe.OUTSIDE_NOTE}"
    assert sum("stopped from outside" in r.message for r in caplog.records) == probe.SHORTAGE_TRIES
    assert list(fresh_verdicts.glob("*.json")) == [] and verdict.key not in probe._MEMO
    # a device's own crash stays a verdict
    assert not probe.stopped_from_outside(probe.Verdict(False, "cpu", "d", "the build or first run killed its process (SIGSEGV): x", 0, ""))


def test_probe_that_hangs_is_stopped_by_the_timeout(ctx, monkeypatch):
    from meshsom.bmu_opencl import probe_layout
    from meshsom.probe import ENV_TIMEOUT

    monkeypatch.setenv(ENV_TIMEOUT, "0.05")
    verdict = probe_layout(ctx, "tiled", 9, 1)
    assert not verdict.ok and "no answer within" in verdict.reason


def test_direct_calls_go_through_the_guard_and_raise_instead_of_aborting(ctx, monkeypatch, forget_programs):
    """The OpenCL tests call bmu_opencl directly: a layout that would kill the process raises."""
    from meshsom.bmu_opencl import KernelLayoutError, bmu_opencl, layout_params
    from meshsom.probe import ENV_INJECT

    monkeypatch.setenv(ENV_INJECT, "tiled=trap")
    X, W, index, sign = data()
    with pytest.raises(KernelLayoutError, match=TRAPPED) as info:
        bmu_opencl(X, W, index, sign, context=ctx, params=layout_params(ctx.devices[0], "tiled"))
    # and the error crosses process boundaries (Dask) as plain text
    again = pickle.loads(pickle.dumps(info.value))
    assert str(again) == str(info.value) and again.layout == "tiled"


def test_fallback_chain_runs_the_next_layout_with_its_answers(ctx, monkeypatch, forget_programs, caplog):
    from meshsom.bmu_opencl import CHAINS, bmu_opencl, layout_params
    from meshsom.probe import ENV_INJECT

    import pyopencl as cl

    if not ctx.devices[0].type & cl.device_type.CPU:
        pytest.skip(f"not a CPU device: {ctx.devices[0].name}")
    chain = CHAINS["cpu"]  # three layouts, whatever this CPU's own chain (two where PoCL's target lacks AVX-512)
    X, W, index, sign = data()
    alone = bmu_opencl(X, W, index, sign, context=ctx, params=layout_params(ctx.devices[0], chain[2]))
    monkeypatch.setenv(ENV_INJECT, f"{chain[0]}=error,{chain[1]}=trap")
    with caplog.at_level(logging.WARNING, logger="meshsom.bmu"):
        result, engine = find_bmus(X, W, index, sign, backend=resolve_backend("auto", context=ctx,
                                                                            layout=",".join(chain)))
        find_bmus(X, W, index, sign, backend=engine)  # the same engine does not try them again
    np.testing.assert_array_equal(result.unit, alone.unit)
    np.testing.assert_array_equal(result.variation, alone.variation)
    np.testing.assert_array_equal(result.unit, bmu_numpy(X, W, index, sign).unit)
    info = engine.describe(9, 6)
    assert info["backend"] == "opencl" and info["layout"] == chain[2]
    assert f"{chain[0]} -> {chain[1]}" in info["fallback"] and f"{chain[1]} -> {chain[2]}" in info["fallback"]
    warnings = [r.message for r in caplog.records]
    assert len(warnings) == 2 and all(ctx.devices[0].name.strip() in w for w in warnings)
    assert "injected build failure" in warnings[0] and "killed its process" in warnings[1]


def test_every_layout_failing_falls_back_to_numpy_or_raises_when_opencl_was_asked_for(ctx, monkeypatch,
                                                                                      forget_programs):
    from meshsom.bmu_opencl import layout_chain
    from meshsom.probe import ENV_INJECT

    monkeypatch.setenv(ENV_INJECT, ",".join(f"{name}=error" for name in layout_chain(ctx.devices[0])))
    X, W, index, sign = data(D=36, n=3)
    result, engine = find_bmus(X, W, index, sign, backend="auto", context=ctx)
    np.testing.assert_array_equal(result.unit, bmu_numpy(X, W, index, sign).unit)
    assert engine.describe(36, 3)["layout"] == "numpy" and "-> numpy" in engine.describe(36, 3)["fallback"]
    strict = resolve_backend("opencl", context=ctx)
    with pytest.raises(DeviceError, match="no BMUofN kernel layout works on .* --backend numpy"):
        strict.search(X, W, index, sign)


def test_unknown_layout_is_a_clear_error(ctx):
    with pytest.raises(ValueError, match="unknown kernel layout 'fast'; known layouts: cpu, cpu-narrow"):
        resolve_backend("opencl", context=ctx, layout="fast")


def test_layout_list_sets_the_chain_and_is_validated(ctx):
    from meshsom.config import OpenCLConfig, parse_layouts

    assert resolve_backend("opencl", context=ctx, layout="cpu-narrow, tiled").layouts == ("cpu-narrow", "tiled")
    assert parse_layouts("cpu,cpu-narrow,tiled") == ("cpu", "cpu-narrow", "tiled")
    with pytest.raises(ValueError, match="layout must be one or more of cpu, cpu-narrow, gpu, tiled"):
        OpenCLConfig(layout="cpu,fast")
    with pytest.raises(ValueError, match="received ','"):
        parse_layouts(",")


def test_fitted_som_pickles_without_its_opencl_context(ctx):
    from meshsom.som import SOM

    X, _, _, _ = data(N=60)
    som = SOM(rows=3, cols=4, epochs=2, backend="opencl").fit(X)
    again = pickle.loads(pickle.dumps(som))
    assert not hasattr(again, "engine_") and again.backend_ == "opencl"
    np.testing.assert_array_equal(again.predict(X), som.predict(X))


def test_explicit_layout_runs_alone(ctx, monkeypatch, forget_programs):
    from meshsom.probe import ENV_INJECT

    monkeypatch.setenv(ENV_INJECT, "tiled=error")
    engine = resolve_backend("opencl", context=ctx, layout="tiled")
    assert engine.layouts == ("tiled",)
    X, W, index, sign = data()
    with pytest.raises(DeviceError, match="tiled: kernels/bmu.cl failed to build"):
        engine.search(X, W, index, sign)


def test_epoch_kernels_that_fail_leave_the_search_on_the_device(ctx, monkeypatch, forget_programs, caplog):
    """A layout whose program fails only in the epoch's kernels keeps its search (built without them);
    sums, errors and updates run on the host, with one warning line, and the map is NumPy's bit for bit."""
    from meshsom.bmu_opencl import has_fp64, layout_chain, probe_layout
    from meshsom.probe import ENV_INJECT
    from meshsom.som import SOM

    if not has_fp64(ctx):
        pytest.skip("no float64: the programs hold no epoch kernels")
    first = layout_chain(ctx.devices[0])[0]
    monkeypatch.setenv(ENV_INJECT, f"{first}=epoch-error")
    full = probe_layout(ctx, first, 9, 6)
    assert not full.ok and "injected build failure of the epoch kernels" in full.reason
    assert probe_layout(ctx, first, 9, 6, epoch_kernels=False).ok
    X = data(N=2000)[0]
    engine = resolve_backend("opencl", context=ctx)
    assert engine.prepare(9, 1) == first and engine.search_only == {first}
    with caplog.at_level(logging.WARNING, logger="meshsom.bmu"):
        som = SOM(5, 6, epochs=3, backend=engine, update="device").fit(X)
    assert engine.describe()["layout"] == first and som.update_ == "host"
    assert "the epoch kernels of layout" in engine.describe()["fallback"]
    lines = [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING]
    assert len(lines) == 2 and "its search works but the epoch's kernels do not" in lines[0]
    assert lines[1].startswith("epoch updates run on the host")  # update="device" was asked for
    ref = SOM(5, 6, epochs=3, backend="numpy").fit(X)
    assert som.weights_.tobytes() == ref.weights_.tobytes()


def test_a_search_that_fails_is_not_rescued_by_dropping_the_epoch_kernels(ctx, monkeypatch, forget_programs):
    from meshsom.bmu_opencl import layout_chain

    chain = layout_chain(ctx.devices[0])
    from meshsom.probe import ENV_INJECT

    monkeypatch.setenv(ENV_INJECT, f"{chain[0]}=error")
    X, W, index, sign = data()
    engine = resolve_backend("opencl", context=ctx)
    engine.search(X, W, index, sign)
    assert engine.search_only == set() and engine.describe(9, 6)["layout"] == chain[1]
