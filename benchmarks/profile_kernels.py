"""Per-kernel profile: where the device time of a render or an SGD iteration goes.

    python benchmarks/profile_kernels.py                       # 1080x1920 RGB, L=32, T=3
    python benchmarks/profile_kernels.py --shape 2160x3840 --frames 1
    python benchmarks/profile_kernels.py --sgd 2048 --pad auto
    python benchmarks/profile_kernels.py --sgd 1024 --fuse none   # SGD's steps as kernels
    python benchmarks/profile_kernels.py --markdown profile.md  # also as a Markdown file

Every kernel launch of clholo (``clholo.host.runtime.KernelRecorder``) during ``--repeats``
renders (or ``--iterations`` SGD steps) after a warm-up, grouped by kernel and FFT pass: launches
and device time per run, the bytes each FFT pass must move (one read of its source window, one
write of what it stores) and its time against a buffer copy of those bytes, with the copy
bandwidth measured in the same run (``clholo.bench.copy_bandwidth``); then the host's time to
enqueue a run against the run's wall time (issue 23 asks for <= 20 %). The same table as the
per-kernel profile of ``../shared/gpu/H100.md``, from any OpenCL device (``CLHOLO_DEVICE``).
"""

import argparse
import os
import sys
from pathlib import Path

if str(Path(__file__).resolve().parent) not in sys.path:  # loaded by path (the tests)
    sys.path.insert(0, str(Path(__file__).resolve().parent))
import _bench_args as _args  # noqa: E402

from clholo.bench import format_profile, profile_render, profile_sgd

def main(argv=None) -> None:
    """Parse the arguments (every one checked before anything is measured), profile, print."""
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--shape", default="1080x1920",
                    help="HxW of the render (default 1080x1920)")
    ap.add_argument("--colours", type=int, default=3, choices=(1, 3))
    ap.add_argument("--layers", type=_args.positive_int, default=32)
    ap.add_argument("--frames", type=_args.positive_int, default=3,
                    help="frames per render, in one batch")
    ap.add_argument("--pad", type=_args.pad, default="auto",
                    help="'auto' (default) or a factor >= 1 such as 2")
    ap.add_argument("--repeats", type=_args.positive_int, default=3, help="renders recorded")
    ap.add_argument("--sgd", type=_args.positive_int, default=None, metavar="N",
                    help="profile an SGD iteration of N x N instead of a render")
    ap.add_argument("--iterations", type=_args.positive_int, default=5,
                    help="SGD iterations recorded")
    ap.add_argument("--fuse", default=None, choices=("none", "residual", "all", "round-trips"),
                    help="what SGD runs inside its adjoint propagation (default: the device's)")
    ap.add_argument("--markdown", type=_args.output_file, default=None, metavar="PATH",
                    help="also write the table to PATH (written whole, then renamed; its folder "
                         "must exist)")
    a = ap.parse_args(argv)
    try:
        height, width = _args.shape(a.shape)
    except argparse.ArgumentTypeError:
        ap.error(f"--shape takes HxW such as 1080x1920 (both >= 1), got {a.shape!r}")
    pad = a.pad
    if a.sgd is not None:
        result = profile_sgd(size=a.sgd, pad=pad, iterations=a.iterations, fuse=a.fuse)
    else:
        result = profile_render(height=height, width=width, colours=a.colours, layers=a.layers,
                                frames=a.frames, pad=pad, repeats=a.repeats)
    lines = format_profile(result)
    print("\n".join(lines))
    if a.markdown:
        tmp = f"{a.markdown}.partial"
        with open(tmp, "w") as f:
            f.write("\n".join(lines) + "\n")
        os.replace(tmp, a.markdown)


if __name__ == "__main__":
    main()
