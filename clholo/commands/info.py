"""``clholo info``: the OpenCL platforms and devices, and the one clholo uses."""

from __future__ import annotations

import argparse


def register(subparsers) -> None:
    p = subparsers.add_parser("info", help="list OpenCL platforms and devices, and the one "
                                           "clholo uses")
    p.set_defaults(func=cmd_info)


def _fmt_bytes(n: int) -> str:
    for unit in ("B", "KiB", "MiB", "GiB", "TiB"):
        if n < 1024 or unit == "TiB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1024
    return str(n)


def cmd_info(args: argparse.Namespace) -> int:
    from clholo.host import runtime

    from clholo.host import drivers

    devices = runtime.list_devices()
    if not devices:  # exit 3 (environment) through the error boundary, as for every command
        raise runtime.no_device_error()
    # CLHOLO_DEVICE / PYOPENCL_CTX matching nothing: exit 3 with the list of devices (and the
    # driver advice, when there is some), before anything is printed
    chosen = runtime.choose_device()
    chosen_key = (chosen.platform.name.strip(), chosen.name.strip())
    platform = None
    problems = []
    for d in devices:
        if d.platform_index != platform:  # by index: two PoCLs share a name
            platform = d.platform_index
            print(f"platform {platform}: {d.platform_name}")
        mark = "*" if chosen_key == (d.platform_name, d.device_name) else " "
        print(f" {mark} {d.selector}  {d.device_name}  [{d.device_type}]")
        print(f"        compute units {d.compute_units}, global memory "
              f"{_fmt_bytes(d.global_mem_bytes)}, local memory {_fmt_bytes(d.local_mem_bytes)}, "
              f"max work-group {d.max_work_group_size}, fp64 {'yes' if d.fp64 else 'no'}")
        print(f"        {d.opencl_version}")
        # a device whose compiler refuses even a one-line kernel is listed, never chosen
        problem = runtime.device_build_problem(runtime.choose_device(d.selector))
        if problem is not None:
            problems.append(problem)
            print(f"        cannot compile OpenCL kernels here: {problem}")
    if not any("GPU" in d.device_type for d in devices):
        # a GPU driver that is installed but not registered is the usual reason (containers)
        advice = drivers.driver_advice(situation="No GPU among the OpenCL devices")
        if advice:
            print(advice)
    if any(runtime.UNKNOWN_CPU in p for p in problems):
        print(runtime.UNKNOWN_CPU_HINT)
    print(f"clholo uses * ({chosen_key[0]} / {chosen_key[1]}); choose another with "
          f"CLHOLO_DEVICE=P:D, a name substring or a type (cpu, gpu)")
    print(_fft_line(chosen))
    print(_tuning_line(chosen))
    return 0


def _fft_line(device) -> str:
    """How far the chosen device's FFT keeps a line of complex64 in one launch a pass
    (:func:`clholo.fft.plan_reach`)."""
    from clholo import fft

    reach = fft.plan_reach(fft.DeviceLimits.of(device))
    if "cpu strips" in reach:
        return (f"FFT on *: CPU strips, lines of up to {reach['cpu strips']} complex64 points "
                f"one launch a pass")
    kinds = [(k, w) for k, w in (("two buffers", "two local buffers"), ("in place", "in place"),
                                 ("split", "split")) if k in reach]
    longest = max((reach[k] for k, _ in kinds), default=0)
    return ("FFT on *: complex64 lines one launch a pass up to "
            + (f"{longest} points (" + ", ".join(f"{w} up to {reach[k]}" for k, w in kinds)
               + ")" if kinds else "none")
            + "; longer ones one launch a radix stage (a render's layer then takes four passes)")


def _tuning_line(device) -> str:
    """Whether the chosen device's GPU kernels run with a stored tuning (clholo tune)."""
    from clholo._version import __version__
    from clholo.host import tuning

    path = tuning.tuning_file()
    if path is None:
        return f"tuning: off ({tuning.TUNING_FILE_ENV}=off): the project's default settings"
    import pyopencl as cl

    entry = tuning.stored_entry(device)
    if entry is None and device.type & cl.device_type.CPU:
        return ("tuning: none needed for * (a CPU device runs clholo's CPU kernels, which the "
                "settings `clholo tune` measures do not change)")
    if entry is None:
        return (f"tuning: none stored for * in {path}; `clholo tune` measures the GPU kernels' "
                f"settings on it")
    changed = {k: v for k, v in dict(tuning.settings_for(device)).items()
               if tuning.SETTINGS[k].default != v}
    if entry.get("clholo") != __version__:
        return (f"tuning: stored for * in {path} by clholo {entry.get('clholo')}, not used by "
                f"{__version__}; run `clholo tune` again")
    return (f"tuning: stored for * in {path} ("
            + (", ".join(f"{k}={v}" for k, v in changed.items()) or "the defaults")
            + "); `clholo tune --show` for details")
