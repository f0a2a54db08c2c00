"""Image files a user gives clholo are read as every viewer shows them, or refused with an
error that names the file: EXIF orientation, cut-off JPEGs, empty files, PNG gamma chunks,
EXR data windows, and the PNG/JPEG/TIFF variants a holography researcher feeds it."""

import json
import re
import struct
import zlib

import numpy as np
import pytest

from clholo import MPI
from clholo.io import (load_scene, read_depth, read_image, read_mpi, srgb_to_linear, write_image,
                       write_mpi)
from clholo.io.rgbd import read_rgb

PIL = pytest.importorskip("PIL", reason="Pillow makes the PNG/JPEG variants these tests read")
from PIL import Image, ImageOps  # noqa: E402


def _with_chunks(src, dst, chunks):
    """A copy of PNG ``src`` with ``chunks`` ((type, body) pairs) inserted after IHDR."""
    data = src.read_bytes()
    at = 8 + 8 + 13 + 4  # signature, IHDR's length+type, its 13 bytes, its CRC
    extra = b"".join(struct.pack(">I", len(body)) + kind + body
                     + struct.pack(">I", zlib.crc32(kind + body) & 0xFFFFFFFF)
                     for kind, body in chunks)
    dst.write_bytes(data[:at] + extra + data[at:])
    return dst


def _exif(orientation):
    exif = Image.Exif()
    exif[0x0112] = orientation
    return exif


def _codes(rng, shape):
    return rng.integers(1, 255, shape, dtype=np.uint8)


# --- EXIF orientation -----------------------------------------------------------------------

def test_every_exif_orientation_reads_as_viewers_show_it(tmp_path, rng):
    pixels = _codes(rng, (6, 10, 3))
    for orientation in range(1, 9):
        path = tmp_path / f"o{orientation}.png"
        Image.fromarray(pixels).save(path, exif=_exif(orientation))
        px, info = read_image(path, normalise=False)
        shown = np.asarray(ImageOps.exif_transpose(Image.open(path)))
        np.testing.assert_array_equal(px, shown, err_msg=f"Orientation {orientation}")
        assert info["size"] == shown.shape[:2]


def test_phone_jpeg_with_orientation_6_is_read_upright(tmp_path, rng):
    # a phone held upright stores the photo sideways and says so in the EXIF Orientation
    stored = np.repeat(np.repeat(_codes(rng, (3, 5, 3)), 8, 0), 8, 1)   # 24 x 40, stored
    path = tmp_path / "phone.jpg"
    Image.fromarray(stored).save(path, exif=_exif(6), quality=100, subsampling=0)
    rgb = read_rgb(path)
    assert rgb.shape == (40, 24, 3)                      # upright: 24 wide, 40 tall
    upright = np.rot90(stored, k=-1) / 255.0             # 90 degrees clockwise
    assert np.abs(rgb - srgb_to_linear(upright)).max() < 0.05


def test_rgbd_pair_of_a_turned_photo_and_its_upright_depth_loads(tmp_path, rng):
    stored = _codes(rng, (16, 24, 3))
    photo = tmp_path / "phone.png"
    Image.fromarray(stored).save(photo, exif=_exif(8))
    depth = rng.uniform(1.0, 2.0, (24, 16)).astype(np.float32)      # upright, as MiDaS writes
    np.save(tmp_path / "depth.npy", depth)
    mpi = load_scene([photo, tmp_path / "depth.npy"], layers=4, near=0.002, far=0.004)
    assert mpi.shape == (24, 16)
    # a depth map in the stored (sideways) orientation is refused, and the message says why
    np.save(tmp_path / "sideways.npy", depth.T.copy())
    with pytest.raises(ValueError, match=r"sideways\.npy is 24x16 but .*phone\.png is 16x24; "
                                         r".*transposed.*EXIF Orientation"):
        load_scene([photo, tmp_path / "sideways.npy"], layers=4, near=0.002, far=0.004)


def test_depth_png_with_orientation_turns_with_its_photo(tmp_path, rng):
    depth = rng.integers(100, 60000, (6, 10), dtype=np.uint16)
    path = tmp_path / "depth.png"
    Image.fromarray(depth).save(path, exif=_exif(3))
    np.testing.assert_array_equal(read_depth(path), depth[::-1, ::-1])


# --- cut-off, empty and misnamed files ------------------------------------------------------

@pytest.mark.parametrize("progressive", [False, True])
def test_jpeg_cut_short_is_refused_not_padded_with_grey(tmp_path, rng, progressive):
    path = tmp_path / "photo.jpg"
    Image.fromarray(_codes(rng, (120, 160, 3))).save(path, quality=90, progressive=progressive)
    data = path.read_bytes()
    cut = tmp_path / "cut.jpg"
    cut.write_bytes(data[:int(len(data) * 0.9)])
    with pytest.raises(ValueError, match=r"cannot read pixels of .*cut\.jpg: .*Premature end of "
                                         r"JPEG file.*\(truncated file\?\)"):
        read_image(cut)
    with pytest.raises(ValueError, match=r"cut\.jpg"):
        read_rgb(cut)


def test_empty_image_file_says_it_is_empty(tmp_path):
    path = tmp_path / "layer.png"
    path.write_bytes(b"")
    with pytest.raises(ValueError, match=r"image file .*layer\.png is empty \(0 bytes\): copy "
                                         r"or export it again"):
        read_image(path)


def test_png_data_named_jpg_is_read_by_its_content(tmp_path, rng):
    pixels = _codes(rng, (5, 7, 3))
    Image.fromarray(pixels).save(tmp_path / "x.png")
    (tmp_path / "x.jpg").write_bytes((tmp_path / "x.png").read_bytes())
    px, _ = read_image(tmp_path / "x.jpg", normalise=False)
    np.testing.assert_array_equal(px, pixels)


def test_a_folder_named_like_an_image_is_refused(tmp_path):
    (tmp_path / "layer.png").mkdir()
    with pytest.raises(ValueError, match=r"image file .*layer\.png is a folder: give an image"):
        read_image(tmp_path / "layer.png")


# --- transfer functions: sRGB decoded once, gamma chunks honoured ---------------------------

def test_png_with_gamma_1_chunk_is_read_as_linear(tmp_path, rng):
    pixels = _codes(rng, (4, 6, 3))
    Image.fromarray(pixels).save(tmp_path / "plain.png")
    linear = _with_chunks(tmp_path / "plain.png", tmp_path / "linear.png",
                          [(b"gAMA", struct.pack(">I", 100000))])       # gamma 1.0
    np.testing.assert_allclose(read_rgb(linear), pixels / 255.0, atol=1e-6)
    # a plain PNG, and one with an sRGB chunk (which outranks gAMA), are sRGB: decoded once
    srgb = _with_chunks(tmp_path / "plain.png", tmp_path / "srgb.png",
                        [(b"gAMA", struct.pack(">I", 100000)), (b"sRGB", b"\0")])
    for path in (tmp_path / "plain.png", srgb):
        np.testing.assert_allclose(read_rgb(path), srgb_to_linear(pixels / 255.0), atol=1e-6)


def test_png_with_another_gamma_is_decoded_by_that_gamma(tmp_path, rng):
    pixels = _codes(rng, (4, 6, 3))
    Image.fromarray(pixels).save(tmp_path / "plain.png")
    path = _with_chunks(tmp_path / "plain.png", tmp_path / "g18.png",
                        [(b"gAMA", struct.pack(">I", 55556))])          # file gamma 1/1.8
    np.testing.assert_allclose(read_rgb(path), (pixels / 255.0) ** 1.8, rtol=1e-4, atol=1e-6)


def _mpi_folder(tmp_path, files, meta=None):
    meta = dict({"layers": files, "depths": [1.0, 2.0][:len(files)]}, **(meta or {}))
    (tmp_path / "mpi.json").write_text(json.dumps(meta))
    return tmp_path


def test_mpi_layer_that_states_linear_in_an_srgb_mpi_is_refused(tmp_path, rng):
    Image.fromarray(_codes(rng, (4, 6, 4)), "RGBA").save(tmp_path / "a.png")
    _with_chunks(tmp_path / "a.png", tmp_path / "layer.png", [(b"gAMA", struct.pack(">I", 100000))])
    folder = _mpi_folder(tmp_path, ["layer.png"])           # no "format": sRGB by default
    with pytest.raises(ValueError, match=r"layer\.png states linear values \(gamma 1\) but .*"
                                         r"mpi\.json reads its layers as sRGB.*color_encoding"):
        read_mpi(folder)
    _mpi_folder(tmp_path, ["layer.png"], {"color_encoding": "linear"})
    mpi = read_mpi(folder)                                   # said so: read as it is
    stored = np.asarray(Image.open(tmp_path / "a.png"))
    np.testing.assert_allclose(mpi.color[0], stored[..., :3] / 255.0, atol=1e-6)


# --- EXR data window ------------------------------------------------------------------------

def test_exr_with_a_cropped_data_window_is_placed_in_its_display_window(tmp_path, rng):
    import OpenImageIO as oiio

    data = rng.uniform(1.0, 2.0, (3, 4, 1)).astype(np.float32)
    spec = oiio.ImageSpec(4, 3, 1, "float")
    spec.x, spec.y = 2, 1
    spec.full_x, spec.full_y, spec.full_width, spec.full_height = 0, 0, 8, 6
    spec.channelnames = ("Z",)
    path = tmp_path / "depth.exr"
    out = oiio.ImageOutput.create(str(path))
    assert out.open(str(path), spec) and out.write_image(data)
    out.close()
    expected = np.zeros((6, 8), np.float32)
    expected[1:4, 2:6] = data[..., 0]
    np.testing.assert_array_equal(read_depth(path), expected)


# --- variants that are read right today (pinned) --------------------------------------------

def test_palette_png_with_trns_is_a_straight_rgba_layer(tmp_path, rng):
    pal = Image.fromarray(_codes(rng, (6, 8, 3))).convert("P", palette=Image.ADAPTIVE,
                                                          colors=16)
    pal.save(tmp_path / "layer.png", transparency=3)
    expected = np.asarray(Image.open(tmp_path / "layer.png").convert("RGBA"))
    assert (expected[..., 3] == 0).any() and (expected[..., 3] == 255).any()
    mpi = read_mpi(_mpi_folder(tmp_path, ["layer.png"],
                               {"format": "clholo-mpi", "color_encoding": "srgb"}))
    np.testing.assert_allclose(mpi.alpha[0], expected[..., 3] / 255.0)
    np.testing.assert_allclose(mpi.color[0], srgb_to_linear(expected[..., :3] / 255.0),
                               atol=1e-6)


def test_mpi_of_8_and_16_bit_grey_alpha_layers_decodes_each_by_its_depth(tmp_path, rng):
    la8 = _codes(rng, (4, 6, 2))
    Image.fromarray(la8, "LA").save(tmp_path / "l0.png")
    la16 = rng.integers(1, 65535, (4, 6, 2), dtype=np.uint16)
    write_image(tmp_path / "l1.png", la16 / 65535.0, dtype="uint16")
    mpi = read_mpi(_mpi_folder(tmp_path, ["l0.png", "l1.png"]))
    np.testing.assert_allclose(mpi.color[0, ..., 0], srgb_to_linear(la8[..., 0] / 255.0),
                               atol=1e-6)
    np.testing.assert_allclose(mpi.color[1, ..., 0], srgb_to_linear(la16[..., 0] / 65535.0),
                               atol=1e-6)
    np.testing.assert_allclose(mpi.alpha[0], la8[..., 1] / 255.0, atol=1e-6)
    np.testing.assert_allclose(mpi.alpha[1], 1.0)           # farthest layer opaque (SM rule)


def test_16_bit_grey_png_depth_keeps_its_codes(tmp_path, rng):
    depth = rng.integers(1, 65535, (5, 7), dtype=np.uint16)
    Image.fromarray(depth).save(tmp_path / "depth_mm.png")
    np.testing.assert_array_equal(read_depth(tmp_path / "depth_mm.png"), depth)
    np.testing.assert_allclose(read_depth(tmp_path / "depth_mm.png", scale=1e-3), depth * 1e-3,
                               rtol=1e-6)


def test_float_tiff_depth_keeps_nan_and_inf_holes(tmp_path, rng):
    tifffile = pytest.importorskip("tifffile", reason="tifffile writes the float TIFF")
    depth = rng.uniform(0.5, 3.0, (5, 7)).astype(np.float32)
    depth[1, 2], depth[3, 4] = np.nan, np.inf
    tifffile.imwrite(tmp_path / "depth.tif", depth)
    got = read_depth(tmp_path / "depth.tif")
    np.testing.assert_array_equal(got, depth)                 # NaN == NaN here
    assert np.isnan(got[1, 2]) and np.isinf(got[3, 4])


def test_cmyk_jpeg_is_read_as_rgb_like_viewers(tmp_path, rng):
    rgb = np.repeat(np.repeat(_codes(rng, (3, 4, 3)), 8, 0), 8, 1)
    Image.fromarray(rgb).convert("CMYK").save(tmp_path / "print.jpg", quality=100)
    px, info = read_image(tmp_path / "print.jpg", normalise=False)
    assert px.shape == (24, 32, 3) and info["channels"] == ("R", "G", "B")
    shown = np.asarray(Image.open(tmp_path / "print.jpg").convert("RGB")).astype(np.float32)
    assert np.abs(px - shown).max() <= 2


# --- what clholo writes says what it holds --------------------------------------------------

def _png_chunks(path):
    """The chunk types of PNG ``path`` with their bodies (the colour statements among them)."""
    data, at, chunks = path.read_bytes(), 8, {}
    while at < len(data):
        (length,), kind = struct.unpack(">I", data[at:at + 4]), data[at + 4:at + 8]
        chunks[kind] = data[at + 8:at + 8 + length]
        at += 12 + length
    return chunks


@pytest.mark.parametrize("fmt", ["png8", "png16"])
def test_write_mpi_png_layers_state_their_encoding(tmp_path, rng, fmt):
    # linear layers in a PNG labelled sRGB would be shown (and read by every other tool)
    # brighter than they are: they state gamma 1 and no sRGB; sRGB layers state sRGB
    mpi = MPI(rng.random((2, 5, 7, 3), dtype=np.float32) * 0.9 + 0.05,
              rng.random((2, 5, 7), dtype=np.float32), [1e-3, 2e-3])
    for encoding in ("linear", "srgb"):
        folder = write_mpi(tmp_path / encoding, mpi, format=fmt, encoding=encoding)
        chunks = _png_chunks(folder / "layer_00.png")
        if encoding == "linear":
            assert b"sRGB" not in chunks and b"iCCP" not in chunks
            assert struct.unpack(">I", chunks[b"gAMA"]) == (100000,)
        else:
            assert b"sRGB" in chunks
        # a viewer's reading of the file alone (read_rgb honours gAMA) is the layer's colour
        top = 255 if fmt == "png8" else 65535
        np.testing.assert_allclose(read_rgb(folder / "layer_00.png"), mpi.color[0],
                                   atol=(0.5 if encoding == "linear" else 6.0) / top)
        np.testing.assert_allclose(read_mpi(folder).color, mpi.color, atol=6.0 / top)


def test_slm_pattern_pngs_state_no_colour(tmp_path, rng):
    # phase levels are no colour: no sRGB or gamma statement for a viewer to colour-manage
    from clholo.encode.quantize import read_pattern_pngs, write_pattern_pngs

    gray = rng.integers(0, 256, (2, 1, 6, 9), dtype=np.uint8)
    folder = write_pattern_pngs(gray, tmp_path / "slm")
    for png in sorted(folder.glob("*.png")):
        assert not {b"sRGB", b"gAMA", b"iCCP", b"cHRM"} & set(_png_chunks(png)), png.name
    np.testing.assert_array_equal(read_pattern_pngs(folder), gray)


def test_write_image_refuses_an_unknown_encoding(tmp_path, rng):
    with pytest.raises(ValueError, match=r"encoding must be one of \['data', 'linear', 'srgb'\]"):
        write_image(tmp_path / "x.png", rng.random((3, 4, 3)), dtype="uint8", encoding="sRGB")
    assert not list(tmp_path.iterdir())


# --- colour and depth in one file (an RGB-D EXR) --------------------------------------------

_BLENDER_MULTILAYER = ("ViewLayer.Combined.R", "ViewLayer.Combined.G", "ViewLayer.Combined.B",
                       "ViewLayer.Combined.A", "ViewLayer.Depth.Z")


@pytest.mark.parametrize("names", [("R", "G", "B", "A", "Z"), ("R", "G", "B", "depth"),
                                   _BLENDER_MULTILAYER])
def test_exr_with_colour_and_z_is_an_rgbd_scene_by_itself(tmp_path, rng, names):
    # a renderer's EXR with a Z pass (Blender: R G B A Z, or a multilayer file's
    # ViewLayer.Depth.Z) was refused as a colour-mapped depth map; it is an RGB-D scene
    h, w = 12, 18
    colour = rng.random((h, w, 3), dtype=np.float32)
    depth = (1.0 + 3.0 * rng.random((h, w))).astype(np.float32)
    planes = [colour] + ([rng.random((h, w, 1), dtype=np.float32)] if len(names) == 5 else [])
    write_image(tmp_path / "render.exr", np.concatenate(planes + [depth[..., None]], axis=-1),
                channel_names=names)
    np.testing.assert_array_equal(read_depth(tmp_path / "render.exr"), depth)
    np.testing.assert_array_equal(read_rgb(tmp_path / "render.exr"), colour)
    # the same scene as the colour and the depth in files of their own
    write_image(tmp_path / "colour.exr", colour)
    np.save(tmp_path / "depth.npy", depth)
    pair = load_scene([tmp_path / "colour.exr", tmp_path / "depth.npy"], layers=6,
                      near=2e-3, far=6e-3)
    for given in (tmp_path / "render.exr", [tmp_path / "render.exr"] * 2):
        one = load_scene(given, layers=6, near=2e-3, far=6e-3)
        np.testing.assert_array_equal(one.color, pair.color)
        np.testing.assert_array_equal(one.alpha, pair.alpha)
        np.testing.assert_array_equal(one.depths, pair.depths)
    assert len(np.unique(np.argmax(pair.alpha > 0, axis=0))) > 2   # the depths spread planes


def test_render_command_takes_an_rgbd_exr(tmp_path, rng):
    from clholo import cli, io

    px = rng.random((16, 20, 4), dtype=np.float32)
    px[..., 3] += 1.0
    write_image(tmp_path / "render.exr", px, channel_names=("R", "G", "B", "Z"))
    out = tmp_path / "out"
    assert cli.main(["render", str(tmp_path / "render.exr"), "--near", "0.002", "--far",
                     "0.004", "--layers", "4", "--frames", "1", "--out", str(out)]) == 0
    assert io.read_hologram(out / "hologram.npz")[0].shape == (1, 3, 16, 20)


def test_depth_without_colour_or_colour_without_depth_in_one_file_is_refused(tmp_path, rng):
    write_image(tmp_path / "z.exr", 1.0 + rng.random((8, 8, 1), dtype=np.float32),
                channel_names=("Z",))
    with pytest.raises(ValueError, match=r"z\.exr holds depth \(Z\) but no colour: give the "
                                         r"image first, then this file as its depth map"):
        load_scene(tmp_path / "z.exr", near=2e-3, far=6e-3)
    with pytest.raises(ValueError, match=r"z\.exr holds no colour channel \(only Z\)"):
        read_rgb(tmp_path / "z.exr")
    write_image(tmp_path / "rgb.exr", rng.random((8, 8, 3), dtype=np.float32))
    with pytest.raises(ValueError, match=r"rgb\.exr is an image without a depth channel: give "
                                         r"it and its depth map together \(image first\), or "
                                         r"one image with colour and a depth channel named Z"):
        load_scene(tmp_path / "rgb.exr", near=2e-3, far=6e-3)
    write_image(tmp_path / "zz.exr", 1.0 + rng.random((8, 8, 5), dtype=np.float32),
                channel_names=("R", "G", "B", "left.Z", "right.Z"))
    with pytest.raises(ValueError, match=r"zz\.exr has 2 depth channels \(left\.Z, right\.Z\): "
                                         r"clholo takes one"):
        read_depth(tmp_path / "zz.exr")


def test_renderer_background_depth_is_no_surface_not_the_far_end(tmp_path, rng):
    # Blender's Z pass writes 1e10 where a ray hits nothing: taken as a depth it stretched the
    # range so that every surface landed in the nearest plane; it is filled like inf
    h, w = 16, 24
    depth = (1.0 + 3.0 * rng.random((h, w))).astype(np.float32)
    depth[:5] = 1e10                                       # sky
    colour = rng.random((h, w, 3), dtype=np.float32)
    write_image(tmp_path / "blender.exr", np.dstack([colour, depth]),
                channel_names=("R", "G", "B", "Z"))
    mpi = load_scene(tmp_path / "blender.exr", layers=8, near=2e-3, far=6e-3)
    inf = depth.copy()
    inf[:5] = np.inf
    np.save(tmp_path / "inf.npy", inf)
    write_image(tmp_path / "colour.exr", colour)
    same = load_scene([tmp_path / "colour.exr", tmp_path / "inf.npy"], layers=8,
                      near=2e-3, far=6e-3)
    np.testing.assert_array_equal(mpi.alpha, same.alpha)
    plane = np.argmax(mpi.alpha > 0, axis=0)             # hard mode: one plane per pixel
    assert len(np.unique(plane[5:])) >= 6                 # the surfaces spread over the planes
    with pytest.raises(ValueError, match=r"120 invalid pixel\(s\) \(NaN, inf or >= 1e10"):
        load_scene(tmp_path / "blender.exr", layers=8, near=2e-3, far=6e-3, invalid="error")


# --- files that hold several pictures -------------------------------------------------------

def _multi_picture(path, rng, sizes):
    import OpenImageIO as oiio

    specs = [oiio.ImageSpec(w, h, 3, "uint8") for h, w in sizes]
    out = oiio.ImageOutput.create(str(path))
    assert out.open(str(path), specs)
    for k, (h, w) in enumerate(sizes):
        if k:
            assert out.open(str(path), specs[k], "AppendSubimage")
        assert out.write_image(_codes(rng, (h, w, 3)))
    out.close()
    return path


@pytest.mark.parametrize("name, count, kind", [("stack.tif", 3, "pages"),
                                               ("stereo.exr", 2, "parts of an EXR")])
def test_a_stack_of_pictures_in_one_file_is_refused_not_cut_to_its_first(tmp_path, rng, name,
                                                                        count, kind):
    # a multi-page TIFF (frames, layers) or a multi-part EXR (a stereo pair's views) was read
    # as its first picture, the others dropped without a word
    path = _multi_picture(tmp_path / name, rng, [(8, 12)] * count)
    with pytest.raises(ValueError, match=rf"{name} holds {count} pictures of 12x8 \({kind}\); "
                                         r"clholo reads one picture per file"):
        read_image(path)
    np.save(tmp_path / "depth.npy", 1.0 + rng.random((8, 12)))
    with pytest.raises(ValueError, match=rf"{name} holds {count} pictures"):
        load_scene([path, tmp_path / "depth.npy"], near=2e-3, far=6e-3)


def test_a_tiff_with_a_thumbnail_page_reads_its_picture(tmp_path, rng):
    # smaller later pages (a thumbnail, reduced-resolution pages) are what viewers skip too
    path = _multi_picture(tmp_path / "photo.tif", rng, [(8, 12), (4, 6)])
    pixels, info = read_image(path)
    assert pixels.shape == (8, 12, 3) and info["size"] == (8, 12)


@pytest.mark.parametrize("name, hint", [
    ("IMG_0001.HEIC", r"export the photo as JPEG or PNG \(on an iPhone: Settings > Camera > "
                      r"Formats > Most Compatible"),
    ("DSC_0001.NEF", r"develop the camera raw file to a 16-bit TIFF or PNG first"),
])
def test_a_photo_format_without_a_reader_says_how_to_convert_it(tmp_path, rng, name, hint):
    # an iPhone's HEIC or a camera's raw file: OpenImageIO's PyPI build has no reader for them
    # and said only that it "could not find a format reader"
    import OpenImageIO as oiio

    from clholo.io import images

    path = tmp_path / name
    path.write_bytes(b"\0\0\0\x18ftypheic\0\0\0\0mif1heic" + rng.bytes(512))
    with pytest.raises(ValueError) as exc:
        read_rgb(path)
    assert str(path) in str(exc.value)
    if not images._has_reader(oiio, path.suffix):      # OpenImageIO's PyPI wheel (CI's)
        assert re.search(rf"no reader for {path.suffix} files: {hint}", str(exc.value))
    else:                                               # a build with the plugin: its own error
        assert "no reader for" not in str(exc.value)


def test_a_phones_smaller_depth_map_says_which_size_to_resize_to(tmp_path, rng):
    # an iPhone's depth map is 768x576 for a 4032x3024 photo: the size mismatch says so
    Image.fromarray(_codes(rng, (30, 40, 3))).save(tmp_path / "photo.jpg", quality=95)
    np.save(tmp_path / "small.npy", 1.0 + rng.random((15, 20)))
    with pytest.raises(ValueError, match=r"small\.npy is 20x15 but .*photo\.jpg is 40x30; they "
                                         r"must match; the depth map is the photo's shape 2x "
                                         r"smaller \(a phone's is\): match_size='photo' "
                                         r"\(--match-size photo\) resizes the depth map to "
                                         r"40x30 .*match_size='depth' \(--match-size depth\) "
                                         r"the photo to 20x15"):
        load_scene([tmp_path / "photo.jpg", tmp_path / "small.npy"], near=2e-3, far=6e-3)
    np.save(tmp_path / "other.npy", 1.0 + rng.random((20, 20)))   # another shape: no hint
    for match in (None, "photo", "depth"):  # and no resize: which part to crop is unknown
        with pytest.raises(ValueError, match=r"other\.npy is 20x20 but .*; they must match$"):
            load_scene([tmp_path / "photo.jpg", tmp_path / "other.npy"], near=2e-3, far=6e-3,
                       match_size=match)


def test_match_size_resizes_the_depth_map_or_the_photo(tmp_path, rng):
    from clholo.io import read_rgb, write_image

    codes = _codes(rng, (30, 40, 3))
    Image.fromarray(codes).save(tmp_path / "photo.png")
    small = (1.0 + rng.random((15, 20))).astype(np.float32)
    np.save(tmp_path / "small.npy", small)
    pair = [tmp_path / "photo.png", tmp_path / "small.npy"]
    opts = dict(layers=6, near=2e-3, far=6e-3)
    # "photo": the depth map at the photo's size, nearest neighbour (each value twice along
    # each axis at 2x): the same MPI as that map given at full size
    np.save(tmp_path / "big.npy", np.repeat(np.repeat(small, 2, axis=0), 2, axis=1))
    got = load_scene(pair, match_size="photo", **opts)
    want = load_scene([tmp_path / "photo.png", tmp_path / "big.npy"], **opts)
    assert got.shape == (30, 40)
    np.testing.assert_array_equal(got.color, want.color)
    np.testing.assert_array_equal(got.alpha, want.alpha)
    np.testing.assert_array_equal(got.depths, want.depths)
    # "depth": the photo at the depth map's size, anti-aliased in linear colour (its mean kept)
    got = load_scene(pair, match_size="depth", **opts)
    assert got.shape == (15, 20)
    full = read_rgb(tmp_path / "photo.png")
    shown = (got.color * got.alpha[..., None]).sum(axis=0)   # hard layers: one plane a pixel
    np.testing.assert_allclose(shown.mean(axis=(0, 1)), full.mean(axis=(0, 1)), rtol=0.02)
    write_image(tmp_path / "smallphoto.exr", shown, dtype="float")
    same = load_scene([tmp_path / "smallphoto.exr", tmp_path / "small.npy"], **opts)
    np.testing.assert_allclose(same.color, got.color, atol=1e-6)
    # sizes that already match: nothing resized
    np.testing.assert_array_equal(
        load_scene([tmp_path / "photo.png", tmp_path / "big.npy"], match_size="depth",
                   **opts).color, want.color)
    # turned a quarter: refused as before
    np.save(tmp_path / "turned.npy", np.ones((40, 30), np.float32))
    with pytest.raises(ValueError, match="transposed"):
        load_scene([tmp_path / "photo.png", tmp_path / "turned.npy"], match_size="photo",
                   **opts)


def test_match_size_edges_follows_the_photos_edge(tmp_path, rng):
    """A phone's depth map is 6-8x coarser than its photo: resized by nearest neighbour, its
    edge lies on the map's pixel grid, up to half a map pixel (here 4 photo pixels) off the
    photo's edge, and those pixels land on the wrong surface's plane. "edges" moves each
    photo pixel to the map pixel of its own colour: the depth edge is the photo's edge, and
    every depth is one of the map's."""
    from clholo.io.load import _edge_guided, _nearest

    H, W, f, edge = 48, 96, 8, 37            # the photo's edge at column 37
    image = np.empty((H, W, 3), np.float32)
    image[:, :edge] = (0.8, 0.2, 0.1)       # a red object in front ...
    image[:, edge:] = (0.1, 0.2, 0.7)       # ... of a blue wall
    image += rng.uniform(-0.02, 0.02, image.shape).astype(np.float32)  # sensor noise
    depth = np.where(np.arange(W // f) <= edge // f, 0.8, 2.5)[None].repeat(H // f, 0)
    depth = depth.astype(np.float32)         # the map's estimate: its column 4 (32..39) near
    nearest = _nearest(depth, (H, W))
    assert np.count_nonzero(nearest[:, edge:] == 0.8) == 3 * H   # 37..39 on the near plane
    got = _edge_guided(depth, image)
    assert np.all(got[:, :edge] == 0.8) and np.all(got[:, edge:] == 2.5)
    # each of the 3x3 candidates counts: a red object reaches one photo row into the grey map
    # pixel below it, whose average stays mostly grey; those red pixels take the depth of the
    # red map pixel straight above (dy -1, dx 0), not a diagonal one's or their own, and no
    # grey pixel takes it
    grey = np.full((20, 20, 3), 0.5, np.float32)
    grey[4:9, 8:12] = (0.9, 0.1, 0.1)        # map pixel (1, 2) and photo row 8 below it
    labels = np.arange(25, dtype=np.float32).reshape(5, 5)
    got = _edge_guided(labels, grey)
    assert np.array_equal(got == labels[1, 2], grey[..., 0] > 0.8)
    # away from edges (one colour all round) it is nearest neighbour
    flat = np.full((H, W, 3), 0.5, np.float32)
    smooth = rng.uniform(1, 2, (H // f, W // f)).astype(np.float32)
    np.testing.assert_array_equal(_edge_guided(smooth, flat), _nearest(smooth, (H, W)))
    # through load_scene, for a pair and through the option's checks
    Image.fromarray((np.clip(image, 0, 1) * 255).round().astype(np.uint8)).save(
        tmp_path / "photo.png")
    np.save(tmp_path / "small.npy", depth)
    mpi = load_scene([tmp_path / "photo.png", tmp_path / "small.npy"], layers=2, near=2e-3,
                     far=6e-3, match_size="edges")
    assert np.array_equal(mpi.alpha[0] > 0, np.arange(W)[None].repeat(H, 0) < edge)


def test_match_size_is_checked(tmp_path, rng):
    Image.fromarray(_codes(rng, (30, 40, 3))).save(tmp_path / "photo.png")
    np.save(tmp_path / "small.npy", 1.0 + rng.random((15, 20)))
    pair = [tmp_path / "photo.png", tmp_path / "small.npy"]
    with pytest.raises(ValueError, match="match_size must be 'photo'.*got 'both'"):
        load_scene(pair, near=2e-3, far=6e-3, match_size="both")
    from clholo.io import write_mpi
    from clholo.scene import MPI

    mpi = MPI(rng.random((2, 6, 8, 3), dtype=np.float32), rng.random((2, 6, 8), dtype=np.float32),
              np.array([2e-3, 3e-3]))
    folder = write_mpi(tmp_path / "mpi", mpi)
    with pytest.raises(ValueError, match="match_size='photo' resizes an RGB-D pair's photo or "
                                         "depth map; this input is 'mpi_folder': drop "
                                         "match_size"):
        load_scene(folder, match_size="photo")
