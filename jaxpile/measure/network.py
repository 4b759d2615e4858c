"""The contact network and its force chains: each disk's strongest and weakest
contact, the "lines of maximum and minimum force" of Liffman, Chan & Hughes
1992, Figs. 10 and 16."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from jaxpile.engine.interactions import ContactForces
from jaxpile.engine.simulate import Simulator
from jaxpile.engine.state import SimState
from jaxpile.errors import InputError
from jaxpile.measure.arrays import positive_number
from jaxpile.measure.forces import force_unit


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


def wall_partner(wall: int) -> int:
    """The partner id `force_chains` gives wall `wall`: -1 - wall (ground = -1)."""
    return -1 - int(wall)


class ForceChains(NamedTuple):
    """Each disk's strongest and weakest contact (Liffman, Chan & Hughes 1992, Figs. 10, 16).

    Partners are disk ids `0..n-1`, or walls as `-1 - w` (`wall_partner(w)`: the
    ground is -1); a disk without a contact has partner `n` (the empty-slot mark
    of the neighbour list) and force NaN.

    Attributes:
      strongest: `[n]` partner of the largest contact force on each disk.
      strongest_force: `[n]` its magnitude.
      weakest: `[n]` partner of the smallest contact force on each disk.
      weakest_force: `[n]` its magnitude.
      contacts: `[n]` how many contacts were compared.
    """

    strongest: np.ndarray
    strongest_force: np.ndarray
    weakest: np.ndarray
    weakest_force: np.ndarray
    contacts: np.ndarray


def force_chains(forces: ContactForces, neighbor_idx, *, measure: str = "total",
                 min_force: float = 0.0, unit: float = 1.0) -> ForceChains:
    """For every disk, the partner pushing on it hardest and the one pushing least.

    Liffman et al. draw "the lines of maximum and minimum force" acting on each
    particle (Figs. 10(a), (b) and 16(a), (b)). A contact counts when its slot is
    `in_contact` and its force exceeds `min_force`: so a touching pair that
    carries nothing (the same-level neighbours of the 1992 equilateral pile, of
    which the paper says "no contacts between particles on the same level")
    is not anybody's weakest contact. Ties go to the first slot (disks before walls).

    Args:
      forces: `ContactForces` (`.pair` `[n, k]`, `.wall` `[n, w]`), e.g. from
        `Simulator.contact_forces`.
      neighbor_idx: `[n, k]` the neighbour slots the forces belong to (empty = n).
      measure: `"total"` compares |F| (normal and tangential together);
        `"normal"` compares the normal force `PairForce.normal`.
      min_force: the force a contact must exceed to count (in `unit`s).
      unit: forces are divided by it (e.g. `force_unit(state)` for mg).
    """
    idx = np.asarray(neighbor_idx)
    if idx.ndim != 2 or idx.shape[0] == 0:
        raise InputError(f"neighbor_idx must have shape [n, k] with n > 0; got {idx.shape}.")
    if measure not in ("total", "normal"):
        raise InputError(f"measure must be 'total' or 'normal'; got {measure!r}.")
    unit = positive_number("unit", unit)
    n = idx.shape[0]

    def magnitude(pf):
        value = np.linalg.norm(np.asarray(pf.force), axis=-1) if measure == "total" else np.abs(np.asarray(pf.normal))
        return value / unit

    pair_f, wall_f = magnitude(forces.pair), magnitude(forces.wall)
    if pair_f.shape != idx.shape or wall_f.shape[0] != n:
        raise InputError(f"forces do not match neighbor_idx: pair {pair_f.shape}, "
                         f"wall {wall_f.shape}, idx {idx.shape}.")
    walls = wall_f.shape[1]
    partner = np.concatenate([idx, np.broadcast_to(-1 - np.arange(walls), (n, walls))], axis=1)
    force = np.concatenate([pair_f, wall_f], axis=1)
    counts = np.concatenate([np.asarray(forces.pair.in_contact) & (idx >= 0) & (idx < n),
                             np.asarray(forces.wall.in_contact)], axis=1) & (force > min_force)
    any_contact = counts.any(axis=1)
    rows = np.arange(n)
    high = np.argmax(np.where(counts, force, -np.inf), axis=1)
    low = np.argmin(np.where(counts, force, np.inf), axis=1)

    def pick(col):
        return (np.where(any_contact, partner[rows, col], n),
                np.where(any_contact, force[rows, col], np.nan))

    strongest, strongest_force = pick(high)
    weakest, weakest_force = pick(low)
    return ForceChains(strongest=strongest, strongest_force=strongest_force, weakest=weakest,
                       weakest_force=weakest_force, contacts=counts.sum(axis=1))


def force_chains_of(sim: Simulator, params, state: SimState, **kwargs) -> ForceChains:
    """`force_chains` of a state, forces in mg (`force_unit`)."""
    return force_chains(sim.contact_forces(params, state), state.neighbors.idx,
                        unit=kwargs.pop("unit", force_unit(state)), **kwargs)


__all__ = ["ContactNetwork", "ForceChains", "contact_network", "force_chains", "force_chains_of", "wall_partner"]
