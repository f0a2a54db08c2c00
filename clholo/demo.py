"""The work behind ``clholo demo`` and ``clholo render``: scene -> MPI -> hologram -> focal stack
-> files, with a line per step saying what it did, where and how long it took.
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path
from typing import Optional, Sequence, TextIO

import numpy as np

from clholo.scene import MPI, Optics

DEMO_NEAR = 2e-3   # metres behind the hologram plane: "a few millimetres"
DEMO_FAR = 6e-3
MIN_SCENE_PIXELS = 16  # below this a focal stack shows nothing a person could judge


class StepLog:
    """Prints ``[ 1.23 s] what ...`` lines, and progress while a long step runs.

    On a terminal the progress is one bar redrawn in place; elsewhere (logs, CI, notebooks'
    captured output) it is a plain line with the count and the elapsed time at most every
    ``interval`` seconds, so that a long render never looks hung and logs hold no carriage
    returns.
    """

    def __init__(self, stream: Optional[TextIO] = None, *, interval: float = 2.0):
        self.stream = stream if stream is not None else sys.stdout
        self.t0 = time.perf_counter()
        self.interval = float(interval)
        self._last_line = -float("inf")

    def _tty(self) -> bool:
        return bool(getattr(self.stream, "isatty", lambda: False)())

    def start(self, message: str) -> None:
        """Say what a long step is about to do (its ``step`` line follows when it is done)."""
        print(f"[{'':9}] {message} ...", file=self.stream, flush=True)
        self._last_line = time.perf_counter()

    def step(self, message: str, seconds: float) -> None:
        print(f"[{seconds:7.2f} s] {message}", file=self.stream, flush=True)

    def progress(self, label: str, done: int, total: int, t_start: float) -> None:
        elapsed = time.perf_counter() - t_start
        if self._tty():
            width = 30
            filled = int(width * done / max(total, 1))
            print(f"\r  {label} [{'#' * filled}{'.' * (width - filled)}] {done}/{total} "
                  f"{elapsed:6.1f} s", end="" if done < total else "\n", file=self.stream,
                  flush=True)
            return
        now = time.perf_counter()
        if done < total and now - self._last_line < self.interval:
            return
        rate = f", {elapsed / done:.2f} s each" if done else ""
        print(f"  {label}: {done}/{total} after {elapsed:.1f} s{rate}", file=self.stream,
              flush=True)
        self._last_line = now


def motorcycle_mpi(*, layers: int = 8, near: float = DEMO_NEAR, far: float = DEMO_FAR,
                   scale: float = 1.0) -> MPI:
    """The Middlebury "motorcycle" RGB-D pair of scikit-image as an ``layers``-plane MPI.

    Invalid disparities are filled from their nearest valid neighbours (``rgbd_to_mpi``'s
    documented policy); disparity becomes depth, binned uniformly (hard assignment) over
    ``[near, far]`` metres behind the hologram plane.
    """
    from skimage import data
    from skimage.transform import rescale

    from clholo.io import rgbd_to_mpi, srgb_to_linear

    from clholo import validate

    scale = validate.real_scalar("scale", scale)
    left, _right, disparity = data.stereo_motorcycle()
    smallest = min(left.shape[:2])
    if not scale > 0 or round(smallest * scale) < MIN_SCENE_PIXELS:
        raise ValueError(
            f"scale={scale:g} shrinks the {left.shape[1]}x{left.shape[0]} scene to "
            f"{max(0, round(left.shape[1] * scale))}x{max(0, round(left.shape[0] * scale))} pixels; "
            f"use a scale of at least {MIN_SCENE_PIXELS / smallest:.3g}")
    image = srgb_to_linear(left.astype(np.float32) / 255.0)
    if scale != 1.0:
        image = np.clip(rescale(image, scale, channel_axis=-1, anti_aliasing=True), 0, 1)
        # nearest neighbour keeps invalid (inf) disparities from smearing into valid ones
        disparity = rescale(disparity, scale, order=0, anti_aliasing=False)
    return rgbd_to_mpi(image.astype(np.float32), disparity, layers=layers, near=near, far=far,
                       mode="hard", depth_kind="disparity", invalid="fill", srgb=False)


def contact_sheet(panels: Sequence[np.ndarray], *, gap: int = 8) -> np.ndarray:
    """Panels ``(H, W, C)`` in [0, 1] side by side on a white background."""
    H = max(p.shape[0] for p in panels)
    C = panels[0].shape[2]
    W = sum(p.shape[1] for p in panels) + gap * (len(panels) - 1)
    sheet = np.ones((H, W, C), np.float32)
    x = 0
    for p in panels:
        sheet[:p.shape[0], x:x + p.shape[1]] = p
        x += p.shape[1] + gap
    return sheet


def sheet_exposure(panels: Sequence[np.ndarray]) -> float:
    """One exposure for every panel of a contact sheet: the 99.5th percentile of all of them.

    Hologram focal slices and the ray-optics reference are on the same scale (linear intensity:
    an opaque layer of colour ``c`` refocuses to mean intensity ``c``), so one exposure shows
    their real brightness relative to each other; a panel scaled to its own percentile would hide
    a hologram that is several times too bright or too dark.
    """
    values = np.concatenate([np.asarray(p, np.float32).ravel() for p in panels])
    exposure = float(np.percentile(values, 99.5))
    return exposure if exposure > 0 else 1.0


def render_and_save(mpi: MPI, optics: Optics, out_dir: Path, *, frames: int, seed: int,
                    pad, log: StepLog, source: str, overwrite: bool = False,
                    hologram_format: str = "npz", command: str = "render",
                    holograms: Optional[np.ndarray] = None,
                    summary_extra: Optional[dict] = None) -> dict:
    """Render ``mpi``, its focal stack at the near, middle and far layer, and write
    ``focal_stack.png`` (ray-optics reference + 3 focal slices), ``focal_stack.npz``,
    ``hologram.<npz|exr>`` and ``summary.json`` into ``out_dir`` (built under a temporary name,
    renamed when complete, with clholo's manifest; an existing ``out_dir`` is replaced only with
    ``overwrite=True`` and only when clholo wrote it: :mod:`clholo.io.output`).

    ``holograms`` (complex64 ``[frames, C, H, W]``), when given, are frames already rendered
    with the same MPI, optics, seed and pad (``clholo batch`` assembles them from frame-range
    parts): they are written instead of rendering again. ``summary_extra`` adds fields to
    ``summary.json``."""
    from clholo.hologram import HologramRenderer
    from clholo.host import runtime
    from clholo.io.output import check_output_folder

    check_output_folder(out_dir, overwrite=overwrite)  # before minutes of work, not after
    queue = runtime.get_queue()
    dev = queue.device
    log.step(f"device: {dev.platform.name.strip()} / {dev.name.strip()}", 0.0)
    L, (H, W), C = mpi.layers, mpi.shape, mpi.channels
    t = time.perf_counter()
    renderer = HologramRenderer(mpi, optics, seed=seed, pad=pad, queue=queue)
    log.step(f"planned {L} layers {H}x{W}x{C} at {mpi.depths[0] * 1e3:.2f}..{mpi.depths[-1] * 1e3:.2f} mm, "
             f"padded grid {renderer.padded[0]}x{renderer.padded[1]}, "
             f"{renderer.frames_per_batch} frame(s) per launch", time.perf_counter() - t)

    t = time.perf_counter()
    if holograms is not None:
        holo = np.asarray(holograms)
        if holo.shape != (frames, C, H, W) or holo.dtype != np.complex64:
            raise ValueError(f"holograms must be complex64 {(frames, C, H, W)}, got "
                             f"{holo.dtype} {holo.shape}")
        log.step(f"took {frames} hologram frame(s) x {C} colour(s) rendered before", 0.0)
    else:
        log.start(f"rendering {frames} frame(s) x {C} colour(s) x {L} layers")
        t = time.perf_counter()
        holo = np.empty((frames, C, H, W), np.complex64)
        done = 0
        for t0, batch in renderer.iter_frames(frames):
            holo[t0:t0 + batch.shape[0]] = batch
            done += batch.shape[0]
            log.progress("frames", done, frames, t)
        seconds = time.perf_counter() - t
        log.step(f"rendered {frames} hologram frame(s) x {C} colour(s): "
                 f"{seconds / (frames * C) * 1e3:.1f} ms per colour-frame", seconds)

    summary = {
        "source": source, "layers": L, "height": H, "width": W, "channels": C,
        "depths_m": mpi.depths.tolist(), "pitch_m": optics.pitch,
        "wavelengths_m": list(optics.wavelengths), "frames": frames, "seed": seed,
        "padded_grid": list(renderer.padded),
        "contact_sheet": "all-in-focus ray-optics MPI | focused near | middle | far",
        **(summary_extra or {}),
    }
    return write_render_folder(out_dir, holo, optics, reference_view=mpi.over(),
                        focal_depths=[float(mpi.depths[0]), float(mpi.depths[L // 2]),
                                      float(mpi.depths[-1])],
                        summary=summary, seed=seed, pad=pad, log=log,
                        hologram_format=hologram_format, overwrite=overwrite, command=command,
                        queue=queue)


def write_render_folder(out_dir: Path, holograms: np.ndarray, optics: Optics, *,
                        reference_view: np.ndarray, focal_depths: Sequence[float],
                        summary: dict, seed: int, pad, log: StepLog, hologram_format: str = "npz",
                        overwrite: bool = False, command: str = "render", queue=None) -> dict:
    """The focal stack of ``holograms`` at ``focal_depths`` and the output folder of a render:
    ``focal_stack.png`` (``reference_view`` + the focal slices, one exposure), ``focal_stack.npz``,
    ``hologram.<npz|exr>``, ``summary.json`` (``summary`` plus the focal depths and the
    exposure), built under a temporary name with clholo's manifest. Shared by every method that
    writes a render folder (the MPI method, RPWS), so they cannot drift apart."""
    from clholo.hologram import focal_stack
    from clholo.io import linear_to_srgb, write_hologram, write_image
    from clholo.io.output import output_folder

    frames, C = holograms.shape[:2]
    depths = [float(d) for d in focal_depths]
    log.start(f"focal stack: {len(depths)} depths x {frames} frame(s) x {C} colour(s)")
    t = time.perf_counter()
    stack = focal_stack(holograms, optics, depths, pad=pad, queue=queue)
    log.step(f"focal stack at {', '.join(f'{d * 1e3:.2f}' for d in depths)} mm",
             time.perf_counter() - t)

    t = time.perf_counter()
    panels = [reference_view] + [s.transpose(1, 2, 0) for s in stack]
    exposure = sheet_exposure(panels)
    sheet = linear_to_srgb(contact_sheet([np.clip(p / exposure, 0, 1) for p in panels]))
    dev = (queue if queue is not None else _default_queue()).device
    summary = dict(summary)
    summary.setdefault("device", f"{dev.platform.name.strip()} / {dev.name.strip()}")
    summary.update({
        "focal_depths_m": depths,
        "contact_sheet_exposure": exposure,
        "contact_sheet_caption": (
            f"every panel is linear intensity divided by one exposure, {exposure:.4g} (the "
            f"99.5th percentile of all panels together), clipped to [0, 1], then sRGB-encoded"),
    })
    with output_folder(out_dir, overwrite=overwrite, command=command) as tmp:
        write_image(tmp / "focal_stack.png", sheet, dtype="uint8")
        np.savez(tmp / "focal_stack.npz", intensity=stack, depths_m=np.array(depths),
                 wavelengths_m=np.array(optics.wavelengths))
        write_hologram(tmp / f"hologram.{hologram_format}", holograms, pitch=optics.pitch,
                       wavelengths=optics.wavelengths, seed=seed)
        (tmp / "summary.json").write_text(json.dumps(summary, indent=1))
    log.step(f"wrote {out_dir}/: focal_stack.png (reference | near | middle | far), "
             f"focal_stack.npz, hologram.{hologram_format}, summary.json",
             time.perf_counter() - t)
    return summary


def _default_queue():
    from clholo.host import runtime

    return runtime.get_queue()
