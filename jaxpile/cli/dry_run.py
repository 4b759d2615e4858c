"""`--dry-run`'s report, shared by `pile`, `sweep` and `fit`: the set-up, the
memory estimate and the planned steps, printed; nothing is run or written."""

from __future__ import annotations

import numpy as np

from jaxpile import budget

PHASE_STEPS = ("pour_steps", "ramp_steps", "max_steps", "max_settle_steps", "relax_steps")
"""Step counts that are phases of a run (summed for the --dry-run bound)."""


def dry_run_report(what: str, particles, info: dict, precision: str, steps: dict) -> dict:
    """Prints what a run of `particles` would hold and step, refuses it when it
    does not fit in memory (`budget.check`), and returns the same facts."""
    movable = int(np.sum(np.asarray(particles.active) & ~np.asarray(particles.fixed)))
    total = int(particles.count)
    planned = {k: int(v) for k, v in {**{k: v for k, v in info.items() if k.endswith("steps")}, **steps}.items()
               if isinstance(v, (int, float)) and not isinstance(v, bool)}
    # the phases run one after another; the other step facts (intervals, hold times) are rules inside them
    bound = sum(v for k, v in planned.items() if k in PHASE_STEPS)
    noun = "spheres" if particles.dim == 3 else "disks"
    print(f"jaxpile: dry run of {what}: {total:,} {noun} ({movable:,} movable at the start), {precision}")
    print(f"jaxpile: {budget.describe(total, precision)}")
    if planned:
        print("jaxpile: steps: " + ", ".join(f"{k} {v:,}" for k, v in planned.items())
              + (f"; at most {bound:,} steps = {bound * total:.3g} particle-steps (a run that comes to rest "
                 "stops sooner)" if bound else ""))
    budget.check(total, precision, what=what)
    return {"dry_run": True, "disks": total, "movable": movable, "estimate_bytes": budget.estimate(total, precision),
            "steps": planned, "particle_steps_bound": bound * total}
