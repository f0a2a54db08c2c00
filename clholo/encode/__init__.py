"""Phase-only SLM patterns from complex holograms (HOLOGRAPHY.md section 8).

* :func:`sgd_encode`: SGD (Adam) with a complex-field loss, the paper's lab path.
* :func:`dpac_encode`: double-phase amplitude coding, direct.
* :mod:`clholo.encode.quantize`: wrap, 8-bit lookup tables (linear or measured), SLM-sized PNGs
  (its function ``quantize`` shares the module's name: call ``clholo.encode.quantize.quantize``).
* :func:`simulate_slm`: the quantised patterns back to holograms for :func:`clholo.focal_stack`.

Names and submodules are imported on first use, so that ``clholo encode --help`` (which
imports :mod:`clholo.commands.encode`) does not load the device code.
"""

import importlib as _importlib

_SUBMODULE = {
    "PhaseLUT": "quantize", "dequantize": "quantize", "fit_to_slm": "quantize",
    "parse_lut": "quantize", "parse_luts": "quantize", "read_luts": "quantize",
    "read_pattern_pngs": "quantize",
    "write_pattern_pngs": "quantize",
    "SGDResult": "sgd", "sgd_encode": "sgd",
    "dpac_encode": "dpac",
    "phase_to_hologram": "simulate", "simulate_slm": "simulate",
    "compare_encodings": "results",
}

__all__ = sorted(_SUBMODULE)


def __getattr__(name: str):
    sub = _SUBMODULE.get(name)
    if sub is not None:
        return getattr(_importlib.import_module(f"{__name__}.{sub}"), name)
    if not name.startswith("_"):  # a submodule: ``clholo.encode.quantize.quantize``
        try:
            return _importlib.import_module(f"{__name__}.{name}")
        except ModuleNotFoundError as exc:
            if exc.name != f"{__name__}.{name}":
                raise  # the submodule exists but one of its own imports is missing: say which
    raise AttributeError(f"module 'clholo.encode' has no attribute {name!r}")
