"""``clholo selftest``: does clholo work on this device? Every kernel family against its NumPy
reference, the device's facts, one speed line (docs/selftest.md)."""

from __future__ import annotations

import argparse

from clholo import options


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "selftest", help="check every kernel family against its NumPy reference on the chosen "
                         "OpenCL device (CLHOLO_DEVICE) and print the device's facts; exit 1 on "
                         "any failure")
    p.add_argument("--quick", action="store_true",
                   help="smaller speed measurement (FFT 256^2 instead of 1024^2)")
    options.add_out_option(p, default=None, kind="file", option="--json",
                           what="(the report as JSON, to attach to a bug report; default: the "
                                "report is only printed)")
    p.set_defaults(func=cmd_selftest)


def cmd_selftest(args: argparse.Namespace) -> int:
    """0 when every check passed, 1 (FAILED) otherwise."""
    import json
    import sys

    from clholo.errors import ExitCode
    from clholo.io.output import check_output_file, output_file
    from clholo.selftest import run_selftest

    from clholo.errors import InputError

    if args.overwrite and args.json is None:  # it would be ignored: say so, as display does
        raise InputError("--overwrite replaces an earlier --json report: give --json FILE, or "
                         "drop --overwrite")
    if args.json is not None:  # --json "" is a mistake to refuse, not "no report"
        check_output_file(args.json, overwrite=args.overwrite, option="--json")  # before work
    report = run_selftest(quick=args.quick,
                          progress=lambda line: print(line, file=sys.stderr, flush=True))
    print(report.format_text())
    if args.json is not None:
        with output_file(args.json, overwrite=args.overwrite, command="selftest",
                         option="--json") as tmp:
            tmp.write_text(json.dumps(report.to_dict(), indent=1))
        print(f"report written to {args.json}")
    return int(ExitCode.OK if report.passed else ExitCode.FAILED)
