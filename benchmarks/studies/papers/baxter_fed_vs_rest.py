"""Is the 1997 heap steeper while it is still being fed? Baxter et al.'s Fig. 1
shows the 1334-disk heap "at near rest after 2.15e3 time units", which is the
moment the last disk is released at their rate. This pours heaps and measures
each one twice: at the last release, and after it comes to rest.

    python benchmarks/studies/papers/baxter_fed_vs_rest.py [--n 300] [--seeds 10,11] [--out FILE]

Prints one JSON row per seed. It holds the mean least-squares flank angle, the
mid-flank angles and atan(2h/B), both fed and at rest.
"""

from __future__ import annotations

import argparse
import json

import jaxpile

jaxpile.configure()  # float64 and the commands' XLA settings
from jaxpile.protocols import pour
from jaxpile.measure import poured_heap
from jaxpile.measure import heap


def angles(summary: dict) -> dict:
    a = summary["angle_of_repose"]
    return {"least_squares": (a["left"]["least_squares"] + a["right"]["least_squares"]) / 2,
            "mid_flank": summary["angle_mid_flank"], "height_base": summary["angle_height_base"],
            "in_play": summary["counts"]["in_play"]}


def main(argv=None) -> list[dict]:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, default=300)
    parser.add_argument("--seeds", default="10,11")
    parser.add_argument("--out", default=None)
    args = parser.parse_args(argv)
    rows = []
    for seed in (int(s) for s in args.seeds.split(",")):
        setup = pour.SPEC.set_up("baxter", args.n, seed=seed, insert_height=heap.steepest_heap_height(args.n) + 6.0)
        _, _, params = pour.law_and_params("baxter")
        sim = pour.make_simulator("baxter")
        state = sim.init(params, setup.particles, setup.boundaries, box=setup.box,
                         protocol_state=setup.protocol_state)
        state = sim.run(params, state, setup.info["pour_steps"], progress=False)
        fed = angles(poured_heap.summary(poured_heap.measure(sim, params, state)))
        state, _ = sim.run_until_rest(params, state, speed_tolerance=pour.PAPER_SETTING["speed_tolerance"],
                                      max_steps=pour.PAPER_SETTING["max_settle_steps"], progress=False)
        rest = angles(poured_heap.summary(poured_heap.measure(sim, params, state)))
        rows.append({"n": args.n, "seed": seed, "fed": fed, "rest": rest})
        print(json.dumps(rows[-1]), flush=True)
    if args.out:
        with open(args.out, "w") as f:
            json.dump(rows, f, indent=1)
    return rows


if __name__ == "__main__":
    main()
