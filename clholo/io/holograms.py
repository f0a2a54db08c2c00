"""Complex hologram fields on disk: OpenEXR (float32 real/imag channels) and NumPy ``.npz``.

EXR layout: one FLOAT channel per (frame, colour, part), named ``t{frame}.{colour}.re`` /
``.im`` with colour ``R``, ``G``, ``B`` for three channels and ``c{index}`` otherwise. The header
carries ``clholo:pitch`` (metres), ``clholo:wavelengths`` (metres, JSON list),
``clholo:frames``, ``clholo:channels``, ``clholo:seed`` (decimal string: seeds are 64-bit),
``clholo:metadata`` (JSON of everything, including the caller's extra keys) and
``clholo:sha256`` (of the field's complex64 bytes, ``[T, C, H, W]`` in C order: an EXR stores
uncompressible random-phase data raw, without a checksum of its own, so a changed byte read
as a value of 1e26 without a word; ``.npz`` members carry zip's CRC). Files without it (written
before 2026-11-29) are read unchecked.
"""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Optional, Sequence, Tuple

import numpy as np

from clholo import validate
from clholo.errors import InputError, InputTypeError

from ._json import parse_json
from ._npy import open_npz
from .images import PathLike, _oiio, _one_line, atomic_path, check_input_file, write_failure

__all__ = ["write_hologram", "read_hologram"]


_NPZ_FIX = "give the hologram.npz that clholo render or clholo.io.write_hologram writes"


def _colour_names(C: int) -> Tuple[str, ...]:
    return ("R", "G", "B") if C == 3 else tuple(f"c{i}" for i in range(C))


def write_hologram(path: PathLike, field: np.ndarray, *, pitch: float,
                   wavelengths: Sequence[float], seed: Optional[int] = None,
                   metadata: Optional[dict] = None) -> Path:
    """Write a complex field ``[T, C, H, W]`` to ``.exr`` or ``.npz`` (by extension).

    Parameters
    ----------
    path : path-like
        ``*.exr`` or ``*.npz``. Written under a temporary name and renamed when complete.
    field : ndarray, shape (T, C, H, W), complex64
        Frames ``T``, colour channels ``C``. ``(C, H, W)`` and ``(H, W)`` are taken as
        ``T = 1`` (and ``C = 1``). Stored as complex64 (float32 parts).
    pitch : float
        Pixel pitch in metres.
    wavelengths : sequence of float, length C
        Metres, one per colour channel.
    seed : int, optional
        Random-phase seed the field was made with (0 <= seed < 2**64).
    metadata : dict, optional
        Extra JSON-serialisable keys, stored and returned by :func:`read_hologram`.
    """
    path = Path(path)
    field = np.asarray(field)
    if not np.iscomplexobj(field):
        raise InputTypeError(f"field must be complex (complex64), got {field.dtype}")
    while field.ndim < 4:
        field = field[None]
    if field.ndim != 4:
        raise InputError(f"field must have shape (T, C, H, W), got {field.shape}")
    if field.size == 0:
        raise InputError(f"field is empty (shape {field.shape}): every axis needs at least one "
                         f"frame, colour or pixel")
    # no copy of a complex64 field (the render's frames: the write's peak memory was twice
    # theirs), and the check a frame at a time (no array of flags as large as a frame's bytes)
    field = field.astype(np.complex64, copy=False)
    if not all(np.isfinite(frame).all() for frame in field):
        raise InputError("field contains NaN/inf values")
    T, C, H, W = field.shape
    # the same checks read_hologram makes: a file written here is one it reads back
    wl = list(validate.wavelengths(wavelengths, name="wavelengths"))
    if len(wl) != C:
        raise InputError(f"wavelengths has {len(wl)} entries but field has {C} colour channels")
    pitch = validate.pitch(pitch, name="pitch")
    for w in wl:
        validate.wavelength_for_pitch(w, pitch, name="wavelengths")
    if seed is not None:
        seed = validate.seed(seed, name="seed")
    meta = {"pitch": pitch, "wavelengths": wl, "frames": T, "channels": C,
            "seed": None if seed is None else int(seed), "extra": metadata or {}}
    try:
        meta_json = json.dumps(meta)
    except TypeError as exc:
        raise TypeError(f"metadata must be JSON-serialisable: {exc}") from None
    suffix = path.suffix.lower()
    if suffix == ".npz":
        with atomic_path(path) as tmp:
            with open(tmp, "wb") as f:  # a file object: np.savez must not append ".npz"
                np.savez(f, field=field, pitch=np.float64(pitch),
                         wavelengths=np.asarray(wl, np.float64),
                         seed=np.asarray(-1 if seed is None else int(seed), dtype=np.uint64
                                         if seed is not None else np.int64),
                         metadata=np.asarray(meta_json))
        return path
    if suffix != ".exr":
        raise ValueError(f"{path}: hologram files are .exr or .npz, got {suffix!r}")
    oiio = _oiio()
    names = []
    planes = []
    cn = _colour_names(C)
    for t in range(T):
        for c in range(C):
            names += [f"t{t}.{cn[c]}.re", f"t{t}.{cn[c]}.im"]
            planes += [field[t, c].real, field[t, c].imag]
    data = np.ascontiguousarray(np.stack(planes, axis=-1).astype(np.float32))
    spec = oiio.ImageSpec(W, H, len(names), "float")
    spec.channelnames = tuple(names)
    spec.attribute("compression", "zip")
    spec.attribute("clholo:pitch", pitch)
    spec.attribute("clholo:wavelengths", json.dumps(wl))
    spec.attribute("clholo:frames", T)
    spec.attribute("clholo:channels", C)
    spec.attribute("clholo:seed", "" if seed is None else str(int(seed)))
    spec.attribute("clholo:metadata", meta_json)
    spec.attribute("clholo:sha256", _field_sha256(field))
    with atomic_path(path) as tmp:
        out = oiio.ImageOutput.create(str(tmp))
        if out is None:
            raise RuntimeError(f"cannot write {path}: {_one_line(oiio.geterror())}")
        try:
            if not out.open(str(tmp), spec) or not out.write_image(data):
                error = _one_line(out.geterror()) or "the writer failed"
                # a full disk or a file-size limit is the machine's (exit 3), not a bug (70)
                failure = write_failure(path, tmp, error[:200])
                if failure is not None:
                    raise failure
                raise RuntimeError(f"cannot write {path}: {error}")
        finally:
            out.close()
    return path


def read_hologram(path: PathLike) -> Tuple[np.ndarray, dict]:
    """Read a field written by :func:`write_hologram`.

    Parameters
    ----------
    path : str or os.PathLike
        A ``.npz`` or ``.exr`` file.

    Returns
    -------
    field : ndarray, shape (T, C, H, W), complex64
    meta : dict
        ``pitch`` (m), ``wavelengths`` (m, list), ``frames``, ``channels``, ``seed`` (int or
        None), ``extra`` (the caller's metadata).
    """
    path = check_input_file(path, "hologram file", "give a hologram .npz or .exr file (the "
                            "hologram.npz that clholo render writes)")
    suffix = path.suffix.lower()
    if suffix == ".npz":
        with open(path, "rb") as fh:
            head = fh.read(4)
        if head and head[:2] != b"PK":
            # np.load takes any other file for a pickle and says "pickled (object) data"
            what = ("a NumPy .npy array (numpy.save), not an .npz archive"
                    if head == b"\x93NUM" else
                    f"not a NumPy .npz archive (it starts with {head!r}, not the zip "
                    f"signature)")
            raise InputError(f"{path} is {what}: {_NPZ_FIX}")
        # open_npz checks each array's header against the bytes stored before reading it:
        # np.load allocated what a damaged header claimed (terabytes: "Unable to allocate",
        # exit 3) and read a prefix of a member longer than its header says (frames dropped)
        try:
            with open_npz(path, what="", fix=_NPZ_FIX) as z:
                missing = [k for k in ("field", "metadata") if k not in z.files]
                if missing:
                    raise InputError(
                        f"{path} is not a clholo hologram .npz: it has no "
                        f"{' or '.join(repr(k) for k in missing)} array (it holds "
                        f"{', '.join(z.files) or 'no array'}); write it with "
                        f"clholo.io.write_hologram")
                field = z.load("field")
                # named "its metadata array": the message below puts the path before it
                meta = parse_json(str(z.load("metadata")), "its metadata array")
                arrays = {k: z.load(k) for k in ("pitch", "wavelengths") if k in z.files}
        except InputError:
            raise
        except (KeyError, ValueError, OSError) as exc:
            raise ValueError(f"{path} is not a clholo hologram .npz: {exc}") from None
        field = _checked_field(path, field)
        _check_counts(path, meta, field.shape)
        meta = _checked_meta(path, meta, arrays, channels=field.shape[1])
        return field.astype(np.complex64), meta
    if suffix != ".exr":
        raise ValueError(f"{path}: hologram files are .exr or .npz, got {suffix!r}")
    oiio = _oiio()
    inp = oiio.ImageInput.open(str(path))
    if inp is None:
        # OpenImageIO stacks its reader's messages on several lines: one line for the boundary
        raise ValueError(f"cannot read {path}: {_one_line(oiio.geterror()) or 'unknown format'}")
    try:
        spec = inp.spec()
        raw = spec.getattribute("clholo:metadata")
        if not raw:
            raise ValueError(f"{path} has no clholo:metadata header; not a clholo hologram")
        meta = parse_json(raw, f"{path}: its clholo:metadata header")
        header = {"pitch": spec.getattribute("clholo:pitch")}
        raw_wl = spec.getattribute("clholo:wavelengths")
        if raw_wl:
            try:
                header["wavelengths"] = np.asarray(json.loads(raw_wl))
            except (ValueError, RecursionError):
                header["wavelengths"] = np.asarray(raw_wl)
        names = list(spec.channelnames)
        checksum = str(spec.getattribute("clholo:sha256") or "")
        # before any pixel is read or the field allocated: the metadata's frames and channels
        # size the field, and an edited count dropped frames or asked for petabytes
        T, C = _exr_counts(path, meta, spec, names)
        data = inp.read_image(0, 0, 0, spec.nchannels, "float")
        if data is None:
            raise ValueError(f"cannot read pixels of {path}: "
                             f"{_one_line(inp.geterror()) or 'unknown error'} (truncated?)")
    finally:
        inp.close()
    data = np.asarray(data).reshape(spec.height, spec.width, spec.nchannels)
    meta = _checked_meta(path, meta, {"pitch": header.get("pitch"),
                                      "wavelengths": header.get("wavelengths")}, channels=C,
                         stored_as="header attribute")
    cn = _colour_names(C)
    field = np.empty((T, C, spec.height, spec.width), np.complex64)
    index = {n: i for i, n in enumerate(names)}  # EXR files may store channels sorted by name
    for t in range(T):
        for c in range(C):
            field[t, c].real = data[..., index[f"t{t}.{cn[c]}.re"]]
            field[t, c].imag = data[..., index[f"t{t}.{cn[c]}.im"]]
    if checksum and _field_sha256(field) != checksum:
        raise InputError(f"{path}: its pixels do not match the checksum written with them "
                         f"(clholo:sha256): {_EDITED}")
    return _checked_field(path, field), meta


def _field_sha256(field: np.ndarray) -> str:
    """SHA-256 of a complex64 ``[T, C, H, W]`` field's bytes in C order, a frame at a time
    (no copy of the whole field)."""
    import hashlib

    digest = hashlib.sha256()
    for frame in field:
        digest.update(np.ascontiguousarray(frame, np.complex64).data)
    return digest.hexdigest()


_EDITED = "the file was edited or is inconsistent; write it again with clholo.io.write_hologram"


def _whole_count(path: Path, meta: dict, key: str) -> int:
    """``meta[key]`` (``frames``, ``channels``) as a whole number >= 1, else refused."""
    value = meta.get(key)
    if isinstance(value, bool) or not isinstance(value, int) or value < 1:
        raise InputError(f"{path}: its metadata '{key}' must be a whole number >= 1, got "
                         f"{value!r}")
    return value


def _exr_counts(path: Path, meta, spec, names: Sequence[str]) -> Tuple[int, int]:
    """The frames and colour channels of a hologram EXR, once its metadata, its
    ``clholo:frames`` / ``clholo:channels`` attributes and the channels it stores agree: a
    metadata edited to fewer frames dropped the others without a word, one edited to more
    asked for the memory of a trillion frames."""
    if not isinstance(meta, dict):
        raise InputError(f"{path}: its clholo:metadata header is not a JSON object; write the "
                         f"file again with clholo.io.write_hologram")
    T, C = _whole_count(path, meta, "frames"), _whole_count(path, meta, "channels")
    for key, count in (("frames", T), ("channels", C)):
        attribute = spec.getattribute(f"clholo:{key}")
        if attribute is not None and (isinstance(attribute, bool) or attribute != count):
            raise InputError(f"{path}: its clholo:{key} header attribute says {attribute!r} but "
                             f"its metadata says {count}: {_EDITED}")
    # the field's channels are t{frame}.{colour}.{re|im}; others (an alpha a tool added) are
    # not the field's and are left alone, as before
    stored = {n for n in names if re.fullmatch(r"t\d+\..+", n)}
    if len(stored) != 2 * T * C:
        raise InputError(f"{path}: its metadata says {T} frame(s) of {C} colour channel(s), "
                         f"{2 * T * C} channels of real and imaginary parts, but the file "
                         f"stores {len(stored)} such channels (t0.R.re, t0.R.im, ...): "
                         f"{_EDITED}")
    cn = _colour_names(C)
    expected = [f"t{t}.{cn[c]}.{part}" for t in range(T) for c in range(C)
                for part in ("re", "im")]
    missing = [n for n in expected if n not in stored]
    if missing:
        raise InputError(f"{path} lacks channel {missing[0]} (it stores "
                         f"{', '.join(sorted(stored - set(expected))[:4])} instead): "
                         f"{_EDITED}")
    return T, C


def _check_counts(path: Path, meta, shape: Tuple[int, ...]) -> None:
    """Refuse an ``.npz`` whose metadata ``frames`` / ``channels`` (when it has them) differ
    from its field's shape: the metadata was returned as it was, saying 5 frames of a
    2-frame field."""
    if not isinstance(meta, dict):
        return  # said by _checked_meta, with the fix
    for key, count in (("frames", shape[0]), ("channels", shape[1])):
        if key not in meta:
            continue
        value = _whole_count(path, meta, key)
        if value != count:
            raise InputError(f"{path}: its metadata says {key} = {value} but its field has "
                             f"{count} (shape {tuple(shape)}): {_EDITED}")


def _checked_field(path: Path, field: np.ndarray) -> np.ndarray:
    """The stored field as it must be: complex ``[T, C, H, W]``, not empty, finite, and within
    the complex64 range it is read in; each refusal names ``path``."""
    if field.ndim != 4:
        raise InputError(f"{path}: holograms must have shape [T, C, H, W], got {field.shape}")
    if not np.iscomplexobj(field):
        raise InputError(
            f"{path}: its field is {field.dtype}, not complex: a hologram is a complex field "
            f"(amplitude and phase); store field.astype(np.complex64) (clholo.io.write_hologram "
            f"refuses a real field)")
    if min(field.shape) < 1:
        raise InputError(f"{path}: holograms must hold at least one frame, colour and pixel, "
                         f"got shape {field.shape}")
    finite = np.isfinite(field)
    bad = int(field.size - np.count_nonzero(finite))
    if bad:  # here, where the file is known, rather than "holograms contain NaN" later
        first = np.unravel_index(int(np.argmin(finite)), field.shape)
        raise InputError(f"{path}: its field holds {bad} NaN/inf value(s) (the first at "
                         f"[t, c, y, x] = {list(map(int, first))}): every value must be finite; "
                         f"render or write the hologram again")
    top = float(np.finfo(np.float32).max)
    if field.dtype.itemsize > np.dtype(np.complex64).itemsize:
        # a wider field is cast to complex64 when read: a part beyond float32's range would
        # become inf there (with only NumPy's overflow warning) and be refused later as
        # "holograms contain NaN/inf", without the file's name
        big = np.maximum(np.abs(field.real), np.abs(field.imag)) > top
        if big.any():
            first = np.unravel_index(int(np.argmax(big)), field.shape)
            raise InputError(
                f"{path}: its field holds {int(big.sum())} value(s) beyond the complex64 range "
                f"that holograms are read in (parts up to {top:.4g}; the first at [t, c, y, x] "
                f"= {list(map(int, first))} is {complex(field[first]):.4g}): scale the field "
                f"down (a hologram's overall amplitude is free) and write it again")
    return field


def _scalar(value):
    """A 0-d or one-element array as its element (what np.savez makes of a float)."""
    arr = np.asarray(value)
    return arr.item() if arr.size == 1 and arr.ndim <= 1 else value  # .item(): a Python float


def _checked_meta(path: Path, meta, arrays: dict, *, channels: int,
                  stored_as: str = "array") -> dict:
    """``meta`` with its ``pitch`` and ``wavelengths`` checked as the command line checks them
    (metres, finite, one wavelength per colour), and the file's own ``pitch`` /
    ``wavelengths`` arrays (or EXR attributes), where present, equal to them: a file whose
    arrays were edited says so rather than being encoded with the metadata's values."""
    if not isinstance(meta, dict) or "pitch" not in meta or "wavelengths" not in meta:
        raise InputError(f"{path}: its metadata lacks pitch and wavelengths; write the file "
                         f"again with clholo.io.write_hologram")
    what = f"{path}: metadata"
    pitch = validate.pitch(_scalar(meta["pitch"]), name=f"{what} pitch")
    wl = validate.wavelengths(meta["wavelengths"], name=f"{what} wavelengths")
    for key, value in arrays.items():
        if value is None:
            continue
        name = f"{path}: {key}"
        if key == "pitch":
            got = validate.pitch(_scalar(value), name=name)
            same = np.isclose(got, pitch, rtol=1e-6, atol=0)
        else:
            if np.asarray(value).dtype.kind not in "fiu":
                raise InputTypeError(f"{name} must be numbers in metres, got {value!r}")
            got = validate.wavelengths(np.asarray(value).ravel().tolist(), name=name)
            if len(got) != channels:
                raise InputError(f"{name} has {len(got)} value(s) but the field has {channels} "
                                 f"colour channel(s): give one wavelength per colour")
            same = len(got) == len(wl) and np.allclose(got, wl, rtol=1e-6, atol=0)
        if not same:
            shown = (lambda v: f"{v:g}") if key == "pitch" else \
                (lambda v: "[" + ", ".join(f"{x:g}" for x in v) + "]")
            raise InputError(
                f"{path}: its {key} {stored_as} says {shown(got)} m but its metadata says "
                f"{shown(pitch if key == 'pitch' else wl)} m: the file was edited or is "
                f"inconsistent; write it again with clholo.io.write_hologram")
    if len(wl) != channels:
        raise InputError(f"{what} wavelengths has {len(wl)} value(s) but the field has "
                         f"{channels} colour channel(s): give one wavelength per colour")
    return {**meta, "pitch": pitch, "wavelengths": list(wl)}
