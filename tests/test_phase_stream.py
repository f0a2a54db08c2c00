"""The phase stream itself pinned, not only raw Philox words (HOLOGRAPHY.md section 4).

The bit patterns below were worked out once from the text of HOLOGRAPHY.md section 4 with the
independent pure-Python Philox of :func:`spec_phase` (Python integers, no NumPy uint32 tricks),
and then written down. They pin what known answers on raw Philox words cannot: the counter
layout ``(p // 4, layer, frame, colour)``, the key ``(seed & 0xffffffff, seed >> 32)``, the word
``p % 4``, the ``>> 8`` and the ``+ 0.5``, and (through the renderer) that layer 0 is the
nearest. A reordered counter or a dropped ``+ 0.5`` in both kernel and reference is caught here.
"""

import numpy as np
import pyopencl as cl
import pyopencl.array as cla
import pytest

import clholo
from clholo import reference
from clholo.random import random_phases

M32 = 0xFFFFFFFF

# (seed, layer, frame, colour, y, x, W) -> float32 bit pattern of the phase
PINNED = [
    ((0, 0, 0, 0, 0, 0, 16), 0x40207753),
    ((1, 3, 7, 2, 5, 9, 33), 0x3F8DA413),
    ((2 ** 40 + 12345, 31, 23, 1, 100, 77, 384), 0x3F3DE206),
    ((2 ** 64 - 1, 0, 2 ** 32 - 1, 2, 0, 3, 4), 0x40AAC0BC),
    ((987654321, 12, 0, 0, 1, 2, 3), 0x3F7ABFE8),
    ((20261121, 0, 1, 2, 3, 5, 16), 0x40A401E2),
    ((20261121, 0, 1, 2, 15, 15, 16), 0x40A0978D),
    ((20261121, 1, 1, 2, 3, 5, 16), 0x40B74181),
    ((20261121, 1, 0, 0, 8, 0, 16), 0x400A408E),
]


def spec_phase(seed, layer, frame, colour, y, x, W) -> np.float32:
    """HOLOGRAPHY.md section 4 read literally, on Python integers (Random123's Philox4x32-10:
    10 rounds, the key bumped by the Weyl constants before every round but the first)."""
    p = y * W + x
    c0, c1, c2, c3 = p // 4, layer, frame, colour
    k0, k1 = seed & M32, seed >> 32
    for r in range(10):
        if r:
            k0, k1 = (k0 + 0x9E3779B9) & M32, (k1 + 0xBB67AE85) & M32
        p0, p1 = 0xD2511F53 * c0, 0xCD9E8D57 * c2
        c0, c1, c2, c3 = (p1 >> 32) ^ c1 ^ k0, p1 & M32, (p0 >> 32) ^ c3 ^ k1, p0 & M32
    word = (c0, c1, c2, c3)[p % 4]
    t = np.float32(word >> 8) + np.float32(0.5)
    return np.float32(np.float32(2 * np.pi) * t) * np.float32(2.0 ** -24)


def _bits(x) -> int:
    return int(np.asarray(x, np.float32).view(np.uint32))


@pytest.mark.parametrize("case,bits", PINNED)
def test_the_pins_follow_the_written_spec(case, bits):
    assert _bits(spec_phase(*case)) == bits


@pytest.mark.parametrize("case,bits", PINNED)
def test_reference_phases_match_the_pins(case, bits):
    seed, layer, frame, colour, y, x, W = case
    phi = reference.random_phase((y + 1, W), seed=seed, frame=frame, colour=colour, layer=layer)
    assert _bits(phi[y, x]) == bits


def test_device_phases_match_the_pins(queue):
    for (seed, layer, frame, colour, y, x, W), bits in PINNED:
        phi = random_phases((y + 1, W), seed=seed, layer=layer, frames=1, colours=1,
                            frame0=frame, colour0=colour, queue=queue).get()
        assert _bits(phi[0, 0, y, x]) == bits, (seed, layer, frame, colour, y, x, W)


@pytest.mark.parametrize("layer", [0, 1])
def test_renderer_draws_layer_i_for_the_ith_nearest_layer(queue, layer):
    # Two layers on a 16x16 grid with circular propagation (pad = the field itself, where the
    # band limit cuts nothing at these distances), so propagating back is exact: the field at
    # the emitting layer is sqrt(c) exp(i phi) with phi from the pinned stream. Layer 0 (the
    # nearest) opaque hides layer 1; layer 0 transparent shows layer 1 alone.
    seed, frame, colour, W = 20261121, 1, 2, 16
    depths = np.array([1e-3, 1.5e-3])
    alpha = np.zeros((2, W, W), np.float32)
    alpha[layer] = 1.0
    color = np.full((2, W, W, 3), 0.25, np.float32)
    mpi = clholo.MPI(color, alpha, depths)
    holo = clholo.render_hologram(mpi, clholo.Optics(), frames=2, seed=seed, pad=(W, W),
                                  queue=queue)
    at_layer = clholo.propagate(holo[frame, colour], -depths[layer],
                                wavelength=clholo.Optics().wavelengths[colour], pitch=8e-6,
                                pad=(W, W), queue=queue)
    np.testing.assert_allclose(np.abs(at_layer), 0.5, atol=1e-4)
    for (s, lay, f, c, y, x, w), bits in PINNED:
        if (s, lay, f, c, w) == (seed, layer, frame, colour, W):
            want = np.float32(np.array(bits, np.uint32).view(np.float32))
            got = np.angle(at_layer[y, x]) % (2 * np.pi)
            assert abs(np.angle(np.exp(1j * (got - want)))) < 1e-4, (y, x)


PHASES_N = """
#include "random_phase.h"
__kernel void phases(__global float *out, uint layer, uint frame, uint colour, uint key_lo,
                     uint key_hi)
{
    /* work-item i: Philox blocks N i .. N i + N - 1, one per lane; pixel 4 block + j */
    const uint i = get_global_id(0);
    uintN lane;
    for (int l = 0; l < N; ++l) ((uint *)&lane)[l] = l;
    floatN ph[4];
    PHASE_BLOCKS((uintN)(N * i) + lane, layer, frame, colour, key_lo, key_hi, ph);
    for (int j = 0; j < 4; ++j)
        for (int l = 0; l < N; ++l)
            out[4 * N * i + 4 * l + j] = ((float *)&ph[j])[l];
}
"""


@pytest.mark.parametrize("width", [8, 16])
@pytest.mark.parametrize("seed", [0, 20261121, 2 ** 64 - 1])
def test_vector_block_phases_are_the_stream_bit_for_bit(queue, rng, seed, width):
    """random_phase.h's uint8 and uint16 Philox (products from 64-bit multiplies; the CPU row
    round trip's composite draws eight rows by two blocks with the uint16 one) give the
    reference stream's phases bit for bit (layer, frame and colour words up to 2^31)"""
    from clholo.host import runtime

    source = (f"#define N {width}\n#define uintN uint{width}\n#define floatN float{width}\n"
              f"#define PHASE_BLOCKS clholo_phase_blocks{width}\n" + PHASES_N)
    prg = runtime.build_program(queue.context, f"random_phase{width}.cl", source=source)
    knl = cl.Kernel(prg, "phases")
    n = 64  # work-items: 64 * 4 * width pixels
    layer, frame, colour = (int(v) for v in rng.integers(0, 2 ** 31, 3))
    k0, k1 = reference.seed_key(seed)
    out = cla.empty(queue, (n * 4 * width,), np.float32)
    knl(queue, (n,), None, out.data, np.uint32(layer), np.uint32(frame), np.uint32(colour),
        k0, k1)
    want = reference.random_phase((1, n * 4 * width), seed=seed, frame=frame, colour=colour,
                                  layer=layer)[0]
    np.testing.assert_array_equal(out.get().view(np.uint32), want.view(np.uint32))
