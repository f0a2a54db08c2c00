"""clholo.fft's plan geometry without a device: plan_geometry is a pure function of shape,
dtype and device limits, so its passes, windows and buffers are checked here by running them
with NumPy (each pass reads its lines through its source window, transforms them with
np.fft.fft and writes through its destination window) against np.fft.fft2 / np.fft.fft of the
zero-padded, cropped input. The kernels' argument declarations are checked against the kernel
sources' signatures."""

import re

import numpy as np
import pytest

from clholo import fft as F
from clholo.host import runtime

CPU = F.DeviceLimits(is_cpu=True, local_mem_size=1 << 20, max_work_group_size=4096)
GPU = F.DeviceLimits(is_cpu=False, local_mem_size=48 * 1024, max_work_group_size=1024)


def _gather(buf, w, batch, nlines, n):
    """lines [batch, nlines, n] read through window w: zero outside nl x ne"""
    b = np.arange(batch)[:, None, None]
    line = np.arange(nlines)[None, :, None]
    k = np.arange(n)[None, None, :]
    valid = (line < w.nl) & (k < min(w.ne, n)) & (b >= 0)
    idx = np.where(valid, b * w.bs + line * w.ls + k * w.es, 0)
    return np.where(valid, buf[idx], 0)


def _run_geometry(g, x):
    elems = {"x": x.size, "out": int(np.prod(g.out_full_shape))}
    elems.update(dict(g.buffers))
    bufs = {role: np.full(size, np.nan + 0j) for role, size in elems.items()}
    bufs["x"] = x.reshape(-1).astype(np.complex128)
    for p in g.passes:
        src, dst = p.launches[0].src, p.launches[-1].dst
        for w in (src, dst):
            assert w.role in bufs, f"window role {w.role} has no buffer"
        lines = np.fft.fft(_gather(bufs[src.role], src, g.batch, p.nlines, p.n), axis=-1)
        b = np.arange(g.batch)[:, None, None]
        line = np.arange(min(dst.nl, p.nlines))[None, :, None]
        k = np.arange(min(dst.ne, p.n))[None, None, :]
        idx = b * dst.bs + line * dst.ls + k * dst.es
        assert idx.max() < bufs[dst.role].size, f"{p.axis} pass writes past {dst.role}"
        bufs[dst.role][idx] = lines[:, :line.shape[1], :k.shape[2]]
    return bufs["out"].reshape(g.out_full_shape)


CASES = [
    # shape, input_shape, output_shape, axes (small: the NumPy run of every case costs time;
    # the renderer's 2048^2 grid is checked below without running it)
    ((512, 512), (256, 256), None, (-2, -1)),       # the renderer's forward, pad 2
    ((512, 512), None, (256, 256), (-2, -1)),       # and its inverse
    ((3, 64, 128), (40, 100), None, (-2, -1)),
    ((2, 64, 128), (64, 20), None, (-2, -1)),       # columns first
    ((128, 64), (100, 30), (70, 64), (-2, -1)),
    ((32, 32), (48, 40), None, (-2, -1)),           # input larger than the transform
    ((2, 48, 160), (40, 96), (40, 96), (-2, -1)),
    ((45, 72), (40, 60), (40, 60), (-2, -1)),       # radix 3 and 5 (1125 x 1944's kind)
    ((4, 8, 8192), None, (8, 4096), (-2, -1)),      # lines too long for local memory
    ((6, 360), (300,), (200,), (-1,)),
    ((5, 16384), None, None, (-1,)),
]


@pytest.mark.parametrize("device", [CPU, GPU], ids=["cpu-limits", "gpu-limits"])
@pytest.mark.parametrize("dtype", [np.complex64, np.complex128])
@pytest.mark.parametrize("shape,ishape,oshape,axes", CASES)
def test_geometry_computes_the_transform(device, dtype, shape, ishape, oshape, axes):
    g = F.plan_geometry(shape, dtype, device=device, axes=axes, input_shape=ishape,
                        output_shape=oshape)
    rng = np.random.default_rng(len(shape) * 1000 + shape[-1])
    x = rng.standard_normal(g.in_full_shape) + 1j * rng.standard_normal(g.in_full_shape)
    nd = len(axes)
    padded = np.zeros(g.batch_shape + g.transform_shape, np.complex128)
    win = tuple(slice(0, min(i, t)) for i, t in zip(g.input_shape, g.transform_shape))
    padded[(Ellipsis,) + win] = x[(Ellipsis,) + win]
    want = (np.fft.fft2 if nd == 2 else np.fft.fft)(padded)
    want = want[(Ellipsis,) + tuple(slice(0, o) for o in g.output_shape)]
    got = _run_geometry(g, x)
    assert np.isfinite(got).all(), "output elements the passes never write"
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-9 * np.abs(want).max())
    assert g.scale == 1.0 / np.prod(g.transform_shape)
    if nd == 2:
        assert g.mul_frame == np.prod(g.transform_shape)


@pytest.mark.parametrize("device", [CPU, GPU], ids=["cpu-limits", "gpu-limits"])
@pytest.mark.parametrize("shape,ishape,oshape,axes", CASES)
def test_launches_cover_every_line(device, shape, ishape, oshape, axes):
    g = F.plan_geometry(shape, np.complex64, device=device, axes=axes, input_shape=ishape,
                        output_shape=oshape)
    for p in g.passes:
        assert p.kind in ("cpu", "gpu", "global")
        for lg in p.launches:
            assert len(lg.extra) == len(F.FFT_KERNEL_ARGS[p.kernel][1]) - (lg.local_bytes > 0)
            if p.kind == "cpu":
                lanes = dict(p.defines)["VW"] // 2
                assert lg.gsize[0] * lanes * lg.extra[0] >= p.nlines
                assert lg.local_bytes <= device.local_mem_size
            elif p.kind == "gpu":
                lines, nthr = lg.extra[0], lg.lsize[0]
                assert (lg.gsize[0] // nthr) * lines >= p.nlines
                assert lg.local_bytes <= device.local_mem_size
                assert nthr <= device.max_work_group_size
        if p.kind == "global":  # one launch per radix stage, ping-pong through stage buffers
            assert [lg.extra[1] for lg in p.launches] == F._radices(p.n)
            assert np.prod([lg.extra[1] for lg in p.launches]) == p.n
            for a, b in zip(p.launches, p.launches[1:]):  # each stage reads the last's output
                assert a.dst == b.src and a.dst.role in ("stage0", "stage1")
                assert a.src.role != a.dst.role, "a stage cannot run in place"


def test_order_and_buffers_of_the_renderer_grid():
    fwd = F.plan_geometry((1, 2048, 2048), device=CPU, input_shape=(1024, 1024))
    inv = F.plan_geometry((1, 2048, 2048), device=CPU, output_shape=(1024, 1024))
    assert fwd.order == inv.order == "rows-first"
    # forward: 1024 rows (the rest is padding) into the output, then all 2048 columns
    assert [(p.axis, p.nlines) for p in fwd.passes] == [("rows", 1024), ("cols", 2048)]
    assert fwd.passes[0].launches[0].dst.role == "out" and fwd.buffers == ()
    # inverse: every row, only the 1024 columns the crop keeps, through a work buffer
    assert [(p.axis, p.nlines) for p in inv.passes] == [("rows", 2048), ("cols", 1024)]
    assert inv.buffers == (("tmp", 2048 * 1024),)


@pytest.mark.parametrize("bad,match", [
    (dict(shape=(7, 12)), "2\\^a 3\\^b 5\\^c"), (dict(shape=(8,)), "fewer than"),
    (dict(shape=(8, 32768)), "exceeds"), (dict(shape=(8, 8), axes=(0,)), "axes"),
    (dict(shape=(8, 8), output_shape=(9, 8)), "output_shape"),
    (dict(shape=(8, 8), variant="fpga"), "variant"), (dict(shape=(0, 8, 8)), "batch axis"),
])
def test_geometry_errors(bad, match):
    with pytest.raises(ValueError, match=match):
        F.plan_geometry(device=CPU, **bad)


def test_kernel_signatures_use_the_declared_arguments():
    """the kernels name their parameter lists by the macros clholo/fft.py defines, and the
    header no longer spells them out itself"""
    for path, kernels in (("fft_cpu.cl", ["fft_strip"]), ("fft_gpu.cl", ["fft_lines",
                                                                         "fft_stage"])):
        text = runtime.read_kernel_source(path)
        for name in kernels:
            macro = F.FFT_KERNEL_ARGS[name][0]
            sig = re.search(r"__kernel\s+void\s+" + name + r"\s*\(([^)]*)\)", text).group(1)
            assert " ".join(sig.split()) == f"FFT_PASS_ARGS, {macro} FFT_CB_PARAMS", sig
    assert "#define FFT_PASS_ARGS" not in runtime.read_kernel_source("fft_common.h")
    macros = F.kernel_arg_macros()
    for arg in F.FFT_PASS_ARGS:
        assert arg.decl() in macros
    dts = F.kernel_arg_dtypes("fft_strip", np.float32)
    assert len(dts) == len(F.FFT_PASS_ARGS) + 2
    assert dts[F.FFT_PASS_ARGS.index(F.KernelArg("scale", "real"))] is np.float32


def _smooth_sizes(limit):
    return sorted({2 ** a * 3 ** b * 5 ** c for a in range(14) for b in range(9)
                   for c in range(7) if 2 ** a * 3 ** b * 5 ** c <= limit})


@pytest.mark.parametrize("radix_max", [8, 16, 32, 64])
def test_fused_stages_multiply_to_the_line(radix_max):
    """every size's fused stages: butterfly radix pairs whose product is n, none above
    radix_max, no more stages than the butterfly radices alone; 8 gives those exactly"""
    for n in _smooth_sizes(F.MAX_SIZE):
        stages = F._fused_radices(n, radix_max)
        radices = [r1 * r2 for r1, r2 in stages]
        assert int(np.prod(radices)) == n, (n, stages)
        for r1, r2 in stages:
            assert r1 in F._BUTTERFLY_RADICES and (r2 == 1 or r2 in F._BUTTERFLY_RADICES)
            assert r2 <= r1 and r1 * r2 <= max(radix_max, 8), (n, stages)
        assert len(stages) <= len(F._radices(n))
        if radix_max <= 8:
            assert radices == F._radices(n)
        else:  # odd radices first (the p == 1 stage's strided writes)
            odd = [r % 2 for r in radices]
            assert odd == sorted(odd, reverse=True), (n, stages)
    # the SLM grid's lines: fewer stages than the 6 and 5 butterfly stages
    assert len(F._fused_radices(1944, 16)) == 4 and len(F._fused_radices(1125, 16)) == 3
    assert F._stage_list(1125, 16) == "FFT_STAGE(5,3,1)FFT_STAGE(5,3,15)FFT_STAGE(5,1,225)"


def test_stage_lists_of_planned_passes():
    """both local-memory plans fuse radices (up to _FUSED_RADIX_MAX and
    _INPLACE_FUSED_RADIX_MAX); the in-place plan sizes its registers by the largest radix and
    the widest stage"""
    inplace = 0
    for shape in [(1125, 1944), (2250, 2250), (2187, 3888), (4096, 4096)]:
        for p in F.plan_geometry(shape, device=GPU, variant="gpu").passes:
            d = dict(p.defines)
            most = F._INPLACE_FUSED_RADIX_MAX if "FFT_INPLACE" in d else F._FUSED_RADIX_MAX
            assert d["FFT_STAGE_LIST"] == F._stage_list(p.n, most), (shape, p.axis)
            if "FFT_INPLACE" in d:
                inplace += 1
                radices = [r1 * r2 for r1, r2 in F._fused_radices(p.n, most)]
                lines, nthr = p.launches[0].extra[0], p.launches[0].lsize[0]
                assert d["FFT_INPLACE_R"] == max(radices)
                for r in radices:  # each stage's butterflies fit FFT_INPLACE per work-item
                    q = -(-(lines * p.n // r) // nthr)
                    assert q <= d["FFT_INPLACE"] and q * r <= F._INPLACE_MAX_HELD, (p.n, r)
    assert inplace >= 3  # 2250, 2187 and 3888 points (4096 too, in 48 KiB)
