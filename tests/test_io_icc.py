"""Embedded ICC profiles (clholo.io.icc): a photo in Display P3, Adobe RGB or another
matrix/TRC space reads as the linear sRGB it shows, checked against littlecms (Pillow's
ImageCms, an independent implementation) and against the published P3 -> sRGB matrix; sRGB's
own profile changes nothing; a profile clholo cannot apply is named in a warning. OpenEXR's
chromaticities (ACES, ACEScg, Rec. 2020 renders) likewise, against the published ACES ->
sRGB matrices."""

import io
import struct
import warnings

import numpy as np
import pytest

from clholo.io import load_scene, srgb_to_linear, linear_to_srgb
from clholo.io.icc import ColourProfileWarning, parse_icc
from clholo.io.rgbd import read_rgb

PIL = pytest.importorskip("PIL", reason="Pillow (scikit-image's dependency) writes the files")
from PIL import Image, ImageCms  # noqa: E402

_D50 = (0.9642, 1.0, 0.8249)  # ICC's PCS illuminant
_BRADFORD = np.array([[0.8951, 0.2664, -0.1614], [-0.7502, 1.7135, 0.0367],
                      [0.0389, -0.0685, 1.0296]])
_P3 = ((0.680, 0.320), (0.265, 0.690), (0.150, 0.060))
_ADOBE = ((0.64, 0.33), (0.21, 0.71), (0.15, 0.06))
_SRGB = ((0.64, 0.33), (0.30, 0.60), (0.15, 0.06))
_SRGB_CURVE = ("para", 3, (2.4, 1 / 1.055, 0.055 / 1.055, 1 / 12.92, 0.04045))


def _colorants(primaries, white=(0.3127, 0.3290)):
    """An RGB space's colorant matrix (columns rXYZ, gXYZ, bXYZ) adapted to D50 by Bradford,
    as a display profile stores it."""
    def xyz(x, y):
        return np.array([x / y, 1.0, (1 - x - y) / y])
    prim = np.stack([xyz(*p) for p in primaries], axis=1)
    w = xyz(*white)
    m = prim * np.linalg.solve(prim, w)
    cone = np.diag((_BRADFORD @ np.array(_D50)) / (_BRADFORD @ w))
    return np.linalg.inv(_BRADFORD) @ cone @ _BRADFORD @ m


def _s15(v):
    return struct.pack(">i", int(round(v * 65536)))


def _curve_tag(curve):
    if curve[0] == "gamma":
        return b"curv" + bytes(4) + struct.pack(">IH", 1, int(round(curve[1] * 256))) + bytes(2)
    if curve[0] == "table":
        table = np.round(np.asarray(curve[1]) * 65535).astype(">u2").tobytes()
        return b"curv" + bytes(4) + struct.pack(">I", len(curve[1])) + table
    return (b"para" + bytes(4) + struct.pack(">HH", curve[1], 0)
            + b"".join(_s15(p) for p in curve[2]))


def _profile(primaries=_P3, curve=_SRGB_CURVE, *, name="Display P3 (test)", space=b"RGB ",
             extra=(), colorants=True):
    """An ICC v2.1 display profile of matrix/TRC form, byte by byte (ICC.1 7.2, 7.3)."""
    text = name.encode() + b"\0"
    tags = [(b"desc", b"desc" + bytes(4) + struct.pack(">I", len(text)) + text + bytes(78)),
            (b"wtpt", b"XYZ " + bytes(4) + b"".join(_s15(v) for v in _D50))]
    if colorants:
        m = _colorants(primaries)
        tags += [(n, b"XYZ " + bytes(4) + b"".join(_s15(v) for v in m[:, k]))
                 for k, n in enumerate((b"rXYZ", b"gXYZ", b"bXYZ"))]
    if curve is not None:
        names = (b"rTRC", b"gTRC", b"bTRC") if space == b"RGB " else (b"kTRC",)
        tags += [(n, _curve_tag(curve)) for n in names]
    tags += list(extra)
    at = 128 + 4 + 12 * len(tags)
    table, body = b"", b""
    for sig, data in tags:
        data += bytes(-len(data) % 4)
        table += struct.pack(">4sII", sig, at, len(data))
        body += data
        at += len(data)
    header = (struct.pack(">I", at) + bytes(4) + struct.pack(">I", 0x02100000) + b"mntr"
              + space + b"XYZ " + bytes(12) + b"acsp" + bytes(28)
              + b"".join(_s15(v) for v in _D50) + bytes(48))
    assert len(header) == 128
    return header + struct.pack(">I", len(tags)) + table + body


def _littlecms(codes, profile):
    """8-bit ``codes`` through littlecms from ``profile`` to its sRGB, relative colorimetric."""
    transform = ImageCms.buildTransform(
        ImageCms.ImageCmsProfile(io.BytesIO(profile)),
        ImageCms.ImageCmsProfile(ImageCms.createProfile("sRGB")), "RGB", "RGB",
        renderingIntent=ImageCms.Intent.RELATIVE_COLORIMETRIC)
    return np.asarray(ImageCms.applyTransform(Image.fromarray(codes), transform)).astype(float)


def _codes(rng, shape=(24, 32, 3)):
    codes = rng.integers(0, 256, shape, dtype=np.uint8)
    codes[0, :8] = [[255, 0, 0], [0, 255, 0], [0, 0, 255], [255, 255, 255], [0, 0, 0],
                    [255, 255, 0], [128, 128, 128], [1, 2, 3]]     # primaries, white, black
    return codes


@pytest.mark.parametrize("primaries, curve", [
    (_P3, _SRGB_CURVE),                                         # Display P3
    (_ADOBE, ("gamma", 563 / 256)),                             # Adobe RGB (1998)
    (_P3, ("para", 0, (1.8,))),                                 # each parametric form
    (_ADOBE, ("para", 1, (2.2, 1.05, -0.05))),
    (_P3, ("para", 2, (2.2, 0.95, 0.05, 0.002))),
    (_ADOBE, ("para", 4, (2.4, 0.95, 0.05, 0.08, 0.05, 0.001, 0.0005))),
    (_P3, ("table", np.linspace(0, 1, 1024) ** 2.6)),           # a table (DCI's gamma)
])
def test_profiled_photo_reads_as_littlecms_converts_it(tmp_path, rng, primaries, curve):
    codes = _codes(rng)
    profile = _profile(primaries, curve)
    Image.fromarray(codes).save(tmp_path / "photo.png", icc_profile=profile)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # an applied profile warns of nothing
        ours = read_rgb(tmp_path / "photo.png")
    lcms = _littlecms(codes, profile)
    # littlecms rounds to 8-bit codes; ours is float: half a code apart, plus its rounding
    np.testing.assert_allclose(linear_to_srgb(ours) * 255.0, lcms, atol=1.0)
    # and it changed something: as sRGB the colours would read otherwise
    assert np.max(np.abs(linear_to_srgb(ours) * 255.0 - codes)) > 8


def test_display_p3_matches_the_published_p3_to_srgb_matrix_at_16_bits(tmp_path, rng):
    # linear P3 -> linear sRGB, both D65 (e.g. Apple's and W3C CSS Color 4's, to 4 decimals)
    p3_to_srgb = np.array([[1.2249, -0.2247, 0.0], [-0.0420, 1.0419, 0.0],
                           [-0.0197, -0.0786, 1.0979]])
    codes = rng.integers(0, 65536, (16, 20, 3), dtype=np.uint16)
    Image.fromarray(np.zeros((16, 20, 3), np.uint8)).save(tmp_path / "x.png")  # for its size
    import OpenImageIO as oiio

    spec = oiio.ImageSpec(20, 16, 3, "uint16")
    spec.attribute("ICCProfile", oiio.TypeDesc("uint8[%d]" % len(_profile())),
                   np.frombuffer(_profile(), np.uint8))
    out = oiio.ImageOutput.create(str(tmp_path / "p3.tif"))
    assert out.open(str(tmp_path / "p3.tif"), spec) and out.write_image(codes)
    out.close()
    ours = read_rgb(tmp_path / "p3.tif")
    expected = np.clip(srgb_to_linear(codes / 65535.0) @ p3_to_srgb.T, 0.0, 1.0)
    np.testing.assert_allclose(ours, expected, atol=6e-4)
    # P3's pure green lies outside sRGB: clipped, as littlecms clips it
    green = np.array([[[0, 65535, 0]]], np.uint16)
    assert np.allclose(np.clip(srgb_to_linear(green / 65535.0) @ p3_to_srgb.T, 0, 1),
                       [0, 1, 0], atol=1e-3)


@pytest.mark.parametrize("how", ["littlecms sRGB", "sRGB as a table"])
def test_srgb_profile_reads_bit_for_bit_as_no_profile(tmp_path, rng, how):
    codes = _codes(rng)
    profile = (ImageCms.ImageCmsProfile(ImageCms.createProfile("sRGB")).tobytes()
               if how == "littlecms sRGB" else
               _profile(_SRGB, ("table", srgb_to_linear(np.linspace(0, 1, 1024))),
                        name="sRGB IEC61966-2.1"))
    assert parse_icc(profile).is_srgb()
    Image.fromarray(codes).save(tmp_path / "plain.png")
    Image.fromarray(codes).save(tmp_path / "tagged.png", icc_profile=profile)
    np.testing.assert_array_equal(read_rgb(tmp_path / "tagged.png"),
                                  read_rgb(tmp_path / "plain.png"))


def test_grey_profile_decodes_by_its_curve(tmp_path, rng):
    codes = rng.integers(0, 256, (10, 12), dtype=np.uint8)
    profile = _profile(curve=("gamma", 460 / 256), space=b"GRAY", colorants=False, name="Gray 1.8")
    Image.fromarray(codes, "L").save(tmp_path / "grey.png", icc_profile=profile)
    np.testing.assert_allclose(read_rgb(tmp_path / "grey.png"),
                               np.repeat(((codes / 255.0) ** (460 / 256))[..., None], 3, axis=2),
                               atol=1e-6)


@pytest.mark.parametrize("kind, message", [
    ("lut", r"its ICC profile 'Camera LUT \(test\)' \(built from lookup tables\) is not "
            r"applied: colour taken as sRGB; convert the image to sRGB first"),
    ("broken", r"its ICC profile cannot be read \(tag rTRC is b'junk', not a curve"),
])
def test_a_profile_clholo_cannot_apply_is_named_and_the_colour_read_as_srgb(tmp_path, rng,
                                                                           kind, message):
    codes = _codes(rng)
    if kind == "lut":  # A2B0 tables (a camera or printer profile), no matrix/TRC
        profile = _profile(curve=None, colorants=False, name="Camera LUT (test)",
                           extra=[(b"A2B0", b"mft2" + bytes(48))])
    else:
        profile = _profile()
        at = profile.index(b"para")
        profile = profile[:at] + b"junk" + profile[at + 4:]
    Image.fromarray(codes).save(tmp_path / "photo.png", icc_profile=profile)
    with pytest.warns(ColourProfileWarning, match=r"photo\.png: " + message):
        colour = read_rgb(tmp_path / "photo.png")
    np.testing.assert_allclose(colour, srgb_to_linear(codes / 255.0), atol=1e-6)


def test_rgbd_scene_of_a_p3_photo_carries_its_colour(tmp_path, rng):
    codes = _codes(rng, (16, 24, 3))
    Image.fromarray(codes).save(tmp_path / "photo.jpg", icc_profile=_profile(), quality=100)
    np.save(tmp_path / "depth.npy", 1.0 + rng.random((16, 24)))
    mpi = load_scene([tmp_path / "photo.jpg", tmp_path / "depth.npy"], layers=4,
                     near=2e-3, far=6e-3)
    np.testing.assert_allclose(mpi.color[0], read_rgb(tmp_path / "photo.jpg"), atol=1e-6)
    decoded = np.asarray(Image.open(tmp_path / "photo.jpg"))   # the JPEG's own codes
    np.testing.assert_allclose(linear_to_srgb(mpi.color[0]) * 255.0,
                               _littlecms(decoded, _profile()), atol=1.0)


def _profile_warnings_of_folder(folder, layers, **fields):
    """The ColourProfileWarning messages of reading an MPI folder of ``layers`` (an mpi.json
    written with depths 1, 2, 3, ... and ``fields``)."""
    import json

    from clholo.io import read_mpi

    (folder / "mpi.json").write_text(json.dumps(
        {"layers": layers, "depths": [float(k + 1) for k in range(len(layers))], **fields}))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        read_mpi(folder)
    return [str(w.message) for w in caught if issubclass(w.category, ColourProfileWarning)]


def test_mpi_layers_with_a_p3_profile_are_named_once_for_the_folder(tmp_path, rng):
    # MPI layers follow mpi.json's color_encoding; a profile they carry is not applied, and
    # the folder says so once (not once a layer); sRGB's own profile says nothing
    for name, profile in (("p3", _profile()),
                          ("srgb", ImageCms.ImageCmsProfile(ImageCms.createProfile("sRGB"))
                           .tobytes())):
        folder = tmp_path / name
        folder.mkdir()
        for k in range(3):
            Image.fromarray(rng.integers(0, 256, (6, 8, 4), dtype=np.uint8), "RGBA").save(
                folder / f"layer_{k}.png", icc_profile=profile)
        said = _profile_warnings_of_folder(folder, [f"layer_{k}.png" for k in range(3)])
        if name == "p3":
            assert len(said) == 1, said
            assert ("3 layer file(s) of" in said[0] and "layer_0.png: 'Display P3 (test)'"
                    in said[0] and "color_encoding ('srgb'), not by profiles" in said[0])
        else:
            assert said == []


# --------------------------------------------------------------- OpenEXR chromaticities
# ACES primaries (SMPTE ST 2065-1; S-2014-004 for AP1), white point "D60" of both
_AP0 = (0.7347, 0.2653, 0.0, 1.0, 0.0001, -0.0770, 0.32168, 0.33767)
_AP1 = (0.713, 0.293, 0.165, 0.830, 0.128, 0.044, 0.32168, 0.33767)
_REC2020 = (0.708, 0.292, 0.170, 0.797, 0.131, 0.046, 0.3127, 0.3290)
_REC709 = (0.64, 0.33, 0.30, 0.60, 0.15, 0.06, 0.3127, 0.3290)
# the published conversions to linear sRGB (Rec. 709, D65) with Bradford's adaptation, to
# five decimals (colour-science's RGB_COLOURSPACE matrices; OpenColorIO's ACES configuration)
_AP1_TO_SRGB = np.array([[1.70505, -0.62179, -0.08326], [-0.13026, 1.14080, -0.01055],
                         [-0.02400, -0.12897, 1.15297]])
_AP0_TO_SRGB = np.array([[2.52169, -1.13413, -0.38756], [-0.27648, 1.37272, -0.09624],
                         [-0.01538, -0.15298, 1.16835]])


@pytest.mark.parametrize("chroma,published", [(_AP1, _AP1_TO_SRGB), (_AP0, _AP0_TO_SRGB)])
def test_aces_chromaticities_give_the_published_matrices(chroma, published):
    from clholo.io.icc import chromaticities_matrix

    np.testing.assert_allclose(chromaticities_matrix(chroma), published, atol=6e-6)


@pytest.mark.parametrize("chroma", [_AP0, _AP1, _REC2020])
def test_chromaticities_keep_white_white_and_primaries_map_to_their_colour(chroma):
    # relative colorimetric: the file's white is sRGB's white; the file's red, as XYZ under
    # the file's white adapted to D65, is what sRGB's matrix makes of the converted value
    from clholo.io.icc import _bradford, _rgb_to_xyz, _xyz, chromaticities_matrix

    m = chromaticities_matrix(chroma)
    np.testing.assert_allclose(m @ np.ones(3), np.ones(3), atol=1e-12)
    pts = np.reshape(chroma, (4, 2))
    file_xyz = _bradford(_xyz(*pts[3]), _xyz(0.3127, 0.3290)) @ _rgb_to_xyz(pts[:3], pts[3])
    srgb_xyz = _rgb_to_xyz(((0.64, 0.33), (0.30, 0.60), (0.15, 0.06)), (0.3127, 0.3290))
    for k in range(3):
        rgb = np.eye(3)[k]
        np.testing.assert_allclose(srgb_xyz @ (m @ rgb), file_xyz @ rgb, atol=1e-12)
    # Rec. 2020's green lies outside sRGB's gamut: a negative component, clipped by callers
    if chroma is _REC2020:
        assert (m @ np.array([0.0, 1.0, 0.0])).min() < -0.05


def test_rec709_chromaticities_mean_no_conversion():
    from clholo.io.icc import chromaticities_matrix

    assert chromaticities_matrix(_REC709) is None
    assert chromaticities_matrix(np.float32(_REC709)) is None  # as an EXR stores them
    assert chromaticities_matrix(np.add(_REC709, 3e-3)) is not None


@pytest.mark.parametrize("bad,said", [
    ((0.64, 0.33, 0.30, 0.60, 0.15, 0.06, 0.3127), "8 finite numbers"),
    ((0.64, 0.33, 0.30, 0.60, 0.15, 0.06, 0.3127, float("nan")), "8 finite numbers"),
    ((0.64, 0.33, 0.30, 0.60, 0.15, 0.06, 0.3127, 0.0), "white has y = 0"),
    ((0.1, 0.1, 0.2, 0.2, 0.3, 0.3, 0.3127, 0.3290), "span no colour space"),
    ((0.64, 0.33, 0.30, 0.60, 0.15, 0.06, 0.70, 0.25), "span no colour space"),
])
def test_chromaticities_that_are_no_colour_space_are_refused(bad, said):
    from clholo.io.icc import chromaticities_matrix

    with pytest.raises(ValueError, match=said):
        chromaticities_matrix(bad)


def _exr(path, px, chroma=None):
    from clholo.io import write_image

    write_image(path, px, dtype="float", attributes=None if chroma is None else {
        "chromaticities": tuple(float(v) for v in chroma)})


def test_an_acescg_exr_reads_as_linear_srgb(tmp_path, rng):
    px = (0.05 + 0.9 * rng.random((12, 16, 3))).astype(np.float32)
    _exr(tmp_path / "plain.exr", px)
    _exr(tmp_path / "rec709.exr", px, _REC709)
    _exr(tmp_path / "acescg.exr", px, _AP1)
    plain = read_rgb(tmp_path / "plain.exr")
    np.testing.assert_array_equal(plain, px)
    np.testing.assert_array_equal(read_rgb(tmp_path / "rec709.exr"), plain)
    got = read_rgb(tmp_path / "acescg.exr")
    want = np.clip(px.astype(np.float64) @ _AP1_TO_SRGB.T, 0.0, 1.0)
    assert np.abs(got - want).max() < 2e-5  # the published matrix's five decimals
    grey = np.full((2, 2, 3), 0.25, np.float32)  # white stays white
    _exr(tmp_path / "grey.exr", grey, _AP1)
    np.testing.assert_allclose(read_rgb(tmp_path / "grey.exr"), grey, atol=1e-6)


def test_an_rgbd_exr_in_aces_is_converted_as_a_scene(tmp_path, rng):
    from clholo.io import write_image

    px = (0.1 + 0.8 * rng.random((12, 16, 3))).astype(np.float32)
    z = (1.0 + rng.random((12, 16, 1))).astype(np.float32)
    write_image(tmp_path / "render.exr", np.concatenate([px, z], axis=2), dtype="float",
                channel_names=("R", "G", "B", "Z"),
                attributes={"chromaticities": tuple(float(v) for v in _AP0)})
    mpi = load_scene(tmp_path / "render.exr", layers=4, near=2e-3, far=6e-3)
    want = np.clip(px.astype(np.float64) @ _AP0_TO_SRGB.T, 0.0, 1.0)
    np.testing.assert_allclose(mpi.color[0], want, atol=2e-5)


def test_chromaticities_that_are_no_colour_space_are_named_and_ignored(tmp_path, rng):
    px = (0.1 + 0.8 * rng.random((6, 8, 3))).astype(np.float32)
    _exr(tmp_path / "odd.exr", px, (0.1, 0.1, 0.2, 0.2, 0.3, 0.3, 0.3127, 0.3290))
    with pytest.warns(ColourProfileWarning, match="odd.exr: its chromaticities are not a "
                                                   "colour space"):
        got = read_rgb(tmp_path / "odd.exr")
    np.testing.assert_array_equal(got, px)


def test_mpi_layers_in_acescg_are_named_once_for_the_folder(tmp_path, rng):
    for name, chroma in (("acescg", _AP1), ("rec709", _REC709), ("none", None)):
        folder = tmp_path / name
        folder.mkdir()
        for k in range(3):
            _exr(folder / f"layer_{k}.exr", rng.random((6, 8, 4)).astype(np.float32), chroma)
        said = _profile_warnings_of_folder(folder, [f"layer_{k}.exr" for k in range(3)],
                                           color_encoding="linear")
        if name == "acescg":
            assert len(said) == 1, said
            assert "3 layer file(s) of" in said[0] and "EXR chromaticities 0.713" in said[0]
        else:
            assert said == [], said
