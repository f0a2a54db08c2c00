"""Host time to enqueue work vs the time the device takes for it (issue 23, "host side").

    python benchmarks/bench_enqueue.py [--shape 270x480] [--layers 8] [--frames 3] [--repeats 5]

Prints, side by side:

* one ``HologramRenderer.render`` (RGB, two kernels per layer where they fit): the host time
  until ``render`` returns ("enqueue") and until ``queue.finish()`` returns ("total"), and their
  ratio. Enqueueing that returns at once shows as enqueue << total; a host that waits inside the
  loop shows as enqueue ~ total.
* per-launch host microseconds of a bare ``pyopencl`` launch, ``runtime.launch`` and
  ``FFTPlan.execute`` (1024^2 by default, ``--fft``), each enqueued ``--launches`` times behind a
  held user event, so the device does nothing while the host time is taken.

Every timing starts with the queue idle (``queue.finish()``). PoCL runs kernels on its own
threads, so host and device time are apart there as on a GPU.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import numpy as np
import pyopencl as cl
import pyopencl.array as cla

if str(Path(__file__).resolve().parent) not in sys.path:  # loaded by path (the tests)
    sys.path.insert(0, str(Path(__file__).resolve().parent))
import _bench_args as _args  # noqa: E402


def _held(queue):
    """A user event that holds ``queue`` (a marker waits for it) until it is set."""
    ev = cl.UserEvent(queue.context)
    cl.enqueue_marker(queue, wait_for=[ev])
    return ev


def per_launch_us(queue, fn, launches: int) -> float:
    """Median over 3 of host microseconds per call of ``fn()``, enqueued behind a held queue."""
    fn()
    queue.finish()
    times = []
    for _ in range(3):
        ev = _held(queue)
        t = time.perf_counter()
        for _ in range(launches):
            fn()
        times.append((time.perf_counter() - t) / launches * 1e6)
        ev.set_status(cl.command_execution_status.COMPLETE)
        queue.finish()
    return statistics.median(times)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--shape", type=_args.shape, default="270x480", help="HxW of the MPI")
    ap.add_argument("--layers", type=_args.positive_int, default=8)
    ap.add_argument("--frames", type=_args.positive_int, default=3)
    ap.add_argument("--repeats", type=_args.positive_int, default=5)
    ap.add_argument("--fft", type=_args.fft_size, default="1024",
                    help="N of the N x N FFTPlan (a size 2^a 3^b 5^c)")
    ap.add_argument("--launches", type=_args.positive_int, default=200)
    a = ap.parse_args(argv)

    import clholo
    from clholo.fft import FFTPlan
    from clholo.host import runtime
    from clholo.host.kernel_args import COMPOSITE_LAYER

    queue = runtime.get_queue()
    H, W = a.shape
    optics = clholo.Optics()
    C, L, T = optics.channels, a.layers, a.frames
    rng = np.random.default_rng(0)
    mpi = clholo.MPI(rng.random((L, H, W, C), dtype=np.float32),
                     rng.random((L, H, W), dtype=np.float32), np.linspace(2e-3, 6e-3, L))
    r = clholo.HologramRenderer(mpi, optics, seed=1, queue=queue)
    r.prepare(T)
    out = cla.empty(queue, (T, C, H, W), np.complex64)
    r.render(T, out=out)
    queue.finish()
    enq, tot = [], []
    for _ in range(a.repeats):
        queue.finish()
        t = time.perf_counter()
        r.render(T, out=out)
        t1 = time.perf_counter()
        queue.finish()
        t2 = time.perf_counter()
        enq.append(t1 - t)
        tot.append(t2 - t)
    e, s = statistics.median(enq) * 1e3, statistics.median(tot) * 1e3
    print(f"device: {queue.device.name.strip()}")
    print(f"render {H}x{W}x{C}, L={L}, T={T}, grid {r.padded[0]}x{r.padded[1]}, "
          f"two_pass={r.two_pass}, {a.repeats} repeats (median)")
    print(f"| what | host enqueue | total | host / total |")
    print(f"|---|---|---|---|")
    print(f"| HologramRenderer.render | {e:.2f} ms | {s:.2f} ms | {e / s:.1%} |")

    # per-launch host time, behind a held queue (the device runs nothing meanwhile)
    knl = runtime.get_kernel(queue.context, "composite.cl", "composite_layer")
    u = cla.empty(queue, (1, C, H, W), np.complex64)
    gsize = ((H * W + 3) // 4, C, 1)
    color0 = cla.to_device(queue, np.ascontiguousarray(mpi.color[0]))  # composite_layer's
    alpha0 = cla.to_device(queue, np.ascontiguousarray(mpi.alpha[0]))  # row-major layer
    args = COMPOSITE_LAYER.args(u=u.data, color=color0.data, alpha=alpha0.data,
                                npix=H * W, n_channels=C, layer=0, frame0=0, colour0=0,
                                key_lo=1, key_hi=0, farthest=1)
    bare = per_launch_us(queue, lambda: knl(queue, gsize, None, *args), a.launches)
    rl = per_launch_us(queue, lambda: runtime.launch(knl, queue, gsize, None, *args),
                       a.launches)
    N = a.fft
    plan = FFTPlan((N, N), np.complex64, queue=queue)
    x = cla.zeros(queue, (N, N), np.complex64)
    y = cla.empty(queue, (N, N), np.complex64)

    def fft():
        plan.execute(x, out=y)
        del y.events[:]  # else pyopencl's add_event waits every 12 calls (see docs)

    fx = per_launch_us(queue, fft, a.launches)
    nl = len(plan._launches)
    print(f"\n| launch | host us per call |")
    print(f"|---|---|")
    print(f"| bare pyopencl kernel call (composite_layer) | {bare:.1f} |")
    print(f"| runtime.launch (composite_layer) | {rl:.1f} |")
    print(f"| FFTPlan.execute {N}x{N} ({nl} kernels) | {fx:.1f} |")


if __name__ == "__main__":
    main()
