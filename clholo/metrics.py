"""Image quality of a hologram's reconstruction against a reference, after a scale fit.

Random-phase holograms lose contrast and overall brightness against what ray optics says they
should show (HOLOGRAPHY.md section 6), so every score is taken after the least-squares scale
``s = <I, R> / <I, I>`` that best maps the hologram's intensity ``I`` onto the reference ``R``;
``s`` is reported too. Colours that pass the optics differently (a pupil passes about
``1 / lambda^2`` of each colour; phase-only encodings shift the balance) need one scale per
colour, ``fit_scale="per_channel"``: ``s_c = <I_c, R_c> / <I_c, I_c>``, reported as a list.
One entry point, :func:`score`:

* PSNR and SSIM from scikit-image on linear intensity;
* FLIP (NVIDIA's perceptual difference, ``flip-evaluator`` on PyPI, the ``eval`` extra): an
  analytic model of contrast sensitivity, no downloaded weights. It is given linear intensity
  divided by ``data_range`` and clipped to [0, 1] ("LDR", not sRGB-encoded). 0 = identical,
  1 = as different as it gets.
"""

from __future__ import annotations

import warnings
from typing import Dict, List, Optional, Sequence, Union

import numpy as np

from clholo.errors import InputError, InputTypeError

__all__ = ["score", "scale_fit", "METRICS", "FIT_SCALES"]

METRICS = ("psnr", "ssim", "flip")
#: What ``score(..., fit_scale=)`` accepts: one scale for all colours, none, one per colour.
FIT_SCALES = (True, False, "per_channel")


def _as_hwc(name: str, a, layout: str) -> np.ndarray:
    arr = np.asarray(a)
    if not (np.issubdtype(arr.dtype, np.floating) or np.issubdtype(arr.dtype, np.integer)):
        raise InputTypeError(f"{name} must be a real image array, got dtype {arr.dtype}")
    if arr.size == 0:
        raise InputError(f"{name} is empty (shape {arr.shape}): an image needs at least one "
                         f"pixel")
    arr = arr.astype(np.float64)
    if layout not in ("auto", "hwc", "chw"):
        raise InputError(f"layout must be 'auto', 'hwc' or 'chw', got {layout!r}")
    if arr.ndim == 2:
        return arr[..., None]
    if arr.ndim != 3:
        raise ValueError(f"{name} must be (H, W), (H, W, C) or (C, H, W), got shape {arr.shape}")
    if layout == "auto":
        if arr.shape[-1] <= 4:
            layout = "hwc"
        elif arr.shape[0] <= 4:
            layout = "chw"
        else:
            raise ValueError(f"{name} has shape {arr.shape}: cannot tell the colour axis (at most "
                             f"4 channels first or last); pass layout='hwc' or 'chw'")
    if layout == "chw":
        return np.moveaxis(arr, 0, -1)
    if layout != "hwc":
        raise ValueError(f"layout must be 'auto', 'hwc' or 'chw', got {layout!r}")
    return arr


def _check_kinds(image, reference) -> None:
    """Refuse integer codes scored against floats: 8-bit (sRGB-coded) images against linear
    intensities gave PSNR 4.8 and SSIM 0.0002 for the same picture."""
    kinds = [np.asarray(a).dtype for a in (image, reference)]
    integer = [np.issubdtype(k, np.integer) for k in kinds]
    if integer[0] != integer[1]:
        codes, name = (kinds[0], "image") if integer[0] else (kinds[1], "reference")
        raise InputError(
            f"{name} holds {codes} codes and the other image floats: score linear intensities "
            f"of the same kind (clholo.io.images.srgb_to_linear({name} / "
            f"{np.iinfo(codes).max}) for sRGB-coded images)")


def _warn_negative(image: np.ndarray, reference: np.ndarray) -> None:
    """Intensities are >= 0: a field's real part, or an image offset by a constant, scored
    without a word. Dark-subtracted captures dip below 0 by their noise: only values below
    -25 % of the largest magnitude warn."""
    for name, a in (("image", image), ("reference", reference)):
        top = float(np.abs(a).max())
        low = float(a.min())
        if top > 0 and low < -0.25 * top:
            warnings.warn(f"{name} holds negative values (down to {low:.4g}, largest magnitude "
                          f"{top:.4g}): scores compare intensities (>= 0); pass |u|^2, not a "
                          f"field's real part, or clip dark-subtracted captures "
                          f"(numpy.clip(a, 0, None))", UserWarning, stacklevel=3)


def _check_pair(image: np.ndarray, reference: np.ndarray, how: str = "") -> None:
    """Refuse an image and reference of different shapes, or with NaN/inf values, by name."""
    if image.shape != reference.shape:
        raise ValueError(f"image {image.shape} and reference {reference.shape} must have the "
                         f"same shape{how}")
    for name, a in (("image", image), ("reference", reference)):
        if not np.all(np.isfinite(a)):
            raise ValueError(f"{name} contains NaN/inf values; every value must be finite")


def scale_fit(image: np.ndarray, reference: np.ndarray) -> float:
    """Least-squares ``s`` minimising ``||s image - reference||^2``: ``<I, R> / <I, I>``.
    ``image`` and ``reference`` must have the same shape and finite values."""
    image, reference = np.asarray(image), np.asarray(reference)
    for name, a in (("image", image), ("reference", reference)):
        if not (np.issubdtype(a.dtype, np.floating) or np.issubdtype(a.dtype, np.integer)):
            raise InputTypeError(f"{name} must be a real image array, got dtype {a.dtype}")
        if a.size == 0:
            raise InputError(f"{name} is empty (shape {a.shape}): nothing to fit")
    _check_pair(image, reference)
    # in float64: float32 products overflow near 1.8e19 (a NaN scale)
    image, reference = image.astype(np.float64), reference.astype(np.float64)
    den = float(np.sum(image * image))
    if den == 0:
        raise ValueError("image is all zeros: no scale maps it onto the reference")
    return float(np.sum(image * reference)) / den


def _check_fit_scale(fit_scale):
    if isinstance(fit_scale, (bool, np.bool_)):
        return bool(fit_scale)
    if isinstance(fit_scale, str) and fit_scale == "per_channel":
        return fit_scale
    raise ValueError(f"fit_scale must be one of {list(FIT_SCALES)} (True: one least-squares "
                     f"scale for all colours, False: none, 'per_channel': one per colour), got "
                     f"{fit_scale!r}")


def _flip(test: np.ndarray, ref: np.ndarray, data_range: float) -> float:
    try:
        import flip_evaluator
    except ImportError:
        raise ImportError(
            "the 'flip' metric needs the flip-evaluator package: pip install "
            "'clholo[eval]' (or flip-evaluator), or leave 'flip' out of metrics") from None
    t = np.clip(test / data_range, 0.0, 1.0).astype(np.float32)
    r = np.clip(ref / data_range, 0.0, 1.0).astype(np.float32)
    if r.shape[-1] == 3:
        pairs = [(r, t)]
    else:  # FLIP's colour model wants RGB: score each channel as a grey image
        pairs = [(np.repeat(r[..., c:c + 1], 3, axis=-1), np.repeat(t[..., c:c + 1], 3, axis=-1))
                 for c in range(r.shape[-1])]
    values = []
    for rr, tt in pairs:
        _, mean, _ = flip_evaluator.evaluate(np.ascontiguousarray(rr), np.ascontiguousarray(tt),
                                             "LDR", inputsRGB=False, applyMagma=False)
        values.append(float(mean))
    return float(np.mean(values))


def score(image, reference, *, metrics: Sequence[str] = METRICS,
          data_range: Optional[float] = None, fit_scale: Union[bool, str] = True,
          layout: str = "auto") -> Dict[str, Union[float, List[float]]]:
    """Scores of ``image`` (a hologram's intensity) against ``reference``.

    Parameters
    ----------
    image, reference : array (H, W), (H, W, C) or (C, H, W)
        Linear intensity (not sRGB-encoded), same shape. ``layout="auto"`` takes the axis of at
        most 4 entries (last first) as the colours.
    metrics : sequence of {"psnr", "ssim", "flip"}
    data_range : float, optional
        Intensity that counts as full scale (PSNR's peak, SSIM's L, FLIP's white); default the
        reference's maximum. Give one fixed value per scene (e.g. a high percentile of the
        clean reference) when comparing several images of it: the maximum of a speckled or
        per-image reference moves with the noise.
    fit_scale : True, False or "per_channel"
        ``True`` (default): score ``s * image`` with the one least-squares ``s`` for all
        colours; ``"per_channel"``: one least-squares ``s_c`` per colour; ``False``: the image
        as given (``scale`` is then 1). Anything else raises ``ValueError``.
    layout : {"auto", "hwc", "chw"}

    Returns
    -------
    dict
        ``"scale"`` (a float, or a list of one float per colour for ``"per_channel"``) and one
        float per metric: PSNR in dB (``inf`` for identical images), SSIM
        (1 for identical), FLIP (0 for identical, lower is better).

    Raises
    ------
    ValueError
        Shape mismatch, NaN, unknown metric, an unknown ``fit_scale``, an all-zero image (or
        colour, per channel), images smaller than SSIM's 7x7 window, a ``data_range`` more
        than 50x below the reference's maximum (0..255 images given ``data_range=1``), integer
        codes scored against floats.
    ImportError
        "flip" asked for without the flip-evaluator package.
    """
    fit_scale = _check_fit_scale(fit_scale)
    _check_kinds(image, reference)
    img = _as_hwc("image", image, layout)
    ref = _as_hwc("reference", reference, layout)
    _check_pair(img, ref, " (after moving colours last)")
    _warn_negative(img, ref)
    if isinstance(metrics, str):
        metrics = (metrics,)
    try:
        metrics = tuple(metrics)
    except TypeError:
        metrics = ()
    if not metrics:
        raise ValueError(f"metrics must be a non-empty sequence of {list(METRICS)}, got "
                         f"{metrics!r}")
    unknown = [m for m in metrics if m not in METRICS]
    if unknown:
        raise ValueError(f"unknown metric(s) {unknown}; choose from {list(METRICS)}")
    if data_range is None:
        data_range = float(ref.max())
        if data_range <= 0:
            raise ValueError("the reference is all zeros (or negative): give data_range")
    else:
        from clholo import validate

        data_range = validate.real_scalar("data_range", data_range)
        if data_range <= 0:
            raise ValueError(f"data_range must be > 0, got {data_range!r}")
        peak = float(ref.max())
        if peak > 50 * data_range:
            # PSNR goes negative and FLIP clips both images to white: an unrelated image
            # scored as nearly identical
            raise InputError(
                f"data_range {data_range:g} is {peak / data_range:.0f}x below the reference's "
                f"maximum {peak:.4g}: give the range the images span (255 for 0..255 images, "
                f"1 for 0..1), or leave data_range out (the reference's maximum)")
        if peak > 0 and data_range > 50 * peak:
            warnings.warn(f"data_range {data_range:g} is {data_range / peak:.0f}x the "
                          f"reference's maximum {peak:.4g}: scores then hardly see the errors; "
                          f"for images in 0..1 give data_range=1 (255 is for 0..255 images)",
                          UserWarning, stacklevel=2)
    if fit_scale == "per_channel":
        scales = []
        for c in range(img.shape[-1]):
            try:
                scales.append(scale_fit(img[..., c], ref[..., c]))
            except ValueError:
                raise ValueError(f"colour {c} of the image is all zeros: no scale maps it onto "
                                 f"the reference; use fit_scale=True") from None
        test = img * np.asarray(scales)
        out: Dict[str, Union[float, List[float]]] = {"scale": scales}
    else:
        s = scale_fit(img, ref) if fit_scale else 1.0
        test = s * img
        out = {"scale": s}
    if "psnr" in metrics:
        from skimage.metrics import peak_signal_noise_ratio

        with np.errstate(divide="ignore"), warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            out["psnr"] = float(peak_signal_noise_ratio(ref, test, data_range=data_range))
    if "ssim" in metrics:
        from skimage.metrics import structural_similarity

        if min(ref.shape[:2]) < 7:
            raise ValueError(f"SSIM needs images of at least 7 x 7 pixels, got {ref.shape[:2]}")
        out["ssim"] = float(structural_similarity(ref, test, data_range=data_range,
                                                  channel_axis=-1))
    if "flip" in metrics:
        out["flip"] = _flip(test, ref, data_range)
    return out
