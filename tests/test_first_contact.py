"""What a new user sees (issue 8, items 4 and 7): the demo's focal stack really focuses, progress
shows off a terminal, every option documents itself, the README's example runs, one import
reaches every public module, and the contact sheet has one exposure."""

import io
import json
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from clholo import cli
from clholo.demo import motorcycle_mpi
from clholo.progress import StepLog

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def demo_run(tmp_path_factory):
    """One small demo run shared by the tests below: (folder, stdout)."""
    import contextlib

    out = tmp_path_factory.mktemp("demo") / "out"
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        rc = cli.main(["demo", "--scale", "0.25", "--frames", "4", "--layers", "4",
                       "--out", str(out)])
    assert rc == 0
    return out, buf.getvalue()


def _edge_agreement(image, reference, mask):
    """Correlation of gradient magnitudes inside ``mask``: 1 = the same edges, 0 = unrelated
    (speckle has gradients everywhere, so raw gradient energy cannot tell focus; agreement with
    the reference's edges can)."""
    from scipy.ndimage import gaussian_filter, sobel

    a, b = gaussian_filter(image, 1.0), gaussian_filter(reference, 1.0)
    ga, gb = np.hypot(sobel(a, 0), sobel(a, 1)), np.hypot(sobel(b, 0), sobel(b, 1))
    return float(np.corrcoef(ga[mask], gb[mask])[0, 1])


def test_demo_focuses_near_content_near_and_far_content_far(demo_run):
    out, _ = demo_run
    stack = np.load(out / "focal_stack.npz")["intensity"]  # near, middle, far
    mpi = motorcycle_mpi(layers=4, scale=0.25)
    reference = mpi.over().mean(-1)
    near, far = mpi.alpha[0] > 0.5, mpi.alpha[-1] > 0.5
    assert near.mean() > 0.05 and far.mean() > 0.05
    near_in_near = _edge_agreement(stack[0].mean(0), reference, near)
    near_in_far = _edge_agreement(stack[-1].mean(0), reference, near)
    far_in_far = _edge_agreement(stack[-1].mean(0), reference, far)
    far_in_near = _edge_agreement(stack[0].mean(0), reference, far)
    assert near_in_near > near_in_far + 0.3, (near_in_near, near_in_far)
    assert far_in_far > far_in_near + 0.3, (far_in_far, far_in_near)


def test_progress_is_shown_off_a_terminal(demo_run):
    _, log = demo_run
    assert "\r" not in log
    assert re.search(r"rendering 4 frame\(s\) x 3 colour\(s\) x 4 layers \(mpi\) \.\.\.", log)
    assert re.search(r"frames: 4/4 after [0-9.]+ s", log)
    assert re.search(r"focal stack: 3 depths x 4 frame\(s\) x 3 colour\(s\) \.\.\.", log)


def test_step_log_paces_its_lines():
    stream = io.StringIO()
    log = StepLog(stream, interval=3600.0)
    for done in range(1, 11):
        log.progress("frames", done, 10, 0.0)
    lines = stream.getvalue().splitlines()
    # the first call prints (nothing printed yet), then only the last within the interval
    assert len(lines) == 2 and lines[-1].startswith("  frames: 10/10")


def test_contact_sheet_has_one_exposure_for_every_panel(demo_run):
    from clholo.io import linear_to_srgb, read_image

    out, _ = demo_run
    summary = json.loads((out / "summary.json").read_text())
    exposure = summary["contact_sheet_exposure"]
    assert str(round(exposure, 3))[:4] in summary["contact_sheet_caption"]
    sheet, _ = read_image(out / "focal_stack.png")
    mpi = motorcycle_mpi(layers=4, scale=0.25)
    H, W = mpi.shape
    reference_panel = sheet[:H, :W, :3]
    want = linear_to_srgb(np.clip(mpi.over() / exposure, 0, 1))
    assert np.max(np.abs(reference_panel - want)) <= 1.5 / 255
    stack = np.load(out / "focal_stack.npz")["intensity"]
    near_panel = sheet[:H, W + 8:2 * W + 8, :3]
    want = linear_to_srgb(np.clip(stack[0].transpose(1, 2, 0) / exposure, 0, 1))
    assert np.max(np.abs(near_panel - want)) <= 1.5 / 255


def _commands(parser, prefix=()):
    """Every (nested) subcommand: ("capture", "focal-sweep") -> its parser."""
    import argparse

    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield prefix + (name,), sub
                yield from _commands(sub, prefix + (name,))


@pytest.mark.parametrize("rows_per_band", [1, 3, 1000])
def test_contact_sheet_codes_are_the_float_sheets_encoded(rng, monkeypatch, rows_per_band):
    # the banded 8-bit sheet of render folders against the whole-image float sheet: panels
    # of different heights, float32 and float64, a transposed focal slice, values beyond the
    # exposure and below zero
    import clholo.render_folder as rf
    from clholo.io import linear_to_srgb8

    panels = [rng.uniform(-0.1, 1.3, (9, 7, 3)).astype(np.float32),
              rng.uniform(0.0, 1.3, (3, 6, 7)).transpose(1, 2, 0),  # float64, (6, 7, 3)
              rng.uniform(0.0, 0.9, (9, 5, 3)).astype(np.float32)]
    exposure = rf.sheet_exposure(panels)
    # the 99.5th percentile of every value as float32
    assert exposure == float(np.percentile(
        np.concatenate([np.asarray(p, np.float32).ravel() for p in panels]), 99.5))
    want = linear_to_srgb8(rf.contact_sheet([np.clip(p / exposure, 0, 1) for p in panels],
                                            gap=2))
    monkeypatch.setattr(rf, "_SHEET_BAND_ELEMENTS", 7 * 3 * rows_per_band)
    got = rf.contact_sheet_srgb8(panels, exposure, gap=2)
    assert got.dtype == np.uint8
    np.testing.assert_array_equal(got, want)
    # the layout itself: 7 + 2 + 7 + 2 + 5 columns, white gaps and white below short panels
    assert got.shape == (9, 23, 3)
    assert np.all(got[:, 7:9] == 255) and np.all(got[:, 16:18] == 255)
    assert np.all(got[6:, 9:16] == 255)
    np.testing.assert_array_equal(got[:6, 9:16], linear_to_srgb8(
        np.clip(panels[1] / exposure, 0, 1).astype(np.float32)))
    # float64 values just below a code's rounding edge whose float32 is above it: the float
    # sheet holds float32, and so must the bands
    from clholo.io import srgb_to_linear

    edges = srgb_to_linear((np.arange(1, 255) + 0.5) / 255)
    below = np.nextafter(edges, 0.0)  # float32 rounds half of them up to the edge or above
    edge_panel = np.stack([below, below, below], axis=-1)[None]
    assert not np.array_equal(linear_to_srgb8(edge_panel),
                              linear_to_srgb8(edge_panel.astype(np.float32)))
    np.testing.assert_array_equal(
        rf.contact_sheet_srgb8([edge_panel], 1.0, gap=2),
        linear_to_srgb8(rf.contact_sheet([np.clip(edge_panel, 0, 1)], gap=2)))


def test_every_option_of_every_command_has_help_and_shows_its_default():
    import argparse

    commands = dict(_commands(cli.build_parser()))
    assert ("experiment", "layers") in commands and len(commands) >= 12
    for path, sub in commands.items():
        name = " ".join(path)
        assert issubclass(sub.formatter_class, argparse.ArgumentDefaultsHelpFormatter), name
        for action in sub._actions:
            if not action.option_strings or isinstance(action, argparse._HelpAction):
                continue
            assert action.help, f"clholo {name} {action.option_strings[0]} has no help text"
            if action.default is None and not action.required:  # say what happens instead
                assert "default" in action.help, f"clholo {name} {action.option_strings[0]}"
        text = sub.format_help()
        assert "(default: None)" not in text, name
        text = text[text.index("options:"):]  # the option list, not the usage lines
        for action in sub._actions:
            if (action.option_strings and action.default not in (None, argparse.SUPPRESS)
                    and not isinstance(action, argparse._HelpAction)):
                flag = action.option_strings[-1]
                block = text[text.index("\n  " + flag) + 1:]
                assert "(default:" in block.split("\n  -")[0], f"clholo {name} {flag}"


def test_one_import_reaches_every_public_module():
    code = ("import clholo, numpy as np; "
            "x = clholo.fft.fft2(np.ones((4, 4), np.complex64)); "
            "assert x[0, 0] == 16; "
            "clholo.reference.propagate; clholo.validate.wavelength; clholo.io.load_scene; "
            # a subpackage's submodule its docstring names: clholo.encode.quantize.quantize
            "assert callable(clholo.encode.quantize.quantize); clholo.encode.dpac.dpac_encode; "
            "print('ok')")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=120)
    assert done.returncode == 0 and done.stdout.strip() == "ok", done.stderr
    with pytest.raises(AttributeError, match="no attribute 'not_a_module'"):
        import clholo

        clholo.not_a_module


def test_readme_python_example_runs(tmp_path, monkeypatch):
    readme = (ROOT / "README.md").read_text()
    blocks = re.findall(r"```python\n(.*?)```", readme, flags=re.S)
    assert blocks, "the README has no Python example"
    monkeypatch.chdir(tmp_path)
    namespace = {}
    exec(compile(blocks[0], "README.md", "exec"), namespace)
    assert namespace["holograms"].shape == (8, 3, 128, 192)
    assert namespace["stack"].shape == (3, 3, 128, 192)
    assert namespace["scene"].layers == 8
    from tolerances import rel_l2

    assert rel_l2(namespace["holograms"][:1], namespace["oracle"]) < 1e-5
