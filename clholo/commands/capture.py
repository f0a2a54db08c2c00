"""``clholo capture focal-sweep|parallax-sweep``: capture sweeps on the lab bench."""

from __future__ import annotations

import argparse

from clholo import options

#: --speedup below this makes the simulated CONEX reset (12 s / speedup) longer than the
#: reset_wait the driver allows (120 s)
_MIN_SPEEDUP = 0.1


def _add_common(p: argparse.ArgumentParser) -> None:
    p.add_argument("--config", required=True,
                   help="bench TOML file (ports, counts per mm, monitor, LUTs, positions)")
    p.add_argument("--simulate", action="store_true", default=False,
                   help="use the stage simulators and a memory display instead of hardware "
                        "(default: %(default)s)")


def register(subparsers) -> None:
    cap = subparsers.add_parser("capture", help="capture sweeps on the lab bench")
    sub = cap.add_subparsers(dest="sweep", required=True)
    for name, section in (("focal-sweep", "z_stage"), ("parallax-sweep", "pupil_stage")):
        p = sub.add_parser(name,
                           help=f"step the [{section}] through the [{name.replace('-', '_')}] "
                                f"positions, show the patterns at each, capture images")
        _add_common(p)
        p.add_argument("--patterns", required=True,
                       help="uint8 pattern sequence: .npy [T, C, H, W] (H, W = the SLM's)")
        options.add_out_option(p, default=None, required=True,
                               what="(one image per position and pattern, log.json, frames.csv)")
        p.add_argument("--no-home", action="store_true", default=False,
                       help="do not home the stage first (a stage not homed since power-up "
                            "then refuses to move)")
        p.add_argument("--speedup", type=options.positive, default=None,
                       help=f"with --simulate only: how much faster than real time the simulated "
                            f"stages move, at least {_MIN_SPEEDUP:g} (default: 200)")
        p.add_argument("--move-timeout", type=float, default=None, metavar="SECONDS",
                       help=f"seconds one stage move (or the homing) may take (default: "
                            f"[{section}] move_timeout in the bench file, else 60)")
        p.set_defaults(func=cmd_capture, section=section, interrupt_note="nothing written")


def cmd_capture(args) -> int:
    import contextlib

    from clholo.errors import InputError
    from clholo.io.output import check_output_folder
    from clholo.tools import capture
    from clholo.tools.camera import FileCamera, OpenCVCamera
    from clholo.tools.config import load_bench_config
    from clholo.tools.slm import MemoryDisplay, SLMWindow, check_display_server
    from clholo.tools.stages import StageError, StageNotReferencedError, open_stage

    if args.speedup is not None and not args.simulate:
        raise InputError("--speedup sets how fast the simulated stages move: it applies only "
                         "with --simulate; drop --speedup (real stages move at their own speed)")
    if args.speedup is not None and args.speedup < _MIN_SPEEDUP:
        # the simulated CONEX controller reboots for 12 s / speedup, which the driver must
        # wait for: a slower simulation than 1/10 of real time is refused naming the option
        raise InputError(f"--speedup {args.speedup:g} is below {_MIN_SPEEDUP:g}: give "
                         f"--speedup {_MIN_SPEEDUP:g} or more (1 is real time; the default 200 "
                         f"runs the simulated stages 200 times faster)")
    speedup = 200.0 if args.speedup is None else args.speedup
    move_timeout = None
    if args.move_timeout is not None:
        import math

        from clholo.tools.stages.base import SECONDS

        top = SECONDS["move_timeout"][2]
        move_timeout = args.move_timeout
        if not (math.isfinite(move_timeout) and 0 < move_timeout <= top):
            raise InputError(f"--move-timeout {move_timeout:g} must be seconds > 0 and at most "
                             f"{top:g} (milliseconds given?): e.g. --move-timeout 120 for two "
                             f"minutes")
    cfg = load_bench_config(args.config)
    sweep_name = args.sweep.replace("-", "_")
    sweep_cfg = getattr(cfg, sweep_name)
    if sweep_cfg is None:
        raise InputError(f"{args.config} has no [{sweep_name}] section with positions_mm")
    stage_cfg = getattr(cfg, args.section)
    if stage_cfg is None:
        raise InputError(f"{args.config} has no [{args.section}] section (port, kind)")
    width, height = cfg.resolution
    patterns = capture.load_patterns(args.patterns, (height, width), option="--patterns")
    colours = len(cfg.wavelengths_m)
    if patterns.shape[1] not in (1, colours):
        # a colour without a laser (or a laser left without its pattern) would be captured
        # under the wrong light, or not at all, without a word
        shown = ", ".join(f"{w:g}" for w in cfg.wavelengths_m)
        raise InputError(
            f"--patterns {args.patterns} has {patterns.shape[1]} colour(s) (shape "
            f"{tuple(patterns.shape)}, [T, C, H, W]) but the bench has {colours} laser(s) "
            f"([slm] wavelengths_m = [{shown}]): give one pattern per wavelength (or one "
            f"colour), or fix wavelengths_m in {args.config}")
    check_output_folder(args.out, overwrite=args.overwrite, option="--out")  # before hardware
    if not args.simulate:
        check_display_server()
        if cfg.camera["kind"] != "opencv":
            raise InputError(f"{args.config}: [camera] kind = 'file' records a memory display "
                             f"only: use kind = 'opencv' on the bench, or --simulate")
    with contextlib.ExitStack() as stack:
        settings = dict(stage_cfg.settings)
        if args.simulate:
            from clholo.tools.stages.simulators import AptSimulator, ConexSimulator

            sim_cls = AptSimulator if stage_cfg.kind == "apt" else ConexSimulator
            sim = stack.enter_context(sim_cls(speedup=speedup))
            port = sim.port
            if stage_cfg.kind == "conex":
                settings.setdefault("reset_wait", 12.0 / speedup)
            display = MemoryDisplay(width, height, luts=cfg.luts(), settle_s=cfg.settle_s,
                                    refresh_hz=cfg.refresh_hz)
        else:
            port = stage_cfg.port
            # a named monitor whose size is not [slm] resolution is refused here, naming the
            # file, before the stage opens
            display = stack.enter_context(SLMWindow(cfg.monitor, resolution=cfg.resolution,
                                                    luts=cfg.luts(), settle_s=cfg.settle_s,
                                                    source=cfg.source))
        # the stage is closed (stopped first if it moves) on any exit, Ctrl-C included
        where = f"{args.config}: [{args.section}] port = {port!r}"
        try:
            stage = stack.enter_context(open_stage(port, stage_cfg.kind, **settings))
        except StageError as exc:
            # a device fault (exit 3) whose message names the port but not the bench file
            exc.args = (f"{where}: {exc.args[0] if exc.args else type(exc).__name__}",) \
                + exc.args[1:]
            raise exc from None
        except InputError as exc:   # an unknown URL protocol, limits beyond the controller's
            raise InputError(f"{where}: {exc}") from None
        except OSError as exc:   # serial.SerialException: no such port, no permission
            from clholo.errors import EnvironmentProblem

            raise EnvironmentProblem(
                f"{where} did not open ({exc}): check the cable, the port name and that no "
                f"other program holds it") from None
        args.interrupt_note = "the stage was stopped and closed; nothing written"
        if cfg.camera["kind"] == "opencv" and not args.simulate:
            camera = OpenCVCamera(int(cfg.camera.get("device", 0)),
                                  width=cfg.camera.get("width"), height=cfg.camera.get("height"))
            stack.callback(camera.close)
        else:
            camera = FileCamera(display=display)
        common = dict(home=not args.no_home, overwrite=args.overwrite, out_option="--out",
                      move_timeout=(stage_cfg.move_timeout if move_timeout is None
                                    else move_timeout))
        try:
            if args.sweep == "focal-sweep":
                out = capture.focal_sweep(stage, display, camera, patterns,
                                          sweep_cfg.positions_mm, args.out,
                                          depths_m=sweep_cfg.depths_m, **common)
            else:
                out = capture.parallax_sweep(stage, display, camera, patterns,
                                             sweep_cfg.positions_mm, args.out,
                                             distance_m=sweep_cfg.distance_m, **common)
        except StageNotReferencedError:
            if not args.no_home:
                raise
            # the option is the mistake (exit 2), not the stage
            raise InputError(
                f"--no-home: the [{args.section}] {stage_cfg.kind} stage has not been homed "
                f"and refuses to move; drop --no-home so that capture homes it first") from None
    n = len(sweep_cfg.positions_mm) * patterns.shape[0] * patterns.shape[1]
    print(f"{args.sweep}: {len(sweep_cfg.positions_mm)} positions, {n} images -> {out}")
    return 0
