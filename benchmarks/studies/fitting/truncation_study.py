"""How long must the windows of the truncated pathwise gradient be on a poured heap? (issue 17, items 2-3)

Small Baxter pours (`--n` disks, `--members` seeds in one vmapped rollout),
theta = log n (the force-law index); the loss is the squared distance between
the members' mean smoothed base profile (normal force, `--bins` bins over the
protocol's heap extent) and a target made the same way at `--truth` from seeds
the estimate never sees. At theta0 = log `--at` it compares:

- central differences with common random numbers at steps h (the reference:
  they see the ensemble mean move; a chaotic pour needs a wide h),
- the pathwise gradient (one window: the whole construction),
- `estimators.truncated_pathwise` with windows W, summed and averaged,

each with its jackknife standard error over members and its cost (seconds,
and forward particle-steps). Prints a table and writes JSON (and a figure).

    python benchmarks/studies/fitting/truncation_study.py [--n 12] [--members 8] [--at 36] [--truth 30]
        [--windows 1000,250,60] [--steps-h 0.1,0.3] [--settle 1500]
        [--out benchmarks/results/truncation_study.json] [--figure docs/truncation_study.png]
"""

from __future__ import annotations

import argparse
import json
import math
import pathlib
import sys
import time

import numpy as np

HERE = pathlib.Path(__file__).resolve().parent  # benchmarks/studies/fitting
RESULTS = HERE.parents[1] / "results"  # benchmarks/results


def problem(n: int, seeds: list[int], interval: float, insert_height: float, settle: int, bins: int):
    """`(advance, statistics, start, steps, particles)` for the members `seeds`:
    advance(theta, state, k) runs k steps of every member at n = exp(theta)."""
    import jax

    import jaxpile

    jaxpile.configure()  # float64 and the commands' XLA settings
    from jaxpile import analysis, batches, fit
    from jaxpile.engine import ensemble
    from jaxpile.engine import pairs as pair_list
    from jaxpile.engine.neighbors import overflowed
    from jaxpile.protocols import pour

    sim = pour.make_simulator("baxter", in_play=None)  # rollouts carry every disk (no host blocks inside)
    base = pour.law_params("baxter")
    protocols = [pour.SPEC.set_up("baxter", n, seed=s, interval=interval, insert_height=insert_height) for s in seeds]
    ens = ensemble.Ensemble(sim)
    start = ens.init([base] * len(seeds), protocols)
    steps = int(protocols[0].info["pour_steps"]) + settle
    # size the lists on a host run of the whole construction (a rollout has no overflow handling)
    end = ens.run([base] * len(seeds), start, steps, progress=False)
    # with head-room: other n (the target's, the central differences') pack the heap differently
    slots, cells = int(end.neighbors.max_occupancy) + 8, None  # None: a cell window of every disk (few here)
    pairs = pair_list.aligned(int(1.5 * int(end.contacts.pairs.shape[-2])))
    start = ensemble.stack([ensemble.at_capacity(ensemble.member(start, i), slots, cells, pairs)
                            for i in range(len(seeds))])
    _, x_left, x_right = batches.batch_of("pour").extent(protocols[0])

    def params(theta):
        return base.set(n=jax.numpy.exp(theta[0]))

    def advance(theta, state, k):
        return jax.vmap(lambda m: sim.rollout(params(theta), m, k))(state)

    def statistics(theta, state):
        def one(m):
            load = analysis.base_load(sim, params(theta), m, base="substrate")
            return fit.smooth_base_profile(load, x_left=x_left, x_right=x_right, bins=bins).normal
        return jax.vmap(one)(state)

    def checked(state):
        if bool(np.any(np.asarray(overflowed(state)))):
            raise RuntimeError(f"a list overflowed inside a rollout (neighbours {np.asarray(state.neighbors.did_buffer_overflow)}, "
                               f"pairs {np.asarray(state.contacts.demand)} > {state.contacts.pairs.shape[-2]}): "
                               "raise the capacity")
        return state

    return advance, statistics, start, steps, checked, start.particles.position.shape[1]


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, default=12, help="disks per heap")
    parser.add_argument("--members", type=int, default=8, help="heaps per ensemble (seeds 0..B-1)")
    parser.add_argument("--at", type=float, default=36.0, help="the force-law index where the gradient is taken")
    parser.add_argument("--truth", type=float, default=30.0, help="the index the target is made at")
    parser.add_argument("--windows", default="1000,250,60", help="truncation windows W (steps)")
    parser.add_argument("--steps-h", default="0.1,0.3", help="central differences: h in log n")
    parser.add_argument("--interval", type=float, default=0.15, help="time between releases (paper: 1.612)")
    parser.add_argument("--insert-height", type=float, default=8.0)
    parser.add_argument("--settle", type=int, default=1500, help="steps after the last release")
    parser.add_argument("--bins", type=int, default=5)
    parser.add_argument("--out", default=str(RESULTS / "truncation_study.json"))
    parser.add_argument("--figure", default=None)
    args = parser.parse_args(argv)

    import jax
    import jax.numpy as jnp

    from jaxpile.fit.estimators import central_differences, pathwise, truncated_pathwise

    seeds = list(range(args.members))
    t0 = time.perf_counter()
    advance, statistics, start, steps, checked, particles = problem(
        args.n, seeds, args.interval, args.insert_height, args.settle, args.bins)
    target_problem = problem(args.n, [10_000 + s for s in seeds], args.interval, args.insert_height,
                             args.settle, args.bins)
    truth = jnp.asarray([math.log(args.truth)])
    t_adv, t_stats, t_start, t_steps, t_checked, _ = target_problem
    target = jnp.asarray(t_stats(truth, t_checked(jax.jit(t_adv, static_argnums=2)(truth, t_start, t_steps))).mean(0))
    objective = lambda m: jnp.sum((m - target) ** 2)
    theta = np.array([math.log(args.at)])
    run = jax.jit(advance, static_argnums=2)
    print(f"{args.members} heaps of {args.n} disks ({particles} with the substrate), {steps} steps; "
          f"target at n = {args.truth} (seeds 10000+), gradient at n = {args.at}; set-up {time.perf_counter() - t0:.0f} s",
          flush=True)

    rows = []
    members = lambda x: statistics(jnp.asarray(x), checked(run(jnp.asarray(x), start, steps)))
    for h in [float(v) for v in args.steps_h.split(",")]:
        t1 = time.perf_counter()
        est = central_differences(members, objective, theta, step=h)  # jackknife s.e. over members
        rows.append({"estimator": "central differences", "h": h, "gradient": float(est.gradient[0]),
                     "stderr": float(est.stderr[0]), "value": est.value, "seconds": time.perf_counter() - t1,
                     "particle_steps": 3 * args.members * particles * steps})
    value = next(r["value"] for r in rows)  # F(theta0), which central differences evaluated
    t1 = time.perf_counter()
    path = pathwise(lambda x: statistics(x, checked(run(x, start, steps))), objective, theta)
    rows.append({"estimator": "pathwise", "window": steps, "gradient": float(path.gradient[0]),
                 "stderr": float(path.stderr[0]), "seconds": time.perf_counter() - t1,
                 "particle_steps": args.members * particles * steps})
    for w in [int(v) for v in args.windows.split(",")]:
        for combine in ("sum", "mean"):
            t1 = time.perf_counter()
            est = truncated_pathwise(advance, statistics, objective, theta, start, steps, w, combine=combine)
            rows.append({"estimator": f"truncated ({combine})", "window": w, "gradient": float(est.gradient[0]),
                         "stderr": float(est.stderr[0]), "seconds": time.perf_counter() - t1,
                         "particle_steps": args.members * particles * steps})
    print(f"loss at n = {args.at}: {value:.4g}")
    print(f"{'estimator':22s} {'h or W':>8s} {'dL/dlog n':>12s} {'s.e.':>10s} {'seconds':>8s}")
    for r in rows:
        knob = r.get("h", r.get("window"))
        se = "—" if r["stderr"] is None else f"{r['stderr']:.3g}"
        print(f"{r['estimator']:22s} {knob:>8g} {r['gradient']:>12.4g} {se:>10s} {r['seconds']:>8.1f}")
    record = {"command": "python benchmarks/studies/fitting/truncation_study.py " + " ".join(argv if argv is not None else sys.argv[1:]),
              "n": args.n, "members": args.members, "at": args.at, "truth": args.truth, "steps": steps,
              "particles": particles, "loss": value, "rows": rows,
              "device": f"{jax.devices()[0].platform}, jax {jax.__version__}"}
    pathlib.Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    pathlib.Path(args.out).write_text(json.dumps(record, indent=1))
    if args.figure:
        figure(record, args.figure)
    return record


def figure(record: dict, path: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.5, 4))
    for r in record["rows"]:
        if r["estimator"] == "central differences":
            colour = "0.3" if r["h"] < 0.2 else "0.65"
            ax.axhline(r["gradient"], ls="--", color=colour, label=f"central differences, h = {r['h']:g} (+- s.e.)")
            ax.axhspan(r["gradient"] - r["stderr"], r["gradient"] + r["stderr"], color=colour, alpha=0.15)
    for k, combine in enumerate(("sum", "mean")):
        mine = [r for r in record["rows"] if r["estimator"] == f"truncated ({combine})"]
        path_row = [r for r in record["rows"] if r["estimator"] == "pathwise"]
        pts = path_row + mine
        ax.errorbar([r["window"] for r in pts], [r["gradient"] for r in pts], [r["stderr"] for r in pts],
                    marker="os"[k], capsize=3, label=f"truncated pathwise, {combine} (W = T: pathwise)")
    ax.set_xscale("log")
    ax.set_xlabel("window W (steps)")
    ax.set_ylabel("d loss / d log n")
    ax.set_title(f"{record['members']} poured heaps of {record['n']} disks, gradient at n = {record['at']:g}")
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


if __name__ == "__main__":
    main()
