"""Ray-optics references (clholo.rayoptics, kernels/rayoptics.cl): kernel against the NumPy
reference, geometry of the views, the incoherent focal slice, and Stereo Magnification's renders
of the twain MPI."""

import json

import numpy as np
import pytest

from clholo import MPI, Optics
from clholo import reference as ref
from clholo.rayoptics import (incoherent_focal_slice, orthographic_view, perspective_view,
                              pupil_directions, warp_over)
from tolerances import rel_l2, tol


def random_mpi(rng, L, H, W, C, *, depths=None):
    color = rng.uniform(0.05, 1.0, (L, H, W, C)).astype(np.float32)
    alpha = rng.uniform(0.05, 1.0, (L, H, W)).astype(np.float32)
    if depths is None:
        depths = np.sort(rng.uniform(1e-3, 6e-3, L))
    return MPI(color, alpha, depths)


def random_homographies(rng, C, V, L, H, W):
    """Shifts of a few pixels (some off the layer), mild scale, shear and perspective."""
    hom = np.zeros((C, V, L, 3, 3))
    hom[..., 0, 0] = rng.uniform(0.8, 1.25, (C, V, L))
    hom[..., 1, 1] = rng.uniform(0.8, 1.25, (C, V, L))
    hom[..., 0, 1] = rng.uniform(-0.1, 0.1, (C, V, L))
    hom[..., 1, 0] = rng.uniform(-0.1, 0.1, (C, V, L))
    hom[..., 0, 2] = rng.uniform(-0.4 * W, 0.4 * W, (C, V, L))
    hom[..., 1, 2] = rng.uniform(-0.4 * H, 0.4 * H, (C, V, L))
    hom[..., 2, 0] = rng.uniform(-2e-3, 2e-3, (C, V, L)) / W
    hom[..., 2, 1] = rng.uniform(-2e-3, 2e-3, (C, V, L)) / H
    hom[..., 2, 2] = 1.0
    return hom


@pytest.mark.parametrize("L,H,W,C,V", [(1, 5, 7, 1, 1), (3, 16, 9, 3, 2), (4, 33, 20, 2, 3),
                                       (5, 24, 64, 3, 1)])
@pytest.mark.parametrize("premultiplied", [True, False])
@pytest.mark.parametrize("shared", [False, True], ids=["maps-per-channel", "maps-shared"])
def test_kernel_matches_reference(queue, rng, L, H, W, C, V, premultiplied, shared):
    mpi = random_mpi(rng, L, H, W, C)
    hom = random_homographies(rng, 1 if shared else C, V, L, H, W)
    got = warp_over(mpi, hom[0] if shared else hom, premultiplied=premultiplied, queue=queue)
    want = ref.warp_over_mean(mpi.color, mpi.alpha, np.broadcast_to(hom, (C,) + hom.shape[1:]),
                              premultiplied=premultiplied)
    assert got.shape == (H, W, C) and got.dtype == np.float32
    t = tol("rayoptics", np.float32)
    assert rel_l2(got, want) <= t["rel_l2"]
    assert np.max(np.abs(got - want)) <= t["max_abs"]


def test_premultiplied_and_straight_differ_where_alpha_varies(queue, rng):
    # a half-pixel shift mixes neighbours: straight colour bleeds in from under low alpha
    mpi = random_mpi(rng, 2, 8, 8, 1)
    a = orthographic_view(mpi, 8e-6, angle_rad=(0.001, 0.0), premultiplied=True, queue=queue)
    b = orthographic_view(mpi, 8e-6, angle_rad=(0.001, 0.0), premultiplied=False, queue=queue)
    assert np.max(np.abs(a - b)) > 1e-3


def test_head_on_view_is_the_over_composite(queue, rng):
    mpi = random_mpi(rng, 4, 12, 10, 3)
    got = orthographic_view(mpi, 8e-6, queue=queue)
    np.testing.assert_allclose(got, mpi.over(), atol=2e-6)


def point_mpi(depths, H=21, W=31, spot=(10, 15)):
    """Transparent layers with one opaque white pixel on the last (farthest) layer."""
    L = len(depths)
    color = np.ones((L, H, W, 1), np.float32)
    alpha = np.zeros((L, H, W), np.float32)
    alpha[-1][spot] = 1.0
    return MPI(color, alpha, depths)


@pytest.mark.parametrize("axis", [0, 1])
def test_point_behind_focus_moves_with_the_angle(queue, axis):
    # a point 2 mm behind the focus, viewed at theta: (d - f) tan(theta) / p = +3 pixels along
    # +x (axis 0, columns) or +y (axis 1, rows); a point in front moves the other way
    p = 8e-6
    f, d = 3e-3, 5e-3
    theta = np.arctan(3 * p / (d - f))
    angle = (theta, 0.0) if axis == 0 else (0.0, theta)
    for depth, sign in ((d, +1), (f - (d - f), -1)):
        mpi = point_mpi([0.5e-3, depth])
        view = orthographic_view(mpi, p, angle_rad=angle, focus_depth=f, queue=queue)[..., 0]
        y, x = np.unravel_index(np.argmax(view), view.shape)
        moved = (x - 15, y - 10)
        want = (3 * sign, 0) if axis == 0 else (0, 3 * sign)
        assert moved == want, (depth, moved, want)
        assert view[y, x] == pytest.approx(1.0, abs=1e-5)


def test_near_layer_hides_the_far_one_at_every_view(queue):
    # an opaque near layer covering the frame: nothing of the far layer shows, whatever the angle
    H, W = 9, 11
    color = np.stack([np.full((H, W, 1), 0.25), np.full((H, W, 1), 1.0)]).astype(np.float32)
    alpha = np.ones((2, H, W), np.float32)
    mpi = MPI(color, alpha, [2e-3, 4e-3])
    view = orthographic_view(mpi, 8e-6, angle_rad=(0.004, -0.004), focus_depth=2e-3,
                             queue=queue)
    np.testing.assert_allclose(view, 0.25, atol=1e-6)


def opaque_plane(rng, depth, H=28, W=30):
    color = rng.uniform(0.05, 1.0, (1, H, W, 1)).astype(np.float32)
    return MPI(color, np.ones((1, H, W), np.float32), [depth])


def test_focal_slice_at_the_plane_is_the_plane(queue, rng):
    mpi = opaque_plane(rng, 4e-3)
    for pupil in ("square", "disc"):
        got = incoherent_focal_slice(mpi, Optics(wavelengths=(520e-9,)), 4e-3, pupil=pupil,
                                     queue=queue)
        np.testing.assert_allclose(got, mpi.color[0], atol=2e-6)


@pytest.mark.parametrize("pupil", ["square", "disc"])
def test_focal_slice_away_from_the_plane_blurs_by_the_pupil(queue, rng, pupil):
    # defocus delta with delta * tan(half) / p = 3.5 px: 7 samples per axis land on whole
    # pixels -3..3, so the slice is the plane convolved with the 7x7 square (or the disc of
    # radius 3.5 px) footprint of the pupil
    from scipy.ndimage import correlate

    p, half, depth = 8e-6, 0.02, 4e-3
    delta = 3.5 * p / np.tan(half)
    mpi = opaque_plane(rng, depth)
    got = incoherent_focal_slice(mpi, Optics(wavelengths=(520e-9,)), depth + delta,
                                 pupil_angle_rad=half, samples=7, pupil=pupil,
                                 queue=queue)[..., 0]
    i, j = np.mgrid[-3:4, -3:4]
    footprint = np.ones((7, 7)) if pupil == "square" else (i ** 2 + j ** 2 <= 3.5 ** 2) * 1.0
    want = correlate(mpi.color[0, ..., 0].astype(np.float64), footprint / footprint.sum(),
                     mode="constant")
    inner = (slice(3, -3), slice(3, -3))  # away from the zero border
    np.testing.assert_allclose(got[inner], want[inner], atol=3e-3)
    # and not the in-focus plane
    assert np.max(np.abs(got[inner] - mpi.color[0, ..., 0][inner])) > 0.1


def test_off_centre_pupil_shifts_the_blur(queue, rng):
    # a pupil centred at theta_c: the same box blur, moved by delta * tan(theta_c) / p = +2 px
    p, half, depth = 8e-6, 0.02, 4e-3
    delta = 3.5 * p / np.tan(half)
    theta_c = np.arctan(2 * p / delta)
    mpi = opaque_plane(rng, depth)
    optics = Optics(wavelengths=(520e-9,))
    centred = incoherent_focal_slice(mpi, optics, depth + delta, pupil_angle_rad=half,
                                     samples=7, queue=queue)[..., 0]
    moved = incoherent_focal_slice(mpi, optics, depth + delta, pupil_angle_rad=half, samples=7,
                                   pupil_center_rad=(0.0, theta_c), queue=queue)[..., 0]
    # the plane is in front of the focus: a pupil towards +y moves it up (smaller row)
    np.testing.assert_allclose(moved[4:-8, 4:-4], centred[6:-6, 4:-4], atol=1e-3)
    with pytest.raises(ValueError, match="beyond 90 degrees"):
        pupil_directions(0.5, 7, center_rad=(1.3, 0.0))


def test_focal_slice_default_pupil_is_per_channel(queue, rng):
    # blue's pupil (asin(450 nm / 16 um)) is smaller than red's: less blur of the same plane
    H, W = 24, 24
    c = rng.uniform(0.05, 1.0, (1, H, W, 1)).astype(np.float32)
    mpi = MPI(np.repeat(c, 2, axis=3), np.ones((1, H, W), np.float32), [2e-3])
    got = incoherent_focal_slice(mpi, Optics(wavelengths=(638e-9, 450e-9)), 2.4e-3, queue=queue)
    inner = (slice(8, -8), slice(8, -8))
    contrast = [np.std(got[inner + (k,)]) for k in range(2)]
    assert contrast[1] > contrast[0] * 1.05, contrast


def test_pupil_directions_sample_the_square_and_the_disc():
    sq = pupil_directions(0.03, 7, pupil="square")
    disc = pupil_directions(0.03, 7, pupil="disc")
    assert sq.shape == (49, 2) and disc.shape == (37, 2)
    assert np.max(np.abs(np.sin(sq))) == pytest.approx(np.sin(0.03) * 6 / 7)
    assert np.all(np.sum(np.sin(disc) ** 2, axis=1) <= np.sin(0.03) ** 2 + 1e-15)
    assert np.allclose(sq.mean(axis=0), 0.0) and [0.0, 0.0] in sq.tolist()


def test_perspective_view_geometry(queue):
    # sideways: a plane at depth d shifts by -fx tx / d; forward: it magnifies about (cx, cy)
    mpi = point_mpi([1.5, 2.0], H=41, W=41, spot=(26, 30))
    view = perspective_view(mpi, fx_pixels=100.0, translation=(0.08, -0.06, 0.0),
                            queue=queue)[..., 0]
    assert np.unravel_index(np.argmax(view), view.shape) == (26 + 3, 30 - 4)
    view = perspective_view(mpi, fx_pixels=100.0, translation=(0.0, 0.0, 1.0), queue=queue)[..., 0]
    # d / (d - tz) = 2: (30, 26) is (+10, +6) from the centre (20, 20) -> (+20, +12)
    assert np.unravel_index(np.argmax(view), view.shape) == (20 + 12, 20 + 20)


def test_bad_inputs_name_the_argument(queue, rng):
    mpi = random_mpi(rng, 2, 6, 6, 3)
    with pytest.raises(TypeError, match="mpi must be a clholo.MPI"):
        orthographic_view(mpi.color, 8e-6)
    with pytest.raises(ValueError, match=r"angle_rad\[0\]"):
        orthographic_view(mpi, 8e-6, angle_rad=(2.0, 0.0))
    with pytest.raises(TypeError, match="angle_rad must be a pair"):
        orthographic_view(mpi, 8e-6, angle_rad=0.1)
    with pytest.raises(ValueError, match="pitch"):
        orthographic_view(mpi, 8.0)
    with pytest.raises(ValueError, match="3 colour channel"):
        incoherent_focal_slice(mpi, Optics(wavelengths=(520e-9,)), 1e-3)
    with pytest.raises(ValueError, match="pupil must be one of"):
        incoherent_focal_slice(mpi, Optics(), 1e-3, pupil="hexagon")
    with pytest.raises(ValueError, match="samples must be >= 1"):
        incoherent_focal_slice(mpi, Optics(), 1e-3, samples=0)
    with pytest.raises(ValueError, match="pupil_angle_rad"):
        incoherent_focal_slice(mpi, Optics(), 1e-3, pupil_angle_rad=[0.01, 0.02])
    with pytest.raises(ValueError, match="homographies must have shape"):
        warp_over(mpi, np.eye(3)[None].repeat(3, axis=0))
    with pytest.raises(ValueError, match="tz must be smaller"):
        perspective_view(mpi, fx_pixels=100.0, translation=(0, 0, 1.0))
    with pytest.raises(ValueError, match="depths must be 2"):
        perspective_view(mpi, fx_pixels=100.0, translation=(0.1, 0, 0), depths=[3.0, 1.0])
    with pytest.raises(ValueError, match="fx_pixels"):
        perspective_view(mpi, fx_pixels=-1.0, translation=(0.1, 0, 0))


# --- Stereo Magnification's own renders of the twain MPI ------------------------------------------

def psnr(a, b):
    return 10 * np.log10(1.0 / np.mean((np.asarray(a, np.float64) - b) ** 2))


@pytest.fixture(scope="module")
def twain(shared_data):
    from clholo.io.images import read_image

    folder = shared_data / "twain-mpi"
    meta = json.loads((folder / "mpi.json").read_text())
    # The source composites its stored values (sRGB codes / 255, straight colour, linear alpha,
    # the farthest alpha taken as 1); so do we, to reproduce its renders (docs/inputs.md, "The
    # twain check", does the same through read_mpi and an exact re-encoding).
    layers = np.stack([read_image(folder / name)[0] for name in meta["layers"]])
    alpha = layers[..., 3].copy()
    alpha[0] = 1.0  # layer_00 is the farthest
    scene = MPI(layers[..., :3], alpha, meta["depths"])  # sorted nearest first
    # Placed in metres for a hologram, the planes keep their scene depths for the camera.
    return folder, meta, scene.placed(2e-3, 6e-3, spacing="inverse"), scene.depths


@pytest.mark.parametrize("name,multiple,border,floor_db", [
    ("render_04_0.0.png", 0.0, 0, 50.0),
    ("render_00_-2.0.png", -2.0, 32, 40.0),
    ("render_08_2.0.png", 2.0, 32, 40.0),
])
def test_twain_renders_are_reproduced(queue, twain, name, multiple, border, floor_db):
    from clholo.io.images import read_image

    folder, meta, mpi_m, scene_depths = twain
    assert meta["renders"][name] == multiple
    fx = meta["intrinsics"]["fx_pixels"]
    # the nearest plane (depth 1) moves by fx * 2 * xoffset = 29 px: keep 32 columns off each side
    view = perspective_view(mpi_m, fx_pixels=fx, translation=(multiple * meta["xoffset"], 0, 0),
                            depths=scene_depths, premultiplied=False, queue=queue)
    render, _ = read_image(folder / name)
    got = view[8:776, 8:1032][:, border:1024 - border]
    want = render[..., :3][:, border:1024 - border]
    score = psnr(got, want)
    print(f"{name}: {score:.2f} dB")
    assert score >= floor_db
    if multiple:
        # the move is visible: the source's head-on render is far from this one
        still, _ = read_image(folder / "render_04_0.0.png")
        assert psnr(still[..., :3][:, border:1024 - border], want) < score - 10
