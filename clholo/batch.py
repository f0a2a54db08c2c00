"""Datasets of holograms on Dask: ``clholo batch MANIFEST --out DIR``.

A manifest (CSV with a header row, or JSON lines) lists items; each item is one ``clholo
render`` (or ``clholo demo``) command: its scene input(s) and options, parsed with the very
option definitions of those commands (:mod:`clholo.options`), so a row means what the
same command line means. An item is a :class:`clholo.scenes.SceneSpec`, a method of
:data:`clholo.methods.METHODS` (``mpi``, ``rgbd``, ``rpws``) and the render options. Every item
becomes a Dask task, or several when ``split_frames`` cuts its frames into ranges (frame ``t`` is
the same hologram whatever the batching, for every method: the phases depend on the absolute
frame index), followed by a task that writes the item through
:func:`clholo.render_folder.render_to_folder`, the writer of ``clholo render``.

Output folder ``DIR``::

    DIR/<item>/             what ``clholo render`` writes (hologram, focal_stack.png/.npz,
                            summary.json, clholo-output.json) plus batch_item.json (options,
                            SHA-256 of each file, the render's log)
    DIR/batch-log.jsonl     events appended as they happen: started, rendered, failed
    DIR/results.csv         one row per item: status, device, seconds, bytes, error
    DIR/results.jsonl       the same as JSON lines
    DIR/.staging/           items being written (what a killed run left is removed by the next;
                            removed with .parts/ and .batch.lock when empty at the end)
    DIR/.parts/<item>/      finished frame ranges of split items, until the item is written

An item is built under ``.staging`` and renamed into place when complete, so a killed batch
leaves only whole items; a rerun skips an item whose ``batch_item.json`` records the same
options and whose files still have the recorded SHA-256, and renders every other one again. A
file that clholo did not write is never deleted: an item folder holding one is refused (the
item fails, naming the file), and so is a changed ``results.csv``. ``batch-log.jsonl`` records
the manifest that made the folder (:func:`dataset_record`); a run whose manifest drops an item
the folder holds, or (another manifest) changes one's options, is refused before any work
unless ``overwrite`` (:func:`check_resume`): one folder, one dataset.

Dask (``pip install clholo[batch]``) is imported only by this module's functions. Library code:
it reports progress through a :class:`clholo.progress.StepLog`, raises
:class:`BatchInterrupted` (a ``KeyboardInterrupt`` saying what was kept) on Ctrl-C or SIGTERM,
and never exits.
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import hashlib
import io
import json
import os
import re
import shutil
import signal
import socket
import sys
import threading
import time
import uuid
from dataclasses import dataclass, field
from pathlib import Path
from typing import Dict, List, Optional

from clholo.errors import EnvironmentProblem, InputError, InputTypeError, OutputRefused
from clholo.io.images import replace_path

__all__ = ["BatchItem", "BatchInterrupted", "read_manifest", "render_dataset", "item_status",
           "check_resume", "dataset_record", "MOTORCYCLE"]

MOTORCYCLE = "skimage:motorcycle"   # manifest input that means ``clholo demo``'s scene
RECORD = "batch_item.json"
LOG = "batch-log.jsonl"
RESULTS = ("results.csv", "results.jsonl")
STAGING = ".staging"
PARTS = ".parts"
LOCK = ".batch.lock"
_TASK_DIR = re.compile(r"^[0-9a-f]{32}$")            # .staging/<uuid hex>/ of one task
# .parts/<item>/ files; frame numbers are written with at least six digits (frame 10**6 on
# has seven: those parts were left behind by _remove_parts and not counted by _kept)
_PART_FILE = re.compile(r"^frames-\d{6,}-\d{6,}\.npz$")

# manifest columns that are not options of the row's command (the batch's own, or set by it)
_NOT_COLUMNS = {"help", "out", "overwrite", "inputs", "progress", "debug"}
_PATH_COLUMNS = {"camera_json"}   # resolved from the manifest's folder, like inputs
_BATCH_COLUMNS = ("id", "input", "depth", "split_frames")
#: Longest item id, bytes of UTF-8: a folder name, with room for the temporary names made
#: beside it (``.<id>.<random>.tmp``) within the 255 bytes of a file system's name.
MAX_ID_BYTES = 100
#: Most tasks ``split_frames`` may cut one item into: each range is a Dask task and a part file
#: that the item's task reads back, so a manifest row ``frames=1e8`` with ``split_frames=1``
#: submitted 10**8 tasks (and held their futures) before anything rendered
MAX_PARTS = 10_000


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

    @property
    def method(self) -> str:
        """The name of the item's method in :data:`clholo.methods.METHODS`."""
        return str(self.options["method"])

    @property
    def spec(self):
        """The item's :class:`clholo.scenes.SceneSpec` (built by the options' own function)."""
        from clholo import options

        return options.scene_spec_from_args(argparse.Namespace(**self.options),
                                            demo=self.command == "demo")

    def frame_ranges(self) -> List[tuple]:
        """``[(first, count), ...]`` of the tasks of this item.

        Returns
        -------
        list of (int, int)
            At most :data:`MAX_PARTS` ranges.

        Raises
        ------
        clholo.errors.InputError
            ``split_frames`` would cut the item into more than :data:`MAX_PARTS` tasks
            (:func:`read_manifest` and :func:`run` refuse that first; this is the last guard
            before the list is made).
        """
        T = self.frames
        step = self.split_frames or T
        _check_parts(T, step, self.where or f"item {self.id}")
        return [(t0, min(step, T - t0)) for t0 in range(0, T, step)]


def _check_parts(frames: int, split_frames: int, where: str,
                name: str = "split_frames") -> None:
    """Refuse a ``split_frames`` that cuts ``frames`` into more than :data:`MAX_PARTS` tasks.

    Parameters
    ----------
    frames : int
        The item's frames.
    split_frames : int
        Frames per task (>= 1).
    where : str
        The manifest row or item, for the message.
    name : str
        How the caller spells the option (``split_frames`` in a row or in Python,
        ``--split-frames`` on the command line).

    Raises
    ------
    clholo.errors.InputError
        More than :data:`MAX_PARTS` tasks.
    """
    parts = -(-int(frames) // int(split_frames))
    if parts > MAX_PARTS:
        raise InputError(f"{where}: {name}={split_frames} cuts frames={frames} into {parts} "
                         f"tasks; at most {MAX_PARTS} per item: give {name} >= "
                         f"{-(-int(frames) // MAX_PARTS)} (or fewer frames)")


class BatchInterrupted(KeyboardInterrupt):
    """Ctrl-C or SIGTERM stopped a batch; ``note`` says what was kept (for the one line the
    command prints)."""

    def __init__(self, note: str):
        super().__init__(note)
        self.note = note


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


def row_parser(command: str) -> argparse.ArgumentParser:
    """The options of ``clholo <command>`` (``render`` or ``demo``) for one manifest row: the
    same option factories as the command (:mod:`clholo.options`), in a
    :class:`~clholo.options.RowParser` that raises instead of exiting."""
    from clholo import options

    p = options.RowParser(prog=f"clholo {command}")
    options.add_render_flow_options(p, demo=command == "demo")
    return p


_PARSERS: Dict[str, tuple] = {}


def _parser_and_columns(command: str):
    """``(parser, {dest: default})`` of a row command (cached: building it imports the method
    registry)."""
    if command not in _PARSERS:
        p = row_parser(command)
        # the options a row may set: every dest the command parses, read from its defaults
        defaults = vars(p.parse_args([] if command == "demo" else ["scene"]))
        _PARSERS[command] = (p, {k: v for k, v in defaults.items() if k not in _NOT_COLUMNS})
    return _PARSERS[command]


def _cells(row: dict, where: str) -> dict:
    """Cells of a CSV row or a JSON object, blanks dropped, keys checked."""
    out = {}
    for key, value in row.items():
        if key is None:
            raise InputError(f"{where}: more cells than header columns")
        key = key.strip()
        if value is None or (isinstance(value, str) and not value.strip()):
            continue
        if key not in _BATCH_COLUMNS and (key in _NOT_COLUMNS or not key.isidentifier()):
            raise InputError(f"{where}: column {key!r} cannot be set per item (the batch's "
                             f"--out holds every item; a rerun resumes)")
        if isinstance(value, (dict, bool)):
            raise InputError(f"{where}: column {key!r} must be a number, a word or a list, "
                             f"got {json.dumps(value)}")
        for text in (value if isinstance(value, list) else [value]):
            _check_text(text, key, where)
        out[key] = value.strip() if isinstance(value, str) else value
    return out


def _check_text(value, key: str, where: str) -> None:
    """Refuse a cell's text that no path or option can hold: a NUL byte (JSON's ``\u0000``;
    the file system refuses it as "embedded null byte", naming no row) or a lone surrogate
    (``\ud800``: no UTF-8 can encode it, for a file name or the batch's own records)."""
    if not isinstance(value, str):
        return
    if "\x00" in value:
        raise InputError(f"{where}: column {key!r} holds a NUL byte ({ascii(value)}), which no "
                         f"path or option can; remove the \\u0000")
    try:
        value.encode("utf-8")
    except UnicodeEncodeError as exc:
        raise InputError(f"{where}: column {key!r} holds {ascii(value[exc.start])}, a lone "
                         f"surrogate that is not a character ({ascii(value)}): write the "
                         f"character itself (or its surrogate pair)") from None


def _item_from_cells(cells: dict, base: Path, row: int, where: str) -> BatchItem:
    if "input" not in cells:
        raise InputError(f"{where}: no 'input' (a scene path, or {MOTORCYCLE})")
    for key in ("input", "depth"):
        if key in cells and not isinstance(cells[key], str):
            # a JSON list or number would become the path "['a', 'b']" and fail as a missing
            # scene on a worker
            raise InputError(f"{where}: column {key!r} must be one path as text, got "
                             f"{json.dumps(cells[key])}; an image and its depth map go in the "
                             f"columns 'input' and 'depth'")
    scene = str(cells["input"])
    if scene == MOTORCYCLE:
        command, inputs = "demo", []
        if "depth" in cells:
            raise InputError(f"{where}: 'depth' goes with an image input, not {MOTORCYCLE}")
    else:
        command = "render"
        inputs = [scene] + ([str(cells["depth"])] if "depth" in cells else [])
        inputs = [str((base / p).resolve()) if not Path(p).is_absolute() else str(Path(p))
                  for p in inputs]
    parser, columns = _parser_and_columns(command)
    argv = list(inputs)
    for key, value in cells.items():
        if key in _BATCH_COLUMNS:
            continue
        if key not in columns:
            raise InputError(f"{where}: unknown column {key!r}: clholo {command} has no option "
                             f"--{key.replace('_', '-')}; columns: "
                             f"{', '.join(list(_BATCH_COLUMNS) + sorted(columns))}")
        flag = "--" + key.replace("_", "-")
        if isinstance(columns[key], list):  # a list option (wavelengths)
            values = value if isinstance(value, list) else str(value).replace(",", " ").split()
            argv += [flag] + [str(v) for v in values]
        elif isinstance(value, list):
            raise InputError(f"{where}: column {key!r} takes one value, got a list {value!r}")
        else:
            if key in _PATH_COLUMNS and not Path(str(value)).is_absolute():
                value = str((base / str(value)).resolve())
            argv.append(f"{flag}={value}")
    from clholo.options import parse_row

    args = parse_row(parser, argv, where)
    from clholo.options import optics_from_args

    try:  # units and ranges now, as the command checks them, not on a worker later
        optics_from_args(args)
    except (ValueError, TypeError) as exc:
        raise InputError(f"{where}: {exc}") from None
    options = dict(vars(args))
    options["command"] = command
    if command == "render":
        options["inputs"] = list(options["inputs"])
    _check_scene_options(BatchItem(id="-", command=command, argv=argv, options=options),
                         where)
    split = cells.get("split_frames")
    if split is not None:
        try:
            split = int(str(split))
        except ValueError:
            raise InputError(f"{where}: split_frames must be a positive integer, got "
                             f"{split!r}") from None
        if split < 1:
            raise InputError(f"{where}: split_frames must be a positive integer, got {split}")
        if split >= int(options["frames"]):
            split = None
        else:  # before any task is submitted: a Dask task and a part file per range
            _check_parts(int(options["frames"]), split, where)
    stem = Path(scene).stem if command == "render" else "motorcycle"
    # the row number keeps default ids apart, so a long file name can be cut to fit
    default_id = f"{row:04d}-{stem.encode()[:MAX_ID_BYTES - 8].decode(errors='ignore')}"
    item_id = str(cells.get("id", default_id))
    if (not item_id or item_id.startswith(".")
            or any(not (c.isalnum() or c in "._-") for c in item_id)):
        raise InputError(f"{where}: id {item_id!r} must be letters, digits, '.', '_' or '-' "
                         f"and not start with '.' (it names the item's folder)")
    if len(item_id.encode()) > MAX_ID_BYTES:
        raise InputError(f"{where}: id {item_id[:40]!r}... is {len(item_id.encode())} bytes "
                         f"long; at most {MAX_ID_BYTES} (it names the item's folder, and its "
                         f"temporary names must fit a file system's 255): choose a shorter id")
    if item_id in RESULTS or item_id == LOG:
        raise InputError(f"{where}: id {item_id!r} is the name of a file the batch writes; "
                         f"choose another id")
    return BatchItem(id=item_id, command=command, argv=argv, options=options,
                     split_frames=split, row=row, where=where)


def _check_scene_options(item: BatchItem, where: str) -> None:
    """What the scene layer refuses before any work: ``--near`` without ``--far``, and, when
    the input exists, an option that does not act on it or on the method (``--layers`` with
    RPWS, RPWS of an MPI). A missing input is left to the item (it fails, the others go on)."""
    from clholo import scenes

    try:
        spec = item.spec
        try:
            kind = scenes.input_kind(spec)
        except (OSError, ValueError):
            return
        scenes.check_applicable(spec, kind, method=item.method)
    except InputError as exc:
        raise InputError(f"{where}: {exc}") from None


def _manifest_text(path: Path) -> str:
    """The manifest's text, or an error naming the file when it is not UTF-8 text."""
    data = path.read_bytes()
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise InputError(f"manifest {path} is not a text file (byte {exc.start} is "
                         f"0x{data[exc.start]:02x}, not UTF-8): give a CSV or JSON-lines "
                         f"manifest (see docs/batch.md)") from None
    if "\x00" in text:
        raise InputError(f"manifest {path} is not a text file (it holds NUL bytes): give a CSV "
                         f"or JSON-lines manifest (see docs/batch.md)")
    return text.lstrip("\ufeff")  # a byte-order mark from a spreadsheet's "UTF-8 CSV"


def read_manifest(path) -> List[BatchItem]:
    """Items of a manifest: CSV (``.csv``, a header row) or JSON lines (``.jsonl``/``.json``).

    Columns: ``input`` (a scene path relative to the manifest's folder, or
    ``skimage:motorcycle`` for ``clholo demo``'s scene), optional ``depth`` (the depth map of an
    image input), ``id`` (the item's folder name; default row number and input name),
    ``split_frames`` (frames per task), and every option of ``clholo render`` (``clholo demo``
    for the motorcycle) by its name with underscores: ``method`` (``mpi``, ``rgbd``, ``rpws``),
    ``layers``, ``near``, ``far``, ``frames``, ``seed``, ``pad``, ``pitch``, ``wavelengths``
    (space-separated in CSV, a list in JSON), ``hologram_format``, ``spacing``, ``mode``,
    ``depth_kind``, ``scale``, ``camera_json``, ``max_splats``, ... Blank cells take the
    command's defaults; each row is checked by the command's own option definitions.

    Raises
    ------
    clholo.errors.InputError
        Naming the row and the column, for unknown columns, bad values and repeated ids, or
        naming the file when it is not a text manifest.
    FileNotFoundError
        No such manifest.
    """
    from clholo.io.images import check_input_file

    # stat only, never open: a named pipe would wait for a writer; a loop of links is not
    # "does not exist"
    path = check_input_file(path, "manifest", "give a CSV or JSON-lines file")
    base = path.parent.resolve()
    suffix = path.suffix.lower()
    if suffix not in (".csv", ".jsonl", ".json", ".ndjson"):
        raise InputError(f"manifest {path} must end in .csv or .jsonl (JSON lines)")
    text = _manifest_text(path)
    rows = []
    if suffix == ".csv":
        try:
            reader = csv.DictReader(io.StringIO(text))
            if not reader.fieldnames or "input" not in [f.strip() for f in reader.fieldnames]:
                raise InputError(f"{path}: a CSV manifest needs a header row with an 'input' "
                                 f"column")
            names = [f.strip() for f in reader.fieldnames]
            twice = sorted({n for n in names if names.count(n) > 1 and n})
            if twice:
                # DictReader keeps the last of two equal columns: the other is lost unseen
                raise InputError(f"{path}: column {twice[0]!r} appears {names.count(twice[0])} "
                                 f"times in the header row; give each column once")
            for k, row in enumerate(reader):
                where = f"{path.name} row {k + 2}"
                missing = [key for key, value in row.items() if key is not None and value is None]
                if missing:
                    # a dropped comma shifts the cells: a missing one is not a blank one
                    raise InputError(
                        f"{where}: {len(names) - len(missing)} cell(s) but the header has "
                        f"{len(names)} columns (no cell for "
                        f"{', '.join(repr(m.strip()) for m in missing)}); write an empty cell "
                        f"(two commas) for a default")
                rows.append((k, where, row))
        except csv.Error as exc:
            raise InputError(f"manifest {path} is not a readable CSV file ({exc})") from None
    else:
        for k, line in enumerate(text.splitlines()):
            if not line.strip() or line.lstrip().startswith("#"):
                continue
            where = f"{path.name} line {k + 1}"
            try:
                row = json.loads(line, object_pairs_hook=lambda pairs: _unique_keys(
                    pairs, where))
            except json.JSONDecodeError as exc:
                raise InputError(f"{where}: not JSON ({exc.msg})") from None
            except RecursionError:
                raise InputError(f"{where}: not JSON that can be read (arrays or objects "
                                 f"nested thousands deep: a corrupt or generated file); write "
                                 f"the line again") from None
            except ValueError as exc:  # Python's limit on integer digits (4300)
                if isinstance(exc, InputError) or "digits" not in str(exc):
                    raise
                raise InputError(f"{where}: holds an integer of more than 4300 digits, which "
                                 f"no option takes (a corrupt or generated file); write the "
                                 f"line again") from None
            if not isinstance(row, dict):
                raise InputError(f"{where}: each line must be a JSON object")
            rows.append((len(rows), where, row))
    items = [_item_from_cells(_cells(row, where), base, k, where) for k, where, row in rows]
    if not items:
        raise InputError(f"manifest {path} lists no items")
    seen = {}
    for item in items:
        # by case too: "A" and "a" are one folder on macOS's and Windows' file systems
        if item.id.lower() in seen:
            other_id, other_where = seen[item.id.lower()]
            same = "" if other_id == item.id else f" (as {other_id!r}: ids differing in case " \
                "only name one folder where case is ignored)"
            raise InputError(f"id {item.id!r} is used by {other_where}{same} and {item.where}; "
                             f"ids name output folders and must be unique")
        seen[item.id.lower()] = (item.id, item.where)
    return items


def _unique_keys(pairs, where: str) -> dict:
    """A JSON-lines row's object, refusing a key given twice (json keeps the last: a
    ``"frames"`` overridden without a word), as the CSV header refuses a repeated column."""
    out = {}
    for key, value in pairs:
        if any(k.strip() == key.strip() for k in out):  # "frames " is "frames" too
            raise InputError(f"{where}: key {key!r} is given twice; give each column once")
        out[key] = value
    return out


# ------------------------------------------------------------------------------------------
# item state on disk
def _record(folder: Path) -> Optional[dict]:
    try:
        record = json.loads((folder / RECORD).read_text())
    except (OSError, ValueError):
        return None
    return record if isinstance(record, dict) else None


def item_status(out_dir, item: BatchItem) -> tuple:
    """``(complete, reason)``: whether ``out_dir/<item.id>`` holds this item, whole.

    Complete means: ``batch_item.json`` records the same options, every file it lists has the
    recorded SHA-256 and no other file is there.
    """
    from clholo.io.output import MANIFEST_NAME

    folder = Path(out_dir) / item.id
    if not folder.is_dir():
        return False, "absent"
    record = _record(folder)
    if record is None:
        return False, f"no readable {RECORD}"
    if record.get("options_sha256") != item.options_sha256:
        return False, "rendered with other options"
    files = record.get("files") or {}
    present = {p.name for p in folder.iterdir()} - {RECORD, MANIFEST_NAME}
    if present != set(files):
        return False, "files differ from the record"
    for name, digest in files.items():
        if _sha256_file(folder / name) != digest:
            return False, f"{name} changed since it was written"
    return True, "complete"


def foreign_in_item(folder: Path) -> List[str]:
    """Entries of an item folder that clholo did not write (never deleted): those neither its
    ``batch_item.json`` nor its clholo manifest lists. ``["."]`` when the folder itself is not
    an item clholo wrote (a file, a link, a folder of the user's)."""
    from clholo.io.output import MANIFEST_NAME, foreign_entries, is_clholo_output

    if not (folder.exists() or folder.is_symlink()):
        return []
    record = _record(folder) if folder.is_dir() and not folder.is_symlink() else None
    if record is None and not (folder.is_dir() and not folder.is_symlink()
                               and is_clholo_output(folder)):
        return ["."]
    listed = set((record or {}).get("files") or {}) | {RECORD, MANIFEST_NAME}
    names = {p.name for p in folder.iterdir()} - listed
    if is_clholo_output(folder):  # the manifest may list more (an older batch's record)
        names &= set(foreign_entries(folder))
    return sorted(names)


def _foreign_message(folder: Path, foreign: List[str]) -> str:
    if foreign == ["."]:
        return (f"{folder} exists and clholo did not write it; it is left alone: move it away "
                f"or give the item another id")
    shown = ", ".join(foreign[:3]) + (f" and {len(foreign) - 3} more" if len(foreign) > 3 else "")
    return (f"{folder} holds {shown}, which clholo did not write; rendering the item again "
            f"would delete it, so the item is left alone: move it out of the item's folder and "
            f"run again")


def changed_in_item(folder: Path) -> List[str]:
    """Files of an item folder that changed since clholo wrote them (their SHA-256 differs
    from the one ``batch_item.json`` or the folder's ``clholo-output.json`` records), sorted.
    A file the user deleted is not listed: rendering again loses nothing of theirs."""
    from clholo.io.output import changed_entries

    if not folder.is_dir() or folder.is_symlink():
        return []
    changed = set(changed_entries(folder))
    record = _record(folder)
    for name, digest in ((record or {}).get("files") or {}).items():
        path = folder / name
        if path.is_file() and not path.is_symlink() and _sha256_file(path) != digest:
            changed.add(name)
    return sorted(changed)


def _refusal(folder: Path) -> Optional[str]:
    """Why rendering an item again into ``folder`` would lose something of the user's (what
    clholo did not write, or a file edited since), or ``None``."""
    foreign = foreign_in_item(folder)
    if foreign:
        return _foreign_message(folder, foreign)
    changed = changed_in_item(folder)
    if changed:
        shown = ", ".join(changed[:3]) + (f" and {len(changed) - 3} more" if len(changed) > 3
                                          else "")
        return (f"{folder} holds {shown}, which changed since clholo wrote it; rendering the "
                f"item again would replace it, so the item is left alone: move it out of the "
                f"item's folder (or put back what clholo wrote) and run again")
    return None


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


def _load(item: BatchItem, log):
    """``(scene, method, optics)`` of an item: the scene layer and the method registry, as
    ``clholo render`` uses them."""
    from clholo import scenes
    from clholo import options
    from clholo.methods import get_method

    args = argparse.Namespace(**item.options)
    method = get_method(item.method)
    optics = options.optics_from_args(args)
    scene = scenes.load(item.spec, needs=method.needs, method=method.name, log=log)
    channels = scene.mpi.channels if scene.mpi is not None else scene.primitives.channels
    return scene, method, options.match_channels(optics, channels)


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
    """Task: frames ``first .. first+count-1`` of a split item into ``.parts``, by the item's
    method (``renderer.iter_frames(count, start=first)``: absolute frame indices)."""
    import numpy as np

    from clholo.host import runtime
    from clholo.io import write_hologram
    from clholo.io.images import atomic_path
    from clholo.progress import StepLog

    _detach_local_worker()
    out = Path(out_dir)
    path = _part_path(out, item, first, count)
    try:
        if _part_ok(path, item):
            meta_seconds = _part_seconds(path)
            return {"status": "ok", "path": str(path), "seconds": 0.0,
                    "render_seconds": meta_seconds}
        t = time.perf_counter()
        scene, method, optics = _load(item, StepLog(io.StringIO(), mode="off"))
        renderer = method.renderer(scene, optics, seed=item.options["seed"],
                                   pad=item.options["pad"], queue=runtime.get_queue())
        t_render = time.perf_counter()
        holo = None
        for t0, batch in renderer.iter_frames(count, start=first):
            if holo is None:
                holo = np.empty((count,) + batch.shape[1:], np.complex64)
            holo[t0 - first:t0 - first + batch.shape[0]] = batch
        render_seconds = time.perf_counter() - t_render
        path.parent.mkdir(parents=True, exist_ok=True)
        with atomic_path(path) as tmp:
            write_hologram(tmp, holo, pitch=optics.pitch, wavelengths=optics.wavelengths,
                           seed=item.options["seed"],
                           metadata={"options_sha256": item.options_sha256,
                                     "first_frame": first, "render_seconds": render_seconds})
        return {"status": "ok", "path": str(path), "seconds": time.perf_counter() - t,
                "render_seconds": render_seconds}
    except Exception as exc:  # noqa: BLE001 - recorded, the other items go on
        return {"status": "failed", "error": f"frames {first}..{first + count - 1}: "
                                             f"{type(exc).__name__}: {exc}"}


def _part_seconds(path: Path) -> float:
    from clholo.io import read_hologram

    try:
        return float(read_hologram(path)[1].get("render_seconds", 0.0))
    except Exception:  # noqa: BLE001
        return 0.0


def _run_item(out_dir: str, item: BatchItem, *parts: dict) -> dict:
    """Task: write item ``item`` (rendering it, or from its ``parts``) and rename it into
    place. Never raises: a failure is returned (and logged) with its error."""
    _detach_local_worker()
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
    task_dir = None
    try:
        from clholo.host import runtime
        from clholo.io.output import update_manifest
        from clholo.progress import StepLog
        from clholo.render_folder import render_to_folder

        holograms, extra = None, None
        t_start -= sum(p["seconds"] for p in parts)  # the item's seconds include its parts'
        if parts:
            import numpy as np

            from clholo.io import read_hologram

            holograms = np.concatenate([read_hologram(p["path"])[0] for p in parts])
            extra = {"render_seconds": sum(p["render_seconds"] for p in parts)}
        render_id = uuid.uuid4().hex
        task_dir = out / STAGING / render_id
        task_dir.mkdir()
        staging = task_dir / item.id
        text = io.StringIO()
        log = StepLog(text, mode="off")
        scene, method, optics = _load(item, log)
        opts = item.options
        summary = render_to_folder(scene, method, optics, staging, frames=item.frames,
                                   seed=opts["seed"], pad=opts["pad"], log=log,
                                   hologram_format=opts["hologram_format"],
                                   command=item.command, holograms=holograms,
                                   summary_extra=extra)
        from clholo.io.output import MANIFEST_NAME

        files = {p.name: _sha256_file(p) for p in sorted(staging.iterdir())
                 if p.name != MANIFEST_NAME}
        seconds = time.perf_counter() - t_start
        record = {
            "item": item.id, "command": item.command, "argv": item.argv,
            "options": item.options, "options_sha256": item.options_sha256, "files": files,
            "bytes": sum((staging / n).stat().st_size for n in files),
            "device": summary["device"], "worker": worker, "seconds": seconds,
            "render_id": render_id, "parts": len(parts), "log": text.getvalue(),
        }
        (staging / RECORD).write_text(json.dumps(record, indent=1))
        update_manifest(staging, add=[RECORD])
        _install(staging, out / item.id)
        device = runtime.get_queue().device.name.strip()
        result = dict(base, status="rendered", seconds=seconds, device=summary["device"],
                      bytes=record["bytes"], frames=item.frames, height=summary["height"],
                      width=summary["width"], channels=summary["channels"],
                      parts=len(parts), render_id=render_id)
        _append_log(out, dict(result, event="rendered", time=time.time(), opencl=device))
        if parts:
            _remove_parts(out, item.id)
        return result
    except Exception as exc:  # noqa: BLE001 - recorded, the other items go on
        result = dict(base, status="failed", error=f"{type(exc).__name__}: {exc}",
                      seconds=time.perf_counter() - t_start)
        _append_log(out, dict(result, event="failed", time=time.time()))
        return result
    finally:
        if task_dir is not None:
            shutil.rmtree(task_dir, ignore_errors=True)


def _remove_parts(out: Path, item_id: str) -> None:
    """Remove the part files of item ``item_id`` (written, or removed by ``--overwrite``; only
    files named like parts)."""
    folder = out / PARTS / item_id
    if not folder.is_dir():
        return
    for p in folder.iterdir():
        if _PART_FILE.match(p.name) and p.is_file():
            with contextlib.suppress(OSError):
                p.unlink()
    with contextlib.suppress(OSError):
        folder.rmdir()  # only when empty: anything else in it is left


def _install(staging: Path, target: Path) -> None:
    """Rename the finished ``staging`` folder to ``target``; an old ``target`` (an item clholo
    wrote, holding nothing else) is swapped out in one step where the system can, moved aside
    first elsewhere, and removed after, so a crash leaves the old or the new one whole
    (:func:`clholo.io.images.replace_path`)."""
    refused = _refusal(target)  # again at the rename: the user may have edited it meanwhile
    if refused:
        raise OutputRefused(refused)
    # in one step where the system can (the old one then lies at staging's name); else the
    # old one waits in the task folder (removed after this), put back if the second rename fails
    replace_path(staging, target, aside=staging.with_name(staging.name + ".old"))


def _clean_staging(out: Path) -> None:
    """Remove what killed runs left in ``.staging`` (task folders only: anything else there
    was not written by clholo and is left)."""
    staging = out / STAGING
    staging.mkdir(exist_ok=True)
    for p in staging.iterdir():
        if _TASK_DIR.match(p.name) and p.is_dir() and not p.is_symlink():
            shutil.rmtree(p, ignore_errors=True)


# ------------------------------------------------------------------------------------------
# engine
def _local_devices() -> List[str]:
    """``P:D`` selectors of the devices the local cluster's workers use: the one that
    ``CLHOLO_DEVICE`` (else ``PYOPENCL_CTX``) selects, as for every other command; without
    either, every GPU that compiles kernels, else every device that compiles kernels, one CPU
    device at most (two CPU drivers, PyPI's PoCL and a distribution's, share the same cores).

    Raises
    ------
    clholo.host.runtime.NoDeviceError
        A variable that matches no device (the message lists the devices), or no device.
    clholo.errors.EnvironmentProblem
        The device the variable picks cannot compile OpenCL kernels: every item would fail
        with its build log, so the batch stops before the cluster starts.
    """
    from clholo.host import runtime

    variable = next((var for var in ("CLHOLO_DEVICE", "PYOPENCL_CTX") if os.environ.get(var)),
                    None)
    if variable is not None:
        chosen = runtime.choose_device()  # the rule of every command; names the variable
        devices = runtime.list_devices()
        picked = [d for d in devices if runtime.choose_device(d.selector) == chosen][:1]
        # a selector names its device without the probe the default choice makes: probe it
        # here, once, rather than let every item fail with the compiler's log
        problem = runtime.device_build_problem(chosen)
        if problem is not None:
            where = (f"{picked[0].selector} ({picked[0].platform_name} / {picked[0].device_name})"
                     if picked else chosen.name.strip())
            raise EnvironmentProblem(
                f"{variable}={os.environ[variable]!r} picks device {where}, which cannot "
                f"compile OpenCL kernels here ({problem}): the batch's workers could render "
                f"nothing; choose another device with CLHOLO_DEVICE=P:D (`clholo info` lists "
                f"the devices and says which cannot compile)")
        return [d.selector for d in picked]
    devices = runtime.list_devices()
    # a GPU whose compiler fails here (a driver without its compiler package) would fail
    # every item it is given: probe each, as the CPU devices below are probed
    gpus = [d for d in devices if "GPU" in d.device_type
            and runtime.device_build_problem(runtime.choose_device(d.selector)) is None]
    if gpus:
        return [d.selector for d in gpus]
    runtime.choose_device()  # none that compiles: the rule's error, naming each one's problem
    pool, cpu_taken = [], False
    for d in devices:
        if (len(devices) > 1
                and runtime.device_build_problem(runtime.choose_device(d.selector)) is not None):
            continue  # its compiler does not work here (clholo info says why)
        if "CPU" in d.device_type:
            if cpu_taken:
                continue
            cpu_taken = True
        pool.append(d.selector)
    return pool


class _HeldInterrupts:
    """Ctrl-C and SIGTERM received while worker processes start, held until they have
    started (see :func:`_interrupts_held`)."""

    def __init__(self):
        self.signals: List[int] = []

    def __call__(self, signum, frame) -> None:
        self.signals.append(signum)

    def raise_if_any(self) -> None:
        if self.signals:
            raise KeyboardInterrupt(f"signal {self.signals[0]}")


@contextlib.contextmanager
def _interrupts_held():
    """While the cluster and its worker processes start: Ctrl-C and SIGTERM are recorded, not
    acted on and never lost (the caller ends the batch with :meth:`_HeldInterrupts.raise_if_any`
    once the cluster is in its hands, so that it can close it); and SIGINT is blocked in the
    threads and processes started meanwhile (the worker processes inherit the mask), so that a
    Ctrl-C on the terminal, which reaches the whole process group, stops the batch here and not
    as one traceback per worker; the batch then closes the workers itself. Before issue 26 this
    ignored SIGINT instead, and a Ctrl-C in the batch's first second was lost."""
    held = _HeldInterrupts()
    if threading.current_thread() is not threading.main_thread():
        yield held
        return
    previous = {sig: signal.signal(sig, held) for sig in (signal.SIGINT, signal.SIGTERM)}
    mask = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    try:
        yield held
    finally:
        # unblocking delivers a held SIGINT (pthread_sigmask runs the handler: recorded)
        signal.pthread_sigmask(signal.SIG_SETMASK, mask)
        for sig, handler in previous.items():
            signal.signal(sig, handler)


_LOCAL_WORKER = "CLHOLO_BATCH_LOCAL_WORKER"


def _detach_local_worker() -> None:
    """In a worker of the batch's own local cluster: leave the terminal's process group, so
    that a Ctrl-C there (sent to the whole foreground group) reaches only the batch, which
    closes the workers, and not the OpenCL compiler inside a worker (which would print its
    own errors). Workers of a cluster the user runs are left as they are."""
    if os.environ.get(_LOCAL_WORKER) == "1" and hasattr(os, "setpgid"):
        with contextlib.suppress(OSError):
            if os.getpgid(0) != os.getpid():
                os.setpgid(0, 0)


def _local_cluster(workers: Optional[int], devices: List[str]):
    """A local Dask cluster: one single-threaded worker process per OpenCL device of
    ``devices`` (:func:`_local_devices`), each pinned to it through ``CLHOLO_DEVICE``;
    ``workers`` more or fewer than the devices go round."""
    import logging

    from distributed import Nanny, Scheduler, SpecCluster

    if not devices:
        from clholo.host.runtime import INSTALL_HINT, NoDeviceError

        raise NoDeviceError("No OpenCL device for the batch's workers. " + INSTALL_HINT)
    n = len(devices) if workers is None else int(workers)
    spec = {f"clholo-{k}": {"cls": Nanny,
                            "options": {"nthreads": 1, "host": "127.0.0.1",
                                        "silence_logs": logging.CRITICAL,
                                        "dashboard": False,
                                        "dashboard_address": "127.0.0.1:0",
                                        "env": {"CLHOLO_DEVICE": devices[k % len(devices)],
                                                _LOCAL_WORKER: "1"}}}
            for k in range(n)}
    # SpecCluster is LocalCluster's base: it takes a spec per worker, hence a device per worker
    # (the caller holds Ctrl-C while it starts: _interrupts_held)
    cluster = SpecCluster(workers=spec,
                          scheduler={"cls": Scheduler,
                                     # no dashboard; the scheduler's own HTTP
                                     # routes on a free port, not 8787 (which another
                                     # cluster may hold: Dask would warn)
                                     "options": {"dashboard": False,
                                                 "dashboard_address": "127.0.0.1:0",
                                                 "host": "127.0.0.1"}},
                          silence_logs=logging.CRITICAL, name="clholo-batch")
    return cluster, [devices[k % len(devices)] for k in range(n)]


@contextlib.contextmanager
def _sigterm_interrupts():
    """SIGTERM ends the batch like Ctrl-C: the cluster is closed, no item is left half-written
    in place (items in flight stay in ``.staging``, removed by the next run)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def handler(signum, frame):
        raise KeyboardInterrupt(f"signal {signum}")

    previous = signal.signal(signal.SIGTERM, handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


@contextlib.contextmanager
def _quiet_dask():
    """Dask's own loggers say nothing below CRITICAL while the batch closes its cluster (the
    batch reports what happened, once)."""
    import logging

    loggers = [logging.getLogger(name) for name in ("distributed", "tornado", "asyncio")]
    levels = [lg.level for lg in loggers]
    for lg in loggers:
        lg.setLevel(logging.CRITICAL)
    try:
        yield
    finally:
        for lg, level in zip(loggers, levels):
            lg.setLevel(level)


@contextlib.contextmanager
def _lock(out: Path):
    """Hold ``out/.batch.lock`` (``flock``) while the batch runs; when it ends, however it
    ends, remove the lock file and an empty ``.staging``/``.parts`` (a finished batch leaves
    only its items, its log and its results)."""
    import fcntl

    path = out / LOCK
    for _ in range(20):
        fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o666)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            os.close(fd)
            raise OutputRefused(f"another clholo batch is writing {out} (it holds "
                                f"{path}); wait for it or give another --out") from None
        try:  # the file a batch that just ended removed: lock the one that is there now
            if os.stat(path).st_ino == os.fstat(fd).st_ino:
                break
        except FileNotFoundError:
            pass
        os.close(fd)
    else:  # pragma: no cover - twenty batches starting and ending in between
        raise OutputRefused(f"other clholo batches keep starting on {out}; wait for them")
    try:
        yield
    finally:
        for name in (STAGING, PARTS):
            with contextlib.suppress(OSError):
                (out / name).rmdir()  # only when empty
        with contextlib.suppress(OSError):
            os.unlink(path)  # still holding it: a batch starting now locks a new file
        os.close(fd)


def _write_results(out: Path, rows: List[dict]) -> None:
    from clholo.io.output import output_file

    columns = ["item", "status", "method", "device", "worker", "seconds", "bytes", "frames",
               "height", "width", "channels", "parts", "error", "options"]
    with output_file(out / "results.csv", overwrite=True, command="batch") as tmp:
        with open(tmp, "w", newline="") as f:
            writer = csv.DictWriter(f, fieldnames=columns, extrasaction="ignore")
            writer.writeheader()
            for row in rows:
                writer.writerow(dict(row, options=json.dumps(row.get("options"), sort_keys=True)))
    with output_file(out / "results.jsonl", overwrite=True, command="batch") as tmp:
        tmp.write_text("".join(json.dumps(r, sort_keys=True) + "\n" for r in rows))


def _record_row(out: Path, item: BatchItem) -> dict:
    record = json.loads((out / item.id / RECORD).read_text())
    summary = json.loads((out / item.id / "summary.json").read_text())
    return {"device": record.get("device"), "worker": record.get("worker"),
            "bytes": record.get("bytes"), "frames": summary["frames"],
            "height": summary["height"], "width": summary["width"],
            "channels": summary["channels"], "parts": record.get("parts", 0)}


def check_out_folder(out_dir) -> Path:
    """Refuse, before any work, a batch ``--out`` that is not new (with an existing parent),
    empty, or an earlier batch's folder, or whose results files someone changed."""
    from clholo.io.output import check_output_file, check_output_folder

    if not str(out_dir).strip():  # Path('') would be the current folder
        raise OutputRefused("--out is empty: give a folder for the dataset, e.g. --out dataset")
    out = Path(out_dir)
    if out.is_symlink() or (out.exists() and not out.is_dir()):
        raise OutputRefused(f"--out {out} is a file; give a folder for the dataset")
    if not out.exists():
        check_output_folder(out, option="--out")  # parent exists and is writable
        return out
    if any(out.iterdir()) and not (out / LOG).is_file() and not (out / LOCK).is_file():
        raise OutputRefused(f"--out {out} is a folder with other files in it (no {LOG}); give "
                            f"an empty or new folder, or the folder of an earlier batch")
    for name in RESULTS:  # rewritten at the end: refuse now, not after the work
        if (out / name).exists() or (out / name).is_symlink():
            try:
                check_output_file(out / name, overwrite=True, option="results file")
            except OutputRefused:
                raise OutputRefused(
                    f"{out / name} is not the file an earlier batch wrote (changed since, or "
                    f"written by someone else): this run would replace it, so it stops here; "
                    f"move it out of {out} and run again") from None
    return out


# ------------------------------------------------------------------------------------------
# what made the folder: a later run of another manifest must not mix its items in
_DATASET_EVENT = "dataset"


def dataset_record(out_dir) -> Optional[dict]:
    """What made the batch folder ``out_dir``: the last ``"dataset"`` event of its
    ``batch-log.jsonl`` (``manifest``: the manifest's absolute path, ``None`` for items given in
    Python; ``items``: the ids it listed), or ``None`` (a new folder, or one an older clholo
    made). Every run that renders (or finds every item complete) appends one."""
    path = Path(out_dir) / LOG
    try:
        lines = path.read_text(errors="replace").splitlines()
    except OSError:
        return None
    for line in reversed(lines):
        if f'"{_DATASET_EVENT}"' not in line:  # most lines are item events: skip them fast
            continue
        try:
            event = json.loads(line)
        except ValueError:  # a line cut short by a killed run: not a record
            continue
        if isinstance(event, dict) and event.get("event") == _DATASET_EVENT:
            return event
    return None


def _items_in_folder(out: Path) -> Dict[str, dict]:
    """``{id: batch_item.json}`` of the item folders in ``out`` (folders clholo wrote as items;
    a folder of the user's, without a record, is not one)."""
    found = {}
    if not out.is_dir():
        return found
    for p in out.iterdir():
        if p.name.startswith(".") or p.is_symlink() or not p.is_dir():
            continue
        record = _record(p)
        if record is not None and "options_sha256" in record:
            found[p.name] = record
    return found


def _short(value, other=None) -> str:
    """A value of an option for a message, beside ``other`` (the value it changed from or
    to): input paths by their names unless those are the same, long texts cut."""
    def names(v):
        return ([Path(p).name for p in v]
                if isinstance(v, list) and all(isinstance(p, str) for p in v) else v)

    if names(value) != names(other):  # the names tell the two apart: the paths need not
        value = names(value)
    text = json.dumps(value)
    return text if len(text) <= 60 else "..." + text[-57:]  # a path's end tells it apart


def _option_changes(record: dict, item: BatchItem) -> str:
    """``"frames 1 -> 2, seed 0 -> 3"``: how ``item``'s options differ from those its folder
    was rendered with (``record``: its ``batch_item.json``)."""
    old = record.get("options") if isinstance(record.get("options"), dict) else {}
    new = item.options
    keys = sorted(k for k in set(old) | set(new) if old.get(k) != new.get(k))
    shown = [f"{k} {_short(old.get(k), new.get(k))} -> {_short(new.get(k), old.get(k))}"
             for k in keys[:2]]
    if len(keys) > 2:
        shown.append(f"{len(keys) - 2} more")
    return ", ".join(shown) or "options recorded otherwise"


def _some(names: List[str], limit: int = 5) -> str:
    shown = ", ".join(names[:limit])
    return shown + (f" and {len(names) - limit} more" if len(names) > limit else "")


def check_resume(out_dir, items: List[BatchItem], manifest: Optional[str], *,
                 overwrite: bool = False) -> List[str]:
    """Refuse, before any work, a run whose manifest does not fit the items already in
    ``out_dir``; return the ids of item folders that ``overwrite`` removes.

    A batch folder holds one dataset. A run may add items (growing a dataset is normal) and
    completes or re-renders the items it lists. It is refused (unless ``overwrite``) when its
    manifest

    - does not list an item whose folder is in ``out_dir``: the folder would be left there
      without a row in ``results.csv`` (a dataset mixed from two manifests);
    - is not the manifest that made the folder (:func:`dataset_record`) and gives an item
      other options than its folder was rendered with: the item would be replaced without a
      word. Editing the manifest that made the folder is how a dataset is changed: its changed
      items are rendered again (and the run says which).

    Parameters
    ----------
    out_dir : path-like
        The batch folder (may not exist yet: nothing to check).
    items : list of BatchItem
        This run's items.
    manifest : str or None
        This run's manifest, an absolute path; ``None`` for items given in Python (never the
        manifest that made a folder).
    overwrite : bool
        Make ``out_dir`` this manifest's dataset: the items it does not list are removed (when
        clholo wrote them and nothing of the user's is in them), changed ones rendered again.

    Returns
    -------
    list of str
        Ids of the item folders to remove (only with ``overwrite``).

    Raises
    ------
    clholo.errors.OutputRefused
        Naming ``--out``, the items and the fixes.
    """
    out = Path(out_dir)
    present = _items_in_folder(out)
    if not present:
        return []
    listed = {item.id for item in items}
    dropped = sorted(set(present) - listed)
    made = dataset_record(out)
    made_by = made.get("manifest") if made is not None else None
    same = manifest is not None and made_by == manifest
    changed = [] if same else [
        (item, present[item.id]) for item in items
        if item.id in present and present[item.id].get("options_sha256") != item.options_sha256]
    if overwrite:
        for item_id in dropped:
            refused = _refusal(out / item_id)
            if refused:
                raise OutputRefused(f"--overwrite would remove {item_id}, which the manifest "
                                    f"does not list, but {refused}")
        return dropped
    if not dropped and not changed:
        return []
    name = Path(manifest).name if manifest is not None else "the items given"
    problems = []
    if dropped:
        problems.append(f"{name} does not list {_some(dropped)}, whose folder(s) would be "
                        f"left in --out without a row in results.csv")
    if changed:
        problems.append(f"{name} gives other options for "
                        + _some([f"{item.id} ({_option_changes(record, item)})"
                                 for item, record in changed], 3)
                        + ", whose folder(s) would be replaced")
    if same:
        origin, fix = (f"was made from this manifest ({manifest})",
                       f"put the row(s) back in {name}")
    elif made_by is not None:
        origin, fix = (f"was made from the manifest {made_by}",
                       f"run the manifest that made it ({Path(made_by).name}; adding rows to it "
                       f"is fine)")
    elif made is not None:
        origin, fix = "was made from items given in Python", "give the same items"
    else:
        origin, fix = ("holds items of an earlier batch (its manifest is not recorded: an "
                       "older clholo)", "run the manifest that made it")
    raise OutputRefused(
        f"--out {out} {origin}, but {'; and '.join(problems)}: {fix}, give a new --out, or "
        f"pass --overwrite to make {out} this manifest's dataset (items it does not list are "
        f"removed, changed ones rendered again)")


def _remove_items(out: Path, ids: List[str]) -> None:
    """Remove the item folders ``ids`` (``--overwrite``: the manifest no longer lists them),
    checked again under the lock; each removal is logged."""
    for item_id in ids:
        folder = out / item_id
        if not folder.is_dir() or folder.is_symlink():
            continue  # gone since the check
        refused = _refusal(folder)  # the user may have put something there since the check
        if refused:
            raise OutputRefused(f"--overwrite would remove {item_id}, which the manifest does "
                                f"not list, but {refused}")
        # renamed aside first, so that a crash leaves the whole item or no item
        aside = out / STAGING / f"{uuid.uuid4().hex}"
        os.replace(folder, aside)
        shutil.rmtree(aside, ignore_errors=True)
        _remove_parts(out, item_id)
        _append_log(out, {"event": "removed", "item": item_id, "time": time.time(),
                          "reason": "not in the manifest (--overwrite)"})


#: Seconds to connect to a ``--scheduler`` and complete Dask's handshake with it.
SCHEDULER_TIMEOUT_S = 20.0


def _scheduler_client(client_class, scheduler: str):
    """A Dask client of the scheduler at ``scheduler``, or an :class:`EnvironmentProblem` within
    about :data:`SCHEDULER_TIMEOUT_S`. Dask's own ``timeout`` bounds the TCP connect only: a
    server that accepts and then does not speak Dask's protocol (the dashboard's port, 8787,
    for the scheduler's, 8786) held the command forever, and one that answers in HTTP made
    Dask read the reply as a message length (a MemoryError of exbibytes). So the client is made
    on a thread of its own, waited for with a time limit; the thread is a daemon, so a hung one
    does not hold the process at its exit. Starts no process of ours: Ctrl-C acts at once."""
    box: dict = {}

    def connect():
        try:
            box["client"] = client_class(scheduler, timeout=SCHEDULER_TIMEOUT_S)
        except BaseException as exc:  # handed to the caller's thread
            box["error"] = exc

    thread = threading.Thread(target=connect, name="clholo-dask-connect", daemon=True)
    thread.start()
    thread.join(SCHEDULER_TIMEOUT_S + 5.0)
    fix = ("start it, or fix --scheduler / DASK_SCHEDULER_ADDRESS (the scheduler's port, "
           "8786 by default, not its dashboard's, 8787)")
    if thread.is_alive():
        raise EnvironmentProblem(
            f"the Dask scheduler {scheduler!r} did not answer within "
            f"{SCHEDULER_TIMEOUT_S + 5.0:g} s: is a Dask scheduler listening there? {fix}")
    exc = box.get("error")
    if isinstance(exc, (OSError, TimeoutError, ValueError)):
        raise EnvironmentProblem(f"cannot reach the Dask scheduler {scheduler!r} ({exc}): "
                                 f"{fix}") from None
    if isinstance(exc, MemoryError):
        raise EnvironmentProblem(f"{scheduler!r} does not answer as a Dask scheduler (its "
                                 f"reply is not Dask's protocol): {fix}") from None
    if exc is not None:
        raise exc
    return box["client"]


def render_dataset(manifest, out_dir, *, scheduler: Optional[str] = None,
                   workers: Optional[int] = None, split_frames: Optional[int] = None,
                   progress: str = "auto", stream=None, interval: float = 5.0,
                   overwrite: bool = False) -> List[dict]:
    """Render every item of ``manifest`` into ``out_dir`` on Dask; returns one row per item.

    Parameters
    ----------
    manifest : path-like or sequence of BatchItem
        A CSV or JSON-lines manifest (see :func:`read_manifest`), or items already read.
    out_dir : path-like
        Output folder: new (its parent must exist), empty, or an earlier batch's (items
        already complete in it are skipped).
    scheduler : str, optional
        Address of an existing Dask scheduler (``tcp://host:8786``); default
        ``DASK_SCHEDULER_ADDRESS``, else a local cluster of one worker per OpenCL device.
    workers : int, optional
        Local cluster only: worker processes, at most 256 (default one per device; more than
        the devices share them round-robin).
    split_frames : int, optional
        Frames per task for items whose manifest row gives no ``split_frames``.
    progress : {"auto", "bar", "lines", "off"}
        :mod:`clholo.progress`: a bar over items on a terminal, a plain line at least every
        ``interval`` seconds elsewhere (``auto``); a line per finished item except with a bar; a
        failed item's error always.
    stream : file, optional
        Where progress and the summary line go (default ``sys.stderr``).
    interval : float
        Seconds between two progress lines off a terminal.
    overwrite : bool
        Make ``out_dir`` this manifest's dataset when it holds items that the manifest does
        not list (they are removed) or, made from another manifest, items that it gives other
        options (rendered again); refused without it (:func:`check_resume`). Items a folder
        holds that clholo did not write, or files edited since, are never removed.

    Returns
    -------
    list of dict
        Per item: ``item``, ``status`` ("rendered", "skipped" or "failed"), ``method``,
        ``device``, ``worker``, ``seconds``, ``bytes``, ``frames``, ``height``, ``width``,
        ``channels``, ``error``, ``options``; also written to ``out_dir/results.csv`` and
        ``results.jsonl``.

    Raises
    ------
    BatchInterrupted
        Ctrl-C or SIGTERM: the cluster is closed, whole items and finished frame ranges are
        kept; its ``note`` says what.
    clholo.errors.OutputRefused
        Before any work: ``out_dir`` is not a batch folder, or holds items that this manifest
        drops or changes (see ``overwrite``).
    clholo.errors.EnvironmentProblem
        Before any work: the device that ``CLHOLO_DEVICE`` (or ``PYOPENCL_CTX``) picks for the
        local workers cannot compile OpenCL kernels.
    """
    from clholo import validate
    from clholo.errors import require_extra
    from clholo.progress import StepLog

    stream = stream if stream is not None else sys.stderr
    overwrite = validate.flag(overwrite, name="overwrite")
    out = check_out_folder(out_dir)  # before any work
    if isinstance(manifest, (str, os.PathLike)):
        items = read_manifest(manifest)
        source = str(Path(manifest).resolve())
    else:
        items, source = list(manifest), None
        odd = next((x for x in items if not isinstance(x, BatchItem)), None)
        if odd is not None or not items:
            raise InputTypeError(
                f"manifest must be a CSV or JSON-lines file, or a non-empty list of the "
                f"BatchItems read_manifest returns, got "
                f"{'an empty list' if not items else type(odd).__name__ + ' ' + repr(odd)[:60]}"
                f": write the rows to a manifest file and give its path")
    interval = validate.real_scalar("interval", interval)
    if not interval > 0:
        raise InputError(f"interval must be > 0 seconds between progress lines, got {interval}")
    # another manifest's items in --out: refused now, not found mixed in results.csv later
    # (and checked again under the lock: another batch may fill the folder meanwhile)
    check_resume(out, items, source, overwrite=overwrite)
    if workers is not None:
        workers = validate.count(workers, name="workers", maximum=256)  # processes to start
    if split_frames is not None:
        split_frames = validate.count(split_frames, name="split_frames")
        for item in items:  # every item checked before any is changed
            if item.split_frames is None and split_frames < item.frames:
                _check_parts(item.frames, split_frames, item.where or f"item {item.id}")
        for item in items:
            if item.split_frames is None and split_frames < item.frames:
                item.split_frames = split_frames
    scheduler = scheduler or os.environ.get("DASK_SCHEDULER_ADDRESS") or None
    if scheduler and workers is not None:
        raise InputError(f"--workers sets the processes of the local cluster, but the items go "
                         f"to the Dask scheduler {scheduler} (--scheduler or "
                         f"DASK_SCHEDULER_ADDRESS), whose workers run them: drop --workers")
    require_extra("distributed", "batch", "clholo batch")

    # the device rule of every command, before any work: CLHOLO_DEVICE / PYOPENCL_CTX pick the
    # local workers' device; one that matches nothing is refused with the list of devices
    devices = None if scheduler else _local_devices()

    log = StepLog(stream, mode=progress, interval=interval)
    created = not out.exists()
    out.mkdir(exist_ok=True)
    t_start = time.perf_counter()
    try:
        table, engine, n_workers = _render_all(out, items, scheduler, workers, devices, log,
                                               source=source, overwrite=overwrite)
    except BatchInterrupted:
        if created:
            _remove_if_unused(out)
        raise
    except KeyboardInterrupt:  # before the items' loop (the lock, the staging clean-up)
        if created:
            _remove_if_unused(out)
        raise BatchInterrupted(_kept(out, items, {})) from None
    except BaseException:
        if created:
            _remove_if_unused(out)
        raise
    seconds = time.perf_counter() - t_start
    counts = {s: sum(r["status"] == s for r in table) for s in ("rendered", "skipped", "failed")}
    rate = counts["rendered"] / seconds * 60 if seconds > 0 else 0.0
    log.end_line()
    print(f"clholo batch: {len(items)} item(s): {counts['rendered']} rendered, "
          f"{counts['skipped']} skipped (complete), {counts['failed']} failed in "
          f"{seconds:.1f} s ({rate:.1f} rendered/min; {engine}, {n_workers} worker(s)); "
          f"results in {out / 'results.csv'}", file=stream, flush=True)
    return table


def _render_all(out: Path, items: List[BatchItem], scheduler, workers, devices, log, *,
                source: Optional[str] = None, overwrite: bool = False):
    """The batch inside its lock: returns ``(table, engine, n_workers)``. ``source`` (the
    manifest's path) is recorded as what made the folder (:func:`dataset_record`) once the
    folder starts to change under this run. :func:`check_resume` runs again under the lock
    (another batch may have written the folder between the first check and the lock); the item
    folders it returns are what ``overwrite`` removes."""
    from distributed import Client

    rows: Dict[str, dict] = {}
    recorded = []

    def record_dataset() -> None:
        if not recorded:
            _append_log(out, {"event": _DATASET_EVENT, "manifest": source,
                              "items": [item.id for item in items], "time": time.time()})
            recorded.append(True)

    with _lock(out), _sigterm_interrupts():
        remove = check_resume(out, items, source, overwrite=overwrite)
        _clean_staging(out)
        if remove:
            record_dataset()
            _remove_items(out, list(remove))
            log.note(f"--overwrite: removed {_some(list(remove))}, which the manifest does not "
                     f"list")
        todo, changed = [], []
        for item in items:
            complete, reason = item_status(out, item)
            refused = None if complete else _refusal(out / item.id)
            if complete:
                rows[item.id] = dict(item=item.id, status="skipped", seconds=0.0,
                                     **_record_row(out, item))
            elif refused:
                rows[item.id] = dict(item=item.id, status="failed", seconds=0.0, error=refused)
                _append_log(out, dict(rows[item.id], event="failed", time=time.time()))
                _say_failed(log, rows[item.id])
            else:
                todo.append(item)
                if reason == "rendered with other options":
                    changed.append(item.id)
        # said, not silent: an item rendered before with other options is rendered again
        again = (f" ({len(changed)} with other options than before: {_some(changed)})"
                 if changed else "")
        if not todo:
            record_dataset()
        cluster = client = None
        engine, n_workers = "nothing to render", 0
        try:
            if todo:
                if scheduler:
                    client = _scheduler_client(Client, scheduler)
                    engine = f"scheduler {scheduler}"
                else:
                    with _interrupts_held() as held:
                        cluster, pinned = _local_cluster(workers, devices)
                        client = Client(cluster)
                    held.raise_if_any()  # the cluster is ours now: the except below closes it
                    engine = f"local cluster on device(s) {', '.join(pinned)}"
                n_workers = len(client.scheduler_info().get("workers", {}))
                log.note(f"{len(todo)} item(s) to render{again}, {len(items) - len(todo)} "
                         f"done or refused; {engine}, {n_workers} worker(s)")
                record_dataset()
                _run(client, out, todo, rows, log, len(items))
        except KeyboardInterrupt:
            log.end_line()
            with _quiet_dask():
                _close(client, cluster)
            client = cluster = None
            raise BatchInterrupted(_kept(out, items, rows)) from None
        finally:
            with _quiet_dask():
                _close(client, cluster)
        table = []
        for item in items:
            row = rows[item.id]
            row.setdefault("error", "")
            row["method"] = item.method
            row["options"] = item.options
            table.append(row)
        _write_results(out, table)
    return table, engine, n_workers


def _remove_if_unused(out: Path) -> None:
    """Remove the ``--out`` folder this run created when the run ended before writing anything
    into it (a scheduler that does not answer, a manifest error, ...), holding its lock: a
    folder that another batch holds (it made the folder too, at the same moment, and got the
    lock first) is its, and is left alone."""
    try:
        with _lock(out):
            names = {p.name for p in out.iterdir()}
            if names <= {LOCK, STAGING, PARTS} and not any(
                    (out / n).is_dir() and any((out / n).iterdir()) for n in (STAGING, PARTS)):
                shutil.rmtree(out, ignore_errors=True)
    except (OutputRefused, OSError):  # another batch holds it, or it is gone: left as it is
        pass


def _say_failed(log, row: dict) -> None:
    log.end_line()
    print(f"clholo batch: item {row['item']} failed: {row.get('error', '')}", file=log.stream,
          flush=True)


def _run(client, out: Path, todo: List[BatchItem], rows: Dict[str, dict], log,
         total: int) -> None:
    """Submit the items' tasks and wait for them, saying what happens: a line per finished
    item (with a bar: the bar), the error of a failed one, and, off a terminal, a line at least
    every ``log.interval`` seconds while items render."""
    futures = {}
    for item in todo:
        parts = [client.submit(_run_part, str(out), item, a, n, pure=False,
                               key=f"part-{item.id}-{a}-{uuid.uuid4().hex[:8]}")
                 for a, n in item.frame_ranges()] if item.split_frames else []
        fut = client.submit(_run_item, str(out), item, *parts, pure=False,
                            key=f"item-{item.id}-{uuid.uuid4().hex[:8]}")
        futures[fut] = item
    done = total - len(todo)
    t0 = time.perf_counter()
    pending = dict(futures)
    last_draw = -1.0
    while pending:
        finished = [f for f in pending if f.done()]
        for fut in finished:
            item = pending.pop(fut)
            try:
                result = fut.result()
            except Exception as exc:  # noqa: BLE001 - e.g. KilledWorker: record it
                result = {"item": item.id, "status": "failed",
                          "error": f"{type(exc).__name__}: {exc}"}
                _append_log(out, dict(result, event="failed", time=time.time()))
            if result["status"] == "skipped" and (out / item.id / RECORD).is_file():
                result.update(_record_row(out, item))
            rows[item.id] = result
            done += 1
            if result["status"] == "failed":
                _say_failed(log, result)
            elif log.mode == "lines":
                log.note(f"{item.id}: {result['status']} ({result.get('seconds', 0.0):.1f} s)")
        now = time.perf_counter()
        if finished or log.mode == "lines" or now - last_draw >= 1.0:
            log.progress(f"items ({len(pending)} to go)" if log.mode == "lines" else "items",
                         done, total, t0)
            last_draw = now
        if pending:
            time.sleep(0.1)


def _close(client, cluster) -> None:
    for thing in (client, cluster):
        if thing is not None:
            with contextlib.suppress(Exception):
                thing.close()


def _kept(out: Path, items: List[BatchItem], rows: Dict[str, dict]) -> str:
    """What an interrupted batch kept, in words."""
    complete = sum(item_status(out, i)[0] for i in items)
    before = sum(r.get("status") == "skipped" for r in rows.values())
    parts = len([p for p in (out / PARTS).glob("*/*") if _PART_FILE.match(p.name)]) \
        if (out / PARTS).is_dir() else 0
    text = (f"{complete} of {len(items)} item(s) complete in {out} ({before} of them before "
            f"this run)")
    if parts:
        text += f", {parts} finished frame range(s) of split items kept in {out / PARTS}"
    return text + "; run the same command again to render the rest (complete items are skipped)"
