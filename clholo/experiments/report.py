"""``clholo report``: one self-contained HTML page of a render folder or an experiment folder.

The page needs no server and no network: every image is inline (base64 PNG) and the only
script is the page's own. What it shows depends on what the folder holds (all optional, at
least one needed):

* ``focal_stack.npz`` (written by ``clholo render`` / ``clholo demo``): ``intensity``
  ``[D, C, H, W]`` (linear), ``depths_m`` ``[D]``, ``wavelengths_m`` ``[C]``: the focal stack
  with a depth slider. One exposure for the whole stack (its 99.5th percentile maps to white),
  sRGB-encoded for the screen.
* ``views.npz``: ``angles_rad`` ``[A]`` (horizontal angles) or ``[A, 2]`` (``theta_x,
  theta_y``) and ``intensity`` ``[A, C, H, W]`` (linear; e.g. pupil views of a hologram or
  ray-optics views): the views with an angle slider, one exposure for all of them.
* ``summary.json``: a table of its keys and values.
* ``results.csv``: a table; ``results.md``: shown as text.
* ``*.png``: the figures (plots, picture sheets, ``focal_stack.png``), inline.

Images are shown at most ``max_side`` pixels on their longer side (default
:data:`DISPLAY_MAX_SIDE_PX`): a larger one is reduced by a whole factor, each shown pixel the
mean of a block of stored ones in linear light, and the page says so; the stored files keep
every pixel. A 12-megapixel render's page was 300 MB at full size, more than a browser opens.

The sliders can be set from the address: ``report.html#depth=2&view=1`` moves the depth slider
to slice 2 and the angle slider to view 1 (through the same ``input`` event a hand on the
slider fires), and moving a slider writes its position back into the address.
"""

from __future__ import annotations

import base64
import contextlib
import csv
import html
import io
import json
import tempfile
import warnings
from pathlib import Path
from typing import List, Optional, Sequence, Tuple

import numpy as np

from clholo.io.output import update_manifest

__all__ = ["build_report", "ReportWarning", "block_mean", "DISPLAY_MAX_SIDE_PX"]


def _png_data_uri(pixels: np.ndarray) -> str:
    """``data:image/png;base64,...`` of display values ``(H, W, C)``: in [0, 1], or 8-bit
    codes."""
    from clholo.io import write_image

    with tempfile.TemporaryDirectory(prefix="clholo-report-") as tmp:
        path = Path(tmp) / "image.png"
        write_image(path, pixels, dtype="uint8", atomic=False)
        data = path.read_bytes()
    return "data:image/png;base64," + base64.b64encode(data).decode("ascii")


_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"

# The longest side, in pixels, an image is shown at by default: a 4K screen's width, and a
# page of a 12-megapixel render's slices and contact sheet that a browser still opens (37 MB)
DISPLAY_MAX_SIDE_PX = 2048
# Values per band of a large figure's reduction (16 MiB of float64)
_FIGURE_BAND_ELEMENTS = 1 << 21


class ReportWarning(UserWarning):
    """Something in the folder that the report leaves out (the message names it)."""


def _file_data_uri(path: Path) -> str:
    return "data:image/png;base64," + base64.b64encode(path.read_bytes()).decode("ascii")


def _figure(path: Path, max_side: Optional[int]) -> Tuple[str, str]:
    """A figure's data URI and a note of its reduction ("" when shown as stored): a PNG
    larger than ``max_side`` is decoded (sRGB, or linear when it says so), reduced by
    :func:`block_mean` in linear light (alpha as it is) and encoded again. Every PNG is
    decoded whole (ValueError for a truncated or damaged one: a page that embeds it would
    show a broken image without a word)."""
    from clholo.io import linear_to_srgb8, read_image, srgb_to_linear

    pixels, info = read_image(path)  # decodes every row: a cut-off file fails here
    factor = _reduction(pixels.shape[:2], max_side)
    if factor == 1:
        return _file_data_uri(path), ""
    H, W, C = pixels.shape
    colour = [k for k in range(C) if k != info["alpha_channel"]]
    linear = str(info["attributes"].get("oiio:ColorSpace", "")).lower().startswith("lin")
    shown = np.empty((-(-H // factor), -(-W // factor), C), np.float64)
    # bands of whole blocks: no float64 copy of a 48-megapixel contact sheet is made whole
    rows = factor * max(1, _FIGURE_BAND_ELEMENTS // (factor * W * C))
    for r in range(0, H, rows):
        band = pixels[r:r + rows].astype(np.float64)
        if not linear:
            band[..., colour] = srgb_to_linear(band[..., colour])
        shown[r // factor:(r + band.shape[0] - 1) // factor + 1] = block_mean(band, factor)
    codes = np.round(np.clip(shown, 0.0, 1.0) * 255).astype(np.uint8)
    if not linear:
        codes[..., colour] = linear_to_srgb8(shown[..., colour])
    return _png_data_uri(codes), _size_note(pixels.shape[:2], factor)


def _reduction(shape: Tuple[int, int], max_side: Optional[int]) -> int:
    """The whole factor that brings ``shape`` (H, W) to ``max_side`` or less (1: as stored)."""
    if not max_side:
        return 1
    return max(1, -(-max(shape) // max_side))


def block_mean(image: np.ndarray, factor: int) -> np.ndarray:
    """``image`` (H, W, C) reduced by ``factor``: each output pixel the mean of a
    ``factor x factor`` block (the last row and column of blocks hold what is left), float64,
    shape ``(ceil(H / factor), ceil(W / factor), C)``."""
    image = np.asarray(image, dtype=np.float64)
    if factor == 1:
        return image
    H, W = image.shape[:2]
    rows, cols = np.arange(0, H, factor), np.arange(0, W, factor)
    sums = np.add.reduceat(np.add.reduceat(image, rows, axis=0), cols, axis=1)
    counts = np.outer(np.diff(np.append(rows, H)), np.diff(np.append(cols, W)))
    return sums / counts[..., None]


def _size_note(shape: Tuple[int, int], factor: int) -> str:
    if factor == 1:
        return ""
    H, W = shape
    return (f"shown at {-(-W // factor)}x{-(-H // factor)}, 1/{factor} of the stored "
            f"{W}x{H} in each direction (means of {factor}x{factor} blocks in linear light)")


def _display_frames(intensity: np.ndarray, name: str,
                    max_side: Optional[int] = None) -> Tuple[List[str], str]:
    """PNG data URIs of ``intensity[N, C, H, W]`` (linear), one exposure for all N frames,
    reduced to ``max_side`` (:func:`block_mean`), and a note of the reduction ("" when
    none)."""
    from clholo.io import linear_to_srgb8

    arr = np.asarray(intensity)
    if np.iscomplexobj(arr) or not (np.issubdtype(arr.dtype, np.floating)
                                    or np.issubdtype(arr.dtype, np.integer)):
        raise ValueError(f"{name}: intensity must be real (|u|^2 of the field), got "
                         f"{arr.dtype}; a focal stack written by clholo holds float32")
    if arr.ndim != 4 or arr.shape[1] < 1 or min(arr.shape) < 1:
        raise ValueError(f"{name}: intensity must have shape [N, C, H, W], got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name}: intensity holds NaN or infinity")
    if arr.min() < 0:
        raise ValueError(f"{name}: intensity holds negative values (down to {arr.min():.4g}): "
                         f"an intensity is |u|^2 >= 0 (a field's real part is not one)")
    if not arr.any():
        warnings.warn(f"{name}: every intensity is 0: the page shows black images",
                      UserWarning, stacklevel=2)
    # the percentile of the float64 values partitions its own copy; the frames are converted
    # one at a time (a 12-megapixel stack is 880 MB in float64)
    scale = float(np.percentile(arr.astype(np.float64), 99.5, overwrite_input=True))
    if scale <= 0:
        scale = float(arr.max()) or 1.0
    factor = _reduction(arr.shape[2:], max_side)
    frames = []
    for frame in arr:
        img = np.clip(block_mean(frame.transpose(1, 2, 0), factor) / scale, 0.0, 1.0)
        if img.shape[2] == 2:  # two wavelengths: show them as red and green
            img = np.concatenate([img, np.zeros_like(img[..., :1])], axis=2)
        elif img.shape[2] > 3:
            img = img[..., :3]
        frames.append(_png_data_uri(linear_to_srgb8(img)))
    return frames, _size_note(arr.shape[2:], factor)


def _load_npz(path: Path, keys: Sequence[str]) -> dict:
    """Every array of the render folder's archive ``path``, which must hold ``keys``; a
    damaged archive is refused naming it (a header claiming 45 GiB was "Unable to allocate",
    a changed header byte an internal error)."""
    import zipfile

    from clholo.io._npy import open_npz

    if not zipfile.is_zipfile(path):
        raise ValueError(f"{path} is not a readable .npz file (not a zip archive)")
    fix = "render the folder again (clholo render)"
    with open_npz(path, what="", fix=fix) as data:
        missing = [k for k in keys if k not in data.files]
        if missing:
            raise ValueError(f"{path} lacks the array(s) {', '.join(missing)}; it holds "
                             f"{', '.join(data.files) or 'nothing'}")
        return {k: data.load(k) for k in data.files}


def _focal_section(folder: Path, max_side: Optional[int]) -> Optional[Tuple[str, List[dict]]]:
    path = folder / "focal_stack.npz"
    if not path.is_file():
        return None
    data = _load_npz(path, ["intensity"])
    inten = data["intensity"]
    frames, size = _display_frames(inten, str(path), max_side)
    depths = data.get("depths_m")
    if depths is not None and np.shape(depths) != (len(frames),):
        raise ValueError(f"{path}: depths_m has shape {np.shape(depths)} but intensity has "
                         f"{len(frames)} slices")
    if depths is not None:  # metres: millimetres given as metres warn (DepthWarning)
        from clholo import validate

        depths = [validate.distance(d.item(), name=f"{path}: depths_m")
                  for d in np.ravel(depths)]
    labels = [f"slice {k}" + (f": focused at {float(depths[k]) * 1e3:.3f} mm"
                              if depths is not None else "") for k in range(len(frames))]
    wl = data.get("wavelengths_m")
    if wl is not None:
        from clholo import validate

        wl = [validate.wavelength(w.item(), name=f"{path}: wavelengths_m")
              for w in np.ravel(wl)]
    note = "" if wl is None else \
        "wavelengths " + ", ".join(f"{w * 1e9:.0f} nm" for w in np.ravel(wl)) + "; "
    note += "one exposure for the whole stack (99.5th percentile = white), sRGB display"
    note += f"; {size} (every pixel in focal_stack.npz)" if size else ""
    return note, [{"label": lab, "src": src} for lab, src in zip(labels, frames)]


def _views_section(folder: Path, max_side: Optional[int]) -> Optional[Tuple[str, List[dict]]]:
    path = folder / "views.npz"
    if not path.is_file():
        return None
    data = _load_npz(path, ["angles_rad", "intensity"])
    angles = np.asarray(data["angles_rad"], dtype=np.float64)
    frames, size = _display_frames(data["intensity"], str(path), max_side)
    if angles.ndim == 1:
        angles = np.stack([angles, np.zeros_like(angles)], axis=1)
    if angles.shape != (len(frames), 2):
        raise ValueError(f"{path}: angles_rad must have shape [A] or [A, 2] with A = "
                         f"{len(frames)} views, got {data['angles_rad'].shape}")
    if not np.all(np.isfinite(angles)) or np.abs(angles).max() >= np.pi / 2:
        worst = angles.ravel()[np.argmax(np.where(np.isfinite(angles), np.abs(angles),
                                                  np.inf).ravel())]
        raise ValueError(f"{path}: angles_rad holds {worst:g}, not an angle in (-pi/2, pi/2) "
                         f"radians; angles are radians (1 degree = {np.pi / 180:.5f} rad)")
    labels = [f"view {k}: theta_x = {np.degrees(ax):+.3f} deg, theta_y = {np.degrees(ay):+.3f} deg"
              for k, (ax, ay) in enumerate(angles)]
    note = "one exposure for all views (99.5th percentile = white), sRGB display"
    note += f"; {size} (every pixel in views.npz)" if size else ""
    return note, [{"label": lab, "src": src} for lab, src in zip(labels, frames)]


def _table(rows: List[List[str]]) -> str:
    if not rows:
        return "<p>(empty)</p>"
    head, body = rows[0], rows[1:]
    out = ["<table><thead><tr>"]
    out += [f"<th>{html.escape(c)}</th>" for c in head]
    out.append("</tr></thead><tbody>")
    for r in body:
        out.append("<tr>" + "".join(f"<td>{html.escape(c)}</td>" for c in r) + "</tr>")
    out.append("</tbody></table>")
    return "".join(out)


def _text(path: Path) -> str:
    """A text file of the folder, or an error naming it when it is not UTF-8 text."""
    data = path.read_bytes()
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ValueError(f"{path} is not a text file (byte {exc.start} is "
                         f"0x{data[exc.start]:02x}, not UTF-8): move it out of the folder, or "
                         f"write it again") from None


#: The files a report has a section for (``*.png`` besides).
_REPORTED = ("focal_stack.npz", "views.npz", "summary.json", "results.csv", "results.md")


def _listed_but_missing(folder: Path) -> List[str]:
    """The files of :data:`_REPORTED` (and PNGs) that the folder's manifest lists but that are
    not there: a section the page would otherwise leave out without a word."""
    from clholo.io.output import MANIFEST_NAME

    try:
        listed = json.loads((folder / MANIFEST_NAME).read_text()).get("files", [])
    except (OSError, ValueError, AttributeError):  # no manifest (an experiment's), or not ours
        return []
    return [name for name in listed if isinstance(name, str) and "/" not in name
            and (name in _REPORTED or name.endswith(".png")) and not (folder / name).exists()]


def _summary_rows(path: Path) -> List[List[str]]:
    try:
        summary = json.loads(_text(path))
    except json.JSONDecodeError as exc:
        raise ValueError(f"{path} is not valid JSON: {exc}") from None
    if not isinstance(summary, dict):
        return [["value"], [json.dumps(summary)]]
    rows = [["key", "value"]]
    for k, v in summary.items():
        rows.append([str(k), v if isinstance(v, str) else json.dumps(v)])
    return rows


_SCRIPT = """
const SLIDERS = %(sliders)s;
function show(name, k) {
  const s = SLIDERS[name];
  k = Math.max(0, Math.min(s.frames.length - 1, k | 0));
  const img = document.getElementById(name + "-img");
  img.src = s.frames[k].src;
  img.dataset.index = String(k);
  document.getElementById(name + "-label").textContent = s.frames[k].label;
}
function writeHash() {
  const parts = [];
  for (const name of Object.keys(SLIDERS))
    parts.push(name + "=" + document.getElementById(name + "-slider").value);
  history.replaceState(null, "", "#" + parts.join("&"));
}
function readHash() {
  for (const part of location.hash.replace(/^#/, "").split("&")) {
    const [name, value] = part.split("=");
    const slider = document.getElementById(name + "-slider");
    if (!slider || value === undefined || isNaN(parseInt(value))) continue;
    slider.value = String(parseInt(value));
    slider.dispatchEvent(new Event("input"));  // the same path as a hand on the slider
  }
}
for (const name of Object.keys(SLIDERS)) {
  const slider = document.getElementById(name + "-slider");
  slider.addEventListener("input", () => { show(name, parseInt(slider.value)); });
  slider.addEventListener("change", writeHash);
  show(name, 0);
}
window.addEventListener("hashchange", readHash);
readHash();
"""

_STYLE = """
body { font-family: sans-serif; margin: 1.5em; background: #fafafa; color: #222; }
h1 { font-size: 1.4em; } h2 { font-size: 1.15em; margin-top: 1.6em; }
.viewer img { width: min(100%, 900px); image-rendering: pixelated; background: #000; }
figure img { max-width: 100%; }
.viewer input[type=range] { width: min(600px, 90%); }
.note { color: #666; font-size: 0.9em; }
table { border-collapse: collapse; font-size: 0.9em; }
th, td { border: 1px solid #ccc; padding: 0.2em 0.6em; text-align: left; }
pre { background: #eee; padding: 0.6em; overflow-x: auto; }
"""


def _slider_html(name: str, title: str, note: str, frames: List[dict]) -> str:
    return (f'<section class="viewer" id="{name}"><h2>{html.escape(title)}</h2>'
            f'<p class="note">{html.escape(note)}</p>'
            f'<input type="range" id="{name}-slider" min="0" max="{len(frames) - 1}" '
            f'step="1" value="0" aria-label="{html.escape(title)}"> '
            f'<div id="{name}-label"></div>'
            f'<img id="{name}-img" alt="{html.escape(title)}" data-index="0" '
            f'src="{frames[0]["src"]}"></section>')


def build_report(folder, out=None, *, title: Optional[str] = None,
                 overwrite: bool = False, warn=None,
                 max_side: Optional[int] = DISPLAY_MAX_SIDE_PX) -> Path:
    """Write one self-contained HTML page of a render or experiment folder.

    Parameters
    ----------
    folder : path-like
        A folder written by ``clholo render`` / ``clholo demo`` (``focal_stack.npz``,
        ``summary.json``, ...) or by an experiment (``results.csv``, ``results.md``, ``*.png``),
        optionally with ``views.npz`` (``angles_rad`` ``[A]`` or ``[A, 2]``, ``intensity``
        ``[A, C, H, W]``). See the module docstring.
    out : path-like, optional
        The HTML file (default ``folder/report.html``, which needs ``folder`` to be a clholo
        output folder: the report is then listed in its manifest, so that a later
        ``--overwrite`` of the folder still replaces it). Written under a temporary name and
        renamed when complete, through the single-file output policy
        (:func:`clholo.io.output.output_file`): a file clholo did not write, or one changed
        since, is never replaced; a report clholo wrote is replaced only with ``overwrite``.
        A file that belongs to a clholo output folder (listed in its manifest, such as
        ``hologram.npz``) is never replaced by a report.
    title : str, optional
        Page title (default: the folder's name).
    overwrite : bool
        Replace an earlier report written by clholo (``--overwrite``).
    warn : callable, optional
        ``warn(message)`` for what the page leaves out (a ``*.png`` that is not a PNG image is
        skipped, named); default: :func:`warnings.warn` (:class:`ReportWarning`).
    max_side : int or None
        The longest side, in pixels, an image is shown at (default
        :data:`DISPLAY_MAX_SIDE_PX`, 2048): a larger slice, view or figure is reduced by the
        whole factor that brings it there (means of blocks in linear light) and its note
        says so; None or 0 shows every stored pixel (a 12-megapixel render's page is then
        300 MB).

    Returns
    -------
    Path
        The written file.

    Raises
    ------
    FileNotFoundError
        When ``folder`` does not exist, or the parent folder of ``out`` does not.
    clholo.errors.OutputRefused
        When ``out`` may not be written (see ``out``); checked before any work.
    ValueError
        When it holds nothing the report can show, or a file in it is malformed (the message
        names the file).
    """
    if max_side is not None and (isinstance(max_side, bool)
                                 or not isinstance(max_side, (int, np.integer))
                                 or max_side < 0):
        raise ValueError(f"max_side must be a whole number of pixels >= 0 (0 or None: every "
                         f"stored pixel), got {max_side!r}")
    folder = Path(folder)
    if not folder.is_dir():
        what = "is not a folder" if folder.exists() else "does not exist"
        raise FileNotFoundError(f"folder {folder} {what} (give a render or experiment output "
                                f"folder)")
    out = _check_report_path(folder, out, overwrite=overwrite)
    from clholo.io.output import destination_state

    # the folder the report goes into, as read: another run may replace it while this one reads
    owner_state = destination_state(out.parent)
    title = title or folder.resolve().name

    def say(message: str) -> None:
        if warn is None:
            import warnings

            warnings.warn(message, ReportWarning, stacklevel=3)
        else:
            warn(message)

    for name in _listed_but_missing(folder):
        say(f"{folder / name} is listed in {folder.name}'s clholo-output.json but is gone "
            f"(moved or deleted since), so the report has no section for it")
    sections, sliders = [], {}
    focal = _focal_section(folder, max_side)
    if focal is not None:
        sliders["depth"] = focal[1]
        sections.append(_slider_html("depth", "Focal stack", *focal))
    views = _views_section(folder, max_side)
    if views is not None:
        sliders["view"] = views[1]
        sections.append(_slider_html("view", "Views", *views))
    if (folder / "summary.json").is_file():
        sections.append("<section id=\"summary\"><h2>Summary</h2>"
                        + _table(_summary_rows(folder / "summary.json")) + "</section>")
    if (folder / "results.csv").is_file():
        rows = [r for r in csv.reader(io.StringIO(_text(folder / "results.csv"),
                                                 newline=""))]
        sections.append("<section id=\"results\"><h2>Results (results.csv)</h2>"
                        + _table(rows) + "</section>")
    if (folder / "results.md").is_file():
        sections.append("<section id=\"results-md\"><h2>Results (results.md)</h2><pre>"
                        + html.escape(_text(folder / "results.md")) + "</pre></section>")
    figures = []
    for p in sorted(p for p in folder.glob("*.png") if p.is_file()):
        with open(p, "rb") as fh:
            head = fh.read(len(_PNG_SIGNATURE))
        problem = None if head == _PNG_SIGNATURE else "it does not start with the PNG signature"
        if problem is None:
            try:
                figures.append((p, *_figure(p, max_side)))  # decodes it: every row read
                continue
            except (ValueError, OSError) as exc:
                problem = str(exc)
        say(f"{p} is not a readable PNG image ({problem}), so the report leaves it out")
    if figures:
        figs = ""
        for p, src, size in figures:
            caption = p.name + (f" ({size})" if size else "")
            figs += (f"<figure><img alt=\"{html.escape(p.name)}\" src=\"{src}\">"
                     f"<figcaption>{html.escape(caption)}</figcaption></figure>")
        sections.append(f"<section id=\"figures\"><h2>Figures</h2>{figs}</section>")
    if not sections:
        raise ValueError(f"{folder} holds nothing to report: expected focal_stack.npz, "
                         f"views.npz, summary.json, results.csv, results.md or *.png (the "
                         f"output of clholo render/demo or of an experiment)")
    script = ""
    if sliders:
        data = json.dumps({k: {"frames": v} for k, v in sliders.items()})
        script = ("<script>" + _SCRIPT % {"sliders": data.replace("</", "<\\/")}
                  + "</script>")
    page = ("<!DOCTYPE html><html lang=\"en\"><head><meta charset=\"utf-8\">"
            f"<title>{html.escape(title)}</title><style>{_STYLE}</style></head><body>"
            f"<h1>clholo report: {html.escape(title)}</h1>"
            f"<p class=\"note\">from {html.escape(str(folder))}</p>"
            + "".join(sections) + script + "</body></html>")
    from clholo.io.output import listed_entries, output_file, unchanged_folder

    owner = _owning_output_folder(out)
    with (unchanged_folder(owner, owner_state, command="clholo report") if owner is not None
          else contextlib.nullcontext()):
        listed = listed_entries(owner) if owner is not None else set()
        with output_file(out, overwrite=overwrite, command="report") as tmp:
            tmp.write_text(page, encoding="utf-8")
        if owner is not None:  # a clholo folder keeps listing everything in it
            try:
                update_manifest(owner, add=[out.name, _record_name(out)])
            except BaseException:
                # not listed, the page would stay in the folder unknown to its manifest (and
                # refuse every later --overwrite of it): a full disk, or Ctrl-C just then
                for name in (out.name, _record_name(out)):
                    if name not in listed:
                        with contextlib.suppress(OSError):
                            (owner / name).unlink()
                raise
    return out


def _record_name(path: Path) -> str:
    """The name of the sidecar record that :func:`clholo.io.output.output_file` writes."""
    from clholo.io.output import MANIFEST_NAME

    return f".{path.name}.{MANIFEST_NAME}"


def _owning_output_folder(path: Path) -> Optional[Path]:
    """The clholo output folder ``path`` lies directly in, if any."""
    from clholo.io.output import is_clholo_output

    parent = path.parent
    return parent if is_clholo_output(parent) else None


def _check_report_path(folder: Path, out, *, overwrite: bool) -> Path:
    """The report's destination, refused before any work when it may not be written."""
    from clholo.errors import OutputRefused
    from clholo.io.output import MANIFEST_NAME, check_output_file, is_clholo_file, \
        is_clholo_output, why_not_clholo_output

    if out is not None and not str(out).strip():  # Path('') would be the current folder
        raise OutputRefused("--out is empty: give a file name, e.g. --out report.html")
    if out is None:
        if not is_clholo_output(folder):
            raise OutputRefused(
                f"{folder} is not a folder clholo wrote ({why_not_clholo_output(folder)}), so the "
                f"report will not be written into it: give --out FILE.html outside it")
        out = folder / "report.html"
    out = Path(out)
    owner = _owning_output_folder(out.absolute())
    if owner is not None and out.exists() and not is_clholo_file(out):
        listed = _manifest_files(owner)
        if out.name in listed:
            edited = (owner / _record_name(out)).is_file()  # report wrote it, with its record
            why = ("a report clholo wrote there, changed since: clholo will not replace an "
                   "edited file" if edited else
                   f"part of the clholo output {owner} (its {MANIFEST_NAME} lists it): a "
                   f"report never replaces it")
            raise OutputRefused(
                f"--out {out} is {why}; choose another --out, e.g. "
                f"{_free_report_path(Path(out).parent)}")
    check_output_file(out, overwrite=overwrite)
    return out


def _free_report_path(folder: Path) -> Path:
    """``folder/report.html``, or the first ``report-N.html`` there that does not exist."""
    out = folder / "report.html"
    n = 2
    while out.exists() or out.is_symlink():
        out = folder / f"report-{n}.html"
        n += 1
    return out


def _manifest_files(folder: Path) -> set:
    from clholo.io.output import MANIFEST_NAME

    try:
        data = json.loads((folder / MANIFEST_NAME).read_text())
        return set(data.get("files", []))
    except (OSError, ValueError, AttributeError):
        return set()
