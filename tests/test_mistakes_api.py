"""User mistakes at the Python API: each is refused with an error that names the argument (or
cannot happen at all), never an internal error or a silent wrong result."""

import re

import numpy as np
import pytest

import clholo
from clholo.scene import MPI, Optics


def _mpi(L=2, H=8, W=8, C=1, seed=0):
    rng = np.random.default_rng(seed)
    color = rng.random((L, H, W, C)).astype(np.float32)
    alpha = rng.random((L, H, W)).astype(np.float32)
    return color, alpha, np.linspace(1e-3, 2e-3, L)


# 1. an MPI's arrays cannot change after they were checked

@pytest.mark.parametrize("name", ["color", "alpha", "depths"])
def test_mpi_arrays_are_read_only(name):
    m = MPI(*_mpi())
    arr = getattr(m, name)
    with pytest.raises(ValueError, match="read-only"):
        arr[0] = 7
    with pytest.raises(ValueError, match="read-only"):
        arr[0] = np.nan
    with pytest.raises(ValueError):  # and the flag cannot be set back
        arr.flags.writeable = True


def test_mpi_does_not_follow_the_callers_float32_arrays():
    color, alpha, depths = _mpi()
    m = MPI(color, alpha, depths)
    alpha[0] = 7
    color[0] = np.nan
    depths[0] = -1
    assert not np.shares_memory(m.alpha, alpha) and not np.shares_memory(m.color, color)
    assert float(m.alpha.max()) <= 1 and np.all(np.isfinite(m.color)) and m.depths[0] > 0
    # the checked MPI renders finite holograms whatever the caller does with its arrays
    h = clholo.render_hologram(m, Optics(wavelengths=(520e-9,)), frames=1)
    assert np.all(np.isfinite(h))


def test_mpi_placed_shares_its_read_only_layers():
    m = MPI(*_mpi())
    p = m.placed(1e-3, 5e-3)
    assert np.shares_memory(p.color, m.color)  # no second copy of the layers
    assert not p.color.flags.writeable


def test_one_colour_image_shared_by_every_layer_stays_one():
    """An RGB-D scene's layers all carry the photo's colour (alpha says where each shows):
    the MPI keeps one read-only copy broadcast to the layers, not L copies (32 layers of a
    12-megapixel photo: 4.6 GB), checked as strictly, renders as the dense layers do."""
    import tracemalloc

    color, alpha, depths = _mpi(L=6, H=16, W=20, C=3)
    image = color[0].copy()
    shared = MPI(np.broadcast_to(image, color.shape), alpha, depths)
    dense = MPI(np.repeat(image[None], 6, axis=0), alpha, depths)
    assert shared.color.strides[0] == 0 and not np.shares_memory(shared.color, image)
    image[0, 0] = np.nan  # the caller's array: nothing of it is kept
    assert np.array_equal(shared.color, dense.color)
    with pytest.raises(ValueError, match="read-only"):
        shared.color[2, 0, 0, 0] = 0.5
    reversed_ = MPI(shared.color[::-1], alpha[::-1], depths[::-1])  # sorted nearest first
    assert np.array_equal(reversed_.alpha, shared.alpha) and reversed_.color.strides[0] == 0
    placed = shared.placed(1e-3, 4e-3)
    assert np.shares_memory(placed.color, shared.color) and placed.color.strides[0] == 0
    optics = Optics(wavelengths=(638e-9, 520e-9, 450e-9))
    assert np.array_equal(clholo.render_hologram(shared, optics, frames=1, seed=3),
                          clholo.render_hologram(dense, optics, frames=1, seed=3))
    bad = np.broadcast_to(np.full((16, 20, 3), 1.5, np.float32), color.shape)
    with pytest.raises(ValueError, match=r"color must be linear intensity in \[0, 1\]"):
        MPI(bad, alpha, depths)
    # rgbd_to_mpi makes its layers so: the MPI of a 512^2 photo at 32 layers takes its alpha
    # and one image, not 32 images (100 MB of float32 colour)
    rng = np.random.default_rng(1)
    photo, depth = rng.random((512, 512, 3)), rng.uniform(1, 2, (512, 512))
    tracemalloc.start()
    try:
        mpi = clholo.io.rgbd_to_mpi(photo, depth, layers=32, near=1e-3, far=2e-3)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert mpi.color.strides[0] == 0 and mpi.color.shape == (32, 512, 512, 3)
    assert peak < 80e6, peak
    for arr in (mpi.color, mpi.alpha):  # read-only for good, as every MPI's arrays
        with pytest.raises(ValueError):
            arr.flags.writeable = True


@pytest.mark.parametrize("shared", [True, False])
def test_a_pickled_mpi_arrives_checked_and_read_only(shared):
    """multiprocessing and Dask pickle: the MPI is rebuilt by its constructor where it
    arrives (read-only, checked), and a colour shared by the layers travels once."""
    import pickle

    color, alpha, depths = _mpi(L=8, H=32, W=40, C=3)
    if shared:
        color = np.broadcast_to(color[0], color.shape)
    m = MPI(color, alpha, depths)
    data = pickle.dumps(m)
    back = pickle.loads(data)
    assert np.array_equal(back.color, m.color) and np.array_equal(back.alpha, m.alpha)
    assert np.array_equal(back.depths, m.depths)
    for arr in (back.color, back.alpha, back.depths):
        with pytest.raises(ValueError, match="read-only"):
            arr[0] = 0.5
    assert (back.color.strides[0] == 0) == shared
    colour_bytes = color[0].nbytes if shared else color.nbytes
    assert len(data) < colour_bytes + alpha.nbytes + 4096


# 2. complex or non-numeric phases are refused by every encode entry point

from clholo.errors import InputTypeError  # noqa: E402
from clholo.encode import quantize as qz  # noqa: E402


def _complex_phase():
    return np.exp(1j * np.linspace(0, 6, 16)).reshape(1, 1, 4, 4)


@pytest.mark.parametrize("entry", [
    lambda p: qz.quantize(p),
    lambda p: qz.wrap_phase(p),
    lambda p: qz.PhaseLUT.linear().to_gray(p),
    lambda p: qz.DeviceQuantizer()(p.astype(np.complex64)),
])
def test_complex_phase_refused(entry):
    with pytest.raises(InputTypeError, match=r"^phase must be real .*complex.*np\.angle"):
        entry(_complex_phase())


def test_complex_phase_refused_by_phase_to_hologram():
    from clholo.encode.simulate import phase_to_hologram

    with pytest.raises(InputTypeError, match=r"^phase must be real .*complex"):
        phase_to_hologram(_complex_phase(), Optics(wavelengths=(520e-9,)))


def test_non_numeric_phase_refused():
    with pytest.raises(InputTypeError, match=r"^phase must be real phases"):
        qz.quantize(np.array([[["a", "b"]]]))
    with pytest.raises(InputTypeError, match=r"^phase must be"):
        qz.quantize(None)


@pytest.mark.parametrize("luts", [None, 5, np.zeros(256)])
def test_quantize_luts_of_another_type_named(luts):
    with pytest.raises(InputTypeError, match=r"^luts must be a PhaseLUT"):
        qz.quantize(np.zeros((1, 4, 4)), luts)


def test_quantize_luts_empty_named():
    with pytest.raises(ValueError, match=r"^luts must name at least one"):
        qz.quantize(np.zeros((1, 4, 4)), [])


# 3. a table in degrees is refused by the API as by a table file

def test_phase_lut_in_degrees_refused_like_a_file(tmp_path):
    deg = np.linspace(0, 360, 256)
    with pytest.raises(ValueError, match=r"^lookup table: the phases span 360 rad .*degrees"):
        qz.PhaseLUT(deg)
    np.save(tmp_path / "deg.npy", deg)
    with pytest.raises(ValueError, match="degrees"):
        qz.read_luts(tmp_path / "deg.npy")
    # linear:N stays what it was (linear:2 spans many turns on purpose)
    assert qz.PhaseLUT.linear(2).usable_levels == 2
    assert len(qz.device_table(qz.PhaseLUT.linear(2))[0]) > 0


# 4. empty patterns are not written; a damaged patterns.json is one clear error

@pytest.mark.parametrize("cut", [lambda g: g[:0], lambda g: g[:, :0], lambda g: g[:, :, :0],
                                 lambda g: g[..., :0]])
def test_write_pattern_pngs_refuses_empty(tmp_path, cut):
    g = np.zeros((2, 1, 4, 4), np.uint8)
    with pytest.raises(ValueError, match=r"^gray must hold at least one frame"):
        qz.write_pattern_pngs(cut(g), tmp_path / "p", slm_shape=(8, 8))
    assert not (tmp_path / "p").exists()


def _written(tmp_path):
    import json

    folder = qz.write_pattern_pngs(np.full((1, 1, 4, 6), 7, np.uint8), tmp_path / "p")
    info = json.loads((folder / "patterns.json").read_text())
    return folder, info


@pytest.mark.parametrize("text, what", [
    ("{not json", "is not valid JSON"),
    ("[1, 2]", "must hold a JSON object"),
    ('{"frames": 1, "channels": ["c0"], "rows": 4}', "lacks cols"),
    ('{"frames": 1, "channels": ["c0"], "rows": 4, "cols": 5}', "does not match"),
    ('{"frames": 1, "channels": ["c0"], "rows": "4", "cols": 6}', "rows must be a whole number"),
    ('{"frames": 2, "channels": ["c0"], "rows": 4, "cols": 6}', "is missing"),
    ('{"frames": 1, "channels": [], "rows": 4, "cols": 6}', "channels must be"),
])
def test_read_pattern_pngs_damaged_json(tmp_path, text, what):
    folder, _ = _written(tmp_path)
    assert qz.read_pattern_pngs(folder).shape == (1, 1, 4, 6)
    (folder / "patterns.json").write_text(text)
    with pytest.raises(ValueError, match=what) as info:
        qz.read_pattern_pngs(folder)
    assert "patterns.json" in str(info.value)


# 5. fit_to_slm's fill and DeviceQuantizer's phase_range are checked

@pytest.mark.parametrize("fill, err", [(300, ValueError), (-1, ValueError), (1.5, TypeError),
                                       (True, TypeError), ("0", TypeError)])
def test_fit_to_slm_fill_checked(fill, err):
    with pytest.raises(err, match=r"^fill must"):
        qz.fit_to_slm(np.zeros((1, 1, 4, 4), np.uint8), (8, 8), fill=fill)
    assert qz.fit_to_slm(np.zeros((1, 1, 4, 4), np.uint8), (8, 8), fill=255)[0, 0, 0, 0] == 255


@pytest.mark.parametrize("rng", [(-1e30, 1e30), (0, 1e4)])
def test_device_quantizer_unreasonable_phase_range(rng):
    with pytest.raises(ValueError, match=r"^phase_range=.* is not a plausible range"):
        qz.DeviceQuantizer(phase_range=rng)


def test_device_quantizer_documented_limit_accepted():
    # the documented largest range is a valid range; the next float32 beyond it is not
    limit = qz.MAX_DEVICE_PHASE
    assert qz.DeviceQuantizer(phase_range=(-limit, limit)).phase_range[1] >= limit
    beyond = float(np.nextafter(np.float32(limit), np.float32(np.inf)))
    with pytest.raises(ValueError, match=r"^phase_range=.* is not a plausible range"):
        qz.DeviceQuantizer(phase_range=(-1.0, beyond))


def test_sgd_encode_complex_init_refused():
    from clholo.encode.sgd import sgd_encode

    h = np.ones((1, 1, 8, 8), np.complex64)
    with pytest.raises(InputTypeError, match=r"^init must be real phases .*complex"):
        sgd_encode(h, Optics(wavelengths=(520e-9,)), init=np.ones((1, 1, 8, 8), np.complex64),
                   iterations=1)


# 6. propagation and render arguments

_KW = dict(wavelength=520e-9, pitch=8e-6)


@pytest.mark.parametrize("pad, err, what", [
    (None, TypeError, r"^pad must be 'auto', a factor"),
    (True, TypeError, r"^pad must be .*a bool"),
    (np.True_, TypeError, r"^pad must be .*a bool"),
    ((32.5, 40), TypeError, r"^pad as a shape must be \(Hp, Wp\), two whole numbers"),
    ((16, 16, 3), TypeError, r"^pad as a shape"),
    ("twice", ValueError, r"^pad must be 'auto'"),
    (float("nan"), ValueError, r"^pad factor must be finite"),
])
def test_propagate_pad_checked(pad, err, what):
    with pytest.raises(err, match=what):
        clholo.propagate(np.ones((8, 8), np.complex64), 1e-3, pad=pad, **_KW)


def test_propagate_pad_forms_still_taken():
    f = np.ones((8, 8), np.complex64)
    for pad in ("auto", 2, 1.5, (16, 16), [16, 16], np.array([16, 16])):
        assert clholo.propagate(f, 1e-3, pad=pad, **_KW).shape == (8, 8)


@pytest.mark.parametrize("value", ["no", 0, 1, None])
def test_band_limit_must_be_a_bool(value):
    with pytest.raises(TypeError, match=r"^band_limit must be True or False"):
        clholo.propagate(np.ones((8, 8), np.complex64), 1e-3, band_limit=value, **_KW)
    m = MPI(*_mpi())
    with pytest.raises(TypeError, match=r"^band_limit must be True or False"):
        clholo.render_hologram(m, Optics(wavelengths=(520e-9,)), frames=1, band_limit=value)


def test_propagate_field_type_and_emptiness():
    with pytest.raises(TypeError, match=r"^field must be a NumPy or pyopencl array"):
        clholo.propagate([[1, 2], [3, 4]], 1e-3, **_KW)
    for shape in [(0, 8), (8, 0), (0, 8, 8)]:
        with pytest.raises(ValueError, match=r"^field must hold at least one pixel .*"
                           + re.escape(str(shape))):
            clholo.propagate(np.ones(shape, np.complex64), 1e-3, **_KW)


def test_queue_must_be_a_command_queue():
    m, o = MPI(*_mpi()), Optics(wavelengths=(520e-9,))
    for call in (lambda: clholo.render_hologram(m, o, frames=1, queue="gpu"),
                 lambda: list(clholo.iter_hologram_frames(m, o, frames=1, queue="gpu")),
                 lambda: clholo.focal_stack(np.ones((1, 1, 8, 8), np.complex64), o, [1e-3],
                                            queue="gpu"),
                 lambda: clholo.propagate(np.ones((8, 8), np.complex64), 1e-3, queue="gpu",
                                          **_KW)):
        with pytest.raises(TypeError, match=r"^queue must be a pyopencl.CommandQueue"):
            call()


@pytest.mark.parametrize("alpha_shape", [(2, 3, 16), (2, 16, 24)])
def test_mpi_channels_first_colour_named(alpha_shape):
    color = np.random.default_rng(0).random((2, 3, 16, 24)).astype(np.float32)
    with pytest.raises(ValueError, match=r"^color has shape \(2, 3, 16, 24\), which reads as "
                                         r"channels-first .*np\.moveaxis\(color, 1, -1\)"):
        MPI(color, np.ones(alpha_shape, np.float32), [1e-3, 2e-3])
    # channels-last of the same scene is taken
    assert MPI(np.moveaxis(color, 1, -1), np.ones((2, 16, 24)), [1e-3, 2e-3]).channels == 3


# 7. clholo encode's implausible values; clholo report's empty --title

from clholo import cli  # noqa: E402


def _holo_file(tmp_path):
    rng = np.random.default_rng(1)
    field = (rng.standard_normal((1, 1, 16, 24))
             + 1j * rng.standard_normal((1, 1, 16, 24))).astype(np.complex64)
    path = tmp_path / "holo.npz"
    clholo.io.write_hologram(path, field, pitch=8e-6, wavelengths=[520e-9])
    return path


@pytest.mark.parametrize("amax, what", [("1e-30", "far below"), ("1e30", "far above")])
def test_encode_warns_of_an_amax_far_outside_the_amplitudes(tmp_path, capsys, amax, what):
    holo = _holo_file(tmp_path)
    assert cli.main(["encode", str(holo), "--method", "dpac", "--amax", amax, "--slm-size",
                     "16", "24", "--progress", "off", "--out", str(tmp_path / "o")]) == 0
    err = [ln for ln in capsys.readouterr().err.splitlines() if "warning" in ln]
    assert len(err) == 1 and err[0].startswith("clholo encode: warning: --amax ") and what in err[0]
    # a plausible amax says nothing
    assert cli.main(["encode", str(holo), "--method", "dpac", "--amax", "2", "--slm-size", "16",
                     "24", "--progress", "off", "--out", str(tmp_path / "p")]) == 0
    assert "warning" not in capsys.readouterr().err


@pytest.mark.parametrize("argv, named", [
    (["--tol", "0", "--iterations", "1000000000"], "argument --iterations: must be <= "),
    (["--check-every", "1000000000"], "argument --check-every: must be <= "),
    (["--lr", "1e9"], "argument --lr: must be in [1e-07, 6.283]"),
    (["--lr", "1e-12"], "argument --lr: must be in [1e-07, 6.283]"),
])
def test_encode_refuses_implausible_sgd_options(tmp_path, capsys, monkeypatch, argv, named):
    import clholo.encode.sgd

    def ran(*a, **k):  # without the check, a billion iterations would run for days
        raise AssertionError(f"encode ran with {argv}")

    monkeypatch.setattr(clholo.encode.sgd, "sgd_encode", ran)
    holo = _holo_file(tmp_path)
    with pytest.raises(SystemExit) as exc:
        cli.main(["encode", str(holo), *argv, "--out", str(tmp_path / "o")])
    assert exc.value.code == 2
    assert named in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


def test_report_refuses_an_empty_title(tmp_path, capsys):
    with pytest.raises(SystemExit) as exc:
        cli.main(["report", str(tmp_path), "--title", ""])
    assert exc.value.code == 2
    assert "argument --title: the value is empty" in capsys.readouterr().err


# 8. an OSError while writing names the path (and --out)

def test_out_name_too_long_is_a_usage_error_naming_out(tmp_path, capsys, monkeypatch):
    holo = _holo_file(tmp_path)
    monkeypatch.chdir(tmp_path)
    assert cli.main(["encode", str(holo), "--method", "dpac", "--out", "x" * 300]) == 2
    err = capsys.readouterr().err
    assert err.startswith("clholo encode: error: argument --out: xxx") and "shorter --out" in err


@pytest.mark.parametrize("filename", [None, "inside"])
def test_disk_full_names_the_output(tmp_path, capsys, monkeypatch, filename):
    import errno

    from clholo.encode import quantize as q

    holo = _holo_file(tmp_path)
    out = tmp_path / "o"

    def full(*a, **k):
        raise OSError(errno.ENOSPC, "No space left on device",
                      *([str(tmp_path / ".o.x1y2.tmp" / "frame000_c0.png")] if filename else []))

    monkeypatch.setattr(q, "write_pattern_pngs", full)
    assert cli.main(["encode", str(holo), "--method", "dpac", "--progress", "off", "--out",
                     str(out)]) == 3
    err = capsys.readouterr().err
    assert "No space left on device while writing the output --out " + str(out) in err


def test_renderer_refuses_a_queue_name_and_non_bool_flags(queue, rng):
    """``HologramRenderer`` used directly checks its queue and yes/no options by name, as
    ``render_hologram`` does (a device name is no queue; ``"no"`` would count as true)."""
    from clholo.host.scheduler import HologramRenderer

    mpi = clholo.MPI(rng.random((2, 16, 24, 1)), rng.random((2, 16, 24)), [1e-3, 2e-3])
    optics = clholo.Optics(wavelengths=(520e-9,))
    with pytest.raises(TypeError, match="queue must be a pyopencl.CommandQueue"):
        HologramRenderer(mpi, optics, queue="gpu")
    with pytest.raises(TypeError, match="band_limit must be True or False"):
        HologramRenderer(mpi, optics, queue=queue, band_limit="no")
    with pytest.raises(TypeError, match="occlusion must be True or False"):
        HologramRenderer(mpi, optics, queue=queue, occlusion=0.5)


@pytest.mark.parametrize("pad", [True, None, (32.5, 40)])
def test_reference_propagation_checks_pad_like_the_device(pad):
    """The NumPy oracle takes the device's padding forms only: a bool is no factor, a shape
    holds whole pixels."""
    from clholo import reference as ref

    with pytest.raises(TypeError, match="pad"):
        ref.propagate(np.ones((8, 8), np.complex128), 1e-3, wavelength=520e-9, pitch=8e-6,
                      pad=pad)


def test_cli_shows_clholo_warnings_as_one_line(capsys):
    """A warning of clholo's own while a command runs is one line naming the command, as the
    commands' own warning lines are; a library's keeps Python's form; --debug keeps it too."""
    import warnings

    from clholo import cli
    from clholo.io.splats import SplatCullWarning

    with cli._warnings_as_lines("render", False):
        warnings.warn("12 of 50 splats lie behind the camera", SplatCullWarning)
        with pytest.warns(DeprecationWarning, match="a library's note"):  # Python's path
            warnings.warn("a library's note", DeprecationWarning)
    err = capsys.readouterr().err.splitlines()
    assert err == ["clholo render: warning: 12 of 50 splats lie behind the camera"]
    with cli._warnings_as_lines("render", True), pytest.warns(SplatCullWarning):
        warnings.warn("12 of 50 splats lie behind the camera", SplatCullWarning)
    assert capsys.readouterr().err == ""


# 8. what an audit of the API found (eighteenth session): each refused by name

def _holograms(rng, T=1, C=1, H=16, W=24):
    return (rng.standard_normal((T, C, H, W))
            + 1j * rng.standard_normal((T, C, H, W))).astype(np.complex64)


def test_rgbd_float_colour_outside_0_1_is_refused_not_clipped_to_white():
    from clholo.baselines.rgbd import rgbd_layers
    from clholo.io.rgbd import rgbd_to_mpi

    rng = np.random.default_rng(3)
    img, dep = rng.random((16, 24, 3)), rng.random((16, 24)) + 0.5
    kw = dict(layers=3, near=2e-3, far=4e-3)
    with pytest.raises(ValueError, match="image as floats.*divide by 255"):
        rgbd_layers(img * 255, dep, **kw)
    with pytest.raises(ValueError, match=r"image as floats.*\[-0\.4"):
        rgbd_to_mpi(img - 0.5, dep, **kw)
    bad = img.copy()
    bad[2, 3, 1] = np.nan
    with pytest.raises(ValueError, match="image contains NaN"):
        rgbd_to_mpi(bad, dep, **kw)
    # in range, and the uint8 form of the same image, still work
    assert rgbd_to_mpi(img, dep, **kw).layers == 3
    assert rgbd_to_mpi((img * 255).astype(np.uint8), dep, **kw).layers == 3
    with pytest.raises(TypeError, match="near must be a real number"):
        rgbd_to_mpi(img, dep, layers=3, near="a", far=4e-3)


@pytest.mark.parametrize("depth_range, kind, match", [
    ((np.nan, 1.0), "depth", "depth_range must be finite"),
    ((2.0, 0.1), "depth", "closest value is the smaller one"),
    ((0.1, 2.0), "disparity", "closest value is the larger one"),
    ((1.0, 1.0), "depth", "closest value"),
    (1.0, "depth", r"depth_range must be \(closest, farthest\)"),
    ((1.0, 2.0, 3.0), "depth", r"depth_range must be \(closest, farthest\)")])
def test_rgbd_depth_range_is_two_finite_values_closest_first(depth_range, kind, match):
    from clholo.io.rgbd import rgbd_to_mpi

    rng = np.random.default_rng(4)
    img, dep = rng.random((16, 24, 3)), rng.random((16, 24)) + 0.5
    with pytest.raises((ValueError, TypeError), match=match):
        rgbd_to_mpi(img, dep, layers=3, near=2e-3, far=4e-3, depth_kind=kind,
                    depth_range=depth_range)
    good = (0.5, 1.5) if kind == "depth" else (1.5, 0.5)
    m = rgbd_to_mpi(img, dep, layers=3, near=2e-3, far=4e-3, depth_kind=kind,
                    depth_range=good)
    assert m.alpha.sum() == 16 * 24


def _queue_calls(rng):
    from clholo import encode, rayoptics, views

    opt = Optics(pitch=8e-6, wavelengths=(520e-9,))
    h = _holograms(rng)
    m = MPI(*_mpi(H=16, W=24))
    return {
        "pupil_view": lambda q: views.pupil_view(h, opt, focus_depth=2e-3,
                                                 angles_rad=[(0, 0)], queue=q),
        "light_field": lambda q: views.light_field(h, opt, window=8, queue=q),
        "orthographic_view": lambda q: rayoptics.orthographic_view(m, 8e-6, queue=q),
        "fft2": lambda q: clholo.fft.fft2(h[0, 0], queue=q),
        "FFTPlan": lambda q: clholo.fft.FFTPlan((16, 24), np.complex64, queue=q),
        "sgd_encode": lambda q: encode.sgd_encode(h, opt, iterations=1, progress=False,
                                                  queue=q),
        "dpac_encode": lambda q: encode.dpac_encode(h, opt, queue=q),
        "phase_to_hologram": lambda q: encode.phase_to_hologram(
            rng.uniform(0, 6, (1, 1, 16, 24)), opt, queue=q),
    }


@pytest.mark.parametrize("what", ["pupil_view", "light_field", "orthographic_view", "fft2",
                                  "FFTPlan", "sgd_encode", "dpac_encode", "phase_to_hologram"])
def test_a_queue_that_is_not_a_queue_is_refused_by_name(what):
    call = _queue_calls(np.random.default_rng(5))[what]
    with pytest.raises(TypeError, match="queue must be a pyopencl.CommandQueue"):
        call("gpu")
    call(None)      # the default device: runs


def test_yes_no_options_take_only_bools():
    from clholo import encode, rayoptics, views

    rng = np.random.default_rng(6)
    opt = Optics(pitch=8e-6, wavelengths=(520e-9,))
    h = _holograms(rng)
    m = MPI(*_mpi(H=16, W=24))
    with pytest.raises(TypeError, match="premultiplied must be True or False"):
        rayoptics.orthographic_view(m, 8e-6, angle_rad=(0.01, 0), premultiplied="no")
    with pytest.raises(TypeError, match="band_limit must be True or False"):
        views.pupil_view(h, opt, focus_depth=2e-3, angles_rad=[(0, 0)], band_limit="no")
    with pytest.raises(TypeError, match="prefilter must be True or False"):
        encode.dpac_encode(h, opt, prefilter="no")
    with pytest.raises(TypeError, match="progress must be True"):
        encode.sgd_encode(h, opt, iterations=1, progress="no")
    with pytest.raises(TypeError, match="inverse must be True or False"):
        clholo.fft.FFTPlan((16, 24), np.complex64).execute_host(h[0, 0], inverse="yes")


def test_fft_of_nan_is_refused():
    x = np.ones((16, 24), np.complex64)
    x[3, 4] = np.nan
    with pytest.raises(ValueError, match="NaN/inf"):
        clholo.fft.fft2(x)
    with pytest.raises(ValueError, match="NaN/inf"):
        clholo.fft.ifft2(x)
    with pytest.raises(ValueError, match="x contains NaN/inf"):
        clholo.fft.FFTPlan((16, 24), np.complex64).execute_host(x)


def test_gray_levels_are_not_taken_for_radians():
    from clholo.encode import phase_to_hologram
    from clholo.encode.quantize import dequantize, quantize

    opt = Optics(pitch=8e-6, wavelengths=(520e-9,))
    gray = np.full((1, 1, 16, 24), 128, np.uint8)
    with pytest.raises(TypeError, match="looks like SLM gray levels.*dequantize"):
        phase_to_hologram(gray, opt)
    with pytest.raises(TypeError, match="phase must be real phases"):
        quantize(quantize(np.zeros((1, 4, 4))))
    # the fix the message gives works; signed integers are still radians
    assert phase_to_hologram(dequantize(gray, "linear"), opt).shape == gray.shape
    assert quantize(np.zeros((1, 4, 4), np.int32)).dtype == np.uint8


def test_display_loop_and_dpac_encoder_check_their_objects_at_once():
    from clholo.encode import phase_to_hologram
    from clholo.host.display_loop import DisplayLoop, dpac_encoder, phase_quantize_encoder
    from clholo.tools.slm import MemoryDisplay

    opt = Optics(pitch=8e-6, wavelengths=(520e-9,))
    m = MPI(*_mpi(H=16, W=24))
    display = MemoryDisplay(24, 16)
    with pytest.raises(TypeError, match="encode must be a callable"):
        DisplayLoop(m, opt, display, None)
    with pytest.raises(TypeError, match="optics must be a clholo.Optics"):
        DisplayLoop(m, None, display, phase_quantize_encoder())
    with pytest.raises(TypeError, match="display must be a clholo.tools.slm.Display"):
        DisplayLoop(m, opt, None, phase_quantize_encoder())
    with pytest.raises(ValueError, match="z_slm"):
        dpac_encoder(opt, z_slm=0)
    with pytest.raises(ValueError, match="cutoff"):
        dpac_encoder(opt, cutoff=5)
    with pytest.raises(TypeError, match="cutoff must be a real number"):
        dpac_encoder(opt, cutoff="half")
    with pytest.raises(TypeError, match="optics must be a clholo.Optics"):
        dpac_encoder(None)
    with pytest.raises(TypeError, match="queue must be"):
        phase_quantize_encoder(queue="gpu")
    with pytest.raises(TypeError, match="optics must be a clholo.Optics"):
        phase_to_hologram(np.zeros((1, 1, 16, 24)), None)


def test_dpac_amax_and_cutoff_are_numbers():
    from clholo import encode

    rng = np.random.default_rng(7)
    opt = Optics(pitch=8e-6, wavelengths=(520e-9,))
    h = _holograms(rng)
    with pytest.raises(TypeError, match="amax must be a real number"):
        encode.dpac_encode(h, opt, amax="1")
    with pytest.raises(TypeError, match="cutoff must be a real number"):
        encode.dpac_encode(h, opt, cutoff="half")
    with pytest.raises(TypeError, match="cutoff must be a real number"):
        encode.dpac_encode(h, opt, cutoff=np.array([0.5, 0.5]))


def test_scores_refuse_nonsense():
    from clholo import metrics

    rng = np.random.default_rng(8)
    a, b = rng.random((16, 16, 3)), rng.random((16, 16, 3))
    with pytest.raises(ValueError, match="same shape"):
        metrics.scale_fit(a, b[:8])
    with pytest.raises(ValueError, match="image contains NaN"):
        metrics.scale_fit(np.full_like(a, np.nan), b)
    for bad in (None, [], ()):
        with pytest.raises(ValueError, match="metrics must be a non-empty sequence"):
            metrics.score(a, b, metrics=bad)
    with pytest.warns(UserWarning, match="data_range 255 is .*x the reference's maximum"):
        metrics.score(a, b, data_range=255)
    assert set(metrics.score(a, b, metrics=("psnr",))) == {"scale", "psnr"}


def test_mpi_placed_and_perspective_view_name_the_argument():
    from clholo import rayoptics

    m = MPI(*_mpi(H=16, W=24))
    with pytest.raises(ValueError, match="far must be finite"):
        m.placed(1e-3, np.inf)
    with pytest.raises(TypeError, match="near must be a real number"):
        m.placed("a", 2e-3)
    for kw, name in ((dict(translation=0.1), "translation"), (dict(translation=None),
                                                               "translation"),
                     (dict(principal_point=5), "principal_point"),
                     (dict(depths=["a", "b"]), "depths")):
        with pytest.raises(ValueError, match=f"^{name} must be"):
            rayoptics.perspective_view(m, fx_pixels=100, **kw)
    with pytest.raises(ValueError, match="shifts_px must be"):
        rayoptics.shift_homographies(3.0)


def test_render_out_mistakes_say_what_to_do(queue):
    import pyopencl as cl
    import pyopencl.array as cla

    from clholo import render_hologram

    m = MPI(*_mpi(H=16, W=24))
    opt = Optics(pitch=8e-6, wavelengths=(520e-9,))
    with pytest.raises(ValueError, match="out must be a pyopencl device array.*leave out= off"):
        render_hologram(m, opt, frames=2, out=np.empty((2, 1, 16, 24), np.complex64),
                        queue=queue)
    other = cl.CommandQueue(cl.Context([queue.device]))
    with pytest.raises(ValueError, match="another OpenCL context.*queue=out.queue"):
        render_hologram(m, opt, frames=1, out=cla.empty(other, (1, 1, 16, 24), np.complex64),
                        queue=queue)
    with pytest.raises(MemoryError, match="frames=1000000000 .*iter_hologram_frames"):
        render_hologram(m, opt, frames=10**9, queue=queue)


def test_cli_shows_numpy_value_warnings_from_clholo_as_one_line(capsys):
    """NumPy's warnings about values (overflow, a dropped imaginary part) raised in clholo's
    code while a command runs: one line naming the place, not Python's form with a code line;
    the same warning from elsewhere (a user's script) keeps Python's form."""
    import warnings

    from clholo import cli

    here = cli.__file__
    with cli._warnings_as_lines("encode", False):
        warnings.warn_explicit("overflow encountered in cast", RuntimeWarning, here, 12)
        with pytest.warns(RuntimeWarning, match="elsewhere"):
            warnings.warn_explicit("elsewhere", RuntimeWarning, "/tmp/script.py", 3)
    err = capsys.readouterr().err.splitlines()
    assert err == ["clholo encode: warning: overflow encountered in cast (NumPy, in "
                   "clholo/cli.py:12: check the input's values)"]


def test_a_far_distance_warns_once_at_the_users_line():
    """One mistake, one DepthWarning, pointing at the caller (the transfer function built
    behind the cache does not warn again from inside clholo); a direct build still warns."""
    import warnings

    from clholo.propagation import build_transfer_function, propagate
    from clholo.validate import DepthWarning

    with warnings.catch_warnings(record=True) as got:
        warnings.simplefilter("always")
        propagate(np.ones((16, 16), np.complex64), 5.5, wavelength=520e-9, pitch=8e-6)
    far = [w for w in got if issubclass(w.category, DepthWarning)]
    assert len(far) == 1 and far[0].filename == __file__, [(w.filename, w.lineno) for w in far]
    with pytest.warns(DepthWarning, match="dz=5.5 m"):
        build_transfer_function(clholo.host.runtime.get_queue(), (16, 16), 5.5,
                                wavelengths=[520e-9], pitch=8e-6)

