"""The rolling-resistance ensembles' table and figures, from the sweeps that made them.

    python benchmarks/studies/papers/rolling_results.py [FOLDER]

reads FOLDER/box_mu_roll.csv (the 1993 box's angle of repose against mu_roll) and
FOLDER/drop_dip_grid.csv (the dropped pile's central dip over (mu, mu_roll)), written by
`benchmarks/studies/papers/gpu_rolling.sh` (`jaxpile sweep` rows), and writes
FOLDER/rolling_summary.json (mean, standard error and count per point) and
FOLDER/rolling.png. FOLDER defaults to benchmarks/results/rolling/gpu_h200.

    python benchmarks/studies/papers/rolling_results.py --pour benchmarks/results/rolling/cpu_pour

summarises a pour sweep over mu_roll instead (its sweep.csv, from `jaxpile sweep --protocol pour
... --vary mu_roll=...`; the command is in its sweep.json) into pour_summary.json beside it.
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import pathlib
from collections import defaultdict

import numpy as np

HERE = pathlib.Path(__file__).resolve()
DEFAULT = HERE.parents[3] / "benchmarks" / "results" / "rolling" / "gpu_h200"


def _number(text: str) -> float:
    try:
        return float(text)
    except ValueError:
        return math.nan


def summarise(rows: list[dict], by: tuple, columns: tuple) -> list[dict]:
    """Mean, standard error, count and unmeasurable count of each column at each point of `by`."""
    groups = defaultdict(list)
    for row in rows:
        groups[tuple(_number(row[k]) for k in by)].append(row)
    out = []
    for point in sorted(groups):
        entry = dict(zip(by, point))
        for column in columns:
            values = np.array([_number(r[column]) for r in groups[point]])
            ok = values[np.isfinite(values)]
            entry[column] = {"mean": float(ok.mean()) if ok.size else math.nan,
                             "stderr": float(ok.std(ddof=1) / math.sqrt(ok.size)) if ok.size > 1 else math.nan,
                             "count": int(ok.size), "missing": int(values.size - ok.size)}
        out.append(entry)
    return out


POUR_COLUMNS = ("repose_mean", "central_dip", "flank_over_centre", "m_ratio", "height", "base_width")
"""What a poured heap's row says about its shape: the angle, the dip and the M (`measure.poured_heap`)."""


def pour_summary(folder: pathlib.Path) -> dict:
    """mean +- s.e. of `POUR_COLUMNS` and the count of M-shaped heaps at each mu_roll of FOLDER/sweep.csv."""
    rows = list(csv.DictReader(open(folder / "sweep.csv")))
    record = json.load(open(folder / "sweep.json"))
    points = summarise(rows, ("mu_roll",), POUR_COLUMNS)
    for p in points:
        p["m_shaped"] = sum(r["m_shaped"] == "True" for r in rows if _number(r["mu_roll"]) == p["mu_roll"])
    command = record.get("argv") or (folder / "command.txt").read_text().split()
    summary = {"how": "jaxpile " + " ".join(command[1:] if command[:1] == ["jaxpile"] else command)
                      + ", summarised by benchmarks/studies/papers/rolling_results.py --pour",
               "law": record["law"], "params": record["params"], "law_options": record.get("law_options"),
               "options": record["options"], "points": points}
    (folder / "pour_summary.json").write_text(json.dumps(summary, indent=1) + "\n")
    for p in points:
        cells = ", ".join(f"{c} {p[c]['mean']:+.3f} +- {p[c]['stderr']:.3f}" for c in POUR_COLUMNS)
        print(f"pour mu_roll = {p['mu_roll']:g} ({p['repose_mean']['count']} heaps, {p['m_shaped']} M-shaped): {cells}")
    return summary


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("folder", nargs="?", default=str(DEFAULT))
    parser.add_argument("--pour", default=None, help="a pour sweep's folder to summarise instead")
    args = parser.parse_args(argv)
    if args.pour is not None:
        pour_summary(pathlib.Path(args.pour))
        return
    folder = pathlib.Path(args.folder)
    box = list(csv.DictReader(open(folder / "box_mu_roll.csv")))
    drop = list(csv.DictReader(open(folder / "drop_dip_grid.csv")))
    summary = {
        "how": "benchmarks/studies/papers/gpu_rolling.sh on one H200 (jaxpile sweep, hooke, spins on, rolling sds "
               "k_roll = 1000, gamma_roll = 30), summarised by benchmarks/studies/papers/rolling_results.py",
        "box": {"setting": json.load(open(folder / "box_mu_roll.json"))["options"] or "the paper's W = H = 4 box",
                "points": summarise(box, ("mu_roll",), ("repose_cumulative_parabola", "repose_least_squares"))},
        "drop": {"points": summarise(drop, ("mu", "mu_roll"),
                                     ("central_dip", "repose_angle_left", "repose_angle_right", "height"))},
    }
    (folder / "rolling_summary.json").write_text(json.dumps(summary, indent=1) + "\n")

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (a, b) = plt.subplots(1, 2, figsize=(10, 4))
    points = summary["box"]["points"]
    x = [p["mu_roll"] for p in points]
    y = [p["repose_cumulative_parabola"] for p in points]
    a.errorbar(x, [v["mean"] for v in y], [v["stderr"] for v in y], marker="o", capsize=3)
    a.set(xlabel="mu_roll", ylabel="theta_R, method 3 (deg)", title="1993 box (409 disks, mu = 0.2): 16 piles a point")
    for mu in sorted({p["mu"] for p in summary["drop"]["points"]}):
        sel = [p for p in summary["drop"]["points"] if p["mu"] == mu]
        b.errorbar([p["mu_roll"] for p in sel], [p["central_dip"]["mean"] for p in sel],
                   [p["central_dip"]["stderr"] for p in sel], marker="o", capsize=3, label=f"mu = {mu:g}")
    b.axhspan(0.2, 0.3, color="0.85", label="Smid & Novosad's dip (20-30 %)")
    b.axhline(0.0, color="0.5", lw=0.8)
    b.set(xlabel="mu_roll", ylabel="central dip (1 - centre / lower flank maximum)",
          title="1992 drop (300 disks): 16 piles a point")
    b.legend()
    fig.tight_layout()
    fig.savefig(folder / "rolling.png", dpi=120)
    for p in summary["drop"]["points"]:
        d = p["central_dip"]
        print(f"drop mu = {p['mu']:g}, mu_roll = {p['mu_roll']:g}: dip {d['mean']:+.3f} +- {d['stderr']:.3f} "
              f"({d['count']} piles)")
    for p in points:
        r = p["repose_cumulative_parabola"]
        print(f"box mu_roll = {p['mu_roll']:g}: theta_R {r['mean']:.2f} +- {r['stderr']:.2f} deg "
              f"({r['count']} piles, {r['missing']} unmeasurable)")


if __name__ == "__main__":
    main()
