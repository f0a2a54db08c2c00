"""The command layer's seams (issue 17): one output policy, one error boundary, one progress
policy, one scene layer and one method registry for every command. Each case here failed on the
code before the restructure (f474cde)."""

from __future__ import annotations

import io
import json
import sys

import numpy as np
import pytest

from clholo import cli
from clholo.errors import ExitCode
from clholo.io import output

DEMO = ["demo", "--scale", "0.08", "--layers", "3", "--frames", "1", "--progress", "off"]


# ---- outputs -----------------------------------------------------------------------------------

def test_overwrite_never_deletes_a_file_the_user_added_inside(tmp_path, capsys):
    out = tmp_path / "demo"
    assert cli.main([*DEMO, "--out", str(out)]) == 0
    (out / "my-notes.txt").write_text("mine")
    rc = cli.main([*DEMO, "--out", str(out), "--overwrite"])
    err = capsys.readouterr().err
    assert rc == ExitCode.USAGE and "my-notes.txt" in err and "did not write" in err
    assert (out / "my-notes.txt").read_text() == "mine"
    (out / "my-notes.txt").unlink()
    assert cli.main([*DEMO, "--out", str(out), "--overwrite"]) == 0


def test_single_files_clholo_wrote_are_replaced_and_nothing_else(tmp_path):
    mine = tmp_path / "notes.html"
    mine.write_text("the user's notes")
    with pytest.raises(output.OutputRefused, match="did not write"):
        output.check_output_file(mine, overwrite=True)
    ours = tmp_path / "report.html"
    with output.output_file(ours, command="test") as tmp:
        tmp.write_text("first")
    assert ours.read_text() == "first" and output.is_clholo_file(ours)
    with pytest.raises(output.OutputRefused, match="--overwrite"):
        output.check_output_file(ours)
    with output.output_file(ours, overwrite=True, command="test") as tmp:
        tmp.write_text("second")
    assert ours.read_text() == "second"
    ours.write_text("edited by hand")           # changed since clholo wrote it: now the user's
    assert not output.is_clholo_file(ours)
    with pytest.raises(output.OutputRefused):
        output.check_output_file(ours, overwrite=True)
    with pytest.raises(FileNotFoundError, match="does not exist"):
        output.check_output_file(tmp_path / "missing" / "x.html")
    with pytest.raises(output.OutputRefused, match="is a folder"):
        output.check_output_file(tmp_path)


def test_a_failed_write_leaves_the_old_file(tmp_path):
    ours = tmp_path / "log.csv"
    with output.output_file(ours) as tmp:
        tmp.write_text("old")
    with pytest.raises(RuntimeError):
        with output.output_file(ours, overwrite=True) as tmp:
            tmp.write_text("half")
            raise RuntimeError("interrupted")
    assert ours.read_text() == "old"
    assert sorted(p.name for p in tmp_path.iterdir()) == [".log.csv.clholo-output.json",
                                                          "log.csv"]


# ---- the error boundary --------------------------------------------------------------------

def _run_with(monkeypatch, exc, argv=("info",)):
    from clholo.commands import info

    def boom(args):
        raise exc
    monkeypatch.setattr(info, "cmd_info", boom)
    return cli.main(list(argv))


@pytest.mark.parametrize("exc, code, words", [
    (ValueError("--thing must be positive"), ExitCode.USAGE, "error: --thing must be positive"),
    (FileExistsError("out exists"), ExitCode.USAGE, "error: out exists"),
    (MemoryError(), ExitCode.ENVIRONMENT, "out of memory"),
    (OSError(28, "No space left on device"), ExitCode.ENVIRONMENT, "No space left"),
    (KeyboardInterrupt(), ExitCode.INTERRUPTED, "interrupted; nothing written"),
], ids=["value", "exists", "memory", "disk-full", "ctrl-c"])
def test_foreseeable_conditions_are_one_line_and_a_documented_code(monkeypatch, capsys, exc,
                                                                    code, words):
    assert _run_with(monkeypatch, exc) == code
    err = capsys.readouterr().err
    assert words in err and "Traceback" not in err and len(err.strip().splitlines()) == 1


def test_no_device_is_an_environment_error(monkeypatch, capsys):
    from clholo.host.runtime import NoDeviceError

    assert _run_with(monkeypatch, NoDeviceError("no OpenCL device")) == ExitCode.ENVIRONMENT


def test_a_bug_is_reported_as_an_internal_error_not_a_usage_error(monkeypatch, capsys):
    rc = _run_with(monkeypatch, TypeError("unsupported operand type(s)"))
    err = capsys.readouterr().err
    assert rc == ExitCode.INTERNAL
    assert "Traceback" in err and "internal error: TypeError" in err and "bug" in err


@pytest.mark.parametrize("exc, code", [
    (ValueError("--thing must be positive"), ExitCode.USAGE),
    (MemoryError("needs 2 GiB"), ExitCode.ENVIRONMENT),
    (TypeError("unsupported operand"), ExitCode.INTERNAL),
    (KeyboardInterrupt(), ExitCode.INTERRUPTED),
], ids=["user", "environment", "bug", "ctrl-c"])
def test_debug_shows_the_traceback_and_keeps_the_exit_code(monkeypatch, capsys, exc, code):
    """``--debug`` (before or after the command) adds the full traceback; the exit code stays
    the documented one (issue 26: it was Python's 1 for every error)."""
    for argv in (("info", "--debug"), ("--debug", "info")):
        assert _run_with(monkeypatch, exc, argv=argv) == code
        err = capsys.readouterr().err
        assert "Traceback (most recent call last)" in err and type(exc).__name__ in err
        assert err.strip().splitlines()[-1 if code != ExitCode.INTERNAL else -2].startswith(
            "clholo info: ")


def test_an_error_never_lands_on_a_half_drawn_bar(monkeypatch, capsys):
    from clholo.commands import info
    from clholo.progress import StepLog

    class Tty(io.StringIO):
        def isatty(self):
            return True

    def half_done(args):
        log = StepLog(sys.stderr, mode="bar")
        log.progress("items", 3, 7, 0.0)
        raise ValueError("item 4 failed")
    monkeypatch.setattr(info, "cmd_info", half_done)
    assert cli.main(["info"]) == ExitCode.USAGE
    err = capsys.readouterr().err
    assert "\nclholo info: error: item 4 failed" in err


def test_a_mistyped_command_gets_a_suggestion(capsys):
    with pytest.raises(SystemExit):
        cli.main(["rendr", "x"])
    assert "maybe you meant 'render'" in capsys.readouterr().err


def test_progress_lines_off_a_terminal_and_off_means_off():
    from clholo.progress import StepLog

    lines = io.StringIO()
    log = StepLog(lines, interval=0.0)            # auto: not a terminal -> plain lines
    track = log.tracker("frames", 4)
    for k in range(1, 5):
        track(k)
    assert lines.getvalue().count("frames: ") == 4 and "\r" not in lines.getvalue()
    quiet = io.StringIO()
    StepLog(quiet, mode="off").tracker("frames", 4)(4)
    assert quiet.getvalue() == ""


def test_progress_off_shows_step_lines_only(tmp_path, capsys):
    """``--progress off`` is step lines only: no ``scene: loading ...`` line (it printed in every
    mode before), no ``rendering ...`` line, no counts; the step lines stay. ``lines`` still
    announces the steps."""
    from clholo.progress import StepLog

    lines = {}
    for mode in ("off", "lines"):
        assert cli.main([*DEMO[:-1], mode, "--out", str(tmp_path / mode)]) == 0
        lines[mode] = capsys.readouterr().out.splitlines()
    off = lines["off"]
    assert not [line for line in off if line.endswith(" ...")], off
    assert any(line.startswith("[") and "scene: skimage.data.stereo_motorcycle -> 3-plane MPI"
               in line for line in off), off                      # the step line
    assert any("rendered 1 hologram frame(s)" in line for line in off), off
    assert any(line.endswith("scene: loading skimage.data.stereo_motorcycle ...")
               for line in lines["lines"]), lines["lines"]
    text = io.StringIO()
    log = StepLog(text, mode="off")
    log.start("a long step")
    log.step("a long step", 1.0)
    assert text.getvalue().splitlines() == ["[   1.00 s] a long step"]


# ---- options act or are refused; one scene layer ---------------------------------------------

@pytest.mark.parametrize("argv, words", [
    (["bench", "--slm", "--size", "512"], "--size do(es) not apply to bench --slm"),
    (["bench", "--slm", "--no-numpy"], "--no-numpy do(es) not apply to bench --slm"),
    (["bench", "--profile", "--no-scaling"], "--no-scaling do(es) not apply to bench --profile"),
    (["bench", "--profile", "--slm", "--pad", "2"],
     "--pad do(es) not apply to bench --profile --slm"),
    (["render", "DEMO.ply", "--method", "rpws", "--layers", "8", "--near", "0.002",
      "--far", "0.006"], "--layers does not apply to --method rpws"),
    (["render", "SCENE", "--mode", "soft"], "--mode does not apply to an MPI folder"),
    (["render", "SCENE", "--near", "0.002"], "give both --near and --far"),
    (["render", "SCENE", "--method", "rpws", "--near", "0.002", "--far", "0.006"],
     "give one .ply input"),
], ids=["bench-slm-size", "bench-slm-numpy", "bench-profile-scaling", "bench-profile-slm-pad", "rpws-layers", "mpi-mode", "near-alone", "rpws-mpi"])
def test_options_that_would_not_act_are_refused(tmp_path, monkeypatch, capsys, argv, words,
                                                rng):
    import clholo

    scene = tmp_path / "scene"
    clholo.io.write_mpi(scene, clholo.MPI(rng.random((2, 8, 8, 3)), rng.random((2, 8, 8)),
                                          [2e-3, 3e-3]))
    ply = tmp_path / "scene.ply"
    ply.write_bytes(b"ply\n")
    argv = [str(scene) if a == "SCENE" else str(ply) if a == "DEMO.ply" else a for a in argv]
    monkeypatch.chdir(tmp_path)
    rc = cli.main([*argv, "--out", str(tmp_path / "o")] if argv[0] == "render" else argv)
    assert rc == ExitCode.USAGE
    assert words in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("method", ["mpi", "rpws"])
def test_metres_are_checked_the_same_way_for_every_method(capsys, method):
    with pytest.raises(SystemExit):
        cli.main(["render", "x.ply", "--method", method, "--near", "2", "--far", "6"])
    assert "argument --near: 2 m is more than a metre" in capsys.readouterr().err


def test_render_method_rgbd_is_the_baseline(tmp_path):
    from clholo.baselines.rgbd import render_rgbd_hologram
    from clholo.demo import motorcycle_mpi
    from clholo.io import read_hologram
    from clholo.scene import Optics

    out = tmp_path / "rgbd"
    assert cli.main([*DEMO, "--method", "rgbd", "--seed", "4", "--out", str(out)]) == 0
    holo, meta = read_hologram(out / "hologram.npz")
    mpi = motorcycle_mpi(layers=3, scale=0.08)
    expected = render_rgbd_hologram(mpi, Optics(), frames=1, seed=4)
    np.testing.assert_array_equal(holo, expected)
    summary = json.loads((out / "summary.json").read_text())
    assert summary["method"] == "rgbd"


def _tiny_scene(method, rng, shape, *, channels):
    """A small random scene of what ``method`` renders from: five splats, or a 3-layer MPI."""
    import clholo
    from clholo.baselines.rpws import Primitives
    from clholo.scenes import Scene, SceneSpec

    H, W = shape
    if method.needs == "primitives":
        K = 5
        prims = Primitives(xy=rng.uniform(4, 20, (K, 2)).astype(np.float32),
                           conic=np.tile(np.float32([0.25, 0.05, 0.5]), (K, 1)),
                           opacity=rng.uniform(0.3, 0.9, K).astype(np.float32),
                           color=rng.uniform(0.2, 1, (K, channels)).astype(np.float32),
                           depths=np.linspace(2e-3, 3e-3, K), radius=np.full(K, 6.0),
                           shape=(H, W))
        return Scene(SceneSpec(inputs=("memory",)), "ply", primitives=prims)
    mpi = clholo.MPI(rng.random((3, H, W, channels)), rng.random((3, H, W)),
                     [2e-3, 2.5e-3, 3e-3])
    return Scene(SceneSpec(inputs=("memory",)), "mpi_folder", mpi=mpi)


@pytest.mark.parametrize("name", ["mpi", "rgbd", "rpws"])
def test_every_method_streams_the_same_frames_whatever_the_start(name, queue, rng):
    """Frame t does not depend on batching or on where a range starts (batch parts rely on
    it), for every method in the registry."""
    import clholo
    from clholo.methods import METHODS

    method = METHODS[name]
    optics = clholo.Optics(wavelengths=(520e-9,))
    scene = _tiny_scene(method, rng, (24, 24), channels=1)
    whole = method.render(scene, optics, frames=4, seed=7, queue=queue)
    tail = method.render(scene, optics, frames=2, seed=7, start=2, queue=queue)
    assert whole.shape == (4, 1, 24, 24) and np.abs(whole).max() > 0
    np.testing.assert_array_equal(whole[2:], tail)
    assert not np.array_equal(whole[0], whole[1])  # fresh phases per frame


@pytest.mark.parametrize("name", ["mpi", "rgbd", "rpws"])
def test_every_method_writes_the_same_frames_on_the_device(name, queue, rng):
    """The device-side entry of every renderer (enqueue_frames, what the display loop uses)
    gives iter_frames' frames bit for bit: from any start, in one launch or in several
    (frames_per_batch 2 for 5 frames), into a buffer or a view of one."""
    import pyopencl.array as cla

    import clholo
    from clholo.methods import METHODS

    method = METHODS[name]
    optics = clholo.Optics(wavelengths=(638e-9, 450e-9))
    scene = _tiny_scene(method, rng, (24, 20), channels=2)
    renderer = method.renderer(scene, optics, seed=11, queue=queue)
    host = np.concatenate([b for _, b in renderer.iter_frames(5, start=3)])
    out = cla.empty(renderer.queue, (5, 2, 24, 20), np.complex64)
    out.fill(np.complex64(np.nan))
    assert renderer.enqueue_frames(3, 5, out) is out
    np.testing.assert_array_equal(out.get(), host)
    assert np.abs(host).max() > 0 and not np.array_equal(host[0], host[1])
    # several launches (frames_per_batch 2) into a view with an offset
    inner = renderer._r if hasattr(renderer, "_r") else renderer
    inner.frames_per_batch = 2
    big = cla.empty(queue, (7, 2, 24, 20), np.complex64)
    big.fill(np.complex64(np.nan))
    inner.enqueue_frames(3, 5, big[1:6])
    got = big.get()
    want = np.concatenate([b for _, b in renderer.iter_frames(5, start=3)])
    np.testing.assert_array_equal(got[1:6], want)
    assert np.isnan(got[0]).all() and np.isnan(got[6]).all()
    with pytest.raises(ValueError, match="complex64"):
        renderer.enqueue_frames(3, 5, cla.empty(queue, (4, 2, 24, 20), np.complex64))


def test_holograms_larger_than_the_machine_are_refused_before_rendering(tmp_path, capsys):
    rc = cli.main([*DEMO, "--frames", "100000000", "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err
    assert rc == ExitCode.ENVIRONMENT and "use fewer --frames" in err and "GiB" in err
    assert not (tmp_path / "o").exists()


def test_demo_scale_is_a_downsampling_factor_like_every_other_scale(capsys):
    with pytest.raises(SystemExit):   # 50x the scene once took minutes, then all memory
        cli.main(["demo", "--scale", "50"])
    assert "argument --scale: must be in (0, 1]" in capsys.readouterr().err
