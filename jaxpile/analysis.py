"""Measurements on a state: base forces, contact network, speeds and energies."""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp
import numpy as np

from jaxpile.boundaries import GROUND
from jaxpile.simulate import Simulator, max_speed
from jaxpile.state import SimState


class BaseForces(NamedTuple):
    """Every contact between the pile and the ground, sorted by x.

    Attributes:
      x: `[c]` contact x (the disk centre's x).
      normal: `[c]` normal force of the ground on the disk, in mg.
      horizontal: `[c]` horizontal force the disk exerts on the ground, in mg
        (the sign convention of Liffman et al. 1992, eq. 43: negative = leftwards).
      particle: `[c]` disk ids.
    """

    x: np.ndarray
    normal: np.ndarray
    horizontal: np.ndarray
    particle: np.ndarray


def force_unit(state: SimState) -> float:
    """mg: the mean mass of the active movable disks times |g| (g taken as 1
    when gravity is off, so forces are then in units of force)."""
    p = state.particles
    movable = np.asarray(p.movable)
    mass = np.asarray(p.mass)[movable].mean() if movable.any() else 1.0
    g = float(jnp.linalg.norm(state.boundaries.gravity))
    return float(mass) * (g if g > 0 else 1.0)


def base_forces(sim: Simulator, params, state: SimState, wall: int = GROUND) -> BaseForces:
    """Forces at every disk-ground contact (in mg)."""
    cf = sim.contact_forces(params, state)
    in_contact = np.asarray(cf.wall.in_contact[:, wall])
    force = np.asarray(cf.wall.force[:, wall])[in_contact]  # ground on disk
    normal_dir = np.asarray(state.boundaries.wall_normal[wall])
    tangent = np.array([normal_dir[1], -normal_dir[0]])  # +x for the ground
    unit = force_unit(state)
    ids = np.flatnonzero(in_contact)
    x = np.asarray(state.particles.position)[ids, 0]
    order = np.argsort(x)
    return BaseForces(
        x=x[order],
        normal=(force @ normal_dir)[order] / unit,
        horizontal=-(force @ tangent)[order] / unit,
        particle=ids[order],
    )


class ContactNetwork(NamedTuple):
    """Each disk-disk contact once (i < j) with its force, in mg."""

    i: np.ndarray
    j: np.ndarray
    normal: np.ndarray
    tangential: np.ndarray


def contact_network(sim: Simulator, params, state: SimState) -> ContactNetwork:
    cf = sim.contact_forces(params, state)
    idx = np.asarray(state.neighbors.idx)
    n = idx.shape[0]
    rows = np.repeat(np.arange(n)[:, None], idx.shape[1], axis=1)
    keep = np.asarray(cf.pair.in_contact) & (idx > rows) & (idx < n)
    i, j = rows[keep], idx[keep]
    pos = np.asarray(state.particles.position)
    d = pos[i] - pos[j]
    nhat = d / np.linalg.norm(d, axis=1, keepdims=True)
    f = np.asarray(cf.pair.force)[keep]
    fn = np.sum(f * nhat, axis=1)
    ft = np.abs(f[:, 0] * nhat[:, 1] - f[:, 1] * nhat[:, 0])
    unit = force_unit(state)
    return ContactNetwork(i=i, j=j, normal=fn / unit, tangential=ft / unit)


def kinetic_energy(state: SimState) -> float:
    """Translational plus rotational kinetic energy of the movable disks."""
    p = state.particles
    e = 0.5 * p.mass * jnp.sum(p.velocity**2, -1) + 0.5 * p.inertia * p.angular_velocity**2
    return float(jnp.sum(jnp.where(p.movable, e, 0.0)))


__all__ = ["BaseForces", "ContactNetwork", "base_forces", "contact_network", "force_unit", "kinetic_energy", "max_speed"]
