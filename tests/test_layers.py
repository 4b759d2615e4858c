"""The package layout (issue 18): each layer imports only the layers below it,
and the old flat module paths are the same modules as the new ones."""

import ast
import importlib
import pathlib

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[1] / "jaxpile"

# a layer may import itself and what is listed for it (the modules at the package's top are the base)
BASE = {"errors", "ranges", "budget", "io", "_compat", "_version"}
ALLOWED = {
    "engine": {"engine", "laws"},
    "laws": {"laws", "engine"},  # laws read the engine's pair geometry and state types
    "measure": {"measure", "engine", "laws"},
    "protocols": {"protocols", "engine", "laws", "measure", "runner", "sweep", "fit", "plot"},
    "runner": {"runner", "engine", "protocols"},
}


def _imports(path: pathlib.Path) -> set[str]:
    """Every `jaxpile.X` module a file imports when it runs, at its top or inside
    functions (not under `if TYPE_CHECKING:`, which is for annotations only)."""
    tree = ast.parse(path.read_text())
    for node in ast.walk(tree):
        if isinstance(node, ast.If) and getattr(node.test, "id", getattr(node.test, "attr", "")) == "TYPE_CHECKING":
            node.body = []
    found = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.module and node.module.split(".")[0] == "jaxpile":
            parts = node.module.split(".")
            if len(parts) == 1:
                found |= {f"jaxpile.{a.name}" for a in node.names}
            else:
                found.add(node.module)
        elif isinstance(node, ast.Import):
            found |= {a.name for a in node.names if a.name.split(".")[0] == "jaxpile"}
    return found


def _layer(module: str) -> str:
    from jaxpile._compat import MOVED

    module = MOVED.get(module, module)
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else ""


@pytest.mark.parametrize("layer", sorted(ALLOWED))
def test_a_layer_imports_only_the_layers_below_it(layer):
    files = sorted((ROOT / layer).rglob("*.py")) if (ROOT / layer).is_dir() else [ROOT / f"{layer}.py"]
    wrong = {}
    for path in files:
        bad = {m for m in _imports(path) if _layer(m) not in ALLOWED[layer] | BASE | {""}}
        if bad:
            wrong[str(path.relative_to(ROOT))] = sorted(bad)
    assert not wrong, wrong


def test_the_old_module_paths_are_the_new_modules():
    from jaxpile._compat import MOVED

    for old, new in MOVED.items():
        assert importlib.import_module(old) is importlib.import_module(new), old
    import jaxpile

    assert jaxpile.simulate is importlib.import_module("jaxpile.engine.simulate")
    assert jaxpile.blocks is importlib.import_module("jaxpile.engine.blocks")  # as an attribute, not imported
