"""The command layer: one module per command (or family of commands), each thin.

Every command follows one flow (``docs/architecture.md``)::

    options -> scene -> method -> frames -> outputs

with the options from :mod:`clholo.options`, the scene from :mod:`clholo.scenes`, the
method from :mod:`clholo.methods`, the frames from ``host/`` and the outputs through
:mod:`clholo.io.output`; progress through :mod:`clholo.progress`, errors through the one
boundary in :func:`clholo.cli.main`.

Rules (a test checks them): library code never imports this package; a command module imports
no other command module (shared pieces live in :mod:`clholo.options` or the library).
Each module defines ``register(subparsers)``, which imports only argparse and the options at
registration, so ``clholo --help`` stays fast and optional extras are imported only by the
command that needs them.
"""

# Registration order is the order of ``clholo --help``.
COMMAND_MODULES = (
    "clholo.commands.info",
    "clholo.commands.render",
    "clholo.commands.bench",
    "clholo.commands.tune",
    "clholo.commands.encode",
    "clholo.commands.capture",
    "clholo.commands.display",
    "clholo.commands.experiment",
    "clholo.commands.report",
    "clholo.commands.batch",
    "clholo.commands.selftest",
)
