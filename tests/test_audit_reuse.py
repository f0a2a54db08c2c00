"""Objects built once and called many times, as a notebook uses them: called again after a
Ctrl-C, from a second thread, with arrays of another context or of the wrong kind; the caller's
arrays are never written.

The thread tests are deterministic: the first thread is stopped at a chosen point (between
setting a kernel's arguments and enqueueing it, between two kernels of one render) and the
second thread's whole call is run there, as an unlucky thread switch would. Where the first
holds what the second needs, the second waits and the first goes on after a short wait
(``_OTHER_WAIT_S``)."""

import inspect
import sys
import threading

import numpy as np
import pyopencl as cl
import pyopencl._cl as _cl
import pyopencl.array as cla
import pytest

import clholo
from clholo import fft
from clholo.host.scheduler import HologramRenderer

from conftest import random_complex

# how long the stopped thread waits for the other thread's call before going on (the other
# thread waits for a lock the stopped one holds, where that is fixed)
_OTHER_WAIT_S = 1.5


def _mpi(seed, L=3, H=16, W=24, C=3):
    r = np.random.default_rng(seed)
    return clholo.MPI(r.random((L, H, W, C), dtype=np.float32),
                      r.random((L, H, W), dtype=np.float32), np.linspace(1e-3, 3e-3, L))


def _interrupt_at(func, line_text):
    """A trace function that raises KeyboardInterrupt once, as ``func`` is about to run its
    line ``line_text`` (stripped): where a Ctrl-C may land between two bytecodes."""
    src, first = inspect.getsourcelines(func)
    hits = [first + i for i, text in enumerate(src) if text.strip() == line_text]
    assert len(hits) == 1, f"{line_text!r} not found once in {func.__qualname__}"
    line, code, done = hits[0], func.__code__, []

    def local(frame, event, arg):
        if event == "line" and frame.f_lineno == line and not done:
            done.append(True)
            raise KeyboardInterrupt
        return local

    def glob(frame, event, arg):
        return local if frame.f_code is code else None

    return glob, done


def _other_thread_inside(monkeypatch, targets, other, *, call=1):
    """Patch ``(owner, name)`` of ``targets`` so that their ``call``-th call from this thread
    first runs ``other()`` to its end in a second thread (waiting at most ``_OTHER_WAIT_S``
    for it), then goes on. Returns ``finish()``: joins the second thread, returns its result
    (re-raising its error)."""
    me = threading.get_ident()
    state = {"thread": None, "calls": 0}
    result = {}

    def run_other():
        try:
            result["value"] = other()
        except BaseException as exc:  # noqa: BLE001 - re-raised by finish
            result["error"] = exc

    for owner, name in targets:
        real = getattr(owner, name)

        def patched(*args, _real=real, **kwargs):
            if threading.get_ident() == me and state["thread"] is None:
                state["calls"] += 1
                if state["calls"] == call:
                    t = state["thread"] = threading.Thread(target=run_other, daemon=True)
                    t.start()
                    t.join(_OTHER_WAIT_S)
            return _real(*args, **kwargs)

        monkeypatch.setattr(owner, name, patched)

    def finish():
        assert state["thread"] is not None, "the patched call was never made"
        state["thread"].join(300)
        assert not state["thread"].is_alive(), "the other thread's call hangs"
        monkeypatch.undo()
        if "error" in result:
            raise result["error"]
        return result.get("value")

    return finish


# ------------------------------------------------------------------ FFT plans after a Ctrl-C
@pytest.mark.parametrize("which", ["FFTPlan", "RoundTripPlan"])
def test_a_plan_interrupted_between_setting_and_noting_an_argument_reads_the_next_calls_array(
        queue, rng, which):
    """A Ctrl-C landed after a kernel argument was set to this call's array but before the plan
    noted it: the plan believed the kernel still held the previous array, and the next call
    with that array transformed the interrupted call's array instead, silently."""
    shape = (2, 16, 24)
    if which == "FFTPlan":
        plan = fft.FFTPlan(shape, np.complex64, queue=queue)
        func, line = fft.FFTPlan.execute, "held[i] = v"
    else:
        plan = fft.RoundTripPlan(shape, 24, np.complex64, axis="rows", queue=queue)
        func, line = fft.RoundTripPlan._set, "self._args[index] = value"
    a = cla.to_device(queue, random_complex(rng, shape))
    b = cla.to_device(queue, random_complex(rng, shape))
    want_a = plan.execute(a).get()
    want_b = plan.execute(b).get()
    plan.execute(a).get()
    trace, done = _interrupt_at(func, line)
    before = sys.gettrace()  # a coverage run's tracer, given back after
    sys.settrace(trace)
    try:
        with pytest.raises(KeyboardInterrupt):
            plan.execute(b)
    finally:
        sys.settrace(before)
    assert done
    queue.finish()
    got = plan.execute(a).get()
    assert not np.array_equal(got, want_b), "the plan transformed the interrupted call's array"
    np.testing.assert_array_equal(got, want_a)


@pytest.mark.parametrize("two_pass", [True, False])
def test_render_after_an_interrupt_or_an_abandoned_iteration_gives_a_fresh_renderers_bits(
        queue, monkeypatch, two_pass):
    from clholo.host import runtime

    mpi = _mpi(1)
    want = HologramRenderer(mpi, clholo.Optics(), seed=3, queue=queue,
                            two_pass=two_pass).render(2).get()
    r = HologramRenderer(mpi, clholo.Optics(), seed=3, queue=queue, two_pass=two_pass,
                         frames_per_batch=1)
    real, calls = runtime.launch, []

    def launch(*args, **kwargs):
        calls.append(1)
        if len(calls) == 2:
            raise KeyboardInterrupt
        return real(*args, **kwargs)

    monkeypatch.setattr(runtime, "launch", launch)
    with pytest.raises(KeyboardInterrupt):
        r.render(2)
    monkeypatch.undo()
    assert r.render(2).get().tobytes() == want.tobytes()
    frames = r.iter_frames(2)
    next(frames)            # abandoned with its second batch enqueued
    frames.close()
    assert np.concatenate([h for _, h in r.iter_frames(2)]).tobytes() == want.tobytes()


# ------------------------------------------------------------------ FFT plans: wrong arrays
@pytest.mark.parametrize("which", ["FFTPlan", "RoundTripPlan"])
def test_a_plans_multiply_of_another_context_is_refused_by_name(queue, rng, which):
    """A multiply made in another context was launched as it was: OpenCL leaves that undefined
    (PoCL ran it; other drivers fail deep inside or read another buffer)."""
    shape = (2, 16, 24)
    plan = (fft.FFTPlan(shape, np.complex64, queue=queue) if which == "FFTPlan" else
            fft.RoundTripPlan(shape, 24, np.complex64, axis="rows", queue=queue))
    q2 = cl.CommandQueue(cl.Context([queue.device]))
    x = cla.to_device(queue, random_complex(rng, shape))
    m = cla.to_device(q2, random_complex(rng, (16, 24)))
    with pytest.raises(ValueError, match="^multiply lives in another OpenCL context.*to_device"):
        plan.execute(x, multiply=m)


def test_plan_direction_flags_take_only_bools(queue, rng):
    """``inverse="no"`` ran the inverse transform, ``multiply_even="no"`` read a quarter of a
    multiply that need not be even: silently wrong values."""
    shape = (2, 16, 24)
    x = cla.to_device(queue, random_complex(rng, shape))
    plan = fft.FFTPlan(shape, np.complex64, queue=queue)
    with pytest.raises(TypeError, match="inverse must be True or False"):
        plan.execute(x, inverse="no")
    rt = fft.RoundTripPlan(shape, 24, np.complex64, axis="rows", queue=queue)
    m = cla.to_device(queue, random_complex(rng, (16, 24)))
    with pytest.raises(TypeError, match="multiply_even must be True or False"):
        rt.execute(x, multiply=m, multiply_even="no")
    # NumPy's bools are bools
    plan.execute(x, inverse=np.bool_(True))
    rt.execute(x, multiply=m, multiply_even=np.bool_(False))
    queue.finish()


def test_fft_into_a_read_only_out_is_refused_by_name(rng):
    out = np.empty((16, 24), np.complex64)
    out.flags.writeable = False
    with pytest.raises(ValueError, match="^out is a read-only array"):
        fft.fft2(random_complex(rng, (16, 24)), out=out)


# ------------------------------------------------------------------ threads
def test_two_renderers_on_one_queue_in_two_threads_give_their_own_bits(queue):
    """Renderers of one context share the compositing kernel (runtime.get_kernel); a kernel
    object carries its arguments: the second thread's launch set them between the first
    thread's setting and enqueueing, and the first composited the second's layers into the
    second's field."""
    ra = HologramRenderer(_mpi(1), clholo.Optics(), seed=3, queue=queue)
    rb = HologramRenderer(_mpi(2), clholo.Optics(), seed=4, queue=queue)
    want_a, want_b = ra.render(2).get(), rb.render(2).get()
    mp = pytest.MonkeyPatch()
    try:
        # pyopencl's kernel call sets the arguments, then enqueues through this
        finish = _other_thread_inside(mp, [(_cl, "enqueue_nd_range_kernel")],
                                      lambda: rb.render(2).get())
        got_a = ra.render(2).get()
        got_b = finish()
    finally:
        mp.undo()
    assert got_b.tobytes() == want_b.tobytes()
    assert got_a.tobytes() == want_a.tobytes()


@pytest.mark.parametrize("where", ["device", "host"])
def test_fft2_of_one_shape_from_two_threads(queue, rng, where):
    """``fft2`` keeps one plan per shape and queue: two threads' calls set its kernels'
    arguments in between each other's launches (device arrays) or put their values into its
    buffers in turn (NumPy arrays through a non-CPU device's plan-owned buffers)."""
    fft.clear_plan_cache()
    xa, xb = random_complex(rng, (16, 24)), random_complex(rng, (16, 24))
    want_a, want_b = np.fft.fft2(xa), np.fft.fft2(xb)
    tol = 1e-4 * np.abs(want_a).max()
    mp = pytest.MonkeyPatch()
    try:
        if where == "device":
            da, db = cla.to_device(queue, xa), cla.to_device(queue, xb)
            finish = _other_thread_inside(mp, [(cl, "enqueue_nd_range_kernel")],
                                          lambda: fft.fft2(db).get())
            got_a = fft.fft2(da).get()
        else:
            plan = fft._plan_for((16, 24), np.complex64, queue, (-2, -1))
            plan._host_zero_copy = False   # the path of GPUs: the plan's own buffers
            fft.fft2(xb, queue=queue)
            # the other call runs between this call's copy in and its transform
            finish = _other_thread_inside(mp, [(plan, "execute")],
                                          lambda: fft.fft2(xb, queue=queue))
            got_a = fft.fft2(xa, queue=queue)
        got_b = finish()
    finally:
        mp.undo()
        fft.clear_plan_cache()
    assert np.abs(got_b - want_b).max() <= tol
    assert np.abs(got_a - want_a).max() <= tol, "thread a got another thread's transform"


@pytest.mark.parametrize("two_pass", [True, False])
def test_one_renderer_shared_by_two_threads(queue, two_pass):
    """One renderer's batches share its working buffers (the two-pass layer's row spectrum,
    the four-pass propagator's spectrum): a second thread's render that ran between two
    kernels of the first's left the first thread reading its leftovers."""
    r = HologramRenderer(_mpi(1), clholo.Optics(), seed=3, queue=queue, two_pass=two_pass)
    want = r.render(2).get()
    # between the row transform and the first column round trip; between the first layer's
    # forward and inverse transforms
    between = (fft.RoundTripPlan, "execute") if two_pass else (fft.FFTPlan, "execute")
    mp = pytest.MonkeyPatch()
    try:
        finish = _other_thread_inside(mp, [between],
                                      lambda: np.concatenate([h for _, h in r.iter_frames(2)]),
                                      call=1 if two_pass else 2)
        got_a = r.render(2).get()
        got_b = finish()
    finally:
        mp.undo()
    assert got_b.tobytes() == want.tobytes()
    assert got_a.tobytes() == want.tobytes()


# ------------------------------------------------------------------ renderer.prepare
def test_prepare_checks_frames_per_batch_like_iter_frames(queue):
    r = HologramRenderer(_mpi(1), clholo.Optics(), seed=3, queue=queue)
    with pytest.raises(ValueError, match="frames_per_batch"):
        r.prepare(2, frames_per_batch=-1)
    with pytest.raises(ValueError, match="frames_per_batch"):
        r.prepare(2, frames_per_batch=0)


# ------------------------------------------------------------------ phase retrieval
def _engine(queue, rng, B=4, H=16, W=24):
    from clholo.encode.sgd import slm_padded_shape
    from clholo.host.phase_retrieval import PhaseRetrieval

    optics = clholo.Optics(pitch=8e-6, wavelengths=(520e-9, 638e-9))
    target = cla.to_device(queue, random_complex(rng, (B, H, W)))
    padded = slm_padded_shape((H, W), optics, 0.04)
    return PhaseRetrieval(target, wavelengths=optics.wavelengths, pitch=optics.pitch, z=0.04,
                          padded=padded, queue=queue)


def test_set_phase_refuses_a_shorter_phase_instead_of_keeping_the_rest(queue, rng):
    """A device phase of fewer fields was copied as far as it went; the rest of the engine's
    phase stayed what it was (and NumPy mistakes ended in a bare AssertionError of pyopencl's)."""
    eng = _engine(queue, rng)
    with pytest.raises(ValueError, match=r"^phase must be float32 \(4, 16, 24\)"):
        eng.set_phase(cla.zeros(queue, (2, 16, 24), np.float32))
    with pytest.raises(ValueError, match=r"^phase must be float32 \(4, 16, 24\)"):
        eng.set_phase(cla.zeros(queue, (4, 16, 24), np.float64))
    with pytest.raises(ValueError, match=r"^phase must be real radians of shape \(4, 16, 24\)"):
        eng.set_phase(np.zeros((2, 16, 24), np.float32))
    with pytest.raises(ValueError, match="^phase must be real radians"):
        eng.set_phase(np.zeros((4, 16, 24), np.complex64))


def test_set_phase_takes_a_view_and_leaves_it_alone(queue, rng):
    """A view ``phases[4:]`` (an offset into its buffer) failed with pyopencl's
    ArrayHasOffsetError."""
    eng = _engine(queue, rng)
    phases = rng.uniform(0, 2 * np.pi, (8, 16, 24)).astype(np.float32)
    dp = cla.to_device(queue, phases)
    eng.set_phase(dp[4:])
    np.testing.assert_array_equal(eng.phase.get(), phases[4:])
    eng.run(2, check_every=1)
    np.testing.assert_array_equal(dp.get(), phases)
    eng.set_phase(phases[4:].astype(np.float64))  # NumPy reals are converted
    np.testing.assert_array_equal(eng.phase.get(), phases[4:])


def test_sgd_encode_twice_with_the_same_arrays_leaves_them_alone(queue, rng):
    from clholo.encode.sgd import sgd_encode

    optics = clholo.Optics(pitch=8e-6, wavelengths=(520e-9, 638e-9))
    h = random_complex(rng, (2, 2, 16, 24))
    init = rng.uniform(0, 2 * np.pi, h.shape).astype(np.float32)
    roi = np.ones((16, 24), np.float32)
    roi[:4] = 0.5
    keep = (h.copy(), init.copy(), roi.copy())
    dh = cla.to_device(queue, h)
    kw = dict(iterations=3, progress=False, init=init, roi=roi, queue=queue)
    first = sgd_encode(h, optics, **kw).phase
    calls = []

    def progress(done, total):
        calls.append(done)
        if len(calls) == 2:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        sgd_encode(dh, optics, **{**kw, "progress": progress})
    np.testing.assert_array_equal(sgd_encode(dh, optics, **kw).phase, first)
    np.testing.assert_array_equal(sgd_encode(h, optics, **kw).phase, first)
    for a, b in zip((h, init, roi), keep):
        np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(dh.get(), keep[0])


# --- the propagator's field shapes and the transfer-function cache's count ---------------

@pytest.mark.parametrize("three_pass", [True, False])
def test_a_propagator_refuses_a_field_of_another_shape_with_as_many_elements(queue, rng,
                                                                            three_pass):
    """A ``[2, 24, 16]`` field given to a ``[2, 16, 24]`` propagator was reshaped and
    propagated as garbage; leading axes that only split the batch (``[1, 2, 16, 24]``) are
    still taken, with the same result."""
    from clholo.propagation import ASMPropagator, build_transfer_function

    prop = ASMPropagator(2, (16, 24), (20, 30), queue=queue, three_pass=three_pass)
    tf = build_transfer_function(queue, (20, 30), 1e-3, wavelengths=[520e-9], pitch=8e-6)
    u = random_complex(rng, (2, 16, 24)).astype(np.complex64)
    want = prop.apply(cla.to_device(queue, u), tf).get()
    split = prop.apply(cla.to_device(queue, u.reshape(1, 2, 16, 24)), tf).get()
    np.testing.assert_array_equal(split, want)
    swapped = cla.to_device(queue, np.ascontiguousarray(u.transpose(0, 2, 1)))
    with pytest.raises(ValueError, match=r"field.shape is \(2, 24, 16\); this propagator "
                                         r"takes 2 fields of 16x24"):
        prop.apply(swapped, tf)
    with pytest.raises(ValueError, match=r"out.shape is \(2, 24, 16\)"):
        prop.apply(cla.to_device(queue, u), tf, out=swapped)


def test_the_transfer_function_cache_counts_a_key_built_twice_once():
    """Two threads that miss on one key both build it; the second insert replaced the first
    but counted its bytes again, so the cache evicted other entries to a budget it was not
    using. The build of the other thread is made to happen inside this one's (deterministic)."""
    from clholo.propagation import TransferFunctionCache

    class Item:
        nbytes = 80

    cache = TransferFunctionCache(1000)
    inner, started = [], []

    def build():
        if not started:  # "another thread" misses and builds the same key meanwhile
            started.append(1)
            inner.append(cache.get_or_build(("k",), build))
        return Item()

    got = cache.get_or_build(("k",), build)
    assert got is inner[0]                      # one object kept and handed to both callers
    assert cache._bytes == sum(v.nbytes for v in cache._items.values()) == 80
