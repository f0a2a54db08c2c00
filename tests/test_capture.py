"""Bench configuration, camera hooks and capture sweeps, end to end on the simulators and the
memory display (API and CLI)."""

import json

import numpy as np
import pytest

from clholo.cli import main
from clholo.tools.camera import Camera, FileCamera
from clholo.tools.capture import focal_sweep, parallax_sweep
from clholo.tools.config import load_bench_config, parse_bench_config
from clholo.tools.slm import MemoryDisplay
from clholo.tools.stages import StageLimitError, open_stage
from clholo.tools.stages.simulators import AptSimulator, ConexSimulator

BENCH = """
[slm]
monitor = "PLUTO"
resolution = [12, 8]
wavelengths_m = [638e-9, 520e-9]
luts = ["red.lut", "green.lut"]
phase_luts = ["linear:230", "measured_green.csv"]
settle_s = 0.001

[z_stage]
port = "/dev/ttyUSB0"
kind = "apt"
counts_per_mm = 34304
limits_mm = [0.0, 25.0]
reply_timeout = 0.3

[pupil_stage]
port = "/dev/ttyUSB1"
kind = "conex"
reply_timeout = 0.3

[camera]
kind = "file"

[focal_sweep]
positions_mm = [2.0, 4.5, 7.0]
depths_m = [0.002, 0.004, 0.006]

[parallax_sweep]
positions_mm = [-1.5, 0.0, 1.5]
distance_m = 0.1
"""


@pytest.fixture
def bench(tmp_path, rng):
    luts = [rng.permutation(256).astype(np.uint8) for _ in range(2)]
    for name, lut in zip(("red", "green"), luts):
        (tmp_path / f"{name}.lut").write_text(" ".join(str(int(v)) for v in lut))
    (tmp_path / "bench.toml").write_text(BENCH)
    # a measured phase table in radians (2 pi reached at gray 240)
    phases = 2 * np.pi * np.arange(256) / 240 + rng.uniform(0, 1e-3, 256).cumsum()
    (tmp_path / "measured_green.csv").write_text("\n".join(f"{v:.9f}" for v in phases))
    patterns = rng.integers(0, 256, (2, 2, 8, 12), dtype=np.uint8)
    np.save(tmp_path / "patterns.npy", patterns)
    return tmp_path, luts, patterns


def test_config_reads_every_section(bench):
    folder, luts, _ = bench
    cfg = load_bench_config(folder / "bench.toml")
    assert cfg.monitor == "PLUTO" and cfg.resolution == (12, 8)
    assert cfg.phase_luts == ["linear:230", str(folder / "measured_green.csv")]
    assert cfg.wavelengths_m == (638e-9, 520e-9)
    for got, want in zip(cfg.luts(), luts):
        np.testing.assert_array_equal(got, want)
    assert cfg.z_stage.kind == "apt" and cfg.z_stage.settings["counts_per_mm"] == 34304
    assert cfg.z_stage.settings["limits"] == [0.0, 25.0]
    assert cfg.pupil_stage.kind == "conex"
    assert cfg.focal_sweep.positions_mm == [2.0, 4.5, 7.0]
    assert cfg.parallax_sweep.distance_m == 0.1


@pytest.mark.parametrize("data, msg", [
    ({"slm": {"wavelength": [1]}}, "unknown key.*wavelength"),
    ({"lasers": {}}, "unknown section"),
    ({"slm": {"wavelengths_m": [520]}}, "metres"),
    ({"z_stage": {"kind": "apt"}}, "port"),
    ({"z_stage": {"port": "x", "kind": "apt", "address": 1}}, "unknown key 'address'"),
    ({"z_stage": {"port": "x", "kind": "newport"}}, "kind"),
    ({"focal_sweep": {"positions_mm": [1, 2], "depths_m": [0.001]}}, "2 entries"),
    ({"slm": {"luts": ["a.lut"]}}, "one file per wavelength"),
    ({"slm": {"phase_luts": ["linear", "linear"]}}, "one per wavelength"),
])
def test_config_errors_name_the_key(data, msg):
    with pytest.raises((ValueError, TypeError), match=msg):
        parse_bench_config(data)


def test_focal_sweep_end_to_end(bench, tmp_path):
    folder, luts, patterns = bench
    display = MemoryDisplay(12, 8, luts=luts, settle_s=0.001)
    camera = FileCamera(display=display)
    assert isinstance(camera, Camera)
    positions = [2.0, 4.5, 7.0]
    with AptSimulator(speedup=400.0) as sim, \
            open_stage(sim.port, "apt", reply_timeout=0.3, poll=0.01) as z:
        out = focal_sweep(z, display, camera, patterns, positions, tmp_path / "stack",
                          depths_m=[0.002, 0.004, 0.006])
    log = json.loads((out / "log.json").read_text())
    assert log["kind"] == "focal-sweep" and log["depths_m"] == [0.002, 0.004, 0.006]
    assert [p["requested_mm"] for p in log["positions"]] == positions
    from clholo.io.images import read_image

    for p, want in zip(log["positions"], positions):
        assert abs(p["measured_mm"] - want) < 1e-4
        assert p["move_start_s"] <= p["move_end_s"] <= p["images"][0]["shown_s"]
        assert [(im["t"], im["c"]) for im in p["images"]] == [(0, 0), (0, 1), (1, 0), (1, 1)]
        for im in p["images"]:
            assert im["shown_s"] <= im["settled_s"] <= im["captured_s"]
            pixels, _ = read_image(out / im["file"], normalise=False)
            np.testing.assert_array_equal(pixels.reshape(8, 12),
                                          luts[im["c"]][patterns[im["t"], im["c"]]])
    rows = (out / "frames.csv").read_text().splitlines()
    assert len(rows) == 1 + 3 * 4
    assert sorted(f.name for f in tmp_path.iterdir() if f.name.startswith(".")) == []


def test_parallax_sweep_and_fault_leaves_no_folder(bench, tmp_path):
    _, luts, patterns = bench
    display = MemoryDisplay(12, 8, luts=luts)
    with ConexSimulator(speedup=400.0, reset_s=2.0) as sim, \
            open_stage(sim.port, "conex", reply_timeout=0.3, poll=0.005,
                       reset_wait=0.01) as pupil:
        out = parallax_sweep(pupil, display, FileCamera(display=display), patterns,
                             [-1.5, 0.0, 1.5], tmp_path / "views", distance_m=0.1)
        log = json.loads((out / "log.json").read_text())
        assert log["kind"] == "parallax-sweep"
        np.testing.assert_allclose(log["angles_deg"],
                                   np.degrees(np.arctan(np.array([-1.5, 0, 1.5]) / 100)))
        assert len(list(out.glob("p*_t*_c*.png"))) == 12
        # out-of-travel positions are refused before anything moves
        with pytest.raises(ValueError, match=r"positions_mm\[1\]"):
            parallax_sweep(pupil, display, FileCamera(display=display), patterns,
                           [0.0, 99.0], tmp_path / "never")
        with pytest.raises(TypeError, match="uint8"):
            parallax_sweep(pupil, display, FileCamera(display=display),
                           patterns.astype(float), [0.0], tmp_path / "never")
        # a limit switch mid-sweep: named error, no output folder, no temporary left
        sim.limit_switch = (-5.0, 1.0)
        with pytest.raises(StageLimitError):
            parallax_sweep(pupil, display, FileCamera(display=display), patterns,
                           [0.5, 1.5], tmp_path / "broken", home=False)
    assert not (tmp_path / "never").exists() and not (tmp_path / "broken").exists()
    assert not [f for f in tmp_path.iterdir() if f.name.startswith(".")]


@pytest.mark.parametrize("sweep", ["focal-sweep", "parallax-sweep"])
def test_cli_sweeps_on_simulators(bench, sweep, capsys):
    folder, luts, patterns = bench
    out = folder / sweep
    rc = main(["capture", sweep, "--config", str(folder / "bench.toml"), "--patterns",
               str(folder / "patterns.npy"), "--out", str(out), "--simulate",
               "--speedup", "400"])
    assert rc == 0, capsys.readouterr().err
    log = json.loads((out / "log.json").read_text())
    assert len(log["positions"]) == 3 and len(list(out.glob("*.png"))) == 12
    assert "12 images" in capsys.readouterr().out
    rc = main(["capture", sweep, "--config", str(folder / "bench.toml"), "--patterns",
               str(folder / "patterns.npy"), "--out", str(out), "--simulate"])
    assert rc == 2 and "--overwrite" in capsys.readouterr().err
    rc = main(["capture", sweep, "--config", str(folder / "bench.toml"), "--patterns",
               str(folder / "patterns.npy"), "--out", str(out), "--simulate", "--overwrite",
               "--speedup", "400"])
    assert rc == 0 and (out / "clholo-output.json").is_file()
    # a folder clholo did not write is never replaced (an empty one destroys nothing and is
    # taken as new: clholo.io.output)
    (folder / "mine").mkdir()
    (folder / "mine" / "notes.txt").write_text("mine")
    rc = main(["capture", sweep, "--config", str(folder / "bench.toml"), "--patterns",
               str(folder / "patterns.npy"), "--out", str(folder / "mine"), "--simulate",
               "--overwrite"])
    assert rc == 2 and "not a folder clholo wrote" in capsys.readouterr().err


def test_opencv_camera_import_error_names_the_extra(monkeypatch):
    import sys

    from clholo.tools.camera import OpenCVCamera

    monkeypatch.setitem(sys.modules, "cv2", None)   # as if OpenCV were not installed
    with pytest.raises(ImportError, match=r"clholo\[camera\]"):
        OpenCVCamera(0)


def test_opencv_camera_faults_are_environment_problems(monkeypatch, tmp_path):
    """A camera that does not open or returns no frame: this machine cannot (exit 3 on the
    command line), not an internal error."""
    import sys
    import types

    from clholo.errors import EnvironmentProblem
    from clholo.tools.camera import OpenCVCamera

    class Capture:
        def __init__(self, device):
            self.opened = device == 0

        def isOpened(self):
            return self.opened

        def grab(self):
            return True

        def read(self):
            return False, None

        def release(self):
            pass

    fake = types.SimpleNamespace(VideoCapture=Capture, CAP_PROP_FRAME_WIDTH=3,
                                 CAP_PROP_FRAME_HEIGHT=4)
    monkeypatch.setitem(sys.modules, "cv2", fake)
    with pytest.raises(EnvironmentProblem, match="camera device 1 did not open"):
        OpenCVCamera(1)
    cam = OpenCVCamera(0)
    with pytest.raises(EnvironmentProblem, match="no frame"):
        cam.capture(tmp_path / "x", {})
    # a missing frame names the camera's key and where in the sweep it was asked for
    with pytest.raises(EnvironmentProblem, match=r"camera device 0 \(\[camera\] device.*no frame "
                                                 r"at position index 2 \(5 mm\), frame t=1"):
        cam.capture(tmp_path / "x", {"index": 2, "position_mm": 5.0, "t": 1, "c": 0})


def test_tools_import_no_gui_or_vendor_library():
    import subprocess
    import sys

    code = ("import sys, clholo.tools, clholo.tools.slm, clholo.tools.camera, "
            "clholo.tools.capture, clholo.tools.stages.apt, clholo.tools.stages.conex, "
            "clholo.commands.capture, clholo.commands.display; "
            "bad = [m for m in ('glfw', 'OpenGL', 'cv2') if m in sys.modules]; print(bad)")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=120)
    assert done.returncode == 0 and done.stdout.strip() == "[]", done.stderr


# ---- units and files read from the bench file (issue 17) -------------------------------------

def _with(text: str, old: str, new: str) -> str:
    assert old in text
    return text.replace(old, new)


@pytest.mark.parametrize("old, new, words", [
    ("settle_s = 0.001", "settle_s = 150", ["[slm] settle_s = 150", "milliseconds",
                                            "settle_s = 0.15"]),
    ("depths_m = [0.002, 0.004, 0.006]", "depths_m = [2, 4, 6]",
     ["[focal_sweep] depths_m = [2, 4, 6]", "metres", "0.002"]),
    ("counts_per_mm = 34304", "counts_per_mm = 34.304",
     ["[z_stage] counts_per_mm = 34.304", "micrometre", "34554.96"]),
    ("limits_mm = [0.0, 25.0]", "limits_mm = [0.0, 25000.0]",
     ["[z_stage] limits_mm", "millimetres", "[0.0, 25.0]"]),
    ("reply_timeout = 0.3\n\n[pupil", "reply_timeout = 300\n\n[pupil",
     ["[z_stage] reply_timeout = 300", "seconds"]),
    ("distance_m = 0.1", "distance_m = 100", ["[parallax_sweep] distance_m = 100", "0.2"]),
    ("settle_s = 0.001", "settle_s = 0.001\nrefresh_hz = 0.06",
     ["[slm] refresh_hz = 0.06", "hertz", "refresh_hz = 60"]),
    ("kind = \"file\"", "kind = \"file\"\ndevice = 1.5", ["[camera] device", "1.5"]),
    ("positions_mm = [2.0, 4.5, 7.0]", "positions_mm = [2000.0, 4500.0, 7000.0]",
     ["[focal_sweep] positions_mm", "millimetres"]),
    ("\"red.lut\"", "\"missing.lut\"", ["[slm] luts", "missing.lut", "does not exist"]),
])
def test_units_in_the_bench_file_are_checked(bench, old, new, words):
    """A value in another unit (milliseconds, millimetres, counts per micrometre, ...) is refused
    naming the file, the key, the value and the fix, like the same mistake on the command line;
    a file the bench names is read and checked when the bench file is."""
    from clholo.errors import InputError

    folder, _, _ = bench
    path = folder / "bench.toml"
    path.write_text(_with(BENCH, old, new))
    with pytest.raises(InputError) as err:
        load_bench_config(path)
    text = str(err.value)
    assert text.startswith(str(path)), text
    for w in words:
        assert w in text, text


def test_phase_table_in_degrees_is_refused(bench, tmp_path):
    from clholo.encode.quantize import PhaseLUT, parse_lut
    from clholo.errors import InputError

    folder, _, _ = bench
    degrees = 360.0 * np.arange(256) / 256
    (folder / "deg.csv").write_text("\n".join(f"{v:.6f}" for v in degrees))
    np.save(folder / "deg.npy", degrees)
    for name in ("deg.csv", "deg.npy"):
        with pytest.raises(ValueError, match="degrees.*give radians"):
            parse_lut(folder / name)
    # radians still read, an SLM range above 2 pi (2 pi at gray 200) too
    np.save(folder / "rad.npy", np.radians(degrees) * 256 / 200)
    assert parse_lut(folder / "rad.npy").usable_levels == 200
    assert isinstance(parse_lut(folder / "measured_green.csv"), PhaseLUT)
    np.save(folder / "cplx.npy", np.exp(1j * np.radians(degrees)))
    with pytest.raises(ValueError, match="complex"):
        parse_lut(folder / "cplx.npy")
    # through the bench file: refused when the file is read, naming it
    path = folder / "bench.toml"
    path.write_text(_with(BENCH, "measured_green.csv", "deg.csv"))
    with pytest.raises(InputError, match=r"bench.toml: \[slm\] phase_luts: .*deg.csv.*degrees"):
        load_bench_config(path)


def _capture(folder, *extra, sweep="focal-sweep", patterns="patterns.npy", out="run"):
    return main(["capture", sweep, "--config", str(folder / "bench.toml"), "--patterns",
                 str(folder / patterns), "--out", str(folder / out)] + list(extra))


def test_cli_capture_checks_the_pattern_file(bench, capsys):
    """Every pattern file is read and checked before any hardware opens: one line, exit 2,
    naming --patterns, the file, what it holds and the fix (a float array used to end in an
    internal error)."""
    folder, _, patterns = bench
    np.save(folder / "float.npy", patterns.astype(np.float32))
    np.save(folder / "wide.npy", patterns[..., :-1].copy())
    np.save(folder / "five.npy", patterns[None, None])
    np.save(folder / "objects.npy", np.array([{"a": 1}], dtype=object), allow_pickle=True)
    np.savez(folder / "both.npz", a=patterns)
    (folder / "notes.npy").write_text("not numbers")
    for name, words in [("float.npy", "float32 values"), ("wide.npy", "8 x 11 pixels"),
                        ("five.npy", "shape"), ("objects.npy", "Python objects"),
                        ("both.npz", ".npz archive"), ("notes.npy", "not a NumPy .npy")]:
        rc = _capture(folder, "--simulate", patterns=name)
        err = capsys.readouterr().err
        assert rc == 2 and f"--patterns {folder / name}" in err and words in err, err
        assert err.count("\n") == 1, err
        assert not (folder / "run").exists()


def test_cli_capture_options_act_or_are_refused(bench, capsys):
    folder, _, _ = bench
    rc = _capture(folder, "--speedup", "10")
    err = capsys.readouterr().err
    assert rc == 2 and "--speedup" in err and "--simulate" in err
    # --no-home acts: the simulated stage starts unreferenced and refuses to move; the option
    # is the mistake (exit 2), not the stage
    for sweep in ("focal-sweep", "parallax-sweep"):
        rc = _capture(folder, "--simulate", "--no-home", "--speedup", "400", sweep=sweep)
        err = capsys.readouterr().err
        assert rc == 2 and "drop --no-home" in err and err.count("\n") == 1, err
    assert not (folder / "run").exists()


def test_cli_capture_without_display_server(bench, capsys, monkeypatch):
    folder, _, _ = bench
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    rc = _capture(folder)
    err = capsys.readouterr().err
    assert rc == 3 and "no display server" in err and "--simulate" in err
    assert err.count("\n") == 1, err


def test_cli_capture_ctrl_c_stops_the_stage_and_writes_nothing(bench, capsys, monkeypatch):
    """Ctrl-C in the middle of a move: one line, exit 130, the stage told to stop and its port
    closed, no output folder and no temporary one."""
    from clholo.tools.stages.apt import AptStage

    folder, _, _ = bench
    (folder / "bench.toml").write_text(_with(BENCH, "reply_timeout = 0.3\n\n[pupil",
                                             "require_homed = false\n\n[pupil"))
    calls = []
    real_move, real_stop, real_close = AptStage.move_to, AptStage.stop, AptStage.close

    def move_to(self, position_mm, *, wait=True, timeout=30.0):
        real_move(self, position_mm, wait=False, timeout=timeout)
        calls.append(("moving", self.is_moving()))
        raise KeyboardInterrupt

    monkeypatch.setattr(AptStage, "move_to", move_to)
    monkeypatch.setattr(AptStage, "stop", lambda self: (calls.append("stop"), real_stop(self)))
    monkeypatch.setattr(AptStage, "close",
                        lambda self: (calls.append("close"), real_close(self)))
    rc = _capture(folder, "--simulate", "--no-home", "--speedup", "1")
    err = capsys.readouterr().err
    assert rc == 130 and "interrupted" in err and "stage was stopped" in err, err
    assert err.count("\n") == 1, err
    assert calls == [("moving", True), "close", "stop"]
    assert not (folder / "run").exists()
    assert not [f for f in folder.iterdir() if f.name.startswith(".")]


def test_bench_file_that_is_not_a_bench_file(tmp_path):
    from clholo.errors import InputError

    (tmp_path / "bin.toml").write_bytes(bytes(range(256)))
    with pytest.raises(InputError, match="not a text"):
        load_bench_config(tmp_path / "bin.toml")
    with pytest.raises(InputError, match="is a folder"):
        load_bench_config(tmp_path)
    (tmp_path / "bad.toml").write_text("[slm\n")
    with pytest.raises(InputError, match="not valid TOML"):
        load_bench_config(tmp_path / "bad.toml")
    (tmp_path / "flat.toml").write_text("slm = 3\n")
    with pytest.raises(InputError, match=r"\[slm\] section"):
        load_bench_config(tmp_path / "flat.toml")


def test_cli_capture_port_that_does_not_open(bench, capsys, monkeypatch, tmp_path):
    """On the bench (no --simulate) a stage port that does not open: one line naming the bench
    file, the section and the port, exit 3, nothing written."""
    from clholo.tools import slm

    folder, _, _ = bench
    monkeypatch.setattr(slm, "check_display_server", lambda: None)
    monkeypatch.setattr(slm, "SLMWindow", lambda *a, **k: MemoryDisplay(12, 8))
    (folder / "bench.toml").write_text(_with(BENCH, 'port = "/dev/ttyUSB0"',
                                             f'port = "{tmp_path / "no-such-port"}"')
                                       .replace('kind = "file"', 'kind = "opencv"'))
    rc = _capture(folder)
    err = capsys.readouterr().err
    assert rc == 3 and "[z_stage] port" in err and "no-such-port" in err and "bench.toml" in err
    assert err.count("\n") == 1, err
    assert not (folder / "run").exists()
