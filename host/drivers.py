"""GPU vendors' OpenCL drivers that are installed but that the OpenCL loader does not see.

In containers NVIDIA's ``libnvidia-opencl.so.1`` is often present (the container runtime mounts
it with the CUDA driver) while no ICD file names it, so the loader finds no NVIDIA platform and
clholo runs on PoCL, or on nothing (issue 22). When no platform or no GPU is found, ``clholo
info``, ``clholo selftest`` and the device errors look for the vendors' OpenCL libraries in the
usual places and print the exact fix: an ICD file holding the library's path in
``/etc/OpenCL/vendors`` (or in the folder ``OCL_ICD_VENDORS`` names).

Where it looks (:func:`search_dirs`): ``CLHOLO_OPENCL_LIB_DIRS`` (folders separated by
``os.pathsep``) replaces everything else when set (tests use it); otherwise the folders of
``LD_LIBRARY_PATH``, the distributions' library folders, NVIDIA's container mounts
(``/usr/local/nvidia/lib64``), CUDA toolkits (``/usr/local/cuda*/...``), ROCm
(``/opt/rocm*/lib``), Intel's compute runtime, and the ld.so cache (``ldconfig -p``).
"""

from __future__ import annotations

import glob
import os
import subprocess
from dataclasses import dataclass
from typing import Iterable, List, Optional, Sequence

__all__ = ["VENDOR_LIBRARIES", "VendorLibrary", "search_dirs", "icd_dirs", "registered_libraries",
           "find_vendor_libraries", "driver_advice", "SEARCH_ENV"]

#: Environment variable whose folders (``os.pathsep``-separated) replace the default search.
SEARCH_ENV = "CLHOLO_OPENCL_LIB_DIRS"

#: (vendor, library file name, ICD file name the fix writes)
VENDOR_LIBRARIES = (
    ("NVIDIA", "libnvidia-opencl.so.1", "nvidia.icd"),
    ("NVIDIA", "libnvidia-opencl.so", "nvidia.icd"),
    ("AMD ROCm", "libamdocl64.so", "amdocl64.icd"),
    ("Intel", "libigdrcl.so", "intel.icd"),
)

_DEFAULT_DIRS = (
    "/usr/lib/x86_64-linux-gnu", "/usr/lib/aarch64-linux-gnu", "/usr/lib64", "/usr/lib",
    "/usr/local/lib", "/usr/local/lib64",
    "/usr/local/nvidia/lib64", "/usr/local/nvidia/lib",      # NVIDIA container toolkit mounts
    "/usr/lib/wsl/lib",                                       # WSL2
    "/usr/local/cuda*/lib64", "/usr/local/cuda*/targets/*/lib", "/usr/local/cuda*/compat",
    "/opt/rocm*/lib", "/opt/rocm*/opencl/lib", "/opt/rocm*/lib/opencl",
    "/usr/lib/x86_64-linux-gnu/intel-opencl", "/usr/lib64/intel-opencl",
    "/usr/local/lib/intel-opencl", "/opt/intel/opencl*/lib64",
)


@dataclass(frozen=True)
class VendorLibrary:
    """One vendor OpenCL library found on disk."""

    vendor: str
    path: str             # absolute path as found (what an ICD file should hold)
    icd_name: str         # e.g. "nvidia.icd"
    registered: bool      # an ICD file of the folders the loader reads names it

    def to_dict(self) -> dict:
        return {"vendor": self.vendor, "path": self.path, "icd_file": self.icd_name,
                "registered": self.registered}


def search_dirs(dirs: Optional[Sequence[str]] = None) -> List[str]:
    """Folders searched for vendor libraries, in order, without repeats (globs expanded).

    Parameters
    ----------
    dirs : sequence of str, optional
        The folders to search, instead of ``CLHOLO_OPENCL_LIB_DIRS`` or the defaults (the
        ld.so cache is then not read either).
    """
    if dirs is None:
        env = os.environ.get(SEARCH_ENV)
        if env is not None:
            dirs = [d for d in env.split(os.pathsep) if d]
        else:
            dirs = [d for d in os.environ.get("LD_LIBRARY_PATH", "").split(os.pathsep) if d]
            dirs += list(_DEFAULT_DIRS)
    out: List[str] = []
    for pattern in dirs:
        for d in sorted(glob.glob(pattern)) if any(c in pattern for c in "*?[") else [pattern]:
            if d not in out and os.path.isdir(d):
                out.append(d)
    return out


_LDCONFIG = ("/sbin/ldconfig", "/usr/sbin/ldconfig", "ldconfig")


def _ldconfig_paths() -> List[str]:
    """Paths of vendor libraries in the ld.so cache (``ldconfig -p``); [] when unavailable."""
    names = {lib for _, lib, _ in VENDOR_LIBRARIES}
    for exe in _LDCONFIG:
        try:
            text = subprocess.run([exe, "-p"], capture_output=True, text=True, timeout=5,
                                  check=False).stdout
        except (OSError, subprocess.SubprocessError):
            continue
        paths = []
        for line in text.splitlines():
            name, _, path = line.strip().partition(" => ")
            if name.split(" ", 1)[0] in names and path:
                paths.append(path.strip())
        return paths
    return []


def icd_dirs() -> List[str]:
    """The folders of ICD files the loader reads: ``OCL_ICD_VENDORS`` when it names a folder
    (the ocl-icd loader then reads only that one), else ``/etc/OpenCL/vendors``."""
    env = os.environ.get("OCL_ICD_VENDORS")
    if env and os.path.isdir(env):
        return [env]
    return ["/etc/OpenCL/vendors"]


def registered_libraries(dirs: Optional[Iterable[str]] = None) -> List[str]:
    """What the ICD files of ``dirs`` (default :func:`icd_dirs`) name, as written in them (an
    absolute path or a bare library name); ``OCL_ICD_VENDORS`` naming one ``.icd`` file counts."""
    files: List[str] = []
    env = os.environ.get("OCL_ICD_VENDORS")
    if dirs is None and env and os.path.isfile(env):
        files.append(env)
    for d in (icd_dirs() if dirs is None else dirs):
        files += sorted(glob.glob(os.path.join(d, "*.icd")))
    names = []
    for f in files:
        try:
            with open(f, encoding="utf-8", errors="replace") as fh:
                line = fh.readline().strip()
        except OSError:
            continue
        if line:
            names.append(line)
    return names


def _is_registered(path: str, registered: Sequence[str]) -> bool:
    base = os.path.basename(path)
    real = os.path.realpath(path)
    for r in registered:
        if r == path or r == base or (os.path.isabs(r) and os.path.realpath(r) == real):
            return True
    return False


def find_vendor_libraries(dirs: Optional[Sequence[str]] = None) -> List[VendorLibrary]:
    """The vendors' OpenCL libraries present on this machine (one per vendor and real file).

    Parameters
    ----------
    dirs : sequence of str, optional
        Folders to search instead of the defaults (see :func:`search_dirs`).
    """
    registered = registered_libraries()
    found: List[VendorLibrary] = []
    seen_real = set()
    candidates: List[str] = []
    for d in search_dirs(dirs):
        for _, lib, _ in VENDOR_LIBRARIES:
            candidates.append(os.path.join(d, lib))
    if dirs is None and os.environ.get(SEARCH_ENV) is None:
        candidates += _ldconfig_paths()
    for path in candidates:
        if not os.path.isfile(path):
            continue
        real = os.path.realpath(path)
        if real in seen_real:
            continue
        for vendor, lib, icd in VENDOR_LIBRARIES:
            if os.path.basename(path) == lib:
                seen_real.add(real)
                found.append(VendorLibrary(vendor, os.path.abspath(path), icd,
                                           _is_registered(path, registered)))
                break
    return found


def driver_advice(found: Optional[Sequence[VendorLibrary]] = None, *,
                  situation: str = "no GPU among the OpenCL devices") -> str:
    """The exact fix for each vendor library found but not registered, as text ('' when none
    is found).

    Parameters
    ----------
    found : sequence of VendorLibrary, optional
        Default: :func:`find_vendor_libraries`.
    situation : str
        What was seen, for the first line ("no OpenCL platform", ...).
    """
    found = find_vendor_libraries() if found is None else list(found)
    if not found:
        return ""
    lines = []
    folder = icd_dirs()[0]
    env_folder = os.environ.get("OCL_ICD_VENDORS")
    for lib in found:
        if lib.registered:
            lines.append(
                f"{situation}, although {lib.vendor}'s OpenCL driver {lib.path} is registered "
                f"(an ICD file in {folder} names it): the driver itself did not load. Check that "
                f"the GPU is visible (nvidia-smi / rocm-smi / clinfo; in a container, that it was "
                f"started with the GPU, e.g. `docker run --gpus all`).")
            continue
        lines.append(
            f"{situation}, but {lib.vendor}'s OpenCL driver is installed at {lib.path} and no "
            f"ICD file names it, so the OpenCL loader does not see it. Fix, as root:\n"
            f"    mkdir -p {folder} && echo {lib.path} > {folder}/{lib.icd_name}\n"
            + (f"  (OCL_ICD_VENDORS={env_folder} is set, so the loader reads that folder only)\n"
               if env_folder else "")
            + f"  or without root, for this shell:\n"
            f"    mkdir -p ~/.opencl-vendors && echo {lib.path} > ~/.opencl-vendors/"
            f"{lib.icd_name} && export OCL_ICD_VENDORS=~/.opencl-vendors\n"
            f"  (the loader then reads only that folder: copy other .icd files into it too);\n"
            f"  then `clholo info` lists the {lib.vendor} device.")
    return "\n".join(lines)
