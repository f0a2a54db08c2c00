"""The ``clholo`` console script's entry point: signals first, then the package.

``import clholo`` takes about a second (NumPy, PyOpenCL, the package's own modules) before
:func:`clholo.cli.main` runs and puts its own SIGINT/SIGTERM handling in place. Without this
module a SIGTERM in that second ended the command with Python's 143 and no word, and a Ctrl-C
with a traceback. :func:`main` installs the handling before any heavy import, so that a signal
while the package loads is ``clholo: interrupted; nothing written`` and exit 130, as
``docs/errors.md`` says for any other moment.

A top-level module, not ``clholo._something``: importing a submodule runs
``clholo/__init__.py`` (and its heavy imports) first. Only the console script imports this
module; ``import clholo`` installs no signal handler (no side effect on import for Python users).
This module imports nothing but the standard library's ``signal`` and ``sys``.
"""

import signal
import sys

__all__ = ["main"]

#: The exit status of an interrupted command (``clholo.errors.ExitCode.INTERRUPTED``, which is
#: not imported here: importing it loads the package).
INTERRUPTED = 130


def _as_interrupt(signum, frame):
    """SIGTERM (and SIGINT) while the package loads: unwind as Ctrl-C does."""
    raise KeyboardInterrupt(f"signal {signum}")


def main() -> int:
    """Run the ``clholo`` command line (:func:`clholo.cli.main` on ``sys.argv``).

    Returns
    -------
    int
        The exit code (``docs/errors.md``); 130 when SIGINT or SIGTERM arrives before the
        command's own handling is in place.
    """
    for sig in (signal.SIGINT, signal.SIGTERM):
        # a signal the caller ignores stays ignored (a shell's `clholo ... &` ignores Ctrl-C,
        # as Python itself leaves it then)
        if signal.getsignal(sig) is not signal.SIG_IGN:
            signal.signal(sig, _as_interrupt)
    try:
        from clholo import cli

        return cli.main()
    except KeyboardInterrupt:
        # while the package loaded (nothing ran yet), or in the instant between its import and
        # cli.main's own boundary; cli.main itself ends an interrupted command with its line
        for sig in (signal.SIGINT, signal.SIGTERM):
            signal.signal(sig, signal.SIG_IGN)  # a second signal must not cut the line short
        print("clholo: interrupted; nothing written", file=sys.stderr)
        return INTERRUPTED


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
