"""SLM display: pattern checks, LUTs, playback log, monitor choice, and a real GLFW window under
Xvfb read back pixel-exact."""

import os

import numpy as np
import pytest

from clholo.tools.slm import (MemoryDisplay, Monitor, check_lut, choose_monitor, load_lut)

from conftest import private_xvfb

MONITORS = [Monitor("DELL U2720Q", 3840, 2160, 0, 0, 60.0),
            Monitor("HOLOEYE PLUTO", 1920, 1080, 3840, 0, 60.0),
            Monitor("projector", 1920, 1080, 5760, 0, 60.0)]


def test_choose_monitor_from_injected_list():
    assert choose_monitor(MONITORS, name="pluto").x == 3840
    assert choose_monitor(MONITORS, index=0).name == "DELL U2720Q"
    # by resolution: the last matching one (the extra monitor)
    assert choose_monitor(MONITORS).name == "projector"
    assert choose_monitor(MONITORS[:2]).name == "HOLOEYE PLUTO"
    with pytest.raises(ValueError, match="matches none.*DELL"):
        choose_monitor(MONITORS, name="LG")
    with pytest.raises(ValueError, match="index=5"):
        choose_monitor(MONITORS, index=5)
    with pytest.raises(ValueError, match="1920x1080"):
        choose_monitor(MONITORS[:1])
    with pytest.raises(ValueError, match="no monitor"):
        choose_monitor([])


def test_bad_patterns_are_refused_before_upload(rng):
    d = MemoryDisplay(12, 8)
    good = rng.integers(0, 256, (8, 12), dtype=np.uint8)
    for bad, err, msg in [(good.astype(np.float32), TypeError, "uint8"),
                          (good.astype(np.uint16), TypeError, "uint8"),
                          (good.T.copy(), ValueError, r"\(8, 12\)"),
                          (good[None], ValueError, "shape"),
                          (good.tolist(), TypeError, "NumPy")]:
        with pytest.raises(err, match=msg):
            d.show(bad)
    assert d.count == 0 and not d.log and not d.screen.any()
    # a sequence with one bad frame shows nothing at all
    seq = rng.integers(0, 256, (2, 3, 8, 12), dtype=np.uint8)
    with pytest.raises(TypeError):
        d.play(np.concatenate([seq, seq.astype(np.int16)]))
    assert d.count == 0


def test_per_colour_lut_and_playback_log(rng, tmp_path):
    luts = [rng.permutation(256).astype(np.uint8) for _ in range(3)]
    d = MemoryDisplay(10, 6, luts=luts, keep=100, settle_s=0.001)
    seq = rng.integers(0, 256, (4, 3, 6, 10), dtype=np.uint8)
    fired = []
    log = d.play(seq, repeats=2, on_frame=fired.append)
    assert [(r.t, r.c) for r in log] == [(t, c) for _ in range(2) for t in range(4)
                                          for c in range(3)]
    assert fired == log
    for i, (r, shown) in enumerate(zip(log, d.history)):
        np.testing.assert_array_equal(shown, luts[r.c][seq[r.t, r.c]])
    assert all(r.settled_s - r.shown_s >= 0.001 for r in log)
    d.write_log(tmp_path / "frames.csv")
    rows = (tmp_path / "frames.csv").read_text().splitlines()
    assert rows[0] == "t,channel,shown_s,settled_s,interval_s" and len(rows) == 1 + 24
    with pytest.raises(ValueError, match="256 entries"):
        check_lut(np.arange(255))
    with pytest.raises(ValueError, match="0..255"):
        check_lut(np.arange(256) + 1)
    (tmp_path / "red.lut").write_text(",".join(str(int(v)) for v in luts[0]))
    np.testing.assert_array_equal(load_lut(tmp_path / "red.lut"), luts[0])
    with pytest.raises(FileNotFoundError):
        load_lut(tmp_path / "none.lut")


def test_level_lut_files_are_checked(tmp_path):
    (tmp_path / "words.lut").write_text("0 1 two 3")
    (tmp_path / "bin.lut").write_bytes(bytes(range(256)) * 2)
    (tmp_path / "wide.lut").write_text(" ".join(str(4 * i) for i in range(256)))
    (tmp_path / "ok.lut").write_text(",".join(str(255 - i) for i in range(256)))
    for name, words in [("words", "cannot be read"), ("bin", "cannot be read"),
                        ("wide", "integers 0..255")]:
        with pytest.raises(ValueError, match=words) as err:
            load_lut(tmp_path / f"{name}.lut")
        assert f"{name}.lut" in str(err.value)
    assert load_lut(tmp_path / "ok.lut")[0] == 255


def test_paced_memory_display_keeps_the_refresh():
    d = MemoryDisplay(4, 4, pace=True, refresh_hz=200.0)
    frames = np.zeros((10, 1, 4, 4), np.uint8)
    log = d.play(frames)
    # swaps land on refresh ticks: whole numbers of periods apart, never two in one period
    periods = np.diff([r.shown_s for r in log]) * 200.0
    assert periods.min() > 0.999 and np.allclose(periods, np.round(periods), atol=1e-6)


def test_window_without_display_server_or_glfw(monkeypatch):
    """No display server: a named NoDisplayError (exit 3 on the command line) before GLFW is
    touched; GLFW missing: the pip extra that has it."""
    import sys

    from clholo.errors import MissingExtraError, NoDisplayError
    from clholo.tools.slm import SLMWindow

    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    monkeypatch.setitem(sys.modules, "glfw", None)
    with pytest.raises(NoDisplayError, match="DISPLAY is not set"):
        SLMWindow(resolution=(8, 8))
    monkeypatch.setenv("DISPLAY", ":12345")
    with pytest.raises(MissingExtraError, match=r"clholo\[slm\]"):
        SLMWindow(resolution=(8, 8))
    with pytest.raises(ValueError, match="refresh_hz"):
        MemoryDisplay(4, 4, refresh_hz=0)


@pytest.fixture(scope="module")
def xvfb_display():
    """A private Xvfb server (:func:`conftest.private_xvfb`), set as ``DISPLAY`` meanwhile."""
    with private_xvfb() as display:
        old = os.environ.get("DISPLAY")
        os.environ["DISPLAY"] = display
        try:
            yield display
        finally:
            if old is None:
                os.environ.pop("DISPLAY", None)
            else:
                os.environ["DISPLAY"] = old


def test_window_reads_back_exactly_what_was_uploaded(xvfb_display, rng):
    from clholo.tools.slm import SLMWindow

    luts = [np.arange(256, dtype=np.uint8), rng.permutation(256).astype(np.uint8)]
    try:
        win = SLMWindow(resolution=(96, 40), luts=luts, keep_readback=True)
    except RuntimeError as exc:
        pytest.skip(f"no OpenGL window under Xvfb: {exc}")
    with win:
        assert (win.width, win.height) == (96, 40)
        seq = rng.integers(0, 256, (3, 2, 40, 96), dtype=np.uint8)
        for t in range(3):
            for c in range(2):
                win.show(seq[t, c], channel=c, t=t)
                np.testing.assert_array_equal(win.read_back(), luts[c][seq[t, c]])
        with pytest.raises(TypeError, match="uint8"):
            win.show(seq[0, 0].astype(np.float64))
        with pytest.raises(ValueError, match="shape"):
            win.show(seq[0, 0, :, :95].copy())
        np.testing.assert_array_equal(win.read_back(), luts[1][seq[2, 1]])   # unchanged
        assert len(win.log) == 6


def test_cli_display_on_a_window(xvfb_display, rng, tmp_path, capsys):
    """`clholo display` without --memory opens the SLM window (here on Xvfb, whose only screen
    has the bench file's resolution) and runs the loop on it."""
    from clholo.cli import main
    from clholo.io.mpi_folder import write_mpi
    from clholo.scene import MPI

    write_mpi(tmp_path / "scene", MPI(color=rng.uniform(0.05, 1, (2, 8, 8, 3)),
                                      alpha=rng.uniform(0.05, 1, (2, 8, 8)),
                                      depths=[1e-3, 2e-3]))
    (tmp_path / "bench.toml").write_text("[slm]\nresolution = [96, 40]\n")
    rc = main(["display", str(tmp_path / "scene"), "--config", str(tmp_path / "bench.toml"),
               "--seconds", "0.3", "--frames", "1", "--log", str(tmp_path / "log.csv")])
    out = capsys.readouterr()
    if rc == 3 and "could not open a window" in out.err:
        pytest.skip(f"no OpenGL window under Xvfb: {out.err}")
    assert rc == 0, out.err
    assert "fps shown" in out.out and len((tmp_path / "log.csv").read_text().splitlines()) > 3
