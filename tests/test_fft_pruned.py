"""The CPU strips' pruned stages (kernels/fft_cpu.cl, FFT_PRUNE): a transform whose input is
zero from N / 2 on runs its first stage on the nonzero half alone, and one whose outputs from
N / 2 on nobody reads skips them in its last radix-8 stage. Checked against NumPy and bit for
bit against the same plans built with FFT_PRUNE 0 (the zeros read and added), at the edges of
the rule (N / 2 - 1, N / 2 and N / 2 + 1 elements), for every first radix (2, 4, 8: lengths
2^(3k+1), 2^(3k+2), 2^(3k)), lengths with factors 3 and 5, line counts that are not a multiple
of a strip, both precisions, 1D, 2D (rows and columns) and round trips (the propagation's
pad 2 and crop)."""

import numpy as np
import pyopencl.array as cla
import pytest

from clholo import fft as F
from clholo import reference as ref
from clholo.host import runtime
from conftest import random_complex
from tolerances import rel_l2, tol

# first stage radix 2 (16, 128), 4 (32, 256), 8 (64, 512); even lengths with factors 3 and 5
# (24 = 8 3, 40 = 8 5, 12 = 4 3, 6 = 2 3, 90 = 2 9 5, 360 = 8 9 5)
LENGTHS = [16, 32, 64, 128, 256, 512, 24, 40, 12, 6, 90, 360]


def _edges(n):
    """(elements loaded, elements kept) pairs around the rule's n / 2."""
    h = n // 2
    return [(h, n), (h - 1, n), (h + 1, n), (n, h), (n, h - 1), (n, h + 1), (h, h),
            (h - 1, h - 1)]


def _both(monkeypatch, build):
    """build() with the pruned stages and without them: (pruned result, plain result)."""
    outs = []
    for prune in (True, False):
        monkeypatch.setattr(F, "_CPU_PRUNE", prune)
        outs.append(build())
    return outs


def _dtypes(cl_device):
    return [np.complex64] + ([np.complex128] if runtime.has_fp64(cl_device) else [])


def _poisoned(queue, shape, dtype):
    out = cla.empty(queue, shape, dtype)
    out.fill(np.array(np.nan + 1j * np.nan, dtype=dtype))
    return out


@pytest.mark.parametrize("n", LENGTHS)
def test_1d_transforms_of_half_zero_inputs_and_half_read_outputs(queue, cl_device, rng,
                                                                  monkeypatch, n):
    for dtype in _dtypes(cl_device):
        for nin, nout in _edges(n):
            a = random_complex(rng, (2, 11, nin), dtype)
            padded = np.zeros((2, 11, n), np.complex128)
            padded[..., :nin] = a

            def run(inverse):
                plan = F.FFTPlan((2, 11, n), dtype, queue=queue, axes=(-1,),
                                 input_shape=(nin,), output_shape=(nout,), variant="cpu")
                return plan.execute(cla.to_device(queue, a), inverse=inverse,
                                    out=_poisoned(queue, (2, 11, nout), dtype)).get()

            for inverse, want in ((False, np.fft.fft(padded)), (True, np.fft.ifft(padded))):
                pruned, plain = _both(monkeypatch, lambda: run(inverse))
                what = f"n={n} in={nin} out={nout} inverse={inverse} {np.dtype(dtype).name}"
                assert np.isfinite(pruned).all(), what
                assert rel_l2(pruned, want[..., :nout]) <= tol("fft", dtype)["rel_l2"], what
                np.testing.assert_array_equal(pruned, plain, err_msg=what)


@pytest.mark.parametrize("shape", [(64, 128), (48, 40), (90, 24), (32, 512)])
def test_2d_padded_and_cropped_rows_and_columns(queue, rng, monkeypatch, shape):
    # the propagation's window: the top-left (H/2, W/2) in, the same window out; columns run
    # several strips per work-item, rows one (fft_cpu.cl's two load paths)
    H, W = shape
    for (h, w), (oh, ow) in (((H // 2, W // 2), (H // 2, W // 2)),
                             ((H // 2 - 1, W // 2 + 1), (H // 2 + 1, W // 2 - 1))):
        a = random_complex(rng, (3, h, w))
        padded = np.zeros((3, H, W), np.complex128)
        padded[:, :h, :w] = a

        def run(inverse):
            plan = F.FFTPlan((3, H, W), np.complex64, queue=queue, input_shape=(h, w),
                             output_shape=(oh, ow), variant="cpu")
            return plan.execute(cla.to_device(queue, a), inverse=inverse,
                                out=_poisoned(queue, (3, oh, ow), np.complex64)).get()

        for inverse, want in ((False, np.fft.fft2(padded)), (True, np.fft.ifft2(padded))):
            pruned, plain = _both(monkeypatch, lambda: run(inverse))
            what = f"{shape} in={(h, w)} out={(oh, ow)} inverse={inverse}"
            assert np.isfinite(pruned).all(), what
            assert rel_l2(pruned, want[:, :oh, :ow]) <= tol("fft", np.complex64)["rel_l2"], what
            np.testing.assert_array_equal(pruned, plain, err_msg=what)


@pytest.mark.parametrize("axis", ["rows", "cols"])
@pytest.mark.parametrize("first", ["forward", "inverse"])
def test_round_trips_at_pad_2_with_the_crop(queue, cl_device, rng, monkeypatch, axis, first):
    # lines of L values on a grid of n, cropped to mid between the transforms and to L at the
    # store. n = 2 L: every transform of the round trip is pruned on one side (the column
    # kernel's); L = n, mid = n / 2: the first reads all, the second half (the row kernel's);
    # the edges n / 2 +- 1 on either side.
    for dtype in _dtypes(cl_device):
        for L, n, other, mid in ((32, 64, 19, 32), (45, 90, 9, 45), (64, 128, 24, 31),
                                 (20, 40, 8, 11), (64, 64, 10, 32), (40, 40, 12, 21),
                                 (48, 96, 10, None), (33, 64, 9, 64)):
            shape = (2, other, L) if axis == "rows" else (2, L, other)
            x = random_complex(rng, shape, dtype)
            m = random_complex(rng, (1,) + ((other, n) if axis == "rows" else (n, other)),
                               dtype)

            def run():
                plan = F.RoundTripPlan(shape, n, axis=axis, first=first, mid_n=mid,
                                       queue=queue, variant="cpu", dtype=dtype)
                out = _poisoned(queue, shape, dtype)
                return plan.execute(cla.to_device(queue, x), out=out,
                                    multiply=cla.to_device(queue, m)).get()

            pruned, plain = _both(monkeypatch, run)
            want = ref.round_trip(x, n, axis=axis, first=first, multiply=m, mid_n=mid)
            what = f"{axis} {first} L={L} mid={mid} {np.dtype(dtype).name}"
            assert np.isfinite(pruned).all(), what
            assert rel_l2(pruned, want) <= tol("fft", dtype)["rel_l2"], what
            np.testing.assert_array_equal(pruned, plain, err_msg=what)
