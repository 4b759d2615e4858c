"""Building blocks for protocol drivers: pure `state -> state` functions that a
`Simulator(driver=...)` applies at the start of every step inside the compiled
loop. Shapes never change: disks not yet poured exist from the start, parked
and inactive, and a driver activates them.
"""

from __future__ import annotations

from typing import Any, Callable

import jax.numpy as jnp
from jax import lax

from jaxpile.engine.simulate import max_speed
from jaxpile.engine.state import SimState

Array = Any


def next_inactive(state: SimState):
    """Index of the first inactive, non-fixed disk, and whether there is one."""
    waiting = ~state.particles.active & ~state.particles.fixed
    return jnp.argmax(waiting), jnp.any(waiting)


def activate(state: SimState, index, position, velocity=None, when=True) -> SimState:
    """Disk `index` placed at `position` with `velocity` (default at rest, no
    spin) and switched on, where `when` holds; the state unchanged otherwise."""
    p = state.particles
    dtype = p.position.dtype
    velocity = jnp.zeros(2, dtype) if velocity is None else jnp.asarray(velocity, dtype)
    hit = (jnp.arange(p.count) == index) & when
    p = p.set(
        position=jnp.where(hit[:, None], jnp.asarray(position, dtype)[None, :], p.position),
        velocity=jnp.where(hit[:, None], velocity[None, :], p.velocity),
        angular_velocity=jnp.where(hit, 0.0, p.angular_velocity),
        force=jnp.where(hit[:, None], 0.0, p.force),
        torque=jnp.where(hit, 0.0, p.torque),
        active=p.active | hit,
    )
    return state.set(particles=p)


def switch_wall_at(step: int, wall: int, on: bool = False) -> Callable[[SimState], SimState]:
    """A driver that sets wall `wall` on or off from step `step` onwards."""

    def driver(state: SimState) -> SimState:
        b = state.boundaries
        flag = jnp.where(state.step >= step, on, b.wall_active[wall])
        return state.set(boundaries=b.set(wall_active=b.wall_active.at[wall].set(flag)))

    return driver


def compose(*drivers: Callable[[SimState], SimState]) -> Callable[[SimState], SimState]:
    """One driver running the given ones in order."""

    def driver(state: SimState) -> SimState:
        for d in drivers:
            state = d(state)
        return state

    return driver


def when(condition: Callable[[SimState], jnp.ndarray], driver: Callable[[SimState], SimState]):
    """A driver that runs `driver` only on steps where `condition(state)` holds
    (a `lax.cond`, so the other branch costs nothing)."""

    def conditional(state: SimState) -> SimState:
        return lax.cond(condition(state), driver, lambda s: s, state)

    return conditional


# ------------------------------------------------ rest, shared by the 1993 drivers and the hopper
def rms_speed(state: SimState) -> Array:
    """sqrt(2 E / M): the mass-weighted rms speed of the movable disks, E their
    kinetic energy (translation and rotation) and M their mass; the kinetic
    energy per disk of Fig. 1(b) expressed as a speed."""
    p = state.particles
    movable = p.movable
    energy = p.mass * jnp.sum(p.velocity**2, -1) + p.inertia * p.angular_velocity**2
    total = jnp.sum(jnp.where(movable, energy, 0.0))
    mass = jnp.sum(jnp.where(movable, p.mass, 0.0))
    return jnp.sqrt(total / jnp.maximum(mass, jnp.finfo(p.mass.dtype).tiny))


def motion(state: SimState, use_max) -> Array:
    """The speed the rest criteria read: `max_speed` where `use_max`, else `rms_speed`."""
    return jnp.where(use_max, max_speed(state), rms_speed(state))


def rest_detector(speed, rest_speed, quiet, armed, hold, fallback):
    """One step of the rest detector shared by this paper's drivers.

    Returns:
      (quiet, armed, rested): `quiet` counts consecutive steps with `speed <
      rest_speed`, `armed` records that the speed reached `rest_speed` (so a
      pile that starts at rest is not taken as settled before it moved), and
      `rested` is true once armed and quiet for `hold` steps, or quiet for
      `fallback` steps without ever moving.
    """
    still = speed < rest_speed
    quiet = jnp.where(still, quiet + 1, 0)
    armed = armed | ~still
    rested = (quiet >= hold) & (armed | (quiet >= fallback))
    return quiet, armed, rested
