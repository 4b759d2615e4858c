"""How a poured heap grows (Baxter et al. 1997, sec. III): "by a series of
avalanches in a boundary layer ~3-4 particles thick on the surface, with the
inner particles largely static", where the Hooke law's heap grows "by small
numbers of grains rolling down the sides"; "large-scale avalanches are not
observed".

Pours heaps and samples them every `--sample-steps` steps while they are fed.
At each sample the heap is every poured disk in play but the last three
released (still falling); a heap disk moves when it went more than
`--distance` sigma since the last sample (the heap shakes at ~0.1 (sigma
g)^(1/2) under the impacts, so a speed would count its whole interior; a
displacement counts flow). Each moving disk's depth is the height of its
column's surface (columns one substrate spacing wide, the top of their highest
heap disk) above its own top. Per heap, over the samples with motion: how many
disks move at once, the flowing layer's thickness (the deepest moving disk's
depth + 1, in diameters), and the share of samples with 5 or more moving
(collective motion); per setting, mean +- s.e. over heaps.

    python benchmarks/studies/papers/baxter_avalanches.py [--n 300] [--seeds 8] [--settings baxter,hooke-k500]

About 3 minutes a 300-disk heap on one core. Writes
benchmarks/results/baxter_readings/n<N>/avalanches.json (each heap's row as it
finishes, so a rerun skips the heaps done) with the command that made it.
"""

from __future__ import annotations

import argparse
import json
import math
import pathlib
import sys
import time

import numpy as np

import jaxpile

jaxpile.configure()  # float64 and the commands' XLA settings
from jaxpile.measure import heap
from jaxpile.protocols import pour

RESULTS = pathlib.Path(__file__).resolve().parents[2] / "results" / "baxter_readings"
SETTINGS = {"baxter": "baxter", "hooke-k500": "hooke"}
"""The laws compared, by setting name: the paper's, and its equivalent Hooke law (k = 500 mg/sigma)."""
FALLING = 3
"""The last disks released that are still in the air at a sample (a disk falls 6 sigma onto the heap in
about 2.2 release intervals)."""
COLLECTIVE = 5
"""Disks moving at once that make a sample collective motion rather than single grains rolling."""


def sample(state, before, first: int, spacing: float, distance: float) -> tuple[dict | None, np.ndarray]:
    """One sample of a heap being fed: how many of its disks moved more than
    `distance` since the last sample (`before`, their positions then) and how
    deep they are now; None while the heap is empty. Returns it with the
    positions to compare the next sample with."""
    p = state.particles
    poured = int(state.protocol_state.poured)
    now = np.asarray(p.position)
    index = np.arange(p.count)
    heap_disks = np.asarray(p.movable) & (index < first + poured - FALLING)
    if not heap_disks.any():
        return None, now
    pos, rad = now[heap_disks], np.asarray(p.radius)[heap_disks]
    top = pos[:, 1] + rad
    column = np.floor((pos[:, 0] - float(now[0, 0])) / spacing + 0.5).astype(int)
    surface = {}
    for c, t in zip(column, top):
        surface[c] = max(surface.get(c, -math.inf), t)
    moved = np.linalg.norm(pos - before[heap_disks], axis=1) > distance
    depth = np.array([surface[c] - t for c, t in zip(column[moved], top[moved])])
    return {"moving": int(moved.sum()), "thickness": float(depth.max() + 1.0) if depth.size else 0.0}, now


def one_heap(setting: str, seed: int, n: int, sample_steps: int, distance: float) -> dict:
    """Pours one heap, sampling it every `sample_steps` steps while it is fed."""
    law = SETTINGS[setting]
    t0 = time.perf_counter()
    setup = pour.SPEC.set_up(law, n, seed=seed, insert_height=heap.steepest_heap_height(n) + 6.0)
    _, _, params = pour.law_and_params(law)
    sim = pour.make_simulator(law)
    state = sim.init(params, setup.particles, setup.boundaries, box=setup.box, protocol_state=setup.protocol_state)
    first, spacing = setup.info["n_substrate"], setup.info["spacing"]
    samples, before = [], np.asarray(state.particles.position)
    for _ in range(setup.info["pour_steps"] // sample_steps):
        state = sim.run(params, state, sample_steps, progress=False)
        s, before = sample(state, before, first, spacing, distance)
        if s is not None:
            samples.append(s)
    active = [s for s in samples if s["moving"]]
    return {"setting": setting, "seed": seed, "n": n, "samples": len(samples), "with_motion": len(active),
            "moving": float(np.mean([s["moving"] for s in active])) if active else 0.0,
            "thickness": float(np.median([s["thickness"] for s in active])) if active else 0.0,
            "thickness_p90": float(np.percentile([s["thickness"] for s in active], 90)) if active else 0.0,
            "collective": float(np.mean([s["moving"] >= COLLECTIVE for s in active])) if active else 0.0,
            "seconds": time.perf_counter() - t0}


def mean_stderr(values) -> dict:
    v = np.asarray(values, float)
    return {"mean": float(v.mean()), "stderr": float(v.std(ddof=1) / math.sqrt(len(v))) if len(v) > 1 else None,
            "count": int(len(v))}


def summarise(rows: list[dict]) -> dict:
    out = {}
    for setting in dict.fromkeys(r["setting"] for r in rows):
        mine = [r for r in rows if r["setting"] == setting]
        out[setting] = {"heaps": len(mine), **{key: mean_stderr([r[key] for r in mine])
                                               for key in ("moving", "thickness", "thickness_p90", "collective")}}
    return out


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, default=300)
    parser.add_argument("--seeds", type=int, default=8)
    parser.add_argument("--settings", default=",".join(SETTINGS))
    parser.add_argument("--sample-steps", type=int, default=4000, help="steps between samples (2 chunks)")
    parser.add_argument("--distance", type=float, default=0.5,
                        help="how far (sigma) a heap disk must move between samples to count as moving")
    parser.add_argument("--out", default=None, help="default: benchmarks/results/baxter_readings/n<N>/avalanches.json")
    args = parser.parse_args(argv)
    settings = [s.strip() for s in args.settings.split(",") if s.strip()]
    unknown = set(settings) - set(SETTINGS)
    if unknown:
        parser.error(f"unknown setting(s) {sorted(unknown)}; known: {list(SETTINGS)}")
    out = pathlib.Path(args.out or RESULTS / f"n{args.n}" / "avalanches.json")
    out.parent.mkdir(parents=True, exist_ok=True)
    options = {"n": args.n, "sample_steps": args.sample_steps, "distance": args.distance}
    saved = json.loads(out.read_text()) if out.exists() else {}
    rows = saved.get("heaps", []) if saved.get("options") == options else []
    done = {(r["setting"], r["seed"]) for r in rows}
    command = "python benchmarks/studies/papers/baxter_avalanches.py " + " ".join(argv if argv is not None else sys.argv[1:])
    for setting in settings:
        for seed in range(args.seeds):
            if (setting, seed) in done:
                continue
            row = one_heap(setting, seed, args.n, args.sample_steps, args.distance)
            rows.append(row)
            print(f"  {setting:12s} seed {seed}: {row['moving']:.1f} moving at once, layer {row['thickness']:.1f} "
                  f"diameters (90%: {row['thickness_p90']:.1f}), collective {100 * row['collective']:.0f}% of {row['with_motion']} samples, "
                  f"{row['seconds']:.0f} s", flush=True)
            out.write_text(json.dumps({"command": command, "options": options, "summary": summarise(rows),
                                       "heaps": rows}, indent=1))
    for setting, s in summarise(rows).items():
        print(f"{setting:12s} {s['heaps']} heaps: moving {s['moving']['mean']:.1f}, layer {s['thickness']['mean']:.2f} "
              f"± {s['thickness']['stderr'] or float('nan'):.2f} diameters, collective {s['collective']['mean']:.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
