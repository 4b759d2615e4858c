"""The 1993 angles and the 1992 dropped pile as ensembles (issue 16): each pile
one resumable job, the mean +- standard error over seeds.

- `tilt` (Lee & Herrmann 1993, Figs. 4 and 7a): for each mu, `--seeds` box
  piles (W = H = 4, the paper's 409 disks) built and tilted at the paper's rate
  until they move: theta_R of the pile (method 3), theta_T, and theta_R +
  theta_T beside theta_MS = arctan(3 mu) (eq. 3) and eq. 4's theta_T.
- `drop` (Liffman et al. 1992, Fig. 20): `--seeds` piles of 968 disks dropped
  one at a time and relaxed (the paper's own law): the mean base-force profile
  with its band, and the central dip per pile.

Each pile's result is written to `<out>/<job>.json` when it ends and its state
is saved beside it (`.npz`) every `--checkpoint-every` steps while it runs; a
rerun skips the finished piles and resumes the one in progress. Those files
are the run's workings and are not committed: `<out>/summary.json` is, with
the command, the mean +- standard error and every pile's row (`piles`), which
the papers table and its figures read (`pile_rows`). Rerunning the committed
commands costs about 0.4 h (tilt, 40 piles) and 6.7 h (drop, 8 piles) of one
CPU core.

    python benchmarks/studies/papers/paper_ensembles.py tilt [--mu 0.1,0.2,0.3,0.4,0.5] [--seeds 8] [--n 409]
    python benchmarks/studies/papers/paper_ensembles.py drop [--seeds 8] [--n 968]
        [--workers 1] [--checkpoint-every 20000] [--out benchmarks/results/...] [--figure PNG]
"""

from __future__ import annotations

import argparse
import concurrent.futures
import json
import math
import os
import pathlib
import sys
import time

sys.path.insert(0, str(pathlib.Path(__file__).parent))
from baxter_readings import mean_stderr  # noqa: E402  (one definition of mean +- s.e.)

RESULTS = pathlib.Path(__file__).resolve().parents[2] / "results"  # benchmarks/results


def _plain(value):
    """JSON-able: numbers, lists and dicts of them (NaN kept as None)."""
    import numpy as np

    if isinstance(value, dict):
        return {k: _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if isinstance(value, (np.ndarray, np.generic)) or hasattr(value, "__array__"):
        array = np.asarray(value)
        if array.ndim == 0:
            return _plain(array.item())
        if array.size > 2000:
            return None  # per-step series: not needed for the ensemble
        return _plain(array.tolist())
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, (bool, int, float, str)) or value is None:
        return value
    return None


def one_tilt(mu: float, seed: int, n: int, out: str, every: int) -> dict:
    import jaxpile
    jaxpile.configure()  # float64 and the commands' XLA settings
    from jaxpile.protocols import tilt

    state_file = out.replace(".json", ".npz")
    resume = state_file if os.path.exists(state_file) else None
    t0 = time.perf_counter()
    _, m = tilt.SPEC.run("lee-herrmann", n, params={"mu": mu}, seed=seed, checkpoint=(state_file, every),
                         resume=resume)
    keep = ("theta_t", "theta_r", "theta_ms_theory", "theta_t_theory", "theta_r_plus_theta_t", "theory_note")
    row = {"mu": mu, "seed": seed, "n": n, "seconds": time.perf_counter() - t0,
           **{k: _plain(m.get(k)) for k in keep},
           "pile_repose": _plain(m.get("pile_repose")), "at_rest_box": _plain((m.get("box") or {}).get("at_rest")),
           "onset_step": m.get("onset_step"), "moved_step": m.get("moved_step")}
    pathlib.Path(out).write_text(json.dumps(row, indent=1))
    return row


def one_drop(seed: int, n: int, out: str, every: int) -> dict:
    import jaxpile
    jaxpile.configure()  # float64 and the commands' XLA settings
    from jaxpile.protocols import drop

    state_file = out.replace(".json", ".npz")
    resume = state_file if os.path.exists(state_file) else None
    t0 = time.perf_counter()
    _, m = drop.SPEC.run("liffman", n, seed=seed, checkpoint=(state_file, every), resume=resume)
    keep = ("n_particles", "all_inserted", "at_rest", "profile_x_over_base", "profile_normal", "profile_normalised",
            "central_dip", "has_central_dip", "weight_balance", "base_width", "height")
    row = {"seed": seed, "n": n, "seconds": time.perf_counter() - t0, **{k: _plain(m.get(k)) for k in keep},
           "angles": _plain({k: v for k, v in m.items() if "repose" in k or "angle" in k})}
    pathlib.Path(out).write_text(json.dumps(row, indent=1))
    return row


def summarise_tilt(rows: list[dict]) -> dict:
    out = {}
    for mu in sorted({r["mu"] for r in rows}):
        mine = [r for r in rows if r["mu"] == mu]
        out[f"{mu:g}"] = {
            "piles": len(mine),
            "theta_r": mean_stderr([r["theta_r"] for r in mine]),
            "theta_t": mean_stderr([r["theta_t"] for r in mine]),
            "theta_r_plus_theta_t": mean_stderr([r["theta_r_plus_theta_t"] for r in mine]),
            "theta_t_theory": mean_stderr([r["theta_t_theory"] for r in mine]),
            "theta_ms_theory": mine[0]["theta_ms_theory"],
            "moved": sum(r["theta_t"] is not None for r in mine),
        }
    return out


def summarise_drop(rows: list[dict]) -> dict:
    return {"piles": len(rows),
            "central_dip": mean_stderr([r["central_dip"] for r in rows]),
            "has_central_dip": sum(bool(r["has_central_dip"]) for r in rows),
            "weight_balance": mean_stderr([r["weight_balance"] for r in rows]),
            "at_rest": sum(bool(r["at_rest"]) for r in rows)}


def figure_tilt(rows, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    table = summarise_tilt(rows)
    mus = np.array([float(k) for k in table])
    fig, (a, b) = plt.subplots(1, 2, figsize=(10, 4))
    for key, label, marker in (("theta_r", "theta_R (method 3)", "o"), ("theta_t", "theta_T", "s"),
                               ("theta_r_plus_theta_t", "theta_R + theta_T", "^")):
        m = [table[k][key]["mean"] or np.nan for k in table]
        e = [table[k][key]["stderr"] or 0 for k in table]
        (a if key != "theta_t" else b).errorbar(mus, m, e, marker=marker, capsize=3, label=label)
    grid = np.linspace(mus.min(), mus.max(), 50)
    a.plot(grid, np.degrees(np.arctan(3 * grid)), "k--", label="theta_MS = arctan 3 mu (eq. 3)")
    t = [table[k]["theta_t_theory"]["mean"] or np.nan for k in table]
    b.plot(mus, t, "k--", label="eq. 4 at the measured theta_R")
    for ax, title in ((a, "angles against mu (Fig. 7a)"), (b, "tilting angle (Fig. 4)")):
        ax.set_xlabel("mu")
        ax.set_ylabel("degrees")
        ax.set_title(title)
        ax.legend(fontsize=8)
    fig.suptitle(f"Lee & Herrmann 1993 boxes W = H = 4, {rows[0]['n']} disks: mean +- s.e. over seeds")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def figure_drop(rows, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    grid = np.linspace(0.02, 0.98, 25)
    curves = np.array([np.interp(grid, r["profile_x_over_base"], r["profile_normalised"]) for r in rows
                       if r.get("profile_x_over_base")])
    fig, ax = plt.subplots(figsize=(6, 4))
    for c in curves:
        ax.plot(grid, c, color="0.6", lw=0.6)
    mean = curves.mean(0)
    err = curves.std(0, ddof=1) / np.sqrt(len(curves)) if len(curves) > 1 else 0 * mean
    ax.plot(grid, mean, "C0", lw=2, label=f"mean of {len(curves)} piles")
    ax.fill_between(grid, mean - err, mean + err, color="C0", alpha=0.3, label="+- s.e.")
    ax.set_xlabel("x / B")
    ax.set_ylabel("base normal force / max")
    ax.set_title(f"Liffman et al. 1992 Fig. 20: dropped piles of {rows[0]['n']} disks")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def pile_rows(folder) -> list[dict]:
    """Every pile's row of a study in `folder`: the committed summary's `piles`,
    with any pile whose own file is there (`seed<k>.json`, `mu<mu>_seed<k>.json`:
    the workings of a run, not committed) read from that file instead
    (`baxter_readings.study_rows`)."""
    from baxter_readings import study_rows

    return study_rows(folder, "piles", lambda row: (row.get("mu") or 0.0, row["seed"]), "*seed*.json")


def keep_piles(folder, study: str, n: int) -> None:
    """Writes every finished pile's row in `folder` into its summary.json
    (`piles`), so that a study stopped before its end keeps what it has done
    in the one committed file."""
    folder = pathlib.Path(folder)
    summary_file = folder / "summary.json"
    out = json.loads(summary_file.read_text()) if summary_file.exists() else {"study": study, "n": n}
    out["piles"] = pile_rows(folder)
    summary_file.write_text(json.dumps(out, indent=1))


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("study", choices=["tilt", "drop"])
    parser.add_argument("--mu", default="0.1,0.2,0.3,0.4,0.5", help="tilt: friction coefficients")
    parser.add_argument("--seeds", type=int, default=8)
    parser.add_argument("--n", type=int, default=None, help="disks per pile (tilt: 409, drop: 968)")
    parser.add_argument("--workers", type=int, default=1)
    parser.add_argument("--checkpoint-every", type=int, default=20_000)
    parser.add_argument("--out", default=None)
    parser.add_argument("--figure", default=None)
    args = parser.parse_args(argv)
    n = args.n or {"tilt": 409, "drop": 968}[args.study]
    folder = pathlib.Path(args.out or RESULTS / {"tilt": "lee_herrmann_1993", "drop": "liffman_1992"}[args.study]) \
        / f"{args.study}_n{n}"
    folder.mkdir(parents=True, exist_ok=True)
    if args.study == "tilt":
        mus = [float(v) for v in args.mu.split(",")]
        jobs = [((mu, s), str(folder / f"mu{mu:g}_seed{s}.json")) for mu in mus for s in range(args.seeds)]
        run = lambda key, path: (one_tilt, key[0], key[1], n, path, args.checkpoint_every)
    else:
        jobs = [((s,), str(folder / f"seed{s}.json")) for s in range(args.seeds)]
        run = lambda key, path: (one_drop, key[0], n, path, args.checkpoint_every)
    done = {(row.get("mu"), row["seed"]) if args.study == "tilt" else (row["seed"],) for row in pile_rows(folder)}
    todo = [(k, p) for k, p in jobs if k not in done]
    print(f"{len(jobs)} {args.study} piles of {n} disks, {len(jobs) - len(todo)} already done; results in {folder}",
          flush=True)
    with concurrent.futures.ProcessPoolExecutor(max_workers=args.workers) as pool:
        futures = [pool.submit(*run(k, p)) for k, p in todo]
        for future in concurrent.futures.as_completed(futures):
            row = future.result()
            keep_piles(folder, args.study, n)  # a study stopped early keeps the piles it finished
            shown = {k: row.get(k) for k in ("mu", "seed", "theta_r", "theta_t", "central_dip", "seconds") if k in row}
            print("  " + ", ".join(f"{k} {v:.3g}" if isinstance(v, float) else f"{k} {v}" for k, v in shown.items()),
                  flush=True)
    every = pile_rows(folder)
    wanted = {k for k, _ in jobs}
    rows = [r for r in every if ((r.get("mu"), r["seed"]) if args.study == "tilt" else (r["seed"],)) in wanted]
    table = summarise_tilt(rows) if args.study == "tilt" else summarise_drop(rows)
    command = "python benchmarks/studies/papers/paper_ensembles.py " + " ".join(argv if argv is not None else sys.argv[1:])
    out = {"study": args.study, "n": n, "command": command, "summary": table, "piles": every}
    (folder / "summary.json").write_text(json.dumps(out, indent=1))
    print(json.dumps(table, indent=1))
    if args.figure:
        (figure_tilt if args.study == "tilt" else figure_drop)(rows, args.figure)
        print(f"figure: {args.figure}")
    return out


if __name__ == "__main__":
    main()
