"""clholo report: the self-contained HTML page, its inputs and errors, and its sliders in a real
headless browser (Debian's chromium)."""

import json
import os
import re
import shutil
import subprocess

import numpy as np
import pytest

from clholo.cli import main
from clholo.experiments.report import build_report


def render_folder(path, rng, *, views=True, D=3, A=4, C=3, H=24, W=40):
    """What clholo render writes (focal_stack.npz, summary.json, focal_stack.png), + views, as
    a clholo output folder (with its manifest)."""
    from clholo.io.output import output_folder

    with output_folder(path, command="test") as tmp:
        _render_files(tmp, rng, views=views, D=D, A=A, C=C, H=H, W=W)
    return path


def _render_files(path, rng, *, views, D, A, C, H, W):
    from clholo.io import write_image

    np.savez(path / "focal_stack.npz", intensity=rng.uniform(0.0, 1.0, (D, C, H, W)),
             depths_m=np.linspace(2e-3, 6e-3, D), wavelengths_m=np.array([638e-9, 520e-9,
                                                                         450e-9][:C]))
    (path / "summary.json").write_text(json.dumps({"layers": 8, "frames": 4, "seed": 3,
                                                   "depths_m": [0.002, 0.006]}))
    write_image(path / "focal_stack.png", rng.uniform(0, 1, (H, 3 * W, 3)), dtype="uint8")
    if views:
        np.savez(path / "views.npz", angles_rad=np.linspace(-0.02, 0.02, A),
                 intensity=rng.uniform(0.0, 1.0, (A, C, H, W)))


def frames_of(page, name):
    data = json.loads(re.search(r"const SLIDERS = (.*);\n", page).group(1).replace("<\\/", "</"))
    return data[name]["frames"] if name in data else None


def test_render_folder_page_is_self_contained(tmp_path, rng):
    folder = render_folder(tmp_path / "run", rng)
    out = build_report(folder)
    assert out == folder / "report.html"
    page = out.read_text()
    # no server, no network: every src is inline data, no external link or script
    srcs = re.findall(r'src="([^"]*)"', page)
    assert srcs and all(s.startswith("data:image/png;base64,") for s in srcs)
    assert "http://" not in page and "https://" not in page and "<link" not in page
    depth, view = frames_of(page, "depth"), frames_of(page, "view")
    assert len(depth) == 3 and len(view) == 4
    assert len({f["src"] for f in depth}) == 3  # the slices differ
    assert "focused at 4.000 mm" in depth[1]["label"]
    assert "theta_x = -1.146 deg" in view[0]["label"]
    assert 'id="depth-slider" min="0" max="2"' in page
    assert 'id="view-slider" min="0" max="3"' in page
    assert "<td>seed</td><td>3</td>" in page and "focal_stack.png" in page
    # written under a temporary name and renamed: nothing else left beside it
    # (and the page and its record are listed in the folder's manifest)
    assert sorted(os.listdir(folder)) == [".report.html.clholo-output.json", "clholo-output.json",
                                          "focal_stack.npz", "focal_stack.png", "report.html",
                                          "summary.json", "views.npz"]


def test_views_only_when_views_npz_is_there(tmp_path, rng):
    folder = render_folder(tmp_path / "run", rng, views=False, C=1)
    page = build_report(folder, tmp_path / "page.html", title="mono").read_text()
    assert frames_of(page, "view") is None and 'id="view-slider"' not in page
    assert len(frames_of(page, "depth")) == 3 and "<title>mono</title>" in page


def test_experiment_folder_tables_and_plots(tmp_path, rng):
    from clholo.io import write_image

    folder = tmp_path / "exp"
    folder.mkdir()  # a folder of the user's: the page goes elsewhere
    (folder / "results.csv").write_text("L,method,psnr_db\n4,mpi,31.5\n4,rgbd,27.25\n")
    (folder / "results.md").write_text("| L | method |\n|---|---|\n| 4 | mpi <b> |\n")
    write_image(folder / "quality.png", rng.uniform(0, 1, (20, 30, 3)), dtype="uint8")
    page = build_report(folder, tmp_path / "exp.html").read_text()
    assert "<td>rgbd</td><td>27.25</td>" in page
    assert "mpi &lt;b&gt;" in page  # text is escaped
    assert "<figcaption>quality.png</figcaption>" in page and "<script>" not in page


def test_bad_folders_are_named(tmp_path, rng):
    with pytest.raises(FileNotFoundError, match="does not exist"):
        build_report(tmp_path / "missing")
    (tmp_path / "empty").mkdir()
    with pytest.raises(ValueError, match="holds nothing to report"):
        build_report(tmp_path / "empty", tmp_path / "empty.html")
    assert not (tmp_path / "empty.html").exists()
    folder = render_folder(tmp_path / "run", rng)
    np.savez(folder / "views.npz", angles_rad=np.zeros(2), intensity=np.ones((3, 1, 4, 4)))
    with pytest.raises(ValueError, match="views.npz: angles_rad must have shape"):
        build_report(folder)
    np.savez(folder / "views.npz", intensity=np.ones((3, 1, 4, 4)))
    with pytest.raises(ValueError, match="lacks the array"):
        build_report(folder)
    (folder / "views.npz").write_bytes(b"not a zip")
    with pytest.raises(ValueError, match="not a readable .npz"):
        build_report(folder)
    assert not (folder / "report.html").exists()


def test_damaged_figures_and_complex_stacks_are_not_shown_silently(tmp_path, rng):
    """A cut-off PNG (signature intact) is left out with a warning naming it, not embedded
    as a broken image; a focal stack of complex values (the field, not |u|^2) is refused."""
    from clholo.experiments.report import ReportWarning

    folder = tmp_path / "exp"
    folder.mkdir()
    (folder / "results.csv").write_text("L,psnr_db\n4,31.5\n")
    from clholo.io import write_image

    write_image(folder / "good.png", rng.uniform(0, 1, (20, 30, 3)), dtype="uint8")
    whole = (folder / "good.png").read_bytes()
    (folder / "cut.png").write_bytes(whole[:100])
    with pytest.warns(ReportWarning, match=r"cut\.png is not a readable PNG image"):
        page = build_report(folder, tmp_path / "exp.html").read_text()
    assert "<figcaption>good.png</figcaption>" in page and "cut.png</figcaption>" not in page
    run = render_folder(tmp_path / "run", rng, views=False)
    with np.load(run / "focal_stack.npz") as data:
        arrays = dict(data)
    arrays["intensity"] = arrays["intensity"] * (1 + 1j)
    np.savez(run / "focal_stack.npz", **arrays)
    with pytest.raises(ValueError, match="intensity must be real"):
        build_report(run, tmp_path / "run.html")


def test_cli(tmp_path, rng, capsys):
    folder = render_folder(tmp_path / "run", rng)
    assert main(["report", str(folder), "--out", str(tmp_path / "r.html")]) == 0
    assert (tmp_path / "r.html").is_file() and "wrote" in capsys.readouterr().out
    assert main(["report", str(tmp_path / "nothing")]) == 2
    assert "clholo report: error: folder" in capsys.readouterr().err


# --- the output policy (issue 17): a report never replaces what clholo did not write -------------

def test_report_never_overwrites_a_users_file(tmp_path, rng, capsys):
    folder = render_folder(tmp_path / "run", rng, views=False)
    notes = tmp_path / "notes.html"
    notes.write_text("my notes")
    for extra in ([], ["--overwrite"]):
        assert main(["report", str(folder), "--out", str(notes), *extra]) == 2
        err = capsys.readouterr().err
        assert f"--out {notes} exists and is a file clholo did not write" in err, err
        assert notes.read_text() == "my notes"
    # a file the user changed after clholo wrote it is theirs now
    page = tmp_path / "page.html"
    assert main(["report", str(folder), "--out", str(page)]) == 0
    capsys.readouterr()
    page.write_text(page.read_text() + "<!-- my edit -->")
    assert main(["report", str(folder), "--out", str(page), "--overwrite"]) == 2
    assert "changed since" in capsys.readouterr().err
    assert page.read_text().endswith("<!-- my edit -->")
    # a missing parent is refused before any work
    assert main(["report", str(folder), "--out", str(tmp_path / "no" / "r.html")]) == 2
    assert "its parent folder" in capsys.readouterr().err


def test_report_never_replaces_a_file_of_the_output_folder(tmp_path, rng, capsys):
    folder = render_folder(tmp_path / "run", rng, views=False)
    np.savez(folder / "hologram.npz", h=np.ones(3))  # as clholo render writes it, listed
    from clholo.io.output import update_manifest

    update_manifest(folder, add=["hologram.npz"])
    before = (folder / "hologram.npz").read_bytes()
    for extra in ([], ["--overwrite"]):
        assert main(["report", str(folder), "--out", str(folder / "hologram.npz"), *extra]) == 2
        err = capsys.readouterr().err
        assert "is part of the clholo output" in err and "hologram.npz" in err, err
    assert (folder / "hologram.npz").read_bytes() == before


def test_default_report_is_listed_in_the_folders_manifest(tmp_path, rng, capsys):
    from clholo.io.output import check_output_folder, foreign_entries

    folder = render_folder(tmp_path / "run", rng, views=False)
    assert main(["report", str(folder)]) == 0
    assert (folder / "report.html").is_file()
    capsys.readouterr()
    # the folder still holds only what clholo wrote: a later --overwrite of it still works
    assert foreign_entries(folder) == []
    check_output_folder(folder, overwrite=True)
    # a second report needs --overwrite, like every other output
    assert main(["report", str(folder)]) == 2
    assert "already holds an earlier clholo output" in capsys.readouterr().err
    assert main(["report", str(folder), "--overwrite", "--title", "again"]) == 0
    assert "<title>again</title>" in (folder / "report.html").read_text()
    assert foreign_entries(folder) == []


def test_default_report_only_inside_a_clholo_folder(tmp_path, rng, capsys):
    folder = tmp_path / "mine"
    folder.mkdir()
    (folder / "results.csv").write_text("a,b\n1,2\n")
    assert main(["report", str(folder)]) == 2
    err = capsys.readouterr().err
    assert "is not a folder clholo wrote" in err and "--out" in err, err
    assert sorted(p.name for p in folder.iterdir()) == ["results.csv"]
    assert main(["report", str(folder), "--out", str(tmp_path / "mine.html")]) == 0
    assert (tmp_path / "mine.html").is_file()


# --- in a real browser ----------------------------------------------------------------------------

def chromium():
    for name in ("chromium", "chromium-browser"):
        path = shutil.which(name)
        if path:
            return path
    pytest.skip("chromium is not installed (apt-get install -y chromium); the page's sliders "
                "are tested in a headless browser only")


def run_chromium(tmp_path, *args):
    exe = chromium()
    profile = tmp_path / "chromium-profile"
    cmd = [exe, "--headless", "--no-sandbox", "--disable-gpu", "--hide-scrollbars",
           "--no-first-run", "--disable-extensions", f"--user-data-dir={profile}",
           "--window-size=700,900", *args]
    res = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stderr[-2000:]
    return res.stdout


def test_sliders_in_headless_chromium(tmp_path, rng):
    from clholo.io.images import read_image

    folder = render_folder(tmp_path / "run", rng, H=96, W=160)
    page = build_report(folder)
    url = page.resolve().as_uri()
    frames = frames_of(page.read_text(), "depth")
    # the page moves its slider from the address (the slider's own input event), after load
    dom = run_chromium(tmp_path, "--dump-dom", url + "#depth=2&view=3")
    img = re.search(r'<img id="depth-img"[^>]*>', dom).group(0)
    assert 'data-index="2"' in img and frames[2]["src"] in img
    assert 'data-index="3"' in re.search(r'<img id="view-img"[^>]*>', dom).group(0)
    assert "slice 2: focused at 6.000 mm" in dom
    shots = {}
    for k in (0, 2):
        shot = tmp_path / f"depth{k}.png"
        run_chromium(tmp_path, f"--screenshot={shot}", url + f"#depth={k}")
        shots[k] = read_image(shot)[0][..., :3]
    assert shots[0].shape == shots[2].shape
    changed = np.any(np.abs(shots[0] - shots[2]) > 0.02, axis=2)
    # the shown image changed: a block of pixels at least the size of the focal image
    assert changed.sum() > 0.5 * 96 * 160, changed.sum()


def test_block_mean_is_the_mean_of_each_block(rng):
    from clholo.experiments.report import block_mean

    image = rng.uniform(0, 1, (11, 7, 2))
    assert np.array_equal(block_mean(image, 1), image)
    out = block_mean(image, 3)  # 11 = 3+3+3+2 rows, 7 = 3+3+1 columns
    assert out.shape == (4, 3, 2)
    for i in range(4):
        for j in range(3):
            np.testing.assert_allclose(out[i, j], image[3 * i:3 * i + 3, 3 * j:3 * j + 3]
                                       .mean(axis=(0, 1)), rtol=1e-13)


def test_large_images_are_shown_reduced_and_say_so(tmp_path, rng):
    from clholo.experiments.report import DISPLAY_MAX_SIDE_PX, block_mean
    from clholo.io import linear_to_srgb8, read_image, srgb_to_linear

    folder = render_folder(tmp_path / "run", rng, H=24, W=40)
    out = build_report(folder, max_side=16)  # 40 -> 14 (1/3), the sheet's 120 -> 15 (1/8)
    page = out.read_text()
    stack = np.load(folder / "focal_stack.npz")["intensity"]
    scale = np.percentile(stack, 99.5)

    def decoded(src, name):
        path = tmp_path / name
        path.write_bytes(__import__("base64").b64decode(src.split(",", 1)[1]))
        return read_image(path, normalise=False)[0]

    for k, frame in enumerate(frames_of(page, "depth")):
        want = linear_to_srgb8(np.clip(block_mean(stack[k].transpose(1, 2, 0), 3) / scale, 0, 1))
        np.testing.assert_array_equal(decoded(frame["src"], f"d{k}.png"), want)
    assert "shown at 14x8, 1/3 of the stored 40x24 in each direction" in page
    assert "every pixel in focal_stack.npz" in page and "every pixel in views.npz" in page
    assert decoded(frames_of(page, "view")[0]["src"], "v.png").shape == (8, 14, 3)
    # the contact sheet figure: decoded from sRGB, block means in linear light, encoded again
    sheet, _ = read_image(folder / "focal_stack.png")
    figure = re.search(r'<figure><img alt="focal_stack.png" src="([^"]*)"', page).group(1)
    want = linear_to_srgb8(block_mean(srgb_to_linear(sheet), 8))
    np.testing.assert_array_equal(decoded(figure, "f.png"), want)
    assert "focal_stack.png (shown at 15x3, 1/8 of the stored 120x24" in page
    # in bands of whole blocks (8 rows: three bands), the same figure
    import clholo.experiments.report as report

    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(report, "_FIGURE_BAND_ELEMENTS", 8 * 120 * 3)
        banded = build_report(folder, tmp_path / "banded.html", max_side=16).read_text()
    assert re.search(r'<figure><img alt="focal_stack.png" src="([^"]*)"',
                     banded).group(1) == figure
    # a figure whose last block is cut short (27 rows in blocks of 2), in bands of 4 rows,
    # RGBA: its alpha reduced as stored
    from clholo.io import write_image

    plots = tmp_path / "plots"
    plots.mkdir()
    rgba = rng.uniform(0, 1, (27, 20, 4))
    write_image(plots / "plot.png", rgba, dtype="uint8")
    stored, _ = read_image(plots / "plot.png")
    want = block_mean(np.concatenate([srgb_to_linear(stored[..., :3]), stored[..., 3:]], -1), 2)
    want_codes = np.round(want * 255).astype(np.uint8)
    want_codes[..., :3] = linear_to_srgb8(want[..., :3])
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(report, "_FIGURE_BAND_ELEMENTS", 4 * 20 * 4)
        page = build_report(plots, tmp_path / "plots.html", max_side=16).read_text()
    src = re.search(r'<figure><img alt="plot.png" src="([^"]*)"', page).group(1)
    np.testing.assert_array_equal(decoded(src, "p.png"), want_codes)
    # 0 or None: every pixel, and no note
    for full in (0, None):
        page = build_report(folder, tmp_path / f"full{full}.html", max_side=full).read_text()
        assert decoded(frames_of(page, "depth")[0]["src"], "full.png").shape == (24, 40, 3)
        assert "shown at" not in page
    # the default leaves images of up to 2048 pixels as they are
    assert DISPLAY_MAX_SIDE_PX == 2048 and "shown at" not in build_report(
        folder, tmp_path / "default.html").read_text()
    for bad in (-1, 2.5, True, "16"):
        with pytest.raises(ValueError, match="max_side must be a whole number"):
            build_report(folder, tmp_path / "bad.html", max_side=bad)


def test_cli_max_side(tmp_path, rng, capsys):
    from clholo.cli import build_parser
    from clholo.experiments.report import DISPLAY_MAX_SIDE_PX

    args = build_parser().parse_args(["report", "x"])
    assert args.max_side == DISPLAY_MAX_SIDE_PX
    folder = render_folder(tmp_path / "run", rng, H=24, W=40)
    assert main(["report", str(folder), "--max-side", "20"]) == 0
    assert "shown at 20x12, 1/2 of the stored 40x24" in (folder / "report.html").read_text()
    with pytest.raises(SystemExit):
        main(["report", str(folder), "--max-side", "-3"])
    assert "--max-side" in capsys.readouterr().err
