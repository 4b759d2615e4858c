"""The 1992 equilateral close-packed pile (Liffman, Chan & Hughes, Fig. 7).

k layers of equal disks in hexagonal close packing standing on the flat ground:
layer j (0 at the bottom) holds k - j disks, so the pile has k(k+1)/2 disks
(k = 45: 1035) and its sides slope at 60 degrees. The pile is loaded by a
gravity ramp and run to rest (`loaded_pile`); its ground forces are compared
with eqs. 42 and 44 (Figs. 8-9).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from jaxpile import budget
from jaxpile.engine.boundaries import make_boundaries
from jaxpile.engine.state import Boundaries, Particles, make_particles
from jaxpile.errors import InputError
from jaxpile.protocols import loaded_pile
from jaxpile.protocols.base import Setting, Setup
from jaxpile.protocols.paper1992 import PAPER_SETTING
from jaxpile.protocols.spec import Options, option
from jaxpile.ranges import SIZE, SPEED, STEPS, Range


@dataclass(frozen=True)
class LatticeOptions(Options):
    """The lattice pile's options: its geometry, and the run that loads it and
    brings it to rest (`loaded_pile.relax`)."""

    layers: int = option(PAPER_SETTING["layers"], range=Range(low=1, whole=True, unit="layers"),
                         help="k, the pile's layers (k(k+1)/2 disks)")
    diameter: float = option(1.0, range=SIZE, help="the disks' diameter")
    mass: float = option(1.0, range=SIZE, help="each disk's mass")
    gap: float = option(0.0, range=Range(low=0, high=0.1, high_open=True, why="diameters"),
                        help="horizontal gap between neighbours on one level, in diameters")
    ramp_steps: int = option(PAPER_SETTING["ramp_steps"], range=STEPS, help="steps of the gravity ramp that loads the pile")
    speed_tolerance: float = option(PAPER_SETTING["speed_tolerance"], range=SPEED,
                                    help="at rest when the fastest disk is below this speed")
    max_steps: int = option(PAPER_SETTING["max_steps"], range=STEPS, help="give up after this many steps, ramp included")
    hard_collisions: object = option(None, help="the Simulator's hard collisions (a HardCollisions), or None")


def equilateral_positions(layers: int, diameter: float = 1.0, x0: float | None = None, gap: float = 0.0) -> np.ndarray:
    """`[k(k+1)/2, 2]` centres of a k-layer equilateral pile standing on y = 0.
    Ordered bottom layer first, left to right; the bottom layer's disk i (1-based,
    as in eq. 44) is row index i - 1.

    Args:
      gap: horizontal gap between neighbours on the same level, as a fraction of
        the diameter. Diagonal neighbours always touch, so the lattice angle is
        theta = asin((1 + gap) / 2) (pi/6 for gap = 0, see `lattice_angle`).
    """
    if int(layers) != layers or layers < 1:
        raise InputError(f"layers must be a positive integer; got {layers!r}.")
    if not 0.0 <= gap < 0.1:
        raise InputError(f"gap must be in [0, 0.1) diameters; got {gap!r}.")
    layers = int(layers)
    x0 = diameter if x0 is None else x0
    spacing = diameter * (1.0 + gap)
    rise = math.sqrt(diameter**2 - (0.5 * spacing) ** 2)
    rows = []
    for j in range(layers):
        i = np.arange(layers - j)
        x = x0 + (i + 0.5 * j) * spacing
        y = 0.5 * diameter + j * rise
        rows.append(np.stack([x, np.full_like(x, y)], axis=1))
    return np.concatenate(rows, axis=0)


def lattice_angle(gap: float = 0.0) -> float:
    """theta of the 1992 Fig. 5 (angle of the diagonals from the vertical)."""
    return math.asin((1.0 + gap) / 2.0)


def equilateral_pile(layers: int, *, diameter: float = 1.0, mass: float = 1.0, gap: float = 0.0,
                     dtype=None) -> tuple[Particles, Boundaries]:
    """Particles and boundaries (the ground alone, no side-wall slots) of the k-layer pile."""
    o = LatticeOptions(layers=layers, diameter=diameter, mass=mass, gap=gap)  # types, finiteness and ranges first
    layers, diameter, mass, gap = o.layers, o.diameter, o.mass, o.gap
    if int(layers) == layers and layers >= 1:  # before any array is allocated
        budget.check(int(layers) * (int(layers) + 1) // 2, dtype or "float64", what=f"a {int(layers):,}-layer lattice pile")
    position = equilateral_positions(layers, diameter, gap=gap)
    particles = make_particles(position, 0.5 * diameter, mass=mass, dtype=dtype)
    return particles, make_boundaries(sides=False, dtype=particles.position.dtype)


def pile_count(layers: int) -> int:
    """k(k+1)/2 disks in a k-layer pile."""
    return layers * (layers + 1) // 2


LAW_SETTING = Setting(law="hooke", params=PAPER_SETTING["params"], dt=PAPER_SETTING["dt"],
                      rotation=PAPER_SETTING["rotation"])
"""The lattice's laws: the 1992 setting."""
law_and_params = LAW_SETTING.law_and_params


relax = loaded_pile.relax  # gravity ramped in, then a run to rest (shared with the sloped pile)


def setup(o: LatticeOptions, *, law, seed: int, dt: float, dtype=None) -> Setup:
    """The k-layer pile as a `Setup` (`equilateral_pile`). The pile is
    deterministic (`seed` is not used); the gravity ramp is the simulator's."""
    particles, boundaries = equilateral_pile(o.layers, diameter=o.diameter, mass=o.mass, gap=o.gap, dtype=dtype)
    return Setup(particles=particles, boundaries=boundaries,
                 info={"protocol": "lattice", "layers": int(o.layers), "n": int(particles.count), "dt": float(dt)})


def _compare(sim, params, state, p) -> dict:
    """`compare_with_theory` of the pile's ground forces, with its layers, steps
    and the ground friction a static pile needs (the largest |H| / N)."""
    from jaxpile.measure import analysis, theory

    layers = p.info["layers"]
    return {"layers": layers, **compare_with_theory(analysis.base_forces(sim, params, state), layers),
            "ground_friction_needed": theory.lattice_ground_friction_needed(int(layers)), "steps": int(state.step)}


def compare_with_theory(base, layers: int) -> dict:
    """Ground forces of a relaxed k-layer pile against eqs. 42 and 44.

    Args:
      base: `analysis.BaseForces` (in mg), sorted by x.

    Returns:
      dict with the theory arrays and the largest relative deviations: of N from
      (k + 1)/2 relative to it, and of H from eq. 44 relative to max |H|
      (the paper's own measure, Figs. 8-9).
    """
    from jaxpile.measure import theory

    n_theory = theory.lattice_ground_normal_force(layers)
    h_theory = theory.lattice_ground_horizontal_force(layers)
    intact = len(base.x) == layers
    if intact:
        dev_n = float(np.max(np.abs(base.normal - n_theory)) / n_theory)
        dev_h = float(np.max(np.abs(base.horizontal - h_theory)) / np.max(np.abs(h_theory)))
    else:
        dev_n = dev_h = float("nan")
    return {
        "base_contacts": len(base.x),
        "pile_intact": bool(intact),
        "theory_normal": n_theory,
        "theory_horizontal": h_theory,
        "max_rel_dev_normal": dev_n,
        "max_rel_dev_horizontal": dev_h,
    }


COMPARED = ("layers", "base_contacts", "pile_intact", "theory_normal", "max_rel_dev_normal", "max_rel_dev_horizontal",
            "ground_friction_needed", "steps")
"""The plain numbers of `_compare` a sweep row carries (`jaxpile.batches`)."""


SPEC = loaded_pile.spec_of(
    "lattice", options=LatticeOptions, setting=LAW_SETTING, setup=setup, compare=_compare, size="layers")
"""The lattice pile (Liffman et al. 1992, Figs. 7-9): `SPEC.run("hooke", 12)` builds the 12-layer pile, loads
it by a gravity ramp, runs it to rest and compares its ground forces with eqs. 42 and 44."""


__all__ = ["COMPARED", "PAPER_SETTING", "SPEC", "LatticeOptions", "compare_with_theory", "equilateral_pile",
           "equilateral_positions", "lattice_angle", "law_and_params", "pile_count", "relax", "setup"]
