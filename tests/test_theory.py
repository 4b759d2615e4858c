"""The papers' analytic models (jaxpile.measure.theory) against hand-computed values and limits:
Liffman, Chan & Hughes 1992 eqs. 40-44, 49-59 and Figs. 18-19; Lee & Herrmann 1993 eqs. 3-4."""

import math

import numpy as np
import pytest

from jaxpile import theory
from jaxpile.errors import InputError


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


# --- Liffman, Chan & Hughes 1992, continuum pile, eqs. 49-59 -------------------
# Hand values: alpha = 30 deg, B = 1, chi g = 1 gives sin(2pi/3 - a) = 1,
# sin(pi/3 - a) = 1/2, x_c = 1/3, so N = 3x/4, H = -x/(4 sqrt 3) on the left flank
# and N = 1/4, H = (x - 1/2)/(2 sqrt 3) in the middle. alpha = 45 deg gives
# sin(75) sin(15) = 1/4, so N = sqrt(3) x, H = -x/sqrt(3), N_mid = (sqrt(3) - 1)/2.

A30, A45, A60 = math.radians(30), math.radians(45), math.pi / 3
S3 = math.sqrt(3)


def test_xc_hand_values():
    assert theory.continuum_critical_distance(A30, 1.0) == pytest.approx(1 / 3)
    assert theory.continuum_critical_distance(A45, 1.0) == pytest.approx((1 - 1 / S3) / 2)
    assert theory.continuum_critical_distance(A45, 2.0) == pytest.approx(1 - 1 / S3)
    assert theory.continuum_critical_distance(A60, 1.0) == 0.0


def test_eqs49_51_line_lengths_hand_values():
    l1, l2 = theory.continuum_diagonal_lengths([0.2, 0.4, 0.6, 0.9], A30, 1.0)
    np.testing.assert_allclose(l1, [0.1, 0.2, 0.3, 0.1])    # eq. 49 x/2; mirrored eq. 50 at 0.9
    np.testing.assert_allclose(l2, [0.2, 0.3, 0.2, 0.05])   # eq. 50 x; eq. 51 (1 - x)/2


@pytest.mark.parametrize("alpha_deg", [20.0, 45.0, 59.0])
def test_eqs49_51_lines_end_on_the_pile_surface(alpha_deg):
    alpha, base = math.radians(alpha_deg), 2.0
    x = np.linspace(0.01, 1.99, 37)
    l1, l2 = theory.continuum_diagonal_lengths(x, alpha, base)
    for length, direction in ((l1, -1), (l2, 1)):
        end_x, end_y = x + direction * length / 2, S3 * length / 2
        surface = (base / 2 - np.abs(end_x - base / 2)) * math.tan(alpha)
        np.testing.assert_allclose(end_y, surface, atol=1e-12)


def test_eq54_eq55_hand_values_left_flank():
    x = np.array([0.1, 0.2, 1 / 3])
    np.testing.assert_allclose(theory.continuum_ground_normal_force(x, A30, 1.0), 3 * x / 4)
    np.testing.assert_allclose(theory.continuum_ground_horizontal_force(x, A30, 1.0), -x / (4 * S3))
    x = np.array([0.05, 0.2])
    np.testing.assert_allclose(theory.continuum_ground_normal_force(x, A45, 1.0), S3 * x)
    np.testing.assert_allclose(theory.continuum_ground_horizontal_force(x, A45, 1.0), -x / S3)


def test_eq56_eq57_hand_values_middle():
    np.testing.assert_allclose(theory.continuum_ground_normal_force([0.4, 0.5, 0.6], A30, 1.0), 0.25)
    assert theory.continuum_ground_horizontal_force(0.4, A30, 1.0) == pytest.approx(-0.1 / (2 * S3))
    assert theory.continuum_ground_normal_force(0.3, A45, 1.0) == pytest.approx((S3 - 1) / 2)
    assert theory.continuum_ground_horizontal_force(0.3, A45, 1.0) == pytest.approx(-0.4 / (3 + S3))
    # eq. 56 is linear in B and chi g
    assert theory.continuum_ground_normal_force(1.0, A30, 2.0, line_weight=3.0) == pytest.approx(1.5)


def test_eq58_eq59_hand_values_right_flank():
    assert theory.continuum_ground_normal_force(0.9, A30, 1.0) == pytest.approx(0.075)
    assert theory.continuum_ground_horizontal_force(0.9, A30, 1.0) == pytest.approx(0.1 / (4 * S3))


@pytest.mark.parametrize("alpha_deg", [10.0, 30.0, 45.0, 55.0])
def test_eq56_equals_eq54_at_xc_and_eq58_at_b_minus_xc(alpha_deg):
    alpha, base = math.radians(alpha_deg), 1.7
    xc = theory.continuum_critical_distance(alpha, base)
    eps = 1e-9
    for edge in (xc, base - xc):
        n = theory.continuum_ground_normal_force([edge - eps, edge + eps], alpha, base)
        h = theory.continuum_ground_horizontal_force([edge - eps, edge + eps], alpha, base)
        assert n[0] == pytest.approx(n[1], abs=1e-7)    # 54 = 56 = 58
        assert h[0] == pytest.approx(h[1], abs=1e-7)    # 55 = 57 = 59
    # the plateau value really is eq. 56
    s = math.sin(alpha) / (2 * math.sin(2 * math.pi / 3 - alpha))
    assert theory.continuum_ground_normal_force(base / 2, alpha, base) == pytest.approx(base * s)


@pytest.mark.parametrize("alpha_deg", [15.0, 40.0, 58.0])
def test_eqs54_59_equal_eqs52_53_of_eqs49_51(alpha_deg):
    alpha, base = math.radians(alpha_deg), 3.0
    x = np.linspace(0.0, base, 101)
    n, h = theory.diagonal_ground_forces(*theory.continuum_diagonal_lengths(x, alpha, base), line_weight=2.5)
    np.testing.assert_allclose(theory.continuum_ground_normal_force(x, alpha, base, 2.5), n, atol=1e-12)
    np.testing.assert_allclose(theory.continuum_ground_horizontal_force(x, alpha, base, 2.5), h, atol=1e-12)


def test_eqs52_53_hand_values():
    n, h = theory.diagonal_ground_forces(0.3, 0.1, line_weight=2.0)
    assert n == pytest.approx(0.4)
    assert h == pytest.approx(0.2 / S3)


def test_eqs54_59_mirror_symmetry_about_the_apex():
    alpha, base = math.radians(37.0), 2.0
    x = np.linspace(0.0, base, 81)
    n = theory.continuum_ground_normal_force(x, alpha, base)
    h = theory.continuum_ground_horizontal_force(x, alpha, base)
    np.testing.assert_allclose(n[::-1], n, atol=1e-14)
    np.testing.assert_allclose(h[::-1], -h, atol=1e-14)
    assert h[40] == pytest.approx(0.0, abs=1e-15)
    assert np.all(h[1:40] < 0) and np.all(h[41:-1] > 0)   # the pile pushes the ground outwards
    assert n[0] == 0.0 and n[-1] == 0.0


def _integral_piecewise_linear(f, alpha, base, **kw):
    xc = theory.continuum_critical_distance(alpha, base)
    x = np.unique(np.concatenate([np.linspace(0, base, 11), [xc, base - xc]]))
    y = f(x, alpha, base, **kw)
    return float(np.sum((y[1:] + y[:-1]) * np.diff(x)) / 2)   # exact: the profile is linear between the knots


def test_eqs54_58_integrate_to_the_pile_weight():
    # chi g B h / sqrt 3, h = (B/2) tan(alpha): 1/6 for (30 deg, B = 1); 2 sqrt 3 for (45 deg, B = 2, chi g = 3)
    assert _integral_piecewise_linear(theory.continuum_ground_normal_force, A30, 1.0) == pytest.approx(1 / 6)
    assert _integral_piecewise_linear(theory.continuum_ground_normal_force, A45, 2.0,
                                      line_weight=3.0) == pytest.approx(2 * S3)
    net_shear = _integral_piecewise_linear(theory.continuum_ground_horizontal_force, A45, 2.0)
    assert net_shear == pytest.approx(0, abs=1e-14)


@pytest.mark.parametrize("layers", [3, 7, 45])
def test_eqs56_57_at_60deg_recover_lattice_eqs42_44(layers):
    # ground disk i at x = i sigma, base (k + 1) sigma, chi g = mg / sigma (eq. 60)
    mg, i = 2.0, np.arange(1, layers + 1)
    n = theory.continuum_ground_normal_force(i, A60, layers + 1.0, line_weight=mg)
    h = theory.continuum_ground_horizontal_force(i, A60, layers + 1.0, line_weight=mg)
    np.testing.assert_allclose(n, theory.lattice_ground_normal_force(layers, mg=mg))
    np.testing.assert_allclose(h, theory.lattice_ground_horizontal_force(layers, mg=mg), atol=1e-12)
    # radians(60) is accepted as the lattice limit
    assert theory.continuum_critical_distance(math.radians(60.0), 1.0) == 0.0


def test_eqs54_59_tend_to_the_60deg_profile():
    x = np.linspace(0.0, 1.0, 21)
    for f in (theory.continuum_ground_normal_force, theory.continuum_ground_horizontal_force):
        np.testing.assert_allclose(f(x, A60 - 1e-9, 1.0), f(x, A60, 1.0), atol=1e-7)


def test_eqs54_59_friction_ratio_peaks_at_tan_alpha_over_3_on_the_flanks():
    alpha, base = math.radians(40.0), 1.0
    x = np.linspace(0.01, 0.99, 99)
    ratio = np.abs(theory.continuum_ground_horizontal_force(x, alpha, base)
                   / theory.continuum_ground_normal_force(x, alpha, base))
    xc = theory.continuum_critical_distance(alpha, base)
    flank = (x <= xc) | (x >= base - xc)
    np.testing.assert_allclose(ratio[flank], math.tan(alpha) / 3)
    assert np.all(ratio[~flank] < math.tan(alpha) / 3)


def test_eqs54_59_zero_off_the_base():
    for f in (theory.continuum_ground_normal_force, theory.continuum_ground_horizontal_force):
        np.testing.assert_array_equal(f([-0.5, 1.5], A30, 1.0), 0.0)
    assert theory.continuum_ground_normal_force(np.zeros((2, 3)) + 0.5, A30, 1.0).shape == (2, 3)


@pytest.mark.parametrize("alpha, base", [(0.0, 1.0), (-0.1, 1.0), (math.radians(61), 1.0),
                                         (float("nan"), 1.0), (A30, 0.0), (A30, -1.0), (A30, math.inf)])
def test_eqs49_59_reject_bad_pile(alpha, base):
    with pytest.raises(InputError):
        theory.continuum_ground_normal_force(0.5, alpha, base)
    with pytest.raises(InputError):
        theory.continuum_diagonal_lengths(0.5, alpha, base)


# --- 'Tent' piles, Figs. 18-19 -------------------------------------------------

def test_fig18_tent_height_hand_values():
    y = theory.tent_height([0.0, 0.2, 0.38, 0.5, 0.9, 1.0, 1.2], A30, A45, 0.38, 1.0)
    top = 0.38 / S3 + 0.12
    np.testing.assert_allclose(y, [0.0, 0.2 / S3, 0.38 / S3, top, 0.1 / S3, 0.0, 0.0], atol=1e-15)


@pytest.mark.parametrize("alpha_deg, knee", [(35.0, 0.2), (50.0, 0.0), (59.0, 0.45)])
def test_fig18_tent_with_equal_slopes_is_eqs54_59(alpha_deg, knee):
    alpha, x = math.radians(alpha_deg), np.linspace(0.0, 1.0, 57)
    n, h = theory.tent_ground_forces(x, alpha, alpha, knee, 1.0, line_weight=1.5)
    np.testing.assert_allclose(n, theory.continuum_ground_normal_force(x, alpha, 1.0, 1.5), atol=1e-12)
    np.testing.assert_allclose(h, theory.continuum_ground_horizontal_force(x, alpha, 1.0, 1.5), atol=1e-12)


def test_fig18_tent_with_knee_at_the_apex_is_eqs54_59():
    x = np.linspace(0.0, 1.0, 31)
    n, _ = theory.tent_ground_forces(x, A30, A45, 0.5, 1.0)
    np.testing.assert_allclose(n, theory.continuum_ground_normal_force(x, A30, 1.0), atol=1e-12)


def test_fig19_tent_hand_values():
    # alpha1 = 30, alpha2 = 45 deg, X_1 = 0.38, B = 1. At x = 0.5 both lines end on the
    # lower flanks (t sqrt3/2 = (0.5 - t/2)/sqrt3 gives t = 1/4), so N = 1/4, H = 0.
    # At x = 0.3: l_1 = 0.15 (lower flank); l_2 meets the upper flank,
    # t sqrt3/2 = 0.38/sqrt3 + (0.3 + t/2 - 0.38), t = 2 (0.38/sqrt3 - 0.08)/(sqrt3 - 1).
    n, h = theory.tent_ground_forces([0.3, 0.5], A30, A45, 0.38, 1.0)
    l2 = 2 * (0.38 / S3 - 0.08) / (S3 - 1)
    np.testing.assert_allclose(n, [(0.15 + l2) / 2, 0.25], rtol=1e-12)
    np.testing.assert_allclose(h, [(0.15 - l2) / (2 * S3), 0.0], atol=1e-12)


def test_fig19_peaked_tent_has_a_central_dip_flattened_one_has_none():
    x = np.linspace(0.0, 1.0, 401)
    n_peaked, _ = theory.tent_ground_forces(x, A30, A45, 0.38, 1.0)        # Fig. 18(b), Fig. 19
    assert n_peaked[200] < 0.95 * n_peaked.max()
    n_flat, _ = theory.tent_ground_forces(x, A45, A30, 0.38, 1.0)          # Fig. 18(a)
    assert n_flat[200] == pytest.approx(n_flat.max())
    assert np.all(np.diff(n_flat[:201]) >= -1e-12)


def test_fig19_tent_normal_force_integrates_to_its_weight():
    alpha1, alpha2, knee, base = A45, math.radians(20.0), 0.3, 2.0
    area = knee**2 * math.tan(alpha1) + (base - 2 * knee) * knee * math.tan(alpha1) \
        + (base / 2 - knee) ** 2 * math.tan(alpha2)
    x = np.linspace(0.0, base, 20001)
    n, h = theory.tent_ground_forces(x, alpha1, alpha2, knee, base)
    assert np.sum((n[1:] + n[:-1]) * np.diff(x)) / 2 == pytest.approx(2 * area / S3, rel=1e-6)
    assert np.sum((h[1:] + h[:-1]) * np.diff(x)) / 2 == pytest.approx(0.0, abs=1e-9)


def test_surface_line_lengths_zero_off_the_pile():
    l1, l2 = theory.surface_diagonal_lengths([-1.0, 0.0, 2.0], lambda s: np.where(np.abs(s - 1) < 1, 1.0, 0.0), 1.0)
    np.testing.assert_array_equal(l1, [0.0, 0.0, 0.0])
    np.testing.assert_array_equal(l2, [0.0, 0.0, 0.0])


@pytest.mark.parametrize("alpha1, alpha2, knee", [(A30, A45, 0.6), (A30, A45, -0.1),
                                                  (A30, math.radians(70), 0.2), (0.0, A45, 0.2)])
def test_fig18_tent_rejects_bad_shape(alpha1, alpha2, knee):
    with pytest.raises(InputError):
        theory.tent_ground_forces(0.5, alpha1, alpha2, knee, 1.0)


# --- Lee & Herrmann 1993, eqs. 3-4 --------------------------------------------

def _eq4_mu(theta_r, theta_t):
    """Eqs. 4a-4b as printed, with the brackets of 4b around the sums."""
    p = math.pi / 3
    r = ((math.tan(p + theta_t) + math.tan(theta_r)) * math.cos(p + theta_t)
         / ((math.tan(p - theta_t) - math.tan(theta_r)) * math.cos(p - theta_t)))
    return ((r * math.cos(p - theta_t) - math.cos(p + theta_t))
            / (r * math.sin(p - theta_t) + math.sin(p + theta_t)))


def test_eq3_hand_values():
    mu = [0.0, 1 / (3 * S3), 1 / 3, 1 / S3]
    np.testing.assert_allclose(theory.marginal_stability_angle(mu), [0, math.pi / 6, math.pi / 4, math.pi / 3])
    assert theory.marginal_stability_angle(0.2) == pytest.approx(math.atan(0.6))


def test_eq3_steeper_than_one_contact_and_3mu_for_small_mu():
    mu = np.array([0.01, 0.1, 0.3, 1.0])
    assert np.all(theory.marginal_stability_angle(mu) > np.arctan(mu))
    assert theory.marginal_stability_angle(1e-4) == pytest.approx(3e-4, rel=1e-7)


@pytest.mark.parametrize("mu", [0.1, 0.2, 0.3])
def test_eq3_is_where_eqs54_59_base_friction_reaches_mu(mu):
    alpha = float(theory.marginal_stability_angle(mu))
    x = np.linspace(0.001, 0.999, 999)
    for a, compare in ((alpha, pytest.approx(mu)), (0.95 * alpha, None)):
        ratio = np.max(np.abs(theory.continuum_ground_horizontal_force(x, a, 1.0)
                              / theory.continuum_ground_normal_force(x, a, 1.0)))
        assert ratio == compare if compare is not None else ratio < mu


@pytest.mark.parametrize("mu", [-0.1, float("nan"), [0.2, -1.0]])
def test_eq3_rejects_negative_mu(mu):
    with pytest.raises(InputError):
        theory.marginal_stability_angle(mu)


def test_eq4_hand_value():
    # theta_R = 30, theta_T = 15 deg: R = sin(105)/sin(15) = 2 + sqrt3 and eq. 4a gives
    # mu = (5 + sqrt3)/(5 + 3 sqrt3) = 5 sqrt3 - 8
    assert theory.tilting_angle(A30, 5 * S3 - 8) == pytest.approx(math.radians(15.0), abs=1e-12)


@pytest.mark.parametrize("mu", [0.1, 0.2, 0.3, 0.5])
@pytest.mark.parametrize("fraction", [0.2, 0.5, 0.9])
def test_eq4_theta_t_solves_eq4(mu, fraction):
    theta_r = fraction * float(theory.marginal_stability_angle(mu))
    theta_t = theory.tilting_angle(theta_r, mu)
    assert theta_t > 0
    assert _eq4_mu(theta_r, theta_t) == pytest.approx(mu, rel=1e-10)
    # the smallest tilt: every smaller one leaves the base below mu
    assert all(_eq4_mu(theta_r, t) < mu for t in np.linspace(0, theta_t, 20)[:-1])


def test_eq4_zero_tilt_at_marginal_stability_eq3():
    for mu in (0.1, 0.2, 0.4):
        assert theory.tilting_angle(float(theory.marginal_stability_angle(mu)), mu) == pytest.approx(0.0, abs=1e-12)


def test_eq4_tilt_shrinks_as_the_pile_steepens():
    tilts = [theory.tilting_angle(math.radians(a), 0.2) for a in (5, 10, 20, 30)]
    assert all(a > b for a, b in zip(tilts, tilts[1:]))
    assert 0 < math.degrees(theory.tilting_angle(math.radians(18.0), 0.2)) < 10   # "a few degrees"


@pytest.mark.parametrize("theta_r, mu", [(A30, -0.1), (0.0, 0.2), (math.pi / 2, 0.2), (-0.1, 0.2),
                                         (float("nan"), 0.2), (A30, float("nan")),
                                         (math.radians(40), 0.2),      # beyond theta_MS = 31 deg
                                         (math.radians(5), 0.0),       # mu = 0: theta_MS = 0
                                         (math.radians(50), 2.0)])     # theta_R + theta_T > 60 deg
def test_eq4_rejects_impossible_inputs(theta_r, mu):
    with pytest.raises(InputError):
        theory.tilting_angle(theta_r, mu)
