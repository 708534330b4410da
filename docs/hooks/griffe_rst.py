"""Griffe extension for the API reference: the docstrings' reStructuredText as Markdown.

cipval's docstrings use Sphinx roles (``:mod:`cip.runner```, ``:func:`~x.y```) and
reStructuredText simple tables (rows between ``=====  =====`` borders).  mkdocstrings
renders Markdown, so the roles would show as literal text and the tables as one
paragraph: this extension rewrites each role as inline code (the last component with
``~``, as Sphinx shows it) and wraps each simple table in a text block.  It changes
only what the documentation site shows, never the code.  Loaded by ``mkdocs.yml``
(``extensions``), from the repository root.
"""

from __future__ import annotations

import re
from typing import Any

import griffe

_ROLE = re.compile(r":(?:py:)?(?:mod|func|class|data|attr|meth|exc|obj|const):`(~?)([^`]+)`")
_BORDER = re.compile(r"^(\s*)=+(?:\s+=+)+\s*$")


def _role(m: re.Match) -> str:
    target = m.group(2)
    return f"`{target.rsplit('.', 1)[-1] if m.group(1) else target}`"


def _tables(text: str) -> str:
    """Each reStructuredText simple table (three border lines) as a fenced text block."""
    out: list[str] = []
    lines = text.splitlines()
    i = 0
    while i < len(lines):
        m = _BORDER.match(lines[i])
        if m is None:
            out.append(lines[i])
            i += 1
            continue
        borders, j = 0, i
        while j < len(lines):
            if _BORDER.match(lines[j]):
                borders += 1
                if borders == 3:
                    break
            j += 1
        if borders < 3:  # not a table: keep the line as it is
            out.append(lines[i])
            i += 1
            continue
        indent = m.group(1)
        table = [line.replace("`", "") for line in lines[i : j + 1]]  # code, not markup
        out += ["", f"{indent}```text", *table, f"{indent}```", ""]
        i = j + 1
    return "\n".join(out)


def _rewrite(obj: griffe.Object) -> None:
    if obj.docstring is not None:
        obj.docstring.value = _tables(_ROLE.sub(_role, obj.docstring.value))


class RstToMarkdown(griffe.Extension):
    """Rewrite Sphinx roles and simple tables in every docstring (module docstring)."""

    def on_package(self, *, pkg: griffe.Module, **kwargs: Any) -> None:
        _rewrite(pkg)  # the package itself (on_object sees only its members)

    def on_object(self, *, obj: griffe.Object, **kwargs: Any) -> None:
        _rewrite(obj)
