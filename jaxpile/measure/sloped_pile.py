"""A relaxed sloped pile's base forces against the continuum pile of Liffman,
Chan & Hughes 1992 (eqs. 54-59): the central plateau of N (eq. 56), the linear
central region of H (eq. 57), the whole profile, its mirror symmetry and its
weight balance. `jaxpile.protocols.sloped` builds the pile; this reads it."""

from __future__ import annotations

import math

import numpy as np

from jaxpile.errors import InputError

SQRT3 = math.sqrt(3.0)


def check_alpha(alpha_degrees) -> float:
    alpha = float(alpha_degrees)
    if not 0.0 < alpha < 60.0 + 1e-9:
        raise InputError(
            f"alpha must be in (0, 60] degrees (a close-packed pile cannot be steeper than its "
            f"lattice's 60 deg; 60 is the lattice protocol); got {alpha_degrees!r}.")
    return min(alpha, 60.0)


def check_base(base) -> float:
    b = float(base)
    if not (b > 0 and math.isfinite(b)):
        raise InputError(f"the base B must be a positive, finite number of diameters; got {base!r}.")
    return b


def _slope(x, y) -> float:
    if len(x) < 2:
        return float("nan")
    return float(np.polyfit(x, y, 1)[0])


# the keys of `compare_with_theory`'s dict, in its order (`weight_balance` where it is given `n_particles`)
COMPARED = ("alpha_degrees", "base", "critical_distance", "base_contacts", "central_contacts", "total_normal",
            "total_horizontal", "central_slope_horizontal", "theory_central_slope_horizontal", "central_slope_rel_dev",
            "central_normal_mean", "theory_central_normal", "central_normal_slope", "central_normal_dip", "max_normal",
            "max_dev_normal", "max_dev_horizontal", "asymmetry_normal", "asymmetry_horizontal",
            "central_normal_rel_dev", "weight_balance")


def compare_with_theory(base_forces, alpha_degrees: float, base: float, *, n_particles: int | None = None) -> dict:
    """Base forces of a relaxed sloped pile against eqs. 54-59.

    x is measured from the pile's left foot (x = 0 where it was built), B in
    diameters, line weight chi g = mg / sigma (eq. 60), forces in mg per ground
    disk. The central region is x_c < x < B - x_c.

    Args:
      base_forces: `analysis.BaseForces` (in mg), sorted by x.
      n_particles: disks in the pile, for the weight balance (optional).

    Returns:
      dict of plain numbers:
        `central_slope_horizontal` and `theory_central_slope_horizontal`: dH/dx
        from a least-squares line through the central contacts, and eq. 57's
        sin(a) / (sqrt 3 sin(2 pi/3 - a)); `central_slope_rel_dev` their relative
        difference; `central_normal_mean` against eq. 56's plateau
        (`theory_central_normal`, `central_normal_rel_dev`); `central_normal_slope`
        (0 in theory; a dip would show as curvature, reported as
        `central_normal_dip`: mean of the central region's outer quarters minus
        the middle half, over eq. 56); `max_dev_normal` / `max_dev_horizontal`:
        the largest |simulation - theory| over the whole base, over the theory's
        maximum; `asymmetry_normal`, `asymmetry_horizontal`: largest mirror
        mismatch N(x) - N(B - x) and H(x) + H(B - x) over max |N| and max |H|;
        `total_normal` and (with `n_particles`) `weight_balance` = total / n - 1.
    """
    from jaxpile.measure import theory

    alpha_deg = check_alpha(alpha_degrees)
    alpha = math.radians(alpha_deg)
    base = check_base(base)
    x = np.asarray(base_forces.x, dtype=float)
    normal = np.asarray(base_forces.normal, dtype=float)
    horizontal = np.asarray(base_forces.horizontal, dtype=float)
    n_theory = theory.continuum_ground_normal_force(x, alpha, base)
    h_theory = theory.continuum_ground_horizontal_force(x, alpha, base)
    xc = theory.continuum_critical_distance(alpha, base)
    central = (x > xc) & (x < base - xc)
    plateau = float(theory.continuum_ground_normal_force(0.5 * base, alpha, base))
    slope_theory = math.sin(alpha) / (SQRT3 * math.sin(2.0 * math.pi / 3.0 - alpha))
    slope = _slope(x[central], horizontal[central])
    xs = x[central]
    if len(xs) >= 4:
        half = 0.25 * (xs.max() - xs.min())
        middle = np.abs(xs - 0.5 * base) <= half
        dip = float((normal[central][~middle].mean() - normal[central][middle].mean()) / plateau)
    else:
        dip = float("nan")
    mirrored = len(x) > 0 and np.allclose(x + x[::-1], x[0] + x[-1], atol=0.05)
    h_scale = max(float(np.max(np.abs(horizontal))) if len(x) else 0.0, 1e-300)
    n_scale = max(float(np.max(np.abs(normal))) if len(x) else 0.0, 1e-300)
    out = {
        "alpha_degrees": alpha_deg,
        "base": base,
        "critical_distance": xc,
        "base_contacts": int(len(x)),
        "central_contacts": int(central.sum()),
        "total_normal": float(normal.sum()),
        "total_horizontal": float(horizontal.sum()),
        "central_slope_horizontal": slope,
        "theory_central_slope_horizontal": slope_theory,
        "central_slope_rel_dev": slope / slope_theory - 1.0,
        "central_normal_mean": float(normal[central].mean()) if central.any() else float("nan"),
        "theory_central_normal": plateau,
        "central_normal_slope": _slope(x[central], normal[central]),
        "central_normal_dip": dip,
        "max_normal": float(normal.max()) if len(x) else float("nan"),
        "max_dev_normal": float(np.max(np.abs(normal - n_theory)) / plateau) if len(x) else float("nan"),
        "max_dev_horizontal": (float(np.max(np.abs(horizontal - h_theory)) / np.max(np.abs(h_theory)))
                               if len(x) else float("nan")),
        "asymmetry_normal": float(np.max(np.abs(normal - normal[::-1])) / n_scale) if mirrored else float("nan"),
        "asymmetry_horizontal": (float(np.max(np.abs(horizontal + horizontal[::-1])) / h_scale)
                                 if mirrored else float("nan")),
    }
    out["central_normal_rel_dev"] = out["central_normal_mean"] / plateau - 1.0
    if n_particles is not None:
        out["weight_balance"] = out["total_normal"] / n_particles - 1.0
    return out
