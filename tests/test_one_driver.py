"""One SOM driver: the same config gives the same codebook through SOM.fit, `meshsom train` and `meshsom run`."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import yaml

from meshsom.codebook import load_codebook
from meshsom.som import SOM
from meshsom.store import open_store
from meshsom.variations import variation_table
from pipelines.cli import main
from pipelines.train import load_level

QUICK = Path(__file__).resolve().parents[1] / "configs" / "quick.yaml"


@pytest.mark.parametrize("init", ["random", "pca"])
def test_same_codebook_through_every_entry_point(tmp_path, capsys, init):
    cfg = yaml.safe_load(QUICK.read_text())
    cfg["som"]["init"] = init
    cfg["som"]["epochs"] = 4
    cfg["train"] = [{"level": 1, "kernel": "bmuofn"}]
    cfg["encoding"]["levels"] = [1]
    cfg["domain"] = {"enabled": False}
    cfg["opencl"] = {"backend": "numpy"}
    cfg["dask"] = {"workers": 2, "shard_meshes": 6}
    cfg["tracking"] = {"enabled": False}
    store = tmp_path / "q.zarr"
    cfg["store"] = {"path": str(store)}
    config = tmp_path / "q.yaml"
    config.write_text(yaml.safe_dump(cfg))
    assert main(["run", str(config)]) == 0
    group = open_store(store)
    ran = load_codebook(group, "level1-bmuofn")
    ran_metrics = dict(group["runs"]["level1-bmuofn"].attrs["metrics"])

    capsys.readouterr()
    som_cfg = cfg["som"]
    assert main(["train", str(store), "--level", "1", "--kernel", "bmuofn", "--map", f"{som_cfg['rows']}x{som_cfg['cols']}",
                 "--epochs", str(som_cfg["epochs"]), "--seed", str(som_cfg["seed"]), "--init", init,
                 "--sigma-end", str(som_cfg["sigma_end"]), "--backend", "numpy", "--run", "again", "--json"]) == 0
    printed = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    trained = load_codebook(open_store(store), "again")
    assert np.array_equal(trained.weights, ran.weights)
    assert {k: printed[k] for k in ran_metrics} == ran_metrics

    X = load_level(open_store(store), 1)
    index, sign = variation_table(1, kernel="bmuofn")
    som = SOM(rows=som_cfg["rows"], cols=som_cfg["cols"], epochs=som_cfg["epochs"], sigma_end=som_cfg["sigma_end"],
              init=init, random_state=som_cfg["seed"], backend="numpy").fit(X, index, sign)
    assert np.array_equal(som.weights_, ran.weights)
    assert som.evaluate(X) == ran_metrics
