"""Audit of clholo's file outputs (gaps the output-folder tests did not cover): every public
writer keeps clholo's promises that nothing is half-written (a temporary name, renamed when
complete; Ctrl-C leaves neither a partial file nor a stray temporary one), that a user's file
or folder is never replaced, and that a destination which cannot be written is named in a clear
error before the work, not in a traceback about a temporary name nobody asked for."""

import os
import sys
from pathlib import Path

import numpy as np
import pytest

import clholo
import clholo.io.images as images
from clholo.errors import OutputRefused
from clholo.io import read_mpi, write_hologram, write_image, write_mpi
from clholo.io.output import MANIFEST_NAME
from clholo.tools import slm


def _mpi(rng, value=None):
    color = rng.uniform(0.1, 1, (2, 4, 4, 3)) if value is None else np.full((2, 4, 4, 3), value)
    return clholo.MPI(color, rng.uniform(0.1, 1, (2, 4, 4)), [1.0, 2.0])


def _field(rng):
    return (rng.standard_normal((1, 1, 4, 4)) + 1j).astype(np.complex64)


def _records():
    return [slm.FrameRecord(0, 0, 1.0, 1.01), slm.FrameRecord(0, 1, 1.02, 1.03)]


# ---- write_mpi(overwrite=True) never replaces what clholo did not write ----------------------

def test_write_mpi_overwrite_never_replaces_a_users_folder_or_file(tmp_path, rng):
    thesis = tmp_path / "thesis"
    thesis.mkdir()
    (thesis / "chapter1.tex").write_text("years of work")
    notes = tmp_path / "notes.txt"
    notes.write_text("keep me")
    for path in (thesis, notes):
        with pytest.raises(OutputRefused, match="clholo will not replace it") as info:
            write_mpi(path, _mpi(rng), overwrite=True)
        assert str(path) in str(info.value)
    assert sorted(p.name for p in thesis.iterdir()) == ["chapter1.tex"]
    assert (thesis / "chapter1.tex").read_text() == "years of work"
    assert notes.read_text() == "keep me"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["notes.txt", "thesis"]


def test_write_mpi_overwrite_keeps_a_file_the_user_added_or_edited(tmp_path, rng):
    scene = tmp_path / "scene"
    write_mpi(scene, _mpi(rng, 0.25))
    assert (scene / MANIFEST_NAME).is_file()  # recognised as clholo's on a later overwrite
    write_mpi(scene, _mpi(rng, 0.5), overwrite=True)  # clholo's own, unchanged: replaced
    np.testing.assert_allclose(read_mpi(scene).color, 0.5)

    (scene / "my_notes.txt").write_text("mine")
    with pytest.raises(OutputRefused, match="my_notes.txt"):
        write_mpi(scene, _mpi(rng, 0.75), overwrite=True)
    (scene / "my_notes.txt").unlink()

    layer = sorted(scene.glob("layer_*.exr"))[0]
    write_image(layer, np.ones((4, 4, 4)))  # the user retouched a layer
    edited = layer.read_bytes()
    with pytest.raises(OutputRefused, match=layer.name):
        write_mpi(scene, _mpi(rng, 0.75), overwrite=True)
    assert layer.read_bytes() == edited


def test_write_mpi_names_an_unusable_path(tmp_path, rng, monkeypatch):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(OutputRefused, match="path is empty"):
        write_mpi("", _mpi(rng))
    with pytest.raises(FileNotFoundError, match="parent folder .* does not exist"):
        write_mpi(tmp_path / "no" / "scene", _mpi(rng))
    assert os.listdir(tmp_path) == []


# ---- single files: a folder or an unwritable place is named, before the work -----------------

@pytest.mark.parametrize("write", ["npz", "exr", "png"])
def test_a_folder_given_as_a_file_is_named_before_the_write(tmp_path, rng, write):
    target = tmp_path / f"out.{write}"
    target.mkdir()
    (target / "mine.txt").write_text("mine")
    with pytest.raises(IsADirectoryError, match="it is a folder; give a file name") as info:
        if write == "png":
            write_image(target, np.zeros((4, 4, 3)), dtype="uint8")
        else:
            write_hologram(target, _field(rng), pitch=8e-6, wavelengths=[520e-9])
    assert str(target) in str(info.value) and ".tmp" not in str(info.value)
    assert sorted(os.listdir(tmp_path)) == [target.name]
    assert os.listdir(target) == ["mine.txt"]


@pytest.mark.skipif(not os.path.isdir("/proc/self"), reason="needs Linux's /proc")
def test_an_unwritable_folder_names_the_destination_not_a_temporary_name(rng):
    with pytest.raises(PermissionError, match=r"cannot write /proc/h\.npz: nothing can be "
                                              r"created in /proc") as info:
        write_hologram("/proc/h.npz", _field(rng), pitch=8e-6, wavelengths=[520e-9])
    assert ".tmp" not in str(info.value)
    with pytest.raises(PermissionError, match=r"cannot write /proc/x\.png"):
        write_image("/proc/x.png", np.zeros((2, 2)))


# ---- Ctrl-C at any point leaves the old file and no temporary one ----------------------------

def test_interrupt_right_after_the_temporary_file_is_made_leaves_nothing(tmp_path, rng,
                                                                         monkeypatch):
    # the window between mkstemp/mkdtemp and the block: the permission fix-up
    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(images.os, "chmod", interrupted)
    (tmp_path / "h.npz").write_bytes(b"old")
    with pytest.raises(KeyboardInterrupt):
        write_hologram(tmp_path / "h.npz", _field(rng), pitch=8e-6, wavelengths=[520e-9])
    with pytest.raises(KeyboardInterrupt):
        write_mpi(tmp_path / "scene", _mpi(rng))
    assert os.listdir(tmp_path) == ["h.npz"]
    assert (tmp_path / "h.npz").read_bytes() == b"old"


@pytest.mark.parametrize("writer", ["hologram-npz", "hologram-exr", "image", "mpi", "patterns",
                                    "frame-log"])
def test_interrupt_halfway_keeps_the_earlier_output_whole(tmp_path, rng, monkeypatch, writer):
    """Ctrl-C in the middle of the bytes (after part of the data went to disk): the earlier
    output is untouched and nothing else is left beside it."""
    from clholo.encode import quantize

    def write():
        if writer.startswith("hologram"):
            return write_hologram(tmp_path / f"h.{writer[-3:]}", _field(rng), pitch=8e-6,
                                  wavelengths=[520e-9])
        if writer == "image":
            return write_image(tmp_path / "x.png", rng.random((4, 4, 3)), dtype="uint8")
        if writer == "mpi":
            return write_mpi(tmp_path / "scene", _mpi(rng), overwrite=True)
        if writer == "patterns":
            return quantize.write_pattern_pngs(
                rng.integers(0, 256, (1, 3, 4, 4), dtype=np.uint8), tmp_path / "pat",
                overwrite=True)
        return slm.write_frame_log(_records(), tmp_path / "frames.csv", overwrite=True)

    write()
    before = {p.relative_to(tmp_path): p.read_bytes() for p in tmp_path.rglob("*")
              if p.is_file()}

    def halfway(target, *args, **kwargs):
        if hasattr(target, "write"):  # np.savez gets an open file
            target.write(b"PK\x03\x04 half")
        else:  # the temporary file (or a file in the temporary folder) beside the destination
            assert tmp_path in Path(target).parents, target
            Path(target).write_bytes(b"half")
        raise KeyboardInterrupt

    if writer == "hologram-npz":
        monkeypatch.setattr(np, "savez", halfway)
    elif writer == "frame-log":
        monkeypatch.setattr(slm, "_write_frame_rows", lambda records, path: halfway(path))
    else:  # every image file goes through OpenImageIO: its Nth file is cut short
        import OpenImageIO as oiio

        real, calls = oiio.ImageOutput.create, []
        nth = 2 if writer in ("mpi", "patterns") else 1  # the second layer or pattern

        def create(path, *args):
            calls.append(path)
            return halfway(path) if len(calls) == nth else real(path, *args)

        monkeypatch.setattr(oiio.ImageOutput, "create", create)
    with pytest.raises(KeyboardInterrupt):
        write()
    after = {p.relative_to(tmp_path): p.read_bytes() for p in tmp_path.rglob("*")
             if p.is_file()}
    assert after == before
    assert sorted(p.name for p in tmp_path.iterdir()
                  if p.name.startswith(".") and "clholo-output" not in p.name) == []


# ---- tools.slm.write_frame_log: the output-file rule of Display.write_log --------------------

def test_write_frame_log_never_replaces_a_users_file(tmp_path):
    mine = tmp_path / "mine.csv"
    mine.write_text("my measurements")
    for overwrite in (False, True):
        with pytest.raises(OutputRefused, match="clholo did not write"):
            slm.write_frame_log(_records(), mine, overwrite=overwrite)
    assert mine.read_text() == "my measurements"

    with pytest.raises(OutputRefused, match=r"is a folder: give a file name, e\.g\. .*frames"
                                            r"\.csv"):
        slm.write_frame_log(_records(), tmp_path)
    with pytest.raises(FileNotFoundError, match="parent folder"):
        slm.write_frame_log(_records(), tmp_path / "no" / "frames.csv")

    log = tmp_path / "frames.csv"
    slm.write_frame_log(_records(), log)
    assert log.read_text().splitlines()[0] == "t,channel,shown_s,settled_s,interval_s"
    with pytest.raises(OutputRefused, match="overwrite"):
        slm.write_frame_log(_records()[:1], log)  # an earlier log: only with overwrite
    slm.write_frame_log(_records()[:1], log, overwrite=True)
    assert len(log.read_text().splitlines()) == 2
    with pytest.raises(TypeError, match="overwrite"):
        slm.write_frame_log(_records(), log, overwrite="yes")


# ---- clholo batch: an item rendered again is replaced whole or not at all ------------------

def test_batch_install_interrupted_between_its_renames_keeps_the_old_item(tmp_path, rng,
                                                                         monkeypatch):
    """``_install`` moves the old item aside, then the new one in (where the system cannot swap
    them in one step): Ctrl-C between the two renames put the old one back (the task folder
    holding it is removed after)."""
    import clholo.batch as batch

    monkeypatch.setattr(images, "exchange_paths", lambda a, b: False)

    out = tmp_path / "dataset"
    out.mkdir()
    target = out / "item"
    write_mpi(target, _mpi(rng, 0.25))  # an item folder clholo wrote (its manifest)
    task = out / "staging-task"
    task.mkdir()
    staging = task / "item"
    write_mpi(staging, _mpi(rng, 0.5))
    before = {p.name: p.read_bytes() for p in target.iterdir()}

    real, calls = os.replace, []

    def replace(src, dst):
        calls.append((src, dst))
        if len(calls) == 2:  # the new folder's rename: interrupted
            raise KeyboardInterrupt
        return real(src, dst)

    monkeypatch.setattr(batch.os, "replace", replace)
    with pytest.raises(KeyboardInterrupt):
        batch._install(staging, target)
    monkeypatch.setattr(batch.os, "replace", real)
    assert {p.name: p.read_bytes() for p in target.iterdir()} == before
    np.testing.assert_allclose(read_mpi(target).color, 0.25)


@pytest.mark.skipif(not sys.platform.startswith("linux"),
                    reason="renameat2(RENAME_EXCHANGE) is Linux's; elsewhere two renames")
@pytest.mark.parametrize("writer", ["write_mpi", "batch"])
def test_overwrite_swaps_old_and_new_in_one_step_where_linux_can(tmp_path, rng, monkeypatch,
                                                                  writer):
    """On Linux the finished folder and the old one swap names in one step: the destination
    never stops existing for a reader (two renames left a moment without it)."""
    import clholo.batch as batch

    target = tmp_path / "item"
    write_mpi(target, _mpi(rng, 0.25))
    moved_away = []
    real = os.replace

    def replace(src, dst, **kwargs):
        if Path(src) == target:  # the destination moved aside: a moment without it
            moved_away.append((src, dst))
        return real(src, dst, **kwargs)

    monkeypatch.setattr(os, "replace", replace)
    if writer == "write_mpi":
        write_mpi(target, _mpi(rng, 0.5), overwrite=True)
    else:
        (tmp_path / "task").mkdir()
        write_mpi(tmp_path / "task" / "item", _mpi(rng, 0.5))
        batch._install(tmp_path / "task" / "item", target)
        assert list((tmp_path / "task").iterdir()) == []  # the old one removed
    assert moved_away == []
    np.testing.assert_allclose(read_mpi(target).color, 0.5)
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(
        ["item"] + (["task"] if writer == "batch" else []))


def test_exchange_paths_swaps_or_says_it_cannot(tmp_path, monkeypatch):
    a, b = tmp_path / "a", tmp_path / "b"
    a.mkdir()
    (a / "x").write_text("from a")
    b.write_text("a file")
    if images._renameat2() is not None:  # Linux with glibc >= 2.28 (CI's)
        assert images.exchange_paths(a, b)
        assert (b / "x").read_text() == "from a" and a.read_text() == "a file"
        with pytest.raises(FileNotFoundError, match="missing"):  # not "cannot": an error
            images.exchange_paths(a, tmp_path / "missing")
    else:
        assert not sys.platform.startswith("linux")
    # where it cannot, nothing changed and replace_path renames twice
    monkeypatch.setattr(images, "_renameat2", lambda: None)
    before = sorted(p.name for p in tmp_path.iterdir())
    assert not images.exchange_paths(a, b)
    assert sorted(p.name for p in tmp_path.iterdir()) == before
    new = tmp_path / "new"
    new.mkdir()
    (new / "y").write_text("new")
    images.replace_path(new, b)
    assert (b / "y").read_text() == "new" and sorted(p.name for p in tmp_path.iterdir()) == [
        "a", "b"]
