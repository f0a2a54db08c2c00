"""Every code block of ``README.md`` and ``docs/*.md`` runs, so the docs cannot drift (issue 17).

What each fenced block's language means here:

* ``python``: executed, file by file in document order, in one namespace per file, in a fresh
  temporary folder (so a block may use what an earlier block of its file defined or wrote, and
  nothing leaks between files);
* ``sh``: every ``clholo ...`` command (also ``.venv/bin/clholo``, after ``&&``, ``;``, ``|``,
  ``&`` and ``VAR=value`` prefixes; ``\\`` continues a line, ``#`` starts a comment) is parsed by
  the real parser, :func:`clholo.cli.build_parser`, so an option name or value cannot drift;
  then, in the same temporary folder and order as the file's python blocks, each is run
  in-process through :func:`clholo.cli.main` and must exit 0. A runnable block holds only
  ``clholo`` commands;
* ``json``, ``toml``, ``csv``: parsed (a csv's rows all have the header's width); a ``toml`` block
  is a bench file, checked by the bench's own reader
  (:func:`clholo.tools.config.parse_bench_config`: sections, keys, units); a ``json`` block with
  ``"format": "clholo-mpi"`` is an ``mpi.json``, read by :func:`clholo.io.read_mpi` beside the
  layer files it names;
* ``text``: output listings and drawings, not checked.

A block that cannot run here says so on the line before its fence, with its reason::

    <!-- docs-test: illustrative: needs an SLM and two stages -->

Such a block is still checked as far as it can be: a python block is compiled and its
``import``/``from clholo... import`` lines that name clholo are executed (a renamed function is
caught); a shell block's ``clholo`` commands are all parsed. ``README.md``'s set-up block (between
``<!-- setup -->`` markers) is run as written on a fresh clone by ``.ci/run``, and only parsed here.
A block with no language, or another language, fails: say what it is.

Sphinx directives in the pages the reference adds (``docs/index.md``, ``docs/changelog.md``)
are MyST colon fences (``:::{toctree}``), not backtick code blocks: they hold no code, so this
runner does not see them, and the reference build (``-W``) checks them instead.
"""

from __future__ import annotations

import ast
import contextlib
import csv
import io
import json
import re
import shlex
import sys
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import List, Optional

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
LANGUAGES = {"python", "sh", "json", "toml", "csv", "text"}
MARKER = re.compile(r"<!--\s*docs-test:\s*illustrative:\s*(?P<reason>\S.*?)\s*-->")
SETUP = "<!-- setup -->"


@dataclass
class Block:
    path: Path
    line: int  # of the opening fence, 1-based
    lang: str
    text: str
    illustrative: Optional[str]  # the reason, when the block only illustrates

    @property
    def where(self) -> str:
        return f"{self.path.relative_to(ROOT)}:{self.line}"


def blocks_of(path: Path) -> List[Block]:
    """The fenced code blocks of a Markdown file, in order."""
    lines = path.read_text(encoding="utf-8").splitlines()
    out: List[Block] = []
    k = 0
    while k < len(lines):
        m = re.match(r"^(`{3,})(.*)$", lines[k])
        if not m:
            k += 1
            continue
        fence, lang = m.group(1), m.group(2).strip()
        end = k + 1
        while end < len(lines) and not lines[end].startswith(fence):
            end += 1
        if end >= len(lines):
            raise AssertionError(f"{path.relative_to(ROOT)}:{k + 1}: code block never closed")
        before = next((lines[j].strip() for j in range(k - 1, -1, -1) if lines[j].strip()), "")
        reason = None
        marker = MARKER.fullmatch(before)
        if marker:
            reason = marker.group("reason")
        elif before == SETUP:
            reason = "the set-up commands, run as written on a fresh clone by .ci/run"
        out.append(Block(path, k + 1, lang, "\n".join(lines[k + 1:end]) + "\n", reason))
        k = end + 1
    return out


ALL_BLOCKS = [b for path in DOCS for b in blocks_of(path)]


def _read_documented_mpi_json(data: dict, tmp_path: Path) -> None:
    """Write an MPI with as many layers as the document's mpi.json, put that mpi.json in its
    place (renaming the layer files to the names it gives) and read the folder back."""
    import numpy as np

    import clholo

    L = len(data["layers"])
    rng = np.random.default_rng(0)
    mpi = clholo.MPI(color=rng.random((L, 8, 12, 3)), alpha=rng.random((L, 8, 12)),
                     depths=np.linspace(2e-3, 6e-3, L))
    folder = tmp_path / "mpi"
    clholo.io.write_mpi(folder, mpi)
    written = json.loads((folder / "mpi.json").read_text())
    for old, new in zip(written["layers"], data["layers"]):
        (folder / old).rename(folder / new)
    (folder / "mpi.json").write_text(json.dumps(data))
    back = clholo.io.read_mpi(folder)
    assert back.color.shape[0] == L
    np.testing.assert_allclose(back.depths, data["depths"])


# --- shell ---------------------------------------------------------------------------------------

def shell_commands(text: str) -> List[List[str]]:
    """The simple commands of a shell block, each as its argument list (``VAR=x`` prefixes
    dropped)."""
    logical = re.sub(r"\\\n", " ", text)
    commands: List[List[str]] = []
    for line in logical.splitlines():
        lexer = shlex.shlex(line, posix=True, punctuation_chars=";&|")
        lexer.whitespace_split = True
        lexer.commenters = "#"
        current: List[str] = []
        for token in lexer:
            if token and set(token) <= set(";&|"):
                if current:
                    commands.append(current)
                current = []
                continue
            if not current and re.match(r"^[A-Za-z_][A-Za-z0-9_]*=", token):
                continue  # CLHOLO_DEVICE=0:0 dask worker ...
            current.append(token)
        if current:
            commands.append(current)
    return commands


def clholo_argvs(text: str) -> List[List[str]]:
    """The argument lists (after the program) of the block's ``clholo`` commands."""
    return [cmd[1:] for cmd in shell_commands(text)
            if cmd[0] == "clholo" or cmd[0].endswith("/clholo")]


def parse_clholo(argv: List[str], where: str):
    from clholo.cli import build_parser

    err = io.StringIO()
    try:
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
            args = build_parser().parse_args(argv)
    except SystemExit as exc:
        raise AssertionError(f"{where}: `clholo {shlex.join(argv)}` does not parse (exit "
                             f"{exc.code}): {(err.getvalue().strip().splitlines() or [''])[-1]}") from None
    # argparse takes unambiguous abbreviations (--frame for --frames): the docs spell options out
    # the help of the command the argv names: every clholo-wide option before it (and its value)
    # is skipped, then the words up to the command's first option; the clholo-wide help is
    # read too, since those options may stand before the command
    rest = list(argv)
    while rest and rest[0].startswith("-"):
        takes_value = rest[0] in ("--progress",) and "=" not in rest[0]
        rest = rest[2:] if takes_value else rest[1:]
    prefix = []
    for token in rest:
        if token.startswith("-"):
            break
        prefix.append(token)
    out = io.StringIO()
    for help_argv in ([*prefix, "--help"], ["--help"]):
        with contextlib.redirect_stdout(out), pytest.raises(SystemExit):
            build_parser().parse_args(help_argv)
    for token in argv:
        name = token.split("=", 1)[0]
        if name.startswith("--") and not re.search(rf"(?<![\w-]){re.escape(name)}(?![\w-])",
                                                    out.getvalue()):
            raise AssertionError(f"{where}: `clholo {shlex.join(argv)}`: {name} is an "
                                 f"abbreviation, not an option's name; spell it out")
    return args


# --- python --------------------------------------------------------------------------------------

def clholo_imports(source: str, filename: str) -> str:
    """The import statements of ``source`` that name clholo, as a module of their own."""
    tree = ast.parse(source, filename=filename)
    keep = []
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and (node.module or "").split(".")[0] == "clholo":
            keep.append(node)
        elif isinstance(node, ast.Import) and any(a.name.split(".")[0] == "clholo"
                                                  for a in node.names):
            keep.append(node)
    return ast.unparse(ast.Module(body=keep, type_ignores=[]))


# --- the tests -----------------------------------------------------------------------------------

def test_the_docs_have_blocks_of_every_kind():
    """The runner sees the blocks (a broken fence regex would make every test below vacuous)."""
    kinds = {b.lang for b in ALL_BLOCKS}
    assert {"python", "sh", "json", "toml", "csv"} <= kinds, kinds
    assert sum(b.lang == "python" and not b.illustrative for b in ALL_BLOCKS) >= 5
    assert sum(b.lang == "sh" and not b.illustrative for b in ALL_BLOCKS) >= 2


@pytest.mark.parametrize("block", ALL_BLOCKS, ids=lambda b: b.where)
def test_block_says_what_it_is(block):
    assert block.lang in LANGUAGES, (
        f"{block.where}: a code block must name its language, one of {sorted(LANGUAGES)} "
        f"(got {block.lang!r}); see tests/test_docs.py")
    if block.illustrative is not None:
        assert block.lang in ("python", "sh"), f"{block.where}: only code can be illustrative"


@pytest.mark.parametrize("block", [b for b in ALL_BLOCKS if b.lang in ("json", "toml", "csv")],
                         ids=lambda b: b.where)
def test_data_blocks_parse(block, tmp_path):
    if block.lang == "json":
        data = json.loads(block.text)
        if isinstance(data, dict) and data.get("format") == "clholo-mpi":
            _read_documented_mpi_json(data, tmp_path)
    elif block.lang == "toml":
        from clholo.tools.config import parse_bench_config

        parse_bench_config(tomllib.loads(block.text))
    else:
        rows = list(csv.reader(io.StringIO(block.text)))
        widths = {len(r) for r in rows}
        assert rows and widths == {len(rows[0])}, f"{block.where}: rows of widths {widths}"


@pytest.mark.parametrize("block", [b for b in ALL_BLOCKS if b.lang == "sh"],
                         ids=lambda b: b.where)
def test_shell_commands_parse(block):
    argvs = clholo_argvs(block.text)
    for argv in argvs:
        parse_clholo(argv, block.where)
    if block.illustrative is None:
        others = [c for c in shell_commands(block.text)
                  if not (c[0] == "clholo" or c[0].endswith("/clholo"))]
        assert argvs and not others, (
            f"{block.where}: a runnable shell block holds only clholo commands (found "
            f"{[shlex.join(c) for c in others]}); mark it illustrative with a reason")


@pytest.mark.parametrize("block", [b for b in ALL_BLOCKS
                                   if b.lang == "python" and b.illustrative is not None],
                         ids=lambda b: b.where)
def test_illustrative_python_compiles_and_its_clholo_imports_exist(block):
    compile(block.text, block.where, "exec")
    exec(compile(clholo_imports(block.text, block.where), block.where, "exec"), {})


RUNNABLE = sorted({b.path for b in ALL_BLOCKS if b.illustrative is None and
                   b.lang in ("python", "sh")})


@pytest.mark.parametrize("path", RUNNABLE, ids=lambda p: str(p.relative_to(ROOT)))
def test_runnable_blocks_run(path, tmp_path, monkeypatch, capsys):
    """The file's python and shell blocks, in order, in one temporary folder."""
    from clholo.cli import main

    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(sys, "argv", ["clholo"])
    namespace = {"__name__": "__docs__"}
    for block in blocks_of(path):
        if block.illustrative is not None or block.lang not in ("python", "sh"):
            continue
        if block.lang == "python":
            try:
                exec(compile(block.text, block.where, "exec"), namespace)
            except Exception as exc:
                raise AssertionError(f"{block.where}: the block raised "
                                     f"{type(exc).__name__}: {exc}") from exc
            continue
        for argv in clholo_argvs(block.text):
            parse_clholo(argv, block.where)
            rc = main(argv)
            captured = capsys.readouterr()
            assert rc == 0, (f"{block.where}: `clholo {shlex.join(argv)}` exited {rc}:\n"
                             f"{captured.err[-2000:]}")


# --- docs/errors.md: every command-line row is the real exit code and line ----------------------

ERROR_ROW = re.compile(r"^\|\s*`clholo (?P<argv>[^`]+)`\s*\|\s*(?P<code>\d+)\s*\|\s*(?P<line>.*?)\s*\|$")


def error_rows():
    rows = []
    for k, line in enumerate((ROOT / "docs" / "errors.md").read_text().splitlines(), 1):
        m = ERROR_ROW.match(line)
        if m:
            rows.append((f"docs/errors.md:{k}", shlex.split(m.group("argv")),
                         int(m.group("code")), m.group("line")))
    return rows


ERROR_ROWS = error_rows()


@pytest.fixture(scope="module")
def error_fixtures(tmp_path_factory):
    """The folder docs/errors.md describes, made once."""
    import numpy as np

    import clholo
    from clholo.io.output import output_folder

    root = tmp_path_factory.mktemp("errors-md")
    rng = np.random.default_rng(0)
    field = (rng.standard_normal((2, 3, 16, 24))
             + 1j * rng.standard_normal((2, 3, 16, 24))).astype(np.complex64)
    clholo.io.write_hologram(root / "holo.npz", field, pitch=8e-6,
                             wavelengths=[638e-9, 520e-9, 450e-9])
    clholo.io.write_mpi(root / "scene", clholo.MPI(color=rng.random((2, 16, 24, 3)),
                                                   alpha=rng.random((2, 16, 24)),
                                                   depths=[2e-3, 4e-3]))
    with output_folder(root / "run", command="render") as tmp:
        np.savez(tmp / "focal_stack.npz", intensity=rng.random((3, 3, 8, 8)))
        np.savez(tmp / "hologram.npz", holograms=field)
    (root / "notes.html").write_text("my notes")
    (root / "mydata.csv").write_text("a,b\n1,2\n")
    (root / "mine").mkdir()
    (root / "mine" / "results.csv").write_text("a,b\n1,2\n")
    (root / "empty").mkdir()
    np.savetxt(root / "bad.csv", np.r_[np.linspace(0, 6, 255), 1.0])
    np.save(root / "seq.npy", np.zeros((1, 1, 8, 8), np.uint8))
    (root / "bench.toml").write_text("[slm]\nresolution = [1920, 1080]\n")
    return root


def test_errors_md_has_rows_for_every_command():
    from clholo.cli import build_parser

    parser = build_parser()
    commands = set()
    for action in parser._subparsers._group_actions:  # the test may look; library code may not
        commands |= set(action.choices)
    covered = {argv[0] for _, argv, _, _ in ERROR_ROWS}
    assert commands <= covered, f"docs/errors.md has no row for {sorted(commands - covered)}"


@pytest.mark.parametrize("where, argv, code, line", ERROR_ROWS, ids=[r[0] for r in ERROR_ROWS])
def test_errors_md_rows_are_the_real_messages(error_fixtures, monkeypatch, capsys, where, argv,
                                              code, line):
    from clholo.cli import main

    monkeypatch.chdir(error_fixtures)
    try:
        rc = main(argv)
    except SystemExit as exc:  # argparse's own usage errors
        rc = exc.code
    err = capsys.readouterr().err.replace(f"{error_fixtures}/", "")
    last = (err.strip().splitlines() or [""])[-1]
    assert (rc, last) == (code, line), f"{where}: `clholo {shlex.join(argv)}`"
    assert not (error_fixtures / "o").exists() and not (error_fixtures / "r").exists()


# --- the runner itself ---------------------------------------------------------------------------

def test_runner_reads_markers_commands_and_imports(tmp_path):
    doc = tmp_path / "x.md"
    doc.write_text("text\n\n<!-- docs-test: illustrative: needs an SLM -->\n```sh\n"
                   "CLHOLO_DEVICE=0:1 .venv/bin/clholo info && clholo demo \\\n  --frames 2 "
                   "# comment\ndask worker --x & clholo info\n```\n\n```python\nx = 1\n```\n")
    a, b = blocks_of(doc)
    assert (a.lang, a.illustrative, a.line) == ("sh", "needs an SLM", 4)
    assert (b.lang, b.illustrative) == ("python", None)
    assert clholo_argvs(a.text) == [["info"], ["demo", "--frames", "2"], ["info"]]
    with pytest.raises(AssertionError, match="does not parse"):
        parse_clholo(["demo", "--franes", "2"], "x.md:1")
    with pytest.raises(AssertionError, match="--frame is an abbreviation"):
        parse_clholo(["demo", "--frame", "2"], "x.md:1")
    parse_clholo(["demo", "--frames", "2"], "x.md:1")
    # clholo-wide options before the command: the command's own options are still its own
    parse_clholo(["--progress", "lines", "experiment", "layers", "--methods", "mpi"], "x.md:1")
    with pytest.raises(AssertionError, match="--method is an abbreviation"):
        parse_clholo(["--progress", "lines", "experiment", "layers", "--method", "mpi"], "x.md:1")
    assert clholo_imports("import os\nfrom clholo.io import load_scene\nf(1)\n", "x") == \
        "from clholo.io import load_scene"
