"""RGB-D input: depth/disparity files and the layering of an image into an MPI.

Layering (``rgbd_to_mpi``):

* The valid depth values are normalised to ``t`` in [0, 1], 0 nearest: for ``depth_kind="depth"``
  ``t = (z - z_min) / (z_max - z_min)``, for ``"disparity"`` ``t = (d_max - d) / (d_max - d_min)``
  (large disparity is near). ``z_min``/``z_max`` are the map's own range unless ``depth_range``
  fixes them.
* ``L`` planes sit at ``t_i = i / (L - 1)`` and are placed at ``near + t_i (far - near)`` metres,
  uniform by index like :meth:`MPI.placed` with ``spacing="index"`` (for disparity input this is
  uniform in disparity, the usual MPI spacing). ``depth_spacing="disparity"`` bins a depth map
  by ``1 / z`` instead, so that its planes too are uniform in disparity.
* ``mode="hard"``: each pixel goes to its nearest plane with alpha 1 (the RGB-D baseline's
  binning, HOLOGRAPHY.md section 7).
* ``mode="soft"``: a pixel at ``t`` between planes ``i`` and ``i+1`` (fraction ``w`` of the way
  to ``i+1``) is split so that the *contributions* to the over-composite are linear:
  the near plane gets alpha ``1 - w``, the far plane alpha 1 (0 when ``w = 0``). Then
  ``over = c (1 - w) + w c = c``: the composite gives the image back exactly, and the pixel's
  light is shared between the two planes in proportion to closeness. (Splitting the *alpha*
  itself linearly, ``1 - w`` and ``w``, would lose ``w (1 - w)`` of the light: up to 25 %.)

Invalid depth (NaN, inf, and 0 when ``zero_is_invalid``) is, with ``invalid="fill"``, replaced
by the value of the nearest valid pixel (Euclidean distance transform; ties broken by scan
order) -- a background-agnostic fill that never invents depths outside the valid range;
``invalid="error"`` raises instead.
"""

from __future__ import annotations

import os
from typing import Optional, Tuple

import numpy as np

from ..errors import InputError, InputTypeError
from ..scene import MPI, _handed_over
from ._npy import load_npy
from .images import (PathLike, check_input_file, grey_channel, read_image, refuse_complex,
                     srgb_to_linear)

__all__ = ["read_depth", "read_pfm", "read_dpt", "fill_invalid", "rgbd_to_mpi", "read_rgb",
           "DPT_TAG", "DEPTH_NO_SURFACE", "depth_channels", "DepthMapWarning",
           "MOSTLY_INVALID_FRACTION"]


class DepthMapWarning(UserWarning):
    """An RGB-D scene's depth taken in a way that may not be what was meant: most of the map
    invalid and filled from the rest, or another depth source in the input left unused."""


#: Above this fraction of invalid depth pixels, ``invalid="fill"`` fills them with a
#: :class:`DepthMapWarning`: a map that is mostly NaN, zero or negative is more likely a wrong
#: file, offset or encoding than a sensor's holes.
MOSTLY_INVALID_FRACTION = 0.5

# The last part of a channel name that marks depth in an image that also holds colour: "Z"
# (OpenEXR's convention: Blender's single-layer EXR R G B A Z), "ViewLayer.Depth.Z" (Blender's
# multilayer EXR), "depth"
DEPTH_CHANNEL_WORDS = ("z", "depth")


def depth_channels(names) -> Tuple[int, ...]:
    """Indices of the channels in ``names`` that hold depth (last dot-separated part ``Z`` or
    ``depth``, any case), e.g. an EXR's ``R G B A Z``: ``(4,)``."""
    return tuple(i for i, name in enumerate(names)
                 if str(name).rsplit(".", 1)[-1].strip().lower() in DEPTH_CHANNEL_WORDS)


_DEPTH_FILE_FIX = "give a depth map file (.npy, .pfm, .dpt, or an image such as a 16-bit PNG)"
_DEPTH_NPY_FIX = "save the depth map with numpy.save (a 2-D float32 array), or give a .pfm or PNG"

#: First four bytes of an MPI Sintel ``.dpt`` depth file (a float32 "magic number").
DPT_TAG = 202021.25


def read_pfm(path: PathLike) -> np.ndarray:
    """Read a Portable Float Map (Middlebury disparities): ``Pf`` (grey) or ``PF`` (RGB).

    Rows are stored bottom to top; a negative scale means little-endian. Returns float32
    ``(H, W)`` or ``(H, W, 3)``, top row first; ``inf`` (Middlebury's "unknown") is kept.

    Parameters
    ----------
    path : str or os.PathLike
        The file.
    """
    path = check_input_file(path, "depth file", _DEPTH_FILE_FIX)
    with open(path, "rb") as f:
        data = f.read()
    try:
        header, rest = [], data
        while len(header) < 3:
            line, sep, rest = rest.partition(b"\n")
            if not sep:
                raise ValueError("header ends early")
            line = line.split(b"#")[0].strip()
            header.extend(line.split())
        kind, width, height, scale = header[0], int(header[1]), int(header[2]), None
        if len(header) < 4:
            line, _, rest = rest.partition(b"\n")
            header.extend(line.split())
        scale = float(header[3])
    except (ValueError, IndexError) as exc:
        raise ValueError(f"{path} is not a PFM file (bad header: {exc})") from None
    if kind not in (b"Pf", b"PF"):
        raise ValueError(f"{path} is not a PFM file (magic {kind!r}, expected Pf or PF)")
    channels = 1 if kind == b"Pf" else 3
    count = width * height * channels
    dtype = np.dtype("<f4" if scale < 0 else ">f4")
    if len(rest) < count * 4:
        raise ValueError(f"{path} is truncated: {len(rest)} bytes of pixels, expected {count * 4}"
                         f" for {width}x{height}x{channels}")
    arr = np.frombuffer(rest, dtype=dtype, count=count).astype(np.float32)
    arr = arr.reshape(height, width, channels)[::-1]
    return np.ascontiguousarray(arr[..., 0] if channels == 1 else arr)


def read_dpt(path: PathLike) -> np.ndarray:
    """Read an MPI Sintel ``.dpt`` depth file (the format of Sintel's ``depth/*.dpt``).

    Layout, little-endian: the float32 tag ``202021.25``, the width and the height as int32,
    then ``width * height`` float32 depths row by row, top row first (Sintel's own
    ``sintel_io.depth_read``). Returns float32 ``(H, W)`` in the file's units.

    Parameters
    ----------
    path : str or os.PathLike
        The file.

    Raises
    ------
    ValueError
        A wrong tag, a size that is not positive, fewer or more bytes than the size says; the
        message names the file.
    """
    path = check_input_file(path, "depth file", _DEPTH_FILE_FIX)
    with open(path, "rb") as f:
        data = f.read()
    if len(data) < 12:
        raise ValueError(f"{path} is not a Sintel .dpt depth file: {len(data)} bytes, shorter "
                         f"than its 12-byte header (tag, width, height)")
    tag = float(np.frombuffer(data, "<f4", count=1)[0])
    if tag != np.float32(DPT_TAG):
        raise ValueError(f"{path} is not a Sintel .dpt depth file: tag {tag!r}, expected "
                         f"{DPT_TAG} (the float32 that starts every .dpt)")
    width, height = (int(v) for v in np.frombuffer(data, "<i4", count=2, offset=4))
    if not (0 < width < 100000 and 0 < height < 100000):
        raise ValueError(f"{path}: .dpt header gives a size of {width}x{height} pixels; the "
                         f"file is corrupt")
    need = width * height * 4
    have = len(data) - 12
    if have != need:
        what = "truncated" if have < need else "longer than its header says"
        raise ValueError(f"{path} is {what}: {have} bytes of depth after the header, "
                         f"{width}x{height} float32 need {need}")
    return np.frombuffer(data, "<f4", offset=12).reshape(height, width).astype(np.float32)


def read_depth(path: PathLike, *, scale: float = 1.0) -> np.ndarray:
    """Read a depth or disparity map as float32 ``(H, W)`` in the file's own units.

    Parameters
    ----------
    path : path-like
        ``.npy`` (2-D array, or ``(H, W, C)``), ``.pfm`` (Middlebury), ``.dpt`` (MPI Sintel, see
        :func:`read_dpt`), or an image OpenImageIO reads: integer
        PNG/TIFF keep their raw codes (a 16-bit PNG of millimetres gives millimetres), float
        EXR/TIFF their values. An image with a channel named ``Z`` or ``depth`` (an EXR's
        ``R G B A Z``, Blender's ``ViewLayer.Depth.Z``) gives that channel. Otherwise a
        multi-channel image (an RGB ``.pfm``, a ``(H, W, C)`` ``.npy``) is read when all its
        colour channels are equal (a grey map saved as RGB) and refused when they differ (a
        colour-mapped picture of depth is not depth); an image's alpha channel is ignored.
    scale : float
        Multiplies the values (for example 1e-3 for millimetre PNGs).

    Raises
    ------
    FileNotFoundError
        Missing file.
    ValueError
        Not a regular file (a folder, a named pipe), not a 2-D map, complex values, channels
        that differ, a corrupt file; the message names the file.
    """
    path = check_input_file(path, "depth file", _DEPTH_FILE_FIX)
    suffix = path.suffix.lower()
    if suffix == ".npy":
        arr = load_npy(path, what="depth file", fix=_DEPTH_NPY_FIX)
        refuse_complex(arr, path, "depth map")
        if arr.ndim == 3 and np.issubdtype(arr.dtype, np.number):
            arr = grey_channel(arr, path, "depth map", fix=_GREY_FIX)
        if arr.ndim != 2 or not (np.issubdtype(arr.dtype, np.number)):
            raise ValueError(f"{path}: a depth .npy must hold a 2-D numeric array, got "
                             f"{arr.dtype} {arr.shape}")
    elif suffix == ".dpt":
        arr = read_dpt(path)
    elif suffix == ".pfm":
        arr = read_pfm(path)
        if arr.ndim == 3:
            arr = grey_channel(arr, path, "depth map", fix=_GREY_FIX)
    else:
        px, info = read_image(path, normalise=False)
        found = depth_channels(info["channels"])
        if len(found) > 1:
            raise ValueError(f"{path} has {len(found)} depth channels "
                             f"({', '.join(info['channels'][i] for i in found)}): clholo takes "
                             f"one; save the depth map you mean as a file of its own")
        if found and px.shape[2] > 1:
            arr = px[..., found[0]]  # the depth beside the colour (an RGB-D EXR)
        else:
            a = info["alpha_channel"]
            if a >= 0 and px.shape[2] > 1:
                px = np.delete(px, a, axis=2)
            arr = grey_channel(px, path, "depth map", fix=_GREY_FIX)
    return (np.asarray(arr, dtype=np.float64) * scale).astype(np.float32)


_GREY_FIX = ("a colour-mapped picture of depth cannot be read back as depth: give the depth "
             "values themselves (a grey PNG/EXR/TIFF, .npy, .pfm or .dpt)")


def read_rgb(path: PathLike) -> np.ndarray:
    """Read a colour image as linear intensity ``(H, W, 3)`` float32.

    Integer files are taken as sRGB-encoded and decoded with the exact EOTF, unless the file
    says otherwise: a PNG whose ``gAMA`` chunk (without an ``sRGB`` chunk) states gamma 1 holds
    linear values and is read as they are, one that states another gamma ``g`` is decoded as
    ``v ** g``; one with an embedded ICC profile of the matrix/TRC kind (Display P3, Adobe RGB,
    ...: :mod:`clholo.io.icc`) is converted to linear sRGB by it (relative colorimetric;
    colours outside sRGB's gamut are clipped), and one whose profile clholo cannot apply gets
    a :class:`~clholo.io.icc.ColourProfileWarning` and is read as sRGB.
    Float files (EXR, float TIFF) are taken as linear intensity in [0, 1] (an EXR whose
    ``chromaticities`` state other primaries than sRGB's, e.g. an ACES or ACEScg render, is
    converted to sRGB's: :func:`clholo.io.icc.chromaticities_matrix`; colours outside sRGB's
    gamut are clipped), and refused when
    they hold values outside it or NaN/inf (a 0..255 image saved as floats, an HDR render):
    clipping them would give a white picture without a word. The image is turned upright by
    its EXIF ``Orientation`` (:func:`~clholo.io.images.read_image`). Alpha and depth channels
    (named ``Z`` or ``depth``: :func:`depth_channels`) are dropped; grey images are repeated
    to three channels.

    Parameters
    ----------
    path : str or os.PathLike
        The file.

    Raises
    ------
    FileNotFoundError
        Missing file.
    ValueError
        Not a regular file, not an image OpenImageIO reads, float colour outside [0, 1] or not
        finite; the message names the file and the fix.
    """
    px, info = read_image(path)
    a = info["alpha_channel"]
    drop = sorted(set(depth_channels(info["channels"])) | ({a} if a >= 0 else set()))
    if len(drop) == px.shape[2]:
        raise ValueError(f"{path} holds no colour channel (only "
                         f"{', '.join(info['channels'])}): give the colour image, then this "
                         f"file as its depth map")
    px = np.delete(px, drop, axis=2)
    if px.shape[2] == 1:
        px = np.repeat(px, 3, axis=2)
    px = px[..., :3]
    profile = _colour_profile(info["attributes"], path)
    if info["format"] in ("uint8", "uint16", "int8", "int16", "uint32", "int32"):
        px = _decoded(px, info["attributes"], profile)
    elif info["max_code"] is None:  # float pixels, as stored
        if profile is not None and not profile.is_srgb():
            _warn_profile(path, f"its ICC profile {profile.name!r} is not applied to float "
                                f"pixels: they are taken as linear sRGB")
        _check_float_file_colour(px, path)
        px = _to_srgb_primaries(px, info["attributes"], path)
    return np.clip(px, 0.0, 1.0).astype(np.float32)


def _to_srgb_primaries(px: np.ndarray, attributes: dict, path) -> np.ndarray:
    """Linear float colour in the primaries an OpenEXR file states (its ``chromaticities``:
    ACES AP0, ACEScg's AP1, Rec. 2020, ...) as linear sRGB (:func:`clholo.io.icc.
    chromaticities_matrix`); as it is where the file states none or Rec. 709's. Chromaticities
    that span no colour space get a :class:`~clholo.io.icc.ColourProfileWarning` and are
    ignored."""
    chroma = attributes.get("chromaticities")
    if chroma is None:
        return px
    from .icc import chromaticities_matrix

    try:
        m = chromaticities_matrix(chroma)
    except ValueError as exc:
        _warn_profile(path, f"its chromaticities are not a colour space ({exc}): colour taken "
                            f"as linear sRGB (Rec. 709)")
        return px
    return px if m is None else (px.astype(np.float64) @ m.T).astype(np.float32)


def _warn_profile(path, what: str) -> None:
    import warnings

    from .icc import ColourProfileWarning

    warnings.warn(f"{path}: {what}", ColourProfileWarning, stacklevel=4)


def _colour_profile(attributes: dict, path):
    """The file's embedded ICC profile (OpenImageIO's ``ICCProfile``) where clholo can apply
    it, else None: one it cannot (lookup tables, CMYK, malformed) is named in a
    :class:`~clholo.io.icc.ColourProfileWarning` and the colour taken as sRGB."""
    data = attributes.get("ICCProfile")
    if data is None or len(data) == 0:
        return None
    from .icc import parse_icc

    try:
        profile = parse_icc(data)
    except ValueError as exc:
        _warn_profile(path, f"its ICC profile cannot be read ({exc}): colour taken as sRGB")
        return None
    if not profile.applicable:
        why = ("built from lookup tables" if profile.lut_based else
               f"of the {profile.space} colour space" if profile.space not in ("RGB", "GRAY")
               else "without the curves and colorants of a matrix/TRC profile")
        _warn_profile(path, f"its ICC profile {profile.name!r} ({why}) is not applied: colour "
                            f"taken as sRGB; convert the image to sRGB first if it matters")
        return None
    return profile


def _decoded(px: np.ndarray, attributes: dict, profile=None) -> np.ndarray:
    """Integer colour normalised to [0, 1] as linear intensity, by the transfer function its
    file states: an embedded ICC profile (``profile``, :mod:`clholo.io.icc`: its curves and
    colorants, to linear sRGB; sRGB's own profile by the exact EOTF) first, as PNG ranks
    ``iCCP`` above ``sRGB`` and ``gAMA``; then OpenImageIO's ``oiio:ColorSpace`` for a PNG's
    ``gAMA`` chunk: ``"lin_rec709_scene"`` (gamma 1: the values are linear already) or
    ``"gNN_..."`` with ``oiio:Gamma`` (a power law); anything else (an ``sRGB`` chunk, no
    statement) is sRGB."""
    if profile is not None:
        return srgb_to_linear(px) if profile.is_srgb() else profile.to_linear_srgb(px)
    space = str(attributes.get("oiio:ColorSpace", "")).strip().lower()
    gamma = attributes.get("oiio:Gamma")
    if space.startswith("lin"):
        return px
    if space.startswith("g") and isinstance(gamma, (int, float)) and gamma > 0:
        return np.power(np.clip(px, 0.0, None), float(gamma))
    return srgb_to_linear(px)


def _check_float_file_colour(px: np.ndarray, path) -> None:
    """:func:`_check_float_colour` for an image file: the same test, and a message that names
    the file, the values found and how to fix the file."""
    from clholo.errors import InputError

    try:
        _check_float_colour(px)
    except ValueError:
        pass
    else:
        return
    finite = np.isfinite(px)
    if not finite.all():
        bad = ~finite.all(axis=-1)
        ys, xs = np.nonzero(bad)
        raise InputError(f"{path} holds {int(bad.sum())} pixel(s) of NaN/inf colour (the first "
                         f"at row {ys[0]}, column {xs[0]}): every colour value must be finite "
                         f"linear intensity in [0, 1]; fill them and save the image again")
    lo, hi = float(px.min()), float(px.max())
    fix = ("it looks like 0..255 never divided: divide by 255 and save it again (or save the "
           "picture as an 8-bit sRGB PNG)" if 1.5 < hi <= 255 and lo >= -1e-6 else
           "scale it into [0, 1] (an HDR image: divide by its maximum) and save it again")
    raise InputError(f"{path} holds float colour in [{lo:.4g}, {hi:.4g}], but a float image "
                     f"(EXR, float TIFF) is read as linear intensity in [0, 1]: {fix}")


def fill_invalid(depth: np.ndarray, invalid: np.ndarray) -> np.ndarray:
    """Replace ``depth[invalid]`` by the value of the nearest valid pixel (Euclidean).

    Raises
    ------
    ValueError
        When no pixel is valid.
    """
    from scipy import ndimage  # scikit-image depends on SciPy

    if invalid.all():
        raise ValueError("depth map has no valid pixel to fill from")
    if not invalid.any():
        return depth
    _, (iy, ix) = ndimage.distance_transform_edt(invalid, return_distances=True,
                                                return_indices=True)
    return depth[iy, ix]


#: Depths at or beyond this mark no surface, like inf: renderers write a huge finite value
#: where a ray hits nothing (Blender's Z pass: 1e10 for the background). Taken as a depth it
#: would stretch the map's range so far that every surface fell into the nearest plane. No
#: depth or disparity in any unit comes near it (1e10 mm is 10,000 km).
DEPTH_NO_SURFACE = 1e10


def _validated_depth(depth, shape, *, invalid: str, zero_is_invalid: bool) -> np.ndarray:
    if isinstance(depth, (str, bytes, os.PathLike)):
        raise InputTypeError(f"depth must be an array of depth values, got the path {depth!r}: "
                             f"read the file first (clholo.io.read_depth, or "
                             f"clholo.io.load_scene for an image and its depth map)")
    refuse_complex(depth, "depth", "depth map")
    depth = np.asarray(depth, dtype=np.float64)
    if depth.ndim == 3 and depth.shape[-1] == 1:
        depth = depth[..., 0]
    if depth.shape != shape:
        raise ValueError(f"depth has shape {depth.shape} but the image is {shape}; they must "
                         f"match pixel for pixel")
    bad = ~(np.abs(depth) < DEPTH_NO_SURFACE)  # NaN, inf and a renderer's "no surface"
    if zero_is_invalid:
        bad |= depth == 0
    bad |= depth < 0
    if bad.all():  # nothing to fill from: say what every pixel is, not "no valid pixel to fill"
        finite = depth[np.isfinite(depth)]  # NaN first: nanmin of all NaN would only warn
        # (the range includes the values >= DEPTH_NO_SURFACE: the message says what they are)
        values = (f"range {finite.min():g}..{finite.max():g}" if finite.size else
                  "all NaN" if np.all(np.isnan(depth)) else "all NaN or inf")
        raise ValueError(f"depth has no valid pixel: every value is NaN, inf (or >= 1e10: "
                         f"no surface), negative"
                         f"{' or 0' if zero_is_invalid else ''} ({values}); is it the depth "
                         f"map, in its own units?")
    if bad.any():
        if invalid == "error":
            ys, xs = np.nonzero(bad)
            raise ValueError(
                f"depth has {int(bad.sum())} invalid pixel(s) (NaN, inf or >= 1e10, "
                f"negative"
                f"{', or 0' if zero_is_invalid else ''}), first at row {ys[0]}, column {xs[0]}; "
                f"pass invalid='fill' to fill them from the nearest valid pixel")
        if invalid != "fill":
            raise ValueError(f"invalid must be 'fill' or 'error', got {invalid!r}")
        share = float(bad.mean())
        if share > MOSTLY_INVALID_FRACTION:
            from clholo.validate import warn_at_caller

            warn_at_caller(
                f"depth: {share:.0%} of its pixels are invalid (NaN, inf, negative"
                f"{' or 0' if zero_is_invalid else ''}) and are filled from the nearest valid "
                f"ones: is it the right map, offset and encoding? (invalid='error' refuses "
                f"such maps)", DepthMapWarning)
        depth = fill_invalid(depth, bad)
    return depth


def _check_integer_codes(img: np.ndarray) -> None:
    """Integer colour is 8- or 16-bit codes (uint8, uint16: divided by 255 or 65535). Any other
    integer type would be divided by its own largest value: 0..255 in an int64 array (NumPy's
    default for a list of ints) would be 2e-17 of full scale, a black scene without a word; 8-bit
    codes in a uint16 array 1/257 of what was meant."""
    if img.dtype not in (np.uint8, np.uint16):
        lo, hi = (int(img.min()), int(img.max())) if img.size else (0, 0)
        bits = "uint8" if 0 <= lo and hi <= 255 else "uint16" if 0 <= lo and hi <= 65535 \
            else None
        fix = (f"image.astype(np.{bits}) if these are {bits[4:]}-bit codes" if bits else
               "floats in [0, 1] (linear intensity)")
        raise InputError(f"image holds {img.dtype} values ({lo}..{hi}); integer colour must be "
                         f"uint8 or uint16 codes (sRGB): give {fix}")
    if img.dtype == np.uint16 and img.size and int(img.max()) <= 255 and int(img.max()) > 0:
        raise InputError(f"image is uint16 but its values lie in 0..{int(img.max())}: 8-bit codes "
                         f"in a 16-bit array would be 1/257 of full scale; give "
                         f"image.astype(np.uint8), or 16-bit codes (0..65535)")


def _check_float_colour(color: np.ndarray) -> None:
    """A float image is linear intensity in [0, 1]: a 0..255 image given as floats, or an
    HDR one, would otherwise be clipped to white without a word."""
    if not np.all(np.isfinite(color)):
        raise ValueError("image contains NaN/inf values; every colour value must be finite")
    lo, hi = float(color.min()), float(color.max())
    if lo < -1e-6 or hi > 1 + 1e-6:
        hint = ("it looks like 0..255: divide by 255, or pass the uint8 image (decoded from "
                "sRGB)" if hi > 1.5 and hi <= 255 else "scale it into [0, 1] first")
        raise ValueError(f"image as floats must be linear intensity in [0, 1], got values in "
                         f"[{lo:.4g}, {hi:.4g}]: {hint}")


def _checked_depth_range(depth_range, depth_kind: str) -> Tuple[float, float]:
    """``depth_range`` as two finite floats, closest first: smaller for a depth map, larger
    for a disparity map (a reversed pair would put every plane upside down)."""
    from clholo import validate

    if isinstance(depth_range, (str, bytes)) or np.ndim(depth_range) != 1 \
            or len(depth_range) != 2:
        raise ValueError(f"depth_range must be (closest, farthest), two values of the "
                         f"{depth_kind} map, got {depth_range!r}")
    closest, farthest = (validate.real_scalar("depth_range", v) for v in depth_range)
    if closest == farthest or (closest > farthest) != (depth_kind == "disparity"):
        order = ("larger" if depth_kind == "disparity" else "smaller")
        raise ValueError(f"depth_range is (closest, farthest); for a {depth_kind} map the "
                         f"closest value is the {order} one, got {depth_range!r}: swap them, "
                         f"or set depth_kind")
    return closest, farthest


def rgbd_to_mpi(image, depth, *, layers: int, near: float, far: float, mode: str = "hard",
                depth_kind: str = "depth", depth_spacing: str = "linear",
                invalid: str = "fill", zero_is_invalid: bool = True,
                depth_range: Optional[Tuple[float, float]] = None,
                srgb: Optional[bool] = None) -> MPI:
    """Layer an image with a depth or disparity map into an ``L``-plane MPI.

    Parameters
    ----------
    image : array_like, shape (H, W, C) or (H, W)
        Colour. uint8/uint16 arrays are taken as sRGB and decoded to linear; float arrays as
        linear intensity in [0, 1] (override with ``srgb``).
    depth : array_like, shape (H, W)
        Depth (larger is farther) or disparity (larger is nearer), any units.
    layers : int
        Number of planes ``L``, 2 to 256 (the paper uses 4 to 64).
    near, far : float
        Metres behind the hologram plane of the nearest and farthest plane, ``0 < near < far``.
    mode : {"hard", "soft"}
        See the module docstring: hard = nearest plane, alpha 0/1; soft = split between the two
        nearest planes so that the over-composite reproduces the image.
    depth_kind : {"depth", "disparity"}
    depth_spacing : {"linear", "disparity"}
        ``"linear"``: planes uniform in the map's own values (depth for a depth map).
        ``"disparity"``: planes uniform in disparity (inverse depth): a depth map is binned by
        ``1 / z``, which gives near surfaces, where most pixels of a typical frame lie and depth
        of field is shallowest, more planes; for a disparity map it is the same as ``"linear"``.
        The planes' depths in metres are uniform in ``[near, far]`` by index either way.
    invalid : {"fill", "error"}
        Policy for NaN/inf/negative (and zero, see ``zero_is_invalid``) depth, and depth at
        or beyond :data:`DEPTH_NO_SURFACE` (1e10: a renderer's "no surface", Blender's
        background in its Z pass).
    zero_is_invalid : bool
        Treat 0 as "unknown" (true for most depth sensors and disparity maps).
    depth_range : (float, float), optional
        ``(closest, farthest)`` value of ``depth`` (in the map's own kind and units) mapped to
        ``near`` and ``far``; default the valid range of the map. Values outside are clamped.
    srgb : bool, optional
        Force the colour decoding decision.

    Returns
    -------
    MPI
        ``L`` layers, colour = the image in every layer (so that soft edges and later
        filtering see the true colour; one image shared by the layers, a read-only broadcast
        view, see :class:`~clholo.MPI`), alpha as described, depths uniform in
        ``[near, far]``.
    """
    if isinstance(image, (str, bytes, os.PathLike)):
        raise InputTypeError(f"image must be an array of colour values, got the path {image!r}: "
                             f"read the file first (clholo.io.read_rgb, or clholo.io.load_scene "
                             f"for an image and its depth map)")
    img = np.asarray(image)
    refuse_complex(img, "image", "colour image")
    if img.ndim == 2:
        img = img[..., None]
    if img.ndim != 3:
        raise ValueError(f"image must have shape (H, W, C), got {img.shape}")
    if img.size == 0:
        raise InputError(f"image is empty (shape {img.shape}): it needs at least one pixel and "
                         f"one colour channel")
    from clholo import validate

    zero_is_invalid = validate.flag(zero_is_invalid, name="zero_is_invalid")
    if srgb is not None:
        srgb = validate.flag(srgb, name="srgb")
    decode = np.issubdtype(img.dtype, np.integer) if srgb is None else srgb
    if np.issubdtype(img.dtype, np.integer):
        _check_integer_codes(img)
        color = img.astype(np.float64) / np.iinfo(img.dtype).max
    else:
        color = img.astype(np.float64)
        _check_float_colour(color)
    if decode:
        color = srgb_to_linear(color)
    if not isinstance(layers, (int, np.integer)) or not (2 <= layers <= 256):
        raise ValueError(f"layers must be an integer from 2 to 256, got {layers!r}")
    near, far = validate.real_scalar("near", near), validate.real_scalar("far", far)
    if not 0 < near < far:
        raise ValueError(f"need 0 < near < far (metres), got near={near}, far={far}")
    if mode not in ("hard", "soft"):
        raise ValueError(f"mode must be 'hard' or 'soft', got {mode!r}")
    if depth_kind not in ("depth", "disparity"):
        raise ValueError(f"depth_kind must be 'depth' or 'disparity', got {depth_kind!r}")
    if depth_spacing not in ("linear", "disparity"):
        raise ValueError(f"depth_spacing must be 'linear' or 'disparity', got {depth_spacing!r}")
    z = _validated_depth(depth, img.shape[:2], invalid=invalid, zero_is_invalid=zero_is_invalid)
    if depth_range is not None:
        depth_range = _checked_depth_range(depth_range, depth_kind)
    if depth_spacing == "disparity" and depth_kind == "depth":
        # bin depths by inverse depth: from here on the map is a disparity map
        if np.any(z <= 0) or (depth_range is not None and min(depth_range) <= 0):
            raise ValueError("depth_spacing='disparity' needs depths > 0 (0 has no inverse); "
                             "mark zeros invalid (zero_is_invalid=True) or use 'linear'")
        z = 1.0 / z
        if depth_range is not None:
            depth_range = tuple(1.0 / float(v) for v in depth_range)
        depth_kind = "disparity"
    if depth_range is None:
        lo_val, hi_val = float(z.min()), float(z.max())
        if depth_kind == "disparity":  # nearest = largest disparity
            lo_val, hi_val = hi_val, lo_val
    else:
        lo_val, hi_val = (float(v) for v in depth_range)
    if lo_val == hi_val:
        t = np.zeros_like(z)
    else:
        t = np.clip((z - lo_val) / (hi_val - lo_val), 0.0, 1.0)
    L = int(layers)
    s = t * (L - 1)  # continuous plane coordinate, 0 = nearest plane
    H, W = z.shape
    alpha = np.zeros((L, H, W), np.float32)
    yy, xx = np.mgrid[0:H, 0:W]
    if mode == "hard":
        idx = np.clip(np.rint(s).astype(int), 0, L - 1)
        alpha[idx, yy, xx] = 1.0
    else:
        i0 = np.clip(np.floor(s).astype(int), 0, L - 2)
        w = np.clip(s - i0, 0.0, 1.0)
        alpha[i0, yy, xx] = (1.0 - w).astype(np.float32)
        alpha[i0 + 1, yy, xx] = (w > 0).astype(np.float32)
    color = np.broadcast_to(np.clip(color, 0.0, 1.0).astype(np.float32)[None],
                            (L,) + color.shape)
    depths = np.linspace(near, far, L)
    # one colour image shared by every layer, and the alpha kept without a copy (nothing else
    # holds it)
    return MPI(color, _handed_over(alpha), depths)
