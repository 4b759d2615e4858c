"""One ensemble on one machine at several instruction sets: README's box
(Lee & Herrmann 1993, `lee-herrmann` law, 72 disks, W = H = 1.6 cm) at
mu = 0.1, 0.3, 0.5, 16 piles each, XLA compiling for each level in turn
(`--xla_cpu_max_isa`, one process a level: XLA reads its flags once).

    python benchmarks/studies/reproducibility/isa_box.py            # about 10 minutes on 2 cores
    python benchmarks/studies/reproducibility/isa_box.py --table    # docs/testing.md's table from the JSON

Writes benchmarks/results/reproducibility/isa_box.json (each level's angles,
pile by pile, and their summaries) and the table between the markers in
docs/testing.md: the same seeds give other piles on another instruction set,
and the same statistics.
"""

from __future__ import annotations

import argparse
import json
import os
import pathlib
import subprocess
import sys

ROOT = pathlib.Path(__file__).resolve().parents[3]
sys.path.insert(0, str(ROOT / "benchmarks"))  # machine
RESULT = ROOT / "benchmarks" / "results" / "reproducibility" / "isa_box.json"
PAGE = ROOT / "docs" / "testing.md"
BEGIN, END = "<!-- isa_box table: begin -->", "<!-- isa_box table: end -->"

LEVELS = ("default", "AVX2", "AVX", "SSE4_2")
"""The CPU's own code first, then the levels below it."""

MU = (0.1, 0.3, 0.5)
SEEDS = 16
OPTIONS = {"n": 72, "width": 1.6, "height": 1.6}

ONE_LEVEL = """
import json, sys
import jaxpile as jp
jp.configure()
rows = jp.sweep("box", "lee-herrmann", vary={"mu": %r}, seeds=%d, options=%r, progress=False)
angles = {str(m): [r["repose_cumulative_parabola"] for r in rows.rows if r["mu"] == m] for m in %r}
print(json.dumps({"angles": angles, "summary": jp.summarise(rows, "mu", "repose_cumulative_parabola"),
                  "settings": rows.info["settings"]}))
""" % (list(MU), SEEDS, OPTIONS, list(MU))


def run_level(level: str) -> dict:
    env = {k: v for k, v in os.environ.items() if k not in ("XLA_FLAGS", "PJRT_NPROC", "JAXPILE_MULTI_OUTPUT_FUSION")}
    if level != "default":
        env["XLA_FLAGS"] = f"--xla_cpu_max_isa={level}"
    done = subprocess.run([sys.executable, "-c", ONE_LEVEL], env=env, capture_output=True, text=True, check=True)
    return json.loads(done.stdout.strip().splitlines()[-1])


def table(record: dict) -> str:
    rows = ["| instruction set | " + " | ".join(f"θ_R at μ = {m} (deg)" for m in MU) + " | piles measured |",
            "|---|" + "---|" * (len(MU) + 1)]
    for level in record["levels"]:
        s = record["results"][level]["summary"]
        cells = [f"{mean:.1f} ± {se:.1f}" for mean, se in zip(s["mean"], s["stderr"])]
        name = f"default ({record['default_isa']})" if level == "default" else level
        rows.append(f"| {name} | " + " | ".join(cells) + f" | {sum(s['count'])} of {sum(s['count']) + sum(s['missing'])} |")
    note = (f"\n\nMean ± standard error over {SEEDS} piles (seeds 0–{SEEDS - 1}), cumulative-parabola method; "
            f"{record['cpu']}, jax {record['jax']}. From `python benchmarks/studies/reproducibility/isa_box.py` "
            "(`benchmarks/results/reproducibility/isa_box.json`).")
    return "\n".join(rows) + note


def rewrite_page(check: bool = False) -> bool:
    """Puts the table into docs/testing.md; with `check`, whether it is there already."""
    record = json.loads(RESULT.read_text())
    text = PAGE.read_text()
    head, rest = text.split(BEGIN, 1)
    _, tail = rest.split(END, 1)
    new = f"{head}{BEGIN}\n{table(record)}\n{END}{tail}"
    if check:
        return new == text
    PAGE.write_text(new)
    return True


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--table", action="store_true", help="rewrite docs/testing.md's table from the JSON only")
    args = parser.parse_args()
    if not args.table:
        from machine import details

        results = {}
        for level in LEVELS:
            print(f"isa_box: {level} ...", flush=True)
            results[level] = run_level(level)
            print(f"isa_box: {level}: {results[level]['summary']}", flush=True)
        machine = details()  # after the levels: it starts JAX in this process, which runs no pile
        record = {"cpu": machine["processor"], "default_isa": machine["vector_isa"] or "this CPU's",
                  "jax": machine["jax_version"], "mu": list(MU), "seeds": SEEDS,
                  "options": OPTIONS, "levels": list(LEVELS), "results": results,
                  "command": "python benchmarks/studies/reproducibility/isa_box.py"}
        RESULT.parent.mkdir(parents=True, exist_ok=True)
        RESULT.write_text(json.dumps(record, indent=1) + "\n")
    rewrite_page()
    print(table(json.loads(RESULT.read_text())))


if __name__ == "__main__":
    main()
