"""One scene layer: what a scene is made from (:class:`SceneSpec`) and the loaded scene
(:class:`Scene`), for every command and for Python users.

``clholo render``, ``demo``, ``display``, ``batch`` rows and ``experiment`` scenes all describe
their scene with a :class:`SceneSpec` (the command line fills it through
:func:`clholo.options.add_scene_options`; a batch row through the same options) and
turn it into a :class:`Scene` with :func:`load`. So an option means the same everywhere, an
option that does not apply to the input is refused everywhere, and depths are checked to be
metres everywhere.

A field left ``None`` was not given: the input's own default applies (an MPI keeps its layers
and depths; RGB-D and splats make 32 layers).
"""

from __future__ import annotations

import dataclasses
import os
import time
import warnings
from dataclasses import dataclass
from typing import Callable, Optional, Tuple

import numpy as np

from clholo.errors import InputError

__all__ = ["DEMO", "SceneSpec", "Scene", "input_kind", "load", "check_metric_depths",
           "NoLightWarning"]

DEMO = "skimage:motorcycle"  # the bundled scene: scikit-image's Middlebury motorcycle RGB-D

# Which scene options act on which input kind; any other given option is refused with the fix.
_APPLIES = {
    "layers": {"demo", "rgbd", "ply", "mpi_folder", "stereo_mag"},
    "near": {"demo", "rgbd", "ply", "mpi_folder", "stereo_mag"},
    "far": {"demo", "rgbd", "ply", "mpi_folder", "stereo_mag"},
    "spacing": {"ply", "mpi_folder", "stereo_mag"},
    "mode": {"rgbd"},
    "depth_kind": {"rgbd"},
    "depth_spacing": {"rgbd"},
    "match_size": {"rgbd"},
    "scale": {"demo", "rgbd", "ply", "mpi_folder", "stereo_mag"},
    "min_depth": {"stereo_mag"},
    "max_depth": {"stereo_mag"},
    "camera_json": {"ply"},
    "camera_index": {"ply"},
    "znear": {"ply"},
    "max_splats": {"ply"},
}
_KIND_WORDS = {"demo": "the bundled demo scene", "rgbd": "an RGB-D pair",
               "ply": "a 3D Gaussian splat .ply", "mpi_folder": "an MPI folder",
               "stereo_mag": "a Stereo Magnification folder"}
_OPTION = {"camera_json": "--camera-json", "camera_index": "--camera-index",
           "min_depth": "--min-depth", "max_depth": "--max-depth", "max_splats": "--max-splats",
           "depth_kind": "--depth-kind", "depth_spacing": "--depth-spacing",
           "match_size": "--match-size"}


class NoLightWarning(UserWarning):
    """A scene that carries no light (alpha 0 in every layer, black wherever alpha is above
    0, or splats whose opacities are all 0): its hologram is all zero and its focal stack
    black. A warning, not an error: a black frame can be meant (a blank between scenes)."""


def _option(field: str) -> str:
    return _OPTION.get(field, "--" + field.replace("_", "-"))


@dataclass(frozen=True)
class SceneSpec:
    """What a scene is made from. ``None`` means "not given" (the input's default).

    Parameters
    ----------
    inputs : tuple of str
        One path (MPI folder, Stereo Magnification folder, ``.ply``), an (image, depth) pair, or
        ``(DEMO,)`` for the bundled scene.
    layers : int, optional
        Planes to make from RGB-D or splats (default 32; the demo 8). An MPI keeps its own.
    near, far : float, optional
        Metres behind the hologram plane of the nearest and farthest plane (or splat).
    spacing, mode, depth_kind, depth_spacing, match_size, scale, min_depth, max_depth
        As :func:`clholo.io.load_scene`.
    camera_json, camera_index, znear, max_splats, subset_seed
        Splat inputs: the camera, the near plane in scene units, and a seeded subset of at most
        ``max_splats`` visible splats (``subset_seed``).
    """

    inputs: Tuple[str, ...]
    layers: Optional[int] = None
    near: Optional[float] = None
    far: Optional[float] = None
    spacing: Optional[str] = None
    mode: Optional[str] = None
    depth_kind: Optional[str] = None
    depth_spacing: Optional[str] = None
    match_size: Optional[str] = None
    scale: Optional[float] = None
    min_depth: Optional[float] = None
    max_depth: Optional[float] = None
    camera_json: Optional[str] = None
    camera_index: Optional[int] = None
    znear: Optional[float] = None
    max_splats: Optional[int] = None
    subset_seed: int = 0

    def __post_init__(self) -> None:
        inputs = (self.inputs,) if isinstance(self.inputs, str) else tuple(self.inputs)
        object.__setattr__(self, "inputs", tuple(str(p) for p in inputs))
        if not self.inputs:
            raise InputError("a scene needs an input: a path, an (image, depth) pair, or DEMO")
        if (self.near is None) != (self.far is None):
            raise InputError("give both --near and --far (metres behind the hologram plane), "
                             "or neither")
        if self.near is not None and not self.near < self.far:
            raise InputError(f"--near ({self.near:g} m) must be less than --far "
                             f"({self.far:g} m)")

    @classmethod
    def demo(cls, **options) -> "SceneSpec":
        """The bundled demo scene (its defaults: 8 layers at 2..6 mm).

        Parameters
        ----------
        **options
            Any other :class:`SceneSpec` field (``layers``, ``near``, ``far``, ...).
        """
        options.setdefault("layers", 8)
        options.setdefault("near", 2e-3)
        options.setdefault("far", 6e-3)
        return cls(inputs=(DEMO,), **options)

    @property
    def source(self) -> str:
        """How the scene is named in logs and summaries."""
        return ("skimage.data.stereo_motorcycle" if self.inputs == (DEMO,)
                else " + ".join(self.inputs))

    def given(self) -> dict:
        """The options that were given (not ``None``), by field name."""
        return {f.name: getattr(self, f.name) for f in dataclasses.fields(self)
                if f.name not in ("inputs", "subset_seed") and getattr(self, f.name) is not None}

    def replace(self, **changes) -> "SceneSpec":
        """A copy with the fields in ``changes`` replaced (``dataclasses.replace``).

        Parameters
        ----------
        **changes
            :class:`SceneSpec` fields and their new values.
        """
        return dataclasses.replace(self, **changes)


def input_kind(spec: SceneSpec) -> str:
    """``"demo"``, ``"mpi_folder"``, ``"stereo_mag"``, ``"rgbd"`` or ``"ply"``.

    Parameters
    ----------
    spec : SceneSpec
        The scene's description.
    """
    if spec.inputs == (DEMO,):
        return "demo"
    from clholo.io.load import detect_kind

    return detect_kind(list(spec.inputs))


@dataclass
class Scene:
    """A loaded scene: an MPI, and for splat inputs also the RPWS primitives.

    Attributes
    ----------
    spec : SceneSpec
    kind : str
        :func:`input_kind`.
    mpi : clholo.MPI or None
        Depths in metres. ``None`` when only primitives were asked for.
    primitives : clholo.baselines.rpws.Primitives or None
        Splat inputs, when asked for.
    info : dict
        Facts to report (``"subsampling"`` for splats).
    """

    spec: SceneSpec
    kind: str
    mpi: Optional[object] = None
    primitives: Optional[object] = None
    info: dict = dataclasses.field(default_factory=dict)

    @property
    def source(self) -> str:
        """What the scene was made from, for logs and summaries (the spec's ``source``)."""
        return self.spec.source


def check_applicable(spec: SceneSpec, kind: str, *, method: Optional[str] = None) -> None:
    """Refuse every given option that would not act on this input (an option either acts or
    is refused)."""
    for field, value in spec.given().items():
        if kind not in _APPLIES[field]:
            raise InputError(
                f"{_option(field)} does not apply to {_KIND_WORDS[kind]} ({spec.source}); "
                f"it applies to {', '.join(sorted(_KIND_WORDS[k] for k in _APPLIES[field]))}: "
                f"drop {_option(field)}")
    if spec.spacing is not None and spec.near is None:  # else the depths stay as stored
        raise InputError("--spacing places the planes between --near and --far: give both, or "
                         "drop --spacing")
    if method == "rpws" and kind != "ply":
        raise InputError(f"--method rpws renders 3D Gaussian splats: give one .ply input, not "
                         f"{_KIND_WORDS[kind]} ({spec.source})")
    if method == "rpws" and spec.layers is not None:
        raise InputError("--layers does not apply to --method rpws: RPWS renders one layer per "
                         "splat, with no depth quantisation; drop --layers")


def check_metric_depths(depths, *, source: str, given: bool) -> None:
    """Refuse depths that are not metres a few millimetres behind a display (scene units), the
    same way for every method.

    Parameters
    ----------
    depths : array of float
        The scene's layer depths.
    source : str
        What the scene was made from (:attr:`SceneSpec.source`).
    given : bool
        Whether ``--near``/``--far`` were given (else the depths are scene units).

    Raises
    ------
    clholo.errors.InputError
        Depths in scene units, or beyond 1 m.
    """
    d = np.asarray(depths, np.float64)
    if not given:
        raise InputError(
            f"the scene's depths are in scene units ({d.min():.4g}..{d.max():.4g}): give "
            f"--near and --far in metres behind the hologram plane, e.g. --near 0.002 --far 0.006")
    if d.max() > 1.0:
        raise InputError(
            f"the scene's depths reach {d.max():.4g} m: --near/--far are metres behind the "
            f"hologram plane (a few millimetres for a holographic display), e.g. --near 0.002 "
            f"--far 0.006")


def load(spec: SceneSpec, *, needs: str = "mpi", method: Optional[str] = None,
         log=None, queue=None) -> Scene:
    """Load the scene ``spec`` describes.

    Parameters
    ----------
    spec : SceneSpec
    needs : {"mpi", "primitives"}
        What the method renders from: an MPI (every input) or RPWS primitives (``.ply``).
    method : str, optional
        The method's name, for method-specific refusals (``--layers`` with RPWS).
    log : clholo.progress.StepLog, optional
        Gets a line saying what was loaded and how long it took.
    queue : pyopencl.CommandQueue, optional
        Queue to run on (default: clholo's default device, ``CLHOLO_DEVICE``).

    Raises
    ------
    clholo.errors.InputError
        An option that does not apply to this input, depths not in metres, ...
    """
    if needs not in ("mpi", "primitives"):
        raise ValueError(f"needs must be 'mpi' or 'primitives', got {needs!r}")
    kind = input_kind(spec)
    check_applicable(spec, kind, method=method)
    if needs == "primitives" and kind != "ply":
        raise InputError(f"this method renders 3D Gaussian splats: give one .ply input, not "
                         f"{_KIND_WORDS[kind]} ({spec.source})")
    if log is not None:
        log.start(f"scene: loading {spec.source}")
    t = time.perf_counter()
    scene = Scene(spec=spec, kind=kind)
    if kind == "demo":
        from clholo.demo import motorcycle_mpi

        scene.mpi = motorcycle_mpi(layers=spec.layers, near=spec.near, far=spec.far,
                                   scale=1.0 if spec.scale is None else spec.scale)
    elif kind == "ply":
        _load_splats(spec, scene, needs=needs, queue=queue)
    else:
        from clholo.io.load import load_scene

        inputs = spec.inputs[0] if len(spec.inputs) == 1 else list(spec.inputs)
        opts = {k: v for k, v in spec.given().items() if k != "max_splats"}
        scene.mpi = load_scene(inputs, queue=queue, **opts)
    given = spec.near is not None
    if kind in ("mpi_folder",) and not given:
        from clholo.io.load import scene_depth_units

        given = scene_depth_units(spec.inputs[0]) == "metres"
    depths = scene.mpi.depths if scene.mpi is not None else scene.primitives.depths
    if log is not None:
        what = (f"{scene.mpi.layers}-plane MPI ({scene.mpi.shape[0]}x{scene.mpi.shape[1]}x"
                f"{scene.mpi.channels})" if scene.mpi is not None else
                f"{len(scene.primitives)} splat primitives ({scene.primitives.shape[0]}x"
                f"{scene.primitives.shape[1]})")
        units = "m" if given else "scene units"
        log.step(f"scene: {spec.source} -> {what}, depths {np.min(depths):.4g}.."
                 f"{np.max(depths):.4g} {units}", time.perf_counter() - t)
        if "subsampling" in scene.info:
            log.note(f"splats: {scene.info['subsampling']}")
        if kind == "rgbd":
            log.note(_depth_kind_line(spec))
    check_metric_depths(depths, source=spec.source, given=given)
    dark = scene.info.pop("no_light", None) or (
        _no_light(scene.mpi) if scene.mpi is not None else None)
    if dark:  # once, where every command loads its scene: else it renders black in silence
        warnings.warn(f"{spec.source} carries no light: {dark}", NoLightWarning, stacklevel=2)
    return scene


def _depth_kind_line(spec: SceneSpec) -> str:
    """How an RGB-D scene's map was read, for the log: a depth map taken the wrong way round
    renders a plausible scene inside out without a word (MiDaS and Depth Anything write
    relative inverse depth, larger = nearer, in files that say "depth")."""
    from clholo.io.load import rgbd_depth_kind

    path = spec.inputs[-1]
    kind, why = rgbd_depth_kind(path, spec.depth_kind or "auto")
    name = os.path.basename(str(path))
    if kind == "depth":
        other = ("; if larger values are nearer (inverse depth, as MiDaS and Depth Anything "
                 "write), give --depth-kind disparity" if why == "by default" else "")
        return f"depth map: {name} taken as depth ({why}): larger values farther{other}"
    other = ("; if larger values are farther, give --depth-kind depth"
             if why != "as given" else "")
    return f"depth map: {name} taken as disparity ({why}): larger values nearer{other}"


def _no_light(mpi) -> Optional[str]:
    """What makes ``mpi`` carry no light, or None when some pixel has alpha and colour."""
    if not np.any(mpi.alpha > 0):
        return (f"alpha is 0 in every pixel of its {mpi.layers} layer(s), so the hologram is "
                f"all zero and the focal stack black; check the layers' alpha (channel or "
                f"file)")
    for color, alpha in zip(mpi.color, mpi.alpha):  # a layer at a time: no (L, H, W, C) copy
        if np.any(color[alpha > 0] > 0):
            return None
    return ("its colour is 0 (black) wherever alpha is above 0, so the hologram is all zero "
            "and the focal stack black; check the colour channels")


def _load_splats(spec: SceneSpec, scene: Scene, *, needs: str, queue) -> None:
    """A ``.ply``: the seeded subset (``max_splats``), then an MPI or RPWS primitives."""
    from clholo.io.splats import (camera_from_json, check_ply_has_splats, default_camera,
                                  read_ply, splats_to_mpi)

    path = spec.inputs[0]
    check_ply_has_splats(path)  # first: a file without splats says so, not that --near/--far
    if spec.near is None:       # are missing; both at once, from the header alone
        raise InputError(f"the depths of a 3D Gaussian splat .ply ({spec.source}) are in scene "
                         f"units: give --near and --far in metres behind the hologram plane, "
                         f"e.g. --near 0.002 --far 0.006")
    g = read_ply(path)
    if not np.any(g.opacities > 0):  # said by load() as a warning, naming the field
        scene.info["no_light"] = (
            f"the opacity of every one of its {len(g)} splat(s) is 0 (their stored 'opacity' "
            f"logits are far below 0; 3DGS stores logit(opacity), so 0 is an opacity of "
            f"0.5), so the hologram is all zero and the focal stack black; export the trained "
            f"point cloud again")
    if spec.camera_json is not None:
        camera = camera_from_json(spec.camera_json,
                                  0 if spec.camera_index is None else spec.camera_index)
    elif spec.camera_index is not None:
        raise InputError("--camera-index picks a camera of --camera-json: give --camera-json "
                         "(the 3DGS output's cameras.json) too")
    else:
        camera = default_camera(g, width=512)
    if spec.scale is not None and spec.scale != 1.0:
        from clholo.io.load import _check_scale, scaled_size

        scale = _check_scale(spec.scale)
        scaled_size((camera.height, camera.width), scale, what="camera view")
        camera = camera.scaled(scale)
    from clholo.io.splats import check_camera_renders, subsample_visible

    # before any work: a camera of 100000 x 100000 pixels is refused here, named with its file
    # (splats_to_mpi then checks that its slabs fit the device, check_camera_fits)
    check_camera_renders(camera)

    g, note = subsample_visible(g, camera, spec.max_splats, seed=spec.subset_seed,
                                znear=spec.znear)
    scene.info["subsampling"] = note
    scene.info["splats"] = len(g)
    if needs == "primitives":
        from clholo.baselines.rpws import primitives_from_splats

        prims, info = primitives_from_splats(g, camera=camera, near=spec.near, far=spec.far,
                                             znear=spec.znear)
        scene.primitives = prims
        scene.info["splats"] = info["splats"]
    else:
        scene.mpi = splats_to_mpi(g, layers=32 if spec.layers is None else spec.layers,
                                  camera=camera, near=spec.near, far=spec.far,
                                  spacing="index" if spec.spacing is None else spec.spacing,
                                  znear=spec.znear, queue=queue)


ProgressCallback = Callable[[int, int], None]
