"""Liffman, Chan & Hughes 1992 eqs. 40-44 against hand-computed values."""

import math

import numpy as np
import pytest

from jaxpile import theory


def test_eq42_normal_force_is_half_the_column_weight():
    assert theory.lattice_ground_normal_force(45) == 23.0
    assert theory.lattice_ground_normal_force(3, mg=2.0) == 4.0


def test_eq44_horizontal_forces_hand_values():
    h = theory.lattice_ground_horizontal_force(3)
    np.testing.assert_allclose(h, [-1 / math.sqrt(3), 0.0, 1 / math.sqrt(3)])
    h45 = theory.lattice_ground_horizontal_force(45)
    assert h45[0] == pytest.approx(-44 / (2 * math.sqrt(3)))
    assert h45[22] == 0.0  # i = (k + 1) / 2
    assert abs(h45.sum()) < 1e-12


def test_eq43_reduces_to_eq44_at_pi_over_6():
    np.testing.assert_allclose(theory.lattice_ground_horizontal_force(7, theta=math.pi / 6),
                               [(2 * i - 8) / (2 * math.sqrt(3)) for i in range(1, 8)])


def test_eqs40_41_diagonal_forces_balance_weight():
    # eq. 38: L(x, y) + R(x, y) - L(x, y-1) - R(x-1, y) = W
    x, y = 4, 6
    l1, r1 = theory.lattice_diagonal_forces(x, y)
    l0, _ = theory.lattice_diagonal_forces(x, y - 1)
    _, r0 = theory.lattice_diagonal_forces(x - 1, y)
    assert l1 + r1 - l0 - r0 == pytest.approx(1 / math.cos(math.pi / 6))
    # eq. 37 (horizontal): L(x, y-1) + R(x, y) - L(x, y) - R(x-1, y) = 0
    assert l0 + r1 - l1 - r0 == pytest.approx(0.0)


def test_ground_friction_needed():
    assert theory.lattice_ground_friction_needed(45) == pytest.approx(44 / (math.sqrt(3) * 46))
    assert 0.55 < theory.lattice_ground_friction_needed(45) < 0.56
