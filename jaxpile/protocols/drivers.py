"""Building blocks for protocol drivers: pure `state -> state` functions that a
`Simulator(driver=...)` applies at the start of every step inside the compiled
loop. Shapes never change: disks not yet poured exist from the start, parked
and inactive, and a driver activates them.
"""

from __future__ import annotations

from typing import Callable

import jax.numpy as jnp
from jax import lax

from jaxpile.state import SimState


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
