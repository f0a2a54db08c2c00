"""Scene data model: the display optics and the multiplane image (MPI).

Conventions (``docs/conventions.md``): depths are metres *behind* the hologram plane (layer ``i``
sits at ``z = -depths[i]``), layers are ordered nearest first, colour is linear intensity.
"""

from __future__ import annotations

import math
import weakref
from dataclasses import dataclass
from typing import Tuple

import numpy as np

from clholo.errors import InputTypeError

__all__ = ["Optics", "MPI", "validate_finite"]


def validate_finite(name: str, array: np.ndarray) -> None:
    """Raise ``ValueError`` naming ``name`` when ``array`` holds NaN or infinity."""
    if not np.all(np.isfinite(array)):
        bad = int(np.size(array) - np.count_nonzero(np.isfinite(array)))
        raise ValueError(f"{name} contains {bad} NaN/inf value(s); every value must be finite")


# the read-only copies MPIs hold: an MPI made from another's arrays (MPI.placed) shares them
_OWNED: "weakref.WeakValueDictionary[int, np.ndarray]" = weakref.WeakValueDictionary()


def _root(array: np.ndarray) -> np.ndarray:
    while isinstance(array.base, np.ndarray):
        array = array.base
    return array


def _owned(array: np.ndarray, given: np.ndarray) -> np.ndarray:
    """``array`` C-contiguous and read-only, as a view of a copy that no caller can write:
    copied unless it shares no memory with the caller's ``given`` or is another MPI's."""
    out = np.ascontiguousarray(array)
    root = _root(out)
    if _OWNED.get(id(root)) is root:
        return out
    if np.may_share_memory(out, given):
        out = out.copy()
    out.flags.writeable = False
    _OWNED[id(out)] = out
    view = out.view()  # a view of a read-only base: its flag cannot be set back to True
    return view


# Pixels of MPI.over's bands (see there)
_OVER_BAND_PIXELS = 1 << 16


def _handed_over(array: np.ndarray) -> np.ndarray:
    """``array`` made read-only and counted as an MPI's own, so that an MPI built from it keeps
    it without the copy :class:`MPI` makes of its caller's arrays: for a builder of layers
    that keeps no reference to them (``rgbd_to_mpi``'s alpha: 1.6 GB at 32 layers of a
    12-megapixel photo)."""
    array = np.ascontiguousarray(array)
    array.flags.writeable = False
    _OWNED[id(array)] = array
    return array.view()  # a view of a read-only base: its flag cannot be set back to True


@dataclass(frozen=True)
class Optics:
    """Display optics shared by every colour channel.

    Parameters
    ----------
    pitch : float
        SLM pixel pitch in metres (HOLOEYE Pluto-2.1: 8e-6).
    wavelengths : sequence of float
        One wavelength in metres per colour channel, in channel order (default R, G, B of the
        paper's laser: 638, 520, 450 nm).
    """

    pitch: float = 8e-6
    wavelengths: Tuple[float, ...] = (638e-9, 520e-9, 450e-9)

    def __post_init__(self) -> None:
        from clholo import validate

        pitch = validate.pitch(self.pitch)
        wl = validate.wavelengths(self.wavelengths)
        for w in wl:
            validate.wavelength_for_pitch(w, pitch, name="wavelengths")
        object.__setattr__(self, "pitch", pitch)
        object.__setattr__(self, "wavelengths", wl)

    @property
    def channels(self) -> int:
        """Number of wavelengths, one per colour channel ``C``."""
        return len(self.wavelengths)

    def max_angle_rad(self, channel: int = 0) -> float:
        """Largest diffraction angle ``asin(lambda / (2 p))`` for ``channel`` (``0 <= channel <
        C``), in radians."""
        from clholo import validate

        c = validate.count(channel, name="channel", minimum=0, maximum=self.channels - 1)
        return float(np.arcsin(min(1.0, self.wavelengths[c] / (2 * self.pitch))))

    def check_direction_sent(self, sx: float, sy: float, what: str) -> None:
        """Refuse a direction of sines ``(sx, sy)`` beyond what the SLM sends in any colour,
        ``|sin theta| > lambda / (2 p)`` on either axis for the shortest wavelength; ``what``
        names it ("angles_rad[0] = ... rad") at the start of the :class:`ValueError`, which
        gives the limit in degrees."""
        limits = np.asarray(self.wavelengths) / (2 * self.pitch)  # largest sine, per colour
        tightest = int(np.argmin(limits))
        if max(abs(sx), abs(sy)) > limits[tightest]:
            lim = math.degrees(math.asin(min(1.0, limits[tightest])))
            raise ValueError(
                f"{what} lies beyond the largest angle the SLM sends, asin(lambda / 2p) = "
                f"{lim:.3f} deg for {self.wavelengths[tightest] * 1e9:.0f} nm at pitch "
                f"{self.pitch:g} m; keep |theta| <= {lim:.3f} deg on each axis")


@dataclass(frozen=True, eq=False)
class MPI:
    """A multiplane image: ``L`` RGBA layers at depths behind the hologram plane.

    Parameters
    ----------
    color : array_like, shape (L, H, W, C)
        Straight (not premultiplied) colour as linear intensity in [0, 1]; converted to float32.
        A 3-D array ``(L, H, W)`` is taken as one channel.
    alpha : array_like, shape (L, H, W)
        Opacity in [0, 1]; converted to float32.
    depths : array_like, shape (L,)
        Metres behind the hologram plane, each > 0 and distinct. Given in any order, the layers
        are sorted nearest first on construction.

    Notes
    -----
    The MPI holds its own copies of ``color``, ``alpha`` and ``depths``, made read-only
    (``flags.writeable`` is False): what was checked cannot change afterwards, and
    ``mpi.alpha[0] = 7`` raises NumPy's "assignment destination is read-only". Input that is
    already float32 is therefore copied once (as much memory again as the layers take; other
    dtypes are converted, which is that copy). Build a new MPI to change a scene.

    A ``color`` whose layers are one image broadcast to all of them (stride 0 along ``L``, as
    ``np.broadcast_to(image, (L, H, W, C))`` gives and :func:`clholo.io.rgbd_to_mpi` makes)
    is kept so: ``mpi.color`` is then a read-only broadcast view of one ``(H, W, C)`` copy,
    ``L`` times less memory (a 12-megapixel photo's 32 layers: 146 MB, not 4.6 GB).

    Raises
    ------
    TypeError
        ``color``, ``alpha`` or ``depths`` is not a real numeric array.
    ValueError
        On shape or channel mismatches, NaN/inf, values outside [0, 1], non-positive or
        duplicate depths; the message names the argument.
    """

    color: np.ndarray
    alpha: np.ndarray
    depths: np.ndarray

    def __post_init__(self) -> None:
        color = np.asarray(self.color)
        alpha = np.asarray(self.alpha)
        depths = np.asarray(self.depths)
        given = {"color": color, "alpha": alpha, "depths": depths}
        for name, arr in (("color", color), ("alpha", alpha), ("depths", depths)):
            # bools are masks for colour and alpha (0/1), but not distances: True is not 1 m
            if not (np.issubdtype(arr.dtype, np.floating) or np.issubdtype(arr.dtype, np.integer)
                    or (arr.dtype == bool and name != "depths")):
                raise InputTypeError(f"{name} must be a real numeric array, got dtype "
                                     f"{arr.dtype}")
        if color.ndim == 3:
            color = color[..., None]
        if color.ndim != 4:
            raise ValueError(f"color must have shape (L, H, W, C), got {color.shape}")
        if alpha.ndim == 4 and alpha.shape[-1] == 1:
            alpha = alpha[..., 0]
        if alpha.ndim != 3:
            raise ValueError(f"alpha must have shape (L, H, W), got {alpha.shape}")
        if depths.ndim != 1:
            raise ValueError(f"depths must have shape (L,), got {depths.shape}")
        L = color.shape[0]
        if color.shape[1] in (1, 3, 4) and color.shape[3] > 4:
            # (L, C, H, W) read as (L, H, W, C): C = W colour channels on C-row layers; the
            # shapes fit only a channels-first reading (a later error said "24 colour channels")
            fix = (f"give color as (L, H, W, C) = {(L,) + color.shape[2:] + color.shape[1:2]} "
                   f"with np.moveaxis(color, 1, -1), and alpha as (L, H, W) = "
                   f"{(L,) + color.shape[2:]}")
            raise ValueError(
                f"color has shape {color.shape}, which reads as channels-first colour (L, C, H, "
                f"W) with C = {color.shape[1]}: as (L, H, W, C) it would be {color.shape[3]} "
                f"colour channels on layers of {color.shape[1]} x {color.shape[2]} pixels; "
                f"{fix}")
        if alpha.shape != color.shape[:3]:
            raise ValueError(
                f"alpha shape {alpha.shape} does not match color's (L, H, W) = {color.shape[:3]}")
        if depths.shape[0] != L:
            raise ValueError(f"depths has {depths.shape[0]} entries but color has {L} layers")
        if L == 0:
            raise ValueError("an MPI needs at least one layer (L >= 1)")
        if color.shape[1] < 1 or color.shape[2] < 1:
            raise ValueError(f"color must have at least 1 x 1 pixels per layer, got "
                             f"{color.shape[1]} x {color.shape[2]} (shape (L, H, W, C) = "
                             f"{color.shape})")
        if color.shape[3] < 1:
            raise ValueError(f"color must have at least one channel, got shape {color.shape}")
        # one colour image broadcast to every layer (stride 0 along L: rgbd_to_mpi's layers,
        # where alpha alone says where each shows) stays one image: L copies of a 12-megapixel
        # photo's colour are 4.6 GB at 32 layers
        shared = L > 1 and color.strides[0] == 0
        if shared:
            color = color[:1]
        color = color.astype(np.float32, copy=False)
        alpha = alpha.astype(np.float32, copy=False)
        depths = depths.astype(np.float64, copy=False)
        validate_finite("color", color)
        validate_finite("alpha", alpha)
        validate_finite("depths", depths)
        if color.min() < 0 or color.max() > 1:
            raise ValueError(
                f"color must be linear intensity in [0, 1], got range [{color.min():.4g}, "
                f"{color.max():.4g}]; clip or rescale it (and decode sRGB first)")
        if alpha.min() < 0 or alpha.max() > 1:
            raise ValueError(
                f"alpha must lie in [0, 1], got range [{alpha.min():.4g}, {alpha.max():.4g}]")
        if np.any(depths <= 0):
            raise ValueError(
                f"depths must be > 0 metres behind the hologram plane, got {depths.tolist()}; "
                f"use MPI.placed(near, far) to map scene depths to metres")
        from clholo import validate

        validate._refuse_beyond_bench("depths", float(depths.max()))
        order = np.argsort(depths, kind="stable")
        depths = depths[order]
        if np.any(np.diff(depths) == 0):
            dup = depths[1:][np.diff(depths) == 0]
            raise ValueError(f"depths must be distinct; duplicated: {np.unique(dup).tolist()}")
        if not np.all(order == np.arange(L)):
            color = color if shared else color[order]
            alpha = alpha[order]
        # the MPI holds its own read-only arrays: an edit of the caller's array after this
        # check (or of mpi.alpha itself) cannot change what was checked
        color = _owned(color, given["color"])
        if shared:  # read-only, as every MPI array is
            color = np.broadcast_to(color, (L,) + color.shape[1:])
        object.__setattr__(self, "color", color)
        object.__setattr__(self, "alpha", _owned(alpha, given["alpha"]))
        object.__setattr__(self, "depths", _owned(depths, given["depths"]))

    def __reduce__(self):
        # pickled (multiprocessing, Dask) through the constructor: checked and read-only again
        # where it arrives (a plain dataclass pickle restores writeable arrays unchecked), and
        # a colour shared by every layer travels once, not L times
        if self.layers > 1 and self.color.strides[0] == 0:
            return _shared_colour_mpi, (np.ascontiguousarray(self.color[0]), self.alpha,
                                        self.depths)
        return MPI, (self.color, self.alpha, self.depths)

    @property
    def layers(self) -> int:
        """Number of layers ``L``."""
        return int(self.color.shape[0])

    @property
    def shape(self) -> Tuple[int, int]:
        """``(H, W)`` of every layer."""
        return int(self.color.shape[1]), int(self.color.shape[2])

    @property
    def channels(self) -> int:
        """Number of colour channels ``C`` (1 or 3)."""
        return int(self.color.shape[3])

    def placed(self, near: float, far: float, *, spacing: str = "index") -> "MPI":
        """The same layers re-placed between ``near`` and ``far`` metres behind the hologram.

        Parameters
        ----------
        near, far : float
            Depths in metres of the nearest and farthest layer, ``0 < near < far``.
        spacing : {"index", "depth", "inverse"}
            ``"index"``: uniform steps by layer index (what the paper does); ``"depth"``: linear
            in the current depths; ``"inverse"``: linear in inverse depth (dioptres), which keeps
            the spacing of MPIs made uniform in disparity.
        """
        return MPI(self.color, self.alpha, placed_depths(self.depths, near, far,
                                                         spacing=spacing))

    def over(self) -> np.ndarray:
        """Ray-optics "over" composite seen head-on, ``(H, W, C)`` linear intensity.

        ``C = sum_i c_i a_i prod_{j<i} (1 - a_j)`` with ``j < i`` the nearer layers.
        """
        H, W, C = self.color.shape[1:]
        out = np.empty((H, W, C), np.float32)
        # a band of rows at a time through every layer: 64 K pixels in float64 stay in cache
        # (twice as fast as whole layers at 12 megapixels; the same operations, the same bits)
        rows = max(1, _OVER_BAND_PIXELS // W)
        for y0 in range(0, H, rows):
            band = np.zeros((min(rows, H - y0), W, C), np.float64)
            for i in range(self.layers - 1, -1, -1):  # back to front
                a = self.alpha[i, y0:y0 + rows][..., None].astype(np.float64)
                band *= 1.0 - a
                band += self.color[i, y0:y0 + rows] * a
            out[y0:y0 + rows] = band
        return out


def placed_depths(depths, near: float, far: float, *, spacing: str = "index") -> np.ndarray:
    """Layer depths ``depths`` (any positive unit, any order) re-placed between ``near`` and
    ``far`` metres, as :meth:`MPI.placed` places an MPI's: what a loader of scene-unit depths
    gives :class:`MPI`, so that depths of any size (a scene in millimetres: 18000) are placed
    before the MPI's 1 km check of metres sees them.

    Parameters
    ----------
    depths : array of float, shape ``(L,)``
        The stored depths: finite, > 0 and distinct, in any order (each keeps its rank).
    near, far : float
        Depths in metres of the nearest and farthest layer, ``0 < near < far``.
    spacing : {"index", "depth", "inverse"}
        See :meth:`MPI.placed`.

    Returns
    -------
    numpy.ndarray, float64, shape ``(L,)``
        The placed depths in metres, in the order of ``depths``.

    Raises
    ------
    ValueError
        ``near``/``far`` not ``0 < near < far`` (or not numbers), an unknown ``spacing``, or
        ``depths`` not finite, positive and distinct.
    """
    from clholo import validate

    near = validate.real_scalar("near", near, fix="a depth > 0 in metres")
    far = validate.real_scalar("far", far, fix="a depth > near in metres")
    d = np.asarray(depths, np.float64).reshape(-1)
    L = d.size
    if near <= 0:
        raise ValueError(f"near must be a finite depth > 0 metres, got {near!r}")
    if far < near or (L > 1 and far == near):
        raise ValueError(f"far ({far}) must be greater than near ({near})")
    if spacing not in ("index", "depth", "inverse"):
        raise ValueError(f"spacing must be 'index', 'depth' or 'inverse', got {spacing!r}")
    validate_finite("depths", d)
    if L == 0 or np.any(d <= 0):
        raise ValueError(f"depths to place must be > 0 (any unit), got {d.tolist()}")
    order = np.argsort(d, kind="stable")
    if np.any(np.diff(d[order]) == 0):
        dup = d[order][1:][np.diff(d[order]) == 0]
        raise ValueError(f"depths must be distinct; duplicated: {np.unique(dup).tolist()}")
    # the nearest and farthest by value, not by position: a loader's depths may run far to
    # near (Stereo Magnification's, mpi.json's back_to_front); for MPI.placed's sorted depths
    # these are d[0] and d[-1], the same bits as before
    lo, hi = d[order[0]], d[order[-1]]
    if L == 1:
        return np.array([near])
    if spacing == "index":
        new = np.empty(L)
        new[order] = np.linspace(near, far, L)
    elif spacing == "depth":
        new = near + (d - lo) / (hi - lo) * (far - near)
    else:
        inv = 1.0 / d
        t = (1.0 / lo - inv) / (1.0 / lo - 1.0 / hi)  # 0 at the nearest, 1 at the farthest
        new = 1.0 / (1.0 / near + t * (1.0 / far - 1.0 / near))
    if not np.all(np.isfinite(new)):  # 1/d of a subnormal depth is inf
        raise ValueError(f"depths {lo:g}..{hi:g} span too wide a range to place with "
                         f"spacing={spacing!r}: use spacing='index'")
    return new


def stored_or_placed_depths(depths, near, far, *, spacing: str, source: str,
                            units: str) -> np.ndarray:
    """The depths a loader gives :class:`MPI`: ``depths`` placed between ``near`` and ``far``
    metres (:func:`placed_depths`) when both are given, else as stored, refused when they
    reach beyond 1 km (``clholo.validate.MAX_DISTANCE_M``) with the fix for their units:
    scene units need ``near``/``far``, metres that far are no bench's.

    Parameters
    ----------
    depths : array of float, shape ``(L,)``
        The stored depths: finite, > 0 and distinct, in any order.
    near, far : float or None
        Metres behind the hologram plane, or both None to keep the depths as stored.
    spacing : {"index", "depth", "inverse"}
        See :meth:`MPI.placed`.
    source : str
        The file or folder the depths come from, starting the message.
    units : {"metres", "scene units"}
        What the stored depths are in.

    Returns
    -------
    numpy.ndarray, float64, shape ``(L,)``
        In the order of ``depths``.

    Raises
    ------
    clholo.errors.InputError
        Stored depths beyond 1 km without ``near``/``far``, or one of ``near``/``far`` alone.
    ValueError
        See :func:`placed_depths`.
    """
    from clholo import validate
    from clholo.errors import InputError

    if near is not None or far is not None:
        if near is None or far is None:
            raise InputError("give both near and far (metres), or neither")
        return placed_depths(depths, near, far, spacing=spacing)
    d = np.asarray(depths, np.float64)
    farthest = float(np.max(d)) if d.size else 0.0
    if farthest > validate.MAX_DISTANCE_M:
        if units == "metres":
            raise InputError(f"{source}: depths reach {farthest:g} m, beyond "
                             f"{validate.MAX_DISTANCE_M:g} m: not a distance on an optical "
                             f"bench; give metres (2e-3 for 2 mm)")
        raise InputError(f"{source}: depths reach {farthest:g} scene units, which are not "
                         f"metres: place them with near and far (--near/--far, metres behind "
                         f"the hologram plane), e.g. --near 0.002 --far 0.006")
    return d


def _shared_colour_mpi(image: np.ndarray, alpha: np.ndarray, depths: np.ndarray) -> MPI:
    """An :class:`MPI` whose ``len(depths)`` layers share the colour ``image`` ``(H, W, C)``
    (what a pickled one of them is rebuilt by)."""
    return MPI(np.broadcast_to(image, (len(depths),) + np.shape(image)), alpha, depths)
