"""Enqueueing returns at once (issue 23, "host side"): a render or an FFT enqueued behind a
queue held by a user event returns while the event is unset, and gives, once the event is set,
the same bytes as without the hold; launch checks are made once per kernel and sizes."""

import threading

import numpy as np
import pyopencl as cl
import pyopencl.array as cla
import pytest

import clholo
from clholo import fft
from clholo.host import runtime
from clholo.host.kernel_args import COMPOSITE_LAYER
from clholo.host.scheduler import HologramRenderer

COMPLETE = cl.command_execution_status.COMPLETE
# a hang guard, not a timing: an enqueue that waits for the held queue never returns, and the
# test then releases the queue and fails instead of hanging
HANG_GUARD_S = 300


def _mpi(rng, L, H, W, C):
    return clholo.MPI(rng.random((L, H, W, C), dtype=np.float32),
                      rng.random((L, H, W), dtype=np.float32), np.linspace(1e-3, 4e-3, L))


def _behind_held_queue(queue, enqueue):
    """Run ``enqueue()`` while ``queue`` is held by an unset user event; returns its result
    once the event is set. Fails if ``enqueue`` does not return while the event is unset."""
    hold = cl.UserEvent(queue.context)
    cl.enqueue_marker(queue, wait_for=[hold])
    result = {}

    def run():
        try:
            result["value"] = enqueue()
        except BaseException as exc:  # noqa: BLE001 - reported below
            result["error"] = exc

    t = threading.Thread(target=run, daemon=True)
    t.start()
    t.join(HANG_GUARD_S)
    returned = not t.is_alive()
    held = hold.command_execution_status != COMPLETE
    hold.set_status(COMPLETE)  # release the queue whatever happened
    t.join()
    queue.finish()
    assert returned, "the enqueue waited for the device (it did not return while the queue " \
                     "was held)"
    assert held
    if "error" in result:
        raise result["error"]
    return result.get("value")


@pytest.mark.parametrize("two_pass", [True, False])
def test_render_returns_while_the_queue_is_held(queue, rng, two_pass):
    # 8 layers: 17 kernels write the row spectrum in place (pyopencl's Array.add_event waits
    # on the host once 13 events are held)
    mpi = _mpi(rng, 8, 24, 40, 3)
    r = HologramRenderer(mpi, clholo.Optics(), seed=11, queue=queue, two_pass=two_pass)
    want = r.render(2).get()
    out = cla.empty(queue, (2, 3, 24, 40), np.complex64)
    r.prepare(2)

    def enqueue():
        r.render(2, out=out)
        # nothing has run yet: the render's last kernel waits behind the held queue
        assert out.events and out.events[-1].command_execution_status != COMPLETE
        assert len(out.events) == 1  # the event list does not grow with the layers

    _behind_held_queue(queue, enqueue)
    assert out.get().tobytes() == want.tobytes()


def test_render_in_batches_returns_while_the_queue_is_held(queue, rng):
    mpi = _mpi(rng, 7, 16, 24, 3)
    r = HologramRenderer(mpi, clholo.Optics(), seed=2, queue=queue, frames_per_batch=2)
    want = r.render(5).get()
    out = cla.empty(queue, (5, 3, 16, 24), np.complex64)
    _behind_held_queue(queue, lambda: r.render(5, out=out))
    assert out.get().tobytes() == want.tobytes()


@pytest.mark.parametrize("variant", ["cpu", "gpu", "gpu-global"])
def test_fft_in_place_many_times_returns_while_the_queue_is_held(queue, rng, variant):
    shape = (2, 24, 360)
    x0 = (rng.standard_normal(shape) + 1j * rng.standard_normal(shape)).astype(np.complex64)
    plan = fft.FFTPlan(shape, np.complex64, queue=queue, variant=variant)
    m = cla.to_device(queue, rng.standard_normal(shape[1:]).astype(np.complex64))

    def steps(x):
        for k in range(20):
            plan.execute(x, out=x, inverse=bool(k % 2), multiply=m if k % 3 == 0 else None)
        return x

    want = steps(cla.to_device(queue, x0)).get()
    x = cla.to_device(queue, x0)
    queue.finish()
    _behind_held_queue(queue, lambda: steps(x))
    assert len(x.events) == 1
    assert x.get().tobytes() == want.tobytes()


def test_launch_checks_once_per_kernel_and_sizes(queue, monkeypatch):
    calls = []
    real = runtime.check_launch
    monkeypatch.setattr(runtime, "check_launch",
                        lambda *a, **k: (calls.append(a[2]), real(*a, **k))[1])
    knl = runtime.get_kernel(queue.context, "composite.cl", "composite_layer")
    u = cla.empty(queue, (1, 1, 4, 8), np.complex64)
    c = cla.zeros(queue, 32, np.float32)
    args = COMPOSITE_LAYER.args(u=u.data, color=c.data, alpha=c.data, npix=32, n_channels=1,
                                layer=0, frame0=0, colour0=0, key_lo=1, key_hi=0, farthest=1)
    for _ in range(3):
        runtime.launch(knl, queue, (8, 1, 1), None, *args)
    runtime.launch(knl, queue, (4, 1, 1), None, *args)
    assert calls == [(8, 1, 1), (4, 1, 1)]
    # a launch the device cannot run is still stopped, after passing ones of that kernel
    with pytest.raises(runtime.LaunchLimitError, match="composite_layer"):
        runtime.launch(knl, queue, (8, 1, 1, 1), None, *args)
    queue.finish()

    # an FFT plan checks its launches at its first execute only
    plan = fft.FFTPlan((4, 16, 20), np.complex64, queue=queue, variant="gpu-global")
    x = cla.zeros(queue, (4, 16, 20), np.complex64)
    del calls[:]
    for _ in range(3):
        plan.execute(x, out=x)
    assert len(calls) == len(plan._launches) > 1
    queue.finish()


def test_launch_check_sees_a_stand_in_device_after_a_passing_launch(queue, monkeypatch):
    import dataclasses

    knl = runtime.get_kernel(queue.context, "composite.cl", "composite_layer")
    u = cla.empty(queue, (1, 1, 4, 8), np.complex64)
    c = cla.zeros(queue, 32, np.float32)
    args = COMPOSITE_LAYER.args(u=u.data, color=c.data, alpha=c.data, npix=32, n_channels=1,
                                layer=0, frame0=0, colour0=0, key_lo=1, key_hi=0, farthest=1)
    runtime.launch(knl, queue, (8, 1, 1), (8, 1, 1), *args)
    real = runtime._limits_of_device
    monkeypatch.setattr(runtime, "_limits_of_device",
                        lambda dev: dataclasses.replace(real(dev), max_item_sizes=(4, 4, 4)))
    with pytest.raises(runtime.LaunchLimitError, match="CL_DEVICE_MAX_WORK_ITEM_SIZES"):
        runtime.launch(knl, queue, (8, 1, 1), (8, 1, 1), *args)
    queue.finish()
