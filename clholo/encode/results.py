"""Complex hologram vs SGD (8-bit) vs DPAC (8-bit) on a real MPI, at equal T.

:func:`compare_encodings` renders the MPI's random-phase holograms (``T`` frames), encodes every
frame both ways, quantises through a linear 8-bit table, simulates what the SLM shows
(:func:`clholo.encode.simulate_slm`), and scores the focal stacks of all three with PSNR/SSIM
(scikit-image, linear intensity) after one least-squares scale per colour (phase-only encodings
shift the colour balance), with one data range for all depths: the 99.5th percentile of the
reference focal stack (against the complex hologram: of its focal stack). The reference at every
depth is the incoherent focal slice there (HOLOGRAPHY.md section 6), or the MPI's all-in-focus
"over" composite (``reference="over"``). Run ``python -m clholo.encode.results --help``.
"""

from __future__ import annotations

import argparse
import time
from typing import Dict, Optional, Sequence

import numpy as np

from clholo.scene import MPI, Optics

__all__ = ["compare_encodings", "score", "crop_mpi"]


def crop_mpi(mpi: MPI, size: int) -> MPI:
    """The centre ``size x size`` pixels of every layer.

    Parameters
    ----------
    mpi : MPI
        The scene.
    size : int
        Side of the square crop, pixels.
    """
    H, W = mpi.shape
    size = min(size, H, W)
    y0, x0 = (H - size) // 2, (W - size) // 2
    return MPI(mpi.color[:, y0:y0 + size, x0:x0 + size], mpi.alpha[:, y0:y0 + size, x0:x0 + size],
               mpi.depths)


def score(intensity: np.ndarray, reference: np.ndarray, *,
          data_range: Optional[float] = None) -> Dict[str, object]:
    """PSNR (dB) and SSIM of ``intensity [C, H, W]`` against ``reference [H, W, C]`` after one
    least-squares scale per colour (:func:`clholo.metrics.score`, ``fit_scale="per_channel"``;
    ``scale`` is the list of them). ``data_range``: give the scene's (default: the
    reference's max)."""
    from clholo.metrics import score as metrics_score

    return metrics_score(np.moveaxis(np.asarray(intensity), 0, -1), reference,
                         metrics=("psnr", "ssim"), layout="hwc", data_range=data_range,
                         fit_scale="per_channel")


def compare_encodings(mpi: MPI, optics: Optics, *, frames: int = 4, z_slm: float = 0.04,
                      iterations: int = 100, lr: float = 0.05, cutoff: float = 0.5,
                      depths: Optional[Sequence[float]] = None, seed: int = 0,
                      reference: str = "incoherent", queue=None) -> Dict[str, dict]:
    """Scores and times of the three holograms of ``mpi`` (module docstring).

    Returns ``{method: {"seconds", "psnr", "ssim", ...}}`` for ``complex``, ``sgd``, ``dpac``
    with PSNR and SSIM averaged over ``depths`` (default: four depths from the nearest to the
    farthest layer); ``psnr_vs_complex``/``ssim_vs_complex`` (encodings only) score the focal
    stack against the complex hologram's, and ``scale_vs_complex`` the per-colour intensity scales
    (mean over depths) that map it onto the complex hologram's: its colour shift; ``sgd`` also
    has its final mean ``loss`` and ``colour_balance`` (:meth:`SGDResult.colour_balance`).
    ``reference``: ``"incoherent"`` scores each depth against the ray-optics incoherent focal
    slice there (:func:`clholo.rayoptics.incoherent_focal_slice`, HOLOGRAPHY.md section 6);
    ``"over"`` against the all-in-focus composite at every depth.

    Parameters
    ----------
    mpi : MPI
        The scene (one wavelength of ``optics`` per channel).
    optics : Optics
        Pitch and wavelengths, metres.
    frames : int
        Time-multiplexed frames of every hologram.
    z_slm : float
        SLM -> hologram plane distance, metres.
    iterations, lr : int, float
        SGD's steps and Adam learning rate (:func:`clholo.encode.sgd_encode`).
    cutoff : float
        DPAC's filter half-width, a fraction of Nyquist (:func:`clholo.encode.dpac_encode`).
    depths : sequence of float, optional
        Focus depths scored, metres.
    seed : int
        Key of the phase stream.
    reference : {"incoherent", "over"}
        What each depth is scored against (above).
    queue : pyopencl.CommandQueue, optional
        Queue to run on (default: clholo's default device, ``CLHOLO_DEVICE``).
    """
    import clholo
    from clholo.encode.dpac import dpac_encode
    from clholo.encode.quantize import quantize
    from clholo.encode.sgd import sgd_encode
    from clholo.encode.simulate import simulate_slm
    from clholo._arrays import resolve_queue

    queue = resolve_queue(queue)
    if depths is None:
        depths = np.linspace(mpi.depths[0], mpi.depths[-1], 4)
    if reference == "incoherent":
        from clholo.rayoptics import incoherent_focal_slice

        references = [incoherent_focal_slice(mpi, optics, float(d), queue=queue) for d in depths]
    elif reference == "over":
        references = [mpi.over()] * len(depths)
    else:
        raise ValueError(f"reference must be 'incoherent' or 'over', got {reference!r}")
    t = time.perf_counter()
    holo = clholo.render_hologram(mpi, optics, frames=frames, seed=seed, queue=queue)
    stacks, out = {}, {}
    out["complex"] = {"seconds": time.perf_counter() - t}
    stacks["complex"] = clholo.focal_stack(holo, optics, depths, queue=queue)

    t = time.perf_counter()
    res = sgd_encode(holo, optics, z_slm=z_slm, iterations=iterations, lr=lr, progress=False,
                     queue=queue)
    gray = quantize(res.phase, "linear")
    out["sgd"] = {"seconds": time.perf_counter() - t, "loss": float(res.loss.mean()),
                  "colour_balance": res.colour_balance().tolist()}
    stacks["sgd"] = clholo.focal_stack(simulate_slm(gray, optics, "linear", z_slm=z_slm,
                                                    queue=queue), optics, depths, queue=queue)
    t = time.perf_counter()
    gray = quantize(dpac_encode(holo, optics, z_slm=z_slm, cutoff=cutoff, queue=queue), "linear")
    out["dpac"] = {"seconds": time.perf_counter() - t}
    stacks["dpac"] = clholo.focal_stack(
        simulate_slm(gray, optics, "linear", z_slm=z_slm, fourier_filter=cutoff, queue=queue),
        optics, depths, queue=queue)
    from clholo.experiments.layers import scene_data_range

    data_range = scene_data_range(references)
    complex_range = scene_data_range([np.moveaxis(s, 0, -1) for s in stacks["complex"]])
    for name, stack in stacks.items():
        scores = [score(stack[k], references[k], data_range=data_range)
                  for k in range(len(depths))]
        out[name]["psnr"] = float(np.mean([s["psnr"] for s in scores]))
        out[name]["ssim"] = float(np.mean([s["ssim"] for s in scores]))
        if name == "complex":
            continue
        vs = [score(stack[k], np.moveaxis(stacks["complex"][k], 0, -1), data_range=complex_range)
              for k in range(len(depths))]
        out[name]["scale_vs_complex"] = np.mean([v["scale"] for v in vs], axis=0).tolist()
        out[name]["psnr_vs_complex"] = float(np.mean([s["psnr"] for s in vs]))
        out[name]["ssim_vs_complex"] = float(np.mean([s["ssim"] for s in vs]))
    return out


def main(argv=None) -> int:
    from pathlib import Path

    import clholo

    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    p.add_argument("--mpi", default=str(Path(__file__).resolve().parents[2].parent / "shared"
                                        / "data" / "twain-mpi"), help="MPI folder")
    p.add_argument("--size", type=int, default=256, help="centre crop, pixels")
    p.add_argument("--near", type=float, default=2e-3, help="nearest plane, metres")
    p.add_argument("--far", type=float, default=6e-3, help="farthest plane, metres")
    p.add_argument("--frames", type=int, default=4, help="T for every method")
    p.add_argument("--iterations", type=int, default=100, help="SGD iterations")
    p.add_argument("--z-slm", type=float, default=0.04, help="metres")
    p.add_argument("--reference", choices=["incoherent", "over"], default="incoherent",
                   help="what each focal slice is scored against")
    args = p.parse_args(argv)
    mpi = crop_mpi(clholo.io.load_scene(args.mpi, near=args.near, far=args.far), args.size)
    optics = Optics()
    res = compare_encodings(mpi, optics, frames=args.frames, z_slm=args.z_slm,
                            iterations=args.iterations, reference=args.reference)
    print(f"{mpi.shape[0]}x{mpi.shape[1]} crop, {mpi.layers} layers {args.near}-{args.far} m, "
          f"T = {args.frames}, z_slm = {args.z_slm} m, SGD {args.iterations} iterations, "
          f"reference: {args.reference}")
    print("| hologram | PSNR (dB) | SSIM | PSNR vs complex (dB) | SSIM vs complex | time (s) |")
    print("|---|---|---|---|---|---|")
    for name, label in (("complex", "complex (render)"), ("sgd", "SGD, 8-bit"),
                        ("dpac", "DPAC, 8-bit")):
        r = res[name]
        vs = (f"{r['psnr_vs_complex']:.2f} | {r['ssim_vs_complex']:.3f}"
              if "psnr_vs_complex" in r else "- | -")
        print(f"| {label} | {r['psnr']:.2f} | {r['ssim']:.3f} | {vs} | {r['seconds']:.2f} |")
    if "loss" in res["sgd"]:
        balance = " / ".join(f"{v:.3g}" for v in res["sgd"]["colour_balance"])
        print(f"SGD final loss (mean over fields): {res['sgd']['loss']:.4f}; colour balance "
              f"(laser power, max 1): {balance}")
    for name in ("sgd", "dpac"):
        print(f"{name} per-colour intensity scale vs complex: "
              f"{' / '.join(f'{v:.3g}' for v in res[name]['scale_vs_complex'])}")
    print("Scores: one least-squares scale per colour; data range the 99.5th percentile of the "
          "reference focal stack (of the complex hologram's for 'vs complex').")
    return 0


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
