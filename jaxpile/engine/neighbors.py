"""Neighbour lists (full lists in jax-md's `NeighborList`, Dense format, built
by a sorted cell list of our own), the half pair list built from them, and
contact history carried across rebuilds.

The full list gives each particle each neighbour within the reach (cutoff +
skin) in one of K slots (`idx[n, K]`, empty = n, each row in increasing index
order). It is built by sorting the disks by cell: the three cells of a row next
to a disk are then one contiguous run of the sorted keys, whose start is read
from a table of each cell's first disk (or found by binary search in a box far
larger than its disks), read through a window of W entries (`_build`). It costs
a fraction of jax-md's own cell list per rebuild on a CPU, and a third of its
temporary memory, by avoiding chains of small XLA kernels
(docs/choices.md#neighbour-lists). The list keeps jax-md's `NeighborList` type
and its overflow flags: `max_occupancy` is K, `cell_list_capacity` is W.

The dimension d (2 or 3) is static: the length of the settings' box, the
positions `[n, d]`. A row is a run of three cells along x; a disk reads the
3^(d-1) rows around its own (d = 2: 3, d = 3: 9), in the order of
`cells.row_offsets`. Where packings differ by dimension the constants do too
(`PACKED_SLOTS_MAX_BY_DIMENSION`, `PAIRS_PER_PARTICLE`); d = 2 builds the same
lists as before, bit for bit.

The contact laws run on a *half* list instead, `pairs[P, 2]` with i < j, each
pair once, compacted from the full list at each rebuild (sorted by i, so the
gathers of x_i walk memory in order; empty entries (n, n)): the law is
evaluated once per pair and the reaction on j added by a scatter, as LAMMPS
does with its half list, on about a third of the full list's slots.

Two fixed particles are never each other's neighbours: they exert nothing
on each other (docs/choices.md#pairs-of-two-fixed-particles).

The half list's capacity P (`pair_capacity_for`) is room for 3 pairs per free
disk (the most any packing of equal disks has in 2D) or 10% over the pairs at
allocation, whichever is more, and never more than ceil(n K / 2); K carries
head-room for the densest row, P only for the mean, so its padding costs far
less. A pour's list is sized for its whole heap from the start, so it is not
re-allocated (and a chunk re-run) as the heap grows. A rebuild that finds more
pairs than P keeps the first P, records the demand in `Contacts.demand` and
raises the overflow flag, so the runner re-allocates and re-runs the chunk as
for an overflow of the full list (no contact is ever dropped); so does a window
too small for a crowded run of cells. A re-allocation sizes the slots by the
most neighbours any rebuild found (`Contacts.slot_demand`, `slots_needed`) and
the pair room by the pair demand (`pairs_needed`). `allocate` runs outside jit,
`update` inside; the runner checks `overflowed(state)` after each chunk (see
`simulate`).
"""

from __future__ import annotations

import functools
import itertools
import math
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax
from jaxpile._jax_md import partition

from jaxpile.engine import host_lists, transfer
from jaxpile.engine.cells import (cell_count, cell_grid, cell_index, cell_key, grid_counts, grid_widths,
                                  row_offsets, rows_in_grid, squared_distance)
from jaxpile.engine.pairs import aligned, contacts_for, pair_capacity

Array = Any


class NeighborSettings(NamedTuple):
    """Everything a neighbour list is built from (hashable: a static field).

    The cell grid covers `origin .. origin + box` (origin None: from 0); a
    particle outside it is clamped into a border cell, which is correct but
    crowds that cell (every clamped particle is read by its neighbours)."""

    box: tuple[float, ...]  # one extent per axis: its length is the dimension d
    cutoff: float
    skin: float
    capacity_multiplier: float
    origin: tuple[float, ...] | None = None  # the grid's lower corner, one value per axis (None: 0)


def _in_grid_frame(position, settings: NeighborSettings, xp=jnp):
    """`position` measured from the grid's lower corner (itself when the origin is 0)."""
    if settings.origin is None:
        return position
    return position - xp.asarray(settings.origin, dtype=position.dtype)


def _grid(settings: NeighborSettings) -> tuple:
    """The settings' cell grid (`cells.cell_grid` of its box and reach):
    `(n_0, .., n_{d-1}, w_0, .., w_{d-1})`, d = 2: `(nx, ny, wx, wy)`."""
    return cell_grid(settings.box, settings.cutoff + settings.skin)


def dimension_of(settings: NeighborSettings) -> int:
    """The dimension d of the settings (its box's length)."""
    return len(settings.box)


WINDOW_HEADROOM = 2.0
"""The window's head-room over the most disks in a run of three cells at
allocation (at most the capacity multiplier): a packed heap of equal disks
holds ~5 in a run where the substrate row holds 4, and every window entry
is a candidate each rebuild checks."""


CELL_TABLE_PER_DISK = 64
"""A rebuild finds where each run of cells starts from a table with an entry
per cell when the grid has at most this many cells per disk (plus
`CELL_TABLE_MIN`), and by binary search otherwise (a box far larger than
its disks: the table would cost more than it saves)."""

CELL_TABLE_MIN = 4096

SELECT_SLOTS_BY_DIMENSION = {2: 16, 3: 24}
"""Up to this many slots a rebuild fills each row slot by slot; more, by a row
sort. The sort's cost grows with the candidates a row reads (3 W in 2D, 9 W in
3D), the picks' with the slots too, so in 3D picking pays for more slots
(measured: docs/choices.md#neighbour-lists)."""


def _sorted_by_cell(key: Array, n: int, cells: int) -> tuple[Array, Array]:
    """`(order, sorted_key)`: the disks sorted by cell key, ties by index (a
    stable sort). One sort of the code `key n + index`, not an argsort with an
    index payload, which is several times slower on a CPU
    (docs/choices.md#neighbour-lists). The code is int32
    where `cells n` fits in it (jaxpile runs with 64-bit integers enabled)."""
    wide = jnp.int32 if cells * n < 2**31 else jnp.int64
    code = jnp.sort(key.astype(wide) * n + jnp.arange(n, dtype=wide))
    return (code % n).astype(jnp.int32), (code // n).astype(jnp.int32)


def _run_starts(sorted_key: Array, lo: Array, hi: Array, cells: int) -> Array:
    """For each run of cells `lo .. hi` (at most three cells of one row), the
    first position in `sorted_key` whose key is >= lo: `searchsorted(sorted_key,
    lo)` wherever the run holds a disk (elsewhere a position whose key is >
    hi, or n). With a table of each cell's first position (one scatter) this is
    three gathers; a binary search is a loop of ~log2(n) rounds of small
    kernels, a large share of a small pile's rebuild
    (docs/choices.md#neighbour-lists)."""
    n = sorted_key.shape[0]
    if cells > CELL_TABLE_PER_DISK * n + CELL_TABLE_MIN:
        return jnp.searchsorted(sorted_key, lo, side="left").astype(jnp.int32)
    first = jnp.full((cells + 1,), n, jnp.int32).at[sorted_key].min(jnp.arange(n, dtype=jnp.int32))
    start = first[jnp.clip(lo, 0, cells)]
    for extra in (1, 2):  # a run is at most three cells; cells past hi are not part of it
        at = lo + extra
        start = jnp.where(at <= hi, jnp.minimum(start, first[jnp.clip(at, 0, cells)]), start)
    return start


def _build(position: Array, grid, reach: float, window: int, slots: int, fixed: Array | None = None):
    """The full neighbour list of `position` `[n, d]` (traceable), on the cell
    grid `grid` of the same dimension. Two `fixed` particles (`[n]` bool, or
    None: none) are never each other's neighbours: they exert nothing on each
    other, and a rough base of fixed spheres would otherwise fill most of a
    small heap's pair list.

    The disks are sorted by cell key (`cells.cell_key`: d = 2 `cy nx + cx`).
    The cells `cx - 1 .. cx + 1` of one row are then one contiguous run of
    the sorted keys, so a disk finds the candidates of each of its 3^(d-1)
    rows (`row_offsets`) where that run starts (`_run_starts`) and reads
    `window` entries from there. Candidates within `reach` (not itself) fill
    the row of `idx` in increasing index order.

    Returns:
      `(idx [n, slots], occupancy, window_overflow)`: idx empty = n; the most
      neighbours any disk has (more than `slots`: the list overflowed, and
      the row keeps its `slots` lowest indices); whether some three-cell run
      held more than `window` disks.
    """
    n = position.shape[0]
    counts = grid_counts(grid)
    nx, cells = counts[0], cell_count(grid)
    cell = cell_index(position, grid)
    cx = cell[0]
    key = cell_key(cell, grid)
    order, sorted_key = _sorted_by_cell(key, n, cells)
    beyond = jnp.int32(cells)  # past every key: reads past the end stop there
    padded_key = jnp.concatenate([sorted_key, jnp.full((window + 1,), beyond, jnp.int32)])
    padded_order = jnp.concatenate([order, jnp.full((window + 1,), n, jnp.int32)])
    left, right = jnp.maximum(cx - 1, 0), jnp.minimum(cx + 1, nx - 1)
    span = jnp.arange(window, dtype=jnp.int32)
    candidates, overflow = [], jnp.zeros((), bool)
    for offset in row_offsets(len(counts)):
        row = [c + o for c, o in zip(cell[1:], offset)]
        row_ok = rows_in_grid(row, grid)
        if row_ok is None:  # d = 1: the one row
            row_ok = jnp.ones((n,), bool)
        lo, hi = cell_key([left] + row, grid), cell_key([right] + row, grid)
        first = _run_starts(sorted_key, lo, hi, cells)
        at = first[:, None] + span[None, :]
        inside = row_ok[:, None] & (padded_key[at] <= hi[:, None])
        candidates.append(jnp.where(inside, padded_order[at], n))
        overflow = overflow | jnp.any(row_ok & (padded_key[first + window] <= hi))
    candidate = jnp.concatenate(candidates, axis=1)  # [n, 3^(d-1) window]
    partner = jnp.minimum(candidate, n - 1)
    me = jnp.arange(n, dtype=jnp.int32)[:, None]
    keep = (candidate < n) & (candidate != me) & (squared_distance(position, partner) < reach * reach)
    if fixed is not None:
        keep = keep & ~(fixed[:, None] & fixed[partner])
    occupancy = jnp.max(jnp.sum(keep, axis=1, dtype=jnp.int32), initial=0)
    # the row's lowest indices first, the neighbours (no disk is a candidate
    # twice: it lies in one cell), picked one slot at a time: each slot holds
    # the least candidate above the slot before. For the few slots of a 2D list
    # that costs less than a row sort (a cumsum, scatter and sort: more again)
    value = jnp.where(keep, candidate, n)
    if slots <= SELECT_SLOTS_BY_DIMENSION[position.shape[1]]:
        # only as many picks as the fullest row has neighbours, the slots past it left empty: a list
        # sized for a whole heap is mostly empty while it is poured (docs/choices.md#neighbour-lists)
        def pick(carry):
            k, last, idx = carry
            last = jnp.min(jnp.where(value > last[:, None], value, n), axis=1)
            return k + 1, last, lax.dynamic_update_slice_in_dim(idx, last[:, None], k, axis=1)

        picks = jnp.minimum(occupancy, slots)
        start = (jnp.zeros((), jnp.int32), jnp.full((n,), -1, jnp.int32), jnp.full((n, slots), n, jnp.int32))
        idx = lax.while_loop(lambda carry: carry[0] < picks, pick, start)[2]
    else:
        idx = jnp.sort(value, axis=1)[:, :slots]
        if idx.shape[1] < slots:
            idx = jnp.concatenate([idx, jnp.full((n, slots - idx.shape[1]), n, jnp.int32)], axis=1)
    return idx, occupancy, overflow


HOST_BUILD_MAX = 200_000
"""Lists of up to this many disks are allocated and rebuilt to a capacity on
the host (`host_lists.build`, numpy: nothing to compile per new pile size);
larger ones by the compiled `_build`, the faster there even with its compile
(measured: docs/choices.md#host-built-lists)."""

_build_jit = jax.jit(_build, static_argnums=(1, 2, 3, 4))


def _build_outside_loop(position, grid, reach: float, window: int, slots: int, fixed=None):
    """`(idx, occupancy, window_overflow)` of a list built outside the step
    loop, the occupancy and overflow as host values (see `HOST_BUILD_MAX`)."""
    if position.shape[0] <= HOST_BUILD_MAX:
        return host_lists.build(position, grid, reach, window, slots, fixed)
    fixed = None if fixed is None else jnp.asarray(fixed)
    idx, occupancy, over = _build_jit(jnp.asarray(position), grid, reach, window, slots, fixed)
    return idx, int(occupancy), bool(over)


def _no_update(*args, **kwargs):
    raise NotImplementedError("jaxpile builds its lists with neighbors.rebuild, not jax-md's update.")


def _make_list(settings: NeighborSettings, idx, position, window: int, error=None):
    """A jax-md `NeighborList` holding our list: `max_occupancy` is the slot
    count K, `cell_list_capacity` the window W of a three-cell run."""
    error = _error(False, False) if error is None else error
    return partition.NeighborList(idx, position, error, int(window), int(idx.shape[1]), partition.Dense,
                                  float(settings.cutoff + settings.skin), None, _no_update)


PACKED_SLOTS_MAX = 16
"""`packed_capacity` gives at most this many slots in 2D (`SELECT_SLOTS_BY_DIMENSION`:
rebuilds stay slot by slot) and at most twice this window: a pile with disks far smaller
than its largest gets these, and is re-allocated if it packs denser."""

PACKED_SLOTS_MAX_BY_DIMENSION = {2: PACKED_SLOTS_MAX, 3: 32}
"""`PACKED_SLOTS_MAX` per dimension. 3D: a packed fcc pile of equal spheres
has 12 neighbours within a reach of 1.2 diameters, 18 slots with the usual
multiplier of 1.5 (above 16), and a run of three cells 1.2 diameters wide
holds up to 16 of them (two close-packed layers): 32 slots and a window of 64
keep that head-room and cap smaller spheres. Equal spheres' 18 slots are
filled slot by slot, the cap's 32 by a row sort (`SELECT_SLOTS_BY_DIMENSION`)."""


def packed_slots_max(dimension: int) -> int:
    """`PACKED_SLOTS_MAX_BY_DIMENSION[dimension]`."""
    try:
        return PACKED_SLOTS_MAX_BY_DIMENSION[int(dimension)]
    except KeyError:
        raise ValueError(f"packed lists are sized for d = 2 or 3, not d = {dimension}") from None


@functools.lru_cache(maxsize=256)  # milliseconds a call, and an ensemble asks once per member with the same values
def packed_capacity(settings: NeighborSettings, radius: float) -> tuple[int, int]:
    """`(slots, window)` for a close-packed pile of disks of `radius` (the
    smallest disks: the densest pile of them), from a triangular packing of
    spacing 2 radius: the slots are its points within the reach of a point
    times the capacity multiplier (the head-room `allocate` gives any list:
    a disordered pile puts a seventh or eighth disk within the reach), the
    window the most of its points in a run of three cells (over 64 offsets and
    the lattice's two orientations: already the densest, no head-room); at
    most `PACKED_SLOTS_MAX` and twice it. A list sized so from the start is
    not re-allocated when its disks fall, flow or are pressed into a pile
    (each re-allocation compiles the step loop again and re-runs a chunk).
    Equal disks, reach 1.2 diameters: 9 slots (multiplier 1.5), a window of 8.

    In 3D (a box of three extents) the packing is fcc and the caps
    `PACKED_SLOTS_MAX_BY_DIMENSION[3]` (`_packed_capacity_3d`): equal
    spheres, reach 1.2 diameters: 18 slots (12 neighbours times 1.5)."""
    if not (radius > 0 and math.isfinite(radius)):
        return 1, 1
    if dimension_of(settings) == 3:
        return _packed_capacity_3d(settings, radius)
    if dimension_of(settings) != 2:
        raise ValueError(f"packed lists are sized for d = 2 or 3, not d = {dimension_of(settings)}")
    reach = settings.cutoff + settings.skin
    _, _, wx, wy = _grid(settings)
    spacing = 2.0 * radius

    def lattice(extent):  # the triangular lattice's points within about `extent` of the origin
        m = int(math.ceil(extent / spacing)) + 2
        a, b = np.meshgrid(np.arange(-m, m + 1), np.arange(-m, m + 1))
        return np.stack([a + 0.5 * b, b * (math.sqrt(3.0) / 2.0)], -1).reshape(-1, 2) * spacing

    per_area = 2.0 / (math.sqrt(3.0) * spacing**2)  # points per unit area
    if math.pi * reach**2 * per_area > 4 * PACKED_SLOTS_MAX:  # disks far smaller than the reach
        neighbours = 4 * PACKED_SLOTS_MAX
    else:
        points = lattice(reach)
        distance = np.hypot(points[:, 0], points[:, 1])
        neighbours = int(np.count_nonzero((distance > 0) & (distance <= reach)))
    if 3 * wx * wy * per_area > 4 * PACKED_SLOTS_MAX:  # wide cells or small disks: the cap
        most = 4 * PACKED_SLOTS_MAX
    else:
        points, most = lattice(max(3 * wx, wy)), 0
        for turned in (points, points[:, ::-1]):
            for ox in np.linspace(0.0, spacing, 8, endpoint=False):
                for oy in np.linspace(0.0, spacing * math.sqrt(3.0), 8, endpoint=False):
                    x, y = turned[:, 0] + ox, turned[:, 1] + oy
                    most = max(most, int(np.count_nonzero((x >= 0) & (x < 3 * wx) & (y >= 0) & (y < wy))))
    slots = min(PACKED_SLOTS_MAX, int(math.ceil(neighbours * settings.capacity_multiplier)))
    window = min(2 * PACKED_SLOTS_MAX, most)
    return max(1, slots), max(1, window)


FCC_CUBIC = np.array([[0.0, 0.5, 0.5], [0.5, 0.0, 0.5], [0.5, 0.5, 0.0]]) * math.sqrt(2.0)
"""Primitive vectors (rows) of an fcc lattice of unit spacing, cube-aligned."""

FCC_LAYERED = np.array([[1.0, 0.0, 0.0], [0.5, math.sqrt(3.0) / 2.0, 0.0],
                        [0.5, math.sqrt(3.0) / 6.0, math.sqrt(2.0 / 3.0)]])
"""Primitive vectors (rows) of an fcc lattice of unit spacing, its
close-packed (111) layers normal to z (ABC stacking)."""


def _packed_capacity_3d(settings: NeighborSettings, radius: float) -> tuple[int, int]:
    """`packed_capacity` in 3D: the fcc packing of spacing 2 radius (12
    neighbours at one spacing, the next 6 at sqrt 2); the window the most of
    its points in a run of three cells over 8^3 offsets within a primitive
    cell, the lattice cube-aligned and with its close-packed layers normal to
    each of the three axes (either way along the run); at most
    `PACKED_SLOTS_MAX_BY_DIMENSION[3]` and twice it."""
    cap = packed_slots_max(3)
    reach = settings.cutoff + settings.skin
    wx, wy, wz = grid_widths(_grid(settings))
    spacing = 2.0 * radius
    per_volume = math.sqrt(2.0) / spacing**3  # points per unit volume
    height = math.sqrt(2.0 / 3.0) * spacing  # the least distance between planes of a primitive cell

    def lattice(basis, extent):  # the lattice's points within at least `extent` of the origin
        m = int(math.ceil(extent / height)) + 2
        ijk = np.stack(np.meshgrid(*(np.arange(-m, m + 1),) * 3, indexing="ij"), -1).reshape(-1, 3)
        return ijk @ (basis * spacing)

    if 4.0 / 3.0 * math.pi * reach**3 * per_volume > 4 * cap:  # spheres far smaller than the reach
        neighbours = 4 * cap
    else:
        distance = np.linalg.norm(lattice(FCC_CUBIC, reach), axis=1)
        neighbours = int(np.count_nonzero((distance > 0) & (distance <= reach)))
    run = np.array([3 * wx, wy, wz])
    if float(np.prod(run)) * per_volume > 4 * cap:  # wide cells or small spheres: the cap
        most = 4 * cap
    else:
        fractions = np.linspace(0.0, 1.0, 8, endpoint=False)
        grid = np.stack(np.meshgrid(fractions, fractions, fractions, indexing="ij"), -1).reshape(-1, 3)
        orientations = [FCC_CUBIC] + [FCC_LAYERED[:, list(p)] for p in itertools.permutations(range(3))]
        most = 0
        for basis in orientations:
            offsets = grid @ (basis * spacing)  # [512, 3], within one primitive cell
            points = lattice(basis, float(np.linalg.norm(run)) + 3.0 * spacing)
            low, high = -offsets.max(axis=0), run - offsets.min(axis=0)
            points = points[np.all((points >= low) & (points < high), axis=1)]  # those some offset brings in
            moved = points[None, :, :] + offsets[:, None, :]
            inside = np.all((moved >= 0) & (moved < run), axis=2)
            most = max(most, int(inside.sum(axis=1).max(initial=0)))
    slots = min(cap, int(math.ceil(neighbours * settings.capacity_multiplier)))
    window = min(2 * cap, most)
    return max(1, slots), max(1, window)


def allocate(settings: NeighborSettings, position: Array, extra_capacity: int = 0,
             packed_radius: float | None = None, min_slots: int = 0, min_window: int = 0, fixed=None):
    """A new neighbour list (host-side), sized like jax-md's: the window W is
    the most disks in any run of three cells of a row times the capacity
    multiplier (at most `WINDOW_HEADROOM`), the slots K the most neighbours of
    any disk times the multiplier, each plus `extra_capacity`. With
    `packed_radius` (the smallest disk's radius), K and W are at least what a
    close-packed pile of such disks needs (`packed_capacity`), so disks that
    start apart (parked, poured, dropped, a loose fill) get a list for the
    pile they will make. `min_slots` and `min_window` are floors on K and W
    (a re-allocation's: see `slots_needed`). `fixed` (`[n]` bool): particles
    never listed as each other's neighbours (`_build`).

    One build, wide enough for every candidate (3^(d-1) W slots), gives both the
    occupancy and the list: its rows are in increasing index order, so their
    first K columns are what a build with K slots gives. Up to
    `HOST_BUILD_MAX` disks the build runs on the host (`host_lists.build`, the
    traced `_build`'s list up to rounding at the reach): compiled, it would
    be an XLA program for every new pile size (docs/choices.md#host-built-lists)."""
    host = _in_grid_frame(np.asarray(position), settings, xp=np)
    position = transfer.to_device(position)
    n = int(position.shape[0])
    grid = _grid(settings)
    if host.ndim != 2 or host.shape[1] != len(settings.box):
        raise ValueError(f"positions of shape {host.shape} for a neighbour box of {len(settings.box)} extents")
    cell = [a.astype(np.int64) for a in cell_index(host, grid, xp=np)]
    cells, counts = np.unique(cell_key(cell, grid), return_counts=True)  # occupied cells only: O(n)

    def count(key, ok):
        at = np.minimum(np.searchsorted(cells, key), len(cells) - 1)
        return np.where(ok & (cells[at] == key), counts[at], 0)

    # the runs a disk reads are centred on its column in its own row and the rows around it
    # (d = 2: above and below)
    sizes = grid_counts(grid)
    nx = sizes[0]
    strides = np.cumprod((1,) + sizes[:-1])  # each axis's step in the cell key
    coords = [(cells // int(stride)) % size for stride, size in zip(strides, sizes)]
    shifted = []
    for offset in row_offsets(len(sizes)):
        row = [c + o for c, o in zip(coords[1:], offset)]
        ok = rows_in_grid(row, grid)
        step = sum(int(o) * int(stride) for o, stride in zip(offset, strides[1:]))
        shifted.append(cells + step if ok is None else cells[ok] + step)
    centres = np.unique(np.concatenate([cells] + shifted))
    x = centres % nx
    runs = count(centres, True) + count(centres - 1, x > 0) + count(centres + 1, x < nx - 1)
    most = int(runs.max()) if n else 0
    headroom = min(settings.capacity_multiplier, WINDOW_HEADROOM)
    packed_slots, packed_window = (0, 0) if packed_radius is None else packed_capacity(settings, packed_radius)
    window = max(int(math.ceil(most * headroom)) + int(extra_capacity), packed_window, int(min_window))
    window = max(1, min(n, window))
    probe = max(1, min(n - 1, len(row_offsets(len(sizes))) * window))
    on_host = host if n <= HOST_BUILD_MAX else _in_grid_frame(position, settings)  # no second device copy below
    fixed = None if fixed is None else np.asarray(fixed)
    wide, occupancy, over = _build_outside_loop(on_host, grid, float(settings.cutoff + settings.skin), window, probe,
                                                fixed)
    slots = max(int(occupancy * settings.capacity_multiplier) + int(extra_capacity), packed_slots, int(min_slots))
    slots = max(1, min(max(n - 1, 1), slots))
    idx = wide[:, :slots] if slots <= probe else jnp.pad(wide, ((0, 0), (0, slots - probe)), constant_values=n)
    return _make_list(settings, transfer.to_device(idx), position, window, _error(occupancy > slots, over))


def _error(overflowed: bool, window_overflowed: bool):
    """A fresh list's error flag (host values): its slots and its window
    overflowed or not. Made on the host: jax-md's `update` is three compiles."""
    code = (int(partition.PEC.NEIGHBOR_LIST_OVERFLOW) if overflowed else 0) | (
        int(partition.PEC.CELL_LIST_OVERFLOW) if window_overflowed else 0)
    return partition.PartitionError(transfer.to_device(np.uint8(code)))


def rebuild(neighbors, position: Array, settings: NeighborSettings, fixed: Array | None = None):
    """`neighbors` rebuilt from `position` with its own capacities (traceable);
    an overflow of its slots or window is or-ed into its error flag. Two
    `fixed` particles are never neighbours (`_build`)."""
    return _rebuilt(neighbors, position, settings, fixed)[0]


def _rebuilt(neighbors, position: Array, settings: NeighborSettings, fixed: Array | None = None):
    """`rebuild`, and the most neighbours any disk has (more than the list's
    slots when it overflowed: what a re-allocation must make room for)."""
    idx, occupancy, over = _build(_in_grid_frame(position, settings), _grid(settings),
                                  float(settings.cutoff + settings.skin), int(neighbors.cell_list_capacity),
                                  int(neighbors.max_occupancy), fixed)
    error = neighbors.error.update(partition.PEC.NEIGHBOR_LIST_OVERFLOW, occupancy > neighbors.max_occupancy)
    return neighbors.set(idx=idx, reference_position=position,
                         error=error.update(partition.PEC.CELL_LIST_OVERFLOW, over)), occupancy


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
    (the displacement over all d axes)."""
    d = position - neighbors.reference_position
    moved = d[:, 0] ** 2
    for k in range(1, d.shape[-1]):  # written out: a reduce over a size-2 axis is slow on CPU
        moved = moved + d[:, k] ** 2
    return jnp.any(moved > (0.5 * skin) ** 2 * (1.0 - 1e-5))


def _rebuilt_where_needed(neighbors, position: Array, settings: NeighborSettings, need: Array,
                          axis_name: str | None, fixed: Array | None = None):
    """The rebuilt list and its occupancy (`_rebuilt`); in a batch, members
    that did not move keep theirs and count 0 (each member's list, and what
    it records, is exactly what it would be alone)."""
    new, occupancy = _rebuilt(neighbors, position, settings, fixed)
    if axis_name is None:
        return new, occupancy
    return jax.tree.map(lambda a, b: jnp.where(need, a, b), new, neighbors), jnp.where(need, occupancy, 0)


def update(neighbors, position: Array, settings: NeighborSettings, axis_name: str | None = None,
           fixed: Array | None = None):
    """The list rebuilt when some disk moved more than skin / 2, decided once
    for a whole batch when `axis_name` names the batch's `vmap` axis (a cond
    under vmap would become a select: every member rebuilding at every step)."""
    own = needs_rebuild(neighbors, position, settings.skin)
    return lax.cond(any_member(own, axis_name),
                    lambda: _rebuilt_where_needed(neighbors, position, settings, own, axis_name, fixed)[0],
                    lambda: neighbors)


def rebuild_at_capacity(neighbors, position: Array, max_occupancy: int, cell_capacity: int | None,
                        settings: NeighborSettings, fixed=None):
    """The list rebuilt from `position` with `max_occupancy` slots per particle
    and a window of `cell_capacity` (so lists of a batch share their shapes);
    an overflow of either raises its error flag. Two `fixed` particles are
    never neighbours. Host-side (see `HOST_BUILD_MAX`)."""
    n = position.shape[0]
    window = n if cell_capacity is None else int(cell_capacity)
    fixed = None if fixed is None else np.asarray(fixed)
    idx, occupancy, over = _build_outside_loop(_in_grid_frame(position, settings), _grid(settings),
                                               float(settings.cutoff + settings.skin), window, int(max_occupancy),
                                               fixed)
    return _make_list(settings, transfer.to_device(idx), transfer.to_device(position), window,
                      _error(occupancy > max_occupancy, over))


PAIRS_PER_DISK = 3.0
"""Pair room allocated per disk at least in 2D: a close-packed 2D pile of equal
disks has 3 pairs per disk, looser packings fewer."""

PAIRS_PER_PARTICLE = {2: PAIRS_PER_DISK, 3: 6.0}
"""`PAIRS_PER_DISK` per dimension: a close-packed (fcc or hcp) 3D pile of equal
spheres has 12 contacts a sphere, 6 pairs."""


def pairs_per_particle(dimension: int) -> float:
    """`PAIRS_PER_PARTICLE[dimension]`."""
    try:
        return PAIRS_PER_PARTICLE[int(dimension)]
    except KeyError:
        raise ValueError(f"pair room is sized for d = 2 or 3, not d = {dimension}") from None


PAIR_HEADROOM = 1.1
"""Pair room allocated over the pairs a list holds at allocation (the mean
coordination of a pile moves little; the densest row, which sizes K, more)."""

PAIR_GROWTH = 1.25
"""A re-allocation that ran out of pair room grows it by at least this factor
(`pairs_needed`)."""


def pairs_needed(state, overflowed) -> int:
    """Host-side: the pair capacity a re-allocation of `state` must give at
    least, after the chunk that ended in `overflowed`: the old one, or, if the
    chunk found more pairs than that, the more of `PAIR_GROWTH` times it and
    `PAIR_HEADROOM` times the demand (a chunk that starts with few contacts
    may end with more; a growth too small re-allocates again, at a compile and
    a chunk's re-run each, and one too large, such as doubling, makes every
    step pay for the empty entries: docs/choices.md#neighbour-lists)."""
    capacity = int(state.contacts.pairs.shape[-2])
    demand = int(np.max(np.asarray(overflowed.contacts.demand)))
    if demand <= capacity:
        return capacity
    return max(math.ceil(PAIR_GROWTH * capacity), math.ceil(PAIR_HEADROOM * demand))


SLOT_HEADROOM, SLOT_EXTRA = 1.25, 4
"""A re-allocation after the slots overflowed gives this many times the most
neighbours any disk had in the chunk (`Contacts.slot_demand`; `slots_needed`),
and at least this many more: a growth of one or two slots can re-allocate a
small list several times in one chunk, a compile each
(docs/choices.md#neighbour-lists)."""


def slots_needed(state, overflowed) -> int:
    """Host-side: the slots a re-allocation of `state` must give at least,
    after the chunk that ended in `overflowed`: the old K, or, if some rebuild
    of the chunk found a disk with more neighbours than that,
    `SLOT_HEADROOM` times the most it found (at least `SLOT_EXTRA` more). The
    slots follow what the chunk found, not a fixed step on any overflow (the
    pair room's included): every slot beyond the pile's need makes each
    rebuild dearer (docs/choices.md#neighbour-lists)."""
    slots = int(state.neighbors.max_occupancy)
    demand = int(np.max(np.asarray(overflowed.contacts.slot_demand)))
    if demand > slots:
        return max(math.ceil(SLOT_HEADROOM * demand), demand + SLOT_EXTRA)
    flagged = (np.asarray(overflowed.neighbors.error.code) & int(partition.PEC.NEIGHBOR_LIST_OVERFLOW)) != 0
    pairs_short = np.asarray(overflowed.contacts.demand) > overflowed.contacts.pairs.shape[-2]
    if np.any(flagged & ~pairs_short):
        # flagged by no rebuild of the chunk (a list rebuilt to a given capacity outside it,
        # as a batch's or a checkpoint's): no demand to size by, so grow by the old slots (at least 4)
        return slots + max(4, slots)
    return slots


def window_needed(state, overflowed) -> int:
    """Host-side: the window W a re-allocation of `state` must give at least:
    the old one, or, if some rebuild of the chunk that ended in `overflowed`
    (any member of a batch) found more disks in a run of three cells than it
    holds, the old one plus the old slots (at least 4): a fixed step, as no
    rebuild records how many disks a crowded run held."""
    window = int(state.neighbors.cell_list_capacity or 0)
    code = np.asarray(overflowed.neighbors.error.code)
    if not np.any(code & int(partition.PEC.CELL_LIST_OVERFLOW)):
        return window
    return window + max(4, int(state.neighbors.max_occupancy))


def pair_capacity_for(idx: Array, at_least: int = 0, dimension: int = 2, fixed=None) -> int:
    """Host-side: the pair capacity to allocate for the full list `idx`: the
    more of `pairs_per_particle(dimension)` per particle that is not `fixed`
    (2D: `PAIRS_PER_DISK`; all of them when `fixed` is None) and
    `PAIR_HEADROOM` times its pairs, at least `at_least`, at most
    `pair_capacity` (which holds them all), rounded up to `PAIR_ALIGN`. Two
    fixed particles are never a pair (`_build`), so a pile's fixed base needs
    no room of its own."""
    n, k = idx.shape
    free = n if fixed is None else n - int(np.sum(np.asarray(fixed)))
    wanted = max(int(at_least), math.ceil(pairs_per_particle(dimension) * free),
                 math.ceil(PAIR_HEADROOM * host_lists.pair_count(idx)))
    return min(pair_capacity(n, k), aligned(wanted))


def update_with_contacts(neighbors, contacts, position: Array, settings: NeighborSettings,
                         axis_name: str | None = None, fixed: Array | None = None):
    """`update` and, when the list was rebuilt, the contacts re-laid on its
    half pairs, in one branch: the steps with no rebuild pay for neither. More
    pairs than the pair capacity raise the list's overflow flag. The contacts
    record the most pairs and the most neighbours of a disk any rebuild found
    (`Contacts.demand`, `Contacts.slot_demand`): a re-allocation's sizes."""
    own = needs_rebuild(neighbors, position, settings.skin)

    def rebuild():
        new, occupancy = _rebuilt_where_needed(neighbors, position, settings, own, axis_name, fixed)
        laid = contacts_for(contacts, neighbors.idx, new.idx)
        demand = jnp.maximum(contacts.demand, laid.demand)
        over = demand > contacts.pairs.shape[0]
        new = new.set(error=new.error.update(partition.PEC.NEIGHBOR_LIST_OVERFLOW, over))
        return new, laid.set(demand=demand, slot_demand=jnp.maximum(contacts.slot_demand, occupancy))

    return lax.cond(any_member(own, axis_name), rebuild, lambda: (neighbors, contacts))


def overflowed(state) -> Array:
    """Whether a state's lists lost anything: the full list overflowed, or some
    rebuild (or the laying of the pairs itself) found more half pairs than the
    pair list holds. Traceable; for a batch, per member. A concrete state is
    read on the host (numpy: the runner asks after every chunk, and the three
    eager ops would compile a program each per pile size)."""
    code, demand = state.neighbors.error.code, state.contacts.demand
    if isinstance(code, jax.core.Tracer) or isinstance(demand, jax.core.Tracer):
        return state.neighbors.did_buffer_overflow | (demand > state.contacts.pairs.shape[-2])
    lost = (np.asarray(code) & int(partition.PEC.NEIGHBOR_LIST_OVERFLOW | partition.PEC.CELL_LIST_OVERFLOW)) != 0
    return lost | (np.asarray(demand) > state.contacts.pairs.shape[-2])


