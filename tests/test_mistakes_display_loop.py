"""A user's mistakes with the display loop's Python API (the audit of DisplayLoop): each is
refused by name before anything runs, or no longer leaves the loop broken. Every run here is
short (``batches=`` or ``seconds=``) and every thread is joined with a timeout: a regression
fails, it does not hang."""

import threading

import numpy as np
import pytest

from clholo.errors import InputError, OutputRefused
from clholo.host.display_loop import DisplayLoop, phase_quantize_encoder, resample_mpi
from clholo.scene import MPI, Optics
from clholo.tools.slm import MemoryDisplay

OPTICS = Optics(pitch=8e-6, wavelengths=(638e-9, 520e-9, 450e-9))


def random_mpi(rng, L=2, H=10, W=14, C=3, near=1e-3):
    return MPI(color=rng.uniform(0.05, 1, (L, H, W, C)), alpha=rng.uniform(0.05, 1, (L, H, W)),
               depths=near + 1e-3 * np.arange(L))


def fast_display(width=18, height=12):
    # paced fast: the display waits for the producer (it repeats meanwhile, one per ms)
    return MemoryDisplay(width, height, keep=10**4, pace=True, refresh_hz=1000.0)


def render_threads():
    return [t for t in threading.enumerate() if t.name == "clholo-render" and t.is_alive()]


def no_repeats(records):
    return [(r.batch, r.frame, r.channel) for r in records if not r.repeated]


# -- 1. a log in a missing folder ---------------------------------------------------------------
def test_a_log_in_a_missing_folder_is_refused_before_any_thread_starts(queue, rng, tmp_path):
    mpi = random_mpi(rng)
    with pytest.raises(FileNotFoundError, match=r"log_path .*nope.* does not exist; create it"):
        DisplayLoop(mpi, OPTICS, fast_display(), phase_quantize_encoder(), queue=queue,
                    log_path=tmp_path / "nope" / "x.csv")
    # the folder goes away after the loop was made: run() refuses before its producer starts,
    # so the next run has one producer (each frame shown once, no batch skipped)
    (tmp_path / "gone").mkdir()
    loop = DisplayLoop(mpi, OPTICS, fast_display(), phase_quantize_encoder(), queue=queue,
                       frames_per_batch=1, log_path=tmp_path / "gone" / "x.csv")
    (tmp_path / "gone").rmdir()
    with pytest.raises(FileNotFoundError, match="log_path"):
        loop.run(batches=1)
    assert not render_threads()
    loop.log_path = None
    new = no_repeats(loop.run(batches=4))
    assert len(new) == len(set(new))
    assert sorted({b for b, _, _ in new}) == [0, 1, 2, 3]
    assert not render_threads()


# -- 2. one producer error ----------------------------------------------------------------------
def test_a_producer_error_is_raised_by_its_own_run_only(queue, rng):
    encode = phase_quantize_encoder()
    calls = []

    def flaky(fields):                  # fails once, on its second chunk
        calls.append(1)
        if len(calls) == 2:
            raise RuntimeError("encoder failed once")
        return encode(fields)

    loop = DisplayLoop(random_mpi(rng), OPTICS, fast_display(), flaky, queue=queue,
                       frames_per_batch=1)
    with pytest.raises(RuntimeError, match="encoder failed once"):
        loop.run(batches=3)
    assert loop.run(batches=2) and not loop.errors    # the encoder works again: so does
    assert loop.run(batches=2) and not loop.errors    # the loop, run after run


# -- 3. run() while running -----------------------------------------------------------------
def test_run_while_another_thread_runs_the_loop_is_refused(queue, rng):
    loop = DisplayLoop(random_mpi(rng), OPTICS, fast_display(), phase_quantize_encoder(),
                       queue=queue, frames_per_batch=1)
    showing = threading.Event()
    got = {}

    def background():
        try:
            got["records"] = loop.run(seconds=20, on_pattern=lambda rec: showing.set())
        except BaseException as exc:    # reported below
            got["error"] = exc

    thread = threading.Thread(target=background, daemon=True)
    thread.start()
    try:
        assert showing.wait(60), "the first run showed nothing"
        with pytest.raises(RuntimeError, match=r"already running \(in another thread\): call "
                                               r"stop\(\) first, or wait for run\(\) to return"):
            loop.run(batches=1)
    finally:
        loop.stop(join_timeout=30)
        thread.join(30)
    assert not thread.is_alive() and "error" not in got
    new = no_repeats(got["records"])
    assert len(new) == len(set(new))    # one producer: no frame shown twice
    # stop() waited for the other run() to return: the loop runs again at once
    assert loop.run(batches=1)
    assert not render_threads()

    # run() called from on_pattern (the thread that runs the loop) is refused as well
    def again(rec):
        if "inner" not in got:
            try:
                loop.run(batches=1)
            except RuntimeError as exc:
                got["inner"] = exc

    loop.run(batches=1, on_pattern=again)
    assert "on_pattern" in str(got["inner"])


# -- 4. the user's files ------------------------------------------------------------------------
def test_a_file_clholo_did_not_write_is_never_replaced(queue, rng, tmp_path):
    mpi = random_mpi(rng)
    notes = tmp_path / "notes.csv"
    notes.write_text("precious user data\n")

    def loop_for(path, **kw):
        return DisplayLoop(mpi, OPTICS, fast_display(), phase_quantize_encoder(), queue=queue,
                           frames_per_batch=1, log_path=path, **kw)

    for overwrite in (False, True):
        with pytest.raises(OutputRefused, match=r"log_path .*notes.csv exists and is a file "
                                                r"clholo did not write"):
            loop_for(notes, overwrite=overwrite)
    # the log of a run: a temporary file, renamed when the run ends, recorded as clholo's
    log = tmp_path / "run.csv"
    loop = loop_for(log)
    assert loop.run(batches=1) and log.read_text().startswith("batch,frame,channel")
    assert not [p for p in tmp_path.iterdir() if ".tmp" in p.name]
    assert loop.run(batches=2)          # the loop replaces its own earlier log
    with pytest.raises(OutputRefused, match="earlier clholo output.*overwrite=True"):
        loop_for(log)
    assert loop_for(log, overwrite=True).run(batches=1)
    # a note added to that log makes it the user's: not replaced, even with overwrite
    with open(log, "a") as fh:
        fh.write("my note\n")
    with pytest.raises(OutputRefused, match="clholo did not write, or one changed since"):
        loop_for(log, overwrite=True)
    with pytest.raises(OutputRefused, match="log_path"):
        loop.run(batches=1)
    assert log.read_text().endswith("my note\n")
    # a file that appeared after the loop was made: refused when run() starts, nothing runs
    later = tmp_path / "later.csv"
    loop = loop_for(later)
    later.write_text("precious user data\n")
    with pytest.raises(OutputRefused, match="log_path"):
        loop.run(batches=1)
    assert later.read_text() == "precious user data\n" and not render_threads()
    # Ctrl-C: the rows shown so far are kept as the log; an error of on_pattern leaves
    # log_path as it was (no half-written file, no temporary left behind)
    def interrupt(rec):
        raise KeyboardInterrupt

    cut = tmp_path / "cut.csv"
    with pytest.raises(KeyboardInterrupt):
        loop_for(cut).run(batches=3, on_pattern=interrupt)
    assert len(cut.read_text().splitlines()) == 1 + 1
    failed = tmp_path / "failed.csv"
    with pytest.raises(ZeroDivisionError):
        loop_for(failed).run(batches=3, on_pattern=lambda rec: 1 / 0)
    assert not failed.exists()
    assert not [p for p in tmp_path.iterdir() if ".tmp" in p.name]

    # write_log: the same rule
    with pytest.raises(OutputRefused, match="clholo did not write"):
        loop.write_log(notes)
    with pytest.raises(OutputRefused, match="clholo did not write"):
        loop.write_log(notes, overwrite=True)
    assert notes.read_text() == "precious user data\n"
    mine = tmp_path / "mine.csv"
    loop.write_log(mine)
    with pytest.raises(OutputRefused, match="overwrite=True"):
        loop.write_log(mine)
    loop.write_log(mine, overwrite=True)

    # the option itself
    with pytest.raises(TypeError, match="overwrite"):
        loop_for(tmp_path / "x.csv", overwrite="yes")
    with pytest.raises(InputError, match="give log_path, or drop overwrite"):
        loop_for(None, overwrite=True)
    with pytest.raises(TypeError):
        loop.write_log(mine, True)      # keyword-only


# -- 5. a scene larger than the display -----------------------------------------------------
def test_a_scene_larger_than_the_display_is_refused(queue, rng):
    big = random_mpi(rng, H=16, W=24)
    with pytest.raises(InputError, match=r"the scene is 16x24 pixels, larger than the display "
                                         r"\(8x12.*resample_mpi\(mpi, \(8, 12\)\)"):
        DisplayLoop(big, OPTICS, MemoryDisplay(12, 8), phase_quantize_encoder(), queue=queue)
    # what the message suggests fits
    assert DisplayLoop(resample_mpi(big, (8, 12)), OPTICS, MemoryDisplay(12, 8),
                       phase_quantize_encoder(), queue=queue)
    loop = DisplayLoop(random_mpi(rng), OPTICS, fast_display(), phase_quantize_encoder(),
                       queue=queue, frames_per_batch=1)
    with pytest.raises(InputError, match=r"the new scene is 16x24 pixels, larger than the "
                                         r"display \(12x18"):
        loop.set_scene(big)
    refused = []

    def swap(rec):                      # while running: refused the same way, loop goes on
        if not refused:
            with pytest.raises(InputError, match="larger than the display"):
                loop.set_scene(big)
            refused.append(1)

    records = loop.run(batches=3, on_pattern=swap)
    assert refused and {r.scene for r in records} == {0}


# -- 6. fewer LUTs than colours ---------------------------------------------------------------
def test_a_display_with_fewer_luts_than_colours_is_refused(queue, rng):
    identity = np.arange(256, dtype=np.uint8)
    display = MemoryDisplay(18, 12, luts=[identity])
    with pytest.raises(InputError, match=r"the display has 1 LUT\(s\).*the optics have 3 "
                                         r"colour\(s\) \(638 nm, 520 nm, 450 nm\)"):
        DisplayLoop(random_mpi(rng), OPTICS, display, phase_quantize_encoder(), queue=queue)
    four = Optics(pitch=8e-6, wavelengths=(638e-9, 520e-9, 450e-9, 405e-9))
    with pytest.raises(InputError, match="without LUTs shows at most 3"):
        DisplayLoop(random_mpi(rng, C=4), four, fast_display(), phase_quantize_encoder(),
                    queue=queue)
    # one LUT per colour, or one colour for one LUT: shown
    assert DisplayLoop(random_mpi(rng), OPTICS, MemoryDisplay(18, 12, luts=[identity] * 3),
                       phase_quantize_encoder(), queue=queue).run(batches=1)
    red = Optics(pitch=8e-6, wavelengths=(638e-9,))
    assert DisplayLoop(random_mpi(rng, C=1), red, display, phase_quantize_encoder(),
                       queue=queue).run(batches=1)
