"""Scores that mean what they say (issue 18 section 4): one least-squares scale per colour."""

import numpy as np
import pytest

from clholo import metrics


def _reference(rng, shape=(40, 48, 3)):
    from scipy.ndimage import gaussian_filter

    img = gaussian_filter(rng.random(shape), (2, 2, 0))
    return (img - img.min()) / (img.max() - img.min()) + 0.05


@pytest.mark.parametrize("layout", ["hwc", "chw"])
def test_per_channel_recovers_a_different_gain_per_colour(rng, layout):
    """An image whose colours came through gains g_c (the pupil's 1/lambda^2, a phase-only
    encoding's colour shift): per colour the fitted scales are exactly 1 / g_c and the image
    scores as identical; one scale for all colours cannot fit and scores clearly worse."""
    ref = _reference(rng)
    gains = np.array([1 / 1.50, 1 / 0.85, 1 / 0.54])
    img = ref * gains
    if layout == "chw":
        ref, img = np.moveaxis(ref, -1, 0), np.moveaxis(img, -1, 0)
    per = metrics.score(img, ref, fit_scale="per_channel", layout=layout)
    assert isinstance(per["scale"], list) and len(per["scale"]) == 3
    np.testing.assert_allclose(per["scale"], 1 / gains, rtol=1e-12)
    assert per["psnr"] > 100 and per["ssim"] == pytest.approx(1.0, abs=1e-9)
    assert per["flip"] == pytest.approx(0.0, abs=1e-4)
    one = metrics.score(img, ref, fit_scale=True, layout=layout)
    assert isinstance(one["scale"], float)
    assert one["psnr"] < 30 and one["flip"] > 0.01
    # the one scale is the least-squares compromise: between the smallest and largest gain
    assert min(1 / gains) < one["scale"] < max(1 / gains)
    none = metrics.score(img, ref, fit_scale=False, layout=layout)
    assert none["scale"] == 1.0 and none["psnr"] < per["psnr"]


def test_per_channel_with_noise_matches_the_least_squares_formula(rng):
    ref = _reference(rng)
    img = np.clip(ref * [0.3, 1.0, 2.2] + 0.02 * rng.standard_normal(ref.shape), 0, None)
    got = metrics.score(img, ref, fit_scale="per_channel", metrics=("psnr",))["scale"]
    want = [np.sum(img[..., c] * ref[..., c]) / np.sum(img[..., c] ** 2) for c in range(3)]
    np.testing.assert_allclose(got, want, rtol=1e-12)


def test_per_channel_on_grey_images(rng):
    ref = _reference(rng)[..., 0]
    got = metrics.score(ref / 4, ref, fit_scale="per_channel")
    assert got["scale"] == pytest.approx([4.0], rel=1e-12)


@pytest.mark.parametrize("bad", ["per-channel", "per_colour", "", None, 1, 0, 2.0, "True"])
def test_fit_scale_refuses_anything_else(rng, bad):
    ref = _reference(rng)
    with pytest.raises(ValueError, match="fit_scale") as err:
        metrics.score(ref, ref, fit_scale=bad)
    assert "per_channel" in str(err.value) and "True" in str(err.value)


def test_per_channel_refuses_a_dark_colour(rng):
    ref = _reference(rng)
    img = ref.copy()
    img[..., 2] = 0
    with pytest.raises(ValueError, match="colour 2"):
        metrics.score(img, ref, fit_scale="per_channel")


# --- SGD: every field's fitted scale and the colour balance -------------------------------------

def test_sgd_scale_and_colour_balance_restore_known_gains(queue, rng):
    """Targets that a phase-only SLM reaches exactly, each colour g_c times brighter than a unit
    plane wave makes it (per frame and colour, with a phase): the fitted scales have modulus
    |g_tc|, and the laser power that restores the colours goes as mean_t |g_tc|^2 (normalised to
    the largest)."""
    from clholo import reference as ref
    from clholo.encode import sgd_encode
    from clholo.propagation import device_padded_shape
    from clholo.scene import Optics

    optics = Optics()
    T, C, H, W, z = 2, 3, 32, 32, 2e-3
    gains = np.array([[0.5, 1.0, 2.0], [0.7, 1.1, 1.6]]) * np.exp(1j * rng.uniform(0, 6, (T, C)))
    padded = device_padded_shape((H, W), z, wavelength=optics.wavelengths, pitch=optics.pitch)
    A, _ = ref.asm_operator((H, W), z, wavelengths=optics.wavelengths, pitch=optics.pitch,
                            padded=padded)
    # smooth phases: the back-propagated target is then almost exactly the SLM field
    from scipy.ndimage import gaussian_filter

    P = gaussian_filter(rng.uniform(0, 40, (T * C, H, W)), (0, 3, 3))
    target = (A(np.exp(1j * P)).reshape(T, C, H, W) * gains[..., None, None]).astype(np.complex64)
    power = np.mean(np.abs(gains) ** 2, axis=0)   # (0.37, 1.105, 3.28)
    for batch in (None, 1):
        res = sgd_encode(target, optics, z_slm=z, iterations=20, progress=False,
                         frames_per_batch=batch, queue=queue)
        assert res.scale.shape == (T, C) and res.scale.dtype == np.complex64
        assert np.all(res.loss < 1e-3)
        # a constant phase moves freely between P and s: only |s| is physical
        np.testing.assert_allclose(np.abs(res.scale), np.abs(gains), rtol=2e-2)
        np.testing.assert_allclose(res.colour_balance(), power / power.max(), rtol=4e-2)


def test_encode_cli_writes_and_prints_the_colour_balance(tmp_path, rng, capsys):
    import json

    import clholo
    from clholo import cli

    field = (rng.standard_normal((2, 2, 16, 24)) + 1j * rng.standard_normal((2, 2, 16, 24)))
    field[:, 0] *= 3.0   # red three times the amplitude: about nine times the power
    path = tmp_path / "holo.npz"
    clholo.io.write_hologram(path, field.astype(np.complex64), pitch=8e-6,
                             wavelengths=[638e-9, 520e-9])
    out = tmp_path / "sgd"
    assert cli.main(["encode", str(path), "--z-slm", "0.002", "--iterations", "5",
                     "--slm-size", "16", "24", "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "colour balance" in printed
    info = json.loads((out / "patterns.json").read_text())["extra"]
    balance = np.array(info["colour_balance"])
    assert balance.shape == (2,) and balance.max() == 1.0
    assert balance[0] == 1.0 and 0.05 < balance[1] < 0.25
    assert np.array(info["scale_abs"]).shape == (2, 2)
