"""Which gradient estimator survives a pile built at random? (issue 17, item 3)

The box protocol of Lee & Herrmann 1993 (theta_R moves from ~8 to ~46 deg over
mu = 0.1-0.5): the loss is (mean theta_R over B boxes - target)^2, a function of
theta = log mu. For each estimator (`jaxpile.estimators`) and ensemble size B,
`--repeats` independent ensembles (disjoint seeds) give the estimate's spread;
the bias is measured against a reference (central differences at the largest
B, over all repeats' seeds). The cost is counted in particle-steps per gradient.
Every ensemble of a given theta is one batched `jaxpile.sweep` call (the same
seeds at every theta: common random numbers).

    python benchmarks/estimator_study.py [--mu 0.25] [--target 20] [--B 8,32] [--repeats 4]
        [--n 409] [--estimators fd,smoothing] [--sigma 0.1] [--pairs 4] [--step 0.1]
        [--out benchmarks/results/estimator_study.json] [--figure docs/estimator_study.png]

The pathwise estimator is not in this study yet: differentiating a 250 000-step
box pile needs the checkpointed reverse pass over the whole fill and collapse
(issue 15's gradient cost) and explodes through the collapse (issue 17's
measurements on the pour); it is measured on the synthetic chaotic response in
tests/test_estimators.py.
"""

from __future__ import annotations

import argparse
import json
import math
import pathlib
import sys
import time

import numpy as np


def box_members(n: int, seeds: list[int], options: dict, cost: list, missing: list | None = None):
    """`thetas [m, 1] -> [m, B, 1]`: theta_R (method 3, degrees) of B boxes at
    mu = exp(theta) for each theta, one batched sweep; adds the particle-steps
    spent to `cost` and the piles left out (no angle at some theta) to `missing`."""
    from jaxpile import sweep
    from jaxpile.ensemble_fit import _fill_missing

    missing = [] if missing is None else missing

    def members_batch(thetas):
        mus = [float(math.exp(t)) for t in np.asarray(thetas)[:, 0]]
        unique = list(dict.fromkeys(mus))
        result = sweep.sweep("box", vary={"mu": unique}, seeds=seeds, options={"n": n, **options}, progress=False)
        cost.append(result.info["particle_steps_per_second"] * result.info["run_seconds"])
        by = {(round(r["mu"], 12), r["seed"]): r["repose_cumulative_parabola"] for r in result.rows}
        s = np.array([[[by[(round(mu, 12), s)]] for s in seeds] for mu in mus])
        # a box with no surface to fit (small boxes, low mu) has no theta_R: leave that pile out at
        # every theta, as the ensemble fit does (common random numbers), instead of a NaN gradient
        s, filled = _fill_missing(s)
        missing.append(filled)
        return s

    return members_batch


def one_call(members_batch, theta, step: float):
    """`members(theta)` for central differences, served from one batched call
    at theta and theta +- step e_i (one sweep, one compile, instead of 2d + 1)."""
    thetas = [theta] + [theta + s * e for e in np.eye(theta.size) for s in (step, -step)]
    values = members_batch(np.array(thetas))
    table = {tuple(np.round(t, 12)): v for t, v in zip(thetas, values)}
    return lambda t: table[tuple(np.round(np.asarray(t, dtype=float), 12))]


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--mu", type=float, default=0.25, help="where the gradient is taken")
    parser.add_argument("--target", type=float, default=20.0, help="target mean theta_R (degrees)")
    parser.add_argument("--B", default="8,32", help="ensemble sizes")
    parser.add_argument("--repeats", type=int, default=4, help="independent ensembles per (estimator, B)")
    parser.add_argument("--n", type=int, default=409, help="disks per box (the paper's W = H = 4: 409)")
    parser.add_argument("--option", action="append", default=[], metavar="NAME=VALUE",
                        help="a box option (e.g. width=1.5, max_time=0.2 for a quick check)")
    parser.add_argument("--estimators", default="fd,smoothing")
    parser.add_argument("--step", type=float, default=0.1, help="central differences: h in log mu")
    parser.add_argument("--sigma", type=float, default=0.1, help="smoothing: width in log mu")
    parser.add_argument("--pairs", type=int, default=4, help="smoothing: antithetic pairs")
    parser.add_argument("--out", default=str(pathlib.Path(__file__).parent / "results" / "estimator_study.json"))
    parser.add_argument("--figure", default=None)
    args = parser.parse_args(argv)

    import jax
    import jax.numpy as jnp

    import jaxpile  # noqa: F401  (float64)
    from jaxpile import cli, estimators

    cli.threads_for_batches()  # batches of piles: XLA's threads, as `jaxpile fit` gives an ensemble fit

    options = {}
    for item in args.option:
        name, _, value = item.partition("=")
        options[name] = float(value)
    sizes = [int(b) for b in args.B.split(",")]
    theta = np.array([math.log(args.mu)])
    objective = lambda m: (m[0] - args.target) ** 2
    rows = []
    seed_base = 0
    t_all = time.perf_counter()
    for size in sizes:
        for r in range(args.repeats):
            seeds = list(range(seed_base, seed_base + size))
            seed_base += size
            for name in args.estimators.split(","):
                cost, missing = [], []
                batch = box_members(args.n, seeds, options, cost, missing)
                t0 = time.perf_counter()
                if name == "fd":
                    est = estimators.central_differences(one_call(batch, theta, args.step), objective, theta,
                                                         step=args.step)
                elif name == "smoothing":
                    est = estimators.antithetic_smoothing(batch, objective, theta, jax.random.PRNGKey(seed_base + r),
                                                          sigma=args.sigma, pairs=args.pairs)
                else:
                    parser.error(f"unknown estimator {name!r}; known: fd, smoothing")
                row = {"estimator": name, "B": size, "repeat": r, "seeds": [seeds[0], seeds[-1]],
                       "gradient": float(est.gradient[0]), "stderr": float(est.stderr[0]),
                       "value": est.value, "ensembles": est.evaluations, "particle_steps": float(sum(cost)),
                       "piles_left_out": int(sum(missing)),
                       "seconds": time.perf_counter() - t0}
                rows.append(row)
                print(f"{name:10s} B {size:4d} repeat {r}: dL/dlog mu = {row['gradient']:.4g} +- {row['stderr']:.2g}, "
                      f"{row['particle_steps']:.3g} particle-steps, {row['seconds']:.0f} s", flush=True)
    # the reference: central differences over every seed used, at the study's h
    all_seeds = list(range(seed_base))
    cost = []
    ref = estimators.central_differences(one_call(box_members(args.n, all_seeds, options, cost), theta, args.step),
                                         objective, theta, step=args.step)
    reference = {"gradient": float(ref.gradient[0]), "stderr": float(ref.stderr[0]), "B": len(all_seeds),
                 "particle_steps": float(sum(cost))}
    summary = {}
    for name in args.estimators.split(","):
        for size in sizes:
            g = np.array([r["gradient"] for r in rows if r["estimator"] == name and r["B"] == size])
            c = np.array([r["particle_steps"] for r in rows if r["estimator"] == name and r["B"] == size])
            summary[f"{name}/B{size}"] = {
                "mean": float(g.mean()), "spread": float(g.std(ddof=1)) if g.size > 1 else None,
                "bias": float(g.mean() - reference["gradient"]),
                "bias_stderr": float(g.std(ddof=1) / math.sqrt(g.size)) if g.size > 1 else None,
                "particle_steps_per_gradient": float(c.mean())}
    out = {"protocol": "box", "law": "lee-herrmann", "quantity": "theta_R (method 3)", "mu": args.mu,
           "target": args.target, "n": args.n, "options": options, "step": args.step, "sigma": args.sigma,
           "pairs": args.pairs, "reference": reference, "summary": summary, "rows": rows,
           "seconds": time.perf_counter() - t_all,
           "command": "python benchmarks/estimator_study.py " + " ".join(argv if argv is not None else sys.argv[1:])}
    pathlib.Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    pathlib.Path(args.out).write_text(json.dumps(out, indent=1))
    print(json.dumps({"reference": reference, "summary": summary}, indent=1))
    if args.figure:
        figure(out, args.figure)
        print(f"figure: {args.figure}")
    return out


def figure(out: dict, path: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (a, b) = plt.subplots(1, 2, figsize=(10, 4))
    ref = out["reference"]
    a.axhspan(ref["gradient"] - ref["stderr"], ref["gradient"] + ref["stderr"], color="0.85",
              label=f"reference: FD over {ref['B']} boxes")
    for k, (key, s) in enumerate(out["summary"].items()):
        mine = [r for r in out["rows"] if f"{r['estimator']}/B{r['B']}" == key]
        a.plot([k] * len(mine), [r["gradient"] for r in mine], "o", color=f"C{k}", alpha=0.5)
        a.errorbar(k + 0.15, s["mean"], s["spread"] or 0, fmt="s", color=f"C{k}", capsize=3)
        b.plot(s["particle_steps_per_gradient"], s["spread"] or float("nan"), "o", color=f"C{k}", label=key)
    a.set_xticks(range(len(out["summary"])), list(out["summary"]), fontsize=8)
    a.set_ylabel("dL / d log mu")
    a.set_title(f"estimates (each repeat) and their spread; mu = {out['mu']}")
    a.legend(fontsize=8)
    b.set_xscale("log")
    b.set_xlabel("particle-steps per gradient")
    b.set_ylabel("spread of the estimate")
    b.set_title("cost against spread")
    b.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


if __name__ == "__main__":
    main()
