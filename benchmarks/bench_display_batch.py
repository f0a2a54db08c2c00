"""The display loop's producer step, side by side: render one batch and DPAC-encode it

* ``device``: the loop before issue 17, the MPI renderer writing into a device buffer
  (``HologramRenderer.enqueue_batch``) and the encoder reading that buffer;
* ``registry``: the loop now, frames from the method registry's renderer (``iter_frames``, host
  NumPy arrays, so one device -> host copy) and the encoder uploading them again.

Interleaved repetitions, medians, and the ratio registry / device::

    python benchmarks/bench_display_batch.py --size 256 --layers 8 --frames 2 --repeats 7
"""

from __future__ import annotations

import argparse
import time

import numpy as np


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", type=int, default=256)
    ap.add_argument("--layers", type=int, default=8)
    ap.add_argument("--frames", type=int, default=2)
    ap.add_argument("--repeats", type=int, default=7)
    args = ap.parse_args()

    import pyopencl.array as cla

    from clholo.host import runtime
    from clholo.host.display_loop import dpac_encoder
    from clholo.host.scheduler import HologramRenderer
    from clholo.methods import METHODS
    from clholo.scene import MPI, Optics
    from clholo.scenes import Scene, SceneSpec

    rng = np.random.default_rng(0)
    L, N, n = args.layers, args.size, args.frames
    mpi = MPI(color=rng.uniform(0.05, 1, (L, N, N, 3)), alpha=rng.uniform(0.05, 1, (L, N, N)),
              depths=2e-3 + 4e-3 * np.arange(L) / max(L - 1, 1))
    optics = Optics(pitch=8e-6, wavelengths=(638e-9, 520e-9, 450e-9))
    queue = runtime.get_queue()
    encode = dpac_encoder(optics, z_slm=0.04, queue=queue)
    old = HologramRenderer(mpi, optics, seed=0, frames_per_batch=n, queue=queue)
    field = cla.empty(queue, (n, 3, N, N), np.complex64)
    new = METHODS["mpi"].renderer(Scene(spec=SceneSpec(inputs=("x",)), kind="mpi_folder",
                                        mpi=mpi), optics, seed=0, queue=queue)

    def device(frame0):
        old.enqueue_batch(frame0, n, field)
        return encode(field)

    def registry(frame0):
        parts = [b for _, b in new.iter_frames(n, start=frame0)]
        return encode(parts[0] if len(parts) == 1 else np.concatenate(parts))

    np.testing.assert_array_equal(device(0), registry(0))   # the same patterns
    times = {"device": [], "registry": []}
    for k in range(args.repeats):
        for name, fn in (("device", device), ("registry", registry)):
            t = time.perf_counter()
            fn(n * (k + 1))
            times[name].append(time.perf_counter() - t)
    d, r = (float(np.median(times[k])) for k in ("device", "registry"))
    print(f"{queue.device.name.strip()}: {L} layers {N}x{N}x3, {n} frames per batch, "
          f"{args.repeats} interleaved repeats")
    print(f"  device   (before): {d * 1e3:8.1f} ms per batch (median)")
    print(f"  registry (now)   : {r * 1e3:8.1f} ms per batch (median)")
    print(f"  ratio registry / device: {r / d:.2f}")


if __name__ == "__main__":
    main()
