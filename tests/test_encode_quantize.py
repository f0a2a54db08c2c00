"""8-bit lookup tables, wrap, gray levels and SLM-sized PNG sequences (clholo.encode.quantize)."""

import math

import numpy as np
import pytest

from clholo.encode.quantize import (PhaseLUT, dequantize, fit_to_slm, parse_lut, quantize,
                                    read_pattern_pngs, wrap_phase, write_pattern_pngs)

TWO_PI = 2 * math.pi


def _measured(rng, top=TWO_PI * 1.1):
    steps = rng.uniform(0.2, 1.8, 255)
    return np.concatenate([[0.3], 0.3 + np.cumsum(steps) / steps.sum() * top])


@pytest.mark.parametrize("kind", ["linear255", "linear256", "linear200", "measured"])
def test_round_trip_is_exact_for_every_level(rng, kind):
    lut = PhaseLUT(_measured(rng)) if kind == "measured" else \
        PhaseLUT.linear(int(kind[len("linear"):]))
    levels = np.arange(lut.usable_levels, dtype=np.uint8)
    np.testing.assert_array_equal(lut.to_gray(lut.to_phase(levels)), levels)
    # shifted by whole turns, the same levels come back
    np.testing.assert_array_equal(lut.to_gray(lut.to_phase(levels) - 3 * TWO_PI), levels)
    # levels at or beyond 2 pi (range > 2 pi) come back as a level of the same phase mod 2 pi
    if lut.usable_levels < 256:
        beyond = np.arange(lut.usable_levels, 256).astype(np.uint8)
        back = lut.to_gray(lut.to_phase(beyond))
        err = np.angle(np.exp(1j * (lut.to_phase(back) - lut.to_phase(beyond))))
        assert np.all(back < lut.usable_levels)
        assert np.max(np.abs(err)) <= np.max(np.diff(lut.phases)) / 2 + 1e-12


def test_usable_levels():
    assert PhaseLUT.linear(255).usable_levels == 255  # gray 255 is 2 pi = gray 0
    assert PhaseLUT.linear(256).usable_levels == 256
    assert PhaseLUT.linear(200).usable_levels == 200


def test_nearest_level_on_the_circle(rng):
    lut = PhaseLUT(_measured(rng))
    phase = rng.uniform(-20, 20, 5000)
    gray = lut.to_gray(phase)
    got = lut.to_phase(gray)
    err = np.abs(np.angle(np.exp(1j * (got - phase))))
    # no usable level is nearer on the circle than the chosen one
    cand = lut.phases[:lut.usable_levels]
    best = np.min(np.abs(np.angle(np.exp(1j * (cand[None, :] - phase[:, None])))), axis=1)
    np.testing.assert_allclose(err, best, atol=1e-12)
    # the linear map is HOLOGRAPHY.md's round(wrap(P) / 2 pi * N) (mod N)
    lin = PhaseLUT.linear(255)
    w = wrap_phase(phase)
    want = np.round(w / TWO_PI * 255).astype(int) % 255
    ties = np.isclose((w / TWO_PI * 255) % 1, 0.5)
    np.testing.assert_array_equal(lin.to_gray(phase)[~ties], want[~ties])


def test_wrap_phase():
    w = wrap_phase(np.array([-1e-17, 0.0, TWO_PI, 7.0, -7.0]))
    assert np.all((w >= 0) & (w < TWO_PI))
    np.testing.assert_allclose(w[3:], [7.0 - TWO_PI, TWO_PI * 2 - 7.0])


@pytest.mark.parametrize("value", [7.0, -7.0, -1e-17, TWO_PI])
def test_wrap_phase_of_one_number(value):
    # one number in, one wrapped number out, as for each element of an array
    w = wrap_phase(value)
    assert np.ndim(w) == 0
    assert w == wrap_phase(np.array([value]))[0]
    assert 0 <= w < TWO_PI


@pytest.mark.parametrize("table,match", [
    (np.linspace(0, 7, 255), "256 phases"),
    (np.r_[np.linspace(0, 7, 128), np.linspace(6.9, 8, 128)], "not monotone: the phase at gray 128"),
    (np.r_[np.linspace(0, 7, 100), [np.nan], np.linspace(7.1, 8, 155)], "gray level 100"),
    (np.r_[np.linspace(0, 7, 128), np.linspace(7, 8, 128)], "gray 128 .* does not exceed"),
    (np.linspace(0, 3.0, 256), "short of 2 pi"),
    (np.linspace(0, 360, 256)[::-1], "not monotone"),
])
def test_bad_tables_are_refused_with_the_reason(table, match):
    with pytest.raises(ValueError, match=match):
        PhaseLUT(table)


def test_linear_spec_and_files(tmp_path, rng):
    assert parse_lut("linear").usable_levels == 255
    assert parse_lut("linear:128").usable_levels == 128
    with pytest.raises(ValueError, match="linear:N"):
        parse_lut("linear:x")
    with pytest.raises(ValueError, match="gray_2pi"):
        PhaseLUT.linear(300)
    with pytest.raises(FileNotFoundError):
        parse_lut(tmp_path / "none.csv")
    table = _measured(rng)
    np.save(tmp_path / "lut.npy", table)
    np.savetxt(tmp_path / "one.csv", table, delimiter=",")
    np.savetxt(tmp_path / "two.csv", np.c_[np.arange(256), table], delimiter=",",
               header="gray,phase", comments="")
    for name in ("lut.npy", "one.csv", "two.csv"):
        np.testing.assert_allclose(parse_lut(tmp_path / name).phases, table - table[0],
                                   atol=1e-12)
    np.savetxt(tmp_path / "gaps.csv", np.c_[np.arange(256) * 2, table], delimiter=",")
    with pytest.raises(ValueError, match="gray column"):
        parse_lut(tmp_path / "gaps.csv")
    np.savetxt(tmp_path / "short.csv", table[:200], delimiter=",")
    with pytest.raises(ValueError, match="256"):
        parse_lut(tmp_path / "short.csv")


def test_quantize_per_colour(rng):
    phase = rng.uniform(-10, 10, (2, 3, 5, 7))
    luts = ["linear:255", "linear:200", PhaseLUT(_measured(rng))]
    gray = quantize(phase, luts)
    assert gray.dtype == np.uint8 and gray.shape == phase.shape
    assert gray[:, 1].max() < 200
    back = dequantize(gray, luts)
    err = np.abs(np.angle(np.exp(1j * (back - phase))))
    assert err[:, 0].max() <= math.pi / 255 + 1e-12
    np.testing.assert_array_equal(quantize(back, luts), gray)
    with pytest.raises(ValueError, match="one per colour"):
        quantize(phase, ["linear", "linear"])
    with pytest.raises(ValueError, match="NaN"):
        quantize(np.full((1, 1, 2, 2), np.nan))
    with pytest.raises(TypeError, match="uint8"):
        dequantize(gray.astype(np.int32))


def test_fit_to_slm_centres_crop_and_pad():
    g = np.arange(1, 5 * 6 + 1, dtype=np.uint8).reshape(5, 6)
    out = fit_to_slm(g, (9, 4))
    assert out.shape == (9, 4)
    # pattern centre (2, 3) lands on the SLM centre (4, 2)
    assert out[4, 2] == g[2, 3]
    np.testing.assert_array_equal(out[2:7], g[:, 1:5])
    assert np.all(out[:2] == 0) and np.all(out[7:] == 0)
    # odd pattern on an even SLM and the reverse: centre pixel on centre pixel
    odd = fit_to_slm(g, (6, 3))
    assert odd[3, 1] == g[2, 3]
    np.testing.assert_array_equal(odd[1:6], g[:, 2:5])
    same = fit_to_slm(g, (5, 6))
    np.testing.assert_array_equal(same, g)


def test_png_sequence_round_trip(tmp_path, rng):
    gray = rng.integers(0, 256, (2, 3, 12, 10)).astype(np.uint8)
    folder = write_pattern_pngs(gray, tmp_path / "slm", slm_shape=(16, 20),
                                metadata={"method": "test"})
    names = sorted(p.name for p in folder.iterdir())
    assert names == sorted([f"frame{t:03d}_{c}.png" for t in range(2) for c in "RGB"]
                           + ["clholo-output.json", "patterns.json"])
    back = read_pattern_pngs(folder)
    np.testing.assert_array_equal(back, fit_to_slm(gray, (16, 20)))
    assert [p.name for p in tmp_path.iterdir()] == ["slm"]  # no temporary folder left
    with pytest.raises(FileExistsError):
        write_pattern_pngs(gray, folder)
