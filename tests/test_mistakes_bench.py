"""A user's mistake on the bench's drivers and displays is refused, naming the argument and the
fix; nothing hangs (a NaN deadline, a 1e9 s refresh period, a batch shown past --seconds)."""

import math
import time

import numpy as np
import pytest

from clholo.errors import InputError, InputTypeError
from clholo.tools.config import parse_bench_config
from clholo.tools.slm import MemoryDisplay
from clholo.tools.stages import open_stage
from clholo.tools.stages.base import check_setting, wait_for
from clholo.tools.stages.conex import ConexStage

NAN, INF = float("nan"), float("inf")

# (kind, argument, bad value, words of the message besides the argument's name)
STAGE_MISTAKES = [
    ("apt", "reply_timeout", NAN, "finite"), ("apt", "reply_timeout", -1, "> 0"),
    ("apt", "reply_timeout", 0, "> 0"), ("apt", "reply_timeout", INF, "finite"),
    ("apt", "reply_timeout", 500, "milliseconds"),
    ("apt", "poll", -1, "> 0"), ("apt", "poll", NAN, "finite"),
    ("apt", "keepalive", 0, "> 0"), ("apt", "keepalive", 2.0, "1 s"),
    ("apt", "purge_dwell", -0.1, ">= 0"), ("apt", "purge_dwell", NAN, "finite"),
    ("apt", "retries", -1, ">= 0"), ("apt", "retries", 1000, "<= 100"),
    ("apt", "channel", 0, ">= 1"),
    ("apt", "counts_per_mm", NAN, "finite"), ("apt", "counts_per_mm", 34.3, "micrometre"),
    ("apt", "limits", (0.0, INF), "finite"), ("apt", "limits", (0.0, NAN), "finite"),
    ("apt", "limits", (0.0, 25000.0), "millimetres"), ("apt", "limits", (5.0, 1.0), "low < high"),
    ("conex", "reply_timeout", NAN, "finite"), ("conex", "reply_timeout", -1, "> 0"),
    ("conex", "poll", -1, "> 0"), ("conex", "retries", -1, ">= 0"),
    ("conex", "reset_wait", NAN, "finite"), ("conex", "reset_wait", -5, ">= 0"),
    ("conex", "address", 0, ">= 1"), ("conex", "address", 99, "<= 31"),
    ("conex", "limits", (-INF, INF), "finite"),
]


@pytest.mark.parametrize("kind, key, value, words", STAGE_MISTAKES,
                         ids=[f"{k}-{a}-{v}" for k, a, v, _ in STAGE_MISTAKES])
def test_stage_settings_are_refused_at_construction(kind, key, value, words):
    """Refused before the port opens ('loop://' answers nothing: a setting that got through
    would time out, or hang on a NaN deadline), naming the argument and its range."""
    t = time.monotonic()
    with pytest.raises(InputError) as err:
        open_stage("loop://", kind=kind, **{key: value})
    assert time.monotonic() - t < 1.0
    text = str(err.value)
    assert text.startswith(key) and words in text, text


def test_conex_negative_retries_is_not_an_internal_error():
    """ConexStage(retries=-1) raised UnboundLocalError ('text') from its first query."""
    with pytest.raises(InputError, match=r"^retries must be >= 0, got -1"):
        ConexStage("loop://", retries=-1)


def test_counts_are_whole_numbers():
    with pytest.raises(InputTypeError, match="^retries"):
        open_stage("loop://", kind="apt", retries=2.5)
    with pytest.raises(InputTypeError, match="^require_homed"):
        open_stage("loop://", kind="apt", require_homed="no")


@pytest.mark.parametrize("key, value", [("reply_timeout", NAN), ("poll", -1), ("retries", -1),
                                        ("limits", [0.0, INF]), ("counts_per_mm", 34.3)])
def test_bench_file_and_python_api_share_one_check(key, value):
    """The same value is refused by the bench file and by the driver, with the same words."""
    with pytest.raises(InputError) as api:
        check_setting(key, value)
    toml_key = "limits_mm" if key == "limits" else key
    with pytest.raises(ValueError) as bench:
        parse_bench_config({"z_stage": {"port": "x", "kind": "apt", toml_key: value}})
    assert str(bench.value).startswith(f"[z_stage] {toml_key}")
    tail = lambda text: text.split(" ", 2 if text.startswith("[") else 1)[-1]  # noqa: E731
    assert tail(str(bench.value)) == tail(str(api.value))


@pytest.mark.parametrize("timeout, poll, name", [(NAN, 0.01, "timeout"), (-1, 0.01, "timeout"),
                                                 (1.0, NAN, "poll"), (1.0, -1, "poll")])
def test_waits_refuse_a_deadline_that_never_comes(timeout, poll, name):
    t = time.monotonic()
    with pytest.raises(InputError, match=f"^{name}="):
        wait_for(lambda: False, timeout=timeout, poll=poll, what="motion")
    assert time.monotonic() - t < 1.0


def test_stage_call_timeouts_are_checked():
    from clholo.tools.stages.simulators import AptSimulator

    with AptSimulator(speedup=400.0) as sim:
        with open_stage(sim.port, "apt", reply_timeout=0.2, poll=0.01, purge_dwell=0.005) as z:
            for call in (lambda: z.home(timeout=NAN), lambda: z.move_to(1.0, timeout=-1),
                         lambda: z.move_by(0.1, timeout=INF)):
                t = time.monotonic()
                with pytest.raises(InputError, match="^timeout="):
                    call()
                assert time.monotonic() - t < 1.0


# --- item 2: the memory display -----------------------------------------------------------

@pytest.mark.parametrize("kwargs, name, words", [
    ({"refresh_hz": 1e-9}, "refresh_hz", "1..1000"),
    ({"refresh_hz": 5000.0}, "refresh_hz", "1..1000"),
    ({"refresh_hz": NAN}, "refresh_hz", "finite"),
    ({"settle_s": 150}, "settle_s", "milliseconds"),
    ({"settle_s": NAN}, "settle_s", "finite"),
    ({"settle_s": INF}, "settle_s", "finite"),
    ({"keep": -1}, "keep", ">= 0"),
])
def test_memory_display_refuses_settings(kwargs, name, words):
    with pytest.raises(ValueError) as err:
        MemoryDisplay(12, 8, pace=True, **kwargs)
    assert str(err.value).startswith(name) and words in str(err.value), str(err.value)


def test_memory_display_refresh_range_is_the_bench_files():
    from clholo.tools.config import parse_bench_config

    for hz in (1e-9, 0.06, 1001):
        with pytest.raises(ValueError) as bench:
            parse_bench_config({"slm": {"refresh_hz": hz}})
        with pytest.raises(InputError) as api:
            MemoryDisplay(12, 8, refresh_hz=hz)
        assert str(bench.value) == f"[slm] {api.value}"
    for hz in (1, 60.0, 1000):
        assert MemoryDisplay(4, 4, refresh_hz=hz).refresh_hz == hz
        assert parse_bench_config({"slm": {"refresh_hz": hz}}).refresh_hz == hz


@pytest.mark.parametrize("channel, cls", [(5, InputError), (-1, InputError), (3, InputError),
                                          (1.0, InputTypeError)])
def test_show_refuses_a_channel_out_of_range_without_luts(channel, cls):
    d = MemoryDisplay(12, 8)
    with pytest.raises(cls, match=r"^channel"):
        d.show(np.zeros((8, 12), np.uint8), channel=channel)
    assert d.count == 0 and d.log == []
    d.show(np.zeros((8, 12), np.uint8), channel=2)
    assert d.count == 1


def test_show_refuses_a_channel_out_of_range_with_luts():
    luts = [np.arange(256, dtype=np.uint8)] * 2
    d = MemoryDisplay(12, 8, luts=luts)
    for channel in (2, -1):
        with pytest.raises(InputError, match=r"^channel=.*2 LUT"):
            d.show(np.zeros((8, 12), np.uint8), channel=channel)


def test_show_refuses_a_bad_settle_for_one_frame():
    d = MemoryDisplay(12, 8)
    for bad in (NAN, -1, 100):
        with pytest.raises(InputError, match="^settle_s"):
            d.show(np.zeros((8, 12), np.uint8), settle_s=bad)
    assert d.count == 0


@pytest.mark.parametrize("repeats", [0, -1])
def test_play_refuses_repeats_that_show_nothing(repeats):
    d = MemoryDisplay(12, 8)
    with pytest.raises(ValueError, match=r"^repeats must be >= 1"):
        d.play(np.zeros((2, 1, 8, 12), np.uint8), repeats=repeats)
    assert d.count == 0


def test_play_refuses_more_colours_than_a_display_without_luts_shows():
    d = MemoryDisplay(12, 8)
    with pytest.raises(InputError, match="4 colours"):
        d.play(np.zeros((1, 4, 8, 12), np.uint8))
    assert d.count == 0


def test_paced_display_at_the_lowest_refresh_does_not_sleep_forever():
    """refresh_hz=1e-9 slept about 1e9 s at the second show(); 1 Hz, the lowest accepted, waits
    at most a second."""
    d = MemoryDisplay(4, 4, pace=True, refresh_hz=1000.0)
    t = time.monotonic()
    for _ in range(3):
        d.show(np.zeros((4, 4), np.uint8))
    assert time.monotonic() - t < 1.0


# --- item 3: --seconds is honoured whatever --frames is -----------------------------------

def _scene(tmp_path, rng):
    from clholo.io.mpi_folder import write_mpi
    from clholo.scene import MPI

    L, H, W = 2, 8, 8
    mpi = MPI(color=rng.uniform(0, 1, (L, H, W, 3)).astype(np.float32),
              alpha=rng.uniform(0.2, 1, (L, H, W)).astype(np.float32),
              depths=np.array([0.002, 0.004]))
    write_mpi(tmp_path / "scene", mpi)
    return mpi, tmp_path / "scene"


def test_loop_stops_at_seconds_inside_a_large_batch(queue, rng):
    """A batch of 400 frames (1200 patterns, 5 s at 240 Hz) on a 0.3 s run: the loop stops at
    the time, within about a render chunk, not after showing the whole batch."""
    from clholo.host.display_loop import RENDER_CHUNK, DisplayLoop, phase_quantize_encoder
    from clholo.scene import MPI, Optics

    mpi = MPI(color=rng.uniform(0, 1, (2, 8, 8, 3)).astype(np.float32),
              alpha=rng.uniform(0.2, 1, (2, 8, 8)).astype(np.float32),
              depths=np.array([0.002, 0.004]))
    optics = Optics(pitch=8e-6, wavelengths=(638e-9, 520e-9, 450e-9))
    display = MemoryDisplay(8, 8, pace=True, refresh_hz=240.0)
    encode = phase_quantize_encoder()
    calls = []

    def counting(fields):
        calls.append(fields.shape[0])
        return encode(fields)

    loop = DisplayLoop(mpi, optics, display, counting, frames_per_batch=400, queue=queue)
    t = time.monotonic()
    records = loop.run(seconds=0.3)
    took = time.monotonic() - t
    # showing the whole batch takes 5 s; the loop stops at 0.3 s (plus the kernels' build and
    # the first chunk's render)
    assert took < 3.0, took
    assert 0 < len(records) < 1200 and display.count == len(records)
    assert max(calls) <= RENDER_CHUNK
    assert [r.frame for r in records[:1]] == [0]


def test_cli_display_seconds_with_a_huge_batch(tmp_path, rng, capsys):
    """The audit's case: --seconds 0.5 --frames 1000 ran about 60 s without a word. It now
    says so up front (naming --seconds and --frames, with the estimate) and stops in time."""
    from clholo.cli import main

    _, scene = _scene(tmp_path, rng)
    t = time.monotonic()
    rc = main(["display", str(scene), "--memory", "--seconds", "0.5", "--frames", "1000",
               "--size", "8", "8", "--progress", "off"])
    took = time.monotonic() - t
    err = capsys.readouterr().err
    assert rc == 0
    assert "warning" in err and "--frames 1000" in err and "--seconds 0.5" in err, err
    assert "50 s at 60 Hz" in err, err
    assert took < 20.0, took   # was about 60 s (render and show the whole batch)


def test_cli_display_no_warning_when_a_batch_fits(tmp_path, rng, capsys):
    from clholo.cli import main

    _, scene = _scene(tmp_path, rng)
    assert main(["display", str(scene), "--memory", "--seconds", "0.3", "--frames", "2",
                 "--size", "8", "8", "--progress", "off"]) == 0
    assert "warning" not in capsys.readouterr().err


def test_run_refuses_bad_seconds_and_batches(queue, rng):
    from clholo.host.display_loop import DisplayLoop, phase_quantize_encoder
    from clholo.scene import MPI, Optics

    mpi = MPI(color=rng.uniform(0, 1, (1, 8, 8, 1)).astype(np.float32),
              alpha=np.ones((1, 8, 8), np.float32), depths=np.array([0.002]))
    loop = DisplayLoop(mpi, Optics(pitch=8e-6, wavelengths=(520e-9,)), MemoryDisplay(8, 8),
                       phase_quantize_encoder(), queue=queue)
    for kwargs, name in (({"seconds": NAN}, "seconds"), ({"seconds": -1}, "seconds"),
                         ({"batches": 0}, "batches"), ({"batches": 1.5}, "batches")):
        with pytest.raises((ValueError, TypeError), match=f"^{name}"):
            loop.run(**kwargs)
    assert not math.isnan(loop.run(batches=1)[0].shown_s)
