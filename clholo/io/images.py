"""Image files through OpenImageIO, sRGB transfer functions and all-or-nothing writes.

Every reader and writer of :mod:`clholo.io` goes through this module, so that

* pixels come out as every viewer shows them: turned upright by the EXIF/TIFF ``Orientation``
  tag (a phone photo is stored sideways with Orientation 6 or 8), and an EXR's data window
  placed in its display window (0 outside the data window, as OpenEXR defines it);
* a file whose reader reports an error while decoding (a JPEG cut short, which libjpeg would
  pad with grey rows) is refused, never returned half-read;
* alpha is read *as stored*: OpenImageIO premultiplies straight-alpha files (PNG, WebP, ...) on
  read unless told otherwise (``oiio:UnassociatedAlpha``); we always ask for the stored values and
  let the caller decide what the alpha means;
* integer images come back either normalised to [0, 1] (colour) or as their raw integer values
  (depth maps in millimetres, say);
* nothing is ever half-written: files are written under a temporary name in the destination's
  folder and renamed over the target when complete (``os.replace`` is atomic on one file system).
"""

from __future__ import annotations

import contextlib
import ctypes
import errno
import functools
import os
import shutil
import stat
import sys
import tempfile
import time
from pathlib import Path
from typing import Iterator, Optional, Tuple, Union

import numpy as np

from clholo.errors import InputError

__all__ = [
    "srgb_to_linear", "linear_to_srgb", "linear_to_srgb8", "read_image", "write_image",
    "atomic_path", "atomic_directory", "replace_path", "exchange_paths", "PathLike", "grey_channel",
    "refuse_complex",
]

PathLike = Union[str, "os.PathLike[str]"]


def srgb_to_linear(v: np.ndarray) -> np.ndarray:
    """Exact sRGB EOTF (IEC 61966-2-1): encoded values in [0, 1] to linear intensity.

    ``v / 12.92`` below 0.04045, ``((v + 0.055) / 1.055) ** 2.4`` above -- not a plain 2.2 gamma,
    which is off by up to 0.6 % of full scale near black.
    """
    v = _fractions(v, "srgb_to_linear")
    out = np.where(v <= 0.04045, v / 12.92, ((np.maximum(v, 0.04045) + 0.055) / 1.055) ** 2.4)
    return out


def _fractions(v, what: str) -> np.ndarray:
    """``v`` as float64 values of [0, 1]'s scale: integer codes (uint8 0..255 would decode to
    half a million), complex numbers and strings are refused, naming ``v``."""
    from clholo.errors import InputTypeError

    arr = np.asarray(v)  # a string is an array of dtype <U: refused below
    if np.issubdtype(arr.dtype, np.integer) and arr.size and \
            not 0 <= int(arr.min()) <= int(arr.max()) <= 1:
        top = 255 if int(arr.max()) <= 255 else 65535
        raise InputTypeError(f"{what}: v holds {arr.dtype} values up to {int(arr.max())}, not "
                             f"values of [0, 1]'s scale: codes of 0..{top}? divide by {top} "
                             f"first")
    if np.iscomplexobj(arr) or not (np.issubdtype(arr.dtype, np.floating)
                                    or np.issubdtype(arr.dtype, np.integer)
                                    or arr.dtype == bool):
        raise InputTypeError(f"{what}: v must be real values of [0, 1]'s scale, got "
                             f"{arr.dtype}")
    return arr.astype(np.float64)


def linear_to_srgb(v: np.ndarray) -> np.ndarray:
    """Inverse of :func:`srgb_to_linear`: linear intensity in [0, 1] to sRGB-encoded values.

    Parameters
    ----------
    v : array
        Linear intensity in [0, 1].
    """
    v = _fractions(v, "linear_to_srgb")
    return np.where(v <= 0.0031308, v * 12.92,
                    1.055 * np.maximum(v, 0.0031308) ** (1.0 / 2.4) - 0.055)


# Elements per band of the banded encoders: whole-image float64 temporaries of a 48-megapixel
# contact sheet (1.2 GB each, five of them) cost more in fresh pages than in arithmetic
_BAND_ELEMENTS = 1 << 21


def linear_to_srgb8(v: np.ndarray) -> np.ndarray:
    """8-bit sRGB codes of linear intensities: ``round(255 clip(linear_to_srgb(v), 0, 1))``.

    The codes :func:`write_image` stores for ``linear_to_srgb(v)`` with ``dtype="uint8"``
    (the same arithmetic, in float64), computed a band of rows at a time: a large image (a
    12-megapixel render's contact sheet, 146 million values) is encoded without float64
    copies of the whole of it.

    Parameters
    ----------
    v : array
        Linear intensity; values outside [0, 1] give codes 0 and 255.

    Returns
    -------
    ndarray, uint8, the shape of ``v``.
    """
    v = np.asarray(v)
    out = np.empty(v.shape, np.uint8)
    flat_in, flat_out = v.reshape(-1), out.reshape(-1)
    for start in range(0, flat_in.size, _BAND_ELEMENTS):
        band = linear_to_srgb(flat_in[start:start + _BAND_ELEMENTS])
        flat_out[start:start + _BAND_ELEMENTS] = np.round(np.clip(band, 0.0, 1.0) * 255)
    return out


def _oiio():
    try:
        import OpenImageIO as oiio
    except ImportError as exc:  # pragma: no cover - hard dependency
        raise ImportError("clholo.io needs OpenImageIO: `pip install OpenImageIO`") from exc
    return oiio


def write_failure(path: PathLike, written: PathLike, detail: str) -> Optional[OSError]:
    """The :class:`OSError` for an image writer's failure at ``written`` (the temporary file
    of ``path``) whose cause is the machine's: a file-size limit (the shell's ``ulimit -f``:
    the file reached it) or a full disk (under a MiB left). None where neither explains it.

    OpenImageIO reports neither as such: its PNG writer returns success from every call and
    only leaves "Write error at position ..." in ``geterror()``, and its EXR writer says "File
    output failed"; the errno is gone. Without this a truncated PNG passed as written."""
    detail = detail.split(";")[0][:120]  # the first of the writer's repeated lines
    try:
        size = os.stat(written).st_size
    except OSError:
        size = None
    try:
        import resource

        limit, _ = resource.getrlimit(resource.RLIMIT_FSIZE)
        unlimited = limit == resource.RLIM_INFINITY or limit < 0
    except (ImportError, OSError, ValueError):  # pragma: no cover - not POSIX
        limit, unlimited = 0, True
    if size is not None and not unlimited and size >= limit:
        return OSError(errno.EFBIG, f"File too large ({detail})", os.fspath(path))
    try:
        st = os.statvfs(os.path.dirname(os.path.abspath(os.fspath(written))))
        if st.f_bavail * st.f_frsize < (1 << 20):
            return OSError(errno.ENOSPC, f"No space left on device ({detail})", os.fspath(path))
    except (OSError, AttributeError):  # pragma: no cover - no statvfs
        pass
    return None


def _one_line(message: str) -> str:
    """OpenImageIO's error text on one line (it stacks the reader's lines, e.g. libpng's
    "Read error" and then "PNG library error (truncated file?)"), repeats dropped."""
    lines = []
    for line in str(message or "").splitlines():
        line = line.strip().rstrip(".")
        if line and line not in lines:
            lines.append(line)
    return "; ".join(lines)


def _not_regular(mode: int) -> Tuple[str, str]:
    """What a path that is neither a regular file nor a folder is, and a hint, for a
    message."""
    if stat.S_ISFIFO(mode):
        return ("a named pipe, as bash's <(...) gives", "; clholo reads its inputs from files "
                "(more than once), so save the stream to a file first")
    if stat.S_ISCHR(mode) or stat.S_ISBLK(mode):
        return "a device", ""
    if stat.S_ISSOCK(mode):
        return "a socket", ""
    return "a special file", ""


def check_input_file(path: PathLike, what: str, fix: str) -> Path:
    """``path`` as a :class:`~pathlib.Path` when it is a regular file (a link to one counts),
    else an error that names it, says what it is and what to give instead.

    Only ``stat`` is asked, never ``open``: opening a named pipe waits for a writer that may
    never come (a hang that not even SIGTERM ends while OpenImageIO or ``open`` holds it), and
    a device may block or never end.

    Parameters
    ----------
    path : str or os.PathLike
        The input file.
    what : str
        What it should be, starting the message (``"image file"``).
    fix : str
        What to give instead (``"give an image file (PNG, EXR, ...)"``).

    Returns
    -------
    pathlib.Path

    Raises
    ------
    FileNotFoundError
        ``path`` does not exist.
    clholo.errors.InputError
        ``path`` is a folder, a named pipe, a device or a socket, a loop of links, or a name
        no file can have (a NUL byte, a lone surrogate).
    """
    path = Path(path)
    try:
        mode = path.stat().st_mode
    except (FileNotFoundError, NotADirectoryError):
        raise FileNotFoundError(f"{what} {path} does not exist") from None
    except PermissionError as exc:
        raise PermissionError(f"cannot read {what} {path}: {exc.strerror}; check its "
                              f"folder's permissions") from None
    except OSError as exc:  # a loop of symbolic links, a name too long, ...
        raise InputError(f"cannot read {what} {path}: {exc.strerror or exc}; {fix}") from None
    except ValueError:  # a name no file can have: stat says "embedded null byte", or cannot
        # encode a lone surrogate (from a JSON "\ud800") for the file system
        bad = ("a NUL byte" if "\x00" in str(path) else
               "a character that is not valid Unicode (a lone surrogate)")
        raise InputError(f"{what} {ascii(str(path))} is not a file name: it holds {bad}, which "
                         f"no file's name can; {fix}") from None
    if stat.S_ISDIR(mode):
        raise InputError(f"{what} {path} is a folder: {fix}")
    if not stat.S_ISREG(mode):
        kind, hint = _not_regular(mode)
        raise InputError(f"{what} {path} is not a regular file ({kind}): {fix}{hint}")
    return path


def read_image(path: PathLike, *, normalise: bool = True) -> Tuple[np.ndarray, dict]:
    """Read an image file as stored (no colour conversion, alpha not premultiplied by us),
    turned upright by its EXIF/TIFF ``Orientation`` tag as every viewer shows it, an EXR's
    data window placed in its display window (0 outside it).

    Parameters
    ----------
    path : path-like
        Any file OpenImageIO reads (PNG, EXR, TIFF, WebP, JPEG, ...).
    normalise : bool
        True: integer pixels are scaled to [0, 1] (8-bit by 1/255, 16-bit by 1/65535); float
        pixels are returned unchanged. False: integer pixels keep their raw values (depth maps).

    Returns
    -------
    pixels : ndarray, shape (H, W, C), float32 (float64 for 32-bit integer files read raw)
    info : dict
        ``channels`` (channel names), ``format`` (stored pixel type name such as ``"uint8"``,
        ``"half"``, ``"float"``), ``alpha_channel`` (index or -1), ``attributes`` (header
        attributes as a dict; ``Orientation``, when present, is the stored one, already
        applied to ``pixels``), ``size`` (``(H, W)`` of ``pixels``), ``max_code`` (largest
        code of an integer file, else None).

    Raises
    ------
    FileNotFoundError
        When ``path`` does not exist.
    ValueError
        When ``path`` is not a regular file (a folder, a named pipe, a device), is empty,
        OpenImageIO cannot read it, its reader reports an error while decoding (a JPEG cut
        short, whose missing rows libjpeg would fill with grey), or it holds several pictures
        of one size (a multi-page TIFF, a multi-part EXR: only one would be read); the
        message names the file.
    """
    oiio = _oiio()
    path = check_input_file(path, "image file", "give an image file (PNG, EXR, TIFF, ...)")
    if path.stat().st_size == 0:  # else OpenImageIO's reader for the extension says "Not a PNG"
        raise ValueError(f"image file {path} is empty (0 bytes): copy or export it again, or "
                         f"give an image file (PNG, EXR, TIFF, ...)")
    config = oiio.ImageSpec()
    # Keep straight alpha straight: without this hint PNG/WebP/TIFF readers premultiply.
    config.attribute("oiio:UnassociatedAlpha", 1)
    inp = oiio.ImageInput.open(str(path), config)
    if inp is None:
        why = _one_line(oiio.geterror()) or "unknown format"
        hint = _NO_READER_HINTS.get(path.suffix.lower())
        if hint and not _has_reader(oiio, path.suffix):
            why = f"this OpenImageIO has no reader for {path.suffix} files: {hint}"
        raise ValueError(f"cannot read image {path}: {why}")
    try:
        spec = inp.spec()
        fmt = str(spec.format)
        _refuse_beyond_memory(spec, path)
        pixels = inp.read_image(0, 0, 0, spec.nchannels, "unknown")
        # libjpeg fills the rows of a cut-off JPEG with grey and returns them: the reader
        # records the error ("Premature end of JPEG file") without failing the read
        error = _one_line(inp.geterror())
        if pixels is None or error:
            raise ValueError(f"cannot read pixels of {path}: {error or 'unknown error'} "
                             f"(truncated file?)")
        attributes = {a.name: a.value for a in spec.extra_attribs}
        _refuse_picture_stack(inp, spec, path)
        info = {"channels": tuple(spec.channelnames), "format": fmt,
                "alpha_channel": int(spec.alpha_channel), "attributes": attributes,
                "size": (spec.height, spec.width), "max_code": None}
    finally:
        inp.close()
    pixels = np.asarray(pixels)
    if pixels.ndim == 2:
        pixels = pixels[..., None]
    if pixels.ndim != 3:
        raise ValueError(f"{path}: expected a 2-D image, got pixel array of shape {pixels.shape}"
                         f" (volumes and deep images are not supported)")
    pixels = _display_window(pixels, spec, path)
    pixels = _upright(pixels, attributes.get("Orientation", 1))
    info["size"] = pixels.shape[:2]
    if np.issubdtype(pixels.dtype, np.integer):
        info["max_code"] = int(np.iinfo(pixels.dtype).max)
        if normalise:
            scale = float(np.iinfo(pixels.dtype).max)
            pixels = (pixels.astype(np.float64) / scale).astype(np.float32)
        else:
            pixels = pixels.astype(np.float64 if pixels.dtype.itemsize >= 4 else np.float32)
    else:
        pixels = pixels.astype(np.float32, copy=False)
    return pixels, info


def _refuse_beyond_memory(spec, path: Path) -> None:
    """Refuse, from its header, an image whose pixels cannot be held here: a 4.6 MB PNG that
    says 40000 x 40000 was decoded in full (minutes, gigabytes, whatever ``--scale``), then
    failed with NumPy's or C++'s bare "bad_alloc"."""
    from clholo.errors import EnvironmentProblem
    from clholo._sysmem import available_host_bytes

    values = int(spec.width) * int(spec.height) * max(1, int(spec.depth)) * int(spec.nchannels)
    # the decoded values, then their float64 and float32 conversions (read_image's peak)
    need = values * (int(spec.format.size()) + 12)
    room = available_host_bytes()
    if need > room:
        raise EnvironmentProblem(
            f"image {path} is {spec.width} x {spec.height} pixels x {spec.nchannels} channels: "
            f"reading it needs {need / 2**30:.1f} GiB, more than the {room / 2**30:.1f} GiB of "
            f"memory available here (--scale applies after the read); make a smaller copy "
            f"first (e.g. `magick {path.name} -resize 25% smaller{path.suffix}`), or read it "
            f"on a machine with more memory")


# Subimages looked at for a second picture of the first one's size (a file with more is a
# stack either way: the message says "at least")
_MAX_SUBIMAGES_SEEN = 64


def _refuse_picture_stack(inp, spec, path: Path) -> None:
    """Refuse a file that holds more than one picture of its first one's size: pages of a
    multi-page TIFF (a stack of frames or layers), parts of a multi-part EXR (a stereo pair's
    two views, colour and depth in parts of their own). Only the first would be read, the rest
    dropped without a word. Smaller later subimages (a TIFF's thumbnail or reduced pages)
    are what viewers skip too: the first picture is the image."""
    size = (spec.width, spec.height)
    same, more = [0], True
    for index in range(1, _MAX_SUBIMAGES_SEEN):
        if not inp.seek_subimage(index, 0):
            more = False
            break
        sub = inp.spec()
        if (sub.width, sub.height) == size:
            same.append(index)
    inp.geterror()  # a failed seek past the last subimage is no error of the file
    if len(same) > 1:
        kind = ("parts of an EXR" if str(path).lower().endswith(".exr") else
                "pages" if str(path).lower().endswith((".tif", ".tiff")) else "subimages")
        count = f"at least {len(same)}" if more else len(same)
        raise ValueError(f"{path} holds {count} pictures of {size[0]}x{size[1]} ({kind}); "
                         f"clholo reads one picture per file and would drop the others: save "
                         f"the one you mean in a file of its own (for an MPI, one file per "
                         f"layer; for RGB-D, the image and its depth map)")


_HEIF_HINT = ("export the photo as JPEG or PNG (on an iPhone: Settings > Camera > Formats > "
              "Most Compatible, whose portrait JPEGs keep their depth map for clholo to read, "
              "or share it as JPEG), or convert it (heif-convert, ImageMagick)")
_RAW_HINT = ("develop the camera raw file to a 16-bit TIFF or PNG first (darktable, "
             "RawTherapee, dcraw -T -4)")
# Formats users bring that OpenImageIO's PyPI build reads only with plugins it may lack
_NO_READER_HINTS = {
    **{ext: _HEIF_HINT for ext in (".heic", ".heif", ".hif", ".avif")},
    **{ext: _RAW_HINT for ext in (".cr2", ".cr3", ".nef", ".arw", ".dng", ".raf", ".orf",
                                  ".rw2", ".pef", ".srw")},
}


def _has_reader(oiio, suffix: str) -> bool:
    """Whether OpenImageIO's build lists a reader for files ending in ``suffix``."""
    ext = suffix.lower().lstrip(".")
    for entry in oiio.get_string_attribute("extension_list").split(";"):
        _, _, exts = entry.partition(":")
        if ext in exts.lower().split(","):
            return True
    return False


# The largest field clholo renders, per axis (clholo.propagation.MAX_FFT_SIZE; imported from
# there, it would close an import cycle: clholo.propagation reaches this module)
_MAX_FIELD_SIDE = 8192


def _display_window(pixels: np.ndarray, spec, path=None) -> np.ndarray:
    """``pixels`` of the data window placed in the display window (an EXR's ``displayWindow``,
    what every viewer shows), 0 outside the data window as OpenEXR defines it: an EXR whose
    data window was cropped to its non-empty pixels (a compositor's "auto crop", a render
    region) would otherwise read as a smaller, shifted image.

    A display window wider or taller than both the data window and the largest field clholo
    renders (:data:`clholo.propagation.MAX_FFT_SIZE` per axis) is refused naming ``path``
    before anything is allocated: a 401-byte file whose display window says 60000 x 60000
    asked for 54 GiB of zeros ("Unable to allocate", read as this machine's fault)."""
    x, y, w, h = spec.x, spec.y, spec.width, spec.height
    fx, fy, fw, fh = spec.full_x, spec.full_y, spec.full_width, spec.full_height
    if (x, y, w, h) == (fx, fy, fw, fh) or fw <= 0 or fh <= 0:
        return pixels
    if (fw > max(w, _MAX_FIELD_SIDE)) or (fh > max(h, _MAX_FIELD_SIDE)):
        raise InputError(
            f"{path}: its display window is {fw} x {fh} pixels around a data window of "
            f"{w} x {h}, larger than the largest field clholo renders ({_MAX_FIELD_SIDE} "
            f"pixels per axis): the file's header is damaged, or the image is cropped from a "
            f"larger one; write it with a display window equal to its data window (e.g. "
            f"oiiotool IN --fullpixels -o OUT)")
    full = np.zeros((fh, fw, pixels.shape[2]), pixels.dtype)
    x0, y0 = max(x, fx), max(y, fy)
    x1, y1 = min(x + w, fx + fw), min(y + h, fy + fh)
    if x1 > x0 and y1 > y0:
        full[y0 - fy:y1 - fy, x0 - fx:x1 - fx] = pixels[y0 - y:y1 - y, x0 - x:x1 - x]
    return full


def _upright_header(path: PathLike) -> Tuple[int, Tuple[int, int]]:
    """An image file's stored EXIF/TIFF ``Orientation`` (1 when absent or not a number) and
    its upright ``(H, W)`` (as :func:`read_image` returns it), from its header alone."""
    oiio = _oiio()
    inp = oiio.ImageInput.open(str(path))
    if inp is None:
        raise ValueError(f"cannot read image {path}: "
                         f"{_one_line(oiio.geterror()) or 'unknown format'}")
    try:
        spec = inp.spec()
        try:
            turn = int(spec.get_int_attribute("Orientation", 1))
        except (TypeError, ValueError):
            turn = 1
        size = (spec.height, spec.width)
    finally:
        inp.close()
    return turn, (size[::-1] if turn in (5, 6, 7, 8) else size)


def _upright(pixels: np.ndarray, orientation) -> np.ndarray:
    """``pixels`` (H, W, C) turned as the EXIF/TIFF ``Orientation`` tag says (1 to 8), so that
    they come out as every viewer shows them: a phone photo held upright is stored sideways
    with Orientation 6 or 8. Other values (0, absent) mean "as stored", as they do to viewers.
    """
    try:
        orientation = int(orientation)
    except (TypeError, ValueError):
        return pixels
    turned = {
        2: lambda p: p[:, ::-1],                            # mirrored left-right
        3: lambda p: p[::-1, ::-1],                         # rotated 180 degrees
        4: lambda p: p[::-1, :],                            # mirrored top-bottom
        5: lambda p: p.transpose(1, 0, 2),                  # transposed
        6: lambda p: p[::-1].transpose(1, 0, 2),            # rotated 90 degrees clockwise
        7: lambda p: p[::-1, ::-1].transpose(1, 0, 2),      # transversed
        8: lambda p: p[:, ::-1].transpose(1, 0, 2),         # rotated 90 degrees anticlockwise
    }.get(orientation)
    return pixels if turned is None else np.ascontiguousarray(turned(pixels))


def refuse_complex(array: np.ndarray, source, what: str) -> None:
    """Refuse complex values where real ones are read (a depth map, an image, alpha): NumPy
    would drop the imaginary part with only a ``ComplexWarning``.

    Parameters
    ----------
    array : ndarray
        The values read.
    source : str or os.PathLike
        The file (or argument) they came from, for the message.
    what : str
        What they should be (``"depth map"``).
    """
    if np.iscomplexobj(array):
        raise ValueError(f"{source} holds complex numbers ({np.asarray(array).dtype}); a {what} "
                         f"is real: save the real values you mean (numpy: .real or abs())")


def grey_channel(pixels: np.ndarray, source, what: str, *, fix: str = "") -> np.ndarray:
    """The one channel of a grey map ``(H, W, C)``: ``C`` is 1, or every channel holds the same
    values (a grey image saved as RGB); channels that differ are refused, since which one
    would be meant is a guess (a colour-mapped picture of depth is not depth).

    Parameters
    ----------
    pixels : ndarray, shape (H, W, C)
        The channels to read (an alpha channel already taken out).
    source : str or os.PathLike
        The file, for the message.
    what : str
        What the map is (``"depth map"``, ``"alpha"``), for the message.
    fix : str
        What to do instead, appended to the message.

    Returns
    -------
    ndarray, shape (H, W)
    """
    pixels = np.asarray(pixels)
    if pixels.ndim == 2:
        return pixels
    first = pixels[..., :1]
    same = (pixels == first) | (np.isnan(pixels) & np.isnan(first)) \
        if np.issubdtype(pixels.dtype, np.floating) else pixels == first
    if pixels.shape[-1] > 1 and not np.all(same):
        differ = int(np.count_nonzero(~np.all(same, axis=-1)))
        raise ValueError(f"{source} has {pixels.shape[-1]} channels that differ ({differ} "
                         f"pixel(s)): a grey {what} is expected (one channel, or all channels "
                         f"equal){'; ' + fix if fix else ''}")
    return pixels[..., 0]


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


@contextlib.contextmanager
def atomic_path(path: PathLike) -> Iterator[Path]:
    """Yield a temporary file name beside ``path`` (same extension); rename it over ``path``
    when the block succeeds, delete it when the block raises (Ctrl-C included). The temporary
    file is locked while the block runs; those that runs which died left beside ``path`` are
    removed first (:func:`remove_abandoned_temporaries`).

    Raises
    ------
    FileNotFoundError
        The folder of ``path`` does not exist.
    IsADirectoryError
        ``path`` is a folder (found before the block runs, not at the rename after it).
    PermissionError
        Nothing can be created in the folder of ``path`` (the message names ``path``).
    """
    path = Path(path)
    parent = path.parent if str(path.parent) else Path(".")
    if not parent.is_dir():
        raise FileNotFoundError(f"cannot write {path}: folder {parent} does not exist")
    if path.is_dir() and not path.is_symlink():  # else found only at the rename, after the work
        raise IsADirectoryError(f"cannot write {path}: it is a folder; give a file name, e.g. "
                                f"{path / ('clholo-out' + path.suffix)}")
    remove_abandoned_temporaries(path, kind="file")
    fd, name = _make_temporary(path, parent, lambda: tempfile.mkstemp(
        prefix=f".{path.stem}.", suffix=f".tmp{path.suffix}", dir=str(parent)))
    tmp = Path(name)
    lock = None
    try:  # from here on an exception (Ctrl-C included) removes the temporary file
        os.close(fd)
        # held on the file (its inode: writers that open the name again keep it) until it is
        # renamed or removed: "not abandoned"
        lock = _lock_exclusive(tmp)
        # mkstemp makes the file private (0600); the finished file gets the usual permissions
        os.chmod(tmp, 0o666 & ~_umask())
        yield tmp
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            tmp.unlink()
        raise
    finally:
        if lock is not None:
            os.close(lock)


#: The bytes clholo's temporary names add to an output's name (``.NAME.XXXXXXXX.probe``).
TEMPORARY_NAME_BYTES = 16


def creation_failure(path: Path, parent: Path, exc: OSError, what: str) -> Optional[Exception]:
    """The error for a temporary name beside ``path`` that could not be made in ``parent``,
    where its cause is not a permission: a name too long once clholo's temporary names are
    added (the user's to shorten), a full disk (the machine's), a read-only file system. None
    for the rest (each caller words its "not writable" its own way). ``what`` names the
    destination (``--out``, ``cannot write``)."""
    if exc.errno == errno.ENAMETOOLONG:
        try:
            name_max = int(os.pathconf(str(parent), "PC_NAME_MAX"))
        except (OSError, ValueError):
            name_max = 255
        return InputError(
            f"{what} {path}: its name is {len(os.fsencode(path.name))} bytes, and the "
            f"temporary name clholo writes first beside it would be longer than the file "
            f"system's {name_max}; give a name of at most {name_max - TEMPORARY_NAME_BYTES} "
            f"bytes")
    if exc.errno == errno.ENOSPC:
        from clholo.errors import EnvironmentProblem

        return EnvironmentProblem(f"{what} {path}: no space left on the device of {parent}; "
                                  f"free some, or choose a folder on another disk")
    if exc.errno == errno.EROFS:
        return PermissionError(f"{what} {path}: {parent} is on a read-only file system; "
                               f"choose a folder you can write to")
    return None


def _make_temporary(path: Path, parent: Path, make):
    """``make()`` (``mkstemp``/``mkdtemp`` in ``parent``), its failure told as the destination
    ``path`` that cannot be written, not as the temporary name nobody asked for."""
    try:
        return make()
    except OSError as exc:
        failure = creation_failure(path, parent, exc, "cannot write")
        if failure is not None:
            raise failure from None
        raise PermissionError(
            f"cannot write {path}: nothing can be created in {parent} "
            f"({exc.strerror or exc}); choose a folder you can write to") from None


# renameat2's flag and "the current directory" for its folder arguments (linux/fs.h, fcntl.h)
_RENAME_EXCHANGE = 2
_AT_FDCWD = -100


@functools.lru_cache(maxsize=None)
def _renameat2():
    """glibc's ``renameat2`` (Linux, glibc >= 2.28), or None where there is none."""
    if not sys.platform.startswith("linux"):
        return None
    try:
        fn = ctypes.CDLL(None, use_errno=True).renameat2
    except (OSError, AttributeError):
        return None
    fn.argtypes = [ctypes.c_int, ctypes.c_char_p, ctypes.c_int, ctypes.c_char_p, ctypes.c_uint]
    fn.restype = ctypes.c_int
    return fn


def exchange_paths(a: PathLike, b: PathLike) -> bool:
    """Swap what the names ``a`` and ``b`` (both existing, one file system) point to in one
    step: Linux's ``renameat2(RENAME_EXCHANGE)``. Returns False, having changed nothing, where
    the system or the file system cannot (other systems, old kernels, some network file
    systems); other failures raise ``OSError`` naming ``b``.

    Why: replacing a folder by renames alone takes two (the old one aside, the new one in),
    and between them the destination does not exist for whoever reads it; an exchange leaves
    no such moment.
    """
    fn = _renameat2()
    if fn is None:
        return False
    if fn(_AT_FDCWD, os.fsencode(os.fspath(a)), _AT_FDCWD, os.fsencode(os.fspath(b)),
          _RENAME_EXCHANGE) == 0:
        return True
    err = ctypes.get_errno()
    if err in (errno.EINVAL, errno.ENOSYS, errno.EOPNOTSUPP, errno.ENOTSUP):
        return False
    raise OSError(err, os.strerror(err), os.fspath(b))


def replace_path(new: PathLike, path: PathLike, *, aside: Optional[PathLike] = None) -> None:
    """Rename ``new`` (a finished folder or file) to ``path``, replacing what is there; a
    failure (Ctrl-C included) leaves the old or the new one whole at ``path``, never neither.

    Where :func:`exchange_paths` can, the two swap in one step and ``path`` never stops
    existing; elsewhere the old one is moved aside first (a brief moment without ``path``)
    and put back if the second rename fails. The old one is then removed.

    Parameters
    ----------
    new, path : path-like
        The finished item and its destination, on one file system.
    aside : path-like, optional
        Where the old one waits when two renames are needed (a name that does not exist, on
        the same file system); default a fresh hidden name beside ``path``.
    """
    new, path = Path(new), Path(path)
    if not (path.exists() or path.is_symlink()):
        os.replace(new, path)
        return
    if exchange_paths(new, path):
        old = new  # the name new now holds what was at path
    else:
        if aside is None:
            old = Path(tempfile.mkdtemp(prefix=f".{path.name}.", suffix=".old",
                                        dir=str(path.parent)))
            os.rmdir(old)
        else:
            old = Path(aside)
        os.replace(path, old)
        try:
            os.replace(new, path)
        except BaseException:
            os.replace(old, path)
            raise
    if old.is_dir() and not old.is_symlink():
        shutil.rmtree(old, ignore_errors=True)
    else:
        with contextlib.suppress(OSError):
            old.unlink()


#: A temporary folder of :func:`atomic_directory` (or file of :func:`atomic_path`) unchanged
#: for this long, whose lock nobody holds, was left by a run that died (SIGKILL, power loss):
#: the next write of the same destination removes it.
ABANDONED_AFTER_S = 60.0
# tempfile's names: 8 characters of this alphabet between the prefix and the suffix
_TEMPORARY_NAME = "abcdefghijklmnopqrstuvwxyz0123456789_"


def _lock_exclusive(path) -> Optional[int]:
    """A descriptor holding an exclusive ``flock`` on the folder or file ``path`` (released
    when closed), or None: another process holds it, or the system cannot lock it (Windows;
    some network file systems), where nothing is ever taken for abandoned."""
    try:
        import fcntl
    except ImportError:
        return None
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:
        return None
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        os.close(fd)
        return None
    return fd


def remove_abandoned_temporaries(path: PathLike, *, kind: str = "folder") -> list:
    """Remove the temporary folders (or files) of ``path`` that a run which died left beside it.

    :func:`atomic_directory` builds ``path`` as ``.NAME.XXXXXXXX.tmp`` beside it, and
    :func:`atomic_path` writes ``STEM.EXT`` as ``.STEM.XXXXXXXX.tmp.EXT``; both remove theirs on
    any exception, Ctrl-C and SIGTERM included. A run killed outright (SIGKILL, an out-of-memory
    kill, power loss) cannot, and its folder (gigabytes for a large render) or file stayed
    hidden there. Its writer holds an exclusive ``flock`` on it for as long as it lives, so one
    of that name that nobody holds a lock on, unchanged for :data:`ABANDONED_AFTER_S`, is an
    abandoned one. One that is locked, recent, not of that exact name, of the other kind, or on
    a system that cannot lock is left alone (as are ``.old`` folders: one of those may hold the
    only copy of an earlier output).

    Parameters
    ----------
    path : path-like
        The destination.
    kind : {"folder", "file"}
        What ``path`` is written as: the temporaries of :func:`atomic_directory` or of
        :func:`atomic_path`.

    Returns
    -------
    list of pathlib.Path
        What was removed.
    """
    if kind not in ("folder", "file"):
        raise ValueError(f"kind must be 'folder' or 'file', got {kind!r}")
    path = Path(path)
    parent = path.parent if str(path.parent) else Path(".")
    if kind == "folder":
        head, tail = f".{path.name}.", ".tmp"
    else:
        head, tail = f".{path.stem}.", f".tmp{path.suffix}"
    removed = []
    try:
        entries = list(os.scandir(parent))
    except OSError:
        return removed
    now = time.time()
    for entry in entries:
        name = entry.name
        middle = name[len(head):len(name) - len(tail)]
        if not (name.startswith(head) and name.endswith(tail) and len(middle) == 8
                and all(c in _TEMPORARY_NAME for c in middle)):
            continue
        try:
            is_kind = entry.is_dir(follow_symlinks=False) if kind == "folder" else \
                entry.is_file(follow_symlinks=False)
            if not is_kind or \
                    now - entry.stat(follow_symlinks=False).st_mtime < ABANDONED_AFTER_S:
                continue
        except OSError:
            continue
        fd = _lock_exclusive(entry.path)
        if fd is None:  # its writer is alive (or the system cannot tell)
            continue
        try:
            if kind == "folder":
                shutil.rmtree(entry.path, ignore_errors=True)
            else:
                os.unlink(entry.path)
            removed.append(Path(entry.path))
        except OSError:
            continue
        finally:
            os.close(fd)
    return removed


@contextlib.contextmanager
def atomic_directory(path: PathLike, *, overwrite: bool = False) -> Iterator[Path]:
    """Yield a fresh temporary folder beside ``path``; move it to ``path`` when the block
    succeeds, remove it when the block raises. An existing ``path`` is replaced only with
    ``overwrite=True``, only after the new folder is complete, and where the system can in
    one step, so that ``path`` never stops existing (:func:`replace_path`). The temporary
    folder is locked while it is written; those of earlier runs that died are removed first
    (:func:`remove_abandoned_temporaries`)."""
    path = Path(path)
    parent = path.parent if str(path.parent) else Path(".")
    if not parent.is_dir():
        raise FileNotFoundError(f"cannot write {path}: folder {parent} does not exist")
    if path.exists() and not overwrite:
        raise FileExistsError(f"{path} already exists; pass overwrite=True to replace it")
    remove_abandoned_temporaries(path)
    tmp = Path(_make_temporary(path, parent, lambda: tempfile.mkdtemp(
        prefix=f".{path.name}.", suffix=".tmp", dir=str(parent))))
    lock = _lock_exclusive(tmp)  # held until the folder is in place (or gone): "not abandoned"
    try:
        os.chmod(tmp, 0o777 & ~_umask())  # mkdtemp makes it private (0700)
        yield tmp
        replace_path(tmp, path)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    finally:
        if lock is not None:
            os.close(lock)


# write_image's encoding -> OpenImageIO's oiio:ColorSpace (3.x names; "raw": no statement)
_ENCODING_COLORSPACE = {"srgb": "srgb_rec709_scene", "linear": "lin_rec709_scene",
                        "data": "raw"}


def _check_pixels_for(pixels: np.ndarray, dtype: str, np_type) -> None:
    """Refuse what write_image would store as something else without a word: integer codes
    of another width than the stored type's (they were clipped to [0, 1]: every code >= 1
    white), NaN in integer formats (stored as 0), floats beyond the stored float's range
    (stored as inf)."""
    integer_out = np.issubdtype(np_type, np.integer)
    if np.issubdtype(pixels.dtype, np.integer) and pixels.dtype != np_type and integer_out:
        raise InputError(
            f"pixels are {pixels.dtype} codes but dtype={dtype!r} stores 0..{np.iinfo(np_type).max}:"
            f" give {dtype} codes (pixels.astype(np.{dtype}) when they already span that "
            f"range), or floats in [0, 1]")
    if pixels.dtype.kind == "f" and pixels.size:
        if integer_out and np.isnan(pixels).any():
            raise InputError(f"pixels hold NaN, which dtype={dtype!r} cannot store (it would "
                             f"be 0): replace them first (numpy.nan_to_num)")
        if not integer_out:
            top = float(np.finfo(np_type).max)
            finite = pixels[np.isfinite(pixels)]
            if finite.size and float(np.abs(finite).max()) > top:
                raise InputError(f"pixels reach {float(np.abs(finite).max()):.4g}, beyond "
                                 f"dtype={dtype!r}'s largest value {top:.4g} (it would store "
                                 f"inf): scale them, or use dtype='float'")


def write_image(path: PathLike, pixels: np.ndarray, *, dtype: str = "float",
                channel_names: Optional[Tuple[str, ...]] = None,
                straight_alpha: bool = True, attributes: Optional[dict] = None,
                encoding: Optional[str] = None, atomic: bool = True) -> None:
    """Write ``pixels`` (H, W, C) to ``path`` exactly as given (no colour conversion).

    Parameters
    ----------
    path : path-like
        Output file; the extension picks the format.
    pixels : ndarray, shape (H, W, C) or (H, W)
        Values in [0, 1] for integer formats (they are rounded to the nearest code), or codes
        of the stored type itself (``uint8`` pixels for ``dtype="uint8"``, ``uint16`` for
        ``"uint16"``), written as they are; any float for ``dtype="float"``/``"half"``.
    dtype : {"float", "half", "uint8", "uint16"}
        Stored pixel type.
    channel_names : tuple of str, optional
        Default ``R, G, B, A`` style names for 1 to 4 channels.
    straight_alpha : bool
        True: the alpha channel is straight (not premultiplied); the writer is told so that
        it does not un-premultiply the colour (OpenImageIO's PNG writer would).
    attributes : dict, optional
        Extra header attributes (str, int, float or float sequences).
    encoding : {"srgb", "linear", "data"}, optional
        What the file says its values are, for the viewers that read it (the values are
        written as given either way): ``"srgb"`` (a PNG gets an ``sRGB`` chunk), ``"linear"``
        (a PNG gets a ``gAMA`` chunk of gamma 1, so that viewers do not show linear values
        as if they were sRGB), ``"data"`` (codes that are no colour, e.g. SLM phase levels:
        no colour statement). Default: the format's own (PNG, JPEG, TIFF: sRGB; EXR: linear).
    atomic : bool
        Write to a temporary name and rename when complete (default).
    """
    from clholo.errors import InputTypeError

    oiio = _oiio()
    pixels = np.asarray(pixels)
    if pixels.ndim == 2:
        pixels = pixels[..., None]
    if pixels.ndim != 3:
        raise InputError(f"pixels must have shape (H, W) or (H, W, C), got {pixels.shape}")
    if not (np.issubdtype(pixels.dtype, np.number) or pixels.dtype == bool) \
            or np.iscomplexobj(pixels):
        raise InputTypeError(f"pixels must be real numbers, got {pixels.dtype}")
    h, w, c = pixels.shape
    types = {"float": ("float", np.float32), "half": ("half", np.float16),
             "uint8": ("uint8", np.uint8), "uint16": ("uint16", np.uint16)}
    if dtype not in types:
        raise ValueError(f"dtype must be one of {sorted(types)}, got {dtype!r}")
    oiio_type, np_type = types[dtype]
    _check_pixels_for(pixels, dtype, np_type)
    if channel_names is not None and len(channel_names) != c:
        raise InputError(f"channel_names has {len(channel_names)} name(s) but pixels have {c} "
                         f"channel(s): give one name per channel")
    if encoding is not None and encoding not in _ENCODING_COLORSPACE:
        raise ValueError(f"encoding must be one of {sorted(_ENCODING_COLORSPACE)} or None "
                         f"(the format's default), got {encoding!r}")
    if pixels.dtype == np_type:
        data = pixels  # codes (or floats) of the stored type: nothing to convert
    elif np.issubdtype(np_type, np.integer):
        top = np.iinfo(np_type).max
        data = np.round(np.clip(pixels.astype(np.float64), 0.0, 1.0) * top).astype(np_type)
    else:
        data = pixels.astype(np_type)
    spec = oiio.ImageSpec(w, h, c, oiio_type)
    if channel_names is None:
        channel_names = {1: ("Y",), 2: ("Y", "A"), 3: ("R", "G", "B"),
                         4: ("R", "G", "B", "A")}.get(c, tuple(f"c{i}" for i in range(c)))
    spec.channelnames = tuple(channel_names)
    if "A" in channel_names:
        spec.alpha_channel = list(channel_names).index("A")
        if straight_alpha:
            spec.attribute("oiio:UnassociatedAlpha", 1)
    if encoding is not None:  # OpenImageIO's PNG writer turns it into sRGB / gAMA chunks
        spec.attribute("oiio:ColorSpace", _ENCODING_COLORSPACE[encoding])
    for key, value in (attributes or {}).items():
        if isinstance(value, (str, int, float, np.integer, np.floating)):
            spec.attribute(key, value.item() if isinstance(value, np.generic) else value)
        else:  # a float sequence (OpenEXR's chromaticities: float[8]) needs its type named
            values = tuple(float(v) for v in np.ravel(value))
            spec.attribute(key, oiio.TypeDesc(f"float[{len(values)}]"), values)

    def _write(target: Path) -> None:
        out = oiio.ImageOutput.create(str(target))
        if out is None:
            raise ValueError(f"cannot write {path}: {oiio.geterror() or 'unknown format'}")
        closed = False
        try:
            if not out.open(str(target), spec):
                raise ValueError(f"cannot open {path} for writing: {_one_line(out.geterror())}")
            written = out.write_image(np.ascontiguousarray(data))
            # the PNG writer says True to a short write and leaves the error text behind
            error = _one_line(out.geterror())
            closed = True
            written = out.close() and written
            error = error or _one_line(out.geterror())
            if not written or error:
                failure = write_failure(path, target, error[:200] or "the writer failed")
                if failure is not None:
                    raise failure
                raise ValueError(f"cannot write pixels to {path}: {error or 'the writer failed'}")
        finally:
            if not closed:
                out.close()

    if atomic:
        with atomic_path(path) as tmp:
            _write(tmp)
    else:
        _write(Path(path))
