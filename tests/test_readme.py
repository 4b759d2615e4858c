"""README's ```python blocks run as written, in order, as one script in a
user's environment (none of the suite's XLA settings), and print what their
comments say: the four recipes are what a newcomer pastes first."""

import ast
import math
import os
import pathlib
import re
import subprocess
import sys

README = pathlib.Path(__file__).resolve().parents[1] / "README.md"
SUITE_SETTINGS = ("XLA_FLAGS", "PJRT_NPROC", "JAXPILE_MULTI_OUTPUT_FUSION", "JAXPILE_HOST_DEVICES")


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


def test_readme_recipes_run_as_written_and_print_what_they_say(tmp_path):
    script = "\n".join(python_blocks(README.read_text()))
    env = {k: v for k, v in os.environ.items() if k not in SUITE_SETTINGS}
    done = subprocess.run([sys.executable, "-c", script], cwd=tmp_path, env=env, capture_output=True, text=True,
                          timeout=900)
    assert done.returncode == 0, done.stderr[-3000:]
    angle, summary, derivative, fitted = done.stdout.strip().splitlines()[-4:]
    assert 20.0 < float(angle) < 70.0, angle  # a frictional box pile stands
    summary = ast.literal_eval(summary)
    assert summary["x"] == [0.1, 0.3, 0.5] and summary["count"] == [3, 3, 3], summary
    assert summary["mean"][0] < summary["mean"][2], summary  # steeper with more friction
    assert math.isfinite(float(derivative)) and float(derivative) != 0.0, derivative
    assert abs(float(fitted) - 0.3) < 0.003, fitted
