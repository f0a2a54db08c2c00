"""Device ASM propagation against the complex128 reference, at the same padded grid."""

import numpy as np
import pyopencl.array as cla
import pytest

import clholo
from clholo import reference as ref
from clholo.fft import is_fft_size
from clholo.host.runtime import has_fp64
from clholo.propagation import build_transfer_function, device_padded_shape

from conftest import random_complex
from tolerances import rel_l2, tol

LAM, P = 520e-9, 8e-6


@pytest.mark.parametrize("shape,dz", [((64, 64), 1e-3), ((256, 384), 2e-3), ((100, 70), -5e-3),
                                      ((256, 256), 0.2), ((128, 96), -0.2), ((1, 16), 3e-3)])
@pytest.mark.parametrize("pad", ["auto", 2, 1])
def test_propagate_matches_reference(queue, rng, shape, dz, pad):
    u = random_complex(rng, shape)
    got = clholo.propagate(u, dz, wavelength=LAM, pitch=P, pad=pad, queue=queue)
    padded = device_padded_shape(shape, dz, wavelength=LAM, pitch=P, pad=pad)
    want = ref.propagate(u, dz, wavelength=LAM, pitch=P, pad=padded)
    assert got.dtype == np.complex64 and got.shape == shape
    assert rel_l2(got, want) <= tol("propagate", np.float32)["rel_l2"]


def test_transfer_function_at_millimetres_and_20cm(queue):
    # the carrier split keeps float32 transfer functions exact where the phase is ~1e6 rad
    for dz in (1e-3, -2e-3, 0.2, -0.2):
        H = build_transfer_function(queue, (256, 512), dz, wavelengths=[638e-9, 450e-9],
                                    pitch=P).get()
        for c, lam in enumerate((638e-9, 450e-9)):
            want = ref.transfer_function((256, 512), dz, wavelength=lam, pitch=P)
            assert np.max(np.abs(H[c] - want)) < 5e-7
            assert np.array_equal(H[c] != 0, want != 0)  # same band limit, bin for bin


def test_batch_and_device_arrays(queue, rng):
    u = random_complex(rng, (3, 2, 48, 80))
    du = cla.to_device(queue, u)
    got = clholo.propagate(du, 1.5e-3, wavelength=LAM, pitch=P, queue=queue)
    assert isinstance(got, cla.Array) and got.shape == u.shape
    padded = device_padded_shape((48, 80), 1.5e-3, wavelength=LAM, pitch=P)
    want = ref.propagate(u, 1.5e-3, wavelength=LAM, pitch=P, pad=padded)
    assert rel_l2(got.get(), want) <= tol("propagate", np.float32)["rel_l2"]
    np.testing.assert_array_equal(du.get(), u)  # input untouched


@pytest.mark.parametrize("shares", [True, False])
def test_numpy_in_out_both_paths(queue, rng, monkeypatch, shares):
    """NumPy in and out read and written in place on CPU devices (host-pointer buffers) or
    copied (other devices), forced either way on PoCL: same result, input untouched, a fresh
    output array that does not alias the input; render_hologram's NumPy frames likewise"""
    from clholo import _arrays

    monkeypatch.setattr(_arrays, "shares_host_memory", lambda queue: shares)
    u = random_complex(rng, (2, 48, 80))
    keep = u.copy()
    got = clholo.propagate(u, 1.5e-3, wavelength=LAM, pitch=P, queue=queue)
    padded = device_padded_shape((48, 80), 1.5e-3, wavelength=LAM, pitch=P)
    want = ref.propagate(u, 1.5e-3, wavelength=LAM, pitch=P, pad=padded)
    assert isinstance(got, np.ndarray) and got.shape == u.shape
    assert not np.shares_memory(got, u)
    assert rel_l2(got, want) <= tol("propagate", np.float32)["rel_l2"]
    np.testing.assert_array_equal(u, keep)
    # a non-contiguous complex128 view is converted, then read
    v = random_complex(rng, (48, 160), np.complex128)[:, ::2]
    got = clholo.propagate(v, 1e-3, wavelength=LAM, pitch=P, queue=queue)
    want = ref.propagate(v, 1e-3, wavelength=LAM, pitch=P,
                         pad=device_padded_shape((48, 80), 1e-3, wavelength=LAM, pitch=P))
    assert rel_l2(got, want) <= tol("propagate", np.float32)["rel_l2"]
    # render_hologram: NumPy frames against the device-array output of the same render
    mpi = clholo.MPI(rng.random((3, 24, 40, 1), dtype=np.float32),
                     rng.random((3, 24, 40), dtype=np.float32), [2e-3, 3e-3, 4e-3])
    optics = clholo.Optics(wavelengths=(520e-9,))
    holo = clholo.render_hologram(mpi, optics, frames=3, seed=5, queue=queue)
    dev = cla.empty(queue, (3, 1, 24, 40), np.complex64)
    clholo.render_hologram(mpi, optics, frames=3, seed=5, out=dev, queue=queue)
    assert isinstance(holo, np.ndarray) and holo.shape == (3, 1, 24, 40)
    np.testing.assert_array_equal(holo, dev.get())
    # focal_stack reads NumPy frames in place, chunk by chunk (2 frames per chunk here)
    depths = [2.5e-3, 3.5e-3]
    budget = 8 * 2 * (24 * 40 * 2 + 2 * 48 * 80) + 4 * 2 * 24 * 40 + 8 * 48 * 80 + 4096
    kw = dict(pad=(48, 80), memory_budget=budget, queue=queue)
    stack = clholo.focal_stack(holo, optics, depths, **kw)
    np.testing.assert_array_equal(stack, clholo.focal_stack(dev, optics, depths, **kw))
    np.testing.assert_array_equal(holo, dev.get())  # read, not written


def test_complex128(queue, cl_device, rng):
    if not has_fp64(cl_device):
        with pytest.raises(TypeError, match="fp64"):
            clholo.propagate(random_complex(rng, (32, 32), np.complex128), 1e-3,
                             wavelength=LAM, pitch=P, queue=queue)
        return
    u = random_complex(rng, (64, 48), np.complex128)
    got = clholo.propagate(u, 4e-3, wavelength=LAM, pitch=P, queue=queue)
    padded = device_padded_shape((64, 48), 4e-3, wavelength=LAM, pitch=P)
    assert got.dtype == np.complex128
    # complex128 reaches ~8e-16: hold it to the fp64 row, so a float32 slip in the double
    # path (the transfer function's phase, the FFT's twiddles) is caught
    assert rel_l2(got, ref.propagate(u, 4e-3, wavelength=LAM, pitch=P, pad=padded)) <= tol(
        "propagate", np.float64)["rel_l2"]


def test_forward_backward_on_device(queue, rng):
    shape, dz = (128, 128), 3e-3
    padded = device_padded_shape(shape, dz, wavelength=LAM, pitch=P, pad=1)
    spectrum = random_complex(rng, padded, np.complex128)
    mask = ref.band_limit_mask(padded, dz, wavelength=LAM, pitch=P)
    u = np.fft.ifft2(spectrum * mask).astype(np.complex64)
    there = clholo.propagate(u, dz, wavelength=LAM, pitch=P, pad=1, queue=queue)
    back = clholo.propagate(there, -dz, wavelength=LAM, pitch=P, pad=1, queue=queue)
    assert rel_l2(back, u) < 1e-5
    assert rel_l2(there, u) > 1e-2


def test_auto_pad_error_against_double_pad(queue, rng):
    # On a random-phase field (full band: the worst case) the 2^a 3^b 5^c "auto" grid differs
    # from 2x padding only through the kernel's sinc tail; docs/benchmarks.md has the figures.
    u = np.exp(2j * np.pi * rng.random((200, 300))).astype(np.complex64)
    for dz in (1e-3, 4e-3):
        auto = clholo.propagate(u, dz, wavelength=LAM, pitch=P, pad="auto", queue=queue)
        two = clholo.propagate(u, dz, wavelength=LAM, pitch=P, pad=2, queue=queue)
        grid_auto = device_padded_shape(u.shape, dz, wavelength=LAM, pitch=P, pad="auto")
        grid_two = device_padded_shape(u.shape, dz, wavelength=LAM, pitch=P, pad=2)
        assert grid_two == (400, 600)  # 2 N is already an accepted size
        spread = ref.kernel_spread_pixels(dz, wavelength=LAM, pitch=P)
        for n, na, n2 in zip(u.shape, grid_auto, grid_two):
            # the smallest accepted size covering the spread: really a different, smaller grid
            assert n + spread <= na < n2 and is_fft_size(na)
            assert not any(is_fft_size(m) for m in range(n + spread, na))
        assert 0 < rel_l2(auto, two) < 0.02


@pytest.mark.parametrize("bad,kwargs,exc,match", [
    (np.ones((8, 8), np.float32), {}, TypeError, "field must be complex"),
    (np.full((8, 8), np.nan, np.complex64), {}, ValueError, "NaN"),
    (np.ones(8, np.complex64), {}, ValueError, "at least 2-D"),
    (np.ones((8, 8), np.complex64), {"pad": (14, 16)}, ValueError, "2, 3 and 5.*2\\^a 3\\^b 5\\^c: use 15"),
    (np.ones((8, 8), np.complex64), {"pad": 0.5}, ValueError, "pad factor"),
    (np.ones((8, 8), np.complex64), {"pitch": -1.0}, ValueError, "pitch"),
    (np.ones((8, 8), np.complex64), {"wavelength": np.inf}, ValueError, "wavelength"),
    (np.ones((8, 8), np.complex64), {"dz": np.nan}, ValueError, "dz"),
    (np.ones((6000, 8), np.complex64), {"pad": 2}, ValueError,
     "grid of 12000 x 16, but the FFT.s largest size is 8192 per axis: the largest pad for "
     "this 6000 x 8 field is 1.365"),
])
def test_bad_input(queue, bad, kwargs, exc, match):
    args = {"dz": 1e-3, "wavelength": LAM, "pitch": P}
    args.update(kwargs)
    dz = args.pop("dz")
    with pytest.raises(exc, match=match):
        clholo.propagate(bad, dz, queue=queue, **args)
