"""Building blocks for protocol drivers: pure `state -> state` functions that a
`Simulator(driver=...)` applies at the start of every step inside the compiled
loop. Shapes never change: disks not yet poured exist from the start, parked
and inactive, and a driver activates them.
"""

from __future__ import annotations

from typing import Any, Callable, NamedTuple

import jax.numpy as jnp
from jax import lax

from jaxpile.engine.integrators import per_spin
from jaxpile.engine.simulate import max_speed
from jaxpile.engine.state import SimState
from jaxpile.protocols.geometry import park_where

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
    velocity = jnp.zeros(p.dim, dtype) if velocity is None else jnp.asarray(velocity, dtype)
    hit = (jnp.arange(p.count) == index) & when
    spin = per_spin(hit, p.angular_velocity)  # a sphere's spin is a vector
    p = p.set(
        position=jnp.where(hit[:, None], jnp.asarray(position, dtype)[None, :], p.position),
        velocity=jnp.where(hit[:, None], velocity[None, :], p.velocity),
        angular_velocity=jnp.where(spin, 0.0, p.angular_velocity),
        force=jnp.where(hit[:, None], 0.0, p.force),
        torque=jnp.where(spin, 0.0, p.torque),
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
    energy = p.mass * jnp.sum(p.velocity**2, -1) + p.inertia * p.spin_squared
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


# ---------------------------------------------------------------- pouring
class Pouring(NamedTuple):
    """What the pouring driver carries (`SimState.protocol_state`): the 1997
    pour's and the cone's (disks or spheres, `[n, d]`; heights along the last axis).

    Attributes:
      poured: int scalar, disks released so far.
      total: int scalar, disks to release.
      first: int scalar, index of the first pourable disk (the substrate comes first).
      interval: int scalar, steps between releases (the first at step 0).
      release_position: `[n, 2]` where each disk is released (rows of the
        substrate unused).
      release_velocity: `[2]` velocity at release ((0, 0) unless `insert_height`
        is used).
      park_position: `[n, 2]` where each disk waits (and returns to when lost).
      lost: `[n]` bool, disks that fell off the substrate's ends.
      lost_below: scalar, the centre height below which a disk is lost.
      ends: `[2]` x beyond which a disk's centre has left a flat floor and is
        lost (-inf, inf on a row, which disks leave by falling).
    """

    poured: Array
    total: Array
    first: Array
    interval: Array
    release_position: Array
    release_velocity: Array
    park_position: Array
    lost: Array
    lost_below: Array
    ends: Array


def pouring(state: SimState) -> SimState:
    """The pouring driver (run before every step inside the compiled loop).

    Takes out of play every active disk whose centre fell below `lost_below`
    (it falls off an end of the substrate row) or passed one of a flat floor's
    `ends` (parked again, inactive, counted in `lost`), then on steps `0, interval, 2 interval, ...` releases the next disk
    at its `release_position` with `release_velocity` and with its force set to
    its weight, so the first half kick is the free fall's.
    """
    ps: Pouring = state.protocol_state
    p = state.particles
    x = p.position[:, 0]
    fell = p.active & ~p.fixed & ((p.position[:, -1] < ps.lost_below) | (x < ps.ends[0]) | (x > ps.ends[1]))
    due = (state.step % ps.interval == 0) & (ps.poured < ps.total)

    def act(state: SimState) -> SimState:
        state = park_where(state, fell, ps.park_position)
        index = ps.first + jnp.minimum(ps.poured, ps.total - 1)
        state = activate(state, index, ps.release_position[index], ps.release_velocity, when=due)
        p = state.particles
        hit = (jnp.arange(p.count) == index) & due
        p = p.set(force=jnp.where(hit[:, None], p.mass[:, None] * state.boundaries.gravity[None, :], p.force))
        return state.set(particles=p, protocol_state=ps._replace(poured=ps.poured + due.astype(ps.poured.dtype),
                                                                 lost=ps.lost | fell))

    # most steps neither release nor lose a disk: skip the writes over every disk
    # (a cond; under vmap a select, which costs what the writes alone do). Both branches agree bit for bit then.
    return lax.cond(due | jnp.any(fell), act, lambda s: s, state)


def poured_in_play(state: SimState, steps: int) -> int:
    """Host-side: how many leading disks can be in play during the next `steps`
    steps: the substrate and every disk released by then (disks are released in
    index order, one at each multiple of the interval; lost disks are parked
    at their own index). The `Simulator(in_play=...)` of a pour runs each chunk
    on the smallest block that holds them (`jaxpile.engine.blocks`)."""
    ps: Pouring = state.protocol_state
    step, interval = int(state.step), int(ps.interval)
    releases = (step + int(steps) - 1) // interval - (step - 1) // interval
    return int(ps.first) + min(int(ps.total), int(ps.poured) + max(releases, 0))
