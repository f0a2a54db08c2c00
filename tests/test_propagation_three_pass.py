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


def test_three_pass_refuses_a_store_callback(queue):
    from clholo.fft import FFTCallback

    cb = FFTCallback("void clholo_store(__global real2 *p, real2 v, long b, int r, int c)"
                     "{ *p = v; }")
    with pytest.raises(ValueError, match="three_pass=True"):
        ASMPropagator(1, (8, 8), (16, 16), queue=queue, store_callback=cb, three_pass=True)
    assert not ASMPropagator(1, (8, 8), (16, 16), queue=queue, store_callback=cb).three_pass
