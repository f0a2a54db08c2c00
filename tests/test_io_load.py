"""load_scene: one entry point that recognises every input kind."""

import numpy as np
import pytest

from clholo import MPI
from clholo.io import Camera, detect_kind, load_scene, write_image, write_mpi


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


# --- issue 8 item 6: inputs that did not load, or loaded wrong ----------------------------------

def _stereo_mag(folder, rng, L=4, H=6, W=8):
    folder.mkdir()
    for i in range(L):
        write_image(folder / f"mpi_rgb_{i:02d}.png", rng.uniform(size=(H, W, 3)), dtype="uint8")
        write_image(folder / f"mpi_alpha_{i:02d}.png", rng.uniform(size=(H, W)), dtype="uint8")


def test_stereo_mag_min_max_depth(tmp_path, rng):
    _stereo_mag(tmp_path / "sm", rng, L=5)
    mpi = load_scene(tmp_path / "sm", min_depth=2.0, max_depth=50.0)
    # nearest first, uniform in inverse depth from 1/2 to 1/50
    np.testing.assert_allclose(1.0 / mpi.depths, np.linspace(0.5, 0.02, 5), rtol=1e-12)
    default = load_scene(tmp_path / "sm")
    np.testing.assert_allclose(default.depths[[0, -1]], [1.0, 100.0])
    placed = load_scene(tmp_path / "sm", min_depth=2.0, max_depth=50.0, near=0.002, far=0.004,
                        spacing="depth")
    want = 0.002 + (mpi.depths - 2.0) / 48.0 * 0.002
    np.testing.assert_allclose(placed.depths, want, rtol=1e-12)
    with pytest.raises(ValueError, match="min_depth"):
        load_scene(tmp_path / "sm", min_depth=50.0, max_depth=2.0)
    write_mpi(tmp_path / "m", MPI(rng.uniform(0.1, 1, (2, 3, 3, 3)),
                                  rng.uniform(0.1, 1, (2, 3, 3)), [1.0, 2.0]))
    with pytest.raises(ValueError, match="min_depth/max_depth describe Stereo Magnification"):
        load_scene(tmp_path / "m", min_depth=2.0)


def test_scene_depth_units(tmp_path, rng):
    from clholo.io.load import scene_depth_units

    _stereo_mag(tmp_path / "sm", rng)
    write_mpi(tmp_path / "m", MPI(rng.uniform(0.1, 1, (2, 3, 3, 3)),
                                  rng.uniform(0.1, 1, (2, 3, 3)), [0.002, 0.003]))
    assert scene_depth_units(tmp_path / "sm") == "scene units"
    assert scene_depth_units(tmp_path / "m") == "metres"
    (tmp_path / "m" / "mpi.json").write_text(
        (tmp_path / "m" / "mpi.json").read_text().replace('"metres"', '"units"'))
    assert scene_depth_units(tmp_path / "m") == "scene units"


def _levels_uniform_in_disparity(L, z_near=1.0, z_far=10.0):
    return 1.0 / np.linspace(1.0 / z_near, 1.0 / z_far, L)


@pytest.mark.parametrize("L", [4, 9])
def test_depth_map_planes_uniform_in_disparity(tmp_path, rng, L):
    H, W = 5, 7
    plane = rng.integers(0, L, (H, W))
    plane.flat[:L] = np.arange(L)  # every plane used, so the range is [z_near, z_far]
    depth = _levels_uniform_in_disparity(L)[plane]
    write_image(tmp_path / "im.exr", rng.uniform(0.1, 0.9, (H, W, 3)), dtype="float")
    np.save(tmp_path / "z.npy", depth)
    pair = [tmp_path / "im.exr", tmp_path / "z.npy"]
    mpi = load_scene(pair, layers=L, near=0.01, far=0.02, depth_spacing="disparity")
    np.testing.assert_array_equal(np.argmax(mpi.alpha, axis=0), plane)
    np.testing.assert_allclose(mpi.depths, np.linspace(0.01, 0.02, L))
    linear = load_scene(pair, layers=L, near=0.01, far=0.02, depth_spacing="linear")
    # uniform in depth crowds these surfaces into the first planes
    assert (np.argmax(linear.alpha, axis=0) < plane).any()
    # a disparity map is already uniform in disparity: both spacings agree
    np.save(tmp_path / "disp.npy", 1.0 / depth)
    a = load_scene([tmp_path / "im.exr", tmp_path / "disp.npy"], layers=L, near=0.01, far=0.02,
                   depth_spacing="disparity")
    np.testing.assert_array_equal(np.argmax(a.alpha, axis=0), plane)
    with pytest.raises(ValueError, match="depth_spacing"):
        load_scene(pair, layers=L, near=0.01, far=0.02, depth_spacing="log")


def test_scale_downsamples_rgbd_nearest_depth_antialiased_colour(tmp_path):
    H, W = 32, 40
    checker = ((np.indices((H, W)).sum(0) % 2) * 1.0)[..., None].repeat(3, 2)
    depth = np.where(np.arange(W)[None, :] < 20, 1.0, 5.0) * np.ones((H, 1))
    depth[6:14, 8:16] = np.nan  # a hole: filled from its neighbours, never mixed in
    write_image(tmp_path / "im.exr", checker, dtype="float")
    np.save(tmp_path / "z.npy", depth)
    pair = [tmp_path / "im.exr", tmp_path / "z.npy"]
    mpi = load_scene(pair, layers=8, near=0.01, far=0.02, scale=0.5)
    assert mpi.shape == (16, 20)
    used = np.argmax(mpi.alpha, axis=0)
    assert set(np.unique(used)) == {0, 7}  # only the two true depths: nothing interpolated
    np.testing.assert_array_equal(used[:, :10], 0)
    np.testing.assert_array_equal(used[:, 10:], 7)
    # a one-pixel checkerboard averages to grey instead of aliasing to black or white
    np.testing.assert_allclose(mpi.over()[2:-2, 2:-2], 0.5, atol=0.05)
    with pytest.raises(ValueError, match=r"scale must be a downsampling factor"):
        load_scene(pair, layers=8, near=0.01, far=0.02, scale=0)
    with pytest.raises(ValueError, match=r"scale must be a downsampling factor"):
        load_scene(pair, layers=8, near=0.01, far=0.02, scale=2.0)


def test_scale_downsamples_mpi_premultiplied(tmp_path):
    H, W = 32, 48
    color = np.zeros((2, H, W, 3))
    alpha = np.zeros((2, H, W))
    color[0, :, W // 2:] = 1.0   # colour under zero alpha must not bleed into the edge
    color[0, :, :W // 2] = 0.25
    alpha[0, :, :W // 2] = 1.0
    color[1], alpha[1] = 0.75, 1.0
    write_mpi(tmp_path / "m", MPI(color, alpha, [1.0, 2.0]))
    mpi = load_scene(tmp_path / "m", scale=0.5)
    assert mpi.shape == (16, 24)
    front = mpi.alpha[0] > 0
    np.testing.assert_allclose(mpi.color[0][front], 0.25, atol=1e-6)
    assert 0 < mpi.alpha[0, 0, 11] < 1  # the edge is blended, not snapped
    np.testing.assert_allclose(mpi.color[1], 0.75, atol=1e-6)


def test_splat_camera_options_through_load_scene(tmp_path, shared_data, queue):
    import json

    from clholo.io import SplatCullWarning

    path = shared_data / "gaussians" / "fox-50k.ply"
    R = np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]])  # the README's side view
    t = -R @ np.array([0, 0, 1.25]) + np.array([0, 0, 4.0])
    entries = [{"id": i, "img_name": f"{i:05d}", "width": 48, "height": 64,
                "position": (-R.T @ t + [0, i, 0]).tolist(), "rotation": R.T.tolist(),
                "fx": 60.0, "fy": 60.0} for i in range(2)]
    (tmp_path / "cameras.json").write_text(json.dumps(entries))
    mpi = load_scene(path, layers=4, camera_json=tmp_path / "cameras.json", camera_index=0,
                     queue=queue)
    assert mpi.shape == (64, 48)
    over = mpi.over()
    # upright statue (the camera's y is world -z): the wide pedestal fills rows 46..52, the
    # narrow head is near rows 14..20, nothing above it
    cover = mpi.alpha.max(0)
    assert cover[46:52, 14:34].mean() > 0.9
    assert cover[14:20, 14:34].mean() < 0.8 and cover[:10].max() < 0.1
    assert np.isfinite(over).all()
    small = load_scene(path, layers=4, camera_json=tmp_path / "cameras.json", scale=0.5,
                       queue=queue)
    assert small.shape == (32, 24)
    moved = load_scene(path, layers=4, camera_json=tmp_path / "cameras.json", camera_index=1,
                       queue=queue)
    assert not np.allclose(moved.alpha, mpi.alpha)
    cam = Camera(32, 32, 40.0, 40.0, rotation=R, translation=t - [0, 0, 3.2])
    with pytest.warns(SplatCullWarning):
        load_scene(path, layers=2, camera=cam, znear=0.5, queue=queue)
    with pytest.raises(ValueError, match="camera_index picks a camera of camera_json"):
        load_scene(path, camera_index=1)
    write_mpi(tmp_path / "m", MPI(np.full((1, 2, 2, 3), 0.5), np.ones((1, 2, 2)), [1.0]))
    with pytest.raises(ValueError, match=r"znear apply to 3D Gaussian splat"):
        load_scene(tmp_path / "m", znear=0.1)
