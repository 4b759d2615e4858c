"""The neighbour and pair lists built on the host, in numpy: set-up,
re-allocation, batches brought to one capacity and checkpoints restored.

These run a few times per run, each on one pile, with shapes that change
from pile to pile: compiled with `jax.jit` each new shape would be an XLA
program of its own, for work numpy does in well under a second even for 1e5
disks (measured: docs/choices.md#host-built-lists). The step loop keeps the traced twins in
`jaxpile.engine.neighbors` (`_build`, `half_pairs`, `carry_history`,
`pair_count`); each function here returns what its twin returns
(`tests/test_engine.py` compares the build, pair lists, count and carried
history). The one exception is rounding: XLA may divide by a cell width as a
product with its inverse and fuse dx*dx + dy*dy (+ dz*dz) into multiply-adds, so a
disk within a rounding unit of a cell's edge, or a pair within one of the
reach (cutoff + skin), beyond any force, can fall on the other side here.
"""

from __future__ import annotations

from typing import Any

import jax.numpy as jnp
import numpy as np

from jaxpile.engine import transfer
from jaxpile.engine.cells import (cell_count, cell_index, cell_key, grid_counts, row_offsets, rows_in_grid,
                                  squared_distance)

Array = Any


def build(position, grid, reach: float, window: int, slots: int, fixed=None) -> tuple[np.ndarray, int, bool]:
    """`neighbors._build` on the host: `(idx [n, slots] int32, occupancy,
    window_overflow)`, each row the neighbours within `reach` in increasing
    index order (empty = n), the most neighbours any disk has, and whether a
    run of three cells of a row held more than `window` disks. `position`
    is `[n, d]` on a grid of the same dimension; a disk reads the 3^(d-1)
    rows of `cells.row_offsets(d)` around its own. Two `fixed` particles
    (`[n]` bool, or None) are never neighbours."""
    position = np.asarray(position)
    n = position.shape[0]
    if n == 0:
        return np.zeros((0, slots), np.int32), 0, False
    counts = grid_counts(grid)
    nx, cells = counts[0], cell_count(grid)
    cell = [c.astype(np.int64) for c in cell_index(position, grid, xp=np)]
    cx = cell[0]
    key = cell_key(cell, grid)
    order = np.argsort(key, kind="stable").astype(np.int32)  # ties by index, as the traced sort of key n + index
    sorted_key = key[order]
    padded_key = np.concatenate([sorted_key, np.full(window + 1, cells)])
    padded_order = np.concatenate([order, np.full(window + 1, n, np.int32)])
    left, right = np.maximum(cx - 1, 0), np.minimum(cx + 1, nx - 1)
    offsets = np.array(row_offsets(len(counts)), np.int64).reshape(-1, len(counts) - 1)  # [R, d - 1]
    rows = len(offsets)  # d = 2: the rows dy = -1, 0, 1
    row = [c[None, :] + offsets[:, k, None] for k, c in enumerate(cell[1:])]  # each [R, n]
    row_ok = rows_in_grid(row, grid)
    if row_ok is None:  # d = 1: the one row
        row_ok = np.ones((rows, n), bool)
    lo = cell_key([np.broadcast_to(left, (rows, n))] + row, grid)
    hi = cell_key([np.broadcast_to(right, (rows, n))] + row, grid)
    first = np.searchsorted(sorted_key, lo, side="left").astype(np.int32)
    at = first[..., None] + np.arange(window, dtype=np.int32)
    inside = row_ok[..., None] & (padded_key[at] <= hi[..., None])
    overflow = bool(np.any(row_ok & (padded_key[first + window] <= hi)))
    candidate = np.where(inside, padded_order[at], n).transpose(1, 0, 2).reshape(n, rows * window)
    partner = np.minimum(candidate, n - 1)
    with np.errstate(invalid="ignore", over="ignore"):  # non-finite disks: the runner stops on them
        near = squared_distance(position, partner) < reach * reach
        keep = (candidate < n) & (candidate != np.arange(n)[:, None]) & near
    if fixed is not None:
        fixed = np.asarray(fixed, bool)
        keep &= ~(fixed[:, None] & fixed[partner])
    occupancy = int(keep.sum(axis=1).max(initial=0))  # int32 throughout: a window of n holds [R, n, n]
    idx = np.sort(np.where(keep, candidate, n), axis=1)[:, :slots]
    if idx.shape[1] < slots:
        idx = np.concatenate([idx, np.full((n, slots - idx.shape[1]), n)], axis=1)
    return idx.astype(np.int32), occupancy, overflow


def half_slots(idx) -> tuple[np.ndarray, np.ndarray]:
    """`pairs.half_slots` on the host: the slots (i, k) with i < idx[i, k],
    and each one's entry in the half pair list in row-major order (-1 elsewhere)."""
    idx = np.asarray(idx)
    n = idx.shape[0]
    keep = (idx < n) & (idx > np.arange(n)[:, None])
    entry = np.cumsum(keep.reshape(-1)).reshape(keep.shape) - 1
    return keep, np.where(keep, entry, -1)


def slot_count(idx) -> np.ndarray:
    """The most neighbours any row of a full list holds (`pairs.slot_count`),
    int32; for a batch's lists `[B, n, K]`, one per member."""
    idx = np.asarray(idx)
    return np.max(np.sum(idx < idx.shape[-2], axis=-1), axis=-1, initial=0).astype(np.int32)


def pair_count(idx) -> int:
    """The number of half pairs of a full list (`pairs.pair_count`)."""
    return int(half_slots(idx)[0].sum())


def half_pairs(idx, capacity: int) -> np.ndarray:
    """`pairs.half_pairs` on the host: `[capacity, 2]` int32 `(i, j)`, i < j,
    each pair once in row-major slot order; pairs past `capacity` are left
    out; empty entries `(n, n)`."""
    idx = np.asarray(idx)
    n = idx.shape[0]
    keep, entry = half_slots(idx)
    rows, _ = np.nonzero(keep)
    e = entry[keep]
    held = e < capacity
    pairs = np.full((int(capacity), 2), n, np.int32)
    pairs[e[held], 0] = rows[held]
    pairs[e[held], 1] = idx[keep][held]
    return pairs


def carry_history(old_idx, old_history, new_pairs) -> np.ndarray:
    """`pairs.carry_history` on the host: each new pair's history taken
    from the same pair of the old list (a copy, bit for bit), zero for a new
    pair or one the old list had no room for."""
    old_idx, old_history, new_pairs = np.asarray(old_idx), np.asarray(old_history), np.asarray(new_pairs)
    n = old_idx.shape[0]
    keep, entry = half_slots(old_idx)
    i, j = new_pairs[:, 0], new_pairs[:, 1]
    row = np.minimum(i, n - 1)
    match = keep[row] & (old_idx[row] == j[:, None])
    found = np.max(np.where(match, entry[row], -1), axis=1, initial=-1)
    found = np.where(found < old_history.shape[0], found, -1)
    old = old_history[np.maximum(found, 0)]
    return np.where(((found >= 0) & (i < n))[:, None], old, np.zeros_like(old))


def contacts_for(contacts, old_idx, new_idx, capacity: int | None = None):
    """`pairs.contacts_for` on the host: `contacts` re-laid on the half
    pairs of `new_idx` (`capacity` entries; default as many as now), history
    carried pair by pair from `old_idx`, the demands the new list's pairs and
    its fullest row."""
    capacity = contacts.pairs.shape[0] if capacity is None else int(capacity)
    pairs = half_pairs(new_idx, capacity)
    history = carry_history(old_idx, contacts.history, pairs)
    return contacts.set(pairs=transfer.to_device(pairs), history=transfer.to_device(history, contacts.history.dtype),
                        demand=transfer.to_device(pair_count(new_idx), jnp.int32),
                        slot_demand=transfer.to_device(slot_count(new_idx), jnp.int32))


__all__ = ["build", "half_slots", "slot_count", "pair_count", "half_pairs", "carry_history", "contacts_for"]
