"""Kernel arguments declared once, by name (pyopencl's ``VectorArg``/``ScalarArg`` model).

A :class:`KernelSignature` names a kernel's parameters in order, each a buffer or a scalar with
its NumPy dtype. Callers pass arguments by name (:meth:`KernelSignature.args`), so a call cannot
put ``layer`` where ``frame0`` belongs, and ``tests/test_kernel_hygiene.py`` checks every
declaration against the parameter list in the ``.cl`` source, so the two cannot drift. (The FFT's
arguments are declared in :mod:`clholo.fft`, which generates its C parameter lists from them.)
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Optional, Tuple

import numpy as np

__all__ = ["KernelSignature", "COMPOSITE_LAYER", "QUANTIZE_PHASE", "c_parameters"]

_C_SCALARS = {"uint": np.uint32, "int": np.int32, "ulong": np.uint64, "long": np.int64,
              "float": np.float32, "double": np.float64}


@dataclass(frozen=True)
class KernelSignature:
    """``file``'s kernel ``name`` with ``params``: ``(name, dtype)`` pairs, ``dtype`` ``None`` for
    a ``__global`` buffer."""

    file: str
    name: str
    params: Tuple[Tuple[str, Optional[type]], ...]

    def args(self, **values) -> list:
        """The positional argument list from ``values`` by parameter name (buffers as
        ``cl.Buffer``/``.data``; scalars cast to their declared dtype). Every parameter must be
        given, and nothing else."""
        names = [n for n, _ in self.params]
        missing = [n for n in names if n not in values]
        extra = sorted(set(values) - set(names))
        if missing or extra:
            raise TypeError(f"{self.name}: missing arguments {missing}, unknown {extra}")
        return [values[n] if dt is None else dt(values[n]) for n, dt in self.params]


COMPOSITE_LAYER = KernelSignature("composite.cl", "composite_layer", (
    ("u", None), ("color", None), ("alpha", None), ("npix", np.uint32),
    ("n_channels", np.uint32), ("layer", np.uint32), ("frame0", np.uint32),
    ("colour0", np.uint32), ("key_lo", np.uint32), ("key_hi", np.uint32),
    ("farthest", np.int32)))

QUANTIZE_PHASE = KernelSignature("quantize.cl", "quantize_phase", (
    ("phase", None), ("gray", None), ("bp", None), ("lv", None), ("guess", None),
    ("table", None), ("range", None), ("n_channels", np.uint32), ("flags", None)))


def c_parameters(source: str, name: str) -> Tuple[Tuple[str, Optional[type]], ...]:
    """The parameters of ``__kernel void name(...)`` in OpenCL C ``source``, as
    :attr:`KernelSignature.params` would declare them."""
    m = re.search(r"__kernel\s+void\s+" + re.escape(name) + r"\s*\(([^)]*)\)", source)
    if m is None:
        raise ValueError(f"no __kernel void {name}(...) in the source")
    out = []
    for raw in m.group(1).split(","):
        words = re.sub(r"/\*.*?\*/", " ", raw).replace("*", " * ").split()
        pname = words[-1]
        if "__global" in words or "global" in words or "*" in words:
            out.append((pname, None))
        else:
            ctype = [w for w in words[:-1] if w not in ("const", "__private")][-1]
            out.append((pname, _C_SCALARS[ctype]))
    return tuple(out)
