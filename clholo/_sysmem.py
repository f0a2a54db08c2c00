"""How much memory this process can still have: what the system has free, within any
address-space limit (``ulimit -v``). A leaf module: the device side (:mod:`clholo.host.memory`,
which re-exports it) and the file readers (:mod:`clholo.io`) both ask it."""

from __future__ import annotations

__all__ = ["available_host_bytes"]


def _address_space_headroom() -> int:
    """Bytes this process may still map under its address-space limit (``RLIMIT_AS``,
    ``ulimit -v``), or a huge number where there is none (or it cannot be told)."""
    try:
        import resource

        soft, _ = resource.getrlimit(resource.RLIMIT_AS)
    except (ImportError, OSError, ValueError):  # pragma: no cover - not POSIX
        return 1 << 62
    if soft == resource.RLIM_INFINITY or soft < 0:
        return 1 << 62
    try:
        with open("/proc/self/status") as fh:
            for line in fh:
                if line.startswith("VmSize:"):
                    return max(0, soft - int(line.split()[1]) * 1024)
    except OSError:
        pass
    return soft  # the mapped size cannot be told: the limit itself bounds it


def available_host_bytes() -> int:
    """Memory the host can still give this process, bytes: ``MemAvailable`` on Linux (else
    the physical memory), or less where an address-space limit (``ulimit -v``) leaves less."""
    import os

    free = None
    try:
        with open("/proc/meminfo") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    free = int(line.split()[1]) * 1024
                    break
    except OSError:
        pass
    if free is None:
        try:
            free = int(os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES"))
        except (ValueError, OSError, AttributeError):  # pragma: no cover - not POSIX
            free = 1 << 62
    return min(free, _address_space_headroom())
