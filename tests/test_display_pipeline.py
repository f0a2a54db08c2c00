"""The display loop's pipelined producer (issue 23, the display goal): the device renders and
codes the next chunk while the host waits for, centres and hands over this one. The patterns,
frames, batches and scenes are those of the producer that waits for each chunk, bit for bit;
the work is enqueued ahead; a slow display still gets a batch started only once the one before
is on screen; mistakes are refused by name."""

import time

import numpy as np
import pyopencl as cl
import pyopencl.array as cla
import pytest

from clholo.encode.quantize import DeviceQuantizer, PendingPatterns
from clholo.host.display_loop import (PIPELINE_DEPTH, RENDER_CHUNK, DeviceEncoder, DisplayLoop,
                                      centre_on, dpac_encoder, phase_quantize_encoder)
from clholo.host.memory import pinned_empty
from clholo.scene import MPI, Optics
from clholo.tools.slm import MemoryDisplay

OPTICS = Optics(pitch=8e-6, wavelengths=(638e-9, 520e-9, 450e-9))


def random_mpi(rng, L=2, H=10, W=14, near=1e-3):
    return MPI(color=rng.uniform(0.05, 1, (L, H, W, 3)), alpha=rng.uniform(0.05, 1, (L, H, W)),
               depths=near + 1e-3 * np.arange(L))


class Recording(DeviceEncoder):
    """A DeviceEncoder that logs when each chunk is enqueued and waited for."""

    def __init__(self, inner: DeviceEncoder, *, delay_s: float = 0.0):
        super().__init__(inner._code, inner._quantizer_for, inner.what)
        self.log = []
        self.delay_s = delay_s      # a slower device: each chunk takes this much more

    def enqueue(self, fields, *, out=None):
        time.sleep(self.delay_s)
        pending = super().enqueue(fields, out=out)
        key = len([e for e in self.log if e[0] == "enqueue"])
        self.log.append(("enqueue", key, fields.shape[0]))
        log = self.log

        class Logged:
            shape = pending.shape

            def wait(self):
                got = pending.wait()
                log.append(("wait", key, got.shape[0]))
                return got

        return Logged()


def _run(mpi, queue, *, pipeline, frames, batches, swap=None, display_shape=(12, 18)):
    # paced fast: the display waits for the producer (it repeats meanwhile, one per ms)
    display = MemoryDisplay(display_shape[1], display_shape[0], keep=10**5, pace=True,
                            refresh_hz=1000.0)
    loop = DisplayLoop(mpi, OPTICS, display, phase_quantize_encoder(), frames_per_batch=frames,
                       seed=5, queue=queue, pipeline=pipeline)
    swapped = []

    def on_pattern(rec):
        if swap is not None and rec.batch == 1 and not swapped:
            loop.set_scene(swap)
            swapped.append(1)

    records = loop.run(batches=batches, on_pattern=on_pattern)
    records += loop.run(batches=1)          # a second run goes on where the first stopped
    return loop, display, records


@pytest.mark.parametrize("frames", [1, 3, RENDER_CHUNK + 3])
def test_pipelined_patterns_are_those_of_the_producer_that_waits(queue, rng, frames):
    """Same bits, same frames, batches and scenes (a scene swap of another size included),
    with batches of one chunk and of two chunks of different sizes."""
    mpi, other = random_mpi(rng), random_mpi(rng, L=3, H=8, W=16, near=2e-3)
    got = _run(mpi, queue, pipeline=True, frames=frames, batches=4, swap=other)
    want = _run(mpi, queue, pipeline=False, frames=frames, batches=4, swap=other)
    assert got[0]._pipelined() and not want[0]._pipelined()
    new = [[(r.batch, r.frame, r.channel, r.scene) for r in recs if not r.repeated]
           for recs in (got[2], want[2])]
    assert new[0] == new[1]
    frames_shown = [f for _, f, c, _ in new[0] if c == 0]
    assert frames_shown == list(range(5 * frames))       # 4 batches, then 1, no gap
    assert {s for *_, s in new[0]} == {0, 1}
    shown = {}
    for loop, display, recs in (got, want):
        for rec, pattern in zip(recs, display.history):
            if not rec.repeated:
                shown.setdefault((rec.frame, rec.channel), []).append(pattern)
    assert all(len(v) == 2 for v in shown.values())
    for (frame, channel), (a, b) in shown.items():
        np.testing.assert_array_equal(a, b, err_msg=f"frame {frame} colour {channel}")
    assert any(p.any() for p, _ in shown.values())


def test_the_next_chunk_is_enqueued_before_this_one_is_waited_for(queue, rng):
    """Two chunks a batch (8 + 3 frames): the second is enqueued before the first is read; the
    display waits (it shows at once), so the next batch's first chunk is enqueued before the
    last chunk of this one is read; never more than PIPELINE_DEPTH chunks in flight."""
    encode = Recording(phase_quantize_encoder())
    loop = DisplayLoop(random_mpi(rng), OPTICS,
                       MemoryDisplay(18, 12, pace=True, refresh_hz=1000.0), encode,
                       frames_per_batch=RENDER_CHUNK + 3, queue=queue)
    records = loop.run(batches=3)
    assert len({r.batch for r in records}) >= 3
    log = encode.log
    order = [(kind, key) for kind, key, _ in log]
    assert order.index(("enqueue", 1)) < order.index(("wait", 0))
    assert order.index(("enqueue", 2)) < order.index(("wait", 1))   # the next batch's first
    assert [n for kind, _, n in log if kind == "enqueue"][:4] == [RENDER_CHUNK, 3] * 2
    inflight = peak = 0
    for kind, _, _ in log:
        inflight += 1 if kind == "enqueue" else -1
        peak = max(peak, inflight)
    assert peak == PIPELINE_DEPTH
    # waited for in the order enqueued
    assert [key for kind, key, _ in log if kind == "wait"] == sorted(
        key for kind, key, _ in log if kind == "wait")


def test_a_slow_display_still_gets_a_batch_started_only_once_the_one_before_is_shown(queue,
                                                                                     rng):
    """The display is the slower (paced at 60 Hz): the producer does not work a batch ahead,
    so latency stays at one batch: batch k+1 starts after batch k-1 has left the screen."""
    encode = Recording(phase_quantize_encoder())
    display = MemoryDisplay(18, 12, pace=True, refresh_hz=60.0)
    loop = DisplayLoop(random_mpi(rng), OPTICS, display, encode, frames_per_batch=2,
                       queue=queue)
    records = loop.run(batches=5)
    last_shown, starts = {}, {}
    for r in records:
        last_shown[r.batch] = r.shown_s
        starts.setdefault(r.batch, r.render_start_s)
    for k in range(1, 4):
        assert last_shown[k - 1] < starts[k + 1] < last_shown[k]
    assert loop._pipelined()


def test_pipelined_loop_stops_at_seconds_inside_a_large_batch(queue, rng):
    """400 frames a batch, 0.05 s a chunk (20 s for the batch), on a 0.3 s run: the pipelined
    producer stops enqueueing at the time, within about two chunks, hands over the batch cut
    short and shows frames from 0 on, in order."""
    encode = Recording(phase_quantize_encoder(), delay_s=0.05)
    display = MemoryDisplay(18, 12, pace=True, refresh_hz=240.0)
    loop = DisplayLoop(random_mpi(rng), OPTICS, display, encode, frames_per_batch=400,
                       queue=queue)
    t = time.monotonic()
    records = loop.run(seconds=0.3)
    assert time.monotonic() - t < 3.0
    assert 0 < len(records) < 1200 and display.count == len(records)
    assert max(n for _, _, n in encode.log) <= RENDER_CHUNK
    enqueued = sum(n for kind, _, n in encode.log if kind == "enqueue")
    assert enqueued <= 20 * RENDER_CHUNK, enqueued     # 0.3 s is 6 chunks, not 50
    frames = [r.frame for r in records if r.channel == 0 and not r.repeated]
    assert frames == list(range(len(frames)))


def test_pipelined_dpac_is_the_encoders_own_result(queue, rng):
    """DPAC through the pipelined producer: the patterns the encoder gives called directly."""
    from clholo.host.scheduler import HologramRenderer

    mpi = random_mpi(rng, H=16, W=16)
    encode = dpac_encoder(OPTICS, z_slm=0.02, luts=["linear:255", "linear:230", "linear:200"])
    display = MemoryDisplay(16, 16, keep=10**5, pace=True, refresh_hz=1000.0)
    loop = DisplayLoop(mpi, OPTICS, display, encode, frames_per_batch=3, seed=3, queue=queue)
    records = loop.run(batches=2)
    assert loop._pipelined()
    r = HologramRenderer(mpi, OPTICS, seed=3, frames_per_batch=3, queue=queue)
    fields = np.concatenate([f for _, f in r.iter_frames(6, frames_per_batch=3)])
    want = encode(fields)
    for rec, shown in zip(records, display.history):
        np.testing.assert_array_equal(shown, want[rec.frame, rec.channel])


def test_pipeline_mistakes_are_refused_by_name(queue, rng):
    mpi = random_mpi(rng)
    display = MemoryDisplay(18, 12)

    def plain(fields):
        return phase_quantize_encoder()(fields)

    with pytest.raises(TypeError, match="pipeline=True needs an encoder with enqueue"):
        DisplayLoop(mpi, OPTICS, display, plain, queue=queue, pipeline=True)
    with pytest.raises(TypeError, match="^pipeline must be"):
        DisplayLoop(mpi, OPTICS, display, phase_quantize_encoder(), queue=queue, pipeline="yes")
    # a plain callable is called and waited for (pipeline=None)
    loop = DisplayLoop(mpi, OPTICS, display, plain, queue=queue)
    assert not loop._pipelined() and loop.run(batches=1)
    # an out-of-order queue: refused where pipelining is asked for, in turn where it is not
    props = cl.command_queue_properties.OUT_OF_ORDER_EXEC_MODE_ENABLE
    if queue.device.queue_properties & props:
        ooo = cl.CommandQueue(queue.context, queue.device, properties=props)
        with pytest.raises(ValueError, match="pipeline=True needs an in-order queue"):
            DisplayLoop(mpi, OPTICS, display, phase_quantize_encoder(), queue=ooo,
                        pipeline=True)
        assert not DisplayLoop(mpi, OPTICS, display, phase_quantize_encoder(),
                               queue=ooo)._pipelined()

    # an encoder on another queue of the context: refused where pipelining is asked for (the
    # loop's queue would not wait for the encoder's reads of a chunk before rendering the next
    # into the same buffer), in turn where it is not, with the same patterns
    other = cl.CommandQueue(queue.context, queue.device)
    with pytest.raises(ValueError, match="pipeline=True needs the encoder on the loop's queue"):
        DisplayLoop(mpi, OPTICS, display, phase_quantize_encoder(queue=other), queue=queue,
                    pipeline=True)
    kept = MemoryDisplay(18, 12, keep=10**4, pace=True, refresh_hz=1000.0)
    loop = DisplayLoop(mpi, OPTICS, kept, phase_quantize_encoder(queue=other), queue=queue,
                       frames_per_batch=2)
    assert not loop._pipelined()
    records = loop.run(batches=2)
    same = MemoryDisplay(18, 12, keep=10**4, pace=True, refresh_hz=1000.0)
    want = DisplayLoop(mpi, OPTICS, same, phase_quantize_encoder(), queue=queue,
                       frames_per_batch=2)
    want_records = want.run(batches=2)
    shown = {(r.frame, r.channel): p for r, p in zip(records, kept.history) if not r.repeated}
    for r, p in zip(want_records, same.history):
        if not r.repeated and (r.frame, r.channel) in shown:
            np.testing.assert_array_equal(shown[r.frame, r.channel], p)

    class NoWait(DeviceEncoder):
        def enqueue(self, fields, *, out=None):
            return super().enqueue(fields, out=out).wait()    # an array: no wait()

    base = phase_quantize_encoder()
    loop = DisplayLoop(mpi, OPTICS, display, NoWait(base._code, base._quantizer_for, "x"),
                       queue=queue)
    with pytest.raises(TypeError, match=r"encode.enqueue must return a pending result"):
        loop.run(batches=1)


def _held(queue):
    """A user event that holds ``queue`` (a marker waits for it) until it is set."""
    ev = cl.UserEvent(queue.context)
    cl.enqueue_marker(queue, wait_for=[ev])
    return ev


def test_enqueue_read_returns_before_the_device_has_run(queue, rng):
    """With the queue held, enqueue_read returns, its result is not done; once released,
    wait() gives the host quantiser's levels (same float32 phases), into the array given. A
    timer releases the queue after 20 s whatever happens, so a read that waits on the host
    fails the test instead of hanging it."""
    import threading

    from clholo.encode.quantize import quantize

    luts = ["linear:255", "linear:230", "linear:200"]
    phase = rng.uniform(-3, 3, (2, 3, 5, 7)).astype(np.float32)
    dq = DeviceQuantizer(luts, 3)
    dq(phase[:1], queue=queue)                 # its tables go to the device once, first
    d_phase = cla.to_device(queue, phase)
    out = pinned_empty(queue, phase.shape, np.uint8)
    out[...] = 0
    ev = _held(queue)
    release = threading.Timer(
        20.0, lambda: ev.set_status(cl.command_execution_status.COMPLETE))
    release.start()
    try:
        t = time.monotonic()
        pending = dq.enqueue_read(d_phase, out=out)
        returned_s = time.monotonic() - t
        assert isinstance(pending, PendingPatterns) and not pending.done()
        assert pending.shape == phase.shape and not out.any()
    finally:
        if release.is_alive():
            release.cancel()
            ev.set_status(cl.command_execution_status.COMPLETE)
    assert returned_s < 10.0, f"enqueue_read waited {returned_s:.1f} s for the held queue"
    got = pending.wait()
    assert got is out and pending.done() and pending.wait() is out
    np.testing.assert_array_equal(got, quantize(phase, luts))


def test_enqueue_read_refuses_bad_out_and_reports_nan_at_wait(queue, rng):
    phase = rng.uniform(-3, 3, (1, 2, 4, 6)).astype(np.float32)
    dq = DeviceQuantizer("linear", 2)
    d_phase = cla.to_device(queue, phase)
    for bad in (np.empty((1, 2, 4, 5), np.uint8), np.empty(phase.shape, np.int16),
                np.empty((1, 2, 6, 4), np.uint8).transpose(0, 1, 3, 2)):
        with pytest.raises(ValueError, match="^out must be"):
            dq.enqueue_read(d_phase, out=bad)
    phase[0, 1, 2, 3] = np.nan
    pending = dq.enqueue_read(cla.to_device(queue, phase))
    with pytest.raises(ValueError, match="NaN.*colour 1"):
        pending.wait()


def test_pinned_empty_is_host_memory_the_device_reads_into(queue, rng):
    a = rng.standard_normal((3, 17)).astype(np.float32)
    host = pinned_empty(queue, a.shape, np.float32)
    assert host.shape == a.shape and host.dtype == np.float32 and host.flags.writeable
    cl.enqueue_copy(queue, host, cla.to_device(queue, a).data, is_blocking=True)
    np.testing.assert_array_equal(host, a)
    with pytest.raises(ValueError, match="not empty"):
        pinned_empty(queue, (0, 4), np.uint8)


def test_centre_on_into_an_array_clears_its_margins(rng):
    a = rng.integers(1, 256, (2, 3, 5), dtype=np.uint8)
    out = np.full((2, 7, 9), 7, np.uint8)
    assert centre_on(a, (7, 9), out=out) is out
    np.testing.assert_array_equal(out, centre_on(a, (7, 9)))
    assert out.sum() == a.astype(int).sum()
    same = np.full((2, 3, 5), 9, np.uint8)
    np.testing.assert_array_equal(centre_on(a, (3, 5), out=same), a)
    with pytest.raises(ValueError, match="^out must have shape"):
        centre_on(a, (7, 9), out=np.empty((2, 9, 7), np.uint8))


def test_encoders_reuse_their_device_buffers(queue, rng):
    """Batch after batch an encoder codes into the same device buffers (its memory pool):
    after two calls nothing more is allocated (DPAC's FFT plan keeps its last output until the
    next call, so two of those take turns), and the patterns stay the same."""
    from conftest import random_complex

    fields = cla.to_device(queue, random_complex(rng, (2, 3, 12, 10)))
    for encode in (phase_quantize_encoder(), dpac_encoder(OPTICS, z_slm=0.02)):
        first = encode(fields)
        np.testing.assert_array_equal(encode(fields), first)
        pool = encode._pools[queue.context.int_ptr]
        managed = pool.managed_bytes
        assert managed > 0 and pool.active_blocks <= 1     # handed back after the wait
        for _ in range(3):
            pending = encode.enqueue(fields)
            np.testing.assert_array_equal(pending.wait(), first)
        assert encode._pools[queue.context.int_ptr] is pool
        assert pool.managed_bytes == managed, (encode, managed, pool.managed_bytes)


@pytest.mark.parametrize("make_encoder", [phase_quantize_encoder,
                                          lambda: dpac_encoder(OPTICS, z_slm=0.02)],
                         ids=["quantize", "dpac"])
def test_a_running_loop_makes_no_device_buffers(queue, rng, monkeypatch, make_encoder):
    """Once a loop runs, a batch makes no device buffer: the render writes into the loop's
    buffer, the encoder codes through its memory pool and the patterns are read into page-locked
    arrays kept from batch to batch. A buffer made and freed per batch can wait for an idle
    device on some drivers (CUDA's cudaFree does) and would undo the pipeline. Every buffer
    counts here, also those made outside a pool (e.g. a propagator's output)."""
    made = []

    class CountedBuffer(cl.Buffer):
        def __init__(self, *args, **kwargs):
            made.append(args[2] if len(args) > 2 else kwargs.get("size"))
            super().__init__(*args, **kwargs)

    display = MemoryDisplay(18, 12, keep=10**4, pace=True, refresh_hz=1000.0)
    loop = DisplayLoop(random_mpi(rng, L=3), OPTICS, display, make_encoder(),
                       frames_per_batch=5, seed=2, queue=queue, pipeline=True)
    loop.run(batches=3)             # the first batches make the buffers and fill the pools
    monkeypatch.setattr(cl, "Buffer", CountedBuffer)
    loop.run(batches=4)
    assert display.count >= 7 * 5 * OPTICS.channels
    assert made == [], f"{len(made)} device buffers made in 4 batches ({made[:6]} bytes)"
