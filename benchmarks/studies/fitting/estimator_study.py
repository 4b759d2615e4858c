"""Which gradient estimator survives a pile built at random? (issue 17, item 3)

Two cases, each a loss of ensemble means taken as a function of
theta = log(parameters), at a point some way from where the loss is least:

- `box` (Lee & Herrmann 1993; theta_R moves from ~8 to ~46 deg over
  mu = 0.1-0.5): loss (mean theta_R over B boxes - target)^2 against log mu.
- `pour` (Baxter et al. 1997, 40-disk heaps as in `fit_recovery.py pour`):
  the fit's loss (the angles and the 9-bin normal and horizontal base profile,
  in the fit's weights, against a target ensemble at the truth) against
  log n and log mu (the paper calls the heap insensitive to mu in 0.2-0.6:
  the mu component measures how much of an estimate is noise).

For each estimator (`jaxpile.fit.estimators`) and ensemble size B, `--repeats`
independent ensembles (disjoint seeds) give the estimate's spread; the bias
is measured against a reference: central differences over every seed of the
central-difference rows together (their members, reused: no second run).
The cost is counted in particle-steps per gradient. Every ensemble of a
given theta is one batched `jaxpile.sweeps` (through `ensemble_fit.Runner`;
the same seeds at every theta: common random numbers).

    python benchmarks/studies/fitting/estimator_study.py [--case box|pour] [--B 8,32] [--repeats 4]
        [--estimators fd,smoothing,truncated:W] [--step H] [--sigma S] [--pairs 4] [--resume] [--checkpoint-every STEPS]
        [--out benchmarks/results/estimator_study.json] [--figure docs/estimator_study.png]
      box:  [--mu 0.25] [--target 20] [--n 409] [--option width=2 ...]
      pour: [--n 40] (point n = 33, mu = 0.5; target 32 heaps at n = 41.3, seeds 10000+)
    python benchmarks/studies/fitting/estimator_study.py --table   # docs/fitting.md's table from the results JSON
    python benchmarks/studies/fitting/estimator_study.py ... --resume --summarise-only   # the rows so far, summarised

Each finished row is written to `--out` at once; `--resume` skips the rows
already there (a study at B = 128 outlasts a session on 2 cores), and with
`--checkpoint-every` continues the row that was running from its last save.

`truncated:W` (the pour): `estimators.truncated_pathwise` with windows of W
steps, their sensitivities averaged (`combine="mean"`, the low-noise one in
`truncation_study.py`), through the same heaps run as fixed-length rollouts
(`jaxpile.fit.construction`, as `jaxpile fit --estimator truncated` runs
them). It differentiates the base profile's terms of the loss only (the
angles are fitted on the host): its bias is measured against
central differences of those terms, from the same members.

The pathwise estimator is not in this study: differentiating a 250 000-step
box pile needs the checkpointed reverse pass over the whole fill and collapse
and explodes through the collapse (issue 17's measurements on the pour); it
is measured on small heaps by `truncation_study.py` and on the synthetic
chaotic response in tests/test_estimators.py.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import pathlib
import sys
import time

import numpy as np

HERE = pathlib.Path(__file__).resolve().parent  # benchmarks/studies/fitting
BENCHMARKS = HERE.parents[1]
sys.path.insert(0, str(BENCHMARKS.parent))  # jaxpile from this checkout where it is not installed (a GPU call)
sys.path.insert(1, str(BENCHMARKS))  # docs_block

CASES = {
    "box": dict(protocol="box", law="lee-herrmann", options={"n": 409}, point={"mu": 0.25},
                statistics=dict(columns=("repose_cumulative_parabola",)), step=0.1),
    # the fit_recovery pour, its gradient taken 20 % below the truth in n (where a fit from its start passes)
    "pour": dict(protocol="pour", law="baxter", options={"n": 40}, point={"n": 33.0, "mu": 0.5},
                 truth={"n": 41.3, "mu": 0.5}, target_seeds=32,
                 statistics=dict(columns=("repose_mean", "angle_height_base"), bins=9), step=0.2),
}

STUDIES = ("estimator_study.json", "estimator_study_b32.json", "estimator_study_b128.json",
           "estimator_study_pour.json", "estimator_study_pour_b128.json")
"""The results the table in docs/fitting.md is built from, in its order (those that exist)."""

START, END = "<!-- estimator-study:start -->\n", "<!-- estimator-study:end -->"


class Members:
    """`[m, d]` log-parameters -> `[m, B, k]` statistics of the B seeds at each,
    one batched run; keeps the particle-steps spent and the piles left out (a
    pile with no statistic at some theta is left out at every theta, as the
    ensemble fit does, instead of a NaN gradient)."""

    def __init__(self, runner, names, seeds, statistics, checkpoint: str | None = None, every: int = 0,
                 resume: bool = False):
        self.runner, self.names, self.seeds, self.statistics = runner, list(names), list(seeds), statistics
        self.checkpoint, self.every = checkpoint, int(every)
        if checkpoint and os.path.exists(checkpoint) and not resume:  # another study's batch: not this one's
            os.remove(checkpoint)
        self.particle_steps, self.left_out, self.last = 0.0, 0, None

    def _run(self, points):
        """`runner.run`, with the batch saved every `every` steps to `checkpoint`
        and resumed from it when it is there (a B = 128 batch of boxes runs
        for hours on 2 cores). The file stays until the row is in the JSON
        (`main` removes it then)."""
        if not (self.checkpoint and self.every):
            return self.runner.run(points, self.seeds, self.statistics)
        return self.runner.run(points, self.seeds, self.statistics, checkpoint=(self.checkpoint, self.every),
                               resume=self.checkpoint if os.path.exists(self.checkpoint) else None)

    def __call__(self, thetas):
        from jaxpile.fit.ensemble_runs import fill_missing

        thetas = np.asarray(thetas, dtype=float)
        points = [{n: float(math.exp(t)) for n, t in zip(self.names, row)} for row in thetas]
        s, info = self._run(points)
        self.particle_steps += float(info["particle_steps"])
        s, filled = fill_missing(s)
        self.left_out += filled
        self.last = s
        return s


def profile_part(labels, objective_weights, target_mean):
    """`(indices, objective)`: the base-profile terms of the fit's loss alone
    (the same weights and target; the angles' terms left out)."""
    import jax.numpy as jnp

    idx = np.array([i for i, label in enumerate(labels) if label.startswith(("normal[", "horizontal["))])
    w, t, k = jnp.asarray(objective_weights)[idx], jnp.asarray(target_mean)[idx], len(labels)
    return idx, lambda m: jnp.sum(w * (jnp.asarray(m) - t) ** 2) / k


def case_objective(case: str, args, runner, statistics, out: dict):
    """`(objective, weights, target mean)`: the loss of the ensemble-mean
    statistics, and (pour) the fit's weights and its target's means."""
    from jaxpile.fit import ensemble_fit as ef

    if case == "box":
        return (lambda m: (m[0] - args.target) ** 2), None, None
    if "target_ensemble" in out:  # resumed: the same target
        target = ef.EnsembleTarget.from_json(out["target_ensemble"])
    else:
        c = CASES[case]
        t0 = time.perf_counter()
        target = ef.make_target(runner, c["truth"], range(10_000, 10_000 + c["target_seeds"]), statistics)
        out["target_ensemble"] = target.to_json()
        out["target_seconds"] = time.perf_counter() - t0
    w = ef.weights(target)
    return ef.objective_for(target, w), np.asarray(w), np.asarray(target.mean)


def _save(out: dict, path: str) -> None:
    pathlib.Path(path).parent.mkdir(parents=True, exist_ok=True)
    tmp = path + ".tmp"
    with open(tmp, "w") as fh:  # compact: its per-replicate records are read by scripts, its summary printed
        json.dump(out, fh, separators=(",", ":"))
        fh.write("\n")
    os.replace(tmp, path)


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--case", choices=sorted(CASES), default="box")
    parser.add_argument("--mu", type=float, default=None, help="box: where the gradient is taken (default 0.25)")
    parser.add_argument("--target", type=float, default=20.0, help="box: target mean theta_R (degrees)")
    parser.add_argument("--B", default="8,32", help="ensemble sizes")
    parser.add_argument("--repeats", type=int, default=4, help="independent ensembles per (estimator, B)")
    parser.add_argument("--n", type=int, default=None, help="disks per pile (box: the paper's W = H = 4: 409; "
                                                            "pour: 40)")
    parser.add_argument("--option", action="append", default=[], metavar="NAME=VALUE",
                        help="a protocol option (e.g. width=1.5, max_time=0.2 for a quick check)")
    parser.add_argument("--estimators", default="fd,smoothing")
    parser.add_argument("--step", type=float, default=None, help="central differences: h in log-parameter "
                                                                  "(box 0.1, pour 0.2: the fits' steps)")
    parser.add_argument("--sigma", type=float, default=None, help="smoothing: width in log-parameter (default h)")
    parser.add_argument("--pairs", type=int, default=4, help="smoothing: antithetic pairs")
    parser.add_argument("--resume", action="store_true", help="keep the rows already in --out and run the rest")
    parser.add_argument("--checkpoint-every", type=int, default=0, metavar="STEPS",
                        help="save a row's batch every STEPS steps beside --out (OUT.ROW.ckpt) and, with --resume, "
                             "continue it from there")
    parser.add_argument("--out", default=str(BENCHMARKS / "results" / "estimator_study.json"))
    parser.add_argument("--figure", default=None)
    parser.add_argument("--table", action="store_true", help="rewrite docs/fitting.md's table from the results and stop")
    parser.add_argument("--summarise-only", action="store_true",
                        help="with --resume: run nothing, summarise the rows in --out (a study cut off by the end "
                             "of a session; `complete` says whether every planned row is in)")
    args = parser.parse_args(argv)
    if args.table:
        rewrite_page()
        print(table())
        return {}

    import jax

    import jaxpile

    jaxpile.configure(threads=True)  # float64, XLA's settings and its threads: batches, as `jaxpile fit` runs an ensemble fit
    from jaxpile.fit import estimators
    from jaxpile.fit import construction
    from jaxpile.fit import ensemble_fit as ef


    estimator_names = list(dict.fromkeys(args.estimators.split(",")))  # each once
    if args.summarise_only and not args.resume:
        parser.error("--summarise-only summarises the rows of --out: give --resume as well.")
    for name in estimator_names:  # before any pile runs: a typo must not cost an hour's rows
        window = name.partition(":")[2]
        if not (name in ("fd", "smoothing") or (name.startswith("truncated:") and window.isdigit() and int(window) > 0
                                                and args.case == "pour")):
            parser.error(f"unknown estimator {name!r}; known: fd, smoothing, truncated:W (W > 0 steps; the pour)")
    c = CASES[args.case]
    options = dict(c["options"])
    if args.n is not None:
        options["n"] = args.n
    for item in args.option:
        name, _, value = item.partition("=")
        options[name] = float(value)
    point = dict(c["point"])
    if args.mu is not None:
        point["mu"] = args.mu
    step = args.step or c["step"]
    sigma = args.sigma or step
    names = list(point)
    sizes = list(dict.fromkeys(int(b) for b in args.B.split(",")))
    theta = np.log([point[n] for n in names])
    runner = ef.Runner(c["protocol"], c["law"], options=options)
    statistics = ef.Statistics(**c["statistics"])
    command = "python benchmarks/studies/fitting/estimator_study.py " + " ".join(argv if argv is not None else sys.argv[1:])
    setting = {"case": args.case, "protocol": c["protocol"], "law": c["law"], "names": names, "point": point,
               "options": options, "statistics": statistics.labels(), "step": step, "sigma": sigma,
               "pairs": args.pairs, "target": args.target if args.case == "box" else c.get("truth")}
    out = {**setting, "rows": [], "seconds": 0.0, "command": command}
    if args.resume and os.path.exists(args.out):
        with open(args.out) as fh:
            old = json.load(fh)
        differ = [k for k in setting if old.get(k) != setting[k]]
        if differ:
            raise SystemExit(f"{args.out} was made with other settings ({', '.join(differ)}); give another --out.")
        out = {k: v for k, v in old.items() if k not in ("summary", "reference", "reference_profile", "complete")}
        if args.summarise_only:  # the command that ran the rows stays the record's
            out["summarised_by"] = command
        else:
            out.update(command=command, resumed_from_seconds=old.get("seconds", 0.0))
    objective, weights, target_mean = case_objective(args.case, args, runner, statistics, out)
    _save(out, args.out)  # the target (the pour's 32 heaps) is kept even if the first row is cut off
    profile_idx, profile_objective = (None, None) if weights is None else profile_part(
        statistics.labels(), weights, target_mean)
    truncated = {}  # seeds -> Construction: one host run and compile per ensemble
    done = {(r["estimator"], r["B"], r["repeat"]): r["seeds"] for r in out["rows"]}
    t_all = time.perf_counter() - out.get("seconds", 0.0)
    seed_base, planned = 0, set()
    for size in sizes:
        for r in range(args.repeats):
            seeds = list(range(seed_base, seed_base + size))
            seed_base += size
            for name in estimator_names:
                planned.add((name, size, r))
                if (name, size, r) in done:
                    if done[(name, size, r)] != [seeds[0], seeds[-1]]:  # --B or --repeats changed: other seeds
                        raise SystemExit(f"{args.out}'s {name} row at B = {size}, repeat {r} has seeds "
                                         f"{done[(name, size, r)]}, this plan {[seeds[0], seeds[-1]]}: resume "
                                         "with the --B and --repeats that made it.")
                    continue
                if args.summarise_only:
                    continue
                members = Members(runner, names, seeds, statistics, f"{args.out}.{name}-B{size}-r{r}.ckpt",
                                  args.checkpoint_every, resume=args.resume)
                t0 = time.perf_counter()
                direction_key = seed_base + r  # smoothing's directions: jax.random.PRNGKey(direction_key)
                if name == "fd":
                    s = members(estimators.central_points(theta, step))
                    est = estimators.central_from_members(s, objective, step)
                elif name == "smoothing":
                    est = estimators.antithetic_smoothing(members, objective, theta,
                                                          jax.random.PRNGKey(direction_key), sigma=sigma,
                                                          pairs=args.pairs)
                elif name.startswith("truncated:") and args.case == "pour":
                    window = int(name.split(":")[1])
                    key = (seeds[0], seeds[-1])
                    if key not in truncated:  # the traceable statistics: the base profile alone
                        truncated[key] = construction.Construction(runner, seeds, statistics._replace(columns=()),
                                                                   names, theta)
                    tp = truncated[key]
                    est = estimators.truncated_pathwise(tp.advance, tp.statistics, profile_objective, theta, tp.start,
                                                        tp.steps, window, combine="mean")
                    members.particle_steps = float(len(seeds) * tp.particles * tp.steps)
                else:
                    parser.error(f"unknown estimator {name!r}; known: fd, smoothing, truncated:W (the pour)")
                row = {"estimator": name, "B": size, "repeat": r, "seeds": [seeds[0], seeds[-1]],
                       "gradient": np.asarray(est.gradient).tolist(), "stderr": np.asarray(est.stderr).tolist(),
                       "value": est.value, "ensembles": est.evaluations, "particle_steps": members.particle_steps,
                       "piles_left_out": members.left_out, "seconds": time.perf_counter() - t0}
                if name == "fd":  # the reference reuses them
                    row["members"] = members.last.tolist()
                if name == "smoothing":  # its directions as this JAX drew them from the key
                    row["key"] = direction_key
                    row["directions"] = estimators.smoothing_directions(jax.random.PRNGKey(direction_key), args.pairs,
                                                                        len(names)).tolist()
                out["rows"].append(row)
                done[(name, size, r)] = row["seeds"]
                out["seconds"] = time.perf_counter() - t_all
                _save(out, args.out)
                if members.checkpoint and os.path.exists(members.checkpoint):  # the row is in the JSON now
                    os.remove(members.checkpoint)
                print(f"{name:10s} B {size:4d} repeat {r}: dL/dlog {names} = {np.round(row['gradient'], 4)} +- "
                      f"{np.round(row['stderr'], 3)}, {row['particle_steps']:.3g} particle-steps, "
                      f"{row['seconds']:.0f} s", flush=True)
    out.update(summarise(out, objective, profile_idx, profile_objective))
    out["complete"] = planned <= {(r["estimator"], r["B"], r["repeat"]) for r in out["rows"]}
    out["seconds"] = time.perf_counter() - t_all
    _save(out, args.out)
    print(json.dumps({"reference": out["reference"], "summary": out["summary"]}, indent=1))
    if args.figure:
        figure(out, args.figure)
        print(f"figure: {args.figure}")
    return out


def _gradient(row) -> np.ndarray:
    """A row's gradient as `[d]` (the first studies wrote a scalar)."""
    return np.atleast_1d(np.asarray(row["gradient"], dtype=float))


def summarise(out: dict, objective, profile_idx=None, profile_objective=None) -> dict:
    """The reference (central differences over the members of every `fd` row
    together: the same thetas, disjoint seeds) and, per (estimator, B), the
    mean, spread and bias of the estimates. The truncated rows differentiate
    the base-profile terms of the loss alone: their reference
    (`reference_profile`) is taken from the same members, those terms only."""
    from jaxpile.fit import estimators

    fd = [r for r in out["rows"] if r["estimator"] == "fd"]
    if not fd:
        raise SystemExit("the reference is built from the central-difference rows: include fd in --estimators.")
    s = np.concatenate([np.asarray(r["members"], float) for r in fd], axis=1)
    cost = float(sum(r["particle_steps"] for r in fd))

    def reference_of(s, objective):
        ref = estimators.central_from_members(s, objective, out["step"])
        return {"gradient": np.asarray(ref.gradient).tolist(), "stderr": np.asarray(ref.stderr).tolist(),
                "B": int(s.shape[1]), "particle_steps": cost}

    reference = reference_of(s, objective)
    reference["by_size"] = central_by_size(s, objective, out["step"],
                                           sorted({8, 32, 128} | {int(r["B"]) for r in out["rows"]}))
    extra = {}
    if profile_objective is not None and any(r["estimator"].startswith("truncated") for r in out["rows"]):
        extra["reference_profile"] = reference_of(s[..., profile_idx], profile_objective)
    summary = {}
    for key in dict.fromkeys(f"{r['estimator']}/B{r['B']}" for r in out["rows"]):
        mine = _rows_of(out, key)
        g = np.stack([_gradient(r) for r in mine])
        against = extra["reference_profile"] if key.startswith("truncated") else reference
        summary[key] = {
            "mean": g.mean(axis=0).tolist(),
            "spread": g.std(axis=0, ddof=1).tolist() if len(g) > 1 else None,
            "bias": (g.mean(axis=0) - np.asarray(against["gradient"])).tolist(),
            "bias_stderr": (g.std(axis=0, ddof=1) / math.sqrt(len(g))).tolist() if len(g) > 1 else None,
            "particle_steps_per_gradient": float(np.mean([r["particle_steps"] for r in mine]))}
    return {"reference": reference, **extra, "summary": summary}


def central_by_size(s: np.ndarray, objective, step: float, sizes=(8, 32, 128), draws: int = 400) -> dict:
    """What central differences from B of the pooled piles `s` (`[2d + 1, N,
    k]`) give, over `draws` random choices of B (the same piles at every
    point): their mean and spread, for each B < N. The loss of an ensemble mean
    depends on B through the mean's own variance; these say by how much, and
    what spread a row of B independent piles should show (B drawn from N
    without replacement vary less by sqrt((N - B) / (N - 1)), taken out)."""
    d, n = (s.shape[0] - 1) // 2, s.shape[1]
    rng = np.random.default_rng(0)
    result = {}
    for size in (b for b in sizes if b < n):
        g = []
        for _ in range(draws):
            f = [float(objective(m)) for m in s[:, rng.choice(n, size, replace=False)].mean(axis=1)]
            g.append([(f[1 + i] - f[1 + d + i]) / (2 * step) for i in range(d)])
        g = np.asarray(g)
        finite_population = math.sqrt((n - size) / (n - 1))
        result[str(size)] = {"mean": g.mean(axis=0).tolist(),
                             "spread": (g.std(axis=0, ddof=1) / finite_population).tolist(), "draws": draws}
    return result


def _fmt(x: float) -> str:
    """3 significant figures (whole numbers from 100 up), a true minus sign."""
    text = f"{x:.0f}" if 100 <= abs(x) < 1e5 else f"{x:.3g}".replace("e+0", "e").replace("e-0", "e-")
    return text.replace("-", "−")


def _cost(x: float) -> str:
    return f"{x:.2g}".replace("e+0", "e").replace("e+", "e")


def table(folder: pathlib.Path = BENCHMARKS / "results") -> str:
    """The estimator-study table of docs/fitting.md: one block of rows per study in
    `STUDIES`, its reference first; each gradient component is a column group
    (d loss / d log p)."""
    lines = ["| case | estimator | B | d loss / d log | estimates | bias against the reference (± s.e. of the mean) | "
             "particle-steps per gradient | seconds per gradient |", "|---|---|---|---|---|---|---|---|"]
    for file in STUDIES:
        path = folder / file
        if not path.exists():
            continue
        out = json.loads(path.read_text())
        if "summary" not in out:  # a study still running (its rows so far are saved for --resume)
            continue
        case = out.get("case", "box")
        names = out.get("names", ["mu"])
        where = ", ".join(f"{n} = {v:g}" for n, v in out.get("point", {"mu": out.get("mu")}).items())
        disks = out.get("options", {}).get("n", out.get("n"))
        label = f"{case}, {disks:g} disks ({where})" + ("" if out.get("complete", True) else ", in progress")
        for which, title in (("reference", "reference: central differences"),
                             ("reference_profile", "reference, the profile's terms: central differences")):
            ref = out.get(which)
            for i, n in enumerate(names if ref else []):
                g, e = np.atleast_1d(ref["gradient"])[i], np.atleast_1d(ref["stderr"])[i]
                lines.append(f"| {label} | {title}, h = {out['step']:g} | {ref['B']} | {n} | "
                             f"{_fmt(g)} ± {_fmt(e)} | — | {_cost(ref['particle_steps'])} | — |")
        for key, s in out["summary"].items():
            estimator, size = key.split("/B")
            what = (f"central differences, h = {out['step']:g}" if estimator == "fd" else
                    (f"truncated pathwise, mean over windows of {estimator.split(':')[1]} steps, the profile's terms "
                     f"(one construction carrying {len(names)} tangents)")
                    if estimator.startswith("truncated") else
                    f"antithetic smoothing, sigma = {out.get('sigma', out['step']):g}, {out['pairs']} pairs")
            mine = _rows_of(out, key)
            for i, n in enumerate(names):
                estimates = ", ".join(_fmt(_gradient(r)[i]) for r in mine)
                bias = np.atleast_1d(s["bias"])[i]
                # the mean's s.e.: the larger of the repeats' spread / sqrt(R) and the estimates' own s.e.
                # (jackknife, or over 2 pairs) combined: with two repeats neither alone is a measure of it
                own = np.array([np.atleast_1d(np.asarray(r["stderr"], float))[i] for r in mine])
                parts = [] if s["bias_stderr"] is None else [np.atleast_1d(s["bias_stderr"])[i]]
                if np.all(np.isfinite(own)):
                    parts.append(math.sqrt(np.sum(own ** 2)) / len(own))
                be = max(parts) if parts else None
                bias_text = _fmt(bias) + ("" if be is None else f" ± {_fmt(be)}")
                if estimator == "fd":  # the reference pools these rows' members: 0 by construction
                    bias_text = "— (pooled into the reference)"
                seconds = np.mean([r["seconds"] for r in mine])
                lines.append(f"| {label} | {what} | {size} | {n} | {estimates} | {bias_text} | "
                             f"{_cost(s['particle_steps_per_gradient'])} | {seconds:.0f} |")
    return "\n".join(lines) + "\n"


def rewrite_page(check: bool = False) -> bool:
    """Writes `table()` between its markers in docs/fitting.md (with `check`: only compares)."""
    import docs_block

    return docs_block.rewrite(START, END, table(), check=check, page=docs_block.DOCS / "fitting.md")


def _rows_of(out: dict, key: str) -> list:
    """The rows of one `estimator/B` summary key."""
    return [r for r in out["rows"] if f"{r['estimator']}/B{r['B']}" == key]


def _spread(summary: dict, rows: list) -> np.ndarray:
    """The spread over repeats, or (one repeat) that row's own standard error."""
    if summary["spread"] is not None:
        return np.atleast_1d(np.asarray(summary["spread"], dtype=float))
    return np.atleast_1d(np.asarray(rows[0]["stderr"], dtype=float))


def figure(out: dict, path: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = out.get("names", ["mu"])
    fig, axes = plt.subplots(1, len(names) + 1, figsize=(5 * (len(names) + 1), 4))
    ref = out["reference"]
    keys = list(out["summary"])
    for i, n in enumerate(names):
        a = axes[i]
        g, e = np.atleast_1d(ref["gradient"])[i], np.atleast_1d(ref["stderr"])[i]
        a.axhspan(g - e, g + e, color="0.85", label=f"reference: FD over {ref['B']} piles")
        if "reference_profile" in out:
            gp = np.atleast_1d(out["reference_profile"]["gradient"])[i]
            a.axhline(gp, color="0.4", ls="--", lw=1, label="reference, the profile's terms (truncated rows)")
        for k, key in enumerate(keys):
            s = out["summary"][key]
            mine = _rows_of(out, key)
            a.plot([k] * len(mine), [_gradient(r)[i] for r in mine], "o", color=f"C{k}", alpha=0.5)
            a.errorbar(k + 0.15, np.atleast_1d(s["mean"])[i], _spread(s, mine)[i], fmt="s", color=f"C{k}", capsize=3)
        scale = abs(g) + 3 * e  # an estimate far beyond it (one heap's window exploding) would flatten the rest
        if max(abs(_gradient(r)[i]) for r in out["rows"]) > 20 * scale:
            a.set_yscale("symlog", linthresh=scale)
        a.set_xticks(range(len(keys)), keys, fontsize=8, rotation=20)
        a.set_ylabel(f"dL / d log {n}")
        a.set_title(f"{out.get('case', 'box')}: estimates (each repeat) and their spread", fontsize=9)
        a.legend(fontsize=8)
    b = axes[-1]
    spreads = []
    for k, key in enumerate(keys):
        s = out["summary"][key]
        spread = float(np.linalg.norm(_spread(s, _rows_of(out, key))))
        b.plot(s["particle_steps_per_gradient"], spread, "o", color=f"C{k}", label=key)
        spreads.append(spread)
    b.set_xscale("log")
    if min(spreads) > 0 and max(spreads) > 100 * min(spreads):
        b.set_yscale("log")
    b.set_xlabel("particle-steps per gradient")
    b.set_ylabel("spread of the estimate (norm over components;\none repeat: its standard error)")
    b.set_title("cost against spread")
    b.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


if __name__ == "__main__":
    main()
