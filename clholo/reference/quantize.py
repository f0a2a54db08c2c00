"""NumPy reference of ``kernels/quantize.cl``: 8-bit quantisation through exact step tables.

The host quantises a phase with :meth:`clholo.encode.quantize.PhaseLUT.to_gray`: wrap in float64,
then the nearest usable level on the circle. A float32 kernel doing that arithmetic would differ
from it at near-ties. The kernel evaluates the *same function* of its float32 input instead,
from a table:

For float32 inputs ``p`` in ``[lo, hi]``, ``g(p) = to_gray(p)`` is a step function. Its
*breakpoints* are the float32 values ``x`` where ``g(x) != g(previous float32 before x)``; sorted,
``bp[0..n-1]``, with the levels ``lv[0] = g(lo)`` and ``lv[k + 1] = g(bp[k])``. Then, for every
float32 ``p`` in ``[lo, hi]``,

    g(p) = lv[#{k : bp[k] <= p}]

(:func:`quantize_lookup`; the kernel finds the count by comparisons, from a first guess that
cannot change the result). No float32 rounding decides a level: bit for bit the host's result
wherever the table is right.

:func:`step_table` finds every breakpoint, exact by construction:

1. *candidates*: the real values where ``g`` can change, given by the caller
   (:func:`lut_boundaries`: the midpoints between neighbouring usable levels of a lookup table,
   the last one with ``2 pi``, and the wraps ``2 pi k``, each plus ``2 pi k`` for every period
   that meets ``[lo, hi]``);
2. every float32 within ``window`` steps of a candidate (in float32 order) is evaluated with the
   host's own function, vectorised, and each change between two adjacent float32 values is a
   breakpoint: several breakpoints close together are all found;
3. between two windows ``g`` must be constant: the values at both ends of every gap are
   compared, and a gap whose ends differ (a change the candidates missed) is bisected in float32
   order down to two adjacent values; a window goes around the change found and the sweep runs
   again. Only an even number of changes inside one gap that cancel out could escape, which the
   candidates exclude: inside a period, between two candidates, the wrapped phase grows with
   ``p`` and the nearest level stays the same.

Float32 order: the ordinal of a float32 is its bit pattern as a signed integer, negated for
negative values, so that ``-0.0`` and ``+0.0`` share ordinal 0 (they compare equal in the kernel
too) and neighbouring floats have neighbouring ordinals.
"""

from __future__ import annotations

import math
from typing import Callable, Sequence, Tuple

import numpy as np

__all__ = ["QUANTIZE_NAN", "QUANTIZE_INF", "QUANTIZE_BELOW", "QUANTIZE_ABOVE",
           "float32_ordinal", "float32_from_ordinal", "lut_boundaries", "step_table",
           "lut_table", "quantize_lookup", "quantize_phase"]

#: error flags of the kernel (``kernels/quantize.cl``), OR-ed per colour
QUANTIZE_NAN = 1
QUANTIZE_INF = 2
QUANTIZE_BELOW = 4
QUANTIZE_ABOVE = 8

TWO_PI = 2.0 * math.pi


def float32_ordinal(x) -> np.ndarray:
    """int64 ordinals of float32 values: monotone in the value, neighbours differ by 1, ``-0.0``
    and ``+0.0`` both 0."""
    bits = np.asarray(x, np.float32).view(np.int32).astype(np.int64)
    return np.where(bits < 0, -(bits & 0x7FFFFFFF), bits)


def float32_from_ordinal(o) -> np.ndarray:
    """The float32 values of ordinals (:func:`float32_ordinal`'s inverse; 0 gives ``+0.0``)."""
    o = np.asarray(o, np.int64)
    bits = np.where(o < 0, (-o) | 0x80000000, o).astype(np.uint32)
    return bits.view(np.float32)


def lut_boundaries(phases: Sequence[float], usable_levels: int, lo: float, hi: float
                   ) -> np.ndarray:
    """Where the forward map of a lookup table can change, float64, within ``[lo, hi]`` (plus a
    period on each side): ``2 pi k`` and ``2 pi k + (c_j + c_{j+1}) / 2`` with ``c`` the usable
    levels' phases (relative to gray 0) followed by ``2 pi``."""
    phases = np.asarray(phases, np.float64)
    circle = np.append(phases[:usable_levels], TWO_PI)
    mids = np.concatenate([[0.0], 0.5 * (circle[:-1] + circle[1:])])
    k = np.arange(math.floor(lo / TWO_PI) - 1, math.floor(hi / TWO_PI) + 2)
    cand = (k[:, None] * TWO_PI + mids[None, :]).ravel()
    return np.sort(cand[(cand >= lo - TWO_PI) & (cand <= hi + TWO_PI)])


def step_table(to_gray: Callable[[np.ndarray], np.ndarray], boundaries, lo, hi, *,
               window: int = 16) -> Tuple[np.ndarray, np.ndarray]:
    """Every float32 breakpoint of ``g = to_gray`` on ``[lo, hi]`` (module docstring).

    Parameters
    ----------
    to_gray : callable
        ``to_gray(float32 array) -> uint8 array``, the host's function (e.g.
        ``PhaseLUT.to_gray``); called on float32 arrays only.
    boundaries : array of float
        Candidate real values where ``g`` may change (:func:`lut_boundaries`).
    lo, hi : float
        The float32 input range (rounded to float32).
    window : int
        Float32 steps searched exhaustively on each side of a candidate.

    Returns
    -------
    bp : float32 ``[n]``, ascending, within ``(lo, hi]``
    lv : uint8 ``[n + 1]``
    """
    lo32, hi32 = np.float32(lo), np.float32(hi)
    if not (np.isfinite(lo32) and np.isfinite(hi32) and lo32 < hi32):
        raise ValueError(f"the input range must be finite with lo < hi, got [{lo}, {hi}]")
    o_lo, o_hi = (int(float32_ordinal(v)) for v in (lo32, hi32))
    cand = np.asarray(boundaries, np.float64)
    cand = cand[(cand >= float(lo32) - 1.0) & (cand <= float(hi32) + 1.0)]
    centres = float32_ordinal(cand.astype(np.float32))
    steps = np.arange(-int(window), int(window) + 1, dtype=np.int64)

    def g(ords):
        return np.asarray(to_gray(float32_from_ordinal(ords)), np.uint8)

    extra = np.zeros(0, np.int64)
    while True:
        pts = (np.concatenate([centres, extra])[:, None] + steps[None, :]).ravel()
        pts = np.unique(np.concatenate([pts[(pts >= o_lo) & (pts <= o_hi)], [o_lo, o_hi]]))
        vals = g(pts)
        change = np.flatnonzero(vals[1:] != vals[:-1]) + 1     # pts[j] differs from pts[j-1]
        gaps = change[pts[change] - pts[change - 1] > 1]
        if gaps.size == 0:
            break
        # a change the candidates missed: bisect each such gap to adjacent floats (vectorised)
        a, b = pts[gaps - 1].copy(), pts[gaps].copy()
        va = vals[gaps - 1]
        while np.any(b - a > 1):
            m = (a + b) // 2
            same = g(m) == va
            a = np.where(same, m, a)
            b = np.where(same, b, m)
        extra = np.concatenate([extra, b])
    bp = float32_from_ordinal(pts[change])
    lv = np.concatenate([vals[:1], vals[change]]).astype(np.uint8)
    return bp, lv


def lut_table(lut, lo: float, hi: float) -> Tuple[np.ndarray, np.ndarray]:
    """:func:`step_table` of a :class:`clholo.encode.quantize.PhaseLUT`'s forward map
    (``lut.to_gray``) on the float32 range ``[lo, hi]``."""
    return step_table(lut.to_gray, lut_boundaries(lut.phases, lut.usable_levels, lo, hi),
                      lo, hi)


def quantize_lookup(phase, bp, lv, lo, hi) -> Tuple[np.ndarray, int]:
    """The kernel for one table: ``(gray uint8, flags)``; ``gray = lv[#{k : bp[k] <= p}]``
    inside ``[lo, hi]``, 0 elsewhere, and ``flags`` the OR of :data:`QUANTIZE_NAN`,
    :data:`QUANTIZE_INF`, :data:`QUANTIZE_BELOW`, :data:`QUANTIZE_ABOVE` over the phases."""
    p = np.asarray(phase, np.float32)
    lo32, hi32 = np.float32(lo), np.float32(hi)
    with np.errstate(invalid="ignore"):
        inside = (p >= lo32) & (p <= hi32)
        count = np.searchsorted(np.asarray(bp, np.float32), p, side="right")
        gray = np.where(inside, np.asarray(lv, np.uint8)[np.minimum(count, len(lv) - 1)], 0)
        flags = 0
        bad = ~inside
        if bad.any():
            q = p[bad]
            flags |= QUANTIZE_NAN if np.isnan(q).any() else 0
            flags |= QUANTIZE_INF if np.isinf(q).any() else 0
            finite = q[np.isfinite(q)]
            flags |= QUANTIZE_BELOW if (finite < lo32).any() else 0
            flags |= QUANTIZE_ABOVE if (finite > hi32).any() else 0
    return gray.astype(np.uint8), int(flags)


def quantize_phase(phase, tables) -> Tuple[np.ndarray, np.ndarray]:
    """The kernel on patterns ``[..., C, H, W]`` float32 with one ``(bp, lv, lo, hi)`` per
    colour: ``(gray uint8 [..., C, H, W], flags uint32 [C])``."""
    p = np.asarray(phase, np.float32)
    C = p.shape[-3]
    if len(tables) != C:
        raise ValueError(f"{len(tables)} table(s) for {C} colour(s)")
    gray = np.empty(p.shape, np.uint8)
    flags = np.zeros(C, np.uint32)
    for c, (bp, lv, lo, hi) in enumerate(tables):
        gray[..., c, :, :], flags[c] = quantize_lookup(p[..., c, :, :], bp, lv, lo, hi)
    return gray, flags
