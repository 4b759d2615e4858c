"""Kinetic energy: a state's, the mean per disk over time (Lee & Herrmann 1993,
Fig. 1(b)), and the step from which a series stays at rest."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from jaxpile.engine.state import SimState
from jaxpile.errors import InputError
from jaxpile.measure.arrays import positive_number


def kinetic_energy(state: SimState) -> float:
    """Translational plus rotational kinetic energy of the movable disks."""
    p = state.particles
    e = 0.5 * p.mass * jnp.sum(p.velocity**2, -1) + 0.5 * p.inertia * p.spin_squared
    return float(jnp.sum(jnp.where(p.movable, e, 0.0)))


def _mean_kinetic_energy(mass, velocity, inertia, angular_velocity, movable):
    """Mean over movable disks of m v^2 / 2 + I w^2 / 2; arrays may carry a leading time axis."""
    spin2 = angular_velocity**2 if np.ndim(angular_velocity) < np.ndim(velocity) else np.sum(angular_velocity**2, -1)
    e = 0.5 * mass * np.sum(velocity**2, axis=-1) + 0.5 * inertia * spin2
    count = np.maximum(np.sum(movable, axis=-1), 1)
    return np.sum(np.where(movable, e, 0.0), axis=-1) / count


def mean_kinetic_energy(state: SimState) -> float:
    """Kinetic energy per movable disk (translation plus rotation): the quantity
    Lee & Herrmann 1993 monitor in Fig. 1(b)."""
    p = state.particles
    return float(_mean_kinetic_energy(*(np.asarray(a) for a in (p.mass, p.velocity, p.inertia,
                                                               p.angular_velocity, p.movable))))


def kinetic_energy_series(states) -> np.ndarray:
    """`[T]` kinetic energy per movable disk of each state, for Lee & Herrmann's Fig. 1(b).

    Args:
      states: a sequence of `SimState`s, or one `SimState` whose particle arrays
        carry a leading time axis (a stacked rollout).
    """
    if isinstance(states, SimState):
        p = states.particles
        arrays = [np.asarray(a) for a in (p.mass, p.velocity, p.inertia, p.angular_velocity, p.movable)]
        if arrays[1].ndim != 3:
            raise InputError("a single SimState needs a leading time axis; pass a list of states instead.")
        return np.atleast_1d(_mean_kinetic_energy(*arrays))
    states = list(states)
    if not states:
        raise InputError("no states: the kinetic-energy series of an empty run is undefined.")
    return np.array([mean_kinetic_energy(s) for s in states])


def rest_index(series, tolerance: float) -> int | None:
    """The first index from which `series` (a kinetic energy or max-speed history)
    stays below `tolerance` to its end; None if its last value is not below it.

    Lee & Herrmann 1993 wait "until the maximum velocity of the particles is again
    smaller than v_cut" (sec. 5); this finds when that happened for good.
    """
    values = np.asarray(series, dtype=np.float64)
    if values.ndim != 1 or values.size == 0:
        raise InputError(f"series must be a non-empty 1-D array; got shape {values.shape}.")
    tolerance = positive_number("tolerance", tolerance)
    moving = np.flatnonzero(~(values < tolerance))  # NaN counts as moving
    if moving.size == 0:
        return 0
    last = int(moving[-1])
    return None if last == values.size - 1 else last + 1


__all__ = ["kinetic_energy", "kinetic_energy_series", "mean_kinetic_energy", "rest_index"]
