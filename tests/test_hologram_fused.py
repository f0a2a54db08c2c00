"""The four-pass renderer (two_pass=False) with the next layer's composite fused into the
inverse transform's store (kernels/composite_store.h through an FFT store callback) against the
unfused loop and the reference."""

import numpy as np
import pytest

import clholo
from clholo import reference as ref
from clholo.host.scheduler import HologramRenderer

from tolerances import rel_l2, tol


def _random_mpi(rng, L, H, W, C, near=1e-3, far=4e-3):
    return clholo.MPI(rng.random((L, H, W, C)), rng.random((L, H, W)),
                      np.linspace(near, far, L))


@pytest.mark.parametrize("shape,C,pad", [((48, 80), 3, "auto"), ((60, 45), 2, 2),
                                         ((33, 50), 1, (40, 64))])
def test_fused_composite_matches_unfused_and_reference(queue, rng, shape, C, pad):
    mpi = _random_mpi(rng, 4, shape[0], shape[1], C)
    optics = clholo.Optics(wavelengths=(638e-9, 520e-9, 450e-9)[:C])
    seed = int(rng.integers(0, 2 ** 40))
    fused = HologramRenderer(mpi, optics, seed=seed, pad=pad, queue=queue, fuse_composite=True,
                             two_pass=False)
    plain = HologramRenderer(mpi, optics, seed=seed, pad=pad, queue=queue, fuse_composite=False,
                             two_pass=False)
    assert fused.fuse_composite and not plain.fuse_composite
    got = fused.render(3).get()
    base = plain.render(3).get()
    # the same operations up to the contraction of a multiply-add (5e-7 relative on PoCL)
    assert rel_l2(got, base) <= tol("composite", np.float32)["rel_l2"] * mpi.layers
    want = ref.mpi_hologram(mpi.color, mpi.alpha, mpi.depths, wavelengths=optics.wavelengths,
                            pitch=optics.pitch, frames=3, seed=seed, pad=fused.padded)
    assert rel_l2(got, want) <= tol("hologram", np.float32)["rel_l2"]


def test_fused_renderer_keeps_the_layer_sum_without_occlusion(queue, rng):
    """with occlusion off (the RGB-D baseline) a renderer built to fuse its composite still
    sums every layer's own wave carried from its depth to the hologram plane"""
    mpi = _random_mpi(rng, 3, 32, 40, 1)
    optics = clholo.Optics(wavelengths=(520e-9,))
    occl = HologramRenderer(mpi, optics, seed=5, queue=queue, fuse_composite=True)
    free = HologramRenderer(mpi, optics, seed=5, queue=queue, fuse_composite=True,
                            occlusion=False)
    a, b = occl.render(1).get(), free.render(1).get()
    assert rel_l2(b, a) > 1e-2
    want = ref.rgbd_hologram(mpi.color, mpi.alpha, mpi.depths, wavelengths=optics.wavelengths,
                             pitch=optics.pitch, frames=1, seed=5, pad=free.padded)
    assert rel_l2(b, want) <= tol("hologram", np.float32)["rel_l2"]

