"""clholo.metrics.score: scale fit, the identity, and the ranking of known degradations."""

import builtins

import numpy as np
import pytest

from clholo import metrics


def _image(rng, shape=(48, 40, 3)):
    from scipy.ndimage import gaussian_filter

    img = gaussian_filter(rng.random(shape), (2, 2, 0))
    return (img - img.min()) / (img.max() - img.min())


def test_scale_is_recovered(rng):
    ref = _image(rng)
    s = float(rng.uniform(0.1, 10))
    got = metrics.score(ref / s, ref)
    assert got["scale"] == pytest.approx(s, rel=1e-9)
    assert got["psnr"] > 100  # exact up to rounding once rescaled
    assert got["ssim"] == pytest.approx(1.0, abs=1e-6)
    assert got["flip"] == pytest.approx(0.0, abs=1e-4)
    unfitted = metrics.score(ref / s, ref, fit_scale=False)
    assert unfitted["scale"] == 1.0 and unfitted["psnr"] < got["psnr"]


@pytest.mark.parametrize("layout", ["hwc", "chw", "gray"])
def test_identical_images(rng, layout):
    ref = _image(rng)
    if layout == "chw":
        ref = np.moveaxis(ref, -1, 0)
    elif layout == "gray":
        ref = ref[..., 0]
    got = metrics.score(ref.copy(), ref)
    assert got["psnr"] == np.inf
    assert got["ssim"] == pytest.approx(1.0)
    assert got["flip"] == 0.0


def test_known_degradations_rank_worse(rng):
    from scipy.ndimage import gaussian_filter

    ref = _image(rng)
    noise = rng.standard_normal(ref.shape)
    mild = np.clip(ref + 0.02 * noise, 0, None)
    strong = np.clip(ref + 0.2 * noise, 0, None)
    blurred = gaussian_filter(ref, (3, 3, 0))
    s_mild, s_strong = metrics.score(mild, ref), metrics.score(strong, ref)
    assert s_mild["psnr"] > s_strong["psnr"] + 10
    assert s_mild["ssim"] > s_strong["ssim"]
    assert s_mild["flip"] < s_strong["flip"]
    s_blur = metrics.score(blurred, ref)
    assert s_blur["ssim"] < 0.999 and s_blur["flip"] > 0.0 and s_blur["psnr"] < 60


def test_metric_selection_and_errors(rng, monkeypatch):
    ref = _image(rng)
    assert set(metrics.score(ref, ref, metrics=("psnr",))) == {"scale", "psnr"}
    with pytest.raises(ValueError, match="unknown metric"):
        metrics.score(ref, ref, metrics=("lpips",))
    with pytest.raises(ValueError, match="same shape"):
        metrics.score(ref[:-1], ref)
    with pytest.raises(ValueError, match="NaN"):
        metrics.score(np.full_like(ref, np.nan), ref)
    with pytest.raises(ValueError, match="all zeros"):
        metrics.score(np.zeros_like(ref), ref)
    real_import = builtins.__import__

    def no_flip(name, *args, **kwargs):
        if name == "flip_evaluator":
            raise ImportError("No module named 'flip_evaluator'")
        return real_import(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", no_flip)
    with pytest.raises(ImportError, match="flip-evaluator"):
        metrics.score(ref, ref, metrics=("flip",))
    assert "psnr" in metrics.score(ref, ref, metrics=("psnr", "ssim"))
