"""What an iterate of a truncated pathwise fit costs (`jaxpile fit --estimator
truncated`: a host run to size the rollouts, a checking rollout, then the
windows' forward-mode rollout; `construction.Construction` and
`estimators.truncated_pathwise`), side by side in one process:

- `fresh`: every iterate builds its simulator and rollout functions anew, so
  each compiles again (how the fit ran before they were kept per configuration);
- `kept`: the fit's iterates share one simulator and one set of functions
  (`construction._pieces`), and the windows' jitted program is kept on the
  `advance` function: only the first iterate compiles.

    python benchmarks/truncated_fit_cost.py --out benchmarks/results/cpu/truncated_fit_cost.json

The gradients of the two modes must agree bit for bit (the script checks it).
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import jax
import numpy as np

jax.config.update("jax_enable_x64", True)

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import machine  # noqa: E402

from jaxpile import io  # noqa: E402
from jaxpile.fit import construction, ensemble_fit, estimators  # noqa: E402


def iterates(mode: str, thetas, runner, statistics, seeds, window: int) -> list[dict]:
    construction._PIECES.clear()  # each mode starts from nothing compiled for its configuration
    rows = []
    for theta in thetas:
        if mode == "fresh":
            construction._PIECES.clear()
        t0 = time.perf_counter()
        c = construction.Construction(runner, seeds, statistics, ["n"], theta)
        t1 = time.perf_counter()
        est = estimators.truncated_pathwise(c.advance, c.statistics, lambda m: (m ** 2).sum(), theta, c.start,
                                            c.steps, window, combine="mean")
        gradient = np.asarray(est.gradient, float)
        t2 = time.perf_counter()
        rows.append({"mode": mode, "theta": theta.tolist(), "steps": c.steps, "construction_s": t1 - t0,
                     "windows_s": t2 - t1, "iterate_s": t2 - t0, "gradient": gradient.tolist()})
        print(f"{mode:5s} n = {np.exp(theta[0]):5.1f}: construction {t1 - t0:6.1f} s, windows {t2 - t1:6.1f} s "
              f"({c.steps} steps), gradient {gradient[0]:+.6e}", flush=True)
    return rows


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--disks", type=int, default=3)
    ap.add_argument("--seeds", type=int, default=2)
    ap.add_argument("--iterates", type=int, default=3)
    ap.add_argument("--window", type=int, default=500)
    ap.add_argument("--out", default=None)
    args = ap.parse_args(argv)
    runner = ensemble_fit.Runner("pour", options={"n": args.disks, "insert_height": 5.0})
    statistics = ensemble_fit.Statistics(bins=3)
    thetas = [np.log([30.0 + k]) for k in range(args.iterates)]
    seeds = list(range(args.seeds))
    rows = [r for mode in ("fresh", "kept") for r in iterates(mode, thetas, runner, statistics, seeds, args.window)]
    fresh = [r for r in rows if r["mode"] == "fresh"]
    kept = [r for r in rows if r["mode"] == "kept"]
    same = all(a["gradient"] == b["gradient"] for a, b in zip(fresh, kept))
    later = {m: float(np.mean([r["iterate_s"] for r in rs[1:]])) for m, rs in (("fresh", fresh), ("kept", kept))}
    print(f"after the first iterate: fresh {later['fresh']:.1f} s, kept {later['kept']:.1f} s an iterate "
          f"({later['fresh'] / later['kept']:.1f}x); gradients bit-identical: {same}")
    if not same:
        raise SystemExit("the kept functions changed the gradient")
    if args.out:
        out = {"machine": machine.details(), "command": "python benchmarks/truncated_fit_cost.py " + " ".join(
            argv if argv is not None else sys.argv[1:]), "disks": args.disks, "seeds": args.seeds,
            "window": args.window, "rows": rows, "later_iterate_s": later}
        io.write_json(args.out, out)


if __name__ == "__main__":
    main()
