"""OpenCL runtime: device choice, program loading and profiling helpers.

Everything that touches an OpenCL platform goes through this module so that device choice,
build options and error messages are the same for every kernel in clholo.

Device choice, in order:

1. ``CLHOLO_DEVICE`` (environment), else
2. ``PYOPENCL_CTX`` (pyopencl's own variable), else
3. the first GPU of any platform, else
4. the first CPU device (for example PoCL), else
5. any device at all.

Steps 3 to 5 (and a name or type that matches several devices) skip a device whose compiler
cannot build a one-line kernel, saying so when no device is left: PyPI's PoCL
(``pocl-binary-distribution`` 3.0) carries LLVM 14, which does not know CPUs made after it
(AMD Zen 5, family 26h: its ``getHostCPUName()`` answers ``"generic"``, which PoCL hands on as
``-target-cpu`` and clang refuses, "unknown target CPU 'generic'"). Beside a distribution's PoCL
(Debian's ``pocl-opencl-icd``, LLVM 15, which falls back to a CPU it knows) clholo then picks
the one that works.

Both variables take ``"P:D"`` (platform and device index, as ``clholo info`` prints them),
``"P"`` (first device of platform ``P``), a case-insensitive substring of
``"<platform name> <platform vendor> <device name>"`` such as ``"pocl"`` or ``"nvidia"``, or
the device type that ``clholo info`` shows in brackets (``"cpu"``, ``"gpu"``: the first such
device).
"""

from __future__ import annotations

import os
import re
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
    "UNKNOWN_CPU_HINT",
    "EMPTY_PROGRAM_HINT",
    "device_build_problem",
    "ProgramBuildError",
    "DeviceInfo",
    "list_devices",
    "choose_device",
    "get_context",
    "get_queue",
    "release_context",
    "create_queue",
    "kernel_dir",
    "build_program",
    "get_kernel",
    "require_fp64",
    "has_fp64",
    "event_seconds",
    "EventTimer",
    "LaunchRecord",
    "KernelRecorder",
    "note_launch",
    "LaunchLimitError",
    "check_launch",
    "launch",
    "enqueue_nd_range",
    "set_launch_args",
    "launched_kernels",
    "kernel_local_bytes",
    "kernel_work_group_size",
    "source_line_table",
    "map_build_log",
    "BuildCounter",
    "ProgramBuild",
    "compiler_cache_dir",
]

INSTALL_HINT = (
    "Install an OpenCL driver: `pip install pocl-binary-distribution` (PoCL, CPU, any OS; "
    "or `pip install clholo[pocl]`), or Debian's `apt-get install pocl-opencl-icd`, or your "
    "GPU vendor's OpenCL driver."
)


class NoDeviceError(RuntimeError):
    """No OpenCL platform/device exists, or the requested one matches none."""


# What a compiler that does not know the CPU it runs on prints (PoCL with an LLVM older than
# the CPU), and the fix, added to every error that shows such a log.
UNKNOWN_CPU = "unknown target CPU"
UNKNOWN_CPU_HINT = (
    "This OpenCL driver's compiler does not know this CPU (\"unknown target CPU\": PyPI's PoCL, "
    "pocl-binary-distribution 3.0, has LLVM 14, older than CPUs such as AMD Zen 5). Install a "
    "PoCL whose LLVM knows it, e.g. Debian/Ubuntu `apt-get install pocl-opencl-icd`: clholo "
    "then picks the device that compiles (`clholo info` lists both), or name it with "
    "CLHOLO_DEVICE."
)


class ProgramBuildError(RuntimeError):
    """An OpenCL program failed to compile; carries the file name and the build log.

    Parameters
    ----------
    filename : str
        The ``kernels/`` file that was built.
    device_names : sequence of str
        The devices it failed on.
    log : str
        The build log, locations mapped back to the pasted headers' files and lines.
    options : sequence of str
        The build options.
    raw_log : str, optional
        The log as the compiler printed it (default: ``log``).
    """

    def __init__(self, filename: str, device_names: Sequence[str], log: str, options: Sequence[str],
                 raw_log: Optional[str] = None):
        self.filename = filename
        self.log = log  # locations mapped back to the pasted headers' files and lines
        self.raw_log = log if raw_log is None else raw_log  # as the compiler printed it
        self.options = list(options)
        hint = f"\n{UNKNOWN_CPU_HINT}" if UNKNOWN_CPU in log else ""
        super().__init__(
            f"OpenCL build of kernels/{filename} failed on {', '.join(device_names)}\n"
            f"options: {' '.join(self.options)}\n--- build log ---\n{log.strip()}{hint}"
        )


@dataclass(frozen=True)
class DeviceInfo:
    """What ``clholo info`` prints about one device.

    Parameters
    ----------
    platform_index, device_index : int
        Its place in pyopencl's platform and device lists.
    platform_name, device_name : str
        As the driver names them.
    device_type : str
        ``"GPU"``, ``"CPU"``, ``"ACCELERATOR"`` (``+``-joined where several), or ``"OTHER"``.
    compute_units : int
        ``CL_DEVICE_MAX_COMPUTE_UNITS``.
    global_mem_bytes, local_mem_bytes : int
        Global and local (per work-group) memory, bytes.
    max_work_group_size : int
        ``CL_DEVICE_MAX_WORK_GROUP_SIZE``.
    fp64 : bool
        Whether it has double precision (:func:`has_fp64`).
    opencl_version : str
        The device's OpenCL version string.
    """

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
        """``"P:D"``, what ``CLHOLO_DEVICE`` and ``PYOPENCL_CTX`` take to pick this device."""
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


def no_device_error() -> "NoDeviceError":
    """The error for a machine whose OpenCL lists no device: with no platform, how to install
    a driver (and the fix for a GPU driver installed but not registered); with platforms that
    list no device, why that happens (an install hint would mislead: PoCL lists none when it
    cannot create its kernel cache, e.g. ``XDG_CACHE_HOME`` naming a file)."""
    platforms = sorted({p.name.strip() for p in _platforms()})
    if platforms:
        return NoDeviceError(
            f"the OpenCL platform(s) {', '.join(platforms)} list no device. PoCL lists none "
            f"when it cannot create its kernel cache: check that POCL_CACHE_DIR, or else "
            f"XDG_CACHE_HOME (default ~/.cache), names a folder you can write to; for a GPU "
            f"driver, that the GPU is visible (nvidia-smi, rocm-smi)")
    return NoDeviceError("No OpenCL platform/device found. " + INSTALL_HINT
                         + _driver_advice("No OpenCL platform"))


def _type_name(dev: "cl.Device") -> str:
    t = dev.type
    names = []
    for flag, name in ((cl.device_type.GPU, "GPU"), (cl.device_type.CPU, "CPU"),
                       (cl.device_type.ACCELERATOR, "ACCELERATOR")):
        if t & flag:
            names.append(name)
    return "+".join(names) or "OTHER"


def has_fp64(dev: "cl.Device") -> bool:
    """True when ``dev`` (a ``pyopencl.Device``) supports double precision (``cl_khr_fp64``,
    or a non-zero ``CL_DEVICE_DOUBLE_FP_CONFIG`` on OpenCL >= 1.2)."""
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


_PROBE_SOURCE = "__kernel void clholo_probe(__global float *a) { a[get_global_id(0)] += 1.0f; }"
_build_problems: Dict[int, Optional[str]] = {}  # cl_device_id -> None (compiles) or the reason
_probe_contexts: Dict[int, "cl.Context"] = {}  # the context a probe made, for get_queue to reuse


def device_build_problem(dev: "cl.Device") -> Optional[str]:
    """``None`` when ``dev`` (a ``pyopencl.Device``) builds a one-line kernel, else why not
    (the compiler's log, or the error). Probed once per device and process."""
    key = dev.int_ptr
    with _lock:
        if key in _build_problems:
            return _build_problems[key]
    try:
        ctx = cl.Context([dev])
        cl.Program(ctx, _PROBE_SOURCE).build()
        problem = None
    except cl.Error as exc:
        ctx = None
        lines = [ln.strip() for ln in str(exc).splitlines() if ln.strip()]
        reason = next((ln for ln in lines if UNKNOWN_CPU in ln), None)
        problem = reason or (lines[-1] if lines else type(exc).__name__)
    with _lock:
        _build_problems[key] = problem
        if ctx is not None:
            _probe_contexts.setdefault(key, ctx)
    return problem


def _pocl_llvm_major(device: "cl.Device") -> Optional[int]:
    """The LLVM major version a PoCL device's platform reports (``"... LLVM 15.0.6 ..."``),
    or None (not PoCL, or not said)."""
    import re

    platform = device.platform
    if "portable computing language" not in str(getattr(platform, "name", "")).lower():
        return None
    found = re.search(r"LLVM (\d+)", str(getattr(platform, "version", "")))
    return int(found.group(1)) if found else None


def _first_that_compiles(candidates: Sequence[Tuple[int, int, "cl.Device"]],
                         what: str) -> "cl.Device":
    """The first of ``candidates`` whose compiler works; a :class:`NoDeviceError` naming each
    one's problem when none does. A lone candidate is taken without a probe (its own build
    error, with :data:`UNKNOWN_CPU_HINT` where it applies, says the rest)."""
    if len(candidates) == 1:
        return candidates[0][2]
    problems = []
    for pi, di, dev in candidates:
        problem = device_build_problem(dev)
        if problem is None:
            return dev
        problems.append(f"  {pi}:{di}  {dev.platform.name.strip()} / {dev.name.strip()}: "
                        f"{problem}")
    hint = f"\n{UNKNOWN_CPU_HINT}" if any(UNKNOWN_CPU in p for p in problems) else ""
    raise NoDeviceError(f"{what}, but none of them compiles OpenCL kernels:\n"
                        + "\n".join(problems) + hint)


def _haystack(dev: "cl.Device") -> str:
    # the vendor too: PoCL's platform is "Portable Computing Language", its vendor "The pocl
    # project", so that "pocl" finds it
    return f"{dev.platform.name} {getattr(dev.platform, 'vendor', '')} {dev.name}".lower()


def _match(selector: str, devices, variable: str):
    sel = selector.strip()
    parts = sel.split(":")
    # isdecimal, not isdigit: "²" is a digit that int() refuses
    if all(p.strip().isdecimal() and p.strip().isascii() for p in parts if p != "") \
            and 1 <= len(parts) <= 2 and parts[0] != "":
        pi = int(parts[0])
        di = int(parts[1]) if len(parts) == 2 and parts[1] != "" else 0
        for p, d, dev in devices:
            if p == pi and d == di:
                return dev
    else:
        # a name or type may match several devices (two PoCLs, say): the first that compiles
        needle = sel.lower()
        by_name = [t for t in devices if needle in _haystack(t[2])]
        # else the type clholo info shows in brackets: cpu, gpu
        found = by_name or [t for t in devices if needle == _type_name(t[2]).lower()]
        if found:
            return _first_that_compiles(found, f"{variable}={selector!r} matches {len(found)} "
                                               f"devices")
    raise NoDeviceError(
        f"{variable}={selector!r} matches no OpenCL device. Available devices:\n"
        f"{_device_listing(devices)}\n"
        f"Set {variable} to 'P:D' (platform:device index from the list above) or to a "
        f"substring of the platform/device name, or to its type in brackets (cpu, gpu), or "
        f"unset it to let clholo choose."
        + _driver_advice(f"{variable}={selector!r} matches no OpenCL device",
                         any(d.type & cl.device_type.GPU for _, _, d in devices))
    )


def _driver_advice(situation: str, have_gpu: bool = False) -> str:
    """``"\n" + the fix`` for GPU drivers installed but not registered (:mod:`.drivers`);
    '' when a GPU is visible or no such driver is found."""
    if have_gpu:
        return ""
    from clholo.host.drivers import driver_advice

    try:
        advice = driver_advice(situation=situation)
    except OSError:  # pragma: no cover - an unreadable folder must not hide the real error
        return ""
    return "\n" + advice if advice else ""


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
        no device (with the list of devices); either way, with the exact fix when a GPU
        vendor's OpenCL library is installed but not registered (:mod:`clholo.host.drivers`).
    """
    devices = _all_devices()
    if not devices:
        raise no_device_error()
    if selector is not None:
        return _match(selector, devices, "device")
    for var in ("CLHOLO_DEVICE", "PYOPENCL_CTX"):
        value = os.environ.get(var)
        if value and value.strip():  # blanks are unset (an empty needle matches every name)
            return _match(value, devices, var)
    # GPUs first, then CPUs, then the rest, each in P:D order; of two PoCLs the one with the
    # newer LLVM first: PyPI's PoCL 3.0 (LLVM 14) compiles a one-line probe on an AMD Zen 4
    # but its compiler crashes on clholo's kernels there, while Debian's (LLVM 15) runs them,
    # and which of the two the ICD loader lists first is not fixed
    rank = [(0 if d.type & cl.device_type.GPU else 1 if d.type & cl.device_type.CPU else 2,
             -(_pocl_llvm_major(d) or 0)) for _, _, d in devices]
    ordered = [t for _, t in sorted(zip(rank, devices), key=lambda rt: rt[0])]
    return _first_that_compiles(ordered, f"{len(devices)} OpenCL devices are installed")


_lock = threading.RLock()
_default: Dict[str, object] = {}
# Held while a kernel's arguments are set and it is enqueued (launch, the FFT plans' execute):
# get_kernel's kernel objects are shared by every caller of a context, and an object carries
# its arguments, so two threads that set and enqueue one at once would launch each other's
# arguments (two renderers on the default queue, fft2 of one shape). Enqueueing does not wait
# for the device: the lock is held for microseconds. pyopencl's own array kernels (``a += b``,
# ``fill``) are memoized per context too, so clholo runs them under this lock as well
# (:func:`pyopencl_op`).
_launch_lock = threading.RLock()


def pyopencl_op():
    """The launch lock, to hold around one of pyopencl's own array operations that runs a
    kernel (``field += scratch``, ``array.fill(0)``): pyopencl keeps one kernel object per
    context and operation and sets its arguments, then enqueues it, so two threads of one
    context could launch each other's arguments. ``with runtime.pyopencl_op(): a += b``."""
    return _launch_lock


def zeros(queue: "cl.CommandQueue", shape, dtype, *, allocator=None) -> "cla.Array":
    """``pyopencl.array.zeros`` under the launch lock: pyopencl zeroes with a fill command,
    except on NVIDIA for buffers of 2 GiB or more, where it runs its shared fill kernel
    (:func:`pyopencl_op`)."""
    import pyopencl.array as cla

    with _launch_lock:
        return cla.zeros(queue, shape, dtype, allocator=allocator)


def get_context() -> "cl.Context":
    """The process-wide default context on :func:`choose_device` (created on first use)."""
    return get_queue().context


def get_queue() -> "cl.CommandQueue":
    """The process-wide default in-order command queue (profiling enabled)."""
    with _lock:
        queue = _default.get("queue")
        if queue is None:
            dev = choose_device()
            ctx = _probe_contexts.get(dev.int_ptr) or cl.Context([dev])
            queue = create_queue(ctx, dev)
            _default["queue"] = queue
        return queue  # type: ignore[return-value]


def reset_default_queue() -> None:
    """Forget the default queue so the next :func:`get_queue` re-reads the environment."""
    with _lock:
        _default.clear()


def create_queue(context: "cl.Context", device: Optional["cl.Device"] = None, *,
                 profiling: bool = True) -> "cl.CommandQueue":
    """An in-order queue on ``device`` (default: the context's first) of ``context``; profiling
    is on by default because it costs nothing measurable (:class:`KernelRecorder` and
    :class:`EventTimer` read its events' times)."""
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


_INCLUDE_RE = re.compile(r'^[ \t]*#[ \t]*include[ \t]*([<"])([^>"]+)[>"]')
_LINE_RE = re.compile(r'^[ \t]*#[ \t]*line[ \t]+(\d+)(?:[ \t]+"([^"]*)")?')


def _include_path(name: str, quoted: bool, including_dir: Optional[str]) -> Optional[str]:
    """Where the compiler would find ``#include "name"`` / ``<name>`` with ``-I`` on the kernels
    folder and pyopencl's ``cl`` folder: the including file's folder first for quoted names."""
    dirs = ([including_dir] if quoted and including_dir else []) + [kernel_dir(),
                                                                     _pyopencl_include_dir()]
    for d in dirs:
        path = os.path.join(d, name)
        if os.path.isfile(path):
            return path
    return None


def inline_includes(text: str, name: str) -> str:
    """``text`` with every ``#include`` that the kernels folder or pyopencl's ``cl`` folder holds
    replaced by the header's own text (recursively, between ``#line`` markers so that compiler
    messages still name the header and its line).

    Why: the build options then carry no file-system path, so a driver's binary cache
    (PoCL's kcache, pyopencl's cache) is keyed on the sources' content alone, and a fresh
    checkout or virtual environment elsewhere reuses the kernels compiled for another (a
    ``-I /path/to/checkout`` in the options made every clone compile everything again).
    Includes found in neither folder (system headers in branches OpenCL never takes) stay as
    they are. Include guards work as before: a header is pasted wherever it is included.
    """
    return _inline(text, name, None, 0)


def _inline(text: str, name: str, folder: Optional[str], depth: int) -> str:
    if depth > 32:
        raise RecursionError(f"#include nesting deeper than 32 levels at {name}")
    out: List[str] = []
    current, line_no = name, 1
    for line in text.splitlines():
        m = _INCLUDE_RE.match(line)
        path = m and _include_path(m.group(2), m.group(1) == '"', folder)
        if path:
            with open(path, encoding="utf-8") as f:
                body = _inline(f.read(), os.path.basename(path), os.path.dirname(path),
                               depth + 1)
            out += [f'#line 1 "{os.path.basename(path)}"', body,
                    f'#line {line_no + 1} "{current}"']
        else:
            out.append(line)
            lm = _LINE_RE.match(line)
            if lm:  # a #line marker in the text itself (FFT callbacks) sets what follows
                current = lm.group(2) if lm.group(2) is not None else current
                line_no = int(lm.group(1))
                continue
        line_no += 1
    return "\n".join(out) + "\n"


def source_line_table(text: str, name: str) -> List[Tuple[str, int]]:
    """Where each line of ``text`` (the source handed to the compiler) came from: entry ``i``
    is the ``(file, line)`` of physical line ``i + 1``, following the ``#line`` markers that
    :func:`inline_includes` (and the FFT callbacks) put in, as a preprocessor would. ``name``
    is the file the text starts in.

    clholo pastes the headers in itself, so it knows this table whatever the compiler does with
    ``#line``: PoCL's log names the header, NVIDIA's names ``<kernel>`` and the physical line
    (issue 22); :func:`map_build_log` turns the latter into the former.
    """
    table: List[Tuple[str, int]] = []
    current, line_no = name, 1
    for line in text.splitlines():
        table.append((current, line_no))
        lm = _LINE_RE.match(line)
        if lm:
            current = lm.group(2) if lm.group(2) is not None else current
            line_no = int(lm.group(1))
        else:
            line_no += 1
    return table


# a location in a compiler's log: "<kernel>:12:5:", ":12:5:", "/tmp/x.cl:12:", "1:12:5:"
# (Intel), "hdr.h:2:28:" (PoCL, which follows #line); at a line's start or after a space or
# "(" ("In file included from <kernel>:3:"); the known file names (some hold a space, as
# "load callback") are tried first
_LOG_LOCATION = (r"(?P<pre>^|[\s(])(?P<file>{known}<[^>\n]*>|[^\s:\"'()<>]*)"
                 r":(?P<line>\d+)(?P<post>:(?:\d+:)?)")


def map_build_log(log: str, table: Sequence[Tuple[str, int]],
                  source: Optional[str] = None) -> str:
    """``log`` with every location that names no file of ``table`` (``<kernel>:123:5:`` from
    NVIDIA, a temporary file's path, an empty name) read as a physical line of the built source
    and written as the header or kernel file and line it came from (``random_phase.h:40:5:``).

    Locations that already name a file of ``table`` are left alone: that compiler followed the
    ``#line`` markers itself (PoCL). Numbers beyond the built source are left alone too.

    With ``source`` (the built text), a location followed by the quoted source line (as clang
    based compilers print it) is checked against it: when the physical line's text differs but
    exactly one line of the source that ``#line`` numbers so has that text, the compiler
    followed the markers' numbers without their names, and that line is taken instead.
    """
    names = {f for f, _ in table}
    known = "".join(re.escape(n) + "|" for n in sorted(names, key=len, reverse=True) if n)
    pattern = re.compile(_LOG_LOCATION.format(known=known), re.MULTILINE)
    src = source.splitlines() if source is not None else None

    def where(n: int, snippet: Optional[str]) -> Optional[Tuple[str, int]]:
        physical = table[n - 1] if 1 <= n <= len(table) else None
        if src is None or not snippet or not snippet.strip():
            return physical
        want = snippet.strip()
        if physical is not None and src[n - 1].strip() == want:
            return physical
        by_marker = [table[i] for i, (_, line) in enumerate(table)
                     if line == n and i < len(src) and src[i].strip() == want]
        return by_marker[0] if len(by_marker) == 1 else physical

    log_lines = log.splitlines(keepends=True)
    out = []
    for k, text in enumerate(log_lines):
        following = log_lines[k + 1] if k + 1 < len(log_lines) else None

        def repl(m: "re.Match") -> str:
            if m.group("file") in names:
                return m.group(0)
            loc = where(int(m.group("line")), following)
            if loc is None:
                return m.group(0)
            return f"{m.group('pre')}{loc[0]}:{loc[1]}{m.group('post')}"

        out.append(pattern.sub(repl, text))
    return "".join(out)


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
# program handle -> kernels/<file> it was built from (launch errors name the file)
_program_files: Dict[int, str] = {}


def build_program(context: "cl.Context", filename: str, *,
                  defines: Optional[Mapping[str, object]] = None,
                  source: Optional[str] = None,
                  extra_options: Sequence[str] = ()) -> "cl.Program":
    """Build ``kernels/<filename>`` for ``context``, once per (context, file, options).

    Parameters
    ----------
    context : pyopencl.Context
    filename : str
        Name of a ``.cl`` file in ``kernels/``. Headers it includes are looked up in the
        kernels folder and in pyopencl's own ``cl`` folder (for Random123), as ``-I`` would, and
        pasted into the source (:func:`inline_includes`).
    defines : mapping, optional
        Preprocessor macros, ``{"N": 8}`` -> ``-DN=8``; ``True``/``None`` values define the bare
        name, ``False`` omits it.
    source : str, optional
        Source text to build instead of the file's (tests use it for broken kernels); the
        filename still names it in errors.
    extra_options : sequence of str
        Further compiler options, after the defines.

    Raises
    ------
    ProgramBuildError
        With the file name, the options and the compiler's build log.
    """
    # no -I: the headers are pasted in (inline_includes), so the options hold no path and the
    # drivers' binary caches are keyed on content
    options = tuple(["-cl-mad-enable"] + _define_options(defines) + list(extra_options))
    key = (filename, options, source)
    with _lock:
        per_ctx = _program_cache.setdefault(context, {})
        program = per_ctx.get(key)
        if program is not None:
            return program
    text = inline_includes(source if source is not None else read_kernel_source(filename),
                           filename)
    # the driver's cache folder is compared around the build call itself, while a
    # BuildCounter asks for it (a walk of the folder: not for every library call)
    folder = compiler_cache_dir(context.devices[0]) if _probes else None
    before = _cache_snapshot(folder, by_entry=_is_pocl(context.devices[0]))
    t0 = time.perf_counter()
    try:
        program = cl.Program(context, text).build(options=list(options))
    except cl.RuntimeError as exc:
        # every compiler's line numbers mapped back to the header or file and line they came
        # from, whether or not it follows the #line markers (NVIDIA's does not)
        raw = _build_log(exc, context)
        log = map_build_log(raw, source_line_table(text, filename), text)
        raise ProgramBuildError(filename, [d.name.strip() for d in context.devices], log,
                                options, raw_log=raw) from None
    seconds = time.perf_counter() - t0
    new_files = _new_cache_entries(folder, before)
    info = getattr(program, "_build_duration_info", None)  # pyopencl's (descr, cached, s)
    with _lock:
        _program_cache.setdefault(context, {})[key] = program
        _program_files[program.int_ptr] = filename
        _builds.append(ProgramBuild(filename, seconds,
                                    bool(info[1]) if isinstance(info, tuple) and len(info) > 1
                                    else False, folder, new_files))
    return program


# What a program that "built" without its kernels means, and the fix: seen with PyPI's PoCL
# 3.0-rc2 (LLVM 14) on an AMD EPYC of family 25 (Zen 4; LLVM 14 builds for znver3, without
# AVX-512), whose compiler segfaults on clholo's 16-wide CPU kernels (PoCL's kernel library
# passes float16 in another layout: vload16, shuffle2, sqrt of a float16, ...) and leaves
# entries in its kernel cache that later processes load as programs without kernels.
EMPTY_PROGRAM_HINT = (
    "The OpenCL driver's compiler returned a program without the kernels its source defines: "
    "a fault of the driver, not of the source. Seen with PyPI's PoCL (pocl-binary-distribution "
    "3.0, LLVM 14) on AMD Zen 4 CPUs, whose compiler crashes on clholo's kernels and leaves "
    "broken entries in its cache (~/.cache/pocl; remove it). Install a PoCL with a newer LLVM, "
    "e.g. Debian/Ubuntu `apt-get install pocl-opencl-icd`, and choose it with CLHOLO_DEVICE "
    "(`clholo info` lists the devices); `clholo selftest --quick` then says whether clholo runs "
    "on it."
)


def _missing_kernel(program: "cl.Program", filename: str, name: str,
                    context: "cl.Context") -> Exception:
    """The error for kernel ``name`` that ``program`` (built from ``kernels/<filename>``
    without error) does not hold: pyopencl's bare ``INVALID_KERNEL_NAME`` names neither the
    file nor the fix. A program that holds no kernel at all is the driver's fault
    (:data:`EMPTY_PROGRAM_HINT`)."""
    try:
        names = [n for n in program.kernel_names.split(";") if n]
    except cl.Error:
        names = None
    devices = ", ".join(d.name.strip() for d in context.devices)
    if names == []:
        return ProgramBuildError(filename, [devices], f"(the build succeeded, but the program "
                                 f"holds no kernels, not even {name})\n{EMPTY_PROGRAM_HINT}", [])
    return LookupError(f"kernels/{filename} built for {devices} holds no kernel {name!r}"
                       + (f" (it holds {', '.join(names)})" if names else ""))


# ------------------------------------------------------------------------------ build accounting
@dataclass(frozen=True)
class ProgramBuild:
    """One program compiled (not found in :func:`build_program`'s memo) in this process.

    Parameters
    ----------
    filename : str
        The ``kernels/`` file.
    seconds : float
        Host wall clock of the driver's build call.
    pyopencl_cache : bool
        Whether pyopencl served the binary from its own cache.
    cache_folder : str, optional
        The driver's compiler cache, when one was watched.
    new_cache_files : int, optional
        What that folder gained during the build call: files and folders of new programs
        for PoCL (its first level's time stamps tell where to look), files for other drivers.
    """

    filename: str
    seconds: float          # host wall clock of the driver's build call
    pyopencl_cache: bool    # pyopencl served the binary from its own cache
    cache_folder: Optional[str] = None  # the driver's compiler cache, when one was watched
    new_cache_files: Optional[int] = None  # entries (PoCL) or files it gained meanwhile


_builds: List[ProgramBuild] = []
_probes: List[object] = []  # active BuildCounters: build_program then watches the cache folder


def _is_pocl(device: "cl.Device") -> bool:
    platform = device.platform.name.strip().lower()
    return "portable computing language" in platform or "pocl" in platform


def compiler_cache_dir(device: "cl.Device") -> Optional[str]:
    """The folder where ``device``'s driver keeps compiled programs between processes, when it
    is known and enabled: PoCL's kcache (``POCL_CACHE_DIR``, else ``$XDG_CACHE_HOME/pocl/kcache``
    or ``~/.cache/pocl/kcache``), NVIDIA's compute cache (``CUDA_CACHE_PATH``, else
    ``~/.nv/ComputeCache``; none with ``CUDA_CACHE_DISABLE=1``); None for other drivers."""
    platform = device.platform.name.strip().lower()
    home = os.path.expanduser("~")
    if _is_pocl(device):
        if os.environ.get("POCL_KERNEL_CACHE", "1") == "0":
            return None
        if os.environ.get("POCL_CACHE_DIR"):
            return os.environ["POCL_CACHE_DIR"]
        xdg = os.environ.get("XDG_CACHE_HOME") or os.path.join(home, ".cache")
        return os.path.join(xdg, "pocl", "kcache")
    if "nvidia" in platform:
        if os.environ.get("CUDA_CACHE_DISABLE", "0") == "1":
            return None
        return os.environ.get("CUDA_CACHE_PATH") or os.path.join(home, ".nv", "ComputeCache")
    return None


def _count_files(folder: Optional[str]) -> Optional[int]:
    if folder is None or not os.path.isdir(folder):
        return None
    n = 0
    for _, _, files in os.walk(folder):
        n += len(files)
    return n


# How far a file's timestamp may lag time.time_ns() (the kernel stamps files from a coarse
# clock, a tick behind): entries made this long before a build call count as its own
_CLOCK_SLACK_NS = 50_000_000


def _cache_snapshot(folder: Optional[str], *, by_entry: bool):
    """What :func:`_new_cache_entries` compares after a build call with the folder as it is
    then. ``by_entry`` (PoCL's kcache, ``<2 letters>/<program hash>/...``): the clock and the
    time stamps of the folder's first level only, not a walk of it (a kcache that years of
    builds grew to thousands of folders took 0.6 s a walk, 20 s of a 12-megapixel render's
    16 builds); otherwise the count of files in the whole folder."""
    if folder is None or not os.path.isdir(folder):
        return None
    if not by_entry:
        return ("files", _count_files(folder))
    return ("entries", time.time_ns() - _CLOCK_SLACK_NS, _first_level_stamps(folder))


def _first_level_stamps(folder: str) -> Dict[str, int]:
    stamps = {}
    with os.scandir(folder) as entries:
        for entry in entries:
            try:
                stamps[entry.name] = entry.stat(follow_symlinks=False).st_mtime_ns
            except OSError:  # removed meanwhile
                pass
    return stamps


def _entries_since(path: str, since_ns: int) -> int:
    """Entries under ``path`` stamped at ``since_ns`` or later, each new folder's whole
    contents with it (a folder that gained nothing since then is not opened)."""
    n = 0
    try:
        with os.scandir(path) as entries:
            for entry in entries:
                try:
                    stamp = entry.stat(follow_symlinks=False).st_mtime_ns
                except OSError:
                    continue
                if stamp < since_ns:
                    continue
                n += 1
                if entry.is_dir(follow_symlinks=False):
                    n += _entries_since(entry.path, since_ns)
    except OSError:
        pass
    return n


def _new_cache_entries(folder: Optional[str], before) -> Optional[int]:
    """Entries (by_entry) or files the driver's cache folder gained since ``before``
    (:func:`_cache_snapshot`); None when unknown. By entry: a program the build call compiled
    is a new ``<hash>`` folder in a first-level folder, whose time stamp it changes; a cached
    program read (its ``last_accessed`` rewritten a level deeper) changes none of them."""
    if before is None or folder is None or not os.path.isdir(folder):
        return None
    if before[0] == "files":
        after = _count_files(folder)
        return None if after is None or before[1] is None else after - before[1]
    _, since_ns, stamps = before
    n = 0
    for name, stamp in _first_level_stamps(folder).items():
        if stamps.get(name) == stamp:
            continue  # nothing added or removed in it
        path = os.path.join(folder, name)
        if name not in stamps:
            n += 1 + (_entries_since(path, 0) if os.path.isdir(path) else 0)
        elif os.path.isdir(path):
            n += _entries_since(path, since_ns)
        else:
            n += 1  # a file of the first level rewritten
    return n


class BuildCounter:
    """The programs :func:`build_program` compiled while a block ran, their time, and what can
    be known of whether the driver's compiler cache served them.

    ``with BuildCounter(device) as b: ...`` then ``b.programs``, ``b.seconds`` and
    ``b.cache``, one of ``"none built"``, ``"served from the cache"`` (the driver's cache
    folder gained no file during any build call), ``"compiled"`` (it gained files during every
    one), ``"partly compiled"`` (during some: ``b.programs_compiled``),
    ``"pyopencl cache"``, or ``"unknown"`` (no cache folder known for this driver, or none
    exists), and :meth:`describe` for a line of text. Counts every thread's builds (a
    process-wide list).

    What can be known, and what cannot: the folder is compared around each build call, so
    another process compiling into the same cache at that moment reads as "compiled"; PoCL
    also compiles at a kernel's first launch (its work-group specialisation), after the
    build call, and that time is not counted here (it shows in the first launches, and only
    once per cache); NVIDIA compiles in the build call.
    """

    def __init__(self, device: Optional["cl.Device"] = None):
        self.device = device
        self.folder = compiler_cache_dir(device) if device is not None else None

    def __enter__(self) -> "BuildCounter":
        with _lock:
            self._start = len(_builds)
            if self.folder is not None:
                _probes.append(self)
        self.builds: List[ProgramBuild] = []
        return self

    def __exit__(self, *exc) -> None:
        with _lock:
            self.builds = list(_builds[self._start:])
            if self in _probes:
                _probes.remove(self)

    @property
    def new_cache_files(self) -> Optional[int]:
        """Entries (PoCL) or files the driver's cache folder gained during this block's build
        calls (None when unknown; :class:`ProgramBuild`)."""
        counts = [b.new_cache_files for b in self.builds if not b.pyopencl_cache]
        if not counts or any(c is None for c in counts):
            return None
        return sum(counts)

    @property
    def programs(self) -> int:
        """Programs built during the block."""
        return len(self.builds)

    @property
    def seconds(self) -> float:
        """Host seconds of their build calls, summed."""
        return sum(b.seconds for b in self.builds)

    @property
    def cache(self) -> str:
        """What served them: one of the words of the class docstring."""
        if not self.builds:
            return "none built"
        if all(b.pyopencl_cache for b in self.builds):
            return "pyopencl cache"
        if self.new_cache_files is None:
            return "unknown"
        compiled = self.programs_compiled
        if compiled == 0:
            return "served from the cache"
        return "compiled" if compiled == self.programs else "partly compiled"

    @property
    def programs_compiled(self) -> Optional[int]:
        """Builds during which the driver's cache folder gained files (None when unknown)."""
        if self.new_cache_files is None:
            return None
        return sum(1 for b in self.builds if not b.pyopencl_cache and b.new_cache_files)

    def to_dict(self) -> Dict[str, object]:
        """Everything above as JSON-ready values (``summary.json``'s ``build``)."""
        return {"programs": self.programs, "seconds": round(self.seconds, 4),
                "compiler_cache": self.cache, "cache_folder": self.folder,
                "new_cache_files": self.new_cache_files,
                "programs_compiled": self.programs_compiled,
                "files": sorted({b.filename for b in self.builds})}

    def describe(self) -> str:
        """``"built 12 OpenCL programs in 5.40 s: compiled (PoCL/NVIDIA cache ...)"``."""
        if not self.builds:
            return "no OpenCL program to build (all built before in this process)"
        what = {"compiled": f"compiled by the driver ({self.new_cache_files} new entries in "
                            f"its cache {self.folder})",
                "partly compiled": f"{self.programs_compiled} compiled by the driver, the "
                                   f"others served from its cache {self.folder}",
                "served from the cache": f"served from the driver's compiler cache (nothing "
                                         f"new in {self.folder})",
                "pyopencl cache": "served from pyopencl's binary cache",
                "unknown": ("whether a compiler cache served them is unknown (no cache folder "
                            "known for this driver)" if self.folder is None else
                            f"whether a compiler cache served them is unknown ({self.folder} "
                            f"does not exist)")}[self.cache]
        return (f"built {self.programs} OpenCL program(s) in {self.seconds:.2f} s: {what}")


_kernel_cache: "weakref.WeakKeyDictionary[cl.Context, Dict[Tuple, cl.Kernel]]" = weakref.WeakKeyDictionary()


def release_context(context: "cl.Context") -> None:
    """Forget everything clholo keeps for the OpenCL ``context``: its compiled programs and
    kernels, transfer functions, propagators and :func:`clholo.fft.fft2`'s plans.

    clholo keeps these per context for as long as the context lives, but each of them holds
    the context itself, so a context passed as ``queue=`` and then dropped stayed alive with
    its caches (5-15 MiB of host memory each on PoCL; device memory on a GPU). A program that
    makes a context per job (a service, a worker) calls this when a job's context is done;
    clholo's own commands use one context per process and need not. Using the context again
    afterwards is fine: what it needs is built again.

    Parameters
    ----------
    context : pyopencl.Context
    """
    if not isinstance(context, cl.Context):
        raise TypeError(f"context must be a pyopencl.Context, got {type(context).__name__}")
    with _lock:
        programs = _program_cache.pop(context, {})
        _kernel_cache.pop(context, None)
        for program in programs.values():
            _program_files.pop(program.int_ptr, None)
        hooks = list(_release_hooks)
    for forget in hooks:
        forget(context)


# the modules that keep their own per-context caches (clholo.fft, clholo.propagation) register
# how to forget a context here when they are imported: runtime imports none of them
_release_hooks: List = []


def on_release_context(forget) -> None:
    """Have :func:`release_context` call ``forget(context)`` too (a cache of another module)."""
    with _lock:
        if forget not in _release_hooks:
            _release_hooks.append(forget)


def get_kernel(context: "cl.Context", filename: str, name: str, *,
               defines: Optional[Mapping[str, object]] = None) -> "cl.Kernel":
    """Kernel ``name`` of ``kernels/<filename>`` (see :func:`build_program`), memoized.

    Retrieving a kernel from a program creates a new object each time (at a cost on some
    drivers), so clholo keeps one per (context, file, defines, name). Kernel objects carry
    their arguments: launch them with :func:`launch`, which sets them and enqueues as one step
    (other threads' launches wait), not with a ``set_arg`` of your own.
    """
    key = (filename, tuple(sorted((defines or {}).items())), name)
    with _lock:
        per_ctx = _kernel_cache.setdefault(context, {})
        kern = per_ctx.get(key)
    if kern is None:
        program = build_program(context, filename, defines=defines)
        try:
            kern = cl.Kernel(program, name)
        except cl.LogicError as exc:
            if "INVALID_KERNEL_NAME" not in str(exc):
                raise
            raise _missing_kernel(program, filename, name, context) from None
        with _lock:
            _kernel_cache.setdefault(context, {})[key] = kern
    return kern


def _build_log(exc: Exception, context: "cl.Context") -> str:
    # pyopencl puts the per-device logs into the exception text; keep it whole.
    text = str(exc)
    return text if text else "(the OpenCL compiler gave no log)"


def require_fp64(device: "cl.Device", what: str) -> None:
    """Raise a clear error when ``device`` lacks double precision and ``what`` needs it:
    :class:`clholo.errors.NoDoublePrecisionError` (the machine cannot: exit 3 in a command; a
    ``TypeError`` too)."""
    if not has_fp64(device):
        from clholo.errors import NoDoublePrecisionError

        raise NoDoublePrecisionError(
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
        """Count ``event`` (a profiled ``pyopencl.Event``) under ``label``; returns it."""
        self._events.append((label, event))
        return event

    def summary(self) -> Dict[str, float]:
        """Device seconds per label (waits for every event)."""
        out: Dict[str, float] = {}
        for label, event in self._events:
            out[label] = out.get(label, 0.0) + event_seconds(event)
        return out


@dataclass(frozen=True)
class LaunchRecord:
    """One kernel launch seen by a :class:`KernelRecorder`.

    Attributes
    ----------
    label : str
        What ran: the kernel's function name, or a name its caller gives (the FFT plans name
        the pass, e.g. ``"fft_strip rows n=1944"``).
    global_size, local_size : tuple of int
        The launch's sizes (``local_size`` None: the driver's choice).
    event : pyopencl.Event
        Its event (profiling on: :func:`create_queue`'s default).
    bytes_moved : int or None
        Bytes of global memory the launch must read and write at least, where its caller
        knows them (the FFT passes: one read of the source window and one write of the
        stored window; the fused multiply and callbacks not counted); None elsewhere.
    """

    label: str
    global_size: Tuple[int, ...]
    local_size: Optional[Tuple[int, ...]]
    event: "cl.Event"
    bytes_moved: Optional[int] = None

    @property
    def seconds(self) -> float:
        """Device time of the launch (waits for it)."""
        return event_seconds(self.event)


_recorders: List["KernelRecorder"] = []


def note_launch(kernel: "cl.Kernel", global_size: Sequence[int],
                local_size: Optional[Sequence[int]], event: "cl.Event", *,
                label: Optional[str] = None, bytes_moved: Optional[int] = None) -> None:
    """Tell every active :class:`KernelRecorder` about a launch (:func:`launch` and
    :func:`enqueue_nd_range` call it; code that enqueues kernels itself, as the FFT plans do,
    calls it too). Costs one list check when no recorder is active.

    Parameters
    ----------
    kernel : pyopencl.Kernel
        What ran (its function name is the default label).
    global_size, local_size : sequence of int
        The launch's sizes (``local_size`` None: the driver's choice).
    event : pyopencl.Event
        The launch's event.
    label : str, optional
        A name for the profile's table instead of the function name.
    bytes_moved : int, optional
        Bytes of global memory the launch must read and write at least (:class:`LaunchRecord`).
    """
    if not _recorders:
        return
    rec = LaunchRecord(label or kernel.function_name, tuple(int(v) for v in global_size),
                       None if local_size is None else tuple(int(v) for v in local_size),
                       event, bytes_moved)
    with _lock:
        for r in _recorders:
            r.launches.append(rec)


class KernelRecorder:
    """Record every kernel launch of clholo while active: the per-kernel profile.

    Every launch through :func:`launch`, :func:`enqueue_nd_range` and the FFT plans, from any
    thread, lands in ``launches`` (a list of :class:`LaunchRecord`) between ``__enter__`` and
    ``__exit__``; recorders nest. Device times come from the events, so the queue must have
    profiling on (clholo's queues do). pyopencl's own array kernels (``fill``, arithmetic on
    ``pyopencl.array``) and copies are not recorded.

    Examples
    --------
    >>> with KernelRecorder() as rec:                  # doctest: +SKIP
    ...     renderer.render(3, out=out); queue.finish()
    >>> rec.summary()[0]                               # doctest: +SKIP
    {'label': 'fft_strip rows n=1944 round trip', 'launches': 31, 'seconds': 3.28, ...}
    """

    def __init__(self) -> None:
        self.launches: List[LaunchRecord] = []

    def __enter__(self) -> "KernelRecorder":
        with _lock:
            _recorders.append(self)
        return self

    def __exit__(self, *exc) -> None:
        with _lock:
            if self in _recorders:
                _recorders.remove(self)

    def summary(self, *, copy_bandwidth: Optional[float] = None) -> List[Dict[str, object]]:
        """Launches grouped by label, the most device time first (waits for every event).

        Parameters
        ----------
        copy_bandwidth : float, optional
            The device's buffer-to-buffer copy bandwidth, bytes/s, read + write counted
            (``clholo.bench.copy_bandwidth``): then each group with known bytes also gets
            ``"floor_ratio"``, its time over the time a copy of its bytes takes.

        Returns
        -------
        list of dict
            Per label: ``"label"``, ``"launches"``, ``"seconds"`` (device time, summed),
            ``"share"`` (of every recorded launch's time), ``"bytes"`` (None when any launch
            of the group has none), ``"bandwidth"`` (bytes/s or None) and ``"floor_ratio"``
            (or None).
        """
        groups: Dict[str, Dict[str, object]] = {}
        for rec in self.launches:
            g = groups.setdefault(rec.label, {"label": rec.label, "launches": 0,
                                              "seconds": 0.0, "bytes": 0})
            g["launches"] = int(g["launches"]) + 1
            g["seconds"] = float(g["seconds"]) + rec.seconds
            g["bytes"] = (None if g["bytes"] is None or rec.bytes_moved is None
                          else int(g["bytes"]) + rec.bytes_moved)
        total = sum(float(g["seconds"]) for g in groups.values())
        rows = sorted(groups.values(), key=lambda g: -float(g["seconds"]))
        for g in rows:
            secs, nbytes = float(g["seconds"]), g["bytes"]
            g["share"] = secs / total if total > 0 else 0.0
            g["bandwidth"] = (int(nbytes) / secs if nbytes is not None and secs > 0 else None)
            g["floor_ratio"] = (secs / (int(nbytes) / copy_bandwidth)
                                if copy_bandwidth and nbytes else None)
        return rows

    def device_span(self) -> float:
        """Seconds from the first recorded launch's start to the last one's end (waits)."""
        if not self.launches:
            return 0.0
        for rec in self.launches:
            rec.event.wait()
        start = min(rec.event.profile.start for rec in self.launches)
        end = max(rec.event.profile.end for rec in self.launches)
        return (end - start) * 1e-9


class WallTimer:
    """``with WallTimer() as t: ...; t.seconds`` -- host wall-clock time of a block."""

    def __enter__(self) -> "WallTimer":
        self._t0 = time.perf_counter()
        self.seconds = 0.0
        return self

    def __exit__(self, *exc) -> None:
        self.seconds = time.perf_counter() - self._t0


# ------------------------------------------------------------------------------ launch limits
class LaunchLimitError(ValueError):
    """A kernel launch asks for more than the device or the compiled kernel allows.

    Raised by :func:`check_launch` before the launch (an OpenCL driver would fail it with a bare
    ``CL_INVALID_WORK_GROUP_SIZE`` or ``CL_OUT_OF_RESOURCES``, or worse, some drivers run it
    wrong). The message names the kernel, its file, the size asked for, the limit and the fix.
    """


@dataclass(frozen=True)
class _KernelLimits:
    name: str
    filename: str
    work_group_size: int          # CL_KERNEL_WORK_GROUP_SIZE on this device
    compile_work_group: Tuple[int, int, int]  # reqd_work_group_size, (0, 0, 0) when none
    static_local_bytes: int       # CL_KERNEL_LOCAL_MEM_SIZE before this launch's local args


@dataclass(frozen=True)
class _DeviceLimits:
    name: str
    max_dims: int
    max_item_sizes: Tuple[int, ...]
    max_work_group_size: int
    local_mem_bytes: int


_device_limits: Dict[int, _DeviceLimits] = {}
_launched: set = set()


def launched_kernels() -> List[str]:
    """Names of every kernel function :func:`check_launch` has seen in this process, sorted
    (the self-test reports it, and the Oclgrind test checks every kernel of ``kernels/`` ran)."""
    with _lock:
        return sorted(_launched)


def _limits_of_device(device: "cl.Device") -> _DeviceLimits:
    key = device.int_ptr
    lim = _device_limits.get(key)
    if lim is None:
        lim = _DeviceLimits(name=device.name.strip(),
                            max_dims=int(device.max_work_item_dimensions),
                            max_item_sizes=tuple(int(s) for s in device.max_work_item_sizes),
                            max_work_group_size=int(device.max_work_group_size),
                            local_mem_bytes=int(device.local_mem_size))
        with _lock:
            _device_limits[key] = lim
    return lim


def _limits_of_kernel(kernel: "cl.Kernel", device: "cl.Device") -> _KernelLimits:
    # cached on the kernel object itself (kernels are not weak-referenceable, and a handle
    # address could be reused by a later kernel): one entry per device
    per_dev = getattr(kernel, "_clholo_limits", None)
    if per_dev is None:
        per_dev = {}
        try:
            kernel._clholo_limits = per_dev
        except AttributeError:  # pragma: no cover - a kernel type without a __dict__
            pass
    lim = per_dev.get(device.int_ptr)
    if lim is None:
        wgi = cl.kernel_work_group_info
        name = kernel.function_name
        try:
            prog = kernel.get_info(cl.kernel_info.PROGRAM).int_ptr
        except cl.Error:  # pragma: no cover
            prog = None
        try:
            compiled = tuple(int(s) for s in kernel.get_work_group_info(
                wgi.COMPILE_WORK_GROUP_SIZE, device))
        except cl.Error:  # pragma: no cover - optional on some drivers
            compiled = (0, 0, 0)
        lim = _KernelLimits(
            name=name, filename=_program_files.get(prog, "?"),
            work_group_size=int(kernel.get_work_group_info(wgi.WORK_GROUP_SIZE, device)),
            compile_work_group=compiled,
            static_local_bytes=int(kernel.get_work_group_info(wgi.LOCAL_MEM_SIZE, device)))
        per_dev[device.int_ptr] = lim
    return lim


def kernel_local_bytes(kernel: "cl.Kernel", device: "cl.Device") -> int:
    """Local memory ``kernel`` holds itself on ``device``, in bytes (``CL_KERNEL_LOCAL_MEM_SIZE``,
    its ``__local`` variables and what the implementation needs), queried once per kernel and
    device and cached with the other launch limits.

    A plan whose ``__local`` arguments fill the device's local memory must leave this much free
    (NVIDIA's ``fft_strip`` holds 1 byte on an H100 although it declares no ``__local``
    variable). The OpenCL specification counts ``__local`` arguments already set into the
    query, so ask before setting them: the first query is the one kept.
    """
    return _limits_of_kernel(kernel, device).static_local_bytes


def kernel_work_group_size(kernel: "cl.Kernel", device: "cl.Device") -> int:
    """Work-items ``kernel`` allows in one work-group on ``device``
    (``CL_KERNEL_WORK_GROUP_SIZE``), queried once per kernel and device and cached with the
    other launch limits.

    It is often below the device's maximum, and a compiler sets it from the registers the
    kernel needs: NVIDIA's H200 driver gives the in-place ``fft_lines`` at most 256 of the
    device's 1024, even when it was compiled with ``reqd_work_group_size(512, 1, 1)``. Plans
    ask after building and plan again where a launch would not fit.
    """
    return _limits_of_kernel(kernel, device).work_group_size


_REPORT = ("This is a limit clholo did not plan for on this device: please report it with the "
           "output of `clholo selftest --json selftest.json` (docs/selftest.md); meanwhile "
           "choose another device with CLHOLO_DEVICE (see `clholo info`)")


def check_launch(queue: "cl.CommandQueue", kernel: "cl.Kernel", global_size: Sequence[int],
                 local_size: Optional[Sequence[int]] = None, args: Sequence = (), *,
                 fix: Optional[str] = None) -> None:
    """Check one launch against the device's and the kernel's limits before it is enqueued.

    Checks: at most ``CL_DEVICE_MAX_WORK_ITEM_DIMENSIONS`` dimensions; with a local size, each dimension within ``CL_DEVICE_MAX_WORK_ITEM_SIZES``, their
    product within ``CL_KERNEL_WORK_GROUP_SIZE`` (the kernel's own limit on this device, often
    below the device's), equal to a ``reqd_work_group_size`` the kernel was compiled with, and
    dividing the global size; and the local memory (``CL_KERNEL_LOCAL_MEM_SIZE`` plus the
    ``pyopencl.LocalMemory`` arguments in ``args``) within ``CL_DEVICE_LOCAL_MEM_SIZE``. The
    per-kernel and per-device queries are made once and cached.

    Parameters
    ----------
    queue : pyopencl.CommandQueue
        The launch's queue (its device is the one checked).
    kernel : pyopencl.Kernel
    global_size, local_size : sequence of int
        As given to the launch (``local_size=None``: the driver chooses).
    args : sequence
        The launch's arguments, when at hand: their ``LocalMemory`` sizes count.
    fix : str, optional
        What the caller can change, put into the message instead of the generic advice.

    Raises
    ------
    LaunchLimitError
        Naming the kernel and its file, the size, the limit and the fix.
    """
    device = queue.device
    dev = _limits_of_device(device)
    k = _limits_of_kernel(kernel, device)
    with _lock:
        _launched.add(k.name)
    where = f"kernel {k.name} (kernels/{k.filename}) on {dev.name!r}"
    advice = fix or _REPORT
    gsize = tuple(int(g) for g in global_size)
    if not 1 <= len(gsize) <= dev.max_dims:
        raise LaunchLimitError(
            f"{where}: global size {gsize} has {len(gsize)} dimension(s); the device allows 1 "
            f"to {dev.max_dims} (CL_DEVICE_MAX_WORK_ITEM_DIMENSIONS). {advice}")
    if local_size is not None:
        lsize = tuple(int(s) for s in local_size)
        if len(lsize) != len(gsize):
            raise LaunchLimitError(f"{where}: local size {lsize} and global size {gsize} have "
                                   f"different numbers of dimensions. {advice}")
        for d, (l, m) in enumerate(zip(lsize, dev.max_item_sizes)):
            if not 1 <= l <= m:
                raise LaunchLimitError(
                    f"{where}: local size {lsize} has {l} work-items in dimension {d}; the "
                    f"device allows 1 to {m} there (CL_DEVICE_MAX_WORK_ITEM_SIZES = "
                    f"{list(dev.max_item_sizes)}). {advice}")
        items = 1
        for l in lsize:
            items *= l
        if items > k.work_group_size:
            raise LaunchLimitError(
                f"{where}: local size {lsize} is a work-group of {items} work-items; this kernel "
                f"allows at most {k.work_group_size} on this device (CL_KERNEL_WORK_GROUP_SIZE; "
                f"device maximum {dev.max_work_group_size}). {advice}")
        if any(k.compile_work_group):
            req = k.compile_work_group[:len(lsize)]
            if tuple(lsize) != tuple(req) or any(c > 1 for c in k.compile_work_group[len(lsize):]):
                raise LaunchLimitError(
                    f"{where}: local size {lsize} differs from the reqd_work_group_size "
                    f"{k.compile_work_group} the kernel was compiled with. {advice}")
        for d, (g, l) in enumerate(zip(gsize, lsize)):
            if g % l:
                raise LaunchLimitError(
                    f"{where}: global size {gsize} is not a multiple of the local size {lsize} "
                    f"in dimension {d} (OpenCL 1.2 devices require it). {advice}")
    dynamic = sum(int(a.size) for a in args if isinstance(a, cl.LocalMemory))
    need = k.static_local_bytes + dynamic
    if need > dev.local_mem_bytes:
        raise LaunchLimitError(
            f"{where}: needs {need} bytes of local memory ({k.static_local_bytes} in the kernel "
            f"(CL_KERNEL_LOCAL_MEM_SIZE) + {dynamic} in __local arguments); the device has "
            f"{dev.local_mem_bytes} (CL_DEVICE_LOCAL_MEM_SIZE). {advice}")


def _check_once(queue: "cl.CommandQueue", kernel: "cl.Kernel", global_size: Sequence[int],
                local_size: Optional[Sequence[int]], args: Sequence) -> None:
    """:func:`check_launch`, made once per kernel, queue, sizes and ``__local`` bytes: a launch
    that passed is remembered on the kernel object (with its queue, so that the queue's handle
    cannot be reused by another while the entry lives), and its repeats cost one lookup."""
    dynamic = 0
    for a in args:
        if isinstance(a, cl.LocalMemory):
            dynamic += a.size
    # the limit sources are part of the key: a stand-in device or kernel (tests make smaller
    # ones) is checked afresh
    key = (queue.int_ptr, tuple(global_size),
           None if local_size is None else tuple(local_size), dynamic,
           _limits_of_device, _limits_of_kernel)
    checked = getattr(kernel, "_clholo_checked", None)
    if checked is not None and key in checked:
        return
    check_launch(queue, kernel, global_size, local_size, args)
    if checked is None:
        checked = {}
        try:
            kernel._clholo_checked = checked
        except AttributeError:  # pragma: no cover - a kernel type without a __dict__
            return
    checked[key] = queue


def launch(kernel: "cl.Kernel", queue: "cl.CommandQueue", global_size: Sequence[int],
           local_size: Optional[Sequence[int]], *args, wait_for=None) -> "cl.Event":
    """``kernel(queue, global_size, local_size, *args)`` after :func:`check_launch` (made the
    first time a kernel is launched on a queue with these sizes; its repeats skip it), seen by
    every active :class:`KernelRecorder`; returns the launch's event.

    Parameters
    ----------
    kernel : pyopencl.Kernel
        The kernel, its scalar argument dtypes set.
    queue : pyopencl.CommandQueue
        Where it runs.
    global_size, local_size : sequence of int
        The launch's sizes (``local_size`` None: the driver's choice).
    *args
        The kernel's arguments.
    wait_for : list of pyopencl.Event, optional
        Events the launch waits for.
    """
    _check_once(queue, kernel, global_size, local_size, args)
    with _launch_lock:  # the arguments set and the launch enqueued as one step
        event = kernel(queue, global_size, local_size, *args, wait_for=wait_for)
    if _recorders:
        note_launch(kernel, global_size, local_size, event)
    return event


def enqueue_nd_range(queue: "cl.CommandQueue", kernel: "cl.Kernel", global_size: Sequence[int],
                     local_size: Optional[Sequence[int]] = None, wait_for=None) -> "cl.Event":
    """``pyopencl.enqueue_nd_range_kernel`` after :func:`check_launch` (for kernels whose
    arguments were set beforehand; ``__local`` arguments then count through the kernel's own
    ``CL_KERNEL_LOCAL_MEM_SIZE`` only: launch those with :func:`launch` or
    :func:`set_launch_args`). The check is made once per kernel, queue and sizes; the launch
    is seen by every active :class:`KernelRecorder`. ``global_size``, ``local_size`` and
    ``wait_for`` as for :func:`launch`."""
    _check_once(queue, kernel, global_size, local_size, ())
    with _launch_lock:  # every clholo launch holds it (tests/test_launch_lock.py checks)
        event = cl.enqueue_nd_range_kernel(queue, kernel, global_size, local_size,
                                           wait_for=wait_for)
    if _recorders:
        note_launch(kernel, global_size, local_size, event)
    return event


def set_launch_args(queue: "cl.CommandQueue", kernel: "cl.Kernel", global_size: Sequence[int],
                    local_size: Optional[Sequence[int]], args: Sequence) -> None:
    """``kernel.set_args(*args)`` after :func:`check_launch` of the launch that follows (on
    ``queue``, with ``global_size`` and ``local_size`` as for :func:`launch`)."""
    check_launch(queue, kernel, global_size, local_size, args)
    kernel.set_args(*args)
