"""Argument types shared by the benchmark scripts: a mistake in a command line is refused by
argparse before anything is built or measured (``argument --size: must be a whole number >= 1,
got '0'``), not found as a traceback, a division by zero or an empty median minutes later on a
lent GPU.

The scripts import it from their own folder (``python benchmarks/x.py`` puts that folder first
on ``sys.path``; a script loaded by path, as the tests load them, puts it there itself).
"""

from __future__ import annotations

import argparse
import math
import os
from pathlib import Path
from typing import Callable, Iterable, List, Tuple, Union

def _bad(text: str, rule: str) -> argparse.ArgumentTypeError:
    return argparse.ArgumentTypeError(f"must be {rule}, got {text!r}")


def _int(text: str, rule: str) -> int:
    try:
        return int(str(text).strip())
    except ValueError:
        raise _bad(text, rule) from None


def positive_int(text: str) -> int:
    """A whole number >= 1 (sizes, layers, frames, repeats, rounds, iterations)."""
    value = _int(text, "a whole number >= 1")
    if value < 1:
        raise _bad(text, "a whole number >= 1")
    return value


def at_least(low: int) -> Callable[[str], int]:
    """A whole number >= ``low``."""
    rule = f"a whole number >= {low}"

    def check(text: str) -> int:
        value = _int(text, rule)
        if value < low:
            raise _bad(text, rule)
        return value

    check.__name__ = f"at_least_{low}"
    return check


def positive_float(text: str) -> float:
    """A finite number > 0 (seconds, metres)."""
    rule = "a finite number > 0"
    try:
        value = float(text)
    except ValueError:
        raise _bad(text, rule) from None
    if not math.isfinite(value) or value <= 0:
        raise _bad(text, rule)
    return value


def pad(text: str) -> Union[str, float]:
    """A propagation's padding: ``auto`` or a finite factor >= 1."""
    rule = "'auto' or a finite factor >= 1 (such as 2)"
    if str(text).strip() == "auto":
        return "auto"
    try:
        value = float(text)
    except ValueError:
        raise _bad(text, rule) from None
    if not math.isfinite(value) or value < 1:
        raise _bad(text, rule)
    return value


def _dims(text: str, rule: str) -> Tuple[int, ...]:
    parts = str(text).strip().lower().split("x")
    try:
        dims = tuple(int(p) for p in parts)
    except ValueError:
        raise _bad(text, rule) from None
    if any(d < 1 for d in dims):
        raise _bad(text, rule)
    return dims


def shape(text: str) -> Tuple[int, int]:
    """``HxW``, both whole numbers >= 1 (``1080x1920``)."""
    rule = "HxW such as 1080x1920, both >= 1"
    dims = _dims(text, rule)
    if len(dims) != 2:
        raise _bad(text, rule)
    return dims  # type: ignore[return-value]


def _fft_checked(dims: Tuple[int, ...], text: str) -> Tuple[int, ...]:
    from clholo.fft import MAX_SIZE, is_fft_size, next_fft_size, prev_fft_size

    for n in dims:
        if not is_fft_size(n) or n > MAX_SIZE:
            near = sorted({prev_fft_size(min(n, MAX_SIZE)), min(next_fft_size(n), MAX_SIZE)})
            raise argparse.ArgumentTypeError(
                f"{text!r}: {n} is not a size clholo.fft takes (2^a 3^b 5^c, 1 to {MAX_SIZE}); "
                f"nearest: {' or '.join(map(str, near))}")
    return dims


def fft_size(text: str) -> int:
    """``N``: a size the FFT takes (``2^a 3^b 5^c`` up to ``clholo.fft.MAX_SIZE``)."""
    dims = _dims(text, "a size N such as 1024")
    if len(dims) != 1:
        raise _bad(text, "a size N such as 1024")
    return _fft_checked(dims, text)[0]


def fft_shape(text: str) -> Tuple[int, int]:
    """``N`` (``N x N``) or ``HxW``, sizes the FFT takes (``2^a 3^b 5^c`` up to
    ``clholo.fft.MAX_SIZE``)."""
    rule = "N or HxW such as 1024 or 1080x1920"
    dims = _dims(text, rule)
    if len(dims) == 1:
        dims = (dims[0], dims[0])
    if len(dims) != 2:
        raise _bad(text, rule)
    return _fft_checked(dims, text)  # type: ignore[return-value]


def fft_shapes(text: str) -> List[Tuple[int, int]]:
    """Comma-separated :func:`fft_shape` entries; ``''`` for none."""
    return [fft_shape(s) for s in str(text).split(",") if s.strip()]


def batch(text: str) -> Tuple[int, int, int]:
    """``BxN``: a batch of ``B`` transforms of ``N x N``; ``(0, 0, 0)`` for ``''`` (none)."""
    if not str(text).strip():
        return (0, 0, 0)
    dims = _dims(text, "BxN such as 8x1024, or '' for none")
    if len(dims) != 2:
        raise _bad(text, "BxN such as 8x1024, or '' for none")
    _fft_checked(dims[1:], text)
    return (dims[0], dims[1], dims[1])


def names(choices: Iterable[str], *, allow_empty: bool = True) -> Callable[[str], List[str]]:
    """Comma-separated names, each one of ``choices`` (an unknown one is refused, naming the
    choices: a typo must not silently select nothing)."""
    choices = list(choices)

    def check(text: str) -> List[str]:
        got = [n.strip() for n in str(text).split(",") if n.strip()]
        unknown = [n for n in got if n not in choices]
        if unknown:
            raise argparse.ArgumentTypeError(
                f"unknown {', '.join(map(repr, unknown))}; choose from {', '.join(choices)}")
        if not got and not allow_empty:
            raise argparse.ArgumentTypeError(f"names nothing; choose from {', '.join(choices)}")
        return got

    check.__name__ = "names"
    return check


def output_file(text: str) -> str:
    """A file to write at the end: its folder must exist now (checked before any measuring)
    and it must not be a folder."""
    path = Path(text)
    if path.is_dir():
        raise argparse.ArgumentTypeError(f"{text} is a folder; give a file's path")
    parent = path.parent if str(path.parent) else Path(".")
    if not parent.is_dir():
        raise argparse.ArgumentTypeError(f"{text}: its folder {parent} does not exist; "
                                         f"create it first")
    if not os.access(parent, os.W_OK):
        raise argparse.ArgumentTypeError(f"{text}: its folder {parent} is not writable")
    return text


def ms(value: float) -> str:
    """Milliseconds with 3 significant digits (``0.0263``, ``2.63``, ``263``, ``2630``): a
    GPU's 0.026 ms must not print as 0.03, nor 0.004 as 0.00."""
    if not math.isfinite(value):
        return str(value)
    if value == 0:
        return "0"
    digits = max(0, 2 - int(math.floor(math.log10(abs(value)))))
    return f"{value:.{digits}f}"
