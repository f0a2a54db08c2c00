"""The one interface every motion stage of the bench implements, and its named errors.

A stage moves along one axis in millimetres. Every wait has a timeout; when a wait fails the
driver tells the controller to stop before it raises, so that a fault never leaves a motor
running.
"""

from __future__ import annotations

import abc
import time
from typing import Callable, Optional, Tuple

__all__ = ["Stage", "StageError", "StageTimeoutError", "HomingTimeoutError",
           "StageProtocolError", "StageLimitError", "StageNotReferencedError",
           "StageCommandError", "wait_for"]


class StageError(RuntimeError):
    """Base class of every stage fault."""


class StageTimeoutError(StageError, TimeoutError):
    """A reply or a motion did not arrive within its timeout (the stage was told to stop)."""


class HomingTimeoutError(StageTimeoutError):
    """Homing did not finish within its timeout (the stage was told to stop)."""


class StageProtocolError(StageError):
    """A reply could not be decoded (garbled bytes, wrong message, wrong length)."""


class StageLimitError(StageError):
    """The stage hit a limit switch or reports an end-of-run error (it was told to stop)."""


class StageNotReferencedError(StageError):
    """The controller refuses to move before it is homed: call ``home()`` first."""


class StageCommandError(StageError):
    """The controller reported an error for the last command (its code and text are kept).

    Parameters
    ----------
    message : str
        The controller's text.
    code : str
        Its error code.
    """

    def __init__(self, message: str, code: str = ""):
        super().__init__(message)
        self.code = code


def wait_for(predicate: Callable[[], bool], *, timeout: float, poll: float,
             what: str, on_timeout: Optional[Callable[[], None]] = None,
             error: type = StageTimeoutError) -> None:
    """Call ``predicate`` every ``poll`` seconds until it returns True; after ``timeout`` seconds
    call ``on_timeout`` (e.g. stop the motor) and raise ``error`` naming ``what``."""
    deadline = time.monotonic() + timeout
    while True:
        if predicate():
            return
        if time.monotonic() >= deadline:
            if on_timeout is not None:
                try:
                    on_timeout()
                except StageError:
                    pass  # the timeout is the fault to report; the stop was best effort
            raise error(f"{what} did not finish within {timeout:g} s; the stage was told to stop")
        time.sleep(poll)


class Stage(abc.ABC):
    """One motorised axis, positions in millimetres.

    Use as a context manager (``with open_stage(...) as z:``) so that ``close()`` runs.
    ``limits`` are the travel range the driver allows, ``(low, high)`` in mm; a target outside
    is refused with ``ValueError`` before anything is sent.
    """

    #: travel range in mm, set by each driver
    _limits: Tuple[float, float] = (float("-inf"), float("inf"))

    @property
    def limits(self) -> Tuple[float, float]:
        """``(low, high)``: the travel range in mm."""
        return self._limits

    def _check_target(self, target_mm: float, *, name: str = "position_mm") -> float:
        from clholo.validate import real_scalar

        target = real_scalar(name, target_mm)
        low, high = self.limits
        if not low <= target <= high:
            raise ValueError(f"{name}={target:g} mm is outside the stage's travel "
                             f"[{low:g}, {high:g}] mm: give a position inside it")
        return target

    @abc.abstractmethod
    def home(self, *, timeout: float = 60.0) -> None:
        """Find the reference switch; raises :class:`HomingTimeoutError` after ``timeout`` s."""

    @abc.abstractmethod
    def move_to(self, position_mm: float, *, wait: bool = True, timeout: float = 30.0) -> None:
        """Move to ``position_mm`` (mm); with ``wait`` block until the move completes.

        Parameters
        ----------
        position_mm : float
            Target position, millimetres.
        wait : bool
            Block until the move completes.
        timeout : float
            Seconds to wait at most (then :class:`StageTimeoutError`).
        """

    def move_by(self, distance_mm: float, *, wait: bool = True, timeout: float = 30.0) -> None:
        """Move by ``distance_mm`` (mm) from the current position.

        Parameters
        ----------
        distance_mm : float
            Distance, millimetres (negative moves back).
        wait : bool
            Block until the move completes.
        timeout : float
            Seconds to wait at most (then :class:`StageTimeoutError`).
        """
        from clholo.validate import real_scalar

        distance = real_scalar("distance_mm", distance_mm)
        self._check_target(self.position() + distance, name="position + distance_mm")
        self._move_relative(distance, wait=wait, timeout=timeout)

    @abc.abstractmethod
    def _move_relative(self, distance_mm: float, *, wait: bool, timeout: float) -> None:
        """Driver's relative move (target already checked against the limits)."""

    @abc.abstractmethod
    def position(self) -> float:
        """The current position in mm."""

    @abc.abstractmethod
    def is_moving(self) -> bool:
        """True while the axis moves or homes."""

    def wait_until_stopped(self, *, timeout: float = 30.0, poll: float = 0.05) -> None:
        """Block until :meth:`is_moving` is False; raise :class:`StageTimeoutError` after
        ``timeout`` s (and stop the stage).

        Parameters
        ----------
        timeout : float
            Seconds to wait at most.
        poll : float
            Seconds between checks.
        """
        wait_for(lambda: not self.is_moving(), timeout=timeout, poll=poll, what="motion",
                 on_timeout=self.stop)

    @abc.abstractmethod
    def stop(self) -> None:
        """Stop any motion now."""

    @abc.abstractmethod
    def close(self) -> None:
        """Release the port (the motor is stopped first if it moves)."""

    def __enter__(self) -> "Stage":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
