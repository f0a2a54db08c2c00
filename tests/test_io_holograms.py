"""Hologram files: EXR and NPZ round trips with metadata; all-or-nothing writes."""

import os

import numpy as np
import pytest

from clholo.io import read_hologram, write_hologram



def random_complex(rng, shape):
    """Random complex64 values, never zeros."""
    return (rng.standard_normal(shape) + 1j * rng.standard_normal(shape)).astype(np.complex64)


@pytest.mark.parametrize("suffix", [".exr", ".npz"])
@pytest.mark.parametrize("shape", [(2, 3, 5, 7), (1, 1, 4, 4)])
def test_round_trip_is_exact(tmp_path, rng, suffix, shape):
    field = random_complex(rng, shape)
    wl = [638e-9, 520e-9, 450e-9][: shape[1]]
    seed = 2 ** 63 + 12345  # 64-bit seeds survive
    path = tmp_path / f"h{suffix}"
    write_hologram(path, field, pitch=8e-6, wavelengths=wl, seed=seed, metadata={"layers": 32})
    got, meta = read_hologram(path)
    assert got.dtype == np.complex64 and got.shape == shape
    np.testing.assert_array_equal(got, field)
    assert meta["pitch"] == 8e-6 and meta["wavelengths"] == wl
    assert meta["frames"] == shape[0] and meta["seed"] == seed
    assert meta["extra"] == {"layers": 32}
    assert os.listdir(tmp_path) == [path.name]


def test_exr_header_has_the_metadata(tmp_path, rng):
    import OpenImageIO as oiio

    write_hologram(tmp_path / "h.exr", random_complex(rng, (1, 3, 4, 4)), pitch=8e-6,
                   wavelengths=[638e-9, 520e-9, 450e-9], seed=7)
    inp = oiio.ImageInput.open(str(tmp_path / "h.exr"))
    spec = inp.spec()
    inp.close()
    assert spec.getattribute("clholo:pitch") == pytest.approx(8e-6)
    assert spec.getattribute("clholo:seed") == "7"
    assert spec.getattribute("clholo:frames") == 1
    assert "t0.G.im" in spec.channelnames


def test_bad_input_writes_nothing(tmp_path, rng):
    f = random_complex(rng, (1, 2, 4, 4))
    with pytest.raises(ValueError, match="wavelengths has 1"):
        write_hologram(tmp_path / "h.exr", f, pitch=8e-6, wavelengths=[520e-9])
    with pytest.raises(TypeError, match="complex"):
        write_hologram(tmp_path / "h.exr", f.real, pitch=8e-6, wavelengths=[5e-7, 6e-7])
    with pytest.raises(ValueError, match=r"\.exr or \.npz"):
        write_hologram(tmp_path / "h.png", f, pitch=8e-6, wavelengths=[5e-7, 6e-7])
    with pytest.raises(ValueError, match="pitch"):
        write_hologram(tmp_path / "h.npz", f, pitch=8, wavelengths=[5e-7, 6e-7])
    bad = f.copy()
    bad[0, 0, 0, 0] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        write_hologram(tmp_path / "h.npz", bad, pitch=8e-6, wavelengths=[5e-7, 6e-7])
    assert os.listdir(tmp_path) == []


def test_overwrite_replaces_whole_file(tmp_path, rng):
    a, b = random_complex(rng, (1, 1, 8, 8)), random_complex(rng, (1, 1, 3, 3))
    write_hologram(tmp_path / "h.exr", a, pitch=8e-6, wavelengths=[520e-9])
    write_hologram(tmp_path / "h.exr", b, pitch=8e-6, wavelengths=[520e-9])
    np.testing.assert_array_equal(read_hologram(tmp_path / "h.exr")[0][0, 0], b[0, 0])


@pytest.mark.parametrize("suffix", [".npz", ".exr"])
@pytest.mark.parametrize("keep", [0.5, 0.98])
def test_truncated_hologram_file_is_refused_naming_it(tmp_path, rng, suffix, keep):
    write_hologram(tmp_path / f"h{suffix}", random_complex(rng, (1, 2, 16, 16)), pitch=8e-6,
                   wavelengths=[5e-7, 6e-7])
    data = (tmp_path / f"h{suffix}").read_bytes()
    (tmp_path / f"cut{suffix}").write_bytes(data[:int(len(data) * keep)])
    with pytest.raises(ValueError, match=rf"cut\{suffix}"):
        read_hologram(tmp_path / f"cut{suffix}")


def test_exr_header_values_that_disagree_with_its_metadata_are_refused(tmp_path, rng):
    """Issue 26: an EXR's clholo:pitch / clholo:wavelengths attributes are read and checked
    against its clholo:metadata, as the arrays of an .npz are (an edited header is not
    silently encoded with the metadata's values)."""
    import OpenImageIO as oiio

    path = tmp_path / "h.exr"
    write_hologram(path, random_complex(rng, (1, 2, 4, 4)), pitch=8e-6,
                   wavelengths=[638e-9, 520e-9])
    inp = oiio.ImageInput.open(str(path))
    spec, pixels = inp.spec(), inp.read_image(0, 0, 0, inp.spec().nchannels, "float")
    inp.close()
    for attribute, value, match in [
            ("clholo:pitch", 4e-6, r"h2\.exr: its pitch header attribute says 4e-06 m but its metadata "
                                   r"says 8e-06 m"),
            ("clholo:wavelengths", "[638, 520]", r"h2\.exr: wavelengths=638 is not a wavelength "
                                                 r"in metres"),
            ("clholo:wavelengths", "[6.38e-07]", r"h2\.exr: wavelengths has 1 value\(s\) but "
                                                 r"the field has 2 colour channel\(s\)")]:
        edited = oiio.ImageSpec(spec)
        edited.attribute(attribute, value)
        out = oiio.ImageOutput.create(str(tmp_path / "h2.exr"))
        assert out.open(str(tmp_path / "h2.exr"), edited) and out.write_image(pixels)
        out.close()
        with pytest.raises(ValueError, match=match):
            read_hologram(tmp_path / "h2.exr")
    assert read_hologram(path)[1]["pitch"] == 8e-6
