"""``clholo report``: one self-contained HTML page of an output folder."""

from __future__ import annotations

import argparse


def cmd_report(args: argparse.Namespace) -> int:
    from clholo.experiments.report import build_report

    out = build_report(args.folder, args.out, title=args.title)
    print(f"wrote {out}")
    return 0


def register(subparsers) -> None:
    """Add ``clholo report`` (imports only argparse here)."""
    p = subparsers.add_parser(
        "report", help="write one self-contained HTML page (focal stack and view sliders, "
                       "tables, plots) of a render or experiment output folder")
    p.add_argument("folder", help="output folder of clholo render/demo or of an experiment")
    p.add_argument("--out", default=None,
                   help="HTML file to write (default: FOLDER/report.html)")
    p.add_argument("--title", default=None, help="page title (default: the folder's name)")
    p.set_defaults(func=cmd_report)
