"""Nothing a user owns is destroyed (issue 8, item 1): output folders are refused when they
exist and clholo did not write them, checked before the work starts, and Ctrl-C leaves nothing."""

import json
import os
import signal
import subprocess
import sys
import time

import pytest

import clholo
from clholo import cli
from clholo.io.output import MANIFEST_NAME, check_output_folder, is_clholo_output

DEMO = ["demo", "--scale", "0.1", "--frames", "1", "--layers", "2"]


def _demo(out, *extra):
    return cli.main(DEMO + ["--out", str(out), *extra])


def test_existing_folder_with_unrelated_files_is_refused(tmp_path, capsys):
    out = tmp_path / "thesis"
    out.mkdir()
    (out / "chapter1.tex").write_text("years of work")
    for flags in ([], ["--overwrite"]):
        assert _demo(out, *flags) == 2
        err = capsys.readouterr().err
        assert str(out) in err and "not a folder clholo wrote" in err
        assert (out / "chapter1.tex").read_text() == "years of work"
        assert sorted(p.name for p in out.iterdir()) == ["chapter1.tex"]


def test_existing_regular_file_is_refused(tmp_path, capsys):
    out = tmp_path / "notes.txt"
    out.write_text("keep me")
    for flags in ([], ["--overwrite"]):
        assert _demo(out, *flags) == 2
        assert "exists and is not a folder" in capsys.readouterr().err
        assert out.read_text() == "keep me"


def test_symlink_is_refused(tmp_path, capsys):
    target = tmp_path / "data"
    target.mkdir()
    (target / "x.npy").write_text("data")
    link = tmp_path / "link"
    link.symlink_to(target)
    assert _demo(link, "--overwrite") == 2
    assert "not a folder" in capsys.readouterr().err
    assert (target / "x.npy").read_text() == "data" and link.is_symlink()


def test_overwrite_replaces_only_an_earlier_clholo_output(tmp_path, capsys):
    out = tmp_path / "run"
    assert _demo(out, "--seed", "1") == 0
    assert is_clholo_output(out)
    manifest = json.loads((out / MANIFEST_NAME).read_text())
    assert manifest["written_by"].startswith("clholo") and manifest["command"] == "demo"
    assert "summary.json" in manifest["files"]
    capsys.readouterr()
    assert _demo(out, "--seed", "2") == 2  # exists: refused without --overwrite
    assert "--overwrite" in capsys.readouterr().err
    assert json.loads((out / "summary.json").read_text())["seed"] == 1
    assert _demo(out, "--seed", "2", "--overwrite") == 0
    assert json.loads((out / "summary.json").read_text())["seed"] == 2
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run"]  # nothing temporary left


@pytest.mark.parametrize("where,message", [
    ("current", "current folder"),
    ("parent-of-current", "current folder"),
    ("missing-parent", "does not exist"),
    ("proc", "not writable"),
    ("long-name", "its name is 250 bytes, and the temporary name clholo writes first beside it "
                  "would be longer than the file system's 255; give a name of at most 239"),
])
def test_unusable_destinations_fail_before_any_work(tmp_path, monkeypatch, capsys, where,
                                                    message):
    work = tmp_path / "work"
    work.mkdir()
    monkeypatch.chdir(work)
    out = {"current": ".", "parent-of-current": "..",
           "missing-parent": str(tmp_path / "no" / "such" / "out"),
           "proc": "/proc/clholo-test-out", "long-name": "z" * 250}[where]
    rendered = []
    monkeypatch.setattr(clholo.hologram.HologramRenderer, "__init__",
                        lambda *a, **k: rendered.append(1) or (_ for _ in ()).throw(
                            AssertionError("rendering started")))
    t = time.perf_counter()
    assert _demo(out) == 2
    captured = capsys.readouterr()
    assert message in captured.err and len(captured.err.strip().splitlines()) == 1
    assert not rendered and "scene:" not in captured.out  # refused before loading anything
    assert time.perf_counter() - t < 5
    assert sorted(p.name for p in work.iterdir()) == []


def test_check_output_folder_python_api(tmp_path):
    (tmp_path / "x").mkdir()
    (tmp_path / "x" / "mine.txt").write_text("mine")
    with pytest.raises(FileExistsError, match="out_dir"):
        check_output_folder(tmp_path / "x", option="out_dir")
    assert check_output_folder(tmp_path / "new") == tmp_path / "new"
    assert not (tmp_path / "new").exists()


def test_interrupt_leaves_nothing_and_says_one_line(tmp_path, monkeypatch, capsys):
    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(clholo.hologram, "focal_stack", interrupted)
    out = tmp_path / "out"
    assert _demo(out) == 130
    err = capsys.readouterr().err
    assert err.strip() == "clholo demo: interrupted; nothing written"
    assert sorted(p.name for p in tmp_path.iterdir()) == []


# Runs `clholo ARGS` exactly as `python -m clholo.cli` does, with one hook: the render's first
# progress report (a batch of frames done, the command in the middle of its work) says so on
# stdout and then waits until a signal ends it. No timing assumption: the render may take
# 5 ms on a GPU or seconds on a CPU, the signal always lands in running work (issue 22).
_PAUSED = "test hook: paused mid-render"
_PAUSING_CLI = f"""
import runpy, sys, threading
import clholo.progress as progress
real = progress.StepLog.tracker
def tracker(self, label, total=None):
    update = real(self, label, total)
    def paused(done, total_now=None):
        update(done, total_now)
        print({_PAUSED!r}, flush=True)
        threading.Event().wait()  # until a signal ends the process
    return paused
progress.StepLog.tracker = tracker
sys.argv = ["clholo"] + sys.argv[1:]
runpy.run_module("clholo.cli", run_name="__main__", alter_sys=True)
"""


def test_sigint_to_a_running_render(tmp_path):
    # the real thing: SIGINT to a process in the middle of its work
    out = tmp_path / "out"
    proc = subprocess.Popen(
        [sys.executable, "-c", _PAUSING_CLI, "demo", "--scale", "0.1", "--frames", "4",
         "--layers", "2", "--out", str(out)],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=tmp_path,
        env={**os.environ, "PYTHONUNBUFFERED": "1"})
    lines = []
    for line in proc.stdout:  # wait until the render is under way (and held there)
        lines.append(line)
        if _PAUSED in line:
            break
    assert lines and _PAUSED in lines[-1], (lines, proc.communicate(timeout=120))
    assert any("rendering" in line for line in lines), lines
    proc.send_signal(signal.SIGINT)
    rest, err = proc.communicate(timeout=120)
    assert proc.returncode == 130, (lines, rest, err)
    assert "Traceback" not in err
    assert err.strip().splitlines()[-1] == "clholo demo: interrupted; nothing written"
    assert sorted(p.name for p in tmp_path.iterdir()) == []


def test_an_empty_folder_is_a_new_destination(tmp_path, capsys):
    """``mkdir out && clholo demo --out out`` was refused as "not a folder clholo wrote": an
    empty folder holds nothing to destroy. One that is not empty stays refused."""
    out = tmp_path / "out"
    out.mkdir()
    assert _demo(out) == 0
    assert is_clholo_output(out) and (out / "summary.json").is_file()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]  # nothing temporary left
    capsys.readouterr()
    hidden = tmp_path / "hidden"
    hidden.mkdir()
    (hidden / ".keep").write_text("")
    assert _demo(hidden) == 2
    assert "not a folder clholo wrote" in capsys.readouterr().err


def test_an_empty_mount_point_is_refused_by_name(tmp_path, monkeypatch):
    out = tmp_path / "usb"
    out.mkdir()
    monkeypatch.setattr(os.path, "ismount", lambda p: os.fspath(p) == os.fspath(out))
    with pytest.raises(FileExistsError, match=r"is a mount point: .* give a folder inside it"):
        check_output_folder(out, option="--out")


@pytest.mark.parametrize("code, kind, message", [
    ("ENAMETOOLONG", ValueError, "give a name of at most"),
    ("ENOSPC", clholo.errors.EnvironmentProblem, "no space left on the device"),
    ("EROFS", PermissionError, "is on a read-only file system"),
    ("EACCES", None, None),
])
def test_creation_failures_say_their_cause(tmp_path, code, kind, message):
    import errno

    from clholo.io.images import creation_failure

    exc = OSError(getattr(errno, code), os.strerror(getattr(errno, code)))
    failure = creation_failure(tmp_path / "out", tmp_path, exc, "cannot create --out")
    if kind is None:  # a permission: each caller's own "not writable"
        assert failure is None
    else:
        assert isinstance(failure, kind) and message in str(failure)
        assert str(failure).startswith(f"cannot create --out {tmp_path / 'out'}")


# --- temporary folders of runs that died ---------------------------------------------------


def _temporary(parent, name, middle="abcd1234", age_s=3600.0):
    tmp = parent / f".{name}.{middle}.tmp"
    tmp.mkdir()
    (tmp / "hologram.npz").write_bytes(b"x" * 1000)
    old = time.time() - age_s
    os.utime(tmp, (old, old))
    return tmp


def test_a_killed_runs_temporary_folder_is_removed_by_the_next_write(tmp_path):
    """A run killed outright (SIGKILL, out of memory) left ``.out.XXXXXXXX.tmp`` beside its
    destination for good (gigabytes for a large render); the next write of it removes it."""
    from clholo.io.images import atomic_directory

    dead = _temporary(tmp_path, "out")
    with atomic_directory(tmp_path / "out") as tmp:
        (tmp / "a.txt").write_text("new")
    assert not dead.exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]


def test_a_live_runs_temporary_folder_is_kept(tmp_path):
    """Its writer holds a lock on it: however old, it is not abandoned."""
    from clholo.io.images import atomic_directory, remove_abandoned_temporaries

    with atomic_directory(tmp_path / "out") as live:
        (live / "part.npz").write_text("being written")
        old = time.time() - 3600
        os.utime(live, (old, old))
        assert remove_abandoned_temporaries(tmp_path / "out") == []
        assert (live / "part.npz").read_text() == "being written"
    assert (tmp_path / "out" / "part.npz").is_file()


def test_what_is_not_an_abandoned_temporary_is_left_alone(tmp_path):
    from clholo.io.images import remove_abandoned_temporaries

    recent = _temporary(tmp_path, "out", "recent12", age_s=5.0)
    other = _temporary(tmp_path, "outer", "abcd1234")          # another destination's
    odd = _temporary(tmp_path, "out", "abc")                    # not tempfile's name
    mine = _temporary(tmp_path, "out", "MY-COPY!")              # nor this (8 characters)
    aside = tmp_path / ".out.abcd1234.old"                      # may be an earlier output
    aside.mkdir()
    os.utime(aside, (time.time() - 3600,) * 2)
    a_file = tmp_path / ".out.abcd5678.tmp"
    a_file.write_text("a file")
    os.utime(a_file, (time.time() - 3600,) * 2)
    dead = _temporary(tmp_path, "out", "dead5678")
    assert remove_abandoned_temporaries(tmp_path / "out") == [dead]
    for kept in (recent, other, odd, mine, aside, a_file):
        assert kept.exists(), kept


# --- temporary files of runs that died (atomic_path's .STEM.XXXXXXXX.tmp.EXT) ----------------


def _temporary_file(parent, stem, suffix, middle="abcd1234", age_s=3600.0):
    tmp = parent / f".{stem}.{middle}.tmp{suffix}"
    tmp.write_bytes(b"x" * 1000)
    old = time.time() - age_s
    os.utime(tmp, (old, old))
    return tmp


def test_a_killed_runs_temporary_file_is_removed_by_the_next_write(tmp_path):
    """A writer killed with SIGKILL inside atomic_path left its hidden temporary file for good
    (a hologram file is gigabytes); the next write of the same file removes it."""
    code = (
        "import sys, time; from pathlib import Path\n"
        "from clholo.io.images import atomic_path\n"
        "with atomic_path(Path(sys.argv[1])) as p:\n"
        "    p.write_bytes(b'y' * 1000); print('writing', flush=True); time.sleep(60)\n")
    proc = subprocess.Popen([sys.executable, "-c", code, str(tmp_path / "holo.npz")],
                            stdout=subprocess.PIPE, text=True)
    try:
        assert proc.stdout.readline().strip() == "writing"
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=30)
        proc.stdout.close()
    (left,) = tmp_path.iterdir()
    assert left.name.startswith(".holo.") and left.name.endswith(".tmp.npz")
    os.utime(left, (time.time() - 3600,) * 2)
    from clholo.io.images import atomic_path

    with atomic_path(tmp_path / "holo.npz") as tmp:
        tmp.write_bytes(b"new")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["holo.npz"]
    assert (tmp_path / "holo.npz").read_bytes() == b"new"


def test_a_live_writers_temporary_file_is_kept(tmp_path):
    from clholo.io.images import atomic_path, remove_abandoned_temporaries

    with atomic_path(tmp_path / "holo.npz") as live:
        live.write_bytes(b"being written")
        os.utime(live, (time.time() - 3600,) * 2)
        assert remove_abandoned_temporaries(tmp_path / "holo.npz", kind="file") == []
        assert live.read_bytes() == b"being written"
    assert (tmp_path / "holo.npz").read_bytes() == b"being written"


def test_what_is_not_an_abandoned_temporary_file_is_left_alone(tmp_path):
    from clholo.io.images import remove_abandoned_temporaries

    recent = _temporary_file(tmp_path, "holo", ".npz", "recent12", age_s=5.0)
    other = _temporary_file(tmp_path, "hologram", ".npz")       # another destination's
    other_ext = _temporary_file(tmp_path, "holo", ".exr")       # holo.exr's, not holo.npz's
    odd = _temporary_file(tmp_path, "holo", ".npz", "abc")      # not tempfile's name
    a_folder = tmp_path / ".holo.abcd5678.tmp.npz"              # a folder is not the file's
    a_folder.mkdir()
    os.utime(a_folder, (time.time() - 3600,) * 2)
    folders = _temporary(tmp_path, "holo.npz")                  # atomic_directory's, kept
    dead = _temporary_file(tmp_path, "holo", ".npz", "dead5678")
    assert remove_abandoned_temporaries(tmp_path / "holo.npz", kind="file") == [dead]
    for kept in (recent, other, other_ext, odd, a_folder, folders):
        assert kept.exists(), kept
    # and a folder destination's cleaning leaves files of its pattern alone
    assert remove_abandoned_temporaries(tmp_path / "holo.npz") == [folders]
    assert other.exists() and other_ext.exists()
    with pytest.raises(ValueError, match=r"^kind must be 'folder' or 'file'"):
        remove_abandoned_temporaries(tmp_path / "holo.npz", kind="files")
