"""Gradient estimators of an ensemble-mean loss.

The quantity to differentiate is F(theta) = objective(mean over members of
s_b(theta)): `members(theta) -> [B, k]` runs an ensemble of B piles at the
(log-)parameters theta and returns k statistics per pile (base-force bins, an
angle...), and `objective([k]) -> scalar` compares their ensemble mean with a
target. Every estimator uses common random numbers: `members` must build member
b from the same seed at every theta, so that the difference between two thetas
is not buried under the difference between two packings.

- `pathwise`: jax.grad through the whole construction (the baseline; through a
  chaotic pour it explodes: docs/gradients.md#what-is-chaotic).
- `central_differences`: (F(theta + h e_i) - F(theta - h e_i)) / 2h, 2d runs of
  the ensemble; the reference, and a usable estimator for one or two parameters.
- `truncated_pathwise`: the construction cut into windows of W steps, each
  window's sensitivity to theta taken through that window alone (forward mode,
  its start held fixed), summed or averaged and carried to the end. Short
  windows cut the products of step Jacobians that explode in a chaotic pour, at
  the price of a bias (W set by measuring; W = the whole run is `pathwise`).
- `antithetic_smoothing`: the gradient of the Gaussian-smoothed F,
  (1 / 2 sigma K) sum_k [F(theta + sigma u_k) - F(theta - sigma u_k)] u_k over K
  antithetic pairs, all 2K ensembles in one batched call; biased by the
  smoothing (not for a quadratic F), its variance falling as 1/K.

Each returns an `Estimate` with the standard error of every component: over the
K pairs for the smoothing, and by the jackknife over members (leave one pile
out, the same pile at every theta) for the others, which is right for a loss
that is a nonlinear function of the ensemble mean. None of this is in the three
papers: Gaussian smoothing with antithetic pairs is Nesterov & Spokoiny's (Found.
Comput. Math. 17, 2017); the truncation is Williams & Peng's truncated
back-propagation through time (Neural Comput. 2, 1990) in forward mode, its
windows laid end to end; the jackknife is Quenouille-Tukey's (var = (B - 1)/B
sum (g_(b) - mean)^2). tests/test_estimators.py checks each against exact
gradients of synthetic ensembles.
"""

from __future__ import annotations

import functools
from typing import Callable, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxpile.engine.compile import jit_derivative
from jaxpile.errors import InputError
from jaxpile.ranges import COUNT, POSITIVE

Array = jax.Array


class Estimate(NamedTuple):
    """A gradient estimate.

    Attributes:
      gradient: `[d]` dF / dtheta.
      stderr: `[d]` its standard error (NaN where it cannot be told: one member).
      value: F(theta) where it was evaluated (NaN for the smoothing, which does
        not evaluate theta itself).
      evaluations: ensemble runs it cost (a batched call of m thetas counts m).
    """

    gradient: Array
    stderr: Array
    value: float
    evaluations: int


def _theta(theta) -> np.ndarray:
    theta = np.asarray(theta, dtype=float)
    if theta.ndim != 1 or theta.size == 0 or not np.all(np.isfinite(theta)):
        raise InputError(f"theta must be a non-empty 1-D array of finite numbers; got {theta!r}.")
    return theta


def _members(members, theta) -> np.ndarray:
    s = np.asarray(members(jnp.asarray(theta)), dtype=float)
    if s.ndim == 1:
        s = s[:, None]
    if s.ndim != 2 or s.shape[0] < 1:
        raise InputError(f"members(theta) must return [B, k] (or [B]) statistics; got shape {s.shape}.")
    return s


def _jackknife_stderr(estimates: np.ndarray) -> np.ndarray:
    """Standard error from B leave-one-out estimates `[B, d]`."""
    b = estimates.shape[0]
    if b < 2:
        return np.full(estimates.shape[1:], np.nan)
    mean = estimates.mean(axis=0)
    return np.sqrt((b - 1) / b * ((estimates - mean) ** 2).sum(axis=0))


def _leave_one_out_means(s: np.ndarray) -> np.ndarray:
    """`[B, k]` -> `[B, k]`: the mean over all members but b, for each b."""
    b = s.shape[0]
    return (s.sum(axis=0, keepdims=True) - s) / max(b - 1, 1)


def central_points(theta, step: float = 0.05) -> np.ndarray:
    """`[2d + 1, d]`: theta, then theta + h e_i and theta - h e_i for each i (the
    thetas `central_from_members` expects, to run as one batch)."""
    theta = _theta(theta)
    step = POSITIVE.check("step", step, scalar=True)
    e = step * np.eye(theta.size)
    return np.concatenate([theta[None], theta + e, theta - e])


def central_from_members(s, objective: Callable, step: float = 0.05) -> Estimate:
    """Central differences from the members' statistics at `central_points`.

    Args:
      s: `[2d + 1, B, k]` statistics of the B members (common random numbers)
        at each of `central_points(theta, step)`.
      objective: `[k] -> scalar`, the loss of the ensemble mean.
      step: h, as given to `central_points`.

    Returns:
      `Estimate` with the jackknife standard error over members: 2d + 1 runs.
    """
    s = np.asarray(s, dtype=float)
    if s.ndim == 2:
        s = s[..., None]
    if s.ndim != 3 or s.shape[0] < 3 or s.shape[0] % 2 != 1:
        raise InputError(f"central differences need statistics [2d + 1, B, k]; got shape {s.shape}.")
    d = (s.shape[0] - 1) // 2

    def f(m):
        return float(objective(jnp.asarray(m)))

    value = f(s[0].mean(axis=0))
    gradient, loo = np.zeros(d), np.zeros((s.shape[1], d))
    for i in range(d):
        up, down = s[1 + i], s[1 + d + i]
        gradient[i] = (f(up.mean(0)) - f(down.mean(0))) / (2 * step)
        f_up = np.array([f(m) for m in _leave_one_out_means(up)])
        f_down = np.array([f(m) for m in _leave_one_out_means(down)])
        loo[:, i] = (f_up - f_down) / (2 * step)
    return Estimate(jnp.asarray(gradient), jnp.asarray(_jackknife_stderr(loo)), value, 2 * d + 1)


def central_differences(members: Callable, objective: Callable, theta, *, step: float = 0.05) -> Estimate:
    """Central differences of F(theta) = objective(mean_b members(theta)[b]).

    Args:
      members: `theta [d] -> [B, k]` per-member statistics, common random
        numbers (member b from the same seed at every theta).
      objective: `[k] -> scalar`, the loss of the ensemble mean.
      theta: `[d]` where to differentiate (log-parameters, so `step` is relative).
      step: h.

    Returns:
      `Estimate`: 2d + 1 ensemble runs (theta itself for the value).
    """
    thetas = central_points(theta, step)
    runs = [_members(members, t) for t in thetas]
    if len({r.shape for r in runs}) > 1:
        raise InputError(f"members(theta) must return the same [B, k] at every theta (the same piles: common random "
                         f"numbers); got shapes {sorted({r.shape for r in runs})}.")
    return central_from_members(np.stack(runs), objective, step)


def loss_stderr(s, objective: Callable) -> float:
    """The jackknife standard error of objective(mean of the members `[B, k]`):
    how much the loss of this ensemble would move with other piles."""
    s = np.asarray(s, dtype=float)
    if s.ndim == 1:
        s = s[:, None]
    values = np.array([[float(objective(jnp.asarray(m)))] for m in _leave_one_out_means(s)])
    return float(_jackknife_stderr(values)[0])


def smoothing_directions(key, pairs: int, d: int) -> np.ndarray:
    """`[pairs, d]` the directions u_k ~ N(0, I) `antithetic_smoothing` draws
    from `key` (a record keeps them: the draw may differ between JAX versions)."""
    return np.asarray(jax.random.normal(key, (int(pairs), int(d))), dtype=float)


def antithetic_smoothing(members_batch: Callable, objective: Callable, theta, key, *, sigma: float = 0.05,
                         pairs: int = 8) -> Estimate:
    """The gradient of F smoothed by a Gaussian of width `sigma`, from `pairs`
    antithetic pairs of directions u_k ~ N(0, I), all 2K ensembles in one call.

    Args:
      members_batch: `thetas [m, d] -> [m, B, k]`, common random numbers across
        the m thetas (e.g. `Ensemble` over (theta, seed) members).
      objective: `[k] -> scalar`.
      theta: `[d]`.
      key: a `jax.random` key for the directions.
      sigma: the smoothing width (in log-parameter units).
      pairs: K.

    Returns:
      `Estimate` whose standard error is over the K pairs (each pair is an
      unbiased estimate of the smoothed gradient on its own).
    """
    theta = _theta(theta)
    sigma = POSITIVE.check("sigma", sigma, scalar=True)
    pairs = COUNT.check("pairs", pairs, scalar=True)
    u = smoothing_directions(key, pairs, theta.size)
    thetas = np.concatenate([theta + sigma * u, theta - sigma * u])
    s = np.asarray(members_batch(jnp.asarray(thetas)), dtype=float)
    if s.ndim == 2:
        s = s[..., None]
    if s.shape[0] != 2 * pairs:
        raise InputError(f"members_batch returned {s.shape[0]} ensembles for {2 * pairs} thetas.")
    f = np.array([float(objective(jnp.asarray(m))) for m in s.mean(axis=1)])
    per_pair = ((f[:pairs] - f[pairs:]) / (2 * sigma))[:, None] * u
    stderr = per_pair.std(axis=0, ddof=1) / np.sqrt(pairs) if pairs > 1 else np.full(theta.size, np.nan)
    return Estimate(jnp.asarray(per_pair.mean(axis=0)), jnp.asarray(stderr), float("nan"), 2 * pairs)


def pathwise(members: Callable, objective: Callable, theta) -> Estimate:
    """jax.grad of F through `members` (which must be traceable), with the
    jackknife standard error from each member's own sensitivity
    (`jax.jacfwd`: d forward passes, the same seeds)."""
    theta = _theta(theta)
    t = jnp.asarray(theta)
    s = jnp.asarray(members(t))
    if s.ndim == 1:
        s = s[:, None]
    jac = jax.jacfwd(lambda x: jnp.reshape(members(x), s.shape))(t)  # [B, k, d]
    return _from_jacobians(s, jac, objective)


def _from_jacobians(s, jac, objective: Callable) -> Estimate:
    """The gradient of objective(mean_b s_b) from the members' statistics
    `[B, k]` and their Jacobians `[B, k, d]`, with the jackknife standard error
    (leave one member out of both means; NaN for one member)."""
    mean = s.mean(axis=0)
    value, outer = jax.value_and_grad(objective)(mean)
    gradient = outer @ jac.mean(axis=0)
    b = s.shape[0]
    if b < 2:
        return Estimate(gradient, jnp.full(jac.shape[-1], jnp.nan), float(value), 1)
    loo_means = (s.sum(0, keepdims=True) - s) / (b - 1)
    loo_jacs = (jac.sum(0, keepdims=True) - jac) / (b - 1)
    loo = jax.vmap(lambda m, j: jax.grad(objective)(m) @ j)(loo_means, loo_jacs)
    return Estimate(gradient, jnp.asarray(_jackknife_stderr(np.asarray(loo))), float(value), 1)


def _is_float(x) -> bool:
    return jnp.issubdtype(jnp.result_type(x), jnp.inexact)


def _window_run(advance: Callable):
    """`(directions, theta, state, n) -> (state, tangents)`: n steps of `advance`
    with its d tangents, jitted once per `advance` function (one compile per
    window length, at most two) and kept on it: a fit that hands the same
    `advance` at every iterate (`construction.Construction`) compiles its
    windows once."""
    kept = getattr(advance, "_window_run", None)
    if kept is not None:
        return kept

    @functools.partial(jit_derivative, static_argnums=3)
    def window_run(directions, x0, s, n):
        def along(e):
            return jax.jvp(lambda x: advance(x, s, n), (x0,), (e,))
        return jax.vmap(along, out_axes=(None, 0))(directions)

    try:
        advance._window_run = window_run
    except AttributeError:  # a bound method or a builtin: compiled for this call alone
        pass
    return window_run


def truncated_pathwise(advance: Callable, statistics: Callable, objective: Callable, theta, state, steps: int,
                       window: int, combine: str = "sum") -> Estimate:
    """The truncated pathwise gradient of F through a construction of `steps` steps.

    The construction runs in windows of `window` steps (the last one shorter
    if `window` does not divide `steps`). In window j the state's sensitivity
    to theta is taken through that window alone, its start held fixed:
    v_j = d advance(theta, s_j, W) / d theta (forward mode, d tangents at once).
    The sensitivity of the end state is taken from the v_j alone (the products
    of the later steps' Jacobians, which explode in a chaotic pour, are cut),
    and the statistics' Jacobian is d statistics / d theta + d statistics /
    d state . v, with v:

    - `combine="sum"`: v = sum_j v_j, each window's perturbation carried to
      the end unchanged. Exact where later steps pass a perturbation on as it
      is (a disk that lands shifted stays shifted); where they damp it, a
      pile's elastic response to theta is derived afresh in every window and
      counted once per window.
    - `combine="mean"`: v = the windows' mean (weighted by their lengths):
      exact where the state relaxes to its new equilibrium within a window (a
      settled pile), and it dilutes a once-only shift by the number of windows.

    For `window >= steps` both are the exact pathwise gradient.
    tests/test_estimators.py checks that, and both biases in closed form on a
    contracting and a conservative map.

    Args:
      advance: `(theta, state, n) -> state`: n steps at the (log-)parameters
        theta, traceable (e.g. `Simulator.rollout` of the members' batched state).
      statistics: `(theta, state) -> [B, k]` (or `[k]`: one member).
      objective: `[k] -> scalar`, of the members' mean statistics.
      theta: `[d]` where the gradient is taken.
      state: the construction's first state.
      steps, window: the construction's length and the truncation window.
      combine: `"sum"` or `"mean"` of the windows' sensitivities (above).

    Returns:
      `Estimate`; its standard error is the jackknife over members (as `pathwise`).
    """
    steps = COUNT.check("steps", steps, scalar=True)
    window = COUNT.check("window", window, scalar=True)
    if combine not in ("sum", "mean"):
        raise InputError(f"combine must be 'sum' or 'mean'; got {combine!r}.")
    theta = _theta(theta)
    t = jnp.asarray(theta)
    directions = jnp.eye(theta.size, dtype=t.dtype)

    window_run = functools.partial(_window_run(advance), directions)
    moving = [i for i, x in enumerate(jax.tree.leaves(state)) if _is_float(x)]  # integer leaves have no tangent
    total, s, done = None, state, 0
    while done < steps:
        n = min(int(window), int(steps) - done)
        s, v = window_run(t, s, n)
        weight = n / steps if combine == "mean" else 1.0
        v = jax.tree.leaves(v)
        v = [v[i] * weight for i in moving]
        total = v if total is None else [a + b for a, b in zip(total, v)]
        done += n
    leaves, tree = jax.tree.flatten(s)

    def with_moving(parts):
        whole = list(leaves)
        for i, x in zip(moving, parts):
            whole[i] = x
        return jax.tree.unflatten(tree, whole)

    def stats_along(e, ds):
        return jax.jvp(lambda x, parts: statistics(x, with_moving(parts)), (t, [leaves[i] for i in moving]), (e, ds))

    stats, jac = jax.vmap(stats_along, out_axes=(None, 0))(directions, total)
    stats = jnp.asarray(stats)
    jac = jnp.moveaxis(jnp.asarray(jac), 0, -1)  # [B, k, d]
    if stats.ndim == 1:
        stats, jac = stats[None, :], jac[None, ...]
    return _from_jacobians(stats, jac, objective)
