"""``clholo render``'s scene-input options: Stereo Magnification depth range, scene units,
--scale, --depth-spacing, and 3DGS cameras (--camera-json, --camera-index, --znear)."""

import json
import struct

import numpy as np
import pytest

import clholo
from clholo import cli
from clholo.io import write_image


def _stereo_mag(folder, rng, L=3, H=8, W=12):
    folder.mkdir()
    for i in range(L):
        write_image(folder / f"mpi_rgb_{i:02d}.png", rng.uniform(size=(H, W, 3)), dtype="uint8")
        write_image(folder / f"mpi_alpha_{i:02d}.png", rng.uniform(size=(H, W)), dtype="uint8")


def test_stereo_mag_depths_are_scene_units_and_min_max_depth(tmp_path, capsys, rng):
    _stereo_mag(tmp_path / "sm", rng)
    out = tmp_path / "o"
    # depths 0.2..0.5 scene units would pass a "> 1 m" test: they must still be placed
    rc = cli.main(["render", str(tmp_path / "sm"), "--min-depth", "0.2", "--max-depth", "0.5",
                   "--out", str(out)])
    captured = capsys.readouterr()
    assert rc == 2 and not out.exists()
    assert "0.2..0.5 scene units" in captured.out and "scene units" in captured.err
    assert "--near" in captured.err and " m " not in captured.err
    rc = cli.main(["render", str(tmp_path / "sm"), "--min-depth", "2", "--max-depth", "50",
                   "--near", "0.002", "--far", "0.004", "--spacing", "depth", "--frames", "1",
                   "--out", str(out)])
    assert rc == 0, capsys.readouterr().err
    depths = np.array(json.loads((out / "summary.json").read_text())["depths_m"])
    scene = 1.0 / np.linspace(1 / 2, 1 / 50, 3)
    np.testing.assert_allclose(depths, 0.002 + (scene - 2) / 48 * 0.002, rtol=1e-12)


def test_render_scale_and_depth_spacing_on_a_sintel_pair(tmp_path, capsys, rng):
    H, W = 32, 40
    depth = rng.uniform(1, 20, (H, W)).astype(np.float32)
    with open(tmp_path / "frame.dpt", "wb") as f:
        f.write(struct.pack("<fii", 202021.25, W, H) + depth.astype("<f4").tobytes())
    write_image(tmp_path / "frame.png", rng.uniform(size=(H, W, 3)), dtype="uint8")
    out = tmp_path / "o"
    rc = cli.main(["render", str(tmp_path / "frame.png"), str(tmp_path / "frame.dpt"),
                   "--layers", "4", "--near", "0.002", "--far", "0.004", "--scale", "0.5",
                   "--depth-spacing", "disparity", "--frames", "1", "--out", str(out)])
    assert rc == 0, capsys.readouterr().err
    holo, _ = clholo.io.read_hologram(out / "hologram.npz")
    assert holo.shape == (1, 3, H // 2, W // 2)
    with pytest.raises(SystemExit) as exc:  # argparse refuses it, naming the option
        cli.main(["render", str(tmp_path / "frame.png"), str(tmp_path / "frame.dpt"),
                  "--near", "0.002", "--far", "0.004", "--scale", "3", "--out",
                  str(tmp_path / "o2")])
    assert exc.value.code == 2 and "argument --scale: must be in (0, 1]" in capsys.readouterr().err


def test_render_splats_from_a_3dgs_training_camera(tmp_path, capsys, shared_data):
    R = np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]])
    t = -R @ np.array([0, 0, 1.25]) + np.array([0, 0, 4.0])
    entries = [{"id": i, "img_name": f"{i:05d}", "width": 24 + 8 * i, "height": 32,
                "position": (-R.T @ t).tolist(), "rotation": R.T.tolist(), "fx": 30.0,
                "fy": 30.0} for i in range(2)]
    (tmp_path / "cameras.json").write_text(json.dumps(entries))
    ply = shared_data / "gaussians" / "fox-50k.ply"
    out = tmp_path / "o"
    rc = cli.main(["render", str(ply), "--camera-json", str(tmp_path / "cameras.json"),
                   "--camera-index", "1", "--znear", "0.5", "--layers", "2", "--frames", "1",
                   "--near", "0.002", "--far", "0.003", "--out", str(out)])
    assert rc == 0, capsys.readouterr().err
    holo, _ = clholo.io.read_hologram(out / "hologram.npz")
    assert holo.shape == (1, 3, 32, 32)
    rc = cli.main(["render", str(ply), "--camera-json", str(tmp_path / "cameras.json"),
                   "--camera-index", "5", "--near", "0.002", "--far", "0.003",
                   "--out", str(tmp_path / "o2")])
    err = capsys.readouterr().err
    assert rc == 2 and "camera_index 5 is out of range" in err and "cameras.json" in err


def test_render_match_size_on_a_phone_like_pair(tmp_path, capsys, rng):
    # a depth map of the photo's shape at half its size: refused without --match-size (the
    # message names it), rendered at the photo's size with "photo", the map's with "depth"
    H, W = 24, 32
    write_image(tmp_path / "photo.png", rng.uniform(size=(H, W, 3)), dtype="uint8")
    np.save(tmp_path / "depth.npy", rng.uniform(1, 2, (H // 2, W // 2)).astype(np.float32))
    base = ["render", str(tmp_path / "photo.png"), str(tmp_path / "depth.npy"), "--layers",
            "3", "--near", "0.002", "--far", "0.004", "--frames", "1"]
    rc = cli.main(base + ["--out", str(tmp_path / "refused")])
    err = capsys.readouterr().err
    assert rc != 0 and "--match-size photo" in err and "--match-size depth" in err, err
    for match, shape in (("photo", (H, W)), ("depth", (H // 2, W // 2))):
        out = tmp_path / match
        rc = cli.main(base + ["--match-size", match, "--out", str(out)])
        assert rc == 0, capsys.readouterr().err
        holo, _ = clholo.io.read_hologram(out / "hologram.npz")
        assert holo.shape == (1, 3) + shape
    # an MPI folder has no depth map to resize: the option is refused, naming the input kind
    mpi_dir = clholo.io.write_mpi(tmp_path / "mpi", clholo.MPI(
        rng.random((2, 8, 8, 3), dtype=np.float32), rng.random((2, 8, 8), dtype=np.float32),
        np.array([2e-3, 3e-3])))
    rc = cli.main(["render", str(mpi_dir), "--match-size", "photo", "--frames", "1",
                   "--out", str(tmp_path / "m")])
    err = capsys.readouterr().err
    assert rc != 0 and "--match-size" in err and "MPI folder" in err, err
