"""Which reading of the 1997 law gives the paper's heap? Poured heaps in each
reading of Baxter et al.'s printed equations, several seeds each, with the
angle of repose and the M depth per heap and their mean +- standard error.

The readings are options of `jaxpile.laws.baxter.law` (see its docstring):
`lever_arm` "contact-point" or "centre-distance" (eqs. 6 and 13 as printed),
`slip` "hold" or "accumulate" (delta_F at gross sliding). The paper: angle of
repose 35 +- 5 deg (1334 disks; 31 deg for n = 36 in its n = 144 comparison),
base force M-shaped with flank maxima 20-30% above the centre.

Each (reading, seed) heap is one job whose result is written to
`<out>/n<N>/<reading>_seed<k>.json` as soon as it finishes, its state saved
beside it (`.npz`: every `--checkpoint-every` steps while it runs, the final
state at the end). A rerun skips the jobs already written and resumes a heap in
progress from its last saved state, so a long study continues where it stopped. `--workers 2` runs
two heaps at once (one pile keeps about one core busy).

    python benchmarks/baxter_readings.py [--n 300] [--seeds 4] [--readings contact-point/hold,centre-distance/hold]
        [--workers 2] [--out benchmarks/results/baxter_readings]

The angle is each flank's by the three methods of Lee & Herrmann 1993 (sec. 3;
`analysis.repose_angles`) and atan(2 h / B) from the heap's height and base.
"""

from __future__ import annotations

import argparse
import concurrent.futures
import json
import math
import os
import pathlib
import time

READINGS = ("contact-point/hold", "centre-distance/hold", "contact-point/accumulate", "centre-distance/accumulate")
ANGLE_METHODS = ("mid_flank", "endpoints", "least_squares", "cumulative_parabola")


def one_heap(reading: str, seed: int, n: int, out: str, insert_height: float | None,
             checkpoint_every: int = 200_000) -> dict:
    """Pours one heap in `reading` and writes its measurements to `out`."""
    import jaxpile  # noqa: F401  (float64)
    from jaxpile.protocols import pour

    lever_arm, slip = reading.split("/")
    if insert_height is None:
        insert_height = pour.steepest_heap_height(n) + 6.0
    state_file = out.replace(".json", ".npz")  # checkpoints during the run, the final state after it
    resume = state_file if os.path.exists(state_file) else None
    t0 = time.perf_counter()
    _, result = pour.run("baxter", n, seed=seed, insert_height=insert_height,
                         law_options={"lever_arm": lever_arm, "slip": slip}, progress=False,
                         checkpoint=(state_file, checkpoint_every), resume=resume)
    row = {"reading": reading, "seed": seed, "n": n, "insert_height": insert_height,
           "seconds": time.perf_counter() - t0, **result["summary"]}
    pathlib.Path(out).write_text(json.dumps(row, indent=1))
    return row


def angle(row: dict, method: str) -> float | None:
    """Both flanks' mean angle by `method`, or None if a flank was not measured."""
    if method == "mid_flank":
        values = [v for v in (row.get("angle_mid_flank") or {}).values() if v is not None]
        return sum(values) / len(values) if len(values) == 2 else None
    flanks = row.get("angle_of_repose") or {}
    values = [flanks[f][method] for f in ("left", "right") if flanks.get(f)]
    return sum(values) / len(values) if len(values) == 2 else None


def mean_stderr(values) -> dict:
    values = [v for v in values if v is not None and math.isfinite(v)]
    k = len(values)
    if k == 0:
        return {"mean": None, "stderr": None, "count": 0}
    mean = sum(values) / k
    spread = math.sqrt(sum((v - mean) ** 2 for v in values) / (k - 1)) if k > 1 else float("nan")
    return {"mean": mean, "stderr": spread / math.sqrt(k) if k > 1 else None, "count": k}


def summarise(rows: list[dict]) -> dict:
    out = {}
    for reading in dict.fromkeys(r["reading"] for r in rows):
        mine = [r for r in rows if r["reading"] == reading]
        out[reading] = {
            "heaps": len(mine),
            "angle": {m: mean_stderr([angle(r, m) for r in mine]) for m in ANGLE_METHODS},
            "angle_height_base": mean_stderr([r.get("angle_height_base") for r in mine]),
            "m_ratio": mean_stderr([(r.get("m_shape") or {}).get("ratio") for r in mine]),
            "m_shaped": sum(bool((r.get("m_shape") or {}).get("m_shaped")) for r in mine),
            "lost": mean_stderr([r["counts"]["lost"] for r in mine]),
            "at_rest": sum(bool(r["run"]["at_rest"]) for r in mine),
        }
    return out


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, default=300, help="disks per heap (the paper: 1334)")
    parser.add_argument("--seeds", type=int, default=4)
    parser.add_argument("--readings", default=",".join(READINGS[:2]))
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--checkpoint-every", type=int, default=200_000,
                        help="steps between saved states of a heap in progress (a rerun resumes from them)")
    parser.add_argument("--insert-height", type=float, default=None,
                        help="where disks appear, moving at their free-fall speed from 100 sigma (default: "
                             "6 sigma above a 45-degree heap; the paper's 100 sigma costs 14000 steps a disk)")
    parser.add_argument("--out", default=str(pathlib.Path(__file__).parent / "results" / "baxter_readings"))
    args = parser.parse_args(argv)
    readings = args.readings.split(",")
    unknown = set(readings) - set(READINGS)
    if unknown:
        parser.error(f"unknown reading(s) {sorted(unknown)}; known: {list(READINGS)}")
    folder = pathlib.Path(args.out) / f"n{args.n}"
    folder.mkdir(parents=True, exist_ok=True)

    jobs = [(r, s, str(folder / f"{r.replace('/', '_')}_seed{s}.json")) for r in readings for s in range(args.seeds)]
    todo = [j for j in jobs if not os.path.exists(j[2])]
    print(f"{len(jobs)} heaps of {args.n} disks, {len(jobs) - len(todo)} already done; results in {folder}")
    with concurrent.futures.ProcessPoolExecutor(max_workers=args.workers) as pool:
        futures = {pool.submit(one_heap, r, s, args.n, path, args.insert_height, args.checkpoint_every): (r, s) for r, s, path in todo}
        for future in concurrent.futures.as_completed(futures):
            row = future.result()
            print(f"  {row['reading']:28s} seed {row['seed']}: angle (least squares) "
                  f"{angle(row, 'least_squares'):.1f}, mid flank {angle(row, 'mid_flank')}, atan(2h/B) {row.get('angle_height_base'):.1f}, "
                  f"M ratio {(row.get('m_shape') or {}).get('ratio')}, {row['seconds']:.0f} s", flush=True)

    rows = [json.loads(pathlib.Path(path).read_text()) for _, _, path in jobs]
    table = summarise(rows)
    print(f"\n{'reading':28s} {'heaps':>5s} {'mid flank':>12s} {'endpoints':>12s} {'least sq.':>12s} {'cum. parab.':>12s} "
          f"{'atan(2h/B)':>12s} {'M ratio':>12s}")
    fmt = lambda s: "—" if s["mean"] is None else f"{s['mean']:.1f}±{(s['stderr'] or float('nan')):.1f}"
    for reading, t in table.items():
        print(f"{reading:28s} {t['heaps']:5d} " + " ".join(f"{fmt(t['angle'][m]):>12s}" for m in ANGLE_METHODS)
              + f" {fmt(t['angle_height_base']):>12s} {fmt(t['m_ratio']):>12s}")
    out = {"n": args.n, "seeds": args.seeds, "insert_height": args.insert_height, "readings": table}
    (folder / "summary.json").write_text(json.dumps(out, indent=1))
    return out


if __name__ == "__main__":
    main()
