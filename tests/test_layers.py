"""The package's layers: `[tool.importlinter]` in pyproject.toml names them, top
to bottom (cli > fit > sweeps > batches > protocols | export > measure > engine > laws >
the ground modules > errors), and import-linter checks that each imports only
what lies below it (TYPE_CHECKING imports counted), that each contact law and
each command stands alone, and that the commands do not reach into the
engine's loop. Two rules its contracts cannot see are checked here too: no two
modules import each other (by any chain, inside one package included), and no
module reaches into another's private names."""

import ast
import pathlib
import sys

import grimp
import pytest
from importlinter.cli import lint_imports

REPO = pathlib.Path(__file__).resolve().parents[1]
PACKAGE = REPO / "jaxpile"


@pytest.fixture(scope="module")
def graph():
    """Every import between jaxpile's modules, those inside functions and under
    `if TYPE_CHECKING:` included."""
    return grimp.build_graph("jaxpile", include_external_packages=False, exclude_type_checking_imports=False,
                             cache_dir=None)


def test_the_import_linter_contracts_hold(monkeypatch):
    monkeypatch.chdir(REPO)
    assert lint_imports(config_filename=str(REPO / "pyproject.toml"), no_cache=True) == 0, (
        "a contract is broken: run `lint-imports` for the chain")


def _cycles(edges: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan)."""
    index, low, on_stack, stack, found, counter = {}, {}, set(), [], [], [0]

    def visit(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on_stack.add(v)
        for w in edges.get(v, ()):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    limit = sys.getrecursionlimit()
    sys.setrecursionlimit(max(limit, 10 * len(edges) + 100))
    try:
        for v in sorted(edges):
            if v not in index:
                visit(v)
    finally:
        sys.setrecursionlimit(limit)
    return found


def test_the_cycle_finder_finds_a_cycle():
    assert _cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert _cycles({"a": {"b"}, "b": set()}) == []


def test_no_two_modules_import_each_other(graph):
    edges = {m: set(graph.find_modules_directly_imported_by(m)) for m in graph.modules}
    assert _cycles(edges) == [], "import circles (a function-local import does not hide one)"


def _is_private(name: str) -> bool:
    return name.startswith("_") and not name.startswith("__")


def _private_uses(path: pathlib.Path, modules: set[str], root: pathlib.Path = REPO) -> list[str]:
    """`from jaxpile.x import _name` and `x._name` where x is another jaxpile
    module bound in `path`, as `file:line module.name`. A private module
    (`jaxpile._jax_md`) is its package's to import, like any module."""
    tree = ast.parse(path.read_text())
    here = ".".join(path.relative_to(root).with_suffix("").parts).removesuffix(".__init__")
    aliases, found = {}, []
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.module and node.module.split(".")[0] == "jaxpile":
            for a in node.names:
                if f"{node.module}.{a.name}" in modules:
                    aliases[a.asname or a.name] = f"{node.module}.{a.name}"
                elif _is_private(a.name) and node.module != here:
                    found.append(f"{path.name}:{node.lineno} {node.module}.{a.name}")
        elif isinstance(node, ast.Import):  # `import jaxpile.x as y` binds y; `import jaxpile.x` binds jaxpile
            aliases.update({a.asname or a.name.split(".")[0]: a.name if a.asname else a.name.split(".")[0]
                            for a in node.names if a.name in modules})
    for node in ast.walk(tree):
        if (isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) and _is_private(node.attr)
                and aliases.get(node.value.id, here) != here):
            found.append(f"{path.name}:{node.lineno} {aliases[node.value.id]}.{node.attr}")
    return found


def test_no_module_uses_another_modules_private_names(graph):
    modules = set(graph.modules)
    assert [use for path in sorted(PACKAGE.rglob("*.py")) for use in _private_uses(path, modules)] == []


def test_the_private_name_check_sees_both_forms(tmp_path, graph):
    (tmp_path / "jaxpile").mkdir()
    module = tmp_path / "jaxpile" / "a.py"
    module.write_text("import jaxpile\n"
                      "from jaxpile.engine.neighbors import _build, rebuild\n"
                      "from jaxpile.engine import simulate; from jaxpile import _jax_md\n"
                      "x = simulate._is_concrete, simulate.Simulator, _jax_md.partition, jaxpile._ONE_THREAD_BY_DEFAULT\n")
    assert sorted(_private_uses(module, set(graph.modules), tmp_path)) == [
        "a.py:2 jaxpile.engine.neighbors._build", "a.py:4 jaxpile._ONE_THREAD_BY_DEFAULT",
        "a.py:4 jaxpile.engine.simulate._is_concrete"]
