"""Lines that local memory holds one component of but not as complex values (issue 23: "lines
that do not fit local memory at once get a local-memory plan of their own, not global stages"):
7680 and 8192 points of complex64 in an H100's 48 KiB, the rows of a 4K grid at pad 2 and an
8192^2 grid, complex128 up to about 6000. The split plan (``fft_lines`` with ``FFT_SPLIT``)
keeps the values in registers between stages and exchanges them through local memory one
component at a time, so each axis is still one launch and a round trip still one pass, where before they
were one global-memory launch per radix stage and two plain passes.

Its butterflies are the in-place plan's, so its results are that plan's bit for bit: FFTs both
ways, round trips with a multiply, a render's rows with the composite (SGD's steps to float
rounding: its loss sums may add up in another order). Geometry with
an H100's limits (pure); results on PoCL with ``variant="gpu"``, at the real sizes and at small
ones through a device that reports less local memory; the kernel under Oclgrind (data races
on).
"""

import dataclasses

import numpy as np
import pyopencl.array as cla
import pytest

from clholo import fft as F
from clholo import reference as ref
from clholo.host import runtime
from conftest import fft_snippet, random_complex, run_snippet_under_oclgrind
from tolerances import rel_l2, tol

H100 = F.DeviceLimits(is_cpu=False, local_mem_size=48 * 1024, max_work_group_size=1024,
                      kernel_local=(("fft_lines", 16),))


def _limits(monkeypatch, local, wg=1024):
    """Plans see ``local`` bytes of local memory and ``wg`` work-items, kernels that hold none
    themselves (PoCL's device has more of both)."""
    real_of = F.DeviceLimits.of
    monkeypatch.setattr(F.DeviceLimits, "of", classmethod(
        lambda cls, dev: dataclasses.replace(real_of(dev), local_mem_size=local,
                                             max_work_group_size=min(wg, dev.max_work_group_size),
                                             kernel_local=())))
    monkeypatch.setattr(F.runtime, "kernel_local_bytes", lambda knl, dev: 0)
    F.clear_plan_cache()


def _split(p):
    return bool(dict(p.defines).get("FFT_SPLIT"))


def _long_pass(plan, n):
    (p,) = [p for p in plan.geometry.passes if p.n == n]
    return p


@pytest.mark.parametrize("shape, dtype", [((4, 8192), np.complex64), ((8192, 4), np.complex64),
                                          ((3, 7680), np.complex64), ((7680, 2), np.complex64),
                                          ((2, 3840), np.complex128), ((6000, 2), np.complex128)])
def test_h100_plans_the_long_lines_split(shape, dtype):
    g = F.plan_geometry(shape, dtype, device=H100, variant="gpu")
    n = max(shape)
    (p,) = [p for p in g.passes if p.n == n]
    assert p.kind == "gpu" and _split(p), p
    (lg,) = p.launches
    assert lg.local_bytes == n * np.dtype(dtype).itemsize // 2
    assert lg.local_bytes + 16 <= H100.local_mem_size and lg.lsize[0] <= 256
    assert not any(role.startswith("stage") for role, _ in g.buffers)  # no global stages
    defines = dict(p.defines)
    assert "FFT_INPLACE_DIRECT" not in defines  # the split plan reads and writes global itself
    # every stage names the stage before it; the first names the last
    stages = defines["FFT_SPLIT_STAGES"].split("FFT_SSTAGE")[1:]
    assert len(stages) >= 2
    params = [tuple(int(v) for v in s.strip("()").split(",")) for s in stages]
    for cur, prev in zip(params, params[-1:] + params[:-1]):
        assert cur[3:] == prev[:3]
    assert np.prod([r1 * r2 for r1, r2, *_ in params]) == n


def test_h100_lines_beyond_one_component_still_run_global_stages():
    g = F.plan_geometry((2, 16384), np.complex64, device=H100, variant="gpu")  # 64 KiB of reals
    assert [p.kind for p in g.passes if p.n == 16384] == ["global"]
    g = F.plan_geometry((2, 4096), np.complex64, device=H100, variant="gpu")  # fits in place
    assert not _split(g.passes[0]) and dict(g.passes[0].defines).get("FFT_INPLACE")


def test_h100_the_4k_grid_at_pad_2_renders_as_two_kernels():
    """What host/scheduler.py asks before it runs a layer as two kernels: 2160x3840 at pad 2
    (grid 4320x7680), and an 8192^2 grid, fit round trips on an H100 now."""
    for (H, Hp, Wp) in ((2160, 4320, 7680), (4096, 8192, 8192)):
        assert F.round_trip_fits((1, H, Wp), Hp, device=H100, axis="cols", variant="gpu")
        assert F.round_trip_fits((1, H, Wp), Wp, device=H100, axis="rows", variant="gpu")
        g = F.round_trip_geometry((3, H, Wp), Wp, device=H100, axis="rows", variant="gpu")
        assert _split(g.pass_)


@pytest.mark.parametrize("wg", [1024, 16])
@pytest.mark.parametrize("n", [100, 120, 125, 128])
def test_split_fft_is_the_in_place_plan_bit_for_bit(queue, rng, monkeypatch, wg, n):
    """600 bytes of local memory hold 100..128 points as floats, not as complex values: the split
    plan, against NumPy and against the in-place plan (1200 bytes), bit for bit; rows and
    columns, forward and inverse, a zero-padded input window and a cropped output. Few
    work-items (16) give each several butterflies per stage."""
    t = tol("fft", np.float32)["rel_l2"]
    # the split plan's stages (the largest smallest radix among the fewest stages) are the
    # in-place plan's at these sizes
    assert F._fused_radices(n, 16, True) == F._fused_radices(n, 16)
    for shape, kw in (((3, 5, n), {}), ((n, 6), {}),
                      ((6, n), dict(input_shape=(4, n - 11), output_shape=(5, n - 3))),
                      ((n, 4), dict(input_shape=(n - 7, 3), output_shape=(n - 2, 4)))):
        got = {}
        for local in (600, 1200):
            _limits(monkeypatch, local, wg)
            plan = F.FFTPlan(shape, np.complex64, queue=queue, variant="gpu", **kw)
            p = _long_pass(plan, n)
            assert _split(p) == (local == 600) and dict(p.defines).get("FFT_INPLACE"), p
            assert len(p.launches) == 1
            x = random_complex(rng, kw.get("input_shape", shape)) if local == 600 else x
            got[local] = plan.execute_host(x), plan.execute_host(x, inverse=True)
        s = shape[-2:]
        want = np.fft.fft2(x.astype(np.complex128), s=s)
        want_inv = np.fft.ifft2(x.astype(np.complex128), s=s)
        o = kw.get("output_shape", s)
        assert rel_l2(got[600][0], want[..., :o[0], :o[1]]) <= t
        assert rel_l2(got[600][1], want_inv[..., :o[0], :o[1]]) <= t
        for a, b in zip(got[600], got[1200]):
            np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("axis", ["rows", "cols"])
@pytest.mark.parametrize("first", ["forward", "inverse"])
def test_split_round_trip_is_the_in_place_plan_bit_for_bit(queue, rng, monkeypatch, axis, first):
    t = tol("fft", np.float32)["rel_l2"]
    for n, wg in ((120, 1024), (125, 16), (100, 64)):
        shape = (2, 5, n - 3) if axis == "rows" else (2, n - 3, 6)
        x = random_complex(rng, shape)
        m = random_complex(rng, (5, n) if axis == "rows" else (n, 6))
        got = {}
        for local in (600, 1200):
            _limits(monkeypatch, local, wg)
            plan = F.RoundTripPlan(shape, n, axis=axis, first=first, mid_n=n - 9, queue=queue,
                                   variant="gpu")
            assert _split(plan.geometry.pass_) == (local == 600)
            got[local] = plan.execute(cla.to_device(queue, x),
                                      multiply=cla.to_device(queue, m)).get()
        want = ref.round_trip(x, n, axis=axis, first=first, mid_n=n - 9, multiply=m)
        assert rel_l2(got[600], want) <= t
        np.testing.assert_array_equal(got[600], got[1200])


@pytest.mark.parametrize("axis", ["rows", "cols"])
def test_split_round_trip_with_a_mid_callback(queue, rng, monkeypatch, axis):
    """A mid callback (which the split plan runs in a sweep over local memory, half a line at
    a time) that tells frame positions and batch elements apart: against the reference and
    the in-place plan's bits, at an odd length (halves of 63 and 62) and an even one."""
    from test_fft_round_trip import MID_AFFINE

    t = tol("fft", np.float32)["rel_l2"]
    for n, wg in ((125, 16), (120, 1024)):
        B, rows, cols = (2, 5, n - 4) if axis == "rows" else (2, n - 4, 6)
        frame = (rows, n) if axis == "rows" else (n, cols)
        x, m, gm = (random_complex(rng, sh) for sh in ((B, rows, cols), frame, frame))
        got = {}
        for local in (600, 1200):
            _limits(monkeypatch, local, wg)
            plan = F.RoundTripPlan((B, rows, cols), n, axis=axis, first="inverse",
                                   mid_n=n - 10, mid_callback=MID_AFFINE, queue=queue,
                                   variant="gpu")
            assert _split(plan.geometry.pass_) == (local == 600)
            got[local] = plan.execute(cla.to_device(queue, x), multiply=cla.to_device(queue, m),
                                      mid_args=[cla.to_device(queue, gm), frame[1], 0.5]).get()

        def mid(v):
            s = (0.5 + np.arange(B))[:, None, None]
            return v * s + (gm[:, :n - 10] if axis == "rows" else gm[:n - 10, :])

        want = ref.round_trip(x, n, axis=axis, first="inverse", multiply=m, mid_n=n - 10,
                              mid=mid)
        assert rel_l2(got[600], want) <= t, n
        np.testing.assert_array_equal(got[600], got[1200])


def test_split_in_place_pass_with_src_equal_dst(queue, rng, monkeypatch):
    """A pass that reads and writes the same buffer (an FFTPlan of one axis, out=x): every
    read of the source is ordered before the last stage's writes."""
    _limits(monkeypatch, 600, 16)
    plan = F.FFTPlan((3, 120), np.complex64, queue=queue, variant="gpu", axes=(-1,))
    assert _split(plan.geometry.passes[0])
    x = random_complex(rng, (3, 120))
    d = cla.to_device(queue, x)
    plan.execute(d, out=d)
    assert rel_l2(d.get(), np.fft.fft(x.astype(np.complex128), axis=-1)) \
        <= tol("fft", np.float32)["rel_l2"]


def test_split_complex128(queue, cl_device, rng, monkeypatch):
    if not runtime.has_fp64(cl_device):
        pytest.skip("device without fp64")
    _limits(monkeypatch, 1200)  # 100 points: 1600 bytes as complex128, 800 as doubles
    t = tol("fft", np.float64)["rel_l2"]
    for shape in ((3, 100), (100, 4)):
        plan = F.FFTPlan(shape, np.complex128, queue=queue, variant="gpu")
        assert _split(_long_pass(plan, 100))
        x = random_complex(rng, shape, np.complex128)
        assert rel_l2(plan.execute_host(x), np.fft.fft2(x)) <= t
    for axis, shape in (("rows", (2, 3, 97)), ("cols", (1, 97, 4))):
        plan = F.RoundTripPlan(shape, 100, np.complex128, axis=axis, mid_n=90, queue=queue,
                               variant="gpu")
        assert _split(plan.geometry.pass_)
        x = random_complex(rng, shape, np.complex128)
        m = random_complex(rng, (3, 100) if axis == "rows" else (100, 4), np.complex128)
        got = plan.execute(cla.to_device(queue, x), multiply=cla.to_device(queue, m)).get()
        assert rel_l2(got, ref.round_trip(x, 100, axis=axis, multiply=m, mid_n=90)) <= t


@pytest.mark.parametrize("n", [7680, 8192])
def test_split_at_the_real_sizes(queue, rng, monkeypatch, n):
    """The H100's case on PoCL: 48 KiB, the in-place kernel's 256 work-items; an FFT of rows
    and of columns and a row round trip, against NumPy and the reference."""
    _limits(monkeypatch, 48 * 1024, 256)
    t = tol("fft", np.float32)["rel_l2"]
    for shape in ((2, n), (n, 2)):
        plan = F.FFTPlan(shape, np.complex64, queue=queue, variant="gpu")
        p = _long_pass(plan, n)
        assert _split(p) and p.launches[0].lsize[0] <= 256
        x = random_complex(rng, shape)
        assert rel_l2(plan.execute_host(x), np.fft.fft2(x.astype(np.complex128))) <= t
    shape = (1, 2, n - 40)
    plan = F.RoundTripPlan(shape, n, axis="rows", first="inverse", mid_n=n - 100, queue=queue,
                           variant="gpu")
    assert _split(plan.geometry.pass_)
    x, m = random_complex(rng, shape), random_complex(rng, (2, n))
    got = plan.execute(cla.to_device(queue, x), multiply=cla.to_device(queue, m)).get()
    want = ref.round_trip(x, n, axis="rows", first="inverse", mid_n=n - 100, multiply=m)
    assert rel_l2(got, want) <= t


def test_split_rows_render_the_same_holograms(queue, rng, monkeypatch, built_defines):
    """A render on the GPU kernels as two kernels a layer, its 512-point rows split (3000 bytes
    of local memory) or in place (6000): the same frames, bit for bit (the composite runs on
    the first transform's outputs in registers instead of in a sweep over local memory)."""
    from test_tuning import _not_a_cpu, _render, _every_line_in_place

    _not_a_cpu(monkeypatch)
    _every_line_in_place(monkeypatch)
    seen = built_defines
    seed = int(rng.integers(2 ** 31))
    frames = {}
    for local in (3000, 6000):
        seen.clear()
        _limits(monkeypatch, local)
        r, frames[local] = _render(queue, seed)
        assert r.two_pass
        split_rows = [d for d in seen if d.get("FFT_SPLIT") and d.get("FFT_N") == 512
                      and d.get("FFT_ROUND_TRIP")]
        assert bool(split_rows) == (local == 3000), seen
    np.testing.assert_array_equal(frames[3000], frames[6000])
    assert np.abs(frames[3000]).max() > 0


def test_split_sgd_steps(queue, rng, monkeypatch, built_defines):
    """SGD's round trips on the GPU kernels with split rows (the loss sums accumulate on the
    first transform's outputs in registers): three steps, the phase, moments and gradient of
    the in-place plan within float rounding, and the loss."""
    from test_encode import gpu_round_trip_steps
    from test_tuning import _every_line_in_place

    _every_line_in_place(monkeypatch)
    real_of = F.DeviceLimits.of
    monkeypatch.setattr(F.runtime, "kernel_local_bytes", lambda knl, dev: 0)

    class Local:  # gpu_round_trip_steps sets an attribute per run
        value = 0

    def of(cls, dev):
        return dataclasses.replace(real_of(dev), local_mem_size=Local.value, kernel_local=())

    monkeypatch.setattr(F.DeviceLimits, "of", classmethod(of))
    seen = built_defines
    runs = gpu_round_trip_steps(queue, int(rng.integers(2 ** 32)), monkeypatch, Local, "value",
                                [300, 1 << 15])
    # the 300-byte run split SGD's 48-point rows (as floats 192 bytes, as complex 384)
    assert any(d.get("FFT_SPLIT") and d.get("FFT_N") == 48 and d.get("FFT_ROUND_TRIP")
               for d in seen), seen
    for key in ("phase", "adam_m", "grad", "loss"):
        np.testing.assert_allclose(runs[0][key], runs[1][key], rtol=1e-5, atol=1e-7,
                                   err_msg=key)


_OCLGRIND_SNIPPET = fft_snippet("""
    for shape in ((2, 120), (120, 3)):
        plan = F.FFTPlan(shape, np.complex64, queue=q, variant="gpu")
        assert any(dict(p.defines).get("FFT_SPLIT") for p in plan.geometry.passes)
        x = rnd(shape)
        errs.append(rel(plan.execute_host(x), np.fft.fft2(x.astype(np.complex128))))
        errs.append(rel(plan.execute_host(x, inverse=True), np.fft.ifft2(x.astype(np.complex128))))
    plan = F.FFTPlan((2, 100), np.complex64, queue=q, variant="gpu", axes=(-1,))
    x = rnd((2, 100))
    d = cla.to_device(q, x)
    plan.execute(d, out=d)  # in place: source and destination one buffer
    errs.append(rel(d.get(), np.fft.fft(x.astype(np.complex128), axis=-1)))
    # v * (s + b) + g[row][col]: a mid callback, in the sweep half a line at a time
    mid_cb = F.FFTCallback('''
    real2 clholo_mid(real2 v, long b, int row, int col, __global const real2 *g, int w, real s)
    {
        return v * (s + (real)b) + g[row * w + col];
    }
    ''', params=["__global const real2 *", "int", "real"])
    for n in (120, 125):
        for axis, shape in (("rows", (2, 2, n - 3)), ("cols", (1, n - 3, 2))):
            plan = F.RoundTripPlan(shape, n, axis=axis, mid_n=n - 20, queue=q, variant="gpu")
            assert dict(plan.geometry.pass_.defines).get("FFT_SPLIT")
            x = rnd(shape)
            fr = (2, n) if axis == "rows" else (n, 2)
            m, gm = rnd(fr), rnd(fr)
            got = plan.execute(cla.to_device(q, x), multiply=cla.to_device(q, m)).get()
            errs.append(rel(got, ref.round_trip(x, n, axis=axis, multiply=m, mid_n=n - 20)))
            plan = F.RoundTripPlan(shape, n, axis=axis, first="inverse", mid_n=n - 20,
                                   mid_callback=mid_cb, queue=q, variant="gpu")
            got = plan.execute(cla.to_device(q, x), multiply=cla.to_device(q, m),
                               mid_args=[cla.to_device(q, gm), fr[1], 0.5]).get()
            def mid(v):
                s = (0.5 + np.arange(shape[0]))[:, None, None]
                return v * s + (gm[:, :n - 20] if axis == "rows" else gm[:n - 20, :])
            errs.append(rel(got, ref.round_trip(x, n, axis=axis, first="inverse", multiply=m,
                                                mid_n=n - 20, mid=mid)))
""", local=600, wg=16, seed=7)


def test_split_under_oclgrind():
    """The split plan, FFTs both ways, a pass in place and round trips (with a mid callback:
    the sweep half a line at a time), on the simulator with data races on (a barrier between
    the exchange's writes and reads left out is a race)."""
    run_snippet_under_oclgrind(_OCLGRIND_SNIPPET)


# --- the tunable setting split_columns: columns that two buffers hold too few of, split ---

@pytest.mark.parametrize("threads", [512, 1024])
def test_h100_split_columns_hold_more_columns_a_group(threads):
    """split_columns (off by default): on an H100's limits the SLM grid's 1125-point columns ten
    to a group (two buffers: two; in place: five), 2048-point columns five (one, two), with
    the two-buffer plan's stages in its order; where inplace_columns is on too, the plan that
    holds more; columns two buffers hold enough of, or none of, keep their plans."""
    from clholo.host import tuning

    def cols(shape, n, **settings):
        with tuning.override(**settings):
            g = F.round_trip_geometry(shape, n, device=H100, axis="cols", variant="gpu")
        (lg,) = g.pass_.launches
        return g.pass_, lg.extra[0], lg.lsize[0], lg.local_bytes

    for shape, n, want, two in (((9, 1080, 1944), 1125, 10, 2), ((1, 1024, 2048), 2048, 5, 1)):
        p, lines, nthr, local = cols(shape, n, split_columns=threads)
        assert _split(p) and (lines, nthr) == (want, threads), (n, lines, nthr)
        assert local == lines * (n + n % 2) * 4 <= H100.local_budget("fft_lines")
        d = dict(p.defines)
        # the two-buffer plan's stages, in its order (its bits), each naming the one before
        stages = [tuple(int(v) for v in s.strip("()").split(",")[:2])
                  for s in d["FFT_SPLIT_STAGES"].split("FFT_SSTAGE")[1:]]
        assert stages == list(F._fused_radices(n, F._FUSED_RADIX_MAX)), stages
        assert d["FFT_STAGE_LIST"] == F._stage_list(n, F._FUSED_RADIX_MAX)
        assert d["FFT_WG"] == threads and d["FFT_INPLACE"] <= F._INPLACE_MAX_PER_ITEM
        p, lines, _, _ = cols(shape, n, split_columns=threads, inplace_columns=True)
        assert _split(p) and lines == want
        p, lines, _, _ = cols(shape, n)
        assert not _split(p) and lines == two
    # the rows are not columns
    with tuning.override(split_columns=threads):
        g = F.round_trip_geometry((9, 1080, 1944), 1944, device=H100, axis="rows",
                                  variant="gpu")
        assert not _split(g.pass_)


@pytest.mark.parametrize("threads", [512, 1024])
def test_h100_split_columns_of_the_in_place_plan(threads):
    """Columns that the in-place plan holds fewer than four of (the 4K grid's 2187 points, SGD
    2048's 2250: two to a group) take the split plan with the in-place plan's own stages: five
    to a group; rows and columns the in-place plan holds four or more of keep it."""
    from clholo.host import tuning

    for shape, n in (((3, 2160, 3888), 2187), ((1, 2048, 2250), 2250)):
        inplace = F.round_trip_geometry(shape, n, device=H100, axis="cols", variant="gpu").pass_
        with tuning.override(split_columns=threads):
            p = F.round_trip_geometry(shape, n, device=H100, axis="cols", variant="gpu").pass_
        assert not _split(inplace) and inplace.launches[0].extra[0] == 2
        assert _split(p) and p.launches[0].extra[0] == 5, p.launches
        assert p.launches[0].lsize[0] == min(threads, F._SPLIT_INPLACE_COLUMN_THREADS)
        d, di = dict(p.defines), dict(inplace.defines)
        assert d["FFT_STAGE_LIST"] == di["FFT_STAGE_LIST"]
        stages = [tuple(int(v) for v in s.strip("()").split(",")[:2])
                  for s in d["FFT_SPLIT_STAGES"].split("FFT_SSTAGE")[1:]]
        assert stages == list(F._fused_radices(n, F._INPLACE_FUSED_RADIX_MAX))
    with tuning.override(split_columns=threads):
        g = F.round_trip_geometry((3, 2160, 3888), 3888, device=H100, axis="rows", variant="gpu")
        assert not _split(g.pass_) and dict(g.pass_.defines).get("FFT_INPLACE")


@pytest.mark.parametrize("direct", [False, True])
@pytest.mark.parametrize("n", [2187, 2250])
def test_split_columns_give_the_in_place_bits(queue, rng, monkeypatch, n, direct):
    """split_columns on columns of the in-place plan (48 KiB: two to a group; with and without
    its direct stages, inplace_direct): the same FFTs both ways and column round trips with a
    multiply, bit for bit, with more columns a group."""
    from clholo.host import tuning

    _limits(monkeypatch, 48 * 1024)
    monkeypatch.setattr(tuning.SETTINGS["inplace_direct"], "default", direct)
    x = random_complex(rng, (n, 12))
    xr, m = random_complex(rng, (3, n - 25, 12)), random_complex(rng, (n, 12))
    runs = []
    for threads in (0, 512):
        with tuning.override(split_columns=threads):
            plan = F.FFTPlan((n, 12), np.complex64, queue=queue, variant="gpu")
            rt = F.RoundTripPlan((3, n - 25, 12), n, axis="cols", mid_n=n - 40, queue=queue,
                                 variant="gpu")
        for p in (_long_pass(plan, n), rt.geometry.pass_):
            assert _split(p) == bool(threads) and dict(p.defines).get("FFT_INPLACE")
            assert p.launches[0].extra[0] == (5 if threads else 2), p.launches
        runs.append([plan.execute_host(x), plan.execute_host(x, inverse=True),
                     rt.execute(cla.to_device(queue, xr), multiply=cla.to_device(queue, m)).get()])
    for a, b in zip(*runs):
        np.testing.assert_array_equal(b.view(np.float32), a.view(np.float32))
    want = ref.round_trip(xr, n, axis="cols", multiply=m, mid_n=n - 40)
    assert rel_l2(runs[1][2], want) <= tol("fft", np.float32)["rel_l2"]


def test_split_columns_planned_again_within_the_kernels_work_items():
    """A built kernel that allows fewer work-items (NVIDIA's CL_KERNEL_WORK_GROUP_SIZE, set by
    its registers) gives fewer columns a group: 256 hold five 1125-point columns, which the
    in-place plan holds too, and it is taken at the tie."""
    from clholo.host import tuning

    learnt = dataclasses.replace(H100, kernel_threads=(("fft_lines", 256),))
    with tuning.override(split_columns=1024):
        g = F.round_trip_geometry((9, 1080, 1944), 1125, device=learnt, axis="cols",
                                  variant="gpu")
        assert _split(g.pass_) and g.pass_.launches[0].lsize == (256, 1)
        assert g.pass_.launches[0].extra[0] == 5
    with tuning.override(split_columns=1024, inplace_columns=True):
        g = F.round_trip_geometry((9, 1080, 1944), 1125, device=learnt, axis="cols",
                                  variant="gpu")
        assert not _split(g.pass_) and dict(g.pass_.defines).get("FFT_INPLACE")
        assert g.pass_.launches[0].extra[0] == 5


def test_split_columns_complex128(queue, cl_device, rng, monkeypatch):
    """complex128 columns of 2250 points at 48 KiB: in place one to a group, split two (its
    doubles), the same bits."""
    from clholo.host import tuning

    if not runtime.has_fp64(cl_device):
        pytest.skip("device without fp64")
    _limits(monkeypatch, 48 * 1024)
    x = random_complex(rng, (2250, 4), np.complex128)
    got = []
    for threads in (0, 1024):
        with tuning.override(split_columns=threads):
            plan = F.FFTPlan((2250, 4), np.complex128, queue=queue, variant="gpu")
        p = _long_pass(plan, 2250)
        assert _split(p) == bool(threads) and p.launches[0].extra[0] == (2 if threads else 1)
        got.append(plan.execute_host(x))
    np.testing.assert_array_equal(got[1].view(np.float64), got[0].view(np.float64))
    assert rel_l2(got[1], np.fft.fft2(x)) <= tol("fft", np.float64)["rel_l2"]


def test_split_columns_sgd_steps(queue, rng, monkeypatch, built_defines):
    """SGD's round trips on the GPU kernels at 300 bytes of local memory (its rows split, its
    columns in place one to a group) with split_columns: its columns split too, three to a
    group, and three steps give the same phase, moments, gradient and loss, bit for bit."""
    from clholo.host import tuning
    from test_encode import gpu_round_trip_steps
    from test_tuning import _every_line_in_place

    _every_line_in_place(monkeypatch)
    _limits(monkeypatch, 300)
    runs = gpu_round_trip_steps(queue, int(rng.integers(2 ** 32)), monkeypatch,
                                tuning.SETTINGS["split_columns"], "default", [0, 512])
    cols = [d for d in built_defines if d.get("FFT_LINE_FAST") and d.get("FFT_ROUND_TRIP")]
    assert any(d.get("FFT_SPLIT") and d["FFT_L"] > 1 for d in cols), cols
    assert any(d.get("FFT_INPLACE") and not d.get("FFT_SPLIT") and d["FFT_L"] == 1
               for d in cols), cols
    for key in ("phase", "adam_m", "grad", "loss"):
        np.testing.assert_array_equal(runs[1][key], runs[0][key], err_msg=key)


_OCLGRIND_COLUMNS_SNIPPET = fft_snippet("""
    # split_columns: 125- and 120-point columns seven and eight to a group of 64 work-items
    # (two buffers of 4000 bytes hold two), the last group partly full; FFTs both ways, round
    # trips with a multiply, against NumPy and the reference
    SETTINGS["split_columns"].default = 512
    for n in (125, 120):  # as many as 4000 bytes hold of one component (two buffers: two)
        check_columns(n, 15, n - 5, "FFT_SPLIT", 4000 // ((n + n % 2) * 4))
    # 400-point columns, which the in-place plan holds one of (two buffers none): split with
    # its stages, two to a group
    check_columns(400, 5, 390, "FFT_SPLIT", 2)
""", local=4000, wg=64, seed=11)


def test_split_columns_under_oclgrind():
    """split_columns on the simulator with data races on: several columns a group, a last
    group partly full, FFTs and round trips, with the two-buffer and the in-place plan's
    stages."""
    run_snippet_under_oclgrind(_OCLGRIND_COLUMNS_SNIPPET)


def test_in_place_plan_takes_balanced_stages_only_where_its_own_do_not_fit(queue, rng,
                                                                           monkeypatch):
    """8192 points as 16 16 16 2 give a work-item 16 radix-2 butterflies at 256 work-items,
    beyond the in-place plan's 8: where the local memory holds the line (64 KiB, an AMD GPU's;
    PoCL) it takes 16 8 8 8 instead of global stages; the lines whose stages fit keep them
    (their bits)."""
    amd = F.DeviceLimits(is_cpu=False, local_mem_size=64 * 1024, max_work_group_size=1024)
    (p,) = F.plan_geometry((2, 8192), np.complex64, device=amd, variant="gpu", axes=(-1,)).passes
    d = dict(p.defines)
    assert p.kind == "gpu" and d.get("FFT_INPLACE") and not d.get("FFT_SPLIT")
    assert d["FFT_STAGE_LIST"] == F._stage_list(8192, 16, True) != F._stage_list(8192, 16)
    for n in (2250, 2187, 3888, 4096, 2560):
        for dev in (amd, H100):
            (p,) = F.plan_geometry((2, n), np.complex64, device=dev, variant="gpu",
                                   axes=(-1,)).passes
            assert dict(p.defines)["FFT_STAGE_LIST"] == F._stage_list(n, 16), (n, dev)
    _limits(monkeypatch, 64 * 1024, 256)
    for shape in ((2, 8192), (8192, 2)):
        plan = F.FFTPlan(shape, np.complex64, queue=queue, variant="gpu")
        p = _long_pass(plan, 8192)
        assert dict(p.defines).get("FFT_INPLACE") and not _split(p)
        x = random_complex(rng, shape)
        assert rel_l2(plan.execute_host(x), np.fft.fft2(x.astype(np.complex128))) \
            <= tol("fft", np.float32)["rel_l2"]


def test_plan_reach_and_clholo_info_say_how_far_a_line_stays_one_launch(monkeypatch, capsys,
                                                                        cl_device):
    """``clholo.fft.plan_reach``: on an H100's limits two buffers take up to 2048 complex64
    points, the in-place plan up to 6075, the split plan up to 12150 (as complex128, half);
    ``clholo info`` prints it for the device it uses (here shown an H100's limits)."""
    assert F.plan_reach(H100) == {"two buffers": 2048, "in place": 6075, "split": 12150,
                                  "global stages": 16384}
    assert F.plan_reach(H100, np.complex128) == {"two buffers": 1024, "in place": 3000,
                                                 "split": 6075, "global stages": 16384}
    cpu = F.DeviceLimits(is_cpu=True, local_mem_size=1 << 20, max_work_group_size=4096)
    assert F.plan_reach(cpu) == {"cpu strips": 16384}
    from clholo import cli

    monkeypatch.setattr(F.DeviceLimits, "of", classmethod(lambda cls, dev: H100))
    assert cli.main(["info"]) == 0
    line = [ln for ln in capsys.readouterr().out.splitlines() if ln.startswith("FFT on *")]
    assert line == ["FFT on *: complex64 lines one launch a pass up to 12150 points (two local "
                    "buffers up to 2048, in place up to 6075, split up to 12150); longer ones "
                    "one launch a radix stage (a render's layer then takes four passes)"], line
