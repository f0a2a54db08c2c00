"""Phone photos that carry their depth map inside the JPEG.

Three layouts, two Google's and one Apple's, each described by XMP metadata:

* **Dynamic Depth** (Android 10 and later: Pixel ``PORTRAIT`` photos and other Android cameras'
  depth photos). The XMP's ``Device`` element lists the file's items in a
  ``Container:Directory`` (``Item:Mime``, ``Item:Length``, ``Item:Padding``, ``Item:DataURI``);
  the first is the primary image (the JPEG itself), the others are appended after it, in
  order, filling the file's tail. A camera's ``DepthMap`` element (``Format``, ``Near``,
  ``Far``, ``Units``, ``MeasureType``, ``DepthURI``) names the item holding its depth image.
* **GDepth** (the older "depthmap metadata": Google Camera's Lens Blur and apps that follow
  it). ``GDepth:Format``, ``Near``, ``Far``, ``Mime`` and ``Data`` (the depth image in base64,
  in the extended XMP that continues over several APP1 segments). Lens Blur's primary image is
  the blurred result; ``GImage:Data``, when present, is the photo before the blur, and it is
  the one read as colour (a hologram should focus by itself, not show a baked-in blur).

* **Apple's depth data in MPF images** (an iPhone's portrait photo saved as JPEG, "Most
  Compatible"). The primary JPEG's APP2 ``MPF`` index (CIPA DC-007, the Multi-Picture Format)
  lists the images appended after it; the one whose XMP in Apple's pixel data info namespace
  (``apdi:``) states a ``NativeFormat`` of disparity or depth (Core Video's ``hdis``,
  ``fdis``, ``hdep``, ``fdep``, written as the number their four characters make) is the map;
  the portrait mattes beside it are skipped. Its codes run linearly from ``IntMinValue`` at
  ``FloatMinValue`` to ``IntMaxValue`` at ``FloatMaxValue``: disparity in 1/m (so linear in
  inverse depth, as ``RangeInverse``, the largest code nearest) or depth in metres.
  ``depthData:Accuracy`` says whether those units are measured (``absolute``) or estimated
  (``relative``: right about what is nearer, not about how far).

The depth image holds normalised codes ``d_n = code / max_code`` in [0, 1], decoded by the
file's ``Format`` (Google's depthmap encoding):

* ``RangeLinear``: ``d = near + d_n (far - near)``;
* ``RangeInverse``: ``d = far near / (far - d_n (far - near))`` (``d_n`` linear in ``1 / d``:
  ``0`` at ``near``, ``1`` at ``far``).

``Near``/``Far`` are in the file's ``Units`` (metres: ``Meters`` or ``m``; ``mm`` is scaled to
metres; ``Diopters`` are inverted). The depth image is stored in the primary image's stored
orientation (it is "stretched to fit" the colour image): it is turned upright by the
primary's EXIF ``Orientation`` tag as the photo is, unless it states an orientation of its own.
"""

from __future__ import annotations

import base64
import binascii
import re
import struct
import tempfile
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path
from typing import Dict, List, Optional, Tuple

import numpy as np

from ..validate import warn_at_caller
from .images import PathLike, _upright, _upright_header, check_input_file, read_image

__all__ = ["DepthPhotoWarning", "EmbeddedDepth", "find_embedded_depth", "read_depth_photo",
           "decode_depth_codes"]


class DepthPhotoWarning(UserWarning):
    """A depth photo's map is read, but not exactly as its metadata means (distances along
    each pixel's ray taken as depths along the optical axis, units clholo does not know)."""


_XMP_HEADER = b"http://ns.adobe.com/xap/1.0/\x00"
_XMP_EXTENSION_HEADER = b"http://ns.adobe.com/xmp/extension/\x00"
_RDF = "http://www.w3.org/1999/02/22-rdf-syntax-ns#"
_GDEPTH = "http://ns.google.com/photos/1.0/depthmap/"
_GIMAGE = "http://ns.google.com/photos/1.0/image/"
_GCONTAINER = "http://ns.google.com/photos/1.0/container/"
# Dynamic Depth's namespaces are http://ns.google.com/photos/dd/1.0/<element>/; its elements
# are found by local name (DepthMap, Directory, Profile, Cameras) within them
_DYNAMIC_DEPTH = "http://ns.google.com/photos/dd/"
_APPLE_PIXEL_INFO = "http://ns.apple.com/pixeldatainfo/1.0/"
_APPLE_DEPTH_DATA = "http://ns.apple.com/depthData/1.0/"
# Core Video's pixel formats of a depth map, by their four characters: what the codes stand for
_APPLE_FORMATS = {b"hdis": "disparity", b"fdis": "disparity", b"hdep": "depth",
                  b"fdep": "depth"}
_MPF_HEADER = b"MPF\x00"
_MP_ENTRY_TAG = 0xB002  # the MP Index IFD's list of images: 16 bytes each
_SIGNATURES = {"image/jpeg": b"\xff\xd8\xff", "image/png": b"\x89PNG\r\n\x1a\n"}
_SUFFIXES = {"image/jpeg": ".jpg", "image/png": ".png"}
# Units as the files write them, to metres (None: relative values, kept as they are)
_UNITS = {"meters": 1.0, "metres": 1.0, "m": 1.0, "mm": 1e-3, "millimeters": 1e-3,
          "millimetres": 1e-3, "cm": 1e-2, "none": None, "": None}
# The channels of a depth JPEG saved as RGB differ by the codec's rounding alone
_JPEG_CHANNEL_SLACK = 0.02


@dataclass(frozen=True)
class EmbeddedDepth:
    """A depth map found inside a photo, as its metadata states it.

    Attributes
    ----------
    layout : str
        ``"Dynamic Depth"``, ``"GDepth"`` or ``"Apple MPF"``.
    encoding : str
        ``"RangeInverse"`` or ``"RangeLinear"`` (see :func:`decode_depth_codes`).
    near, far : float
        The range of the encoding, in ``units``.
    units : str
        As the file states them (``"Meters"``, ``"m"``, ``"mm"``, ``"Diopters"``, ``""``).
    measure : str
        ``"OpticalAxis"`` (depth along the optical axis, the default) or ``"OpticRay"``
        (distance along each pixel's ray).
    mime : str
        The depth image's type, ``"image/jpeg"`` or ``"image/png"``.
    data : bytes
        The depth image file.
    colour : bytes or None
        GDepth's ``GImage:Data``: the photo before Lens Blur, read as colour when present.
    colour_mime : str
    code_near, code_far : float or None
        The stored codes at ``near`` and at ``far`` (Apple's ``IntMaxValue`` and
        ``IntMinValue`` for disparity: the largest code nearest); None: ``0`` and the image's
        largest code (Google's ``d_n = code / max_code``).
    accuracy : str
        Apple's ``depthData:Accuracy``: ``"absolute"`` (measured metres), ``"relative"``
        (estimated: right about what is nearer, not about how far) or ``""`` (not stated).
    statement : str
        The range as the file states it, where it differs from ``near``/``far`` (Apple's
        disparity in 1/m), for :meth:`describe`.
    """

    layout: str
    encoding: str
    near: float
    far: float
    units: str
    measure: str
    mime: str
    data: bytes
    colour: Optional[bytes] = None
    colour_mime: str = ""
    code_near: Optional[float] = None
    code_far: Optional[float] = None
    accuracy: str = ""
    statement: str = ""

    def describe(self) -> str:
        """One phrase for a log line: ``"Dynamic Depth, RangeInverse 0.3..4 Meters"``."""
        if self.statement:
            return f"{self.layout}, {self.statement}"
        units = f" {self.units}" if self.units else " (units not stated)"
        return f"{self.layout}, {self.encoding} {self.near:g}..{self.far:g}{units}"

    def normalised(self, codes: np.ndarray, max_code: float) -> np.ndarray:
        """``d_n`` of :func:`decode_depth_codes` (0 at ``near``, 1 at ``far``) from the depth
        image's codes (float64)."""
        codes = np.asarray(codes, dtype=np.float64)
        if self.code_near is None or self.code_far is None:
            return codes / max_code
        return (codes - self.code_near) / (self.code_far - self.code_near)


def decode_depth_codes(normalised: np.ndarray, *, encoding: str, near: float,
                       far: float) -> np.ndarray:
    """Depths from the normalised codes of a depth photo's map (Google's depthmap encoding).

    Parameters
    ----------
    normalised : ndarray
        ``code / max_code``, in [0, 1].
    encoding : {"RangeInverse", "RangeLinear"}
        ``RangeLinear``: ``near + d_n (far - near)``; ``RangeInverse``:
        ``far near / (far - d_n (far - near))``, linear in inverse depth.
    near, far : float
        The encoding's range, in the file's units; ``0 <= near < far`` (``0 < near`` for
        ``RangeInverse``).

    Returns
    -------
    ndarray, float64, same shape: depths in the units of ``near``/``far``.
    """
    d_n = np.asarray(normalised, dtype=np.float64)
    if encoding == "RangeLinear":
        return near + d_n * (far - near)
    if encoding == "RangeInverse":
        return far * near / (far - d_n * (far - near))
    raise ValueError(f"encoding must be 'RangeInverse' or 'RangeLinear', got {encoding!r}")


def _jpeg_app1(data: bytes) -> List[bytes]:
    """The payloads of a JPEG's APP1 segments, up to its first scan (where metadata ends)."""
    return [payload for _, payload in _jpeg_segments(data, 0xE1)]


def _jpeg_segments(data: bytes, wanted: int) -> List[Tuple[int, bytes]]:
    """``(offset in data, payload)`` of a JPEG's segments with marker ``0xFF wanted``, up to
    its first scan (where metadata ends)."""
    if data[:2] != b"\xff\xd8":
        return []
    found, pos = [], 2
    while pos + 4 <= len(data):
        if data[pos] != 0xFF:
            break  # not a marker: a damaged header; the image reader says what is wrong
        marker = data[pos + 1]
        if marker == 0xFF:  # fill byte before a marker
            pos += 1
            continue
        if marker == 0x01 or 0xD0 <= marker <= 0xD7:
            pos += 2
            continue
        if marker in (0xDA, 0xD9):  # start of scan, end of image
            break
        length = struct.unpack(">H", data[pos + 2:pos + 4])[0]
        if length < 2 or pos + 2 + length > len(data):
            break
        if marker == wanted:
            found.append((pos + 4, data[pos + 4:pos + 2 + length]))
        pos += 2 + length
    return found


def _xmp_packets(data: bytes, path: Path) -> List[bytes]:
    """The JPEG's XMP: the main packet, then the extended XMP it points to, assembled from
    its chunks (each APP1 holds at most 64 KiB, so a depth image in base64 spans many)."""
    segments = _jpeg_app1(data)
    main = [s[len(_XMP_HEADER):] for s in segments if s.startswith(_XMP_HEADER)]
    if not main:
        return []
    guid_match = re.search(rb'HasExtendedXMP\s*(?:=\s*["\']|>)\s*([0-9A-Fa-f]{32})',
                           b"".join(main))
    chunks: Dict[int, bytes] = {}
    total = None
    for s in segments:
        if not s.startswith(_XMP_EXTENSION_HEADER):
            continue
        body = s[len(_XMP_EXTENSION_HEADER):]
        if len(body) < 40 or guid_match is None or body[:32] != guid_match.group(1):
            continue  # another packet's chunk (only the one the main packet names counts)
        size, offset = struct.unpack(">II", body[32:40])
        total = size
        chunks[offset] = body[40:]
    packets = list(main)
    if guid_match is not None and total is not None:
        extended = bytearray(total)
        covered = 0
        for offset, chunk in sorted(chunks.items()):
            if offset != covered or offset + len(chunk) > total:
                raise ValueError(f"{path}: its extended XMP metadata (where a depth photo keeps "
                                 f"its depth map) is incomplete: parts are missing from byte "
                                 f"{covered} of {total}; export the photo again from the "
                                 f"phone (an editor may have dropped them)")
            extended[offset:offset + len(chunk)] = chunk
            covered = offset + len(chunk)
        if covered != total:
            raise ValueError(f"{path}: its extended XMP metadata (where a depth photo keeps its "
                             f"depth map) stops at byte {covered} of {total}; export the "
                             f"photo again from the phone")
        packets.append(bytes(extended))
    return packets


def _describes_depth(packet: bytes) -> bool:
    """Whether an XMP packet is a depth map's metadata (Google's or Apple's words)."""
    return b"depthmap/" in packet or _APPLE_PIXEL_INFO.encode() in packet


def _parse(packet: bytes, path: Path) -> Optional[ET.Element]:
    if b"<!DOCTYPE" in packet or b"<!ENTITY" in packet:
        # XMP has no document type; entities are how XML is made to expand without end
        if _describes_depth(packet):
            raise ValueError(f"{path}: its XMP metadata, which describes its depth map, "
                             f"declares a document type or entities, which XMP never does; "
                             f"export the photo again from the phone")
        return None
    try:
        return ET.fromstring(packet.strip(b"\x00 \r\n\t"))
    except ET.ParseError as exc:
        if _describes_depth(packet):  # a depth photo whose metadata cannot be read: say so
            raise ValueError(f"{path}: its XMP metadata, which describes its depth map, is not "
                             f"well-formed XML ({exc}); export the photo again from the "
                             f"phone") from None
        return None


def _local(tag: str) -> Tuple[str, str]:
    """``(namespace, local name)`` of an ElementTree tag or attribute name."""
    if tag.startswith("{"):
        ns, _, name = tag[1:].partition("}")
        return ns, name
    return "", tag


def _properties(element: ET.Element, in_namespace) -> Dict[str, str]:
    """The simple properties an RDF node states in the namespaces ``in_namespace`` accepts,
    by local name: as attributes (``DepthMap:Near="0.2"``) or as child elements with text
    (``<DepthMap:Near>0.2</DepthMap:Near>``), the two forms RDF allows."""
    found = {}
    for key, value in element.attrib.items():
        ns, name = _local(key)
        if in_namespace(ns):
            found[name] = value.strip()
    for child in element:
        ns, name = _local(child.tag)
        if in_namespace(ns) and len(child) == 0 and child.text is not None:
            found.setdefault(name, child.text.strip())
    return found


def _nodes(root: ET.Element, local_name: str, in_namespace) -> List[ET.Element]:
    """Elements named ``local_name`` in an accepted namespace, in document order; an element
    written with ``rdf:parseType="Resource"`` or an ``rdf:Description`` inside stands for
    itself and its description both."""
    nodes = []
    for element in root.iter():
        ns, name = _local(element.tag)
        if name == local_name and in_namespace(ns):
            nodes.append(element)
            nodes.extend(d for d in element if d.tag == f"{{{_RDF}}}Description")
    return nodes


def _dd(ns: str) -> bool:
    return ns.startswith(_DYNAMIC_DEPTH)


def _container(ns: str) -> bool:
    """Dynamic Depth's container and item namespaces, and Google's camera container's
    (``http://ns.google.com/photos/1.0/container/``, whose items state a ``Semantic``)."""
    return _dd(ns) or ns.startswith(_GCONTAINER)


def _merged(elements: List[ET.Element], in_namespace) -> Dict[str, str]:
    found: Dict[str, str] = {}
    for element in elements:
        for key, value in _properties(element, in_namespace).items():
            found.setdefault(key, value)
    return found


def _sequence(element: ET.Element) -> List[ET.Element]:
    """The ``rdf:li`` entries of the ``rdf:Seq`` inside ``element``."""
    return [li for li in element.iter(f"{{{_RDF}}}li")]


def _number(props: Dict[str, str], key: str, path: Path, where: str) -> float:
    if key not in props:
        raise ValueError(f"{path}: its {where} states no {key}, which decoding the depth map "
                         f"needs; export the photo again from the phone, or give the photo "
                         f"and a depth map file")
    try:
        value = float(props[key])
    except ValueError:
        raise ValueError(f"{path}: its {where} states {key}={props[key]!r}, not a number; "
                         f"export the photo again, or give the photo and a depth map "
                         f"file") from None
    if not np.isfinite(value):
        raise ValueError(f"{path}: its {where} states {key}={props[key]!r}; export the photo "
                         f"again, or give the photo and a depth map file")
    return value


def _dynamic_depth(roots: List[ET.Element], data: bytes, path: Path) -> Optional[EmbeddedDepth]:
    maps = [m for r in roots for m in _nodes(r, "DepthMap", _dd)]
    maps = [m for m in maps if _properties(m, _dd)]
    if not maps:
        return None
    depth_maps = [m for m in maps
                  if _properties(m, _dd).get("ItemSemantic", "Depth").lower() != "segmentation"]
    if not depth_maps:
        return None
    props = _properties(depth_maps[0], _dd)  # the first camera's: the primary image's
    where = "Dynamic Depth DepthMap"
    uri = props.get("DepthURI", "")
    directory = [li for r in roots for d in _nodes(r, "Directory", _container)
                 for li in _sequence(d)]
    items = [_merged(list(li.iter()), lambda ns: _container(ns) and "item" in ns)
             for li in directory]
    if not items:
        raise ValueError(f"{path}: its Dynamic Depth metadata describes a depth map but lists "
                         f"no items (Container:Directory), so where the map is in the file "
                         f"is unknown; export the photo again from the phone")
    matches = [i for i, item in enumerate(items) if i > 0 and uri and item.get("DataURI") == uri]
    if not matches:  # items that state their role instead of a URI
        matches = [i for i, item in enumerate(items)
                   if i > 0 and item.get("Semantic", "").lower() == "depth"]
    if not matches:
        raise ValueError(f"{path}: its Dynamic Depth depth map (DepthURI {uri!r}) is none of "
                         f"the items its directory lists "
                         f"({', '.join(repr(i.get('DataURI', '')) for i in items)}); export the "
                         f"photo again from the phone")
    payload, mime = _item_bytes(items, matches[0], data, path)
    return EmbeddedDepth(layout="Dynamic Depth", encoding=_encoding(props, path, where),
                         near=_number(props, "Near", path, where),
                         far=_number(props, "Far", path, where), units=props.get("Units", ""),
                         measure=props.get("MeasureType", "OpticalAxis"), mime=mime,
                         data=payload)


def _item_bytes(items: List[Dict[str, str]], index: int, data: bytes,
                path: Path) -> Tuple[bytes, str]:
    """Item ``index`` of a Dynamic Depth directory. Items after the primary image are
    appended to the file in the directory's order and fill its tail: item ``k`` starts
    ``sum(Length of items k..)`` bytes before the end (``Padding`` counted in ``Length``, or
    else after it: the place where the item's file signature is)."""
    lengths = []
    for number, item in enumerate(items[1:], start=1):
        try:
            length, padding = int(item.get("Length", "")), int(item.get("Padding", "0") or 0)
        except ValueError:
            raise ValueError(f"{path}: item {number} of its Dynamic Depth directory states "
                             f"Length {item.get('Length')!r}, Padding {item.get('Padding')!r}; "
                             f"export the photo again from the phone") from None
        if length <= 0 or padding < 0 or padding >= length:
            raise ValueError(f"{path}: item {number} of its Dynamic Depth directory states "
                             f"Length {length}, Padding {padding}; export the photo again "
                             f"from the phone")
        lengths.append((length, padding))
    mime = items[index].get("Mime", "").lower()
    if mime not in _SIGNATURES:
        raise ValueError(f"{path}: its depth map is stored as {mime or 'an unstated type'!r}; "
                         f"clholo reads depth images of type image/jpeg and image/png")
    tail = sum(length for length, _ in lengths)
    if tail > len(data):
        raise ValueError(f"{path}: its Dynamic Depth items take {tail} bytes but the file has "
                         f"{len(data)}: it is cut short (copy it again)")
    length, padding = lengths[index - 1]
    starts = []
    # Padding within Length (Google's Dynamic Depth library checks Length > Padding), or
    # between the item's Length bytes and the next item (as Google's camera container
    # describes the primary image's padding)
    for outside in (0, 1):
        sizes = [n + outside * pad for n, pad in lengths]
        start = len(data) - sum(sizes) + sum(sizes[:index - 1])
        payload = data[start:start + length - (1 - outside) * padding] if start >= 0 else b""
        if payload.startswith(_SIGNATURES[mime]):
            return payload, mime
        starts.append(str(start))
    raise ValueError(f"{path}: its depth map is not where its Dynamic Depth directory puts it "
                     f"(byte {' or '.join(dict.fromkeys(starts))} does not start a {mime} "
                     f"file): the file was changed after the camera wrote it (an editor that "
                     f"appended or dropped bytes?); export the photo again from the phone")


def _encoding(props: Dict[str, str], path: Path, where: str) -> str:
    stated = props.get("Format", "")
    for encoding in ("RangeInverse", "RangeLinear"):
        if stated.lower() == encoding.lower():
            return encoding
    raise ValueError(f"{path}: its {where} states Format {stated!r}; the depth encodings are "
                     f"RangeInverse and RangeLinear; give the photo and a depth map file")


def _base64(text: str, path: Path, what: str) -> bytes:
    try:
        return base64.b64decode("".join(text.split()), validate=True)
    except (binascii.Error, ValueError):
        raise ValueError(f"{path}: its {what} is not valid base64; export the photo again "
                         f"from the phone") from None


def _gdepth(roots: List[ET.Element], path: Path) -> Optional[EmbeddedDepth]:
    descriptions = [d for r in roots for d in r.iter(f"{{{_RDF}}}Description")]
    props = _merged(descriptions, lambda ns: ns == _GDEPTH)
    if not props:
        return None
    where = "GDepth metadata"
    if "Data" not in props:
        raise ValueError(f"{path}: its GDepth metadata describes a depth map but holds no "
                         f"GDepth:Data (the map itself, kept in the extended XMP): an editor "
                         f"may have dropped it; export the photo again from the phone")
    mime = props.get("Mime", "image/jpeg").lower()
    if mime not in _SIGNATURES:
        raise ValueError(f"{path}: its depth map is stored as {mime!r}; clholo reads depth "
                         f"images of type image/jpeg and image/png")
    image = _merged(descriptions, lambda ns: ns == _GIMAGE)
    colour = _base64(image["Data"], path, "GImage:Data") if "Data" in image else None
    colour_mime = image.get("Mime", "image/jpeg").lower()
    if colour is not None and colour_mime not in _SIGNATURES:
        raise ValueError(f"{path}: its original image (GImage:Data) is stored as "
                         f"{colour_mime!r}; clholo reads image/jpeg and image/png")
    return EmbeddedDepth(layout="GDepth", encoding=_encoding(props, path, where),
                         near=_number(props, "Near", path, where),
                         far=_number(props, "Far", path, where), units=props.get("Units", "m"),
                         measure=props.get("MeasureType", "OpticalAxis"), mime=mime,
                         data=_base64(props["Data"], path, "GDepth:Data"), colour=colour,
                         colour_mime=colour_mime)


def _mpf_images(data: bytes, path: Path) -> List[Tuple[int, bytes]]:
    """``(number, bytes)`` of the images after the first that a JPEG's MPF index lists
    (CIPA DC-007: an APP2 segment ``MPF\\0``, a TIFF header, the MP Index IFD whose MP Entry
    tag lists each image's attribute, size and offset from that TIFF header; the first image
    is the JPEG itself, at offset 0). Numbered from 1 as the index counts them."""
    for start, payload in _jpeg_segments(data, 0xE2):
        if payload.startswith(_MPF_HEADER):
            base, tiff = start + len(_MPF_HEADER), payload[len(_MPF_HEADER):]
            break
    else:
        return []
    order = {b"II": "<", b"MM": ">"}.get(tiff[:2])
    if order is None or len(tiff) < 8 or struct.unpack(order + "H", tiff[2:4])[0] != 42:
        return []  # not an MP header: another APP2 use
    ifd = struct.unpack(order + "I", tiff[4:8])[0]
    if ifd + 2 > len(tiff):
        return []
    entries = b""
    for k in range(struct.unpack(order + "H", tiff[ifd:ifd + 2])[0]):
        at = ifd + 2 + 12 * k
        if at + 12 > len(tiff):
            break
        tag, _, count, value = struct.unpack(order + "HHII", tiff[at:at + 12])
        if tag == _MP_ENTRY_TAG:
            entries = tiff[value:value + count] if count > 4 else tiff[at + 8:at + 8 + count]
            break
    images = []
    for number in range(2, len(entries) // 16 + 1):
        _, size, offset, _, _ = struct.unpack(order + "IIIHH",
                                              entries[16 * (number - 1):16 * number])
        if size == 0 or offset == 0:
            continue  # an entry that holds no image of its own
        if base + offset + size > len(data):
            raise ValueError(f"{path}: its MPF index places image {number} at bytes "
                             f"{base + offset}..{base + offset + size} but the file has "
                             f"{len(data)}: it is cut short (copy it again)")
        images.append((number, data[base + offset:base + offset + size]))
    return images


def _apple_format(stated: str) -> Optional[str]:
    """``"disparity"``, ``"depth"`` or None (a matte's grey, or not Apple's) for an
    ``apdi:NativeFormat``: the number its four characters make, or the characters."""
    stated = stated.strip()
    try:
        code = int(stated).to_bytes(4, "big")
    except (ValueError, OverflowError):
        code = stated.encode("ascii", "replace")
    return _APPLE_FORMATS.get(code)


def _apple_mpf(data: bytes, path: Path) -> Optional[EmbeddedDepth]:
    for number, image in _mpf_images(data, path):
        if not image.startswith(_SIGNATURES["image/jpeg"]):
            continue
        roots = [r for r in (_parse(p, path) for p in _xmp_packets(image, path))
                 if r is not None]
        descriptions = [d for r in roots for d in r.iter(f"{{{_RDF}}}Description")]
        props = _merged(descriptions, lambda ns: ns == _APPLE_PIXEL_INFO)
        quantity = _apple_format(props.get("NativeFormat", ""))
        if quantity is None or "matte" in props.get("AuxiliaryImageSubType", "").lower():
            continue  # a portrait matte, a gain map, a preview: no depth
        where = f"MPF image {number}'s Apple depth metadata"
        low, high = (_number(props, k, path, where) for k in ("FloatMinValue", "FloatMaxValue"))
        code_low, code_high = (_number(props, k, path, where)
                               for k in ("IntMinValue", "IntMaxValue"))
        if not low < high or code_low == code_high:
            raise ValueError(f"{path}: its {where} maps codes {code_low:g}..{code_high:g} to "
                             f"{low:g}..{high:g}: no range (it needs FloatMinValue < "
                             f"FloatMaxValue, IntMinValue != IntMaxValue); give the photo and "
                             f"a depth map file")
        depth_data = _merged(descriptions, lambda ns: ns == _APPLE_DEPTH_DATA)
        accuracy = depth_data.get("Accuracy", "")
        if quantity == "disparity":
            if low <= 0:
                raise ValueError(f"{path}: its {where} states disparities from {low:g} 1/m: "
                                 f"a disparity of 0 or less is no distance; give the photo "
                                 f"and a depth map file")
            # linear in 1/d, the largest code nearest: RangeInverse from 1/high to 1/low
            encoding, near, far = "RangeInverse", 1.0 / high, 1.0 / low
            code_near, code_far = code_high, code_low
            statement = f"disparity {low:g}..{high:g} 1/m"
        else:
            encoding, near, far = "RangeLinear", low, high
            code_near, code_far = code_low, code_high
            statement = f"depth {low:g}..{high:g} m"
        if accuracy:
            statement += f" ({accuracy.lower()})"
        return EmbeddedDepth(layout="Apple MPF", encoding=encoding, near=near, far=far,
                             units="Meters", measure="OpticalAxis", mime="image/jpeg",
                             data=image, code_near=code_near, code_far=code_far,
                             accuracy=accuracy.lower(), statement=statement)
    return None


def find_embedded_depth(path: PathLike) -> Optional[EmbeddedDepth]:
    """The depth map a photo carries inside (Dynamic Depth, GDepth, Apple's MPF images), or
    None.

    Parameters
    ----------
    path : path-like
        A JPEG file; any other file gives None.

    Raises
    ------
    ValueError
        The file's metadata describes a depth map that cannot be read (its XMP cut short or
        not well-formed, the map not where the directory or MPF index puts it, a range that
        is not a number); the message names the file and the fix.
    """
    path = Path(path)
    with open(path, "rb") as f:
        if f.read(2) != b"\xff\xd8":
            return None
        data = b"\xff\xd8" + f.read()
    packets = _xmp_packets(data, path)
    roots = [r for r in (_parse(p, path) for p in packets) if r is not None]
    return ((_dynamic_depth(roots, data, path) or _gdepth(roots, path)) if roots else None) \
        or _apple_mpf(data, path)


def _check_range(depth: EmbeddedDepth, path: Path) -> None:
    near, far = depth.near, depth.far
    lowest = 0.0 if depth.encoding == "RangeLinear" else np.nextafter(0.0, 1.0)
    if not (lowest <= near < far):
        need = "0 <= near < far" if depth.encoding == "RangeLinear" else "0 < near < far"
        raise ValueError(f"{path}: its depth map's range is Near {near:g}, Far {far:g}; "
                         f"{depth.encoding} needs {need}; give the photo and a depth map "
                         f"file")


def _stated_orientation(attributes: dict) -> int:
    try:
        return int(attributes.get("Orientation", 1))
    except (TypeError, ValueError):
        return 1


def _read_item(payload: bytes, mime: str, tmp: Path, name: str, *, colour: bool):
    """An embedded image file read as clholo reads files (through a temporary file: the
    same reader, orientation and colour rules)."""
    from .rgbd import read_rgb

    item = tmp / f"{name}{_SUFFIXES[mime]}"
    item.write_bytes(payload)
    pixels, info = read_image(item, normalise=False)
    return (read_rgb(item) if colour else pixels), info


def read_depth_photo(path: PathLike) -> Tuple[np.ndarray, np.ndarray, dict]:
    """A phone photo's colour and the depth map it carries inside (Dynamic Depth, GDepth,
    Apple's MPF images).

    Parameters
    ----------
    path : path-like
        A JPEG with an embedded depth map (:func:`find_embedded_depth`).

    Returns
    -------
    image : ndarray, shape (H, W, 3), float32
        Linear colour (:func:`~clholo.io.read_rgb`), upright: the primary image, or GDepth's
        original (``GImage:Data``, the photo before Lens Blur) when the file holds one.
    depth : ndarray, shape (h, w), float32
        Depth in metres (in the file's units when it states none, or units clholo does not
        know), upright like ``image``, at the map's own size (usually smaller than the
        photo's; it stands for the whole photo).
    info : dict
        ``layout``, ``encoding``, ``near``, ``far``, ``units``, ``measure`` (as the file states
        them; Apple's range as ``near``/``far`` in metres), ``accuracy`` (Apple's
        ``"absolute"`` or ``"relative"``, ``""`` elsewhere), ``colour`` (``"primary image"``
        or ``"GImage (before Lens Blur)"``), ``describe`` (one phrase for a log line),
        ``primary_size`` (the primary image's upright ``(H, W)``).

    Raises
    ------
    ValueError
        The file holds no depth map, or one that cannot be read; the message names the file.
    """
    from .rgbd import read_rgb

    path = check_input_file(path, "depth photo", "give a JPEG photo with its depth map inside")
    embedded = find_embedded_depth(path)
    if embedded is None:
        raise ValueError(f"{path} carries no depth map (no Dynamic Depth, GDepth or Apple "
                         f"MPF depth metadata): give it and its depth map together (image "
                         f"first)")
    _check_range(embedded, path)
    turn, primary_size = _upright_header(path)
    with tempfile.TemporaryDirectory(prefix="clholo-depth-photo-") as tmp:
        try:
            codes, info = _read_item(embedded.data, embedded.mime, Path(tmp), "depth",
                                     colour=False)
            if embedded.colour is not None:
                image, colour_info = _read_item(embedded.colour, embedded.colour_mime,
                                                Path(tmp), "original", colour=True)
            else:
                image, colour_info = read_rgb(path), None
        except ValueError as exc:
            raise ValueError(f"{path}: its embedded {embedded.layout} image cannot be read: "
                             f"{str(exc).replace(str(tmp), '<embedded>')}") from None
    if info["max_code"] is None:
        raise ValueError(f"{path}: its embedded depth map holds float values; the depth "
                         f"encodings store integer codes (8- or 16-bit)")
    a = info["alpha_channel"]
    if a >= 0 and codes.shape[2] > 1:
        codes = np.delete(codes, a, axis=2)
    spread = float(np.max(np.ptp(codes, axis=2))) if codes.shape[2] > 1 else 0.0
    if spread > _JPEG_CHANNEL_SLACK * info["max_code"]:
        raise ValueError(f"{path}: its embedded depth map has {codes.shape[2]} channels that "
                         f"differ (by up to {spread:g} codes): not a grey depth image")
    if embedded.code_near is not None and max(embedded.code_near,
                                              embedded.code_far) > info["max_code"]:
        raise ValueError(f"{path}: its {embedded.layout} depth metadata states codes up to "
                         f"{max(embedded.code_near, embedded.code_far):g} but its depth image "
                         f"stores codes up to {info['max_code']:g}; give the photo and a depth "
                         f"map file")
    normalised = embedded.normalised(np.mean(codes, axis=2, dtype=np.float64),
                                     info["max_code"])
    depth = decode_depth_codes(normalised, encoding=embedded.encoding, near=embedded.near,
                               far=embedded.far)
    units = embedded.units.strip().lower()
    if units in ("diopters", "dioptres"):
        depth = 1.0 / depth
    elif units in _UNITS:
        depth = depth * (_UNITS[units] or 1.0)
    else:
        warn_at_caller(f"{path}: its depth map states units {embedded.units!r}, which clholo "
                       f"does not know: the values are taken as they are (only their ratios "
                       f"matter to the planes)", DepthPhotoWarning)
    if embedded.measure.lower() == "opticray":
        warn_at_caller(f"{path}: its depth map holds distances along each pixel's ray "
                       f"(MeasureType OpticRay); they are binned as depths along the optical "
                       f"axis, which puts the photo's corners slightly farther than they are",
                       DepthPhotoWarning)
    # the items hold the primary image's stored pixels: turned as the photo is, unless an
    # item states an orientation of its own (then its reader turned it already)
    if _stated_orientation(info["attributes"]) == 1:
        depth = _upright(depth[..., None], turn)[..., 0]
    if colour_info is not None and _stated_orientation(colour_info["attributes"]) == 1:
        image = _upright(image, turn)
    colour = "GImage (before Lens Blur)" if embedded.colour is not None else "primary image"
    return image, depth.astype(np.float32), {
        "layout": embedded.layout, "encoding": embedded.encoding, "near": embedded.near,
        "far": embedded.far, "units": embedded.units, "measure": embedded.measure,
        "accuracy": embedded.accuracy,
        "colour": colour, "describe": embedded.describe(), "primary_size": primary_size}
