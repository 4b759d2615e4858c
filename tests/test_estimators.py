"""The gradient estimators of an ensemble-mean loss (jaxpile/estimators.py,
issue 17), on synthetic ensembles whose gradient is known exactly: member b's
statistics s_b(theta) = A_b theta + q theta_0^2 + noise_b, the noise fixed per
member (common random numbers), the loss quadratic in the ensemble mean."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxpile.errors import InputError
from jaxpile.fit.estimators import antithetic_smoothing, central_differences, pathwise, smoothing_directions

B, K_STATS = 16, 3
_rng = np.random.default_rng(7)
A = jnp.asarray(1.0 + 0.3 * _rng.standard_normal((B, K_STATS, 2)))  # member-specific sensitivities
NOISE = jnp.asarray(0.5 * _rng.standard_normal((B, K_STATS)))
TARGET = jnp.asarray([0.3, -0.2, 0.5])
WEIGHT = jnp.asarray([1.0, 2.0, 0.5])
THETA = np.array([0.2, -0.1])


def members(theta, quadratic=0.4):
    theta = jnp.asarray(theta)
    return jnp.einsum("bkd,d->bk", A, theta) + quadratic * theta[0] ** 2 + NOISE


def objective(mean):
    return jnp.sum(WEIGHT * (mean - TARGET) ** 2)


def exact_gradient(theta, quadratic=0.4):
    return np.asarray(jax.grad(lambda t: objective(members(t, quadratic).mean(0)))(jnp.asarray(theta)))


def test_central_differences_with_common_random_numbers_match_the_exact_gradient():
    est = central_differences(members, objective, THETA, step=1e-3)
    np.testing.assert_allclose(est.gradient, exact_gradient(THETA), rtol=1e-5)
    assert est.evaluations == 5 and np.isclose(est.value, float(objective(members(THETA).mean(0))))


def test_pathwise_matches_the_exact_gradient():
    est = pathwise(members, objective, THETA)
    np.testing.assert_allclose(est.gradient, exact_gradient(THETA), rtol=1e-10)


def test_the_jackknife_standard_error_is_the_classic_one_for_a_linear_loss():
    """For objective = w . mean and s linear in theta, each member's gradient is
    w . A_b: the jackknife over members must give std(w . A_b) / sqrt(B)."""
    weight = jnp.asarray([1.0, -0.5, 2.0])
    linear = lambda m: jnp.sum(weight * m)
    per_member = np.asarray(jnp.einsum("k,bkd->bd", weight, A))
    classic = per_member.std(axis=0, ddof=1) / np.sqrt(B)
    lin_members = lambda t: members(t, quadratic=0.0)
    np.testing.assert_allclose(pathwise(lin_members, linear, THETA).stderr, classic, rtol=1e-10)
    np.testing.assert_allclose(central_differences(lin_members, linear, THETA, step=0.1).stderr, classic, rtol=1e-8)


def test_antithetic_smoothing_is_unbiased_for_a_quadratic_loss_and_its_error_falls_as_one_over_sqrt_pairs():
    """s linear in theta makes F quadratic, whose Gaussian smoothing leaves the
    gradient unchanged: the estimate must sit within 4 standard errors of the
    exact gradient, and 16x the pairs must shrink the error ~4x."""
    batch = jax.vmap(lambda t: members(t, quadratic=0.0))
    exact = exact_gradient(THETA, quadratic=0.0)
    small = antithetic_smoothing(batch, objective, THETA, jax.random.PRNGKey(0), sigma=0.2, pairs=64)
    large = antithetic_smoothing(batch, objective, THETA, jax.random.PRNGKey(1), sigma=0.2, pairs=1024)
    for est in (small, large):
        assert np.all(np.abs(np.asarray(est.gradient) - exact) <= 4 * np.asarray(est.stderr) + 1e-12)
    ratio = np.asarray(small.stderr) / np.asarray(large.stderr)
    assert np.all((2.5 < ratio) & (ratio < 6.5)), ratio
    assert large.evaluations == 2048


def test_smoothing_of_a_linear_loss_is_the_gradient_seen_through_its_directions_whatever_the_noise():
    """For a loss linear in theta, each antithetic pair returns u u^T g exactly
    (common random numbers cancel every member's noise), so K pairs give
    (1/K) sum_k u_k u_k^T g, with the directions `smoothing_directions` names:
    an error of variance (g_i^2 + |g|^2) / K in component i that no ensemble
    size removes (K = 2, one parameter: +-100 %; the box study at B = 128)."""
    weight = jnp.asarray([1.0, -0.5, 2.0])
    linear = lambda m: jnp.sum(weight * m)
    batch = jax.vmap(lambda t: members(t, quadratic=0.0))
    g = np.asarray(jnp.einsum("k,bkd->d", weight, A)) / B
    for seed in range(3):
        key = jax.random.PRNGKey(seed)
        u = smoothing_directions(key, 2, THETA.size)
        est = antithetic_smoothing(batch, linear, THETA, key, sigma=0.3, pairs=2)
        np.testing.assert_allclose(est.gradient, (u.T @ (u @ g)) / 2, rtol=1e-9)


def test_on_a_chaotic_response_smoothing_stays_bounded_where_the_pathwise_gradient_explodes():
    """The issue's failure in miniature: s_b = sin(1000 omega_b theta) varies
    fast and differently per member (a pour's sensitivity to its parameters).
    Each member's own slope is of order 1000 with a random sign, so the
    pathwise gradient's standard error over members is in the tens to hundreds;
    the ensemble mean smoothed over sigma = 0.1 is nearly flat, and the
    smoothing says so with an error a hundred times smaller."""
    omega = jnp.asarray(1.0 + _rng.random(B))

    def chaotic(theta):
        return jnp.sin(1000.0 * omega[:, None] * jnp.asarray(theta)[None, :1])

    mean_sq = lambda m: jnp.sum(m ** 2)
    for x in (0.3, 0.5):
        path = pathwise(chaotic, mean_sq, np.array([x]))
        smooth = antithetic_smoothing(jax.vmap(chaotic), mean_sq, np.array([x]), jax.random.PRNGKey(2),
                                      sigma=0.1, pairs=256)
        assert float(path.stderr[0]) > 100 * float(smooth.stderr[0])
        assert abs(float(smooth.gradient[0])) < 4 * float(smooth.stderr[0]) + 0.05


@pytest.mark.parametrize("call, message", [
    (lambda: central_differences(members, objective, [np.nan, 0.0]), "theta must be"),
    (lambda: central_differences(members, objective, THETA, step=0.0), "step must be > 0"),
    (lambda: antithetic_smoothing(jax.vmap(members), objective, THETA, jax.random.PRNGKey(0), pairs=0),
     "pairs must be a positive whole number"),
    (lambda: antithetic_smoothing(jax.vmap(members), objective, THETA, jax.random.PRNGKey(0), sigma=-1.0),
     "sigma must be > 0"),
])
def test_bad_estimator_settings_are_refused_in_one_line(call, message):
    with pytest.raises(InputError, match=message):
        call()


def test_central_differences_refuse_ensembles_of_different_sizes():
    calls = iter([2, 3, 2])
    with pytest.raises(InputError, match="same"):
        central_differences(lambda t: np.ones((next(calls), 1)), lambda m: m.sum(), [0.0])


# ------------------------------------------------------------ truncated pathwise
A_MAP = 0.8  # x_{t+1} = a x_t + theta_0 c_b + theta_1: a perturbation decays by a per step
C = jnp.asarray(1.0 + 0.5 * _rng.standard_normal(B))


def _advance(theta, state, n, a=A_MAP):
    def step(s, _):
        return {"x": a * s["x"] + theta[0] * C + theta[1], "count": s["count"] + 1}, None
    return jax.lax.scan(step, state, None, length=n)[0]


def _statistics(theta, state):
    return jnp.stack([state["x"], 2.0 * state["x"] + theta[1]], axis=-1)  # [B, 2]; theta also directly


def _start():
    return {"x": jnp.zeros(B), "count": jnp.zeros(B, jnp.int32)}  # an integer leaf, as a pile's lists


def _truncated(steps, window, a=A_MAP, objective_fn=None, combine="sum"):
    from jaxpile.fit.estimators import truncated_pathwise

    return truncated_pathwise(lambda t, s, n: _advance(t, s, n, a), _statistics,
                              objective_fn or (lambda m: jnp.sum((m - jnp.asarray([0.3, -0.2])) ** 2)),
                              THETA, _start(), steps, window, combine=combine)


def _closed_form(windows, a, combine="sum"):
    """d x_T / d theta_0 over c_b (and d x_T / d theta_1) from the windows'
    own sensitivities sum_{j < n} a^j: summed, or their length-weighted mean."""
    each = [(1 - a ** n) / (1 - a) if a != 1 else float(n) for n in windows]
    if combine == "mean":
        return sum(e * n for e, n in zip(each, windows)) / sum(windows)
    return sum(each)


def test_truncated_pathwise_over_one_window_is_the_pathwise_gradient():
    from jaxpile.fit.estimators import pathwise

    objective_fn = lambda m: jnp.sum((m - jnp.asarray([0.3, -0.2])) ** 2)
    full = pathwise(lambda t: _statistics(t, _advance(t, _start(), 12)), objective_fn, THETA)
    for window, combine in ((12, "sum"), (50, "sum"), (12, "mean")):
        est = _truncated(12, window, combine=combine)
        np.testing.assert_allclose(est.gradient, full.gradient, rtol=1e-10)
        np.testing.assert_allclose(est.stderr, full.stderr, rtol=1e-8)
        assert est.value == pytest.approx(full.value, rel=1e-12)


@pytest.mark.parametrize("steps, window, a, combine", [(12, 3, A_MAP, "sum"), (10, 4, A_MAP, "sum"),
                                                       (12, 1, A_MAP, "sum"), (12, 5, 1.0, "sum"),
                                                       (10, 4, A_MAP, "mean"), (12, 5, 1.0, "mean")])
def test_truncated_pathwise_combines_the_windows_sensitivities_as_in_closed_form(steps, window, a, combine):
    """The windows' sensitivities sum_{j<n} a^j, summed or averaged, against
    the exact (1 - a^T)/(1 - a): summed, the exact gradient for a = 1 (a
    perturbation passed on unchanged) and a known bias for a < 1; averaged,
    biased for both at these short windows (it is exact only once a window
    outlasts the relaxation). Checked through a linear objective, whose
    gradient is the mean sensitivity itself."""
    windows = [window] * (steps // window) + ([steps % window] if steps % window else [])
    sensitivity = _closed_form(windows, a, combine)
    weight = jnp.asarray([1.0, 0.25])
    est = _truncated(steps, window, a, objective_fn=lambda m: jnp.sum(weight * m), combine=combine)
    # d/d theta_0 of w . mean(x, 2x + theta_1) = (w0 + 2 w1) mean(c) s; d/d theta_1 adds w1
    expected = [float(weight[0] + 2 * weight[1]) * float(C.mean()) * sensitivity,
                float(weight[0] + 2 * weight[1]) * sensitivity + float(weight[1])]
    np.testing.assert_allclose(est.gradient, expected, rtol=1e-10)
    exact_sensitivity = (1 - a ** steps) / (1 - a) if a != 1.0 else float(steps)
    exact = float(weight[0] + 2 * weight[1]) * exact_sensitivity + float(weight[1])
    if a == 1.0 and combine == "sum":
        assert est.gradient[1] == pytest.approx(exact, rel=1e-12)
    else:
        assert abs(float(est.gradient[1]) - exact) > 1e-3 * abs(exact)  # truncation is biased here


def test_truncated_pathwise_compiles_the_windows_of_one_advance_function_once():
    """A fit hands the same `advance` at every iterate (`construction._pieces`):
    its windows are traced and compiled at the first call only, and the second
    call's gradient is the same function's. A new function compiles afresh."""
    from jaxpile.fit.estimators import truncated_pathwise

    traces = []

    def advance(t, s, n):
        traces.append(n)  # runs while jax traces it, not when the compiled window runs
        return _advance(t, s, n, A_MAP)

    def gradient(fn, theta):
        return truncated_pathwise(fn, _statistics, lambda m: jnp.sum(m ** 2), theta, _start(), 12, 4).gradient

    first = gradient(advance, THETA)
    assert traces == [4]
    again = gradient(advance, THETA + 0.1)
    assert traces == [4]
    np.testing.assert_allclose(again, gradient(lambda t, s, n: _advance(t, s, n, A_MAP), THETA + 0.1), rtol=1e-12)
    assert not np.allclose(first, again)


def test_truncated_pathwise_refuses_a_window_of_no_steps_and_an_unknown_combination():
    with pytest.raises(InputError, match="window must be a positive whole number"):
        _truncated(12, 0)
    with pytest.raises(InputError, match="combine must be"):
        _truncated(12, 3, combine="median")
