"""SGD phase retrieval and DPAC kernels (kernels/encode.cl) against clholo.reference.encode,
the gradient against finite differences, and SGD on the real twain MPI."""

import numpy as np
import pyopencl.array as cla
import pytest

import clholo
from clholo import reference as ref
from clholo.host.tuning import SETTINGS
from clholo.encode import dpac_encode, phase_to_hologram, sgd_encode
from clholo.host.phase_retrieval import (PhaseRetrieval, encode_kernel, field_max_abs,
                                         _fallback_fuse, default_fuse, quads)
from clholo.propagation import device_padded_shape
from clholo.scene import Optics

from conftest import random_complex
from tolerances import rel_l2, tol

P = 8e-6
WL = (638e-9, 450e-9)


def _operators(shape, z, padded, wavelengths=WL):
    return ref.asm_operator(shape, z, wavelengths=wavelengths, pitch=P, padded=padded)


@pytest.mark.parametrize("with_mask", [False, True])
def test_reference_gradient_matches_finite_differences(rng, with_mask):
    B, H, W, z = 2, 12, 20, 1e-3
    padded = ref.padded_shape((H, W), z, wavelength=max(WL), pitch=P, pad=2)
    A, AH = _operators((H, W), z, padded)
    phase = rng.uniform(0, 2 * np.pi, (B, H, W))
    target = random_complex(rng, (B, H, W), np.complex128)
    mask = (rng.uniform(size=(H, W)) > 0.3).astype(float) if with_mask else None
    loss, grad, _ = ref.sgd_loss_and_gradient(phase, target, A, AH, mask=mask)
    np.testing.assert_allclose(loss, ref.sgd_loss(phase, target, A, mask=mask), rtol=1e-12)
    h = 1e-6
    for _ in range(8):
        b, y, x = rng.integers(B), rng.integers(H), rng.integers(W)
        up, down = phase.copy(), phase.copy()
        up[b, y, x] += h
        down[b, y, x] -= h
        fd = (ref.sgd_loss(up, target, A, mask=mask)[b]
              - ref.sgd_loss(down, target, A, mask=mask)[b]) / (2 * h)
        assert abs(fd - grad[b, y, x]) <= 1e-7 + 1e-5 * abs(fd), (b, y, x, fd, grad[b, y, x])
    # the other field's loss does not depend on this pixel: fields are independent
    assert np.all(np.isfinite(grad)) and np.std(grad) > 0


def test_reference_adjoint_is_asm_minus_z(rng):
    # <A u, v> = <u, A^H v> for the padded, cropped, band-limited ASM
    H, W, z = 16, 24, 3e-3
    padded = (32, 64)
    A, AH = _operators((H, W), z, padded)
    u = random_complex(rng, (2, H, W), np.complex128)
    v = random_complex(rng, (2, H, W), np.complex128)
    lhs = np.sum(np.conj(A(u)) * v, axis=(-2, -1))
    rhs = np.sum(np.conj(u) * AH(v), axis=(-2, -1))
    np.testing.assert_allclose(lhs, rhs, rtol=1e-10)


def _engine(queue, rng, B, H, W, z, *, mask=None, lr=0.05, wavelengths=WL, fuse=None,
            three_pass=None, variant="auto", target=None):
    padded = device_padded_shape((H, W), z, wavelength=wavelengths, pitch=P)
    target = random_complex(rng, (B, H, W)) if target is None else target
    dmask = None if mask is None else cla.to_device(queue, mask.astype(np.float32))
    eng = PhaseRetrieval(cla.to_device(queue, target), wavelengths=wavelengths, pitch=P, z=z,
                         padded=padded, mask=dmask, lr=lr, queue=queue, fuse=fuse,
                         three_pass=three_pass, variant=variant)
    if fuse is None:  # the device's default, or where round trips do not fit its fallback
        assert eng.fuse == (default_fuse(queue.device) if eng.propagator.three_pass
                            else _fallback_fuse(queue.device, variant))
    else:
        assert eng.fuse == fuse
    phase = rng.uniform(0, 2 * np.pi, (B, H, W)).astype(np.float32)
    eng.set_phase(cla.to_device(queue, phase))
    A, AH = _operators((H, W), z, padded, wavelengths)
    return eng, target, phase, A, AH


# fuse: the residual, or the residual and the Adam step, as callbacks of the adjoint
# propagation's first and last passes (kernels/sgd_callbacks.h), in its three-pass and
# four-pass forms; the whole iteration in two column and two row round trips
FORMS = [pytest.param("none", None, id="kernels"),
         pytest.param("residual", None, id="residual-fused"),
         pytest.param("all", None, id="all-fused"),
         pytest.param("all", False, id="all-fused-four-pass"),
         pytest.param("round-trips", None, id="round-trips")]


def _row_spectrum(phase, padded_width):
    """FFT_rows(pad(exp(i P))) ``[B, H, Wp]``: what fuse="round-trips" keeps instead of x."""
    x = np.exp(1j * phase.astype(np.float64))
    pad = np.zeros(x.shape[:-1] + (padded_width,), np.complex128)
    pad[..., :x.shape[-1]] = x
    return np.fft.fft(pad, axis=-1)


@pytest.mark.parametrize("fuse,three_pass", FORMS)
@pytest.mark.parametrize("B,H,W,z,with_mask", [(2, 16, 16, 1e-3, False), (4, 40, 24, 4e-3, True),
                                               (6, 64, 96, 2e-3, False), (2, 7, 33, -2e-3, True)])
def test_device_gradient_matches_reference(queue, rng, B, H, W, z, with_mask, fuse,
                                           three_pass):
    mask = (rng.uniform(size=(H, W)) > 0.25).astype(np.float32) if with_mask else None
    eng, target, phase, A, AH = _engine(queue, rng, B, H, W, z, mask=mask, fuse=fuse,
                                        three_pass=three_pass)
    eng.step()
    loss, grad, s = ref.sgd_loss_and_gradient(phase, target, A, AH, mask=mask)
    t = tol("encode_gradient", np.float32)
    assert rel_l2(eng.grad.get(), grad) <= t["rel_l2"]
    np.testing.assert_allclose(eng.loss.get(), loss, rtol=t["rel_l2"], atol=t["max_abs"])
    assert rel_l2(eng.scale.get(), s) <= t["rel_l2"]


@pytest.mark.parametrize("fuse,three_pass", FORMS)
@pytest.mark.parametrize("B,H,W", [(3, 24, 32), (1, 13, 27)])  # 1 x 13 x 27: a ragged end of 3
def test_adam_matches_reference_step_by_step(queue, rng, B, H, W, fuse, three_pass):
    z, lr = 2e-3, 0.03
    eng, target, phase, A, AH = _engine(queue, rng, B, H, W, z, lr=lr,
                                        wavelengths=(638e-9, 520e-9, 450e-9), fuse=fuse,
                                        three_pass=three_pass)
    t = tol("encode_adam", np.float32)
    m = np.zeros((B, H, W))
    v = np.zeros((B, H, W))
    # the first whole iteration (forward, gradient, Adam) against the reference; Adam's first
    # step is lr * sign(g), so compare where the gradient is well above float32 rounding
    _, _, _, _, g_ref, _ = ref.sgd_iteration(phase, m, v, 1, target, A, AH, lr=lr)
    p_ref, _, _ = ref.adam_step(phase, g_ref, m, v, 1, lr=lr)
    eng.step()
    strong = np.abs(g_ref) > 1e-2 * np.sqrt(np.mean(g_ref ** 2))
    assert strong.mean() > 0.9
    np.testing.assert_allclose(eng.phase.get()[strong], p_ref[strong], atol=t["max_abs"])
    # then step by step: the Adam kernel from the device's own state and gradient
    for k in range(2, 7):
        p0, m0, v0 = eng.phase.get(), eng.adam_m.get(), eng.adam_v.get()
        eng.step()
        g = eng.grad.get().astype(np.float64)
        assert rel_l2(g, ref.sgd_loss_and_gradient(p0, target, A, AH)[1]) <= \
            tol("encode_gradient", np.float32)["rel_l2"]
        p_want, m_want, v_want = ref.adam_step(p0.astype(np.float64), g, m0, v0, k, lr=lr)
        assert eng.step_count == k
        np.testing.assert_allclose(eng.phase.get(), p_want, atol=t["max_abs"], rtol=0)
        assert rel_l2(eng.adam_m.get(), m_want) <= t["rel_l2"]
        assert rel_l2(eng.adam_v.get(), v_want) <= t["rel_l2"]
        if fuse == "round-trips":  # keeps the row spectrum of x instead of x
            assert eng.x is None
            want = _row_spectrum(eng.phase.get(), eng.propagator.padded[1])
            got = eng.spectrum.get()[..., :eng.propagator.padded[1]]
            assert rel_l2(got, want) <= tol("fft", np.float32)["rel_l2"]
        else:
            np.testing.assert_allclose(eng.x.get(), np.exp(1j * eng.phase.get().astype(float)),
                                       atol=t["max_abs"])


@pytest.mark.parametrize("fuse,three_pass", [("residual", None), ("all", None), ("all", False)])
@pytest.mark.parametrize("B,H,W,with_mask", [(2, 40, 56, True), (3, 21, 34, False)])
def test_fused_iterations_match_the_kernels(queue, rng, B, H, W, with_mask, fuse, three_pass):
    # the callbacks do the kernels' arithmetic: five iterations of both forms, from the same
    # start, give the same phases, moments, gradients, fields and losses
    z = 3e-3
    mask = (rng.uniform(size=(H, W)) > 0.3).astype(np.float32) if with_mask else None
    seed = int(rng.integers(2 ** 32))
    runs = []
    for form in ("none", fuse):
        eng, *_ = _engine(queue, np.random.default_rng(seed), B, H, W, z, mask=mask,
                          fuse=form, three_pass=three_pass)
        for _ in range(5):
            eng.step()
        runs.append([a.get() for a in (eng.phase, eng.adam_m, eng.adam_v, eng.grad, eng.x,
                                       eng.loss)])
    t = tol("encode_adam", np.float32)
    for name, a, b in zip(("phase", "m", "v", "grad", "x", "loss"), *runs):
        assert np.std(a) > 0, name
        assert rel_l2(b, a) <= t["rel_l2"], name


@pytest.mark.parametrize("three_pass", [None, False])
def test_fused_iteration_on_the_gpu_kernels(queue, rng, three_pass):
    # GPUs fuse the residual and the Adam step by default: their FFT kernels (fft_gpu.cl, one
    # element per callback) run the callbacks here on the CPU device, against the kernels'
    # iteration on the CPU strips
    from clholo.host.phase_retrieval import SGD_ADAM_STORE, SGD_RESIDUAL_LOAD
    from clholo.propagation import ASMPropagator

    B, H, W, z = 2, 24, 40, 2e-3
    mask = (rng.uniform(size=(H, W)) > 0.3).astype(np.float32)
    seed = int(rng.integers(2 ** 32))
    runs = []
    for fuse in ("none", "all"):
        eng, *_ = _engine(queue, np.random.default_rng(seed), B, H, W, z, mask=mask, fuse=fuse,
                          three_pass=three_pass)
        if fuse == "all":
            eng.propagator = ASMPropagator(B, (H, W), eng.propagator.padded, queue=queue,
                                           load_callback=SGD_RESIDUAL_LOAD,
                                           store_callback=SGD_ADAM_STORE,
                                           three_pass=three_pass, variant="gpu")
        for _ in range(3):
            eng.step()
        runs.append([a.get() for a in (eng.phase, eng.adam_v, eng.grad, eng.x, eng.loss)])
    # two FFT implementations round differently, so everything from the first gradient on
    # carries a float32 gradient's error, and Adam's first steps, about the gradient's sign,
    # magnify it where the gradient is near zero: a gradient's tolerance (grad and x 1.4e-6 on
    # PoCL 3.1 / LLVM 15, whose multiply-adds differ from PoCL 3.0's; a dropped or misplaced
    # term is O(1)). test_fused_iterations_match_the_kernels holds one FFT to Adam's 1e-6.
    t = tol("encode_gradient", np.float32)
    for name, a, b in zip(("phase", "v", "grad", "x", "loss"), *runs):
        assert np.std(a) > 0, name
        assert rel_l2(b, a) <= t["rel_l2"], name


def _first_two_steps_match_the_reference(eng, phase, target, A, AH, mask):
    """The first step's gradient and loss against the reference, then the second Adam step
    from the device's own state and gradient (lr 0.05)."""
    eng.step()
    loss, grad, s = ref.sgd_loss_and_gradient(phase, target, A, AH, mask=mask)
    t = tol("encode_gradient", np.float32)
    assert rel_l2(eng.grad.get(), grad) <= t["rel_l2"]
    np.testing.assert_allclose(eng.loss.get(), loss, rtol=t["rel_l2"], atol=t["max_abs"])
    p0, m0, v0 = eng.phase.get(), eng.adam_m.get(), eng.adam_v.get()
    eng.step()
    p_want, _, _ = ref.adam_step(p0.astype(np.float64), eng.grad.get().astype(np.float64),
                                 m0, v0, 2, lr=0.05)
    np.testing.assert_allclose(eng.phase.get(), p_want, atol=tol("encode_adam",
                                                                  np.float32)["max_abs"])


def test_fused_iteration_on_in_place_gpu_lines(queue, rng, monkeypatch):
    # SGD's 2250^2 grid takes the GPU kernels' in-place path on an H100 (lines longer than two
    # local buffers): here a device with 1000 bytes of local memory sends rows of 96 points
    # there, and the residual and Adam callbacks must still run where the lines load and store
    import dataclasses

    from clholo import fft as F
    from clholo.host.phase_retrieval import SGD_ADAM_STORE, SGD_RESIDUAL_LOAD
    from clholo.propagation import ASMPropagator

    B, H, W, z = 2, 30, 90, 1e-3
    mask = (rng.uniform(size=(H, W)) > 0.3).astype(np.float32)
    eng, target, phase, A, AH = _engine(queue, rng, B, H, W, z, mask=mask, fuse="all")
    real_of = F.DeviceLimits.of
    monkeypatch.setattr(F.DeviceLimits, "of", classmethod(
        lambda cls, dev: dataclasses.replace(real_of(dev), local_mem_size=1000,
                                             max_work_group_size=64)))
    prop = ASMPropagator(B, (H, W), eng.propagator.padded, queue=queue, variant="gpu",
                         load_callback=SGD_RESIDUAL_LOAD, store_callback=SGD_ADAM_STORE)
    for plan in (prop._first_cb, prop._last_cb):
        assert all(dict(p.defines).get("FFT_INPLACE") for p in plan.geometry.passes)
    eng.propagator = prop
    _first_two_steps_match_the_reference(eng, phase, target, A, AH, mask)


def test_default_fuse_by_device_kind(queue):
    import pyopencl as cl

    class FakeDevice:
        def __init__(self, kind):
            self.type = kind

    for kind in (cl.device_type.GPU, cl.device_type.ACCELERATOR, cl.device_type.CPU):
        assert default_fuse(FakeDevice(kind)) == "round-trips"
    # where the round trips do not fit (here: three_pass=False), CPUs fall back to "none",
    # GPUs to "all"
    # (by the FFT kernels' family: the GPU kernels on a CPU device fall back as on a GPU)
    assert _fallback_fuse(FakeDevice(cl.device_type.CPU)) == "none"
    assert _fallback_fuse(FakeDevice(cl.device_type.GPU)) == "all"
    assert _fallback_fuse(FakeDevice(cl.device_type.CPU), "gpu") == "all"
    assert _fallback_fuse(FakeDevice(cl.device_type.GPU), "cpu") == "none"
    eng, *_ = _engine(queue, np.random.default_rng(0), 1, 16, 24, 1e-3, three_pass=False)
    assert eng.fuse == _fallback_fuse(queue.device)
    eng, *_ = _engine(queue, np.random.default_rng(0), 1, 16, 24, 1e-3)
    assert eng.fuse == "round-trips"
    with pytest.raises(ValueError, match="fuse must be one of 'none', 'residual', 'all', "
                                         "'round-trips'"):
        _engine(queue, np.random.default_rng(0), 1, 8, 8, 1e-3, fuse="adam")


# fuse="round-trips": the iteration in four passes (host/phase_retrieval.py), on the CPU strips
# and on the GPU kernels (one pixel per mid callback), with and without a mask, and on lines
# the GPU kernels hold in place
ROUND_TRIP_FORMS = [pytest.param("auto", False, id="cpu-strips"),
                    pytest.param("auto", True, id="cpu-strips-mask"),
                    pytest.param("gpu", True, id="gpu-kernels-mask"),
                    pytest.param("gpu", False, id="gpu-kernels")]


@pytest.mark.parametrize("variant,with_mask", ROUND_TRIP_FORMS)
@pytest.mark.parametrize("B,H,W", [(2, 40, 56), (3, 21, 34), (1, 16, 72)])
def test_round_trips_iterations_match_the_kernels(queue, rng, B, H, W, variant, with_mask):
    # five iterations of the four-pass form against the kernels' form from the same start: the
    # rearranged gradient (|s|^2 w A^H(m y) - conj(s) w A^H(m t)) within the gradient's
    # tolerance, the loss sums of the same y
    z = 3e-3
    mask = (rng.uniform(size=(H, W)) > 0.3).astype(np.float32) if with_mask else None
    seed = int(rng.integers(2 ** 32))
    runs = []
    for form, v in (("none", "auto"), ("round-trips", variant)):
        eng, target, phase, A, AH = _engine(queue, np.random.default_rng(seed), B, H, W, z,
                                            mask=mask, fuse=form, variant=v)
        eng.step()
        loss, grad, s = ref.sgd_loss_and_gradient(phase, target, A, AH, mask=mask)
        t = tol("encode_gradient", np.float32)
        assert rel_l2(eng.grad.get(), grad) <= t["rel_l2"], form
        np.testing.assert_allclose(eng.loss.get(), loss, rtol=t["rel_l2"], atol=t["max_abs"])
        assert rel_l2(eng.scale.get(), s) <= t["rel_l2"], form
        for _ in range(4):
            eng.step()
        runs.append([a.get() for a in (eng.phase, eng.adam_m, eng.adam_v, eng.grad, eng.loss)]
                    + [eng.evaluate()])
    t = tol("encode_gradient", np.float32)
    for name, a, b in zip(("phase", "m", "v", "grad", "loss", "evaluate"), *runs):
        assert (a.min() > 0) if name in ("loss", "evaluate") else (np.std(a) > 0), name
        assert rel_l2(b, a) <= t["rel_l2"], name


@pytest.mark.parametrize("variant", ["auto", "gpu"])
def test_round_trips_loss_sums_do_not_depend_on_the_batch(queue, rng, variant):
    # the forward row round trip adds the loss sums up per part of each field's lines
    # (FFT_MID_CB_SUMS) in an order fixed by the plan: a field's loss and scale are the same
    # bits alone and among others, and its sums' parts are as many as the plan says
    B, H, W, z, wl = 3, 20, 44, 2e-3, (520e-9,)
    padded = device_padded_shape((H, W), z, wavelength=wl, pitch=P)
    target = random_complex(rng, (B, H, W))
    phase = rng.uniform(0, 2 * np.pi, (B, H, W)).astype(np.float32)
    mask = cla.to_device(queue, (rng.uniform(size=(H, W)) > 0.2).astype(np.float32))
    got = []
    for sl in (slice(0, B), slice(1, 2)):
        eng = PhaseRetrieval(cla.to_device(queue, target[sl]), wavelengths=wl, pitch=P, z=z,
                             padded=padded, mask=mask, queue=queue, fuse="round-trips",
                             variant=variant)
        assert eng._rt_partial.shape == (sl.stop - sl.start, eng._rows_forward.mid_parts, 4)
        eng.set_phase(cla.to_device(queue, phase[sl]))
        eng.step()
        got.append((eng.loss.get(), eng.scale.get()))
    (loss3, scale3), (loss1, scale1) = got
    assert loss3[1] == loss1[0] and scale3[1] == scale1[0]
    A, AH = _operators((H, W), z, padded, wl)
    loss, _, s = ref.sgd_loss_and_gradient(phase, target, A, AH, mask=mask.get())
    t = tol("encode_gradient", np.float32)
    np.testing.assert_allclose(loss3, loss, rtol=t["rel_l2"], atol=t["max_abs"])
    assert rel_l2(scale3, s) <= t["rel_l2"]


@pytest.mark.parametrize("direct", [False, True], ids=["in-place", "in-place-direct"])
def test_round_trips_on_in_place_gpu_lines(queue, rng, monkeypatch, direct):
    # SGD's 2250^2 grid holds its lines in place on an H100: here a device with 1000 bytes of
    # local memory sends rows and columns of 72-96 points there, where the mid callbacks must
    # still run, the sums' tree too; also with the stages that read and write global memory
    # themselves (the tunable setting inplace_direct, off until measured on a GPU)
    import dataclasses

    from clholo import fft as F

    monkeypatch.setattr(SETTINGS["inplace_direct"], "default", direct)
    B, H, W, z = 2, 64, 90, 1e-3
    mask = (rng.uniform(size=(H, W)) > 0.3).astype(np.float32)
    real_of = F.DeviceLimits.of
    monkeypatch.setattr(F.DeviceLimits, "of", classmethod(
        lambda cls, dev: dataclasses.replace(real_of(dev), local_mem_size=1000,
                                             max_work_group_size=64)))
    eng, target, phase, A, AH = _engine(queue, rng, B, H, W, z, mask=mask, fuse="round-trips",
                                        variant="gpu")
    for plan in (eng._rows_forward, eng._rows_adam, eng.propagator.columns):
        defines = dict(plan.geometry.pass_.defines)
        assert defines.get("FFT_INPLACE"), plan.geometry.pass_
        assert bool(defines.get("FFT_INPLACE_DIRECT")) == direct, plan.geometry.pass_
    _first_two_steps_match_the_reference(eng, phase, target, A, AH, mask)


@pytest.mark.parametrize("delta", [1e-1, 1e-3])
def test_round_trips_gradient_near_convergence(queue, rng, delta):
    # the rearranged gradient subtracts two propagated fields that nearly cancel near
    # convergence; the residual the other forms propagate already carries the forward FFT's
    # rounding, so both forms' absolute errors are of one size at any distance (about 1.7x in
    # a float32 model; 3x allowed). Target: a reachable field (s A exp(i P0)), phase P0 + delta
    B, H, W, z = 2, 48, 64, 3e-3
    padded = device_padded_shape((H, W), z, wavelength=WL, pitch=P)
    A, AH = _operators((H, W), z, padded)
    p0 = rng.uniform(0, 2 * np.pi, (B, H, W))
    target = ((0.6 + 0.3j) * A(np.exp(1j * p0))).astype(np.complex64)
    phase = (p0 + delta * rng.standard_normal(p0.shape)).astype(np.float32)
    _, grad, _ = ref.sgd_loss_and_gradient(phase, target, A, AH)
    errors = {}
    for form in ("none", "round-trips"):
        eng, *_ = _engine(queue, rng, B, H, W, z, fuse=form, target=target)
        eng.set_phase(cla.to_device(queue, phase))
        eng.step()
        errors[form] = np.linalg.norm(eng.grad.get() - grad)
    assert errors["round-trips"] <= 3 * errors["none"], errors
    # the gradient's tolerance holds away from convergence; at delta 1e-3 the gradient is so
    # small that any float32 form's error is near it (the residual form's 1.2e-4 here)
    if delta >= 0.1:
        assert errors["round-trips"] <= tol("encode_gradient", np.float32)["rel_l2"] * \
            np.linalg.norm(grad), errors


def test_round_trips_refusals_and_fallback(queue, rng, monkeypatch):
    import dataclasses

    from clholo import fft as F
    from clholo.host import phase_retrieval as PR

    with pytest.raises(ValueError, match="fuse='round-trips' needs .* three_pass not False"):
        _engine(queue, rng, 1, 16, 24, 1e-3, fuse="round-trips", three_pass=False)
    eng, *_ = _engine(queue, rng, 1, 16, 24, 1e-3, fuse="round-trips")
    with pytest.raises(ValueError, match="fuse='none'"):
        eng.gradient()
    # lines longer than the GPU kernels' fast memory: refused when asked for, and the
    # default (round trips on GPUs) falls back to fusing the residual and the Adam step
    real_of = F.DeviceLimits.of
    monkeypatch.setattr(F.DeviceLimits, "of", classmethod(
        lambda cls, dev: dataclasses.replace(real_of(dev), local_mem_size=256,
                                             max_work_group_size=8)))
    assert not PR.round_trips_fit(1, (16, 24), (64, 96), queue.device, variant="gpu")
    with pytest.raises(ValueError, match="use fuse='all'"):
        PhaseRetrieval(cla.to_device(queue, random_complex(rng, (1, 16, 24))),
                       wavelengths=WL, pitch=P, z=1e-3, padded=(64, 96), queue=queue,
                       fuse="round-trips", variant="gpu")
    monkeypatch.setattr(PR, "default_fuse", lambda device: "round-trips")
    eng = PhaseRetrieval(cla.to_device(queue, random_complex(rng, (1, 16, 24))),
                         wavelengths=WL, pitch=P, z=1e-3, padded=(64, 96), queue=queue,
                         variant="gpu")
    assert eng.fuse == "all"


@pytest.mark.parametrize("B,H,W", [(1, 8, 8), (3, 17, 29), (5, 64, 48)])
def test_elementwise_kernels_match_reference(queue, rng, B, H, W):
    t = tol("encode_elementwise", np.float32)
    u = random_complex(rng, (B, H, W))
    du = cla.to_device(queue, u)
    phase = rng.uniform(-10, 10, (B, H, W)).astype(np.float32)
    x = cla.empty(queue, u.shape, np.complex64)
    encode_kernel(queue.context, "phase_to_field")(queue, (quads(u.size),), None,
                                                   cla.to_device(queue, phase).data, x.data,
                                                   np.uint32(u.size))
    assert np.max(np.abs(x.get() - ref.phase_to_field(phase))) <= t["max_abs"]
    ang = cla.empty(queue, u.shape, np.float32)
    encode_kernel(queue.context, "field_angle")(queue, (u.size,), None, du.data, ang.data)
    assert np.max(np.abs(np.angle(np.exp(1j * (ang.get() - np.angle(u)))))) <= t["max_abs"]
    amax = field_max_abs(du)  # bit for bit: tests/test_encode_max.py
    np.testing.assert_allclose(amax.get(), np.abs(u).max(axis=(-2, -1)), rtol=1e-6)
    # DPAC: normalise by 0.7 of the max so some amplitudes clip at 1
    am = (0.7 * np.abs(u).max(axis=(-2, -1))).astype(np.float32)
    out = cla.empty(queue, (B, H, W), np.float32)
    encode_kernel(queue.context, "dpac_encode")(queue, (W, H, B), None, du.data,
                                                cla.to_device(queue, am).data, out.data)
    want = ref.dpac_phase(u, am)
    assert np.max(np.abs(np.angle(np.exp(1j * (out.get() - want))))) <= 10 * t["max_abs"]


def test_dpac_reference_pairs_average_to_the_field(rng):
    u = random_complex(rng, (2, 6, 8), np.complex128)
    amax = np.abs(u).max(axis=(-2, -1))
    P_ = ref.dpac_phase(u, amax)
    # the even and odd phase of each pixel average to a exp(i phi): build both from the formula
    odd = (np.add.outer(np.arange(6), np.arange(8)) & 1).astype(bool)
    partner = 2 * np.angle(u) - P_  # phi +- acos a <-> phi -+ acos a
    pair = 0.5 * (np.exp(1j * P_) + np.exp(1j * partner))
    np.testing.assert_allclose(pair, u / amax[:, None, None], atol=1e-12)
    assert odd.any() and (~odd).any()


def test_dpac_filter_removes_the_checkerboard_copy(queue, rng):
    # a field band-limited to the filter at the SLM plane, DPAC-coded, comes back through the
    # filter close to itself; without the filter the copy term stays
    H, W, z = 64, 64, 2e-3
    optics = Optics(pitch=P, wavelengths=(520e-9,))
    padded = device_padded_shape((H, W), z, wavelength=520e-9, pitch=P)
    spec = np.zeros((H, W), np.complex128)
    spec[:6, :6] = random_complex(rng, (6, 6), np.complex128)
    spec[-5:, :6] = random_complex(rng, (5, 6), np.complex128)
    slm_field = np.fft.ifft2(spec) + 0.2 * np.exp(0j)
    holo = ref.propagate(slm_field, z, wavelength=520e-9, pitch=P, pad=padded)
    holo = holo.astype(np.complex64)[None, None]
    phase = dpac_encode(holo, optics, z_slm=z, prefilter=False, queue=queue)
    filtered = phase_to_hologram(phase, optics, z_slm=z, fourier_filter=0.5, queue=queue)[0, 0]
    plain = phase_to_hologram(phase, optics, z_slm=z, queue=queue)[0, 0]

    def fitted_error(got):
        inner = slice(8, -8)  # away from the borders of the finite SLM
        g, w = got[inner, inner].ravel(), holo[0, 0][inner, inner].ravel()
        s = np.vdot(g, w) / np.vdot(g, g)
        return np.linalg.norm(s * g - w) / np.linalg.norm(w)

    assert fitted_error(filtered) < 0.1
    assert fitted_error(plain) > 3 * fitted_error(filtered)


def test_dpac_filter_transfer_is_built_once_per_setting(queue):
    """the filtered transfer function is cached per context (a display loop encodes every batch
    with it): the same array again, equal to H times the mask built afresh; another cutoff,
    distance or band limit is another entry"""
    from clholo.encode.dpac import fourier_filter_transfer
    from clholo.propagation import build_transfer_function

    optics = Optics(pitch=P, wavelengths=(638e-9, 520e-9))
    padded, z = (48, 40), 3e-3
    tf = fourier_filter_transfer(queue, padded, z, optics, cutoff=0.5)
    assert fourier_filter_transfer(queue, padded, z, optics, cutoff=0.5) is tf
    want = build_transfer_function(queue, padded, z, wavelengths=optics.wavelengths,
                                   pitch=P).get() * ref.dpac_filter_mask(padded, cutoff=0.5)
    np.testing.assert_array_equal(tf.get(), want.astype(np.complex64))
    others = [fourier_filter_transfer(queue, padded, z, optics, cutoff=0.25),
              fourier_filter_transfer(queue, padded, -z, optics, cutoff=0.5)]
    for other in others:
        assert other is not tf and not np.array_equal(other.get(), tf.get())
    # (the band limit cuts nothing on this small grid: another entry, the same values)
    assert fourier_filter_transfer(queue, padded, z, optics, cutoff=0.5,
                                   band_limit=False) is not tf


def test_dpac_mask_cutoff():
    m = ref.dpac_filter_mask((16, 8), cutoff=0.5)
    ky = np.abs(np.fft.fftfreq(16) * 16)
    kx = np.abs(np.fft.fftfreq(8) * 8)
    np.testing.assert_array_equal(m, np.outer(ky < 4, kx < 2).astype(float))


def test_sgd_bad_input(queue, rng):
    optics = Optics(pitch=P, wavelengths=(520e-9,))
    holo = random_complex(rng, (1, 1, 8, 8))
    with pytest.raises(ValueError, match="channel"):
        sgd_encode(random_complex(rng, (1, 2, 8, 8)), optics, progress=False, queue=queue)
    with pytest.raises(ValueError, match="init"):
        sgd_encode(holo, optics, init="zeros", progress=False, queue=queue)
    with pytest.raises(ValueError, match="lr"):
        sgd_encode(holo, optics, lr=-1, progress=False, queue=queue)
    with pytest.raises(ValueError, match="roi"):
        sgd_encode(holo, optics, roi=np.ones((4, 4)), progress=False, queue=queue)
    with pytest.raises(TypeError, match="complex64"):
        sgd_encode(np.ones((1, 1, 8, 8)), optics, progress=False, queue=queue)
    bad = holo.copy()
    bad[0, 0, 1, 1] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        dpac_encode(bad, optics, queue=queue)


def _twain_holograms(shared_data, size=48, frames=2):
    mpi = clholo.io.load_scene(shared_data / "twain-mpi", near=2e-3, far=6e-3)
    H, W = mpi.shape
    y0, x0 = H // 2 - size // 2, W // 2 - size // 2
    crop = clholo.MPI(mpi.color[:, y0:y0 + size, x0:x0 + size],
                      mpi.alpha[:, y0:y0 + size, x0:x0 + size], mpi.depths)
    optics = Optics(pitch=P)
    return crop, optics, clholo.render_hologram(crop, optics, frames=frames, seed=3)


def test_sgd_loss_falls_monotonically_on_twain(queue, shared_data):
    _, optics, holo = _twain_holograms(shared_data)
    for init in ("target", "random"):
        res = sgd_encode(holo, optics, z_slm=0.04, iterations=12, lr=0.05, init=init,
                         check_every=1, progress=False, queue=queue)
        losses = np.stack([loss for _, loss in res.history])  # [12, T, C]
        assert losses.shape == (12,) + holo.shape[:2]
        assert np.all(np.diff(losses, axis=0) < 0), init
        assert np.all(res.loss < losses[0])
        assert np.all((losses >= 0) & (losses <= 1))


def test_sgd_batches_and_stopping(queue, rng):
    optics = Optics(pitch=P, wavelengths=(520e-9, 450e-9))
    holo = random_complex(rng, (3, 2, 16, 16))
    one = sgd_encode(holo, optics, z_slm=1e-3, iterations=5, progress=False, queue=queue)
    split = sgd_encode(holo, optics, z_slm=1e-3, iterations=5, frames_per_batch=2,
                       progress=False, queue=queue)
    np.testing.assert_allclose(split.phase, one.phase, atol=1e-5)
    stop = sgd_encode(holo, optics, z_slm=1e-3, iterations=400, tol=0.5, check_every=2,
                      progress=False, queue=queue)
    assert stop.iterations < 400 and stop.iterations % 2 == 0


@pytest.mark.parametrize("roi", [False, True])
def test_sgd_encode_in_four_passes_as_a_gpu_runs_it(queue, rng, monkeypatch, roi):
    # the default form (fuse="round-trips") through the whole of sgd_encode: init from the
    # target, batches of frames, the stopping test's readings and the final evaluate() (which
    # rebuilds the row spectrum it overwrites), against every step a pass of its own ("none")
    from clholo.host import phase_retrieval as PR

    optics = Optics(pitch=P, wavelengths=(520e-9, 450e-9))
    holo = random_complex(rng, (3, 2, 24, 40))
    mask = (rng.uniform(size=(24, 40)) > 0.3).astype(np.float32) if roi else None
    kw = dict(z_slm=2e-3, iterations=8, check_every=2, frames_per_batch=2, roi=mask,
              progress=False, queue=queue)
    monkeypatch.setattr(PR, "default_fuse", lambda device: "none")
    cpu = sgd_encode(holo, optics, **kw)
    monkeypatch.setattr(PR, "default_fuse", lambda device: "round-trips")
    gpu = sgd_encode(holo, optics, **kw)
    t = tol("encode_gradient", np.float32)
    assert rel_l2(gpu.phase, cpu.phase) <= t["rel_l2"]
    np.testing.assert_allclose(gpu.loss, cpu.loss, rtol=t["rel_l2"])
    assert rel_l2(gpu.scale, cpu.scale) <= t["rel_l2"]
    for (k1, a), (k2, b) in zip(cpu.history, gpu.history):
        assert k1 == k2
        np.testing.assert_allclose(b, a, rtol=t["rel_l2"])
    assert np.all(gpu.loss < cpu.history[0][1])  # it optimised, every field


def test_simulate_slm_inverts_quantisation(queue, rng):
    from clholo.encode import simulate_slm
    from clholo.encode.quantize import quantize

    optics = Optics(pitch=P, wavelengths=WL)
    phase = rng.uniform(-5, 5, (2, 2, 16, 24)).astype(np.float32)
    luts = ["linear", "linear:200"]
    gray = quantize(phase, luts)
    got = simulate_slm(gray, optics, luts, z_slm=1e-3, queue=queue)
    want = phase_to_hologram(phase, optics, z_slm=1e-3, queue=queue)
    # 8-bit: phase errors up to pi/255 (linear) and pi/200
    assert rel_l2(got, want) < np.pi / 200
    assert rel_l2(got, want) > 1e-4  # quantisation happened
    padded = device_padded_shape((16, 24), 1e-3, wavelength=WL, pitch=P)
    for c, w in enumerate(WL):
        ref_field = ref.propagate(np.exp(1j * phase[:, c].astype(float)), 1e-3, wavelength=w,
                                  pitch=P, pad=padded)
        assert rel_l2(want[:, c], ref_field) <= tol("propagate", np.float32)["rel_l2"] * 5


def test_sgd_init_array_and_roi(queue, rng):
    optics = Optics(pitch=P, wavelengths=(520e-9,))
    holo = random_complex(rng, (1, 1, 16, 16))
    init = rng.uniform(0, 6, (1, 1, 16, 16)).astype(np.float32)
    roi = np.zeros((16, 16), np.float32)
    roi[4:12, 4:12] = 1
    res = sgd_encode(holo, optics, z_slm=1e-3, iterations=1, lr=0.1, init=init, roi=roi,
                     progress=False, queue=queue)
    # one Adam step moves every pixel with a non-zero gradient by lr (first step: lr sign(g))
    moved = np.abs(res.phase - init)
    assert np.median(moved) == pytest.approx(0.1, rel=1e-3)
    padded = device_padded_shape((16, 16), 1e-3, wavelength=520e-9, pitch=P)
    A, _ = ref.asm_operator((16, 16), 1e-3, wavelengths=(520e-9,), pitch=P, padded=padded)
    want = ref.sgd_loss(res.phase[0], holo[0], A, mask=roi)
    np.testing.assert_allclose(res.loss[0], want, rtol=1e-3)
    assert want[0] < ref.sgd_loss(init[0], holo[0], A, mask=roi)[0]


def test_compare_encodings_and_score(queue, rng):
    from clholo.encode.results import compare_encodings, score

    img = rng.uniform(0.1, 1, (2, 12, 12))
    s = score(3 * img, np.moveaxis(img, 0, -1))
    assert s["scale"] == pytest.approx([1 / 3, 1 / 3]) and s["psnr"] > 100 and s["ssim"] > 0.999
    noisy = score(img + rng.normal(0, 0.1, img.shape), np.moveaxis(img, 0, -1))
    assert 10 < noisy["psnr"] < 40 and noisy["ssim"] < 0.99
    mpi = clholo.MPI(rng.uniform(0, 1, (2, 24, 24, 1)), rng.uniform(0.2, 1, (2, 24, 24)),
                     [1e-3, 2e-3])
    res = compare_encodings(mpi, Optics(pitch=P, wavelengths=(520e-9,)), frames=1, z_slm=2e-3,
                            iterations=3, queue=queue)
    over = compare_encodings(mpi, Optics(pitch=P, wavelengths=(520e-9,)), frames=1, z_slm=2e-3,
                             iterations=3, reference="over", queue=queue)
    # the same holograms, scored against another reference
    assert res["complex"]["psnr"] != over["complex"]["psnr"]
    with pytest.raises(ValueError, match="reference must be"):
        compare_encodings(mpi, Optics(pitch=P, wavelengths=(520e-9,)), reference="x")
    assert set(res) == {"complex", "sgd", "dpac"}
    for name in ("sgd", "dpac"):
        assert np.isfinite(res[name]["psnr_vs_complex"]) and res[name]["seconds"] > 0
    assert 0 < res["sgd"]["loss"] < 1
    assert res["sgd"]["colour_balance"] == [1.0] and len(res["dpac"]["scale_vs_complex"]) == 1


def test_sgd_progress_bar_shows_the_loss(queue, rng, capsys):
    optics = Optics(pitch=P, wavelengths=(520e-9,))
    sgd_encode(random_complex(rng, (1, 1, 8, 8)), optics, z_slm=1e-3, iterations=4,
               check_every=2, progress=True, queue=queue)
    err = capsys.readouterr().err
    assert "sgd" in err and "loss=" in err


@pytest.mark.parametrize("fuse,variant", [("none", "auto"), ("residual", "auto"),
                                          ("all", "auto"), ("round-trips", "cpu"),
                                          ("round-trips", "gpu")])
def test_row_pitch_leaves_the_iterations_bit_for_bit(queue, rng, monkeypatch, fuse, variant):
    """The three-pass propagations' row spectrum at a pitch (rows of a multiple of 4 KiB on
    CPUs; here of 128 bytes, so that a small grid takes it) gives the same bits, with the
    callbacks of every fused form and the round trips' rows."""
    from clholo import fft as F

    seed = int(rng.integers(2 ** 32))
    runs = []
    for alias in (None, 128):
        if alias is not None:
            monkeypatch.setattr(F, "_PITCH_ALIAS_BYTES", alias)
        # 20 x 32 at 3 mm: the padded grid is 36 x 48, rows of 384 bytes
        eng, *_ = _engine(queue, np.random.default_rng(seed), 2, 20, 32, 3e-3, fuse=fuse,
                          variant=variant)
        cpu = F.DeviceLimits.of(queue.device).is_cpu
        assert eng.propagator.three_pass and eng.propagator.padded == (36, 48)
        assert eng.propagator.row_pitch == (64 if alias and cpu else 48)
        for _ in range(3):
            eng.step()
        runs.append([a.get() for a in (eng.phase, eng.adam_m, eng.grad, eng.loss)])
    for name, a, b in zip(("phase", "m", "grad", "loss"), *runs):
        np.testing.assert_array_equal(b, a, err_msg=name)


def test_gpu_batch_first_order_keeps_the_round_trips_sums(queue, rng, monkeypatch):
    """The round trips' loss sums (one part per group of lines) with the GPU kernels' groups
    in batch-first order: the same bits as in the default order."""
    from clholo import fft as F

    runs = gpu_round_trip_steps(queue, int(rng.integers(2 ** 32)), monkeypatch,
                                SETTINGS["batch_fast"], "default", (False, True))
    for name in ("phase", "grad", "loss"):
        np.testing.assert_array_equal(runs[1][name], runs[0][name], err_msg=name)


def gpu_round_trip_steps(queue, seed, monkeypatch, owner, attr, values, *, steps=3):
    """Per value of ``owner.attr`` (a module's setting, or a tunable setting's ``default``):
    SGD's round trips on the GPU kernels after ``steps``
    steps from the same start: ``{"phase", "adam_m", "grad", "loss"}`` in NumPy (runs whose
    settings must not change a bit compare them)."""
    runs = []
    for value in values:
        monkeypatch.setattr(owner, attr, value)
        eng, *_ = _engine(queue, np.random.default_rng(seed), 3, 16, 32, 3e-3,
                          fuse="round-trips", variant="gpu")
        for _ in range(steps):
            eng.step()
        runs.append({name: getattr(eng, name).get()
                     for name in ("phase", "adam_m", "grad", "loss")})
    return runs
