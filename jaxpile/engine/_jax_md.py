"""jax-md's neighbour lists and pytree dataclasses, without importing all of jax-md.

`import jax_md` runs the package's `__init__`, which imports every module it
has: `energy` with its neural-network potentials (flax, e3nn, sympy, scipy) and
`rigid_body`, which computes at import: ten times as long as the four modules
jaxpile uses (`partition`, `space`, `util`, `dataclasses`), and it would be most
of every `jaxpile` command's start-up and of the time to refuse a run too big
for the machine (measured: docs/choices.md#importing-jax-md).

`register()` puts the package in `sys.modules` without running its `__init__`,
so `from jax_md import partition` loads that module and what it imports. A
module-level `__getattr__` (PEP 562) keeps the rest of jax-md one attribute
away: a submodule is imported on first use, and any other name runs jax-md's
own `__init__` once, so `import jax_md; jax_md.energy.soft_sphere(...)` after
`import jaxpile` works as it does without jaxpile. If jax-md was imported first, nothing
changes.
"""

from __future__ import annotations

import importlib
import importlib.util
import sys


def register() -> None:
    if "jax_md" in sys.modules:
        return
    spec = importlib.util.find_spec("jax_md")
    if spec is None or spec.loader is None or not spec.submodule_search_locations:
        return  # not installed as a package: the plain import reports it where it is used
    package = importlib.util.module_from_spec(spec)
    complete = []

    def __getattr__(name: str):
        if not name.startswith("__") and importlib.util.find_spec(f"jax_md.{name}") is not None:
            return importlib.import_module(f"jax_md.{name}")  # sets the attribute on the package
        if not complete:  # a name jax-md's __init__ defines: run it once, as `import jax_md` would have
            complete.append(True)
            spec.loader.exec_module(package)
            return getattr(package, name)
        raise AttributeError(f"module 'jax_md' has no attribute {name!r}")

    package.__getattr__ = __getattr__
    sys.modules["jax_md"] = package
