#!/usr/bin/env bash
# The GPU check of issue 13, as one command on the GPU machine (NVIDIA H200, Python 3.12 with
# numpy, torch, CuPy and pytest; no pyopencl, nothing downloadable). Run from the repository
# root with the wheels in .whl/ (pyopencl and its pure dependencies, the XPySom wheel; see
# the note of the GPU run) and the paper's level vectors in .gpu/paper-levels.npz (bench/gpu.py
# --export-levels), writes everything to $OUT/gpu.log. As the device tool's command, carrying
# [".whl", ".gpu"], with timeout_s 600:
#
#     bash bench/gpu_device.sh
#
# Budget: at most 90 s of layout verdicts, 360 s of benchmark and 120 s of tests, under the 10
# minutes of one run.
# 1. installs the wheels into /tmp/site; 2. registers NVIDIA's OpenCL library with the ICD
# loader bundled in the pyopencl wheel (ocl-icd: OCL_ICD_VENDORS names a folder of .icd
# files); 3. lists the OpenCL devices; 4. every kernel layout's probe verdict and GFLOP/s;
# 5. bench/gpu.py --device nvidia --autotune --levels (tables a, b, c); 6. the BMU, probe and
# epoch-sums and device-update tests on the NVIDIA device.
set -u
export PYTHONUNBUFFERED=1
OUT=${OUT:-/tmp/out}
mkdir -p "$OUT"
LOG="$OUT/gpu.log"
exec > >(tee -a "$LOG") 2>&1
started=$(date +%s)
step() { echo; echo "=== $* ($(( $(date +%s) - started )) s)"; }

step "install wheels"
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl
export PYTHONPATH=/tmp/site:$PWD

step "register NVIDIA's OpenCL library"
lib=/usr/lib/libnvidia-opencl.so.1
if [ ! -e "$lib" ]; then
    found=$(ls /usr/lib*/libnvidia-opencl.so* /usr/lib*/*/libnvidia-opencl.so* /usr/local/nvidia/lib*/libnvidia-opencl.so* 2>/dev/null
            ldconfig -p 2>/dev/null | awk '/libnvidia-opencl/ {print $NF}')
    echo "no $lib; found: ${found:-nothing}"
    lib=$(echo "$found" | grep -m1 'so.1$' || echo "$found" | head -n1)
fi
echo "OpenCL library: $lib"
mkdir -p /tmp/icd && echo "$lib" > /tmp/icd/nvidia.icd
export OCL_ICD_VENDORS=/tmp/icd
nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv,noheader 2>/dev/null
python3 -c 'import sys, numpy; print("python", sys.version.split()[0], "numpy", numpy.__version__)'
python3 -c 'import torch, cupy; print("torch", torch.__version__, "cupy", cupy.__version__)' 2>&1 | tail -n1

step "OpenCL devices"
python3 -c 'import pyopencl as cl; print("pyopencl", cl.VERSION_TEXT); [print(p.name, "/", d.name, "/", d.version, "/ CUs", d.max_compute_units, "/ local", d.local_mem_size) for p in cl.get_platforms() for d in p.get_devices()]' \
    || { echo "no platform through OCL_ICD_VENDORS; trying OCL_ICD_FILENAMES"; unset OCL_ICD_VENDORS; export OCL_ICD_FILENAMES=$lib;
         python3 -c 'import pyopencl as cl; print([(p.name, [d.name for d in p.get_devices()]) for p in cl.get_platforms()])'; }

# the tests take their device from PYOPENCL_CTX (a name substring); they skip when it matches none
export PYOPENCL_CTX=nvidia MESHSOM_PROBE_TIMEOUT=60
step "kernel layout verdicts on the NVIDIA device (meshsom doctor's check: child-process probes, GFLOP/s)"
timeout 90 python3 -c 'from meshsom.bmu_opencl import get_context; from pipelines.doctor import kernel_verdicts
[print(v) for v in kernel_verdicts(get_context("nvidia").devices[0])]'

levels=.gpu/paper-levels.npz
[ -e "$levels" ] && levels_arg="--levels $levels" || { echo "no $levels: table (c) skipped"; levels_arg=""; }
step "bench/gpu.py --device nvidia --autotune $levels_arg"
timeout 360 python3 bench/gpu.py --device nvidia --autotune $levels_arg

step "tests: tests/test_bmu.py, test_probe.py, test_epoch_sums.py and test_device_update.py on the NVIDIA device (8 pytest workers)"
timeout 120 python3 -m pytest -q -p no:cacheprovider -n 8 tests/test_bmu.py tests/test_probe.py tests/test_epoch_sums.py tests/test_device_update.py
step "done"
