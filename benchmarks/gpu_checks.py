"""Issue 23's measurements in one prepared run for the GPU test machine (or any device).

    bash .gpu/run-on-gpu.sh python3 benchmarks/gpu_checks.py --out "$OUT"           # all
    bash .gpu/run-on-gpu.sh python3 benchmarks/gpu_checks.py --out "$OUT" --budget 500
    bash .gpu/run-on-gpu.sh python3 benchmarks/gpu_checks.py --out "$OUT" --only suite,slm
    python benchmarks/gpu_checks.py --list                                 # what would run

A GPU is lent rarely and briefly (about 15 minutes of device time a session, at most 10 minutes a
command: ``../shared/gpu/README.md``), so every measurement issue 23's table asks for is here,
most important first, each as its own subprocess with its own time limit: its output goes to
``OUT/NN-step.txt`` as it runs, and ``OUT/summary.md`` gets one row per step (exit status,
seconds, or why it was skipped) after each step, so a run cut short still leaves what it did. A
step that would not finish inside what is left of ``--budget`` seconds is skipped (listed as
such: each step has the time it should take on an H100, kernel builds included, and a limit
of its own); run those in a second call with ``--only``. ``--quick`` runs every step at toy sizes: it
checks the plumbing on PoCL (the test suite runs it), it measures nothing.

Every step runs with ``CLHOLO_TUNING_FILE=OUT/tuning.json``: the step ``tune`` (``clholo tune``)
measures the settings of :mod:`clholo.tuning` on the device and stores the fastest there, so the
steps after it measure what a lab gets after ``clholo tune``; without it, the defaults. A later
call on a fresh machine takes the first call's file with ``--tuning`` (carried along, e.g. as
``.gpu/tuning.json``).

The PyTorch peers run on CUDA when clholo's device is a GPU and torch has CUDA
(``clholo.bench.torch_peer``); steps that need torch fail with its message where it is missing.

Before the call, on this machine: ``bash ../shared/gpu/prepare.sh`` (the wheels, about 10 MB)
and ``cp -r ../shared/data .gpu/data`` (about 50 MB: the suite's tests on real data run
instead of skipping; ``run-on-gpu.sh`` points ``CLHOLO_SHARED_DATA`` there), then ``run`` with
``carry: [".gpu"]``: 60 MB of the 64 MiB a call carries.
"""

from __future__ import annotations

import argparse
import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import List, NamedTuple, Sequence

ROOT = Path(__file__).resolve().parents[1]
BENCH = ROOT / "benchmarks"
PY = sys.executable


class Step(NamedTuple):
    name: str
    what: str            # the row of issue 23's table it measures
    expect_s: int        # what it should take on an H100, kernel builds included (seconds)
    limit_s: int         # its own time limit, seconds
    argv: Sequence[str]  # the full-size command
    quick: Sequence[str]  # the same at toy sizes (plumbing only)


def _slm(height: int, width: int, frames: int, layers: int = 32, repeats: int = 3) -> List[str]:
    return [PY, "-c", "from clholo.bench import run_slm_benchmark; "
            f"run_slm_benchmark(height={height}, width={width}, frames={frames}, "
            f"layers={layers}, repeats={repeats})"]


def _profile(*args: str) -> List[str]:
    return [PY, str(BENCH / "profile_kernels.py"), *args]


STEPS = (
    Step("info", "the device and driver", 10, 60, [PY, "-m", "clholo.cli", "info"],
         [PY, "-m", "clholo.cli", "info"]),
    Step("tune", "clholo tune: the settings that change speed, never results, measured on the "
         "device (1080x1920 RGB L=32 T=3 and SGD 2048^2), the fastest stored in OUT/tuning.json "
         "for every later step", 60, 180,
         [PY, "-m", "clholo.cli", "tune", "--sgd", "2048"],
         [PY, "-m", "clholo.cli", "tune", "--shape", "24x40", "--layers", "2", "--frames", "1",
          "--rounds", "1", "--sgd", "32", "--variant", "gpu"]),
    Step("profile-slm", "per-kernel profile, 1080x1920 RGB, L=32, T=3", 40, 150,
         _profile("--shape", "1080x1920", "--frames", "3", "--repeats", "5"),
         _profile("--shape", "24x40", "--layers", "2", "--frames", "1", "--repeats", "1")),
    Step("slm-t3", "hologram 1080x1920 RGB, L=32, T=3 vs PyTorch", 45, 150, _slm(1080, 1920, 3),
         _slm(24, 40, 1, layers=2, repeats=1)),
    Step("variants", "the GPU FFT kernel's variants side by side: as planned (default), the "
         "in-place plan's first and last stages on global memory (radices up to 16 or 8), "
         "columns on the in-place plan (plain, direct) and on the split plan (512 and 1024 "
         "work-items), round trips in batch-first order", 110, 280,
         [PY, str(BENCH / "fft_variants.py"), "--variants",
          "fixed,inplace-direct,inplace-direct8,cols-inplace,cols-inplace-direct,cols-split,"
          "cols-split1024,batch-fast",
          "--shape",
          "1080x1920", "--sizes", "1125x1944,2250x2250,2187x3888,4096x4096,1024x1024", "--sgd",
          "2048"],
         [PY, str(BENCH / "fft_variants.py"), "--shape", "24x40", "--layers", "2", "--frames",
          "1", "--repeats", "1", "--sizes", "30x40", "--rounds", "2"]),
    Step("composite", "the render's composite on the GPU: by quads (one Philox block per four "
         "pixels), the layers as planes (coalesced, no square roots), both; SGD's Adam step by "
         "quads", 60, 180,
         [PY, str(BENCH / "fft_variants.py"), "--variants",
          "fixed,mid-quads,layer-planes,planes-quads", "--shape", "1080x1920", "--sizes", "",
          "--sgd", "2048"],
         [PY, str(BENCH / "fft_variants.py"), "--variants",
          "fixed,mid-quads,layer-planes,planes-quads", "--shape", "24x40", "--layers", "2",
          "--frames", "1", "--repeats", "1", "--sizes", "", "--sgd", "32"]),
    Step("suite", "the test suite on the device (-n 12)", 120, 420,
         [PY, "-m", "pytest", "-q", "-n", "12", "-p", "no:cacheprovider", str(ROOT / "tests")],
         [PY, "-c", "print('suite: full size only')"]),
    Step("slm-t24", "hologram 1080x1920 RGB, L=32, T=24, pad auto vs PyTorch (goal <= 1.5 ms "
         "per colour-frame)", 70, 200, _slm(1080, 1920, 24), _slm(24, 40, 2, layers=2, repeats=1)),
    Step("fft", "FFT device-resident vs cuFFT (goal <= 1.3x its time)", 90, 240,
         [PY, str(BENCH / "bench_fft.py"), "--sizes",
          "1024,2048,4096,1125x1944,2160x3840,2250,2187x3888", "--batch", "", "--budget", "8",
          "--skip", "numpy,pyfftw,pyvkfft"],
         [PY, str(BENCH / "bench_fft.py"), "--sizes", "32,24x40", "--batch", "", "--rounds",
          "2", "--budget", "1", "--skip", "numpy,pyfftw,pyvkfft"]),
    Step("sgd-1024", "SGD iteration 1024^2 vs autograd (goal >= 4x)", 30, 120,
         [PY, str(BENCH / "bench_sgd.py"), "--size", "1024", "--iterations", "20", "--rounds",
          "5", "--breakdown"],
         [PY, str(BENCH / "bench_sgd.py"), "--size", "32", "--iterations", "1", "--rounds", "1"]),
    Step("sgd-2048", "SGD iteration 2048^2, grid 2250^2 vs autograd (goal >= 3x)", 40, 150,
         [PY, str(BENCH / "bench_sgd.py"), "--size", "2048", "--iterations", "20", "--rounds",
          "5", "--breakdown"],
         [PY, str(BENCH / "bench_sgd.py"), "--size", "48", "--iterations", "1", "--rounds", "1"]),
    Step("hologram-1024", "hologram L=32, 1024^2, pad 2, one colour vs PyTorch (goal >= 3x)", 25, 150,
         [PY, str(BENCH / "bench_hologram.py"), "--size", "1024", "--pad", "2", "--no-scaling",
          "--no-numpy", "--repeats", "5"],
         [PY, str(BENCH / "bench_hologram.py"), "--size", "32", "--layers", "2", "--pad", "2",
          "--no-scaling", "--repeats", "1"]),
    Step("profile-1024", "per-kernel profile, 1024^2 pad 2, one colour, L=32, T=1 (where the "
         "hologram-1024 step's time goes)", 30, 120,
         _profile("--shape", "1024x1024", "--colours", "1", "--frames", "1", "--pad", "2",
                  "--repeats", "10"),
         _profile("--shape", "32x32", "--colours", "1", "--layers", "2", "--frames", "1",
                  "--pad", "2", "--repeats", "1")),
    Step("pitch", "the CPUs' row pitch on the GPU (2064 for 2048-element rows): the 1024^2 "
         "pad-2 render and SGD's 2048^2 grid, without and with", 40, 150,
         [PY, str(BENCH / "fft_variants.py"), "--variants", "fixed,row-pitch", "--shape",
          "1024x1024", "--colours", "1", "--frames", "1", "--pad", "2", "--sizes", "",
          "--sgd", "1024"],
         [PY, str(BENCH / "fft_variants.py"), "--variants", "fixed,row-pitch", "--shape",
          "32x32", "--colours", "1", "--layers", "2", "--frames", "1", "--repeats", "1",
          "--pad", "2", "--sizes", ""]),
    Step("split", "lines the local memory holds one component of (7680, 8192 points): the split "
         "plan (one launch a pass; a 4K render at pad 2 as two kernels a layer) against the "
         "global stages and four passes before it", 60, 200,
         [PY, str(BENCH / "fft_variants.py"), "--variants", "fixed,no-split", "--shape",
          "2160x3840", "--frames", "1", "--pad", "2", "--sizes", "8192x8192,4320x7680"],
         [PY, str(BENCH / "fft_variants.py"), "--variants", "fixed,no-split", "--shape",
          "24x40", "--layers", "2", "--frames", "1", "--repeats", "1", "--pad", "2", "--sizes",
          "30x40", "--rounds", "2"]),
    Step("4k", "hologram 2160x3840 RGB, L=32, T=1 vs PyTorch (goal >= 2x faster)", 100, 200,
         _slm(2160, 3840, 1), _slm(32, 48, 1, layers=2, repeats=1)),
    Step("profile-4k", "per-kernel profile, 2160x3840 RGB, L=32, T=1", 50, 150,
         _profile("--shape", "2160x3840", "--frames", "1", "--repeats", "3"),
         _profile("--shape", "32x48", "--layers", "2", "--frames", "1", "--repeats", "1")),
    Step("profile-sgd", "per-kernel profile, SGD 2048^2", 25, 90,
         _profile("--sgd", "2048", "--iterations", "20"),
         _profile("--sgd", "32", "--iterations", "1")),
    Step("display", "display loop producer, 1080x1920 RGB, 32 layers, DPAC (goal >= 360 "
         "patterns/s)", 45, 150,
         [PY, str(BENCH / "bench_display_batch.py"), "--size", "1080", "1920", "--layers", "32",
          "--frames", "3", "--repeats", "5"],
         [PY, str(BENCH / "bench_display_batch.py"), "--size", "24", "40", "--layers", "2",
          "--frames", "1", "--repeats", "1"]),
    Step("display-loop", "the display loop itself (DisplayLoop, DPAC, 1080x1920 RGB, 32 layers, "
         "T=3): its producer pipelined (the default) against in turn, patterns/s (goal >= 360)",
         40, 150,
         [PY, str(BENCH / "bench_display_batch.py"), "--loop", "--size", "1080", "1920",
          "--layers", "32", "--frames", "3", "--repeats", "3", "--loop-batches", "8"],
         [PY, str(BENCH / "bench_display_batch.py"), "--loop", "--size", "24", "40", "--layers",
          "2", "--frames", "1", "--repeats", "1", "--loop-batches", "3"]),
    Step("enqueue", "host time to enqueue a render vs its device time (goal <= 20 %)", 30, 120,
         [PY, str(BENCH / "bench_enqueue.py"), "--shape", "1080x1920", "--layers", "32",
          "--frames", "3"],
         [PY, str(BENCH / "bench_enqueue.py"), "--shape", "24x40", "--layers", "2", "--frames",
          "1", "--repeats", "1", "--fft", "32", "--launches", "5"]),
    Step("selftest", "clholo selftest on the device", 60, 240, [PY, "-m", "clholo.cli", "selftest"],
         [PY, "-c", "import clholo; print('selftest: full size only')"]),
)


def _kill_group(proc: subprocess.Popen) -> None:
    """SIGKILL to the step's process group, then reap it."""
    try:
        os.killpg(proc.pid, signal.SIGKILL)
    except (ProcessLookupError, PermissionError):
        proc.kill()
    proc.wait()


def _write_atomic(path: Path, text: str) -> None:
    tmp = path.with_name(path.name + ".partial")
    tmp.write_text(text)
    os.replace(tmp, path)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", default=os.environ.get("OUT"),
                    help="folder for the outputs (default: $OUT)")
    ap.add_argument("--budget", type=float, default=540.0,
                    help="seconds for the whole run; steps that would overrun it are skipped "
                         "(default 540: one device call of at most 600 s)")
    ap.add_argument("--only", default="",
                    help="comma-separated step names, in the order given (default: all)")
    ap.add_argument("--tuning", default=None, metavar="FILE",
                    help="a tuning file an earlier call stored (its OUT/tuning.json, carried "
                         "along, e.g. as .gpu/tuning.json): copied to OUT/tuning.json first, so "
                         "a second call on a fresh machine measures the tuned device")
    ap.add_argument("--quick", action="store_true", help="toy sizes: plumbing only")
    ap.add_argument("--list", action="store_true", help="print the steps and exit")
    a = ap.parse_args(argv)
    names = [s.name for s in STEPS]
    if a.only:
        wanted = [n.strip() for n in a.only.split(",") if n.strip()]
        unknown = [n for n in wanted if n not in names]
        if unknown:
            ap.error(f"--only: no step {', '.join(unknown)}; the steps are {', '.join(names)}")
        steps = [STEPS[names.index(n)] for n in wanted]
    else:
        steps = list(STEPS)
    if a.list:
        for s in steps:
            print(f"{s.name:<14}{s.expect_s:>5} s  {s.what}\n{'':19}{' '.join(s.argv)}")
        return 0
    if not a.out:
        ap.error("--out is required (or set $OUT)")
    if a.budget <= 0:
        ap.error(f"--budget is {a.budget}; give the seconds the run may take, e.g. 540")
    tuning_from = None
    if a.tuning is not None:
        tuning_from = Path(a.tuning)
        if not tuning_from.is_file():
            ap.error(f"--tuning {a.tuning}: no such file; give the tuning.json an earlier "
                     f"call wrote under its OUT (or leave --tuning out: the defaults)")
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    if tuning_from is not None and tuning_from.resolve() != (out / "tuning.json").resolve():
        _write_atomic(out / "tuning.json", tuning_from.read_text())
    # the step "tune" stores the device's tuning here, and every later step's plans take it
    # (benchmarks/fft_variants.py's variants ignore it: they set the settings themselves)
    env = dict(os.environ, CLHOLO_TUNING_FILE=str((out / "tuning.json").resolve()))
    start = time.monotonic()
    rows = ["| step | measures | status | seconds |", "|---|---|---|---|"]
    failed = 0
    for i, s in enumerate(steps):
        left = a.budget - (time.monotonic() - start)
        if s.expect_s > left and not a.quick:
            rows.append(f"| {s.name} | {s.what} | skipped: takes about {s.expect_s} s, "
                        f"{left:.0f} s left (run it with --only {s.name}) | |")
            _write_atomic(out / "summary.md", "\n".join(rows) + "\n")
            continue
        log = out / f"{i:02d}-{s.name}.txt"
        limit = s.limit_s if a.quick else min(s.limit_s, max(left, 1.0))
        t = time.monotonic()
        with open(log, "w") as f:
            f.write("$ " + " ".join(s.quick if a.quick else s.argv) + "\n")
            f.flush()
            # its own session: a step past its limit is killed with every process it started
            # (pytest -n 12's workers would otherwise hold the device into the next step)
            proc = subprocess.Popen(s.quick if a.quick else s.argv, stdout=f,
                                    stderr=subprocess.STDOUT, cwd=ROOT, start_new_session=True,
                                    env=env)
            try:
                rc = proc.wait(timeout=limit)
                status = "ok" if rc == 0 else f"exit {rc}"
            except subprocess.TimeoutExpired:
                _kill_group(proc)
                status = f"timed out after {limit:.0f} s"
        if status != "ok":
            failed += 1
        rows.append(f"| {s.name} | {s.what} | {status} | {time.monotonic() - t:.1f} |")
        _write_atomic(out / "summary.md", "\n".join(rows) + "\n")
        print(f"{s.name}: {status} ({time.monotonic() - t:.1f} s) -> {log.name}", flush=True)
    print("\n".join(rows))
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
