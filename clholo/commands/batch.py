"""``clholo batch``: a dataset of holograms on Dask, resumable."""

from __future__ import annotations

import argparse

from clholo import options


def cmd_batch(args: argparse.Namespace) -> int:
    from clholo.batch import BatchInterrupted, render_dataset

    try:
        rows = render_dataset(args.manifest, args.out, scheduler=args.scheduler,
                              workers=args.workers, split_frames=args.split_frames,
                              progress=args.progress, overwrite=args.overwrite)
    except BatchInterrupted as exc:
        args.interrupt_note = exc.note  # the boundary's one line says what was kept
        raise
    return 1 if any(r["status"] == "failed" for r in rows) else 0


def register(subparsers) -> None:
    """Add ``clholo batch`` (imports only argparse here; Dask when it runs)."""
    p = subparsers.add_parser(
        "batch", help="render a dataset (a manifest of scenes) on Dask, resumable",
        description="Render every row of MANIFEST (CSV or JSON lines: an input and clholo "
                    "render's options, --method included) into OUT/<id>/ on Dask; a rerun "
                    "skips complete items.")
    p.add_argument("manifest", help="CSV (header row) or JSON-lines file; see docs/batch.md")
    p.add_argument("--out", default="clholo-batch",
                   help="dataset folder: new (its parent must exist), empty, or an earlier "
                        "batch's, which a rerun completes; nothing in it that clholo did not "
                        "write is ever replaced")
    p.add_argument("--overwrite", action="store_true",
                   help="make --out this manifest's dataset when it holds items the manifest "
                        "does not list (removed) or, made from another manifest, items it "
                        "gives other options (rendered again); without it such a run is "
                        "refused. Never removes a file clholo did not write")
    p.add_argument("--scheduler", default=None,
                   help="address of an existing Dask scheduler (default: "
                        "DASK_SCHEDULER_ADDRESS, else a local cluster)")
    p.add_argument("--workers", type=options.whole(1, 256), default=None,
                   help="local cluster: worker processes (default: one per OpenCL device)")
    p.add_argument("--split-frames", type=options.whole(1), default=None,
                   help="frames per task for rows without split_frames (default: whole items)")
    p.set_defaults(func=cmd_batch,
                   interrupt_note="complete items are kept; run the same command again to "
                                  "finish")
