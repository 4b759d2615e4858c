"""The module paths from before the package layout (issue 18), kept working.

`jaxpile.simulate` is `jaxpile.engine.simulate` (the same module object, so
private names and `monkeypatch.setattr` on either path reach the same code):
an import of an old path loads the new module and registers it under the old
name too. Imported by `jaxpile/__init__.py` before anything else of jaxpile.
"""

from __future__ import annotations

import importlib
import importlib.abc
import importlib.util
import sys

MOVED = {
    **{f"jaxpile.{m}": f"jaxpile.engine.{m}" for m in (
        "state", "boundaries", "neighbors", "_jax_md", "interactions", "collisions", "integrators", "blocks",
        "batch", "simulate", "checkpoint", "ensemble")},
    "jaxpile.analysis": "jaxpile.measure.analysis",
    "jaxpile.theory": "jaxpile.measure.theory",
    "jaxpile.estimators": "jaxpile.fit.estimators",
    "jaxpile.ensemble_fit": "jaxpile.fit.ensemble_fit",
    "jaxpile.ensemble_fit_command": "jaxpile.fit.command",
    "jaxpile.show": "jaxpile.cli.show",
}
"""Old module path -> where the module lives now."""


class _OldPaths(importlib.abc.MetaPathFinder, importlib.abc.Loader):
    """Answers an import of an old path with the module at its new path."""

    def find_spec(self, name, path=None, target=None):
        return importlib.util.spec_from_loader(name, self) if name in MOVED else None

    def create_module(self, spec):
        return importlib.import_module(MOVED[spec.name])  # the import system keeps its own attributes

    def exec_module(self, module):
        pass  # already executed at its new path


def install() -> None:
    if not any(isinstance(finder, _OldPaths) for finder in sys.meta_path):
        sys.meta_path.insert(0, _OldPaths())
