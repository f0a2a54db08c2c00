"""Embedded ICC colour profiles of image inputs, applied where colour is read as intensity.

A phone's photo is usually Display P3 (an iPhone's since 2016, many Android cameras), a
camera's often Adobe RGB; taken as sRGB, its colours come out less saturated than they are.
:func:`read_rgb <clholo.io.rgbd.read_rgb>` therefore decodes an integer image through the
profile it carries: for a matrix/TRC profile (what display, phone and most camera profiles
are: sRGB, Display P3, Adobe RGB, ProPhoto, Rec. 2020, a grey gamma) exactly, in floating
point, at any bit depth:

* each channel through its tone curve (``rTRC``/``gTRC``/``bTRC``, or ``kTRC`` for grey): a
  gamma, a table, or one of ICC's five parametric curves;
* to the profile connection space (XYZ under D50) by the colorant matrix
  (``rXYZ``/``gXYZ``/``bXYZ``, already adapted to D50 as ICC requires);
* to linear sRGB by the inverse of sRGB's own colorant matrix, built from sRGB's primaries and
  D65 white with the Bradford adaptation to the profile's D50, as ICC profiles of sRGB are.

That is ICC's relative colorimetric intent, as littlecms computes it for these profiles;
colours outside sRGB's gamut (a P3 green) leave [0, 1] and are clipped by the caller, as
littlecms clips them. A profile that is sRGB's own (its colorants and curves within 1e-3 of
sRGB's) decodes by the exact sRGB EOTF, so such files read bit for bit as before. Profiles
built from lookup tables (``A2B0``: printer and some camera profiles), and profiles of other
colour spaces (CMYK, Lab), are not applied: :class:`ColourProfileWarning` says so, naming the
profile, and the colour is taken as sRGB.

OpenEXR states the primaries of its linear RGB instead, in a ``chromaticities`` attribute:
:func:`chromaticities_matrix` turns them into the matrix to linear sRGB by the same route (RGB
to XYZ under the file's white, Bradford to D65, sRGB's inverse).

Reference: ICC.1:2022 (profile version 4.4), sections 7.2 (header), 7.3 (tag table), 10.6
(curveType), 10.18 (parametricCurveType), 10.31 (XYZType).
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from typing import Optional, Tuple

import numpy as np

__all__ = ["CHROMATICITIES_MATCH", "ColourProfileWarning", "IccProfile", "chromaticities_matrix",
           "parse_icc", "srgb_pcs_matrix"]


class ColourProfileWarning(UserWarning):
    """An image's embedded colour profile that clholo cannot apply (the colour is then taken
    as sRGB)."""


# sRGB's primaries and white (IEC 61966-2-1), chromaticities x, y
_SRGB_PRIMARIES = ((0.64, 0.33), (0.30, 0.60), (0.15, 0.06))
_D65 = (0.3127, 0.3290)
# the Bradford cone response matrix (Lam 1985; ICC.1 Annex E uses it for the adaptation)
_BRADFORD = np.array([[0.8951, 0.2664, -0.1614],
                      [-0.7502, 1.7135, 0.0367],
                      [0.0389, -0.0685, 1.0296]])
# the sRGB test: colorants (XYZ) and tone curves (linear values) within this of sRGB's
_SRGB_MATCH = 1e-3


def _xyz(x: float, y: float) -> np.ndarray:
    return np.array([x / y, 1.0, (1.0 - x - y) / y])


def _rgb_to_xyz(primaries, white_xy) -> np.ndarray:
    """Linear RGB of these primaries (three chromaticities x, y) to XYZ, scaled so that
    r = g = b = 1 is the white ``white_xy`` with Y = 1. A primary's column is (x, y, 1 - x - y)
    times its scale, so a primary of y <= 0 (ACES AP0's blue, outside the visible colours)
    works as well."""
    cols = _primary_columns(primaries)
    return cols * np.linalg.solve(cols, _xyz(*white_xy))


def _primary_columns(primaries) -> np.ndarray:
    return np.array([[x, y, 1.0 - x - y] for x, y in primaries], float).T


def _bradford(src_white, dst_white) -> np.ndarray:
    """XYZ under the white ``src_white`` to XYZ under ``dst_white`` (both XYZ), by Bradford."""
    cone_src, cone_dst = _BRADFORD @ np.asarray(src_white, float), _BRADFORD @ np.asarray(
        dst_white, float)
    return np.linalg.solve(_BRADFORD, np.diag(cone_dst / cone_src) @ _BRADFORD)


def srgb_pcs_matrix(pcs_white) -> np.ndarray:
    """sRGB's colorant matrix in the profile connection space: linear sRGB ``(r, g, b)`` to
    XYZ under ``pcs_white`` (ICC's D50, ``(0.9642, 1, 0.8249)``), adapted from D65 by
    Bradford. Its columns are what an sRGB profile stores as ``rXYZ``, ``gXYZ``, ``bXYZ``.

    Parameters
    ----------
    pcs_white : sequence of 3 float
        XYZ of the profile connection space's illuminant (the profile header's).
    """
    return _bradford(_xyz(*_D65), pcs_white) @ _rgb_to_xyz(_SRGB_PRIMARIES, _D65)


#: OpenEXR's ``chromaticities`` within this (in x and y) of Rec. 709's (sRGB's primaries, D65)
#: are Rec. 709's: files store them in float32, and some writers round to four digits.
CHROMATICITIES_MATCH = 5e-4


def chromaticities_matrix(chromaticities) -> Optional[np.ndarray]:
    """The matrix from linear RGB of an OpenEXR file's ``chromaticities`` to linear sRGB.

    OpenEXR states its linear RGB's primaries and white in a ``chromaticities`` header
    attribute (Rec. 709 with D65 when absent); ACES files (ACES2065-1: AP0 primaries, D60
    white) and ACEScg renders (AP1) carry theirs. The matrix takes RGB to XYZ under the file's
    white, adapts that white to D65 by Bradford (relative colorimetric, as for ICC profiles)
    and XYZ to linear sRGB: ``rgb_srgb = M @ rgb_file``. Colours outside sRGB's gamut leave
    [0, 1]; callers clip them.

    Parameters
    ----------
    chromaticities : sequence of 8 float
        ``(red x, red y, green x, green y, blue x, blue y, white x, white y)``, CIE 1931.

    Returns
    -------
    ndarray (3, 3) or None
        None where they are Rec. 709's within :data:`CHROMATICITIES_MATCH` (no conversion).

    Raises
    ------
    ValueError
        Not eight finite numbers, a white of y at or below 0, or primaries that span no colour
        space (on one line, or the white on a side of their triangle: no positive mix of them
        makes it).
    """
    c = np.asarray(chromaticities, float).ravel()
    if c.size != 8 or not np.isfinite(c).all():
        raise ValueError(f"chromaticities must be 8 finite numbers (red, green, blue and white "
                         f"x, y), got {np.asarray(chromaticities).ravel().tolist()}")
    pts = c.reshape(4, 2)
    if pts[3, 1] <= 0:
        raise ValueError(f"chromaticities' white has y = {pts[3, 1]:g}: {c.tolist()}")
    ref = np.array(_SRGB_PRIMARIES + (_D65,))
    if np.max(np.abs(pts - ref)) <= CHROMATICITIES_MATCH:
        return None
    primaries = tuple(map(tuple, pts[:3]))
    cols = _primary_columns(primaries)
    if abs(np.linalg.det(cols)) < 1e-9 or (np.linalg.solve(cols, _xyz(*pts[3])) <= 1e-9).any():
        raise ValueError(f"chromaticities' primaries span no colour space with that white "
                         f"(on one line, or the white outside their triangle): {c.tolist()}")
    to_xyz = _rgb_to_xyz(primaries, tuple(pts[3]))
    to_d65 = _bradford(_xyz(*pts[3]), _xyz(*_D65))
    return np.linalg.solve(_rgb_to_xyz(_SRGB_PRIMARIES, _D65), to_d65 @ to_xyz)


def _s15f16(data: bytes, at: int, n: int) -> np.ndarray:
    return np.array(struct.unpack(f">{n}i", data[at:at + 4 * n]), float) / 65536.0


@dataclass(frozen=True)
class _Curve:
    """One tone curve: encoded value in [0, 1] -> linear value."""

    kind: str                      # "gamma", "table", "para"
    gamma: float = 1.0
    table: Optional[np.ndarray] = None
    function: int = 0
    params: Tuple[float, ...] = ()

    def __call__(self, v: np.ndarray) -> np.ndarray:
        v = np.clip(np.asarray(v, np.float64), 0.0, 1.0)
        if self.kind == "gamma":
            return v ** self.gamma
        if self.kind == "table":
            t = self.table
            return np.interp(v, np.linspace(0.0, 1.0, t.size), t)
        g, *p = self.params
        f = self.function
        if f == 0:
            return v ** g
        a, b = p[0], p[1]
        base = np.maximum(a * v + b, 0.0) ** g
        if f == 1:
            return np.where(v >= -b / a, base, 0.0)
        if f == 2:
            return np.where(v >= -b / a, base + p[2], p[2])
        if f == 3:
            return np.where(v >= p[3], base, p[2] * v)
        return np.where(v >= p[3], base + p[4], p[2] * v + p[5])   # f == 4


_PARA_COUNTS = {0: 1, 1: 3, 2: 4, 3: 5, 4: 7}


def _curve(data: bytes, at: int, size: int, name: str) -> _Curve:
    kind = data[at:at + 4]
    if kind == b"curv":
        (count,) = struct.unpack(">I", data[at + 8:at + 12])
        if count == 0:
            return _Curve("gamma", 1.0)
        if count == 1:
            (g,) = struct.unpack(">H", data[at + 12:at + 14])
            return _Curve("gamma", g / 256.0)
        if 12 + 2 * count > size:
            raise ValueError(f"tag {name}: a table of {count} entries does not fit its "
                             f"{size} bytes")
        table = np.frombuffer(data, ">u2", count=count, offset=at + 12) / 65535.0
        return _Curve("table", table=table.astype(np.float64))
    if kind == b"para":
        (function,) = struct.unpack(">H", data[at + 8:at + 10])
        if function not in _PARA_COUNTS:
            raise ValueError(f"tag {name}: parametric curve type {function} (ICC has 0 to 4)")
        n = _PARA_COUNTS[function]
        if 12 + 4 * n > size:
            raise ValueError(f"tag {name}: {n} parameters do not fit its {size} bytes")
        params = tuple(_s15f16(data, at + 12, n))
        if function and params[1] == 0:
            raise ValueError(f"tag {name}: parametric curve with a = 0")
        return _Curve("para", function=function, params=params)
    raise ValueError(f"tag {name} is {kind!r}, not a curve ('curv' or 'para')")


def _description(data: bytes, tags: dict) -> str:
    """The profile's name (``desc``: v2 ``desc`` ASCII, v4 ``mluc`` first record)."""
    if b"desc" not in tags:
        return "unnamed profile"
    at, size = tags[b"desc"]
    kind = data[at:at + 4]
    try:
        if kind == b"desc":
            (n,) = struct.unpack(">I", data[at + 8:at + 12])
            text = data[at + 12:at + 12 + n].split(b"\0")[0].decode("latin-1")
        elif kind == b"mluc":
            (count,) = struct.unpack(">I", data[at + 8:at + 12])
            record = at + 16  # the first record: language, country, length, offset
            length, offset = (struct.unpack(">II", data[record + 4:record + 12]) if count
                              else (0, 0))
            text = data[at + offset:at + offset + length].decode("utf-16-be")
        else:
            text = ""
    except (struct.error, UnicodeDecodeError):
        text = ""
    return text.strip() or "unnamed profile"


@dataclass(frozen=True)
class IccProfile:
    """What clholo uses of an ICC profile.

    Attributes
    ----------
    name : str
        The profile's description (``desc``).
    space : str
        Its data colour space: ``"RGB"``, ``"GRAY"``, or another (``"CMYK"``, ...).
    curves : tuple
        Tone curves, one per channel (RGB: 3, grey: 1); empty when the profile has none.
    matrix : ndarray (3, 3) or None
        RGB: linear channel values to PCS XYZ (columns ``rXYZ``, ``gXYZ``, ``bXYZ``).
    pcs_white : ndarray (3,)
        The PCS illuminant from the header (D50).
    lut_based : bool
        The profile carries ``A2B0``/``A2B1`` lookup tables and no matrix/TRC to use instead.
    """

    name: str
    space: str
    curves: Tuple[_Curve, ...]
    matrix: Optional[np.ndarray]
    pcs_white: np.ndarray
    lut_based: bool

    @property
    def applicable(self) -> bool:
        """A matrix/TRC RGB profile or a grey TRC profile: what :meth:`to_linear_srgb` does."""
        if self.space == "RGB":
            return self.matrix is not None and len(self.curves) == 3
        return self.space == "GRAY" and len(self.curves) == 1

    def is_srgb(self) -> bool:
        """Colorants and curves within 1e-3 of sRGB's (a grey profile: its curve of sRGB's)."""
        from .images import srgb_to_linear

        v = np.linspace(0.0, 1.0, 257)
        if not all(np.max(np.abs(c(v) - srgb_to_linear(v))) <= _SRGB_MATCH
                   for c in self.curves):
            return False
        return self.space == "GRAY" or bool(
            np.max(np.abs(self.matrix - srgb_pcs_matrix(self.pcs_white))) <= _SRGB_MATCH)

    def to_linear_srgb(self, px: np.ndarray) -> np.ndarray:
        """Encoded values ``px`` (H, W, C) in [0, 1] (C = 3 for RGB, 1 or more for grey:
        each channel alike) to linear sRGB (relative colorimetric; not clipped: out-of-gamut
        colours leave [0, 1])."""
        if not self.applicable:
            raise ValueError(f"ICC profile {self.name!r} ({self.space}) cannot be applied")
        if self.space == "GRAY":
            return self.curves[0](px)
        lin = np.stack([c(px[..., k]) for k, c in enumerate(self.curves)], axis=-1)
        to_srgb = np.linalg.solve(srgb_pcs_matrix(self.pcs_white), self.matrix)
        return lin @ to_srgb.T


def parse_icc(data) -> IccProfile:
    """Read what clholo uses of an ICC profile (bytes, or OpenImageIO's ``ICCProfile``
    attribute: a uint8 array).

    Raises
    ------
    ValueError
        Not an ICC profile (no ``acsp`` signature), or a tag it needs is malformed.
    """
    data = bytes(np.asarray(data, np.uint8).tobytes() if not isinstance(data, bytes) else data)
    if len(data) < 132 or data[36:40] != b"acsp":
        raise ValueError("not an ICC profile (no 'acsp' signature in its header)")
    space = data[16:20].decode("latin-1").strip()
    pcs_white = _s15f16(data, 68, 3)
    (count,) = struct.unpack(">I", data[128:132])
    tags = {}
    for k in range(min(count, (len(data) - 132) // 12)):
        sig, at, size = struct.unpack(">4sII", data[132 + 12 * k:144 + 12 * k])
        if at + size <= len(data) and size >= 8:
            tags[sig] = (at, size)
    name = _description(data, tags)
    names = {"RGB": (b"rTRC", b"gTRC", b"bTRC"), "GRAY": (b"kTRC",)}.get(space, ())
    curves: Tuple[_Curve, ...] = ()
    if names and all(n in tags for n in names):
        curves = tuple(_curve(data, *tags[n], n.decode()) for n in names)
    matrix = None
    colorants = (b"rXYZ", b"gXYZ", b"bXYZ")
    if space == "RGB" and all(n in tags for n in colorants):
        cols = []
        for n in colorants:
            at, size = tags[n]
            if data[at:at + 4] != b"XYZ " or size < 20:
                raise ValueError(f"tag {n.decode()} is not an XYZType")
            cols.append(_s15f16(data, at + 8, 3))
        matrix = np.stack(cols, axis=1)
    lut_based = not (curves and (matrix is not None or space == "GRAY")) and any(
        n in tags for n in (b"A2B0", b"A2B1", b"A2B2"))
    if pcs_white[1] <= 0:
        raise ValueError(f"ICC profile {name!r}: its PCS illuminant {pcs_white} has Y <= 0")
    return IccProfile(name=name, space=space, curves=curves, matrix=matrix,
                      pcs_white=pcs_white, lut_based=lut_based)
