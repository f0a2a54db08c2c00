"""A lab user's mistakes with the bench's Python API (the audit of tools/slm.py, tools/capture.py,
tools/camera.py and PhaseLUT): each is refused with a message naming the argument and the fix,
before anything moves or is written, instead of a NumPy error, a silently wrong file, or an
aborted process.

The real-window tests run their windows in a child process under a private Xvfb: a regression
there aborts the child (GLFW's assertion, exit 134), never the test run.
"""

import json
import os
import subprocess
import sys
import textwrap
import types

import numpy as np
import pytest

from clholo.errors import EnvironmentProblem, InputError, InputTypeError, OutputRefused
from clholo.tools.camera import FileCamera
from clholo.tools.capture import focal_sweep, parallax_sweep
from clholo.tools.slm import MemoryDisplay

from conftest import private_xvfb

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


# ---- helpers -----------------------------------------------------------------------------------

class RecordingStage:
    """A stage that only records what it was told: every motion is an entry in ``moves``, so a
    test sees whether a sweep moved anything before it refused."""

    limits = (0.0, 25.0)

    def __init__(self):
        self.moves = []
        self._at = 0.0

    def _check_target(self, target_mm, *, name="position_mm"):
        lo, hi = self.limits
        if not lo <= target_mm <= hi:
            raise ValueError(f"{name}={target_mm:g} mm is outside [{lo:g}, {hi:g}] mm")
        return target_mm

    def home(self, *, timeout=60.0):
        self.moves.append("home")
        self._at = 0.0

    def move_to(self, position_mm, *, wait=True, timeout=30.0):
        self.moves.append(position_mm)
        self._at = position_mm

    def position(self):
        return self._at


@pytest.fixture
def lab(tmp_path):
    display = MemoryDisplay(12, 8)
    patterns = np.random.default_rng(0).integers(0, 256, (1, 2, 8, 12), dtype=np.uint8)
    return RecordingStage(), display, FileCamera(display=display), patterns, tmp_path


def _no_output(tmp_path, name):
    """Nothing at ``name``, and no temporary folder left beside it."""
    assert not (tmp_path / name).exists()
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]


@pytest.fixture(scope="module")
def xvfb_display():
    """A private Xvfb server (:func:`conftest.private_xvfb`); its display, for child
    processes."""
    with private_xvfb() as display:
        yield display


def _run_child(display, code):
    """Run ``code`` in a child Python on ``display``; its completed process (never hangs)."""
    env = dict(os.environ, DISPLAY=display)
    env.pop("WAYLAND_DISPLAY", None)
    try:
        return subprocess.run([sys.executable, "-c", textwrap.dedent(code)], env=env, cwd=ROOT,
                              capture_output=True, text=True, timeout=120)
    except subprocess.TimeoutExpired as exc:
        pytest.fail(f"the child hung: {exc}")


def _skip_without_gl(done):
    if "could not open a window" in done.stderr or "NoDisplayError" in done.stderr:
        pytest.skip(f"no OpenGL window under Xvfb: {done.stderr[-300:]}")


# ---- 1. a closed SLM window --------------------------------------------------------------------

def test_closed_window_refuses_show_instead_of_aborting_python(xvfb_display):
    """show() after close() used to abort the process in glfwSwapBuffers (exit 134, a dead
    notebook kernel); `with w:` after close() was accepted."""
    done = _run_child(xvfb_display, """
        import numpy as np
        from clholo.errors import InputError
        from clholo.tools.slm import SLMWindow
        w = SLMWindow(None, resolution=None, keep_readback=True)
        p = np.full(w.shape, 9, np.uint8)
        w.show(p)
        w.close()
        w.close()                      # twice: nothing
        for what, call in [("show", lambda: w.show(p)),
                           ("play", lambda: w.play(p[None, None])),
                           ("read_back", lambda: w.read_back()),
                           ("with", lambda: w.__enter__()),
                           ("_present", lambda: w._present(p))]:
            try:
                call()
            except InputError as exc:
                assert "the SLM window is closed: open a new SLMWindow" in str(exc), exc
                print("refused", what)
            else:
                raise SystemExit(f"{what} after close was accepted")
    """)
    _skip_without_gl(done)
    assert done.returncode == 0, (done.returncode, done.stderr[-2000:])
    for what in ("show", "play", "read_back", "with", "_present"):
        assert f"refused {what}" in done.stdout, done.stdout


# ---- 2. two windows ----------------------------------------------------------------------------

def test_closing_one_window_keeps_another_showing(xvfb_display):
    """Closing one window used to terminate GLFW under the other: its show() went on returning
    records while read_back gave zeros. A notebook cell run again opens a second window, so both
    stay usable, each in its own context, and find_monitor does not end GLFW under them."""
    done = _run_child(xvfb_display, """
        import numpy as np
        from clholo.tools.slm import SLMWindow, find_monitor
        a = SLMWindow(None, resolution=None, keep_readback=True)
        pa = np.random.default_rng(1).integers(0, 256, a.shape, dtype=np.uint8)
        b = SLMWindow(None, resolution=None, keep_readback=True)     # the cell run again
        pb = np.full(b.shape, 7, np.uint8)
        a.show(pa)                                                   # a's own context
        assert (a.read_back() == pa).all(), "a shows a's pattern"
        b.show(pb)
        assert (b.read_back() == pb).all(), "b shows b's pattern"
        b.close()
        a.show(pa[::-1].copy())
        assert (a.read_back() == pa[::-1]).all(), "a still shows after b closed"
        find_monitor(resolution=None)                                # must not end GLFW
        a.show(pa)
        assert (a.read_back() == pa).all(), "a still shows after find_monitor"
        a.close()
        c = SLMWindow(None, resolution=None, keep_readback=True)     # GLFW starts again
        c.show(pb)
        assert (c.read_back() == pb).all()
        c.close()
        print("ok")
    """)
    _skip_without_gl(done)
    assert done.returncode == 0 and "ok" in done.stdout, (done.returncode, done.stderr[-2000:])


class CountingGLFW(types.ModuleType):
    """The part of glfw an SLMWindow touches, counting init/terminate; windows are tokens."""

    class GLFWError(UserWarning):
        pass

    DECORATED, RESIZABLE, FLOATING, AUTO_ICONIFY, FOCUS_ON_SHOW, DOUBLEBUFFER = range(6)

    def __init__(self):
        super().__init__("glfw")
        self.live = False
        self.terminated = 0
        self.destroyed = []

    def init(self):
        self.live = True
        return True

    def terminate(self):
        self.live = False
        self.terminated += 1

    def get_monitors(self):
        return [0]

    def get_video_mode(self, m):
        return types.SimpleNamespace(size=types.SimpleNamespace(width=16, height=8),
                                     refresh_rate=60)

    def get_monitor_pos(self, m):
        return 0, 0

    def get_monitor_name(self, m):
        return b"fake"

    def window_hint(self, hint, value):
        pass

    def create_window(self, *args):
        return object()

    def set_window_pos(self, *args):
        pass

    def make_context_current(self, window):
        pass

    def swap_interval(self, n):
        pass

    def destroy_window(self, window):
        self.destroyed.append(window)


def test_glfw_ends_only_when_the_last_window_closes(monkeypatch):
    """The same rule without a display server: two windows, the first closed, GLFW still
    initialised; the last closed, GLFW terminated once."""
    from clholo.tools import slm

    fake = CountingGLFW()
    monkeypatch.setenv("DISPLAY", ":0")
    monkeypatch.setitem(sys.modules, "glfw", fake)
    monkeypatch.setattr(slm.SLMWindow, "_setup_gl", lambda self: None)
    monkeypatch.setattr(slm, "_glfw_users", 0)
    a = slm.SLMWindow(None, resolution=None)
    b = slm.SLMWindow(None, resolution=None)
    a.close()
    assert fake.live and fake.terminated == 0, "closing one window ended GLFW under the other"
    slm.find_monitor(resolution=None)
    assert fake.live and fake.terminated == 0, "find_monitor ended GLFW under a window"
    b.close()
    b.close()
    assert not fake.live and fake.terminated == 1
    with pytest.raises(InputError, match="the SLM window is closed"):
        b.show(np.zeros(b.shape, np.uint8))


# ---- 3. Display.write_log ----------------------------------------------------------------------

def test_write_log_never_replaces_a_users_file(tmp_path):
    d = MemoryDisplay(4, 2)
    d.show(np.zeros(d.shape, np.uint8))
    mine = tmp_path / "notes.csv"
    mine.write_text("my measurements\n")
    with pytest.raises(OutputRefused, match=r"notes\.csv.*clholo did not write"):
        d.write_log(mine)
    with pytest.raises(OutputRefused, match=r"notes\.csv.*clholo did not write"):
        d.write_log(mine, overwrite=True)
    assert mine.read_text() == "my measurements\n"
    # a folder: named, with a file name to give instead (was IsADirectoryError on a temp name)
    with pytest.raises(OutputRefused, match=rf"{tmp_path}.* is a folder.*frames\.csv"):
        d.write_log(tmp_path)
    # its own log: written, refused the second time, replaced with overwrite=True
    d.write_log(tmp_path / "frames.csv")
    assert (tmp_path / "frames.csv").read_text().startswith("t,channel,shown_s")
    with pytest.raises(OutputRefused, match="overwrite=True"):
        d.write_log(tmp_path / "frames.csv")
    d.show(np.zeros(d.shape, np.uint8))
    d.write_log(tmp_path / "frames.csv", overwrite=True)
    assert len((tmp_path / "frames.csv").read_text().splitlines()) == 3


# ---- 4. Display.play with nothing to play ------------------------------------------------------

@pytest.mark.parametrize("shape", [(0, 3, 8, 12), (2, 0, 8, 12)])
def test_play_of_no_pattern_is_named(shape):
    d = MemoryDisplay(12, 8)
    with pytest.raises(InputError, match=r"at least one pattern.*T \(frames\) and C"):
        d.play(np.zeros(shape, np.uint8))
    assert d.count == 0


# ---- 5. Display LUTs ---------------------------------------------------------------------------

def test_display_lut_mistakes_are_named():
    ident = np.arange(256, dtype=np.uint8)
    with pytest.raises(InputError, match="luts is empty.*luts=None"):
        MemoryDisplay(12, 8, luts=[])
    for one in (ident, list(range(256))):
        with pytest.raises(InputError, match=r"one table.*luts=\[table\]"):
            MemoryDisplay(12, 8, luts=one)
    with pytest.raises(InputError, match=r"\(256, 3\).*list\(luts\.T\)"):
        MemoryDisplay(12, 8, luts=np.stack([ident] * 3, axis=1))
    with pytest.raises(InputTypeError, match=r"luts\[0\] must hold integers 0\.\.255.*<U"):
        MemoryDisplay(12, 8, luts=[np.array([str(i) for i in range(256)])])
    with pytest.raises(InputTypeError, match="load_lut"):
        MemoryDisplay(12, 8, luts="red.lut")
    # what works is unchanged: one table per colour, a (C, 256) array
    assert len(MemoryDisplay(12, 8, luts=[ident, ident]).luts) == 2
    assert len(MemoryDisplay(12, 8, luts=np.stack([ident] * 3)).luts) == 3


# ---- 6. capture sweeps -------------------------------------------------------------------------

def test_sweep_positions_and_depths_given_as_one_number(lab):
    stage, display, camera, patterns, tmp = lab
    with pytest.raises(InputTypeError, match=r"positions_mm must be a list.*\[5\.0"):
        focal_sweep(stage, display, camera, patterns, 5.0, tmp / "a")
    with pytest.raises(InputTypeError, match=r"positions_mm must be a list"):
        focal_sweep(stage, display, camera, patterns, 5.0, tmp / "a", depths_m=[0.002])
    with pytest.raises(InputTypeError, match=r"depths_m must be a list"):
        focal_sweep(stage, display, camera, patterns, [5.0], tmp / "a", depths_m=0.002)
    with pytest.raises(InputTypeError, match=r"positions_mm must be a list"):
        parallax_sweep(stage, display, camera, patterns, 1.0, tmp / "a", distance_m=0.2)
    assert stage.moves == []
    _no_output(tmp, "a")


def test_sweep_of_no_pattern_is_named(lab):
    stage, display, camera, patterns, tmp = lab
    with pytest.raises(InputError, match=r"no pattern.*\(0, 2, 8, 12\)"):
        focal_sweep(stage, display, camera, patterns[:0], [5.0], tmp / "a")
    assert stage.moves == []


def test_sweep_checks_the_camera_before_anything_moves(lab):
    stage, display, _, patterns, tmp = lab
    with pytest.raises(InputTypeError, match=r"capture\(path, info\) method.*got object"):
        focal_sweep(stage, display, object(), patterns, [5.0], tmp / "a")
    assert stage.moves == [], "the stage moved before the camera was checked"
    _no_output(tmp, "a")


def test_sweep_checks_every_image_naming_the_position(lab):
    stage, display, camera, patterns, tmp = lab

    class NoReturn:
        def capture(self, path, info):
            camera.capture(path, info)

    with pytest.raises(InputTypeError, match=r"position index 0 .*returned None.*path"):
        focal_sweep(stage, display, NoReturn(), patterns, [5.0], tmp / "none")
    _no_output(tmp, "none")
    # a float read-out of NaN: refused, not written as a black image
    nan = FileCamera(source=lambda: np.full((8, 12), np.nan))
    with pytest.raises(InputError, match=r"position index 0.*NaN/inf"):
        focal_sweep(stage, display, nan, patterns, [5.0], tmp / "nan")
    _no_output(tmp, "nan")
    # the camera's frame size changes at the second position: the hardware changed mode, not
    # the user's input (EnvironmentProblem: exit 3)
    sizes = iter([(8, 12)] * 2 + [(4, 4)] * 2)
    shrinking = FileCamera(source=lambda: np.zeros(next(sizes), np.uint8))
    with pytest.raises(EnvironmentProblem, match=r"position index 1 .*4 x 4 .*first was 8 x 12"):
        focal_sweep(stage, display, shrinking, patterns, [5.0, 6.0], tmp / "sizes")
    _no_output(tmp, "sizes")


@pytest.mark.parametrize("kwargs, words", [
    ({"distance_m": 0}, r"distance_m = 0 must be > 0 metres"),
    ({"distance_m": float("nan")}, r"distance_m must be finite"),
    ({"distance_m": 200}, r"distance_m = 200 is more than a metre.*millimetres"),
])
def test_parallax_distance_is_checked_like_the_bench_file(lab, kwargs, words):
    stage, display, camera, patterns, tmp = lab
    with pytest.raises(InputError, match=words):
        parallax_sweep(stage, display, camera, patterns, [1.0, 2.0], tmp / "p", **kwargs)
    assert stage.moves == []
    _no_output(tmp, "p")


def test_focal_depths_are_checked_like_the_bench_file(lab):
    stage, display, camera, patterns, tmp = lab
    with pytest.raises(InputError, match=r"depths_m\[0\] = 2 is more than a metre.*millimetres"):
        focal_sweep(stage, display, camera, patterns, [5.0, 6.0], tmp / "d", depths_m=[2, 4])
    with pytest.raises(InputError, match=r"depths_m\[0\] must be finite"):
        focal_sweep(stage, display, camera, patterns, [5.0, 6.0], tmp / "d",
                    depths_m=[float("nan"), 0.004])
    assert stage.moves == []
    _no_output(tmp, "d")
    # metres pass, and the log holds valid JSON (no NaN)
    out = parallax_sweep(stage, display, camera, patterns, [1.0, 2.0], tmp / "ok",
                         distance_m=0.2)
    log = json.loads((out / "log.json").read_text(), parse_constant=pytest.fail)
    assert log["distance_m"] == 0.2 and len(log["angles_deg"]) == 2


# ---- 7. FileCamera -----------------------------------------------------------------------------

def test_file_camera_names_its_source_and_what_a_frame_is(tmp_path):
    with pytest.raises(InputTypeError, match=r"FileCamera source.*returned None.*NumPy array "
                                             r"\[H, W\] or \[H, W, C\]"):
        FileCamera(source=lambda: None).capture(tmp_path / "x", {})
    with pytest.raises(InputError, match=r"FileCamera source.*shape \(10,\).*\[H, W\]"):
        FileCamera(source=lambda: np.zeros(10)).capture(tmp_path / "x", {})
    with pytest.raises(InputTypeError, match=r"FileCamera source must be a callable.*not its "
                                             r"result"):
        FileCamera(source=np.zeros((4, 4)))
    assert not list(tmp_path.iterdir())
    # a good frame is written as before
    assert FileCamera(source=lambda: np.ones((4, 5))).capture(tmp_path / "x", {}).is_file()


# ---- 8. PhaseLUT -------------------------------------------------------------------------------

def test_phase_lut_refuses_nan_phases_and_names_gray_2pi():
    from clholo.encode.quantize import PhaseLUT

    lut = PhaseLUT.linear()
    for bad in (np.nan, np.inf, -np.inf):
        with pytest.raises(ValueError, match="phase contains NaN/inf"):
            lut.to_gray(np.array([1.0, bad]))
    assert lut.to_gray(np.array([2 * np.pi * 100 / 255])).tolist() == [100]
    for bad in (float("nan"), None, "255"):
        with pytest.raises(TypeError, match="gray_2pi"):
            PhaseLUT.linear(bad)
    with pytest.raises(ValueError, match="gray_2pi"):
        PhaseLUT.linear(300)
