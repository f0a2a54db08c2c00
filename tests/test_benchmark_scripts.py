"""The benchmark scripts' command lines: a mistake is refused by argparse before anything is
built or measured (exit 2, naming the argument and its rule), not a traceback, a division by
zero or an empty median minutes into a lent GPU's time; times in milliseconds keep three
significant digits; PyTorch as a peer is required where ``CLHOLO_BENCH_PEER`` says so."""

import importlib.util
import re
import sys
import types
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
BENCH = ROOT / "benchmarks"


def _script(name):
    spec = importlib.util.spec_from_file_location(f"bench_script_{name}", BENCH / f"{name}.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


MISTAKES = [
    ("bench_sgd", ["--size", "0"], "argument --size: must be a whole number >= 1"),
    ("bench_sgd", ["--iterations", "0"], "argument --iterations: must be a whole number >= 1"),
    ("bench_sgd", ["--rounds", "0"], "argument --rounds"),
    ("bench_sgd", ["--pad", "0"], "argument --pad: must be 'auto' or a finite factor >= 1"),
    ("bench_sgd", ["--z", "nan"], "argument --z: must be a finite number > 0"),
    ("bench_hologram", ["--size", "0"], "argument --size"),
    ("bench_hologram", ["--layers", "0"], "argument --layers"),
    ("bench_hologram", ["--repeats", "0"], "argument --repeats"),
    ("bench_hologram", ["--pad", "0"], "argument --pad"),
    ("bench_hologram", ["--pad", "inf"], "argument --pad"),
    ("bench_hologram", ["--breakdown-only", "--shape", "0x8"], "argument --shape"),
    ("bench_fft", ["--skip", "numpy,pyfftww"], "argument --skip: unknown 'pyfftww'; choose from"),
    ("bench_fft", ["--sizes", "1024,1001"], "1001 is not a size clholo.fft takes"),
    ("bench_fft", ["--sizes", "20000"], "20000 is not a size clholo.fft takes"),
    ("bench_fft", ["--batch", "8x1001"], "argument --batch"),
    ("bench_fft", ["--rounds", "0"], "argument --rounds"),
    ("bench_fft", ["--budget", "0"], "argument --budget"),
    ("bench_fft", ["--sizes", "", "--batch", ""], "name no transform"),
    ("bench_display_batch", ["--repeats", "0"], "argument --repeats"),
    ("bench_display_batch", ["--loop", "--loop-batches", "2"],
     "argument --loop-batches: must be a whole number >= 3"),
    ("bench_display_batch", ["--size", "0", "40"], "argument --size"),
    ("bench_display_batch", ["--layers", "0"], "argument --layers"),
    ("profile_kernels", ["--repeats", "0"], "argument --repeats"),
    ("profile_kernels", ["--sgd", "32", "--iterations", "0"], "argument --iterations"),
    ("profile_kernels", ["--pad", "0.5"], "argument --pad"),
    ("profile_kernels", ["--shape", "24by40"], "--shape takes HxW"),
    ("profile_kernels", ["--markdown", "/no/such/folder/profile.md"],
     "its folder /no/such/folder does not exist"),
    ("fft_variants", ["--sizes", "30x41"], "41 is not a size clholo.fft takes"),
    ("fft_variants", ["--rounds", "0"], "argument --rounds"),
    ("fft_variants", ["--repeats", "0"], "argument --repeats"),
    ("fft_variants", ["--variants", "fixed,nosuch"], "unknown 'nosuch'"),
    ("fft_variants", ["--layers", "0"], "argument --layers"),
    ("fft_variants", ["--sgd", "0"], "argument --sgd"),
    ("bench_enqueue", ["--fft", "1001"], "1001 is not a size clholo.fft takes"),
    ("bench_enqueue", ["--repeats", "0"], "argument --repeats"),
    ("bench_enqueue", ["--launches", "0"], "argument --launches"),
    ("bench_enqueue", ["--shape", "0x4"], "argument --shape"),
    ("bench_views", ["--repeats", "0"], "argument --repeats"),
    ("bench_rpws", ["cost", "--steps", "0"], "argument --steps"),
    ("bench_batch", ["--rounds", "0"], "argument --rounds"),
    ("soak_display", ["--seconds", "nan"], "argument --seconds"),
]


@pytest.mark.parametrize("name, argv, message", MISTAKES,
                         ids=[f"{n}{''.join(a)}" for n, a, _ in MISTAKES])
def test_a_mistake_is_refused_before_anything_runs(monkeypatch, capsys, name, argv, message):
    """Refused by argparse (exit 2, the argument and its rule named), before a queue is made:
    ``--size 0`` no longer reads "--fuse None: input_shape[0] = 0", ``--repeats 0`` no longer
    ends in an empty median, an unknown ``--skip`` name no longer selects nothing silently."""
    from clholo.host import runtime

    def measured(*a, **k):
        raise AssertionError("measured before checking its arguments")

    monkeypatch.setattr(runtime, "get_queue", measured)
    mod = _script(name)
    monkeypatch.setattr(sys, "argv", [f"{name}.py", *argv])
    with pytest.raises(SystemExit) as stop:
        mod.main()
    err = capsys.readouterr().err
    assert stop.value.code == 2, err
    assert message in err, err


def test_milliseconds_keep_three_significant_digits():
    args = _script("_bench_args")
    assert [args.ms(v) for v in (0.0263, 0.004, 2.634, 26.34, 263.4, 2634.0, 0.0, 0.99951)] == \
        ["0.0263", "0.00400", "2.63", "26.3", "263", "2634", "0", "1.000"]
    assert args.ms(float("nan")) == "nan"


def test_bench_fft_prints_small_times_with_three_digits_and_survives_a_failing_shape(
        monkeypatch, capsys):
    """A GPU's 0.026 ms FFT printed as 0.03 (two decimals); and one shape failing on the device
    ended the whole run: now its line says why, the others are timed, and the exit status is
    1."""
    bench_fft = _script("bench_fft")
    real = bench_fft.run

    def run(shape, *a, **k):
        if shape == (16, 16):
            raise RuntimeError("this device refused it")
        res, n = real(shape, *a, **k)
        return {name: ms / 1000 for name, ms in res.items()}, n   # microseconds, as on a GPU

    monkeypatch.setattr(bench_fft, "run", run)
    with pytest.raises(SystemExit) as stop:
        bench_fft.main(["--sizes", "16,8", "--batch", "", "--rounds", "3", "--budget", "0.05",
                        "--skip", "numpy,scipy,pyfftw,torch,pyvkfft"])
    assert "1 of 2 shapes failed: 16x16" in str(stop.value.code)
    out = capsys.readouterr().out
    assert "16x16 failed: RuntimeError: this device refused it" in out
    (row,) = [line for line in out.splitlines() if re.match(r"\s+8x8\s+clholo dev ", line)]
    value = row.split()[3]
    assert re.fullmatch(r"0\.0*[1-9]\d\d", value), row


def test_fft_variants_exits_non_zero_when_every_variant_fails(monkeypatch, capsys):
    fv = _script("fft_variants")

    def fails(*a, **k):
        raise RuntimeError("out of resources")

    monkeypatch.setattr(fv, "measure_variant", fails)
    with pytest.raises(SystemExit) as stop:
        fv.main(["--variants", "fixed,unfused", "--sizes", ""])
    assert "2 of 2 variants failed (fixed, unfused)" in str(stop.value.code)
    out = capsys.readouterr().out
    assert "| error | fixed | nan |" in out and "| error | unfused | nan |" in out


# --- PyTorch as the peer: required where CLHOLO_BENCH_PEER says so -----------------------------

GPU, CPU = 1 << 2, 1 << 1


def _device(kind, name="NVIDIA H100 80GB HBM3"):
    return types.SimpleNamespace(type=kind, name=name)


def test_a_cpu_peer_for_a_gpu_is_refused_where_required(monkeypatch):
    """torch without CUDA (this machine's CPU build) on a GPU device: by default the CPU peer,
    as before (its table says "PyTorch ... CPU"); under gpu_checks.py (required) refused with
    a message naming --allow-cpu-peer; with it (any), the CPU peer."""
    pytest.importorskip("torch", reason="the bench extra: pip install 'clholo[bench]'")
    from clholo import bench

    monkeypatch.setattr("torch.cuda.is_available", lambda: False)
    monkeypatch.delenv(bench.PEER_ENV, raising=False)
    assert bench.torch_peer(_device(GPU), threads=1).kind == "cpu"
    monkeypatch.setenv(bench.PEER_ENV, "required")
    with pytest.raises(SystemExit, match="no CUDA PyTorch peer: clholo's OpenCL device NVIDIA "
                                         "H100 80GB HBM3 is a GPU") as stop:
        bench.torch_peer(_device(GPU), threads=1)
    assert "--allow-cpu-peer" in str(stop.value.code)
    # a CPU device's peer is PyTorch on the CPU, required or not
    assert bench.torch_peer(_device(CPU, "pthread-cpu"), threads=1).kind == "cpu"
    monkeypatch.setenv(bench.PEER_ENV, "any")
    assert bench.torch_peer(_device(GPU), threads=1).kind == "cpu"
    monkeypatch.setenv(bench.PEER_ENV, "sometimes")
    from clholo.errors import InputError

    with pytest.raises(InputError, match="CLHOLO_BENCH_PEER='sometimes'"):  # exit 2, one line
        bench.torch_peer(_device(CPU), threads=1)


def test_a_missing_torch_is_refused_where_a_peer_is_required(monkeypatch):
    from clholo import bench

    monkeypatch.setitem(sys.modules, "torch", None)  # import torch raises ImportError
    monkeypatch.delenv(bench.PEER_ENV, raising=False)
    assert bench.torch_peer(_device(GPU)) is None
    for rule in ("required", "any"):
        monkeypatch.setenv(bench.PEER_ENV, rule)
        with pytest.raises(SystemExit, match="no PyTorch peer: torch is not installed"):
            bench.torch_peer(_device(CPU))
