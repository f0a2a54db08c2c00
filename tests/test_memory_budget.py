"""The device-memory budget is obeyed (issue 26, section 8): a smaller ``memory_budget`` gives
fewer frames per launch, and what the renderer allocates on the device never exceeds it.

``host/memory.py`` plans ``fixed + n * per_frame`` bytes; these tests check the plan itself
(:func:`clholo.host.memory.frames_per_launch`) and what the renderer really does with it: the
size of every launch, and every device buffer it creates while rendering (counted by wrapping
``pyopencl.Buffer``). The transfer functions live in the context's own cache, which has its own
budget (a quarter of the device, :func:`clholo.propagation.transfer_function_cache`): it is
filled before counting, so the count is the renderer's own memory.
"""

import numpy as np
import pyopencl as cl
import pyopencl.array as cla
import pytest

import clholo
from clholo.host import memory
from clholo.host.scheduler import HologramRenderer


def _mpi(rng, L=5, H=24, W=40):
    return clholo.MPI(rng.uniform(0, 1, (L, H, W, 3)), rng.uniform(0, 1, (L, H, W)),
                      np.linspace(1e-3, 3e-3, L))


def test_frames_per_launch_follows_the_budget(queue):
    fixed, per = 10_000, 3_000
    kw = dict(fixed_bytes=fixed, per_frame_bytes=per, samples_per_frame=16,
              device=queue.device, what="a test plan")
    got = []
    for budget in range(fixed + 9 * per, fixed + per - 1, -997):  # ever smaller budgets
        n = memory.frames_per_launch(budget_bytes=budget, **kw)
        assert n >= 1 and fixed + n * per <= budget, (budget, n)  # the plan fits the budget
        assert fixed + (n + 1) * per > budget, (budget, n)  # and uses it
        got.append(n)
    assert got == sorted(got, reverse=True) and got[0] == 9 and got[-1] == 1
    for k in (1, 2, 5):
        assert memory.frames_per_launch(budget_bytes=fixed + k * per, **kw) == k
    for k in (2, 5):  # one byte short of k frames: k - 1
        assert memory.frames_per_launch(budget_bytes=fixed + k * per - 1, **kw) == k - 1
    with pytest.raises(MemoryError, match="memory_budget"):
        memory.frames_per_launch(budget_bytes=fixed + per - 1, **kw)


def _renderer_plan(mpi, queue, two_pass=None, occlusion=True, fuse=None):
    r = HologramRenderer(mpi, clholo.Optics(), queue=queue, two_pass=two_pass,
                         occlusion=occlusion, fuse_composite=fuse)
    (Hp, Wp), (H, W), C = r.padded, mpi.shape, mpi.channels
    # one step's transfer functions, and on CPUs the two-pass layer's strips of them, made
    # from them (both live while the strips are made)
    strips = 0
    if r.two_pass and r.queue.device.type & cl.device_type.CPU:
        from clholo.fft import DeviceLimits, even_factors_bytes, round_trip_geometry
        g = round_trip_geometry((C, H, Wp), Hp, device=DeviceLimits.of(r.queue.device),
                                axis="cols", pitch=r.row_pitch)
        lanes = dict(g.pass_.defines)["VW"] // 2
        strips = 8 * C * -(-Wp // lanes) * lanes * (Hp // 2 + 1)
        assert strips == even_factors_bytes(g, C) > 0
    assert r.tf_strip_bytes == strips
    fixed = r.layer_bytes + 8 * C * Hp * Wp + strips
    # the field double-buffered, and the layer's working arrays: the two kernels' row spectrum
    # [C, H, Wp], or, twice (a last, smaller batch has its own), the four passes' spectrum,
    # pruned inverse work and (layer sum) scratch field
    work = (8 * C * H * Wp if r.two_pass
            else 2 * 8 * C * (Hp * Wp + H * Wp + (0 if occlusion else H * W)))
    assert r.memory_plan == (fixed, 8 * C * H * W * 2 + work)
    return r.memory_plan


# fuse True: the four passes with the composite in the inverse's store, a GPU's default (its
# callback plan shares the plain inverse's work buffers; it once held its own, over budget)
@pytest.mark.parametrize("two_pass,occlusion,fuse", [(True, True, None), (False, True, None),
                                                     (False, False, None), (False, True, True),
                                                     (False, False, True)])
@pytest.mark.parametrize("T", [8, 7])  # 7: the last batch is smaller than the others
def test_a_smaller_budget_gives_fewer_frames_per_launch_and_stays_within_it(queue, rng,
                                                                            monkeypatch, T,
                                                                            two_pass, occlusion,
                                                                            fuse):
    mpi = _mpi(rng)
    fixed, per_frame = _renderer_plan(mpi, queue, two_pass, occlusion, fuse)
    # fill the context's transfer-function cache (its own budget) with this MPI's steps
    for _ in HologramRenderer(mpi, clholo.Optics(), queue=queue).iter_frames(1):
        pass
    whole = HologramRenderer(mpi, clholo.Optics(), queue=queue, frames_per_batch=T,
                             two_pass=two_pass, occlusion=occlusion,
                             fuse_composite=fuse)
    want = np.concatenate([f for _, f in whole.iter_frames(T)])
    device_want = whole.render(T).get()
    real_buffer = cl.Buffer
    allocated = []

    def counting_buffer(*args, **kwargs):
        buf = real_buffer(*args, **kwargs)
        allocated.append(buf.size)
        return buf

    launches_seen = {}
    for k in (4, 2, 1):  # ever smaller budgets
        budget = fixed + k * per_frame
        launches = []
        allocated.clear()
        monkeypatch.setattr(cl, "Buffer", counting_buffer)
        renderer = HologramRenderer(mpi, clholo.Optics(), queue=queue, memory_budget=budget,
                                    two_pass=two_pass, occlusion=occlusion,
                             fuse_composite=fuse)
        real_enqueue = renderer.enqueue_batch

        def enqueue_batch(frame0, frames, field, real_enqueue=real_enqueue, launches=launches):
            launches.append(frames)
            return real_enqueue(frame0, frames, field)

        renderer.enqueue_batch = enqueue_batch
        got = np.concatenate([f for _, f in renderer.iter_frames(T)])
        queue.finish()
        monkeypatch.setattr(cl, "Buffer", real_buffer)
        assert renderer.frames_per_batch == k
        assert max(launches) == k and sum(launches) == T, launches
        # every buffer made while planning and rendering, all of them at once (an upper bound
        # of what is held at any moment), is within the budget
        assert 0 < sum(allocated) <= budget, (k, sum(allocated), budget)
        np.testing.assert_array_equal(got, want)  # the same holograms, whatever the batching
        launches_seen[k] = max(launches)
        # the device-side path (enqueue_frames: its own batch buffer) on a fresh renderer, into
        # the caller's array: within the budget too, and the same frames
        out = cla.empty(queue, device_want.shape, np.complex64)
        allocated.clear()
        monkeypatch.setattr(cl, "Buffer", counting_buffer)
        renderer = HologramRenderer(mpi, clholo.Optics(), queue=queue, memory_budget=budget,
                                    two_pass=two_pass, occlusion=occlusion,
                             fuse_composite=fuse)
        renderer.render(T, out=out)
        queue.finish()
        monkeypatch.setattr(cl, "Buffer", real_buffer)
        assert 0 < sum(allocated) <= budget, (k, sum(allocated), budget)
        np.testing.assert_array_equal(out.get(), device_want)
    assert launches_seen[4] > launches_seen[2] > launches_seen[1]


def test_the_renderers_device_memory_is_freed_before_the_files(tmp_path, rng, monkeypatch):
    """A render folder's focal stack and files are made after the renderer has gone: on a CPU
    device its layers are host memory (6.2 GB for 32 layers of a 12-megapixel photo), and
    writing the folder needs as much again (a 12-megapixel RGB-D render peaked at 21 GB with
    it alive, 8.8 GB without)."""
    import weakref

    from clholo import render_folder

    made, alive = [], []
    init = HologramRenderer.__init__

    def record(self, *args, **kwargs):
        init(self, *args, **kwargs)
        made.append(weakref.ref(self))

    def write(*args, **kwargs):
        import gc

        gc.collect()
        alive.extend(r() is not None for r in made)
        return write_render_folder(*args, **kwargs)

    write_render_folder = render_folder.write_render_folder
    monkeypatch.setattr(HologramRenderer, "__init__", record)
    monkeypatch.setattr(render_folder, "write_render_folder", write)
    mpi = clholo.io.rgbd_to_mpi(rng.random((24, 40, 3)), rng.uniform(1, 2, (24, 40)),
                                layers=4, near=2e-3, far=4e-3)
    render_folder.render_and_save(mpi, clholo.Optics(), tmp_path / "o", frames=1, seed=0)
    assert made and alive == [False] * len(made)
    assert (tmp_path / "o" / "hologram.npz").exists()
