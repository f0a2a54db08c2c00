"""``benchmarks/gpu_checks.py``: the prepared run of issue 23's measurements for a lent GPU.
A GPU session has minutes, so every step's command is run here at toy sizes (``--quick``) with
the full command's flags, the plan's two calls as the session makes them, and the budget, skip,
failure, time-limit, stop (signals, errors), tuning and PyTorch-peer paths are checked on
stand-in steps. Nothing here can hang: every subprocess has a timeout, and the stand-in steps'
processes are killed by the test where the script failed to."""

import importlib.util
import json
import os
import re
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "benchmarks" / "gpu_checks.py"
PY = sys.executable


def _module():
    spec = importlib.util.spec_from_file_location("gpu_checks", SCRIPT)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _has_torch():
    return importlib.util.find_spec("torch") is not None


def _gone(pid: int) -> bool:
    """The process is gone, or a zombie nobody has reaped yet (its parent was killed too)."""
    stat = Path(f"/proc/{pid}/stat")
    try:
        return stat.read_text().rsplit(")", 1)[1].split()[0] == "Z"
    except (FileNotFoundError, ProcessLookupError):
        return True


def _wait_gone(pids, seconds=10.0):
    end = time.monotonic() + seconds
    while time.monotonic() < end and not all(_gone(p) for p in pids):
        time.sleep(0.05)
    return [p for p in pids if not _gone(p)]


def _kill(pids):
    for p in pids:
        try:
            os.kill(p, signal.SIGKILL)
        except (ProcessLookupError, PermissionError):
            pass


def _rows(summary: str):
    return {line.split("|")[1].strip(): line for line in summary.splitlines()
            if line.startswith("| ") and not line.startswith("| step |")}


# a stand-in step that starts a child of its own (as pytest -n starts workers), writes both
# pids to PIDS, then sleeps: the child must go with it
def _sleeper(pids_file: Path, seconds: int = 60):
    return [PY, "-c", "import os, subprocess, sys, time; "
            "c = subprocess.Popen([sys.executable, '-c', 'import time; time.sleep(120)']); "
            f"open({str(pids_file)!r} + '.tmp', 'w').write(f'{{os.getpid()}} {{c.pid}}'); "
            f"os.replace({str(pids_file)!r} + '.tmp', {str(pids_file)!r}); "
            f"time.sleep({seconds})"]


def test_every_step_names_files_that_exist_and_lists():
    mod = _module()
    names = [s.name for s in mod.STEPS]
    assert len(names) == len(set(names))
    for s in mod.STEPS:
        assert 0 < s.expect_s <= s.limit_s <= 600, s.name
        for arg in list(s.argv) + list(s.quick):
            if arg.endswith(".py"):
                assert Path(arg).is_file(), (s.name, arg)
    res = subprocess.run([PY, str(SCRIPT), "--list"], capture_output=True, text=True, timeout=60)
    assert res.returncode == 0, res.stderr
    assert all(name in res.stdout for name in names)
    for only, _ in mod.PLAN:
        assert set(only.split(",")) <= set(names), only


def _flags(argv):
    """``--flag`` -> its value (the next argument, or None), of a step's command."""
    argv = list(argv)
    return {a: (argv[i + 1] if i + 1 < len(argv) and not argv[i + 1].startswith("--") else None)
            for i, a in enumerate(argv) if a.startswith("--")}


def test_quick_commands_take_the_full_commands_flags():
    """--quick runs what the GPU runs, at toy sizes: every flag of a step's full command is in
    its quick one (a renamed or removed flag then fails the quick run here), with the same
    variant names, skipped contenders and choices; the steps that compare against PyTorch are
    the ones marked as such (they run with CLHOLO_BENCH_PEER)."""
    mod = _module()
    same_value = ("--variants", "--skip", "--fuse", "--colours", "--loop", "--variant")
    for s in mod.STEPS:
        full, quick = _flags(s.argv), _flags(s.quick)
        assert set(full) <= set(quick), (s.name, set(full) - set(quick))
        for flag in same_value:
            if flag in full:
                assert quick[flag] == full[flag], (s.name, flag)
        assert s.argv[:3] == s.quick[:3] or s.argv[:2] == s.quick[:2], s.name
        peers = any(k in " ".join(s.argv) for k in ("run_slm_benchmark", "bench_sgd.py",
                                                     "bench_hologram.py", "bench_fft.py"))
        assert s.peer == peers, s.name
    from clholo import bench

    assert mod.PEER_ENV == bench.PEER_ENV


def _ok_or_no_torch(rows, out: Path, steps, index_of):
    for s in steps:
        row = rows[s.name]
        if "| ok |" not in row:
            log = (out / f"{index_of[s.name]:02d}-{s.name}.txt").read_text()
            assert s.peer and not _has_torch() and "no PyTorch peer" in row, (row, log[-2000:])


def test_quick_run_of_the_plan_and_of_every_other_step(tmp_path):
    """The plan's two calls as a session makes them (the second with the first's tuning file,
    which then holds this device's entry: no warning), at toy sizes on this device, then every
    step the plan leaves out: a GPU session must not lose its minutes to a wrong flag."""
    mod = _module()
    by_name = {s.name: s for s in mod.STEPS}
    (only1, budget1), (only2, budget2) = mod.PLAN
    out1, out2, out3 = tmp_path / "call1", tmp_path / "call2", tmp_path / "rest"
    res1 = subprocess.run([PY, str(SCRIPT), "--quick", "--out", str(out1), "--budget",
                           str(budget1), "--only", only1], capture_output=True, text=True,
                          timeout=600)
    assert (out1 / "tuning.json").is_file(), res1.stdout + res1.stderr
    res2 = subprocess.run([PY, str(SCRIPT), "--quick", "--out", str(out2), "--budget",
                           str(budget2), "--tuning", str(out1 / "tuning.json"), "--only", only2],
                          capture_output=True, text=True, timeout=600)
    rest = [s.name for s in mod.STEPS if s.name not in set(only1.split(",") + only2.split(","))]
    res3 = subprocess.run([PY, str(SCRIPT), "--quick", "--out", str(out3), "--only",
                           ",".join(rest)], capture_output=True, text=True, timeout=600)
    for res, out, only in ((res1, out1, only1), (res2, out2, only2), (res3, out3, ",".join(rest))):
        names = only.split(",")
        summary = (out / "summary.md").read_text()
        rows = _rows(summary)
        assert set(rows) == set(names), summary
        _ok_or_no_torch(rows, out, [by_name[n] for n in names],
                        {n: i for i, n in enumerate(names)})
        assert res.returncode == (0 if all("| ok |" in r for r in rows.values()) else 1), summary
        assert "WARNING" not in summary and "WARNING" not in res.stderr, summary
        assert not list(out.glob("*.partial"))
    assert (out2 / "tuning.json").read_text() == (out1 / "tuning.json").read_text()


def test_budget_failures_and_time_limits(tmp_path, monkeypatch, capsys):
    mod = _module()
    monkeypatch.setattr(mod, "STEPS", (
        mod.Step("fails", "a failing step", 1, 30,
                 [PY, "-c", "print('the reason it failed'); raise SystemExit(3)"], []),
        mod.Step("slow", "a step past its limit", 1, 1, _sleeper(tmp_path / "pids", 20), []),
        mod.Step("big", "a step longer than the budget", 10_000, 10_000, [PY, "-c", "pass"], []),
        mod.Step("fine", "a step that works", 1, 30, [PY, "-c", "print('hello')"], []),
    ))
    rc = mod.main(["--out", str(tmp_path), "--budget", "100"])
    assert rc == 1
    summary = (tmp_path / "summary.md").read_text()
    # the status says what the step said last
    assert "| fails | a failing step | exit 3: the reason it failed |" in summary
    assert "timed out after 1 s (its limit)" in summary
    # the step's own child was killed with it
    assert not _wait_gone([int(p) for p in (tmp_path / "pids").read_text().split()])
    assert "| big | a step longer than the budget | skipped" in summary
    assert "--only big" in summary
    assert "| fine | a step that works | ok |" in summary
    assert "hello" in (tmp_path / "03-fine.txt").read_text()
    assert not (tmp_path / "02-big.txt").exists()
    # each skipped step is printed as it is skipped
    assert re.search(r"^big: skipped: takes about 10000 s", capsys.readouterr().out, re.M)


def test_a_step_leaves_nothing_running_when_it_ends(tmp_path, monkeypatch):
    """A step that exits on its own but leaves a child running (a worker it did not stop):
    the child is killed with the step's process group, before the next step."""
    mod = _module()
    pids = tmp_path / "pids"
    code = (f"import subprocess, sys; c = subprocess.Popen([sys.executable, '-c', "
            f"'import time; time.sleep(120)']); open({str(pids)!r}, 'w').write(str(c.pid))")
    monkeypatch.setattr(mod, "STEPS", (mod.Step("leaves", "leaves a child", 1, 30,
                                                [PY, "-c", code], []),))
    try:
        assert mod.main(["--out", str(tmp_path / "out"), "--budget", "60"]) == 0
        assert not _wait_gone([int(pids.read_text())])
    finally:
        if pids.exists():
            _kill([int(pids.read_text())])


@pytest.mark.parametrize("quick", [False, True])
def test_the_budget_is_a_hard_wall(tmp_path, monkeypatch, capsys, quick):
    """No step runs past --budget, whatever its own limit (its limit is cut to what is left,
    a few seconds kept to stop it and write the summary), --quick included; the steps after it
    are skipped, each printed; a call where no step ran exits 1."""
    mod = _module()
    monkeypatch.setattr(mod, "RESERVE_S", 1.0)
    slow = _sleeper(tmp_path / "pids", 60)
    monkeypatch.setattr(mod, "STEPS", (
        mod.Step("long", "longer than the budget allows", 1, 300, slow, slow),
        mod.Step("next", "after it", 1, 30, [PY, "-c", "pass"], [PY, "-c", "pass"]),
    ))
    t = time.monotonic()
    args = ["--out", str(tmp_path / "out"), "--budget", "5"] + (["--quick"] if quick else [])
    try:
        assert mod.main(args) == 1
    finally:
        if (tmp_path / "pids").exists():
            _kill([int(p) for p in (tmp_path / "pids").read_text().split()])
    assert time.monotonic() - t < 5.0 + 1.5
    rows = _rows((tmp_path / "out" / "summary.md").read_text())
    assert re.search(r"timed out after [34] s \(the end of --budget\)", rows["long"]), rows
    assert "skipped" in rows["next"], rows
    assert re.search(r"^next: skipped", capsys.readouterr().out, re.M)
    # no step fits at all: nothing ran, and the exit status says so
    assert mod.main(["--out", str(tmp_path / "none"), "--budget", "1.5"]) == 1
    assert "no step ran" in (tmp_path / "none" / "summary.md").read_text()


_WRAPPER = """
import importlib.util, sys
spec = importlib.util.spec_from_file_location("gpu_checks", {script!r})
mod = importlib.util.module_from_spec(spec)
spec.loader.exec_module(mod)
py = sys.executable
mod.STEPS = (
    mod.Step("first", "a quick one", 1, 30, [py, "-c", "print('first')"], []),
    mod.Step("slow", "sleeps with a child", 1, 300, {slow!r}, []),
    mod.Step("after", "never starts", 1, 30, [py, "-c", "pass"], []),
)
sys.exit(mod.main(sys.argv[1:]))
"""


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT, signal.SIGKILL],
                         ids=["SIGTERM", "SIGINT", "SIGKILL"])
def test_a_stopped_call_stops_its_step_and_writes_the_summary(tmp_path, sig):
    """`timeout` sends SIGTERM, Ctrl-C SIGINT: the running step (in a session of its own) is
    killed with the process it started, summary.md holds the finished row, an "interrupted"
    row and the step not run, and the call exits 128 + the signal. Killed with SIGKILL (no
    handler runs), the step still dies with it."""
    pids = tmp_path / "pids"
    wrapper = tmp_path / "wrapper.py"
    wrapper.write_text(_WRAPPER.format(script=str(SCRIPT), slow=_sleeper(pids, 120)))
    out = tmp_path / "out"
    proc = subprocess.Popen([PY, str(wrapper), "--out", str(out), "--budget", "200"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    started = []
    try:
        end = time.monotonic() + 60
        while not pids.exists() and time.monotonic() < end and proc.poll() is None:
            time.sleep(0.05)
        assert pids.exists(), proc.communicate(timeout=30)
        started = [int(p) for p in pids.read_text().split()]
        proc.send_signal(sig)
        stdout, stderr = proc.communicate(timeout=30)
        # killed with SIGKILL, no handler runs: the step dies with it (PR_SET_PDEATHSIG), the
        # step's own child is left to the machine (the step's session ends with the call's)
        left = _wait_gone(started[:1] if sig == signal.SIGKILL else started)
        assert not left, "the step or its child outlived the call"
    finally:
        proc.kill()
        proc.wait(timeout=30)
        _kill(started)
    if sig == signal.SIGKILL:
        return
    assert proc.returncode == 128 + sig, (proc.returncode, stderr)
    summary = (out / "summary.md").read_text()
    rows = _rows(summary)
    assert "| ok |" in rows["first"]
    assert f"interrupted by {sig.name}" in rows["slow"], summary
    assert "not run" in rows["after"], summary
    assert not list(out.glob("*.partial"))
    assert "summary.md written" in stderr


def test_an_error_of_its_own_stops_the_step_and_writes_the_summary(tmp_path, monkeypatch):
    """Any exception in gpu_checks.py itself (here, while it waits on the step) kills the step
    with its processes and writes the summary, then propagates (exit status non-zero)."""
    mod = _module()
    pids = tmp_path / "pids"
    monkeypatch.setattr(mod, "STEPS", (mod.Step("slow", "sleeps", 1, 300, _sleeper(pids), []),))
    real_wait = subprocess.Popen.wait

    def wait(self, timeout=None):
        if timeout is not None:  # the step's wait: fail once it has started its child
            end = time.monotonic() + 30
            while not pids.exists() and time.monotonic() < end:
                time.sleep(0.05)
            raise RuntimeError("the harness broke")
        return real_wait(self, timeout)

    monkeypatch.setattr(subprocess.Popen, "wait", wait)
    try:
        with pytest.raises(RuntimeError, match="the harness broke"):
            mod.main(["--out", str(tmp_path / "out"), "--budget", "100"])
        assert not _wait_gone([int(p) for p in pids.read_text().split()])
    finally:
        if pids.exists():
            _kill([int(p) for p in pids.read_text().split()])
    rows = _rows((tmp_path / "out" / "summary.md").read_text())
    assert "interrupted by an error of gpu_checks.py: RuntimeError: the harness broke" in \
        rows["slow"]


def test_sigint_in_process_restores_the_handlers(tmp_path, monkeypatch):
    """main() called in a process (as here) takes SIGINT while a step runs, returns 130, and
    leaves the process's own signal handlers as they were."""
    if threading.current_thread() is not threading.main_thread():
        pytest.skip("signal handlers are set from the main thread only (main() sets none here)")
    mod = _module()
    pids = tmp_path / "pids"
    monkeypatch.setattr(mod, "STEPS", (mod.Step("slow", "sleeps", 1, 300, _sleeper(pids), []),))
    before = signal.getsignal(signal.SIGINT)

    def interrupt():
        end = time.monotonic() + 30
        while not pids.exists() and time.monotonic() < end:
            time.sleep(0.05)
        os.kill(os.getpid(), signal.SIGINT)

    timer = threading.Thread(target=interrupt, daemon=True)
    timer.start()
    try:
        assert mod.main(["--out", str(tmp_path / "out"), "--budget", "100"]) == 130
        assert not _wait_gone([int(p) for p in pids.read_text().split()])
    finally:
        timer.join(timeout=30)
        if pids.exists():
            _kill([int(p) for p in pids.read_text().split()])
    assert signal.getsignal(signal.SIGINT) is before
    assert "interrupted by SIGINT" in (tmp_path / "out" / "summary.md").read_text()


def _tuning_file(path: Path, device_key: str, version: str):
    path.write_text(json.dumps({"format": "clholo-tuning", "version": 1, "devices": {
        device_key: {"clholo": version, "settings": {}}}}))
    return path


def _this_device_key():
    from clholo.host import runtime, tuning

    return tuning.device_key(runtime.choose_device())


def test_a_tuning_file_from_an_earlier_call_reaches_every_step(tmp_path, monkeypatch, capsys):
    """--tuning: the first call's OUT/tuning.json, carried to a fresh machine, is what every
    step of the second call sees (CLHOLO_TUNING_FILE=OUT/tuning.json); with this device's
    entry, no warning."""
    from clholo._version import __version__

    mod = _module()
    monkeypatch.setattr(mod, "STEPS", (
        mod.Step("show", "prints the tuning file it sees", 1, 30,
                 [PY, "-c", "import os; print(open(os.environ['CLHOLO_TUNING_FILE']).read())"],
                 []),))
    carried = _tuning_file(tmp_path / "carried.json", _this_device_key(), __version__)
    out = tmp_path / "out"
    assert mod.main(["--out", str(out), "--tuning", str(carried)]) == 0
    assert (out / "tuning.json").read_text() == carried.read_text()
    assert _this_device_key() in (out / "00-show.txt").read_text()
    assert "WARNING" not in (out / "summary.md").read_text()
    # given its own OUT/tuning.json (a warm machine's second call), it is left as it is
    assert mod.main(["--out", str(out), "--tuning", str(out / "tuning.json")]) == 0
    assert (out / "tuning.json").read_text() == carried.read_text()
    assert "WARNING" not in capsys.readouterr().err


@pytest.mark.parametrize("whose", ["another device", "another version"])
def test_a_tuning_file_no_step_uses_is_a_loud_warning(tmp_path, monkeypatch, capsys, whose):
    """A tuning file without this device's entry (another GPU, another driver) or measured by
    another clholo is used by no step: a WARNING naming the devices stored and this one, at
    the start, at the top of summary.md and of every step's log."""
    from clholo._version import __version__

    mod = _module()
    monkeypatch.setattr(mod, "STEPS", (mod.Step("one", "a step", 1, 30, [PY, "-c", "pass"], []),))
    other = "NVIDIA CUDA | NVIDIA Corporation | NVIDIA H100 80GB HBM3 | driver 550.54"
    key, version = ((other, __version__) if whose == "another device"
                    else (_this_device_key(), "0.0.0-old"))
    carried = _tuning_file(tmp_path / "carried.json", key, version)
    out = tmp_path / "out"
    assert mod.main(["--out", str(out), "--tuning", str(carried)]) == 0
    summary = (out / "summary.md").read_text()
    log = (out / "00-one.txt").read_text()
    err = capsys.readouterr().err
    for text in (summary, log, err):
        assert "WARNING: --tuning" in text and "every step measures the project's defaults" in \
            text, text
        assert _this_device_key() in text
        if whose == "another device":
            assert other in text and "no entry for this device" in text
        else:
            assert "0.0.0-old" in text


@pytest.mark.parametrize("text", ['{"format": "clholo-tuning", "from": "call 1"}', "{}",
                                  "not json", '{"format": "clholo-tuning", "version": 1}'])
def test_a_tuning_file_clholo_did_not_write_is_refused_at_the_start(tmp_path, text):
    bad = tmp_path / "bad.json"
    bad.write_text(text)
    out = tmp_path / "out"
    res = subprocess.run([PY, str(SCRIPT), "--out", str(out), "--tuning", str(bad), "--only",
                          "info"], capture_output=True, text=True, timeout=120)
    assert res.returncode == 2, res.stderr
    assert f"--tuning {bad}: not a tuning file clholo wrote" in res.stderr
    assert not out.exists()


def test_peer_steps_run_with_the_peer_rule(tmp_path, monkeypatch):
    """The steps that compare against PyTorch run with CLHOLO_BENCH_PEER=required (=any with
    --allow-cpu-peer); the others without it, whatever the caller's environment says."""
    mod = _module()
    show = [PY, "-c", f"import os; print('rule', os.environ.get({mod.PEER_ENV!r}))"]
    monkeypatch.setattr(mod, "STEPS", (mod.Step("vs", "vs PyTorch", 1, 30, show, [], True),
                                       mod.Step("own", "no peer", 1, 30, show, [])))
    monkeypatch.setenv(mod.PEER_ENV, "stray")
    assert mod.main(["--out", str(tmp_path / "a")]) == 0
    assert "rule required" in (tmp_path / "a" / "00-vs.txt").read_text()
    assert "rule None" in (tmp_path / "a" / "01-own.txt").read_text()
    assert mod.main(["--out", str(tmp_path / "b"), "--allow-cpu-peer"]) == 0
    assert "rule any" in (tmp_path / "b" / "00-vs.txt").read_text()


def test_a_missing_pytorch_peer_fails_the_step(tmp_path):
    """Without torch, a step that compares against it fails (it does not report "ok" with the
    PyTorch column left out), and summary.md says why."""
    fake = tmp_path / "site" / "torch"
    fake.mkdir(parents=True)
    (fake / "__init__.py").write_text("raise ImportError('simulated: no torch here')\n")
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(
        [str(tmp_path / "site"), str(ROOT), os.environ.get("PYTHONPATH", "")]))
    out = tmp_path / "out"
    res = subprocess.run([PY, str(SCRIPT), "--quick", "--out", str(out), "--only",
                          "hologram-1024,slm-t3,info"], capture_output=True, text=True,
                         timeout=300, env=env)
    assert res.returncode == 1, res.stdout + res.stderr
    rows = _rows((out / "summary.md").read_text())
    for name in ("hologram-1024", "slm-t3"):
        assert "exit 1: no PyTorch peer: torch is not installed" in rows[name], rows[name]
    assert "| ok |" in rows["info"]


@pytest.mark.parametrize("args, message", [
    (["--only", "nosuch"], "no step nosuch"),
    (["--only", ","], "names no step"),
    (["--only", "info,info"], "info more than once"),
    (["--budget", "0"], "--budget"), (["--budget", "nan"], "argument --budget: must be"),
    (["--budget", "inf"], "argument --budget: must be"), (["--budget", "-5"], "--budget"),
    (["--tuning", "/no/such/tuning.json"], "--tuning /no/such/tuning.json: no such file"),
    (["--out-is-a-file"], "is a file; give a folder"),
    ([], "--out is required")])
def test_bad_arguments_name_the_fix(tmp_path, args, message):
    if args == ["--out-is-a-file"]:
        (tmp_path / "afile").write_text("")
        out, args = ["--out", str(tmp_path / "afile")], []
    else:
        out = [] if args == [] else ["--out", str(tmp_path / "out")]
    res = subprocess.run([PY, str(SCRIPT), *out, *args], capture_output=True,
                         text=True, timeout=60, env={k: v for k, v in os.environ.items()
                                                     if k != "OUT"})
    assert res.returncode == 2 and message in res.stderr, res.stderr
    assert "Traceback" not in res.stderr
    assert not (tmp_path / "out" / "summary.md").exists()


def _fft_variants():
    spec = importlib.util.spec_from_file_location("fft_variants",
                                                  ROOT / "benchmarks" / "fft_variants.py")
    fv = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(fv)
    return fv


def test_fft_variants_step_names_known_variants_and_survives_a_failing_one(monkeypatch, capsys):
    """The variants step names only variants fft_variants.py has; a variant that fails on the
    device (a limit no plan foresaw) is a row of its own, the others are still measured, its
    settings are restored, and the run exits non-zero (a step of failed variants is no "ok")."""
    fv = _fft_variants()
    (step,) = [s for s in _module().STEPS if s.name == "variants"]
    named = step.argv[list(step.argv).index("--variants") + 1].split(",")
    assert named[0] == "fixed" and set(named) <= set(fv.VARIANTS), named
    assert {"cols-inplace", "cols-inplace-direct", "cols-split", "cols-split1024"} <= set(named)

    real = fv.profile_render

    def render(**kw):
        if fv.F.host_tuning.value("inplace_columns"):
            raise RuntimeError("no such work-group on this device")
        return real(**kw)

    monkeypatch.setattr(fv, "profile_render", render)
    with pytest.raises(SystemExit) as stop:
        fv.main(["--variants", "fixed,cols-inplace,unfused", "--shape", "16x24", "--layers",
                 "2", "--frames", "1", "--repeats", "1", "--sizes", "16x20", "--rounds", "1"])
    assert stop.value.code not in (0, None)
    assert "1 of 3 variants failed (cols-inplace)" in str(stop.value.code)
    out = capsys.readouterr().out
    assert "| error | cols-inplace | nan |  | RuntimeError: no such work-group" in out, out
    for name in ("fixed", "unfused"):
        assert f"| render: kernels per render | {name} |" in out
        (row,) = [line for line in out.splitlines() if line.startswith(f"| FFT 16x20 | {name} |")]
        assert float(re.search(r"error (\S+) \|$", row).group(1)) < 1e-6, row
    assert fv.F.host_tuning.value("inplace_columns") is False


def test_fft_variants_checks_its_sizes_before_measuring(monkeypatch, capsys):
    """A size the FFT does not take is refused before any variant is measured (it used to
    fail only after every render profile had run)."""
    fv = _fft_variants()
    measured = []
    monkeypatch.setattr(fv, "measure_variant", lambda *a, **k: measured.append(a))
    monkeypatch.setattr(fv.runtime, "get_queue", lambda: measured.append("queue"))
    with pytest.raises(SystemExit) as stop:
        fv.main(["--variants", "fixed", "--sizes", "1125x1944,30x41"])
    assert stop.value.code == 2 and measured == []
    assert "41 is not a size clholo.fft takes" in capsys.readouterr().err


def test_the_plan_in_the_docs_is_the_plan_tested():
    """docs/benchmarks.md's plan for the next GPU run is PLAN (what the quick test runs), and
    its two budgets leave room in a session's 900 s for two machine starts and set-ups."""
    mod = _module()
    text = (ROOT / "docs" / "benchmarks.md").read_text()
    flat = " ".join(text[text.index("## Issue 23, eighteenth session"):].split())
    for only, budget in mod.PLAN:
        assert re.search(rf"gpu_checks\.py --out \$OUT --budget {budget} (--tuning \S+ )?"
                         rf"--only {re.escape(only)}`", flat), (only, budget)
    assert sum(b for _, b in mod.PLAN) + 2 * 90 <= 900
    assert mod.PLAN[0][0].split(",")[0] == mod.PLAN[1][0].split(",")[0] == "info"
