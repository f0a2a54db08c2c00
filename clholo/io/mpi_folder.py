"""MPI folders: one image per layer plus ``mpi.json`` (format described in ``docs/inputs.md``).

``mpi.json`` written by clholo::

    {
      "format": "clholo-mpi", "version": 1,
      "layers": ["layer_00.exr", ...]            # RGBA (or YA) files, or
                [{"color": "rgb_00.png", "alpha": "alpha_00.png"}, ...],
      "layer_order": "front_to_back",            # or "back_to_front": order of "layers"
      "depths": [0.05, ...],                     # one per entry of "layers", same order
      "depth_units": "metres",                   # or "scene units" (placed by near/far)
      "color_encoding": "linear",                # or "srgb" (decoded with the exact sRGB EOTF)
      "alpha": "straight",                       # or "premultiplied"
      "farthest_alpha": "stored"                 # or "opaque" (Stereo Magnification's rule)
    }

A file without ``"format"`` (for example ``../shared/data/twain-mpi/mpi.json``) is read with the
Stereo Magnification conventions for every key it does not state: straight alpha, sRGB colour,
farthest alpha taken as 1. ``layer_order`` may carry a trailing comment (``"back_to_front
(layer_00 is the farthest)"``). A key that would be ignored is refused: in a ``"clholo-mpi"``
file any key not listed above, in a file without ``"format"`` (which may carry descriptive keys
of its own, as twain's ``source`` and ``intrinsics``) a misspelling of one listed above
(``"depht_units"``).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import List, Optional, Sequence, Tuple

import numpy as np

from ..errors import InputError
from ..scene import MPI, stored_or_placed_depths
from ._json import read_json
from .images import (PathLike, check_input_file, grey_channel, linear_to_srgb, read_image,
                     srgb_to_linear, write_image)
from .output import output_folder

__all__ = ["read_mpi", "write_mpi", "MPI_JSON", "KEYS"]

MPI_JSON = "mpi.json"
_FORMATS = {"exr": ("exr", "float", "linear"), "png16": ("png", "uint16", "srgb"),
            "png8": ("png", "uint8", "srgb")}


#: The keys of ``mpi.json`` that :func:`read_mpi` reads (the module docstring says what each
#: means); :func:`write_mpi` writes exactly these.
KEYS = ("format", "version", "layers", "layer_order", "depths", "depth_units",
        "color_encoding", "alpha", "farthest_alpha")


def _check_keys(meta: dict, json_path: Path) -> None:
    """Refuse a key that would be ignored: in a ``"format": "clholo-mpi"`` file any key that is
    not one of :data:`KEYS` (clholo writes no other); in a file without ``"format"`` (Stereo
    Magnification's, which carries descriptive keys of its own such as ``source``,
    ``intrinsics``) a key that is a misspelling of one of :data:`KEYS`."""
    import difflib

    ours = meta.get("format") == "clholo-mpi"
    for key in meta:
        if key in KEYS:
            continue
        close = difflib.get_close_matches(str(key), KEYS, n=1, cutoff=0.8)
        if not (ours or close):
            continue
        hint = f"did you mean {close[0]!r}? " if close else ""
        raise ValueError(f"{json_path}: unknown key {key!r}; {hint}the keys an mpi.json may "
                         f"hold are {', '.join(KEYS)} (docs/inputs.md)")


def _choice(meta: dict, key: str, allowed: Sequence[str], default: str, json_path: Path) -> str:
    value = meta.get(key, default)
    if not isinstance(value, str):
        raise ValueError(f"{json_path}: {key!r} must be one of {list(allowed)}, got {value!r}")
    word = value.strip().split()[0].lower() if value.strip() else ""
    if word not in allowed:
        raise ValueError(f"{json_path}: {key!r} must be one of {list(allowed)}, got {value!r}")
    return word


def _check_linear_tag(info: dict, path: Path, encoding: Optional[str], json_path: Path) -> None:
    """Refuse an integer layer file that states linear values (a PNG ``gAMA`` chunk of gamma 1,
    which OpenImageIO reports as ``oiio:ColorSpace`` ``"lin_..."``) in an MPI whose
    ``color_encoding`` is sRGB: decoding it as sRGB would darken every mid-tone without a word.
    (The reverse cannot be told: a file that states nothing reads as sRGB.)"""
    space = str(info["attributes"].get("oiio:ColorSpace", "")).strip().lower()
    if encoding == "srgb" and info["max_code"] is not None and space.startswith("lin"):
        raise ValueError(f"{path} states linear values (gamma 1) but {json_path} reads its "
                         f"layers as sRGB (color_encoding {encoding!r}, stated or by default): "
                         f'set "color_encoding": "linear" in {json_path.name} if the layers are '
                         f"linear, or save them without the gamma-1 gAMA chunk")


def _foreign_profile(info: dict) -> Optional[str]:
    """The name of a colour file's embedded ICC profile when it is not sRGB's, or its OpenEXR
    ``chromaticities`` when they are not Rec. 709's (MPI layers follow ``color_encoding``, not
    profiles or primaries), else None."""
    chroma = info["attributes"].get("chromaticities")
    if chroma is not None:
        from .icc import chromaticities_matrix

        try:
            foreign = chromaticities_matrix(chroma) is not None
        except ValueError:
            foreign = True
        if foreign:
            return "EXR chromaticities " + ", ".join(f"{v:.4g}" for v in np.ravel(chroma))
    data = info["attributes"].get("ICCProfile")
    if data is None or len(data) == 0:
        return None
    from .icc import parse_icc

    try:
        profile = parse_icc(data)
    except ValueError:
        return "an unreadable profile"
    return None if profile.applicable and profile.is_srgb() else repr(profile.name)


def _read_rgba(folder: Path, entry, index: int, json_path: Path,
               encoding: Optional[str] = None, profiles: Optional[list] = None):
    """Colour (H, W, C) and alpha (H, W) as stored (integer files: raw codes), the largest code
    of each (None for float files), and a name for errors. With ``encoding``, a colour file
    that states another encoding is refused (:func:`_check_linear_tag`). A colour file with
    an ICC profile other than sRGB's is added to ``profiles`` as ``(path, profile name)``."""
    if isinstance(entry, str):
        path = folder / entry
        if path.is_dir():
            raise ValueError(f"{json_path}: layer {index} names {entry!r}, which is a folder "
                             f"({path}): give the layer's image file")
        if not path.is_file():
            check_input_file(path, f"{json_path}: layer {index} file",
                             "give the layer's image file (RGBA PNG or EXR)")
        px, info = read_image(path, normalise=False)
        _check_linear_tag(info, path, encoding, json_path)
        foreign = _foreign_profile(info) if profiles is not None else None
        if foreign:
            profiles.append((path, foreign))
        names = info["channels"]
        a = info["alpha_channel"]
        if a < 0 and names and names[-1].upper() in ("A", "ALPHA"):
            a = len(names) - 1
        if a < 0 or px.shape[2] < 2:
            raise ValueError(
                f"{path} has no alpha channel (channels {','.join(names)}); an MPI layer file "
                f"needs RGBA (or YA), or give colour and alpha as separate files in {json_path}: "
                f'{{"color": "...", "alpha": "..."}}')
        keep = [i for i in range(px.shape[2]) if i != a]
        return px[..., keep], px[..., a], info["max_code"], info["max_code"], str(path)
    if (isinstance(entry, dict) and isinstance(entry.get("color"), str)
            and isinstance(entry.get("alpha"), str)):
        cpath, apath = folder / entry["color"], folder / entry["alpha"]
        for p in (cpath, apath):
            if p.is_dir():
                raise ValueError(f"{json_path}: layer {index} names {p}, which is a folder: "
                                 f"give the layer's image file")
            if not p.is_file():
                check_input_file(p, f"{json_path}: layer {index} file",
                                 "give the layer's image file (PNG or EXR)")
        cpx, cinfo = read_image(cpath, normalise=False)
        _check_linear_tag(cinfo, cpath, encoding, json_path)
        foreign = _foreign_profile(cinfo) if profiles is not None else None
        if foreign:
            profiles.append((cpath, foreign))
        apx, ainfo = read_image(apath, normalise=False)
        if apx.shape[2] != 1:
            ai = ainfo["alpha_channel"]
            if ai < 0:  # a grey alpha saved as RGB is read; channels that differ are not
                apx = grey_channel(apx, f"alpha file {apath}", "alpha map", fix=(
                    "save alpha as a one-channel image"))[..., None]
            else:
                apx = apx[..., ai:ai + 1]
        if cpx.shape[:2] != apx.shape[:2]:
            raise ValueError(f"{cpath} is {cpx.shape[1]}x{cpx.shape[0]} but its alpha {apath} is "
                             f"{apx.shape[1]}x{apx.shape[0]}; colour and alpha must match")
        return cpx, apx[..., 0], cinfo["max_code"], ainfo["max_code"], str(cpath)
    raise ValueError(f"{json_path}: layer {index} must be a file name or "
                     f'{{"color": file, "alpha": file}} (each one file name, as text), got '
                     f"{json.dumps(entry)}")


def _normalise(arr: np.ndarray, max_code: Optional[int]) -> np.ndarray:
    return arr if max_code is None else arr * np.float32(1.0 / max_code)


def _decode_layers(colors: List[np.ndarray], alphas: List[np.ndarray], names: List[str], *,
                   encoding: str, alpha_mode: str, color_codes: Sequence[Optional[int]] = (),
                   alpha_codes: Sequence[Optional[int]] = ()) -> Tuple[np.ndarray, np.ndarray]:
    """Stack layers and decode them to straight linear colour and alpha in [0, 1], float32.

    Integer layers may come as raw codes (``color_codes``/``alpha_codes`` give the largest code
    per layer, None for float data); straight sRGB codes are decoded through an exact lookup
    table, which is both faster and more accurate than evaluating the EOTF per pixel.
    """
    color_codes = list(color_codes) or [None] * len(colors)
    alpha_codes = list(alpha_codes) or [None] * len(colors)
    shapes = {c.shape for c in colors}
    if len(shapes) != 1:
        first = colors[0].shape
        bad = next(n for n, c in zip(names, colors) if c.shape != first)
        raise ValueError(f"layers differ in size or channels: {names[0]} is "
                         f"{first[1]}x{first[0]}x{first[2]} but {bad} is "
                         f"{colors[names.index(bad)].shape[1]}x{colors[names.index(bad)].shape[0]}"
                         f"x{colors[names.index(bad)].shape[2]}; every layer must match")
    alpha = np.stack([_normalise(a, k) for a, k in zip(alphas, alpha_codes)]).astype(np.float32)
    codes = set(color_codes)
    if (alpha_mode == "straight" and encoding == "srgb" and len(codes) == 1
            and None not in codes):
        top = codes.pop()
        lut = srgb_to_linear(np.arange(top + 1) / top).astype(np.float32)
        color = np.stack([lut[c.astype(np.int64)] for c in colors])
        return color, alpha
    color = np.stack([_normalise(c, k) for c, k in zip(colors, color_codes)]).astype(np.float64)
    alphas = list(alpha)
    colors = list(color)
    for name, c, a in zip(names, colors, alphas):
        if not (np.all(np.isfinite(c)) and np.all(np.isfinite(a))):
            bad = int(np.count_nonzero(~np.isfinite(c)) + np.count_nonzero(~np.isfinite(a)))
            raise ValueError(f"{name} holds {bad} NaN/inf value(s): export the layer again, or "
                             f"replace them with 0 (alpha 0 is transparent, colour 0 black)")
        if a.min() < 0 or a.max() > 1:
            raise ValueError(f"{name}: alpha outside [0, 1] (range {a.min():.4g}..{a.max():.4g})")
    if alpha_mode == "premultiplied":
        # Premultiplication is undone on the stored values, before any sRGB decoding: that is
        # how 8-bit premultiplied files are made. Colour under zero alpha is unknown: 0.
        a = alpha[..., None]
        color = np.where(a > 0, color / np.where(a > 0, a, 1.0), 0.0)
        color = np.clip(color, 0.0, 1.0)  # quantisation can push c/a a hair past 1
    for name, c in zip(names, color):  # name the layer, as the alpha check does
        if c.min() < 0 or c.max() > 1:
            raise ValueError(f"{name}: colour outside [0, 1] (range {c.min():.4g}.."
                             f"{c.max():.4g}); MPI colour is intensity in [0, 1]")
    if encoding == "srgb":
        color = srgb_to_linear(color)
    return color.astype(np.float32), alpha.astype(np.float32)


def depth_units(meta: dict, json_path) -> str:
    """``"metres"`` or ``"scene units"``: what ``mpi.json``'s ``depth_units`` says its depths
    are in (its first word: ``"metres"``, ``"meters"``, ``"m"``, or ``"scene"`` as in twain's
    ``"scene units; planes uniform in inverse depth ..."``; scene units when absent). Another
    unit (``"mm"``) is refused: read as scene units, its depths would need --near/--far and
    say nothing of the millimetres they are.

    Parameters
    ----------
    meta : dict
        The ``mpi.json`` object.
    json_path : path-like
        The file, for the message.
    """
    value = meta.get("depth_units", "scene units")
    word = value.strip().split()[0].lower() if isinstance(value, str) and value.strip() else ""
    if word in ("metres", "meters", "m"):
        return "metres"
    if word == "scene":
        return "scene units"
    raise InputError(f"{json_path}: 'depth_units' must be \"metres\" (depths in metres behind "
                     f"the hologram plane) or \"scene units\" (depths that --near/--far "
                     f"place), got {json.dumps(value)}: give the depths in metres (2 mm is "
                     f"0.002) with \"metres\", or write \"scene units\"")


def read_mpi(path: PathLike, *, near: Optional[float] = None, far: Optional[float] = None,
             spacing: str = "index") -> MPI:
    """Read an MPI folder (``mpi.json`` + one image per layer).

    Parameters
    ----------
    path : path-like
        The folder, or its ``mpi.json``.
    near, far : float, optional
        Metres behind the hologram plane. When given, the layers are placed into
        ``[near, far]`` with :meth:`MPI.placed` (``spacing``); otherwise the depths are returned
        as stored (scene units unless ``depth_units`` is ``"metres"``).
    spacing : {"index", "depth", "inverse"}
        How :meth:`MPI.placed` spaces the layers when ``near``/``far`` are given.

    Returns
    -------
    MPI
        Colour as linear intensity (sRGB decoded), straight alpha, layers nearest first.

    Raises
    ------
    FileNotFoundError
        Missing folder, ``mpi.json`` or layer file (named).
    ValueError
        Malformed ``mpi.json`` (not JSON, an unknown or misspelt key, a key given twice, a
        ``depth_units`` other than metres or scene units), layers of different sizes, a layer
        without alpha, depths that are not strictly monotonic in the stated layer order, or
        that reach beyond 1 km without ``near``/``far`` to place them; each names the file.
    """
    path = Path(path)
    json_path = path if path.suffix.lower() == ".json" else path / MPI_JSON
    folder = json_path.parent
    if not json_path.is_file():
        if json_path.exists() or json_path.is_symlink():   # a pipe, a device or a folder
            check_input_file(json_path, "MPI description",
                             "give the folder's mpi.json as a file (see docs/inputs.md)")
        raise FileNotFoundError(f"{json_path} does not exist; an MPI folder needs an mpi.json "
                                f"(see docs/inputs.md)")
    meta = read_json(json_path)
    if not isinstance(meta, dict):
        raise ValueError(f"{json_path} must hold a JSON object")
    _check_keys(meta, json_path)
    for key in ("layers", "depths"):
        if key not in meta or not isinstance(meta[key], list) or not meta[key]:
            raise ValueError(f"{json_path} needs a non-empty list {key!r}")
    layers, depths = meta["layers"], meta["depths"]
    if len(layers) != len(depths):
        raise ValueError(f"{json_path} lists {len(layers)} layers but {len(depths)} depths; "
                         f"give one depth per layer")
    bad = [d for d in depths if isinstance(d, bool) or not isinstance(d, (int, float))]
    if bad:  # np.asarray would take "0.004" and true (as 1.0) without a word
        raise ValueError(f"{json_path}: 'depths' must be numbers, got {json.dumps(bad[0])} "
                         f"({type(bad[0]).__name__}) among them; write e.g. 0.004, unquoted")
    try:
        depths = np.asarray(depths, dtype=np.float64)
    except OverflowError:  # an integer of hundreds of digits: no float holds it
        big = next(d for d in depths if isinstance(d, int) and abs(d) > 1e308)
        raise ValueError(f"{json_path}: 'depths' holds an integer of {len(str(abs(big)))} "
                         f"digits, beyond any depth; write the depths as numbers such as "
                         f"0.004") from None
    except (TypeError, ValueError):
        raise ValueError(f"{json_path}: 'depths' must be numbers, got {meta['depths']!r}") from None
    if not np.all(np.isfinite(depths)) or np.any(depths <= 0):
        raise ValueError(f"{json_path}: depths must be finite and > 0, got {depths.tolist()}")
    ours = meta.get("format") == "clholo-mpi"
    if "format" in meta and not ours:
        raise ValueError(f"{json_path}: unknown format {meta['format']!r} (expected 'clholo-mpi')")
    version = meta.get("version", 1)
    if ours and (isinstance(version, bool) or version != 1):
        # a later version may mean something else by the same keys: read it with that clholo
        raise ValueError(f"{json_path}: 'version' {version!r} of the clholo-mpi format is not "
                         f"one this clholo reads (1): upgrade clholo, or write the folder "
                         f"with clholo.io.write_mpi")
    # Files without "format" follow Stereo Magnification unless they say otherwise.
    encoding = _choice(meta, "color_encoding", ("srgb", "linear"),
                       "linear" if ours else "srgb", json_path)
    alpha_mode = _choice(meta, "alpha", ("straight", "premultiplied"), "straight", json_path)
    farthest = _choice(meta, "farthest_alpha", ("stored", "opaque"),
                       "stored" if ours else "opaque", json_path)
    order = meta.get("layer_order")
    if order is not None:
        order = _choice(meta, "layer_order", ("front_to_back", "back_to_front"), "", json_path)
        steps = np.diff(depths) if order == "front_to_back" else -np.diff(depths)
        if np.any(steps <= 0):
            bad = int(np.argmax(steps <= 0))
            raise ValueError(
                f"{json_path}: layer_order is {order!r} but depths are not strictly "
                f"{'increasing' if order == 'front_to_back' else 'decreasing'} (layer {bad}: "
                f"{depths[bad]}, layer {bad + 1}: {depths[bad + 1]}); fix the depths or the order")
    elif len(depths) > 1 and not (np.all(np.diff(depths) > 0) or np.all(np.diff(depths) < 0)):
        raise ValueError(f"{json_path}: depths must be strictly monotonic in layer order, got "
                         f"{depths.tolist()}")
    # before any layer is read: depths that cannot be used as stored are said at once
    units = depth_units(meta, json_path)
    placed = stored_or_placed_depths(depths, near, far, spacing=spacing, source=str(json_path),
                                     units=units)
    colors, alphas, names, ccodes, acodes, profiles = [], [], [], [], [], []
    for i, entry in enumerate(layers):
        c, a, ck, ak, name = _read_rgba(folder, entry, i, json_path, encoding, profiles)
        colors.append(c)
        alphas.append(a)
        ccodes.append(ck)
        acodes.append(ak)
        names.append(name)
    if profiles:  # once for the folder, not once a layer
        import warnings

        from .icc import ColourProfileWarning

        first, name = profiles[0]
        warnings.warn(f"{len(profiles)} layer file(s) of {folder} carry an ICC profile or "
                      f"primaries other than sRGB's ({first.name}: {name}); MPI layers are "
                      f"decoded by {json_path.name}'s color_encoding ({encoding!r}), not by "
                      f"profiles: convert the layers to sRGB if their colours matter",
                      ColourProfileWarning, stacklevel=2)
    color, alpha = _decode_layers(colors, alphas, names, encoding=encoding, alpha_mode=alpha_mode,
                                  color_codes=ccodes, alpha_codes=acodes)
    if farthest == "opaque":
        alpha[int(np.argmax(depths))] = 1.0
    return MPI(color, alpha, placed)


def write_mpi(path: PathLike, mpi: MPI, *, format: str = "exr", overwrite: bool = False,
              encoding: Optional[str] = None) -> Path:
    """Write ``mpi`` as a folder of RGBA layer images plus ``mpi.json``.

    Parameters
    ----------
    path : path-like
        Folder to create. It is built under a temporary name in the same parent and renamed
        when complete, so a failure (Ctrl-C included) leaves nothing (or the previous folder)
        behind. It gets clholo's manifest (:data:`clholo.io.output.MANIFEST_NAME`), as every
        output folder does (:func:`clholo.io.output.output_folder`).
    mpi : MPI
    format : {"exr", "png16", "png8"}
        ``"exr"``: float32, exact round trip. ``"png16"``/``"png8"``: quantised (PNG supports
        1 or 3 colour channels only).
    overwrite : bool
        Replace an existing ``path`` that clholo wrote (an MPI folder written by this function,
        with nothing added or changed in it since); a folder or file clholo did not write is
        never replaced, whatever this says.
    encoding : {"linear", "srgb"}, optional
        Colour encoding in the files; default linear for EXR and sRGB for PNG (8-bit sRGB keeps
        dark tones; linear 8-bit bands them).

    Returns
    -------
    Path
        The folder written.

    Raises
    ------
    clholo.errors.OutputRefused
        ``path`` exists and may not be replaced (a ``FileExistsError``; the message says why).
    FileNotFoundError
        The parent folder of ``path`` does not exist.
    PermissionError
        The parent folder of ``path`` cannot be written to.
    """
    if format not in _FORMATS:
        raise ValueError(f"format must be one of {sorted(_FORMATS)}, got {format!r}")
    if not isinstance(mpi, MPI):
        raise TypeError(f"mpi must be a clholo.MPI, got {type(mpi).__name__}")
    ext, dtype, default_enc = _FORMATS[format]
    encoding = default_enc if encoding is None else encoding
    if encoding not in ("linear", "srgb"):
        raise ValueError(f"encoding must be 'linear' or 'srgb', got {encoding!r}")
    C = mpi.channels
    if ext == "png" and C not in (1, 3):
        raise ValueError(f"PNG layers hold 1 or 3 colour channels; this MPI has {C}: use "
                         f"format='exr'")
    names = {1: ("Y", "A"), 3: ("R", "G", "B", "A")}.get(
        C, tuple(f"c{i}" for i in range(C)) + ("A",))
    digits = max(2, len(str(mpi.layers - 1)))
    files = [f"layer_{i:0{digits}d}.{ext}" for i in range(mpi.layers)]
    meta = {"format": "clholo-mpi", "version": 1, "layers": files,
            "layer_order": "front_to_back", "depths": [float(d) for d in mpi.depths],
            "depth_units": "metres", "color_encoding": encoding, "alpha": "straight",
            "farthest_alpha": "stored"}
    # clholo's output-folder rule: an existing path is replaced only with overwrite, and only
    # when clholo wrote it and nothing in it changed since (a user's folder or file never)
    with output_folder(path, overwrite=overwrite, command="write_mpi", option="path") as tmp:
        for i, name in enumerate(files):
            color = mpi.color[i]
            if encoding == "srgb":
                color = linear_to_srgb(color)
            rgba = np.concatenate([color, mpi.alpha[i][..., None]], axis=-1)
            write_image(tmp / name, rgba, dtype=dtype, channel_names=names, encoding=encoding,
                        atomic=False)
        (tmp / MPI_JSON).write_text(json.dumps(meta, indent=1), encoding="utf-8")
    return Path(path)
