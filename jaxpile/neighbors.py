"""jax-md neighbour lists (Dense format, full list), the half pair list built
from them, and contact history carried across rebuilds.

jax-md finds the candidates: each particle sees each neighbour in one of K
slots (`idx[n, K]`, empty = n). The contact laws do not run on those slots.
Each rebuild compacts the full list into a *half* list, `pairs[P, 2]` with
i < j, each pair once (row-major: sorted by i, so the gathers of x_i walk
memory in order; empty entries (n, n)). The law is then evaluated once per
pair and the reaction on j is added by a scatter, as LAMMPS does with its half
list: on the 1035-disk lattice pile, 2970 pairs against 9315 full-list slots,
and one law evaluation per pair instead of two.

The half list has a capacity of its own, P (`pair_capacity_for`): room for 3
pairs per disk (a close-packed 2D pile of equal disks, the most any packing of
them has) or 10% over the pairs at allocation, whichever is more, and never
more than ceil(n K / 2), which holds every pair of the full list. The full
list's K carries head-room for its densest row; P only for the mean, so padding
costs far less (the lattice: 2970 pairs in 3328 entries instead of 4658; a pour
sized for its whole heap from the start, where sizing it for the pairs at
allocation cost three re-allocations, each re-running a chunk). A rebuild
that finds more pairs than P keeps the first P, records the demand in
`Contacts.demand` and raises the list's overflow flag, so the runner re-allocates and re-runs the chunk exactly
as for an overflow of the full list (no contact is ever dropped). `allocate`
runs outside jit, `update` inside; the runner checks `overflowed(state)`
after each chunk (see `simulate`).
"""

from __future__ import annotations

import functools
import math
from typing import Any, NamedTuple

import jax.numpy as jnp
import numpy as np
from jax import lax
from jax_md import partition, space

Array = Any


class NeighborSettings(NamedTuple):
    """Everything a neighbour list is built from (hashable: a static field)."""

    box: tuple[float, float]
    cutoff: float
    skin: float
    capacity_multiplier: float


@functools.lru_cache(maxsize=64)
def neighbor_fn(box: tuple[float, float], cutoff: float, skin: float, capacity_multiplier: float):
    """jax-md `NeighborListFns` for free space, cached so the same settings give
    the same (hashable) update function and compiled steps are reused.

    Args:
      box: `(width, height)` of the region the cell list covers. Free space: a
        particle outside it is hashed periodically into the cells and still
        finds its true neighbours (distances use free-space displacements);
        the box only sets how crowded the cells are.
      cutoff: the largest interaction distance of any pair.
      skin: extra radius; the list is rebuilt when a particle has moved more
        than skin / 2 since the last build.
      capacity_multiplier: head-room on the slot count at allocation.
    """
    displacement, _ = space.free()
    return partition.neighbor_list(
        displacement,
        jnp.asarray(box),
        r_cutoff=cutoff,
        dr_threshold=skin,
        capacity_multiplier=capacity_multiplier,
        format=partition.Dense,
    )


_CELL_LIST_FNS: dict = {}


def allocate(settings: NeighborSettings, position: Array, extra_capacity: int = 0):
    """A new neighbour list (outside jit).

    jax-md builds a new cell-list closure at every allocation, and that closure
    is a static field of the list, so each new list would recompile every jitted
    function it passes through. Lists with the same settings get one canonical
    closure (it depends only on the box, cell size and multiplier)."""
    nbrs = neighbor_fn(*settings).allocate(position, extra_capacity=extra_capacity)
    if nbrs.cell_list_fn is not None:
        nbrs = nbrs.set(cell_list_fn=_CELL_LIST_FNS.setdefault(settings, nbrs.cell_list_fn))
    return nbrs


def any_member(flag: Array, axis_name: str | None) -> Array:
    """`flag` (a bool scalar), or-ed over the named `vmap` axis when there is one.

    Under `vmap` a `lax.cond` whose predicate differs between members becomes a
    `select`: both branches run for every member at every step. An or over the
    batch axis gives one unbatched predicate, so the cond stays a real branch
    and the whole batch skips the work on the steps where no member needs it.
    """
    if axis_name is None:
        return flag
    return lax.pmax(flag.astype(jnp.int32), axis_name) > 0


def needs_rebuild(neighbors, position: Array, skin: float) -> Array:
    """Whether any particle moved more than skin / 2 since the last build
    (jax-md's own criterion, in free space; a hair more eager than jax-md's
    float32 threshold, so it never says no where jax-md would rebuild)."""
    d = position - neighbors.reference_position
    moved = d[:, 0] ** 2 + d[:, 1] ** 2  # written out: a reduce over a size-2 axis is slow on CPU
    return jnp.any(moved > (0.5 * skin) ** 2 * (1.0 - 1e-5))


def update(neighbors, position: Array, skin: float, axis_name: str | None = None):
    """`neighbors.update(position)` behind our own rebuild check (cheaper on CPU
    than jax-md's, which then runs only inside the rebuild branch), decided once
    for a whole batch when `axis_name` names the batch's `vmap` axis.

    jax-md decides per list with a `lax.cond`; vmapped, that cond becomes a
    select and every member rebuilds at every step. Here the rebuild branch runs
    only when some member needs it; inside it, jax-md's own per-member decision
    keeps the members that did not move unchanged, so each member's list is
    exactly what it would be alone."""
    need = any_member(needs_rebuild(neighbors, position, skin), axis_name)
    return lax.cond(need, lambda: neighbors.update(position), lambda: neighbors)


def rebuild_at_capacity(neighbors, position: Array, max_occupancy: int, cell_capacity: int | None):
    """The list rebuilt from `position` with `max_occupancy` slots per particle
    and `cell_capacity` per cell (so lists of a batch share their shapes)."""
    n = position.shape[0]
    # an empty list of the new shape whose reference is infinitely far: update rebuilds it
    forced = neighbors.set(idx=jnp.full((n, int(max_occupancy)), n, neighbors.idx.dtype),
                           error=partition.PartitionError(jnp.zeros((), jnp.uint8)),  # a fresh list: no old overflow
                           max_occupancy=int(max_occupancy), cell_list_capacity=cell_capacity,
                           reference_position=jnp.full_like(position, jnp.inf))
    return forced.update(position)


PAIRS_PER_DISK = 3.0
"""Pair room allocated per disk at least: a close-packed 2D pile of equal disks
has 3 pairs per disk, looser packings fewer."""

PAIR_HEADROOM = 1.1
"""Pair room allocated over the pairs a list holds at allocation (the mean
coordination of a pile moves little; the densest row, which sizes K, more)."""

PAIR_ALIGN = 64
"""Pair capacities are rounded up to a multiple of this. Measured on 2 CPU
cores (45-layer lattice): 4455 entries ran at 246 us per step, 4658 at 178 and
4480 (4455 rounded up) at the figure in the commit; on one core all alike. XLA
splits a loop of an odd length across threads badly."""


def pair_capacity(n: int, slots: int) -> int:
    """Room for the most half pairs a full list with `slots` slots per disk
    can hold, ceil(n K / 2), rounded up to a multiple of `PAIR_ALIGN`."""
    most = max(1, -(-int(n) * int(slots) // 2))
    return -(-most // PAIR_ALIGN) * PAIR_ALIGN


def pairs_needed(state, overflowed) -> int:
    """Host-side: the pair capacity a re-allocation of `state` must give at
    least, after the chunk that ended in `overflowed`: the old one, or, if the
    chunk found more pairs than that, the more of twice it and the demand (a
    chunk that starts with few contacts may end with many)."""
    capacity = int(state.contacts.pairs.shape[-2])
    demand = int(np.max(np.asarray(overflowed.contacts.demand)))
    return capacity if demand <= capacity else max(2 * capacity, demand)


def pair_count(idx: Array) -> Array:
    """The number of half pairs (slots with i < j) of a full list."""
    return jnp.sum(half_slots(idx)[0], dtype=jnp.int32)


def pair_capacity_for(idx: Array, at_least: int = 0) -> int:
    """Host-side: the pair capacity to allocate for the full list `idx`: the
    more of `PAIRS_PER_DISK` per disk and `PAIR_HEADROOM` times its pairs, at
    least `at_least`, at most `pair_capacity` (which holds them all), rounded
    up to `PAIR_ALIGN`."""
    n, k = idx.shape
    wanted = max(int(at_least), math.ceil(PAIRS_PER_DISK * n), math.ceil(PAIR_HEADROOM * int(pair_count(idx))))
    return min(pair_capacity(n, k), -(-wanted // PAIR_ALIGN) * PAIR_ALIGN)


def half_slots(idx: Array) -> tuple[Array, Array]:
    """`[n, K]` bool: the slots (i, k) with i < idx[i, k] (each pair once), and
    `[n, K]` int: each such slot's entry in the half pair list (-1 elsewhere)."""
    n = idx.shape[0]
    keep = (idx < n) & (idx > jnp.arange(n, dtype=idx.dtype)[:, None])
    order = jnp.cumsum(keep.reshape(-1), dtype=jnp.int32).reshape(keep.shape) - 1
    return keep, jnp.where(keep, order, -1)


def half_pairs(idx: Array, capacity: int | None = None) -> Array:
    """The half pair list of a full neighbour list.

    Args:
      idx: `[n, K]` full list (both rows of each pair; empty = n).
      capacity: P, the entries of the result (default `pair_capacity(n, K)`,
        which holds every pair); pairs past it are left out (check
        `pair_count(idx) <= P`: `update_with_contacts` flags an overflow).

    Returns:
      `[P, 2]` int32 `(i, j)` with i < j, each pair once, in row-major slot
      order (sorted by i); empty entries `(n, n)`.
    """
    n, k = idx.shape
    capacity = pair_capacity(n, k) if capacity is None else int(capacity)
    keep, entry = half_slots(idx)
    target = jnp.where(keep, entry, capacity).reshape(-1)  # past the end: dropped
    rows = jnp.broadcast_to(jnp.arange(n, dtype=jnp.int32)[:, None], idx.shape).reshape(-1)
    empty = jnp.full((capacity,), n, jnp.int32)
    i = empty.at[target].set(rows, mode="drop", unique_indices=True)
    j = empty.at[target].set(idx.reshape(-1).astype(jnp.int32), mode="drop", unique_indices=True)
    return jnp.stack([i, j], axis=1)


def carry_history(old_idx: Array, old_history: Array, new_pairs: Array) -> Array:
    """History of the half pairs `new_pairs`, each taken from the same pair
    (i, j) of the old list, or zero for a new pair.

    Args:
      old_idx: `[n, K_old]` the full list the old history's pairs came from
        (`half_pairs(old_idx)` is their layout).
      old_history: `[P_old, h]`.
      new_pairs: `[P_new, 2]`, the half pairs of the new list.

    Returns:
      `[P_new, h]`. Exact (a gather, no arithmetic): a list rebuilt where
      nothing moved gives the same history bit for bit. O(P K_old).
    """
    n = old_idx.shape[0]
    keep, entry = half_slots(old_idx)
    i, j = new_pairs[:, 0], new_pairs[:, 1]
    row = jnp.minimum(i, n - 1)
    match = keep[row] & (old_idx[row] == j[:, None])  # [P_new, K_old]
    found = jnp.max(jnp.where(match, entry[row], -1), axis=1, initial=-1)
    found = jnp.where(found < old_history.shape[0], found, -1)  # past the old capacity: it was not kept
    old = old_history[jnp.maximum(found, 0)]
    return jnp.where(((found >= 0) & (i < n))[:, None], old, jnp.zeros_like(old))


def contacts_for(contacts, old_idx: Array, new_idx: Array, capacity: int | None = None):
    """`contacts` (a `state.Contacts`) re-laid on the half pairs of `new_idx`
    (`capacity` entries; default: as many as now), history carried pair by
    pair from the list `old_idx` it was laid on; the demand restarts from the
    new list's pairs."""
    capacity = contacts.pairs.shape[0] if capacity is None else int(capacity)
    pairs = half_pairs(new_idx, capacity)
    return contacts.set(pairs=pairs, history=carry_history(old_idx, contacts.history, pairs),
                        demand=pair_count(new_idx))


def update_with_contacts(neighbors, contacts, position: Array, skin: float, axis_name: str | None = None):
    """`update` and, when the list was rebuilt, the contacts re-laid on its
    half pairs, in one branch: the steps with no rebuild pay for neither. More
    pairs than the pair capacity raise the list's overflow flag."""
    need = any_member(needs_rebuild(neighbors, position, skin), axis_name)

    def rebuild():
        new = neighbors.update(position)
        laid = contacts_for(contacts, neighbors.idx, new.idx)
        demand = jnp.maximum(contacts.demand, laid.demand)
        over = demand > contacts.pairs.shape[0]
        new = new.set(error=new.error.update(partition.PEC.NEIGHBOR_LIST_OVERFLOW, over))
        return new, laid.set(demand=demand)

    return lax.cond(need, rebuild, lambda: (neighbors, contacts))


def overflowed(state) -> Array:
    """Whether a state's lists lost anything: the full list overflowed, or some
    rebuild (or the laying of the pairs itself) found more half pairs than the
    pair list holds. Traceable; for a batch, per member."""
    return state.neighbors.did_buffer_overflow | (state.contacts.demand > state.contacts.pairs.shape[-2])


def pair_entry(pairs, i: int, j: int) -> int | None:
    """Host-side: the entry of pair (i, j) (either order) in a half pair list, or None."""
    a, b = min(i, j), max(i, j)
    hits = np.flatnonzero((np.asarray(pairs[:, 0]) == a) & (np.asarray(pairs[:, 1]) == b))
    return int(hits[0]) if len(hits) else None

