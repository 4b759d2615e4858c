"""Time integrators. Each advances the particles by one step given `forces_at`,
a function that returns the contact + external forces at given positions and
velocities (and advances the contact history).

velocity_verlet (default): kick-drift-kick, the scheme of LAMMPS `run_style verlet` with
`fix nve/sphere disc` (disks, I = m r^2 / 2): the velocity-dependent forces
(damping, tangential history) are evaluated with the half-step velocities, as
LAMMPS does, so the two codes can be compared step for step. Second order for
smooth conservative forces.

leapfrog: Baxter et al. 1997 eqs. 9-12. Velocities live at half steps (the
state's velocity is v(t - dt/2)); the force F(t) is evaluated at x(t) with the
latest velocity v(t - dt/2), then v(t + dt/2) = v(t - dt/2) + F(t) dt / m and
x(t + dt) = x(t) + v(t + dt/2) dt (likewise the spin with I). Second order.

gear: the fifth-order (six-value) Gear predictor-corrector of Allen & Tildesley
(1987, sec. 3.2 and appendix E), used by Lee & Herrmann 1993. One force
evaluation per step, at the predicted positions and velocities.

implicit_midpoint: the energy-conserving implicit scheme of Liffman, Chan &
Hughes 1992 (sec. 2.2, eq. 24): x_{k+1} - x_k = dt (v_k + v_{k+1}) / 2,
v_{k+1} - v_k = dt F_k / m with F_k evaluated between steps k and k+1, solved
by relaxed fixed-point iteration (the paper's Newton-Raphson with simultaneous
over-relaxation, relaxation parameter 0.5-0.9).

An `Integrator` bundles `advance` with `start`, which prepares the state when a
simulation is initialised (the leapfrog's half kick back, Gear's higher
derivatives), and the state it carries between steps (`extra`, kept in
`SimState.integrator_state`).
"""

from __future__ import annotations

from typing import Any, Callable, NamedTuple

import jax
import jax.numpy as jnp
from jax import lax
from jaxpile._jax_md import dataclasses

from jaxpile.errors import InputError
from jaxpile.engine.state import Particles

Array = Any


def per_spin(x, spin):
    """A per-disk array (`[n]`, or `[m, n]` for a batch) laid out against a
    spin-shaped one: as it is for disks (spins `[..., n]`), with a last axis
    of 1 for spheres (spins `[..., n, 3]`)."""
    return x if spin.ndim == x.ndim else x[..., None]


def kick(p: Particles, force, torque, h, rotation: bool) -> Particles:
    """Velocities (and spins) of the movable disks advanced by h F / m (h tau / I)."""
    movable = p.movable
    p = p.set(velocity=p.velocity + h * force * jnp.where(movable, 1.0 / p.mass, 0.0)[:, None])
    if rotation:
        p = p.set(angular_velocity=p.angular_velocity
                  + h * torque * per_spin(jnp.where(movable, 1.0 / p.inertia, 0.0), torque))
    return p


def drift(p: Particles, dt, rotation: bool) -> Particles:
    """Positions (and angles) of the movable disks advanced by dt v (dt omega)."""
    movable = p.movable
    p = p.set(position=jnp.where(movable[:, None], p.position + dt * p.velocity, p.position))
    if rotation:
        p = p.set(angle=jnp.where(per_spin(movable, p.angle), p.angle + dt * p.angular_velocity, p.angle))
    return p


def _no_start(particles: Particles, dt, rotation, force_fn):
    return particles, None


def velocity_verlet(particles: Particles, extra, dt, rotation: bool, forces_at: Callable) -> tuple:
    """One velocity-Verlet step with rotation: kick dt/2, drift dt, forces, kick dt/2.

    Args:
      particles: the state at t, with `force`/`torque` evaluated at t.
      extra: unused (None).
      dt: time step.
      rotation: integrate spins (False: spins stay as they are).
      forces_at: `particles(t + dt, half-step velocities) -> (force, torque, aux)`.

    Returns:
      (particles at t + dt, None, aux from `forces_at`).
    """
    p = drift(kick(particles, particles.force, particles.torque, 0.5 * dt, rotation), dt, rotation)
    force, torque, aux = forces_at(p)
    p = kick(p, force, torque, 0.5 * dt, rotation)
    return p.set(force=force, torque=torque), extra, aux


def leapfrog(particles: Particles, extra, dt, rotation: bool, forces_at: Callable) -> tuple:
    """One leapfrog step (Baxter et al. 1997, eqs. 9-12): forces at t, kick dt
    (eqs. 11-12), drift dt (eqs. 9-10).

    Args:
      particles: positions at t, velocities and spins at t - dt/2.
      forces_at: `particles -> (force, torque, aux)` evaluated at the given
        positions and velocities.

    Returns:
      (particles with x(t + dt), v(t + dt/2) and `force`/`torque` = F(t), None, aux).
    """
    force, torque, aux = forces_at(particles)
    p = drift(kick(particles, force, torque, dt, rotation), dt, rotation)
    return p.set(force=force, torque=torque), extra, aux


def _leapfrog_start(particles: Particles, dt, rotation, force_fn):
    """The velocities given for t = 0 become v(-dt/2) = v(0) - F(0) dt / 2m."""
    return kick(particles, particles.force, particles.torque, -0.5 * dt, rotation), None


# ----------------------------------------------------------------------------- Gear

GEAR_CORRECTOR = (3.0 / 16.0, 251.0 / 360.0, 1.0, 11.0 / 18.0, 1.0 / 6.0, 1.0 / 60.0)
"""Corrector coefficients c_0..c_5 of the six-value Gear method for second-order
equations (Allen & Tildesley 1987, table E.2). A&T suggest c_0 = 3/20 when the
force depends on velocity; we measured no gain from it (see `gear`)."""


@dataclasses.dataclass
class GearDerivatives:
    """The scaled higher derivatives the Gear method carries between steps,
    r_q = dt^q / q! d^q x / dt^q for q = 3, 4, 5 (r_0..r_2 are the position,
    dt * velocity and dt^2 / 2 * force / mass, read from `Particles`).

    Attributes:
      position: `[3, n, d]` r_3, r_4, r_5 of the centres.
      angle: `[3, n]` the same for the rotation angles (`[3, n, 3]` for spheres).
    """

    position: Array
    angle: Array


def _pascal(r):
    """Taylor predictor on stacked scaled derivatives r[0..5] (Pascal's triangle)."""
    r0, r1, r2, r3, r4, r5 = r
    return (
        r0 + r1 + r2 + r3 + r4 + r5,
        r1 + 2 * r2 + 3 * r3 + 4 * r4 + 5 * r5,
        r2 + 3 * r3 + 6 * r4 + 10 * r5,
        r3 + 4 * r4 + 10 * r5,
        r4 + 5 * r5,
        r5,
    )


def gear(particles: Particles, extra: GearDerivatives, dt, rotation: bool, forces_at: Callable) -> tuple:
    """One step of the fifth-order Gear predictor-corrector (Allen & Tildesley
    1987, eqs. 3.14-3.16 and table E.2; the integrator of Lee & Herrmann 1993).

    Predict r_0..r_5 with Pascal's triangle, evaluate the force at the predicted
    positions and velocities, and correct every r_q by c_q (dt^2/2 a - r_2^p).
    The position, velocity and force in `Particles` are r_0, r_1 / dt and
    m * 2 r_2 / dt^2, so a user may edit positions and velocities between runs.

    Measured on a smooth oscillator (tests/test_integrators.py): the error falls
    as dt^4.3-dt^4.6, against dt^2 for velocity Verlet. With velocity-dependent
    forces (damping) the order stays near 4.5 because `start` initialises r_3
    from the exact jerk (a forward-mode derivative of the force); contact
    making and breaking is not smooth, and there every scheme drops to low order.
    """
    movable = particles.movable
    inv_m = jnp.where(movable, 1.0 / particles.mass, 0.0)
    inv_i = per_spin(jnp.where(movable, 1.0 / particles.inertia, 0.0), particles.angle)
    spinning = per_spin(movable, particles.angle)
    h2 = 0.5 * dt * dt

    def predict(x, v, acc, higher):
        return _pascal((x, dt * v, h2 * acc, higher[0], higher[1], higher[2]))

    px = predict(particles.position, particles.velocity, particles.force * inv_m[:, None], extra.position)
    pa = predict(particles.angle, particles.angular_velocity, particles.torque * inv_i, extra.angle)
    p = particles.set(position=jnp.where(movable[:, None], px[0], particles.position),
                      velocity=jnp.where(movable[:, None], px[1] / dt, particles.velocity))
    if rotation:
        p = p.set(angle=jnp.where(spinning, pa[0], particles.angle),
                  angular_velocity=jnp.where(spinning, pa[1] / dt, particles.angular_velocity))
    force, torque, aux = forces_at(p)

    def correct(pred, acc, mask):
        delta = h2 * acc - pred[2]
        out = tuple(q + c * delta for q, c in zip(pred, GEAR_CORRECTOR))
        return tuple(jnp.where(mask, q, jnp.zeros_like(q)) for q in out)

    cx = correct(px, force * inv_m[:, None], movable[:, None])
    p = p.set(position=jnp.where(movable[:, None], cx[0], particles.position),
              velocity=jnp.where(movable[:, None], cx[1] / dt, particles.velocity), force=force)
    higher_x = jnp.stack(cx[3:])
    higher_a = extra.angle
    if rotation:
        ca = correct(pa, torque * inv_i, spinning)
        p = p.set(angle=jnp.where(spinning, ca[0], particles.angle),
                  angular_velocity=jnp.where(spinning, ca[1] / dt, particles.angular_velocity), torque=torque)
        higher_a = jnp.stack(ca[3:])
    else:
        p = p.set(torque=torque)
    return p, GearDerivatives(position=higher_x, angle=higher_a), aux


def _gear_start(particles: Particles, dt, rotation, force_fn):
    """r_3 = dt^3/6 x''' from the exact jerk x''' = (dF/dx . v + dF/dv . a) / m,
    one forward-mode derivative of the force along (v, a) with the contact
    history held; r_4 = r_5 = 0. Starting r_3 at zero would cost two orders with
    velocity-dependent forces (measured: dt^2 instead of dt^5)."""
    movable = particles.movable
    inv_m = jnp.where(movable, 1.0 / particles.mass, 0.0)
    inv_i = jnp.where(movable, 1.0 / particles.inertia, 0.0)
    inv_i = per_spin(inv_i, particles.angle)
    acc = particles.force * inv_m[:, None]
    alpha = particles.torque * inv_i if rotation else jnp.zeros_like(particles.torque)
    _, (d_force, d_torque) = jax.jvp(
        force_fn,
        (particles.position, particles.velocity, particles.angular_velocity),
        (jnp.where(movable[:, None], particles.velocity, 0.0), acc, alpha),
    )
    c3 = dt ** 3 / 6.0
    zeros_x = jnp.zeros((2,) + particles.position.shape, particles.position.dtype)
    zeros_a = jnp.zeros((2,) + particles.angle.shape, particles.angle.dtype)
    r3x = c3 * d_force * inv_m[:, None]
    r3a = c3 * d_torque * inv_i if rotation else jnp.zeros_like(particles.angle)
    return particles, GearDerivatives(position=jnp.concatenate([r3x[None], zeros_x]),
                                      angle=jnp.concatenate([r3a[None], zeros_a]))


# ----------------------------------------------------------- implicit midpoint


def implicit_midpoint_with(relaxation: float = 0.9, iterations: int = 10) -> Callable:
    """The energy-conserving implicit scheme of Liffman, Chan & Hughes 1992
    (sec. 2.2): x_{k+1} = x_k + dt (v_k + v_{k+1}) / 2, v_{k+1} = v_k + dt F_k / m,
    with F_k evaluated at the midpoint positions and velocities of steps k and
    k + 1; the `liffman` law then uses the time-averaged spring of eq. 24,
    K_s [sigma - (r_{k+1} + r_k) / 2], which makes the scheme conserve the spring
    energy exactly (other laws get the implicit midpoint rule).

    The implicit equations are solved by `iterations` sweeps of relaxed
    fixed-point iteration, z <- z + omega (G(z) - z), omega = `relaxation`
    (the paper's simultaneous over-relaxation, omega = 0.5-0.9), from the
    explicit velocity-Verlet guess. A fixed count (not a tolerance) keeps the
    step differentiable and vmappable; each sweep shrinks the error by about
    1 - omega + omega dt^2 k / (4 m), so the default 10 sweeps at omega = 0.9
    reach ~1e-10 of the first correction. Measured on a three-disk collision
    with all dissipation off: kinetic energy after / before - 1 = 1e-14 (20
    sweeps), 8e-7 (8 sweeps, omega = 0.8), against 2e-3 for velocity Verlet at
    the same dt; see tests/test_integrators.py.
    """
    if not 0.0 < relaxation <= 1.0:
        raise InputError(f"the relaxation parameter must be in (0, 1]; got {relaxation}.")
    if int(iterations) != iterations or iterations < 1:
        raise InputError(f"iterations must be a whole number >= 1; got {iterations}.")

    def advance(particles: Particles, extra, dt, rotation: bool, forces_at: Callable) -> tuple:
        p0 = particles
        movable = p0.movable
        inv_m = jnp.where(movable, 1.0 / p0.mass, 0.0)[:, None]
        inv_i = per_spin(jnp.where(movable, 1.0 / p0.inertia, 0.0), p0.angle)

        def solve(force, torque):
            v1 = p0.velocity + dt * force * inv_m
            x1 = jnp.where(movable[:, None], p0.position + 0.5 * dt * (p0.velocity + v1), p0.position)
            w1 = p0.angular_velocity + dt * torque * inv_i if rotation else p0.angular_velocity
            a1 = jnp.where(per_spin(movable, p0.angle), p0.angle + 0.5 * dt * (p0.angular_velocity + w1), p0.angle)
            return x1, v1, a1, w1

        def evaluate(z):
            x1, v1, a1, w1 = z
            mid = p0.set(position=0.5 * (p0.position + x1), velocity=0.5 * (p0.velocity + v1),
                         angle=0.5 * (p0.angle + a1), angular_velocity=0.5 * (p0.angular_velocity + w1))
            return forces_at(mid, (p0.position, x1))

        def relax(z, target):
            return tuple(a + relaxation * (b - a) for a, b in zip(z, target))

        z = solve(p0.force, p0.torque)  # the explicit guess
        force, torque, aux = evaluate(z)

        def sweep(_, carry):
            z, force, torque, aux = carry
            z = relax(z, solve(force, torque))
            force, torque, aux = evaluate(z)
            return z, force, torque, aux

        z, force, torque, aux = lax.fori_loop(0, iterations - 1, sweep, (z, force, torque, aux))
        x1, v1, a1, w1 = relax(z, solve(force, torque))
        p = p0.set(position=x1, velocity=v1, force=force, torque=torque)
        if rotation:
            p = p.set(angle=a1, angular_velocity=w1)
        return p, extra, aux

    return advance


class Integrator(NamedTuple):
    """A time integrator.

    Attributes:
      name: registry name.
      advance: `(particles, extra, dt, rotation, forces_at) -> (particles, extra, aux)`;
        `forces_at(particles, step_positions=None) -> (force, torque, aux)`.
      start: `(particles, dt, rotation, force_fn) -> (particles, extra)`, run once by
        `Simulator.init` after the first force evaluation; `force_fn(position,
        velocity, angular_velocity) -> (force, torque)` with the history held.
      force_step: 1 when the step evaluates its force at t + dt (a schedule is read
        at step + 1), 0 when at t (leapfrog).
      stability_factor: the largest stable step relative to velocity Verlet's
        (omega dt < 2 for a spring, gamma dt < 2 for a dashpot). The eigenvalues
        of Gear's step matrix exceed 1 for omega dt > 0.3 on x'' = -omega^2 x
        and for gamma dt > 0.15 on x'' = -gamma x', so its factor is 0.075.
    """

    name: str
    advance: Callable
    start: Callable
    force_step: int
    stability_factor: float = 1.0


def implicit_midpoint(relaxation: float = 0.9, iterations: int = 10) -> Integrator:
    """The implicit midpoint integrator with a chosen relaxation and sweep count."""
    return Integrator("implicit_midpoint", implicit_midpoint_with(relaxation, iterations), _no_start, 1)


INTEGRATORS = {
    "velocity_verlet": Integrator("velocity_verlet", velocity_verlet, _no_start, 1),
    "leapfrog": Integrator("leapfrog", leapfrog, _leapfrog_start, 0),
    "gear": Integrator("gear", gear, _gear_start, 1, 0.075),
    "implicit_midpoint": implicit_midpoint(),
}


def get_integrator(integrator) -> Integrator:
    """An `Integrator` from its name (or the integrator itself)."""
    if isinstance(integrator, Integrator):
        return integrator
    if integrator not in INTEGRATORS:
        raise InputError(f"unknown integrator {integrator!r}; known: {sorted(INTEGRATORS)}.")
    return INTEGRATORS[integrator]
