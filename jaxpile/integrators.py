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


def velocity_verlet(
    particles: Particles,
    dt,
    rotation: bool,
    forces_at: Callable[[Particles], tuple],
) -> tuple[Particles, object]:
    """One velocity-Verlet step with rotation.

    Args:
      particles: the state at t, with `force`/`torque` evaluated at t.
      dt: time step.
      rotation: integrate spins (False: spins stay as they are).
      forces_at: `particles(t + dt, half-step velocities) -> (force, torque, aux)`.

    Returns:
      (particles at t + dt, aux from `forces_at`).
    """
    p = particles
    movable = p.movable
    inv_m = jnp.where(movable, 1.0 / p.mass, 0.0)[:, None]
    v_half = p.velocity + 0.5 * dt * p.force * inv_m
    x_new = jnp.where(movable[:, None], p.position + dt * v_half, p.position)
    if rotation:
        inv_i = jnp.where(movable, 1.0 / p.inertia, 0.0)
        w_half = p.angular_velocity + 0.5 * dt * p.torque * inv_i
        angle = jnp.where(movable, p.angle + dt * w_half, p.angle)
    else:
        inv_i, w_half, angle = None, p.angular_velocity, p.angle
    drifted = p.set(position=x_new, velocity=v_half, angular_velocity=w_half, angle=angle)
    force, torque, aux = forces_at(drifted)
    v_new = v_half + 0.5 * dt * force * inv_m
    w_new = w_half + 0.5 * dt * torque * inv_i if rotation else w_half
    return drifted.set(velocity=v_new, angular_velocity=w_new, force=force, torque=torque), aux


def leapfrog(
    particles: Particles,
    dt,
    rotation: bool,
    forces_at: Callable[[Particles], tuple],
) -> tuple[Particles, object]:
    """One leapfrog step (Baxter et al. 1997, eqs. 9-12).

    Args:
      particles: positions at t, velocities and spins at t - dt/2.
      forces_at: `particles -> (force, torque, aux)` evaluated at the given
        positions and velocities.

    Returns:
      (particles with x(t + dt), v(t + dt/2) and `force`/`torque` = F(t), aux).
    """
    p = particles
    movable = p.movable
    force, torque, aux = forces_at(p)
    inv_m = jnp.where(movable, 1.0 / p.mass, 0.0)[:, None]
    v_new = p.velocity + dt * force * inv_m  # (11)
    x_new = jnp.where(movable[:, None], p.position + dt * v_new, p.position)  # (9)
    if rotation:
        w_new = p.angular_velocity + dt * torque * jnp.where(movable, 1.0 / p.inertia, 0.0)  # (12)
        angle = jnp.where(movable, p.angle + dt * w_new, p.angle)  # (10)
    else:
        w_new, angle = p.angular_velocity, p.angle
    return p.set(position=x_new, velocity=v_new, angular_velocity=w_new, angle=angle, force=force,
                 torque=torque), aux


INTEGRATORS = {"velocity_verlet": velocity_verlet, "leapfrog": leapfrog}
