"""MPI folders, Stereo Magnification folders, sRGB decoding, MPI.placed, and the twain MPI."""

import json
import os

import numpy as np
import pytest

from clholo import MPI
from clholo.io import (linear_to_srgb, read_mpi, read_stereo_mag, srgb_to_linear, write_image,
                       write_mpi)
from clholo.io.stereo_mag import stereo_mag_depths


def random_mpi(rng, L=3, H=9, W=7, C=3):
    color = rng.uniform(0.01, 1.0, (L, H, W, C)).astype(np.float32)
    alpha = rng.uniform(0.01, 1.0, (L, H, W)).astype(np.float32)
    depths = np.sort(rng.uniform(0.01, 0.2, L))
    return MPI(color, alpha, depths)


def leftovers(parent, keep):
    return sorted(p for p in os.listdir(parent) if p not in keep)


# --- sRGB --------------------------------------------------------------------------------------

def test_srgb_eotf_is_the_exact_piecewise_curve():
    # Known values of the IEC 61966-2-1 curve; a 2.2 gamma misses 0.5 -> 0.2140 by 0.004.
    v = np.array([0.0, 0.04045, 0.5, 1.0])
    want = np.array([0.0, 0.04045 / 12.92, 0.21404114048223255, 1.0])
    np.testing.assert_allclose(srgb_to_linear(v), want, rtol=1e-12, atol=1e-15)
    x = np.linspace(0, 1, 1001)
    np.testing.assert_allclose(linear_to_srgb(srgb_to_linear(x)), x, atol=1e-12)


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("shape", [(5,), (7, 9, 3), (40, 33, 3)])
def test_linear_to_srgb8_are_the_codes_write_image_stores(tmp_path, rng, monkeypatch, dtype,
                                                          shape):
    import clholo.io.images as images
    from clholo.io import linear_to_srgb8, read_image

    # bands far smaller than the image, and one that does not divide it
    monkeypatch.setattr(images, "_BAND_ELEMENTS", 37)
    v = rng.uniform(-0.2, 1.2, shape).astype(dtype)
    # values at the codes' rounding edges, and on either side of them
    edges = srgb_to_linear((np.arange(255) + 0.5) / 255).astype(dtype)
    n = 3 * min(v.size // 6, 255)  # half the values, the others uniform
    v.reshape(-1)[:n] = np.concatenate([np.nextafter(edges, -np.inf, dtype=dtype), edges,
                                        np.nextafter(edges, np.inf, dtype=dtype)])[:n]
    codes = linear_to_srgb8(v)
    assert codes.dtype == np.uint8 and codes.shape == v.shape
    image = v.reshape(v.shape[0], -1) if v.ndim < 3 else v
    write_image(tmp_path / "a.png", linear_to_srgb(image), dtype="uint8")
    stored, _ = read_image(tmp_path / "a.png", normalise=False)
    np.testing.assert_array_equal(codes.reshape(stored.shape), stored)
    assert codes.min() == 0 and codes.max() == 255 or v.size < 10


@pytest.mark.parametrize("dtype, top", [("uint8", 255), ("uint16", 65535)])
def test_write_image_stores_codes_of_its_own_type_as_they_are(tmp_path, rng, dtype, top):
    from clholo.io import read_image

    codes = rng.integers(0, top + 1, (6, 5, 3)).astype(dtype)
    write_image(tmp_path / "c.png", codes, dtype=dtype)
    stored, info = read_image(tmp_path / "c.png", normalise=False)
    assert info["max_code"] == top
    np.testing.assert_array_equal(stored, codes)
    # values in [0, 1] of another type are still rounded to the nearest code
    write_image(tmp_path / "f.png", codes / top, dtype=dtype)
    np.testing.assert_array_equal(read_image(tmp_path / "f.png", normalise=False)[0], codes)


# --- MPI folder round trips -------------------------------------------------------------------

def test_exr_round_trip_is_exact(tmp_path, rng):
    mpi = random_mpi(rng)
    write_mpi(tmp_path / "scene", mpi, format="exr")
    back = read_mpi(tmp_path / "scene")
    np.testing.assert_array_equal(back.color, mpi.color)
    np.testing.assert_array_equal(back.alpha, mpi.alpha)
    np.testing.assert_array_equal(back.depths, mpi.depths)
    assert leftovers(tmp_path, {"scene"}) == []


@pytest.mark.parametrize("fmt, bits", [("png8", 8), ("png16", 16)])
def test_png_round_trip_within_quantisation(tmp_path, rng, fmt, bits):
    mpi = random_mpi(rng)
    write_mpi(tmp_path / "scene", mpi, format=fmt)
    back = read_mpi(tmp_path / "scene")
    step = 1.0 / (2 ** bits - 1)
    # alpha is stored linearly: half a code; colour in sRGB: half a code in the encoded values,
    # at most 2.28 x that in linear (the EOTF's steepest slope, at white)
    assert np.abs(back.alpha - mpi.alpha).max() <= 0.5 * step + 1e-7
    enc = linear_to_srgb(back.color)
    assert np.abs(enc - linear_to_srgb(mpi.color)).max() <= 0.5 * step + 1e-6
    assert np.abs(back.color - mpi.color).max() <= 1.6 * step
    np.testing.assert_array_equal(back.depths, mpi.depths)


def test_one_channel_mpi_round_trips(tmp_path, rng):
    mpi = random_mpi(rng, C=1)
    write_mpi(tmp_path / "grey", mpi, format="exr")
    back = read_mpi(tmp_path / "grey")
    assert back.channels == 1
    np.testing.assert_array_equal(back.color, mpi.color)


def test_write_refuses_to_overwrite_then_replaces(tmp_path, rng):
    a, b = random_mpi(rng), random_mpi(rng)
    write_mpi(tmp_path / "s", a)
    with pytest.raises(FileExistsError, match="overwrite=True"):
        write_mpi(tmp_path / "s", b)
    write_mpi(tmp_path / "s", b, overwrite=True)
    np.testing.assert_array_equal(read_mpi(tmp_path / "s").color, b.color)
    assert leftovers(tmp_path, {"s"}) == []


def test_failed_write_leaves_nothing(tmp_path, rng, monkeypatch):
    mpi = random_mpi(rng, C=2)  # PNG cannot hold 2 colour channels + alpha
    with pytest.raises(ValueError, match="format='exr'"):
        write_mpi(tmp_path / "s", mpi, format="png8")
    assert os.listdir(tmp_path) == []

    # a failure after the first layer file is written (a full disk, say) leaves nothing either
    import clholo.io.mpi_folder as mf

    real = mf.write_image
    calls = []

    def flaky(*args, **kw):
        calls.append(args[0])
        if len(calls) == 2:
            raise OSError("No space left on device")
        return real(*args, **kw)

    monkeypatch.setattr(mf, "write_image", flaky)
    with pytest.raises(OSError, match="No space"):
        write_mpi(tmp_path / "s", random_mpi(rng))
    assert len(calls) == 2 and os.listdir(tmp_path) == []


def write_folder(folder, layers, meta):
    folder.mkdir()
    for name, px, names in layers:
        write_image(folder / name, px, dtype="uint8", channel_names=names, atomic=False)
    (folder / "mpi.json").write_text(json.dumps(meta))


def test_premultiplied_srgb_with_separate_alpha_files(tmp_path, rng):
    H, W = 5, 6
    straight = rng.integers(1, 256, (2, H, W, 3)) / 255.0
    alpha = rng.integers(1, 256, (2, H, W)) / 255.0
    layers, entries = [], []
    for i in range(2):
        pre = straight[i] * alpha[i][..., None]
        layers.append((f"c{i}.png", pre, ("R", "G", "B")))
        layers.append((f"a{i}.png", alpha[i], ("Y",)))
        entries.append({"color": f"c{i}.png", "alpha": f"a{i}.png"})
    write_folder(tmp_path / "m", layers, {
        "format": "clholo-mpi", "layers": entries, "depths": [2.0, 1.0],
        "layer_order": "back_to_front", "color_encoding": "srgb", "alpha": "premultiplied"})
    mpi = read_mpi(tmp_path / "m")
    np.testing.assert_allclose(mpi.depths, [1.0, 2.0])
    stored = np.round(straight * alpha[..., None] * 255) / 255
    want = srgb_to_linear(np.clip(stored / alpha[..., None], 0, 1))[::-1]  # nearest first
    np.testing.assert_allclose(mpi.color, want, atol=1e-6)
    np.testing.assert_allclose(mpi.alpha, alpha[::-1], atol=1e-7)


# --- bad input --------------------------------------------------------------------------------

def _rgba(rng, H=4, W=5):
    return rng.uniform(0.1, 0.9, (H, W, 4))


def test_layers_of_different_sizes_name_the_file(tmp_path, rng):
    write_folder(tmp_path / "m", [("l0.png", _rgba(rng), None), ("l1.png", _rgba(rng, 4, 6), None)],
                 {"layers": ["l0.png", "l1.png"], "depths": [1.0, 2.0]})
    with pytest.raises(ValueError, match=r"l1\.png.*every layer must match"):
        read_mpi(tmp_path / "m")


def test_missing_alpha_channel_names_the_file(tmp_path, rng):
    write_folder(tmp_path / "m", [("l0.png", _rgba(rng), None),
                                  ("l1.png", _rgba(rng)[..., :3], None)],
                 {"layers": ["l0.png", "l1.png"], "depths": [1.0, 2.0]})
    with pytest.raises(ValueError, match=r"l1\.png has no alpha channel"):
        read_mpi(tmp_path / "m")


def test_missing_layer_file_and_missing_json(tmp_path, rng):
    write_folder(tmp_path / "m", [("l0.png", _rgba(rng), None)],
                 {"layers": ["l0.png", "l1.png"], "depths": [1.0, 2.0]})
    with pytest.raises(FileNotFoundError, match=r"l1\.png does not exist"):
        read_mpi(tmp_path / "m")
    (tmp_path / "empty").mkdir()
    with pytest.raises(FileNotFoundError, match="mpi.json"):
        read_mpi(tmp_path / "empty")


def test_depth_count_mismatch_and_non_monotonic_depths(tmp_path, rng):
    layers = [("l0.png", _rgba(rng), None), ("l1.png", _rgba(rng), None),
              ("l2.png", _rgba(rng), None)]
    write_folder(tmp_path / "a", layers, {"layers": ["l0.png", "l1.png"], "depths": [1.0]})
    with pytest.raises(ValueError, match="2 layers but 1 depths"):
        read_mpi(tmp_path / "a")
    names = ["l0.png", "l1.png", "l2.png"]
    write_folder(tmp_path / "b", layers, {"layers": names, "depths": [1.0, 3.0, 2.0]})
    with pytest.raises(ValueError, match="strictly monotonic"):
        read_mpi(tmp_path / "b")
    write_folder(tmp_path / "c", layers, {"layers": names, "depths": [1.0, 2.0, 3.0],
                                          "layer_order": "back_to_front"})
    with pytest.raises(ValueError, match=r"mpi\.json.*not strictly decreasing"):
        read_mpi(tmp_path / "c")


def test_bad_json_names_the_file(tmp_path):
    (tmp_path / "m").mkdir()
    (tmp_path / "m" / "mpi.json").write_text("{not json")
    with pytest.raises(ValueError, match=r"mpi\.json is not valid JSON"):
        read_mpi(tmp_path / "m")


# --- Stereo Magnification folders -------------------------------------------------------------

def make_stereo_mag(folder, rng, L=4, H=6, W=5):
    folder.mkdir()
    rgb = rng.integers(0, 256, (L, H, W, 3)).astype(np.float64) / 255
    alpha = rng.integers(0, 256, (L, H, W)).astype(np.float64) / 255
    for i in range(L):
        write_image(folder / f"mpi_rgb_{i:02d}.png", rgb[i], dtype="uint8", atomic=False)
        write_image(folder / f"mpi_alpha_{i:02d}.png", alpha[i], dtype="uint8", atomic=False)
    return rgb, alpha


def test_stereo_mag_folder_reads_back_to_front_with_opaque_farthest(tmp_path, rng):
    rgb, alpha = make_stereo_mag(tmp_path / "sm", rng)
    mpi = read_stereo_mag(tmp_path / "sm")
    np.testing.assert_allclose(mpi.depths, stereo_mag_depths(4)[::-1])
    np.testing.assert_allclose(mpi.depths[[0, -1]], [1.0, 100.0])
    np.testing.assert_allclose(np.diff(1 / mpi.depths), np.diff(1 / mpi.depths)[0])
    np.testing.assert_allclose(mpi.color, srgb_to_linear(rgb[::-1]), atol=1e-6)
    np.testing.assert_allclose(mpi.alpha[:-1], alpha[::-1][:-1], atol=1e-7)
    assert np.all(mpi.alpha[-1] == 1)  # mpi_alpha_00 is the farthest and taken as opaque
    placed = read_stereo_mag(tmp_path / "sm", near=0.01, far=0.02)
    np.testing.assert_allclose(placed.depths, np.linspace(0.01, 0.02, 4))


def test_stereo_mag_missing_and_extra_files(tmp_path, rng):
    make_stereo_mag(tmp_path / "a", rng)
    os.remove(tmp_path / "a" / "mpi_alpha_02.png")
    with pytest.raises(ValueError, match=r"no alpha file for mpi_rgb_02\.png"):
        read_stereo_mag(tmp_path / "a")
    make_stereo_mag(tmp_path / "b", rng)
    write_image(tmp_path / "b" / "mpi_alpha_07.png", np.zeros((6, 5)), dtype="uint8")
    with pytest.raises(ValueError, match=r"no colour file for mpi_alpha_07\.png"):
        read_stereo_mag(tmp_path / "b")
    make_stereo_mag(tmp_path / "c", rng)
    for kind in ("rgb", "alpha"):
        os.remove(tmp_path / "c" / f"mpi_{kind}_01.png")
    with pytest.raises(ValueError, match="missing 01"):
        read_stereo_mag(tmp_path / "c")


# --- MPI.placed ---------------------------------------------------------------------------------

def _placed_input():
    d = np.array([1.0, 1.5, 4.0, 10.0])
    return MPI(np.full((4, 2, 2, 1), 0.5), np.full((4, 2, 2), 0.5), d)


def test_placed_index_depth_inverse():
    mpi = _placed_input()
    np.testing.assert_allclose(mpi.placed(0.01, 0.04).depths, [0.01, 0.02, 0.03, 0.04])
    lin = mpi.placed(0.01, 0.04, spacing="depth").depths
    np.testing.assert_allclose(lin, 0.01 + (mpi.depths - 1) / 9 * 0.03)
    inv = mpi.placed(0.01, 0.04, spacing="inverse").depths
    t = (1 - 1 / mpi.depths) / (1 - 0.1)
    np.testing.assert_allclose(1 / inv, 100 + t * (25 - 100))
    for d in (lin, inv):
        assert d[0] == pytest.approx(0.01) and d[-1] == pytest.approx(0.04)
    # placing keeps the layers' content and order
    np.testing.assert_array_equal(mpi.placed(0.01, 0.04, spacing="inverse").alpha, mpi.alpha)
    with pytest.raises(ValueError, match="far"):
        mpi.placed(0.04, 0.01)
    with pytest.raises(ValueError, match="spacing"):
        mpi.placed(0.01, 0.04, spacing="log")


def test_placed_inverse_keeps_uniform_disparity_uniform():
    d = stereo_mag_depths(8)[::-1]
    mpi = MPI(np.zeros((8, 1, 1, 1)), np.zeros((8, 1, 1)), d)
    new = mpi.placed(0.02, 0.2, spacing="inverse").depths
    np.testing.assert_allclose(np.diff(1 / new), np.diff(1 / new)[0], rtol=1e-9)


# --- the real twain MPI ---------------------------------------------------------------------------

def psnr(a, b):
    return 10 * np.log10(1.0 / np.mean((np.asarray(a, np.float64) - b) ** 2))


def test_twain_reproduces_the_source_render(shared_data):
    from clholo.io.images import read_image

    folder = shared_data / "twain-mpi"
    mpi = read_mpi(folder)
    assert mpi.layers == 32 and mpi.shape == (784, 1040)
    assert mpi.depths[0] == 1.0 and mpi.depths[-1] == 100.0  # scene units as stored
    assert np.all(mpi.alpha[-1] == 1)  # farthest taken as opaque
    # The source composites its stored (sRGB-encoded) values. Our colour is linear; the exact
    # EOTF round trip brings back code/255 to ~1e-7, and we composite those values as it did.
    srgb = linear_to_srgb(mpi.color)
    out = np.zeros(srgb.shape[1:])
    for i in range(mpi.layers - 1, -1, -1):  # back to front
        a = mpi.alpha[i][..., None].astype(np.float64)
        out = out * (1 - a) + srgb[i] * a
    render, _ = read_image(folder / "render_04_0.0.png")
    score = psnr(out[8:776, 8:1032], render[..., :3])
    assert score >= 50.0, score
    # Compositing linear intensity instead (what a hologram shows) differs only where alpha is
    # fractional; it scores lower, which is why the test composites in the source's space.
    lin = mpi.over()[8:776, 8:1032]
    assert psnr(linear_to_srgb(lin), render[..., :3]) < score - 2.0
    print(f"twain PSNR {score:.2f} dB (sRGB-space over), "
          f"{psnr(linear_to_srgb(lin), render[..., :3]):.2f} dB (linear over)")
