"""clholo experiment layers at a tiny size: every output is written, complete, atomically."""

import csv
import dataclasses
import json

import numpy as np
import pytest

from clholo import MPI
from clholo.experiments import layers as study

TINY = dataclasses.replace(study.REDUCED, scenes=("motorcycle",), layers=(2, 4), frames=2,
                           width=32, focal_depths=2, view_angles_deg=(-1.0, 1.0),
                           reference_samples=3)


def test_tiny_study_writes_every_output(tmp_path, queue, monkeypatch):
    from clholo import metrics, rayoptics

    calls, slices = [], []
    score, slice_ = metrics.score, rayoptics.incoherent_focal_slice

    def spy_score(image, reference, **kw):
        calls.append(kw)
        return score(image, reference, **kw)

    def spy_slice(*a, **kw):
        slices.append(slice_(*a, **kw))
        return slices[-1]

    monkeypatch.setattr(metrics, "score", spy_score)
    monkeypatch.setattr(rayoptics, "incoherent_focal_slice", spy_slice)
    out = tmp_path / "study"
    result = study.run_study(out, TINY, queue=queue)
    # every score: one scale per colour, the scene's data range (99.5th percentile of the whole
    # reference focal stack)
    want = float(np.percentile(np.stack(slices).astype(np.float64), 99.5))
    assert len(calls) == 16 and len(slices) == TINY.focal_depths
    for kw in calls:
        assert kw["fit_scale"] == "per_channel"
        assert kw["data_range"] == pytest.approx(want, rel=1e-12)
    names = {p.name for p in out.iterdir()}
    assert {"results.csv", "results.md", "quality_vs_layers.png", "time_vs_layers.png",
            "crops_motorcycle.png", "config.json", "focal_stack.npz", "views.npz"} <= names
    assert [p.name for p in tmp_path.iterdir()] == ["study"]  # no temporary folder left
    with open(out / "results.csv") as f:
        rows = list(csv.DictReader(f))
    # 2 L x 2 methods x (2 depths + 2 angles)
    assert len(rows) == len(result["rows"]) == 16
    assert {r["method"] for r in rows} == {"mpi", "rgbd"}
    # one data range per scene: the reference focal stack's 99.5th percentile
    assert len({r["data_range"] for r in rows}) == 1
    for r in rows:
        assert float(r["render_seconds"]) > 0
        scales = [float(v) for v in r["scale"].split()]     # one per colour
        assert len(scales) == 3 and min(scales) > 0
        assert float(r["data_range"]) > 0
        assert np.isfinite(float(r["psnr"])) and -1 <= float(r["ssim"]) <= 1
        assert 0 <= float(r["flip"]) <= 1
    table = (out / "results.md").read_text()
    assert table.count("| motorcycle |") == 4
    for png in ("quality_vs_layers.png", "time_vs_layers.png", "crops_motorcycle.png"):
        assert (out / png).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    views = np.load(out / "views.npz")
    assert views["intensity"].shape[:2] == (2, 3) and views["angles_rad"].shape == (2,)
    from clholo.experiments import report

    page = report.build_report(out, tmp_path / "report.html")  # the study's folder reads back
    html = page.read_text()
    assert "results.csv" in html and html.count("data:image/png;base64") >= 3 + 2 + 2
    page.unlink()
    with pytest.raises(FileExistsError, match="overwrite"):
        study.run_study(out, TINY, queue=queue)


def test_merge_layers_is_over_within_groups(rng):
    L, H, W = 6, 5, 7
    mpi = MPI(rng.random((L, H, W, 3)), rng.random((L, H, W)),
              np.linspace(1e-3, 2e-3, L))
    one = study.merge_layers(mpi, np.array([1.5e-3]))
    np.testing.assert_allclose(one.alpha[0], 1 - np.prod(1 - mpi.alpha, axis=0), atol=1e-6)
    np.testing.assert_allclose(one.over(), mpi.over(), atol=1e-5)
    two = study.merge_layers(mpi, np.array([1e-3, 2e-3]))
    np.testing.assert_allclose(two.over(), mpi.over(), atol=1e-5)
    assert not np.allclose(two.alpha[0], one.alpha[0])


def test_config_is_validated():
    with pytest.raises(ValueError, match="scenes"):
        dataclasses.replace(TINY, scenes=("garden",)).validated()
    with pytest.raises(ValueError, match="near"):
        dataclasses.replace(TINY, near=5e-3, far=2e-3).validated()


def test_cli_registers_the_study(tmp_path, capsys):
    from clholo import cli

    with pytest.raises(SystemExit) as exc:
        cli.main(["experiment", "layers", "--help"])
    assert exc.value.code == 0
    assert "--reduced" in capsys.readouterr().out
    with pytest.raises(SystemExit) as exc:
        cli.main(["experiment", "layers", "--layers", "1", "--out", str(tmp_path / "x"),
                  "--progress", "off"])
    assert exc.value.code == 2
    assert "argument --layers: must be >= 2, got 1" in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []


def test_methods_come_from_the_registry(tmp_path, capsys):
    """``--methods`` offers the registry's methods; RPWS needs a splat scene, --max-splats
    acts on one (refused before any work, one line each)."""
    from clholo import cli
    from clholo.methods import METHODS

    assert set(study.METHODS) <= set(METHODS)
    cases = [
        (["--methods", "rpws", "--scenes", "twain", "--max-splats", "10"],
         "--max-splats acts on the splat scene (fox), which --scenes leaves out"),
        (["--methods", "mpi", "rpws", "--scenes", "twain"],
         "method rpws renders 3D Gaussian splats: of the scenes only fox has them"),
        (["--methods", "rpws", "--scenes", "twain", "fox", "--max-splats", "10", "--out",
          str(tmp_path / "missing" / "x")], "its parent folder"),
        (["--data", str(tmp_path / "nowhere")], "--data"),
    ]
    for extra, message in cases:
        rc = cli.main(["experiment", "layers", "--out", str(tmp_path / "x"), *extra])
        err = capsys.readouterr().err
        assert rc == 2 and message in err and len(err.strip().splitlines()) == 1, err
    with pytest.raises(ValueError, match="method rpws renders 3D Gaussian splats"):
        dataclasses.replace(TINY, methods=("rpws",)).validated()
    with pytest.raises(ValueError, match="methods must be some of"):
        dataclasses.replace(TINY, methods=("sgd",)).validated()
    assert list(tmp_path.iterdir()) == []


def test_reduced_study_with_rpws_rows(tmp_path, shared_data):
    """The reduced study (every scene, L = 4, 8, T = 4, 64 px) with the three methods of the
    registry, run as a user runs it with its output redirected: RPWS gets one row, for fox,
    rendered from the same (subsampled) splats as fox's MPI and RGB-D rows; progress is plain
    lines (no bar, no carriage return) with a line per hologram."""
    import os
    import subprocess
    import sys

    out = tmp_path / "study"
    proc = subprocess.run(
        [sys.executable, "-m", "clholo.cli", "experiment", "layers", "--reduced", "--methods",
         "mpi", "rgbd", "rpws", "--max-splats", "300", "--data", str(shared_data), "--out",
         str(out)], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
        env=dict(os.environ, PYTHONUNBUFFERED="1"), timeout=900)
    log = proc.stdout
    assert proc.returncode == 0, log
    assert "\r" not in log
    for k, what in enumerate(["twain L=4 mpi", "twain L=4 rgbd", "twain L=8 mpi"], start=1):
        assert f"] [{k}/13] {what}: render " in log, log
    assert "] [13/13] fox rpws (300 splats): render " in log
    assert "fox: 64x64" in log and "300 of " in log and "seed 0" in log
    with open(out / "results.csv") as f:
        rows = list(csv.DictReader(f))
    assert {(r["scene"], r["method"]) for r in rows if r["method"] == "rpws"} == {("fox", "rpws")}
    rpws = [r for r in rows if r["method"] == "rpws"]
    assert len(rpws) == 3 + 2 and {r["layers"] for r in rpws} == {"300"}
    for r in rpws:
        assert float(r["render_seconds"]) > 0 and np.isfinite(float(r["psnr"]))
    assert len(rows) == (3 * 2 * 2 + 1) * (3 + 2)
    table = (out / "results.md").read_text()
    assert "| fox | 300 | rpws |" in table and "RPWS (random-phase wave splatting) has no L" in table
    config = json.loads((out / "config.json").read_text())
    assert config["methods"] == ["mpi", "rgbd", "rpws"] and config["max_splats"] == 300
    assert (out / "crops_fox.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_an_error_line_is_never_glued_to_progress(tmp_path):
    """A failure part-way (here: the scene's mpi.json is damaged, found when the study loads
    it) is one line of its own after the progress (f474cde: tqdm's bar and the error on one
    line)."""
    import os
    import subprocess
    import sys

    (tmp_path / "empty" / "twain-mpi").mkdir(parents=True)
    (tmp_path / "empty" / "twain-mpi" / "mpi.json").write_text('{"layers": [')
    proc = subprocess.run(
        [sys.executable, "-m", "clholo.cli", "experiment", "layers", "--reduced", "--scenes",
         "twain", "--data", str(tmp_path / "empty"), "--progress", "bar", "--out",
         str(tmp_path / "x")], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
        env=dict(os.environ, PYTHONUNBUFFERED="1"), timeout=300)
    assert proc.returncode == 2, proc.stdout
    lines = proc.stdout.splitlines()
    errors = [line for line in lines if "error:" in line]
    assert len(errors) == 1 and errors[0].startswith("clholo experiment"), lines
    assert "empty/twain-mpi/mpi.json" in errors[0], errors
    assert any("twain" in line for line in lines[:lines.index(errors[0])]), lines  # progress
    assert not (tmp_path / "x").exists()


# --- issue 26, section 6: a repeated scene, layer count or method runs once, and says so ---------

def test_repeated_values_run_once_and_say_so(tmp_path, capsys, monkeypatch):
    from clholo import cli

    seen = []

    def fake_run_study(out, config, **kwargs):
        seen.append(config)
        return {"rows": [], "out_dir": out, "seconds": 0.0}

    monkeypatch.setattr(study, "run_study", fake_run_study)
    out = tmp_path / "x"
    rc = cli.main(["experiment", "layers", "--layers", "8", "4", "4", "--scenes", "twain",
                   "fox", "twain", "--methods", "mpi", "mpi", "--progress", "lines",
                   "--out", str(out)])
    text = capsys.readouterr().out
    assert rc == 0
    assert seen[0].layers == (4, 8) and seen[0].scenes == ("twain", "fox")
    assert seen[0].methods == ("mpi",)
    lines = [ln.strip() for ln in text.splitlines() if "runs once" in ln]
    assert lines == ["each value runs once: --scenes twain fox twain runs twain fox; --methods "
                     "mpi mpi runs mpi; --layers 8 4 4 runs 8 4"], text
    assert list(tmp_path.iterdir()) == []
    # without a repeat, no such line; the API de-duplicates the same way
    assert cli.main(["experiment", "layers", "--layers", "4", "8", "--out", str(out)]) == 0
    assert "runs once" not in capsys.readouterr().out
    config = dataclasses.replace(TINY, layers=(4, 4, 2), scenes=("fox", "fox")).validated()
    assert config.layers == (2, 4) and config.scenes == ("fox",)


def test_the_run_prints_its_expected_time_when_it_starts(tmp_path, capsys, monkeypatch):
    """README's `clholo experiment layers --methods mpi rgbd rpws` takes minutes on 2 cores:
    the run says so before any work, from a model of the measured runs."""
    from clholo import cli

    monkeypatch.setattr(study, "run_study", lambda out, config, **kw: {
        "rows": [], "out_dir": out, "seconds": 0.0})
    assert cli.main(["experiment", "layers", "--methods", "mpi", "rgbd", "rpws",
                     "--out", str(tmp_path / "x")]) == 0
    out = capsys.readouterr().out
    assert "expected time: about 8 min on 2 CPU cores with PoCL" in out.splitlines()[0], out
    full = dataclasses.replace(study.FULL, methods=("mpi", "rgbd", "rpws"))
    reduced = dataclasses.replace(study.REDUCED, methods=("mpi", "rgbd", "rpws"))
    # the two measured runs (462 s and 67 s), within the model's +-50 %
    assert 462 / 1.5 < study.estimate_seconds(full) < 462 * 1.5
    assert 67 / 1.5 < study.estimate_seconds(reduced) < 67 * 1.5
    # more work, more time
    for more in (dict(frames=48), dict(width=256), dict(layers=(4, 8, 16, 32, 64, 128)),
                 dict(max_splats=None)):
        fewer = dataclasses.replace(full, max_splats=1000)
        assert study.estimate_seconds(dataclasses.replace(fewer, **more)) > \
            study.estimate_seconds(fewer)


@pytest.mark.parametrize("change, error, match", [
    ({"layers": (4.7,)}, TypeError, "layers"),
    ({"layers": (float("nan"),)}, TypeError, "layers"),
    ({"layers": 4}, TypeError, r"layers must be a sequence \(a tuple\)"),
    ({"scenes": "motorcycle"}, TypeError, r"scenes must be a sequence .*scenes=\('motorcycle',\)"),
    ({"near": "2e-3"}, TypeError, "near"),
    ({"far": float("inf")}, ValueError, "far"),
    ({"view_angles_deg": (float("nan"),)}, ValueError, "view_angles_deg"),
    ({"view_angles_deg": (1000.0,)}, ValueError, r"view_angles_deg must be angles in degrees"),
    ({"pupil_angle_rad": 2.0}, ValueError, "pupil_angle_rad"),
    ({"reference_samples": 0}, ValueError, "reference_samples"),
    ({"seed": 1.5}, TypeError, "seed"),
])
def test_study_config_names_what_it_cannot_take(change, error, match):
    """An audit found these cut (layers 4.7 -> 4), crashing (NaN, an int, a string near) or
    read letter by letter (scenes="motorcycle"), or refused late under internal names."""
    import dataclasses

    from clholo.experiments.layers import REDUCED

    with pytest.raises(error, match=match):
        dataclasses.replace(REDUCED, **change).validated()
