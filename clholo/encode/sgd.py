r"""SGD phase retrieval: phase-only SLM patterns for complex holograms (the paper's lab path).

For each frame and colour, find the SLM phase ``P`` such that ``s * ASM(exp(1j P), z_slm)``
matches the complex hologram (the target, ``z_slm`` in front of the SLM; paper: 4 cm). The loss
of field ``b`` is the relative complex-field error at the least-squares scale,

.. math::

    L_b = \frac{\sum w \, |s_b y_b - t_b|^2}{\sum w \, |t_b|^2} \in [0, 1], \qquad
    y_b = \mathrm{ASM}(e^{i P_b}, z_\mathrm{slm}),

with ``w`` optional region-of-interest weights (each multiplies its pixel's squared error) and
``s_b = sum w conj(y) t / sum w |y|^2`` fitted in closed form every iteration (not by Adam). Its
gradient is ``2 Im(g conj(x))`` with ``g = ASM(conj(s) w (s y - t), -z_slm) / sum w |t|^2``
(the adjoint of ASM is ASM by ``-z`` with the same band limit and padded grid); see
:mod:`clholo.reference.encode`. Adam (PyTorch's form) updates ``P``. Everything runs on the
device for all frames and colours of a batch at once
(:class:`clholo.host.phase_retrieval.PhaseRetrieval`); the loss is read back every
``check_every`` iterations for the progress bar and the stopping test.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import List, Optional, Tuple, Union

import numpy as np
import pyopencl as cl
import pyopencl.array as cla

from clholo._arrays import resolve_queue, to_device
from clholo.errors import InputError, InputTypeError
from clholo.scene import Optics

__all__ = ["SGDResult", "sgd_encode", "slm_padded_shape"]


@dataclass
class SGDResult:
    """What :func:`sgd_encode` returns.

    Attributes
    ----------
    phase : ndarray float32 ``[T, C, H, W]``
        SLM phases in radians (not wrapped; :func:`clholo.encode.quantize` wraps).
    loss : ndarray float32 ``[T, C]``
        Final loss ``L_b`` of each field.
    history : list of (int, ndarray [T, C])
        Losses read back during the run: ``(k, L)`` with ``L`` the loss after ``k - 1`` steps
        (per batch of frames, concatenated over batches of the same step counts).
    iterations : int
        Steps run (the largest over batches; the stopping test may end a batch early).
    padded : (int, int)
        The propagation grid.
    max_iterations : int
        The largest number of steps asked for (``iterations`` of :func:`sgd_encode`).
    tol : float
        The stopping tolerance (0: no early stop).
    batch_iterations : tuple of int
        Steps run by each batch of frames, in order.
    scale : ndarray complex64 ``[T, C]``
        Fitted scale ``s_b`` of every field at the final phase: ``s_b ASM(exp(1j P_b), z_slm)``
        best matches the target, so ``|s_b|^2`` is the illumination power (relative to a unit
        plane wave on the SLM) that field needs to show the complex hologram's brightness.
        Phase-only patterns change the colour balance; :meth:`colour_balance` gives the laser
        power ratios that restore it.
    """

    phase: np.ndarray
    loss: np.ndarray
    history: List[Tuple[int, np.ndarray]]
    iterations: int
    padded: Tuple[int, int]
    scale: np.ndarray
    max_iterations: int = 0
    tol: float = 0.0
    batch_iterations: Tuple[int, ...] = ()

    def stop_reason(self) -> str:
        """Why SGD stopped, in a few words: ``"tolerance 0.0001 reached at 180"`` (the loss
        fell by less than ``tol`` between two readings), ``"tolerance 0.0001 not reached"`` or
        ``"tol 0: no early stop"`` (every iteration run)."""
        if not self.tol > 0:
            return "tol 0: no early stop"
        early = [n for n in self.batch_iterations if n < self.max_iterations]
        if not early:
            return f"tolerance {self.tol:g} not reached"
        if len(self.batch_iterations) == 1:
            return f"tolerance {self.tol:g} reached at {early[0]}"
        at = f"{early[0]}" if min(early) == max(early) else f"{min(early)}..{max(early)}"
        return (f"tolerance {self.tol:g} reached at {at} in {len(early)} of "
                f"{len(self.batch_iterations)} batches of frames")

    def colour_balance(self) -> np.ndarray:
        """Laser power per colour ``[C]`` that restores the complex hologram's colour balance,
        normalised so that the largest is 1: ``mean_t |s_tc|^2 / max_c mean_t |s_tc|^2``
        (the laser power of a colour is shared by its frames; intensity goes as ``|s|^2``)."""
        power = np.mean(np.abs(self.scale.astype(np.complex128)) ** 2, axis=0)
        top = float(power.max())
        if not top > 0:
            raise ValueError("every fitted scale is zero: the patterns reach none of the target")
        return power / top


def slm_padded_shape(shape: Tuple[int, int], optics: Optics, z_slm: float, *, pad="auto"
                     ) -> Tuple[int, int]:
    """The padded grid (sides ``2^a 3^b 5^c``) on which SLM -> hologram-plane propagation by ``z_slm`` runs
    (every wavelength of ``optics``).

    Parameters
    ----------
    shape : (int, int)
        ``(H, W)`` of the patterns, pixels.
    optics : Optics
        Pitch and wavelengths, metres.
    z_slm : float
        SLM -> hologram plane distance, metres.
    pad : "auto", float or (int, int)
        ``"auto"`` (what the band-limited kernel's spread over ``z_slm`` needs), a factor, or
        the grid itself.
    """
    from clholo.propagation import device_padded_shape

    return device_padded_shape(shape, z_slm, wavelength=optics.wavelengths,
                               pitch=optics.pitch, pad=pad)


def _check_holograms(holograms, optics: Optics) -> Tuple[int, int, int, int]:
    from clholo._arrays import check_holograms

    return check_holograms(holograms, optics)


def _check_z(z_slm) -> float:
    from clholo import validate

    return validate.distance(z_slm, name="z_slm", nonzero=True)


#: Largest amplitudes SGD takes as they are: [2^-20, 2^20]. Its loss sums |field|^2 over a
#: frame in float32; far outside (1e19: inf, every phase NaN; 1e-25: zero, nothing fitted) the
#: target is first brought to a largest amplitude near 1 (:func:`_amplitude_exponent`).
SGD_AMPLITUDE_EXPONENTS = (-20, 20)


def _amplitude_exponent(holograms, dholo) -> int:
    """``k`` such that ``holograms / 2^k`` has its largest amplitude near 1, or 0 where it
    already lies in ``2^SGD_AMPLITUDE_EXPONENTS``. The fit does not depend on the target's
    scale (the fitted ``scale`` takes it, and the loss is relative), and a division by a power
    of two is exact: the patterns are the scaled target's, and a hologram of ordinary amplitude
    is not touched at all (the same bits as before)."""
    if isinstance(holograms, np.ndarray):
        largest = float(np.abs(holograms).max())  # by hypot: no overflow of the squares
    else:
        from clholo.host.phase_retrieval import field_max_abs

        # on the device, from |u|^2 in float32 (kernels take buffers without offsets)
        largest = float(field_max_abs(dholo if dholo.offset == 0 else dholo.copy()).get().max())
        if not 2.0 ** -60 < largest < 2.0 ** 60:  # the squares may have overflowed or
            largest = float(np.abs(dholo.get()).max())  # underflowed: read the values once
    if not largest > 0:  # all zeros: nothing to scale (SGD says what it cannot fit)
        return 0
    tiny = float(np.finfo(np.float32).tiny)
    if largest < tiny:
        # every value is a float32 subnormal: a few significant bits are left (1e-44 keeps 3),
        # and 2^-k itself would be beyond float32 (the patterns were NaN)
        raise InputError(
            f"holograms reach an amplitude of only {largest:.3g}, below float32's smallest "
            f"normal number {tiny:.3g}: their values keep only a few significant bits; scale "
            f"them up before they are stored as complex64 (in float64 or complex128)")
    exponent = int(np.round(np.log2(largest)))
    lo, hi = SGD_AMPLITUDE_EXPONENTS
    return exponent if not lo <= exponent <= hi else 0


def sgd_encode(holograms, optics: Optics, *, z_slm: float = 0.04, iterations: int = 200,
               lr: float = 0.05, init: Union[str, np.ndarray] = "target", seed: int = 0,
               tol: float = 0.0, check_every: int = 10, roi: Optional[np.ndarray] = None,
               pad="auto", frames_per_batch: Optional[int] = None, progress=True,
               queue: Optional["cl.CommandQueue"] = None) -> SGDResult:
    """Phase-only SLM patterns for complex holograms by SGD (Adam) with a complex-field loss.

    Parameters
    ----------
    holograms : array complex64 ``[T, C, H, W]`` (NumPy or device)
        Complex targets at the hologram plane, ``z_slm`` in front of the SLM.
    optics : Optics
        Pitch and one wavelength per channel (metres).
    z_slm : float
        SLM -> hologram plane distance, metres (paper: 0.04).
    iterations : int
        Largest number of Adam steps.
    lr : float
        Adam learning rate (radians per step, roughly).
    init : "target", "random" or array ``[T, C, H, W]``
        Initial phase: the phase of the target propagated back to the SLM plane
        (``ASM(t, -z_slm)``), uniform random on ``[0, 2 pi)`` from ``seed``, or given.
    seed : int
        Seed of the random initial phase.
    tol : float
        Stop a batch when the mean loss falls by less than ``tol`` (relative) between two
        readings; 0 runs every iteration.
    check_every : int
        Iterations between loss readings (the only host synchronisation).
    roi : array ``[H, W]``, optional
        Region of interest of the loss: 0/1, or weights that multiply each pixel's squared
        error (0.5 halves a pixel's contribution to the loss and its gradient).
    pad : "auto", float or (int, int)
        Padding of both propagations (:func:`clholo.propagation.device_padded_shape`).
    frames_per_batch : int, optional
        Frames optimised together (all colours); default: as many as fit half the device's
        memory.
    progress : bool or callable
        True: a tqdm progress bar with the loss; a callable ``progress(done, total)``: called
        with the iterations done of the largest number (``iterations`` per batch of frames;
        what a command passes, :meth:`clholo.progress.StepLog.tracker`); False: nothing. When
        the tolerance stops a batch early, the total shrinks by the steps it did not run, so
        the bar ends where SGD stopped (``180/180``, not ``200/200``).
    queue : pyopencl.CommandQueue, optional
        Queue to run on (default: clholo's default device, ``CLHOLO_DEVICE``).

    Returns
    -------
    SGDResult
    """
    from clholo import validate
    from clholo.host.phase_retrieval import PhaseRetrieval

    queue = resolve_queue(queue, holograms)
    T, C, H, W = _check_holograms(holograms, optics)
    z_slm = _check_z(z_slm)
    iterations = validate.count(iterations, name="iterations")
    check_every = validate.count(check_every, name="check_every")
    seed = validate.seed(seed)
    lr = validate.real_scalar("lr", lr)
    if not lr > 0:
        raise ValueError(f"lr must be > 0 (radians per step, e.g. 0.05), got {lr}")
    tol = validate.real_scalar("tol", tol)
    if tol < 0:
        raise ValueError(f"tol must be >= 0 (0 runs every iteration), got {tol}")
    padded = slm_padded_shape((H, W), optics, z_slm, pad=pad)
    mask = None
    if roi is not None:
        from clholo.io.images import refuse_complex

        kind = np.asarray(roi).dtype
        if not (np.issubdtype(kind, np.number) or kind == bool):  # a string's dtype is <U
            raise InputTypeError(f"roi must be an array [H, W] of weights (1 = inside, 0 = "
                                 f"outside), got {roi!r:.60}")
        refuse_complex(roi, "roi", "weight map")
        roi = np.asarray(roi, np.float32)
        if roi.shape != (H, W):
            raise ValueError(f"roi must have the field's shape {(H, W)}, got {roi.shape}")
        if not np.all(np.isfinite(roi)) or roi.min() < 0 or not roi.max() > 0:
            raise ValueError("roi must be finite, >= 0 and non-zero somewhere (1 = inside)")
        mask = cla.to_device(queue, roi)
    init_phase = None
    if not isinstance(init, str):
        from clholo.encode.quantize import real_phases

        init_phase = real_phases(init, name="init").astype(np.float32, copy=False)
        if init_phase.shape != (T, C, H, W):
            raise ValueError(f"init as an array must be phases of shape {(T, C, H, W)}, got "
                             f"{init_phase.shape}")
        if not np.all(np.isfinite(init_phase)):
            raise ValueError(f"init holds {int(np.sum(~np.isfinite(init_phase)))} NaN/inf "
                             f"value(s); every initial phase must be finite (radians)")
    elif init not in ("target", "random"):
        raise ValueError(f"init must be 'target', 'random' or an array of phases, got {init!r}")
    Tb = _frames_per_batch(queue, frames_per_batch, T, C, (H, W), padded)

    dholo, _ = to_device(queue, holograms, name="holograms")
    dholo = dholo.reshape((T * C, H, W))
    exponent = _amplitude_exponent(holograms, dholo)
    if exponent:
        dholo = dholo * np.float32(2.0 ** -exponent)
    phase_out = np.empty((T, C, H, W), np.float32)
    loss_out = np.empty((T, C), np.float32)
    scale_out = np.empty((T, C), np.complex64)
    histories: dict = {}
    steps_max = 0
    batch_steps = []
    bar = None
    if not callable(progress) and not isinstance(progress, (bool, np.bool_)):
        raise TypeError(f"progress must be True (a bar), False or a callable "
                        f"progress(done, total), got {progress!r}")
    if callable(progress):
        bar = _CallbackBar(progress, iterations * -(-T // Tb))
    elif progress:
        from tqdm.auto import tqdm

        bar = tqdm(total=iterations * -(-T // Tb), desc="sgd", unit="it", leave=False)
    rng = np.random.default_rng(seed)
    try:
        for t0 in range(0, T, Tb):
            tb = min(Tb, T - t0)
            # a fresh array: kernels take buffers without offsets (a caller's device array may
            # be a view at an offset, e.g. holograms[1:])
            target = (dholo if tb == T and dholo.offset == 0
                      else dholo[t0 * C:(t0 + tb) * C].copy())
            engine = PhaseRetrieval(target, wavelengths=optics.wavelengths, pitch=optics.pitch,
                                    z=z_slm, padded=padded, mask=mask, lr=lr, queue=queue)
            if init_phase is not None:
                p0 = init_phase[t0:t0 + tb].reshape(tb * C, H, W)
            elif init == "random":
                p0 = rng.uniform(0, 2 * np.pi, (tb * C, H, W)).astype(np.float32)
            else:
                p0 = None
            if p0 is None:
                back = engine.propagator.apply(target, engine.tf_adjoint, tf_even=True)
                engine.set_phase(_angle(queue, back))
            else:
                engine.set_phase(cla.to_device(queue, np.ascontiguousarray(p0)))
            sub_bar = _SubBar(bar) if bar is not None else None
            history, steps = engine.run(iterations, check_every=check_every, tol=tol,
                                        progress=sub_bar)
            steps_max = max(steps_max, steps)
            batch_steps.append(int(steps))
            if sub_bar is not None and sub_bar.n < iterations:  # stopped early by tol
                if steps > sub_bar.n:
                    sub_bar.update(steps - sub_bar.n)
                sub_bar.shrink(iterations - steps)  # the bar ends where SGD stopped
            for k, loss in history:
                histories.setdefault(k, []).append(loss.reshape(tb, C))
            loss_out[t0:t0 + tb] = engine.evaluate().reshape(tb, C)
            scale_out[t0:t0 + tb] = engine.scale.get().reshape(tb, C)
            phase_out[t0:t0 + tb] = engine.phase.get().reshape(tb, C, H, W)
    finally:
        if bar is not None:
            bar.close()
    if exponent:  # the fitted scale in the caller's units (a power of two: exact)
        scale_out *= np.float32(2.0 ** exponent)
    history = [(k, np.concatenate(v)) for k, v in sorted(histories.items())]
    return SGDResult(phase=phase_out, loss=loss_out, history=history, iterations=steps_max,
                     padded=padded, scale=scale_out, max_iterations=iterations, tol=tol,
                     batch_iterations=tuple(batch_steps))


class _SubBar:
    """A view of the overall bar for one batch (its own count from 0)."""

    def __init__(self, bar):
        self.bar, self.n = bar, 0

    def update(self, k):
        self.n += k
        self.bar.update(k)

    def set_postfix(self, **kw):
        self.bar.set_postfix(**kw)

    def shrink(self, k):
        """The batch ran ``k`` steps fewer than planned: take them off the total."""
        if hasattr(self.bar, "shrink"):
            self.bar.shrink(k)
        else:  # tqdm
            self.bar.total -= k
            self.bar.refresh()


class _CallbackBar:
    """The bar interface of :class:`_SubBar` over a ``progress(done, total)`` callback."""

    def __init__(self, callback, total: int):
        self.callback, self.total, self.n = callback, int(total), 0
        callback(0, self.total)

    def update(self, k):
        self.n += k
        self.callback(self.n, self.total)

    def set_postfix(self, **kw):
        pass

    def shrink(self, k):
        self.total -= k
        self.callback(self.n, self.total)

    def close(self):
        pass


def _angle(queue, field: "cla.Array") -> "cla.Array":
    """``arg(field)`` as float32 ``[B, H, W]`` on the device (the initial phase)."""
    from clholo.host.phase_retrieval import encode_kernel, runtime

    out = cla.empty(queue, field.shape, np.float32)
    runtime.launch(encode_kernel(queue.context, "field_angle"), queue, (field.size,), None, field.data,
                                                out.data)
    return out


def _frames_per_batch(queue, requested, T, C, shape, padded) -> int:
    if requested is not None:
        from clholo import validate

        return min(T, validate.count(requested, name="frames_per_batch"))
    H, W = shape
    per_frame = C * (2 * 8 * padded[0] * padded[1] + 3 * 8 * H * W + 4 * 4 * H * W)
    budget = queue.device.global_mem_size // 2
    return int(max(1, min(T, budget // max(per_frame, 1))))
