"""Differentiable losses of a predicted base profile against a `ProfileTarget`:
the whole profile (`profile_loss`) or the features it is known to show
(`dip_loss`, `feature_loss`)."""

from __future__ import annotations

from typing import Any

import jax.numpy as jnp

from jaxpile.errors import InputError
from jaxpile.fit.profiles import Profile, central_slope, dip_below_peak, profile_at
from jaxpile.fit.targets import ProfileTarget

Array = Any


def profile_loss(predicted: Profile, target: ProfileTarget, *, horizontal_weight: float = 0.0) -> Array:
    """Mean squared difference between normalised profiles at the target's points.

    loss = mean_m (N_pred(u_m) - N_target(u_m))^2
           + horizontal_weight * mean_m (H_pred(u_m) - H_target(u_m))^2,

    the predicted profile read at the target's x/B by linear interpolation
    between its bin centres, taken as 0 at the feet x/B = 0 and 1 (choose the
    base extent of `smooth_base_profile` at the feet of the pile).

    Args:
      predicted: a `Profile` (from `smooth_base_profile`), normalised.
      target: a `ProfileTarget` (or any `Profile`).
      horizontal_weight: weight of the horizontal term (0: normal only).

    Raises:
      InputError: on a negative weight, or a positive one when either side has
        no horizontal profile.
    """
    if not horizontal_weight >= 0:
        raise InputError(f"horizontal_weight must be >= 0; got {horizontal_weight!r}.")
    u = jnp.asarray(target.x_over_b)
    normal, horizontal = profile_at(predicted, u)
    loss = jnp.mean((normal - jnp.asarray(target.normal)) ** 2)
    if horizontal_weight > 0:
        if horizontal is None or target.horizontal is None:
            raise InputError("horizontal_weight > 0 needs a horizontal profile in both the prediction and the "
                             "target; set horizontal_weight=0 or give a target with a horizontal column.")
        loss = loss + horizontal_weight * jnp.mean((horizontal - jnp.asarray(target.horizontal)) ** 2)
    return loss


def dip_loss(predicted, target_dip: float = 0.25) -> Array:
    """(dip_below_peak(predicted) - target_dip)^2: the squared miss of the central
    minimum's depth (Smid & Novosad: 0.2-0.3, 0.25 in the middle)."""
    return (dip_below_peak(predicted) - target_dip) ** 2


def feature_loss(predicted, target: ProfileTarget, *, dip_weight: float = 1.0, slope_weight: float = 0.0,
                 half_width: float = 0.1) -> Array:
    """Squared misses of a target's features, weighted:

    dip_weight (dip_below_peak(pred) - target.central_dip)^2
    + slope_weight (central_slope(pred) - central_slope(target))^2,

    the slope over |x/B - 1/2| <= half_width (eq. 57's region, about 0.185 wide
    on each side at 32.6 degrees).

    Raises:
      InputError: on a negative weight, or a positive weight for a feature the
        target (or the prediction) does not have.
    """
    if not (dip_weight >= 0 and slope_weight >= 0):
        raise InputError(f"the feature weights must be >= 0; got dip_weight={dip_weight!r}, "
                         f"slope_weight={slope_weight!r}.")
    loss = jnp.zeros(())
    if dip_weight > 0:
        if target.central_dip is None:
            raise InputError("the target has no central_dip; set dip_weight=0 or give one.")
        loss = loss + dip_weight * dip_loss(predicted, target.central_dip)
    if slope_weight > 0:
        slope = central_slope(target, half_width)
        loss = loss + slope_weight * (central_slope(predicted, half_width) - slope) ** 2
    return loss
