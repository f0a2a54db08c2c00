"""Sphinx configuration of clholo's reference: the API from the docstrings (numpydoc), the
Markdown pages of this folder as narrative (MyST), and the tutorial notebook, executed at build
time (myst-nb, through nbclient). Build with warnings as errors, as ``.ci/run`` does::

    .venv/bin/pip install -e ".[docs]"
    .venv/bin/python -m sphinx -W --keep-going -b html docs docs/_build/html
"""

import os
import sys
from importlib.metadata import version as _dist_version

sys.path.insert(0, os.path.join(os.path.dirname(__file__), "_ext"))

project = "clholo"
author = "the clholo developers"
copyright = "the clholo developers"
release = _dist_version("clholo")  # the installed package's metadata: one version everywhere
version = release

extensions = [
    "sphinx.ext.autodoc",
    "numpydoc",
    "myst_nb",
    "mathml",  # docs/_ext/mathml.py: math as MathML, no CDN
]

root_doc = "index"
exclude_patterns = ["_build", "_ext", "**/.ipynb_checkpoints", "jupyter_execute"]
source_suffix = {".rst": "restructuredtext", ".md": "myst-nb", ".ipynb": "myst-nb"}

# --- API -------------------------------------------------------------------------------------
autodoc_member_order = "bysource"
autodoc_typehints = "none"  # the numpydoc sections say the types, with shapes and units
autodoc_default_options = {"members": True, "show-inheritance": False}
numpydoc_show_class_members = False
numpydoc_class_members_toctree = False
numpydoc_xref_param_type = False

# --- Markdown and the notebook ---------------------------------------------------------------
myst_enable_extensions = ["colon_fence", "dollarmath"]
myst_heading_anchors = 3
nb_execution_mode = "force"          # the notebook runs at every build: it cannot go stale
nb_execution_timeout = 180           # seconds per cell
NOTEBOOK_LIMIT_S = 180               # the whole notebook, on PoCL on two cores (issue 24)
nb_execution_raise_on_error = True
nb_execution_show_tb = True
nb_merge_streams = True

# --- HTML --------------------------------------------------------------------------------------
html_theme = "pydata_sphinx_theme"
html_title = f"clholo {release}"
html_theme_options = {"navigation_with_keys": False, "show_toc_level": 2}
html_static_path = ["_static"]
html_css_files = ["clholo.css"]  # display math centred


def setup(app):
    # the pages' csv blocks (docs/batch.md): Pygments has no csv lexer; show them as text
    from pygments.lexers.special import TextLexer

    app.add_lexer("csv", TextLexer)
    app.connect("source-read", _title_generated_pages)
    app.connect("build-finished", _notebook_time)


def _notebook_time(app, exception):
    """Say how long each notebook ran, and fail the build past ``NOTEBOOK_LIMIT_S``."""
    if exception is not None or app.builder.format != "html":
        return
    from myst_nb.sphinx_ import NbMetadataCollector
    from sphinx.errors import ExtensionError

    for docname in sorted(NbMetadataCollector.get_doc_data(app.env)):
        data = NbMetadataCollector.get_exec_data(app.env, docname)
        if not data or data.get("runtime") is None:
            continue
        seconds = float(data["runtime"])
        # printed, not logged: CI builds with -q and its log should show the figure
        print(f"notebook {docname}: executed in {seconds:.1f} s (limit {NOTEBOOK_LIMIT_S} s)")
        if seconds > NOTEBOOK_LIMIT_S:
            raise ExtensionError(f"notebook {docname} ran {seconds:.0f} s, more than the "
                                 f"{NOTEBOOK_LIMIT_S} s it may take in CI: make it smaller")


def _title_generated_pages(app, docname, source):
    # docs/results/results.md is written by `clholo experiment layers` and starts with its
    # caption, not a heading: give it one here rather than in the generator's output
    if docname == "results/results" and not source[0].lstrip().startswith("#"):
        source[0] = "# The layers study: every row\n\n" + source[0]
