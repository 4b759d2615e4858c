"""The base profile of a simulated pile as a function of the law parameters,
and the loss `fit` minimises over them: differentiable through the rollout
that builds the pile."""

from __future__ import annotations

from typing import Any, Callable

import jax

from jaxpile.engine.state import SimState
from jaxpile.errors import InputError
from jaxpile.fit.losses import dip_loss, profile_loss
from jaxpile.fit.profiles import Profile, base_load, smooth_base_profile
from jaxpile.fit.targets import ProfileTarget
from jaxpile.measure.heap import ProfileSetting

Array = Any


def simulated_profile(sim, params, state: SimState, steps: int, setting: ProfileSetting, *,
                      window: int | None = None, checkpoint: bool | int = True) -> Profile:
    """The smooth base profile after `steps` steps from `state` with `params`:
    differentiable in `params` through the whole rollout.

    Args:
      window: differentiate only the last `window` steps (the state before them
        held fixed with `stop_gradient`); None for the whole rollout. A pile
        that has settled responds smoothly to its parameters over a short
        relaxation, while through a long frictional flow the gradient grows
        without bound (benchmarks/gradient_cost.py); fitting a poured heap uses
        a window from the relaxed heap.
      checkpoint: `Simulator.rollout`'s reverse-pass memory setting.
    """
    if int(steps) != steps or steps < 1:
        raise InputError(f"steps must be a whole number >= 1; got {steps!r}.")
    if window is not None and not 1 <= int(window) <= steps:
        raise InputError(f"window must be between 1 and steps ({steps}); got {window!r}.")
    if window is not None and window < steps:
        state = jax.lax.stop_gradient(sim.rollout(params, state, int(steps - window)))
        steps = window
    final = sim.rollout(params, state, int(steps), checkpoint=checkpoint)
    load = base_load(sim, params, final, base=setting.base)
    return smooth_base_profile(load, x_left=setting.x_left, x_right=setting.x_right, bins=setting.bins,
                               bandwidth=setting.bandwidth)


def profile_objective(sim, state: SimState, steps: int, setting: ProfileSetting, target: ProfileTarget, *,
                      window: int | None = None, checkpoint: bool | int = True, horizontal_weight: float = 0.0,
                      dip_weight: float = 0.0) -> Callable[[Any], Array]:
    """`params -> loss`: `profile_loss` (plus `dip_weight` times the squared
    miss of the target's central dip, when it has one) of `simulated_profile`."""
    if dip_weight > 0 and target.central_dip is None:
        raise InputError("dip_weight > 0 needs a target with a central_dip (e.g. smid_novosad_profile()).")

    def loss(params):
        predicted = simulated_profile(sim, params, state, steps, setting, window=window, checkpoint=checkpoint)
        value = profile_loss(predicted, target, horizontal_weight=horizontal_weight)
        if dip_weight > 0:
            value = value + dip_weight * dip_loss(predicted, target.central_dip)
        return value

    return loss
