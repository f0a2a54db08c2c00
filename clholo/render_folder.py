"""The output folder of a render (``clholo demo``, ``render``, ``batch`` items), whatever the
method: ``focal_stack.png`` (the all-in-focus ray-optics reference and three focal slices, one
exposure), ``focal_stack.npz``, ``hologram.<npz|exr>`` and ``summary.json``, written through
:mod:`clholo.io.output` (temporary name, manifest, never replacing what clholo did not write).
"""

from __future__ import annotations

import json
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Optional, Sequence

import numpy as np

from clholo.progress import StepLog
from clholo.scene import MPI, Optics

# Values per band of contact_sheet_srgb8 (4 MiB of float32)
_SHEET_BAND_ELEMENTS = 1 << 20
# libpng's PNG_FILTER_SUB: each byte less the one a pixel to its left
_PNG_FILTER_SUB = 0x10

__all__ = ["contact_sheet", "contact_sheet_srgb8", "sheet_exposure", "render_to_folder",
           "render_and_save", "write_render_folder"]


def _sheet_layout(panels: Sequence[np.ndarray], gap: int):
    """A contact sheet's ``(H, W, C)`` and each panel's first column."""
    H = max(p.shape[0] for p in panels)
    C = panels[0].shape[2]
    starts = np.cumsum([0] + [p.shape[1] + gap for p in panels])
    return (H, int(starts[-1]) - gap, C), [int(x) for x in starts[:-1]]


def contact_sheet(panels: Sequence[np.ndarray], *, gap: int = 8) -> np.ndarray:
    """Panels ``(H, W, C)`` in [0, 1] side by side on a white background."""
    shape, starts = _sheet_layout(panels, gap)
    sheet = np.ones(shape, np.float32)
    for p, x in zip(panels, starts):
        sheet[:p.shape[0], x:x + p.shape[1]] = p
    return sheet


def contact_sheet_srgb8(panels: Sequence[np.ndarray], exposure: float, *,
                        gap: int = 8) -> np.ndarray:
    """The 8-bit sRGB codes of a contact sheet of linear panels under one exposure:
    ``linear_to_srgb8(contact_sheet([np.clip(p / exposure, 0, 1) for p in panels]))``, the
    same codes, made a band of rows of one panel at a time (a 12-megapixel render's sheet
    is 146 million values: no float copy of it, nor of its panels, is made whole).

    Parameters
    ----------
    panels : sequence of ndarray, each (H_i, W_i, C)
        Linear intensities.
    exposure : float
        The intensity shown as white (:func:`sheet_exposure`).
    gap : int
        White columns between panels.

    Returns
    -------
    ndarray, uint8, shape (max H_i, sum W_i + gap (n - 1), C)
    """
    from clholo.io import linear_to_srgb8

    shape, starts = _sheet_layout(panels, gap)
    sheet = np.full(shape, 255, np.uint8)  # white: linear_to_srgb8(1.0)
    rows = max(1, _SHEET_BAND_ELEMENTS // max(p.shape[1] * shape[2] for p in panels))
    for p, x in zip(panels, starts):
        for r in range(0, p.shape[0], rows):
            # float32 first, as contact_sheet's sheet holds them
            band = np.clip(p[r:r + rows] / exposure, 0, 1).astype(np.float32, copy=False)
            sheet[r:r + band.shape[0], x:x + p.shape[1]] = linear_to_srgb8(band)
    return sheet


def sheet_exposure(panels: Sequence[np.ndarray]) -> float:
    """One exposure for every panel of a contact sheet: the 99.5th percentile of all of them.

    Hologram focal slices and the ray-optics reference are on the same scale (linear intensity:
    an opaque layer of colour ``c`` refocuses to mean intensity ``c``), so one exposure shows
    their real brightness relative to each other; a panel scaled to its own percentile would hide
    a hologram that is several times too bright or too dark.
    """
    panels = [np.asarray(p) for p in panels]
    # one copy of every value, each panel read in its memory's order (a transposed focal
    # slice too: the order of the values does not change a percentile); it is this
    # function's own, so the percentile partitions it in place
    values = np.empty(sum(p.size for p in panels), np.float32)
    start = 0
    for p in panels:
        values[start:start + p.size] = p.ravel(order="K")
        start += p.size
    exposure = float(np.percentile(values, 99.5, overwrite_input=True))
    return exposure if exposure > 0 else 1.0


def render_to_folder(scene, method, optics: Optics, out_dir, *, frames: int, seed: int,
                     pad="auto", log: Optional[StepLog] = None, hologram_format: str = "npz",
                     overwrite: bool = False, command: str = "render",
                     holograms: Optional[np.ndarray] = None,
                     summary_extra: Optional[dict] = None, queue=None,
                     option: str = "out_dir") -> dict:
    """Render ``scene`` (:class:`clholo.scenes.Scene`) by ``method``
    (:class:`clholo.methods.Method`), take its focal stack at the nearest, middle and farthest
    depth, and write the render folder ``out_dir`` (see the module docstring).

    Parameters
    ----------
    frames, seed, pad
        The hologram's T, phase-stream key and padding.
    holograms : numpy.ndarray, optional
        complex64 ``[frames, C, H, W]`` rendered before with the same scene, method, optics,
        seed and pad (``clholo batch`` assembles them from frame-range parts): written instead
        of rendering again.
    summary_extra : dict, optional
        More fields for ``summary.json``.
    option : str
        How the caller names ``out_dir`` (and, from it, ``overwrite``) in a refusal: ``"--out"``
        from the command line, so a late refusal says ``--out``/``--overwrite`` there.

    Returns
    -------
    dict
        The summary written to ``summary.json``.
    """
    from clholo.host import runtime
    from clholo.io.output import check_output_folder, destination_state

    # before minutes of work, not after; and what overwrite may replace is what is there now
    # (an output another run writes there meanwhile is refused at the rename, not replaced)
    check_output_folder(out_dir, overwrite=overwrite, option=option)
    expect = (destination_state(out_dir),)  # write_render_folder's expect
    log = StepLog(mode="off") if log is None else log
    queue = runtime.get_queue() if queue is None else queue
    dev = queue.device
    log.step(f"device: {dev.platform.name.strip()} / {dev.name.strip()}", 0.0)
    t = time.perf_counter()
    # kernel builds are counted apart from planning and rendering (issue 22: NVIDIA compiles
    # every program on first use, 5.6 s of the twain render's 5.9 s on an H100)
    builds = runtime.BuildCounter(dev)  # planning's builds and the warm-up's, together
    with builds:
        with runtime.BuildCounter() as plan_builds:
            renderer = method.renderer(scene, optics, seed=seed, pad=pad, queue=queue)
        depths = method.depths(scene)
        reference_view = method.reference_view(scene)
        H, W, C = reference_view.shape[0], reference_view.shape[1], optics.channels
        L = len(depths)
        what = "splat primitives" if method.needs == "primitives" else "layers"
        log.step(f"planned {method.name}: {L} {what} {H}x{W}x{C} at {depths[0] * 1e3:.2f}.."
                 f"{depths[-1] * 1e3:.2f} mm, padded grid {renderer.padded[0]}x"
                 f"{renderer.padded[1]}, {renderer.frames_per_batch} frame(s) per launch",
                 time.perf_counter() - t - plan_builds.seconds)
        if holograms is None:
            _check_host_memory(frames * C * H * W * 8, frames=frames)
            # warm-up: every program the render needs is built here, before its timer
            prepare = getattr(renderer, "prepare", None)
            if prepare is not None:
                prepare(frames)
            del prepare  # a bound method: it would keep the renderer past its del below
    seconds = 0.0
    timing = {}
    if holograms is not None:
        holo = np.asarray(holograms)
        if holo.shape != (frames, C, H, W) or holo.dtype != np.complex64:
            raise ValueError(f"holograms must be complex64 {(frames, C, H, W)}, got "
                             f"{holo.dtype} {holo.shape}")
        log.step(f"took {frames} hologram frame(s) x {C} colour(s) rendered before", 0.0)
    else:
        log.step(builds.describe(), builds.seconds)
        log.start(f"rendering {frames} frame(s) x {C} colour(s) x {L} {what} ({method.name})")
        t = time.perf_counter()
        holo = np.empty((frames, C, H, W), np.complex64)
        with runtime.BuildCounter() as late:  # what the warm-up missed, if anything
            for t0, batch in renderer.iter_frames(frames, progress=log.tracker(
                    "frames" if method.needs == "mpi" else "splat steps")):
                holo[t0:t0 + batch.shape[0]] = batch
        seconds = time.perf_counter() - t
        late_note = (f" (of which {late.seconds:.2f} s building {late.programs} OpenCL "
                     f"program(s) the warm-up did not)" if late.programs else "")
        log.step(f"rendered {frames} hologram frame(s) x {C} colour(s): "
                 f"{seconds / (frames * C) * 1e3:.1f} ms per colour-frame{late_note}", seconds)
        # the render's own time; the builds before it (planning and warm-up) and any during it
        timing = {"render_seconds": seconds,
                  "build": dict(builds.to_dict(), during_render_seconds=round(late.seconds, 4),
                                during_render_programs=late.programs)}

    padded = list(renderer.padded)
    # the renderer's device buffers go before the focal stack and the files: on a CPU device
    # they are host memory, the layers alone L (C + 1) H W 4 bytes (6.2 GB for 32 layers of a
    # 12-megapixel photo), and writing needs as much again
    del renderer
    summary = {
        "source": scene.source, "method": method.name, "layers": L, "height": H, "width": W,
        "channels": C, "depths_m": [float(d) for d in depths], "pitch_m": optics.pitch,
        "wavelengths_m": list(optics.wavelengths), "frames": frames, "seed": seed,
        "pad": pad, "padded_grid": padded,
        "contact_sheet": "all-in-focus ray-optics view | focused near | middle | far",
        **timing,
        **{k: v for k, v in scene.info.items() if isinstance(v, (str, int, float))},
        **(summary_extra or {}),
    }
    if L > 64:  # one entry per splat would swamp summary.json
        summary["depths_m"] = [float(depths[0]), float(depths[-1])]
        summary["depths_note"] = "nearest and farthest of the primitives' depths"
    return write_render_folder(out_dir, holo, optics, reference_view=reference_view,
                               focal_depths=[float(depths[0]), float(depths[L // 2]),
                                             float(depths[-1])],
                               summary=summary, seed=seed, pad=pad, log=log,
                               hologram_format=hologram_format, overwrite=overwrite,
                               command=command, queue=queue, option=option, expect=expect)


def render_and_save(mpi: MPI, optics: Optics, out_dir, *, frames: int, seed: int, pad="auto",
                    log: Optional[StepLog] = None, source: str = "an MPI",
                    overwrite: bool = False, hologram_format: str = "npz",
                    command: str = "render", method: str = "mpi") -> dict:
    """:func:`render_to_folder` for an :class:`clholo.MPI` in memory (the MPI method unless
    ``method="rgbd"``)."""
    from clholo.methods import get_method
    from clholo.scenes import Scene, SceneSpec

    scene = Scene(spec=SceneSpec(inputs=(source,)), kind="memory", mpi=mpi)
    return render_to_folder(scene, get_method(method), optics, out_dir, frames=frames,
                            seed=seed, pad=pad, log=log, hologram_format=hologram_format,
                            overwrite=overwrite, command=command)


def write_render_folder(out_dir: Path, holograms: np.ndarray, optics: Optics, *,
                        reference_view: np.ndarray, focal_depths: Sequence[float],
                        summary: dict, seed: int, pad, log: Optional[StepLog] = None,
                        hologram_format: str = "npz",
                        overwrite: bool = False, command: str = "render", queue=None,
                        option: str = "out_dir", expect=None) -> dict:
    """The focal stack of ``holograms`` at ``focal_depths`` and the output folder of a render:
    ``focal_stack.png`` (``reference_view`` + the focal slices, one exposure), ``focal_stack.npz``,
    ``hologram.<npz|exr>``, ``summary.json`` (``summary`` plus the focal depths and the
    exposure), built under a temporary name with clholo's manifest (``option`` names ``out_dir``
    in a refusal, as in :func:`render_to_folder`; ``expect``, a one-element tuple holding
    :func:`clholo.io.output.destination_state` of ``out_dir`` when the command began, is
    passed on to :func:`clholo.io.output.output_folder`). Shared by every method that
    writes a render folder (the MPI method, RPWS), so they cannot drift apart."""
    from clholo.hologram import focal_stack
    from clholo.io import write_hologram, write_image
    from clholo.io.output import output_folder

    log = StepLog(mode="off") if log is None else log
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
    sheet = contact_sheet_srgb8(panels, exposure)
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
    state = {} if expect is None else {"expect": expect[0]}
    with output_folder(out_dir, overwrite=overwrite, command=command, option=option,
                       **state) as tmp:
        # the PNG with the SUB filter alone: libpng's adaptive choice took 3 of the 7 s of a
        # 12-megapixel render's 48-megapixel sheet, for 3 % less; its compression
        # (OpenImageIO releases the GIL) runs beside the .npz writes
        with ThreadPoolExecutor(1, thread_name_prefix="clholo-sheet") as pool:
            sheet_written = pool.submit(write_image, tmp / "focal_stack.png", sheet,
                                        dtype="uint8",
                                        attributes={"png:filter": _PNG_FILTER_SUB})
            np.savez(tmp / "focal_stack.npz", intensity=stack, depths_m=np.array(depths),
                     wavelengths_m=np.array(optics.wavelengths))
            write_hologram(tmp / f"hologram.{hologram_format}", holograms, pitch=optics.pitch,
                           wavelengths=optics.wavelengths, seed=seed)
            (tmp / "summary.json").write_text(json.dumps(summary, indent=1))
            sheet_written.result()
    log.step(f"wrote {out_dir}/: focal_stack.png (reference | near | middle | far), "
             f"focal_stack.npz, hologram.{hologram_format}, summary.json",
             time.perf_counter() - t)
    return summary


def _check_host_memory(nbytes: int, *, frames: int) -> None:
    """Refuse, before rendering, holograms that cannot fit the memory this process can still
    have (:func:`clholo.host.memory.available_host_bytes`: what is free, within any
    ``ulimit -v``). Against the whole machine's memory, renders of up to all of it passed
    the check and failed at the write after the work (or met the out-of-memory killer)."""
    from clholo.errors import EnvironmentProblem
    from clholo.host.memory import available_host_bytes

    free = available_host_bytes()
    if nbytes > free:
        raise EnvironmentProblem(
            f"{frames} frame(s) of holograms take {nbytes / 2**30:.1f} GiB but only "
            f"{free / 2**30:.1f} GiB of memory is available (free, within any ulimit -v): use "
            f"fewer --frames (or a smaller --scale)")


def _default_queue():
    from clholo.host import runtime

    return runtime.get_queue()
