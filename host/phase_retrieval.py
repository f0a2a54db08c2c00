"""Host loop of SGD phase retrieval (HOLOGRAPHY.md section 8; kernels/encode.cl).

:class:`PhaseRetrieval` holds one batch of ``B`` fields (frames x colours, field ``b`` of colour
``b % C``) on the device and runs Adam iterations with no host round trip:

    forward       y <- crop(IFFT2(FFT2(pad(x)) * H(+z)))            (2 fused FFTs)
    field_sums    per-field partial sums of conj(y) t, |y|^2, |t|^2 inside the ROI
    fit_scale     s_b = <y, t> / ||y||^2, w_b = 1 / ||t||^2, loss L_b
    residual      y <- conj(s_b) w_b m (s_b y - t)                 (in place)
    adjoint       g <- crop(IFFT2(FFT2(pad(y)) * H(-z)))           (same grid, same band limit)
    adam          grad = 2 Im(g conj(x)); Adam on P; x <- exp(i P)

The loss buffer ``[B]`` is read back only when the caller asks (every ``k`` iterations).

Device memory (complex64, bytes): ``8 B Hp Wp`` spectrum + FFT work (up to the same again),
``8 B H W`` each for x, y, target, ``4 B H W`` each for P, Adam m, Adam v, gradient, and the
transfer functions ``2 x 8 C Hp Wp``.
"""

from __future__ import annotations

from typing import Optional, Sequence, Tuple

import numpy as np
import pyopencl as cl
import pyopencl.array as cla

from clholo.host import runtime

SUM_LOCAL = 64


def encode_kernel(context: "cl.Context", name: str) -> "cl.Kernel":
    """A kernel of ``kernels/encode.cl`` in float32."""
    return runtime.get_kernel(context, "encode.cl", name,
                              defines={"REAL": "float", "SUM_LOCAL": SUM_LOCAL})


def quads(n: int) -> int:
    """Work-items of the element-wise SGD kernels of ``kernels/encode.cl`` (``phase_to_field``,
    ``phase_gradient_adam``) for ``n`` elements: four each, the last one the ragged end."""
    return max(1, (int(n) + 3) // 4)


# field_sums work-groups a GPU gets per compute unit (all fields together): several resident
# groups per SM/CU hide the loads' latency; CPUs keep the measured cap of 64 per field
_GPU_GROUPS_PER_CU = 8


def sum_groups(n: int, *, compute_units: int = 0, is_cpu: bool = True, batch: int = 1) -> int:
    """Work-groups per field for ``field_sums``: enough to keep a device busy, few enough that
    the second stage (one work-item per field) stays short.

    CPUs (and calls without a device): at most 64 per field, each work-item reading at least
    32 elements. GPUs: ``8 x compute_units`` groups over the ``batch`` fields together (at
    least 64 per field where the field is large enough), each work-item reading at least 4
    elements (issue 23: 64 groups left most of an H100's 132 SMs idle).
    """
    n = int(n)
    if is_cpu or compute_units <= 0:
        return int(max(1, min(64, -(-n // (SUM_LOCAL * 32)))))
    want = max(64, -(-_GPU_GROUPS_PER_CU * int(compute_units) // max(1, int(batch))))
    return int(max(1, min(want, -(-n // (SUM_LOCAL * 4)))))


class PhaseRetrieval:
    """SGD with Adam for phase-only patterns of one batch of fields, all on the device.

    Parameters
    ----------
    target : pyopencl.array.Array, complex64 ``[B, H, W]``
        Complex target at the hologram plane (``z`` in front of the SLM).
    wavelengths : sequence of C floats, metres
        Field ``b`` uses ``wavelengths[b % C]``.
    pitch, z : float
        Metres; ``z > 0`` propagates the SLM field forward to the target.
    padded : (int, int)
        Power-of-two grid of both propagations.
    mask : pyopencl.array.Array float32 ``[H, W]``, optional
        Region of interest (0/1, or weights) of the loss.
    lr, beta1, beta2, eps : float
        Adam (PyTorch's form).
    """

    def __init__(self, target: "cla.Array", *, wavelengths: Sequence[float], pitch: float,
                 z: float, padded: Tuple[int, int], mask: Optional["cla.Array"] = None,
                 lr: float = 0.05, beta1: float = 0.9, beta2: float = 0.999, eps: float = 1e-8,
                 band_limit: bool = True, queue: Optional["cl.CommandQueue"] = None):
        from clholo.propagation import ASMPropagator, transfer_function_cache

        self.queue = queue or target.queue
        q = self.queue
        B, H, W = target.shape
        self.B, self.shape, self.n = B, (H, W), H * W
        self.target = target
        self.mask = mask
        cache = transfer_function_cache(q.context)
        self.tf_forward = cache.get(q, padded, z, wavelengths=wavelengths, pitch=pitch,
                                    band_limit=band_limit)
        self.tf_adjoint = cache.get(q, padded, -z, wavelengths=wavelengths, pitch=pitch,
                                    band_limit=band_limit)
        self.propagator = ASMPropagator(B, (H, W), padded, queue=q)
        self.lr, self.beta1, self.beta2, self.eps = lr, beta1, beta2, eps
        self.x = cla.empty(q, (B, H, W), np.complex64)
        self.y = cla.empty(q, (B, H, W), np.complex64)
        self.phase = cla.empty(q, (B, H, W), np.float32)
        self.adam_m = cla.zeros(q, (B, H, W), np.float32)
        self.adam_v = cla.zeros(q, (B, H, W), np.float32)
        self.grad = cla.zeros(q, (B, H, W), np.float32)
        dev = q.device
        self.groups = sum_groups(self.n, compute_units=int(dev.max_compute_units),
                                 is_cpu=bool(dev.type & cl.device_type.CPU), batch=B)
        self.partial = cla.empty(q, (B, self.groups, 4), np.float32)
        self.scale = cla.empty(q, (B,), np.complex64)
        self.weight = cla.empty(q, (B,), np.float32)
        self.loss = cla.empty(q, (B,), np.float32)
        self._mask_arg = (mask.data if mask is not None else self.weight.data)  # unread if none
        self._k = {name: encode_kernel(q.context, name) for name in
                   ("phase_to_field", "field_sums", "fit_scale", "scaled_residual",
                    "phase_gradient_adam")}
        self.step_count = 0

    def set_phase(self, phase: "cla.Array") -> None:
        """Start from ``phase [B, H, W]`` float32 (copied); resets Adam."""
        self.phase.set(phase) if isinstance(phase, np.ndarray) else cl.enqueue_copy(
            self.queue, self.phase.data, phase.data)
        self.adam_m.fill(0)
        self.adam_v.fill(0)
        self.step_count = 0
        runtime.launch(self._k["phase_to_field"], self.queue, (quads(self.phase.size),), None,
                       self.phase.data, self.x.data, np.uint32(self.phase.size))

    def _forward_and_fit(self) -> None:
        q, k = self.queue, self._k
        self.propagator.apply(self.x, self.tf_forward, out=self.y)
        runtime.launch(k["field_sums"], q, (self.groups * SUM_LOCAL, self.B), (SUM_LOCAL, 1), self.y.data,
                        self.target.data, self._mask_arg, np.uint32(self.mask is not None),
                        np.uint32(self.n), self.partial.data)
        runtime.launch(k["fit_scale"], q, (self.B,), None, self.partial.data, np.uint32(self.groups),
                       self.scale.data, self.weight.data, self.loss.data)

    def gradient(self) -> None:
        """Forward, loss and the residual propagated back: leaves ``g`` in ``self.y``."""
        q, k = self.queue, self._k
        self._forward_and_fit()
        runtime.launch(k["scaled_residual"], q, (self.n, self.B), None, self.y.data, self.target.data,
                             self._mask_arg, np.uint32(self.mask is not None), self.scale.data,
                             self.weight.data)
        self.propagator.apply(self.y, self.tf_adjoint, out=self.y)

    def step(self) -> None:
        """One iteration; afterwards ``self.loss`` holds the loss of the phase *before* it and
        ``self.grad`` that phase's gradient."""
        self.gradient()
        self.step_count += 1
        t = self.step_count
        b1, b2 = self.beta1, self.beta2
        runtime.launch(self._k["phase_gradient_adam"],
            self.queue, (quads(self.phase.size),), None, self.y.data, self.x.data,
            self.phase.data, self.adam_m.data, self.adam_v.data, self.grad.data,
            np.float32(self.lr), np.float32(b1), np.float32(b2), np.float32(1.0 - b1),
            np.float32(1.0 - b2), np.float32(self.eps),
            np.float32(1.0 - b1 ** t), np.float32(1.0 - b2 ** t), np.uint32(self.phase.size))

    def evaluate(self) -> np.ndarray:
        """Loss ``[B]`` of the current phase (forward and fit only), read back."""
        self._forward_and_fit()
        return self.loss.get()

    def run(self, iterations: int, *, check_every: int = 10, tol: float = 0.0,
            progress=None) -> Tuple[list, int]:
        """Up to ``iterations`` steps; every ``check_every`` steps the mean loss is read back
        (the only host synchronisation), shown on ``progress`` (a tqdm bar) and compared with
        the previous reading: a relative decrease below ``tol`` stops the run.

        Returns ``(history, steps)``: ``history`` is a list of ``(step, loss [B])`` with the
        loss of the phase after ``step - 1`` updates."""
        history = []
        previous = None
        done = 0
        for i in range(iterations):
            self.step()
            done += 1
            if (i + 1) % check_every == 0 or i + 1 == iterations:
                loss = self.loss.get()
                history.append((self.step_count, loss))
                mean = float(np.mean(loss))
                if progress is not None:
                    progress.update(done - progress.n)
                    progress.set_postfix(loss=f"{mean:.4g}")
                if previous is not None and tol > 0 and previous - mean < tol * previous:
                    break
                previous = mean
        return history, done
