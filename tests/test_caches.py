"""Cache folders that cannot be written (a container user whose home is /nonexistent, a read-only
home): PoCL showed no device, pyopencl's probes raised, meshsom's verdict cache stopped the run.
Now each is moved to a private temporary folder with one warning (meshsom/caches.py).

An unwritable folder here is one under /proc, where nobody (root included) may create one.
"""

from __future__ import annotations

import json
import logging
import os
import subprocess
import sys
from pathlib import Path

import pytest

from meshsom import caches

ROOT = Path(__file__).resolve().parents[1]
NOWHERE = "/proc/meshsom-no-such-home"


@pytest.fixture
def fresh(monkeypatch, tmp_path):
    """A process state as before the first check, and a temporary folder of the test's own."""
    monkeypatch.setattr(caches, "_CHECKED", [])
    caches._root.cache_clear()
    monkeypatch.setattr(caches.tempfile, "tempdir", str(tmp_path / "tmp"))
    (tmp_path / "tmp").mkdir()
    for name in ("XDG_CACHE_HOME", "XDG_CONFIG_HOME", "MPLCONFIGDIR", caches.ENV_POCL_CACHE, caches.ENV_CACHE,
                 "MESHSOM_CLIENT_SAYS_FALLBACK"):
        monkeypatch.delenv(name, raising=False)
    yield tmp_path
    caches._root.cache_clear()


def test_a_writable_home_changes_nothing(fresh, monkeypatch):
    monkeypatch.setenv("HOME", str(fresh / "home"))
    assert caches.ensure_user_cache() == {}
    assert "XDG_CACHE_HOME" not in os.environ
    assert caches.meshsom_cache_root() == fresh / "home" / ".cache" / "meshsom"
    assert caches.ensure_user_cache() == {}  # once per process


def test_an_unwritable_home_moves_the_caches_with_one_warning(fresh, monkeypatch, caplog):
    monkeypatch.setenv("HOME", NOWHERE)
    with caplog.at_level(logging.INFO, logger="meshsom.caches"):
        changed = caches.ensure_user_cache()
        root = caches.meshsom_cache_root()
    uid = os.getuid()
    assert changed["XDG_CACHE_HOME"] == os.environ["XDG_CACHE_HOME"] == str(fresh / "tmp" / f"meshsom-{uid}" / "xdg-cache")
    assert changed["MPLCONFIGDIR"] == str(fresh / "tmp" / f"meshsom-{uid}" / "matplotlib")
    assert root == Path(changed["XDG_CACHE_HOME"]) / "meshsom" and caches.unwritable(root) is None
    said = [r for r in caplog.records if r.levelno == logging.WARNING]
    assert len(said) == 1 and f"{NOWHERE}/.cache cannot be written" in said[0].message, said
    assert "XDG_CACHE_HOME=" in said[0].message


@pytest.mark.parametrize("variable", [caches.ENV_CACHE, caches.ENV_POCL_CACHE])
def test_a_cache_variable_naming_an_unwritable_folder_is_replaced(fresh, monkeypatch, caplog, variable):
    monkeypatch.setenv("HOME", str(fresh / "home"))
    monkeypatch.setenv(variable, f"{NOWHERE}/cache")
    with caplog.at_level(logging.WARNING, logger="meshsom.caches"):
        caches.ensure_user_cache()
        root = caches.meshsom_cache_root()
    said = [r.message for r in caplog.records]
    assert len(said) == 1 and f"{NOWHERE}/cache cannot be written" in said[0], said
    if variable == caches.ENV_CACHE:
        assert root == fresh / "tmp" / f"meshsom-{os.getuid()}" / "cache"
    else:
        assert os.environ[variable] == str(fresh / "tmp" / f"meshsom-{os.getuid()}" / "pocl")


def test_the_workers_of_a_local_cluster_say_it_at_info(fresh, monkeypatch, caplog):
    monkeypatch.setenv("HOME", NOWHERE)
    monkeypatch.setenv("MESHSOM_CLIENT_SAYS_FALLBACK", "1")
    with caplog.at_level(logging.INFO, logger="meshsom.caches"):
        caches.ensure_user_cache()
    assert [r.levelno for r in caplog.records] == [logging.INFO]


def test_a_temporary_folder_of_another_user_is_not_used(fresh, monkeypatch):
    other = fresh / "tmp" / f"meshsom-{os.getuid()}"
    other.mkdir()
    real_stat = Path.stat

    def foreign(self, *a, **kw):
        st = real_stat(self, *a, **kw)
        if self == other:
            return os.stat_result((st.st_mode, st.st_ino, st.st_dev, st.st_nlink, st.st_uid + 1, *tuple(st)[5:]))
        return st

    monkeypatch.setattr(Path, "stat", foreign)
    folder = caches.private_temp("xdg-cache")
    assert folder.parent == fresh / "tmp" and folder.name.startswith("meshsom-xdg-cache-")


SCRIPT = """
import json
import numpy as np
from meshsom.bmu import find_bmus
from meshsom.bmu_opencl import list_devices
from meshsom.variations import variation_table
rng = np.random.default_rng(0)
X = rng.normal(size=(500, 9)).astype(np.float32)
W = rng.normal(size=(60, 9)).astype(np.float32)
index, sign = variation_table(1)
devices = [name for _, name, _ in list_devices()]
out = {"devices": devices}
if devices:
    got, engine = find_bmus(X, W, index, sign, backend="opencl")
    ref, _ = find_bmus(X, W, index, sign, backend="numpy")
    out.update(engine=engine.backend, same=bool((got.unit == ref.unit).all() and (got.variation == ref.variation).all()))
print(json.dumps(out))
"""


def _run(env: dict) -> dict:
    out = subprocess.run([sys.executable, "-c", SCRIPT], capture_output=True, text=True, env=env, cwd=ROOT, timeout=600)
    assert out.returncode == 0, out.stderr[-3000:]
    return json.loads(out.stdout.strip().splitlines()[-1]) | {"stderr": out.stderr}


def test_opencl_runs_with_an_unwritable_home(tmp_path):
    """The same devices as with a writable home, and the OpenCL search (probed in a child process,
    launched through pyopencl's invoker cache) gives the NumPy backend's units and variations."""
    base = {k: v for k, v in os.environ.items() if k not in ("XDG_CACHE_HOME", caches.ENV_CACHE, caches.ENV_POCL_CACHE)}
    home = _run({**base, "HOME": str(tmp_path / "home")})
    if not home["devices"]:
        pytest.skip("no OpenCL device here")
    (tmp_path / "tmp").mkdir()
    nowhere = _run({**base, "HOME": NOWHERE, "TMPDIR": str(tmp_path / "tmp")})
    assert nowhere["devices"] == home["devices"]
    assert nowhere["engine"] == "opencl" and nowhere["same"] and home["same"]
    assert nowhere["stderr"].count("cannot be written") == 1, nowhere["stderr"]
