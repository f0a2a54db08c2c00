"""Shared fixtures: OpenCL devices (parametrized), queues, random generators, shared data."""

import contextlib
import os
import shutil
import subprocess
import time
from pathlib import Path

import numpy as np
import pytest

import pyopencl as cl

from clholo.host import runtime

# A tuning stored on this machine (`clholo tune`, clholo.tuning) would change which forms of the
# GPU kernels the tests' plans build; tests that need a tuning file set their own.
os.environ["CLHOLO_TUNING_FILE"] = "off"


def _test_devices():
    """Devices to run kernel tests on: CLHOLO_TEST_DEVICES ("all" or comma-separated
    selectors), else the one device clholo would choose."""
    spec = os.environ.get("CLHOLO_TEST_DEVICES", "")
    try:
        if spec.strip().lower() == "all":
            # every device that compiles: one whose compiler does not know this CPU (PyPI's
            # PoCL on an AMD Zen 5) is left out, and the header says so
            chosen = [(i.selector, runtime.choose_device(i.selector))
                      for i in runtime.list_devices()]
            return [(s, d) for s, d in chosen if runtime.device_build_problem(d) is None]
        if spec.strip():
            return [(s.strip(), runtime.choose_device(s.strip())) for s in spec.split(",")]
        dev = runtime.choose_device()
        return [(dev.name.strip()[:24], dev)]
    except runtime.NoDeviceError as exc:  # pragma: no cover - CI always has PoCL
        pytest.exit(f"no OpenCL device for the tests: {exc}", returncode=3)


def unavailable(msg: str):
    """Skip a test that needs what this environment lacks (an installed ``clholo``, a test
    extra, a tool), saying what and how to get it; with ``CI=true`` (``.ci/run``) fail instead,
    so that a missing install step cannot pass unseen there. (The GPU test machine runs the
    suite from a checkout: nothing is installed there.)"""
    if os.environ.get("CI", "").lower() == "true":
        pytest.fail("CI=true but " + msg)
    pytest.skip(msg)


def require_module(name: str, extra: str):
    """The module ``name``, or :func:`unavailable` naming the extra that brings it."""
    try:
        return __import__(name)
    except ImportError:
        unavailable(f"{name} is not installed (pip install -e '.[{extra}]')")


def require_installed():
    """The installed distribution's metadata: tests of the entry point and the version need
    ``clholo`` installed (``pip install -e .``), not only importable from a checkout."""
    from importlib.metadata import PackageNotFoundError, distribution

    try:
        return distribution("clholo")
    except PackageNotFoundError:
        unavailable("clholo is importable but not installed (run from a checkout through "
                    "PYTHONPATH): pip install -e '.[pocl,test]'")


def start_private_xvfb(screen: str = "96x40x24", *, start_s: float = 10.0):
    """A private Xvfb server: ``(process, display)``, the display ``":N"`` a free number Xvfb
    picks itself through ``-displayfd``; the caller ends the process (the tests of a display
    server that goes away kill it mid-run).

    Skips (``pytest.skip``) where GLFW or PyOpenGL (the ``slm`` extra) or Xvfb is absent, or
    the server has not said its number within ``start_s`` seconds: the number is read without
    blocking, so a server that never answers cannot hang the test. ``DISPLAY`` is left alone:
    the caller sets it where it needs it.
    """
    pytest.importorskip("glfw", reason="glfw is not installed (pip install 'clholo[slm]')")
    pytest.importorskip("OpenGL", reason="PyOpenGL is not installed (pip install 'clholo[slm]')")
    xvfb = shutil.which("Xvfb")
    if xvfb is None:
        pytest.skip("Xvfb is absent (apt-get install xvfb): no window system to test the SLM "
                    "window on")
    read_fd, write_fd = os.pipe()
    proc = subprocess.Popen([xvfb, "-displayfd", str(write_fd), "-screen", "0", screen,
                             "-nolisten", "tcp"], pass_fds=(write_fd,),
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    os.close(write_fd)
    try:
        os.set_blocking(read_fd, False)
        number, deadline = b"", time.monotonic() + start_s
        while not number.endswith(b"\n") and time.monotonic() < deadline:
            try:
                chunk = os.read(read_fd, 16)
            except BlockingIOError:
                time.sleep(0.05)
                continue
            if not chunk:
                break
            number += chunk
    finally:
        os.close(read_fd)
    if not number.strip() or proc.poll() is not None:
        _end(proc)
        pytest.skip("Xvfb did not start")
    return proc, ":" + number.decode().strip()


def _end(proc) -> None:
    proc.terminate()
    try:
        proc.wait(timeout=10)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait(timeout=10)


@contextlib.contextmanager
def private_xvfb(screen: str = "96x40x24", *, start_s: float = 10.0):
    """A private Xvfb server for the SLM window's tests (:func:`start_private_xvfb`): yields
    its display; the server is ended at the end."""
    proc, display = start_private_xvfb(screen, start_s=start_s)
    try:
        yield display
    finally:
        _end(proc)


_DEVICES = None
_CONTEXTS = {}


def pytest_report_header(config):
    """Which devices the kernel tests run on, and any installed device left out because its
    compiler cannot build a kernel here."""
    global _DEVICES
    if _DEVICES is None:
        _DEVICES = _test_devices()
    names = ", ".join(f"{i} ({d.platform.name.strip()})" for i, d in _DEVICES)
    lines = [f"clholo test devices: {names}"]
    for info in runtime.list_devices():
        problem = runtime.device_build_problem(runtime.choose_device(info.selector))
        if problem is not None:
            lines.append(f"clholo: left out {info.selector} {info.platform_name} / "
                         f"{info.device_name}: {problem}")
    return lines


def pytest_generate_tests(metafunc):
    global _DEVICES
    if "cl_device" in metafunc.fixturenames:
        if _DEVICES is None:
            _DEVICES = _test_devices()
        metafunc.parametrize("cl_device", [d for _, d in _DEVICES],
                             ids=[i for i, _ in _DEVICES], scope="session")


@pytest.fixture(scope="session")
def cl_context(cl_device):
    """One context per device for the whole run: the default queue's where it is on this device,
    so that library calls made without a queue and tests that pass one share every compiled
    program (programs are memoized per context: one build per program per run)."""
    ctx = _CONTEXTS.get(cl_device.int_ptr)
    if ctx is None:
        default = runtime.get_queue()
        ctx = default.context if default.device == cl_device else cl.Context([cl_device])
        _CONTEXTS[cl_device.int_ptr] = ctx
    return ctx


@pytest.fixture(scope="session")
def queue(cl_context, cl_device):
    """The default queue itself on the default device (one in-order queue, as in a user's
    process), else a queue of its own."""
    default = runtime.get_queue()
    if default.context == cl_context:
        return default
    return runtime.create_queue(cl_context, cl_device)


@pytest.fixture
def rng(request):
    """A fresh generator per test, seeded from the test's name so failures reproduce."""
    import zlib

    return np.random.default_rng(zlib.crc32(request.node.nodeid.encode()))


SHARED = Path(__file__).resolve().parents[1].parent / "shared"


@pytest.fixture(scope="session")
def shared_data():
    """``../shared/data`` beside the checkout; tests that need it skip where it is absent."""
    path = Path(os.environ.get("CLHOLO_SHARED_DATA", SHARED / "data"))
    if not path.is_dir():
        pytest.skip(f"shared data folder {path} is absent (set CLHOLO_SHARED_DATA to point at "
                    f"the repository's shared/data)")
    return path


def random_complex(rng, shape, dtype=np.complex64):
    """Random complex values, never zeros: standard normal real and imaginary parts."""
    return (rng.standard_normal(shape) + 1j * rng.standard_normal(shape)).astype(dtype)


_FFT_SNIPPET_HEAD = """import dataclasses, sys
import numpy as np
import pyopencl.array as cla
from clholo import fft as F
from clholo import reference as ref
from clholo.host import runtime
from clholo.host.tuning import SETTINGS
real_of = F.DeviceLimits.of
F.DeviceLimits.of = classmethod(lambda cls, dev: dataclasses.replace(
    real_of(dev), local_mem_size={local}, max_work_group_size={wg}, kernel_local=()))
F.runtime.kernel_local_bytes = lambda knl, dev: 0
q = runtime.get_queue()
rng = np.random.default_rng({seed})
def rnd(s):
    return (rng.standard_normal(s) + 1j * rng.standard_normal(s)).astype(np.complex64)
def rel(a, b):
    return float(np.linalg.norm(a - b) / np.linalg.norm(b))
errs = []
def check_columns(n, ncols, rows, define, held):
    # an FFT of (n, ncols) both ways and a column round trip of (2, rows, ncols) with a
    # multiply, on the plan that `define` names, `held` columns a group
    plan = F.FFTPlan((n, ncols), np.complex64, queue=q, variant="gpu")
    rt = F.RoundTripPlan((2, rows, ncols), n, axis="cols", mid_n=rows - 4, queue=q,
                         variant="gpu")
    (cols,) = [p for p in plan.geometry.passes if p.axis == "cols"]
    for p in (cols, rt.geometry.pass_):
        assert dict(p.defines).get(define) and p.launches[0].extra[0] == held, p
    x = rnd((n, ncols))
    errs.append(rel(plan.execute_host(x), np.fft.fft2(x.astype(np.complex128))))
    errs.append(rel(plan.execute_host(x, inverse=True), np.fft.ifft2(x.astype(np.complex128))))
    x, m = rnd((2, rows, ncols)), rnd((n, ncols))
    got = rt.execute(cla.to_device(q, x), multiply=cla.to_device(q, m)).get()
    errs.append(rel(got, ref.round_trip(x, n, axis="cols", multiply=m, mid_n=rows - 4)))
"""
_FFT_SNIPPET_TAIL = """
print("device", q.device.name, "errors", errs)
sys.exit(0 if max(errs) < 1e-5 else 1)
"""


def fft_snippet(body: str, *, local: int, wg: int, seed: int) -> str:
    """A Python snippet for :func:`run_snippet_under_oclgrind`: FFT plans see ``local`` bytes
    of local memory and ``wg`` work-items (kernels that hold none themselves); ``body`` (at
    any indentation) has ``F``, ``ref``, ``cla``, ``SETTINGS``, ``real_of``, the queue ``q``,
    ``rnd(shape)`` (random complex64), ``rel(got, want)``, ``check_columns(n, ncols, rows,
    define, held)`` (column FFTs and round trips on a plan, against NumPy and the reference)
    and appends errors to ``errs``; the
    snippet fails unless every one is below 1e-5."""
    import textwrap

    return (_FFT_SNIPPET_HEAD.format(local=local, wg=wg, seed=seed) + textwrap.dedent(body)
            + _FFT_SNIPPET_TAIL)


def run_snippet_under_oclgrind(snippet: str, *, timeout: int = 600) -> None:
    """Run the Python ``snippet`` on Oclgrind's simulated device with data races on, and fail
    on a non-zero exit, a run that did not reach the simulator (the snippet prints its
    device's name) or any Oclgrind report; :func:`unavailable` where oclgrind is not
    installed."""
    import sys

    from clholo import oclgrind

    if oclgrind.find_icd() is None:
        unavailable("oclgrind is not installed: `apt-get install oclgrind`")
    run = oclgrind.run_under_oclgrind([sys.executable, "-c", snippet], data_races=True,
                                      timeout=timeout,
                                      env={**os.environ, "CLHOLO_DEVICE": "oclgrind"})
    assert run.returncode == 0, run.stdout + run.stderr[-3000:]
    assert "Oclgrind" in run.stdout, run.stdout  # it ran on the simulator
    assert run.clean, run.summary()


@pytest.fixture
def built_defines(monkeypatch):
    """Every FFT program built while the test runs: its defines, the extra ones included."""
    from clholo import fft as F

    seen = []
    real = F._pass_program

    def record(context, p, callbacks, layout, extra_defines=None):
        seen.append({**dict(p.defines), **(extra_defines or {})})
        return real(context, p, callbacks, layout, extra_defines)

    monkeypatch.setattr(F, "_pass_program", record)
    return seen
