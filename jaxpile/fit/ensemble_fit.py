"""Fitting law parameters to the ensemble a protocol builds.

A pile built at random (a box emptied by an avalanche, a poured heap, a dropped
pile) is one draw from the distribution a protocol makes at given law
parameters, so the fit compares a target with the *ensemble mean* of per-pile
statistics (an angle of repose, a binned base-force profile):

    F(theta) = mean_k w_k (mean_b s_bk(exp theta) - t_k)^2,

over log-parameters theta, with w_k = 1 / (the target's pile-to-pile spread of
s_k)^2, so every statistic counts in units of its own noise. Every ensemble is
run with the same seeds at every theta (common random numbers), so that a
difference between two thetas is not buried under that between two packings.

The gradient through a chaotic construction explodes (docs/gradients.md), so
the estimators use the construction as a black box, batched:

- `"central"`: central differences of the ensemble means at theta +- h e_i
  (`estimators.central_from_members`), all 2d + 1 ensembles in one batched run;
  their Jacobian J drives the default Gauss-Newton step theta <- theta -
  (J^T W J)^-1 J^T W r (r: the mean minus the target), clipped to `max_step`.
- `"smoothing"` (`estimators.antithetic_smoothing`) and `"truncated"`
  (`estimators.truncated_pathwise` over `construction.Construction`: the pour's
  base profile), for an optax optimiser; the truncated gradient was wrong in
  sign on 40-disk heaps (docs/fitting.md#the-estimator-study).

The answer's confidence interval comes from the ensembles' own spread: near the
optimum theta_hat is linear in the two ensemble means, so (the sandwich)
Cov(theta_hat) = H^-1 J^T W (Sigma_fit / B + Sigma_target / B_t) W J H^-1 with
H = J^T W J and Sigma the covariance of one pile's statistics. None of this is
in the three papers: Gauss-Newton with Levenberg-Marquardt damping (Levenberg
1944, Marquardt 1963); the sandwich covariance of an M-estimator (Huber 1967,
White 1982) with a Student-t quantile for B - 1 degrees of freedom; for a
deterministic pile, the nonlinear-least-squares covariance s^2 H^-1
(tests/test_ensemble_fit.py checks each on a toy whose answer is known).

A fit checkpoints its history to JSON before its first iteration and after
every one; `resume` replays it (optax states rebuilt from the recorded
gradients, so the resumed fit is step for step the uninterrupted one), and
`batch_checkpoint` saves the running batch of piles as a sweep does, for
iterations that outlast a working session. The ensembles are built in
`ensemble_runs` (`Runner`, `Statistics`) and the targets in `ensemble_targets`
(`EnsembleTarget`, `make_target`, `smid_novosad_target`); their names are
re-exported here, so one import serves a fit.
"""

from __future__ import annotations

import json
import math
import os
import time
import warnings
from typing import Callable, NamedTuple, Sequence

import jax
import jax.numpy as jnp
import numpy as np
import optax

import jaxpile.fit.construction as construction
import jaxpile.fit.estimators as estimators
import jaxpile.fit.regression as regression
import jaxpile.fit.verdict as verdict
from jaxpile import config, distributed, io
from jaxpile.errors import InputError
from jaxpile.fit.ensemble_runs import Runner, Statistics
from jaxpile.fit.ensemble_runs import MissingEverywhere, fill_missing, run_saved
from jaxpile.fit.ensemble_targets import EnsembleTarget, make_target, smid_novosad_target
from jaxpile.fit.stats import t_quantile, weights
from jaxpile.fit.optimise import UPPER_BOUNDS
from jaxpile.laws import granular
from jaxpile.ranges import COUNT, POSITIVE

ESTIMATORS = ("central", "smoothing", "truncated")


def objective_for(target: EnsembleTarget, w: np.ndarray) -> Callable:
    """`[k] ensemble mean -> loss`: F of the module docstring, the mean of the
    weighted squared misses of the target's statistics."""
    t, w = jnp.asarray(target.mean), jnp.asarray(w)
    return lambda mean: jnp.mean(w * (mean - t) ** 2)


class EnsembleFitResult(NamedTuple):
    """A finished fit.

    Attributes:
      names: fitted parameters.
      values: `{name: fitted value}`.
      start: `{name: starting value}`.
      interval: `{name: (low, high)}` the 95 % confidence interval.
      stderr_log: `{name: standard error of log value}`.
      history: one dict per iteration (values, loss, its standard error, the
        gradient with its standard error, the ensembles' cost; with central
        differences also `points`, the 2d + 1 log-parameters run, and
        `point_means`, their ensembles' means: every ensemble a fit runs, for
        a regression over them).
      target: the `EnsembleTarget`.
      fitted_mean, start_mean: `[k]` ensemble means at the end and the start.
      fitted_members: `[B, k]` the fitted ensemble's piles.
      record: the set-up (protocol, law, estimator, optimiser, seeds, cost), and
        `regression`: the estimate from a line through all of the fit's
        ensembles (`jaxpile.fit.regression`), or None.
    """

    names: list
    values: dict
    start: dict
    interval: dict
    stderr_log: dict
    history: list
    target: EnsembleTarget
    fitted_mean: np.ndarray
    start_mean: np.ndarray
    fitted_members: np.ndarray
    record: dict

    def to_json(self) -> dict:
        return {"names": self.names, "values": self.values, "start": self.start,
                "interval": {k: list(v) for k, v in self.interval.items()}, "stderr_log": self.stderr_log,
                "history": self.history, "target": self.target.to_json(),
                "fitted_mean": self.fitted_mean.tolist(), "start_mean": self.start_mean.tolist(),
                "fitted_members": self.fitted_members.tolist(), **self.record}

    @classmethod
    def from_json(cls, record: dict) -> "EnsembleFitResult":
        """The result `to_json` wrote (fit.json): what `jaxpile show` redraws from."""
        own = ("names", "values", "start", "interval", "stderr_log", "history", "target", "fitted_mean",
               "start_mean", "fitted_members")
        return cls(list(record["names"]), dict(record["values"]), dict(record["start"]),
                   {k: tuple(v) for k, v in record["interval"].items()}, dict(record["stderr_log"]),
                   list(record["history"]), EnsembleTarget.from_json(record["target"]),
                   np.asarray(record["fitted_mean"], float), np.asarray(record["start_mean"], float),
                   np.asarray(record["fitted_members"], float),
                   {k: v for k, v in record.items() if k not in own})


def confidence(jacobian: np.ndarray, w: np.ndarray, members: np.ndarray, target: EnsembleTarget
               ) -> tuple[np.ndarray, float]:
    """The covariance `[d, d]` of the fitted log-parameters and the degrees of
    freedom of its estimate (for a Student-t interval).

    From the Jacobian `[k, d]` of the ensemble means, the fitted piles `[B, k]`
    and the target's: the sandwich in the module docstring, with B - 1 degrees
    of freedom (the smaller ensemble's). When neither side has any spread (one
    pile each, or a deterministic protocol whose piles are all the same), the
    nonlinear-least-squares covariance s^2 H^-1 from the weighted residual per
    degree of freedom (k - d): what the fit cannot explain, e.g. the rest
    tolerance."""
    jw = jacobian.T * w  # [d, k]
    hessian = jw @ jacobian
    d = hessian.shape[0]
    if not np.all(np.isfinite(hessian)) or np.linalg.matrix_rank(hessian) < d:
        return np.full(hessian.shape, np.nan), float("nan")
    inv = np.linalg.inv(hessian)

    def spread(piles):
        return piles is not None and len(piles) > 1 and float(np.ptp(np.asarray(piles), axis=0).max()) > 0

    def projected(piles):
        if not spread(piles):
            return np.zeros_like(hessian)
        g = piles @ jw.T  # [B, d]
        return np.atleast_2d(np.cov(g, rowvar=False)) / len(piles)

    error = None if target.error is None else np.nan_to_num(np.asarray(target.error, float))
    error = error if error is not None and np.any(error > 0) else None
    if not spread(members) and not spread(target.members) and error is None:
        r = np.asarray(members, float).mean(axis=0) - target.mean
        dof = max(len(r) - d, 1)
        return float(np.sum(w * r ** 2)) / dof * inv, float(dof)
    measured = np.zeros_like(hessian) if error is None else (jw * error ** 2) @ jw.T  # a measurement's own error
    sizes = [len(p) for p in (members, target.members) if spread(p)]
    dof = float(min(sizes) - 1) if sizes else math.inf  # a measurement's stated errors are taken as known
    return inv @ (projected(members) + projected(target.members) + measured) @ inv, dof


def _optimiser(name: str, lr: float):
    if not hasattr(optax, name) or not callable(getattr(optax, name)):
        raise InputError(f"unknown optimiser {name!r}: use gauss-newton or an optax optimiser (adam, sgd, ...).")
    return getattr(optax, name)(lr)


class Gradient(NamedTuple):
    """How an ensemble fit estimates its loss's gradient.

    Attributes:
      estimator: `"central"`, `"smoothing"` (module docstring) or
        `"truncated"`: the truncated pathwise gradient through the pour's
        construction (`construction.Construction`, windows of `window` steps,
        their sensitivities averaged); the base profile alone. Measured biased
        on 40-disk heaps (docs/fitting.md, the estimator study): for trying on others.
      step: central differences' h (log units; a chaotic pile needs ~0.2).
      sigma, pairs, key: the smoothing's width, antithetic pairs and random key.
      window: the truncated estimator's steps per sensitivity.
    """

    estimator: str = "central"
    step: float = 0.05
    sigma: float = 0.05
    pairs: int = 4
    key: int = 0
    window: int = 60


class Stopping(NamedTuple):
    """When an ensemble fit stops.

    Attributes:
      steps: iterations at most.
      tolerance: stop when a Gauss-Newton step is below this (log units).
      max_step: the largest change of a log-parameter per Gauss-Newton step.
      noise_stop: also stop when every component of a Gauss-Newton step is
        below its own standard error (the sandwich at that iterate: the spread
        of the fitted and the target piles). Off by default: the iterates
        wander by more than these standard errors, which leave out the
        finite-difference Jacobian's own noise, so on the pour recovery it
        stopped early with an interval that missed the truth (docs/fitting.md,
        "Stopping on the noise"; docs/choices.md, "Stopping an ensemble fit
        on its noise"). Every entry records `step_stderr` either way, and the
        verdict judges the last step against it.
    """

    steps: int = 6
    tolerance: float = 1e-3
    max_step: float = 0.3
    noise_stop: bool = False


class Saving(NamedTuple):
    """What an ensemble fit saves as it goes, and continues from.

    Attributes:
      checkpoint: a JSON path to write the history (and the first pass) to
        before the first iteration and after every one.
      resume: a checkpoint JSON of this fit to continue from.
      batch: `(path, every)`: each batch of piles the runner runs (an
        iteration's ensembles, the final ones) is saved to the `.npz` `path`
        every `every` steps (`batches.sweep`'s checkpoint), continued from it
        when the fit is resumed, and removed when the batch ends; without
        `resume` a file left there is removed first. The central and
        smoothing estimators' batches (the truncated estimator's rollouts are
        not saved).
    """

    checkpoint: str | None = None
    resume: str | None = None
    batch: tuple[str, int] | None = None


def fit(runner: Runner, names: Sequence[str], start: dict, target: EnsembleTarget, *, seeds,
        statistics: Statistics, gradient: Gradient = Gradient(), optimizer: str = "gauss-newton", lr: float = 0.1,
        stopping: Stopping = Stopping(), saving: Saving = Saving(), interval: bool = True,
        identifiability: str = "refuse", progress: Callable | bool | None = True) -> EnsembleFitResult:
    """Fits the law parameters `names` (positive; fitted as logs) so that the
    ensemble of `seeds` matches `target`.

    Args:
      runner: the protocol, law and set-up the ensembles are built with.
      names: parameters to fit; start: their starting values (and may hold no
        others: fixed parameters go in `runner.params`).
      target: from `make_target` (or `EnsembleTarget.from_json`).
      seeds: the fit's piles (never the target's).
      statistics: what each pile contributes (as the target was made).
      gradient: how the gradient is estimated (`Gradient`: central
        differences by default).
      optimizer: `"gauss-newton"` (central only) or an optax name (`adam`, `sgd`...).
      lr: the optax learning rate (log units).
      stopping: when to stop (`Stopping`: 6 iterations at most by default).
      saving: the history's checkpoint, a resume, the running batch (`Saving`).
      interval: run the final central differences for the confidence
        interval (2d + 1 more ensembles); False: NaN interval.
      identifiability: the first pass (`verdict.first_pass`, on the first
        central differences' ensembles, before any step) judges whether each
        parameter moves the statistics beyond their noise: `"refuse"` raises
        `InputError` with its numbers when one does not, `"warn"` says so and
        fits regardless. It also measures the errors a target lacks (a
        measurement without standard errors: one pile's spread at the start).
      progress: print the first pass, a line per iteration and the verdict
        (True), or a callable given each history entry.

    Returns:
      `EnsembleFitResult` (the interval from a final central-difference
      Jacobian at the fitted values; its record's `first_pass` and `verdict`).
    """
    for record_, kind in ((gradient, Gradient), (stopping, Stopping), (saving, Saving)):
        if not isinstance(record_, kind):
            raise InputError(f"{kind.__name__.lower()} must be an ensemble_fit.{kind.__name__}; got "
                             f"{type(record_).__name__}.")
    estimator, step, sigma, pairs, key, window = gradient
    steps, tolerance, max_step, noise_stop = stopping
    checkpoint, resume, batch_checkpoint = saving
    statistics, names, seeds, steps = _checked(runner, names, start, target, seeds, statistics, estimator,
                                               optimizer, steps, window)
    if identifiability not in ("refuse", "warn"):
        raise InputError(f"identifiability is refuse or warn; got {identifiability!r}.")
    theta = np.log(np.array([float(start[n]) for n in names]))
    opt = None if optimizer == "gauss-newton" else _optimiser(optimizer, lr)
    opt_state = None if opt is None else opt.init(jnp.asarray(theta))
    history: list = []
    record = {"protocol": runner.protocol, "law": runner.law_name(), "names": names, "start": dict(start),
              "estimator": estimator, "optimizer": optimizer, "seeds": seeds, "statistics": statistics.labels(),
              "steps": steps, "lr": lr, "step": step, "sigma": sigma, "pairs": pairs, "key": key,
              **({"window": int(window)} if estimator == "truncated" else {}),
              "max_step": max_step, "tolerance": tolerance, "noise_stop": noise_stop,
              "options": dict(runner.options or {}),
              "params": dict(runner.params or {}), "target_mean": [float(x) for x in target.mean],
              **({"reading": {"at": list(statistics.at), "bandwidth": statistics.bandwidth,
                              "normalised_by": statistics.normalised_by}} if statistics.at else {}),
              "settings": config.settings()}
    passed: dict = {}

    def save_history():
        if checkpoint is not None:
            _write_json(checkpoint, {**record, "history": history, "target": target.to_json(), **passed})

    if resume is not None:
        theta, opt_state, history, passed = _replay(resume, record, theta, opt, opt_state)
    else:
        save_history()  # a fit stopped in its first iteration resumes from here
    if batch_checkpoint is not None:
        COUNT.check("the batch checkpoint's interval", batch_checkpoint[1], scalar=True)
        if distributed.process_count() > 1:
            raise InputError("batch_checkpoint saves one process's batch: a distributed fit resumes from its "
                             "histories, at the end of an iteration.")
        if resume is None and os.path.exists(batch_checkpoint[0]):  # another fit's batch
            os.remove(batch_checkpoint[0])
    t0 = time.perf_counter()
    fitting = _Fitting(runner, names, seeds, statistics, target, weights(target), None, estimator, opt, step, sigma,
                       pairs, key, window, max_step, tolerance, noise_stop, batch_checkpoint, {}, progress is True)
    if not passed and history:  # a fit saved before fits had a first pass: resumed as it began
        passed = {"first_pass": {"report": None, "skipped": "resumed a fit saved before its first pass"}}
    elif not passed:
        passed = {"first_pass": _first_pass(fitting, theta, progress)}
    first = passed["first_pass"]
    if first.get("spread") is not None:  # the errors the target lacked, as the first pass measured them
        target = target._replace(spread=np.asarray(first["spread"], float), error=np.asarray(first["error"], float))
    w = weights(target)
    fitting = fitting._replace(target=target, w=w, objective=objective_for(target, w))
    if first.get("statistics") is not None and estimator == "central" and not history:
        fitting.cache[estimators.central_points(theta, step).tobytes()] = np.asarray(first["statistics"], float)
    save_history()
    report = first["report"]
    if progress is True:
        for line in verdict.first_pass_lines(report) if report else []:
            print(f"first pass: {line}", flush=True)
    if identifiability == "refuse" and report and not report["identifiable"]:
        bad = {n: p for n, p in report["parameters"].items() if p["identifiable"] is False}
        raise InputError(f"the target cannot identify {', '.join(bad)} at {report['disks']} disks (the first pass: "
                         + ", ".join(f"{n} moves {p['most_moved']} most, by {p['z']:.1f}x its noise where "
                                     f"{p['needed']:.1f}x is needed" for n, p in bad.items())
                         + "); use more disks, a larger ensemble or a wider difference step, or measure another "
                         "quantity (an angle, the profile), or fit regardless (--fit-anyway, "
                         "identifiability='warn').")
    message = ""
    done = bool(history) and history[-1].get("converged", False)
    for it in range(len(history), steps):
        if done:
            break
        try:
            entry, delta, opt_state, message = fitting.iteration(theta, it, opt_state,
                                                                 history[-1] if history else None)
        except MissingEverywhere as err:  # no mean to compare: the fit stops, its history kept, and says why
            kept = f"; its {len(history)} iteration(s) are kept in {checkpoint}" if checkpoint and history else ""
            raise MissingEverywhere(f"the fit stopped in iteration {it + 1}: {err}{kept}") from None
        history.append(entry)
        theta = theta + delta
        if progress is True:
            vals = ", ".join(f"{n} = {v:.5g}" for n, v in entry["values"].items())
            loss = ("" if not math.isfinite(entry["loss"]) else f"loss {entry['loss']:.4g}"
                    + (f" +- {entry['loss_stderr']:.2g}, " if math.isfinite(entry["loss_stderr"]) else ", "))
            left = f", {entry['missing']} pile statistic(s) missing, left out" if entry["missing"] else ""
            print(f"fit {it + 1}/{steps}: {vals}: {loss}step {np.round(delta, 4).tolist()} "
                  f"({entry['seconds']:.0f} s{left})", flush=True)
        elif callable(progress):
            progress(entry)
        save_history()
        if entry["converged"] or message:
            break
    record["first_pass"] = {k: v for k, v in first.items() if k != "statistics"}
    result = fitting.finish(theta, start, history, record, message, interval, steps, t0)
    if progress is True:
        for line in verdict.verdict_lines(record["verdict"]):
            print(f"verdict: {line}", flush=True)
    # the same answer from a line through every ensemble run (`regression`): the honest one in chaos
    estimate = regression.estimate(result, w)
    record["regression"] = None if estimate is None else estimate.to_json()
    return result


def _checked(runner: Runner, names, start: dict, target: EnsembleTarget, seeds, statistics: Statistics,
             estimator: str, optimizer: str, steps, window) -> tuple[Statistics, list, list, int]:
    """`fit`'s settings checked (before any pile runs): the statistics as the
    runner reads them, the names, the seeds and the steps."""
    statistics = runner.check(statistics)
    names = list(names)
    if not names or len(set(names)) != len(names):
        raise InputError(f"name the parameters to fit, each once; got {names!r}.")
    missing = [n for n in names if n not in start]
    if missing or set(start) - set(names):
        raise InputError(f"start must give exactly the fitted parameters {names}; got {sorted(start)}.")
    for n in names:
        POSITIVE.check(f"the starting {n}", start[n], scalar=True)
    bounded = sorted({n for n in names for bounds in UPPER_BOUNDS.values() if n in bounds})
    if bounded:
        raise InputError(f"{', '.join(bounded)} is bounded above, and the ensemble fit steps in log space, which "
                         "would cross the bound: fix it (--set), or fit it on one pile (--estimator pathwise, in "
                         "logit space).")
    if estimator not in ESTIMATORS:
        raise InputError(f"estimator must be one of {ESTIMATORS}; got {estimator!r}.")
    if estimator == "truncated":
        construction.check(runner, statistics)
        COUNT.check("window", window, scalar=True)
    if optimizer == "gauss-newton" and estimator != "central":
        raise InputError("Gauss-Newton needs the Jacobian of the means: use --estimator central, or an optax optimiser.")
    if isinstance(steps, bool) or int(steps) != steps or steps < 0:
        raise InputError(f"steps must be a whole number >= 0; got {steps!r}.")
    seeds = [int(s) for s in seeds]
    if not seeds:
        raise InputError("a fit needs at least one seed (2 or more for standard errors and an interval; one for "
                         "a deterministic pile, e.g. the lattice, whose interval then has zero width).")
    if set(seeds) & set(target.seeds or []):
        raise InputError(f"the fit's seeds overlap the target's ({sorted(set(seeds) & set(target.seeds))}): "
                         "a fit must not see the piles its target was made from.")
    if list(target.labels) != statistics.labels():
        raise InputError(f"the target holds the statistics {list(target.labels)}, this fit compares "
                         f"{statistics.labels()}: make the target with the same statistics.")
    here = runner.setting() if hasattr(runner, "setting") else None
    if target.setting is not None and here is not None and target.setting != here:
        raise InputError(f"the target was made with {target.setting}, this fit builds {here}: the piles must be "
                         "built the same way (only the fitted parameters may differ).")
    return statistics, names, seeds, int(steps)


def _replay(resume: str, record: dict, theta: np.ndarray, opt, opt_state):
    """`(theta, opt_state, history, passed)` after the iterations of the
    checkpoint `resume`, which this fit (`record`) must have written: the optax
    state is a function of the gradients seen, so it is rebuilt by replaying
    them; `passed`: the saved first pass, if it ended."""
    saved = io.read_json(resume, "an ensemble fit's checkpoint")
    if not isinstance(saved, dict) or not isinstance(saved.get("history"), list):
        raise InputError(f"{resume} is not an ensemble fit's checkpoint (no history in it).")
    # when to stop may change on resume; other JAX/XLA settings are said, not refused
    same = [k for k in record if k not in ("steps", "noise_stop", "settings")]
    differ = [k for k in same if json.dumps(saved.get(k), default=float) != json.dumps(record[k], default=float)]
    if differ:
        raise InputError(f"{resume} was written by another fit (its {', '.join(differ)} differ); resume it "
                         "with the command that made it.")
    if distributed.process_count() > 1:  # each process saved its own history: they must all be at one iteration
        at = distributed.gather([2 * len(saved["history"]) + int(bool(saved.get("first_pass")))])
        lengths = [a // 2 for a in at]
        if len(set(at)) > 1:
            raise InputError(f"the processes' checkpoints hold {', '.join(map(str, lengths))} iterations (a process "
                             "stopped between saves): copy the longest fit_checkpoint.json over the others, and resume.")
    settings_differ = config.differences(saved.get("settings"), record["settings"], batch=True)
    if settings_differ:
        warnings.warn(f"{resume} was written under other JAX/XLA settings ({'; '.join(settings_differ)}): the "
                      "fit goes on, and its next iterations are those of a fit under these settings.", stacklevel=3)
    history = []
    for entry in saved["history"]:
        theta = np.asarray(entry["next_theta"], float)
        if opt is not None:
            _, opt_state = opt.update(jnp.asarray(entry["gradient"]), opt_state, jnp.asarray(entry["theta"]))
        history.append(entry)
    return theta, opt_state, history, ({"first_pass": saved["first_pass"]} if saved.get("first_pass") else {})


def _first_pass(fitting: "_Fitting", theta: np.ndarray, progress) -> dict:
    """The first central differences' ensembles at `theta`, run once (the
    central estimator's first iteration reuses them): the errors a target
    lacks, taken as one pile's spread there, and `verdict.first_pass`."""
    t1 = time.perf_counter()
    if progress is True:
        print("first pass: is each parameter identifiable at this size?", flush=True)
    points = estimators.central_points(theta, fitting.step)
    s, _, info = fitting.run(points, fill=False)
    options = fitting.runner.options or {}
    spec = getattr(fitting.runner, "spec", None)  # a protocol's own pile size, not its padded disk count
    size = getattr(spec().make_options(options), "n", None) if spec is not None and "n" not in options else None
    disks = int(options.get("n") or size or info.get("n_particles", 0))
    scarce = {lab: int(c) for lab, c in zip(fitting.target.labels, info["missing_by_statistic"]) if 2 * c > s.shape[1]}
    if scarce:  # a statistic most piles lack at this size would soon be missing from all at some point
        raise InputError(f"at {disks} disks " + ", ".join(f"{lab!r} is missing from {c} of {s.shape[1]} piles"
                                                         for lab, c in scarce.items())
                         + " in the first pass's ensembles (heaps too small to read it): use more disks or other "
                         "statistics.")
    s, missing = fill_missing(s, fitting.statistics.labels())
    target, out = fitting.target, {"statistics": s.tolist(), "particle_steps": int(info["particle_steps"]),
                                   "missing": missing}
    unknown = ~np.isfinite(np.asarray(target.spread, float))
    pile = s[0].std(axis=0, ddof=1) if s.shape[1] > 1 else np.zeros(s.shape[2])
    if unknown.any():
        # the piles' spread stands in for a missing error (the measurement as one heap); where the piles have
        # none (one pile, or a deterministic protocol) the points weigh alike and the interval is least squares'
        # from the misfit (`confidence`), the error NaN: not known, not judged
        from_piles = bool(np.any(pile[unknown] > 0))
        given = np.asarray(target.error if target.error is not None else target.spread, float)
        target = target._replace(spread=np.where(unknown, pile if from_piles else 1.0, target.spread),
                                 error=np.where(np.isfinite(given), given, pile if from_piles else np.nan))
        out.update({"spread": target.spread.tolist(), "error": target.error.tolist(),
                    "errors_from_piles" if from_piles else "errors_from_misfit":
                        [lab for lab, u in zip(target.labels, unknown) if u]})
        if progress is True:
            print(f"first pass: the target gives no errors for {int(unknown.sum())} of its {len(unknown)} "
                  "statistics: " + ("each is taken as one simulated pile's spread at the start (the measurement "
                                    "as one heap)" if from_piles else "the piles have no spread to stand in, so "
                                    "they weigh alike and the interval comes from the misfit (least squares)"),
                  flush=True)
    out["report"] = verdict.first_pass(s, fitting.step, weights(target), target, fitting.names, disks)
    out["seconds"] = time.perf_counter() - t1
    return out


def _central_jacobian(s: np.ndarray, step: float) -> np.ndarray:
    """`[k, d]` the Jacobian of the ensemble means from the statistics `s`
    `[2d + 1, B, k]` at `estimators.central_points(theta, step)`."""
    d = (s.shape[0] - 1) // 2
    return (s[1:1 + d].mean(axis=1) - s[1 + d:].mean(axis=1)).T / (2 * step)


def _damped(proposed: np.ndarray, previous: dict | None) -> np.ndarray:
    """The Gauss-Newton step taken: `proposed`, except that a component which
    reverses the previous step is at most half that step's size (a step that
    undoes the last one bisects it instead: noisy Jacobians otherwise make the
    iterates cycle between two values, as they did on poured heaps,
    docs/calibrate.md). The proposal itself is what the stopping rules and
    the verdict judge."""
    if previous is None or "next_theta" not in previous:
        return proposed
    last = np.asarray(previous["next_theta"], float) - np.asarray(previous["theta"], float)
    reverses = proposed * last < 0
    half = 0.5 * np.abs(last)
    return np.where(reverses, np.clip(proposed, -half, half), proposed)


def _gauss_newton_step(jac: np.ndarray, w: np.ndarray, r: np.ndarray, max_step: float) -> tuple[np.ndarray, str]:
    """`(delta, message)`: the Gauss-Newton step for the residual `r` (the mean
    minus the target) with Levenberg-Marquardt damping, each component clipped
    to `max_step` on its own (a poorly determined parameter must not take a
    huge step nor shrink the others'); a zero step and why when the statistics
    do not move with the parameters."""
    d = jac.shape[1]
    hessian = (jac.T * w) @ jac
    if not np.any(hessian):
        return np.zeros(d), "the statistics do not move with the parameters (a zero Jacobian): nothing to fit"
    damped = hessian + 1e-3 * np.diag(np.diag(hessian)) + 1e-12 * np.trace(hessian) * np.eye(d)
    return np.clip(-np.linalg.solve(damped, (jac.T * w) @ r), -max_step, max_step), ""


class _Iterate(NamedTuple):
    """An iteration's ensembles: the gradient estimate, the statistics `[m,
    B, k]` of the m thetas run (None for the truncated estimator's rollouts),
    the piles left out of a statistic (`fill_missing`), the runs' `info`
    (`particle_steps`, `total_seconds`); with central differences also the
    thetas run, the Jacobian of the means and their value at theta."""

    estimate: estimators.Estimate
    s: np.ndarray | None
    missing: int
    info: dict
    points: np.ndarray | None = None
    jac: np.ndarray | None = None
    mean: np.ndarray | None = None


class _Fitting(NamedTuple):
    """What stays fixed over a fit's iterations (`fit`'s arguments, checked,
    the weights `w` and the `objective` of the ensemble mean)."""

    runner: Runner
    names: list
    seeds: list
    statistics: Statistics
    target: EnsembleTarget
    w: np.ndarray
    objective: Callable
    estimator: str
    opt: object
    step: float
    sigma: float
    pairs: int
    key: int
    window: int
    max_step: float
    tolerance: float
    noise_stop: bool
    batch_checkpoint: tuple[str, int] | None = None
    cache: dict | None = None  # statistics already run, by their thetas' bytes (the first pass's)
    show: bool = False  # a line before each batch, and the sweep's progress bar in a terminal

    def params_of(self, theta) -> dict:
        return {n: float(v) for n, v in zip(self.names, np.exp(theta))}

    def run(self, thetas, fill: bool = True):
        """`(s, missing, info)`: the statistics `[m, B, k]` of the seeds at
        each of the m `thetas` (one batched run), missing ones filled; the
        batch saved as it runs and continued from its save (`fit`'s
        `batch_checkpoint`)."""
        thetas = np.asarray(thetas, float)
        ran = (self.cache or {}).pop(thetas.tobytes(), None)
        if ran is not None:
            s, info = ran, {"particle_steps": 0, "total_seconds": 0.0}
        else:
            if self.show:
                print(f"  running {len(thetas)} ensemble(s) of {len(self.seeds)} piles ({len(thetas) * len(self.seeds)} "
                      "piles in one batch)", flush=True)
            s, info = run_saved(self.runner, [self.params_of(t) for t in thetas], self.seeds, self.statistics,
                                self.batch_checkpoint, progress=None if self.show else False)
        info = {**info, "missing_by_statistic": np.isnan(s).any(axis=0).sum(axis=0).tolist()}
        if not fill:
            return s, 0, info
        try:
            s, missing = fill_missing(s, self.statistics.labels())
        except MissingEverywhere as err:
            at = thetas[err.point if err.point is not None else 0]
            where = ", ".join(f"{n} = {v:.4g}" for n, v in self.params_of(at).items())
            raise MissingEverywhere(f"{err.name} is missing from every pile at {where} (no pile had a surface to "
                                    "measure, none moved, or the heaps were too narrow to read it): choose other "
                                    "statistics or a larger pile") from None
        return s, missing, info

    def ensembles(self, theta: np.ndarray, it: int) -> _Iterate:
        """Iteration `it`'s ensembles around `theta` and the gradient estimate from them."""
        if self.estimator == "central":
            points = estimators.central_points(theta, self.step)
            s, missing, info = self.run(points)
            est = estimators.central_from_members(s, self.objective, self.step)
            return _Iterate(est, s, missing, info, points, _central_jacobian(s, self.step), s[0].mean(axis=0))
        if self.estimator == "truncated":  # one host run at theta sizes the rollouts, then the windows
            t1 = time.perf_counter()
            c = construction.Construction(self.runner, self.seeds, self.statistics, self.names, theta)
            est = estimators.truncated_pathwise(c.advance, c.statistics, self.objective, theta, c.start, c.steps,
                                                int(self.window), combine="mean")
            info = {"particle_steps": c.particle_steps(), "total_seconds": time.perf_counter() - t1}
            return _Iterate(est, None, 0, info)
        cache = {}

        def batch(ts):
            cache["s"], cache["missing"], cache["info"] = self.run(np.asarray(ts))
            return cache["s"]

        est = estimators.antithetic_smoothing(batch, self.objective, theta, jax.random.PRNGKey(int(self.key) + it),
                                              sigma=self.sigma, pairs=self.pairs)
        return _Iterate(est, cache["s"], cache["missing"], cache["info"])  # the smoothing does not run theta itself

    def iteration(self, theta: np.ndarray, it: int, opt_state, previous: dict | None = None):
        """`(entry, delta, opt_state, message)`: iteration `it` from `theta`
        (after the history entry `previous`), its history entry and step, and
        why the fit must stop ("" to go on)."""
        ens = self.ensembles(theta, it)
        gradient = np.asarray(ens.estimate.gradient, float)
        message, proposed = "", None
        if self.opt is None:
            proposed, message = _gauss_newton_step(ens.jac, self.w, ens.mean - self.target.mean, self.max_step)
            delta = _damped(proposed, previous)
        elif not np.all(np.isfinite(gradient)):  # a pile's NaN would spoil the optimiser's state for good
            message = f"the {self.estimator} gradient is not finite ({gradient.tolist()}): stopped before stepping"
            delta = np.zeros(len(self.names))
        else:
            updates, opt_state = self.opt.update(jnp.asarray(gradient), opt_state, jnp.asarray(theta))
            delta = np.asarray(updates, float)
        converged, why, step_stderr = self.stop(ens, delta if proposed is None else proposed, message)
        base = ens.s[0] if ens.jac is not None else None  # the piles at theta itself (central differences)
        loss_se = estimators.loss_stderr(base, self.objective) if base is not None else float("nan")
        entry = {"iteration": it, "theta": theta.tolist(), "values": self.params_of(theta),
                 "loss": float(ens.estimate.value), "loss_stderr": loss_se, "gradient": gradient.tolist(),
                 "gradient_stderr": np.asarray(ens.estimate.stderr, float).tolist(),
                 "ensembles": int(ens.estimate.evaluations), "particle_steps": int(ens.info["particle_steps"]),
                 "missing": ens.missing, "mean": None if ens.mean is None else ens.mean.tolist(),
                 "next_theta": (theta + delta).tolist(),
                 **({} if proposed is None else {"proposed_step": proposed.tolist()}),
                 **({} if ens.points is None else {"points": ens.points.tolist(),
                                                   "point_means": ens.s.mean(axis=1).tolist()}),
                 "converged": converged, "stopped_by": why, "step_stderr": step_stderr,
                 "seconds": ens.info["total_seconds"]}
        return entry, delta, opt_state, message

    def stop(self, ens: _Iterate, delta: np.ndarray, message: str) -> tuple[bool, str, list]:
        """`(converged, stopped_by, step_stderr)`: a Gauss-Newton step below
        the tolerance, or (`noise_stop`) below its own standard error in every
        component; the standard errors (NaN but for Gauss-Newton)."""
        gauss_newton = self.opt is None and not message
        converged = bool(gauss_newton and np.max(np.abs(delta)) < self.tolerance)
        step_stderr, why = [float("nan")] * len(self.names), "tolerance" if converged else ""
        if gauss_newton:  # the fitted piles' noise alone: the target's own error does not change between steps
            cov, _ = confidence(ens.jac, self.w, ens.s[0], self.target._replace(members=None, error=None))
            if np.all(np.isfinite(cov)):
                step_stderr = np.sqrt(np.clip(np.diag(cov), 0, None)).tolist()
                if self.noise_stop and not converged and np.all(np.abs(delta) < np.asarray(step_stderr)):
                    converged, why = True, "noise"
        return converged, why, step_stderr

    def finish(self, theta: np.ndarray, start: dict, history: list, record: dict, message: str, interval: bool,
               steps: int, t0: float) -> EnsembleFitResult:
        """The result at `theta`, its interval from a central-difference
        Jacobian there (`interval`; else NaN), and `record` completed."""
        names, d, target, w = self.names, len(self.names), self.target, self.w
        final_points = estimators.central_points(theta, self.step) if interval else theta[None]
        s, _, info = self.run(final_points)
        if interval:
            jac = _central_jacobian(s, self.step)
            cov, dof = confidence(jac, w, s[0], target)
        else:
            jac, cov, dof = np.full((s.shape[-1], d), np.nan), np.full((d, d), np.nan), float("nan")
        se = np.sqrt(np.clip(np.diag(cov), 0, None)) if np.all(np.isfinite(cov)) else np.full(d, np.nan)
        z = t_quantile(dof)
        bounds = {n: (float(np.exp(theta[i] - z * se[i])), float(np.exp(theta[i] + z * se[i])))
                  for i, n in enumerate(names)}
        # how strongly each parameter moves the weighted statistics (per unit log value): one that barely
        # moves them is not determined by this target, whatever its interval says
        sensitivity = np.sqrt(np.sum(w[:, None] * jac ** 2, axis=0))
        converged = bool(history) and bool(history[-1]["converged"])
        judged = verdict.verdict(history, jac, w, s[0], target, names, converged, message, steps)
        record.update({"final_points": final_points.tolist(), "final_point_means": s.mean(axis=1).tolist(),
                       "final_loss": float(self.objective(jnp.asarray(s[0].mean(axis=0)))),
                       "final_loss_stderr": estimators.loss_stderr(s[0], self.objective),
                       "jacobian": jac.tolist(), "sensitivity": dict(zip(names, sensitivity.tolist())),
                       "interval_dof": dof, "interval_quantile": z, "converged": judged["converged"],
                       "verdict": judged,
                       "message": message or ("" if judged["converged"] or self.opt is not None else
                                              f"not converged in {steps} iterations: the interval is at the last one"),
                       "fit_seconds": time.perf_counter() - t0,
                       "particle_steps": int(sum(h["particle_steps"] for h in history) + info["particle_steps"]
                                             + record.get("first_pass", {}).get("particle_steps", 0))})
        line = granular.line_at(record["law"], {**record.get("params", {}), **self.params_of(theta)})
        if line is not None:  # the fitted law as a LAMMPS pair_coeff line, to take back
            record["lammps_pair_coeff"] = line
        first = history[0]["mean"] if history and history[0].get("mean") is not None else None
        start_mean = np.asarray(first, float) if first is not None else np.full(len(target.mean), np.nan)
        return EnsembleFitResult(names, self.params_of(theta), {n: float(start[n]) for n in names}, bounds,
                                 {n: float(se[i]) for i, n in enumerate(names)}, history, target,
                                 s[0].mean(axis=0), start_mean, s[0], record)


def _write_json(path: str, record: dict) -> None:
    tmp = f"{path}.tmp"
    with open(tmp, "w") as fh:
        json.dump(record, fh, indent=1, default=float)  # numpy scalars in options or params
    os.replace(tmp, path)


def figure(result: EnsembleFitResult, path=None):
    """The fit on one page: the parameters over the iterations with the final
    95 % interval, the estimate through all ensembles beside it (open diamond)
    and the truth of a synthetic target, the loss with its
    standard error, and the statistics of the target, the start and the fit
    (the base profile with its one-pile band where there is one)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names, hist = result.names, result.history
    fig, axes = plt.subplots(1, 3, figsize=(14, 4))
    it = np.arange(len(hist) + 1)
    for i, n in enumerate(names):
        path_values = [h["values"][n] for h in hist] + [result.values[n]]
        line, = axes[0].plot(it, np.asarray(path_values) / result.start[n], "o-", label=n)
        lo, hi = result.interval[n]
        axes[0].errorbar([it[-1]], [result.values[n] / result.start[n]],
                         yerr=[[(result.values[n] - lo) / result.start[n]], [(hi - result.values[n]) / result.start[n]]],
                         color=line.get_color(), capsize=4)
        through_all = result.record.get("regression")
        if through_all is not None:  # the line through every ensemble (jaxpile.fit.regression), beside it
            v, (lo, hi) = through_all["values"][n], through_all["interval"][n]
            axes[0].errorbar([it[-1] + 0.25], [v / result.start[n]], fmt="D", mfc="none", capsize=4,
                             yerr=[[(v - lo) / result.start[n]], [(hi - v) / result.start[n]]],
                             color=line.get_color(), label=f"{n} through all ensembles")
        truth = (result.target.truth or {}).get(n)
        if truth is not None:
            axes[0].axhline(truth / result.start[n], color=line.get_color(), ls=":", label=f"{n} truth")
    axes[0].set(xlabel="iteration", ylabel="value / start", title="parameters (95 % interval at the end)")
    axes[0].legend(fontsize=8)
    loss = np.array([h["loss"] for h in hist] + [result.record["final_loss"]])
    err = np.array([h["loss_stderr"] for h in hist] + [result.record["final_loss_stderr"]])
    axes[1].errorbar(it, loss, yerr=err, fmt="o-")
    axes[1].set(xlabel="iteration", ylabel="loss (per-pile spread units^2)", yscale="log", title="loss +- s.e.")
    labels = list(result.target.labels)
    profile = [i for i, lab in enumerate(labels) if lab.startswith("normal[")]
    ax = axes[2]
    if profile:
        at = [lab.split("x/B=")[1].rstrip("]") for lab in (labels[i] for i in profile) if "x/B=" in lab]
        x = np.asarray(at, float) if len(at) == len(profile) else (np.arange(len(profile)) + 0.5) / len(profile)
        t = result.target
        ax.fill_between(x, t.mean[profile] - t.spread[profile], t.mean[profile] + t.spread[profile], alpha=0.2,
                        color="k", label="target +- its error" if t.error is not None else "target +- one pile")
        ax.plot(x, t.mean[profile], "ko-" if len(at) else "k-", label="target")
        ax.plot(x, result.start_mean[profile], "C1--", label="start")
        ax.plot(x, result.fitted_mean[profile], "C0-", label="fit")
        ax.set(xlabel="x / B", ylabel="normal base force / peak", title="ensemble-mean base profile")
    else:  # each statistic in units of its target's spread: a dip of 0.25 and an angle of 32.6 deg on one axis
        k, t = np.arange(len(labels)), result.target
        spread = np.where(t.spread > 0, t.spread, 1.0)
        ax.errorbar(k - 0.15, np.zeros(len(labels)), yerr=np.ones(len(labels)), fmt="ks", label="target +- its spread")
        ax.plot(k, (result.start_mean - t.mean) / spread, "C1o", label="start")
        sd = result.fitted_members.std(axis=0, ddof=1) / spread if len(result.fitted_members) > 1 else None
        ax.errorbar(k + 0.15, (result.fitted_mean - t.mean) / spread, yerr=sd, fmt="C0o", label="fit +- one pile")
        ax.set_xticks(k, labels, rotation=20, fontsize=8)
        ax.set(ylabel="(mean - target) / spread", title="ensemble means against the target")
    ax.legend(fontsize=8)
    judged = result.record.get("verdict")
    said = "" if judged is None else "\n" + verdict.verdict_lines(judged)[0] + (
        "; the interval can be trusted" if judged["interval_trusted"] else "; the interval cannot be trusted")
    fig.suptitle(f"{result.record['protocol']} / {result.record['law']}: fit of {', '.join(names)} "
                 f"({result.record['estimator']}, {result.record['optimizer']}, B = {len(result.record['seeds'])})"
                 + said, color="k" if judged is None or judged["interval_trusted"] else "firebrick")
    fig.tight_layout()
    if path is not None:
        fig.savefig(path, dpi=110)
        plt.close(fig)
    return fig


__all__ = ["ESTIMATORS", "EnsembleFitResult", "EnsembleTarget", "Gradient", "Runner", "Saving", "Statistics",
           "Stopping", "confidence", "figure", "fit", "make_target", "objective_for", "smid_novosad_target", "weights"]
