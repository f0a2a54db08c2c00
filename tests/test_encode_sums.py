"""SGD's loss sums (``field_sums`` then ``fit_scale``, kernels/encode.cl) split by the device:
the sizing rule as a pure function on the limits of devices we do not have (a 2-core CPU, an
H100), and the kernels with each device's split against ``clholo.reference.sgd_fit`` on PoCL,
the same bits run to run and whatever else shares the batch (issue 23)."""

import types

import numpy as np
import pyopencl as cl
import pyopencl.array as cla
import pytest

from clholo import reference as ref
from clholo.host import phase_retrieval as pr
from clholo.host import runtime
from clholo.host.phase_retrieval import SumPlan, launch_sums, sum_plan
from clholo.propagation import device_padded_shape

from conftest import random_complex
from tolerances import rel_l2, tol

# CL_DEVICE_* of devices the tests do not have: PoCL on a 2-core CPU, and the H100 of
# ../shared/gpu/H100.md (132 compute units, 1024 work-items a group, 48 KiB local memory)
CPU2 = dict(gpu=False, compute_units=2, max_work_group=4096, max_items=4096,
            local_mem_bytes=2 << 20)
H100 = dict(gpu=True, compute_units=132, max_work_group=1024, max_items=1024,
            local_mem_bytes=48 << 10)


def test_a_2_core_cpu_keeps_the_measured_split():
    assert sum_plan(2048 * 2048, **CPU2) == SumPlan(64, 64)
    assert sum_plan(1024 * 1024, **CPU2) == SumPlan(64, 64)
    assert sum_plan(64 * 32 * 5, **CPU2) == SumPlan(64, 5)  # >= 32 pixels per work-item
    assert sum_plan(1000, **CPU2) == SumPlan(64, 1)
    assert sum_plan(1, **CPU2) == SumPlan(64, 1)
    # more cores change nothing on a CPU (measured on PoCL)
    assert sum_plan(2048 * 2048, **dict(CPU2, compute_units=64)) == SumPlan(64, 64)


def test_an_h100_gets_256_work_items_and_8_groups_per_compute_unit():
    assert sum_plan(2048 * 2048, **H100) == SumPlan(256, 8 * 132)  # was 64 x 64
    assert sum_plan(2250 * 2250, **H100) == SumPlan(256, 1056)
    assert sum_plan(1024 * 1024, **H100) == SumPlan(256, 1024)  # 4 pixels per work-item
    assert sum_plan(300_001, **H100) == SumPlan(256, 293)  # >= 4 pixels per work-item
    assert sum_plan(1000, **H100) == SumPlan(256, 1)
    assert sum_plan(1, **H100) == SumPlan(256, 1)
    assert sum_plan(2048 * 2048, **dict(H100, compute_units=20)) == SumPlan(256, 160)


@pytest.mark.parametrize("limit, local", [
    (dict(max_work_group=128), 128),        # a small work-group limit
    (dict(max_items=96), 64),               # not a power of two: the one below
    (dict(max_items=8), 8),
    (dict(local_mem_bytes=1024), 64),       # 16 bytes of scratch per work-item
    (dict(local_mem_bytes=16), 1),
])
def test_a_gpu_s_limits_bound_the_work_group(limit, local):
    plan = sum_plan(2048 * 2048, **dict(H100, **limit))
    assert plan.local == local
    assert plan.groups == min(1056, -(-2048 * 2048 // (local * 4)))


@pytest.mark.parametrize("n", [1, 3, 64, 65, 1000, 4097, 300_001, 2048 * 2048, 2 ** 31])
@pytest.mark.parametrize("device", [CPU2, H100], ids=["cpu2", "h100"])
def test_every_group_has_pixels_and_every_pixel_a_group(n, device):
    plan = sum_plan(n, **device)
    assert plan.groups >= 1 and plan.local >= 1 and plan.local & (plan.local - 1) == 0
    # field_sums reads quads: every group but a lone one has some
    assert (plan.groups - 1) * plan.local < n // 4 or plan.groups == 1


def _fake_device(kind, cu, wg, items, local_mem):
    return types.SimpleNamespace(
        int_ptr=-(10_000 + cu), name=f"fake {kind}", type=getattr(cl.device_type, kind),
        max_compute_units=cu, max_work_item_dimensions=3, max_work_item_sizes=[items, items, 64],
        max_work_group_size=wg, local_mem_size=local_mem)


def test_the_device_s_plan_reads_its_kind_and_limits():
    gpu = _fake_device("GPU", 132, 1024, 1024, 48 << 10)
    cpu = _fake_device("CPU", 2, 4096, 4096, 2 << 20)
    try:
        assert pr.device_sum_plan(gpu, 2048 * 2048) == SumPlan(256, 1056)
        assert pr.device_sum_plan(cpu, 2048 * 2048) == SumPlan(64, 64)
        assert pr.device_sums_local(types.SimpleNamespace(devices=[gpu])) == 256
        assert pr.device_sums_local(types.SimpleNamespace(devices=[gpu, cpu])) == 64
    finally:
        for dev in (gpu, cpu):
            runtime._device_limits.pop(dev.int_ptr, None)


# --- the kernels on PoCL, with each device's split ------------------------------------------

def _plans(queue, n):
    """The device's own split, the H100's and a ragged one (within this device's limits)."""
    dev = runtime._limits_of_device(queue.device)
    cap = min(dev.max_work_group_size, dev.max_item_sizes[0])
    h100 = sum_plan(n, **dict(H100, max_work_group=min(cap, 1024), max_items=min(cap, 1024)))
    return [pr.device_sum_plan(queue.device, n), h100, SumPlan(32, 7)]


def _fit(queue, plan, y, t, w, lanes=None):
    B, n = y.shape
    partial = cla.empty(queue, (B, plan.groups, 4), np.float32)
    scale = cla.empty(queue, (B,), np.complex64)
    weight = cla.empty(queue, (B,), np.float32)
    loss = cla.empty(queue, (B,), np.float32)
    launch_sums(queue, plan, cla.to_device(queue, y).data, cla.to_device(queue, t).data,
                None if w is None else cla.to_device(queue, w).data, n, B, partial.data,
                scale.data, weight.data, loss.data, lanes=lanes)
    return partial.get(), scale.get(), weight.get(), loss.get()


@pytest.mark.parametrize("with_mask", [False, True])
@pytest.mark.parametrize("n", [1, 65, 1000, 4097, 300_001])
def test_sums_and_fit_match_the_reference_with_every_split(queue, rng, n, with_mask):
    B = 3
    y = random_complex(rng, (B, n))
    t = (0.5 * y + random_complex(rng, (B, n))).astype(np.complex64)  # loss well inside (0, 1)
    w = rng.uniform(0.2, 1, n).astype(np.float32) if with_mask else None
    want_s, want_w, want_loss = ref.sgd_fit(y[:, None], t[:, None],
                                            mask=None if w is None else w[None])
    yc, tc = y.astype(np.complex128), t.astype(np.complex128)
    ww = 1.0 if w is None else w.astype(np.float64)
    c = np.sum(ww * np.conj(yc) * tc, axis=1)
    want_sums = np.stack([c.real, c.imag, np.sum(ww * np.abs(yc) ** 2, 1),
                          np.sum(ww * np.abs(tc) ** 2, 1)], 1)
    bound = tol("encode_gradient", np.float32)["rel_l2"]  # per-field float32 sums
    for plan in _plans(queue, n):
        partial, s, weight, loss = _fit(queue, plan, y, t, w)
        assert rel_l2(partial.astype(np.float64).sum(1), want_sums) <= bound, plan
        assert rel_l2(s, want_s) <= bound, plan
        assert rel_l2(weight, want_w) <= bound, plan
        # the loss is in [0, 1] (0 for one pixel): its absolute error counts
        assert np.max(np.abs(loss - want_loss)) <= tol("encode_gradient", np.float32)["max_abs"]


def test_the_sums_are_the_same_bits_run_to_run_and_alone_or_in_a_batch(queue, rng):
    n, B = 300_001, 3
    y = random_complex(rng, (B, n))
    t = random_complex(rng, (B, n))
    w = rng.uniform(0.2, 1, n).astype(np.float32)
    for plan in _plans(queue, n):
        first = _fit(queue, plan, y, t, w)
        again = _fit(queue, plan, y, t, w)
        alone = _fit(queue, plan, y[1:2], t[1:2], w)
        for a, b, c in zip(first, again, alone):
            np.testing.assert_array_equal(a, b)
            np.testing.assert_array_equal(a[1:2], c)


def test_phase_retrieval_takes_the_device_s_plan_and_a_gpu_s_on_pocl(queue, rng, monkeypatch):
    """A step with the device's own split, and with the split a GPU of this device's compute
    units would get (the kernels built for 256 work-items), both against the reference."""
    B, H, W, z, P, wl = 2, 40, 52, 2e-3, 8e-6, (638e-9, 450e-9)
    padded = device_padded_shape((H, W), z, wavelength=wl, pitch=P)
    A, AH = ref.asm_operator((H, W), z, wavelengths=wl, pitch=P, padded=padded)
    target = random_complex(rng, (B, H, W))
    phase = rng.uniform(0, 2 * np.pi, (B, H, W)).astype(np.float32)
    loss, grad, s = ref.sgd_loss_and_gradient(phase, target, A, AH)
    bound = tol("encode_gradient", np.float32)["rel_l2"]
    plans = []
    for gpu in (False, True):
        if gpu:
            real = pr._device_limits
            monkeypatch.setattr(pr, "_device_limits",
                                lambda d: dict(real(d), gpu=True, max_work_group=256))
        eng = pr.PhaseRetrieval(cla.to_device(queue, target), wavelengths=wl, pitch=P, z=z,
                                padded=padded, queue=queue)
        assert eng.sums == pr.device_sum_plan(queue.device, H * W)
        plans.append(eng.sums)
        eng.set_phase(cla.to_device(queue, phase))
        eng.step()
        assert rel_l2(eng.loss.get(), loss) <= bound
        assert rel_l2(eng.scale.get(), s) <= bound
        assert rel_l2(eng.grad.get(), grad) <= bound
    if queue.device.type & cl.device_type.CPU:
        assert plans[0].local == pr.SUM_LOCAL
    assert plans[1].local == 256


@pytest.mark.parametrize("local, groups", [(0, 4), (48, 4), (64, 0)])
def test_a_bad_split_is_refused_in_one_line(local, groups):
    with pytest.raises(ValueError, match=r"power of two .*SumPlan\(64, 64\)"):
        SumPlan(local, groups)


@pytest.mark.parametrize("with_mask", [False, True])
@pytest.mark.parametrize("n", [1, 7, 65, 1000, 4097, 16_387, 300_001])
def test_cpu_lanes_form_gives_field_sums_bits(queue, rng, n, with_mask):
    """field_sums_lanes (a group's work-items side by side in one work-item: CPUs' form) adds
    the same terms in the same order as field_sums: the same bits, for every split (the
    device's, an H100's, a ragged one), ragged quads and a last pass of a few work-items."""
    B = 2
    y, t = random_complex(rng, (B, n)), random_complex(rng, (B, n))
    w = rng.uniform(0.2, 1, n).astype(np.float32) if with_mask else None
    for plan in _plans(queue, n) + [SumPlan(64, 3), SumPlan(16, 1)]:
        groups = _fit(queue, plan, y, t, w, lanes=False)
        lanes = _fit(queue, plan, y, t, w, lanes=True)
        assert np.abs(groups[0]).sum() > 0, (plan, n)
        for a, b in zip(groups, lanes):
            np.testing.assert_array_equal(b.view(np.uint32), a.view(np.uint32),
                                          err_msg=f"{plan} n={n}")


def test_engine_adds_its_sums_with_the_device_s_form(queue):
    from clholo.host.phase_retrieval import PhaseRetrieval, sums_lanes

    eng = PhaseRetrieval(cla.zeros(queue, (1, 8, 12), np.complex64), wavelengths=[520e-9],
                         pitch=8e-6, z=1e-3, padded=(16, 20), queue=queue, fuse="none")
    name = eng._own["field_sums"][0].function_name
    assert name == ("field_sums_lanes" if sums_lanes(queue.device) else "field_sums")


def test_cpu_lanes_form_needs_four_work_items_a_group(queue, rng):
    y = random_complex(rng, (1, 40))
    with pytest.raises(ValueError, match="plan.local is 2: use lanes=False"):
        _fit(queue, SumPlan(2, 1), y, y, None, lanes=True)
