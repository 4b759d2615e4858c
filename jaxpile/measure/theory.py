"""The papers' analytic models.

Liffman, Chan & Hughes 1992, "A close packed equilateral sandpile - analytic
model": hard, equal disks on a lattice (Fig. 5) carrying force only along the two
lattice diagonals at angle theta to the vertical (theta = pi/6 for close packing).

Liffman, Chan & Hughes 1992, "A close packed sandpile with arbitrary slope -
theory" (eqs. 49-59, Fig. 11): the continuum limit of that lattice. A pile of base
B and slope alpha <= pi/3 stands on the ground from x = 0 to x = B (the paper's
origin is the left foot); the weight travels down straight lines at 2 pi/3 (l_1,
up-left from the ground point x) and pi/3 (l_2, up-right) to the horizontal, and
a line of length l carries chi g l / sqrt(3), chi being the mass per length of a
line (eq. 60: chi = m / sigma). The same construction under any surface gives
the 'tent' piles of Figs. 18-19, whose line lengths are found numerically.

Lee & Herrmann 1993, sec. 6: that construction plus the Coulomb criterion at the
base gives the angle of marginal stability (eq. 3) and the tilting angle (eq. 4).

All angles are in radians. Forces are per ground disk: N(x) / sigma is the force
per unit length of base.
"""

from __future__ import annotations

import math
from typing import Callable

import numpy as np

from jaxpile.errors import InputError

SQRT3 = math.sqrt(3.0)


def lattice_diagonal_forces(x, y, theta: float = math.pi / 6, mg: float = 1.0):
    """Eqs. 40-41: forces along the left and right diagonals at lattice point (x, y),
    L(x, y) = W y / 2 and R(x, y) = W x / 2 with W = mg / cos(theta) (eq. 38)."""
    w = mg / math.cos(theta)
    return w * np.asarray(y) / 2.0, w * np.asarray(x) / 2.0


def lattice_ground_normal_force(layers: int, mg: float = 1.0) -> float:
    """Eq. 42: every ground disk of a k-layer pile carries N = (k + 1) mg / 2."""
    return (layers + 1) * mg / 2.0


def lattice_ground_horizontal_force(layers: int, i=None, theta: float = math.pi / 6, mg: float = 1.0):
    """Eqs. 43-44: the horizontal force ground disk i (1..k, left to right) exerts
    on the ground, H = mg tan(theta) (2i - k - 1) / 2; for theta = pi/6 this is
    H = mg (2i - k - 1) / (2 sqrt 3). Negative on the left half: the pile pushes
    the ground outwards. `i=None` returns all k values."""
    i = np.arange(1, layers + 1) if i is None else np.asarray(i)
    return mg * math.tan(theta) * (2 * i - layers - 1) / 2.0


def lattice_ground_friction_needed(layers: int) -> float:
    """The largest |H| / N over the base, (k - 1) / (sqrt(3) (k + 1)): the ground
    friction coefficient a static pile needs (from eqs. 42 and 44)."""
    return (layers - 1) / (math.sqrt(3.0) * (layers + 1))


# --- Liffman, Chan & Hughes 1992, continuum pile (eqs. 49-59) -----------------

def _check_pile(alpha: float, base: float, name: str = "alpha") -> float:
    """alpha clipped to pi/3 (so that radians(60) passes); InputError when the
    continuum model does not apply (it needs 0 < alpha <= pi/3, base > 0)."""
    if not 0.0 < alpha <= math.pi / 3 + 1e-12:
        raise InputError(f"{name} must be in (0, pi/3] radians (the force lines are at pi/3 to the "
                         f"ground and must leave through the slope); got {alpha!r}.")
    if not 0.0 < base < math.inf:
        raise InputError(f"base must be positive and finite; got {base!r}.")
    return min(alpha, math.pi / 3)


def continuum_critical_distance(alpha: float, base: float) -> float:
    """x_c = h (cot alpha - 1/sqrt 3), h = (B/2) tan alpha (text above eq. 49): the
    ground point whose pi/3 line l_2 ends at the apex. Computed as the equal
    B sin(pi/3 - alpha) / (sqrt(3) cos alpha), exactly 0 at alpha = pi/3."""
    alpha = _check_pile(alpha, base)
    return base * math.sin(math.pi / 3 - alpha) / (SQRT3 * math.cos(alpha))


def continuum_diagonal_lengths(x, alpha: float, base: float):
    """Eqs. 49-51: lengths `(l1, l2)` (shape of `x`) of the force lines from the
    ground point x (0 <= x <= B) up to the surface of the triangular pile.

    l_1 (up-left, 2 pi/3 to the ground) = x sin(alpha) / sin(2 pi/3 - alpha)  (49)
    for x <= B - x_c; l_2 (up-right, pi/3) = x sin(alpha) / sin(pi/3 - alpha) (50)
    for x <= x_c and (B - x) sin(alpha) / sin(2 pi/3 - alpha) (51) beyond, where
    it meets the far slope. For x > B - x_c, l_1 meets the far slope: eq. 50 with
    x -> B - x, by the pile's mirror symmetry. Zero outside [0, B]."""
    alpha = _check_pile(alpha, base)
    x = np.asarray(x, dtype=float)
    xc = continuum_critical_distance(alpha, base)
    s_obtuse = math.sin(2 * math.pi / 3 - alpha)
    s_acute = math.sin(math.pi / 3 - alpha)
    inv_acute = 1.0 / s_acute if s_acute > 0 else 0.0  # its region is {0, B} at pi/3
    sa = math.sin(alpha)
    l1 = np.where(x <= base - xc, x * sa / s_obtuse, (base - x) * sa * inv_acute)
    l2 = np.where(x <= xc, x * sa * inv_acute, (base - x) * sa / s_obtuse)
    inside = (x >= 0) & (x <= base)
    return np.where(inside, l1, 0.0), np.where(inside, l2, 0.0)


def diagonal_ground_forces(l1, l2, line_weight: float = 1.0):
    """Eqs. 52-53: `(N, H)` at a ground point from its two force-line lengths.

    N = chi g (l_1 + l_2) / 2 is the ground's normal force on the pile (52) and
    H = chi g (l_1 - l_2) / (2 sqrt 3) the horizontal force of the pile on the
    ground (53), positive to the right. `line_weight` is chi g, the weight per
    length of a line (eq. 60: chi = m / sigma, so chi g = mg / sigma). A line
    carries chi g l / (2 cos(pi/6)) = chi g l / sqrt 3, eq. 40's W y / 2 with
    theta = pi/6 from the vertical (the paper's "theta = pi/3" is the angle to
    the horizontal)."""
    l1, l2 = np.asarray(l1, dtype=float), np.asarray(l2, dtype=float)
    return line_weight * (l1 + l2) / 2.0, line_weight * (l1 - l2) / (2.0 * SQRT3)


def continuum_ground_normal_force(x, alpha: float, base: float, line_weight: float = 1.0):
    """Eqs. 54, 56, 58: normal force N(x) of the ground on a pile of slope alpha
    (radians, 0 < alpha <= pi/3) and base B, at ground points `x` (any shape;
    origin at the left foot, N = 0 outside [0, B]). `line_weight` = chi g.

    N = sqrt(3) x chi g sin(a) cos(a) / (2 sin(2pi/3 - a) sin(pi/3 - a))  x <= x_c   (54)
    N = chi g B sin(a) / (2 sin(2pi/3 - a))                    x_c < x < B - x_c    (56)
    N = eq. 54 with x -> B - x                                  x >= B - x_c        (58)

    The profile integrates to chi g B h / sqrt 3, h = (B/2) tan(a): sigma times the
    pile's weight for close-packed disks (2 / (sqrt(3) sigma^2) per area). At
    alpha = pi/3, x_c = 0 and N = chi g B / 2 everywhere: eq. 42 with B = (k+1) sigma."""
    alpha = _check_pile(alpha, base)
    x = np.asarray(x, dtype=float)
    xc = continuum_critical_distance(alpha, base)
    s_obtuse = math.sin(2 * math.pi / 3 - alpha)
    s_acute = math.sin(math.pi / 3 - alpha)
    flank = (SQRT3 * line_weight * math.sin(alpha) * math.cos(alpha) / (2.0 * s_obtuse * s_acute)
             if s_acute > 0 else 0.0)
    middle = line_weight * base * math.sin(alpha) / (2.0 * s_obtuse)
    n = np.where(x <= xc, flank * x, np.where(x >= base - xc, flank * (base - x), middle))
    return np.where((x >= 0) & (x <= base), n, 0.0)


def continuum_ground_horizontal_force(x, alpha: float, base: float, line_weight: float = 1.0):
    """Eqs. 55, 57, 59: horizontal force H(x) the pile exerts on the ground
    (positive to the right, so negative on the left half), arguments as in
    `continuum_ground_normal_force`.

    H = -x chi g sin^2(a) / (2 sqrt(3) sin(2pi/3 - a) sin(pi/3 - a))  x <= x_c        (55)
    H = chi g (x - B/2) sin(a) / (sqrt(3) sin(2pi/3 - a))            x_c < x < B - x_c (57)
    H = (B - x) chi g sin^2(a) / (2 sqrt(3) sin(2pi/3 - a) sin(pi/3 - a))  x >= B - x_c (59)

    |H| / N = tan(alpha) / 3 on the flanks, the largest over the base (Lee &
    Herrmann's eq. 3). At alpha = pi/3, H = chi g (x - B/2) / sqrt 3: eq. 44 with
    x = i sigma, B = (k + 1) sigma."""
    alpha = _check_pile(alpha, base)
    x = np.asarray(x, dtype=float)
    xc = continuum_critical_distance(alpha, base)
    s_obtuse = math.sin(2 * math.pi / 3 - alpha)
    s_acute = math.sin(math.pi / 3 - alpha)
    flank = (line_weight * math.sin(alpha) ** 2 / (2.0 * SQRT3 * s_obtuse * s_acute)
             if s_acute > 0 else 0.0)
    middle = line_weight * (x - base / 2.0) * math.sin(alpha) / (SQRT3 * s_obtuse)
    h = np.where(x <= xc, -flank * x, np.where(x >= base - xc, flank * (base - x), middle))
    return np.where((x >= 0) & (x <= base), h, 0.0)


# --- The same construction under any surface: 'tent' piles (Figs. 18-19) -------

def surface_diagonal_lengths(x, surface: Callable, max_height: float, iterations: int = 60):
    """`(l1, l2)` (shape of `x`): lengths of the force lines from ground points `x`
    at 2 pi/3 (l_1) and pi/3 (l_2) to the horizontal, up to where they leave the
    pile y = surface(x), found by bisection (Liffman et al. 1992, text below Fig. 18).

    `surface` is a vectorised height function, <= 0 off the pile, <= max_height,
    with slopes of magnitude <= sqrt 3 (pi/3) so that each line leaves it once.
    Lengths are 0 where surface(x) <= 0. Feed them to `diagonal_ground_forces`."""
    x = np.asarray(x, dtype=float)
    under = surface(x) > 0

    def length(direction):  # direction = -1 (up-left, l_1) or +1 (up-right, l_2)
        lo = np.zeros_like(x)
        hi = np.full_like(x, 2.0 * max_height / SQRT3 * (1.0 + 1e-9))
        for _ in range(iterations):  # invariant: the line is inside at lo, outside at hi
            mid = 0.5 * (lo + hi)
            inside = surface(x + 0.5 * direction * mid) > 0.5 * SQRT3 * mid
            lo, hi = np.where(inside, mid, lo), np.where(inside, hi, mid)
        return np.where(under, 0.5 * (lo + hi), 0.0)

    return length(-1.0), length(1.0)


def _check_tent(alpha1: float, alpha2: float, knee: float, base: float) -> tuple[float, float]:
    alpha1 = _check_pile(alpha1, base, "alpha1")
    alpha2 = _check_pile(alpha2, base, "alpha2")
    if not 0.0 <= knee <= base / 2:
        raise InputError(f"knee (X_1) must be in [0, base/2] = [0, {base / 2!r}]; got {knee!r}.")
    return alpha1, alpha2


def tent_height(x, alpha1: float, alpha2: float, knee: float, base: float):
    """The 'tent' pile of Fig. 18: slope alpha1 from each foot (x = 0, B) up to the
    knees at x = X_1 and B - X_1 (`knee`), then alpha2 up to the apex at B/2.
    Fig. 18(a) alpha1 > alpha2 (flattened top); (b) alpha2 > alpha1 (peaked top)
    (the text's "angles shown in Fig. 13" and peaked "Fig. 18(a)" mean Fig. 18, 18(b)).
    Radians; 0 < alpha1, alpha2 <= pi/3, 0 <= X_1 <= B/2. Zero outside [0, B]."""
    alpha1, alpha2 = _check_tent(alpha1, alpha2, knee, base)
    x = np.asarray(x, dtype=float)
    d = np.minimum(x, base - x)  # distance from the nearer foot
    y = np.where(d <= knee, d * math.tan(alpha1), knee * math.tan(alpha1) + (d - knee) * math.tan(alpha2))
    return np.where(d >= 0, y, 0.0)


def tent_ground_forces(x, alpha1: float, alpha2: float, knee: float, base: float, line_weight: float = 1.0):
    """`(N, H)` under the 'tent' pile of Figs. 18-19 (see `tent_height`): eqs. 52-53
    with l_1, l_2 found numerically, as the paper does. alpha1 = alpha2 gives eqs.
    54-59; Fig. 19 is alpha1 = 30 deg, alpha2 = 45 deg, X_1 = 0.38 B (a central dip)."""
    alpha1, alpha2 = _check_tent(alpha1, alpha2, knee, base)
    top = knee * math.tan(alpha1) + (base / 2 - knee) * math.tan(alpha2)
    l1, l2 = surface_diagonal_lengths(x, lambda s: tent_height(s, alpha1, alpha2, knee, base), top)
    return diagonal_ground_forces(l1, l2, line_weight)


# --- Lee & Herrmann 1993, sec. 6 ------------------------------------------------

def _check_mu(mu) -> np.ndarray:
    mu = np.asarray(mu, dtype=float)
    if not np.all(mu >= 0):  # also catches NaN
        raise InputError(f"mu must be >= 0 (a Coulomb friction coefficient); got {mu!r}.")
    return mu


def marginal_stability_angle(mu):
    """Eq. 3: theta_MS = arctan(3 mu) (radians), the steepest pile whose base
    contacts all satisfy Coulomb's |H| <= mu N under Liffman et al.'s lines
    (|H| / N = tan(alpha) / 3 on the flanks, eqs. 54-55). Above mu = 1/sqrt 3 this
    exceeds pi/3, where that construction no longer covers the pile."""
    return np.arctan(3.0 * _check_mu(mu))


def tilting_angle(theta_r: float, mu: float) -> float:
    """Eq. 4: the tilt theta_T (radians) that makes a pile of repose angle theta_R
    (radians) fail at its base, for friction coefficient mu:

      mu = (R cos(pi/3 - T) - cos(pi/3 + T)) / (R sin(pi/3 - T) + sin(pi/3 + T))  (4a)
      R = (tan(pi/3 + T) + tan(theta_R)) cos(pi/3 + T)
          / ((tan(pi/3 - T) - tan(theta_R)) cos(pi/3 - T))                      (4b)
        = sin(pi/3 + theta_R + T) / sin(pi/3 - theta_R - T),

    T = theta_T. R is l_A / l_B at a base point near the foot: the line at pi/3 - T
    to the tilted base over the one at pi/3 + T. (4b is printed without the
    brackets around the sums; read literally it gives theta_MS = arctan(6 mu) at
    T = 0, against eq. 3.) With mu = tan(lambda), eq. 4 is
    sin(theta_R + 2T - lambda) = sin(theta_R + lambda) / 2, whose smallest root
    is taken in closed form.

    Raises InputError for mu < 0, theta_R outside (0, pi/2), theta_R above
    theta_MS = arctan(3 mu) (the pile already fails: no tilt >= 0 solves eq. 4),
    and when the tilted slope theta_R + theta_T would reach pi/3 (R -> infinity:
    the lines no longer meet the slope, the model has no answer)."""
    mu = float(_check_mu(mu))
    if not 0.0 < theta_r < math.pi / 2:
        raise InputError(f"theta_r must be in (0, pi/2) radians; got {theta_r!r}.")
    theta_ms = float(marginal_stability_angle(mu))
    if theta_r > theta_ms + 1e-12:
        raise InputError(f"theta_r = {theta_r!r} exceeds theta_MS = arctan(3 mu) = {theta_ms!r} for "
                         f"mu = {mu!r}: the pile is already unstable, no tilt >= 0 solves eq. 4.")
    friction_angle = math.atan(mu)
    theta_t = max(0.5 * (friction_angle + math.asin(0.5 * math.sin(theta_r + friction_angle)) - theta_r), 0.0)
    if theta_r + theta_t >= math.pi / 3:
        raise InputError(f"for theta_r = {theta_r!r}, mu = {mu!r} the tilted slope theta_r + theta_T "
                         f"= {theta_r + theta_t!r} reaches pi/3, where eq. 4b's lines no longer meet the "
                         "slope; use mu < 1/sqrt(3) or a smaller theta_r.")
    return theta_t


def marginal_stability_overlay(name, values):
    """The sweep figure's overlay against mu: theta_MS = arctan(3 mu) (1993 eq. 3)."""
    if name != "mu":
        return None
    return "theta_MS = arctan(3 mu) (1993 eq. 3)", np.degrees(marginal_stability_angle(np.asarray(values)))
