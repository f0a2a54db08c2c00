"""clholo.fft.RoundTripPlan (a forward and an inverse FFT of every line in one pass, with a
pointwise step between them in fast memory) against its NumPy reference
clholo.reference.round_trip, for both kernel variants on PoCL: rows and columns, either
direction first, the mid multiply and crop, generic and composite mid callbacks (the two-pass
layer's row kernel), several sizes 2^a 3^b 5^c, partial strips and ragged rows."""

import numpy as np
import pyopencl.array as cla
import pytest

from clholo import fft as F
from clholo.host.tuning import SETTINGS
from clholo import reference as ref
from clholo.host import runtime
from clholo.host.scheduler import COMPOSITE_STORE_PARAMS
from conftest import random_complex
from tolerances import rel_l2, tol

VARIANTS = ["cpu", "gpu"]

# (batch, rows, cols, n, mid_n): powers of two and 2^a 3^b 5^c, lines shorter than n, row and
# column counts that are not multiples of a CPU strip (8 lines) or of 4
SIZES = [(2, 16, 32, 32, None), (3, 13, 30, 45, 20), (1, 40, 17, 60, 50), (2, 9, 24, 27, 25),
         (1, 24, 40, 40, 40)]


def _frame(axis, rows, cols, n):
    return (rows, n) if axis == "rows" else (n, cols)


@pytest.mark.parametrize("variant", VARIANTS)
@pytest.mark.parametrize("axis", ["rows", "cols"])
@pytest.mark.parametrize("first", ["forward", "inverse"])
def test_round_trip_with_multiply_matches_reference(queue, rng, variant, axis, first):
    for B, rows, cols, n, mid_n in SIZES:
        n = max(n, F.next_fft_size(cols if axis == "rows" else rows))
        mid_n = None if mid_n is None else min(mid_n, n)
        x = random_complex(rng, (B, rows, cols))
        m = random_complex(rng, (2,) + _frame(axis, rows, cols, n))
        plan = F.RoundTripPlan((B, rows, cols), n, axis=axis, first=first, mid_n=mid_n,
                               queue=queue, variant=variant)
        out = cla.empty(queue, x.shape, np.complex64)
        out.fill(np.complex64(np.nan))
        got = plan.execute(cla.to_device(queue, x), out=out, multiply=cla.to_device(queue, m))
        want = ref.round_trip(x, n, axis=axis, first=first, multiply=m, mid_n=mid_n)
        err = rel_l2(got.get(), want)
        assert err <= tol("fft", np.float32)["rel_l2"], (B, rows, cols, n, mid_n, err)
        # without a multiply, in place
        xd = cla.to_device(queue, x)
        plan.execute(xd, out=xd)
        want = ref.round_trip(x, n, axis=axis, first=first, mid_n=mid_n)
        assert rel_l2(xd.get(), want) <= tol("fft", np.float32)["rel_l2"]


@pytest.mark.parametrize("variant", VARIANTS)
def test_round_trip_complex128(queue, cl_device, rng, variant):
    if not runtime.has_fp64(cl_device):
        pytest.skip("device without fp64")
    for axis in ("rows", "cols"):
        x = random_complex(rng, (2, 12, 20), np.complex128)
        n = 30 if axis == "rows" else 15
        m = random_complex(rng, _frame(axis, 12, 20, n), np.complex128)
        plan = F.RoundTripPlan(x.shape, n, np.complex128, axis=axis, queue=queue,
                               variant=variant)
        got = plan.execute(cla.to_device(queue, x), multiply=cla.to_device(queue, m)).get()
        want = ref.round_trip(x, n, axis=axis, multiply=m)
        assert rel_l2(got, want) <= tol("fft", np.float64)["rel_l2"], axis


# v * s + g[row][col], g over the transform frame (width w): tells rows, columns and the batch
# index apart (s depends on b)
MID_AFFINE = F.FFTCallback("""
real2 clholo_mid(real2 v, long b, int row, int col, __global const real2 *g, int w, real s)
{
    return v * (s + (real)b) + g[row * w + col];
}
""", params=["__global const real2 *", "int", "real"])


@pytest.mark.parametrize("variant", VARIANTS)
@pytest.mark.parametrize("axis", ["rows", "cols"])
def test_mid_callback_sees_frame_positions(queue, rng, variant, axis):
    for B, rows, cols, n, mid_n in SIZES:
        n = max(n, F.next_fft_size(cols if axis == "rows" else rows))
        mid_n = n if mid_n is None else min(mid_n, n)
        x = random_complex(rng, (B, rows, cols))
        m = random_complex(rng, _frame(axis, rows, cols, n))
        fr = _frame(axis, rows, cols, n)
        g = random_complex(rng, fr)
        plan = F.RoundTripPlan((B, rows, cols), n, axis=axis, first="inverse", mid_n=mid_n,
                               mid_callback=MID_AFFINE, queue=queue, variant=variant)
        got = plan.execute(cla.to_device(queue, x), multiply=cla.to_device(queue, m),
                           mid_args=[cla.to_device(queue, g), fr[1], 0.5]).get()

        def mid(v):
            s = (0.5 + np.arange(B))[:, None, None]
            return v * s + (g[:, :mid_n] if axis == "rows" else g[:mid_n, :])

        want = ref.round_trip(x, n, axis=axis, first="inverse", multiply=m, mid_n=mid_n,
                              mid=mid)
        assert rel_l2(got, want) <= tol("fft", np.float32)["rel_l2"], (B, rows, cols, n)


COMPOSITE = F.FFTCallback('#include "composite_store.h"\n', params=COMPOSITE_STORE_PARAMS)


@pytest.mark.parametrize("variant", VARIANTS)
@pytest.mark.parametrize("H,W,Wp,C,frames", [(16, 24, 32, 3, 2), (13, 30, 45, 1, 3),
                                             (17, 21, 27, 2, 2), (8, 64, 64, 3, 1)])
def test_row_round_trip_composites_the_next_layer(queue, rng, variant, H, W, Wp, C, frames):
    """the two-pass layer's row kernel: inverse row FFT, crop to W, the next layer's
    composite (its colour, alpha and Philox phases), zero-pad, forward row FFT"""
    B = frames * C
    spec = random_complex(rng, (B, H, Wp))
    color = rng.random((H, W, C)).astype(np.float32)
    alpha = rng.random((H, W)).astype(np.float32)
    seed, layer, frame0 = int(rng.integers(0, 2 ** 40)), 5, 7
    k0, k1 = ref.seed_key(seed)
    plan = F.RoundTripPlan((B, H, Wp), Wp, axis="rows", first="inverse", mid_n=W,
                           mid_callback=COMPOSITE, queue=queue, variant=variant)
    dc, da = cla.to_device(queue, color), cla.to_device(queue, alpha)
    got = plan.execute(cla.to_device(queue, spec), mid_args=[
        dc, da, np.uint32(W), np.uint32(C), np.uint32(layer), np.uint32(frame0), k0, k1]).get()

    def mid(v):
        out = np.empty_like(v)
        for b in range(B):
            f, c = divmod(b, C)
            phi = ref.random_phase((H, W), seed=seed, frame=frame0 + f, colour=c, layer=layer)
            out[b] = ref.composite_layer(v[b], color[..., c], alpha, phi)
        return out

    want = ref.round_trip(spec, Wp, axis="rows", first="inverse", mid_n=W, mid=mid)
    assert rel_l2(got, want) <= tol("composite", np.float32)["rel_l2"]


@pytest.mark.parametrize("variant", VARIANTS)
def test_arguments_follow_every_call(queue, rng, variant):
    """arguments are set once per plan and reset only where a call changes them: alternating
    arrays, factors and callback values still give each call's own result"""
    shape, n = (2, 12, 40), 48
    plan = F.RoundTripPlan(shape, n, axis="rows", first="inverse", mid_n=33,
                           mid_callback=MID_AFFINE, queue=queue, variant=variant)
    xs = [random_complex(rng, shape) for _ in range(2)]
    ms = [random_complex(rng, (12, n)) for _ in range(2)]
    gs = [random_complex(rng, (12, n)) for _ in range(2)]
    dx = [cla.to_device(queue, a) for a in xs]
    dm = [cla.to_device(queue, a) for a in ms]
    dg = [cla.to_device(queue, a) for a in gs]
    outs = [cla.empty(queue, shape, np.complex64) for _ in range(2)]
    for i, j, k, s in ((0, 0, 0, 1.0), (1, 1, 1, 2.0), (0, 1, 0, 2.0), (1, None, 1, 1.0),
                       (0, 0, 1, 1.0)):
        got = plan.execute(dx[i], out=outs[i % 2], multiply=None if j is None else dm[j],
                           mid_args=[dg[k], n, s]).get()

        def mid(v):
            return v * (s + np.arange(2))[:, None, None] + gs[k][:, :33]

        want = ref.round_trip(xs[i], n, axis="rows", first="inverse",
                              multiply=None if j is None else ms[j], mid_n=33, mid=mid)
        assert rel_l2(got, want) <= tol("fft", np.float32)["rel_l2"], (i, j, k, s)


def test_round_trip_geometry_errors():
    dev = F.DeviceLimits(is_cpu=False, local_mem_size=48 * 1024, max_work_group_size=1024)
    with pytest.raises(ValueError, match="axis="):
        F.round_trip_geometry((4, 8), 8, device=dev, axis="x")
    with pytest.raises(ValueError, match="first="):
        F.round_trip_geometry((4, 8), 8, device=dev, axis="rows", first="back")
    with pytest.raises(ValueError, match="n=7"):
        F.round_trip_geometry((4, 7), 7, device=dev, axis="rows")
    with pytest.raises(ValueError, match="longer than the transform"):
        F.round_trip_geometry((4, 20), 16, device=dev, axis="rows")
    with pytest.raises(ValueError, match="mid_n=17"):
        F.round_trip_geometry((4, 8), 16, device=dev, axis="rows", mid_n=17)
    with pytest.raises(ValueError, match="variant="):
        F.round_trip_geometry((4, 8), 16, device=dev, axis="rows", variant="gpu-global")
    # the GPU variant's 48 KiB of local memory hold a line of up to 6144 complex64 once (in
    # place beyond 2048), and up to 12288 points one component at a time (split): longer
    # lines have no round trip (the renderer then keeps four passes)
    assert F.round_trip_fits((1, 8, 2048), 2048, device=dev, axis="rows")
    assert F.round_trip_fits((1, 8, 4096), 4096, device=dev, axis="rows")
    assert F.round_trip_fits((1, 8, 8192), 8192, device=dev, axis="rows")
    assert not F.round_trip_fits((1, 8, 16384), 16384, device=dev, axis="rows")
    with pytest.raises(ValueError, match="does not fit"):
        F.round_trip_geometry((1, 8, 16384), 16384, device=dev, axis="rows")
    cpu = F.DeviceLimits(is_cpu=True, local_mem_size=1 << 20, max_work_group_size=4096)
    assert F.round_trip_fits((1, 8, 8192), 8192, device=cpu, axis="rows")
    g = F.round_trip_geometry((3, 5, 40, 64), 48, device=cpu, axis="cols")
    assert (g.batch, g.nlines, g.nelems, g.mul_frame) == (15, 64, 40, (48, 64))


def test_execute_errors(queue, rng):
    plan = F.RoundTripPlan((2, 8, 16), 16, axis="rows", queue=queue)
    x = cla.to_device(queue, random_complex(rng, (2, 8, 16)))
    with pytest.raises(ValueError, match="x.shape"):
        plan.execute(cla.to_device(queue, random_complex(rng, (2, 8, 12))))
    with pytest.raises(ValueError, match="multiply.shape"):
        plan.execute(x, multiply=cla.to_device(queue, random_complex(rng, (16, 8))))
    with pytest.raises(ValueError, match="no mid_callback"):
        plan.execute(x, mid_args=[1])
    with pytest.raises(TypeError, match="pyopencl.array"):
        plan.execute(np.zeros((2, 8, 16), np.complex64))
    with pytest.raises(ValueError, match="multiply_even=True needs a multiply"):
        plan.execute(x, multiply_even=True)


def _even_frames(rng, m, lines, n):
    """``m`` random frames ``[lines, n]`` that are even in both indices, exactly (every value
    is a copy of one in the quarter l <= lines/2, k <= n/2), and the same frames with NaN
    everywhere outside that quarter."""
    g = random_complex(rng, (m, lines, n))
    li, ki = np.arange(lines), np.arange(n)
    lq, kq = np.minimum(li, (lines - li) % lines), np.minimum(ki, (n - ki) % n)
    even = np.ascontiguousarray(g[:, lq[:, None], kq[None, :]])
    poisoned = even.copy()
    poisoned[:, li > lines // 2, :] = np.nan
    poisoned[:, :, ki > n // 2] = np.nan
    return even, poisoned


# (batch, rows, cols, n): line counts even and odd, strips wholly below, across and above the
# middle line, partial strips, column passes of several strips per work-item (64 columns)
EVEN_SIZES = [(2, 13, 40, 27), (1, 16, 64, 32), (2, 9, 30, 45), (1, 20, 33, 40),
              (3, 8, 17, 16)]


@pytest.mark.parametrize("variant", VARIANTS)
@pytest.mark.parametrize("axis", ["rows", "cols"])
def test_even_factors_give_the_quarter_s_bits(queue, rng, variant, axis):
    """EvenFactors (on CPU strips the frames laid out strip by strip, mul_mode 5; on the GPU
    kernels the frames read in their quarter) give the same bits as the plain multiply of an
    even frame, read nothing beyond the quarter, and the CPU layout is its reference's."""
    for B, rows, cols, n in EVEN_SIZES:
        n = max(n, F.next_fft_size(cols if axis == "rows" else rows))
        lines = rows if axis == "rows" else cols
        x = cla.to_device(queue, random_complex(rng, (B, rows, cols)))
        even, poisoned = _even_frames(rng, 2, lines, n)
        if axis == "cols":
            even, poisoned = even.transpose(0, 2, 1).copy(), poisoned.transpose(0, 2, 1).copy()
        plan = F.RoundTripPlan((B, rows, cols), n, axis=axis, queue=queue, variant=variant)
        plain = plan.execute(x, multiply=cla.to_device(queue, even)).get()
        ef = plan.even_factors(cla.to_device(queue, poisoned))
        assert ef.layout == ("strips" if variant == "cpu" else "quarter") and ef.count == 2
        case = (B, rows, cols, n)
        np.testing.assert_array_equal(plan.execute(x, multiply=ef).get(), plain, str(case))
        if variant == "cpu":
            assert ef.nbytes == ef.data.nbytes > 0
            with pytest.raises(ValueError, match="keep no frames"):
                ef.frames
            np.testing.assert_array_equal(
                ef.data.get(), ref.even_strip_factors(even, ef.lanes, axis=axis), str(case))
        one = plan.even_factors(cla.to_device(queue, even[1]))  # one frame: every element
        np.testing.assert_array_equal(
            plan.execute(x, multiply=one).get(),
            plan.execute(x, multiply=cla.to_device(queue, even[1])).get(), str(case))


def test_even_factors_errors(queue, rng):
    plan = F.RoundTripPlan((1, 8, 24), 8, axis="cols", queue=queue, variant="cpu")
    other = F.RoundTripPlan((1, 8, 24), 8, axis="cols", queue=queue, variant="gpu")
    x = cla.to_device(queue, random_complex(rng, (1, 8, 24)))
    frames = cla.to_device(queue, random_complex(rng, (8, 24)))
    with pytest.raises(ValueError, match="even_factors"):
        plan.execute(x, multiply=other.even_factors(frames))
    with pytest.raises(ValueError, match=r"multiply.shape is \(24, 8\)"):
        plan.even_factors(cla.to_device(queue, random_complex(rng, (24, 8))))
    with pytest.raises(TypeError, match="multiply.dtype"):
        plan.even_factors(cla.to_device(queue, np.ones((8, 24), np.complex128)))
    with pytest.raises(TypeError, match="pyopencl.array.Array"):
        plan.even_factors(np.ones((8, 24), np.complex64))


@pytest.mark.parametrize("variant", VARIANTS)
@pytest.mark.parametrize("axis", ["rows", "cols"])
def test_even_multiply_reads_only_its_quarter(queue, rng, variant, axis):
    """multiply_even=True gives the same bits as the plain multiply of an even frame, and
    reads nothing beyond the frame's quarter (NaN there changes nothing)."""
    for B, rows, cols, n in EVEN_SIZES:
        n = max(n, F.next_fft_size(cols if axis == "rows" else rows))
        lines = rows if axis == "rows" else cols
        x = cla.to_device(queue, random_complex(rng, (B, rows, cols)))
        even, poisoned = _even_frames(rng, 2, lines, n)
        if axis == "cols":  # the frame is (n, lines): elements along axis 0
            even, poisoned = even.transpose(0, 2, 1).copy(), poisoned.transpose(0, 2, 1).copy()
        plan = F.RoundTripPlan((B, rows, cols), n, axis=axis, queue=queue, variant=variant)
        plain = plan.execute(x, multiply=cla.to_device(queue, even)).get()
        folded = plan.execute(x, multiply=cla.to_device(queue, even), multiply_even=True).get()
        quarter = plan.execute(x, multiply=cla.to_device(queue, poisoned),
                               multiply_even=True).get()
        case = (B, rows, cols, n)
        assert np.isfinite(plain).all(), case
        np.testing.assert_array_equal(folded, plain, err_msg=str(case))
        np.testing.assert_array_equal(quarter, plain, err_msg=str(case))
        want = ref.round_trip(x.get(), n, axis=axis, multiply=even)
        assert rel_l2(plain, want) <= tol("fft", np.float32)["rel_l2"], case


@pytest.mark.parametrize("variant", VARIANTS)
@pytest.mark.parametrize("H,W,Hp,C", [(16, 24, 32, 2), (13, 20, 27, 1), (12, 19, 25, 3)])
def test_column_round_trip_composites_too(queue, rng, variant, H, W, Hp, C):
    """the composite as the mid callback of a column round trip (lanes of adjacent columns:
    runs of four pixels of one row as they are), cropped to H rows"""
    B = C
    spec = random_complex(rng, (B, Hp, W))
    color = rng.random((H, W, C)).astype(np.float32)
    alpha = rng.random((H, W)).astype(np.float32)
    seed, layer, frame0 = int(rng.integers(0, 2 ** 40)), 1, 3
    k0, k1 = ref.seed_key(seed)
    plan = F.RoundTripPlan((B, Hp, W), Hp, axis="cols", first="inverse", mid_n=H,
                           mid_callback=COMPOSITE, queue=queue, variant=variant)
    dc, da = cla.to_device(queue, color), cla.to_device(queue, alpha)
    got = plan.execute(cla.to_device(queue, spec), mid_args=[
        dc, da, np.uint32(W), np.uint32(C), np.uint32(layer), np.uint32(frame0), k0, k1]).get()

    def mid(v):
        return np.stack([ref.composite_layer(v[c], color[..., c], alpha, ref.random_phase(
            (H, W), seed=seed, frame=frame0, colour=c, layer=layer)) for c in range(C)])

    want = ref.round_trip(spec, Hp, axis="cols", first="inverse", mid_n=H, mid=mid)
    assert rel_l2(got, want) <= tol("composite", np.float32)["rel_l2"]


@pytest.mark.parametrize("variant", VARIANTS)
@pytest.mark.parametrize("axis", ["rows", "cols"])
def test_pitch_reads_and_writes_the_first_cols_of_each_row(queue, rng, variant, axis):
    """A plan with a row pitch gives the unpitched plan's bits in the first ``cols`` elements
    of each row and leaves the rest of the row as it was."""
    for B, rows, cols, n, extra in [(2, 13, 40, 45, 16), (1, 16, 64, 64, 8), (3, 9, 17, 20, 3)]:
        n = max(n, F.next_fft_size(cols if axis == "rows" else rows))
        x = random_complex(rng, (B, rows, cols))
        m = random_complex(rng, _frame(axis, rows, cols, n))
        plain = F.RoundTripPlan((B, rows, cols), n, axis=axis, queue=queue, variant=variant)
        want = plain.execute(cla.to_device(queue, x), multiply=cla.to_device(queue, m)).get()
        P = cols + extra
        plan = F.RoundTripPlan((B, rows, cols), n, axis=axis, queue=queue, variant=variant,
                               pitch=P)
        assert plan.geometry.array_shape == (B, rows, P)
        xp = random_complex(rng, (B, rows, P))
        xp[..., :cols] = x
        junk = xp[..., cols:].copy()
        d = cla.to_device(queue, xp)
        got = plan.execute(d, out=d, multiply=cla.to_device(queue, m)).get()
        case = (B, rows, cols, n, P)
        np.testing.assert_array_equal(got[..., :cols], want, err_msg=str(case))
        np.testing.assert_array_equal(got[..., cols:], junk, err_msg=str(case))


def test_pitch_errors(queue, rng):
    with pytest.raises(ValueError, match="pitch=15 is shorter than a row of cols=16"):
        F.RoundTripPlan((2, 8, 16), 16, axis="rows", queue=queue, pitch=15)
    plan = F.RoundTripPlan((2, 8, 16), 16, axis="cols", queue=queue, pitch=20)
    with pytest.raises(ValueError, match=r"x.shape is \(2, 8, 16\), the plan expects \(2, 8, 20\)"):
        plan.execute(cla.to_device(queue, random_complex(rng, (2, 8, 16))))


def test_row_pitch_pads_rows_of_a_multiple_of_4_kib_on_cpus():
    assert F.row_pitch(2048, np.complex64, cpu=True) == 2064
    assert F.row_pitch(1024, np.complex128, cpu=True) == 1032
    assert F.row_pitch(512, np.complex64, cpu=True) == 528
    for n in (1944, 1125, 2250, 3888, 1000):
        assert F.row_pitch(n, np.complex64, cpu=True) == n
    assert F.row_pitch(2048, np.complex64, cpu=False) == 2048


@pytest.mark.parametrize("axis", ["rows", "cols"])
def test_gpu_batch_first_order_gives_the_same_bits(queue, rng, monkeypatch, axis):
    """The GPU kernels' batch-first work-group order (the tunable setting batch_fast, off by default until a
    GPU measures it) computes the same values: only the order of the groups changes."""
    B, rows, cols, n = 5, 12, 40, 48
    n = max(n, F.next_fft_size(cols if axis == "rows" else rows))
    x = cla.to_device(queue, random_complex(rng, (B, rows, cols)))
    m = cla.to_device(queue, random_complex(rng, (3,) + _frame(axis, rows, cols, n)))
    plain = F.RoundTripPlan((B, rows, cols), n, axis=axis, queue=queue, variant="gpu")
    want = plain.execute(x, multiply=m).get()
    monkeypatch.setattr(SETTINGS["batch_fast"], "default", True)
    plan = F.RoundTripPlan((B, rows, cols), n, axis=axis, queue=queue, variant="gpu")
    assert plan._gsize[0] == B * plan._lsize[0] and plan._gsize[1] == plan.mid_parts
    np.testing.assert_array_equal(plan.execute(x, multiply=m).get(), want)
