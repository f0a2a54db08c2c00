"""The paper's runtime-and-quality-versus-layers study (its Fig. "metrics_plot"), on our data.

For every scene and every layer count ``L``, the chosen methods of the registry
(:data:`clholo.methods.METHODS`; by default ``mpi``, the MPI hologram of HOLOGRAPHY.md section 4,
and ``rgbd``, the RGB-D layer sum of section 7, :mod:`clholo.baselines.rgbd`) are rendered with
the same ``T`` frames, seed and planes; ``rpws`` (random-phase wave splatting, one layer per
Gaussian, no ``L``) adds one row per splat scene, rendered from the very splats the scene's
MPIs are binned from. Every hologram is scored against what ray optics says the scene looks
like (:mod:`clholo.rayoptics`) and timed:

* focal stack: :func:`clholo.hologram.focal_stack` at several depths against the incoherent
  focal slice of the scene's reference MPI (shift-and-add over the SLM's whole band);
* pupil views: :func:`clholo.views.pupil_view` (focused on the middle of the scene) at
  several horizontal angles against the mean of orthographic views over the same pupil;
* runtime of the ``T`` frames on the OpenCL device, read back to the host (the second of two
  identical renders, so that building FFT plans, programs and transfer functions is not
  counted; RPWS, which costs minutes, is rendered once and its time includes those builds).

Scoring (:func:`clholo.metrics.score`): one least-squares scale per colour
(``fit_scale="per_channel"``: a pupil passes about ``1 / lambda^2`` of each colour, so one
scale for all colours would score colour balance, not the image), and one data range per scene,
:data:`DATA_RANGE_PERCENTILE` (99.5th) percentile of the reference's whole focal stack (every
depth, pixel and colour of the incoherent focal slices), for every focal and view score of that
scene (PSNR's peak, SSIM's L, FLIP's white). ``results.csv`` records the per-colour scales
(``scale``, space separated, R G B) and the data range of each row.

Scenes (each placed between ``near`` and ``far`` metres behind the hologram):

``twain``
    the 32-layer Stereo Magnification MPI (``shared/data/twain-mpi``), downscaled; reference =
    all 32 layers; the ``L``-plane MPI merges the layers nearest each of ``L`` uniform planes
    with "over"; the RGB-D image is its composite and expected depth.
``motorcycle``
    scikit-image's Middlebury RGB-D pair; reference = a soft ``2 max(L)``-plane MPI (alpha split
    between the two nearest planes: the continuous surface); MPI and RGB-D holograms from
    the same hard bins (so they differ only by occlusion).
``fox``
    the 3DGS scene ``shared/data/gaussians/fox-50k.ply`` from its README's camera, binned into
    ``L`` slabs (the paper's data path); reference = ``2 max(L)`` slabs; the RGB-D image is
    the reference's composite and expected depth. ``max_splats`` keeps a seeded uniform subset
    of the visible splats for every method (RPWS costs one propagation per splat).

Outputs (built in a temporary folder, renamed when complete): ``results.csv`` (one row per
scene, L, method, operator and depth/angle), ``results.md`` (means), ``quality_vs_layers.png``,
``time_vs_layers.png``, ``crops_<scene>.png`` (crops at the strongest depth edge: reference,
MPI, RGB-D, at the nearest focal depth and the leftmost view), ``config.json``, and the focal
stack and pupil views of the first scene's MPI hologram at the largest L (``focal_stack.npz``,
``views.npz``) for ``clholo report``.
"""

from __future__ import annotations

import csv
import dataclasses
import io
import json
import math
import time
from pathlib import Path
from typing import Dict, List, Optional, Tuple

import numpy as np

from clholo.scene import MPI, Optics

__all__ = ["StudyConfig", "REDUCED", "FULL", "prepare_scene", "run_study", "estimate_seconds"]

SCENES = ("twain", "motorcycle", "fox")
#: Percentile of the reference focal stack that is the scene's data range (module docstring).
DATA_RANGE_PERCENTILE = 99.5
SPLAT_SCENES = ("fox",)          # scenes made of 3D Gaussians: the ones RPWS can render
METHODS = ("mpi", "rgbd", "rpws")  # the registry's methods, in the order of the tables
#: Widest scene of the study, pixels (``StudyConfig.width``; ``--width``).
MAX_WIDTH = 2048
#: What a scene reads from the shared data folder (the motorcycle is scikit-image's own).
SCENE_DATA = {"twain": "twain-mpi/mpi.json", "fox": "gaussians/fox-50k.ply"}


@dataclasses.dataclass(frozen=True)
class StudyConfig:
    """Sizes of the study. ``FULL`` is the documented run; ``REDUCED`` the CI-sized one."""

    scenes: Tuple[str, ...] = SCENES
    layers: Tuple[int, ...] = (4, 8, 16, 32, 64)
    frames: int = 24
    width: int = 128                     # scene width in pixels (height keeps the aspect)
    near: float = 2e-3                   # metres behind the hologram plane
    far: float = 6e-3
    focal_depths: int = 5                # evenly over [near, far]
    view_angles_deg: Tuple[float, ...] = (-1.0, 0.0, 1.0)
    pupil_angle_rad: float = 0.01        # pupil half-angle of the views (0.57 deg)
    reference_samples: int = 7           # directions per axis of the ray-optics references
    seed: int = 0
    pad: str = "auto"
    methods: Tuple[str, ...] = ("mpi", "rgbd")   # names in clholo.methods.METHODS
    max_splats: Optional[int] = None     # splat scenes: seeded subset of the visible splats

    def validated(self) -> "StudyConfig":
        from clholo import validate
        from clholo.methods import METHODS as REGISTRY

        for name in ("scenes", "methods", "layers", "view_angles_deg"):
            value = getattr(self, name)
            # a string would be taken letter by letter ("motorcycle" as m, o, t, ...), a
            # number is not a sequence at all
            if isinstance(value, (str, bytes)) or not hasattr(value, "__iter__"):
                raise TypeError(f"{name} must be a sequence (a tuple), got {value!r}: e.g. "
                                f"{name}=({value!r},)")
        unknown = [s for s in self.scenes if s not in SCENES]
        if unknown or not self.scenes:
            raise ValueError(f"scenes must be some of {list(SCENES)}, got {list(self.scenes)}")
        bad = [m for m in self.methods if m not in REGISTRY or m not in METHODS]
        if bad or not self.methods:
            raise ValueError(f"methods must be some of {list(METHODS)}, got "
                             f"{list(self.methods)}")
        if "rpws" in self.methods and not any(s in SPLAT_SCENES for s in self.scenes):
            raise ValueError(f"method rpws renders 3D Gaussian splats: of the scenes only "
                             f"{', '.join(SPLAT_SCENES)} has them; add it to the scenes")
        if self.max_splats is not None:
            validate.count(self.max_splats, name="max_splats")
        if not self.layers:
            raise ValueError("layers must name at least one count from 2 to 256")
        for L in self.layers:  # whole numbers: 4.7 was cut to 4, NaN crashed int()
            validate.count(L, name="layers", minimum=2, maximum=256)
        validate.count(self.frames, name="frames")
        validate.count(self.width, name="width", minimum=16, maximum=MAX_WIDTH)
        validate.count(self.focal_depths, name="focal_depths")
        validate.count(self.reference_samples, name="reference_samples")
        validate.seed(self.seed)
        near = validate.real_scalar("near", self.near)
        far = validate.real_scalar("far", self.far)
        if not 0 < near < far:
            raise ValueError(f"need 0 < near < far (metres), got {self.near}, {self.far}")
        validate.depths([near, far], name="near and far")  # millimetres as metres: refused
        if not self.view_angles_deg:
            raise ValueError("view_angles_deg must name at least one angle")
        for a in self.view_angles_deg:
            if not abs(validate.real_scalar("view_angles_deg", a)) < 90:
                raise ValueError(f"view_angles_deg must be angles in degrees within (-90, 90), "
                                 f"got {list(self.view_angles_deg)}")
        beta = validate.real_scalar("pupil_angle_rad", self.pupil_angle_rad)
        if not 0 < beta < np.pi / 2:
            raise ValueError(f"pupil_angle_rad is the views' pupil half-angle in radians, "
                             f"within (0, pi/2), got {self.pupil_angle_rad!r}")
        validate.pad(self.pad)
        # each scene, layer count and method once (a repeated one would be rendered and scored
        # twice, duplicate points in the plots); scenes keep their order, layers sort
        return dataclasses.replace(self, layers=tuple(sorted({int(L) for L in self.layers})),
                                   scenes=tuple(dict.fromkeys(self.scenes)),
                                   methods=tuple(m for m in METHODS if m in self.methods))


FULL = StudyConfig()
REDUCED = StudyConfig(layers=(4, 8), frames=4, width=64, focal_depths=3,
                      view_angles_deg=(-1.0, 1.0), reference_samples=5)


#: Splats of the splat scene (fox-50k.ply); ``max_splats`` keeps fewer.
SPLATS_PER_SCENE = 50_000


def estimate_seconds(config: StudyConfig) -> float:
    """The study's expected wall time in seconds on the 2-core development machine (PoCL on
    an AMD EPYC, under the load of other sessions), a rough guide only (+-50 %; a GPU takes a
    fraction of it).

    A model fitted to two measured runs, the full study with RPWS (462 s, of it RPWS 207 s;
    docs/results.md) and ``--reduced`` with RPWS (67 s, RPWS 23 s; 2026-11-25): 3 s to start,
    14 s per scene (loading it, ray-optics references), ``0.3 s x T x (width / 128)^2`` per
    MPI or RGB-D hologram (rendering and scoring), and per splat scene with RPWS
    ``(15 s + 8 s x T x (width / 128)^2) x splats / 50,000``.
    """
    config = config.validated()
    size = config.frames * (config.width / 128.0) ** 2
    holograms = len(config.scenes) * len(config.layers) * \
        len([m for m in config.methods if m != "rpws"])
    seconds = 3.0 + 14.0 * len(config.scenes) + 0.3 * size * holograms
    if "rpws" in config.methods:
        splats = min(SPLATS_PER_SCENE, config.max_splats or SPLATS_PER_SCENE)
        seconds += sum((15.0 + 8.0 * size) * splats / SPLATS_PER_SCENE
                       for s in config.scenes if s in SPLAT_SCENES)
    return seconds


def describe_estimate(config: StudyConfig) -> str:
    """One line: the expected time of :func:`estimate_seconds`, in seconds or minutes."""
    t = estimate_seconds(config)
    when = f"{t:.0f} s" if t < 90 else f"{t / 60:.0f} min"
    return (f"expected time: about {when} on 2 CPU cores with PoCL (a rough guide from the "
            f"documented runs; less on a GPU)")


# ------------------------------------------------------------------------------------ scenes
@dataclasses.dataclass
class Scene:
    """A scene at one size: its reference MPI, its RGB-D image and how to make L planes."""

    name: str
    reference: MPI            # what ray optics is computed from
    image: np.ndarray         # (H, W, 3) linear, the RGB-D baseline's colour
    depth: np.ndarray         # (H, W) metres, the RGB-D baseline's depth
    make_mpi: object          # L -> MPI
    primitives: object = None  # splat scenes: RPWS primitives of the same splats
    note: str = ""            # what was kept of the input (splat subsampling)


def _resize(a: np.ndarray, shape: Tuple[int, int]) -> np.ndarray:
    from skimage.transform import resize

    return resize(a, shape, order=1, anti_aliasing=True, preserve_range=True)


def _expected_depth(mpi: MPI) -> np.ndarray:
    """Depth of the over-composite: sum_i w_i d_i / sum_i w_i, w_i = a_i prod_{j<i} (1 - a_j)."""
    num = np.zeros(mpi.shape)
    den = np.zeros(mpi.shape)
    trans = np.ones(mpi.shape)
    for i in range(mpi.layers):  # front to back
        w = mpi.alpha[i] * trans
        num += w * mpi.depths[i]
        den += w
        trans = trans * (1.0 - mpi.alpha[i])
    far = float(mpi.depths[-1])
    return np.where(den > 1e-6, num / np.maximum(den, 1e-6), far)


def merge_layers(mpi: MPI, planes: np.ndarray) -> MPI:
    """The MPI's layers merged onto the nearest of ``planes`` (metres, increasing) with "over"
    (``alpha = 1 - prod(1 - a)``, colour = premultiplied over / alpha): the L-plane version of
    a finer MPI, like binning Gaussians into slabs."""
    planes = np.asarray(planes, np.float64)
    group = np.argmin(np.abs(mpi.depths[:, None] - planes[None, :]), axis=1)
    L = len(planes)
    H, W = mpi.shape
    color = np.zeros((L, H, W, mpi.channels), np.float64)
    alpha = np.zeros((L, H, W), np.float64)
    for g in range(L):
        members = np.nonzero(group == g)[0]
        premult = np.zeros((H, W, mpi.channels))
        a_acc = np.zeros((H, W))
        for i in members[::-1]:  # back to front inside the group
            a = mpi.alpha[i].astype(np.float64)
            premult = premult * (1 - a[..., None]) + mpi.color[i] * a[..., None]
            a_acc = a_acc * (1 - a) + a
        alpha[g] = a_acc
        color[g] = np.where(a_acc[..., None] > 1e-8, premult / np.maximum(a_acc, 1e-8)[..., None],
                            0.0)
    return MPI(np.clip(color, 0, 1).astype(np.float32), np.clip(alpha, 0, 1).astype(np.float32),
               planes)


def _planes(config: StudyConfig, L: int) -> np.ndarray:
    return np.linspace(config.near, config.far, L)


def prepare_scene(name: str, config: StudyConfig, *, data: Optional[Path] = None,
                  queue=None) -> Scene:
    """Load and size scene ``name`` (see the module docstring)."""
    from clholo.io import rgbd_to_mpi

    config = config.validated()
    truth_layers = 2 * max(config.layers)
    if name == "twain":
        from clholo.io.mpi_folder import read_mpi

        folder = _data_dir(data) / "twain-mpi"
        full = read_mpi(folder, near=config.near, far=config.far, spacing="index")
        H0, W0 = full.shape
        shape = (max(8, round(config.width * H0 / W0)), config.width)
        alpha = np.stack([_resize(a, shape) for a in full.alpha])
        premult = np.stack([_resize(c * a[..., None], shape)
                            for c, a in zip(full.color, full.alpha)])
        color = np.where(alpha[..., None] > 1e-6, premult / np.maximum(alpha, 1e-6)[..., None], 0)
        reference = MPI(np.clip(color, 0, 1), np.clip(alpha, 0, 1), full.depths)
        return Scene(name, reference, reference.over(), _expected_depth(reference),
                     lambda L: merge_layers(reference, _planes(config, L)))
    if name == "motorcycle":
        from skimage import data as skdata

        from clholo.io import srgb_to_linear

        left, _, disparity = skdata.stereo_motorcycle()
        H0, W0 = left.shape[:2]
        shape = (max(8, round(config.width * H0 / W0)), config.width)
        image = np.clip(_resize(srgb_to_linear(left.astype(np.float64) / 255.0), shape), 0, 1)
        finite = np.isfinite(disparity)
        disp = np.where(finite, disparity, 0.0)
        # nearest neighbour keeps invalid disparities (0 after the line above) from smearing
        from skimage.transform import resize

        disp = resize(disp, shape, order=0, anti_aliasing=False, preserve_range=True)
        valid = disp[disp > 0]
        drange = (float(valid.max()), float(valid.min()))  # nearest = largest disparity
        kw = dict(near=config.near, far=config.far, depth_kind="disparity", srgb=False,
                  depth_range=drange)
        reference = rgbd_to_mpi(image, disp, layers=truth_layers, mode="soft", **kw)
        hard = rgbd_to_mpi(image, disp, layers=truth_layers, mode="hard", **kw)
        # the depth map the RGB-D baseline bins: the continuous one, in metres
        return Scene(name, reference, image, _expected_depth(hard),
                     lambda L: rgbd_to_mpi(image, disp, layers=L, mode="hard", **kw))
    if name == "fox":
        from clholo.io.splats import Camera, read_ply, splats_to_mpi

        from clholo.io.splats import subsample_visible

        g = read_ply(_data_dir(data) / "gaussians" / "fox-50k.ply")
        R = np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]])
        t = -R @ np.array([0.0, 0.0, 1.25]) + np.array([0.0, 0.0, 4.0])
        camera = Camera.from_fov(config.width, config.width, 50.0, rotation=R, translation=t)
        g, note = subsample_visible(g, camera, config.max_splats, seed=config.seed)
        kw = dict(camera=camera, near=config.near, far=config.far, queue=queue)
        reference = splats_to_mpi(g, layers=truth_layers, **kw)
        primitives = None
        if "rpws" in config.methods:
            from clholo.baselines.rpws import primitives_from_splats

            primitives, _ = primitives_from_splats(g, camera=camera, near=config.near,
                                                   far=config.far)
        return Scene(name, reference, reference.over(), _expected_depth(reference),
                     lambda L: splats_to_mpi(g, layers=L, **kw), primitives=primitives,
                     note=note)
    raise ValueError(f"unknown scene {name!r}; choose from {list(SCENES)}")


def check_data(scenes, data: Optional[Path] = None, *, option: str = "data") -> None:
    """Refuse, before any work, a data folder without what ``scenes`` read from it
    (:data:`SCENE_DATA`), naming the commonest slip: a scene folder (``.../twain-mpi``) given
    for the folder that holds it.

    Parameters
    ----------
    scenes : sequence of str
        Names of :data:`SCENES`.
    data : path, optional
        The shared data folder; default as :func:`prepare_scene` finds it (when none is found,
        nothing is checked: loading the scene says so).
    option : str
        How the caller named ``data``, for the message (``"--data"``).

    Raises
    ------
    clholo.errors.InputError
        Naming the folder, what is missing and the folder to give instead.
    """
    import os

    from clholo.errors import InputError

    needed = [(s, SCENE_DATA[s]) for s in dict.fromkeys(scenes) if s in SCENE_DATA]
    if not needed:
        return
    if data is not None:
        folder, named = Path(data), f"{option} {data}"
    else:
        try:
            folder = _data_dir(None)
        except FileNotFoundError:
            return
        env = os.environ.get("CLHOLO_SHARED_DATA")
        named = f"CLHOLO_SHARED_DATA={env}" if env else f"the shared data folder {folder}"
    missing = [(s, rel) for s, rel in needed if not (folder / rel).is_file()]
    if not missing:
        return
    scene, rel = missing[0]
    sub = rel.split("/", 1)[0]
    subs = sorted({r.split("/", 1)[0] for r in SCENE_DATA.values()})
    holds = " and ".join(f"{d}/" for d in subs)
    if folder.name in subs:  # e.g. .../twain-mpi: the folder of one scene, not their parent
        raise InputError(f"{named} is a scene folder; give the folder that holds {sub}/ (its "
                         f"parent, {folder.resolve().parent})")
    if (folder / "mpi.json").is_file() or any(folder.glob("*.ply")):
        raise InputError(f"{named} is a scene folder (it holds "
                         f"{'mpi.json' if (folder / 'mpi.json').is_file() else '.ply files'}), "
                         f"not the shared data folder: give the folder that holds {holds}")
    scenes_of = "--scenes" if option.startswith("--") else "the scenes"
    raise InputError(f"{named} holds no {sub}/ for the {scene} scene ({folder / rel} does not "
                     f"exist): give the shared data folder (it holds {holds}), or leave the "
                     f"scene out of {scenes_of}")


def _data_dir(data: Optional[Path]) -> Path:
    if data is not None:
        return Path(data)
    import os

    env = os.environ.get("CLHOLO_SHARED_DATA")
    if env:
        return Path(env)
    here = Path(__file__).resolve().parents[2]
    for cand in (here.parent / "shared" / "data", here / "shared" / "data"):
        if cand.is_dir():
            return cand
    raise FileNotFoundError("the shared data folder (twain-mpi, gaussians) was not found; pass "
                            "--data DIR or set CLHOLO_SHARED_DATA")


# -------------------------------------------------------------------------------- references
def _view_reference(mpi: MPI, optics: Optics, angle_rad: float, *, focus: float,
                    pupil_angle_rad: float, samples: int, queue=None) -> np.ndarray:
    """Ray optics of a pupil view: the mean of orthographic views (focused at ``focus``) over
    the disc pupil of half-angle ``pupil_angle_rad`` centred at ``angle_rad`` horizontally,
    directions uniform in sine; (H, W, C)."""
    from clholo import rayoptics

    offsets = rayoptics.pupil_directions(pupil_angle_rad, samples, pupil="disc")
    sx = math.sin(angle_rad) + np.sin(offsets[:, 0])
    sy = np.sin(offsets[:, 1])
    directions = np.stack([np.arcsin(sx), np.arcsin(sy)], axis=-1)
    shifts = rayoptics.layer_shifts_px(mpi.depths, focus, optics.pitch, directions)
    return rayoptics.warp_over(mpi, rayoptics.shift_homographies(shifts), queue=queue)


def _edge_box(depth: np.ndarray, size: int) -> Tuple[int, int]:
    """Top-left corner of the ``size``-square crop centred on the strongest depth edge."""
    from scipy.ndimage import gaussian_filter, sobel

    d = gaussian_filter(depth, 1.0)
    g = np.hypot(sobel(d, 0), sobel(d, 1))
    H, W = depth.shape
    m = size // 2
    g[:m] = g[H - m:] = 0
    g[:, :m] = g[:, W - m:] = 0
    y, x = np.unravel_index(np.argmax(g), g.shape)
    return int(min(max(0, y - m), H - size)), int(min(max(0, x - m), W - size))


# ------------------------------------------------------------------------------------ study
def _hologram(method: str, layers: Optional[MPI], primitives, optics: Optics,
              config: StudyConfig, *, queue, progress=None):
    """Render ``config.frames`` holograms by ``method`` of :data:`clholo.methods.METHODS`
    (from ``layers``, or from ``primitives`` for RPWS); returns (complex64 ``[T, C, H, W]``,
    seconds).

    The MPI methods are rendered twice with the same seed (bit-identical frames): the first
    pass builds the FFT plans, programs and transfer functions of exactly the batches the
    second one runs, which is the one timed. RPWS is rendered once (minutes; its builds are a
    negligible part of them).
    """
    from clholo.methods import get_method
    from clholo.scenes import Scene as LoadedScene, SceneSpec

    m = get_method(method)
    scene = LoadedScene(spec=SceneSpec(inputs=(f"study scene ({method})",)),
                        kind="ply" if m.needs == "primitives" else "memory",
                        mpi=None if m.needs == "primitives" else layers,
                        primitives=primitives if m.needs == "primitives" else None)
    kw = dict(frames=config.frames, seed=config.seed, pad=config.pad, queue=queue)
    if m.needs != "primitives":
        m.render(scene, optics, **kw)
    queue.finish()
    t0 = time.perf_counter()
    holo = m.render(scene, optics, progress=progress, **kw)
    queue.finish()
    return holo, time.perf_counter() - t0


def _check_host_memory(config: StudyConfig) -> None:
    """Refuse, before any scene is loaded, a frame count whose holograms cannot fit this
    machine's memory: one render holds ``T`` frames x 3 colours of complex64 at the study's
    width and at least 8 rows (every scene is at least 8 rows high)."""
    import os

    from clholo.errors import EnvironmentProblem

    try:
        total = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (ValueError, OSError, AttributeError):  # not every system reports it
        return
    least = config.frames * 3 * 8 * config.width * np.dtype(np.complex64).itemsize
    if least > total:
        raise EnvironmentProblem(
            f"frames={config.frames}: the holograms of one render take at least "
            f"{least / 2**30:.1f} GiB ({config.frames} frames x 3 colours x 8 x {config.width} "
            f"pixels or more, complex64) but this machine has {total / 2**30:.1f} GiB of "
            f"memory: use far fewer frames (the paper uses 24)")


def run_study(out_dir, config: StudyConfig = FULL, *, data: Optional[Path] = None,
              overwrite: bool = False, log=None, queue=None) -> Dict[str, object]:
    """Run the study and write its outputs into ``out_dir`` (built under a temporary name).

    Parameters
    ----------
    log : clholo.progress.StepLog, optional
        Gets a line per scene and per hologram, and progress while a slow one (RPWS) renders
        (the one progress policy: a bar on a terminal, plain lines elsewhere). Default: silent.

    Returns a summary: ``{"rows": [...], "out_dir": Path, "seconds": float}``.
    """
    from clholo import metrics, rayoptics, views
    from clholo.hologram import focal_stack
    from clholo.host import runtime
    from clholo.io.output import output_folder

    from clholo.progress import StepLog

    config = config.validated()
    _check_host_memory(config)  # before loading anything: a frame count from the user
    check_data(config.scenes, data)  # not after minutes of the scenes before the one missing
    queue = queue if queue is not None else runtime.get_queue()
    log = StepLog(io.StringIO(), mode="off") if log is None else log
    optics = Optics()
    t_start = time.perf_counter()
    depths = np.linspace(config.near, config.far, config.focal_depths)
    focus = 0.5 * (config.near + config.far)
    angles = [math.radians(a) for a in config.view_angles_deg]
    rows: List[dict] = []
    crops: Dict[str, dict] = {}
    jobs = _jobs(config)
    done = 0
    with output_folder(out_dir, overwrite=overwrite, command="experiment layers",
                       option="out_dir") as tmp:
        for scene_name in config.scenes:
            log.start(f"{scene_name}: loading the scene and its ray-optics references")
            t_scene = time.perf_counter()
            scene = prepare_scene(scene_name, config, data=data, queue=queue)
            ref = scene.reference
            focal_refs = [rayoptics.incoherent_focal_slice(
                ref, optics, float(d), samples=config.reference_samples, queue=queue)
                for d in depths]
            view_refs = [_view_reference(ref, optics, a, focus=focus,
                                         pupil_angle_rad=config.pupil_angle_rad,
                                         samples=config.reference_samples, queue=queue)
                         for a in angles]
            data_range = scene_data_range(focal_refs)
            size = max(8, min(96, min(ref.shape) // 2))
            box = _edge_box(scene.depth, size)
            crops[scene_name] = {"box": box, "size": size,
                                 "reference": (focal_refs[0], view_refs[0])}
            log.step(f"{scene_name}: {ref.shape[1]}x{ref.shape[0]}, references at "
                     f"{len(depths)} depths and {len(angles)} angles"
                     + (f"; splats: {scene.note}" if scene.note else ""),
                     time.perf_counter() - t_scene)
            for L in config.layers + ((0,) if any(j[2] == "rpws" for j in jobs) else ()):
                for method in [m for s_, L_, m in jobs if (s_, L_) == (scene_name, L)]:
                    layers_L = _layers(scene, method, L, config)
                    if method == "rpws":
                        L = len(scene.primitives)
                    what = (f"{scene_name} rpws ({L} splats)" if method == "rpws"
                            else f"{scene_name} L={L} {method}")
                    if method == "rpws":
                        log.start(f"{what}: rendering {config.frames} frame(s), one "
                                  f"propagation per splat")
                    t_job = time.perf_counter()
                    first = len(rows)
                    holo, seconds = _hologram(
                        method, layers_L, scene.primitives, optics, config, queue=queue,
                        progress=log.tracker("splat steps") if method == "rpws" else None)
                    stack = focal_stack(holo, optics, depths, pad=config.pad, queue=queue)
                    pv = views.pupil_view(holo, optics, focus_depth=focus, angles_rad=[
                        (a, 0.0) for a in angles], pupil_angle_rad=config.pupil_angle_rad,
                        pad=config.pad, queue=queue)
                    base = dict(scene=scene_name, layers=L, method=method, frames=config.frames,
                                data_range=round(data_range, 6),
                                height=ref.shape[0], width=ref.shape[1],
                                render_seconds=round(seconds, 5))
                    for k, d in enumerate(depths):
                        s = metrics.score(np.moveaxis(stack[k], 0, -1), focal_refs[k],
                                          layout="hwc", data_range=data_range,
                                          fit_scale="per_channel")
                        rows.append(dict(base, operator="focal", at=round(float(d) * 1e3, 4),
                                         **_rounded(s)))
                    for k, a in enumerate(config.view_angles_deg):
                        s = metrics.score(np.moveaxis(pv[k], 0, -1), view_refs[k],
                                          layout="hwc", data_range=data_range,
                                          fit_scale="per_channel")
                        rows.append(dict(base, operator="view", at=float(a), **_rounded(s)))
                    if L in (config.layers[0], config.layers[-1]) or method == "rpws":
                        crops[scene_name][(method, L)] = (np.moveaxis(stack[0], 0, -1),
                                                          np.moveaxis(pv[0], 0, -1))
                    if (scene_name, L, method) == (config.scenes[0], config.layers[-1], "mpi"):
                        # for `clholo report`: the depth and angle sliders of one hologram
                        np.savez(tmp / "focal_stack.npz", intensity=stack, depths_m=depths,
                                 wavelengths_m=np.asarray(optics.wavelengths))
                        np.savez(tmp / "views.npz", intensity=pv, angles_rad=np.asarray(angles))
                    del holo
                    done += 1
                    focal = np.mean([r["psnr"] for r in rows[first:] if r["operator"] == "focal"])
                    log.step(f"[{done}/{len(jobs)}] {what}: render {seconds:.3f} s, focal PSNR "
                             f"{focal:.2f} dB", time.perf_counter() - t_job)
        _write_csv(tmp / "results.csv", rows)
        table = _summary(rows)
        (tmp / "results.md").write_text(_markdown(table, config), encoding="utf-8")
        _plots(tmp, table, config)
        for scene_name, c in crops.items():
            _crop_sheet(tmp / f"crops_{scene_name}.png", c, config)
        cfg = dataclasses.asdict(config)
        cfg["device"] = queue.device.name.strip()
        cfg["total_seconds"] = round(time.perf_counter() - t_start, 1)
        (tmp / "config.json").write_text(json.dumps(cfg, indent=1), encoding="utf-8")
    return {"rows": rows, "out_dir": Path(out_dir), "seconds": time.perf_counter() - t_start}


def scene_data_range(focal_refs) -> float:
    """The scene's data range: :data:`DATA_RANGE_PERCENTILE` percentile of its reference focal
    stack (all depths, pixels and colours; the maximum if that percentile is 0)."""
    stack = np.stack([np.asarray(r, np.float64) for r in focal_refs])
    value = float(np.percentile(stack, DATA_RANGE_PERCENTILE))
    if not value > 0:
        value = float(stack.max())
    if not value > 0:
        raise ValueError("the scene's reference focal stack is black: no data range")
    return value


def _rounded(s: dict) -> dict:
    def one(v):
        return float(v) if not np.isfinite(v) else round(float(v), 5)

    return {k: ([one(x) for x in v] if isinstance(v, list) else one(v)) for k, v in s.items()}


def _layers(scene: Scene, method: str, L: int, config: StudyConfig) -> Optional[MPI]:
    """What ``method`` renders at ``L`` layers: the scene's L-plane MPI (``mpi``), the RGB-D
    layers of its image and depth (``rgbd``), nothing (``rpws`` renders the primitives)."""
    if method == "rpws":
        return None
    if method == "mpi":
        return scene.make_mpi(L)
    from clholo.baselines.rgbd import rgbd_layers

    return rgbd_layers(scene.image, scene.depth, layers=L, near=config.near, far=config.far,
                       depth_range=(config.near, config.far), srgb=False)


def _jobs(config: StudyConfig) -> List[tuple]:
    """``(scene, L, method)`` of every hologram of the study, in order (RPWS: one per splat
    scene, ``L`` unused)."""
    jobs = []
    for s in config.scenes:
        for L in config.layers:
            jobs += [(s, L, m) for m in config.methods if m != "rpws"]
        if "rpws" in config.methods and s in SPLAT_SCENES:
            jobs.append((s, 0, "rpws"))
    return jobs


_LABELS = {"mpi": "MPI", "rgbd": "RGB-D", "rpws": "RPWS"}


def _write_csv(path: Path, rows: List[dict]) -> None:
    fields = ["scene", "layers", "method", "operator", "at", "psnr", "ssim", "flip", "scale",
              "data_range", "render_seconds", "frames", "height", "width"]
    with open(path, "w", newline="", encoding="utf-8") as f:
        w = csv.DictWriter(f, fieldnames=fields)
        w.writeheader()
        for r in rows:
            row = {k: r[k] for k in fields}
            if isinstance(row["scale"], list):  # one least-squares scale per colour
                row["scale"] = " ".join(f"{v:g}" for v in row["scale"])
            w.writerow(row)


def _summary(rows: List[dict]) -> List[dict]:
    """Means over depths (focal) and angles (view) per scene, L and method."""
    keys = sorted({(r["scene"], r["layers"], r["method"]) for r in rows},
                  key=lambda k: (SCENES.index(k[0]), k[1], METHODS.index(k[2])))
    out = []
    for scene, L, method in keys:
        sel = [r for r in rows if (r["scene"], r["layers"], r["method"]) == (scene, L, method)]
        entry = dict(scene=scene, layers=L, method=method,
                     render_seconds=sel[0]["render_seconds"])
        for op in ("focal", "view"):
            ops = [r for r in sel if r["operator"] == op]
            for m in ("psnr", "ssim", "flip"):
                entry[f"{op}_{m}"] = float(np.mean([r[m] for r in ops]))
        out.append(entry)
    return out


def _markdown(table: List[dict], config: StudyConfig) -> str:
    lines = [f"T = {config.frames} frames, scenes {config.width} px wide, planes over "
             f"{config.near * 1e3:g}-{config.far * 1e3:g} mm; focal: mean over "
             f"{config.focal_depths} depths against the incoherent focal slice; view: mean over "
             f"angles {list(config.view_angles_deg)} deg (pupil half-angle "
             f"{config.pupil_angle_rad:g} rad, focus mid-scene) against ray-optics views. "
             f"Scored after one least-squares scale per colour, with one data range per "
             f"scene: the {DATA_RANGE_PERCENTILE:g}th percentile of its reference focal stack. "
             f"PSNR/SSIM higher is better, FLIP lower is better."
             + (" RPWS (random-phase wave splatting) has no L: its row gives the number of "
                "splat primitives it rendered, the same splats the scene's MPIs are binned "
                "from; it is rendered once, so its time includes building its plans."
                if "rpws" in config.methods else ""), "",
             "| scene | L | method | render s | focal PSNR | focal SSIM | focal FLIP | "
             "view PSNR | view SSIM | view FLIP |",
             "|---|---:|---|---:|---:|---:|---:|---:|---:|---:|"]
    for e in table:
        lines.append(
            f"| {e['scene']} | {e['layers']} | {e['method']} | {e['render_seconds']:.3f} | "
            f"{e['focal_psnr']:.2f} | {e['focal_ssim']:.4f} | {e['focal_flip']:.4f} | "
            f"{e['view_psnr']:.2f} | {e['view_ssim']:.4f} | {e['view_flip']:.4f} |")
    return "\n".join(lines) + "\n"


def _plots(folder: Path, table: List[dict], config: StudyConfig) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    scenes = [s for s in SCENES if any(e["scene"] == s for e in table)]
    cols = [("focal_psnr", "focal PSNR (dB)"), ("focal_ssim", "focal SSIM"),
            ("focal_flip", "focal FLIP (lower better)"), ("view_psnr", "view PSNR (dB)"),
            ("view_ssim", "view SSIM"), ("view_flip", "view FLIP (lower better)")]
    fig, axes = plt.subplots(len(scenes), len(cols), figsize=(3.2 * len(cols), 2.6 * len(scenes)),
                             squeeze=False)
    for i, s in enumerate(scenes):
        for j, (key, label) in enumerate(cols):
            ax = axes[i, j]
            for method, style in (("mpi", "o-"), ("rgbd", "s--")):
                pts = [(e["layers"], e[key]) for e in table
                       if e["scene"] == s and e["method"] == method]
                if pts:
                    ax.plot(*zip(*pts), style, label=_LABELS[method])
            for e in table:  # RPWS has no L: a level across the plot
                if e["scene"] == s and e["method"] == "rpws":
                    ax.axhline(e[key], color="k", ls=":", label=f"RPWS ({e['layers']} splats)")
            ax.set_xscale("log", base=2)
            ax.set_xticks(list(config.layers), [str(L) for L in config.layers])
            ax.set_title(f"{s}: {label}", fontsize=9)
            ax.grid(alpha=0.3)
            if i == len(scenes) - 1:
                ax.set_xlabel("layers L")
    for i in range(len(scenes)):
        axes[i, 0].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(folder / "quality_vs_layers.png", dpi=90)
    plt.close(fig)

    fig, ax = plt.subplots(figsize=(5, 3.6))
    for s in scenes:
        for method, style in (("mpi", "o-"), ("rgbd", "s--")):
            pts = [(e["layers"], e["render_seconds"]) for e in table
                   if e["scene"] == s and e["method"] == method]
            if pts:
                ax.plot(*zip(*pts), style, label=f"{s} {_LABELS[method]}")
        for e in table:
            if e["scene"] == s and e["method"] == "rpws":
                ax.axhline(e["render_seconds"], color="k", ls=":",
                           label=f"{s} RPWS ({e['layers']} splats)")
                ax.set_yscale("log")
    ax.set_xlabel("layers L")
    ax.set_ylabel(f"render time of T={config.frames} frames (s)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(folder / "time_vs_layers.png", dpi=90)
    plt.close(fig)


def _crop_sheet(path: Path, crops: dict, config: StudyConfig) -> None:
    """Rows: focal slice at the nearest depth, view at the first angle; columns: reference,
    then MPI and RGB-D at the smallest and the largest L. Each panel scaled to the reference
    (least squares) and sRGB-encoded."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from clholo.io.images import linear_to_srgb
    from clholo.metrics import scale_fit

    (y, x), n = crops["box"], crops["size"]
    cols = [("reference", None)] + [(m, L) for L in sorted({config.layers[0], config.layers[-1]})
                                    for m in config.methods if m != "rpws"]
    cols += [k for k in crops if isinstance(k, tuple) and k[0] == "rpws"]
    fig, axes = plt.subplots(2, len(cols), figsize=(2.0 * len(cols), 4.3), squeeze=False)
    for row, (ref_img, label) in enumerate(zip(crops["reference"],
                                               (f"focus {config.near * 1e3:g} mm",
                                                f"view {config.view_angles_deg[0]:g} deg"))):
        ref_c = ref_img[y:y + n, x:x + n]
        peak = max(float(ref_c.max()), 1e-6)
        for j, (method, L) in enumerate(cols):
            if method == "reference":
                img, title = ref_c, "ray optics"
            else:
                full = crops[(method, L)][row]
                img = full[y:y + n, x:x + n] * scale_fit(full, ref_img)
                title = (f"RPWS {L} splats" if method == "rpws" else
                         f"{_LABELS[method]} L={L}")
            ax = axes[row, j]
            ax.imshow(linear_to_srgb(np.clip(img / peak, 0, 1)), interpolation="nearest")
            ax.set_title(title, fontsize=8)
            ax.set_xticks([])
            ax.set_yticks([])
            if j == 0:
                ax.set_ylabel(label, fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


# -------------------------------------------------------------------------------------- CLI
