"""Load and store callbacks of clholo.fft.FFTPlan against NumPy.

The callbacks used here are the three the issue names: a pointwise factor at the load (as the
phase-only optimisation's exp(iP) will be), a factor and an offset at the store written through
the pointer, and |v|^2 accumulated into another buffer at the store (the focal stack's pattern,
where the transform's own output is never written). Every plan shape routes the callbacks
through another code path: rows- and columns-first 2D plans with zero-padded input and cropped
output windows, 1D plans, the CPU strips (with and without several strips per work-item), the
GPU local-memory kernel and the global-memory stages, both precisions.
"""

import numpy as np
import pyopencl.array as cla
import pytest

from clholo import fft as F
from clholo.host import runtime
from conftest import random_complex
from tolerances import rel_l2, tol

VARIANTS = ["cpu", "gpu", "gpu-global"]

# factor f[b % M][row][col] of the transform frame (M frames of Hp*Wp) at the load
LOAD_FACTOR = F.FFTCallback("""
real2 clholo_load(real2 v, long b, int row, int col, __global const real2 *f, int m, int h,
                  int w)
{
    const real2 g = f[((b % m) * h + row) * w + col];
    return (real2)(v.x * g.x - v.y * g.y, v.x * g.y + v.y * g.x);
}
""", params=["__global const real2 *", "int", "int", "int"])

# out = v * s + c[row][col] (c over the output window, width wo)
STORE_AFFINE = F.FFTCallback("""
void clholo_store(__global real2 *ptr, real2 v, long b, int row, int col, real s,
                  __global const real2 *c, int wo)
{
    *ptr = v * s + c[row * wo + col];
}
""", params=["real", "__global const real2 *", "int"])

# acc[row][col] += |v|^2 for every batch element (one work-item per batch element and pixel:
# batch elements are accumulated one plan execution at a time here, so no races)
STORE_INTENSITY = F.FFTCallback("""
void clholo_store(__global real2 *ptr, real2 v, long b, int row, int col,
                  __global real *acc, int wo)
{
    acc[row * wo + col] += v.x * v.x + v.y * v.y;
}
""", params=["__global real *", "int"])


CASES = [
    # transform, input window, output window (None: the transform's)
    ((64, 128), (48, 100), (40, 90)),   # rows-first, pad and crop
    ((64, 128), (64, 20), None),        # columns-first (narrow input)
    ((60, 45), None, (30, 45)),         # radix 3/5 sizes
    ((32, 32), None, None),
]


@pytest.mark.parametrize("variant", VARIANTS)
@pytest.mark.parametrize("dtype", [np.complex64, np.complex128])
def test_load_and_store_callbacks_2d(queue, cl_device, rng, variant, dtype):
    if dtype == np.complex128 and not runtime.has_fp64(cl_device):
        pytest.skip("device without fp64")
    load, store = LOAD_FACTOR, STORE_AFFINE
    for tshape, ishape, oshape in CASES:
        ishape, oshape = ishape or tshape, oshape or tshape
        B, M = 3, 2
        a = random_complex(rng, (B,) + ishape, dtype)
        f = random_complex(rng, (M,) + tshape, dtype)
        c = random_complex(rng, oshape, dtype)
        s = 0.75
        plan = F.FFTPlan((B,) + tshape, dtype, queue=queue, input_shape=ishape,
                         output_shape=oshape, variant=variant, load_callback=load,
                         store_callback=store)
        h, w = min(ishape[0], tshape[0]), min(ishape[1], tshape[1])
        padded = np.zeros((B,) + tshape, np.complex128)
        padded[..., :h, :w] = a[..., :h, :w]
        fb = np.stack([f[b % M] for b in range(B)]).astype(np.complex128)
        for inverse, ref in ((False, np.fft.fft2), (True, np.fft.ifft2)):
            out = cla.empty(queue, (B,) + oshape, dtype)
            out.fill(np.array(np.nan, dtype))
            got = plan.execute(cla.to_device(queue, a), out=out, inverse=inverse,
                               load_args=[cla.to_device(queue, f), M] + list(tshape),
                               store_args=[s, cla.to_device(queue, c), oshape[1]])
            want = ref(padded * fb)[..., :oshape[0], :oshape[1]] * s + c
            err = rel_l2(got.get(), want)
            assert err <= tol("fft", dtype)["rel_l2"], \
                f"{variant} {plan.order} {tshape} inverse={inverse}: {err:.3g}"


@pytest.mark.parametrize("variant", VARIANTS)
def test_callbacks_with_fused_multiply(queue, rng, variant):
    """callbacks compose with the built-in multiply: load callback, then the input multiply;
    output multiply, then the store callback"""
    load, store = LOAD_FACTOR, STORE_AFFINE
    tshape, ishape = (32, 64), (20, 50)
    a = random_complex(rng, (2,) + ishape)
    f = random_complex(rng, tshape)
    hm = random_complex(rng, tshape)
    c = random_complex(rng, tshape)
    plan = F.FFTPlan((2,) + tshape, np.complex64, queue=queue, input_shape=ishape,
                     variant=variant, load_callback=load, store_callback=store)
    padded = np.zeros((2,) + tshape, np.complex128)
    padded[..., :20, :50] = a
    for where in ("input", "output"):
        got = plan.execute(cla.to_device(queue, a), multiply=cla.to_device(queue, hm),
                           multiply_at=where, load_args=[cla.to_device(queue, f), 1, 32, 64],
                           store_args=[2.0, cla.to_device(queue, c), 64])
        if where == "input":
            want = np.fft.fft2(padded * f * hm) * 2 + c
        else:
            want = np.fft.fft2(padded * f) * hm * 2 + c
        assert rel_l2(got.get(), want) <= tol("fft", np.complex64)["rel_l2"], where


@pytest.mark.parametrize("variant", VARIANTS)
def test_store_callback_accumulates_intensity(queue, rng, variant):
    """the focal-stack pattern: |ifft2(x)|^2 summed over executions, output never written"""
    tshape, oshape = (48, 80), (30, 70)
    plan = F.FFTPlan(tshape, np.complex64, queue=queue, output_shape=oshape, variant=variant,
                     store_callback=STORE_INTENSITY)
    acc = cla.zeros(queue, oshape, np.float32)
    out = cla.zeros(queue, oshape, np.complex64)
    want = np.zeros(oshape)
    for _ in range(3):
        x = random_complex(rng, tshape)
        plan.execute(cla.to_device(queue, x), out=out, inverse=True, store_args=[acc, oshape[1]])
        want += np.abs(np.fft.ifft2(x.astype(np.complex128))[:30, :70]) ** 2
    assert rel_l2(acc.get(), want) <= 2 * tol("fft", np.complex64)["rel_l2"]
    assert not np.any(out.get())  # the store callback replaced the plain store


@pytest.mark.parametrize("variant", ["cpu", "gpu"])
def test_callbacks_1d(queue, rng, variant):
    """1D plans: b is the line (every line of every batch element), row is 0"""
    load = F.FFTCallback("""
real2 clholo_load(real2 v, long b, int row, int col, __global const real2 *f, int n)
{
    return (row == 0) ? v * f[b * n + col].x : (real2)(1e30f, 1e30f);
}""", params=["__global const real2 *", "int"])
    a = random_complex(rng, (2, 3, 120))
    f = random_complex(rng, (6, 120))
    plan = F.FFTPlan(a.shape, np.complex64, queue=queue, axes=(-1,), variant=variant,
                     load_callback=load)
    got = plan.execute(cla.to_device(queue, a), load_args=[cla.to_device(queue, f), 120])
    want = np.fft.fft(a.astype(np.complex128) * f.real.reshape(2, 3, 120))
    assert rel_l2(got.get(), want) <= tol("fft", np.complex64)["rel_l2"]


def test_callback_errors(queue, rng):
    with pytest.raises(ValueError, match="params\\[1\\].*not an OpenCL scalar"):
        F.FFTCallback("x", params=["int", "float3"])
    with pytest.raises(ValueError, match="__global"):
        F.FFTCallback("x", params=["float *"])
    with pytest.raises(TypeError, match="load_callback must be"):
        F.FFTPlan((8, 8), np.complex64, queue=queue, load_callback="v * 2")
    plan = F.FFTPlan((8, 8), np.complex64, queue=queue, load_callback=LOAD_FACTOR)
    x = cla.to_device(queue, random_complex(rng, (8, 8)))
    with pytest.raises(ValueError, match="load_args has 1 value"):
        plan.execute(x, load_args=[1])
    with pytest.raises(TypeError, match="load_args\\[0\\] must be a pyopencl array"):
        plan.execute(x, load_args=[1, 1, 8, 8])
    with pytest.raises(ValueError, match="store_args given but the plan has no store_callback"):
        plan.execute(x, load_args=[x, 1, 8, 8], store_args=[1])


# The affine store again, with the four-element form the CPU variant uses for runs of adjacent
# columns; it counts its calls so the test can tell that the quad path really ran.
STORE_AFFINE_QUAD = F.FFTCallback("""
void clholo_store(__global real2 *ptr, real2 v, long b, int row, int col, real s,
                  __global const real2 *c, int wo, __global int *quads)
{
    *ptr = v * s + c[row * wo + col];
}
#define FFT_STORE_CB_QUAD 1
void clholo_store4(__global real2 *ptr, real2 v0, real2 v1, real2 v2, real2 v3, long b,
                   int row, int col, real s, __global const real2 *c, int wo,
                   __global int *quads)
{
    atomic_inc(quads);
    __global const real2 *cc = c + row * wo + col;
    ptr[0] = v0 * s + cc[0]; ptr[1] = v1 * s + cc[1];
    ptr[2] = v2 * s + cc[2]; ptr[3] = v3 * s + cc[3];
}
""", params=["real", "__global const real2 *", "int", "__global int *"])


@pytest.mark.parametrize("variant", VARIANTS)
@pytest.mark.parametrize("tshape,ishape,oshape", [
    ((64, 128), (48, 100), (40, 90)),   # last pass columns: adjacent lanes, ragged last strip
    ((64, 128), (64, 20), (50, 96)),    # last pass rows: runs after the in-register transpose
    ((16, 64), None, (16, 62)),         # 62 columns: quads, then a ragged strip element-wise
    ((120, 40), None, None)])           # several strips per work-item (column pass)
def test_store_callback_quads(queue, rng, variant, tshape, ishape, oshape):
    ishape, oshape = ishape or tshape, oshape or tshape
    B = 2
    a = random_complex(rng, (B,) + ishape)
    c = random_complex(rng, oshape)
    plan = F.FFTPlan((B,) + tshape, np.complex64, queue=queue, input_shape=ishape,
                     output_shape=oshape, variant=variant, store_callback=STORE_AFFINE_QUAD)
    h, w = min(ishape[0], tshape[0]), min(ishape[1], tshape[1])
    padded = np.zeros((B,) + tshape, np.complex128)
    padded[..., :h, :w] = a[..., :h, :w]
    quads = cla.zeros(queue, 1, np.int32)
    out = cla.empty(queue, (B,) + oshape, np.complex64)
    out.fill(np.complex64(np.nan))
    got = plan.execute(cla.to_device(queue, a), out=out, inverse=True,
                       store_args=[0.5, cla.to_device(queue, c), oshape[1], quads])
    want = np.fft.ifft2(padded)[..., :oshape[0], :oshape[1]] * 0.5 + c
    assert rel_l2(got.get(), want) <= tol("fft", np.complex64)["rel_l2"], plan.order
    n = int(quads.get()[0])
    if variant == "cpu" and oshape[1] % 8 == 0:
        assert n > 0  # the CPU strips hand whole runs of four to clholo_store4
    if variant != "cpu":
        assert n == 0  # the GPU kernels store element by element
