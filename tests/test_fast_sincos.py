"""kernels/fast_sincos.h: sin and cos against float64, on every phase the Philox stream can
produce and on random arguments of both signs up to 1e5 (where the builtin takes over)."""

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
    const uint i = get_global_id(0) * 4u;
    float4 v = (float4)(0.0f);
    for (uint k = 0; k < 4u; ++k)
        if (i + k < n) ((float *)&v)[k] = x[i + k];
    float4 co;
    const float4 si = clholo_sincos4(v, &co);
    for (uint k = 0; k < 4u; ++k)
        if (i + k < n) { s[i + k] = ((float *)&si)[k]; c[i + k] = ((float *)&co)[k]; }
}
"""


@functools.lru_cache(maxsize=None)
def _probe(context):
    return cl.Kernel(runtime.build_program(context, "fast_sincos_probe.cl", source=PROBE),
                     "probe")


def _sincos(queue, x):
    kern = _probe(queue.context)
    dx = cla.to_device(queue, x)
    s, c = cla.empty_like(dx), cla.empty_like(dx)
    runtime.launch(kern, queue, ((x.size + 3) // 4,), None, dx.data, s.data, c.data,
                   np.uint32(x.size))
    return s.get().astype(np.float64), c.get().astype(np.float64)


def _check(queue, x):
    s, c = _sincos(queue, x)
    x64 = x.astype(np.float64)
    limit = tol("fast_sincos", np.float32)["max_abs"]
    err_s, err_c = np.abs(s - np.sin(x64)), np.abs(c - np.cos(x64))
    worst = int(np.argmax(np.maximum(err_s, err_c)))
    assert max(err_s.max(), err_c.max()) <= limit, (x[worst], err_s[worst], err_c[worst])
    return max(err_s.max(), err_c.max())


def test_every_phase_of_the_philox_stream(queue):
    """The phases composite.cl draws: 2 pi ((x >> 8) + 0.5) 2^-24 in float32, all 2^24 of them
    (HOLOGRAPHY.md section 4), in that order of float32 operations."""
    k = np.arange(1 << 24, dtype=np.float32)
    phases = np.float32(2 * np.pi) * ((k + np.float32(0.5)) * np.float32(2.0 ** -24))
    _check(queue, phases)


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
