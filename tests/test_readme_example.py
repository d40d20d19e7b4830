"""The README's Python API example runs as written, and constraints.txt pins every dependency.

``python tests/test_readme_example.py > constraints.txt`` regenerates the constraints from the
installed environment (the closure of meshsom's requirements with every extra).
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
CONSTRAINTS = ROOT / "constraints.txt"
HEADER = """\
# The tested set of meshsom's dependencies (the closure of pyproject.toml with every extra), pinned.
# Reproducible install:  pip install -e '.[test]' -c constraints.txt   (the plain install stays unpinned)
# Made on Linux x86_64, Python 3.11; regenerate after changing dependencies:
#   python tests/test_readme_example.py > constraints.txt"""


def readme_block(heading: str) -> str:
    """The first ```python block after a README heading."""
    text = README.read_text()
    start = text.index(heading)
    match = re.compile(r"```python\n(.*?)```", re.S).search(text, start)
    assert match, f"no python block after {heading!r} in {README}"
    return match.group(1)


def test_python_api_example_runs_and_its_bmus_are_right(monkeypatch):
    code = readme_block("## Python API")
    monkeypatch.chdir(ROOT)  # the example names the bundled data relative to the repository root
    ns: dict = {}
    exec(compile(code, "README.md (Python API)", "exec"), ns)
    meshes, X, bmu, som, errors = ns["meshes"], ns["X"], ns["bmu"], ns["som"], ns["errors"]
    assert len(meshes) > 10 and not ns["rejected"]
    assert X.shape == (sum(len(m.faces) for m in meshes), 9)
    assert ns["umatrix"].shape == (12, 15)
    # independent: brute force over every variation and unit, in float64
    index, sign = ns["index"], ns["sign"]
    x = X.astype(np.float64)
    varied = sign[None] * x[:, index]  # (N, 6, 9)
    d2 = ((varied[:, :, None, :] - som.weights_.astype(np.float64)[None, None]) ** 2).sum(-1)  # (N, 6, M)
    best = d2.reshape(len(x), -1).min(axis=1)
    np.testing.assert_allclose(bmu.dist2, best, rtol=1e-4, atol=1e-6)
    np.testing.assert_allclose(errors["q_error"], np.sqrt(best).mean(), rtol=1e-4)
    assert set(errors) == {"t_error", "q_error", "qc_error"}


def _norm(name: str) -> str:
    return re.sub(r"[-_.]+", "-", name).lower()


def closure_pins() -> dict[str, str]:
    """Installed version of every distribution meshsom needs, with every extra (name -> version)."""
    from importlib.metadata import PackageNotFoundError, distribution

    from packaging.requirements import Requirement

    root = distribution("meshsom")
    extras = set(root.metadata.get_all("Provides-Extra") or [])
    pins: dict[str, str] = {}
    todo = [(r, extras) for r in root.requires or []]
    while todo:
        raw, active = todo.pop()
        req = Requirement(raw)
        if req.marker and not any(req.marker.evaluate({"extra": e}) for e in (active or {""})):
            continue
        name = _norm(req.name)
        if name in pins or name == "meshsom":
            continue
        try:
            dist = distribution(req.name)
        except PackageNotFoundError:
            continue  # an extra's dependency that is not installed here
        pins[name] = dist.version
        todo += [(r, set(req.extras)) for r in dist.requires or []]
    return dict(sorted(pins.items()))


def read_constraints() -> dict[str, str]:
    pins = {}
    for line in CONSTRAINTS.read_text().splitlines():
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        name, sep, version = line.partition("==")
        assert sep and version and re.fullmatch(r"[A-Za-z0-9_.\-]+", name), f"{CONSTRAINTS.name}: {line!r} is not NAME==VERSION"
        pins[_norm(name)] = version
    return pins


def test_constraints_pin_every_dependency_and_not_the_project():
    pytest.importorskip("packaging")
    pins = read_constraints()
    assert "meshsom" not in pins
    needed = closure_pins()
    missing = sorted(set(needed) - set(pins))
    assert not missing, f"{CONSTRAINTS.name} does not pin {missing}; regenerate: python tests/test_readme_example.py > constraints.txt"
    for direct in ("numpy", "zarr", "dask", "distributed", "mlflow", "pyopencl", "pytest"):
        assert direct in pins
    assert "pip install -e '.[test]' -c constraints.txt" in README.read_text()


if __name__ == "__main__":
    print(HEADER)
    print("\n".join(f"{name}=={version}" for name, version in closure_pins().items()))
