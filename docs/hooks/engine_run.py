"""MkDocs hook: the engine tables of the documentation, rendered from a stored run.

A page that holds a marker line

    <!-- engines-run: data/engines-smoke.json -->

gets, in its place, the tables that ``cip-validate engines`` writes to its
``report.md`` (:func:`validation.engines.markdown`), rendered from the ``results.json``
of that run, kept at the path named (relative to ``docs/``).  The tables are therefore
never copied by hand: to refresh them, rerun the command the JSON records (its
``command`` field) and replace the file.  The report's title is dropped and its
headings demoted one level, so that they sit under the page's own.  Loaded by
``mkdocs.yml`` (``hooks``), from the repository root.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

_MARKER = re.compile(r"^<!-- engines-run: (\S+) -->$", re.MULTILINE)


def render(results: dict) -> str:
    """The report's markdown for ``results``, its title dropped and headings demoted."""
    from validation.engines import markdown

    lines = markdown(results).splitlines()
    if lines and lines[0].startswith("# "):
        lines = lines[1:]
    return "\n".join("#" + ln if ln.startswith("#") else ln for ln in lines)


def on_page_markdown(markdown: str, page, config, files) -> str:
    """Replace each marker with the tables of the run it names."""
    docs = Path(config["docs_dir"])

    def table(m: re.Match) -> str:
        path = docs / m.group(1)
        try:
            results = json.loads(path.read_text())
        except (OSError, ValueError) as exc:
            raise RuntimeError(f"engines-run marker in {page.file.src_path}: {exc}") from exc
        return render(results)

    return _MARKER.sub(table, markdown)
