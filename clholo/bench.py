"""Side-by-side timing of the MPI -> hologram method (``clholo bench``,
``benchmarks/bench_hologram.py``).

The same method three ways, interleaved in one run so that machine drift hits all alike:

* clholo on the chosen OpenCL device (transfer functions cached, as in a display loop),
* the NumPy version at complex64 (``numpy.fft``, the same recursion and padding),
* the PyTorch version (``torch.fft``), when torch is installed: on CUDA when the OpenCL device
  is a GPU and ``torch.cuda.is_available()`` (the strongest peer of a GPU), else on the CPU
  (:func:`torch_peer`). Every frame and colour goes in one batch per layer.

and, where the renderer runs a layer as two kernels (``HologramRenderer.two_pass``), clholo with
the four-pass layer beside it ("clholo, four passes/layer": the layer before issue 23).

Each takes its own random phases (the method, not our Philox stream), and each gets its
transfer functions precomputed outside the timed region (on the peer's device), so all three
time the per-hologram work: L x (composite, FFT2, multiply, IFFT2). Each timing starts and ends
with its own side idle (``queue.finish()``, ``torch.cuda.synchronize()``), and the printed
table names the device each ran on (also in the returned ``"devices"``).
"""

from __future__ import annotations

import math
import os
import statistics
import time
from dataclasses import dataclass
from typing import Any, Callable, Dict, List, Optional, Tuple

import numpy as np

from clholo import reference

#: ``CL_DEVICE_TYPE_GPU``: the bit of ``pyopencl.Device.type`` that marks a GPU.
CL_DEVICE_TYPE_GPU = 1 << 2


@dataclass(frozen=True)
class TorchPeer:
    """Where PyTorch runs as clholo's peer in a benchmark (:func:`torch_peer`).

    Attributes
    ----------
    torch : module
        The ``torch`` module.
    kind : str
        ``"cuda"`` or ``"cpu"``.
    device : str
        The torch device its tensors live on (``"cuda:0"``, ``"cpu"``).
    label : str
        Its name in the tables, e.g. ``"PyTorch 2.13.0 CUDA"``.
    where : str
        The device in words, e.g. ``"cuda:0 NVIDIA H100 80GB HBM3"`` or ``"CPU, 2 threads"``.
    """

    torch: Any
    kind: str
    device: str
    label: str
    where: str

    def synchronize(self) -> None:
        """Wait for the work queued on the peer's device (CUDA runs asynchronously)."""
        if self.kind == "cuda":
            self.torch.cuda.synchronize()


# glibc's mallopt parameters (malloc.h)
_M_TRIM_THRESHOLD = -1
_M_MMAP_MAX = -4
_heap_kept: List[bool] = []


def keep_host_heap() -> bool:
    """Keep freed host memory in this process's heap for the rest of its life (glibc only):
    ``mallopt(M_MMAP_MAX, 0)`` and the largest ``M_TRIM_THRESHOLD``. True where it took.

    Why: by default glibc serves allocations of 32 MiB and more (and smaller ones, depending
    on what the process freed before) with a fresh ``mmap`` and unmaps them when freed, so a
    host peer that allocates its temporaries on every call (PyTorch and NumPy on the CPU)
    pays the page faults of touching them anew each time: PyTorch's SGD iteration at 1024^2
    took 31 to 110 ms in one process depending on its allocation history, and 32-36 ms with
    the heap kept; the 1024^2 pad-2 hologram 2.18 s against 1.08 s (PoCL on a Zen 5 EPYC,
    2026-11-27). The benchmarks time the host peers at their best, as a tuned PyTorch script
    would run (``MALLOC_MMAP_MAX_=0``). Nothing of clholo's device work depends on it.
    """
    if _heap_kept:
        return _heap_kept[0]
    ok = False
    try:
        import ctypes

        mallopt = getattr(ctypes.CDLL(None), "mallopt", None)  # glibc's, where it is libc
        if mallopt is not None:
            mallopt.argtypes = [ctypes.c_int, ctypes.c_int]
            ok = bool(mallopt(_M_MMAP_MAX, 0)) and bool(mallopt(_M_TRIM_THRESHOLD, 2 ** 31 - 1))
    except OSError:  # pragma: no cover - no C library to load (not Linux or macOS)
        ok = False
    _heap_kept.append(ok)
    return ok


def _host_where(base: str) -> str:
    """``base`` with how the host heap is kept (:func:`keep_host_heap`), for the tables."""
    return f"{base}, heap kept" if keep_host_heap() else base


#: The environment variable that makes :func:`torch_peer` strict (``benchmarks/gpu_checks.py``
#: sets it for its steps that compare against PyTorch, so that a missing peer fails the step
#: instead of leaving a table without it): ``required``: torch must be installed and, where the
#: OpenCL device is a GPU, have CUDA (a CPU peer for a GPU is refused); ``any``: torch must be
#: installed (on the CPU where it has no CUDA). Unset (or empty): neither is required.
PEER_ENV = "CLHOLO_BENCH_PEER"


def _peer_rule() -> str:
    rule = os.environ.get(PEER_ENV, "").strip().lower()
    if rule not in ("", "required", "any"):
        from clholo.errors import InputError

        raise InputError(f"{PEER_ENV}={os.environ[PEER_ENV]!r}: give 'required', 'any' or "
                         f"leave it unset")
    return rule


def torch_peer(cl_device, *, threads: Optional[int] = None) -> Optional[TorchPeer]:
    """PyTorch as the strongest peer of ``cl_device``, or None when torch is not installed.

    On CUDA when the OpenCL device is a GPU and ``torch.cuda.is_available()`` (the CUDA device
    of the same name, else torch's current one); otherwise on the CPU with ``threads`` threads
    (default: every core this process may use), with the host heap kept
    (:func:`keep_host_heap`: its temporaries are not mapped anew on every call).

    With ``CLHOLO_BENCH_PEER`` set (:data:`PEER_ENV`, as ``benchmarks/gpu_checks.py`` sets it),
    a missing torch, and with ``required`` a torch without CUDA for a GPU, end the process
    (``SystemExit``, exit status 1) with a message that says so, instead of returning None or
    a CPU peer.

    Parameters
    ----------
    cl_device : pyopencl.Device
        The device clholo runs on (its ``type`` and ``name`` are read).
    threads : int, optional
        CPU threads for torch when it runs on the CPU.
    """
    rule = _peer_rule()
    try:
        import torch
    except ImportError:
        if rule:
            raise SystemExit(f"no PyTorch peer: torch is not installed, and this benchmark "
                             f"compares against it ({PEER_ENV}={rule}, set by "
                             f"benchmarks/gpu_checks.py): pip install 'clholo[bench]'") from None
        return None
    version = torch.__version__
    gpu = bool(int(cl_device.type) & CL_DEVICE_TYPE_GPU)
    if gpu and torch.cuda.is_available():
        names = [torch.cuda.get_device_name(i) for i in range(torch.cuda.device_count())]
        cl_name = cl_device.name.strip()
        index = names.index(cl_name) if cl_name in names else torch.cuda.current_device()
        return TorchPeer(torch, "cuda", f"cuda:{index}", f"PyTorch {version} CUDA",
                         f"cuda:{index} {names[index]}")
    if gpu and rule == "required":
        raise SystemExit(f"no CUDA PyTorch peer: clholo's OpenCL device {cl_device.name.strip()} "
                         f"is a GPU, but torch {version} has no CUDA here "
                         f"(torch.cuda.is_available() is False), and PyTorch on the CPU is no "
                         f"peer of a GPU. Install torch with CUDA, or run gpu_checks.py with "
                         f"--allow-cpu-peer ({PEER_ENV}=any) to compare against it on the CPU")
    torch.set_num_threads(max(1, threads if threads is not None
                              else len(os.sched_getaffinity(0))))
    return TorchPeer(torch, "cpu", "cpu", f"PyTorch {version} CPU",
                     _host_where(f"CPU, {torch.get_num_threads()} threads"))


def _idle() -> None:
    """The host's own work is done when its call returns."""


def _opencl_where(queue) -> str:
    dev = queue.device
    return f"{dev.platform.name.strip()} / {dev.name.strip()}"


#: ``_time_peers`` times each peer in blocks of back-to-back calls that last at least this long
#: (seconds): a render of a few milliseconds on a GPU is then timed as one of a stream of calls,
#: as a display loop runs it, not alone after the other peers' seconds of work, where its time
#: would include the device waking up. Calls of this long or longer are timed one at a time.
MIN_BLOCK_S = 0.05
#: ... and at most this many calls per block.
MAX_BLOCK_CALLS = 100
# a warm-up call shorter than this may have spent most of it building kernels: one more call
# (timed warm) then sizes the blocks
_REWARM_BELOW_S = 10.0


def _timed(fn: Callable[[], object], sync: Callable[[], None], calls: int = 1) -> float:
    """Seconds per call of ``calls`` back-to-back calls of ``fn``, its device idle before the
    first and waited for after the last (``sync`` waits for it)."""
    sync()
    t = time.perf_counter()
    for _ in range(calls):
        fn()
    sync()
    return (time.perf_counter() - t) / calls


def _block_calls(seconds: float, min_block_s: float) -> int:
    """Calls per timed block for calls of ``seconds`` each (1 .. MAX_BLOCK_CALLS)."""
    if seconds <= 0:
        return MAX_BLOCK_CALLS
    return int(min(MAX_BLOCK_CALLS, max(1, math.ceil(min_block_s / seconds))))


def _time_peers(peers: Dict[str, Tuple[Callable[[], object], Callable[[], None]]],
                repeats: int, between: Callable[[], None] = lambda: None, *,
                min_block_s: float = MIN_BLOCK_S,
                block_calls: Optional[Dict[str, int]] = None) -> Dict[str, float]:
    """Median seconds per call of each ``name -> (run, sync)`` over ``repeats`` interleaved
    rounds, after a warm-up run each (kernel builds, plans, allocators; a second, timed one
    where the first took less than 10 s). Each round times each peer in one block of
    back-to-back calls lasting about ``min_block_s`` (:func:`_timed`; one call where a call
    takes that long); ``between`` runs at the start of each round. ``block_calls``, a dict,
    receives the calls per block of each peer."""
    calls: Dict[str, int] = {}
    for name, (fn, sync) in peers.items():
        t = _timed(fn, sync)
        if t < _REWARM_BELOW_S:
            t = _timed(fn, sync)
        calls[name] = _block_calls(t, min_block_s)
    if block_calls is not None:
        block_calls.update(calls)
    times: Dict[str, List[float]] = {k: [] for k in peers}
    for _ in range(repeats):
        between()
        for name, (fn, sync) in peers.items():
            times[name].append(_timed(fn, sync, calls[name]))
    return {k: statistics.median(v) for k, v in times.items()}


def _blocks_line(calls: Dict[str, int]) -> str:
    """The table's note on how each peer was timed."""
    return ("timed per call, in blocks of back-to-back calls of at least "
            f"{MIN_BLOCK_S * 1e3:.0f} ms: " + ", ".join(f"{k} {v}" for k, v in calls.items()))


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


def _check_random_layers(layers: int, height: int, width: int, colours: int) -> None:
    """Refuse, before drawing them, random layers that this machine's memory cannot hold: the
    float32 colour and alpha arrays and their device copies (on a CPU device those are host
    memory too)."""
    from clholo.host.memory import available_host_bytes

    need = 2 * 4 * layers * height * width * (colours + 1)
    room = available_host_bytes()
    if need > 0.8 * room:
        raise MemoryError(
            f"{layers} random layers of {height}x{width} ({colours} colour(s) and alpha, "
            f"float32, with their device copies) take {need / 2**30:.1f} GiB of host memory but "
            f"{room / 2**30:.1f} GiB is available: use fewer --layers or a smaller --size")


def _scene(size, layers: int, seed: int = 0):
    """A random one-colour MPI of ``size`` pixels (``N`` for ``N x N``, or ``(H, W)``)."""
    import clholo

    H, W = (size, size) if np.isscalar(size) else size
    _check_random_layers(layers, H, W, 1)
    rng = np.random.default_rng(seed)
    color = rng.random((layers, H, W, 1), dtype=np.float32)
    alpha = rng.random((layers, H, W), dtype=np.float32)
    depths = np.linspace(2e-3, 6e-3, layers)
    return clholo.MPI(color, alpha, depths)


def _median_time(fn: Callable[[], object], finish: Callable[[], None]) -> float:
    t = time.perf_counter()
    fn()
    finish()
    return time.perf_counter() - t


def run_hologram_benchmark(*, size: int = 1024, layers: int = 32, repeats: int = 3,
                           scaling: bool = True, pad=2.0, numpy: bool = True,
                           print_fn=print) -> Dict[str, Any]:
    """Time the three implementations for ``layers`` layers of a ``size`` x ``size`` field,
    one colour, one frame; print a table with ratios and the device each ran on, then
    clholo's time versus L (4..64).

    Parameters
    ----------
    size : int
        Side of the square field, pixels.
    layers : int
        Number of MPI layers.
    repeats : int
        Timed runs of each implementation (the median counts).
    scaling : bool
        Also time clholo for L = 4 .. 64 layers.
    pad : "auto", float or (int, int)
        Padding of each propagation: ``"auto"`` (what the band-limited kernel's spread needs),
        a factor per axis, or the padded grid ``(Hp, Wp)`` itself (sizes ``2^a 3^b 5^c``).
    numpy : bool
        Also time the NumPy version (seconds a call at 1024^2: leave it out where the
        device's time is scarce, e.g. a lent GPU).
    print_fn : callable
        Where the table's lines go (default :func:`print`).

    Returns
    -------
    dict
        Median seconds per call of each implementation (keyed by the table's names; PyTorch
        where installed; each timed in blocks of back-to-back calls of at least
        :data:`MIN_BLOCK_S`), ``"block_calls"`` (name -> calls per block), ``"devices"``
        (name -> the device it ran on, in words) and, with
        ``scaling``, ``"ms_per_layer"`` and ``"r2"`` of the linear fit.
    """
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

    peers: Dict[str, Tuple[Callable[[], object], Callable[[], None]]] = {
        "clholo (OpenCL)": (lambda: renderer.render(1, out=out), queue.finish)}
    if numpy:
        peers["NumPy complex64"] = (lambda: _numpy_method(color, alpha, tfs, padded, rng), _idle)
    if renderer.two_pass:  # the layer as four passes (before issue 23), in the same rounds
        four = clholo.HologramRenderer(mpi, optics, seed=1, pad=pad, queue=queue,
                                       two_pass=False)
        peers["clholo, four passes/layer"] = (lambda: four.render(1, out=out), queue.finish)
    devices = {name: _opencl_where(queue) for name in peers if name.startswith("clholo")}
    if numpy:
        devices["NumPy complex64"] = _host_where("CPU (host)")
    peer = torch_peer(queue.device)
    if peer is not None:
        peers[peer.label] = (_torch_batched_factory(mpi.color, alpha, [t[None] for t in tfs],
                                                    padded, 1, peer), peer.synchronize)
        devices[peer.label] = peer.where
    else:
        print_fn("(torch not installed: PyTorch column skipped; pip install torch==2.13.0)")

    print_fn(f"MPI -> hologram, L={layers}, {size}x{size}, 1 colour, T=1, padded grid "
             f"{padded[0]}x{padded[1]}; device {_opencl_where(queue)}; a layer is "
             f"{'two kernels' if renderer.two_pass else 'four passes'}")
    calls: Dict[str, int] = {}
    med = _time_peers(peers, repeats, block_calls=calls)
    ours = med["clholo (OpenCL)"]
    print_fn(f"{'implementation':<28}{'median ms':>10}{'ms/layer':>10}{'vs clholo':>11}  ran on")
    for name, t in med.items():
        print_fn(f"{name:<28}{t * 1e3:>10.3f}{t / layers * 1e3:>10.3f}{t / ours:>10.2f}x  "
                 f"{devices[name]}")
    print_fn(_blocks_line(calls))

    result: Dict[str, Any] = dict(med)
    result["devices"] = devices
    result["block_calls"] = calls
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


def run_hologram_breakdown(*, size=1024, layers: int = 32, repeats: int = 5, pad=2.0,
                           print_fn=print) -> Dict[str, float]:
    """Where one layer of the hologram loop goes: its pieces timed one by one on the
    renderer's own plans, kernels and buffers (interleaved rounds, median ms), next to the
    whole render divided by ``layers``.

    Pieces: the composite pass, the forward transform (zero-padded input pruned), the inverse
    with the transfer function multiplied as it loads (cropped output), the same inverse
    without the multiply, the forward with the multiply in its last store (where it sat
    before), and one unpruned transform of the padded grid. "floor" is the two
    pruned transforms without the multiply, the least a layer can cost with this FFT;
    "launch + host" is the layer minus the sum of its pieces. ``size``: ``N`` (``N x N``) or
    ``(H, W)``, e.g. the SLM's ``(1080, 1920)`` with ``pad="auto"``.

    Parameters
    ----------
    size : int or (int, int)
        ``N`` for an ``N x N`` field, or ``(H, W)``, pixels.
    layers : int
        Number of MPI layers of the whole render.
    repeats : int
        Interleaved rounds (the median counts).
    pad : "auto", float or (int, int)
        Padding of each propagation: ``"auto"`` (what the band-limited kernel's spread needs),
        a factor per axis, or the padded grid ``(Hp, Wp)`` itself (sizes ``2^a 3^b 5^c``).
    print_fn : callable
        Where the table's lines go (default :func:`print`).

    Returns
    -------
    dict
        Median milliseconds per piece, keyed by the table's names.
    """
    import clholo
    from clholo.host import runtime

    H, W = (size, size) if np.isscalar(size) else (int(size[0]), int(size[1]))

    queue = runtime.get_queue()
    optics = clholo.Optics(wavelengths=(520e-9,))
    mpi = _scene(size, layers)
    r = clholo.HologramRenderer(mpi, optics, seed=1, pad=pad, queue=queue)
    out = clholo.host.scheduler.cla.empty(queue, (1, 1, H, W), np.complex64)
    r.render(1, out=out)
    queue.finish()
    prop = r._propagator(1)
    flat = out.reshape((1, H, W))
    spec = prop.spectrum
    tf = r.transfer_functions(layers // 2)
    from clholo.fft import FFTPlan

    full = FFTPlan(spec.shape, np.complex64, queue=queue)
    spare = clholo.host.scheduler.cla.empty(queue, spec.shape, np.complex64)
    key = r.key

    def composite():
        # the renderer's own composite launch (on CPUs the 8x8-block kernel)
        r._launch_composite(out.data, 1, 0, 1, farthest=False)

    pieces: Dict[str, Callable[[], object]] = {
        "composite": composite,
        "forward (input pruned)": lambda: prop.forward.execute(flat, out=spec),
        "inverse x H (output pruned)": lambda: prop.inverse.execute(
            spec, out=flat, inverse=True, multiply=tf, multiply_at="input"),
        "inverse alone": lambda: prop.inverse.execute(spec, out=flat, inverse=True),
        # where the multiply sat before (the forward's column-pass store): compare with the line
        # above it, in the same rounds
        "forward x H at its store": lambda: prop.forward.execute(
            flat, out=spec, multiply=tf, multiply_at="output"),
        "unpruned transform": lambda: full.execute(spec, out=spare),
        "whole render / L": lambda: r.render(1, out=out),
    }
    if r.two_pass:  # the layer's two kernels on the renderer's own plans
        _, columns, rows, _ = r._layer_plans(1)
        rspec = r._row_spectrum_buffer(1)
        mid = [*r.layers[1], np.uint32(W), np.uint32(1), np.uint32(1), np.uint32(0),
               key[0], key[1]]
        pieces["column round trip x H"] = lambda: columns.execute(rspec, out=rspec,
                                                                  multiply=tf,
                                                                  multiply_even=True)
        pieces["row round trip + composite"] = lambda: rows.execute(rspec, out=rspec,
                                                                    mid_args=mid)
    for fn in pieces.values():
        fn()
        queue.finish()
    times: Dict[str, List[float]] = {k: [] for k in pieces}
    for _ in range(repeats):
        for name, fn in pieces.items():
            queue.finish()
            times[name].append(_median_time(fn, queue.finish))
    ms = {k: statistics.median(v) * 1e3 for k, v in times.items()}
    ms["whole render / L"] /= layers
    layer = ms["whole render / L"]
    if r.two_pass:
        used = ms["column round trip x H"] + ms["row round trip + composite"]
    else:
        used = (ms["composite"] + ms["forward (input pruned)"]
                + ms["inverse x H (output pruned)"])
    floor = ms["forward (input pruned)"] + ms["inverse alone"]
    Hp, Wp = r.padded
    print_fn(f"one layer of L={layers}, {H}x{W}, padded {Hp}x{Wp}, one colour, T=1 "
             f"(median of {repeats} interleaved rounds; the render's layer is "
             f"{'two kernels' if r.two_pass else 'four passes'}, the four-pass pieces are "
             f"timed beside it):")
    for name, t in ms.items():
        print_fn(f"  {name:<30}{t:8.2f} ms")
    print_fn(f"  {'multiply (inverse x H - alone)':<30}"
             f"{ms['inverse x H (output pruned)'] - ms['inverse alone']:8.2f} ms")
    print_fn(f"  {'multiply in the forward store':<30}"
             f"{ms['forward x H at its store'] - ms['forward (input pruned)']:8.2f} ms "
             f"(the placement before; now at the inverse's load)")
    print_fn(f"  {'launch + host (layer - pieces)':<30}{layer - used:8.2f} ms")
    print_fn(f"  layer / floor (two pruned transforms) = {layer / floor:.2f}")
    ms["floor"] = floor
    return ms


# ---------------------------------------------------------------------------------------------
# The SLM's real size (issue 10): 1080 x 1920, RGB, T frames, pad "auto"

#: Bytes one layer of one colour-frame must move at least, per padded sample: four FFT passes
#: (two per transform) that each read and write the complex64 grid once, plus the transfer
#: function read once: 4 x 2 x 8 + 8.
FLOOR_BYTES_PER_SAMPLE = 72
#: Bytes the two-kernel layer (issue 23) moves per sample of the cropped rows, H x Wp: the
#: column and the row round trip each read and write the complex64 row spectrum once,
#: 2 x 2 x 8 (the transfer function's and the layer's bytes, shared by a launch's fields, left
#: out: issue 23's "about 67 MB per layer and colour-frame" at 1080x1920 on 1125x1944).
TWO_KERNEL_BYTES_PER_SAMPLE = 32


def copy_bandwidth(queue, nbytes: int = 256 << 20, repeats: int = 5) -> float:
    """Device buffer-to-buffer copy bandwidth in bytes/s, counting read + write (best of
    ``repeats``): the floor for any pass that reads and writes global memory once.

    Parameters
    ----------
    queue : pyopencl.CommandQueue
        The device's queue.
    nbytes : int
        Size of the copied buffer, bytes.
    repeats : int
        Copies timed (the best counts).
    """
    import pyopencl as cl

    a = cl.Buffer(queue.context, cl.mem_flags.READ_WRITE, nbytes)
    b = cl.Buffer(queue.context, cl.mem_flags.READ_WRITE, nbytes)
    cl.enqueue_fill_buffer(queue, a, np.uint8(1), 0, nbytes)
    cl.enqueue_copy(queue, b, a)
    queue.finish()
    best = float("inf")
    for _ in range(repeats):
        t = time.perf_counter()
        cl.enqueue_copy(queue, b, a)
        queue.finish()
        best = min(best, time.perf_counter() - t)
    return 2 * nbytes / best


def _torch_batched_factory(color, alpha, tfs, padded, frames, peer: TorchPeer):
    """The same method in PyTorch on ``peer``'s device for ``frames`` frames and C colours at
    once (B = T C fields, like clholo's batch, one batch per layer); ``color`` is
    ``[L, H, W, C]``, ``tfs[i]`` is ``[C, Hp, Wp]``, moved to the device here, outside the timed
    region, as are the layers and the random generator."""
    torch = peer.torch
    dev = peer.device
    L, H, W, C = color.shape
    # copies: an MPI's arrays are read-only, which torch.from_numpy warns about
    a = torch.from_numpy(np.array(alpha))[:, None].to(dev)                    # [L, 1, H, W]
    c = torch.from_numpy(np.array(color.transpose(0, 3, 1, 2), order="C")).to(dev)
    keep = torch.sqrt(1 - a)
    amp = torch.sqrt(c * a)                                                    # [L, C, H, W]
    H_t = [torch.from_numpy(np.ascontiguousarray(t)).to(dev) for t in tfs]    # [C, Hp, Wp]
    gen = torch.Generator(device=dev).manual_seed(0)

    def run():
        with torch.no_grad():
            u = torch.zeros((frames, C, H, W), dtype=torch.complex64, device=dev)
            for i in range(L - 1, -1, -1):
                phi = torch.rand((frames, C, H, W), generator=gen, device=dev) * (2 * np.pi)
                v = keep[i] * u + amp[i] * torch.polar(torch.ones_like(phi), phi)
                big = torch.nn.functional.pad(v, (0, padded[1] - W, 0, padded[0] - H))
                u = torch.fft.ifft2(torch.fft.fft2(big) * H_t[i])[..., :H, :W]
            return u

    return run


def run_slm_benchmark(*, height: int = 1080, width: int = 1920, layers: int = 32,
                      frames: int = 3, repeats: int = 3, pad="auto", near: float = 2e-3,
                      far: float = 6e-3, print_fn=print) -> Dict[str, Any]:
    """clholo against the same method in PyTorch (on CUDA when clholo's device is a GPU and
    torch has CUDA, else on the CPU: :func:`torch_peer`) at the SLM's size, side by side.

    ``layers`` random RGB layers of ``height x width`` between ``near`` and ``far`` metres,
    ``frames`` frames per hologram; both sides run on clholo's padded grid (sizes 2^a 3^b 5^c,
    ``pad="auto"``; torch's FFT takes any size) with transfer functions precomputed outside the
    timed region. Prints per-colour-frame times, the ratio, clholo's time per layer (per
    colour-frame) against the copy-bandwidth floor measured in the same run
    (:data:`FLOOR_BYTES_PER_SAMPLE` per padded sample), and returns them, with ``"devices"``:
    each implementation's name -> the device it ran on.

    Parameters
    ----------
    height, width : int
        The SLM's size, pixels (Pluto-2.1: 1080 x 1920).
    layers : int
        Number of MPI layers.
    frames : int
        Frames per render.
    repeats : int
        Timed rounds (the median counts).
    pad : "auto", float or (int, int)
        Padding of each propagation: ``"auto"`` (what the band-limited kernel's spread needs),
        a factor per axis, or the padded grid ``(Hp, Wp)`` itself (sizes ``2^a 3^b 5^c``).
    near, far : float
        Depths of the nearest and farthest layer, metres.
    print_fn : callable
        Where the table's lines go (default :func:`print`).

    Returns
    -------
    dict
        Median seconds per call of each implementation (timed in blocks of back-to-back
        calls of at least :data:`MIN_BLOCK_S`), with ``"bandwidth"`` (bytes/s),
        ``"floor_ms"`` (four passes' bytes: :data:`FLOOR_BYTES_PER_SAMPLE`),
        ``"two_kernel_floor_ms"`` (the two kernels' own: :data:`TWO_KERNEL_BYTES_PER_SAMPLE`),
        ``"layer_ms"``, ``"padded"`` (the grid ``(Hp, Wp)``), ``"devices"``
        and ``"block_calls"`` (name -> calls per block).
    """
    import clholo
    from clholo.host import runtime
    from clholo.propagation import next_pow2

    queue = runtime.get_queue()
    optics = clholo.Optics()  # 8 um pitch, 638/520/450 nm
    C = optics.channels
    _check_random_layers(layers, height, width, C)
    rng = np.random.default_rng(0)
    color = rng.random((layers, height, width, C), dtype=np.float32)
    alpha = rng.random((layers, height, width), dtype=np.float32)
    mpi = clholo.MPI(color, alpha, np.linspace(near, far, layers))
    renderer = clholo.HologramRenderer(mpi, optics, seed=1, pad=pad, queue=queue,
                                       frames_per_batch=frames)
    Hp, Wp = renderer.padded
    out = clholo.host.scheduler.cla.empty(queue, (frames, C, height, width), np.complex64)
    steps = reference.layer_steps(mpi.depths)
    tfs = [np.stack([reference.transfer_function((Hp, Wp), float(s), wavelength=lam,
                                                 pitch=optics.pitch).astype(np.complex64)
                     for lam in optics.wavelengths]) for s in steps]
    peers: Dict[str, Tuple[Callable[[], object], Callable[[], None]]] = {
        "clholo (OpenCL)": (lambda: renderer.render(frames, out=out), queue.finish)}
    if renderer.two_pass:  # the layer as four passes (before issue 23), in the same rounds
        four = clholo.HologramRenderer(mpi, optics, seed=1, pad=pad, queue=queue,
                                       frames_per_batch=frames, two_pass=False)
        peers["clholo, four passes/layer"] = (lambda: four.render(frames, out=out), queue.finish)
    devices = {name: _opencl_where(queue) for name in peers}
    peer = torch_peer(queue.device)
    if peer is not None:
        peers[peer.label] = (_torch_batched_factory(color, alpha, tfs, (Hp, Wp), frames, peer),
                             peer.synchronize)
        devices[peer.label] = peer.where
    else:
        print_fn("(torch not installed: PyTorch column skipped; pip install clholo[bench])")
    p2 = (next_pow2(Hp), next_pow2(Wp))
    print_fn(f"MPI -> hologram at the SLM size: L={layers}, {height}x{width}, RGB, T={frames}, "
             f"pad {pad!r} -> grid {Hp}x{Wp} ({Hp * Wp / (p2[0] * p2[1]):.2f} of the "
             f"power-of-two grid {p2[0]}x{p2[1]}); device {_opencl_where(queue)}; "
             f"fused composite: {renderer.fuse_composite}; a layer is "
             f"{'two kernels' if renderer.two_pass else 'four passes'}")
    bws = []
    # interleaved, the bandwidth probe too
    calls: Dict[str, int] = {}
    med = _time_peers(peers, repeats, between=lambda: bws.append(copy_bandwidth(queue)),
                      block_calls=calls)
    bw = statistics.median(bws)
    per_cf = frames * C
    ours = med["clholo (OpenCL)"]
    print_fn(f"{'implementation':<28}{'s / hologram':>13}{'ms / colour-frame':>19}"
             f"{'ms / layer':>12}{'vs clholo':>11}  ran on")
    for name, t in med.items():
        print_fn(f"{name:<28}{t:>13.4f}{t / per_cf * 1e3:>19.2f}"
                 f"{t / per_cf / layers * 1e3:>12.3f}{t / ours:>10.2f}x  {devices[name]}")
    print_fn(_blocks_line(calls))
    floor = FLOOR_BYTES_PER_SAMPLE * Hp * Wp / bw
    two = TWO_KERNEL_BYTES_PER_SAMPLE * height * Wp / bw
    layer = ours / per_cf / layers
    print_fn(f"copy bandwidth {bw / 1e9:.1f} GB/s (read + write, median of {repeats}); floor "
             f"per layer and colour-frame {floor * 1e3:.2f} ms "
             f"({FLOOR_BYTES_PER_SAMPLE} B x {Hp}x{Wp}: four passes); clholo "
             f"{layer * 1e3:.2f} ms = {layer / floor:.2f}x the floor; the two kernels' own "
             f"bytes {two * 1e3:.2f} ms ({TWO_KERNEL_BYTES_PER_SAMPLE} B x {height}x{Wp}): "
             f"{layer / two:.2f}x those")
    result: Dict[str, Any] = {k: v for k, v in med.items()}
    result.update(bandwidth=bw, floor_ms=floor * 1e3, two_kernel_floor_ms=two * 1e3,
                  layer_ms=layer * 1e3, padded=(Hp, Wp), devices=devices, block_calls=calls)
    return result


# ---------------------------------------------------------------------------------------------
# The per-kernel profile (issue 23): where a render's or an SGD iteration's device time goes,
# each kernel's bytes against the copy bandwidth measured in the same run

def _profile_runs(run: Callable[[], object], queue, repeats: int):
    """``run`` once to warm up, then ``repeats`` times under one :class:`KernelRecorder`;
    returns the recorder and, per run, the median host seconds (until ``run`` returned:
    enqueueing), wall seconds (until the queue was idle) and device span (first launch's start
    to last one's end)."""
    from clholo.host import runtime

    run()
    queue.finish()
    host, wall, span = [], [], []
    with runtime.KernelRecorder() as rec:
        for _ in range(repeats):
            with runtime.KernelRecorder() as one:
                t = time.perf_counter()
                run()
                host.append(time.perf_counter() - t)
                queue.finish()
                wall.append(time.perf_counter() - t)
            span.append(one.device_span())
    return rec, statistics.median(host), statistics.median(wall), statistics.median(span)


def _profile_result(rec, host: float, wall: float, span: float, repeats: int,
                    bandwidth: float, **fields) -> Dict[str, Any]:
    rows = rec.summary(copy_bandwidth=bandwidth)
    kernel_s = sum(float(r["seconds"]) for r in rows) / repeats
    out: Dict[str, Any] = dict(fields)
    out.update(rows=rows, repeats=repeats, bandwidth=bandwidth, host_s=host, wall_s=wall,
               kernel_s=kernel_s, span_s=span)
    return out


def profile_render(*, height: int = 1080, width: int = 1920, colours: int = 3,
                   layers: int = 32, frames: int = 3, pad="auto", repeats: int = 3,
                   near: float = 2e-3, far: float = 6e-3, seed: int = 0,
                   queue=None) -> Dict[str, Any]:
    """Per-kernel device time of :meth:`HologramRenderer.render` of random RGB(A) layers.

    Parameters
    ----------
    height, width : int
        The field, pixels.
    colours : {1, 3}
        Colour channels (1: the green wavelength of :class:`clholo.Optics` alone).
    layers, frames : int
        MPI layers L and frames T of each render (all frames in one launch batch).
    pad : "auto", float or (int, int)
        The renderer's padding (``HologramRenderer``'s ``pad``).
    repeats : int
        Renders recorded after one warm-up; times are per render.
    near, far : float
        Depths of the nearest and farthest layer, metres.
    seed : int
        Seed of the random layers and of the renderer's phases.
    queue : pyopencl.CommandQueue, optional
        Default: clholo's queue.

    Returns
    -------
    dict
        ``"rows"`` (:meth:`clholo.host.runtime.KernelRecorder.summary`, summed over the
        repeats), ``"repeats"``, ``"bandwidth"`` (bytes/s, :func:`copy_bandwidth` in the same
        run), ``"host_s"`` (median seconds until ``render`` returned), ``"wall_s"`` (until the
        queue was idle), ``"kernel_s"`` (recorded device time per render), ``"span_s"``
        (median first start to last end of a render), ``"what"``, ``"padded"``, ``"per"`` (layer
        and colour-frame count ``L T C``) and ``"device"``.
    """
    import clholo
    from clholo.host import runtime
    from clholo.errors import InputError

    if colours not in (1, 3):
        raise InputError(f"colours is {colours!r}; give 1 or 3")
    for name, v in (("height", height), ("width", width), ("layers", layers),
                    ("frames", frames), ("repeats", repeats)):
        if int(v) < 1:
            raise InputError(f"{name} is {v!r}; give a positive integer")
    _check_random_layers(layers, height, width, colours)
    queue = queue or runtime.get_queue()
    optics = clholo.Optics()
    if colours == 1:
        optics = clholo.Optics(wavelengths=(optics.wavelengths[1],))
    rng = np.random.default_rng(seed)
    color = rng.random((layers, height, width, colours), dtype=np.float32)
    alpha = rng.random((layers, height, width), dtype=np.float32)
    mpi = clholo.MPI(color, alpha, np.linspace(near, far, layers))
    renderer = clholo.HologramRenderer(mpi, optics, seed=seed, pad=pad, queue=queue,
                                       frames_per_batch=frames)
    out = clholo.host.scheduler.cla.empty(queue, (frames, colours, height, width),
                                          np.complex64)
    bandwidth = copy_bandwidth(queue, min(256 << 20, max(16 << 20, 8 * renderer.padded[0]
                                                         * renderer.padded[1] * colours)))
    rec, host, wall, span = _profile_runs(lambda: renderer.render(frames, out=out), queue,
                                          repeats)
    return _profile_result(
        rec, host, wall, span, repeats, bandwidth, padded=tuple(renderer.padded),
        per=layers * frames * colours, device=_opencl_where(queue),
        what=(f"render: L={layers}, {height}x{width}, {colours} colour(s), T={frames}, "
              f"grid {renderer.padded[0]}x{renderer.padded[1]}, "
              f"{'two kernels' if renderer.two_pass else 'four passes'} per layer"))


def profile_sgd(*, size: int = 1024, pad="auto", iterations: int = 5, z: float = 0.04,
                seed: int = 0, fuse: Optional[str] = None, queue=None) -> Dict[str, Any]:
    """Per-kernel device time of SGD phase retrieval (``PhaseRetrieval.step``), as
    ``benchmarks/bench_sgd.py`` runs it: one field at 520 nm and 8 um pitch.

    Parameters
    ----------
    size : int
        The field is ``size x size`` pixels.
    pad : "auto" or float
        Padding of both propagations (``device_padded_shape``'s ``pad``).
    iterations : int
        Steps recorded after one warm-up; times are per iteration.
    z : float
        SLM -> target plane, metres.
    seed : int
        Seed of the random target and start phase.
    fuse : {"none", "residual", "all", "round-trips"}, optional
        The form of the iteration (``PhaseRetrieval``'s ``fuse``; default the device's,
        :func:`clholo.host.phase_retrieval.default_fuse`).
    queue : pyopencl.CommandQueue, optional
        Default: clholo's queue.

    Returns
    -------
    dict
        What :func:`profile_render` returns (``"per"``: 1).
    """
    import pyopencl.array as cla

    from clholo.host import runtime
    from clholo.host.phase_retrieval import PhaseRetrieval
    from clholo.propagation import device_padded_shape
    from clholo.errors import InputError

    for name, v in (("size", size), ("iterations", iterations)):
        if int(v) < 1:
            raise InputError(f"{name} is {v!r}; give a positive integer")
    queue = queue or runtime.get_queue()
    lam, pitch = 520e-9, 8e-6
    padded = device_padded_shape((size, size), z, wavelength=lam, pitch=pitch, pad=pad)
    rng = np.random.default_rng(seed)
    target = (rng.standard_normal((1, size, size))
              + 1j * rng.standard_normal((1, size, size))).astype(np.complex64)
    try:
        eng = PhaseRetrieval(cla.to_device(queue, target), wavelengths=[lam], pitch=pitch, z=z,
                             padded=padded, queue=queue, fuse=fuse)
    except ValueError as exc:
        raise InputError(str(exc)) from None
    eng.set_phase(cla.to_device(queue, rng.uniform(0, 2 * np.pi, (1, size, size)
                                                   ).astype(np.float32)))
    bandwidth = copy_bandwidth(queue, min(256 << 20, max(16 << 20, 8 * padded[0] * padded[1])))
    rec, host, wall, span = _profile_runs(eng.step, queue, iterations)
    return _profile_result(rec, host, wall, span, iterations, bandwidth, padded=tuple(padded), per=1,
                           device=_opencl_where(queue),
                           what=f"SGD iteration: {size}x{size}, grid {padded[0]}x{padded[1]}, "
                                f"fuse {eng.fuse}")


def format_profile(result: Dict[str, Any]) -> List[str]:
    """A :func:`profile_render` / :func:`profile_sgd` result as Markdown lines: a header, one
    table row per kernel (per run: launches, ms, share; bytes, GB/s and the ratio to a copy of
    the same bytes where known) and the host's enqueue time against the device's."""
    n = result["repeats"]
    bw = result["bandwidth"]
    lines = [f"{result['what']}; device {result['device']}; copy bandwidth "
             f"{bw / 1e9:.1f} GB/s (read + write)", "",
             "| kernel | launches | ms | share | MB moved | GB/s | x copy time |",
             "|---|---|---|---|---|---|---|"]
    for r in result["rows"]:
        nbytes = r["bytes"]
        mb = f"{int(nbytes) / n / 1e6:.1f}" if nbytes is not None else "n/a"
        gbs = f"{float(r['bandwidth']) / 1e9:.1f}" if r["bandwidth"] is not None else "n/a"
        ratio = f"{float(r['floor_ratio']):.2f}" if r["floor_ratio"] is not None else "n/a"
        lines.append(f"| {r['label']} | {int(r['launches']) / n:g} | "
                     f"{float(r['seconds']) / n * 1e3:.3f} | {float(r['share']) * 100:.1f} % | "
                     f"{mb} | {gbs} | {ratio} |")
    host, wall, kern, span = (result[k] for k in ("host_s", "wall_s", "kernel_s", "span_s"))
    lines += ["",
              f"per run: kernels {kern * 1e3:.3f} ms ({kern / result['per'] * 1e3:.3f} ms per "
              f"{'layer and colour-frame' if result['per'] > 1 else 'iteration'}), device span "
              f"{span * 1e3:.3f} ms (idle {max(span - kern, 0.0) * 1e3:.3f} ms between "
              f"launches), wall {wall * 1e3:.3f} ms; the host enqueued it in "
              f"{host * 1e3:.3f} ms = {host / wall * 100 if wall > 0 else 0.0:.0f} % of the wall "
              f"time (issue 23's goal: <= 20 %)"]
    return lines
