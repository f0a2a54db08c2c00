"""One mistake, one warning, at the user's line: a far distance (a :class:`DepthWarning`) or
splats the camera cannot see (a :class:`SplatCullWarning`) warn once per call, pointing at the
line that called the public function, whatever route inside clholo reached the check (a fixed
``stacklevel`` pointed into ``clholo/encode/dpac.py`` for ``dpac_encode``; a CPU render warned a
second time from the transfer-function cache; a display loop's encoder warned at every batch)."""

import warnings

import numpy as np
import pytest

import clholo
from clholo.scene import MPI, Optics
from clholo.validate import DepthWarning, warn_at_caller

OPTICS = Optics(pitch=8e-6, wavelengths=(638e-9, 520e-9))


def _mpi(depths_m):
    rng = np.random.default_rng(7)
    L = len(depths_m)
    return MPI(rng.random((L, 16, 24, 2)).astype(np.float32),
               rng.uniform(0.2, 1.0, (L, 16, 24)).astype(np.float32), depths_m)


def _holograms():
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # millimetres: no warning of its own
        return clholo.render_hologram(_mpi([1e-3, 2e-3, 3e-3]), OPTICS, frames=2)


def _caught(call, category):
    with warnings.catch_warnings(record=True) as got:
        warnings.simplefilter("always")
        call()
    return [w for w in got if issubclass(w.category, category)]


def _encoder_twice():
    from clholo.host.display_loop import dpac_encoder

    encoder = dpac_encoder(OPTICS, z_slm=2.0)  # the user's line: the one warning
    fields = _holograms()
    encoder(fields)
    encoder(fields)  # a batch later: the distance was checked once


def _renderer_twice():
    from clholo.hologram import HologramRenderer

    renderer = HologramRenderer(_mpi([1.0, 2.0, 3.0]), OPTICS)  # the user's line
    renderer.render(2)
    renderer.render(2)


# name -> (a call whose far distance is on this file's lines, the line's text that must warn)
FAR_CALLS = {
    "render_hologram": lambda: clholo.render_hologram(_mpi([1.0, 2.0, 3.0]), OPTICS, frames=2),
    "iter_hologram_frames": lambda: list(clholo.iter_hologram_frames(_mpi([1.0, 2.0]), OPTICS,
                                                                     frames=2)),
    "HologramRenderer, two renders": _renderer_twice,
    "propagate": lambda: clholo.propagate(np.ones((16, 24), np.complex64), 3.0,
                                          wavelength=520e-9, pitch=8e-6),
    "focal_stack": lambda: clholo.focal_stack(_holograms(), OPTICS, [1e-3, 2.5]),
    "dpac_encode": lambda: clholo.encode.dpac.dpac_encode(_holograms(), OPTICS, z_slm=2.0),
    "sgd_encode": lambda: clholo.encode.sgd.sgd_encode(_holograms(), OPTICS, z_slm=2.0,
                                                       iterations=1, progress=False),
    "dpac_encoder, two batches": _encoder_twice,
    "pupil_view": lambda: clholo.views.pupil_view(_holograms(), OPTICS, focus_depth=2.0,
                                                  angles_rad=[(0.0, 0.0)]),
    "incoherent_focal_slice": lambda: clholo.rayoptics.incoherent_focal_slice(
        _mpi([1e-3, 2e-3]), OPTICS, 2.0),
}


@pytest.mark.parametrize("name", list(FAR_CALLS))
def test_a_far_distance_warns_once_at_the_users_line(name):
    far = _caught(FAR_CALLS[name], DepthWarning)
    assert [w.filename for w in far] == [__file__], \
        [(w.filename, w.lineno, str(w.message)) for w in far]
    assert "more than 1 m" in str(far[0].message)


def test_splats_out_of_view_warn_once_at_the_users_line(tmp_path):
    """``load_scene`` reaches the cull check through the splat reader and the MPI builder:
    the warning still names the user's line, not clholo's."""
    from clholo.io import Camera, SplatCullWarning, load_scene

    from test_mistakes_io import _ply, _table

    table = _table()
    table[:2, 2] = -1.0  # two of six behind the camera
    path = _ply(tmp_path / "s.ply", table)
    got = _caught(lambda: load_scene(path, layers=2, camera=Camera(32, 24, 30.0, 30.0)),
                  SplatCullWarning)
    assert [w.filename for w in got] == [__file__], [(w.filename, w.lineno) for w in got]
    assert "2 of 6 splats" in str(got[0].message)


def test_warn_at_caller_skips_every_frame_of_clholo():
    """From a function in clholo's folder (its code compiled under a clholo file name, as a
    check nested in clholo is), the warning lands on this file's calling line."""
    import os

    folder = os.path.dirname(clholo.__file__)
    inner = compile("def inner(warn):\n    warn('far', UserWarning)\n",
                    os.path.join(folder, "validate.py"), "exec")
    outer = compile("def outer(inner, warn):\n    inner(warn)\n",
                    os.path.join(folder, "hologram.py"), "exec")
    space = {}
    exec(inner, space)
    exec(outer, space)
    with warnings.catch_warnings(record=True) as got:
        warnings.simplefilter("always")
        space["outer"](space["inner"], warn_at_caller)
    assert [(w.filename, str(w.message)) for w in got] == [(__file__, "far")]
