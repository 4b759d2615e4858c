"""A generated block of a docs page, between two marker lines, rewritten from
generated text (the papers table, the recovery and estimator-study tables, the
benchmark table): one rule for every generator."""

from __future__ import annotations

import pathlib

DOCS = pathlib.Path(__file__).resolve().parent.parent / "docs"


def rewrite(start: str, end: str, text: str, *, page: pathlib.Path, check: bool = False) -> bool:
    """Puts `text` between the lines `start` and `end` of `page` (with `check`:
    only compares). Returns True when the page already held it."""
    content = page.read_text()
    if start not in content or end not in content:
        raise SystemExit(f"{page.name} has no {start.strip()} ... {end.strip()} block.")
    i, j = content.index(start) + len(start), content.index(end)
    if content[i:j] == text:
        return True
    if not check:
        page.write_text(content[:i] + text + content[j:])
    return False
