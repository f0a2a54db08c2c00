"""Command-line mistakes found by an audit (2026-11-29): each message now names the file,
the option or the cause it was missing."""

import zipfile

import numpy as np
import pytest

import clholo
from clholo import cli


def _hologram(tmp_path, C=1):
    rng = np.random.default_rng(0)
    field = (rng.standard_normal((1, C, 16, 24))
             + 1j * rng.standard_normal((1, C, 16, 24))).astype(np.complex64)
    path = tmp_path / "holo.npz"
    clholo.io.write_hologram(path, field, pitch=8e-6, wavelengths=[520e-9][:C])
    return path


def test_a_pickled_lut_names_the_file(tmp_path, capsys):
    """``--lut obj.npy`` said only NumPy's "Object arrays cannot be loaded when
    allow_pickle=False"."""
    np.save(tmp_path / "obj.npy", np.array([{"a": 1}], dtype=object), allow_pickle=True)
    assert cli.main(["encode", str(_hologram(tmp_path)), "--lut", str(tmp_path / "obj.npy"),
                     "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert f"lookup table {tmp_path / 'obj.npy'} is not a NumPy array of numbers" in err
    assert "numpy.save" in err and err.count("\n") == 1 and not (tmp_path / "o").exists()


def test_a_lut_with_a_blank_line_says_where(tmp_path, capsys):
    """NumPy skips blank lines: the table read as 255 rows, and the message said only that."""
    lines = [f"{v:.6f}" for v in np.linspace(0, 7, 256)]
    lines[56] = ""
    (tmp_path / "gap.csv").write_text("\n".join(lines) + "\n")
    assert cli.main(["encode", str(_hologram(tmp_path)), "--lut", str(tmp_path / "gap.csv"),
                     "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert "holds 255 rows, not 256: line(s) 57 are blank (a phase left out?)" in err
    # a blank line where every phase is there is no mistake
    lines = [f"{v:.6f}" for v in np.linspace(0, 7, 256)]
    lines.insert(56, "")
    (tmp_path / "spaced.csv").write_text("\n".join(lines) + "\n")
    from clholo.encode.quantize import read_luts

    (lut,) = read_luts(tmp_path / "spaced.csv")
    np.testing.assert_allclose(lut.phases, np.linspace(0, 7, 256), atol=1e-6)


def test_demo_layers_range_is_the_one_it_takes(capsys):
    """``demo --layers 0`` said ">= 1", then ``--layers 1`` was refused "from 2 to 256"."""
    with pytest.raises(SystemExit):
        cli.build_parser().parse_args(["demo", "--layers", "1"])
    assert "--layers" in capsys.readouterr().err
    assert cli.build_parser().parse_args(["demo", "--layers", "2"]).layers == 2


def test_stereo_mag_depth_range_names_its_options():
    from clholo.io.stereo_mag import stereo_mag_depths

    with pytest.raises(ValueError, match=r"min_depth must be > 0 and smaller than max_depth "
                                         r"\(--min-depth, --max-depth.*got 5 and 2"):
        stereo_mag_depths(4, min_depth=5, max_depth=2)


def test_hologram_metadata_that_is_not_json_names_the_file_once(tmp_path):
    path = _hologram(tmp_path)
    with zipfile.ZipFile(path) as z:
        arrays = {n: z.read(n) for n in z.namelist()}
    np.save(tmp_path / "m.npy", np.asarray("{not json"))
    arrays["metadata.npy"] = (tmp_path / "m.npy").read_bytes()
    bad = tmp_path / "bad.npz"
    with zipfile.ZipFile(bad, "w") as z:
        for name, data in arrays.items():
            z.writestr(name, data)
    with pytest.raises(ValueError) as info:
        clholo.io.read_hologram(bad)
    message = str(info.value)
    assert message.startswith(f"{bad} is not a clholo hologram .npz: its metadata array is "
                              f"not valid JSON")
    assert message.count(str(bad)) == 1


def test_report_says_which_listed_file_is_gone(tmp_path, capsys):
    """A render folder whose focal_stack.npz was deleted gave a page without its focal stack
    and exit 0, without a word."""
    from clholo.io.output import output_folder

    rng = np.random.default_rng(1)
    run = tmp_path / "run"
    with output_folder(run, command="render") as tmp:
        np.savez(tmp / "focal_stack.npz", intensity=rng.random((2, 3, 8, 8)))
        (tmp / "summary.json").write_text('{"frames": 1}')
    (run / "focal_stack.npz").unlink()
    assert cli.main(["report", str(run), "--out", str(tmp_path / "r.html")]) == 0
    err = capsys.readouterr().err
    assert f"{run / 'focal_stack.npz'} is listed in run's clholo-output.json but is gone" in err
    assert (tmp_path / "r.html").is_file()


def test_report_of_a_complete_folder_says_nothing_is_gone(tmp_path):
    import warnings

    from clholo.experiments.report import build_report
    from clholo.io.output import output_folder

    run = tmp_path / "run"
    with output_folder(run, command="render") as tmp:
        (tmp / "summary.json").write_text('{"frames": 1}')
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        build_report(run, out=tmp_path / "r.html")


def test_a_tuning_file_under_an_unknown_home_is_named(monkeypatch, capsys):
    """``CLHOLO_TUNING_FILE='~nouser/x.json'`` ended every command in an internal error (exit
    70): Path.expanduser's RuntimeError."""
    monkeypatch.setenv("CLHOLO_TUNING_FILE", "~clholo-no-such-user/x.json")
    assert cli.main(["info"]) == 2
    err = capsys.readouterr().err
    assert "CLHOLO_TUNING_FILE='~clholo-no-such-user/x.json': its '~' names no home" in err
    assert err.count("\n") == 1


def test_a_bad_bench_peer_rule_is_bad_input(monkeypatch):
    """It was ``SystemExit(text)``: exit 1 ("a check failed") without clholo's error form."""
    from clholo import bench
    from clholo.errors import InputError

    monkeypatch.setenv(bench.PEER_ENV, "bogus")
    with pytest.raises(InputError, match="CLHOLO_BENCH_PEER='bogus': give 'required', 'any'"):
        bench._peer_rule()


def test_device_selectors_of_odd_digits_and_blanks(monkeypatch):
    """``CLHOLO_DEVICE='²'``: "invalid literal for int()" (str.isdigit takes it); a blank
    value matched every device name and overrode PYOPENCL_CTX."""
    from clholo.host import runtime

    monkeypatch.setenv("CLHOLO_DEVICE", "²")
    with pytest.raises(runtime.NoDeviceError, match="CLHOLO_DEVICE='²' matches no OpenCL "
                                                    "device"):
        runtime.choose_device()
    monkeypatch.setenv("CLHOLO_DEVICE", "  ")
    monkeypatch.setenv("PYOPENCL_CTX", "no-such-device-name")
    with pytest.raises(runtime.NoDeviceError, match="PYOPENCL_CTX='no-such-device-name'"):
        runtime.choose_device()


def test_tune_show_of_a_missing_file_says_it_is_missing(tmp_path, capsys):
    """A mistyped ``--file`` read as "nothing for this device", exit 0."""
    assert cli.main(["tune", "--show", "--file", str(tmp_path / "nope.json")]) == 0
    out = capsys.readouterr().out
    assert f"stored: nothing: {tmp_path / 'nope.json'} does not exist" in out
