"""Time integrators. Each advances a `SimState` by one step given a function that
returns the contact forces at new positions (and advances the contact history).

velocity_verlet (default): kick-drift-kick, the scheme of LAMMPS `run_style verlet` with
`fix nve/sphere disc` (disks, I = m r^2 / 2): the velocity-dependent forces
(damping, tangential history) are evaluated with the half-step velocities, as
LAMMPS does, so the two codes can be compared step for step. Second order for
smooth conservative forces.

leapfrog: Baxter et al. 1997 eqs. 9-12. Velocities live at half steps (the
state's velocity is v(t - dt/2)); the force F(t) is evaluated at x(t) with the
latest velocity v(t - dt/2), then v(t + dt/2) = v(t - dt/2) + F(t) dt / m and
x(t + dt) = x(t) + v(t + dt/2) dt (likewise the spin with I). Second order.
"""

from __future__ import annotations

from typing import Callable

import jax.numpy as jnp

from jaxpile.state import Particles


def kick(p: Particles, force, torque, h, rotation: bool) -> Particles:
    """Velocities (and spins) of the movable disks advanced by h F / m (h tau / I)."""
    movable = p.movable
    p = p.set(velocity=p.velocity + h * force * jnp.where(movable, 1.0 / p.mass, 0.0)[:, None])
    if rotation:
        p = p.set(angular_velocity=p.angular_velocity + h * torque * jnp.where(movable, 1.0 / p.inertia, 0.0))
    return p


def drift(p: Particles, dt, rotation: bool) -> Particles:
    """Positions (and angles) of the movable disks advanced by dt v (dt omega)."""
    movable = p.movable
    p = p.set(position=jnp.where(movable[:, None], p.position + dt * p.velocity, p.position))
    if rotation:
        p = p.set(angle=jnp.where(movable, p.angle + dt * p.angular_velocity, p.angle))
    return p


def velocity_verlet(
    particles: Particles,
    dt,
    rotation: bool,
    forces_at: Callable[[Particles], tuple],
) -> tuple[Particles, object]:
    """One velocity-Verlet step with rotation: kick dt/2, drift dt, forces, kick dt/2.

    Args:
      particles: the state at t, with `force`/`torque` evaluated at t.
      dt: time step.
      rotation: integrate spins (False: spins stay as they are).
      forces_at: `particles(t + dt, half-step velocities) -> (force, torque, aux)`.

    Returns:
      (particles at t + dt, aux from `forces_at`).
    """
    p = drift(kick(particles, particles.force, particles.torque, 0.5 * dt, rotation), dt, rotation)
    force, torque, aux = forces_at(p)
    p = kick(p, force, torque, 0.5 * dt, rotation)
    return p.set(force=force, torque=torque), aux


def leapfrog(
    particles: Particles,
    dt,
    rotation: bool,
    forces_at: Callable[[Particles], tuple],
) -> tuple[Particles, object]:
    """One leapfrog step (Baxter et al. 1997, eqs. 9-12): forces at t, kick dt
    (eqs. 11-12), drift dt (eqs. 9-10).

    Args:
      particles: positions at t, velocities and spins at t - dt/2.
      forces_at: `particles -> (force, torque, aux)` evaluated at the given
        positions and velocities.

    Returns:
      (particles with x(t + dt), v(t + dt/2) and `force`/`torque` = F(t), aux).
    """
    force, torque, aux = forces_at(particles)
    p = drift(kick(particles, force, torque, dt, rotation), dt, rotation)
    return p.set(force=force, torque=torque), aux


INTEGRATORS = {"velocity_verlet": velocity_verlet, "leapfrog": leapfrog}
