"""RGB-D to MPI (hard and soft layering) and depth/disparity file readers."""

import struct

import numpy as np
import pytest

from clholo.io import (load_scene, read_depth, read_dpt, read_pfm, rgbd_to_mpi, srgb_to_linear,
                       write_image)
from clholo.io.rgbd import fill_invalid


@pytest.fixture(scope="module")
def motorcycle():
    from skimage.data import stereo_motorcycle

    left, _, disparity = stereo_motorcycle()
    return left, disparity


@pytest.mark.parametrize("layers", [4, 16, 64])
def test_motorcycle_hard_layering(motorcycle, layers):
    left, disp = motorcycle
    disp = disp.astype(np.float64)
    assert np.isinf(disp).any()  # the real map has unknown pixels: the fill policy is exercised
    mpi = rgbd_to_mpi(left, disp, layers=layers, near=0.01, far=0.03, mode="hard",
                      depth_kind="disparity")
    assert mpi.layers == layers and mpi.shape == left.shape[:2]
    np.testing.assert_allclose(mpi.depths, np.linspace(0.01, 0.03, layers))
    assert set(np.unique(mpi.alpha)) <= {0.0, 1.0}
    np.testing.assert_array_equal(mpi.alpha.sum(0), 1.0)  # every pixel in exactly one plane
    # the largest disparity is in the nearest plane, the smallest in the farthest
    valid = np.isfinite(disp)
    assert np.all(mpi.alpha[0][valid & (disp == disp[valid].max())] == 1)
    assert np.all(mpi.alpha[-1][valid & (disp == disp[valid].min())] == 1)
    # nearest-plane binning: the plane index is round((dmax - d) / (dmax - dmin) * (L - 1))
    t = (disp[valid].max() - disp) / (disp[valid].max() - disp[valid].min())
    idx = np.argmax(mpi.alpha, axis=0)
    np.testing.assert_array_equal(idx[valid], np.rint(t[valid] * (layers - 1)))
    # the over-composite gives back the (linear) image
    want = srgb_to_linear(left / 255.0)
    np.testing.assert_allclose(mpi.over(), want, atol=1e-6)


@pytest.mark.parametrize("layers", [4, 64])
def test_motorcycle_soft_layering(motorcycle, layers):
    left, disp = motorcycle
    disp = disp.astype(np.float64)
    mpi = rgbd_to_mpi(left, disp, layers=layers, near=0.01, far=0.03, mode="soft",
                      depth_kind="disparity")
    np.testing.assert_allclose(mpi.over(), srgb_to_linear(left / 255.0), atol=1e-6)
    valid = np.isfinite(disp)
    d = np.where(valid, disp, disp[valid].max())  # the unknown pixels are checked elsewhere
    s = (disp[valid].max() - d) / (disp[valid].max() - disp[valid].min()) * (layers - 1)
    i0 = np.minimum(np.floor(s), layers - 2).astype(int)
    w = s - i0
    yy, xx = np.nonzero(valid)
    # near plane alpha 1 - w, far plane 1 where w > 0: contributions (1 - w, w) add up to 1
    np.testing.assert_allclose(mpi.alpha[i0[valid], yy, xx], 1 - w[valid], atol=1e-6)
    far_alpha = mpi.alpha[i0[valid] + 1, yy, xx]
    np.testing.assert_array_equal(far_alpha, (w[valid] > 0).astype(np.float32))
    # at most two planes per pixel
    assert (mpi.alpha > 0).sum(0).max() <= 2
    # the soft split really is soft on this map
    assert np.any((mpi.alpha > 0.05) & (mpi.alpha < 0.95))


def test_invalid_depth_fill_and_error():
    depth = np.array([[1.0, np.nan, 3.0], [np.inf, 2.0, 0.0]])
    image = np.full((2, 3, 3), 0.5)
    with pytest.raises(ValueError, match="invalid='fill'.*") as exc:
        rgbd_to_mpi(image, depth, layers=4, near=0.1, far=0.2, invalid="error")
    assert "3 invalid pixel" in str(exc.value)
    bad = ~np.isfinite(depth) | (depth == 0)
    filled = fill_invalid(np.nan_to_num(depth, nan=0, posinf=0), bad)
    assert np.all(np.isfinite(filled)) and np.all(filled > 0)
    np.testing.assert_array_equal(filled[~bad], depth[~bad])
    assert filled[0, 1] in (1.0, 2.0, 3.0) and filled[1, 0] in (1.0, 2.0)
    assert filled[1, 2] in (2.0, 3.0)
    mpi = rgbd_to_mpi(image, depth, layers=4, near=0.1, far=0.2)
    np.testing.assert_array_equal(mpi.alpha.sum(0), 1.0)
    with pytest.raises(ValueError, match="no valid pixel"):
        rgbd_to_mpi(image, np.zeros((2, 3)), layers=4, near=0.1, far=0.2)


def test_bad_arguments_are_named():
    img, depth = np.zeros((2, 2, 3)), np.ones((2, 2))
    with pytest.raises(ValueError, match="layers"):
        rgbd_to_mpi(img, depth, layers=1, near=0.1, far=0.2)
    with pytest.raises(ValueError, match="near < far"):
        rgbd_to_mpi(img, depth, layers=4, near=0.2, far=0.1)
    with pytest.raises(ValueError, match="mode"):
        rgbd_to_mpi(img, depth, layers=4, near=0.1, far=0.2, mode="fuzzy")
    with pytest.raises(ValueError, match="depth has shape"):
        rgbd_to_mpi(img, np.ones((3, 2)), layers=4, near=0.1, far=0.2)


def test_depth_range_fixes_the_mapping():
    depth = np.array([[2.0, 3.0]])
    mpi = rgbd_to_mpi(np.ones((1, 2, 1)), depth, layers=5, near=0.1, far=0.2,
                      depth_range=(0.0, 4.0))
    assert mpi.alpha[2, 0, 0] == 1 and mpi.alpha[3, 0, 1] == 1  # 2/4*4 = 2, 3/4*4 = 3


# --- depth file readers -----------------------------------------------------------------------

def write_pfm(path, arr, little=True):
    h, w = arr.shape
    with open(path, "wb") as f:
        f.write(b"Pf\n%d %d\n%s\n" % (w, h, b"-1.0" if little else b"1.0"))
        f.write(np.ascontiguousarray(arr[::-1]).astype("<f4" if little else ">f4").tobytes())


@pytest.mark.parametrize("little", [True, False])
def test_pfm_reader_flips_rows_and_keeps_inf(tmp_path, rng, little):
    arr = rng.uniform(1, 60, (7, 5)).astype(np.float32)
    arr[2, 3] = np.inf
    write_pfm(tmp_path / "d.pfm", arr, little)
    np.testing.assert_array_equal(read_pfm(tmp_path / "d.pfm"), arr)
    np.testing.assert_array_equal(read_depth(tmp_path / "d.pfm"), arr)
    data = (tmp_path / "d.pfm").read_bytes()
    (tmp_path / "t.pfm").write_bytes(data[:-8])
    with pytest.raises(ValueError, match=r"t\.pfm is truncated"):
        read_pfm(tmp_path / "t.pfm")


def test_depth_readers_png16_png8_exr_npy(tmp_path, rng):
    codes = rng.integers(1, 65536, (6, 4))
    write_image(tmp_path / "d16.png", codes / 65535.0, dtype="uint16")
    np.testing.assert_array_equal(read_depth(tmp_path / "d16.png"), codes)  # raw codes
    np.testing.assert_allclose(read_depth(tmp_path / "d16.png", scale=1e-3), codes * 1e-3,
                               rtol=1e-6)
    c8 = rng.integers(1, 256, (6, 4))
    write_image(tmp_path / "d8.png", c8 / 255.0, dtype="uint8")
    np.testing.assert_array_equal(read_depth(tmp_path / "d8.png"), c8)
    f = rng.uniform(0.5, 20, (6, 4)).astype(np.float32)
    write_image(tmp_path / "d.exr", f, dtype="float")
    np.testing.assert_array_equal(read_depth(tmp_path / "d.exr"), f)
    np.save(tmp_path / "d.npy", f.astype(np.float64))
    np.testing.assert_array_equal(read_depth(tmp_path / "d.npy"), f)
    with pytest.raises(FileNotFoundError, match="nope.png"):
        read_depth(tmp_path / "nope.png")


def write_dpt(path, arr, tag=202021.25):
    """An MPI Sintel .dpt byte for byte, as Sintel's sintel_io.depth_write lays it out."""
    h, w = arr.shape
    with open(path, "wb") as f:
        f.write(struct.pack("<f", tag))
        f.write(struct.pack("<i", w))
        f.write(struct.pack("<i", h))
        f.write(struct.pack(f"<{w * h}f", *arr.ravel().tolist()))


@pytest.mark.parametrize("shape", [(3, 5), (7, 2), (1, 1)])
def test_sintel_dpt_reader(tmp_path, rng, shape):
    arr = rng.uniform(0.5, 80, shape).astype(np.float32)
    write_dpt(tmp_path / "frame_0001.dpt", arr)
    got = read_dpt(tmp_path / "frame_0001.dpt")
    assert got.dtype == np.float32 and got.shape == shape
    np.testing.assert_array_equal(got, arr)
    np.testing.assert_array_equal(read_depth(tmp_path / "frame_0001.dpt"), arr)


def test_sintel_dpt_through_load_scene(tmp_path, rng):
    depth = rng.uniform(1, 9, (6, 5)).astype(np.float32)
    write_dpt(tmp_path / "d.dpt", depth)
    write_image(tmp_path / "im.exr", rng.uniform(0.1, 0.9, (6, 5, 3)), dtype="float")
    mpi = load_scene([tmp_path / "im.exr", tmp_path / "d.dpt"], layers=4, near=0.01, far=0.02)
    nearest = np.unravel_index(np.argmin(depth), depth.shape)
    farthest = np.unravel_index(np.argmax(depth), depth.shape)
    assert mpi.alpha[(0,) + nearest] == 1 and mpi.alpha[(3,) + farthest] == 1


def test_bad_dpt_files_are_refused_naming_the_file(tmp_path, rng):
    arr = rng.uniform(0.5, 80, (4, 6)).astype(np.float32)
    write_dpt(tmp_path / "tag.dpt", arr, tag=202021.0)
    with pytest.raises(ValueError, match=r"tag\.dpt is not a Sintel \.dpt.*tag 202021\.0"):
        read_depth(tmp_path / "tag.dpt")
    write_dpt(tmp_path / "ok.dpt", arr)
    data = (tmp_path / "ok.dpt").read_bytes()
    (tmp_path / "cut.dpt").write_bytes(data[:-4])
    with pytest.raises(ValueError, match=r"cut\.dpt is truncated.*6x4"):
        read_depth(tmp_path / "cut.dpt")
    (tmp_path / "head.dpt").write_bytes(data[:9])
    with pytest.raises(ValueError, match=r"head\.dpt is not a Sintel"):
        read_depth(tmp_path / "head.dpt")
    (tmp_path / "long.dpt").write_bytes(data + b"\0\0\0\0")
    with pytest.raises(ValueError, match=r"long\.dpt is longer"):
        read_depth(tmp_path / "long.dpt")
    (tmp_path / "size.dpt").write_bytes(data[:4] + struct.pack("<ii", 0, 4) + data[12:])
    with pytest.raises(ValueError, match=r"size\.dpt.*0x4"):
        read_depth(tmp_path / "size.dpt")
