"""Ray-optics references: what a hologram of an MPI should look like (HOLOGRAPHY.md section 6).

Every view here is one launch of ``kernels/rayoptics.cl`` (NumPy reference:
:func:`clholo.reference.rayoptics.warp_over_mean`): each output pixel maps through one 3x3
homography per layer (and per view and channel) into the layer, samples it bilinearly, and
composites the layers back to front with "over",
``C = sum_i c_i a_i prod_{j<i} (1 - a_j)`` (``j < i`` the nearer layers); several views are
averaged in the same launch. The work is per pixel and per layer (a 32-layer view of a
1040x784 RGB MPI is 78 M bilinear samples, a 49-view focal slice 50 times that), hence a kernel.

Conventions
-----------
* Pixel centres sit at integer coordinates ``(x, y)``, ``x`` the column (horizontal, to the
  right), ``y`` the row (vertical, downwards). The output has the MPI's size; bilinear taps
  outside a layer are transparent (colour 0, alpha 0), so a shifted view has an empty border.
* Interpolation is ``premultiplied`` by default: ``c * a`` (the light) and ``a`` (the absorber)
  are interpolated, so colour hidden under zero alpha never bleeds in -- what shifting the
  layer's emitted light and its transmission does. ``premultiplied=False`` interpolates the
  straight colour and alpha separately, as Stereo Magnification's renderer does.
* Angles: a view at ``angle_rad = (theta_x, theta_y)`` collects the rays travelling towards
  ``+x`` (``theta_x > 0``) and ``+y`` (``theta_y > 0``) as they leave the scene towards the viewer,
  the rays a pupil centred at spatial frequency ``(sin theta_x, sin theta_y) / lambda`` passes
  (``clholo.views.pupil_view``). A point at depth ``d`` crosses the focus plane at depth ``f``
  displaced by ``(d - f) tan(theta)``: layer ``i`` shifts by ``(d_i - f) tan(theta) / p`` pixels
  (along one axis; a direction off both axes moves by ``(d_i - f) sin(theta) / cos_z / p`` per
  axis, ``cos_z = sqrt(1 - sin^2 theta_x - sin^2 theta_y)``: :func:`layer_shifts_px`).
  So for ``theta_x > 0`` content *behind* the focus moves right (larger column index), content in
  front of it moves left; ``theta_y > 0`` moves content behind the focus down (larger row).
* Colour is composited as given: pass linear intensity (``MPI.color``) for what a hologram shows.
"""

from __future__ import annotations

import math
from typing import Optional, Sequence, Tuple, Union

import numpy as np
import pyopencl as cl
import pyopencl.array as cla

from clholo import validate
from clholo._arrays import resolve_queue
from clholo.errors import InputTypeError
from clholo.host import runtime
from clholo.scene import MPI, Optics

__all__ = ["warp_over", "orthographic_view", "pupil_directions", "incoherent_focal_slice",
           "perspective_view", "shift_homographies", "layer_shifts_px"]

PUPIL_SHAPES = ("square", "disc")


def _check_mpi(mpi) -> MPI:
    if not isinstance(mpi, MPI):
        raise TypeError(f"mpi must be a clholo.MPI, got {type(mpi).__name__}; build one with "
                        f"clholo.MPI(color, alpha, depths) or clholo.io.load_scene")
    return mpi


def warp_over(mpi: MPI, homographies, *, premultiplied: bool = True,
              queue: Optional["cl.CommandQueue"] = None) -> np.ndarray:
    """Warp every layer by its homography, composite with "over", average over views.

    Parameters
    ----------
    mpi : MPI
        ``L`` layers ``(H, W, C)``, nearest first.
    homographies : array_like, shape (L, 3, 3), (V, L, 3, 3) or (C, V, L, 3, 3)
        Maps from an output pixel ``(x, y, 1)`` to the source position ``(x', y', w)`` (divided
        by ``w``) in layer ``l``, for each of ``V`` views (and each channel); pixel units.
    premultiplied : bool
        Interpolate ``c * a`` and ``a`` (default) or the straight ``c`` and ``a``.
    queue : pyopencl.CommandQueue, optional

    Returns
    -------
    ndarray, shape (H, W, C), float32
        The mean over the views of the composites.
    """
    mpi = _check_mpi(mpi)
    L, (H, W), C = mpi.layers, mpi.shape, mpi.channels
    try:
        hom = np.asarray(homographies, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputTypeError(f"homographies must be 3x3 matrices, numbers of shape (L, 3, 3), "
                             f"(V, L, 3, 3) or (C, V, L, 3, 3), got {homographies!r:.60}") from None
    if hom.ndim == 3:
        hom = hom[None]
    if hom.ndim == 4:
        hom = hom[None]
    if hom.ndim != 5 or hom.shape[0] not in (1, C) or hom.shape[2] != L or hom.shape[3:] != (3, 3):
        raise ValueError(f"homographies must have shape (L, 3, 3), (V, L, 3, 3) or "
                         f"(C, V, L, 3, 3) with L = {L} layers and C = {C} channels, got "
                         f"{np.shape(homographies)}")
    if hom.shape[1] < 1:
        raise ValueError("homographies must hold at least one view (V >= 1)")
    if not np.all(np.isfinite(hom)):
        raise ValueError("homographies must be finite")
    # one set of maps for every channel when they agree: the kernel then shares coordinates
    # and alpha taps across channels
    if hom.shape[0] > 1 and np.all(hom == hom[:1]):
        hom = hom[:1]
    n_maps, V = hom.shape[:2]
    hom = np.ascontiguousarray(hom, dtype=np.float32)
    premultiplied = validate.flag(premultiplied, name="premultiplied")
    queue = resolve_queue(queue)
    per_channel = n_maps > 1
    kernel = runtime.get_kernel(queue.context, "rayoptics.cl", "warp_over_mean",
                                defines={"NC": C, "PER_CHANNEL_MAPS": per_channel,
                                         "PREMULTIPLIED": bool(premultiplied)})
    d_color = cla.to_device(queue, np.ascontiguousarray(mpi.color))  # a shared one: L copies
    d_alpha = cla.to_device(queue, mpi.alpha)
    d_hom = cla.to_device(queue, hom.reshape(n_maps, V, L, 9))
    d_out = cla.empty(queue, (H, W, C), np.float32)
    runtime.launch(kernel, queue, (W, H, C if per_channel else 1), None, d_color.data, d_alpha.data,
           d_hom.data, d_out.data, np.int32(L), np.int32(H), np.int32(W), np.int32(V))
    return d_out.get()


def shift_homographies(shifts_px) -> np.ndarray:
    """Homographies ``(..., 3, 3)`` that move content by ``shifts_px[..., (sx, sy)]`` pixels.

    Content at ``(x, y)`` of a layer appears at ``(x + sx, y + sy)`` in the view, so the map from
    output to source subtracts the shift.
    """
    try:
        s = np.asarray(shifts_px, dtype=np.float64)
    except (TypeError, ValueError):
        s = None
    if s is None or s.ndim < 1 or s.shape[-1] != 2:
        raise ValueError(f"shifts_px must be pixel shifts of shape (..., 2), (sx, sy) each, got "
                         f"{shifts_px!r}")
    hom = np.zeros(s.shape[:-1] + (3, 3))
    hom[..., 0, 0] = hom[..., 1, 1] = hom[..., 2, 2] = 1.0
    hom[..., 0, 2] = -s[..., 0]
    hom[..., 1, 2] = -s[..., 1]
    return hom


def _angles(angle_rad, name: str) -> Tuple[float, float]:
    try:
        tx, ty = angle_rad
    except (TypeError, ValueError):
        raise TypeError(f"{name} must be a pair (theta_x, theta_y) in radians, got "
                        f"{angle_rad!r}") from None
    tx = validate.real_scalar(f"{name}[0]", tx)
    ty = validate.real_scalar(f"{name}[1]", ty)
    for v, axis in ((tx, 0), (ty, 1)):
        if abs(v) >= math.pi / 2:
            raise ValueError(f"{name}[{axis}] = {v!r} rad is not inside (-pi/2, pi/2); angles "
                             f"are radians (1 degree = {math.pi / 180:.5f} rad)")
    return tx, ty


def layer_shifts_px(depths: np.ndarray, focus_depth: float, pitch: float,
                    angles: np.ndarray) -> np.ndarray:
    """Shifts ``[V, L, 2]`` in pixels: ``(d_l - f) sin(theta) / cos_z / p`` per axis for each
    view's angles, ``cos_z = sqrt(1 - sin^2 theta_x - sin^2 theta_y)``: the exact displacement
    of a ray whose direction sines (spatial frequency times wavelength) are ``sin(theta)``.
    Along one axis it is ``tan(theta)``; HOLOGRAPHY.md section 6's per-axis ``tan`` is its
    small-angle form (under 0.1 % apart within an 8 um SLM's band, 185 % at a corner of a
    0.4 um one's).

    Parameters
    ----------
    depths : array ``(L,)``
        Layer depths, metres.
    focus_depth : float
        The depth that stays still, metres.
    pitch : float
        Pixel pitch, metres.
    angles : array ``(V, 2)``
        ``(theta_x, theta_y)`` per view, radians.

    Raises
    ------
    ValueError
        A direction with ``sin^2 theta_x + sin^2 theta_y >= 1`` (no ray travels that way).
    """
    sines = np.sin(np.asarray(angles, np.float64))  # [V, 2]
    cos_z2 = 1.0 - np.sum(sines ** 2, axis=-1)
    if np.any(cos_z2 <= 0):
        v = int(np.argmin(cos_z2))
        raise ValueError(
            f"the direction (theta_x, theta_y) = ({angles[v][0]:.5g}, {angles[v][1]:.5g}) rad "
            f"has sin^2 theta_x + sin^2 theta_y >= 1: no ray travels that way; angles are "
            f"radians (1 degree = {math.pi / 180:.5f} rad)")
    slopes = sines / np.sqrt(cos_z2)[:, None]
    return (depths[None, :, None] - focus_depth) * slopes[:, None, :] / pitch


def orthographic_view(mpi: MPI, pitch: float, *, angle_rad=(0.0, 0.0),
                      focus_depth: float = 0.0, premultiplied: bool = True,
                      queue: Optional["cl.CommandQueue"] = None) -> np.ndarray:
    """The MPI seen by parallel rays at an angle, focused at a depth (HOLOGRAPHY.md section 6).

    Layer ``i`` shifts by ``(d_i - focus_depth) * tan(theta) / pitch`` pixels along one axis
    (both at once: :func:`layer_shifts_px`, the exact ray displacement; sub-pixel,
    bilinear) along each axis, then the layers are composited with "over". For
    ``theta_x > 0`` content behind the focus moves right (towards larger column index) and
    content in front of it moves left; ``theta_y > 0`` moves content behind the focus down
    (towards larger row index). See the module docstring.

    Parameters
    ----------
    mpi : MPI
        Depths in metres behind the hologram plane.
    pitch : float
        Pixel pitch in metres (8e-6 for the Pluto-2.1).
    angle_rad : (float, float)
        ``(theta_x, theta_y)``: horizontal and vertical viewing angle in radians.
    focus_depth : float
        Depth in metres of the plane that stays still (0: the hologram plane).
    premultiplied : bool
        Interpolate ``c * a`` and ``a`` (default) or the straight colour and alpha.
    queue : pyopencl.CommandQueue, optional

    Returns
    -------
    ndarray, shape (H, W, C), float32
        Composite of the MPI's colour values (linear intensity for an MPI in clholo's units).
    """
    mpi = _check_mpi(mpi)
    p = validate.pitch(pitch)
    angles = np.array([_angles(angle_rad, "angle_rad")])
    f = validate.distance(focus_depth, name="focus_depth")
    shifts = layer_shifts_px(mpi.depths, f, p, angles)  # [1, L, 2]
    return warp_over(mpi, shift_homographies(shifts), premultiplied=premultiplied, queue=queue)


def pupil_directions(half_angle_rad: float, samples: int, *, pupil: str = "square",
                     center_rad=(0.0, 0.0)) -> np.ndarray:
    """Viewing angles ``[V, 2]`` (``theta_x, theta_y``, radians) that sample a pupil.

    The directions are uniform in ``sin(theta)`` (= spatial frequency times wavelength), the
    variable in which a random-phase hologram's spectrum is flat: ``samples`` cell midpoints
    per axis, ``sin(theta) = sin(half_angle) * (2k + 1 - samples) / samples`` for
    ``k = 0 .. samples-1``, with ``half_angle = half_angle_rad``. ``"square"`` keeps all
    ``samples**2`` (the band an SLM sends, ``|f_x|, |f_y| < 1/(2p)``, is a square); ``"disc"``
    keeps the midpoints inside the circle of radius ``sin(half_angle)``. An odd ``samples`` includes the head-on view.
    ``center_rad = (theta_x, theta_y)`` moves the pupil's centre to ``sin(theta) = sin(center)``
    (a pupil view's pupil); every direction must stay inside (-90, 90) degrees.
    """
    half = validate.real_scalar("pupil_angle_rad", half_angle_rad)
    if not 0 <= half < math.pi / 2:
        raise ValueError(f"pupil_angle_rad must lie in [0, pi/2) radians, got {half!r}")
    n = validate.count(samples, name="samples", minimum=1, maximum=101)
    if pupil not in PUPIL_SHAPES:
        raise ValueError(f"pupil must be one of {PUPIL_SHAPES}, got {pupil!r}")
    u = (2 * np.arange(n) + 1 - n) / n  # cell midpoints in (-1, 1)
    ux, uy = np.meshgrid(u, u, indexing="xy")
    ux, uy = ux.ravel(), uy.ravel()
    if pupil == "disc":
        keep = ux ** 2 + uy ** 2 <= 1.0 + 1e-12
        ux, uy = ux[keep], uy[keep]
    cx, cy = (math.sin(a) for a in _angles(center_rad, "pupil_center_rad"))
    s = math.sin(half)
    sx, sy = cx + ux * s, cy + uy * s
    if max(np.max(np.abs(sx)), np.max(np.abs(sy))) >= 1.0:
        raise ValueError(f"the pupil (centre {center_rad!r} rad, half-angle {half!r} rad) "
                         f"reaches beyond 90 degrees; make it smaller or centre it nearer 0")
    return np.stack([np.arcsin(sx), np.arcsin(sy)], axis=-1)


def _check_pupil_in_band(optics: Optics, halves, center_rad) -> None:
    """Refuse a pupil the hologram cannot fill, as :func:`clholo.views.pupil_view` does: a
    centre beyond the band the SLM sends in any colour, or a half-angle wider than its
    colour's band (directions no hologram sends: a reference blurrier than any hologram)."""
    limits = np.asarray(optics.wavelengths) / (2 * optics.pitch)  # largest sine, per colour
    cx, cy = (math.sin(a) for a in _angles(center_rad, "pupil_center_rad"))
    optics.check_direction_sent(cx, cy, f"pupil_center_rad = {tuple(center_rad)!r} rad")
    for c, (h, limit) in enumerate(zip(halves, limits)):
        if math.sin(h) > limit * (1 + 1e-9):
            raise ValueError(
                f"pupil_angle_rad = {h:.5g} rad for channel {c} "
                f"({optics.wavelengths[c] * 1e9:.0f} nm) is wider than the band the SLM sends "
                f"there, asin(lambda / 2p) = {math.asin(min(1.0, limit)):.5g} rad: no hologram "
                f"sends those directions; leave pupil_angle_rad out for the whole band, or give "
                f"a smaller one (radians)")


def incoherent_focal_slice(mpi: MPI, optics: Optics, depth: float, *,
                           pupil_angle_rad: Union[None, float, Sequence[float]] = None,
                           samples: int = 7, pupil: str = "square",
                           pupil_center_rad=(0.0, 0.0), premultiplied: bool = True,
                           queue: Optional["cl.CommandQueue"] = None) -> np.ndarray:
    """What a focal slice of the MPI's hologram should show: the mean of refocused views.

    Shift-and-add light-field refocusing (HOLOGRAPHY.md section 6): the mean of
    :func:`orthographic_view` focused at ``depth`` over the directions of
    :func:`pupil_directions`, per colour channel with that channel's pupil, in one launch.
    Occlusion at depth edges is handled view by view. A layer at distance ``delta`` from the
    focus blurs by the pupil's shape scaled to ``delta * tan(half_angle) / p`` pixels (half
    width), sampled by ``samples`` copies per axis.

    Parameters
    ----------
    mpi : MPI
        ``C`` channels, one per wavelength of ``optics``; depths in metres.
    optics : Optics
        Pitch and wavelengths.
    depth : float
        Focus depth in metres behind the hologram plane.
    pupil_angle_rad : float or sequence of float, optional
        Half-angle (radius) of the pupil in radians, one for all channels or one per channel.
        Default per channel ``asin(lambda / (2 p))``: every direction the SLM can send.
    samples : int
        Directions per axis (7: 49 views for a square pupil, 37 for a disc).
    pupil : {"square", "disc"}
        ``"square"`` (default) is the band a pixelated SLM sends (``|sin theta_x|`` and
        ``|sin theta_y| <= lambda / (2p)``), what a focal slice of a random-phase hologram sees;
        ``"disc"`` a round aperture of that radius.
    pupil_center_rad : (float, float)
        Centre ``(theta_x, theta_y)`` of the pupil in radians (default head-on). Off-centre, this
        is the ray-optics counterpart of a pupil view (``clholo.views.pupil_view``): the mean of
        the views through a pupil centred at spatial frequency ``sin(theta) / lambda``.
    premultiplied : bool
    queue : pyopencl.CommandQueue, optional

    Returns
    -------
    ndarray, shape (H, W, C), float32
    """
    mpi = _check_mpi(mpi)
    if not isinstance(optics, Optics):
        raise TypeError(f"optics must be a clholo.Optics, got {type(optics).__name__}")
    C = mpi.channels
    if optics.channels != C:
        raise ValueError(f"the MPI has {C} colour channel(s) but optics has "
                         f"{optics.channels} wavelength(s); give one wavelength per channel")
    d = validate.distance(depth, name="depth")
    if pupil_angle_rad is None:
        halves = [optics.max_angle_rad(c) for c in range(C)]
    else:
        arr = np.atleast_1d(np.asarray(pupil_angle_rad, dtype=object))
        if arr.ndim != 1 or arr.size not in (1, C):
            raise ValueError(f"pupil_angle_rad must be one angle or {C} (one per channel), got "
                             f"{pupil_angle_rad!r}")
        halves = [validate.real_scalar("pupil_angle_rad", v) for v in arr]
        halves = halves * C if len(halves) == 1 else halves
    _check_pupil_in_band(optics, halves, pupil_center_rad)
    directions = [pupil_directions(h, samples, pupil=pupil, center_rad=pupil_center_rad)
                  for h in halves]
    shifts = np.stack([layer_shifts_px(mpi.depths, d, optics.pitch, a) for a in directions])
    return warp_over(mpi, shift_homographies(shifts), premultiplied=premultiplied, queue=queue)


def _reals(name: str, value, form: str) -> tuple:
    """``value`` as a tuple of finite floats of the length ``form`` names; anything else is
    refused by ``name``."""
    n = form.count(",") + 1
    items = None if isinstance(value, (str, bytes)) or np.ndim(value) != 1 else list(value)
    if items is None or len(items) != n:
        raise ValueError(f"{name} must be {form}, got {value!r}")
    return tuple(validate.real_scalar(name, v, fix=f"give {form}") for v in items)


def perspective_view(mpi: MPI, *, fx_pixels: float, translation=(0.0, 0.0, 0.0),
                     fy_pixels: Optional[float] = None,
                     principal_point: Optional[Tuple[float, float]] = None,
                     depths=None, premultiplied: bool = True,
                     queue: Optional["cl.CommandQueue"] = None) -> np.ndarray:
    """The MPI seen by a translated pinhole camera: per-plane homography, then "over".

    The reference camera sits at the origin looking along the MPI's depth axis (OpenCV axes:
    x right, y down, z forward) with focal lengths ``fx, fy`` and principal point ``(cx, cy)``
    in pixels; layer ``i`` is the fronto-parallel plane ``z = depths[i]``. The new camera sits
    at ``translation = (tx, ty, tz)`` (same units as ``depths``), not rotated. A plane at depth
    ``d`` maps by ``x' = cx + (x - cx) d / (d - tz) - fx tx / (d - tz)`` (and the same in
    ``y``): for a sideways move each plane shifts by ``-fx tx / d`` pixels, as Stereo
    Magnification renders (its render multiple ``m`` is ``tx = m * xoffset``).

    Parameters
    ----------
    mpi : MPI
    fx_pixels : float
        Horizontal focal length in pixels.
    translation : (float, float, float)
        Camera position in the units of ``depths``; ``tz`` must stay in front of every plane.
    fy_pixels : float, optional
        Vertical focal length in pixels (default ``fx_pixels``).
    principal_point : (float, float), optional
        ``(cx, cy)`` in pixels (default the image centre ``((W - 1) / 2, (H - 1) / 2)``); only
        matters when ``tz != 0``.
    depths : array_like, shape (L,), optional
        The planes' depths in the camera's units, nearest first (default ``mpi.depths``). Pass
        the scene depths when the MPI was re-placed in metres (e.g. the twain MPI's ``mpi.json``
        depths 1..100 rather than the millimetres it is rendered at).
    premultiplied : bool
        Interpolate ``c * a`` (default) or the straight colour as Stereo Magnification does.
    queue : pyopencl.CommandQueue, optional

    Returns
    -------
    ndarray, shape (H, W, C), float32
    """
    mpi = _check_mpi(mpi)
    H, W = mpi.shape
    fx = validate.real_scalar("fx_pixels", fx_pixels)
    fy = fx if fy_pixels is None else validate.real_scalar("fy_pixels", fy_pixels)
    if fx <= 0 or fy <= 0:
        raise ValueError(f"fx_pixels and fy_pixels must be > 0 pixels, got {fx}, {fy}")
    tx, ty, tz = _reals("translation", translation, "(tx, ty, tz) in metres")
    if principal_point is None:
        cx, cy = (W - 1) / 2.0, (H - 1) / 2.0
    else:
        cx, cy = _reals("principal_point", principal_point, "(cx, cy) in pixels")
    if depths is None:
        d = mpi.depths
    else:
        try:
            d = np.asarray(depths, dtype=np.float64)
        except (TypeError, ValueError):
            raise ValueError(f"depths must be {mpi.layers} numbers in metres, got "
                             f"{depths!r}") from None
        if d.shape != (mpi.layers,) or not np.all(np.isfinite(d)) or np.any(np.diff(d) <= 0) \
                or np.any(d <= 0):
            raise ValueError(f"depths must be {mpi.layers} finite positive values, strictly "
                             f"increasing (nearest first), got {np.asarray(depths).tolist()}")
    if np.any(d - tz <= 0):
        raise ValueError(f"translation tz = {tz} puts the camera at or behind the nearest "
                         f"plane (depth {d[0]}); tz must be smaller than every depth")
    # output -> source: x = cx + (x' - cx) (d - tz) / d + fx tx / d
    k = (d - tz) / d
    hom = np.zeros((mpi.layers, 3, 3))
    hom[:, 0, 0] = k
    hom[:, 0, 2] = cx - cx * k + fx * tx / d
    hom[:, 1, 1] = k
    hom[:, 1, 2] = cy - cy * k + fy * ty / d
    hom[:, 2, 2] = 1.0
    return warp_over(mpi, hom, premultiplied=premultiplied, queue=queue)
