"""Output folders that never destroy what the user has.

Every command that writes a folder (``clholo demo``, ``render``, and the ones after them) goes
through :func:`check_output_folder` *before* its work starts and :func:`output_folder` when it
writes, so that:

* an existing path is never replaced unless ``overwrite`` is asked for, and even then only when it
  is a folder that clholo itself wrote: recognised by the manifest :data:`MANIFEST_NAME` that
  :func:`output_folder` puts in every folder it writes (a regular file, a symbolic link, the current
  folder or one of its parents, or any folder without that manifest is refused, whatever the flag);
* a destination that cannot be created (missing or unwritable parent, a pseudo file system such as
  ``/proc``) is found out in a second, not after minutes of rendering;
* nothing is half-written: the folder is built under a temporary name beside the destination and
  renamed when complete (:func:`clholo.io.images.atomic_directory`).
"""

from __future__ import annotations

import contextlib
import json
import os
import tempfile
import time
from pathlib import Path
from typing import Iterator, Optional

from .images import PathLike, atomic_directory

__all__ = ["MANIFEST_NAME", "is_clholo_output", "check_output_folder", "output_folder"]

MANIFEST_NAME = "clholo-output.json"


def is_clholo_output(path: PathLike) -> bool:
    """True when ``path`` is a folder holding a manifest that clholo wrote."""
    manifest = Path(path) / MANIFEST_NAME
    try:
        data = json.loads(manifest.read_text())
    except (OSError, ValueError):
        return False
    return isinstance(data, dict) and str(data.get("written_by", "")).startswith("clholo")


def check_output_folder(path: PathLike, *, overwrite: bool = False,
                        option: str = "--out") -> Path:
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
    dest = Path(os.path.abspath(os.fspath(path)))
    cwd = Path(os.path.abspath(os.getcwd()))
    if dest == cwd or dest in cwd.parents:
        raise FileExistsError(
            f"{option} {path} is the current folder or one of its parents: clholo never replaces "
            f"those; give a new folder name, e.g. {option} clholo-out")
    if dest.is_symlink() or (dest.exists() and not dest.is_dir()):
        raise FileExistsError(
            f"{option} {dest} exists and is not a folder: clholo will not replace it; choose "
            f"another {option}")
    if dest.exists():
        if not is_clholo_output(dest):
            raise FileExistsError(
                f"{option} {dest} exists and is not a folder clholo wrote (it has no "
                f"{MANIFEST_NAME}): clholo will not replace it; choose another {option}")
        if not overwrite:
            raise FileExistsError(
                f"{option} {dest} already holds an earlier clholo output: choose another "
                f"{option}, or pass --overwrite (overwrite=True) to replace it")
    parent = dest.parent
    if not parent.is_dir():
        raise FileNotFoundError(
            f"cannot create {option} {dest}: its parent folder {parent} does not exist; create "
            f"it first")
    try:  # prove that a folder can be made there, as the real write will do
        probe = tempfile.mkdtemp(prefix=f".{dest.name}.", suffix=".probe", dir=str(parent))
        os.rmdir(probe)
    except OSError as exc:
        raise PermissionError(
            f"cannot create {option} {dest}: {parent} is not writable ({exc.strerror}); choose "
            f"a folder you can write to") from None
    return dest


@contextlib.contextmanager
def output_folder(path: PathLike, *, overwrite: bool = False, command: str = "",
                  option: str = "--out", details: Optional[dict] = None) -> Iterator[Path]:
    """Yield a temporary folder; on success it gets clholo's manifest and becomes ``path``.

    The same checks as :func:`check_output_folder` run again right before the rename (the
    destination may have appeared while the work ran). On an exception (Ctrl-C included) the
    temporary folder is removed and ``path`` is left as it was.
    """
    dest = check_output_folder(path, overwrite=overwrite, option=option)
    with atomic_directory(dest, overwrite=True) as tmp:
        yield tmp
        manifest = {"written_by": f"clholo {_version()}", "command": command,
                    "written_at": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
                    "files": sorted(p.name for p in tmp.iterdir())}
        if details:
            manifest.update(details)
        (tmp / MANIFEST_NAME).write_text(json.dumps(manifest, indent=1))
        check_output_folder(dest, overwrite=overwrite, option=option)


def _version() -> str:
    from clholo import __version__

    return __version__
