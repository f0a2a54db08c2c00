"""``clholo report``: one self-contained HTML page of an output folder."""

from __future__ import annotations

import argparse

from clholo import options


def cmd_report(args: argparse.Namespace) -> int:
    import sys

    from clholo.experiments.report import build_report

    def warn(message: str) -> None:
        print(f"clholo report: warning: {message}", file=sys.stderr, flush=True)

    out = build_report(args.folder, args.out, title=args.title, overwrite=args.overwrite,
                       warn=warn, max_side=args.max_side)
    print(f"wrote {out}")
    return 0


def register(subparsers) -> None:
    """Add ``clholo report`` (imports only argparse and the shared options here)."""
    p = subparsers.add_parser(
        "report", help="write one self-contained HTML page (focal stack and view sliders, "
                       "tables, plots) of a render or experiment output folder",
        description="One HTML page with every image inline. By default it is written inside "
                    "FOLDER (which must be a folder clholo wrote; the page is listed in its "
                    "manifest); --out writes it anywhere else. A file clholo did not write is "
                    "never replaced.")
    p.add_argument("folder", help="output folder of clholo render/demo or of an experiment")
    p.add_argument("--out", default=None,
                   help="output file (HTML; default: FOLDER/report.html); written under a "
                        "temporary name and renamed when complete (see --overwrite)")
    options.add_overwrite_option(p)
    p.add_argument("--title", default=None, help="page title (default: the folder's name)")
    p.add_argument("--max-side", type=options.whole(0), default=2048, metavar="PIXELS",
                   help="show images at most this many pixels on their longer side: a larger "
                        "focal slice, view or figure is reduced by a whole factor (means of "
                        "blocks in linear light; the page says so, the files keep every "
                        "pixel); 0: every stored pixel (a 12-megapixel render's page is then "
                        "300 MB)")
    p.set_defaults(func=cmd_report)
