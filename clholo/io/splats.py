"""3D Gaussian splats (``.ply`` of the original 3DGS code) to an MPI of D depth slabs.

Pipeline (HOLOGRAPHY.md section 7):

1. :func:`read_ply` -- binary little-endian (or ASCII) PLY with ``x y z f_dc_0..2 opacity
   scale_0..2 rot_0..3``: opacity through a sigmoid, scales through ``exp``, the quaternion
   ``(w, x, y, z)`` normalised, colour ``0.5 + 0.28209479 f_dc`` clipped to [0, 1] (degree-0 SH;
   higher orders are ignored: an MPI layer has one colour per pixel, not per direction).
2. :func:`project` -- pinhole :class:`Camera` (OpenCV axes: x right, y down, z forward; pixel
   ``(row, col)`` has its centre at ``(y, x) = (row, col)``), EWA splatting as in 3DGS
   rasterisers: ``Sigma2 = J W Sigma W^T J^T + 0.3 I`` (the 0.3 px^2 low-pass dilation), with
   3DGS's clamping of the Jacobian's evaluation point to 1.3x the field of view; 3-sigma radius.
3. Sort by camera depth, assign each splat the slab its centre falls in (D slabs uniform in
   inverse depth or in depth between the nearest and farthest visible splat).
4. Rasterise (:func:`rasterize_slabs`): OpenCL, tiles of 16x16 pixels with per-tile splat lists
   built on the host; :func:`rasterize_slabs_reference` is the NumPy reference (same float32
   arithmetic). Front to back within each slab with the 3DGS rules (alpha <= 0.99, skip
   < 1/255, stop at transmittance < ``t_min``):
   ``alpha_d = 1 - prod(1 - alpha_k)``,
   ``c_d = sum_k alpha_k c_k prod_{j<k}(1 - alpha_j) / alpha_d``.
   The "over" of the slabs then equals ordinary 3DGS blending.

Colour: 3DGS is trained on sRGB images, so its colours and its blending live in sRGB values.
The slabs are composited in that space (so that their over-composite is the 3DGS render) and
:func:`splats_to_mpi` decodes each slab's colour to linear intensity at the end.

Scaling: projection, sorting and tile binning are vectorised NumPy (a few seconds for millions
of splats); the per-pixel work, which grows with pixels x overlapping splats, runs on the device.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Dict, List, Optional, Tuple

import numpy as np

from .. import validate
from ..scene import MPI, stored_or_placed_depths
from ._json import read_json
from .images import PathLike, check_input_file, srgb_to_linear

__all__ = ["Gaussians", "Camera", "read_ply", "default_camera", "project", "Projected",
           "rasterize_slabs", "rasterize_slabs_reference", "slab_edges", "tile_lists",
           "splats_to_mpi", "SH_C0", "SplatCullWarning", "auto_znear", "read_cameras_json",
           "camera_from_json", "NEAR_FRACTION", "subsample_visible", "check_camera_fits",
           "check_camera_renders"]

SH_C0 = 0.28209479177387814
TILE = 16
#: The automatic near plane, as a fraction of the median camera depth of the splats in front of
#: the camera (3DGS culls at an absolute 0.2 scene units, which swallows whole small scenes).
NEAR_FRACTION = 0.01


class SplatCullWarning(UserWarning):
    """Splats were dropped because they lie behind the camera or nearer than its near plane."""
_PLY_FIX = "give a 3D Gaussian splat .ply file"
_NEEDED = ("x", "y", "z", "f_dc_0", "f_dc_1", "f_dc_2", "opacity", "scale_0", "scale_1",
           "scale_2", "rot_0", "rot_1", "rot_2", "rot_3")
_PLY_TYPES = {"char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1", "short": "i2",
              "int16": "i2", "ushort": "u2", "uint16": "u2", "int": "i4", "int32": "i4",
              "uint": "u4", "uint32": "u4", "float": "f4", "float32": "f4", "double": "f8",
              "float64": "f8"}


@dataclass(frozen=True, eq=False)
class Gaussians:
    """N 3D Gaussians in world (scene) units, activated.

    Attributes
    ----------
    means : ndarray, shape (N, 3), float32
    scales : ndarray, shape (N, 3), float32
        Standard deviations along the local axes (``exp`` of the stored logs).
    rotations : ndarray, shape (N, 4), float32
        Unit quaternions ``(w, x, y, z)``.
    opacities : ndarray, shape (N,), float32
        In (0, 1) (sigmoid of the stored logits).
    colors : ndarray, shape (N, 3), float32
        sRGB-encoded colour in [0, 1] from the degree-0 SH coefficient.
    """

    means: np.ndarray
    scales: np.ndarray
    rotations: np.ndarray
    opacities: np.ndarray
    colors: np.ndarray

    def __post_init__(self) -> None:
        n = np.asarray(self.means).shape[0]
        shapes = {"means": (n, 3), "scales": (n, 3), "rotations": (n, 4), "opacities": (n,),
                  "colors": (n, 3)}
        for name, shape in shapes.items():
            arr = np.ascontiguousarray(np.asarray(getattr(self, name), dtype=np.float32))
            if arr.shape != shape:
                raise ValueError(f"{name} must have shape {shape}, got {arr.shape}")
            if not np.all(np.isfinite(arr)):
                raise ValueError(f"{name} contains NaN/inf")
            object.__setattr__(self, name, arr)
        q = self.rotations
        norm = np.linalg.norm(q, axis=1, keepdims=True)
        if np.any(norm == 0):
            raise ValueError("rotations contains a zero quaternion; it has no orientation")
        object.__setattr__(self, "rotations", (q / norm).astype(np.float32))

    def __len__(self) -> int:
        return int(self.means.shape[0])

    @classmethod
    def from_raw(cls, x, y, z, f_dc, opacity_logit, log_scales, quats) -> "Gaussians":
        """Activate stored 3DGS values (logit opacity, log scales, raw quaternion, SH DC).

        Parameters
        ----------
        x, y, z : array ``(N,)``
            Centres, scene units.
        f_dc : array ``(N, 3)``
            Spherical-harmonic DC coefficients (colour ``0.5 + SH_C0 f_dc``, clipped to [0, 1]).
        opacity_logit : array ``(N,)``
            Opacity before the sigmoid.
        log_scales : array ``(N, 3)``
            Natural logarithms of the scales, scene units.
        quats : array ``(N, 4)``
            Rotations as stored (not yet normalised).

        Raises
        ------
        ValueError
            A stored value that is NaN or inf, or that activation would turn into one (a
            log-scale whose ``exp`` overflows float32: a linear scale stored); the message
            names the PLY property, the splat and the value.
        """
        x, y, z, opacity_logit = (np.asarray(v, np.float64) for v in (x, y, z, opacity_logit))
        f_dc, log_scales, quats = (np.asarray(v, np.float64) for v in (f_dc, log_scales, quats))
        _check_stored(x, y, z, f_dc, opacity_logit, log_scales, quats)
        means = np.stack([x, y, z], axis=1)
        with np.errstate(over="ignore"):  # a logit far below 0 is opacity 0: exp(inf) is right
            opacity = 1.0 / (1.0 + np.exp(-opacity_logit))
        colors = np.clip(0.5 + SH_C0 * f_dc, 0.0, 1.0)
        return cls(means, np.exp(log_scales), quats, opacity, colors)


#: The largest stored log-scale whose ``exp`` is a float32 (about 88.72).
_LOG_SCALE_MAX = float(np.log(np.finfo(np.float32).max))


def _check_stored(x, y, z, f_dc, opacity_logit, log_scales, quats) -> None:
    """Refuse stored 3DGS values that activation would turn into inf or NaN, naming the PLY
    property, the splat and the value (the caller adds the file): NaN anywhere, a centre or
    quaternion that is infinite or beyond float32, a log-scale whose ``exp`` overflows float32
    (a linear scale stored where 3DGS stores its logarithm). Shapes are :class:`Gaussians`' to
    check."""
    top = float(np.finfo(np.float32).max)
    columns = [("x", x), ("y", y), ("z", z), ("opacity", opacity_logit)]
    for name, arr, count in (("f_dc", f_dc, 3), ("scale", log_scales, 3), ("rot", quats, 4)):
        if arr.ndim == 2 and arr.shape[1] == count:
            columns += [(f"{name}_{i}", arr[:, i]) for i in range(count)]
    for name, v in columns:
        if v.ndim != 1:
            continue
        if name.startswith(("f_dc_", "opacity")):
            # +-inf have limits (colour clipped to 0 or 1, opacity 0 or 1; trained files hold
            # logits of inf); NaN has none
            bad = np.isnan(v)
        elif name.startswith("scale_"):  # -inf is a scale of 0
            bad = np.isnan(v) | (v > _LOG_SCALE_MAX)
        else:  # cast to float32 as stored
            bad = ~np.isfinite(v) | (np.abs(v) > top)
        if not bad.any():
            continue
        k = int(np.argmax(bad))
        more = f" ({int(bad.sum())} splats in all)" if bad.sum() > 1 else ""
        if name.startswith("scale_") and np.isfinite(v[k]):
            raise ValueError(
                f"{name} of splat {k} is {v[k]:g}{more}: 3DGS stores each scale as its natural "
                f"logarithm, and exp({v[k]:g}) overflows (at most {_LOG_SCALE_MAX:.4g}); a "
                f"file of linear scales must store log(scale): export the point cloud again")
        what = "not finite" if not np.isfinite(v[k]) else "beyond float32"
        raise ValueError(f"{name} of splat {k} is {v[k]:g}{more}: every stored value must be a "
                         f"finite number ({what}); export the trained point cloud again")


def check_ply_has_splats(path: PathLike) -> None:
    """Refuse, from its first bytes only (fast for any size), a ``.ply`` that holds no splats
    (an empty file, or a header saying ``element vertex 0``) or that is not a PLY: what
    :func:`read_ply` would say, before slower checks (such as missing ``--near/--far``)."""
    path = check_input_file(path, "PLY file", _PLY_FIX)
    with open(path, "rb") as f:
        head = f.read(1 << 16)
    if not head.strip():
        raise ValueError(f"{path} holds no splats (the file is empty, {path.stat().st_size} "
                         f"bytes); export the trained point cloud again")
    if not head.startswith(b"ply"):
        raise ValueError(f"{path} is not a PLY file (it does not start with 'ply')")
    for line in head.split(b"end_header", 1)[0].decode("ascii", errors="replace").splitlines():
        parts = line.split()
        if len(parts) == 3 and parts[:2] == ["element", "vertex"] and parts[2] == "0":
            raise ValueError(f"{path} holds no splats (its header says 'element vertex 0'); "
                             f"export the trained point cloud again")


def _ply_count(path: Path, number: int, line: str, word: str, *, minimum: int) -> int:
    try:
        count = int(word)
    except ValueError:
        count = None
    if count is None or count < minimum:
        what = "a whole number" + (" >= 1" if minimum == 1 else " >= 0")
        raise ValueError(f"{path}: line {number}: {line.strip()!r}: the count {word!r} is not "
                         f"{what}; the header says how many splats follow "
                         f"('element vertex N'): export the point cloud again")
    return count


def _parse_ply_header(path: Path, header: List[str]):
    """The format and the elements ``[(name, count, [(property, dtype or None)])]`` of a PLY
    header (its lines before ``end_header``); a malformed line is refused as
    ``FILE: line N: ...`` with what it should be."""
    fmt = None
    elements = []  # (name, count, [(prop, dtype)])
    expected = {"format": "'format binary_little_endian 1.0' (or binary_big_endian, ascii)",
                "element": "'element NAME COUNT'",
                "property": "'property TYPE NAME' (or 'property list COUNT_TYPE TYPE NAME')"}
    for number, line in enumerate(header, start=1):
        parts = line.split()
        if not parts or parts[0] in ("ply", "comment", "obj_info"):
            continue
        key = parts[0]
        shape_ok = {"format": len(parts) == 3, "element": len(parts) == 3,
                    "property": (len(parts) == 5 if len(parts) > 1 and parts[1] == "list"
                                 else len(parts) == 3)}
        if key not in shape_ok:
            raise ValueError(f"{path}: line {number}: {line.strip()!r} is not a PLY header "
                             f"line (they start with format, element, property, comment or "
                             f"obj_info); the header is corrupt")
        if not shape_ok[key]:
            raise ValueError(f"{path}: line {number}: {line.strip()!r} is malformed: expected "
                             f"{expected[key]}")
        if key == "format":
            fmt = parts[1]
        elif key == "element":
            name = parts[1]
            minimum = 1 if (name == "vertex" and not elements) else 0
            if minimum == 1 and parts[2] == "0":  # said as before: the file holds no splats
                raise ValueError(f"{path} holds no splats (its header says 'element vertex 0'); "
                                 f"export the trained point cloud again")
            elements.append((name, _ply_count(path, number, line, parts[2], minimum=minimum),
                             []))
        else:
            if not elements:
                raise ValueError(f"{path}: line {number}: property before any element in the "
                                 f"PLY header")
            name = parts[-1]
            if any(name == known for known, _ in elements[-1][2]):
                # which of the two holds the splats' values cannot be told (NumPy's record
                # type refused it with "field 'x' occurs more than once", naming no file)
                raise ValueError(f"{path}: line {number}: property {name!r} of element "
                                 f"{elements[-1][0]!r} is listed twice in the PLY header; "
                                 f"the file is corrupt: export the point cloud again")
            if parts[1] == "list":
                elements[-1][2].append((parts[-1], None))
            else:
                if parts[1] not in _PLY_TYPES:
                    raise ValueError(f"{path}: line {number}: unknown PLY property type "
                                     f"{parts[1]!r} (known: {', '.join(sorted(_PLY_TYPES))})")
                elements[-1][2].append((parts[2], _PLY_TYPES[parts[1]]))
    if fmt not in ("binary_little_endian", "binary_big_endian", "ascii"):
        raise ValueError(f"{path}: unsupported PLY format {fmt!r}")
    if not elements or elements[0][0] != "vertex":
        raise ValueError(f"{path}: the first PLY element must be 'vertex' (the splats)")
    return fmt, elements


def read_ply(path: PathLike) -> Gaussians:
    """Read a 3D Gaussian Splatting ``.ply`` (binary little-endian, big-endian or ASCII).

    Parameters
    ----------
    path : str or os.PathLike
        The file.

    Raises
    ------
    FileNotFoundError
        Missing file.
    ValueError
        Not a PLY, a malformed header line (``FILE: line N: ...``), a splat count that is not
        a whole number >= 1, no ``vertex`` element, missing properties (named, with the 3DGS
        list), list properties in the vertex element, no splats at all, fewer or (with the
        vertex element alone) more bytes/values than the header promises, a stored value that
        is NaN/inf or a log-scale whose ``exp`` overflows (see :meth:`Gaussians.from_raw`), a
        path that is not a regular file (a folder, a named pipe); every message names the
        file.
    """
    path = check_input_file(path, "PLY file", _PLY_FIX)
    with open(path, "rb") as f:
        data = f.read()
    if not data.strip():
        raise ValueError(f"{path} holds no splats (the file is empty, {len(data)} bytes); "
                         f"export the trained point cloud again")
    if not data.startswith(b"ply"):
        raise ValueError(f"{path} is not a PLY file (it does not start with 'ply')")
    end = data.find(b"end_header")
    if end < 0:
        raise ValueError(f"{path}: PLY header has no end_header (truncated or not a PLY)")
    body_start = data.index(b"\n", end) + 1 if b"\n" in data[end:] else len(data)
    header = data[:end].decode("ascii", errors="replace").splitlines()
    fmt, elements = _parse_ply_header(path, header)
    _, count, props = elements[0]
    names = [p for p, _ in props]
    missing = [p for p in _NEEDED if p not in names]
    if missing:
        raise ValueError(f"{path} lacks the 3D Gaussian property/properties {', '.join(missing)};"
                         f" a 3DGS PLY has x y z f_dc_0..2 opacity scale_0..2 rot_0..3")
    if any(t is None for _, t in props):
        raise ValueError(f"{path}: list properties in the vertex element are not supported")
    if fmt == "ascii":
        text = data[body_start:].decode("ascii", errors="replace").split()
        need = count * len(props)
        if len(text) < need:
            raise ValueError(f"{path} is truncated: {len(text)} values after the header, the "
                             f"header promises {count} splats x {len(props)} = {need}")
        if len(elements) == 1 and len(text) > need:
            raise ValueError(f"{path} holds {len(text)} values after the header but its "
                             f"'element vertex {count}' promises {count} splats x {len(props)} "
                             f"= {need}: the count in the header is wrong (or the file is "
                             f"corrupt); export the point cloud again")
        try:
            table = np.asarray(text[:need], dtype=np.float64).reshape(count, len(props))
        except ValueError:
            raise ValueError(f"{path}: non-numeric value in the ASCII vertex data") from None
        cols = {n: table[:, i] for i, n in enumerate(names)}
    else:
        order = "<" if fmt == "binary_little_endian" else ">"
        dtype = np.dtype([(n, order + t) for n, t in props])
        need = count * dtype.itemsize
        have = len(data) - body_start
        if have < need:
            raise ValueError(f"{path} is truncated: {have} bytes of vertex data, the header "
                             f"promises {count} splats x {dtype.itemsize} bytes = {need}")
        tail = data[body_start + need:]
        if len(elements) == 1 and tail and not (len(tail) < dtype.itemsize
                                                and not tail.strip()):
            raise ValueError(f"{path} holds {have} bytes of vertex data but its 'element vertex "
                             f"{count}' promises {count} splats x {dtype.itemsize} bytes = "
                             f"{need}: the count in the header is wrong (or the file is "
                             f"corrupt); export the point cloud again")
        rec = np.frombuffer(data, dtype=dtype, count=count, offset=body_start)
        cols = {n: rec[n].astype(np.float64) for n in names}
    try:
        return Gaussians.from_raw(
            cols["x"], cols["y"], cols["z"],
            np.stack([cols[f"f_dc_{i}"] for i in range(3)], axis=1), cols["opacity"],
            np.stack([cols[f"scale_{i}"] for i in range(3)], axis=1),
            np.stack([cols[f"rot_{i}"] for i in range(4)], axis=1))
    except ValueError as exc:
        raise ValueError(f"{path}: {exc}") from None


@dataclass(frozen=True)
class Camera:
    """Pinhole camera, OpenCV axes (x right, y down, z forward).

    Parameters
    ----------
    width, height : int
        Image size in pixels.
    fx, fy : float
        Focal lengths in pixels.
    cx, cy : float, optional
        Principal point in pixel coordinates with pixel centres at integers; default
        ``(width - 1) / 2``, ``(height - 1) / 2`` (the 3DGS convention).
    rotation : ndarray, shape (3, 3)
        World-to-camera rotation ``R``; a world point ``p`` is at ``R p + t`` in camera axes.
    translation : ndarray, shape (3,)
        World-to-camera translation ``t`` (scene units).
    source : str, optional
        Where the camera came from (``cameras.json: camera 3``), for messages.
    """

    width: int
    height: int
    fx: float
    fy: float
    cx: Optional[float] = None
    cy: Optional[float] = None
    rotation: np.ndarray = None  # type: ignore[assignment]
    translation: np.ndarray = None  # type: ignore[assignment]
    source: Optional[str] = field(default=None, compare=False, repr=False)

    def __post_init__(self) -> None:
        if int(self.width) < 1 or int(self.height) < 1:
            raise ValueError(f"camera width/height must be >= 1, got {self.width}x{self.height}")
        if not (self.fx > 0 and self.fy > 0 and np.isfinite(self.fx) and np.isfinite(self.fy)):
            raise ValueError(f"fx, fy must be positive focal lengths in pixels, got "
                             f"{self.fx}, {self.fy}")
        object.__setattr__(self, "width", int(self.width))
        object.__setattr__(self, "height", int(self.height))
        if self.cx is None:
            object.__setattr__(self, "cx", (self.width - 1) / 2.0)
        if self.cy is None:
            object.__setattr__(self, "cy", (self.height - 1) / 2.0)
        R = np.eye(3) if self.rotation is None else np.asarray(self.rotation, np.float64)
        t = np.zeros(3) if self.translation is None else np.asarray(self.translation, np.float64)
        if R.shape != (3, 3) or not np.allclose(R @ R.T, np.eye(3), atol=1e-6):
            raise ValueError("rotation must be a 3x3 orthonormal world-to-camera matrix")
        if t.shape != (3,):
            raise ValueError(f"translation must have shape (3,), got {t.shape}")
        if not np.all(np.isfinite(t)):  # else every splat is "behind the camera"
            raise ValueError(f"translation holds NaN or infinity ({t.tolist()}); the camera's "
                             f"position must be finite")
        if not (np.isfinite(self.cx) and np.isfinite(self.cy)):
            raise ValueError(f"the principal point cx, cy must be finite, got {self.cx}, "
                             f"{self.cy}")
        object.__setattr__(self, "rotation", R)
        object.__setattr__(self, "translation", t)

    def scaled(self, factor: float) -> "Camera":
        """The same view with ``factor`` times the pixels along each axis (at least 1).

        Focal lengths scale with the actual size ratio of each axis; the principal point keeps
        its place on the image (pixel centres at integers: ``c' = (c + 0.5) s - 0.5``).
        """
        factor = float(factor)
        if not (np.isfinite(factor) and factor > 0):
            raise ValueError(f"scale must be a positive factor, got {factor!r}")
        w = max(1, int(round(self.width * factor)))
        h = max(1, int(round(self.height * factor)))
        sx, sy = w / self.width, h / self.height
        return Camera(w, h, self.fx * sx, self.fy * sy, (self.cx + 0.5) * sx - 0.5,
                      (self.cy + 0.5) * sy - 0.5, self.rotation, self.translation,
                      source=self.source)

    @classmethod
    def from_fov(cls, width: int, height: int, fov_deg: float, **kw) -> "Camera":
        """Square pixels with horizontal field of view ``fov_deg`` degrees.

        Parameters
        ----------
        width, height : int
            Image size, pixels.
        fov_deg : float
            Horizontal field of view, degrees.
        **kw
            The other :class:`Camera` fields (rotation, translation, ...).
        """
        fx = width / (2.0 * np.tan(np.radians(fov_deg) / 2.0))
        return cls(width, height, fx, fx, **kw)


def default_camera(gaussians: Gaussians, *, width: int = 512, height: Optional[int] = None,
                   fov_deg: float = 50.0, fx: Optional[float] = None, fy: Optional[float] = None,
                   margin: float = 1.05) -> Camera:
    """A camera looking along world +z at the splats, framing them.

    The camera has the world's axes (identity rotation: 3DGS/COLMAP scenes use x right, y down,
    z forward). It sits on the axis through the centre of the splats' robust bounding box
    (2nd..98th percentile of the centres, so stray floaters do not shrink the picture), far
    enough in front (-z) that the box's front face fills the view with a ``margin``.

    Parameters
    ----------
    gaussians : Gaussians
        The splats to frame.
    width, height : int
        Pixels; ``height`` defaults to the box's aspect ratio.
    fov_deg : float
        Horizontal field of view in degrees when ``fx`` is not given.
    fx, fy : float, optional
        Focal lengths in pixels (``fy`` defaults to ``fx``).
    margin : float
        Factor on the distance that frames the box (1.05: 5 % room around it).
    """
    m = gaussians.means.astype(np.float64)
    if len(m) == 0:
        raise ValueError("no splats to frame")
    lo = np.percentile(m, 2, axis=0)
    hi = np.percentile(m, 98, axis=0)
    centre = (lo + hi) / 2
    half = np.maximum((hi - lo) / 2, 1e-6)
    if height is None:
        height = max(1, int(round(width * half[1] / half[0])))
    if fx is None:
        fx = width / (2.0 * np.tan(np.radians(fov_deg) / 2.0))
    fy = fx if fy is None else fy
    dist = margin * max(half[0] * fx / (width / 2.0), half[1] * fy / (height / 2.0))
    position = np.array([centre[0], centre[1], lo[2] - dist])
    return Camera(width, height, float(fx), float(fy), translation=-position)


def read_cameras_json(path: PathLike) -> List[dict]:
    """The entries of a 3DGS ``cameras.json`` (the original code's training cameras).

    Each entry has ``id``, ``img_name``, ``width``, ``height`` (pixels), ``position`` (camera
    centre, world units), ``rotation`` (3x3 camera-to-world, rows), ``fx``, ``fy`` (pixels).

    Parameters
    ----------
    path : str or os.PathLike
        The file.

    Raises
    ------
    FileNotFoundError, ValueError
        Missing file, invalid JSON, not a non-empty list, an entry without those keys; the
        message names the file.
    """
    path = Path(path)
    try:  # stat's answer in check_input_file's words: a loop of links does exist
        check_input_file(path, "camera file", "give the cameras.json that 3DGS writes beside "
                                              "point_cloud/")
    except FileNotFoundError:
        raise FileNotFoundError(f"camera file {path} does not exist (3DGS writes cameras.json "
                                f"beside point_cloud/)") from None
    entries = read_json(path)
    if not isinstance(entries, list) or not entries:
        raise ValueError(f"{path} must hold a non-empty JSON list of cameras (3DGS "
                         f"cameras.json format)")
    for i, entry in enumerate(entries):
        missing = [k for k in ("width", "height", "position", "rotation", "fx", "fy")
                   if not isinstance(entry, dict) or k not in entry]
        if missing:
            raise ValueError(f"{path}: camera {i} lacks {', '.join(missing)} (a 3DGS camera "
                             f"has id, img_name, width, height, position, rotation, fx, fy)")
    return entries


def camera_from_json(path: PathLike, index: int = 0, *, width: Optional[int] = None,
                     height: Optional[int] = None) -> Camera:
    """Training camera ``index`` (position in the list) of a 3DGS ``cameras.json``.

    3DGS stores the camera centre ``position`` and the camera-to-world ``rotation`` ``Rc``, in
    COLMAP's axes (x right, y down, z forward: the axes of :class:`Camera`); the world-to-camera
    pose is ``R = Rc^T``, ``t = -Rc^T position``. 3DGS renders with the principal point at the
    image centre, as :class:`Camera` does by default.

    Parameters
    ----------
    path : path-like
        The ``cameras.json``.
    index : int
        Which camera (0-based position in the file's list).
    width, height : int, optional
        Render size in pixels; default the training image's. Only ``width`` given: the height
        keeps the aspect ratio. The focal lengths scale with the size.
    """
    from .. import validate

    entries = read_cameras_json(path)
    index = validate.count(index, name="camera_index", minimum=0)
    if index >= len(entries):
        raise ValueError(f"camera_index {index} is out of range: {path} holds {len(entries)} "
                         f"camera(s), 0..{len(entries) - 1}")
    e = entries[index]
    where = f"{path}: camera {index} ({e.get('img_name', 'unnamed')})"
    w0, h0 = (_json_number(e, key, where, whole=True) for key in ("width", "height"))
    fx, fy = (_json_number(e, key, where) for key in ("fx", "fy"))
    rot = _json_numbers(e, "rotation", where, (3, 3), "a 3x3 list of numbers (rows)")
    pos = _json_numbers(e, "position", where, (3,), "3 numbers (the camera centre)")
    try:
        camera = Camera(w0, h0, fx, fy, rotation=rot.T, translation=-rot.T @ pos,
                        source=where.split(" (")[0])
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{where}: {exc}") from None
    if width is None and height is None:
        return camera
    w = int(width) if width is not None else max(1, int(round(w0 * int(height) / h0)))
    h = int(height) if height is not None else max(1, int(round(h0 * w / w0)))
    if w < 1 or h < 1:
        raise ValueError(f"width/height must be >= 1 pixel, got {w}x{h}")
    sx, sy = w / w0, h / h0
    return Camera(w, h, fx * sx, fy * sy, rotation=camera.rotation,
                  translation=camera.translation, source=camera.source)


def _json_number(entry: dict, key: str, where: str, *, whole: bool = False) -> float:
    """``entry[key]`` as a finite number (a whole one when ``whole``), else a ValueError that
    names the key and the camera: ``"30"`` (a string) or ``true`` would otherwise be taken."""
    value = entry[key]
    kind = "a whole number of pixels" if whole else "a finite number"
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        fix = (f"; write it unquoted: {value.strip()}" if isinstance(value, str)
               and _is_number(value) else "")
        raise ValueError(f"{where}: {key!r} must be {kind}, got {json.dumps(value)} "
                         f"({type(value).__name__}){fix}")
    try:
        number = float(value)
    except OverflowError:  # an integer of hundreds of digits (np.isfinite refused its type)
        raise ValueError(f"{where}: {key!r} must be {kind}, got an integer of "
                         f"{len(str(abs(value)))} digits: fix or re-export cameras.json") from None
    if not np.isfinite(number) or (whole and number != int(number)):
        raise ValueError(f"{where}: {key!r} must be {kind}, got {value!r}")
    return int(number) if whole else number


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def _json_numbers(entry: dict, key: str, where: str, shape, what: str) -> np.ndarray:
    """``entry[key]`` as a float64 array of ``shape`` with finite numbers only (named)."""
    value = entry[key]
    flat = value if isinstance(value, list) else None
    if flat is not None and len(shape) == 2:  # rows: each a list
        flat = ([v for row in value for v in row]
                if all(isinstance(row, list) for row in value) else None)
    if flat is None or any(isinstance(v, bool) or not isinstance(v, (int, float))
                           for v in flat):
        raise ValueError(f"{where}: {key!r} must be {what}, got {json.dumps(value)}")
    if len(shape) == 2 and any(len(row) != shape[1] for row in value):
        # rows of different lengths: NumPy's "inhomogeneous shape" named neither key nor file
        raise ValueError(f"{where}: {key!r} must be {what}, got rows of "
                         f"{', '.join(str(len(row)) for row in value)} numbers: "
                         f"{json.dumps(value)}")
    try:
        arr = np.asarray(value, np.float64)
    except OverflowError:
        raise ValueError(f"{where}: {key!r} must be {what}, got an integer too large for any "
                         f"number: fix or re-export cameras.json") from None
    if arr.shape != shape:
        raise ValueError(f"{where}: {key!r} must be {what}, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{where}: {key!r} holds NaN or infinity ({json.dumps(value)}); "
                         f"the camera's pose needs finite numbers: fix or re-export "
                         f"cameras.json")
    return arr


@dataclass(frozen=True, eq=False)
class Projected:
    """Screen-space splats, sorted front to back (arrays of length M <= N, float32)."""

    xy: np.ndarray       # (M, 2) mean in pixels (x, y)
    conic: np.ndarray    # (M, 3) inverse 2-D covariance (a, b, c)
    opacity: np.ndarray  # (M,)
    color: np.ndarray    # (M, 3)
    depth: np.ndarray    # (M,) camera z, ascending
    radius: np.ndarray   # (M,) 3-sigma radius in pixels (int)
    index: np.ndarray    # (M,) index into the Gaussians
    znear: float = 0.0   # the near plane used (scene units)
    dropped_near: int = 0     # splats behind the camera or nearer than znear
    dropped_outside: int = 0  # splats in front whose 3-sigma square misses the image
    dropped_behind: int = 0   # of dropped_near, those behind the camera (camera z <= 0)


def _warn_culled(dropped: int, behind: int, total: int, znear: float) -> None:
    """The :class:`SplatCullWarning` of :func:`project`, when it dropped splats, at the
    user's line (:func:`clholo.validate.warn_at_caller`)."""
    if dropped:
        validate.warn_at_caller(
            f"{dropped} of {total} splats ({100.0 * dropped / total:.1f} %) are "
            f"dropped: {behind} behind the camera, {dropped - behind} nearer than the near "
            f"plane znear={znear:.4g} scene units; move the camera back (or give one from "
            f"cameras.json) or lower znear", SplatCullWarning)


def _none_visible(proj: Projected, total: int) -> ValueError:
    """The refusal when no splat of ``total`` is left to draw (the counts of that projection,
    not of an empty subset of it)."""
    return ValueError(
        f"no splat is in front of the camera and inside the image ({proj.dropped_near} of "
        f"{total} behind or nearer than znear={proj.znear:.4g} ({proj.dropped_behind} behind "
        f"the camera), {proj.dropped_outside} off the image); check the camera pose")


def _quat_to_rot(q: np.ndarray) -> np.ndarray:
    w, x, y, z = q[:, 0], q[:, 1], q[:, 2], q[:, 3]
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
        np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
        np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
    ], axis=1)


def auto_znear(gaussians: Gaussians, camera: Camera) -> float:
    """The near plane relative to the scene: :data:`NEAR_FRACTION` of the median camera depth
    of the splats in front of the camera (scene units; 1.0 when none is in front)."""
    z = gaussians.means.astype(np.float64) @ camera.rotation[2] + camera.translation[2]
    z = z[z > 0]
    return NEAR_FRACTION * float(np.median(z)) if len(z) else 1.0


def project(gaussians: Gaussians, camera: Camera, *, znear: Optional[float] = None,
            dilation: float = 0.3, warn: bool = True) -> Projected:
    """EWA-project the Gaussians through ``camera``; cull, sort by depth.

    Parameters
    ----------
    gaussians : Gaussians
        The splats.
    camera : Camera
        The pinhole camera.
    znear : float, optional
        Splats whose centre is not farther than this (camera z, scene units) are dropped.
        Default :func:`auto_znear`: 1 % of the median depth of the splats in front, so that the
        near plane scales with the scene (3DGS's fixed 0.2 swallows small scenes whole).
    dilation : float
        Added to the diagonal of the 2-D covariance in px^2 (3DGS's low-pass filter: 0.3).
    warn : bool
        Warn (:class:`SplatCullWarning`, with the counts) when splats are dropped behind the
        camera or by the near plane. Splats off the sides of the image are counted in
        ``dropped_outside`` but not warned about: framing is the camera's choice.

    Returns
    -------
    Projected
        Splats in front of ``znear`` with a nonempty 3-sigma square on the image, nearest first,
        with the near plane used and the counts dropped.
    """
    from .. import validate

    if znear is None:
        znear = auto_znear(gaussians, camera)
    else:
        znear = validate.real_scalar("znear", znear)
        if znear <= 0:
            raise ValueError(f"znear must be > 0 scene units in front of the camera, got {znear!r}")
    R, t = camera.rotation, camera.translation
    p = gaussians.means.astype(np.float64) @ R.T + t
    keep = p[:, 2] > znear
    dropped_near = int(len(p) - np.count_nonzero(keep))
    behind = int(np.count_nonzero(p[:, 2] <= 0))
    if dropped_near and warn:
        _warn_culled(dropped_near, behind, len(p), znear)
    idx = np.nonzero(keep)[0]
    p = p[keep]
    tx, ty, tz = p[:, 0], p[:, 1], p[:, 2]
    # 3DGS evaluates the Jacobian at a point clamped to 1.3x the field of view, which keeps
    # splats far outside the view from blowing up.
    limx = 1.3 * (camera.width / (2 * camera.fx))
    limy = 1.3 * (camera.height / (2 * camera.fy))
    jx = np.clip(tx / tz, -limx, limx) * tz
    jy = np.clip(ty / tz, -limy, limy) * tz
    J = np.zeros((len(p), 2, 3))
    J[:, 0, 0] = camera.fx / tz
    J[:, 0, 2] = -camera.fx * jx / tz ** 2
    J[:, 1, 1] = camera.fy / tz
    J[:, 1, 2] = -camera.fy * jy / tz ** 2
    Rq = _quat_to_rot(gaussians.rotations[idx].astype(np.float64))
    M = Rq * gaussians.scales[idx].astype(np.float64)[:, None, :]  # R_q S
    sigma = M @ np.transpose(M, (0, 2, 1))
    TW = J @ R
    cov = TW @ sigma @ np.transpose(TW, (0, 2, 1))
    a = cov[:, 0, 0] + dilation
    b = cov[:, 0, 1]
    c = cov[:, 1, 1] + dilation
    det = a * c - b * b
    mid = 0.5 * (a + c)
    lam = mid + np.sqrt(np.maximum(0.1, mid * mid - det))
    # a splat wider than any image (a log-scale of 50: 5e21 scene units) covers it all; its
    # radius is capped where int64 still holds it exactly (the cast made it garbage and
    # dropped the splat: a scene "without light")
    radius = np.minimum(np.ceil(3.0 * np.sqrt(lam)), 2.0 ** 53)
    u = camera.fx * tx / tz + camera.cx
    v = camera.fy * ty / tz + camera.cy
    ok = (det > 0) & (radius > 0)
    ok &= (u + radius >= -0.5) & (u - radius <= camera.width - 0.5)
    ok &= (v + radius >= -0.5) & (v - radius <= camera.height - 0.5)
    inv = 1.0 / np.where(ok, det, 1.0)
    order = np.argsort(tz[ok], kind="stable")
    sel = np.nonzero(ok)[0][order]
    g = idx[sel]
    return Projected(
        xy=np.stack([u[sel], v[sel]], 1).astype(np.float32),
        conic=np.stack([c[sel] * inv[sel], -b[sel] * inv[sel], a[sel] * inv[sel]],
                       1).astype(np.float32),
        opacity=gaussians.opacities[g].astype(np.float32),
        color=gaussians.colors[g].astype(np.float32),
        depth=tz[sel].astype(np.float64),
        radius=radius[sel].astype(np.int64),
        index=g, znear=float(znear), dropped_near=dropped_near,
        dropped_outside=int(len(p) - len(sel)), dropped_behind=behind)


def slab_edges(depth: np.ndarray, slabs: int, *,
               spacing: str = "inverse") -> Tuple[np.ndarray, np.ndarray]:
    """Slab index of every (sorted) splat depth and the slab centre depths.

    ``spacing="inverse"``: slabs uniform in 1/z between the nearest and farthest splat (the usual
    MPI spacing: equal disparity steps); ``"depth"``: uniform in z.

    Returns
    -------
    index : ndarray (M,), int32, nondecreasing for sorted input
    centres : ndarray (slabs,), float64, increasing, scene units
    """
    if slabs < 1:
        raise ValueError(f"layers (slabs) must be >= 1, got {slabs}")
    if spacing not in ("inverse", "depth"):
        raise ValueError(f"slab spacing must be 'inverse' or 'depth', got {spacing!r}")
    z0, z1 = (float(depth.min()), float(depth.max())) if len(depth) else (1.0, 2.0)
    if z1 <= z0:
        z1 = z0 * (1 + 1e-3) + 1e-6
    f = (lambda z: 1.0 / z) if spacing == "inverse" else (lambda z: z)
    e0, e1 = f(z0), f(z1)
    s = np.floor((f(depth) - e0) / (e1 - e0) * slabs)
    index = np.clip(s, 0, slabs - 1).astype(np.int32)
    mids = e0 + (np.arange(slabs) + 0.5) / slabs * (e1 - e0)
    centres = 1.0 / mids if spacing == "inverse" else mids
    return index, centres


def _tile_rects(proj: Projected, width: int, height: int, tile: int):
    tiles_x, tiles_y = -(-width // tile), -(-height // tile)
    u, v, r = proj.xy[:, 0].astype(np.float64), proj.xy[:, 1].astype(np.float64), proj.radius
    x0 = np.clip(np.floor((u - r) / tile), 0, tiles_x).astype(np.int64)
    x1 = np.clip(np.floor((u + r) / tile) + 1, 0, tiles_x).astype(np.int64)
    y0 = np.clip(np.floor((v - r) / tile), 0, tiles_y).astype(np.int64)
    y1 = np.clip(np.floor((v + r) / tile) + 1, 0, tiles_y).astype(np.int64)
    return tiles_x, tiles_y, x0, x1, y0, y1


def tile_lists(proj: Projected, width: int, height: int, *, tile: int = TILE):
    """Per-tile lists of splat indices in depth order (vectorised, O(pairs log pairs)).

    Returns
    -------
    lst : ndarray (P,), uint32
        Splat indices grouped by tile, depth order inside a tile.
    ranges : ndarray (tiles_y * tiles_x, 2), int32
        ``[start, end)`` of each tile in ``lst``.
    """
    tiles_x, tiles_y, x0, x1, y0, y1 = _tile_rects(proj, width, height, tile)
    nx = np.maximum(x1 - x0, 0)
    ny = np.maximum(y1 - y0, 0)
    cnt = nx * ny
    total = int(cnt.sum())
    if total >= 2 ** 31:
        raise MemoryError(f"{total} splat-tile pairs: lower the resolution or split the scene")
    splat = np.repeat(np.arange(len(cnt), dtype=np.int64), cnt)
    first = np.repeat(np.cumsum(cnt) - cnt, cnt)
    off = np.arange(total, dtype=np.int64) - first
    nxr = np.repeat(nx, cnt)
    tx = np.repeat(x0, cnt) + off % np.maximum(nxr, 1)
    ty = np.repeat(y0, cnt) + off // np.maximum(nxr, 1)
    tile_id = ty * tiles_x + tx
    # Splats are already depth-sorted, so a stable sort by tile keeps depth order per tile.
    perm = np.argsort(tile_id, kind="stable")
    lst = splat[perm].astype(np.uint32)
    counts = np.bincount(tile_id, minlength=tiles_x * tiles_y)
    ends = np.cumsum(counts)
    ranges = np.stack([ends - counts, ends], 1).astype(np.int32)
    return lst, ranges


def _power_floor(opacity: np.ndarray) -> np.ndarray:
    """``log(1 / (255 o))`` in float32, less a margin: a Gaussian exponent below it gives
    ``alpha < 1/255`` (skipped anyway), so the exp can be skipped. The margin (1e-5, far above
    float32 rounding of the log) keeps the shortcut from ever dropping a splat that the
    ``alpha < 1/255`` test would keep."""
    o = np.asarray(opacity, np.float64)
    with np.errstate(divide="ignore"):  # opacity 0 gives inf here, replaced below
        floor = np.log(1.0 / (255.0 * o)) - 1e-5
    # a splat of opacity 0 never reaches 1/255, so every exponent is below its floor: the
    # largest float32 says so without an inf in the kernel's arguments
    return np.where(o > 0, floor, np.finfo(np.float32).max).astype(np.float32)


def rasterize_slabs_reference(proj: Projected, slab: np.ndarray, slabs: int, width: int,
                              height: int, *, t_min: float = 1e-4,
                              tile: int = TILE) -> Tuple[np.ndarray, np.ndarray]:
    """NumPy reference of :func:`rasterize_slabs` (float32, same rules; small scenes only).

    Each splat touches the pixels of the tiles its 3-sigma square overlaps, as in the kernel.

    Returns
    -------
    alpha : ndarray, shape (slabs, height, width), float32
    color : ndarray, shape (slabs, height, width, 3), float32
    """
    f32 = np.float32
    alpha_out = np.zeros((slabs, height, width), f32)
    color_out = np.zeros((slabs, height, width, 3), f32)
    T = np.ones((height, width), f32)
    Ts = np.ones((height, width), f32)
    C = np.zeros((height, width, 3), f32)
    cur = np.full((height, width), -1, np.int64)
    done = np.zeros((height, width), bool)
    _, _, x0, x1, y0, y1 = _tile_rects(proj, width, height, tile)
    t_min = f32(t_min)

    def flush(mask, ys, xs):
        cy, cx = ys[mask], xs[mask]
        s = cur[cy, cx]
        a = f32(1) - Ts[cy, cx]
        alpha_out[s, cy, cx] = a
        color_out[s, cy, cx] = C[cy, cx] / a[:, None]

    for k in range(len(proj.opacity)):
        ra, rb = int(y0[k]) * tile, min(int(y1[k]) * tile, height)
        ca, cb = int(x0[k]) * tile, min(int(x1[k]) * tile, width)
        if ra >= rb or ca >= cb:
            continue
        ys, xs = np.mgrid[ra:rb, ca:cb]
        dx = proj.xy[k, 0] - xs.astype(f32)
        dy = proj.xy[k, 1] - ys.astype(f32)
        a_, b_, c_ = proj.conic[k]
        power = f32(-0.5) * (a_ * dx * dx + c_ * dy * dy) - b_ * dx * dy
        alpha = np.minimum(f32(0.99), proj.opacity[k] * np.exp(power.astype(f32)))
        live = ~done[ys, xs] & (power <= 0) & (alpha >= f32(1.0 / 255.0))
        test_T = T[ys, xs] * (f32(1) - alpha)
        stop = live & (test_T < t_min)
        done[ys[stop], xs[stop]] = True
        live &= ~stop
        s = int(slab[k])
        change = live & (cur[ys, xs] != s)
        flush(change & (cur[ys, xs] >= 0), ys, xs)
        cy, cx = ys[change], xs[change]
        cur[cy, cx] = s
        Ts[cy, cx] = 1
        C[cy, cx] = 0
        ly, lx = ys[live], xs[live]
        al = alpha[live]
        C[ly, lx] += proj.color[k][None, :] * (al * Ts[ly, lx])[:, None]
        Ts[ly, lx] *= f32(1) - al
        T[ly, lx] = test_T[live]
    ys, xs = np.mgrid[0:height, 0:width]
    flush(cur >= 0, ys, xs)
    return alpha_out, color_out


def rasterize_slabs(proj: Projected, slab: np.ndarray, slabs: int, width: int, height: int, *,
                    t_min: float = 1e-4, queue=None, timings: Optional[Dict[str, float]] = None
                    ) -> Tuple[np.ndarray, np.ndarray]:
    """Rasterise sorted screen-space splats into slabs with the OpenCL kernel
    ``kernels/splat_raster.cl``.

    Parameters
    ----------
    proj : Projected
        From :func:`project` (sorted front to back).
    slab : ndarray, shape (M,), int
        Slab of each splat, nondecreasing.
    slabs : int
        Number of slabs D.
    width, height : int
    t_min : float
        Stop a pixel when the transmittance through everything in front would fall below this
        (3DGS: 1e-4; 0 disables).
    queue : pyopencl.CommandQueue, optional
        Default :func:`clholo.host.runtime.get_queue`.
    timings : dict, optional
        Filled with ``"binning"`` (host seconds) and ``"raster"`` (device seconds).

    Returns
    -------
    alpha : ndarray, shape (D, H, W), float32
    color : ndarray, shape (D, H, W, 3), float32
        Slab colour in the splats' own colour space; 0 where alpha is 0.
    """
    import time

    import pyopencl as cl

    from clholo.host import runtime

    if queue is None:
        queue = runtime.get_queue()
    slab = np.asarray(slab, np.int32)
    if len(slab) != len(proj.opacity):
        raise ValueError(f"slab has {len(slab)} entries for {len(proj.opacity)} splats")
    if len(slab) and (np.any(np.diff(slab) < 0) or slab.min() < 0 or slab.max() >= slabs):
        raise ValueError("slab indices must be nondecreasing (depth order) and in [0, slabs)")
    device = queue.device
    tile = TILE if device.max_work_group_size >= TILE * TILE else 8
    t0 = time.perf_counter()
    lst, ranges = tile_lists(proj, width, height, tile=tile)
    t1 = time.perf_counter()
    ctx = queue.context
    mf = cl.mem_flags
    npix = width * height
    alpha_buf = cl.Buffer(ctx, mf.READ_WRITE, max(4, slabs * npix * 4))
    color_buf = cl.Buffer(ctx, mf.READ_WRITE, max(4, slabs * npix * 12))
    cl.enqueue_fill_buffer(queue, alpha_buf, np.float32(0), 0, slabs * npix * 4)
    cl.enqueue_fill_buffer(queue, color_buf, np.float32(0), 0, slabs * npix * 12)
    out_alpha = np.empty((slabs, height, width), np.float32)
    out_color = np.empty((slabs, height, width, 3), np.float32)
    m = max(1, len(slab))

    def buf(arr, dtype, width_):
        a = np.zeros((m, width_), dtype)
        if len(slab):
            a[:, :arr.shape[1]] = arr
        return cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=a)

    xy = buf(proj.xy, np.float32, 2)
    co = buf(np.concatenate([proj.conic, proj.opacity[:, None]], 1), np.float32, 4)
    rgb = buf(np.concatenate([proj.color, _power_floor(proj.opacity)[:, None]], 1), np.float32, 4)
    sl = cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR,
                   hostbuf=np.ascontiguousarray(slab if len(slab) else np.zeros(1, np.int32)))
    lst_buf = cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR,
                        hostbuf=lst if len(lst) else np.zeros(1, np.uint32))
    rng_buf = cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=np.ascontiguousarray(ranges))
    prg = runtime.build_program(ctx, "splat_raster.cl", defines={"TILE": tile})
    tiles_x, tiles_y = -(-width // tile), -(-height // tile)
    kernel = cl.Kernel(prg, "splat_raster")
    ev = runtime.launch(kernel, queue, (tiles_x * tile, tiles_y * tile), (tile, tile), xy, co, rgb, sl,
                lst_buf, rng_buf, np.int32(width), np.int32(height), np.float32(t_min),
                alpha_buf, color_buf)
    cl.enqueue_copy(queue, out_alpha, alpha_buf, wait_for=[ev])
    cl.enqueue_copy(queue, out_color, color_buf, wait_for=[ev])
    queue.finish()
    if timings is not None:
        timings["binning"] = t1 - t0
        timings["pairs"] = int(len(lst))
        try:
            timings["raster"] = runtime.event_seconds(ev)
        except cl.Error:  # profiling off on a caller's queue
            timings["raster"] = float("nan")
    return out_alpha, out_color


def check_camera_renders(camera: Camera) -> None:
    """Refuse a camera whose image is larger than any hologram field (the FFT's
    :data:`clholo.propagation.MAX_FFT_SIZE` pixels per axis), naming the camera (its file and
    index for one from :func:`camera_from_json`), its size and the fix; before any splat is
    drawn.

    Parameters
    ----------
    camera : Camera
        The camera a scene's splats are seen through.

    Raises
    ------
    clholo.errors.InputError
        Wider or taller than the largest field.
    """
    import math

    from clholo.errors import InputError
    from clholo.propagation import MAX_FFT_SIZE
    from clholo.validate import MIN_SCENE_PIXELS

    side = max(camera.width, camera.height)
    if side <= MAX_FFT_SIZE:
        return
    # three significant digits, rounded down so that it fits: a fixed 3 decimals gave
    # "--scale 0 or less" for a camera 1000 times too wide, a scale that is refused
    ratio = MAX_FFT_SIZE / side
    digits = 2 - int(math.floor(math.log10(ratio)))
    scale = math.floor(ratio * 10 ** digits) / 10 ** digits
    # a scale that leaves the shorter side fewer pixels than any scene may have is no fix
    scaled = (f", or pass --scale {scale:g} or less"
              if min(camera.width, camera.height) * scale >= MIN_SCENE_PIXELS else "")
    raise InputError(
        f"{camera.source or 'the camera'} is {camera.width}x{camera.height} pixels, larger than "
        f"any hologram field (at most {MAX_FFT_SIZE} pixels per axis, before padding): give the "
        f"camera at most {MAX_FFT_SIZE} pixels per axis (its width and height){scaled}")


def check_camera_fits(camera: Camera, layers: int, *, backend: str = "opencl",
                      queue=None) -> None:
    """Refuse, before any work, a camera whose slabs (``layers`` x its pixels) do not fit:
    the rasteriser's colour buffer (12 bytes a pixel and slab, in one allocation) beyond the
    device's largest allocation, both buffers (16 bytes) beyond its memory, or the slabs
    beyond the host's available memory. The message names the camera (its file and index for
    one from :func:`camera_from_json`) and its size.

    Parameters
    ----------
    camera : Camera
        The camera the slabs are drawn through.
    layers : int
        Number of slabs.
    backend : {"opencl", "numpy"}
        ``"numpy"`` (the reference) allocates nothing on the device.
    queue : pyopencl.CommandQueue, optional
        Its device is checked (default: clholo's default device).

    Raises
    ------
    MemoryError
        The slabs do not fit (an environment limit: exit 3 on the command line).
    """
    from clholo.host.memory import available_host_bytes

    def gib(n: float) -> str:
        return f"{n / 2**30:.1f} GiB" if n >= 2**28 else f"{n / 2**20:.1f} MiB"

    npix = int(camera.width) * int(camera.height)
    colour, both = int(layers) * npix * 12, int(layers) * npix * 16
    what = (f"{camera.source or 'the camera'} is {camera.width}x{camera.height} pixels: "
            f"{int(layers)} slabs of it")
    fix = ("; give the camera fewer pixels (its width and height), pass --scale (scale=) "
           "below 1, or fewer --layers")
    problem = None
    if backend == "opencl":
        if queue is None:
            from clholo.host import runtime

            queue = runtime.get_queue()
        device = queue.device
        name = device.name.strip()
        if colour > int(device.max_mem_alloc_size):
            problem = (f"need a colour buffer of {gib(colour)} in one allocation but the device "
                       f"{name} allows at most {gib(device.max_mem_alloc_size)}")
        elif both > int(device.global_mem_size):
            problem = (f"need {gib(both)} of device memory but the device {name} has "
                       f"{gib(device.global_mem_size)}")
    if problem is None and both > available_host_bytes():
        problem = (f"need {gib(both)} of host memory but {gib(available_host_bytes())} is "
                   f"available")
    if problem is not None:
        raise MemoryError(f"{what} {problem}{fix}")


def splats_to_mpi(source, *, layers: int = 32, camera: Optional[Camera] = None,
                  width: int = 512, height: Optional[int] = None, fov_deg: float = 50.0,
                  near: Optional[float] = None, far: Optional[float] = None,
                  spacing: str = "index", slab_spacing: str = "inverse", t_min: float = 1e-4,
                  znear: Optional[float] = None, backend: str = "opencl", queue=None,
                  timings: Optional[Dict[str, float]] = None) -> MPI:
    """3D Gaussians (a :class:`Gaussians` or a ``.ply`` path) to a D-slab MPI.

    Parameters
    ----------
    source : Gaussians or path-like
    layers : int
        Number of slabs D.
    camera : Camera, optional
        Default :func:`default_camera` (``width``, ``height``, ``fov_deg``); a 3DGS training
        camera comes from :func:`camera_from_json`.
    width, height : int
        The default camera's image size, pixels (``height`` from the splats' aspect ratio).
    fov_deg : float
        The default camera's horizontal field of view, degrees.
    near, far : float, optional
        Metres; when given the slabs are placed with :meth:`MPI.placed` (``spacing``).
        Otherwise the MPI depths are the slab centres in scene units (camera z).
    spacing : {"index", "depth", "inverse"}
        How :meth:`MPI.placed` spreads the slabs over ``[near, far]``.
    slab_spacing : {"inverse", "depth"}
        Slabs uniform in inverse depth (default) or depth between the nearest and farthest
        visible splat.
    t_min : float
        3DGS early-stop transmittance (1e-4).
    znear : float, optional
        Near plane in scene units (camera z); default relative to the scene, see
        :func:`project`, which warns (:class:`SplatCullWarning`) when it or the camera's
        position drops splats.
    backend : {"opencl", "numpy"}
        The OpenCL kernel, or the NumPy reference (small scenes).
    queue : pyopencl.CommandQueue, optional
        Queue to run on (default: clholo's default device, ``CLHOLO_DEVICE``).
    timings : dict, optional
        Filled with the stages' times in seconds (``"binning"``, ``"raster"``) and the count of
        splat-tile ``"pairs"``.

    Returns
    -------
    MPI
        Linear colour (the slabs' sRGB colour decoded), D layers nearest first.
    """
    from clholo import validate

    # before reading anything: a count from the user sizes a device buffer (slabs x pixels)
    layers = validate.count(layers, name="layers", maximum=256)
    g = source if isinstance(source, Gaussians) else read_ply(source)
    if camera is None:
        camera = default_camera(g, width=width, height=height, fov_deg=fov_deg)
    check_camera_fits(camera, layers, backend=backend, queue=queue)
    proj = project(g, camera, znear=znear, warn=False)
    if len(proj.opacity) == 0:  # said once, as an error (no warning about the same splats)
        raise _none_visible(proj, len(g))
    _warn_culled(proj.dropped_near, proj.dropped_behind, len(g), proj.znear)
    slab, centres = slab_edges(proj.depth, layers, spacing=slab_spacing)
    # placed before the slabs are drawn and before the MPI is made: camera z in scene units
    # (a scene in millimetres: 18000) is no MPI's metres until near/far place it
    depths = stored_or_placed_depths(
        centres, near, far, spacing=spacing, units="scene units",
        source="the splats" if isinstance(source, Gaussians) else str(source))
    if backend == "opencl":
        alpha, color = rasterize_slabs(proj, slab, layers, camera.width, camera.height,
                                       t_min=t_min, queue=queue, timings=timings)
    elif backend == "numpy":
        alpha, color = rasterize_slabs_reference(proj, slab, layers, camera.width, camera.height,
                                                 t_min=t_min)
    else:
        raise ValueError(f"backend must be 'opencl' or 'numpy', got {backend!r}")
    color = srgb_to_linear(np.clip(color, 0.0, 1.0)).astype(np.float32)
    return MPI(color, np.clip(alpha, 0.0, 1.0), depths)


def subsample_visible(gaussians, camera, max_splats: Optional[int], *, seed: int = 0,
                      znear: Optional[float] = None):
    """At most ``max_splats`` of the Gaussians visible through ``camera``, drawn uniformly
    without replacement (seeded), as a new :class:`clholo.io.splats.Gaussians`, and a
    sentence that states the subsampling. ``znear``: see :func:`clholo.io.splats.project`.

    Parameters
    ----------
    gaussians : Gaussians
        The splats.
    camera : Camera
        The camera they are seen through.
    max_splats : int or None
        How many to keep at most (None: all visible).
    seed : int
        Seed of the draw.
    znear : float, optional
        Near plane in scene units (:func:`clholo.io.splats.project`).

    Returns
    -------
    gaussians : Gaussians
    note : str
    """
    from clholo import validate

    proj = project(gaussians, camera, znear=znear, warn=False)
    if len(proj.opacity) == 0:  # here, with the file's counts (not those of an empty subset)
        raise _none_visible(proj, len(gaussians))
    _warn_culled(proj.dropped_near, proj.dropped_behind, len(gaussians), proj.znear)
    visible = np.sort(proj.index)
    n = len(visible)
    if max_splats is None or n <= max_splats:
        keep = visible
        note = f"all {n} visible splats of {len(gaussians)} (no subsampling)"
    else:
        validate.count(max_splats, name="max_splats")
        rng = np.random.default_rng(validate.seed(seed))
        keep = np.sort(rng.choice(visible, size=int(max_splats), replace=False))
        note = (f"{len(keep)} of {n} visible splats ({len(gaussians)} in the file), drawn "
                f"uniformly at random without replacement (seed {seed})")
    g = Gaussians(gaussians.means[keep], gaussians.scales[keep], gaussians.rotations[keep],
                  gaussians.opacities[keep], gaussians.colors[keep])
    return g, note
