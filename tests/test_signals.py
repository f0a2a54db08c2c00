"""SIGTERM and Ctrl-C as ``docs/errors.md`` says, for every command (issue 26, section 2).

SIGTERM is what SLURM, systemd and ``docker stop`` send; every command handles it as it
handles Ctrl-C: one line ``clholo CMD: interrupted; ...``, exit 130, and nothing half-written
(the files around are exactly what they were before the command).

No timing luck: each command runs in a child process in which one function of its work is
wrapped by a hook that says "reached" (a file) and then waits; the test sends the signal while
the hook waits, so the signal always lands in that function, and only then lets the hook go on.
A signal that is lost (ignored, or handled too late) lets the command finish: exit 0, and the
test fails.
"""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

import clholo
from clholo import cli
from conftest import require_installed

ENV = dict(os.environ, PYTHONUNBUFFERED="1")

# the child: wrap MODULE:ATTR (ATTR may be Class.method) with a hook, then run clholo ARGS
HOOKED_CLI = r"""
import importlib, os, sys, time
ready, go, target, argv = sys.argv[1], sys.argv[2], sys.argv[3], sys.argv[4:]
module, attr = target.split(":")
owner = importlib.import_module(module)
*path, name = attr.split(".")
for part in path:
    owner = getattr(owner, part)
original = getattr(owner, name)

def hooked(*args, **kwargs):
    open(ready, "a").close()
    t = time.monotonic()
    while not os.path.exists(go) and time.monotonic() - t < 120:
        time.sleep(0.01)
    return original(*args, **kwargs)

setattr(owner, name, hooked)
from clholo import cli
sys.exit(cli.main(argv))
"""


def run_interrupted(tmp_path, argv, hook, sig=signal.SIGTERM, *, group=False, env=None,
                    timeout=240):
    """Run ``clholo ARGV`` in ``tmp_path`` with ``hook`` waiting, send ``sig`` once the hook is
    reached (to the whole process group with ``group``, as Ctrl-C on a terminal does), then
    let the hook go on. Returns ``(returncode, stdout, stderr)``."""
    ready, go = tmp_path.parent / f"{tmp_path.name}.ready", tmp_path.parent / f"{tmp_path.name}.go"
    for f in (ready, go):
        f.unlink(missing_ok=True)
    proc = subprocess.Popen([sys.executable, "-c", HOOKED_CLI, str(ready), str(go), hook,
                             *argv], cwd=tmp_path, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env=env or ENV,
                            start_new_session=True)
    try:
        t = time.monotonic()
        while not ready.exists():
            if proc.poll() is not None:
                out, err = proc.communicate()
                raise AssertionError(f"{hook} was never reached (exit {proc.returncode}):\n"
                                     f"{out}\n{err}")
            assert time.monotonic() - t < timeout, f"{hook} was not reached in {timeout} s"
            time.sleep(0.02)
        if group:
            os.killpg(proc.pid, sig)
        else:
            proc.send_signal(sig)
        go.touch()
        out, err = proc.communicate(timeout=timeout)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
        for f in (ready, go):
            f.unlink(missing_ok=True)
    return proc.returncode, out, err


def tree(folder: Path) -> dict:
    """Every path under ``folder`` with its bytes (folders as None)."""
    return {p.relative_to(folder).as_posix(): (None if p.is_dir() else p.read_bytes())
            for p in sorted(folder.rglob("*"))}


@pytest.fixture(scope="module")
def inputs(tmp_path_factory):
    """A 2-layer MPI folder, a render folder of it (a hologram.npz) and a bench file."""
    folder = tmp_path_factory.mktemp("inputs")
    rng = np.random.default_rng(26)
    mpi = clholo.MPI(rng.random((2, 12, 16, 3)), rng.random((2, 12, 16)), [2e-3, 4e-3])
    clholo.io.write_mpi(folder / "scene", mpi)
    assert cli.main(["render", str(folder / "scene"), "--frames", "1", "--out",
                     str(folder / "run"), "--progress", "off"]) == 0
    from test_capture import BENCH

    (folder / "bench.toml").write_text(BENCH.replace('luts = ["red.lut", "green.lut"]\n', "")
                                       .replace('phase_luts = ["linear:230", '
                                                '"measured_green.csv"]\n', ""))
    np.save(folder / "patterns.npy", rng.integers(0, 256, (1, 2, 8, 12), dtype=np.uint8))
    (folder / "m.csv").write_text(f"id,input,frames\na,{folder / 'scene'},1\n")
    return folder


def _case(name, argv, hook, note="nothing written"):
    return pytest.param(argv, hook, note, id=name)


WRITING = "clholo.io.output:_sha256"   # the output complete under its temporary name, not renamed

CASES = [
    _case("render-loading", ["render", "{in}/scene", "--frames", "1", "--out", "o"],
          "clholo.scenes:load"),
    _case("render-rendering", ["render", "{in}/scene", "--frames", "1", "--out", "o"],
          "clholo.host.runtime:launch"),  # a kernel launch of the render
    _case("render-writing", ["render", "{in}/scene", "--frames", "1", "--out", "o"], WRITING),
    _case("demo", ["demo", "--scale", "0.05", "--frames", "1", "--layers", "2", "--out", "o"],
          WRITING),
    _case("encode", ["encode", "{in}/run/hologram.npz", "--method", "dpac", "--slm-size", "12",
                     "16", "--out", "o"], WRITING),
    _case("display", ["display", "{in}/scene", "--memory", "--seconds", "60"],
          "clholo.tools.slm:MemoryDisplay.show", "the display was closed; nothing written"),
    _case("capture", ["capture", "focal-sweep", "--config", "{in}/bench.toml", "--patterns",
                      "{in}/patterns.npy", "--out", "o", "--simulate", "--speedup", "400"],
          WRITING, "the stage was stopped and closed; nothing written"),
    _case("selftest", ["selftest", "--quick", "--json", "r.json"],
          "clholo.host.runtime:get_queue"),
    _case("bench", ["bench", "--size", "16", "--layers", "2", "--repeats", "1", "--no-scaling"],
          "clholo.bench:_timed"),  # a timed run of the table (_time_peers)
    _case("report", ["report", "{in}/run", "--out", "r.html"], WRITING),
    _case("batch", ["batch", "{in}/m.csv", "--out", "o", "--workers", "1"],
          "distributed:SpecCluster.__init__",
          "complete items are kept; run the same command again to finish"),
]


@pytest.mark.parametrize("argv, hook, note", CASES)
def test_sigterm_is_one_line_exit_130_and_nothing_written(tmp_path, inputs, argv, hook, note):
    if hook.startswith("distributed:"):
        pytest.importorskip("distributed")
    argv = [a.replace("{in}", str(inputs)) for a in argv] + ["--progress", "off"]
    before, run_before = tree(tmp_path), tree(inputs / "run")
    rc, out, err = run_interrupted(tmp_path, argv, hook)
    lines = err.strip().splitlines()
    command = " ".join(argv[:2]) if argv[0] == "capture" else argv[0]
    assert rc == 130, (out, err)
    assert "Traceback" not in err, err
    if argv[0] == "batch":  # it names what it kept: nothing here
        assert lines[-1].startswith("clholo batch: interrupted; 0 of 1 item(s) complete in "), err
    else:
        assert lines[-1] == f"clholo {command}: interrupted; {note}", err
    assert sum("interrupted" in line for line in lines) == 1, err
    assert tree(tmp_path) == before  # nothing half-written, nothing temporary left
    assert tree(inputs / "run") == run_before


def test_experiment_sigterm(tmp_path):
    """The hook holds the study where it starts loading its first scene (inside its output
    folder's temporary name): no data is read, so a --data folder whose twain-mpi/ holds an
    unread mpi.json does (the folder the scene needs is checked before any work)."""
    data = tmp_path.parent / f"{tmp_path.name}-data"
    (data / "twain-mpi").mkdir(parents=True)
    (data / "twain-mpi" / "mpi.json").write_text("{}")
    argv = ["experiment", "layers", "--data", str(data), "--scenes", "twain",
            "--methods", "mpi", "--layers", "2", "4", "--frames", "1", "--width", "16",
            "--out", "o", "--progress", "off"]
    rc, out, err = run_interrupted(tmp_path, argv, "clholo.experiments.layers:prepare_scene")
    assert rc == 130, (out, err)
    assert err.strip().splitlines()[-1].startswith("clholo experiment layers: interrupted; "
                                                   "nothing written"), err
    assert "Traceback" not in err and tree(tmp_path) == {}


@pytest.mark.parametrize("hook, line", [
    ("clholo.batch:_local_devices", "clholo batch: interrupted; complete items are kept; run "
                                    "the same command again to finish"),
    ("clholo.batch:_clean_staging", "clholo batch: interrupted; 0 of 1 item(s) complete"),
    ("distributed:SpecCluster.__init__", "clholo batch: interrupted; 0 of 1 item(s) complete"),
], ids=["choosing-devices", "in-the-lock", "workers-starting"])
@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["ctrl-c", "sigterm"])
def test_batch_interrupt_in_its_first_second_is_not_lost(tmp_path, inputs, sig, hook, line):
    """Ctrl-C right after Enter (the batch's first second: devices, the lock, its workers
    starting) ends the batch with 130, renders nothing and leaves no folder; before issue 26
    SIGINT was ignored while the workers started, so the batch went on to render every item and
    exit 0."""
    pytest.importorskip("distributed")
    argv = ["batch", str(inputs / "m.csv"), "--out", "o", "--workers", "1", "--progress", "off"]
    rc, out, err = run_interrupted(tmp_path, argv, hook, sig, group=sig == signal.SIGINT)
    assert rc == 130, (out, err)
    lines = err.strip().splitlines()
    assert lines[-1].startswith(line), err
    assert "Traceback" not in err and tree(tmp_path) == {}, err


def test_debug_keeps_the_traceback_and_the_exit_code(tmp_path, inputs):
    """``--debug`` adds the traceback; the exit code stays the documented one (not Python's 1)."""
    for argv, code in ((["render", str(inputs / "scene"), "--pad", "1e9", "--out", "o"], 2),
                       (["info"], 3)):
        env = dict(ENV, CLHOLO_DEVICE="nonsense") if code == 3 else ENV
        proc = subprocess.run([sys.executable, "-m", "clholo.cli", *argv, "--debug"],
                              cwd=tmp_path, capture_output=True, text=True, env=env,
                              timeout=120)
        assert proc.returncode == code, proc.stderr
        assert "Traceback (most recent call last)" in proc.stderr
        assert f"clholo {argv[0]}: error: " in proc.stderr
    assert tree(tmp_path) == {}


def test_sigterm_handler_is_restored_after_main(monkeypatch):
    """``cli.main`` called from Python puts back the caller's SIGTERM handler."""
    from clholo.commands import info

    seen = []
    monkeypatch.setattr(info, "cmd_info", lambda args: seen.append(
        signal.getsignal(signal.SIGTERM)) or 0)
    before = signal.getsignal(signal.SIGTERM)
    assert cli.main(["info"]) == 0
    assert seen and seen[0] is not before and signal.getsignal(signal.SIGTERM) is before



# ---- the console script: a signal while the package imports ------------------------------------

# put first on PYTHONPATH, it holds the import of HOLD_MODULE (the first time it is asked for):
# it says "reached" (a file), then waits for the test's "go" (a file)
HOLD_IMPORT = r"""
import os, sys, time

class _Hold:
    def find_spec(self, name, path=None, target=None):
        if name == os.environ["HOLD_MODULE"]:
            sys.meta_path.remove(self)
            open(os.environ["HOLD_READY"], "a").close()
            t = time.monotonic()
            while not os.path.exists(os.environ["HOLD_GO"]) and time.monotonic() - t < 120:
                time.sleep(0.01)
        return None

sys.meta_path.insert(0, _Hold())
"""


def console_script() -> Path:
    """The installed ``clholo`` script of this environment (editable or not)."""
    require_installed()
    script = Path(sys.executable).parent / "clholo"
    assert script.is_file(), f"no console script {script}: pip install -e . (or .[pocl,test])"
    return script


def test_the_console_script_enters_through_the_light_module():
    from importlib.metadata import entry_points

    require_installed()
    (ep,) = [ep for ep in entry_points(group="console_scripts") if ep.name == "clholo"]
    assert ep.value == "clholo_entry:main", (
        f"{ep.value}: setup.cfg names clholo_entry:main; reinstall (pip install -e .)")
    assert "clholo_entry" in console_script().read_text()


def signal_while_importing(tmp_path, sig, module, argv, *, ignore_sigint=False):
    """Run the ``clholo`` script with ``argv``, hold the import of ``module``, send ``sig``
    (SIGINT to the process group, as Ctrl-C does), let the import go on; ``(proc, out, err,
    work)``."""
    hold = tmp_path / "hold"
    hold.mkdir()
    (hold / "sitecustomize.py").write_text(HOLD_IMPORT)
    work = tmp_path / "work"
    work.mkdir()
    ready, go = tmp_path / "ready", tmp_path / "go"
    env = dict(ENV, PYTHONPATH=os.pathsep.join([str(hold), *filter(None, [
        os.environ.get("PYTHONPATH")])]), HOLD_MODULE=module, HOLD_READY=str(ready),
        HOLD_GO=str(go))
    proc = subprocess.Popen([str(console_script()), *argv], cwd=work,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env,
                            start_new_session=True, preexec_fn=(lambda: signal.signal(
                                signal.SIGINT, signal.SIG_IGN)) if ignore_sigint else None)
    try:
        t = time.monotonic()
        while not ready.exists():
            if proc.poll() is not None:
                out, err = proc.communicate()
                raise AssertionError(f"the import of {module} was never held "
                                     f"(exit {proc.returncode}):\n{out}\n{err}")
            assert time.monotonic() - t < 60, f"the import of {module} was not reached"
            time.sleep(0.01)
        os.killpg(proc.pid, sig) if sig == signal.SIGINT else proc.send_signal(sig)
        go.touch()
        out, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    return proc, out, err, work


@pytest.mark.parametrize("module", ["numpy", "clholo.cli"])
@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["ctrl-c", "sigterm"])
def test_a_signal_while_the_package_imports_is_one_line_and_130(tmp_path, sig, module):
    """Before issue 26's leftovers the script imported ``clholo.cli`` (NumPy, PyOpenCL, about a
    second) before any handler was in place: SIGTERM then exited 143 with no word and Ctrl-C
    printed a traceback. The signal is sent while the import of ``module`` is held (NumPy: the
    first heavy import; ``clholo.cli``: the package's own)."""
    proc, out, err, work = signal_while_importing(tmp_path, sig, module,
                                                  ["render", "scene", "--out", "o"])
    assert proc.returncode == 130, (proc.returncode, out, err)
    assert err.splitlines() == ["clholo: interrupted; nothing written"], err
    assert out == "" and list(work.iterdir()) == []


def test_an_ignored_ctrl_c_stays_ignored(tmp_path):
    """A caller that ignores SIGINT (a shell's ``clholo ... &``) keeps it ignored: the script
    runs on, as Python alone would."""
    from clholo._version import __version__

    proc, out, err, _ = signal_while_importing(tmp_path, signal.SIGINT, "numpy", ["--version"],
                                               ignore_sigint=True)
    assert proc.returncode == 0 and out.strip() == f"clholo {__version__}", (out, err)


def test_importing_the_library_installs_no_signal_handler():
    """``import clholo`` (and ``clholo.cli``) has no side effect on a Python user's signals; the
    entry module installs its handling only when the script calls its ``main``."""
    code = ("import signal, sys\n"
            "before = [signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)]\n"
            "import clholo_entry\n"
            "assert not {'numpy', 'pyopencl', 'clholo'} & set(sys.modules), sorted(sys.modules)\n"
            "import clholo, clholo.cli, clholo.commands.render\n"
            "after = [signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)]\n"
            "assert after == before == [signal.default_int_handler, signal.SIG_DFL], after\n")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          env=ENV, timeout=120)
    assert proc.returncode == 0, proc.stderr


def test_python_m_clholo_is_the_command_line(tmp_path):
    """``python -m clholo`` runs the console script's entry point: its version line, and a
    mistake's exit code 2 with the one-line error (not a traceback, not ``__main__.py``)."""
    require_installed()  # clholo_entry is the installed distribution's top-level module
    run = [sys.executable, "-m", "clholo"]
    proc = subprocess.run(run + ["--version"], capture_output=True, text=True, cwd=tmp_path,
                          timeout=120)
    assert proc.returncode == 0 and proc.stdout.strip() == f"clholo {clholo.__version__}"
    proc = subprocess.run(run + ["no-such-command"], capture_output=True, text=True,
                          cwd=tmp_path, timeout=120)
    assert proc.returncode == 2, proc.stderr
    assert proc.stderr.startswith("usage: clholo ") and "invalid choice" in proc.stderr
    assert "Traceback" not in proc.stderr
