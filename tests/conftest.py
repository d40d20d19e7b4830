"""Shared fixtures: tiny analytic meshes and paths to the bundled data."""

from __future__ import annotations

import os
import sys
from pathlib import Path

import numpy as np
import pytest

# One BLAS/OpenCL thread per test process: the machines have 2 cores.
os.environ.setdefault("POCL_MAX_PTHREAD_COUNT", "1")

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT / "data" / "real"


@pytest.fixture(autouse=True)
def _mlflow_tracking_uri_left_as_found():
    """A test that sets MLflow's process-wide tracking URI (``mlflow.set_tracking_uri``, which sets
    ``MLFLOW_TRACKING_URI`` too) leaves both as it found them: otherwise a later test's run in the same worker
    process logs into that test's store (a ``meshsom run`` without ``tracking.uri`` takes MLflow's URI)."""
    before = os.environ.get("MLFLOW_TRACKING_URI")
    yield
    utils = sys.modules.get("mlflow.tracking._tracking_service.utils")
    if utils is not None and getattr(utils, "_tracking_uri", None) is not None:
        import mlflow

        mlflow.set_tracking_uri(None)  # MLflow's own way back to no URI set (it unsets the variable too)
    if before is None:
        os.environ.pop("MLFLOW_TRACKING_URI", None)
    else:
        os.environ["MLFLOW_TRACKING_URI"] = before


@pytest.fixture
def data_dir() -> Path:
    return DATA


def box(sx=1.0, sy=1.0, sz=1.0) -> tuple[np.ndarray, np.ndarray]:
    """An axis-aligned box of 12 outward triangles, corner at the origin.

    Returns
    -------
    vertices : (8, 3) float64
    faces : (12, 3) int64
    """
    v = np.array(
        [[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0, 0, 1], [1, 0, 1], [1, 1, 1], [0, 1, 1]], np.float64
    ) * [sx, sy, sz]
    f = np.array(
        [[0, 2, 1], [0, 3, 2], [4, 5, 6], [4, 6, 7], [0, 1, 5], [0, 5, 4],
         [1, 2, 6], [1, 6, 5], [2, 3, 7], [2, 7, 6], [3, 0, 4], [3, 4, 7]], np.int64
    )
    return v, f


@pytest.fixture
def cube():
    return box()


@pytest.fixture
def fresh_verdicts(tmp_path, monkeypatch):
    """A verdict cache of the test's own (kernel probes run anew), no injected failures.

    Yields the verdict folder (:func:`meshsom.probe.cache_dir`).
    """
    from meshsom import probe
    from meshsom.caches import ENV_CACHE

    monkeypatch.setenv(ENV_CACHE, str(tmp_path / "cache"))
    monkeypatch.delenv(probe.ENV_INJECT, raising=False)
    monkeypatch.setattr(probe, "_MEMO", {})
    yield probe.cache_dir()
