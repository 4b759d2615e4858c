"""A batch's members side by side (vmapped) or one after another (`lax.map`), in one compiled call.

A pour rebuilds a heap's list every ~8 steps while disks fall. Side by side
(`Ensemble(sim)`: one vmapped step, the rebuild decided once for the batch by
a `lax.pmax` of the members' needs, then one real branch), every member is
rebuilt whenever *any* needs it, and with 16 heaps falling out of phase that
is almost every step. One after another (`Ensemble(sim, sequential=True)`:
`lax.map` of each member's own loop of the single pile's step), each member
rebuilds only on its own steps.

This pours `--members` heaps of the fits' set-up (the 1997 pour, baxter law
with rolling sds, spins on, the source narrowed to +-0.5 sigma; release from
the paper's 100 sigma), or builds `--members` piles of another protocol with its
own law and options (`--protocol drop`: Liffman et al. 1992, disks dropped one
at a time; `flux`: Lee & Herrmann 1993, disks fed one at a time; `hopper`: a
silo filled, then discharged), runs them `--warm` steps, then times the next `--steps`
steps with each decision, the two arms alternated `--repeats` times in one
run, and checks that both end in the same state bit for bit. Prints
particle-steps per second (the disks in play, the substrate row included) and
the ratio, and how often the first heap alone rebuilds its list over the
`--probe` steps after the warm ones; writes JSON.

    python benchmarks/ensemble_sequential.py [--protocol pour|drop|flux|hopper] [--members 16] [--n 300] [--warm 60000]
        [--steps 20000] [--repeats 2] [--probe 2000] [--out FILE]
"""

from __future__ import annotations

import argparse
import time

import jax
import numpy as np

import jaxpile
from jaxpile import io
from jaxpile.engine.ensemble import member
from jaxpile.engine.ensemble import Ensemble
from jaxpile.protocols import PROTOCOLS, pour
from machine import describe  # benchmarks/machine.py (scripts run from benchmarks/)

# as the commands run: float64 and XLA's settings, multi-output fusion included
# (jaxpile.config), unless JAXPILE_MULTI_OUTPUT_FUSION=0
jaxpile.configure()

ROLLING = {"k_roll": 1000.0, "gamma_roll": 30.0, "mu_roll": 0.14}
"""The rolling spring of the committed heaps and a mu_roll near the fitted one (docs/rolling_resistance.md)."""


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--protocol", default="pour", choices=["pour", "drop", "flux", "hopper"])
    parser.add_argument("--members", type=int, default=16)
    parser.add_argument("--n", type=int, default=300, help="disks poured per heap")
    parser.add_argument("--warm", type=int, default=60_000, help="steps run before the timed ones")
    parser.add_argument("--steps", type=int, default=20_000, help="steps timed per arm and repeat")
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--probe", type=int, default=2000, help="steps of the first heap counted for its rebuilds")
    parser.add_argument("--out", default=None, help="JSON file for the figures")
    args = parser.parse_args(argv)

    if args.protocol == "pour":
        law_options = {"rolling": "sds"}
        _, _, params = pour.law_and_params("baxter", ROLLING, rotation=True, law_options=law_options)
        sim = pour.make_simulator("baxter", rotation=True, law_options=law_options)
        setups = [pour.SPEC.set_up("baxter", args.n, spread=0.5, seed=s) for s in range(args.members)]
        what = f"{args.members} pours x {args.n} disks (baxter, rolling sds, narrow source)"
    else:
        spec = PROTOCOLS[args.protocol]
        law = spec.default_law
        options = spec.make_options(n=args.n)
        _, _, params = spec.law_and_params(law, None, None, None, {})
        sim = spec.simulator(options, law=law, dt=spec.default_dt(law), rotation=None, integrator=None,
                             chunk_steps=None, law_options={})
        setups = [spec.set_up(law, args.n, seed=s) for s in range(args.members)]
        what = f"{args.members} {args.protocol} piles x {args.n} disks ({law})"
    params = [params] * args.members
    arms = {"side_by_side": Ensemble(sim), "one_after_another": Ensemble(sim, sequential=True)}
    start = arms["one_after_another"].run(params, arms["one_after_another"].init(params, setups), args.warm,
                                          progress=False)
    in_play = int(np.asarray(start.particles.active).sum(axis=1).mean())
    seconds = {name: [] for name in arms}
    ends = {}
    for _ in range(args.repeats):
        for name, ens in arms.items():
            ens.run(params, start, 1000, progress=False)  # compiled and warm before it is timed
            t0 = time.perf_counter()
            end = ens.run(params, start, args.steps, progress=False)
            jax.block_until_ready(end.particles.position)
            seconds[name].append(time.perf_counter() - t0)
            ends[name] = end
    first = member(start, 0)  # one heap alone, a step at a time: a rebuild moves its list's reference positions
    step, rebuilds = jax.jit(sim.step), 0
    for _ in range(args.probe):
        moved = step(params[0], first)
        rebuilds += not np.array_equal(np.asarray(moved.neighbors.reference_position),
                                       np.asarray(first.neighbors.reference_position))
        first = moved
    same = all(np.array_equal(np.asarray(a), np.asarray(b))
               for a, b in zip(jax.tree.leaves(ends["side_by_side"]), jax.tree.leaves(ends["one_after_another"])))
    apart = float(np.max(np.abs(np.asarray(ends["side_by_side"].particles.position)
                                - np.asarray(ends["one_after_another"].particles.position))))
    work = args.members * in_play * args.steps
    rate = {name: work / min(s) for name, s in seconds.items()}
    out = {"machine": describe(), "protocol": args.protocol, "members": args.members, "n": args.n, "in_play_mean": in_play,
           "warm_steps": args.warm, "steps": args.steps, "repeats": args.repeats, "seconds": seconds,
           "particle_steps_per_s": rate, "sequential_used": arms["one_after_another"].sequential,
           "one_after_another_over_side_by_side": rate["one_after_another"] / rate["side_by_side"],
           "bit_identical": same, "largest_position_difference": apart, "probe_steps": args.probe,
           "one_heap_rebuilds": rebuilds}
    case = f"{what}, steps {args.warm}-{args.warm + args.steps}: members one after another vs side by side"
    ratio = out["one_after_another_over_side_by_side"]
    out["table"] = [{"case": case, "jaxpile": rate["one_after_another"], "lammps": None, "ratio": None,
                     "note": f"{ratio:.2f}x side by side ({rate['side_by_side']:.3g}); bit-identical: {same}"}]
    print(f"{case} ({out['machine']}), {in_play} disks in play a heap:")
    for name in arms:
        print(f"  {name:17s} {rate[name]:.3g} particle-steps/s (best of {', '.join(f'{s:.1f}' for s in seconds[name])} s)")
    print(f"  one after another over side by side: {ratio:.2f}x; the same states bit for bit: {same}"
          + ("" if same else f" (positions up to {apart:.2g} apart)"))
    print(f"  one heap alone rebuilds {rebuilds} times in {args.probe} steps (every {args.probe / max(rebuilds, 1):.1f})")
    if args.out:
        io.write_json(args.out, out)
    return out


if __name__ == "__main__":
    main()
