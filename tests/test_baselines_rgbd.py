"""RGB-D layer-sum baseline: the recursion with transmission 1 on the device against the
plain sum of separately propagated layers (clholo.reference.rgbd_hologram)."""

import numpy as np

from clholo.host.kernel_args import COMPOSITE_LAYER
import pyopencl.array as cla
import pytest

from clholo import MPI, Optics, hologram_padded_shape, reference, render_hologram
from clholo.baselines import rgbd
from clholo.host import runtime

from conftest import random_complex
from tolerances import rel_l2, tol


def _scene(rng, H, W, L, margin):
    """A random image over a depth map of patches (every layer has pixels, edges between
    them), dark within ``margin`` pixels of the border."""
    image = rng.random((H, W, 3))
    depth = np.kron(rng.random((4, 4)), np.ones((H // 4 + 1, W // 4 + 1)))[:H, :W] + 0.1
    layers = rgbd.rgbd_layers(image, depth, layers=L, near=1e-3, far=2e-3, srgb=False)
    alpha = layers.alpha.copy()
    alpha[:, :margin] = alpha[:, H - margin:] = 0
    alpha[:, :, :margin] = alpha[:, :, W - margin:] = 0
    return MPI(layers.color, alpha, layers.depths)


@pytest.mark.parametrize("shape,channels,frames,farthest", [
    ((17, 29), 3, 2, False), ((64, 96), 1, 3, False), ((5, 3), 2, 1, True)])
def test_composite_kernel_without_occlusion(queue, rng, shape, channels, frames, farthest):
    """-D CLHOLO_NO_OCCLUSION: u <- u + sqrt(c a) exp(i phi), phases from the same stream."""
    H, W = shape
    seed, layer, frame0 = int(rng.integers(0, 2 ** 63)), int(rng.integers(0, 40)), 3
    u0 = random_complex(rng, (frames, channels, H, W))
    color = rng.random((H, W, channels)).astype(np.float32)
    alpha = rng.random((H, W)).astype(np.float32)
    du = cla.to_device(queue, u0)
    kern = runtime.get_kernel(queue.context, "composite.cl", "composite_layer",
                              defines={"CLHOLO_NO_OCCLUSION": True})
    k0, k1 = reference.seed_key(seed)
    kern(queue, ((H * W + 3) // 4, channels, frames), None, *COMPOSITE_LAYER.args(
        u=du.data, color=cla.to_device(queue, color).data, alpha=cla.to_device(queue, alpha).data,
        npix=H * W, n_channels=channels, layer=layer, frame0=frame0, colour0=0, key_lo=k0,
        key_hi=k1, farthest=farthest))
    got = du.get()
    t = tol("composite", np.float32)
    for f in range(frames):
        for c in range(channels):
            phi = reference.random_phase((H, W), seed=seed, frame=frame0 + f, colour=c,
                                         layer=layer).astype(np.float64)
            behind = 0 if farthest else u0[f, c]
            want = behind + np.sqrt(color[..., c] * alpha) * np.exp(1j * phi)
            assert rel_l2(got[f, c], want) <= t["rel_l2"]
            assert np.max(np.abs(got[f, c] - want)) <= t["max_abs"]


@pytest.mark.parametrize("shape,L,frames,margin,pad", [
    ((64, 64), 3, 2, 16, 2), ((64, 48), 5, 1, 0, 2), ((48, 80), 4, 2, 0, "auto")])
def test_rgbd_hologram_matches_layer_sum(queue, rng, shape, L, frames, margin, pad):
    # margin 0: content up to the border, where a recursion that crops at every plane would
    # lose the light that diffracts back in (~10 %); the layer sum must not
    H, W = shape
    layers = _scene(rng, H, W, L, margin=margin)
    assert set(np.unique(layers.alpha)) == {0.0, 1.0}
    optics = Optics()
    seed = int(rng.integers(0, 2 ** 63))
    got = rgbd.render_rgbd_hologram(layers, optics, frames=frames, seed=seed, pad=pad,
                                    queue=queue)
    padded = rgbd.rgbd_renderer(layers, optics, seed=seed, pad=pad, queue=queue).padded
    want = reference.rgbd_hologram(layers.color, layers.alpha, layers.depths,
                                   wavelengths=optics.wavelengths, pitch=optics.pitch,
                                   frames=frames, seed=seed, pad=padded)
    assert got.shape == want.shape and got.dtype == np.complex64
    assert rel_l2(got, want) <= tol("hologram", np.float32)["rel_l2"]


def test_rgbd_differs_from_mpi_only_by_occlusion(queue, rng):
    """Same phases and grid: with one layer there is nothing to occlude and the two agree; with
    several the MPI hologram is darker behind the nearer masks."""
    H, W = 32, 32
    optics = Optics(wavelengths=(520e-9,))
    one = MPI(rng.random((1, H, W, 1)), np.ones((1, H, W)), [2e-3])
    a = rgbd.render_rgbd_hologram(one, optics, frames=2, seed=7, queue=queue)
    b = render_hologram(one, optics, frames=2, seed=7, queue=queue)
    assert rel_l2(a, b) <= tol("composite", np.float32)["rel_l2"]
    # two full-opacity layers: the MPI hologram only shows the front one, the sum shows both
    two = MPI(rng.random((2, H, W, 1)) * 0.5 + 0.25, np.ones((2, H, W)), [1e-3, 2e-3])
    mpi = render_hologram(two, optics, frames=4, seed=7, queue=queue)
    summed = rgbd.render_rgbd_hologram(two, optics, frames=4, seed=7, queue=queue)
    e_mpi, e_sum = np.mean(np.abs(mpi) ** 2), np.mean(np.abs(summed) ** 2)
    assert e_sum > 1.5 * e_mpi


def test_rgbd_layers_refuses_soft_masks(rng):
    with pytest.raises(ValueError, match="hard"):
        rgbd.rgbd_layers(rng.random((8, 8, 3)), rng.random((8, 8)) + 0.1, layers=2, near=1e-3,
                         far=2e-3, mode="soft")
