"""The command line as a user runs it: demo, render, and the errors they see."""

import json

import numpy as np
import pytest

import clholo
from clholo import cli


def test_demo_writes_complete_outputs(tmp_path, capsys):
    out = tmp_path / "demo"
    rc = cli.main(["demo", "--scale", "0.25", "--frames", "2", "--layers", "4",
                   "--out", str(out)])
    assert rc == 0
    log = capsys.readouterr().out
    assert "motorcycle" in log and "rendered 2 hologram frame(s)" in log and str(out) in log
    for name in ("focal_stack.png", "focal_stack.npz", "hologram.npz", "summary.json"):
        assert (out / name).is_file()
    holo, meta = clholo.io.read_hologram(out / "hologram.npz")
    summary = json.loads((out / "summary.json").read_text())
    assert holo.shape == (2, 3, summary["height"], summary["width"])
    assert np.all(np.isfinite(holo)) and np.abs(holo).max() > 0
    stack = np.load(out / "focal_stack.npz")["intensity"]
    assert stack.shape == (3, 3, summary["height"], summary["width"])
    # nothing temporary left beside the output
    assert sorted(p.name for p in tmp_path.iterdir()) == ["demo"]


def test_render_an_mpi_folder(tmp_path, capsys, rng):
    mpi = clholo.MPI(rng.random((3, 40, 56, 3)), rng.random((3, 40, 56)), [1.0, 2.0, 4.0])
    clholo.io.write_mpi(tmp_path / "scene", mpi)
    out = tmp_path / "render"
    # depths in scene units: metres must be given
    assert cli.main(["render", str(tmp_path / "scene"), "--out", str(out)]) == 2
    assert "--near" in capsys.readouterr().err
    assert not out.exists()
    rc = cli.main(["render", str(tmp_path / "scene"), "--near", "0.002", "--far", "0.004",
                   "--frames", "1", "--out", str(out)])
    assert rc == 0
    holo, meta = clholo.io.read_hologram(out / "hologram.npz")
    assert holo.shape == (1, 3, 40, 56)


def test_render_missing_input(tmp_path, capsys):
    rc = cli.main(["render", str(tmp_path / "nothing-here"), "--near", "0.002", "--far",
                   "0.004", "--out", str(tmp_path / "o")])
    assert rc == 2
    assert "nothing-here" in capsys.readouterr().err


def test_bad_pad_argument(capsys):
    with pytest.raises(SystemExit):
        cli.main(["demo", "--pad", "lots"])
    assert "argument --pad: must be 'auto' or a factor" in capsys.readouterr().err


@pytest.mark.parametrize("depth_name, extra, line", [
    ("depth.png", [], "depth map: depth.png taken as depth (by default): larger values farther; "
                      "if larger values are nearer (inverse depth, as MiDaS and Depth Anything "
                      "write), give --depth-kind disparity"),
    ("disp.png", [], "depth map: disp.png taken as disparity (its name says disp): larger values "
                     "nearer; if larger values are farther, give --depth-kind depth"),
    ("depth.png", ["--depth-kind", "disparity"],
     "depth map: depth.png taken as disparity (as given): larger values nearer"),
])
def test_render_says_which_way_round_it_took_the_depth_map(tmp_path, capsys, rng, depth_name,
                                                           extra, line):
    # a map taken the wrong way round renders a plausible scene inside out without a word:
    # monocular depth networks write inverse depth in files that say "depth"
    from clholo.io import write_image

    write_image(tmp_path / "photo.png", rng.random((12, 16, 3)), dtype="uint8")
    write_image(tmp_path / depth_name, rng.uniform(0.1, 1.0, (12, 16)), dtype="uint16")
    rc = cli.main(["render", str(tmp_path / "photo.png"), str(tmp_path / depth_name),
                   "--near", "0.002", "--far", "0.004", "--layers", "3", "--frames", "1",
                   "--out", str(tmp_path / "out")] + extra)
    assert rc == 0
    assert line in capsys.readouterr().out
