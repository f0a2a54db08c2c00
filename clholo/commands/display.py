"""``clholo display``: the real-time loop, scene -> method -> hologram -> pattern -> SLM.

The scene comes through the one scene layer (every scene option, ``--near/--far`` included, so
an MPI in scene units or a ``.ply`` is shown at metres), the method from the one registry
(``--method``); the loop itself is :class:`clholo.host.display_loop.DisplayLoop`.

Choices made here (``docs/bench.md``):

* ``--method rpws`` is allowed: the loop is double-buffered and shows the last batch again
  while the next one renders, so a method slower than the display gives fewer new frames per
  second (the summary and the log's ``repeated`` column say how many), never a dark SLM;
* ``--size H W`` resamples the whole scene to H x W pixels (what the help says), so a large
  scene can be shown in real time; it must fit on the SLM;
* ``--memory`` paces the memory display at the bench's refresh rate (``[slm] refresh_hz``,
  default the Pluto-2.1's 60 Hz), so "fps shown" is what the SLM would show;
* ``--seconds`` is honoured whatever ``--frames`` is: the loop renders in chunks and stops at
  the time (:meth:`DisplayLoop.run <clholo.host.display_loop.DisplayLoop.run>`); a batch that
  takes longer to show than the whole run is said up front (a warning naming ``--seconds`` and
  ``--frames`` with the estimate), since most of its frames would never be shown;
* ``--log`` is a single output file under the one output policy: a file clholo did not write
  is never replaced; Ctrl-C keeps the log of the patterns shown so far (whole rows).
"""

from __future__ import annotations


from clholo import options

DEFAULT_Z_SLM = 0.04


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "display",
        help="real-time loop: render a scene -> hologram -> phase pattern -> SLM, "
             "double-buffered, with an fps/latency CSV log",
        description="Render holograms of a scene continuously and show them on the SLM "
                    "(or a memory display paced at the SLM's refresh), colour after colour.")
    options.add_scene_options(p)
    options.add_method_option(p)
    p.add_argument("--config", default=None,
                   help="bench TOML file (monitor, refresh, LUTs, wavelengths, pitch); default: "
                        "Pluto-2.1 values (1920x1080, 8 um, 60 Hz)")
    p.add_argument("--memory", action="store_true", default=False,
                   help="show on a memory display paced at the SLM's refresh instead of the "
                        "SLM window (no display server needed)")
    p.add_argument("--size", type=options.whole(8), nargs=2, default=None, metavar=("H", "W"),
                   help="render at this size: the whole scene is resampled to H x W pixels "
                        "(stretched if the aspect differs), centred on the SLM (default: the "
                        "scene's size)")
    p.add_argument("--frames", type=options.whole(1), default=2,
                   help="time-multiplexed frames per hologram batch")
    p.add_argument("--seed", type=options.whole(0), default=0,
                   help="key of the random-phase stream (and of --max-splats' subset)")
    p.add_argument("--pad", type=options.pad, default="auto",
                   help="zero padding of each propagation: 'auto' or a factor such as 2")
    p.add_argument("--seconds", type=options.positive, default=10.0,
                   help="how long to run (Ctrl-C stops earlier and keeps the log)")
    p.add_argument("--encoding", choices=["dpac", "phase"], default="dpac",
                   help="dpac: double-phase amplitude coding (the real-time path); phase: the "
                        "random-phase hologram's own phase (kinoform)")
    p.add_argument("--z-slm", type=options.metres, default=None,
                   help=f"dpac only: distance from the SLM to the hologram plane, metres "
                        f"(default: {DEFAULT_Z_SLM})")
    options.add_out_option(p, default=None, kind="file", option="--log",
                           what="(CSV: one row per pattern shown, fps / latency / dropped)")
    p.set_defaults(func=cmd_display, interrupt_note="nothing written")


def _check_options(args) -> None:
    """An option that would not act is refused (before anything loads)."""
    from clholo.errors import InputError

    if args.z_slm is not None and args.encoding != "dpac":
        raise InputError("--z-slm sets the double-phase coding's distance: it does not apply "
                         "to --encoding phase; drop --z-slm (or use --encoding dpac)")
    if args.overwrite and args.log is None:
        raise InputError("--overwrite replaces an earlier --log file: give --log FILE, or drop "
                         "--overwrite")


def _warn_batch_longer_than_run(args, channels: int, refresh_hz: float) -> None:
    """Say, before the loop starts, when one batch takes longer to show than the whole run:
    the loop stops at --seconds (within about a render chunk), so most of each batch's
    time-multiplexed frames would never be shown."""
    import sys

    from clholo.host.display_loop import batch_show_seconds

    show_s = batch_show_seconds(args.frames, channels, refresh_hz)
    if show_s <= args.seconds:
        return
    patterns = max(1, int(args.seconds * refresh_hz))
    print(f"clholo display: warning: one batch of --frames {args.frames} x {channels} "
          f"colour(s) is {args.frames * channels} patterns, {show_s:.4g} s at "
          f"{refresh_hz:g} Hz, longer than --seconds {args.seconds:g}: the run stops at "
          f"--seconds after about {patterns} pattern(s), {max(1, patterns // channels)} of the "
          f"{args.frames} frames; give fewer --frames (e.g. --frames "
          f"{max(1, int(args.seconds * refresh_hz / channels))}) or more --seconds (at least "
          f"{show_s:.4g})", file=sys.stderr, flush=True)


def tables_for(cfg, optics):
    """The bench's level LUTs and phase LUTs for the colours shown: all of them, or, for a
    one-colour scene shown at one of the bench's wavelengths (the middle one of three), that
    wavelength's tables (not the first colour's). A phase LUT file of one column per colour
    gives its columns (:class:`clholo.encode.quantize.PhaseLUT`), as ``clholo encode --lut``
    reads it; the other phase tables stay as the bench file names them."""
    from clholo.encode.quantize import parse_luts

    luts, phase = cfg.luts(), cfg.phase_luts
    if phase is not None:
        expanded = []
        for spec in phase:
            tables = parse_luts(spec)
            expanded.extend(tables if len(tables) > 1 else [spec])
        phase = expanded
    wavelengths = tuple(cfg.wavelengths_m)
    if tuple(optics.wavelengths) != wavelengths:
        k = wavelengths.index(optics.wavelengths[0])
        luts = None if luts is None else [luts[k]]
        phase = None if phase is None else [phase[k] if len(phase) > 1 else phase[0]]
    return luts, phase


def _default_size() -> str:
    """The default SLM size as ``"1920 x 1080"`` (:class:`clholo.tools.config.BenchConfig`)."""
    from clholo.tools.config import BenchConfig

    w, h = BenchConfig().resolution
    return f"{w} x {h}"


def cmd_display(args) -> int:
    import os
    import time

    from clholo import scenes
    from clholo.errors import InputError
    from clholo.host.display_loop import (DisplayLoop, dpac_encoder, phase_quantize_encoder,
                                          resample_mpi, summarize)
    from clholo.io.output import check_output_file, output_file
    from clholo.methods import get_method
    from clholo.progress import StepLog
    from clholo.scene import Optics
    from clholo.tools.config import BenchConfig, load_bench_config
    from clholo.tools.slm import MemoryDisplay, SLMWindow, check_display_server, find_monitor

    _check_options(args)
    if args.log is not None:
        check_output_file(args.log, overwrite=args.overwrite, option="--log")
    cfg = load_bench_config(args.config) if args.config else BenchConfig()
    if not args.memory:
        check_display_server()          # before the scene loads: no window, no point
        # the SLM's monitor too: a named monitor whose size is not [slm] resolution (which
        # --size is checked against) is refused in a second, not after the scene loaded
        try:
            find_monitor(cfg.monitor, resolution=cfg.resolution, source=cfg.source)
        except InputError as exc:
            if args.config:
                raise
            # without --config the SLM is the Pluto-2.1 default: the fix is a bench file
            raise InputError(f"{exc}; without --config, clholo display looks for a "
                             f"{_default_size()} monitor (the Pluto-2.1): give --config "
                             f"BENCH.toml with [slm] monitor and resolution for the SLM, or "
                             f"--memory to run without one") from None
    method = get_method(args.method)
    width, height = cfg.resolution
    if args.size is not None:
        if method.needs != "mpi":
            raise InputError(f"--size resamples an MPI; --method {method.name} renders the "
                             f"splats themselves: drop --size (use --scale to shrink the "
                             f"camera's image)")
        h, w = args.size
        if h > height or w > width:
            raise InputError(f"--size {h} {w} is larger than the SLM ({height} x {width}, "
                             f"[slm] resolution): give at most {height} {width}")
    log = StepLog(mode=args.progress)
    spec = options.scene_spec_from_args(args)
    scene = scenes.load(spec, needs=method.needs, method=method.name, log=log)
    source = scene.mpi if method.needs == "mpi" else scene.primitives
    optics = options.match_channels(Optics(pitch=cfg.pitch_m,
                                           wavelengths=tuple(cfg.wavelengths_m)),
                                    source.channels,
                                    source=(f"[slm] wavelengths_m of {args.config}"
                                            if args.config else "the bench's wavelengths_m"))
    if args.size is not None and tuple(args.size) != tuple(scene.mpi.shape):
        H, W = scene.mpi.shape
        scene.mpi = resample_mpi(scene.mpi, args.size)
        log.note(f"display: scene resampled from {H}x{W} to {args.size[0]}x{args.size[1]}")
    if method.name == "rpws":
        log.note("display: rpws renders one layer per splat, slower than the display "
                 "refreshes: the SLM shows the last batch again until the next is ready "
                 "(counted as repeated)")
    # the phase LUTs act in the encoder; the display's level LUTs (if any) act on top
    luts, phase_luts = tables_for(cfg, optics)
    if args.encoding == "dpac":
        phase_luts = phase_luts if phase_luts else "linear"
        z_slm = DEFAULT_Z_SLM if args.z_slm is None else args.z_slm
        encode = dpac_encoder(optics, z_slm=z_slm, luts=phase_luts)
    else:
        if phase_luts and any(str(t) not in ("linear", "linear:255") for t in phase_luts):
            raise InputError(f"{cfg.source}: [slm] phase_luts are applied by the double-phase "
                             f"coding; --encoding phase quantises linearly: drop phase_luts or "
                             f"use --encoding dpac")
        encode = phase_quantize_encoder()
    if args.memory:
        display = MemoryDisplay(width, height, luts=luts, settle_s=cfg.settle_s, pace=True,
                                refresh_hz=cfg.refresh_hz)
    else:
        display = SLMWindow(cfg.monitor, resolution=cfg.resolution, luts=luts,
                            settle_s=cfg.settle_s, source=cfg.source)
    records, interrupted = [], False
    with display:
        loop = DisplayLoop(scene, optics, display, encode, method=method,
                           frames_per_batch=args.frames, seed=args.seed, pad=args.pad)
        _warn_batch_longer_than_run(args, optics.channels, display.refresh_hz)
        log.start(f"display: {method.name}, {args.frames} frame(s) per batch, "
                  f"{display.refresh_hz:g} Hz, {args.seconds:g} s")
        t = time.perf_counter()
        args.interrupt_note = "the display was closed; nothing written"
        if args.log is None:
            try:
                records = loop.run(seconds=args.seconds)
            except KeyboardInterrupt:
                interrupted = True
        else:
            from clholo.tools.slm import on_display_lost

            with output_file(args.log, overwrite=args.overwrite, command="display",
                             option="--log") as tmp, \
                    on_display_lost(lambda: os.unlink(tmp), f"--log {args.log} not written"):
                # (a lost X server ends the process in Xlib's handler, where no with block
                # unwinds: the temporary log is removed there)
                loop.log_path = tmp
                try:
                    records = loop.run(seconds=args.seconds)
                except KeyboardInterrupt:
                    # the rows streamed so far are whole (written one by one, the file closed
                    # by run): keep them as the log of what was shown
                    interrupted = True
        log.step("display: loop", time.perf_counter() - t)
    if interrupted:
        if args.log is not None:
            args.interrupt_note = (f"the display was closed; the log of the patterns shown "
                                   f"is in {args.log}")
        raise KeyboardInterrupt
    s = summarize(records, optics.channels)
    nan = float("nan")
    print(f"display: {s['patterns']} patterns, {s.get('display_fps', nan):.2f} fps "
          f"shown, {s.get('new_frames_per_s', nan):.2f} new frames/s, latency "
          f"{s.get('latency_mean_s', nan) * 1e3:.1f} ms mean, {s.get('dropped', 0)} "
          f"dropped, {s.get('repeated', 0)} repeated"
          + (f" -> {args.log}" if args.log else ""))
    return 0
