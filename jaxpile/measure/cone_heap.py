"""The measurements of a conical heap of spheres (`jaxpile.protocols.cone`), as
an experimentalist reads a heap poured onto a plate (Smid & Novosad 1981, the
2D papers' three-dimensional original): the azimuthally averaged surface h(r)
and the angle of repose from it, the radial base pressure p(r) (the base's
normal force per annulus area) and its dip at the centre, and the packing
fraction of the core. Heights are above the plate's top (its spheres' highest
point). Host-side numpy on a state at rest."""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from jaxpile.engine.state import SimState

SECTORS = 8
"""Azimuthal sectors h(r) is read in: each sector's highest sphere top per ring, then their mean."""

ANGLE_BAND = (0.2, 0.8)
"""The rings of h(r) the angle of repose is fitted over, as fractions of the apex height (the 2D
`mid_flank_angle`'s band): the toe and the rounded apex left out."""

DIP_RING = (0.3, 0.6)
"""Where the ring maximum is looked for, in r / R (R the heap's base radius): the 2D dip's flank windows
(x/B 0.20-0.35 and 0.65-0.80, `heap.DIP_FLANK_WINDOWS`) turned about the axis."""

DIP_CENTRE = 0.1
"""The centre's disk, r / R below this (the 2D centre window x/B 0.45-0.55)."""


class RadialProfile(NamedTuple):
    """A radial profile over rings about the heap's axis.

    Attributes:
      r: `[b]` ring centres (diameters).
      value: `[b]` the profile in each ring (NaN where a ring holds nothing to read).
      width: the rings' width.
    """

    r: np.ndarray
    value: np.ndarray
    width: float


def heap_spheres(state: SimState) -> np.ndarray:
    """`[n]` bool: the poured spheres in play (active and not fixed)."""
    return np.asarray(state.particles.movable)


def surface(position, radius, axis, *, base: float = 1.0, ring: float = 1.0, sectors: int = SECTORS) -> RadialProfile:
    """h(r) above the plate's top `base`: in each ring `ring` wide and each of
    its sectors (`sectors`, fewer near the axis: one on it), the highest sphere
    top (z + r), a sector with none at the plate (h = 0); their mean, as an
    azimuthally averaged surface scan reads it."""
    d = position[:, :2] - np.asarray(axis)[None, :]
    r = np.hypot(d[:, 0], d[:, 1])
    theta = np.arctan2(d[:, 1], d[:, 0])
    rings = int(np.floor(r.max() / ring)) + 1 if len(r) else 1
    k = np.minimum((r / ring).astype(int), rings - 1)
    # fewer sectors near the axis, where a ring is too small to hold a sphere in each: one on the axis
    counts = np.minimum(sectors, np.maximum(1, np.round(2.0 * math.pi * np.arange(rings)).astype(int)))
    s = np.minimum(((theta + math.pi) / (2 * math.pi) * counts[k]).astype(int), counts[k] - 1)
    top = np.zeros((rings, sectors))
    np.maximum.at(top, (k, s), np.maximum(position[:, 2] + radius - base, 0.0))
    return RadialProfile(r=(np.arange(rings) + 0.5) * ring, value=top.sum(axis=1) / counts, width=ring)


def repose_angle(profile: RadialProfile, band=ANGLE_BAND) -> float | None:
    """The angle of repose (degrees): the least-squares slope of h(r) over the
    rings outward of the apex (the highest ring) whose height lies within
    `band` of the apex height, up to the first ring below it (a skirt of
    scattered spheres beyond is not the flank); None when fewer than 3 rings."""
    h = profile.value
    if not np.isfinite(h).any():
        return None
    top = int(np.nanargmax(h))
    apex = float(h[top])
    low, high = band[0] * apex, band[1] * apex
    below = np.flatnonzero(np.arange(len(h)) > top) if top + 1 < len(h) else np.zeros(0, int)
    below = below[~(h[below] >= low)]  # the first ring outward under the band ends the flank: the skirt is not read
    end = int(below[0]) if len(below) else len(h)
    keep = (np.arange(len(h)) > top) & (np.arange(len(h)) < end) & (h >= low) & (h <= high)
    if keep.sum() < 3:
        return None
    slope = np.polyfit(profile.r[keep], h[keep], 1)[0]
    return float(math.degrees(math.atan(-slope)))


def base_contacts(sim, params, state: SimState) -> tuple[np.ndarray, np.ndarray]:
    """The heap's contacts with the fixed base spheres: their points' (x, y)
    `[c, 2]` and the normal force each carries along -g, in mg (the mean heap
    sphere's weight)."""
    cf = sim.contact_forces(params, state)
    p = state.particles
    idx = np.asarray(state.neighbors.idx)
    n = idx.shape[0]
    movable, fixed = np.asarray(p.movable), np.asarray(p.fixed)
    valid = idx < n
    partner = np.where(valid, idx, 0)
    touching = np.asarray(cf.pair.in_contact) & valid & movable[:, None] & fixed[partner]
    i, slot = np.nonzero(touching)
    j = idx[i, slot]
    x, rad = np.asarray(p.position), np.asarray(p.radius)
    point = x[j] + (x[i] - x[j]) * (rad[j] / (rad[i] + rad[j]))[:, None]
    g = np.asarray(state.boundaries.gravity)
    up = -g / np.linalg.norm(g)
    mg = float(np.mean(np.asarray(p.mass)[movable])) * float(np.linalg.norm(g))
    force = np.asarray(cf.pair.force)[i, slot] @ up / mg
    return point[:, :2], force


def base_pressure(points, forces, axis, radius: float, *, rings: int = 10) -> RadialProfile:
    """p(r): the base's normal force in each of `rings` annuli out to `radius`,
    over the annulus' area, normalised by the mean pressure over the disk of
    that radius (the heap's weight over its base area): 1 for a uniform load."""
    r = np.hypot(*(points - np.asarray(axis)[None, :]).T)
    edges = np.linspace(0.0, radius, rings + 1)
    load, _ = np.histogram(r, bins=edges, weights=forces)
    area = math.pi * (edges[1:] ** 2 - edges[:-1] ** 2)
    mean = forces[r <= radius].sum() / (math.pi * radius ** 2)
    return RadialProfile(r=0.5 * (edges[1:] + edges[:-1]), value=load / area / mean if mean > 0 else load * np.nan,
                         width=radius / rings)


def central_dip(points, forces, axis, radius: float, centre: float = DIP_CENTRE, ring=DIP_RING) -> float:
    """1 - the pressure on the centre's disk (r < `centre` R) over the
    pressure on the ring `ring` (r / R within it, one annulus: the
    flanks' windows turned about the axis), R = `radius`: Smid & Novosad's
    dip read with windows fixed in advance. NaN when either holds no load."""
    r = np.hypot(*(points - np.asarray(axis)[None, :]).T) / radius
    inner = forces[r < centre].sum() / (math.pi * centre ** 2)
    lo, hi = ring
    outer = forces[(r >= lo) & (r < hi)].sum() / (math.pi * (hi ** 2 - lo ** 2))
    return 1.0 - inner / outer if outer > 0 and inner > 0 else float("nan")


def packing_fraction(position, radius, axis, bottom: float, top: float, core: float) -> float:
    """The spheres' volume fraction in the cylinder of radius `core` about the
    axis from z = `bottom` to `top`, counting the spheres whose centres lie
    inside (their whole volume: for a cylinder several diameters across the
    edge errors are a surface term)."""
    d = np.hypot(*(position[:, :2] - np.asarray(axis)[None, :]).T)
    inside = (d < core) & (position[:, 2] > bottom) & (position[:, 2] < top)
    volume = math.pi * core ** 2 * (top - bottom)
    return float((4.0 / 3.0) * math.pi * np.sum(radius[inside] ** 3) / volume) if volume > 0 else float("nan")


def measure(sim, params, state: SimState, *, axis, ring: float = 1.0, rings: int = 10) -> dict:
    """The cone's measurements.

    Returns a dict with `counts` (poured, in play, lost), `height` (the apex's
    top above the plate's top), `base_radius` R (the radius within which the base carries
    99% of the heap's load), `surface` (h(r), `RadialProfile`), `angle` (the
    angle of repose from h(r), degrees; None for a heap too flat or small to
    read), `angle_height_base` atan(h / R), `pressure` (p(r) over `rings`
    annuli out to R, normalised), `central_dip` (`central_dip`), `weight` and
    `base_load` (mg: the heap's weight and what the base carries) and
    `packing_fraction` (a cylinder R / 4 about the axis from the plate up to
    half the height).
    """
    p = state.particles
    ps = state.protocol_state
    heap = heap_spheres(state)
    out = {"counts": {"poured": int(ps.poured), "in_play": int(heap.sum()), "lost": int(np.asarray(ps.lost).sum())}}
    if not heap.any():
        return out
    x, rad = np.asarray(p.position)[heap], np.asarray(p.radius)[heap]
    fixed = np.asarray(p.fixed)
    if fixed.any():  # the plate: the lowest layer of fixed spheres (a lifted cylinder's are fixed too)
        z = np.asarray(p.position)[:, 2]
        plate = fixed & (z <= z[fixed].min() + 1e-6)
        base = float(np.max(z[plate] + np.asarray(p.radius)[plate]))
    else:
        base = 0.0
    h = surface(x, rad, axis, base=base, ring=ring)
    points, forces = base_contacts(sim, params, state)
    r = np.hypot(*(points - np.asarray(axis)[None, :]).T) if len(points) else np.zeros(0)
    order = np.argsort(r)
    cumulative = np.cumsum(forces[order]) if len(r) else np.zeros(0)
    radius = float(r[order][np.searchsorted(cumulative, 0.99 * cumulative[-1])]) if len(r) else float("nan")
    height = float(np.max(x[:, 2] + rad)) - base
    mass = np.asarray(p.mass)[heap]
    out.update(height=height, base_radius=radius, surface=h, angle=repose_angle(h),
               angle_height_base=math.degrees(math.atan2(height, radius)) if radius > 0 else float("nan"),
               weight=float(np.sum(mass) / np.mean(mass)), base_load=float(forces.sum()))
    if len(points) and radius > 0:
        out["pressure"] = base_pressure(points, forces, axis, radius, rings=rings)
        out["central_dip"] = central_dip(points, forces, axis, radius)
    out["packing_fraction"] = packing_fraction(x, rad, axis, base, base + 0.5 * height, 0.25 * radius)
    return out


def summary(measured: dict) -> dict:
    """The scalar measurements and the profiles as plain JSON numbers (for `summary.json`)."""
    out = {"counts": dict(measured["counts"])}
    for key in ("height", "base_radius", "angle", "angle_height_base", "central_dip", "weight", "base_load",
                "packing_fraction"):
        if key in measured:
            value = measured[key]
            out[key] = None if value is None else float(value)
    for key in ("surface", "pressure"):
        if key in measured:
            prof = measured[key]
            out[key] = {"r": prof.r.tolist(), "value": [None if not np.isfinite(v) else float(v) for v in prof.value],
                        "width": float(prof.width)}
    return out


PRESSURE_AT = tuple(round(0.05 + 0.1 * k, 2) for k in range(10))
"""r / R where a sweep row reads p(r): the centres of ten rings out to R (the
default rings exactly; other ring counts interpolated), so that heaps of
different R average ring by ring."""

PRESSURE_COLUMNS = tuple(f"pressure_{round(100 * x):02d}" for x in PRESSURE_AT)

ROW_COLUMNS = ("in_play", "lost", "height", "base_radius", "angle", "angle_height_base", "central_dip",
               "packing_fraction", "load_balance") + PRESSURE_COLUMNS
"""The keys of every cone's sweep row (NaN where it cannot be read): `pressure_05` is p at r = 0.05 R."""


def sweep_row(measured: dict) -> dict:
    """A cone's sweep row: its counts, size, angles, dip, the base's load over
    the weight - 1, and p(r) at `PRESSURE_AT` r / R."""
    m = summary(measured)
    row = {"in_play": m["counts"]["in_play"], "lost": m["counts"]["lost"]}
    for key in ROW_COLUMNS[2:ROW_COLUMNS.index("load_balance")]:
        value = m.get(key)
        row[key] = float("nan") if value is None else value
    row["load_balance"] = m["base_load"] / m["weight"] - 1.0 if m.get("weight") else float("nan")
    pressure = measured.get("pressure")
    radius = m.get("base_radius")
    if pressure is None or not radius:
        values = [float("nan")] * len(PRESSURE_AT)
    else:
        values = np.interp(np.asarray(PRESSURE_AT) * radius, pressure.r, pressure.value).tolist()
    row.update(zip(PRESSURE_COLUMNS, (float(v) for v in values)))
    return row
