"""The one tolerance table: the test suite and ``clholo selftest`` compare kernels with it.

Every comparison of an OpenCL kernel against ``clholo.reference`` takes its tolerance from here,
keyed by what is compared and the precision it runs in (``tests/tolerances.py`` re-exports this
module, so the tests and the self-test users run on their own device share one table). Relative errors are L2 norms:
``||got - want|| / ||want||``; ``max_abs`` are absolute maxima on values of order one.
"""

TOLERANCES = {
    # elementwise complex arithmetic: a handful of roundings per element
    ("elementwise", "float32"): {"rel_l2": 1e-6, "max_abs": 1e-5},
    ("elementwise", "float64"): {"rel_l2": 1e-14, "max_abs": 1e-13},
    # random phases are specified bit for bit
    ("random_phase", "float32"): {"rel_l2": 0.0, "max_abs": 0.0},
    # FFT: peers reach 1.5-2e-7 at 2048^2 in complex64; we allow 3x that and a little growth
    ("fft", "float32"): {"rel_l2": 6e-7, "max_abs": None},
    ("fft", "float64"): {"rel_l2": 1e-14, "max_abs": None},
    # ASM propagation (FFT + transfer function + FFT) in complex64 against complex128
    ("propagate", "float32"): {"rel_l2": 2e-5, "max_abs": None},
    ("propagate", "float64"): {"rel_l2": 1e-12, "max_abs": None},
    # ASM transfer function in complex64 against complex128 (|H| = 1): the phase in double
    # (device fp64, or the host without it), then one float32 sine and its rounding: 1.9e-7
    # measured from 1 mm to 1 m on 8192-point grids
    ("transfer_function", "float32"): {"rel_l2": None, "max_abs": 5e-7},
    # whole MPI hologram (L layers of propagate + composite) in complex64 against complex128
    ("hologram", "float32"): {"rel_l2": 1e-4, "max_abs": None},
    # compositing kernel (phase drawn in place, sqrt, complex fma)
    ("composite", "float32"): {"rel_l2": 2e-6, "max_abs": 1e-5},
    # splat rasterisation and layer compositing in float32
    ("raster", "float32"): {"rel_l2": 1e-5, "max_abs": 1e-4},
    # random-phase wave splatting: K primitives (composite over a box + propagate), complex64
    # against complex128; like "hologram" with one layer per primitive
    ("rpws", "float32"): {"rel_l2": 1e-4, "max_abs": None},
    # views.cl per-pixel kernels (pupil mask times tf, STFT windows, |.|^2 accumulation):
    # a product or a cosine per element; max_abs on values of order one (relative for sums)
    ("views", "float32"): {"rel_l2": 1e-6, "max_abs": 1e-5},
    # pupil view and STFT light field (two FFTs / one FFT, |.|^2, frame mean) in complex64
    # against complex128 (an intensity: about twice the field's relative error)
    ("pupil_view", "float32"): {"rel_l2": 5e-5, "max_abs": None},
    ("light_field", "float32"): {"rel_l2": 5e-6, "max_abs": None},
    ("rayoptics", "float32"): {"rel_l2": 2e-6, "max_abs": 2e-5},
    # kernels/fast_sincos.h against float64: a polynomial on [-pi/4, pi/4] after a three-part
    # reduction by pi/2: 9.5e-8 measured, like the builtin sincos (9.4e-8); 1.5e-7 leaves
    # room for another compiler's contraction of the multiply-adds
    ("fast_sincos", "float32"): {"rel_l2": None, "max_abs": 1.5e-7},
}


def tol(kind: str, dtype) -> dict:
    """Tolerances for ``kind`` at the real precision of ``dtype`` (complex64 -> float32)."""
    import numpy as np

    real = np.dtype(np.finfo(np.dtype(dtype)).dtype).name
    return TOLERANCES[(kind, real)]


def rel_l2(got, want) -> float:
    import numpy as np

    got = np.asarray(got, dtype=np.complex128)
    want = np.asarray(want, dtype=np.complex128)
    denom = np.linalg.norm(want.ravel())
    return float(np.linalg.norm((got - want).ravel()) / (denom if denom > 0 else 1.0))
# phase-only encodings (kernels/encode.cl) in float32 against float64
TOLERANCES.update({
    # exp(i P), arg(u), DPAC phases: a few ulps of sincos/atan2/acos per element (radians)
    ("encode_elementwise", "float32"): {"rel_l2": 1e-6, "max_abs": 2e-5},
    # SGD loss, scale and phase gradient: two propagations and per-field sums in float32
    ("encode_gradient", "float32"): {"rel_l2": 2e-4, "max_abs": 1e-4},
    # one Adam step given the same gradient and state
    ("encode_adam", "float32"): {"rel_l2": 1e-6, "max_abs": 1e-5},
    # the largest |u| per field (field_max_abs2 + field_max_abs): a maximum is exact in any
    # order, so bit for bit sqrt of the largest |u|^2 as the device's cabs2 rounds it, whatever
    # the split
    ("encode_max", "float32"): {"rel_l2": 0.0, "max_abs": 0.0},
    # 8-bit quantisation (kernels/quantize.cl): gray levels bit for bit the host's (max_abs in
    # levels), error flags equal
    ("quantize", "float32"): {"rel_l2": 0.0, "max_abs": 0.0},
    # two forms of one computation that promise the same bits: field_sums_lanes against
    # field_sums, an even multiply laid out strip by strip (EvenFactors) against the plain one
    ("same_bits", "float32"): {"rel_l2": 0.0, "max_abs": 0.0},
})
