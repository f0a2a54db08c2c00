"""kernels/fast_sincos.h: sin and cos against float64, on every phase the Philox stream can
produce and on random arguments of both signs up to 1e5 (where the builtin takes over), in every
width (clholo_sincos4, 8 and 16), which must agree bit for bit."""

import functools

import numpy as np
import pyopencl as cl
import pyopencl.array as cla
import pytest

from clholo.host import runtime
from tolerances import tol

PROBE = """
#include "fast_sincos.h"
__kernel void probe(__global const float *x, __global float *s, __global float *c, const uint n)
{
    const uint i = get_global_id(0) * WIDTH;
    floatW v = (floatW)(0.0f);
    for (uint k = 0; k < WIDTH; ++k)
        if (i + k < n) ((float *)&v)[k] = x[i + k];
    floatW si, co;
    SINCOS(v, si, co);
    for (uint k = 0; k < WIDTH; ++k)
        if (i + k < n) { s[i + k] = ((float *)&si)[k]; c[i + k] = ((float *)&co)[k]; }
}
"""
WIDTHS = {4: "s = clholo_sincos4(v, &c)", 8: "s = clholo_sincos8(v, &c)",
          16: "clholo_sincos16(v, &s, &c)"}  # the call of each width
# the phases' form: no test of the range (only for arguments within it)
PHASE_FORM = "clholo_sincos16_phase(v, &s, &c)"


@functools.lru_cache(maxsize=None)
def _probe(context, width, call=None):
    source = (f"#define WIDTH {width}u\n#define floatW float{width}\n"
              f"#define SINCOS(v, s, c) {call or WIDTHS[width]}\n" + PROBE)
    name = f"fast_sincos_probe{width}{'_phase' if call else ''}.cl"
    return cl.Kernel(runtime.build_program(context, name, source=source), "probe")


def _sincos(queue, x, width, call=None):
    kern = _probe(queue.context, width, call)
    dx = cla.to_device(queue, x)
    s, c = cla.empty_like(dx), cla.empty_like(dx)
    runtime.launch(kern, queue, ((x.size + width - 1) // width,), None, dx.data, s.data,
                   c.data, np.uint32(x.size))
    return s.get(), c.get()


def _check(queue, x):
    """Every width within the table's bound of float64, and the wide forms the same bits as the
    float4 one (composite.cl uses float4, the CPU round trip's composite float16)."""
    got = {width: _sincos(queue, x, width) for width in WIDTHS}
    for width in (8, 16):
        _same_bits(x, got[4], got[width], width)
    x64 = x.astype(np.float64)
    limit = tol("fast_sincos", np.float32)["max_abs"]
    for width, (sw, cw) in got.items():
        err_s = np.abs(sw.astype(np.float64) - np.sin(x64))
        err_c = np.abs(cw.astype(np.float64) - np.cos(x64))
        worst = int(np.argmax(np.maximum(err_s, err_c)))
        assert max(err_s.max(), err_c.max()) <= limit, (width, x[worst], err_s[worst],
                                                        err_c[worst])


def _same_bits(x, narrow, wide, width):
    """The wide form's results are the float4 form's bit for bit where both take the fast path
    (a vector with one argument beyond CLHOLO_SINCOS_FAST_MAX goes to the builtin whole, so
    compare the width-aligned groups that lie within it), but for the sign of a zero (sin(-0):
    the widths' code contracts x - j pi/2 differently there; no phase of the stream is
    zero)."""
    (s, c), (sw, cw) = narrow, wide
    pad = -x.size % width
    groups = np.concatenate([np.abs(x), np.zeros(pad, x.dtype)]).reshape(-1, width)
    fast = np.repeat((groups <= np.float32(12000.0)).all(axis=1), width)[:x.size]
    np.testing.assert_array_equal(sw[fast], s[fast])
    same = fast & (s != 0)
    np.testing.assert_array_equal(sw.view(np.uint32)[same], s.view(np.uint32)[same])
    np.testing.assert_array_equal(cw.view(np.uint32)[fast], c.view(np.uint32)[fast])


def test_every_phase_of_the_philox_stream(queue):
    """The phases composite.cl draws: 2 pi ((x >> 8) + 0.5) 2^-24 in float32, all 2^24 of them
    (HOLOGRAPHY.md section 4), in that order of float32 operations."""
    k = np.arange(1 << 24, dtype=np.float32)
    phases = np.float32(2 * np.pi) * ((k + np.float32(0.5)) * np.float32(2.0 ** -24))
    _check(queue, phases)


def test_the_phase_form_gives_the_general_forms_bits_on_every_phase(queue, rng):
    """clholo_sincos16_phase (the composites' form, without the range test) against
    clholo_sincos16 on all 2^24 phases of the stream, bit for bit, and on random arguments
    within the fast range of both signs (every quadrant)."""
    k = np.arange(1 << 24, dtype=np.float32)
    phases = np.float32(2 * np.pi) * ((k + np.float32(0.5)) * np.float32(2.0 ** -24))
    inside = rng.uniform(-12000.0, 12000.0, 100_003).astype(np.float32)
    for x in (phases, inside):
        s, c = _sincos(queue, x, 16)
        sp, cp = _sincos(queue, x, 16, PHASE_FORM)
        np.testing.assert_array_equal(sp.view(np.uint32), s.view(np.uint32))
        np.testing.assert_array_equal(cp.view(np.uint32), c.view(np.uint32))


@pytest.mark.parametrize("span", [7.0, 400.0, 2e4, 1e5])
def test_random_arguments_of_both_signs(queue, rng, span):
    """SGD's phases wander without bound: both signs, every quadrant, the Cody-Waite range and
    beyond it (the builtin's exact reduction), an odd count (ragged vectors)."""
    x = rng.uniform(-span, span, 300_001).astype(np.float32)
    x[:8] = [0.0, -0.0, np.pi / 2, -np.pi / 2, np.pi, 3 * np.pi / 2, 12000.0, -12000.5]
    _check(queue, x)


def test_quadrant_boundaries(queue):
    """Arguments one float32 step either side of every multiple of pi/4 up to 64 turns: where
    the quadrant and the swap of sin and cos change."""
    m = np.arange(-1024, 1025) * (np.pi / 4)
    centre = m.astype(np.float32)
    x = np.concatenate([np.nextafter(centre, -np.inf), centre, np.nextafter(centre, np.inf)])
    _check(queue, x.astype(np.float32))


def test_the_quadrant_is_rint_bit_for_bit(queue, rng):
    """fast_sincos.h rounds y = x 2/pi to its quadrant with CLHOLO_QUADRANT, (y + 1.5 2^23) -
    1.5 2^23 (PoCL's rint was 17 instructions): the builtin rint's value for every |y| < 2^22, ties to even
    included (every half-integer up to 4096 and either side of it), random y, and zeros."""
    source = """
    #include "fast_sincos.h"
    __kernel void quadrant(__global const float *y, __global float *trick, __global float *r)
    {
        const uint i = get_global_id(0);
        const float v = y[i];
        trick[i] = CLHOLO_QUADRANT(v);
        r[i] = rint(v);
    }
    """
    kern = cl.Kernel(runtime.build_program(queue.context, "quadrant_probe.cl", source=source),
                     "quadrant")
    half = np.arange(-8192, 8193, dtype=np.float32) * np.float32(0.5)
    y = np.concatenate([half, np.nextafter(half, np.float32(-np.inf)),
                        np.nextafter(half, np.float32(np.inf)),
                        rng.uniform(-4e6, 4e6, 100_000).astype(np.float32),
                        rng.uniform(-8, 8, 100_000).astype(np.float32),
                        np.float32([0.0, 2 ** 22 - 0.5, -(2 ** 22) + 0.5])])
    dy = cla.to_device(queue, y)
    trick, rint = cla.empty_like(dy), cla.empty_like(dy)
    runtime.launch(kern, queue, (y.size,), None, dy.data, trick.data, rint.data)
    np.testing.assert_array_equal(trick.get(), rint.get())
    np.testing.assert_array_equal(trick.get(), np.rint(y))
