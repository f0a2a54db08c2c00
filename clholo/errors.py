"""The exceptions clholo raises for foreseeable conditions, and the exit code of each.

Every command runs inside one error boundary (:func:`clholo.cli.main`): an exception of a family
below becomes one line ``clholo CMD: error: ...`` and its exit code; anything else is a bug and is
reported as an internal error with its traceback (exit :attr:`ExitCode.INTERNAL`); ``--debug``
adds the full traceback of any error and keeps its exit code; SIGTERM is handled as Ctrl-C.
Library code raises these (or the built-in families they derive from, so ``except ValueError``
keeps working for Python users); it never exits or prints.

===========  ====  ===================================================================
name         code  when
===========  ====  ===================================================================
OK           0     done
FAILED       1     the command ran, and what it checked or produced failed (a self-test
                   check, a batch item)
USAGE        2     bad options, values, units or input files; an output that may not be
                   written; fix the command line or the file
ENVIRONMENT  3     this machine cannot do it: no OpenCL device, kernels that do not build,
                   no display server, an optional extra not installed, hardware that does
                   not answer, not enough memory on the device
INTERNAL     70    a bug in clholo (the traceback is printed; please report it)
INTERRUPTED  130   Ctrl-C or SIGTERM; the command says what it kept
===========  ====  ===================================================================
"""

from __future__ import annotations

import enum

__all__ = ["ExitCode", "ClholoError", "InputError", "InputTypeError", "OutputRefused",
           "EnvironmentProblem", "NoDisplayError", "NoDoublePrecisionError", "MissingExtraError",
           "CommandFailed"]


class ExitCode(enum.IntEnum):
    """How a ``clholo`` command ends (``docs/errors.md``): 0 done, 1 a check or item failed,
    2 bad input or options, 3 this machine cannot (no device, display, memory or extra), 70 an
    internal error (a bug), 130 interrupted.
    """
    OK = 0
    FAILED = 1
    USAGE = 2
    ENVIRONMENT = 3
    INTERNAL = 70
    INTERRUPTED = 130


class ClholoError(Exception):
    """Base of clholo's foreseeable conditions; ``exit_code`` says how a command ends."""

    exit_code = ExitCode.USAGE


class InputError(ClholoError, ValueError):
    """A value, unit, option or input file that clholo cannot take (the message names it and
    says what to give instead)."""


class InputTypeError(ClholoError, TypeError):
    """A value of the wrong type (a string for a number, a float for a count)."""


class OutputRefused(ClholoError, FileExistsError):
    """An output path that clholo may not write: it would replace something clholo did not
    write, or something foreign is inside a folder it would replace."""


class EnvironmentProblem(ClholoError, RuntimeError):
    """This machine cannot do what was asked (the message says what to install or change)."""

    exit_code = ExitCode.ENVIRONMENT


class NoDisplayError(EnvironmentProblem):
    """A window was asked for and there is no display server."""


class MissingExtraError(EnvironmentProblem, ImportError):
    """An optional dependency is not installed (the message names the pip extra)."""


class NoDoublePrecisionError(EnvironmentProblem, TypeError):
    """complex128/float64 data on an OpenCL device without fp64 (a ``TypeError`` too, so
    ``except TypeError`` around a dtype keeps working)."""


class CommandFailed(ClholoError):
    """The command ran and what it checked or produced failed; its report says what."""

    exit_code = ExitCode.FAILED


def require_extra(module: str, extra: str, what: str):
    """Import ``module`` or raise :class:`MissingExtraError` naming the pip extra that has it."""
    import importlib

    try:
        return importlib.import_module(module)
    except ImportError as exc:
        raise MissingExtraError(
            f"{what} needs the Python package {module!r} ({exc}); install it with "
            f"pip install 'clholo[{extra}]'") from None
