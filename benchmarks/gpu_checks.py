"""Issue 23's measurements in one prepared run for the GPU test machine (or any device).

    bash .gpu/run-on-gpu.sh python3 benchmarks/gpu_checks.py --out "$OUT"           # all
    bash .gpu/run-on-gpu.sh python3 benchmarks/gpu_checks.py --out "$OUT" --budget 360
    bash .gpu/run-on-gpu.sh python3 benchmarks/gpu_checks.py --out "$OUT" --only suite,slm-t3
    python benchmarks/gpu_checks.py --list                                 # what would run

A GPU is lent rarely and briefly (about 15 minutes of device time a session, machine starts
included, at most 10 minutes a command: ``../shared/gpu/README.md``), so every measurement issue
23's table asks for is here, most important first, each as its own subprocess (in a process
group of its own) with its own time limit: its output goes to ``OUT/NN-step.txt`` as it runs, and
``OUT/summary.md`` gets one row per step (exit status and the log's last line, seconds, or why it
was skipped) after each step, so a run cut short still leaves what it did.

``--budget`` is a hard wall for the whole call: no step runs past it (a step's limit is its own
or what is left of the budget, whichever is less, a few seconds kept to stop it and write the
summary), and a step that would not finish inside what is left (each step has the time it should
take on an H100, kernel builds included) is skipped, printed and listed as such; run those in a
later call with ``--only``. ``PLAN`` holds the two calls of a session (docs/benchmarks.md).

Stopped (SIGTERM from ``timeout``, SIGINT, SIGHUP, or any error of its own), the running step is
killed with every process it started, ``summary.md`` gets the finished rows, an "interrupted"
row and the steps not run, and the call exits non-zero (128 + the signal's number). A step that
ends leaves nothing behind either: its process group is killed after it.

``--quick`` runs every step at toy sizes with the same options (the full command's flags and
variant names), inside ``--budget`` too: it checks the plumbing on PoCL (the test suite runs the
plan's two calls this way), it measures nothing.

Every step runs with ``CLHOLO_TUNING_FILE=OUT/tuning.json``: the step ``tune`` (``clholo tune``)
measures the settings of :mod:`clholo.tuning` on the device and stores the fastest there, so the
steps after it measure what a lab gets after ``clholo tune``; without it, the defaults. A later
call on a fresh machine takes the first call's file with ``--tuning`` (carried along, e.g. as
``.gpu/tuning.json``): a file clholo did not write is refused at the start, and one without an
entry for this device (platform, vendor, device name and driver) or from another clholo
version is used by no step: a WARNING line at the start, at the top of ``summary.md`` and of
every step's log names the devices stored and this one.

The steps that compare against PyTorch (``peer`` in ``STEPS``) run with
``CLHOLO_BENCH_PEER=required`` (``clholo.bench.torch_peer``): without torch they fail ("no
PyTorch peer"), and where clholo's device is a GPU and torch has no CUDA they fail too, rather
than compare a GPU against PyTorch on the CPU; ``--allow-cpu-peer`` allows that
(``CLHOLO_BENCH_PEER=any``).

Before the call, on this machine: ``bash ../shared/gpu/prepare.sh`` (the wheels, about 10 MB)
and ``cp -r ../shared/data .gpu/data`` (about 50 MB: the suite's tests on real data run
instead of skipping; ``run-on-gpu.sh`` points ``CLHOLO_SHARED_DATA`` there), then ``run`` with
``carry: [".gpu"]``: 60 MB of the 64 MiB a call carries.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Dict, List, NamedTuple, Optional, Sequence

ROOT = Path(__file__).resolve().parents[1]
BENCH = ROOT / "benchmarks"
PY = sys.executable

#: Seconds of ``--budget`` kept back to stop a step and write ``summary.md``: the call ends
#: inside its budget.
RESERVE_S = 3.0
#: ``clholo.bench.PEER_ENV``: set for the steps that compare against PyTorch.
PEER_ENV = "CLHOLO_BENCH_PEER"
#: The signals that stop a call (``timeout`` sends SIGTERM; Ctrl-C SIGINT).
STOP_SIGNALS = (signal.SIGTERM, signal.SIGINT, signal.SIGHUP)


class Step(NamedTuple):
    name: str
    what: str            # the row of issue 23's table it measures
    expect_s: int        # what it should take on an H100, kernel builds included (seconds)
    limit_s: int         # its own time limit, seconds
    argv: Sequence[str]  # the full-size command
    quick: Sequence[str]  # the same at toy sizes and with the same flags (plumbing only)
    peer: bool = False   # compares against PyTorch: run with CLHOLO_BENCH_PEER


def _slm(height: int, width: int, frames: int, layers: int = 32, repeats: int = 3) -> List[str]:
    return [PY, "-c", "from clholo.bench import run_slm_benchmark; "
            f"run_slm_benchmark(height={height}, width={width}, frames={frames}, "
            f"layers={layers}, repeats={repeats})"]


def _profile(*args: str) -> List[str]:
    return [PY, str(BENCH / "profile_kernels.py"), *args]


def _variants(*args: str) -> List[str]:
    return [PY, str(BENCH / "fft_variants.py"), *args]


# the variants step's variants, the same in its quick command
_VARIANTS = ("fixed,inplace-direct,inplace-direct8,cols-inplace,cols-inplace-direct,cols-split,"
             "cols-split1024,batch-fast")
_COMPOSITE = "fixed,mid-quads,layer-planes,planes-quads"

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
         _slm(24, 40, 1, layers=2, repeats=1), peer=True),
    Step("variants", "the GPU FFT kernel's variants side by side: as planned (default), the "
         "in-place plan's first and last stages on global memory (radices up to 16 or 8), "
         "columns on the in-place plan (plain, direct) and on the split plan (512 and 1024 "
         "work-items), round trips in batch-first order", 110, 280,
         _variants("--variants", _VARIANTS, "--shape", "1080x1920", "--sizes",
                   "1125x1944,2250x2250,2187x3888,4096x4096,1024x1024", "--sgd", "2048"),
         _variants("--variants", _VARIANTS, "--shape", "24x40", "--layers", "2", "--frames", "1",
                   "--repeats", "1", "--sizes", "30x40", "--rounds", "2", "--sgd", "32")),
    Step("composite", "the render's composite on the GPU: by quads (one Philox block per four "
         "pixels), the layers as planes (coalesced, no square roots), both; SGD's Adam step by "
         "quads", 60, 180,
         _variants("--variants", _COMPOSITE, "--shape", "1080x1920", "--sizes", "",
                   "--sgd", "2048"),
         _variants("--variants", _COMPOSITE, "--shape", "24x40", "--layers", "2", "--frames",
                   "1", "--repeats", "1", "--sizes", "", "--sgd", "32")),
    Step("suite", "the test suite on the device (-n 12)", 120, 420,
         [PY, "-m", "pytest", "-q", "-n", "12", "-p", "no:cacheprovider", str(ROOT / "tests")],
         # collected, not run: every test module imports
         [PY, "-m", "pytest", "-q", "-p", "no:cacheprovider", "--collect-only",
          str(ROOT / "tests")]),
    Step("slm-t24", "hologram 1080x1920 RGB, L=32, T=24, pad auto vs PyTorch (goal <= 1.5 ms "
         "per colour-frame)", 70, 200, _slm(1080, 1920, 24), _slm(24, 40, 2, layers=2, repeats=1),
         peer=True),
    Step("fft", "FFT device-resident vs cuFFT (goal <= 1.3x its time)", 90, 240,
         [PY, str(BENCH / "bench_fft.py"), "--sizes",
          "1024,2048,4096,1125x1944,2160x3840,2250,2187x3888", "--batch", "", "--budget", "8",
          "--skip", "numpy,pyfftw,pyvkfft"],
         [PY, str(BENCH / "bench_fft.py"), "--sizes", "32,24x40", "--batch", "", "--rounds",
          "2", "--budget", "1", "--skip", "numpy,pyfftw,pyvkfft"], peer=True),
    Step("sgd-1024", "SGD iteration 1024^2 vs autograd (goal >= 4x)", 30, 120,
         [PY, str(BENCH / "bench_sgd.py"), "--size", "1024", "--iterations", "20", "--rounds",
          "5", "--breakdown"],
         [PY, str(BENCH / "bench_sgd.py"), "--size", "32", "--iterations", "1", "--rounds", "1",
          "--breakdown"], peer=True),
    Step("sgd-2048", "SGD iteration 2048^2, grid 2250^2 vs autograd (goal >= 3x)", 40, 150,
         [PY, str(BENCH / "bench_sgd.py"), "--size", "2048", "--iterations", "20", "--rounds",
          "5", "--breakdown"],
         [PY, str(BENCH / "bench_sgd.py"), "--size", "48", "--iterations", "1", "--rounds", "1",
          "--breakdown"], peer=True),
    Step("hologram-1024", "hologram L=32, 1024^2, pad 2, one colour vs PyTorch (goal >= 3x)", 25,
         150,
         [PY, str(BENCH / "bench_hologram.py"), "--size", "1024", "--pad", "2", "--no-scaling",
          "--no-numpy", "--repeats", "5"],
         [PY, str(BENCH / "bench_hologram.py"), "--size", "32", "--layers", "2", "--pad", "2",
          "--no-scaling", "--no-numpy", "--repeats", "1"], peer=True),
    Step("profile-1024", "per-kernel profile, 1024^2 pad 2, one colour, L=32, T=1 (where the "
         "hologram-1024 step's time goes)", 30, 120,
         _profile("--shape", "1024x1024", "--colours", "1", "--frames", "1", "--pad", "2",
                  "--repeats", "10"),
         _profile("--shape", "32x32", "--colours", "1", "--layers", "2", "--frames", "1",
                  "--pad", "2", "--repeats", "1")),
    Step("pitch", "the CPUs' row pitch on the GPU (2064 for 2048-element rows): the 1024^2 "
         "pad-2 render and SGD's 2048^2 grid, without and with", 40, 150,
         _variants("--variants", "fixed,row-pitch", "--shape", "1024x1024", "--colours", "1",
                   "--frames", "1", "--pad", "2", "--sizes", "", "--sgd", "1024"),
         _variants("--variants", "fixed,row-pitch", "--shape", "32x32", "--colours", "1",
                   "--layers", "2", "--frames", "1", "--repeats", "1", "--pad", "2", "--sizes",
                   "", "--sgd", "32")),
    Step("split", "lines the local memory holds one component of (7680, 8192 points): the split "
         "plan (one launch a pass; a 4K render at pad 2 as two kernels a layer) against the "
         "global stages and four passes before it", 60, 200,
         _variants("--variants", "fixed,no-split", "--shape", "2160x3840", "--frames", "1",
                   "--pad", "2", "--sizes", "8192x8192,4320x7680"),
         _variants("--variants", "fixed,no-split", "--shape", "24x40", "--layers", "2",
                   "--frames", "1", "--repeats", "1", "--pad", "2", "--sizes", "30x40",
                   "--rounds", "2")),
    Step("4k", "hologram 2160x3840 RGB, L=32, T=1 vs PyTorch (goal >= 2x faster)", 100, 200,
         _slm(2160, 3840, 1), _slm(32, 48, 1, layers=2, repeats=1), peer=True),
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
         # the command and its options (its checks take a minute on PoCL)
         [PY, "-m", "clholo.cli", "selftest", "--help"]),
)

#: A lent GPU session's two calls, most important first (docs/benchmarks.md): ``--only`` and
#: ``--budget`` of each. The second call also takes ``--tuning .gpu/tuning.json`` (the first
#: call's), and its budget is lowered to what the session has left (``status``) minus about
#: 90 s for the machine's start and the call's set-up.
PLAN = (
    ("info,tune,variants,slm-t24,4k,sgd-2048", 360),
    ("info,selftest,hologram-1024,display,display-loop,split,profile-slm,suite", 330),
)

# run in a subprocess at the start of a call given --tuning: is the file one clholo wrote, and
# does it hold an entry for the device the steps will use (the key clholo looks it up by)?
_TUNING_CHECK = r"""
import json, sys
from pathlib import Path
from clholo.host import tuning
try:
    devices = tuning._parse(Path(sys.argv[1]))
except Exception as exc:
    print(json.dumps({"bad": f"{type(exc).__name__}: {exc}"}))
    sys.exit(0)
from clholo._version import __version__
from clholo.host import runtime
key = tuning.device_key(runtime.choose_device())
entry = devices.get(key)
print(json.dumps({"device": key, "stored": sorted(devices), "version": __version__,
                  "entry_version": None if entry is None else entry.get("clholo")}))
"""


class _Stop(BaseException):
    """A signal asked the call to stop."""

    def __init__(self, signum: int):
        super().__init__(signum)
        self.signum = signum


def _on_stop_signal(signum, frame):
    # once: a second signal while the step is being stopped and the summary written is ignored
    for sig in STOP_SIGNALS:
        signal.signal(sig, signal.SIG_IGN)
    raise _Stop(signum)


def _die_with_parent() -> None:  # pragma: no cover - runs in the child before exec
    """The step gets SIGKILL if this process dies without stopping it (killed with SIGKILL)."""
    try:
        import ctypes

        ctypes.CDLL(None).prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG
    except Exception:
        pass


def _kill_group(proc: subprocess.Popen) -> None:
    """SIGKILL to the step's process group (it, and whatever it started that is still
    running), then reap it."""
    try:
        os.killpg(proc.pid, signal.SIGKILL)
    except (ProcessLookupError, PermissionError):
        proc.kill()
    proc.wait()


def _write_atomic(path: Path, text: str) -> None:
    tmp = path.with_name(path.name + ".partial")
    tmp.write_text(text)
    os.replace(tmp, path)


def _cell(text: str) -> str:
    return " ".join(str(text).split()).replace("|", "\\|")


def _last_line(path: Path, after: int = 0) -> str:
    """The log's last non-empty line after its first ``after`` bytes (what a failing step said
    last), shortened."""
    try:
        with open(path, "rb") as f:
            f.seek(0, os.SEEK_END)
            f.seek(max(after, f.tell() - 4096))
            lines = [ln for ln in f.read().decode("utf-8", "replace").splitlines() if ln.strip()]
    except OSError:
        return ""
    line = lines[-1].strip() if lines else ""
    return line if len(line) <= 200 else line[:197] + "..."


class _Summary:
    """``OUT/summary.md``: warnings, then one row per step; written whole after each change."""

    def __init__(self, out: Path, command: str):
        self.out = out
        self.command = command
        self.notes: List[str] = []
        self.rows = ["| step | measures | status | seconds |", "|---|---|---|---|"]
        self.tail: List[str] = []

    def row(self, step: Step, status: str, seconds: str = "") -> None:
        self.rows.append(f"| {step.name} | {step.what} | {_cell(status)} | {seconds} |")
        self.write()

    def write(self) -> None:
        head = [f"`{self.command}`", ""] + [f"**{n}**" for n in self.notes]
        text = "\n".join(head + ([""] if self.notes else []) + self.rows + self.tail) + "\n"
        _write_atomic(self.out / "summary.md", text)


def _finite_budget(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        value = float("nan")
    if not math.isfinite(value) or value <= 0:
        raise argparse.ArgumentTypeError(
            f"must be the seconds the call may take (a finite number > 0, e.g. 540), got {text!r}")
    return value


def _check_tuning(ap, path: Path, env: Dict[str, str], timeout: float) -> List[str]:
    """Refuse a file clholo did not write (exit 2); return WARNING lines where no step will use
    it (no entry for this device, or one from another clholo version)."""
    try:
        res = subprocess.run([PY, "-c", _TUNING_CHECK, str(path)], capture_output=True,
                             text=True, cwd=ROOT, env=env, timeout=timeout)
        last = (res.stdout.strip().splitlines() or [""])[-1]
        got = json.loads(last) if res.returncode == 0 else None
    except subprocess.TimeoutExpired:
        return [f"WARNING: --tuning {path}: could not check it against this device (no answer "
                f"in {timeout:.0f} s); the steps may measure the defaults"]
    except ValueError:
        got = None
    if not isinstance(got, dict):
        why = (res.stderr.strip().splitlines() or [f"exit {res.returncode}"])[-1]
        return [f"WARNING: --tuning {path}: could not check it against this device ({why}); "
                f"the steps may measure the defaults"]
    if "bad" in got:
        ap.error(f"--tuning {path}: not a tuning file clholo wrote ({got['bad']}); give the "
                 f"tuning.json an earlier call wrote under its OUT (or leave --tuning out: the "
                 f"defaults)")
    stored = "; ".join(f"`{k}`" for k in got["stored"]) or "none"
    if got["entry_version"] is None:
        return [f"WARNING: --tuning {path} holds no entry for this device, so no step uses it: "
                f"every step measures the project's defaults. Stored: {stored}. This device: "
                f"`{got['device']}`. (Run the step tune in this call, or carry the file from a "
                f"call on the same device and driver.)"]
    if got["entry_version"] != got["version"]:
        return [f"WARNING: --tuning {path}: its entry for this device (`{got['device']}`) was "
                f"measured by clholo {got['entry_version']}, this is {got['version']}: no step "
                f"uses it, every step measures the project's defaults"]
    return []


def main(argv=None) -> int:
    start = time.monotonic()
    names = [s.name for s in STEPS]
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", default=os.environ.get("OUT"),
                    help="folder for the outputs (default: $OUT)")
    ap.add_argument("--budget", type=_finite_budget, default=540.0,
                    help="seconds for the whole call, a hard wall: no step runs past it, and "
                         "steps that would not fit are skipped (default 540: one device call "
                         "of at most 600 s)")
    ap.add_argument("--only", default=None,
                    help="comma-separated step names, in the order given (default: all)")
    ap.add_argument("--tuning", default=None, metavar="FILE",
                    help="a tuning file an earlier call stored (its OUT/tuning.json, carried "
                         "along, e.g. as .gpu/tuning.json): copied to OUT/tuning.json first, so "
                         "a second call on a fresh machine measures the tuned device")
    ap.add_argument("--allow-cpu-peer", action="store_true",
                    help="let the steps that compare against PyTorch use it on the CPU where "
                         "clholo's device is a GPU and torch has no CUDA (refused by default)")
    ap.add_argument("--quick", action="store_true",
                    help="toy sizes, the same options: plumbing only (inside --budget too)")
    ap.add_argument("--list", action="store_true", help="print the steps and exit")
    a = ap.parse_args(argv)
    if a.only is not None:
        wanted = [n.strip() for n in a.only.split(",") if n.strip()]
        if not wanted:
            ap.error(f"--only {a.only!r} names no step; the steps are {', '.join(names)}")
        unknown = [n for n in wanted if n not in names]
        if unknown:
            ap.error(f"--only: no step {', '.join(unknown)}; the steps are {', '.join(names)}")
        twice = sorted({n for n in wanted if wanted.count(n) > 1})
        if twice:
            ap.error(f"--only names {', '.join(twice)} more than once")
        steps = [STEPS[names.index(n)] for n in wanted]
    else:
        steps = list(STEPS)
    if a.list:
        for s in steps:
            print(f"{s.name:<14}{s.expect_s:>5} s  {s.what}{' (vs PyTorch)' if s.peer else ''}"
                  f"\n{'':19}{' '.join(s.argv)}")
        return 0
    if not a.out:
        ap.error("--out is required (or set $OUT)")
    out = Path(a.out)
    if out.exists() and not out.is_dir():
        ap.error(f"--out {out} is a file; give a folder (created where missing)")
    tuning_from = None
    if a.tuning is not None:
        tuning_from = Path(a.tuning)
        if not tuning_from.is_file():
            ap.error(f"--tuning {a.tuning}: no such file; give the tuning.json an earlier "
                     f"call wrote under its OUT (or leave --tuning out: the defaults)")
    deadline = start + a.budget
    # the step "tune" stores the device's tuning here, and every later step's plans take it
    # (benchmarks/fft_variants.py's variants ignore it: they set the settings themselves)
    env = dict(os.environ, CLHOLO_TUNING_FILE=str((out / "tuning.json").resolve()))
    env.pop(PEER_ENV, None)
    notes = []
    if tuning_from is not None:  # refused here, before anything is written, if not clholo's
        notes = _check_tuning(ap, tuning_from, env,
                              max(1.0, min(60.0, deadline - time.monotonic())))
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        ap.error(f"--out {out}: cannot create it ({exc.strerror or exc})")
    summary = _Summary(out, "gpu_checks.py " + " ".join(sys.argv[1:] if argv is None else argv))
    summary.notes = notes
    if a.quick:
        print(f"--quick: every step at toy sizes (plumbing only), inside --budget {a.budget:g} s",
              flush=True)
    if tuning_from is not None:
        if tuning_from.resolve() != (out / "tuning.json").resolve():
            _write_atomic(out / "tuning.json", tuning_from.read_text())
    for note in summary.notes:
        print(note, file=sys.stderr, flush=True)

    state = {"proc": None, "step": None, "t": 0.0, "next": 0}
    saved = {}
    if threading.current_thread() is threading.main_thread():
        saved = {sig: signal.signal(sig, _on_stop_signal) for sig in STOP_SIGNALS}
    try:
        summary.write()
        failed = ran = 0
        for i, s in enumerate(steps):
            state["next"] = i
            left = deadline - time.monotonic() - RESERVE_S
            need = 1.0 if a.quick else s.expect_s
            if need > left:
                why = (f"skipped: takes about {s.expect_s} s, {max(left, 0):.0f} s of --budget "
                       f"left (run it with --only {s.name})")
                summary.row(s, why)
                state["next"] = i + 1
                print(f"{s.name}: {why}", flush=True)
                continue
            limit = min(s.limit_s, left)
            by_budget = left < s.limit_s
            log = out / f"{i:02d}-{s.name}.txt"
            cmd = list(s.quick if a.quick else s.argv)
            step_env = dict(env)
            if s.peer:
                step_env[PEER_ENV] = "any" if a.allow_cpu_peer else "required"
            t = time.monotonic()
            with open(log, "w") as f:
                f.write("$ " + " ".join(cmd) + "\n")
                f.writelines(f"# {note}\n" for note in summary.notes)
                f.flush()
                header = f.tell()
                state.update(step=s, t=t)
                try:
                    # its own session: a step is killed with every process it started (pytest
                    # -n 12's workers would otherwise hold the device into the next step)
                    proc = subprocess.Popen(cmd, stdout=f, stderr=subprocess.STDOUT, cwd=ROOT,
                                            start_new_session=True, env=step_env,
                                            preexec_fn=_die_with_parent)
                except OSError as exc:
                    proc = None
                    status = f"could not start: {exc}"
                if proc is not None:
                    state["proc"] = proc
                    try:
                        rc = proc.wait(timeout=limit)
                        status = "ok" if rc == 0 else f"exit {rc}"
                    except subprocess.TimeoutExpired:
                        status = (f"timed out after {limit:.0f} s ("
                                  + ("the end of --budget" if by_budget else "its limit") + ")")
                    # whatever it started and left running goes with it
                    _kill_group(proc)
                    state["proc"] = None
            state.update(step=None, next=i + 1)
            ran += 1
            secs = time.monotonic() - t
            if status != "ok":
                failed += 1
                said = _last_line(log, header)
                if said:
                    status += f": {said}"
            summary.row(s, status, f"{secs:.1f}")
            print(f"{s.name}: {status} ({secs:.1f} s) -> {log.name}", flush=True)
        if not ran:
            summary.tail = ["", f"no step ran: --budget {a.budget:g} s is less than any of "
                                f"them takes"]
            summary.write()
        print("\n".join(summary.rows + summary.tail))
        for note in summary.notes:  # again, below the table
            print(note, file=sys.stderr, flush=True)
        return 1 if failed or not ran else 0
    except BaseException as exc:
        for sig in saved:
            signal.signal(sig, signal.SIG_IGN)
        why = (f"interrupted by {signal.Signals(exc.signum).name}" if isinstance(exc, _Stop)
               else f"interrupted by an error of gpu_checks.py: {type(exc).__name__}: {exc}")
        _interrupted(summary, state, steps, why)
        if isinstance(exc, _Stop):
            return 128 + exc.signum
        raise
    finally:
        for sig, handler in saved.items():
            signal.signal(sig, handler)


def _interrupted(summary: _Summary, state, steps: Sequence[Step], why: str) -> None:
    """The call was stopped: the running step killed with its processes, its row, the steps
    not run, ``summary.md`` written."""
    proc, step = state["proc"], state["step"]
    if proc is not None:
        _kill_group(proc)
    first = state["next"]
    if step is not None:
        summary.row(step, f"{why} after {time.monotonic() - state['t']:.1f} s: stopped with "
                          f"every process it started",
                    f"{time.monotonic() - state['t']:.1f}")
        first += 1
    else:
        summary.rows.append(f"| (call) | | {_cell(why)} | |")
    for s in steps[first:]:
        summary.rows.append(f"| {s.name} | {s.what} | not run: the call was interrupted | |")
    summary.tail = ["", f"{why}: the summary above is what it did"]
    summary.write()
    print(f"gpu_checks.py: {why}; summary.md written", file=sys.stderr, flush=True)


if __name__ == "__main__":
    sys.exit(main())
