"""The half pair list: each interacting pair once, laid out from a full
neighbour list, and the contact history carried pair by pair onto a new
layout when the list is rebuilt.

A full list `idx` `[n, K]` holds both rows of each pair (empty = n); its half
pairs `[P, 2]` are the slots with i < j, in row-major slot order, empty
entries `(n, n)` last. The contact history `[P, h]` lives on those pairs
(`state.Contacts`); a rebuild re-lays it (`contacts_for`), a gather with no
arithmetic, so a list rebuilt where nothing moved keeps it bit for bit.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax

Array = Any


PAIR_ALIGN = 64
"""Pair capacities are rounded up to a multiple of this: XLA splits a loop of an
odd length across threads badly (measured: docs/choices.md#neighbour-lists)."""


def aligned(entries: int) -> int:
    """`entries` rounded up to a multiple of `PAIR_ALIGN`."""
    return -(-int(entries) // PAIR_ALIGN) * PAIR_ALIGN


def pair_capacity(n: int, slots: int) -> int:
    """Room for the most half pairs a full list with `slots` slots per disk
    can hold, ceil(n K / 2), rounded up to a multiple of `PAIR_ALIGN`."""
    most = max(1, -(-int(n) * int(slots) // 2))
    return aligned(most)


def slot_count(idx: Array) -> Array:
    """The most neighbours any row of a full list holds."""
    return jnp.max(jnp.sum(idx < idx.shape[0], axis=1, dtype=jnp.int32), initial=0)


def pair_count(idx: Array) -> Array:
    """The number of half pairs (slots with i < j) of a full list."""
    return jnp.sum(half_slots(idx)[0], dtype=jnp.int32)


def half_slots(idx: Array) -> tuple[Array, Array]:
    """`[n, K]` bool: the slots (i, k) with i < idx[i, k] (each pair once), and
    `[n, K]` int: each such slot's entry in the half pair list (-1 elsewhere),
    in row-major slot order.

    A slot's entry is the kept slots of the rows above plus the kept slots to
    its left in its row: a cumulative sum over the n rows and a K x K triangle
    within each, not a cumulative sum over all n K slots (on a CPU XLA writes a
    cumsum as a reduce-window whose cost grows with its length:
    docs/choices.md#neighbour-lists)."""
    n, k = idx.shape
    keep = (idx < n) & (idx > jnp.arange(n, dtype=idx.dtype)[:, None])
    count = jnp.sum(keep, axis=1, dtype=jnp.int32)
    rows_above = jnp.cumsum(count, dtype=jnp.int32) - count
    left = jnp.arange(k)[:, None] < jnp.arange(k)[None, :]  # [k', k]: slot k' lies left of slot k
    in_row = jnp.sum(keep[:, :, None] & left[None], axis=1, dtype=jnp.int32)
    return keep, jnp.where(keep, rows_above[:, None] + in_row, -1)


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


def sorted_half_pairs(idx: Array, capacity: int | None = None) -> Array:
    """`half_pairs` of a full list whose rows hold their neighbours in
    increasing index order, empty entries last, as every list the builders
    make (`neighbors._build`, `host_lists.build`). A row's pairs, its
    neighbours above it, are then one run of its slots: each entry of the
    half list is read by a gather from where its row's run starts, instead of
    laid by a scatter over all n K slots, which made most of a rebuild's
    `half_pairs` (measured: docs/choices.md#neighbour-lists). The same pairs.
    """
    n, k = idx.shape
    capacity = pair_capacity(n, k) if capacity is None else int(capacity)
    me = jnp.arange(n, dtype=jnp.int32)
    valid = idx < n
    keep = valid & (idx > me[:, None].astype(idx.dtype))
    count = jnp.sum(keep, axis=1, dtype=jnp.int32)
    below = jnp.sum(valid & ~keep, axis=1, dtype=jnp.int32)  # the row's neighbours below it come first
    above = jnp.cumsum(count, dtype=jnp.int32) - count  # the row's first entry
    # each row that has pairs marks its first entry; an entry's row is the last mark at or before it
    marks = jnp.full((capacity + 1,), -1, jnp.int32).at[jnp.where(count > 0, above, capacity)].max(me, mode="drop")
    entry = jnp.arange(capacity, dtype=jnp.int32)
    row = jnp.clip(lax.cummax(marks[:capacity]), 0, n - 1)
    used = entry < above[-1] + count[-1]
    slot = jnp.clip(below[row] + entry - above[row], 0, k - 1)
    j = idx.reshape(-1)[row * k + slot].astype(jnp.int32)
    return jnp.stack([jnp.where(used, row, n), jnp.where(used, j, n)], axis=1)


def _history_at(old_history: Array, found: Array, valid: Array) -> Array:
    """Each new pair's history: the old entry `found` (-1: none, a new pair),
    zero where `found` is -1 or the new entry is empty (`valid` False)."""
    old = old_history[jnp.maximum(found, 0)]
    return jnp.where(((found >= 0) & valid)[:, None], old, jnp.zeros_like(old))


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
      nothing moved gives the same history bit for bit. O(P K_old). The step
      carries with `carry_history_from_pairs`, the same gather read from the
      old pairs themselves; this form, from the old full list, is the
      reference the host twin (`host_lists.carry_history`) and tests use.
    """
    n = old_idx.shape[0]
    keep, entry = half_slots(old_idx)
    i, j = new_pairs[:, 0], new_pairs[:, 1]
    row = jnp.minimum(i, n - 1)
    match = keep[row] & (old_idx[row] == j[:, None])  # [P_new, K_old]
    found = jnp.max(jnp.where(match, entry[row], -1), axis=1, initial=-1)
    found = jnp.where(found < old_history.shape[0], found, -1)  # past the old capacity: it was not kept
    return _history_at(old_history, found, i < n)


def carry_history_from_pairs(old_pairs: Array, old_history: Array, new_pairs: Array, n: int, k: int) -> Array:
    """`carry_history` read from the old half pairs themselves, `old_pairs`
    `[P_old, 2]` (`half_pairs(old_idx, P_old)`: row-major, each row's pairs in
    increasing j, empty entries (n, n) last), for a full list of `k` slots:
    row i's pairs start where the rows above end (a count per row and one
    cumulative sum over the n rows), and the new pair (i, j) is looked for
    among the at most `k` entries from there. The same gather as
    `carry_history`, bit for bit, without its `[n, K, K]` triangle and two of
    its three `[P_new, K]` gathers."""
    p_old = old_pairs.shape[0]
    count = jax.ops.segment_sum(jnp.ones((p_old,), jnp.int32), old_pairs[:, 0], n + 1)[:n]
    start = jnp.cumsum(count, dtype=jnp.int32) - count
    i, j = new_pairs[:, 0], new_pairs[:, 1]
    row = jnp.minimum(i, n - 1)
    at = start[row][:, None] + jnp.arange(k, dtype=jnp.int32)[None, :]  # [P_new, K]
    ok = jnp.arange(k)[None, :] < count[row][:, None]
    match = ok & (old_pairs[jnp.minimum(at, p_old - 1), 1] == j[:, None])
    found = jnp.max(jnp.where(match, at, -1), axis=1, initial=-1)
    return _history_at(old_history, found, i < n)


def contacts_for(contacts, old_idx: Array, new_idx: Array, capacity: int | None = None):
    """`contacts` (a `state.Contacts`) re-laid on the half pairs of `new_idx`
    (`capacity` entries; default: as many as now; its rows in increasing
    order, as `sorted_half_pairs` needs), history carried pair by
    pair from the pairs it was laid on (`contacts.pairs`, the half pairs of
    `old_idx`); the demands restart from the new list's pairs and its fullest row."""
    capacity = contacts.pairs.shape[0] if capacity is None else int(capacity)
    pairs = sorted_half_pairs(new_idx, capacity)
    n, k = old_idx.shape
    history = carry_history_from_pairs(contacts.pairs, contacts.history, pairs, n, k)
    return contacts.set(pairs=pairs, history=history,
                        demand=pair_count(new_idx), slot_demand=slot_count(new_idx))


def pair_entry(pairs, i: int, j: int) -> int | None:
    """Host-side: the entry of pair (i, j) (either order) in a half pair list, or None."""
    a, b = min(i, j), max(i, j)
    hits = np.flatnonzero((np.asarray(pairs[:, 0]) == a) & (np.asarray(pairs[:, 1]) == b))
    return int(hits[0]) if len(hits) else None


__all__ = ["PAIR_ALIGN", "aligned", "carry_history", "carry_history_from_pairs", "contacts_for", "half_pairs",
           "half_slots", "pair_capacity", "pair_count", "pair_entry", "slot_count", "sorted_half_pairs"]
