"""The compositing kernel (phases drawn in place) against the NumPy reference."""

import numpy as np
import pyopencl.array as cla
import pytest

from clholo import reference
from clholo.host import runtime

from clholo.host.kernel_args import COMPOSITE_LAYER
from conftest import random_complex
from tolerances import rel_l2, tol


def run_composite_kernel(queue, u0, color, alpha, *, seed, layer, frame0, farthest=False):
    """One launch of ``composite_layer`` on ``u0`` [frames, colours, H, W]; the result on host."""
    frames, colours, H, W = u0.shape
    du = cla.to_device(queue, u0)
    kern = runtime.get_kernel(queue.context, "composite.cl", "composite_layer")
    k0, k1 = reference.seed_key(seed)
    kern(queue, ((H * W + 3) // 4, colours, frames), None, *COMPOSITE_LAYER.args(
        u=du.data, color=cla.to_device(queue, color).data, alpha=cla.to_device(queue, alpha).data,
        npix=H * W, n_channels=color.shape[-1], layer=layer, frame0=frame0, colour0=0,
        key_lo=k0, key_hi=k1, farthest=farthest))
    return du.get()


def assert_matches_reference(got, u0, color, alpha, *, seed, layer, frame0, farthest):
    """Every field ``got[f, c]`` against ``reference.composite_layer`` of the same phases, with
    the composite tolerances (channel c of the batch is colour c)."""
    frames, colours, H, W = got.shape
    t = tol("composite", np.float32)
    for f in range(frames):
        for c in range(colours):
            phi = reference.random_phase((H, W), seed=seed, frame=frame0 + f, colour=c,
                                         layer=layer)
            behind = np.zeros((H, W)) if farthest else u0[f, c]
            want = reference.composite_layer(behind, color[..., c], alpha, phi)
            assert rel_l2(got[f, c], want) <= t["rel_l2"]
            assert np.max(np.abs(got[f, c] - want)) <= t["max_abs"]


@pytest.mark.parametrize("shape,frames,colours,channels", [
    ((1, 3), 1, 1, 1), ((17, 29), 2, 3, 3), ((64, 96), 3, 2, 3), ((128, 128), 1, 1, 4)])
@pytest.mark.parametrize("farthest", [False, True])
def test_composite_layer_matches_reference(queue, rng, shape, frames, colours, channels,
                                           farthest):
    H, W = shape
    seed = int(rng.integers(0, 2 ** 64, dtype=np.uint64))
    layer = int(rng.integers(0, 40))
    frame0 = int(rng.integers(0, 100))
    u0 = random_complex(rng, (frames, colours, H, W))
    color = rng.random((H, W, channels)).astype(np.float32)
    alpha = rng.random((H, W)).astype(np.float32)
    alpha[0, 0] = 1.0  # the ends of [0, 1] included
    alpha.flat[-1] = 0.0
    got = run_composite_kernel(queue, u0, color, alpha, seed=seed, layer=layer, frame0=frame0,
                               farthest=farthest)
    assert_matches_reference(got, u0, color, alpha, seed=seed, layer=layer, frame0=frame0,
                             farthest=farthest)


@pytest.mark.parametrize("shape,frames,channels", [
    ((8, 8), 1, 1), ((17, 29), 2, 3), ((64, 96), 3, 3), ((40, 36), 1, 2), ((23, 64), 2, 1)])
@pytest.mark.parametrize("farthest", [False, True])
def test_cpu_composite_blocks_match_composite_layer_and_reference(queue, rng, shape, frames,
                                                                  channels, farthest):
    """``composite_layer_rows8`` (kernels/composite_cpu.cl: 8x8 blocks, the row round trip's
    composite) against ``composite_layer`` and the reference, with edge blocks (H, W not
    multiples of 8; W = 29 and 23 x 64 not multiples of 4 either way), transparent 8x8 blocks
    (kept as they are, or zero for the farthest layer) and every channel in the batch."""
    H, W = shape
    seed = int(rng.integers(0, 2 ** 64, dtype=np.uint64))
    layer, frame0 = int(rng.integers(0, 40)), int(rng.integers(0, 100))
    u0 = random_complex(rng, (frames, channels, H, W))
    color = rng.random((H, W, channels)).astype(np.float32)
    alpha = rng.random((H, W)).astype(np.float32)
    alpha[:8, :8] = 0.0            # a whole transparent block
    alpha[-1, -1] = 1.0
    du = cla.to_device(queue, u0)
    kern = runtime.get_kernel(queue.context, "composite_cpu.cl", "composite_layer_rows8")
    k0, k1 = reference.seed_key(seed)
    kern(queue, (-(-W // 8), -(-H // 8), frames * channels), None, du.data,
         cla.to_device(queue, color).data, cla.to_device(queue, alpha).data, np.uint32(H),
         np.uint32(W), np.uint32(channels), np.uint32(layer), np.uint32(frame0), np.uint32(k0),
         np.uint32(k1), np.int32(farthest))
    got = du.get()
    gpu_form = run_composite_kernel(queue, u0, color, alpha, seed=seed, layer=layer,
                                    frame0=frame0, farthest=farthest)
    # the same phases and sin/cos bits; only the contraction of a * b + c may differ
    assert np.max(np.abs(got - gpu_form)) <= 4 * np.finfo(np.float32).eps * (
        1 + np.abs(u0).max())
    assert_matches_reference(got, u0, color, alpha, seed=seed, layer=layer, frame0=frame0,
                             farthest=farthest)
