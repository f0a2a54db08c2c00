"""`clholo bench --slm` machinery at a tiny size (the figures themselves go in
docs/benchmarks.md, never in tests)."""

import numpy as np
import pytest

from clholo import bench


@pytest.fixture(autouse=True)
def heap_untouched(monkeypatch):
    """Not the test process's heap (see tests/test_bench_peers.py)."""
    monkeypatch.setattr(bench, "keep_host_heap", lambda: True)


def test_copy_bandwidth_positive(queue):
    bw = bench.copy_bandwidth(queue, nbytes=1 << 20, repeats=2)
    assert np.isfinite(bw) and bw > 0


def test_slm_benchmark_runs_at_a_tiny_size():
    lines = []
    res = bench.run_slm_benchmark(height=12, width=20, layers=2, frames=1, repeats=1,
                                  print_fn=lines.append)
    from clholo.fft import is_fft_size

    assert all(is_fft_size(n) and n >= f for n, f in zip(res["padded"], (12, 20)))
    assert res["layer_ms"] > 0 and res["floor_ms"] > 0
    # the two kernels move 32 B per sample of the H x Wp rows, four passes 72 of Hp x Wp
    Hp, Wp = res["padded"]
    np.testing.assert_allclose(res["two_kernel_floor_ms"] / res["floor_ms"],
                               (32 * 12 * Wp) / (72 * Hp * Wp), rtol=1e-12)
    assert any("clholo (OpenCL)" in line for line in lines)
    assert any("x the floor" in line and f"(32 B x 12x{Wp})" in line for line in lines)


def test_layer_breakdown_runs_on_a_non_square_field():
    """The breakdown's pieces run on the renderer's own plans for an (H, W) field (the SLM's
    shape in docs/benchmarks.md), and its printout names that shape and the padded grid."""
    from clholo.bench import run_hologram_breakdown

    lines = []
    ms = run_hologram_breakdown(size=(24, 40), layers=3, repeats=1, pad="auto",
                                print_fn=lines.append)
    assert lines[0].startswith("one layer of L=3, 24x40, padded ")
    assert set(ms) >= {"composite", "forward (input pruned)", "inverse x H (output pruned)",
                       "whole render / L", "floor"}
    assert all(v > 0 and v == v for k, v in ms.items() if k != "floor") and ms["floor"] > 0
