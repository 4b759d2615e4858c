"""The measurements of a poured heap (Baxter, Tuzun, Burnell & Heyes 1997):
the forces on the substrate row (the paper's F_B/mg, Figs. 3(b), 5(b), 7), their
binned profile over x/B and its M shape, the flank angles by the three methods
of Lee & Herrmann 1993, the heap's height, base and asymmetry, and its voidage
(Figs. 2, 5, 6, 8). `jaxpile.protocols.pour` builds the heap; these read it."""

from __future__ import annotations

import math

import numpy as np

from jaxpile import budget
from jaxpile.engine.state import SimState
from jaxpile.errors import InputError
from jaxpile.engine.boundaries import GROUND
from jaxpile.measure.forces import SubstrateForces, base_forces, force_unit, substrate_forces
from jaxpile.measure.surface import apex_x, mid_flank_angle, repose_angles, surface_profile, SurfaceProfile
from jaxpile.measure.voidage import packing_fraction, voidage_map, voidage_map_bytes
from jaxpile.measure.heap import (DIP_BINS, base_profile, central_dip, dip_below_flanks, flank_over_centre, m_shape,
                                  steepest_heap_height)

# -------------------------------------------------------------- measurements
def heap_mask(state: SimState) -> np.ndarray:
    """`[n]` bool: the poured disks in play (active and not fixed)."""
    return np.asarray(state.particles.movable)


def floor_forces(sim, params, state: SimState) -> SubstrateForces:
    """The forces the heap stands on: its contacts with the substrate row, or
    with the ground wall on a flat floor (`pour`'s `floor="flat"`; `substrate`
    then -1 and x the disk centre's)."""
    if not bool(np.asarray(state.boundaries.wall_active)[GROUND]):
        return substrate_forces(sim, params, state)
    ground = base_forces(sim, params, state, base="ground")
    return SubstrateForces(x=ground.x, normal=ground.normal, horizontal=ground.horizontal, particle=ground.particle,
                           substrate=np.full(ground.particle.shape, -1))


def _contiguous_columns(profile: SurfaceProfile) -> tuple[float, float]:
    """x range (column centres) of the run of non-empty columns holding the apex."""
    filled = ~np.isnan(profile.height)
    top = int(np.nanargmax(profile.height))
    lo = top
    while lo > 0 and filled[lo - 1]:
        lo -= 1
    hi = top
    while hi < len(filled) - 1 and filled[hi + 1]:
        hi += 1
    return float(profile.x[lo]), float(profile.x[hi])


def measure(sim, params, state: SimState, *, bins: int | None = None, voidage_cell: float = 3.0,
            m_threshold: float = 0.1) -> dict:
    """The 1997 measurements of a poured heap.

    Returns a dict with:
      `counts`: poured, in play (on the substrate), lost (fell off an end), still
        parked, and `strays` (in play but outside the heap's contiguous columns);
      `substrate_forces` (`floor_forces`: the row's, or a flat floor's), `base_profile` (`BaseProfile` over
        the heap's base), `m_shape` (`MShape`), `dip_profile` (the same in
        `heap.DIP_BINS` bins, which `heap.dip_below_flanks` reads; only when
        each bin is at least a substrate spacing wide);
      `weight` (mg, of the disks in play), `substrate_normal_total` (mg) and
        `force_balance` = total / weight - 1 (zero at rest);
      `surface` (`surface.SurfaceProfile` of the disks in play, columns one
        substrate spacing wide centred on the notches of the row), `apex_x`,
        `height` (apex centre height above the substrate's centre line),
        `base_width` B, `angles` {"left", "right"}: `surface.ReposeAngles` of each
        flank (the contiguous columns only), `angle_mid_flank` {"left", "right"}:
        `surface.mid_flank_angle` (the line through the columns between 20% and
        80% of the apex height; None when fewer than 3), `angle_height_base` = atan(2 h / B),
        `asymmetry`: apex and centre-of-mass offsets from the pouring centre;
      `voidage` (`voidage.VoidageMap` over the heap, cells `voidage_cell` sigma)
        and `core_packing_fraction` (a rectangle B/4 wide and h/2 high under the apex).
    """
    ps = state.protocol_state  # a pour.PourState
    p = state.particles
    in_play = heap_mask(state)
    first = int(ps.first)
    poured = int(ps.poured)
    lost = int(np.asarray(ps.lost).sum())
    parked = int((~np.asarray(p.active) & ~np.asarray(p.fixed)).sum()) - lost
    pos, rad = np.asarray(p.position), np.asarray(p.radius)
    base_y = float(pos[0, 1])
    spacing = float(pos[1, 0] - pos[0, 0])
    centre_x = 0.5 * float(pos[first - 1, 0] + pos[0, 0])

    out: dict = {"counts": {"poured": poured, "in_play": int(in_play.sum()), "lost": lost, "parked": parked,
                            "total": int(p.count) - first}}
    forces = floor_forces(sim, params, state)
    unit = force_unit(state)
    weight = float(np.asarray(p.mass)[in_play].sum() * np.linalg.norm(np.asarray(state.boundaries.gravity)) / unit)
    total = float(forces.normal.sum())
    out.update(substrate_forces=forces, weight=weight, substrate_normal_total=total,
               force_balance=total / weight - 1.0 if weight > 0 else float("nan"))
    if not in_play.any():
        return out

    # columns one substrate spacing wide, each centred on a notch of the row: with
    # the mean diameter (Lee & Herrmann's choice) every tenth column of a
    # one-disk-high toe would be empty, as its disks sit in notches S apart
    rows = first
    surface = surface_profile(pos[in_play], rad[in_play], x_min=float(pos[0, 0]),
                                       width=float(pos[rows - 1, 0] - pos[0, 0]), column_width=spacing)
    lo, hi = _contiguous_columns(surface)
    half = 0.5 * surface.column_width
    heap_cols = (pos[in_play, 0] >= lo - half) & (pos[in_play, 0] <= hi + half)
    out["counts"]["strays"] = int((~heap_cols).sum())
    apex = apex_x(surface)
    height = float(np.nanmax(surface.height)) - base_y
    x_left, x_right = lo - half, hi + half
    width = x_right - x_left
    angles = {}
    for flank in ("left", "right"):
        try:
            angles[flank] = repose_angles(surface, flank=flank, x_range=(lo, hi), apex=apex)
        except InputError:
            angles[flank] = None  # fewer than 3 columns on that side
    mid_flank = {flank: mid_flank_angle(surface, flank=flank, base=base_y, apex=apex)
                 for flank in ("left", "right")}
    heap_x = pos[in_play, 0][heap_cols]
    heap_m = np.asarray(p.mass)[in_play][heap_cols]
    out.update(surface=surface, apex_x=apex, height=height, base_width=width, extent=(x_left, x_right),
               angles=angles, angle_mid_flank=mid_flank, angle_height_base=math.degrees(math.atan2(2.0 * height, width)),
               asymmetry={"apex_offset": apex - centre_x,
                          "mass_centre_offset": float(np.sum(heap_m * heap_x) / np.sum(heap_m)) - centre_x})
    if forces.x.size:
        profile = base_profile(forces, extent=(x_left, x_right), bins=bins, spacing=spacing)
        out["base_profile"] = profile
        out["m_shape"] = m_shape(profile, m_threshold)
        if width >= DIP_BINS * spacing:  # narrower bins hold a substrate disk or none: no reading
            out["dip_profile"] = base_profile(forces, extent=(x_left, x_right), bins=DIP_BINS)
    top = float(np.max(pos[in_play, 1] + rad[in_play]))
    region = (x_left, x_right, base_y, top)
    out["voidage"] = voidage_map(pos[in_play], rad[in_play], voidage_cell, region=region)
    core = (apex - width / 8.0, apex + width / 8.0, base_y + 0.5, base_y + 0.5 + max(height / 2.0, 1.0))
    out["core_packing_fraction"] = packing_fraction(pos[in_play], rad[in_play], core)
    return out


def summary(measurements: dict) -> dict:
    """The scalar measurements as plain JSON-friendly numbers (for `summary.json`)."""
    m = measurements
    out = {"counts": dict(m["counts"]), "weight_mg": m["weight"],
           "substrate_normal_total_mg": m["substrate_normal_total"], "force_balance": m["force_balance"]}
    for key in ("apex_x", "height", "base_width", "angle_height_base", "core_packing_fraction"):
        if key in m:
            out[key] = float(m[key])
    if "asymmetry" in m:
        out["asymmetry"] = {k: float(v) for k, v in m["asymmetry"].items()}
    if "angles" in m:
        out["angle_of_repose"] = {
            flank: None if a is None else {"endpoints": a.endpoints, "least_squares": a.least_squares,
                                           "cumulative_parabola": a.cumulative_parabola}
            for flank, a in m["angles"].items()}
        out["angle_mid_flank"] = dict(m["angle_mid_flank"])
    if "m_shape" in m:
        out["m_shape"] = {k: (bool(v) if isinstance(v, (bool, np.bool_)) else float(v))
                          for k, v in m["m_shape"]._asdict().items()}
    if "dip_profile" in m:
        out["dip_below_flanks"] = dip_below_flanks(m["dip_profile"])
    if "base_profile" in m:
        prof = m["base_profile"]
        out["base_profile"] = {"x_over_b": prof.x_over_b.tolist(), "normalised": prof.normalised.tolist(),
                               "force_mg": prof.force.tolist(), "width": prof.width}
    return out


ROW_COLUMNS = ("in_play", "lost", "force_balance", "height", "base_width", "angle_height_base",
               "core_packing_fraction", "repose_left", "repose_right", "repose_mean", "m_ratio", "central_dip",
               "flank_over_centre", "dip_below_flanks", "m_shaped")
"""The keys of every `sweep_row`, whatever the heap (NaN where it cannot be read)."""


def sweep_row(full: dict) -> dict:
    """A poured heap's sweep row (from `measure`'s dict): the flank angles,
    the height and base, the M ratio, the central dip, the dip below the
    flanks and the force balance."""
    m = summary(full)
    out = {"in_play": m["counts"]["in_play"], "lost": m["counts"]["lost"], "force_balance": m["force_balance"]}
    for key in ("height", "base_width", "angle_height_base", "core_packing_fraction"):
        out[key] = m.get(key, float("nan"))
    for flank in ("left", "right"):
        a = (m.get("angle_of_repose") or {}).get(flank) or {}
        out[f"repose_{flank}"] = a.get("cumulative_parabola", float("nan"))
    out["repose_mean"] = 0.5 * (out["repose_left"] + out["repose_right"])
    ms = m.get("m_shape") or {}
    out["m_ratio"] = ms.get("ratio", float("nan"))
    # the drop's dip (1992 Fig. 20, Smid-Novosad's 0.2-0.3): 1 - centre over the lower flank maximum
    profile = full.get("base_profile")
    out["central_dip"] = float("nan") if profile is None else central_dip(profile)
    out["flank_over_centre"] = float("nan") if profile is None else flank_over_centre(profile)
    out["dip_below_flanks"] = m.get("dip_below_flanks", float("nan"))  # Smid-Novosad's dip, windows fixed
    out["m_shaped"] = bool(ms.get("m_shaped", False))
    return out


def check_options(options, *, n_substrate: int, substrate_length: float, n_poured: int) -> None:
    """Refuses, before a pour is built, more profile bins than substrate disks
    (a bin narrower than a substrate spacing holds no contact) and a voidage
    map whose cells are too fine for this machine's memory (the map covers at
    most the substrate row and the steepest heap of the disks poured);
    `options` are the pour's (`PourOptions`)."""
    bins, cell = options.bins, options.voidage_cell
    if bins is not None and bins > n_substrate:
        raise InputError(f"bins ({bins:g}) must be at most the substrate's {n_substrate} disks: a bin "
                         "narrower than a substrate spacing holds no contact.")
    width, height = substrate_length, steepest_heap_height(n_poured) + 2.0
    need = voidage_map_bytes(width, height, cell, n_poured, 0.5)
    budget.check_host(need, f"the voidage map (voidage_cell = {cell:g} sigma over up to "
                            f"{width:.0f} x {height:.0f} sigma)", "Give a larger voidage_cell (the default is 3).")
