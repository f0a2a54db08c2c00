"""load_scene: one entry point that recognises every input kind."""

import numpy as np
import pytest

from clholo import MPI
from clholo.io import detect_kind, load_scene, write_image, write_mpi


def test_mpi_folder_and_json(tmp_path, rng):
    mpi = MPI(rng.uniform(0.1, 1, (3, 4, 5, 3)), rng.uniform(0.1, 1, (3, 4, 5)), [1.0, 2.0, 4.0])
    write_mpi(tmp_path / "m", mpi)
    assert detect_kind(tmp_path / "m") == "mpi_folder"
    assert detect_kind(tmp_path / "m" / "mpi.json") == "mpi_folder"
    got = load_scene(tmp_path / "m")
    np.testing.assert_array_equal(got.depths, mpi.depths)
    placed = load_scene(tmp_path / "m", near=0.01, far=0.03, spacing="index")
    np.testing.assert_allclose(placed.depths, [0.01, 0.02, 0.03])
    with pytest.raises(ValueError, match="has 3 layers"):
        load_scene(tmp_path / "m", layers=8)
    with pytest.raises(ValueError, match="both near and far"):
        load_scene(tmp_path / "m", near=0.01)


def test_stereo_mag_folder(tmp_path, rng):
    (tmp_path / "sm").mkdir()
    for i in range(3):
        write_image(tmp_path / "sm" / f"mpi_rgb_{i:02d}.png", rng.uniform(size=(4, 4, 3)),
                    dtype="uint8")
        write_image(tmp_path / "sm" / f"mpi_alpha_{i:02d}.png", rng.uniform(size=(4, 4)),
                    dtype="uint8")
    assert detect_kind(tmp_path / "sm") == "stereo_mag"
    mpi = load_scene(tmp_path / "sm", near=0.02, far=0.04)
    assert mpi.layers == 3
    np.testing.assert_allclose(mpi.depths, [0.02, 0.03, 0.04])


def test_rgbd_pair(tmp_path, rng):
    from skimage.data import stereo_motorcycle

    left, _, disp = stereo_motorcycle()
    left, disp = left[::4, ::4], disp[::4, ::4]
    write_image(tmp_path / "im.png", left / 255.0, dtype="uint8")
    np.save(tmp_path / "disp.npy", disp)
    assert detect_kind([tmp_path / "im.png", tmp_path / "disp.npy"]) == "rgbd"
    mpi = load_scene([tmp_path / "im.png", tmp_path / "disp.npy"], layers=8, near=0.01,
                     far=0.02, depth_kind="disparity", mode="soft")
    assert mpi.layers == 8 and mpi.shape == left.shape[:2]
    from clholo.io import srgb_to_linear
    np.testing.assert_allclose(mpi.over(), srgb_to_linear(left / 255.0), atol=1e-6)
    with pytest.raises(ValueError, match="needs near and far"):
        load_scene([tmp_path / "im.png", tmp_path / "disp.npy"])
    np.save(tmp_path / "small.npy", disp[:-1])
    with pytest.raises(ValueError, match=r"small\.npy is .* must match"):
        load_scene([tmp_path / "im.png", tmp_path / "small.npy"], near=0.01, far=0.02)


def test_ply(shared_data, queue):
    path = shared_data / "gaussians" / "train-1000.ply"
    assert detect_kind(path) == "ply"
    mpi = load_scene(path, layers=6, near=0.05, far=0.1, width=96, queue=queue)
    assert mpi.layers == 6 and mpi.shape[1] == 96
    np.testing.assert_allclose(mpi.depths, np.linspace(0.05, 0.1, 6))


def test_unknown_inputs_are_named(tmp_path):
    with pytest.raises(FileNotFoundError, match="nothing_here"):
        load_scene(tmp_path / "nothing_here")
    (tmp_path / "empty").mkdir()
    with pytest.raises(ValueError, match="without mpi.json"):
        load_scene(tmp_path / "empty")
    (tmp_path / "x.txt").write_text("hi")
    with pytest.raises(ValueError, match=r"x\.txt"):
        load_scene(tmp_path / "x.txt")
    with pytest.raises(ValueError, match="3 paths"):
        load_scene([tmp_path / "a", tmp_path / "b", tmp_path / "c"])


def test_depth_kind_auto_takes_disparity_from_the_name(tmp_path, rng):
    image = rng.uniform(0.1, 0.9, (2, 3, 3))
    write_image(tmp_path / "im.exr", image, dtype="float")
    values = np.array([[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]])
    np.save(tmp_path / "disp.npy", values)
    np.save(tmp_path / "z.npy", values)
    near_first = load_scene([tmp_path / "im.exr", tmp_path / "disp.npy"], layers=6, near=0.01,
                            far=0.02)
    assert near_first.alpha[0, 1, 2] == 1  # largest disparity is nearest
    depth = load_scene([tmp_path / "im.exr", tmp_path / "z.npy"], layers=6, near=0.01, far=0.02)
    assert depth.alpha[0, 0, 0] == 1  # smallest depth is nearest
    np.testing.assert_allclose(depth.over(), image, atol=1e-6)  # float images are linear


def test_every_input_kind_feeds_render_hologram(tmp_path, rng, shared_data, queue):
    hologram = pytest.importorskip("clholo.hologram")
    from clholo import Optics

    from clholo.io import read_hologram, write_hologram

    write_mpi(tmp_path / "m", MPI(rng.uniform(0.1, 1, (2, 16, 16, 3)),
                                  rng.uniform(0.1, 1, (2, 16, 16)), [1.0, 2.0]))
    scenes = {
        "mpi": load_scene(tmp_path / "m", near=0.002, far=0.003),
        "ply": load_scene(shared_data / "gaussians" / "train-1000.ply", layers=4, width=48,
                          near=0.002, far=0.003, queue=queue),
    }
    for name, mpi in scenes.items():
        field = hologram.render_hologram(mpi, Optics(), frames=1, seed=3, queue=queue)
        assert field.shape == (1, 3) + mpi.shape and np.all(np.isfinite(field))
        assert np.abs(field).max() > 0, name
        write_hologram(tmp_path / f"{name}.npz", field, pitch=8e-6,
                       wavelengths=Optics().wavelengths, seed=3)
        np.testing.assert_array_equal(read_hologram(tmp_path / f"{name}.npz")[0], field)
