"""One validator for the units, ranges and counts that every public entry point takes.

Every function here raises :class:`clholo.errors.InputTypeError` (a ``TypeError``) or
:class:`clholo.errors.InputError` (a ``ValueError``) whose message starts with the argument's
name, says what it got, and says what to give instead (with the unit hint: clholo's lengths are
metres). :class:`clholo.Optics`, :func:`clholo.propagate`, the renderer, the operators and the CLI
all call these, so one wrong unit gets the same message wherever it enters.

The bounds are physical, not arbitrary:

* a wavelength is one a holographic display can use, ultraviolet to near infrared:
  [0.2 um, 2 um] in metres (:data:`MIN_WAVELENGTH_M`, :data:`MAX_WAVELENGTH_M`); a number far
  outside is almost always a unit slip (``520`` for ``520e-9``, ``1e-9`` for ``1e-6``) and the
  message names the likely value;
* a pitch is an SLM or sensor pixel in metres: (0, 1 mm];
* a wavelength must be below twice the pitch, or no angle but zero can be diffracted;
* a distance or depth of more than 1 m behind a display a few millimetres thick is almost always
  a scene unit taken for metres: accepted, with a :class:`DepthWarning`.
"""

from __future__ import annotations

import contextlib
import numbers
import os
import sys
import threading
import warnings
from typing import Optional, Sequence, Tuple

import numpy as np

from clholo.errors import InputError, InputTypeError

__all__ = ["DepthWarning", "warn_at_caller", "real_scalar", "wavelength", "wavelengths", "pitch",
           "wavelength_for_pitch", "distance", "depths", "seed", "count", "optional_count",
           "flag", "pad", "queue", "alpha_cut", "is_whole", "stream_index", "frame_range"]

# the wavelengths a holographic display can use: UV lasers (~250 nm) to near-infrared (~1.6 um);
# outside, no SLM, laser or camera of a display bench works, and the number is a unit slip
MIN_WAVELENGTH_M = 2e-7
MAX_WAVELENGTH_M = 2e-6
MAX_PITCH_M = 1e-3
# half the shortest wavelength: a finer pitch carries nothing more (every propagating frequency
# fits already), and 8e-9 for 8 um (nanometres for micrometres) is a unit slip
MIN_PITCH_M = MIN_WAVELENGTH_M / 2
FAR_DEPTH_M = 1.0
# beyond a kilometre no optical bench propagates, and far beyond it (1e150 m) the band limit's
# arithmetic overflows: refused, where up to here it is a warning
MAX_DISTANCE_M = 1e3
#: The fewest pixels a scene may have on its shorter side after ``--scale`` (a focal stack of
#: a few pixels shows nothing a person could judge): ``clholo.io.load.scaled_size``,
#: ``clholo.demo`` and ``clholo.io.splats.check_camera_renders`` use it.
MIN_SCENE_PIXELS = 16
# Frames, layers and colours of the random phase stream are 32-bit Philox counter words
# (clholo.random): frame, layer or colour 2**32 would be index 0's phases again
STREAM_INDICES = 2 ** 32


class DepthWarning(UserWarning):
    """A distance or depth larger than 1 m: probably scene units rather than metres."""


def real_scalar(name: str, value, *, fix: Optional[str] = None) -> float:
    """``value`` as a finite Python float; ``bool`` and strings are refused.

    Parameters
    ----------
    name : str
        The argument's name, for the message.
    value : float, int or NumPy scalar
        A real number (any unit: the caller's).
    fix : str, optional
        What to give instead, appended to the message (``"give seconds > 0, e.g. 0.5"``).

    Returns
    -------
    float
        ``float(value)``, finite.

    Raises
    ------
    clholo.errors.InputTypeError
        A bool, a string or anything ``float()`` does not take (a ``TypeError``).
    clholo.errors.InputError
        NaN or infinity (a ``ValueError``).
    """
    tail = f": {fix}" if fix else ""
    if isinstance(value, (bool, np.bool_)) or isinstance(value, (str, bytes)):
        raise InputTypeError(f"{name} must be a real number, got {value!r}{tail}")
    try:
        out = float(value)
    except (TypeError, ValueError):
        raise InputTypeError(f"{name} must be a real number, got {value!r}{tail}") from None
    if not np.isfinite(out):
        raise InputError(f"{name} must be finite, got {value!r}{tail}")
    return out


def bench_metres(name: str, value, *, example: str) -> float:
    """A lab-bench distance in metres: finite, > 0 and at most 1 m.

    The bench file (``clholo bench``'s ``[sweep]`` and ``[...] distance_m``) and the capture
    sweeps' Python API check their metres with this one rule, so that both refuse the same
    values. A value above a metre is taken for millimetres.

    Parameters
    ----------
    name : str
        The argument's or key's name, for the message (its last word is the one named as
        being in metres).
    value : float
        The distance, metres.
    example : str
        A correct value to show, e.g. ``"distance_m=0.2 for 200 mm"``.

    Returns
    -------
    float
        ``0 < value <= 1``, metres.

    Raises
    ------
    clholo.errors.InputTypeError
        Not a real number.
    clholo.errors.InputError
        NaN, infinite, <= 0, or more than a metre.
    """
    x = real_scalar(name, value)
    if x <= 0:
        raise InputError(f"{name} = {value!r} must be > 0 metres, e.g. {example}")
    if x > 1.0:
        raise InputError(f"{name} = {value!r} is more than a metre: {name.split()[-1]} is in "
                         f"metres (millimetres given?); write e.g. {example}")
    return x


def _short(v: float) -> str:
    """``1e-06`` as ``1e-6``, ``5.2e-07`` as ``5.2e-7`` (how people write metres)."""
    import re

    return re.sub(r"e([+-])0*(\d)", lambda m: "e" + ("-" if m.group(1) == "-" else "") + m.group(2),
                  f"{v:.4g}")


def _likely_wavelength(w: float) -> Optional[float]:
    """The wavelength ``w`` probably meant: ``w`` times a power of 1000 that lands in range."""
    for factor in (1e3, 1e-3, 1e6, 1e-6, 1e-9, 1e9, 1e12, 1e-12):
        v = float(f"{w * factor:.12g}")  # 1e-9 * 1e3 is 1.0000000000000002e-06
        if MIN_WAVELENGTH_M <= v <= MAX_WAVELENGTH_M:
            return v
    return None


def wavelength(value, *, name: str = "wavelength") -> float:
    """A wavelength in metres, ``0.2 um <= w <= 2 um`` (what a holographic display can use).

    Parameters
    ----------
    value : float
        Wavelength in metres (SI), e.g. ``520e-9`` for green.
    name : str
        The argument's name, for the message.

    Returns
    -------
    float
        The wavelength in metres, in ``[MIN_WAVELENGTH_M, MAX_WAVELENGTH_M]`` (2e-7..2e-6 m).

    Raises
    ------
    clholo.errors.InputTypeError
        Not a real number.
    ValueError
        Not positive, or outside 0.2-2 um: nanometres given as metres (``520``) are named as
        such; another slip by a power of 1000 is named with the value probably meant
        (``1e-9``: "did you mean 1e-6?").
    """
    w = real_scalar(name, value)
    if w <= 0:
        raise InputError(f"{name} must be a positive length in metres (e.g. 520e-9), got {value!r}")
    if 100 <= w <= 20000:  # nanometres given as metres: the most common slip
        raise InputError(
            f"{name}={value!r} is not a wavelength in metres: give it in metres, e.g. 520e-9 for "
            f"green ({w:g} nm is {w * 1e-9:g} m)")
    if not MIN_WAVELENGTH_M <= w <= MAX_WAVELENGTH_M:
        likely = _likely_wavelength(w)
        hint = f": did you mean {_short(likely)}?" if likely is not None else \
            ": give metres, e.g. 520e-9 for green"
        raise InputError(
            f"{name}={_short(w)} m is outside 0.2-2 um, the wavelengths a holographic display "
            f"can use{hint}")
    return w


def wavelengths(values, *, name: str = "wavelengths") -> Tuple[float, ...]:
    """One or more wavelengths in metres, as a tuple of floats.

    Parameters
    ----------
    values : float or sequence of float, shape ``(C,)``
        One wavelength per colour channel, metres (SI); a single number is one channel.
    name : str
        The argument's name, for the message.

    Returns
    -------
    tuple of float, length ``C >= 1``
        Each checked by :func:`wavelength` (metres, 0.2-2 um).

    Raises
    ------
    clholo.errors.InputTypeError
        A string, or an entry that is not a real number.
    ValueError
        No wavelength, more than one dimension, or an entry :func:`wavelength` refuses.
    """
    if isinstance(values, (str, bytes)):
        raise InputTypeError(f"{name} must be numbers in metres, got {values!r}")
    arr = np.atleast_1d(np.asarray(values, dtype=object))
    if arr.ndim != 1 or arr.size == 0:
        raise InputError(f"{name} must name at least one wavelength in metres, got {values!r}")
    return tuple(wavelength(w, name=name) for w in arr)


def pitch(value, *, name: str = "pitch") -> float:
    """A pixel pitch in metres, ``0.1 um <= p <= 1 mm``.

    Parameters
    ----------
    value : float
        The SLM's or sensor's pixel pitch, metres (SI), e.g. ``8e-6`` for 8 um.
    name : str
        The argument's name, for the message.

    Returns
    -------
    float
        The pitch in metres, ``MIN_PITCH_M <= p <= MAX_PITCH_M`` (1e-7 .. 1e-3 m).

    Raises
    ------
    clholo.errors.InputTypeError
        Not a real number.
    ValueError
        Not positive, below 0.1 um (half the shortest wavelength: a unit slip, nanometres
        for micrometres), or above a millimetre (micrometres given as metres).
    """
    p = real_scalar(name, value)
    if p <= 0:
        raise InputError(f"{name} must be a positive length in metres (e.g. 8e-6), got {value!r}")
    if p < MIN_PITCH_M:
        raise InputError(
            f"{name}={value!r} m is below {MIN_PITCH_M * 1e6:g} um, half the shortest "
            f"wavelength clholo takes: give it in metres (8e-6 for 8 um)")
    if p > MAX_PITCH_M:
        raise InputError(
            f"{name}={value!r} m is larger than a millimetre: give it in metres (8e-6 for 8 um)")
    return p


def wavelength_for_pitch(w: float, p: float, *, name: str = "wavelength") -> None:
    """Refuse a wavelength of at least twice the pitch: nothing but the zero order diffracts.

    A wavelength between one and two pitches is physical and accepted: the grating equation
    ``sin(theta) = lambda / (2 p)`` still has a solution below 90 degrees.

    Parameters
    ----------
    w : float
        Wavelength, metres (already checked by :func:`wavelength`).
    p : float
        Pixel pitch, metres (already checked by :func:`pitch`).
    name : str
        The wavelength's argument name, for the message.

    Raises
    ------
    ValueError
        ``w >= 2 p``.
    """
    if w >= 2 * p:
        raise InputError(
            f"{name} {w:g} m is not smaller than twice the pitch {p:g} m: the SLM cannot "
            f"diffract it; check both are in metres")


_far_warned = threading.local()


@contextlib.contextmanager
def far_warned_already():
    """Inside: no :class:`DepthWarning` from this thread. For a library step behind an entry
    point that has checked (and warned about) the same distances: one mistake, one warning,
    pointing at the user's line rather than at clholo's."""
    before = getattr(_far_warned, "on", False)
    _far_warned.on = True
    try:
        yield
    finally:
        _far_warned.on = before


def _clholo_folders() -> Tuple[str, ...]:
    # clholo's packages lie in up to three folders (``setup.cfg``'s ``package_dir``: clholo/,
    # host/, tools/ in a source tree; one in an installed wheel)
    folders = set()
    for module in ("clholo", "clholo.host", "clholo.tools"):
        path = getattr(sys.modules.get(module), "__file__", None)
        if path:
            folders.add(os.path.dirname(os.path.abspath(path)) + os.sep)
    return tuple(folders)


def warn_at_caller(message: str, category: type) -> None:
    """:func:`warnings.warn` pointing at the nearest frame outside clholo: the user's line
    that called the public function, however many of clholo's own functions lie between (a
    fixed ``stacklevel`` points into clholo when the same check is reached by two routes,
    e.g. ``dpac_encode`` -> ``dpac_encode_device`` -> the check). Where every frame is
    clholo's (``python -m clholo``), the outermost.

    Parameters
    ----------
    message : str
        The warning's text.
    category : type
        A :class:`Warning` subclass, e.g. :class:`DepthWarning`.
    """
    folders = _clholo_folders()
    frame = sys._getframe(1)
    level = 2  # warnings.warn's stacklevel of this function's caller
    while frame.f_back is not None and \
            os.path.abspath(frame.f_code.co_filename).startswith(folders):
        frame = frame.f_back
        level += 1
    warnings.warn(message, category, stacklevel=level)


def _warn_far(name: str, value: float) -> None:
    if abs(value) > FAR_DEPTH_M and not getattr(_far_warned, "on", False):
        warn_at_caller(
            f"{name}={value:g} m is more than 1 m: clholo's lengths are metres (scene units "
            f"need placing first, e.g. MPI.placed(near, far) or --near/--far)", DepthWarning)


def distance(value, *, name: str = "dz", nonzero: bool = False) -> float:
    """A signed propagation distance in metres (warns beyond 1 m).

    Parameters
    ----------
    value : float
        Distance in metres (SI); positive propagates away from the hologram plane, negative
        back towards it.
    name : str
        The argument's name, for the message.
    nonzero : bool
        Refuse ``0`` (a propagation that would do nothing).

    Returns
    -------
    float
        The distance in metres.

    Raises
    ------
    clholo.errors.InputTypeError
        Not a real number.
    ValueError
        NaN or infinity, beyond ``MAX_DISTANCE_M`` (1 km), or ``0`` with ``nonzero``.

    Warns
    -----
    DepthWarning
        ``|value| > 1 m`` (``FAR_DEPTH_M``): probably scene units, not metres; it points at
        the first line outside clholo (:func:`warn_at_caller`).
    """
    d = real_scalar(name, value)
    if nonzero and d == 0:
        raise InputError(f"{name} must be a non-zero distance in metres, got {value!r}")
    _refuse_beyond_bench(name, abs(d))
    _warn_far(name, d)
    return d


def _refuse_beyond_bench(name: str, farthest: float) -> None:
    if farthest > MAX_DISTANCE_M:
        raise InputError(f"{name} reaches {farthest:g} m, beyond {MAX_DISTANCE_M:g} m: not a "
                         f"distance on an optical bench; give metres (2e-3 for 2 mm)")


def depths(values, *, name: str = "depths", positive: bool = True,
           sorted_: bool = False) -> np.ndarray:
    """A non-empty 1-D float64 array of depths in metres behind the hologram plane.

    Parameters
    ----------
    values : float or sequence of float, shape ``(L,)``
        Depths in metres (SI) behind the hologram plane, e.g. an MPI's layer depths.
    name : str
        The argument's name, for the message.
    positive : bool
        Refuse depths ``<= 0`` (in front of or on the hologram plane).
    sorted_ : bool
        Refuse depths that are not strictly increasing (nearest first, the MPI convention).

    Returns
    -------
    numpy.ndarray, float64, shape ``(L,)``, ``L >= 1``
        The depths in metres.

    Raises
    ------
    clholo.errors.InputTypeError
        A string, or entries that are not numbers.
    ValueError
        Empty, more than one dimension, NaN or infinity, beyond ``MAX_DISTANCE_M`` (1 km), or a
        depth that ``positive`` or ``sorted_`` refuses.

    Warns
    -----
    DepthWarning
        A depth beyond 1 m (``FAR_DEPTH_M``): probably scene units, not metres; it points at
        the first line outside clholo (:func:`warn_at_caller`).
    """
    if isinstance(values, (str, bytes)):
        raise InputTypeError(f"{name} must be numbers in metres, got {values!r}")
    try:
        arr = np.atleast_1d(np.asarray(values, dtype=np.float64))
    except (TypeError, ValueError):
        raise InputTypeError(f"{name} must be numbers in metres, got {values!r}") from None
    if arr.ndim != 1 or arr.size == 0:
        raise InputError(f"{name} must be a non-empty 1-D sequence of metres, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise InputError(f"{name} must be finite, got {arr.tolist()}")
    if positive and np.any(arr <= 0):
        raise InputError(
            f"{name} must be > 0 metres behind the hologram plane, got {arr.tolist()}")
    if sorted_ and np.any(np.diff(arr) <= 0):
        raise InputError(f"{name} must be strictly increasing (nearest first), got {arr.tolist()}")
    _refuse_beyond_bench(name, float(np.max(np.abs(arr))))
    if np.any(np.abs(arr) > FAR_DEPTH_M):
        _warn_far(name, float(np.max(np.abs(arr))))
    return arr


def seed(value, *, name: str = "seed") -> int:
    """A phase-stream key: an integer in ``[0, 2**64)`` (floats, bools and strings refused).

    Parameters
    ----------
    value : int
        The seed of the counter-based random phase stream (:mod:`clholo.random`); dimensionless.
    name : str
        The argument's name, for the message.

    Returns
    -------
    int
        ``0 <= seed < 2**64``.

    Raises
    ------
    clholo.errors.InputTypeError
        Not an integer (a float would otherwise be truncated silently), or a bool.
    ValueError
        Negative, or ``2**64`` or more.
    """
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Integral):
        why = ("; a fractional seed would otherwise be truncated silently"
               if isinstance(value, numbers.Real) and not isinstance(value, (bool, np.bool_))
               else "")
        raise InputTypeError(
            f"{name} must be an integer in [0, 2**64), got {value!r} ({type(value).__name__})"
            f"{why}")
    s = int(value)
    if not 0 <= s < 2 ** 64:
        raise InputError(f"{name} must lie in [0, 2**64), got {s}")
    return s


def alpha_cut(alpha_max, alpha_min) -> Tuple[float, float]:
    """A footprint's opacity clamp and cut (3DGS's 0.99 and 1/255): ``0 <= alpha_min <
    alpha_max <= 1``; outside, every footprint is cut away (a hologram of zeros) or opacity
    leaves [0, 1].

    Parameters
    ----------
    alpha_max, alpha_min : float
        Largest opacity a footprint takes, and the smallest it keeps (dimensionless).

    Returns
    -------
    (float, float)
        ``(alpha_max, alpha_min)``.

    Raises
    ------
    clholo.errors.InputTypeError
        Not real numbers.
    clholo.errors.InputError
        Outside ``0 <= alpha_min < alpha_max <= 1``.
    """
    hi, lo = real_scalar("alpha_max", alpha_max), real_scalar("alpha_min", alpha_min)
    if not 0 <= lo < hi <= 1:
        raise InputError(f"alpha_max and alpha_min must satisfy 0 <= alpha_min < alpha_max <= 1 "
                         f"(opacities; 3DGS: 0.99 and 1/255), got alpha_max={hi:g}, "
                         f"alpha_min={lo:g}")
    return hi, lo


def count(value, *, name: str, minimum: int = 1, maximum: Optional[int] = None) -> int:
    """A whole number ``>= minimum`` (and ``<= maximum``); bools and floats are refused.

    Parameters
    ----------
    value : int
        A count: frames, layers, iterations, bytes of a memory budget, ...
    name : str
        The argument's name, for the message.
    minimum : int
        The smallest count allowed.
    maximum : int, optional
        The largest count allowed (default: no limit).

    Returns
    -------
    int
        ``minimum <= n`` (and ``n <= maximum``).

    Raises
    ------
    clholo.errors.InputTypeError
        Not an integer, or a bool.
    ValueError
        Below ``minimum`` or above ``maximum``.
    """
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Integral):
        raise InputTypeError(f"{name} must be a whole number >= {minimum}, got {value!r} "
                        f"({type(value).__name__})")
    n = int(value)
    if n < minimum:
        raise InputError(f"{name} must be >= {minimum}, got {n}")
    if maximum is not None and n > maximum:
        raise InputError(f"{name} must be <= {maximum}, got {n}")
    return n


def optional_count(value, *, name: str, minimum: int = 1) -> Optional[int]:
    """``None`` (meaning: choose for me) or a :func:`count`.

    Parameters
    ----------
    value : int or None
        A count, or ``None`` for the caller's default.
    name : str
        The argument's name, for the message.
    minimum : int
        The smallest count allowed.

    Returns
    -------
    int or None

    Raises
    ------
    clholo.errors.InputTypeError, ValueError
        As :func:`count`.
    """
    return None if value is None else count(value, name=name, minimum=minimum)


def stream_index(value, *, name: str) -> int:
    """A frame, layer or colour index of the random phase stream: a whole number in
    ``[0, 2**32)`` (:data:`STREAM_INDICES`); bools and floats are refused.

    Parameters
    ----------
    value : int
        The index (Python's or NumPy's integer).
    name : str
        The argument's name, for the message.

    Returns
    -------
    int
        ``0 <= index < 2**32``.

    Raises
    ------
    clholo.errors.InputTypeError
        Not an integer (``int()`` would cut 2.7 to 2: another frame's phases), or a bool.
    clholo.errors.InputError
        Negative, or ``2**32`` or more (a NumPy ``-1`` cast to the kernel's ``uint`` would be
        index ``2**32 - 1``, and ``2**32 + 3`` index 3, without a word).
    """
    n = count(value, name=name, minimum=0)
    if n >= STREAM_INDICES:
        raise InputError(f"{name} must lie in [0, 2**32), got {n}: the phase stream counts "
                         f"frames, layers and colours in 32 bits (index 2**32 would repeat "
                         f"index 0's phases)")
    return n


def frame_range(start, frames, *, start_name: str = "start",
                frames_name: str = "frames") -> Tuple[int, int]:
    """The first frame and the number of frames of a render: frames ``start ..
    start+frames-1`` must all lie in the phase stream, ``[0, 2**32)``.

    Every renderer checks this before any work (before it plans batches or writes a frame), so
    that a range beyond the stream is refused whole, never after some of its frames.

    Parameters
    ----------
    start : int
        Absolute index of the first frame (>= 0).
    frames : int
        Number of frames (>= 1).
    start_name, frames_name : str
        The arguments' names, for the messages.

    Returns
    -------
    (int, int)
        ``(start, frames)`` with ``start + frames <= 2**32``.

    Raises
    ------
    clholo.errors.InputTypeError
        Either is not an integer, or is a bool.
    clholo.errors.InputError
        ``start < 0``, ``frames < 1``, or ``start + frames > 2**32``.
    """
    n = count(frames, name=frames_name)
    s = count(start, name=start_name, minimum=0)
    if s + n > STREAM_INDICES:
        raise InputError(f"frames must lie in [0, 2**32), got {s}..{s + n}: the phase stream "
                         f"counts frames in 32 bits; give {start_name} + {frames_name} <= 2**32 "
                         f"(= 4294967296)")
    return s, n


def is_whole(v) -> bool:
    """Whether ``v`` is an integer (Python's or NumPy's; not a bool), or a real number with no
    fractional part: what a size may be (``int()`` would cut ``16.7`` to 16 and take ``True``
    for 1)."""
    if isinstance(v, (bool, np.bool_)):
        return False
    if isinstance(v, numbers.Integral):
        return True
    return isinstance(v, numbers.Real) and float(v).is_integer()


def shape2d(value: Sequence[int], *, name: str) -> Tuple[int, int]:
    """A field size ``(H, W)``, each at least 1.

    Parameters
    ----------
    value : sequence of int, length 2
        Rows and columns, pixels.
    name : str
        The argument's name, for the message.

    Returns
    -------
    (int, int)
        ``(H, W)``, each ``>= 1``.

    Raises
    ------
    ValueError
        Not a pair of whole numbers, or a side below 1.
    """
    try:
        pair = tuple(value)
    except TypeError:
        pair = ()
    if len(pair) != 2 or not all(is_whole(v) for v in pair):
        # int() would cut 16.7 to 16 and take True for 1: a size that is not what was meant
        raise InputError(f"{name} must be a pair (H, W) of whole numbers, got {value!r}")
    h, w = (int(v) for v in pair)
    if h < 1 or w < 1:
        raise InputError(f"{name} must be at least 1 x 1 pixels, got {h} x {w}")
    return h, w


def flag(value, *, name: str) -> bool:
    """A yes/no option: ``True`` or ``False`` (NumPy's bools too); nothing else is taken for one
    (``"no"`` would be true, ``0.5`` too).

    Parameters
    ----------
    value : bool
        The option's value.
    name : str
        The argument's name, for the message.

    Returns
    -------
    bool

    Raises
    ------
    clholo.errors.InputTypeError
        Not a bool.
    """
    if not isinstance(value, (bool, np.bool_)):
        raise InputTypeError(f"{name} must be True or False, got {value!r} "
                             f"({type(value).__name__})")
    return bool(value)


PAD_ACCEPTED = "'auto', a factor >= 1 (a number) or a padded shape (Hp, Wp) of whole numbers"


def pad(value, *, name: str = "pad"):
    """A propagation's padding: ``"auto"``, a real factor, or a shape ``(Hp, Wp)`` of whole
    numbers (their ranges are checked where the field's size is known:
    :func:`clholo.propagation.device_padded_shape`).

    Parameters
    ----------
    value : "auto", float or (int, int)
        The padding.
    name : str
        The argument's name, for the message.

    Returns
    -------
    "auto", float or (int, int)
        ``value`` itself, or the shape as a tuple of Python ints.

    Raises
    ------
    clholo.errors.InputTypeError
        ``None``, a bool (``True`` is not a factor of 1), a shape of more or fewer than two
        entries or with entries that are not whole numbers (``(32.5, 40)``), or anything else
        that is not one of the three forms.
    ValueError
        A string other than ``"auto"``, or a NaN or infinite factor.
    """
    if isinstance(value, str):
        if value != "auto":
            raise InputError(f"{name} must be {PAD_ACCEPTED}, got {value!r}")
        return value
    if isinstance(value, (bool, np.bool_)):
        raise InputTypeError(f"{name} must be {PAD_ACCEPTED}, got {value!r} (a bool, not a "
                             f"factor)")
    if isinstance(value, (tuple, list, np.ndarray)):
        items = list(np.asarray(value, dtype=object).reshape(-1)) \
            if isinstance(value, np.ndarray) else list(value)
        if (isinstance(value, np.ndarray) and value.ndim != 1) or len(items) != 2 or any(
                isinstance(v, (bool, np.bool_)) or not isinstance(v, numbers.Integral)
                for v in items):
            raise InputTypeError(f"{name} as a shape must be (Hp, Wp), two whole numbers of "
                                 f"pixels, got {value!r}")
        return int(items[0]), int(items[1])
    if not isinstance(value, numbers.Real):
        raise InputTypeError(f"{name} must be {PAD_ACCEPTED}, got {value!r} "
                             f"({type(value).__name__})")
    if not np.isfinite(float(value)):
        raise InputError(f"{name} factor must be finite and >= 1, got {value!r}")
    return value


def queue(value, *, name: str = "queue"):
    """``None`` (clholo's default device) or a ``pyopencl.CommandQueue``.

    Parameters
    ----------
    value : pyopencl.CommandQueue or None
        The queue to run on.
    name : str
        The argument's name, for the message.

    Returns
    -------
    pyopencl.CommandQueue or None

    Raises
    ------
    clholo.errors.InputTypeError
        Anything else (a device name such as ``"gpu"``, a context, a device).
    """
    if value is None:
        return None
    import pyopencl as cl

    if not isinstance(value, cl.CommandQueue):
        raise InputTypeError(
            f"{name} must be a pyopencl.CommandQueue or None (clholo's default device, chosen "
            f"with CLHOLO_DEVICE, e.g. CLHOLO_DEVICE=gpu), got {value!r} "
            f"({type(value).__name__}); clholo.host.runtime.get_queue() gives one")
    return value
