"""Datasets of holograms on Dask: ``clholo batch MANIFEST --out DIR``.

A manifest (CSV with a header row, or JSON lines) lists items; each item is one ``clholo
render`` (or ``clholo demo``) command: its scene input(s) and options. Every item becomes a Dask
task, or several when ``split_frames`` cuts its frames into ranges (frames are independent: the
phase stream depends on the absolute frame index, so the parts put together equal a whole render
bit for bit), followed by a task that writes the item from its parts.

Output folder ``DIR``::

    DIR/<item>/             what ``clholo render`` writes (hologram, focal_stack.png/.npz,
                            summary.json) plus batch_item.json (options, SHA-256 of each file)
    DIR/batch-log.jsonl     events appended as they happen: started, rendered, failed
    DIR/results.csv         one row per item: status, device, seconds, bytes, error
    DIR/results.jsonl       the same as JSON lines
    DIR/.staging/           items being written (emptied at the start of every run)
    DIR/.parts/<item>/      finished frame ranges of split items, until the item is written

An item is built under ``.staging`` and renamed into place when complete, so a killed batch
leaves only whole items; a rerun skips an item whose ``batch_item.json`` records the same
options and whose files still have the recorded SHA-256, and renders every other one again.

Dask (``pip install clholo[batch]``) is imported only by this module's functions.
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import hashlib
import io
import json
import os
import shutil
import signal
import socket
import sys
import threading
import time
import uuid
from dataclasses import dataclass, field
from pathlib import Path
from typing import Dict, List, Optional, Sequence

__all__ = ["BatchItem", "read_manifest", "render_dataset", "item_status", 
           "MOTORCYCLE"]

MOTORCYCLE = "skimage:motorcycle"   # manifest input that means ``clholo demo``'s scene
RECORD = "batch_item.json"
LOG = "batch-log.jsonl"
STAGING = ".staging"
PARTS = ".parts"
LOCK = ".batch.lock"

# manifest columns that are not clholo render/demo options; the options are read off the
# command's own parser (every option by its dest name: near, depth_kind, camera_json, ...)
_NOT_COLUMNS = {"help", "out", "overwrite", "inputs"}
_PATH_OPTIONS = {"camera_json"}   # resolved from the manifest's folder, like inputs
_BATCH_COLUMNS = ("id", "input", "depth", "split_frames")


@dataclass
class BatchItem:
    """One manifest row: a ``clholo render`` (or ``demo``) command and how to split it.

    Attributes
    ----------
    id : str
        Output folder name under ``DIR`` (letters, digits, ``._-``).
    command : {"render", "demo"}
    argv : list of str
        The command's arguments without ``--out`` (inputs as absolute paths).
    options : dict
        Every option of the command once parsed, defaults filled in: what the item is.
    split_frames : int or None
        Frames per task; ``None`` renders the item in one task.
    """

    id: str
    command: str
    argv: List[str]
    options: Dict[str, object]
    split_frames: Optional[int] = None
    row: int = 0
    where: str = ""
    options_sha256: str = field(init=False)

    def __post_init__(self) -> None:
        self.options_sha256 = _sha256_text(json.dumps(self.options, sort_keys=True))

    @property
    def frames(self) -> int:
        return int(self.options["frames"])

    def frame_ranges(self) -> List[tuple]:
        """``[(first, count), ...]`` of the tasks of this item."""
        T = self.frames
        step = self.split_frames or T
        return [(t0, min(step, T - t0)) for t0 in range(0, T, step)]


# ------------------------------------------------------------------------------------------
# manifest
def _sha256_text(text: str) -> str:
    return hashlib.sha256(text.encode()).hexdigest()


def _sha256_file(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def _command_options(command: str) -> Dict[str, argparse.Action]:
    """``dest -> action`` of the options of ``clholo <command>`` that a manifest may set."""
    from clholo import cli

    for action in cli.build_parser()._actions:
        if isinstance(action, argparse._SubParsersAction):
            sub = action.choices[command]
            return {a.dest: a for a in sub._actions
                    if a.option_strings and a.dest not in _NOT_COLUMNS}
    raise RuntimeError("clholo's parser has no subcommands")  # pragma: no cover


def _parse_command(command: str, argv: List[str], where: str) -> argparse.Namespace:
    """Parse ``argv`` with ``clholo``'s own parser: same options, defaults and checks."""
    from clholo import cli

    err = io.StringIO()
    try:
        with contextlib.redirect_stderr(err):
            return cli.build_parser().parse_args([command] + argv)
    except SystemExit:
        lines = err.getvalue().strip().splitlines()
        message = lines[-1].split(" error: ", 1)[-1] if lines else "bad options"
        raise ValueError(f"{where}: {message}") from None


def _cells(row: dict, where: str) -> dict:
    """Cells of a CSV row or a JSON object, blanks dropped, keys checked."""
    out = {}
    for key, value in row.items():
        if key is None:
            raise ValueError(f"{where}: more cells than header columns")
        key = key.strip()
        if value is None or (isinstance(value, str) and not value.strip()):
            continue
        if key not in _BATCH_COLUMNS and (key in _NOT_COLUMNS or not key.isidentifier()):
            raise ValueError(f"{where}: column {key!r} cannot be set per item")
        out[key] = value.strip() if isinstance(value, str) else value
    return out


def _item_from_cells(cells: dict, base: Path, row: int, where: str) -> BatchItem:
    if "input" not in cells:
        raise ValueError(f"{where}: no 'input' (a scene path, or {MOTORCYCLE})")
    scene = str(cells["input"])
    if scene == MOTORCYCLE:
        command, inputs = "demo", []
        if "depth" in cells:
            raise ValueError(f"{where}: 'depth' goes with an image input, not {MOTORCYCLE}")
    else:
        command = "render"
        inputs = [scene] + ([str(cells["depth"])] if "depth" in cells else [])
        inputs = [str((base / p).resolve()) if not Path(p).is_absolute() else str(Path(p))
                  for p in inputs]
    argv = list(inputs)
    actions = _command_options(command)
    for key, value in cells.items():
        if key in _BATCH_COLUMNS:
            continue
        action = actions.get(key)
        if action is None:
            raise ValueError(f"{where}: unknown column {key!r}: clholo {command} has no option "
                             f"--{key.replace('_', '-')}; columns: "
                             f"{', '.join(list(_BATCH_COLUMNS) + sorted(actions))}")
        flag = action.option_strings[-1]
        if action.nargs == 0:  # a switch: true/1/yes sets it
            if str(value).strip().lower() in ("1", "true", "yes"):
                argv.append(flag)
            elif str(value).strip().lower() not in ("0", "false", "no"):
                raise ValueError(f"{where}: {key} must be true or false, got {value!r}")
        elif action.nargs in ("+", "*"):
            values = value if isinstance(value, list) else str(value).replace(",", " ").split()
            argv += [flag] + [str(v) for v in values]
        else:
            if key in _PATH_OPTIONS and not Path(str(value)).is_absolute():
                value = str((base / str(value)).resolve())
            argv += [flag, str(value)]
    args = _parse_command(command, argv, where)
    options = {k: v for k, v in vars(args).items()
               if k not in ("func", "out", "command", "overwrite")}
    options["command"] = command
    split = cells.get("split_frames")
    if split is not None:
        try:
            split = int(split)
        except (TypeError, ValueError):
            raise ValueError(f"{where}: split_frames must be a positive integer, got "
                             f"{split!r}") from None
        if split < 1:
            raise ValueError(f"{where}: split_frames must be a positive integer, got {split}")
        if split >= int(options["frames"]):
            split = None
    default_id = f"{row:04d}-{Path(scene).stem if command == 'render' else 'motorcycle'}"
    item_id = str(cells.get("id", default_id))
    if (not item_id or item_id.startswith(".")
            or any(not (c.isalnum() or c in "._-") for c in item_id)):
        raise ValueError(f"{where}: id {item_id!r} must be letters, digits, '.', '_' or '-' "
                         f"and not start with '.' (it names the item's folder)")
    return BatchItem(id=item_id, command=command, argv=argv, options=options,
                     split_frames=split, row=row, where=where)


def read_manifest(path) -> List[BatchItem]:
    """Items of a manifest: CSV (``.csv``, a header row) or JSON lines (``.jsonl``/``.json``).

    Columns: ``input`` (a scene path relative to the manifest's folder, or
    ``skimage:motorcycle`` for ``clholo demo``'s scene), optional ``depth`` (the depth map of an
    image input), ``id`` (the item's folder name; default row number and input name),
    ``split_frames`` (frames per task), and every option of ``clholo render`` (``clholo demo``
    for the motorcycle) by its name with underscores: ``layers``, ``near``, ``far``, ``frames``,
    ``seed``, ``pad``, ``pitch``, ``wavelengths`` (space-separated in CSV, a list in JSON),
    ``hologram_format``, ``spacing``, ``mode``, ``depth_kind``, ``scale``, ``camera_json``, ...
    Blank cells take the command's defaults; each row is checked by the command's own parser.

    Raises
    ------
    ValueError
        Naming the row and the column, for unknown columns, bad values and repeated ids.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"manifest {path} does not exist")
    base = path.parent.resolve()
    text = path.read_text(encoding="utf-8")
    rows = []
    if path.suffix.lower() == ".csv":
        reader = csv.DictReader(io.StringIO(text))
        if not reader.fieldnames or "input" not in [f.strip() for f in reader.fieldnames]:
            raise ValueError(f"{path}: a CSV manifest needs a header row with an 'input' column")
        for k, row in enumerate(reader):
            rows.append((k, f"{path.name} row {k + 2}", row))
    elif path.suffix.lower() in (".jsonl", ".json", ".ndjson"):
        for k, line in enumerate(text.splitlines()):
            if not line.strip() or line.lstrip().startswith("#"):
                continue
            where = f"{path.name} line {k + 1}"
            try:
                row = json.loads(line)
            except json.JSONDecodeError as exc:
                raise ValueError(f"{where}: not JSON ({exc.msg})") from None
            if not isinstance(row, dict):
                raise ValueError(f"{where}: each line must be a JSON object")
            rows.append((len(rows), where, row))
    else:
        raise ValueError(f"manifest {path} must end in .csv or .jsonl (JSON lines)")
    items = [_item_from_cells(_cells(row, where), base, k, where) for k, where, row in rows]
    if not items:
        raise ValueError(f"manifest {path} lists no items")
    seen = {}
    for item in items:
        if item.id in seen:
            raise ValueError(f"id {item.id!r} is used by {seen[item.id]} and {item.where}; ids "
                             f"name output folders and must be unique")
        seen[item.id] = item.where
    return items


# ------------------------------------------------------------------------------------------
# item state on disk
def item_status(out_dir, item: BatchItem) -> tuple:
    """``(complete, reason)``: whether ``out_dir/<item.id>`` holds this item, whole.

    Complete means: ``batch_item.json`` records the same options, every file it lists has the
    recorded SHA-256 and no other file is there.
    """
    folder = Path(out_dir) / item.id
    if not folder.is_dir():
        return False, "absent"
    try:
        record = json.loads((folder / RECORD).read_text())
    except (OSError, ValueError):
        return False, f"no readable {RECORD}"
    if record.get("options_sha256") != item.options_sha256:
        return False, "rendered with other options"
    files = record.get("files") or {}
    present = {p.name for p in folder.iterdir()} - {RECORD}
    if present != set(files):
        return False, "files differ from the record"
    for name, digest in files.items():
        if _sha256_file(folder / name) != digest:
            return False, f"{name} changed since it was written"
    return True, "complete"


def _append_log(out_dir: Path, event: dict) -> None:
    # one write() per line with O_APPEND: lines from several processes do not interleave
    line = (json.dumps(event, sort_keys=True) + "\n").encode()
    fd = os.open(out_dir / LOG, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o666)
    try:
        os.write(fd, line)
    finally:
        os.close(fd)


def _worker_name() -> str:
    try:
        from distributed import get_worker

        return str(get_worker().name)
    except (ImportError, ValueError):
        return f"{socket.gethostname()}:{os.getpid()}"


def _run_command(item: BatchItem, out_dir: Path, *, holograms=None, scene_only: bool = False):
    """The item's own ``clholo render`` / ``clholo demo`` work with ``--out out_dir``.

    The scene is built by the same function the command line uses
    (:data:`clholo.cli.SCENES`) and the folder written by :func:`clholo.cli.render_folder`;
    ``holograms`` (frames rendered as frame-range parts) are written instead of rendering again;
    ``scene_only`` stops after the scene. Returns ``(captured, log_text)``, ``captured`` holding
    ``mpi``, ``optics`` and (unless ``scene_only``) ``summary``.
    """
    from clholo import cli
    from clholo.demo import StepLog

    args = _parse_command(item.command, item.argv + ["--out", str(out_dir)], item.id)
    if item.command == "render" and (args.method != "mpi" or args.max_splats is not None):
        raise ValueError(f"item {item.id}: --method rpws and --max-splats render splats one "
                         f"primitive at a time; run them with clholo render, not in a batch")
    text = io.StringIO()
    log = StepLog(text)
    with contextlib.redirect_stdout(text):
        mpi, optics, source = cli.SCENES[item.command](args, log)
        captured = {"mpi": mpi, "optics": optics}
        if not scene_only:
            captured["summary"] = cli.render_folder(args, mpi, optics, source, log,
                                                    command=item.command, holograms=holograms)
    return captured, text.getvalue()


def _part_path(out_dir: Path, item: BatchItem, first: int, count: int) -> Path:
    return out_dir / PARTS / item.id / f"frames-{first:06d}-{first + count - 1:06d}.npz"


def _part_ok(path: Path, item: BatchItem) -> bool:
    from clholo.io import read_hologram

    if not path.is_file():
        return False
    try:  # np.load checks each member's CRC-32: a damaged file does not read
        _, meta = read_hologram(path)
    except Exception:  # noqa: BLE001 - any unreadable part is rendered again
        return False
    return meta.get("options_sha256") == item.options_sha256


def _run_part(out_dir: str, item: BatchItem, first: int, count: int) -> dict:
    """Task: frames ``first .. first+count-1`` of a split item into ``.parts``."""
    from clholo.hologram import HologramRenderer
    from clholo.host import runtime
    from clholo.io import write_hologram

    out = Path(out_dir)
    path = _part_path(out, item, first, count)
    t = time.perf_counter()
    try:
        if not _part_ok(path, item):
            scene, _ = _run_command(item, out / STAGING / f"{item.id}.{uuid.uuid4().hex}",
                                    scene_only=True)
            mpi, optics = scene["mpi"], scene["optics"]
            queue = runtime.get_queue()
            renderer = HologramRenderer(mpi, optics, seed=item.options["seed"],
                                        pad=item.options["pad"], queue=queue)
            import numpy as np

            holo = np.empty((count, mpi.channels) + mpi.shape, np.complex64)
            for t0, batch in renderer.iter_frames(count, start=first):
                holo[t0 - first:t0 - first + batch.shape[0]] = batch
            path.parent.mkdir(parents=True, exist_ok=True)
            write_hologram(path, holo, pitch=optics.pitch, wavelengths=optics.wavelengths,
                           seed=item.options["seed"],
                           metadata={"options_sha256": item.options_sha256,
                                     "first_frame": first})
        return {"status": "ok", "path": str(path), "seconds": time.perf_counter() - t}
    except Exception as exc:  # noqa: BLE001 - recorded, the other items go on
        return {"status": "failed", "error": f"frames {first}..{first + count - 1}: "
                                             f"{type(exc).__name__}: {exc}"}


def _run_item(out_dir: str, item: BatchItem, *parts: dict) -> dict:
    """Task: write item ``item`` (rendering it, or from its ``parts``) and rename it into
    place. Never raises: a failure is returned (and logged) with its error."""
    out = Path(out_dir)
    worker = _worker_name()
    base = {"item": item.id, "worker": worker, "pid": os.getpid()}
    t_start = time.perf_counter()
    complete, _ = item_status(out, item)
    if complete:  # a task Dask ran again after its worker died just after the rename
        return dict(base, status="skipped", seconds=0.0)
    failed = [p["error"] for p in parts if p.get("status") != "ok"]
    if failed:
        result = dict(base, status="failed", error="; ".join(failed),
                      seconds=time.perf_counter() - t_start)
        _append_log(out, dict(result, event="failed", time=time.time()))
        return result
    _append_log(out, dict(base, event="started", time=time.time()))
    try:
        from clholo.host import runtime

        holograms = None
        t_start -= sum(p["seconds"] for p in parts)  # the item's seconds include its parts'
        if parts:
            import numpy as np

            from clholo.io import read_hologram

            holograms = np.concatenate([read_hologram(p["path"])[0] for p in parts])
        render_id = uuid.uuid4().hex
        staging = out / STAGING / f"{item.id}.{render_id}"
        captured, log_text = _run_command(item, staging, holograms=holograms)
        summary = captured["summary"]
        files = {p.name: _sha256_file(p) for p in sorted(staging.iterdir())}
        seconds = time.perf_counter() - t_start
        record = {
            "item": item.id, "command": item.command, "argv": item.argv,
            "options": item.options, "options_sha256": item.options_sha256, "files": files,
            "bytes": sum((staging / n).stat().st_size for n in files),
            "device": summary["device"], "worker": worker, "seconds": seconds,
            "render_id": render_id, "parts": len(parts), "log": log_text,
        }
        (staging / RECORD).write_text(json.dumps(record, indent=1))
        _install(staging, out / item.id)
        device = runtime.get_queue().device.name.strip()
        result = dict(base, status="rendered", seconds=seconds, device=summary["device"],
                      bytes=record["bytes"], frames=item.frames, height=summary["height"],
                      width=summary["width"], channels=summary["channels"],
                      parts=len(parts), render_id=render_id)
        _append_log(out, dict(result, event="rendered", time=time.time(), opencl=device))
        if parts:
            shutil.rmtree(out / PARTS / item.id, ignore_errors=True)
        return result
    except Exception as exc:  # noqa: BLE001 - recorded, the other items go on
        result = dict(base, status="failed", error=f"{type(exc).__name__}: {exc}",
                      seconds=time.perf_counter() - t_start)
        _append_log(out, dict(result, event="failed", time=time.time()))
        return result


def _foreign(path: Path) -> bool:
    """True when ``path`` exists and is not an item folder clholo wrote (never replaced)."""
    from clholo.io.output import is_clholo_output

    if not (path.exists() or path.is_symlink()):
        return False
    return path.is_symlink() or not path.is_dir() or not (
        is_clholo_output(path) or (path / RECORD).is_file())


def _install(staging: Path, target: Path) -> None:
    """Rename the finished ``staging`` folder to ``target``; an old (invalid) ``target`` is
    moved aside first and removed after, so a crash leaves the old or the new one whole."""
    if _foreign(target):
        raise FileExistsError(f"{target} exists and clholo did not write it; it is left alone: "
                              f"move it away or give the item another id")
    if target.exists():
        old = staging.with_name(staging.name + ".old")
        os.replace(target, old)
        os.replace(staging, target)
        shutil.rmtree(old, ignore_errors=True)
    else:
        os.replace(staging, target)


# ------------------------------------------------------------------------------------------
# engine
def _local_devices() -> List[str]:
    """``P:D`` selectors of this machine's devices: every GPU, else every device."""
    from clholo.host import runtime

    devices = runtime.list_devices()
    gpus = [d for d in devices if "GPU" in d.device_type]
    return [d.selector for d in (gpus or devices)]


def _local_cluster(workers: Optional[int]):
    """A local Dask cluster: one single-threaded worker process per OpenCL device, each pinned
    to it through ``CLHOLO_DEVICE``; ``workers`` more or fewer than the devices go round."""
    import logging

    from distributed import Nanny, Scheduler, SpecCluster

    devices = _local_devices()
    if not devices:
        from clholo.host.runtime import INSTALL_HINT, NoDeviceError

        raise NoDeviceError("No OpenCL device for the batch's workers. " + INSTALL_HINT)
    n = len(devices) if workers is None else int(workers)
    spec = {f"clholo-{k}": {"cls": Nanny,
                            "options": {"nthreads": 1, "host": "127.0.0.1",
                                        "silence_logs": logging.ERROR,
                                        "dashboard_address": None,
                                        "env": {"CLHOLO_DEVICE": devices[k % len(devices)]}}}
            for k in range(n)}
    # SpecCluster is LocalCluster's base: it takes a spec per worker, hence a device per worker
    cluster = SpecCluster(workers=spec,
                          scheduler={"cls": Scheduler,
                                     "options": {"dashboard_address": None,
                                                 "host": "127.0.0.1"}},
                          silence_logs=logging.ERROR, name="clholo-batch")
    return cluster, [devices[k % len(devices)] for k in range(n)]


class _Interrupted(BaseException):
    """SIGTERM: a BaseException, so that no `except Exception` around a result swallows it."""


@contextlib.contextmanager
def _sigterm_raises():
    """SIGTERM ends the batch like Ctrl-C: the cluster is closed, no item is left half-written
    in place (items in flight stay in ``.staging``, removed by the next run)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def handler(signum, frame):
        raise _Interrupted(f"signal {signum}")

    previous = signal.signal(signal.SIGTERM, handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


@contextlib.contextmanager
def _lock(out: Path):
    import fcntl

    fd = os.open(out / LOCK, os.O_RDWR | os.O_CREAT, 0o666)
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            raise FileExistsError(f"another clholo batch is writing {out} (it holds "
                                  f"{out / LOCK}); wait for it or give another --out") from None
        yield
    finally:
        os.close(fd)


def _write_results(out: Path, rows: List[dict]) -> None:
    from clholo.io.images import atomic_path

    columns = ["item", "status", "device", "worker", "seconds", "bytes", "frames", "height",
               "width", "channels", "parts", "error", "options"]
    with atomic_path(out / "results.csv") as tmp:
        with open(tmp, "w", newline="") as f:
            writer = csv.DictWriter(f, fieldnames=columns, extrasaction="ignore")
            writer.writeheader()
            for row in rows:
                writer.writerow(dict(row, options=json.dumps(row.get("options"), sort_keys=True)))
    with atomic_path(out / "results.jsonl") as tmp:
        tmp.write_text("".join(json.dumps(r, sort_keys=True) + "\n" for r in rows))


def _record_row(out: Path, item: BatchItem) -> dict:
    record = json.loads((out / item.id / RECORD).read_text())
    summary = json.loads((out / item.id / "summary.json").read_text())
    return {"device": record.get("device"), "worker": record.get("worker"),
            "bytes": record.get("bytes"), "frames": summary["frames"],
            "height": summary["height"], "width": summary["width"],
            "channels": summary["channels"], "parts": record.get("parts", 0)}


def render_dataset(manifest, out_dir, *, scheduler: Optional[str] = None,
                   workers: Optional[int] = None, split_frames: Optional[int] = None,
                   progress: Optional[bool] = None, stream=None) -> List[dict]:
    """Render every item of ``manifest`` into ``out_dir`` on Dask; returns one row per item.

    Parameters
    ----------
    manifest : path-like or sequence of BatchItem
        A CSV or JSON-lines manifest (see :func:`read_manifest`), or items already read.
    out_dir : path-like
        Output folder (created; items already complete in it are skipped).
    scheduler : str, optional
        Address of an existing Dask scheduler (``tcp://host:8786``); default
        ``DASK_SCHEDULER_ADDRESS``, else a local cluster of one worker per OpenCL device.
    workers : int, optional
        Local cluster only: worker processes (default one per device; more than the devices
        share them round-robin).
    split_frames : int, optional
        Frames per task for items whose manifest row gives no ``split_frames``.
    progress : bool, optional
        A tqdm bar over items on ``stream`` (default: when ``stream`` is a terminal).
    stream : file, optional
        Where the progress bar and summary line go (default ``sys.stderr``).

    Returns
    -------
    list of dict
        Per item: ``item``, ``status`` ("rendered", "skipped" or "failed"), ``device``,
        ``worker``, ``seconds``, ``bytes``, ``frames``, ``height``, ``width``, ``channels``,
        ``error``, ``options``; also written to ``out_dir/results.csv`` and ``results.jsonl``.
    """
    from clholo import validate

    try:
        from distributed import Client, as_completed
    except ImportError:
        raise ImportError("clholo batch needs Dask: pip install 'clholo[batch]'") from None

    stream = stream if stream is not None else sys.stderr
    items = read_manifest(manifest) if isinstance(manifest, (str, os.PathLike)) else list(manifest)
    if workers is not None:
        workers = validate.count(workers, name="workers")
    if split_frames is not None:
        split_frames = validate.count(split_frames, name="split_frames")
        for item in items:
            if item.split_frames is None and split_frames < item.frames:
                item.split_frames = split_frames
    scheduler = scheduler or os.environ.get("DASK_SCHEDULER_ADDRESS") or None
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise FileExistsError(f"--out {out} is a file; give a folder for the dataset")
    if (out.is_dir() and any(out.iterdir()) and not (out / LOG).is_file()
            and not (out / LOCK).is_file()):
        raise FileExistsError(f"--out {out} is a folder with other files in it (no {LOG}); give "
                              f"an empty or new folder, or the folder of an earlier batch")
    out.mkdir(parents=True, exist_ok=True)
    t_start = time.perf_counter()
    rows: Dict[str, dict] = {}
    with _lock(out), _sigterm_raises():
        shutil.rmtree(out / STAGING, ignore_errors=True)   # items a killed run left unfinished
        (out / STAGING).mkdir()
        todo = []
        for item in items:
            complete, reason = item_status(out, item)
            if complete:
                rows[item.id] = dict(item=item.id, status="skipped", seconds=0.0,
                                     **_record_row(out, item))
            elif _foreign(out / item.id):
                rows[item.id] = dict(item=item.id, status="failed", seconds=0.0, error=(
                    f"{out / item.id} exists and clholo did not write it; it is left alone: "
                    f"move it away or give the item another id"))
                _append_log(out, dict(rows[item.id], event="failed", time=time.time()))
            else:
                todo.append(item)
        if progress is None:
            progress = bool(getattr(stream, "isatty", lambda: False)())
        bar = None
        if progress:
            from tqdm import tqdm

            bar = tqdm(total=len(items), initial=len(items) - len(todo), unit="item",
                       file=stream, desc="clholo batch")
        cluster = None
        client = None
        try:
            if todo:
                if scheduler:
                    client = Client(scheduler)
                    engine = f"scheduler {scheduler}"
                else:
                    cluster, pinned = _local_cluster(workers)
                    client = Client(cluster)
                    engine = f"local cluster on device(s) {', '.join(pinned)}"
                n_workers = len(client.scheduler_info().get("workers", {}))
                futures = {}
                for item in todo:
                    if item.split_frames:
                        parts = [client.submit(_run_part, str(out), item, a, n, pure=False,
                                               key=f"part-{item.id}-{a}-{uuid.uuid4().hex[:8]}")
                                 for a, n in item.frame_ranges()]
                    else:
                        parts = []
                    fut = client.submit(_run_item, str(out), item, *parts, pure=False,
                                        key=f"item-{item.id}-{uuid.uuid4().hex[:8]}")
                    futures[fut] = item
                for fut in as_completed(list(futures)):
                    item = futures[fut]
                    try:
                        result = fut.result()
                    except Exception as exc:  # noqa: BLE001 - e.g. KilledWorker: record it
                        result = {"item": item.id, "status": "failed",
                                  "error": f"{type(exc).__name__}: {exc}"}
                        _append_log(out, dict(result, event="failed", time=time.time()))
                    if result["status"] == "skipped" and (out / item.id / RECORD).is_file():
                        result.update(_record_row(out, item))
                    rows[item.id] = result
                    if bar is not None:
                        bar.update(1)
            else:
                engine, n_workers = "nothing to render", 0
        except (KeyboardInterrupt, _Interrupted):
            print(f"clholo batch: interrupted; {sum(r['status'] == 'rendered' for r in rows.values())}"
                  f" item(s) rendered this run are complete in {out}; run again to finish",
                  file=stream, flush=True)
            raise
        finally:
            if bar is not None:
                bar.close()
            if client is not None:
                with contextlib.suppress(Exception):
                    client.close()
            if cluster is not None:
                with contextlib.suppress(Exception):
                    cluster.close()
        table = []
        for item in items:
            row = rows[item.id]
            row.setdefault("error", "")
            row["options"] = item.options
            table.append(row)
        _write_results(out, table)
    seconds = time.perf_counter() - t_start
    counts = {s: sum(r["status"] == s for r in table) for s in ("rendered", "skipped", "failed")}
    rate = counts["rendered"] / seconds * 60 if seconds > 0 else 0.0
    print(f"clholo batch: {len(items)} item(s): {counts['rendered']} rendered, "
          f"{counts['skipped']} skipped (complete), {counts['failed']} failed in "
          f"{seconds:.1f} s ({rate:.1f} rendered/min; {engine}, {n_workers} worker(s)); "
          f"results in {out / 'results.csv'}", file=stream, flush=True)
    return table


# ------------------------------------------------------------------------------------------
# command line
