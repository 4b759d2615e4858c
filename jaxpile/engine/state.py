"""State pytrees: what changes in time, kept apart from the contact-law parameters.

Everything here is a frozen, registered pytree (``jax_md.dataclasses``), so a whole
simulation state passes through ``jit``, ``scan``, ``vmap`` and ``grad`` untouched.
Update with ``state.set(field=value)``.

Units are reduced unless a paper preset says otherwise: lengths in the largest
diameter sigma, masses in the disk mass m, gravity g = 1, forces in mg, time in
sqrt(sigma / g).
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from jaxpile._jax_md import dataclasses, partition

from jaxpile.errors import InputError
from jaxpile.engine import transfer

Array = Any


@dataclasses.dataclass
class Particles:
    """The disks (or spheres): kinematics, inertia and flags. The dimension d
    is the positions' last axis, static; a disk's spin is a number, a sphere's
    a vector.

    Attributes:
      position: `[n, d]` centres.
      velocity: `[n, d]`.
      angle: `[n]` rotation angle (rad), counter-clockwise; for spheres `[n, 3]`,
        the spin integrated over time (spheres carry no orientation, as LAMMPS's
        `nve/sphere`).
      angular_velocity: `[n]` (rad / time), counter-clockwise; `[n, 3]` for spheres.
      force: `[n, d]` total force at the current positions (contacts + gravity);
        the velocity-Verlet integrator reuses it for the next half kick.
      torque: `[n]` total torque at the current positions; `[n, 3]` for spheres.
      radius: `[n]`.
      mass: `[n]` (finite even for fixed disks; `fixed` decides who moves).
      inertia: `[n]` moment of inertia (m r^2 / 2 for a uniform disk, 2 m r^2 / 5
        for a uniform sphere).
      fixed: `[n]` bool; fixed disks never move and count as infinitely heavy
        partners in the contact laws' effective mass.
      active: `[n]` bool; inactive disks exert and feel no force and do not move
        (disks not yet poured exist from the start, parked, with `active=False`).
    """

    position: Array
    velocity: Array
    angle: Array
    angular_velocity: Array
    force: Array
    torque: Array
    radius: Array
    mass: Array
    inertia: Array
    fixed: Array
    active: Array

    @property
    def count(self) -> int:
        return self.position.shape[-2]

    @property
    def dim(self) -> int:
        """2 for disks, 3 for spheres (static: the positions' shape)."""
        return self.position.shape[-1]

    @property
    def spin_squared(self) -> Array:
        """`[n]` |omega|^2: the spin squared (disks), the spin vector's square (spheres)."""
        w = self.angular_velocity
        return w**2 if w.ndim < self.position.ndim else jnp.sum(w**2, -1)

    @property
    def movable(self) -> Array:
        """`[n]` bool: disks the integrator moves (on the host for concrete
        arrays: two eager ops would compile a program each per pile size)."""
        if isinstance(self.active, jax.core.Tracer) or isinstance(self.fixed, jax.core.Tracer):
            return self.active & ~self.fixed
        return transfer.to_device(np.asarray(self.active) & ~np.asarray(self.fixed))


@dataclasses.dataclass
class Contacts:
    """Contact history as fixed-size padded arrays, one entry per pair.

    Attributes:
      pairs: `[P, 2]` int, the half pair list `(i, j)`, i < j, each pair of the
        neighbour list once (`pairs.half_pairs(neighbors.idx)`, rebuilt with
        the list; empty entries `(n, n)`).
      history: `[P, h]` per-pair history, in the frame of the pair's lower id i
        (for `hooke`: the accumulated shear displacement of i relative to j).
        Non-zero only while the pair is in contact; carried pair by pair across
        neighbour-list rebuilds (`pairs.contacts_for`).
      wall_history: `[n, w, h]` the same for each particle against each wall.
      demand: int scalar, the most half pairs any rebuild found since the pair
        list was allocated (more than P: the list overflowed and is re-allocated
        with room for them).
      slot_demand: int scalar, the most neighbours any disk had at a rebuild of
        the full list since it was allocated (more than its K slots: the list
        overflowed, and is re-allocated with room for that many;
        `neighbors.slots_needed`).
    """

    pairs: Array
    history: Array
    wall_history: Array
    demand: Array
    slot_demand: Array


@dataclasses.dataclass
class Boundaries:
    """Run-time boundary settings: changing them never recompiles.

    Walls are half-planes `normal . x >= offset`, with `normal` pointing into
    the granular domain. The default set (see `jaxpile.engine.boundaries.make_boundaries`)
    is the ground y = 0 (wall 0), a left wall (1) and a right wall (2).

    Attributes:
      gravity: `[2]` acceleration vector (tilt it to tilt the pile).
      wall_normal: `[w, 2]` unit normals.
      wall_offset: `[w]` plane offsets.
      wall_active: `[w]` bool; a wall switched off exerts no force and its
        contact history is cleared.
    """

    gravity: Array
    wall_normal: Array
    wall_offset: Array
    wall_active: Array


@dataclasses.dataclass
class SimState:
    """A whole simulation at one instant.

    Attributes:
      particles: the disks.
      contacts: the contact history.
      boundaries: walls and gravity.
      neighbors: the jax-md Dense neighbour list (full list: each pair appears
        in both rows).
      step: int scalar, steps taken since `init`.
      neighbor_settings: static `neighbors.NeighborSettings` (box, cutoff,
        skin, capacity multiplier) the list was built with, so a re-allocation
        always uses this state's own settings.
      integrator_state: what the integrator carries between steps (None for
        velocity Verlet and leapfrog; `integrators.GearDerivatives` for Gear).
      protocol_state: what a protocol's driver carries between steps (e.g. the
        next disk to insert, a log of measurements); None when there is none.
    """

    particles: Particles
    contacts: Contacts
    boundaries: Boundaries
    neighbors: partition.NeighborList
    step: Array
    neighbor_settings: Any = dataclasses.static_field()
    integrator_state: Any = None
    protocol_state: Any = None


def make_particles(
    position,
    radius,
    *,
    mass=None,
    density: float | None = None,
    velocity=None,
    angular_velocity=None,
    fixed=None,
    active=None,
    dtype=None,
) -> Particles:
    """Builds `Particles` with checked inputs.

    The dimension is the position's: `[n, 2]` disks, `[n, 3]` spheres.

    Args:
      position: `[n, 2]` or `[n, 3]` centres.
      radius: `[n]` or a scalar.
      mass: `[n]` or a scalar; default: a uniform areal (disks) or volume
        (spheres) density `density`, by default the one that gives diameter 1
        mass 1.
      density: the density used when `mass` is not given.
      velocity: `[n, d]`, default zero.
      angular_velocity: `[n]` (disks, counter-clockwise) or `[n, 3]` (spheres),
        default zero.
      fixed: `[n]` bool, default all False.
      active: `[n]` bool, default all True.
      dtype: float dtype (default: that of `position` if floating, else
        float64, which needs JAX's float64: `jaxpile.configure()`).

    Raises:
      InputError: on a non-positive radius or mass, a wrong shape, or NaN/inf;
        on float64 while JAX's float64 is off.
    """
    position = np.asarray(position)
    if dtype is None:
        dtype = position.dtype if np.issubdtype(position.dtype, np.floating) else np.float64
    if np.dtype(dtype) == np.float64 and not jax.config.jax_enable_x64:
        raise InputError("float64 particles need JAX's float64, which is off: call jaxpile.configure() right after "
                         "`import jaxpile` (or jax.config.update('jax_enable_x64', True)); for single precision "
                         "give dtype=numpy.float32.")
    position = np.asarray(position, dtype=dtype)
    if position.ndim != 2 or position.shape[1] not in (2, 3):
        raise InputError(f"position must have shape [n, 2] (disks) or [n, 3] (spheres); got {position.shape}.")
    n, dim = position.shape
    if n == 0:
        raise InputError("no particles: position is empty.")

    def per_particle(name, value, dt):
        value = np.asarray(value, dtype=dt)
        if value.ndim > 1 or (value.ndim == 1 and value.shape[0] != n):
            raise InputError(f"{name} must be a scalar or have one value per particle ({n}); got shape {value.shape}.")
        return np.broadcast_to(value, (n,)).copy()

    radius = per_particle("radius", radius, dtype)
    if np.any(~np.isfinite(radius)) or np.any(radius <= 0):
        bad = int(np.flatnonzero(~(radius > 0) | ~np.isfinite(radius))[0])
        raise InputError(
            f"radius must be positive and finite; particle {bad} has radius {float(radius[bad])}."
        )
    if mass is None:
        if dim == 2:
            rho = (4.0 / np.pi) if density is None else float(density)  # diameter 1 -> mass 1
            mass = rho * np.pi * radius**2
        else:
            rho = (6.0 / np.pi) if density is None else float(density)  # diameter 1 -> mass 1
            mass = rho * (4.0 / 3.0) * np.pi * radius**3
    mass = per_particle("mass", mass, dtype)
    if np.any(~np.isfinite(mass)) or np.any(mass <= 0):
        bad = int(np.flatnonzero(~(mass > 0) | ~np.isfinite(mass))[0])
        raise InputError(f"mass must be positive and finite; particle {bad} has mass {float(mass[bad])}.")
    velocity = np.zeros_like(position) if velocity is None else np.asarray(velocity, dtype=dtype)
    if velocity.shape != position.shape:
        raise InputError(f"velocity must have shape {position.shape}; got {velocity.shape}.")
    if dim == 2:
        omega = np.zeros(n, dtype) if angular_velocity is None else per_particle("angular_velocity", angular_velocity,
                                                                                  dtype)
    else:  # a spin vector per sphere
        omega = np.zeros((n, 3), dtype) if angular_velocity is None else np.asarray(angular_velocity, dtype=dtype)
        if omega.shape != (n, 3):
            raise InputError(f"angular_velocity of spheres must have shape {(n, 3)}; got {omega.shape}.")
    fixed = np.zeros(n, bool) if fixed is None else per_particle("fixed", fixed, bool)
    active = np.ones(n, bool) if active is None else per_particle("active", active, bool)
    for name, value in (("position", position), ("velocity", velocity), ("angular_velocity", omega)):
        if not np.all(np.isfinite(value)):
            bad = int(np.flatnonzero(~np.isfinite(value.reshape(n, -1)).all(axis=1))[0])
            raise InputError(f"{name} of particle {bad} is not finite: {value[bad].tolist()}.")
    moving_fixed = fixed & ((np.abs(velocity).sum(axis=1) > 0) | (omega.reshape(n, -1) != 0).any(axis=1))
    if moving_fixed.any():
        bad = int(np.flatnonzero(moving_fixed)[0])
        raise InputError(
            f"fixed particle {bad} has a non-zero velocity or spin; fixed disks never move, "
            "so give them zero velocity."
        )
    return Particles(  # put on the device without compiling (see engine.transfer)
        position=transfer.to_device(position),
        velocity=transfer.to_device(velocity),
        angle=transfer.zeros(omega.shape, dtype),
        angular_velocity=transfer.to_device(omega),
        force=transfer.zeros(position.shape, dtype),
        torque=transfer.zeros(omega.shape, dtype),
        radius=transfer.to_device(radius),
        mass=transfer.to_device(mass),
        inertia=transfer.to_device((0.5 if dim == 2 else 0.4) * mass * radius**2),  # a uniform disk, a uniform sphere
        fixed=transfer.to_device(fixed),
        active=transfer.to_device(active),
    )
