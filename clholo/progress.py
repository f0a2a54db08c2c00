"""One progress policy for every command: step lines, and progress while a long step runs.

The mode is decided once per run (:func:`resolve_mode`), from ``--progress`` or from the stream:

* ``bar`` (a terminal): one bar redrawn in place;
* ``lines`` (logs, CI, pipes, notebooks' captured output): a plain line with the count, the
  elapsed time and the rate at most every ``interval`` seconds, and always the last one, so that
  a long command never looks hung and a log holds no carriage returns;
* ``off``: step lines only (no ``what ...`` line before a step, no bar, no counts).

Library code never imports this module's printing: it takes a ``progress(done, total)``
callback, and a command passes :meth:`StepLog.tracker`.
"""

from __future__ import annotations

import sys
import time
import weakref
from typing import Callable, Optional, TextIO

__all__ = ["MODES", "resolve_mode", "StepLog", "end_open_lines"]

MODES = ("auto", "bar", "lines", "off")

# StepLogs that may have a bar drawn without its newline: the error boundary ends those lines
# before it prints, so an error never lands glued onto a half-drawn bar.
_LIVE: "weakref.WeakSet[StepLog]" = weakref.WeakSet()


def resolve_mode(mode: str, stream: TextIO) -> str:
    """``bar``, ``lines`` or ``off`` for ``mode`` in :data:`MODES` (``auto``: a bar on a
    terminal, lines elsewhere)."""
    if mode not in MODES:
        from clholo.errors import InputError

        raise InputError(f"progress must be one of {', '.join(MODES)}, got {mode!r}")
    if mode != "auto":
        return mode
    return "bar" if bool(getattr(stream, "isatty", lambda: False)()) else "lines"


class StepLog:
    """Prints ``[ 1.23 s] what ...`` lines, and progress while a long step runs.

    Parameters
    ----------
    stream : file, optional
        Where to print (default ``sys.stdout``).
    interval : float
        Seconds between two progress lines in ``lines`` mode.
    mode : {"auto", "bar", "lines", "off"}
        See the module docstring; decided once, here.
    """

    def __init__(self, stream: Optional[TextIO] = None, *, interval: float = 2.0,
                 mode: str = "auto"):
        self.stream = stream if stream is not None else sys.stdout
        self.t0 = time.perf_counter()
        self.interval = float(interval)
        self.mode = resolve_mode(mode, self.stream)
        self._last_line = -float("inf")
        self._open = False
        _LIVE.add(self)

    def _print(self, text: str, *, end: str = "\n") -> None:
        self.end_line()
        print(text, end=end, file=self.stream, flush=True)

    def end_line(self) -> None:
        """End a bar's line if one is open (before any other output)."""
        if self._open:
            self._open = False
            print(file=self.stream, flush=True)

    def start(self, message: str) -> None:
        """Say what a long step is about to do (its ``step`` line follows when it is done).

        Progress, not a step: nothing in ``off`` mode, which shows the step lines only."""
        if self.mode == "off":
            return
        self._print(f"[{'':9}] {message} ...")
        self._last_line = time.perf_counter()

    def step(self, message: str, seconds: float) -> None:
        """Say what a step did and how long it took."""
        self._print(f"[{seconds:7.2f} s] {message}")

    def note(self, message: str) -> None:
        """A line of information that is not a timed step."""
        self._print(f"{'':12}{message}")

    def progress(self, label: str, done: int, total: int, t_start: float) -> None:
        """Show that ``done`` of ``total`` ``label`` are finished, ``t_start`` being when the
        step began (``time.perf_counter()``)."""
        if self.mode == "off":
            return
        elapsed = time.perf_counter() - t_start
        if self.mode == "bar":
            width = 30
            filled = int(width * done / max(total, 1))
            print(f"\r  {label} [{'#' * filled}{'.' * (width - filled)}] {done}/{total} "
                  f"{elapsed:6.1f} s", end="", file=self.stream, flush=True)
            self._open = True
            if done >= total:
                self.end_line()
            return
        now = time.perf_counter()
        if done < total and now - self._last_line < self.interval:
            return
        rate = f", {elapsed / done:.2f} s each" if done else ""
        self._print(f"  {label}: {done}/{total} after {elapsed:.1f} s{rate}")
        self._last_line = now

    def tracker(self, label: str, total: Optional[int] = None) -> Callable[[int, int], None]:
        """A ``progress(done, total)`` callback for library code, timed from now."""
        t_start = time.perf_counter()

        def update(done: int, total_now: Optional[int] = None) -> None:
            self.progress(label, int(done), int(total_now if total_now is not None else total),
                          t_start)
        return update


def end_open_lines() -> None:
    """End every half-drawn progress line (the error boundary calls this before it prints)."""
    for log in list(_LIVE):
        log.end_line()
