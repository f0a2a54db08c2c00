"""The lab bench's hardware faults and a user's slips around them (the bench hardware audit).

1. APT: a status reply cut short left its bytes in the decoder; the next reply completed it,
   mis-framed, into a valid-looking position (2218 mm on a 0..25 mm stage).
2. Short moves passed silently: a stage that stopped at the end of its travel was logged as
   measured there and the sweep exited 0; CONEX took ``inf``/``nan`` answers and absurd
   travel.
3. ``[z_stage] port = ""`` ended in a TypeError traceback (exit 70).
4. Failures opening a stage named neither the bench file nor its section, and a controller
   that answered its travel as NaN was blamed on the user (exit 2).
5. A port another program holds was opened a second time.
6. APT: status replies lost during a motion gave "homing did not finish within 60 s" after
   60 s; the motion timeout could not be set.
7. CONEX ``limits_mm`` wider than the controller's travel failed only after homing.
8. ``--speedup 0.05`` was refused naming ``reset_wait``, a setting the user never gave.
9. The X server dying mid-sweep exited 1 after Xlib's lines, leaving the temporary folder.

Every wait here has a short timeout; the simulators run fast.
"""

import json
import os
import subprocess
import sys
import textwrap
import time

import numpy as np
import pytest

from clholo.cli import main
from clholo.errors import InputError
from clholo.tools.camera import FileCamera
from clholo.tools.capture import focal_sweep
from clholo.tools.slm import MemoryDisplay
from clholo.tools.stages import (StageProtocolError, StageTimeoutError, open_stage)
from clholo.tools.stages import simulators
from clholo.tools.stages.base import StagePortBusyError, StagePositionError, open_port
from clholo.tools.stages.simulators import AptSimulator, ConexSimulator

APT_FAST = dict(reply_timeout=0.2, poll=0.01, purge_dwell=0.005)
CONEX_FAST = dict(reply_timeout=0.2, poll=0.005, reset_wait=0.03)
ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


class CutApt(AptSimulator):
    """Cuts the next ``cut`` status replies short: header and 4 of 14 data bytes, then the
    line goes quiet (a glitch)."""
    cut = 0

    def _reply(self, name, data):
        if name == "MOT_GET_DCSTATUSUPDATE" and self.cut > 0:
            self.cut -= 1
            data = data[:10]
        super()._reply(name, data)


class FarApt(AptSimulator):
    """Answers status requests with a position far outside the travel (or another
    channel) once ``far`` is set."""
    far = None   # "position" or "channel"

    def _status_data(self):
        if self.far == "position":
            return simulators.apt.pack_status(1, int(2218.3 * self.counts_per_mm), 0, 0x400)
        if self.far == "channel":
            return simulators.apt.pack_status(2, self._counts(), 0, 0x400)
        return super()._status_data()


class OddConex(ConexSimulator):
    """Answers ``SL?``/``SR?``/``TP`` with the texts in ``answers`` (e.g. ``"nan"``)."""
    answers = {}

    def _send_line(self, name, text):
        if name in self.answers:
            text = name + self.answers[name]
        super()._send_line(name, text)


def _no_output(folder, name):
    assert not (folder / name).exists()
    assert not [p for p in folder.iterdir() if p.name.startswith(f".{name}.")]


# ---- 1. APT: a reply cut short ----------------------------------------------------------------

def test_apt_reply_cut_short_is_not_read_as_a_position():
    """One retry (retries=1) must do: the reply after the cut one is framed from its own
    header (without the resync it completes the cut one into 2218 mm, which the plausibility
    check can only refuse, using up the tries)."""
    with CutApt(speedup=400.0) as sim, \
            open_stage(sim.port, "apt", retries=1, **APT_FAST) as z:
        z.home(timeout=5)
        z.move_to(5.0, timeout=5)
        sim.cut = 1
        assert abs(z.position() - 5.0) < 1e-4     # the retry is framed from its own header
        assert abs(z.position() - 5.0) < 1e-4
        assert z._decoder.discarded >= 10


@pytest.mark.parametrize("far, words", [("position", r"2218\.3.* far outside the travel"),
                                        ("channel", r"channel 2 \(this stage is channel 1\)")])
def test_apt_implausible_status_is_a_protocol_error(far, words):
    with FarApt(speedup=400.0) as sim, open_stage(sim.port, "apt", **APT_FAST) as z:
        sim.far = far
        with pytest.raises(StageProtocolError, match=words) as info:
            z.position()
        assert sim.port in str(info.value)


# ---- 2. short moves ---------------------------------------------------------------------------

def test_apt_move_beyond_the_travel_is_refused_not_returned():
    """limits wider than the stage travels: the controller ends the move at its end with
    MOVE_COMPLETED; the driver says where it stopped."""
    with AptSimulator(speedup=400.0) as sim, \
            open_stage(sim.port, "apt", limits=(0.0, 50.0), **APT_FAST) as z:
        z.home(timeout=5)
        with pytest.raises(StagePositionError, match=r"move to 40 mm ended at 25\.0000 mm.*"
                                                     r"tolerance_mm"):
            z.move_to(40.0, timeout=10)


class ShortStage:
    """Duck-typed stage that stops ``short`` mm before each target (or reads ``value``)."""
    limits = (0.0, 25.0)

    def __init__(self, short=0.0, value=None):
        self.short, self.value, self._at = short, value, 0.0

    def _check_target(self, target, *, name="position_mm"):
        return target

    def home(self, *, timeout=60.0):
        self._at = 0.0

    def move_to(self, target, *, wait=True, timeout=30.0):
        self._at = target - self.short

    def position(self):
        return self._at if self.value is None else self.value


@pytest.mark.parametrize("stage, words", [
    (ShortStage(short=0.5), r"position index 0 \(5 mm\): the stage stopped at 4\.5000 mm, "
                            r"-0\.5000 mm .*tolerance_mm = 0\.005"),
    (ShortStage(value=float("inf")), r"position index 0 \(5 mm\).*position as inf"),
    (ShortStage(value=float("nan")), r"position index 0 \(5 mm\).*position as nan"),
])
def test_sweep_refuses_a_measured_position_off_the_target(tmp_path, stage, words):
    display = MemoryDisplay(12, 8)
    patterns = np.zeros((1, 1, 8, 12), np.uint8)
    with pytest.raises(StagePositionError, match=words):
        focal_sweep(stage, display, FileCamera(display=display), patterns, [5.0], tmp_path / "o")
    _no_output(tmp_path, "o")
    # within a tolerance given explicitly it is taken, and the log is valid JSON
    if stage.value is None:
        out = focal_sweep(stage, display, FileCamera(display=display), patterns, [5.0],
                          tmp_path / "o", tolerance_mm=0.6)
        log = json.loads((out / "log.json").read_text(), parse_constant=pytest.fail)
        assert log["positions"][0]["measured_mm"] == 4.5
    with pytest.raises(InputError, match=r"tolerance_mm = 5000.*micrometres"):
        focal_sweep(stage, display, FileCamera(display=display), patterns, [5.0],
                    tmp_path / "p", tolerance_mm=5000)


def test_conex_non_finite_answers_are_device_faults():
    with OddConex(speedup=400.0) as sim:
        sim.answers = {"SL": "-1e9", "SR": "1e9"}
        with pytest.raises(StageProtocolError, match=r"SL -1e\+09 mm.*not a stage's travel") as e:
            open_stage(sim.port, "conex", **CONEX_FAST)
        assert sim.port in str(e.value)
        sim.answers = {"SL": "nan", "SR": "nan"}
        with pytest.raises(StageProtocolError, match=r"1SL\? with 'nan', not a finite number"):
            open_stage(sim.port, "conex", **CONEX_FAST)
        sim.answers = {}
        with open_stage(sim.port, "conex", **CONEX_FAST) as pupil:
            sim.answers = {"TP": "inf"}
            with pytest.raises(StageProtocolError, match=r"1TP with 'inf'"):
                pupil.position()


# ---- 3, 4, 7, 8: the command line ------------------------------------------------------------

BENCH = """
[slm]
resolution = [12, 8]
wavelengths_m = [520e-9]

[z_stage]
port = "/dev/ttyUSB0"
kind = "apt"
reply_timeout = 0.3

[pupil_stage]
port = "/dev/ttyUSB1"
kind = "conex"
reply_timeout = 0.2

[camera]
kind = "file"

[focal_sweep]
positions_mm = [2.0, 4.5]

[parallax_sweep]
positions_mm = [-1.5, 1.5]
"""


@pytest.fixture
def bench(tmp_path):
    (tmp_path / "bench.toml").write_text(BENCH)
    np.save(tmp_path / "patterns.npy", np.zeros((1, 1, 8, 12), np.uint8))
    return tmp_path


def _capture(folder, *extra, sweep="focal-sweep"):
    return main(["capture", sweep, "--config", str(folder / "bench.toml"), "--patterns",
                 str(folder / "patterns.npy"), "--out", str(folder / "run")] + list(extra))


def _edit(folder, old, new):
    text = (folder / "bench.toml").read_text()
    assert old in text
    (folder / "bench.toml").write_text(text.replace(old, new))


def _on_the_bench(monkeypatch):
    """No --simulate, without a display server or an SLM: a memory display stands in."""
    from clholo.tools import slm

    monkeypatch.setattr(slm, "check_display_server", lambda: None)
    monkeypatch.setattr(slm, "SLMWindow", lambda *a, **k: MemoryDisplay(12, 8))


@pytest.mark.parametrize("port", ['""', '"  "'])
def test_empty_port_names_file_section_and_example(bench, capsys, port):
    _edit(bench, 'port = "/dev/ttyUSB0"', f"port = {port}")
    rc = _capture(bench, "--simulate")
    err = capsys.readouterr().err
    assert rc == 2 and "bench.toml" in err and "[z_stage] port" in err, err
    assert 'port = "/dev/ttyUSB0"' in err and err.count("\n") == 1, err
    with pytest.raises(InputError, match=r"port = '' is empty.*/dev/ttyUSB0"):
        open_stage("", "apt")


def test_unknown_url_protocol_names_file_and_section(bench, capsys, monkeypatch):
    _on_the_bench(monkeypatch)
    _edit(bench, 'port = "/dev/ttyUSB0"', 'port = "foo://x"')
    _edit(bench, 'kind = "file"', 'kind = "opencv"')
    rc = _capture(bench)
    err = capsys.readouterr().err
    assert rc == 2 and "bench.toml: [z_stage] port = 'foo://x'" in err, err
    assert "protocol 'foo' not known" in err and "/dev/ttyUSB0" in err and err.count("\n") == 1
    _no_output(bench, "run")


@pytest.mark.parametrize("answers, words", [
    ({"SL": "nan", "SR": "nan"}, "1SL? with 'nan', not a finite number"),
    ({"SL": "x?", "SR": "x?"}, "not a finite number"),
])
def test_conex_odd_answers_at_open_are_device_faults_naming_the_file(bench, capsys, monkeypatch,
                                                                     answers, words):
    monkeypatch.setattr(simulators, "ConexSimulator",
                        type("Odd", (OddConex,), {"answers": answers}))
    rc = _capture(bench, "--simulate", "--speedup", "400", sweep="parallax-sweep")
    err = capsys.readouterr().err
    assert rc == 3 and "bench.toml: [pupil_stage] port" in err and words in err, err
    assert err.count("\n") == 1, err
    _no_output(bench, "run")


def test_conex_garbage_names_file_section_and_reply_timeout(bench, capsys, monkeypatch):
    class Garbage(ConexSimulator):
        def _send_line(self, name, text):
            self._reply(name, b"\x07\x07garbage\r\n")

    monkeypatch.setattr(simulators, "ConexSimulator", Garbage)
    rc = _capture(bench, "--simulate", "--speedup", "400", sweep="parallax-sweep")
    err = capsys.readouterr().err
    assert rc == 3 and "bench.toml: [pupil_stage] port" in err, err
    assert "no valid reply to 1SL?" in err and "reply_timeout" in err and err.count("\n") == 1


def test_conex_limits_wider_than_the_controller_are_refused_at_open(bench, capsys):
    with ConexSimulator(speedup=400.0) as sim:
        with pytest.raises(InputError, match=r"limits = \[-50, 50\] mm \(limits_mm in the bench "
                                             r"file\).*\[-13.5, 13.5\] mm"):
            open_stage(sim.port, "conex", limits=(-50.0, 50.0), **CONEX_FAST)
        assert not any(line.endswith("OR") for _, line in sim.received)   # nothing moved
    _edit(bench, 'kind = "conex"', 'kind = "conex"\nlimits_mm = [-20.0, 20.0]')
    rc = _capture(bench, "--simulate", "--speedup", "400", sweep="parallax-sweep")
    err = capsys.readouterr().err
    assert rc == 2 and "bench.toml: [pupil_stage]" in err and "limits_mm" in err, err
    assert "[-13.5, 13.5]" in err and err.count("\n") == 1, err


def test_a_short_move_in_a_cli_sweep_exits_3_and_writes_nothing(bench, capsys):
    """[z_stage] limits_mm wider than the simulated stage's 25 mm: the move to 40 mm ends at
    25 mm; the sweep names the position and writes nothing."""
    _edit(bench, "reply_timeout = 0.3", "reply_timeout = 0.3\nlimits_mm = [0.0, 50.0]")
    _edit(bench, "positions_mm = [2.0, 4.5]", "positions_mm = [2.0, 40.0]")
    rc = _capture(bench, "--simulate", "--speedup", "400")
    err = capsys.readouterr().err
    assert rc == 3 and "40 mm" in err and "25.0000 mm" in err and err.count("\n") == 1, err
    _no_output(bench, "run")


def test_speedup_below_its_range_names_the_option(bench, capsys):
    rc = _capture(bench, "--simulate", "--speedup", "0.05", sweep="parallax-sweep")
    err = capsys.readouterr().err
    assert rc == 2 and "--speedup 0.05" in err and "0.1" in err, err
    assert "reset_wait" not in err and err.count("\n") == 1, err


# ---- 5. a busy port ---------------------------------------------------------------------------

@pytest.mark.parametrize("kind", ["apt", "conex"])
def test_a_port_held_by_another_program_is_refused_at_once(kind):
    sim_cls, fast = (AptSimulator, APT_FAST) if kind == "apt" else (ConexSimulator, CONEX_FAST)
    with sim_cls(speedup=400.0) as sim, open_stage(sim.port, kind, **fast):
        t = time.monotonic()
        with pytest.raises(StagePortBusyError, match=rf"port {sim.port} is busy.*another"):
            open_stage(sim.port, kind, **fast)
        assert time.monotonic() - t < 1.0
    # a pyserial URL is not a device: it keeps opening
    loop = open_port("loop://", timeout=0.01)
    loop.write(b"ok")
    assert loop.read(2) == b"ok"
    loop.close()


# ---- 6. APT: lost status replies during a motion; the motion timeout -------------------------

def test_apt_lost_status_during_homing_says_the_controller_stopped_answering():
    with AptSimulator(speedup=2.0) as sim, open_stage(sim.port, "apt", **APT_FAST) as z:
        sim.drop["MOT_GET_DCSTATUSUPDATE"] = 10**9
        t = time.monotonic()
        with pytest.raises(StageTimeoutError, match=r"homing: the APT controller on .* stopped "
                                                    r"answering status requests.*3 tries, "
                                                    r"reply_timeout = 0\.2 s.*cable") as e:
            z.home(timeout=30)
        assert time.monotonic() - t < 5, "the motion's own 30 s timeout was waited for"
        assert "stop command was sent" in str(e.value)
        time.sleep(0.05)
        assert "MOT_MOVE_STOP" in [n for _, n in sim.received]


def test_move_timeout_from_the_bench_file_and_the_command_line(bench, capsys):
    # a slow simulation (homing takes seconds): the timeout given acts
    rc = _capture(bench, "--simulate", "--speedup", "0.5", "--move-timeout", "0.3")
    err = capsys.readouterr().err
    assert rc == 3 and "homing did not finish within 0.3 s" in err, err
    _no_output(bench, "run")
    _edit(bench, "reply_timeout = 0.3", "reply_timeout = 0.3\nmove_timeout = 0.4")
    rc = _capture(bench, "--simulate", "--speedup", "0.5")
    err = capsys.readouterr().err
    assert rc == 3 and "homing did not finish within 0.4 s" in err, err
    # refused, naming the option or the key
    for bad in ("0", "nan", "5000"):
        rc = _capture(bench, "--simulate", "--move-timeout", bad)
        err = capsys.readouterr().err
        assert rc == 2 and "--move-timeout" in err and "seconds" in err, err
    _edit(bench, "move_timeout = 0.4", "move_timeout = 60000")
    rc = _capture(bench, "--simulate")
    err = capsys.readouterr().err
    assert rc == 2 and "[z_stage] move_timeout = 60000" in err and "seconds" in err, err


# ---- minor: the display command without --config ----------------------------------------------

def test_display_without_config_and_without_the_default_monitor_names_config(capsys,
                                                                             monkeypatch):
    from clholo.tools import slm

    def no_pluto(monitor=None, *, resolution=None, source=None):
        return slm.choose_monitor([slm.Monitor("HDMI-1", 800, 600, 0, 0, 60.0)],
                                  resolution=resolution, source=source)

    monkeypatch.setattr(slm, "check_display_server", lambda: None)
    monkeypatch.setattr(slm, "find_monitor", no_pluto)
    rc = main(["display", "no-such-scene-is-loaded-first", "--seconds", "0.1"])
    err = capsys.readouterr().err
    assert rc == 2 and "--config" in err and "--memory" in err and "1920 x 1080" in err, err
    assert err.count("\n") == 1, err


# ---- 9. the X server going away mid-sweep -----------------------------------------------------

def _run_until_x_is_lost(argv, cwd, started):
    """Run ``argv`` under a private Xvfb until ``started(process)`` says it is under way, then
    kill the X server: ``(returncode, stdout, stderr)``. Skips where no OpenGL window opens
    under Xvfb."""
    from conftest import start_private_xvfb

    proc, display = start_private_xvfb("48x32x24")
    env = dict(os.environ, DISPLAY=display, PYTHONPATH=ROOT)
    env.pop("WAYLAND_DISPLAY", None)
    p = subprocess.Popen(argv, env=env, cwd=str(cwd), stdout=subprocess.PIPE,
                         stderr=subprocess.PIPE, text=True)
    try:
        if not started(p):
            if p.poll() is None:
                p.kill()
            out, err = p.communicate(timeout=30)
            if "GLFW" in err or "OpenGL" in err or "window" in err:
                pytest.skip(f"no OpenGL window under Xvfb here: {err.strip()[-300:]}")
            pytest.fail(f"the child did not get under way: {out}{err}")
        proc.kill()
        proc.wait(timeout=10)
        out, err = p.communicate(timeout=60)
    finally:
        if p.poll() is None:
            p.kill()
        if proc.poll() is None:
            proc.kill()
    return p.returncode, out, err


def test_x_server_dying_mid_sweep_exits_3_stops_the_stage_and_leaves_no_folder(tmp_path):
    child = textwrap.dedent(f"""
        import sys, numpy as np
        from clholo.tools.camera import FileCamera
        from clholo.tools.capture import focal_sweep
        from clholo.tools.slm import SLMWindow
        from clholo.tools.stages import open_stage
        from clholo.tools.stages.simulators import AptSimulator
        shots = []
        def source():
            shots.append(1)
            if len(shots) == 1:
                print("ready", flush=True)
            return np.zeros((8, 8), np.uint8)
        sim = AptSimulator(speedup=400.0)
        with open_stage(sim.port, "apt", reply_timeout=0.2, poll=0.01,
                        purge_dwell=0.005) as z, SLMWindow(None, resolution=None) as w:
            pats = np.zeros((1, 1) + w.shape, np.uint8)
            focal_sweep(z, w, FileCamera(source=source), pats, [1.0 + 0.01 * i for i in
                        range(2000)], {str(tmp_path / "out")!r})
        print("finished", flush=True)
    """)
    rc, out, err = _run_until_x_is_lost([sys.executable, "-c", child], tmp_path,
                                        lambda p: "ready" in p.stdout.readline())
    assert rc == 3, (rc, err)
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "display server" in lines[0] and "went away" in lines[0], err
    assert "the stage was told to stop" in lines[0] and "nothing written" in lines[0], err
    assert "finished" not in out
    assert not [f for f in tmp_path.iterdir() if f.name.startswith(".out.")]
    assert not (tmp_path / "out").exists()


def test_x_server_dying_mid_display_leaves_no_temporary_log(tmp_path):
    """``clholo display ... --log w.csv`` ended by the X server's loss (exit 3) left its
    temporary ``.w.XXXX.tmp.csv`` with the rows so far: Xlib's handler ends the process where
    no with block unwinds; the display's cleanup removes it there."""
    from clholo.io import write_mpi
    from clholo.scene import MPI

    rng = np.random.default_rng(0)
    write_mpi(tmp_path / "scene", MPI(rng.random((2, 32, 48, 3)), rng.random((2, 32, 48)),
                                      [2e-3, 4e-3]))
    (tmp_path / "b.toml").write_text("[slm]\nmonitor = 0\nresolution = [48, 32]\n")

    def log_started(p):  # the temporary log holds its first rows
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and p.poll() is None:
            if any(f.name.startswith(".w.") and f.name.endswith(".tmp.csv")
                   and f.stat().st_size > 0 for f in tmp_path.iterdir()):
                return True
            time.sleep(0.1)
        return False

    rc, out, err = _run_until_x_is_lost(
        [sys.executable, "-m", "clholo", "display", "scene", "--config", "b.toml", "--seconds",
         "60", "--log", "w.csv"], tmp_path, log_started)
    assert rc == 3, (rc, err)
    assert "went away" in err and "--log w.csv not written" in err, err
    assert not [f for f in tmp_path.iterdir() if f.name.startswith(".w.")]
    assert not (tmp_path / "w.csv").exists()
