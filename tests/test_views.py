"""Operators on holograms (kernels/views.cl, clholo.views): kernels against clholo.reference,
operators against the reference, and the physics of HOLOGRAPHY.md section 5."""

import math

import numpy as np
import pyopencl.array as cla
import pytest

from clholo import MPI, Optics, rayoptics, reference, render_hologram, views
from clholo.host import runtime

from conftest import random_complex
from tolerances import rel_l2, tol

GREEN = Optics(pitch=8e-6, wavelengths=(520e-9,))
RGB = Optics()


def _tf_real(queue):
    fp64 = runtime.has_fp64(queue.device)
    defines = {"TF_REAL": "double" if fp64 else "float"}
    if fp64:
        defines["CLHOLO_FP64"] = True
    return (np.float64 if fp64 else np.float32), defines


# ----------------------------------------------------------------------------- kernels
@pytest.mark.parametrize("padded,C", [((5, 7), 1), ((16, 24), 3), ((33, 64), 2)])
@pytest.mark.parametrize("square", [False, True])
def test_pupil_transfer_function_kernel(queue, rng, padded, C, square):
    Hp, Wp = padded
    pitch = 8e-6
    tf = random_complex(rng, (C, Hp, Wp))
    # centres anywhere in the band, radii from a few bins to half the band
    centres = [tuple(rng.uniform(-0.4, 0.4, 2) / pitch) for _ in range(C)]
    radii = list(rng.uniform(0.05, 0.5, C) / pitch)
    params = np.array([[cx * Wp * pitch, cy * Hp * pitch, r * Wp * pitch, r * Hp * pitch]
                       for (cx, cy), r in zip(centres, radii)])
    real, defines = _tf_real(queue)
    kern = runtime.get_kernel(queue.context, "views.cl", "pupil_transfer_function",
                              defines=defines)
    out = cla.empty(queue, (C, Hp, Wp), np.complex64)
    kern(queue, (Wp, Hp, C), None, cla.to_device(queue, tf).data, out.data,
         cla.to_device(queue, params.astype(real)).data, np.uint32(Hp), np.uint32(Wp),
         np.int32(square))
    want = reference.pupil_transfer_function(tf, pitch=pitch, centres=centres, radii=radii,
                                             square=square)
    got = out.get()
    t = tol("views", np.float32)
    assert np.count_nonzero(want) > 0 and np.count_nonzero(want) < want.size
    assert rel_l2(got, want) <= t["rel_l2"]
    assert np.max(np.abs(got - want)) <= t["max_abs"]


@pytest.mark.parametrize("shape,B,w,hop", [((13, 21), 2, 4, 3), ((32, 48), 3, 8, 8),
                                           ((17, 16), 1, 16, 1), ((9, 40), 4, 2, 5)])
@pytest.mark.parametrize("taper", ["rect", "hann"])
def test_stft_windows_kernel(queue, rng, shape, B, w, hop, taper):
    H, W = shape
    lead = int(rng.integers(0, 3))  # frames before the chunk: the kernel's offset argument
    u = random_complex(rng, (lead + B, H, W))
    Ny, Nx = (H - w) // hop + 1, (W - w) // hop + 1
    kern = runtime.get_kernel(queue.context, "views.cl", "stft_windows")
    out = cla.empty(queue, (B, Ny, Nx, w, w), np.complex64)
    du = cla.to_device(queue, u)
    kern(queue, (w * w, Ny * Nx, B), None, du.data, np.uint64(lead * H * W), out.data,
         np.uint32(H), np.uint32(W), np.uint32(Nx), np.uint32(w), np.uint32(hop),
         np.int32(taper == "hann"))
    want = reference.stft_windows(u[lead:], window=w, hop=hop, taper=taper)
    t = tol("views", np.float32)
    assert rel_l2(out.get(), want) <= t["rel_l2"]
    assert np.max(np.abs(out.get() - want)) <= t["max_abs"]


@pytest.mark.parametrize("T,M,w", [(1, 3, 2), (3, 7, 8), (5, 2, 16), (2, 12, 4)])
def test_stft_accumulate_kernel(queue, rng, T, M, w):
    spec = random_complex(rng, (T, M, w, w))
    acc0 = rng.random((M, w, w)).astype(np.float32)
    kern = runtime.get_kernel(queue.context, "views.cl", "stft_accumulate")
    acc = cla.to_device(queue, acc0)
    kern(queue, (w * w, M), None, cla.to_device(queue, spec).data, acc.data,
         np.float32(1.0 / T), np.uint32(w), np.uint32(T))
    want = acc0 + reference.stft_accumulate(spec)
    t = tol("views", np.float32)
    assert rel_l2(acc.get(), want) <= t["rel_l2"]
    assert np.max(np.abs(acc.get() - want) / np.maximum(1.0, np.abs(want))) <= t["max_abs"]


# ----------------------------------------------------------------------------- operators
@pytest.mark.parametrize("shape,optics,square", [((24, 40), GREEN, False),
                                                 ((17, 31), RGB, True)])
def test_pupil_view_matches_reference(queue, rng, shape, optics, square):
    H, W = shape
    T, C = 3, optics.channels
    holo = random_complex(rng, (T, C, H, W))
    depth = float(rng.uniform(0.5e-3, 2e-3))
    angles = [(0.0, 0.0), (float(rng.uniform(-0.02, 0.02)), float(rng.uniform(-0.02, 0.02)))]
    got = views.pupil_view(holo, optics, focus_depth=depth, angles_rad=angles,
                           pupil_angle_rad=0.01, pupil="square" if square else "disc",
                           pad=(64, 64), queue=queue)
    want = reference.pupil_view(holo, depth, wavelengths=optics.wavelengths,
                                pitch=optics.pitch, angles_rad=angles, pupil_angle_rad=0.01,
                                square=square, pad=(64, 64))
    assert got.shape == (2, C, H, W) and got.dtype == np.float32
    assert rel_l2(got, want) <= tol("pupil_view", np.float32)["rel_l2"]


def test_pupil_view_chunks_and_device_input_agree(queue, rng):
    T, C, H, W = 5, 3, 16, 24
    holo = random_complex(rng, (T, C, H, W))
    kw = dict(focus_depth=1e-3, angles_rad=[(0.01, -0.005)], pad=(32, 32), queue=queue)
    whole = views.pupil_view(holo, RGB, **kw)
    # a budget that fits two frames per chunk: 5 frames in 3 chunks (2, 2, 1)
    per_frame = 8 * C * H * W * 2 + 16 * C * 32 * 32
    fixed = 16 * C * 32 * 32 + 4 * C * H * W
    chunked = views.pupil_view(holo, RGB, memory_budget=fixed + 2 * per_frame, **kw)
    on_device = views.pupil_view(cla.to_device(queue, holo), RGB,
                                 memory_budget=fixed + 2 * per_frame, **kw)
    assert rel_l2(chunked, whole) <= tol("pupil_view", np.float32)["rel_l2"]
    assert rel_l2(on_device, whole) <= tol("pupil_view", np.float32)["rel_l2"]
    with pytest.raises(MemoryError, match="memory_budget"):
        views.pupil_view(holo, RGB, memory_budget=fixed, **kw)


LARGEST_PAD = (r"; the largest pad this budget holds on this 12x37 field is ([0-9.]+) "
               r"\((\d+)x(\d+)\)$")


@pytest.mark.parametrize("operator", ["pupil_view", "focal_stack"])
@pytest.mark.parametrize("budget", [2 * 2**20, 8 * 2**20], ids=["2MiB", "8MiB"])
def test_memory_refusal_names_the_largest_pad_that_fits(queue, rng, monkeypatch, operator,
                                                        budget):
    """A pad beyond the memory budget is refused naming the largest pad that fits (as the
    renderer's refusal does), before any transfer function is built: that pad runs, a little
    more is refused again. The parallax views (pupil_view) lacked the hint."""
    import re

    from clholo import hologram, propagation

    holo = random_complex(rng, (2, 3, 12, 37))
    depth = 2e-3

    def run(pad):
        if operator == "pupil_view":
            return views.pupil_view(holo, RGB, focus_depth=depth, angles_rad=[(0.0, 0.0),
                                    (0.01, 0.0)], pad=pad, memory_budget=budget, queue=queue)
        return hologram.focal_stack(holo, RGB, [depth], pad=pad, memory_budget=budget,
                                    queue=queue)

    with monkeypatch.context() as m:   # refused before any transfer function is built
        m.setattr(propagation, "transfer_function_cache", lambda *a, **k: pytest.fail(
            "a transfer function was built before the refusal"))
        with pytest.raises(MemoryError) as info:
            run(40)
    found = re.search(LARGEST_PAD, str(info.value))
    assert found, str(info.value)
    largest = float(found.group(1))
    assert 1 < largest < 40
    grid = propagation.device_padded_shape((12, 37), -depth, wavelength=RGB.wavelengths,
                                           pitch=RGB.pitch, pad=largest)
    assert grid == (int(found.group(2)), int(found.group(3)))
    assert run(largest).shape[-2:] == (12, 37)
    with pytest.raises(MemoryError, match="the largest pad"):
        run(largest + 0.05)


def test_light_field_memory_refusal_names_its_own_fix(queue, rng):
    """The light field has no pad and no angles: its refusal says what it does have."""
    holo = random_complex(rng, (2, 3, 32, 32))
    with pytest.raises(MemoryError) as info:
        views.light_field(holo, RGB, window=8, hop=2, memory_budget=2**14, queue=queue)
    assert str(info.value).endswith("raise memory_budget or use a smaller window or a larger "
                                    "hop"), str(info.value)


@pytest.mark.parametrize("shape,w,hop,taper", [((32, 48), 8, 8, "rect"),
                                               ((21, 37), 4, 3, "hann"),
                                               ((16, 16), 16, 5, "hann"),
                                               ((23, 31), 6, 4, "rect"),
                                               ((30, 33), 15, 7, "hann")])
def test_light_field_matches_reference(queue, rng, shape, w, hop, taper):
    H, W = shape
    holo = random_complex(rng, (3, 2, H, W))
    optics = Optics(wavelengths=(638e-9, 450e-9))
    lf = views.light_field(holo, optics, window=w, hop=hop, taper=taper, queue=queue)
    want = reference.light_field(holo, window=w, hop=hop, taper=taper)
    assert lf.intensity.shape == want.shape and lf.intensity.dtype == np.float32
    assert rel_l2(lf.intensity, want) <= tol("light_field", np.float32)["rel_l2"]
    for c, lam in enumerate(optics.wavelengths):
        np.testing.assert_allclose(lf.bin_angles_rad[c],
                                   reference.stft_bin_angles(w, wavelength=lam, pitch=8e-6))
    assert list(lf.window_x) == [k * hop for k in range(want.shape[2])]
    # chunked (one frame per chunk) from a device array gives the same
    per_frame = 16 * 2 * want.shape[1] * want.shape[2] * w * w
    small = views.light_field(cla.to_device(queue, holo), optics, window=w, hop=hop,
                              taper=taper, memory_budget=4 * want.size + per_frame, queue=queue)
    assert rel_l2(small.intensity, want) <= tol("light_field", np.float32)["rel_l2"]


def test_operator_errors(queue, rng):
    holo = random_complex(rng, (1, 1, 16, 16))
    limit = math.degrees(math.asin(520e-9 / 16e-6))
    with pytest.raises(ValueError, match=f"{limit:.3f} deg"):
        views.pupil_view(holo, GREEN, focus_depth=1e-3, angles_rad=[(0.0, 0.04)], queue=queue)
    with pytest.raises(ValueError, match=r"window must be a size the FFT takes.*got 7; use 6 or 8"):
        views.light_field(holo, GREEN, window=7, queue=queue)
    with pytest.raises(ValueError, match="channel"):
        views.light_field(holo, RGB, window=4, queue=queue)
    with pytest.raises(TypeError, match="complex64"):
        views.pupil_view(holo.astype(np.complex128), GREEN, focus_depth=0.0,
                         angles_rad=[(0, 0)], queue=queue)
    with pytest.raises(ValueError, match="pupil"):
        views.pupil_view(holo, GREEN, focus_depth=0.0, angles_rad=[(0, 0)], pupil="hex",
                         queue=queue)
    with pytest.raises(ValueError, match="fourier_focal_length_m"):
        views.pupil_view(holo, GREEN, focus_depth=0.0, angles_rad=[(0, 0)],
                         pupil_diameter_m=1e-3, queue=queue)


# ----------------------------------------------------------------------------- physics
def _blur(img, sigma):
    from scipy.ndimage import gaussian_filter

    return gaussian_filter(img, sigma, mode="nearest")


def test_pupil_view_of_a_single_plane_is_its_content(queue, rng):
    """Focused on a plane, every pupil view shows the plane's content, up to a scale and the
    pupil's blur (the incoherent PSF |IFFT(A)|^2) and speckle (compared low-passed)."""
    H = W = 64
    # 16-pixel cells of random brightness: features the pupil's blur and speckle leave intact
    content = _blur(np.kron(rng.uniform(0.15, 1.0, (4, 4)), np.ones((16, 16))), 1.5)
    depth = 2e-3
    mpi = MPI(content[None, :, :, None], np.ones((1, H, W)), [depth])
    holo = render_hologram(mpi, GREEN, frames=24, seed=int(rng.integers(1 << 30)), pad=2,
                           queue=queue)
    angles = [(0.0, 0.0), (0.01, 0.0), (0.0, -0.008)]
    got = views.pupil_view(holo, GREEN, focus_depth=depth, pupil_angle_rad=0.015,
                           angles_rad=angles, pad=2,
                           queue=queue)
    margin = 8  # the plane's own edges diffract inwards
    for (tx, ty), view in zip(angles, got[:, 0]):
        # the ray-optics view of the plane at that angle, focused on it: its content
        ref = rayoptics.orthographic_view(mpi, GREEN.pitch, angle_rad=(tx, ty),
                                          focus_depth=depth, queue=queue)[..., 0]
        a, b = _blur(view, 2.5)[margin:-margin, margin:-margin], \
            _blur(ref, 2.5)[margin:-margin, margin:-margin]
        scale = float(np.sum(a * b) / np.sum(b * b))
        assert scale > 0
        assert rel_l2(a / scale, b) < 0.08
        # not a constant image: the view follows the content, not its mean
        assert np.corrcoef(a.ravel(), b.ravel())[0, 1] > 0.95


def _centroid_x(img):
    img = np.clip(img - np.median(img), 0, None)
    x = np.arange(img.shape[1])
    return float(np.sum(img * x[None, :]) / np.sum(img))


@pytest.mark.parametrize("focus_shift", [-1.5e-3, 2e-3])
def test_point_moves_across_pupil_views_as_geometry_says(queue, rng, focus_shift):
    """A point at d_p seen focused at d_f through a pupil at angle theta sits
    (d_p - d_f) tan(theta) / p pixels along +x (behind the focus: moves with the pupil)."""
    H, W = 48, 64
    d_point = 3e-3
    d_focus = d_point - focus_shift
    y, x = np.mgrid[0:H, 0:W]
    spot = np.exp(-((x - 31.3) ** 2 + (y - 23.6) ** 2) / (2 * 1.2 ** 2))
    mpi = MPI(spot[None, :, :, None], (spot > 1e-3)[None].astype(np.float32), [d_point])
    holo = render_hologram(mpi, GREEN, frames=16, seed=int(rng.integers(1 << 30)), pad=2,
                           queue=queue)
    theta = math.radians(1.0)
    got = views.pupil_view(holo, GREEN, focus_depth=d_focus, pupil_angle_rad=0.003,
                           angles_rad=[(-theta, 0.0), (theta, 0.0)], pad=2, queue=queue)
    shift = _centroid_x(got[1, 0]) - _centroid_x(got[0, 0])
    want = 2 * (d_point - d_focus) * math.tan(theta) / GREEN.pitch
    assert abs(want) > 5
    assert abs(shift - want) < 0.1 * abs(want) + 0.5


@pytest.mark.parametrize("taper,w", [("rect", 16), ("hann", 16), ("rect", 15), ("hann", 12)])
def test_stft_of_tilted_plane_wave_peaks_at_its_angle(queue, rng, taper, w):
    H, W = 32, 48
    kx, ky = (int(k) for k in rng.integers(-((w - 1) // 2), w // 2, size=2))
    fx, fy = kx / (w * GREEN.pitch), ky / (w * GREEN.pitch)
    y, x = np.mgrid[0:H, 0:W] * GREEN.pitch
    phase0 = rng.uniform(0, 2 * np.pi, size=(2, 1, 1, 1))  # two frames, other phases
    wave = np.exp(1j * (2 * np.pi * (fx * x + fy * y) + phase0)).astype(np.complex64)
    lf = views.light_field(wave, GREEN, window=w, hop=8, taper=taper, queue=queue)
    theta_x, theta_y = math.asin(520e-9 * fx), math.asin(520e-9 * fy)
    for wy in range(lf.intensity.shape[1]):
        for wx in range(lf.intensity.shape[2]):
            j, i = np.unravel_index(np.argmax(lf.intensity[0, wy, wx]), (w, w))
            assert lf.bin_angles_rad[0, i] == pytest.approx(theta_x, abs=1e-12)
            assert lf.bin_angles_rad[0, j] == pytest.approx(theta_y, abs=1e-12)
