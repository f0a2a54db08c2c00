"""Phase-only SLM patterns from complex holograms (HOLOGRAPHY.md section 8).

* :func:`sgd_encode`: SGD (Adam) with a complex-field loss, the paper's lab path.
* :func:`dpac_encode`: double-phase amplitude coding, direct.
* :mod:`clholo.encode.quantize`: wrap, 8-bit lookup tables (linear or measured), SLM-sized PNGs.
* :func:`simulate_slm`: the quantised patterns back to holograms for :func:`clholo.focal_stack`.
"""

from .quantize import (PhaseLUT, dequantize, fit_to_slm, parse_lut, quantize,  # noqa: F401
                       read_pattern_pngs, write_pattern_pngs)
from .sgd import SGDResult, sgd_encode  # noqa: F401
from .dpac import dpac_encode  # noqa: F401
from .simulate import phase_to_hologram, simulate_slm  # noqa: F401
