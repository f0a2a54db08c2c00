"""The display loop's producer step, before and after the 8-bit patterns came from the device

* ``host`` (before issue 19's device path): frames from the method registry's renderer as NumPy
  arrays (``iter_frames``: device -> host), double-phase coding on the device returning float32
  phases (``clholo.encode.dpac.dpac_encode``: host -> device -> host), quantisation through the
  per-wavelength lookup tables in NumPy (``clholo.encode.quantize.quantize``, float64);
* ``device`` (the loop now, ``DisplayLoop``'s producer): the renderer writes the frames into a
  device buffer (``enqueue_frames``), ``dpac_encoder`` codes them there
  (``dpac_encode_device``) and quantises them there (``DeviceQuantizer``): only the uint8
  patterns come back.

Both render the same frames of the same random MPI (``--layers`` layers of ``--size H W``, RGB,
``--frames`` frames per batch, consecutive frame indices as the loop renders them) through
``METHODS["mpi"]``; centring on the SLM (the same for both) is left out. The two take turns in
every round (interleaved, so a shared machine's drift hits both alike), every round's patterns
are compared bit for bit, and the medians, their ratio, the median of the rounds' ratios, the
producer's patterns per second (one pattern per frame and colour) and the CPU time the process
used (all its threads: less sensitive to other jobs on a shared machine than the wall clock)
are printed. Who goes first alternates from round to round. ``--breakdown`` adds rounds timing each piece
(a ``queue.finish()`` after each device piece)::

    python benchmarks/bench_display_batch.py --size 1080 1920 --layers 32 --frames 2 --repeats 5

``--loop`` times the display loop itself instead (``DisplayLoop`` with ``dpac_encoder`` on a
memory display paced at 1000 Hz, so the producer is the slower): its producer pipelined
(``pipeline=None``, the default: the next chunk's render is enqueued before this chunk's
patterns are read back into page-locked memory, centred and handed over) and in turn
(``pipeline=False``), ``--repeats`` runs of ``--loop-batches`` batches each, taking turns; the
producer's seconds per batch are the median spacing of the batches' ready times after the
first. The patterns each shows are compared bit for bit::

    python benchmarks/bench_display_batch.py --loop --size 1080 1920 --layers 32 --frames 3
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

if str(Path(__file__).resolve().parent) not in sys.path:  # loaded by path (the tests)
    sys.path.insert(0, str(Path(__file__).resolve().parent))
import _bench_args as _args  # noqa: E402


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", type=_args.positive_int, nargs=2, default=(1080, 1920),
                    metavar=("H", "W"))
    ap.add_argument("--layers", type=_args.positive_int, default=32)
    ap.add_argument("--frames", type=_args.positive_int, default=2, help="frames per batch")
    ap.add_argument("--repeats", type=_args.positive_int, default=5)
    ap.add_argument("--z-slm", type=_args.positive_float, default=0.04)
    ap.add_argument("--luts", nargs="+", default=["linear:255", "linear:230", "linear:200"],
                    help="phase lookup tables, one for all colours or one per colour")
    ap.add_argument("--breakdown", action="store_true",
                    help="also time each piece of both steps (extra rounds)")
    ap.add_argument("--loop", action="store_true",
                    help="time the display loop's producer, pipelined and in turn, instead")
    ap.add_argument("--loop-batches", type=_args.at_least(3), default=8,
                    help="batches per run of the loop (--loop; at least 3: the producer's time "
                         "is the median spacing of the batches after the first)")
    a = ap.parse_args(argv)
    return run(a)


def run(args) -> None:
    """The producer step side by side (or, with ``--loop``, the loop itself)."""
    import pyopencl.array as cla

    from clholo.encode.dpac import dpac_encode, dpac_encode_device
    from clholo.encode.quantize import DeviceQuantizer, _luts_for, quantize
    from clholo.host import runtime
    from clholo.host.display_loop import dpac_encoder
    from clholo.methods import METHODS
    from clholo.scene import MPI, Optics
    from clholo.scenes import Scene, SceneSpec

    rng = np.random.default_rng(0)
    L, (H, W), n = args.layers, args.size, args.frames
    mpi = MPI(color=rng.uniform(0.05, 1, (L, H, W, 3)).astype(np.float32),
              alpha=rng.uniform(0.05, 1, (L, H, W)).astype(np.float32),
              depths=2e-3 + 4e-3 * np.arange(L) / max(L - 1, 1))
    optics = Optics(pitch=8e-6, wavelengths=(638e-9, 520e-9, 450e-9))
    queue = runtime.get_queue()
    scene = Scene(spec=SceneSpec(inputs=("memory",)), kind="mpi_folder", mpi=mpi)
    renderer = METHODS["mpi"].renderer(scene, optics, seed=0, queue=queue)
    tables = _luts_for(args.luts, 3)                  # read once, as dpac_encoder does
    encode = dpac_encoder(optics, z_slm=args.z_slm, luts=args.luts, queue=queue)
    fields = cla.empty(queue, (n, 3, H, W), np.complex64)   # the loop's reused buffer

    def host(frame0):
        parts = [b for _, b in renderer.iter_frames(n, start=frame0)]
        frames = parts[0] if len(parts) == 1 else np.concatenate(parts)
        phase = dpac_encode(frames, optics, z_slm=args.z_slm, queue=queue)
        return quantize(phase, tables)

    def device(frame0):
        return encode(renderer.enqueue_frames(frame0, n, fields))

    if args.loop:
        return time_loop(args, mpi, optics, queue)

    print(f"{queue.device.name.strip()}: {L} layers {H}x{W}x3, {n} frame(s) per batch "
          f"(renderer: {renderer.frames_per_batch} per launch, padded grid "
          f"{renderer.padded[0]}x{renderer.padded[1]}), DPAC at {args.z_slm} m, LUTs "
          f"{' '.join(args.luts)}, {args.repeats} interleaved rounds", flush=True)
    t = time.perf_counter()
    a, b = host(0), device(0)                          # warm-up: builds, plans, tables
    np.testing.assert_array_equal(a, b)
    print(f"  warm-up (both, with kernel builds): {time.perf_counter() - t:.1f} s; patterns "
          f"equal bit for bit", flush=True)
    times = {"host": [], "device": []}
    cpu = {"host": [], "device": []}
    for k in range(args.repeats):
        frame0 = n * (k + 1)
        got = {}
        order = (("host", host), ("device", device))
        for name, fn in (order if k % 2 == 0 else order[::-1]):   # who goes first alternates
            c, t = time.process_time(), time.perf_counter()
            got[name] = fn(frame0)
            times[name].append(time.perf_counter() - t)
            cpu[name].append(time.process_time() - c)
        np.testing.assert_array_equal(got["host"], got["device"])
        print(f"  round {k + 1}: host {times['host'][-1]:.3f} s, device "
              f"{times['device'][-1]:.3f} s (patterns equal)", flush=True)
    h, d = (float(np.median(times[k])) for k in ("host", "device"))
    hc, dc = (float(np.median(cpu[k])) for k in ("host", "device"))
    ratios = np.array(times["host"]) / np.array(times["device"])
    patterns = n * 3
    print(f"  host   (before): {h:8.3f} s per batch (median), {patterns / h:6.2f} patterns/s; "
          f"CPU time of this process {hc:.3f} s")
    print(f"  device (now)   : {d:8.3f} s per batch (median), {patterns / d:6.2f} patterns/s; "
          f"CPU time of this process {dc:.3f} s")
    print(f"  ratio host / device: {h / d:.3f} (medians), {float(np.median(ratios)):.3f} (median "
          f"of the rounds' ratios), {hc / dc:.3f} (CPU time)")

    if args.breakdown:
        quantizer = DeviceQuantizer(args.luts, 3)
        pieces = {k: [] for k in ("host: render + download", "host: DPAC (upload, phases "
                                  "down)", "host: NumPy quantise", "device: render",
                                  "device: DPAC", "device: quantise + uint8 down")}
        for k in range(args.repeats):
            frame0 = n * (args.repeats + k + 1)
            names = iter(pieces)
            t = time.perf_counter()
            parts = [b for _, b in renderer.iter_frames(n, start=frame0)]
            frames = parts[0] if len(parts) == 1 else np.concatenate(parts)
            t1 = time.perf_counter()
            phase = dpac_encode(frames, optics, z_slm=args.z_slm, queue=queue)
            t2 = time.perf_counter()
            want = quantize(phase, tables)
            t3 = time.perf_counter()
            for v in (t1 - t, t2 - t1, t3 - t2):
                pieces[next(names)].append(v)
            t = time.perf_counter()
            renderer.enqueue_frames(frame0, n, fields)
            queue.finish()
            t1 = time.perf_counter()
            dphase = dpac_encode_device(fields, optics, z_slm=args.z_slm, queue=queue)
            queue.finish()
            t2 = time.perf_counter()
            got = quantizer(dphase)
            t3 = time.perf_counter()
            for v in (t1 - t, t2 - t1, t3 - t2):
                pieces[next(names)].append(v)
            np.testing.assert_array_equal(got, want)
        print("  breakdown (median s):")
        for name, v in pieces.items():
            print(f"    {name:<32} {float(np.median(v)):8.3f}")


def time_loop(args, mpi, optics, queue) -> None:
    """The display loop's producer, pipelined and in turn, side by side (``--loop``)."""
    from clholo.host.display_loop import DisplayLoop, dpac_encoder
    from clholo.tools.slm import MemoryDisplay

    (H, W), n, runs = args.size, args.frames, args.repeats
    batches = args.loop_batches

    def run(pipeline):
        encode = dpac_encoder(optics, z_slm=args.z_slm, luts=args.luts, queue=queue)
        display = MemoryDisplay(W, H, pace=True, refresh_hz=1000.0)
        loop = DisplayLoop(mpi, optics, display, encode, frames_per_batch=n, seed=0,
                           queue=queue, pipeline=pipeline)
        shown = {}

        def keep(rec):
            if not rec.repeated and rec.frame < n:      # the first batch's, for the check
                shown[rec.frame, rec.channel] = display.screen.copy()

        t = time.perf_counter()
        records = loop.run(batches=batches, on_pattern=keep)
        wall = time.perf_counter() - t
        ready = sorted({r.batch: r.ready_s for r in records}.values())
        per_batch = float(np.median(np.diff(ready[1:]))) if len(ready) > 2 else float("nan")
        return per_batch, wall, loop._pipelined(), shown

    print(f"{queue.device.name.strip()}: display loop, {mpi.layers} layers {H}x{W}x3, {n} "
          f"frame(s) per batch, DPAC at {args.z_slm} m, memory display paced at 1000 Hz; "
          f"{runs} runs of {batches} batches each way, taking turns", flush=True)
    t = time.perf_counter()
    run(None)
    print(f"  warm-up (kernel builds): {time.perf_counter() - t:.1f} s", flush=True)
    per = {"pipelined": [], "in turn": []}
    for k in range(runs):
        got = {}
        order = (("pipelined", None), ("in turn", False))
        for name, pipeline in (order if k % 2 == 0 else order[::-1]):
            per_batch, wall, pipelined, shown = run(pipeline)
            assert pipelined == (pipeline is None), (name, pipelined)
            per[name].append(per_batch)
            got[name] = shown
        assert got["pipelined"].keys() == got["in turn"].keys()
        for key, pattern in got["pipelined"].items():
            np.testing.assert_array_equal(pattern, got["in turn"][key])
        print(f"  run {k + 1}: pipelined {per['pipelined'][-1]:.4f} s/batch, in turn "
              f"{per['in turn'][-1]:.4f} s/batch (first batch's patterns equal)", flush=True)
    p, q = (float(np.median(per[k])) for k in ("pipelined", "in turn"))
    patterns = n * 3
    print(f"  producer pipelined: {p:.4f} s per batch (median), {patterns / p:7.1f} patterns/s")
    print(f"  producer in turn  : {q:.4f} s per batch (median), {patterns / q:7.1f} patterns/s")
    print(f"  ratio in turn / pipelined: {q / p:.3f}")


if __name__ == "__main__":
    main()
