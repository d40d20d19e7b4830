"""``meshsom inspect STORE`` and ``meshsom runs`` on a tracked quick run, checked against the store and MLflow."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from tracked_quick import tracked_quick_run

pytestmark = pytest.mark.timeout(900)
MAPS = ("level1-default", "level1-bmuofn", "level2-bmuofn")


@pytest.fixture(scope="module")
def quick_run(tmp_path_factory):
    return tracked_quick_run(tmp_path_factory.mktemp("tracked"))


def _store_arrays(store: Path) -> set[str]:
    """Array paths of a zarr v3 store, from its zarr.json files (independent of zarr-python)."""
    out = set()
    for meta in store.rglob("zarr.json"):
        if json.loads(meta.read_text()).get("node_type") == "array":
            out.add(meta.parent.relative_to(store).as_posix())
    return out


def _store_metrics(store: Path, run: str) -> dict:
    return json.loads((store / "runs" / run / "zarr.json").read_text())["attributes"]["metrics"]


def _fits(text: str, width: int = 80) -> None:
    """Every line of ``text`` fits in ``width`` columns, but a ``store <path>`` line (as long as the
    test's temporary folder, which depends on the runner)."""
    long = [line for line in text.splitlines() if len(line) > width and not line.startswith("store /")]
    assert not long, long


def test_inspect_names_every_array_and_map(quick_run, capsys):
    from pipelines.cli import main

    assert main(["inspect", str(quick_run.store)]) == 0
    text = capsys.readouterr().out
    _fits(text)
    arrays = _store_arrays(quick_run.store)
    assert {"rings/level1", "rings/level2", "faces", "runs/level2-bmuofn/weights"} <= arrays
    lines = text.splitlines()
    for name in arrays:
        assert any(line.split()[:1] == [name] for line in lines), name
    assert "manifest: 24 inputs, 24 accepted, 0 rejected" in text
    assert any(line.split()[:3] == ["rings/level2", "636", "x"] and "float32" in line for line in lines)
    for run in MAPS:
        m = _store_metrics(quick_run.store, run)
        line = next(line for line in lines if line.split()[:1] == [run])
        assert "12x15" in line and "8/8" in line
        for key in ("t_error", "q_error", "qc_error"):
            assert f"{m[key]:.4f}" in line.split(), (run, key)
    assert "level 1: standard scaling" in text and "level 2: standard scaling" in text
    assert text.count("folds: alpha median") == 2


def test_inspect_json_matches_the_store(quick_run, capsys):
    from pipelines.cli import main

    assert main(["inspect", str(quick_run.store), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert {a["name"] for a in info["arrays"]} == _store_arrays(quick_run.store)
    assert {r["name"]: r["qc_error"] for r in info["runs"]} == {
        run: _store_metrics(quick_run.store, run)["qc_error"] for run in MAPS}
    stats = json.loads((quick_run.store / "rings" / "stats" / "zarr.json").read_text())["attributes"]
    assert [lv["folds"] for lv in info["levels"]] == [stats["folds_level1"], stats["folds_level2"]]


def test_inspect_counts_rejections_and_their_reasons(tmp_path, capsys):
    from meshsom.store import create_store, write_manifest
    from pipelines.cli import main

    store = tmp_path / "s.zarr"
    create_store(store)
    records = [{"id": f"m{i}", "source": "x.obj", "status": "accepted", "reason": "",
                "notes": [f"height from building:levels = {i + 2} storeys x 3 m"]} for i in range(3)]
    records += [{"id": f"open{i}", "source": "y.obj", "status": "rejected", "reason": f"not closed: {4 + 2 * i} boundary edges"}
                for i in range(2)]
    records += [{"id": "flat", "source": "z.obj", "status": "rejected", "reason": "zero volume " + "x" * 200}]
    write_manifest(store, records)
    assert main(["inspect", str(store)]) == 0
    text = capsys.readouterr().out
    _fits(text)
    assert "manifest: 6 inputs, 3 accepted, 3 rejected" in text
    assert "    2 x not closed: N boundary edges" in text  # one kind, whatever the count
    assert "first rejected: open0: not closed" in text
    assert "    3 x read: height from building:levels = N storeys x N m" in text  # the reader's notes, by kind
    assert "trained maps (0)" in text and "no ring levels encoded" in text


def test_runs_lists_every_map_with_its_mlflow_metrics(quick_run, capsys):
    from mlflow.tracking import MlflowClient

    from pipelines.cli import main

    client = MlflowClient(quick_run.uri)
    exp = client.get_experiment_by_name(quick_run.experiment)
    children = {r.info.run_id: r for r in client.search_runs([exp.experiment_id])
                if "mlflow.parentRunId" in r.data.tags}
    assert len(children) == len(MAPS)

    assert main(["runs", "--tracking-uri", quick_run.uri, "--json"]) == 0
    records = json.loads(capsys.readouterr().out)
    assert {r["run_id"] for r in records} == set(children)
    for rec in records:
        run = children[rec["run_id"]]
        for key in ("t_error", "q_error", "qc_error"):
            assert rec[key] == run.data.metrics[key]
        assert rec["config"] == "quick" and rec["epochs"] == 8 and rec["backend"] == "numpy"
        assert (rec["level"], rec["kernel"]) == (int(run.data.params["level"]), run.data.params["kernel"])
        assert rec["model_uri"] == run.data.tags["model_uri"]
        assert rec["seconds"] > 0

    assert main(["runs", "--tracking-uri", quick_run.uri, "--experiment", "quick"]) == 0
    text = capsys.readouterr().out
    _fits(text)
    lines = text.splitlines()
    assert lines[0].split()[:4] == ["config", "L", "kernel", "backend"]
    for rec in records:
        cells = [f"{rec[k]:.4f}" for k in ("t_error", "q_error", "qc_error")]
        assert any(line.split()[:3] == ["quick", str(rec["level"]), rec["kernel"]] and
                   all(c in line.split() for c in cells) for line in lines), rec

    assert main(["runs", "--tracking-uri", quick_run.uri, "--wide"]) == 0
    wide = capsys.readouterr().out
    for rec in records:
        assert rec["run_id"] in wide and rec["run"] in wide


def test_runs_names_the_experiments_it_has(quick_run, capsys):
    from pipelines.cli import main

    assert main(["runs", "--tracking-uri", quick_run.uri, "--experiment", "nope"]) == 2
    err = capsys.readouterr().err
    assert "no experiment 'nope'" in err and "quick" in err


def test_format_table_truncates_the_shrinkable_column_to_fit():
    from pipelines.runs_cmd import format_table

    rows = [["a" * 50, "1.0000", "2.0000"], ["b", "3.0000", "4.0000"]]
    text = format_table(["name", "x", "y"], rows, [False, True, True], width=30, shrink=[0])
    _fits(text, 30)
    assert text.splitlines()[2].startswith("a" * 13 + "~") and text.splitlines()[3].split() == ["b", "3.0000", "4.0000"]
