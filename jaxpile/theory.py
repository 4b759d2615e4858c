"""The papers' analytic models.

Liffman, Chan & Hughes 1992, "A close packed equilateral sandpile - analytic
model": hard, equal disks on a lattice (Fig. 5) carrying force only along the two
lattice diagonals at angle theta to the vertical (theta = pi/6 for close packing).
"""

from __future__ import annotations

import math

import numpy as np


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
