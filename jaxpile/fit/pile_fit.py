"""The pathwise fit of one deterministic pile to a base profile: the gradient
through the pile's whole construction (`problem`), descended in log space by
an optax optimiser (`optimise.descend`), stopped before a step where dt would
be above the law's stability limit, and refused if a contact was lost inside
a rollout. What `jaxpile fit --estimator pathwise` and
`calibrate(..., estimator="pathwise")` run.
"""

from __future__ import annotations

import time
import warnings
from typing import NamedTuple, Sequence

import numpy as np

from jaxpile.errors import InputError, SimulationError
from jaxpile.fit.optimise import FitResult, descend
from jaxpile.fit.problem import problem
from jaxpile.fit.profiles import Profile
from jaxpile.fit.simulated import profile_objective, simulated_profile
from jaxpile.fit.targets import ProfileTarget


class PileFit(NamedTuple):
    """A finished pathwise fit.

    Attributes:
      result: `descend`'s `FitResult` (the best params, the loss path).
      before, after: the pile's profile at the start and the fitted values.
      target: the profile fitted to (normalised by its maximum).
      described: the pile, in words.
      seconds: the optimiser's wall time.
    """

    result: FitResult
    before: Profile
    after: Profile
    target: ProfileTarget
    described: str
    seconds: float


def pathwise_target(profile: ProfileTarget, source: str) -> ProfileTarget:
    """`profile` as the pathwise loss compares it (profiles whose maximum is 1),
    or `InputError` when it carries what that loss would ignore (a weight
    scale, standard errors)."""
    if profile.normalised_by != "max" or profile.normal_stderr is not None or profile.horizontal_stderr is not None:
        raise InputError(f"{source} is scaled by the weight or gives standard errors, which a pathwise fit "
                         "(profiles over their maximum, unweighted) would ignore: fit it by the ensemble mean, "
                         "--estimator central.")
    peak = float(np.max(profile.normal))
    return profile._replace(normal=profile.normal / peak,
                            horizontal=None if profile.horizontal is None else profile.horizontal / peak)


def fit_pile(protocol: str, law: str, names: Sequence[str], start: dict, target: ProfileTarget, optimizer, *,
             steps: int = 40, size: int | None = None, seed: int = 0, options: dict | None = None,
             bins: int | None = None, window: int = 2000, horizontal_weight: float = 1.0, dip_weight: float = 0.0,
             progress=None, announce=None) -> PileFit:
    """Builds `protocol`'s pile at `start` and fits `names` through it to `target`.

    Args:
      protocol: a protocol that offers a pathwise fit (`problem.pathwise_of`).
      law, start: the law and its starting parameters (a dict).
      target: the profile, normalised by its maximum (`pathwise_target`).
      optimizer: an optax optimiser; steps: its updates at most.
      size, seed, options, bins, window: the pile (`problem`).
      horizontal_weight: the horizontal profile's weight in the loss, where
        the target has one; dip_weight: the central dip's.
      progress: `descend`'s bar (None: when stderr is a terminal; False: none).
      announce: optional `str -> None`, told the pile before the fit starts.
    """
    import jax
    import jax.numpy as jnp

    names = list(names)
    if steps < 0:
        raise InputError(f"steps must be >= 0; got {steps}.")
    sim, params, state, n, setting, window, described = problem(
        protocol, law, start, size=size, seed=seed, options=options, bins=bins, window=window,
        progress=False if progress is False else None)
    if announce is not None:
        announce(described)
    loss = profile_objective(sim, state, n, setting, target, window=window,
                             horizontal_weight=horizontal_weight if target.horizontal is not None else 0.0,
                             dip_weight=dip_weight)
    profile = jax.jit(lambda p: simulated_profile(sim, p, state, n, setting, window=window))
    stopped = []

    def stable(record) -> bool:
        """Stops the fit before it steps where dt is above the law's stability
        limit (the rollout would blow up and its gradient turn NaN)."""
        try:
            sim.check_params(params.set(**{k: jnp.asarray(record[k]) for k in names}), state.particles)
        except InputError as err:
            stopped.append(f"stopped at step {record['step']}: {err}")
            return True
        return False

    t0 = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # its message is in the result
        result = descend(loss, params, names, optimizer=optimizer, steps=steps, progress=progress is not False,
                         callback=stable)
    seconds = time.perf_counter() - t0
    if stopped:
        result = result._replace(message=stopped[0] + " Keeping the best parameters before it.")
    _check_contacts_kept(sim, state, n, params, result.params)
    return PileFit(result, profile(params), profile(result.params), target, described, seconds)


def _check_contacts_kept(sim, state, steps, start, fitted) -> None:
    """The rollouts are pure (no re-allocation inside): refuses the fit when the
    neighbour list overflowed with the starting or the fitted parameters."""
    import jax

    from jaxpile.engine.neighbors import overflowed as lost_contacts

    overflowed = jax.jit(lambda p: lost_contacts(sim.rollout(p, state, steps)))
    for label, p in (("starting", start), ("fitted", fitted)):
        if bool(overflowed(p)):
            raise SimulationError(f"the neighbour list overflowed in the rollout with the {label} parameters, so "
                                  "contacts were missing from it; the fit is not valid. Give the pile more neighbour "
                                  "head-room (a larger capacity_multiplier) and fit again.")


__all__ = ["PileFit", "fit_pile", "pathwise_target"]
