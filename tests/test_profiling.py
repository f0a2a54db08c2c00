"""The per-kernel profile (issue 23): ``runtime.KernelRecorder``, the bytes each FFT pass is
counted with, ``clholo.bench.profile_render`` / ``profile_sgd`` and
``benchmarks/profile_kernels.py``."""

import subprocess
import sys
from pathlib import Path

import numpy as np
import pyopencl.array as cla
import pytest

from clholo.bench import format_profile, profile_render, profile_sgd
from clholo.errors import InputError
from clholo.fft import FFTPlan, RoundTripPlan
from clholo.host import runtime

ROOT = Path(__file__).resolve().parents[1]


def _field(queue, rng, shape):
    return cla.to_device(queue, (rng.standard_normal(shape)
                                 + 1j * rng.standard_normal(shape)).astype(np.complex64))


def test_recorder_sees_launches_only_while_active_and_nests(queue, rng):
    x = _field(queue, rng, (2, 48, 80))
    plan = FFTPlan(x.shape, np.complex64, queue=queue)
    plan.execute(x, out=x)  # before: not recorded
    with runtime.KernelRecorder() as outer:
        plan.execute(x, out=x)
        with runtime.KernelRecorder() as inner:
            plan.execute(x, out=x, inverse=True)
    plan.execute(x, out=x)  # after: not recorded
    queue.finish()
    npass = len(plan.geometry.passes)
    assert npass >= 2
    assert len(outer.launches) == 2 * sum(len(p.launches) for p in plan.geometry.passes)
    assert len(inner.launches) == len(outer.launches) // 2
    assert inner.launches == outer.launches[len(outer.launches) // 2:]
    assert all(r.seconds >= 0 for r in outer.launches)
    assert runtime._recorders == []


def test_fft_passes_count_one_read_and_one_write_of_the_field(queue, rng):
    B, H, W = 3, 40, 72
    x = _field(queue, rng, (B, H, W))
    plan = FFTPlan(x.shape, np.complex64, queue=queue)
    with runtime.KernelRecorder() as rec:
        plan.execute(x, out=x)
    queue.finish()
    field = B * H * W * 8
    single = [r for r in rec.launches
              if not r.label.endswith("stages")]  # global stages read their own buffers
    assert single, [r.label for r in rec.launches]
    for r in single:
        assert r.bytes_moved == 2 * field, r
    labels = {r.label.split(" n=")[0].split()[-1] for r in rec.launches}
    assert labels == {"rows", "cols"}

    # a zero-padded row transform: reads W of each row, writes all Wp
    Wp = 90
    y = _field(queue, rng, (B, H, Wp))
    padded = FFTPlan((B, H, Wp), np.complex64, queue=queue, axes=(-1,), input_shape=(W,))
    with runtime.KernelRecorder() as rec1:
        padded.execute(x, out=y)
    queue.finish()
    (only,) = rec1.launches
    assert only.bytes_moved == B * H * (W + Wp) * 8

    rt = RoundTripPlan((B, H, W), 48, axis="cols", first="forward", queue=queue)
    with runtime.KernelRecorder() as rec2:
        rt.execute(x, out=x)
    queue.finish()
    (only,) = rec2.launches
    assert only.label.endswith("cols n=48 round trip")
    assert only.bytes_moved == 2 * field


def test_summary_groups_shares_and_ratios(queue, rng):
    x = _field(queue, rng, (2, 32, 64))
    plan = FFTPlan(x.shape, np.complex64, queue=queue)
    with runtime.KernelRecorder() as rec:
        for _ in range(3):
            plan.execute(x, out=x)
    queue.finish()
    rows = rec.summary(copy_bandwidth=1e9)
    assert sum(int(r["launches"]) for r in rows) == len(rec.launches)
    assert abs(sum(float(r["share"]) for r in rows) - 1.0) < 1e-9
    secs = [float(r["seconds"]) for r in rows]
    assert secs == sorted(secs, reverse=True)
    for r in rows:
        mine = [x for x in rec.launches if x.label == r["label"]]
        assert int(r["launches"]) == len(mine) and len(mine) % 3 == 0
        assert r["bytes"] == sum(x.bytes_moved for x in mine)
        assert r["floor_ratio"] == pytest.approx(float(r["seconds"]) / (int(r["bytes"]) / 1e9))
        assert r["bandwidth"] == pytest.approx(int(r["bytes"]) / float(r["seconds"]))
    assert rec.device_span() >= max(x.seconds for x in rec.launches)


def test_render_profile_shows_a_layer_as_two_kernels(queue):
    L, T = 3, 2
    res = profile_render(height=36, width=60, colours=1, layers=L, frames=T, repeats=2,
                         queue=queue)
    counts = {r["label"]: int(r["launches"]) // res["repeats"] for r in res["rows"]}
    trips = {k: v for k, v in counts.items() if k.endswith("round trip")}
    # one batch of T frames: the farthest layer's row FFT, then per layer a column round
    # trip, a row round trip between layers (composite fused) and the nearest row inverse
    cols = [v for k, v in trips.items() if " cols " in k]
    rows = [v for k, v in trips.items() if " rows " in k]
    assert cols == [L] and rows == [L - 1], counts
    # the farthest layer's composite alone (composite_layer, or its 8x8-block CPU form)
    assert sum(v for k, v in counts.items() if k.startswith("composite_layer")) == 1, counts
    plain_rows = [v for k, v in counts.items() if " rows " in k and k not in trips]
    assert plain_rows == [2], counts
    assert res["per"] == L * T
    assert 0 < res["host_s"] <= res["wall_s"]
    # PoCL stamps overlap by a hair (a sum of 5614 ms in a span of 5605 ms was seen)
    assert res["kernel_s"] <= res["span_s"] * 1.05
    lines = format_profile(res)
    assert sum(line.startswith("| fft_") for line in lines) == len(trips) + len(plain_rows)
    assert "two kernels per layer" in lines[0]


@pytest.mark.parametrize("fuse", [None, "none", "residual", "all", "round-trips"])
def test_sgd_profile_lists_its_kernels(queue, fuse):
    from clholo.host.phase_retrieval import default_fuse, sums_lanes

    res = profile_sgd(size=48, iterations=2, queue=queue, fuse=fuse)
    labels = {r["label"] for r in res["rows"]}
    form = fuse or default_fuse(queue.device)
    # the steps fused into the adjoint propagation launch no kernel of their own
    # (the four round trips add the loss sums up inside the forward's row round trip)
    sums = "field_sums_lanes" if sums_lanes(queue.device) else "field_sums"
    own = {"scaled_residual": form == "none",
           "phase_gradient_adam": form not in ("all", "round-trips"),
           sums: form != "round-trips"}
    assert "fit_scale" in labels
    assert {k for k, launched in own.items() if launched} <= labels
    assert not {k for k, launched in own.items() if not launched} & labels
    assert any(label.endswith("round trip") for label in labels)
    # the four round trips are every FFT launch of the iteration: two columns, two rows
    fft = {r["label"]: int(r["launches"]) / res["repeats"] for r in res["rows"]
           if r["label"].startswith("fft_")}
    if form == "round-trips":
        assert sum(fft.values()) == 4 and all(k.endswith("round trip") for k in fft), fft
    else:
        assert sum(fft.values()) == 6, fft
    assert f"fuse {form}" in format_profile(res)[0]
    assert "per iteration" in format_profile(res)[-1]


def test_sgd_profile_refuses_an_unknown_fuse(queue):
    with pytest.raises(InputError, match="fuse must be one of"):
        profile_sgd(size=16, iterations=1, queue=queue, fuse="adam")


@pytest.mark.parametrize("kwargs, name", [({"colours": 2}, "colours"), ({"layers": 0}, "layers"),
                                          ({"repeats": 0}, "repeats")])
def test_render_profile_refuses_bad_arguments(queue, kwargs, name):
    with pytest.raises(InputError, match=name):
        profile_render(height=16, width=16, queue=queue, **kwargs)


def test_profile_script_writes_its_markdown_whole(tmp_path):
    out = tmp_path / "profile.md"
    res = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "profile_kernels.py"),
                          "--shape", "24x40", "--layers", "2", "--frames", "1", "--repeats", "1",
                          "--colours", "1", "--markdown", str(out)],
                         capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr
    text = out.read_text()
    assert text.strip() == res.stdout.strip()
    assert "| kernel | launches |" in text and "host enqueued" in text
    assert list(tmp_path.iterdir()) == [out]
    bad = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "profile_kernels.py"),
                          "--shape", "24by40"], capture_output=True, text=True, timeout=120)
    assert bad.returncode != 0 and "--shape takes HxW" in bad.stderr


def test_bench_command_prints_the_profile(capsys):
    from clholo import cli

    assert cli.main(["bench", "--profile", "--size", "16", "--layers", "2", "--repeats", "1",
                     "--pad", "2"]) == 0
    out = capsys.readouterr().out
    assert "render: L=2, 16x16, 3 colour(s), T=3" in out
    assert "| fft_strip cols" in out or "| fft_lines cols" in out
    assert "host enqueued" in out


def test_random_layers_too_large_for_the_host_are_refused_before_drawing(monkeypatch, capsys):
    """``clholo bench --profile --size 4096 --layers 256`` would draw 64 GiB of random layers
    (128 GiB with their device copies): refused at once (exit 3, one line naming the fix), as
    every bench command's scene is."""
    from clholo import bench, cli
    from clholo.host import memory

    monkeypatch.setattr(memory, "available_host_bytes", lambda: 2 << 30)
    drawn = []
    monkeypatch.setattr(np.random, "default_rng", lambda *a: drawn.append(a))
    with pytest.raises(MemoryError, match=r"256 random layers of 4096x4096 .* 128\.0 GiB .* "
                                          r"2\.0 GiB is available: use fewer --layers"):
        profile_render(height=4096, width=4096, layers=256)
    with pytest.raises(MemoryError, match="fewer --layers or a smaller --size"):
        bench._scene(4096, 256)
    with pytest.raises(MemoryError, match="fewer --layers"):
        bench.run_slm_benchmark(layers=256)
    assert cli.main(["bench", "--profile", "--size", "4096", "--layers", "256"]) == 3
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "use fewer --layers or a smaller --size" in err[0], err
    assert drawn == []
