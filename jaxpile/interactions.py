"""All contact forces of a state: disk pairs from the neighbour slots and every
disk against every wall, through one law kernel vectorised with `vmap`."""

from __future__ import annotations

from typing import Any, NamedTuple

import jax
import jax.numpy as jnp

from jaxpile.boundaries import wall_distance
from jaxpile.laws.base import ContactLaw, PairForce, PairGeometry
from jaxpile.state import Boundaries, Contacts, Particles

Array = Any


class ContactForces(NamedTuple):
    """Per-slot results and their sums.

    Attributes:
      pair: `PairForce` with leading axes `[n, k]` (row i, slot k: force on i
        from its k-th neighbour).
      wall: `PairForce` with leading axes `[n, w]` (force on i from wall w).
      force: `[n, 2]` total contact force on each disk.
      torque: `[n]` total contact torque (zero when the law's rotation is off).
    """

    pair: PairForce
    wall: PairForce
    force: Array
    torque: Array


def _kernel_over_slots(law: ContactLaw):
    one = law.pair_force
    return jax.vmap(jax.vmap(one, (None, 0, 0, None)), (None, 0, 0, None))


def _mask(pf: PairForce, mask) -> PairForce:
    return PairForce(
        force=jnp.where(mask[..., None], pf.force, 0.0),
        torque=jnp.where(mask, pf.torque, 0.0),
        history=jnp.where(mask[..., None], pf.history, 0.0),
        normal=jnp.where(mask, pf.normal, 0.0),
        in_contact=pf.in_contact & mask,
    )


def evaluate(
    law: ContactLaw,
    params,
    particles: Particles,
    contacts: Contacts,
    neighbor_idx: Array,
    boundaries: Boundaries,
    dt,
    step_positions=None,
) -> ContactForces:
    """Forces, torques and new history of every contact.

    Args:
      law: the contact law.
      params: its parameters pytree.
      particles: positions, velocities (at the half step when called from the
        integrator), spins.
      contacts: history aligned with `neighbor_idx`.
      neighbor_idx: `[n, k]` neighbour slots (empty = n).
      boundaries: walls and gravity.
      dt: time step used to advance the history (0 evaluates without advancing).
      step_positions: optional `(x_k, x_{k+1})`, each `[n, 2]`, from the implicit
        midpoint integrator (`particles.position` is then their midpoint); the
        kernels receive the pair displacements at both steps.
    """
    p = particles
    n = p.count
    valid = neighbor_idx < n
    j = jnp.where(valid, neighbor_idx, 0)  # safe gather; masked below
    omega = p.angular_velocity if law.rotation else jnp.zeros_like(p.angular_velocity)

    m_i, m_j = p.mass[:, None], p.mass[j]
    fixed_i, fixed_j = p.fixed[:, None], p.fixed[j]
    pair_mask = valid & p.active[:, None] & p.active[j] & ~(fixed_i & fixed_j) & (j != jnp.arange(n)[:, None])
    m_eff = jnp.where(fixed_j, m_i, jnp.where(fixed_i, m_j, m_i * m_j / (m_i + m_j)))
    # a fixed disk's mass is infinite: keep it out of the slots that are masked anyway,
    # or inf * 0 in their (discarded) forces turns the gradient NaN
    m_eff = jnp.where(pair_mask, m_eff, 1.0)
    shape = j.shape
    pair_geometry = PairGeometry(
        displacement=p.position[:, None, :] - p.position[j],
        radius_i=jnp.broadcast_to(p.radius[:, None], shape),
        radius_j=p.radius[j],
        velocity=p.velocity[:, None, :] - p.velocity[j],
        angular_velocity_i=jnp.broadcast_to(omega[:, None], shape),
        angular_velocity_j=omega[j],
        effective_mass=m_eff,
        step_displacements=None if step_positions is None else jnp.stack(
            [x[:, None, :] - x[j] for x in step_positions], axis=-2),
    )
    kernel = _kernel_over_slots(law)
    pair = kernel(params, pair_geometry, contacts.history, dt)
    pair = _mask(pair, pair_mask)

    # Walls: partners of zero radius and infinite mass at the foot of the normal.
    w = boundaries.wall_normal.shape[0]
    wshape = (n, w)
    wall_mask = boundaries.wall_active[None, :] & (p.active & ~p.fixed)[:, None]
    wall_geometry = PairGeometry(
        displacement=_wall_displacement(boundaries, p.position, p.radius, wall_mask),
        radius_i=jnp.broadcast_to(p.radius[:, None], wshape),
        radius_j=jnp.zeros(wshape, p.radius.dtype),
        velocity=jnp.broadcast_to(p.velocity[:, None, :], wshape + (2,)),
        angular_velocity_i=jnp.broadcast_to(omega[:, None], wshape),
        angular_velocity_j=jnp.zeros(wshape, omega.dtype),
        effective_mass=jnp.where(wall_mask, p.mass[:, None], 1.0),  # finite where masked (see above)
        step_displacements=None if step_positions is None else jnp.stack(
            [_wall_displacement(boundaries, x, p.radius, wall_mask) for x in step_positions], axis=-2),
    )
    wall = kernel(law.wall_params(params), wall_geometry, contacts.wall_history, dt)
    wall = _mask(wall, wall_mask)

    force = pair.force.sum(axis=1) + wall.force.sum(axis=1)
    torque = pair.torque.sum(axis=1) + wall.torque.sum(axis=1)
    if not law.rotation:
        torque = jnp.zeros_like(torque)
    return ContactForces(pair=pair, wall=wall, force=force, torque=torque)


def _wall_displacement(boundaries: Boundaries, position, radius, mask=None):
    """`[n, w, 2]` from each wall plane to each centre along the wall normal.
    Where `mask` is False (a wall that is off, a fixed or parked disk) the
    distance is put far out of every law's reach: a disk far behind a wall that is
    off would otherwise sit "1e-6 r from it", where a steep law (baxter's
    (sigma/r)^(n+1)) overflows, and inf * 0 in the masked-out force makes NaN
    gradients."""
    distance = wall_distance(boundaries, position)  # [n, w]
    # A centre pushed through a wall keeps the wall's normal (never flips it).
    distance = jnp.maximum(distance, 1e-6 * radius[:, None])
    if mask is not None:
        distance = jnp.where(mask, distance, 1e3 * radius[:, None])
    return distance[..., None] * boundaries.wall_normal[None, :, :]


def external_force(particles: Particles, boundaries: Boundaries) -> Array:
    """`[n, 2]` gravity m g on every active disk."""
    return jnp.where(particles.active[:, None], particles.mass[:, None] * boundaries.gravity[None, :], 0.0)
