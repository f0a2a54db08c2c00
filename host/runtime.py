"""OpenCL runtime: device choice, program loading and profiling helpers.

Everything that touches an OpenCL platform goes through this module so that device choice,
build options and error messages are the same for every kernel in clholo.

Device choice, in order:

1. ``CLHOLO_DEVICE`` (environment), else
2. ``PYOPENCL_CTX`` (pyopencl's own variable), else
3. the first GPU of any platform, else
4. the first CPU device (for example PoCL), else
5. any device at all.

Both variables take ``"P:D"`` (platform and device index, as ``clholo info`` prints them),
``"P"`` (first device of platform ``P``) or a case-insensitive substring of
``"<platform name> <device name>"`` such as ``"pocl"`` or ``"nvidia"``.
"""

from __future__ import annotations

import os
import threading
import time
import weakref
from dataclasses import dataclass
from importlib import resources
from typing import Dict, Iterable, List, Mapping, Optional, Sequence, Tuple


try:  # pyopencl is a hard dependency, but keep the import error readable
    import pyopencl as cl
except ImportError as exc:  # pragma: no cover - exercised only on broken installs
    raise ImportError(
        "clholo needs pyopencl: `pip install pyopencl` (and an OpenCL driver; "
        "`pip install pocl-binary-distribution` gives a CPU one)"
    ) from exc

__all__ = [
    "NoDeviceError",
    "ProgramBuildError",
    "DeviceInfo",
    "list_devices",
    "choose_device",
    "get_context",
    "get_queue",
    "create_queue",
    "kernel_dir",
    "build_program",
    "get_kernel",
    "require_fp64",
    "has_fp64",
    "event_seconds",
    "EventTimer",
]

INSTALL_HINT = (
    "Install an OpenCL driver: `pip install pocl-binary-distribution` (PoCL, CPU, any OS; "
    "or `pip install clholo[pocl]`), or Debian's `apt-get install pocl-opencl-icd`, or your "
    "GPU vendor's OpenCL driver."
)


class NoDeviceError(RuntimeError):
    """No OpenCL platform/device exists, or the requested one matches none."""


class ProgramBuildError(RuntimeError):
    """An OpenCL program failed to compile; carries the file name and the build log."""

    def __init__(self, filename: str, device_names: Sequence[str], log: str, options: Sequence[str]):
        self.filename = filename
        self.log = log
        self.options = list(options)
        super().__init__(
            f"OpenCL build of kernels/{filename} failed on {', '.join(device_names)}\n"
            f"options: {' '.join(self.options)}\n--- build log ---\n{log.strip()}"
        )


@dataclass(frozen=True)
class DeviceInfo:
    """What ``clholo info`` prints about one device."""

    platform_index: int
    device_index: int
    platform_name: str
    device_name: str
    device_type: str
    compute_units: int
    global_mem_bytes: int
    local_mem_bytes: int
    max_work_group_size: int
    fp64: bool
    opencl_version: str

    @property
    def selector(self) -> str:
        return f"{self.platform_index}:{self.device_index}"


def _platforms() -> List["cl.Platform"]:
    try:
        return list(cl.get_platforms())
    except cl.LogicError:  # pyopencl raises this for CL_PLATFORM_NOT_FOUND_KHR
        return []
    except cl.Error:
        return []


def _all_devices() -> List[Tuple[int, int, "cl.Device"]]:
    out = []
    for pi, platform in enumerate(_platforms()):
        try:
            devices = platform.get_devices()
        except cl.Error:
            devices = []
        for di, dev in enumerate(devices):
            out.append((pi, di, dev))
    return out


def _type_name(dev: "cl.Device") -> str:
    t = dev.type
    names = []
    for flag, name in ((cl.device_type.GPU, "GPU"), (cl.device_type.CPU, "CPU"),
                       (cl.device_type.ACCELERATOR, "ACCELERATOR")):
        if t & flag:
            names.append(name)
    return "+".join(names) or "OTHER"


def has_fp64(dev: "cl.Device") -> bool:
    """True when the device supports double precision (``cl_khr_fp64`` or OpenCL >= 1.2 config)."""
    try:
        if dev.double_fp_config:
            return True
    except cl.Error:
        pass
    return "cl_khr_fp64" in dev.extensions


def _info(pi: int, di: int, dev: "cl.Device") -> DeviceInfo:
    return DeviceInfo(
        platform_index=pi,
        device_index=di,
        platform_name=dev.platform.name.strip(),
        device_name=dev.name.strip(),
        device_type=_type_name(dev),
        compute_units=int(dev.max_compute_units),
        global_mem_bytes=int(dev.global_mem_size),
        local_mem_bytes=int(dev.local_mem_size),
        max_work_group_size=int(dev.max_work_group_size),
        fp64=has_fp64(dev),
        opencl_version=dev.version.strip(),
    )


def list_devices() -> List[DeviceInfo]:
    """Every OpenCL device of every platform, in ``P:D`` order."""
    return [_info(pi, di, dev) for pi, di, dev in _all_devices()]


def _device_listing(devices: Iterable[Tuple[int, int, "cl.Device"]]) -> str:
    lines = [f"  {pi}:{di}  [{_type_name(d)}] {d.platform.name.strip()} / {d.name.strip()}"
             for pi, di, d in devices]
    return "\n".join(lines) if lines else "  (none)"


def _match(selector: str, devices, variable: str):
    sel = selector.strip()
    parts = sel.split(":")
    if all(p.strip().isdigit() for p in parts if p != "") and 1 <= len(parts) <= 2 and parts[0] != "":
        pi = int(parts[0])
        di = int(parts[1]) if len(parts) == 2 and parts[1] != "" else 0
        for p, d, dev in devices:
            if p == pi and d == di:
                return dev
    else:
        needle = sel.lower()
        for _, _, dev in devices:
            hay = f"{dev.platform.name} {dev.name}".lower()
            if needle in hay:
                return dev
    raise NoDeviceError(
        f"{variable}={selector!r} matches no OpenCL device. Available devices:\n"
        f"{_device_listing(devices)}\n"
        f"Set {variable} to 'P:D' (platform:device index from the list above) or to a "
        f"substring of the platform/device name, or unset it to let clholo choose."
    )


def choose_device(selector: Optional[str] = None) -> "cl.Device":
    """Return the OpenCL device clholo uses.

    Parameters
    ----------
    selector : str, optional
        ``"P:D"``, ``"P"`` or a name substring. Default: ``CLHOLO_DEVICE``, else
        ``PYOPENCL_CTX``, else the first GPU, else the first CPU device.

    Raises
    ------
    NoDeviceError
        When no OpenCL platform exists (with install instructions) or the selector matches
        no device (with the list of devices).
    """
    devices = _all_devices()
    if not devices:
        raise NoDeviceError("No OpenCL platform/device found. " + INSTALL_HINT)
    if selector is not None:
        return _match(selector, devices, "device")
    for var in ("CLHOLO_DEVICE", "PYOPENCL_CTX"):
        value = os.environ.get(var)
        if value:
            return _match(value, devices, var)
    for kind in (cl.device_type.GPU, cl.device_type.CPU):
        for _, _, dev in devices:
            if dev.type & kind:
                return dev
    return devices[0][2]


_lock = threading.RLock()
_default: Dict[str, object] = {}


def get_context() -> "cl.Context":
    """The process-wide default context on :func:`choose_device` (created on first use)."""
    return get_queue().context


def get_queue() -> "cl.CommandQueue":
    """The process-wide default in-order command queue (profiling enabled)."""
    with _lock:
        queue = _default.get("queue")
        if queue is None:
            dev = choose_device()
            ctx = cl.Context([dev])
            queue = create_queue(ctx, dev)
            _default["queue"] = queue
        return queue  # type: ignore[return-value]


def reset_default_queue() -> None:
    """Forget the default queue so the next :func:`get_queue` re-reads the environment."""
    with _lock:
        _default.clear()


def create_queue(context: "cl.Context", device: Optional["cl.Device"] = None, *,
                 profiling: bool = True) -> "cl.CommandQueue":
    """An in-order queue; profiling is on by default because it costs nothing measurable."""
    props = cl.command_queue_properties.PROFILING_ENABLE if profiling else 0
    return cl.CommandQueue(context, device, properties=props)


def kernel_dir() -> str:
    """File-system path of the installed ``clholo.kernels`` package (the ``.cl``/``.h`` files)."""
    root = resources.files("clholo.kernels")
    path = os.fspath(root)  # a real directory for regular and editable installs
    if not os.path.isdir(path):  # pragma: no cover - zipped installs are not supported
        raise RuntimeError(f"clholo.kernels is not a directory ({path}); install clholo unzipped")
    return path


def _pyopencl_include_dir() -> str:
    import pyopencl as _pcl
    return os.path.join(os.path.dirname(_pcl.__file__), "cl")


def read_kernel_source(filename: str) -> str:
    """Source text of ``kernels/<filename>`` via importlib.resources."""
    res = resources.files("clholo.kernels").joinpath(filename)
    if not res.is_file():
        raise FileNotFoundError(f"no kernel source kernels/{filename} in {kernel_dir()}")
    return res.read_text(encoding="utf-8")


def _define_options(defines: Optional[Mapping[str, object]]) -> List[str]:
    opts = []
    for key, value in sorted((defines or {}).items()):
        if value is None or value is True:
            opts.append(f"-D{key}")
        elif value is False:
            continue
        else:
            opts.append(f"-D{key}={value}")
    return opts


# Programs are memoized per context: key (filename, options) -> Program. A WeakKeyDictionary on
# the context lets the cache die with it.
_program_cache: "weakref.WeakKeyDictionary[cl.Context, Dict[Tuple, cl.Program]]" = weakref.WeakKeyDictionary()


def build_program(context: "cl.Context", filename: str, *,
                  defines: Optional[Mapping[str, object]] = None,
                  source: Optional[str] = None,
                  extra_options: Sequence[str] = ()) -> "cl.Program":
    """Build ``kernels/<filename>`` for ``context``, once per (context, file, options).

    Parameters
    ----------
    context : pyopencl.Context
    filename : str
        Name of a ``.cl`` file in ``kernels/``. Headers it includes are found with ``-I`` on the
        kernels folder and on pyopencl's own ``cl`` folder (for Random123).
    defines : mapping, optional
        Preprocessor macros, ``{"N": 8}`` -> ``-DN=8``; ``True``/``None`` values define the bare
        name, ``False`` omits it.
    source : str, optional
        Source text to build instead of the file's (tests use it for broken kernels); the
        filename still names it in errors.

    Raises
    ------
    ProgramBuildError
        With the file name, the options and the compiler's build log.
    """
    options = tuple(["-I", kernel_dir(), "-I", _pyopencl_include_dir(),
                     "-cl-mad-enable"] + _define_options(defines) + list(extra_options))
    key = (filename, options, source)
    with _lock:
        per_ctx = _program_cache.setdefault(context, {})
        program = per_ctx.get(key)
        if program is not None:
            return program
    text = source if source is not None else read_kernel_source(filename)
    try:
        program = cl.Program(context, text).build(options=list(options))
    except cl.RuntimeError as exc:
        log = _build_log(exc, context)
        raise ProgramBuildError(filename, [d.name.strip() for d in context.devices], log,
                                options) from None
    with _lock:
        _program_cache.setdefault(context, {})[key] = program
    return program


_kernel_cache: "weakref.WeakKeyDictionary[cl.Context, Dict[Tuple, cl.Kernel]]" = weakref.WeakKeyDictionary()


def get_kernel(context: "cl.Context", filename: str, name: str, *,
               defines: Optional[Mapping[str, object]] = None) -> "cl.Kernel":
    """Kernel ``name`` of ``kernels/<filename>`` (see :func:`build_program`), memoized.

    Retrieving a kernel from a program creates a new object each time (at a cost on some
    drivers), so clholo keeps one per (context, file, defines, name). Kernel objects carry
    their arguments: call them from one thread at a time.
    """
    key = (filename, tuple(sorted((defines or {}).items())), name)
    with _lock:
        per_ctx = _kernel_cache.setdefault(context, {})
        kern = per_ctx.get(key)
    if kern is None:
        kern = cl.Kernel(build_program(context, filename, defines=defines), name)
        with _lock:
            _kernel_cache.setdefault(context, {})[key] = kern
    return kern


def _build_log(exc: Exception, context: "cl.Context") -> str:
    # pyopencl puts the per-device logs into the exception text; keep it whole.
    text = str(exc)
    return text if text else "(the OpenCL compiler gave no log)"


def require_fp64(device: "cl.Device", what: str) -> None:
    """Raise a clear error when ``device`` lacks double precision and ``what`` needs it."""
    if not has_fp64(device):
        raise TypeError(
            f"{what} needs double precision (complex128/float64), but the OpenCL device "
            f"{device.name.strip()!r} has no fp64 support. Use complex64/float32 input, or pick "
            f"a device with fp64 via CLHOLO_DEVICE (see `clholo info`)."
        )


def event_seconds(event: "cl.Event") -> float:
    """Device time of a finished profiled event, in seconds."""
    event.wait()
    return (event.profile.end - event.profile.start) * 1e-9


class EventTimer:
    """Collect (label, event) pairs and report device seconds per label.

    Examples
    --------
    >>> t = EventTimer()
    >>> t.add("fft", program.kernel(queue, ...))  # doctest: +SKIP
    >>> t.summary()  # doctest: +SKIP
    {'fft': 0.0012}
    """

    def __init__(self) -> None:
        self._events: List[Tuple[str, "cl.Event"]] = []

    def add(self, label: str, event: "cl.Event") -> "cl.Event":
        self._events.append((label, event))
        return event

    def summary(self) -> Dict[str, float]:
        out: Dict[str, float] = {}
        for label, event in self._events:
            out[label] = out.get(label, 0.0) + event_seconds(event)
        return out


class WallTimer:
    """``with WallTimer() as t: ...; t.seconds`` -- host wall-clock time of a block."""

    def __enter__(self) -> "WallTimer":
        self._t0 = time.perf_counter()
        self.seconds = 0.0
        return self

    def __exit__(self, *exc) -> None:
        self.seconds = time.perf_counter() - self._t0
