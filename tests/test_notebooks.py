"""Every notebook runs to the end at its small size (JAXPILE_NOTEBOOK_SIZE=small),
so the notebooks never rot."""

import pathlib
import re

import nbformat
from nbclient import NotebookClient

# recipes.ipynb is README's recipes with their outputs (tools/recipes_notebook.py): tests/test_readme.py
# runs that code and checks the notebook holds it, so it is not run twice
NOTEBOOKS = sorted(p for p in (pathlib.Path(__file__).parent.parent / "notebooks").glob("*.ipynb")
                   if p.name != "recipes.ipynb")


def _run_to_the_end(path, monkeypatch, tmp_path):
    monkeypatch.setenv("JAXPILE_NOTEBOOK_SIZE", "small")
    monkeypatch.setenv("MPLBACKEND", "Agg")
    nb = nbformat.read(path, as_version=4)
    # "python3" is jupyter_client's native kernel: it runs this interpreter (the .venv's)
    client = NotebookClient(nb, timeout=900, kernel_name="python3",
                            resources={"metadata": {"path": str(tmp_path)}})
    client.execute()
    outputs = "".join(o.get("text", "") for c in nb.cells if c.cell_type == "code" for o in c.get("outputs", []))
    assert "verdict" in outputs  # reached the closing table
    nbformat.write(nb, tmp_path / path.name)


# One test class per notebook: `make test` distributes the suite with
# `pytest -n N --dist loadscope`, which schedules each class as a unit, so the
# notebooks run side by side on different workers.
def _notebook_class(path):
    def test_runs_to_the_end(self, monkeypatch, tmp_path):
        _run_to_the_end(path, monkeypatch, tmp_path)

    name = "TestNotebook_" + path.stem
    return name, type(name, (), {"test_runs_to_the_end": test_runs_to_the_end, "__doc__": f"notebooks/{path.name}"})


for _path in NOTEBOOKS:
    _name, _cls = _notebook_class(_path)
    globals()[_name] = _cls


def test_every_notebook_has_a_test_class():
    assert NOTEBOOKS and all(("TestNotebook_" + p.stem) in globals() for p in NOTEBOOKS)


def _tool(name):
    """A module of tools/ (not a package: the dev tools stay out of the install)."""
    import importlib.util

    path = pathlib.Path(__file__).resolve().parents[1] / "tools" / f"{name}.py"
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


PAPERS = {"liffman1992": "1992", "lee_herrmann1993": "1993", "baxter1997": "1997"}
DRAWS = re.compile(r"\b\w*_figure\(|\bplt\.(subplots|figure|plot|gca|errorbar)\(|\bax\.\w+\(")
"""A code cell that draws: one of jaxpile's figures, or matplotlib by hand."""


def test_committed_notebooks_hold_the_outputs_of_their_code_and_judge_the_papers_from_ensembles():
    """Each notebook is stored with its outputs (the docs site and GitHub show them), made from the code as
    committed (tools/execute_notebooks.py records a hash of the code cells: edit a cell and run it again),
    without an error, each cell that draws with its figure; a paper notebook's closing table judges the paper's figures from the committed
    ensembles (one verdict per row of the papers table), its own single piles shown and not judged."""
    execute_notebooks = _tool("execute_notebooks")
    import sys

    sys.path.insert(0, str(execute_notebooks.ROOT / "benchmarks" / "studies" / "papers"))
    import papers

    for path in NOTEBOOKS:
        nb = nbformat.read(path, as_version=4)
        stored = nb.metadata.get("jaxpile", {})
        assert stored.get("code_hash") == execute_notebooks.code_hash(nb), \
            f"{path.name}: its outputs are not of its code; run `python tools/execute_notebooks.py {path.stem}`"
        code = [c for c in nb.cells if c.cell_type == "code"]
        assert all(c.execution_count is not None for c in code), path.name
        assert not any(o.get("output_type") == "error" for c in code for o in c.outputs), path.name
        blank = [k for k, c in enumerate(code) if DRAWS.search(c.source)
                 and not any("image/png" in o.get("data", {}) for o in c.outputs)]
        assert blank == [], f"{path.name}: code cells {blank} draw and hold no figure: run tools/execute_notebooks.py"
        closing = "".join(o.get("text", "") for o in code[-1].outputs)
        if path.stem in PAPERS:
            rows = papers.verdict_rows(PAPERS[path.stem])
            assert closing.count("    verdict: ") == len(rows) > 0, path.name
            for quantity, _, _, verdict in rows:
                assert f"{quantity}\n" in closing and f"verdict: {verdict}\n" in closing, (path.name, quantity)
            assert "this notebook's run" in closing
        else:
            assert "verdict" in closing, path.name
