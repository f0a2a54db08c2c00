"""``clholo encode`` as a user runs it: outputs, LUT errors, the folder written atomically."""

import json

import numpy as np

import clholo
from clholo import cli
from clholo.encode import read_pattern_pngs

from conftest import random_complex


def _hologram(tmp_path, rng, C=2):
    field = random_complex(rng, (2, C, 16, 24))
    path = tmp_path / "holo.npz"
    clholo.io.write_hologram(path, field, pitch=8e-6, wavelengths=[638e-9, 520e-9][:C])
    return path


def test_encode_sgd_and_dpac(tmp_path, rng, capsys):
    holo = _hologram(tmp_path, rng)
    for method in ("sgd", "dpac"):
        out = tmp_path / method
        rc = cli.main(["encode", str(holo), "--method", method, "--z-slm", "0.002",
                       "--iterations", "5", "--slm-size", "20", "22", "--lut", "linear",
                       "linear:200", "--out", str(out)])
        assert rc == 0, capsys.readouterr().err
        assert method.upper() in capsys.readouterr().out
        gray = read_pattern_pngs(out)
        assert gray.shape == (2, 2, 20, 22) and gray.dtype == np.uint8
        assert gray[:, 1].max() < 200 and gray[:, 0].max() < 255  # usable levels only
        assert gray[:, :, 2:18, :].std() > 0
        info = json.loads((out / "patterns.json").read_text())
        assert info["extra"]["method"] == method
    # an existing folder is kept unless --overwrite
    assert cli.main(["encode", str(holo), "--method", "dpac", "--out", str(tmp_path / "dpac")]) == 2
    assert "already holds an earlier clholo output" in capsys.readouterr().err
    assert cli.main(["encode", str(holo), "--method", "dpac", "--overwrite", "--slm-size", "8",
                     "8", "--out", str(tmp_path / "dpac")]) == 0
    assert read_pattern_pngs(tmp_path / "dpac").shape == (2, 2, 8, 8)
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]


def test_encode_refuses_bad_luts(tmp_path, rng, capsys):
    holo = _hologram(tmp_path, rng)
    bad = np.linspace(0, 7, 256)
    bad[40] = bad[38]
    np.savetxt(tmp_path / "bad.csv", bad)
    out = tmp_path / "out"
    assert cli.main(["encode", str(holo), "--lut", str(tmp_path / "bad.csv"), "--out",
                     str(out)]) == 2
    err = capsys.readouterr().err
    assert "not monotone" in err and "gray 40" in err
    np.savetxt(tmp_path / "nan.csv", np.r_[np.linspace(0, 7, 255), np.nan])
    assert cli.main(["encode", str(holo), "--lut", str(tmp_path / "nan.csv"), "--out",
                     str(out)]) == 2
    assert "gray level 255" in capsys.readouterr().err
    np.savetxt(tmp_path / "short.csv", np.linspace(0, 7, 100))
    assert cli.main(["encode", str(holo), "--lut", str(tmp_path / "short.csv"), "--out",
                     str(out)]) == 2
    assert "256" in capsys.readouterr().err
    assert cli.main(["encode", str(holo), "--lut", "linear", "linear", "linear", "--out",
                     str(out)]) == 2
    assert "one per colour" in capsys.readouterr().err
    assert not out.exists()
