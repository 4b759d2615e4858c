"""Measurements on a state: base forces, contact network, speeds and energies,
and the papers' heap measurements (host-side numpy, pure):

* the surface profile h(x) and the angle of repose by the three methods of
  Lee & Herrmann 1993, sec. 3, also per flank of a symmetric heap (Baxter et al. 1997);
* each disk's strongest and weakest contact, the "lines of maximum and minimum
  force" of Liffman, Chan & Hughes 1992, Figs. 10 and 16;
* the packing-fraction / voidage map, a cell-averaged version of the density
  maps of Baxter et al. 1997, Figs. 2, 5, 6 and 8;
* the mean kinetic energy per disk over time (Lee & Herrmann 1993, Fig. 1(b))
  and the step from which a series stays at rest.
"""

from __future__ import annotations

import functools
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxpile import budget
from jaxpile.engine.boundaries import GROUND
from jaxpile.errors import InputError
from jaxpile.engine.interactions import ContactForces
from jaxpile.engine.simulate import Simulator, max_speed
from jaxpile.engine.state import SimState


Array = Any

BASES = ("ground", "substrate")
"""What `base_load` can measure: a flat wall (the ground), or the fixed base disks."""


class BaseLoad(NamedTuple):
    """Every possible base contact with its force, as fixed-shape arrays.

    Entries that are not a contact (disks off the ground, empty neighbour slots,
    pairs not involving a fixed disk) are padding: weight 0 and zero x and forces.

    Attributes:
      x: `[c]` contact x: the disk centre's x on the ground; for a base disk, the
        point on the centre line that divides it in the ratio of the radii.
      normal: `[c]` force of the base on the pile normal to the base (the
        ground's normal; along -g for base disks), in mg.
      horizontal: `[c]` force the pile exerts on the base along it (+x for the
        ground), in mg: the sign convention of `analysis.base_forces` (Liffman
        et al. 1992, eq. 43: negative = leftwards).
      weight: `[c]` 1.0 for a contact, 0.0 for padding.
    """

    x: Array
    normal: Array
    horizontal: Array
    weight: Array


@jax.jit  # one program, not the ~12 eager ops it was on a concrete state (a compile each per pile size)
def traced_force_unit(state: SimState):
    """mg as a traceable scalar: the mean mass of the active movable disks times
    |g| (mass 1 when no disk moves, g taken as 1 when gravity is off)."""
    p = state.particles
    movable = p.movable
    count = jnp.sum(movable)
    total = jnp.sum(jnp.where(movable, p.mass, 0.0))
    mass = jnp.where(count > 0, total / jnp.maximum(count, 1), 1.0)
    g2 = jnp.sum(state.boundaries.gravity**2)
    g = jnp.where(g2 > 0, jnp.sqrt(jnp.where(g2 > 0, g2, 1.0)), 1.0)
    return mass * g


def base_load(sim, params, state: SimState, *, base: str = "ground", wall: int = GROUND) -> BaseLoad:
    """The forces at every contact between the pile and its base, traceable.

    Masks instead of boolean indexing, so the shapes do not depend on the
    contacts: usable under `jax.jit` and `jax.grad` (e.g. on the state a
    `Simulator.rollout` returns; `fit` does). Entries are not sorted;
    `base_forces` and `substrate_forces` are the contacts alone, sorted by x.

    Args:
      sim: the `Simulator` (its law evaluates the forces).
      params: the law's params pytree.
      state: the state to measure.
      base: `"ground"`: a wall (`wall`, default the ground), one entry per disk,
        x the disk centre's x. `"substrate"`: the fixed base disks (the poured heap
        of Baxter et al. 1997), one entry per neighbour slot `[n * k]`, "normal"
        along -g (+y when gravity is off).

    Returns:
      `BaseLoad` of `[n]` (ground) or `[n * k]` (substrate) arrays, forces in mg
      (`traced_force_unit`).

    Raises:
      InputError: on an unknown `base`.
    """
    if base not in BASES:
        raise InputError(f"base must be one of {list(BASES)}; got {base!r}.")
    return _base_load_from(sim.contact_forces(params, state), state, base, int(wall))


@functools.partial(jax.jit, static_argnums=(2, 3))
def _base_load_from(cf, state: SimState, base: str, wall: int) -> BaseLoad:
    """`base_load` from the contact forces `cf`: one compiled program (inlined
    when traced), not ~40 primitives each compiled op by op for each shape."""
    p = state.particles
    unit = traced_force_unit(state)
    if base == "ground":
        contact = cf.wall.in_contact[:, wall]
        force = jnp.where(contact[:, None], cf.wall.force[:, wall], 0.0)  # wall on disk
        normal_dir = state.boundaries.wall_normal[wall]
        along = jnp.stack([normal_dir[1], -normal_dir[0]])  # +x for the ground
        x = jnp.where(contact, p.position[:, 0], 0.0)
    else:
        idx = state.neighbors.idx
        n = idx.shape[0]
        valid = idx < n
        partner = jnp.where(valid, idx, 0)
        contact = cf.pair.in_contact & valid & p.movable[:, None] & p.fixed[partner]
        force = jnp.where(contact[..., None], cf.pair.force, 0.0)  # base disk on pile disk
        x_i, x_j = p.position[:, None, 0], p.position[partner, 0]
        r_i, r_j = p.radius[:, None], p.radius[partner]
        x = jnp.where(contact, x_j + (x_i - x_j) * r_j / (r_i + r_j), 0.0)
        g = state.boundaries.gravity
        g2 = jnp.sum(g**2)
        up = jnp.where(g2 > 0, -g / jnp.sqrt(jnp.where(g2 > 0, g2, 1.0)), jnp.array([0.0, 1.0], g.dtype))
        normal_dir = up
        along = jnp.stack([up[1], -up[0]])
        contact, force, x = contact.reshape(-1), force.reshape(-1, 2), x.reshape(-1)
    normal = (force @ normal_dir) / unit
    horizontal = -(force @ along) / unit
    return BaseLoad(x=x, normal=normal, horizontal=horizontal, weight=contact.astype(force.dtype))


class BaseForces(NamedTuple):
    """Every contact between the pile and the ground, sorted by x.

    Attributes:
      x: `[c]` contact x (the disk centre's x).
      normal: `[c]` normal force of the ground on the disk, in mg.
      horizontal: `[c]` horizontal force the disk exerts on the ground, in mg
        (the sign convention of Liffman et al. 1992, eq. 43: negative = leftwards).
      particle: `[c]` disk ids.
    """

    x: np.ndarray
    normal: np.ndarray
    horizontal: np.ndarray
    particle: np.ndarray


def force_unit(state: SimState) -> float:
    """mg: the mean mass of the active movable disks times |g| (g taken as 1
    when gravity is off, so forces are then in units of force)."""
    return float(traced_force_unit(state))


def base_forces(sim: Simulator, params, state: SimState, wall: int = GROUND) -> BaseForces:
    """Forces at every disk-ground contact (in mg): `base_load`'s contacts, sorted by x."""
    load = base_load(sim, params, state, base="ground", wall=wall)
    ids = np.flatnonzero(np.asarray(load.weight) > 0)
    x = np.asarray(load.x)[ids]
    order = np.argsort(x)
    return BaseForces(x=x[order], normal=np.asarray(load.normal)[ids][order],
                      horizontal=np.asarray(load.horizontal)[ids][order], particle=ids[order])


class SubstrateForces(NamedTuple):
    """Every contact between a movable disk and a fixed (substrate) disk, sorted
    by x, in mg (`force_unit`: the mean movable mass times g). The fields of
    `BaseForces`, plus the substrate partner.

    Attributes:
      x: `[c]` x of the contact point (on the centre line, dividing it in the
        ratio of the radii).
      normal: `[c]` force of the substrate on the heap normal to the base
        (upwards, along -g): the paper's F_B.
      horizontal: `[c]` force the heap disk exerts on the substrate along the
        base (+x; the sign convention of `analysis.base_forces`).
      particle: `[c]` the movable disk ids.
      substrate: `[c]` the substrate disk ids.
    """

    x: np.ndarray
    normal: np.ndarray
    horizontal: np.ndarray
    particle: np.ndarray
    substrate: np.ndarray


def substrate_forces(sim, params, state: SimState) -> SubstrateForces:
    """Forces at every contact of a movable disk with a fixed one (a row of base
    disks: the poured heap of Baxter et al. 1997, the flux pile of Lee & Herrmann
    1993), in mg, with "normal" along -g: `base_load`'s contacts, sorted by x."""
    load = base_load(sim, params, state, base="substrate")
    idx = np.asarray(state.neighbors.idx)
    keep = np.flatnonzero(np.asarray(load.weight) > 0)  # flat [n * k] slots
    i, j = keep // idx.shape[1], idx.reshape(-1)[keep]
    x = np.asarray(load.x)[keep]
    order = np.argsort(x, kind="stable")
    return SubstrateForces(x=x[order], normal=np.asarray(load.normal)[keep][order],
                           horizontal=np.asarray(load.horizontal)[keep][order], particle=i[order],
                           substrate=j[order])


class ContactNetwork(NamedTuple):
    """Each disk-disk contact once (i < j) with its force, in mg."""

    i: np.ndarray
    j: np.ndarray
    normal: np.ndarray
    tangential: np.ndarray


def contact_network(sim: Simulator, params, state: SimState) -> ContactNetwork:
    cf = sim.contact_forces(params, state)
    idx = np.asarray(state.neighbors.idx)
    n = idx.shape[0]
    rows = np.repeat(np.arange(n)[:, None], idx.shape[1], axis=1)
    keep = np.asarray(cf.pair.in_contact) & (idx > rows) & (idx < n)
    i, j = rows[keep], idx[keep]
    pos = np.asarray(state.particles.position)
    d = pos[i] - pos[j]
    nhat = d / np.linalg.norm(d, axis=1, keepdims=True)
    f = np.asarray(cf.pair.force)[keep]
    fn = np.sum(f * nhat, axis=1)
    ft = np.abs(f[:, 0] * nhat[:, 1] - f[:, 1] * nhat[:, 0])
    unit = force_unit(state)
    return ContactNetwork(i=i, j=j, normal=fn / unit, tangential=ft / unit)


def kinetic_energy(state: SimState) -> float:
    """Translational plus rotational kinetic energy of the movable disks."""
    p = state.particles
    e = 0.5 * p.mass * jnp.sum(p.velocity**2, -1) + 0.5 * p.inertia * p.angular_velocity**2
    return float(jnp.sum(jnp.where(p.movable, e, 0.0)))


# ---------------------------------------------------------------- input checks
def _disks(position, radius, active=None):
    """Checked `[n, 2]` positions, `[n]` radii and `[n]` active mask (float64 numpy)."""
    position = np.asarray(position, dtype=np.float64)
    if position.ndim != 2 or position.shape[1] != 2:
        raise InputError(f"position must have shape [n, 2]; got {position.shape}.")
    n = position.shape[0]
    if n == 0:
        raise InputError("no disks: position is empty.")
    radius = np.asarray(radius, dtype=np.float64)
    if radius.ndim > 1 or (radius.ndim == 1 and radius.shape[0] != n):
        raise InputError(f"radius must be a scalar or have one value per disk ({n}); got shape {radius.shape}.")
    radius = np.broadcast_to(radius, (n,))
    if not np.all(np.isfinite(position)) or not np.all(np.isfinite(radius)) or np.any(radius <= 0):
        raise InputError("positions must be finite and radii positive and finite.")
    active = np.ones(n, bool) if active is None else np.asarray(active, dtype=bool)
    if active.shape != (n,):
        raise InputError(f"active must have shape [{n}]; got {active.shape}.")
    return position, radius, active


def _positive(name: str, value) -> float:
    value = float(value)
    if not (value > 0 and np.isfinite(value)):
        raise InputError(f"{name} must be positive and finite; got {value!r}.")
    return value


# ------------------------------------------------ surface and angle of repose
class SurfaceProfile(NamedTuple):
    """The surface h(x) of a heap, one value per vertical column (Lee & Herrmann 1993, sec. 3).

    Attributes:
      x: `[c]` column centres (length).
      height: `[c]` h(x): the highest disk-centre height in the column (or the
        highest disk top, y + r, when built with `top=True`); NaN for an empty column.
      count: `[c]` number of disks whose centre lies in the column.
      particle: `[c]` id of the disk that sets h(x); -1 for an empty column.
      column_width: the column width actually used (length).
    """

    x: np.ndarray
    height: np.ndarray
    count: np.ndarray
    particle: np.ndarray
    column_width: float


def surface_profile(position, radius, active=None, *, x_min: float | None = None,
                    width: float | None = None, column_width: float | None = None,
                    top: bool = False) -> SurfaceProfile:
    """h(x) from vertical columns about one mean diameter wide (Lee & Herrmann 1993, sec. 3).

    "We could first divide the box into several vertical cells, the width of each
    cell being equal to the average diameter of the particles. For the centre of
    each cell x, we find the maximum position h(x) of the particles in the cell."
    A disk belongs to the column holding its centre; h(x) is the largest centre
    height there ("maximum position of the particles"), or the largest y + r with
    `top=True` (same slopes for equal disks).

    The columns tile `[x_min, x_min + width]` exactly: their number is
    `round(width / column_width)` (at least 1), so the width used (returned as
    `column_width`) differs from the one asked for by at most half a column spread
    over all columns. Disks with centres outside the range are ignored.

    Args:
      position: `[n, 2]` centres.
      radius: `[n]` or a scalar.
      active: `[n]` bool, the disks that count (default: all).
      x_min: left end of the range (the box's left wall in Lee & Herrmann);
        default: the leftmost disk edge.
      width: W, the length of the range; default: up to the rightmost disk edge.
      column_width: default: the mean diameter of the counted disks.
      top: measure the disk tops (y + r) rather than the centres.

    Raises:
      InputError: on empty or malformed arrays, no active disk, or a width or
        column width that is not positive.
    """
    position, radius, active = _disks(position, radius, active)
    if not active.any():
        raise InputError("no active disk: the surface of an empty heap is undefined.")
    x, r = position[:, 0], radius
    if x_min is None:
        x_min = float(np.min((x - r)[active]))
    if width is None:
        width = float(np.max((x + r)[active])) - float(x_min)
    width = _positive("width W", width)
    wanted = 2.0 * float(np.mean(r[active])) if column_width is None else _positive("column_width", column_width)
    columns = max(1, int(round(width / wanted)))
    dx = width / columns
    column = np.floor((x - x_min) / dx).astype(np.int64)
    # a centre exactly on the right end belongs to the last column
    column = np.where(np.isclose(x, x_min + width, rtol=0.0, atol=1e-12 * width), columns - 1, column)
    counted = active & (column >= 0) & (column < columns)
    y = position[:, 1] + (r if top else 0.0)
    height = np.full(columns, np.nan)
    particle = np.full(columns, -1, np.int64)
    count = np.bincount(column[counted], minlength=columns)
    ids = np.flatnonzero(counted)
    order = ids[np.lexsort((-y[ids], column[ids]))]  # by column, highest first
    first = np.unique(column[order], return_index=True)[1]
    tops = order[first]
    height[column[tops]] = y[tops]
    particle[column[tops]] = tops
    centres = x_min + dx * (np.arange(columns) + 0.5)
    return SurfaceProfile(x=centres, height=height, count=count, particle=particle, column_width=dx)


def surface_profile_of(state: SimState, **kwargs) -> SurfaceProfile:
    """`surface_profile` of the active disks of a state (fixed disks included)."""
    p = state.particles
    return surface_profile(np.asarray(p.position), np.asarray(p.radius), np.asarray(p.active), **kwargs)


class ReposeAngles(NamedTuple):
    """Angle of repose by the three methods of Lee & Herrmann 1993, sec. 3.

    Angles are the inclination of the surface to the horizontal, in degrees,
    >= 0 whichever way the flank faces; `slopes` keeps the sign.

    Attributes:
      endpoints: method (1), the line joining h at the first and the last column.
      least_squares: method (2), a least-squares straight line through h(x).
      cumulative_parabola: method (3), the one Lee & Herrmann keep: a least-squares
        parabola a x^2 + b x + c through the running sum S(x) = sum_{x' <= x} h(x') dx;
        a straight h of slope s gives exactly a = s / 2, so the slope is 2a.
      slopes: `[3]` the signed slopes dh/dx of methods (1), (2), (3).
      x: `[c]` centres of the columns used.
    """

    endpoints: float
    least_squares: float
    cumulative_parabola: float
    slopes: np.ndarray
    x: np.ndarray


def apex_x(profile: SurfaceProfile) -> float:
    """x of the highest column (the mean x of the columns tied for highest)."""
    h = np.asarray(profile.height)
    if np.all(np.isnan(h)):
        raise InputError("the profile has no non-empty column.")
    top = np.nanmax(h)
    tied = np.isclose(h, top, rtol=0.0, atol=1e-9 * max(1.0, abs(top)))
    return float(np.mean(np.asarray(profile.x)[tied]))


def repose_angles(profile: SurfaceProfile, *, flank: str | None = None, x_range=None,
                  apex: float | None = None) -> ReposeAngles:
    """The angle of repose of a surface profile by Lee & Herrmann's three methods.

    Lee & Herrmann measure the single slope of a pile leaning on the left wall of
    its box (`flank=None`). For a heap poured onto a base with its apex in the
    middle (Baxter et al. 1997), measure each flank: `flank="left"` keeps the
    columns at or left of the apex, `"right"` those at or right of it (the apex
    column, or the tied top columns, belong to their side).

    Empty columns at either end of the selection (beyond the toe of the heap)
    are dropped; an empty column inside it is an error.

    Args:
      profile: from `surface_profile`.
      flank: None (all columns), `"left"` or `"right"`.
      x_range: optional `(x_lo, x_hi)`: only columns with centres in it, e.g. to
        leave out the rounded apex and the toe.
      apex: the apex x used by `flank`; default `apex_x(profile)`.

    Raises:
      InputError: on an unknown flank, fewer than 3 non-empty columns, or a gap.
    """
    x = np.asarray(profile.x, dtype=np.float64)
    h = np.asarray(profile.height, dtype=np.float64)
    keep = np.ones(x.shape, bool)
    if flank is not None:
        if flank not in ("left", "right"):
            raise InputError(f"flank must be None, 'left' or 'right'; got {flank!r}.")
        centre = apex_x(profile) if apex is None else float(apex)
        keep &= (x <= centre) if flank == "left" else (x >= centre)
    if x_range is not None:
        lo, hi = (float(v) for v in x_range)
        if not lo < hi:
            raise InputError(f"x_range must be (x_lo, x_hi) with x_lo < x_hi; got {x_range!r}.")
        keep &= (x >= lo) & (x <= hi)
    x, h = x[keep], h[keep]
    filled = np.flatnonzero(~np.isnan(h))
    if filled.size:
        x, h = x[filled[0]: filled[-1] + 1], h[filled[0]: filled[-1] + 1]
    if filled.size < 3:
        raise InputError(f"the angle of repose needs at least 3 non-empty columns; the selection has {filled.size}.")
    if np.isnan(h).any():
        gap = float(x[np.isnan(h)][0])
        raise InputError(f"empty column at x = {gap:g} inside the selection; "
                         "narrow it with x_range or use wider columns.")
    endpoint_slope = (h[-1] - h[0]) / (x[-1] - x[0])
    line_slope = np.polyfit(x - x.mean(), h, 1)[0]
    running_sum = np.cumsum(h) * profile.column_width
    parabola_slope = 2.0 * np.polyfit(x - x.mean(), running_sum, 2)[0]
    slopes = np.array([endpoint_slope, line_slope, parabola_slope])
    angles = np.degrees(np.arctan(np.abs(slopes)))
    return ReposeAngles(endpoints=float(angles[0]), least_squares=float(angles[1]),
                        cumulative_parabola=float(angles[2]), slopes=slopes, x=x)



def _fill_gaps(height: np.ndarray) -> np.ndarray:
    """Empty columns between filled ones get the linear interpolation of their
    neighbours (a bottom-layer column can hold no disk centre); empty columns
    at the ends stay empty."""
    h = np.array(height, dtype=np.float64)
    h[~np.isfinite(h)] = np.nan
    filled = np.flatnonzero(~np.isnan(h))
    if filled.size >= 2:
        inside = np.arange(filled[0], filled[-1] + 1)
        h[inside] = np.interp(inside, filled, h[filled])
    return h


def recorded_repose_angles(x_min: float, column_width: float, heights) -> dict:
    """The three angles of Lee & Herrmann 1993 sec. 3 (degrees) of each recorded
    surface h(x) (the flux protocol records one before each insertion, Fig. 5).

    Args:
      x_min, column_width: the columns.
      heights: `[k, c]` recorded h(x) (-inf or NaN for an empty column).

    Returns:
      dict of `[k]` lists `endpoints`, `least_squares`, `cumulative_parabola`
      (NaN where a surface has fewer than 3 columns).
    """
    heights = np.atleast_2d(np.asarray(heights, dtype=np.float64))
    x = x_min + column_width * (np.arange(heights.shape[1]) + 0.5)
    out = {"endpoints": [], "least_squares": [], "cumulative_parabola": []}
    for row in heights:
        h = _fill_gaps(row)
        profile = SurfaceProfile(x=x, height=h, count=(~np.isnan(h)).astype(np.int64),
                                          particle=np.full(h.size, -1), column_width=float(column_width))
        try:
            a = repose_angles(profile)
            values = (a.endpoints, a.least_squares, a.cumulative_parabola)
        except InputError:
            values = (float("nan"),) * 3
        for key, value in zip(out, values):
            out[key].append(float(value))
    return out

def mid_flank_angle(profile: SurfaceProfile, *, flank: str, base: float, band=(0.2, 0.8),
                    apex: float | None = None) -> float | None:
    """The angle between a heap's flank and its base (Baxter et al. 1997, sec.
    III), from the straight part of the flank only: a least-squares line through
    the flank's columns whose height above `base` lies in `band` (fractions of
    the apex height), so that neither the rounded apex nor a one-disk toe spread
    along the base tilts the line.

    Args:
      profile: from `surface_profile` (h = disk-centre heights).
      flank: `"left"` or `"right"` of the apex.
      base: the height the apex height is measured from (the substrate's
        centre line for a poured heap).
      band: `(lo, hi)` fractions of the apex height, 0 <= lo < hi <= 1.
      apex: the apex x; default `apex_x(profile)`.

    Returns:
      The angle in degrees, or None when fewer than 3 columns lie in the band.
    """
    if flank not in ("left", "right"):
        raise InputError(f"flank must be 'left' or 'right'; got {flank!r}.")
    lo, hi = (float(b) for b in band)
    if not 0.0 <= lo < hi <= 1.0:
        raise InputError(f"band must be (lo, hi) with 0 <= lo < hi <= 1; got {band!r}.")
    x = np.asarray(profile.x, dtype=np.float64)
    h = np.asarray(profile.height, dtype=np.float64) - float(base)
    centre = apex_x(profile) if apex is None else float(apex)
    top = float(np.nanmax(h))
    side = (x <= centre) if flank == "left" else (x >= centre)
    with np.errstate(invalid="ignore"):
        keep = side & (h >= lo * top) & (h <= hi * top)
    if keep.sum() < 3:
        return None
    slope = np.polyfit(x[keep] - x[keep].mean(), h[keep], 1)[0]
    return float(np.degrees(np.arctan(abs(slope))))


# --------------------------------------------------------------- force chains
def wall_partner(wall: int) -> int:
    """The partner id `force_chains` gives wall `wall`: -1 - wall (ground = -1)."""
    return -1 - int(wall)


class ForceChains(NamedTuple):
    """Each disk's strongest and weakest contact (Liffman, Chan & Hughes 1992, Figs. 10, 16).

    Partners are disk ids `0..n-1`, or walls as `-1 - w` (`wall_partner(w)`: the
    ground is -1); a disk without a contact has partner `n` (the empty-slot mark
    of the neighbour list) and force NaN.

    Attributes:
      strongest: `[n]` partner of the largest contact force on each disk.
      strongest_force: `[n]` its magnitude.
      weakest: `[n]` partner of the smallest contact force on each disk.
      weakest_force: `[n]` its magnitude.
      contacts: `[n]` how many contacts were compared.
    """

    strongest: np.ndarray
    strongest_force: np.ndarray
    weakest: np.ndarray
    weakest_force: np.ndarray
    contacts: np.ndarray


def force_chains(forces: ContactForces, neighbor_idx, *, measure: str = "total",
                 min_force: float = 0.0, unit: float = 1.0) -> ForceChains:
    """For every disk, the partner pushing on it hardest and the one pushing least.

    Liffman et al. draw "the lines of maximum and minimum force" acting on each
    particle (Figs. 10(a), (b) and 16(a), (b)). A contact counts when its slot is
    `in_contact` and its force exceeds `min_force`: so a touching pair that
    carries nothing (the same-level neighbours of the 1992 equilateral pile, of
    which the paper says "no contacts between particles on the same level")
    is not anybody's weakest contact. Ties go to the first slot (disks before walls).

    Args:
      forces: `ContactForces` (`.pair` `[n, k]`, `.wall` `[n, w]`), e.g. from
        `Simulator.contact_forces`.
      neighbor_idx: `[n, k]` the neighbour slots the forces belong to (empty = n).
      measure: `"total"` compares |F| (normal and tangential together);
        `"normal"` compares the normal force `PairForce.normal`.
      min_force: the force a contact must exceed to count (in `unit`s).
      unit: forces are divided by it (e.g. `force_unit(state)` for mg).
    """
    idx = np.asarray(neighbor_idx)
    if idx.ndim != 2 or idx.shape[0] == 0:
        raise InputError(f"neighbor_idx must have shape [n, k] with n > 0; got {idx.shape}.")
    if measure not in ("total", "normal"):
        raise InputError(f"measure must be 'total' or 'normal'; got {measure!r}.")
    unit = _positive("unit", unit)
    n = idx.shape[0]

    def magnitude(pf):
        value = np.linalg.norm(np.asarray(pf.force), axis=-1) if measure == "total" else np.abs(np.asarray(pf.normal))
        return value / unit

    pair_f, wall_f = magnitude(forces.pair), magnitude(forces.wall)
    if pair_f.shape != idx.shape or wall_f.shape[0] != n:
        raise InputError(f"forces do not match neighbor_idx: pair {pair_f.shape}, "
                         f"wall {wall_f.shape}, idx {idx.shape}.")
    walls = wall_f.shape[1]
    partner = np.concatenate([idx, np.broadcast_to(-1 - np.arange(walls), (n, walls))], axis=1)
    force = np.concatenate([pair_f, wall_f], axis=1)
    counts = np.concatenate([np.asarray(forces.pair.in_contact) & (idx >= 0) & (idx < n),
                             np.asarray(forces.wall.in_contact)], axis=1) & (force > min_force)
    any_contact = counts.any(axis=1)
    rows = np.arange(n)
    high = np.argmax(np.where(counts, force, -np.inf), axis=1)
    low = np.argmin(np.where(counts, force, np.inf), axis=1)

    def pick(col):
        return (np.where(any_contact, partner[rows, col], n),
                np.where(any_contact, force[rows, col], np.nan))

    strongest, strongest_force = pick(high)
    weakest, weakest_force = pick(low)
    return ForceChains(strongest=strongest, strongest_force=strongest_force, weakest=weakest,
                       weakest_force=weakest_force, contacts=counts.sum(axis=1))


def force_chains_of(sim: Simulator, params, state: SimState, **kwargs) -> ForceChains:
    """`force_chains` of a state, forces in mg (`force_unit`)."""
    return force_chains(sim.contact_forces(params, state), state.neighbors.idx,
                        unit=kwargs.pop("unit", force_unit(state)), **kwargs)


# -------------------------------------------------------------- packing maps
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
    position, radius, active = _disks(position, radius, active)
    cell = _positive("cell_size", cell_size)
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
    position, radius, active = _disks(position, radius, active)
    x_min, x_max, y_min, y_max = _region(position, radius, active, region)
    inside = disk_rectangle_overlap(position[active], radius[active], x_min, x_max, y_min, y_max)
    return float(inside.sum() / ((x_max - x_min) * (y_max - y_min)))


# ------------------------------------------------------- energy and rest in time
def _mean_kinetic_energy(mass, velocity, inertia, angular_velocity, movable):
    """Mean over movable disks of m v^2 / 2 + I w^2 / 2; arrays may carry a leading time axis."""
    e = 0.5 * mass * np.sum(velocity**2, axis=-1) + 0.5 * inertia * angular_velocity**2
    count = np.maximum(np.sum(movable, axis=-1), 1)
    return np.sum(np.where(movable, e, 0.0), axis=-1) / count


def mean_kinetic_energy(state: SimState) -> float:
    """Kinetic energy per movable disk (translation plus rotation): the quantity
    Lee & Herrmann 1993 monitor in Fig. 1(b)."""
    p = state.particles
    return float(_mean_kinetic_energy(*(np.asarray(a) for a in (p.mass, p.velocity, p.inertia,
                                                               p.angular_velocity, p.movable))))


def kinetic_energy_series(states) -> np.ndarray:
    """`[T]` kinetic energy per movable disk of each state, for Lee & Herrmann's Fig. 1(b).

    Args:
      states: a sequence of `SimState`s, or one `SimState` whose particle arrays
        carry a leading time axis (a stacked rollout).
    """
    if isinstance(states, SimState):
        p = states.particles
        arrays = [np.asarray(a) for a in (p.mass, p.velocity, p.inertia, p.angular_velocity, p.movable)]
        if arrays[1].ndim != 3:
            raise InputError("a single SimState needs a leading time axis; pass a list of states instead.")
        return np.atleast_1d(_mean_kinetic_energy(*arrays))
    states = list(states)
    if not states:
        raise InputError("no states: the kinetic-energy series of an empty run is undefined.")
    return np.array([mean_kinetic_energy(s) for s in states])


def rest_index(series, tolerance: float) -> int | None:
    """The first index from which `series` (a kinetic energy or max-speed history)
    stays below `tolerance` to its end; None if its last value is not below it.

    Lee & Herrmann 1993 wait "until the maximum velocity of the particles is again
    smaller than v_cut" (sec. 5); this finds when that happened for good.
    """
    values = np.asarray(series, dtype=np.float64)
    if values.ndim != 1 or values.size == 0:
        raise InputError(f"series must be a non-empty 1-D array; got shape {values.shape}.")
    tolerance = _positive("tolerance", tolerance)
    moving = np.flatnonzero(~(values < tolerance))  # NaN counts as moving
    if moving.size == 0:
        return 0
    last = int(moving[-1])
    return None if last == values.size - 1 else last + 1


__all__ = [
    "BaseForces",
    "ContactNetwork",
    "ForceChains",
    "ReposeAngles",
    "SurfaceProfile",
    "VoidageMap",
    "apex_x",
    "base_forces",
    "contact_network",
    "disk_rectangle_overlap",
    "force_chains",
    "force_chains_of",
    "force_unit",
    "kinetic_energy",
    "kinetic_energy_series",
    "max_speed",
    "mean_kinetic_energy",
    "packing_fraction",
    "mid_flank_angle",
    "recorded_repose_angles",
    "repose_angles",
    "rest_index",
    "surface_profile",
    "surface_profile_of",
    "voidage_map",
    "voidage_map_bytes",
    "voidage_map_of",
    "wall_partner",
]
