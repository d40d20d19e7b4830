"""`meshsom run` as a user starts it: --set overrides, paths relative to the config file, inputs checked
before a store exists, and the MLflow conventions (names, tags, params, metrics), read back with
MlflowClient from a local SQLite tracking store."""

from __future__ import annotations

import subprocess
from pathlib import Path

import numpy as np
import pytest
import yaml

from meshsom.config import to_dict
from meshsom.store import open_store
from pipelines.cli import main
from pipelines.settings import load_config

ROOT = Path(__file__).resolve().parents[1]
MAPS = ("level1-default", "level1-bmuofn", "level2-bmuofn")
SETS = ["--set", "som.epochs=2", "--set", "domain.enabled=false", "--set", "dask.workers=2",
        "--set", "dask.dashboard=false", "--set", "tracking.experiment=cli"]
EPOCHS = 2


def _write_config(folder: Path, corpus: str, store: str = "../out/q.zarr") -> Path:
    """configs/quick.yaml with its corpus and store replaced, in ``folder``."""
    data = yaml.safe_load((ROOT / "configs" / "quick.yaml").read_text())
    data["corpus"] = yaml.safe_load(corpus)
    data["store"] = {"path": store}
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / "c.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def _cube_obj(path: Path) -> None:
    import trimesh

    trimesh.creation.box(extents=(2.0, 3.0, 5.0)).export(path)


@pytest.fixture(scope="module")
def tracked(tmp_path_factory):
    """One tracked quick run (2 epochs), started from a working directory that is not the config's."""
    tmp = tmp_path_factory.mktemp("cli")
    blocks = tmp / "data" / "blocks"
    blocks.mkdir(parents=True)
    _cube_obj(blocks / "cube.obj")
    (blocks / "notes.txt").write_text("not a mesh")
    config = _write_config(tmp / "cfgs", "{paths: [../data/blocks], generator: {n_blocks: 12, seed: 0}}")
    elsewhere = tmp / "elsewhere"
    elsewhere.mkdir()
    uri = f"sqlite:///{tmp / 'mlflow.db'}"
    mp = pytest.MonkeyPatch()
    mp.chdir(elsewhere)
    mp.setenv("MLFLOW_TRACKING_URI", uri)
    try:
        import contextlib
        import io

        out = io.StringIO()
        with contextlib.redirect_stdout(out):
            rc = main(["run", str(config), *SETS])
        with contextlib.redirect_stdout(io.StringIO()):
            rc_resume = None if rc else main(["run", str(config), *SETS, "--resume"])
    finally:
        mp.undo()
    return {"tmp": tmp, "config": config, "uri": uri, "rc": rc, "out": out.getvalue(), "rc_resume": rc_resume,
            "store": tmp / "out" / "q.zarr"}


def _runs(tracked):
    from mlflow.tracking import MlflowClient

    client = MlflowClient(tracked["uri"])
    exp = client.get_experiment_by_name("cli")
    runs = client.search_runs([exp.experiment_id])
    parents = [r for r in runs if "mlflow.parentRunId" not in r.data.tags]
    children = {r.data.tags["map"]: r for r in runs if "mlflow.parentRunId" in r.data.tags}
    return client, parents, children


def test_run_from_another_directory_finds_its_inputs_and_lists_skipped_files(tracked):
    assert tracked["rc"] == 0, tracked["out"]
    store = tracked["store"]
    assert store.exists() and not (tracked["tmp"] / "elsewhere" / "out").exists()
    g = open_store(store)
    ids = list(g["meshes"]["ids"][:])
    assert any(str(i).startswith("cube.obj") for i in ids) and len(ids) == 13
    assert "skipped: notes.txt (unknown file type '.txt'" in tracked["out"]


def test_terminal_output_fits_80_columns(tracked):
    lines = [ln for ln in tracked["out"].splitlines() if str(tracked["tmp"]) not in ln]  # paths are as long as they are
    assert len(lines) > 8
    assert max(len(ln) for ln in lines) <= 80, max(lines, key=len)


def test_set_overrides_land_in_the_resolved_config_and_mlflow_params(tracked):
    client, parents, children = _runs(tracked)
    assert len(parents) == 1
    parent = parents[0]
    params = parent.data.params
    assert params["som.epochs"] == "2" and params["domain.enabled"] == "False" and params["dask.workers"] == "2"
    assert params["store.path"] == "../out/q.zarr" and params["corpus.paths"] == "['../data/blocks']"
    assert "seed" not in params and "som.training" not in params and "som.learning_rate" not in params
    # the config artifact is the resolved configuration, not the file
    local = client.download_artifacts(parent.info.run_id, "config/config.yaml", str(tracked["tmp"]))
    logged = yaml.safe_load(Path(local).read_text())
    expected = to_dict(load_config(tracked["config"], sets=[s for s in SETS if s != "--set"]))
    assert logged == yaml.safe_load(yaml.safe_dump(expected)) and logged["som"]["epochs"] == 2
    assert logged["som"]["rows"] == 12 and logged["domain"]["enabled"] is False
    # no param holds a local absolute path
    for run in [parent, *children.values()]:
        assert not [v for v in run.data.params.values() if str(tracked["tmp"]) in v], run.info.run_name


def test_mlflow_names_tags_params(tracked):
    _, (parent,), children = _runs(tracked)
    info = open_store(tracked["store"]).attrs["mlflow"]
    short = info["short_id"]
    assert parent.info.run_name == f"quick/{short}" and len(short) == 6
    assert sorted(children) == sorted(MAPS)
    commit = subprocess.run(["git", "rev-parse", "HEAD"], capture_output=True, text=True, cwd=ROOT).stdout.strip()
    tags = parent.data.tags
    assert tags["mlflow.source.name"] == "meshsom run c.yaml" and tags["mlflow.source.type"] == "LOCAL"
    if commit:
        assert tags["mlflow.source.git.commit"] == commit and "git_commit" not in tags
    assert tags["store"] == str(tracked["store"])
    for name, run in children.items():
        assert run.info.run_name == f"quick/{name}/{short}"
        assert run.data.tags["mlflow.parentRunId"] == parent.info.run_id
        assert run.data.params["codebook"] == f"runs/{name}" and run.data.params["epochs"] == "2"
        assert run.info.status == "FINISHED"
    assert parent.info.status == "FINISHED"


def test_metrics_history_final_timing_and_parent_summary_each_once(tracked):
    """Per epoch at step=epoch, the final errors at step=epochs, once each, also after --resume."""
    assert tracked["rc_resume"] == 0
    client, parents, children = _runs(tracked)
    assert len(parents) == 1 and len(children) == len(MAPS)  # the resume continued the same runs
    parent = parents[0]
    g = open_store(tracked["store"])
    for name, run in children.items():
        attrs = g["runs"][name].attrs
        for key in ("t_error", "q_error", "qc_error"):
            history = client.get_metric_history(run.info.run_id, key)
            assert sorted(m.step for m in history) == list(range(EPOCHS + 1)), (name, key)
            by_step = {m.step: m.value for m in history}
            assert by_step[EPOCHS] == pytest.approx(attrs["metrics"][key])
            for h in attrs["result"]["history"]:
                assert by_step[h["epoch"]] == pytest.approx(h[key])
            summary = client.get_metric_history(parent.info.run_id, f"{name}.{key}")
            assert len(summary) == 1 and summary[0].value == pytest.approx(attrs["metrics"][key])
        level = int(name[5])
        triangles = g["rings"][f"level{level}"].shape[0]
        seconds = attrs["result"]["seconds"]
        perf = {k: client.get_metric_history(run.info.run_id, k)
                for k in ("wall_seconds", "seconds_per_epoch", "triangles_per_second")}
        assert all(len(v) == 1 for v in perf.values()), name
        assert perf["seconds_per_epoch"][0].value == pytest.approx(seconds / EPOCHS)
        assert perf["triangles_per_second"][0].value == pytest.approx(triangles * EPOCHS / seconds)
        assert perf["wall_seconds"][0].value >= seconds
    assert len(client.get_metric_history(parent.info.run_id, "total_seconds")) == 1


def test_bad_set_is_the_yaml_error_with_source_set(tmp_path, capsys):
    config = _write_config(tmp_path / "cfgs", "{generator: {n_blocks: 4}}")
    assert main(["run", str(config), "--set", "som.epochs=x", "--no-tracking"]) == 2
    err = capsys.readouterr().err
    assert "error: --set: som.epochs: expected an integer, received 'x'" in err
    text = config.read_text().replace("epochs: 8", "epochs: x")
    config.write_text(text)
    assert main(["run", str(config), "--no-tracking"]) == 2
    assert f"error: {config}: som.epochs: expected an integer, received 'x'" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("corpus, why", [
    ("{paths: [../missing]}", "no such file or folder"),
    ("{paths: [../empty], generator: {n_blocks: 4}}", "folder holds no readable mesh"),
])
def test_missing_or_empty_input_leaves_no_store(tmp_path, capsys, corpus, why):
    (tmp_path / "empty").mkdir()
    (tmp_path / "empty" / "notes.txt").write_text("nothing to read")
    config = _write_config(tmp_path / "cfgs", corpus)
    assert main(["run", str(config), "--no-tracking"]) == 2
    err = capsys.readouterr().err
    assert why in err and "corpus.paths" in err and "c.yaml" in err
    assert not (tmp_path / "out").exists()


def test_nothing_readable_removes_the_store_so_a_plain_rerun_works(tmp_path, capsys):
    (tmp_path / "bad").mkdir()
    (tmp_path / "bad" / "broken.obj").write_text("v 0 0 0\nf 1 2 3\n")
    config = _write_config(tmp_path / "cfgs", "{paths: [../bad]}")
    for _ in range(2):  # the second attempt is not blocked by a leftover store
        assert main(["run", str(config), "--no-tracking", "--set", "dask.workers=1"]) == 2
        err = capsys.readouterr().err
        assert "nothing could be ingested" in err and "broken.obj" in err
        assert not (tmp_path / "out" / "q.zarr").exists()
