"""One entry point for every scene input: :func:`load_scene` (used by ``clholo render``)."""

from __future__ import annotations

from pathlib import Path
from typing import Optional, Sequence, Union

from ..scene import MPI
from .images import PathLike
from .mpi_folder import MPI_JSON, read_mpi
from .rgbd import read_depth, read_rgb, rgbd_to_mpi
from .splats import splats_to_mpi
from .stereo_mag import is_stereo_mag_folder, read_stereo_mag

__all__ = ["load_scene", "detect_kind"]

_DEPTH_SUFFIXES = (".npy", ".pfm", ".dpt", ".exr", ".png", ".tif", ".tiff")


def detect_kind(path_or_paths) -> str:
    """``"mpi_folder"``, ``"stereo_mag"``, ``"rgbd"`` or ``"ply"`` for an input, else ValueError.

    A folder with ``mpi.json`` is an MPI folder; a folder with ``mpi_rgb_NN.png`` a Stereo
    Magnification folder; a ``.ply`` file splats; two paths (image, depth) an RGB-D pair.
    """
    if isinstance(path_or_paths, (list, tuple)):
        if len(path_or_paths) == 1:
            return detect_kind(path_or_paths[0])
        if len(path_or_paths) == 2:
            return "rgbd"
        raise ValueError(f"give one scene path or an (image, depth) pair, got "
                         f"{len(path_or_paths)} paths")
    path = Path(path_or_paths)
    if not path.exists():
        raise FileNotFoundError(f"scene input {path} does not exist")
    if path.is_dir():
        if (path / MPI_JSON).is_file():
            return "mpi_folder"
        if is_stereo_mag_folder(path):
            return "stereo_mag"
        raise ValueError(f"{path} is a folder without mpi.json or mpi_rgb_NN.png files; an MPI "
                         f"folder needs an mpi.json (see docs/inputs.md)")
    if path.name.lower() == MPI_JSON:
        return "mpi_folder"
    if path.suffix.lower() == ".ply":
        return "ply"
    raise ValueError(f"cannot tell what scene {path} is: give an MPI folder, a Stereo "
                     f"Magnification folder, a .ply, or an image and a depth map together")


def load_scene(path_or_paths: Union[PathLike, Sequence[PathLike]], *,
               layers: Optional[int] = None, near: Optional[float] = None,
               far: Optional[float] = None, spacing: str = "index", mode: str = "hard",
               depth_kind: str = "auto", invalid: str = "fill", width: int = 512,
               height: Optional[int] = None, fov_deg: float = 50.0, backend: str = "opencl",
               queue=None) -> MPI:
    """Load any supported scene as an :class:`MPI`.

    Parameters
    ----------
    path_or_paths : path-like or (image, depth) pair
        An MPI folder (``mpi.json``), a Stereo Magnification folder, a 3DGS ``.ply``, or an
        image and a depth/disparity map.
    layers : int, optional
        Planes to make (RGB-D: default 32; splats: slabs, default 32). MPI folders keep their
        own layers: asking for a different number is an error, not a silent resample.
    near, far : float, optional
        Metres behind the hologram plane. Required for RGB-D. For the others, when given the
        layers are placed with :meth:`MPI.placed` (``spacing``); otherwise depths stay as
        stored (scene units for Stereo Magnification and splats).
    spacing : {"index", "depth", "inverse"}
    mode, invalid
        RGB-D options, see :func:`rgbd_to_mpi`.
    depth_kind : {"auto", "depth", "disparity"}
        ``"auto"``: disparity for ``.pfm`` files (Middlebury stores disparities) and for file
        names containing ``disp``, depth otherwise.
    width, height, fov_deg, backend, queue
        Splat options, see :func:`splats_to_mpi`.
    """
    kind = detect_kind(path_or_paths)
    if (near is None) != (far is None):
        raise ValueError("give both near and far (metres), or neither")
    if kind in ("mpi_folder", "stereo_mag"):
        path = path_or_paths[0] if isinstance(path_or_paths, (list, tuple)) else path_or_paths
        mpi = read_mpi(path) if kind == "mpi_folder" else read_stereo_mag(path)
        if layers is not None and layers != mpi.layers:
            raise ValueError(f"{path} has {mpi.layers} layers; --layers {layers} cannot change "
                             f"that for an MPI input (omit it)")
        if near is not None:
            mpi = mpi.placed(near, far, spacing=spacing)
        return mpi
    if kind == "ply":
        path = path_or_paths[0] if isinstance(path_or_paths, (list, tuple)) else path_or_paths
        return splats_to_mpi(path, layers=32 if layers is None else layers, width=width,
                             height=height, fov_deg=fov_deg, near=near, far=far,
                             spacing=spacing, backend=backend, queue=queue)
    image_path, depth_path = (Path(p) for p in path_or_paths)
    if near is None:
        raise ValueError("an RGB-D input needs near and far (metres behind the hologram plane)")
    image = read_rgb(image_path)
    depth = read_depth(depth_path)
    if depth.shape != image.shape[:2]:
        raise ValueError(f"{depth_path} is {depth.shape[1]}x{depth.shape[0]} but {image_path} "
                         f"is {image.shape[1]}x{image.shape[0]}; they must match")
    if depth_kind == "auto":
        name = depth_path.name.lower()
        depth_kind = "disparity" if (name.endswith(".pfm") or "disp" in name) else "depth"
    return rgbd_to_mpi(image, depth, layers=32 if layers is None else layers, near=near,
                       far=far, mode=mode, depth_kind=depth_kind, invalid=invalid, srgb=False)
