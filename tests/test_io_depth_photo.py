"""Phone photos with their depth map inside (``clholo.io.depth_photo``): Google's Dynamic Depth
(Pixel PORTRAIT photos) and GDepth (Lens Blur), built here byte by byte from the two formats'
descriptions: XMP in APP1 segments, the extended XMP in chunks, Dynamic Depth's items appended
after the primary JPEG and found from the directory's lengths, the RangeInverse/RangeLinear
encodings, and the primary image's EXIF orientation applied to the map."""

import base64
import struct
import warnings

import numpy as np
import pytest

from clholo import cli
from clholo.io import detect_kind, load_scene, read_depth_photo, write_image
from clholo.io.depth_photo import DepthPhotoWarning, decode_depth_codes, find_embedded_depth
from clholo.io.images import _upright

NEAR_M, FAR_M = 0.4, 3.0  # the encoding's range, as a phone states it
H, W = 24, 32             # the photo as stored (before its EXIF orientation)


def _encode(z, encoding, near, far):
    """Google's depthmap encoding, forward (the reader implements its inverse):
    RangeLinear d_n = (d - near) / (far - near); RangeInverse
    d_n = far (d - near) / (d (far - near))."""
    if encoding == "RangeLinear":
        return (z - near) / (far - near)
    return far * (z - near) / (z * (far - near))


def _scene_depth(h, w):
    """Metres: a left-right ramp with a near block in the top-left corner (not symmetric
    under any turn, so a wrong orientation shows)."""
    x = np.linspace(0.0, 1.0, w)[None, :]
    z = np.repeat(NEAR_M + 1.1 + 1.4 * x, h, axis=0)  # 1.5 .. 2.9 m
    z[: h // 3, : w // 4] = NEAR_M + 0.05
    return z


def _segment(payload: bytes) -> bytes:
    assert len(payload) + 2 <= 0xFFFF
    return b"\xff\xe1" + struct.pack(">H", len(payload) + 2) + payload


def _with_app1(jpeg: bytes, payloads) -> bytes:
    assert jpeg[:2] == b"\xff\xd8"
    return jpeg[:2] + b"".join(_segment(p) for p in payloads) + jpeg[2:]


def _file_bytes(tmp_path, name, pixels, **kw) -> bytes:
    path = tmp_path / name
    write_image(path, pixels, **kw)
    data = path.read_bytes()
    path.unlink()
    return data


def _smooth_colour(rng):
    """A photo JPEG keeps to a few codes (random noise would lose its chroma)."""
    y, x = np.mgrid[0:H, 0:W]
    a, b, c = rng.uniform(0.2, 0.8, 3)
    return np.stack([0.1 + 0.8 * x / W, 0.1 + 0.8 * y / H,
                     0.5 + 0.3 * np.sin(a * x / 3 + b * y / 4 + c)], axis=-1)


def _primary(tmp_path, rng, orientation=1, colour=None):
    colour = _smooth_colour(rng) if colour is None else colour
    attrs = {"Orientation": orientation} if orientation != 1 else None
    return _file_bytes(tmp_path, "primary.jpg", colour, dtype="uint8", attributes=attrs), colour


def _depth_png(tmp_path, z, encoding="RangeInverse", near=NEAR_M, far=FAR_M, bits=16):
    d_n = _encode(z, encoding, near, far)
    return _file_bytes(tmp_path, "depth.png", d_n, dtype=f"uint{bits}", encoding="data")


XMP_OPEN = (b'<x:xmpmeta xmlns:x="adobe:ns:meta/"><rdf:RDF '
            b'xmlns:rdf="http://www.w3.org/1999/02/22-rdf-syntax-ns#">')
XMP_CLOSE = b"</rdf:RDF></x:xmpmeta>"
DD_NS = b" ".join(f'xmlns:{p}="http://ns.google.com/photos/dd/1.0/{p.lower()}/"'.encode()
                  for p in ("Device", "Container", "Item", "Camera", "DepthMap", "Image",
                            "Profile"))


def _depthmap_xml(props, form):
    if form == "attributes":
        attrs = " ".join(f'DepthMap:{k}="{v}"' for k, v in props.items())
        return f"<Camera:DepthMap {attrs}/>"
    body = "".join(f"<DepthMap:{k}>{v}</DepthMap:{k}>" for k, v in props.items())
    return f'<Camera:DepthMap rdf:parseType="Resource">{body}</Camera:DepthMap>'


def _dynamic_depth(primary: bytes, items, depth_props, *, form="attributes",
                   primary_length=0, padding_inside=True) -> bytes:
    """A Dynamic Depth JPEG: the XMP (directory, profile, one camera with its DepthMap) in
    the primary's APP1, then each item's bytes (its data and padding) appended in order.
    ``items``: (mime, data uri, payload, padding)."""
    entries = [f'<rdf:li rdf:parseType="Resource"><Container:Item Item:Mime="image/jpeg" '
               f'Item:Length="{primary_length}" Item:DataURI="primary_image"/></rdf:li>']
    for mime, uri, payload, padding in items:
        pad = f' Item:Padding="{padding}"' if padding else ""
        entries.append(f'<rdf:li rdf:parseType="Resource"><Container:Item Item:Mime="{mime}" '
                       f'Item:Length="{len(payload) + padding * padding_inside}"{pad} '
                       f'Item:DataURI="{uri}"/>'
                       f'</rdf:li>')
    xmp = (XMP_OPEN + b'<rdf:Description rdf:about="" ' + DD_NS + b">"
           + b"<Device:Container><Container:Directory><rdf:Seq>" + "".join(entries).encode()
           + b"</rdf:Seq></Container:Directory></Device:Container>"
           + b'<Device:Profiles><rdf:Seq><rdf:li rdf:parseType="Resource"><Device:Profile '
             b'Profile:Type="DepthPhoto" Profile:CameraIndices="0"/></rdf:li></rdf:Seq>'
             b"</Device:Profiles>"
           + b'<Device:Cameras><rdf:Seq><rdf:li rdf:parseType="Resource">'
             b'<Device:Camera rdf:parseType="Resource">'
           + b'<Camera:Image Image:ItemSemantic="Primary" Image:ItemURI="primary_image"/>'
           + _depthmap_xml(depth_props, form).encode()
           + b"</Device:Camera></rdf:li></rdf:Seq></Device:Cameras>"
           + b"</rdf:Description>" + XMP_CLOSE)
    out = _with_app1(primary, [b"http://ns.adobe.com/xap/1.0/\x00" + xmp])
    return out + b"".join(payload + b"\x00" * padding for _, _, payload, padding in items)


def _dd_props(**changes):
    props = {"ItemSemantic": "Depth", "Format": "RangeInverse", "Near": NEAR_M, "Far": FAR_M,
             "Units": "Meters", "MeasureType": "OpticalAxis", "DepthURI": "android/depthmap",
             "ConfidenceURI": "android/confidencemap"}
    props.update(changes)
    return {k: v for k, v in props.items() if v is not None}


def _dd_file(tmp_path, rng, *, orientation=1, shrink=1, form="attributes", padding=7,
             depth_last=False, padding_inside=True, **changes):
    primary, colour = _primary(tmp_path, rng, orientation)
    z = _scene_depth(H // shrink, W // shrink)
    depth = _depth_png(tmp_path, z)
    confidence = _file_bytes(tmp_path, "conf.png", rng.uniform(size=z.shape), dtype="uint8",
                             encoding="data")
    items = [("image/png", "android/depthmap", depth, padding),
             ("image/png", "android/confidencemap", confidence, padding + 4)]
    if depth_last:
        items = items[::-1]
    path = tmp_path / "PXL_PORTRAIT.jpg"
    path.write_bytes(_dynamic_depth(primary, items, _dd_props(**changes), form=form,
                                    padding_inside=padding_inside))
    return path, z, colour


@pytest.mark.parametrize("form", ["attributes", "elements"])
def test_dynamic_depth_map_decodes_to_metres(tmp_path, rng, form):
    path, z, colour = _dd_file(tmp_path, rng, form=form)
    image, depth, info = read_depth_photo(path)
    assert info["layout"] == "Dynamic Depth" and info["encoding"] == "RangeInverse"
    assert depth.shape == (H, W) and image.shape == (H, W, 3)
    # 16-bit codes of d_n, linear in 1/z: the step in z is z^2 (1/near - 1/far) / 65535
    step = z ** 2 * (1 / NEAR_M - 1 / FAR_M) / 65535
    assert np.max(np.abs(depth - z) / step) <= 0.51
    srgb = np.round(colour * 255) / 255
    linear = np.where(srgb <= 0.04045, srgb / 12.92, ((srgb + 0.055) / 1.055) ** 2.4)
    # the primary JPEG read as colour (its chroma is subsampled: a few codes of error)
    assert np.max(np.abs(image - linear)) < 0.1
    assert np.corrcoef(image.ravel(), linear.ravel())[0, 1] > 0.99


def test_depth_map_follows_the_photos_exif_orientation(tmp_path, rng):
    # a phone held upright stores the photo sideways (Orientation 6); its depth map is stored
    # as the photo's pixels are, and must turn with them
    path, z, _ = _dd_file(tmp_path, rng, orientation=6, shrink=2)
    image, depth, info = read_depth_photo(path)
    assert image.shape[:2] == (W, H) and info["primary_size"] == (W, H)
    expected = _upright(z[..., None], 6)[..., 0]
    assert depth.shape == expected.shape == (W // 2, H // 2)
    np.testing.assert_allclose(depth, expected, rtol=2e-3)
    # load_scene resizes the smaller map to the photo (it stands for the whole photo): the
    # near block lands in the upright photo's top-right corner, on the nearest plane
    mpi = load_scene(path, layers=4, near=0.002, far=0.004)
    assert mpi.shape[:2] == (W, H)
    full = _upright(np.repeat(np.repeat(z, 2, 0), 2, 1)[..., None], 6)[..., 0]
    near_block = full <= NEAR_M + 0.06
    assert np.array_equal(mpi.alpha[0] > 0, near_block)


@pytest.mark.parametrize("padding_inside", [True, False])
@pytest.mark.parametrize("depth_last", [False, True])
def test_items_around_the_depth_map_and_padding_are_skipped(tmp_path, rng, depth_last,
                                                            padding_inside):
    # the items (a depth and a confidence map, either first) carry padding, counted in their
    # Length or after it: the depth map's place comes from the lengths of the items after
    # the primary image
    path, z, _ = _dd_file(tmp_path, rng, padding=13, depth_last=depth_last,
                          padding_inside=padding_inside)
    _, depth, _ = read_depth_photo(path)
    np.testing.assert_allclose(depth, z, rtol=2e-3)
    found = find_embedded_depth(path)
    assert found.data.startswith(b"\x89PNG") and found.data.endswith(b"IEND\xaeB`\x82")


def test_items_named_by_their_semantic(tmp_path, rng):
    # a camera container whose items state their role (Item:Semantic) and no URI, with a
    # DepthMap that names none: the item whose Semantic is Depth holds the map
    primary, _ = _primary(tmp_path, rng)
    z = _scene_depth(H // 2, W // 2)
    png = _depth_png(tmp_path, z)
    props = " ".join(f'DepthMap:{k}="{v}"' for k, v in _dd_props(DepthURI=None).items())
    xmp = (XMP_OPEN + b'<rdf:Description rdf:about="" ' + DD_NS
           + b' xmlns:GC="http://ns.google.com/photos/1.0/container/" '
             b'xmlns:GI="http://ns.google.com/photos/1.0/container/item/">'
           + b'<GC:Directory><rdf:Seq>'
             b'<rdf:li rdf:parseType="Resource"><GC:Item GI:Semantic="Primary" '
             b'GI:Mime="image/jpeg"/></rdf:li>'
             b'<rdf:li rdf:parseType="Resource"><GC:Item GI:Semantic="Depth" '
           + f'GI:Mime="image/png" GI:Length="{len(png)}"/></rdf:li>'.encode()
           + b"</rdf:Seq></GC:Directory>"
           + f"<Device:Cameras><rdf:Seq><rdf:li><Device:Camera rdf:parseType=\"Resource\">"
             f"<Camera:DepthMap {props}/></Device:Camera></rdf:li></rdf:Seq>"
             f"</Device:Cameras>".encode()
           + b"</rdf:Description>" + XMP_CLOSE)
    path = tmp_path / "semantic.jpg"
    path.write_bytes(_with_app1(primary, [b"http://ns.adobe.com/xap/1.0/\x00" + xmp]) + png)
    _, depth, _ = read_depth_photo(path)
    np.testing.assert_allclose(depth, z, rtol=2e-3)


def test_one_photo_is_an_rgbd_scene_and_renders(tmp_path, rng, capsys):
    path, _, _ = _dd_file(tmp_path, rng, shrink=2)
    assert detect_kind(path) == "rgbd" and detect_kind([path]) == "rgbd"
    out = tmp_path / "o"
    rc = cli.main(["render", str(path), "--layers", "4", "--near", "0.002", "--far", "0.004",
                   "--frames", "1", "--out", str(out)])
    captured = capsys.readouterr()
    assert rc == 0, captured.err
    assert "Dynamic Depth, RangeInverse 0.4..3 Meters" in captured.out
    assert (out / "hologram.npz").exists()


def test_match_size_depth_renders_at_the_maps_size(tmp_path, rng):
    path, z, _ = _dd_file(tmp_path, rng, shrink=2)
    mpi = load_scene(path, layers=4, near=0.002, far=0.004, match_size="depth")
    assert mpi.shape[:2] == z.shape
    edges = load_scene(path, layers=4, near=0.002, far=0.004, match_size="edges")
    assert edges.shape[:2] == (H, W)
    with pytest.raises(ValueError, match="depth_kind='disparity'.*inside out"):
        load_scene(path, layers=4, near=0.002, far=0.004, depth_kind="disparity")


@pytest.mark.parametrize("units, scale", [("mm", 1e-3), ("Diopters", None)])
def test_units(tmp_path, rng, units, scale):
    near, far = (400.0, 3000.0) if scale else (0.4, 2.5)  # dioptres: 2.5 m .. 0.4 m
    path, z, _ = _dd_file(tmp_path, rng, Units=units, Near=near, Far=far)
    # the file's range in its units: write codes for the same scene in those units
    values = z / scale if scale else 1.0 / z
    values = np.clip(values, near, far)
    png = _depth_png(tmp_path, values, near=near, far=far)
    primary, _ = _primary(tmp_path, rng)
    items = [("image/png", "android/depthmap", png, 0)]
    path.write_bytes(_dynamic_depth(primary, items, _dd_props(Units=units, Near=near, Far=far)))
    _, depth, _ = read_depth_photo(path)
    expected = values * scale if scale else 1.0 / values
    np.testing.assert_allclose(depth, expected, rtol=2e-3)


def test_optic_ray_and_unknown_units_warn(tmp_path, rng):
    path, _, _ = _dd_file(tmp_path, rng, MeasureType="OpticRay")
    with pytest.warns(DepthPhotoWarning, match="OpticRay"):
        read_depth_photo(path)
    path, z, _ = _dd_file(tmp_path, rng, Units="furlongs")
    with pytest.warns(DepthPhotoWarning, match="furlongs"):
        _, depth, _ = read_depth_photo(path)
    np.testing.assert_allclose(depth, z, rtol=2e-3)


def _gdepth_file(tmp_path, rng, *, encoding="RangeLinear", chunk=700, drop_chunk=False,
                 shuffle=True, with_original=True):
    """A Lens Blur photo: the primary is the blurred picture (flat grey here), GImage:Data the
    original, GDepth:Data an 8-bit depth JPEG, both in the extended XMP over several
    APP1 chunks (shuffled: readers place them by offset)."""
    blurred = np.full((H, W, 3), 0.5)
    primary, _ = _primary(tmp_path, rng, colour=blurred)
    original = _smooth_colour(rng)
    original_jpeg = _file_bytes(tmp_path, "orig.jpg", original, dtype="uint8")
    z = _scene_depth(H, W)
    d_n = _encode(z, encoding, NEAR_M, FAR_M)
    depth_jpeg = _file_bytes(tmp_path, "d.jpg", d_n, dtype="uint8", encoding="data")
    guid = b"0123456789ABCDEF0123456789ABCDEF"
    image = (f'<rdf:Description rdf:about="" xmlns:GImage="http://ns.google.com/photos/1.0/'
             f'image/" GImage:Mime="image/jpeg" GImage:Data="'
             f'{base64.b64encode(original_jpeg).decode()}"/>') if with_original else ""
    extended = (XMP_OPEN + (f'<rdf:Description rdf:about="" xmlns:GDepth="http://ns.google.com/'
                            f'photos/1.0/depthmap/" GDepth:Data="'
                            f'{base64.b64encode(depth_jpeg).decode()}"/>' + image).encode()
                + XMP_CLOSE)
    main = (XMP_OPEN + b'<rdf:Description rdf:about="" '
            b'xmlns:GDepth="http://ns.google.com/photos/1.0/depthmap/" '
            b'xmlns:xmpNote="http://ns.adobe.com/xmp/note/" '
            + f'GDepth:Format="{encoding}" GDepth:Near="{NEAR_M}" GDepth:Far="{FAR_M}" '
              f'GDepth:Mime="image/jpeg" xmpNote:HasExtendedXMP="'.encode() + guid + b'"/>'
            + XMP_CLOSE)
    chunks = [b"http://ns.adobe.com/xmp/extension/\x00" + guid
              + struct.pack(">II", len(extended), offset) + extended[offset:offset + chunk]
              for offset in range(0, len(extended), chunk)]
    assert len(chunks) >= 2
    if drop_chunk:
        del chunks[1]
    if shuffle:
        chunks = chunks[::-1]
    path = tmp_path / "lens_blur.jpg"
    path.write_bytes(_with_app1(primary, [b"http://ns.adobe.com/xap/1.0/\x00" + main]
                                + chunks))
    return path, z, original


@pytest.mark.parametrize("encoding", ["RangeLinear", "RangeInverse"])
def test_gdepth_lens_blur_photo(tmp_path, rng, encoding):
    path, z, original = _gdepth_file(tmp_path, rng, encoding=encoding)
    image, depth, info = read_depth_photo(path)
    assert info["layout"] == "GDepth" and info["colour"].startswith("GImage")
    # 8-bit JPEG codes: a few codes of error in d_n
    d_n = _encode(z, encoding, NEAR_M, FAR_M)
    codes = _encode(depth, encoding, NEAR_M, FAR_M)
    assert np.max(np.abs(codes - d_n)) * 255 < 4
    # the colour is the original, not the blurred primary (flat grey)
    assert np.std(image) > 0.1
    assert np.corrcoef(image.ravel(), original.ravel())[0, 1] > 0.95


def test_gdepth_small_map_in_the_main_xmp(tmp_path, rng):
    # a map under 64 KB may sit in the main XMP itself (Google's example), attributes of one
    # rdf:Description, no extended XMP
    primary, _ = _primary(tmp_path, rng)
    z = _scene_depth(H, W)
    png = _depth_png(tmp_path, z, encoding="RangeLinear")
    xmp = (XMP_OPEN + b'<rdf:Description rdf:about="" '
           b'xmlns:GDepth="http://ns.google.com/photos/1.0/depthmap/" '
           + f'GDepth:Format="RangeLinear" GDepth:Near="{NEAR_M}" GDepth:Far="{FAR_M}" '
             f'GDepth:Mime="image/png" GDepth:Units="m" '
             f'GDepth:Data="{base64.encodebytes(png).decode()}"/>'.encode() + XMP_CLOSE)
    path = tmp_path / "small.jpg"
    path.write_bytes(_with_app1(primary, [b"http://ns.adobe.com/xap/1.0/\x00" + xmp]))
    _, depth, info = read_depth_photo(path)
    assert info["layout"] == "GDepth" and info["encoding"] == "RangeLinear"
    assert np.max(np.abs(depth - z)) <= (FAR_M - NEAR_M) / 65535


def test_gdepth_without_original_reads_the_primary(tmp_path, rng):
    path, _, _ = _gdepth_file(tmp_path, rng, with_original=False)
    image, _, info = read_depth_photo(path)
    assert info["colour"] == "primary image" and np.std(image) < 0.01


def test_decode_depth_codes_inverts_the_encodings():
    z = np.linspace(NEAR_M, FAR_M, 50)
    for encoding in ("RangeLinear", "RangeInverse"):
        d_n = _encode(z, encoding, NEAR_M, FAR_M)
        assert d_n[0] == pytest.approx(0) and d_n[-1] == pytest.approx(1)
        np.testing.assert_allclose(decode_depth_codes(d_n, encoding=encoding, near=NEAR_M,
                                                      far=FAR_M), z, rtol=1e-12)
    with pytest.raises(ValueError, match="encoding must be"):
        decode_depth_codes(z, encoding="Linear", near=NEAR_M, far=FAR_M)


# -- what a damaged or odd file says ---------------------------------------------------------

def test_extended_xmp_with_a_chunk_missing(tmp_path, rng):
    path, _, _ = _gdepth_file(tmp_path, rng, drop_chunk=True)
    with pytest.raises(ValueError, match="extended XMP.*incomplete"):
        read_depth_photo(path)
    with pytest.raises(ValueError, match="lens_blur.jpg"):
        load_scene(path, layers=4, near=0.002, far=0.004)


def test_file_cut_short_or_changed(tmp_path, rng):
    path, _, _ = _dd_file(tmp_path, rng)
    data = path.read_bytes()
    path.write_bytes(data[:-40])  # the tail cut: the items are not where the lengths say
    with pytest.raises(ValueError, match="not where its Dynamic Depth directory puts it"):
        read_depth_photo(path)
    path.write_bytes(data[:3000])
    with pytest.raises(ValueError, match="cut short|not where"):
        read_depth_photo(path)


@pytest.mark.parametrize("changes, message", [
    ({"Near": None}, "states no Near"),
    ({"Far": "far"}, "Far='far', not a number"),
    ({"Format": "RangeLog"}, "Format 'RangeLog'"),
    ({"Near": 0.0}, "0 < near < far"),
    ({"Near": 5.0}, "Near 5, Far 3"),
    ({"DepthURI": "android/elsewhere"}, "none of the items"),
])
def test_bad_metadata_names_what_is_wrong(tmp_path, rng, changes, message):
    path, _, _ = _dd_file(tmp_path, rng, **changes)
    with pytest.raises(ValueError, match=message) as exc:
        read_depth_photo(path)
    assert str(path) in str(exc.value)


def test_plain_jpeg_is_no_depth_photo(tmp_path, rng):
    primary, _ = _primary(tmp_path, rng)
    path = tmp_path / "plain.jpg"
    path.write_bytes(primary)
    assert find_embedded_depth(path) is None
    with pytest.raises(ValueError, match="Dynamic Depth, GDepth"):
        detect_kind(path)
    with pytest.raises(ValueError, match="carries no depth map"):
        read_depth_photo(path)
    png = tmp_path / "x.png"
    write_image(png, rng.uniform(size=(4, 4, 3)), dtype="uint8")
    assert find_embedded_depth(png) is None
    # an Ultra HDR photo: a camera container with a gain map, no depth map
    gain = _file_bytes(tmp_path, "gain.jpg", np.full((H // 4, W // 4), 0.5), dtype="uint8")
    xmp = (XMP_OPEN + b'<rdf:Description rdf:about="" '
           b'xmlns:Container="http://ns.google.com/photos/1.0/container/" '
           b'xmlns:Item="http://ns.google.com/photos/1.0/container/item/">'
           b'<Container:Directory><rdf:Seq>'
           b'<rdf:li rdf:parseType="Resource"><Container:Item Item:Semantic="Primary" '
           b'Item:Mime="image/jpeg"/></rdf:li>'
           b'<rdf:li rdf:parseType="Resource"><Container:Item Item:Semantic="GainMap" '
           + f'Item:Mime="image/jpeg" Item:Length="{len(gain)}"/></rdf:li>'.encode()
           + b"</rdf:Seq></Container:Directory></rdf:Description>" + XMP_CLOSE)
    hdr = tmp_path / "ultrahdr.jpg"
    hdr.write_bytes(_with_app1(primary, [b"http://ns.adobe.com/xap/1.0/\x00" + xmp]) + gain)
    assert find_embedded_depth(hdr) is None


def test_malformed_xmp_of_a_depth_photo_is_refused(tmp_path, rng):
    primary, _ = _primary(tmp_path, rng)
    xmp = (XMP_OPEN + b'<rdf:Description xmlns:GDepth="http://ns.google.com/photos/1.0/'
           b'depthmap/" GDepth:Format="RangeLinear"' + XMP_CLOSE)  # the tag is never closed
    path = tmp_path / "broken.jpg"
    path.write_bytes(_with_app1(primary, [b"http://ns.adobe.com/xap/1.0/\x00" + xmp]))
    with pytest.raises(ValueError, match="not well-formed XML"):
        find_embedded_depth(path)


def test_a_depth_map_turned_against_the_photo_is_refused(tmp_path, rng):
    primary, _ = _primary(tmp_path, rng)
    z = _scene_depth(W, H)  # the photo's shape transposed
    items = [("image/png", "android/depthmap", _depth_png(tmp_path, z), 0)]
    path = tmp_path / "turned.jpg"
    path.write_bytes(_dynamic_depth(primary, items, _dd_props()))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(ValueError, match="turned a quarter"):
            load_scene(path, layers=4, near=0.002, far=0.004)


# -- Apple: an iPhone's portrait JPEG, the depth map among the MPF images ---------------------

APDI = "http://ns.apple.com/pixeldatainfo/1.0/"
DEPTH_DATA = "http://ns.apple.com/depthData/1.0/"
DISPARITY_RANGE = (1.0 / 2.9, 1.0 / (NEAR_M + 0.05))  # 1/m, the farthest and nearest


def _fourcc(text):
    return str(int.from_bytes(text.encode(), "big"))


def _apple_xmp(props, form="elements", accuracy="relative"):
    """The XMP an iPhone writes into an auxiliary image's JPEG (Apple's pixel data info and
    depth data namespaces)."""
    extra = {"depthData:Accuracy": accuracy} if accuracy else {}
    fields = {**{f"apdi:{k}": v for k, v in props.items()}, **extra}
    head = (XMP_OPEN + f'<rdf:Description rdf:about="" xmlns:apdi="{APDI}" '
            f'xmlns:depthData="{DEPTH_DATA}"'.encode())
    if form == "attributes":
        attrs = " ".join(f'{k}="{v}"' for k, v in fields.items())
        return head + f" {attrs}/>".encode() + XMP_CLOSE
    body = "".join(f"<{k}>{v}</{k}>" for k, v in fields.items())
    return head + b">" + body.encode() + b"</rdf:Description>" + XMP_CLOSE


def _disparity_props(**changes):
    low, high = DISPARITY_RANGE
    props = {"IntMaxValue": 255, "StoredFormat": _fourcc("L008"),
             "NativeFormat": _fourcc("hdis"), "IntMinValue": 0,
             "FloatMaxValue": f"{high:.6f}", "FloatMinValue": f"{low:.6f}",
             "AuxiliaryImageType": "disparity"}
    props.update(changes)
    return {k: v for k, v in props.items() if v is not None}


def _aux_jpeg(tmp_path, codes, xmp):
    """A grey 8-bit JPEG holding ``codes`` with ``xmp`` in its APP1, and the codes it really
    stores (JPEG rounds)."""
    from clholo.io.images import read_image

    data = _file_bytes(tmp_path, "aux.jpg", codes / 255.0, dtype="uint8", encoding="data",
                       attributes={"CompressionQuality": 100})
    (tmp_path / "stored.jpg").write_bytes(data)
    stored, _ = read_image(tmp_path / "stored.jpg", normalise=False)
    return _with_app1(data, [b"http://ns.adobe.com/xap/1.0/\x00" + xmp]), stored[..., 0]


def _with_mpf(primary: bytes, images, order=">"):
    """The primary JPEG with an APP2 MPF index (CIPA DC-007) listing itself and ``images``,
    which are appended after it; offsets count from the MP header's byte-order mark."""
    after = 2
    while primary[after + 1] in range(0xE0, 0xF0):  # after the APPn segments already there
        after += 2 + struct.unpack(">H", primary[after + 2:after + 4])[0]
    count = 1 + len(images)
    ifd_entries = 3
    ifd_size = 2 + 12 * ifd_entries + 4
    entries_at = 8 + ifd_size
    header_len = entries_at + 16 * count
    segment_len = 2 + 4 + header_len
    first = len(primary) + 2 + segment_len
    base = after + 4 + 4  # marker, length, "MPF\0"
    tiff = (b"MM" if order == ">" else b"II") + struct.pack(order + "HI", 42, 8)
    tiff += struct.pack(order + "H", ifd_entries)
    tiff += struct.pack(order + "HHI", 0xB000, 7, 4) + b"0100"
    tiff += struct.pack(order + "HHII", 0xB001, 4, 1, count)
    tiff += struct.pack(order + "HHII", 0xB002, 7, 16 * count, entries_at)
    tiff += struct.pack(order + "I", 0)
    tiff += struct.pack(order + "IIIHH", 0x030000, first, 0, 0, 0)
    offset = first
    for image in images:
        tiff += struct.pack(order + "IIIHH", 0, len(image), offset - base, 0, 0)
        offset += len(image)
    assert len(tiff) == header_len
    segment = b"\xff\xe2" + struct.pack(">H", segment_len) + b"MPF\x00" + tiff
    out = primary[:after] + segment + primary[after:]
    assert len(out) == first
    return out + b"".join(images)


def _iphone_file(tmp_path, rng, *, orientation=1, matte_first=True, order=">",
                 form="elements", native="hdis", accuracy="relative", **changes):
    """An iPhone portrait JPEG: the photo, then (in its MPF index) the portrait matte and the
    disparity map (8-bit codes of 1/z, linear from FloatMinValue to FloatMaxValue), at half
    the photo's size; returns the path, the stored codes and the colour."""
    primary, colour = _primary(tmp_path, rng, orientation)
    z = _scene_depth(H // 2, W // 2)
    low, high = DISPARITY_RANGE
    if native.endswith("dis"):
        codes = np.round(255 * (1.0 / z - low) / (high - low))
    else:
        low, high = NEAR_M, 3.0
        codes = np.round(255 * (z - low) / (high - low))
        changes = {"FloatMinValue": low, "FloatMaxValue": high, **changes}
    props = _disparity_props(NativeFormat=native if not native.isalpha() or len(native) != 4
                             else _fourcc(native), **changes)
    disparity, stored = _aux_jpeg(tmp_path, np.clip(codes, 0, 255),
                                  _apple_xmp(props, form, accuracy))
    matte, _ = _aux_jpeg(tmp_path, rng.uniform(0, 255, z.shape), _apple_xmp(
        {"AuxiliaryImageSubType": "portraiteffectsmatte", "NativeFormat": _fourcc("L008"),
         "AuxiliaryImageType": "depth", "StoredFormat": _fourcc("L008")}, accuracy=None))
    images = [matte, disparity] if matte_first else [disparity, matte]
    path = tmp_path / "IMG_0001.jpg"
    path.write_bytes(_with_mpf(primary, images, order))
    return path, stored, colour


@pytest.mark.parametrize("order, form, matte_first", [(">", "elements", True),
                                                      ("<", "attributes", False)])
def test_apple_disparity_map_in_mpf_decodes_to_metres(tmp_path, rng, order, form, matte_first):
    path, stored, colour = _iphone_file(tmp_path, rng, order=order, form=form,
                                        matte_first=matte_first)
    found = find_embedded_depth(path)
    assert found.layout == "Apple MPF" and found.accuracy == "relative"
    image, depth, info = read_depth_photo(path)
    low, high = (float(f"{v:.6f}") for v in DISPARITY_RANGE)
    expected = 1.0 / (low + stored / 255.0 * (high - low))  # the largest code nearest
    assert depth.shape == (H // 2, W // 2) and image.shape == (H, W, 3)
    np.testing.assert_allclose(depth, expected, rtol=1e-6)
    # and the scene: 8-bit disparity codes, 1/z to within half a code (and JPEG's rounding)
    z = _scene_depth(H // 2, W // 2)
    assert np.max(np.abs(1.0 / depth - 1.0 / z)) < 2.5 * (high - low) / 255
    assert info["layout"] == "Apple MPF" and info["accuracy"] == "relative"
    assert info["describe"] == f"Apple MPF, disparity {low:g}..{high:g} 1/m (relative)"
    assert info["near"] == pytest.approx(1.0 / high) and info["far"] == pytest.approx(1.0 / low)


def test_apple_depth_map_and_orientation(tmp_path, rng):
    # a map of depth (fdep, metres, the largest code farthest), the photo stored sideways
    path, stored, _ = _iphone_file(tmp_path, rng, orientation=6, native="fdep",
                                   accuracy=None)
    image, depth, info = read_depth_photo(path)
    assert image.shape[:2] == (W, H) and info["accuracy"] == ""
    expected = _upright((NEAR_M + stored / 255.0 * (3.0 - NEAR_M))[..., None], 6)[..., 0]
    np.testing.assert_allclose(depth, expected, rtol=1e-6)
    assert info["describe"] == f"Apple MPF, depth {NEAR_M:g}..3 m"
    # the four characters themselves are read too
    path, stored2, _ = _iphone_file(tmp_path, rng, native="fdis")
    assert find_embedded_depth(path).encoding == "RangeInverse"


def test_iphone_photo_renders(tmp_path, rng, capsys):
    path, _, _ = _iphone_file(tmp_path, rng)
    assert detect_kind(path) == "rgbd"
    out = tmp_path / "o"
    rc = cli.main(["render", str(path), "--layers", "4", "--near", "0.002", "--far", "0.004",
                   "--frames", "1", "--depth-spacing", "disparity", "--out", str(out)])
    captured = capsys.readouterr()
    assert rc == 0, captured.err
    assert "Apple MPF, disparity" in captured.out
    assert (out / "hologram.npz").exists()
    # the nearest plane holds the near block (the largest disparity codes)
    mpi = load_scene(path, layers=4, near=0.002, far=0.004)
    z = np.repeat(np.repeat(_scene_depth(H // 2, W // 2), 2, 0), 2, 1)
    assert np.array_equal(mpi.alpha[0] > 0, z <= NEAR_M + 0.06)


def test_mpf_without_depth_is_no_depth_photo(tmp_path, rng):
    # a matte alone, and a camera's MPF preview without any XMP: no depth map
    primary, _ = _primary(tmp_path, rng)
    matte, _ = _aux_jpeg(tmp_path, rng.uniform(0, 255, (H // 2, W // 2)), _apple_xmp(
        {"AuxiliaryImageSubType": "portraiteffectsmatte", "NativeFormat": _fourcc("hdis"),
         "AuxiliaryImageType": "depth"}, accuracy=None))
    preview = _file_bytes(tmp_path, "preview.jpg", rng.uniform(size=(8, 8, 3)), dtype="uint8")
    path = tmp_path / "mpf.jpg"
    path.write_bytes(_with_mpf(primary, [matte, preview]))
    assert find_embedded_depth(path) is None
    with pytest.raises(ValueError, match="an iPhone's JPEG"):
        detect_kind(path)


@pytest.mark.parametrize("changes, message", [
    ({"FloatMinValue": 0.0}, "disparities from 0 1/m"),
    ({"FloatMaxValue": None}, "states no FloatMaxValue"),
    ({"IntMaxValue": 0}, "maps codes 0..0"),
    ({"FloatMinValue": 3.0}, "to 3..2.2.*: no range"),
    ({"IntMaxValue": 1023}, "codes up to 1023"),
])
def test_apple_bad_metadata_names_what_is_wrong(tmp_path, rng, changes, message):
    path, _, _ = _iphone_file(tmp_path, rng, **changes)
    with pytest.raises(ValueError, match=message) as exc:
        read_depth_photo(path)
    assert str(path) in str(exc.value) and "MPF" in str(exc.value)


def test_iphone_photo_cut_short(tmp_path, rng):
    path, _, _ = _iphone_file(tmp_path, rng, matte_first=False)
    data = path.read_bytes()
    path.write_bytes(data[:-10])
    with pytest.raises(ValueError, match="MPF index places image 3 at bytes .* cut short"):
        find_embedded_depth(path)
