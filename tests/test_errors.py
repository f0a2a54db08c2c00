"""Bad input gets a clear error that names the argument and the fix (issue 8, item 2).

One table per entry (the Python API, the command line); ``docs/errors.md`` lists the same cases
and what each gets. Every case asserts the exception type and that the message names the
argument (and, where there is one, the unit hint or the fix).
"""

import warnings

import numpy as np
import pytest

import clholo
from clholo import cli
from clholo.validate import DepthWarning

LAM, P = 520e-9, 8e-6
F = np.ones((8, 8), np.complex64)


def _mpi(depths=(1e-3, 2e-3), H=8, W=8, **over):
    L = len(depths)
    args = dict(color=np.full((L, H, W, 3), 0.5), alpha=np.full((L, H, W), 0.5), depths=depths)
    args.update(over)
    return clholo.MPI(**args)


def _frames(**kwargs):
    return list(clholo.iter_hologram_frames(_mpi(), clholo.Optics(), frames=2, **kwargs))


def _device_quantize(bad):
    from clholo.encode.quantize import DeviceQuantizer

    phase = np.zeros((1, 3, 4, 4), np.float32)
    phase[0, 1, 2, 2] = bad
    return DeviceQuantizer(["linear", "linear:230", "linear:200"], 3)(phase)


# (what, call, exception, regex the message must match)
def _edit_checked_mpi():
    mpi = _mpi()
    mpi.alpha[0] = 7.0  # after the MPI checked alpha: refused, not rendered


def _quantize_complex():
    from clholo.encode.quantize import quantize

    quantize(np.ones((1, 8, 8), np.complex64), ["linear:256"])


API_CASES = [
    ("Optics: wavelength in nanometres", lambda: clholo.Optics(wavelengths=(638, 520, 450)),
     ValueError, r"wavelengths=638 is not a wavelength in metres.*e\.g\. 520e-9"),
    ("Optics: pitch in micrometres", lambda: clholo.Optics(pitch=8),
     ValueError, r"pitch=8 m is larger than a millimetre.*8e-6"),
    ("Optics: wavelength not below twice the pitch",
     lambda: clholo.Optics(pitch=0.5e-6, wavelengths=(1.5e-6,)),
     ValueError, r"wavelengths 1\.5e-06 m is not smaller than twice the pitch 5e-07 m"),
    ("Optics: wavelength of 1 nm (a unit slip)",
     lambda: clholo.Optics(wavelengths=(1e-9, 1e-9, 1e-9)),
     ValueError, r"wavelengths=1e-9 m is outside 0\.2-2 um, the wavelengths a holographic "
                 r"display can use: did you mean 1e-6\?"),
    ("Optics: wavelength of 5 um", lambda: clholo.Optics(wavelengths=(5e-6,)),
     ValueError, r"wavelengths=5e-6 m is outside 0\.2-2 um.*give metres, e\.g\. 520e-9"),
    ("propagate: wavelength in nanometres",
     lambda: clholo.propagate(F, 1e-3, wavelength=520, pitch=P),
     ValueError, r"wavelength=520 is not a wavelength in metres.*520 nm is 5.2e-07 m"),
    ("propagate: wavelength of exactly twice the pitch",
     lambda: clholo.propagate(F, 1e-3, wavelength=1.2e-6, pitch=0.6e-6),
     ValueError, r"wavelength 1\.2e-06 m is not smaller than twice the pitch 6e-07 m"),
    ("propagate: wavelength in picometres' place",
     lambda: clholo.propagate(F, 1e-3, wavelength=520e-12, pitch=P),
     ValueError, r"wavelength=5\.2e-10 m is outside 0\.2-2 um.*did you mean 5\.2e-7\?"),
    ("propagate: pitch in micrometres", lambda: clholo.propagate(F, 1e-3, wavelength=LAM, pitch=8),
     ValueError, r"pitch=8 m is larger than a millimetre"),
    ("propagate: distance as text", lambda: clholo.propagate(F, "1mm", wavelength=LAM, pitch=P),
     TypeError, r"dz must be a real number, got '1mm'"),
    ("propagate: float field", lambda: clholo.propagate(F.real, 1e-3, wavelength=LAM, pitch=P),
     TypeError, r"field must be complex64 or complex128.*astype"),
    ("render: fractional seed", lambda: clholo.render_hologram(_mpi(), clholo.Optics(), seed=1.5),
     TypeError, r"seed must be an integer .*got 1\.5.*truncated"),
    ("render: seed as text", lambda: clholo.render_hologram(_mpi(), clholo.Optics(), seed="abc"),
     TypeError, r"seed must be an integer in \[0, 2\*\*64\), got 'abc'"),
    ("render: negative seed", lambda: clholo.render_hologram(_mpi(), clholo.Optics(), seed=-1),
     ValueError, r"seed must lie in \[0, 2\*\*64\), got -1"),
    ("render: frames=True", lambda: clholo.render_hologram(_mpi(), clholo.Optics(), frames=True),
     TypeError, r"frames must be a whole number >= 1, got True"),
    ("render: frames=0", lambda: clholo.render_hologram(_mpi(), clholo.Optics(), frames=0),
     ValueError, r"frames must be >= 1, got 0"),
    ("render: memory budget too small",
     lambda: clholo.render_hologram(_mpi(), clholo.Optics(), frames=1, memory_budget=1000),
     MemoryError, r"memory_budget"),
    ("iter_hologram_frames: frames_per_batch=0", lambda: _frames(frames_per_batch=0),
     ValueError, r"frames_per_batch must be >= 1, got 0"),
    ("render: channels and wavelengths differ",
     lambda: clholo.render_hologram(_mpi(), clholo.Optics(wavelengths=(LAM,))),
     ValueError, r"3 colour channel\(s\) but optics has 1 wavelength"),
    ("MPI: 0 x 0 layers", lambda: _mpi(H=0, W=0),
     ValueError, r"color must have at least 1 x 1 pixels"),
    ("MPI: alpha outside [0, 1]", lambda: _mpi(alpha=np.full((2, 8, 8), 1.5)),
     ValueError, r"alpha must lie in \[0, 1\]"),
    ("MPI: colour outside [0, 1]", lambda: _mpi(color=np.full((2, 8, 8, 3), 255.0)),
     ValueError, r"color must be linear intensity in \[0, 1\].*decode sRGB"),
    ("MPI: NaN in alpha", lambda: _mpi(alpha=np.full((2, 8, 8), np.nan)),
     ValueError, r"alpha contains 128 NaN/inf"),
    ("MPI: negative depth", lambda: _mpi(depths=(-1e-3, 2e-3)),
     ValueError, r"depths must be > 0 metres behind the hologram plane.*placed"),
    ("MPI: duplicate depths", lambda: _mpi(depths=(2e-3, 2e-3)),
     ValueError, r"depths must be distinct"),
    ("focal_stack: NaN depth",
     lambda: clholo.focal_stack(np.ones((1, 1, 8, 8), np.complex64),
                                clholo.Optics(wavelengths=(LAM,)), [np.nan]),
     ValueError, r"depths must be finite"),
    ("focal_stack: depths as text",
     lambda: clholo.focal_stack(np.ones((1, 1, 8, 8), np.complex64),
                                clholo.Optics(wavelengths=(LAM,)), "far"),
     TypeError, r"depths must be numbers in metres"),
    ("focal_stack: memory budget too small",
     lambda: clholo.focal_stack(np.ones((1, 1, 8, 8), np.complex64),
                                clholo.Optics(wavelengths=(LAM,)), [1e-3], memory_budget=10),
     MemoryError, r"memory_budget"),
    ("DeviceQuantizer: NaN phase", lambda: _device_quantize(np.nan),
     ValueError, r"phase contains NaN/inf values \(colour 1, lookup table linear:230; "
                 r"quantised on the device\): no pattern is made from them"),
    ("DeviceQuantizer: phase beyond its tables",
     lambda: _device_quantize(7.0),
     ValueError, r"phase of colour 1, lookup table linear:230 has values above \[-6.283185, "
                 r"6.283185\] rad, the range the device's tables cover: give DeviceQuantizer a "
                 r"phase_range=\(lo, hi\) that holds them"),
    ("MPI: an array edited after the check", _edit_checked_mpi,
     ValueError, r"assignment destination is read-only"),
    ("MPI: colour channels first",
     lambda: clholo.MPI(np.random.rand(2, 3, 8, 24), np.random.rand(2, 3, 8), [1e-3, 2e-3]),
     ValueError, r"reads as channels-first colour \(L, C, H, W\) with C = 3.*np.moveaxis"),
    ("propagate: band_limit as text",
     lambda: clholo.propagate(F, 1e-3, wavelength=LAM, pitch=P, band_limit="no"),
     TypeError, r"band_limit must be True or False, got 'no'"),
    ("propagate: pad=True", lambda: clholo.propagate(F, 1e-3, wavelength=LAM, pitch=P, pad=True),
     TypeError, r"pad must be 'auto', a factor >= 1 .* got True \(a bool, not a factor\)"),
    ("render: queue as a device name",
     lambda: clholo.render_hologram(_mpi(), clholo.Optics(), queue="gpu"),
     TypeError, r"queue must be a pyopencl.CommandQueue or None .* got 'gpu'"),
    ("quantize: complex phase", _quantize_complex,
     TypeError, r"phase must be real phases in radians, got complex values"),
]


@pytest.mark.parametrize("what,call,exc,match", API_CASES, ids=[c[0] for c in API_CASES])
def test_api_errors_name_the_argument(what, call, exc, match):
    with pytest.raises(exc, match=match):
        call()


@pytest.mark.parametrize("what,call", [
    ("render with depths in scene units",
     lambda: clholo.render_hologram(_mpi(depths=(1.0, 2.0)), clholo.Optics(), frames=1)),
    ("propagate by 2 m", lambda: clholo.propagate(F, 2.0, wavelength=LAM, pitch=P)),
])
def test_metres_that_look_like_scene_units_warn(what, call):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        call()
    depth_warnings = [w for w in caught if issubclass(w.category, DepthWarning)]
    assert depth_warnings and "more than 1 m" in str(depth_warnings[0].message)
    assert depth_warnings[0].filename == __file__  # points at the caller's line


# (argv, regex the one-line error must match); exit code 2 for each
CLI_CASES = [
    (["render", "x", "--frames", "-2"], r"argument --frames: must be >= 1, got -2"),
    (["render", "x", "--frames", "1.5"], r"argument --frames: expected a whole number"),
    (["demo", "--scale", "0"], r"argument --scale: must be a finite number > 0"),
    (["demo", "--scale", "0.01"], r"scale=0.01 shrinks the 741x500 scene to 7x5 pixels.*0\.032"),
    (["bench", "--size", "0"], r"argument --size: must be >= 8, got 0"),
    (["demo", "--pad", "0.5"], r"argument --pad: must be 'auto' or a factor >= 1"),
    (["demo", "--pitch", "8"], r"pitch=8\.0 m is larger than a millimetre"),
    (["demo", "--wavelengths", "520"], r"wavelengths=520\.0 is not a wavelength in metres"),
    (["demo", "--layers", "0"], r"argument --layers: must be >= 2, got 0"),
    (["render", "missing-scene-folder", "--near", "0.002", "--far", "0.004"],
     r"missing-scene-folder"),
]


@pytest.mark.parametrize("argv,match", CLI_CASES, ids=[" ".join(c[0]) for c in CLI_CASES])
def test_cli_errors_name_the_option(tmp_path, monkeypatch, capsys, argv, match):
    import re

    monkeypatch.chdir(tmp_path)
    try:
        rc = cli.main(argv + ["--out", str(tmp_path / "out")])
    except SystemExit as exc:  # argparse's own usage errors
        rc = exc.code
    assert rc == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert re.search(match, err), err
    assert not (tmp_path / "out").exists()


# --- issue 26, section 8: a wavelength between one and two pitches is physical ------------------

@pytest.mark.parametrize("ratio", [1.0, 1.5, 1.99])
def test_a_wavelength_between_one_and_two_pitches_is_accepted(ratio):
    """Only lambda >= 2 p is refused (nothing but the zero order can leave the SLM); between one
    and two pitches the first orders still diffract, at asin(lambda / (2 p)) up to 90 degrees."""
    pitch = 1e-6
    lam = ratio * pitch
    optics = clholo.Optics(pitch=pitch, wavelengths=(lam,))
    assert optics.wavelengths == (lam,)
    out = clholo.propagate(F, 1e-5, wavelength=lam, pitch=pitch)
    assert out.shape == F.shape and np.all(np.isfinite(out)) and np.abs(out).max() > 0
    with pytest.raises(ValueError, match="not smaller than twice the pitch"):
        clholo.Optics(pitch=pitch, wavelengths=(2 * pitch,))


@pytest.mark.parametrize("value,exc,match", [
    (0.0, ValueError, r"d_m = 0.0 must be > 0 metres, e\.g\. 0\.2"),
    (-0.1, ValueError, r"must be > 0 metres"),
    (200, ValueError, r"d_m = 200 is more than a metre: d_m is in metres \(millimetres given\?\)"),
    (float("nan"), ValueError, r"d_m must be finite"),
    ("0.2", TypeError, r"d_m must be a real number"),
])
def test_bench_metres_refuses_what_the_bench_file_refuses(value, exc, match):
    # one rule for the bench file and the capture sweeps' Python API
    from clholo.validate import bench_metres

    with pytest.raises(exc, match=match):
        bench_metres("d_m", value, example="0.2")


@pytest.mark.parametrize("value", [1e-6, 0.2, 1.0])
def test_bench_metres_takes_metres_up_to_one(value):
    from clholo.validate import bench_metres

    assert bench_metres("d_m", value, example="0.2") == value
