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
        only = ["--iterations", "5"] if method == "sgd" else ["--cutoff", "0.4"]
        rc = cli.main(["encode", str(holo), "--method", method, "--z-slm", "0.002", *only,
                       "--slm-size", "20", "22", "--lut", "linear", "linear:200", "--out",
                       str(out)])
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


# --- issue 17: an option acts or is refused; --pad checked like render's; progress -------------

import pytest  # noqa: E402


@pytest.mark.parametrize("method, extra, named", [
    ("sgd", ["--amax", "2"], "--amax"),
    ("sgd", ["--cutoff", "0.3"], "--cutoff"),
    ("sgd", ["--cutoff", "0.3", "--amax", "2"], "--cutoff, --amax"),
    ("dpac", ["--iterations", "5"], "--iterations"),
    ("dpac", ["--lr", "0.1"], "--lr"),
    ("dpac", ["--init", "random"], "--init"),
    ("dpac", ["--tol", "0.01"], "--tol"),
    ("dpac", ["--check-every", "2"], "--check-every"),
    ("dpac", ["--seed", "3"], "--seed"),
])
def test_encode_refuses_the_other_methods_options(tmp_path, rng, capsys, method, extra, named):
    holo = _hologram(tmp_path, rng)
    out = tmp_path / "out"
    assert cli.main(["encode", str(holo), "--method", method, *extra, "--out", str(out)]) == 2
    err = capsys.readouterr().err
    other = "dpac" if method == "sgd" else "sgd"
    assert f"{named} appl" in err and f"--method {other} only" in err, err
    assert err.count("\n") == 1 and not out.exists()


def test_encode_refuses_seed_without_random_init(tmp_path, rng, capsys):
    holo = _hologram(tmp_path, rng)
    out = tmp_path / "out"
    assert cli.main(["encode", str(holo), "--seed", "4", "--out", str(out)]) == 2
    assert "--seed seeds the random initial phase of --init random only" in \
        capsys.readouterr().err
    assert not out.exists()
    assert cli.main(["encode", str(holo), "--seed", "4", "--init", "random", "--iterations", "2",
                     "--slm-size", "8", "8", "--out", str(out)]) == 0
    info = json.loads((out / "patterns.json").read_text())["extra"]
    assert info["seed"] == 4 and info["init"] == "random" and info["max_iterations"] == 2


@pytest.mark.parametrize("pad", ["0.5", "0", "-1", "nan", "inf", "two"])
def test_encode_pad_checked_like_render(tmp_path, rng, capsys, pad):
    holo = _hologram(tmp_path, rng)
    out = tmp_path / "out"
    for command in (["encode", str(holo)], ["render", str(holo)]):
        with pytest.raises(SystemExit) as exc:
            cli.main([*command, "--pad", pad, "--out", str(out)])
        assert exc.value.code == 2
        err = capsys.readouterr().err
        assert f"argument --pad: must be 'auto' or a factor >= 1 such as 2, got '{pad}'" in err
    assert not out.exists()


def test_encode_shows_progress_off_a_terminal(tmp_path, rng, capsys):
    holo = _hologram(tmp_path, rng)
    out = tmp_path / "out"
    # capsys is not a terminal: 'auto' gives plain lines, the last one always
    assert cli.main(["encode", str(holo), "--iterations", "4", "--check-every", "2",
                     "--slm-size", "8", "8", "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "\r" not in text
    assert "sgd iterations: 4/4 after" in text, text
    assert cli.main(["encode", str(holo), "--iterations", "4", "--slm-size", "8", "8",
                     "--progress", "off", "--overwrite", "--out", str(out)]) == 0
    assert "sgd iterations" not in capsys.readouterr().out


def test_sgd_progress_callback_ends_where_sgd_stopped(rng):
    """Issue 26: the bar ends where SGD stopped (the total shrinks by the steps a batch did
    not run), not at the planned 2 x 40."""
    from clholo.encode import sgd_encode

    field = random_complex(rng, (3, 1, 16, 16))
    optics = clholo.Optics(wavelengths=(520e-9,))
    seen = []
    res = sgd_encode(field, optics, z_slm=0.002, iterations=40, check_every=2, tol=0.5,
                     frames_per_batch=2, progress=lambda done, total: seen.append((done, total)))
    assert res.iterations < 40  # the tolerance stopped it
    assert len(res.batch_iterations) == 2 and max(res.batch_iterations) == res.iterations
    ran = sum(res.batch_iterations)
    assert seen[0] == (0, 80) and seen[-1] == (ran, ran) and ran < 80
    assert all(b[0] >= a[0] and b[1] <= a[1] for a, b in zip(seen, seen[1:]))
    assert all(done <= total for done, total in seen)
    assert res.stop_reason().startswith("tolerance 0.5 reached at ")
    # tol 0: every iteration, the bar at its planned total
    seen.clear()
    res = sgd_encode(field, optics, z_slm=0.002, iterations=6, check_every=2, tol=0.0,
                     frames_per_batch=2, progress=lambda done, total: seen.append((done, total)))
    assert res.batch_iterations == (6, 6) and seen[-1] == (12, 12)
    assert res.stop_reason() == "tol 0: no early stop"


def test_encode_refuses_an_slm_size_beyond_any_slm_before_work(tmp_path, rng, capsys):
    holo = _hologram(tmp_path, rng)
    out = tmp_path / "out"
    with pytest.raises(SystemExit) as exc:
        cli.main(["encode", str(holo), "--slm-size", "100000", "100000", "--out", str(out)])
    assert exc.value.code == 2
    assert "argument --slm-size: must be <= 16384, got 100000" in capsys.readouterr().err
    assert not out.exists()


# --- issue 26, section 5: a hologram file means what it says -------------------------------------

def _edited(path, **arrays):
    """A copy of the hologram .npz ``path`` with some of its arrays replaced (as a user's script
    or another tool would edit it)."""
    with np.load(path, allow_pickle=False) as z:
        data = {k: z[k] for k in z.files}
    data.update({k: np.asarray(v) for k, v in arrays.items()})
    out = path.with_name("edited.npz")
    with open(out, "wb") as f:
        np.savez(f, **data)
    return out


def _meta_with(path, **keys):
    with np.load(path, allow_pickle=False) as z:
        meta = json.loads(str(z["metadata"]))
    meta.update(keys)
    return json.dumps(meta)


@pytest.mark.parametrize("what, edit, line", [
    ("pitch array edited to 4 um", lambda p: {"pitch": np.float64(4e-6)},
     "edited.npz: its pitch array says 4e-06 m but its metadata says 8e-06 m: the file was "
     "edited or is inconsistent; write it again with clholo.io.write_hologram"),
    ("pitch array as text", lambda p: {"pitch": "abc"},
     "edited.npz: pitch must be a real number, got 'abc'"),
    ("pitch array not finite", lambda p: {"pitch": np.float64(np.nan)},
     "edited.npz: pitch must be finite, got nan"),
    ("wavelengths array in nanometres", lambda p: {"wavelengths": np.array([638.0, 520.0])},
     "edited.npz: wavelengths=638.0 is not a wavelength in metres: give it in metres, e.g. "
     "520e-9 for green (638 nm is 6.38e-07 m)"),
    ("wavelengths array, one too many", lambda p: {"wavelengths": np.array([638e-9, 520e-9,
                                                                             450e-9])},
     "edited.npz: wavelengths has 3 value(s) but the field has 2 colour channel(s): give one "
     "wavelength per colour"),
    ("wavelengths array edited", lambda p: {"wavelengths": np.array([638e-9, 532e-9])},
     "edited.npz: its wavelengths array says [6.38e-07, 5.32e-07] m but its metadata says "
     "[6.38e-07, 5.2e-07] m: the file was edited or is inconsistent; write it again with "
     "clholo.io.write_hologram"),
    ("metadata wavelengths in nanometres",
     lambda p: {"metadata": _meta_with(p, wavelengths=[638, 520])},
     "edited.npz: metadata wavelengths=638 is not a wavelength in metres: give it in metres, "
     "e.g. 520e-9 for green (638 nm is 6.38e-07 m)"),
    ("metadata pitch in micrometres", lambda p: {"metadata": _meta_with(p, pitch=8)},
     "edited.npz: metadata pitch=8 m is larger than a millimetre: give it in metres (8e-6 for "
     "8 um)"),
    ("a real float32 field",
     lambda p: {"field": np.ones((2, 2, 16, 24), np.float32)},
     "edited.npz: its field is float32, not complex: a hologram is a complex field (amplitude "
     "and phase); store field.astype(np.complex64) (clholo.io.write_hologram refuses a real "
     "field)"),
    ("an integer field",
     lambda p: {"field": np.ones((2, 2, 16, 24), np.int16)},
     "edited.npz: its field is int16, not complex"),
    ("a field of rank 3",
     lambda p: {"field": np.ones((3, 16, 16), np.complex64)},
     "edited.npz: holograms must have shape [T, C, H, W], got (3, 16, 16)"),
])
@pytest.mark.parametrize("method", ["dpac", "sgd"])
def test_encode_refuses_a_hologram_file_that_disagrees_with_itself(tmp_path, rng, capsys, what,
                                                                    edit, line, method):
    holo = _hologram(tmp_path, rng)
    edited = _edited(holo, **edit(holo))
    before = sorted(p.name for p in tmp_path.iterdir())
    data = edited.read_bytes()
    out = tmp_path / "out"
    rc = cli.main(["encode", str(edited), "--method", method, "--slm-size", "8", "8",
                   "--out", str(out)])
    err = capsys.readouterr().err
    assert rc == 2, err
    assert err.count("\n") == 1, err
    assert err.startswith(f"clholo encode: error: {tmp_path / line}"), err
    assert sorted(p.name for p in tmp_path.iterdir()) == before and not out.exists()
    assert edited.read_bytes() == data


def test_encode_reads_the_pitch_it_encodes_with(tmp_path, rng, capsys):
    """The same field written at 4 um and at 8 um gives different DPAC patterns: the pitch of
    the file is the one used (the arrays and the metadata agree)."""
    field = random_complex(rng, (1, 1, 16, 24))
    grays = []
    for pitch in (8e-6, 4e-6):
        path = tmp_path / f"h{pitch:g}.npz"
        clholo.io.write_hologram(path, field, pitch=pitch, wavelengths=[520e-9])
        out = tmp_path / f"o{pitch:g}"
        assert cli.main(["encode", str(path), "--method", "dpac", "--z-slm", "0.002",
                         "--slm-size", "16", "24", "--out", str(out)]) == 0, \
            capsys.readouterr().err
        grays.append(read_pattern_pngs(out))
    assert not np.array_equal(grays[0], grays[1])


# --- issue 26, section 7: the bar ends where SGD stopped, the summary says why; --tol 0 ---------

def test_encode_sgd_says_where_and_why_it_stopped(tmp_path, rng, capsys):
    holo = _hologram(tmp_path, rng)
    out = tmp_path / "out"
    assert cli.main(["encode", str(holo), "--iterations", "200", "--check-every", "2",
                     "--tol", "0.5", "--slm-size", "8", "8", "--progress", "lines",
                     "--out", str(out)]) == 0
    text = capsys.readouterr().out
    info = json.loads((out / "patterns.json").read_text())["extra"]
    n = info["iterations"]
    assert n < 200 and info["stopped"] == f"tolerance 0.5 reached at {n}"
    bar = [ln for ln in text.splitlines() if "sgd iterations:" in ln]
    assert bar[-1].strip().startswith(f"sgd iterations: {n}/{n} after"), text
    # never a bar that claims the planned 200 done; a line printed while it ran (its first
    # steps are slow where kernels are built: 2 s each on an H200) shows the plan of then
    assert "200/200" not in text
    for line in bar[:-1]:
        done = int(line.split("sgd iterations:")[1].split("/")[0])
        assert done < n, line
    assert f"SGD {n}/200 iterations (tolerance 0.5 reached at {n}), mean loss" in text


def test_encode_tol_0_means_no_early_stop(tmp_path, rng, capsys):
    """sgd_encode(tol=0.0) runs every iteration; the command line says the same with --tol 0
    (it was refused, 'must be > 0', leaving no way to switch early stopping off)."""
    holo = _hologram(tmp_path, rng)
    out = tmp_path / "out"
    assert cli.main(["encode", str(holo), "--iterations", "6", "--check-every", "2",
                     "--tol", "0", "--slm-size", "8", "8", "--out", str(out)]) == 0
    text = capsys.readouterr().out
    info = json.loads((out / "patterns.json").read_text())["extra"]
    assert info["tol"] == 0.0 and info["iterations"] == 6
    assert "SGD 6/6 iterations (tol 0: no early stop)" in text
    for bad in ("-1", "nan", "inf", "x"):
        with pytest.raises(SystemExit) as exc:
            cli.main(["encode", str(holo), "--tol", bad, "--out", str(tmp_path / "o2")])
        assert exc.value.code == 2
        assert "argument --tol: " in capsys.readouterr().err
    assert not (tmp_path / "o2").exists()


def test_encode_refuses_a_hologram_without_light_but_codes_a_dark_colour(tmp_path, rng, capsys):
    """A file of zeros has nothing to code (DPAC would write flat patterns, SGD has no scale):
    refused, naming the file, for either method and before any output; one dark colour of a
    hologram (a red scene has no green light) is coded."""
    dark = tmp_path / "dark.npz"
    clholo.io.write_hologram(dark, np.zeros((1, 2, 16, 24), np.complex64), pitch=8e-6,
                             wavelengths=[638e-9, 520e-9])
    for method in ("dpac", "sgd"):
        out = tmp_path / f"out-{method}"
        assert cli.main(["encode", str(dark), "--method", method, "--out", str(out)]) == 2
        err = capsys.readouterr().err
        assert f"{dark} holds no light" in err and "render the scene again" in err
        assert not out.exists()
    field = random_complex(rng, (1, 2, 16, 24))
    field[:, 1] = 0
    red = tmp_path / "red.npz"
    clholo.io.write_hologram(red, field, pitch=8e-6, wavelengths=[638e-9, 520e-9])
    assert cli.main(["encode", str(red), "--method", "dpac", "--z-slm", "0.002", "--out",
                     str(tmp_path / "red")]) == 0, capsys.readouterr().err
    gray = read_pattern_pngs(tmp_path / "red")
    assert gray[:, 0].std() > 0
