"""What the suite did not see before (issue 8, item 4 and 5): fractional alpha, focus through a
partly transparent layer, the band limit switched off, complex128 at its own precision, the
compositing kernel's ragged tail with several channels, non-square grids in the focal stack, and
focal stacks computed in frame chunks.

Physics tests use circular propagation (``pad`` = the field's own power-of-two size) where noted:
at these distances the band limit cuts nothing there, so every propagation is unitary and the
expected intensities are exact, not approximations spoiled by light leaving the window.
"""

import numpy as np
import pyopencl as cl
import pyopencl.array as cla
import pytest

import clholo
from clholo import reference as ref
from clholo.host import runtime
from clholo.propagation import device_padded_shape

from conftest import random_complex
from test_composite import run_composite_kernel
from tolerances import rel_l2, tol

LAM, P = 520e-9, 8e-6
GREEN = clholo.Optics(pitch=P, wavelengths=(LAM,))


def _smooth_texture(rng, n, sigma=3.0):
    from scipy.ndimage import gaussian_filter

    t = gaussian_filter(rng.random((n, n)), sigma, mode="wrap")
    return (0.2 + 0.8 * (t - t.min()) / (t.max() - t.min())).astype(np.float32)


# ---------------------------------------------------------------------------------- alpha
@pytest.mark.parametrize("a_near,a_far", [(0.3, 0.8), (0.6, 0.45)])
def test_partly_transparent_layers_give_the_over_intensity(queue, a_near, a_far):
    # Expected intensity of random-phase layers is the "over" composite:
    #   a1 c1 + (1 - a1) a2 c2,
    # which needs sqrt(1 - a) on the field (1 - a would give (1 - a1)^2) and sqrt(c a) on the
    # emission. Uniform layers on a circular grid: every pixel is a sample of the same mean.
    n, T = 64, 12
    c_near, c_far = 0.5, 0.9
    color = np.array([np.full((n, n), c_near), np.full((n, n), c_far)])[..., None]
    alpha = np.array([np.full((n, n), a_near), np.full((n, n), a_far)])
    mpi = clholo.MPI(color, alpha, [1e-3, 2.5e-3])
    holo = clholo.render_hologram(mpi, GREEN, frames=T, seed=5, pad=(n, n), queue=queue)
    over = a_near * c_near + (1 - a_near) * a_far * c_far
    wrong_transmission = a_near * c_near + (1 - a_near) ** 2 * a_far * c_far
    measured = float(np.mean(np.abs(holo) ** 2))
    # speckle: ~1/sqrt(n^2 T) relative noise, well under 2%
    assert measured == pytest.approx(over, rel=0.02)
    assert abs(measured - wrong_transmission) > 5 * abs(measured - over)


def test_layer_behind_a_partly_transparent_layer_stays_in_focus(queue, rng):
    # The random phase belongs to each layer's own emission only: the far layer seen through a
    # half-transparent near layer must refocus sharply at its own depth, with (1 - a1) of its
    # intensity, plus the near layer's defocused (uniform) light a1 c1.
    from scipy.ndimage import gaussian_filter

    n, T, a1, c1 = 128, 16, 0.5, 0.3
    texture = _smooth_texture(rng, n)
    color = np.stack([np.full((n, n), c1, np.float32), texture])[..., None]
    alpha = np.stack([np.full((n, n), a1, np.float32), np.ones((n, n), np.float32)])
    depths = [1.5e-3, 3e-3]
    mpi = clholo.MPI(color, alpha, depths)
    holo = clholo.render_hologram(mpi, GREEN, frames=T, seed=2, pad=(n, n), queue=queue)
    far = clholo.focal_stack(holo, GREEN, [depths[1]], pad=(n, n), queue=queue)[0, 0]
    expected = (1 - a1) * texture + a1 * c1
    smooth = gaussian_filter(far, 2.0, mode="wrap")
    corr = np.corrcoef(smooth.ravel(), gaussian_filter(expected, 2.0, mode="wrap").ravel())[0, 1]
    assert corr > 0.9
    assert float(far.mean()) == pytest.approx(float(expected.mean()), rel=0.03)


# ---------------------------------------------------------------------------------- band limit
def test_band_limit_off_and_on_on_the_same_grid(queue, rng):
    # at 20 cm on this grid the band limit cuts: the two transfer functions differ, and a cache
    # keyed without the band limit would hand the second call the first one's
    shape, dz = (128, 96), 0.2
    u = random_complex(rng, shape)
    padded = device_padded_shape(shape, dz, wavelength=LAM, pitch=P)
    assert 0 < ref.band_limit_mask(padded, dz, wavelength=LAM, pitch=P).mean() < 1
    results = {}
    for band_limit in (True, False, True):
        got = clholo.propagate(u, dz, wavelength=LAM, pitch=P, band_limit=band_limit,
                               queue=queue)
        want = ref.propagate(u, dz, wavelength=LAM, pitch=P, pad=padded, band_limit=band_limit)
        assert rel_l2(got, want) <= tol("propagate", np.float32)["rel_l2"], band_limit
        results[band_limit] = got
    assert rel_l2(results[True], results[False]) > 0.05


def test_renderer_without_band_limit_matches_reference(queue, rng):
    L, H, W = 3, 32, 48
    mpi = clholo.MPI(rng.random((L, H, W, 1)), rng.uniform(0.1, 0.9, (L, H, W)),
                     [0.05, 0.1, 0.2])
    holo = clholo.render_hologram(mpi, GREEN, frames=1, seed=9, band_limit=False, queue=queue)
    grid = clholo.hologram_padded_shape(mpi, GREEN)
    want = ref.mpi_hologram(mpi.color, mpi.alpha, mpi.depths, wavelengths=GREEN.wavelengths,
                            pitch=P, frames=1, seed=9, pad=grid, band_limit=False)
    with_limit = ref.mpi_hologram(mpi.color, mpi.alpha, mpi.depths,
                                  wavelengths=GREEN.wavelengths, pitch=P, frames=1, seed=9,
                                  pad=grid, band_limit=True)
    assert rel_l2(want, with_limit) > 1e-2  # the switch matters on this scene
    assert rel_l2(holo, want) <= tol("hologram", np.float32)["rel_l2"]


# ---------------------------------------------------------------------------------- fp64
@pytest.mark.parametrize("shape,dz", [((64, 48), 4e-3), ((128, 96), -0.2), ((100, 70), 1e-3)])
def test_complex128_propagation_at_double_precision(queue, cl_device, rng, shape, dz):
    if not runtime.has_fp64(cl_device):
        pytest.skip(f"{cl_device.name.strip()} has no fp64 (the error for it is tested in "
                    f"test_propagation.py)")
    u = random_complex(rng, shape, np.complex128)
    got = clholo.propagate(u, dz, wavelength=LAM, pitch=P, queue=queue)
    padded = device_padded_shape(shape, dz, wavelength=LAM, pitch=P)
    want = ref.propagate(u, dz, wavelength=LAM, pitch=P, pad=padded)
    assert got.dtype == np.complex128
    assert rel_l2(got, want) <= tol("propagate", np.float64)["rel_l2"]


# ---------------------------------------------------------------------------------- composite
@pytest.mark.parametrize("npix_mod_4", [1, 2, 3])
def test_composite_ragged_tail_with_several_channels(queue, rng, npix_mod_4):
    # the kernel works on 4 pixels at a time; the last group is partial. Every pixel of the
    # tail has alpha strictly inside (0, 1) and each channel its own colour, so reading the
    # wrong channel, pixel or alpha there changes the result.
    H, W = 3, 4 * 5 + npix_mod_4
    frames, colours = 2, 3
    seed, layer, frame0 = int(rng.integers(0, 2 ** 63)), 4, 11
    u0 = random_complex(rng, (frames, colours, H, W))
    color = rng.uniform(0.05, 0.95, (H, W, colours)).astype(np.float32)
    alpha = rng.uniform(0.05, 0.95, (H, W)).astype(np.float32)
    got = run_composite_kernel(queue, u0, color, alpha, seed=seed, layer=layer, frame0=frame0)
    t = tol("composite", np.float32)
    for f in range(frames):
        for c in range(colours):
            phi = ref.random_phase((H, W), seed=seed, frame=frame0 + f, colour=c, layer=layer)
            want = ref.composite_layer(u0[f, c], color[..., c], alpha, phi)
            tail = np.s_[-1, W - npix_mod_4:]
            assert np.max(np.abs(got[f, c][tail] - want[tail])) <= t["max_abs"], (f, c)
            assert rel_l2(got[f, c], want) <= t["rel_l2"]


# ---------------------------------------------------------------------------------- focal stack
@pytest.mark.parametrize("shape", [(40, 120), (120, 40)])
def test_focal_stack_on_non_square_grids(queue, rng, shape):
    H, W = shape
    optics = clholo.Optics(wavelengths=(638e-9, 450e-9))
    holo = random_complex(rng, (3, 2, H, W))
    depths = [1e-3, 3e-3]
    got = clholo.focal_stack(holo, optics, depths, pad=1, queue=queue)
    padded = device_padded_shape((H, W), -np.array(depths), wavelength=optics.wavelengths,
                                 pitch=optics.pitch, pad=1)
    assert padded[0] != padded[1]
    want = ref.focal_stack(holo, depths, wavelengths=optics.wavelengths, pitch=optics.pitch,
                           pad=padded)
    assert got.shape == (2, 2, H, W)
    assert rel_l2(got, want) <= 2 * tol("propagate", np.float32)["rel_l2"]


@pytest.mark.parametrize("on_device", [False, True])
def test_focal_stack_in_frame_chunks_equals_one_batch(queue, rng, on_device):
    T, C, H, W = 7, 2, 32, 48
    optics = clholo.Optics(wavelengths=(638e-9, 520e-9))
    holo = random_complex(rng, (T, C, H, W))
    src = cla.to_device(queue, holo) if on_device else holo
    depths = [1e-3, 2e-3, 4e-3]
    whole = clholo.focal_stack(src, optics, depths, queue=queue)
    grid = device_padded_shape((H, W), -np.array(depths), wavelength=optics.wavelengths,
                               pitch=optics.pitch)
    fixed = 4 * 3 * C * H * W + 8 * C * grid[0] * grid[1]
    per_frame = 8 * C * (H * W * (1 if on_device else 2) + 2 * grid[0] * grid[1])
    # a budget for 2 frames: chunks of 2, 2, 2, 1
    chunked = clholo.focal_stack(src, optics, depths, memory_budget=fixed + 2 * per_frame,
                                 queue=queue)
    assert rel_l2(chunked, whole) < 1e-6
    want = ref.focal_stack(holo, depths, wavelengths=optics.wavelengths, pitch=optics.pitch,
                           pad=grid)
    assert rel_l2(chunked, want) <= 2 * tol("propagate", np.float32)["rel_l2"]
    with pytest.raises(MemoryError, match="memory_budget"):
        clholo.focal_stack(src, optics, depths, memory_budget=fixed + per_frame // 2,
                           queue=queue)


def test_focal_stack_allocation_failure_becomes_memory_error(queue, rng, monkeypatch):
    holo = random_complex(rng, (2, 1, 16, 16))

    def refuse(*args, **kwargs):
        raise cl.MemoryError("clCreateBuffer", cl.status_code.MEM_OBJECT_ALLOCATION_FAILURE,
                             "MEM_OBJECT_ALLOCATION_FAILURE")

    monkeypatch.setattr(cla, "empty", refuse)
    with pytest.raises(MemoryError, match=r"ran out of memory for focal stack.*memory_budget"):
        clholo.focal_stack(holo, GREEN, [1e-3], queue=queue)
