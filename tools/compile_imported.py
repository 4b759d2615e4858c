"""Byte-compiles the installed modules that jaxpile, its commands, notebooks and
test suite import (and jax, jaxlib, jax-md and optax whole), and no others:
`make` installs with `pip install --no-compile` and then runs this.

pip byte-compiles every file it installs, one at a time; jax-md's requirements
alone bring tens of thousands of lines jaxpile never imports (a materials
library, symbolic algebra, plotting and data-frame packages), and compiling
them was about half of a fresh install (docs/choices.md#the-install). The
bytecode is only a cache: a module this leaves out still imports, parsed from
its source (in every process, where PYTHONDONTWRITEBYTECODE is set).

    .venv/bin/python tools/compile_imported.py   # with the python of the environment to compile
"""

from __future__ import annotations

import compileall
import importlib
import os
import pathlib
import sys
import sysconfig

# What the package, its commands, notebooks, docs build and test suite import, at the top and inside
# functions (scipy.stats for an ensemble fit's interval, tqdm for progress), in the workers and in the
# processes the suite starts (xdist's, the notebook kernels, the docs build).
ROOTS = ("jaxpile", "jaxpile.cli", "jaxpile.fit", "jaxpile.fit.ensemble_fit", "jaxpile.sweeps",
         "jaxpile.distributed", "jax.numpy", "jax.scipy", "scipy.stats", "tqdm.auto", "optax", "matplotlib.pyplot",
         "numpy", "pytest", "xdist.plugin", "xdist.remote", "_hypothesis_pytestplugin", "hypothesis", "nbclient",
         "nbformat", "ipykernel.kernelapp", "IPython", "importlinter", "mkdocs", "mkdocs.commands.build",
         "material", "mkdocstrings", "mkdocstrings_handlers.python", "mkdocs_jupyter", "mkdocs_jupyter.plugin")
WHOLE = ("jax", "jaxlib", "jax_md", "optax")


def main() -> int:
    sys.dont_write_bytecode = False  # each import below writes its module's bytecode as it loads
    for name in ROOTS:
        try:
            importlib.import_module(name)
        except Exception:  # noqa: BLE001 - an extra not installed, or one that fails: bytecode is only a cache
            pass
    # the engine's packages whole, for the submodules they import lazily (jax's on first use);
    # quiet=2: a file that does not compile (test data for another Python) is skipped, as pip skips it
    site = pathlib.Path(sysconfig.get_paths()["purelib"])
    whole = [site / name for name in WHOLE if (site / name).is_dir()]
    for path in whole:
        compileall.compile_dir(path, quiet=2, workers=os.cpu_count() or 1)
    imported = sum(1 for m in list(sys.modules.values()) if str(getattr(m, "__file__", "")).startswith(str(site)))
    print(f"byte-compiled the {imported} modules imported and {', '.join(p.name for p in whole)} whole, in {site}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
