#!/usr/bin/env bash
# The GPU check of issue 13, as one command on the GPU machine (NVIDIA H200, Python 3.12 with
# numpy, torch, CuPy and pytest; no pyopencl, nothing downloadable). Run from the repository
# root with the wheels in .whl/ (pyopencl and its pure dependencies, the XPySom wheel; see
# the note of the GPU run), writes everything to $OUT/gpu.log:
#
#     bash bench/gpu_device.sh
#
# Budget: at most 100 + 120 s of tests and 300 s of benchmark, under the 10 minutes of one run.
# 1. installs the wheels into /tmp/site; 2. registers NVIDIA's OpenCL library with the ICD
# loader bundled in the pyopencl wheel (ocl-icd: OCL_ICD_VENDORS names a folder of .icd
# files); 3. lists the OpenCL devices; 4. the BMU tests on the NVIDIA device (the gemm layout
# with the GPU tiling first, then the whole file); 5. bench/gpu.py --device nvidia --autotune.
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
export PYOPENCL_CTX=nvidia
step "tests: the gemm layout and the ties, NVIDIA device"
timeout 100 python3 -m pytest -q -p no:cacheprovider tests/test_bmu.py -x -k "gemm or ties or default or float64"
step "tests: tests/test_bmu.py, NVIDIA device"
timeout 120 python3 -m pytest -q -p no:cacheprovider tests/test_bmu.py -x

step "bench/gpu.py --device nvidia --autotune"
timeout 300 python3 bench/gpu.py --device nvidia --autotune
step "done"
