"""The cell grid both neighbour-list builders share: the traced one in
`jaxpile.engine.neighbors` and the host one in `jaxpile.engine.host_lists`.
A particle's neighbours within the reach (cutoff + skin) lie in its own cell
or the 3^d - 1 around it (d = 2: eight; d = 3: 26).

A grid is the flat tuple `(n_0, .., n_{d-1}, w_0, .., w_{d-1})`: the cells
along each axis and their widths (d = 2: `(nx, ny, wx, wy)`). The dimension d
is static: the box's length, half the grid's."""

from __future__ import annotations

import functools
import itertools
from typing import Any, Sequence

import jax.numpy as jnp

Array = Any


MAX_CELLS = 1 << 30
"""Most cells a grid may have (cell keys are int32): a larger box gets larger cells."""


def grid_dimension(grid) -> int:
    """The dimension d of a grid `(n_0, .., n_{d-1}, w_0, .., w_{d-1})`."""
    if len(grid) % 2 or not grid:
        raise ValueError(f"a cell grid is (counts..., widths...), one each per axis; got {grid!r}")
    return len(grid) // 2


def grid_counts(grid) -> tuple[int, ...]:
    """The cells along each axis of `grid`."""
    return tuple(grid[:grid_dimension(grid)])


def grid_widths(grid) -> tuple[float, ...]:
    """The cell widths along each axis of `grid`."""
    return tuple(grid[grid_dimension(grid):])


def cell_grid(box: Sequence[float], reach: float) -> tuple:
    """`(n_0, .., n_{d-1}, w_0, .., w_{d-1})` (d = 2: `(nx, ny, wx, wy)`): the
    cells over `box` (one extent per axis, d = len(box)), each at least
    `reach` (cutoff + skin) wide, so a particle's neighbours lie in its own
    cell or the ones around it."""
    box = tuple(float(b) for b in box)
    if not box:
        raise ValueError("a neighbour box has one extent per axis; got none")
    counts = [max(1, int(b // reach)) for b in box]
    while _product(counts) > MAX_CELLS:
        counts = [max(1, c // 2) for c in counts]
    return tuple(counts) + tuple(b / c for b, c in zip(box, counts))


def _product(values) -> int:
    out = 1
    for v in values:
        out *= int(v)
    return out


def cell_count(grid) -> int:
    """The number of cells of `grid` (the product of its counts)."""
    return _product(grid_counts(grid))


def cell_key(cell: Sequence[Array], grid) -> Array:
    """The cell key of per-axis cell indices `cell` (`cell_index`'s): Horner's
    `((c_{d-1} n_{d-2} + c_{d-2}) .. ) n_0 + c_0`, so axis 0 is the fastest and
    d = 2 gives `cy nx + cx`. Any integer type; indices out of range give a
    key that is not their cell's (the builders mask those)."""
    counts = grid_counts(grid)
    key = cell[-1]
    for k in range(len(counts) - 2, -1, -1):
        key = key * counts[k] + cell[k]
    return key


def cell_index(position: Array, grid, xp=jnp) -> tuple[Array, ...]:
    """Each particle's cell, one index array per axis (d = 2: `(cx, cy)`).
    Particles outside the box are clamped into the border cells: clamping
    keeps two particles within the reach in the same or adjacent cells, so
    they are still found (a crowded border cell only needs a larger window).
    Non-finite positions go to cell (0, .., 0) (the runner stops on them after
    the chunk)."""
    counts, widths = grid_counts(grid), grid_widths(grid)
    d = len(counts)
    if position.shape[-1] != d:
        raise ValueError(f"positions of dimension {position.shape[-1]} on a {d}D cell grid; "
                         f"give the neighbour box one extent per axis")
    axes = [position[:, k] for k in range(d)]
    ok = xp.isfinite(axes[0])
    for a in axes[1:]:
        ok = ok & xp.isfinite(a)
    return tuple(xp.where(ok, xp.clip(xp.floor(a / w), 0, c - 1), 0).astype(xp.int32)
                 for a, w, c in zip(axes, widths, counts))


@functools.lru_cache(maxsize=8)
def row_offsets(dimension: int) -> tuple[tuple[int, ...], ...]:
    """The offsets along axes 1 .. d-1 of the rows of cells a particle reads
    (each row a run of three cells along x: one contiguous run of cell keys),
    in the order both builders read them: d = 2 `(-1,), (0,), (1,)`; d = 3
    the nine `(dy, dz)`, dz fastest."""
    return tuple(itertools.product((-1, 0, 1), repeat=int(dimension) - 1))


def rows_in_grid(row: Sequence[Array], grid) -> Array | None:
    """Whether the rows of cell indices `row` (axes 1 .. d-1, any array type)
    lie in the grid; None for d = 1 (the one row)."""
    ok = None
    for r, c in zip(row, grid_counts(grid)[1:]):
        inside = (r >= 0) & (r < c)
        ok = inside if ok is None else ok & inside
    return ok


def squared_distance(position: Array, partner: Array) -> Array:
    """`|x_i - x_partner|^2` for `position [n, d]` and partner indices
    `[n, m]` (jax or numpy), summed over the axes in order: d = 2 is exactly
    `dx * dx + dy * dy` (written out: a reduce over a size-2 axis is slow on a CPU)."""
    total = None
    for k in range(position.shape[1]):
        delta = position[:, k, None] - position[partner, k]
        total = delta * delta if total is None else total + delta * delta
    return total
