"""Every public name of the documented API has a docstring, and every docstring's parameters
match its signature (issue 24).

The documented API is what ``docs/api/*.rst`` puts in the reference (``automodule``,
``autoclass`` and ``autofunction`` directives), so a new API page is checked as soon as it
exists. A module's public names are its ``__all__`` (else its functions and classes whose names
do not start with ``_``); a class's public members are the functions, class/static methods and
properties it defines whose names do not start with ``_``.

The parameter rule, our own (numpydoc's validation also wants sections this house style leaves
out, such as ``Returns`` for ``None`` and ``See Also``):

* a docstring with a numpydoc ``Parameters`` (or ``Other Parameters``) section names exactly the
  signature's parameters there (``self``/``cls`` aside; ``*args``/``**kwargs`` with or without
  their stars): none missing, none that the signature does not have;
* a short docstring without that section names every parameter in its text (as ``seed`` or
  seed), so that prose does not drift from the signature either;
* a record (a dataclass) may list its fields under ``Attributes`` instead.

A class's parameters are its ``__init__``'s (a dataclass's fields), read from the class
docstring, or from ``__init__``'s own where it has one.
"""

from __future__ import annotations

import dataclasses
import importlib
import inspect
import re
import warnings
from pathlib import Path
from typing import Iterator, List, Optional, Tuple

import pytest

from conftest import require_module

ROOT = Path(__file__).resolve().parents[1]
API_RST = sorted((ROOT / "docs" / "api").glob("*.rst"))
DIRECTIVE = re.compile(r"^\.\. (automodule|autoclass|autofunction|module):: (\S+)", re.M)


def documented_modules() -> List[str]:
    """The modules whose names the reference shows, from ``docs/api/*.rst``."""
    modules = set()
    for path in API_RST:
        for kind, target in DIRECTIVE.findall(path.read_text()):
            modules.add(target if kind in ("automodule", "module") else target.rsplit(".", 1)[0])
    return sorted(modules)


def public_names(module) -> List[str]:
    names = getattr(module, "__all__", None)
    if names is not None:
        return list(names)
    return [n for n, o in vars(module).items() if not n.startswith("_")
            and (inspect.isfunction(o) or inspect.isclass(o))
            and (getattr(o, "__module__", "") or "").split(".")[0] == "clholo"]


def own_doc(obj) -> Optional[str]:
    """The object's own docstring; a dataclass's generated ``Name(field, ...)`` is none."""
    doc = obj.__doc__ if not isinstance(obj, property) else (obj.fget.__doc__ if obj.fget else None)
    if inspect.isclass(obj):
        if "__doc__" not in obj.__dict__:
            return None
        if dataclasses.is_dataclass(obj) and doc and doc.startswith(f"{obj.__name__}("):
            return None
    return doc if doc and doc.strip() else None


def api_objects() -> Iterator[Tuple[str, object]]:
    """``(qualified name, object)`` of every public function, class and class member."""
    seen = set()
    for modname in documented_modules():
        module = importlib.import_module(modname)
        for name in public_names(module):
            obj = getattr(module, name)
            if not (inspect.isfunction(obj) or inspect.isclass(obj)) or id(obj) in seen:
                continue
            seen.add(id(obj))
            qual = f"{modname}.{name}"
            yield qual, obj
            if inspect.isclass(obj):
                for member, value in vars(obj).items():
                    if member.startswith("_"):
                        continue
                    if isinstance(value, (staticmethod, classmethod)):
                        value = value.__func__
                    if inspect.isfunction(value) or isinstance(value, property):
                        yield f"{qual}.{member}", value


def signature_parameters(obj) -> Optional[List[str]]:
    """Parameter names as a docstring would name them (``*args``, ``**kw``), or None where
    there is no signature of the object's own to check."""
    if isinstance(obj, property):
        return None
    if inspect.isclass(obj):
        if getattr(obj, "_is_protocol", False):
            return None  # a typing.Protocol: an interface, never constructed
        if "__init__" not in vars(obj) and not dataclasses.is_dataclass(obj):
            return None  # inherited (object, Exception, a base class): nothing of its own
        target = obj.__init__
    else:
        target = obj
    try:
        sig = inspect.signature(target)
    except (TypeError, ValueError):
        return None
    names = []
    for p in sig.parameters.values():
        if p.name in ("self", "cls"):
            continue
        star = {p.VAR_POSITIONAL: "*", p.VAR_KEYWORD: "**"}.get(p.kind, "")
        names.append(star + p.name)
    return names


def documented_parameters(doc: str, *, record: bool = False) -> Optional[List[str]]:
    """The names in the numpydoc ``Parameters``/``Other Parameters`` sections (for a record,
    a dataclass, its ``Attributes`` where it has no ``Parameters``), or None where the
    docstring has none of them."""
    require_module("numpydoc", "test")
    from numpydoc.docscrape import NumpyDocString

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        parsed = NumpyDocString(inspect.cleandoc(doc))
    entries = parsed["Parameters"] + parsed["Other Parameters"]
    if not entries and record:
        entries = parsed["Attributes"]
    if not entries:
        return None
    return [n.strip() for e in entries for n in e.name.split(",") if n.strip()]


def parameter_problem(obj) -> Optional[str]:
    """What is wrong between the object's signature and its docstring, or None."""
    params = signature_parameters(obj)
    if not params:
        return None
    docs = [own_doc(obj)]
    if inspect.isclass(obj) and "__init__" in vars(obj):
        docs.append(obj.__init__.__doc__)
    docs = [d for d in docs if d and d.strip()]
    bare = {p.lstrip("*"): p for p in params}
    for doc in docs:
        named = documented_parameters(doc, record=dataclasses.is_dataclass(obj))
        if named is None:
            continue
        named_bare = [n.lstrip("*") for n in named]
        missing = [p for p in params if p.lstrip("*") not in named_bare]
        extra = [n for n in named if n.lstrip("*") not in bare]
        if missing or extra:
            return (f"Parameters section: not documented {missing}, not in the signature "
                    f"{extra}")
        return None
    text = "\n".join(docs)
    missing = [p for p in params
               if not re.search(rf"(?<![\w]){re.escape(p.lstrip('*'))}(?![\w])", text)]
    if missing:
        return f"no Parameters section, and the text does not name {missing}"
    return None


API = list(api_objects())


def test_the_checked_api_is_the_documented_api():
    """The walk sees the modules the issue names and their objects (an empty walk would make
    the tests below vacuous)."""
    modules = documented_modules()
    for name in ("clholo", "clholo.fft", "clholo.views", "clholo.metrics", "clholo.io",
                 "clholo.scenes", "clholo.methods", "clholo.bench", "clholo.encode.sgd",
                 "clholo.tools.stages"):
        assert name in modules, name
    names = {q for q, _ in API}
    assert {"clholo.render_hologram", "clholo.MPI", "clholo.fft.FFTPlan",
            "clholo.fft.FFTPlan.execute", "clholo.io.load_scene"} <= names
    assert len(API) > 150, len(API)


def test_every_public_name_has_a_docstring():
    missing = [q for q, obj in API if own_doc(obj) is None]
    assert not missing, "public names without a docstring:\n  " + "\n  ".join(missing)


def test_every_docstring_names_the_signatures_parameters():
    problems = [f"{q}: {p}" for q, obj in API if (p := parameter_problem(obj))]
    assert not problems, "docstrings that do not match their signature:\n  " + \
        "\n  ".join(problems)


# --- the checker itself --------------------------------------------------------------------------

def _numpydoc(a, b=1, *, c=None):
    """Something.

    Parameters
    ----------
    a : int
    b, c : float
    """


def _numpydoc_stale(a, *, renamed=None):
    """Something.

    Parameters
    ----------
    a : int
    old_name : float
    """


def _prose(shape, *, seed=0):
    """The phases of ``shape`` for ``seed``."""


def _prose_stale(shape, *, seed=0, frames=1):
    """The phases of ``shape`` for ``seed``."""


@dataclasses.dataclass
class _Undocumented:
    x: int


class _Init:
    """A thing.

    Parameters
    ----------
    x : int
    """

    def __init__(self, x, y):
        pass


def test_checker_catches_what_it_should():
    assert parameter_problem(_numpydoc) is None
    assert "not documented ['renamed']" in parameter_problem(_numpydoc_stale)
    assert "not in the signature ['old_name']" in parameter_problem(_numpydoc_stale)
    assert parameter_problem(_prose) is None
    assert "does not name ['frames']" in parameter_problem(_prose_stale)
    assert own_doc(_Undocumented) is None and own_doc(_Init) is not None
    assert "not documented ['y']" in parameter_problem(_Init)
    assert signature_parameters(lambda *args, **kw: None) == ["*args", "**kw"]
