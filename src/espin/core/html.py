"""Small HTML tables for the ``_repr_html_`` of espin's objects in Jupyter."""

from __future__ import annotations

import re
from collections.abc import Sequence
from html import escape

__all__ = ["html_table"]

_MICROMETRE = re.compile(r"\bum\b")


def html_table(caption: str, rows: Sequence[tuple[str, str]]) -> str:
    """A small HTML table for the ``_repr_html_`` (Jupyter) of espin's objects.

    Parameters
    ----------
    caption
        The table's caption (the class name).
    rows
        (quantity, value with its unit) pairs, one row each; the text is escaped and the
        unit ``um`` (as the one-line reprs write it) is shown as µm.

    Returns
    -------
    str
        ``<table>...</table>``.
    """
    body = "".join(
        f'<tr><th style="text-align:left">{escape(name)}</th>'
        f'<td style="text-align:left">{escape(_MICROMETRE.sub("µm", value))}</td></tr>'
        for name, value in rows
    )
    return f"<table><caption>{escape(caption)}</caption>{body}</table>"
