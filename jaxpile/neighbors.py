"""jax-md neighbour lists (Dense format, full list) and contact-history remapping.

Each particle sees each neighbour in one of K slots (`idx[n, K]`, empty = n), and
each side of a pair is computed from its own row: a gather and a sum over the
slot axis, no scatter. `allocate` runs outside jit, `update` inside; the runner
checks `did_buffer_overflow` after each chunk and re-allocates (see `simulate`).
"""

from __future__ import annotations

import functools
from typing import Any

import jax.numpy as jnp
from jax_md import partition, space

Array = Any


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
