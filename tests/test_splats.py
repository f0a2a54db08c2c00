"""3D Gaussian splats: PLY reading, EWA projection, slab rasterisation (OpenCL and NumPy)."""

import numpy as np
import pytest

from clholo.io import Camera, Gaussians, read_ply, splats_to_mpi
from clholo.io.splats import (SH_C0, project, rasterize_slabs, rasterize_slabs_reference,
                              slab_edges)
from tolerances import rel_l2, tol

PROPS = (["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"]
         + [f"f_rest_{i}" for i in range(45)]
         + ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"])


def write_ply(path, table, props=PROPS, fmt="binary_little_endian"):
    """A PLY in the original 3DGS layout (float32 per property)."""
    head = ["ply", f"format {fmt} 1.0", f"element vertex {len(table)}"]
    head += [f"property float {p}" for p in props] + ["end_header"]
    with open(path, "wb") as f:
        f.write(("\n".join(head) + "\n").encode())
        if fmt == "ascii":
            for row in table:
                f.write((" ".join(repr(float(v)) for v in row) + "\n").encode())
        else:
            f.write(np.asarray(table, "<f4").tobytes())


def raw_table(rng, n):
    t = rng.standard_normal((n, len(PROPS))).astype(np.float32)
    return t


def random_gaussians(rng, n, *, zmin=2.0, zmax=8.0, spread=0.35):
    z = rng.uniform(zmin, zmax, n)
    means = np.stack([rng.uniform(-spread, spread, n) * z, rng.uniform(-spread, spread, n) * z,
                      z], 1)
    scales = np.exp(rng.uniform(np.log(0.01), np.log(0.25), (n, 3)))
    quats = rng.standard_normal((n, 4))
    return Gaussians(means, scales, quats, rng.uniform(0.05, 0.99, n),
                     rng.uniform(0.02, 1.0, (n, 3)))


def blend_3dgs(proj, width, height, t_min=1e-4, tile=16):
    """Ordinary 3DGS front-to-back blending of the same splats (one accumulator, no slabs)."""
    C = np.zeros((height, width, 3), np.float64)
    T = np.ones((height, width), np.float32)
    done = np.zeros((height, width), bool)
    r = proj.radius
    for k in range(len(proj.opacity)):
        x0 = int(np.clip(np.floor((proj.xy[k, 0] - r[k]) / tile), 0, None)) * tile
        x1 = int(np.floor((proj.xy[k, 0] + r[k]) / tile) + 1) * tile
        y0 = int(np.clip(np.floor((proj.xy[k, 1] - r[k]) / tile), 0, None)) * tile
        y1 = int(np.floor((proj.xy[k, 1] + r[k]) / tile) + 1) * tile
        for y in range(y0, min(y1, height)):
            for x in range(x0, min(x1, width)):
                if done[y, x]:
                    continue
                dx, dy = proj.xy[k, 0] - x, proj.xy[k, 1] - y
                a, b, c = proj.conic[k]
                power = -0.5 * (a * dx * dx + c * dy * dy) - b * dx * dy
                if power > 0:
                    continue
                alpha = min(0.99, proj.opacity[k] * np.exp(power))
                if alpha < 1 / 255:
                    continue
                if T[y, x] * (1 - alpha) < t_min:
                    done[y, x] = True
                    continue
                C[y, x] += proj.color[k] * alpha * T[y, x]
                T[y, x] *= 1 - alpha
    return C


def over(alpha, color):
    out = np.zeros(color.shape[1:], np.float64)
    for i in range(alpha.shape[0] - 1, -1, -1):
        out = out * (1 - alpha[i][..., None]) + color[i] * alpha[i][..., None]
    return out


# --- PLY ------------------------------------------------------------------------------------------

def test_read_ply_activates_values(tmp_path, rng):
    t = raw_table(rng, 20)
    write_ply(tmp_path / "g.ply", t)
    g = read_ply(tmp_path / "g.ply")
    col = {p: t[:, i].astype(np.float64) for i, p in enumerate(PROPS)}
    np.testing.assert_allclose(g.means, np.stack([col["x"], col["y"], col["z"]], 1))
    np.testing.assert_allclose(g.opacities, 1 / (1 + np.exp(-col["opacity"])), rtol=1e-6)
    np.testing.assert_allclose(g.scales[:, 1], np.exp(col["scale_1"]), rtol=1e-6)
    q = np.stack([col[f"rot_{i}"] for i in range(4)], 1)
    np.testing.assert_allclose(g.rotations, q / np.linalg.norm(q, axis=1, keepdims=True),
                               rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(g.colors[:, 2], np.clip(0.5 + SH_C0 * col["f_dc_2"], 0, 1),
                               rtol=1e-6)
    write_ply(tmp_path / "a.ply", t, fmt="ascii")
    np.testing.assert_allclose(read_ply(tmp_path / "a.ply").means, g.means)


def test_read_ply_errors_name_the_file(tmp_path, rng):
    t = raw_table(rng, 10)
    write_ply(tmp_path / "g.ply", t)
    data = (tmp_path / "g.ply").read_bytes()
    (tmp_path / "cut.ply").write_bytes(data[:-100])
    with pytest.raises(ValueError, match=r"cut\.ply is truncated"):
        read_ply(tmp_path / "cut.ply")
    keep = [i for i, p in enumerate(PROPS) if p not in ("opacity", "rot_3")]
    write_ply(tmp_path / "few.ply", t[:, keep], [PROPS[i] for i in keep])
    with pytest.raises(ValueError, match=r"few\.ply lacks .*opacity, rot_3"):
        read_ply(tmp_path / "few.ply")
    (tmp_path / "no.ply").write_bytes(b"hello")
    with pytest.raises(ValueError, match=r"no\.ply is not a PLY"):
        read_ply(tmp_path / "no.ply")
    (tmp_path / "hdr.ply").write_bytes(data[:200])
    with pytest.raises(ValueError, match=r"hdr\.ply.*end_header"):
        read_ply(tmp_path / "hdr.ply")
    with pytest.raises(FileNotFoundError, match=r"missing\.ply"):
        read_ply(tmp_path / "missing.ply")
    for fmt in ("binary_little_endian", "ascii"):
        write_ply(tmp_path / "none.ply", t[:0], fmt=fmt)
        with pytest.raises(ValueError, match=r"none\.ply holds no splats"):
            read_ply(tmp_path / "none.ply")
        with pytest.raises(ValueError, match=r"none\.ply holds no splats"):
            splats_to_mpi(tmp_path / "none.ply", layers=2, width=8, backend="numpy")


def test_train_ply_reads(shared_data):
    g = read_ply(shared_data / "gaussians" / "train-1000.ply")
    assert len(g) == 1000
    assert np.all((g.opacities > 0) & (g.opacities < 1)) and np.all(g.scales > 0)
    np.testing.assert_allclose(np.linalg.norm(g.rotations, axis=1), 1, rtol=1e-6)


# --- single splats -------------------------------------------------------------------------------

def _cam(W=64, H=64, f=100.0):
    return Camera(W, H, f, f)


@pytest.mark.parametrize("backend", ["numpy", "opencl"])
def test_single_isotropic_gaussian_footprint_and_peak(backend, queue):
    z, s, o = 5.0, 0.2, 0.8
    # on the optical axis, centred on pixel (x, y) = (32, 30): there the EWA Jacobian has no
    # perspective cross terms and the screen variance is exactly (f s / z)^2
    cam = Camera(64, 64, 100.0, 100.0, cx=32.0, cy=30.0)
    means = [[0.0, 0.0, z]]
    g = Gaussians(means, [[s, s, s]], [[1, 0, 0, 0]], [o], [[0.2, 0.5, 0.9]])
    proj = project(g, cam)
    slab, _ = slab_edges(proj.depth, 4)
    if backend == "numpy":
        alpha, color = rasterize_slabs_reference(proj, slab, 4, 64, 64)
    else:
        alpha, color = rasterize_slabs(proj, slab, 4, 64, 64, queue=queue)
    assert (alpha.reshape(4, -1).max(1) > 0).sum() == 1  # one slab
    a = alpha[slab[0]]
    var = (100 * s / z) ** 2 + 0.3  # EWA screen variance + 3DGS dilation, px^2
    yy, xx = np.mgrid[0:64, 0:64]
    want = o * np.exp(-0.5 * ((xx - 32) ** 2 + (yy - 30) ** 2) / var)
    want[want < 1 / 255] = 0
    assert a[30, 32] == pytest.approx(o, rel=1e-6)  # peak opacity
    np.testing.assert_allclose(a, want, atol=2e-6)
    np.testing.assert_allclose(color[slab[0]][a > 0], np.broadcast_to([0.2, 0.5, 0.9],
                               ((a > 0).sum(), 3)), rtol=1e-5)
    # footprint: the 1/255 contour has radius sqrt(2 var ln(255 o))
    r = np.sqrt(2 * var * np.log(255 * o))
    d = np.hypot(xx - 32, yy - 30)
    assert np.all(a[d < r - 0.5] > 0) and np.all(a[d > r + 0.5] == 0)


def test_anisotropic_rotated_gaussian_projects_like_ewa():
    # A Gaussian long along the world x axis rotated 90 degrees about z is long along y.
    cam = _cam()
    q = [np.cos(np.pi / 4), 0, 0, np.sin(np.pi / 4)]
    g = Gaussians([[0.0, 0.0, 4.0]], [[0.4, 0.05, 0.05]], [q], [0.9], [[1, 1, 1]])
    proj = project(g, cam)
    a, b, c = proj.conic[0]
    cov = np.linalg.inv([[a, b], [b, c]])
    np.testing.assert_allclose(cov, [[(100 * 0.05 / 4) ** 2 + 0.3, 0],
                                     [0, (100 * 0.4 / 4) ** 2 + 0.3]], rtol=1e-5, atol=1e-3)


@pytest.mark.parametrize("backend", ["numpy", "opencl"])
def test_two_gaussians_at_two_depths_land_in_two_slabs(backend, queue):
    cam = Camera(64, 64, 100.0, 100.0, cx=32.0, cy=32.0)  # both centres on pixel centres
    g = Gaussians([[-0.3, 0.0, 5.0], [0.6, 0.0, 10.0]], [[0.2] * 3, [0.4] * 3],
                  [[1, 0, 0, 0]] * 2, [0.7, 0.9], [[1, 0, 0], [0, 0, 1]])
    mpi = splats_to_mpi(g, layers=4, camera=cam, backend=backend, queue=queue)
    peaks = mpi.alpha.reshape(4, -1).max(1)
    np.testing.assert_allclose(peaks, [0.7, 0, 0, 0.9], rtol=1e-6)
    # slab depths are inverse-uniform centres between z = 5 and z = 10
    inv = 1 / 5 + (np.arange(4) + 0.5) / 4 * (1 / 10 - 1 / 5)
    np.testing.assert_allclose(mpi.depths, 1 / inv)
    # colour is decoded from the splats' sRGB to linear: pure red / blue stay pure
    assert mpi.color[0][mpi.alpha[0] > 0, 0].min() == pytest.approx(1.0, rel=1e-4)
    assert mpi.color[3][mpi.alpha[3] > 0, 2].min() == pytest.approx(1.0, rel=1e-4)


# --- slabs vs ordinary blending, kernel vs reference ---------------------------------------------

@pytest.mark.parametrize("slabs, n, spread", [(1, 120, 0.35), (3, 120, 0.35), (7, 120, 0.35),
                                               (5, 400, 0.1)])
def test_over_of_slabs_equals_3dgs_blending(rng, slabs, n, spread):
    # the dense case (400 splats in a narrow cone) drives pixels to the 3DGS early stop
    g = random_gaussians(rng, n, spread=spread)
    cam = Camera(40, 32, 40.0, 40.0)
    proj = project(g, cam)
    slab, _ = slab_edges(proj.depth, slabs)
    alpha, color = rasterize_slabs_reference(proj, slab, slabs, 40, 32)
    want = blend_3dgs(proj, 40, 32)
    got = over(alpha.astype(np.float64), color.astype(np.float64))
    t = tol("raster", np.float32)
    assert rel_l2(got, want) <= t["rel_l2"]
    assert np.abs(got - want).max() <= t["max_abs"]
    assert (alpha.reshape(slabs, -1).max(1) > 0).sum() >= min(slabs, 3)  # the slabs matter


@pytest.mark.parametrize("n, W, H, slabs", [(40, 17, 23, 1), (400, 64, 48, 5),
                                            (3000, 150, 90, 16)])
def test_kernel_matches_reference(queue, rng, n, W, H, slabs):
    g = random_gaussians(rng, n)
    cam = Camera(W, H, 0.9 * W, 0.9 * W)
    proj = project(g, cam)
    slab, _ = slab_edges(proj.depth, slabs, spacing="depth")
    want_a, want_c = rasterize_slabs_reference(proj, slab, slabs, W, H)
    got_a, got_c = rasterize_slabs(proj, slab, slabs, W, H, queue=queue)
    assert np.count_nonzero(want_a) > 0.3 * want_a[0].size
    for got, want in ((got_a, want_a), (got_c, want_c)):
        assert_raster_close(got, want)


def assert_raster_close(got, want):
    """The kernel and the float32 reference agree within the table's tolerance but for rare
    elements where one contribution sits at the 1/255 cut: the kernel's exp and NumPy's round
    it to different sides, and a whole contribution (alpha about 1/255) counts in one and not
    the other. One pixel of 216000 did at 3000 splats on PoCL and on an H200 alike (the seed
    of the test's H200 id: 0.0021 off, rel_l2 1.3e-5 in all; 1e-7 with other seeds). Such
    elements: at most 1 in 10^4 (3 at least: a pixel's colours), each at most 2/255 off."""
    t = tol("raster", np.float32)
    d = np.abs(got - want)
    at_cut = d > t["max_abs"]
    assert at_cut.sum() <= max(3, at_cut.size // 10_000), (at_cut.sum(), d.max())
    assert d.max() <= 2 / 255
    assert rel_l2(got[~at_cut], want[~at_cut]) <= t["rel_l2"]


def test_kernel_handles_no_visible_splats_and_large_tiles(queue):
    proj = project(Gaussians(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros((0, 4)) + [1, 0, 0, 0],
                             np.zeros(0), np.zeros((0, 3))), _cam(8, 8))
    a, c = rasterize_slabs(proj, np.zeros(0, np.int32), 2, 8, 8, queue=queue)
    assert a.shape == (2, 8, 8) and not a.any() and not c.any()


def test_train_ply_becomes_an_mpi(shared_data, queue):
    path = shared_data / "gaussians" / "train-1000.ply"
    mpi = splats_to_mpi(path, layers=8, width=160, near=0.05, far=0.08, queue=queue)
    assert mpi.layers == 8 and mpi.shape[1] == 160
    np.testing.assert_allclose(mpi.depths, np.linspace(0.05, 0.08, 8))
    assert (mpi.alpha.reshape(8, -1).max(1) > 0.1).sum() >= 6
    ref = splats_to_mpi(path, layers=8, width=160, near=0.05, far=0.08, backend="numpy")
    t = tol("raster", np.float32)
    assert rel_l2(mpi.alpha, ref.alpha) <= t["rel_l2"]
    assert rel_l2(mpi.color, ref.color) <= t["rel_l2"]


# --- cameras and the near plane ------------------------------------------------------------------

def _shrunk(g, s):
    return Gaussians(g.means * s, g.scales * s, g.rotations, g.opacities, g.colors)


def _in_image(g, cam):
    """Splats whose centre lies in front of the camera and projects inside the image."""
    p = g.means.astype(np.float64) @ cam.rotation.T + cam.translation
    z = p[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        u = cam.fx * p[:, 0] / z + cam.cx
        v = cam.fy * p[:, 1] / z + cam.cy
    return np.nonzero((z > 0) & (u >= 0) & (u <= cam.width - 1) & (v >= 0)
                      & (v <= cam.height - 1))[0]


@pytest.mark.parametrize("shrink", [1.0, 0.1])
def test_default_camera_keeps_every_splat_of_a_real_scene(shared_data, shrink):
    """fox-50k, and the same fox at a tenth of its size (a 0.2-unit scene, where a fixed
    znear=0.2 dropped 20 % to 39 % of the splats at 50..80 degrees without a word)."""
    import warnings

    from clholo.io import SplatCullWarning, default_camera

    g = _shrunk(read_ply(shared_data / "gaussians" / "fox-50k.ply"), shrink)
    for fov in (50, 60, 70, 80):
        cam = default_camera(g, width=96, fov_deg=fov)
        with warnings.catch_warnings():
            warnings.simplefilter("error", SplatCullWarning)
            proj = project(g, cam)
        visible = _in_image(g, cam)
        assert len(visible) > 0.9 * len(g)
        missing = np.setdiff1d(visible, proj.index)
        assert len(missing) == 0, f"fov {fov}: {len(missing)} visible splats culled"
        assert proj.dropped_near == 0


def test_culled_splats_are_counted_in_a_warning(shared_data):
    from clholo.io import SplatCullWarning

    g = read_ply(shared_data / "gaussians" / "fox-50k.ply")
    # the README's side view, moved in to 1 unit from the statue's axis: part of it is behind
    R = np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]])
    cam = Camera.from_fov(64, 64, 50, rotation=R, translation=-R @ np.array([0, 0, 1.25])
                          + np.array([0, 0, 1.0]))
    z = g.means.astype(np.float64) @ R[2] + cam.translation[2]
    for znear in (None, 0.2):
        with pytest.warns(SplatCullWarning) as record:
            proj = project(g, cam, znear=znear)
        expect = int(np.count_nonzero(z <= proj.znear))
        assert 0 < expect < len(g) and proj.dropped_near == expect
        message = str(record[0].message)
        assert f"{expect} of {len(g)} splats" in message
        assert f"{int(np.count_nonzero(z <= 0))} behind the camera" in message
    assert proj.znear == 0.2
    with pytest.raises(ValueError, match="znear"):
        project(g, cam, znear=-1.0)


def _cameras_json(path, cams):
    """A cameras.json as the original 3DGS code writes it (utils/camera_utils.camera_to_JSON):
    position = camera centre, rotation = camera-to-world rows."""
    import json

    entries = []
    for i, (centre, c2w, w, h, fx, fy) in enumerate(cams):
        entries.append({"id": i, "img_name": f"{i:05d}", "width": w, "height": h,
                        "position": list(map(float, centre)),
                        "rotation": [list(map(float, row)) for row in c2w],
                        "fy": fy, "fx": fx})
    path.write_text(json.dumps(entries))


def _rot_y(deg):
    a = np.radians(deg)
    return np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])


def test_camera_from_3dgs_cameras_json(tmp_path):
    from clholo.io import camera_from_json

    centre, c2w = np.array([0.5, -0.25, -3.0]), _rot_y(30)
    _cameras_json(tmp_path / "cameras.json",
                  [(np.zeros(3), np.eye(3), 40, 30, 35.0, 36.0), (centre, c2w, 80, 60, 70.0, 72.0)])
    cam = camera_from_json(tmp_path / "cameras.json", 1)
    assert (cam.width, cam.height, cam.fx, cam.fy) == (80, 60, 70.0, 72.0)
    # a point 2 units straight ahead of the camera, 0.3 right and 0.1 down, in camera axes
    local = np.array([0.3, 0.1, 2.0])
    world = centre + c2w @ local
    g = Gaussians(world[None], np.full((1, 3), 1e-3), [[1.0, 0, 0, 0]], [0.9], [[0.5] * 3])
    proj = project(g, cam)
    np.testing.assert_allclose(proj.xy[0], [70.0 * 0.15 + 39.5, 72.0 * 0.05 + 29.5], rtol=1e-6)
    np.testing.assert_allclose(proj.depth, [2.0], rtol=1e-6)  # float32 means
    half = camera_from_json(tmp_path / "cameras.json", 1, width=40)
    assert (half.width, half.height, half.fx, half.fy) == (40, 30, 35.0, 36.0)
    assert camera_from_json(tmp_path / "cameras.json").width == 40  # index 0 by default
    with pytest.raises(ValueError, match=r"camera_index 2 is out of range.*cameras\.json holds 2"):
        camera_from_json(tmp_path / "cameras.json", 2)
    (tmp_path / "bad.json").write_text('[{"id": 0, "width": 4}]')
    with pytest.raises(ValueError, match=r"bad\.json: camera 0 lacks height, position"):
        camera_from_json(tmp_path / "bad.json")
    with pytest.raises(FileNotFoundError, match=r"nope\.json"):
        camera_from_json(tmp_path / "nope.json")


def test_camera_scaled_keeps_the_view():
    cam = Camera(80, 60, 70.0, 72.0, cx=41.0, cy=28.5, translation=[0.1, 0.2, 3.0])
    half = cam.scaled(0.5)
    assert (half.width, half.height) == (40, 30)
    g = Gaussians([[0.4, -0.3, 1.0]], np.full((1, 3), 1e-3), [[1.0, 0, 0, 0]], [0.9], [[0.5] * 3])
    full_xy, half_xy = project(g, cam).xy[0], project(g, half).xy[0]
    np.testing.assert_allclose((half_xy + 0.5), (full_xy + 0.5) * 0.5, rtol=1e-6)
