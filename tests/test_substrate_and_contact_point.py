"""Base-disk forces, contact points and wall damping against hand statics and
closed forms, not against the functions the code itself uses:

* a frictionless disk at rest in the hollow between two fixed (substrate) disks
  of unequal radii (the poured heap's base of Baxter et al. 1997): the force it
  exerts on each base disk follows from its own force balance (eq. 2 with
  F_i = 0), the contact point from the geometry of the two circles;
* a small disk rolling without slip on a larger one under Baxter's law (eq. 6):
  the contact-point lever arms split the centre line in the ratio of the radii,
  so the touching surfaces do not slip and the torques are (Q - x) x F;
* a disk sliding on the ground with no tangential spring: its velocity decays
  at exactly the wall's tangential damping rate, which defaults to the disk
  gamma_t (itself gamma_n / 2, LAMMPS's default).
"""

import math

import jax.numpy as jnp
import numpy as np
import pytest

import jaxpile  # noqa: F401  (float64 on)
from jaxpile import fit
from jaxpile.engine.boundaries import make_boundaries
from jaxpile.engine.simulate import Simulator
from jaxpile.engine.state import make_particles
from jaxpile.laws import baxter, hooke
from jaxpile.laws.base import PairGeometry
from jaxpile.measure import analysis

# The hollow: base disks of radii 0.5 (left) and 0.3 (right), centres 0.95 apart
# (a gap of 0.15), holding a disk of radius 0.25. Unequal radii everywhere, so the
# contact point's split of the centre line (r_base : r_disk) differs from its
# mirror (r_disk : r_base) by about 0.1 for the left pair and 0.02 for the right.
BASE_RADII = (0.5, 0.3)
BASE_X = (2.0, 2.95)
BASE_Y = 3.0
DISK_RADIUS = 0.25
GRAVITY = 1.5  # not 1, so that "in mg" is not "in m"


def _touching_position():
    """The disk's centre touching both base disks (the upper intersection of the
    circles |P - B_L| = r_L + r and |P - B_R| = r_R + r)."""
    (xl, xr), (rl, rr) = BASE_X, BASE_RADII
    dl, dr, d = rl + DISK_RADIUS, rr + DISK_RADIUS, xr - xl
    a = (dl**2 - dr**2 + d**2) / (2 * d)
    return np.array([xl + a, BASE_Y + math.sqrt(dl**2 - a**2)])


@pytest.fixture(scope="module")
def hollow():
    """The disk settled in the hollow (frictionless, rotation off, no walls in
    reach: the ground is 2 diameters below the base)."""
    position = np.array([[BASE_X[0], BASE_Y], [BASE_X[1], BASE_Y], _touching_position()])
    particles = make_particles(position, [*BASE_RADII, DISK_RADIUS], fixed=[True, True, False])
    params = hooke.make_params(kn=1e4, gamma_n=50.0, mu=0.0)
    sim = Simulator(hooke.law(rotation=False), dt=2e-4, chunk_steps=2000)
    state = sim.init(params, particles, make_boundaries(gravity=GRAVITY, sides=False))
    state, info = sim.run_until_rest(params, state, speed_tolerance=1e-9, max_steps=40_000, progress=False)
    assert info.at_rest
    return sim, params, state


def _hand_statics(state):
    """Per base disk (left, right): the unit vector u from its centre to the
    disk's, the centre distance, and the normal force N the base exerts on the
    disk (along u), from the disk's balance N_L u_L + N_R u_R + m g = 0."""
    pos = np.asarray(state.particles.position)
    mass = float(state.particles.mass[2])
    d = pos[2] - pos[:2]  # [base, xy]
    dist = np.linalg.norm(d, axis=1)
    u = d / dist[:, None]
    normal = np.linalg.solve(u.T, [0.0, mass * GRAVITY])  # columns u_L, u_R
    return u, dist, normal, mass


def test_disk_in_a_substrate_hollow_pushes_the_base_disks_apart(hollow):
    """Baxter et al. 1997, eq. 2 at rest: sum_k F_ik + F_i^g = 0 for the disk, so
    the two base contacts' horizontal forces cancel (the pile's base takes no net
    shear without walls), and by Newton's third law the disk pushes the left base
    disk to -x and the right one to +x, each by N u_x with N from the disk's
    balance, H = mg / (u_Ly / u_Lx - u_Ry / u_Rx) (the sign convention of
    Liffman et al. 1992, eq. 43: the force on the base, negative = leftwards)."""
    sim, params, state = hollow
    u, _, normal, mass = _hand_statics(state)
    assert np.all(normal > 0)  # both contacts carry load
    mg = mass * GRAVITY
    expected_h = -normal * u[:, 0] / mg  # the force on base k is -N_k u_k
    expected_n = normal * u[:, 1] / mg
    assert expected_h[0] < -0.1 and expected_h[1] > 0.1  # outward, and far from 0
    closed_form = 1.0 / (u[0, 1] / u[0, 0] - u[1, 1] / u[1, 0])
    assert expected_h[1] == pytest.approx(closed_form, rel=1e-12)

    f = analysis.substrate_forces(sim, params, state)
    np.testing.assert_array_equal(f.substrate, [0, 1])  # sorted by x: left base first
    np.testing.assert_array_equal(f.particle, [2, 2])
    # at rest to a speed of 1e-9: the residual force on the disk (damping, the
    # last oscillation) is below 1e-6 mg; the hand balance is exact
    np.testing.assert_allclose(f.horizontal, expected_h, rtol=0, atol=1e-6)
    np.testing.assert_allclose(f.normal, expected_n, rtol=0, atol=1e-6)
    assert abs(f.horizontal.sum()) < 1e-6  # no net shear on the base
    assert f.normal.sum() == pytest.approx(1.0, abs=1e-6)  # the base carries the weight
    # the traceable form (fit's) the same, contact by contact
    load = fit.base_load(sim, params, state, base="substrate")
    keep = np.asarray(load.weight) > 0
    order = np.argsort(np.asarray(load.x)[keep])
    np.testing.assert_allclose(np.asarray(load.horizontal)[keep][order], expected_h, rtol=0, atol=1e-6)


def test_substrate_contact_point_lies_on_each_base_disk_surface(hollow):
    """The contact point of the disk (radius r, centre P) with a base disk (radius
    a, centre B) lies on the centre line at distance a from B, to within the pair's
    overlap delta = a + r - |P - B| (the code divides the centre line in the ratio
    a : r, i.e. a |P - B| / (a + r) from B). Unequal radii, so the mirrored ratio
    r : a would put it about 0.1 (left) and 0.02 (right) away."""
    sim, params, state = hollow
    u, dist, _, _ = _hand_statics(state)
    base_x = np.asarray(state.particles.position)[:2, 0]
    radii = np.asarray(BASE_RADII)
    overlap = radii + DISK_RADIUS - dist
    assert np.all(overlap > 0) and np.all(overlap < 1e-3)  # touching, barely squeezed
    on_surface = base_x + radii * u[:, 0]
    convention = base_x + radii * dist / (radii + DISK_RADIUS) * u[:, 0]
    mirrored = base_x + DISK_RADIUS * dist / (radii + DISK_RADIUS) * u[:, 0]
    assert np.all(np.abs(mirrored - on_surface) > 0.01)  # the test can tell them apart

    f = analysis.substrate_forces(sim, params, state)
    # the surface point and the ratio point differ by a u_x delta / (a + r) < delta
    np.testing.assert_allclose(f.x, on_surface, rtol=0, atol=overlap.max())
    np.testing.assert_allclose(f.x, convention, rtol=0, atol=1e-12)  # positions are O(1): round-off only
    load = fit.base_load(sim, params, state, base="substrate")
    keep = np.asarray(load.weight) > 0
    np.testing.assert_allclose(np.sort(np.asarray(load.x)[keep]), on_surface, rtol=0, atol=overlap.max())


def test_sliding_disk_velocity_decays_at_the_default_wall_tangential_damping_rate():
    """hooke (LAMMPS gran/hooke/history): F_t = -(k_t s + m_eff gamma_t v_t); with
    k_t = 0, no spin and no Coulomb cap a disk sliding on the ground obeys
    m dv/dt = -m gamma_t^wall v, so v(t) = v(0) exp(-gamma_t^wall t). With
    `wall_gamma_t` left None it is the disk gamma_t (documented), which itself
    defaults to gamma_n / 2; both cases, and neither may be gamma_n."""
    gamma_n = 40.0
    m = 1.0  # a disk of diameter 1 (the default density)
    kn = 1e4
    # resting on the ground at its equilibrium overlap mg / kn, sliding along it
    particles = make_particles([[0.0, 0.5 - m * 1.0 / kn]], 0.5, velocity=[[0.2, 0.0]])
    sim = Simulator(hooke.law(rotation=False), dt=1e-4, chunk_steps=500)
    boundaries = make_boundaries(gravity=1.0, sides=False)
    cases = {"gamma_t default (gamma_n / 2)": (hooke.make_params(kn=kn, kt=0.0, gamma_n=gamma_n, mu=10.0),
                                                gamma_n / 2),
             "gamma_t = 8": (hooke.make_params(kn=kn, kt=0.0, gamma_n=gamma_n, gamma_t=8.0, mu=10.0), 8.0)}
    for name, (params, expected) in cases.items():
        assert params.wall_gamma_t is None
        state = sim.init(params, particles, boundaries)
        v = []
        for _ in range(3):  # t = 0, 0.05, 0.1
            v.append(float(state.particles.velocity[0, 0]))
            state = sim.run(params, state, 500, progress=False)
        assert abs(float(state.particles.velocity[0, 1])) < 1e-6  # stays on the ground, no bounce
        rate = -np.log(v[2] / v[1]) / 0.05  # from t = 0.05 on (the first step's half-kick excluded)
        # velocity Verlet with a velocity-dependent force: O(gamma dt) = 2e-3 relative error at most
        assert rate == pytest.approx(expected, rel=5e-3), name
        assert v[1] == pytest.approx(0.2 * math.exp(-expected * 0.05), rel=5e-3), name


def test_baxter_small_disk_rolling_without_slip_on_a_large_one_leaves_the_contact_unstrained():
    """Baxter et al. 1997, eq. 6 (contact-point reading): delta_F integrates the
    slip of the touching surfaces at the contact point Q, which divides the centre
    line in the ratio of the radii (|Q - x_i| = r a_i / (a_i + a_j)). A disk i of
    radius 0.3 rolling on a still disk j of radius 0.6 with v_i = w |Q - x_i| t has
    its material at Q at rest (v_i + w z x (Q - x_i) = 0), so delta_F stays 0; the
    mirrored split (arm r a_j / sigma for i) would strain it by w r (a_i - a_j) / sigma dt.
    Eq. 13, T = (Q - x) x F for each disk, by hand from Q."""
    law = baxter.law(lever_arm="contact-point")
    p = baxter.make_params(n=36.0, r0=1.2, mu=0.5, damping_fraction=0.0)
    a_i, a_j, r, w, dt = 0.3, 0.6, 0.95, 0.8, 1e-3  # r inside the cut-off 1.2 (a_i + a_j)
    n = np.array([1.0, 0.0])  # x_i - x_j = r n
    t = np.array([-n[1], n[0]])  # z x n
    x_i, x_j = r * n, np.zeros(2)
    q = x_i - r * a_i / (a_i + a_j) * n  # on the centre line, a_i : a_j
    assert np.linalg.norm(q - x_i) / np.linalg.norm(q - x_j) == pytest.approx(a_i / a_j, rel=1e-14)
    v_i = -w * np.array([-(q - x_i)[1], (q - x_i)[0]])  # v_i + w z x (q - x_i) = 0: no slip at Q
    f = lambda x: jnp.asarray(x, jnp.float64)
    rolling = PairGeometry(f(x_i - x_j), f(a_i), f(a_j), f(v_i), f(w), f(0.0), f(0.5))
    out = law.pair_force(p, rolling, jnp.zeros(1), dt)
    assert bool(out.in_contact)
    assert abs(w * r * (a_i - a_j) / (a_i + a_j) * dt) > 1e-4  # what the mirrored split would give
    assert abs(float(out.history[0])) < 1e-15  # round-off of O(1) products times dt

    strained = law.pair_force(p, rolling._replace(velocity=f((0.0, 0.0)), angular_velocity_i=f(0.0)),
                              jnp.array([0.01]), 0.0)
    force = np.asarray(strained.force)  # on i; -force on j
    assert abs(force @ t) > 1e-3  # a tangential force, so the arms matter
    cross = lambda a, b: a[0] * b[1] - a[1] * b[0]
    assert float(strained.torque) == pytest.approx(cross(q - x_i, force), rel=1e-12)
    assert float(strained.torque_j) == pytest.approx(cross(q - x_j, -force), rel=1e-12)
