"""pymeshlab's repairs run in a child process (meshsom.meshlab_repair): the same answers as pymeshlab
in this process's main thread, a crashing or hanging child costs one mesh, and a process that
repairs in a worker thread (as the pipelines do) no longer corrupts its heap."""

from __future__ import annotations

import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from meshsom import meshlab_repair
from meshsom.errors import MeshError

ZURICH = Path(__file__).resolve().parents[1] / "data/real/zurich-lod2-subset/zurich_subset_lod2.city.json"


def _open_box():
    """A unit cube without its top (two triangles), one corner duplicated: a hole of four edges."""
    v = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0, 0, 1], [1, 0, 1], [1, 1, 1], [0, 1, 1], [0, 0, 0]], float)
    f = np.array([[8, 2, 1], [0, 3, 2], [0, 1, 5], [0, 5, 4], [1, 2, 6], [1, 6, 5], [2, 3, 7], [2, 7, 6],
                  [3, 0, 4], [3, 4, 7]])
    return v, f


def _edges_twice(f):
    e = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
    _, counts = np.unique(e, axis=0, return_counts=True)
    return bool((counts == 2).all())


@pytest.fixture
def fresh(monkeypatch):
    """A new child for the test (and after it), with the environment the test sets."""
    meshlab_repair.shutdown()
    yield monkeypatch
    monkeypatch.delenv(meshlab_repair.ENV_INJECT, raising=False)
    meshlab_repair.shutdown()


def test_child_repairs_as_pymeshlab_does_here(fresh):
    v, f = _open_box()
    got_v, got_f = meshlab_repair.repair(v, f, "box")
    want_v, want_f = meshlab_repair._repair_here(v, f)  # this process's main thread: safe
    np.testing.assert_array_equal(got_v, want_v)
    np.testing.assert_array_equal(got_f, want_f)
    assert len(got_v) == 8 and _edges_twice(got_f)  # the duplicate merged, the hole closed
    again = meshlab_repair.repair(v, f, "box")  # the same child answers again
    np.testing.assert_array_equal(again[1], got_f)


@pytest.mark.parametrize("inject,problem", [("abort", "crashed (killed by signal 6"), ("hang", "longer than 2 s")])
def test_a_crashing_or_hanging_child_costs_one_mesh(fresh, inject, problem):
    v, f = _open_box()
    fresh.setenv(meshlab_repair.ENV_INJECT, inject)
    with pytest.raises(MeshError, match="box") as err:
        meshlab_repair.repair(v, f, "box", timeout=2)
    assert problem in err.value.problem
    fresh.delenv(meshlab_repair.ENV_INJECT)
    got_v, got_f = meshlab_repair.repair(v, f, "box")  # a new child
    assert _edges_twice(got_f)


def test_repairs_in_a_worker_thread_leave_the_heap_whole():
    """As `meshsom ingest --repair` runs: Zurich's buildings read and preprocessed with repairs in a worker
    thread, PROJ used there too. pymeshlab in that thread aborted the process at exit
    (malloc_consolidate: Qt's thread data freed twice); now the process ends cleanly."""
    script = textwrap.dedent(f"""
        import threading, pyproj
        from meshsom.io import read_file
        from meshsom.preprocess import PreprocessParams
        from pipelines.ingest import process_one
        def work():
            pyproj.Transformer.from_crs("EPSG:2056", "EPSG:4326")
            records = [process_one(m, PreprocessParams(repair=True))[0] for m in read_file({str(ZURICH)!r})]
            assert sum("repaired with pymeshlab" in " ".join(r["repairs"]) for r in records) > 0, records
            pyproj.Transformer.from_crs("EPSG:2056", "EPSG:4979")
        t = threading.Thread(target=work)
        t.start()
        t.join()
        print("done")
    """)
    run = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=600,
                         cwd=Path(__file__).resolve().parents[1])
    assert run.returncode == 0 and run.stdout.strip() == "done", run.stderr[-2000:]
