"""Nothing hangs: a size the FFT cannot take is refused at once (issue 26, section 1).

``fft.next_fft_size`` counted up one integer at a time and the FFT's size limit was checked
only after it: ``clholo render moto-mpi --pad 1e9`` never finished. Now the limit comes first
(with the grid the request needs and the largest pad this field can have), the next size
``2^a 3^b 5^c`` is found by enumerating exponents, and counts from the command line that size a
buffer (``--layers``, ``--repeats``) are bounded by the parser. No timings: the tests count the
work done (the calls of the old search) instead.
"""

import math

import numpy as np
import pytest

import clholo
from clholo import cli, fft, propagation


class _Counted:
    """``is_fft_size`` that counts its calls and stops a linear search long before it hangs."""

    def __init__(self, limit=1000):
        self.calls, self.limit, self.real = 0, limit, fft.is_fft_size

    def __call__(self, n):
        self.calls += 1
        if self.calls > self.limit:
            raise AssertionError(f"is_fft_size called {self.calls} times: a linear search")
        return self.real(n)


def _smooth(n):
    for f in (2, 3, 5):
        while n % f == 0:
            n //= f
    return n == 1


@pytest.mark.parametrize("n", [2, 3, 7, 1081, 8193, 185 * 10**9 + 1, 10**12 + 7,
                               2**61 - 1, 10**30 + 1])
def test_next_fft_size_enumerates_exponents(monkeypatch, n):
    counted = _Counted()
    monkeypatch.setattr(fft, "is_fft_size", counted)
    nxt, below = fft.next_fft_size(n), fft.prev_fft_size(n - 1)
    assert _smooth(nxt) and nxt >= n
    assert _smooth(below) and below < n
    # nothing smooth in between: the next smooth size after ``below`` is ``nxt``
    assert fft.next_fft_size(below + 1) == nxt
    assert fft.nearest_fft_sizes(n) == (fft.prev_fft_size(n - 1), fft.next_fft_size(n + 1))


def test_next_and_prev_fft_size_match_a_plain_search():
    smooth = [m for m in range(1, 20000) if _smooth(m)]
    for n in range(0, 19000):
        assert fft.next_fft_size(n) == next(m for m in smooth if m >= max(n, 1)), n
    for n in range(1, 19000):
        assert fft.prev_fft_size(n) == max(m for m in smooth if m <= n), n


def test_padding_limit_is_checked_before_any_search(monkeypatch):
    def no_search(n):
        raise AssertionError(f"searched for an FFT size >= {n} beyond the limit")

    monkeypatch.setattr(propagation, "next_fft_size", no_search)
    with pytest.raises(ValueError) as info:
        propagation.device_padded_shape((125, 185), 1e-3, wavelength=520e-9, pitch=8e-6,
                                        pad=1e9)
    msg = str(info.value)
    assert msg == ("pad 1e+09 needs a padded grid of 125000000000 x 185000000000, but the "
                   "FFT's largest size is 8192 per axis: the largest pad for this 125 x 185 "
                   "field is 44.281 (or use pad 'auto')")


def test_a_pad_too_large_for_a_float_product_is_refused_exactly():
    """pad 1e308 on 125 rows overflows a float product (it was an internal error, exit 70)."""
    assert _refusal((125, 185), 1e308).startswith(
        "pad 1e+308 needs a padded grid of 1.25e+310 x 1.85e+310, but the FFT's largest size is "
        "8192 per axis")


def test_the_largest_pad_named_is_the_largest_that_works():
    M = propagation.MAX_FFT_SIZE
    for H, W in ((125, 185), (12, 37), (1080, 1920), (1, 8192)):
        largest = math.floor(M / max(H, W) * 1000) / 1000
        assert f"is {largest:g} " in _refusal((H, W), largest + 0.001)
        Hp, Wp = propagation.device_padded_shape((H, W), 1e-3, wavelength=520e-9, pitch=8e-6,
                                                 pad=largest)
        assert max(Hp, Wp) <= M
    assert "largest pad shape is (8192, 8192)" in _refusal((12, 37), (8192, 8193 * 2))
    assert "the field (12 x 9000) is itself larger" in _refusal((12, 9000), 1)


def _refusal(shape, pad):
    with pytest.raises(ValueError) as info:
        propagation.device_padded_shape(shape, 1e-3, wavelength=520e-9, pitch=8e-6, pad=pad)
    return str(info.value)


# ------------------------------------------------------------------------------ command line
@pytest.fixture(scope="module")
def scenes(tmp_path_factory):
    """An MPI folder of 12 x 37 (37e9 is no FFT size: the old search hung on --pad 1e9), an
    RGB-D pair, a splat .ply and a hologram file."""
    from PIL import Image

    folder = tmp_path_factory.mktemp("scenes")
    rng = np.random.default_rng(261)
    clholo.io.write_mpi(folder / "mpi", clholo.MPI(rng.random((3, 12, 37, 3)),
                                                   rng.random((3, 12, 37)), [2e-3, 3e-3, 4e-3]))
    Image.fromarray((rng.random((12, 37, 3)) * 255).astype(np.uint8)).save(folder / "img.png")
    Image.fromarray((rng.random((12, 37)) * 255).astype(np.uint8)).save(folder / "depth.png")
    props = ["x", "y", "z", "f_dc_0", "f_dc_1", "f_dc_2", "opacity", "scale_0", "scale_1",
             "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]
    t = np.zeros((5, len(props)), np.float32)
    t[:, 0:2] = rng.uniform(-0.5, 0.5, (5, 2))
    t[:, 2] = rng.uniform(3.0, 5.0, 5)
    t[:, 6] = 2.0
    t[:, 7:10] = np.log(0.1)
    t[:, 10] = 1.0
    head = ["ply", "format binary_little_endian 1.0", "element vertex 5"]
    head += [f"property float {p}" for p in props] + ["end_header"]
    (folder / "s.ply").write_bytes(("\n".join(head) + "\n").encode() + t.tobytes())
    holo = (rng.standard_normal((1, 3, 12, 37)) + 1j).astype(np.complex64)
    clholo.io.write_hologram(folder / "good.npz", holo, pitch=8e-6,
                             wavelengths=(638e-9, 520e-9, 450e-9), seed=0)
    return folder


PAD_CASES = [
    ("render", ["render", "{s}/mpi", "--pad", "1e9", "--frames", "1", "--out", "o"]),
    ("render-rgbd", ["render", "{s}/img.png", "{s}/depth.png", "--near", "0.002", "--far",
                     "0.004", "--layers", "4", "--method", "rgbd", "--pad", "1e9", "--frames",
                     "1", "--out", "o"]),
    ("render-rpws", ["render", "{s}/s.ply", "--method", "rpws", "--near", "0.002", "--far",
                     "0.004", "--pad", "1e9", "--frames", "1", "--out", "o"]),
    ("display", ["display", "{s}/mpi", "--memory", "--pad", "1e9"]),
    ("encode", ["encode", "{s}/good.npz", "--pad", "1e9", "--out", "o"]),
    ("render-1e308", ["render", "{s}/mpi", "--pad", "1e308", "--frames", "1", "--out", "o"]),
]


@pytest.mark.parametrize("name, argv", PAD_CASES, ids=[c[0] for c in PAD_CASES])
def test_pad_beyond_the_fft_is_one_line_exit_2(tmp_path, monkeypatch, capsys, scenes, name,
                                               argv):
    monkeypatch.chdir(tmp_path)
    counted = _Counted()
    monkeypatch.setattr(fft, "is_fft_size", counted)
    monkeypatch.setattr(propagation, "is_fft_size", counted)
    argv = [a.replace("{s}", str(scenes)) for a in argv] + ["--progress", "off"]
    before = sorted(p.name for p in scenes.iterdir())
    assert cli.main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    command = argv[0]
    pad = argv[argv.index("--pad") + 1]
    assert err[0].startswith(f"clholo {command}: error: pad {float(pad):g} needs a padded grid "
                             f"of "), err
    assert "but the FFT's largest size is 8192 per axis: the largest pad for this " in err[0]
    assert list(tmp_path.iterdir()) == [] and sorted(p.name for p in scenes.iterdir()) == before


@pytest.mark.parametrize("argv, line", [
    (["render", "{s}/s.ply", "--near", "0.002", "--far", "0.004", "--layers", "100000000",
      "--out", "o"], "clholo render: error: argument --layers: must be <= 256, got 100000000"),
    (["render", "{s}/img.png", "{s}/depth.png", "--near", "0.002", "--far", "0.004",
      "--layers", "100000000", "--out", "o"],
     "clholo render: error: argument --layers: must be <= 256, got 100000000"),
    (["bench", "--repeats", "1000000000"],
     "clholo bench: error: argument --repeats: must be <= 100, got 1000000000"),
    (["bench", "--layers", "100000000"],
     "clholo bench: error: argument --layers: must be <= 256, got 100000000"),
    (["batch", "{s}/m.csv", "--workers", "1000000", "--out", "o"],
     "clholo batch: error: argument --workers: must be <= 256, got 1000000"),
], ids=["ply-layers", "rgbd-layers", "bench-repeats", "bench-layers", "batch-workers"])
def test_counts_that_size_work_are_bounded_by_the_parser(tmp_path, monkeypatch, capsys, scenes,
                                                         argv, line):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(SystemExit) as info:
        cli.main([a.replace("{s}", str(scenes)) for a in argv])
    assert info.value.code == 2
    assert capsys.readouterr().err.strip().splitlines()[-1] == line
    assert list(tmp_path.iterdir()) == []


def test_splats_to_mpi_refuses_a_layer_count_before_reading(tmp_path):
    from clholo.io import splats_to_mpi

    with pytest.raises(ValueError, match=r"layers must be <= 256, got 100000000"):
        splats_to_mpi(tmp_path / "not-read.ply", layers=100_000_000)


def test_experiment_refuses_a_frame_count_before_loading(tmp_path, monkeypatch, capsys):
    """``clholo experiment layers --frames 100000000`` used to load the scenes and their
    references first (minutes on 2 cores); the hologram memory is checked before."""
    from clholo.experiments import layers

    def no_loading(*args, **kwargs):
        raise AssertionError("a scene was loaded")

    monkeypatch.setattr(layers, "prepare_scene", no_loading)
    monkeypatch.chdir(tmp_path)
    assert cli.main(["experiment", "layers", "--frames", "100000000", "--out", "o"]) == 3
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(
        "clholo experiment layers: error: frames=100000000: the holograms of one render take "
        "at least 2288.8 GiB"), err
    assert err[0].endswith("use far fewer frames (the paper uses 24)")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("budget", [2 * 2**20, 8 * 2**20], ids=["2MiB", "8MiB"])
def test_memory_refusal_names_the_largest_pad_that_fits(budget):
    """A pad beyond the device memory budget is refused before any work, naming the largest
    pad that fits (rounded up to FFT sizes as the renderer does): that pad renders, a little
    more is refused again."""
    import re

    rng = np.random.default_rng(262)
    mpi = clholo.MPI(rng.random((2, 12, 37, 3)), rng.random((2, 12, 37)), [2e-3, 4e-3])
    optics = clholo.Optics()
    with pytest.raises(MemoryError) as info:
        clholo.render_hologram(mpi, optics, frames=1, pad=40, memory_budget=budget)
    found = re.search(r"; the largest pad this budget holds on this 12x37 field is "
                      r"([0-9.]+) \((\d+)x(\d+)\)$", str(info.value))
    assert found, str(info.value)
    largest = float(found.group(1))
    assert 1 < largest < 40
    grid = propagation.device_padded_shape((12, 37), [2e-3], wavelength=optics.wavelengths,
                                           pitch=optics.pitch, pad=largest)
    assert grid == (int(found.group(2)), int(found.group(3)))
    assert clholo.render_hologram(mpi, optics, frames=1, pad=largest,
                                  memory_budget=budget).shape == (1, 3, 12, 37)
    with pytest.raises(MemoryError, match="the largest pad"):
        clholo.render_hologram(mpi, optics, frames=1, pad=largest + 0.05, memory_budget=budget)
