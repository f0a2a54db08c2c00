"""Mistakes an audit found in ``clholo batch``, ``selftest``, ``tune`` and ``experiment``,
refused before any work with one line that names the option, file or device and the fix.

1. ``clholo batch`` resumed into a folder made from another manifest and mixed the two
   datasets without a word (an item replaced, another left without a row in results.csv).
2. ``clholo selftest`` on a device that cannot compile printed some 60 build logs and "send the
   --json report with a bug report" (exit 1) instead of saying so (exit 3).
3. ``clholo batch`` with ``CLHOLO_DEVICE`` naming such a device failed every item with its
   build log instead of refusing before the cluster starts (exit 3).
4. ``clholo tune --file /missing/dir/t.json`` created the whole path.
5. ``clholo experiment layers --data .../twain-mpi`` (a scene folder) said
   ``.../twain-mpi/twain-mpi/mpi.json does not exist``.
6. ``clholo experiment layers --width 100000`` did not name ``--width``.

A device that cannot compile is simulated by replacing ``runtime.device_build_problem`` (the
probe ``clholo info`` and the default device choice use); where this machine has a real one
(PyPI's PoCL on a CPU newer than its LLVM), it is used too.
"""

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import clholo
from clholo import cli
from clholo.host import runtime

ENV = dict(os.environ, PYTHONUNBUFFERED="1")
CANNOT = "error: unknown target CPU 'generic'"


def one_line_error(capsys, command: str, *, usage: bool = False) -> str:
    """The command's error, ``clholo COMMAND: error: ...``: the only line on stderr (the last,
    after argparse's usage lines, with ``usage``)."""
    err = capsys.readouterr().err.strip()
    lines = err.splitlines()
    assert lines and lines[-1].startswith(f"clholo {command}: error: "), err
    assert usage or len(lines) == 1, err
    return lines[-1]


# ------------------------------------------------------------------------------------------
# 1. clholo batch: one folder, one dataset
def _tiny_mpi(path: Path, seed: int) -> None:
    rng = np.random.default_rng(seed)
    clholo.io.write_mpi(path, clholo.MPI(rng.random((2, 8, 8, 3)), rng.random((2, 8, 8)),
                                         np.array([0.002, 0.004])))


def _manifest(path: Path, rows) -> Path:
    path.write_text("id,input,frames,seed\n" + "".join(",".join(map(str, r)) + "\n"
                                                      for r in rows))
    return path


def _batch(manifest: Path, out: Path, *extra) -> subprocess.CompletedProcess:
    """A batch that starts its local cluster: in a process of its own, with a time limit (a
    test never hangs)."""
    return subprocess.run([sys.executable, "-m", "clholo.cli", "batch", str(manifest), "--out",
                           str(out), "--workers", "1", "--progress", "off", *extra],
                          stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=ENV,
                          timeout=300)


def _results(out: Path):
    return [(r["item"], r["status"]) for r in
            map(json.loads, (out / "results.jsonl").read_text().splitlines())]


def test_batch_refuses_to_mix_another_manifest_into_its_folder(tmp_path, capsys):
    pytest.importorskip("distributed")
    from clholo import batch

    _tiny_mpi(tmp_path / "tiny", 1)
    _tiny_mpi(tmp_path / "tiny2", 2)
    out = tmp_path / "ds"
    ok = _manifest(tmp_path / "m_ok.csv", [("a", "tiny", 1, 0), ("b", "tiny2", 1, 0)])
    run = _batch(ok, out)
    assert run.returncode == 0, run.stdout
    assert batch.dataset_record(out)["manifest"] == str(ok.resolve())
    assert batch.dataset_record(out)["items"] == ["a", "b"]

    def unchanged():
        return {p.name: p.stat().st_mtime_ns for p in out.rglob("*")}

    before, log = unchanged(), (out / batch.LOG).read_text()

    # another manifest: item a with other options, b left out, c new -> refused, nothing runs
    other = _manifest(tmp_path / "m_other.csv", [("a", "tiny", 2, 0), ("c", "tiny2", 1, 0)])
    argv = ["batch", str(other), "--out", str(out), "--workers", "1", "--progress", "off"]
    assert cli.main(argv) == 2
    err = one_line_error(capsys, "batch")
    assert f"--out {out} was made from the manifest {ok.resolve()}" in err, err
    assert "m_other.csv does not list b" in err and "without a row in results.csv" in err, err
    assert "other options for a (frames 1 -> 2)" in err, err
    for fix in ("run the manifest that made it (m_ok.csv", "give a new --out",
                "pass --overwrite"):
        assert fix in err, err
    assert unchanged() == before and (out / batch.LOG).read_text() == log
    assert not (out / "c").exists()

    # growing the dataset: the same items and a new one (another manifest file) -> rendered
    grow = _manifest(tmp_path / "m_grow.csv", [("a", "tiny", 1, 0), ("b", "tiny2", 1, 0),
                                                ("c", "tiny", 1, 0)])
    run = _batch(grow, out)
    assert run.returncode == 0, run.stdout
    assert "1 rendered, 2 skipped (complete), 0 failed" in run.stdout, run.stdout
    assert _results(out) == [("a", "skipped"), ("b", "skipped"), ("c", "rendered")]

    # the first manifest again: it leaves c out -> refused, naming c
    assert cli.main(["batch", str(ok), "--out", str(out), "--workers", "1"]) == 2
    err = one_line_error(capsys, "batch")
    assert "m_ok.csv does not list c" in err and "run the manifest that made it (m_grow.csv" in err

    # the manifest that made the folder, edited in place: its changed item is rendered again,
    # and the run says so; a dropped row is refused all the same
    _manifest(grow, [("a", "tiny", 1, 0), ("b", "tiny2", 1, 5), ("c", "tiny", 1, 0)])
    run = _batch(grow, out)
    assert run.returncode == 0, run.stdout
    assert "1 item(s) to render (1 with other options than before: b)" in run.stdout, run.stdout
    assert json.loads((out / "b" / "summary.json").read_text())["seed"] == 5
    _manifest(grow, [("a", "tiny", 1, 0), ("b", "tiny2", 1, 5)])
    assert cli.main(["batch", str(grow), "--out", str(out), "--workers", "1"]) == 2
    err = one_line_error(capsys, "batch")
    assert "was made from this manifest" in err and "does not list c" in err
    assert "put the row(s) back in m_grow.csv" in err and "--overwrite" in err

    # --overwrite: never removes a file the user put in an item it would remove
    (out / "b" / "notes.txt").write_text("mine")
    assert cli.main(argv + ["--overwrite"]) == 2
    err = one_line_error(capsys, "batch")
    assert "--overwrite would remove b" in err and "notes.txt" in err
    assert (out / "b" / "notes.txt").read_text() == "mine"
    (out / "b" / "notes.txt").unlink()
    # ... and otherwise makes the folder this manifest's dataset
    run = _batch(other, out, "--overwrite")
    assert run.returncode == 0, run.stdout
    assert "--overwrite: removed b" in run.stdout, run.stdout
    assert sorted(p.name for p in out.iterdir() if p.is_dir()) == ["a", "c"]
    assert _results(out) == [("a", "rendered"), ("c", "rendered")]
    assert json.loads((out / "a" / "summary.json").read_text())["frames"] == 2
    assert batch.dataset_record(out)["manifest"] == str(other.resolve())
    # and resuming it is quiet again
    run = _batch(other, out)
    assert run.returncode == 0 and "0 rendered, 2 skipped" in run.stdout, run.stdout


# ------------------------------------------------------------------------------------------
# 2. clholo selftest on a device that cannot compile
def test_selftest_on_a_device_that_cannot_compile_says_so_in_one_line(monkeypatch, capsys,
                                                                      tmp_path):
    from clholo import selftest

    first = runtime.list_devices()[0].selector
    monkeypatch.setenv("CLHOLO_DEVICE", first)  # a selector: chosen without the rule's probe
    monkeypatch.setattr(runtime, "device_build_problem", lambda dev: CANNOT)
    report = tmp_path / "r.json"
    assert cli.main(["selftest", "--quick", "--json", str(report)]) == 3
    captured = capsys.readouterr()
    err = captured.err.strip()
    assert len(err.splitlines()) == 1, err  # no build logs, no "checking ..." lines
    assert err.startswith(f"clholo selftest: error: CLHOLO_DEVICE='{first}' picks device "
                          f"{first} ("), err
    assert f"cannot compile OpenCL kernels here ({CANNOT})" in err
    assert "choose another device with CLHOLO_DEVICE=P:D (`clholo info`" in err
    assert "bug report" not in err and captured.out == "" and not report.exists()
    # the library says the same, for a queue it is given too
    with pytest.raises(clholo.errors.EnvironmentProblem, match="the queue's device"):
        selftest.run_selftest(queue=runtime.get_queue(), families=["random"], speed=False)


def test_selftest_on_a_device_that_compiles_still_runs(queue):
    from clholo import selftest

    report = selftest.run_selftest(quick=True, queue=queue, families=["random"], speed=False)
    assert report.passed and report.checks


def _real_device_that_cannot_compile():
    for info in runtime.list_devices():
        if runtime.device_build_problem(runtime.choose_device(info.selector)) is not None:
            return info.selector
    return None


def test_selftest_and_batch_on_this_machines_device_that_cannot_compile(tmp_path):
    """Where this machine has one (PyPI's PoCL on a CPU its LLVM does not know): the real
    commands, one line each, exit 3."""
    selector = _real_device_that_cannot_compile()
    if selector is None:
        pytest.skip("every OpenCL device here compiles kernels (the tests above simulate one)")
    env = dict(ENV, CLHOLO_DEVICE=selector)
    proc = subprocess.run([sys.executable, "-m", "clholo.cli", "selftest", "--quick"],
                          capture_output=True, text=True, env=env, timeout=300)
    assert proc.returncode == 3, proc.stdout + proc.stderr
    assert proc.stderr.strip().splitlines() == [proc.stderr.strip()]
    assert "cannot compile OpenCL kernels here" in proc.stderr and proc.stdout == ""
    pytest.importorskip("distributed")
    _tiny_mpi(tmp_path / "tiny", 1)
    manifest = _manifest(tmp_path / "m.csv", [("a", "tiny", 1, 0)])
    proc = subprocess.run([sys.executable, "-m", "clholo.cli", "batch", str(manifest), "--out",
                           str(tmp_path / "ds"), "--workers", "1"],
                          capture_output=True, text=True, env=env, timeout=300)
    assert proc.returncode == 3, proc.stdout + proc.stderr
    assert proc.stderr.strip().startswith(f"clholo batch: error: CLHOLO_DEVICE='{selector}'")
    assert len(proc.stderr.strip().splitlines()) == 1, proc.stderr
    assert not (tmp_path / "ds").exists()


# ------------------------------------------------------------------------------------------
# 3. clholo batch with CLHOLO_DEVICE naming a device that cannot compile
def test_batch_refuses_a_chosen_device_that_cannot_compile(tmp_path, monkeypatch, capsys):
    pytest.importorskip("distributed")
    from clholo import batch

    _tiny_mpi(tmp_path / "tiny", 1)
    manifest = _manifest(tmp_path / "m.csv", [("a", "tiny", 1, 0)])
    first = runtime.list_devices()[0].selector
    for var in ("CLHOLO_DEVICE", "PYOPENCL_CTX"):
        monkeypatch.delenv(var, raising=False)
    monkeypatch.setenv("CLHOLO_DEVICE", first)
    # the valid case: the device compiles, the workers take it
    assert batch._local_devices() == [first]
    monkeypatch.setattr(runtime, "device_build_problem", lambda dev: CANNOT)
    assert cli.main(["batch", str(manifest), "--out", str(tmp_path / "ds"), "--workers",
                     "1"]) == 3
    err = one_line_error(capsys, "batch")
    assert err.startswith(f"clholo batch: error: CLHOLO_DEVICE='{first}' picks device {first}")
    assert f"cannot compile OpenCL kernels here ({CANNOT})" in err
    assert "choose another device with CLHOLO_DEVICE=P:D (`clholo info`" in err
    assert not (tmp_path / "ds").exists()  # before the cluster, before the folder


# ------------------------------------------------------------------------------------------
# 4. clholo tune --file in a folder that does not exist
def _fake_result(device):
    from clholo import tuning

    defaults = {n: s.default for n, s in tuning.SETTINGS.items()}
    return tuning.TuningResult(device=tuning.device_key(device), settings=dict(defaults),
                               defaults=defaults, rows=[], speedup=1.0,
                               workload={"shape": [16, 24]})


def test_tune_refuses_a_file_in_a_missing_folder_before_measuring(tmp_path, monkeypatch,
                                                                  capsys, queue):
    from clholo import tuning

    measured = []

    def fake_tune(**kw):
        measured.append(kw)
        return _fake_result(kw["queue"].device)

    monkeypatch.setattr(tuning, "tune", fake_tune)
    small = ["--variant", "gpu", "--shape", "16x24", "--layers", "2", "--frames", "1",
             "--rounds", "1", "--sgd", "0"]
    missing = tmp_path / "nonexist" / "dir" / "t.json"
    assert cli.main(["tune", *small, "--file", str(missing)]) == 2
    err = one_line_error(capsys, "tune")
    assert err == (f"clholo tune: error: cannot create --file {missing}: its parent folder "
                   f"{missing.parent} does not exist; create it first")
    assert not measured and not (tmp_path / "nonexist").exists()
    # CLHOLO_TUNING_FILE in a missing folder: the same, naming the variable
    monkeypatch.setenv(tuning.TUNING_FILE_ENV, str(missing))
    assert cli.main(["tune", *small]) == 2
    assert f"cannot create {tuning.TUNING_FILE_ENV} {missing}" in one_line_error(capsys, "tune")
    assert not measured and not (tmp_path / "nonexist").exists()
    # the library refuses it too
    with pytest.raises(FileNotFoundError, match="does not exist; create it first"):
        tuning.save_tuning(_fake_result(queue.device), path=missing)
    assert not (tmp_path / "nonexist").exists()
    # valid: a file in a folder that exists
    monkeypatch.setenv(tuning.TUNING_FILE_ENV, "off")
    assert cli.main(["tune", *small, "--file", str(tmp_path / "t.json")]) == 0
    assert f"stored for this device in {tmp_path / 't.json'}" in capsys.readouterr().out
    assert len(measured) == 1 and (tmp_path / "t.json").is_file()
    # valid: the default file, whose cache folder clholo creates
    monkeypatch.delenv(tuning.TUNING_FILE_ENV)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    assert tuning.save_tuning(_fake_result(queue.device)) == \
        tmp_path / "cache" / "clholo" / "tuning.json"
    assert (tmp_path / "cache" / "clholo" / "tuning.json").is_file()


# ------------------------------------------------------------------------------------------
# 5, 6. clholo experiment layers: --data a scene folder, --width too large
@pytest.fixture
def fake_study(monkeypatch):
    """run_study replaced: the command's checks run, no scene is rendered."""
    from clholo.experiments import layers as study

    seen = []

    def fake_run_study(out, config, **kw):
        seen.append((config, kw))
        return {"rows": [], "out_dir": out, "seconds": 0.0}

    monkeypatch.setattr(study, "run_study", fake_run_study)
    return seen


def _data_folder(root: Path) -> Path:
    """A data folder as the shared one is laid out (the files' contents are not read)."""
    (root / "twain-mpi").mkdir(parents=True)
    (root / "twain-mpi" / "mpi.json").write_text("{}")
    (root / "gaussians").mkdir()
    (root / "gaussians" / "fox-50k.ply").write_bytes(b"ply\n")
    return root


def test_experiment_data_that_is_a_scene_folder_names_its_parent(tmp_path, capsys,
                                                                 fake_study):
    data = _data_folder(tmp_path / "data")
    base = ["experiment", "layers", "--reduced", "--progress", "off", "--out",
            str(tmp_path / "x")]
    assert cli.main(base + ["--scenes", "twain", "--data", str(data / "twain-mpi")]) == 2
    err = one_line_error(capsys, "experiment layers")
    assert err == (f"clholo experiment layers: error: --data {data / 'twain-mpi'} is a scene "
                   f"folder; give the folder that holds twain-mpi/ (its parent, "
                   f"{data.resolve()})")
    assert cli.main(base + ["--scenes", "fox", "--data", str(data / "gaussians")]) == 2
    assert "is a scene folder; give the folder that holds gaussians/ (its parent" in \
        one_line_error(capsys, "experiment layers")
    # a folder without the scene's sub-folder: named before any scene is loaded
    (tmp_path / "empty").mkdir()
    assert cli.main(base + ["--scenes", "motorcycle", "fox", "--data",
                            str(tmp_path / "empty")]) == 2
    err = one_line_error(capsys, "experiment layers")
    assert f"--data {tmp_path / 'empty'} holds no gaussians/ for the fox scene" in err
    assert "give the shared data folder (it holds gaussians/ and twain-mpi/)" in err
    assert not fake_study and not (tmp_path / "x").exists()
    # valid: the folder that holds them (and the motorcycle alone needs none)
    assert cli.main(base + ["--scenes", "twain", "fox", "--data", str(data)]) == 0
    assert cli.main(base + ["--scenes", "motorcycle", "--data", str(tmp_path / "empty")]) == 0
    assert len(fake_study) == 2 and fake_study[0][1]["data"] == data


def test_experiment_width_beyond_its_limit_names_the_option(tmp_path, capsys, fake_study):
    base = ["experiment", "layers", "--scenes", "motorcycle", "--progress", "off", "--out",
            str(tmp_path / "x")]
    with pytest.raises(SystemExit) as exc:
        cli.main(base + ["--width", "100000"])
    assert exc.value.code == 2
    assert one_line_error(capsys, "experiment layers", usage=True) == (
        "clholo experiment layers: error: argument --width: must be <= 2048, got 100000")
    assert not fake_study
    assert cli.main(base + ["--width", "2048"]) == 0
    assert fake_study[0][0].width == 2048
