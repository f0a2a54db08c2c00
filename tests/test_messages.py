"""Messages that say what is wrong (issue 26, sections 6 and 7), as a user meets them: the exit
code, the one line on stderr, and the files before and after."""

import json

import numpy as np
import pytest

import clholo
from clholo import cli

from conftest import random_complex, require_module

PLY_HEADER = ("ply\nformat binary_little_endian 1.0\nelement vertex 0\n"
              + "".join(f"property float {p}\n" for p in
                        ["x", "y", "z", "f_dc_0", "f_dc_1", "f_dc_2", "opacity", "scale_0",
                         "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"])
              + "end_header\n")


def _run(argv, capsys):
    """(exit code, stderr lines) of one command, argparse's exits included."""
    try:
        rc = cli.main(argv)
    except SystemExit as exc:
        rc = exc.code
    return rc, capsys.readouterr().err.strip().splitlines()


def _files(folder):
    return sorted(str(p.relative_to(folder)) for p in folder.rglob("*"))


def _mpi_folder(path, rng, L=2, H=8, W=8):
    mpi = clholo.MPI(rng.uniform(0, 1, (L, H, W, 3)), rng.uniform(0, 1, (L, H, W)),
                     np.linspace(2e-3, 3e-3, L))
    clholo.io.write_mpi(path, mpi, format="png8")
    return path


# --- empty .ply ---------------------------------------------------------------------------------

@pytest.mark.parametrize("content, line", [
    ("", "{p} holds no splats (the file is empty, 0 bytes); export the trained point cloud "
         "again"),
    (PLY_HEADER, "{p} holds no splats (its header says 'element vertex 0'); export the "
                 "trained point cloud again"),
    (PLY_HEADER.replace("property float opacity\n", ""),
     "{p} holds no splats (its header says 'element vertex 0'); export the trained point "
     "cloud again"),
])
@pytest.mark.parametrize("argv", [
    ["display", "{p}", "--memory", "--seconds", "1"],
    ["display", "{p}", "--memory", "--seconds", "1", "--near", "0.002", "--far", "0.004"],
    ["render", "{p}", "--frames", "1", "--out", "{out}"],
    ["render", "{p}", "--method", "rpws", "--frames", "1", "--near", "0.002", "--far", "0.004",
     "--out", "{out}"],
])
def test_a_ply_without_splats_says_so(tmp_path, capsys, content, line, argv):
    ply = tmp_path / "empty.ply"
    ply.write_text(content)
    before = _files(tmp_path)
    rc, err = _run([a.format(p=ply, out=tmp_path / "out") for a in argv], capsys)
    assert rc == 2 and len(err) == 1, err
    assert err[0] == f"clholo {argv[0]}: error: " + line.format(p=ply)
    assert _files(tmp_path) == before


# --- two scenes are not an RGB-D pair -----------------------------------------------------------

def test_two_scenes_are_not_an_rgbd_pair(tmp_path, rng, capsys):
    a, b = _mpi_folder(tmp_path / "a", rng), _mpi_folder(tmp_path / "b", rng)
    ply = tmp_path / "s.ply"
    ply.write_text(PLY_HEADER)
    before = _files(tmp_path)
    rest = "give one scene; two paths are an RGB-D pair only as an image and its depth map"
    for inputs, what in [
        ([a, b], f"{a} (an MPI folder) and {b} (an MPI folder)"),
        ([ply, ply], f"{ply} (a 3D Gaussian splat .ply) and {ply} (a 3D Gaussian splat .ply)"),
        ([a, tmp_path / "gone.png"], f"{a} (an MPI folder) and {tmp_path / 'gone.png'} "
                                     f"(missing)"),
    ]:
        for command in (["render", *map(str, inputs), "--out", str(tmp_path / "out")],
                        ["display", *map(str, inputs), "--memory"]):
            rc, err = _run([*command, "--near", "0.002", "--far", "0.004"], capsys)
            assert rc == 2 and len(err) == 1, err
            assert err[0] == f"clholo {command[0]}: error: two scene inputs given, {what}: {rest}"
    assert _files(tmp_path) == before
    # an image and a depth map that are missing: said so, not that near/far are missing
    rc, err = _run(["render", str(tmp_path / "x.png"), str(tmp_path / "d.npy"), "--out",
                    str(tmp_path / "out")], capsys)
    assert rc == 2 and err == [f"clholo render: error: scene input {tmp_path / 'x.png'} does "
                               f"not exist"]


# --- lookup tables ------------------------------------------------------------------------------

def _hologram(tmp_path, rng, C=3):
    path = tmp_path / "holo.npz"
    clholo.io.write_hologram(path, random_complex(rng, (1, C, 8, 12)), pitch=8e-6,
                             wavelengths=[638e-9, 520e-9, 450e-9][:C])
    return path


def _tables():
    g = np.arange(256)
    return np.stack([2 * np.pi * g / n for n in (255, 230, 200)], axis=1)  # (256, 3)


def test_lut_folder_is_called_a_folder(tmp_path, rng, capsys):
    holo = _hologram(tmp_path, rng)
    (tmp_path / "luts").mkdir()
    before = _files(tmp_path)
    rc, err = _run(["encode", str(holo), "--lut", str(tmp_path / "luts"), "--out",
                    str(tmp_path / "out")], capsys)
    assert rc == 2 and err == [f"clholo encode: error: lookup table {tmp_path / 'luts'} is a "
                               f"folder, not a file: give a .csv or .npy table of 256 phases "
                               f"in radians (or 'linear', 'linear:N')"]
    assert _files(tmp_path) == before


@pytest.mark.parametrize("write", ["npy", "csv", "csv-gray"])
def test_a_lut_of_one_column_per_colour_is_one_table_per_colour(tmp_path, rng, capsys, write):
    """Colour-sequential SLMs ship one table per laser: 256 rows, one column per colour, in the
    order of the wavelengths (docs/encode.md); the same patterns as three files."""
    holo = _hologram(tmp_path, rng)
    tables = _tables()
    if write == "npy":
        path = tmp_path / "rgb.npy"
        np.save(path, tables)
    else:
        path = tmp_path / "rgb.csv"
        data = np.c_[np.arange(256), tables] if write == "csv-gray" else tables
        np.savetxt(path, data, delimiter=",")
    singles = []
    for c in range(3):
        singles.append(tmp_path / f"c{c}.npy")
        np.save(singles[-1], tables[:, c])
    common = ["--method", "dpac", "--z-slm", "0.002", "--slm-size", "8", "12"]
    assert cli.main(["encode", str(holo), *common, "--lut", str(path), "--out",
                     str(tmp_path / "one")]) == 0, capsys.readouterr().err
    assert cli.main(["encode", str(holo), *common, "--lut", *map(str, singles), "--out",
                     str(tmp_path / "three")]) == 0, capsys.readouterr().err
    one = clholo.encode.read_pattern_pngs(tmp_path / "one")
    np.testing.assert_array_equal(one, clholo.encode.read_pattern_pngs(tmp_path / "three"))
    assert [int(one[:, c].max()) < n for c, n in enumerate((255, 230, 200))] == [True] * 3
    info = json.loads((tmp_path / "one" / "patterns.json").read_text())["extra"]
    assert [t["name"] for t in info["luts"]] == [f"{path}[colour {c}]" for c in range(3)]


@pytest.mark.parametrize("shape, line", [
    ((3, 256), "{p}: a lookup table is 256 phases (one per gray level 0..255), or 256 rows "
               "with one column per colour; the file holds shape (3, 256) (one row per colour: "
               "transpose it)"),
    ((768,), "{p}: an 8-bit SLM's lookup table has 256 phases (one per gray level 0..255), got "
             "shape (768,)"),
    ((256, 4), "--lut: give one table for all colours or 3 (one per colour), got 4; {p} holds "
               "4 (one column per colour)"),
    ((2, 256, 3), "{p}: a lookup table is 256 phases (one per gray level 0..255), or 256 rows "
                  "with one column per colour; the file holds shape (2, 256, 3)"),
])
def test_other_lut_shapes_are_named_as_written(tmp_path, rng, capsys, shape, line):
    holo = _hologram(tmp_path, rng)
    path = tmp_path / "lut.npy"
    np.save(path, np.resize(_tables().T.ravel(), shape) if shape != (256, 4)
            else np.c_[_tables(), _tables()[:, :1]])
    before = _files(tmp_path)
    rc, err = _run(["encode", str(holo), "--lut", str(path), "--out", str(tmp_path / "out")],
                   capsys)
    assert rc == 2 and err == ["clholo encode: error: " + line.format(p=path)], err
    assert _files(tmp_path) == before


# --- report -------------------------------------------------------------------------------------

@pytest.fixture
def render_folder(tmp_path, rng, capsys):
    scene = _mpi_folder(tmp_path / "scene", rng)
    out = tmp_path / "run"
    assert cli.main(["render", str(scene), "--frames", "1", "--out", str(out),
                     "--progress", "off"]) == 0
    capsys.readouterr()
    return out


def test_report_overwrite_on_an_edited_report_suggests_another_path(render_folder, capsys):
    run = render_folder
    assert cli.main(["report", str(run)]) == 0
    capsys.readouterr()
    with open(run / "report.html", "a") as f:
        f.write("<!-- my notes -->")
    edited = (run / "report.html").read_bytes()
    before = _files(run)
    rc, err = _run(["report", str(run), "--overwrite"], capsys)
    assert rc == 2 and err == [
        f"clholo report: error: --out {run / 'report.html'} is a report clholo wrote there, "
        f"changed since: clholo will not replace an edited file; choose another --out, e.g. "
        f"{run / 'report-2.html'}"], err
    assert (run / "report.html").read_bytes() == edited and _files(run) == before
    # the suggestion works
    assert cli.main(["report", str(run), "--out", str(run / "report-2.html")]) == 0
    assert (run / "report.html").read_bytes() == edited


def test_report_skips_a_png_that_is_not_one_with_a_warning(render_folder, capsys):
    run = render_folder
    (run / "notes.png").write_text("not an image")
    out = run.parent / "r.html"
    rc, err = _run(["report", str(run), "--out", str(out)], capsys)
    assert rc == 0
    assert err == [f"clholo report: warning: {run / 'notes.png'} is not a readable PNG image "
                   f"(it does not start with the PNG signature), so the report leaves it out"]
    page = out.read_text()
    assert "notes.png" not in page and "focal_stack.png" in page
    with pytest.warns(clholo.experiments.report.ReportWarning, match="notes.png"):
        clholo.experiments.report.build_report(run, run.parent / "r2.html")


# --- experiment name ----------------------------------------------------------------------------

@pytest.mark.parametrize("argv, got", [
    (["experiment", "--out", "x"], " ('x' is not one)"),
    (["experiment"], ""),
    (["experiment", "--progress", "off", "lay"], " ('lay' is not one)"),
])
def test_experiment_without_its_name_says_so_and_lists_them(tmp_path, monkeypatch, capsys, argv,
                                                          got):
    monkeypatch.chdir(tmp_path)
    rc, err = _run(argv, capsys)
    assert rc == 2
    assert err[-1] == (f"clholo experiment: error: the experiment's name is missing{got}: "
                       f"write clholo experiment NAME [options] with NAME one of: layers")
    assert list(tmp_path.iterdir()) == []


# --- wavelengths a display cannot use -----------------------------------------------------------

@pytest.mark.parametrize("value, hint", [
    ("1e-9", "did you mean 1e-6?"), ("520e-12", "did you mean 5.2e-7?"),
    ("0.52", "did you mean 5.2e-7?"), ("5e-6", "give metres, e.g. 520e-9 for green"),
])
def test_render_refuses_a_wavelength_outside_0_2_to_2_um(tmp_path, rng, capsys, value, hint):
    scene = _mpi_folder(tmp_path / "scene", rng)
    before = _files(tmp_path)
    rc, err = _run(["render", str(scene), "--wavelengths", value, value, value, "--frames",
                    "1", "--out", str(tmp_path / "out")], capsys)
    assert rc == 2 and len(err) == 1, err
    shown = {"520e-12": "5.2e-10", "0.52": "0.52"}.get(value, value)
    assert err[0] == (f"clholo render: error: wavelengths={shown} m is outside 0.2-2 um, the "
                      f"wavelengths a holographic display can use: {hint}")
    assert _files(tmp_path) == before


def test_a_batch_item_on_a_ply_without_splats_says_so(tmp_path, capsys):
    require_module("distributed", "batch")  # clholo batch runs its items on Dask
    (tmp_path / "empty.ply").write_text("")
    (tmp_path / "zero.ply").write_text(PLY_HEADER)
    manifest = tmp_path / "m.csv"
    manifest.write_text("id,input,near,far,frames\ne,empty.ply,0.002,0.004,1\nz,zero.ply,,,1\n")
    out = tmp_path / "out"
    rc, err = _run(["batch", str(manifest), "--out", str(out), "--workers", "1",
                    "--progress", "off"], capsys)
    assert rc == 1
    failed = [ln for ln in err if "failed:" in ln]
    assert failed == [
        f"clholo batch: item e failed: ValueError: {tmp_path / 'empty.ply'} holds no splats (the "
        f"file is empty, 0 bytes); export the trained point cloud again",
        f"clholo batch: item z failed: ValueError: {tmp_path / 'zero.ply'} holds no splats (its "
        f"header says 'element vertex 0'); export the trained point cloud again"], err
    assert not (out / "e").exists() and not (out / "z").exists()
