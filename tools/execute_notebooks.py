"""The tutorial notebooks run and stored with their outputs, so the docs site
and GitHub show their figures, numbers and closing verdicts without running
anything.

    python tools/execute_notebooks.py                  # every notebook but recipes.ipynb, at the small size
    python tools/execute_notebooks.py baxter1997       # one of them
    JAXPILE_NOTEBOOK_SIZE=full python tools/execute_notebooks.py lee_herrmann1993   # the paper's size (hours)

Each notebook runs in this interpreter's kernel, in a scratch folder (the
figures it writes stay out of notebooks/), in a user's environment (the
notebooks call `jaxpile.configure()` themselves). The size it ran at and a
hash of its code cells go into its metadata: tests/test_notebooks.py checks
that the stored outputs belong to the code as committed (edit a cell, run
this again). recipes.ipynb is README's recipes, written by
tools/recipes_notebook.py.
"""

from __future__ import annotations

import hashlib
import os
import pathlib
import sys
import tempfile
import time

ROOT = pathlib.Path(__file__).resolve().parents[1]
NOTEBOOKS = ROOT / "notebooks"
GENERATED_ELSEWHERE = {"recipes"}


def code_hash(nb) -> str:
    """A hash of a notebook's code cells, in order: what its outputs were made from."""
    text = "\n\0".join(c.source for c in nb.cells if c.cell_type == "code")
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def paper_notebooks() -> list[pathlib.Path]:
    return sorted(p for p in NOTEBOOKS.glob("*.ipynb") if p.stem not in GENERATED_ELSEWHERE)


def execute(path: pathlib.Path) -> float:
    import nbformat
    from nbclient import NotebookClient

    nb = nbformat.read(path, as_version=4)
    size = os.environ.setdefault("JAXPILE_NOTEBOOK_SIZE", "small")
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as scratch:
        NotebookClient(nb, timeout=None, kernel_name="python3", resources={"metadata": {"path": scratch}}).execute()
    for cell in nb.cells:
        if cell.cell_type == "code":  # tqdm's notice that ipywidgets is absent is about this kernel
            cell.outputs = [o for o in cell.outputs if "TqdmWarning" not in o.get("text", "")]
            cell.metadata.pop("execution", None)
    nb.metadata["jaxpile"] = {"size": size, "code_hash": code_hash(nb)}
    nbformat.write(nb, path)
    return time.perf_counter() - t0


def main(argv: list[str]) -> int:
    for name in ("XLA_FLAGS", "PJRT_NPROC", "JAXPILE_MULTI_OUTPUT_FUSION", "JAXPILE_HOST_DEVICES"):
        os.environ.pop(name, None)  # a user's environment
    # the kernel draws inline, so that each figure is stored as the cell's output (Agg would draw none)
    os.environ["MPLBACKEND"] = "module://matplotlib_inline.backend_inline"
    wanted = set(argv)
    chosen = [p for p in paper_notebooks() if not wanted or p.stem in wanted]
    if wanted - {p.stem for p in chosen}:
        print(f"no such notebook: {', '.join(sorted(wanted - {p.stem for p in chosen}))}", file=sys.stderr)
        return 2
    for path in chosen:
        print(f"{path.relative_to(ROOT)}: ran in {execute(path):.0f} s", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
