"""The oracle's core: FFT, angular spectrum propagation, the Philox phase stream and the MPI
recursion (complex128/float64; ``docs/conventions.md`` line by line).

The kernel families' references (:mod:`clholo.reference.views`, ...) import what they need
from here; :mod:`clholo.reference` re-exports all of it.
"""

from __future__ import annotations

import math
from typing import Callable, Iterable, Optional, Sequence, Tuple, Union

import numpy as np

__all__ = [
    "fft2", "ifft2", "frequency_grid", "band_limit_mask", "transfer_function",
    "apply_transfer_function", "kernel_spread_pixels", "padded_shape", "propagate",
    "philox4x32_10", "random_phase", "composite_layer", "mpi_hologram", "focal_slice",
    "focal_stack", "over_composite", "round_trip", "even_strip_factors", "layer_blocks",
]

Pad = Union[str, float, int, Tuple[int, int]]

# Philox4x32-10 constants (Salmon et al., SC'11; Random123's philox.h)
PHILOX_M0 = np.uint64(0xD2511F53)
PHILOX_M1 = np.uint64(0xCD9E8D57)
PHILOX_W0 = np.uint32(0x9E3779B9)
PHILOX_W1 = np.uint32(0xBB67AE85)
TWO_PI_F32 = np.float32(2 * np.pi)


# --------------------------------------------------------------------------------------------
# FFT
# --------------------------------------------------------------------------------------------

def fft2(a: np.ndarray) -> np.ndarray:
    """Unnormalised forward 2-D FFT over the last two axes, complex128."""
    return np.fft.fft2(np.asarray(a, dtype=np.complex128))


def ifft2(a: np.ndarray) -> np.ndarray:
    """Inverse 2-D FFT (with ``1/(H W)``) over the last two axes, complex128."""
    return np.fft.ifft2(np.asarray(a, dtype=np.complex128))


# --------------------------------------------------------------------------------------------
# Angular spectrum method
# --------------------------------------------------------------------------------------------

def frequency_grid(shape: Tuple[int, int], pitch: float) -> Tuple[np.ndarray, np.ndarray]:
    """Spatial frequencies ``(fy[:, None], fx[None, :])`` in cycles/metre, unshifted order.

    Exactly ``k / (N * pitch)``: ``np.fft.fftfreq(N, d=pitch)``.
    """
    H, W = shape
    return np.fft.fftfreq(H, d=pitch)[:, None], np.fft.fftfreq(W, d=pitch)[None, :]


def band_limit_mask(shape: Tuple[int, int], dz: float, *, wavelength: float,
                    pitch: float) -> np.ndarray:
    """Matsushima-Shimobaba band limit on the (padded) grid ``shape``; bool ``[H, W]``.

    ``|f| < 1 / (lambda * sqrt((2 * df * dz)^2 + 1))`` per axis with ``df = 1 / (N * pitch)``.
    """
    fy, fx = frequency_grid(shape, pitch)
    H, W = shape
    limit_y = 1.0 / (wavelength * math.sqrt((2.0 * dz / (H * pitch)) ** 2 + 1.0))
    limit_x = 1.0 / (wavelength * math.sqrt((2.0 * dz / (W * pitch)) ** 2 + 1.0))
    return (np.abs(fy) < limit_y) & (np.abs(fx) < limit_x)


def transfer_function(shape: Tuple[int, int], dz: float, *, wavelength: float, pitch: float,
                      band_limit: bool = True) -> np.ndarray:
    """Angular spectrum transfer function ``H`` on grid ``shape`` (complex128, unshifted).

    ``H = exp(2j pi dz sqrt(1/lambda^2 - fx^2 - fy^2))`` where the root is real, else 0
    (evanescent waves are dropped), times the band limit when ``band_limit``.
    The phase is split into the carrier ``2 pi dz / lambda`` (reduced mod 2 pi) and the rest,
    ``-2 pi dz f^2 / (1/lambda + sqrt(1/lambda^2 - f^2))``, which keeps full precision even at
    centimetres where the phase itself is ~1e6 rad.
    """
    fy, fx = frequency_grid(shape, pitch)
    f2 = fx ** 2 + fy ** 2
    inv_l2 = 1.0 / wavelength ** 2
    propagating = f2 < inv_l2
    root = np.sqrt(np.where(propagating, inv_l2 - f2, 0.0))
    carrier = math.fmod(2.0 * math.pi * dz / wavelength, 2.0 * math.pi)
    rest = -2.0 * math.pi * dz * f2 / (1.0 / wavelength + root)
    H = np.where(propagating, np.exp(1j * (carrier + rest)), 0.0)
    if band_limit:
        H = H * band_limit_mask(shape, dz, wavelength=wavelength, pitch=pitch)
    return H.astype(np.complex128)


def apply_transfer_function(field: np.ndarray, H: np.ndarray,
                            padded: Tuple[int, int]) -> np.ndarray:
    """``crop(IFFT2(FFT2(pad(field)) * H))`` with top-left placement; complex128.

    ``field`` is ``[..., h, w]``; ``H`` is ``[..., Hp, Wp]`` (broadcast over leading axes).
    Circular convolution is shift-equivariant, so top-left placement gives the same result as
    centring the field in the padded frame.
    """
    field = np.asarray(field, dtype=np.complex128)
    h, w = field.shape[-2:]
    Hp, Wp = padded
    big = np.zeros(field.shape[:-2] + (Hp, Wp), np.complex128)
    big[..., :h, :w] = field
    out = np.fft.ifft2(np.fft.fft2(big) * H)
    return out[..., :h, :w]


def kernel_spread_pixels(dz: float, *, wavelength: float, pitch: float) -> int:
    """How far (pixels, per side) the band-limited ASM kernel spreads light over ``dz``.

    ``|dz| * tan(asin(lambda / (2 p))) / p``, rounded up: the steepest ray the grid can carry.
    """
    s = min(1.0, wavelength / (2.0 * pitch))
    if s >= 1.0:
        return 1 << 30  # evanescent-limited only: spread unbounded in practice
    return int(math.ceil(abs(dz) * math.tan(math.asin(s)) / pitch))


def padded_shape(shape: Tuple[int, int], dz: float, *, wavelength: float, pitch: float,
                 pad: Pad = "auto") -> Tuple[int, int]:
    """Padded grid for propagating a field of ``shape`` by ``dz``.

    Parameters
    ----------
    pad : "auto", float or (int, int)
        ``"auto"``: ``min(N + spread, 2 N)`` per axis, the smallest frame in which the kernel's
        spread (:func:`kernel_spread_pixels`) does not wrap around onto the field; 2 N already
        suffices for any distance because the band limit caps the spread at half the padded
        frame. A number: that factor per axis, rounded up (1 = circular convolution, 2 = the
        classic linear convolution). A pair: exactly that padded shape (each >= the field's).
    """
    from clholo.validate import pad as _valid_pad

    pad = _valid_pad(pad)  # None, a bool, a shape of fractions: refused by name
    H, W = shape
    if isinstance(pad, str):
        if pad != "auto":
            raise ValueError(f"pad must be 'auto', a factor >= 1 or a shape (Hp, Wp), got {pad!r}")
        n = kernel_spread_pixels(dz, wavelength=wavelength, pitch=pitch)
        return min(H + n, 2 * H), min(W + n, 2 * W)
    if isinstance(pad, (tuple, list, np.ndarray)):
        if len(pad) != 2:
            raise ValueError(f"pad as a shape must be (Hp, Wp), got {pad!r}")
        Hp, Wp = int(pad[0]), int(pad[1])
        if Hp < H or Wp < W:
            raise ValueError(f"pad shape {(Hp, Wp)} is smaller than the field {(H, W)}")
        return Hp, Wp
    factor = float(pad)
    if not np.isfinite(factor) or factor < 1:
        raise ValueError(f"pad factor must be >= 1, got {pad!r}")
    return int(math.ceil(H * factor)), int(math.ceil(W * factor))


def propagate(field: np.ndarray, dz: float, *, wavelength: float, pitch: float,
              pad: Pad = "auto", band_limit: bool = True) -> np.ndarray:
    """Angular spectrum propagation of ``field`` by ``dz`` metres; complex128 ``[..., H, W]``.

    ``u' = crop(IFFT2(FFT2(pad(u)) * H * B))`` (see :func:`transfer_function`,
    :func:`padded_shape`). Positive ``dz`` moves towards the viewer (+z).
    """
    field = np.asarray(field)
    if field.ndim < 2:
        raise ValueError(f"field must be at least 2-D [..., H, W], got shape {field.shape}")
    padded = padded_shape(field.shape[-2:], dz, wavelength=wavelength, pitch=pitch, pad=pad)
    H = transfer_function(padded, dz, wavelength=wavelength, pitch=pitch, band_limit=band_limit)
    return apply_transfer_function(field, H, padded)


# --------------------------------------------------------------------------------------------
# Random phases: Philox4x32-10
# --------------------------------------------------------------------------------------------

def _mulhilo32(a: np.ndarray, b: np.uint64) -> Tuple[np.ndarray, np.ndarray]:
    product = a.astype(np.uint64) * b
    return (product >> np.uint64(32)).astype(np.uint32), (product & np.uint64(0xFFFFFFFF)).astype(np.uint32)


def philox4x32_10(counter: Sequence[np.ndarray], key: Sequence[np.ndarray]) -> Tuple[np.ndarray, ...]:
    """Philox4x32 with 10 rounds, vectorised: four uint32 counter words and two key words
    (arrays broadcasting together) -> four uint32 output words. Matches Random123's
    ``philox4x32`` (and pyopencl's ``pyopencl-random123/philox.cl``)."""
    c0, c1, c2, c3 = (np.asarray(c, dtype=np.uint32) for c in counter)
    k0, k1 = (np.asarray(k, dtype=np.uint32) for k in key)
    c0, c1, c2, c3, k0, k1 = np.broadcast_arrays(c0, c1, c2, c3, k0, k1)
    k0 = k0.copy()
    k1 = k1.copy()
    with np.errstate(over="ignore"):
        for r in range(10):
            if r > 0:  # bump the key between rounds
                k0 = k0 + PHILOX_W0
                k1 = k1 + PHILOX_W1
            hi0, lo0 = _mulhilo32(c0, PHILOX_M0)
            hi1, lo1 = _mulhilo32(c2, PHILOX_M1)
            c0, c1, c2, c3 = hi1 ^ c1 ^ k0, lo1, hi0 ^ c3 ^ k1, lo0
    return c0, c1, c2, c3


def phase_from_word(x: np.ndarray) -> np.ndarray:
    """float32 phase in [0, 2 pi] from a uint32 word: ``2 pi ((x >> 8) + 0.5) 2^-24``.

    Each step is one correctly rounded float32 operation, in this order, exactly as
    ``kernels/random_phase.h`` does it, so the device reproduces it bit for bit.
    """
    t = (np.asarray(x, dtype=np.uint32) >> np.uint32(8)).astype(np.float32) + np.float32(0.5)
    return (t * np.float32(2.0 ** -24)) * TWO_PI_F32


def seed_key(seed: int) -> Tuple[np.uint32, np.uint32]:
    """Philox key ``(seed & 0xffffffff, seed >> 32)`` for an integer seed in [0, 2^64).

    Floats, bools and strings are refused (``seed=1.5`` would otherwise give seed 1's phases)."""
    from clholo.validate import seed as _valid_seed

    seed = _valid_seed(seed)
    return np.uint32(seed & 0xFFFFFFFF), np.uint32(seed >> 32)


def random_phase(shape: Tuple[int, int], *, seed: int, frame: int, colour: int,
                 layer: int) -> np.ndarray:
    """Uniform random phases ``[H, W]`` float32 in [0, 2 pi] for one (frame, colour, layer).

    Pixel ``p = y W + x``; Philox counter ``(p // 4, layer, frame, colour)``; key from
    :func:`seed_key`; word ``p % 4`` of the output; float conversion :func:`phase_from_word`.
    ``frame``, ``colour`` and ``layer`` are whole numbers in ``[0, 2**32)`` (the counter's
    32-bit words): a float (2.7 would be frame 2) or an index outside is refused, not cut or
    wrapped into another index's phases (``clholo.errors.InputTypeError`` or
    ``clholo.errors.InputError``).
    """
    from clholo import validate

    H, W = validate.shape2d(shape, name="shape")
    n = H * W
    k0, k1 = seed_key(seed)
    frame = validate.stream_index(frame, name="frame")
    colour = validate.stream_index(colour, name="colour")
    layer = validate.stream_index(layer, name="layer")
    blocks = np.arange((n + 3) // 4, dtype=np.uint32)
    words = philox4x32_10((blocks, np.uint32(layer), np.uint32(frame), np.uint32(colour)),
                          (k0, k1))
    stacked = np.stack(words, axis=1).reshape(-1)[:n]  # word p % 4 of block p // 4
    return phase_from_word(stacked).reshape(H, W)


# --------------------------------------------------------------------------------------------
# The MPI recursion (paper Eq. mpi_random_tm)
# --------------------------------------------------------------------------------------------

def round_trip(x: np.ndarray, n: int, *, axis: str, first: str = "forward",
               multiply: Optional[np.ndarray] = None, mid_n: Optional[int] = None,
               mid: Optional[Callable[[np.ndarray], np.ndarray]] = None) -> np.ndarray:
    """A forward and an inverse FFT of every line with a pointwise step between them (the
    reference of :class:`clholo.fft.RoundTripPlan`); complex128, the shape of ``x``.

    Parameters
    ----------
    x : array ``[..., rows, cols]``, complex
        Lines are its rows (``axis="rows"``) or its columns (``axis="cols"``), zero-padded to
        ``n`` for the first transform.
    n : int
        Transform length (>= the line length).
    first : {"forward", "inverse"}
        The first transform's direction; the second is the other (NumPy's: ``1/n`` on the
        inverse).
    multiply : array ``frame`` or ``(M,) + frame``, optional
        Factor after the first transform, ``frame = (n, cols)`` for columns and ``(rows, n)``
        for rows; batch element ``b`` (flattened leading axes) uses ``multiply[b % M]``.
    mid_n : int, optional
        Elements kept after the first transform (default ``n``); the rest become zero.
    mid : callable, optional
        Applied after the multiply to the kept part: an array ``[B, rows, mid_n]`` (rows) or
        ``[B, mid_n, cols]`` (columns), ``B`` the flattened batch; returns the same shape.
    """
    x = np.asarray(x, np.complex128)
    shape = x.shape
    rows, cols = shape[-2:]
    v = x.reshape((-1, rows, cols))
    ax = -1 if axis == "rows" else -2
    if axis not in ("rows", "cols"):
        raise ValueError(f"axis={axis!r}: use 'rows' or 'cols'")
    f1, f2 = (np.fft.fft, np.fft.ifft) if first == "forward" else (np.fft.ifft, np.fft.fft)
    v = f1(v, n=n, axis=ax)
    if multiply is not None:
        m = np.asarray(multiply, np.complex128)
        if m.ndim == 2:
            m = m[None]
        v = v * m[np.arange(v.shape[0]) % m.shape[0]]
    mid_n = n if mid_n is None else int(mid_n)
    keep = (slice(None), slice(None), slice(0, mid_n)) if axis == "rows" else \
        (slice(None), slice(0, mid_n), slice(None))
    kept = v[keep]
    if mid is not None:
        kept = np.asarray(mid(kept), np.complex128)
    w = np.zeros_like(v)
    w[keep] = kept
    out = f2(w, axis=ax)
    out = out[..., :cols] if axis == "rows" else out[:, :rows, :]
    return out.reshape(shape)


def even_strip_factors(multiply: np.ndarray, lanes: int, *, axis: str) -> np.ndarray:
    """Even factor frames laid out strip by strip (the reference of
    :meth:`clholo.fft.RoundTripPlan.even_factors` on CPU strips, kernel ``fft_even_strips``).

    Parameters
    ----------
    multiply : array ``(M,) + frame``
        Frames even in both indices, ``frame = (n, lines)`` for columns and ``(lines, n)`` for
        rows (:func:`round_trip`'s ``multiply``).
    lanes : int
        Lines per strip.
    axis : {"rows", "cols"}

    Returns
    -------
    ndarray ``[M, S, n // 2 + 1, lanes]``, ``S = ceil(lines / lanes)``
        ``out[f, s, k, l]`` is frame ``f``'s factor of line ``min(c, (lines - c) % lines)``
        (``c = s lanes + l``; zero where ``c >= lines``) and element ``k``: the lower half of
        the elements of every line, each line's value read from the frame's quarter.
    """
    m = np.asarray(multiply)
    if m.ndim == 2:
        m = m[None]
    if axis == "rows":
        m = m.transpose(0, 2, 1)
    elif axis != "cols":
        raise ValueError(f"axis={axis!r}: use 'rows' or 'cols'")
    M, n, lines = m.shape
    S = -(-lines // lanes)
    c = np.arange(S * lanes)
    folded = np.minimum(c, (lines - c) % lines)
    out = m[:, : n // 2 + 1][:, :, np.where(c < lines, folded, 0)]
    out[:, :, c >= lines] = 0
    return np.ascontiguousarray(out.reshape(M, n // 2 + 1, S, lanes).transpose(0, 2, 1, 3))


def layer_blocks(color: np.ndarray, alpha: np.ndarray, *,
                 rows: int = 8) -> Tuple[np.ndarray, np.ndarray]:
    """One MPI layer as the composites read it with ``CLHOLO_LAYER_BLOCKS`` (the reference of
    kernels ``layer_blocks``, ``kernels/composite_cpu.cl``, eight rows to a block: the CPU
    renderer's; and ``layer_planes``, ``kernels/composite.cl``, one row to a block: the GPU
    renderer's planes): its amplitude and transmission, ``rows`` rows to a block.

    Parameters
    ----------
    color : array ``[H, W, C]`` or ``[H, W]``
        Linear colour, float32.
    alpha : array ``[H, W]``
        Alpha in [0, 1], float32.
    rows : {8, 1}
        Rows per block ``R`` (``CLHOLO_LAYER_ROWS``).

    Returns
    -------
    amp : ndarray float32 ``[S, C, W, R]``, ``S = ceil(H / R)``
        ``amp[s, c, x, l] = sqrt(color[R s + l, x, c] * alpha[R s + l, x])`` in float32 (each
        step correctly rounded, as the kernels compute it: the same bits). With ``rows=1``
        that is ``[H, C, W, 1]``: each colour's rows contiguous.
    keep : ndarray float32 ``[S, W, R]``
        ``keep[s, x, l] = sqrt(1 - alpha[R s + l, x])``. Rows past ``H`` are transparent:
        amp 0, keep 1.
    """
    if rows not in (8, 1):
        raise ValueError(f"rows={rows!r}: blocks are 8 rows (CPU strips) or 1 (planes)")
    a = np.asarray(alpha, np.float32)
    c = np.asarray(color, np.float32)
    if c.ndim == 2:
        c = c[..., None]
    H, W = a.shape
    S = -(-H // rows)
    a_pad = np.zeros((S * rows, W), np.float32)
    a_pad[:H] = a
    c_pad = np.zeros((S * rows, W, c.shape[-1]), np.float32)
    c_pad[:H] = c
    amp = np.sqrt(c_pad * a_pad[..., None])                    # [R S, W, C] float32
    keep = np.sqrt(np.float32(1) - a_pad)
    amp = amp.reshape(S, rows, W, -1).transpose(0, 3, 2, 1)   # [S, C, W, R]
    keep = keep.reshape(S, rows, W).transpose(0, 2, 1)        # [S, W, R]
    return np.ascontiguousarray(amp), np.ascontiguousarray(keep)


def composite_layer(u: np.ndarray, color: np.ndarray, alpha: np.ndarray,
                    phase: np.ndarray) -> np.ndarray:
    """Wave-domain "over": ``sqrt(1 - a) u + sqrt(c a) exp(1j phi)``; complex128."""
    a = np.asarray(alpha, np.float64)
    c = np.asarray(color, np.float64)
    return np.sqrt(1.0 - a) * u + np.sqrt(c * a) * np.exp(1j * np.asarray(phase, np.float64))


def layer_steps(depths: Sequence[float]) -> np.ndarray:
    """Propagation distance after each layer, indexed like ``depths`` (nearest first):
    ``d_i - d_{i-1}`` with ``d_0 = 0``, i.e. from layer i forward to layer i-1 (or to z = 0)."""
    d = np.asarray(depths, np.float64)
    return np.diff(np.concatenate([[0.0], d]))


def mpi_hologram(color: np.ndarray, alpha: np.ndarray, depths: Sequence[float], *,
                 wavelengths: Sequence[float], pitch: float, frames: int = 1, seed: int = 0,
                 pad: Pad = "auto", band_limit: bool = True) -> np.ndarray:
    """Random-phase MPI holograms ``[T, C, H, W]`` complex128 at the hologram plane (z = 0).

    Parameters
    ----------
    color : array, shape (L, H, W, C)
        Linear intensity in [0, 1], layers nearest first.
    alpha : array, shape (L, H, W)
    depths : array, shape (L,)
        Metres behind the hologram plane, increasing.
    wavelengths : sequence of C floats, metres
    pitch : float, metres
    frames : int
        T, the number of time-multiplexed frames (fresh phases each).
    seed : int
    pad : see :func:`padded_shape`; applied per propagation step.
    """
    color = np.asarray(color)
    alpha = np.asarray(alpha)
    L, H, W, C = color.shape
    if len(wavelengths) != C:
        raise ValueError(f"wavelengths has {len(wavelengths)} entries for {C} colour channels")
    steps = layer_steps(depths)
    out = np.zeros((frames, C, H, W), np.complex128)
    for t in range(frames):
        for c, lam in enumerate(wavelengths):
            u = np.zeros((H, W), np.complex128)
            for i in range(L - 1, -1, -1):  # back to front
                phi = random_phase((H, W), seed=seed, frame=t, colour=c, layer=i)
                v = composite_layer(u, color[i, :, :, c], alpha[i], phi)
                u = propagate(v, steps[i], wavelength=lam, pitch=pitch, pad=pad,
                              band_limit=band_limit)
            out[t, c] = u
    return out


def focal_slice(holograms: np.ndarray, depth: float, *, wavelengths: Sequence[float],
                pitch: float, pad: Pad = "auto", band_limit: bool = True) -> np.ndarray:
    """Frame-averaged intensity ``[C, H, W]`` seen focused at ``depth`` metres behind the
    hologram: ``mean_t |ASM(u_t, -depth)|^2`` per colour."""
    holograms = np.asarray(holograms)
    T, C, H, W = holograms.shape
    out = np.zeros((C, H, W), np.float64)
    for c, lam in enumerate(wavelengths):
        u = propagate(holograms[:, c], -depth, wavelength=lam, pitch=pitch, pad=pad,
                      band_limit=band_limit)
        out[c] = np.mean(np.abs(u) ** 2, axis=0)
    return out


def focal_stack(holograms: np.ndarray, depths: Iterable[float], **kwargs) -> np.ndarray:
    """:func:`focal_slice` at each depth: ``[D, C, H, W]`` float64."""
    return np.stack([focal_slice(holograms, d, **kwargs) for d in depths])


def over_composite(color: np.ndarray, alpha: np.ndarray) -> np.ndarray:
    """Ray-optics "over" of layers nearest first: ``sum_i c_i a_i prod_{j<i}(1 - a_j)``."""
    color = np.asarray(color, np.float64)
    alpha = np.asarray(alpha, np.float64)
    out = np.zeros(color.shape[1:], np.float64)
    for i in range(color.shape[0] - 1, -1, -1):
        a = alpha[i][..., None] if color.ndim == 4 else alpha[i]
        out = out * (1.0 - a) + color[i] * a
    return out
