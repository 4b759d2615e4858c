"""jax-md neighbour lists (Dense format, full list) and contact-history remapping.

Each particle sees each neighbour in one of K slots (`idx[n, K]`, empty = n), and
each side of a pair is computed from its own row: a gather and a sum over the
slot axis, no scatter. `allocate` runs outside jit, `update` inside; the runner
checks `did_buffer_overflow` after each chunk and re-allocates (see `simulate`).
"""

from __future__ import annotations

import functools
from typing import Any, NamedTuple

import jax.numpy as jnp
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


def remap_history(old_partner: Array, old_history: Array, new_idx: Array) -> Array:
    """Carries per-slot history into a new slot layout by matching partner ids.

    Args:
      old_partner: `[n, k_old]` partner ids the history was written for.
      old_history: `[n, k_old, h]`.
      new_idx: `[n, k_new]` the new neighbour list (empty slots hold n).

    Returns:
      `[n, k_new, h]`: each new slot gets the history its partner had in the old
      layout, or zero if the pair is new. O(n k_new k_old), k ~ 10 in 2D.
    """
    n = new_idx.shape[0]
    match = (new_idx[:, :, None] == old_partner[:, None, :]) & (new_idx[:, :, None] < n)
    return jnp.einsum("nko,noh->nkh", match.astype(old_history.dtype), old_history)
