"""Frames per launch by the device's kind (issue 23): the batch target of host/memory.py, the
one definition both schedulers use, on the limits of devices the tests do not have (a 2-core
CPU, an H100), always under the memory budget."""

import types

import numpy as np
import pyopencl as cl
import pytest

import clholo
from clholo.baselines import rpws as rpws_baseline
from clholo.host import memory
from clholo.host.rpws import RPWSRenderer
from clholo.host.scheduler import HologramRenderer


def _device(kind, compute_units, global_mem):
    return types.SimpleNamespace(type=getattr(cl.device_type, kind),
                                 max_compute_units=compute_units, global_mem_size=global_mem,
                                 name=f"fake {kind}")


CPU2 = _device("CPU", 2, 16 << 30)
H100 = _device("GPU", 132, 80 << 30)


def test_the_target_by_device_kind():
    assert memory.batch_target_samples(gpu=False, compute_units=2) == 1 << 23
    assert memory.batch_target_samples(gpu=False, compute_units=128) == 1 << 23
    assert memory.batch_target_samples(gpu=True, compute_units=132) == 132 << 19
    assert memory.batch_target_samples(gpu=True, compute_units=4) == 1 << 23  # the floor
    assert memory.device_batch_target(CPU2) == 1 << 23
    assert memory.device_batch_target(H100) == 132 << 19
    accel = _device("ACCELERATOR", 64, 16 << 30)
    assert memory.device_batch_target(accel) == 64 << 19


def _hologram_plan(L, H, W, C, Hp, Wp):
    """HologramRenderer's terms (host/scheduler.py)."""
    return dict(fixed_bytes=4 * L * H * W * (C + 1) + 8 * C * Hp * Wp,
                per_frame_bytes=8 * C * H * W * 2 + 8 * C * Hp * Wp * 2,
                samples_per_frame=C * Hp * Wp)


def test_1080p_rgb_takes_ten_frames_a_launch_on_an_h100_and_one_on_a_cpu():
    plan = _hologram_plan(32, 1080, 1920, 3, 1125, 1944)  # the SLM's padded grid
    kw = dict(plan, budget_bytes=None, what="1080p RGB")
    assert memory.frames_per_launch(device=CPU2, **kw) == 1
    assert memory.frames_per_launch(device=H100, **kw) == 10
    # 4K RGB on its 2187x3888 grid: two; 1024^2 one colour at pad 2: sixteen
    assert memory.frames_per_launch(device=H100, **dict(
        _hologram_plan(32, 2160, 3840, 3, 2187, 3888), budget_bytes=None, what="4K")) == 2
    assert memory.frames_per_launch(device=H100, **dict(
        _hologram_plan(32, 1024, 1024, 1, 2048, 2048), budget_bytes=None, what="1K")) == 16


@pytest.mark.parametrize("device", [CPU2, H100], ids=["cpu2", "h100"])
def test_a_smaller_budget_gives_fewer_frames_and_never_more_memory(device):
    plan = _hologram_plan(32, 1080, 1920, 3, 1125, 1944)
    fixed, per = plan["fixed_bytes"], plan["per_frame_bytes"]
    got = []
    for budget in np.linspace(fixed + 12 * per, fixed + per, 200).astype(np.int64):
        n = memory.frames_per_launch(device=device, budget_bytes=int(budget), what="t", **plan)
        assert 1 <= n and fixed + n * per <= budget, (budget, n)
        got.append(n)
    assert got == sorted(got, reverse=True)  # budgets fall, so do the frames
    assert got[-1] == 1 and got[0] == (10 if device is H100 else 1)
    with pytest.raises(MemoryError, match="memory_budget"):
        memory.frames_per_launch(device=device, budget_bytes=fixed + per - 1, what="t", **plan)


def test_both_schedulers_take_the_one_target(queue, rng, monkeypatch):
    """A target of two frames' samples gives both renderers two frames a launch (four or more
    within the budget): neither has a target of its own."""
    L, H, W, C = 3, 12, 20, 3
    mpi = clholo.MPI(rng.uniform(0, 1, (L, H, W, C)), rng.uniform(0, 1, (L, H, W)),
                     np.linspace(1e-3, 2e-3, L))
    K = 3
    prims = rpws_baseline.Primitives(
        np.stack([rng.uniform(0, W, K), rng.uniform(0, H, K)], 1), np.tile([0.2, 0.0, 0.2], (K, 1)),
        rng.uniform(0.2, 1.0, K), rng.uniform(0.05, 1.0, (K, C)), np.linspace(1e-3, 2e-3, K),
        np.full(K, 7.0), (H, W))
    optics = clholo.Optics()
    for make in (lambda: HologramRenderer(mpi, optics, queue=queue),
                 lambda: RPWSRenderer(prims, optics, queue=queue)):
        monkeypatch.undo()
        r = make()
        assert r.frames_per_batch >= 4
        samples = C * r.padded[0] * r.padded[1]
        monkeypatch.setattr(memory, "device_batch_target", lambda dev: 2 * samples + 1)
        assert make().frames_per_batch == 2
