"""The FFT plans take ``x`` and ``out`` as two views of one device buffer when they share no
bytes (``x=frames[0]``, ``out=frames[1]``): the plans pass each as its buffer and element
offset, so such views are separate arrays. Views that share some bytes without being the same
array are refused, naming the fix."""

import numpy as np
import pyopencl.array as cla
import pytest

from clholo import fft as F
from clholo import reference as ref
from conftest import random_complex
from tolerances import rel_l2, tol

VARIANTS = ["cpu", "gpu"]


def _close(got, want):
    assert rel_l2(got, want) <= tol("fft", np.float32)["rel_l2"]


@pytest.mark.parametrize("variant", VARIANTS)
@pytest.mark.parametrize("shape, output_shape", [((24, 40), None), ((16, 30), (10, 25))])
def test_fft_plan_between_two_views_of_one_buffer(queue, rng, variant, shape, output_shape):
    frames = random_complex(rng, (3,) + shape)
    dev = cla.to_device(queue, frames)
    plan = F.FFTPlan(shape, np.complex64, queue=queue, variant=variant,
                     output_shape=output_shape)
    want = np.fft.fft2(frames[0].astype(np.complex128))
    if output_shape is None:
        got = plan.execute(dev[0], out=dev[2]).get()
        _close(got, want)
        _close(dev[2].get(), want)
    else:  # a cropped output in the next frame's bytes
        flat = dev.reshape(-1)
        out = flat[frames[0].size:frames[0].size + int(np.prod(output_shape))].reshape(
            output_shape)
        _close(plan.execute(dev[0], out=out).get(), want[:output_shape[0], :output_shape[1]])
    np.testing.assert_array_equal(dev[0].get(), frames[0])  # x is not written
    if output_shape is None:
        np.testing.assert_array_equal(dev[1].get(), frames[1])  # nor the frame between


@pytest.mark.parametrize("variant", VARIANTS)
def test_fft_plan_refuses_views_that_share_some_bytes(queue, rng, variant):
    dev = cla.to_device(queue, random_complex(rng, (3, 16, 24)))
    plan = F.FFTPlan((16, 24), np.complex64, queue=queue, variant=variant)
    flat = dev.reshape(-1)
    shifted = flat[8:8 + 16 * 24].reshape(16, 24)  # half a row on
    with pytest.raises(ValueError, match="shares no bytes"):
        plan.execute(dev[0], out=shifted)
    same = flat[:16 * 24].reshape(16, 24)  # another view of x's bytes: in place
    before = dev[0].get().astype(np.complex128)
    plan.execute(dev[0], out=same)
    _close(dev[0].get(), np.fft.fft2(before))


@pytest.mark.parametrize("variant", VARIANTS)
@pytest.mark.parametrize("axis", ["rows", "cols"])
def test_round_trip_between_two_views_of_one_buffer(queue, rng, variant, axis):
    B, rows, cols = 2, 12, 20
    n = 30 if axis == "rows" else 15
    x = random_complex(rng, (2 * B, rows, cols))
    m = random_complex(rng, (rows, n) if axis == "rows" else (n, cols))
    dev = cla.to_device(queue, x)
    plan = F.RoundTripPlan((B, rows, cols), n, np.complex64, axis=axis, queue=queue,
                           variant=variant)
    got = plan.execute(dev[:B], out=dev[B:], multiply=cla.to_device(queue, m)).get()
    want = ref.round_trip(x[:B].astype(np.complex128), n, axis=axis, multiply=m)
    _close(got, want)
    np.testing.assert_array_equal(dev[:B].get(), x[:B])
    with pytest.raises(ValueError, match="shares no bytes"):
        plan.execute(dev[:B], out=dev[1:B + 1])
