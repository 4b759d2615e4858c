"""Liffman, Chan & Hughes 1992 Figs. 7-9: the equilateral close-packed pile at rest
carries N = (k + 1) mg / 2 under every ground disk (eq. 42) and pushes the ground
sideways with H = mg (2i - k - 1) / (2 sqrt 3) (eq. 44), within 1% (the paper's
claim). 12 layers here; the 45-layer check runs in `make demo`."""

import numpy as np
import pytest

from jaxpile import analysis
from jaxpile.protocols import lattice

from conftest import LATTICE_LAYERS


def test_lattice_positions_count_and_geometry():
    pos = lattice.equilateral_positions(45)
    assert len(pos) == 1035 == lattice.pile_count(45)
    base = pos[pos[:, 1] < 0.6]
    assert len(base) == 45
    np.testing.assert_allclose(np.diff(base[:, 0]), 1.0)
    d = np.linalg.norm(pos[:, None] - pos[None], axis=-1)
    np.fill_diagonal(d, np.inf)
    assert d.min() == pytest.approx(1.0)  # close packed, touching, no overlap


def test_relaxed_pile_is_at_rest(relaxed_lattice):
    sim, params, state, info = relaxed_lattice
    assert info.at_rest


def test_eq42_ground_normal_force_within_one_percent(relaxed_lattice):
    sim, params, state, info = relaxed_lattice
    base = analysis.base_forces(sim, params, state)
    check = lattice.compare_with_theory(base, LATTICE_LAYERS)
    assert check["pile_intact"]
    assert check["max_rel_dev_normal"] < 0.01


def test_eq44_ground_horizontal_force_within_one_percent_of_max(relaxed_lattice):
    sim, params, state, info = relaxed_lattice
    base = analysis.base_forces(sim, params, state)
    check = lattice.compare_with_theory(base, LATTICE_LAYERS)
    assert check["max_rel_dev_horizontal"] < 0.01
    # the sign convention of eq. 43: the left half pushes the ground to the left
    assert np.all(base.horizontal[: LATTICE_LAYERS // 2] < 0)


def test_total_base_normal_force_equals_total_weight(relaxed_lattice):
    sim, params, state, info = relaxed_lattice
    base = analysis.base_forces(sim, params, state)
    assert base.normal.sum() == pytest.approx(lattice.pile_count(LATTICE_LAYERS), rel=1e-6)
    assert abs(base.horizontal.sum()) < 1e-6 * base.normal.sum()


def test_no_horizontal_forces_between_disks_on_the_same_level(relaxed_lattice):
    """1992: 'no horizontal forces are found between neighbouring particles'."""
    sim, params, state, info = relaxed_lattice
    net = analysis.contact_network(sim, params, state)
    pos = np.asarray(state.particles.position)
    same_level = np.abs(pos[net.i, 1] - pos[net.j, 1]) < 0.1
    assert np.all(np.abs(net.normal[same_level]) < 1e-3 * net.normal.max())
