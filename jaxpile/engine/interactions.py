"""All contact forces of a state: each disk pair of the half pair list once,
and every disk against every wall, through one law kernel vectorised with `vmap`.

The pair loop evaluates the law once per pair (i < j, from i's side) and adds
the reaction -F (and the law's torque on j) by a scatter: half the law
evaluations of a full neighbour list, and none for its padding slots beyond
the half list's own (see `pairs.half_pairs`). Pairs that may not interact
(padding, a parked disk, two fixed disks) are handed to the law far apart, so
the law's own out-of-contact branch zeroes them: no separate mask pass over
the outputs.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
from jax import lax

from jaxpile.laws.base import ContactLaw, PairForce, PairGeometry
from jaxpile.engine.pairs import half_slots
from jaxpile.engine.state import Boundaries, Contacts, Particles

Array = Any

FAR = 1e3
"""Where masked partners are put, in units of their contact distance: beyond
every law's reach (the steepest, baxter's (sigma/r)^(n+1), stays finite there)."""


class ContactForces(NamedTuple):
    """Per-contact results and their sums.

    Attributes:
      pair: `PairForce` with leading axis `[P]`, one entry per half pair
        (`contacts.pairs`): force on i (the lower id) from j, torque on i and,
        in `torque_j`, on j. `in_slots` lays them out as the full list's
        `[n, k]` slots, each disk's view of its own contacts.
      wall: `PairForce` with leading axes `[n, w]` (force on i from wall w).
      force: `[n, d]` total contact force on each disk.
      torque: `[n]` total contact torque (zero when the law's rotation is off);
        `[n, 3]` for spheres.
    """

    pair: PairForce
    wall: PairForce
    force: Array
    torque: Array


def _axes(spin_axis: int) -> tuple[PairGeometry, PairForce]:
    """The kernel's batch axes, component-major; a spin is `[m]` (disks, axis
    0) or `[3, m]` (spheres, axis 1), and so are the torques."""
    geometry = PairGeometry(displacement=1, radius_i=0, radius_j=0, velocity=1, angular_velocity_i=spin_axis,
                            angular_velocity_j=spin_axis, effective_mass=0, step_displacements=2, partner_fixed=0)
    force = PairForce(force=1, torque=spin_axis, history=1, normal=0, in_contact=0, torque_j=spin_axis)
    return geometry, force


_AXES = {1: _axes(0), 2: _axes(1)}
"""The kernel's batch axes by the number of axes a spin has per disk batch: 1 (disks), 2 (spheres)."""


def _kernel_over(law: ContactLaw, spin_ndim: int = 1):
    """The law's per-pair kernel over a component-major batch: vectors `[d, m]`,
    histories `[h, m]`, scalars `[m]`. The batch axis last keeps each component
    one contiguous row, so the law's component-by-component arithmetic fuses
    without transposes in its forward pass and without pads in its reverse pass
    (measured: benchmarks/gradient_cost.py). Under `jax.checkpoint` the
    reverse pass recomputes the law instead of storing its residuals: with
    XLA:CPU's multi-output fusion that costs no measurable time and keeps a
    checkpointed reverse's XLA temporaries under half of what they are
    without it. It also keeps the fusion's emitter abort (see
    `engine.compile`) away from the walls' kernel where it runs outside its
    `cond`, as a batched predicate makes it under `vmap` (measured:
    docs/choices.md#checkpointing-the-law-kernel)."""
    geometry_axes, force_axes = _AXES[spin_ndim]
    return jax.vmap(jax.checkpoint(law.pair_force, prevent_cse=False), (None, geometry_axes, 1, None), force_axes)


def pair_ends(fields, i: Array, j: Array) -> tuple:
    """Each per-disk field (`[n]` or `[n, c]`) at the pair ends i and j,
    component-major (`[P]` or `[c, P]`): one gather per field and end."""
    return tuple((x[..., i], x[..., j]) for x in (f.T for f in fields))


def pair_sums(at_i, at_j, i: Array, j: Array, n: int) -> tuple:
    """Per-pair values (component-major, `[P]` or `[c, P]`) summed onto the
    disks, each `[n]` or `[n, c]`: `at_i[k]` at i plus `at_j[k]` at j, where
    `at_j[k]` None stands for the reaction, `-at_i[k]` at j.

    Vector fields all of one width (a sphere's force and torques, `[3, P]`
    each) are stacked side by side into one `[P, 3 m]` scatter onto i and one
    onto j; any other fields (a disk's `[2, P]` force and `[P]` torque) take a
    scatter each onto i and onto j. On a CPU each way is the faster one for
    its shapes (docs/choices.md#pair-sums). Either way each column is summed
    in the same order, so the sums agree bit for bit. (Stacking the i and j
    ends along P instead would be a fusion of its own that evaluates the law
    a second time.)"""
    reaction = [-a if b is None else b for a, b in zip(at_i, at_j)]
    widths = {a.shape[0] if a.ndim == 2 else None for a in at_i}
    if len(at_i) > 1 and len(widths) == 1 and None not in widths:
        w = widths.pop()
        stacked = lambda fields: jnp.concatenate(fields, 0).T  # noqa: E731  [P, w m]
        total = (jax.ops.segment_sum(stacked(at_i), i, n, indices_are_sorted=True)
                 + jax.ops.segment_sum(stacked(reaction), j, n))
        return tuple(total[:, k * w:(k + 1) * w] for k in range(len(at_i)))
    return tuple(jax.ops.segment_sum(a.T, i, n, indices_are_sorted=True) + jax.ops.segment_sum(b.T, j, n)
                 for a, b in zip(at_i, reaction))


def _pair_geometry(particles: Particles, pairs: Array, omega: Array, step_positions=None):
    """The geometry of every half pair, component-major (vectors `[2, P]`; masked
    pairs put `FAR` apart), and the pair ends i, j. (One gather per field: packing
    the fields into one `[n, m]` table gathered by rows is slower on a CPU,
    docs/choices.md#pair-gathers.)"""
    p = particles
    n = p.count
    valid = pairs[:, 0] < n
    i = jnp.where(valid, pairs[:, 0], 0)  # safe gathers; masked pairs are put far apart
    j = jnp.where(valid, pairs[:, 1], 0)
    fixed_i, fixed_j = p.fixed[i], p.fixed[j]
    mask = valid & p.active[i] & p.active[j] & ~(fixed_i & fixed_j)
    m_i, m_j = p.mass[i], p.mass[j]
    m_eff = jnp.where(fixed_j, m_i, jnp.where(fixed_i, m_j, m_i * m_j / (m_i + m_j)))
    # a fixed disk's mass is infinite: keep it out of the masked entries, or
    # inf * 0 in their (discarded) forces turns the gradient NaN
    m_eff = jnp.where(mask, m_eff, 1.0)
    r_i, r_j = p.radius[i], p.radius[j]
    far = jnp.stack([FAR * (r_i + r_j)] + [jnp.zeros_like(r_i)] * (p.dim - 1))

    steps = () if step_positions is None else tuple(step_positions)
    (x_i, x_j), (v_i, v_j), (w_i, w_j), *step_ends = pair_ends((p.position, p.velocity, omega) + steps, i, j)

    def apart(ends):
        return jnp.where(mask, ends[0] - ends[1], far)

    geometry = PairGeometry(
        displacement=apart((x_i, x_j)),
        radius_i=r_i,
        radius_j=r_j,
        velocity=v_i - v_j,
        angular_velocity_i=w_i,
        angular_velocity_j=w_j,
        effective_mass=m_eff,
        step_displacements=None if step_positions is None else jnp.stack([apart(e) for e in step_ends]),
        partner_fixed=fixed_i | fixed_j,
    )
    return geometry, i, j


def evaluate(
    law: ContactLaw,
    params,
    particles: Particles,
    contacts: Contacts,
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
      contacts: the half pair list and its history (`Contacts`).
      boundaries: walls and gravity.
      dt: time step used to advance the history (0 evaluates without advancing).
      step_positions: optional `(x_k, x_{k+1})`, each `[n, 2]`, from the implicit
        midpoint integrator (`particles.position` is then their midpoint); the
        kernels receive the pair displacements at both steps.
    """
    p = particles
    n = p.count
    omega = p.angular_velocity if law.rotation else jnp.zeros_like(p.angular_velocity)

    geometry, i, j = _pair_geometry(p, contacts.pairs, omega, step_positions)
    spin_ndim = omega.ndim - p.position.ndim + 2  # 1 for disks, 2 for spheres
    pair = _kernel_over(law, spin_ndim)(params, geometry, contacts.history.T, dt)
    # each pair once: +F on i, -F on j (and the law's torques on each)
    if law.rotation:
        force, torque = pair_sums((pair.force, pair.torque), (None, pair.torque_j), i, j, n)
    else:
        force, = pair_sums((pair.force,), (None,), i, j, n)
    pair = pair._replace(force=pair.force.T, history=pair.history.T)
    if spin_ndim == 2:  # spheres: torques `[P, 3]`, as the forces
        pair = pair._replace(torque=pair.torque.T, torque_j=pair.torque_j.T)

    wall, wall_force, wall_torque = _wall_forces(law, params, p, omega, contacts.wall_history, boundaries, dt,
                                                 step_positions)
    force = force + wall_force
    if law.rotation:
        torque = torque + wall_torque
    else:
        torque = jnp.zeros_like(p.angular_velocity)
    return ContactForces(pair=pair, wall=wall, force=force, torque=torque)


def _wall_forces(law: ContactLaw, params, p: Particles, omega, wall_history, boundaries: Boundaries, dt,
                 step_positions=None) -> tuple[PairForce, Array, Array]:
    """`PairForce` `[n, w]`: every disk against every wall, walls being partners of
    zero radius and infinite mass at the foot of the normal; and its sums over
    the walls, force `[n, 2]` and torque `[n]`.

    Each wall behind its own `lax.cond` on it being on: a wall that is off
    costs nothing (a pour has none on, the lattice pile only its ground, a box
    loses a wall). Walls that are off give exactly zero either way (the law's
    out-of-contact branch), so both branches agree bit for bit; under `vmap`
    with a wall differing between members its cond becomes a select and costs
    what the kernel alone did. With no wall on, one cond skips them all
    (measured: docs/choices.md#walls)."""
    w = boundaries.wall_normal.shape[0]
    mass_free = (p.active & ~p.fixed)
    wall_law = law.wall_params(params)

    def displacement(x, k, mask):
        """`[2, n]` from wall k's plane to each centre along its normal. A centre
        pushed through the wall keeps the wall's normal (never flips it). Where
        `mask` is False (a fixed or parked disk) the distance is put far out of
        every law's reach: a disk far behind the wall would otherwise sit "1e-6 r
        from it", where a steep law (baxter's (sigma/r)^(n+1)) overflows, and
        inf * 0 in the masked-out force makes NaN gradients."""
        distance = x @ boundaries.wall_normal[k] - boundaries.wall_offset[k]
        distance = jnp.where(mask, jnp.maximum(distance, 1e-6 * p.radius), 1e3 * p.radius)
        return boundaries.wall_normal[k][:, None] * distance[None, :]

    def one(k):
        def on():
            mask = mass_free & boundaries.wall_active[k]
            geometry = PairGeometry(
                displacement=displacement(p.position, k, mask),
                radius_i=p.radius,
                radius_j=jnp.zeros_like(p.radius),
                velocity=p.velocity.T,
                angular_velocity_i=omega.T,
                angular_velocity_j=jnp.zeros_like(omega.T),
                effective_mass=jnp.where(mask, p.mass, 1.0),  # finite where masked (see _pair_geometry)
                step_displacements=None if step_positions is None else jnp.stack(
                    [displacement(x, k, mask) for x in step_positions]),
                partner_fixed=jnp.ones_like(mask),
            )
            spheres = omega.ndim == p.position.ndim
            wall = _kernel_over(law, 2 if spheres else 1)(wall_law, geometry, wall_history[:, k].T, dt)
            return wall._replace(force=wall.force.T, history=wall.history.T,
                                 **({"torque": wall.torque.T, "torque_j": wall.torque_j.T} if spheres else {}))

        def off():
            return jax.tree.map(lambda s: jnp.zeros(s.shape, s.dtype), jax.eval_shape(on))

        return lax.cond(boundaries.wall_active[k], on, off)

    def every_wall():
        walls = [one(k) for k in range(w)]
        stacked = jax.tree.map(lambda *xs: jnp.stack(xs, axis=1), *walls)
        return stacked, sum(wall.force for wall in walls), sum(wall.torque for wall in walls)

    def no_wall():
        return jax.tree.map(lambda s: jnp.zeros(s.shape, s.dtype), jax.eval_shape(every_wall))

    return lax.cond(jnp.any(boundaries.wall_active), every_wall, no_wall)


def in_slots(pair: PairForce, pairs: Array, idx: Array) -> PairForce:
    """Half-pair results laid out as the full neighbour list's slots.

    Args:
      pair: `PairForce` `[P]` from `evaluate`.
      pairs: `[P, 2]` the half pair list they belong to (`half_pairs(idx)`).
      idx: `[n, k]` the full neighbour list.

    Returns:
      `PairForce` `[n, k]`: slot (i, k) holds the force on i from its k-th
      neighbour j and the torque on i (for j < i: the reaction -F and the
      pair's `torque_j`); `history` is the pair's, in the frame of its lower
      id; empty slots are zero and not in contact. Traceable (used by the
      measurements and by `fit`).
    """
    n, k = idx.shape
    keep, entry = half_slots(idx)
    partner = jnp.where(idx < n, idx, 0)
    # j < i: the entry of pair (j, i), found in row j
    back = (idx[partner] == jnp.arange(n, dtype=idx.dtype)[:, None, None]) & keep[partner]  # [n, k, k]
    mirrored = jnp.max(jnp.where(back, entry[partner], -1), axis=-1, initial=-1)
    lower = keep
    upper = (idx < n) & (idx < jnp.arange(n, dtype=idx.dtype)[:, None]) & (mirrored >= 0)
    e = jnp.where(lower, entry, jnp.maximum(mirrored, 0))
    valid = (lower | upper) & (e < pairs.shape[0])  # a pair past the capacity was not evaluated
    e = jnp.where(valid, e, 0)
    sign = jnp.where(lower, 1.0, -1.0).astype(pair.force.dtype)

    def take(x, flip=None):
        v = x[e]
        if flip is not None:
            v = v * flip.reshape(flip.shape + (1,) * (v.ndim - 2))
        return jnp.where(valid.reshape(valid.shape + (1,) * (v.ndim - 2)), v, jnp.zeros_like(v))

    spin = (1,) * (pair.torque.ndim - 1)  # a sphere's torque has a component axis
    torque = jnp.where(lower.reshape(lower.shape + spin), pair.torque[e], pair.torque_j[e])
    return PairForce(
        force=take(pair.force, sign),
        torque=jnp.where(valid.reshape(valid.shape + spin), torque, 0.0),
        history=take(pair.history),
        normal=take(pair.normal),
        in_contact=pair.in_contact[e] & valid,
        torque_j=None,
    )


def external_force(particles: Particles, boundaries: Boundaries) -> Array:
    """`[n, 2]` gravity m g on every active disk."""
    return jnp.where(particles.active[:, None], particles.mass[:, None] * boundaries.gravity[None, :], 0.0)
