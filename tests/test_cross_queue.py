"""A device array made on one queue and given to clholo with another queue of the same context
(issue 23's pipelined display loop made this a real path): the other queue waits for what was
enqueued on the array's queue before reading it; an array of another context is refused by
name. OpenCL orders commands within one in-order queue only, so without the wait a kernel
could read the array before it was written, silently."""

import threading
import time

import numpy as np
import pyopencl as cl
import pyopencl.array as cla
import pytest

from clholo.elementwise import complex_multiply
from clholo.encode.dpac import dpac_encode, dpac_encode_device
from clholo.scene import Optics

from conftest import random_complex
from tolerances import rel_l2, tol


def _held(queue):
    """A user event that holds ``queue`` (a marker waits for it) until it is set; a timer sets
    it after 20 s whatever happens, so a wait on the host fails the test, never hangs it."""
    ev = cl.UserEvent(queue.context)
    cl.enqueue_marker(queue, wait_for=[ev])
    timer = threading.Timer(20.0, lambda: ev.set_status(cl.command_execution_status.COMPLETE))
    timer.daemon = True
    timer.start()
    return ev, timer


def _release(ev, timer):
    if timer.is_alive():
        timer.cancel()
        ev.set_status(cl.command_execution_status.COMPLETE)


@pytest.mark.parametrize("shape", [(5, 7), (3, 16, 9)])
def test_a_write_still_queued_on_the_arrays_queue_is_seen(queue, rng, shape):
    other = cl.CommandQueue(queue.context, queue.device)
    a0, a1 = random_complex(rng, shape), random_complex(rng, shape)
    b = random_complex(rng, shape[-2:])
    da = cla.to_device(queue, a0)
    db = cla.to_device(queue, b)
    src = cla.to_device(queue, a1)
    queue.finish()
    ev, timer = _held(queue)
    try:
        # the new values are copied on the array's own queue, behind the held event (a copy
        # between device buffers: a write from the host may wait on the host, holding the GIL)
        cl.enqueue_copy(queue, da.data, src.data)
        out = complex_multiply(da, db, queue=other)       # enqueued on the other queue
    finally:
        _release(ev, timer)
    assert out.queue == other
    got = out.get()
    assert rel_l2(got, a1.astype(np.complex128) * b) <= tol("elementwise", np.complex64)["rel_l2"]


def test_dpac_of_holograms_rendered_on_another_queue(queue, rng):
    """The display loop's encoder on a queue of its own: its DPAC waits for the frames."""
    optics = Optics(pitch=8e-6, wavelengths=(520e-9, 638e-9))
    other = cl.CommandQueue(queue.context, queue.device)
    h0, h1 = (random_complex(rng, (2, 2, 12, 10)) for _ in range(2))
    dh = cla.to_device(queue, h0)
    src = cla.to_device(queue, h1)
    dpac_encode_device(dh, optics, z_slm=0.01, queue=other).get()   # its filter, made once
    queue.finish()
    ev, timer = _held(queue)
    try:
        cl.enqueue_copy(queue, dh.data, src.data)
        t = time.monotonic()
        phase = dpac_encode_device(dh, optics, z_slm=0.01, queue=other)
        took = time.monotonic() - t
    finally:
        _release(ev, timer)
    assert took < 10.0, f"dpac_encode_device waited {took:.1f} s on the host"
    # the same kernels on the same values: the same bits
    np.testing.assert_array_equal(phase.get(), dpac_encode(h1, optics, z_slm=0.01, queue=queue))


def test_an_array_of_another_context_is_refused_by_name(queue, rng):
    ctx2 = cl.Context([queue.device])
    q2 = cl.CommandQueue(ctx2)
    a = cla.to_device(q2, random_complex(rng, (4, 4)))
    b = cla.to_device(queue, random_complex(rng, (4,)))
    with pytest.raises(ValueError, match="^b is a device array of another OpenCL context"):
        complex_multiply(a, b)


@pytest.mark.parametrize("variant", ["cpu", "gpu"])
@pytest.mark.parametrize("which", ["FFTPlan", "RoundTripPlan"])
def test_fft_plans_wait_for_the_queues_of_their_arrays(queue, rng, variant, which):
    """An FFT plan's first kernel waits for the queues its input, output and multiply were
    made on (markers there), so values still being written on those are the ones transformed;
    the round-trip plan's too."""
    import clholo.fft as F
    from clholo import reference as ref

    other = cl.CommandQueue(queue.context, queue.device)
    x0, x1 = random_complex(rng, (2, 12, 20)), random_complex(rng, (2, 12, 20))
    m0, m1 = random_complex(rng, (12, 20)), random_complex(rng, (12, 20))
    if which == "FFTPlan":
        plan = F.FFTPlan((2, 12, 20), np.complex64, queue=other, variant=variant)
        want = np.fft.fft2(x1.astype(np.complex128)) * m1
    else:
        plan = F.RoundTripPlan((2, 12, 20), 20, axis="rows", queue=other, variant=variant)
        want = ref.round_trip(x1, 20, axis="rows", first="forward", multiply=m1, mid_n=20)
    dx, dm = cla.to_device(queue, x0), cla.to_device(queue, m0)
    sx, sm = cla.to_device(queue, x1), cla.to_device(queue, m1)
    out = cla.empty(other, dx.shape, np.complex64)
    plan.execute(dx, out=out, multiply=dm).get()          # built and primed before the hold
    queue.finish()
    ev, timer = _held(queue)
    try:
        cl.enqueue_copy(queue, dx.data, sx.data)
        cl.enqueue_copy(queue, dm.data, sm.data)
        got = plan.execute(dx, out=out, multiply=dm)
    finally:
        _release(ev, timer)
    assert rel_l2(got.get(), want) <= tol("fft", np.float32)["rel_l2"]
