"""One SGD phase-retrieval iteration (forward, gradient, Adam step): clholo vs PyTorch autograd.

    python benchmarks/bench_sgd.py [--size 1024] [--iterations 20] [--rounds 3] [--z 0.04]
                                   [--pad auto|2] [--sums LOCALxGROUPS] [--breakdown]

Both run the same optimisation of one green (520 nm) field, complex64, on the same padded grid
(clholo's ``auto`` grid, 2^a 3^b 5^c: 1200^2 for 1024^2 at 4 cm; ``--pad 2``: 2048^2) with the
same band-limited transfer functions; PyTorch on CUDA when clholo's OpenCL device is a GPU and
``torch.cuda.is_available()``, else on the CPU (``clholo.bench.torch_peer``), and the output
names the device each ran on:

* clholo: :class:`clholo.host.phase_retrieval.PhaseRetrieval` (analytic adjoint gradient,
  closed-form scale, Adam in a kernel); the queue is drained after each block of iterations.
* PyTorch: ``x = exp(1j P)``, ``y = crop(ifft2(fft2(pad(x)) * H))``, the closed-form scale
  (detached: the envelope theorem gives the same gradient), the same normalised loss,
  ``loss.backward()``, ``torch.optim.Adam``; the transfer function and the target are on its
  device before timing, and ``torch.cuda.synchronize()`` closes each block on CUDA.

Two more clholo runners share the rounds: the four-pass propagations (two 2D transforms each,
before issue 23) and another form of the iteration: the residual and Adam step as kernels of
their own (``PhaseRetrieval(fuse="none")``: beside ``"round-trips"``, every device's default,
the iteration in two column and two row round trips, on a CPU), or ``fuse="all"`` (both fused
into the adjoint propagation's passes, GPUs' default before it: beside ``"round-trips"`` on a
GPU, and beside ``"none"``); the ratio against the timed form is printed. ``--fuse`` times another form than the device's
default.

``--sums 64x64`` adds another runner: clholo with the loss sums split another way (work-items
per group x work-groups per field; ``64x64`` is the split, not the kernels, every device had
before issue 23), timed in the same rounds, so the device's own split
(:func:`clholo.host.phase_retrieval.sum_plan`, printed) is compared with it side by side.

Blocks of ``--iterations`` alternate between the runners ``--rounds`` times (so all see the same
load), each round starting one runner later than the last (so that none always follows
PyTorch's block); the median time per iteration and the ratios are printed. A block's first
iterations run slower after another runner's block (on PoCL, 2-core Zen 5: clholo's first
iteration after PyTorch's block took 11-15 ms against 7.5, and the next ones about 10 %
more), so a block is 20 iterations (150 ms or more): with 5 that start weighed a fifth. Needs the ``bench`` extra
(torch; CPU wheels from https://download.pytorch.org/whl/cpu).
"""

import argparse
import statistics
import sys
import time
from pathlib import Path

import numpy as np

if str(Path(__file__).resolve().parent) not in sys.path:  # loaded by path (the tests)
    sys.path.insert(0, str(Path(__file__).resolve().parent))
import _bench_args as _args  # noqa: E402


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--size", type=_args.positive_int, default=1024)
    ap.add_argument("--iterations", type=_args.positive_int, default=20,
                    help="iterations per timed block")
    ap.add_argument("--rounds", type=_args.positive_int, default=3,
                    help="alternating blocks per method")
    ap.add_argument("--z", type=_args.positive_float, default=0.04,
                    help="SLM -> hologram plane, metres")
    ap.add_argument("--lr", type=_args.positive_float, default=0.05)
    ap.add_argument("--pad", type=_args.pad, default="auto",
                    help="'auto' (default) or a factor >= 1 such as 2")
    ap.add_argument("--sums", default=None, metavar="LOCALxGROUPS",
                    help="also time clholo with this split of the loss sums, e.g. 64x64")
    ap.add_argument("--fuse", default=None,
                    choices=["none", "residual", "all", "round-trips"],
                    help="the form of the iteration to time (default: the device's)")
    ap.add_argument("--breakdown", action="store_true",
                    help="also time the pieces of one clholo iteration, interleaved")
    a = ap.parse_args(argv)

    import pyopencl as cl
    import pyopencl.array as cla

    from clholo import reference as ref
    from clholo.bench import torch_peer
    from clholo.host import runtime
    from clholo.host.phase_retrieval import PhaseRetrieval, SumPlan
    from clholo.propagation import build_transfer_function, device_padded_shape

    N, lam, pitch = a.size, 520e-9, 8e-6
    queue = runtime.get_queue()
    peer = torch_peer(queue.device)
    if peer is None:
        raise SystemExit("bench_sgd.py needs torch: pip install clholo[bench] (or torch==2.13.0)")
    torch, dev = peer.torch, peer.device
    pad = a.pad
    padded = device_padded_shape((N, N), a.z, wavelength=lam, pitch=pitch, pad=pad)
    rng = np.random.default_rng(0)
    target = (rng.standard_normal((1, N, N)) + 1j * rng.standard_normal((1, N, N))
              ).astype(np.complex64)
    phase0 = rng.uniform(0, 2 * np.pi, (1, N, N)).astype(np.float32)

    try:
        eng = PhaseRetrieval(cla.to_device(queue, target), wavelengths=[lam], pitch=pitch,
                             z=a.z, padded=padded, lr=a.lr, queue=queue, fuse=a.fuse)
    except ValueError as exc:
        raise SystemExit(f"--fuse {a.fuse}: {exc}")
    eng.set_phase(cla.to_device(queue, phase0))
    other = None
    if a.sums:
        try:
            local, groups = (int(v) for v in a.sums.lower().split("x"))
            plan = SumPlan(local, groups)
        except ValueError as exc:
            raise SystemExit(f"--sums takes LOCALxGROUPS such as 64x64 (a power of two of "
                             f"work-items, at least one group), got {a.sums!r}: {exc}")
        other = PhaseRetrieval(cla.to_device(queue, target), wavelengths=[lam], pitch=pitch,
                               z=a.z, padded=padded, lr=a.lr, queue=queue, sums=plan)
        other.set_phase(cla.to_device(queue, phase0))
    # the same optimisation with the four-pass propagations (two 2D transforms each, before
    # issue 23), timed in the same rounds
    eng4 = PhaseRetrieval(cla.to_device(queue, target), wavelengths=[lam], pitch=pitch, z=a.z,
                          padded=padded, lr=a.lr, queue=queue, three_pass=False)
    eng4.set_phase(cla.to_device(queue, phase0))
    # and with the residual and the Adam step as kernels of their own (fuse "none"), or, where
    # the timed form is that or the four round trips, both fused into the adjoint's passes
    # the other form: on a CPU "none" beside "round-trips" (its default since the eleventh
    # session), on a GPU "all" (its default before "round-trips")
    cpu = bool(queue.device.type & cl.device_type.CPU)
    alt_fuse = ("none" if cpu else "all") if eng.fuse == "round-trips" else \
        "all" if eng.fuse == "none" else "none"
    alt = PhaseRetrieval(cla.to_device(queue, target), wavelengths=[lam], pitch=pitch, z=a.z,
                         padded=padded, lr=a.lr, queue=queue, fuse=alt_fuse)
    alt.set_phase(cla.to_device(queue, phase0))
    alt_name = f"clholo, fuse {alt_fuse}"

    # the same transfer function for torch (clholo's device build; equal to the reference's)
    H = build_transfer_function(queue, padded, a.z, wavelengths=[lam], pitch=pitch).get()[0]
    Ht = torch.from_numpy(H).to(dev)
    tt = torch.from_numpy(target[0]).to(dev)
    tnorm = float(np.sum(np.abs(target) ** 2))
    P = torch.tensor(phase0[0], device=dev, requires_grad=True)
    opt = torch.optim.Adam([P], lr=a.lr)
    Hp, Wp = padded

    def torch_step():
        opt.zero_grad(set_to_none=True)
        x = torch.polar(torch.ones_like(P), P)
        big = torch.nn.functional.pad(x, (0, Wp - N, 0, Hp - N))
        y = torch.fft.ifft2(torch.fft.fft2(big) * Ht)[:N, :N]
        with torch.no_grad():
            s = torch.sum(torch.conj(y) * tt) / torch.sum(torch.abs(y) ** 2)
        loss = torch.sum(torch.abs(s * y - tt) ** 2) / tnorm
        loss.backward()
        opt.step()
        return loss

    def clholo_block(engine=eng):
        queue.finish()
        t = time.perf_counter()
        for _ in range(a.iterations):
            engine.step()
        queue.finish()
        return (time.perf_counter() - t) / a.iterations

    def torch_block():
        peer.synchronize()
        t = time.perf_counter()
        for _ in range(a.iterations):
            torch_step()
        peer.synchronize()
        return (time.perf_counter() - t) / a.iterations

    # warm-up (kernel builds, FFT plans, torch allocator) and a check that both optimise the
    # same thing: the first losses agree
    eng.step()
    eng4.step()
    alt.step()
    queue.finish()
    first_cl = float(eng.loss.get()[0])
    if other is not None:
        other.step()
        queue.finish()
        first_other = float(other.loss.get()[0])
    for e in (eng4, alt):
        assert abs(first_cl - float(e.loss.get()[0])) <= 1e-4 * max(1.0, abs(first_cl))
    first_torch = float(torch_step().detach())
    A, AH = ref.asm_operator((N, N), a.z, wavelengths=[lam], pitch=pitch, padded=padded) \
        if N <= 256 else (None, None)
    where = {"clholo": f"{queue.device.platform.name.strip()} / {queue.device.name.strip()}",
             "torch": f"{peer.label}, {peer.where}"}
    print(f"field {N}x{N}, padded {Hp}x{Wp}, z = {a.z} m, 520 nm; clholo on {where['clholo']}; "
          f"torch on {where['torch']}")
    print(f"loss sums: {eng.sums.local} work-items x {eng.sums.groups} groups per field "
          f"(the device's plan); fuse {eng.fuse!r} ("
          + ("the device's default" if a.fuse is None else "--fuse") + ")")
    print(f"first loss: clholo {first_cl:.6f}, torch {first_torch:.6f}")
    if other is not None:
        where["sums"] = where["clholo"]
        print(f"first loss with --sums {other.sums.local}x{other.sums.groups}: "
              f"{first_other:.6f}")
    if A is not None:
        print(f"reference loss {float(ref.sgd_loss(phase0, target, A)[0]):.6f}")
    times = {"clholo": [], "clholo, four-pass propagations": [], alt_name: [], "torch": []}
    if other is not None:
        times["sums"] = []
    where["clholo, four-pass propagations"] = where[alt_name] = where["clholo"]
    runners = [("clholo", clholo_block), ("clholo, four-pass propagations",
                                          lambda: clholo_block(eng4)),
               (alt_name, lambda: clholo_block(alt)), ("torch", torch_block)]
    if other is not None:
        runners.append(("sums", lambda: clholo_block(other)))
    for r in range(a.rounds):
        # each round starts one runner later: the block right after PyTorch's ran 15-20 %
        # slower than the same form elsewhere in the round (PoCL, 2-core Zen 5, 2026-11-27)
        for name, block in runners[r % len(runners):] + runners[:r % len(runners)]:
            times[name].append(block())
    med = {k: statistics.median(v) for k, v in times.items()}
    for k, v in times.items():
        print(f"{k:31s} ms/iteration: median {med[k] * 1e3:.2f}  (blocks: "
              f"{', '.join(f'{x * 1e3:.2f}' for x in v)}) on {where[k]}")
    print(f"ratio torch / clholo: {med['torch'] / med['clholo']:.2f}x (four-pass "
          f"propagations: {med['torch'] / med['clholo, four-pass propagations']:.2f}x)")
    print(f"ratio {alt_name} / clholo: {med[alt_name] / med['clholo']:.3f}x")
    if other is not None:
        print(f"ratio --sums {other.sums.local}x{other.sums.groups} / device's plan: "
              f"{med['sums'] / med['clholo']:.3f}x")
    if a.breakdown:
        # the pieces are the unfused iteration's
        plain = alt if alt.fuse == "none" else eng if eng.fuse == "none" else None
        if plain is None:
            plain = PhaseRetrieval(cla.to_device(queue, target), wavelengths=[lam],
                                   pitch=pitch, z=a.z, padded=padded, lr=a.lr, queue=queue,
                                   fuse="none")
            plain.set_phase(cla.to_device(queue, phase0))
        breakdown(plain, queue, rounds=max(a.rounds, 5), reps=max(a.iterations, 3))


def breakdown(eng, queue, *, rounds, reps):
    """The pieces of one iteration on the engine's own plans, kernels and buffers, each run
    ``reps`` times per round between ``finish`` calls, the pieces interleaved over ``rounds``;
    medians in ms. The sum of the pieces against a whole step shows what lies between them."""
    p = eng.propagator

    def loss_and_scale():
        eng._enqueue("field_sums")  # the engine's own launches, their arguments preset
        eng._enqueue("fit_scale")

    def residual():
        eng._enqueue("scaled_residual")

    def adjoint():
        p.apply(eng.y, eng.tf_adjoint, out=eng.y, tf_even=True)

    def adam():
        knl = eng._own["phase_gradient_adam"][0]  # lr 0 keeps the phase
        for i, value in enumerate([0.0] + eng._adam_scalars(1)[1:]):
            knl.set_arg(6 + i, np.float32(value))
        eng._enqueue("phase_gradient_adam")

    if p.three_pass:
        r = p.row_spectrum
        pieces = {
            "forward: row FFT of x": lambda: p.row_forward.execute(eng.x, out=r),
            "forward: column round trip with H": lambda: p.columns.execute(
                r, out=r, multiply=eng.tf_forward, multiply_even=True),
            "forward: row inverse FFT and crop": lambda: p.row_inverse.execute(
                r, out=eng.y, inverse=True)}
    else:
        pieces = {"forward propagation (2 transforms, H at the inverse's load)":
                  lambda: p.apply(eng.x, eng.tf_forward, out=eng.y)}
    pieces.update({"loss sums + closed-form scale": loss_and_scale,
                   "scaled residual": residual,
                   "adjoint propagation": adjoint,
                   "gradient + Adam + exp(iP) (lr 0: phase kept)": adam,
                   "whole step": eng.step})
    times = {name: [] for name in pieces}
    for _ in range(rounds):
        for name, fn in pieces.items():
            queue.finish()
            t = time.perf_counter()
            for _ in range(reps):
                fn()
            queue.finish()
            times[name].append((time.perf_counter() - t) / reps * 1e3)
    med = {name: statistics.median(v) for name, v in times.items()}
    print(f"one iteration, pieces (median of {rounds} interleaved rounds of {reps}):")
    for name, ms in med.items():
        print(f"  {name:58s} {ms:7.2f} ms")
    parts = sum(v for n, v in med.items() if n != "whole step")
    print(f"  {'whole step - sum of pieces (launches, host work)':58s} "
          f"{med['whole step'] - parts:7.2f} ms")


if __name__ == "__main__":
    main()
