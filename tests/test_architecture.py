"""The house rules of ``docs/architecture.md``, read from the source (issue 17, item 8).

Every ``.py`` file of the package (``clholo/``, and ``host/``, ``tools/``, ``kernels/`` installed
as ``clholo.host``, ``clholo.tools``, ``clholo.kernels``; see ``setup.cfg``) is parsed with
:mod:`ast`, and every ``import``/``from ... import`` statement naming a ``clholo`` module becomes
an edge of one graph:

* **function-level (lazy) imports count** as much as module-level ones. A lazy import only
  postpones the cycle to the first call (the cycle ``clholo.cli <-> clholo.baselines.rpws`` of
  issue 17 was made of lazy imports), and it still ties the two modules together: neither can be
  understood, moved or tested without the other.
* imports under ``if TYPE_CHECKING:`` do not count (they never run).
* a string that is exactly the name of a clholo module counts as an import of it: that is how
  modules are imported by name (``importlib.import_module``; ``clholo.cli`` imports the command
  modules listed in ``clholo.commands.COMMAND_MODULES``).
* an edge goes to the module named: ``from clholo.encode import sgd`` is an edge to
  ``clholo.encode.sgd`` (a submodule), ``from clholo import Optics`` one to ``clholo`` (the
  package's ``__init__``). The implicit import of a parent package when a submodule is imported
  is *not* an edge: Python initialises a package before its submodules, and counting it would
  make every submodule that imports a sibling a "cycle" with its package.

Then: no strongly connected component of more than one module (no cycle, of any length); library
modules (everything outside ``clholo.commands`` and ``clholo.cli``) import neither; a command
module imports no other command module (``clholo.options`` is the shared home of what
commands have in common, and ``clholo.commands`` itself only lists them).
"""

from __future__ import annotations

import ast
import re
from pathlib import Path
from typing import Dict, List, Set

import pytest

ROOT = Path(__file__).resolve().parents[1]
# installed name -> folder in the repository (setup.cfg's package_dir)
PACKAGE_DIRS = {"clholo": "clholo", "clholo.host": "host", "clholo.tools": "tools",
                "clholo.kernels": "kernels"}
COMMAND_LAYER = ("clholo.cli", "clholo.commands")

# Known debts, each with its reason. The tests below fail on any violation *not* listed here, and
# also when a listed one is gone (so that the list only shrinks: delete the entry then).
KNOWN_CYCLES: Dict[frozenset, str] = {}
KNOWN_COMMAND_IMPORTS: Dict[tuple, str] = {}
SHARED_COMMAND_MODULES = {"clholo.commands", "clholo.options"}


def package_modules() -> Dict[str, Path]:
    """Installed module name -> source file, for every module of the package."""
    mods: Dict[str, Path] = {}
    for package, folder in PACKAGE_DIRS.items():
        base = ROOT / folder
        for path in sorted(base.rglob("*.py")):
            parts = list(path.relative_to(base).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts = parts[:-1]
            mods[".".join([package, *parts])] = path
    return mods


def _is_type_checking(node: ast.If) -> bool:
    test = node.test
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or \
        (isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING")


def _import_nodes(tree: ast.AST):
    """Every Import/ImportFrom in the tree, at any depth, except under ``if TYPE_CHECKING:``."""
    stack = [tree]
    while stack:
        node = stack.pop()
        if isinstance(node, ast.If) and _is_type_checking(node):
            stack.extend(node.orelse)
            continue
        if isinstance(node, (ast.Import, ast.ImportFrom)):
            yield node
        stack.extend(ast.iter_child_nodes(node))


def imports_of(name: str, path: Path, known: Set[str]) -> Set[str]:
    """The clholo modules that module ``name`` (source ``path``) imports, lazily or not."""
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    is_package = path.name == "__init__.py"
    package = name if is_package else name.rpartition(".")[0]
    found: Set[str] = set()

    def add(target: str) -> None:
        # the most specific module that exists: clholo.a.b.Name -> clholo.a.b
        while target and target not in known:
            target = target.rpartition(".")[0]
        if target and target != name:
            found.add(target)

    for node in ast.walk(tree):  # importlib.import_module("clholo.x"), COMMAND_MODULES
        if isinstance(node, ast.Constant) and isinstance(node.value, str) and \
                node.value in known and node.value != "clholo":
            add(node.value)
    for node in _import_nodes(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                if alias.name == "clholo" or alias.name.startswith("clholo."):
                    add(alias.name)
            continue
        if node.level:  # relative: from ..errors import X
            base = package.split(".")
            if node.level > 1:
                base = base[:-(node.level - 1)]
            source = ".".join(base + ([node.module] if node.module else []))
        else:
            source = node.module or ""
        if not (source == "clholo" or source.startswith("clholo.")):
            continue
        for alias in node.names:
            sub = f"{source}.{alias.name}"
            add(sub if sub in known else source)
    return found


def import_graph() -> Dict[str, Set[str]]:
    mods = package_modules()
    known = set(mods)
    return {name: imports_of(name, path, known) for name, path in mods.items()}


def strongly_connected(graph: Dict[str, Set[str]]) -> List[List[str]]:
    """Tarjan's strongly connected components (iterative), each sorted; only those of more than
    one module, or of one module importing itself."""
    index: Dict[str, int] = {}
    low: Dict[str, int] = {}
    on_stack: Set[str] = set()
    stack: List[str] = []
    out: List[List[str]] = []
    counter = 0
    for root in sorted(graph):
        if root in index:
            continue
        work = [(root, iter(sorted(graph[root])))]
        index[root] = low[root] = counter
        counter += 1
        stack.append(root)
        on_stack.add(root)
        while work:
            node, children = work[-1]
            for child in children:
                if child not in index:
                    index[child] = low[child] = counter
                    counter += 1
                    stack.append(child)
                    on_stack.add(child)
                    work.append((child, iter(sorted(graph.get(child, ())))))
                    break
                if child in on_stack:
                    low[node] = min(low[node], index[child])
            else:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[node])
                if low[node] == index[node]:
                    comp = []
                    while True:
                        m = stack.pop()
                        on_stack.discard(m)
                        comp.append(m)
                        if m == node:
                            break
                    if len(comp) > 1 or node in graph.get(node, ()):
                        out.append(sorted(comp))
    return out


def _cycle_path(graph: Dict[str, Set[str]], comp: List[str]) -> str:
    """One cycle through the component's first module, as ``a -> b -> a`` (for the message)."""
    members = set(comp)
    start = comp[0]
    prev = {start: None}
    queue = [start]
    while queue:
        node = queue.pop(0)
        for nxt in sorted(graph[node] & members):
            if nxt == start:
                path = [node]
                while prev[path[-1]] is not None:
                    path.append(prev[path[-1]])
                return " -> ".join(reversed(path)) + f" -> {start}"
            if nxt not in prev:
                prev[nxt] = node
                queue.append(nxt)
    return " <-> ".join(comp)


def _in_command_layer(name: str) -> bool:
    return any(name == p or name.startswith(p + ".") for p in COMMAND_LAYER)


# --- the checker itself, on small graphs and sources --------------------------------------------

def test_scc_finds_every_cycle_and_only_cycles():
    graph = {"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a", "e"}, "e": set(), "f": {"f"},
             "g": {"h"}, "h": {"g"}}
    assert sorted(strongly_connected(graph)) == [["a", "b", "c"], ["f"], ["g", "h"]]
    assert strongly_connected({"a": {"b"}, "b": set()}) == []
    assert _cycle_path(graph, ["a", "b", "c"]) == "a -> b -> c -> a"


def test_imports_are_read_at_every_level(tmp_path):
    src = tmp_path / "m.py"
    src.write_text(
        "from typing import TYPE_CHECKING\n"
        "import clholo.io.output\n"
        "from ..errors import InputError\n"
        "from . import sibling\n"
        "if TYPE_CHECKING:\n"
        "    from clholo.cli import main\n"
        "def f():\n"
        "    from clholo.commands import render\n"
        "    class K:\n"
        "        def g(self):\n"
        "            import clholo.scenes as s\n"
        "    return K\n")
    known = {"clholo", "clholo.io", "clholo.io.output", "clholo.errors", "clholo.pkg",
             "clholo.pkg.m", "clholo.pkg.sibling", "clholo.cli", "clholo.commands",
             "clholo.commands.render", "clholo.scenes"}
    assert imports_of("clholo.pkg.m", src, known) == {
        "clholo.io.output", "clholo.errors", "clholo.pkg.sibling", "clholo.commands.render",
        "clholo.scenes"}


# --- the rules, on the package ------------------------------------------------------------------

GRAPH = import_graph()


def test_the_graph_sees_the_package():
    assert len(GRAPH) > 50
    assert "clholo.commands.render" in GRAPH["clholo.cli"] or \
        "clholo.commands" in GRAPH["clholo.cli"]
    assert "clholo.host.runtime" in GRAPH and "clholo.tools.stages" in GRAPH


def test_no_import_cycles():
    comps = strongly_connected(GRAPH)
    new = [f"{_cycle_path(GRAPH, c)}  (component: {', '.join(c)})" for c in comps
           if frozenset(c) not in KNOWN_CYCLES]
    assert not new, ("import cycles inside clholo (lazy imports count: see this module's "
                     "docstring):\n  " + "\n  ".join(new))
    gone = [" <-> ".join(sorted(k)) for k in KNOWN_CYCLES if list(sorted(k)) not in comps]
    assert not gone, ("these known cycles are gone (or changed): delete them from KNOWN_CYCLES "
                      "(and from docs/architecture.md):\n  " + "\n  ".join(gone))


def test_library_never_imports_the_command_layer():
    found = {(mod, target) for mod, targets in GRAPH.items() if not _in_command_layer(mod)
             for target in targets if _in_command_layer(target)}
    bad = sorted(f"{mod} imports {target}" for mod, target in found - set(KNOWN_COMMAND_IMPORTS))
    assert not bad, ("library code imports the command layer (move what it needs into the "
                     "library):\n  " + "\n  ".join(bad))
    gone = sorted(f"{m} -> {t}" for m, t in set(KNOWN_COMMAND_IMPORTS) - found)
    assert not gone, ("these known imports are gone: delete them from KNOWN_COMMAND_IMPORTS "
                      "(and from docs/architecture.md):\n  " + "\n  ".join(gone))


def test_no_command_imports_another_command():
    from clholo.commands import COMMAND_MODULES

    commands = set(COMMAND_MODULES)
    assert commands <= set(GRAPH)
    bad = sorted(f"{mod} imports {target}" for mod in commands for target in GRAPH[mod]
                 if target in commands or (target.startswith("clholo.commands.")
                                           and target not in SHARED_COMMAND_MODULES))
    assert not bad, ("a command module imports another command module (shared pieces belong in "
                     "clholo.options or the library):\n  " + "\n  ".join(bad))


PRIVATE_ARGPARSE = re.compile(r"\bargparse\._|\._actions\b|\._subparsers\b|\._group_actions\b")
# where argparse's private parts may appear, and why
PRIVATE_ARGPARSE_ALLOWED = {
    "clholo.cli": "the parser class itself: its error() reads its own subcommands for 'maybe "
                  "you meant'",
}
KNOWN_PRIVATE_ARGPARSE: Dict[str, str] = {}


def test_no_private_argparse_outside_the_parser():
    """Library code and commands use argparse's public API only (clholo.options holds
    what they share, e.g. RowParser)."""
    mods = package_modules()
    found = {name for name, path in mods.items()
             if PRIVATE_ARGPARSE.search(path.read_text(encoding="utf-8"))}
    bad = sorted(found - set(PRIVATE_ARGPARSE_ALLOWED) - set(KNOWN_PRIVATE_ARGPARSE))
    assert not bad, f"argparse internals (parser._actions, argparse._...) used in {bad}"
    gone = sorted(set(KNOWN_PRIVATE_ARGPARSE) - found)
    assert not gone, f"delete {gone} from KNOWN_PRIVATE_ARGPARSE (fixed)"
