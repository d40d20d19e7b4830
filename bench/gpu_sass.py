"""The "gpu" layout's kernel compiled for an NVIDIA GPU on a machine without one: what the compiler
makes of it (registers, spills, shared memory) and the instruction mix of its loops.

    python bench/gpu_sass.py [--arch sm_90] [--workload n,D ...] [--candidates JSON] [--ptx FILE ...]

Lent GPU time is scarce (issue 13): a change to kernels/bmu_gpu.cl is looked at here first. The
OpenCL source (kernels/bmu_common.cl and kernels/bmu_gpu.cl with the layout's defines, as
meshsom.bmu_opencl builds it for a GPU) is compiled by clang for ``nvptx64-nvidia-nvcl`` into PTX,
by NVIDIA's ptxas into SASS for ``--arch`` (sm_90: the H200 of issue 13), and listed by nvdisasm
(or cuobjdump). Tools: clang of LLVM 14 or later with its NVPTX target (the LLVM packages of most
distributions), ptxas and nvdisasm from a CUDA toolkit or the pip wheels ``nvidia-cuda-nvcc-cu12``
and ``nvidia-cuda-nvdisasm``; a missing tool ends the script with one line naming it (exit 2).
clang's OpenCL target has no builtin library without libclc: :data:`OPENCL_BUILTINS` maps the few
builtins the kernel calls onto NVVM's.

This is clang's front end, not NVIDIA's OpenCL compiler: ptxas allocates the registers and
schedules in both, but the counts differ (NVIDIA's driver compiled the default of 2026-11-30 into
121 registers, this into 173). Compare variants with each other here and confirm on the GPU
(``bench/gpu.py --registers``). ``--ptx FILE`` reads a PTX that NVIDIA's driver wrote
(``bench/gpu.py --diagnose DIR``) through the same ptxas and report.

Per workload (n variations x D) and candidate:

- registers, spill bytes and shared memory of ``bmu_of_n_gemm``;
- the chunk loop (the innermost loop with FFMA: a chunk of KT dimensions multiplied, the next one
  staged): instructions, FFMA;
- per unit tile on the common path, where no row's best or second changes (the ``MESHSOM_ABLATE=1``
  build, whose epilogue issues as many instructions: one FADD per distance for one FSETP):
  instructions = the tile loop + the chunk loop's further iterations, and the share of them that
  are the pass's own FFMA (RM x RN x D per tile: the 2 N n M D flops of its TFLOP/s) -- the
  issue-slot bound on the pass's fraction of the FP32 rate (one warp instruction per cycle and
  scheduler; an FP32 GEMM issues little besides its FFMA).
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import re
import shutil
import subprocess
import sys
import tempfile
from dataclasses import dataclass, replace
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402

#: (n, D) compiled by default: the passes of bench/gpu.py's tables.
WORKLOADS = [(1, 9), (6, 9), (3, 36), (3, 144)]

#: OpenCL builtins the "gemm" program calls, for clang's nvptx64-nvidia-nvcl target without libclc
#: (NVVM's special registers and barrier; fma as an expression, contracted under -cl-mad-enable).
OPENCL_BUILTINS = r"""
#define get_local_id(i) ((i) == 0 ? __nvvm_read_ptx_sreg_tid_x() : __nvvm_read_ptx_sreg_tid_y())
#define get_group_id(i) ((i) == 0 ? __nvvm_read_ptx_sreg_ctaid_x() : __nvvm_read_ptx_sreg_ctaid_y())
#define get_num_groups(i) ((i) == 0 ? __nvvm_read_ptx_sreg_nctaid_x() : __nvvm_read_ptx_sreg_nctaid_y())
#define get_local_size(i) ((i) == 0 ? __nvvm_read_ptx_sreg_ntid_x() : __nvvm_read_ptx_sreg_ntid_y())
#define get_global_id(i) (get_group_id(i) * get_local_size(i) + get_local_id(i))
#define barrier(flags) __syncthreads()
#define fma(a, b, c) ((a) * (b) + (c))
#define min(a, b) ((a) < (b) ? (a) : (b))
#define max(a, b) ((a) > (b) ? (a) : (b))
#define vload2(o, p) ((float2)((p)[2 * (o)], (p)[2 * (o) + 1]))
#define vload4(o, p) ((float4)((p)[4 * (o)], (p)[4 * (o) + 1], (p)[4 * (o) + 2], (p)[4 * (o) + 3]))
#define vstore2(v, o, p) do { float2 v_ = (v); (p)[2 * (o)] = v_.x; (p)[2 * (o) + 1] = v_.y; } while (0)
#define vstore4(v, o, p) do { float4 v_ = (v); (p)[4 * (o)] = v_.x; (p)[4 * (o) + 1] = v_.y; \
                              (p)[4 * (o) + 2] = v_.z; (p)[4 * (o) + 3] = v_.w; } while (0)
"""

#: One SASS instruction of a cuobjdump or nvdisasm listing: address, predicate, opcode (with modifiers), operands.
INSTRUCTION = re.compile(r"/\*([0-9a-f]{4,})\*/\s+(@!?U?P[T0-9]\s+)?([A-Z][A-Z0-9_]*)((?:\.[A-Z0-9_]+)*)\s*([^;]*);")
#: A function's start: cuobjdump ("Function : name") or nvdisasm (".text.name:").
FUNCTION = re.compile(r"^\s*(?:Function : (\S+)|\.text\.(\S+):)\s*$")
LABEL = re.compile(r"^\s*(\.L_x_\d+):\s*$")
TARGET = re.compile(r"(?:`\((\.L_x_\d+)\)|\b0x([0-9a-f]+)\b)")


@dataclass(frozen=True)
class Loop:
    """A loop of a SASS listing: the instructions from a backward branch's target to the branch."""

    start: int  # index of the first instruction
    end: int  # index of the branch
    ops: tuple[str, ...]

    @property
    def length(self) -> int:
        return len(self.ops)

    def count(self, op: str) -> int:
        return sum(1 for o in self.ops if o == op)


def parse_listing(text: str) -> dict[str, list[tuple[int, str, str]]]:
    """The instructions of each function of a SASS listing (cuobjdump -sass or nvdisasm -c):
    {name: [(address, opcode without modifiers, operands)]}; a label's name is kept as its next
    instruction's address in the operands of the branches to it (``0x...``)."""
    functions: dict[str, list[tuple[int, str, str]]] = {}
    labels: dict[str, dict[str, int]] = {}
    current, pending = None, []
    for line in text.splitlines():
        f = FUNCTION.match(line)
        if f:
            current = f.group(1) or f.group(2)
            functions[current], labels[current], pending = [], {}, []
            continue
        if current is None:
            continue
        lab = LABEL.match(line)
        if lab:
            pending.append(lab.group(1))
            continue
        m = INSTRUCTION.search(line)
        if m:
            address = int(m.group(1), 16)
            for name in pending:
                labels[current][name] = address
            pending = []
            functions[current].append((address, m.group(3), m.group(5).strip()))
    for name, instructions in functions.items():
        def resolve(operands, table=labels[name]):
            return TARGET.sub(lambda t: f"0x{table[t.group(1)]:x}" if t.group(1) in table else t.group(0), operands)
        functions[name] = [(a, op, resolve(args) if op == "BRA" else args) for a, op, args in instructions]
    return functions


def loops(instructions: list[tuple[int, str, str]]) -> list[Loop]:
    """Every loop of a function (a branch back to an earlier address), innermost (shortest) first."""
    where = {a: i for i, (a, _, _) in enumerate(instructions)}
    found = []
    for i, (address, op, operands) in enumerate(instructions):
        if op != "BRA":
            continue
        target = re.search(r"0x([0-9a-f]+)", operands)
        if target and int(target.group(1), 16) < address and int(target.group(1), 16) in where:
            start = where[int(target.group(1), 16)]
            found.append(Loop(start, i, tuple(o for _, o, _ in instructions[start:i + 1])))
    return sorted(found, key=lambda loop: loop.length)


@dataclass(frozen=True)
class TileCost:
    """Instructions of one unit tile of ``bmu_of_n_gemm`` on the common path."""

    chunk_length: int  # the chunk loop (0: none, the tile's chunks unrolled in the tile loop)
    chunk_ffma: int
    tile_length: int  # the tile loop once, its chunk loop once
    per_tile: int  # the tile loop with all its chunk loop's iterations
    useful_ffma: int  # RM x RN x D

    @property
    def share(self) -> float:
        return self.useful_ffma / self.per_tile


def tile_cost(instructions, chunks: int, accumulators: int, D: int) -> TileCost:
    """The common-path cost of a unit tile from an (ablated) listing of ``bmu_of_n_gemm``.

    Parameters
    ----------
    instructions : list
        :func:`parse_listing`'s entry for the kernel.
    chunks : int
        DP / KT, the chunks of a tile.
    accumulators : int
        RM x RN, the FFMA of one dimension (and of the epilogue's distances).
    D : int

    The tile loop is the outermost loop with FFMA; the chunk loop the innermost, when another (one
    chunk, or chunks the compiler unrolled, leave the tile loop alone). The kernel (with PF) and
    the compiler may peel chunks out of the chunk loop into the tile loop: their FFMA (beyond the
    epilogue's ``accumulators``) say how many, and the chunk loop runs the rest.
    """
    with_ffma = [loop for loop in loops(instructions) if loop.count("FFMA")]
    if not with_ffma:
        raise ValueError("no loop with FFMA in the listing: not the gemm kernel, or its tile loop was unrolled")
    tile = max(with_ffma, key=lambda loop: (loop.count("FFMA"), loop.length))
    inner = [loop for loop in with_ffma if loop is not tile and tile.start <= loop.start and loop.end <= tile.end]
    if not inner:
        return TileCost(0, 0, tile.length, tile.length, accumulators * D)
    chunk = inner[0]
    kt = chunk.count("FFMA") // accumulators
    peeled = (tile.count("FFMA") - chunk.count("FFMA") - accumulators) // max(1, accumulators * kt)
    runs = max(1, chunks - peeled)
    return TileCost(chunk.length, chunk.count("FFMA"), tile.length, tile.length + (runs - 1) * chunk.length,
                    accumulators * D)


def ptxas_report(text: str, function: str = "bmu_of_n_gemm") -> dict[str, int]:
    """Registers, spill bytes (stores + loads), shared memory and stack of one function from ``ptxas -v``."""
    block = re.search(rf"Compiling entry function '{function}'.*?(?=Compiling entry function|\Z)", text, re.S)
    if not block:
        raise ValueError(f"ptxas -v printed nothing for {function}")
    b = block.group(0)
    number = lambda pattern: int(m.group(1)) if (m := re.search(pattern, b)) else 0  # noqa: E731
    return {"registers": number(r"Used (\d+) registers"), "smem": number(r"(\d+) bytes smem"),
            "stack": number(r"(\d+) bytes stack frame"),
            "spill": number(r"(\d+) bytes spill stores") + number(r"(\d+) bytes spill loads")}


class MissingTool(RuntimeError):
    pass


def _package_bin(module: str, name: str) -> list[Path]:
    try:
        spec = importlib.util.find_spec(module)
    except (ImportError, ValueError):
        return []
    if spec is None or not spec.submodule_search_locations:
        return []
    return [Path(p) / "bin" / name for p in spec.submodule_search_locations] + \
           [Path(p) / "backends" / "nvidia" / "bin" / name for p in spec.submodule_search_locations]


def find_tool(name: str, given: str | None = None) -> str:
    """A tool's path: ``given``, else PATH, a CUDA toolkit, NVIDIA's pip wheels, Triton's bundled copy,
    LLVM's versioned folders (clang)."""
    if given:
        return given
    candidates = [shutil.which(name), f"/usr/local/cuda/bin/{name}"]
    if name == "clang":
        candidates += [shutil.which(f"clang-{v}") for v in range(21, 13, -1)]
        candidates += sorted((str(p) for p in Path("/usr/lib").glob("llvm-*/bin/clang")), reverse=True)
    for module in ("nvidia.cuda_nvcc", "nvidia.cuda_nvdisasm", "nvidia.cuda_cuobjdump", "nvidia.cu13", "triton"):
        candidates += [str(p) for p in _package_bin(module, name)]
    for c in candidates:
        if c and Path(c).is_file():
            return str(c)
    raise MissingTool(f"{name} not found (PATH, /usr/local/cuda/bin, NVIDIA's pip wheels, Triton); "
                      + ("install clang (LLVM 14+, NVPTX target)" if name == "clang" else
                         "pip install nvidia-cuda-nvcc-cu12 nvidia-cuda-nvdisasm"))


def kernel_text() -> str:
    """The "gemm" program as meshsom.bmu_opencl builds it, after :data:`OPENCL_BUILTINS` (its epoch
    kernels compiled out: EPOCH_SUMS 0)."""
    from meshsom.bmu_opencl import kernel_source

    return OPENCL_BUILTINS + kernel_source("gemm")


def gemm_defines(n: int, D: int, fields: dict) -> dict:
    """The "gpu" layout's defines at (n, D) on an NVIDIA GPU (48 KB of local memory), with ``fields``
    over its :class:`KernelParams`."""
    from meshsom.bmu_opencl import DEFAULT_PARAMS, GEMM_LOCAL_LIMIT, _defines

    params = replace(DEFAULT_PARAMS["gpu"], local_limit=GEMM_LOCAL_LIMIT, **fields)
    defines = _defines(D, n, np.dtype(np.float32), params)
    defines.pop("KERNEL")
    return defines


def compile_ptx(clang: str, defines: dict, folder: Path, name: str, ptx_target: str, extra: dict | None = None) -> Path:
    """OpenCL C -> PTX with clang (the options meshsom.bmu_opencl.build_options gives a GPU)."""
    source = folder / f"{name}.cl"
    source.write_text(kernel_text())
    ptx = folder / f"{name}.ptx"
    options = [f"-D{k}={v}" for k, v in {**defines, "UNROLL_EPILOGUE": 1, "EXACT": "double", "EPOCH_SUMS": 0, **(extra or {})}.items()]
    cmd = [clang, "-x", "cl", "-cl-std=CL1.2", "-target", "nvptx64-nvidia-nvcl", "-Xclang", "-finclude-default-header",
           "-Xclang", "-target-cpu", "-Xclang", ptx_target, "-O3", "-cl-mad-enable", "-S", "-o", str(ptx), str(source),
           *options]
    run = subprocess.run(cmd, capture_output=True, text=True)
    if run.returncode:
        raise RuntimeError(f"clang failed on {source}: {run.stderr.strip().splitlines()[-1] if run.stderr else run.returncode}")
    return ptx


def assemble(ptxas: str, disassembler: str, ptx: Path, arch: str, max_registers: int = 0) -> tuple[dict, dict]:
    """PTX -> cubin (ptxas -v; ``max_registers``: its -maxrregcount, as NVIDIA's -cl-nv-maxrregcount)
    -> SASS listing: (ptxas report of bmu_of_n_gemm, parsed listing)."""
    cubin = ptx.with_suffix(".cubin")
    cap = [f"-maxrregcount={max_registers}"] if max_registers else []
    run = subprocess.run([ptxas, f"-arch={arch}", "-v", "-O3", *cap, str(ptx), "-o", str(cubin)], capture_output=True,
                         text=True)
    if run.returncode:
        raise RuntimeError(f"ptxas failed on {ptx}: {(run.stderr or run.stdout).strip().splitlines()[-1]}")
    report = ptxas_report(run.stdout + run.stderr)
    args = [disassembler, "-c", str(cubin)] if Path(disassembler).name.startswith("nvdisasm") else \
        [disassembler, "-sass", str(cubin)]
    listing = subprocess.run(args, capture_output=True, text=True).stdout
    (ptx.with_suffix(".sass")).write_text(listing)
    return report, parse_listing(listing)


def candidate_name(fields: dict) -> str:
    return ", ".join(f"{k}={v}" for k, v in fields.items()) or "default"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--arch", default="sm_90", help="ptxas target (sm_90: H100/H200; sm_80: A100; sm_89: L4/4090)")
    parser.add_argument("--ptx-target", default="sm_80", help="clang's PTX target (LLVM 14 knows up to sm_86)")
    parser.add_argument("--workload", action="append", default=None, metavar="n,D", help=f"default {WORKLOADS}")
    parser.add_argument("--candidates", default=None, metavar="JSON",
                        help='a JSON list of KernelParams fields over the "gpu" default, e.g. \'[{}, {"prefetch": false}]\'')
    parser.add_argument("--ptx", action="append", default=None, metavar="FILE", help="report on this PTX instead")
    parser.add_argument("--keep", default=None, metavar="DIR", help="keep the .cl, .ptx, .cubin, .sass here")
    for tool in ("clang", "ptxas", "nvdisasm"):
        parser.add_argument(f"--{tool}", default=None, help=f"path of {tool}")
    args = parser.parse_args(argv)
    try:
        ptxas = find_tool("ptxas", args.ptxas)
        try:
            disassembler = find_tool("nvdisasm", args.nvdisasm)
        except MissingTool:
            disassembler = find_tool("cuobjdump")
        clang = None if args.ptx else find_tool("clang", args.clang)
    except MissingTool as err:
        print(f"bench/gpu_sass.py: {err}")
        return 2
    folder = Path(args.keep) if args.keep else Path(tempfile.mkdtemp(prefix="meshsom-sass-"))
    folder.mkdir(parents=True, exist_ok=True)
    print(f"clang {clang or '-'}, ptxas {ptxas}, {Path(disassembler).name}; --arch {args.arch}; files in {folder}")

    if args.ptx:
        for path in args.ptx:
            local = folder / Path(path).name
            if Path(path).resolve() != local.resolve():
                shutil.copyfile(path, local)
            report, listing = assemble(ptxas, disassembler, local, args.arch)
            gemm = listing.get("bmu_of_n_gemm", [])
            inner = [loop for loop in loops(gemm) if loop.count("FFMA")]
            chunk = f"chunk loop {inner[0].length} instructions, {inner[0].count('FFMA')} FFMA" if inner else "no FFMA loop"
            print(f"{path}: {report['registers']} registers, {report['spill']} B spilled, {report['stack']} B stack, "
                  f"{report['smem']} B shared; {chunk}")
        return 0

    work = [tuple(int(v) for v in w.split(",")) for w in args.workload] if args.workload else WORKLOADS
    candidates = json.loads(args.candidates) if args.candidates else [{}]
    print(f"{'candidate':<28} {'n x D':>7} {'KT':>3} {'XRES':>4} {'regs':>5} {'spill':>5} {'smem':>6}  "
          f"{'chunk loop: instr':>17} {'FFMA':>5}  {'tile: instr':>11} {'GEMM FFMA':>9}")
    for fields in candidates:
        for n, D in work:
            d = gemm_defines(n, D, fields)
            tag = f"gemm-n{n}-D{D}-{abs(hash(json.dumps(fields, sort_keys=True))) % 10**6}"
            report, listing = assemble(ptxas, disassembler, compile_ptx(clang, d, folder, tag, args.ptx_target), args.arch,
                                       d["MAXREG"])
            _, ablated = assemble(ptxas, disassembler,
                                  compile_ptx(clang, d, folder, tag + "-common", args.ptx_target, {"MESHSOM_ABLATE": 1}),
                                  args.arch, d["MAXREG"])
            accumulators = (d["TM"] // d["WGM"]) * (d["TN"] // d["WGN"])
            cost = tile_cost(ablated["bmu_of_n_gemm"], d["DP"] // d["KT"], accumulators, D)
            chunk = f"{cost.chunk_length:>17} {cost.chunk_ffma:>5}" if cost.chunk_length else f"{'(unrolled)':>17} {'':>5}"
            print(f"{candidate_name(fields):<28} {f'{n}x{D}':>7} {d['KT']:>3} {d['XRES']:>4} {report['registers']:>5} "
                  f"{report['spill']:>5} {report['smem']:>6}  {chunk}  {cost.per_tile:>11} {cost.share:>8.0%}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
