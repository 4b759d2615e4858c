"""Soak: a long pour with periodic checkpoints, killed and resumed several times,
must end exactly as the same pour run without interruption.

Runs `jaxpile pile --protocol pour` twice for `--steps` steps in all (the pour,
then settling with a rest tolerance no heap reaches, so the run uses its whole
budget):

1. uninterrupted, with `--checkpoint-every`;
2. in a subprocess killed with SIGKILL at random moments (after each new
   checkpoint appears, at a random delay), then `jaxpile pile --resume DIR`,
   again and again until a run finishes.

Checks that no disk is lost (the same count of active disks) and that the two
final states are identical, array by array, bit for bit. Marked `soak` (minutes:
not in the default suite): `make soak` (or `pytest -m soak`) runs it at the
sizes below. Run by hand, it takes other sizes, prints the figures and writes
JSON.

    python tests/test_soak.py [--steps 1000000] [--n 100] [--every 50000] [--kills 4] [--out FILE]
"""

from __future__ import annotations

import argparse
import json
import os
import pathlib
import random
import signal
import subprocess
import sys
import tempfile
import time

import numpy as np
import pytest

from jaxpile import io
from jaxpile.engine import checkpoint

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1] / "benchmarks"))
from machine import describe  # noqa: E402  (benchmarks/machine.py)

CLI = "import sys; from jaxpile.cli import main; sys.exit(main(sys.argv[1:]))"


def pour_command(n: int, steps: int, every: int, out: str) -> list[str]:
    from jaxpile.protocols import pour

    pour_steps = pour.SPEC.set_up("hooke", n, dt=pour.PAPER_SETTING["dt"]).info["pour_steps"]
    if pour_steps >= steps:
        raise SystemExit(f"--steps {steps} is shorter than the pour itself ({pour_steps} steps)")
    return ["pile", "--protocol", "pour", "--law", "hooke", "--n", str(n), "--max-steps", str(steps - pour_steps),
            "--speed-tol", "1e-30", "--checkpoint-every", str(every), "--no-progress", "--out", out]


def main(argv=None) -> dict:
    import jaxpile

    jaxpile.configure()  # float64, as the pour's set-up below needs (the suite's conftest does it there)
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=1_000_000)
    parser.add_argument("--n", type=int, default=100, help="disks poured")
    parser.add_argument("--every", type=int, default=50_000, help="checkpoint interval (steps)")
    parser.add_argument("--kills", type=int, default=4, help="interruptions before letting the run finish")
    parser.add_argument("--seed", type=int, default=0, help="when to kill")
    parser.add_argument("--out", default=None)
    args = parser.parse_args(argv)
    rng = random.Random(args.seed)
    root = tempfile.mkdtemp(prefix="soak-")
    whole, cut = os.path.join(root, "whole"), os.path.join(root, "cut")

    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-c", CLI, *pour_command(args.n, args.steps, args.every, whole)], check=True,
                   stdout=subprocess.DEVNULL)
    t_whole = time.perf_counter() - t0

    t0 = time.perf_counter()
    command = pour_command(args.n, args.steps, args.every, cut)
    kills, killed_at = 0, []
    while True:
        proc = subprocess.Popen([sys.executable, "-c", CLI, *command], stdout=subprocess.DEVNULL,
                                stderr=subprocess.DEVNULL)
        path = os.path.join(cut, "checkpoint.npz")
        start = checkpoint.read_metadata(path)["step"] if os.path.exists(path) else -1
        if kills < args.kills:
            # wait for this process's first new checkpoint, then kill it a random moment later
            while proc.poll() is None:
                time.sleep(0.05)
                if os.path.exists(path) and checkpoint.read_metadata(path)["step"] > start:
                    time.sleep(rng.uniform(0.0, 2.0))
                    proc.send_signal(signal.SIGKILL)
                    break
        proc.wait()
        if proc.returncode == 0:
            break
        if proc.returncode != -signal.SIGKILL:
            raise SystemExit(f"the interrupted run failed with exit status {proc.returncode}")
        kills += 1
        killed_at.append(checkpoint.read_metadata(path)["step"])
        command = ["pile", "--resume", cut, "--no-progress"]
    t_cut = time.perf_counter() - t0

    a, b = io.load_arrays(os.path.join(whole, "state.npz")), io.load_arrays(os.path.join(cut, "state.npz"))
    differing = [k for k in a if k != "metadata" and not np.array_equal(a[k], b[k])]
    summary = json.loads(open(os.path.join(cut, "summary.json")).read())
    active = int(np.sum(a["particles.active"])), int(np.sum(b["particles.active"]))
    out = {"machine": describe(), "steps": args.steps, "n": args.n, "every": args.every, "kills": kills,
           "checkpoint_steps_at_kills": killed_at, "uninterrupted_seconds": t_whole,
           "interrupted_seconds": t_cut, "final_step": summary.get("steps"), "active_disks": active,
           "identical": not differing, "differing_arrays": differing}
    print(f"soak: pour of {args.n} disks, {args.steps} steps, checkpoint every {args.every} ({describe()})")
    print(f"  uninterrupted {t_whole:.0f} s; killed {kills} times (at checkpoints {killed_at}) and resumed: "
          f"{t_cut:.0f} s")
    print(f"  active disks {active[0]} / {active[1]}; final states identical: {not differing}"
          + ("" if not differing else f" (differ: {differing})"))
    if args.out:
        io.write_json(args.out, out)
    return out


@pytest.mark.soak
def test_killed_and_resumed_pour_ends_as_the_uninterrupted_one():
    out = main([])
    assert out["active_disks"][0] == out["active_disks"][1], f"disks lost: {out['active_disks']}"
    assert out["identical"], f"final states differ: {out['differing_arrays']}"


if __name__ == "__main__":
    main()
