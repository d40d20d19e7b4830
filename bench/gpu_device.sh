#!/usr/bin/env bash
# The GPU check of issue 13, as one command on the GPU machine (NVIDIA H200, Python 3.12 with
# numpy, torch, CuPy and pytest; no pyopencl, nothing downloadable). Run from the repository
# root with the wheels in .whl/ (pyopencl and its pure dependencies, the XPySom wheel) and the
# paper's level vectors in .gpu/paper-levels.npz, both made here first by bench/gpu_prepare.sh
# (about a minute), writes everything to $OUT/gpu.log. As the device tool's command, carrying
# [".whl", ".gpu"], with timeout_s 600:
#
#     bash bench/gpu_device.sh
#
# Budget: at most 45 s of memory report, 60 s of diagnosis and 40 s of ptxas, 250 s of benchmark
# and 170 s of tests (BENCH_TIMEOUT, TEST_TIMEOUT, CPU_TEST_TIMEOUT): 565 s, under the 10 minutes
# of one run.
# 1. installs the wheels into /tmp/site (pyopencl and its pure dependencies, XPySom, shapely for
# meshsom.config); 2. registers NVIDIA's OpenCL library with the ICD loader bundled in the
# pyopencl wheel (ocl-icd: OCL_ICD_VENDORS names a folder of .icd files); 3. lists the OpenCL
# devices; 4. bench/gpu.py --memory-report (the memory each layout's context holds), --diagnose
# (the pass timed with its epilogue or staging left out; the PTX, compiled by ptxas into SASS and
# its instruction mix counted) and --autotune --registers --levels (the compiler's register
# report and the time of every gemm candidate, tables a, c, b with the best); 5. the BMU, probe,
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
levels=.gpu/paper-levels.npz
[ -e "$levels" ] && levels_arg="--levels $levels" || { echo "no $levels: table (c) skipped"; levels_arg=""; }
step "bench/gpu.py --device nvidia --memory-report"
timeout 45 python3 bench/gpu.py --device nvidia --memory-report

step "bench/gpu.py --device nvidia --diagnose \$OUT/diag (stage timing; the gpu layout's PTX, its SASS instruction mix)"
timeout 60 python3 bench/gpu.py --device nvidia --diagnose "$OUT/diag"
# ptxas / nvdisasm / cuobjdump: a CUDA toolkit, else the copies Triton (PyTorch's) bundles
triton_bin=$(python3 -c 'import os, triton; print(os.path.join(os.path.dirname(triton.__file__), "backends", "nvidia", "bin"))' 2>/dev/null)
PATH=$PATH:/usr/local/cuda/bin${triton_bin:+:$triton_bin}
ptx_args=$(for p in "$OUT"/diag/*.ptx; do [ -e "$p" ] && printf -- '--ptx %s ' "$p"; done)
[ -n "$ptx_args" ] && timeout 30 python3 bench/gpu_sass.py $ptx_args --keep /tmp/sass
for ptx in "$OUT"/diag/*.ptx; do
    [ -e "$ptx" ] || continue
    cubin=/tmp/$(basename "${ptx%.ptx}").cubin
    if timeout 20 ptxas -arch=sm_90a -v "$ptx" -o "$cubin" 2>&1 | grep -E "bmu_of_n_gemm'|registers|spill" | head -n 6 \
            && cuobjdump -sass "$cubin" > "${ptx%.ptx}.sass" 2>/dev/null; then
        echo "SASS instruction mix of $(basename "$ptx") (all kernels of the program):"
        grep -oE '\b(FFMA|FMUL|FADD|FSETP|FSEL|LDS|LDG|STS|STG|BAR|ISETP|IMAD|IADD3|LEA|SEL|BRA|LDL|STL|SHF|LOP3|MOV)(\.[A-Z0-9_]+)*' \
            "${ptx%.ptx}.sass" | sort | uniq -c | sort -rn | head -n 16
    else
        echo "no ptxas / cuobjdump here: $ptx comes back as it is"
    fi
done
step "bench/gpu.py --device nvidia --autotune --registers --no-old $levels_arg"
timeout ${BENCH_TIMEOUT:-250} python3 bench/gpu.py --device nvidia --autotune --registers --no-old $levels_arg

# The "cpu" layouts stage up to panel_bytes (256 KB) of rows in private memory per work-item, and
# NVIDIA's driver reserves a kernel's private memory for every work-item the GPU can hold, for the
# context's lifetime (bench/gpu.py --registers prints it): two such contexts fill an H200. So
# their tests run in one process, the others in 4.
tests="tests/test_bmu.py tests/test_probe.py tests/test_epoch_sums.py tests/test_device_update.py"
step "tests on the NVIDIA device, all but the 'cpu' layouts (4 pytest workers): $tests"
timeout ${TEST_TIMEOUT:-90} python3 -m pytest -q -p no:cacheprovider -n 4 -k "not cpu" $tests
step "tests of the 'cpu' layouts on the NVIDIA device (one process)"
timeout ${CPU_TEST_TIMEOUT:-80} python3 -m pytest -q -p no:cacheprovider -k "cpu" $tests
step "done"
