"""Limits of counters, indices and sizes found by two audits (2026-12: the phase stream's
32-bit counters, frame counts of a display loop, a long-lived renderer): each was a silent
wrong result (another frame's phases, a wrapped frame counter), work or memory spent before a
refusal, a refusal after part of the output was written, or a bare error from NumPy; each is
now refused by name before any work, or bounded."""

import tracemalloc
import types

import numpy as np
import pyopencl.array as cla
import pytest

import clholo
from clholo.errors import InputError, InputTypeError

TOP = 2 ** 32  # frames, layers and colours are 32-bit counter words of the phase stream


def _mpi(channels=1, shape=(16, 16), layers=2, seed=0):
    rng = np.random.default_rng(seed)
    return clholo.MPI(color=rng.random((layers,) + shape + (channels,)),
                      alpha=rng.random((layers,) + shape),
                      depths=[1e-3 * (k + 1) for k in range(layers)])


def _optics():
    return clholo.Optics(wavelengths=[520e-9])


def _rpws(queue, **kw):
    from clholo.baselines.rpws import Primitives
    from clholo.host.rpws import RPWSRenderer

    K = 3
    prims = Primitives(xy=np.array([[8, 8], [6, 9], [10, 5]], np.float32),
                       conic=np.tile(np.array([[0.1, 0.0, 0.1]], np.float32), (K, 1)),
                       opacity=np.full(K, 0.8, np.float32),
                       color=np.full((K, 1), 0.7, np.float32),
                       depths=np.array([1e-3, 1.5e-3, 2e-3]), radius=np.full(K, 6.0),
                       shape=(16, 16))
    return RPWSRenderer(prims, _optics(), seed=5, queue=queue, **kw)


def _python_peak(fn) -> int:
    """Peak bytes Python allocated while ``fn()`` ran."""
    tracemalloc.start()
    try:
        fn()
        return tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()


# ------------------------------------------------------------------------------------------
# the RPWS renderer's frame counter

@pytest.mark.parametrize("start", [TOP - 2, TOP, TOP + 5])
def test_rpws_iter_frames_past_the_stream_is_refused_at_the_call(queue, start):
    """``iter_frames(4, start=2**32-2)`` yielded 4 frames whose last two were frames 0 and 1
    bit for bit (the kernel's uint frame counter wrapped); ``start=2**32`` was a bare
    OverflowError. The MPI renderer's message now, before any batch."""
    r = _rpws(queue, frames_per_batch=4)
    with pytest.raises(InputError, match=r"frames must lie in \[0, 2\*\*32\), got "
                                         rf"{start}\.\.{start + 4}: .*start \+ frames"):
        r.iter_frames(4, start=start)  # at the call: no next() needed


def test_rpws_top_of_the_stream_renders_and_is_not_frame_zero(queue):
    """The last two frames of the stream stay accepted (and are not frames 0 and 1)."""
    r = _rpws(queue, frames_per_batch=4)
    (t0, top), = list(r.iter_frames(2, start=TOP - 2))
    (_, low), = list(r.iter_frames(2, start=0))
    assert t0 == TOP - 2 and top.shape[0] == 2
    assert not np.array_equal(top, low)


def test_method_render_refuses_frames_past_the_stream_before_the_renderer():
    """``Method.render(start=)`` reached the RPWS renderer, which wrapped; now the range is
    refused before any renderer is built (no scene is even looked at)."""
    from clholo import methods

    with pytest.raises(InputError, match=r"frames must lie in \[0, 2\*\*32\)"):
        methods.get_method("rpws").render(None, _optics(), frames=4, start=TOP - 2)
    with pytest.raises(InputTypeError, match=r"start must be a whole number >= 0, got 2\.5"):
        methods.get_method("mpi").render(None, _optics(), frames=4, start=2.5)


def test_rpws_batches_are_made_as_they_come(queue):
    """``_iter_device_batches`` listed every batch first (a display loop's frame count of
    10**8 at one frame a batch: gigabytes before frame one)."""
    r = _rpws(queue, frames_per_batch=1)
    next(iter(r.iter_frames(1)))  # kernels built before the measurement

    def first_batch():
        it = r.iter_frames(10 ** 6)
        next(it)
        it.close()

    peak = _python_peak(first_batch)
    queue.finish()
    assert peak < 16 * 2 ** 20, f"{peak / 2**20:.0f} MiB of Python objects before frame one"


# ------------------------------------------------------------------------------------------
# the MPI renderer: the whole range before any batch, batches made lazily

def test_iter_frames_past_the_stream_is_refused_at_the_call_not_part_way(queue):
    """``iter_frames(6, start=2**32-3, frames_per_batch=1)`` yielded frames 2**32-3 and
    2**32-2 and then raised; ``frames=10**10`` was a MemoryError with an empty message after
    20 s and 7 GB (every batch listed first)."""
    r = clholo.HologramRenderer(_mpi(), _optics(), queue=queue, frames_per_batch=1)
    with pytest.raises(InputError, match=r"frames must lie in \[0, 2\*\*32\), got "
                                         r"4294967293\.\.4294967299"):
        r.iter_frames(6, start=TOP - 3, frames_per_batch=1)
    with pytest.raises(InputError, match=r"frames must lie in \[0, 2\*\*32\), got "
                                         r"0\.\.10000000000"):
        r.iter_frames(10 ** 10)


def test_iter_hologram_frames_refuses_before_building_the_renderer(monkeypatch):
    """``iter_hologram_frames(frames=10**10)`` built the renderer (uploading the layers) and
    then listed 10**10 batches."""
    from clholo import hologram

    def built(*a, **k):
        raise AssertionError("the renderer was built before the frame count was checked")

    monkeypatch.setattr(hologram, "HologramRenderer", built)
    with pytest.raises(InputError, match=r"frames must lie in \[0, 2\*\*32\)"):
        next(clholo.iter_hologram_frames(_mpi(), _optics(), frames=10 ** 10))


def test_iter_frames_makes_batches_as_they_come(queue):
    """Every batch was listed before the first (frames=10**8 at one frame a batch: 7.3 GB
    RSS and 19.5 s, then an empty MemoryError). Now the first batch costs what a batch
    costs."""
    r = clholo.HologramRenderer(_mpi(), _optics(), queue=queue, frames_per_batch=1)
    r.render(1).get()  # kernels and plans built before the measurement

    def first_batch():
        it = r.iter_frames(10 ** 6, frames_per_batch=1)
        next(it)
        it.close()

    peak = _python_peak(first_batch)
    queue.finish()
    assert peak < 16 * 2 ** 20, f"{peak / 2**20:.0f} MiB of Python objects before frame one"


def test_enqueue_frames_past_the_stream_writes_nothing(queue):
    """A range crossing 2**32 was refused at the batch that crossed it, after the earlier
    batches had been written into ``out``."""
    r = clholo.HologramRenderer(_mpi(), _optics(), queue=queue, frames_per_batch=1)
    out = cla.to_device(queue, np.full((6, 1, 16, 16), 7 + 7j, np.complex64))
    with pytest.raises(InputError, match=r"frames must lie in \[0, 2\*\*32\)"):
        r.enqueue_frames(TOP - 3, 6, out)
    queue.finish()
    assert np.all(out.get() == np.complex64(7 + 7j)), "frames were written before the refusal"


@pytest.mark.parametrize("frame0", [2.9, np.float64(2.5), True])
def test_enqueue_batch_refuses_fractional_frame0(queue, frame0):
    """``enqueue_batch(2.9, ...)`` (public) rendered frame 2, where ``enqueue_frames`` refused
    the same value; ``True`` was frame 1."""
    r = clholo.HologramRenderer(_mpi(), _optics(), queue=queue)
    buf = cla.empty(queue, (1, 1, 16, 16), np.complex64)
    with pytest.raises(InputTypeError, match=r"frame0 must be a whole number >= 0"):
        r.enqueue_batch(frame0, 1, buf)


@pytest.mark.parametrize("frame0", [-1, np.int64(-1), TOP])
def test_enqueue_batch_refuses_frames_outside_the_stream(queue, frame0):
    r = clholo.HologramRenderer(_mpi(), _optics(), queue=queue)
    buf = cla.empty(queue, (1, 1, 16, 16), np.complex64)
    with pytest.raises(InputError, match=r"frame0 must be >= 0|frames must lie in \[0, 2\*\*32"):
        r.enqueue_batch(frame0, 1, buf)


# ------------------------------------------------------------------------------------------
# the phase stream's indices

@pytest.mark.parametrize("kw, error, message", [
    (dict(frame0=2.7), InputTypeError, r"frame0 must be a whole number >= 0, got 2\.7"),
    (dict(layer=1.9), InputTypeError, r"layer must be a whole number >= 0, got 1\.9"),
    (dict(colour0=1.5), InputTypeError, r"colour0 must be a whole number >= 0, got 1\.5"),
    (dict(frame0=True), InputTypeError, r"frame0 must be a whole number >= 0, got True"),
    (dict(frame0=np.int64(-1), frames=2), InputError, r"frame0 must be >= 0, got -1"),
    (dict(colour0=np.int64(-1), colours=2), InputError, r"colour0 must be >= 0, got -1"),
    (dict(frame0=-1, frames=2), InputError, r"frame0 must be >= 0, got -1"),
    (dict(layer=np.int64(TOP + 3)), InputError, r"layer must lie in \[0, 2\*\*32\)"),
    (dict(frame0=TOP - 1, frames=2), InputError, r"frames must lie in \[0, 2\*\*32\)"),
    (dict(colour0=TOP - 1, colours=2), InputError, r"colours must lie in \[0, 2\*\*32\)"),
])
def test_random_phases_refuses_indices_it_would_cut_or_wrap(queue, kw, error, message):
    """``frame0=2.7`` gave frame 2's phases, ``layer=1.9`` layer 1's, ``frame0=True`` frame
    1's; a NumPy ``-1`` passed the check of ``frame0 + frames - 1`` and wrapped to frame
    2**32 - 1; a Python -1 was a bare OverflowError."""
    from clholo.random import random_phases

    args = dict(seed=0, layer=0)
    args.update(kw)
    with pytest.raises(error, match=message):
        random_phases((4, 4), queue=queue, **args)


def test_random_phases_top_indices_stay_accepted(queue):
    from clholo import reference
    from clholo.random import random_phases

    got = random_phases((4, 4), seed=9, layer=TOP - 1, frame0=TOP - 1, colour0=TOP - 1,
                        queue=queue).get()
    want = reference.random_phase((4, 4), seed=9, frame=TOP - 1, colour=TOP - 1,
                                  layer=TOP - 1)
    np.testing.assert_array_equal(got[0, 0], want)


@pytest.mark.parametrize("kw, error, message", [
    (dict(frame=2.7), InputTypeError, r"frame must be a whole number >= 0, got 2\.7"),
    (dict(layer=1.9), InputTypeError, r"layer must be a whole number >= 0, got 1\.9"),
    (dict(colour=True), InputTypeError, r"colour must be a whole number >= 0, got True"),
    (dict(frame=np.int64(TOP + 3)), InputError, r"frame must lie in \[0, 2\*\*32\)"),
    (dict(frame=np.int64(-1)), InputError, r"frame must be >= 0, got -1"),
    (dict(colour=TOP), InputError, r"colour must lie in \[0, 2\*\*32\)"),
])
def test_reference_random_phase_refuses_indices_it_would_cut_or_wrap(kw, error, message):
    """The NumPy oracle cut 2.7 to frame 2 and wrapped NumPy ints mod 2**32 (2**32 + 3 was
    frame 3): it gave another frame's phases to compare against."""
    from clholo import reference

    args = dict(seed=0, frame=0, colour=0, layer=0)
    args.update(kw)
    with pytest.raises(error, match=message):
        reference.random_phase((4, 4), **args)


# ------------------------------------------------------------------------------------------
# random_phases' pixel bound: checked before anything is allocated

class _Allocated(Exception):
    """Raised in place of the plane's allocation: the shape passed the check."""


def _no_allocation(monkeypatch):
    import clholo.random as module

    def empty(*a, **k):
        raise _Allocated()

    monkeypatch.setattr(module, "cla", types.SimpleNamespace(empty=empty))


@pytest.mark.parametrize("shape", [(9241, 464773), (65537, 65535), (65536, 65536),
                                   (2 ** 17, 2 ** 16), (2 ** 18, 2 ** 17)])
def test_random_phases_refuses_planes_beyond_the_kernels_pixel_counter(queue, monkeypatch,
                                                                       shape):
    """Only ``npix >= 2**34`` was refused: from 2**32 on, a bare OverflowError from
    ``np.uint32(npix)``; at 2**32 - 3 <= npix < 2**32 (9241 x 464773 is 2**32 - 3, 65537 x
    65535 is 2**32 - 1) the kernel's ``p0 + 4u`` wrapped and wrote past the plane. Refused now before the 16 GiB plane is
    allocated (this test allocates nothing)."""
    from clholo.random import random_phases

    _no_allocation(monkeypatch)
    with pytest.raises(InputError, match=r"shape \d+ x \d+ has \d+ pixels; at most 2\*\*32 - 4"):
        random_phases(shape, seed=0, layer=0, queue=queue)


def test_random_phases_largest_plane_passes_the_check(queue, monkeypatch):
    """2**32 - 4 pixels (131068 x 32769): the kernel's last block ends exactly there."""
    from clholo.random import random_phases

    _no_allocation(monkeypatch)
    with pytest.raises(_Allocated):
        random_phases((131068, 32769), seed=0, layer=0, queue=queue)


# ------------------------------------------------------------------------------------------
# a long-lived renderer's plans: bounded

@pytest.mark.parametrize("form", [dict(two_pass=True), dict(two_pass=False),
                                  dict(occlusion=False)], ids=["two-pass", "four-pass",
                                                               "layer-sum"])
def test_renderer_keeps_two_plan_sets_whatever_frame_counts_it_is_asked(queue, form):
    """``render(T)`` for T = 1..213 kept 213 sets of FFT plans and work buffers, one per batch
    size (+4.66 GB RSS with a 64 MiB memory budget). Two are kept now (the frames-per-batch
    one and the most recent other), and a set made again gives the same bits."""
    r = clholo.HologramRenderer(_mpi(), _optics(), queue=queue, frames_per_batch=4, **form)
    first = r.render(3).get()
    for T in range(1, 12):
        r.render(T).get()
        kept = {"plans": len(r._two_pass_plans), "propagators": len(r._propagators),
                "scratch": len(r._scratch)}
        assert max(kept.values()) <= 2, f"after render({T}): {kept}"
    plans = r._two_pass_plans if r.two_pass else r._propagators
    assert 4 in plans, "the frames-per-batch set was released before the others"
    assert len(plans) == 2
    again = r.render(3).get()  # its set was released and is made again
    np.testing.assert_array_equal(again.view(np.uint32), first.view(np.uint32))
    fresh = clholo.HologramRenderer(_mpi(), _optics(), queue=queue, frames_per_batch=4, **form)
    np.testing.assert_array_equal(r.render(11).get().view(np.uint32),
                                  fresh.render(11).get().view(np.uint32))


def test_rpws_renderer_keeps_two_propagators(queue):
    """The RPWS renderer kept a propagator per batch size too."""
    r = _rpws(queue, frames_per_batch=3)
    first = r.render(2).get()
    for T in range(1, 8):
        r.render(T)
        assert len(r._propagators) <= 2, f"after render({T}): {r._propagators.sizes()}"
    assert 3 in r._propagators
    np.testing.assert_array_equal(r.render(2).get().view(np.uint32), first.view(np.uint32))


def test_plan_sets_release_the_least_recent_other_first():
    from clholo.host.scheduler import PlanSets

    made = []
    sets = PlanSets()

    def make(n):
        made.append(n)
        return object()

    for n in (8, 3, 5, 8, 3, 3):
        sets.get(n, make, pinned=8)
    assert sets.sizes() == (8, 3) and made == [8, 3, 5, 3]
    sets.get(1, make, pinned=None)  # nothing pinned: the least recently used goes
    assert sets.sizes() == (3, 1)


# ------------------------------------------------------------------------------------------
# clholo batch: an item cut into more tasks than a scheduler should hold

def test_batch_row_cut_into_too_many_tasks_is_refused(tmp_path):
    """A manifest row ``frames=100000000, split_frames=1`` submitted 10**8 Dask tasks (and
    held their futures) before anything rendered."""
    pytest.importorskip("distributed")
    from clholo import batch

    (tmp_path / "m.csv").write_text("input,frames,split_frames\n"
                                    "skimage:motorcycle,100000000,1\n")
    with pytest.raises(InputError, match=r"m\.csv row 2: split_frames=1 cuts frames=100000000 "
                                         r"into 100000000 tasks; at most 10000 per item: give "
                                         r"split_frames >= 10000"):
        batch.read_manifest(tmp_path / "m.csv")


def test_batch_split_frames_option_cut_into_too_many_tasks_is_refused(tmp_path):
    """The same through ``render_dataset(split_frames=1)`` (``clholo batch --split-frames 1``),
    before the output folder exists."""
    pytest.importorskip("distributed")
    from clholo import batch

    (tmp_path / "m.csv").write_text("input,frames\nskimage:motorcycle,100000000\n")
    items = batch.read_manifest(tmp_path / "m.csv")
    with pytest.raises(InputError, match=r"split_frames=1 cuts frames=100000000 into "
                                         r"100000000 tasks"):
        batch.render_dataset(items, tmp_path / "out", split_frames=1)
    assert not (tmp_path / "out").exists()
    assert items[0].split_frames is None


def test_batch_part_files_of_frames_past_a_million_are_recognised():
    """Part files are named with at least six digits; frame 10**6 on has seven, and those
    were neither counted nor removed."""
    from clholo import batch

    assert batch._PART_FILE.match("frames-1000000-1000009.npz")
    assert batch._PART_FILE.match("frames-000000-000003.npz")
    assert not batch._PART_FILE.match("frames-12-13.npz")
