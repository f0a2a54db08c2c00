"""Complex elementwise kernels against NumPy on the device, fresh random data."""

import numpy as np
import pyopencl.array as cla
import pytest

from clholo.elementwise import accumulate_intensity, complex_multiply, complex_scale
from clholo.host.runtime import has_fp64

from conftest import random_complex
from tolerances import rel_l2, tol

SHAPES = [(1,), (7,), (33, 65), (3, 128, 96), (2, 5, 64, 64)]
DTYPES = [np.complex64, np.complex128]


def _skip_without_fp64(cl_device, dtype):
    if np.dtype(dtype) == np.complex128 and not has_fp64(cl_device):
        pytest.skip("device has no fp64")


@pytest.mark.parametrize("dtype", DTYPES)
@pytest.mark.parametrize("shape", SHAPES)
def test_complex_multiply_broadcast(queue, cl_device, rng, shape, dtype):
    _skip_without_fp64(cl_device, dtype)
    a = random_complex(rng, shape, dtype)
    b = random_complex(rng, shape[-2:] if len(shape) > 1 else shape, dtype)
    got = complex_multiply(a, b, queue=queue)
    want = a.astype(np.complex128) * b
    t = tol("elementwise", dtype)
    assert got.dtype == dtype and got.shape == a.shape
    assert rel_l2(got, want) <= t["rel_l2"]
    assert np.max(np.abs(got - want)) <= t["max_abs"]


def test_complex_multiply_in_place_device(queue, rng):
    a = random_complex(rng, (4, 32, 32))
    b = random_complex(rng, (32, 32))
    da = cla.to_device(queue, a)
    db = cla.to_device(queue, b)
    res = complex_multiply(da, db, out=da, queue=queue)
    assert res is da
    assert rel_l2(da.get(), a.astype(np.complex128) * b) <= tol("elementwise", np.complex64)["rel_l2"]


@pytest.mark.parametrize("dtype", DTYPES)
@pytest.mark.parametrize("shape", SHAPES)
def test_complex_scale(queue, cl_device, rng, shape, dtype):
    _skip_without_fp64(cl_device, dtype)
    a = random_complex(rng, shape, dtype)
    s = complex(rng.standard_normal(), rng.standard_normal())
    got = complex_scale(a, s, queue=queue)
    assert rel_l2(got, a.astype(np.complex128) * s) <= tol("elementwise", dtype)["rel_l2"]


@pytest.mark.parametrize("dtype", DTYPES)
@pytest.mark.parametrize("shape", [(5, 17), (3, 64, 48), (2, 3, 32, 32)])
def test_accumulate_intensity(queue, cl_device, rng, shape, dtype):
    _skip_without_fp64(cl_device, dtype)
    real = np.float32 if dtype == np.complex64 else np.float64
    u = random_complex(rng, shape, dtype)
    acc0 = rng.random(shape[-2:]).astype(real) + 0.5
    acc = acc0.copy()
    w = float(rng.random() + 0.1)
    accumulate_intensity(u, acc, weight=w, queue=queue)
    batch_axes = tuple(range(len(shape) - 2))
    want = acc0 + w * np.sum(np.abs(u.astype(np.complex128)) ** 2, axis=batch_axes)
    assert rel_l2(acc, want) <= tol("elementwise", dtype)["rel_l2"] * 10  # sums of B terms


def test_elementwise_bad_input(queue, rng):
    a = random_complex(rng, (8, 8))
    with pytest.raises(TypeError, match="a must be complex"):
        complex_multiply(a.real.copy(), a, queue=queue)
    with pytest.raises(TypeError, match="b has dtype"):
        complex_multiply(a, a.astype(np.complex128), queue=queue)
    with pytest.raises(ValueError, match="trailing axes"):
        complex_multiply(a, random_complex(rng, (4, 8)), queue=queue)
    with pytest.raises(TypeError, match="acc must be float32"):
        accumulate_intensity(a, np.zeros((8, 8)), queue=queue)
    with pytest.raises(ValueError, match="s must be finite"):
        complex_scale(a, complex(np.nan, 0), queue=queue)
