"""8-bit quantisation on the device (kernels/quantize.cl) against its NumPy reference
(clholo.reference.quantize) and against the host's own PhaseLUT.to_gray, bit for bit: random
float32 phases over several sizes, every breakpoint of the tables and its float32 neighbours, both
ends of the range; out-of-range, NaN and inf phases are errors."""

import math

import numpy as np
import pyopencl.array as cla
import pytest

from clholo import reference as ref
from clholo.encode.quantize import (DEVICE_PHASE_RANGE, DeviceQuantizer, PhaseLUT, device_table,
                                    quantize)

TWO_PI = 2 * math.pi
LO, HI = (np.float32(v) for v in DEVICE_PHASE_RANGE)


def _measured(rng, top=TWO_PI * 1.05):
    """A random measured monotone table (uneven steps, offset, range a little over 2 pi)."""
    steps = rng.uniform(0.2, 1.8, 255)
    return PhaseLUT(np.concatenate([[0.3], 0.3 + np.cumsum(steps) / steps.sum() * top]),
                    name="measured")


def _lut(kind, rng):
    return {"linear": PhaseLUT.linear(255), "linear:200": PhaseLUT.linear(200),
            "measured": _measured(rng)}[kind]


KINDS = ["linear", "linear:200", "measured"]


def _adversarial(bp, lo=LO, hi=HI):
    """Every breakpoint, the float32 just below and just above it, and both ends of the range
    with their inner neighbours."""
    bp = np.asarray(bp, np.float32)
    pts = np.concatenate([bp, np.nextafter(bp, np.float32(-np.inf)),
                          np.nextafter(bp, np.float32(np.inf)),
                          [lo, hi, np.nextafter(lo, hi), np.nextafter(hi, lo)]]).astype(np.float32)
    return pts[(pts >= lo) & (pts <= hi)]


def _random_phases(rng, shape, lo=LO, hi=HI):
    p = rng.uniform(float(lo), float(hi), shape).astype(np.float32)
    assert np.all(p != 0)  # fresh values, not a zero-filled buffer that happens to match
    return p


# ----------------------------------------------------------------------------- the tables (NumPy)
@pytest.mark.parametrize("kind", KINDS)
def test_table_is_the_host_function_at_every_breakpoint(rng, kind):
    lut = _lut(kind, rng)
    bp, lv = device_table(lut)
    assert bp.dtype == np.float32 and lv.dtype == np.uint8 and len(lv) == len(bp) + 1
    assert np.all(np.diff(bp) > 0) and bp[0] > LO and bp[-1] <= HI
    # each breakpoint is one: the level changes between it and the float32 below it
    below = np.nextafter(bp, np.float32(-np.inf))
    assert np.all(lut.to_gray(bp) != lut.to_gray(below))
    # and the table gives the host's level there, just below, just above, and at the ends
    pts = _adversarial(bp)
    got, flags = ref.quantize_lookup(pts, bp, lv, LO, HI)
    np.testing.assert_array_equal(got, lut.to_gray(pts))
    assert flags == 0
    x = _random_phases(rng, 200_000)
    np.testing.assert_array_equal(ref.quantize_lookup(x, bp, lv, LO, HI)[0], lut.to_gray(x))
    # two periods of the usable levels (one step per level, the last one back to gray 0)
    assert len(bp) == 2 * lut.usable_levels


def test_table_finds_changes_the_candidates_miss(rng):
    """Step 3 of the construction: with every other candidate left out, each gap's change is
    bisected and the table is the same."""
    lut = _measured(rng)
    full = ref.lut_table(lut, LO, HI)
    cand = ref.lut_boundaries(lut.phases, lut.usable_levels, LO, HI)
    bp, lv = ref.step_table(lut.to_gray, cand[::2], LO, HI)
    np.testing.assert_array_equal(bp, full[0])
    np.testing.assert_array_equal(lv, full[1])


def test_float32_order():
    x = np.float32([-np.inf, -3.5, -1e-45, -0.0, 0.0, 1e-45, 2.0, np.float32(np.pi), np.inf])
    o = ref.float32_ordinal(x)
    assert o[3] == o[4] == 0 and o[2] == -1 and o[5] == 1 and np.all(np.diff(o[4:]) > 0)
    np.testing.assert_array_equal(ref.float32_from_ordinal(o + 1)[5:8],
                                  np.nextafter(x[5:8], np.float32(np.inf)))
    assert ref.float32_from_ordinal(0).tobytes() == np.float32(0.0).tobytes()


def test_tables_are_cached_per_table_content():
    a = device_table(PhaseLUT.linear(230))
    b = device_table("linear:230")
    assert a[0] is b[0] and not a[0].flags.writeable


# ------------------------------------------------------------------------------ the kernel
@pytest.mark.parametrize("shape", [(1, 1, 1, 1), (1, 3, 7, 5), (2, 3, 17, 31), (3, 2, 40, 24),
                                   (1, 1, 96, 130)])
def test_kernel_matches_reference_and_host_on_random_phases(queue, rng, shape):
    C = shape[1]
    luts = [_lut(k, rng) for k in KINDS][:C] if C > 1 else [_measured(rng)]
    dq = DeviceQuantizer(luts, C)
    phase = _random_phases(rng, shape)
    gray, flags = dq.enqueue(cla.to_device(queue, phase))
    got = gray.get()
    tables = [device_table(lut) + (LO, HI) for lut in luts]
    want, want_flags = ref.quantize_phase(phase, tables)
    np.testing.assert_array_equal(got, want)
    np.testing.assert_array_equal(got, quantize(phase, luts))          # the host, float64
    np.testing.assert_array_equal(flags.get(), want_flags)
    assert not want_flags.any()


@pytest.mark.parametrize("kind", KINDS)
def test_kernel_at_every_breakpoint_and_its_neighbours(queue, rng, kind):
    lut = _lut(kind, rng)
    bp, lv = device_table(lut)
    pts = _adversarial(bp)
    # one field [1, 1, 1, n]: every breakpoint, both neighbours and the range's ends
    phase = pts.reshape(1, 1, 1, -1)
    got = DeviceQuantizer(lut, 1)(phase, queue=queue)
    np.testing.assert_array_equal(got[0, 0, 0], lut.to_gray(pts))
    np.testing.assert_array_equal(got[0, 0, 0], ref.quantize_lookup(pts, bp, lv, LO, HI)[0])
    # a wider range (more breakpoints, another search depth) is just as exact
    wide = (-5 * math.pi, 7 * math.pi)
    bpw, _ = device_table(lut, wide)
    ptsw = _adversarial(bpw, np.float32(wide[0]), np.float32(wide[1]))
    gotw = DeviceQuantizer(lut, 1, phase_range=wide)(ptsw.reshape(1, 1, 1, -1), queue=queue)
    np.testing.assert_array_equal(gotw[0, 0, 0], lut.to_gray(ptsw))


@pytest.mark.parametrize("guess", ["zero", "all", "random"])
def test_a_wrong_first_guess_does_not_change_the_result(queue, rng, guess):
    """The bucket table only says where the kernel's two scans start: with every guess 0, every
    guess n or random guesses the levels are the same."""
    lut = _measured(rng)
    dq = DeviceQuantizer(lut, 1)
    n = int(dq._table[0, 1])
    dq._guess[:] = {"zero": 0, "all": n}.get(guess, 0) if guess != "random" else \
        rng.integers(0, n + 1, dq._guess.size)
    pts = np.concatenate([_adversarial(device_table(lut)[0]), _random_phases(rng, 5000)])
    got = dq(pts.reshape(1, 1, 1, -1), queue=queue)
    np.testing.assert_array_equal(got[0, 0, 0], lut.to_gray(pts))


def test_every_colour_takes_its_own_table(queue, rng):
    luts = ["linear:255", "linear:230", "linear:200"]
    phase = _random_phases(rng, (2, 3, 9, 11))
    got = DeviceQuantizer(luts, 3)(phase, queue=queue)
    np.testing.assert_array_equal(got, quantize(phase, luts))
    assert got[:, 2].max() < 200 and got[:, 0].max() > 230


@pytest.mark.parametrize("bad, words", [
    (np.nan, "NaN/inf"), (np.inf, "NaN/inf"), (-np.inf, "NaN/inf"),
    (np.nextafter(HI, np.float32(np.inf)), "values above"),
    (np.nextafter(LO, np.float32(-np.inf)), "values below"),
    (100.0, "values above"),
])
def test_out_of_range_nan_and_inf_are_errors(queue, rng, bad, words):
    phase = _random_phases(rng, (2, 3, 5, 6))
    phase[1, 1, 2, 3] = bad
    luts = ["linear", "linear:230", "linear:200"]
    dq = DeviceQuantizer(luts, 3)
    with pytest.raises(ValueError, match=words) as err:
        dq(phase, queue=queue)
    assert "colour 1" in str(err.value) and "linear:230" in str(err.value)
    gray, flags = dq.enqueue(cla.to_device(queue, phase))
    tables = [device_table(lut) + (LO, HI) for lut in luts]
    want, want_flags = ref.quantize_phase(phase, tables)
    np.testing.assert_array_equal(flags.get(), want_flags)
    assert want_flags[1] and not want_flags[0] and not want_flags[2]
    np.testing.assert_array_equal(gray.get(), want)     # the other pixels are still right


def test_bad_arguments(queue):
    dq = DeviceQuantizer("linear", 3)
    with pytest.raises(TypeError, match="float32"):
        dq(np.zeros((1, 3, 2, 2)), queue=queue)
    with pytest.raises(ValueError, match="3 table"):
        dq(np.ones((1, 2, 2, 2), np.float32), queue=queue)
    with pytest.raises(ValueError, match="lo < hi"):
        DeviceQuantizer("linear", 1, phase_range=(1.0, -1.0))
    with pytest.raises(ValueError, match="one per colour"):
        DeviceQuantizer(["linear", "linear"], 3)


# ------------------------------------------------------------------ the encoders on the device
def test_dpac_device_phases_are_dpac_encode_s(queue, rng):
    from clholo.encode.dpac import dpac_encode, dpac_encode_device
    from clholo.scene import Optics

    optics = Optics(pitch=8e-6, wavelengths=(638e-9, 520e-9, 450e-9))
    fields = (rng.standard_normal((2, 3, 12, 20)) + 1j * rng.standard_normal((2, 3, 12, 20))
              ).astype(np.complex64)
    dev = dpac_encode_device(cla.to_device(queue, fields), optics, z_slm=0.01)
    assert isinstance(dev, cla.Array) and dev.shape == fields.shape
    host = dpac_encode(fields, optics, z_slm=0.01, queue=queue)
    np.testing.assert_array_equal(dev.get(), host)
    assert np.abs(host).max() <= 1.5 * np.pi + 1e-5       # inside the tables' range


def test_kinoform_encoder_quantises_the_device_angle(queue, rng):
    from clholo.host.display_loop import phase_quantize_encoder
    from clholo.host.phase_retrieval import encode_kernel
    from clholo.host import runtime

    fields = (rng.standard_normal((2, 3, 9, 14)) + 1j * rng.standard_normal((2, 3, 9, 14))
              ).astype(np.complex64)
    d = cla.to_device(queue, fields)
    angle = cla.empty(queue, fields.shape, np.float32)
    runtime.launch(encode_kernel(queue.context, "field_angle"), queue, (fields.size,), None,
                   d.data, angle.data)
    for n in (255, 256, 200):
        got = phase_quantize_encoder(n)(d)
        np.testing.assert_array_equal(got, PhaseLUT.linear(n).to_gray(angle.get()))
        np.testing.assert_array_equal(phase_quantize_encoder(n, queue=queue)(fields), got)
