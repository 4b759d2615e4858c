"""How often a pour must rebuild its neighbour list under other exact criteria,
measured offline on the pour's own trajectory (a study for issue 15, nothing
in jaxpile uses it yet).

A pour rebuilds its list every ~5-8 steps while disks fall, and at 1000 disks
the rebuilds are a third of its time (`rebuild_cost.py --poured 1000`). The
criterion today is LAMMPS's: rebuild when any disk has moved more than skin/2
since the last build. It is exact for any per-disk skins s_i: list the pairs
closer than cutoff + (s_i + s_j)/2 and rebuild when some disk has moved more
than s_i/2 (two unlisted disks then still cannot have come within the cutoff).
The disks that force the rebuilds are the fast ones, falling alone onto the
heap. So give each disk, at each build, a skin that covers its own travel:
s_i = clip(2 |v_i| tau, s0, s_max), tau a horizon in steps.

This records the `vs_lammps.py --small` pour (200 hooke disks onto 60 fixed
ones, velocity Verlet, every step's positions), replays the rebuild decision
under each criterion, and reports the rebuilds, the pairs listed (against the
fixed skin's, sampled every tenth build) and the candidates a cell build would
examine with cells of cutoff + s_max instead of cutoff + s0 (a 3 x 3 block
must see every listed pair): what per-disk skins would save and cost.

    python benchmarks/rebuild_criteria.py [--poured 200] [--settle 20000] [--out FILE]
"""

from __future__ import annotations

import argparse
import time

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax

import jaxpile  # noqa: F401  (float64)
from jaxpile import io
from jaxpile.protocols import pour
from machine import describe  # benchmarks/machine.py (scripts run from benchmarks/)
from vs_lammps import DT, pour_setup

POLICIES = [(None, None), (10, 0.6), (20, 0.4), (20, 0.6), (40, 0.6), (40, 1.0)]
"""(tau in steps, s_max in sigma); (None, None) is today's fixed skin."""


def record(poured: int, settle: int, chunk: int = 1000):
    """Every step's positions `[T, n, 2]` (float32) of the pour, and its cutoff and skin."""
    protocol = pour_setup(poured, 0.15, 0)
    _, _, params = pour.law_and_params("hooke")
    sim = pour.make_simulator("hooke", dt=DT, integrator="velocity_verlet")
    state = sim.init(params, protocol.particles, protocol.boundaries, box=protocol.box,
                     protocol_state=protocol.protocol_state)

    @jax.jit
    def run(s):
        def body(s, _):
            s = sim.step(params, s)
            return s, s.particles.position.astype(jnp.float32)
        return lax.scan(body, s, None, length=chunk)

    steps = protocol.info["pour_steps"] + settle
    frames = []
    for _ in range(-(-steps // chunk)):
        state, positions = run(state)
        frames.append(np.asarray(positions))
    settings = state.neighbor_settings
    return np.concatenate(frames)[:steps].astype(np.float64), float(settings.cutoff), float(settings.skin)


def listed_pairs(x, skin, cutoff, movable):
    d = np.sqrt(((x[:, None, :] - x[None, :, :]) ** 2).sum(-1))
    m = (d < cutoff + 0.5 * (skin[:, None] + skin[None, :])) & movable[:, None] & movable[None, :]
    np.fill_diagonal(m, False)
    return int(m.sum()) // 2


def block_candidates(x, cell, movable):
    """Disks a cell build examines: for each disk, the disks in its 3 x 3 block of cells."""
    c = np.floor(x[movable] / cell).astype(np.int64)
    near = (np.abs(c[:, None, :] - c[None, :, :]) <= 1).all(-1)
    return int(near.sum())


def replay(traj, cutoff, s0, tau, s_max, dt):
    """Rebuilds under a criterion, and its listed pairs and block candidates against the fixed skin's."""
    n = traj.shape[1]
    reference, skin = traj[0], np.full(n, s0)
    rebuilds, pairs, candidates = 0, [], []
    for t in range(1, len(traj)):
        x = traj[t]
        if np.any(np.sqrt(((x - reference) ** 2).sum(-1)) > 0.5 * skin):
            rebuilds += 1
            reference = x
            if tau is not None:
                speed = np.sqrt(((traj[t] - traj[t - 1]) ** 2).sum(-1)) / dt
                skin = np.clip(2.0 * speed * tau * dt, s0, s_max)
            if tau is not None and rebuilds % 10 == 0:  # the fixed skin is its own reference
                movable = np.abs(x).max(-1) < 500.0  # parked disks wait far away
                fixed = np.full(n, s0)
                pairs.append(listed_pairs(x, skin, cutoff, movable) / max(listed_pairs(x, fixed, cutoff, movable), 1))
                candidates.append(block_candidates(x, cutoff + s_max, movable) / block_candidates(x, cutoff + s0, movable))
    return {"tau_steps": tau, "s_max": s_max, "rebuilds": rebuilds,
            "pairs_over_fixed_skin": float(np.mean(pairs)) if pairs else 1.0,
            "block_candidates_over_fixed_cells": float(np.mean(candidates)) if candidates else 1.0}


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--poured", type=int, default=200)
    parser.add_argument("--settle", type=int, default=20_000)
    parser.add_argument("--out", default=None)
    args = parser.parse_args(argv)

    t0 = time.perf_counter()
    traj, cutoff, s0 = record(args.poured, args.settle)
    print(f"pour of {args.poured} disks, {len(traj)} steps recorded in {time.perf_counter() - t0:.0f} s; "
          f"cutoff {cutoff:g}, skin {s0:g}")
    rows = [replay(traj, cutoff, s0, tau, s_max, DT) for tau, s_max in POLICIES]
    base = rows[0]["rebuilds"]
    for r in rows:
        what = "fixed skin (today)" if r["tau_steps"] is None else f"s_i = clip(2 |v_i| {r['tau_steps']} dt, " \
                                                                  f"{s0:g}, {r['s_max']:g})"
        print(f"  {what:40s} rebuilds {r['rebuilds']:5d} ({base / r['rebuilds']:.2f}x fewer), pairs x"
              f"{r['pairs_over_fixed_skin']:.3f}, cell-build candidates x{r['block_candidates_over_fixed_cells']:.2f}")
    out = {"machine": describe(), "poured": args.poured, "steps": len(traj), "cutoff": cutoff, "skin": s0,
           "criteria": rows}
    if args.out:
        io.write_json(args.out, out)
    return out


if __name__ == "__main__":
    main()
