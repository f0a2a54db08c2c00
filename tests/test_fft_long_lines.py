"""Lines too long for the GPU variant's two local-memory buffers (issue 23): more than 2048
complex64 points (2250, 2187, 2560, 3888, 4096) are held once in the device's whole local
memory and every stage runs in place (``fft_lines`` with ``FFT_INPLACE``), so each axis is
one launch, for :class:`clholo.fft.FFTPlan` passes and for :class:`clholo.fft.RoundTripPlan`.

The geometry is checked with an H100's limits (pure, no device); the results on PoCL with
``variant="gpu"`` against NumPy and :func:`clholo.reference.round_trip`, at the real sizes and,
through a device that reports less local memory, at small sizes; the kernel runs under
Oclgrind (data races on) with no reports.
"""

import dataclasses
import math

import numpy as np
import pyopencl.array as cla
import pytest

from clholo import fft as F
from clholo.host.tuning import SETTINGS
from clholo import reference as ref
from clholo.host import runtime
from conftest import fft_snippet, random_complex, run_snippet_under_oclgrind
from tolerances import rel_l2, tol

LONG = [2250, 2187, 3888, 4096, 2560]
# NVIDIA H100: 48 KiB of local memory, 1024 work-items; fft_lines holds a few bytes itself
H100 = F.DeviceLimits(is_cpu=False, local_mem_size=48 * 1024, max_work_group_size=1024,
                      kernel_local=(("fft_lines", 16),))


def _check_launches(p, device):
    (lg,) = p.launches
    assert p.kind == "gpu" and p.kernel == "fft_lines", p
    assert lg.local_bytes + dict(device.kernel_local).get("fft_lines", 0) \
        <= device.local_mem_size, lg
    assert lg.lsize[0] <= device.max_work_group_size
    lines = lg.extra[0]
    assert lg.gsize[0] // lg.lsize[0] * lines >= p.nlines  # every line is covered


@pytest.mark.parametrize("shape", [(2250, 2250), (2187, 3888), (4096, 4096), (2560, 2560),
                                   (3888, 2187), (1125, 1944), (2, 4096)])
def test_h100_plans_one_launch_per_axis(shape):
    g = F.plan_geometry(shape, np.complex64, device=H100, variant="gpu")
    assert len(g.passes) == 2
    for p in g.passes:
        _check_launches(p, H100)
    assert not any(role.startswith("stage") for role, _ in g.buffers)
    # a line beyond what the local memory holds even one component of still runs as global
    # stages (8192 points take the split plan: tests/test_fft_split.py)
    g = F.plan_geometry((4, 16384), np.complex64, device=H100, variant="gpu")
    assert sorted(p.kind for p in g.passes) == ["global", "gpu"]


@pytest.mark.parametrize("n", LONG)
def test_h100_round_trips_fit_the_long_lines(n):
    for axis in ("rows", "cols"):
        shape = (3, 1080, n) if axis == "rows" else (3, n, 1920)
        assert F.round_trip_fits(shape, n, device=H100, axis=axis)
        g = F.round_trip_geometry(shape, n, device=H100, axis=axis)
        _check_launches(g.pass_, H100)
        assert dict(g.pass_.defines).get("FFT_INPLACE", 0) >= 1


@pytest.mark.parametrize("n", LONG)
def test_long_lines_fft2_matches_numpy(queue, rng, n):
    """Both axes at each long size (the other axis short so that PoCL stays quick), forward
    and inverse, a zero-padded input window and a cropped output."""
    t = tol("fft", np.float32)["rel_l2"]
    for shape in ((2, 6, n), (n, 5)):
        plan = F.FFTPlan(shape, np.complex64, queue=queue, variant="gpu")
        long_pass = [p for p in plan.geometry.passes if p.n == n][0]
        assert dict(long_pass.defines).get("FFT_INPLACE"), long_pass  # the new path ran
        assert len(long_pass.launches) == 1
        x = random_complex(rng, shape)
        assert rel_l2(plan.execute_host(x), np.fft.fft2(x.astype(np.complex128))) <= t
        assert rel_l2(plan.execute_host(x, inverse=True),
                      np.fft.ifft2(x.astype(np.complex128))) <= t
    hp, wp = 8, n
    plan = F.FFTPlan((hp, wp), np.complex64, queue=queue, variant="gpu",
                     input_shape=(5, n - 100), output_shape=(7, n - 37))
    x = random_complex(rng, (5, n - 100))
    want = np.fft.fft2(x.astype(np.complex128), s=(hp, wp))[:7, :n - 37]
    assert rel_l2(plan.execute_host(x), want) <= t


def test_long_lines_complex128(queue, cl_device, rng):
    if not runtime.has_fp64(cl_device):
        pytest.skip("device without fp64")
    for shape in ((3, 2250), (2048, 3)):  # 2048 complex128: two buffers exceed 32 KiB
        plan = F.FFTPlan(shape, np.complex128, queue=queue, variant="gpu")
        assert any(dict(p.defines).get("FFT_INPLACE") for p in plan.geometry.passes)
        x = random_complex(rng, shape, np.complex128)
        assert rel_l2(plan.execute_host(x), np.fft.fft2(x)) <= tol("fft", np.float64)["rel_l2"]


@pytest.mark.parametrize("n", [2250, 3888])
@pytest.mark.parametrize("axis", ["rows", "cols"])
@pytest.mark.parametrize("first", ["forward", "inverse"])
def test_long_round_trip_matches_reference(queue, rng, n, axis, first):
    rows, cols = (3, n - 10) if axis == "rows" else (n - 10, 5)
    x = random_complex(rng, (2, rows, cols))
    m = random_complex(rng, (rows, n) if axis == "rows" else (n, cols))
    mid_n = n - 50
    plan = F.RoundTripPlan((2, rows, cols), n, axis=axis, first=first, mid_n=mid_n,
                           queue=queue, variant="gpu")
    assert dict(plan.geometry.pass_.defines).get("FFT_INPLACE")
    got = plan.execute(cla.to_device(queue, x), multiply=cla.to_device(queue, m)).get()
    want = ref.round_trip(x, n, axis=axis, first=first, multiply=m, mid_n=mid_n)
    assert rel_l2(got, want) <= tol("fft", np.float32)["rel_l2"]


def _small_local(monkeypatch, local, wg):
    """Plans see a device with ``local`` bytes of local memory and ``wg`` work-items, and
    kernels that hold no local memory themselves (NVIDIA's ``fft_lines`` holds a few bytes,
    which at 1000 bytes would leave the in-place plan no room; the real device has 48 KiB)."""
    real_of = F.DeviceLimits.of
    monkeypatch.setattr(F.DeviceLimits, "of", classmethod(
        lambda cls, dev: dataclasses.replace(real_of(dev), local_mem_size=local,
                                             max_work_group_size=wg, kernel_local=())))
    monkeypatch.setattr(F.runtime, "kernel_local_bytes", lambda knl, dev: 0)


def _fewer_work_items(monkeypatch, most):
    """Built ``fft_lines`` kernels allow at most ``most`` work-items per group (as NVIDIA's
    driver reports 256 for the in-place kernel on a 1024-work-item device)."""
    real = runtime.kernel_work_group_size
    monkeypatch.setattr(F.runtime, "kernel_work_group_size", lambda knl, dev: min(
        real(knl, dev), most) if knl.function_name == "fft_lines" else real(knl, dev))


def _group_sizes(passes):
    return [math.prod(lg.lsize) for p in passes for lg in p.launches if p.kind == "gpu"]


@pytest.mark.parametrize("n", [1944, 2560])
def test_a_kernel_that_allows_fewer_work_items_is_planned_again(queue, rng, monkeypatch, n):
    """The plan asks each built kernel for CL_KERNEL_WORK_GROUP_SIZE and plans again within
    it: two local buffers at 1944 points, in place at 2560 (512 radix-5 butterflies a stage,
    four per work-item at 128); FFTPlan and RoundTripPlan alike, results unchanged."""
    _fewer_work_items(monkeypatch, 128)
    t = tol("fft", np.float32)["rel_l2"]
    for shape in ((2, 3, n), (n, 5)):
        plan = F.FFTPlan(shape, np.complex64, queue=queue, variant="gpu")
        sizes = _group_sizes(plan.geometry.passes)
        assert sizes and max(sizes) <= 128, plan.geometry.passes
        assert max(math.prod(lg.lsize) for p in plan.geometry.passes for lg in p.launches
                   if p.n == n) == 128
        x = random_complex(rng, shape)
        assert rel_l2(plan.execute_host(x), np.fft.fft2(x.astype(np.complex128))) <= t
    for axis, shape in (("rows", (2, 3, n - 7)), ("cols", (1, n - 7, 5))):
        plan = F.RoundTripPlan(shape, n, axis=axis, first="forward", mid_n=n - 20,
                               queue=queue, variant="gpu")
        assert _group_sizes([plan.geometry.pass_]) == [128]
        assert bool(dict(plan.geometry.pass_.defines).get("FFT_INPLACE")) == (n == 2560)
        x = random_complex(rng, shape)
        m = random_complex(rng, (3, n) if axis == "rows" else (n, 5))
        got = plan.execute(cla.to_device(queue, x), multiply=cla.to_device(queue, m)).get()
        want = ref.round_trip(x, n, axis=axis, first="forward", multiply=m, mid_n=n - 20)
        assert rel_l2(got, want) <= t


@pytest.mark.parametrize("direct", [False, True])
@pytest.mark.parametrize("wg", [1024, 8])
def test_small_local_memory_takes_the_in_place_path(queue, rng, monkeypatch, wg, direct):
    """1000 bytes of local memory: lines of 64..125 complex64 fit once, not twice; few
    work-items give each several butterflies per stage. ``direct``: the in-place plan's first
    stage reads the source and its last writes the destination (FFT_INPLACE_DIRECT)."""
    _small_local(monkeypatch, 1000, wg)
    monkeypatch.setattr(SETTINGS["inplace_direct"], "default", direct)
    t = tol("fft", np.float32)["rel_l2"]
    for n in (64, 96, 120, 125):
        for shape in ((3, 6, n), (n, 9)):
            plan = F.FFTPlan(shape, np.complex64, queue=queue, variant="gpu")
            p = [p for p in plan.geometry.passes if p.n == n][0]
            assert dict(p.defines).get("FFT_INPLACE") and len(p.launches) == 1, p
            assert bool(dict(p.defines).get("FFT_INPLACE_DIRECT")) == direct
            x = random_complex(rng, shape)
            assert rel_l2(plan.execute_host(x), np.fft.fft2(x.astype(np.complex128))) <= t
        for axis in ("rows", "cols"):
            shape = (2, 5, n - 3) if axis == "rows" else (2, n - 3, 6)
            plan = F.RoundTripPlan(shape, n, axis=axis, first="inverse", mid_n=n - 9,
                                   queue=queue, variant="gpu")
            defines = dict(plan.geometry.pass_.defines)
            assert defines.get("FFT_INPLACE")
            assert bool(defines.get("FFT_INPLACE_DIRECT")) == direct
            x = random_complex(rng, shape)
            want = ref.round_trip(x, n, axis=axis, first="inverse", mid_n=n - 9)
            assert rel_l2(plan.execute(cla.to_device(queue, x)).get(), want) <= t
    # 128 points need 1024 bytes once: the split plan (512 bytes of floats); 256 points
    # (1024 bytes of floats): global stages, as before
    plan = F.FFTPlan((2, 128), np.complex64, queue=queue, variant="gpu", axes=(-1,))
    assert dict(plan.geometry.passes[0].defines).get("FFT_SPLIT")
    plan = F.FFTPlan((2, 256), np.complex64, queue=queue, variant="gpu", axes=(-1,))
    assert plan.geometry.passes[0].kind == "global"
    x = random_complex(rng, (2, 256))
    assert rel_l2(plan.execute_host(x), np.fft.fft(x.astype(np.complex128), axis=-1)) <= t


def test_h100_columns_on_the_in_place_plan(monkeypatch):
    """The tunable setting ``inplace_columns`` (off until a GPU measures it): on an H100's limits columns that two
    buffers hold fewer than four of (complex64: less than a 32-byte sector of each row) take the
    in-place plan where it holds more: 1125 points five to a group (two buffers: two), 2048
    points two (one; three would need the 16 bytes ``fft_lines`` holds itself). Rows, and columns that two buffers hold four or more of, keep their
    plan."""
    def passes(shape, **kw):
        g = F.plan_geometry(shape, np.complex64, device=H100, variant="gpu", **kw)
        return {p.axis: p for p in g.passes}

    def lines(p):
        return p.launches[0].extra[0]

    before = {n: passes((n, 1944)) for n in (1125, 2048, 256)}
    assert [lines(before[n]["cols"]) for n in (1125, 2048, 256)] == [2, 1, 8]
    monkeypatch.setattr(SETTINGS["inplace_columns"], "default", True)
    for n, want in ((1125, 5), (2048, 2)):
        p = passes((n, 1944))
        assert dict(p["cols"].defines).get("FFT_INPLACE") and lines(p["cols"]) == want, p
        _check_launches(p["cols"], H100)
        assert p["rows"] == before[n]["rows"]
        g = F.round_trip_geometry((3, n - 20, 1944), n, device=H100, axis="cols")
        assert dict(g.pass_.defines).get("FFT_INPLACE") and lines(g.pass_) == want
    assert passes((256, 1944)) == before[256]


@pytest.mark.parametrize("direct", [False, True])
def test_columns_on_the_in_place_plan_match_numpy(queue, rng, monkeypatch, direct):
    """The same plans on PoCL (a device of 48 KiB and 1024 work-items whose kernels hold no
    local memory themselves: 2048 points three to a group), with and without the
    first and last stages on global memory: several columns per group and a last group only
    partly full, an FFT pass and a column round trip, against NumPy and the reference."""
    _small_local(monkeypatch, 48 * 1024, 1024)
    monkeypatch.setattr(SETTINGS["inplace_columns"], "default", True)
    monkeypatch.setattr(SETTINGS["inplace_direct"], "default", direct)
    t = tol("fft", np.float32)["rel_l2"]
    for n, per_group in ((1125, 5), (2048, 3)):
        shape = (n, 12)  # 12 columns: the last group holds 2 (1125) or 3 (2048)
        plan = F.FFTPlan(shape, np.complex64, queue=queue, variant="gpu", axes=(-2, -1))
        (cols,) = [p for p in plan.geometry.passes if p.axis == "cols"]
        assert dict(cols.defines).get("FFT_INPLACE") and cols.launches[0].extra[0] == per_group
        assert bool(dict(cols.defines).get("FFT_INPLACE_DIRECT")) == direct
        x = random_complex(rng, shape)
        assert rel_l2(plan.execute_host(x), np.fft.fft2(x.astype(np.complex128))) <= t
        assert rel_l2(plan.execute_host(x, inverse=True),
                      np.fft.ifft2(x.astype(np.complex128))) <= t
        rt = F.RoundTripPlan((2, n - 25, 12), n, axis="cols", first="forward", mid_n=n - 40,
                             queue=queue, variant="gpu")
        assert rt.geometry.pass_.launches[0].extra[0] == per_group
        x = random_complex(rng, (2, n - 25, 12))
        m = random_complex(rng, (n, 12))
        got = rt.execute(cla.to_device(queue, x), multiply=cla.to_device(queue, m)).get()
        want = ref.round_trip(x, n, axis="cols", first="forward", multiply=m, mid_n=n - 40)
        assert rel_l2(got, want) <= t


_OCLGRIND_SNIPPET = fft_snippet("""
    for direct in (False, True):  # the in-place plan, then with FFT_INPLACE_DIRECT
        SETTINGS["inplace_direct"].default = direct
        for shape in ((3, 120), (120, 5)):
            plan = F.FFTPlan(shape, np.complex64, queue=q, variant="gpu")
            assert any(dict(p.defines).get("FFT_INPLACE") for p in plan.geometry.passes)
            x = rnd(shape)
            errs.append(rel(plan.execute_host(x), np.fft.fft2(x.astype(np.complex128))))
        for axis, shape in (("rows", (2, 3, 117)), ("cols", (1, 117, 3))):
            plan = F.RoundTripPlan(shape, 120, axis=axis, mid_n=100, queue=q, variant="gpu")
            defines = dict(plan.geometry.pass_.defines)
            assert defines.get("FFT_INPLACE")
            assert bool(defines.get("FFT_INPLACE_DIRECT")) == direct
            x = rnd(shape)
            m = rnd((3, 120) if axis == "rows" else (120, 3))
            got = plan.execute(cla.to_device(q, x), multiply=cla.to_device(q, m)).get()
            errs.append(rel(got, ref.round_trip(x, 120, axis=axis, multiply=m, mid_n=100)))
        # columns in one buffer, two to a group (inplace_columns: two buffers hold one)
        SETTINGS["inplace_columns"].default = True
        check_columns(60, 5, 57, "FFT_INPLACE", 2)
        SETTINGS["inplace_columns"].default = False
    # the two-buffer plan fixed at build (DIRECT_STAGE: the first stage reads the source, the
    # last writes the destination; 60 points: fused stages of radix 10 and 6), with the
    # device's own limits
    F.DeviceLimits.of = classmethod(lambda cls, dev: real_of(dev))
    F._FUSED_RADIX_MAX = 16  # (the default there is 8: fused stages run in the in-place plan)
    assert F._fused_radices(60, F._FUSED_RADIX_MAX) == ((5, 2), (3, 2))
    for shape in ((3, 60), (60, 5)):
        plan = F.FFTPlan(shape, np.complex64, queue=q, variant="gpu")
        assert all(p.kind == "gpu" and "FFT_STAGE_LIST" in dict(p.defines)
                   and not dict(p.defines).get("FFT_INPLACE") for p in plan.geometry.passes)
        x = rnd(shape)
        errs.append(rel(plan.execute_host(x), np.fft.fft2(x.astype(np.complex128))))
    for axis, shape in (("rows", (2, 3, 57)), ("cols", (1, 57, 3))):
        plan = F.RoundTripPlan(shape, 60, axis=axis, mid_n=50, queue=q, variant="gpu")
        assert not dict(plan.geometry.pass_.defines).get("FFT_INPLACE")
        x = rnd(shape)
        m = rnd((3, 60) if axis == "rows" else (60, 3))
        got = plan.execute(cla.to_device(q, x), multiply=cla.to_device(q, m)).get()
        errs.append(rel(got, ref.round_trip(x, 60, axis=axis, multiply=m, mid_n=50)))
""", local=1000, wg=16, seed=5)


def test_local_memory_lines_under_oclgrind():
    """the in-place plan (also with its first and last stages on global memory, and with
    columns two to a group) and the two-buffer plan fixed at build, plain and round trip, on
    the simulator with data races on: no reports, results right"""
    run_snippet_under_oclgrind(_OCLGRIND_SNIPPET)


@pytest.mark.parametrize("H, Hp, W, Wp", [(2160, 2187, 3840, 3888), (2048, 2250, 2048, 2250)])
def test_h100_two_pass_layer_covers_the_4k_and_sgd_grids(H, Hp, W, Wp):
    """What host/scheduler.py asks before it runs a layer as two kernels (column round trip of
    length Hp over the H x Wp field, row round trip of length Wp): both fit on an H100."""
    assert F.round_trip_fits((1, H, Wp), Hp, device=H100, axis="cols", variant="gpu")
    assert F.round_trip_fits((1, H, Wp), Wp, device=H100, axis="rows", variant="gpu")


@pytest.mark.parametrize("n", [1125, 1200])
def test_columns_of_1025_to_1536_points_go_two_to_a_group(queue, rng, n):
    """Columns of 1125 and 1200 points: 32 KiB holds one as two buffers, 48 KiB two (adjacent
    columns fill more of each sector read; 1.12x on an H200), in an FFT pass and a round trip;
    rows keep 32 KiB. Results against NumPy and the reference."""
    t = tol("fft", np.float32)["rel_l2"]
    shape = (n, 12)
    plan = F.FFTPlan(shape, np.complex64, queue=queue, variant="gpu", axes=(-2, -1))
    (cols,) = [p for p in plan.geometry.passes if p.axis == "cols"]
    assert cols.kind == "gpu" and cols.launches[0].extra[0] == 2
    assert cols.launches[0].local_bytes == 2 * 2 * n * 8 > 32 * 1024
    x = random_complex(rng, shape)
    assert rel_l2(plan.execute_host(x), np.fft.fft2(x.astype(np.complex128))) <= t
    rows = F.plan_geometry((4, n), np.complex64, device=H100, axes=(-1,), variant="gpu")
    assert rows.passes[0].launches[0].local_bytes == 2 * n * 8
    rt = F.RoundTripPlan((2, n - 5, 6), n, axis="cols", first="forward", queue=queue,
                         variant="gpu")
    assert rt.geometry.pass_.launches[0].extra[0] == 2
    x = random_complex(rng, (2, n - 5, 6))
    m = random_complex(rng, (n, 6))
    got = rt.execute(cla.to_device(queue, x), multiply=cla.to_device(queue, m)).get()
    assert rel_l2(got, ref.round_trip(x, n, axis="cols", first="forward", multiply=m)) <= t
