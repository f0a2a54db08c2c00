"""The conventional RGB-D layer-based hologram (HOLOGRAPHY.md section 7): the baseline the
paper's MPI method is compared with.

The depth map is quantised into ``L`` uniform bins over ``[near, far]`` (the same planes as the
MPI made from the same RGB-D image), mask ``m_i`` = the pixels in bin ``i``, and each layer
``sqrt(c) m_i exp(i phi_i)`` is propagated to the hologram plane and the layers are SUMMED: no
occlusion, so light of a far layer leaks past the edges of a nearer one (halos, dark seams).

Phases, frames, seed and padded grid are exactly the MPI method's (the Philox stream indexed
by layer, frame and colour), so the two differ only in occlusion. On the device each layer's
emission ``sqrt(c m)`` (equal to ``sqrt(c) m`` for hard masks) is propagated from its own depth
straight to the hologram plane and added (``HologramRenderer(occlusion=False)``): one
propagation per layer, the cost of the MPI method. Its padded grid covers the farthest layer's
spread (the MPI recursion's covers the largest step), so with ``pad="auto"`` it can be larger.
"""

from __future__ import annotations

from typing import Optional

import numpy as np

from clholo.scene import MPI, Optics

__all__ = ["rgbd_layers", "rgbd_renderer", "render_rgbd_hologram"]


def rgbd_layers(image, depth, *, layers: int, near: float, far: float, **kwargs) -> MPI:
    """Hard depth masks of an RGB-D image as an ``L``-layer MPI (alpha = ``m_i`` in {0, 1}).

    The same binning as :func:`clholo.io.rgbd.rgbd_to_mpi` with ``mode="hard"`` (keywords are
    passed on: ``depth_kind``, ``invalid``, ``depth_range``, ``srgb``, ...), so the MPI hologram
    and the RGB-D hologram of an image use the same planes.

    Parameters
    ----------
    image : array ``(H, W, 3)``
        The colour image.
    depth : array ``(H, W)``
        Its depth (or disparity, ``depth_kind``).
    layers : int
        Number of planes ``L``.
    near, far : float
        Metres behind the hologram plane of the nearest and farthest plane.
    **kwargs
        Passed to :func:`clholo.io.rgbd.rgbd_to_mpi` (above).
    """
    from clholo.io.rgbd import rgbd_to_mpi

    if kwargs.get("mode", "hard") != "hard":
        raise ValueError("the RGB-D baseline uses hard masks: leave mode out (or 'hard')")
    kwargs.pop("mode", None)
    return rgbd_to_mpi(image, depth, layers=layers, near=near, far=far, mode="hard", **kwargs)


def rgbd_renderer(layers: MPI, optics: Optics, *, seed: int = 0, pad="auto",
                  band_limit: bool = True, memory_budget: Optional[int] = None,
                  queue=None):
    """A :class:`clholo.host.scheduler.HologramRenderer` of the layer sum (``occlusion=False``):
    build once, render many times (``.render(frames)``, ``.iter_frames(frames)``).

    Parameters
    ----------
    layers : MPI
        Colour and hard masks at depths in metres (:func:`rgbd_layers`).
    optics : Optics
        Pitch and one wavelength per channel, metres.
    seed : int
        Key of the phase stream.
    pad : "auto", float or (int, int)
        As :func:`clholo.render_hologram`.
    band_limit : bool
        Apply the Matsushima-Shimobaba band limit to every step (default).
    memory_budget : int, optional
        Bytes of device memory to plan for (default: half of the device's).
    queue : pyopencl.CommandQueue, optional
        Queue to run on (default: clholo's default device, ``CLHOLO_DEVICE``).
    """
    from clholo import validate
    from clholo.host.scheduler import HologramRenderer

    if not isinstance(layers, MPI):
        raise TypeError(f"layers must be a clholo.MPI of masks (rgbd_layers), got "
                        f"{type(layers).__name__}")
    return HologramRenderer(layers, optics, seed=validate.seed(seed), pad=pad,
                            band_limit=band_limit, memory_budget=memory_budget,
                            occlusion=False, queue=queue)


def render_rgbd_hologram(layers: MPI, optics: Optics, *, frames: int = 24, seed: int = 0,
                         pad="auto", band_limit: bool = True,
                         memory_budget: Optional[int] = None, queue=None) -> np.ndarray:
    """RGB-D layer-sum holograms ``[T, C, H, W]`` complex64 at the hologram plane.

    Parameters
    ----------
    layers : MPI
        Colour and hard masks (alpha in {0, 1}) at depths in metres: :func:`rgbd_layers`.
        A soft alpha is accepted and summed with emission ``sqrt(c a)`` (an additive MPI).
    optics : Optics
    frames : int
        ``T`` (paper: 24), fresh phases per frame: the MPI method's stream.
    seed : int
    pad : "auto", float or (int, int)
        As :func:`clholo.render_hologram`; the same grid for the same depths.
    band_limit : bool
        Apply the Matsushima-Shimobaba band limit to every step (default).
    memory_budget : int, optional
        Bytes of device memory to plan for (default: half of the device's).
    queue : pyopencl.CommandQueue, optional
        Queue to run on (default: clholo's default device, ``CLHOLO_DEVICE``).

    Returns
    -------
    numpy.ndarray, complex64 ``[T, C, H, W]``
    """
    from clholo import validate

    T = validate.count(frames, name="frames")
    renderer = rgbd_renderer(layers, optics, seed=seed, pad=pad, band_limit=band_limit,
                             memory_budget=memory_budget, queue=queue)
    return renderer.render(T).get()
