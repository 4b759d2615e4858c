"""A sweep on one process and on two (jaxpile.distributed), one core each: particle-steps per second,
wall time and the rows' gather, measured side by side, alternating.

    python benchmarks/distributed_throughput.py [--rounds 2] [--out benchmarks/results/cpu/distributed_throughput.json]

The sweep: 16 box piles (Lee & Herrmann 1993's law, 72 disks, mu 0.1-0.5 x 4 seeds). One process runs
them as one batch pinned to core 0; two processes (localhost coordinator) run 8 each, pinned to cores 0
and 1 (`taskset`). The compile cache is off so that every run compiles as a first run does. The
particle-steps per second are the sweep's own (run time only, summed over processes against the slower
one's); the wall time is the whole command's.
"""

from __future__ import annotations

import argparse
import json
import os
import pathlib
import subprocess
import sys
import tempfile
import time

HERE = pathlib.Path(__file__).resolve().parent
SWEEP = ["sweep", "--protocol", "box", "--law", "lee-herrmann", "--n", "72", "--width", "1.6", "--height", "1.6",
         "--mu", "0.1,0.2,0.3,0.5", "--seeds", "4", "--no-progress"]
COMMAND = "import sys; from jaxpile.cli import main; sys.exit(main(sys.argv[1:]))"


def _start(core: int, args: list[str], env: dict) -> subprocess.Popen:
    return subprocess.Popen(["taskset", "-c", str(core), sys.executable, "-c", COMMAND, *SWEEP, *args],
                            env={**os.environ, "JAXPILE_COMPILE_CACHE": "off", **env},
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)


def _finish(procs: list[subprocess.Popen]) -> None:
    for p in procs:
        _, err = p.communicate(timeout=3600)
        if p.returncode != 0:
            raise SystemExit(f"a sweep failed:\n{err[-2000:]}")


def one_process(folder: pathlib.Path) -> dict:
    t0 = time.perf_counter()
    _finish([_start(0, ["--out", str(folder)], {})])
    record = json.loads((folder / "sweep.json").read_text())
    return {"wall_seconds": time.perf_counter() - t0, "particle_steps_per_second": record["particle_steps_per_second"],
            "run_seconds": record["run_seconds"], "compile_seconds": record["compile_seconds"]}


def two_processes(folder: pathlib.Path) -> dict:
    from jaxpile import distributed

    env = {"JAXPILE_COORDINATOR": distributed.local_coordinator(), "JAXPILE_PROCESSES": "2"}
    t0 = time.perf_counter()
    procs = [_start(k, ["--distributed", "--out", str(folder)], {**env, "JAXPILE_PROCESS_ID": str(k)}) for k in (0, 1)]
    _finish(procs)
    record = json.loads((folder / "sweep.json").read_text())
    return {"wall_seconds": time.perf_counter() - t0, "particle_steps_per_second": record["particle_steps_per_second"],
            "run_seconds": record["run_seconds"], "compile_seconds": record["compile_seconds"],
            "gather_seconds": record["gather_seconds"]}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=2)
    parser.add_argument("--out", default=str(HERE / "results" / "cpu" / "distributed_throughput.json"))
    args = parser.parse_args(argv)
    if (os.cpu_count() or 1) < 2:
        raise SystemExit("two cores are needed: one a process")
    rounds = []
    with tempfile.TemporaryDirectory() as scratch:
        for k in range(args.rounds):
            one = one_process(pathlib.Path(scratch, f"one{k}"))
            two = two_processes(pathlib.Path(scratch, f"two{k}"))
            rounds.append({"one_process": one, "two_processes": two,
                           "rate_ratio": two["particle_steps_per_second"] / one["particle_steps_per_second"],
                           "wall_ratio": one["wall_seconds"] / two["wall_seconds"]})
            print(f"round {k}: one process {one['particle_steps_per_second']:.3g} particle-steps/s "
                  f"({one['wall_seconds']:.1f} s wall), two {two['particle_steps_per_second']:.3g} "
                  f"({two['wall_seconds']:.1f} s wall, gather {two['gather_seconds'] * 1e3:.0f} ms): "
                  f"rate x{rounds[-1]['rate_ratio']:.2f}, wall x{rounds[-1]['wall_ratio']:.2f}", flush=True)
    sys.path.insert(0, str(HERE))
    from machine import details

    from jaxpile.io import write_json

    write_json(args.out, {"command": "python benchmarks/distributed_throughput.py " + " ".join(argv or sys.argv[1:]),
                          "sweep": SWEEP, "rounds": rounds, "machine": details()})
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
