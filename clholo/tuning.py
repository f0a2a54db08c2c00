"""Per-device tuning: the GPU kernels' settings that change how fast clholo runs, never what it
computes, measured on the device that runs them.

clholo's GPU kernels have a few forms that compute the same bits with another order or layout
(the composite four pixels at a time, the layers as planes, ...). Which form is faster depends
on the device and its driver; the project's defaults are what the devices it measured
preferred, and a lab's GPU may be another. :func:`tune` measures each setting on one device with
the lab's workload (by default a 1080 x 1920 RGB render of 32 layers), checks on that device
that every form gives the same bits as the default, and :func:`save_tuning` stores the choices
in a JSON file (:func:`tuning_file`) under the device's name and driver. Plans built afterwards
on that device take them: :meth:`clholo.fft.DeviceLimits.of` carries them into every plan's
geometry, as FFTW's wisdom or CLBlast's tuned parameters are kept per machine.

Only settings that give the same bits are tunable (a test checks each of them on PoCL, and
:func:`tune` again on the device it measures). The FFT's radices, the in-place plan for columns
and the loss sums' grouping change results in their last bits: they stay the project's defaults.

Settings in effect, from first to last: :func:`override` (benchmarks and tests), the stored
tuning of the device (unless :func:`untuned`), the project's default (:data:`SETTINGS`).
``CLHOLO_TUNING_FILE`` names the file (``off`` for none); by default
``$XDG_CACHE_HOME/clholo/tuning.json`` (``~/.cache/clholo/tuning.json``). A stored entry is
used only by the clholo version that measured it (kernels change between versions): another
version's entry is ignored with a :class:`TuningWarning` that says to run ``clholo tune``
again. What plans read lives in :mod:`clholo.host.tuning`; this module measures and stores.

Examples
--------
>>> from clholo import tuning                                  # doctest: +SKIP
>>> result = tuning.tune(shape=(1080, 1920), layers=32)        # doctest: +SKIP
>>> print(result.report())                                     # doctest: +SKIP
>>> tuning.save_tuning(result)                                 # doctest: +SKIP
"""

from __future__ import annotations

import datetime
import math
import statistics
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Dict, List, Optional, Sequence, Tuple

import numpy as np

from clholo._version import __version__
from clholo.errors import InputError
from clholo.host.tuning import (SETTINGS, TUNING_FILE_ENV, Setting, TuningWarning, device_key,
                                override, settings_for, store_entry, stored_entry, tuning_file,
                                untuned)

__all__ = ["SETTINGS", "Setting", "TuningResult", "TuningWarning", "TUNING_FILE_ENV",
           "device_key", "forget_tuning", "override", "save_tuning", "settings_for",
           "stored_entry", "tune", "tuning_file", "untuned"]


def save_tuning(result: "TuningResult", *, path: Optional[Path] = None) -> Path:
    """Store ``result``'s settings for its device in the tuning file (other devices' entries
    are kept); plans built afterwards on the device take them.

    Parameters
    ----------
    result : TuningResult
        What :func:`tune` returned.
    path : path, optional
        Default: :func:`tuning_file`.

    Returns
    -------
    pathlib.Path
        The file written.
    """
    if not isinstance(result, TuningResult):
        raise InputError(f"result must be what clholo.tuning.tune returned, got "
                         f"{type(result).__name__}")
    path = tuning_file() if path is None else Path(path).expanduser()
    if path is None:
        raise InputError(f"{TUNING_FILE_ENV} is off: give a path, or set {TUNING_FILE_ENV} to "
                         f"the file to write")
    store_entry(result.device, result.entry(), path=path)
    return path


def forget_tuning(device, *, path: Optional[Path] = None) -> bool:
    """Remove ``device``'s entry from the tuning file; True if there was one.

    Parameters
    ----------
    device : pyopencl.Device
    path : path, optional
        Default: :func:`tuning_file` (nothing to remove where that is off).
    """
    path = tuning_file() if path is None else Path(path).expanduser()
    if path is None:
        return False
    return store_entry(device_key(device), None, path=path)




# ------------------------------------------------------------------------------ the tuner
@dataclass
class TuningResult:
    """What :func:`tune` measured and chose.

    Attributes
    ----------
    device : str
        :func:`device_key` of the device measured.
    settings : dict
        The chosen value of every setting.
    defaults : dict
        The project's defaults, which the search started from.
    rows : list of dict
        One per value tried: ``setting``, ``value``, ``ms`` (per workload the setting can
        change: the current choice's and the value's median kernel milliseconds),
        ``speedup`` (geometric mean over those workloads of the median of the rounds' current
        / value), ``same_bits``, ``adopted``; a value that failed on the device has
        ``error`` instead of times.
    speedup : float
        The chosen settings against the defaults, measured side by side at the end (1.0 where
        the defaults were kept).
    workload : dict
        What was measured (shape, colours, layers, frames, pad, sgd, rounds, threshold).
    date : str
        When, ISO 8601 in UTC (default: now).
    """

    device: str
    settings: Dict[str, Any]
    defaults: Dict[str, Any]
    rows: List[Dict[str, Any]]
    speedup: float
    workload: Dict[str, Any]
    date: str = field(default_factory=lambda: datetime.datetime.now(
        datetime.timezone.utc).isoformat(timespec="seconds"))

    def entry(self) -> Dict[str, Any]:
        """The tuning file's entry for the device."""
        return {"clholo": __version__, "date": self.date, "settings": dict(self.settings),
                "defaults": dict(self.defaults), "speedup": round(self.speedup, 4),
                "workload": dict(self.workload), "measured": list(self.rows)}

    def report(self) -> str:
        """A Markdown table of every value tried, and the choice."""
        names: List[str] = []
        for r in self.rows:
            names += [n for n in r["ms"] if n not in names]
        head = " | ".join(f"{n}: ms now / with it" for n in names)
        lines = [f"device: {self.device}", "",
                 f"| setting | value | {head} | speed | same bits | taken |",
                 "|---|---|" + "---|" * len(names) + "---|---|---|"]
        for r in self.rows:
            if r.get("error"):
                cells = " | ".join(["failed"] * len(names)) if names else "failed"
                lines.append(f"| {r['setting']} | {r['value']} | {cells} | | | no: "
                             f"{r['error']} |")
                continue
            ms = " | ".join(f"{r['ms'][n][0]:.3f} / {r['ms'][n][1]:.3f}" if n in r["ms"]
                            else "(not changed by it)" for n in names)
            lines.append(f"| {r['setting']} | {r['value']} | {ms} | {r['speedup']:.3f}x | "
                         f"{'yes' if r['same_bits'] else 'NO'} | "
                         f"{'yes' if r['adopted'] else 'no'} |")
        changed = {k: v for k, v in self.settings.items() if self.defaults.get(k) != v}
        lines += ["", "chosen: " + (", ".join(f"{k}={v}" for k, v in changed.items())
                                    if changed else "the defaults"),
                  f"against the defaults, side by side: {self.speedup:.3f}x"]
        return "\n".join(lines)


class _Workload:
    """One measured workload: ``prepare(settings)`` builds its plans under those settings and
    returns ``(run, result)``: a callable that enqueues one timed run, and the result of a
    fixed start, which every form must give exactly (``np.array_equal``: the same bits up to
    the sign of a zero)."""

    name = ""
    kind = ""

    def prepare(self, settings: Dict[str, Any]):  # pragma: no cover - interface
        raise NotImplementedError


class _RenderWorkload(_Workload):
    def __init__(self, queue, shape, colours, layers, frames, pad, seed, variant):
        import clholo

        H, W = shape
        rng = np.random.default_rng(seed)
        depths = np.linspace(2e-3, 6e-3, layers)
        self.mpi = clholo.MPI(rng.random((layers, H, W, colours), dtype=np.float32),
                              rng.random((layers, H, W), dtype=np.float32), depths)
        # one colour: the green wavelength alone, as clholo.bench.profile_render
        self.optics = clholo.Optics(wavelengths=(520e-9,) if colours == 1
                                    else (638e-9, 520e-9, 450e-9))
        self.queue, self.frames, self.pad, self.seed, self.variant = (queue, frames, pad, seed,
                                                                      variant)
        self.kind, self.name = "render", f"render {H}x{W} C={colours} L={layers} T={frames}"

    def prepare(self, settings):
        import pyopencl.array as cla

        from clholo.hologram import HologramRenderer

        with override(**settings):
            r = HologramRenderer(self.mpi, self.optics, seed=self.seed, pad=self.pad,
                                 queue=self.queue, variant=self.variant)
        out = cla.empty(self.queue, (self.frames, self.mpi.channels) + r.shape, np.complex64)
        bits = r.render(self.frames, out=out).get()
        return (lambda: r.render(self.frames, out=out)), bits


class _SGDWorkload(_Workload):
    def __init__(self, queue, size, pad, seed, variant):
        from clholo.propagation import device_padded_shape

        self.queue, self.variant = queue, variant
        self.lam, self.pitch, self.z = 520e-9, 8e-6, 0.04
        self.padded = device_padded_shape((size, size), self.z, wavelength=self.lam,
                                          pitch=self.pitch, pad=pad)
        rng = np.random.default_rng(seed)
        self.target = (rng.standard_normal((1, size, size))
                       + 1j * rng.standard_normal((1, size, size))).astype(np.complex64)
        self.phase = rng.uniform(0, 2 * np.pi, (1, size, size)).astype(np.float32)
        self.kind = "sgd"
        self.name = f"SGD {size}x{size} grid {self.padded[0]}x{self.padded[1]}"

    def prepare(self, settings):
        import pyopencl.array as cla

        from clholo.host.phase_retrieval import PhaseRetrieval

        with override(**settings):
            eng = PhaseRetrieval(cla.to_device(self.queue, self.target), wavelengths=[self.lam],
                                 pitch=self.pitch, z=self.z, padded=self.padded,
                                 queue=self.queue, variant=self.variant)
        eng.set_phase(self.phase)
        for _ in range(3):
            eng.step()
        bits = eng.phase.get()
        return eng.step, bits


def _kernel_seconds(run: Callable[[], object], queue, repeats: int) -> float:
    from clholo.host import runtime

    with runtime.KernelRecorder() as rec:
        for _ in range(repeats):
            run()
        queue.finish()
    return sum(float(r["seconds"]) for r in rec.summary()) / repeats


def _side_by_side(run_a, run_b, queue, rounds: int, repeats: int):
    """Kernel seconds of A and of B timed in alternation (A B, B A, ...), so that a device's
    clocks drifting during the measurement favour neither: the medians of A and of B, and the
    median over rounds of each round's A / B (a ratio of two runs side by side)."""
    ta, tb = [], []
    for i in range(rounds):
        order = ((run_a, ta), (run_b, tb)) if i % 2 == 0 else ((run_b, tb), (run_a, ta))
        for run, times in order:
            times.append(_kernel_seconds(run, queue, repeats))
    ratios = [a / b for a, b in zip(ta, tb) if a > 0 and b > 0]
    return statistics.median(ta), statistics.median(tb), (statistics.median(ratios)
                                                          if ratios else 1.0)


def _geomean(values: Sequence[float]) -> float:
    return math.exp(sum(math.log(v) for v in values) / len(values)) if values else 1.0


def _positive_int(name: str, value, *, low: int = 1, high: Optional[int] = None) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < low or (
            high is not None and value > high):
        raise InputError(f"{name} is {value!r}; give an integer from {low}"
                         + (f" to {high}" if high is not None else " up"))
    return int(value)


def tune(*, shape: Tuple[int, int] = (1080, 1920), colours: int = 3, layers: int = 32,
         frames: int = 3, pad="auto", sgd: Optional[int] = None, rounds: int = 5,
         repeats: int = 2, threshold: float = 0.03, seed: int = 0, variant: str = "auto",
         queue=None, progress: Optional[Callable[[str], None]] = None) -> TuningResult:
    """Measure every tunable setting on one device and choose the fastest values.

    The search starts from the project's defaults and takes the settings one at a time
    (:data:`SETTINGS`' order): each other value is built and timed side by side with the
    current choice on the workloads it can change (kernel time from profiling events, in
    ``rounds`` alternations; the median of the rounds' ratios), and taken where it is faster
    by at least ``threshold`` (geometric mean over the workloads) and gives the same result as
    the current choice on this device, bit for bit. At the end the choice and the defaults are
    timed side by side once more; unless the choice is faster by ``threshold`` there too, the
    defaults are kept (single gains that were noise do not add up).

    Parameters
    ----------
    shape : (int, int)
        ``(H, W)`` of the render measured, pixels (default the lab's SLM, 1080 x 1920).
    colours : {1, 3}
        Colour channels of the render.
    layers, frames : int
        MPI layers ``L`` and frames ``T`` of each render.
    pad : "auto" or float
        The render's (and SGD's) padding (``HologramRenderer``'s ``pad``).
    sgd : int, optional
        Also measure an SGD iteration of ``sgd x sgd`` pixels (``PhaseRetrieval.step``);
        default none (``clholo tune`` measures 1024 unless given ``--sgd 0``).
    rounds : int
        Alternations per comparison (medians of these).
    repeats : int
        Runs timed back to back in each alternation.
    threshold : float
        The relative speed-up a value must show to be taken, in ``[0, 1)`` (default 3 %,
        above the noise of kernel times on a quiet GPU).
    seed : int
        Seed of the random layers, phases and SGD target.
    variant : {"auto", "gpu"}
        The kernels measured: the device's (``"auto"``), or the GPU kernels on any device
        (``"gpu"``: what tests run on PoCL). The settings change only the GPU kernels, so a CPU
        device needs ``"gpu"``.
    queue : pyopencl.CommandQueue, optional
        With profiling enabled; default clholo's queue.
    progress : callable, optional
        Called with a line of text after each comparison.

    Returns
    -------
    TuningResult
        Store it with :func:`save_tuning`.
    """
    import pyopencl as cl

    from clholo import validate
    from clholo.host import runtime

    try:
        H, W = (int(v) for v in shape)
    except (TypeError, ValueError):
        raise InputError(f"shape is {shape!r}; give (H, W) in pixels, such as (1080, 1920)")
    _positive_int("shape's H", H, low=2)
    _positive_int("shape's W", W, low=2)
    if colours not in (1, 3) or isinstance(colours, bool):
        raise InputError(f"colours is {colours!r}; give 1 or 3")
    layers = _positive_int("layers", layers, high=4096)
    frames = _positive_int("frames", frames, high=4096)
    rounds = _positive_int("rounds", rounds, high=1000)
    repeats = _positive_int("repeats", repeats, high=1000)
    if sgd is not None:
        sgd = _positive_int("sgd", sgd, low=2)
    threshold = validate.real_scalar("threshold", threshold,
                                     fix="give a fraction such as 0.03 (3 %)")
    if not 0 <= threshold < 1:
        raise InputError(f"threshold is {threshold!r}; give a fraction in [0, 1), such as 0.03")
    if variant not in ("auto", "gpu"):
        raise InputError(f"variant is {variant!r}; give 'auto' (the device's kernels) or 'gpu'")
    queue = queue if queue is not None else runtime.get_queue()
    if not isinstance(queue, cl.CommandQueue):
        raise InputError(f"queue must be a pyopencl.CommandQueue, got {type(queue).__name__}")
    if not queue.properties & cl.command_queue_properties.PROFILING_ENABLE:
        raise InputError("queue has no profiling: tune() times kernels by their events; make it "
                         "with properties=cl.command_queue_properties.PROFILING_ENABLE, or leave "
                         "queue unset for clholo's queue")
    device = queue.device
    if variant == "auto" and device.type & cl.device_type.CPU:
        raise InputError(f"{device.name.strip()} runs clholo's CPU kernels, which the tunable "
                         f"settings do not change: there is nothing to tune there. Tune a GPU, "
                         f"or give variant='gpu' (--variant gpu) to tune the GPU kernels on it")
    say = progress or (lambda line: None)

    workloads: List[_Workload] = [_RenderWorkload(queue, (H, W), colours, layers, frames, pad,
                                                  seed, variant)]
    if sgd is not None:
        workloads.append(_SGDWorkload(queue, sgd, pad, seed, variant))
    with untuned():
        defaults = {name: s.default for name, s in SETTINGS.items()}
        prepared: Dict[Tuple, List] = {}

        def get(settings):
            key = tuple(sorted(settings.items()))
            if key not in prepared:
                prepared[key] = [w.prepare(settings) for w in workloads]
            return prepared[key]

        def compare(a, b, kinds=("render", "sgd")):
            pa, pb = get(a), get(b)
            same = all(np.array_equal(x[1], y[1]) for x, y in zip(pa, pb))
            ms, ratios = {}, []
            for w, (run_a, _), (run_b, _) in zip(workloads, pa, pb):
                if w.kind not in kinds:
                    continue
                ta, tb, ratio = _side_by_side(run_a, run_b, queue, rounds, repeats)
                ms[w.name] = (round(ta * 1e3, 6), round(tb * 1e3, 6))
                ratios.append(ratio)
            return ms, _geomean(ratios), same

        current = dict(defaults)
        rows = []
        for name, s in SETTINGS.items():
            for value in s.values:
                if value == current[name]:
                    continue
                cand = {**current, name: value}
                get(current)  # the current choice built and run already: its failure is real
                try:
                    ms, speed, same = compare(current, cand, s.workloads)
                except (cl.Error, RuntimeError, ValueError, MemoryError) as exc:
                    # a form this device's driver cannot build or run is not taken; the others
                    # are still measured (an OpenCL error, a limit no plan foresaw)
                    why = f"{type(exc).__name__}: {exc}".strip()[:300]
                    warnings.warn(f"{name}={value!r} failed on {device.name.strip()} ({why}): "
                                  f"not taken. Please report it (clholo {__version__})",
                                  TuningWarning, stacklevel=2)
                    rows.append({"setting": name, "value": value, "ms": {}, "speedup": None,
                                 "same_bits": False, "adopted": False, "error": why})
                    say(f"{name}={value}: failed ({why})")
                    for key in [k for k in prepared if dict(k) not in (current, defaults)]:
                        del prepared[key]
                    continue
                adopted = same and speed >= 1 + threshold
                if not same:
                    warnings.warn(f"{name}={value!r} gave other bits than {current[name]!r} on "
                                  f"{device.name.strip()}: not taken. Please report it (clholo "
                                  f"{__version__}); every form should compute the same",
                                  TuningWarning, stacklevel=2)
                rows.append({"setting": name, "value": value, "ms": ms,
                             "speedup": round(speed, 4), "same_bits": bool(same),
                             "adopted": bool(adopted)})
                say(f"{name}={value}: {speed:.3f}x{'' if same else ', other bits'}"
                    f"{', taken' if adopted else ''}")
                # drop what no later comparison needs (a render's plans and buffers)
                keep = cand if adopted else current
                for key in [k for k in prepared if dict(k) not in (keep, defaults)]:
                    del prepared[key]
                current = keep
        speedup = compare(defaults, current)[1] if current != defaults else 1.0
        if current == defaults:
            say("no setting was faster than the defaults by the threshold: the defaults kept")
        elif speedup < 1 + threshold:
            # each value was taken on its own comparison; together they must still beat the
            # defaults by the threshold, or the gains were noise
            say(f"chosen against the defaults: {speedup:.3f}x, not above the threshold: "
                f"the defaults kept")
            current, speedup = dict(defaults), 1.0
        else:
            say(f"chosen against the defaults: {speedup:.3f}x")
        prepared.clear()
    return TuningResult(device=device_key(device), settings=current, defaults=defaults,
                        rows=rows, speedup=speedup,
                        workload={"shape": [H, W], "colours": colours, "layers": layers,
                                  "frames": frames, "pad": pad, "sgd": sgd, "rounds": rounds,
                                  "repeats": repeats, "threshold": threshold, "seed": seed,
                                  "variant": variant,
                                  "workloads": [w.name for w in workloads]})
