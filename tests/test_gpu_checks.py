"""``benchmarks/gpu_checks.py``: the prepared run of issue 23's measurements for a lent GPU.
A GPU session has minutes, so every step's command is run here at toy sizes (``--quick``), and
the budget, skip, failure and time-limit paths are checked on stand-in steps."""

import importlib.util
import os
import re
import subprocess
import sys
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "benchmarks" / "gpu_checks.py"


def _module():
    spec = importlib.util.spec_from_file_location("gpu_checks", SCRIPT)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _has_torch():
    return importlib.util.find_spec("torch") is not None


def test_every_step_names_files_that_exist_and_lists():
    mod = _module()
    names = [s.name for s in mod.STEPS]
    assert len(names) == len(set(names))
    for s in mod.STEPS:
        assert 0 < s.expect_s <= s.limit_s <= 600, s.name
        for arg in list(s.argv) + list(s.quick):
            if arg.endswith(".py"):
                assert Path(arg).is_file(), (s.name, arg)
    res = subprocess.run([sys.executable, str(SCRIPT), "--list"], capture_output=True,
                         text=True, timeout=60)
    assert res.returncode == 0, res.stderr
    assert all(name in res.stdout for name in names)


def test_quick_run_of_every_step(tmp_path):
    """Every step's command at toy sizes on this device: a GPU session must not lose its
    minutes to a wrong flag. Steps that need torch fail with its message where it is absent."""
    res = subprocess.run([sys.executable, str(SCRIPT), "--quick", "--out", str(tmp_path)],
                         capture_output=True, text=True, timeout=600)
    summary = (tmp_path / "summary.md").read_text()
    mod = _module()
    for i, s in enumerate(mod.STEPS):
        row = next(line for line in summary.splitlines() if line.startswith(f"| {s.name} |"))
        log = (tmp_path / f"{i:02d}-{s.name}.txt").read_text()
        if "| ok |" not in row:
            assert not _has_torch() and "needs torch" in log, (row, log[-2000:])
    assert res.returncode == (0 if "exit" not in summary else 1), summary
    assert not list(tmp_path.glob("*.partial"))


def test_budget_failures_and_time_limits(tmp_path, monkeypatch, capsys):
    mod = _module()
    py = sys.executable
    monkeypatch.setattr(mod, "STEPS", (
        mod.Step("fails", "a failing step", 1, 30, [py, "-c", "raise SystemExit(3)"], []),
        mod.Step("slow", "a step past its limit", 1, 1,
                 [py, "-c", "import subprocess, sys, time; "
                  f"open({str(tmp_path / 'child.pid')!r}, 'w').write(str(subprocess.Popen("
                  "[sys.executable, '-c', 'import time; time.sleep(60)']).pid)); "
                  "time.sleep(20)"], []),
        mod.Step("big", "a step longer than the budget", 10_000, 10_000, [py, "-c", "pass"], []),
        mod.Step("fine", "a step that works", 1, 30, [py, "-c", "print('hello')"], []),
    ))
    rc = mod.main(["--out", str(tmp_path), "--budget", "100"])
    assert rc == 1
    summary = (tmp_path / "summary.md").read_text()
    assert "| fails | a failing step | exit 3 |" in summary
    assert "timed out after 1 s" in summary
    # the step's own child was killed with it
    child = int((tmp_path / "child.pid").read_text())
    time.sleep(0.5)
    stat = Path(f"/proc/{child}/stat")
    if stat.exists():  # gone, or a zombie nobody has reaped yet (its parent was killed too)
        assert stat.read_text().rsplit(")", 1)[1].split()[0] == "Z"
    assert "| big | a step longer than the budget | skipped" in summary
    assert "--only big" in summary
    assert "| fine | a step that works | ok |" in summary
    assert "hello" in (tmp_path / "03-fine.txt").read_text()
    assert not (tmp_path / "02-big.txt").exists()


def test_a_tuning_file_from_an_earlier_call_reaches_every_step(tmp_path, monkeypatch):
    """--tuning: the first call's OUT/tuning.json, carried to a fresh machine, is what every
    step of the second call sees (CLHOLO_TUNING_FILE=OUT/tuning.json)."""
    mod = _module()
    py = sys.executable
    monkeypatch.setattr(mod, "STEPS", (
        mod.Step("show", "prints the tuning file it sees", 1, 30,
                 [py, "-c", "import os; print(open(os.environ['CLHOLO_TUNING_FILE']).read())"],
                 []),))
    carried = tmp_path / "carried.json"
    carried.write_text('{"format": "clholo-tuning", "from": "call 1"}')
    out = tmp_path / "out"
    assert mod.main(["--out", str(out), "--tuning", str(carried)]) == 0
    assert (out / "tuning.json").read_text() == carried.read_text()
    assert '"from": "call 1"' in (out / "00-show.txt").read_text()
    # given its own OUT/tuning.json (a warm machine's second call), it is left as it is
    assert mod.main(["--out", str(out), "--tuning", str(out / "tuning.json")]) == 0
    assert (out / "tuning.json").read_text() == carried.read_text()


@pytest.mark.parametrize("args, message", [(["--only", "nosuch"], "no step nosuch"),
                                           (["--budget", "0"], "--budget"),
                                           (["--tuning", "/no/such/tuning.json"],
                                            "--tuning /no/such/tuning.json: no such file"),
                                           ([], "--out is required")])
def test_bad_arguments_name_the_fix(tmp_path, monkeypatch, args, message):
    monkeypatch.delenv("OUT", raising=False)
    out = [] if args == [] else ["--out", str(tmp_path)]
    res = subprocess.run([sys.executable, str(SCRIPT), *out, *args], capture_output=True,
                         text=True, timeout=60, env={k: v for k, v in __import__("os").environ.items()
                                                     if k != "OUT"})
    assert res.returncode == 2 and message in res.stderr, res.stderr


def test_fft_variants_step_names_known_variants_and_survives_a_failing_one(monkeypatch, capsys):
    """The variants step names only variants fft_variants.py has; a variant that fails on the
    device (a limit no plan foresaw) is a row of its own, the others are still measured, and
    its settings are restored."""
    spec = importlib.util.spec_from_file_location("fft_variants",
                                                  ROOT / "benchmarks" / "fft_variants.py")
    fv = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(fv)
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
    monkeypatch.setattr(sys, "argv", ["fft_variants.py", "--variants",
                                      "fixed,cols-inplace,unfused",
                                      "--shape", "16x24", "--layers", "2", "--frames", "1",
                                      "--repeats", "1", "--sizes", "16x20", "--rounds", "1"])
    fv.main()
    out = capsys.readouterr().out
    assert "| error | cols-inplace | nan |  | RuntimeError: no such work-group" in out, out
    for name in ("fixed", "unfused"):
        assert f"| render: kernels per render | {name} |" in out
        (row,) = [line for line in out.splitlines() if line.startswith(f"| FFT 16x20 | {name} |")]
        assert float(re.search(r"error (\S+) \|$", row).group(1)) < 1e-6, row
    assert fv.F.host_tuning.value("inplace_columns") is False
