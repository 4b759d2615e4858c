"""A pile's surface h(x) and its angle of repose by the three methods of Lee &
Herrmann 1993, sec. 3, also per flank of a symmetric heap (Baxter et al. 1997)."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from jaxpile.engine.state import SimState
from jaxpile.errors import InputError
from jaxpile.measure.arrays import disk_arrays, positive_number


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
    position, radius, active = disk_arrays(position, radius, active)
    if not active.any():
        raise InputError("no active disk: the surface of an empty heap is undefined.")
    x, r = position[:, 0], radius
    if x_min is None:
        x_min = float(np.min((x - r)[active]))
    if width is None:
        width = float(np.max((x + r)[active])) - float(x_min)
    width = positive_number("width W", width)
    wanted = 2.0 * float(np.mean(r[active])) if column_width is None else positive_number("column_width", column_width)
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
                  apex: float | None = None, fill_gaps: bool = False) -> ReposeAngles:
    """The angle of repose of a surface profile by Lee & Herrmann's three methods.

    Lee & Herrmann measure the single slope of a pile leaning on the left wall of
    its box (`flank=None`). For a heap poured onto a base with its apex in the
    middle (Baxter et al. 1997), measure each flank: `flank="left"` keeps the
    columns at or left of the apex, `"right"` those at or right of it (the apex
    column, or the tied top columns, belong to their side).

    Empty columns at either end of the selection (beyond the toe of the heap)
    are dropped; an empty column inside it is an error, or with `fill_gaps`
    takes the straight line between its filled neighbours (a column of a
    single layer resting on the ground can hold no disk centre).

    Args:
      profile: from `surface_profile`.
      flank: None (all columns), `"left"` or `"right"`.
      x_range: optional `(x_lo, x_hi)`: only columns with centres in it, e.g. to
        leave out the rounded apex and the toe.
      apex: the apex x used by `flank`; default `apex_x(profile)`.
      fill_gaps: interpolate empty columns inside the selection instead of refusing them.

    Raises:
      InputError: on an unknown flank, fewer than 3 non-empty columns, or a gap (without `fill_gaps`).
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
    if fill_gaps:
        h = _fill_gaps(h)
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


__all__ = ["ReposeAngles", "SurfaceProfile", "apex_x", "mid_flank_angle", "recorded_repose_angles", "repose_angles", "surface_profile", "surface_profile_of"]
