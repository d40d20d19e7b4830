#!/usr/bin/env bash
# Prepares, on this machine, what bench/gpu_device.sh carries to the GPU machine, so that a session
# lent a GPU can start its one device run at once:
#
#   .whl/                  cp312 x86-64 wheels of what the GPU image lacks: pyopencl (the version
#                          of constraints.txt) with the dependencies pip resolves for it, shapely,
#                          zarr (and theirs), and an XPySom wheel built from its sdist;
#   .gpu/paper-levels.npz  the paper run's level vectors (bench/gpu.py --export-levels), for
#                          table (c) and the training epochs.
#
# Both folders are git-ignored (.git/info/exclude) and carried by the device call:
#
#     run(command="bash bench/gpu_device.sh", carry=[".whl", ".gpu"], timeout_s=600)
#
# Then it checks the wheels as the GPU machine will use them: installed with --no-deps into a
# target folder of a Python 3.12 virtual environment that holds only what the image has of
# meshsom's needs (IMAGE_HAS, from the device tool's KINDS.md), it imports the modules the device
# run imports and collects its tests. Needs the project's .venv (README command b) and a Python
# 3.12 (PY312, default python3.12 or pyenv's). About a minute with a warm pip cache.
set -euo pipefail
cd "$(dirname "$0")/.."
PY=.venv/bin/python
if [ -z "${PY312:-}" ]; then  # the first Python 3.12 that runs (a pyenv shim may not)
    for candidate in python3.12 $(ls -d "${PYENV_ROOT:-$HOME/.pyenv}"/versions/3.12*/bin/python3.12 2>/dev/null); do
        if "$candidate" -c 'import sys; assert sys.version_info[:2] == (3, 12)' 2>/dev/null; then PY312=$candidate; break; fi
    done
fi
# the packages of the GPU image that the device run imports (KINDS.md lists them all)
IMAGE_HAS="numpy scipy pyyaml packaging typing-extensions pytest hypothesis psutil fsspec msgpack cloudpickle toolz"
PLATFORMS=(--platform manylinux_2_17_x86_64 --platform manylinux2014_x86_64 --platform manylinux_2_24_x86_64
           --platform manylinux_2_27_x86_64 --platform manylinux_2_28_x86_64 --platform manylinux_2_31_x86_64
           --platform manylinux_2_34_x86_64 --platform manylinux_2_35_x86_64 --platform manylinux1_x86_64)
pin() { grep -i "^$1==" constraints.txt | head -n1 || { echo "$1 is not pinned in constraints.txt" >&2; exit 1; }; }

for folder in .whl .gpu; do
    grep -qx "/$folder/" .git/info/exclude 2>/dev/null || echo "/$folder/" >> .git/info/exclude
done
rm -rf .whl && mkdir -p .whl .gpu

echo "== wheels for cp312 (pyopencl, shapely, zarr and what pip resolves for them)"
"$PY" -m pip download -q --only-binary=:all: --python-version 3.12 --implementation cp "${PLATFORMS[@]}" -d .whl \
    "$(pin pyopencl)" "$(pin shapely)" "$(pin zarr)" "$(pin pytools)" "$(pin platformdirs)" "$(pin numcodecs)" \
    "$(pin donfig)" "$(pin google-crc32c)"
# what the image has stays out: one version of a package, the image's
for name in $IMAGE_HAS; do
    stem=$(echo "$name" | tr '-' '_')
    rm -f .whl/"$stem"-*.whl .whl/"$name"-*.whl .whl/"$(echo "$stem" | sed 's/^pyyaml$/PyYAML/')"-*.whl
done
echo "== XPySom (an sdist: built into a pure-Python wheel)"
"$PY" -m pip wheel -q --no-deps -w .whl "$(pin xpysom)"
ls -1 .whl
du -sh .whl

echo "== the paper run's level vectors"
[ -e out/paper.zarr/manifest.json ] || .venv/bin/meshsom run configs/paper.yaml --overwrite
"$PY" bench/gpu.py --export-levels out/paper.zarr .gpu/paper-levels.npz

echo "== check: the wheels as the GPU machine installs them, on Python 3.12"
[ -n "${PY312:-}" ] || { echo "no Python 3.12 here (set PY312): the wheels are not checked"; exit 0; }
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
"$PY312" -m venv "$tmp/venv"
"$tmp/venv/bin/python" -m pip install -q $IMAGE_HAS
"$tmp/venv/bin/python" -m pip install -q --no-index --no-deps --no-compile --target "$tmp/site" .whl/*.whl
PYTHONPATH="$tmp/site:$PWD" "$tmp/venv/bin/python" - <<'PY'
import pyopencl, xpysom, shapely, zarr  # noqa: F401
import meshsom.bmu_opencl, meshsom.probe, meshsom.tuning, meshsom.config, meshsom.som  # noqa: F401
print("imports: ok (pyopencl", pyopencl.VERSION_TEXT + ")")
PY
PYTHONPATH="$tmp/site:$PWD" "$tmp/venv/bin/python" -m pytest -q --collect-only -p no:cacheprovider \
    tests/test_bmu.py tests/test_probe.py tests/test_epoch_sums.py tests/test_device_update.py | tail -n1
PYTHONPATH="$tmp/site:$PWD" "$tmp/venv/bin/python" bench/gpu.py --help > /dev/null && echo "bench/gpu.py: ok"
echo "ready: run(command=\"bash bench/gpu_device.sh\", carry=[\".whl\", \".gpu\"], timeout_s=600)"
