"""The GPU kernels' tunable settings per device: the project's defaults, a device's stored
tuning, and what plans built now take (:func:`settings_for`).

The user's side (measuring and storing: :func:`clholo.tuning.tune`, ``clholo tune``) is
:mod:`clholo.tuning`; this module is what the plans read, and imports nothing of clholo's
that plans (it sits below :mod:`clholo.fft` and :mod:`clholo.host.scheduler`).

Settings in effect, from first to last: :func:`override` (benchmarks and tests), the stored
tuning of the device (unless :func:`untuned`), the project's default
(:attr:`Setting.default`). ``CLHOLO_TUNING_FILE`` names the file (``off`` for none); by
default ``$XDG_CACHE_HOME/clholo/tuning.json`` (``~/.cache/clholo/tuning.json``). A stored
entry is used only by the clholo version that measured it (kernels change between versions):
another version's entry is ignored with a :class:`TuningWarning` that says to run
``clholo tune`` again. A malformed file warns once and counts as empty: the settings change
only how fast clholo runs, never what it computes.
"""

from __future__ import annotations

import contextlib
import contextvars
import json
import os
import threading
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Dict, Iterator, Optional, Tuple

import numpy as np

from clholo._version import __version__
from clholo.errors import InputError

__all__ = ["SETTINGS", "Setting", "TuningWarning", "TUNING_FILE_ENV", "device_key", "override",
           "settings_for", "store_entry", "stored_entry", "tuning_file", "untuned", "value",
           "check_writable", "default_tuning_file"]

#: The environment variable naming the tuning file (``off`` or empty: none)
TUNING_FILE_ENV = "CLHOLO_TUNING_FILE"
#: What the file's ``"format"`` says it is
FILE_FORMAT = "clholo-tuning"
FILE_VERSION = 1


class TuningWarning(UserWarning):
    """A stored tuning that is not used (another clholo version, a malformed file), or a form
    of the kernels that gave other bits than the default on the device measured."""


@dataclass
class Setting:
    """One tunable setting: its name, the project's default, the values :func:`clholo.tuning.tune`
    measures, and why the default is what it is.

    Attributes
    ----------
    name : str
        The name in the tuning file and in :func:`override`.
    default : object
        The project's default: what plans take where no stored tuning or override says
        otherwise (tests and ``benchmarks/fft_variants.py`` change it, or use :func:`override`).
    values : tuple
        The values :func:`clholo.tuning.tune` measures.
    what : str
        What the setting changes, and why the default is what it is.
    workloads : tuple of str
        The workloads of :func:`clholo.tuning.tune` it can change (``"render"``, ``"sgd"``):
        the others are not timed for it.
    """

    name: str
    default: Any
    values: Tuple[Any, ...]
    what: str
    workloads: Tuple[str, ...] = ("render", "sgd")


#: Every tunable setting, in the order :func:`clholo.tuning.tune` measures them. Each gives the
#: same bits with any of its values (``tests/test_tuning.py`` checks it on PoCL's run of the GPU
#: kernels; the tuner checks it again on the device it measures). Every default is what the
#: project had before a GPU measured it: the forms off, 2^19 samples per compute unit a launch
#: (docs/benchmarks.md, issue 23).
SETTINGS: Dict[str, Setting] = {s.name: s for s in (
    Setting("mid_quads", False, (False, True),
            "the round trips' mid step (the composite, SGD's Adam step) four elements adjacent "
            "along a row at a time, in a sweep over local memory (FFT_MID_QUADS): one Philox "
            "block per four pixels instead of one per pixel, for a pass over local memory and a "
            "barrier more; GPUs otherwise take the elements one at a time, folded into the "
            "first transform's last stage (CPU strips always go by quads)"),
    Setting("layer_planes", False, (False, True),
            "a two-pass render's layers held as planes, sqrt(c a) [H, C, W] and sqrt(1 - a) "
            "[H, W] made once (layer_layout 'planes' for 'auto' on a GPU): coalesced loads "
            "and no square roots, against the layers as given", ("render",)),
    Setting("batch_fast", False, (False, True),
            "the round trips' work-groups in batch-first order, as the CPU strips run: a group "
            "of lines of every field of a launch one after another, sharing the layer's "
            "colour, alpha and transfer function in the caches (FFT_BATCH_FAST)"),
    Setting("row_pitch", False, (False, True),
            "the row spectrum's rows 128 bytes longer where a row is a multiple of 4 KiB "
            "(clholo.fft.row_pitch), as on CPUs, where such strides cost the column passes "
            "1.19x"),
    Setting("inplace_columns", False, (False, True),
            "columns that two buffers hold fewer than four of per work-group (less than a "
            "32-byte sector of each row: the SLM grid's 1125 points, 2048 at 1024^2 pad 2) on "
            "the in-place plan, which holds more of them (five and two on an H100), with the "
            "two-buffer plan's stages"),
    Setting("split_columns", 0, (0, 512, 1024),
            "the same columns on the split plan (one component at a time in local memory, the "
            "values in registers between stages) with up to this many work-items a group (0: "
            "off), which holds more of them still (the SLM grid's 1125 points ten to a group "
            "on an H100, 2048 points five), with the two-buffer plan's stages; where "
            "inplace_columns is on too, the plan that holds more columns. Also columns that "
            "the in-place plan holds fewer than four of, with its stages (the 4K grid's 2187 "
            "points and SGD 2048's 2250 five to a group, where it holds two; at most 512 "
            "work-items there)"),
    Setting("inplace_direct", False, (False, True),
            "the in-place plan's first stage on the source and last stage on the destination "
            "(FFT_INPLACE_DIRECT): no pass through local memory for the load, the round "
            "trip's step and the store; on two-buffer lines the same was worth 1.31x with "
            "radices up to 8 and lost with 16"),
    Setting("launch_samples", 1 << 19, (1 << 18, 1 << 19, 1 << 20),
            "complex samples per compute unit one GPU launch carries (clholo.host.memory: a "
            "render's frames per launch, within the memory budget; an H100 at 2^19: ten "
            "1080p RGB frames): fewer, larger launches against the first frame's latency; "
            "only renders of more frames than a launch takes see it", ("render",)),
)}

_overrides: "contextvars.ContextVar[Optional[Dict[str, Any]]]" = contextvars.ContextVar(
    "clholo_tuning_overrides", default=None)
_ignore_stored: "contextvars.ContextVar[bool]" = contextvars.ContextVar(
    "clholo_tuning_untuned", default=False)
_lock = threading.RLock()  # store_entry reads the file while holding it
_file_cache: Dict[str, Tuple[Tuple[int, int], Dict[str, Any]]] = {}
_warned: set = set()


def _check_values(values: Dict[str, Any], where: str) -> Dict[str, Any]:
    out = {}
    for name, value in values.items():
        if name not in SETTINGS:
            raise InputError(f"{where}: no tunable setting {name!r}; the settings are "
                             f"{', '.join(SETTINGS)}")
        allowed = SETTINGS[name].values
        if isinstance(value, (bool, np.bool_)) and all(isinstance(v, bool) for v in allowed):
            value = bool(value)
        if value not in allowed or type(value) is not type(allowed[0]):
            raise InputError(f"{where}: {name} is {value!r}; give one of "
                             f"{', '.join(map(repr, allowed))}")
        out[name] = value
    return out


@contextlib.contextmanager
def override(**values: Any) -> Iterator[None]:
    """Plans built in this block take these settings, before any stored tuning.

    Parameters
    ----------
    **values
        ``name=value`` for names of :data:`SETTINGS`.

    Notes
    -----
    Plans keep the settings they were built with; settings reach a plan when it is built
    (:meth:`clholo.fft.DeviceLimits.of`), so build the plans inside the block. The block is
    the calling thread's (a :class:`contextvars.ContextVar`).
    """
    checked = _check_values(values, "clholo.tuning.override")
    token = _overrides.set({**(_overrides.get() or {}), **checked})
    try:
        yield
    finally:
        _overrides.reset(token)


@contextlib.contextmanager
def untuned() -> Iterator[None]:
    """Plans built in this block ignore the stored tuning (the project's defaults, or
    :func:`override`'s settings)."""
    token = _ignore_stored.set(True)
    try:
        yield
    finally:
        _ignore_stored.reset(token)


def tuning_file() -> Optional[Path]:
    """The tuning file: ``CLHOLO_TUNING_FILE`` (``off``, ``none`` or empty: no file), else
    ``$XDG_CACHE_HOME/clholo/tuning.json`` (``~/.cache/clholo/tuning.json``)."""
    env = os.environ.get(TUNING_FILE_ENV)
    if env is not None:
        env = env.strip()
        if env.lower() in ("", "off", "none"):
            return None
        try:
            return Path(env).expanduser()
        except RuntimeError:  # "~nouser/...": no such user, or no home to expand "~" to
            from clholo.errors import InputError

            raise InputError(f"{TUNING_FILE_ENV}={env!r}: its '~' names no home folder here; "
                             f"give the path in full, or unset {TUNING_FILE_ENV}") from None
    return default_tuning_file()


def device_key(device) -> str:
    """The name a device's tuning is stored under: platform, vendor, device and driver
    version (a new driver is another device: its compiler may prefer other forms)."""
    return " | ".join((device.platform.name.strip(), device.vendor.strip(), device.name.strip(),
                       f"driver {device.driver_version.strip()}"))


def _warn_once(key, message: str) -> None:
    with _lock:
        if key in _warned:
            return
        _warned.add(key)
    warnings.warn(message, TuningWarning, stacklevel=3)


def _parse(path: Path) -> Dict[str, Any]:
    """The ``"devices"`` of the tuning file at ``path``; ValueError (or OSError) where it is
    not one clholo wrote."""
    from clholo._files import read_small_file

    # a named pipe there waited for a writer forever, /dev/zero read until memory ran out
    data = json.loads(read_small_file(path))
    if not isinstance(data, dict) or data.get("format") != FILE_FORMAT:
        raise ValueError(f"its \"format\" is not {FILE_FORMAT!r}")
    if data.get("version") != FILE_VERSION:
        raise ValueError(f"its \"version\" is {data.get('version')!r}, this clholo reads "
                         f"{FILE_VERSION}")
    devices = data.get("devices")
    if not isinstance(devices, dict) or not all(isinstance(v, dict) for v in devices.values()):
        raise ValueError("its \"devices\" is not an object of objects")
    return devices


def default_tuning_file() -> Path:
    """Where the tuning file is without ``CLHOLO_TUNING_FILE``:
    ``$XDG_CACHE_HOME/clholo/tuning.json`` (``~/.cache/clholo/tuning.json``). Its folder is
    the only one clholo creates for a tuning file (a cache of its own)."""
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "clholo" / "tuning.json"


def _is_default(path: Path) -> bool:
    return path.expanduser().absolute() == default_tuning_file().expanduser().absolute()


def _ensure_folder(path: Path, option: str, *, create: bool = True) -> None:
    """The folder of the tuning file ``path``: the default cache folder is created (unless
    not ``create``: only checked); any other (a path the user gave) must exist, as every
    output option's parent must: a typo in it would otherwise become a tree of new folders
    holding the tuning where nothing reads it."""
    parent = path.parent
    if parent.is_dir():
        return
    if not _is_default(path):
        raise FileNotFoundError(f"cannot create {option} {path}: its parent folder {parent} "
                                f"does not exist; create it first")
    if create:
        parent.mkdir(parents=True, exist_ok=True)


def check_writable(path: Path, *, option: str = "the tuning file") -> None:
    """Refuse, before any measuring, a tuning file that cannot be written where it is: one
    that exists and is not one clholo wrote, or is a folder (storing would replace the user's
    file), or whose folder does not exist (only the default cache folder,
    :func:`default_tuning_file`, is created).

    Parameters
    ----------
    path : path
        The tuning file about to be written.
    option : str
        How the user named it, for the message (``"--file"``, ``"CLHOLO_TUNING_FILE"``).

    Raises
    ------
    clholo.errors.OutputRefused
        A folder, or a file clholo did not write.
    FileNotFoundError
        Its parent folder does not exist (and is not the default cache folder).
    """
    from clholo.errors import OutputRefused

    path = Path(path)
    if path.is_dir():
        raise OutputRefused(f"the tuning file {path} is a folder: give a file's path, such as "
                            f"{path / 'tuning.json'}")
    if not path.exists():
        _ensure_folder(path, option, create=False)  # created when the tuning is stored
        return
    try:
        _parse(path)
    except (OSError, ValueError, UnicodeDecodeError, RecursionError) as exc:
        raise OutputRefused(f"{path} exists and is not a tuning file clholo wrote ({exc}): "
                            f"clholo will not replace it; give another file, or delete it "
                            f"if it is a damaged tuning file") from None


def _read_file(path: Path, *, fresh: bool = False) -> Dict[str, Any]:
    """The file's ``"devices"`` (``{}`` where there is no file); a malformed file warns once
    and counts as empty. Read again only when the file changed (another inode, time or size:
    each write renames a new file over it), or ``fresh``."""
    try:
        st = path.stat()
    except FileNotFoundError:
        return {}
    except OSError as exc:
        _warn_once(("unreadable", str(path)), f"the tuning file {path} cannot be read ({exc}); "
                   f"clholo runs with its default settings (set {TUNING_FILE_ENV}=off to "
                   f"silence this)")
        return {}
    # the inode too: every write renames a new file over it (another process's, in the same
    # tick of a coarse file-system clock and of the same size, is seen as well)
    stamp = (st.st_ino, st.st_mtime_ns, st.st_size)
    with _lock:
        cached = _file_cache.get(str(path))
    if cached is not None and cached[0] == stamp and not fresh:
        return cached[1]
    try:
        devices = _parse(path)
    except (OSError, ValueError, UnicodeDecodeError, RecursionError) as exc:
        _warn_once(("malformed", str(path), stamp),
                   f"the tuning file {path} is not one clholo wrote ({exc}); clholo runs with "
                   f"its default settings. Delete it, or point {TUNING_FILE_ENV} elsewhere")
        devices = {}
    with _lock:
        _file_cache[str(path)] = (stamp, devices)
    return devices


def stored_entry(device, *, path: Optional[Path] = None) -> Optional[Dict[str, Any]]:
    """The tuning file's entry for ``device`` as stored (any clholo version), or None.

    Parameters
    ----------
    device : pyopencl.Device
    path : path, optional
        Default: :func:`tuning_file`.
    """
    path = tuning_file() if path is None else Path(path)
    if path is None:
        return None
    return _read_file(path).get(device_key(device))


def _stored_settings(device) -> Dict[str, Any]:
    if _ignore_stored.get():
        return {}
    path = tuning_file()
    if path is None:
        return {}
    try:
        key = device_key(device)
    except AttributeError:  # not an OpenCL device (the tests' stand-ins): nothing stored
        return {}
    entry = _read_file(path).get(key)
    if entry is None:
        return {}
    if entry.get("clholo") != __version__:
        _warn_once(("version", str(path), key),
                   f"the tuning of {device.name.strip()} in {path} was measured with clholo "
                   f"{entry.get('clholo')}, this is {__version__}: not used. Run `clholo tune` "
                   f"again")
        return {}
    try:
        settings = entry.get("settings")
        if not isinstance(settings, dict):
            raise InputError("its \"settings\" is not an object")
        return _check_values(settings, "settings")
    except InputError as exc:
        _warn_once(("entry", str(path), key),
                   f"the tuning of {device.name.strip()} in {path} is not used: {exc}. Run "
                   f"`clholo tune` again, or `clholo tune --forget`")
        return {}


def value(name: str) -> Any:
    """A setting's value for plans of no particular device (limits made by hand, as the
    planning tests and ``benchmarks/gpu_registers.py`` make an H100's): :func:`override`'s,
    else the project's default.

    Parameters
    ----------
    name : str
        A name of :data:`SETTINGS`.
    """
    return (_overrides.get() or {}).get(name, SETTINGS[name].default)


def settings_for(device) -> Tuple[Tuple[str, Any], ...]:
    """Every tunable setting's value for plans built now on ``device``: :func:`override`'s,
    else the device's stored tuning, else the project's default; ``(name, value)`` pairs in
    :data:`SETTINGS`' order (what :class:`clholo.fft.DeviceLimits` carries)."""
    values = {name: s.default for name, s in SETTINGS.items()}
    values.update(_stored_settings(device))
    values.update(_overrides.get() or {})
    return tuple((name, values[name]) for name in SETTINGS)


def _write_devices(path: Path, devices: Dict[str, Any]) -> None:
    """The tuning file with these ``devices``, written under a temporary name in its folder and
    renamed over ``path`` when whole (:func:`clholo.io.images.atomic_path`)."""
    from clholo.io.images import atomic_path

    _ensure_folder(path, "the tuning file")
    text = json.dumps({"format": FILE_FORMAT, "version": FILE_VERSION, "devices": devices},
                      indent=2, sort_keys=True) + "\n"
    with atomic_path(path) as tmp:
        tmp.write_text(text, encoding="utf-8")


@contextlib.contextmanager
def _file_lock(path: Path) -> Iterator[None]:
    """Hold ``path``'s lock file (``NAME.lock`` beside it) while the file is read, changed and
    written, so that two processes tuning two devices at once both keep their entries."""
    try:
        import fcntl
    except ImportError:  # pragma: no cover - not POSIX: the rename alone
        yield
        return
    _ensure_folder(path, "the tuning file")
    with open(path.parent / f"{path.name}.lock", "a") as f:
        fcntl.flock(f.fileno(), fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(f.fileno(), fcntl.LOCK_UN)


def store_entry(key: str, entry: Optional[Dict[str, Any]], *, path: Path) -> bool:
    """Set (``entry``) or remove (``None``) the entry ``key`` of the tuning file at ``path``,
    keeping the others (read anew under a lock, so another process's entry written meanwhile
    is kept too); False where there was nothing to remove."""
    with _lock, _file_lock(path):
        check_writable(path)  # never over a file the user owns
        devices = dict(_read_file(path, fresh=True))
        if entry is None:
            if key not in devices:
                return False
            del devices[key]
        else:
            devices[key] = entry
        _write_devices(path, devices)
    return True
