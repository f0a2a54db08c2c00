"""The layers laid out in blocks of eight rows (``CLHOLO_LAYER_BLOCKS``, kernel ``layer_blocks``
in kernels/composite_cpu.cl): the CPU renderer's two-pass layer reads each layer's
``sqrt(c a)`` and ``sqrt(1 - a)`` made once instead of gathering, transposing and taking square
roots per pixel, colour and frame. The layout against its NumPy reference, and every composite
that reads it against the row-major form's bits."""

import numpy as np
import pyopencl as cl
import pyopencl.array as cla
import pytest

import clholo
from clholo import fft as F
from clholo import reference as ref
from clholo.host import runtime
from clholo.host.scheduler import COMPOSITE_STORE_PARAMS, HologramRenderer

from conftest import random_complex
from tolerances import tol

ROWS = F.FFTCallback('#include "composite_store.h"\n', params=COMPOSITE_STORE_PARAMS)
BLOCKS = F.FFTCallback('#include "composite_store.h"\n', params=COMPOSITE_STORE_PARAMS,
                       defines={"CLHOLO_LAYER_BLOCKS": True})
SAME = tol("same_bits", np.float32)["max_abs"]


def _layer(rng, H, W, C):
    """A random layer with opaque, transparent and half-transparent pixels, a whole
    transparent 8x8 block (the composites leave those as they are) and a black one that is
    not transparent."""
    color = rng.random((H, W, C)).astype(np.float32)
    alpha = rng.random((H, W)).astype(np.float32)
    alpha[rng.random((H, W)) < 0.1] = 0.0
    alpha[rng.random((H, W)) < 0.05] = 1.0
    alpha[:8, 8:16] = 0.0
    # a black, half-transparent block: amplitude 0 everywhere but it darkens what lies behind
    color[:8, :8] = 0.0
    alpha[:8, :8] = 0.5
    return color, alpha


def _device_blocks(queue, color, alpha):
    H, W, C = color.shape
    S = -(-H // 8)
    amp = cla.empty(queue, (S, C, W, 8), np.float32)
    keep = cla.empty(queue, (S, W, 8), np.float32)
    # NaN first: every element must be written
    amp.fill(np.float32(np.nan))
    keep.fill(np.float32(np.nan))
    kern = runtime.get_kernel(queue.context, "composite_cpu.cl", "layer_blocks")
    runtime.launch(kern, queue, (W, S), None, cla.to_device(queue, color).data,
                   cla.to_device(queue, alpha).data, amp.data, keep.data, np.uint32(H),
                   np.uint32(W), np.uint32(C))
    return amp, keep


def _bits_equal(a, b):
    a, b = np.asarray(a), np.asarray(b)
    assert a.shape == b.shape and a.dtype == b.dtype
    np.testing.assert_array_equal(a.view(np.uint32), b.view(np.uint32))


@pytest.mark.parametrize("H,W,C", [(8, 8, 1), (17, 29, 3), (64, 96, 3), (23, 64, 2),
                                   (1, 5, 1), (40, 36, 2)])
def test_layer_blocks_match_the_reference(queue, rng, H, W, C):
    """amp ``[S, C, W, 8]`` and keep ``[S, W, 8]`` bit for bit; rows past H transparent."""
    color, alpha = _layer(rng, H, W, C)
    amp, keep = _device_blocks(queue, color, alpha)
    want_amp, want_keep = ref.layer_blocks(color, alpha)
    _bits_equal(amp.get(), want_amp)
    _bits_equal(keep.get(), want_keep)
    S = -(-H // 8)
    y = np.arange(S * 8).reshape(S, 8)
    pad = (y >= H)  # [S, 8]
    assert np.all(want_keep.transpose(0, 2, 1)[pad] == 1.0)
    assert np.all(want_amp.transpose(0, 3, 1, 2)[pad] == 0.0)
    # the layout itself: pixel (8 s + l, x), colour c
    s, l, x, c = S - 1, (H - 1) % 8, W - 1, C - 1
    assert want_amp[s, c, x, l] == np.sqrt(color[H - 1, x, c] * alpha[H - 1, x])
    assert want_keep[0, 0, 0] == np.sqrt(np.float32(1) - alpha[0, 0])


@pytest.mark.parametrize("variant", ["cpu", "gpu"])
@pytest.mark.parametrize("H,W,Wp,C,frames", [(16, 24, 32, 3, 2), (13, 30, 45, 1, 3),
                                             (17, 21, 27, 2, 2), (8, 64, 64, 3, 1),
                                             (24, 40, 48, 2, 1)])
def test_row_round_trip_composite_reads_blocks_with_the_same_bits(queue, rng, variant, H, W,
                                                                   Wp, C, frames):
    """The row round trip's composite (eight rows at a time on the CPU strips, four pixels or
    one on the GPU kernels and at ragged edges) from blocks gives the row-major form's bits:
    H not a multiple of 8 (a last partial strip), W not a multiple of 4 or 8."""
    B = frames * C
    spec = cla.to_device(queue, random_complex(rng, (B, H, Wp)))
    color, alpha = _layer(rng, H, W, C)
    amp, keep = ref.layer_blocks(color, alpha)
    seed, layer, frame0 = int(rng.integers(0, 2 ** 40)), 3, 11
    k0, k1 = ref.seed_key(seed)
    tail = [np.uint32(W), np.uint32(C), np.uint32(layer), np.uint32(frame0), k0, k1]
    got = {}
    for name, callback, arrays in (("rows", ROWS, (color, alpha)), ("blocks", BLOCKS,
                                                                    (amp, keep))):
        plan = F.RoundTripPlan((B, H, Wp), Wp, axis="rows", first="inverse", mid_n=W,
                               mid_callback=callback, queue=queue, variant=variant)
        got[name] = plan.execute(spec, mid_args=[cla.to_device(queue, a) for a in arrays]
                                 + tail).get()
    assert np.max(np.abs(got["blocks"] - got["rows"])) <= SAME
    _bits_equal(got["blocks"].view(np.float32), got["rows"].view(np.float32))


@pytest.mark.parametrize("variant", ["cpu", "gpu"])
@pytest.mark.parametrize("H,W,Hp,C", [(16, 24, 32, 2), (13, 20, 27, 1), (12, 19, 25, 3)])
def test_column_round_trip_composite_reads_blocks_with_the_same_bits(queue, rng, variant, H, W,
                                                                      Hp, C):
    """The composite as a column round trip's mid callback (runs of four pixels of one row,
    clholo_mid4: four lanes of a block, eight floats apart) from blocks: the row-major form's
    bits."""
    spec = cla.to_device(queue, random_complex(rng, (C, Hp, W)))
    color, alpha = _layer(rng, H, W, C)
    k0, k1 = ref.seed_key(int(rng.integers(0, 2 ** 40)))
    tail = [np.uint32(W), np.uint32(C), np.uint32(2), np.uint32(5), k0, k1]
    got = {}
    for name, callback, arrays in (("rows", ROWS, (color, alpha)),
                                   ("blocks", BLOCKS, ref.layer_blocks(color, alpha))):
        plan = F.RoundTripPlan((C, Hp, W), Hp, axis="cols", first="inverse", mid_n=H,
                               mid_callback=callback, queue=queue, variant=variant)
        got[name] = plan.execute(spec, mid_args=[cla.to_device(queue, a) for a in arrays]
                                 + tail).get()
    _bits_equal(got["blocks"].view(np.float32), got["rows"].view(np.float32))


@pytest.mark.parametrize("shape,frames,channels", [((8, 8), 1, 1), ((17, 29), 2, 3),
                                                   ((64, 96), 3, 3), ((23, 64), 2, 1)])
@pytest.mark.parametrize("farthest", [False, True])
def test_cpu_composite_blocks_read_blocks_with_the_same_bits(queue, rng, shape, frames,
                                                              channels, farthest):
    """``composite_layer_rows8`` (the farthest layer of a render) built for blocks: the row-
    major build's bits, edge blocks included."""
    H, W = shape
    u0 = cla.to_device(queue, random_complex(rng, (frames, channels, H, W)))
    color, alpha = _layer(rng, H, W, channels)
    k0, k1 = ref.seed_key(int(rng.integers(0, 2 ** 40)))
    got = {}
    for name, defines, arrays in (("rows", None, (color, alpha)),
                                  ("blocks", {"CLHOLO_LAYER_BLOCKS": True},
                                   ref.layer_blocks(color, alpha))):
        kern = runtime.get_kernel(queue.context, "composite_cpu.cl", "composite_layer_rows8",
                                  defines=defines)
        u = u0.copy()
        kern(queue, (-(-W // 8), -(-H // 8), frames * channels), None, u.data,
             *[cla.to_device(queue, a).data for a in arrays], np.uint32(H), np.uint32(W),
             np.uint32(channels), np.uint32(4), np.uint32(9), k0, k1, np.int32(farthest))
        got[name] = u.get()
    _bits_equal(got["blocks"].view(np.float32), got["rows"].view(np.float32))


@pytest.mark.parametrize("variant", ["cpu", "gpu"])
@pytest.mark.parametrize("shape,C,L", [((40, 64), 3, 3), ((37, 50), 2, 3), ((33, 52), 1, 2)])
def test_renderer_on_cpus_takes_blocks_and_gives_the_same_holograms(queue, rng, variant, shape,
                                                                   C, L):
    """``layer_layout="auto"`` on a CPU's two-pass renderer is ``"blocks"``; its frames are
    the row-major layout's bit for bit."""
    if not queue.device.type & cl.device_type.CPU:
        pytest.skip("the blocks layout is the CPU renderer's")
    H, W = shape
    layers = [_layer(rng, H, W, C) for _ in range(L)]
    mpi = clholo.MPI(np.stack([c for c, _ in layers]), np.stack([a for _, a in layers]),
                     np.linspace(1e-3, 3e-3, L))
    optics = clholo.Optics(wavelengths=(638e-9, 520e-9, 450e-9)[:C])
    seed = int(rng.integers(0, 2 ** 40))
    rows = HologramRenderer(mpi, optics, seed=seed, queue=queue, variant=variant,
                            layer_layout="rows")
    blocks = HologramRenderer(mpi, optics, seed=seed, queue=queue, variant=variant)
    assert rows.layer_layout == "rows" and blocks.layer_layout == "blocks"
    assert blocks.two_pass
    S = -(-H // 8)
    assert blocks.layer_bytes == 4 * (L * S * 8 * W + H * W) * (C + 1)
    _bits_equal(blocks.render(3).get().view(np.float32), rows.render(3).get().view(np.float32))


def test_layer_layout_is_checked(queue, rng):
    mpi = clholo.MPI(rng.random((2, 16, 24, 1)), rng.random((2, 16, 24)), [1e-3, 2e-3])
    optics = clholo.Optics(wavelengths=(520e-9,))
    with pytest.raises(ValueError, match="layer_layout='diagonal'"):
        HologramRenderer(mpi, optics, queue=queue, layer_layout="diagonal")
    with pytest.raises(ValueError, match="layer_layout='blocks' needs"):
        HologramRenderer(mpi, optics, queue=queue, two_pass=False, layer_layout="blocks")
    four = HologramRenderer(mpi, optics, queue=queue, two_pass=False)
    assert four.layer_layout == "rows"
