"""``clholo`` command line: the command registry and the one error boundary.

Commands live in :mod:`clholo.commands` (one module each, listed in
:data:`clholo.commands.COMMAND_MODULES`). :func:`main` parses, runs the command, and maps what
it raises to one line and an exit code (:class:`clholo.errors.ExitCode`, ``docs/errors.md``):

* a foreseeable condition (bad input, an output that may not be written, no device, no
  display, not enough memory, Ctrl-C) is one line ``clholo CMD: error: ...``;
* anything else is a bug: its traceback and ``clholo CMD: internal error`` (exit 70);
* Ctrl-C and SIGTERM: one line ``clholo CMD: interrupted; ...`` and exit 130;
* ``--debug`` adds the full traceback of any error, and keeps the documented exit code.
"""

from __future__ import annotations

import argparse
import contextlib
import difflib
import errno
import importlib
import os
import re
import signal
import sys
import threading
from typing import List, Optional

from clholo.commands import COMMAND_MODULES
from clholo.errors import ClholoError, ExitCode

__all__ = ["build_parser", "main", "COMMAND_MODULES"]


class _HelpFormatter(argparse.ArgumentDefaultsHelpFormatter):
    """Shows each option's default; a default of None (or a suppressed one) is worded in the
    help text instead, since "(default: None)" tells a user nothing."""

    def _get_help_string(self, action):
        if action.default is None or action.default is argparse.SUPPRESS:
            return action.help
        return super()._get_help_string(action)


class _Parser(argparse.ArgumentParser):
    """Every (sub)command: defaults in ``--help``, ``--progress`` and ``--debug``, and "maybe
    you meant" for a mistyped command."""

    # argparse takes "-8e-6" or "-inf" for an option ("expected one argument"): a negative
    # number in any float spelling is a value, so that the option's own check names it
    _negative_number_matcher = re.compile(
        r"^-(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?$|^-(inf|infinity|nan)$", re.IGNORECASE)

    def __init__(self, *args, **kwargs):
        kwargs.setdefault("formatter_class", _HelpFormatter)
        super().__init__(*args, **kwargs)
        self._negative_number_matcher = _Parser._negative_number_matcher
        g = self.add_argument_group("every command")
        # SUPPRESS: a subcommand's parser must not reset a value given before the command name
        g.add_argument("--progress", choices=["auto", "bar", "lines", "off"],
                       default=argparse.SUPPRESS,
                       help="progress display: a bar on a terminal, plain lines elsewhere "
                            "(default: auto)")
        g.add_argument("--debug", action="store_true", default=argparse.SUPPRESS,
                       help="show the full traceback of any error")

    command_names: List[str] = []  # set on the top-level parser by build_parser

    #: options whose empty value means something (none: an empty --title was taken for the
    #: folder's name, silently)
    EMPTY_ALLOWED: frozenset = frozenset()

    def parse_known_args(self, args=None, namespace=None):
        # an empty argument ("" from an unset shell variable) named "." to every path check
        # ("hologram file . does not exist", "--data ''" ran the default data): refuse it here
        namespace, extras = super().parse_known_args(args, namespace)
        for action in self._actions:
            value = getattr(namespace, action.dest, None)
            values = value if isinstance(value, list) else [value]
            if action.dest not in self.EMPTY_ALLOWED and any(
                    isinstance(v, str) and not v.strip() for v in values):
                name = "/".join(action.option_strings) or action.metavar or action.dest
                optional = action.option_strings and not action.required
                what = {"scheduler": "an address", "title": "a title"}.get(action.dest,
                                                                           "a path")
                self.error(f"argument {name}: the value is empty ({value!r}); give {what}"
                           f"{', or leave the option out' if optional else ''}")
        return namespace, extras

    def error(self, message: str):
        if "invalid choice:" in message and self.command_names:
            choice = message.split("invalid choice:", 1)[1].split("(", 1)[0].strip(" '")
            close = difflib.get_close_matches(choice, self.command_names, n=1)
            if close:
                message += f"; maybe you meant {close[0]!r}"
        super().error(message)


def build_parser() -> argparse.ArgumentParser:
    """The ``clholo`` parser: the clholo-wide options and one subparser per command module.

    Returns
    -------
    argparse.ArgumentParser
    """
    from clholo._version import __version__

    parser = _Parser(
        prog="clholo", description="Wave-optics holograms from multiplane images (OpenCL).",
        epilog="Exit codes: 0 done, 1 a check or item failed, 2 bad input or options, "
               "3 this machine cannot (no device, display, memory or extra), 70 internal "
               "error (a bug: please report it), 130 interrupted. See docs/errors.md.")
    sub = parser.add_subparsers(dest="command", required=True, parser_class=_Parser,
                                metavar="COMMAND")
    parser.add_argument("--version", action="version", version=f"clholo {__version__}",
                        help="print clholo's version and exit")
    for module_name in COMMAND_MODULES:
        importlib.import_module(module_name).register(sub)
    parser.command_names = list(sub.choices)
    return parser


def _environment_errors() -> tuple:
    """Exception families that mean "this machine cannot", imported lazily."""
    families = [MemoryError]
    try:
        from clholo.host.runtime import NoDeviceError, ProgramBuildError

        families += [NoDeviceError, ProgramBuildError]
    except ImportError:  # pragma: no cover - pyopencl missing is reported by the command
        pass
    try:
        from clholo.tools.stages.base import StageError

        families.append(StageError)
    except ImportError:  # pragma: no cover
        pass
    return tuple(families)


#: errors that only a write raises: the line names what was being written
_WRITE_ERRNOS = frozenset(getattr(errno, n) for n in ("ENOSPC", "EDQUOT", "EFBIG", "EROFS")
                          if hasattr(errno, n))


def _is_under(filename, out) -> bool:
    """``filename`` is ``out``, inside it, or inside one of the temporary names it is written
    under (``.NAME.xxx.tmp`` beside it: :mod:`clholo.io.output`)."""
    try:
        f = os.path.abspath(os.fsdecode(filename))
        o = os.path.abspath(os.fsdecode(out))
    except (TypeError, ValueError):
        return False
    parent, name = os.path.split(o)
    while True:
        if f == o or (os.path.dirname(f) == parent
                      and os.path.basename(f).startswith(f".{os.path.splitext(name)[0]}.")):
            return True
        up = os.path.dirname(f)
        if up == f:
            return False
        f = up


def _os_error(exc: OSError, args) -> Optional[tuple]:
    """``(code, text)`` for an OSError the command line caused or that stopped a write, naming
    the path and, where it is the output, ``--out``; None for the plain line."""
    out = getattr(args, "out", None) if args is not None else None
    out = out if isinstance(out, (str, bytes, os.PathLike)) else None
    filename = exc.filename
    reason = exc.strerror or str(exc)
    code_text = f"[Errno {exc.errno}] {reason}" if exc.errno is not None else reason
    ours = out is not None and (filename is None or _is_under(filename, out))
    if exc.errno == errno.ENAMETOOLONG:
        if ours:
            return ExitCode.USAGE, (f"argument --out: {_clip(out)} cannot be written: "
                                    f"{code_text}; give a shorter --out")
        if filename is not None:
            return ExitCode.USAGE, f"{_clip(filename)}: {code_text}; give a shorter path"
        return None
    if exc.errno in _WRITE_ERRNOS:
        if ours:
            where = f"the output --out {out}" + (
                f" ({filename})" if filename is not None and os.fsdecode(filename) !=
                os.fsdecode(out) else "")
        elif filename is not None:
            where = os.fsdecode(filename)
        else:
            return None
        if exc.errno == errno.EFBIG:  # a size limit (ulimit -f, the file system's), not space
            return ExitCode.ENVIRONMENT, (
                f"{code_text} while writing {where}: a file there would pass the largest size "
                f"allowed (the shell's ulimit -f, or the file system's own limit, e.g. 4 GiB on "
                f"FAT32); raise the limit, or choose another --out")
        return ExitCode.ENVIRONMENT, (f"{code_text} while writing {where}: free space there "
                                      f"(or choose another --out) and run it again")
    return None


def _clip(path) -> str:
    text = os.fsdecode(path)
    return text if len(text) <= 80 else f"{text[:60]}...{text[-12:]} ({len(text)} characters)"


def _report(command: str, exc: BaseException, args=None) -> int:
    """One line for a foreseeable condition; its exit code."""
    from clholo.progress import end_open_lines

    end_open_lines()
    if isinstance(exc, OSError) and not isinstance(exc, ClholoError):
        mapped = _os_error(exc, args)
        if mapped is not None:
            code, text = mapped
            print(f"clholo {command}: error: {text}", file=sys.stderr)
            return int(code)
    if isinstance(exc, ClholoError):
        code = exc.exit_code
    elif isinstance(exc, _environment_errors()):
        code = ExitCode.ENVIRONMENT
    elif isinstance(exc, (ValueError, FileNotFoundError, FileExistsError, PermissionError,
                          IsADirectoryError, NotADirectoryError)):
        code = ExitCode.USAGE
    elif isinstance(exc, OSError):  # a disk full, a device gone: the machine, not the input
        code = ExitCode.ENVIRONMENT
    else:
        return -1
    text = str(exc) or type(exc).__name__
    if isinstance(exc, MemoryError) and not str(exc):
        text = "out of memory: use a smaller size, fewer frames or --scale"
    print(f"clholo {command}: error: {text}", file=sys.stderr)
    return int(code)


def _sigterm_as_interrupt(signum, frame):
    """SIGTERM (systemd, SLURM, ``docker stop``, ``kill``) ends a command as Ctrl-C does."""
    raise KeyboardInterrupt(f"signal {signum}")


@contextlib.contextmanager
def _signals_as_interrupts():
    """SIGTERM raises ``KeyboardInterrupt`` (as SIGINT does) while a command runs, so that both
    unwind through the outputs' temporary names and end in one line and exit 130; the handler
    is in place before the parser or any command module is imported. Only in the main thread
    (where Python delivers signals); the previous handler comes back afterwards (``main`` is
    also called from Python, e.g. by the tests)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGTERM, _sigterm_as_interrupt)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def main(argv: Optional[List[str]] = None) -> int:
    """Run ``clholo ARGS``; returns the exit code (``docs/errors.md``).

    Ctrl-C and SIGTERM end every command with one line and exit 130. ``--debug`` prints the
    full traceback of any error and still returns the documented code (2 user, 3 environment,
    70 bug, 130 interrupted).
    """
    code = _main(argv)
    if argv is None:  # the process's own command (the console script), not a call from Python
        _late_signals_keep(code)
    return code


def _late_signals_keep(code: int) -> None:
    """After the command has finished (its outputs complete, its line printed), Python still
    shuts down for tens of milliseconds (OpenCL contexts, threads), and resets its signal
    handlers to the default on the way: a SIGTERM then killed the process as 143, as if its
    work were lost. From here on SIGTERM and Ctrl-C are ignored, so the process ends with the
    command's own exit code (``code``). Python keeps an ignored signal ignored through its
    shutdown; a shutdown that hangs still ends with SIGKILL."""
    if threading.current_thread() is not threading.main_thread():
        return
    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, signal.SIG_IGN)


def _main(argv: Optional[List[str]]) -> int:
    with _signals_as_interrupts():
        command, args = "", None
        debug = "--debug" in (sys.argv[1:] if argv is None else list(argv))
        try:
            parser = build_parser()
            args = parser.parse_args(argv)
            command = " ".join(str(v) for v in (args.command, getattr(args, "sweep", None),
                                                 getattr(args, "experiment", None)) if v)
            debug = bool(getattr(args, "debug", False))
            if not hasattr(args, "progress"):
                args.progress = "auto"
            with _warnings_as_lines(command, debug):
                return int(args.func(args) or 0)
        except KeyboardInterrupt:
            if argv is None and not debug:
                # the process's own command: an interrupt can land inside a library's
                # constructor (pyopencl's cache, a pytools.PersistentDict half made), whose
                # __del__ then fails when the traceback is dropped or Python shuts down, and
                # "Exception ignored in ..." with its traceback would follow the one line
                sys.unraisablehook = lambda unraisable: None
            return _interrupted(command, args, debug)
        except Exception as exc:  # the boundary: every exception ends here
            return _failed(command, exc, debug, args)


def _interrupted(command: str, args, debug: bool) -> int:
    # a second Ctrl-C or SIGTERM while the line is written would only cut it short
    saved = {}
    if threading.current_thread() is threading.main_thread():
        for sig in (signal.SIGINT, signal.SIGTERM):
            saved[sig] = signal.signal(sig, signal.SIG_IGN)
    try:
        from clholo.progress import end_open_lines

        end_open_lines()
        if debug:
            import traceback

            traceback.print_exc()
        # outputs are built under a temporary name and renamed only when complete, so an
        # interrupted command has written nothing (a command that keeps finished parts, like
        # batch, says so through interrupt_note)
        note = getattr(args, "interrupt_note", "nothing written")
        print(f"clholo{' ' + command if command else ''}: interrupted; {note}", file=sys.stderr)
    finally:
        for sig, handler in saved.items():
            signal.signal(sig, handler)
    return int(ExitCode.INTERRUPTED)


def _clholo_file(filename: str) -> Optional[str]:
    """``filename`` relative to the checkout (``clholo/io/holograms.py``) when it is clholo's
    code, else None."""
    here = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    path = os.path.abspath(filename)
    if path.startswith(tuple(os.path.join(here, d) + os.sep
                             for d in ("clholo", "host", "tools"))):
        return os.path.relpath(path, here)
    return None


def _from_clholo(category, filename: str) -> bool:
    """A warning of clholo's own: a class of clholo's (``DepthWarning``, ``SplatCullWarning``,
    ...), or a plain ``UserWarning`` raised from clholo's code."""
    if category.__module__.split(".")[0] in ("clholo", "host"):
        return True
    return category is UserWarning and _clholo_file(filename) is not None


def _numeric_in_clholo(category, filename: str) -> Optional[str]:
    """Where a NumPy warning about values (overflow, division by zero, a dropped imaginary
    part) came from, when that is clholo's code: the value is the input's, and one line with
    the place says more to a user than Python's form with a code line."""
    import numpy as np

    numeric = issubclass(category, RuntimeWarning) or category is getattr(
        np, "exceptions", np).ComplexWarning
    return _clholo_file(filename) if numeric else None


@contextlib.contextmanager
def _warnings_as_lines(command: str, debug: bool):
    """clholo's own warnings while a command runs as one line each, ``clholo CMD: warning:
    MESSAGE`` on stderr, like the commands' own warning lines, instead of Python's form with
    a source path, line number and code line; others (a library's) as Python shows them.
    ``--debug`` keeps Python's form for all."""
    if debug:
        yield
        return
    import warnings

    from clholo.progress import end_open_lines

    shown = warnings.showwarning

    def show(message, category, filename, lineno, file=None, line=None):
        where = _numeric_in_clholo(category, filename)
        if where is not None:
            message = f"{message} (NumPy, in {where}:{lineno}: check the input's values)"
        elif not _from_clholo(category, filename):
            return shown(message, category, filename, lineno, file, line)
        end_open_lines()
        print(f"clholo {command}: warning: {message}", file=sys.stderr if file is None
              else file)

    warnings.showwarning = show
    try:
        yield
    finally:
        warnings.showwarning = shown


def _failed(command: str, exc: Exception, debug: bool, args=None) -> int:
    import traceback

    from clholo.progress import end_open_lines

    if debug:  # the traceback first, then the same line and the same documented code
        end_open_lines()
        traceback.print_exc()
    code = _report(command, exc, args)
    if code >= 0:
        return code
    end_open_lines()
    if not debug:
        traceback.print_exc()
    print(f"clholo {command}: internal error: {type(exc).__name__}: {exc}\n"
          f"This is a bug in clholo: please report it with the traceback above "
          f"(clholo --debug {command} ... shows it in full).", file=sys.stderr)
    return int(ExitCode.INTERNAL)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
