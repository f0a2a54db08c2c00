"""What reaches the SLM, found by an audit of the patterns' physics (2026-11-29, seventh
session): pattern files named by channel index rather than by the laser they were computed
for, one measured lookup table silently taken for every wavelength, and the gray-0 border
around patterns smaller than the SLM, whose light the simulation leaves out."""

import json

import numpy as np
import pytest

from clholo import cli


def _hologram(tmp_path, wavelengths, shape=(16, 16)):
    from clholo.io import write_hologram

    rng = np.random.default_rng(0)
    path = tmp_path / "h.npz"
    write_hologram(path, np.exp(2j * np.pi * rng.random((1, len(wavelengths)) + shape))
                   .astype(np.complex64), pitch=8e-6, wavelengths=list(wavelengths))
    return path


def test_pattern_files_are_named_by_their_wavelength(tmp_path):
    """A hologram of (450, 520, 638) nm wrote its 450 nm pattern to frame000_R.png."""
    from clholo.encode.quantize import read_pattern_pngs, write_pattern_pngs

    holo = _hologram(tmp_path, (450e-9, 520e-9, 638e-9))
    out = tmp_path / "p"
    assert cli.main(["encode", str(holo), "--method", "dpac", "--progress", "off",
                     "--slm-size", "16", "16", "--out", str(out)]) == 0
    info = json.loads((out / "patterns.json").read_text())
    assert info["channels"] == ["B", "G", "R"]
    assert info["wavelengths_m"] == [450e-9, 520e-9, 638e-9]
    gray = read_pattern_pngs(out)  # in the hologram's channel order
    from clholo.io.images import read_image

    blue, _ = read_image(out / "frame000_B.png", normalise=False)
    assert np.array_equal(gray[0, 0], blue[..., 0])
    # two lasers of one band, or other counts: c0, c1, ...; none given: R, G, B by index
    levels = np.zeros((1, 3, 4, 4), np.uint8)
    write_pattern_pngs(levels, tmp_path / "q", wavelengths=[520e-9, 532e-9, 638e-9])
    assert json.loads((tmp_path / "q" / "patterns.json").read_text())["channels"] == \
        ["c0", "c1", "c2"]
    write_pattern_pngs(levels, tmp_path / "r")
    assert json.loads((tmp_path / "r" / "patterns.json").read_text())["channels"] == \
        ["R", "G", "B"]
    with pytest.raises(ValueError, match=r"^wavelengths has 2 entries but gray has 3"):
        write_pattern_pngs(levels, tmp_path / "s", wavelengths=[520e-9, 638e-9])


def test_one_measured_table_for_every_colour_warns(tmp_path, capsys):
    """--lut red.csv on an RGB hologram: green's and blue's phases off by up to 23 % and
    42 %, exit 0 and nothing on stderr."""
    holo = _hologram(tmp_path, (638e-9, 520e-9, 450e-9))
    table = tmp_path / "red.csv"
    table.write_text("\n".join(f"{2 * np.pi * g / 255:.9f}" for g in range(256)))
    args = ["encode", str(holo), "--method", "dpac", "--progress", "off", "--slm-size", "16",
            "16"]
    assert cli.main(args + ["--lut", str(table), "--out", str(tmp_path / "a")]) == 0
    assert "is one measured table for all 3 colours" in capsys.readouterr().err
    assert cli.main(args + ["--out", str(tmp_path / "b")]) == 0  # linear for all: a convention
    assert "measured table" not in capsys.readouterr().err
    assert cli.main(args + ["--lut"] + [str(table)] * 3 + ["--out", str(tmp_path / "c")]) == 0
    assert "measured table" not in capsys.readouterr().err


def test_patterns_smaller_than_the_slm_warn_of_its_border(tmp_path, capsys):
    """Gray 0 around the patterns is a flat mirror whose plane wave reaches the hologram plane
    (an error of 0.47 where 0.11 was simulated)."""
    holo = _hologram(tmp_path, (520e-9,))
    args = ["encode", str(holo), "--method", "dpac", "--progress", "off"]
    assert cli.main(args + ["--slm-size", "32", "32", "--out", str(tmp_path / "a")]) == 0
    assert "its border of gray 0 reflects a plane wave" in capsys.readouterr().err
    assert cli.main(args + ["--slm-size", "16", "16", "--out", str(tmp_path / "b")]) == 0
    assert "border" not in capsys.readouterr().err
