"""clholo.fft against NumPy's complex128 FFT.

Every output buffer is poisoned with NaN before the transform runs, so an element the kernels
fail to write shows up as a NaN in the comparison. Sizes: every power-of-two pair 2..1024 for
both kernel variants (grouped per row count to keep the number of test items and plan builds
small), 2048^2 and 4096^2, the longest lines (8192, 16384), 1D transforms, batches, windows,
the fused multiply, complex128 and the error paths.
"""

import re

import numpy as np
import pytest

import pyopencl.array as cla

from clholo import fft as F
from clholo.host.tuning import SETTINGS
from clholo.host import runtime
from conftest import random_complex
from tolerances import rel_l2, tol

SIZES = [2 ** k for k in range(1, 11)]  # 2 .. 1024
VARIANTS = ["cpu", "gpu"]


def _poisoned(queue, shape, dtype):
    out = cla.empty(queue, shape, dtype)
    out.fill(np.array(np.nan + 1j * np.nan, dtype=dtype))
    return out


def _check(got, want, dtype, what, transforms=1):
    got = np.asarray(got)
    assert np.isfinite(got).all(), f"{what}: {np.count_nonzero(~np.isfinite(got))} elements unwritten"
    err = rel_l2(got, want)
    # independent rounding errors of chained transforms add like a random walk
    limit = tol("fft", dtype)["rel_l2"] * np.sqrt(transforms)
    assert err <= limit, f"{what}: relative L2 error {err:.3g} > {limit:.3g}"


def _roundtrip_2d(queue, plan, a, dtype, what):
    """forward, inverse and forward->inverse through one plan, out of place and poisoned"""
    d = cla.to_device(queue, a)
    a128 = a.astype(np.complex128)
    fwd = plan.execute(d, out=_poisoned(queue, a.shape, dtype))
    _check(fwd.get(), np.fft.fft2(a128), dtype, f"{what} fft2")
    inv = plan.execute(d, out=_poisoned(queue, a.shape, dtype), inverse=True)
    _check(inv.get(), np.fft.ifft2(a128), dtype, f"{what} ifft2")
    back = plan.execute(fwd, out=_poisoned(queue, a.shape, dtype), inverse=True)
    _check(back.get(), a128, dtype, f"{what} round trip")


@pytest.mark.parametrize("variant", VARIANTS)
@pytest.mark.parametrize("h", SIZES)
def test_fft2_all_size_pairs(queue, rng, variant, h):
    for w in SIZES:
        a = random_complex(rng, (h, w))
        plan = F.FFTPlan((h, w), np.complex64, queue=queue, variant=variant)
        _roundtrip_2d(queue, plan, a, np.complex64, f"{variant} {h}x{w}")


@pytest.mark.parametrize("n", [2048, 4096])
def test_fft2_large(queue, rng, n):
    a = random_complex(rng, (n, n))
    plan = F.FFTPlan((n, n), np.complex64, queue=queue, variant="cpu")
    _roundtrip_2d(queue, plan, a, np.complex64, f"cpu {n}^2")


@pytest.mark.parametrize("shape", [(64, 96), (45, 1200)])
def test_cpu_strips_in_256_or_512_bit_vectors_give_the_same_bits(queue, rng, monkeypatch,
                                                                  shape):
    # kernels/cpu_wide.h: the strips' float16 in zmm registers where the CPU has AVX-512, or in
    # two ymm halves (CLHOLO_CPU_256): the same operations, so the same bits (a round trip
    # with the multiply between the transforms, every radix of 2^a 3^b 5^c)
    a, m = random_complex(rng, shape), random_complex(rng, shape)
    outs = []
    for wide in (True, False):
        monkeypatch.setattr(F, "_CPU_WIDE", wide)
        plan = F.FFTPlan(shape, np.complex64, queue=queue, variant="cpu")
        spectrum = plan.execute(cla.to_device(queue, a))
        outs.append(plan.execute(spectrum, inverse=True,
                                 multiply=cla.to_device(queue, m)).get())
    assert np.std(outs[0]) > 0
    np.testing.assert_array_equal(outs[0], outs[1])


def test_fft2_large_gpu_variant(queue, rng):
    # 2048 lines take the local-memory kernel of the GPU variant (1024 is covered above)
    a = random_complex(rng, (2048, 2048))
    plan = F.FFTPlan(a.shape, np.complex64, queue=queue, variant="gpu")
    _roundtrip_2d(queue, plan, a, np.complex64, "gpu 2048^2")


@pytest.mark.parametrize("variant", ["cpu", "gpu", "gpu-global"])
@pytest.mark.parametrize("shape", [(8192, 2), (2, 8192), (16384, 4), (4, 16384), (8, 8192)])
def test_fft2_longest_lines(queue, rng, variant, shape):
    a = random_complex(rng, shape)
    plan = F.FFTPlan(shape, np.complex64, queue=queue, variant=variant)
    _roundtrip_2d(queue, plan, a, np.complex64, f"{variant} {shape}")


@pytest.mark.parametrize("shape", [(2, 2), (8, 64), (64, 8), (32, 1024), (512, 256)])
def test_fft2_global_stages(queue, rng, shape):
    """the GPU variant's path for lines too long for local memory, forced on small lines"""
    a = random_complex(rng, shape)
    plan = F.FFTPlan(shape, np.complex64, queue=queue, variant="gpu-global")
    _roundtrip_2d(queue, plan, a, np.complex64, f"gpu-global {shape}")


@pytest.mark.parametrize("variant", VARIANTS)
def test_fft1d_all_sizes(queue, rng, variant):
    for n in [2 ** k for k in range(0, 15)]:
        a = random_complex(rng, (3, 5, n))
        d = cla.to_device(queue, a)
        a128 = a.astype(np.complex128)
        plan = F.FFTPlan(a.shape, np.complex64, queue=queue, axes=(-1,), variant=variant)
        got = plan.execute(d, out=_poisoned(queue, a.shape, np.complex64))
        _check(got.get(), np.fft.fft(a128), np.complex64, f"{variant} fft n={n}")
        got = plan.execute(d, out=_poisoned(queue, a.shape, np.complex64), inverse=True)
        _check(got.get(), np.fft.ifft(a128), np.complex64, f"{variant} ifft n={n}")


@pytest.mark.parametrize("variant", VARIANTS)
def test_batch_and_in_place(queue, rng, variant):
    a = random_complex(rng, (2, 3, 64, 128))
    a128 = a.astype(np.complex128)
    d = cla.to_device(queue, a)
    plan = F.FFTPlan(a.shape, np.complex64, queue=queue, variant=variant)
    same = plan.execute(d, out=d)
    assert same is d
    _check(d.get(), np.fft.fft2(a128), np.complex64, "in-place fft2")
    plan.execute(d, out=d, inverse=True)
    _check(d.get(), a128, np.complex64, "in-place ifft2 round trip")
    # 1D, in place
    plan1 = F.FFTPlan(a.shape, np.complex64, queue=queue, axes=(-1,), variant=variant)
    plan1.execute(d, out=d)
    _check(d.get(), np.fft.fft(a128), np.complex64, "in-place fft")


def test_functions_device_and_host(queue, rng):
    a = random_complex(rng, (4, 32, 16))
    a128 = a.astype(np.complex128)
    # NumPy in -> NumPy out, new array and caller's out, in place
    got = F.fft2(a, queue=queue)
    assert isinstance(got, np.ndarray) and got.dtype == np.complex64
    _check(got, np.fft.fft2(a128), np.complex64, "fft2(np)")
    out = np.full_like(a, np.nan)
    assert F.ifft2(a, out=out, queue=queue) is out
    _check(out, np.fft.ifft2(a128), np.complex64, "ifft2(np, out=)")
    b = a.copy()
    F.fft(b, out=b, queue=queue)
    _check(b, np.fft.fft(a128), np.complex64, "fft(np) in place")
    _check(F.ifft(a, queue=queue), np.fft.ifft(a128), np.complex64, "ifft(np)")
    # device in -> device out
    d = cla.to_device(queue, a)
    got = F.fft2(d)
    assert isinstance(got, cla.Array)
    _check(got.get(), np.fft.fft2(a128), np.complex64, "fft2(device)")
    out = _poisoned(queue, a.shape, np.complex64)
    assert F.ifft(d, out=out) is out
    _check(out.get(), np.fft.ifft(a128), np.complex64, "ifft(device, out=)")


@pytest.mark.parametrize("zero_copy", [True, False])
def test_execute_host_both_paths(queue, rng, zero_copy):
    """NumPy in and out through host-pointer buffers (CPU devices) and through device copies
    (other devices), forced either way on PoCL: new and given out, in place, converted input,
    a cropped output window, read-only input, and the overlap check"""
    a = random_complex(rng, (3, 24, 40))
    a128 = a.astype(np.complex128)
    plan = F.FFTPlan(a.shape, np.complex64, queue=queue)
    plan._host_zero_copy = zero_copy
    _check(plan.execute_host(a), np.fft.fft2(a128), np.complex64, f"new out {zero_copy}")
    out = np.full_like(a, np.nan)
    assert plan.execute_host(a, out=out, inverse=True) is out
    _check(out, np.fft.ifft2(a128), np.complex64, f"given out {zero_copy}")
    b = a.copy()
    assert plan.execute_host(b, out=b) is b
    _check(b, np.fft.fft2(a128), np.complex64, f"in place {zero_copy}")
    _check(plan.execute_host(a128), np.fft.fft2(a128), np.complex64, f"complex128 in {zero_copy}")
    ro = a.copy()
    ro.flags.writeable = False
    _check(plan.execute_host(ro), np.fft.fft2(a128), np.complex64, f"read-only in {zero_copy}")
    crop = F.FFTPlan(a.shape, np.complex64, queue=queue, output_shape=(10, 16))
    crop._host_zero_copy = zero_copy
    _check(crop.execute_host(a), np.fft.fft2(a128)[..., :10, :16], np.complex64,
           f"cropped {zero_copy}")
    if zero_copy:
        big = random_complex(rng, (4, 24, 40))
        with pytest.raises(ValueError, match="overlaps x"):
            plan.execute_host(big[:3], out=big[1:])


WINDOWS = [
    # transform, input window, output window
    ((64, 128), (40, 100), None),        # zero padding bottom/right
    ((64, 128), (64, 37), None),         # pad columns only
    ((64, 128), None, (20, 50)),         # crop the output
    ((128, 64), (100, 30), (70, 64)),    # both
    ((32, 32), (48, 40), None),          # input larger: read the top-left window
    ((256, 256), (128, 128), (128, 128)),  # the propagation pattern: pad 2x, crop back
]


@pytest.mark.parametrize("variant", ["cpu", "gpu", "gpu-global"])
@pytest.mark.parametrize("tshape,ishape,oshape", WINDOWS)
def test_windows(queue, rng, variant, tshape, ishape, oshape):
    batch = (3,)
    ishape = ishape or tshape
    oshape = oshape or tshape
    a = random_complex(rng, batch + ishape)
    padded = np.zeros(batch + tshape, np.complex128)
    h, w = min(ishape[0], tshape[0]), min(ishape[1], tshape[1])
    padded[..., :h, :w] = a[..., :h, :w]
    plan = F.FFTPlan(batch + tshape, np.complex64, queue=queue, input_shape=ishape,
                     output_shape=oshape, variant=variant)
    d = cla.to_device(queue, a)
    for inverse, ref in ((False, np.fft.fft2), (True, np.fft.ifft2)):
        got = plan.execute(d, out=_poisoned(queue, batch + oshape, np.complex64), inverse=inverse)
        want = ref(padded)[..., :oshape[0], :oshape[1]]
        _check(got.get(), want, np.complex64, f"{variant} window {plan.order} inverse={inverse}")


@pytest.mark.parametrize("variant", ["cpu", "gpu", "gpu-global"])
@pytest.mark.parametrize("where", ["input", "output"])
@pytest.mark.parametrize("m", [1, 2])
def test_fused_multiply(queue, rng, variant, where, m):
    tshape, ishape = (64, 128), (48, 100)
    a = random_complex(rng, (4,) + ishape)
    hmul = random_complex(rng, (m,) + tshape)
    padded = np.zeros((4,) + tshape, np.complex128)
    padded[..., :48, :100] = a
    hb = np.concatenate([hmul] * (4 // m)).astype(np.complex128)  # batch b uses hmul[b % m]
    dmul = cla.to_device(queue, hmul if m > 1 else hmul[0])
    plan = F.FFTPlan((4,) + tshape, np.complex64, queue=queue, input_shape=ishape, variant=variant)
    got = plan.execute(cla.to_device(queue, a), out=_poisoned(queue, (4,) + tshape, np.complex64),
                       multiply=dmul, multiply_at=where)
    want = np.fft.fft2(padded * hb) if where == "input" else np.fft.fft2(padded) * hb
    _check(got.get(), want, np.complex64, f"{variant} multiply at {where}")
    # the propagation chain: forward (multiply at output), inverse cropped back
    inv = F.FFTPlan((4,) + tshape, np.complex64, queue=queue, output_shape=ishape, variant=variant)
    spec = plan.execute(cla.to_device(queue, a), multiply=dmul)
    back = inv.execute(spec, out=_poisoned(queue, (4,) + ishape, np.complex64), inverse=True)
    want = np.fft.ifft2(np.fft.fft2(padded) * hb)[..., :48, :100]
    _check(back.get(), want, np.complex64, f"{variant} fft2 * H -> ifft2 cropped")


@pytest.mark.parametrize("variant", ["cpu", "gpu", "gpu-global"])
@pytest.mark.parametrize("dtype", [np.complex64, np.complex128])
@pytest.mark.parametrize("m", [1, 2])
def test_fused_multiply_inverse_input_rows(queue, cl_device, rng, variant, dtype, m):
    """the propagation chain as clholo.propagation runs it: forward over a zero-padded window,
    then the inverse with the factor applied as its first (row) pass loads whole rows, cropped
    back (the CPU kernel multiplies there in row order, before its in-register transpose)"""
    if dtype == np.complex128 and not runtime.has_fp64(cl_device):
        pytest.skip("device without fp64")
    tshape, ishape = (48, 160), (40, 96)
    a = random_complex(rng, (4,) + ishape, dtype)
    hmul = random_complex(rng, (m,) + tshape, dtype)
    hb = np.concatenate([hmul] * (4 // m)).astype(np.complex128)  # batch b uses hmul[b % m]
    padded = np.zeros((4,) + tshape, np.complex128)
    padded[..., :40, :96] = a
    fwd = F.FFTPlan((4,) + tshape, dtype, queue=queue, input_shape=ishape, variant=variant)
    inv = F.FFTPlan((4,) + tshape, dtype, queue=queue, output_shape=ishape, variant=variant)
    assert inv.order == "rows-first"
    spec = fwd.execute(cla.to_device(queue, a), out=_poisoned(queue, (4,) + tshape, dtype))
    got = inv.execute(spec, out=_poisoned(queue, (4,) + ishape, dtype), inverse=True,
                      multiply=cla.to_device(queue, hmul if m > 1 else hmul[0]),
                      multiply_at="input")
    want = np.fft.ifft2(np.fft.fft2(padded) * hb)[..., :40, :96]
    _check(got.get(), want, dtype, f"{variant} fft2 -> x H -> ifft2 cropped", transforms=2)


@pytest.mark.parametrize("variant", ["cpu", "gpu", "gpu-global"])
def test_fused_multiply_input_columns_first(queue, rng, variant):
    """issue 8: the input multiply on a plan whose first pass runs along columns (narrow input
    window), where each strip of columns must pick its own columns of the factor"""
    tshape, ishape = (64, 128), (64, 20)
    a = random_complex(rng, (3,) + ishape)
    hmul = random_complex(rng, tshape)
    plan = F.FFTPlan((3,) + tshape, np.complex64, queue=queue, input_shape=ishape,
                     variant=variant)
    assert plan.order == "columns-first"
    padded = np.zeros((3,) + tshape, np.complex128)
    padded[..., :, :20] = a
    for inverse, ref in ((False, np.fft.fft2), (True, np.fft.ifft2)):
        got = plan.execute(cla.to_device(queue, a), out=_poisoned(queue, (3,) + tshape,
                                                                  np.complex64),
                           multiply=cla.to_device(queue, hmul), multiply_at="input",
                           inverse=inverse)
        _check(got.get(), ref(padded * hmul), np.complex64,
               f"{variant} columns-first multiply at input, inverse={inverse}")


@pytest.mark.parametrize("variant", VARIANTS)
def test_fused_multiply_1d(queue, rng, variant):
    a = random_complex(rng, (6, 256))
    hmul = random_complex(rng, (3, 256))
    plan = F.FFTPlan(a.shape, np.complex64, queue=queue, axes=(-1,), variant=variant)
    got = plan.execute(cla.to_device(queue, a), multiply=cla.to_device(queue, hmul))
    want = np.fft.fft(a.astype(np.complex128)) * np.concatenate([hmul, hmul])
    _check(got.get(), want, np.complex64, f"{variant} 1D multiply at output")
    got = plan.execute(cla.to_device(queue, a), multiply=cla.to_device(queue, hmul),
                       multiply_at="input", inverse=True)
    want = np.fft.ifft(a.astype(np.complex128) * np.concatenate([hmul, hmul]))
    _check(got.get(), want, np.complex64, f"{variant} 1D inverse multiply at input")


@pytest.mark.parametrize("variant", ["cpu", "gpu", "gpu-global"])
@pytest.mark.parametrize("shape", [(2, 2), (16, 512), (1024, 8), (256, 256), (8, 8192)])
def test_complex128(queue, cl_device, rng, variant, shape):
    if not runtime.has_fp64(cl_device):
        pytest.skip("device without fp64")
    a = random_complex(rng, (2,) + shape, np.complex128)
    plan = F.FFTPlan(a.shape, np.complex128, queue=queue, variant=variant)
    _roundtrip_2d(queue, plan, a, np.complex128, f"{variant} complex128 {shape}")


def test_complex128_without_fp64(queue, monkeypatch):
    monkeypatch.setattr(runtime, "has_fp64", lambda dev: False)
    with pytest.raises(TypeError, match="double precision"):
        F.FFTPlan((8, 8), np.complex128, queue=queue)


@pytest.mark.parametrize("shape,axis,nearest", [((14, 64), -2, "12 and 15"),
                                                ((64, 1022), -1, "1000 and 1024"),
                                                ((5, 77, 64), -2, "75 and 80"),
                                                ((4, 7), -1, "6 and 8"),
                                                ((1081, 1920), -2, "1080 and 1125")])
def test_unsupported_prime_factor(queue, shape, axis, nearest):
    with pytest.raises(ValueError, match=rf"axis {axis}\).*2\^a 3\^b 5\^c.*nearest accepted "
                                         rf"sizes: {nearest}"):
        F.FFTPlan(shape, np.complex64, queue=queue)
    with pytest.raises(ValueError, match=rf"axis {axis}"):
        F.fft2(np.ones(shape, np.complex64), queue=queue)


def test_empty_axis(queue):
    with pytest.raises(ValueError, match=r"axis -1\) = 0 must be >= 1"):
        F.FFTPlan((4, 0), np.complex64, queue=queue)


def test_fft_size_helpers():
    smooth = [n for n in range(1, 5000) if F.is_fft_size(n)]
    # every product 2^a 3^b 5^c below 5000, built the other way round
    want = sorted({2 ** a * 3 ** b * 5 ** c for a in range(13) for b in range(8)
                   for c in range(6) if 2 ** a * 3 ** b * 5 ** c < 5000})
    assert smooth == want
    for n in (1, 7, 1000, 1021, 1081, 1921, 2049):
        nxt = F.next_fft_size(n)
        assert nxt >= n and F.is_fft_size(nxt)
        assert not any(F.is_fft_size(m) for m in range(n, nxt))
    assert F.nearest_fft_sizes(1081) == (1080, 1125)
    for n in (3, 5, 6, 60, 1080, 1920, 3840, 6561):
        assert F._radices(n) and int(np.prod(F._radices(n))) == n


@pytest.mark.parametrize("plan_kind", ["two-buffer", "in-place", "in-place-direct"])
@pytest.mark.parametrize("radix_max", [16, 64])
def test_fused_radix_stages(queue, rng, monkeypatch, radix_max, plan_kind):
    """every fused radix R1 R2 of the GPU variant's local-memory plans (two buffers, or in
    place where the local-memory budget is cut below two buffers, also with its first and last
    stages on global memory), as the one stage of an
    R-point line (p == 1, no outer twiddles) and as the second of two (p == R), both
    directions, against NumPy"""
    monkeypatch.setattr(F, "_FUSED_RADIX_MAX", radix_max)
    monkeypatch.setattr(F, "_INPLACE_FUSED_RADIX_MAX", radix_max)
    # the whole local memory for two buffers, or too little for any
    local = queue.device.local_mem_size
    in_place = plan_kind.startswith("in-place")
    monkeypatch.setattr(F, "_GPU_LOCAL_BYTES", 1 if in_place else local)
    monkeypatch.setattr(SETTINGS["inplace_direct"], "default", plan_kind == "in-place-direct")
    fused = sorted({r1 * r2 for r1 in F._BUTTERFLY_RADICES for r2 in F._BUTTERFLY_RADICES
                    if r2 <= r1 and r1 * r2 <= radix_max
                    and r1 * r2 not in F._BUTTERFLY_RADICES})
    assert fused and max(fused) <= radix_max
    lines = []
    for r in fused:
        lines += [r, r * r]  # one stage; two, the second at p = r
    fused_seen = set()  # (R, p > 1) of the fused stages the planned passes run
    for n in sorted(set(lines)):
        if plan_kind == "two-buffer" and 2 * n * 8 > local // 2:
            continue  # (4096 points on a GPU's 48 KiB: the in-place case covers it)
        a = random_complex(rng, (5, n))
        d = cla.to_device(queue, a)
        plan = F.FFTPlan(a.shape, np.complex64, queue=queue, axes=(-1,), variant="gpu")
        (p,) = plan.geometry.passes
        defines = dict(p.defines)
        # (lines of at most 8 points always take two buffers: one radix-n stage)
        assert p.kind == "gpu" and bool(defines.get("FFT_INPLACE")) == (in_place and n > 8)
        assert bool(defines.get("FFT_INPLACE_DIRECT")) == (
            plan_kind == "in-place-direct" and n > 8)
        stages = [tuple(map(int, t)) for t in
                  re.findall(r"FFT_STAGE\((\d+),(\d+),(\d+)\)", defines["FFT_STAGE_LIST"])]
        fused_seen |= {(r1 * r2, at > 1) for r1, r2, at in stages if r2 > 1}
        got = plan.execute(d, out=_poisoned(queue, a.shape, np.complex64))
        _check(got.get(), np.fft.fft(a.astype(np.complex128)), np.complex64,
               f"{plan_kind} {stages} fft n={n}")
        got = plan.execute(d, out=_poisoned(queue, a.shape, np.complex64), inverse=True)
        _check(got.get(), np.fft.ifft(a.astype(np.complex128)), np.complex64,
               f"{plan_kind} {stages} ifft n={n}")
    # every fused radix ran at p == 1 and after another stage (two buffers on a GPU's 48 KiB:
    # but for radix 64 after another)
    missing = {(r, after) for r in fused for after in (False, True)} - fused_seen
    if local < 64 * 1024 and plan_kind == "two-buffer":
        missing -= {(64, True)}
    assert not missing, f"fused stages (radix, p > 1) no line ran: {sorted(missing)}"


# Sizes with radix 3 and/or 5 stages: one of the factors only, both, with and without a
# power of two, and the SLM/display sizes of issue 10.
MIXED_1D = [3, 5, 6, 9, 10, 12, 15, 20, 24, 25, 27, 40, 45, 48, 60, 75, 81, 96, 100, 125, 135,
            160, 243, 320, 375, 625, 729, 1000, 1080, 1152, 1200, 1920, 2160, 2187, 3125, 3840,
            6561, 15360]


@pytest.mark.parametrize("variant", ["cpu", "gpu", "gpu-global"])
@pytest.mark.parametrize("dtype", [np.complex64, np.complex128])
def test_fft1d_radix_3_5(queue, cl_device, rng, variant, dtype):
    if dtype == np.complex128 and not runtime.has_fp64(cl_device):
        pytest.skip("device without fp64")
    for n in MIXED_1D:
        a = random_complex(rng, (3, n), dtype)
        a128 = a.astype(np.complex128)
        d = cla.to_device(queue, a)
        plan = F.FFTPlan(a.shape, dtype, queue=queue, axes=(-1,), variant=variant)
        got = plan.execute(d, out=_poisoned(queue, a.shape, dtype))
        _check(got.get(), np.fft.fft(a128), dtype, f"{variant} fft n={n}")
        got = plan.execute(d, out=_poisoned(queue, a.shape, dtype), inverse=True)
        _check(got.get(), np.fft.ifft(a128), dtype, f"{variant} ifft n={n}")


# 2D: small all-factor grids, and thin batches at the SLM sizes (both orientations, so that
# the long axis is once a row pass and once a column pass)
MIXED_2D = [(3, 5), (6, 10), (15, 9), (12, 25), (40, 27), (45, 64), (96, 75), (125, 48),
            (8, 1080), (1080, 8), (4, 1152), (1200, 4), (8, 1920), (1920, 3), (2, 2160),
            (2160, 5), (2, 3840), (3840, 2)]


@pytest.mark.parametrize("variant", ["cpu", "gpu", "gpu-global"])
@pytest.mark.parametrize("dtype", [np.complex64, np.complex128])
def test_fft2_radix_3_5(queue, cl_device, rng, variant, dtype):
    if dtype == np.complex128 and not runtime.has_fp64(cl_device):
        pytest.skip("device without fp64")
    for shape in MIXED_2D:
        a = random_complex(rng, (2,) + shape, dtype)
        plan = F.FFTPlan(a.shape, dtype, queue=queue, variant=variant)
        _roundtrip_2d(queue, plan, a, dtype, f"{variant} {dtype.__name__} {shape}")


@pytest.mark.parametrize("variant", ["cpu", "gpu"])
@pytest.mark.parametrize("tshape,ishape,oshape", [((120, 150), (100, 130), (100, 130)),
                                                  ((45, 360), (30, 100), None),
                                                  ((360, 45), None, (200, 20))])
def test_windows_radix_3_5(queue, rng, variant, tshape, ishape, oshape):
    """zero-padded input and cropped output on mixed-radix grids, with the fused multiply"""
    ishape = ishape or tshape
    oshape = oshape or tshape
    a = random_complex(rng, (2,) + ishape)
    hmul = random_complex(rng, tshape)
    padded = np.zeros((2,) + tshape, np.complex128)
    h, w = min(ishape[0], tshape[0]), min(ishape[1], tshape[1])
    padded[..., :h, :w] = a[..., :h, :w]
    fwd = F.FFTPlan((2,) + tshape, np.complex64, queue=queue, input_shape=ishape,
                    variant=variant)
    inv = F.FFTPlan((2,) + tshape, np.complex64, queue=queue, output_shape=oshape,
                    variant=variant)
    spec = fwd.execute(cla.to_device(queue, a), multiply=cla.to_device(queue, hmul))
    back = inv.execute(spec, out=_poisoned(queue, (2,) + oshape, np.complex64), inverse=True)
    want = np.fft.ifft2(np.fft.fft2(padded) * hmul)[..., :oshape[0], :oshape[1]]
    _check(back.get(), want, np.complex64, f"{variant} {tshape} pad/multiply/crop", transforms=2)


def test_too_large(queue):
    with pytest.raises(ValueError, match="32768"):
        F.FFTPlan((2, 32768), np.complex64, queue=queue)


@pytest.mark.parametrize("dtype", [np.float32, np.float64, np.int32, "complex256"])
def test_wrong_dtype(queue, dtype):
    if dtype == "complex256" and not hasattr(np, "complex256"):
        pytest.skip("no complex256 here")
    with pytest.raises(TypeError, match="complex64"):
        F.FFTPlan((8, 8), dtype, queue=queue)
    with pytest.raises(TypeError, match="complex64"):
        F.fft2(np.ones((8, 8), dtype), queue=queue)


def test_execute_checks(queue, rng):
    plan = F.FFTPlan((8, 16), np.complex64, queue=queue)
    good = cla.to_device(queue, random_complex(rng, (8, 16)))
    with pytest.raises(ValueError, match="x.shape"):
        plan.execute(cla.zeros(queue, (8, 8), np.complex64))
    with pytest.raises(TypeError, match="x.dtype"):
        plan.execute(cla.zeros(queue, (8, 16), np.complex128))
    with pytest.raises(ValueError, match="multiply.shape"):
        plan.execute(good, multiply=cla.zeros(queue, (8, 8), np.complex64))
    with pytest.raises(ValueError, match="multiply_at"):
        plan.execute(good, multiply=good, multiply_at="middle")
    with pytest.raises(ValueError, match="output_shape"):
        F.FFTPlan((8, 16), np.complex64, queue=queue, output_shape=(9, 16))
    with pytest.raises(ValueError, match="output_shape"):
        F.FFTPlan((8, 16), np.complex64, queue=queue, output_shape=(8, 17))
    with pytest.raises(ValueError, match="variant"):
        F.FFTPlan((8, 16), np.complex64, queue=queue, variant="fpga")


def test_plan_reuse_no_host_sync(queue, rng):
    """many executions chain on the queue; buffers are allocated once per plan"""
    a = random_complex(rng, (2, 64, 64))
    plan = F.FFTPlan(a.shape, np.complex64, queue=queue, input_shape=(40, 64),
                     output_shape=(64, 64))
    x = cla.to_device(queue, np.ascontiguousarray(a[:, :40]))
    y = cla.empty(queue, a.shape, np.complex64)
    z = cla.empty(queue, (2, 40, 64), np.complex64)
    inv = F.FFTPlan(a.shape, np.complex64, queue=queue, output_shape=(40, 64))
    for _ in range(5):
        plan.execute(x, out=y)
        inv.execute(y, out=z, inverse=True)
        plan.execute(z, out=y)
        inv.execute(y, out=x, inverse=True)
    _check(x.get(), a[:, :40], np.complex64, "10 chained round trips", transforms=20)
    assert len(plan._buffers) <= 1 and len(inv._buffers) <= 1


def test_plans_that_share_work_buffers_give_the_same_results(queue, rng):
    """share_work_with: a plan with a store callback uses the plain plan's work buffers (a
    padded inverse keeps a [rows, Wp] or [Hp, cols] intermediate): no buffer of its own, the
    same spectrum either way; a plan whose work buffers are larger is refused, by name."""
    shape, out = (2, 24, 40), (20, 30)
    plain = F.FFTPlan(shape, np.complex64, queue=queue, output_shape=out)
    assert plain.geometry.buffers  # the pruned inverse keeps an intermediate
    scaled = F.FFTCallback("void clholo_store(__global real2 *p, real2 v, long b, int row, "
                           "int col, real s) { *p = v * s; }", params=["real"])
    shared = F.FFTPlan(shape, np.complex64, queue=queue, output_shape=out,
                       store_callback=scaled, share_work_with=plain)
    assert shared._buffers is plain._buffers
    x = random_complex(rng, shape)
    xd = cla.to_device(queue, x)
    a = plain.execute(xd).get()
    b = shared.execute(xd, store_args=(2.0,)).get()
    np.testing.assert_allclose(b, 2 * a, rtol=1e-6, atol=1e-6 * np.abs(a).max())
    assert rel_l2(a, np.fft.fft2(x.astype(np.complex128))[:, :20, :30]) <= tol(
        "fft", np.float32)["rel_l2"]
    small = F.FFTPlan((2, 8, 10), np.complex64, queue=queue, output_shape=(4, 5))
    with pytest.raises(ValueError, match="share_work_with"):
        F.FFTPlan(shape, np.complex64, queue=queue, output_shape=out, share_work_with=small)
    with pytest.raises(TypeError, match="share_work_with"):
        F.FFTPlan(shape, np.complex64, queue=queue, share_work_with="plain")


@pytest.mark.parametrize("variant", ["cpu", "gpu"])
def test_1d_output_longer_than_the_transform_is_a_row_pitch(queue, rng, variant):
    """A 1D plan's output rows longer than n get the transform in their first n elements and
    keep the rest; an input row longer than n is read in its first n (the two-pass layer's
    pitched row spectrum, both ways)."""
    for B, n, w, P in [(6, 32, 20, 40), (5, 45, 45, 48), (3, 64, 50, 80)]:
        x = random_complex(rng, (B, w))
        want = F.FFTPlan((B, n), np.complex64, queue=queue, axes=(-1,), input_shape=(w,),
                         variant=variant).execute(cla.to_device(queue, x)).get()
        plan = F.FFTPlan((B, n), np.complex64, queue=queue, axes=(-1,), input_shape=(w,),
                         output_shape=(P,), variant=variant)
        out = random_complex(rng, (B, P))
        junk = out[:, n:].copy()
        got = plan.execute(cla.to_device(queue, x), out=cla.to_device(queue, out)).get()
        np.testing.assert_array_equal(got[:, :n], want, err_msg=str((B, n, w, P)))
        np.testing.assert_array_equal(got[:, n:], junk, err_msg=str((B, n, w, P)))
        back = F.FFTPlan((B, n), np.complex64, queue=queue, axes=(-1,), input_shape=(P,),
                         output_shape=(w,), variant=variant)
        inv = back.execute(cla.to_device(queue, got), inverse=True).get()
        assert rel_l2(inv, x) <= tol("fft", np.float32)["rel_l2"], (B, n, w, P)
