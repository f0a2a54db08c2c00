"""Odd inputs of the rerun after issue 26 (variants of its cases on every command), as a user
meets them: the exit code, the one line on stderr, and the files before and after."""

import json
import os
import subprocess
import sys

import numpy as np
import pytest

import clholo
from clholo import cli


def _run(argv, capsys):
    """(exit code, stderr lines) of one command, argparse's exits included."""
    try:
        rc = cli.main([str(a) for a in argv])
    except SystemExit as exc:
        rc = exc.code
    return rc, capsys.readouterr().err.strip().splitlines()


def _files(folder):
    return sorted(str(p.relative_to(folder)) for p in folder.rglob("*"))


def _mpi_folder(path, rng, L=2, H=8, W=8, format="png8"):
    mpi = clholo.MPI(rng.uniform(0, 1, (L, H, W, 3)), rng.uniform(0, 1, (L, H, W)),
                     np.linspace(2e-3, 3e-3, L))
    clholo.io.write_mpi(path, mpi, format=format)
    return path


def _refused(argv, capsys, folder, line, code=2):
    before = _files(folder)
    rc, err = _run(argv, capsys)
    assert rc == code and err and err[-1] == line, err
    assert _files(folder) == before


# --- negative numbers in any float spelling reach the option's own check -----------------------

@pytest.mark.parametrize("argv, line", [
    (["render", "scene", "--pitch", "-8e-6"],
     "clholo render: error: argument --pitch: must be a finite number > 0, got '-8e-6'"),
    (["render", "scene", "--wavelengths", "-6.38E-7", "5.2e-7", "4.5e-7"],
     "clholo render: error: argument --wavelengths: must be a finite number > 0, got "
     "'-6.38E-7'"),
    (["render", "scene", "--pad", "-inf"],
     "clholo render: error: argument --pad: must be 'auto' or a factor >= 1 such as 2, got "
     "'-inf'"),
    (["encode", "holo.npz", "--z-slm", "-1e-2"],
     "clholo encode: error: argument --z-slm: must be a finite number > 0, got '-1e-2'"),
])
def test_a_negative_number_in_exponent_form_is_a_value_not_an_option(tmp_path, capsys, argv,
                                                                      line):
    # argparse took "-8e-6" for an option: "argument --pitch: expected one argument"
    _refused(argv, capsys, tmp_path, line)


# --- capture: patterns of colours the bench has no laser for ---------------------------------

def test_capture_refuses_patterns_with_more_colours_than_lasers(tmp_path, rng, capsys,
                                                                monkeypatch):
    from test_capture import BENCH

    monkeypatch.chdir(tmp_path)
    (tmp_path / "bench.toml").write_text(
        BENCH.replace('luts = ["red.lut", "green.lut"]\n', "")
        .replace('phase_luts = ["linear:230", "measured_green.csv"]\n', ""))
    np.save(tmp_path / "rgb.npy", rng.integers(0, 256, (2, 3, 8, 12), dtype=np.uint8))
    _refused(["capture", "focal-sweep", "--config", "bench.toml", "--patterns", "rgb.npy",
              "--out", "stack", "--simulate"], capsys, tmp_path,
             "clholo capture focal-sweep: error: --patterns rgb.npy has 3 colour(s) (shape "
             "(2, 3, 8, 12), [T, C, H, W]) but the bench has 2 laser(s) ([slm] wavelengths_m = "
             "[6.38e-07, 5.2e-07]): give one pattern per wavelength (or one colour), or fix "
             "wavelengths_m in bench.toml")
    # one colour, or one per laser, is taken
    np.save(tmp_path / "one.npy", rng.integers(0, 256, (8, 12), dtype=np.uint8))
    rc, err = _run(["capture", "focal-sweep", "--config", "bench.toml", "--patterns",
                    "one.npy", "--out", "stack", "--simulate", "--speedup", "1000"], capsys)
    assert rc == 0, err
    assert (tmp_path / "stack" / "p000_t00_c0.png").is_file()


# --- batch manifests with odd rows: refused before any work -----------------------------------

@pytest.mark.parametrize("name, text, line", [
    ("twice.csv", "id,input,frames,frames\na,{scene},1,2\n",
     "twice.csv: column 'frames' appears 2 times in the header row; give each column once"),
    ("short.csv", "id,input,frames\na,{scene}\n",
     "short.csv row 2: 2 cell(s) but the header has 3 columns (no cell for 'frames'); write "
     "an empty cell (two commas) for a default"),
    ("nm.csv", "id,input,frames,wavelengths\na,{scene},1,638 520 450\n",
     "nm.csv row 2: wavelengths=638.0 is not a wavelength in metres: give it in metres, e.g. "
     "520e-9 for green (638 nm is 6.38e-07 m)"),
    ("pair.jsonl", '{{"id": "a", "input": ["{scene}", "{scene}"], "frames": 1}}\n',
     'pair.jsonl line 1: column \'input\' must be one path as text, got ["{scene}", '
     '"{scene}"]; an image and its depth map go in the columns \'input\' and \'depth\''),
])
def test_batch_refuses_odd_rows_before_any_work(tmp_path, rng, capsys, monkeypatch, name,
                                                text, line):
    monkeypatch.chdir(tmp_path)
    _mpi_folder(tmp_path / "scene", rng)
    (tmp_path / name).write_text(text.format(scene="scene"))
    # the short row was rendered with the default frames, the second 'frames' column
    # silently won, the list became the path "['scene', 'scene']" on a worker, and nanometres
    # failed every item after the workers had started
    _refused(["batch", name, "--out", "ds"], capsys, tmp_path,
             "clholo batch: error: " + line.format(scene="scene"))


# --- outputs: --overwrite alone, empty paths ----------------------------------------------------

@pytest.mark.parametrize("argv, line", [
    (["selftest", "--quick", "--overwrite"],
     "clholo selftest: error: --overwrite replaces an earlier --json report: give --json FILE, "
     "or drop --overwrite"),
    (["selftest", "--quick", "--json", ""],
     "clholo selftest: error: argument --json: the value is empty (''); give a path, or leave "
     "the option out"),
    (["render", "scene", "--out", ""],
     "clholo render: error: argument --out: the value is empty (''); give a path, or leave the "
     "option out"),
    (["batch", "m.csv", "--out", " "],
     "clholo batch: error: argument --out: the value is empty (' '); give a path, or leave the "
     "option out"),
    (["report", ""],
     "clholo report: error: argument folder: the value is empty (''); give a path"),
    (["encode", "holo.npz", "--lut", ""],
     "clholo encode: error: argument --lut: the value is empty (['']); give a path, or leave "
     "the option out"),
    (["render", "scene", "", "--near", "0.002", "--far", "0.004"],
     "clholo render: error: argument SCENE: the value is empty (['scene', '']); give a path"),
    (["experiment", "layers", "--data", ""],
     "clholo experiment layers: error: argument --data: the value is empty (''); give a path, "
     "or leave the option out"),
])
def test_overwrite_without_a_file_and_empty_values_are_refused(tmp_path, rng, capsys,
                                                              monkeypatch, argv, line):
    # selftest --overwrite ran and ignored the flag; --json "" wrote no report, exit 0;
    # --out "" was "the current folder" or "a folder with other files in it"; an empty path
    # was "." to every check ("hologram file . does not exist"), and --data "" ran the whole
    # experiment on the default data
    monkeypatch.chdir(tmp_path)
    _mpi_folder(tmp_path / "scene", rng)
    (tmp_path / "m.csv").write_text("id,input,frames\na,scene,1\n")
    _refused(argv, capsys, tmp_path, line)


def test_display_log_folder_suggests_a_csv_name(tmp_path, rng, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    _mpi_folder(tmp_path / "scene", rng)
    (tmp_path / "logs").mkdir()
    _refused(["display", "scene", "--memory", "--seconds", "0.2", "--log", "logs"], capsys,
             tmp_path, f"clholo display: error: --log {tmp_path / 'logs'} is a folder; give a "
                       f"file name, e.g. --log {tmp_path / 'logs' / 'clholo-out.csv'}")


# --- hologram .npz files that are not what they say -------------------------------------------

def _good_npz(tmp_path, rng):
    field = (rng.standard_normal((1, 3, 8, 8)) + 1j * rng.standard_normal((1, 3, 8, 8)))
    clholo.io.write_hologram(tmp_path / "good.npz", field.astype(np.complex64), pitch=8e-6,
                             wavelengths=[638e-9, 520e-9, 450e-9])
    return dict(np.load(tmp_path / "good.npz"))


@pytest.mark.parametrize("make, line", [
    (lambda p, z: p.write_text("hello\n"),
     "{p} is not a NumPy .npz archive (it starts with b'hell', not the zip signature): give "
     "the hologram.npz that clholo render or clholo.io.write_hologram writes"),
    (lambda p, z: p.write_bytes(b"\x89PNG\r\n\x1a\n" + bytes(20)),
     "{p} is not a NumPy .npz archive (it starts with b'\\x89PNG', not the zip signature): "
     "give the hologram.npz that clholo render or clholo.io.write_hologram writes"),
    (lambda p, z: p.write_bytes(open(_save_npy(p, z), "rb").read()),
     "{p} is a NumPy .npy array (numpy.save), not an .npz archive: give the hologram.npz that "
     "clholo render or clholo.io.write_hologram writes"),
    (lambda p, z: np.savez(p, **{k: v for k, v in z.items() if k != "field"}),
     "{p} is not a clholo hologram .npz: it has no 'field' array (it holds pitch, "
     "wavelengths, seed, metadata); write it with clholo.io.write_hologram"),
    (lambda p, z: np.savez(p, **dict(z, field=np.where(
        np.arange(z["field"].size).reshape(z["field"].shape) == 9, np.nan,
        z["field"]).astype(np.complex64))),
     "{p}: its field holds 1 NaN/inf value(s) (the first at [t, c, y, x] = [0, 0, 1, 1]): "
     "every value must be finite; render or write the hologram again"),
])
def test_a_hologram_file_that_is_not_one_is_named(tmp_path, rng, capsys, monkeypatch, make,
                                                  line):
    # a text or PNG file was "pickled (object) data", a missing array was
    # "'field is not a file in the archive'", and NaN was "holograms contain NaN/inf values"
    # without the file
    monkeypatch.chdir(tmp_path)
    z = _good_npz(tmp_path, rng)
    if "seed" not in z:
        line = line.replace(" seed,", "")
    make(tmp_path / "odd.npz", z)
    _refused(["encode", "odd.npz", "--out", "o"], capsys, tmp_path,
             "clholo encode: error: " + line.format(p="odd.npz"))


def _save_npy(p, z):
    np.save(p.with_suffix(".tmp.npy"), z["field"])
    return p.with_suffix(".tmp.npy")


# --- output folders: a garbled manifest, and the command's own input --------------------------

def test_a_garbled_manifest_is_called_garbled(tmp_path, rng, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    _mpi_folder(tmp_path / "scene", rng)
    (tmp_path / "run").mkdir()
    (tmp_path / "run" / "clholo-output.json").write_text('{"written_by": "clholo 0.1')
    (tmp_path / "run" / "summary.json").write_text("{}")
    # it said "(it has no clholo-output.json)" beside the file it has
    _refused(["render", "scene", "--out", "run", "--overwrite"], capsys, tmp_path,
             f"clholo render: error: --out {tmp_path / 'run'} exists and is not a folder clholo "
             f"wrote (its clholo-output.json is not valid JSON: edited or cut short): clholo "
             f"will not replace it; choose another --out")
    _refused(["report", "run"], capsys, tmp_path,
             "clholo report: error: run is not a folder clholo wrote (its clholo-output.json is "
             "not valid JSON: edited or cut short), so the report will not be written into it: "
             "give --out FILE.html outside it")


def test_overwrite_never_deletes_the_commands_own_input(tmp_path, rng, capsys, monkeypatch):
    from clholo.io.output import output_folder

    monkeypatch.chdir(tmp_path)
    field = (rng.standard_normal((1, 3, 8, 8)) + 1j * rng.standard_normal((1, 3, 8, 8)))
    with output_folder(tmp_path / "run", command="render") as tmp:
        clholo.io.write_hologram(tmp / "hologram.npz", field.astype(np.complex64), pitch=8e-6,
                                 wavelengths=[638e-9, 520e-9, 450e-9])
    data = (tmp_path / "run" / "hologram.npz").read_bytes()
    # the folder was replaced by the patterns, and the hologram they came from was gone
    _refused(["encode", "run/hologram.npz", "--method", "dpac", "--out", "run", "--overwrite"],
             capsys, tmp_path,
             f"clholo encode: error: --out {tmp_path / 'run'} holds this command's input "
             f"run/hologram.npz: --overwrite would delete it with the folder; choose another "
             f"--out")
    assert (tmp_path / "run" / "hologram.npz").read_bytes() == data


# --- MPI folders -----------------------------------------------------------------------------

def _edit(folder, change):
    meta = json.loads((folder / "mpi.json").read_text())
    change(meta)
    (folder / "mpi.json").write_text(json.dumps(meta))


@pytest.mark.parametrize("change, line", [
    (lambda m: m["depths"].__setitem__(1, "0.003"),
     "scene/mpi.json: 'depths' must be numbers, got \"0.003\" (str) among them; write e.g. "
     "0.004, unquoted"),
    (lambda m: m["depths"].__setitem__(0, True),
     "scene/mpi.json: 'depths' must be numbers, got true (bool) among them; write e.g. 0.004, "
     "unquoted"),
    (lambda m: m.__setitem__("version", 2),
     "scene/mpi.json: 'version' 2 of the clholo-mpi format is not one this clholo reads (1): "
     "upgrade clholo, or write the folder with clholo.io.write_mpi"),
    (lambda m: m["layers"].__setitem__(0, "."),
     "scene/mpi.json: layer 0 names '.', which is a folder (scene): give the layer's image "
     "file"),
])
def test_mpi_json_values_a_user_would_question(tmp_path, rng, capsys, monkeypatch, change,
                                               line):
    # a quoted depth and true (as 1.0) were taken; a later version was read as version 1; a
    # folder as a layer "does not exist"
    monkeypatch.chdir(tmp_path)
    _edit(_mpi_folder(tmp_path / "scene", rng), change)
    _refused(["render", "scene", "--frames", "1", "--out", "r"], capsys, tmp_path,
             "clholo render: error: " + line)


def test_colour_out_of_range_names_its_layer(tmp_path, rng, capsys, monkeypatch):
    from clholo.io.images import read_image, write_image

    monkeypatch.chdir(tmp_path)
    _mpi_folder(tmp_path / "scene", rng, format="exr")
    px, _ = read_image(tmp_path / "scene" / "layer_01.exr")
    px[0, 0, 0] = 2.0
    write_image(tmp_path / "scene" / "layer_01.exr", px, dtype="float")
    # it named the range of all layers, "in scene/layer_00.exr..scene/layer_01.exr"
    rc, err = _run(["render", "scene", "--frames", "1", "--out", "r"], capsys)
    assert rc == 2 and err[-1].startswith(
        "clholo render: error: scene/layer_01.exr: colour outside [0, 1] (range "), err
    assert err[-1].endswith("..2); MPI colour is intensity in [0, 1]"), err
    assert not (tmp_path / "r").exists()


def test_a_truncated_layer_image_is_one_line(tmp_path, rng, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    _mpi_folder(tmp_path / "scene", rng, H=64, W=96)
    png = tmp_path / "scene" / "layer_01.png"
    png.write_bytes(png.read_bytes()[:300])
    # OpenImageIO's error text came on three lines: the last line on stderr was
    # "PNG library error (truncated file?)", not clholo's
    rc, err = _run(["render", "scene", "--frames", "1", "--out", "r"], capsys)
    assert rc == 2
    assert err[-1].startswith("clholo render: error: cannot read pixels of scene/layer_01.png: ")
    assert err[-1].endswith("(truncated file?)") and "PNG library error" in err[-1]
    assert not (tmp_path / "r").exists()


# --- signals at the very end -----------------------------------------------------------------

# the child: run `clholo info` with a command that does CASE, as the console script does
CHILD = r"""
import os, signal, sys
sys.argv = ["clholo", "info"]
from clholo import cli
from clholo.commands import info

class HalfMade:                      # pytools.PersistentDict, interrupted in its __init__
    def __init__(self):
        raise KeyboardInterrupt("signal 15")
    def __del__(self):
        self.mutex

def command(args):
    if CASE == "interrupted":
        HalfMade()
    print("done", flush=True)
    return 0

CASE = os.environ["CASE"]
info.cmd_info = command
code = cli.main()
if CASE == "late":                   # SIGTERM while Python shuts down, the work complete
    os.kill(os.getpid(), signal.SIGTERM)
sys.exit(code)
"""


@pytest.mark.parametrize("case, code, err", [
    ("late", 0, ""),
    ("interrupted", 130, "clholo info: interrupted; nothing written\n"),
])
def test_signals_at_the_end_keep_the_exit_code_and_the_one_line(tmp_path, case, code, err):
    # a SIGTERM after the work (outputs complete) while Python shut down killed the process as
    # 143; an interrupt inside a library's constructor added "Exception ignored in ..." and a
    # traceback after the one line
    p = subprocess.run([sys.executable, "-c", CHILD], capture_output=True, text=True,
                       cwd=tmp_path, env=dict(os.environ, CASE=case), timeout=120)
    assert (p.returncode, p.stderr) == (code, err), p.stderr


# --- RGB-D pairs -----------------------------------------------------------------------------

@pytest.fixture
def rgbd_files(tmp_path, rng, monkeypatch):
    from clholo.io.images import write_image

    monkeypatch.chdir(tmp_path)
    write_image(tmp_path / "img.png", rng.uniform(0, 1, (8, 12, 3)).astype(np.float32),
                dtype="uint8")
    write_image(tmp_path / "depth.exr", rng.uniform(1, 3, (8, 12, 1)).astype(np.float32),
                dtype="float")
    write_image(tmp_path / "zero.exr", np.zeros((8, 12, 1), np.float32), dtype="float")
    return tmp_path


@pytest.mark.parametrize("inputs, line", [
    (["depth.exr", "img.png"],
     "depth.exr has 1 channel and img.png has 3: they look swapped; give the colour image "
     "first, then its depth map"),
    (["img.png", "./img.png"],
     "img.png is given as both the image and its depth map but has no depth channel (named Z "
     "or depth): give the image, then its depth map"),
    (["img.png", "zero.exr"],
     "zero.exr: depth has no valid pixel: every value is NaN, inf (or >= 1e10: no surface), "
     "negative or 0 (range "
     "0..0); is it the depth map, in its own units?"),
])
def test_rgbd_pairs_a_user_would_question(rgbd_files, capsys, inputs, line):
    # the swapped pair rendered the depth map clipped to white as the picture, the same file
    # twice rendered the image as its own depths, and a map of zeros had "no valid pixel to
    # fill from" without its file
    _refused(["render", *inputs, "--near", "0.002", "--far", "0.006", "--frames", "1", "--out",
              "r"], capsys, rgbd_files, "clholo render: error: " + line)


# --- lookup tables ---------------------------------------------------------------------------

@pytest.mark.parametrize("name, text, line", [
    ("empty.csv", "\n\n",
     "empty.csv is empty: give 256 phases in radians, one per line (or one column per colour)"),
    ("semi.csv", ";".join(f"{v:.6f}" for v in np.linspace(0, 6.2, 256)) + "\n",
     "semi.csv: no comma-separated numbers after its first line ('0.000000;0.024314;0.048627;0."
     "072941;0.09"
     "'...): give 256 phases in radians, one per line, with commas between columns"),
    ("linear:0", None,
     "lookup table 'linear:0': N is the gray level that gives 2 pi, an integer in 2..256, got "
     "0; e.g. linear:255"),
])
def test_lookup_tables_a_user_would_question(tmp_path, rng, capsys, monkeypatch, name, text,
                                             line):
    # an empty file and a ';' file were "got shape (0,)" after NumPy's own warning line;
    # linear:0 was "gray_2pi (the gray level that gives 2 pi) must be ..." (a Python name)
    monkeypatch.chdir(tmp_path)
    _good_npz(tmp_path, rng)
    if text is not None:
        (tmp_path / name).write_text(text)
    rc, err = _run(["encode", "good.npz", "--method", "dpac", "--lut", name, "--out", "o"],
                   capsys)
    assert (rc, err) == (2, ["clholo encode: error: " + line])
    assert not (tmp_path / "o").exists()


def test_overwrite_keeps_an_edit_when_the_checksums_were_garbled(tmp_path, capsys,
                                                                 monkeypatch):
    from clholo.io.output import output_folder

    monkeypatch.chdir(tmp_path)
    with output_folder(tmp_path / "run", command="render") as tmp:
        (tmp / "summary.json").write_text("{}\n")
    manifest = tmp_path / "run" / "clholo-output.json"
    data = json.loads(manifest.read_text())
    manifest.write_text(json.dumps(dict(data, sha256=[1])))
    with open(tmp_path / "run" / "summary.json", "a") as f:
        f.write("my note\n")
    # a "sha256" that is not a table of checksums counted as "written before checksums":
    # --overwrite replaced the folder and the note was gone, exit 0
    _refused(["demo", "--out", "run", "--overwrite"], capsys, tmp_path,
             f"clholo demo: error: --out {tmp_path / 'run'} holds summary.json, which changed "
             f"since clholo wrote it: --overwrite would replace it, so clholo will not; move it "
             f"out first, or choose another --out")
    assert (tmp_path / "run" / "summary.json").read_text() == "{}\nmy note\n"


def test_display_names_the_bench_file_for_a_colour_mismatch(tmp_path, rng, capsys,
                                                            monkeypatch):
    from test_capture import BENCH

    monkeypatch.chdir(tmp_path)
    _mpi_folder(tmp_path / "scene", rng)
    (tmp_path / "two.toml").write_text(
        BENCH.replace('luts = ["red.lut", "green.lut"]\n', "")
        .replace('phase_luts = ["linear:230", "measured_green.csv"]\n', ""))
    # it said "--wavelengths gives 2", an option display does not have
    _refused(["display", "scene", "--memory", "--config", "two.toml", "--seconds", "0.2"],
             capsys, tmp_path, "clholo display: error: the scene has 3 colour channel(s) but "
                               "[slm] wavelengths_m of two.toml gives 2: give 3")


def test_encode_warns_when_the_slm_cuts_the_hologram(tmp_path, rng, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    _good_npz(tmp_path, rng)
    # 8 x 8 hologram on a 4 x 6 SLM: its edges were cut off without a word
    rc, err = _run(["encode", "good.npz", "--method", "dpac", "--slm-size", "4", "6", "--out",
                    "o", "--progress", "off"], capsys)
    assert rc == 0
    assert err == ["clholo encode: warning: --slm-size 4 6 is smaller than the hologram "
                   "(8 x 8): the patterns keep its centre 4 x 6, the rest is cut off"]
    assert (tmp_path / "o" / "frame000_R.png").is_file()


# --- CLHOLO_DEVICE by the type clholo info shows ------------------------------------------------

def test_a_device_type_selects_a_device_of_that_type(monkeypatch, capsys):
    from clholo.host import runtime

    # "[CPU]" in the list, and CLHOLO_DEVICE=cpu "matches no OpenCL device"
    devices = runtime.list_devices()
    for kind in {d.device_type for d in devices if "+" not in d.device_type}:
        dev = runtime.choose_device(kind.lower())
        assert runtime._type_name(dev) == kind
    monkeypatch.setenv("CLHOLO_DEVICE", devices[0].device_type.split("+")[0].lower())
    rc, err = _run(["info"], capsys)
    assert rc == 0 and err == []


# --- report --------------------------------------------------------------------------------------

@pytest.mark.parametrize("name", ["results.csv", "results.md", "summary.json"])
def test_report_names_a_file_that_is_not_text(tmp_path, capsys, monkeypatch, name):
    from clholo.io.output import output_folder

    monkeypatch.chdir(tmp_path)
    with output_folder(tmp_path / "run", command="experiment layers") as tmp:
        (tmp / name).write_bytes(b"ok,\xd0\x00\xff")
    # "'utf-8' codec can't decode byte 0xd0 in position 3: invalid continuation byte"
    _refused(["report", "run", "--out", "r.html"], capsys, tmp_path,
             f"clholo report: error: run/{name} is not a text file (byte 3 is 0xd0, not UTF-8): "
             f"move it out of the folder, or write it again")


def test_a_bench_file_focusing_one_depth_at_two_positions_is_refused(tmp_path, rng, capsys,
                                                                     monkeypatch):
    from test_capture import BENCH

    monkeypatch.chdir(tmp_path)
    (tmp_path / "b.toml").write_text(
        BENCH.replace('luts = ["red.lut", "green.lut"]\n', "")
        .replace('phase_luts = ["linear:230", "measured_green.csv"]\n', "")
        .replace("depths_m = [0.002, 0.004, 0.006]", "depths_m = [0.002, 0.002, 0.006]"))
    np.save(tmp_path / "seq.npy", rng.integers(0, 256, (1, 2, 8, 12), dtype=np.uint8))
    # the sweep ran and labelled the images of 2 mm and 4.5 mm both "focused at 2 mm"
    _refused(["capture", "focal-sweep", "--config", "b.toml", "--patterns", "seq.npy", "--out",
              "stack", "--simulate"], capsys, tmp_path,
             "clholo capture focal-sweep: error: b.toml: [focal_sweep] depths_m gives 0.002 m "
             "for two stage positions (2 and 4.5 mm): each position focuses one depth; fix "
             "depths_m (or repeat the position itself)")


def test_values_separated_by_commas_are_told_to_use_spaces(tmp_path, capsys):
    # "expected a number, got '638e-9,520e-9,450e-9'" (a batch cell takes commas, the command
    # line does not)
    _refused(["render", "scene", "--wavelengths", "638e-9,520e-9,450e-9"], capsys, tmp_path,
             "clholo render: error: argument --wavelengths: expected a number, got "
             "'638e-9,520e-9,450e-9': separate several values with spaces, not commas (a "
             "decimal comma is written as a point)")
