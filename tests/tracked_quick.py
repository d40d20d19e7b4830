"""A tracked run of configs/quick.yaml into a folder of its own (store, SQLite MLflow store, artifacts).

Shared by the tests of the MLflow model, ``meshsom runs`` and ``meshsom inspect``.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
CONFIG = ROOT / "configs" / "quick.yaml"
EXPERIMENT = "quick"  # the config's tracking.experiment


@dataclass(frozen=True)
class TrackedRun:
    """Where a tracked quick run left its results."""

    folder: Path
    store: Path
    uri: str
    experiment: str = EXPERIMENT


def tracked_quick_run(folder: Path) -> TrackedRun:
    """``meshsom run configs/quick.yaml`` on the NumPy backend, tracked in ``folder/mlflow.db``.

    The working directory is ``folder`` while it runs, so MLflow's default artifact root
    (``./mlruns``) lands there too.
    """
    from pipelines.cli import main

    store = folder / "quick.zarr"
    uri = f"sqlite:///{folder / 'mlflow.db'}"
    here = Path.cwd()
    os.chdir(folder)
    try:
        code = main(["run", str(CONFIG), "--store", str(store), "--tracking-uri", uri, "--backend", "numpy",
                     "--workers", "1"])
    finally:
        os.chdir(here)
    assert code == 0
    return TrackedRun(folder, store, uri)
