"""Scene and hologram file input/output (see ``docs/inputs.md``).

* MPI folders: :func:`read_mpi`, :func:`write_mpi`
* Stereo Magnification output: :func:`read_stereo_mag`
* RGB-D: :func:`read_depth` (``.npy``, ``.pfm``, Sintel ``.dpt``, images), :func:`read_rgb`
  (embedded ICC profiles applied: :mod:`clholo.io.icc`, :class:`ColourProfileWarning`),
  :func:`rgbd_to_mpi`; phone photos with their depth map inside (Dynamic Depth, GDepth,
  Apple's MPF images): :func:`read_depth_photo` (:mod:`clholo.io.depth_photo`)
* 3D Gaussian splats: :func:`read_ply`, :func:`splats_to_mpi`, :func:`camera_from_json` (and
  the pieces in :mod:`clholo.io.splats`)
* Holograms: :func:`write_hologram`, :func:`read_hologram`
* Anything: :func:`load_scene`
* Output folders that never replace what clholo did not write: :func:`output_folder`
"""

from .depth_photo import DepthPhotoWarning, read_depth_photo
from .holograms import read_hologram, write_hologram
from .icc import ColourProfileWarning
from .images import linear_to_srgb, linear_to_srgb8, read_image, srgb_to_linear, write_image
from .load import detect_kind, load_scene
from .mpi_folder import read_mpi, write_mpi
from .output import check_output_folder, is_clholo_output, output_folder
from .rgbd import (DepthMapWarning, fill_invalid, read_depth, read_dpt, read_pfm, read_rgb,
                   rgbd_to_mpi)
from .splats import (Camera, Gaussians, SplatCullWarning, camera_from_json, default_camera,
                     project, read_cameras_json, read_ply, splats_to_mpi)
from .stereo_mag import read_stereo_mag

__all__ = [
    "read_mpi", "write_mpi", "read_stereo_mag", "read_depth", "read_pfm", "read_dpt", "read_rgb",
    "fill_invalid", "rgbd_to_mpi", "read_ply", "Gaussians", "Camera", "default_camera",
    "camera_from_json", "read_cameras_json", "SplatCullWarning", "ColourProfileWarning",
    "DepthMapWarning",
    "project", "splats_to_mpi", "write_hologram", "read_hologram", "load_scene", "detect_kind",
    "read_image", "write_image", "srgb_to_linear", "linear_to_srgb", "linear_to_srgb8",
    "check_output_folder",
    "output_folder", "is_clholo_output", "read_depth_photo", "DepthPhotoWarning",
]
