"""Math in the reference as MathML, converted at build time by docutils' own LaTeX-to-MathML
translator: no JavaScript and no network, so the pages render offline (CI has no network but
PyPI/Debian, and MathJax's default is a CDN); every current browser shows MathML Core
(Chromium 109+, Firefox, Safari).

A formula the translator cannot read fails the build (Sphinx's ``-W``) with the formula named.
"""

from docutils import nodes
from docutils.utils.math import MathError, latex2mathml
from sphinx.errors import ExtensionError
from sphinx.util import logging

logger = logging.getLogger(__name__)


def _mathml(self, node, *, block: bool) -> str:
    tex = node.astext()
    try:
        return latex2mathml.tex2mathml(tex, as_block=block)
    except (MathError, SyntaxError) as exc:
        logger.warning("MathML: cannot translate %r: %s", tex, exc, location=node)
        return self.encode(tex)


def visit_inline(self, node):
    self.body.append(f'<span class="math notranslate">{_mathml(self, node, block=False)}</span>')
    raise nodes.SkipNode


def visit_block(self, node):
    if node.get("label"):
        self.body.append(f'<span class="eqno">({node["number"]})</span>')
    self.body.append(f'<div class="math notranslate">{_mathml(self, node, block=True)}</div>')
    raise nodes.SkipNode


def setup(app):
    try:
        app.add_html_math_renderer("mathml", (visit_inline, None), (visit_block, None))
    except ExtensionError:  # already registered (a second build in one process)
        pass
    app.config.html_math_renderer = "mathml"
    return {"parallel_read_safe": True, "parallel_write_safe": True}
