"""The step cost of each `granular` sub-model against `hooke` on the same pile.

The 1992 equilateral lattice (`--layers`, 465 disks at 30) loaded by a gravity
ramp, spins on, Coulomb friction sliding at its edges, run by each law in
turn: `hooke` (LAMMPS `gran/hooke/history`), then `granular` compositions,
each changing one sub-model from the Hertz-Mindlin one a DEM user calibrates
(`hertz/material ... damping tsuji tangential mindlin NULL`). Each law's
steps are timed in `--rounds` rounds taken in turn (law A, B, C, A, B, C,
...: the machine's drift falls on every law alike) and its fastest round is
kept; the ratio is its time per step over `hooke`'s in the same run.

    python benchmarks/granular_cost.py [--layers 30] [--steps 4000] [--rounds 3] [--laws hooke,jkr,...]
                                       [--out FILE]
"""

from __future__ import annotations

import argparse
import json
import os
import time

import jaxpile
from jaxpile.engine import Simulator, gravity_ramp
from jaxpile.laws import get_law_module, hooke
from jaxpile.protocols import lattice
from machine import describe  # benchmarks/machine.py (scripts run from benchmarks/)

jaxpile.configure()  # float64 and the commands' XLA settings

HERTZ_MINDLIN = "hertz/material 1e6 0.5 0.3 damping tsuji tangential mindlin NULL 1.0 0.5"
LAWS = {
    "hooke": None,  # hooke.make_params(mu=0.5): LAMMPS's defaults kt = 2/7 kn, gamma_t = gamma_n / 2
    "granular hooke": "hooke 2e5 50.0 damping mass_velocity tangential linear_history 57142.85714285714 0.5 0.5",
    "hertz-mindlin": HERTZ_MINDLIN,
    "+ rolling sds": HERTZ_MINDLIN + " rolling sds 1e3 5.0 0.1",
    "viscoelastic": HERTZ_MINDLIN.replace("0.5 0.3 damping tsuji", "5e3 0.3 damping viscoelastic"),
    "mindlin_rescale": HERTZ_MINDLIN.replace("mindlin NULL", "mindlin_rescale NULL"),
    "mindlin/force": HERTZ_MINDLIN.replace("mindlin NULL", "mindlin/force NULL"),
    "dmt": HERTZ_MINDLIN.replace("hertz/material 1e6 0.5 0.3", "dmt 1e6 0.5 0.3 0.05"),
    "jkr": HERTZ_MINDLIN.replace("hertz/material 1e6 0.5 0.3", "jkr 1e6 0.5 0.3 0.05"),
}


def simulator(name: str, line: str | None, layers: int, dt: float, ramp: int):
    """`(sim, params, state)` of the lattice at the start, for one law."""
    if line is None:
        law, params = hooke.law(rotation=True), hooke.make_params(mu=0.5)
    else:
        module = get_law_module(line)
        law, params = module.law(rotation=True), module.make_params()
    particles, boundaries = lattice.equilateral_pile(layers)
    sim = Simulator(law, dt, schedule=gravity_ramp(ramp), chunk_steps=2000)
    return sim, params, sim.init(params, particles, boundaries)


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--layers", type=int, default=30)
    parser.add_argument("--steps", type=int, default=4000, help="steps timed per round")
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--dt", type=float, default=2e-4)
    parser.add_argument("--laws", default=",".join(LAWS), help="the rows to run, by name (hooke always)")
    parser.add_argument("--out", default=os.path.join(os.path.dirname(__file__), "results", "cpu",
                                                      "granular_cost.json"))
    args = parser.parse_args(argv)
    runs, chosen = {}, {"hooke", *args.laws.split(",")}
    unknown = chosen - set(LAWS)
    if unknown:
        parser.error(f"unknown rows {sorted(unknown)}; known: {', '.join(LAWS)}")
    for name, line in ((n, line) for n, line in LAWS.items() if n in chosen):  # compile, and load past the ramp
        sim, params, state = simulator(name, line, args.layers, args.dt, ramp=2000)
        t0 = time.perf_counter()
        state = sim.run(params, state, 4000, progress=False)
        runs[name] = dict(sim=sim, params=params, state=state, warm_up=time.perf_counter() - t0, seconds=[])
    for _ in range(args.rounds):
        for name, run in runs.items():
            t0 = time.perf_counter()
            run["state"] = run["sim"].run(run["params"], run["state"], args.steps, progress=False)
            run["state"].particles.position.block_until_ready()
            run["seconds"].append(time.perf_counter() - t0)
    n = int(runs["hooke"]["state"].particles.count)
    base = min(runs["hooke"]["seconds"])
    rows = {}
    print(f"{describe()}: the {args.layers}-layer lattice ({n} disks), {args.steps} steps x {args.rounds} rounds")
    print(f"{'law':18s} {'particle-steps/s':>17s} {'time / hooke':>13s} {'strained':>9s}  line")
    for name, run in runs.items():
        best = min(run["seconds"])
        contacts = int((run["state"].contacts.history != 0).any(axis=-1).sum())
        rows[name] = {"line": LAWS[name], "particle_steps_per_second": n * args.steps / best,
                      "ratio_to_hooke": best / base, "seconds": run["seconds"], "strained_contacts": contacts}
        print(f"{name:18s} {n * args.steps / best:17.3g} {best / base:13.2f} {contacts:9d}  {LAWS[name] or ''}")
    out = {"machine": describe(), "layers": args.layers, "disks": n, "steps": args.steps, "rounds": args.rounds,
           "dt": args.dt, "laws": rows}
    os.makedirs(os.path.dirname(args.out), exist_ok=True)
    with open(args.out, "w") as f:
        json.dump(out, f, indent=1)
    print(f"wrote {args.out}")
    return out


if __name__ == "__main__":
    main()
