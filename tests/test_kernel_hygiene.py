"""Kernel builds are silent: a non-empty compiler log is printed by pyopencl on every run
(``CompilerWarning: Non-empty compiler output``), and users rightly take it for a fault.

The known cause was clang's ``-Wpsabi`` note on CPUs without AVX-512: a 16-wide vector returned
by value from a helper function changes the calling convention. The lint test keeps that
construct out of the kernels (it cannot be reproduced on an AVX-512 machine, where clang stays
quiet, and PoCL's wheel ignores POCL_CPU_VARIANT, so no test here can build for an AVX2 target).
"""

import re
from pathlib import Path

import numpy as np
import pytest

from clholo.host import runtime

KERNELS = Path(runtime.kernel_dir())

# helper functions returning vectors of 64 bytes or more (float16, double8/16, or the FFT's
# working vector type vt, which is float16 in the CPU variant)
WIDE_RETURN = re.compile(
    r"^\s*(?:static\s+)?(?:inline\s+)?(?:float16|double8|double16|vt)\s+\w+\s*\(", re.M)


def test_no_helper_returns_a_wide_vector_by_value():
    offenders = []
    for path in sorted(KERNELS.glob("*.cl")) + sorted(KERNELS.glob("*.h")):
        for m in WIDE_RETURN.finditer(path.read_text()):
            line = path.read_text()[:m.start()].count("\n") + 1
            offenders.append(f"{path.name}:{line}: {m.group(0).strip()}")
    assert not offenders, ("pass wide vectors by pointer (see fft_cpu.cl finish()): "
                           + "; ".join(offenders))


def test_declared_kernel_arguments_match_the_c_source():
    """A kernel's arguments are declared once (host/kernel_args.py) and called by name; the
    declaration must be the .cl file's parameter list, name for name and type for type."""
    from clholo.host import runtime
    from clholo.host.kernel_args import COMPOSITE_LAYER, QUANTIZE_PHASE, c_parameters

    for sig in (COMPOSITE_LAYER, QUANTIZE_PHASE):
        source = runtime.read_kernel_source(sig.file)
        assert c_parameters(source, sig.name) == sig.params, sig.name
    with pytest.raises(TypeError, match="missing arguments"):
        COMPOSITE_LAYER.args(u=None)


def test_the_signature_check_sees_a_swapped_parameter():
    from clholo.host.kernel_args import c_parameters

    src = "__kernel void k(__global float2 *u, const uint layer, const uint frame0) {}"
    assert c_parameters(src, "k") == (("u", None), ("layer", np.uint32), ("frame0", np.uint32))
    swapped = src.replace("const uint layer, const uint frame0", "const uint frame0, const uint layer")
    assert c_parameters(swapped, "k") != c_parameters(src, "k")
