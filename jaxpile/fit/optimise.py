"""An optax loop that minimises a traceable loss over chosen law parameters.

The fitted parameters move in log space (`Transform`), so they stay above
their bounds while the rest of the params pytree stays fixed; the gradient is
taken in forward or reverse mode (`gradient_mode`), whichever is the cheaper
for the number of fitted values. `fit_figure` draws what a fit did.
"""

from __future__ import annotations

import dataclasses
import math
import warnings
from collections.abc import Callable, Mapping, Sequence
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optax
from jax.flatten_util import ravel_pytree

from jaxpile.engine.compile import jit_derivative
from jaxpile.errors import InputError
from jaxpile.fit.profiles import is_concrete
from jaxpile.fit.targets import ProfileTarget
from jaxpile.laws import LAWS, granular

Array = Any

# ------------------------------------------------------------ transforms
LOWER_BOUNDS: dict[str, dict[str, float]] = {"baxter": {"r0": 1.0}, "granular": {"nu": -1.0}}
"""Lower bounds other than 0, per law: baxter's cut-off r0 must exceed 1 (a
cut-off beyond contact), a Poisson's ratio -1. Every other fitted parameter must
be > 0 (mu, kn, kt, ks, baxter n, E, ...)."""

UPPER_BOUNDS: dict[str, dict[str, float]] = {"granular": {"nu": 0.5, "restitution": 1.0}}
"""Upper bounds, per law: a Poisson's ratio below 1/2, a coefficient of
restitution below 1. A parameter with one is fitted in logit space."""


def _law_of(params) -> tuple[str | None, tuple[str, ...]]:
    """(law name, PARAM_NAMES) of a law params pytree, or (None, keys) of a mapping."""
    if isinstance(params, Mapping):
        return None, tuple(params)
    for name, module in LAWS.items():
        if isinstance(params, module.Params):
            return name, tuple(module.PARAM_NAMES)
    if isinstance(params, granular.Params):  # the parameters its composition was given
        return granular.NAME, tuple(n for n in granular.PARAM_NAMES if getattr(params, n) is not None)
    raise InputError(f"params must be a law's params pytree (one of the laws {sorted(LAWS)}) or a mapping of "
                     f"names to values; got {type(params).__name__}.")


def _get(params, name: str):
    return params[name] if isinstance(params, Mapping) else getattr(params, name)


def _with(params, values: Mapping[str, Array]):
    if isinstance(params, Mapping):
        return {**params, **values}
    return params.set(**values)


@dataclasses.dataclass(frozen=True)
class Transform:
    """Positive parameters in log space: u = log(value - lower), value = lower + exp(u);
    a parameter bounded above too (`UPPER_BOUNDS`) in logit space:
    u = log((value - lower) / (upper - value)), value = lower + (upper - lower) sigmoid(u).

    An optimiser then moves freely in u while every value stays within its
    bounds (`LOWER_BOUNDS`: 0 for mu, kn, kt, ks, baxter n, ...; 1 for baxter
    r0). A value at a bound (mu = 0) has no image: start from inside instead.
    Steps in u are relative steps in the value, which suits parameters spanning
    decades (stiffnesses).

    Attributes:
      names: the transformed parameters.
      lower: their lower bounds.
      upper: their upper bounds (inf: none); empty for none at all.
    """

    names: tuple[str, ...]
    lower: tuple[float, ...]
    upper: tuple[float, ...] = ()

    @property
    def _bounds(self):
        return zip(self.names, self.lower, self.upper or (math.inf,) * len(self.names))

    @classmethod
    def of(cls, params, names: str | Sequence[str]) -> "Transform":
        """The transform of `names` for a law params pytree (names checked against
        the law's PARAM_NAMES) or a mapping (names checked against its keys).

        Raises:
          InputError: on no names, a repeated name or an unknown name.
        """
        names = (names,) if isinstance(names, str) else tuple(names)
        law, known = _law_of(params)
        if not names:
            raise InputError(f"name at least one parameter to transform; known: {list(known)}.")
        repeated = sorted({n for n in names if names.count(n) > 1})
        if repeated:
            raise InputError(f"parameter(s) {repeated} named more than once.")
        unknown = [n for n in names if n not in known]
        if unknown:
            what = f"the {law} law's parameters (PARAM_NAMES)" if law else "the mapping's keys"
            raise InputError(f"unknown parameter(s) {unknown}; {what}: {list(known)}.")
        lower, upper = (LOWER_BOUNDS.get(law, {}), UPPER_BOUNDS.get(law, {})) if law else ({}, {})
        return cls(names=names, lower=tuple(float(lower.get(n, 0.0)) for n in names),
                   upper=tuple(float(upper.get(n, math.inf)) for n in names) if any(n in upper for n in names)
                   else ())

    def to_unconstrained(self, params) -> dict[str, Array]:
        """{name: log(value - lower)} for the transformed parameters.

        Raises:
          InputError: on a parameter that is None (a `wall_*` left to follow its
            disk value: set it to fit it), non-finite, or not above its bound.
        """
        out = {}
        for name, lower, upper in self._bounds:
            value = _get(params, name)
            if value is None:
                raise InputError(f"parameter {name} is None (it follows its disk value); give it a value to "
                                 "fit it on its own.")
            value = jnp.asarray(value)
            dtype = value.dtype if jnp.issubdtype(value.dtype, jnp.floating) else jnp.zeros(()).dtype
            value = jnp.asarray(value, dtype=dtype)  # strongly typed, so optimiser steps never re-trace
            if is_concrete(value):
                v = np.asarray(value)
                if not np.all(np.isfinite(v)) or np.any(v <= lower):
                    raise InputError(f"parameter {name} must be finite and > {lower:g} to be fitted in log space "
                                     f"(log({name} - {lower:g})); got {v.tolist()}. Start from a value above "
                                     "the bound.")
                if np.any(v >= upper):
                    raise InputError(f"parameter {name} must be < {upper:g} to be fitted in logit space "
                                     f"(log(({name} - {lower:g}) / ({upper:g} - {name}))); got {v.tolist()}. "
                                     "Start from a value below the bound.")
            out[name] = jnp.log(value - lower) if math.isinf(upper) else jnp.log((value - lower) / (upper - value))
        return out

    def to_constrained(self, unconstrained: Mapping[str, Array], params):
        """`params` with each transformed parameter set to lower + exp(u).
        Traceable (used inside the fitted loss)."""
        missing = [n for n in self.names if n not in unconstrained]
        if missing:
            raise InputError(f"unconstrained values missing for {missing}.")
        return _with(params, {n: lower + jnp.exp(unconstrained[n]) if math.isinf(upper)
                              else lower + (upper - lower) * jax.nn.sigmoid(unconstrained[n])
                              for n, lower, upper in self._bounds})


def to_unconstrained(params, names: str | Sequence[str]) -> dict[str, Array]:
    """{name: log(value - lower)} for `names` of a law params pytree or a mapping
    (see `Transform`). Raises InputError on an unknown name (listing the law's
    PARAM_NAMES) or a value not above its lower bound."""
    return Transform.of(params, names).to_unconstrained(params)


def to_constrained(unconstrained: Mapping[str, Array], params):
    """`params` with each parameter named in `unconstrained` set to
    lower + exp(u): the inverse of `to_unconstrained`."""
    return Transform.of(params, tuple(unconstrained)).to_constrained(unconstrained, params)


# ------------------------------------------------------------- gradients
GRADIENT_MODES = ("auto", "reverse", "forward")
FORWARD_MODE_MAX = 4
"""`mode="auto"` takes forward-mode gradients up to this many fitted values.
Forward mode costs about one tangent pass per value, the checkpointed reverse
three passes (forward, recomputation, transpose) whatever the count; forward
mode's memory is also flat in the horizon. At 4 values the two cost about the
same without XLA:CPU's multi-output fusion, and 4 is the most at which forward
mode wins on a 465-disk pile with it (`jaxpile fit` runs with it); the
measurements are in docs/choices.md, "Forward or reverse mode"."""


def _check_mode(mode: str) -> None:
    if mode not in GRADIENT_MODES:
        raise InputError(f"mode must be one of {GRADIENT_MODES}; got {mode!r}.")


def gradient_mode(size: int, mode: str = "auto") -> str:
    """`"forward"` or `"reverse"`: how `value_and_gradient` takes the gradient
    of `size` fitted values in `mode` (`"auto"`: forward up to
    `FORWARD_MODE_MAX`)."""
    _check_mode(mode)
    if mode == "auto":
        return "forward" if size <= FORWARD_MODE_MAX else "reverse"
    return mode


def value_and_gradient(objective: Callable, u, mode: str = "auto") -> Callable:
    """`(u, *args) -> (value, gradient like u)` of a scalar `objective(u, *args)`,
    compiled (`engine.compile.jit_derivative`): reverse mode, or forward mode
    (`jax.jvp` along each unit vector of the flattened u, in one batch)."""
    if gradient_mode(ravel_pytree(u)[0].size, mode) == "reverse":
        return jit_derivative(jax.value_and_grad(objective))

    def forward(u, *args):
        flat, unravel = ravel_pytree(u)
        values, slopes = jax.vmap(lambda e: jax.jvp(lambda x: objective(unravel(x), *args), (flat,), (e,)))(
            jnp.eye(flat.size, dtype=flat.dtype))
        if values.ndim != 1:  # as jax.grad says of a loss that is not a scalar
            raise TypeError(f"the gradient is only defined for a scalar loss; got shape {values.shape[1:]}.")
        return values[0], unravel(slopes)

    return jit_derivative(forward)


# ---------------------------------------------------------------- fitting
class FitResult(NamedTuple):
    """What `descend` did.

    Attributes:
      params: the params pytree with the lowest loss seen.
      loss: that lowest loss.
      best_step: the step at which it was seen.
      initial_params: the params the fit started from.
      history: one dict per evaluated step: `step`, `loss`, each fitted
        parameter's value, and `grad_norm`, the gradient's global norm in the
        log space the optimiser moves in.
      converged: True when the loss stopped improving (see `descend`'s `patience`).
      steps: optimiser updates taken.
      message: why the fit stopped.
    """

    params: Any
    loss: float
    best_step: int
    initial_params: Any
    history: list[dict]
    converged: bool
    steps: int
    message: str


_tree_norm = getattr(getattr(optax, "tree", None), "norm", None) or optax.global_norm  # optax < 0.2.4: global_norm


def _scalar_or_list(value):
    v = np.asarray(value)
    return float(v) if v.ndim == 0 else v.tolist()


def descend(loss_fn: Callable[[Any], Array], params, names: str | Sequence[str], *,
        optimizer: optax.GradientTransformation | None = None, steps: int = 50, patience: int = 20,
        rtol: float = 1e-6, callback: Callable[[dict], Any] | None = None, progress: bool = False,
        mode: str = "auto") -> FitResult:
    """Minimises `loss_fn` over the parameters `names`, in log space, with optax.

    The fitted parameters move in u = log(value - lower) (`Transform`), so they
    stay above their bounds; every other leaf of `params` stays fixed. The loss
    and its gradient are compiled once (`jax.jit(jax.value_and_grad(...))`).
    Step k evaluates the loss at the current parameters, records it, then applies
    one optimiser update; the last evaluation follows the last update.

    Args:
      loss_fn: `params -> scalar`, traceable (e.g. a rollout, `base_load`,
        `smooth_base_profile` and `profile_loss`).
      params: a law params pytree, or a mapping of names to values.
      names: the parameters to fit (a law's PARAM_NAMES, or the mapping's keys).
      optimizer: an optax transformation; default `optax.adam(0.05)` (steps of
        about 5% in each value). Optimisers with a line search
        (`optax.lbfgs()`) get the loss function they need; for a smooth,
        deterministic loss (a quasi-statically loaded pile) L-BFGS converges in
        far fewer steps than adam.
      steps: the most optimiser updates.
      patience, rtol: stop (`converged=True`) when the best loss has not
        improved by more than `rtol` times its size for `patience` evaluations
        in a row. Adam at a constant rate overshoots and circles the minimum,
        with runs of tens of steps without a new best even on a quadratic: a
        stop then means "stalled at this rate", not "at the minimum". Raise
        `patience` or give the optimiser a decaying rate (`optax.adam(
        optax.exponential_decay(...))`) when that matters.
      callback: called with each history record; returning True stops the fit
        (after step 0, the point it stops at is not taken as the best: a
        callback can veto parameters, e.g. above a stability limit).
      progress: show a progress bar.
      mode: how the gradient is taken: `"reverse"` (`jax.value_and_grad`),
        `"forward"` (one `jax.jvp` per fitted value, batched: no stored
        trajectory, so no memory that grows with the rollout), or `"auto"`:
        forward for up to `FORWARD_MODE_MAX` fitted values, where it is the
        cheaper (docs/choices.md, "Forward or reverse mode"), else reverse.

    Returns:
      `FitResult` with the best params found.

    Raises:
      InputError: on bad names or settings, a loss that is not a scalar, or a
        loss or gradient that is not finite at the start. A loss or gradient
        that turns non-finite later stops the fit with a warning (the result
        keeps the best params so far and says why in `message`).
    """
    _check_settings(steps, patience, rtol, mode)  # before any work
    transform = Transform.of(params, names)
    unconstrained = transform.to_unconstrained(params)
    optimizer = optax.adam(0.05) if optimizer is None else optimizer

    def objective(u, fixed):
        return loss_fn(transform.to_constrained(u, fixed))

    value_and_grad = value_and_gradient(objective, unconstrained, mode)
    update = _update_function(optimizer, objective)
    opt_state = optimizer.init(unconstrained)

    from tqdm.auto import tqdm  # it imports asyncio and more: only when a fit runs

    bar = tqdm(total=int(steps), disable=not progress, unit="step", leave=False, dynamic_ncols=True)
    history: list[dict] = []
    best_loss, best_u, best_step = math.inf, unconstrained, 0
    since_improvement = 0
    converged = False
    message = f"reached the step limit ({steps})."
    taken = 0
    try:
        for step in range(int(steps) + 1):
            loss, grad, record, problem = _evaluate(value_and_grad, transform, unconstrained, params, step)
            if problem is not None:
                message = (f"stopped at step {step}: {problem}; keeping the best parameters, from step "
                           f"{best_step} (loss {best_loss:.6g}).")
                warnings.warn(message, RuntimeWarning, stacklevel=2)
                break
            history.append(record)
            if step > 0 and callback is not None and callback(record) is True:
                message = f"stopped by the callback at step {step}."  # this point is not taken as the best
                break
            loss_value = record["loss"]
            improved = step == 0 or loss_value < best_loss - rtol * abs(best_loss)
            since_improvement = 0 if improved else since_improvement + 1
            if loss_value < best_loss:
                best_loss, best_u, best_step = loss_value, unconstrained, step
            if progress:
                bar.set_postfix(loss=f"{loss_value:.4g}")
            if step == 0 and callback is not None and callback(record) is True:
                message = "stopped by the callback at step 0."
                break
            if since_improvement >= patience:
                converged = True
                message = (f"converged: the loss improved by less than rtol = {rtol:g} (relative) over the last "
                           f"{patience} steps.")
                break
            if step == steps:
                break
            updates, opt_state = update(grad, opt_state, unconstrained, loss, params)
            unconstrained = optax.apply_updates(unconstrained, updates)
            taken += 1
            bar.update(1)
    finally:
        bar.close()
    return FitResult(params=transform.to_constrained(best_u, params), loss=best_loss, best_step=best_step,
                     initial_params=params, history=history, converged=converged, steps=taken, message=message)


def _check_settings(steps, patience, rtol, mode: str) -> None:
    if int(steps) != steps or steps < 0:
        raise InputError(f"steps must be a whole number >= 0; got {steps!r}.")
    if int(patience) != patience or patience < 1:
        raise InputError(f"patience must be a whole number >= 1; got {patience!r}.")
    if not rtol >= 0:
        raise InputError(f"rtol must be >= 0; got {rtol!r}.")
    _check_mode(mode)


def _update_function(optimizer: optax.GradientTransformation, objective: Callable) -> Callable:
    """`(grad, opt_state, u, value, fixed) -> (updates, opt_state)`. An optimiser
    with a line search (`optax.GradientTransformationExtraArgs`, e.g.
    `optax.lbfgs()`) evaluates the loss itself, so it gets the value, the
    gradient and the loss function, compiled once (the line search's loop
    traces the loss into the update); any other takes the gradient alone."""
    if not isinstance(optimizer, optax.GradientTransformationExtraArgs):
        return lambda grad, opt_state, u, value, fixed: optimizer.update(grad, opt_state, u)

    @jax.jit
    def search_update(grad, opt_state, u, value, fixed):
        return optimizer.update(grad, opt_state, u, value=value, grad=grad, value_fn=lambda v: objective(v, fixed))

    return search_update


def _evaluate(value_and_grad: Callable, transform: Transform, u, params, step: int):
    """`(loss, gradient, record, problem)` at the unconstrained values `u`: the
    history record of the step, or (record None) what is not finite there, at
    which values, for the fit to stop on. At step 0 a loss that is not a real
    scalar, or is not finite, raises InputError instead."""
    try:
        loss, grad = value_and_grad(u, params)
    except TypeError as err:
        if step == 0:
            raise InputError(f"loss_fn must return a real scalar: {err}") from None
        raise
    if step == 0 and jnp.shape(loss) != ():
        raise InputError(f"loss_fn must return a scalar; got shape {jnp.shape(loss)}.")
    loss_value = float(loss)
    grad_norm = float(_tree_norm(grad))
    values = transform.to_constrained(u, {})
    if not (math.isfinite(loss_value) and math.isfinite(grad_norm)):
        what = (f"the loss is {loss_value}" if not math.isfinite(loss_value)
                else f"the gradient is not finite (global norm {grad_norm})")
        at = ", ".join(f"{n} = {_scalar_or_list(values[n])}" for n in transform.names)
        if step == 0:
            raise InputError(f"{what} at the starting parameters ({at}); the fit needs a finite loss and "
                             "gradient there: check loss_fn and the starting values.")
        return loss, grad, None, f"{what} ({at})"
    record = {"step": step, "loss": loss_value,
              **{n: _scalar_or_list(values[n]) for n in transform.names}, "grad_norm": grad_norm}
    return loss, grad, record, None


# ------------------------------------------------------------------ figure
def fit_figure(result: FitResult, target: ProfileTarget, before, after, path=None):
    """The loss against the step (log scale) and the normalised profiles: the
    target against the prediction before and after the fit (normal, and
    horizontal when the target has it).

    No backend is forced (notebooks draw inline; without a display matplotlib
    falls back to Agg).

    Args:
      result: from `descend`.
      target: the `ProfileTarget`.
      before, after: `Profile`s (from `smooth_base_profile`) at the initial and
        the fitted parameters.
      path: where to save the figure; then it is closed and the path returned.

    Returns:
      The figure, or `path` when given.
    """
    import matplotlib.pyplot as plt

    panels = 3 if target.horizontal is not None else 2
    fig, axes = plt.subplots(1, panels, figsize=(5.0 * panels, 4.0))
    _draw_loss(axes[0], result)
    fields = [("normal", "normal force / max")]
    if target.horizontal is not None:
        fields.append(("horizontal", "horizontal force / max normal"))
    for ax, (field, label) in zip(axes[1:], fields):
        ax.plot(target.x_over_b, getattr(target, field), "-", color="k", lw=2, label="target")
        for profile, name, style in ((before, "before", "--"), (after, "after", "-")):
            values = getattr(profile, field)
            if values is not None:
                ax.plot(np.asarray(profile.x_over_b), np.asarray(values), style, marker="o", ms=3,
                        label=name)
        ax.set_xlabel("x / B")
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    fig.tight_layout()
    if path is not None:
        fig.savefig(path, dpi=130)
        plt.close(fig)
        return path
    return fig


def _draw_loss(ax, result: FitResult) -> None:
    """The loss against the step, the best point marked, the fitted values at
    the last step in the title."""
    steps = [r["step"] for r in result.history]
    losses = [r["loss"] for r in result.history]
    ax.plot(steps, losses, "-", color="C0", lw=1.2)
    if result.history:
        ax.plot([result.best_step], [result.loss], "o", color="C3", ms=5, label=f"best (step {result.best_step})")
        ax.legend(fontsize=8)
    if any(v > 0 for v in losses):
        ax.set_yscale("log")
    ax.set_xlabel("step")
    ax.set_ylabel("loss")
    ax.set_title(", ".join(f"{k} = {v:.4g}" for k, v in result.history[-1].items()
                           if k not in ("step", "loss", "grad_norm") and isinstance(v, float))
                 if result.history else "no steps", fontsize=9)
    ax.grid(alpha=0.3, which="both")
