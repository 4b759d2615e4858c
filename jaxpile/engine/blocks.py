"""Running only the disks in play: a chunk of a pour on the leading block of its disks.

A pour (or any protocol that brings disks into play in index order) carries
every disk it will ever hold from the first step, the ones not yet poured
parked and inactive. They cost as much per step as disks in the heap: the
pair list, the walls, the integrator and the neighbour build all run over the
whole array. LAMMPS only carries the atoms created so far.

Here a chunk runs on the leading `T` disks instead: `T` is the smallest of a
few fixed capacities (`block_size`: powers of two from `MIN_BLOCK`, finer
steps from `FINE_BLOCK`) that holds every
disk the protocol can have in play by the chunk's end (its `in_play(state,
steps)`), so each capacity compiles once. `take` cuts the state down to the
block, `put` lays the chunk's result back into the full state. A disk
outside the block is parked: it has no neighbour, no pair and does not move,
and the driver never touches it during the chunk (the protocol's `in_play`
promises that), so the block's run does the same arithmetic in the same
order as the full run: the result is bit for bit the same (tests compare the
two). `fits` checks the part of that promise a state can show: no pair and no
neighbour crosses the block's edge and no disk past it is in play; a chunk
whose state fails it runs on the full array.

Per-disk arrays of the protocol's carried state (`protocol_state`) are cut
and laid back too: every leaf whose leading axis has the disk count. The
integrator's carried state must be None (velocity Verlet, leapfrog); Gear's
derivatives keep the full array.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from jaxpile.engine import neighbors as nb
from jaxpile.engine import pairs as pair_list
from jaxpile.engine.state import SimState

Array = Any

MIN_BLOCK = 64
"""The smallest block: below this the step's fixed costs dominate anyway."""

FINE_BLOCK = 512
"""From this size up the blocks step by 1.5x and 4/3x (512, 768, 1024, 1536,
2048, ...), below it by 2x: below ~512 disks a step costs its kernel launches
more than its disks, so finer blocks there save less than their compiles cost
(measured: docs/choices.md#pour-blocks)."""

FINE_SAVING = 1 / 8
"""A block from `FINE_BLOCK` up is used when it leaves out at least this
share of the disks (a smaller block, at least half of them): each size costs
a compile (docs/choices.md#pour-blocks)."""


def block_size(needed: int, count: int) -> int | None:
    """The block for `needed` leading disks out of `count`: the smallest size
    >= max(needed, MIN_BLOCK) of 64, 128, 256, 512, 768, 1024, 1536, 2048, ...,
    or None (the chunk runs on all disks) when it saves too little to be worth
    its own compile: below `FINE_BLOCK` a block must leave out half the disks
    (a 48-disk test pour on 35 substrate disks would compile a 64-block to
    save a fifth), from it up an eighth (`FINE_SAVING`)."""
    size = MIN_BLOCK
    while size < needed:
        power_of_two = size & (size - 1) == 0
        if size < FINE_BLOCK:
            size *= 2
        else:
            size = size * 3 // 2 if power_of_two else size * 4 // 3
    if 2 * size <= count or (size >= FINE_BLOCK and size <= (1 - FINE_SAVING) * count):
        return size
    return None


def fits(state: SimState, size: int) -> bool:
    """Host-side: whether the disks past `size` are out of the run's way now:
    parked (inactive and not fixed), without neighbours, and in no pair."""
    n = state.particles.count
    if state.integrator_state is not None:
        return False
    p = state.particles
    tail_in_play = np.asarray(p.active[size:]) | np.asarray(p.fixed[size:])
    if tail_in_play.any():
        return False
    idx = np.asarray(state.neighbors.idx)
    if np.any((idx[:size] >= size) & (idx[:size] < n)) or np.any(idx[size:] < n):
        return False
    pairs = np.asarray(state.contacts.pairs)
    return not np.any((pairs[:, 1] >= size) & (pairs[:, 1] < n))


def _is_per_disk(x, n: int) -> bool:
    """Whether a leaf is a per-disk array (its leading axis is the disk count)."""
    return hasattr(x, "shape") and x.ndim > 0 and x.shape[0] == n


def _renumber(x: Array, old: int, new: int) -> Array:
    """Index arrays whose empty value is `old` given the empty value `new`."""
    return jnp.where(x == old, new, x)


def pair_room(state: SimState, size: int, at_least: int = 0) -> int:
    """The pair entries of a block of `size` disks: `neighbors.pairs_per_particle`
    per disk (or sphere) of the block that is not fixed (two fixed ones are
    never a pair), the pairs the state holds now and `at_least`, rounded up to
    `PAIR_ALIGN`, and never more than the full list's."""
    held = int(np.sum(np.asarray(state.contacts.pairs[:, 0]) < state.particles.count))
    free = size - int(np.sum(np.asarray(state.particles.fixed[:size])))
    wanted = max(int(np.ceil(nb.pairs_per_particle(state.particles.dim) * free)), held, int(at_least))
    return min(int(state.contacts.pairs.shape[0]), pair_list.aligned(wanted))


def take(state: SimState, size: int, pairs: int) -> SimState:
    """The state of the leading `size` disks, with `pairs` pair entries (it must
    `fits`; the pairs held must fit in `pairs`, which `pair_room` makes sure of)."""
    n = state.particles.count
    c, nbrs = state.contacts, state.neighbors
    cut = lambda x: x[:size]
    held = jnp.sum(c.pairs[:, 0] < n, dtype=jnp.int32)
    contacts = c.set(pairs=_renumber(c.pairs[:pairs], n, size), history=c.history[:pairs],
                     wall_history=c.wall_history[:size], demand=held)
    neighbors = nbrs.set(idx=_renumber(nbrs.idx[:size], n, size), reference_position=nbrs.reference_position[:size])
    return state.set(particles=jax.tree.map(cut, state.particles), contacts=contacts, neighbors=neighbors,
                     protocol_state=jax.tree.map(lambda x: cut(x) if _is_per_disk(x, n) else x, state.protocol_state))


def put(full: SimState, block: SimState) -> SimState:
    """`full` with its leading disks replaced by the block's run: the block's
    neighbour and pair capacities carry over (more pair entries than the full
    state's are kept), the disks past the block as they were."""
    n, size = full.particles.count, block.particles.count
    tail = lambda whole, part: jnp.concatenate([part, whole[size:]])
    c = block.contacts
    entries = max(int(full.contacts.pairs.shape[0]), int(c.pairs.shape[0]))
    extra = entries - c.pairs.shape[0]
    pairs = jnp.concatenate([_renumber(c.pairs, size, n), jnp.full((extra, 2), n, c.pairs.dtype)])
    history = jnp.concatenate([c.history, jnp.zeros((extra,) + c.history.shape[1:], c.history.dtype)])
    contacts = c.set(pairs=pairs, history=history, wall_history=tail(full.contacts.wall_history, c.wall_history))
    b = block.neighbors
    idx = jnp.concatenate([_renumber(b.idx, size, n), jnp.full((n - size, b.idx.shape[1]), n, b.idx.dtype)])
    neighbors = b.set(idx=idx, reference_position=tail(full.neighbors.reference_position, b.reference_position))
    protocol_state = jax.tree.map(
        lambda whole, part: tail(whole, part) if _is_per_disk(whole, n) else part,
        full.protocol_state, block.protocol_state)
    return block.set(particles=jax.tree.map(tail, full.particles, block.particles), contacts=contacts,
                     neighbors=neighbors, protocol_state=protocol_state)


# Compiled once per block size: run op by op, take and put are ~50 eager
# primitives each, every one compiled for each new shape
# (docs/choices.md#eager-compiles).
take_jit = jax.jit(take, static_argnums=(1, 2))
put_jit = jax.jit(put)
