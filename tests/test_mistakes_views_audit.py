"""Operators on holograms given what a researcher could plausibly get wrong, found by an audit
(2026-11-29, seventh session): each gave a wrong but plausible image, or an all-black one, with
exit 0; each is now right, or refused by name."""

import math

import numpy as np
import pytest

from clholo import views
from clholo.scene import Optics


def _edge_stripe(H=32, W=64):
    u = np.zeros((1, 1, H, W), np.complex64)
    u[0, 0, :, 0:2] = 1.0  # light on the left edge only
    return u


@pytest.mark.parametrize("focus_depth", [0.0, 1e-3])
def test_pupil_blur_does_not_wrap_round_the_view(queue, focus_depth):
    """pad="auto" padded for the refocus only: at focus 0 the pupil's blur was a circular
    convolution, the right edge as bright as the lit left edge (0.023 against 1.7e-4)."""
    optics = Optics(wavelengths=(520e-9,))
    u = _edge_stripe()
    kw = dict(focus_depth=focus_depth, angles_rad=[(0.0, 0.0)], pupil_angle_rad=0.003,
              queue=queue)
    auto = views.pupil_view(u, optics, pad="auto", **kw)[0, 0]
    linear = views.pupil_view(u, optics, pad=2, **kw)[0, 0]
    circular = views.pupil_view(u, optics, pad=1, **kw)[0, 0]
    right = slice(-4, None)
    assert circular[:, right].mean() > 20 * linear[:, right].mean()  # the wrap is visible
    np.testing.assert_allclose(auto[:, right].mean(), linear[:, right].mean(), rtol=0.05)


def test_pupil_padding_grows_with_the_pupils_point_spread():
    from clholo.views import PUPIL_PSF_WIDTHS, _pupil_padded_shape

    radii = np.array([0.005 / 638e-9, 0.005 / 450e-9])  # cycles/m
    margin = math.ceil(PUPIL_PSF_WIDTHS / (radii.min() * 8e-6))
    Hp, Wp = _pupil_padded_shape((1080, 1920), (1100, 1944), radii, 8e-6)
    assert Hp >= 1100 + margin and Wp >= 1944 + margin
    # never beyond twice the field, where the convolution is linear already
    assert _pupil_padded_shape((32, 64), (40, 72), radii / 100, 8e-6) == (64, 128)


@pytest.mark.parametrize("kw, said", [
    (dict(pupil_angle_rad=1e-4), r"sin\(pupil_angle_rad\) = 0\.0001"),
    (dict(pupil_diameter_m=2e-6, fourier_focal_length_m=0.2),
     r"pupil_diameter_m / \(2 fourier_focal_length_m\) = 5e-06"),
])
def test_pupil_narrower_than_a_frequency_bin_is_refused(queue, kw, said):
    """It held no bin: an all-black view (or one without red) and exit 0."""
    optics = Optics()
    rng = np.random.default_rng(3)
    h = np.exp(2j * np.pi * rng.random((1, 3, 64, 64))).astype(np.complex64)
    with pytest.raises(ValueError, match=rf"^the pupil's radius is 0\.\d+ frequency bins of "
                                         rf"the \d+x\d+ padded grid at 638 nm \({said}\).* "
                                         rf"use a pupil half-angle of at least"):
        views.pupil_view(h, optics, focus_depth=3e-3, angles_rad=[(0.01, 0.0)], queue=queue,
                         **kw)
    # on a grid that is not square (bins of two sizes) at a fixed pad: the smallest half-angle
    # the message names is accepted, and every colour sees light
    wide = h[..., :32, :]
    with pytest.raises(ValueError) as info:
        views.pupil_view(wide, optics, focus_depth=3e-3, angles_rad=[(0.01, 0.0)], queue=queue,
                         pad=2, **kw)
    smallest = float(str(info.value).split("at least ")[1].split(" rad")[0])
    v = views.pupil_view(wide, optics, focus_depth=3e-3, angles_rad=[(0.01, 0.0)], queue=queue,
                         pad=2, pupil_angle_rad=smallest * 1.01)
    assert np.all(v.reshape(3, -1).max(axis=1) > 0)


# units of the operators' own arguments

def test_pitch_below_a_tenth_of_a_micron_is_refused():
    """8e-9 for 8 um gave an all-black orthographic view: validate.pitch had no lower bound."""
    from clholo import rayoptics, validate
    from clholo.errors import InputError
    from clholo.scene import MPI

    with pytest.raises(InputError, match=r"^pitch=8e-09 m is below 0\.1 um"):
        validate.pitch(8e-9)
    assert validate.pitch(validate.MIN_PITCH_M) == validate.MIN_PITCH_M
    mpi = MPI(color=np.ones((2, 8, 8, 1)), alpha=np.ones((2, 8, 8)) * 0.5, depths=[2e-3, 3e-3])
    with pytest.raises(InputError, match=r"^pitch=8e-09 m is below"):
        rayoptics.orthographic_view(mpi, 8e-9, angle_rad=(0.01, 0.0))


@pytest.mark.parametrize("kw, what", [
    (dict(dz=float("nan")), r"^dz must be finite"),
    (dict(dz=[1e-3, float("inf")]), r"^dz must be finite"),
    (dict(pitch=0.0), r"^pitch must be a positive length"),
    (dict(pitch=8.0), r"^pitch=8\.0 m is larger than a millimetre"),
    (dict(wavelength=520.0), r"^wavelength=520\.0 is not a wavelength in metres"),
    (dict(wavelength=[638e-9, -520e-9]), r"^wavelength must be a positive length"),
])
def test_device_padded_shape_checks_its_units(kw, what):
    """They gave ZeroDivisionError/OverflowError naming nothing, or a wrong grid (520 nm as
    520: 128x128 for 72x72)."""
    from clholo.errors import InputError
    from clholo.propagation import device_padded_shape

    args = dict(dz=1e-3, wavelength=520e-9, pitch=8e-6)
    assert device_padded_shape((64, 64), **args) == (72, 72)
    args.update(kw)
    with pytest.raises(InputError, match=what):
        device_padded_shape((64, 64), args.pop("dz"), **args)


# ray optics: exact displacements, pupils inside the band

def test_a_diagonal_ray_moves_by_its_exact_displacement(queue):
    """Direction sines (0.6, 0.6): a point 1 px per unit slope moves by sin / cos_z = 1.134
    per axis, not tan(asin 0.6) = 0.75 (the per-axis small-angle form)."""
    from clholo import rayoptics
    from clholo.scene import MPI

    p = 1e-6
    slope = 0.6 / math.sqrt(1 - 2 * 0.36)
    depth = 10 * p / slope  # a shift of exactly 10 px on each axis
    color = np.zeros((1, 64, 64, 1))
    alpha = np.zeros((1, 64, 64))
    color[0, 20, 20] = alpha[0, 20, 20] = 1.0
    mpi = MPI(color=color, alpha=alpha, depths=[depth])
    a = math.asin(0.6)
    view = rayoptics.orthographic_view(mpi, p, angle_rad=(a, a), queue=queue)[..., 0]
    assert np.unravel_index(np.argmax(view), view.shape) == (30, 30)
    np.testing.assert_allclose(view[30, 30], 1.0, atol=1e-5)
    # along one axis it is tan(theta), as before
    shifts = rayoptics.layer_shifts_px(np.array([depth]), 0.0, p, np.array([[a, 0.0]]))
    np.testing.assert_allclose(shifts[0, 0], [depth * math.tan(a) / p, 0.0], rtol=1e-12)
    with pytest.raises(ValueError, match=r"sin\^2 theta_x \+ sin\^2 theta_y >= 1: no ray"):
        rayoptics.orthographic_view(mpi, p, angle_rad=(1.0, 1.0), queue=queue)


@pytest.mark.parametrize("kw, said", [
    (dict(pupil_angle_rad=0.2), r"^pupil_angle_rad = 0\.2 rad for channel 0 \(638 nm\) is wider "
                                r"than the band"),
    (dict(pupil_angle_rad=[0.03, 0.03, 0.03]), r"^pupil_angle_rad = 0\.03 rad for channel 2 "
                                               r"\(450 nm\)"),
    (dict(pupil_angle_rad=0.005, pupil_center_rad=(0.035, 0.0)),
     r"^pupil_center_rad = \(0\.035, 0\.0\) rad lies beyond the largest angle the SLM sends"),
])
def test_incoherent_slice_pupil_beyond_the_band_is_refused(queue, kw, said):
    """A reference blurred by directions no hologram of these optics sends (pupil_view refuses
    the same pupils)."""
    from clholo import rayoptics
    from clholo.scene import MPI

    rng = np.random.default_rng(0)
    mpi = MPI(color=rng.random((2, 16, 16, 3)), alpha=rng.random((2, 16, 16)),
              depths=[2e-3, 3e-3])
    optics = Optics()
    with pytest.raises(ValueError, match=said):
        rayoptics.incoherent_focal_slice(mpi, optics, 3e-3, queue=queue, **kw)
    # the whole band of each colour (the default), and a pupil inside it, are taken
    rayoptics.incoherent_focal_slice(mpi, optics, 3e-3, queue=queue, samples=3)
    rayoptics.incoherent_focal_slice(mpi, optics, 3e-3, queue=queue, samples=3,
                                     pupil_angle_rad=[optics.max_angle_rad(c) for c in range(3)])


# scores

def _pair(seed=1):
    rng = np.random.default_rng(seed)
    ref = rng.random((32, 32, 3)) * 0.8
    img = np.clip(ref + 0.2 * rng.standard_normal(ref.shape), 0, 1)
    return img, ref


def test_data_range_far_below_the_images_is_refused():
    """data_range=1 for 0..255 images: PSNR -32.7 dB, and FLIP (both images clipped to white)
    scored an unrelated image 0.05, nearly identical."""
    from clholo import metrics
    from clholo.errors import InputError

    img, ref = _pair()
    with pytest.raises(InputError, match=r"^data_range 1 is \d+x below the reference's maximum"):
        metrics.score(img * 255, ref * 255, metrics=("psnr",), data_range=1.0)
    ok = metrics.score(img * 255, ref * 255, metrics=("psnr",), data_range=255.0)
    assert ok["psnr"] == pytest.approx(metrics.score(img, ref, metrics=("psnr",),
                                                     data_range=1.0)["psnr"])
    # a reference somewhat above its data range (highlights) is still taken
    metrics.score(img * 1.5, ref * 1.5, metrics=("psnr",), data_range=1.0)


@pytest.mark.parametrize("which", ["image", "reference"])
def test_integer_codes_against_floats_are_refused(which):
    """8-bit sRGB codes against linear floats: PSNR 4.8, SSIM 0.0002 for the same picture."""
    from clholo import metrics
    from clholo.errors import InputError

    img, ref = _pair()
    codes = np.round(255 * (img if which == "image" else ref)).astype(np.uint8)
    args = (codes, ref) if which == "image" else (img, codes)
    with pytest.raises(InputError, match=rf"^{which} holds uint8 codes and the other image "
                                         rf"floats: .*srgb_to_linear\({which} / 255\)"):
        metrics.score(*args, metrics=("psnr",), fit_scale=False)
    both = metrics.score(np.round(255 * img).astype(np.uint8), np.round(255 * ref).astype(
        np.uint8), metrics=("psnr",), data_range=255)  # codes against codes: taken
    assert both["psnr"] > 10


def test_negative_intensities_warn():
    """A field's real part scored as an intensity: PSNR 4.8 without a word."""
    import warnings

    from clholo import metrics

    img, ref = _pair()
    with pytest.warns(UserWarning, match=r"^image holds negative values \(down to -0\.5"):
        metrics.score(img - 0.5, ref, metrics=("psnr",))
    noisy = img - 0.1  # a dark-subtracted capture's noise: no warning
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        metrics.score(noisy, ref, metrics=("psnr",))


def test_too_wide_physical_pupil_names_the_argument_given():
    """It said "use a smaller pupil_angle_rad", an argument the caller never gave."""
    optics = Optics()
    h = np.ones((1, 3, 16, 16), np.complex64)
    with pytest.raises(ValueError, match=r"use a smaller pupil_diameter_m \(at most 0\.01595 m "
                                         r"at this focal length\)$"):
        views.pupil_view(h, optics, focus_depth=1e-3, angles_rad=[(0.0, 0.0)],
                         pupil_diameter_m=0.05, fourier_focal_length_m=0.2)
    with pytest.raises(ValueError, match=r"use a smaller pupil_angle_rad$"):
        views.pupil_view(h, optics, focus_depth=1e-3, angles_rad=[(0.0, 0.0)],
                         pupil_angle_rad=0.2)


# clholo report of files written by hand: units and intensities

def _report_folder(parent, *, views=None, focal=None):
    rng = np.random.default_rng(0)
    folder = parent / "run"
    folder.mkdir(parents=True)
    if views is not None:
        args = dict(angles_rad=np.array([-0.01, 0.0, 0.01]),
                    intensity=rng.random((3, 3, 16, 16)).astype(np.float32))
        args.update(views)
        np.savez(folder / "views.npz", **args)
    if focal is not None:
        args = dict(intensity=rng.random((2, 3, 16, 16)).astype(np.float32),
                    depths_m=np.array([2e-3, 4e-3]),
                    wavelengths_m=np.array([638e-9, 520e-9, 450e-9]))
        args.update(focal)
        np.savez(folder / "focal_stack.npz", **args)
    return folder


def _report(folder):
    from clholo import cli

    return cli.main(["report", str(folder), "--out", str(folder.parent / "report.html"),
                     "--progress", "off"])


@pytest.mark.parametrize("views, focal, said", [
    (dict(angles_rad=np.array([-1.0, 0.0, 1.0]) * 57.3), None,
     r"views\.npz: angles_rad holds -57\.3, not an angle in \(-pi/2, pi/2\) radians"),
    (dict(intensity=-np.ones((3, 3, 16, 16), np.float32)), None,
     r"views\.npz: intensity holds negative values"),
    (None, dict(wavelengths_m=np.array([638.0, 520.0, 450.0])),
     r"focal_stack\.npz: wavelengths_m=638\.0 is not a wavelength in metres"),
    (None, dict(depths_m=np.array([2e-3, np.nan])), r"focal_stack\.npz: depths_m must be finite"),
])
def test_report_refuses_files_in_other_units(tmp_path, capsys, views, focal, said):
    """Labels read "theta_x = -3282.9 deg" and "638000000000 nm", exit 0."""
    import re

    folder = _report_folder(tmp_path / "bad", views=views, focal=focal)
    assert _report(folder) == 2
    assert re.search(said, capsys.readouterr().err)
    assert not (folder.parent / "report.html").exists()
    # the same files in clholo's own units are reported
    good = _report_folder(tmp_path / "good", views={} if views is not None else None,
                          focal={} if focal is not None else None)
    assert _report(good) == 0 and (good.parent / "report.html").is_file()


def test_report_warns_of_an_all_black_stack_and_millimetres(tmp_path, capsys):
    folder = _report_folder(tmp_path, focal=dict(intensity=np.zeros((2, 3, 16, 16), np.float32),
                                                 depths_m=np.array([2.0, 4.0])))
    assert _report(folder) == 0
    err = capsys.readouterr().err
    assert "every intensity is 0: the page shows black images" in err
    assert "depths_m=2 m is more than 1 m" in err


@pytest.mark.parametrize("option, value", [("--near", "1e-6"), ("--far", "2e-6"),
                                            ("--z-slm", "4e-8")])
def test_bench_distances_below_ten_microns_are_refused(capsys, option, value):
    """``--near 1e-6 --far 2e-6`` (micrometres typed for millimetres) rendered layers half a
    micrometre apart, a thousandth of the hologram's depth of focus, without a word."""
    from clholo import cli

    argv = (["encode", "h.npz"] if option == "--z-slm" else ["render", "x.ply"]) + [option, value]
    with pytest.raises(SystemExit):
        cli.main(argv)
    assert f"argument {option}: {value} m is less than 10 um: give metres" in \
        capsys.readouterr().err


# device arrays of another context than queue=

@pytest.mark.parametrize("operator", ["pupil_view", "light_field", "quantizer"])
def test_device_arrays_of_another_context_are_refused_before_work(operator):
    """light_field launched its kernels on queue B with context A's buffer (undefined in
    OpenCL); pupil_view refused only after the work with a message naming nothing given;
    DeviceQuantizer ignored queue= for a device array."""
    import pyopencl as cl
    import pyopencl.array as cla

    from clholo.encode.quantize import DeviceQuantizer
    from clholo.host import runtime

    device = runtime.choose_device()
    qa = cl.CommandQueue(cl.Context([device]))
    qb = cl.CommandQueue(cl.Context([device]))
    rng = np.random.default_rng(5)
    optics = Optics(wavelengths=(520e-9,))
    if operator == "quantizer":
        phase = cla.to_device(qa, rng.uniform(-1, 1, (1, 1, 8, 8)).astype(np.float32))
        call = (lambda q: DeviceQuantizer()(phase, queue=q))
        name = "phase"
    else:
        h = cla.to_device(qa, np.exp(2j * np.pi * rng.random((1, 1, 32, 32))).astype(np.complex64))
        call = {"pupil_view": lambda q: views.pupil_view(h, optics, focus_depth=1e-3,
                                                         angles_rad=[(0.0, 0.0)], queue=q),
                "light_field": lambda q: views.light_field(h, optics, window=8, queue=q)}[operator]
        name = "holograms"
    with pytest.raises(ValueError, match=rf"^{name} is a device array of another OpenCL "
                                         rf"context than the queue's"):
        call(qb)
    call(qa)  # its own queue: fine
