"""Damaged, truncated and edited ``.npy``/``.npz`` files and hologram EXRs found by an audit
(2026-11-29): one changed header byte was an internal error (``tokenize.TokenError``), a header
that lies about its shape was "Unable to allocate 146 TiB" (exit 3, this machine's fault), a
truncated file said "Failed to read all data" without its name, an edited hologram dropped
frames without a word, and a named pipe given as a lookup table "did not exist". Each is now
one line naming the file, and good files read as ``numpy.load`` reads them.

Every corrupt input is made here from a good file the test writes itself."""

import io
import json
import os
import struct
import zipfile

import numpy as np
import pytest

import clholo
from clholo import cli
from clholo.errors import InputError
from clholo.io._npy import load_npy, open_npz

# a claim no machine can allocate: before the fixes NumPy tried (MemoryError), or read a prefix
HUGE = (10 ** 6, 10 ** 6, 10 ** 3)


# --- making bad files from good ones -----------------------------------------------------------

def _npy_bytes(array) -> bytes:
    buf = io.BytesIO()
    np.lib.format.write_array(buf, np.asarray(array), allow_pickle=False)
    return buf.getvalue()


def _lying_npy_bytes(array, shape) -> bytes:
    """``array``'s bytes behind a version 1.0 header that claims ``shape``."""
    array = np.asarray(array)
    header = np.lib.format.header_data_from_array_1_0(array)
    header["shape"] = tuple(shape)
    buf = io.BytesIO()
    np.lib.format.write_array_header_1_0(buf, header)
    return buf.getvalue() + array.tobytes()


def _damaged_header(data: bytes) -> bytes:
    """The header-length field (offset 8) changed so that the header text ends inside its
    dictionary, as one changed byte there does: NumPy's parser raised
    ``tokenize.TokenError`` ("EOF in multi-line statement")."""
    data = bytearray(data)
    struct.pack_into("<H", data, 8, data.index(b"'shape'") - 10)
    return bytes(data)


def _bad_npy(kind: str, array) -> bytes:
    good = _npy_bytes(array)
    return {"header": _damaged_header(good),
            "lie": _lying_npy_bytes(array, HUGE),
            "truncated": good[:len(good) - np.asarray(array).nbytes // 2],
            "longer": good + bytes(64)}[kind]


_WORDS = {"header": "has a damaged .npy header (EOF in multi-line statement)",
          "lie": "is truncated or its header is damaged: its header says shape (1000000, ",
          "truncated": "is truncated or its header is damaged",
          "longer": "is longer than its header says"}


def _one_line_naming(exc, path) -> str:
    message = str(exc.value)
    assert str(path) in message and "\n" not in message, message
    return message


def _rewrite_npz(src, dst, **members):
    """The archive ``src`` with some members' bytes replaced (``name=bytes``)."""
    with zipfile.ZipFile(src) as z:
        arrays = {n: z.read(n) for n in z.namelist()}
    for name, data in members.items():
        arrays[f"{name}.npy"] = data
    with zipfile.ZipFile(dst, "w") as z:
        for name, data in arrays.items():
            z.writestr(name, data)
    return dst


def _hologram(tmp_path, suffix=".npz", frames=2):
    rng = np.random.default_rng(3)
    field = (rng.standard_normal((frames, 3, 8, 12))
             + 1j * rng.standard_normal((frames, 3, 8, 12))).astype(np.complex64)
    path = tmp_path / f"holo{suffix}"
    clholo.io.write_hologram(path, field, pitch=8e-6, wavelengths=[638e-9, 520e-9, 450e-9],
                             seed=5)
    return path, field


# --- the shared loader: good files are read as numpy.load reads them ---------------------------

def _good_arrays():
    rng = np.random.default_rng(0)
    return {
        "float32": rng.random((5, 7)).astype(np.float32),
        "big-endian": np.arange(12, dtype=">i4").reshape(3, 4),
        "fortran": np.asfortranarray(rng.random((3, 4))),
        "complex64": (rng.random((2, 3)) + 1j * rng.random((2, 3))).astype(np.complex64),
        "scalar": np.float64(3.5),
        "string": np.asarray('{"a": 1}'),
        "empty": np.zeros((0, 3)),
        "structured": np.zeros(3, dtype=[("a", "<f4"), ("b", "<i2")]),
        "utf8-header": np.zeros(2, dtype=[("\u4e2d", "<f4")]),  # a version 3.0 header
    }


@pytest.mark.filterwarnings("ignore:Stored array in format 3.0")
@pytest.mark.parametrize("name", list(_good_arrays()))
def test_good_npy_files_read_bit_for_bit_as_numpy_load(tmp_path, name):
    array = _good_arrays()[name]
    path = tmp_path / "a.npy"
    np.save(path, array)
    got, want = load_npy(path, what="test file", fix="-"), np.load(path, allow_pickle=False)
    assert got.dtype == want.dtype and got.shape == want.shape
    assert got.flags.f_contiguous == want.flags.f_contiguous
    assert got.tobytes("A") == want.tobytes("A")


@pytest.mark.filterwarnings("ignore:Stored array in format 3.0")
@pytest.mark.parametrize("save", [np.savez, np.savez_compressed])
def test_good_npz_archives_read_bit_for_bit_as_numpy_load(tmp_path, save):
    arrays = _good_arrays()
    save(tmp_path / "a.npz", **{k.replace("-", "_"): v for k, v in arrays.items()})
    with open_npz(tmp_path / "a.npz", what="", fix="-") as z, \
            np.load(tmp_path / "a.npz", allow_pickle=False) as want:
        assert z.files == want.files
        for key in z.files:
            got = z.load(key)
            assert got.dtype == want[key].dtype and got.shape == want[key].shape
            assert got.tobytes("A") == want[key].tobytes("A")


# --- the shared loader: what it refuses --------------------------------------------------------

@pytest.mark.parametrize("kind", list(_WORDS))
def test_a_bad_npy_is_one_line_naming_the_file(tmp_path, kind):
    """A damaged header byte was tokenize.TokenError (exit 70); a lying header "Unable to
    allocate" (exit 3); a truncated file "Failed to read all data" without the file; a longer
    one was read without a word."""
    path = tmp_path / f"{kind}.npy"
    path.write_bytes(_bad_npy(kind, np.linspace(0, 1, 256)))
    with pytest.raises(InputError) as info:
        load_npy(path, what="test file", fix="save it again")
    assert _WORDS[kind] in _one_line_naming(info, path)


def test_a_pickled_npy_is_refused_without_unpickling(tmp_path):
    path = tmp_path / "objects.npy"
    np.save(path, np.array([{"a": 1}], dtype=object), allow_pickle=True)
    with pytest.raises(InputError, match=r"holds Python objects.*never unpickles"):
        load_npy(path, what="test file", fix="-")


def test_a_named_pipe_is_never_opened(tmp_path):
    """Opening a named pipe for reading waits for a writer: it is refused from its stat."""
    path = tmp_path / "pipe.npy"
    os.mkfifo(path)
    with pytest.raises(InputError, match=r"test file .*pipe\.npy is not a regular file "
                                         r"\(a named pipe"):
        load_npy(path, what="test file", fix="-")


@pytest.mark.parametrize("kind", ["header", "lie", "truncated", "longer"])
def test_a_bad_npz_member_names_the_archive_and_the_array(tmp_path, kind):
    np.savez(tmp_path / "good.npz", a=np.arange(10.0), b=np.ones((4, 4), np.float32))
    bad = _rewrite_npz(tmp_path / "good.npz", tmp_path / "bad.npz",
                       b=_bad_npy(kind, np.ones((4, 4), np.float32)))
    with open_npz(bad, what="", fix="-") as z:
        np.testing.assert_array_equal(z.load("a"), np.arange(10.0))
        with pytest.raises(InputError) as info:
            z.load("b")
    message = _one_line_naming(info, bad)
    assert "its array 'b'" in message and _WORDS[kind] in message


def test_an_npz_whose_directory_lies_with_its_header_is_refused(tmp_path):
    """The member's header and the archive's directory entry both claim 4 GB where 128 bytes
    are stored: the directory is checked against the archive before it is trusted (else NumPy
    allocates the claim, then finds the data short)."""
    count = (2 ** 32 - 1024) // 8
    member = _lying_npy_bytes(np.ones(16), (count,))
    header_bytes = len(member) - 128
    path = tmp_path / "forged.npz"
    with zipfile.ZipFile(path, "w") as z:
        z.writestr("a.npy", member)
    data = bytearray(path.read_bytes())
    central = data.rindex(b"PK\x01\x02")
    struct.pack_into("<I", data, central + 24, header_bytes + 8 * count)  # uncompressed size
    path.write_bytes(bytes(data))
    with open_npz(path, what="", fix="-") as z:
        with pytest.raises(InputError, match=r"its array 'a' is truncated or corrupt \(its "
                                             r"entry in the archive says \d+ bytes, 256 stored"):
            z.load("a")


# --- each reader of .npy/.npz files uses it ----------------------------------------------------

@pytest.mark.parametrize("kind", list(_WORDS))
def test_a_bad_depth_npy_names_the_file(tmp_path, kind):
    """``clholo render image.png depth.npy`` with one changed header byte was an internal
    error; with a lying header "Unable to allocate 37.3 GiB" (exit 3)."""
    path = tmp_path / "depth.npy"
    path.write_bytes(_bad_npy(kind, np.full((6, 8), 1.5, np.float32)))
    with pytest.raises(InputError) as info:
        clholo.io.read_depth(path)
    message = _one_line_naming(info, path)
    assert message.startswith(f"depth file {path}") and _WORDS[kind] in message


@pytest.mark.parametrize("kind", list(_WORDS))
def test_a_bad_lut_npy_names_the_file(tmp_path, kind):
    """``--lut lut.npy`` caught ValueError only: TokenError was exit 70, a header claiming
    10**12 entries "Unable to allocate 7.28 TiB"."""
    from clholo.encode.quantize import read_luts

    path = tmp_path / "lut.npy"
    path.write_bytes(_bad_npy(kind, np.linspace(0, 2 * np.pi, 256, endpoint=False)))
    with pytest.raises(InputError) as info:
        read_luts(path)
    message = _one_line_naming(info, path)
    assert message.startswith(f"lookup table {path}") and _WORDS[kind] in message


def test_a_lut_with_a_lying_header_is_exit_2_on_the_command_line(tmp_path, capsys):
    hologram, _ = _hologram(tmp_path)
    lut = tmp_path / "lut.npy"
    lut.write_bytes(_bad_npy("lie", np.linspace(0, 6, 256)))
    assert cli.main(["encode", str(hologram), "--lut", str(lut), "--out",
                     str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"lookup table {lut} is truncated or its header" in err
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("make, words", [
    (lambda p: os.mkfifo(p), "is not a regular file (a named pipe"),
    (lambda p: os.symlink(p, p), "Too many levels of symbolic links"),
])
def test_a_lut_that_is_no_regular_file_is_not_said_to_be_missing(tmp_path, make, words):
    """A named pipe or a loop of symbolic links as ``--lut`` (or the bench's LUT file) "did
    not exist"."""
    from clholo.encode.quantize import read_luts
    from clholo.tools.slm import load_lut

    for suffix, read, what in ((".csv", read_luts, "lookup table"),
                               (".npy", read_luts, "lookup table"),
                               (".txt", load_lut, "LUT file"), (".npy", load_lut, "LUT file")):
        path = tmp_path / f"{read.__name__}{suffix}"
        make(path)
        with pytest.raises(InputError) as info:
            read(path)
        message = _one_line_naming(info, path)
        assert what in message and words in message and "does not exist" not in message


@pytest.mark.parametrize("kind", list(_WORDS))
def test_a_bad_bench_lut_npy_names_the_file(tmp_path, kind):
    from clholo.tools.slm import load_lut

    path = tmp_path / "slm.npy"
    path.write_bytes(_bad_npy(kind, np.arange(256, dtype=np.uint8)))
    with pytest.raises(InputError) as info:
        load_lut(path)
    assert _WORDS[kind] in _one_line_naming(info, path)


@pytest.mark.parametrize("kind", list(_WORDS) + ["fifo"])
def test_a_bad_pattern_file_names_the_option_and_the_file(tmp_path, kind):
    from clholo.tools.capture import load_patterns

    path = tmp_path / "patterns.npy"
    if kind == "fifo":
        os.mkfifo(path)  # was "does not exist"
    else:
        path.write_bytes(_bad_npy(kind, np.zeros((1, 1, 8, 12), np.uint8)))
    with pytest.raises(InputError) as info:
        load_patterns(path, (8, 12), option="--patterns")
    message = _one_line_naming(info, path)
    assert message.startswith(f"--patterns {path}")
    assert (_WORDS.get(kind) or "is not a regular file (a named pipe") in message


@pytest.mark.parametrize("kind", list(_WORDS))
def test_a_bad_focal_stack_in_a_report_folder_names_the_file(tmp_path, kind):
    """``clholo report`` on a folder whose focal_stack.npz has one changed header byte was an
    internal error; with a lying header "Unable to allocate 45.8 GiB"."""
    from clholo.experiments.report import _load_npz

    np.savez(tmp_path / "good.npz", intensity=np.ones((2, 3, 4, 4), np.float32),
             depths_m=np.array([0.002, 0.004]))
    bad = _rewrite_npz(tmp_path / "good.npz", tmp_path / "focal_stack.npz",
                       intensity=_bad_npy(kind, np.ones((2, 3, 4, 4), np.float32)))
    with pytest.raises(InputError) as info:
        _load_npz(bad, ["intensity"])
    message = _one_line_naming(info, bad)
    assert "its array 'intensity'" in message and _WORDS[kind] in message


# --- hologram .npz ------------------------------------------------------------------------------

@pytest.mark.parametrize("kind", list(_WORDS))
def test_a_hologram_npz_with_a_bad_field_names_the_file(tmp_path, kind):
    """A field.npy with a lying header: "Unable to allocate 146 TiB" (exit 3); one that says 1
    frame of a 2-frame field read the first frame only, with exit 0."""
    path, field = _hologram(tmp_path)
    bad = _rewrite_npz(path, tmp_path / "bad.npz", field=_bad_npy(kind, field))
    with pytest.raises(InputError) as info:
        clholo.io.read_hologram(bad)
    message = _one_line_naming(info, bad)
    assert "its array 'field'" in message and _WORDS[kind] in message


def test_a_hologram_npz_whose_header_drops_a_frame_is_refused(tmp_path):
    path, field = _hologram(tmp_path)
    bad = _rewrite_npz(path, tmp_path / "bad.npz",
                       field=_lying_npy_bytes(field, (1,) + field.shape[1:]))
    with pytest.raises(InputError, match="its array 'field' is longer than its header says"):
        clholo.io.read_hologram(bad)


@pytest.mark.parametrize("key, value", [("frames", 5), ("channels", 1), ("frames", "2")])
def test_a_hologram_npz_whose_metadata_disagrees_with_its_field_is_refused(tmp_path, key,
                                                                         value):
    """The metadata was returned as it was: ``meta["frames"] == 5`` for a 2-frame field."""
    path, _ = _hologram(tmp_path)
    with np.load(path) as z:
        meta = json.loads(str(z["metadata"]))
    bad = _rewrite_npz(path, tmp_path / "bad.npz",
                       metadata=_npy_bytes(np.asarray(json.dumps({**meta, key: value}))))
    with pytest.raises(InputError) as info:
        clholo.io.read_hologram(bad)
    message = _one_line_naming(info, bad)
    assert f"'{key}' must be a whole number" in message if isinstance(value, str) else \
        f"its metadata says {key} = {value} but its field has" in message
    # the untouched file reads, with its counts
    assert clholo.io.read_hologram(path)[1]["frames"] == 2


# --- hologram .exr ------------------------------------------------------------------------------

def _edited_exr(src, dst, **attributes):
    import OpenImageIO as oiio

    buf = oiio.ImageBuf(str(src))
    for name, value in attributes.items():
        if value is None:
            buf.specmod().erase_attribute(name)
        else:
            buf.specmod().attribute(name, value)
    assert buf.write(str(dst), "float"), buf.geterror()
    return dst


def _exr_meta(path):
    import OpenImageIO as oiio

    return json.loads(oiio.ImageBuf(str(path)).spec().getattribute("clholo:metadata"))


@pytest.mark.parametrize("frames, attribute, words", [
    (1, 1, "its metadata says 1 frame(s) of 3 colour channel(s), 6 channels of real and "
           "imaginary parts, but the file stores 12 such channels"),
    (10 ** 12, None, "its metadata says 1000000000000 frame(s)"),
    (1, 2, "its clholo:frames header attribute says 2 but its metadata says 1"),
    (2, 7, "its clholo:frames header attribute says 7 but its metadata says 2"),
])
def test_a_hologram_exr_whose_frames_were_edited_is_refused(tmp_path, frames, attribute,
                                                            words):
    """Metadata edited to 1 frame read frame 0 and dropped frame 1 without a word; edited to
    10**12 frames it was "Unable to allocate 87.3 PiB" (exit 3); the clholo:frames attribute
    was never compared."""
    path, _ = _hologram(tmp_path, ".exr")
    bad = _edited_exr(path, tmp_path / "bad.exr", **{
        "clholo:metadata": json.dumps({**_exr_meta(path), "frames": frames}),
        "clholo:frames": attribute})  # None: removed (an int attribute cannot hold 10**12)
    with pytest.raises(InputError) as info:
        clholo.io.read_hologram(bad)
    message = _one_line_naming(info, bad)
    assert words in message and "the file was edited or is inconsistent" in message


def test_a_hologram_exr_whose_channel_count_was_edited_is_refused(tmp_path):
    path, _ = _hologram(tmp_path, ".exr")
    bad = _edited_exr(path, tmp_path / "bad.exr", **{"clholo:channels": 1})
    with pytest.raises(InputError, match="its clholo:channels header attribute says 1 but its "
                                         "metadata says 3"):
        clholo.io.read_hologram(bad)


def test_a_good_hologram_exr_still_reads(tmp_path):
    path, field = _hologram(tmp_path, ".exr")
    got, meta = clholo.io.read_hologram(path)
    np.testing.assert_array_equal(got, field)
    assert meta["frames"] == 2 and meta["channels"] == 3


def test_a_hologram_exr_cut_in_its_header_is_one_line(tmp_path, capsys):
    """OpenImageIO stacks its reader's messages: the error took 4 lines, the last not
    ``clholo encode: error: ...``."""
    path, _ = _hologram(tmp_path, ".exr")
    cut = tmp_path / "cut.exr"
    cut.write_bytes(path.read_bytes()[:300])
    with pytest.raises(ValueError) as info:
        clholo.io.read_hologram(cut)
    message = _one_line_naming(info, cut)
    assert message.startswith(f"cannot read {cut}: ") and message.count("EXR Error") > 1


def test_an_image_header_cut_short_is_one_line(tmp_path):
    """The header-only reader (depth photos' orientation) had the same stacked lines."""
    from clholo.io.images import _upright_header

    path, _ = _hologram(tmp_path, ".exr")
    cut = tmp_path / "cut.exr"
    cut.write_bytes(path.read_bytes()[:300])
    with pytest.raises(ValueError) as info:
        _upright_header(cut)
    assert "EXR Error" in _one_line_naming(info, cut)


# --- an image's display window -----------------------------------------------------------------

def _exr_with_windows(path, data, full):
    import OpenImageIO as oiio

    spec = oiio.ImageSpec(data, data, 1, "float")
    spec.full_x, spec.full_y, spec.full_width, spec.full_height = 0, 0, full, full
    out = oiio.ImageOutput.create(str(path))
    assert out.open(str(path), spec), out.geterror()
    out.write_image(np.full((data, data, 1), 0.5, np.float32))
    out.close()
    return path


def test_a_display_window_beyond_the_largest_field_is_refused(tmp_path):
    """A 401-byte EXR with a 20000 x 20000 display window around 4 x 4 pixels reached 4.7 GB
    and "Unable to allocate 5.96 GiB" (exit 3) as two MPI layers; 60000 x 60000 was a
    MemoryError at once."""
    from clholo.io import read_image

    path = _exr_with_windows(tmp_path / "wide.exr", 4, 20000)
    with pytest.raises(InputError) as info:
        read_image(path)
    message = _one_line_naming(info, path)
    assert "display window is 20000 x 20000 pixels around a data window of 4 x 4" in message
    # a display window a field can have is still where the pixels go
    pixels, _ = read_image(_exr_with_windows(tmp_path / "ok.exr", 4, 16))
    assert pixels.shape == (16, 16, 1) and pixels[:4, :4].min() == 0.5 and pixels[4:].max() == 0


def test_the_display_window_limit_is_the_largest_field():
    from clholo.io.images import _MAX_FIELD_SIDE
    from clholo.propagation import MAX_FFT_SIZE

    assert _MAX_FIELD_SIDE == MAX_FFT_SIZE


def test_a_changed_byte_in_an_exr_holograms_pixels_is_refused(tmp_path):
    """Random-phase data does not compress: an EXR stores it raw, with no checksum of its own,
    and a flipped high byte read as a value of 5.9e26 (``clholo encode`` exit 0). The field's
    SHA-256 is written with it (``clholo:sha256``) and checked on reading."""
    import OpenImageIO as oiio

    from clholo.errors import InputError
    from clholo.io import read_hologram, write_hologram

    rng = np.random.default_rng(8)
    h = np.exp(2j * np.pi * rng.random((2, 3, 64, 64))).astype(np.complex64)
    good = tmp_path / "h.exr"
    write_hologram(good, h[:, :, :, ::-1], pitch=8e-6, wavelengths=[638e-9, 520e-9, 450e-9])
    field, _ = read_hologram(good)  # a view of other strides is hashed as its values
    assert np.array_equal(field, h[:, :, :, ::-1])
    data = bytearray(good.read_bytes())
    for pos in (len(data) // 3, len(data) // 2, len(data) - 500):
        bad = tmp_path / f"flip{pos}.exr"
        changed = bytearray(data)
        changed[pos] ^= 0x55
        bad.write_bytes(bytes(changed))
        with pytest.raises(InputError, match=r"its pixels do not match the checksum written "
                                             r"with them \(clholo:sha256\)"):
            read_hologram(bad)
    # a file written before the checksum (no clholo:sha256) is read unchecked
    inp = oiio.ImageInput.open(str(good))
    spec = inp.spec()
    # the documented definition: the field's complex64 bytes, [T, C, H, W] in C order
    import hashlib

    want = hashlib.sha256(np.ascontiguousarray(h[:, :, :, ::-1]).tobytes()).hexdigest()
    assert spec.getattribute("clholo:sha256") == want
    pixels = inp.read_image(0, 0, 0, spec.nchannels, "float")
    inp.close()
    spec.erase_attribute("clholo:sha256")
    old = tmp_path / "old.exr"
    out = oiio.ImageOutput.create(str(old))
    assert out.open(str(old), spec) and out.write_image(pixels)
    out.close()
    assert np.array_equal(read_hologram(old)[0], h[:, :, :, ::-1])
