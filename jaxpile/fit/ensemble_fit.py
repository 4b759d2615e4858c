"""Fitting law parameters to the ensemble a protocol builds (issue 17).

A pile built at random (a box emptied by an avalanche, a poured heap, a
dropped pile) is one draw from the distribution that a protocol makes at
given law parameters. What a measurement can pin down is a property of that
distribution, so the fit compares a target with the *ensemble mean* of per-pile
statistics (an angle of repose, a binned base-force profile):

    F(theta) = mean_k w_k (mean_b s_bk(exp theta) - t_k)^2,

over log-parameters theta, with w_k = 1 / (the target's spread of s_k over
piles)^2, so every statistic counts in units of its own pile-to-pile noise.
Every ensemble is run with the same seeds at every theta (common random
numbers): a difference between two thetas is then not buried under the
difference between two packings.

The gradient through a chaotic construction explodes (issue 17's measurements),
so the estimators here use the construction as a black box, batched:

- `"central"`: central differences of the ensemble means at theta +- h e_i
  (`estimators.central_from_members`); all 2d + 1 ensembles in one batched
  run. They give the Jacobian J of the means as well, so the default
  optimiser is Gauss-Newton, theta <- theta - (J^T W J)^-1 J^T W r
  (r: the mean minus the target), with its steps clipped to `max_step`.
- `"smoothing"`: the gradient of the Gaussian-smoothed F from antithetic
  pairs (`estimators.antithetic_smoothing`), all pairs in one batched run;
  for an optax optimiser.
- `"truncated"`: the pathwise gradient through the construction cut into
  windows (`estimators.truncated_pathwise` over `construction.Construction`:
  the pour, its base profile alone); for an optax optimiser. Wrong in sign
  on 40-disk heaps in README's estimator study; there for trying elsewhere.

The answer carries a confidence interval from the ensembles' own spread: near
the optimum theta_hat is linear in the two ensemble means, so (the sandwich)
Cov(theta_hat) = H^-1 J^T W (Sigma_fit / B + Sigma_target / B_t) W J H^-1 with
H = J^T W J and Sigma the covariance of one pile's statistics.

None of these formulas is in the three papers (they fit no parameters):
Gauss-Newton with Levenberg-Marquardt damping (Levenberg 1944, Marquardt
1963); the sandwich covariance of an M-estimator (Huber 1967, White 1982),
with a Student-t quantile for its B - 1 degrees of freedom; for a
deterministic pile, the nonlinear-least-squares covariance s^2 H^-1.
tests/test_ensemble_fit.py checks each on a toy whose answer is known.

A fit checkpoints its history to JSON after every iteration; `resume` replays
it (optax states are rebuilt by replaying the recorded gradients, which makes
the resumed fit step for step the uninterrupted one).
"""

from __future__ import annotations

import json
import math
import os
import time
from typing import Callable, NamedTuple, Sequence

import jax
import jax.numpy as jnp
import numpy as np

from jaxpile import budget
from jaxpile.fit import estimators
from jaxpile.fit.stats import t_quantile, weights
from jaxpile.errors import InputError
from jaxpile.ranges import COUNT, POSITIVE

ESTIMATORS = ("central", "smoothing", "truncated")


class Statistics(NamedTuple):
    """What each pile contributes to the fit.

    Attributes:
      columns: scalar columns of the protocol's sweep row (`sweep.adapter(P)`'s
        measurement), e.g. `("repose_least_squares",)` or `("central_dip",)`.
      bins: > 0: the pile's base-force profile on this many bins across the
        protocol's fixed extent (`Adapter.extent`), normal force over its peak
        (`fit.smooth_base_profile`); 0: no profile.
      horizontal: the horizontal profile as well (on the same scale).
      bandwidth: the profile's smoothing width (default one bin).
    """

    columns: tuple = ()
    bins: int = 0
    horizontal: bool = True
    bandwidth: float | None = None

    def labels(self) -> list[str]:
        labels = list(self.columns)
        if self.bins:
            labels += [f"normal[{i}]" for i in range(self.bins)]
            if self.horizontal:
                labels += [f"horizontal[{i}]" for i in range(self.bins)]
        return labels


def _check_statistics(statistics: Statistics, adapter) -> Statistics:
    if not isinstance(statistics, Statistics):
        raise InputError(f"statistics must be an ensemble_fit.Statistics; got {type(statistics).__name__}.")
    statistics = statistics._replace(columns=tuple(statistics.columns))
    if int(statistics.bins) != statistics.bins or statistics.bins < 0:
        raise InputError(f"bins must be a whole number >= 0; got {statistics.bins!r}.")
    if not statistics.columns and not statistics.bins:
        raise InputError("a fit needs something to compare: name columns, or bins > 0 for the base profile.")
    if statistics.bins and adapter.extent is None:
        raise InputError("this protocol declares no base extent, so it cannot fit a base profile; fit columns.")
    if adapter.columns is not None:  # before a pile runs, where the protocol names its row (else after, per row)
        from jaxpile.sweep import MEMBER_COLUMNS

        known = adapter.columns | set(MEMBER_COLUMNS)
        unknown = [c for c in statistics.columns if c not in known]
        if unknown:
            raise InputError(f"the protocol's measurement has no column {unknown[0]!r}; it has {sorted(known)}.")
    return statistics


def _profile_hook(adapter, statistics: Statistics) -> Callable | None:
    if not statistics.bins:
        return None
    from jaxpile import fit

    def measure(sim, params, state, protocol):
        base, x_left, x_right = adapter.extent(protocol)
        load = fit.base_load(sim, params, state, base=base)
        profile = fit.smooth_base_profile(load, x_left=x_left, x_right=x_right, bins=int(statistics.bins),
                                          bandwidth=statistics.bandwidth)
        out = {"_profile_normal": np.asarray(profile.normal)}
        if statistics.horizontal:
            out["_profile_horizontal"] = np.asarray(profile.horizontal)
        return out

    return measure


def _row_statistics(row: dict, statistics: Statistics) -> np.ndarray:
    values = []
    for column in statistics.columns:
        if column not in row:
            raise InputError(f"the protocol's measurement has no column {column!r}; it has "
                             f"{sorted(k for k in row if not k.startswith('_'))}.")
        v = row[column]
        if v is not None and not isinstance(v, (int, float, np.number)):
            raise InputError(f"the column {column!r} is not a number per pile ({type(v).__name__}); fit a numeric one.")
        values.append(float(v) if v is not None else math.nan)
    if statistics.bins:
        values += list(row["_profile_normal"])
        if statistics.horizontal:
            values += list(row["_profile_horizontal"])
    return np.asarray(values, dtype=float)


class Runner(NamedTuple):
    """How the ensembles of a fit are built: everything `sweep.sweep` takes
    except the parameter points and seeds."""

    protocol: str
    law: str | None = None
    params: dict | None = None
    options: dict | None = None
    dt: float | None = None
    max_steps: int | None = None
    batch_size: int | None = None
    dtype: object = None

    def adapter(self):
        from jaxpile import sweep

        return sweep.adapter(self.protocol)

    def check(self, statistics: Statistics) -> Statistics:
        """The statistics, checked against what the protocol can measure."""
        return _check_statistics(statistics, self.adapter())

    def law_name(self) -> str:
        return self.law or self.adapter().default_law

    def setting(self) -> dict:
        """What a target made with this runner was made with (fixed law
        parameters other than the fitted ones are compared by name)."""
        return {"protocol": self.protocol, "law": self.law_name(), "options": dict(self.options or {})}

    def run(self, points: Sequence[dict], seeds, statistics: Statistics, progress=None, checkpoint=None,
            resume=None) -> tuple[np.ndarray, dict]:
        """`[len(points), B, k]` statistics (the B seeds at every point, one
        batched run) and the sweep's record (`n_particles`, `batch_steps`,
        `total_seconds` are used). `checkpoint`, `resume`: as `sweep.sweep`'s
        (a long batch saved as it runs, and continued)."""
        from jaxpile import sweep

        a = self.adapter()
        statistics = _check_statistics(statistics, a)
        seeds = [int(s) for s in seeds]
        if statistics.bins and seeds:  # each pile's profile is a [contacts, bins] array: refuse one too big first
            law = self.law_name()
            p = a.setup(law, seeds[0], self.dt or a.default_dt(law), {**(self.options or {}), "dtype": self.dtype})
            budget.check_host(24.0 * int(statistics.bins) * int(p.particles.count),
                              f"the base profile on {int(statistics.bins):,} bins of a {int(p.particles.count):,}-disk "
                              "pile", "Give fewer --bins.")
        result = sweep.sweep(self.protocol, self.law, points=list(points), seeds=seeds, params=self.params,
                             options=self.options, dt=self.dt, max_steps=self.max_steps,
                             batch_size=self.batch_size, progress=progress, dtype=self.dtype,
                             extra_measure=_profile_hook(a, statistics), checkpoint=checkpoint, resume=resume)
        rows = result.rows  # point-major: every seed of point 0, then of point 1, ...
        s = np.stack([_row_statistics(r, statistics) for r in rows]).reshape(len(points), len(seeds), -1)
        # the cost: the steps every pile ran (a batch also carries its finished piles, frozen)
        return s, {**result.info, "particle_steps": result.info["n_particles"] * sum(int(r["steps"]) for r in rows)}


def _fill_missing(s: np.ndarray) -> tuple[np.ndarray, int]:
    """`[m, B, k]` statistics with the piles that could not give one (NaN: e.g.
    no surface to fit an angle to, a tilted pile that never moved) left out of
    that statistic at *every* point, so a difference between two points
    compares the same piles (common random numbers). They are left out by
    taking, at each point, the mean of the piles that gave the statistic at all
    points, which moves no mean (it narrows the spread a little: the count of
    such (pile, statistic) pairs is returned, to report)."""
    s = np.array(s, dtype=float)
    bad = np.isnan(s).any(axis=0)  # [B, k]: missing at some point
    missing = int(bad.sum())
    if missing:
        if bad.all(axis=0).any():
            raise InputError("a statistic is missing from every pile at some point (e.g. no pile had a surface "
                             "to measure, or none moved); choose other statistics or a larger pile.")
        good = np.where(bad[None], np.nan, s)
        fill = np.nanmean(good, axis=1, keepdims=True)  # [m, 1, k]: the mean of the complete piles
        s = np.where(bad[None], np.broadcast_to(fill, s.shape), s)
    return s, missing


class EnsembleTarget(NamedTuple):
    """The target of a fit: ensemble means of `Statistics` with the spread of
    one pile about them.

    Attributes:
      labels: `[k]` what each statistic is.
      mean: `[k]` the target values.
      spread: `[k]` the standard deviation of one pile's statistic (weights).
      members: `[B_t, k]` the target's own piles (its sampling error enters
        the confidence interval), or None.
      source: where it came from.
      truth: the law parameters it was made with (a synthetic target), or None.
      seeds: the seeds of its piles (a fit must use others), or None.
      setting: the protocol, law, options and fixed parameters it was made
        with (a fit of another set-up is refused), or None (from data).
    """

    labels: list
    mean: np.ndarray
    spread: np.ndarray
    members: np.ndarray | None
    source: str
    truth: dict | None = None
    seeds: list | None = None
    setting: dict | None = None

    def to_json(self) -> dict:
        return {"labels": list(self.labels), "mean": self.mean.tolist(), "spread": self.spread.tolist(),
                "members": None if self.members is None else self.members.tolist(), "source": self.source,
                "truth": self.truth, "seeds": self.seeds, "setting": self.setting}

    @classmethod
    def from_json(cls, record: dict, where: str = "the record") -> "EnsembleTarget":
        need = ("labels", "mean", "spread")
        if not isinstance(record, dict) or any(k not in record for k in need):
            raise InputError(f"{where} is not an ensemble target: a target holds {', '.join(need)} (the "
                             "target.json a fit writes, or its fit.json).")
        members = record.get("members")
        return cls(list(record["labels"]), np.asarray(record["mean"], float), np.asarray(record["spread"], float),
                   None if members is None else np.asarray(members, float), record.get("source", ""),
                   record.get("truth"), record.get("seeds"), record.get("setting"))


def make_target(runner: Runner, truth: dict, seeds, statistics: Statistics, progress=None) -> EnsembleTarget:
    """A synthetic target: the ensemble of `seeds` at the law parameters
    `truth` (use seeds the fit never sees)."""
    s, _ = runner.run([truth], seeds, statistics, progress=progress)
    s, _ = _fill_missing(s)
    members = s[0]
    spread = members.std(axis=0, ddof=1) if members.shape[0] > 1 else np.ones(members.shape[1])
    return EnsembleTarget(statistics.labels(), members.mean(axis=0), spread, members,
                          f"{runner.protocol} ensemble of {len(members)} at {truth}", dict(truth),
                          [int(x) for x in seeds], runner.setting())


def smid_novosad_target() -> EnsembleTarget:
    """Smid & Novosad's central dip as an ensemble target (issue 17, item 5): the
    per-pile column `central_dip` (1 - the central bin over the lower flank
    maximum, `jaxpile.measure.heap.central_dip`; the drop and the pour measure it)
    at 0.25, the middle of the reported 0.20-0.30 (`fit.SMID_NOVOSAD_DIP_RANGE`),
    with half that range, 0.05, as its spread. A declared value, not piles: no
    members, no seeds, no setting (any protocol that measures the column may be
    fitted to it). With one statistic the spread only scales the loss."""
    from jaxpile.fit import SMID_NOVOSAD_DIP_RANGE

    low, high = SMID_NOVOSAD_DIP_RANGE
    return EnsembleTarget(["central_dip"], np.asarray([0.5 * (low + high)]), np.asarray([0.5 * (high - low)]), None,
                          f"Smid & Novosad's central dip, {low:.2f}-{high:.2f} below the maximum (Liffman et al. "
                          "1992, Introduction)")


def objective_for(target: EnsembleTarget, w: np.ndarray) -> Callable:
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

    if not spread(members) and not spread(target.members):
        r = np.asarray(members, float).mean(axis=0) - target.mean
        dof = max(len(r) - d, 1)
        return float(np.sum(w * r ** 2)) / dof * inv, float(dof)
    sizes = [len(p) for p in (members, target.members) if spread(p)]
    return inv @ (projected(members) + projected(target.members)) @ inv, float(min(sizes) - 1)


def _optimiser(name: str, lr: float):
    import optax

    if not hasattr(optax, name) or not callable(getattr(optax, name)):
        raise InputError(f"unknown optimiser {name!r}: use gauss-newton or an optax optimiser (adam, sgd, ...).")
    return getattr(optax, name)(lr)


def fit(runner: Runner, names: Sequence[str], start: dict, target: EnsembleTarget, *, seeds,
        statistics: Statistics, estimator: str = "central", optimizer: str = "gauss-newton", steps: int = 6,
        lr: float = 0.1, step: float = 0.05, sigma: float = 0.05, pairs: int = 4, key: int = 0, window: int = 60,
        max_step: float = 0.3, tolerance: float = 1e-3, noise_stop: bool = False,
        progress: Callable | bool | None = True,
        checkpoint: str | None = None, resume: str | None = None, interval: bool = True) -> EnsembleFitResult:
    """Fits the law parameters `names` (positive; fitted as logs) so that the
    ensemble of `seeds` matches `target`.

    Args:
      runner: the protocol, law and set-up the ensembles are built with.
      names: parameters to fit; start: their starting values (and may hold no
        others: fixed parameters go in `runner.params`).
      target: from `make_target` (or `EnsembleTarget.from_json`).
      seeds: the fit's piles (never the target's).
      statistics: what each pile contributes (as the target was made).
      estimator: `"central"`, `"smoothing"` (module docstring) or
        `"truncated"`: the truncated pathwise gradient through the pour's
        construction (`construction.Construction`, windows of `window` steps,
        their sensitivities averaged); the base profile alone. Measured biased
        on 40-disk heaps (README, the estimator study): for trying on others.
      optimizer: `"gauss-newton"` (central only) or an optax name (`adam`, `sgd`...).
      steps: iterations at most.
      lr: the optax learning rate (log units).
      step: central differences' h (log units); sigma, pairs, key: smoothing's.
      max_step: the largest change of a log-parameter per Gauss-Newton step.
      tolerance: stop when a Gauss-Newton step is below this (log units).
      noise_stop: also stop when every component of a Gauss-Newton step is
        below its own standard error (the sandwich at that iterate: the spread
        of the fitted and the target piles). Off by default: on the 40-disk
        pour recovery (16 heaps a side) it stopped at the 4th iterate, n =
        34.8 against the truth 41.3, its interval missing the truth; the
        iterates there wander by 1.5-3.5 of these standard errors (the
        finite-difference Jacobian's own noise is not in them). Every entry
        records `step_stderr` either way, to compare the steps with.
      progress: print a line per iteration (True), or a callable given each
        history entry.
      checkpoint: a JSON path to write the history to after every iteration.
      resume: a checkpoint JSON of this fit to continue from.
      interval: run the final central differences for the confidence
        interval (2d + 1 more ensembles); False: NaN interval.

    Returns:
      `EnsembleFitResult` (the interval from a final central-difference
      Jacobian at the fitted values).
    """
    statistics = runner.check(statistics)
    names = list(names)
    if not names or len(set(names)) != len(names):
        raise InputError(f"name the parameters to fit, each once; got {names!r}.")
    missing = [n for n in names if n not in start]
    if missing or set(start) - set(names):
        raise InputError(f"start must give exactly the fitted parameters {names}; got {sorted(start)}.")
    for n in names:
        POSITIVE.check(f"the starting {n}", start[n], scalar=True)
    if estimator not in ESTIMATORS:
        raise InputError(f"estimator must be one of {ESTIMATORS}; got {estimator!r}.")
    if estimator == "truncated":
        from jaxpile.fit import construction

        construction.check(runner, statistics)
        COUNT.check("window", window, scalar=True)
    if optimizer == "gauss-newton" and estimator != "central":
        raise InputError("Gauss-Newton needs the Jacobian of the means: use --estimator central, or an optax optimiser.")
    if isinstance(steps, bool) or int(steps) != steps or steps < 0:
        raise InputError(f"steps must be a whole number >= 0; got {steps!r}.")
    steps = int(steps)
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
    w = weights(target)
    objective = objective_for(target, w)
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
              "params": dict(runner.params or {}), "target_mean": [float(x) for x in target.mean]}
    if resume is not None:
        from jaxpile import io

        saved = io.read_json(resume, "an ensemble fit's checkpoint")
        if not isinstance(saved, dict) or not isinstance(saved.get("history"), list):
            raise InputError(f"{resume} is not an ensemble fit's checkpoint (no history in it).")
        same = [k for k in record if k not in ("steps", "noise_stop")]  # when to stop may change on resume
        differ = [k for k in same if json.dumps(saved.get(k), default=float) != json.dumps(record[k], default=float)]
        if differ:
            raise InputError(f"{resume} was written by another fit (its {', '.join(differ)} differ); resume it "
                             "with the command that made it.")
        for entry in saved["history"]:  # replay: the optax state is a function of the gradients seen
            theta = np.asarray(entry["next_theta"], float)
            if opt is not None:
                _, opt_state = opt.update(jnp.asarray(entry["gradient"]), opt_state, jnp.asarray(entry["theta"]))
            history.append(entry)
    t0 = time.perf_counter()
    d = len(names)

    def params_of(t):
        return {n: float(v) for n, v in zip(names, np.exp(t))}

    def run(thetas):
        s, info = runner.run([params_of(t) for t in thetas], seeds, statistics, progress=False)
        s, missing = _fill_missing(s)
        return s, missing, info

    def jacobian_of(s):  # [k, d] from the means at theta +- h e_i
        return (s[1:1 + d].mean(axis=1) - s[1 + d:].mean(axis=1)).T / (2 * step)

    message = ""
    done = bool(history) and history[-1].get("converged", False)
    for it in range(len(history), steps):
        if done:
            break
        mean = None
        points = None
        if estimator == "central":
            points = estimators.central_points(theta, step)
            s, missing, info = run(points)
            est = estimators.central_from_members(s, objective, step)
            jac, base = jacobian_of(s), s[0]
            mean = base.mean(axis=0)
        elif estimator == "truncated":  # one host run at theta sizes the rollouts, then the windows
            t1 = time.perf_counter()
            c = construction.Construction(runner, seeds, statistics, names, theta)
            est = estimators.truncated_pathwise(c.advance, c.statistics, objective, theta, c.start, c.steps,
                                                int(window), combine="mean")
            info = {"particle_steps": c.particle_steps(), "total_seconds": time.perf_counter() - t1}
            s, missing, base, jac = None, 0, None, None
        else:
            cache = {}

            def batch(ts):
                cache["s"], cache["missing"], cache["info"] = run(np.asarray(ts))
                return cache["s"]

            est = estimators.antithetic_smoothing(batch, objective, theta, jax.random.PRNGKey(int(key) + it),
                                                  sigma=sigma, pairs=pairs)
            s, missing, info = cache["s"], cache["missing"], cache["info"]
            base, jac = None, None  # the smoothing does not run theta itself
        gradient = np.asarray(est.gradient, float)
        if opt is None:
            r = mean - target.mean
            hessian = (jac.T * w) @ jac
            if not np.any(hessian):
                message = "the statistics do not move with the parameters (a zero Jacobian): nothing to fit"
                delta = np.zeros(d)
            else:
                # Levenberg-Marquardt damping, and each component clipped on its own: a poorly
                # determined parameter must not take a huge step nor shrink the others'
                damped = hessian + 1e-3 * np.diag(np.diag(hessian)) + 1e-12 * np.trace(hessian) * np.eye(d)
                delta = np.clip(-np.linalg.solve(damped, (jac.T * w) @ r), -max_step, max_step)
        elif not np.all(np.isfinite(gradient)):  # a pile's NaN would spoil the optimiser's state for good
            message = f"the {estimator} gradient is not finite ({gradient.tolist()}): stopped before stepping"
            delta = np.zeros(d)
        else:
            updates, opt_state = opt.update(jnp.asarray(gradient), opt_state, jnp.asarray(theta))
            delta = np.asarray(updates, float)
        converged = bool(opt is None and not message and np.max(np.abs(delta)) < tolerance)
        step_stderr, why = [float("nan")] * d, "tolerance" if converged else ""
        if opt is None and not message:
            cov, _ = confidence(jac, w, s[0], target)
            if np.all(np.isfinite(cov)):
                step_stderr = np.sqrt(np.clip(np.diag(cov), 0, None)).tolist()
                if noise_stop and not converged and np.all(np.abs(delta) < np.asarray(step_stderr)):
                    converged, why = True, "noise"
        loss_se = estimators.loss_stderr(base, objective) if base is not None else float("nan")
        entry = {"iteration": it, "theta": theta.tolist(), "values": params_of(theta),
                 "loss": float(est.value), "loss_stderr": loss_se, "gradient": gradient.tolist(),
                 "gradient_stderr": np.asarray(est.stderr, float).tolist(), "ensembles": int(est.evaluations),
                 "particle_steps": int(info["particle_steps"]), "missing": missing,
                 "mean": None if mean is None else mean.tolist(), "next_theta": (theta + delta).tolist(),
                 **({} if points is None else {"points": points.tolist(), "point_means": s.mean(axis=1).tolist()}),
                 "converged": converged, "stopped_by": why, "step_stderr": step_stderr,
                 "seconds": info["total_seconds"]}
        history.append(entry)
        theta = theta + delta
        if progress is True:
            vals = ", ".join(f"{n} = {v:.5g}" for n, v in entry["values"].items())
            loss = "" if not math.isfinite(entry["loss"]) else f"loss {entry['loss']:.4g} +- {loss_se:.2g}, "
            print(f"fit {it + 1}/{steps}: {vals}: {loss}step {np.round(delta, 4).tolist()} "
                  f"({entry['seconds']:.0f} s)", flush=True)
        elif callable(progress):
            progress(entry)
        if checkpoint is not None:
            _write_json(checkpoint, {**record, "history": history, "target": target.to_json()})
        if converged or message:
            break

    # the interval: a central-difference Jacobian at the fitted values
    final_points = estimators.central_points(theta, step) if interval else theta[None]
    s, _, info = run(final_points)
    if interval:
        jac = jacobian_of(s)
        cov, dof = confidence(jac, w, s[0], target)
    else:
        jac, cov, dof = np.full((s.shape[-1], d), np.nan), np.full((d, d), np.nan), float("nan")
    se = np.sqrt(np.clip(np.diag(cov), 0, None)) if np.all(np.isfinite(cov)) else np.full(d, np.nan)
    z = t_quantile(dof)
    values = params_of(theta)
    interval = {n: (float(np.exp(theta[i] - z * se[i])), float(np.exp(theta[i] + z * se[i])))
                for i, n in enumerate(names)}
    final_loss = float(objective(jnp.asarray(s[0].mean(axis=0))))
    # how strongly each parameter moves the weighted statistics (per unit log value): one that barely
    # moves them is not determined by this target, whatever its interval says
    sensitivity = np.sqrt(np.sum(w[:, None] * jac ** 2, axis=0))
    converged = bool(history) and bool(history[-1]["converged"])
    record.update({"final_points": final_points.tolist(), "final_point_means": s.mean(axis=1).tolist(),
                   "final_loss": final_loss, "final_loss_stderr": estimators.loss_stderr(s[0], objective),
                   "jacobian": jac.tolist(), "sensitivity": dict(zip(names, sensitivity.tolist())),
                   "interval_dof": dof, "interval_quantile": z, "converged": converged,
                   "message": message or ("" if converged or opt is not None else
                                          f"not converged in {steps} iterations: the interval is at the last one"),
                   "fit_seconds": time.perf_counter() - t0,
                   "particle_steps": int(sum(h["particle_steps"] for h in history) + info["particle_steps"])})
    first = history[0]["mean"] if history and history[0].get("mean") is not None else None
    start_mean = np.asarray(first, float) if first is not None else np.full(len(target.mean), np.nan)
    result = EnsembleFitResult(names, values, {n: float(start[n]) for n in names}, interval,
                               {n: float(se[i]) for i, n in enumerate(names)}, history, target, s[0].mean(axis=0),
                               start_mean, s[0], record)
    # the same answer from a line through every ensemble run (jaxpile.fit.regression): the honest one in chaos
    from jaxpile.fit import regression

    estimate = regression.estimate(result, w)
    record["regression"] = None if estimate is None else estimate.to_json()
    return result


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
        x = (np.arange(len(profile)) + 0.5) / len(profile)
        t = result.target
        ax.fill_between(x, t.mean[profile] - t.spread[profile], t.mean[profile] + t.spread[profile], alpha=0.2,
                        color="k", label="target +- one pile")
        ax.plot(x, t.mean[profile], "k-", label="target")
        ax.plot(x, result.start_mean[profile], "C1--", label="start")
        ax.plot(x, result.fitted_mean[profile], "C0-", label="fit")
        ax.set(xlabel="x / B", ylabel="normal base force / peak", title="ensemble-mean base profile")
    else:
        k = np.arange(len(labels))
        ax.errorbar(k - 0.15, result.target.mean, yerr=result.target.spread, fmt="ks", label="target +- one pile")
        ax.plot(k, result.start_mean, "C1o", label="start")
        sd = result.fitted_members.std(axis=0, ddof=1) if len(result.fitted_members) > 1 else None
        ax.errorbar(k + 0.15, result.fitted_mean, yerr=sd, fmt="C0o", label="fit +- one pile")
        ax.set_xticks(k, labels, rotation=20, fontsize=8)
        ax.set(title="ensemble means")
    ax.legend(fontsize=8)
    fig.suptitle(f"{result.record['protocol']} / {result.record['law']}: fit of {', '.join(names)} "
                 f"({result.record['estimator']}, {result.record['optimizer']}, B = {len(result.record['seeds'])})")
    fig.tight_layout()
    if path is not None:
        fig.savefig(path, dpi=110)
        plt.close(fig)
    return fig


__all__ = ["ESTIMATORS", "EnsembleFitResult", "EnsembleTarget", "Runner", "Statistics", "confidence", "figure",
           "fit", "make_target", "objective_for", "weights"]
