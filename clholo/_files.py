"""Reading the small files clholo keeps for itself (output manifests, their sidecar records,
the tuning file) without trusting what lies at their names.

A user (or another program) can leave anything there: a named pipe, whose ``open`` for reading
waits for a writer forever; ``/dev/zero``, which reads until memory runs out; a file of
gigabytes. These are opened without blocking, checked to be regular files and read up to a
limit, and each problem is a :class:`ValueError` saying what the path is instead.
"""

from __future__ import annotations

import os
import stat
from pathlib import Path
from typing import Union

__all__ = ["read_small_file", "SMALL_FILE_LIMIT_BYTES"]

#: The largest of clholo's own bookkeeping files it reads (a manifest lists a folder's files;
#: a tuning file holds a few kB per device)
SMALL_FILE_LIMIT_BYTES = 64 << 20

_KINDS = ((stat.S_ISFIFO, "a named pipe"), (stat.S_ISCHR, "a character device"),
          (stat.S_ISBLK, "a block device"), (stat.S_ISSOCK, "a socket"),
          (stat.S_ISDIR, "a folder"))


def read_small_file(path: Union[str, os.PathLike], *,
                    limit: int = SMALL_FILE_LIMIT_BYTES) -> str:
    """The UTF-8 text of the regular file ``path``, at most ``limit`` bytes.

    Raises
    ------
    FileNotFoundError, PermissionError, OSError
        As ``open`` does (a missing file, a symbolic-link loop).
    ValueError
        ``path`` is not a regular file (a named pipe, a device, a socket, a folder: said
        which), is larger than ``limit``, or is not UTF-8.
    """
    # O_NONBLOCK: opening a named pipe for reading returns at once instead of waiting for a
    # writer; the checks below then refuse it before any read
    fd = os.open(os.fspath(path), os.O_RDONLY | getattr(os, "O_NONBLOCK", 0))
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):
            kind = next((name for test, name in _KINDS if test(st.st_mode)), "not a file")
            raise ValueError(f"{Path(path)} is {kind}, not a regular file")
        if st.st_size > limit:
            raise ValueError(f"{Path(path)} holds {st.st_size} bytes, more than the "
                             f"{limit} a file of this kind can")
        chunks, total = [], 0
        while True:  # read to the end, but never past the limit (a file that grows)
            block = os.read(fd, 1 << 20)
            if not block:
                break
            total += len(block)
            if total > limit:
                raise ValueError(f"{Path(path)} holds more than the {limit} bytes a file of "
                                 f"this kind can")
            chunks.append(block)
    finally:
        os.close(fd)
    return b"".join(chunks).decode("utf-8")
