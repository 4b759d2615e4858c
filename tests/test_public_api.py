"""The public API, enforced: what `jaxpile/__init__.py` and the public
subpackages list in `__all__` (docstring of `jaxpile`), every name there
resolves, and the benchmarks, notebooks, docs and README use nothing else.

A module is public when each package above it names it in its `__all__`
(`jaxpile.laws.hooke`: `laws` in `jaxpile.__all__`, `hooke` in
`jaxpile.laws.__all__`); its public names are its `__all__`, or where it has
none, its own top-level names without a leading underscore. Everything else
is internal: tests may reach inside, the rest may not."""

import ast
import glob
import importlib
import json
import os
import re
import types

import pytest

ROOT = os.path.join(os.path.dirname(__file__), "..")

INTERNAL_ON_PURPOSE = {
    "benchmarks/rebuild_cost.py": "times the neighbour and pair list rebuild itself",
    "benchmarks/profile_step.py": "times the step's parts, the block of disks in play among them",
    "benchmarks/studies/fitting/truncation_study.py": "rolls batches out at a fixed list capacity, the "
                                                      "truncated estimator's own machinery",
}
"""Scripts that measure the engine's internals, which no public name reaches."""


def attribute(module_name: str, name: str):
    """`module.name`, importing a submodule a package does not import itself; None if there is none."""
    module = importlib.import_module(module_name)
    if not hasattr(module, name):
        try:
            importlib.import_module(f"{module_name}.{name}")
        except ImportError:
            return None
    return getattr(module, name, None)


def public_names(module_name: str) -> set:
    module = importlib.import_module(module_name)
    if hasattr(module, "__all__"):
        return set(module.__all__)
    return {n for n, v in vars(module).items() if not n.startswith("_") and not isinstance(v, types.ModuleType)
            and getattr(v, "__module__", module_name) == module_name}


def is_public_module(name: str) -> bool:
    parts = name.split(".")
    return all(parts[k] in public_names(".".join(parts[:k])) for k in range(1, len(parts)))


def public_modules(name: str = "jaxpile") -> list[str]:
    """Every public module, walked from `jaxpile` through the `__all__`s."""
    found = [name]
    for attr in sorted(public_names(name)):
        value = attribute(name, attr)
        if isinstance(value, types.ModuleType) and value.__name__ == f"{name}.{attr}":
            found += public_modules(value.__name__)
    return found


def uses():
    """`(where, python source)` of every benchmark, notebook code cell, and python block of the docs and README."""
    for path in sorted(glob.glob(os.path.join(ROOT, "benchmarks", "**", "*.py"), recursive=True)):
        if os.path.relpath(path, ROOT).replace(os.sep, "/") not in INTERNAL_ON_PURPOSE:
            yield os.path.relpath(path, ROOT), open(path).read()
    for path in sorted(glob.glob(os.path.join(ROOT, "notebooks", "*.ipynb"))):
        for k, cell in enumerate(json.load(open(path))["cells"]):
            if cell["cell_type"] == "code":
                lines = "".join(cell["source"]).splitlines()
                yield f"{os.path.relpath(path, ROOT)} cell {k}", "\n".join(
                    line for line in lines if not line.lstrip().startswith(("%", "!")))
    for path in [os.path.join(ROOT, "README.md"), *sorted(glob.glob(os.path.join(ROOT, "docs", "*.md")))]:
        for k, block in enumerate(re.findall(r"```python\n(.*?)```", open(path).read(), re.S)):
            yield f"{os.path.relpath(path, ROOT)} block {k}", block


def non_public(source: str) -> list[str]:
    """What `source` takes from jaxpile outside the public API: imports, and
    attributes read from an imported jaxpile module."""
    try:
        tree = ast.parse(source)
    except SyntaxError:  # a docs block with elided parts: its import lines alone
        tree = ast.parse("\n".join(line.strip() for line in source.splitlines()
                                   if re.match(r"\s*(from|import) jaxpile", line)))
    bad, modules = [], {}  # local name -> the public module it is
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                if alias.name.split(".")[0] == "jaxpile":
                    if not is_public_module(alias.name):
                        bad.append(f"import {alias.name}")
                    modules[alias.asname or "jaxpile"] = alias.name if alias.asname else "jaxpile"
        elif isinstance(node, ast.ImportFrom) and (node.module or "").split(".")[0] == "jaxpile":
            if not is_public_module(node.module):
                bad.append(f"from {node.module} import ...")
                continue
            for alias in node.names:
                value = attribute(node.module, alias.name)
                if alias.name not in public_names(node.module):
                    bad.append(f"from {node.module} import {alias.name}")
                elif isinstance(value, types.ModuleType):
                    modules[alias.asname or alias.name] = value.__name__
    for node in ast.walk(tree):
        chain, base = [], node
        while isinstance(base, ast.Attribute):
            chain.append(base.attr)
            base = base.value
        if not (chain and isinstance(base, ast.Name) and base.id in modules):
            continue
        module = modules[base.id]
        for attr in reversed(chain):
            if attr.startswith("__"):
                break
            if attr not in public_names(module):
                bad.append(f"{module}.{attr}")
                break
            value = attribute(module, attr)
            if not isinstance(value, types.ModuleType):
                break
            module = value.__name__
    return list(dict.fromkeys(bad))  # `a.b.c` and its inner `a.b` are one use


def test_every_name_in_a_public_all_resolves():
    """A stale name in an `__all__` (a function removed, its name left) is an error of the API."""
    missing = [f"{m}.{n}" for m in public_modules() for n in public_names(m) if attribute(m, n) is None]
    assert not missing, missing
    assert {"jaxpile.engine", "jaxpile.protocols.pour", "jaxpile.laws.hooke", "jaxpile.fit.ensemble_fit"} <= set(
        public_modules())
    assert not {"jaxpile.engine.loop", "jaxpile.protocols.stages", "jaxpile.engine.neighbors"} & set(public_modules())


def test_benchmarks_notebooks_docs_and_readme_use_the_public_api_only():
    found = [(where, what) for where, source in uses() for what in non_public(source)]
    assert not found, "\n".join(f"{where}: {what}" for where, what in found)


@pytest.mark.parametrize("source, says", [
    ("from jaxpile.engine.loop import run_chunks", "from jaxpile.engine.loop import ..."),
    ("import jaxpile\njaxpile.engine.simulate.Simulator", "jaxpile.engine.simulate"),
    ("from jaxpile.protocols import pour\npour._private", "jaxpile.protocols.pour._private"),
    ("from jaxpile.fit import ensemble_fit as ef\nef.no_such_name", "jaxpile.fit.ensemble_fit.no_such_name"),
])
def test_the_check_finds_an_internal_name(source, says):
    assert non_public(source) == [says]


def test_the_check_passes_the_public_ways_in():
    assert non_public("import jaxpile as jp\nfrom jaxpile.engine import Simulator\nfrom jaxpile.laws import hooke\n"
                      "jp.run\nhooke.make_params\njp.fit.ensemble_fit.fit\nfrom jaxpile.protocols import pour\n"
                      "pour.SPEC.run") == []
