"""The packing-fraction / voidage map, a cell-averaged version of the density
maps of Baxter et al. 1997, Figs. 2, 5, 6 and 8."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from jaxpile import budget
from jaxpile.engine.state import SimState
from jaxpile.errors import InputError
from jaxpile.measure.arrays import disk_arrays, positive_number


def _upper_area(x0, x1, h, r):
    """Area of the disk of radius r at the origin above y = h >= 0 and within x0 <= x <= x1."""
    half_chord = np.sqrt(np.maximum(r * r - h * h, 0.0))
    a, b = np.clip(x0, -half_chord, half_chord), np.clip(x1, -half_chord, half_chord)

    def integral(t):  # of sqrt(r^2 - t^2) dt
        return 0.5 * (t * np.sqrt(np.maximum(r * r - t * t, 0.0)) + r * r * np.arcsin(np.clip(t / r, -1.0, 1.0)))

    return integral(b) - integral(a) - h * (b - a)


def _above(x0, x1, h, r):
    """Area of the disk above y = h (any sign) within x0 <= x <= x1."""
    mirrored = 2.0 * _upper_area(x0, x1, 0.0, r) - _upper_area(x0, x1, -h, r)
    return np.where(h >= 0, _upper_area(x0, x1, np.abs(h), r), mirrored)


def disk_rectangle_overlap(center, radius, x_lo, x_hi, y_lo, y_hi):
    """Exact area shared by disks and axis-aligned rectangles (broadcasting).

    Args:
      center: `[..., 2]` disk centres.
      radius: `[...]` radii.
      x_lo, x_hi, y_lo, y_hi: `[...]` rectangle edges (lo <= hi).
    """
    center = np.asarray(center, dtype=np.float64)
    cx, cy = center[..., 0], center[..., 1]
    x0, x1 = np.asarray(x_lo) - cx, np.asarray(x_hi) - cx
    y0, y1 = np.asarray(y_lo) - cy, np.asarray(y_hi) - cy
    area = _above(x0, x1, y0, radius) - _above(x0, x1, y1, radius)
    return np.maximum(area, 0.0)


class VoidageMap(NamedTuple):
    """Area fraction of disks in square cells (rows along y, columns along x).

    Attributes:
      packing_fraction: `[ny, nx]` disk area in each cell / cell area.
      voidage: `[ny, nx]` 1 - packing_fraction.
      x_edges: `[nx + 1]` cell edges along x (the last cell is cut at the region's edge).
      y_edges: `[ny + 1]` cell edges along y.
      cell_area: `[ny, nx]` area of each cell inside the region.
    """

    packing_fraction: np.ndarray
    voidage: np.ndarray
    x_edges: np.ndarray
    y_edges: np.ndarray
    cell_area: np.ndarray


def _region(position, radius, active, region):
    if region is None:
        if not active.any():
            raise InputError("no active disk and no region: give region=(x_min, x_max, y_min, y_max).")
        lo = (position - radius[:, None])[active].min(axis=0)
        hi = (position + radius[:, None])[active].max(axis=0)
        return float(lo[0]), float(hi[0]), float(lo[1]), float(hi[1])
    x_min, x_max, y_min, y_max = (float(v) for v in region)
    if not (x_min < x_max and y_min < y_max and np.all(np.isfinite([x_min, x_max, y_min, y_max]))):
        raise InputError(f"region must be finite (x_min, x_max, y_min, y_max) with min < max; got {region!r}.")
    return x_min, x_max, y_min, y_max


def voidage_map(position, radius, cell_size: float, active=None, *, region=None) -> VoidageMap:
    """Local packing fraction and voidage on a grid of square cells.

    Baxter et al. 1997 show the local density of a heap as a shaded map ("lighter
    regions on the figure indicate high voidage", Figs. 2, 5, 6, 8) without a
    formula; this is its cell-averaged, quantitative form. The disk area in each
    cell is exact (the disk-rectangle intersection in closed form, no sampling).
    Overlapping soft disks count their shared area twice, as in "sum of disk
    areas / cell area"; cells are cut where they cross the region's edge, and
    the fraction uses the cut cell's area.

    Args:
      position: `[n, 2]`; radius: `[n]` or a scalar; active: `[n]` bool.
      cell_size: the side of a cell (e.g. 2-5 diameters for a smooth map).
      region: `(x_min, x_max, y_min, y_max)`; default: the bounding box of the
        active disks. The cells start at `(x_min, y_min)`.

    Raises:
      InputError: on empty or malformed arrays, a non-positive cell size or a bad region.
    """
    position, radius, active = disk_arrays(position, radius, active)
    cell = positive_number("cell_size", cell_size)
    x_min, x_max, y_min, y_max = _region(position, radius, active, region)
    rad = radius[active]
    budget.check_host(voidage_map_bytes(x_max - x_min, y_max - y_min, cell, len(rad),
                                        float(rad.max()) if len(rad) else 0.0),
                      f"a voidage map of {x_max - x_min:g} x {y_max - y_min:g} in cells of {cell:g}",
                      "Use larger cells.")

    def edges(lo, hi):
        count = max(1, int(np.ceil((hi - lo) / cell * (1.0 - 1e-12))))
        e = lo + cell * np.arange(count + 1)
        e[-1] = hi
        return e

    x_edges, y_edges = edges(x_min, x_max), edges(y_min, y_max)
    nx, ny = len(x_edges) - 1, len(y_edges) - 1
    area = np.zeros((ny, nx))
    pos, rad = position[active], radius[active]
    if len(rad):
        window = int(np.ceil(2.0 * rad.max() / cell)) + 1  # cells a disk can touch per axis
        ix0 = np.floor((pos[:, 0] - rad - x_min) / cell).astype(np.int64)
        iy0 = np.floor((pos[:, 1] - rad - y_min) / cell).astype(np.int64)
        offsets = np.arange(window)
        ix = ix0[:, None, None] + offsets[None, None, :]  # [m, 1, K]
        iy = iy0[:, None, None] + offsets[None, :, None]  # [m, K, 1]
        ix, iy = np.broadcast_arrays(ix, iy)
        inside = (ix >= 0) & (ix < nx) & (iy >= 0) & (iy < ny)
        cx, cy = np.clip(ix, 0, nx - 1), np.clip(iy, 0, ny - 1)
        overlap = disk_rectangle_overlap(pos[:, None, None, :], rad[:, None, None],
                                         x_edges[cx], x_edges[cx + 1], y_edges[cy], y_edges[cy + 1])
        np.add.at(area, (cy[inside], cx[inside]), overlap[inside])
    cell_area = np.diff(y_edges)[:, None] * np.diff(x_edges)[None, :]
    fraction = area / cell_area
    return VoidageMap(packing_fraction=fraction, voidage=1.0 - fraction,
                      x_edges=x_edges, y_edges=y_edges, cell_area=cell_area)


def voidage_map_bytes(width: float, height: float, cell_size: float, disks: int, max_radius: float) -> float:
    """About the peak bytes `voidage_map` allocates over a `width` x `height`
    region: the grid, and for every disk the block of cells it may touch (a
    dozen float64 and int64 arrays of it). A float: a cell far too small
    gives a number, not an overflow."""
    with np.errstate(over="ignore"):
        cells = (np.ceil(width / cell_size) + 1.0) * (np.ceil(height / cell_size) + 1.0)
        window = np.ceil(2.0 * max_radius / cell_size) + 1.0
        return float(8.0 * 4 * cells + 8.0 * 12 * disks * window * window)


def voidage_map_of(state: SimState, cell_size: float, **kwargs) -> VoidageMap:
    """`voidage_map` of the active disks of a state (fixed disks included)."""
    p = state.particles
    return voidage_map(np.asarray(p.position), np.asarray(p.radius), cell_size, np.asarray(p.active), **kwargs)


def packing_fraction(position, radius, region, active=None) -> float:
    """Disk area inside the rectangle `region = (x_min, x_max, y_min, y_max)` / its area (exact)."""
    position, radius, active = disk_arrays(position, radius, active)
    x_min, x_max, y_min, y_max = _region(position, radius, active, region)
    inside = disk_rectangle_overlap(position[active], radius[active], x_min, x_max, y_min, y_max)
    return float(inside.sum() / ((x_max - x_min) * (y_max - y_min)))


__all__ = ["VoidageMap", "disk_rectangle_overlap", "packing_fraction", "voidage_map", "voidage_map_bytes", "voidage_map_of"]
