"""One version everywhere, a changelog that starts at it, and the README's two audiences
(issue 24). The built sdist and wheel themselves are checked by ``.ci/run`` (``python -m
build``, ``twine check``, the wheel installed in a fresh virtual environment running
``clholo selftest --quick``): building them here would take the network and minutes."""

import configparser
import re
from importlib.metadata import version
from pathlib import Path

import pytest

import clholo
from clholo.cli import main
from conftest import require_installed

ROOT = Path(__file__).resolve().parents[1]


def test_version_is_read_from_one_place():
    cfg = configparser.ConfigParser()
    cfg.read(ROOT / "setup.cfg")
    assert cfg["metadata"]["version"].strip() == "attr: clholo._version.__version__"
    assert re.fullmatch(r"\d+\.\d+\.\d+([ab]|rc)?\d*", clholo.__version__), clholo.__version__


def test_cli_module_and_metadata_agree(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["--version"])
    assert exc.value.code == 0
    assert capsys.readouterr().out.strip() == f"clholo {clholo.__version__}"
    # the installed metadata (editable or not): stale only if _version.py changed since the
    # install, and then `pip install -e .` brings it back in line
    require_installed()
    assert version("clholo") == clholo.__version__, (
        f"installed metadata says {version('clholo')}, clholo/_version.py {clholo.__version__}:"
        f" reinstall (pip install -e .)")


def test_changelog_starts_at_the_current_version():
    text = (ROOT / "CHANGELOG.md").read_text()
    versions = re.findall(r"^## (\S+)", text, re.M)
    assert versions and versions[0] == clholo.__version__, versions[:3]
    assert len(versions) == len(set(versions))


def test_readme_has_an_install_section_apart_from_the_setup_commands():
    text = (ROOT / "README.md").read_text()
    setup = re.search(r"<!-- setup -->\n```sh\n(.*?)```\n<!-- /setup -->", text, re.S)
    assert setup, "the setup markers and their block"
    assert setup.group(1).splitlines() == [
        'python3 -m venv .venv && .venv/bin/pip install -e ".[pocl,test]" && .venv/bin/clholo demo',
        ".venv/bin/python -m pytest -q tests",
    ], "the developers' two set-up commands stay exactly as they are (.ci/run runs them)"
    install = text.index("## Install")
    assert install < text.index("<!-- setup -->")
    section = text[install:text.index("\n## ", install + 1)]
    assert "[pocl]" in section and ".whl" in section and "selftest --quick" in section
    for extra in ("pocl", "docs", "release", "test"):
        assert f"| `{extra}` |" in section, extra
    cfg = configparser.ConfigParser()
    cfg.read(ROOT / "setup.cfg")
    extras = set(cfg["options.extras_require"])
    documented = set(re.findall(r"^\| `(\w+)` \|", section, re.M))
    assert documented == extras, (sorted(extras - documented), sorted(documented - extras))
