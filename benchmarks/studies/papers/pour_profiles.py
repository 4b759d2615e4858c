"""The poured heap's mean base profile with its band, with and without rolling
resistance: the check the central-dip statistic needs before anything is fitted
to Smid and Novosad's dip (docs/rolling_resistance.md).

    python benchmarks/studies/papers/pour_profiles.py --out DIR [--seeds 16] [--mu-roll 0,0.3] [--n 300] [--mu 0.5] [--interval 1.612] [--spread 3]
    python benchmarks/studies/papers/pour_profiles.py --grid RESULTS [RESULTS ...] --out DIR   # `on_the_grid`

runs `jaxpile.sweep` of the 1997 pour (baxter law, spins on, rolling sds with
k_roll = 1000, gamma_roll = 30; sliding friction mu, the paper's 0.5 unless
given) over mu_roll times seeds, checkpointed every
20 000 steps in DIR (rerun the same command to resume), and records each heap's
base normal force, binned over its own base and normalised by its total, on a
common x/B grid (`BINS` bins). Writes DIR/profiles.json (the rows with their
profiles, the mean profile per mu_roll with its standard error band, the dip
of the mean profile) and DIR/profiles.png.
"""

from __future__ import annotations

import argparse
import json
import math
import pathlib
import sys
from types import SimpleNamespace

import numpy as np

BINS = 15
"""Bins over the base: odd, so one sits under the middle; about two substrate spacings each on a 300-disk
heap's base (the pour's own profile, which gives the rows' `central_dip`, has about one per four)."""


def heap_profile(sim, params, state, setup) -> dict:
    """The heap's base normal force in `BINS` bins over its base, each bin's share of the total."""
    from jaxpile.measure import poured_heap
    from jaxpile.measure.heap import base_profile

    m = poured_heap.measure(sim, params, state)
    full = m["base_profile"]
    forces = m["substrate_forces"]
    profile = base_profile(forces, extent=(full.x_left, full.x_left + full.width), bins=BINS)
    share = np.asarray(profile.force, float) / max(float(np.sum(profile.force)), 1e-300)
    return {"profile": share.tolist(), "base_width_bins": float(full.width)}


def centre_below_flanks(profiles: np.ndarray, held_out: bool = False) -> dict:
    """How far the centre bin sits below the flanks, with its standard error:
    the flank bins are the mean profile's largest on each side of the centre,
    and each heap gives (mean of its two flank bins - its centre bin); the mean
    of that over the heaps, over the mean flank, is > 0 for an M. The
    standard error is the heaps' (paired: a heap's bins move together).
    Chosen on the same heaps, the flank bins are those the noise raised, which
    biases the reading up: by 0.12 on a flat-topped 16-heap mean profile
    (docs/rolling_resistance.md). `held_out` chooses each heap's flank bins
    on the mean of the other heaps, which the heap's own noise cannot raise
    (`flank_bins` is then None)."""
    drop, bins = heap_drops(profiles, held_out)
    return {"value": float(drop.mean()), "stderr": float(drop.std(ddof=1) / math.sqrt(len(drop))),
            "flank_bins": bins, "centre_bin": BINS // 2}


def heap_drops(profiles: np.ndarray, held_out: bool = False) -> tuple[np.ndarray, list | None]:
    """`(drops [heaps], flank_bins)`: each heap's (mean of its two flank bins -
    its centre bin) over the mean flank, whose mean is `centre_below_flanks`;
    the flank bins as there (None when `held_out`)."""
    c = BINS // 2

    def flanks(mean):
        return int(np.argmax(mean[:c])), c + 1 + int(np.argmax(mean[c + 1:]))

    if held_out:
        pairs = [flanks(np.delete(profiles, i, axis=0).mean(axis=0)) for i in range(len(profiles))]
        flank = np.array([0.5 * (p[left] + p[right]) for p, (left, right) in zip(profiles, pairs)])
        bins = None
    else:
        left, right = flanks(profiles.mean(axis=0))
        flank, bins = 0.5 * (profiles[:, left] + profiles[:, right]), [left, right]
    return (flank - profiles[:, c]) / flank.mean(), bins


def summarise(rows: list[dict]) -> dict:
    """Mean profile and standard error band per mu_roll; the dip of the mean
    profile (`heap.central_dip`) and the centre below the flanks (`centre_below_flanks`)."""
    from jaxpile.measure.heap import central_dip

    out = {}
    for mu_roll in sorted({r["mu_roll"] for r in rows}):
        p = np.array([r["profile"] for r in rows if r["mu_roll"] == mu_roll and r.get("profile") is not None])
        mean, se = p.mean(axis=0), p.std(axis=0, ddof=1) / math.sqrt(len(p))
        dip = central_dip(SimpleNamespace(force=mean))  # the rows' statistic, of the mean profile
        angle = np.array([r["repose_mean"] for r in rows if r["mu_roll"] == mu_roll and r.get("repose_mean") is not None],
                         float)
        angle = angle[np.isfinite(angle)]  # a heap without a measured angle
        out[str(mu_roll)] = {"heaps": len(p), "mean": mean.tolist(), "stderr": se.tolist(), "dip_of_mean": dip,
                             "centre_below_flanks": centre_below_flanks(p),
                             "repose_mean": {"mean": float(angle.mean()), "count": len(angle),
                                             "stderr": float(angle.std(ddof=1) / math.sqrt(len(angle)))}}
    return out


def _mean_se(values) -> tuple[float, float, int]:
    """`baxter_readings.mean_stderr` of the finite values as (mean, stderr, count), NaN where it has None."""
    from baxter_readings import mean_stderr

    s = mean_stderr(values)
    return tuple(math.nan if s[k] is None else float(s[k]) for k in ("mean", "stderr")) + (s["count"],)


def on_the_grid(summaries: list[dict], mu: float = 0.5) -> dict:
    """Smid and Novosad's declared dip and angle against the grid of poured
    heaps at sliding friction `mu` (`summaries`: profiles.json records of one
    set-up: heap size, binning, release interval and spread; mu None is the paper's
    0.5; records of the same mu and mu_roll are pooled). Per mu_roll: the per-heap means of `central_dip`
    (the fit's statistic) and `repose_mean` with their standard errors and
    counts, the centre below the flanks of the pooled profiles
    (`centre_below_flanks`, its flank bins chosen on the same heaps and, held
    out, on the others), and the loss `jaxpile fit` would give there
    (`ensemble_fit.objective_for` of the declared pair, `smid_novosad_target`).
    `interval` and `spread`: the set-up's pour where it is not the paper's
    (None where it is; `set_up_label` reads them). `crossings`: between each two neighbouring grid points whose angles
    straddle the reported angle, the mu_roll where the linearly interpolated
    angle meets it and the interpolated dip (both readings) there, with errors propagated from
    the points' standard errors (points taken independent: they share seeds,
    so this is a rough band). `fit`: mu_roll fitted to the declared dip and
    angle from every heap along mu_roll at this mu (`fit_along`), and
    `recovery`: the same estimator recovering each grid point's mu_roll from
    the other half of the seeds (`recover_along`); `fit_profile` and
    `recovery_profile`: the same with the dip read off the mean profile
    (each heap's share of the held-out centre below the flanks,
    `profile_drops`); `fit_narrow` and `recovery_narrow`: the same with each
    heap's own dip in fixed narrow windows (`dip_below_flanks`, `narrow_dips`;
    also per point and at the crossings). `every_point`: the same readings at every
    (mu, mu_roll) the records hold, at this mu or another: whether any of
    them stands at the reported angle with the reported dip, whatever its
    parameters."""
    from jaxpile.fit.ensemble_fit import objective_for
    from jaxpile.fit.ensemble_targets import smid_novosad_target
    from jaxpile.fit.stats import weights
    from jaxpile.protocols.pour import PAPER_SETTING

    target = smid_novosad_target(("central_dip", "repose_mean"))
    loss_of = objective_for(target, weights(target))
    angle_target = float(target.mean[1])
    mu_of = {id(s): _mu(s) for s in summaries}
    if mu not in mu_of.values():
        raise ValueError(f"no results at mu = {mu}: the records hold mu = {sorted(set(mu_of.values()))}")
    set_ups = {(s["n"], s["bins"], *(PAPER_SETTING[k] if s.get(k) is None else s[k] for k in ("interval", "spread")))
               for s in summaries}  # the paper's interval and spread where a run did not set them
    if len(set_ups) > 1:
        raise ValueError(f"the records mix set-ups (heap size, bins, release interval, spread) {sorted(set_ups, key=str)}: "
                         "a grid is one set-up")
    rows, seen = {}, set()
    for summary in summaries:
        for r in summary["rows"]:
            key = (mu_of[id(summary)], float(r["mu_roll"]), r.get("seed"))
            if r.get("seed") is not None and key in seen:
                raise ValueError(f"mu = {key[0]:g}, mu_roll = {key[1]:g}, seed {key[2]} is in two records: "
                                 "a heap counts once")
            seen.add(key)
            rows.setdefault(key[:2], []).append(r)
    every = {}
    for (at_mu, x), heaps in sorted(rows.items()):
        dip, angle = _mean_se(r.get("central_dip") for r in heaps), _mean_se(r.get("repose_mean") for r in heaps)
        profiles = [r["profile"] for r in heaps if r.get("profile") is not None]
        readings = [centre_below_flanks(np.asarray(profiles, float), held_out=h) if len(profiles) > 1 else None
                    for h in (False, True)]
        below, held = ([r["value"], r["stderr"], len(profiles)] if r else None for r in readings)
        narrow = _mean_se(r["dip_below_flanks"] for r in narrow_dips(heaps)) if profiles else None
        every[at_mu, x] = {"heaps": len(heaps), "central_dip": dip, "repose_mean": angle,
                           "centre_below_flanks": below, "centre_below_flanks_held_out": held,
                           "dip_below_flanks": narrow,
                           "loss": float(loss_of(np.array([dip[0], angle[0]])))}
    points = {x: point for (at_mu, x), point in every.items() if at_mu == mu}
    xs, crossings = sorted(points), []
    for x0, x1 in zip(xs, xs[1:]):
        (a0, s0, _), (a1, s1, _) = points[x0]["repose_mean"], points[x1]["repose_mean"]
        if not all(map(math.isfinite, (a0, a1))) or a0 == a1 or (a0 - angle_target) * (a1 - angle_target) > 0:
            continue
        # x* = x0 + t (x1 - x0), t = (A - a0) / (a1 - a0): dt/da0 = (A - a1) / (a1 - a0)^2, dt/da1 = -(A - a0) / (a1 - a0)^2
        t = (angle_target - a0) / (a1 - a0)
        dt = math.hypot((angle_target - a1) * s0, (angle_target - a0) * s1) / (a1 - a0) ** 2
        def between(key):
            if points[x0][key] is None or points[x1][key] is None:
                return None
            (d0, e0), (d1, e1) = points[x0][key][:2], points[x1][key][:2]
            return [d0 + t * (d1 - d0), math.sqrt(((1 - t) * e0) ** 2 + (t * e1) ** 2 + ((d1 - d0) * dt) ** 2)]

        crossings.append({"between": [x0, x1], "mu_roll": [x0 + t * (x1 - x0), abs(x1 - x0) * dt],
                          "central_dip": between("central_dip"), "centre_below_flanks": between("centre_below_flanks"),
                          "centre_below_flanks_held_out": between("centre_below_flanks_held_out"),
                          "dip_below_flanks": between("dip_below_flanks")})
    along = {x: heaps for (at_mu, x), heaps in rows.items() if at_mu == mu}
    w = weights(target)
    profiled = {x: profile_drops(heaps) for x, heaps in along.items()}
    return {"mu": mu, "n": summaries[0]["n"], "bins": summaries[0]["bins"],
            **{k: None if summaries[0].get(k) in (None, PAPER_SETTING[k]) else summaries[0][k]
               for k in ("interval", "spread")},  # the set-up's, None for the paper's
            "target": dict(zip(target.labels, zip(target.mean.tolist(), target.spread.tolist()))),
            "points": {str(x): points[x] for x in xs}, "crossings": crossings,
            "fit": fit_along(along, target.mean, w), "recovery": recover_along(along, w),
            "fit_profile": fit_along(profiled, target.mean, w, dip="centre_below_flanks_held_out"),
            "recovery_profile": recover_along(along, w, "centre_below_flanks_held_out", profile_drops),
            "fit_narrow": fit_along({x: narrow_dips(heaps) for x, heaps in along.items()}, target.mean, w,
                                    dip="dip_below_flanks"),
            "recovery_narrow": recover_along(along, w, "dip_below_flanks", narrow_dips),
            "every_point": [{"mu": at_mu, "mu_roll": x, **point} for (at_mu, x), point in every.items()]}


def _reads(row: dict, dip: str) -> bool:
    """Whether a heap's row has a finite dip (`dip`) and angle, the two statistics the grid's fit reads."""
    return all(row.get(k) is not None and math.isfinite(row[k]) for k in (dip, "repose_mean"))


def fit_along(heaps: dict, target_mean, w, target_members=None, dip: str = "central_dip") -> dict | None:
    """mu_roll fitted to a target of (`central_dip`, `repose_mean`) from the
    grid's heaps, each heap a point: the inverse regression
    `jaxpile.fit.regression.inverse` of the two statistics on mu_roll (a
    straight line, least squares), with weights `w` as `jaxpile fit` gives
    them. Like the regression `jaxpile fit` draws through its own ensembles,
    but over mu_roll itself (the grid holds mu_roll = 0, which the fit's log
    parameters cannot), one heap a point, and from ensembles already run. `heaps`: {mu_roll: [rows]}; rows missing either
    statistic are left out. `target_members` `[B, 2]`: the target's own heaps
    (their sampling noise joins the interval), None for declared values.
    The heaps of a seed share their initial draws across mu_roll, which the
    line takes as independent: a positive correlation within a seed would
    make the interval too narrow (on the committed heaps a bootstrap over
    seeds gives the standard error a bootstrap over heaps gives). Returns mu_roll (estimate, standard error, the
    95 % Student-t interval), the line's dip and angle there with their
    standard errors, the loss there (`jaxpile fit`'s: the mean of the weighted
    squared misses), the heaps, the degrees of freedom, the
    residual scatter of each statistic, the line (intercept and slope of
    each) and `lack_of_fit`: per statistic, the p-value of the straight line
    against the grid points' own means (the pure-error lack-of-fit F test,
    Draper & Smith, Applied Regression Analysis, 3rd ed. 1998, sec. 2.1; None with
    fewer than three grid points): a small one says the statistic is not
    straight in mu_roll, and the line's reading at the answer is the line's,
    not the heaps'. None with fewer than two grid points. `dip`: the rows'
    key of the dip read (`central_dip`, the fit's, or
    `centre_below_flanks_held_out`, each heap's share of the mean profile's
    reading: `profile_drops`; or `dip_below_flanks`, each heap's own reading
    in fixed windows: `narrow_dips`); the result names it `central_dip`."""
    from jaxpile.fit import regression
    from jaxpile.fit.stats import t_quantile

    points = [(x, r[dip], r["repose_mean"]) for x, rows in heaps.items() for r in rows if _reads(r, dip)]
    if len({p[0] for p in points}) < 2:
        return None
    x, means = np.array([[p[0]] for p in points]), np.array([p[1:] for p in points])
    sampling = None
    if target_members is not None and len(target_members) > 1:
        sampling = np.cov(np.asarray(target_members, float), rowvar=False) / len(target_members)
    line = regression.inverse(x, means, target_mean, w, (sampling,))
    if line is None:
        return None
    value, se = float(line.theta[0]), float(math.sqrt(max(line.cov[0, 0], 0.0)))
    z = t_quantile(line.dof)
    at, cov = line.predict(line.theta)
    mismatch = (at - np.asarray(target_mean, float)) ** 2
    levels = sorted({p[0] for p in points})
    lack_of_fit = None  # per statistic, p of the line against the grid points' own means (pure-error F test)
    if len(levels) > 2 and len(points) > len(levels):
        from jax.scipy.special import betainc

        group = np.array([levels.index(p[0]) for p in points])
        own = np.array([means[group == g].mean(axis=0) for g in range(len(levels))])[group]
        pure = np.sum((means - own) ** 2, axis=0)
        lack = np.sum((means - line.intercept - x @ line.jacobian.T) ** 2, axis=0) - pure
        d1, d2 = len(levels) - 2, len(points) - len(levels)
        total = np.sum((means - means.mean(axis=0)) ** 2, axis=0)
        lack_of_fit = [None if pk <= 1e-12 * tk else  # no scatter within a grid point: nothing to test against
                       float(betainc(d2 / 2, d1 / 2, d2 / (d2 + d1 * (lk / d1) / (pk / d2))))
                       for lk, pk, tk in zip(lack, pure, total)]
    return {"mu_roll": [value, se], "interval": [value - z * se, value + z * se],
            "central_dip": [float(at[0]), float(math.sqrt(cov[0, 0]))],
            "repose_mean": [float(at[1]), float(math.sqrt(cov[1, 1]))],
            "loss": float(np.mean(np.asarray(w, float) * mismatch)), "heaps": len(points), "dof": line.dof,
            "scatter": line.scatter.tolist(), "grid": sorted({p[0] for p in points}),
            "line": {"intercept": line.intercept.tolist(), "slope": line.jacobian[:, 0].tolist()},
            "lack_of_fit": lack_of_fit}


def narrow_dips(rows: list[dict]) -> list[dict]:
    """The heaps of one grid point that have a profile, each with
    `dip_below_flanks` (`jaxpile.measure.heap.dip_below_flanks`: its centre bin
    below its flank bins, windows fixed in advance) read off its own `BINS`-bin
    profile: what the pour's sweep row reports on a heap of this size, for
    records written before it did. Each heap's reading is its own."""
    from jaxpile.measure.heap import BaseProfile, dip_below_flanks

    x = (np.arange(BINS) + 0.5) / BINS
    return [{**r, "dip_below_flanks": dip_below_flanks(BaseProfile(x, np.asarray(r["profile"], float), None, 0.0, 1.0))}
            for r in rows if r.get("profile") is not None]


def profile_drops(rows: list[dict]) -> list[dict]:
    """The heaps of one grid point that have a profile, each with
    `centre_below_flanks_held_out`: its own drop below the flanks chosen on
    the other heaps (`heap_drops(held_out=True)`), whose mean over the heaps
    is the mean profile's held-out reading. Each is scaled by the heaps' mean
    flank, so the drops of one point are not quite independent."""
    with_profile = [r for r in rows if r.get("profile") is not None]
    if len(with_profile) < 3:  # a held-out flank needs two other heaps to be a choice
        return []
    drops, _ = heap_drops(np.asarray([r["profile"] for r in with_profile], float), held_out=True)
    return [{**r, "centre_below_flanks_held_out": float(d)} for r, d in zip(with_profile, drops)]


def recover_along(heaps: dict, w, dip: str = "central_dip", derive=None) -> list[dict]:
    """`fit_along` checked on known values: for each grid mu_roll, the target is
    the mean dip and angle of its heaps of one half of the seeds (even or
    odd), fitted from the other half's heaps at every grid point. `derive`:
    what makes the `dip` key from one half's rows at one grid point
    (`profile_drops`, read within the half so the halves share nothing);
    None: the rows hold it. Each entry: the truth, the half the target came
    from, the fit (`fit_along`), and whether its interval holds the truth."""
    derive = derive or (lambda rows: rows)
    seeds = sorted({r["seed"] for rows in heaps.values() for r in rows if r.get("seed") is not None})
    halves = {"even": set(seeds[0::2]), "odd": set(seeds[1::2])}
    out = []
    for truth in sorted(heaps):
        for name, half in halves.items():
            members = np.array([[r[dip], r["repose_mean"]]
                                for r in derive([r for r in heaps[truth] if r.get("seed") in half]) if _reads(r, dip)])
            others = {x: derive([r for r in rows if r.get("seed") is not None and r["seed"] not in half])
                      for x, rows in heaps.items()}
            if len(members) < 2:
                continue
            fit = fit_along(others, members.mean(axis=0), w, members, dip)
            if fit is not None:
                out.append({"truth": truth, "target_half": name, "target_heaps": len(members), "fit": fit,
                            "inside": bool(fit["interval"][0] < truth < fit["interval"][1])})
    return out


def set_up_label(summary: dict) -> str:
    """What a record's pour changed from the paper's (its release interval, its source's width), for a label."""
    from jaxpile.protocols.pour import PAPER_SETTING

    return "".join(f", {what.format(summary[key])} (the paper's {PAPER_SETTING[key]:g})"
                   for key, what in (("interval", "a disk every {:g}"), ("spread", "released within ±{:g} σ"))
                   if summary.get(key) is not None)


def _mu(summary: dict) -> float:
    """A record's sliding friction: None is the paper's 0.5."""
    return 0.5 if summary.get("mu") is None else float(summary["mu"])


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", required=True)
    parser.add_argument("--seeds", type=int, default=16)
    parser.add_argument("--mu-roll", default="0,0.3")
    parser.add_argument("--n", type=int, default=300)
    parser.add_argument("--mu", type=float, default=None, help="sliding friction (default: the paper's 0.5)")
    parser.add_argument("--interval", type=float, default=None,
                        help="time between releases, sqrt(sigma/g) (default: the paper's 1.612): the pour's rate")
    parser.add_argument("--spread", type=float, default=None,
                        help="release x uniform in +-spread, sigma (default: the paper's 3): the source's width")
    parser.add_argument("--grid", nargs="+", metavar="RESULTS",
                        help="the declared dip and angle against these runs' profiles.json, along mu_roll at --mu "
                             "(default 0.5) and at every (mu, mu_roll) they hold: writes OUT/pour_grid.json and "
                             "OUT/pour_grid.png (runs nothing)")
    parser.add_argument("--summarise", action="store_true",
                        help="rewrite DIR/profiles.json's summary and figure from its rows (runs nothing)")
    args = parser.parse_args(argv)
    out = pathlib.Path(args.out)
    if args.grid:
        ignored = [f"--{name.replace('_', '-')}" for name in ("summarise", "seeds", "mu_roll", "n", "interval", "spread")
                   if getattr(args, name) != parser.get_default(name)]
        if ignored:
            parser.error(f"--grid runs nothing and reads its RESULTS: {', '.join(ignored)} does not apply")
        summaries = [json.loads((pathlib.Path(d) / "profiles.json").read_text()) for d in args.grid]
        try:
            grid = on_the_grid(summaries, 0.5 if args.mu is None else args.mu)
        except ValueError as error:
            parser.error(str(error))
        given = sys.argv[1:] if argv is None else argv
        grid["command"] = "python benchmarks/studies/papers/pour_profiles.py " + " ".join(given)
        out.mkdir(parents=True, exist_ok=True)
        (out / "pour_grid.json").write_text(json.dumps(grid, indent=1) + "\n")
        _grid_figure(grid, out / "pour_grid.png")
        for x, p in grid["points"].items():
            below = "" if p["centre_below_flanks_held_out"] is None else (
                f" (centre {p['centre_below_flanks'][0]:+.3f}, held out {p['centre_below_flanks_held_out'][0]:+.3f} "
                f"+- {p['centre_below_flanks_held_out'][1]:.3f} below the flanks)")
            narrow = "" if p["dip_below_flanks"] is None else (
                f", {p['dip_below_flanks'][0]:+.3f} +- {p['dip_below_flanks'][1]:.3f} in fixed windows")
            print(f"mu_roll = {x}: dip {p['central_dip'][0]:+.3f} +- {p['central_dip'][1]:.3f}{below}{narrow}, angle "
                  f"{p['repose_mean'][0]:.1f} +- {p['repose_mean'][1]:.1f} deg ({p['heaps']} heaps), loss {p['loss']:.1f}")
        for p in grid["every_point"]:
            if p["mu"] != grid["mu"]:
                held = p["centre_below_flanks_held_out"]
                print(f"mu = {p['mu']:g}, mu_roll = {p['mu_roll']:g}: dip {p['central_dip'][0]:+.3f} +- "
                      f"{p['central_dip'][1]:.3f}" + ("" if held is None else
                                                      f" (held out {held[0]:+.3f} +- {held[1]:.3f} below the flanks)")
                      + f", angle {p['repose_mean'][0]:.1f} +- {p['repose_mean'][1]:.1f} deg ({p['heaps']} heaps)")
        for c in grid["crossings"] or [None]:
            print("the angle does not cross the reported one on this grid" if c is None else
                  f"the angle meets {grid['target']['repose_mean'][0]} deg at mu_roll = {c['mu_roll'][0]:.3f} +- "
                  f"{c['mu_roll'][1]:.3f}, where the dip is {c['central_dip'][0]:+.3f} +- {c['central_dip'][1]:.3f} "
                  + ("" if c["centre_below_flanks_held_out"] is None else
                     f"and the centre {c['centre_below_flanks_held_out'][0]:+.3f} +- "
                     f"{c['centre_below_flanks_held_out'][1]:.3f} below the flanks (held out)"))
        fit = grid["fit"]
        print("too few grid points along mu_roll for a fit" if fit is None else
              f"fitted to both from {fit['heaps']} heaps: mu_roll = {fit['mu_roll'][0]:.3f} +- {fit['mu_roll'][1]:.3f} "
              f"(95 %: {fit['interval'][0]:.3f}-{fit['interval'][1]:.3f}), where the line's dip is "
              f"{fit['central_dip'][0]:+.3f} +- {fit['central_dip'][1]:.3f} and its angle {fit['repose_mean'][0]:.1f} "
              f"+- {fit['repose_mean'][1]:.1f} deg (loss {fit['loss']:.1f})" + (
                  "" if not fit["lack_of_fit"] else ", the line against the points' own means: p = "
                  + ", ".join("-" if q is None else f"{q:.2g}" for q in fit["lack_of_fit"]) + " (dip, angle)"))
        fit = grid["fit_profile"]
        if fit is not None:
            print(f"the same with the dip read off the mean profile (held out): mu_roll = {fit['mu_roll'][0]:.3f} +- "
                  f"{fit['mu_roll'][1]:.3f} (95 %: {fit['interval'][0]:.3f}-{fit['interval'][1]:.3f}), where the dip is "
                  f"{fit['central_dip'][0]:+.3f} +- {fit['central_dip'][1]:.3f} and the angle "
                  f"{fit['repose_mean'][0]:.1f} +- {fit['repose_mean'][1]:.1f} deg (loss {fit['loss']:.2f}); "
                  f"{sum(r['inside'] for r in grid['recovery_profile'])} of {len(grid['recovery_profile'])} "
                  "recoveries hold the truth")
        fit = grid["fit_narrow"]
        if fit is not None:
            print(f"the same with each heap's dip below its flanks (fixed windows): mu_roll = {fit['mu_roll'][0]:.3f} +- "
                  f"{fit['mu_roll'][1]:.3f} (95 %: {fit['interval'][0]:.3f}-{fit['interval'][1]:.3f}), where the dip is "
                  f"{fit['central_dip'][0]:+.3f} +- {fit['central_dip'][1]:.3f} and the angle "
                  f"{fit['repose_mean'][0]:.1f} +- {fit['repose_mean'][1]:.1f} deg (loss {fit['loss']:.2f}); "
                  f"{sum(r['inside'] for r in grid['recovery_narrow'])} of {len(grid['recovery_narrow'])} "
                  "recoveries hold the truth")
        held = [r["inside"] for r in grid["recovery"]]
        if held:
            print(f"recovered from the other half of the seeds: {sum(held)} of {len(held)} intervals hold the truth "
                  "(" + ", ".join(f"{r['truth']:g} -> {r['fit']['mu_roll'][0]:.3f}" for r in grid["recovery"]) + ")")
        return
    if args.summarise:
        summary = json.loads((out / "profiles.json").read_text())
        summary["by_mu_roll"] = summarise(summary["rows"])
        _write(out, summary, summary["n"], summary.get("mu"))
        return
    import jaxpile

    jaxpile.configure(threads=True)  # a batch: XLA's threads, as `jaxpile sweep`

    out.mkdir(parents=True, exist_ok=True)
    path = out / "checkpoint.npz"
    # the run's set-up beside its checkpoint: a resume with another set-up (a pour rate, say) would go on with
    # the saved heaps and label them with the new one
    facts, record = {"n": args.n, "mu": args.mu, "interval": args.interval, "mu_roll": args.mu_roll,
                     "seeds": args.seeds, **({} if args.spread is None else {"spread": args.spread})}, out / "run.json"
    if path.exists() and record.exists() and json.loads(record.read_text()) != facts:
        parser.error(f"{out} holds a run of {record.read_text().strip()}; this command asks for {json.dumps(facts)}: "
                     "resume it with its own options, or choose another --out")
    record.write_text(json.dumps(facts) + "\n")
    result = jaxpile.sweep("pour", "baxter", vary={"mu_roll": [float(v) for v in args.mu_roll.split(",")]},
                           seeds=args.seeds, options={"n": args.n, **{k: getattr(args, k) for k in ("interval", "spread")
                                                             if getattr(args, k) is not None}},
                           params={"k_roll": 1000.0, "gamma_roll": 30.0,
                                                                        **({} if args.mu is None else {"mu": args.mu})},
                           rotation=True, law_options={"rolling": "sds"}, progress=False,
                           checkpoint=(str(path), 20_000), resume=str(path) if path.exists() else None,
                           extra_measure=heap_profile)
    rows = [dict(r) for r in result.rows]
    given = sys.argv[1:] if argv is None else argv
    summary = {"command": "python benchmarks/studies/papers/pour_profiles.py " + " ".join(given),
               "bins": BINS, "n": args.n, "mu": args.mu, "interval": args.interval, "spread": args.spread,
               "settings": result.info.get("settings"),
               "by_mu_roll": summarise(rows), "rows": rows}
    _write(out, summary, args.n, args.mu)


def _grid_figure(grid: dict, path: pathlib.Path) -> None:
    """The angle and the two dip readings against mu_roll at the grid's mu, with Smid and Novosad's and the
    crossings; and the held-out dip against the angle at every (mu, mu_roll) that has one."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Rectangle

    from jaxpile.fit.targets import SMID_NOVOSAD_DIP_RANGE

    x = np.array([float(k) for k in grid["points"]])
    pts = list(grid["points"].values())
    fig, (left, right, both) = plt.subplots(1, 3, figsize=(18, 6.2))
    angle = np.array([p["repose_mean"][:2] for p in pts])
    left.errorbar(x, angle[:, 0], yerr=angle[:, 1], fmt="o-", capsize=4, label="heaps: mean +- s.e.")
    left.axhline(grid["target"]["repose_mean"][0], color="C2", label="Smid & Novosad: 32.6 deg")
    right.axhspan(*SMID_NOVOSAD_DIP_RANGE, color="C2", alpha=0.2, label="Smid & Novosad: 20-30 %")
    right.axhline(0, color="0.5", lw=0.8)
    dip = np.array([p["central_dip"][:2] for p in pts])
    right.errorbar(x, dip[:, 0], yerr=dip[:, 1], fmt="o-", capsize=4, label="central_dip, per heap (the fit's)")
    for key, shift, marker, label in (("centre_below_flanks", 0.004, "s-", "centre below the flanks, mean profile"),
                                      ("centre_below_flanks_held_out", 0.008, "D-",
                                       "the same, flanks chosen on the other heaps"),
                                      ("dip_below_flanks", 0.012, "^-", "dip_below_flanks, per heap (fixed windows)")):
        have = [(xi + shift, *p[key][:2]) for xi, p in zip(x, pts) if p.get(key)]
        if have:
            xs, m, e = map(np.array, zip(*have))
            right.errorbar(xs, m, yerr=e, fmt=marker, capsize=4, label=label)
    for c in grid["crossings"]:
        for ax in (left, right):
            ax.axvspan(c["mu_roll"][0] - c["mu_roll"][1], c["mu_roll"][0] + c["mu_roll"][1], color="C3", alpha=0.15)
        left.plot([c["mu_roll"][0]], [grid["target"]["repose_mean"][0]], "x", color="C3", ms=10,
                  label=f"meets it at mu_roll = {c['mu_roll'][0]:.2f} +- {c['mu_roll'][1]:.2f}")
    fit = grid.get("fit")
    if fit:  # the straight lines the fit drew through the heaps, and where they best meet both targets
        span = np.array([min(fit["grid"]), max(fit["grid"])])
        (m, e), (lo, hi) = fit["mu_roll"], fit["interval"]
        for ax, i, key in ((right, 0, "central_dip"), (left, 1, "repose_mean")):
            ax.plot(span, fit["line"]["intercept"][i] + fit["line"]["slope"][i] * span, "--", color="C4", lw=1)
            ax.axvspan(lo, hi, color="C4", alpha=0.12)
            ax.errorbar([m], [fit[key][0]], xerr=[e], yerr=[fit[key][1]], fmt="*", ms=12, color="C4", capsize=4,
                        label=f"fit to both: mu_roll = {m:.3f} (95 %: {lo:.3f}-{hi:.3f})" if i == 1 else
                        f"the fit's {key} there: {fit[key][0]:+.2f} +- {fit[key][1]:.2f}")
    fit = grid.get("fit_profile")
    if fit:  # the same fit with the dip read off the mean profile (held out)
        (m, e), (d, de) = fit["mu_roll"], fit["central_dip"]
        right.errorbar([m], [d], xerr=[e], yerr=[de], fmt="*", ms=12, color="C2", mec="k", capsize=4,
                       label=f"fit with the held-out reading: mu_roll = {m:.3f} (95 %: {fit['interval'][0]:.3f}-"
                             f"{fit['interval'][1]:.3f}), {d:+.2f} +- {de:.2f}")
    fit = grid.get("fit_narrow")
    if fit:  # the same fit with each heap's dip in fixed windows
        (m, e), (d, de) = fit["mu_roll"], fit["central_dip"]
        right.errorbar([m], [d], xerr=[e], yerr=[de], fmt="*", ms=12, color="C3", mec="k", capsize=4,
                       label=f"fit with dip_below_flanks: mu_roll = {m:.3f} (95 %: {fit['interval'][0]:.3f}-"
                             f"{fit['interval'][1]:.3f}), {d:+.2f} +- {de:.2f}")
    left.set(xlabel="rolling friction mu_roll", ylabel="angle of repose (deg)")
    right.set(xlabel="rolling friction mu_roll", ylabel="dip below the flanks")
    # every (mu, mu_roll): does any stand at the reported angle with the reported dip?
    angle_target, angle_spread = grid["target"]["repose_mean"]
    both.add_patch(Rectangle((angle_target - angle_spread, SMID_NOVOSAD_DIP_RANGE[0]), 2 * angle_spread,
                             SMID_NOVOSAD_DIP_RANGE[1] - SMID_NOVOSAD_DIP_RANGE[0], color="C2", alpha=0.2,
                             label=f"Smid & Novosad: 20-30 %, {angle_target:g} deg (+- {angle_spread:g}: the fit's weight)"))
    both.axhline(0, color="0.5", lw=0.8)
    unread = [q for q in grid["every_point"] if not q["centre_below_flanks_held_out"]]  # fewer than 2 profiles
    for i, p in enumerate(q for q in grid["every_point"] if q["centre_below_flanks_held_out"]):
        (a, ae, _), (d, de, _) = p["repose_mean"], p["centre_below_flanks_held_out"]
        both.errorbar([a], [d], xerr=[ae], yerr=[de], fmt="D", capsize=4, color=f"C{i % 10}",
                      label=f"mu = {p['mu']:g}, mu_roll = {p['mu_roll']:g}")
    both.set(xlabel="angle of repose (deg)", ylabel="centre below the flanks (held out)",
             title="every (mu, mu_roll)" + (f" ({len(unread)} without profiles left out)" if unread else ""))
    both.autoscale_view()
    for ax in (left, right, both):
        ax.grid(alpha=0.3)
    for ax in (left, right):  # below the axes: inside they hide the points
        ax.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.16))
    both.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.02, 1.0))  # beside: inside it hides points
    fig.suptitle(f"poured heaps of {grid['n']} disks{set_up_label(grid)}, baxter law, mu = {grid['mu']:g}, rolling sds: "
                 "the reported angle and dip against mu_roll")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def _write(out: pathlib.Path, summary: dict, n: int, mu: float | None) -> None:
    """DIR/profiles.json and DIR/profiles.png, and the summary printed."""
    (out / "profiles.json").write_text(json.dumps(summary, indent=1, default=float) + "\n")

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    x = (np.arange(BINS) + 0.5) / BINS
    fig, ax = plt.subplots(figsize=(6, 4))
    for key, s in summary["by_mu_roll"].items():
        mean, se = np.array(s["mean"]), np.array(s["stderr"])
        below = s["centre_below_flanks"]
        ax.plot(x, mean, marker="o", label=f"mu_roll = {key}: {s['heaps']} heaps, centre {below['value']:+.2f} +- "
                                           f"{below['stderr']:.2f} below the flanks")
        ax.fill_between(x, mean - se, mean + se, alpha=0.3)
    ax.set(xlabel="x / B", ylabel="share of the base force per bin",
           title=f"poured heaps ({n} disks, baxter{'' if mu is None else f', mu = {mu}'}, rolling sds): mean +- s.e.")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(out / "profiles.png", dpi=120)
    for key, s in summary["by_mu_roll"].items():
        below = s["centre_below_flanks"]
        print(f"mu_roll = {key}: {s['heaps']} heaps, dip of the mean profile {s['dip_of_mean']:+.3f}, centre "
              f"{below['value']:+.3f} +- {below['stderr']:.3f} below the flanks, angle "
              f"{s['repose_mean']['mean']:.1f} +- {s['repose_mean']['stderr']:.1f} deg")


if __name__ == "__main__":
    main()
