"""Every notebook runs to the end at its small size (JAXPILE_NOTEBOOK_SIZE=small),
so the notebooks never rot."""

import pathlib

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
