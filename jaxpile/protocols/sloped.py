"""The 1992 close-packed pile of any slope (Liffman, Chan & Hughes, Figs. 12-16).

Equal disks in hexagonal close packing fill an isosceles triangle of base B and
side angle alpha < 60 deg standing on the ground ("Because the pile is made of
discrete particles, the sides are composed of a number of sloping steps",
Fig. 12). Row j (0 at the bottom) is the strip j sqrt(3)/2 <= y <= (j + 1) sqrt(3)/2
of the lattice; it holds the whole number of disks n_j closest to the width of the
triangle at the strip's mid-height, w_j = B - (2j + 1) sqrt(3) / (2 tan alpha),
centred on the pile's axis. Adjacent rows differ by an odd number of disks, which
keeps them on one hexagonal lattice, so every row is the one below shortened at
both ends (by 1.5 disks per side per row at 30 deg) and the row ends follow the
slope. The rows' cells (area sqrt(3)/2 each) then cover the triangle's area
B^2 tan(alpha) / 4 to within the stepped edges, which is the pile the continuum
theory (eqs. 49-59) describes: the left foot is at x = 0, the right at x = B.
With alpha = 60 deg and B = k + 1 the rows are k, k - 1, ..., 1: the lattice pile.
With `top_alpha_degrees` and `knee` the surface is the 'tent' of Figs. 18-19:
alpha up to the knees at X_1 = knee B from each foot, alpha2 above them.

The pile is loaded by a gravity ramp and relaxed to rest as the lattice protocol
does (`loaded_pile.relax`), with the same per-law setting (`paper1992.PAPER_SETTING`:
hooke with frictionless disks, mu = 0, on a frictional ground, wall_mu = 1, is
the paper's analytic assumption). Its base forces are compared with eqs. 54-59,
in particular the slope dH/dx of eq. 57 between x_c and B - x_c.

Paper sizes (`PAPER_PILES`): alpha = 30, 45, 50, 55 deg with about 360 disks
(Figs. 13-14) and 30 deg with 5490 disks (Fig. 15); `base_for_count` picks B.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from jaxpile import budget
from jaxpile.engine.boundaries import make_boundaries
from jaxpile.engine.state import Boundaries, Particles, make_particles
from jaxpile.errors import InputError

# the comparison with eqs. 54-59 (`jaxpile.measure.sloped_pile`), also under its name here (`sloped.compare_with_theory`)
from jaxpile.measure.sloped_pile import check_alpha, check_base, compare_with_theory
from jaxpile.protocols import loaded_pile, paper1992
from jaxpile.protocols.base import Setting, Setup
from jaxpile.protocols.spec import Options, option
from jaxpile.ranges import DISKS, SIZE, SPEED, STEPS, Range

SQRT3 = math.sqrt(3.0)

# (alpha in degrees, disks) of the paper's piles: Figs. 12-14 and Fig. 15
PAPER_PILES = ((30.0, 360), (45.0, 360), (50.0, 360), (55.0, 360), (30.0, 5490))

# The lattice protocol's loading and per-law parameters (Liffman et al. 1992,
# eq. 46: mg / (k sigma) = 1e-4; frictionless disks on a frictional ground for
# hooke and lee-herrmann, the analytic model's assumptions); the pile is given by
# its slope and size instead of a number of layers.
SETTING = {
    **{k: v for k, v in paper1992.PAPER_SETTING.items() if k != "layers"},
    "alpha_degrees": 30.0,
    "n": 360,
}


@dataclass(frozen=True)
class SlopedOptions(Options):
    """The sloped pile's options: its slope and size, and the run that loads it
    and brings it to rest (`loaded_pile.relax`)."""

    alpha_degrees: float = option(SETTING["alpha_degrees"], range=Range(
        low=1, high=60, why="degrees; 60 is the lattice pile, below 1 a pile is one row"),
        help="alpha, the side angle (60 gives the lattice pile)")
    n: int | None = option(SETTING["n"], range=DISKS, help="target number of disks; B is chosen by base_for_count "
                           "(not used when base is given)")
    base: float | None = option(None, range=SIZE, help="B, the base in diameters (overrides n)")
    ramp_steps: int = option(SETTING["ramp_steps"], range=STEPS, help="steps of the gravity ramp that loads the pile")
    speed_tolerance: float = option(SETTING["speed_tolerance"], range=SPEED,
                                    help="at rest when the fastest disk is below this speed")
    max_steps: int = option(SETTING["max_steps"], range=STEPS, help="give up after this many steps, ramp included")
    hard_collisions: object = option(None, help="the Simulator's hard collisions (a HardCollisions), or None")
    top_alpha_degrees: float | None = option(None, range=Range(low=1, high=60, why="degrees, as alpha"),
                                             help="a tent pile (Figs. 18-19): alpha2, the slope above the knees "
                                                  "(with knee; alpha is the slope below them)")
    knee: float | None = option(None, range=Range(low=0, high=0.5, low_open=True, why="X_1 / B: a knee in each half"),
                                help="a tent pile: X_1 / B, the knees' distance from each foot over the base")

    def validate(self) -> None:
        if (self.top_alpha_degrees is None) != (self.knee is None):
            raise InputError("a tent pile takes top_alpha_degrees and knee together (Fig. 18: alpha2 above the "
                             "knees at X_1 = knee B); give both or neither.")

    @property
    def top(self) -> tuple[float, float] | None:
        """`(alpha2 in degrees, X_1 / B)` of a tent pile, or None."""
        return None if self.knee is None else (float(self.top_alpha_degrees), float(self.knee))


def tent_width(base: float, alpha_degrees: float, top: tuple[float, float], y: float) -> float:
    """The width at height `y` of the tent pile of Fig. 18: slope alpha from
    each foot up to the knees at X_1 = knee B, then alpha2 (`top = (alpha2
    in degrees, knee)`), as `theory.tent_height` draws it."""
    alpha1, alpha2 = math.radians(check_alpha(alpha_degrees)), math.radians(check_alpha(top[0]))
    knee = top[1] * base
    rise = knee * math.tan(alpha1)  # the knees' height
    if y <= rise:
        return base - 2.0 * y / math.tan(alpha1)
    return base - 2.0 * knee - 2.0 * (y - rise) / math.tan(alpha2)


def row_lengths(base: float, alpha_degrees: float, top: tuple[float, float] | None = None) -> list[int]:
    """Disks per row, bottom row first, of the pile of base `base` (diameters)
    and slope `alpha_degrees` (a tent's: `top = (alpha2 in degrees, knee)`,
    alpha2 above the knees at X_1 = knee B, Fig. 18).

    Row j holds the count closest to w_j = B - (2j + 1) sqrt(3) / (2 tan alpha)
    (the tent's width at the row's mid-height; ties rounded down) whose parity
    differs from row j - 1's, and at most one fewer than row j - 1. Rows stop
    at the first that would be empty.
    """
    alpha = math.radians(check_alpha(alpha_degrees))
    base = check_base(base)
    per_row = SQRT3 / math.tan(alpha)  # width lost per row (both ends together)
    rows: list[int] = []
    j = 0
    while True:
        width = base - (j + 0.5) * per_row if top is None else tent_width(base, alpha_degrees, top,
                                                                           (j + 0.5) * SQRT3 / 2.0)
        if j == 0:
            count = math.ceil(width - 0.5 - 1e-9)
        else:
            parity = (rows[-1] - 1) % 2
            count = parity + 2 * math.ceil((width - parity) / 2.0 - 0.5 - 1e-9)
            count = min(count, rows[-1] - 1)
        if count < 1:
            return rows
        rows.append(int(count))
        j += 1


def pile_count(base: float, alpha_degrees: float, top: tuple[float, float] | None = None) -> int:
    """Number of disks in the pile of base `base` and slope `alpha_degrees` (a tent's with `top`)."""
    return sum(row_lengths(base, alpha_degrees, top))


def base_for_count(n: int, alpha_degrees: float, top: tuple[float, float] | None = None) -> float:
    """The base B (diameters) whose pile holds the disk count closest to `n`.

    B^2 tan(alpha) / (2 sqrt 3) disks fill the continuum triangle (area
    B^2 tan(alpha) / 4, sqrt(3)/2 per disk); B is searched on a 0.01 grid around
    that estimate, ties going to the B nearest the estimate. E.g. 360 disks:
    B = 46.5 at 30 deg, 29.5 at 55 deg; 5490 disks at 30 deg: B = 181.5. A
    tent (`top`) is searched around the same estimate.
    """
    if int(n) != n or n < 1:
        raise InputError(f"the disk count must be a positive whole number; got {n!r}.")
    alpha = math.radians(check_alpha(alpha_degrees))
    estimate = math.sqrt(2.0 * SQRT3 * n / math.tan(alpha))
    best = None
    for spread in (0.02, 0.2):  # the estimate is good to ~1%; widen only if no exact hit
        half = spread * estimate + 2.0
        grid = np.round(np.arange(max(1.0, estimate - half), estimate + half, 0.01), 2)
        counts = np.array([pile_count(b, alpha_degrees, top) for b in grid])
        score = np.abs(counts - n) * 1e3 + np.abs(grid - estimate)
        best = float(grid[int(np.argmin(score))])
        if counts.min() <= n <= counts.max() and np.any(counts == n):
            break
    return best


def sloped_positions(base: float, alpha_degrees: float, diameter: float = 1.0,
                     top: tuple[float, float] | None = None) -> np.ndarray:
    """`[n, 2]` centres of the pile standing on y = 0 with its left foot at x = 0,
    bottom row first, left to right. Neighbours touch (no overlap, no gap).
    `base` is in diameters; positions are in length units (times `diameter`);
    `top`: a tent's (`row_lengths`)."""
    if not (diameter > 0 and math.isfinite(diameter)):
        raise InputError(f"diameter must be positive and finite; got {diameter!r}.")
    rows = row_lengths(base, alpha_degrees, top)
    if not rows:
        raise InputError(f"a pile of base {base!r} diameters at {alpha_degrees!r} deg holds no disk; "
                         "use a larger base.")
    out = []
    for j, count in enumerate(rows):
        x = 0.5 * base + np.arange(count) - 0.5 * (count - 1)
        y = np.full(count, 0.5 + j * SQRT3 / 2.0)
        out.append(np.stack([x, y], axis=1))
    return np.concatenate(out, axis=0) * diameter


def sloped_pile(base: float, alpha_degrees: float, *, diameter: float = 1.0, mass: float = 1.0,
                dtype=None, top: tuple[float, float] | None = None) -> tuple[Particles, Boundaries]:
    """Particles and boundaries (ground only, side walls off) of the pile (a tent's with `top`)."""
    position = sloped_positions(base, alpha_degrees, diameter, top)
    particles = make_particles(position, 0.5 * diameter, mass=mass, dtype=dtype)
    return particles, make_boundaries(dtype=particles.position.dtype)


def setup(o: SlopedOptions, *, law, seed: int, dt: float, dtype=None) -> Setup:
    """The sloped pile of Liffman et al. 1992, Figs. 12-16, ready to run: B from
    `o.base`, or `base_for_count(o.n, alpha)`. The pile is deterministic
    (`seed` is not used); the gravity ramp is the simulator's.

    Returns:
      `Setup` with no schedule and no driver; `info` holds the slope, B, the
      row lengths, the disk count, x_c (eq. 49's text) and dt.
    """
    from jaxpile.measure import theory

    alpha, base, top = check_alpha(o.alpha_degrees), o.base, o.top
    if base is None:
        budget.check(o.n, dtype or "float64", what="a sloped pile")  # the search for B is slow for a count far too big
        base = base_for_count(o.n, alpha, top)
    base = check_base(base)
    # counting the rows takes time and memory in B: refuse a base far too big from the
    # continuum count first (within ~1% of the lattice's; a tent's at its steeper slope), then the exact count
    steepest = alpha if top is None else max(alpha, top[0])
    budget.check(math.ceil(base * base * math.tan(math.radians(steepest)) / (2.0 * SQRT3)), dtype or "float64",
                 what="a sloped pile")
    budget.check(pile_count(base, alpha, top), dtype or "float64", what="a sloped pile")
    particles, boundaries = sloped_pile(base, alpha, dtype=dtype, top=top)
    rows = row_lengths(base, alpha, top)
    info = {
        "alpha_degrees": alpha,
        **({} if top is None else {"top_alpha_degrees": top[0], "knee": top[1]}),
        "base": base,
        "rows": rows,
        "n_particles": int(particles.count),
        "critical_distance": theory.continuum_critical_distance(math.radians(alpha), base),
        "dt": float(dt),
    }
    return Setup(particles=particles, boundaries=boundaries, info=info)


LAW_SETTING = Setting(law="hooke", params=SETTING["params"], dt=SETTING["dt"], rotation=SETTING["rotation"])
"""The sloped pile's laws: the 1992 setting."""
law_and_params = LAW_SETTING.law_and_params


def _compare(sim, params, state, p) -> dict:
    from jaxpile.measure import analysis

    n_in = int(np.asarray(state.particles.active).sum())
    return {**compare_with_theory(analysis.base_forces(sim, params, state), p.info["alpha_degrees"],
                                  p.info["base"], n_particles=n_in), "law": sim.law.name}


SPEC = loaded_pile.spec_of(
    "sloped", options=SlopedOptions, setting=LAW_SETTING, setup=setup, compare=_compare)
"""The sloped pile (Liffman et al. 1992, Figs. 12-16): `SPEC.run("hooke", 40, alpha_degrees=30.0,
ramp_steps=2000)` builds the pile of about 40 disks, loads and relaxes it, and compares its base forces with
eqs. 54-59 (`m["central_slope_horizontal"]` against `m["theory_central_slope_horizontal"]`)."""


__all__ = ["PAPER_PILES", "SETTING", "SPEC", "SlopedOptions", "base_for_count", "compare_with_theory",
           "law_and_params", "pile_count", "row_lengths", "setup", "sloped_pile", "sloped_positions", "tent_width"]
