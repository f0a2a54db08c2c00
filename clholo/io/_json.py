"""JSON text read by :mod:`clholo.io`: one place that turns every way a file can fail to be
JSON into a ``ValueError`` naming the file (Python's reader raises ``RecursionError``, not
``JSONDecodeError``, for arrays or objects nested thousands deep)."""

from __future__ import annotations

import json

__all__ = ["parse_json", "read_json", "JSON_ERRORS"]

#: What ``json.loads`` raises for text that is not JSON it can read (``UnicodeDecodeError`` is
#: what reading a file's bytes as UTF-8 raises first; ``RecursionError``: nested too deeply).
JSON_ERRORS = (json.JSONDecodeError, UnicodeDecodeError, RecursionError)


def parse_json(text: str, source) -> object:
    """``json.loads(text)``, or a ``ValueError`` "``source`` is not valid JSON: ...".

    Parameters
    ----------
    text : str
        The JSON text.
    source : str or os.PathLike
        The file (or header) it came from, for the message.
    """
    try:
        return json.loads(text)
    except RecursionError:
        raise ValueError(f"{source} is not valid JSON: its arrays or objects are nested too "
                         f"deeply to read (thousands of levels: a corrupt or generated file); "
                         f"write it again") from None
    except json.JSONDecodeError as exc:
        raise ValueError(f"{source} is not valid JSON: {exc}") from None


def read_json(path) -> object:
    """The JSON document in the file ``path`` (UTF-8), or a ``ValueError`` naming the file
    (:func:`parse_json`); ``OSError`` for a file that cannot be read.

    Parameters
    ----------
    path : str or os.PathLike
        The file.
    """
    from pathlib import Path

    try:
        text = Path(path).read_text(encoding="utf-8")
    except UnicodeDecodeError as exc:
        raise ValueError(f"{path} is not valid JSON: {exc}") from None
    return parse_json(text, path)
