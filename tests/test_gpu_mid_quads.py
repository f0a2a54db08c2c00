"""The GPU round trips' mid step by quads (``FFT_MID_QUADS``, the tunable setting ``mid_quads``, off
until a GPU measures it): a mid callback with a four-element form (the composite, SGD's Adam
step) gets four elements adjacent along a row of the frame at a time in a sweep over local
memory, one Philox block per four pixels, instead of one element at a time folded into the
first transform's last stage. Only the order of the work changes: every result keeps its bits.
Run on PoCL through ``variant="gpu"`` plans."""

import numpy as np
import pyopencl as cl
import pyopencl.array as cla
import pytest

import clholo
from clholo import fft as F
from clholo.host.tuning import SETTINGS
from clholo import reference as ref
from clholo.host.scheduler import COMPOSITE_STORE_PARAMS, HologramRenderer

from conftest import random_complex

LAYOUTS = {"rows": None, "blocks": {"CLHOLO_LAYER_BLOCKS": True},
           "planes": {"CLHOLO_LAYER_BLOCKS": True, "CLHOLO_LAYER_ROWS": 1}}


def _callback(layout):
    return F.FFTCallback('#include "composite_store.h"\n', params=COMPOSITE_STORE_PARAMS,
                         defines=LAYOUTS[layout])


def _layer(rng, H, W, C, layout):
    """A random layer with transparent and opaque pixels, in ``layout``."""
    color = rng.random((H, W, C)).astype(np.float32)
    alpha = rng.random((H, W)).astype(np.float32)
    alpha[rng.random((H, W)) < 0.1] = 0.0
    alpha[rng.random((H, W)) < 0.05] = 1.0
    if layout == "rows":
        return color, alpha
    return ref.layer_blocks(color, alpha, rows=8 if layout == "blocks" else 1)


def _options(plan):
    program = plan._kernel.program
    return program.get_build_info(program.devices[0], cl.program_build_info.OPTIONS)


def _bits_equal(a, b):
    np.testing.assert_array_equal(np.asarray(a).view(np.uint32), np.asarray(b).view(np.uint32))


def _frame(axis, rows, cols, n):
    return (n, cols) if axis == "cols" else (rows, n)


@pytest.mark.parametrize("first", ["inverse", "forward"])
@pytest.mark.parametrize("layout", list(LAYOUTS))
@pytest.mark.parametrize("axis,B,H,W,n,multiply", [
    ("rows", 6, 16, 24, 32, None), ("rows", 3, 13, 30, 45, None),   # 45: no quads, elements
    ("rows", 2, 9, 21, 30, "plain"), ("rows", 4, 8, 64, 64, None),
    ("rows", 3, 11, 22, 36, "even"),                                 # 22: a last, partial quad
    ("cols", 3, 16, 24, 32, "even"), ("cols", 2, 13, 20, 27, "plain"),
    ("cols", 6, 12, 19, 25, None), ("cols", 3, 10, 36, 16, "even")])
def test_quads_give_the_elements_bits(queue, rng, monkeypatch, layout, axis, B, H, W, n,
                                      multiply, first):
    """The composite as the mid callback of a row or column round trip (GPU kernels), either
    transform first (the conjugations around the step), with and without a multiply between
    the transforms, W not a multiple of 4, lines whose length (rows)
    or group (columns) does not split into quads: the same bits by quads as element by
    element."""
    C = 3 if B % 3 == 0 else 2 if B % 2 == 0 else 1
    x = cla.to_device(queue, random_complex(rng, (B, H, W)))
    arrays = [cla.to_device(queue, a) for a in _layer(rng, H, W, C, layout)]
    k0, k1 = ref.seed_key(int(rng.integers(0, 2 ** 40)))
    tail = [np.uint32(W), np.uint32(C), np.uint32(3), np.uint32(7), k0, k1]
    m, even = None, False
    if multiply is not None:
        frame = random_complex(rng, (C,) + _frame(axis, H, W, n))
        if multiply == "even":  # f[l, k] == f[-l, -k]: only a quarter is read
            frame = frame + np.roll(frame[:, ::-1, ::-1], 1, axis=(1, 2))
        m, even = cla.to_device(queue, frame.astype(np.complex64)), multiply == "even"
    mid_n = W if axis == "rows" else H
    got = {}
    for quads in (False, True):
        monkeypatch.setattr(SETTINGS["mid_quads"], "default", quads)
        plan = F.RoundTripPlan((B, H, W), n, axis=axis, first=first, mid_n=mid_n,
                               mid_callback=_callback(layout), queue=queue, variant="gpu")
        assert f"-DFFT_MID_QUADS={int(quads)}" in _options(plan)
        got[quads] = plan.execute(x, multiply=m, multiply_even=even,
                                  mid_args=arrays + tail).get()
    assert np.isfinite(got[True]).all() and np.abs(got[True]).max() > 0
    _bits_equal(got[True].view(np.float32), got[False].view(np.float32))


def test_cpu_strips_ignore_the_setting(queue, rng, monkeypatch):
    """The CPU kernels call the quad form wherever they hold runs of four already: the
    setting is the GPU kernels' alone."""
    monkeypatch.setattr(SETTINGS["mid_quads"], "default", True)
    plan = F.RoundTripPlan((3, 8, 16), 16, axis="rows", first="inverse", mid_n=16,
                           mid_callback=_callback("rows"), queue=queue, variant="cpu")
    assert "-DFFT_MID_QUADS=0" in _options(plan)


@pytest.mark.parametrize("layout", ["rows", "planes"])
@pytest.mark.parametrize("shape,C,L", [((24, 40), 3, 3), ((21, 30), 2, 2)])
def test_renderer_with_quads_gives_the_same_holograms(queue, rng, monkeypatch, layout, shape,
                                                      C, L):
    """A two-pass render on the GPU kernels: the same frames by quads, bit for bit."""
    H, W = shape
    mpi = clholo.MPI(rng.random((L, H, W, C)), rng.random((L, H, W)),
                     np.linspace(1e-3, 3e-3, L))
    optics = clholo.Optics(wavelengths=(638e-9, 520e-9, 450e-9)[:C])
    seed = int(rng.integers(0, 2 ** 40))
    frames = []
    for quads in (False, True):
        monkeypatch.setattr(SETTINGS["mid_quads"], "default", quads)
        r = HologramRenderer(mpi, optics, seed=seed, queue=queue, variant="gpu",
                             layer_layout=layout)
        assert r.two_pass and r.layer_layout == layout
        frames.append(r.render(2).get())
    _bits_equal(frames[1].view(np.float32), frames[0].view(np.float32))


def test_sgd_round_trips_with_quads_keep_their_bits(queue, rng, monkeypatch):
    """SGD's Adam step (a mid callback with a four-element form too) by quads: the same phase,
    moments, gradient and loss after three steps."""
    from test_encode import gpu_round_trip_steps

    runs = gpu_round_trip_steps(queue, int(rng.integers(2 ** 32)), monkeypatch,
                                SETTINGS["mid_quads"], "default", (False, True))
    for name in ("phase", "adam_m", "grad", "loss"):
        np.testing.assert_array_equal(runs[1][name], runs[0][name], err_msg=name)
