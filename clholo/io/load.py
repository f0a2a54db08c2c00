"""One entry point for every scene input: :func:`load_scene` (used by ``clholo render``)."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Optional, Sequence, Tuple, Union

import numpy as np

from ..errors import InputError
from ..scene import MPI, _handed_over
# the fewest pixels a scene keeps per side after --scale; read here by clholo.demo, and
# defined in clholo.validate so that clholo.io.splats can offer a --scale that keeps them
# (splats importing this module would be a cycle)
from ..validate import MIN_SCENE_PIXELS  # noqa: F401
from ._json import read_json
from .depth_photo import find_embedded_depth, read_depth_photo
from .images import PathLike, check_input_file
from .mpi_folder import MPI_JSON, depth_units, read_mpi
from .rgbd import depth_channels, read_depth, read_rgb, rgbd_to_mpi
from .splats import Camera, camera_from_json, default_camera, read_ply, splats_to_mpi
from .stereo_mag import is_stereo_mag_folder, read_stereo_mag

__all__ = ["load_scene", "detect_kind", "scene_depth_units", "downsample_mpi"]

_SCENE_FIX = ("give an MPI folder, a Stereo Magnification folder, a .ply, or an image and its "
              "depth map")
_DEPTH_SUFFIXES = (".npy", ".pfm", ".dpt", ".exr", ".png", ".tif", ".tiff")


def detect_kind(path_or_paths) -> str:
    """``"mpi_folder"``, ``"stereo_mag"``, ``"rgbd"`` or ``"ply"`` for an input, else ValueError.

    A folder with ``mpi.json`` is an MPI folder; a folder with ``mpi_rgb_NN.png`` a Stereo
    Magnification folder; a ``.ply`` file splats; two paths (image, depth) an RGB-D pair, and
    so is one image that holds colour and a depth channel (``Z`` or ``depth``: an EXR's
    ``R G B A Z``, Blender's ``ViewLayer.Depth.Z``).

    Parameters
    ----------
    path_or_paths : str, os.PathLike or sequence of them
        One input path, or an (image, depth) pair.
    """
    if isinstance(path_or_paths, (list, tuple)):
        if len(path_or_paths) == 1:
            return detect_kind(path_or_paths[0])
        if len(path_or_paths) == 2:
            kinds = [_scene_on_its_own(Path(p)) for p in path_or_paths]
            if any(kinds):  # a folder or a .ply is a scene by itself, never half of a pair
                given = " and ".join(f"{p} ({k or _what(Path(p))})"
                                     for p, k in zip(path_or_paths, kinds))
                raise ValueError(f"two scene inputs given, {given}: give one scene; two paths "
                                 f"are an RGB-D pair only as an image and its depth map")
            return "rgbd"
        raise ValueError(f"give one scene path or an (image, depth) pair, got "
                         f"{len(path_or_paths)} paths")
    path = Path(path_or_paths)
    if not path.exists():  # also False for a loop of links or a name with a NUL byte
        check_input_file(path, "scene input", _SCENE_FIX)
    if path.is_dir():
        json_path = path / MPI_JSON
        if json_path.exists():  # never opened here: a named pipe would wait for a writer
            check_input_file(json_path, "MPI folder file", "give mpi.json as a regular file "
                                                           "(see docs/inputs.md)")
            return "mpi_folder"
        if is_stereo_mag_folder(path):
            return "stereo_mag"
        raise ValueError(f"{path} is a folder without mpi.json or mpi_rgb_NN.png files; an MPI "
                         f"folder needs an mpi.json (see docs/inputs.md)")
    check_input_file(path, "scene input", _SCENE_FIX)
    if path.name.lower() == MPI_JSON:
        return "mpi_folder"
    if path.suffix.lower() == ".ply":
        return "ply"
    header = _image_header(path)
    if header is not None:
        names, alpha = header
        found = depth_channels(names)
        colour = [n for i, n in enumerate(names) if i not in found and i != alpha]
        if found and colour:
            return "rgbd"  # colour and depth in one file
        if found:
            raise ValueError(f"{path} holds depth ({', '.join(names)}) but no colour: give "
                             f"the image first, then this file as its depth map")
        if find_embedded_depth(path) is not None:
            return "rgbd"  # a phone photo with its depth map inside
        raise ValueError(f"{path} is an image without a depth channel: give it and its depth "
                         f"map together (image first), or one image with colour and a depth "
                         f"channel named Z (an EXR's R G B A Z), or a phone photo that "
                         f"carries its depth map inside (Dynamic Depth, GDepth, an iPhone's "
                         f"JPEG; see docs/inputs.md)")
    raise ValueError(f"cannot tell what scene {path} is: give an MPI folder, a Stereo "
                     f"Magnification folder, a .ply, or an image and a depth map together")


def _scene_on_its_own(path: Path) -> str:
    """What ``path`` is when it is a whole scene by itself (an MPI folder, a .ply, ...), else
    ''. Never raises: a missing path is for the reader to report."""
    try:
        if path.is_dir():
            if (path / MPI_JSON).is_file():
                return "an MPI folder"
            if is_stereo_mag_folder(path):
                return "a Stereo Magnification folder"
            return "a folder"
        if path.name.lower() == MPI_JSON:
            return "an MPI folder's mpi.json"
        if path.suffix.lower() == ".ply":
            return "a 3D Gaussian splat .ply"
    except OSError:
        pass
    return ""


def _what(path: Path) -> str:
    return "an image or depth map" if path.exists() else "missing"


def scene_depth_units(path_or_paths) -> str:
    """``"metres"`` or ``"scene units"``: what :func:`load_scene` depths are in when no
    ``near``/``far`` place them (RGB-D inputs always need ``near``/``far``: metres)."""
    kind = detect_kind(path_or_paths)
    if kind == "rgbd":
        return "metres"
    if kind == "mpi_folder":
        path = Path(path_or_paths[0] if isinstance(path_or_paths, (list, tuple))
                    else path_or_paths)
        json_path = path if path.suffix.lower() == ".json" else path / MPI_JSON
        try:
            meta = read_json(json_path)
            return depth_units(meta, json_path) if isinstance(meta, dict) else "scene units"
        except (OSError, ValueError):  # read_mpi says what is wrong with it
            return "scene units"
    return "scene units"


def _check_scale(scale) -> float:
    from .. import validate

    scale = validate.real_scalar("scale", scale)
    if not 0 < scale <= 1:
        raise ValueError(f"scale must be a downsampling factor in (0, 1], got {scale!r}; "
                         f"0.5 halves the width and height")
    return scale


def scaled_size(shape, scale: float, *, what: str = "scene") -> Tuple[int, int]:
    """The ``(H, W)`` that ``scale`` makes of a scene of ``shape = (H, W)`` pixels, refused
    when it has fewer than :data:`MIN_SCENE_PIXELS` on its shorter side (a
    focal stack of a few pixels shows nothing a person could judge), as ``clholo demo``
    refuses it. A scene given at that size or smaller is taken as it is (``scale`` 1).

    Parameters
    ----------
    shape : (int, int)
        The scene's height and width in pixels (an MPI's, an image's or a camera's).
    scale : float
        The downsampling factor in (0, 1] (``--scale``).
    what : str
        What the scene is, for the message (``"scene"``, ``"camera view"``).

    Returns
    -------
    (int, int)
        The scaled height and width (``shape`` itself for ``scale`` 1).

    Raises
    ------
    clholo.errors.InputError
        The scaled scene is smaller than ``MIN_SCENE_PIXELS`` on a side; the message gives the
        smallest usable scale (or says to drop it when even 1 is too small).
    """
    H, W = (int(n) for n in shape[:2])
    if scale == 1.0:
        return H, W
    h, w = (int(round(n * scale)) for n in (H, W))
    if min(h, w) >= MIN_SCENE_PIXELS:
        return h, w
    shorter = min(H, W)
    # the smallest scale that keeps MIN_SCENE_PIXELS, rounded up to 3 digits so that it
    # does keep them
    digits = 2 - int(math.floor(math.log10(MIN_SCENE_PIXELS / shorter)))
    least = math.ceil(MIN_SCENE_PIXELS / shorter * 10 ** digits - 1e-9) / 10 ** digits
    fix = (f"use --scale {least:g} or more" if least < 1 else
           f"the {what} has only {shorter} pixels on its shorter side: drop --scale")
    raise InputError(f"--scale {scale:g} (scale={scale:g}) shrinks the {W}x{H} {what} to "
                     f"{max(w, 0)}x{max(h, 0)} pixels, fewer than the {MIN_SCENE_PIXELS} per "
                     f"side a focal stack needs to show anything: {fix}")


def _nearest(array: np.ndarray, size) -> np.ndarray:
    """Nearest-neighbour resampling of the first two axes to ``size`` (pixel centres aligned):
    no value is ever mixed with another, so invalid depths (NaN, inf, 0) stay where they were
    and never leak into valid ones."""
    H, W = array.shape[:2]
    h, w = size
    rows = np.minimum(((np.arange(h) + 0.5) * (H / h)).astype(np.int64), H - 1)
    cols = np.minimum(((np.arange(w) + 0.5) * (W / w)).astype(np.int64), W - 1)
    return array[rows[:, None], cols[None, :]]


#: ``match_size="edges"``: the spread of the distance term, in depth-map pixels, and of the
#: colour term, in linear intensity (an object's edge differs by 0.1 or more)
EDGE_SPATIAL_SIGMA_PX = 1.0
EDGE_COLOUR_SIGMA = 0.1
# photo pixels a band of _edge_guided works on at once
_EDGE_BAND_PIXELS = 1 << 18


def _edge_guided(depth: np.ndarray, image: np.ndarray) -> np.ndarray:
    """``depth`` ``(h, w)`` resized to ``image``'s ``(H, W)`` along the photo's edges: each
    photo pixel takes the depth of one of the 3 x 3 map pixels around it, the one whose colour
    (the photo averaged over that map pixel's footprint) is nearest its own, the nearer map
    pixel where colours are alike (a joint-bilateral choice, Gaussian in distance and colour:
    :data:`EDGE_SPATIAL_SIGMA_PX`, :data:`EDGE_COLOUR_SIGMA`). Like nearest neighbour it never
    mixes depths (no value between two surfaces), but a map's blocky edge follows the
    photo's edge instead of the map's pixel grid."""
    (h, w), (H, W) = depth.shape, image.shape[:2]
    guide = _antialiased(image, (h, w))
    ys = (np.arange(H) + 0.5) * (h / H) - 0.5   # photo pixel centres in map pixels
    xs = (np.arange(W) + 0.5) * (w / W) - 0.5
    rows = np.minimum(((np.arange(H) + 0.5) * (h / H)).astype(np.int64), h - 1)  # _nearest's
    cols = np.minimum(((np.arange(W) + 0.5) * (w / W)).astype(np.int64), w - 1)
    out = np.empty((H, W), depth.dtype)
    spatial = 1.0 / (2.0 * EDGE_SPATIAL_SIGMA_PX ** 2)
    colour = 1.0 / (2.0 * EDGE_COLOUR_SIGMA ** 2)
    band = max(1, _EDGE_BAND_PIXELS // W)
    guide = guide.astype(np.float32)  # the choice needs no more (and moves half the bytes)
    for y0 in range(0, H, band):
        y1 = min(H, y0 + band)
        pixels = image[y0:y1].astype(np.float32)
        best = np.full((y1 - y0, W), np.inf, np.float32)
        chosen = np.empty((y1 - y0, W), depth.dtype)
        for dy, dx in ((dy, dx) for dy in (-1, 0, 1) for dx in (-1, 0, 1)):
            qy = np.clip(rows[y0:y1] + dy, 0, h - 1)
            qx = np.clip(cols + dx, 0, w - 1)
            near = (spatial * ((ys[y0:y1] - qy)[:, None] ** 2 + (xs - qx)[None, :] ** 2))
            diff = pixels - guide[qy][:, qx]  # rows, then columns: two small gathers
            cost = near.astype(np.float32) + np.float32(colour) * np.einsum("ijk,ijk->ij",
                                                                            diff, diff)
            better = cost < best
            np.copyto(best, cost, where=better)
            np.copyto(chosen, depth[qy][:, qx], where=better)
        out[y0:y1] = chosen
    return out


def _antialiased(array: np.ndarray, size) -> np.ndarray:
    """Anti-aliased resampling (Gaussian prefilter, then linear) of axes -3, -2 of a
    ``(..., H, W, C)`` array to ``size``."""
    from skimage.transform import resize

    shape = array.shape[:-3] + tuple(size) + array.shape[-1:]
    return resize(np.asarray(array, np.float64), shape, order=1, anti_aliasing=True,
                  preserve_range=True)


def downsample_mpi(mpi: MPI, scale: float) -> MPI:
    """``mpi`` with ``scale`` times the pixels along each axis, anti-aliased.

    Premultiplied colour ``c a`` and alpha are filtered (so that transparent pixels' colour
    does not bleed into edges), then colour is un-premultiplied (0 where alpha is 0).
    """
    scale = _check_scale(scale)
    size = scaled_size(mpi.shape, scale)
    if size == mpi.shape:
        return mpi
    return resampled_layers(mpi, size)


def resampled_layers(mpi: MPI, size) -> MPI:
    """``mpi`` resampled to ``size = (h, w)`` pixels (up or down; stretched when the aspect
    ratio differs), anti-aliased: premultiplied colour ``c a`` and alpha are filtered, then
    colour is un-premultiplied (0 where alpha is 0). Shared by ``--scale``
    (:func:`downsample_mpi`) and the display loop's resampling to the SLM.

    Parameters
    ----------
    mpi : clholo.MPI
    size : (int, int)
        ``(h, w)`` of the result's layers.
    """
    color = np.empty((mpi.layers,) + tuple(size) + (mpi.channels,), np.float32)
    alpha = np.empty((mpi.layers,) + tuple(size), np.float32)
    # a layer at a time (nothing mixes layers: the same values as the whole stack at once),
    # so that the float64 temporaries are one layer's, not L layers' (32 layers of a
    # 12-megapixel photo are 12 GB as one float64 stack)
    for i in range(mpi.layers):
        a = mpi.alpha[i].astype(np.float64)[..., None]
        premult = _antialiased(mpi.color[i] * a, size)
        kept = np.clip(_antialiased(a, size), 0.0, 1.0)
        color[i] = np.clip(np.where(kept > 1e-6, premult / np.maximum(kept, 1e-6), 0.0), 0.0,
                           1.0)
        alpha[i] = kept[..., 0]
    return MPI(_handed_over(color), _handed_over(alpha), mpi.depths)


def load_scene(path_or_paths: Union[PathLike, Sequence[PathLike]], *,
               layers: Optional[int] = None, near: Optional[float] = None,
               far: Optional[float] = None, spacing: Optional[str] = None, mode: str = "hard",
               depth_kind: str = "auto", depth_spacing: str = "linear", invalid: str = "fill",
               match_size: Optional[str] = None, scale: float = 1.0,
               min_depth: Optional[float] = None, max_depth: Optional[float] = None,
               width: Optional[int] = None, height: Optional[int] = None,
               fov_deg: Optional[float] = None,
               camera: Optional[Camera] = None, camera_json: Optional[PathLike] = None,
               camera_index: Optional[int] = None, znear: Optional[float] = None,
               backend: Optional[str] = None, queue=None) -> MPI:
    """Load any supported scene as an :class:`MPI`.

    Parameters
    ----------
    path_or_paths : path-like or (image, depth) pair
        An MPI folder (``mpi.json``), a Stereo Magnification folder, a 3DGS ``.ply``, an
        image and a depth/disparity map (``.npy``, ``.pfm``, Sintel ``.dpt``, images), one
        image with colour and a depth channel named ``Z`` or ``depth`` (an RGB-D EXR such as
        Blender's ``R G B A Z``), or a phone's depth photo, a JPEG that carries its depth map
        (Dynamic Depth, GDepth, Apple's MPF images: :func:`~clholo.io.read_depth_photo`).
    layers : int, optional
        Planes to make (RGB-D: default 32; splats: slabs, default 32). MPI folders keep their
        own layers: asking for a different number is an error, not a silent resample.
    near, far : float, optional
        Metres behind the hologram plane. Required for RGB-D. For the others, when given the
        layers are placed with :meth:`MPI.placed` (``spacing``); otherwise depths stay as
        stored (scene units for Stereo Magnification and splats, see
        :func:`scene_depth_units`).
    spacing : {"index", "depth", "inverse"}, optional
        How ``near``/``far`` re-place the planes of MPI, Stereo Magnification and splat inputs
        (default ``"index"``). Given without ``near``/``far``, or for an RGB-D pair (whose
        planes ``depth_spacing`` spaces), it would not act: refused.
    mode, invalid
        RGB-D options, see :func:`rgbd_to_mpi`.
    depth_kind : {"auto", "depth", "disparity"}
        ``"auto"``: disparity for ``.pfm`` files (Middlebury stores disparities) and for file
        names containing ``disp``, depth otherwise.
    depth_spacing : {"linear", "disparity"}
        RGB-D: planes uniform in the map's own values, or uniform in disparity (inverse depth;
        the same for a disparity map), see :func:`rgbd_to_mpi`.
    match_size : {"photo", "edges", "depth"}, optional
        RGB-D: what to do when the depth map has the photo's shape at another size (a phone's
        depth map is smaller than its photo: 768x576 for 4032x3024). ``"photo"``: the depth map
        is resized to the photo's size, nearest neighbour (edges never blend into depths
        between the surfaces); ``"edges"``: the same, but each photo pixel takes the depth of
        the one of its 3 x 3 nearest map pixels whose colour is nearest its own (the map's
        blocky edges follow the photo's; still no depth between surfaces); ``"depth"``: the
        photo is resized to the depth map's size, anti-aliased in linear colour (fewer pixels
        to render). Default: refused, naming both sizes, as sizes that differ otherwise are
        (another shape, or turned a quarter). A depth photo's own map stands for the whole
        photo: resized to it as ``"photo"`` does unless ``"edges"`` or ``"depth"``.
    scale : float
        Downsampling factor in (0, 1] for every input (after ``match_size``): RGB-D colour
        anti-aliased and depth nearest-neighbour (invalid pixels never mix with valid ones); MPI layers anti-aliased
        (premultiplied); splats render ``scale`` times the camera's pixels.
    min_depth, max_depth : float, optional
        Stereo Magnification folders: the network's plane range in scene units (its defaults
        1 and 100).
    width, height, fov_deg, backend, queue
        Splat options, see :func:`splats_to_mpi`: size of the default camera (``width``
        default 512), or the size a ``camera_json`` camera is rescaled to (default its own);
        ``fov_deg`` default 50, ``backend`` default ``"opencl"``. Refused for other inputs.
    camera : Camera, optional
        Splats: the camera to render from (default :func:`default_camera`).
    camera_json, camera_index : path-like, int, optional
        Splats: training camera ``camera_index`` (default 0) of a 3DGS ``cameras.json``, see
        :func:`camera_from_json`.
    znear : float, optional
        Splats: near plane in scene units; default relative to the scene (see :func:`project`).
    """
    kind = detect_kind(path_or_paths)
    if (near is None) != (far is None):
        raise ValueError("give both near and far (metres), or neither")
    if spacing is not None and kind == "rgbd":
        raise InputError(f"spacing={spacing!r} re-places the planes of an MPI, a Stereo "
                         f"Magnification folder or splats; an RGB-D pair's planes are spaced "
                         f"by depth_spacing: drop spacing")
    if spacing is not None and near is None:  # it would not act: the depths stay as stored
        raise InputError(f"spacing={spacing!r} places the planes between near and far: give "
                         f"both (metres behind the hologram plane), or drop spacing")
    spacing = "index" if spacing is None else spacing
    if match_size not in (None, "photo", "edges", "depth"):
        raise ValueError(f"match_size must be 'photo' (the depth map resized to the photo's "
                         f"size), 'edges' (the same along the photo's edges), 'depth' (the "
                         f"photo to the depth map's) or None, got {match_size!r}")
    if match_size is not None and kind != "rgbd":
        raise InputError(f"match_size={match_size!r} resizes an RGB-D pair's photo or depth "
                         f"map; this input is {kind!r}: drop match_size")
    scale = _check_scale(scale)
    if kind != "stereo_mag" and (min_depth is not None or max_depth is not None):
        raise ValueError(f"min_depth/max_depth describe Stereo Magnification folders; this "
                         f"input is {kind!r} (omit them)")
    splat_only = {"camera": camera, "camera_json": camera_json, "camera_index": camera_index,
                  "znear": znear, "width": width, "height": height, "fov_deg": fov_deg,
                  "backend": backend}
    given = [k for k, v in splat_only.items() if v is not None]
    if kind != "ply" and given:
        raise ValueError(f"{', '.join(given)} apply to 3D Gaussian splat .ply inputs; this "
                         f"input is {kind!r} (omit them)")
    if kind in ("mpi_folder", "stereo_mag"):
        path = path_or_paths[0] if isinstance(path_or_paths, (list, tuple)) else path_or_paths
        # placed as they are read: scene-unit depths (a scene in millimetres: 18000) are no
        # MPI's metres until near/far place them (downsampling leaves the depths as they are)
        if kind == "mpi_folder":
            _check_layer_files(path)
            mpi = read_mpi(path, near=near, far=far, spacing=spacing)
        else:
            mpi = read_stereo_mag(path, min_depth=1.0 if min_depth is None else min_depth,
                                  max_depth=100.0 if max_depth is None else max_depth,
                                  near=near, far=far, spacing=spacing)
        if layers is not None and layers != mpi.layers:
            raise ValueError(f"{path} has {mpi.layers} layers; --layers {layers} cannot change "
                             f"that for an MPI input (omit it)")
        if scale != 1.0:
            mpi = downsample_mpi(mpi, scale)
        return mpi
    if kind == "ply":
        path = path_or_paths[0] if isinstance(path_or_paths, (list, tuple)) else path_or_paths
        gaussians = read_ply(path)
        if camera is not None and camera_json is not None:
            raise ValueError("give camera or camera_json, not both")
        sizing = [k for k, v in (("width", width), ("height", height), ("fov_deg", fov_deg))
                  if v is not None and (camera is not None or k == "fov_deg"
                                        and camera_json is not None)]
        if sizing:
            raise InputError(f"{', '.join(sizing)} size the default camera (width and height "
                             f"also rescale camera_json's); the camera given has its own: omit "
                             f"{'them' if len(sizing) > 1 else 'it'}")
        if camera_json is not None:
            camera = camera_from_json(camera_json, 0 if camera_index is None else camera_index,
                                      width=width, height=height)
        elif camera_index is not None:
            raise ValueError("camera_index picks a camera of camera_json: give camera_json "
                             "(the 3DGS output's cameras.json) too")
        elif camera is None:
            camera = default_camera(gaussians, width=512 if width is None else width,
                                    height=height, fov_deg=50.0 if fov_deg is None else fov_deg)
        if scale != 1.0:
            scaled_size((camera.height, camera.width), scale, what="camera view")
            camera = camera.scaled(scale)
        return splats_to_mpi(gaussians, layers=32 if layers is None else layers, camera=camera,
                             near=near, far=far, spacing=spacing, znear=znear,
                             backend="opencl" if backend is None else backend, queue=queue)
    # both checked before either is opened (_channels, read_rgb): a named pipe would wait for
    # a writer that never comes
    if not isinstance(path_or_paths, (list, tuple)):
        path_or_paths = (path_or_paths,)
    if len(path_or_paths) == 1:  # one image with colour and depth (detect_kind said so)
        path_or_paths = (path_or_paths[0], path_or_paths[0])
    image_path, depth_path = (check_input_file(p, "scene input", fix) for p, fix in zip(
        path_or_paths, ("give an image file (PNG, EXR, ...), then its depth map",
                        "give the image, then a depth map file (.npy, .pfm, .dpt or an image)")))
    one_file = image_path.resolve() == depth_path.resolve()
    if image_path.suffix.lower() in (".npy", ".pfm", ".dpt"):
        swapped = ("; they look swapped" if depth_path.suffix.lower() not in
                   (".npy", ".pfm", ".dpt") else "")
        raise InputError(f"{image_path} is a depth map's format ({image_path.suffix}), given "
                         f"where the colour image goes{swapped}: give the colour image first, "
                         f"then its depth map")
    no_channel = one_file and not depth_channels((_image_header(image_path) or ((), -1))[0])
    embedded = no_channel and find_embedded_depth(image_path) is not None
    if embedded and depth_kind not in ("auto", "depth"):
        raise InputError(f"depth_kind={depth_kind!r}: {image_path} carries its depth map inside, "
                         f"which its own metadata decodes to depths (larger values farther); "
                         f"taking them as disparities would turn the scene inside out: drop "
                         f"depth_kind")
    if one_file and not no_channel and depth_kind == "disparity":
        raise InputError(f"depth_kind='disparity': {image_path}'s depth channel (named Z or "
                         f"depth) holds depths, larger values farther; taking them as "
                         f"disparities would turn the scene inside out: drop depth_kind")
    if no_channel and not embedded:
        raise InputError(f"{image_path} is given as both the image and its depth map but has "
                         f"no depth channel (named Z or depth): give the image, then its "
                         f"depth map")
    if near is None:
        raise ValueError("an RGB-D input needs near and far (metres behind the hologram plane)")
    if not one_file and depth_channels((_image_header(image_path) or ((), -1))[0]):
        from clholo.validate import warn_at_caller

        from .rgbd import DepthMapWarning

        warn_at_caller(f"{image_path} carries its own depth channel (Z), and {depth_path} is "
                       f"given as the depth map too: the depth map is used, the image's "
                       f"channel is not (give the image alone to use its own)",
                       DepthMapWarning)
    image_channels, depth_count = _channels(image_path), _channels(depth_path)
    if not one_file and image_channels == 1 and (depth_count or 0) >= 3:
        # a grey image first and a colour one second: the depth map would be shown as the
        # picture (clipped to [0, 1]) and the picture's red taken for depths, without a word
        raise InputError(f"{image_path} has 1 channel and {depth_path} has {depth_count}: "
                         f"they look swapped; give the colour image first, then its depth map")
    if embedded:
        image, depth = _depth_photo(image_path, match_size)
    else:
        image = read_rgb(image_path)
        depth = read_depth(depth_path)
    if depth.shape != image.shape[:2]:
        if match_size is not None and _same_shape(depth.shape, image.shape[:2]):
            if match_size == "photo":
                depth = _nearest(depth, image.shape[:2])
            elif match_size == "edges":
                depth = _edge_guided(depth, image)
            else:
                image = np.clip(_antialiased(image, depth.shape), 0.0, 1.0).astype(np.float32)
        else:
            turned = ("; the sizes are transposed: is one turned a quarter? (clholo turns an "
                      "image upright by its EXIF Orientation tag, as viewers show it: save the "
                      "depth map upright too)"
                      if depth.shape == image.shape[1::-1] else _smaller_map(depth.shape,
                                                                             image.shape[:2]))
            raise ValueError(f"{depth_path} is {depth.shape[1]}x{depth.shape[0]} but "
                             f"{image_path} is {image.shape[1]}x{image.shape[0]}; they must "
                             f"match{turned}")
    if scale != 1.0:
        size = scaled_size(depth.shape, scale)
        image = np.clip(_antialiased(image, size), 0.0, 1.0).astype(np.float32)
        depth = _nearest(depth, size)
    depth_kind, _ = rgbd_depth_kind(depth_path, depth_kind)
    try:
        return rgbd_to_mpi(image, depth, layers=32 if layers is None else layers, near=near,
                           far=far, mode=mode, depth_kind=depth_kind,
                           depth_spacing=depth_spacing, invalid=invalid, srgb=False)
    except ValueError as exc:
        if str(exc).startswith("depth "):  # name the file the user gave
            raise ValueError(f"{depth_path}: {exc}") from None
        raise


def _depth_photo(path: Path, match_size: Optional[str]) -> Tuple[np.ndarray, np.ndarray]:
    """A phone photo's colour and embedded depth map at one size. The map stands for the
    whole photo (GDepth's words: it is "stretched to fit" the colour image), so a smaller one
    is resized to the photo's size (nearest neighbour) without being asked, or the photo to
    the map's with ``match_size="depth"``; one turned a quarter against the photo is
    refused."""
    image, depth, _ = read_depth_photo(path)
    size, shape = depth.shape, image.shape[:2]
    if size == shape:
        return image, depth
    if size == shape[::-1] and not _same_shape(size, shape):
        raise ValueError(f"{path}: its embedded depth map is {size[1]}x{size[0]} but the photo "
                         f"is {shape[1]}x{shape[0]}: turned a quarter against it (the photo's "
                         f"EXIF Orientation tag and the map disagree); give the photo and a "
                         f"depth map file, both upright")
    if match_size == "depth":
        return np.clip(_antialiased(image, size), 0.0, 1.0).astype(np.float32), depth
    if match_size == "edges":
        return image, _edge_guided(depth, image)
    return image, _nearest(depth, shape)


def _same_shape(depth_shape, image_shape) -> bool:
    """The depth map and the photo have one shape (aspect ratio) to a pixel, at any sizes."""
    (dh, dw), (ih, iw) = depth_shape, image_shape
    return abs(dh * iw - dw * ih) <= max(iw, ih, dw, dh)


def _smaller_map(depth_shape, image_shape) -> str:
    """A hint for a depth map of the photo's shape at another size (a phone's depth map is
    smaller than its photo): the option that resizes one to the other. Empty when the shapes
    differ."""
    (dh, dw), (ih, iw) = depth_shape, image_shape
    if not _same_shape(depth_shape, image_shape):
        return ""
    how = (f"match_size='photo' (--match-size photo) resizes the depth map to {iw}x{ih} "
           f"(nearest neighbour, so that edges do not blend into in-between depths; 'edges' "
           f"along the photo's edges), "
           f"match_size='depth' (--match-size depth) the photo to {dw}x{dh} (anti-aliased)")
    if dh < ih:
        return f"; the depth map is the photo's shape {ih / dh:.3g}x smaller (a phone's is): {how}"
    return f"; the depth map is the photo's shape {dh / ih:.3g}x larger: {how}"


def rgbd_depth_kind(depth_path: PathLike, depth_kind: str = "auto") -> Tuple[str, str]:
    """What :func:`load_scene` takes an RGB-D pair's map ``depth_path`` for, and why:
    ``("depth" | "disparity", reason)``.

    ``depth_kind="auto"``: disparity for a ``.pfm`` (Middlebury stores disparities) and for a
    file name containing ``disp``, depth otherwise (an image's ``Z`` channel is depth). The
    reason is a phrase for a log line ("a .pfm", "its name says disp", "its Z channel", "by
    default", "as given").

    Parameters
    ----------
    depth_path : path-like
        The depth or disparity map (or the one image with colour and a ``Z`` channel).
    depth_kind : {"auto", "depth", "disparity"}
    """
    if depth_kind != "auto":
        return depth_kind, "as given"
    header = _image_header(Path(depth_path))
    if header is not None and depth_channels(header[0]):
        return "depth", "its Z channel: depth by OpenEXR's convention"
    try:
        embedded = find_embedded_depth(depth_path) if header is not None else None
    except (OSError, ValueError):  # load_scene says what is wrong with it
        embedded = None
    if embedded is not None:
        return "depth", f"the map inside the photo, decoded by its metadata: {embedded.describe()}"
    name = Path(depth_path).name.lower()
    if name.endswith(".pfm"):
        return "disparity", "a .pfm: Middlebury's disparities"
    if "disp" in name:
        return "disparity", "its name says disp"
    return "depth", "by default"


def _check_layer_files(path: PathLike) -> None:
    """Refuse a layer file of an MPI folder that is a named pipe, a device or a socket,
    before anything opens it: opening a pipe waits for a writer that may never come, and
    :func:`read_mpi` (which reads only what ``is_file`` calls a file) would say that it does
    not exist. Everything else is :func:`read_mpi`'s to check and report."""
    path = Path(path)
    json_path = path if path.suffix.lower() == ".json" else path / MPI_JSON
    try:
        meta = read_json(json_path)
    except (OSError, ValueError):
        return
    layers = meta.get("layers") if isinstance(meta, dict) else None
    for index, entry in enumerate(layers if isinstance(layers, list) else []):
        names = ([entry] if isinstance(entry, str) else
                 [entry.get("color"), entry.get("alpha")] if isinstance(entry, dict) else [])
        for name in names:
            if not isinstance(name, str) or not name:
                continue
            layer = json_path.parent / name
            if layer.exists() and not (layer.is_dir() or layer.is_file()):
                check_input_file(layer, f"{json_path}: layer {index} file",
                                 "give the layer's image file")


def _image_header(path: Path) -> Optional[Tuple[Tuple[str, ...], int]]:
    """An image file's channel names and alpha channel's index (-1: none) from its header;
    None for files that are not images (.npy, .pfm, .dpt) or that OpenImageIO cannot open."""
    if path.suffix.lower() in (".npy", ".pfm", ".dpt"):
        return None
    from .images import _oiio

    oiio = _oiio()
    inp = oiio.ImageInput.open(str(path))
    if inp is None:
        oiio.geterror()  # clear it: the caller reports what the path is instead
        return None
    try:
        spec = inp.spec()
        return tuple(spec.channelnames), int(spec.alpha_channel)
    finally:
        inp.close()


def _channels(path: Path) -> Optional[int]:
    """Colour channels of an image file (alpha and depth channels not counted) from its
    header, None for files that are not images or that OpenImageIO cannot open."""
    header = _image_header(path)
    if header is None:
        return None
    names, alpha = header
    return len(names) - len(set(depth_channels(names)) | ({alpha} if alpha >= 0 else set()))
