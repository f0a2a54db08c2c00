"""``clholo batch`` scaling: the same 12-item dataset on 1 and on 2 local workers, side by side.

Items (from ``shared/data`` and scikit-image): 4 crops of the twain MPI (32 layers), 4 sizes of
the motorcycle RGB-D scene (8 layers), 4 renders of the ``train-1000.ply`` splats (512 wide); one
item of each kind split by frame range. The two worker counts alternate round by round so that a
shared machine's drift hits both alike. Each timed run is a whole ``render_dataset`` into a fresh
folder, the local cluster's start included (what a user waits for); items per minute and the
2-worker / 1-worker ratio are printed.

With ``--one-core`` (PoCL only) the same pair runs again with every worker's PoCL device cut to
one compute unit (``POCL_MAX_PTHREAD_COUNT=1``): two workers that do not share cores, the
situation of two GPUs.

    python benchmarks/bench_batch.py [--rounds 2] [--frames 4] [--data ../shared/data]
                                     [--one-core]
"""

from __future__ import annotations

import argparse
import json
import statistics
import tempfile
import sys
import time
from pathlib import Path

if str(Path(__file__).resolve().parent) not in sys.path:  # loaded by path (the tests)
    sys.path.insert(0, str(Path(__file__).resolve().parent))
import _bench_args as _args  # noqa: E402


def build_manifest(folder: Path, data: Path, frames: int) -> Path:
    import clholo

    twain = clholo.io.read_mpi(data / "twain-mpi")
    rows = []
    for k, (y, x) in enumerate([(300, 400), (500, 200), (100, 700), (600, 900)]):
        name = f"twain-{k}"
        clholo.io.write_mpi(folder / name, clholo.MPI(
            twain.color[:, y:y + 64, x:x + 64], twain.alpha[:, y:y + 64, x:x + 64], twain.depths))
        rows.append({"id": name, "input": name, "near": 0.002, "far": 0.005, "frames": frames,
                     "seed": k, **({"split_frames": frames // 2} if k == 0 else {})})
    for k, scale in enumerate([0.1, 0.12, 0.14, 0.16]):
        rows.append({"id": f"motorcycle-{k}", "input": "skimage:motorcycle", "layers": 8,
                     "scale": scale, "frames": frames, "seed": 10 + k,
                     **({"split_frames": frames // 2} if k == 0 else {})})
    for k in range(4):
        rows.append({"id": f"splats-{k}", "input": str(data / "gaussians" / "train-1000.ply"),
                     "layers": 2 + k, "near": 0.002, "far": 0.004, "frames": max(1, frames // 2),
                     "seed": 20 + k, **({"split_frames": 1} if k == 0 and frames > 2 else {})})
    path = folder / "manifest.jsonl"
    path.write_text("".join(json.dumps(r) + "\n" for r in rows))
    return path


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--rounds", type=_args.positive_int, default=2)
    ap.add_argument("--frames", type=_args.positive_int, default=4)
    ap.add_argument("--data", default=str(Path(__file__).resolve().parents[2] / "shared" / "data"))
    ap.add_argument("--one-core", action="store_true",
                    help="also time workers whose PoCL device has one compute unit")
    args = ap.parse_args()

    import io
    import os

    from clholo.batch import render_dataset

    configs = [(1, ""), (2, "")] + ([(1, "1"), (2, "1")] if args.one_core else [])

    def run(manifest, out, workers, cus):
        # the local cluster's worker processes inherit this process's environment
        os.environ.pop("POCL_MAX_PTHREAD_COUNT", None)
        if cus:
            os.environ["POCL_MAX_PTHREAD_COUNT"] = cus
        return render_dataset(manifest, out, workers=workers, stream=io.StringIO())

    with tempfile.TemporaryDirectory(prefix="clholo-bench-batch-") as tmp:
        tmp = Path(tmp)
        manifest = build_manifest(tmp, Path(args.data), args.frames)
        n_items = sum(1 for _ in manifest.open())
        # warm the kernel caches of the OpenCL compiler (not timed)
        for cus in sorted({c for _, c in configs}):
            run(manifest, tmp / f"warm{cus}", 1, cus)
        seconds = {c: [] for c in configs}
        work = {c: [] for c in configs}
        for r in range(args.rounds):
            for config in (configs if r % 2 == 0 else configs[::-1]):
                t = time.perf_counter()
                rows = run(manifest, tmp / f"run-{r}-{config[0]}-{config[1]}", *config)
                seconds[config].append(time.perf_counter() - t)
                assert all(row["status"] == "rendered" for row in rows), rows
                work[config].append(sum(row["seconds"] for row in rows))
        print(f"{n_items} items, {args.frames} frames, {args.rounds} round(s); median of rounds")
        for config in configs:
            s = statistics.median(seconds[config])
            what = f"{config[0]} worker(s)" + (", 1 compute unit each" if config[1] else "")
            print(f"  {what:32s} {s:6.1f} s wall, {n_items / s * 60:6.1f} items/min "
                  f"(item seconds summed {statistics.median(work[config]):6.1f} s)")
        for cus in sorted({c for _, c in configs}):
            ratio = statistics.median(seconds[(1, cus)]) / statistics.median(seconds[(2, cus)])
            print(f"  ratio 2 / 1 workers, items per minute{' (1 compute unit each)' if cus else ''}"
                  f": {ratio:.2f}")

if __name__ == "__main__":
    main()
