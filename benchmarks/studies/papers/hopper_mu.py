"""What in a silo's discharge sees the disk friction mu (issue 17: the hopper
recovery that missed). Every silo of the hopper protocol at each mu, one
batched sweep; per mu the mean +- s.e. over seeds of the flow rate, the disks
left in the dead zones and the dead zones' angle (`hopper.dead_zone_angles`),
and each statistic's sensitivity: its change per unit log mu over one silo's
spread, between neighbouring mu (what a fit of mu can use).

    python benchmarks/studies/papers/hopper_mu.py [--mu 0.05,0.1,0.2,0.41,0.8] [--seeds 8] [--n 200] [--width 16]
        [--orifice 6] [--out benchmarks/results/hopper/mu_sensitivity.json] [--figure docs/hopper_mu.png]
"""

from __future__ import annotations

import argparse
import json
import math
import pathlib
import sys
import time

sys.path.insert(0, str(pathlib.Path(__file__).parent))
from baxter_readings import mean_stderr  # noqa: E402  (one definition of mean +- s.e.)

ROOT = pathlib.Path(__file__).resolve().parents[3]  # the repository
STATISTICS = ("flow_rate", "remaining", "dead_zone_angle")


def stats(values) -> dict:
    """`mean_stderr` and the one-silo spread (the standard deviation)."""
    m = mean_stderr(values)
    return {**m, "spread": None if m["stderr"] is None else m["stderr"] * math.sqrt(m["count"])}


def sensitivity(table: list[dict], key: str) -> list[float | None]:
    """Between neighbouring mu: |change of the mean| per unit log mu over the
    pooled one-silo spread (how many spreads a unit of log mu moves it)."""
    out = []
    for a, b in zip(table, table[1:]):
        sa, sb = a[key]["spread"], b[key]["spread"]
        if a[key]["mean"] is None or b[key]["mean"] is None or not sa or not sb:
            out.append(None)
            continue
        slope = (b[key]["mean"] - a[key]["mean"]) / math.log(b["mu"] / a["mu"])
        out.append(abs(slope) / math.sqrt(0.5 * (sa**2 + sb**2)))
    return out


def figure(result: dict, path: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    table = result["table"]
    mu = [row["mu"] for row in table]
    fig, axes = plt.subplots(1, len(STATISTICS), figsize=(4 * len(STATISTICS), 3.6))
    for ax, key in zip(axes, STATISTICS):
        ax.errorbar(mu, [row[key]["mean"] for row in table], yerr=[row[key]["stderr"] or 0 for row in table],
                    fmt="o-", capsize=3, label="mean +- s.e.")
        ax.set(xscale="log", xlabel="mu (hooke)", title=key.replace("_", " "))
        ax.set_xticks(mu, [f"{m:g}" for m in mu])
        ax.minorticks_off()
        ax.grid(alpha=0.3)
    s = result["setting"]
    fig.suptitle(f"hopper: {s['n']} disks, W = {s['width']:g}, D = {s['orifice']:g}, {len(s['seeds'])} silos per mu")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--mu", default="0.05,0.1,0.2,0.41,0.8")
    parser.add_argument("--seeds", type=int, default=8)
    parser.add_argument("--n", type=int, default=200)
    parser.add_argument("--width", type=float, default=16.0)
    parser.add_argument("--orifice", type=float, default=6.0)
    parser.add_argument("--out", default=str(ROOT / "benchmarks/results/hopper/mu_sensitivity.json"))
    parser.add_argument("--figure", default=str(ROOT / "docs/hopper_mu.png"))
    args = parser.parse_args(argv)

    import jaxpile

    jaxpile.configure(threads=True)  # one batch of silos: XLA's threads, as `jaxpile sweep`
    from jaxpile import sweeps

    mus = sorted(float(m) for m in args.mu.split(","))
    seeds = list(range(args.seeds))
    t0 = time.perf_counter()
    rows = sweeps.sweep("hopper", "hooke", points=[{"mu": m} for m in mus], seeds=seeds,
                       options={"n": args.n, "width": args.width, "orifice": args.orifice}, progress=False).rows
    table = []
    for mu in mus:
        at = [r for r in rows if math.isclose(r["mu"], mu)]
        table.append({"mu": mu, **{k: stats([r[k] for r in at]) for k in STATISTICS}})
    setting = {"n": args.n, "width": args.width, "orifice": args.orifice, "law": "hooke", "seeds": seeds,
               "command": "python benchmarks/studies/papers/hopper_mu.py " + " ".join(sys.argv[1:] if argv is None else argv)}
    result = {"setting": setting, "table": table,
              "sensitivity": {k: sensitivity(table, k) for k in STATISTICS},
              "rows": [{k: r[k] for k in ("mu", "seed", *STATISTICS)} for r in rows],
              "seconds": time.perf_counter() - t0}
    pathlib.Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    pathlib.Path(args.out).write_text(json.dumps(result, indent=1, default=lambda x: None).replace("NaN", "null"))
    for row in table:
        print(f"mu = {row['mu']:g}: " + "; ".join(
            f"{k} {row[k]['mean']:.3g} +- {row[k]['stderr']:.2g} (spread {row[k]['spread']:.2g})" for k in STATISTICS))
    for k, v in result["sensitivity"].items():
        print(f"{k}: spreads per unit log mu between neighbours: {[None if x is None else round(x, 2) for x in v]}")
    if args.figure:
        figure(result, args.figure)
        print(f"figure: {args.figure} ({result['seconds']:.0f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
