"""ASM propagation in three passes over memory (row FFT, column round trip with the transfer
function, row inverse; clholo.propagation.ASMPropagator three_pass) against the reference and
the four-pass form, complex64 and complex128."""

import numpy as np
import pyopencl.array as cla
import pytest

from clholo import reference as ref
from clholo.host import runtime
from clholo.propagation import ASMPropagator, build_transfer_function
from conftest import random_complex
from tolerances import rel_l2, tol


@pytest.mark.parametrize("dtype", [np.complex64, np.complex128])
@pytest.mark.parametrize("shape,padded", [((24, 40), (48, 80)), ((27, 20), (45, 32)),
                                          ((33, 50), (40, 64))])
def test_three_pass_matches_reference_and_four_pass(queue, cl_device, rng, dtype, shape,
                                                    padded):
    if dtype == np.complex128 and not runtime.has_fp64(cl_device):
        pytest.skip("device without fp64")
    B, wl, pitch, dz = 3, (638e-9, 450e-9), 8e-6, 1.7e-3
    three = ASMPropagator(B, shape, padded, dtype=dtype, queue=queue)
    four = ASMPropagator(B, shape, padded, dtype=dtype, queue=queue, three_pass=False)
    assert three.three_pass and not four.three_pass
    tf = build_transfer_function(queue, padded, dz, wavelengths=wl, pitch=pitch, dtype=dtype)
    u = random_complex(rng, (B,) + shape, dtype)
    got = three.apply(cla.to_device(queue, u), tf).get()
    want = np.stack([ref.propagate(u[b], dz, wavelength=wl[b % 2], pitch=pitch, pad=padded)
                     for b in range(B)])
    name = "float32" if dtype == np.complex64 else "float64"
    assert rel_l2(got, want) <= tol("propagate", name)["rel_l2"]
    d = cla.to_device(queue, u)
    four.apply(d, tf, out=d)
    assert rel_l2(got, d.get()) <= tol("propagate", name)["rel_l2"]


# callbacks written for a 2D plan: b the field, (row, col) the pixel of the H x W field
LOAD_SRC = """
real2 clholo_load(real2 v, long b, int row, int col, __global const real2 *f, uint h, uint w)
{
    const real2 g = f[((size_t)b * h + row) * w + col];
    return (real2)(v.x * g.x - v.y * g.y, v.x * g.y + v.y * g.x);
}
"""
STORE_SRC = """
void clholo_store(__global real2 *p, real2 v, long b, int row, int col, real a,
                  __global const real2 *c, uint h, uint w)
{
    *p = a * v + c[((size_t)b * h + row) * w + col];
}
"""


@pytest.mark.parametrize("three_pass", [None, False])
@pytest.mark.parametrize("shape,padded", [((24, 40), (48, 80)), ((27, 21), (45, 32))])
def test_callbacks_see_the_field_in_both_forms(queue, rng, shape, padded, three_pass):
    from clholo.fft import FFTCallback

    B, wl, pitch, dz = 3, (638e-9, 450e-9), 8e-6, 1.7e-3
    (H, W) = shape
    load = FFTCallback(LOAD_SRC, params=["__global const real2 *", "uint", "uint"])
    store = FFTCallback(STORE_SRC, params=["real", "__global const real2 *", "uint", "uint"])
    prop = ASMPropagator(B, shape, padded, queue=queue, load_callback=load,
                         store_callback=store, three_pass=three_pass)
    assert prop.three_pass == (three_pass is None)
    tf = build_transfer_function(queue, padded, dz, wavelengths=wl, pitch=pitch)
    u, f, c = (random_complex(rng, (B,) + shape) for _ in range(3))
    df, dc = cla.to_device(queue, f), cla.to_device(queue, c)
    got = prop.apply(cla.to_device(queue, u), tf,
                     load_args=[df, np.uint32(H), np.uint32(W)],
                     store_args=[0.75, dc, np.uint32(H), np.uint32(W)]).get()
    want = np.stack([ref.propagate(u[b] * f[b], dz, wavelength=wl[b % 2], pitch=pitch,
                                   pad=padded) for b in range(B)]) * 0.75 + c
    assert rel_l2(got, want) <= tol("propagate", "float32")["rel_l2"]
    # without arguments the plain plans run
    plain = prop.apply(cla.to_device(queue, u), tf).get()
    want = np.stack([ref.propagate(u[b], dz, wavelength=wl[b % 2], pitch=pitch, pad=padded)
                     for b in range(B)])
    assert rel_l2(plain, want) <= tol("propagate", "float32")["rel_l2"]


def test_callback_arguments_need_their_callback(queue):
    prop = ASMPropagator(1, (8, 8), (16, 16), queue=queue)
    u = cla.zeros(queue, (1, 8, 8), np.complex64)
    tf = build_transfer_function(queue, (16, 16), 1e-3, wavelengths=(520e-9,), pitch=8e-6)
    for kw in ("load_args", "store_args"):
        with pytest.raises(ValueError, match=kw.replace("args", "callback")):
            prop.apply(u, tf, **{kw: []})


@pytest.mark.parametrize("three_pass", [None, False])
def test_callbacks_must_be_fft_callbacks(queue, three_pass):
    src = "real2 clholo_load(real2 v, long b, int r, int c) { return v; }"
    for kw in ("load_callback", "store_callback"):
        with pytest.raises(TypeError, match=f"{kw} must be a clholo.fft.FFTCallback"):
            ASMPropagator(1, (8, 8), (16, 16), queue=queue, three_pass=three_pass,
                          **{kw: src})



@pytest.mark.parametrize("dtype", [np.complex64, np.complex128])
@pytest.mark.parametrize("three_pass", [None, False])
def test_even_factors_give_the_same_bits(queue, cl_device, rng, dtype, three_pass):
    """apply() with the propagator's even_factors(tf) is apply(tf, tf_even=True), bit for bit,
    in both forms; factors made for another propagator are refused."""
    if dtype == np.complex128 and not runtime.has_fp64(cl_device):
        pytest.skip("device without fp64")
    B, shape, padded = 3, (27, 20), (45, 32)
    prop = ASMPropagator(B, shape, padded, dtype=dtype, queue=queue, three_pass=three_pass)
    tf = build_transfer_function(queue, padded, 1.7e-3, wavelengths=(638e-9, 450e-9),
                                 pitch=8e-6, dtype=dtype)
    u = cla.to_device(queue, random_complex(rng, (B,) + shape, dtype))
    want = prop.apply(u, tf, tf_even=True).get()
    got = prop.apply(u, prop.even_factors(tf)).get()
    assert np.abs(want).max() > 0
    np.testing.assert_array_equal(got, want)
    other = ASMPropagator(B, shape, (48, 40), dtype=dtype, queue=queue, three_pass=three_pass)
    tf_other = build_transfer_function(queue, (48, 40), 1.7e-3, wavelengths=(638e-9,),
                                       pitch=8e-6, dtype=dtype)
    with pytest.raises(ValueError, match="even_factors"):
        prop.apply(u, other.even_factors(tf_other))
