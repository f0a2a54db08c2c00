"""Random-phase wave splatting: device against the NumPy reference, against the MPI recursion,
against physics (refocusing, speckle statistics), and its API."""

import numpy as np
import pytest

import clholo
from clholo import reference as ref
from clholo.baselines import rpws

from tolerances import rel_l2, tol


def _gaussians(rng, K, H, W, *, sigma=(1.5, 5.0), margin=3.0):
    """K random 2-D Gaussians (anisotropic, rotated) with centres on or a little off the
    image: ``(xy, conic, radius)``."""
    xy = np.stack([rng.uniform(-margin, W + margin, K), rng.uniform(-margin, H + margin, K)], 1)
    sx, sy = rng.uniform(*sigma, K), rng.uniform(*sigma, K)
    rho = rng.uniform(-0.6, 0.6, K)
    cov = np.stack([[sx * sx, rho * sx * sy], [rho * sx * sy, sy * sy]]).transpose(2, 0, 1)
    inv = np.linalg.inv(cov)
    conic = np.stack([inv[:, 0, 0], inv[:, 0, 1], inv[:, 1, 1]], 1)
    radius = np.ceil(3 * np.sqrt(np.linalg.eigvalsh(cov)[:, 1]))
    return xy, conic, radius


def _random_primitives(rng, K=9, H=24, W=40, C=2, near=1e-3, far=3e-3, ties=True):
    xy, conic, radius = _gaussians(rng, K, H, W)
    depths = np.sort(rng.uniform(near, far, K))
    if ties:  # equal depths happen in real scenes: a zero step must be the identity
        depths[K // 2] = depths[K // 2 - 1]
    return rpws.Primitives(xy, conic, rng.uniform(0.2, 1.0, K), rng.uniform(0.05, 1.0, (K, C)),
                           depths, radius, (H, W))


def _reference(p, optics, *, frames, seed, pad):
    return ref.rpws_hologram(p.xy, p.conic, p.opacity, p.color, p.depths, p.boxes(), p.shape,
                             wavelengths=optics.wavelengths, pitch=optics.pitch, frames=frames,
                             seed=seed, pad=pad)


OPTICS2 = clholo.Optics(wavelengths=(638e-9, 450e-9))


@pytest.mark.parametrize("size,K,pad", [((24, 40), 9, "auto"), ((33, 20), 5, 2),
                                        ((16, 16), 3, "auto")])
def test_rpws_matches_reference(queue, rng, size, K, pad):
    H, W = size
    p = _random_primitives(rng, K=K, H=H, W=W)
    seed = int(rng.integers(0, 2 ** 40))
    got = rpws.render_rpws(p, OPTICS2, frames=3, seed=seed, pad=pad, queue=queue)
    padded = rpws.rpws_padded_shape(p, OPTICS2, pad=pad)
    want = _reference(p, OPTICS2, frames=3, seed=seed, pad=padded)
    assert got.shape == (3, 2, H, W) and got.dtype == np.complex64
    assert np.abs(want).max() > 0.1
    assert rel_l2(got, want) <= tol("rpws", np.float32)["rel_l2"]


def test_rpws_is_the_mpi_with_one_layer_per_primitive(queue, rng):
    """Distinct depths: RPWS of K primitives is the MPI recursion of K layers whose layer k is
    primitive k's footprint over the whole image, with the same phase stream (layer = k)."""
    p = _random_primitives(rng, K=5, H=20, W=28, ties=False)
    alpha = np.zeros((len(p),) + p.shape, np.float32)
    for k, (x0, y0, x1, y1), a in p.footprints():
        alpha[k, y0:y1, x0:x1] = a
    color = np.broadcast_to(p.color[:, None, None, :], (len(p),) + p.shape + (2,))
    seed = int(rng.integers(0, 2 ** 40))
    padded = rpws.rpws_padded_shape(p, OPTICS2)
    want = ref.mpi_hologram(color, alpha, p.depths, wavelengths=OPTICS2.wavelengths,
                            pitch=OPTICS2.pitch, frames=2, seed=seed, pad=padded)
    got = rpws.render_rpws(p, OPTICS2, frames=2, seed=seed, queue=queue)
    assert rel_l2(got, want) <= tol("rpws", np.float32)["rel_l2"]


def test_batches_same_frames_and_seed_reproduces(queue, rng):
    from clholo.host.rpws import RPWSRenderer

    p = _random_primitives(rng, K=4, H=16, W=24)
    full = rpws.render_rpws(p, OPTICS2, frames=5, seed=9, queue=queue)
    again = rpws.render_rpws(p, OPTICS2, frames=5, seed=9, queue=queue)
    assert full.tobytes() == again.tobytes()
    seen = []
    r = RPWSRenderer(p, OPTICS2, seed=9, frames_per_batch=2, sync_every=1, queue=queue)
    got = r.render(5, progress=lambda done, total: seen.append((done, total))).get()
    np.testing.assert_allclose(got, full, rtol=0, atol=1e-6)
    assert seen[-1] == (12, 12) and [d for d, _ in seen] == sorted(d for d, _ in seen)
    other = rpws.render_rpws(p, OPTICS2, frames=2, seed=10, queue=queue)
    assert np.mean(other != full[:2]) > 0.5  # another seed, other phases where light is


def _single_or_pair(rng, n, *, H=64, W=64, sigma=8.0):
    """n Gaussians near the centre of an (H, W) image, overlapping, all at 1 mm."""
    xy = np.array([[W / 2 - 2.0, H / 2 - 1.0], [W / 2 + 2.0, H / 2 + 1.0]])[:n]
    xy = xy + rng.uniform(-1, 1, xy.shape)
    conic = np.tile([1 / sigma ** 2, 0.0, 1 / sigma ** 2], (n, 1))
    opacity = rng.uniform(0.5, 0.9, n)
    color = rng.uniform(0.3, 1.0, (n, 1))
    return rpws.Primitives(xy, conic, opacity, color, np.full(n, 1e-3),
                           np.full(n, np.ceil(3 * sigma)), (H, W))


GREEN = clholo.Optics(wavelengths=(520e-9,))


def test_single_primitive_refocuses_to_c_alpha(queue, rng):
    p = _single_or_pair(rng, 1)
    holo = rpws.render_rpws(p, GREEN, frames=2, seed=int(rng.integers(1 << 30)), pad=2,
                            queue=queue)
    target = p.over()[..., 0]  # c alpha of the one footprint
    focused = clholo.focal_stack(holo, GREEN, [1e-3], pad=2, queue=queue)[0, 0]
    defocused = clholo.focal_stack(holo, GREEN, [3e-3], pad=2, queue=queue)[0, 0]
    assert rel_l2(focused, target) < 0.02  # exact per frame but for the cropped rim
    assert rel_l2(defocused, target) > 0.3  # and the test can tell focus from blur


def _pair_error(queue, p, frames, seed):
    holo = rpws.render_rpws(p, GREEN, frames=frames, seed=seed, pad=2, queue=queue)
    focused = clholo.focal_stack(holo, GREEN, [1e-3], pad=2, queue=queue)[0, 0]
    return rel_l2(focused, p.over()[..., 0])


def test_overlapping_pair_converges_to_over_as_speckle_says(queue, rng):
    """Two overlapping primitives at one depth, focused there: the cross term
    2 sqrt(...) cos(phi_0 - phi_1) averages out as 1/sqrt(T), so the error against the "over"
    composite at T = 8 is twice that at T = 32. Measured over 60 random pairs and seeds at this
    size: ratio 2.01 +- 0.09 (1 sd, range 1.85..2.23), error at T = 32 0.110 +- 0.010 (range
    0.074..0.125); the band [1.6, 2.45] is about 4 sd each side of 2, the bound 0.15 on the
    error 4 sd above its mean. (It was 0.12: the seed of the test's id on an H200 gave 0.128,
    on PoCL too.)"""
    p = _single_or_pair(rng, 2)
    seeds = rng.integers(0, 2 ** 40, 2)
    e8 = _pair_error(queue, p, 8, int(seeds[0]))
    e32 = _pair_error(queue, p, 32, int(seeds[1]))
    assert 1.6 < e8 / e32 < 2.45
    assert e32 < 0.15


def test_merge_depths_option():
    d = np.array([1.0, 1.05, 1.08, 1.2, 2.0, 2.01]) * 1e-3
    np.testing.assert_array_equal(rpws.merge_depths(d, None), d)
    m = rpws.merge_depths(d, 0.1e-3)
    np.testing.assert_allclose(m, [1.0433333e-3] * 3 + [1.2e-3] + [2.005e-3] * 2, rtol=1e-6)
    assert np.all(np.diff(m) >= 0)
    with pytest.raises(ValueError, match="merge_tolerance"):
        rpws.merge_depths(d, -1.0)


def test_merging_changes_only_the_steps(queue, rng):
    p = _random_primitives(rng, K=6, H=16, W=20, ties=False)
    tol_m = 0.5e-3
    got = rpws.render_rpws(p, OPTICS2, frames=1, seed=4, merge_tolerance=tol_m, queue=queue)
    merged = p.with_depths(rpws.merge_depths(p.depths, tol_m))
    assert len(np.unique(merged.depths)) < len(np.unique(p.depths))
    want = _reference(merged, OPTICS2, frames=1, seed=4,
                      pad=rpws.rpws_padded_shape(merged, OPTICS2))
    assert rel_l2(got, want) <= tol("rpws", np.float32)["rel_l2"]
    unmerged = rpws.render_rpws(p, OPTICS2, frames=1, seed=4, queue=queue)
    assert rel_l2(unmerged, want) > 1e-2  # merging is off by default


def test_metric_depths_and_mpi_from_primitives(rng):
    z = np.array([2.0, 2.5, 4.0, 8.0])
    d = rpws.metric_depths(z, 2e-3, 6e-3)
    assert d[0] == pytest.approx(2e-3) and d[-1] == pytest.approx(6e-3)
    t = (1 / z[0] - 1 / z) / (1 / z[0] - 1 / z[-1])  # linear in inverse depth
    np.testing.assert_allclose(d, 2e-3 + t * 4e-3)
    p = _random_primitives(rng, K=12, H=20, W=24, C=1)
    # one slab per primitive reproduces the primitives' own "over"; few slabs merge them
    for L in (1, 3, 64):
        mpi = rpws.primitives_to_mpi(p, L)
        assert mpi.layers == L
        if L == 64:
            np.testing.assert_allclose(mpi.over(), p.over(), atol=1e-5)
    one = rpws.primitives_to_mpi(p, 1)
    np.testing.assert_allclose(one.over(), p.over(), atol=1e-5)  # in-slab over is the over


def test_bad_input(queue, rng):
    p = _random_primitives(rng, K=3, H=8, W=8)
    with pytest.raises(ValueError, match="wavelength"):
        rpws.render_rpws(p, GREEN, frames=1, queue=queue)
    with pytest.raises(TypeError, match="primitives"):
        rpws.render_rpws("scene.ply", OPTICS2, queue=queue)
    with pytest.raises((TypeError, ValueError), match="frames"):
        rpws.render_rpws(p, OPTICS2, frames=0, queue=queue)
    with pytest.raises(ValueError, match="nondecreasing"):
        p.with_depths(p.depths[::-1] + [0, 1e-4, 2e-4])
    with pytest.raises(ValueError, match="depths"):
        p.with_depths([-1e-3, 1e-3, 2e-3])
    with pytest.raises(ValueError, match="color"):
        rpws.Primitives(p.xy, p.conic, p.opacity, p.color * 3, p.depths, p.radius, p.shape)
    with pytest.raises(ValueError, match="xy"):
        rpws.Primitives(p.xy[:2], p.conic, p.opacity, p.color, p.depths, p.radius, p.shape)
    with pytest.raises(ValueError, match="near"):
        rpws.metric_depths([1.0, 2.0], 3e-3, 2e-3)


def test_fox_subsample_is_stated_and_seeded(shared_data):
    from clholo.io.splats import Camera, read_ply

    g = read_ply(shared_data / "gaussians" / "fox-50k.ply")
    R = np.array([[1, 0, 0], [0, 0, -1], [0, 1, 0]], float)
    cam = Camera.from_fov(64, 64, 50.0, rotation=R,
                          translation=-R @ np.array([0, 0, 1.25]) + np.array([0, 0, 4.0]))
    p, info = rpws.primitives_from_splats(g, camera=cam, max_splats=300, seed=5)
    assert len(p) == 300 and info["splats"] == 300
    assert "300 of" in info["subsampling"] and "seed 5" in info["subsampling"]
    q, _ = rpws.primitives_from_splats(g, camera=cam, max_splats=300, seed=5)
    np.testing.assert_array_equal(p.xy, q.xy)
    assert p.depths[0] == pytest.approx(2e-3) and p.depths[-1] == pytest.approx(6e-3)


def test_cli_render_rpws_and_mpi_state_the_subsampling(tmp_path, capsys, shared_data):
    import json

    from clholo.cli import main

    ply = str(shared_data / "gaussians" / "train-1000.ply")
    for method in ("rpws", "mpi"):
        out = tmp_path / method
        layers = ["--layers", "4"] if method == "mpi" else []  # RPWS has no layers
        rc = main(["render", ply, "--method", method, "--max-splats", "5", "--frames", "1",
                   "--near", "0.002", "--far", "0.006", *layers, "--seed", "3",
                   "--out", str(out)])
        assert rc == 0
        summary = json.loads((out / "summary.json").read_text())
        assert summary["method"] == method and summary["splats"] == 5
        assert "5 of" in summary["subsampling"] and "seed 3" in summary["subsampling"]
        assert {p.name for p in out.iterdir()} == {"focal_stack.png", "focal_stack.npz",
                                                   "hologram.npz", "summary.json",
                                                   "clholo-output.json"}
        assert "5 of" in capsys.readouterr().out
    # an existing folder is refused before any work unless --overwrite is given
    rc = main(["render", ply, "--method", "rpws", "--max-splats", "5", "--frames", "1",
               "--near", "0.002", "--far", "0.006", "--out", str(tmp_path / "rpws")])
    assert rc == 2 and "overwrite" in capsys.readouterr().err
    rc = main(["render", str(shared_data / "twain-mpi"), "--method", "rpws",
               "--out", str(tmp_path / "x")])
    assert rc == 2 and ".ply" in capsys.readouterr().err
