"""One registry of hologram methods: every command chooses its method here.

Each :class:`Method` has one signature: a loaded :class:`clholo.scenes.Scene`, the optics, the
seed, the padding and a queue give a *renderer*, which streams hologram frames::

    renderer = METHODS["mpi"].renderer(scene, optics, seed=0, pad="auto")
    for t0, frames in renderer.iter_frames(T, start=0, progress=None):
        ...   # complex64 [n, C, H, W], frames t0 .. t0+n-1

Frame ``t`` is the same hologram whatever the batching and whatever ``start``: the phases depend
on the absolute frame index. So ``clholo batch`` can render frame ranges of any method in
parts and assemble them bit for bit equal to ``clholo render --method ...``.

Where the frames are used on the device (the display loop encodes them there), every renderer
also writes them into a device buffer of the caller's, with the same frame semantics::

    out = pyopencl.array.empty(renderer.queue, (n, C, H, W), numpy.complex64)
    renderer.enqueue_frames(t0, n, out)     # frames t0 .. t0+n-1, bit for bit iter_frames'

=========  ===============================================================  =============
name       what                                                             renders from
=========  ===============================================================  =============
``mpi``    the paper's method: occlusion-aware wave-domain compositing      an MPI
``rgbd``   the RGB-D baseline: every layer propagated alone and summed      an MPI
``rpws``   random-phase wave splatting, one layer per Gaussian (slow)       splat primitives
=========  ===============================================================  =============

The math of each method lives with the method (:mod:`clholo.hologram`,
:mod:`clholo.baselines`); this module only names them.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Dict, Iterator, Optional, Tuple

import numpy as np

__all__ = ["Method", "METHODS", "get_method"]


@dataclass(frozen=True)
class Method:
    """A hologram method.

    Attributes
    ----------
    name : str
    needs : {"mpi", "primitives"}
        What it renders from (:func:`clholo.scenes.load`'s ``needs``).
    summary : str
        One line for ``--help`` and reports.
    build : callable
        ``build(scene, optics, *, seed, pad, queue) -> renderer`` with ``.padded`` (the padded
        grid ``(Hp, Wp)``), ``.frames_per_batch``, ``.queue`` (its
        ``pyopencl.CommandQueue``), ``.prepare(frames)`` (build every OpenCL program
        rendering ``frames`` frames needs, render nothing: commands time the builds apart from
        the render) and two ways to the same frames:

        * ``.iter_frames(frames, *, start=0, progress=None)``: ``(t0, NumPy complex64
          [n, C, H, W])`` per batch, frames ``t0 .. t0+n-1``;
        * ``.enqueue_frames(frame0, n, out)``: frames ``frame0 .. frame0+n-1`` written into
          ``out``, a C-contiguous pyopencl complex64 array ``[n, C, H, W]`` on ``.queue``'s
          device, in launches of at most ``frames_per_batch`` frames; returns ``out``, the work
          enqueued on ``.queue`` (it may not have finished: read ``out`` through that queue).

        Frame ``t`` is the same hologram, bit for bit, through either and whatever the
        batching: its phases depend on the absolute frame index.
    """

    name: str
    needs: str
    summary: str
    build: Callable

    def renderer(self, scene, optics, *, seed: int = 0, pad="auto", queue=None):
        """The renderer of ``scene`` (a :class:`clholo.scenes.Scene`) by this method.

        Parameters
        ----------
        scene : clholo.scenes.Scene
            What to render (loaded with what the method needs).
        optics : Optics
            Pitch and one wavelength per channel, metres.
        seed : int
            Key of the phase stream.
        pad : "auto", float or (int, int)
            Padding of each propagation.
        queue : pyopencl.CommandQueue, optional
            Queue to run on (default: clholo's default device, ``CLHOLO_DEVICE``).
        """
        return self.build(scene, optics, seed=seed, pad=pad, queue=queue)

    def render(self, scene, optics, *, frames: int, seed: int = 0, pad="auto", start: int = 0,
               progress: Optional[Callable[[int, int], None]] = None,
               queue=None) -> np.ndarray:
        """All ``frames`` holograms, complex64 ``[frames, C, H, W]`` (frames ``start`` ..
        ``start + frames - 1``).

        Parameters
        ----------
        scene : clholo.scenes.Scene
            What to render.
        optics : Optics
            Pitch and one wavelength per channel, metres.
        frames : int
            Number of frames.
        seed : int
            Key of the phase stream.
        pad : "auto", float or (int, int)
            Padding of each propagation.
        start : int
            Absolute index of the first frame.
        progress : callable ``(done, total)``, optional
            Called as frames finish.
        queue : pyopencl.CommandQueue, optional
            Queue to run on (default: clholo's default device, ``CLHOLO_DEVICE``).
        """
        from clholo import validate

        # before any work: start a whole number, and every frame inside the phase stream
        # (the RPWS kernel's uint frame counter wrapped past 2**32 to frame 0's phases)
        start, frames = validate.frame_range(start, frames)
        renderer = self.renderer(scene, optics, seed=seed, pad=pad, queue=queue)
        out = None
        for t0, batch in renderer.iter_frames(frames, start=start, progress=progress):
            if out is None:
                out = np.empty((frames,) + batch.shape[1:], np.complex64)
            out[t0 - start:t0 - start + batch.shape[0]] = batch
        return out

    def reference_view(self, scene) -> np.ndarray:
        """What the scene looks like all in focus (ray-optics "over"), ``[H, W, C]``."""
        return scene.primitives.over() if self.needs == "primitives" else scene.mpi.over()

    def depths(self, scene) -> np.ndarray:
        """The scene's depths in metres, nearest first."""
        return np.asarray(scene.primitives.depths if self.needs == "primitives"
                          else scene.mpi.depths)


class _MPIStream:
    """Adapts :class:`clholo.host.scheduler.HologramRenderer` to the method signature (frame
    batches with a progress callback counting frames)."""

    def __init__(self, renderer):
        self._r = renderer
        self.padded = renderer.padded
        self.frames_per_batch = renderer.frames_per_batch
        self.queue = renderer.queue

    def enqueue_frames(self, frame0: int, n: int, out):
        """Frames ``frame0 .. frame0+n-1`` into the device array ``out`` (complex64
        ``[n, C, H, W]``), enqueued; returns ``out`` (:meth:`HologramRenderer.enqueue_frames
        <clholo.host.scheduler.HologramRenderer.enqueue_frames>`)."""
        return self._r.enqueue_frames(frame0, n, out)

    def prepare(self, frames: int) -> None:
        """Build the OpenCL programs rendering ``frames`` frames needs
        (:meth:`HologramRenderer.prepare <clholo.host.scheduler.HologramRenderer.prepare>`)."""
        self._r.prepare(frames)

    def iter_frames(self, frames: int, *, start: int = 0,
                    progress: Optional[Callable[[int, int], None]] = None
                    ) -> Iterator[Tuple[int, np.ndarray]]:
        done = 0
        for t0, batch in self._r.iter_frames(frames, start=start):
            done += batch.shape[0]
            if progress is not None:
                progress(done, frames)
            yield t0, batch


def _mpi(scene, optics, *, seed, pad, queue):
    from clholo.host.scheduler import HologramRenderer

    return _MPIStream(HologramRenderer(scene.mpi, optics, seed=seed, pad=pad, queue=queue))


def _rgbd(scene, optics, *, seed, pad, queue):
    from clholo.baselines.rgbd import rgbd_renderer

    return _MPIStream(rgbd_renderer(scene.mpi, optics, seed=seed, pad=pad, queue=queue))


def _rpws(scene, optics, *, seed, pad, queue):
    from clholo.host.rpws import RPWSRenderer

    if scene.primitives.channels != optics.channels:
        from clholo.errors import InputError

        raise InputError(f"the splats have {scene.primitives.channels} colour channels but "
                         f"{optics.channels} wavelength(s) were given; give three")
    return RPWSRenderer(scene.primitives, optics, seed=seed, pad=pad, queue=queue)


METHODS: Dict[str, Method] = {
    m.name: m for m in (
        Method("mpi", "mpi", "the paper's method: wave-domain alpha compositing of the MPI "
                             "layers, back to front", _mpi),
        Method("rgbd", "mpi", "RGB-D baseline: every layer propagated on its own and summed "
                              "(no occlusion between layers)", _rgbd),
        Method("rpws", "primitives", "random-phase wave splatting: one layer per 3D Gaussian, "
                                     "no depth quantisation (slow, exact; .ply only)", _rpws),
    )
}


def get_method(name: str) -> Method:
    """The method called ``name``, or an error listing the methods."""
    try:
        return METHODS[name]
    except KeyError:
        from clholo.errors import InputError

        raise InputError(f"unknown method {name!r}; choose one of "
                         f"{', '.join(METHODS)}") from None
