"""Beverloo's law from the hopper protocol: the flow rate Q against the orifice
D, over seeds, and the fitted C and k of Q = C n_A sqrt(g) (D - k d)^(3/2)
(`jaxpile.protocols.hopper`; Beverloo, Leniger & van de Velde 1961).

Each (D, seed) silo is one run; its numbers are written to the results JSON as
soon as it ends, so a rerun skips the silos already done. A silo that clogged
(an arch over the orifice, `clogged`) is counted per D; its rate is the steady
flow before the arch, kept when at least `MIN_OUT` disks came out. C and k are
fitted on the mean rates, and their spread is the jackknife over seeds.

    python benchmarks/studies/papers/hopper_beverloo.py [--orifices 4,5,6,7,8,10] [--seeds 4] [--n 800] [--width 30]
        [--mu 0.5] [--out benchmarks/results/hopper/beverloo.json] [--figure docs/hopper_beverloo.png]
"""

from __future__ import annotations

import argparse
import json
import math
import os
import pathlib
import sys
import time

sys.path.insert(0, str(pathlib.Path(__file__).parent))
from baxter_readings import mean_stderr  # noqa: E402  (one definition of mean +- s.e.)

ROOT = pathlib.Path(__file__).resolve().parents[3]  # the repository
MIN_OUT = 100
"""Disks out for a silo's rate to count (the 10-60 % window then holds 50)."""
KEYS = ("flow_rate", "beverloo_c", "discharged", "remaining", "clogged", "number_density", "opened_step",
        "stopped_step", "steps", "wall_seconds")


def one_silo(orifice: float, seed: int, args) -> dict:
    from jaxpile.protocols import hopper

    state, m = hopper.SPEC.run("hooke", args.n, params={"mu": args.mu}, width=args.width, orifice=orifice, seed=seed)
    return {"orifice": orifice, "seed": seed, **{k: m[k] for k in KEYS}}


def _counts(run: dict) -> bool:
    rate = run["flow_rate"]
    return run["discharged"] >= MIN_OUT and rate is not None and math.isfinite(rate)


def summarise(runs: list[dict], orifices: list[float], seeds: list[int]) -> dict:
    """Mean +- s.e. of Q per D (clogged runs left out), n_A over all runs, and
    C, k fitted on the means with their jackknife spread over seeds."""
    import numpy as np

    from jaxpile.protocols import hopper

    table, density = [], mean_stderr([r["number_density"] for r in runs])
    for d in orifices:
        at = [r for r in runs if r["orifice"] == d]
        flowing = [r["flow_rate"] for r in at if _counts(r)]
        table.append({"orifice": d, "runs": len(at), "clogged": sum(r["clogged"] for r in at),
                      **{f"flow_rate_{k}": v for k, v in mean_stderr(flowing).items()}})

    def fit(rows_runs):
        d, q = [], []
        for o in orifices:
            rates = [r["flow_rate"] for r in rows_runs if r["orifice"] == o and _counts(r)]
            if rates:
                d.append(o)
                q.append(float(np.mean(rates)))
        n_a = float(np.mean([r["number_density"] for r in rows_runs]))
        return hopper.beverloo_fit(d, q, n_a) if len(d) >= 2 else None

    whole = fit(runs)
    leave_one = [f for f in (fit([r for r in runs if r["seed"] != s]) for s in seeds) if f]
    spread = {}
    if len(leave_one) >= 2:
        for key in ("c", "k"):
            values = np.asarray([f[key] for f in leave_one])
            spread[f"{key}_stderr"] = float(math.sqrt((len(values) - 1) / len(values)
                                                      * np.sum((values - values.mean()) ** 2)))
    return {"table": table, "number_density": density, "beverloo": whole, "jackknife": spread}


def figure(result: dict, path: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    rows = [r for r in result["table"] if r["flow_rate_mean"] is not None]
    d = np.asarray([r["orifice"] for r in rows])
    q = np.asarray([r["flow_rate_mean"] for r in rows])
    e = np.asarray([r["flow_rate_stderr"] or 0.0 for r in rows])
    fig, (left, right) = plt.subplots(1, 2, figsize=(10, 4))
    left.errorbar(d, q, yerr=e, fmt="o", label="hopper, mean +- s.e. over seeds")
    fit, n_a = result["beverloo"], result["number_density"]["mean"]
    if fit:
        grid = np.linspace(max(fit["k"], d.min() - 1), d.max() + 0.5, 100)
        curve = fit["c"] * n_a * np.clip(grid - fit["k"], 0, None) ** 1.5
        left.plot(grid, curve, label=f"Beverloo: C = {fit['c']:.2f}, k = {fit['k']:.2f}")
        right.plot(grid, curve ** (2 / 3), color="C1")
    right.errorbar(d, q ** (2 / 3), yerr=(2 / 3) * q ** (-1 / 3) * e, fmt="o")
    left.set(xlabel="orifice D (diameters)", ylabel="flow rate Q (disks per sqrt(d/g))")
    right.set(xlabel="orifice D (diameters)", ylabel="Q^(2/3): a line whose root is k")
    left.legend()
    for ax in (left, right):
        ax.grid(alpha=0.3)
    fig.suptitle(f"hopper: {result['setting']['n']} disks, W = {result['setting']['width']:g}, hooke mu = "
                 f"{result['setting']['mu']:g}, {len(result['setting']['seeds'])} seeds per orifice")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--orifices", default="4,5,6,7,8,10")
    parser.add_argument("--seeds", type=int, default=4)
    parser.add_argument("--n", type=int, default=800)
    parser.add_argument("--width", type=float, default=30.0)
    parser.add_argument("--mu", type=float, default=0.5)
    parser.add_argument("--out", default=str(ROOT / "benchmarks/results/hopper/beverloo.json"))
    parser.add_argument("--figure", default=str(ROOT / "docs/hopper_beverloo.png"))
    args = parser.parse_args(argv)
    import jaxpile

    jaxpile.configure()  # float64 and the commands' XLA settings
    orifices = [float(x) for x in args.orifices.split(",")]
    seeds = list(range(args.seeds))
    setting = {"n": args.n, "width": args.width, "mu": args.mu, "orifices": orifices, "seeds": seeds,
               "law": "hooke", "command": "python benchmarks/studies/papers/hopper_beverloo.py " + " ".join(argv or sys.argv[1:])}
    old = json.loads(pathlib.Path(args.out).read_text()) if os.path.exists(args.out) else {}
    same = {k: v for k, v in old.get("setting", {}).items() if k != "command"} == \
        {k: v for k, v in setting.items() if k != "command"}
    runs = old.get("runs", []) if old and {k: old["setting"][k] for k in ("n", "width", "mu")} == \
        {k: setting[k] for k in ("n", "width", "mu")} else []
    if old and not same:
        print(f"{args.out}: other orifices or seeds; keeping its {len(runs)} silos of the same n, W, mu")
    os.makedirs(os.path.dirname(args.out), exist_ok=True)
    for d in orifices:
        for seed in seeds:
            if any(r["orifice"] == d and r["seed"] == seed for r in runs):
                continue
            t0 = time.perf_counter()
            runs.append(one_silo(d, seed, args))
            r = runs[-1]
            print(f"D = {d:g} seed {seed}: Q = {r['flow_rate']:.3f} disks/time, {r['discharged']} out, "
                  f"clogged {r['clogged']}, {time.perf_counter() - t0:.0f} s", flush=True)
            pathlib.Path(args.out).write_text(json.dumps({"setting": setting, "runs": runs}, indent=1,
                                                         default=lambda x: None))
    runs = [r for r in runs if r["orifice"] in orifices and r["seed"] in seeds]
    result = {"setting": setting, **summarise(runs, orifices, seeds), "runs": runs}
    text = json.dumps(result, indent=1, default=lambda x: None).replace("NaN", "null")
    pathlib.Path(args.out).write_text(text)
    for row in result["table"]:
        print(f"D = {row['orifice']:g}: Q = {row['flow_rate_mean']} +- {row['flow_rate_stderr']} "
              f"({row['flow_rate_count']} of {row['runs']} with >= {MIN_OUT} out; {row['clogged']} clogged)")
    print(f"n_A = {result['number_density']}; Beverloo fit {result['beverloo']} jackknife {result['jackknife']}")
    if args.figure:
        figure(result, args.figure)
        print(f"figure: {args.figure}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
