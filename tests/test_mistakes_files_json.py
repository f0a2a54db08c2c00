"""Scene, camera, manifest and bench files found wrong by an audit of hostile input files
(2026-11-29): each ended as an internal error (exit 70), a message from deep inside Python that
named neither the file nor the fix, a silent acceptance, or a refusal of a scene that was right.
Each is now one line naming the file (and key, line or layer) and the fix, or it works.

The biggest: scene-unit depths above 1000 (a scene in millimetres, a large outdoor one) were
refused as "beyond 1000 m ... give metres" even when near/far placed them in metres."""

import json
import os

import numpy as np
import pytest

from clholo import cli
from clholo.errors import InputError
from clholo.io import (camera_from_json, load_scene, read_mpi, read_ply, read_stereo_mag,
                       splats_to_mpi, write_image, write_mpi)
from clholo.scene import MPI

PROPS = ["x", "y", "z", "f_dc_0", "f_dc_1", "f_dc_2", "opacity", "scale_0", "scale_1",
         "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]
DEEP = "[" * 100000 + "]" * 100000  # valid JSON to the letter, nested beyond Python's reader
HUGE = "9" * 5000                   # beyond Python's 4300 digits for int("...")
BENCH = "[slm]\nresolution = [12, 8]\nwavelengths_m = [520e-9]\n"


def _render(args, capsys):
    rc = cli.main(["render", *map(str, args), "--progress", "off"])
    err = capsys.readouterr().err
    assert "Traceback" not in err and "internal error" not in err, err
    return rc, err


def _mpi_folder(path, rng, *, layers=3, **meta_changes):
    """A small MPI folder (PNG layers, metres) whose mpi.json gets ``meta_changes`` (a value
    None deletes the key)."""
    mpi = MPI(rng.uniform(0.1, 1, (layers, 16, 16, 3)), rng.uniform(0.1, 1, (layers, 16, 16)),
              0.002 + 0.001 * np.arange(layers))
    write_mpi(path, mpi, format="png8")
    meta = json.loads((path / "mpi.json").read_text())
    for key, value in meta_changes.items():
        if value is None:
            meta.pop(key, None)
        else:
            meta[key] = value
    (path / "mpi.json").write_text(json.dumps(meta))
    return path


def _set_json_text(path, old, new):
    path.write_text(path.read_text().replace(old, new))


def _table(n=6, z=4.0):
    """n small splats on a line in front of the origin (the default camera sees them)."""
    t = np.zeros((n, len(PROPS)), np.float32)
    t[:, 0] = np.linspace(-0.5, 0.5, n)
    t[:, 2] = z + np.linspace(0.0, 1.0, n)
    t[:, 6] = 2.0                  # opacity logit
    t[:, 7:10] = np.log(0.05)      # scales
    t[:, 10] = 1.0                 # quaternion w
    return t


def _ply(path, table=None, *, props=PROPS):
    table = _table() if table is None else table
    text = "\n".join(["ply", "format binary_little_endian 1.0", f"element vertex {len(table)}"]
                     + [f"property float {p}" for p in props] + ["end_header"]) + "\n"
    path.write_bytes(text.encode() + np.asarray(table, "<f4").tobytes())
    return path


def _cameras(path, raw_entry=None, **changes):
    """A cameras.json of one camera; ``raw_entry`` is the entry's JSON text as given (for
    numbers json.dumps cannot write)."""
    entry = {"id": 0, "img_name": "00000", "width": 32, "height": 24, "fx": 30.0, "fy": 30.0,
             "position": [0.0, 0.0, 0.0], "rotation": [[1, 0, 0], [0, 1, 0], [0, 0, 1]]}
    entry.update(changes)
    path.write_text("[" + (raw_entry if raw_entry is not None else json.dumps(entry)) + "]")
    return path


def _stereo_mag(path, rng, layers=3):
    path.mkdir()
    for i in range(layers):
        write_image(path / f"mpi_rgb_{i:02d}.png", rng.uniform(0, 1, (16, 16, 3)), dtype="uint8")
        write_image(path / f"mpi_alpha_{i:02d}.png", rng.uniform(0, 1, (16, 16, 1)),
                    dtype="uint8")
    return path


# --- 4. scene-unit depths of any size are placed by near/far ----------------------------------

@pytest.mark.parametrize("spacing", ["index", "depth", "inverse"])
def test_mpi_folder_scene_units_above_1000_load_when_near_far_place_them(tmp_path, rng,
                                                                         spacing):
    """An mpi.json in scene units with depths 500..5000 (a scene in millimetres) was refused
    as "depths reaches 5000 m, beyond 1000 m ... give metres" with or without near/far: the
    MPI was made in scene units before near/far placed it. Now it is placed as it is read, to
    the same depths as the same scene in smaller units."""
    big = _mpi_folder(tmp_path / "big", rng, depth_units=None, depths=[500, 2000, 5000])
    small = _mpi_folder(tmp_path / "small", rng, depth_units=None, depths=[0.5, 2.0, 5.0])
    for read in (lambda p: load_scene(p, near=0.002, far=0.004, spacing=spacing),
                 lambda p: read_mpi(p, near=0.002, far=0.004, spacing=spacing)):
        got, want = read(big), read(small)
        np.testing.assert_allclose(got.depths, want.depths, rtol=1e-12)
        assert got.depths[0] == 0.002 and got.depths[-1] == pytest.approx(0.004)
    # back to front, as Stereo Magnification writes them: the same planes, the same places
    _set_json_text(big / "mpi.json", "[500, 2000, 5000]", "[5000, 2000, 500]")
    meta = json.loads((big / "mpi.json").read_text())
    meta["layer_order"] = "back_to_front"
    (big / "mpi.json").write_text(json.dumps(meta))
    back = read_mpi(big, near=0.002, far=0.004, spacing=spacing)
    np.testing.assert_allclose(back.depths, want.depths, rtol=1e-12)
    # each layer keeps its rank: layer_00, nearest before, is now the farthest plane
    assert np.array_equal(back.alpha, got.alpha[::-1])
    assert np.array_equal(back.color, got.color[::-1])


def test_mpi_folder_scene_units_above_1000_without_near_far_ask_for_them(tmp_path, rng,
                                                                         capsys):
    """Without near/far the refusal said "give metres (2e-3 for 2 mm)" of depths that were
    scene units: it now says they are scene units and to give --near/--far, naming the file;
    and the command line renders the same folder with --near/--far."""
    folder = _mpi_folder(tmp_path / "m", rng, depth_units=None, depths=[500, 2000, 5000])
    with pytest.raises(InputError, match=r"m/mpi\.json: depths reach 5000 scene units, which "
                                         r"are not metres: place them with near and far "
                                         r"\(--near/--far"):
        load_scene(folder)
    rc, err = _render([folder, "--frames", "1", "--out", tmp_path / "o"], capsys)
    assert rc == 2 and "scene units" in err and "--near" in err and "give metres" not in err
    rc, err = _render([folder, "--frames", "1", "--near", "0.002", "--far", "0.004",
                       "--out", tmp_path / "o"], capsys)
    assert rc == 0, err


def test_stereo_mag_range_above_1000_loads_when_near_far_place_it(tmp_path, rng):
    """``load_scene(folder, min_depth=1, max_depth=5000, near=..., far=...)`` was refused as
    metres beyond 1 km; now placed, and without near/far refused as scene units."""
    folder = _stereo_mag(tmp_path / "sm", rng)
    mpi = load_scene(folder, min_depth=1.0, max_depth=5000.0, near=0.002, far=0.004)
    np.testing.assert_allclose(mpi.depths, [0.002, 0.003, 0.004])
    mpi = read_stereo_mag(folder, min_depth=1.0, max_depth=5000.0, near=0.002, far=0.004,
                          spacing="inverse")
    assert mpi.depths[0] == pytest.approx(0.002) and mpi.depths[-1] == pytest.approx(0.004)
    with pytest.raises(InputError, match=r"sm \(min_depth 1, max_depth 5000\): depths reach "
                                         r"5000 scene units.*--near/--far"):
        load_scene(folder, min_depth=1.0, max_depth=5000.0)


def test_splats_in_large_scene_units_render_when_near_far_place_them(tmp_path):
    """A .ply whose positions are millimetres (camera z of 18000) was refused as "depths
    reaches 18439.8 m, beyond 1000 m ... give metres" even with --near/--far."""
    table = _table()
    table[:, :3] *= 1000.0
    table[:, 7:10] += np.log(1000.0)
    path = _ply(tmp_path / "mm.ply", table)
    small = splats_to_mpi(_ply(tmp_path / "m.ply"), layers=4, width=32, backend="numpy",
                          near=0.002, far=0.004, spacing="depth")
    mpi = splats_to_mpi(path, layers=4, width=32, backend="numpy", near=0.002, far=0.004,
                        spacing="depth")
    np.testing.assert_allclose(mpi.depths, small.depths, rtol=1e-6)
    with pytest.raises(InputError, match=r"mm\.ply: depths reach [\d.]+ scene units, which are "
                                         r"not metres: place them with near and far"):
        splats_to_mpi(path, layers=4, width=32, backend="numpy")


def test_placed_mpi_keeps_its_depths_bit_for_bit():
    """MPI.placed now goes through the loaders' placement: the same bits as its own formulas
    (uniform by index, linear in depth, linear in inverse depth)."""
    mpi = MPI(np.full((4, 2, 2, 1), 0.5), np.full((4, 2, 2), 0.5), [0.1, 0.2, 0.5, 0.9])
    d = mpi.depths
    assert np.array_equal(mpi.placed(2e-3, 6e-3).depths, np.linspace(2e-3, 6e-3, 4))
    assert np.array_equal(mpi.placed(2e-3, 6e-3, spacing="depth").depths,
                          2e-3 + (d - d[0]) / (d[-1] - d[0]) * 4e-3)
    inv = 1.0 / d
    t = (inv[0] - inv) / (inv[0] - inv[-1])
    assert np.array_equal(mpi.placed(2e-3, 6e-3, spacing="inverse").depths,
                          1.0 / (1.0 / 2e-3 + t * (1.0 / 6e-3 - 1.0 / 2e-3)))


# --- 3. internal errors (exit 70) for bad JSON and TOML values --------------------------------

def test_mpi_json_depth_of_hundreds_of_digits_is_refused_naming_the_file(tmp_path, rng,
                                                                        capsys):
    """``"depths": [2, 3, 1000...0]`` (400 digits) was ``OverflowError: int too large to
    convert to float``, an internal error."""
    folder = _mpi_folder(tmp_path / "m", rng)
    _set_json_text(folder / "mpi.json", "0.004", "1" + "0" * 400)
    with pytest.raises(ValueError, match=r"m/mpi\.json: 'depths' holds an integer of 401 "
                                         r"digits"):
        read_mpi(folder)
    rc, err = _render([folder, "--frames", "1", "--out", tmp_path / "o"], capsys)
    assert rc == 2 and "mpi.json" in err


@pytest.mark.parametrize("entry", [{"color": ["layer_00.png"], "alpha": "layer_00.png"},
                                   {"color": "layer_00.png", "alpha": 5}])
def test_mpi_json_layer_pair_of_non_names_is_refused(tmp_path, rng, capsys, entry):
    """``{"color": ["layer_00.png"], "alpha": ...}`` was ``TypeError: unsupported operand
    type(s) for /: 'PosixPath' and 'list'``, an internal error."""
    folder = _mpi_folder(tmp_path / "m", rng)
    meta = json.loads((folder / "mpi.json").read_text())
    meta["layers"][0] = entry
    (folder / "mpi.json").write_text(json.dumps(meta))
    with pytest.raises(ValueError, match=r"m/mpi\.json: layer 0 must be a file name or "
                                         r"\{\"color\": file, \"alpha\": file\}"):
        read_mpi(folder)
    rc, err = _render([folder, "--frames", "1", "--out", tmp_path / "o"], capsys)
    assert rc == 2 and "layer 0 must be a file name" in err


@pytest.mark.parametrize("key", ["fx", "width"])
def test_cameras_json_number_of_hundreds_of_digits_is_refused(tmp_path, key):
    """An ``fx`` or ``width`` of 400 digits was ``TypeError: ufunc 'isfinite' not
    supported``, an internal error."""
    entry = {"id": 0, "img_name": "c0", "width": 32, "height": 24, "fx": 30.0, "fy": 30.0,
             "position": [0.0, 0.0, 0.0], "rotation": [[1, 0, 0], [0, 1, 0], [0, 0, 1]]}
    raw = json.dumps(entry).replace(json.dumps(entry[key]) + ",", "9" * 400 + ",", 1)
    path = _cameras(tmp_path / "cameras.json", raw_entry=raw)
    with pytest.raises(ValueError, match=rf"cameras\.json: camera 0 \(c0\): '{key}' must be "
                                         rf".*an integer of 400 digits"):
        camera_from_json(path)


def test_batch_line_nested_too_deeply_is_refused_naming_the_line(tmp_path):
    """A JSON-lines manifest line of 100000 nested ``[`` was a ``RecursionError``."""
    from clholo.batch import read_manifest

    path = tmp_path / "deep.jsonl"
    path.write_text(DEEP + "\n")
    with pytest.raises(InputError, match=r"deep\.jsonl line 1: not JSON that can be read "
                                         r"\(arrays or objects nested thousands deep"):
        read_manifest(path)


def test_bench_toml_nested_too_deeply_is_refused(tmp_path, capsys):
    """``a = [[[...]]]`` 100000 deep in a bench file was a ``RecursionError``."""
    from clholo.tools.config import load_bench_config

    path = tmp_path / "bench.toml"
    path.write_text("a = " + DEEP + "\n")
    with pytest.raises(InputError, match=r"bench\.toml is not valid TOML that can be read: "
                                         r"its arrays or tables are nested thousands deep"):
        load_bench_config(path)


@pytest.mark.parametrize("key", ["luts", "phase_luts"])
def test_bench_toml_lut_list_of_numbers_is_refused(tmp_path, key):
    """``[slm] luts = [5]`` was ``TypeError: expected str, bytes or os.PathLike object, not
    int``, an internal error."""
    from clholo.tools.config import load_bench_config

    path = tmp_path / "bench.toml"
    path.write_text(BENCH + f"{key} = [5]\n")
    with pytest.raises(InputError, match=rf"bench\.toml: \[slm\] {key} must list file names "
                                         rf"as text \(quoted\), got 5"):
        load_bench_config(path)


# --- 9. a line that names the file and the fix -------------------------------------------------

def test_ply_with_a_property_listed_twice_names_the_file_and_line(tmp_path):
    """``property float x`` twice was "field 'x' occurs more than once" (NumPy's words),
    naming neither the file nor what to do."""
    path = _ply(tmp_path / "twice.ply", np.zeros((2, len(PROPS) + 1)), props=PROPS + ["x"])
    with pytest.raises(ValueError, match=r"twice\.ply: line 18: property 'x' of element "
                                         r"'vertex' is listed twice in the PLY header"):
        read_ply(path)


def test_json_integer_beyond_4300_digits_names_the_file(tmp_path, rng, capsys):
    """An integer of 5000 digits in mpi.json or cameras.json was Python's "Exceeds the limit
    (4300 digits) for integer string conversion ...; use sys.set_int_max_str_digits()",
    naming neither file nor fix."""
    folder = _mpi_folder(tmp_path / "m", rng)
    _set_json_text(folder / "mpi.json", "0.004", HUGE)
    with pytest.raises(ValueError, match=r"m/mpi\.json is not valid JSON clholo reads: it "
                                         r"holds an integer of more than 4300 digits"):
        read_mpi(folder)
    rc, err = _render([folder, "--frames", "1", "--out", tmp_path / "o"], capsys)
    assert rc == 2 and "mpi.json" in err and "set_int_max_str_digits" not in err
    path = _cameras(tmp_path / "cameras.json")
    _set_json_text(path, '"width": 32', f'"width": {HUGE}')
    with pytest.raises(ValueError, match=r"cameras\.json is not valid JSON clholo reads"):
        camera_from_json(path)


def test_batch_and_bench_integer_beyond_4300_digits_names_the_file(tmp_path):
    """The same 5000-digit integer in a batch manifest line and a bench TOML."""
    from clholo.batch import read_manifest
    from clholo.tools.config import load_bench_config

    manifest = tmp_path / "big.jsonl"
    manifest.write_text('{"input": "scene", "frames": ' + HUGE + "}\n")
    with pytest.raises(InputError, match=r"big\.jsonl line 1: holds an integer of more than "
                                         r"4300 digits"):
        read_manifest(manifest)
    bench = tmp_path / "bench.toml"
    bench.write_text(BENCH + f"refresh_hz = {HUGE}\n")
    with pytest.raises(InputError, match=r"bench\.toml is not valid TOML that can be read: it "
                                         r"holds an integer of more than 4300 digits"):
        load_bench_config(bench)


def test_nul_byte_in_an_mpi_layer_name_names_the_file_and_layer(tmp_path, rng, capsys):
    """``"layer_00.png\\u0000x"`` in mpi.json was "embedded null byte", from ``stat``."""
    folder = _mpi_folder(tmp_path / "m", rng)
    _set_json_text(folder / "mpi.json", '"layer_00.png"', '"layer_00.png\\u0000x"')
    with pytest.raises(InputError, match=r"m/mpi\.json: layer 0 file '.*/layer_00\.png\\x00x' is "
                                         r"not a file name: it holds a NUL byte"):
        read_mpi(folder)
    rc, err = _render([folder, "--frames", "1", "--out", tmp_path / "o"], capsys)
    assert rc == 2 and "mpi.json: layer 0 file" in err and "NUL byte" in err


@pytest.mark.parametrize("value, words", [("sce\\u0000ne", r"holds a NUL byte"),
                                          ("scene\\ud800", r"holds '\\ud800', a lone "
                                                           r"surrogate")])
def test_batch_input_with_a_nul_byte_or_a_lone_surrogate_names_the_line(tmp_path, value,
                                                                        words):
    """A JSON-lines ``input`` with ``\\u0000`` was "embedded null byte", with ``\\ud800``
    "'utf-8' codec can't encode character ... surrogates not allowed": neither named the
    manifest or its line."""
    from clholo.batch import read_manifest

    path = tmp_path / "items.jsonl"
    path.write_text('{"input": "' + value + '"}\n')
    with pytest.raises(InputError, match=rf"items\.jsonl line 1: column 'input' {words}"):
        read_manifest(path)


def test_ragged_rotation_in_cameras_json_names_the_key(tmp_path):
    """``"rotation": [[1,0,0],[0,1],[0,0,1]]`` was NumPy's "setting an array element with a
    sequence. The requested array has an inhomogeneous shape"."""
    path = _cameras(tmp_path / "cameras.json", rotation=[[1, 0, 0], [0, 1], [0, 0, 1]])
    with pytest.raises(ValueError, match=r"cameras\.json: camera 0 \(00000\): 'rotation' must "
                                         r"be a 3x3 list of numbers \(rows\), got rows of 3, "
                                         r"2, 3 numbers"):
        camera_from_json(path)


def test_mpi_json_metre_depths_beyond_a_kilometre_name_the_file(tmp_path, rng):
    """Depths of 1e300 m in an mpi.json in metres were refused without naming mpi.json."""
    folder = _mpi_folder(tmp_path / "m", rng, depths=[1e300, 1e301, 1e302])
    with pytest.raises(InputError, match=r"m/mpi\.json: depths reach 1e\+302 m, beyond 1000 "
                                         r"m: not a distance on an optical bench"):
        read_mpi(folder)


# --- 10. a named pipe, a device or a loop of links is not "does not exist" --------------------

@pytest.fixture
def specials(tmp_path):
    """A named pipe and a loop of symbolic links."""
    fifo = tmp_path / "fifo.toml"
    os.mkfifo(fifo)
    loop = tmp_path / "loop1"
    os.symlink(tmp_path / "loop2", loop)
    os.symlink(loop, tmp_path / "loop2")
    return fifo, loop


def test_bench_config_that_is_a_pipe_device_or_loop_says_what_it_is(specials):
    """``--config fifo.toml`` and ``--config /dev/zero`` were "bench configuration ... does
    not exist", and so was a loop of links."""
    from clholo.tools.config import load_bench_config

    fifo, loop = specials
    with pytest.raises(InputError, match=r"fifo\.toml is not a regular file \(a named pipe"):
        load_bench_config(fifo)
    with pytest.raises(InputError, match=r"/dev/zero is not a regular file \(a device\)"):
        load_bench_config("/dev/zero")
    with pytest.raises(InputError, match=r"cannot read bench configuration .*loop1: Too many "
                                         r"levels of symbolic links"):
        load_bench_config(loop)


def test_batch_manifest_and_scene_input_loops_are_not_missing(specials):
    """``clholo batch loop1`` and ``clholo render loop1`` said the loop "does not exist"."""
    from clholo.batch import read_manifest

    _, loop = specials
    with pytest.raises(InputError, match=r"cannot read manifest .*loop1: Too many levels of "
                                         r"symbolic links"):
        read_manifest(loop)
    with pytest.raises(InputError, match=r"cannot read scene input .*loop1: Too many levels "
                                         r"of symbolic links"):
        load_scene(loop)


def test_cameras_json_loop_is_not_missing(specials):
    """``--camera-json loop1`` said the loop "does not exist (3DGS writes cameras.json beside
    point_cloud/)"."""
    _, loop = specials
    with pytest.raises(InputError, match=r"cannot read camera file .*loop1: Too many levels "
                                         r"of symbolic links"):
        camera_from_json(loop)


# --- 11. smaller findings ---------------------------------------------------------------------

def test_mpi_json_key_given_twice_is_refused(tmp_path, rng):
    """``"depths"`` given twice in mpi.json: the last won without a word."""
    folder = _mpi_folder(tmp_path / "m", rng)
    text = (folder / "mpi.json").read_text()
    (folder / "mpi.json").write_text(text.replace('"depths":', '"depths": [1, 2, 3], '
                                                               '"depths":', 1))
    with pytest.raises(ValueError, match=r"m/mpi\.json: key 'depths' is given twice in one "
                                         r"object"):
        read_mpi(folder)


def test_mpi_json_depth_units_of_another_unit_is_refused(tmp_path, rng):
    """``"depth_units": "mm"`` was taken as scene units without a word; the Stereo
    Magnification wording (twain's "scene units; planes ...") and metres still read."""
    from clholo.io.load import scene_depth_units

    folder = _mpi_folder(tmp_path / "m", rng, depth_units="mm")
    with pytest.raises(InputError, match=r"m/mpi\.json: 'depth_units' must be \"metres\" .* or "
                                         r"\"scene units\" .*got \"mm\""):
        read_mpi(folder)
    for words, units in (("scene units; planes uniform in inverse depth", "scene units"),
                         ("meters", "metres")):
        _mpi_folder(tmp_path / words[:5], rng, depth_units=words)
        assert read_mpi(tmp_path / words[:5]).layers == 3
        assert scene_depth_units(tmp_path / words[:5]) == units


def test_bench_toml_with_a_byte_order_mark_reads(tmp_path):
    """A bench file saved "UTF-8 with BOM" was "not valid TOML: Invalid statement (at line 1,
    column 1)"."""
    from clholo.tools.config import load_bench_config

    path = tmp_path / "bench.toml"
    path.write_bytes(b"\xef\xbb\xbf" + BENCH.encode())
    assert load_bench_config(path).resolution == (12, 8)


def test_oversized_camera_suggests_a_scale_that_is_one(tmp_path):
    """A camera 1e6 pixels wide was told "pass --scale 0 or less" (3 decimals floored to 0),
    a scale that is refused; now three significant digits, and no --scale where no scale
    would leave a usable scene."""
    from clholo.io.splats import check_camera_renders

    camera = camera_from_json(_cameras(tmp_path / "cameras.json", width=1000000,
                                       height=500000))
    with pytest.raises(InputError, match=r"or pass --scale 0\.00819 or less$"):
        check_camera_renders(camera)
    camera = camera_from_json(_cameras(tmp_path / "thin.json", width=1000000000, height=24))
    with pytest.raises(InputError, match=r"\(its width and height\)$"):
        check_camera_renders(camera)


def test_stereo_mag_infinite_max_depth_is_refused_by_name(tmp_path, rng):
    """``read_stereo_mag(max_depth=inf)`` printed NumPy's "divide by zero" warning and said
    "depths contains 1 NaN/inf value(s)", naming no argument."""
    folder = _stereo_mag(tmp_path / "sm", rng)
    with pytest.raises(InputError, match=r"max_depth must be finite, got inf: the farthest "
                                         r"plane in scene units \(--max-depth\)"):
        read_stereo_mag(folder, max_depth=float("inf"))

