"""A README block between two marker lines, rewritten from generated text
(the papers table, the recovery table): one rule for every generator."""

from __future__ import annotations

import pathlib

README = pathlib.Path(__file__).resolve().parent.parent / "README.md"


def rewrite(start: str, end: str, text: str, *, check: bool = False, readme: pathlib.Path = README) -> bool:
    """Puts `text` between the lines `start` and `end` of README (with `check`:
    only compares). Returns True when README already held it."""
    content = readme.read_text()
    if start not in content or end not in content:
        raise SystemExit(f"README.md has no {start.strip()} ... {end.strip()} block.")
    i, j = content.index(start) + len(start), content.index(end)
    if content[i:j] == text:
        return True
    if not check:
        readme.write_text(content[:i] + text + content[j:])
    return False
