"""README's ```python blocks run as written, in order, as one script in a
user's environment (none of the suite's XLA settings), and print what their
comments say: the four recipes are what a newcomer pastes first."""

import ast
import math
import pathlib
import re
import subprocess
import sys

from test_imports import clean_env

README = pathlib.Path(__file__).resolve().parents[1] / "README.md"


def python_blocks(text: str) -> list[str]:
    return re.findall(r"^```python\n(.*?)^```", text, flags=re.S | re.M)


def test_readme_is_one_page_and_its_recipes_use_few_jaxpile_names():
    text = README.read_text()
    assert len(text.splitlines()) <= 200
    blocks = python_blocks(text)
    assert len(blocks) == 4, "the four recipes"
    for block in blocks:
        names = set(re.findall(r"\bjp\.((?:fit\.)?\w+)", block))
        assert 1 <= len(names) <= 5, names


ROWS = "\nimport json\nprint(json.dumps({'rows': rows.rows, 'settings': rows.info['settings']}, default=float))\n"
"""Appended to the recipes by the test (not in README): recipe (b)'s rows and settings, to compare."""

SWEEP_FLAGS = ["sweep", "--protocol", "box", "--law", "lee-herrmann", "--n", "72", "--width", "1.6", "--height",
               "1.6", "--mu", "0.1,0.3,0.5", "--seeds", "3", "--no-progress"]
"""Recipe (b) as a command."""


def test_readme_recipes_run_as_written_and_the_sweep_is_the_command_s_bit_for_bit(tmp_path):
    """The recipes print what their comments say, and recipe (b)'s `jp.sweep`
    gives the rows `jaxpile sweep` gives with the same arguments, every number
    to the last bit (the command's sweep.csv holds each one's exact repr), under
    the same recorded settings: one seed, one result. The command reuses the
    recipe's compiled programs (the persistent compile cache)."""
    import csv
    import json

    script = "\n".join(python_blocks(README.read_text())) + ROWS
    env = clean_env()  # a user's environment, without the suite's XLA settings
    done = subprocess.run([sys.executable, "-c", script], cwd=tmp_path, env=env, capture_output=True, text=True,
                          timeout=900)
    assert done.returncode == 0, done.stderr[-3000:]
    angle, summary, derivative, fitted, rows = done.stdout.strip().splitlines()[-5:]
    assert 20.0 < float(angle) < 70.0, angle  # a frictional box pile stands
    summary = ast.literal_eval(summary)
    assert summary["x"] == [0.1, 0.3, 0.5] and summary["count"] == [3, 3, 3], summary
    assert summary["mean"][0] < summary["mean"][2], summary  # steeper with more friction
    assert math.isfinite(float(derivative)) and float(derivative) != 0.0, derivative
    assert abs(float(fitted) - 0.3) < 0.003, fitted

    ours = json.loads(rows)
    command = "import sys; from jaxpile.cli import main; sys.exit(main(sys.argv[1:]))"
    out = tmp_path / "cli"
    done = subprocess.run([sys.executable, "-c", command, *SWEEP_FLAGS, "--out", str(out)], env=env,
                          capture_output=True, text=True, timeout=900)
    assert done.returncode == 0, done.stderr[-3000:]
    with open(out / "sweep.csv") as fh:
        cli_rows = list(csv.DictReader(fh))
    assert len(cli_rows) == len(ours["rows"]) == 9
    compared = 0
    for cli_row, row in zip(cli_rows, ours["rows"]):
        for key, value in row.items():
            if isinstance(value, (int, float)) and not isinstance(value, bool) and key != "wall_seconds":
                text = cli_row[key]
                a = None if text in ("", "None") else float(text)
                same = a == value or (a is not None and value is not None and math.isnan(a) and math.isnan(value))
                assert same, (key, text, value)
                compared += 1
    assert compared >= 9 * 3, compared
    recorded = json.loads((out / "sweep.json").read_text())["settings"]
    keys = ("float64", "multi_output_fusion", "fusion_emitters")
    assert {k: recorded[k] for k in keys} == {k: ours["settings"][k] for k in keys} == dict.fromkeys(keys, True)


def test_the_recipes_notebook_is_readme_s_recipes_with_their_outputs():
    """notebooks/recipes.ipynb (tools/recipes_notebook.py: the docs' first tutorial) holds README's
    blocks as its code cells, each run and stored with what it printed."""
    import json

    notebook = json.loads((README.parent / "notebooks" / "recipes.ipynb").read_text())
    cells = [c for c in notebook["cells"] if c["cell_type"] == "code"]
    assert ["".join(c["source"]) for c in cells] == [b.rstrip("\n") for b in python_blocks(README.read_text())], \
        "README's recipes changed: run `python tools/recipes_notebook.py` and commit notebooks/recipes.ipynb"
    assert all(any(o.get("output_type") == "stream" for o in c.get("outputs", [])) for c in cells)
