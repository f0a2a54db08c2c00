"""The renderer with a layer as two kernels (column round trip with the transfer function, row
round trip with the next layer's composite; host/scheduler.py) against the NumPy reference and
the four-pass layer, for both FFT kernel variants on PoCL."""

import dataclasses

import numpy as np
import pyopencl.array as cla
import pytest

import clholo
from clholo import fft as F
from clholo import reference as ref
from clholo.host.scheduler import HologramRenderer

from tolerances import rel_l2, tol


def _random_mpi(rng, L, H, W, C, near=1e-3, far=4e-3):
    return clholo.MPI(rng.random((L, H, W, C)), rng.random((L, H, W)),
                      np.linspace(near, far, L))


@pytest.mark.parametrize("variant", ["cpu", "gpu"])
@pytest.mark.parametrize("shape,C,pad,L", [((48, 80), 3, "auto", 4), ((60, 45), 2, 2, 3),
                                           ((33, 50), 1, (40, 64), 5), ((27, 36), 3, (45, 75), 2),
                                           ((20, 30), 1, (24, 32), 1)])
def test_two_pass_matches_reference_and_four_pass(queue, rng, variant, shape, C, pad, L):
    mpi = _random_mpi(rng, L, shape[0], shape[1], C)
    optics = clholo.Optics(wavelengths=(638e-9, 520e-9, 450e-9)[:C])
    seed = int(rng.integers(0, 2 ** 40))
    two = HologramRenderer(mpi, optics, seed=seed, pad=pad, queue=queue, variant=variant)
    four = HologramRenderer(mpi, optics, seed=seed, pad=pad, queue=queue, two_pass=False)
    assert two.two_pass and not four.two_pass
    got = two.render(3).get()
    want = ref.mpi_hologram(mpi.color, mpi.alpha, mpi.depths, wavelengths=optics.wavelengths,
                            pitch=optics.pitch, frames=3, seed=seed, pad=two.padded)
    assert rel_l2(got, want) <= tol("hologram", np.float32)["rel_l2"]
    # the same recursion as four passes per layer, up to float rounding of other FFT orders
    assert rel_l2(got, four.render(3).get()) <= tol("composite", np.float32)["rel_l2"] * L


@pytest.mark.parametrize("variant", ["cpu", "gpu"])
def test_two_pass_with_transparent_blocks(queue, rng, variant):
    """Layers transparent over whole 8x8 blocks (the CPU composite skips drawing phases there)
    and over lone pixels, as real MPIs are: the reference's holograms, and the four-pass
    layer's up to rounding."""
    L, H, W, C = 4, 40, 64, 2
    mpi = _random_mpi(rng, L, H, W, C)
    alpha = mpi.alpha.copy()
    blocks = rng.random((L, H // 8, W // 8)) < 0.5
    alpha[np.repeat(np.repeat(blocks, 8, axis=1), 8, axis=2)] = 0.0
    alpha[rng.random(alpha.shape) < 0.1] = 0.0  # lone transparent pixels in opaque blocks
    alpha[:, :8, 8:16] = 0.0  # one whole block of every layer
    # blocks transparent in part only: one column, the first row, the last row
    alpha[:, 8:16, 16] = alpha[:, 8, 24:32] = alpha[:, 23, 32:40] = 0.0
    alpha[:, 8:16, 17] = alpha[:, 9, 24:32] = alpha[:, 22, 32:40] = 0.5
    mpi = clholo.MPI(mpi.color, alpha, mpi.depths)
    optics = clholo.Optics(wavelengths=(638e-9, 450e-9))
    seed = int(rng.integers(0, 2 ** 40))
    two = HologramRenderer(mpi, optics, seed=seed, pad=2, queue=queue, variant=variant)
    four = HologramRenderer(mpi, optics, seed=seed, pad=2, queue=queue, two_pass=False)
    got = two.render(2).get()
    want = ref.mpi_hologram(mpi.color, mpi.alpha, mpi.depths, wavelengths=optics.wavelengths,
                            pitch=optics.pitch, frames=2, seed=seed, pad=two.padded)
    assert rel_l2(got, want) <= tol("hologram", np.float32)["rel_l2"]
    assert rel_l2(got, four.render(2).get()) <= tol("composite", np.float32)["rel_l2"] * L


def test_two_pass_frames_do_not_depend_on_batching(queue, rng):
    """phases follow the absolute frame index: frames rendered one by one from frame0 = 1 are
    the frames of one batch, bit for bit"""
    mpi = _random_mpi(rng, 3, 24, 36, 2)
    optics = clholo.Optics(wavelengths=(638e-9, 450e-9))
    r = HologramRenderer(mpi, optics, seed=11, pad=2, queue=queue)
    assert r.two_pass
    whole = r.render(4).get()
    one = cla.empty(queue, (1, 2, 24, 36), np.complex64)
    for t in range(1, 4):
        r.enqueue_frames(t, 1, one)
        np.testing.assert_array_equal(one.get()[0], whole[t])


def test_two_pass_needs_occlusion(queue, rng):
    mpi = _random_mpi(rng, 2, 16, 16, 1)
    optics = clholo.Optics(wavelengths=(520e-9,))
    with pytest.raises(ValueError, match="two_pass=True needs occlusion"):
        HologramRenderer(mpi, optics, queue=queue, occlusion=False, two_pass=True)
    assert not HologramRenderer(mpi, optics, queue=queue, occlusion=False).two_pass
    with pytest.raises(ValueError, match="variant="):
        HologramRenderer(mpi, optics, queue=queue, variant="gpu-global")


def test_long_rows_run_two_passes_in_place(queue, rng):
    """rows of 2250 points (SGD's grid at 2048^2) exceed the GPU variant's two 32 KiB buffers;
    they are held once in local memory (fft_gpu.cl, FFT_INPLACE), so the layer still runs as
    two kernels and matches the reference"""
    mpi = _random_mpi(rng, 2, 8, 1100, 1)
    optics = clholo.Optics(wavelengths=(520e-9,))
    r = HologramRenderer(mpi, optics, seed=2, pad=(8, 2250), queue=queue, variant="gpu")
    assert r.two_pass
    got = r.render(1).get()
    want = ref.mpi_hologram(mpi.color, mpi.alpha, mpi.depths, wavelengths=optics.wavelengths,
                            pitch=optics.pitch, frames=1, seed=2, pad=r.padded)
    assert rel_l2(got, want) <= tol("hologram", np.float32)["rel_l2"]


def test_rows_too_long_for_local_memory_keep_four_passes(queue, rng, monkeypatch):
    """a device with 8 KiB of local memory holds no row of 2250 complex64 (18000 bytes) even
    once, nor their real parts alone (9000 bytes: the split plan): no row round trip there, so
    the renderer keeps the four-pass layer (and says so when asked for two)"""
    real_of = F.DeviceLimits.of
    monkeypatch.setattr(F.DeviceLimits, "of", classmethod(
        lambda cls, dev: dataclasses.replace(real_of(dev), local_mem_size=8192)))
    mpi = _random_mpi(rng, 2, 8, 1100, 1)
    optics = clholo.Optics(wavelengths=(520e-9,))
    r = HologramRenderer(mpi, optics, seed=2, pad=(8, 2250), queue=queue, variant="gpu")
    assert not r.two_pass
    with pytest.raises(ValueError, match="two_pass=True: lines of the padded grid 8x2250"):
        HologramRenderer(mpi, optics, seed=2, pad=(8, 2250), queue=queue, variant="gpu",
                         two_pass=True)
    got = r.render(1).get()
    want = ref.mpi_hologram(mpi.color, mpi.alpha, mpi.depths, wavelengths=optics.wavelengths,
                            pitch=optics.pitch, frames=1, seed=2, pad=r.padded)
    assert rel_l2(got, want) <= tol("hologram", np.float32)["rel_l2"]


@pytest.mark.parametrize("variant", ["cpu", "gpu"])
def test_row_pitch_leaves_the_hologram_bit_for_bit(queue, rng, variant, monkeypatch):
    """The row spectrum at a pitch (rows of a multiple of 4 KiB on CPUs; here of 256 bytes, so
    that a small grid takes it) gives the same bits as without."""
    mpi = _random_mpi(rng, 3, 20, 24, 2)
    optics = clholo.Optics(wavelengths=(638e-9, 520e-9))
    seed = int(rng.integers(0, 2 ** 40))
    plain = HologramRenderer(mpi, optics, seed=seed, pad=(32, 32), queue=queue, variant=variant)
    cpu = F.DeviceLimits.of(queue.device).is_cpu
    assert plain.row_pitch == 32
    want = plain.render(2).get()
    monkeypatch.setattr(F, "_PITCH_ALIAS_BYTES", 256)
    pitched = HologramRenderer(mpi, optics, seed=seed, pad=(32, 32), queue=queue,
                               variant=variant)
    assert pitched.row_pitch == (48 if cpu else 32)
    np.testing.assert_array_equal(pitched.render(2).get(), want)
    assert pitched._row_spectrum.shape[-1] == pitched.row_pitch


@pytest.mark.parametrize("variant", ["cpu", "gpu"])
def test_two_pass_reads_its_transfer_functions_as_even_factors(queue, rng, variant):
    """The column round trips read each step's transfer functions as EvenFactors from the
    context's cache (on CPU strips laid out strip by strip, cached on their own; on GPU
    kernels the cached frames, in their quarter): the same bits as the whole frames."""
    mpi = _random_mpi(rng, 3, 27, 36, 2)
    optics = clholo.Optics(wavelengths=(638e-9, 450e-9))
    r = HologramRenderer(mpi, optics, seed=5, queue=queue, two_pass=True, variant=variant)
    got = r.render(2).get()
    columns = r._layer_plans(2)[1]
    ef = r.even_transfer_functions(0, columns)
    assert isinstance(ef, F.EvenFactors) and ef.count == 2
    assert ef.layout == ("strips" if variant == "cpu" else "quarter")
    if variant == "cpu":
        assert r.even_transfer_functions(0, columns) is ef  # cached on its own
    else:
        assert ef.data is r.transfer_functions(0)  # the cached frames themselves
    assert (r.tf_strip_bytes > 0) == (variant == "cpu" and columns.variant == "cpu")
    whole = HologramRenderer(mpi, optics, seed=5, queue=queue, two_pass=True, variant=variant)
    whole.even_transfer_functions = lambda step, plan: whole.transfer_functions(step)
    np.testing.assert_array_equal(got, whole.render(2).get())
