"""Launch sizes are checked against the device's and the kernel's limits before every launch
(clholo.host.runtime.check_launch): devices and kernels that report small limits get an error
naming the kernel, its file, the size and the limit, instead of a driver failure."""

import dataclasses
import math
import types

import numpy as np
import pyopencl as cl
import pyopencl.array as cla
import pytest

import clholo
from clholo import fft
from clholo.host import runtime
from clholo.elementwise import _kernel as _elementwise_kernel
from clholo.host.phase_retrieval import SUM_LOCAL, device_sums_local, encode_kernel

from conftest import random_complex
from tolerances import rel_l2, tol


def _small_device(monkeypatch, **limits):
    """The real device's limits with some made smaller."""
    real = runtime._limits_of_device
    monkeypatch.setattr(runtime, "_limits_of_device",
                        lambda dev: dataclasses.replace(real(dev), **limits))


def _small_kernel(monkeypatch, **limits):
    real = runtime._limits_of_kernel
    monkeypatch.setattr(runtime, "_limits_of_kernel",
                        lambda k, dev: dataclasses.replace(real(k, dev), **limits))


def test_kernel_work_group_limit_below_the_device_s_is_planned_for(queue, rng, monkeypatch):
    """A GPU may allow 1024 work-items per group but a register-hungry kernel fewer (NVIDIA's
    H200 driver: 256 for the in-place fft_lines): the GPU FFT asks the built kernel
    (CL_KERNEL_WORK_GROUP_SIZE) and plans again within it; a launch that still exceeds it is
    stopped by the check, which names the kernel, the limit and the way out."""
    _small_kernel(monkeypatch, work_group_size=16)
    plan = fft.FFTPlan((2, 16, 32), np.complex64, queue=queue, variant="gpu")
    assert max(math.prod(lg.lsize) for p in plan.geometry.passes for lg in p.launches) <= 16
    x = random_complex(rng, (2, 16, 32))
    got = plan.execute(cla.to_device(queue, x)).get()
    assert rel_l2(got, np.fft.fft2(x.astype(np.complex128))) <= tol("fft", np.float32)["rel_l2"]
    knl = plan._launches[0].kernel
    with pytest.raises(runtime.LaunchLimitError) as info:
        runtime.check_launch(queue, knl, (64, 2), (32, 1))
    msg = str(info.value)
    for part in ("fft_lines", "kernels/fft_gpu.cl", "CL_KERNEL_WORK_GROUP_SIZE", "at most 16",
                 "clholo selftest", "CLHOLO_DEVICE"):
        assert part in msg, (part, msg)


def test_small_local_memory_stops_the_cpu_fft(queue, rng, monkeypatch):
    # the plan is made for the real device, the check sees a smaller one; the variant is named
    # (the default is the GPU variant on a GPU, issue 22)
    _small_device(monkeypatch, local_mem_bytes=1024)
    plan = fft.FFTPlan((24, 40), np.complex64, queue=queue, variant="cpu")
    with pytest.raises(runtime.LaunchLimitError,
                       match=r"fft_strip \(kernels/fft_cpu\.cl\).*bytes of local memory.*"
                             r"the device has 1024 \(CL_DEVICE_LOCAL_MEM_SIZE\)"):
        plan.execute_host(random_complex(rng, (24, 40)))


def test_small_local_memory_stops_the_gpu_fft(queue, rng, monkeypatch):
    _small_device(monkeypatch, local_mem_bytes=256)
    plan = fft.FFTPlan((24, 40), np.complex64, queue=queue, variant="gpu")
    with pytest.raises(runtime.LaunchLimitError,
                       match=r"fft_lines \(kernels/fft_gpu\.cl\).*bytes of local memory.*"
                             r"the device has 256 \(CL_DEVICE_LOCAL_MEM_SIZE\)"):
        plan.execute_host(random_complex(rng, (24, 40)))


@pytest.mark.parametrize("n, dtype", [(256, np.complex64), (2048, np.complex64),
                                      (256, np.complex128), (1024, np.complex128)])
def test_cpu_plan_leaves_room_for_the_kernel_s_own_local_memory(n, dtype):
    """issue 22: on an H100 (48 KiB) the CPU variant's column pass asked for exactly 49152
    bytes of __local arguments and the kernel held 1 byte itself: every launch must fit both"""
    h100 = fft.DeviceLimits(is_cpu=False, local_mem_size=49152, max_work_group_size=1024)
    naive = fft.plan_geometry((n, n), dtype, device=h100, variant="cpu")
    assert max(lg.local_bytes for p in naive.passes for lg in p.launches) == 49152
    held = dataclasses.replace(h100, kernel_local=(("fft_strip", 1),))
    g = fft.plan_geometry((n, n), dtype, device=held, variant="cpu")
    for p in g.passes:
        for lg in p.launches:
            assert lg.local_bytes + (1 if p.kernel == "fft_strip" else 0) <= 49152, (p, lg)
    cols = [p for p in g.passes if p.axis == "cols"][0]
    if cols.kind == "cpu":  # a smaller strip: one strip per work-item instead of two
        assert cols.launches[0].extra == (1,)


@pytest.mark.parametrize("shape", [(2, 64, 64), (3, 64, 48)])
def test_fft_plan_counts_the_kernel_s_own_local_memory(queue, rng, monkeypatch, shape):
    """A device with 12 KiB of local memory whose fft_strip holds 16 bytes itself: the first
    plan's column pass asks for all 12288 bytes of __local arguments, so the plan, once it has
    asked the built kernel (CL_KERNEL_LOCAL_MEM_SIZE), picks a smaller strip; the transform
    runs and matches NumPy."""
    local = 12288
    real_of = fft.DeviceLimits.of
    monkeypatch.setattr(fft.DeviceLimits, "of", classmethod(
        lambda cls, dev: dataclasses.replace(real_of(dev), local_mem_size=local)))
    _small_device(monkeypatch, local_mem_bytes=local)
    real_kernel = runtime._limits_of_kernel
    monkeypatch.setattr(runtime, "_limits_of_kernel", lambda k, dev: dataclasses.replace(
        real_kernel(k, dev), static_local_bytes=16 if k.function_name == "fft_strip" else 0))
    naive = fft.plan_geometry(shape, np.complex64, device=fft.DeviceLimits.of(queue.device),
                              variant="cpu")
    assert max(lg.local_bytes for p in naive.passes for lg in p.launches) == local
    plan = fft.FFTPlan(shape, np.complex64, queue=queue, variant="cpu")
    for p in plan.geometry.passes:
        assert p.kind == "cpu"
        assert all(lg.local_bytes + 16 <= local for lg in p.launches)
    x = random_complex(rng, shape)
    got = plan.execute_host(x)
    want = np.fft.fft2(x.astype(np.complex128))
    assert rel_l2(got, want) <= tol("fft", np.float32)["rel_l2"]


def test_max_work_item_sizes(queue, rng, monkeypatch):
    # the reduction's work-groups of SUM_LOCAL on a device with at most 8 items per dimension:
    # the device's own split of the sums is planned within it, another is stopped
    _small_device(monkeypatch, max_item_sizes=(8, 8, 8))
    assert device_sums_local(queue.context) == 8
    k = encode_kernel(queue.context, "field_sums", sums_local=SUM_LOCAL)
    args = [cla.empty(queue, 4, np.complex64).data] * 2 + [cla.empty(queue, 1, np.float32).data,
                                                         np.uint32(0), np.uint32(4),
                                                         cla.empty(queue, 4, np.float32).data]
    with pytest.raises(runtime.LaunchLimitError,
                       match=rf"field_sums \(kernels/encode\.cl\).*{SUM_LOCAL} work-items in "
                             rf"dimension 0.*1 to 8.*CL_DEVICE_MAX_WORK_ITEM_SIZES"):
        runtime.launch(k, queue, (SUM_LOCAL, 1), (SUM_LOCAL, 1), *args)


def test_required_work_group_size_divisibility_and_dimensions(queue):
    k = encode_kernel(queue.context, "field_sums", sums_local=SUM_LOCAL)  # reqd_work_group_size
    with pytest.raises(runtime.LaunchLimitError, match="reqd_work_group_size"):
        runtime.check_launch(queue, k, (SUM_LOCAL // 2, 1), (SUM_LOCAL // 2, 1))
    k = _elementwise_kernel(queue, np.complex64, "complex_scale")
    with pytest.raises(runtime.LaunchLimitError, match=r"not a multiple of the local size \(4,\)"):
        runtime.check_launch(queue, k, (10,), (4,))
    with pytest.raises(runtime.LaunchLimitError, match="dimension"):
        runtime.check_launch(queue, k, (2, 2, 2, 2), None)
    runtime.check_launch(queue, k, (12,), (4,))  # within every limit: silent
    assert "complex_scale" in runtime.launched_kernels()


def test_local_memory_arguments_count(queue):
    k = _elementwise_kernel(queue, np.complex64, "complex_scale")
    limit = queue.device.local_mem_size
    runtime.check_launch(queue, k, (4,), None, [cl.LocalMemory(limit // 2)])
    with pytest.raises(runtime.LaunchLimitError, match=rf"\+ {limit + 8} in __local arguments"):
        runtime.check_launch(queue, k, (4,), None, [cl.LocalMemory(limit), cl.LocalMemory(8)])


def test_launch_limit_error_is_a_value_error_and_names_the_fix(queue):
    """the CLI's error boundary prints ValueErrors as one line; a caller's own fix wins"""
    assert issubclass(runtime.LaunchLimitError, ValueError)
    k = _elementwise_kernel(queue, np.complex64, "complex_scale")
    with pytest.raises(runtime.LaunchLimitError, match="use fewer lines per group"):
        runtime.check_launch(queue, k, (10,), (4,), fix="use fewer lines per group")


class _CountingKernel:
    """A stand-in kernel that reports small limits and counts its queries."""

    function_name = "stand_in"

    def __init__(self, wg, local):
        self.wg, self.local, self.queries = wg, local, 0

    def get_info(self, what):
        return types.SimpleNamespace(int_ptr=-1)

    def get_work_group_info(self, what, device):
        self.queries += 1
        wgi = cl.kernel_work_group_info
        return {wgi.WORK_GROUP_SIZE: self.wg, wgi.LOCAL_MEM_SIZE: self.local,
                wgi.COMPILE_WORK_GROUP_SIZE: (0, 0, 0)}[what]


def test_stand_in_device_and_kernel_limits_are_queried_once():
    device = types.SimpleNamespace(int_ptr=-12345, name="Tiny GPU ", max_work_item_dimensions=2,
                                   max_work_item_sizes=[32, 4], max_work_group_size=32,
                                   local_mem_size=4096)
    queue = types.SimpleNamespace(device=device)
    kern = _CountingKernel(wg=16, local=1000)
    runtime.check_launch(queue, kern, (64, 4), (16, 1))
    n = kern.queries
    runtime.check_launch(queue, kern, (64, 4), (8, 2))
    assert kern.queries == n  # cached
    with pytest.raises(runtime.LaunchLimitError, match=r"'Tiny GPU'.*allows 1 to 2"):
        runtime.check_launch(queue, kern, (4, 4, 4), None)
    with pytest.raises(runtime.LaunchLimitError, match="at most 16 on this device"):
        runtime.check_launch(queue, kern, (64, 4), (32, 1))
    with pytest.raises(runtime.LaunchLimitError, match=r"dimension 1; the device allows 1 to 4"):
        runtime.check_launch(queue, kern, (64, 8), (2, 8))
    with pytest.raises(runtime.LaunchLimitError, match=r"needs 4104 bytes.*1000 in the kernel"):
        runtime.check_launch(queue, kern, (64,), None, [cl.LocalMemory(3104)])
    runtime._device_limits.pop(device.int_ptr, None)


def test_every_launch_site_is_checked(queue, rng):
    """a hologram render goes through the check: its kernels are recorded as launched (the
    composite runs inside the FFT kernels where it is fused: two kernels per layer on PoCL)"""
    mpi = clholo.MPI(rng.random((2, 12, 20, 1)), rng.random((2, 12, 20)), [1e-3, 2e-3])
    clholo.render_hologram(mpi, clholo.Optics(wavelengths=(520e-9,)), frames=1, queue=queue)
    launched = set(runtime.launched_kernels())
    assert "asm_transfer_function" in launched
    assert launched & {"fft_strip", "fft_lines", "fft_stage"}
