"""MPI -> hologram on the device: against the reference, against physics, and its API."""

import numpy as np
import pyopencl.array as cla
import pytest

import clholo
from clholo import reference as ref

from tolerances import rel_l2, tol

OPTICS = clholo.Optics()


def _random_mpi(rng, L=8, H=256, W=384, C=3, near=1e-3, far=4e-3):
    return clholo.MPI(rng.random((L, H, W, C)), rng.random((L, H, W)),
                      np.linspace(near, far, L))


@pytest.mark.parametrize("pad", [2, "auto"])
def test_hologram_matches_reference(queue, rng, pad):
    mpi = _random_mpi(rng)
    seed = int(rng.integers(0, 2 ** 40))
    got = clholo.render_hologram(mpi, OPTICS, frames=2, seed=seed, pad=pad, queue=queue)
    padded = clholo.hologram_padded_shape(mpi, OPTICS, pad=pad)
    want = ref.mpi_hologram(mpi.color, mpi.alpha, mpi.depths, wavelengths=OPTICS.wavelengths,
                            pitch=OPTICS.pitch, frames=2, seed=seed, pad=padded)
    assert got.shape == (2, 3, 256, 384) and got.dtype == np.complex64
    assert rel_l2(got, want) <= tol("hologram", np.float32)["rel_l2"]


def test_same_seed_same_bits_other_seed_other_phases(queue, rng):
    mpi = _random_mpi(rng, L=3, H=64, W=64)
    a = clholo.render_hologram(mpi, OPTICS, frames=2, seed=11, queue=queue)
    b = clholo.render_hologram(mpi, OPTICS, frames=2, seed=11, queue=queue)
    c = clholo.render_hologram(mpi, OPTICS, frames=2, seed=12, queue=queue)
    assert a.view(np.uint32).tobytes() == b.view(np.uint32).tobytes()
    assert np.mean(a != c) > 0.99
    assert np.mean(a[0] != a[1]) > 0.99  # frames have fresh phases


def test_batching_and_streaming_give_the_same_frames(queue, rng):
    mpi = _random_mpi(rng, L=3, H=48, W=80, C=2)
    optics = clholo.Optics(wavelengths=(638e-9, 450e-9))
    full = clholo.render_hologram(mpi, optics, frames=5, seed=3, queue=queue)
    for per_batch in (1, 2, 5):
        got = np.empty_like(full)
        seen = []
        for t0, frames in clholo.iter_hologram_frames(mpi, optics, frames=5, seed=3,
                                                      frames_per_batch=per_batch, queue=queue):
            got[t0:t0 + len(frames)] = frames
            seen.append(t0)
        assert seen == list(range(0, 5, per_batch))
        np.testing.assert_array_equal(got, full)
    out = cla.empty(queue, full.shape, np.complex64)
    res = clholo.render_hologram(mpi, optics, frames=5, seed=3, out=out, queue=queue)
    assert res is out
    np.testing.assert_array_equal(out.get(), full)


def test_focal_stack_matches_reference(queue, rng):
    mpi = _random_mpi(rng, L=4, H=64, W=96, C=2)
    optics = clholo.Optics(wavelengths=(638e-9, 520e-9))
    holo = clholo.render_hologram(mpi, optics, frames=3, seed=1, queue=queue)
    depths = [1e-3, 2.5e-3]
    got = clholo.focal_stack(holo, optics, depths, queue=queue)
    from clholo.propagation import device_padded_shape

    padded = device_padded_shape((64, 96), -np.array(depths), wavelength=optics.wavelengths,
                                 pitch=optics.pitch)
    want = ref.focal_stack(holo, depths, wavelengths=optics.wavelengths, pitch=optics.pitch,
                           pad=padded)
    assert got.shape == (2, 2, 64, 96) and got.dtype == np.float32
    assert rel_l2(got, want) <= tol("propagate", np.float32)["rel_l2"] * 2


def _texture(rng, n):
    from scipy.ndimage import gaussian_filter

    t = gaussian_filter(rng.random((n, n)), 3)
    return (0.2 + 0.8 * (t - t.min()) / (t.max() - t.min())).astype(np.float32)


def test_opaque_layer_refocuses_to_its_intensity(queue, rng):
    # One opaque layer at d: the focal slice at d returns its intensity away from the borders
    # (the light that left the 256x256 window is gone near them).
    d, n = 2e-3, 256
    optics = clholo.Optics(pitch=8e-6, wavelengths=(520e-9,))
    c = _texture(rng, n)
    mpi = clholo.MPI(c[None, :, :, None], np.ones((1, n, n)), [d])
    holo = clholo.render_hologram(mpi, optics, frames=4, seed=0, pad=2, queue=queue)
    slice_d = clholo.focal_stack(holo, optics, [d], pad=2, queue=queue)[0, 0]
    inner = (slice(48, -48), slice(48, -48))
    mae = np.mean(np.abs(slice_d[inner] - c[inner]))
    assert mae <= 1e-3 * c.max()
    # and it is in focus only there: 1 mm off, the random phase scrambles the texture
    off = clholo.focal_stack(holo, optics, [d - 1e-3], pad=2, queue=queue)[0, 0]
    assert np.mean(np.abs(off[inner] - c[inner])) > 20 * mae


def test_occlusion_black_square_in_front_of_texture(queue, rng):
    n, p = 256, 8e-6
    optics = clholo.Optics(pitch=p, wavelengths=(520e-9,))
    d_front, d_back = 2e-3, 4e-3
    back = np.full((n, n), 0.8, np.float32) * _texture(rng, n) / _texture(rng, n).max()
    square = np.zeros((n, n), bool)
    square[96:160, 96:160] = True
    color = np.stack([np.zeros((n, n), np.float32), back])[..., None]
    alpha = np.stack([square.astype(np.float32), np.ones((n, n), np.float32)])
    mpi = clholo.MPI(color, alpha, [d_front, d_back])
    T = 16
    holo = clholo.render_hologram(mpi, optics, frames=T, seed=2, pad=2, queue=queue)
    at_back, at_front = clholo.focal_stack(holo, optics, [d_back, d_front], pad=2,
                                           queue=queue)[:, 0]

    # RGB-D-style baseline: each masked layer propagated on its own and summed, no occlusion
    visible_back = back * ~square
    rgbd = np.zeros((T, 1, n, n), np.complex64)
    for t in range(T):
        phi = ref.random_phase((n, n), seed=99, frame=t, colour=0, layer=1)
        rgbd[t, 0] = ref.propagate(np.sqrt(visible_back) * np.exp(1j * phi), d_back,
                                   wavelength=520e-9, pitch=p, pad=2)
    rgbd_front = clholo.focal_stack(rgbd, optics, [d_front], pad=2, queue=queue)[0, 0]

    # the spread of the 2 mm gap: light from the back layer reaches ~ d tan(theta) / p px
    spread = int(np.ceil(2e-3 * np.tan(np.arcsin(520e-9 / (2 * p))) / p))  # ~9 px
    hidden = (slice(96 + spread + 2, 160 - spread - 2),) * 2
    # focused on the back layer, the hidden region stays dark apart from the blurred edge
    assert at_back[hidden].mean() < 0.05 * back.mean()
    # focused on the square: its edge is sharp, MPI keeps the square dark right up to the edge,
    # while the RGB-D sum lets the back layer's defocused light spill over it
    rim = np.zeros((n, n), bool)
    rim[98:158, 98:158] = True
    rim[104:152, 104:152] = False  # a 6-pixel band just inside the square's edge
    assert at_front[rim].mean() < 0.2 * rgbd_front[rim].mean()
    outside = np.zeros((n, n), bool)
    outside[84:172, 84:172] = True
    outside[90:166, 90:166] = False  # 6-pixel band just outside
    assert at_front[outside].mean() > 5 * at_front[hidden].mean()


def test_render_bad_input(queue, rng):
    mpi = _random_mpi(rng, L=2, H=16, W=16, C=3)
    with pytest.raises(ValueError, match="wavelength"):
        clholo.render_hologram(mpi, clholo.Optics(wavelengths=(520e-9,)), frames=1,
                               queue=queue)
    with pytest.raises(ValueError, match="frames"):
        clholo.render_hologram(mpi, OPTICS, frames=0, queue=queue)
    with pytest.raises(ValueError, match="seed"):
        clholo.render_hologram(mpi, OPTICS, frames=1, seed=-3, queue=queue)
    with pytest.raises(TypeError, match="clholo.MPI"):
        clholo.render_hologram(mpi.color, OPTICS, queue=queue)
    with pytest.raises(MemoryError, match="budget"):
        clholo.HologramRenderer(mpi, OPTICS, memory_budget=1000, queue=queue)


def test_mpi_validation():
    good = dict(color=np.zeros((2, 4, 4, 3)), alpha=np.zeros((2, 4, 4)), depths=[1e-3, 2e-3])
    for change, match in [
        ({"depths": [2e-3, 2e-3]}, "distinct"),
        ({"depths": [-1e-3, 2e-3]}, "> 0"),
        ({"depths": [np.nan, 2e-3]}, "depths contains"),
        ({"alpha": np.full((2, 4, 4), 1.5)}, r"alpha must lie in \[0, 1\]"),
        ({"color": np.full((2, 4, 4, 3), -0.1)}, "color must be linear"),
        ({"alpha": np.zeros((2, 4, 5))}, "alpha shape"),
        ({"depths": [1e-3]}, "depths has 1"),
        ({"color": np.zeros((2, 4, 4, 3), complex)}, "real numeric"),
    ]:
        args = dict(good)
        args.update(change)
        with pytest.raises((ValueError, TypeError), match=match):
            clholo.MPI(**args)
    # unsorted depths are sorted, layers along with them
    color = np.zeros((2, 4, 4, 1))
    color[1] = 0.5
    m = clholo.MPI(color, np.ones((2, 4, 4)), [3e-3, 1e-3])
    assert m.depths.tolist() == [1e-3, 3e-3] and m.color[0].max() == 0.5
