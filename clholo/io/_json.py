"""JSON text read by :mod:`clholo.io`: one place that turns every way a file can fail to be
JSON into a ``ValueError`` naming the file (Python's reader raises ``RecursionError``, not
``JSONDecodeError``, for arrays or objects nested thousands deep)."""

from __future__ import annotations

import json

__all__ = ["parse_json", "read_json", "JSON_ERRORS"]

#: What ``json.loads`` raises for text that is not JSON it can read (``UnicodeDecodeError`` is
#: what reading a file's bytes as UTF-8 raises first; ``RecursionError``: nested too deeply).
JSON_ERRORS = (json.JSONDecodeError, UnicodeDecodeError, RecursionError)


class _DuplicateKey(ValueError):
    """A key given twice in one JSON object (raised inside ``json.loads``)."""


def _unique_object(pairs) -> dict:
    """A JSON object's dict, refusing a key given twice: ``json`` keeps the last one, so a
    ``"depths"`` written twice (an edit pasted below the old one) would be used without a
    word."""
    out = {}
    for key, value in pairs:
        if key in out:
            raise _DuplicateKey(key)
        out[key] = value
    return out


def parse_json(text: str, source, *, unique_keys: bool = False) -> object:
    """``json.loads(text)``, or a ``ValueError`` "``source`` is not valid JSON: ...".

    Parameters
    ----------
    text : str
        The JSON text.
    source : str or os.PathLike
        The file (or header) it came from, for the message.
    unique_keys : bool
        Refuse an object that gives a key twice (``json`` keeps the last silently).
    """
    try:
        return json.loads(text, object_pairs_hook=_unique_object if unique_keys else None)
    except RecursionError:
        raise ValueError(f"{source} is not valid JSON: its arrays or objects are nested too "
                         f"deeply to read (thousands of levels: a corrupt or generated file); "
                         f"write it again") from None
    except json.JSONDecodeError as exc:
        raise ValueError(f"{source} is not valid JSON: {exc}") from None
    except _DuplicateKey as exc:
        raise ValueError(f"{source}: key {exc.args[0]!r} is given twice in one object (JSON "
                         f"readers keep the last silently); give each key once") from None
    except ValueError as exc:  # Python's limit on integer digits (4300), raised mid-parse
        if "digits" not in str(exc):
            raise
        raise ValueError(f"{source} is not valid JSON clholo reads: it holds an integer of "
                         f"more than 4300 digits, which no count or length is (a corrupt or "
                         f"generated file); write it again") from None


def read_json(path) -> object:
    """The JSON document in the file ``path`` (UTF-8), or a ``ValueError`` naming the file
    (:func:`parse_json`, a key given twice in an object included); ``OSError`` for a file that
    cannot be read.

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
    return parse_json(text, path, unique_keys=True)
