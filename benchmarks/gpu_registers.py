"""Registers, spills and occupancy of the GPU FFT kernels on NVIDIA, without a GPU (issue 23).

    python benchmarks/gpu_registers.py                      # every case, the default variants
    python benchmarks/gpu_registers.py --variants fixed,fused16,cols-inplace --arch sm_90
    python benchmarks/gpu_registers.py --render 1080x1920  # the render's own programs
    python benchmarks/gpu_registers.py --render 8x3840 --pad 2  # 7680-point rows: split
    python benchmarks/gpu_registers.py --sgd 2048           # SGD's, its callbacks included

A GPU is lent rarely. What a GPU build of ``fft_lines`` holds per work-item can still be read
here: each case's pass is planned with an H100's limits (48 KiB of local memory, 1024
work-items, 16 bytes held by ``fft_lines`` itself), its program is built as ``clholo.fft``
builds it (the same defines and source), compiled to PTX by clang's NVPTX target with libclc's
built-ins (``clang-14``, ``llvm-link-14``, ``opt-14``, ``llc-14``; Debian ``clang-14
libclc-14``) and assembled by NVIDIA's ``ptxas -v`` (CUDA), which reports registers per
work-item, spills and stack frame. From those and the launch: work-groups and work-items
resident per SM (65536 registers, 228 KiB of shared memory with 1 KiB reserved per group, 2048
work-items, 32 groups), and the largest work-group the registers allow (what
``CL_KERNEL_WORK_GROUP_SIZE`` reports).

This is a model: NVIDIA's OpenCL compiler (NVVM) is not clang, so its register counts differ
(the H200's driver allowed the in-place kernel 256 work-items); the comparison between variants
of one case is what it is for. The variants are ``benchmarks/fft_variants.py``'s. The cases
leave callbacks out (their round trips carry the multiply only); ``--render`` compiles the
programs a GPU-variant render builds, the composite in the row round trip included.
"""

from __future__ import annotations

import argparse
import importlib.util
import os
import re
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

from typing import Optional

import numpy as np

from clholo import fft as F
from clholo.host import runtime

HERE = Path(__file__).resolve().parent
H100 = F.DeviceLimits(is_cpu=False, local_mem_size=48 * 1024, max_work_group_size=1024,
                      kernel_local=(("fft_lines", 16),))
TOOLS = ("clang-14", "llvm-link-14", "opt-14", "llc-14", "ptxas")
LIBCLC = "/usr/lib/clc/nvptx64--nvidiacl.bc"
# NVIDIA's compilers inline device functions; clang's default threshold left the in-place
# stages (called twice in a round trip) as a call with its arrays on the stack
INLINE_THRESHOLD = 100000
# per SM of an H100 / H200 (compute capability 9.0)
SM_REGISTERS, SM_SHARED, SM_THREADS, SM_GROUPS, GROUP_RESERVED = 65536, 228 * 1024, 2048, 32, 1024


def _round_trip(shape, n, axis):
    """A builder of the round trip's pass over ``shape`` (batch, rows, cols)."""
    return lambda: F.round_trip_geometry(shape, n, device=H100, axis=axis).pass_


def _rows_of(shape):
    """A builder of the row pass of an FFT of ``shape``."""
    return lambda: [p for p in F.plan_geometry(shape, np.complex64, device=H100,
                                               variant="gpu").passes if p.axis == "rows"][0]


_sgd_rows = _rows_of((2250, 2250))


# (name, what it is, geometry builder): the passes the workloads run
CASES = tuple((name, what, _round_trip(shape, n, axis)) for name, what, shape, n, axis in (
    ("slm-cols", "SLM grid: column round trip n=1125 x H (B=9)", (9, 1080, 1944), 1125, "cols"),
    ("slm-rows", "SLM grid: row round trip n=1944 (no composite)", (9, 1080, 1944), 1944,
     "rows"),
    ("1024-cols", "1024^2 pad 2: column round trip n=2048", (1, 1024, 2048), 2048, "cols"),
    ("4k-cols", "4K grid: column round trip n=2187", (3, 2160, 3888), 2187, "cols"),
    ("4k-rows", "4K grid: row round trip n=3888", (3, 2160, 3888), 3888, "rows"),
    ("sgd-cols", "SGD 2048^2: column round trip n=2250", (1, 2048, 2250), 2250, "cols"),
    ("4k-pad2-rows", "4K at pad 2 (grid 4320x7680): row round trip n=7680 (split)",
     (3, 2160, 7680), 7680, "rows"),
)) + (("sgd-rows", "SGD 2048^2: row pass n=2250", _sgd_rows),
      ("8192-rows", "FFT 8192^2: row pass n=8192 (split)", _rows_of((8192, 8192))))
# the cases that are one FFT pass, not a round trip
PLAIN_PASSES = ("sgd-rows", "8192-rows")


def missing_tools():
    """The compilers and files this needs that are not here (empty: all present)."""
    gone = [t for t in TOOLS if shutil.which(t) is None]
    if not os.path.isfile(LIBCLC):
        gone.append(LIBCLC)
    return gone


def _variants():
    spec = importlib.util.spec_from_file_location("fft_variants", HERE / "fft_variants.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def pass_source(p, round_trip: bool):
    """The source text and build options ``clholo.fft`` gives the pass's program."""
    defines = dict(p.defines)
    if round_trip:
        defines["FFT_ROUND_TRIP"] = 1
    text = (F.kernel_arg_macros() + '#line 1 "' + p.program + '"\n'
            + runtime.read_kernel_source(p.program))
    return runtime.inline_includes(text, p.program), ["-cl-mad-enable"] + \
        runtime._define_options(defines)


def register_cap(threads: int) -> int:
    """The most registers a work-item may take for a group of ``threads`` to fit one SM (what a
    compiler that honours ``reqd_work_group_size`` must keep to, spilling the rest)."""
    warps = -(-max(1, threads) // 32)
    return min(255, SM_REGISTERS // (warps * 32) // 8 * 8)


def ptxas_report(source: str, options, arch: str, workdir: str, kernel: str,
                 max_registers: Optional[int] = None) -> dict:
    """Compile ``source`` for NVPTX and assemble it for ``arch``; ``ptxas -v``'s numbers for
    the entry function ``kernel`` (``max_registers``: ``ptxas --maxrregcount``)."""
    cl, bc, linked, opt, ptx = (os.path.join(workdir, f) for f in
                                ("k.cl", "k.bc", "l.bc", "o.bc", "k.ptx"))
    Path(cl).write_text(source)
    steps = (
        # unoptimised IR first (-disable-llvm-passes): the optimiser runs once libclc's
        # built-ins are linked in, so that e.g. min() is known and a loop bound built from it
        # a constant, as in a driver's compiler
        ["clang-14", "-x", "cl", "-cl-std=CL1.2", "-target", "nvptx64-nvidia-nvcl", "-O3",
         "-Xclang", "-disable-llvm-passes", "-emit-llvm", "-c", "-Xclang",
         "-finclude-default-header", *options, cl, "-o", bc],
        ["llvm-link-14", "--only-needed", bc, LIBCLC, "-o", linked],
        ["opt-14", "-O3", f"-inline-threshold={INLINE_THRESHOLD}", linked, "-o", opt],
        ["llc-14", "-mcpu=sm_80", opt, "-o", ptx],
        ["ptxas", f"-arch={arch}", "-v", ptx, "-o", os.path.join(workdir, "k.cubin")]
        + ([f"--maxrregcount={max_registers}"] if max_registers else []),
    )
    out = ""
    for cmd in steps:
        r = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
        if r.returncode != 0:
            raise RuntimeError(f"{cmd[0]} failed:\n{r.stderr[-3000:]}")
        out = r.stderr + r.stdout
    # the program holds other kernels too: the numbers of the entry function `kernel` only
    blocks = re.split(r"ptxas info\s*: Compiling entry function ", out)
    mine = [b for b in blocks if b.startswith(f"'{kernel}'")]
    if not mine:
        raise RuntimeError(f"ptxas reported no entry function {kernel}:\n{out[-2000:]}")
    nums = {}
    for key, pat in (("registers", r"Used (\d+) registers"),
                     ("stack", r"(\d+) bytes stack frame"),
                     ("spill_stores", r"(\d+) bytes spill stores"),
                     ("spill_loads", r"(\d+) bytes spill loads")):
        m = re.search(pat, mine[0])
        nums[key] = int(m.group(1)) if m else 0
    return nums


def occupancy(registers: int, threads: int, local_bytes: int) -> dict:
    """Groups and work-items resident per SM, and the largest group the registers allow."""
    regs = max(1, registers)
    per_warp = -(-regs * 32 // 256) * 256  # registers are allocated per warp, 256 at a time
    warps = -(-threads // 32)
    by_regs = SM_REGISTERS // (per_warp * warps)
    by_shared = SM_SHARED // (local_bytes + 16 + GROUP_RESERVED)
    by_threads = SM_THREADS // (warps * 32)
    groups = max(0, min(by_regs, by_shared, by_threads, SM_GROUPS))
    limit = min(1024, SM_REGISTERS // per_warp * 32)
    return {"groups": groups, "resident": groups * threads, "max_group": limit}


def _held(report: dict, source: str, options, arch: str, workdir: str, kernel: str,
          threads: int) -> str:
    """Where ``report`` has more registers than a group of ``threads`` allows: the kernel
    declares its group's size (``reqd_work_group_size``), so a driver either allows fewer
    work-items (the plan is made again: the largest group) or holds the registers to it and
    spills; the second, assembled again with ``--maxrregcount``. Else ``"-"``."""
    cap = register_cap(threads)
    if not threads or report["registers"] <= cap:
        return "-"
    r = ptxas_report(source, options, arch, workdir, kernel, max_registers=cap)
    return f"{r['registers']} registers, {r['spill_stores']} B spilled, {r['stack']} B stack"


def captured_programs(run):
    """The ``fft_gpu.cl`` programs ``run()`` builds while every plan sees an H100's limits
    (so ``variant="auto"`` picks the GPU kernels, callbacks included): ``(label, source,
    options, defines)``. ``run`` executes on the default OpenCL device (PoCL: the GPU kernels
    run there too, slowly)."""
    real_build, real_of = runtime.build_program, F.DeviceLimits.of
    caught = []

    def spy(context, filename, *, defines=None, source=None, extra_options=()):
        if filename == "fft_gpu.cl":
            caught.append((dict(defines or {}), source))
        return real_build(context, filename, defines=defines, source=source,
                          extra_options=extra_options)

    runtime.build_program = spy
    F.DeviceLimits.of = classmethod(lambda cls, dev: H100)
    try:
        run()
    finally:
        runtime.build_program, F.DeviceLimits.of = real_build, real_of
    programs = []
    for defines, source in caught:
        label = (f"n={defines.get('FFT_N')} L={defines.get('FFT_L')} "
                 f"{'cols' if defines.get('FFT_LINE_FAST') else 'rows'}"
                 f"{' round trip' if defines.get('FFT_ROUND_TRIP') else ''}"
                 f"{' +callbacks' if 'FFT_CB_LAYOUT' in defines else ''}"
                 f"{' split' if defines.get('FFT_SPLIT') else ' in place' if defines.get('FFT_INPLACE') else ''}")
        programs.append((label, runtime.inline_includes(source, "fft_gpu.cl"),
                         ["-cl-mad-enable"] + runtime._define_options(defines), defines))
    return programs


def render_run(height: int, width: int, pad="auto"):
    """A GPU-variant render of ``height x width`` RGB (2 layers, T = 3) at padding ``pad``
    (``"auto"`` or a factor)."""
    import clholo

    def run():
        rng = np.random.default_rng(0)
        mpi = clholo.MPI(rng.random((2, height, width, 3), dtype=np.float32),
                         rng.random((2, height, width), dtype=np.float32), [2e-3, 3e-3])
        r = clholo.HologramRenderer(mpi, clholo.Optics(), seed=1, variant="gpu",
                                    frames_per_batch=3, pad=pad)
        out = clholo.host.scheduler.cla.empty(r.queue, (3, 3, height, width), np.complex64)
        r.render(3, out=out)
        r.queue.finish()
    return run


def sgd_run(size: int, fuse: str = "round-trips"):
    """Two SGD iterations of ``size``^2 in the form ``fuse`` (default GPUs': ``"round-trips"``,
    the mid steps in the row round trips; ``"all"``: the residual, the gradient and Adam inside
    the adjoint propagation's passes)."""
    from clholo.bench import profile_sgd

    return lambda: profile_sgd(size=size, iterations=2, fuse=fuse)


def main(argv=None) -> int:
    fv = _variants()
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--variants", default=None,
                    help=f"comma-separated, from {', '.join(fv.VARIANTS)} (default: fixed, "
                         f"fused16, unfused, inplace-direct, cols-inplace, cols-inplace-direct; "
                         f"with --render or --sgd: fixed)")
    ap.add_argument("--cases", default=",".join(c[0] for c in CASES),
                    help=f"comma-separated, from {', '.join(c[0] for c in CASES)}")
    ap.add_argument("--arch", default="sm_90", help="ptxas -arch (H100 and H200: sm_90)")
    ap.add_argument("--render", metavar="HxW", default=None,
                    help="instead: the programs a GPU-variant render of HxW RGB builds, "
                         "its composite callback included (rendered on the default device)")
    ap.add_argument("--sgd", metavar="N", type=int, default=None,
                    help="instead: the programs SGD phase retrieval of NxN builds (in the "
                         "form --sgd-fuse)")
    ap.add_argument("--pad", default="auto",
                    help="--render's padding: 'auto' or a factor (2: a 4K render's rows of "
                         "7680 points take the split plan)")
    ap.add_argument("--sgd-fuse", default="round-trips", choices=["none", "all", "round-trips"],
                    help="the form of --sgd's iteration (default GPUs': round-trips)")
    a = ap.parse_args(argv)
    gone = missing_tools()
    if gone:
        print(f"gpu_registers: missing {', '.join(gone)}: install Debian's clang-14 and "
              f"libclc-14, and ptxas from NVIDIA's CUDA toolkit", file=sys.stderr)
        return 2
    if a.variants is None:
        a.variants = ("fixed" if a.render or a.sgd else
                      "fixed,fused16,unfused,inplace-direct,cols-inplace,cols-inplace-direct")
    bad = [v for v in a.variants.split(",") if v and v not in fv.VARIANTS]
    if bad:
        ap.error(f"unknown variant: {bad}")
    if a.render or a.sgd:
        if a.render:
            try:
                height, width = (int(v) for v in a.render.lower().split("x"))
            except ValueError:
                ap.error("--render takes HxW such as 1080x1920")
            try:
                pad = a.pad if a.pad == "auto" else float(a.pad)
            except ValueError:
                ap.error("--pad takes 'auto' or a factor such as 2")
            run, what = render_run(height, width, pad), f"{a.render} RGB render, pad {a.pad}"
        else:
            run, what = sgd_run(a.sgd, a.sgd_fuse), f"SGD {a.sgd}^2, fuse {a.sgd_fuse}"
        print(f"| program ({what}, H100 limits) | variant | work-items | registers | "
              f"spills (B st/ld) | stack B | held to its group |\n|---|---|---|---|---|---|---|")
        with tempfile.TemporaryDirectory() as work:
            for name in [v for v in a.variants.split(",") if v]:
                with fv.variant(name):
                    programs = captured_programs(run)
                for label, src, opts, defines in programs:
                    r = ptxas_report(src, opts, a.arch, work, "fft_lines")
                    quads = " quads" if defines.get("FFT_MID_QUADS") else ""
                    held = _held(r, src, opts, a.arch, work, "fft_lines",
                                 int(defines.get("FFT_WG", 0) or 0))
                    print(f"| {label}{quads} | {name} | {defines.get('FFT_WG', '')} | "
                          f"{r['registers']} | {r['spill_stores']}/{r['spill_loads']} | "
                          f"{r['stack']} | {held} |", flush=True)
        return 0
    names = [v for v in a.variants.split(",") if v]
    cases = {c[0]: c for c in CASES}
    wanted = [c for c in a.cases.split(",") if c]
    bad = [v for v in names if v not in fv.VARIANTS] + [c for c in wanted if c not in cases]
    if bad:
        ap.error(f"unknown variant or case: {bad}")
    print(f"| case | variant | plan | work-items | local KiB | registers | spills (B st/ld) "
          f"| stack B | groups/SM | work-items/SM | largest group | held to its group "
          f"|\n|{'---|' * 12}")
    with tempfile.TemporaryDirectory() as work:
        for case in wanted:
            _, what, build = cases[case]
            for name in names:
                with fv.variant(name):
                    p = build()
                    src, opts = pass_source(p, round_trip=case not in PLAIN_PASSES)
                lg = p.launches[0]
                threads = lg.lsize[0] if lg.lsize else 0
                d = dict(p.defines)
                plan = (("split" if d.get("FFT_SPLIT") else "in place" if d.get("FFT_INPLACE")
                         else "two buffers")
                        + (" direct" if d.get("FFT_INPLACE_DIRECT") or not d.get("FFT_INPLACE")
                           else "") + f", {lg.extra[0]} line(s)")
                try:
                    r = ptxas_report(src, opts, a.arch, work, p.kernel)
                except RuntimeError as exc:
                    print(f"| {case} | {name} | {plan} | error: {str(exc)[:200]} |")
                    continue
                occ = occupancy(r["registers"], threads, lg.local_bytes)
                held = _held(r, src, opts, a.arch, work, p.kernel, threads)
                print(f"| {case} | {name} | {plan} | {threads} | {lg.local_bytes / 1024:.1f} | "
                      f"{r['registers']} | {r['spill_stores']}/{r['spill_loads']} | "
                      f"{r['stack']} | {occ['groups']} | {occ['resident']} | "
                      f"{occ['max_group']} | {held} |", flush=True)
    print("\n" + "\n".join(f"{c[0]}: {c[1]}" for c in CASES if c[0] in wanted))
    return 0


if __name__ == "__main__":
    sys.exit(main())
