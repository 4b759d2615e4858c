"""Recovery of known law parameters from ensemble targets (issue 17, item 4).

Each case makes a target with jaxpile itself at parameters that are not round
numbers, from seeds the fit never sees (10000 + b), then fits from a start at
least 30 % away with `jaxpile.fit.ensemble_fit` (central differences with common
random numbers, Gauss-Newton), and reports the recovered value, its 95 %
interval and whether the truth is inside. Sizes are chosen to run in under an
hour on 2 CPU cores each.

    python benchmarks/studies/fitting/fit_recovery.py box          # Lee-Herrmann box piles: mu
    python benchmarks/studies/fitting/fit_recovery.py lattice      # Liffman lattice: K_s and mu_roll together
    python benchmarks/studies/fitting/fit_recovery.py lattice-ks   # Liffman lattice: K_s alone
    python benchmarks/studies/fitting/fit_recovery.py pour         # Baxter heap: n
    python benchmarks/studies/fitting/fit_recovery.py hopper       # a silo's flow rate: mu
    python benchmarks/studies/fitting/fit_recovery.py drop         # Liffman dropped pile (1992 Fig. 20): mu_roll
    python benchmarks/studies/fitting/fit_recovery.py pour-rolling # Baxter heap with rolling resistance (sds): mu_roll
    python benchmarks/studies/fitting/fit_recovery.py --table      # docs/fitting.md's recovery table from the JSON

Writes benchmarks/results/fit_recovery/CASE.json (with the command), the
fit's history as CASE_checkpoint.json while it runs (a rerun resumes; not
committed), and its figure CASE.png beside the JSON (the docs draw the cases
they show with `--figure docs/fit_recovery_CASE.png`).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))  # benchmarks/studies/fitting
BENCHMARKS = os.path.dirname(os.path.dirname(HERE))
ROOT = os.path.dirname(BENCHMARKS)
sys.path.insert(0, ROOT)
sys.path.insert(1, BENCHMARKS)  # docs_block, machine

CASES = {
    # 102-disk boxes (W = H = 2 cm): theta_R moves by ~30 deg per unit log mu, one pile scatters by ~5 deg
    "box": dict(protocol="box", law="lee-herrmann", options={"width": 2.0, "height": 2.0},
                truth={"mu": 0.273}, start={"mu": 0.19},
                statistics=dict(columns=("repose_least_squares", "repose_cumulative_parabola"))),
    # the 1992 lattice (deterministic: one pile): base profile (normal + horizontal) and the pile's height.
    # A static pile's base forces are set by statics (eqs. 42-44 hold for any K_s); K_s shows in the
    # height (the contacts' compression), mu_roll (a force on rolling, eq. 29) in neither: measured here
    "lattice": dict(protocol="lattice", law="liffman", options={"layers": 10, "ramp_steps": 5000},
                    truth={"ks": 13_700.0, "mu_roll": 0.137}, start={"ks": 9_000.0, "mu_roll": 0.09},
                    statistics=dict(columns=("height",), bins=10), seeds=1),
    "lattice-ks": dict(protocol="lattice", law="liffman", options={"layers": 10, "ramp_steps": 5000},
                       truth={"ks": 13_700.0}, start={"ks": 9_000.0},
                       statistics=dict(columns=("height",), bins=10), seeds=1),
    # 40-disk Baxter heaps: the angles and the base profile (normal + horizontal) against n; 16 heaps a side
    # (one pile's statistics move by ~7 spreads per unit log n, measured: n = 28 -> 41.3)
    # A pour is chaotic: a heap at n +- 5 % is another heap, so common random numbers do not cancel its
    # noise and the central difference needs a wide step (h = 0.2 in log n) to see the mean move
    "pour": dict(protocol="pour", law="baxter", options={"n": 40}, truth={"n": 41.3}, start={"n": 28.0},
                 statistics=dict(columns=("repose_mean", "angle_height_base"), bins=9), seeds=16, step=0.2),
    # the hopper (the protocol added in one module, issue 18): 200-disk silos against the disk friction.
    # The flow rate alone hardly tells mu (Beverloo's law has no mu; measured: 11.05 at mu 0.28 against
    # 10.61 at 0.41, and the first gradient of a flow-rate-only fit was 0.32 +- 0.37, not significant),
    # so the disks left in the dead zones beside the orifice (their slope is an angle of repose) ride
    # along; a discharge is chaotic, so the central difference takes the pour's wide step
    "hopper": dict(protocol="hopper", law="hooke", options={"n": 200, "width": 16.0, "orifice": 6.0},
                   truth={"mu": 0.41}, start={"mu": 0.28}, statistics=dict(columns=("flow_rate", "remaining")),
                   seeds=16, step=0.2),
    # the 1992 dropped pile (Fig. 20), Liffman law: rolling friction (eq. 29) acts while disks roll and slide
    # into place, so where a lattice at rest cannot tell mu_roll, a dropped pile's spread shows it (measured,
    # 60 disks, 8 a side: base width 31.1 +- 1.1, 24.6 +- 0.6, 20.7 +- 0.9 at mu_roll 0.09, 0.137, 0.2);
    # K_s is held at the paper's (the lattice case recovers it: a random pile's compression is lost in its
    # scatter). Chaotic like the pour: the wide step
    "drop": dict(protocol="drop", law="liffman", options={"n": 40, "speed_tolerance": 1e-4},
                 truth={"mu_roll": 0.137}, start={"mu_roll": 0.09},
                 statistics=dict(columns=("base_width", "base_contacts", "height")), seeds=16, step=0.2),
    # 100-disk Baxter heaps with LAMMPS's rolling spring-dashpot-slider (docs/rolling_resistance.md): the
    # rolling friction mu_roll raises the angle (300 disks: 23.9, 29.9, 39.1 deg at mu_roll 0, 0.1, 0.3),
    # the lever of a fit to Smid and Novosad's 32.6 deg. Chaotic like the pour: the wide step
    "pour-rolling": dict(protocol="pour", law="baxter", options={"n": 100}, truth={"mu_roll": 0.173},
                         start={"mu_roll": 0.11}, params={"k_roll": 1000.0, "gamma_roll": 30.0},
                         law_options={"rolling": "sds"}, rotation=True,
                         statistics=dict(columns=("repose_mean", "angle_height_base")), seeds=16, step=0.2),
}


START, END = "<!-- fit-recovery:start -->\n", "<!-- fit-recovery:end -->"

MORE_RUNS = ("gpu_h200/box-paper", "gpu_h200/pour-64", "hopper_32/hopper")
"""Runs kept in folders of their own (larger ensembles, a GPU), in the table
after the cases: FOLDER/CASE.json is named by its folder, any other by its file."""


def table(folder: str = os.path.join(BENCHMARKS, "results", "fit_recovery")) -> str:
    """The recovery table of docs/fitting.md, from the cases' result JSON (a case not run yet is left out)."""
    lines = ["| case | fitted | truth | start | recovered | 95 % interval | truth inside | piles a side | "
             "sensitivity | cost | through all ensembles (95 %) |", "|---|---|---|---|---|---|---|---|---|---|---|"]
    runs = [(case, os.path.join(folder, f"{case}.json")) for case in CASES]
    runs += [(os.path.dirname(run) if os.path.basename(run) in CASES else os.path.basename(run),
              os.path.join(folder, f"{run}.json")) for run in MORE_RUNS]
    for name, path in runs:
        if not os.path.exists(path):
            continue
        with open(path) as fh:
            r = json.load(fh)
        case = r["command"].split()[2]  # python benchmarks/studies/fitting/fit_recovery.py CASE ...
        what = CASES[case]
        options = r.get("options", what["options"])
        setting = f"{name}: {what['protocol']}, {what['law']}, " + ", ".join(f"{k} {v}" for k, v in options.items())
        if " gpu " in r.get("machine", ""):
            setting += f" (GPU: {r['machine'].split(' gpu x1 ')[-1]})"
        line = _regression(r)
        for param in r["names"]:
            lo, hi = r["interval"][param]
            err = 100 * r["relative_error"][param]
            err = f"{err:+.1f} %" if abs(err) >= 0.05 else f"{err:+.1e} %"
            d = 5 if hi - lo > 1e-4 * abs(r["values"][param]) else 10  # a deterministic pile's interval is narrow
            lines.append(
                f"| {setting} | {param} | {r['truth'][param]:.5g} | {r['start'][param]:.5g} | "
                f"{r['values'][param]:.{d}g} ({err}) | {lo:.{d}g} – {hi:.{d}g} | "
                f"{'yes' if r['truth_inside_interval'][param] else 'no'} | {r['ensemble']} | "
                f"{r['sensitivity'][param]:.2g} | {len(r['history'])} iterations"
                f"{'' if r.get('converged', True) else ' (not converged)'}, {r['particle_steps']:.2g} "
                f"particle-steps, {(r['wall_seconds'] + r.get('earlier_runs_seconds', 0)) / 60:.0f} min | "
                f"{_through_all(line, param, r['truth'][param])} |")
    return "\n".join(lines) + "\n"


def _through_all(line: dict | None, param: str, truth: float) -> str:
    """The regression's cell: value (interval), whether the truth is in it."""
    if line is None:
        return "—"
    lo, hi = line["interval"][param]
    if not hi < 100 * lo:  # an interval over two decades: the statistics do not determine it
        return "not determined"
    return f"{line['values'][param]:.4g} ({lo:.4g} – {hi:.4g}), truth {'in' if lo <= truth <= hi else 'out'}"


def _regression(record: dict) -> dict | None:
    """The fit's estimate through all its ensembles (`jaxpile.fit.regression`):
    recorded by fits since d937926, computed from the history for older ones."""
    if "regression" in record:
        return record["regression"]
    from jaxpile.fit import regression
    from jaxpile.fit.ensemble_fit import EnsembleFitResult

    estimate = regression.estimate(EnsembleFitResult.from_json(record))
    return None if estimate is None else estimate.to_json()


def rewrite_page(check: bool = False) -> bool:
    """Writes `table()` between its markers in docs/fitting.md (with `check`: only compares)."""
    import docs_block

    return docs_block.rewrite(START, END, table(), check=check, page=docs_block.DOCS / "fitting.md")


def _options(pairs) -> dict:
    """`--option KEY=VALUE` overrides: a VALUE that reads as a number is one."""
    options = {}
    for pair in pairs:
        key, sep, value = pair.partition("=")
        if not sep or not key:
            raise SystemExit(f"--option takes KEY=VALUE, got {pair!r}")
        try:
            options[key] = int(value)
        except ValueError:
            try:
                options[key] = float(value)
            except ValueError:
                options[key] = value
    return options


def _machine() -> str:
    """The processor and JAX device the fit ran on (for the table)."""
    sys.path.insert(0, BENCHMARKS)
    from machine import describe

    return describe()


def main(argv=None) -> dict:
    if argv is None:
        argv = sys.argv[1:]
    if argv and argv[0] == "--table":
        rewrite_page()
        print(table())
        return {}
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("case", choices=sorted(CASES))
    parser.add_argument("--ensemble", type=int, default=None, help="piles per ensemble (default: the case's, 32)")
    parser.add_argument("--steps", type=int, default=6, help="Gauss-Newton iterations at most")
    parser.add_argument("--out", default=os.path.join(BENCHMARKS, "results", "fit_recovery"))
    parser.add_argument("--figure", default=None, help="default OUT/CASE.png")
    parser.add_argument("--option", action="append", default=[], metavar="KEY=VALUE",
                        help="override one of the case's protocol options (e.g. width=4 for the paper's box; "
                             "numbers are read as numbers), repeatable")
    args = parser.parse_args(argv)

    import numpy as np

    import jaxpile

    jaxpile.configure(threads=True)  # float64, XLA's settings and its threads: batches, as `jaxpile fit` runs an ensemble fit

    from jaxpile.fit import ensemble_fit as ef

    case = CASES[args.case]
    b = args.ensemble or case.get("seeds", 32)
    options = {**case["options"], **_options(args.option)}
    os.makedirs(args.out, exist_ok=True)
    runner = ef.Runner(case["protocol"], case["law"], options=options, params=case.get("params"),
                       law_options=case.get("law_options"), rotation=case.get("rotation"))
    statistics = ef.Statistics(**case["statistics"])
    target_path = os.path.join(args.out, f"{args.case}_target.json")
    t0 = time.perf_counter()
    if os.path.exists(target_path):
        with open(target_path) as fh:
            target = ef.EnsembleTarget.from_json(json.load(fh))
    else:
        target = ef.make_target(runner, case["truth"], range(10_000, 10_000 + b), statistics, progress=False)
        with open(target_path, "w") as fh:
            json.dump(target.to_json(), fh)
    print(f"target: {dict(zip(target.labels, np.round(target.mean, 4)))} ({time.perf_counter() - t0:.0f} s)",
          flush=True)
    checkpoint = os.path.join(args.out, f"{args.case}_checkpoint.json")
    earlier = 0.0  # a resumed fit's iterations run before this process: counted in its cost
    if os.path.exists(checkpoint):
        with open(checkpoint) as fh:
            earlier = float(sum(h.get("seconds", 0.0) for h in json.load(fh).get("history", [])))
    result = ef.fit(runner, list(case["start"]), case["start"], target, seeds=range(b), statistics=statistics,
                    gradient=ef.Gradient(step=case.get("step", 0.05)), stopping=ef.Stopping(steps=args.steps),
                    saving=ef.Saving(checkpoint=checkpoint, resume=checkpoint if os.path.exists(checkpoint) else None))
    record = result.to_json()
    record["truth"] = case["truth"]
    record["relative_error"] = {n: result.values[n] / case["truth"][n] - 1 for n in result.names}
    record["truth_inside_interval"] = {n: bool(lo <= case["truth"][n] <= hi) for n, (lo, hi) in result.interval.items()}
    record["ensemble"] = b
    record["options"] = options
    record["machine"] = _machine()
    record["command"] = "python benchmarks/studies/fitting/fit_recovery.py " + " ".join(argv)
    record["wall_seconds"] = time.perf_counter() - t0
    record["earlier_runs_seconds"] = earlier
    try:  # the code that made it
        import subprocess

        record["revision"] = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=HERE, capture_output=True,
                                            text=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        record["revision"] = None
    with open(os.path.join(args.out, f"{args.case}.json"), "w") as fh:
        json.dump(record, fh, indent=1)
    figure = args.figure or os.path.join(args.out, f"{args.case}.png")
    ef.figure(result, path=figure)
    for n in result.names:
        lo, hi = result.interval[n]
        print(f"{args.case}: {n} = {result.values[n]:.5g} (truth {case['truth'][n]}, start {case['start'][n]}): "
              f"{100 * record['relative_error'][n]:+.2f} %, 95 % interval [{lo:.5g}, {hi:.5g}], truth inside: "
              f"{record['truth_inside_interval'][n]}")
        print(f"{args.case}: {n} through all ensembles: {_through_all(record.get('regression'), n, case['truth'][n])}")
    print(f"wrote {args.out}/{args.case}.json and {figure} ({record['wall_seconds']:.0f} s)")
    if args.out == os.path.join(BENCHMARKS, "results", "fit_recovery"):
        rewrite_page()
    return record


if __name__ == "__main__":
    main()
