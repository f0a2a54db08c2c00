"""NumPy ``.npy`` files and ``.npz`` archives read by clholo: one place that checks a file
before NumPy allocates what its header claims, and turns every way the file can be damaged
into an :class:`~clholo.errors.InputError` naming it.

``numpy.load`` trusts the header: a 200-byte file whose header says ``(100000, 100000)``
asks for 37 GiB ("Unable to allocate", read as this machine's fault), a header with one byte
changed raises ``tokenize.TokenError`` (an internal error), a file cut short says "Failed to
read all data" without its name, and a file longer than its header says is read without a
word. Here the header is parsed with :mod:`numpy.lib.format`, the bytes it claims are compared
with the bytes stored (the file's size, or the archive member's) before anything is read, and
only then does :func:`numpy.lib.format.read_array` read the data, as ``numpy.load`` does: a
good file gives the same array, bit for bit (dtype, byte order, Fortran order).
"""

from __future__ import annotations

import io
import math
import os
import stat
import struct
import tokenize
import zipfile
import zlib
from pathlib import Path
from typing import BinaryIO, List, Tuple

import numpy as np

from clholo.errors import InputError

from .images import PathLike, check_input_file

__all__ = ["load_npy", "open_npz", "NpzArchive", "NPY_MAGIC"]

#: The first six bytes of every ``.npy`` file (``numpy.lib.format.MAGIC_PREFIX``).
NPY_MAGIC = b"\x93NUMPY"

# What numpy.lib.format raises for a header it cannot parse: ValueError for most; one changed
# byte can also give SyntaxError or tokenize.TokenError (the header is Python literal text),
# OverflowError, UnicodeDecodeError (a version 3.0 header is UTF-8), EOFError, struct.error,
# TypeError or RecursionError (a descriptor nested thousands deep)
_HEADER_ERRORS = (ValueError, SyntaxError, tokenize.TokenError, OverflowError,
                  UnicodeDecodeError, EOFError, struct.error, TypeError, RecursionError,
                  KeyError, IndexError)

# What reading an archive's members can raise for a damaged archive: a bad CRC or local header
# (BadZipFile), a broken deflate stream (zlib.error), an encrypted member (RuntimeError), a
# compression method this Python lacks (NotImplementedError), a cut-off member (EOFError)
_ZIP_ERRORS = (zipfile.BadZipFile, zlib.error, EOFError, RuntimeError, NotImplementedError,
               OSError, ValueError, struct.error)

# Deflate cannot expand its input more than about 1032 times: a member whose stated size is
# larger than that for its compressed bytes has a damaged (or forged) directory entry
_MAX_DEFLATE_RATIO = 1100


def _header(fp: BinaryIO, source: str, fix: str) -> Tuple[tuple, bool, np.dtype, int]:
    """The ``(shape, fortran_order, dtype, header_bytes)`` of the ``.npy`` stream ``fp`` (at
    its start), or an :class:`InputError` naming ``source``."""
    fmt = np.lib.format
    head = fp.read(len(NPY_MAGIC))
    if head != NPY_MAGIC:
        what = ("an .npz archive" if head[:2] == b"PK" else "not a NumPy .npy file")
        raise InputError(f"{source} is {what}: {fix}")
    try:
        fp.seek(0)
        version = fmt.read_magic(fp)
        if version == (1, 0):
            shape, fortran, dtype = fmt.read_array_header_1_0(fp)
        elif version == (2, 0):
            shape, fortran, dtype = fmt.read_array_header_2_0(fp)
        elif version == (3, 0):
            # 3.0 is 2.0 with a UTF-8 header (structured dtypes with non-Latin-1 field
            # names); NumPy reads it with a private function, so it is checked as UTF-8 here
            # and parsed as 2.0: Latin-1 maps its bytes one to one, so sizes are unchanged
            length = fp.read(4)
            text = fp.read(struct.unpack("<I", length)[0] if len(length) == 4 else 0)
            text.decode("utf-8")
            shape, fortran, dtype = fmt.read_array_header_2_0(io.BytesIO(length + text))
        else:
            raise ValueError(f"format version {version[0]}.{version[1]}, which NumPy does not "
                             f"write")
        end = fp.tell()
    except _HEADER_ERRORS as exc:
        # TokenError's text is a tuple ("('EOF in multi-line statement', (3, 0))")
        text = exc.args[0] if isinstance(exc, tokenize.TokenError) and exc.args else exc
        why = " ".join(str(text).split())[:200] or type(exc).__name__
        raise InputError(f"{source} has a damaged .npy header ({why}): the file was edited or "
                         f"is corrupt; {fix}") from None
    if dtype.hasobject:
        # numpy.load would unpickle these (allow_pickle=True), running code from the file
        raise InputError(f"{source} is not a NumPy array of numbers (it holds Python objects, "
                         f"dtype {dtype}, which clholo never unpickles): {fix}")
    if dtype.itemsize == 0:
        raise InputError(f"{source} holds elements of 0 bytes (dtype {dtype}), no values: "
                         f"{fix}")
    if any(n < 0 for n in shape):
        raise InputError(f"{source} has a damaged .npy header (shape {tuple(shape)} has a "
                         f"negative length): the file was edited or is corrupt; {fix}")
    return tuple(shape), bool(fortran), dtype, end


def _check_size(source: str, shape: tuple, dtype: np.dtype, stored: int) -> None:
    """Refuse a header whose shape and dtype need other than the ``stored`` bytes after it:
    before this, NumPy allocated what a damaged header claimed (terabytes), or read a prefix
    of a longer file (frames dropped without a word)."""
    need = math.prod(shape) * dtype.itemsize  # Python integers: no overflow
    if need == stored:
        return
    what = f"its header says shape {shape} of {dtype} ({need} bytes)"
    if stored < need:
        raise InputError(f"{source} is truncated or its header is damaged: {what} but only "
                         f"{stored} bytes follow it; write the file again")
    raise InputError(f"{source} is longer than its header says: {what} but {stored} bytes "
                     f"follow it; the file was edited or is corrupt: write it again")


def _open_regular(path: Path, what: str, fix: str) -> BinaryIO:
    """``path`` opened for reading once it is known to be a regular file: named pipes and
    devices are refused from their ``stat`` (opening a pipe waits for a writer; ``/dev/zero``
    never ends), and checked again on the open file, without blocking, in case the path
    changed in between."""
    path = check_input_file(path, what, fix)
    fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0))
    try:
        if not stat.S_ISREG(os.fstat(fd).st_mode):
            check_input_file(path, what, fix)  # says what it is now
            raise InputError(f"{what} {path} is not a regular file: {fix}")
        if hasattr(os, "set_blocking"):
            os.set_blocking(fd, True)
        return os.fdopen(fd, "rb")
    except BaseException:
        os.close(fd)
        raise


def load_npy(path: PathLike, *, what: str, fix: str) -> np.ndarray:
    """The array of the ``.npy`` file ``path``, as ``numpy.load(path, allow_pickle=False)``
    gives it, after checks that name the file.

    Parameters
    ----------
    path : str or os.PathLike
        The file.
    what : str
        What the file is, starting each message (``"depth file"``, ``"--patterns"``).
    fix : str
        What to give instead, ending each message about a file that is not a ``.npy`` of
        numbers (``"save 256 phases in radians with numpy.save (float64)"``).

    Returns
    -------
    ndarray
        The stored array (its dtype, byte order and memory order as stored).

    Raises
    ------
    FileNotFoundError
        ``path`` does not exist.
    clholo.errors.InputError
        ``path`` is not a regular file (a folder, a named pipe, a device), not a ``.npy``
        file (an ``.npz`` archive, text), its header is damaged, it holds Python objects, or
        it holds fewer or more bytes than its header says (truncated, edited).
    """
    source = f"{what} {path}"
    with _open_regular(Path(path), what, fix) as fh:
        shape, _, dtype, end = _header(fh, source, fix)
        _check_size(source, shape, dtype, os.fstat(fh.fileno()).st_size - end)
        fh.seek(0)
        try:
            return np.lib.format.read_array(fh, allow_pickle=False)
        except (ValueError, OSError) as exc:  # changed while read: it was checked above
            raise InputError(f"{source} cannot be read ({exc}); write it again") from None


class NpzArchive:
    """An ``.npz`` archive open for reading (:func:`open_npz`): its array names, and each
    array read with the checks of :func:`load_npy`.

    Attributes
    ----------
    files : list of str
        The names of its arrays (member names without ``.npy``, as ``numpy.load`` lists them).
    """

    def __init__(self, fh: BinaryIO, zf: zipfile.ZipFile, size: int, source: str, fix: str):
        self._file, self._zip, self._size = fh, zf, size
        self._source, self._fix = source, fix
        self._members = {(n[:-4] if n.endswith(".npy") else n): n for n in zf.namelist()}
        self.files: List[str] = list(self._members)

    def __enter__(self) -> "NpzArchive":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        """Close the archive (and its file: ZipFile leaves a file object it was given open)."""
        self._zip.close()
        self._file.close()

    def __contains__(self, name: str) -> bool:
        return name in self._members

    def load(self, name: str) -> np.ndarray:
        """The array ``name`` (one of :attr:`files`).

        Raises
        ------
        KeyError
            No array of that name.
        clholo.errors.InputError
            The member is damaged, truncated, longer than its header says, not a ``.npy``,
            or holds Python objects; the message names the archive and the array.
        """
        member = self._members[name]
        source = f"{self._source}: its array '{name}'"
        info = self._zip.getinfo(member)
        # The directory's sizes are checked against the archive before they are trusted:
        # a stored member holds exactly its bytes, a deflated one at most ~1032 times more
        if info.header_offset + info.compress_size > self._size or (
                info.compress_type == zipfile.ZIP_STORED
                and info.file_size != info.compress_size) or (
                info.compress_type == zipfile.ZIP_DEFLATED
                and info.file_size > _MAX_DEFLATE_RATIO * info.compress_size + 1024):
            raise InputError(f"{source} is truncated or corrupt (its entry in the archive says "
                             f"{info.file_size} bytes, {info.compress_size} stored, in a file "
                             f"of {self._size}); write the file again")
        try:
            with self._zip.open(member) as fp:
                shape, _, dtype, end = _header(fp, source, self._fix)
            _check_size(source, shape, dtype, info.file_size - end)
            with self._zip.open(member) as fp:
                return np.lib.format.read_array(fp, allow_pickle=False)
        except InputError:
            raise
        except _ZIP_ERRORS as exc:
            # zipfile checks the CRC when the last byte is read: a changed byte lands here
            raise InputError(f"{source} is truncated or corrupt ({exc}); write the file "
                             f"again") from None


def open_npz(path: PathLike, *, what: str, fix: str) -> NpzArchive:
    """The ``.npz`` archive ``path``, open for reading its arrays one by one
    (:meth:`NpzArchive.load`); use it as a context manager.

    Parameters
    ----------
    path : str or os.PathLike
        The archive.
    what : str
        What the file is, starting each message (``"hologram file"``); ``""`` starts them with
        the path alone.
    fix : str
        What to give instead, ending messages about an archive that is not one of arrays.

    Raises
    ------
    FileNotFoundError
        ``path`` does not exist.
    clholo.errors.InputError
        ``path`` is not a regular file, or not a complete zip archive (truncated, corrupt).
    """
    path = Path(path)
    source = f"{what} {path}" if what else str(path)
    fh = _open_regular(path, what or "file", fix)
    try:
        size = os.fstat(fh.fileno()).st_size
        zf = zipfile.ZipFile(fh)
    except _ZIP_ERRORS as exc:
        fh.close()
        # zipfile's own error for a cut-off archive (its directory, stored last, is gone)
        # names neither the file nor the cause
        raise InputError(f"{source} is truncated or corrupt (not a complete .npz archive: "
                         f"{exc}); write it again") from None
    except BaseException:
        fh.close()
        raise
    return NpzArchive(fh, zf, size, source, fix)
