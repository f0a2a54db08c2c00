"""Every kernel clholo launches is enqueued under the one launch lock (``runtime._launch_lock``).

Kernel objects carry their arguments, and both clholo's (``runtime.get_kernel``) and
pyopencl's own array kernels (``a += b``, ``fill``) are one object per context and operation:
a launch whose arguments are set and enqueued outside the lock can run another thread's
arguments (a wrong result, silently). The tests here watch every ``enqueue_nd_range_kernel``
call of a wide set of workflows and name any that clholo's code makes without the lock."""

import os
import traceback

import numpy as np
import pyopencl as cl
import pyopencl._cl as _cl
import pyopencl.array as cla
import pytest

import clholo
from clholo.host import runtime

from conftest import random_complex

_OURS = tuple(os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), d)
              + os.sep for d in ("clholo", "host", "tools"))
_HOST = os.path.dirname(os.path.abspath(runtime.__file__)) + os.sep


def _caller() -> str:
    """The innermost frame of clholo's code that led to this launch ("" where none did)."""
    for frame in reversed(traceback.extract_stack()[:-2]):
        path = os.path.abspath(frame.filename)
        if path.startswith(_OURS) or path.startswith(_HOST):
            return f"{os.path.basename(path)}:{frame.lineno} {frame.name}"
    return ""


class _Found(list):
    seen = 0


@pytest.fixture
def unlocked(monkeypatch):
    """The launches clholo made without the launch lock, as "file:line function"; counts every
    launch in ``unlocked.seen``."""
    real = _cl.enqueue_nd_range_kernel
    found = _Found()

    def watched(*args, **kwargs):
        where = _caller()
        if where:
            found.seen += 1
            if not runtime._launch_lock._is_owned():
                found.append(where)
        return real(*args, **kwargs)

    # pyopencl's kernels call _cl.enqueue_nd_range_kernel; clholo calls it through pyopencl
    monkeypatch.setattr(_cl, "enqueue_nd_range_kernel", watched)
    monkeypatch.setattr(cl, "enqueue_nd_range_kernel", watched)
    return found


@pytest.fixture
def fill_kernel_zeros(monkeypatch):
    """pyopencl zeroes a new array with a fill command, except on NVIDIA for buffers of 2 GiB
    or more, where it launches its fill kernel: that path, on every size."""
    def zero_fill(self, queue=None, wait_for=None):
        if self.size:
            self.fill(np.zeros((), self.dtype), queue=queue or self.queue, wait_for=wait_for)

    monkeypatch.setattr(cla.Array, "_zero_fill", zero_fill)


def _mpi(rng, L=3, H=16, W=24, C=3):
    return clholo.MPI(rng.uniform(0.05, 1, (L, H, W, C)).astype(np.float32),
                      rng.uniform(0.05, 0.95, (L, H, W)).astype(np.float32),
                      np.linspace(1e-3, 3e-3, L))


OPTICS = clholo.Optics(pitch=8e-6, wavelengths=(638e-9, 520e-9, 450e-9))


def _check(unlocked, at_least=1):
    assert unlocked.seen >= at_least, "the workflow launched nothing: the watch saw nothing"
    assert not unlocked, (f"{len(unlocked)} launch(es) outside the launch lock, first at "
                          f"{sorted(set(unlocked))}")


@pytest.mark.parametrize("variant", ["cpu", "gpu"])
@pytest.mark.parametrize("method", ["mpi", "rgbd"])
def test_render_and_simulate(queue, rng, unlocked, fill_kernel_zeros, method, variant):
    from clholo.host.scheduler import HologramRenderer

    mpi = _mpi(rng)
    holo = HologramRenderer(mpi, OPTICS, seed=3, queue=queue, variant=variant,
                            occlusion=(method == "mpi")).render(2)
    clholo.focal_stack(holo, OPTICS, [1e-3, 2e-3], queue=queue)
    clholo.views.pupil_view(holo, OPTICS, focus_depth=2e-3, angles_rad=[(0.0, 0.0)],
                            queue=queue)
    clholo.views.light_field(holo, OPTICS, window=8, queue=queue)
    _check(unlocked, at_least=10)


def test_encoders(queue, rng, unlocked, fill_kernel_zeros):
    from clholo.encode.dpac import dpac_encode
    from clholo.encode.quantize import DeviceQuantizer
    from clholo.encode.sgd import sgd_encode

    holo = random_complex(rng, (1, 3, 16, 24)).astype(np.complex64)
    phases = dpac_encode(holo, OPTICS, queue=queue)
    sgd_encode(holo, OPTICS, iterations=3, progress=False, queue=queue)
    DeviceQuantizer("linear", channels=3).enqueue(cla.to_device(queue, phases))[1].get()
    _check(unlocked, at_least=5)


def test_phase_retrieval_set_phase(queue, rng, unlocked, fill_kernel_zeros):
    from clholo.encode.sgd import slm_padded_shape
    from clholo.host.phase_retrieval import PhaseRetrieval

    optics = clholo.Optics(pitch=8e-6, wavelengths=(520e-9, 638e-9))
    target = cla.to_device(queue, random_complex(rng, (4, 16, 24)))
    eng = PhaseRetrieval(target, wavelengths=optics.wavelengths, pitch=optics.pitch, z=0.04,
                         padded=slm_padded_shape((16, 24), optics, 0.04), queue=queue)
    eng.step()
    eng.set_phase(rng.uniform(0, 2 * np.pi, (4, 16, 24)))
    eng.step()
    _check(unlocked, at_least=3)


def test_rpws_into_a_given_array(queue, rng, unlocked, fill_kernel_zeros):
    from clholo.baselines import rpws
    from clholo.host.rpws import RPWSRenderer

    K, H, W = 4, 16, 24
    xy = np.stack([rng.uniform(4, W - 4, K), rng.uniform(4, H - 4, K)], axis=1)
    conic = np.tile([1 / 9.0, 0.0, 1 / 9.0], (K, 1))
    prims = rpws.Primitives(xy, conic, rng.uniform(0.3, 0.9, K), rng.uniform(0.1, 1, (K, 2)),
                            np.sort(rng.uniform(1e-3, 3e-3, K)), np.full(K, 9.0), (H, W))
    optics = clholo.Optics(wavelengths=(638e-9, 450e-9))
    r = RPWSRenderer(prims, optics, seed=9, frames_per_batch=4, queue=queue)
    r.render(2)
    r.render(2, out=cla.empty(queue, (2, 2, H, W), np.complex64))
    _check(unlocked, at_least=4)


def test_the_watch_sees_a_launch_without_the_lock(queue, rng, unlocked):
    """The watch itself: a pyopencl ``+=`` run from a frame of clholo's code (code compiled
    under runtime.py's name) is named without the lock, and not with it."""
    a = cla.to_device(queue, rng.standard_normal(64).astype(np.float32))
    b = cla.to_device(queue, rng.standard_normal(64).astype(np.float32))
    namespace = {"a": a, "b": b}
    exec(compile("a += b", runtime.__file__, "exec"), namespace)  # a frame "in" runtime.py
    assert unlocked and unlocked[0].startswith("runtime.py")
    unlocked.clear()
    exec(compile("with lock:\n    a += b", runtime.__file__, "exec"),
         dict(namespace, lock=runtime.pyopencl_op()))
    assert not unlocked and unlocked.seen == 2
