"""Forces on a pile's base: the ground's (Liffman, Chan & Hughes 1992, Figs. 8-9)
and the fixed substrate disks' (Baxter et al. 1997); `base_load` traceable (for
`jax.grad` and `vmap`), `base_forces` either way (the contacts alone, sorted,
on the host), `substrate_forces` on the host."""

from __future__ import annotations

import functools
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxpile.engine.boundaries import GROUND
from jaxpile.engine.simulate import Simulator
from jaxpile.engine.state import SimState
from jaxpile.errors import InputError

Array = Any

BASES = ("ground", "substrate", "pile")
"""What `base_load` can measure: a flat wall (the ground), the fixed base disks,
or whatever the pile stands on (both: its movable disks' contacts with either)."""


class BaseLoad(NamedTuple):
    """Every possible base contact with its force, as fixed-shape arrays.

    Entries that are not a contact (disks off the ground, empty neighbour slots,
    pairs not involving a fixed disk) are padding: weight 0 and zero x and forces.

    Attributes:
      x: `[c]` contact x: the disk centre's x on the ground; for a base disk, the
        point on the centre line that divides it in the ratio of the radii.
      normal: `[c]` force of the base on the pile normal to the base (the
        ground's normal; along -g for base disks), in mg.
      horizontal: `[c]` force the pile exerts on the base along it (+x for the
        ground), in mg: the sign convention of `analysis.base_forces` (Liffman
        et al. 1992, eq. 43: negative = leftwards).
      weight: `[c]` 1.0 for a contact, 0.0 for padding.
    """

    x: Array
    normal: Array
    horizontal: Array
    weight: Array


@jax.jit  # one program, not ~12 eager ops on a concrete state (a compile each per pile size)
def traced_force_unit(state: SimState):
    """mg as a traceable scalar: the mean mass of the active movable disks times
    |g| (mass 1 when no disk moves, g taken as 1 when gravity is off)."""
    p = state.particles
    movable = p.movable
    count = jnp.sum(movable)
    total = jnp.sum(jnp.where(movable, p.mass, 0.0))
    mass = jnp.where(count > 0, total / jnp.maximum(count, 1), 1.0)
    g2 = jnp.sum(state.boundaries.gravity**2)
    g = jnp.where(g2 > 0, jnp.sqrt(jnp.where(g2 > 0, g2, 1.0)), 1.0)
    return mass * g


def base_load(sim, params, state: SimState, *, base: str = "ground", wall: int = GROUND) -> BaseLoad:
    """The forces at every contact between the pile and its base, traceable.

    Masks instead of boolean indexing, so the shapes do not depend on the
    contacts: usable under `jax.jit` and `jax.grad` (e.g. on the state a
    `Simulator.rollout` returns; `fit` does). Entries are not sorted;
    `base_forces` and `substrate_forces` are the contacts alone, sorted by x.

    Args:
      sim: the `Simulator` (its law evaluates the forces).
      params: the law's params pytree.
      state: the state to measure.
      base: `"ground"`: a wall (`wall`, default the ground), one entry per disk,
        x the disk centre's x. `"substrate"`: the fixed base disks (the poured heap
        of Baxter et al. 1997), one entry per neighbour slot `[n * k]`, "normal"
        along -g (+y when gravity is off). `"pile"`: what the pile stands on,
        the movable disks' contacts with the wall `wall` (where the set-up has
        it) followed by their contacts with fixed disks, `[n + n * k]`: a wall
        floor, a row of fixed disks, or both, without saying which.

    Returns:
      `BaseLoad` of `[n]` (ground), `[n * k]` (substrate) or `[n + n * k]`
      (pile) arrays, forces in mg (`traced_force_unit`).

    Raises:
      InputError: on an unknown `base`.
    """
    if base not in BASES:
        raise InputError(f"base must be one of {list(BASES)}; got {base!r}.")
    return _base_load_from(sim.contact_forces(params, state), state, base, int(wall))


def _along_base(normal):
    """The base's "horizontal" direction for a base of unit normal `normal`:
    +x for the ground (z x n turned back, for disks); for spheres x's part
    in the base's plane, normalised."""
    if normal.shape[0] == 2:
        return jnp.stack([normal[1], -normal[0]])
    e = jnp.zeros_like(normal).at[0].set(1.0) - normal[0] * normal
    size = jnp.sqrt(jnp.sum(e * e))
    return jnp.where(size > 0, e / jnp.where(size > 0, size, 1.0), 0.0)


@functools.partial(jax.jit, static_argnums=(2, 3))
def _base_load_from(cf, state: SimState, base: str, wall: int) -> BaseLoad:
    """`base_load` from the contact forces `cf`: one compiled program (inlined
    when traced), not ~40 primitives each compiled op by op for each shape."""
    if base == "pile":
        parts = [_base_load_from(cf, state, "substrate", wall)]
        if state.boundaries.wall_normal.shape[0] > wall:  # a static shape: the set-up has this wall
            ground = _base_load_from(cf, state, "ground", wall)
            on = ground.weight * state.particles.movable  # a fixed disk on the floor is part of the base
            parts.insert(0, BaseLoad(ground.x * on, ground.normal * on, ground.horizontal * on, on))
        return BaseLoad(*(jnp.concatenate(fields) for fields in zip(*parts)))
    p = state.particles
    unit = traced_force_unit(state)
    if base == "ground":
        contact = cf.wall.in_contact[:, wall]
        force = jnp.where(contact[:, None], cf.wall.force[:, wall], 0.0)  # wall on disk
        normal_dir = state.boundaries.wall_normal[wall]
        along = _along_base(normal_dir)
        x = jnp.where(contact, p.position[:, 0], 0.0)
    else:
        idx = state.neighbors.idx
        n = idx.shape[0]
        valid = idx < n
        partner = jnp.where(valid, idx, 0)
        contact = cf.pair.in_contact & valid & p.movable[:, None] & p.fixed[partner]
        force = jnp.where(contact[..., None], cf.pair.force, 0.0)  # base disk on pile disk
        x_i, x_j = p.position[:, None, 0], p.position[partner, 0]
        r_i, r_j = p.radius[:, None], p.radius[partner]
        x = jnp.where(contact, x_j + (x_i - x_j) * r_j / (r_i + r_j), 0.0)
        g = state.boundaries.gravity
        g2 = jnp.sum(g**2)
        vertical = jnp.zeros(g.shape, g.dtype).at[-1].set(1.0)  # +y for disks, +z for spheres
        up = jnp.where(g2 > 0, -g / jnp.sqrt(jnp.where(g2 > 0, g2, 1.0)), vertical)
        normal_dir = up
        along = _along_base(up)
        contact, force, x = contact.reshape(-1), force.reshape(-1, g.shape[0]), x.reshape(-1)
    normal = (force @ normal_dir) / unit
    horizontal = -(force @ along) / unit
    return BaseLoad(x=x, normal=normal, horizontal=horizontal, weight=contact.astype(force.dtype))


class BaseForces(NamedTuple):
    """Every contact between the pile and the ground, sorted by x (numpy
    arrays); under a trace, every disk, padding included (`base_forces`).

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
    return float(traced_force_unit(state))


def base_forces(sim: Simulator, params, state: SimState, wall: int = GROUND, *, base: str = "pile") -> BaseForces:
    """Forces at every contact of the pile with its base (in mg), eagerly or
    under a trace: by default whatever the pile stands on, a wall floor (the
    box, the lattice) or a row of fixed disks (the poured heap, the flux pile,
    the silo), its movable disks' contacts with either (`base_load`'s
    `"pile"`); `base="ground"` or `"substrate"` reads one of them alone.

    Eagerly: the contacts alone, sorted by x (none while the pile is in the
    air). Under `jax.grad`, `jax.vmap` or `jax.jit`, where how many disks touch
    the base is not known: one entry per possible contact (each disk on the
    ground, then each neighbour slot), those that are not a contact with
    particle -1 and zero x and forces, so sums, force-weighted means and the
    maximum normal force are the eager ones (a maximum or minimum of the
    horizontal force, which takes both signs, can be the padding's 0: mask with
    `particle >= 0`).

        load = lambda p: jaxpile.base_forces(sim, p, sim.rollout(p, state, 100)).normal.max()
        jax.grad(load)(params)

    Raises:
      InputError: eagerly, for a set-up with no base to read: no active wall
        `wall` and no fixed disk (for `base="pile"`), or none of the one named.
    """
    load = base_load(sim, params, state, base=base, wall=wall)
    n = state.particles.count
    slots = np.arange(state.neighbors.idx.size) // max(state.neighbors.idx.shape[1], 1)
    ids = {"ground": np.arange(n), "substrate": slots, "pile": np.concatenate(
        [np.arange(n)] * (state.boundaries.wall_normal.shape[0] > wall) + [slots])}[base]
    if any(isinstance(leaf, jax.core.Tracer) for leaf in jax.tree_util.tree_leaves((load, params, state))):
        return BaseForces(x=load.x, normal=load.normal, horizontal=load.horizontal,
                          particle=jnp.where(load.weight > 0, jnp.asarray(ids), -1))
    _check_has_base(state, base, wall)
    keep = np.flatnonzero(np.asarray(load.weight) > 0)
    x = np.asarray(load.x)[keep]
    order = np.argsort(x, kind="stable")
    return BaseForces(x=x[order], normal=np.asarray(load.normal)[keep][order],
                      horizontal=np.asarray(load.horizontal)[keep][order], particle=ids[keep][order])


def _check_has_base(state: SimState, base: str, wall: int) -> None:
    """Refuses to read a base the set-up does not have (an empty answer would
    look like a pile in the air)."""
    b, p = state.boundaries, state.particles
    floor = b.wall_normal.shape[0] > wall and bool(np.asarray(b.wall_active)[wall])
    fixed = bool(np.any(np.asarray(p.fixed) & np.asarray(p.active)))
    lacks = {"pile": None if floor or fixed else "neither an active floor wall nor fixed disks",
             "ground": None if floor else f"no active wall {wall}", "substrate": None if fixed else "no fixed disks"}
    if lacks[base] is not None:
        raise InputError(f"this set-up has {lacks[base]}, so it has no base whose forces could be read"
                         + ("." if base == "pile" else "; leave base out to read what the pile stands on."))


class SubstrateForces(NamedTuple):
    """Every contact between a movable disk and a fixed (substrate) disk, sorted
    by x, in mg (`force_unit`: the mean movable mass times g). The fields of
    `BaseForces`, plus the substrate partner.

    Attributes:
      x: `[c]` x of the contact point (on the centre line, dividing it in the
        ratio of the radii).
      normal: `[c]` force of the substrate on the heap normal to the base
        (upwards, along -g): the paper's F_B.
      horizontal: `[c]` force the heap disk exerts on the substrate along the
        base (+x; the sign convention of `analysis.base_forces`).
      particle: `[c]` the movable disk ids.
      substrate: `[c]` the substrate disk ids.
    """

    x: np.ndarray
    normal: np.ndarray
    horizontal: np.ndarray
    particle: np.ndarray
    substrate: np.ndarray


def substrate_forces(sim, params, state: SimState) -> SubstrateForces:
    """Forces at every contact of a movable disk with a fixed one (a row of base
    disks: the poured heap of Baxter et al. 1997, the flux pile of Lee & Herrmann
    1993), in mg, with "normal" along -g: `base_load`'s contacts, sorted by x."""
    load = base_load(sim, params, state, base="substrate")
    idx = np.asarray(state.neighbors.idx)
    keep = np.flatnonzero(np.asarray(load.weight) > 0)  # flat [n * k] slots
    i, j = keep // idx.shape[1], idx.reshape(-1)[keep]
    x = np.asarray(load.x)[keep]
    order = np.argsort(x, kind="stable")
    return SubstrateForces(x=x[order], normal=np.asarray(load.normal)[keep][order],
                           horizontal=np.asarray(load.horizontal)[keep][order], particle=i[order],
                           substrate=j[order])


__all__ = ["BASES", "BaseForces", "BaseLoad", "SubstrateForces", "base_forces", "base_load", "force_unit", "substrate_forces", "traced_force_unit"]
