"""User mistakes in scene files (clholo.io, clholo.scenes): each is refused with a message that
names the file (and line, key or camera) and the fix; the command line ends with exit 2 (3 for
what this machine cannot hold), never with a traceback or an internal error, and nothing passes
silently."""

import json
import warnings

import numpy as np
import pytest

from clholo import cli
from clholo.io import (Camera, camera_from_json, read_depth, read_mpi, read_ply,
                       read_stereo_mag, rgbd_to_mpi, splats_to_mpi, write_image, write_mpi)
from clholo.io.splats import subsample_visible
from clholo.scene import MPI

PROPS = ["x", "y", "z", "f_dc_0", "f_dc_1", "f_dc_2", "opacity", "scale_0", "scale_1",
         "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]
DEEP = "[" * 100000 + "]" * 100000  # valid JSON to the letter, nested beyond Python's reader


def _table(n=6, z=4.0):
    """n small splats on a line in front of the origin (camera at the origin sees them)."""
    t = np.zeros((n, len(PROPS)), np.float32)
    t[:, 0] = np.linspace(-0.5, 0.5, n)
    t[:, 2] = z
    t[:, 6] = 2.0                  # opacity logit
    t[:, 7:10] = np.log(0.05)      # scales
    t[:, 10] = 1.0                 # quaternion w
    return t


def _ply(path, table=None, *, header=None, extra=b""):
    """A binary 3DGS PLY; ``header`` replaces the lines between 'ply' and 'end_header'."""
    table = _table() if table is None else table
    lines = header if header is not None else (
        ["format binary_little_endian 1.0", f"element vertex {len(table)}"]
        + [f"property float {p}" for p in PROPS])
    text = "\n".join(["ply"] + lines + ["end_header"]) + "\n"
    path.write_bytes(text.encode() + np.asarray(table, "<f4").tobytes() + extra)
    return path


def _cameras(path, **changes):
    entry = {"id": 0, "img_name": "00000", "width": 32, "height": 24, "fx": 30.0, "fy": 30.0,
             "position": [0.0, 0.0, 0.0], "rotation": [[1, 0, 0], [0, 1, 0], [0, 0, 1]]}
    entry.update(changes)
    path.write_text(json.dumps([entry]))
    return path


def _render(args, capsys):
    rc = cli.main(["render", *map(str, args), "--progress", "off"])
    err = capsys.readouterr().err
    assert "Traceback" not in err and "internal error" not in err, err
    return rc, err


# --- 1. a camera too large for any field or for the device ------------------------------------

def test_a_huge_camera_is_refused_up_front_naming_its_file_and_size(tmp_path, capsys):
    ply = _ply(tmp_path / "s.ply")
    cams = _cameras(tmp_path / "cam_huge.json", width=100000, height=100000)
    rc, err = _render([ply, "--camera-json", cams, "--near", "0.002", "--far", "0.006",
                       "--out", tmp_path / "o"], capsys)
    assert rc == 2 and not (tmp_path / "o").exists()
    assert "cam_huge.json: camera 0 is 100000x100000 pixels" in err
    assert "8192 pixels per axis" in err and "--scale" in err


def test_slabs_beyond_the_device_are_a_memory_error_naming_the_camera(tmp_path, queue):
    g = read_ply(_ply(tmp_path / "s.ply"))
    cam = Camera(8192, 8192, 8000.0, 8000.0, source="cams.json: camera 2")
    with pytest.raises(MemoryError, match=r"cams\.json: camera 2 is 8192x8192 pixels: 256 "
                                          r"slabs of it need"):
        splats_to_mpi(g, layers=256, camera=cam, queue=queue)


# --- 2. malformed PLY headers -----------------------------------------------------------------

PLY_FORMAT = "format binary_little_endian 1.0"
PLY_PROPS = [f"property float {p}" for p in PROPS]


@pytest.mark.parametrize("lines, expect", [
    ([PLY_FORMAT, "element vertex 6", "property float"] + PLY_PROPS,
     r"line 4: 'property float' is malformed: expected 'property TYPE NAME'"),
    ([PLY_FORMAT, "element vertex abc"] + PLY_PROPS,
     r"line 3: 'element vertex abc': the count 'abc' is not a whole number >= 1"),
    ([PLY_FORMAT, "element vertex -1"] + PLY_PROPS,
     r"line 3: 'element vertex -1': the count '-1' is not a whole number >= 1"),
    ([PLY_FORMAT, "element vertex 2.5"] + PLY_PROPS, r"line 3: .*not a whole number"),
    ([PLY_FORMAT, "element vertex"] + PLY_PROPS,
     r"line 3: 'element vertex' is malformed: expected 'element NAME COUNT'"),
    ([PLY_FORMAT, "element vertex 6", "proprety float nx"] + PLY_PROPS,
     r"line 4: 'proprety float nx' is not a PLY header line"),
    ([PLY_FORMAT, "element vertex 6", "property floaty nx"] + PLY_PROPS,
     r"line 4: unknown PLY property type 'floaty'"),
    # fewer splats in the header than in the data: the reader took the first ones silently
    ([PLY_FORMAT, "element vertex 4"] + PLY_PROPS,
     r"holds 336 bytes of vertex data but its 'element vertex 4' promises 4 splats"),
])
def test_a_malformed_ply_header_names_the_file_and_line(tmp_path, lines, expect):
    path = _ply(tmp_path / "bad.ply", header=lines)
    with pytest.raises(ValueError, match=r"bad\.ply.*" + expect):
        read_ply(path)


def test_an_ascii_ply_with_more_values_than_its_count_is_refused(tmp_path):
    lines = ["ply", "format ascii 1.0", "element vertex 1"] + PLY_PROPS + ["end_header"]
    rows = "\n".join(" ".join(str(float(v)) for v in row) for row in _table(2))
    (tmp_path / "a.ply").write_text("\n".join(lines) + "\n" + rows + "\n")
    with pytest.raises(ValueError, match=r"a\.ply holds 28 values .* promises 1 splats"):
        read_ply(tmp_path / "a.ply")


def test_a_negative_splat_count_fails_the_command(tmp_path, capsys):
    path = _ply(tmp_path / "neg.ply", header=[PLY_FORMAT, "element vertex -1"] + PLY_PROPS)
    rc, err = _render([path, "--near", "0.002", "--far", "0.006", "--out", tmp_path / "o"],
                      capsys)
    assert rc == 2 and "neg.ply: line 3:" in err and not (tmp_path / "o").exists()


def test_a_ply_with_faces_after_the_splats_still_reads(tmp_path):
    lines = [PLY_FORMAT, "element vertex 6"] + PLY_PROPS + [
        "element face 1", "property list uchar int vertex_indices"]
    face = bytes([3]) + np.array([0, 1, 2], "<i4").tobytes()
    assert len(read_ply(_ply(tmp_path / "f.ply", header=lines, extra=face))) == 6


# --- 3. mpi.json: deep nesting, unknown keys ----------------------------------------------------

def _mpi_folder(path, rng, **changes):
    mpi = MPI(rng.uniform(size=(2, 4, 6, 3)), rng.uniform(size=(2, 4, 6)), [0.002, 0.004])
    write_mpi(path, mpi)
    meta = json.loads((path / "mpi.json").read_text())
    meta.update(changes)
    (path / "mpi.json").write_text(json.dumps(meta))
    return path


def test_json_nested_too_deeply_is_not_valid_json_naming_the_file(tmp_path, rng, capsys):
    from clholo.io.load import scene_depth_units
    from clholo.io.output import is_clholo_output, why_not_clholo_output

    folder = _mpi_folder(tmp_path / "m", rng)
    (folder / "mpi.json").write_text(DEEP)
    with pytest.raises(ValueError, match=r"m/mpi\.json is not valid JSON: .*nested too deeply"):
        read_mpi(folder)
    assert scene_depth_units(folder) == "scene units"  # read_mpi says what is wrong
    rc, err = _render([folder, "--out", tmp_path / "o"], capsys)
    assert rc == 2 and "mpi.json is not valid JSON" in err
    (tmp_path / "c.json").write_text(DEEP)
    with pytest.raises(ValueError, match=r"c\.json is not valid JSON"):
        camera_from_json(tmp_path / "c.json")
    (tmp_path / "out").mkdir()
    (tmp_path / "out" / "clholo-output.json").write_text(DEEP)
    assert not is_clholo_output(tmp_path / "out")
    assert "not valid JSON" in why_not_clholo_output(tmp_path / "out")


def test_a_hologram_npz_with_deeply_nested_metadata_is_refused(tmp_path):
    from clholo.io import read_hologram

    np.savez(tmp_path / "h.npz", field=np.zeros((1, 1, 2, 2), np.complex64),
             metadata=np.array(DEEP))
    with pytest.raises(ValueError, match=r"h\.npz.*not valid JSON"):
        read_hologram(tmp_path / "h.npz")


def test_an_unknown_or_misspelt_mpi_json_key_is_refused(tmp_path, rng, capsys):
    folder = _mpi_folder(tmp_path / "m", rng, depht_units="metres")
    with pytest.raises(ValueError, match=r"m/mpi\.json: unknown key 'depht_units'; did you "
                                         r"mean 'depth_units'\?.*farthest_alpha"):
        read_mpi(folder)
    rc, err = _render([folder, "--frames", "1", "--out", tmp_path / "o"], capsys)
    assert rc == 2 and "unknown key 'depht_units'" in err and "mpi.json" in err
    # clholo's own format holds only its keys
    _mpi_folder(tmp_path / "m2", rng, notes="mine")
    with pytest.raises(ValueError, match=r"m2/mpi\.json: unknown key 'notes'; the keys"):
        read_mpi(tmp_path / "m2")


def test_a_file_without_format_keeps_its_descriptive_keys_but_not_misspellings(tmp_path, rng):
    folder = _mpi_folder(tmp_path / "m", rng)
    meta = json.loads((folder / "mpi.json").read_text())
    del meta["format"], meta["version"]
    # what the shipped twain mpi.json carries besides the keys clholo reads
    meta.update(source="Stereo Magnification", intrinsics={"fx_pixels": 1.0}, xoffset=0.1,
                renders={}, render_pose=[], size_wh=[6, 4], color="srgb")
    (folder / "mpi.json").write_text(json.dumps(meta))
    assert read_mpi(folder).layers == 2
    meta["colour_encoding"] = "linear"
    (folder / "mpi.json").write_text(json.dumps(meta))
    with pytest.raises(ValueError, match=r"unknown key 'colour_encoding'; did you mean "
                                         r"'color_encoding'"):
        read_mpi(folder)


def test_the_shipped_twain_mpi_json_has_no_key_refused(shared_data):
    from clholo.io.mpi_folder import _check_keys

    path = shared_data / "twain-mpi" / "mpi.json"
    _check_keys(json.loads(path.read_text()), path)  # (reading all 32 layers is slow)


# --- 4. cameras.json values, culled-splat counts, NaN depth -------------------------------------

@pytest.mark.parametrize("change, expect", [
    ({"fx": "30"}, r"'fx' must be a finite number, got \"30\" \(str\); "
                   r"write it unquoted: 30"),
    ({"width": "32"}, r"'width' must be a whole number of pixels, got \"32\""),
    ({"height": 24.5}, r"'height' must be a whole number of pixels, got 24.5"),
    ({"fy": True}, r"'fy' must be a finite number, got true \(bool\)"),
    ({"position": [0, 0, float("nan")]}, r"'position' holds NaN or infinity \(\[0, 0, NaN\]\)"),
    ({"position": [0, "0", 0]}, r"'position' must be 3 numbers"),
    ({"rotation": [[1, 0, 0], [0, 1, 0], [0, 0, float("inf")]]},
     r"'rotation' holds NaN or infinity"),
    ({"fx": float("inf")}, r"'fx' must be a finite number, got inf"),
])
def test_a_cameras_json_value_that_is_not_a_number_names_key_and_camera(tmp_path, change,
                                                                         expect):
    path = _cameras(tmp_path / "cams.json", **change)
    with pytest.raises(ValueError, match=r"cams\.json: camera 0 \(00000\): " + expect):
        camera_from_json(path)


def test_a_nan_camera_position_is_named_not_blamed_on_znear(tmp_path, capsys):
    ply = _ply(tmp_path / "s.ply")
    cams = _cameras(tmp_path / "cam_nan.json", position=[0, 0, float("nan")])
    rc, err = _render([ply, "--camera-json", cams, "--near", "0.002", "--far", "0.006",
                       "--out", tmp_path / "o"], capsys)
    assert rc == 2 and "cam_nan.json: camera 0 (00000): 'position' holds NaN" in err
    assert "znear" not in err
    with pytest.raises(ValueError, match="translation holds NaN"):
        Camera(8, 8, 10.0, 10.0, translation=[0, 0, float("nan")])


def test_when_no_splat_is_left_the_error_counts_the_file_and_no_warning_repeats_it(tmp_path,
                                                                                   capsys):
    g = read_ply(_ply(tmp_path / "s.ply"))
    behind = Camera(32, 24, 30.0, 30.0, translation=[0, 0, -10.0])  # the splats are at z = 4
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a SplatCullWarning would fail here
        with pytest.raises(ValueError, match=r"\(6 of 6 behind or nearer than znear=1 \(6 "
                                             r"behind the camera\), 0 off the image\)"):
            subsample_visible(g, behind, None)
        with pytest.raises(ValueError, match=r"\(6 of 6 behind"):
            splats_to_mpi(g, layers=2, camera=behind, backend="numpy")
    cams = _cameras(tmp_path / "c.json", position=[0, 0, 10.0])
    rc, err = _render([tmp_path / "s.ply", "--camera-json", cams, "--near", "0.002", "--far",
                       "0.006", "--out", tmp_path / "o"], capsys)
    assert rc == 2 and "6 of 6 behind" in err and "0 of 0" not in err
    assert "SplatCullWarning" not in err


def test_some_splats_culled_still_warn_once_with_the_counts(tmp_path):
    from clholo.io import SplatCullWarning

    table = _table()
    table[:2, 2] = -1.0  # two behind the camera
    g = read_ply(_ply(tmp_path / "s.ply", table))
    with pytest.warns(SplatCullWarning, match=r"2 of 6 splats .* 2 behind the camera") as rec:
        kept, _ = subsample_visible(g, Camera(32, 24, 30.0, 30.0), None)
    assert len(kept) == 4 and len(rec) == 1


def test_an_all_nan_depth_map_is_refused_without_numpy_warnings():
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # "All-NaN slice encountered" would fail here
        with pytest.raises(ValueError, match=r"depth has no valid pixel.*\(all NaN\)"):
            rgbd_to_mpi(np.zeros((4, 5, 3)), np.full((4, 5), np.nan), layers=2, near=0.002,
                        far=0.004)


# --- 5. complex input ------------------------------------------------------------------------

def test_a_complex_depth_npy_is_refused_naming_the_file(tmp_path, capsys, rng):
    np.save(tmp_path / "d_c.npy", rng.uniform(1, 2, (6, 8)) + 1j)
    write_image(tmp_path / "im.png", rng.uniform(size=(6, 8, 3)), dtype="uint8")
    with pytest.raises(ValueError, match=r"d_c\.npy holds complex numbers \(complex128\)"):
        read_depth(tmp_path / "d_c.npy")
    rc, err = _render([tmp_path / "im.png", tmp_path / "d_c.npy", "--near", "0.002", "--far",
                       "0.006", "--out", tmp_path / "o"], capsys)
    assert rc == 2 and "d_c.npy holds complex numbers" in err and "ComplexWarning" not in err
    assert not (tmp_path / "o").exists()


def test_complex_arrays_are_refused_by_rgbd_to_mpi(rng):
    depth = rng.uniform(1, 2, (4, 5))
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # NumPy's ComplexWarning would fail here
        with pytest.raises(ValueError, match="depth holds complex numbers"):
            rgbd_to_mpi(np.zeros((4, 5, 3)), depth + 0j, layers=2, near=0.002, far=0.004)
        with pytest.raises(ValueError, match="image holds complex numbers"):
            rgbd_to_mpi(np.zeros((4, 5, 3), complex), depth, layers=2, near=0.002, far=0.004)


# --- 6. multi-channel maps -------------------------------------------------------------------

def test_a_colour_depth_map_is_refused_and_a_grey_one_saved_as_rgb_is_read(tmp_path, rng,
                                                                          capsys):
    grey = rng.uniform(0.1, 1, (6, 8))
    write_image(tmp_path / "grey.png", grey, dtype="uint16")
    write_image(tmp_path / "grey_rgb.png", np.repeat(grey[..., None], 3, 2), dtype="uint16")
    write_image(tmp_path / "grey_rgba.png", np.dstack([grey, grey, grey, np.ones_like(grey)]),
                dtype="uint16")
    np.testing.assert_array_equal(read_depth(tmp_path / "grey_rgb.png"),
                                  read_depth(tmp_path / "grey.png"))
    np.testing.assert_array_equal(read_depth(tmp_path / "grey_rgba.png"),
                                  read_depth(tmp_path / "grey.png"))
    write_image(tmp_path / "depth_rgb.png", rng.uniform(size=(6, 8, 3)), dtype="uint8")
    with pytest.raises(ValueError, match=r"depth_rgb\.png has 3 channels that differ .*a grey "
                                         r"depth map is expected"):
        read_depth(tmp_path / "depth_rgb.png")
    write_image(tmp_path / "im.png", rng.uniform(size=(6, 8, 3)), dtype="uint8")
    rc, err = _render([tmp_path / "im.png", tmp_path / "depth_rgb.png", "--near", "0.002",
                       "--far", "0.006", "--out", tmp_path / "o"], capsys)
    assert rc == 2 and "depth_rgb.png has 3 channels that differ" in err


def test_an_rgb_pfm_depth_map_with_differing_channels_is_refused(tmp_path, rng):
    data = rng.uniform(1, 2, (4, 5, 3)).astype("<f4")
    (tmp_path / "d.pfm").write_bytes(b"PF\n5 4\n-1.0\n" + data[::-1].tobytes())
    with pytest.raises(ValueError, match=r"d\.pfm has 3 channels that differ"):
        read_depth(tmp_path / "d.pfm")
    same = np.repeat(data[..., :1], 3, 2)
    (tmp_path / "s.pfm").write_bytes(b"PF\n5 4\n-1.0\n" + same[::-1].tobytes())
    np.testing.assert_array_equal(read_depth(tmp_path / "s.pfm"), data[..., 0])


def _stereo_mag(folder, rng, alpha_rgb):
    folder.mkdir()
    for i in range(2):
        write_image(folder / f"mpi_rgb_{i:02d}.png", rng.uniform(size=(4, 6, 3)), dtype="uint8")
        write_image(folder / f"mpi_alpha_{i:02d}.png", alpha_rgb(rng.uniform(size=(4, 6))),
                    dtype="uint8")
    return folder


def test_stereo_mag_alpha_saved_as_rgb_is_read_when_grey_and_refused_when_not(tmp_path, rng):
    grey = _stereo_mag(tmp_path / "grey", rng, lambda a: np.repeat(a[..., None], 3, 2))
    assert read_stereo_mag(grey).layers == 2
    colour = _stereo_mag(tmp_path / "colour", rng, lambda a: np.dstack([a, 1 - a, a * 0]))
    with pytest.raises(ValueError, match=r"colour/mpi_alpha_00\.png has 3 channels that "
                                         r"differ .*a grey alpha map is expected"):
        read_stereo_mag(colour)


def test_an_mpi_alpha_file_saved_as_grey_rgb_is_read(tmp_path, rng):
    folder = tmp_path / "m"
    folder.mkdir()
    a = rng.uniform(size=(4, 6))
    write_image(folder / "c.png", rng.uniform(size=(4, 6, 3)), dtype="uint8")
    write_image(folder / "a.png", np.repeat(a[..., None], 3, 2), dtype="uint8")
    write_image(folder / "b.png", np.dstack([a, 1 - a, a]), dtype="uint8")
    meta = {"layers": [{"color": "c.png", "alpha": "a.png"}], "depths": [1.0],
            "farthest_alpha": "stored"}
    (folder / "mpi.json").write_text(json.dumps(meta))
    np.testing.assert_allclose(read_mpi(folder, near=0.002, far=0.004).alpha[0],
                               np.round(a * 255) / 255, atol=1e-6)
    meta["layers"] = [{"color": "c.png", "alpha": "b.png"}]
    (folder / "mpi.json").write_text(json.dumps(meta))
    with pytest.raises(ValueError, match=r"alpha file .*b\.png has 3 channels that differ"):
        read_mpi(folder)



def test_a_three_channel_depth_npy_is_read_only_when_grey(tmp_path, rng):
    grey = rng.uniform(1, 2, (4, 5))
    np.save(tmp_path / "g.npy", np.repeat(grey[..., None], 3, 2))
    np.testing.assert_allclose(read_depth(tmp_path / "g.npy"), grey.astype(np.float32))
    np.save(tmp_path / "c.npy", rng.uniform(1, 2, (4, 5, 3)))
    with pytest.raises(ValueError, match=r"c\.npy has 3 channels that differ"):
        read_depth(tmp_path / "c.npy")
