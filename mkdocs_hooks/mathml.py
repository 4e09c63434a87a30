"""TeX math to MathML while the docs site is built: the browser typesets it, with no script
and no network (mkdocs.yml lists this file under ``hooks``).

Two sources of math reach a page: the Markdown pages, where ``pymdownx.arithmatex`` (generic
mode) wraps each formula as ``<span class="arithmatex">\\(...\\)</span>`` or
``<div class="arithmatex">\\[...\\]</div>``, and the tutorial notebooks, whose Markdown cells
mkdocs-jupyter renders with the ``$...$`` and ``$$...$$`` left as written (and an empty
MathJax ``<script src="">``). Both are converted by ``latex2mathml``; code spans are left alone.
A formula it cannot parse stops the build (mkdocs names the page); a command it does not know
would be shown by name, which tests/docs/test_docs_site.py catches.
"""

from __future__ import annotations

import html
import re

from latex2mathml.converter import convert

ARITHMATEX = re.compile(r'<(span|div) class="arithmatex">\s*\\([(\[])(.*?)\\[)\]]\s*</\1>', re.S)
"""A formula as pymdownx.arithmatex writes it (generic mode)."""

NOTEBOOK_MARKDOWN = re.compile(r'(data-mime-type="text/markdown">)(.*?)(</div>)', re.S)
"""The rendered HTML of a notebook's Markdown cell (its paragraphs and lists: no nested div)."""

CODE = re.compile(r"(<code[^>]*>.*?</code>|<pre[^>]*>.*?</pre>)", re.S)
DOLLARS = re.compile(r"(?<![\\$])\$\$(.+?)\$\$|(?<![\\$])\$(?!\s)([^$]+?)(?<!\s)\$(?!\d)", re.S)
"""``$$display$$`` or ``$inline$`` (a ``$`` followed by a space or closing before a digit is
not math: ``$ 5``, ``$5 and $6``)."""

MATHJAX = re.compile(r'<script src="">\s*</script>\s*(?:<!-- MathJax configuration -->.*?'
                     r"<!-- End of mathjax configuration -->)?", re.S)
"""The notebook template's MathJax: an empty script address and its configuration."""


def to_mathml(tex: str, block: bool) -> str:
    """One formula (HTML-escaped TeX, as it stands in the page) as a MathML element."""
    return convert(html.unescape(tex).strip(), display="block" if block else "inline")


def _dollars(text: str) -> str:
    """The ``$...$`` and ``$$...$$`` of a notebook cell's HTML as MathML, outside code."""
    parts = CODE.split(text)
    for i in range(0, len(parts), 2):  # the even parts lie outside <code> and <pre>
        parts[i] = DOLLARS.sub(lambda m: to_mathml(m[1] if m[1] is not None else m[2], m[1] is not None),
                               parts[i])
    return "".join(parts)


def on_page_content(html_text: str, page, config, files) -> str:
    """mkdocs hook: the page's HTML with its math as MathML."""
    out = ARITHMATEX.sub(lambda m: to_mathml(m[3], m[2] == "["), html_text)
    out = NOTEBOOK_MARKDOWN.sub(lambda m: m[1] + _dollars(m[2]) + m[3], out)
    return MATHJAX.sub("", out)
