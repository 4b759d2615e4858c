"""What a neighbour-list rebuild costs on a poured heap, and what it costs a step.

A pour rebuilds its list every ~8 steps while disks fall (any disk that moved
more than half the skin), so the rebuild is a large part of a pour's step.
This pours the heap of `vs_lammps.py --small` (200 hooke disks onto 60 fixed
ones, velocity Verlet), then, on the heap as it stands:

* `rebuild`: one full-list build from the positions, its half pair list and
  the history carried onto it (`neighbors.rebuild` + `pairs.contacts_for`),
  in a compiled loop of `--repeats` (the positions nudged by 1e-12 every other
  turn, so nothing is hoisted out of the loop);
* `step`, `step, rebuild every step`, `step, never rebuilt`: the pour's own
  step as it runs, and with the rebuild decision forced each way.

Prints microseconds per rebuild and per step, and writes JSON.

    python benchmarks/rebuild_cost.py [--poured 200] [--repeats 500] [--out FILE]
"""

from __future__ import annotations

import argparse
import time

import jax
import jax.numpy as jnp
from jax import lax

import jaxpile
from jaxpile import io
from jaxpile.engine import neighbors as nb
from jaxpile.engine import pairs as pair_list
from jaxpile.protocols import pour
from machine import describe  # benchmarks/machine.py (scripts run from benchmarks/)
from vs_lammps import DT, pour_setup

# as the commands run: float64 and XLA's settings, multi-output fusion included
# (jaxpile.config), unless JAXPILE_MULTI_OUTPUT_FUSION=0
jaxpile.configure()


def per_turn(loop, carry, turns: int) -> float:
    """Microseconds per turn of a compiled loop (compiled and warmed up first)."""
    jax.block_until_ready(loop(carry))
    t0 = time.perf_counter()
    jax.block_until_ready(loop(carry))
    return 1e6 * (time.perf_counter() - t0) / turns


def rebuild_us(state, turns: int) -> float:
    """Microseconds per rebuild of `state`'s list at its capacities: the full
    list, its half pairs and the history carried onto them, in a compiled loop
    of `turns` (positions nudged by 1e-12 every other turn, so nothing is
    hoisted out of the loop)."""
    settings, position = state.neighbor_settings, state.particles.position

    def rebuild(i, c):
        neighbors, contacts = c
        new = nb.rebuild(neighbors, position + (i % 2) * 1e-12, settings)
        return new, pair_list.contacts_for(contacts, neighbors.idx, new.idx)

    return per_turn(jax.jit(lambda c: lax.fori_loop(0, turns, rebuild, c)), (state.neighbors, state.contacts), turns)


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--poured", type=int, default=200)
    parser.add_argument("--repeats", type=int, default=500)
    parser.add_argument("--out", default=None)
    args = parser.parse_args(argv)

    protocol = pour_setup(args.poured, 0.15, 0)
    _, law, params = pour.law_and_params("hooke")
    sim = pour.make_simulator("hooke", dt=DT, chunk_steps=2000, integrator="velocity_verlet")
    state = sim.init(params, protocol.particles, protocol.boundaries, box=protocol.box,
                     protocol_state=protocol.protocol_state)
    state = sim.run(params, state, protocol.info["pour_steps"], progress=False)
    turns = args.repeats

    out = {"machine": describe(), "disks": state.particles.count, "slots": state.neighbors.max_occupancy,
           "window": state.neighbors.cell_list_capacity, "pair_entries": int(state.contacts.pairs.shape[0])}
    out["rebuild_us"] = rebuild_us(state, turns)

    real = nb.needs_rebuild
    for name, decide in (("step_us", real), ("step_rebuild_every_step_us", lambda *a: jnp.array(True)),
                         ("step_never_rebuilt_us", lambda *a: jnp.array(False))):
        nb.needs_rebuild = decide  # read when the step is traced
        try:
            step = pour.make_simulator("hooke", dt=DT, integrator="velocity_verlet").step
            loop = jax.jit(lambda s, step=step: lax.fori_loop(0, 4 * turns, lambda i, s: step(params, s), s))
            out[name] = per_turn(loop, state, 4 * turns)
        finally:
            nb.needs_rebuild = real
    print(f"poured heap of {out['disks']} disks (K = {out['slots']}, W = {out['window']}, "
          f"{out['pair_entries']} pair entries), {out['machine']}")
    print(f"  rebuild (list, half pairs, history carry): {out['rebuild_us']:.1f} us")
    print(f"  step: {out['step_us']:.1f} us; rebuilding every step {out['step_rebuild_every_step_us']:.1f} us; "
          f"never rebuilt {out['step_never_rebuilt_us']:.1f} us")
    out["table"] = [{"case": f"neighbour rebuild, poured heap of {out['disks']} disks", "jaxpile": None,
                     "lammps": None, "ratio": None,
                     "note": f"{out['rebuild_us']:.0f} us per rebuild; a step {out['step_never_rebuilt_us']:.0f} us "
                             f"without one, {out['step_rebuild_every_step_us']:.0f} us with one"}]
    if args.out:
        io.write_json(args.out, out)
    return out


if __name__ == "__main__":
    main()
