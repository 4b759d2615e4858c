"""Neighbour lists sized for the packed pile from the start (`Simulator(packed_lists=True)`,
`neighbors.packed_capacity`) against the old sizing that grows by re-allocation
(`packed_lists=False`), on the Lee & Herrmann 1993 box: a polydisperse pile
(radii 0.07-0.13 cm) filled, released and settled, the protocol's whole run.

With polydisperse disks the packed sizing takes the smallest radius, so it
starts with more slots than the old sizing (16 against 9 in a 2 cm box); the
question it answers is whether those slots cost step time. Each set-up runs
with both sizings, alternated (`--rounds` rounds, the seeds 0, 1, ...), in one
process: run time (chunks, compile excluded), compile time, re-allocations and
the list shapes at the start and the end.

With `--rebuild-slots 16,22,29` it also times one rebuild (the full list, its
half pairs, the history carried; as `rebuild_cost.py`) of the last packed
run's final pile at each of those slot counts (same window and pair room),
alternated over `--rounds` rounds: what a re-allocation's slot count costs
each time the list is rebuilt (more than 16 slots: a row sort instead of the
slot-by-slot selection, `neighbors.SELECT_SLOTS`).

    python benchmarks/packed_lists_ab.py [--widths 2,4] [--rounds 2] [--rebuild-slots 16,22,29] [--out FILE]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

import jaxpile  # noqa: F401  (float64)
from jaxpile import io
from jaxpile.engine import batch, simulate
from jaxpile.protocols import box, definition
from machine import describe  # benchmarks/machine.py (scripts run from benchmarks/)
from rebuild_cost import rebuild_us


def one_run(width: float, seed: int, packed: bool, keep: dict | None = None) -> dict:
    starts = []
    init = simulate.Simulator.init

    def recording_init(self, *args, **kwargs):  # the lists the run starts with
        state = init(self, *args, **kwargs)
        starts.append((state.neighbors.idx.shape[1], state.contacts.pairs.shape[0]))
        return state

    simulate.Simulator.init = recording_init
    try:
        t0 = time.perf_counter()
        state, m = definition.run(box.DEFINITION, "lee-herrmann", simulator_options={"packed_lists": packed},
                                  width=width, height=width, seed=seed)
        total = time.perf_counter() - t0
    finally:
        simulate.Simulator.init = init
    if keep is not None:
        keep["state"] = state
    radius = np.asarray(state.particles.radius)
    return {"width": width, "seed": seed, "packed_lists": packed, "disks": int(state.particles.count),
            "radius_min": float(radius.min()), "radius_max": float(radius.max()),
            "slots_start": starts[0][0], "pairs_start": starts[0][1],
            "slots_end": int(state.neighbors.idx.shape[1]), "pairs_end": int(state.contacts.pairs.shape[0]),
            "reallocations": int(m["neighbor_reallocations"]), "steps": int(m["steps"]),
            "run_seconds": m["wall_seconds"], "compile_seconds": m["compile_seconds"], "total_seconds": total,
            "us_per_step": m["wall_seconds"] / max(m["steps"], 1) * 1e6,
            "repose_cumulative_parabola": m.get("repose_cumulative_parabola")}


def rebuild_us_at(state, slots: int, turns: int) -> float:
    """`rebuild_cost.rebuild_us` of `state`'s pile with `slots` slots (its window and pair room)."""
    at = batch.at_capacity(state, slots, state.neighbors.cell_list_capacity, int(state.contacts.pairs.shape[0]))
    return rebuild_us(at, turns)


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--widths", default="2,4", help="box widths = heights (cm), comma-separated")
    parser.add_argument("--rounds", type=int, default=2, help="seeds; each runs with both sizings, alternated")
    parser.add_argument("--rebuild-slots", default=None,
                        help="comma-separated slot counts: time a rebuild of the last packed pile at each")
    parser.add_argument("--out", default=None)
    args = parser.parse_args(argv)
    rows, last_packed = [], {}
    print(f"{'W':>4} {'seed':>4} {'packed':>6} {'disks':>5} {'slots':>9} {'realloc':>7} {'steps':>6} "
          f"{'run s':>6} {'us/step':>7} {'compile s':>9}")
    for width in (float(w) for w in args.widths.split(",")):
        for seed in range(args.rounds):
            for packed in (True, False):
                r = one_run(width, seed, packed, keep=last_packed if packed else None)
                rows.append(r)
                print(f"{width:4g} {seed:4d} {packed!s:>6} {r['disks']:5d} {r['slots_start']:4d}->{r['slots_end']:<4d} "
                      f"{r['reallocations']:7d} {r['steps']:6d} {r['run_seconds']:6.2f} {r['us_per_step']:7.1f} "
                      f"{r['compile_seconds']:9.2f}", flush=True)
    # per set-up (width, seed): old / packed, the two runs of the same pile side by side
    pairs = [(a, b) for a in rows for b in rows
             if a["packed_lists"] and not b["packed_lists"] and (a["width"], a["seed"]) == (b["width"], b["seed"])]
    summary = {f"W{a['width']:g}_seed{a['seed']}": {
        "run_time_old_over_packed": b["run_seconds"] / a["run_seconds"],
        "us_per_step_old_over_packed": b["us_per_step"] / a["us_per_step"],
        "compile_old_over_packed": b["compile_seconds"] / a["compile_seconds"]} for a, b in pairs}
    for k, v in summary.items():
        print(f"{k}: old / packed: step time {v['us_per_step_old_over_packed']:.2f}x, "
              f"compile {v['compile_old_over_packed']:.2f}x")
    rebuilds = []
    if args.rebuild_slots:
        state = last_packed["state"]
        for r in range(args.rounds):
            for slots in (int(k) for k in args.rebuild_slots.split(",")):
                rebuilds.append({"round": r, "slots": slots, "disks": int(state.particles.count),
                                 "rebuild_us": rebuild_us_at(state, slots, 2000)})
                print(f"rebuild of the final {state.particles.count}-disk pile, {slots} slots: "
                      f"{rebuilds[-1]['rebuild_us']:.1f} us", flush=True)
    out = {"machine": describe(), "rows": rows, "old_over_packed": summary, "rebuild_by_slots": rebuilds,
           "command": "python benchmarks/packed_lists_ab.py " + " ".join(argv or [])}
    if args.out:
        io.write_json(args.out, out)
    return out


if __name__ == "__main__":
    import sys

    main(sys.argv[1:])
