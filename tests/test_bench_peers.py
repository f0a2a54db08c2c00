"""Where the benchmarks' PyTorch peer runs (issue 22): on CUDA when clholo's OpenCL device is a
GPU and ``torch.cuda.is_available()``, else on the CPU, and every table names the device each
implementation ran on. This machine has no GPU and a CPU build of torch (if any), so the CUDA
branch runs here with a fake torch, or with the real one whose ``torch.cuda`` is faked (its
tensors then stay on the CPU: everything else is the CUDA branch). No timing is checked."""

import dataclasses
import importlib.util
import sys
import time
import types
from pathlib import Path

import numpy as np
import pytest

from clholo import bench

ROOT = Path(__file__).resolve().parents[1]
GPU, CPU = 1 << 2, 1 << 1   # CL_DEVICE_TYPE_GPU, CL_DEVICE_TYPE_CPU


class FakeCLDevice:
    """What torch_peer reads of a pyopencl.Device."""

    def __init__(self, type_, name, platform="Fake platform"):
        self.type = type_
        self.name = name
        self.platform = types.SimpleNamespace(name=platform)


def fake_torch(calls, *, cuda=True, cuda_names=("NVIDIA H100 80GB HBM3",), current=0):
    """A stand-in ``torch`` module: ``calls`` records what is called, in order."""
    t = types.ModuleType("torch")
    t.__version__ = "9.9.9+fake"
    threads = {"n": 1}

    def set_num_threads(n):
        calls.append(("set_num_threads", n))
        threads["n"] = n

    t.set_num_threads = set_num_threads
    t.get_num_threads = lambda: threads["n"]
    t.cuda = types.SimpleNamespace(
        is_available=lambda: cuda,
        device_count=lambda: len(cuda_names),
        get_device_name=lambda i: cuda_names[i],
        current_device=lambda: current,
        synchronize=lambda: calls.append("synchronize"))

    class Tensor:
        def to(self, device):
            calls.append(("to", device))
            return self

    t.from_numpy = lambda a: Tensor()
    t.fft = types.SimpleNamespace(fft2=lambda x: calls.append("fft2"))
    return t


@pytest.fixture
def calls():
    return []


@pytest.fixture(autouse=True)
def heap_untouched(monkeypatch):
    """The benchmarks keep the host heap (glibc's mallopt, for the rest of the process): not
    in the test process, where it would hold every later test's freed memory. Its effect is
    tested in a process of its own (test_keeping_the_heap_stops_the_page_faults)."""
    monkeypatch.setattr(bench, "keep_host_heap", lambda: True)


_PAGE_FAULTS = """
import resource, sys
import numpy as np
from clholo import bench
if sys.argv[1] == "keep":
    assert bench.keep_host_heap() and bench.keep_host_heap()  # once, then remembered
def faults():
    return resource.getrusage(resource.RUSAGE_SELF).ru_minflt
a = np.ones(64 << 20, np.uint8)   # 64 MiB: mapped anew by default, whatever came before
del a
f0 = faults()
for _ in range(5):
    a = np.ones(64 << 20, np.uint8)
    del a
print(faults() - f0)
"""


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="mallopt is glibc's (Linux)")
def test_keeping_the_heap_stops_the_page_faults():
    """A host peer's temporaries, freed and allocated again, fault their pages in anew every
    call by default; with the heap kept they are reused (PyTorch's SGD step at 1024^2: 31-110
    ms against 32-36 ms)."""
    import subprocess

    def faults(mode):
        out = subprocess.run([sys.executable, "-c", _PAGE_FAULTS, mode], capture_output=True,
                             text=True, timeout=120, check=True)
        return int(out.stdout.strip())

    default, kept = faults("default"), faults("keep")
    assert default >= 5 * 32, (default, kept)  # at least one fault per 2 MiB page, each time
    assert kept * 20 < default, (default, kept)


def test_peer_is_cuda_when_the_opencl_device_is_a_gpu_and_cuda_is_there(monkeypatch, calls):
    monkeypatch.setitem(sys.modules, "torch",
                        fake_torch(calls, cuda_names=("NVIDIA A100", "NVIDIA H100 80GB HBM3")))
    peer = bench.torch_peer(FakeCLDevice(GPU, "NVIDIA H100 80GB HBM3 "))
    # the CUDA device of the OpenCL device's name, not torch's current one
    assert (peer.kind, peer.device) == ("cuda", "cuda:1")
    assert peer.label == "PyTorch 9.9.9+fake CUDA"
    assert peer.where == "cuda:1 NVIDIA H100 80GB HBM3"
    assert not any(c[0] == "set_num_threads" for c in calls if isinstance(c, tuple))
    peer.synchronize()
    assert calls == ["synchronize"]


def test_peer_on_cuda_takes_the_current_device_when_no_name_matches(monkeypatch, calls):
    monkeypatch.setitem(sys.modules, "torch",
                        fake_torch(calls, cuda_names=("GPU A", "GPU B"), current=1))
    peer = bench.torch_peer(FakeCLDevice(GPU | 1, "Radeon"))   # GPU bit among others
    assert (peer.kind, peer.device, peer.where) == ("cuda", "cuda:1", "cuda:1 GPU B")


@pytest.mark.parametrize("cl_type, cuda", [(GPU, False), (CPU, True), (CPU, False)])
def test_peer_is_the_cpu_otherwise(monkeypatch, calls, cl_type, cuda):
    """A GPU without CUDA in torch, or a CPU OpenCL device (CUDA there or not): torch on the
    CPU, with the threads asked for, and synchronize waits for nothing."""
    monkeypatch.setitem(sys.modules, "torch", fake_torch(calls, cuda=cuda))
    peer = bench.torch_peer(FakeCLDevice(cl_type, "NVIDIA H100 80GB HBM3"), threads=3)
    assert (peer.kind, peer.device) == ("cpu", "cpu")
    assert peer.label == "PyTorch 9.9.9+fake CPU"
    assert peer.where == "CPU, 3 threads, heap kept"
    peer.synchronize()
    assert calls == [("set_num_threads", 3)]


def test_no_peer_without_torch(monkeypatch):
    monkeypatch.setitem(sys.modules, "torch", None)   # import torch raises ImportError
    assert bench.torch_peer(FakeCLDevice(GPU, "x")) is None


def test_each_timing_waits_for_its_own_device_before_and_after(calls):
    """_time_peers: two warm-up runs each (the second times a call warm), then interleaved
    rounds; each block of runs sits between two waits on its own device (queue.finish for
    clholo, torch.cuda.synchronize for CUDA)."""
    peers = {name: (lambda n=name: calls.append(f"run {n}"),
                    lambda n=name: calls.append(f"sync {n}")) for name in ("a", "b")}
    blocks = {}
    med = bench._time_peers(peers, 2, between=lambda: calls.append("round"), min_block_s=0,
                            block_calls=blocks)
    assert set(med) == {"a", "b"} and all(v >= 0 for v in med.values())
    assert blocks == {"a": 1, "b": 1}
    one = ["sync a", "run a", "sync a", "sync b", "run b", "sync b"]
    warm = ["sync a", "run a", "sync a"] * 2 + ["sync b", "run b", "sync b"] * 2
    assert calls == warm + ["round"] + one + ["round"] + one


def test_short_calls_are_timed_in_blocks(calls, monkeypatch):
    """A call of a few milliseconds (a render on a GPU) is timed in a block of back-to-back
    calls lasting at least min_block_s, waited for once at each end, and reported per call;
    a call longer than that is timed alone; a first call of 10 s or more is not repeated."""
    def sleeper(name, seconds):
        def run():
            calls.append(f"run {name}")
            time.sleep(seconds)
        return run, lambda: calls.append(f"sync {name}")

    peers = {"short": sleeper("short", 0.002), "long": sleeper("long", 0.06)}
    blocks = {}
    med = bench._time_peers(peers, 3, min_block_s=0.05, block_calls=blocks)
    # about 25 calls of 2 ms a block (fewer where a loaded machine oversleeps)
    assert 3 <= blocks["short"] <= 25 and blocks["long"] == 1, blocks
    # per call, not per block
    assert 0.002 <= med["short"] < 0.0015 * blocks["short"], (med, blocks)
    assert 0.06 <= med["long"] < 0.5, med
    # after the two warm-up runs each, every block: one sync, its runs, one sync
    rounds = calls[12:]
    block = ["sync short"] + ["run short"] * blocks["short"] + ["sync short"]
    assert rounds == (block + ["sync long", "run long", "sync long"]) * 3
    # a slow first call (builds, or seconds of work) sizes the blocks alone
    calls.clear()
    monkeypatch.setattr(bench, "_REWARM_BELOW_S", 0.001)
    bench._time_peers({"short": sleeper("short", 0.002)}, 1, min_block_s=0.05)
    assert calls[:3] == ["sync short", "run short", "sync short"] and calls[3] == "sync short"
    assert bench._block_calls(0.0, 0.05) == bench.MAX_BLOCK_CALLS
    assert bench._block_calls(1e-6, 0.05) == bench.MAX_BLOCK_CALLS
    assert bench._block_calls(2.0, 0.05) == 1


def _load_script(name):
    spec = importlib.util.spec_from_file_location(name, ROOT / "benchmarks" / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_bench_fft_times_torch_on_cuda_on_a_gpu(monkeypatch, calls):
    """bench_fft's torch contender on a GPU: "torch cuda", its input moved to the device
    before timing, synchronize around the transform, and its device named."""
    bench_fft = _load_script("bench_fft")
    monkeypatch.setitem(sys.modules, "torch", fake_torch(calls))
    queue = types.SimpleNamespace(device=FakeCLDevice(GPU, "NVIDIA H100 80GB HBM3"))
    monkeypatch.setattr("clholo.fft.FFTPlan", lambda *a, **k: None)
    monkeypatch.setattr("pyopencl.array.to_device", lambda q, a: a)
    monkeypatch.setattr("pyopencl.array.empty", lambda q, shape, dtype: None)
    where = {}
    cands = dict(bench_fft._contenders((8, 8), np.zeros((8, 8), np.complex64), queue, "auto",
                                       {"numpy", "scipy", "pyfftw", "pyvkfft"}, where))
    assert "torch cuda" in cands and "torch" not in cands
    assert calls == [("to", "cuda:0")]
    cands["torch cuda"]()
    assert calls[1:] == ["synchronize", "fft2", "synchronize"]
    assert where["torch cuda"] == "PyTorch 9.9.9+fake CUDA, cuda:0 NVIDIA H100 80GB HBM3"
    assert where["clholo dev"] == "Fake platform / NVIDIA H100 80GB HBM3"


# --- the hologram benchmarks' CUDA branch with the real torch (CPU build) ------------------------

@pytest.fixture
def torch_as_if_on_a_gpu(monkeypatch, queue, calls):
    """Real torch whose torch.cuda says a GPU of the OpenCL device's name is there, and a
    torch_peer that sees the OpenCL device as a GPU; the peer's tensors stay on the CPU (a CPU
    build cannot allocate on CUDA), so every other line of the CUDA branch runs."""
    torch = pytest.importorskip("torch", reason="the bench extra: pip install 'clholo[bench]'")
    name = queue.device.name.strip()
    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)
    monkeypatch.setattr(torch.cuda, "device_count", lambda: 1)
    monkeypatch.setattr(torch.cuda, "get_device_name", lambda i: name)
    monkeypatch.setattr(torch.cuda, "synchronize", lambda: calls.append("synchronize"))
    real = bench.torch_peer

    def as_gpu(cl_device, **kw):
        peer = real(FakeCLDevice(GPU, cl_device.name), **kw)
        assert (peer.kind, peer.device) == ("cuda", "cuda:0")
        return dataclasses.replace(peer, device="cpu")

    monkeypatch.setattr(bench, "torch_peer", as_gpu)
    return torch


def test_hologram_benchmark_names_pytorch_cuda_and_its_device(torch_as_if_on_a_gpu, queue, calls):
    lines = []
    res = bench.run_hologram_benchmark(size=16, layers=2, repeats=2, scaling=False,
                                       print_fn=lines.append)
    label = f"PyTorch {torch_as_if_on_a_gpu.__version__} CUDA"
    dev = queue.device.name.strip()
    where = f"{queue.device.platform.name.strip()} / {dev}"
    want = {"clholo (OpenCL)": where, "NumPy complex64": "CPU (host), heap kept",
            label: f"cuda:0 {dev}"}
    # the four-pass layer, beside the two-kernel one, where the renderer runs two kernels
    want.update({k: where for k in res["devices"] if k.startswith("clholo, four passes")})
    assert res["devices"] == want
    assert res[label] > 0
    row = next(line for line in lines if line.startswith(label))
    assert row.endswith(f"cuda:0 {dev}")
    assert "ran on" in next(line for line in lines if line.startswith("implementation"))
    # two warm-up runs + 2 rounds, each run or block of runs between two waits on the GPU
    assert calls.count("synchronize") == 2 * 4
    assert set(res["block_calls"]) == set(want) and min(res["block_calls"].values()) >= 1
    assert any(line.startswith("timed per call, in blocks") for line in lines)
    # without the NumPy version (seconds a call; a lent GPU's time is scarce)
    res = bench.run_hologram_benchmark(size=16, layers=2, repeats=1, scaling=False, numpy=False,
                                       print_fn=lines.append)
    assert "NumPy complex64" not in res and "NumPy complex64" not in res["devices"]
    assert label in res and "clholo (OpenCL)" in res


def test_slm_benchmark_batches_frames_and_colours_on_the_peer(torch_as_if_on_a_gpu, queue, calls):
    """--slm's PyTorch peer on the GPU: one batch of T C fields per layer, the result of the
    same shape as clholo's, its device in the table and in the result."""
    lines = []
    res = bench.run_slm_benchmark(height=12, width=20, layers=2, frames=2, repeats=1,
                                  print_fn=lines.append)
    label = f"PyTorch {torch_as_if_on_a_gpu.__version__} CUDA"
    assert res["devices"][label] == f"cuda:0 {queue.device.name.strip()}"
    assert any(line.startswith(label) and line.endswith(res["devices"][label])
               for line in lines)
    assert calls.count("synchronize") == 2 * 3  # two warm-up runs, one round
    peer = bench.torch_peer(queue.device)
    tfs = [np.ones((3, 24, 40), np.complex64)] * 2
    run = bench._torch_batched_factory(np.full((2, 12, 20, 3), 0.25, np.float32),
                                       np.ones((2, 12, 20), np.float32), tfs, (24, 40), 2, peer)
    u = run().numpy()
    assert u.shape == (2, 3, 12, 20)
    # opaque layers of intensity 0.25 and identity steps: |u| = 0.5 in every frame and colour,
    # with phases that differ between them (each field draws its own)
    np.testing.assert_allclose(np.abs(u), 0.5, rtol=1e-5)
    assert len({float(np.angle(u[t, c, 0, 0])) for t in range(2) for c in range(3)}) == 6
