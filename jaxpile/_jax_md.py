"""The jax-md modules jaxpile uses, `dataclasses` and `partition` (with the
`space` and `util` they import), without running jax-md's package `__init__`.

`import jax_md` runs the package's `__init__`, which imports every module it
has: `energy` with its neural-network potentials (flax, e3nn, sympy, scipy) and
`rigid_body`, which computes at import: about six times as long as importing
jaxpile, most of every `jaxpile` command's start-up and of the time to refuse
a run too big for the machine (docs/choices.md#importing-jax-md).

So the package is put in `sys.modules` only while its four modules load, and
taken out again: what stays is jax-md's own modules, run as written, under
their own names (`jax_md.partition`, ...), and no package object of ours. A
later `import jax_md` runs jax-md's `__init__`, which finds those modules
loaded and uses them, so `jax_md.partition.NeighborList` is one class for
jaxpile and for the user. If jax-md was imported first, it is used as it is.
jaxpile imports jax-md's modules from here: `from jaxpile._jax_md import partition`.
"""

from __future__ import annotations

import importlib
import importlib.util
import sys

USED = ("dataclasses", "partition")
"""The jax-md modules jaxpile imports (`partition` brings `space` and `util`)."""


def _load(names: tuple[str, ...]) -> list:
    if "jax_md" in sys.modules:  # the package is imported already: its modules as usual
        return [importlib.import_module(f"jax_md.{name}") for name in names]
    spec = importlib.util.find_spec("jax_md")
    if spec is None or spec.loader is None or not spec.submodule_search_locations:
        raise ImportError("jaxpile needs jax-md (pip install jax-md).")
    sys.modules["jax_md"] = importlib.util.module_from_spec(spec)  # the package, its __init__ not run
    try:
        return [importlib.import_module(f"jax_md.{name}") for name in names]
    finally:
        del sys.modules["jax_md"]  # nothing of ours stays: a later `import jax_md` runs its __init__


dataclasses, partition = _load(USED)

__all__ = ["dataclasses", "partition"]
