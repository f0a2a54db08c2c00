"""DPAC's largest |u| per field (``field_max_abs2`` then ``field_max_abs``, kernels/encode.cl)
split like SGD's loss sums (``sum_plan``): the device's split, an H100's (256 work-items, 8
groups per compute unit) and ragged ones, on PoCL.

A maximum is exact in any order, so the result is pinned bit for bit: ``sqrt`` (once) of the
largest ``|u|^2`` as the device's ``cabs2`` rounds it. The per-pixel reference is computed on
the same device by a one-line kernel with the same ``cabs2`` and build options (PoCL contracts
``x*x + y*y`` into a fused multiply-add under ``-cl-mad-enable``, so NumPy's float32
``re*re + im*im`` differs from it in the last bit now and then); NumPy's ``|u|`` checks it to a
few ulps."""

import numpy as np
import pyopencl as cl
import pyopencl.array as cla
import pytest

from clholo.host import runtime
from clholo.host.phase_retrieval import (SumPlan, device_sum_plan, field_max_abs,
                                         launch_max_abs, sum_plan)

from conftest import random_complex
from tolerances import tol

EXACT = tol("encode_max", np.float32)["max_abs"]  # 0: bit for bit

# |u| per pixel as dpac_encode computes it (sqrt(cabs2(u))); sqrt is monotonic, so the largest
# of these is sqrt of the largest cabs2: what the two-stage kernels must give
_PER_PIXEL = """#include "clholo_complex.h"
__kernel void abs_per_pixel(__global const REAL2 *u, __global REAL *a2, __global REAL *a)
{
    const size_t i = get_global_id(0);
    a2[i] = cabs2(u[i]);
    a[i] = sqrt(cabs2(u[i]));
}
"""


def _per_pixel_abs(queue, u, *, squared=False):
    """``sqrt(cabs2(u))`` per pixel on the device (and ``cabs2(u)`` with ``squared``)."""
    prg = runtime.build_program(queue.context, "encode.cl", source=_PER_PIXEL,
                                defines={"REAL": "float"})
    a2, a = (cla.empty(queue, u.shape, np.float32) for _ in range(2))
    cl.Kernel(prg, "abs_per_pixel")(queue, (u.size,), None, cla.to_device(queue, u).data,
                                    a2.data, a.data)
    return (a2.get(), a.get()) if squared else a.get()


def _plans(queue, n):
    """The device's split, an H100's within this device's limits, and ragged ones."""
    lim = runtime._limits_of_device(queue.device)
    cap = min(256, lim.max_work_group_size, lim.max_item_sizes[0])
    h100 = sum_plan(n, gpu=True, compute_units=132, max_work_group=cap, max_items=cap,
                    local_mem_bytes=48 << 10)
    return [device_sum_plan(queue.device, n), h100, SumPlan(32, 7), SumPlan(1, 3),
            SumPlan(cap, 1)]


def _bits(a):
    return np.asarray(a, np.float32).view(np.uint32)


@pytest.mark.parametrize("n", [1, 2, 3, 5, 7, 64, 65, 255, 1001, 4097, 300_001])
def test_the_max_is_the_per_pixel_abs_bit_for_bit_with_every_split(queue, rng, n):
    B = 3
    # fresh random fields over six decades, so that a few groups hold each field's maximum
    u = (random_complex(rng, (B, n)) * 10.0 ** rng.uniform(-3, 3, (B, 1))).astype(np.complex64)
    want = _per_pixel_abs(queue, u).max(axis=1)
    np.testing.assert_allclose(want, np.abs(u.astype(np.complex128)).max(axis=1), rtol=2e-7)
    du = cla.to_device(queue, u)
    for plan in _plans(queue, n):
        got = field_max_abs(du, plan=plan).get()
        assert np.max(np.abs(got - want)) <= EXACT, (plan, got, want)
        np.testing.assert_array_equal(_bits(got), _bits(want), err_msg=str(plan))


@pytest.mark.parametrize("where", ["first", "middle", "last quad", "tail"])
def test_the_max_anywhere_in_a_field_with_several_groups(queue, rng, where):
    """One pixel far above the others, at the start, in the middle, in the last quad and in the
    n % 4 pixels past it (read by work-item 0 of group 0 only)."""
    n, B = 4 * 1000 + 3, 2
    k = {"first": 0, "middle": 2222, "last quad": 4 * 1000 - 1, "tail": n - 2}[where]
    u = random_complex(rng, (B, n))
    u[:, k] = [40 - 9j, -0.5j]  # field 1: its maximum stays elsewhere
    want = _per_pixel_abs(queue, u).max(axis=1)
    du = cla.to_device(queue, u)
    for plan in _plans(queue, n):
        np.testing.assert_array_equal(_bits(field_max_abs(du, plan=plan).get()), _bits(want),
                                      err_msg=str(plan))
    assert want[0] == np.float32(41)


def test_nan_pixels_are_skipped_as_before_the_split(queue, rng):
    """fmax returns the number: NaN pixels are skipped (the one-group kernel did the same), and
    a field of NaNs gives 0 (dpac_encode then codes a = 0), whatever the split."""
    n, B = 4097, 3
    u = random_complex(rng, (B, n))
    u[0, [0, 17, 4096]] = np.nan  # in a quad, and the last pixel (past the last quad)
    u[1, 5] = complex(np.nan, 1e3)  # a NaN whose other part is large: still skipped
    u[2] = np.nan
    a = _per_pixel_abs(queue, u)
    want = np.array([np.nanmax(a[0]), np.nanmax(a[1]), 0.0], np.float32)
    assert np.isfinite(want).all() and want[1] < 10
    du = cla.to_device(queue, u)
    for plan in _plans(queue, n):
        np.testing.assert_array_equal(_bits(field_max_abs(du, plan=plan).get()), _bits(want),
                                      err_msg=str(plan))


def test_a_field_s_max_does_not_depend_on_its_batch(queue, rng):
    n = 300_001
    u = random_complex(rng, (3, n))
    for plan in _plans(queue, n):
        batch = field_max_abs(cla.to_device(queue, u), plan=plan).get()
        alone = field_max_abs(cla.to_device(queue, u[1:2]), plan=plan).get()
        np.testing.assert_array_equal(_bits(batch[1:2]), _bits(alone))


def test_launch_max_abs_writes_each_group_s_max_of_abs2(queue, rng):
    """The partials: group g of field b holds the largest |u|^2 of the quads it strides over
    (and group 0 the pixels past the last quad); stage 2 takes sqrt of their maximum."""
    n, B, plan = 4 * 50 + 1, 2, SumPlan(4, 3)
    u = random_complex(rng, (B, n))
    a2, a = _per_pixel_abs(queue, u, squared=True)
    partial = cla.empty(queue, (B, plan.groups), np.float32)
    out = cla.empty(queue, (B,), np.float32)
    launch_max_abs(queue, plan, cla.to_device(queue, u).data, n, B, partial.data, out.data)
    q = np.arange(50)
    group = (q // plan.local) % plan.groups  # quad q's group: q = g L + lid + k G L
    part = partial.get()
    for g in range(plan.groups):
        pix = (4 * q[group == g][:, None] + np.arange(4)).ravel()
        if g == 0:
            pix = np.append(pix, n - 1)
        np.testing.assert_array_equal(_bits(part[:, g]), _bits(a2[:, pix].max(axis=1)))
    np.testing.assert_array_equal(_bits(out.get()), _bits(a.max(axis=1)))


def test_field_max_abs_refuses_what_it_cannot_read(queue):
    with pytest.raises(ValueError, match="contiguous complex64"):
        field_max_abs(cla.zeros(queue, (2, 8), np.float32))

