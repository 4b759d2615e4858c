"""A dropped pile's measurements (Liffman, Chan & Hughes 1992, Fig. 20): the
ground's forces, the weight balance, the base normal force binned about the
centre of force with its central dip, the height and the flank angles.
`jaxpile.protocols.drop` builds the pile; this reads it."""

from __future__ import annotations

import numpy as np

from jaxpile.engine.state import SimState
from jaxpile.errors import InputError
from jaxpile.measure.heap import central_dip, normal_profile


def measure(sim, params, state: SimState, *, bins: int = 15, dip_threshold: float = 0.05) -> dict:
    """The drop pile's measurements at `state` (see `run`)."""
    from jaxpile.measure.forces import base_forces
    from jaxpile.measure.surface import repose_angles, surface_profile

    base = base_forces(sim, params, state)
    n_in = int(np.asarray(state.particles.movable).sum())
    out = {
        "base_contacts": int(len(base.x)),
        "total_normal": float(base.normal.sum()),
        "weight_balance": float(base.normal.sum()) / max(n_in, 1) - 1.0,
        "total_horizontal": float(base.horizontal.sum()),
    }
    p = state.particles
    active = np.asarray(p.active)
    pos, radius = np.asarray(p.position), np.asarray(p.radius)
    out["height"] = float(np.max((pos[:, 1] + radius)[active])) if active.any() else 0.0
    try:
        profile = normal_profile(base, bins)
    except InputError:
        profile = None
    if profile is not None:
        dip = central_dip(profile)
        out.update(
            base_width=profile.base,
            centre_x=profile.centre,
            profile_x_over_base=profile.x_over_base.tolist(),
            profile_normal=profile.force.tolist(),
            profile_normalised=profile.normalised.tolist(),
            central_dip=dip,
            has_central_dip=bool(dip > dip_threshold),
        )
    for flank in ("left", "right"):
        try:
            surface = surface_profile(pos, radius, active)
            angle = repose_angles(surface, flank=flank).cumulative_parabola
        except InputError:
            angle = float("nan")
        out[f"repose_angle_{flank}"] = angle
    return out
