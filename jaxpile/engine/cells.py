"""The cell grid both neighbour-list builders share: the traced one in
`jaxpile.engine.neighbors` and the host one in `jaxpile.engine.host_lists`.
A disk's neighbours within the reach (cutoff + skin) lie in its own cell or
the eight around it."""

from __future__ import annotations

from typing import Any

import jax.numpy as jnp

Array = Any


MAX_CELLS = 1 << 30
"""Most cells a grid may have (cell keys are int32): a larger box gets larger cells."""


def cell_grid(box: tuple[float, float], reach: float) -> tuple[int, int, float, float]:
    """`(nx, ny, wx, wy)`: the cells over `box`, each at least `reach` (cutoff +
    skin) wide, so a disk's neighbours lie in its own cell or the eight around it."""
    nx = max(1, int(box[0] // reach))
    ny = max(1, int(box[1] // reach))
    while nx * ny > MAX_CELLS:
        nx, ny = max(1, nx // 2), max(1, ny // 2)
    return nx, ny, box[0] / nx, box[1] / ny


def cell_index(position: Array, grid, xp=jnp) -> tuple[Array, Array]:
    """Each disk's cell `(cx, cy)`. Disks outside the box are clamped into the
    border cells: clamping keeps two disks within the reach in the same or
    adjacent cells, so they are still found (a crowded border cell only needs a
    larger window). Non-finite positions go to cell (0, 0) (the runner stops on
    them after the chunk)."""
    nx, ny, wx, wy = grid
    x, y = position[:, 0], position[:, 1]
    ok = xp.isfinite(x) & xp.isfinite(y)
    cx = xp.where(ok, xp.clip(xp.floor(x / wx), 0, nx - 1), 0).astype(xp.int32)
    cy = xp.where(ok, xp.clip(xp.floor(y / wy), 0, ny - 1), 0).astype(xp.int32)
    return cx, cy
