"""A wall-clock limit on one mesh's preprocessing (meshsom.time_limit, preprocess.max_seconds)."""

from __future__ import annotations

import threading
import time

import pytest

from meshsom.preprocess import PreprocessParams
from meshsom.time_limit import TimeLimitExceeded, check, time_limit
from pipelines.ingest import process_one
from roof_models import MODELS
from test_envelope import _raw


def test_check_raises_only_past_the_deadline_of_its_own_block():
    check("outside any limit")  # nothing to pass
    with time_limit(60):
        check("well within")
    with time_limit(0.01):
        time.sleep(0.02)
        with pytest.raises(TimeLimitExceeded, match=r"took more than 0.01 s, stopped while the stage"):
            check("the stage")
    check("after the block")
    with time_limit(0):  # no limit
        time.sleep(0.01)
        check("unlimited")


def test_a_nested_limit_keeps_the_earlier_deadline():
    with time_limit(0.01):
        with time_limit(60):
            time.sleep(0.02)
            with pytest.raises(TimeLimitExceeded) as err:
                check("inner")
    assert err.value.seconds == 0.01


def test_other_threads_keep_their_own_deadline():
    seen = []
    with time_limit(0.01):
        time.sleep(0.02)
        worker = threading.Thread(target=lambda: seen.append(check("in a thread without a limit")))
        worker.start()
        worker.join()
    assert seen == [None]


def test_max_seconds_is_validated():
    with pytest.raises(ValueError, match="max_seconds must be a finite number >= 0"):
        PreprocessParams(max_seconds=-1)
    with pytest.raises(ValueError, match="max_seconds"):
        PreprocessParams(max_seconds=float("inf"))


@pytest.fixture
def slow_union(monkeypatch):
    """Each union under the roofs takes 0.3 s longer (as a pathological building's would)."""
    import meshsom.envelope as envelope

    unite = envelope._unite

    def slow(*args, **kw):
        time.sleep(0.3)
        return unite(*args, **kw)

    monkeypatch.setattr(envelope, "_unite", slow)


def test_a_mesh_past_the_limit_is_rejected_with_its_stage_and_nothing_else_changes(tmp_path, slow_union):
    name = sorted(MODELS)[0]
    raw = _raw(tmp_path, MODELS[name]()[0])
    record, clean = process_one(raw, PreprocessParams(max_seconds=0.2))
    assert clean is None and record["status"] == "rejected"
    assert record["reason"].startswith("preprocessing took more than 0.2 s, stopped while ")
    assert "(preprocess.max_seconds; raise it, or 0 for no limit)" in record["reason"]
    assert (record["id"], record["faces_in"], record["faces_out"]) == (raw.id, len(raw.faces), 0)
    # without a limit the same slow building is rebuilt under its roofs, as always
    record, clean = process_one(raw, PreprocessParams(max_seconds=0))
    assert record["status"] == "accepted" and record["envelope"] and clean is not None


def test_the_default_limit_leaves_the_bundled_roof_models_alone(tmp_path):
    for name in sorted(MODELS):
        record, _ = process_one(_raw(tmp_path, MODELS[name]()[0]), PreprocessParams())
        assert record["status"] == "accepted", (name, record["reason"])


def test_ingest_lists_every_mesh_past_the_limit_as_rejected(tmp_path, data_dir):
    """From the command line, with the limit in the config: nothing is lost, every building is listed."""
    from meshsom.store import read_manifest
    from pipelines.cli import main

    config = tmp_path / "tight.yaml"
    config.write_text("preprocess:\n  max_seconds: 1.0e-9\n")
    store = tmp_path / "z.zarr"
    source = data_dir / "zurich-lod2-subset" / "zurich_subset_lod1_derived.city.json"
    # no mesh accepted: the command fails, and the manifest says why for each
    assert main(["ingest", str(source), "--out", str(store), "--config", str(config)]) == 1
    records = read_manifest(store)["records"]
    assert len(records) == 49 and all(r["status"] == "rejected" for r in records)
    assert all(r["reason"].startswith("preprocessing took more than 1e-09 s, stopped while ") for r in records)
