"""Random-phase wave splatting of Gaussians (RPWS): the slow, exact baseline (docs/rpws.md).

Each 3D Gaussian, EWA-projected to the view (:func:`clholo.io.splats.project`), is a
screen-parallel 2-D Gaussian at its own depth ``d_k`` with opacity footprint
``alpha_k(x) = min(0.99, o_k exp(-1/2 (x - m_k)^T S_k^-1 (x - m_k)))`` (0 outside its 3-sigma
box and below 1/255, the 3DGS rules) and linear colour ``c_k``. Sorted back to front, the field
is carried from primitive to primitive as the MPI recursion carries it from layer to layer::

    u <- sqrt(1 - alpha_k) u + sqrt(c_k alpha_k) exp(i phi_k);   u <- ASM(u, d_k - d_{k-1})

ending on z = 0; T frames with fresh phases, per colour. This is the MPI method with one layer
per primitive: no depth quantisation, no slab merging.

* :class:`Primitives` -- the screen-space Gaussians at metric depths, nearest first.
* :func:`primitives_from_splats` -- ``.ply``/Gaussians + camera -> primitives (with optional
  seeded subsampling, stated in the returned ``info``), depths mapped to metres linearly in
  inverse scene depth (:func:`metric_depths`).
* :func:`merge_depths` -- the optional (off by default) depth merging.
* :func:`render_rpws` -- the holograms ``[T, C, H, W]`` on the OpenCL device
  (``host/rpws.py`` orders the launches, ``kernels/rpws.cl`` composites one footprint).
* :func:`primitives_to_mpi` -- the same footprints binned into L slabs (the paper's MPI from
  Gaussians, HOLOGRAPHY.md section 7) for a like-for-like MPI-vs-RPWS comparison.

A render folder by RPWS is ``clholo render X.ply --method rpws`` (the method registry,
:mod:`clholo.methods`, and :func:`clholo.render_folder.render_to_folder`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional, Tuple

import numpy as np

__all__ = ["Primitives", "metric_depths", "merge_depths", "subsample_visible",
           "primitives_from_projected", "primitives_from_splats", "render_rpws",
           "rpws_padded_shape", "primitives_to_mpi"]

from clholo.io.splats import subsample_visible  # scene code, re-exported for old imports

ALPHA_MAX = 0.99
ALPHA_MIN = 1.0 / 255.0


@dataclass(frozen=True, eq=False)
class Primitives:
    """K screen-parallel 2-D Gaussians at depths behind the hologram plane, nearest first.

    Attributes
    ----------
    xy : ndarray (K, 2) float32
        Centres in pixels ``(x, y)``; pixel (row, col) has its centre at ``(y, x) = (row, col)``.
    conic : ndarray (K, 3) float32
        Inverse 2-D covariance ``(a, b, c)`` in px^-2: the exponent is
        ``-1/2 (a dx^2 + c dy^2) - b dx dy``.
    opacity : ndarray (K,) float32, in [0, 1]
    color : ndarray (K, C) float32
        Linear intensity in [0, 1].
    depths : ndarray (K,) float64
        Metres behind the hologram plane, > 0, nondecreasing.
    radius : ndarray (K,) float64
        Half-width in pixels of the square bounding box (3 sigma of the major axis).
    shape : (int, int)
        Image ``(H, W)``.
    """

    xy: np.ndarray
    conic: np.ndarray
    opacity: np.ndarray
    color: np.ndarray
    depths: np.ndarray
    radius: np.ndarray
    shape: Tuple[int, int]

    def __post_init__(self) -> None:
        from clholo import validate

        H, W = validate.shape2d(self.shape, name="shape")
        object.__setattr__(self, "shape", (H, W))
        color = np.asarray(self.color, np.float32)
        if color.ndim == 1:
            color = color[:, None]
        K = color.shape[0]
        for name, arr, want in (("xy", self.xy, (K, 2)), ("conic", self.conic, (K, 3)),
                                ("opacity", self.opacity, (K,)), ("radius", self.radius, (K,)),
                                ("depths", self.depths, (K,))):
            a = np.asarray(arr, np.float64 if name in ("depths", "radius") else np.float32)
            if a.shape != want:
                raise ValueError(f"{name} must have shape {want} (K = {K} primitives from "
                                 f"color), got {a.shape}")
            if not np.all(np.isfinite(a)):
                raise ValueError(f"{name} contains NaN/inf; every value must be finite")
            object.__setattr__(self, name, np.ascontiguousarray(a))
        if K == 0:
            raise ValueError("no primitives: RPWS needs at least one Gaussian in view")
        if not np.all(np.isfinite(color)) or color.min() < 0 or color.max() > 1:
            raise ValueError("color must be linear intensity in [0, 1] (decode sRGB first)")
        if self.opacity.min() < 0 or self.opacity.max() > 1:
            raise ValueError("opacity must lie in [0, 1]")
        if np.any(self.radius < 0):
            raise ValueError("radius must be >= 0 pixels")
        a, b, c = (self.conic[:, i].astype(np.float64) for i in range(3))
        bad = ~((a > 0) & (a * c - b * b > 0))
        if bad.any():
            # the footprint's exponent -(a dx^2 + c dy^2)/2 - b dx dy grows away from the
            # centre: every footprint would fill its box at the clamp (a hologram of squares)
            k, more = int(np.argmax(bad)), int(bad.sum()) - 1
            raise ValueError(f"conic of primitive {k} is {self.conic[k].tolist()}"
                             f"{f' ({more} more like it)' if more else ''}: an inverse "
                             f"covariance (a, b, c) must be positive definite (a > 0, "
                             f"a c - b^2 > 0); it is the inverse of the 2-D covariance in "
                             f"px^-2, as clholo.io.splats.project gives it")
        validate.depths(self.depths, name="depths", positive=True)
        if np.any(np.diff(self.depths) < 0):
            raise ValueError("depths must be nondecreasing (primitives sorted nearest first); "
                             "sort all arrays by depth")
        object.__setattr__(self, "color", np.ascontiguousarray(color))

    def __len__(self) -> int:
        return int(self.color.shape[0])

    @property
    def channels(self) -> int:
        """Number of colour channels ``C``."""
        return int(self.color.shape[1])

    def with_depths(self, depths) -> "Primitives":
        """The same primitives at other depths (metres, nondecreasing)."""
        return Primitives(self.xy, self.conic, self.opacity, self.color, depths, self.radius,
                          self.shape)

    def subset(self, index) -> "Primitives":
        """Primitives ``index`` (kept in depth order)."""
        i = np.sort(np.asarray(index, np.int64))
        return Primitives(self.xy[i], self.conic[i], self.opacity[i], self.color[i],
                          self.depths[i], self.radius[i], self.shape)

    def boxes(self) -> np.ndarray:
        """``(K, 4)`` int64 ``(x0, y0, x1, y1)`` bounding boxes (end exclusive) on the image."""
        from clholo.reference.rpws import rpws_boxes

        return rpws_boxes(self.xy, self.radius, self.shape)

    def footprints(self, *, alpha_max: float = ALPHA_MAX, alpha_min: float = ALPHA_MIN):
        """Yield ``(k, box, alpha)`` with ``alpha`` float32 over ``box`` (the kernel's values).

        Parameters
        ----------
        alpha_max, alpha_min : float
            Footprint clamp and cut (3DGS: 0.99 and 1/255).
        """
        from clholo import validate
        from clholo.reference.rpws import rpws_footprint

        alpha_max, alpha_min = validate.alpha_cut(alpha_max, alpha_min)  # before the first
        return ((k, box, rpws_footprint(self.xy[k], self.conic[k], self.opacity[k], box,
                                        alpha_max=alpha_max, alpha_min=alpha_min))
                for k, box in enumerate(self.boxes()))

    def over(self, *, alpha_max: float = ALPHA_MAX, alpha_min: float = ALPHA_MIN) -> np.ndarray:
        """Ray-optics all-in-focus "over" composite ``(H, W, C)`` float64 (nearest on top).

        Parameters
        ----------
        alpha_max, alpha_min : float
            Footprint clamp and cut (3DGS: 0.99 and 1/255).
        """
        out = np.zeros(self.shape + (self.channels,), np.float64)
        fps = list(self.footprints(alpha_max=alpha_max, alpha_min=alpha_min))
        for k, (x0, y0, x1, y1), a in reversed(fps):
            a = a.astype(np.float64)[..., None]
            out[y0:y1, x0:x1] = out[y0:y1, x0:x1] * (1 - a) + self.color[k] * a
        return out


def metric_depths(scene_depth: np.ndarray, near: float, far: float) -> np.ndarray:
    """Camera depths (scene units) to metres behind the hologram, linear in inverse depth.

    The nearest primitive lands on ``near``, the farthest on ``far``; equal steps of disparity
    become equal steps of metres (the MPI's "inverse" slab spacing placed by index).

    Parameters
    ----------
    scene_depth : array ``(K,)``
        Camera depths, scene units.
    near, far : float
        Metres behind the hologram plane of the nearest and farthest primitive.
    """
    from clholo import validate

    near = validate.distance(near, name="near")
    far = validate.distance(far, name="far")
    if not 0 < near < far:
        raise ValueError(f"near and far must satisfy 0 < near < far (metres), got {near}, {far}")
    z = np.asarray(scene_depth, np.float64)
    if z.size == 0 or np.any(z <= 0) or not np.all(np.isfinite(z)):
        raise ValueError("scene depths must be finite and > 0 (camera z in scene units)")
    inv = 1.0 / z
    span = inv.max() - inv.min()
    t = (inv.max() - inv) / span if span > 0 else np.zeros_like(inv)
    return near + t * (far - near)


def merge_depths(depths: np.ndarray, tolerance: Optional[float]) -> np.ndarray:
    """Snap nearly equal depths to one plane (option; off with ``None`` or 0).

    Greedy over the sorted depths: a group starts at its nearest member and takes every
    following depth within ``tolerance`` metres of that start; all members get the group's
    mean depth. Primitives of a group are still composited one by one (each with its own
    phases) but without propagation between them, so the method becomes an MPI with one layer
    per group. The result is nondecreasing.
    """
    d = np.asarray(depths, np.float64)
    if tolerance is None or tolerance == 0:
        return d.copy()
    from clholo import validate

    tol = validate.real_scalar("merge_tolerance", tolerance)
    if tol < 0:
        raise ValueError(f"merge_tolerance must be >= 0 metres, got {tolerance!r}")
    validate.distance(tol, name="merge_tolerance")  # millimetres as metres: a warning
    out = d.copy()
    start = 0
    for i in range(1, len(d) + 1):
        if i == len(d) or d[i] - d[start] > tol:
            out[start:i] = d[start:i].mean()
            start = i
    return np.maximum.accumulate(out)


def primitives_from_projected(proj, shape: Tuple[int, int], *, near: float,
                              far: float) -> Primitives:
    """:class:`clholo.io.splats.Projected` (sorted, sRGB colour) -> :class:`Primitives`
    (linear colour, :func:`metric_depths`).

    Parameters
    ----------
    proj : clholo.io.splats.Projected
        Splats projected through a camera (:func:`clholo.io.splats.project`).
    shape : (int, int)
        Image ``(H, W)``.
    near, far : float
        Metres behind the hologram plane of the nearest and farthest primitive.
    """
    from clholo.io.images import srgb_to_linear

    if len(proj.opacity) == 0:
        raise ValueError("no splat is in front of the camera and inside the image; check the "
                         "camera pose")
    color = srgb_to_linear(np.clip(proj.color, 0, 1)).astype(np.float32)
    return Primitives(proj.xy, proj.conic, np.clip(proj.opacity, 0, 1), color,
                      metric_depths(proj.depth, near, far), proj.radius.astype(np.float64),
                      shape)


def primitives_from_splats(source, *, camera=None, near: float = 2e-3, far: float = 6e-3,
                           max_splats: Optional[int] = None, seed: int = 0, width: int = 512,
                           height: Optional[int] = None, fov_deg: float = 50.0,
                           znear: Optional[float] = None):
    """3DGS ``.ply`` (or :class:`~clholo.io.splats.Gaussians`) -> ``(primitives, info)``.

    Parameters
    ----------
    source : path-like or Gaussians
    camera : clholo.io.splats.Camera, optional
        Default :func:`clholo.io.splats.default_camera` (``width``, ``height``, ``fov_deg``).
    near, far : float
        Metres behind the hologram plane of the nearest and farthest primitive.
    max_splats : int, optional
        Keep at most this many visible splats (uniform random subset, ``seed``).
    seed : int
        Seed of that subset.
    width, height : int
        The default camera's image size, pixels.
    fov_deg : float
        The default camera's horizontal field of view, degrees.
    znear : float, optional
        Near plane in scene units (default :func:`clholo.io.splats.auto_znear`).

    Returns
    -------
    primitives : Primitives
    info : dict
        ``"subsampling"`` (a sentence), ``"splats"`` (kept), ``"gaussians"`` (the subset, to
        build an MPI from the same splats), ``"camera"``, ``"scene_depth"`` (min, max).
    """
    from clholo.io.splats import Gaussians, default_camera, project, read_ply

    g = source if isinstance(source, Gaussians) else read_ply(source)
    if camera is None:
        camera = default_camera(g, width=width, height=height, fov_deg=fov_deg)
    sub, note = subsample_visible(g, camera, max_splats, seed=seed, znear=znear)
    proj = project(sub, camera, znear=znear)
    prims = primitives_from_projected(proj, (camera.height, camera.width), near=near, far=far)
    info = {"subsampling": note, "splats": len(prims), "gaussians": sub, "camera": camera,
            "scene_depth": (float(proj.depth.min()), float(proj.depth.max()))}
    return prims, info


def rpws_padded_shape(primitives: Primitives, optics, *, pad="auto") -> Tuple[int, int]:
    """The padded grid (sides ``2^a 3^b 5^c``) every propagation step of :func:`render_rpws` uses.

    Parameters
    ----------
    primitives : Primitives
        The Gaussians (their image shape and depths set the grid).
    optics : Optics
        Pitch and wavelengths, metres.
    pad : "auto", float or (int, int)
        As for :func:`render_rpws`.
    """
    from clholo import reference
    from clholo.propagation import device_padded_shape

    steps = reference.layer_steps(primitives.depths)
    steps = steps[steps != 0]
    return device_padded_shape(primitives.shape, steps if steps.size else [0.0],
                               wavelength=optics.wavelengths, pitch=optics.pitch, pad=pad)


def render_rpws(primitives: Primitives, optics, *, frames: int = 24, seed: int = 0, pad="auto",
                band_limit: bool = True, merge_tolerance: Optional[float] = None,
                alpha_max: float = ALPHA_MAX, alpha_min: float = ALPHA_MIN,
                progress=None, out=None, queue=None):
    """RPWS holograms at the hologram plane, ``[T, C, H, W]`` complex64.

    Parameters
    ----------
    primitives : Primitives
        K Gaussians, nearest first, depths in metres.
    optics : clholo.Optics
        Pitch and one wavelength per colour channel.
    frames : int
        T frames with fresh phases (paper: 24).
    seed : int
        Philox key; primitive k draws the MPI stream's layer k (docs/rpws.md).
    pad : "auto", float or (int, int)
        Padding of every step (:func:`rpws_padded_shape` tells the grid).
    merge_tolerance : float, optional
        Metres; off by default. When given, depths within the tolerance are snapped together
        (:func:`merge_depths`) and the steps between them vanish.
    alpha_max, alpha_min : float
        Footprint clamp and cut (3DGS: 0.99 and 1/255).
    progress : callable, optional
        ``progress(done, total)`` with primitive-steps done, after every host wait (a command
        passes :meth:`clholo.progress.StepLog.tracker`).
    out : pyopencl.array.Array, optional
        Device array to render into (and return); else a NumPy array comes back.
    band_limit : bool
        Apply the Matsushima-Shimobaba band limit to every step (default).
    queue : pyopencl.CommandQueue, optional
        Queue to run on (default: clholo's default device, ``CLHOLO_DEVICE``).
    """
    from clholo import validate
    from clholo.host.rpws import RPWSRenderer

    if not isinstance(primitives, Primitives):
        raise TypeError(f"primitives must be clholo.baselines.rpws.Primitives, got "
                        f"{type(primitives).__name__}")
    T = validate.count(frames, name="frames")
    if merge_tolerance:
        primitives = primitives.with_depths(merge_depths(primitives.depths, merge_tolerance))
    renderer = RPWSRenderer(primitives, optics, seed=seed, pad=pad, band_limit=band_limit,
                            alpha_max=alpha_max, alpha_min=alpha_min, queue=queue)
    if progress is not None and not callable(progress):
        raise TypeError(f"progress must be a callable progress(done, total) or None, got "
                        f"{progress!r}")
    result = renderer.render(T, out=out, progress=progress)
    return result if out is not None else result.get()


def primitives_to_mpi(primitives: Primitives, layers: int, *, alpha_max: float = ALPHA_MAX,
                      alpha_min: float = ALPHA_MIN):
    """The same footprints binned into ``layers`` slabs: an MPI (the paper's data path).

    Slabs are uniform in metres between the nearest and farthest primitive (uniform in inverse
    scene depth, see :func:`metric_depths`); each slab sits at its centre. Inside a slab, front
    to back, ``alpha_d = 1 - prod(1 - alpha_k)``, ``c_d = sum_k alpha_k c_k prod_{j<k}(1 -
    alpha_j) / alpha_d`` (HOLOGRAPHY.md section 7), in linear colour: the RPWS of the same
    primitives differs only by depth quantisation and the slab merge. NumPy; reduced sizes.

    Parameters
    ----------
    primitives : Primitives
        The Gaussians.
    layers : int
        Number of slabs.
    alpha_max, alpha_min : float
        Footprint clamp and cut (3DGS: 0.99 and 1/255).
    """
    from clholo import validate
    from clholo.scene import MPI

    L = validate.count(layers, name="layers")
    d = primitives.depths
    d0, d1 = float(d[0]), float(d[-1])
    if d1 <= d0:
        d1 = d0 * (1 + 1e-6) + 1e-9
    slab = np.clip(np.floor((d - d0) / (d1 - d0) * L), 0, L - 1).astype(np.int64)
    centres = d0 + (np.arange(L) + 0.5) / L * (d1 - d0)
    H, W = primitives.shape
    C = primitives.channels
    trans = np.ones((L, H, W), np.float64)      # prod(1 - alpha) of the slab so far
    premult = np.zeros((L, H, W, C), np.float64)
    for k, (x0, y0, x1, y1), a in primitives.footprints(alpha_max=alpha_max,
                                                        alpha_min=alpha_min):
        s = slab[k]
        a = a.astype(np.float64)
        tr = trans[s, y0:y1, x0:x1]
        premult[s, y0:y1, x0:x1] += (a * tr)[..., None] * primitives.color[k]
        trans[s, y0:y1, x0:x1] = tr * (1 - a)
    alpha = 1 - trans
    color = np.where(alpha[..., None] > 0, premult / np.maximum(alpha, 1e-30)[..., None], 0.0)
    return MPI(np.clip(color, 0, 1).astype(np.float32), alpha.astype(np.float32), centres)
