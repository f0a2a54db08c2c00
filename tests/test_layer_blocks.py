"""The layers laid out in blocks of eight rows (``CLHOLO_LAYER_BLOCKS``, kernel ``layer_blocks``
in kernels/composite_cpu.cl): the CPU renderer's two-pass layer reads each layer's
``sqrt(c a)`` and ``sqrt(1 - a)`` made once instead of gathering, transposing and taking square
roots per pixel, colour and frame; and in planes, blocks of one row (``CLHOLO_LAYER_ROWS`` 1,
kernel ``layer_planes`` in kernels/composite.cl: ``layer_layout="planes"``, each colour's rows
contiguous for a GPU's coalesced loads). Each layout against its NumPy reference, and every
composite that reads it against the row-major form's bits."""

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
# layout -> (its defines, rows per block)
LAYOUTS = {"blocks": ({"CLHOLO_LAYER_BLOCKS": True}, 8),
           "planes": ({"CLHOLO_LAYER_BLOCKS": True, "CLHOLO_LAYER_ROWS": 1}, 1)}
CALLBACKS = {name: F.FFTCallback('#include "composite_store.h"\n', params=COMPOSITE_STORE_PARAMS,
                                 defines=defines) for name, (defines, _) in LAYOUTS.items()}
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


def _reference(layout, color, alpha):
    return ref.layer_blocks(color, alpha, rows=LAYOUTS[layout][1])


def _device_blocks(queue, color, alpha, layout="blocks"):
    H, W, C = color.shape
    R = LAYOUTS[layout][1]
    S = -(-H // R)
    amp = cla.empty(queue, (S, C, W, R), np.float32)
    keep = cla.empty(queue, (S, W, R), np.float32)
    # NaN first: every element must be written
    amp.fill(np.float32(np.nan))
    keep.fill(np.float32(np.nan))
    kern = (runtime.get_kernel(queue.context, "composite_cpu.cl", "layer_blocks") if R == 8
            else runtime.get_kernel(queue.context, "composite.cl", "layer_planes"))
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
@pytest.mark.parametrize("layout", list(LAYOUTS))
def test_layer_blocks_match_the_reference(queue, rng, H, W, C, layout):
    """amp ``[S, C, W, R]`` and keep ``[S, W, R]`` bit for bit (R = 8 or 1); rows past H
    transparent."""
    color, alpha = _layer(rng, H, W, C)
    amp, keep = _device_blocks(queue, color, alpha, layout)
    want_amp, want_keep = _reference(layout, color, alpha)
    _bits_equal(amp.get(), want_amp)
    _bits_equal(keep.get(), want_keep)
    R = LAYOUTS[layout][1]
    S = -(-H // R)
    y = np.arange(S * R).reshape(S, R)
    pad = (y >= H)  # [S, R]
    assert np.all(want_keep.transpose(0, 2, 1)[pad] == 1.0)
    assert np.all(want_amp.transpose(0, 3, 1, 2)[pad] == 0.0)
    # the layout itself: pixel (R s + l, x), colour c
    s, l, x, c = S - 1, (H - 1) % R, W - 1, C - 1
    assert want_amp[s, c, x, l] == np.sqrt(color[H - 1, x, c] * alpha[H - 1, x])
    assert want_keep[0, 0, 0] == np.sqrt(np.float32(1) - alpha[0, 0])
    if R == 1:  # planes: a colour's row is contiguous
        y, x = H // 2, W // 3
        assert want_amp.reshape(H, C, W)[y, c, x] == np.sqrt(color[y, x, c] * alpha[y, x])
        assert want_keep.reshape(H, W)[y, x] == np.sqrt(np.float32(1) - alpha[y, x])


def test_layer_blocks_reference_takes_eight_or_one_rows(rng):
    with pytest.raises(ValueError, match="rows=4"):
        ref.layer_blocks(rng.random((8, 8, 1)), rng.random((8, 8)), rows=4)


@pytest.mark.parametrize("layout", list(LAYOUTS))
@pytest.mark.parametrize("variant", ["cpu", "gpu"])
@pytest.mark.parametrize("H,W,Wp,C,frames", [(16, 24, 32, 3, 2), (13, 30, 45, 1, 3),
                                             (17, 21, 27, 2, 2), (8, 64, 64, 3, 1),
                                             (24, 40, 48, 2, 1)])
def test_row_round_trip_composite_reads_blocks_with_the_same_bits(queue, rng, variant, H, W,
                                                                   Wp, C, frames, layout):
    """The row round trip's composite (eight rows at a time on the CPU strips, four pixels or
    one on the GPU kernels and at ragged edges) from blocks gives the row-major form's bits:
    H not a multiple of 8 (a last partial strip), W not a multiple of 4 or 8."""
    B = frames * C
    spec = cla.to_device(queue, random_complex(rng, (B, H, Wp)))
    color, alpha = _layer(rng, H, W, C)
    amp, keep = _reference(layout, color, alpha)
    seed, layer, frame0 = int(rng.integers(0, 2 ** 40)), 3, 11
    k0, k1 = ref.seed_key(seed)
    tail = [np.uint32(W), np.uint32(C), np.uint32(layer), np.uint32(frame0), k0, k1]
    got = {}
    for name, callback, arrays in (("rows", ROWS, (color, alpha)),
                                   ("blocks", CALLBACKS[layout], (amp, keep))):
        plan = F.RoundTripPlan((B, H, Wp), Wp, axis="rows", first="inverse", mid_n=W,
                               mid_callback=callback, queue=queue, variant=variant)
        got[name] = plan.execute(spec, mid_args=[cla.to_device(queue, a) for a in arrays]
                                 + tail).get()
    assert np.max(np.abs(got["blocks"] - got["rows"])) <= SAME
    _bits_equal(got["blocks"].view(np.float32), got["rows"].view(np.float32))


@pytest.mark.parametrize("layout", list(LAYOUTS))
@pytest.mark.parametrize("variant", ["cpu", "gpu"])
@pytest.mark.parametrize("H,W,Hp,C", [(16, 24, 32, 2), (13, 20, 27, 1), (12, 19, 25, 3)])
def test_column_round_trip_composite_reads_blocks_with_the_same_bits(queue, rng, variant, H, W,
                                                                      Hp, C, layout):
    """The composite as a column round trip's mid callback (runs of four pixels of one row,
    clholo_mid4: four lanes of a block, eight floats apart) from blocks: the row-major form's
    bits."""
    spec = cla.to_device(queue, random_complex(rng, (C, Hp, W)))
    color, alpha = _layer(rng, H, W, C)
    k0, k1 = ref.seed_key(int(rng.integers(0, 2 ** 40)))
    tail = [np.uint32(W), np.uint32(C), np.uint32(2), np.uint32(5), k0, k1]
    got = {}
    for name, callback, arrays in (("rows", ROWS, (color, alpha)),
                                   ("blocks", CALLBACKS[layout],
                                    _reference(layout, color, alpha))):
        plan = F.RoundTripPlan((C, Hp, W), Hp, axis="cols", first="inverse", mid_n=H,
                               mid_callback=callback, queue=queue, variant=variant)
        got[name] = plan.execute(spec, mid_args=[cla.to_device(queue, a) for a in arrays]
                                 + tail).get()
    _bits_equal(got["blocks"].view(np.float32), got["rows"].view(np.float32))


@pytest.mark.parametrize("shape,frames,channels", [((8, 8), 1, 1), ((17, 29), 2, 3),
                                                   ((64, 96), 3, 3), ((23, 64), 2, 1)])
@pytest.mark.parametrize("farthest", [False, True])
@pytest.mark.parametrize("layout", list(LAYOUTS))
@pytest.mark.parametrize("kernel", ["composite_cpu.cl:composite_layer_rows8",
                                    "composite.cl:composite_layer_rows4"])
def test_composites_launched_alone_read_blocks_with_the_same_bits(queue, rng, shape, frames,
                                                                   channels, farthest, layout,
                                                                   kernel):
    """``composite_layer_rows8`` (the farthest layer of a render on CPUs) and
    ``composite_layer_rows4`` (on GPUs with planes) built for blocks or planes: the row-major
    build's bits, edge blocks and a row's last pixels past a multiple of four included."""
    H, W = shape
    u0 = cla.to_device(queue, random_complex(rng, (frames, channels, H, W)))
    color, alpha = _layer(rng, H, W, channels)
    k0, k1 = ref.seed_key(int(rng.integers(0, 2 ** 40)))
    got = {}
    filename, kernel_name = kernel.split(":")
    grid = ((-(-W // 8), -(-H // 8), frames * channels) if kernel_name.endswith("rows8")
            else (-(-W // 4), H, frames * channels))
    for name, defines, arrays in (("rows", None, (color, alpha)),
                                  ("blocks", LAYOUTS[layout][0],
                                   _reference(layout, color, alpha))):
        kern = runtime.get_kernel(queue.context, filename, kernel_name, defines=defines)
        u = u0.copy()
        kern(queue, grid, None, u.data,
             *[cla.to_device(queue, a).data for a in arrays], np.uint32(H), np.uint32(W),
             np.uint32(channels), np.uint32(4), np.uint32(9), k0, k1, np.int32(farthest))
        got[name] = u.get()
    _bits_equal(got["blocks"].view(np.float32), got["rows"].view(np.float32))


@pytest.mark.parametrize("shape,frames,channels", [((8, 8), 1, 1), ((17, 29), 2, 3),
                                                   ((23, 64), 2, 1)])
@pytest.mark.parametrize("farthest", [False, True])
def test_composite_rows4_gives_composite_layers_values(queue, rng, shape, frames, channels,
                                                       farthest):
    """``composite_layer_rows4`` from the layers as given: composite.cl's ``composite_layer``
    values (the farthest layer's zeros may differ in sign: ``fma(keep, 0, -0)`` is +0)."""
    H, W = shape
    u0 = cla.to_device(queue, random_complex(rng, (frames, channels, H, W)))
    color, alpha = _layer(rng, H, W, channels)
    k0, k1 = ref.seed_key(int(rng.integers(0, 2 ** 40)))
    arrays = [cla.to_device(queue, a).data for a in (color, alpha)]
    rows4 = runtime.get_kernel(queue.context, "composite.cl", "composite_layer_rows4")
    u = u0.copy()
    rows4(queue, (-(-W // 4), H, frames * channels), None, u.data, *arrays, np.uint32(H),
          np.uint32(W), np.uint32(channels), np.uint32(4), np.uint32(9), k0, k1,
          np.int32(farthest))
    plain = runtime.get_kernel(queue.context, "composite.cl", "composite_layer")
    v = u0.copy()
    plain(queue, (-(-H * W // 4), channels, frames), None, v.data, *arrays,
          np.uint32(H * W), np.uint32(channels), np.uint32(4), np.uint32(9), np.uint32(0),
          k0, k1, np.int32(farthest))
    np.testing.assert_array_equal(u.get(), v.get())


def _scene(rng, H, W, C, L):
    """An MPI of L random layers (``_layer``), its optics and a seed."""
    layers = [_layer(rng, H, W, C) for _ in range(L)]
    mpi = clholo.MPI(np.stack([c for c, _ in layers]), np.stack([a for _, a in layers]),
                     np.linspace(1e-3, 3e-3, L))
    return (mpi, clholo.Optics(wavelengths=(638e-9, 520e-9, 450e-9)[:C]),
            int(rng.integers(0, 2 ** 40)))


@pytest.mark.parametrize("variant", ["cpu", "gpu"])
@pytest.mark.parametrize("shape,C,L", [((40, 64), 3, 3), ((37, 50), 2, 3), ((33, 52), 1, 2)])
def test_renderer_on_cpus_takes_blocks_and_gives_the_same_holograms(queue, rng, variant, shape,
                                                                   C, L):
    """``layer_layout="auto"`` on a CPU's two-pass renderer is ``"blocks"``; its frames are
    the row-major layout's bit for bit."""
    if not queue.device.type & cl.device_type.CPU:
        pytest.skip("the blocks layout is the CPU renderer's")
    H, W = shape
    mpi, optics, seed = _scene(rng, H, W, C, L)
    rows = HologramRenderer(mpi, optics, seed=seed, queue=queue, variant=variant,
                            layer_layout="rows")
    blocks = HologramRenderer(mpi, optics, seed=seed, queue=queue, variant=variant)
    assert rows.layer_layout == "rows" and blocks.layer_layout == "blocks"
    assert blocks.two_pass
    S = -(-H // 8)
    assert blocks.layer_bytes == 4 * (L * S * 8 * W + H * W) * (C + 1)
    _bits_equal(blocks.render(3).get().view(np.float32), rows.render(3).get().view(np.float32))


@pytest.mark.parametrize("variant", ["cpu", "gpu"])
@pytest.mark.parametrize("shape,C,L", [((40, 64), 3, 3), ((37, 50), 2, 3), ((33, 51), 1, 2)])
def test_renderer_with_planes_gives_the_same_holograms(queue, rng, variant, shape, C, L):
    """``layer_layout="planes"`` (the GPU renderers' layout once measured there): the rows
    layout's frames (values: the farthest layer's zeros may differ in sign), on either
    kernel variant."""
    H, W = shape
    mpi, optics, seed = _scene(rng, H, W, C, L)
    rows = HologramRenderer(mpi, optics, seed=seed, queue=queue, variant=variant,
                            layer_layout="rows")
    planes = HologramRenderer(mpi, optics, seed=seed, queue=queue, variant=variant,
                              layer_layout="planes")
    assert planes.layer_layout == "planes" and planes.two_pass
    assert planes.layer_bytes == 4 * (L + 1) * H * W * (C + 1)
    assert planes.layers[0][0].shape == (H, C, W, 1) and planes.layers[0][1].shape == (H, W, 1)
    np.testing.assert_array_equal(planes.render(3).get(), rows.render(3).get())


def test_layer_layout_is_checked(queue, rng):
    mpi = clholo.MPI(rng.random((2, 16, 24, 1)), rng.random((2, 16, 24)), [1e-3, 2e-3])
    optics = clholo.Optics(wavelengths=(520e-9,))
    with pytest.raises(ValueError, match="layer_layout='diagonal'"):
        HologramRenderer(mpi, optics, queue=queue, layer_layout="diagonal")
    with pytest.raises(ValueError, match="layer_layout='blocks' needs"):
        HologramRenderer(mpi, optics, queue=queue, two_pass=False, layer_layout="blocks")
    with pytest.raises(ValueError, match="layer_layout='planes' needs the two-pass layer"):
        HologramRenderer(mpi, optics, queue=queue, two_pass=False, layer_layout="planes")
    four = HologramRenderer(mpi, optics, queue=queue, two_pass=False)
    assert four.layer_layout == "rows"
