"""What an ensemble fit can claim: before it spends its budget, whether each
fitted parameter moves the target's statistics beyond their noise at this
size (`first_pass`, on the 2d + 1 ensembles of its first central
differences); after, whether it converged and why, how far the fitted
statistics sit from the target in units of their errors, and whether its
interval can be trusted (`verdict`). Both are plain dicts (fit.json) with a
sentence each for the command line (`first_pass_lines`, `verdict_lines`).

The tests are the usual ones of least squares: whether the finite-difference
Jacobian's column is told from noise in some statistic (a column that is
noise steers Gauss-Newton by noise), with a Bonferroni-corrected t test over
the statistics; the correlation of the estimates from (J^T W J)^-1, and the lack
of fit chi^2 = sum_k r_k^2 / (e_k^2 + v_k / B) on k - d degrees of freedom
(e_k: the target's error, v_k: one fitted pile's variance), which treats the
statistics as independent (the points of a smoothed profile are not quite:
it is a guide, said as one).
"""

from __future__ import annotations

import math

import numpy as np

FALSE_ALARM = 0.05
"""The chance that a parameter which moves nothing is judged to move a statistic:
each of k statistics is tested at FALSE_ALARM / k (Bonferroni), with a Student-t
quantile for the B - 1 degrees of freedom of B piles' paired changes."""

TOLD_APART = 0.95
"""Two parameters whose estimates correlate beyond this are flagged as poorly told apart."""

LACK_OF_FIT_P = 0.01
"""The chi^2 tail probability below which the model is said not to fit the target."""

MIN_PILES = 3
"""The smallest ensemble whose pile-to-pile spread measures the noise of a difference."""


def target_error(target, members=None) -> np.ndarray:
    """`[k]` the standard error of the target values themselves: a measurement's
    stated error, a synthetic target's sampling error (its piles' spread over
    sqrt(B_t)), or a declared target's spread (what the declaration leaves open)."""
    if target.error is not None:
        return np.asarray(target.error, float)
    if target.members is not None and len(target.members) > 1:
        return np.asarray(target.members, float).std(axis=0, ddof=1) / math.sqrt(len(target.members))
    if target.members is not None:
        return np.zeros(len(target.mean))
    return np.asarray(target.spread, float)


def first_pass(s: np.ndarray, step: float, w: np.ndarray, target, names: list, disks: int) -> dict:
    """How well the target can identify each parameter, from the statistics
    `s` `[2d + 1, B, k]` of the ensembles at theta, theta + h e_i and theta - h e_i
    (`estimators.central_points`), with the fit's weights `w`.

    Per parameter: the statistic its change moves most in units of that
    change's standard error (from the piles' paired changes: common random
    numbers), `z` its mean change over that error, `needed` the t quantile
    that `FALSE_ALARM` sets for k statistics and B piles, `identifiable` (|z|
    >= needed; None when fewer than `MIN_PILES` piles cannot measure the
    noise), and `signal`, `noise`, `ratio`: the weighted norms of the mean
    change and of its standard error over all statistics (about 1 when
    nothing moves). With two or more: the estimates' `correlation` from the
    first Jacobian, and which pairs are poorly told apart."""
    from scipy import stats

    s = np.asarray(s, float)
    d, b = len(names), s.shape[1]
    labels = list(target.labels)
    out = {"disks": int(disks), "piles": int(b), "step": float(step), "parameters": {}}
    jac = np.zeros((s.shape[2], d))
    for i, name in enumerate(names):
        change = s[1 + i] - s[1 + d + i]  # [B, k]: each pile's change over the 2h step (common random numbers)
        mean = change.mean(axis=0)
        se = change.std(axis=0, ddof=1) / math.sqrt(b) if b > 1 else np.zeros_like(mean)
        jac[:, i] = mean / (2 * step)
        signal, noise = float(np.sqrt(np.sum(w * mean ** 2))), float(np.sqrt(np.sum(w * se ** 2)))
        with np.errstate(divide="ignore", invalid="ignore"):
            z = np.where(se > 0, np.abs(mean) / np.where(se > 0, se, 1.0), np.where(mean != 0, np.inf, 0.0))
        k = int(np.argmax(z))
        measurable = b >= MIN_PILES or (b >= 1 and noise == 0.0)
        needed = float(stats.t.ppf(1 - FALSE_ALARM / (2 * len(z)), b - 1)) if b > 1 else 0.0
        out["parameters"][name] = {
            "signal": signal, "noise": noise, "ratio": signal / noise if noise > 0 else (math.inf if signal else 0.0),
            "z": float(z[k]), "needed": needed, "identifiable": bool(z[k] >= needed and z[k] > 0) if measurable else None,
            "most_moved": labels[k], "change": float(mean[k]), "change_stderr": float(se[k]),
            "error": float(1.0 / math.sqrt(w[k])) if w[k] > 0 else math.nan}
    hessian = (jac.T * w) @ jac
    if d > 1 and np.all(np.isfinite(hessian)) and np.linalg.matrix_rank(hessian) == d:
        inv = np.linalg.inv(hessian)
        corr = inv / np.sqrt(np.outer(np.diag(inv), np.diag(inv)))
        out["correlation"] = corr.tolist()
        out["poorly_told_apart"] = [[names[i], names[j]] for i in range(d) for j in range(i + 1, d)
                                    if abs(corr[i, j]) > TOLD_APART]
    elif d > 1:
        out["correlation"], out["poorly_told_apart"] = None, [list(names)]
    out["identifiable"] = all(p["identifiable"] is not False for p in out["parameters"].values())
    return out


def first_pass_lines(report: dict) -> list[str]:
    """One line per parameter (and one for a pair poorly told apart)."""
    lines = []
    pct = 100 * (math.exp(report["step"]) - 1)
    for name, p in report["parameters"].items():
        times = f"{p['z']:.1f}x" if p["z"] < 1000 else "over 1000x"  # common random numbers: no noise at all
        moved = (f"at {report['disks']} disks, {name} from -{pct:.2g} % to +{pct:.2g} % moves {p['most_moved']} "
                 f"most, by {p['change']:+.3g} +- {p['change_stderr']:.2g} (the target's spread "
                 f"{p['error']:.2g}): {times} its noise")
        if p["identifiable"] is None:
            lines.append(moved + f", not judged: {report['piles']} piles cannot measure the noise ({MIN_PILES} or "
                                 "more can)")
        elif p["identifiable"]:
            lines.append(moved + (f" ({p['needed']:.1f}x needed)" if report["piles"] > 1 else " (one pile: no noise)")
                         + ": identifiable")
        else:
            lines.append(moved + f" ({p['needed']:.1f}x needed): the target cannot identify {name} at this size")
    for a, b in report.get("poorly_told_apart") or []:
        corr = report.get("correlation")
        how = "" if corr is None else (
            f" (their estimates correlate at {np.asarray(corr)[list(report['parameters']).index(a), list(report['parameters']).index(b)]:+.3f})")
        lines.append(f"{a} and {b} move the statistics alike{how}: the target tells them poorly apart; fit one, "
                     "or add a statistic that moves only one")
    return lines


NOISE_FLOOR_STEPS = 3
"""How many last steps must each lie within twice their standard error, and
not all one way, for a fit to have reached its noise floor."""


def at_noise_floor(history: list) -> bool:
    """Whether a Gauss-Newton fit's last `NOISE_FLOOR_STEPS` steps (as proposed,
    before damping) each lie
    within twice their own standard error (the 95 % band of a step taken at
    the optimum, where the step is the noise) and, in every parameter, do not
    all go one way (a drift, not a wander): further iterations would move the
    estimate by its noise, not towards a better one."""
    recent = history[-NOISE_FLOOR_STEPS:]
    if len(recent) < NOISE_FLOOR_STEPS:
        return False
    steps = np.array([np.asarray(h["proposed_step"], float) if "proposed_step" in h else
                      np.asarray(h["next_theta"], float) - np.asarray(h["theta"], float) for h in recent])
    se = np.array([np.asarray(h.get("step_stderr", [math.nan] * steps.shape[1]), float) for h in recent])
    if not np.all(np.isfinite(se)) or not np.all(se > 0):
        return False
    within = np.all(np.abs(steps) < 2 * se)
    drifting = np.any(np.all(steps > 0, axis=0) | np.all(steps < 0, axis=0))
    return bool(within and not drifting)


def of_record(record: dict) -> dict:
    """The verdict of a fit from its fit.json record (`EnsembleFitResult.to_json`),
    as `ensemble_fit.fit` would judge it now."""
    from jaxpile.fit.ensemble_targets import EnsembleTarget
    from jaxpile.fit.stats import weights

    target = EnsembleTarget.from_json(record["target"])
    history = record["history"]
    converged = bool(history) and bool(history[-1].get("converged"))
    message = record.get("message", "") if not str(record.get("message", "")).startswith("not converged in") else ""
    return verdict(history, np.asarray(record["jacobian"], float), weights(target),
                   np.asarray(record["fitted_members"], float), target, list(record["names"]), converged, message,
                   int(record.get("steps", len(history))))


def verdict(history: list, jacobian: np.ndarray, w: np.ndarray, fitted_members: np.ndarray, target, names: list,
            converged: bool, message: str, steps: int) -> dict:
    """The fit's verdict: converged or not and why (`tolerance`, `noise
    floor`: `at_noise_floor`, or the fit's own `noise_stop`,
    `budget`: iterations spent, or `stopped`: `message`); the loss path; each
    fitted statistic against the target in units of its error (`misfit`), the
    lack-of-fit chi^2 and its p-value; the Jacobian's rank and conditioning;
    and whether the interval can be trusted, with the reasons it cannot."""
    from scipy import stats

    d = len(names)
    last = history[-1] if history else {}
    step = np.abs(np.asarray(last["proposed_step"], float) if "proposed_step" in last else
                  np.asarray(last.get("next_theta", []), float) - np.asarray(last.get("theta", []), float))
    step_se = np.asarray(last.get("step_stderr", [math.nan] * d), float)
    if converged:
        why = "noise floor" if last.get("stopped_by") == "noise" else "tolerance"
    elif message:
        why = "stopped"
    elif at_noise_floor(history):
        why, converged = "noise floor", True
    else:
        why = "budget"
    members = np.asarray(fitted_members, float)
    b = len(members)
    error = target_error(target)
    variance = members.var(axis=0, ddof=1) / b if b > 1 else np.zeros(members.shape[1])
    total = np.sqrt(error ** 2 + variance)
    r = members.mean(axis=0) - np.asarray(target.mean, float)
    misfit = np.where(total > 0, r / np.where(total > 0, total, 1.0), np.nan)
    dof = len(r) - d
    known = np.isfinite(misfit)
    chi2 = float(np.sum(misfit[known] ** 2))
    p = float(stats.chi2.sf(chi2, dof)) if dof > 0 and known.all() else math.nan
    jac = np.asarray(jacobian, float)
    hessian = (jac.T * w) @ jac if np.all(np.isfinite(jac)) else np.full((d, d), np.nan)
    measured = bool(np.all(np.isfinite(hessian)))  # a fit without its final interval measures no Jacobian
    rank = int(np.linalg.matrix_rank(hessian)) if measured else d
    condition = float(np.linalg.cond(hessian)) if measured and rank == d else math.inf
    loss = [h["loss"] for h in history]
    doubts = []
    if not converged:
        doubts.append("the fit did not converge" + (f" ({message})" if message else
                                                     f" in {steps} iterations: its last step was "
                                                     f"{float(step.max()) if step.size else math.nan:.3g} in log units"))
    if not measured:
        doubts.append("no interval was measured (its final central differences were not run)")
    elif rank < d:
        doubts.append(f"the Jacobian has rank {rank} < {d}: a parameter does not move the statistics")
    if math.isfinite(p) and p < LACK_OF_FIT_P:
        doubts.append(f"the model does not fit the target (chi^2 = {chi2:.3g} on {dof} degrees of freedom, "
                      f"p = {p:.2g}): the interval, which assumes it does, is too narrow")
    return {"converged": bool(converged), "why": why, "message": message, "iterations": len(history),
            "last_step": step.tolist(), "last_step_stderr": step_se.tolist(), "loss_path": loss,
            "misfit": dict(zip(target.labels, misfit.tolist())), "chi2": chi2, "dof": dof, "p_value": p,
            "jacobian_rank": rank, "condition": condition, "interval_trusted": not doubts, "doubts": doubts}


def verdict_lines(v: dict) -> list[str]:
    """The verdict in a few sentences."""
    how = {"tolerance": "converged (its last step below the tolerance)",
           "noise floor": f"converged to the noise floor (its last {NOISE_FLOOR_STEPS} steps within twice their "
                          "standard errors, not all one way)",
           "budget": f"did NOT converge: its {v['iterations']} iteration(s) were spent",
           "stopped": f"did NOT converge: it stopped ({v['message']})"}[v["why"]]
    worst = max(v["misfit"].items(), key=lambda kv: abs(kv[1]) if math.isfinite(kv[1]) else -1, default=None)
    fit_line = (f"the fitted statistics sit {math.sqrt(v['chi2'] / max(len(v['misfit']), 1)):.2g} errors from the "
                f"target (rms), the farthest {worst[0]} at {worst[1]:+.2g}"
                if worst is not None and math.isfinite(worst[1]) else "the misfit has no error to be judged in")
    if math.isfinite(v["p_value"]):
        fit_line += f"; chi^2 = {v['chi2']:.3g} on {v['dof']} degrees of freedom (p = {v['p_value']:.2g})"
    trust = ("the interval can be trusted" if v["interval_trusted"]
             else "the interval cannot be trusted: " + "; ".join(v["doubts"]))
    path = [x for x in v["loss_path"] if math.isfinite(x)]
    went = "" if len(path) < 2 else (f"; the loss went {path[0]:.3g} -> {path[-1]:.3g} over its iterations"
                                     + (" (it rose)" if path[-1] > path[0] else ""))
    return [f"the fit {how}{went}", fit_line, trust]


__all__ = ["FALSE_ALARM", "NOISE_FLOOR_STEPS", "at_noise_floor", "of_record", "LACK_OF_FIT_P", "MIN_PILES", "TOLD_APART", "first_pass", "first_pass_lines",
           "target_error", "verdict", "verdict_lines"]
