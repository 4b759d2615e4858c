"""`make bench`: every benchmark at a size that finishes in about ten minutes on
two CPU cores, its JSON written to `benchmarks/results/<backend>/`, and the
benchmark table of docs/performance.md regenerated from those files.

Each benchmark script runs in its own process (a fresh JAX: no compile cache or
memory carried from one to the next) with the arguments below; `--full` runs
them at the issue's full sizes instead (much longer on a CPU; the size a GPU
run should use). The table is rebuilt from every results folder present, so a
GPU run adds its rows beside the CPU ones.

    python benchmarks/run_all.py [--full] [--only NAME,...] [--no-table]
"""

from __future__ import annotations

import argparse
import json
import os
import pathlib
import subprocess
import sys
import time

HERE = pathlib.Path(__file__).resolve().parent
PAGE = HERE.parent / "docs" / "performance.md"
START, END = "<!-- bench-table:start -->", "<!-- bench-table:end -->"

# name -> (script, small arguments, full arguments)
BENCHMARKS = {
    "vs_lammps": ("vs_lammps.py", ["--small", "--cases", "lattice,pour"], ["--cases", "lattice,pour"]),
    # the issue's own pour, 1000 disks, in every run (about a minute): the small one above is launch-bound
    "vs_lammps_pour": ("vs_lammps.py", ["--cases", "pour", "--pour-laws", ""], ["--cases", "pour"]),
    # the batch on every core: one JAX device per core (JAXPILE_HOST_DEVICES, see ENV)
    "vs_lammps_ensemble": ("vs_lammps.py", ["--small", "--cases", "ensemble"], ["--cases", "ensemble"]),
    # the 3D cone pour, one cone and a batch of 4, against LAMMPS replaying its insertion
    "cone_vs_lammps": ("cone_vs_lammps.py", ["--n", "100", "--settle", "5000", "--members", "4"],
                       ["--n", "200", "--members", "4", "--cases", "one,large,ensemble"]),
    "scaling": ("scaling.py", ["--sizes", "1000,10000,100000", "--steps", "200"], ["--steps", "2000"]),
    "gradient": ("gradient_cost.py", ["--horizons", "250,1000", "--no-horizon"],
                 ["--horizons", "250,1000,4000,16000", "--no-horizon"]),
    "ensemble_vmap": ("ensemble_throughput.py", ["--members", "8", "--n", "100", "--steps", "1000"],
                      ["--members", "64", "--n", "409", "--steps", "5000"]),
    "profile": ("profile_step.py", ["--steps", "300"], ["--steps", "2000"]),
    "rebuild": ("rebuild_cost.py", ["--repeats", "500"], ["--repeats", "2000"]),
    "granular_cost": ("granular_cost.py", [], ["--layers", "45", "--steps", "20000"]),
}


ENV = {"vs_lammps_ensemble": {"JAXPILE_HOST_DEVICES": str(os.cpu_count() or 1)},
       # piles of 1e3 to 1e5 disks: XLA's threads, as `jaxpile pile` gives a pile of 2000 disks or more
       "scaling": {"PJRT_NPROC": str(len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity")
                                     else os.cpu_count() or 1)}}
"""Extra environment of a benchmark's process."""


def backend() -> str:
    out = subprocess.run([sys.executable, "-c", "import jax; print(jax.default_backend())"],
                         capture_output=True, text=True, check=True)
    return out.stdout.strip().splitlines()[-1]


def fmt(x) -> str:
    return "—" if x is None else f"{x:.3g}"


def table(results_root: pathlib.Path) -> str:
    """The markdown table of every `table` row in every results JSON."""
    lines = ["| machine | case | jaxpile (particle-steps/s) | LAMMPS (particle-steps/s) | jaxpile / LAMMPS | note |",
             "|---|---|---|---|---|---|"]
    for path in sorted(results_root.glob("*/*.json")):
        data = json.loads(path.read_text())
        machine = data.get("machine", path.parent.name)
        # benchmark rows only: other studies in results/ (the hopper's) keep tables of their own
        for row in (r for r in data.get("table", []) if isinstance(r, dict) and "case" in r and "jaxpile" in r):
            ratio = row.get("ratio")
            lines.append(f"| {machine} | {row['case']} | {fmt(row.get('jaxpile'))} | {fmt(row.get('lammps'))} | "
                         f"{'—' if ratio is None else f'{ratio:.2f}x'} | {row.get('note', '')} |")
    return "\n".join(lines)


def update_page(text: str) -> bool:
    """Writes `text` as the benchmark table of docs/performance.md; False (and
    a warning) when the page has no table block."""
    import docs_block

    content = PAGE.read_text()
    if START not in content or END not in content:
        print(f"{PAGE.name} has no {START} ... {END} block; table not written", file=sys.stderr)
        return False
    docs_block.rewrite(START + "\n", END, text + "\n", page=PAGE)
    return True


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--full", action="store_true", help="the issue's full sizes")
    parser.add_argument("--only", default=None, help="comma-separated names: " + ",".join(BENCHMARKS))
    parser.add_argument("--no-table", action="store_true", help="do not rewrite the table in docs/performance.md")
    args = parser.parse_args(argv)

    names = list(BENCHMARKS) if args.only is None else args.only.split(",")
    unknown = set(names) - set(BENCHMARKS)
    if unknown:
        parser.error(f"unknown benchmark(s) {sorted(unknown)}; known: {list(BENCHMARKS)}")
    out_dir = HERE / "results" / backend()
    out_dir.mkdir(parents=True, exist_ok=True)
    failed = []
    t_all = time.perf_counter()
    for name in names:
        script, small, full = BENCHMARKS[name]
        cmd = [sys.executable, str(HERE / script), *(full if args.full else small), "--out", str(out_dir / f"{name}.json")]
        print(f"\n== {name}: {' '.join(cmd[1:])}", flush=True)
        t0 = time.perf_counter()
        if subprocess.run(cmd, env={**os.environ, **ENV.get(name, {})}).returncode != 0:
            failed.append(name)
        print(f"== {name}: {time.perf_counter() - t0:.0f} s", flush=True)
    print(f"\nall benchmarks: {time.perf_counter() - t_all:.0f} s; results in {out_dir}")
    if not args.no_table:
        text = table(HERE / "results")
        if update_page(text):
            print("docs/performance.md's benchmark table regenerated")
        print(text)
    if failed:
        print(f"failed: {failed}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
