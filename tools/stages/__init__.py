"""Motion stages of the lab bench: one Stage interface, Thorlabs APT and Newport CONEX drivers,
and byte-protocol simulators (:mod:`clholo.tools.stages.simulators`)."""

from __future__ import annotations

from .base import (HomingTimeoutError, Stage, StageClosedError, StageCommandError, StageError,
                   StageLimitError, StageNotReferencedError, StageProtocolError,
                   StageTimeoutError)

__all__ = ["open_stage", "Stage", "StageError", "StageTimeoutError", "HomingTimeoutError",
           "StageProtocolError", "StageLimitError", "StageNotReferencedError",
           "StageCommandError", "StageClosedError", "STAGE_KINDS"]

STAGE_KINDS = ("apt", "conex")


def open_stage(port: str, kind: str = "apt", **settings) -> Stage:
    """Open a stage on ``port`` (anything ``serial.serial_for_url`` takes: ``/dev/ttyUSB0``,
    ``COM3``, a pty's name).

    Parameters
    ----------
    port : str
        Serial port or pyserial URL.
    kind : {"apt", "conex"}
        ``"apt"``: Thorlabs KDC101/TDC001 (see :class:`~clholo.tools.stages.apt.AptStage` for
        settings such as ``counts_per_mm``); ``"conex"``: Newport CONEX-AGP
        (:class:`~clholo.tools.stages.conex.ConexStage`).
    **settings
        Passed to the driver.
    """
    from clholo.errors import InputError, InputTypeError

    if not isinstance(port, str):
        raise InputTypeError(f"port must be a serial port name or pyserial URL (a str), got "
                             f"{port!r}: e.g. open_stage('/dev/ttyUSB0')")
    if not port.strip():
        raise InputError(f"port = {port!r} is empty: give the controller's serial port, e.g. "
                         f"open_stage('/dev/ttyUSB0') (or COM3, or a pyserial URL)")
    if kind == "apt":
        from .apt import AptStage

        return AptStage(port, **settings)
    if kind == "conex":
        from .conex import ConexStage

        return ConexStage(port, **settings)
    raise ValueError(f"kind must be one of {STAGE_KINDS}, got {kind!r}")
