"""``clholo display``: the real-time loop, MPI -> hologram -> pattern -> SLM."""

from __future__ import annotations

import argparse

from clholo import options


def register(subparsers) -> None:
    p = subparsers.add_parser("display", 
                              help="real-time loop: render MPI -> hologram -> phase pattern -> "
                                   "SLM, double-buffered, with an fps/latency CSV log")
    p.add_argument("scene", help="MPI folder (mpi.json) or any scene `clholo render` reads")
    p.add_argument("--config", default=None,
                   help="bench TOML file (monitor, LUTs, wavelengths, pitch); default: Pluto-2.1 "
                        "values")
    p.add_argument("--memory", action="store_true", default=False,
                   help="show on a memory display instead of the SLM window")
    p.add_argument("--size", type=options.whole(8), nargs=2, default=None, metavar=("H", "W"),
                   help="render at this size (default: the scene's), centred on the SLM")
    p.add_argument("--frames", type=options.whole(1), default=2,
                   help="time-multiplexed frames per hologram batch")
    p.add_argument("--seconds", type=options.positive, default=10.0, help="how long to run")
    p.add_argument("--encoding", choices=["dpac", "phase"], default="dpac",
                   help="dpac: double-phase amplitude coding (the real-time path); phase: the "
                        "random-phase hologram's own phase (kinoform)")
    p.add_argument("--z-slm", type=options.metres, default=0.04,
                   help="dpac: distance from the SLM to the hologram plane, metres")
    p.add_argument("--log", default="display-log.csv", help="fps / latency / dropped-frame CSV")
    p.set_defaults(func=cmd_display)


def cmd_display(args) -> int:
    from clholo.host.display_loop import run_display_command

    return run_display_command(args)
