"""Output folders that never destroy what the user has.

Every command that writes a folder (``clholo demo``, ``render``, and the ones after them) goes
through :func:`check_output_folder` *before* its work starts and :func:`output_folder` when it
writes, so that:

* an existing path is never replaced unless ``overwrite`` is asked for, and even then only when it
  is a folder that clholo itself wrote: recognised by the manifest :data:`MANIFEST_NAME` that
  :func:`output_folder` puts in every folder it writes (a regular file, a symbolic link, the current
  folder or one of its parents, or any folder without that manifest is refused, whatever the flag);
  an empty folder (``mkdir out`` first) is taken as a new destination: replacing it destroys
  nothing;
* a destination that cannot be created (missing or unwritable parent, a pseudo file system such as
  ``/proc``) is found out in a second, not after minutes of rendering;
* ``overwrite`` replaces a folder only when everything inside it is listed in its manifest:
  a file the user added inside an earlier output is never deleted (the error names it);
* the manifest records the SHA-256 of every file clholo wrote (``"sha256"``: relative path ->
  digest), and ``overwrite`` also refuses a folder in which any of them changed since (a note
  appended to ``summary.json`` is the user's work too; the error names the file);
* nothing is half-written: the folder is built under a temporary name beside the destination and
  renamed when complete (:func:`clholo.io.images.atomic_directory`); the temporary folder is
  locked while it is written, and one that a killed run (SIGKILL, power loss) left beside the
  same destination is removed by the next write of it
  (:func:`clholo.io.images.remove_abandoned_temporaries`);
* two clholo processes (or threads) writing the same destination at once never both "win": the
  last checks and the rename run holding a lock on the destination's folder (:func:`_locked`),
  so one of them is refused with an error that names the path, and a destination that another
  run wrote (or replaced) while this one worked is never replaced without a word, even with
  ``overwrite`` (which replaces what was there when the write began).

Single files (an HTML report, a display log, a JSON report) follow the same policy through
:func:`check_output_file` and :func:`output_file`: clholo records each file it writes in a small
sidecar, ``.NAME.clholo-output.json`` beside it, holding the file's SHA-256; ``overwrite``
replaces a file only when that record exists and the file is still exactly what clholo wrote.
A file the user made, or edited since, is never replaced. The file and its record are renamed
into place together under the same lock, so they always match.

Every refusal raises :class:`clholo.errors.OutputRefused` (a ``FileExistsError``),
``FileNotFoundError`` for a missing parent folder, or ``PermissionError``.
"""

from __future__ import annotations

import contextlib
import json
import os
import tempfile
import threading
import time
from pathlib import Path
from typing import Iterator, Optional

from .._files import read_small_file
from ..errors import OutputRefused
from .images import PathLike, atomic_directory, creation_failure

__all__ = ["MANIFEST_NAME", "is_clholo_output", "why_not_clholo_output", "foreign_entries",
           "changed_entries",
           "check_output_folder", "output_folder", "update_manifest", "is_clholo_file",
           "check_output_file", "output_file", "destination_state", "listed_entries"]

MANIFEST_NAME = "clholo-output.json"


def is_clholo_output(path: PathLike) -> bool:
    """True when ``path`` is a folder holding a manifest that clholo wrote."""
    manifest = Path(path) / MANIFEST_NAME
    try:
        data = json.loads(read_small_file(manifest))
    except (OSError, ValueError, RecursionError):
        return False
    return isinstance(data, dict) and str(data.get("written_by", "")).startswith("clholo")


def why_not_clholo_output(path: PathLike) -> str:
    """Why ``path`` does not count as a clholo output folder, for refusals: it has no
    manifest, or one that is not clholo's (unreadable, not JSON, edited)."""
    manifest = Path(path) / MANIFEST_NAME
    if not (manifest.exists() or manifest.is_symlink()):
        return f"it has no {MANIFEST_NAME}"
    try:
        text = read_small_file(manifest)
    except ValueError as exc:  # a named pipe, a device, too large, not UTF-8
        return f"its {MANIFEST_NAME} cannot be read ({exc})"
    except OSError as exc:
        return f"its {MANIFEST_NAME} cannot be read ({exc.strerror or exc})"
    try:
        data = json.loads(text)
    except (ValueError, RecursionError):
        return f"its {MANIFEST_NAME} is not valid JSON: edited or cut short"
    if not isinstance(data, dict) or not str(data.get("written_by", "")).startswith("clholo"):
        return f"its {MANIFEST_NAME} does not say clholo wrote it"
    return f"its {MANIFEST_NAME} is clholo's"  # pragma: no cover - only asked when refused


def _manifest(path: Path) -> Optional[dict]:
    try:
        data = json.loads(read_small_file(Path(path) / MANIFEST_NAME))
    except (OSError, ValueError, RecursionError):
        return None
    return data if isinstance(data, dict) else None


def foreign_entries(path: PathLike) -> list:
    """Names inside a clholo output folder that its manifest does not list (what the user
    added), sorted; empty for a folder holding only what clholo wrote."""
    path = Path(path)
    data = _manifest(path) or {}
    listed = set(data.get("files", [])) | {MANIFEST_NAME}
    try:
        names = sorted(p.name for p in path.iterdir())
    except OSError:
        return []
    return [n for n in names if n not in listed]


def _digests(folder: Path, names) -> dict:
    """SHA-256 of every regular file among the entries ``names`` of ``folder`` and inside those
    that are folders, by path relative to ``folder`` (``/``-separated); links are skipped."""
    digests = {}
    for name in names:
        entry = folder / name
        if entry.is_symlink():
            continue
        files = [entry] if entry.is_file() else sorted(entry.rglob("*")) if entry.is_dir() else []
        for f in files:
            if f.is_file() and not f.is_symlink():
                digests[f.relative_to(folder).as_posix()] = _sha256(f)
    return digests


def changed_entries(path: PathLike) -> list:
    """Files of a clholo output folder that changed since clholo wrote them (their SHA-256 is
    not the one its manifest records, or they were replaced by a folder or a link), sorted.
    A file the user deleted is not listed (replacing the folder loses nothing of theirs); a
    manifest without checksums (written before they were recorded) lists nothing."""
    path = Path(path)
    data = _manifest(path) or {}
    digests = data.get("sha256")
    if digests is None:
        return []
    if not isinstance(digests, dict) or not all(isinstance(v, str) for v in digests.values()):
        # checksums edited into something else: nothing proves the files are clholo's as
        # written, so every listed file that is there counts as changed (none is lost)
        listed = data.get("files") if isinstance(data.get("files"), list) else []
        return sorted(str(n) for n in listed if (path / str(n)).exists())
    changed = []
    for rel, digest in digests.items():
        f = path / rel
        if not (f.exists() or f.is_symlink()):
            continue
        try:
            same = f.is_file() and not f.is_symlink() and _sha256(f) == digest
        except OSError:
            same = False
        if not same:
            changed.append(rel)
    return sorted(changed)


def update_manifest(path: PathLike, *, add=()) -> None:
    """List further entries (``add``: names inside ``path``) in the manifest of a clholo output
    folder, with their checksums, for commands that add to their folder after it was installed
    (``clholo batch``, ``clholo report``).

    The manifest is read, changed and written holding the lock that :func:`output_folder` takes
    to replace ``path`` (:func:`_locked`), so two processes adding to one folder at once both
    keep their entries, and a folder being replaced is never half-updated.

    Raises
    ------
    FileNotFoundError
        ``path`` has no manifest, or an entry of ``add`` is not in it (removed, or the folder
        replaced by another run meanwhile): the manifest never lists a file that is not there.
    """
    path = Path(path)
    from .images import atomic_path

    with _locked(path.parent):
        data = _manifest(path)
        if data is None:
            raise FileNotFoundError(f"{path} has no {MANIFEST_NAME}: not a clholo output folder")
        added = {str(n) for n in add}
        missing = sorted(n for n in added if not ((path / n).exists() or (path / n).is_symlink()))
        if missing:
            raise FileNotFoundError(
                f"{path} holds no {_shown(missing)} to list in its {MANIFEST_NAME}: it was "
                f"removed, or the folder replaced by another clholo run, since it was written; "
                f"run the command again")
        data["files"] = sorted(set(data.get("files", [])) | added)
        if isinstance(data.get("sha256"), dict):
            kept = {rel: d for rel, d in data["sha256"].items()
                    if rel.split("/", 1)[0] not in added}
            data["sha256"] = dict(sorted({**kept, **_digests(path, added)}.items()))
        try:
            with atomic_path(path / MANIFEST_NAME) as tmp:
                tmp.write_text(json.dumps(data, indent=1))
        except OSError as exc:
            if exc.filename is not None:
                raise
            # a full disk said without a path ("[Errno 28] No space left on device"): the
            # manifest is what could not be written
            raise OSError(exc.errno, exc.strerror, str(path / MANIFEST_NAME)) from None


def listed_entries(path: PathLike) -> set:
    """The names the manifest of the clholo output folder ``path`` lists (empty where it has
    none, or one that is not clholo's)."""
    data = _manifest(Path(path))
    files = data.get("files", []) if data is not None else []
    return {str(n) for n in files} if isinstance(files, list) else set()


# the folders this thread holds _locked on: a second flock from the same thread on another
# descriptor of the same folder would wait for itself
_held = threading.local()


@contextlib.contextmanager
def _locked(folder: Path) -> Iterator[None]:
    """Hold an exclusive lock on ``folder`` (``flock`` on the folder itself: no lock file is
    left anywhere) while a destination in it is checked and renamed, so that two clholo
    processes, or two threads, writing there take turns. Where locks are not available (not
    POSIX, or a file system without them) the checks and the rename run as before, unlocked.
    A thread that holds it already goes on (the lock is re-entrant per thread).
    """
    held = _held.__dict__.setdefault("folders", set())
    key = os.path.realpath(folder)
    if key in held:
        yield
        return
    try:
        import fcntl
    except ImportError:  # pragma: no cover - Windows: its rename refuses an existing folder
        yield
        return
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:  # the caller's own checks name the folder that cannot be opened
        yield
        return
    try:
        with contextlib.suppress(OSError):  # a file system without locks: unlocked, as before
            _wait_for_lock(fd, fcntl)
        held.add(key)
        yield
    finally:
        held.discard(key)
        os.close(fd)  # releases the lock


@contextlib.contextmanager
def unchanged_folder(path: PathLike, seen: Optional[tuple], *, command: str) -> Iterator[None]:
    """Run the block (writing into the clholo output folder ``path``) holding the lock that
    :func:`output_folder` takes to replace ``path``, after checking that ``path`` is still the
    folder that was there when the command read it (``seen``: :func:`destination_state`).

    For commands that read a folder and then add to it (``clholo report``): had another run
    replaced the folder meanwhile, what they add would describe files that are no longer there.

    Raises
    ------
    clholo.errors.OutputRefused
        ``path`` was replaced (or removed) since ``seen`` was taken; nothing is written.
    """
    path = Path(path)
    with _locked(path.parent):
        if _identity(path) != seen:
            raise OutputRefused(
                f"{path} was replaced by another clholo run while {command} read it: what "
                f"{command} made describes the folder that was there, so it is not written "
                f"into the new one; run {command} again")
        yield


def _wait_for_lock(fd: int, fcntl) -> None:
    """Take the exclusive lock on ``fd``, waiting for another process or thread that holds it
    (it holds it only while it checks and renames)."""
    fcntl.flock(fd, fcntl.LOCK_EX)


def _identity(path: Path) -> Optional[tuple]:
    """What is at ``path`` now (its device and inode), or None: a destination that another run
    wrote or replaced meanwhile is another one."""
    try:
        st = os.lstat(path)
    except OSError:
        return None
    return st.st_dev, st.st_ino


def destination_state(path: PathLike) -> Optional[tuple]:
    """What is at ``path`` now, for :func:`output_folder`'s ``expect``: a command that checks
    its output before minutes of work takes this with that check, so that an output another
    run writes there meanwhile is refused at the rename, not replaced by ``overwrite``."""
    return _identity(Path(path))


#: ``expect`` not given: what is at the destination when the write begins
_WHEN_WRITING = object()


def _check_unchanged(dest: Path, seen: Optional[tuple], option: str) -> None:
    """Refuse to replace ``dest`` when it is not what was there (``seen``) when the write began:
    another clholo run wrote or replaced it meanwhile, and its output is not deleted unseen."""
    now = _identity(dest)
    if now is not None and now != seen:
        raise OutputRefused(
            f"{option} {dest} was written by another clholo run while this one worked: clholo "
            f"will not replace it unseen; look at it, then run again (with "
            f"{_overwrite_word(option)} to replace it), or choose another {option}")


def _example(option: str, value: str) -> str:
    """How a user gives ``value`` for the destination: ``--out run1`` on the command line,
    ``folder='run1'`` in Python (``option`` names the destination in refusals)."""
    return f"{option} {value}" if option.startswith("--") else f"{option}={value!r}"


def _flag(overwrite) -> bool:
    """``overwrite`` as a bool: ``"no"`` would replace a folder as ``True`` does."""
    from clholo import validate

    return validate.flag(overwrite, name="overwrite")


def _overwrite_word(option: str) -> str:
    """The switch that allows a replacement, in the caller's language."""
    return "--overwrite" if option.startswith("--") else "overwrite=True"


def _overwrite(option: str) -> str:
    # the command line's refusal names both: its commands share their checks with the API
    return "--overwrite (overwrite=True)" if option.startswith("--") else "overwrite=True"


def _check_parent(dest: Path, option: str) -> None:
    parent = dest.parent
    if not parent.is_dir():
        raise FileNotFoundError(
            f"cannot create {option} {dest}: its parent folder {parent} does not exist; create "
            f"it first")
    try:  # prove that something can be made there, as the real write will do
        probe = tempfile.mkdtemp(prefix=f".{dest.name}.", suffix=".probe", dir=str(parent))
        os.rmdir(probe)
    except OSError as exc:
        failure = creation_failure(dest, parent, exc, f"cannot create {option}")
        if failure is not None:
            raise failure from None
        raise PermissionError(
            f"cannot create {option} {dest}: {parent} is not writable ({exc.strerror}); choose "
            f"a folder you can write to") from None


def check_output_folder(path: PathLike, *, overwrite: bool = False,
                        option: str = "--out", inputs=()) -> Path:
    """Refuse, before any work, an output folder that would destroy data or cannot be written.

    Parameters
    ----------
    path : path-like
        The folder to create.
    overwrite : bool
        Allow replacing an existing folder *that clholo wrote* (see the module docstring).
    option : str
        How the caller names the destination in its messages (``--out`` on the command line,
        ``out_dir`` in Python).
    inputs : sequence of path-like
        The command's input files or folders: replacing a folder that holds one of them
        would delete what the command reads (``clholo encode run/hologram.npz --out run
        --overwrite``), so that is refused.

    Returns
    -------
    pathlib.Path
        The absolute, normalised destination.

    Raises
    ------
    FileExistsError
        The destination exists and may not be replaced.
    FileNotFoundError
        Its parent folder does not exist.
    PermissionError
        Its parent folder cannot be written to.
    """
    overwrite = _flag(overwrite)
    if not os.fspath(path).strip():  # abspath('') is the current folder: name the slip
        raise OutputRefused(f"{option} is empty: give a new folder name, e.g. "
                            f"{_example(option, 'clholo-out')}")
    dest = Path(os.path.abspath(os.fspath(path)))
    cwd = Path(os.path.abspath(os.getcwd()))
    if dest == cwd or dest in cwd.parents:
        raise OutputRefused(
            f"{option} {path} is the current folder or one of its parents: clholo never replaces "
            f"those; give a new folder name, e.g. {_example(option, 'clholo-out')}")
    if dest.is_symlink() or (dest.exists() and not dest.is_dir()):
        raise OutputRefused(
            f"{option} {dest} exists and is not a folder: clholo will not replace it; choose "
            f"another {option}")
    if dest.exists() and not _empty_folder(dest, option):
        if not is_clholo_output(dest):
            raise OutputRefused(
                f"{option} {dest} exists and is not a folder clholo wrote "
                f"({why_not_clholo_output(dest)}): clholo will not replace it; choose another "
                f"{option}")
        if not overwrite:
            raise OutputRefused(
                f"{option} {dest} already holds an earlier clholo output: choose another "
                f"{option}, or pass {_overwrite(option)} to replace it")
        foreign = foreign_entries(dest)
        if foreign:
            raise OutputRefused(
                f"{option} {dest} holds {_shown(foreign)}, which clholo did not write: "
                f"{_overwrite_word(option)} would delete it, so clholo will not; move it out "
                f"first, or choose another {option}")
        for given in inputs:
            inside = Path(os.path.abspath(os.fspath(given)))
            if inside == dest or dest in inside.parents:
                raise OutputRefused(
                    f"{option} {dest} holds this command's input {given}: "
                    f"{_overwrite_word(option)} would delete it with the folder; choose another "
                    f"{option}")
        changed = changed_entries(dest)
        if changed:
            raise OutputRefused(
                f"{option} {dest} holds {_shown(changed)}, which changed since clholo wrote it: "
                f"{_overwrite_word(option)} would replace it, so clholo will not; move it out "
                f"first, or choose another {option}")
    _check_parent(dest, option)
    return dest


def _empty_folder(dest: Path, option: str) -> bool:
    """True for an empty folder (``mkdir out`` before ``--out out``): replacing it destroys
    nothing, so it is taken as a new destination. The check runs again before the rename, so
    a file put there meanwhile makes it a folder clholo did not write, refused then. A mount
    point cannot be replaced (a rename over it fails after the work): refused now."""
    try:
        with os.scandir(dest) as entries:
            if next(entries, None) is not None:
                return False
    except OSError:
        return False
    if os.path.ismount(dest):
        raise OutputRefused(
            f"{option} {dest} is a mount point: clholo writes an output under a temporary name "
            f"and renames it, which cannot replace a mount point; give a folder inside it, e.g. "
            f"{_example(option, str(dest / 'clholo-out'))}")
    return True


def _shown(names: list) -> str:
    return ", ".join(names[:3]) + (f" and {len(names) - 3} more" if len(names) > 3 else "")


@contextlib.contextmanager
def output_folder(path: PathLike, *, overwrite: bool = False, command: str = "",
                  option: str = "--out", details: Optional[dict] = None,
                  expect=_WHEN_WRITING) -> Iterator[Path]:
    """Yield a temporary folder; on success it gets clholo's manifest and becomes ``path``.

    The same checks as :func:`check_output_folder` run again right before the rename (the
    destination may have appeared while the work ran), holding a lock on the destination's
    folder until the rename is done, so that of two runs writing ``path`` at once one is
    refused; a ``path`` that another run wrote or replaced after this one began is refused
    too, even with ``overwrite``. On an exception (Ctrl-C included) the temporary folder is
    removed and ``path`` is left as it was.

    Parameters
    ----------
    path : str or os.PathLike
        The folder to make.
    overwrite : bool
        Replace an existing ``path`` that clholo wrote (never one it did not write).
    command : str
        The command recorded in the manifest.
    option : str
        The option named in refusals (``--out``).
    details : dict, optional
        Recorded in the manifest.
    expect : tuple or None, optional
        :func:`destination_state` of ``path`` when the command began (taken with its first
        check, before the work): ``overwrite`` replaces only that, and an output another run
        wrote there since is refused. Default: what is there when this write begins.
    """
    if expect is not _WHEN_WRITING and not (expect is None or (
            isinstance(expect, tuple) and len(expect) == 2
            and all(isinstance(v, int) for v in expect))):
        raise TypeError(f"expect is {expect!r}; give destination_state(path) taken when the "
                        f"command began, or leave it unset")
    dest = check_output_folder(path, overwrite=overwrite, option=option)
    # what overwrite may replace: another run's output is not it
    seen = _identity(dest) if expect is _WHEN_WRITING else expect
    with contextlib.ExitStack() as lock:  # released after the rename, not before
        with atomic_directory(dest, overwrite=True) as tmp:
            yield tmp
            names = sorted(p.name for p in tmp.iterdir())
            manifest = {"written_by": f"clholo {_version()}", "command": command,
                        "written_at": time.strftime("%Y-%m-%dT%H:%M:%S%z"), "files": names}
            if details:
                manifest.update(details)
            manifest["sha256"] = _digests(tmp, names)  # what --overwrite checks nobody changed
            (tmp / MANIFEST_NAME).write_text(json.dumps(manifest, indent=1))
            lock.enter_context(_locked(dest.parent))
            check_output_folder(dest, overwrite=overwrite, option=option)
            _check_unchanged(dest, seen, option)


def _sidecar(path: Path) -> Path:
    return path.with_name(f".{path.name}.{MANIFEST_NAME}")


def _sha256(path: Path) -> str:
    import hashlib

    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def is_clholo_file(path: PathLike) -> bool:
    """True when ``path`` is a file that clholo wrote and nobody has changed since (its sidecar
    record exists and holds the file's SHA-256)."""
    path = Path(path)
    try:
        record = json.loads(read_small_file(_sidecar(path)))
    except (OSError, ValueError, RecursionError):
        return False
    if not isinstance(record, dict) or not path.is_file() or path.is_symlink():
        return False
    try:
        return record.get("sha256") == _sha256(path)
    except OSError:
        return False


# what each single-file option writes, for the example name in a refusal
_FILE_SUFFIX = {"--json": ".json", "--log": ".csv", "--out": ".html"}


def check_output_file(path: PathLike, *, overwrite: bool = False, option: str = "--out") -> Path:
    """Refuse, before any work, an output file that would destroy data or cannot be written
    (the single-file form of :func:`check_output_folder`; same errors)."""
    overwrite = _flag(overwrite)
    if not os.fspath(path).strip():  # abspath('') is the current folder: name the slip
        raise OutputRefused(f"{option} is empty: give a file name, e.g. "
                            f"{_example(option, 'clholo-out' + _FILE_SUFFIX.get(option, ''))}")
    dest = Path(os.path.abspath(os.fspath(path)))
    if dest.is_dir() and not dest.is_symlink():
        suffix = Path(os.fspath(path)).suffix or _FILE_SUFFIX.get(option, "")
        raise OutputRefused(
            f"{option} {dest} is a folder; give a file name, e.g. "
            f"{_example(option, str(dest / ('clholo-out' + suffix)))}")
    if dest.is_symlink() or dest.exists():
        if not is_clholo_file(dest):
            why = ("a file clholo did not write, or one changed since" if dest.is_file()
                   else "not a regular file")
            raise OutputRefused(
                f"{option} {dest} exists and is {why}: clholo will not replace it; choose "
                f"another {option}")
        if not overwrite:
            raise OutputRefused(
                f"{option} {dest} already holds an earlier clholo output: choose another "
                f"{option}, or pass {_overwrite(option)} to replace it")
    _check_parent(dest, option)
    return dest


@contextlib.contextmanager
def output_file(path: PathLike, *, overwrite: bool = False, command: str = "",
                option: str = "--out") -> Iterator[Path]:
    """Yield a temporary file name beside ``path`` (same extension); when the block succeeds,
    the same checks as :func:`check_output_file` run again, the file is renamed to ``path`` and
    its sidecar record is written, all holding a lock on the folder (as
    :func:`output_folder`: of two runs writing ``path`` at once, one is refused, and a file
    another run wrote there after this one began is not replaced unseen). On an exception
    nothing at ``path`` changes."""
    from .images import atomic_path

    dest = check_output_file(path, overwrite=overwrite, option=option)
    seen = _identity(dest)
    with contextlib.ExitStack() as lock:  # the file and its record renamed under one lock
        with atomic_path(dest) as tmp:
            yield tmp
            record = {"written_by": f"clholo {_version()}", "command": command,
                      "written_at": time.strftime("%Y-%m-%dT%H:%M:%S%z"), "file": dest.name,
                      "sha256": _sha256(tmp)}
            lock.enter_context(_locked(dest.parent))
            check_output_file(dest, overwrite=overwrite, option=option)
            _check_unchanged(dest, seen, option)
            sidecar = _sidecar(dest)
            with atomic_path(sidecar) as side_tmp:
                side_tmp.write_text(json.dumps(record, indent=1))


def _version() -> str:
    from clholo._version import __version__

    return __version__
