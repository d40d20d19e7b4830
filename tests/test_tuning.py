"""meshsom tune (meshsom.tuning) on PoCL: the GPU layout's candidates timed on the device, the fastest
kept per device and kernel source, used by layout_params there, ignored elsewhere or when damaged."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest

from meshsom import tuning
from meshsom.bmu_opencl import DEFAULT_PARAMS, layout_params

CANDIDATES = [{}, {"prefetch": False}, {"tile_units": 64, "group_units": 8}]


@pytest.fixture
def ctx(fresh_verdicts):
    from tests.test_bmu import _opencl_context

    tuning._READ.clear()
    return _opencl_context()


def test_tune_save_use_forget(ctx):
    result = tuning.tune(ctx, workloads=[(64, 2, 9), (40, 1, 36)], candidates=CANDIDATES, repeat=1)
    # the ratios from the timings, independently: geometric mean over both workloads of time / default's
    times = {}
    for t in result.timings:
        assert t.seconds is not None and t.seconds > 0, t
        times.setdefault(t.candidate, []).append(t.seconds)
    want = {c: float(np.exp(np.mean(np.log(np.array(v) / np.array(times[0]))))) for c, v in times.items()}
    assert result.ratios == pytest.approx(want) and result.ratios[0] == 1.0
    fastest = min(want, key=want.get)
    assert result.best == (fastest if want[fastest] <= tuning.MIN_RATIO else 0)
    # a tuning that won: saved for this device, used by layout_params there, deleted by forget
    won = replace(result, best=2)
    device = ctx.devices[0]
    path = tuning.save(ctx, won)
    assert path.parent == tuning.tuning_dir() and json.loads(path.read_text())["fields"] == CANDIDATES[2]
    default = layout_params(device, "gpu", tuned=False)
    assert layout_params(device, "gpu") == replace(default, tile_units=64, group_units=8)
    assert layout_params(device, "tiled") == layout_params(device, "tiled", tuned=False)  # only the gpu layout
    from pipelines.doctor import _tuning

    assert _tuning(device) == "tuned: tile_units=64, group_units=8"
    assert tuning.forget(ctx) and not tuning.forget(ctx)
    assert layout_params(device, "gpu") == default


def test_a_damaged_or_foreign_tuning_is_ignored(ctx, caplog):
    from tests.test_bmu import FakeDevice

    device = ctx.devices[0]
    path = tuning.tuning_dir() / f"{tuning.tuning_key(device)}.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    for text in ("{not json", json.dumps({"fields": {"tile_rows": 100}}), json.dumps({"fields": {"colour": 1}})):
        path.write_text(text)
        tuning._READ.clear()
        assert tuning.tuned_fields(device) == {}
        assert layout_params(device, "gpu") == layout_params(device, "gpu", tuned=False)
    assert "ignoring the tuning" in caplog.text
    # another driver (or kernel source) is another key: the tuning is not found there
    path.write_text(json.dumps({"fields": {"prefetch": False}}))
    tuning._READ.clear()
    assert tuning.tuned_fields(device) == {"prefetch": False}
    other = FakeDevice("OpenCL 3.0 CUDA", "999.1", width=1, cpu=False)
    assert tuning.tuned_fields(other) == {}
    assert DEFAULT_PARAMS["gpu"].prefetch


def test_tune_command(ctx, capsys, monkeypatch):
    from pipelines.cli import main

    monkeypatch.setattr(tuning, "CANDIDATES", CANDIDATES[:2])  # each candidate is a probe: a few seconds on PoCL
    assert main(["tune", "--quick", "--workload", "64,2,9", "--repeat", "1"]) == 0
    out = capsys.readouterr().out
    assert "time over the default's" in out and "not saved (--quick)" in out and "1.000  default" in out
    assert not tuning.tuning_dir().exists() or not list(tuning.tuning_dir().glob("*.json"))
    with pytest.raises(SystemExit) as err:
        main(["tune", "--workload", "64,2"])
    assert err.value.code == 2 and "N,n,D" in capsys.readouterr().err
