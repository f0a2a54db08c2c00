"""Two clholo processes (or threads) at once on the same outputs: two runs into one new
``--out``, two ``--overwrite`` runs of one folder, two records added to one manifest, two
writers of one file, two batches on one folder. Neither may delete the other's complete
output unseen, leave a mix of the two, a manifest or record that describes other files than
are there, or a temporary folder behind; a clear error for the loser is fine.

The races are deterministic: one thread is stopped at a chosen point (between its last check
and its rename, between two renames, after reading a manifest) and the other's whole write
runs there, as an unlucky switch would. Where the fix makes the other wait for a lock that the
stopped one holds, the stopped one goes on as soon as the other is seen waiting for it
(``output._wait_for_lock`` is watched), so no test sleeps for a guess."""

import contextlib
import io
import json
import os
import subprocess
import sys
import threading
from pathlib import Path

import pytest

from clholo.errors import OutputRefused
from clholo.io import images, output
from clholo.io.output import (MANIFEST_NAME, foreign_entries, is_clholo_file,
                              is_clholo_output, output_file, output_folder, update_manifest)

_WAIT_S = 10.0  # only a broken test waits this long: every wait ends on an event


class _Race:
    """Events two named threads set and wait for. ``wait(name, other)`` returns when ``name``
    is set or when thread ``other`` waits for the output lock (it cannot get further while this
    thread holds the lock)."""

    def __init__(self, monkeypatch):
        self.events = {}
        self.lock = threading.Lock()
        real = getattr(output, "_wait_for_lock", None)

        def watched(fd, fcntl):
            self.event("locking-" + threading.current_thread().name).set()
            return real(fd, fcntl)

        # raising=False: without the fix there is no lock to watch, and nothing waits for it
        monkeypatch.setattr(output, "_wait_for_lock", watched, raising=False)

    def event(self, name):
        with self.lock:
            return self.events.setdefault(name, threading.Event())

    def set(self, name):
        self.event(name).set()

    def wait(self, name, other):
        done, locking = self.event(name), self.event("locking-" + other)
        for _ in range(int(_WAIT_S / 0.005)):
            if done.is_set() or locking.is_set():
                return
            done.wait(0.005)


def _run(name, fn, results):
    def target():
        try:
            results[name] = fn()
        except BaseException as exc:  # noqa: BLE001 - the test looks at it
            results[name] = exc

    t = threading.Thread(target=target, name=name, daemon=True)
    t.start()
    return t


def _write_folder(dest, text, *, overwrite=False, race=None, name=None):
    with output_folder(dest, overwrite=overwrite, command="test") as tmp:
        (tmp / "who.txt").write_text(text)
        (tmp / "data.bin").write_bytes(text.encode() * 100)
    if race is not None:
        race.set(f"{name}-done")
    return "ok"


def _leftovers(parent: Path, dest: Path):
    return sorted(p.name for p in parent.iterdir() if p.name.startswith(f".{dest.name}."))


def _assert_whole(dest: Path, winner: str):
    """``dest`` holds the winner's complete output and a manifest listing just its files."""
    assert (dest / "who.txt").read_text() == winner
    assert (dest / "data.bin").read_bytes() == winner.encode() * 100
    manifest = json.loads((dest / MANIFEST_NAME).read_text())
    assert sorted(manifest["files"]) == ["data.bin", "who.txt"]
    assert foreign_entries(dest) == [] and output.changed_entries(dest) == []


def _one_refused(results):
    refused = [n for n, r in results.items() if isinstance(r, OutputRefused)]
    won = [n for n, r in results.items() if r == "ok"]
    assert len(won) == 1 and len(refused) == 1, results
    return won[0], results[refused[0]]


def _race(first, second, race, signal, results, dest):
    """Run ``first`` (name, function), wait until it raises ``signal``, run ``second``; both
    end, one wins and the other is refused naming ``dest``: ``(winner, refusal)``."""
    t1 = _run(*first, results)
    race.wait(signal, "none")
    t2 = _run(*second, results)
    for t in (t1, t2):
        t.join(_WAIT_S)
        assert not t.is_alive()
    winner, refusal = _one_refused(results)
    assert str(dest) in str(refusal)
    return winner, refusal


# ------------------------------------------------------------------------ output folders
def test_two_runs_into_one_new_folder_one_wins_the_other_is_told(tmp_path, monkeypatch):
    """B passes its last check (nothing there yet) and is stopped before its rename; A writes
    the folder whole. B used to rename anyway, moving A's complete output aside and deleting
    it, and both said they wrote it."""
    dest, race, results = tmp_path / "run", _Race(monkeypatch), {}
    real_check, calls = output.check_output_folder, {}

    def check(*args, **kwargs):
        got = real_check(*args, **kwargs)
        me = threading.current_thread().name
        calls[me] = calls.get(me, 0) + 1
        if me == "B" and calls[me] == 2:  # B's last check, right before its rename
            race.set("B-checked")
            race.wait("A-done", "A")
        return got

    monkeypatch.setattr(output, "check_output_folder", check)
    winner, _ = _race(("B", lambda: _write_folder(dest, "B", race=race, name="B")),
                      ("A", lambda: _write_folder(dest, "A", race=race, name="A")),
                      race, "B-checked", results, dest)
    _assert_whole(dest, winner)
    assert _leftovers(tmp_path, dest) == []


def test_two_overwrites_at_once_leave_one_whole_output_and_no_temporary_folder(
        tmp_path, monkeypatch):
    """A moves the old output aside and is stopped before renaming its new one in; B, seeing no
    folder, renames its own in. A's rename then failed (a folder is there), and putting the
    old one back failed too: a raw OSError, and the old output left as a hidden ``.run.*.old``
    folder beside it."""
    # the two renames are the fallback where the system cannot swap two names in one step
    monkeypatch.setattr(images, "exchange_paths", lambda a, b: False)
    dest = tmp_path / "run"
    _write_folder(dest, "old")
    race, results = _Race(monkeypatch), {}
    real_replace = os.replace

    def replace(src, dst, **kwargs):
        got = real_replace(src, dst, **kwargs)
        if threading.current_thread().name == "A" and Path(src) == dest:  # old moved aside
            race.set("A-aside")
            race.wait("B-done", "B")
        return got

    monkeypatch.setattr(os, "replace", replace)
    winner, refusal = _race(
        ("A", lambda: _write_folder(dest, "A", overwrite=True, race=race, name="A")),
        ("B", lambda: _write_folder(dest, "B", overwrite=True, race=race, name="B")),
        race, "A-aside", results, dest)
    assert "another clholo run" in str(refusal)
    _assert_whole(dest, winner)
    assert _leftovers(tmp_path, dest) == []


def test_overwrite_never_replaces_an_output_another_run_wrote_meanwhile(tmp_path):
    """``--overwrite`` replaces the output that was there when the run began; one that another
    run wrote while this one worked is not deleted unseen (the loser is told, naming it)."""
    dest = tmp_path / "run"
    _write_folder(dest, "old")
    with pytest.raises(OutputRefused, match="another clholo run while this one worked") as exc:
        with output_folder(dest, overwrite=True, command="test") as tmp:
            (tmp / "who.txt").write_text("slow")
            _write_folder(dest, "fast", overwrite=True)  # the other run, complete meanwhile
    assert str(dest) in str(exc.value) and "run again" in str(exc.value)
    _assert_whole(dest, "fast")
    assert _leftovers(tmp_path, dest) == []


def test_the_lock_is_held_across_processes(tmp_path):
    """Another process holding the output lock of a folder makes a write there wait for it
    (``flock`` on the folder: no lock file is left)."""
    pytest.importorskip("fcntl")
    dest, release = tmp_path / "run", tmp_path / "release"
    code = ("import sys, time; from pathlib import Path; from clholo.io import output\n"
            "with output._locked(Path(sys.argv[1])):\n"
            "    print('locked', flush=True)\n"
            "    while not Path(sys.argv[2]).exists(): time.sleep(0.01)\n")
    proc = subprocess.Popen([sys.executable, "-c", code, str(tmp_path), str(release)],
                            stdout=subprocess.PIPE, text=True)
    try:
        assert proc.stdout.readline().strip() == "locked"
        results = {}
        t = _run("A", lambda: _write_folder(dest, "A"), results)
        t.join(0.3)
        assert t.is_alive() and not dest.exists()  # waiting for the other process
        release.touch()
        t.join(_WAIT_S)
        assert results == {"A": "ok"}
        assert proc.wait(timeout=20) == 0
    finally:
        with contextlib.suppress(OSError):
            proc.kill()
    _assert_whole(dest, "A")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["release", "run"]


# ------------------------------------------------------------------------ single files
def _write_file(dest, text, *, race=None, name=None):
    with output_file(dest, overwrite=True, command="test") as tmp:
        tmp.write_text(text)
    if race is not None:
        race.set(f"{name}-done")
    return "ok"


def test_two_writers_of_one_file_keep_file_and_record_matching(tmp_path, monkeypatch):
    """A passes its last check and is stopped; B passes its own, and waits while A renames its
    record in; B then renames its record and its file, A its file. The file was A's and the
    record B's: a file clholo wrote counted as edited, and no ``--overwrite`` replaced it."""
    dest = tmp_path / "report.html"
    _write_file(dest, "old")
    sidecar = tmp_path / f".report.html.{MANIFEST_NAME}"
    race, results = _Race(monkeypatch), {}
    real_check, real_replace, calls = output.check_output_file, os.replace, {}

    def check(*args, **kwargs):
        got = real_check(*args, **kwargs)
        me = threading.current_thread().name
        calls[me] = calls.get(me, 0) + 1
        if calls[me] == 2 and me == "A":
            race.set("A-checked")
            race.wait("B-checked", "B")
        elif calls[me] == 2 and me == "B":
            race.set("B-checked")
            race.wait("A-record", "A")
        return got

    def replace(src, dst, **kwargs):
        got = real_replace(src, dst, **kwargs)
        if threading.current_thread().name == "A" and Path(dst) == sidecar:
            race.set("A-record")
            race.wait("B-done", "B")
        return got

    monkeypatch.setattr(output, "check_output_file", check)
    monkeypatch.setattr(os, "replace", replace)
    winner, _ = _race(("A", lambda: _write_file(dest, "A", race=race, name="A")),
                      ("B", lambda: _write_file(dest, "B", race=race, name="B")),
                      race, "A-checked", results, dest)
    assert dest.read_text() == winner and is_clholo_file(dest)
    assert sorted(p.name for p in tmp_path.iterdir()) == [sidecar.name, "report.html"]


# ------------------------------------------------------------------------ manifests
def test_two_records_added_to_one_manifest_at_once_are_both_kept(tmp_path, monkeypatch):
    """``clholo report`` twice into one render folder: A reads the manifest and is stopped; B
    adds its report. A used to write its stale copy, losing B's entry: B's report became a file
    "clholo did not write", and every later ``--overwrite`` of the folder was refused."""
    folder = tmp_path / "run"
    _write_folder(folder, "run")
    (folder / "a.html").write_text("A")
    (folder / "b.html").write_text("B")
    race, results = _Race(monkeypatch), {}
    real_manifest = output._manifest

    def manifest(path):
        got = real_manifest(path)
        if threading.current_thread().name == "A":
            race.wait("B-done", "B")
        return got

    def add(name, entry):
        def go():
            update_manifest(folder, add=[entry])
            race.set(f"{name}-done")
            return "ok"
        return go

    monkeypatch.setattr(output, "_manifest", manifest)
    ta = _run("A", add("A", "a.html"), results)
    tb = _run("B", add("B", "b.html"), results)
    for t in (ta, tb):
        t.join(_WAIT_S)
        assert not t.is_alive()
    assert results == {"A": "ok", "B": "ok"}
    monkeypatch.undo()
    data = json.loads((folder / MANIFEST_NAME).read_text())
    assert {"a.html", "b.html"} <= set(data["files"]) and {"a.html", "b.html"} <= set(
        data["sha256"])
    assert foreign_entries(folder) == [] and is_clholo_output(folder)


def test_a_report_of_a_folder_replaced_while_it_was_read_is_not_written_into_the_new_one(
        tmp_path, monkeypatch):
    """``clholo report run`` reads the render, another run's ``--overwrite`` replaces ``run``
    meanwhile: the report (of the old render) used to land in the new folder, listed in its
    manifest as if it described it. It is refused; the new folder stays as that run wrote it."""
    from clholo.experiments import report

    def write(text):
        with output_folder(folder, overwrite=True, command="render") as tmp:
            (tmp / "summary.json").write_text(json.dumps({"who": text}))

    folder = tmp_path / "run"
    write("old")
    real = report._summary_rows

    def summary_rows(path):  # the report has read the old render: the other run finishes now
        rows = real(path)
        write("new")
        return rows

    monkeypatch.setattr(report, "_summary_rows", summary_rows)
    before = {p.name: p.read_bytes() for p in folder.iterdir()}
    with pytest.raises(OutputRefused, match=r"run was replaced by another clholo run while "
                                            r"clholo report read it.*run clholo report again"):
        report.build_report(folder)
    assert {p.name: p.read_bytes() for p in folder.iterdir()} != before   # the new run's
    assert json.loads((folder / "summary.json").read_text()) == {"who": "new"}
    assert sorted(p.name for p in folder.iterdir()) == [MANIFEST_NAME, "summary.json"]
    assert foreign_entries(folder) == [] and output.changed_entries(folder) == []
    monkeypatch.undo()
    report.build_report(folder)          # run again: the report of the folder that is there
    assert "report.html" in json.loads((folder / MANIFEST_NAME).read_text())["files"]


def test_a_manifest_never_lists_a_file_that_is_not_there(tmp_path):
    """A report whose file vanished (the folder replaced by another run meanwhile) is told so,
    instead of its name being listed in the manifest of a folder that does not hold it."""
    folder = tmp_path / "run"
    _write_folder(folder, "run")
    before = (folder / MANIFEST_NAME).read_text()
    with pytest.raises(FileNotFoundError, match="report.html") as exc:
        update_manifest(folder, add=["report.html"])
    assert str(folder) in str(exc.value) and "another clholo run" in str(exc.value)
    assert (folder / MANIFEST_NAME).read_text() == before


# ------------------------------------------------------------------------ batches
def _batch_manifest(tmp_path, item_id):
    import numpy as np

    import clholo

    rng = np.random.default_rng(0)
    mpi = tmp_path / "scene.mpi"
    clholo.io.write_mpi(mpi, clholo.MPI(rng.random((2, 8, 10, 3)), rng.random((2, 8, 10)),
                                        np.array([1.0, 2.0])))
    manifest = tmp_path / "items.csv"
    manifest.write_text(f"id,input\n{item_id},{mpi}\n")
    return manifest


def _no_cluster(*args, **kwargs):
    raise RuntimeError("the batch went on to render")


def test_a_batch_checks_the_folder_again_under_its_lock(tmp_path, monkeypatch):
    """B checks ``--out`` (empty), then, while it looks for its devices, another batch (of
    another manifest) fills the folder and ends. B used to render into it anyway, with the
    verdict of its first look: a dataset mixed from two manifests, which check_resume exists to
    refuse."""
    pytest.importorskip("distributed")
    from clholo import batch

    out = tmp_path / "dataset"
    out.mkdir()
    manifest = _batch_manifest(tmp_path, "b")

    def other_batch_ran():  # what batch A left: its item, and the record of its manifest
        (out / "a").mkdir()
        (out / "a" / batch.RECORD).write_text(json.dumps({"options_sha256": "0" * 64,
                                                          "files": {}}))
        batch._append_log(out, {"event": "dataset", "manifest": str(tmp_path / "other.csv"),
                                "items": ["a"], "time": 0.0})
        return ["0:0"]

    monkeypatch.setattr(batch, "_local_devices", other_batch_ran)
    monkeypatch.setattr(batch, "_local_cluster", _no_cluster)
    with pytest.raises(OutputRefused, match="does not list a") as exc:
        batch.render_dataset(manifest, out, progress="off", stream=io.StringIO())
    assert str(out) in str(exc.value)
    assert sorted(p.name for p in out.iterdir()) == ["a", batch.LOG]
    assert not (out / "b").exists()


def test_a_refused_batch_never_removes_the_folder_another_batch_holds(tmp_path, monkeypatch):
    """Two batches start on one new ``--out`` at once: both find no folder, A gets the lock
    first, B is refused ("another clholo batch is writing"). B then removed "the folder it had
    created and left empty": A's, with A's lock file and staging folder in it (and a third
    batch could then start beside A)."""
    pytest.importorskip("distributed")
    from clholo import batch

    out = tmp_path / "dataset"
    manifest = _batch_manifest(tmp_path, "b")
    held, real_render_all = [], batch._render_all

    def render_all(*args, **kwargs):
        lock = batch._lock(out)  # batch A, which made the folder at the same moment
        lock.__enter__()
        held.append(lock)
        (out / batch.STAGING).mkdir()
        return real_render_all(*args, **kwargs)

    monkeypatch.setattr(batch, "_local_devices", lambda: ["0:0"])
    monkeypatch.setattr(batch, "_local_cluster", _no_cluster)
    monkeypatch.setattr(batch, "_render_all", render_all)
    try:
        with pytest.raises(OutputRefused, match="another clholo batch is writing"):
            batch.render_dataset(manifest, out, progress="off", stream=io.StringIO())
        assert (out / batch.LOCK).is_file() and (out / batch.STAGING).is_dir()
    finally:
        for lock in held:
            lock.__exit__(None, None, None)
    assert not out.exists() or not any(out.iterdir())  # A, ending empty, cleans up after itself


# ------------------------------------------------------------------------ the tuning file
def test_a_reader_sees_a_tuning_file_another_process_rewrote_in_the_same_tick(tmp_path):
    """Another process stores a new entry of the same size within one tick of the file
    system's clock (the same modification time, as ext4's coarse clock gives two writes a few
    milliseconds apart): a reader that had the file cached kept reading the old settings."""
    from clholo.host import tuning as host_tuning

    path = tmp_path / "tuning.json"
    host_tuning.store_entry("dev", {"clholo": "x", "settings": {"split_columns": 1}}, path=path)
    before = path.stat()
    assert host_tuning._read_file(path)["dev"]["settings"] == {"split_columns": 1}
    code = ("import sys; from pathlib import Path; from clholo.host import tuning\n"
            "tuning.store_entry('dev', {'clholo': 'x', 'settings': {'split_columns': 2}}, "
            "path=Path(sys.argv[1]))\n")
    subprocess.run([sys.executable, "-c", code, str(path)], check=True, timeout=30)
    os.utime(path, ns=(before.st_atime_ns, before.st_mtime_ns))  # the same tick
    assert path.stat().st_size == before.st_size
    assert host_tuning._read_file(path)["dev"]["settings"] == {"split_columns": 2}
