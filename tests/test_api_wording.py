"""A refusal names what the caller typed: the command line's option on the command line, the
function's parameter (and ``overwrite=True``, not ``--overwrite``) in Python; and a camera's
capture is never half-written."""

import os
import sys
import types

import numpy as np
import pytest

from clholo import cli
from clholo.encode.quantize import write_pattern_pngs
from clholo.errors import OutputRefused
from clholo.io.output import check_output_file, check_output_folder


def _gray(rng):
    return rng.integers(1, 255, (1, 1, 4, 6), dtype=np.uint8)


def _api_words_only(message: str, parameter: str) -> None:
    assert parameter in message, message
    assert "--" not in message, f"a Python caller was told a command-line option: {message}"


def test_write_pattern_pngs_names_its_parameter(tmp_path, rng):
    folder = tmp_path / "patterns"
    write_pattern_pngs(_gray(rng), folder)
    with pytest.raises(OutputRefused) as refused:
        write_pattern_pngs(_gray(rng), folder)
    _api_words_only(str(refused.value), "folder")
    assert "overwrite=True" in str(refused.value)
    write_pattern_pngs(_gray(rng), folder, overwrite=True)  # the fix the message names works

    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "notes.txt").write_text("keep")
    with pytest.raises(OutputRefused) as refused:
        write_pattern_pngs(_gray(rng), mine)
    _api_words_only(str(refused.value), "folder")
    assert (mine / "notes.txt").read_text() == "keep"


def test_foreign_file_in_an_earlier_output_names_overwrite_true(tmp_path, rng):
    folder = tmp_path / "patterns"
    write_pattern_pngs(_gray(rng), folder)
    (folder / "notes.txt").write_text("mine")
    with pytest.raises(OutputRefused) as refused:
        write_pattern_pngs(_gray(rng), folder, overwrite=True)
    message = str(refused.value)
    _api_words_only(message, "folder")
    assert "overwrite=True would delete it" in message
    assert (folder / "notes.txt").read_text() == "mine"


@pytest.mark.parametrize("check", [check_output_folder, check_output_file])
def test_empty_destination_example_is_python_in_python(check):
    with pytest.raises(OutputRefused) as refused:
        check("", option="out_dir")
    assert "out_dir='clholo-out" in str(refused.value)
    with pytest.raises(OutputRefused) as refused:
        check("", option="--out")
    assert "e.g. --out clholo-out" in str(refused.value)


def test_render_folder_api_names_out_dir(tmp_path, rng):
    import clholo
    from clholo.render_folder import render_and_save
    from clholo.scene import Optics

    out = tmp_path / "run"
    out.mkdir()
    (out / "data.csv").write_text("the user's")
    mpi = clholo.MPI(rng.uniform(0.1, 1, (2, 8, 8, 3)), rng.uniform(0.1, 1, (2, 8, 8)),
                     [1e-3, 2e-3])
    with pytest.raises(OutputRefused) as refused:
        render_and_save(mpi, Optics(), out, frames=1, seed=1)
    _api_words_only(str(refused.value), "out_dir")
    assert (out / "data.csv").read_text() == "the user's"


def test_command_line_still_names_its_options(tmp_path, capsys, rng):
    folder = tmp_path / "patterns"
    write_pattern_pngs(_gray(rng), folder)
    holo = tmp_path / "h.npz"
    from clholo.io import write_hologram

    write_hologram(holo, (rng.standard_normal((1, 1, 8, 8))
                          + 1j * rng.standard_normal((1, 1, 8, 8))).astype(np.complex64),
                   pitch=8e-6, wavelengths=(520e-9,), seed=1)
    assert cli.main(["encode", str(holo), "--out", str(folder)]) == 2
    err = capsys.readouterr().err
    assert f"--out {folder}" in err and "--overwrite" in err


def _stereo_mag_scene(folder, rng):
    """A two-layer Stereo Magnification folder of 8x12 random PNGs."""
    from clholo.io import write_image

    folder.mkdir()
    for i in range(2):
        write_image(folder / f"mpi_rgb_{i:02d}.png", rng.uniform(size=(8, 12, 3)), dtype="uint8")
        write_image(folder / f"mpi_alpha_{i:02d}.png", rng.uniform(size=(8, 12)), dtype="uint8")
    return folder


def test_render_refused_late_names_out_on_the_command_line(tmp_path, capsys, rng, monkeypatch):
    """A refusal at the rename (another run wrote ``--out`` while this one rendered) says
    ``--out``/``--overwrite`` to a command-line user, as the refusal before the work does."""
    import clholo.hologram
    from clholo.io.output import output_folder

    scene = _stereo_mag_scene(tmp_path / "sm", rng)
    out = tmp_path / "r"
    focal_stack = clholo.hologram.focal_stack

    def other_run_writes_out_meanwhile(*args, **kwargs):
        if not out.exists():
            with output_folder(out, command="the other run") as tmp:
                (tmp / "theirs.txt").write_text("the other run's")
        return focal_stack(*args, **kwargs)

    monkeypatch.setattr(clholo.hologram, "focal_stack", other_run_writes_out_meanwhile)
    rc = cli.main(["render", str(scene), "--near", "0.002", "--far", "0.004", "--frames", "1",
                   "--out", str(out)])
    err = capsys.readouterr().err
    assert rc == 2, err
    assert f"--out {out}" in err and "--overwrite" in err and "out_dir" not in err, err
    assert (out / "theirs.txt").read_text() == "the other run's"


def test_render_overwrite_refuses_an_output_another_run_wrote_while_it_rendered(
        tmp_path, capsys, rng, monkeypatch):
    """``--overwrite`` replaces what was at ``--out`` when the command began: an output that
    another run wrote there while this one rendered (minutes, at lab sizes) is refused at the
    rename, not deleted unseen."""
    import clholo.hologram
    from clholo.io.output import output_folder

    scene = _stereo_mag_scene(tmp_path / "sm", rng)
    out = tmp_path / "r"
    with output_folder(out, command="the earlier run") as tmp:
        (tmp / "earlier.txt").write_text("the earlier run's")
    focal_stack, replaced = clholo.hologram.focal_stack, []

    def other_run_replaces_out_meanwhile(*args, **kwargs):
        if not replaced:
            with output_folder(out, overwrite=True, command="the other run") as tmp:
                (tmp / "theirs.txt").write_text("the other run's")
            replaced.append(True)
        return focal_stack(*args, **kwargs)

    monkeypatch.setattr(clholo.hologram, "focal_stack", other_run_replaces_out_meanwhile)
    rc = cli.main(["render", str(scene), "--near", "0.002", "--far", "0.004", "--frames", "1",
                   "--out", str(out), "--overwrite"])
    err = capsys.readouterr().err
    assert rc == 2, err
    assert "written by another clholo run" in err and f"--out {out}" in err, err
    assert (out / "theirs.txt").read_text() == "the other run's"
    # the same command again (nothing written meanwhile) replaces it, as the message says
    monkeypatch.setattr(clholo.hologram, "focal_stack", focal_stack)
    assert cli.main(["render", str(scene), "--near", "0.002", "--far", "0.004", "--frames",
                     "1", "--out", str(out), "--overwrite"]) == 0
    assert (out / "summary.json").exists() and not (out / "theirs.txt").exists()


def test_output_folder_expect_is_checked():
    from clholo.io.output import output_folder

    with pytest.raises(TypeError, match="expect is 'yesterday'"):
        with output_folder("never-made", expect="yesterday"):
            pass


# ---- OpenCVCamera.capture writes under a temporary name -------------------------------------

class _Capture:
    def __init__(self, device):
        pass

    def isOpened(self):
        return True

    def grab(self):
        return True

    def read(self):
        return True, np.full((4, 6), 7, np.uint8)

    def release(self):
        pass


def _fake_cv2(imwrite):
    return types.SimpleNamespace(VideoCapture=_Capture, CAP_PROP_FRAME_WIDTH=3,
                                 CAP_PROP_FRAME_HEIGHT=4, imwrite=imwrite)


def test_opencv_capture_lands_complete_under_its_name(monkeypatch, tmp_path):
    from clholo.tools.camera import OpenCVCamera

    written = []

    def imwrite(name, frame):
        assert name.endswith(".png"), "OpenCV picks the format by the extension"
        assert not os.path.exists(tmp_path / "c.png"), "the final name appeared before the end"
        with open(name, "wb") as f:
            f.write(frame.tobytes())
        written.append(name)
        return True

    monkeypatch.setitem(sys.modules, "cv2", _fake_cv2(imwrite))
    out = OpenCVCamera(0).capture(tmp_path / "c", {})
    assert out == tmp_path / "c.png" and out.read_bytes() == bytes([7] * 24)
    assert written and written[0] != str(out)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["c.png"]


@pytest.mark.parametrize("fault", ["returns False", "interrupted"])
def test_opencv_capture_failure_leaves_nothing(monkeypatch, tmp_path, fault):
    from clholo.tools.camera import OpenCVCamera

    def imwrite(name, frame):
        with open(name, "wb") as f:
            f.write(b"half a PNG")
        if fault == "interrupted":
            raise KeyboardInterrupt
        return False

    monkeypatch.setitem(sys.modules, "cv2", _fake_cv2(imwrite))
    cam = OpenCVCamera(0)
    with pytest.raises(KeyboardInterrupt if fault == "interrupted" else OSError) as raised:
        cam.capture(tmp_path / "c", {})
    if fault == "returns False":
        assert "c.png" in str(raised.value) and "imwrite" in str(raised.value)
    assert list(tmp_path.iterdir()) == []
