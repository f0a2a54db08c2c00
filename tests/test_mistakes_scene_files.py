"""Mistakes in scene and hologram files found by an audit, each refused (or warned about) with a
message that names the file or option and the fix, and the valid case beside it still working:

1. a named pipe (FIFO, bash's ``<(...)``) given as any input file: refused from ``stat`` alone,
   never opened (opening one waits for a writer: a hang that SIGTERM did not end);
2. a float image file (EXR) of colour outside [0, 1] or NaN, read as the RGB-D image;
3. ``--scale`` that shrinks any input below ``clholo.demo.MIN_SCENE_PIXELS`` per side;
4. a scene that carries no light (alpha 0 everywhere, splats of opacity 0): one warning;
5. ``--spacing`` without ``--near``/``--far`` (it would not act);
6. stored splat values that ``exp``/the sigmoid turn into inf (no NumPy warnings);
7. a complex128 hologram beyond the complex64 range it is read in;
8. a .ply without ``--near``/``--far``: said without made-up depths.
"""

import json
import os
import subprocess
import sys
import warnings

import numpy as np
import pytest

import clholo
from clholo import cli
from clholo.demo import MIN_SCENE_PIXELS
from clholo.io import load as io_load
from clholo.errors import InputError
from clholo.io import load_scene, read_hologram, read_ply, read_rgb, write_image, write_mpi
from clholo.scenes import NoLightWarning

PROPS = ["x", "y", "z", "f_dc_0", "f_dc_1", "f_dc_2", "opacity", "scale_0", "scale_1",
         "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]
ENV = dict(os.environ, PYTHONUNBUFFERED="1")


def _table(n=9):
    """n small opaque splats on a 3 x 3 grid in front of the origin (a square default view)."""
    t = np.zeros((n, len(PROPS)), np.float32)
    g = np.linspace(-0.5, 0.5, 3)
    t[:, 0] = np.tile(g, 3)[:n]
    t[:, 1] = np.repeat(g, 3)[:n]
    t[:, 2] = 4.0
    t[:, 6] = 2.0                  # opacity logit
    t[:, 7:10] = np.log(0.2)       # log-scales
    t[:, 10] = 1.0                 # quaternion w
    return t


def _ply(path, table=None):
    table = _table() if table is None else table
    text = "\n".join(["ply", "format binary_little_endian 1.0", f"element vertex {len(table)}"]
                     + [f"property float {p}" for p in PROPS] + ["end_header"]) + "\n"
    path.write_bytes(text.encode() + np.asarray(table, "<f4").tobytes())
    return path


def _mpi(path, H=16, W=16, alpha=1.0, colour=0.5):
    write_mpi(path, clholo.MPI(np.full((2, H, W, 3), colour), np.full((2, H, W), alpha),
                               [0.002, 0.004]))
    return path


def _render(args, capsys):
    """Exit code and stderr of ``clholo render ARGS`` (never a traceback)."""
    rc = cli.main(["render", *map(str, args), "--progress", "off"])
    err = capsys.readouterr().err
    assert "Traceback" not in err and "internal error" not in err, err
    return rc, err


# --- 1. named pipes (and folders) as input files ----------------------------------------------

# Every reader, in a child process: a regression that opens the pipe hangs there, and the
# parent's timeout turns it into a failure naming the case (printed as each one ends).
_FIFO_CASES = r"""
import sys
from pathlib import Path
import numpy as np
import clholo
from clholo import io
from clholo.io.splats import check_ply_has_splats

d = Path(sys.argv[1])
cases = [
    ("read_image", lambda: io.read_image(d / "fifo.png")),
    ("read_rgb", lambda: io.read_rgb(d / "fifo.exr")),
    ("read_depth", lambda: io.read_depth(d / "fifo.npy")),
    ("read_pfm", lambda: io.read_pfm(d / "fifo.pfm")),
    ("read_dpt", lambda: io.read_dpt(d / "fifo.dpt")),
    ("read_hologram", lambda: io.read_hologram(d / "fifo.npz")),
    ("read_ply", lambda: io.read_ply(d / "fifo.ply")),
    ("check_ply_has_splats", lambda: check_ply_has_splats(d / "fifo.ply")),
    ("read_cameras_json", lambda: io.read_cameras_json(d / "fifo.json")),
    ("load_scene ply", lambda: io.load_scene(d / "fifo.ply")),
    ("load_scene image", lambda: io.load_scene([d / "fifo.png", d / "depth.npy"],
                                               near=0.002, far=0.004)),
    ("load_scene depth", lambda: io.load_scene([d / "image.png", d / "fifo.npy"],
                                               near=0.002, far=0.004)),
    ("MPI layer file", lambda: io.load_scene(d / "layers")),
    ("MPI mpi.json", lambda: io.load_scene(d / "json")),
    ("Stereo Magnification layer", lambda: io.load_scene(d / "sm")),
    ("read_mpi layer file", lambda: io.read_mpi(d / "layers")),
    ("read_mpi mpi.json", lambda: io.read_mpi(d / "json")),
]
for name, call in cases:
    try:
        call()
        print(f"{name}|no error", flush=True)
    except Exception as exc:
        print(f"{name}|{type(exc).__name__}|{exc}", flush=True)
"""


def _fifo_scene(tmp_path, rng):
    for name in ("fifo.png", "fifo.exr", "fifo.npy", "fifo.pfm", "fifo.dpt", "fifo.npz",
                 "fifo.ply", "fifo.json"):
        os.mkfifo(tmp_path / name)
    write_image(tmp_path / "image.png", rng.uniform(size=(16, 16, 3)), dtype="uint8")
    np.save(tmp_path / "depth.npy", rng.uniform(1, 2, (16, 16)))
    _mpi(tmp_path / "layers")
    layer = json.loads((tmp_path / "layers" / "mpi.json").read_text())["layers"][1]
    (tmp_path / "layers" / layer).unlink()
    os.mkfifo(tmp_path / "layers" / layer)
    (tmp_path / "json").mkdir()
    os.mkfifo(tmp_path / "json" / "mpi.json")
    (tmp_path / "sm").mkdir()
    os.mkfifo(tmp_path / "sm" / "mpi_rgb_00.png")
    write_image(tmp_path / "sm" / "mpi_alpha_00.png", np.ones((16, 16)), dtype="uint8")
    return layer


def test_a_named_pipe_is_refused_by_every_reader_without_opening_it(tmp_path, rng):
    layer = _fifo_scene(tmp_path, rng)
    try:
        done = subprocess.run([sys.executable, "-c", _FIFO_CASES, str(tmp_path)],
                              capture_output=True, text=True, timeout=120, env=ENV)
    except subprocess.TimeoutExpired as exc:
        out = exc.stdout.decode() if isinstance(exc.stdout, bytes) else (exc.stdout or "")
        pytest.fail(f"a reader opened a named pipe and waited; finished before it:\n{out}")
    assert done.returncode == 0, done.stderr
    got = {line.split("|")[0]: line.split("|")[1:] for line in done.stdout.splitlines()}
    expected = {
        "read_image": "image file {d}/fifo.png", "read_rgb": "image file {d}/fifo.exr",
        "read_depth": "depth file {d}/fifo.npy", "read_pfm": "depth file {d}/fifo.pfm",
        "read_dpt": "depth file {d}/fifo.dpt", "read_hologram": "hologram file {d}/fifo.npz",
        "read_ply": "PLY file {d}/fifo.ply", "check_ply_has_splats": "PLY file {d}/fifo.ply",
        "read_cameras_json": "camera file {d}/fifo.json",
        "load_scene ply": "scene input {d}/fifo.ply",
        "load_scene image": "scene input {d}/fifo.png",
        "load_scene depth": "scene input {d}/fifo.npy",
        "MPI layer file": "{d}/layers/mpi.json: layer 1 file {d}/layers/" + layer,
        "MPI mpi.json": "MPI folder file {d}/json/mpi.json",
        "Stereo Magnification layer": "image file {d}/sm/mpi_rgb_00.png",
        "read_mpi layer file": "{d}/layers/mpi.json: layer 1 file {d}/layers/" + layer,
        "read_mpi mpi.json": "MPI description {d}/json/mpi.json",
    }
    assert set(got) == set(expected), done.stdout
    for case, start in expected.items():
        kind, message = got[case]
        assert kind == "InputError", (case, got[case])
        assert message.startswith(start.format(d=tmp_path) + " is not a regular file (a named "
                                  "pipe, as bash's <(...) gives): give "), (case, message)
        assert "does not exist" not in message and "save the stream to a file" in message


def test_a_named_pipe_on_the_command_line_ends_at_once(tmp_path, rng):
    """The audit's repro: clholo render FIFO depth.npy hung in OpenImageIO's open (SIGTERM did
    not stop it); bash's <(...) gives a pipe too. A child with a timeout: a regression fails."""
    _fifo_scene(tmp_path, rng)
    run = f"import sys; from clholo import cli; sys.exit(cli.main(sys.argv[1:]))"
    cases = [
        ([sys.executable, "-c", run, "render", "fifo.png", "depth.npy", "--layers", "4",
          "--near", "0.002", "--far", "0.006", "--out", "o"],
         f"clholo render: error: scene input fifo.png is not a regular file (a named pipe, as "
         f"bash's <(...) gives): give an image file (PNG, EXR, ...), then its depth map; clholo "
         f"reads its inputs from files (more than once), so save the stream to a file first"),
        ([sys.executable, "-c", run, "encode", "fifo.npz", "--out", "o"],
         "clholo encode: error: hologram file fifo.npz is not a regular file (a named pipe, as "
         "bash's <(...) gives): give a hologram .npz or .exr file (the hologram.npz that clholo "
         "render writes); clholo reads its inputs from files (more than once), so save the "
         "stream to a file first"),
        (["bash", "-c", f'"$0" -c "$1" render <(cat image.png) depth.npy --near 0.002 --far '
                        f'0.006 --out o', sys.executable, run],
         "clholo render: error: scene input /dev/fd/"),
    ]
    for argv, line in cases:
        try:
            done = subprocess.run(argv, cwd=tmp_path, capture_output=True, text=True,
                                  timeout=60, env=ENV)
        except subprocess.TimeoutExpired:
            pytest.fail(f"{argv[3:]} waited on a named pipe instead of refusing it")
        last = done.stderr.strip().splitlines()[-1]
        assert done.returncode == 2 and last.startswith(line), done.stderr
        assert "is not a regular file (a named pipe" in last
    assert not (tmp_path / "o").exists()


def test_a_folder_given_as_a_file_is_said_to_be_a_folder(tmp_path, rng):
    """Paths that exist were "does not exist" when they were not regular files."""
    (tmp_path / "x.png").mkdir()
    (tmp_path / "h.npz").mkdir()
    with pytest.raises(InputError, match=r"image file .*x\.png is a folder: give an image file"):
        clholo.io.read_image(tmp_path / "x.png")
    with pytest.raises(InputError, match=r"hologram file .*h\.npz is a folder: give a hologram"):
        read_hologram(tmp_path / "h.npz")
    with pytest.raises(FileNotFoundError, match=r"image file .*y\.png does not exist"):
        clholo.io.read_image(tmp_path / "y.png")
    write_image(tmp_path / "ok.png", rng.uniform(size=(4, 4, 3)), dtype="uint8")
    assert clholo.io.read_image(tmp_path / "ok.png")[0].shape == (4, 4, 3)


# --- 2. float image files of colour outside [0, 1] ---------------------------------------------

def test_a_float_image_outside_0_1_is_refused_naming_the_file_range_and_fix(tmp_path, rng,
                                                                               capsys):
    np.save(tmp_path / "d.npy", rng.uniform(1, 2, (16, 16)))
    write_image(tmp_path / "x255.exr", rng.uniform(0, 255, (16, 16, 3)), dtype="float")
    with pytest.raises(InputError, match=r"x255\.exr holds float colour in \[[\d.]+, 25\d"
                                         r"[\d.]*\].*linear intensity in \[0, 1\].*0\.\.255 "
                                         r"never divided: divide by 255"):
        read_rgb(tmp_path / "x255.exr")
    hdr = rng.uniform(0, 1, (16, 16, 3))
    hdr[3, 4] = 4000.0
    write_image(tmp_path / "hdr.exr", hdr, dtype="float")
    with pytest.raises(InputError, match=r"hdr\.exr holds float colour in \[.*, 4000\].*scale it "
                                         r"into \[0, 1\]"):
        read_rgb(tmp_path / "hdr.exr")
    nan = rng.uniform(0, 1, (16, 16, 3))
    nan[5, 7, 1] = np.nan
    write_image(tmp_path / "nan.exr", nan, dtype="float")
    with pytest.raises(InputError, match=r"nan\.exr holds 1 pixel\(s\) of NaN/inf colour \(the "
                                         r"first at row 5, column 7\).*fill them"):
        read_rgb(tmp_path / "nan.exr")
    rc, err = _render([tmp_path / "x255.exr", tmp_path / "d.npy", "--layers", "2", "--near",
                       "0.002", "--far", "0.004", "--out", tmp_path / "o"], capsys)
    assert rc == 2 and "x255.exr holds float colour" in err and not (tmp_path / "o").exists()
    # valid: linear colour in [0, 1] is read as stored
    good = rng.uniform(0, 1, (16, 16, 3)).astype(np.float32)
    write_image(tmp_path / "good.exr", good, dtype="float")
    np.testing.assert_array_equal(read_rgb(tmp_path / "good.exr"), good)


# --- 3. --scale below MIN_SCENE_PIXELS -------------------------------------------------------

def test_scale_that_shrinks_a_scene_below_the_minimum_is_refused_for_every_input(tmp_path, rng,
                                                                                 capsys):
    # one rule for every input: the demo's ("use a scale of at least 0.032")
    assert io_load.MIN_SCENE_PIXELS == MIN_SCENE_PIXELS == 16
    _mpi(tmp_path / "m", H=32, W=40)
    rc, err = _render([tmp_path / "m", "--scale", "0.1", "--out", tmp_path / "o"], capsys)
    assert rc == 2 and not (tmp_path / "o").exists()
    assert err.strip().splitlines()[-1] == (
        "clholo render: error: --scale 0.1 (scale=0.1) shrinks the 40x32 scene to 4x3 pixels, "
        "fewer than the 16 per side a focal stack needs to show anything: use --scale 0.5 or "
        "more")
    with pytest.raises(InputError, match=r"scale=0\.01\) shrinks the 40x32 scene to 0x0 pixels"):
        load_scene(tmp_path / "m", scale=0.01)
    # RGB-D pair
    write_image(tmp_path / "im.png", rng.uniform(size=(48, 64, 3)), dtype="uint8")
    np.save(tmp_path / "d.npy", rng.uniform(1, 2, (48, 64)))
    pair = [tmp_path / "im.png", tmp_path / "d.npy"]
    with pytest.raises(InputError, match=r"--scale 0\.2 \(scale=0\.2\) shrinks the 64x48 scene "
                                         r"to 13x10 pixels.*use --scale 0\.334 or more"):
        load_scene(pair, layers=2, near=0.002, far=0.004, scale=0.2)
    # splats: the camera's view, refused before any splat is drawn
    _ply(tmp_path / "s.ply")
    rc, err = _render([tmp_path / "s.ply", "--near", "0.002", "--far", "0.004", "--scale",
                       "0.01", "--out", tmp_path / "o"], capsys)
    assert rc == 2 and "--scale 0.01 (scale=0.01) shrinks the 512x512 camera view to 5x5" in err
    with pytest.raises(InputError, match=r"shrinks the 512x512 camera view to 5x5 pixels.*"
                                         r"use --scale 0\.0313 or more"):
        load_scene(tmp_path / "s.ply", near=0.002, far=0.004, scale=0.01)
    # a scene already that small can only be taken as it is
    _mpi(tmp_path / "tiny", H=8, W=12)
    with pytest.raises(InputError, match=r"the scene has only 8 pixels on its shorter side: "
                                         r"drop --scale"):
        load_scene(tmp_path / "tiny", scale=0.5)
    # valid: down to MIN_SCENE_PIXELS, and small scenes at scale 1
    assert load_scene(tmp_path / "m", scale=0.5).shape == (16, 20)
    assert load_scene(pair, layers=2, near=0.002, far=0.004, scale=0.334).shape == (16, 21)
    assert load_scene(tmp_path / "tiny").shape == (8, 12)


# --- 4. scenes that carry no light ------------------------------------------------------------

def test_a_scene_without_light_is_warned_about_once_naming_the_file(tmp_path, capsys):
    _mpi(tmp_path / "clear", alpha=0.0)
    rc, err = _render([tmp_path / "clear", "--frames", "1", "--out", tmp_path / "o"], capsys)
    warned = [line for line in err.splitlines() if "warning" in line]
    assert rc == 0 and warned == [
        f"clholo render: warning: {tmp_path / 'clear'} carries no light: alpha is 0 in every "
        f"pixel of its 2 layer(s), so the hologram is all zero and the focal stack black; check "
        f"the layers' alpha (channel or file)"], err
    _mpi(tmp_path / "black", colour=0.0)
    with pytest.warns(NoLightWarning, match=r"black carries no light: its colour is 0"):
        clholo.scenes.load(clholo.scenes.SceneSpec(inputs=(str(tmp_path / "black"),)))
    table = _table()
    table[:, 6] = -1000.0  # opacity logits: sigmoid 0
    _ply(tmp_path / "dark.ply", table)
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)  # exp overflow, log(0): none
        rc, err = _render([tmp_path / "dark.ply", "--near", "0.002", "--far", "0.004", "--scale",
                           "0.05", "--layers", "2", "--frames", "1", "--out", tmp_path / "o2"],
                          capsys)
    warned = [line for line in err.splitlines() if "warning" in line]
    assert rc == 0 and len(warned) == 1, err
    assert warned[0].startswith(f"clholo render: warning: {tmp_path / 'dark.ply'} carries no "
                                f"light: the opacity of every one of its 9 splat(s) is 0")
    assert "opacity" in warned[0] and "export the trained point cloud again" in warned[0]
    # valid: a scene with light says nothing
    _mpi(tmp_path / "lit")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        scene = clholo.scenes.load(clholo.scenes.SceneSpec(inputs=(str(tmp_path / "lit"),)))
    assert scene.mpi.alpha.max() == 1.0


# --- 5. --spacing without --near/--far ---------------------------------------------------------

def test_spacing_without_near_and_far_is_refused(tmp_path, capsys):
    _mpi(tmp_path / "m")
    rc, err = _render([tmp_path / "m", "--spacing", "inverse", "--out", tmp_path / "o"], capsys)
    assert rc == 2 and not (tmp_path / "o").exists()
    assert err.strip().splitlines()[-1] == (
        "clholo render: error: --spacing places the planes between --near and --far: give both, "
        "or drop --spacing")
    with pytest.raises(InputError, match=r"spacing='depth' places the planes between near and "
                                         r"far: give both .*or drop spacing"):
        load_scene(tmp_path / "m", spacing="depth")
    # valid: with both, the planes move
    rc, err = _render([tmp_path / "m", "--spacing", "inverse", "--near", "0.003", "--far",
                       "0.005", "--frames", "1", "--out", tmp_path / "o"], capsys)
    assert rc == 0, err
    depths = json.loads((tmp_path / "o" / "summary.json").read_text())["depths_m"]
    np.testing.assert_allclose([depths[0], depths[-1]], [0.003, 0.005])
    assert list(load_scene(tmp_path / "m", spacing="depth", near=0.003, far=0.005).depths) == \
        pytest.approx([0.003, 0.005])


# --- 6. stored splat values that activation turns into inf ------------------------------------

def test_stored_splat_values_that_overflow_are_named_without_numpy_warnings(tmp_path, capsys):
    table = _table()
    table[3, 7] = 100.0            # a linear scale where 3DGS stores its logarithm
    _ply(tmp_path / "big.ply", table)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(ValueError, match=r"big\.ply: scale_0 of splat 3 is 100: 3DGS stores "
                                             r"each scale as its natural logarithm.*store "
                                             r"log\(scale\)"):
            read_ply(tmp_path / "big.ply")
    rc, err = _render([tmp_path / "big.ply", "--near", "0.002", "--far", "0.004", "--out",
                       tmp_path / "o"], capsys)
    assert rc == 2 and "NaN" not in err and "warning" not in err, err
    assert "big.ply: scale_0 of splat 3 is 100" in err
    table = _table()
    table[[2, 5], 1] = np.nan
    _ply(tmp_path / "nan.ply", table)
    with pytest.raises(ValueError, match=r"nan\.ply: y of splat 2 is nan \(2 splats in all\): "
                                         r"every stored value must be a finite number"):
        read_ply(tmp_path / "nan.ply")
    # opacity logits far below 0 are opacity 0, without an overflow warning
    table = _table()
    table[:, 6] = -1000.0
    _ply(tmp_path / "dark.ply", table)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        g = read_ply(tmp_path / "dark.ply")
        from clholo.io.splats import _power_floor

        floor = _power_floor(g.opacities)
    assert np.all(g.opacities == 0) and np.all(floor == np.finfo(np.float32).max)
    # valid: stored log-scales are activated; logits of +-inf (trained files hold them) are
    # opacities 1 and 0
    table = _table()
    table[0, 6], table[1, 6] = np.inf, -np.inf
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        g = read_ply(_ply(tmp_path / "ok.ply", table))
    np.testing.assert_allclose(g.scales, 0.2, rtol=1e-6)
    assert g.opacities[0] == 1.0 and g.opacities[1] == 0.0


# --- 7. a complex128 hologram beyond complex64 --------------------------------------------------

def _npz(path, field):
    meta = {"pitch": 8e-6, "wavelengths": [5.2e-7], "frames": 1, "channels": 1, "seed": None,
            "extra": {}}
    np.savez(path, field=field, pitch=np.float64(8e-6), wavelengths=np.array([5.2e-7]),
             seed=np.int64(-1), metadata=np.asarray(json.dumps(meta)))
    return path


def test_a_hologram_beyond_complex64_is_refused_naming_the_file(tmp_path, capsys):
    field = np.full((1, 1, 4, 4), 1.0 + 0j)
    field[0, 0, 1, 2] = 1e300 - 1j
    _npz(tmp_path / "h.npz", field)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(InputError, match=r"h\.npz: its field holds 1 value\(s\) beyond the "
                                             r"complex64 range .*\[0, 0, 1, 2\] is 1e\+300-1j\)"
                                             r": scale the field down"):
            read_hologram(tmp_path / "h.npz")
    rc = cli.main(["encode", str(tmp_path / "h.npz"), "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err
    assert rc == 2 and "warning" not in err and "h.npz: its field holds 1 value(s)" in err, err
    # valid: complex128 within range is read as complex64
    field[0, 0, 1, 2] = 3e38 - 1j
    got, _ = read_hologram(_npz(tmp_path / "ok.npz", field))
    assert got.dtype == np.complex64 and np.isfinite(got).all()


# --- 8. a .ply without --near/--far -------------------------------------------------------------

def test_splats_without_near_far_are_refused_without_made_up_depths(tmp_path, capsys):
    _ply(tmp_path / "s.ply")
    rc, err = _render([tmp_path / "s.ply", "--out", tmp_path / "o"], capsys)
    assert rc == 2 and err.strip().splitlines()[-1] == (
        f"clholo render: error: the depths of a 3D Gaussian splat .ply ({tmp_path / 's.ply'}) "
        f"are in scene units: give --near and --far in metres behind the hologram plane, e.g. "
        f"--near 0.002 --far 0.006")
    assert "(1..1)" not in err
    # valid: with both, the splats are placed in metres
    rc, err = _render([tmp_path / "s.ply", "--near", "0.002", "--far", "0.004", "--scale",
                       "0.05", "--layers", "2", "--frames", "1", "--out", tmp_path / "o"], capsys)
    assert rc == 0, err
    depths = json.loads((tmp_path / "o" / "summary.json").read_text())["depths_m"]
    np.testing.assert_allclose([depths[0], depths[-1]], [0.002, 0.004])
