"""A griffe extension for the docs site: each docstring's first line becomes its
first whole sentence.

mkdocstrings' summary tables (a module's classes and functions, the package's
modules) show a docstring's first line, and ours wrap their first sentence over
two or three lines, so a summary read "...contact networks, surfaces and". The
docstring is rewritten for the site only: the first paragraph's lines joined,
its first sentence alone on the first line, the rest of the paragraph on the
next (Markdown renders the paragraph as before). mkdocs.yml loads it
(`extensions` of the python handler); `tests/test_docs.py` checks the summaries.
"""

from __future__ import annotations

import re

import griffe

# words that end in a full stop without ending a sentence
_ABBREVIATIONS = ("e.g.", "i.e.", "et al.", "eq.", "eqs.", "fig.", "figs.", "sec.", "vs.", "cf.", "approx.", "no.")
_END = re.compile(r"[.!?](?=\s+[A-Z`(\"'])")


def first_sentence(paragraph: str) -> tuple[str, str]:
    """`(first sentence, the rest)` of one paragraph of text (one line of it)."""
    for match in _END.finditer(paragraph):
        head = paragraph[:match.end()]
        if head.lower().endswith(_ABBREVIATIONS):
            continue
        return head, paragraph[match.end():].strip()
    return paragraph, ""


def summary_first(text: str) -> str:
    """The docstring `text` with its first sentence alone on its first line."""
    lines = text.split("\n")
    end = next((k for k, line in enumerate(lines) if not line.strip()), len(lines))
    if end <= 1 and not first_sentence(lines[0].strip())[1]:
        return text  # a one-line summary already
    paragraph = " ".join(line.strip() for line in lines[:end])
    head, rest = first_sentence(paragraph)
    return "\n".join([head, *([rest] if rest else []), *lines[end:]])


class FirstSentenceSummaries(griffe.Extension):
    """Rewrites each object's docstring with `summary_first` as it is loaded."""

    def on_instance(self, *, obj, **kwargs) -> None:
        if obj.docstring is not None and obj.docstring.value:
            obj.docstring.value = summary_first(obj.docstring.value)
