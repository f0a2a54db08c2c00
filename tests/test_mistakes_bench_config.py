"""Bench-file mistakes that used to get through, or fail late naming neither the file nor the key:
a named SLM monitor whose size is not ``[slm] resolution``, no monitor of that resolution, GLFW's
own warning printed before clholo's one-line error, sweep positions outside the stage's travel,
and one stage position given two focus depths.

The monitors are a fake GLFW module's (monkeypatched), so the refusals are checked without a
window system; one test runs the real GLFW under a private Xvfb, one with a DISPLAY where no
server answers.
"""

import os
import subprocess
import sys
import types
import warnings
from pathlib import Path

import numpy as np
import pytest

from clholo.cli import main
from clholo.errors import InputError, NoDisplayError
from clholo.tools.config import load_bench_config, parse_bench_config
from clholo.tools.slm import Monitor, SLMWindow, choose_monitor, find_monitor

from conftest import private_xvfb

SCREEN = Monitor("screen", 1920, 1080, 0, 0, 60.0)
SMALL = Monitor("HOLOEYE mini", 48, 32, 1920, 0, 60.0)


class FakeGLFW(types.ModuleType):
    """The part of the glfw package that the SLM window touches, with a monitor list of our
    choosing; ``create_window`` records its call and fails (no window is ever opened), so a
    command that got past the monitor check ends with 'could not open a window'."""

    class GLFWError(UserWarning):
        pass

    DECORATED, RESIZABLE, FLOATING, AUTO_ICONIFY, FOCUS_ON_SHOW, DOUBLEBUFFER = range(6)

    def __init__(self, monitors, *, init_ok=True, init_warning=None):
        super().__init__("glfw")
        self.monitors = list(monitors)
        self.init_ok, self.init_warning = init_ok, init_warning
        self.windows = []        # create_window's (width, height)
        self.initialised = 0

    def init(self):
        if self.init_warning:
            warnings.warn(self.init_warning, self.GLFWError)
        self.initialised += self.init_ok
        return self.init_ok

    def terminate(self):
        self.initialised = 0

    def get_monitors(self):
        return list(range(len(self.monitors)))

    def get_video_mode(self, m):
        mon = self.monitors[m]
        return types.SimpleNamespace(size=types.SimpleNamespace(width=mon.width,
                                                                height=mon.height),
                                     refresh_rate=int(mon.refresh_hz))

    def get_monitor_pos(self, m):
        return self.monitors[m].x, self.monitors[m].y

    def get_monitor_name(self, m):
        return self.monitors[m].name.encode()

    def window_hint(self, hint, value):
        pass

    def create_window(self, width, height, title, monitor, share):
        self.windows.append((width, height))
        warnings.warn("(65543) b'GLX: no OpenGL here'", self.GLFWError)
        return None


@pytest.fixture
def fake_glfw(monkeypatch):
    """A display server (DISPLAY set) whose only monitor is a 1920x1080 screen."""
    fake = FakeGLFW([SCREEN])
    monkeypatch.setenv("DISPLAY", ":0")
    monkeypatch.setitem(sys.modules, "glfw", fake)
    return fake


@pytest.fixture
def stage_opens(monkeypatch):
    """Records every stage the capture command opens (none should, when the file is wrong)."""
    import clholo.tools.stages as stages

    opened = []
    real = stages.open_stage

    def open_stage(*args, **kwargs):
        opened.append(args)
        return real(*args, **kwargs)

    monkeypatch.setattr(stages, "open_stage", open_stage)
    return opened


def _one_line(err: str) -> str:
    assert err.count("\n") == 1, err
    return err


CAPTURE_BENCH = """
[slm]
{slm}
wavelengths_m = [520e-9]

[z_stage]
port = "{port}"
kind = "apt"
limits_mm = [0.0, 6.0]
reply_timeout = 0.3

[camera]
kind = "{camera}"

[focal_sweep]
positions_mm = {positions}
"""


def _capture_bench(folder: Path, *, slm="resolution = [12, 8]", positions="[2.0, 4.5]",
                   camera="file", port="/dev/ttyUSB0") -> Path:
    path = folder / "bench.toml"
    path.write_text(CAPTURE_BENCH.format(slm=slm, positions=positions, camera=camera, port=port))
    np.save(folder / "patterns.npy", np.zeros((1, 1, 8, 12), np.uint8))
    return path


def _capture(folder: Path, *extra) -> int:
    return main(["capture", "focal-sweep", "--config", str(folder / "bench.toml"), "--patterns",
                 str(folder / "patterns.npy"), "--out", str(folder / "run")] + list(extra))


# ---- 1. a named monitor whose size is not [slm] resolution ------------------------------------

def test_named_monitor_of_another_size_is_refused_naming_both_keys():
    """choose_monitor: a monitor picked by index or name must have the resolution given; the
    bench file's refusal names the file, both keys and both sizes, and the fix."""
    for spec, said in [({"index": 0}, "[slm] monitor = 0"),
                       ({"name": "scr"}, "[slm] monitor = 'scr'")]:
        with pytest.raises(InputError) as err:
            choose_monitor([SCREEN, SMALL], resolution=(48, 32), source="b.toml", **spec)
        text = str(err.value)
        assert text.startswith(f"b.toml: {said} is 1920x1080"), text
        assert "but [slm] resolution = [48, 32]" in text and "fix one" in text, text
        assert "resolution = [1920, 1080]" in text, text
    # the Python API names its own arguments
    with pytest.raises(InputError, match=r"monitor index=0 is 1920x1080 .*resolution=\(48, 32\)"):
        choose_monitor([SCREEN, SMALL], index=0, resolution=(48, 32))
    # the valid cases: the named monitor has the size; no resolution given, any size is taken
    assert choose_monitor([SCREEN, SMALL], index=1, resolution=(48, 32)) == SMALL
    assert choose_monitor([SCREEN, SMALL], name="holoeye", resolution=[48, 32],
                          source="b.toml") == SMALL
    assert choose_monitor([SCREEN, SMALL], index=1) == SMALL


def test_cli_display_refuses_the_monitor_before_the_scene_loads(fake_glfw, tmp_path, capsys):
    """`clholo display` with [slm] monitor = 0 (1920x1080) and resolution = [48, 32]: exit 2,
    one line naming the file and both keys, before the scene loads (it does not exist here) and
    without a window."""
    (tmp_path / "mon0.toml").write_text("[slm]\nmonitor = 0\nresolution = [48, 32]\n")
    rc = main(["display", str(tmp_path / "never-loaded"), "--config",
               str(tmp_path / "mon0.toml"), "--seconds", "0.3"])
    err = _one_line(capsys.readouterr().err)
    assert rc == 2, err
    assert (f"clholo display: error: {tmp_path / 'mon0.toml'}: [slm] monitor = 0 is 1920x1080 "
            f"(screen) but [slm] resolution = [48, 32]; fix one") in err, err
    assert fake_glfw.windows == [] and fake_glfw.initialised == 0
    # the valid case: the monitor has the file's size; the check passes and the window is
    # asked for at that size (the fake refuses it: exit 3, one line with GLFW's reason)
    fake_glfw.monitors = [SCREEN, SMALL]
    (tmp_path / "mon1.toml").write_text("[slm]\nmonitor = 1\nresolution = [48, 32]\n")
    from clholo.io.mpi_folder import write_mpi
    from clholo.scene import MPI

    rng = np.random.default_rng(0)
    write_mpi(tmp_path / "scene", MPI(color=rng.uniform(0.05, 1, (2, 8, 8, 3)),
                                      alpha=rng.uniform(0.05, 1, (2, 8, 8)), depths=[1e-3, 2e-3]))
    rc = main(["display", str(tmp_path / "scene"), "--config", str(tmp_path / "mon1.toml"),
               "--seconds", "0.3"])
    err = capsys.readouterr().err
    assert rc == 3 and "could not open a window" in err and "no OpenGL here" in err, err
    assert "GLFWError" not in err and err.count("error:") == 1, err
    assert fake_glfw.windows == [(48, 32)]


def test_cli_capture_refuses_the_monitor_before_the_stage_opens(fake_glfw, tmp_path, capsys,
                                                                 stage_opens):
    """`clholo capture` on the bench: the same refusal, naming the file, before the stage opens
    (it used to accept 8 x 12 patterns, open the stage, and fail in the sweep with 'display
    needs (1080, 1920)')."""
    _capture_bench(tmp_path, slm="monitor = 0\nresolution = [12, 8]", camera="opencv")
    rc = _capture(tmp_path)
    err = _one_line(capsys.readouterr().err)
    assert rc == 2, err
    assert (f"{tmp_path / 'bench.toml'}: [slm] monitor = 0 is 1920x1080 (screen) but [slm] "
            f"resolution = [12, 8]; fix one") in err, err
    assert stage_opens == [] and fake_glfw.windows == []
    assert not (tmp_path / "run").exists()
    # valid: a monitor of 12 x 8 passes the check and its window is asked for
    fake_glfw.monitors = [SCREEN, Monitor("mini", 12, 8, 1920, 0, 60.0)]
    _capture_bench(tmp_path, slm="monitor = 'mini'\nresolution = [12, 8]", camera="opencv")
    rc = _capture(tmp_path)
    err = _one_line(capsys.readouterr().err)
    assert rc == 3 and "could not open a window" in err, err
    assert fake_glfw.windows == [(12, 8)] and stage_opens == []


def test_named_monitor_on_a_real_window_system(tmp_path, capsys, monkeypatch):
    """The audit's repro on the real GLFW under a private Xvfb (one 96x40 screen): monitor = 0
    with resolution = [48, 32] is refused (the window used to be 96x40); [96, 40] runs."""
    from clholo.io.mpi_folder import write_mpi
    from clholo.scene import MPI

    rng = np.random.default_rng(1)
    write_mpi(tmp_path / "tiny", MPI(color=rng.uniform(0.05, 1, (2, 8, 8, 3)),
                                     alpha=rng.uniform(0.05, 1, (2, 8, 8)), depths=[1e-3, 2e-3]))
    with private_xvfb() as display:
        monkeypatch.setenv("DISPLAY", display)
        (tmp_path / "mon0.toml").write_text("[slm]\nmonitor = 0\nresolution = [48, 32]\n")
        with pytest.raises(InputError, match=r"\[slm\] monitor = 0 is 96x40 .*\[48, 32\]"):
            SLMWindow(0, resolution=(48, 32), source="mon0.toml")
        rc = main(["display", str(tmp_path / "tiny"), "--config", str(tmp_path / "mon0.toml"),
                   "--seconds", "0.3"])
        err = _one_line(capsys.readouterr().err)
        assert rc == 2 and "[slm] monitor = 0 is 96x40" in err, err
        (tmp_path / "mon0.toml").write_text("[slm]\nmonitor = 0\nresolution = [96, 40]\n")
        rc = main(["display", str(tmp_path / "tiny"), "--config", str(tmp_path / "mon0.toml"),
                   "--seconds", "0.3", "--frames", "1"])
        out = capsys.readouterr()
        if rc == 3 and "could not open a window" in out.err:
            pytest.skip(f"no OpenGL window under Xvfb: {out.err}")
        assert rc == 0 and "fps shown" in out.out, out.err


# ---- 2. GLFW's own warning before clholo's one line -------------------------------------------

def test_glfw_errors_go_into_the_one_line(monkeypatch, capsys):
    """GLFW's error (a GLFWError warning of the glfw package) is not shown as Python's
    two-line warning: its text is in clholo's NoDisplayError; other warnings pass on."""
    fake = FakeGLFW([SCREEN], init_ok=False,
                    init_warning="(65550) b'X11: Failed to open display :99'")
    monkeypatch.setenv("DISPLAY", ":99")
    monkeypatch.setitem(sys.modules, "glfw", fake)
    for make in (lambda: SLMWindow(resolution=(48, 32)), lambda: find_monitor()):
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            with pytest.raises(NoDisplayError) as err:
                make()
        assert caught == [], [str(w.message) for w in caught]
        assert "GLFW could not initialise" in str(err.value)
        assert "(X11: Failed to open display :99)" in str(err.value), str(err.value)
    # the command: one line, exit 3 (display and capture on the bench)
    rc = main(["display", "never-loaded", "--seconds", "0.5"])
    err = _one_line(capsys.readouterr().err)
    assert rc == 3 and "Failed to open display :99" in err and "GLFWError" not in err, err
    # a warning that is not GLFW's is passed on, not swallowed
    fake.init_ok, fake.init_warning = True, None
    fake.init = lambda: (warnings.warn("something else", DeprecationWarning), True)[1]
    with pytest.warns(DeprecationWarning, match="something else"):
        assert find_monitor() == SCREEN


def _dead_display() -> str:
    """A display number where no X server runs (no socket, no lock file)."""
    for n in range(731, 931):
        if not (Path(f"/tmp/.X11-unix/X{n}").exists() or Path(f"/tmp/.X{n}-lock").exists()):
            return f":{n}"
    pytest.skip("no free X display number")


@pytest.mark.parametrize("command", ["display", "capture"])
def test_no_x_server_is_one_line_with_the_real_glfw(command, tmp_path):
    """The audit's repro, as a user sees it: DISPLAY names a display where no X server runs;
    stderr is exactly clholo's one line (it used to begin with glfw's `GLFWError: (65550) ...`
    and `warnings.warn(message, GLFWError)`)."""
    pytest.importorskip("glfw", reason="glfw is not installed (pip install 'clholo[slm]')")
    if command == "display":
        argv = ["display", str(tmp_path / "never-loaded"), "--seconds", "0.5"]
    else:
        _capture_bench(tmp_path, camera="opencv")
        argv = ["capture", "focal-sweep", "--config", str(tmp_path / "bench.toml"),
                "--patterns", str(tmp_path / "patterns.npy"), "--out", str(tmp_path / "run")]
    env = {k: v for k, v in os.environ.items() if k != "WAYLAND_DISPLAY"}
    env["DISPLAY"] = _dead_display()
    done = subprocess.run([sys.executable, "-c",
                           "import sys; from clholo.cli import main; sys.exit(main(sys.argv[1:]))"]
                          + argv, capture_output=True, text=True, env=env, timeout=300)
    name = "capture focal-sweep" if command == "capture" else "display"
    assert done.returncode == 3, done.stderr
    assert done.stderr.startswith(f"clholo {name}: error: GLFW could not initialise"), done.stderr
    assert done.stderr.count("\n") == 1 and "GLFWError" not in done.stderr, done.stderr
    assert not (tmp_path / "run").exists()


# ---- 3. no monitor of [slm] resolution --------------------------------------------------------

def test_no_monitor_of_the_resolution_names_the_file_and_keys(fake_glfw, tmp_path, capsys):
    with pytest.raises(InputError) as err:
        choose_monitor([SCREEN], resolution=(48, 32), source="b.toml")
    text = str(err.value)
    assert text.startswith("b.toml: no monitor has the SLM's [slm] resolution = [48, 32]"), text
    assert "0: screen 1920x1080" in text and "set [slm] monitor" in text, text
    # the Python API keeps its words (and the WxH that tests/test_slm.py matches)
    with pytest.raises(InputError, match=r"resolution 48x32 .*name or index"):
        choose_monitor([SCREEN], resolution=(48, 32))
    # the command: exit 2, one line naming the file, before the scene loads
    (tmp_path / "nomon.toml").write_text("[slm]\nresolution = [48, 32]\n")
    rc = main(["display", str(tmp_path / "never-loaded"), "--config",
               str(tmp_path / "nomon.toml"), "--seconds", "0.3"])
    err = _one_line(capsys.readouterr().err)
    assert rc == 2 and f"{tmp_path / 'nomon.toml'}: no monitor has" in err, err
    assert "[slm] resolution = [48, 32]" in err and "[slm] monitor" in err, err
    # valid: a monitor of that size is found (the last of several: the extra monitor)
    other = SMALL._replace(name="second", x=4000)
    assert choose_monitor([SCREEN, SMALL, other], resolution=(48, 32), source="b.toml") == other
    fake_glfw.monitors = [SCREEN, SMALL]
    assert find_monitor(resolution=(48, 32), source="b.toml") == SMALL
    assert fake_glfw.initialised == 0   # terminated again


# ---- 4. sweep positions outside the stage's travel --------------------------------------------

def test_positions_outside_the_stage_travel_are_refused_when_the_file_is_read(tmp_path):
    path = _capture_bench(tmp_path, positions="[5.0, 7.5]")
    with pytest.raises(InputError) as err:
        load_bench_config(path)
    text = str(err.value)
    assert text.startswith(f"{path}: [focal_sweep] positions_mm = [5.0, 7.5]: 7.5 mm (entry 1)"), \
        text
    assert "[z_stage] limits_mm = [0, 6]" in text and "give positions from 0 to 6 mm" in text, text
    # the parallax sweep and its pupil stage; an apt stage without limits_mm: the driver's
    # default travel, 0..25 mm
    for data, words in [
            ({"pupil_stage": {"port": "x", "kind": "apt", "limits_mm": [-2.0, 2.0]},
              "parallax_sweep": {"positions_mm": [-3.0, 0.0]}},
             ["[parallax_sweep] positions_mm", "-3 mm (entry 0)",
              "[pupil_stage] limits_mm = [-2, 2]"]),
            ({"z_stage": {"port": "x"}, "focal_sweep": {"positions_mm": [2.0, 30.0]}},
             ["30 mm (entry 1)", "apt driver's default", "set [z_stage] limits_mm"])]:
        with pytest.raises(ValueError) as err:
            parse_bench_config(data)
        for w in words:
            assert w in str(err.value), str(err.value)
    # valid: inside the limits (the ends included); a conex stage without limits_mm asks its
    # controller when it opens, so nothing is checked here
    path = _capture_bench(tmp_path, positions="[0.0, 6.0]")
    assert load_bench_config(path).focal_sweep.positions_mm == [0.0, 6.0]
    cfg = parse_bench_config({"pupil_stage": {"port": "x", "kind": "conex"},
                              "parallax_sweep": {"positions_mm": [-40.0, 40.0]}})
    assert cfg.parallax_sweep.positions_mm == [-40.0, 40.0]


def test_cli_capture_refuses_unreachable_positions_before_anything_opens(tmp_path, capsys,
                                                                         stage_opens):
    _capture_bench(tmp_path, positions="[5.0, 7.5]")
    rc = _capture(tmp_path, "--simulate")
    err = _one_line(capsys.readouterr().err)
    assert rc == 2 and "bench.toml: [focal_sweep] positions_mm" in err, err
    assert "[z_stage] limits_mm" in err and stage_opens == []
    assert not (tmp_path / "run").exists()
    _capture_bench(tmp_path, positions="[5.0, 6.0]")
    rc = _capture(tmp_path, "--simulate")
    out = capsys.readouterr()
    assert rc == 0 and "2 positions" in out.out, out.err


# ---- 5. one stage position, two focus depths --------------------------------------------------

def test_one_position_with_two_depths_is_refused(tmp_path):
    path = tmp_path / "bench.toml"
    path.write_text("[focal_sweep]\npositions_mm = [4.0, 5.0, 5.0]\n"
                    "depths_m = [0.001, 0.002, 0.004]\n")
    with pytest.raises(InputError) as err:
        load_bench_config(path)
    text = str(err.value)
    assert text.startswith(f"{path}: [focal_sweep] positions_mm gives 5 mm twice (entries 1 "
                           f"and 2) with two depths_m (0.002 and 0.004 m)"), text
    assert "fix positions_mm" in text, text
    # valid: a position repeated with its own depth (a repeat), and distinct positions
    path.write_text("[focal_sweep]\npositions_mm = [5.0, 5.0, 6.0]\n"
                    "depths_m = [0.002, 0.002, 0.004]\n")
    assert load_bench_config(path).focal_sweep.depths_m == [0.002, 0.002, 0.004]
    # the reverse mistake is still refused as before
    with pytest.raises(ValueError, match="depths_m gives 0.002 m for two stage positions"):
        parse_bench_config({"focal_sweep": {"positions_mm": [5.0, 6.0],
                                            "depths_m": [0.002, 0.002]}})
