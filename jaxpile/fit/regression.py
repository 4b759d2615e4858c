"""The fitted parameters from a regression over every ensemble a fit ran.

Gauss-Newton answers with its last iterate and a Jacobian from the last central
difference. In a chaotic protocol (a silo's discharge, a pour) the ensembles at
theta and theta +- h differ by more than the parameter change explains, even
with the same seeds (common random numbers do not cancel chaos), so the last
step is one noisy step and an interval built on one finite-difference Jacobian
is too narrow (docs/fitting.md#the-hopper).

Every ensemble of the fit is a point (theta_n, m_n) on the response of the
ensemble means to the log-parameters. A straight line through all of them,
m(theta) = a + J theta (least squares, per statistic), rests on 3 (iterations +
1) ensembles instead of 3; its parameters where it best meets the target t, in
the fit's weights W,

    theta* = (J^T W J)^-1 J^T W (t - a),

are classical inverse regression, the calibration problem (Eisenhart 1939, Ann.
Math. Statist. 10, 162; Osborne 1991, Int. Statist. Rev. 59, 309). Their
covariance is the delta method through J^T W (a + J theta* - t) = 0 (H = J^T W
J): the line's own noise (the residual covariance times (X^T X)^-1) moves theta*
through the line's level and, where the target is missed, its slope; the
target's and the seeds' noise enter as the sandwich H^-1 J^T W (Sigma_t / B_t +
Sigma / B) W J H^-1 of `ensemble_fit.confidence` (Huber 1967, White 1982). The
interval is Student-t with the residuals' N - d - 1 degrees of freedom. A
straight line is biased over iterates far apart on a curved response, so the
estimate is for fits whose iterates stay near the answer, where Gauss-Newton's
noise matters. tests/test_ensemble_fit.py checks it: exact on a line, and an
interval that holds the truth on a chaotic toy where Gauss-Newton's misses it.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from jaxpile.fit.stats import t_quantile, weights


class Regression(NamedTuple):
    """`values`, `interval` (95 %) and `stderr_log` as in a fit's result;
    `points`: the ensembles used; `scatter`: `[k]` the residual standard
    deviation of each statistic about the line; `dof`: N - d - 1."""

    values: dict
    interval: dict
    stderr_log: dict
    points: int
    scatter: list
    dof: int

    def to_json(self) -> dict:
        return {"values": self.values, "interval": {k: list(v) for k, v in self.interval.items()},
                "stderr_log": self.stderr_log, "points": self.points, "scatter": self.scatter, "dof": self.dof}


def ensembles_of(result, skip: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """`(thetas [N, d], means [N, k])`: every ensemble a finished fit ran (all
    2d + 1 of each iteration where the history kept them, else the one at
    theta), then the final ones; the first `skip` iterations left out (the
    start is far from the answer, where a straight line is no model)."""
    thetas, means = [], []
    for h in result.history[skip:]:
        if "points" in h:
            thetas += h["points"]
            means += h["point_means"]
        elif h.get("mean") is not None:
            thetas.append(h["theta"])
            means.append(h["mean"])
    record = result.record
    if "final_points" in record:
        thetas += record["final_points"]
        means += record["final_point_means"]
    else:
        thetas.append([math.log(result.values[n]) for n in result.names])
        means.append(list(np.asarray(result.fitted_mean, float)))
    return np.asarray(thetas, float), np.asarray(means, float)


def _sampling(piles) -> np.ndarray | None:
    """`[k, k]` covariance of the mean of `piles` `[B, k]`, or None (one pile, no spread)."""
    if piles is None:
        return None
    p = np.asarray(piles, float)
    if p.ndim != 2 or len(p) < 2 or not np.any(np.ptp(p, axis=0) > 0):
        return None
    return np.atleast_2d(np.cov(p, rowvar=False)) / len(p)


class Line(NamedTuple):
    """`theta` `[d]`: where the least-squares line through the points best
    meets the target; `cov` `[d, d]`: its sandwich covariance; `scatter` `[k]`:
    the residual standard deviation of each statistic about the line; `dof`:
    N - d - 1; `intercept` `[k]` and `jacobian` `[k, d]`: the line;
    `residual` `[k, k]`: the residuals' covariance; `design_inverse`
    `[d + 1, d + 1]`: (X^T X)^-1 of the design X = (1, x)."""

    theta: np.ndarray
    cov: np.ndarray
    scatter: np.ndarray
    dof: int
    intercept: np.ndarray
    jacobian: np.ndarray
    residual: np.ndarray
    design_inverse: np.ndarray

    def predict(self, x) -> tuple[np.ndarray, np.ndarray]:
        """`(mean [k], cov [k, k])` of the line at `x` `[d]`: its value and the
        covariance of that value (the residual covariance times the leverage)."""
        at = np.concatenate([[1.0], np.asarray(x, float)])
        return self.intercept + self.jacobian @ at[1:], self.residual * float(at @ self.design_inverse @ at)


def inverse(x, means, target_mean, w, sampling=()) -> Line | None:
    """Inverse regression of points `(x [N, d], means [N, k])` onto a target
    `target_mean` `[k]` in weights `w` `[k]`: the straight line
    m(x) = a + J x by least squares, x* = (J^T W J)^-1 J^T W (t - a), and its
    covariance (this module's docstring). `sampling`: `[k, k]` covariances
    of the mismatch the points' residuals do not hold (the target's mean, the
    means of the piles the points were averaged from). None when there are
    too few points (N < d + 2) or the line does not move with x."""
    x, means, w = np.asarray(x, float), np.asarray(means, float), np.asarray(w, float)
    n, d = x.shape
    if n < d + 2:
        return None
    design = np.hstack([np.ones((n, 1)), x])
    xtx = design.T @ design
    if np.linalg.matrix_rank(xtx) < d + 1:
        return None
    coef = np.linalg.solve(xtx, design.T @ means)  # [d + 1, k]
    a, jac = coef[0], coef[1:].T  # [k], [k, d]
    hessian = (jac.T * w) @ jac
    if not np.all(np.isfinite(hessian)) or np.linalg.matrix_rank(hessian) < d:
        return None
    inv = np.linalg.inv(hessian)
    theta = inv @ ((jac.T * w) @ (np.asarray(target_mean, float) - a))
    resid = means - design @ coef
    dof = n - d - 1
    residual = resid.T @ resid / dof
    design_inverse = np.linalg.inv(xtx)
    at = np.concatenate([[1.0], theta])
    # the line's noise moves x* through its level at x* and, where the target is missed (r != 0), through
    # its slope: dx* = -H^-1 sum_k G_k db_k, G_k = w_k J_k at^T + w_k r_k [0 | I], Cov(db_k, db_l) =
    # residual_kl (X^T X)^-1
    miss = a + jac @ theta - np.asarray(target_mean, float)
    pick = np.hstack([np.zeros((d, 1)), np.eye(d)])
    g = w[:, None, None] * (jac[:, :, None] * at + miss[:, None, None] * pick)  # [k, d, d + 1]
    line_part = np.einsum("kl,kab,bc,lec->ae", residual, g, design_inverse, g)
    jw = jac.T * w
    c = sum((part for part in sampling if part is not None), np.zeros_like(residual))
    cov = inv @ (line_part + jw @ c @ jw.T) @ inv
    return Line(theta, cov, np.sqrt(np.clip(np.diag(residual), 0, None)), int(dof), a, jac, residual, design_inverse)


def estimate(result, w: np.ndarray | None = None, skip: int = 1) -> Regression | None:
    """The inverse-regression estimate (`inverse`, over the log-parameters) of
    a finished `ensemble_fit.fit` (its result or `EnsembleFitResult.from_json`
    of its record), or None when the fit ran too few ensembles (N < d + 2) or
    the line does not move with the parameters. `w`: the fit's weights
    (default `ensemble_fit.weights` of its target)."""
    target = result.target
    w = weights(target) if w is None else np.asarray(w, float)
    thetas, means = ensembles_of(result, skip)
    line = inverse(thetas, means, target.mean, w, (_sampling(target.members), _sampling(result.fitted_members)))
    if line is None:
        return None
    se = np.sqrt(np.clip(np.diag(line.cov), 0, None))
    z = t_quantile(line.dof)
    names, theta = list(result.names), line.theta
    return Regression({k: float(np.exp(theta[i])) for i, k in enumerate(names)},
                      {k: (float(np.exp(theta[i] - z * se[i])), float(np.exp(theta[i] + z * se[i])))
                       for i, k in enumerate(names)},
                      {k: float(se[i]) for i, k in enumerate(names)}, len(thetas), line.scatter.tolist(), line.dof)


__all__ = ["Line", "Regression", "ensembles_of", "estimate", "inverse"]
