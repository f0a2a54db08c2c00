"""Side-by-side timing of the MPI -> hologram method (``clholo bench``,
``benchmarks/bench_hologram.py``).

The same method three ways, interleaved in one run so that machine drift hits all alike:

* clholo on the chosen OpenCL device (transfer functions cached, as in a display loop),
* the NumPy version at complex64 (``numpy.fft``, the same recursion and padding),
* the PyTorch version on the CPU (``torch.fft``), when torch is installed.

Each takes its own random phases (the method, not our Philox stream), and each gets its
transfer functions precomputed outside the timed region, so all three time the per-hologram
work: L x (composite, FFT2, multiply, IFFT2).
"""

from __future__ import annotations

import statistics
import time
from typing import Callable, Dict, List

import numpy as np

from clholo import reference


def _numpy_method(color, alpha, tfs, padded, rng):
    L, H, W = alpha.shape
    u = np.zeros((H, W), np.complex64)
    big = np.zeros(padded, np.complex64)
    for i in range(L - 1, -1, -1):
        phi = rng.random((H, W), dtype=np.float32) * np.float32(2 * np.pi)
        v = np.sqrt(1 - alpha[i]) * u + np.sqrt(color[i] * alpha[i]) * np.exp(1j * phi)
        big[:H, :W] = v
        big[H:, :] = 0
        big[:H, W:] = 0
        u = np.fft.ifft2(np.fft.fft2(big) * tfs[i])[:H, :W].astype(np.complex64)
    return u


def _torch_method_factory(color, alpha, tfs, padded):
    import torch

    c = torch.from_numpy(color)
    a = torch.from_numpy(alpha)
    H_t = [torch.from_numpy(t) for t in tfs]
    keep = torch.sqrt(1 - a)
    amp = torch.sqrt(c * a)
    L, H, W = alpha.shape
    gen = torch.Generator().manual_seed(0)

    def run():
        with torch.no_grad():
            u = torch.zeros((H, W), dtype=torch.complex64)
            for i in range(L - 1, -1, -1):
                phi = torch.rand((H, W), generator=gen) * (2 * np.pi)
                v = keep[i] * u + amp[i] * torch.polar(torch.ones_like(phi), phi)
                big = torch.nn.functional.pad(v, (0, padded[1] - W, 0, padded[0] - H))
                u = torch.fft.ifft2(torch.fft.fft2(big) * H_t[i])[:H, :W]
            return u

    return run


def _scene(size: int, layers: int, seed: int = 0):
    import clholo

    rng = np.random.default_rng(seed)
    color = rng.random((layers, size, size, 1), dtype=np.float32)
    alpha = rng.random((layers, size, size), dtype=np.float32)
    depths = np.linspace(2e-3, 6e-3, layers)
    return clholo.MPI(color, alpha, depths)


def _median_time(fn: Callable[[], object], finish: Callable[[], None]) -> float:
    t = time.perf_counter()
    fn()
    finish()
    return time.perf_counter() - t


def run_hologram_benchmark(*, size: int = 1024, layers: int = 32, repeats: int = 3,
                           scaling: bool = True, pad=2.0, print_fn=print) -> Dict[str, float]:
    """Time the three implementations for ``layers`` layers of a ``size``^2 field, one colour,
    one frame; print a table with ratios, then clholo's time versus L (4..64)."""
    import clholo
    from clholo.host import runtime

    queue = runtime.get_queue()
    optics = clholo.Optics(wavelengths=(520e-9,))
    mpi = _scene(size, layers)
    renderer = clholo.HologramRenderer(mpi, optics, seed=1, pad=pad, queue=queue)
    padded = renderer.padded
    steps = reference.layer_steps(mpi.depths)
    tfs = [reference.transfer_function(padded, float(s), wavelength=520e-9, pitch=optics.pitch
                                       ).astype(np.complex64) for s in steps]
    color = np.ascontiguousarray(mpi.color[..., 0])
    alpha = mpi.alpha
    rng = np.random.default_rng(0)
    out = clholo.host.scheduler.cla.empty(queue, (1, 1, size, size), np.complex64)

    peers: Dict[str, Callable[[], object]] = {
        "clholo (OpenCL)": lambda: renderer.render(1, out=out),
        "NumPy complex64": lambda: _numpy_method(color, alpha, tfs, padded, rng),
    }
    try:
        import torch

        torch.set_num_threads(max(1, len(__import__("os").sched_getaffinity(0))))
        peers[f"PyTorch {torch.__version__} CPU"] = _torch_method_factory(color, alpha, tfs,
                                                                          padded)
    except ImportError:
        print_fn("(torch not installed: PyTorch column skipped; pip install torch==2.13.0)")

    dev = queue.device
    print_fn(f"MPI -> hologram, L={layers}, {size}x{size}, 1 colour, T=1, padded grid "
             f"{padded[0]}x{padded[1]}; device {dev.platform.name.strip()} / {dev.name.strip()}")
    for fn in peers.values():  # warm-up: kernels, plans, transfer functions, allocator
        fn()
        queue.finish()
    times: Dict[str, List[float]] = {k: [] for k in peers}
    for _ in range(repeats):  # interleaved
        for name, fn in peers.items():
            times[name].append(_median_time(fn, queue.finish))
    med = {k: statistics.median(v) for k, v in times.items()}
    ours = med["clholo (OpenCL)"]
    print_fn(f"{'implementation':<28}{'median s':>10}{'ms/layer':>10}{'vs clholo':>11}")
    for name, t in med.items():
        print_fn(f"{name:<28}{t:>10.3f}{t / layers * 1e3:>10.1f}{t / ours:>10.2f}x")

    result = dict(med)
    if scaling:
        print_fn(f"clholo time versus L ({size}x{size}, same padding):")
        Ls, Ts = [], []
        for L in (4, 8, 16, 32, 64):
            r = clholo.HologramRenderer(_scene(size, L, seed=L), optics, seed=1, pad=pad,
                                        queue=queue)
            o = clholo.host.scheduler.cla.empty(queue, (1, 1, size, size), np.complex64)
            r.render(1, out=o)
            queue.finish()
            ts = [_median_time(lambda: r.render(1, out=o), queue.finish) for _ in range(repeats)]
            Ls.append(L)
            Ts.append(statistics.median(ts))
            print_fn(f"  L={L:<3} {Ts[-1]:8.3f} s   {Ts[-1] / L * 1e3:7.1f} ms/layer")
            del r, o
        slope, intercept = np.polyfit(Ls, Ts, 1)
        fit = np.polyval([slope, intercept], Ls)
        r2 = 1 - np.sum((np.array(Ts) - fit) ** 2) / np.sum((np.array(Ts) - np.mean(Ts)) ** 2)
        print_fn(f"  linear fit: {slope * 1e3:.1f} ms/layer + {intercept * 1e3:.1f} ms, "
                 f"R^2 = {r2:.4f}")
        result["ms_per_layer"] = slope * 1e3
        result["r2"] = r2
    return result
