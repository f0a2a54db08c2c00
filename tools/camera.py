"""Camera hooks for the capture sweeps.

A camera is anything with ``capture(path, info) -> Path``: take one image now, write it to
``path`` (the extension may be changed by the camera; the written path is returned) and return.
``info`` says what is on the SLM and where the stage is (for cameras that want to record it).

* :class:`FileCamera`: the default without hardware. It writes what a ``source`` callable returns
  as an 8-bit (``uint8`` input) or 16-bit (other input, scaled to [0, 1] by its maximum) PNG; the
  default source is the display's screen, so on a :class:`~clholo.tools.slm.MemoryDisplay` the
  images are the exact levels on the SLM at capture time. For the bench, give a source that reads
  the real sensor (or use :class:`OpenCVCamera`).
* :class:`OpenCVCamera`: a UVC camera through OpenCV's ``VideoCapture`` (``pip install
  'clholo[camera]'``); OpenCV is imported when the camera opens, never at module load.
"""

from __future__ import annotations

from pathlib import Path
from typing import Callable, Optional, Protocol, runtime_checkable

import numpy as np

__all__ = ["Camera", "FileCamera", "OpenCVCamera", "check_frame"]


@runtime_checkable
class Camera(Protocol):
    """What the capture sweeps need of a camera: ``capture(path, info) -> Path``
    (:class:`FileCamera`, :class:`OpenCVCamera`, or any object with that method)."""
    def capture(self, path: Path, info: dict) -> Path:
        """Take one image, write it to ``path`` (PNG), return the path written.

        Parameters
        ----------
        path : pathlib.Path
            Where to write the image.
        info : dict
            What is shown and where the stage is (position, frame, channel), for the camera's own
            records.

        Returns
        -------
        pathlib.Path
        """


def _where(info) -> str:
    """Where a capture happened, from the ``info`` a sweep passes (position index and mm,
    frame ``t``, colour ``c``), for messages; empty without one."""
    if not isinstance(info, dict):
        return ""
    parts = []
    if "index" in info:
        mm = info.get("position_mm")
        parts.append(f"position index {info['index']}"
                     + (f" ({mm:.4g} mm)" if isinstance(mm, (int, float)) else ""))
    parts += [f"{word} {k}={info[k]}" for k, word in (("t", "frame"), ("c", "colour"))
              if k in info]
    return f" at {', '.join(parts)}" if parts else ""


def check_frame(frame, *, name: str = "frame") -> np.ndarray:
    """Refuse what cannot be written as a camera image: anything but a non-empty NumPy array
    ``[H, W]`` or ``[H, W, C]`` (C = 1 to 4) of finite real numbers.

    Parameters
    ----------
    frame : numpy.ndarray
        The image.
    name : str
        What produced it, named in refusals (e.g. the camera's source and where in a sweep).

    Returns
    -------
    numpy.ndarray
        ``frame``, unchanged.

    Raises
    ------
    clholo.errors.InputTypeError
        Not a NumPy array (``None``: the source returned nothing), or not real numbers.
    clholo.errors.InputError
        Not 2-D or 3-D with 1 to 4 channels, empty, or holding NaN/inf.
    """
    from clholo.errors import InputError, InputTypeError

    want = "a NumPy array [H, W] or [H, W, C] of real numbers (uint8 levels, or any other"\
           " numbers, scaled by their maximum)"
    if not isinstance(frame, np.ndarray):
        got = "None" if frame is None else f"a {type(frame).__name__}"
        raise InputTypeError(f"{name} returned {got}: a frame must be {want}")
    if frame.dtype == np.bool_ or not (np.issubdtype(frame.dtype, np.integer)
                                       or np.issubdtype(frame.dtype, np.floating)):
        raise InputTypeError(f"{name} returned a frame of dtype {frame.dtype}: a frame must be "
                             f"{want}")
    if frame.ndim not in (2, 3) or (frame.ndim == 3 and not 1 <= frame.shape[2] <= 4):
        raise InputError(f"{name} returned a frame of shape {frame.shape}: a frame must be "
                         f"{want}, with C = 1 to 4 channels")
    if frame.size == 0:
        raise InputError(f"{name} returned an empty frame (shape {frame.shape}): a frame must "
                         f"be {want}")
    if np.issubdtype(frame.dtype, np.floating):
        bad = int(np.count_nonzero(~np.isfinite(frame)))
        if bad:
            # written, NaN would become 0 with only a NumPy warning: a black image that looks
            # like a dark capture
            raise InputError(f"{name} returned a frame with {bad} NaN/inf pixel(s) of "
                             f"{frame.size}: a frame must hold finite numbers (a failed "
                             f"read-out? check the sensor source)")
    return frame


def _write_png(path: Path, image: np.ndarray) -> Path:
    from clholo.io.images import write_image

    image = np.asarray(image)
    path = Path(path).with_suffix(".png")
    if image.dtype == np.uint8:
        write_image(path, image, dtype="uint8")  # levels written as they are
    else:
        image = image.astype(np.float64)
        top = float(image.max()) if image.size and image.max() > 0 else 1.0
        write_image(path, image / top, dtype="uint16")
    return path


class FileCamera:
    """Writes what ``source()`` returns ([H, W] or [H, W, C]) as a PNG for every capture.

    Parameters
    ----------
    source : callable or None
        Returns the image, a NumPy array ``[H, W]`` or ``[H, W, C]`` (C = 1 to 4) of finite
        real numbers (:func:`check_frame`); None means ``display.screen`` of the ``display``
        given.
    display : Display or None
        Used when ``source`` is None.

    Raises
    ------
    clholo.errors.InputTypeError
        ``source`` is not callable.
    ValueError
        Neither a ``source`` nor a display with a ``screen``.
    """

    def __init__(self, source: Optional[Callable[[], np.ndarray]] = None, *, display=None):
        if source is None:
            if display is None or not hasattr(display, "screen"):
                raise ValueError("FileCamera needs a source callable, or a display with a "
                                 "'screen' (MemoryDisplay) to record")
            source = lambda: display.screen  # noqa: E731
            self._name = "FileCamera(display=...) screen"
        elif not callable(source):
            from clholo.errors import InputTypeError

            raise InputTypeError(f"FileCamera source must be a callable that returns the image "
                                 f"(a NumPy array [H, W] or [H, W, C]), got "
                                 f"{type(source).__name__}: pass the function itself, e.g. "
                                 f"source=sensor.read, not its result")
        else:
            label = getattr(source, "__qualname__", None) or repr(source)
            self._name = f"FileCamera source {label}"
        self.source = source
        self.count = 0

    def capture(self, path: Path, info: dict) -> Path:
        """Write the source's current image (e.g. a :class:`MemoryDisplay`'s screen) to ``path``
        as PNG; ``info`` (what a sweep says of the capture) only names the place in refusals.
        Returns the path written.

        Raises
        ------
        clholo.errors.InputTypeError, clholo.errors.InputError
            The source returned something that is not an image (:func:`check_frame`), naming
            the source and, in a sweep, the position index, frame and colour.
        """
        name = getattr(self, "_name", "FileCamera source")
        frame = check_frame(self.source(), name=f"{name}{_where(info)}")
        out = _write_png(Path(path), frame)
        self.count += 1
        return out


class OpenCVCamera:
    """A UVC camera through ``cv2.VideoCapture(device)``; grayscale frames as 8-bit PNG.

    Parameters
    ----------
    device : int
        OpenCV's camera index.
    width, height : int, optional
        Frame size to ask the camera for, pixels.
    flush : int
        Buffered frames dropped before each capture (exposed before the pattern settled).
    """

    def __init__(self, device: int = 0, *, width: Optional[int] = None,
                 height: Optional[int] = None, flush: int = 2):
        from clholo.errors import require_extra

        cv2 = require_extra("cv2", "camera", "OpenCVCamera (opencv-python-headless)")
        self._cv2 = cv2
        self._cap = cv2.VideoCapture(int(device))
        if not self._cap.isOpened():
            from clholo.errors import EnvironmentProblem

            raise EnvironmentProblem(f"camera device {device} did not open: check the cable and "
                               f"that no other program holds it")
        if width:
            self._cap.set(cv2.CAP_PROP_FRAME_WIDTH, int(width))
        if height:
            self._cap.set(cv2.CAP_PROP_FRAME_HEIGHT, int(height))
        self.flush = int(flush)
        self.device = int(device)

    def capture(self, path: Path, info: dict) -> Path:
        """Grab a fresh frame (after dropping ``flush`` buffered ones) and write it to ``path``
        with a ``.png`` suffix, under a temporary name renamed when complete (an interrupted
        write leaves no half-written PNG); ``info`` (a sweep's position index, frame, colour)
        only names where a missing frame was asked for. Returns the path written.
        """
        from clholo.io.images import atomic_path

        # UVC cameras buffer frames: drop the ones exposed before the pattern settled
        for _ in range(self.flush):
            self._cap.grab()
        ok, frame = self._cap.read()
        if not ok:
            from clholo.errors import EnvironmentProblem

            raise EnvironmentProblem(
                f"camera device {self.device} ([camera] device in the bench file) returned no "
                f"frame{_where(info)}: unplugged, or another program took it? Check the cable "
                f"and run again")
        path = Path(path).with_suffix(".png")
        with atomic_path(path) as tmp:  # same extension: imwrite picks the format by it
            if not self._cv2.imwrite(str(tmp), frame):
                raise OSError(f"could not write {path}: OpenCV's imwrite failed (disk full, or "
                              f"a frame OpenCV cannot encode as PNG)")
        return path

    def close(self) -> None:
        """Release the camera."""
        self._cap.release()
