"""A measurement made at a known truth, fitted from the command line: does the
interval hold the truth, and does the verdict say converged?

Each case pours `--measured-heaps` heaps at the truth (seeds 10000 + b, which
the fit never sees) and writes what an experimentalist who measured them would
have: their mean base profile at 11 points across each heap's own base with its
standard error (`measurement.csv`), and their mean angle of repose with its
standard error (`measurement.toml`, which names the CSV). Then it runs

    jaxpile fit --protocol pour --target measurement.toml --params P ... --out OUT/CASE/fit

as a user would (a subprocess; rerunning the script resumes it), and records
the fitted value, its interval, whether the truth is inside, the first pass and
the verdict in benchmarks/results/calibrate/CASE.json, with the commands.

    python benchmarks/studies/calibrate/measured_recovery.py pour-mu-roll
    python benchmarks/studies/calibrate/measured_recovery.py pour-mu
    python benchmarks/studies/calibrate/measured_recovery.py pour-mu-hooke
    python benchmarks/studies/calibrate/measured_recovery.py pour-mu-no-spin
    python benchmarks/studies/calibrate/measured_recovery.py pour-profile-only   # the profile alone: mu refused?
    python benchmarks/studies/calibrate/measured_recovery.py --table   # docs/calibrate.md's table from the JSON
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))  # benchmarks/studies/calibrate
BENCHMARKS = os.path.dirname(os.path.dirname(HERE))
ROOT = os.path.dirname(BENCHMARKS)
sys.path.insert(0, ROOT)
sys.path.insert(1, BENCHMARKS)  # machine

POINTS = [i / 10 for i in range(11)]
"""Where the measured profile is read: x/B = 0, 0.1, ..., 1 of each heap's own base."""

ROLLING = {"law_options": {"rolling": "sds"}, "rotation": True, "params": {"k_roll": 1000.0, "gamma_roll": 30.0}}

CASES = {
    # rolling resistance raises the angle (docs/rolling_resistance.md): the lever a heap's angle gives mu_roll.
    # Measured by the first pass at 60 disks: with 8 piles and h = 0.2 the angle moved 3.9 +- 2.1 deg (1.9x its
    # noise, 4.2x needed for 12 statistics and 8 piles); with 16 and h = 0.4, 3.6 +- 1.3 (2.8x, 3.4x needed):
    # 32 piles a side
    "pour-mu-roll": dict(protocol="pour", law="baxter", n=60, truth={"mu_roll": 0.173}, start={"mu_roll": 0.11},
                         angle=True, ensemble=32, step=0.4, **ROLLING),
    # the disk friction of a heap without rolling resistance, from its angle and profile (16 piles, h = 0.4:
    # normal[x/B=0.3] moved 2.4x its noise, 3.4x needed)
    "pour-mu": dict(protocol="pour", law="baxter", n=60, truth={"mu": 0.37}, start={"mu": 0.55}, angle=True,
                    ensemble=32, step=0.4),
    # the same with the hooke law (LAMMPS gran/hooke/history), whose Coulomb friction sets a heap's angle
    "pour-mu-hooke": dict(protocol="pour", law="hooke", n=60, truth={"mu": 0.37}, start={"mu": 0.55}, angle=True,
                          ensemble=32, step=0.4),
    # disks that cannot roll (the hooke law without spins): the Coulomb friction is all that holds a flank.
    # Their foot loads are heavy-tailed (a few heaps in sixteen carry 2-3x the typical load at one foot):
    # measured on 32 heaps, so that the stated errors see the tail
    "pour-mu-no-spin": dict(protocol="pour", law="hooke", n=60, truth={"mu": 0.37}, start={"mu": 0.55}, angle=True,
                            ensemble=32, step=0.4, rotation=False, measured=32),
    # the profile alone against mu, at the sizes that do not tell mu_roll: what the first pass says of it
    "pour-profile-only": dict(protocol="pour", law="baxter", n=60, truth={"mu": 0.37}, start={"mu": 0.55},
                              angle=False, ensemble=8, step=0.2),
}


def measure(case: dict, heaps: int) -> tuple[dict, dict]:
    """The measured heaps' mean profile and angle with their standard errors:
    `({label: mean}, {label: stderr})`."""
    import numpy as np

    from jaxpile.fit import ensemble_fit as ef

    runner = ef.Runner(case["protocol"], case["law"], params={**case.get("params", {}), **case["truth"]},
                       options={"n": case["n"]}, law_options=case.get("law_options"), rotation=case.get("rotation"))
    statistics = ef.Statistics(columns=("repose_mean",), at=tuple(POINTS), horizontal=False, bandwidth=0.05)
    s, _ = runner.run([case["truth"]], range(10_000, 10_000 + heaps), statistics)
    piles = s[0]
    keep = np.isfinite(piles).all(axis=1)  # a heap whose flank could not be measured: left out, as a lab would
    piles = piles[keep]
    labels = statistics.labels()
    return (dict(zip(labels, piles.mean(axis=0).tolist())),
            dict(zip(labels, (piles.std(axis=0, ddof=1) / np.sqrt(len(piles))).tolist())) | {"_heaps": int(keep.sum())})


def write_measurement(folder: str, case: dict, mean: dict, stderr: dict) -> str:
    """measurement.csv (the profile, normalised by its largest point) and measurement.toml (the angle, and the CSV)."""
    normal = [mean[f"normal[x/B={u:g}]"] for u in POINTS]
    errors = [stderr[f"normal[x/B={u:g}]"] for u in POINTS]
    with open(os.path.join(folder, "measurement.csv"), "w") as fh:
        fh.write(f"# the mean of {stderr['_heaps']} heaps poured at {case['truth']} (seeds 10000+)\n")
        fh.write("x/B,normal/max,stderr\n")
        for u, v, e in zip(POINTS, normal, errors):
            fh.write(f"{u:g},{v:.6f},{e:.6f}\n")
    path = os.path.join(folder, "measurement.toml")
    with open(path, "w") as fh:
        fh.write(f'source = "{stderr["_heaps"]} heaps poured at {case["truth"]}"\nprofile = "measurement.csv"\n')
        if case["angle"]:
            fh.write(f"[scalars]\nangle_of_repose = {{ value = {mean['repose_mean']:.4f}, "
                     f"stderr = {stderr['repose_mean']:.4f} }}\n")
    return path


START, END = "<!-- measured-recovery:start -->\n", "<!-- measured-recovery:end -->"


def table(folder: str = os.path.join(BENCHMARKS, "results", "calibrate")) -> str:
    """docs/calibrate.md's table of the cases run (a case not run yet is left out)."""
    lines = ["| case | law, heap | measured (heaps) | fitted | truth | start | first pass | fitted value (95 %) | "
             "truth inside | verdict | through all ensembles (95 %) | piles a side | cost |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for case, what in CASES.items():
        path = os.path.join(folder, f"{case}.json")
        if not os.path.exists(path):
            continue
        with open(path) as fh:
            r = json.load(fh)
        (name, truth), = r["truth"].items()
        measured = ("angle + " if what["angle"] else "") + f"profile at 11 points ({r['measured_heaps']})"
        p = (r.get("first_pass") or {}).get("parameters", {}).get(name, {})
        first = (f"{p['most_moved']} {p['z']:.1f}x its noise ({p['needed']:.1f}x needed)" if p else "—")
        if r.get("value") is None:
            lines.append(f"| {case} | {what['law']}, {r['n']} disks | {measured} | {name} | {truth:g} | "
                         f"{r['start'][name]:g} | {first}: refused | — | — | — | — | {r['ensemble']} | first pass |")
            continue
        lo, hi = r["interval"]
        v = r["verdict"]
        line = r.get("regression") or {}
        through = "—" if not line else (f"{line['values'][name]:.4g} ({line['interval'][name][0]:.4g} – "
                                        f"{line['interval'][name][1]:.4g}), truth "
                                        f"{'in' if r['regression_truth_inside'] else 'out'}")
        said = f"{v['why']}, interval {'trusted' if v['interval_trusted'] else 'not trusted'}, p = {v['p_value']:.2g}"
        lines.append(f"| {case} | {what['law']}, {r['n']} disks | {measured} | {name} | {truth:g} | "
                     f"{r['start'][name]:g} | {first} | {r['value']:.4g} ({lo:.4g} – {hi:.4g}) | "
                     f"{'yes' if r['truth_inside'] else 'no'} | {said} | {through} | {r['ensemble']} | "
                     f"{r['iterations']} iterations, {r['particle_steps']:.2g} particle-steps, "
                     f"{r['fit_seconds'] / 60:.0f} min" + (" in its resumed run" if "--resume" in r["fit_command"]
                                                            else "") + " |")
    return "\n".join(lines) + "\n"


def rewrite_page(check: bool = False) -> bool:
    """Writes `table()` between its markers in docs/calibrate.md (with `check`: only compares)."""
    import docs_block

    return docs_block.rewrite(START, END, table(), check=check, page=docs_block.DOCS / "calibrate.md")


def main(argv=None) -> dict:
    argv = sys.argv[1:] if argv is None else argv
    if argv and argv[0] == "--table":
        rewrite_page()
        print(table())
        return {}
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("case", choices=sorted(CASES))
    parser.add_argument("--measured-heaps", type=int, default=None, help="default: the case's, else 16")
    parser.add_argument("--ensemble", type=int, default=None, help="piles per ensemble (default: the case's)")
    parser.add_argument("--steps", type=int, default=6)
    parser.add_argument("--difference-step", type=float, default=None,
                        help="log-parameter step (default: the case's; a poured heap is chaotic: a wide one)")
    parser.add_argument("--checkpoint-every", type=int, default=20_000)
    parser.add_argument("--out", default=os.path.join(BENCHMARKS, "results", "calibrate"))
    args = parser.parse_args(argv)
    case = CASES[args.case]
    args.ensemble = args.ensemble or case["ensemble"]
    args.measured_heaps = args.measured_heaps or case.get("measured", 16)
    args.difference_step = args.difference_step or case["step"]
    folder = os.path.join(args.out, args.case)
    os.makedirs(folder, exist_ok=True)
    t0 = time.perf_counter()
    target = os.path.join(folder, "measurement.toml")
    if not os.path.exists(target):
        import jaxpile

        jaxpile.configure(threads=True)
        mean, stderr = measure(case, args.measured_heaps)
        write_measurement(folder, case, mean, stderr)
    measured_seconds = time.perf_counter() - t0
    (name, start), = case["start"].items()
    fit_dir = os.path.join(folder, "fit")
    command = [os.path.join(os.path.dirname(sys.executable), "jaxpile"), "fit", "--protocol", case["protocol"], "--law", case["law"],
               "--target", target, "--params", name, "--set", f"{name}={start}", "--n", str(case["n"]),
               "--ensemble", str(args.ensemble), "--steps", str(args.steps), "--difference-step",
               str(args.difference_step), "--checkpoint-every", str(args.checkpoint_every), "--out", fit_dir]
    for key, value in case.get("params", {}).items():
        command += ["--set", f"{key}={value}"]
    if case.get("law_options"):
        command += ["--rolling", case["law_options"]["rolling"]]
    if case.get("rotation") is not None:
        command += ["--rotation", "on" if case["rotation"] else "off"]
    if os.path.exists(os.path.join(fit_dir, "fit_checkpoint.json")) and not os.path.exists(
            os.path.join(fit_dir, "fit.json")):
        command.append("--resume")
    print(" ".join(["jaxpile"] + command[1:]), flush=True)
    fit_json = os.path.join(fit_dir, "fit.json")
    finished = os.path.exists(fit_json)  # a finished fit is summarised again, not run again
    done = subprocess.CompletedProcess(command, 0) if finished else subprocess.run(command, cwd=ROOT)
    record = {"case": args.case, "truth": case["truth"], "start": case["start"], "n": case["n"],
              "measured_heaps": args.measured_heaps, "ensemble": args.ensemble, "returncode": done.returncode,
              "measurement_seconds": measured_seconds,
              "command": "python benchmarks/studies/calibrate/measured_recovery.py " + " ".join(argv),
              "fit_command": " ".join(["jaxpile"] + command[1:]).replace(ROOT + os.sep, "")}
    if done.returncode == 0 and os.path.exists(fit_json):
        from jaxpile.fit import verdict

        with open(fit_json) as fh:
            fit = json.load(fh)
        lo, hi = fit["interval"][name]
        line = fit.get("regression") or {}
        through = line.get("interval", {}).get(name)
        record.update(value=fit["values"][name], interval=[lo, hi], truth_inside=bool(lo <= case["truth"][name] <= hi),
                      # the verdict as the code judges the fit.json now (verdict.of_record), and as the run did
                      verdict=verdict.of_record(fit), verdict_at_run=fit["verdict"],
                      first_pass=fit["first_pass"]["report"], regression=line or None,
                      regression_truth_inside=None if through is None else bool(through[0] <= case["truth"][name]
                                                                                 <= through[1]),
                      particle_steps=fit["particle_steps"], fit_seconds=fit["fit_seconds"],
                      iterations=len(fit["history"]))
    else:
        checkpoint = os.path.join(fit_dir, "fit_checkpoint.json")
        if os.path.exists(checkpoint):
            with open(checkpoint) as fh:
                saved = json.load(fh)
            record["first_pass"] = (saved.get("first_pass") or {}).get("report")
        record["refused"] = done.returncode == 2
    sys.path.insert(0, BENCHMARKS)
    from machine import describe

    record["machine"] = describe()
    with open(os.path.join(args.out, f"{args.case}.json"), "w") as fh:
        json.dump(record, fh, indent=1)
    print(json.dumps({k: record.get(k) for k in ("case", "truth", "value", "interval", "truth_inside", "returncode")}))
    if args.out == os.path.join(BENCHMARKS, "results", "calibrate"):
        rewrite_page()
    return record


if __name__ == "__main__":
    main()
