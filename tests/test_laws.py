"""The papers' contact laws: Lee & Herrmann 1993 eqs. 2a-2b and Baxter et al.
1997 eqs. 3-14, against analytic results and reference integrations."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxpile
from jaxpile.errors import InputError
from jaxpile.laws import baxter, hooke, lee_herrmann, liffman
from jaxpile.laws.base import PairGeometry
from jaxpile.protocols import lattice
from jaxpile.engine.simulate import Simulator, gravity_ramp

NO_WALLS = jnp.array([False, False, False])

LAWS = {
    "hooke": (hooke.law(), hooke.make_params(kn=1e4, gamma_n=60.0, mu=0.5)),
    "liffman": (liffman.law(), liffman.make_params(ks=1e4, kd=30.0, k_slip=30.0)),
    "lee-herrmann": (lee_herrmann.law(), lee_herrmann.make_params(kn=1e5, gamma_n=60.0, mu=0.5)),
    "baxter": (baxter.law(), baxter.make_params(n=36.0, r0=1.2, mu=0.5)),
}


def _geometry(d, v=(0.0, 0.0), meff=0.5, ri=0.5, rj=0.5):
    f = lambda x: jnp.asarray(x, jnp.float64)
    return PairGeometry(f(d), f(ri), f(rj), f(v), f(0.0), f(0.0), f(meff))


def _equilibrium_separation(name):
    if name in ("hooke", "liffman"):
        return 1.0 - 1.0 / 1e4
    if name == "lee-herrmann":
        return 1.0 - (1.0 / 1e5) ** (2.0 / 3.0)
    return 1.0  # Baxter: the force is exactly mg at r = sigma


@pytest.mark.parametrize("name", list(LAWS))
def test_stacked_disks_settle_at_the_analytic_separation(name):
    """A disk resting on a fixed disk: hooke sigma - mg/kn; Hertz (eq. 2a)
    sigma - (mg/kn)^{2/3}; Baxter (eq. 3) exactly sigma."""
    law, params = LAWS[name]
    particles = jaxpile.make_particles([[5.0, 5.0], [5.0, 6.0]], 0.5, fixed=[True, False])
    boundaries = jaxpile.make_boundaries().set(wall_active=NO_WALLS)
    sim = Simulator(law, dt=5e-4)
    state = sim.init(params, particles, boundaries)
    state, info = sim.run_until_rest(params, state, speed_tolerance=1e-10, max_steps=100_000, progress=False)
    assert info.at_rest
    r = float(state.particles.position[1, 1] - state.particles.position[0, 1])
    assert r == pytest.approx(_equilibrium_separation(name), abs=1e-9)


def _reference_restitution(force, meff, u_in, r_start, dt=1e-7):
    """RK4 of meff dr/dt^2 = F(r, dr/dt) for the centre distance r of a head-on
    pair, from first touch until the pair leaves the interaction range."""
    # the two components as Python floats (the same float64 arithmetic, in the same order, as
    # a 2-vector in numpy, without an array per stage: several times faster for 10^5-10^6 steps)
    r, u = float(r_start), -float(u_in)
    half, sixth = 0.5 * dt, dt / 6
    for _ in range(10_000_000):
        k1r, k1u = u, force(r, u) / meff
        r2, u2 = r + half * k1r, u + half * k1u
        k2r, k2u = u2, force(r2, u2) / meff
        r3, u3 = r + half * k2r, u + half * k2u
        k3r, k3u = u3, force(r3, u3) / meff
        r4, u4 = r + dt * k3r, u + dt * k3u
        k4r, k4u = u4, force(r4, u4) / meff
        r, u = r + sixth * (k1r + 2 * k2r + 2 * k3r + k4r), u + sixth * (k1u + 2 * k2u + 2 * k3u + k4u)
        if r >= r_start and u > 0:
            return u / u_in
    raise AssertionError("the reference pair never separated")


def _restitution_force(name):
    law, p = LAWS[name]
    meff = 0.5
    if name == "hooke":
        return (lambda r, u: float(p.kn) * max(1 - r, 0.0) - meff * float(p.gamma_n) * u * (r < 1)), 1.0
    if name == "liffman":
        return (lambda r, u: float(p.ks) * max(1 - r, 0.0) - float(p.kd) * u * (r < 1)), 1.0
    if name == "lee-herrmann":
        return (lambda r, u: float(p.kn) * max(1 - r, 0.0) ** 1.5 - meff * float(p.gamma_n) * u * (r < 1)), 1.0

    def bax(r, u):
        if r >= 1.2:
            return 0.0
        fe = (1.0 / r) ** 37
        return fe - 0.5 * 2.0 * math.sqrt(2 * meff * 37 * fe / r) * u
    return bax, 1.2


@pytest.mark.parametrize("name", list(LAWS))
def test_head_on_restitution_matches_the_law(name):
    """hooke: closed form e = exp(-pi zeta / sqrt(1 - zeta^2)); Hertz (eq. 2a) and
    Baxter (eq. 3 with 50% critical damping): a high-accuracy integration of
    the same two-body ODE."""
    law, params = LAWS[name]
    u_in = 0.5
    force, r_out = _restitution_force(name)
    # Baxter's law is soft and long-ranged: a longer step covers its longer contact
    sim = Simulator(law, dt=1e-4 if name == "baxter" else 2e-5, chunk_steps=2000)
    start = r_out + 0.01
    particles = jaxpile.make_particles([[5.0, 5.0], [5.0 + start, 5.0]], 0.5,
                                       velocity=[[u_in / 2, 0.0], [-u_in / 2, 0.0]])
    state = sim.init(params, particles, jaxpile.make_boundaries(gravity=0.0).set(wall_active=NO_WALLS))
    for _ in range(200):  # until the pair has left the interaction range, moving apart
        state = sim.run(params, state, 2000, progress=False)
        gap = float(state.particles.position[1, 0] - state.particles.position[0, 0])
        if gap > r_out and float(state.particles.velocity[1, 0] - state.particles.velocity[0, 0]) > 0:
            break
    v = np.asarray(state.particles.velocity[:, 0])
    e = (v[1] - v[0]) / u_in
    if name in ("hooke", "liffman"):  # linear spring-dashpot: closed form
        k, c = (float(params.kn), 0.5 * float(params.gamma_n)) if name == "hooke" else (float(params.ks), float(params.kd))
        omega = math.sqrt(k / 0.5)
        zeta = c / (2 * 0.5 * omega)
        expected = math.exp(-math.pi * zeta / math.sqrt(1 - zeta**2))
    else:
        expected = _reference_restitution(force, 0.5, u_in, r_out, dt=1e-5)
    assert 0.01 < e < 0.99  # damped, not dead (Baxter at 50% critical: e ~ 0.02)
    assert e == pytest.approx(expected, rel=5e-3)


@pytest.mark.parametrize("slip", ["cundall-strack", "literal"])
def test_eq2b_lee_herrmann_shear_spring_then_coulomb_cap(slip):
    p = lee_herrmann.make_params(kn=1e5, ks=1e3, gamma_n=0.0, gamma_s=0.0, mu=0.3)
    pair_force = lee_herrmann.law(slip=slip).pair_force
    g = _geometry((-0.99, 0.0), v=(0.0, 0.2))  # i left of j; s = (n_y, -n_x) = (0, 1)

    def step(delta, _):
        out = pair_force(p, g, delta, 1e-3)
        return out.history, out.force[1]

    delta, forces = jax.lax.scan(step, jnp.zeros(1), None, length=3000)
    forces = np.asarray(forces)
    fn = 1e5 * 0.01**1.5
    np.testing.assert_allclose(forces[:5], -1e3 * 0.2e-3 * np.arange(1, 6), rtol=1e-12)  # -k_s delta_s
    np.testing.assert_allclose(forces[-1], -0.3 * fn, rtol=1e-12)  # -mu F_n
    if slip == "literal":
        assert float(delta[0]) == pytest.approx(3000 * 0.2e-3)  # keeps accumulating while sliding
    else:
        assert float(delta[0]) == pytest.approx(0.3 * fn / 1e3, rel=1e-12)  # the spring slipped at mu F_n / k_s
    # Reverse the motion: Cundall-Strack friction reverses within a step; the
    # literal law keeps pushing the old way until delta_s is undone.
    back = g._replace(velocity=-g.velocity)
    out = pair_force(p, back, delta, 1e-3)
    if slip == "literal":
        assert float(out.force[1]) == pytest.approx(-0.3 * fn, rel=1e-12)
    else:
        assert float(out.force[1]) == pytest.approx(-0.3 * fn + 1e3 * 0.2e-3, rel=1e-12)


def test_eq2b_lee_herrmann_cundall_strack_slip_dissipates_mu_fn_per_unit_slide():
    """A contact driven back and forth beyond the slip limit: the Cundall-Strack
    law takes ~ 2 mu F_n A per half cycle (A the amplitude), the literal law
    gives back what it took."""
    p = lee_herrmann.make_params(kn=1e5, ks=1e5, gamma_n=0.0, gamma_s=0.0, mu=0.3)
    fn = 1e5 * 0.01**1.5
    dt, steps, amplitude = 1e-3, 4000, 0.05  # 0.05 >> the slip distance mu F_n / k_s = 3e-4 (F_n = 100)
    t = np.arange(steps) * dt
    omega = 2 * np.pi / 2.0  # two full periods
    speeds = jnp.asarray(amplitude * omega * np.cos(omega * t))
    work = {}
    for slip in ("cundall-strack", "literal"):
        pair_force = lee_herrmann.law(slip=slip).pair_force

        def step(delta, v, pair_force=pair_force):
            out = pair_force(p, _geometry((-0.99, 0.0), v=jnp.stack([0.0, v])), delta, dt)
            return out.history, out.force[1] * v * dt  # work done on i by the contact

        _, w = jax.lax.scan(step, jnp.zeros(1), speeds)
        work[slip] = float(jnp.sum(w))
    slid = 2 * 2 * 2 * amplitude  # 2 periods x 2 half cycles x 2A
    assert -work["cundall-strack"] == pytest.approx(0.3 * fn * slid, rel=0.02)
    assert abs(work["literal"]) < 0.01 * 0.3 * fn * slid


def test_lee_herrmann_unknown_slip_mode_is_an_input_error():
    with pytest.raises(InputError, match="slip"):
        lee_herrmann.law(slip="sticky")


def test_eq5_baxter_tangential_force_mobilises_to_mu_fn_at_delta_max():
    p = baxter.make_params(n=36.0, r0=1.2, mu=0.5, damping_fraction=0.0)
    r = 1.0
    g = _geometry((r, 0.0), v=(0.0, 0.0))
    delta_max = 1.214 * 0.5 * (1.2 - r)
    for frac in (0.1, 0.5, 0.9, 1.0, 1.5):
        out = baxter.pair_force(p, g, jnp.array([frac * delta_max]), 0.0)
        f_t = -float(out.force[1])  # t = z x n = (0, 1) for n = (1, 0)
        expected = 0.5 * 1.0 * (1 - (1 - min(frac, 1.0)) ** 1.5)
        assert f_t == pytest.approx(expected, rel=1e-12)
        assert float(out.history[0]) == pytest.approx(min(frac, 1.0) * delta_max)  # held at delta_max


def test_baxter_history_lives_while_engaged_inside_r0():
    p = baxter.make_params()
    inside = baxter.pair_force(p, _geometry((1.19, 0.0), v=(0.0, 0.1)), jnp.zeros(1), 1e-3)
    outside = baxter.pair_force(p, _geometry((1.21, 0.0), v=(0.0, 0.1)), jnp.array([0.01]), 1e-3)
    assert inside.in_contact and float(inside.history[0]) != 0.0
    assert not outside.in_contact and float(outside.history[0]) == 0.0
    assert float(inside.normal) == pytest.approx(1.19**-37, rel=1e-12)


@pytest.mark.parametrize("slip", baxter.SLIP_MODES)
def test_eq5_baxter_gross_sliding_holds_or_accumulates_delta_f(slip):
    """Past delta_max the force is mu F_e^N either way (eq. 5's limit); "hold"
    clips delta_F to delta_max, "accumulate" keeps integrating it, so a contact
    strained 1.5 delta_max must be strained back past delta_max before its force falls."""
    law = baxter.law(slip=slip)
    p = baxter.make_params(n=36.0, r0=1.2, mu=0.5, damping_fraction=0.0)
    delta_max = 1.214 * 0.5 * 0.2
    out = law.pair_force(p, _geometry((1.0, 0.0)), jnp.array([1.5 * delta_max]), 0.0)
    assert -float(out.force[1]) == pytest.approx(0.5, rel=1e-12)
    held = 1.0 if slip == "hold" else 1.5
    assert float(out.history[0]) == pytest.approx(held * delta_max, rel=1e-12)
    back = law.pair_force(p, _geometry((1.0, 0.0), v=(0.0, -0.2 * delta_max / 1e-3)), out.history, 1e-3)
    expected = 0.5 * (1 - (1 - 0.8) ** 1.5) if slip == "hold" else 0.5
    assert -float(back.force[1]) == pytest.approx(expected, rel=1e-9)


@pytest.mark.parametrize("lever_arm", baxter.LEVER_ARMS)
def test_eq6_eq13_baxter_lever_arm_readings(lever_arm):
    """A pair of equal disks turning rigidly at rate w (v_i - v_j = w r t, both
    spins w): the contact-point arms (r/2 each) see no relative motion of the
    touching surfaces; eqs. 6 and 13 as printed (arm r for both) strain delta_F by
    -w r dt, and the torques use the same arm as delta_F."""
    law = baxter.law(lever_arm=lever_arm)
    p = baxter.make_params(n=36.0, r0=1.2, mu=0.5, damping_fraction=0.0)
    r, w, dt = 1.05, 0.8, 1e-3
    f = lambda x: jnp.asarray(x, jnp.float64)
    g = PairGeometry(f((r, 0.0)), f(0.5), f(0.5), f((0.0, w * r)), f(w), f(w), f(0.5))
    out = law.pair_force(p, g, jnp.zeros(1), dt)
    arm = r / 2 if lever_arm == "contact-point" else r
    assert float(out.history[0]) == pytest.approx(w * r * dt - 2 * w * arm * dt, abs=1e-15)
    strained = law.pair_force(p, g._replace(velocity=f((0.0, 0.0)), angular_velocity_i=f(0.0),
                                            angular_velocity_j=f(0.0)), jnp.array([0.01]), 0.0)
    f_t = float(strained.force[1])  # t = (0, 1)
    assert float(strained.torque) == pytest.approx(-arm * f_t, rel=1e-12)
    assert float(strained.torque_j) == pytest.approx(-arm * f_t, rel=1e-12)


@pytest.mark.parametrize("damping_mass", baxter.DAMPING_MASSES)
def test_eq3_eq8_baxter_damping_mass_against_a_fixed_partner(damping_mass):
    """C_N = 50% of 2 sqrt(m k) (eq. 3). Between free disks both readings use
    2 m_i m_j / (m_i + m_j) (= m for equal disks); against a fixed partner
    (effective mass m_i) "pair" keeps 2 m_i, "disk" takes the printed m_i:
    sqrt(2) less damping."""
    law = baxter.law(damping_mass=damping_mass)
    p = baxter.make_params(mu=0.5)
    f = lambda x: jnp.asarray(x, jnp.float64)
    r, m = 1.0, 1.0
    k = 37.0 * r ** -38.0

    def damping(partner_fixed, meff):
        g = PairGeometry(f((r, 0.0)), f(0.5), f(0.5), f((-0.3, 0.0)), f(0.0), f(0.0), f(meff),
                         partner_fixed=jnp.asarray(partner_fixed))
        return float(law.pair_force(p, g, jnp.zeros(1), 0.0).normal) - 1.0  # F_e^N(sigma) = 1

    assert damping(False, m / 2) == pytest.approx(0.5 * 2 * math.sqrt(m * k) * 0.3, rel=1e-12)
    fixed_mass = m if damping_mass == "disk" else 2 * m
    assert damping(True, m) == pytest.approx(0.5 * 2 * math.sqrt(fixed_mass * k) * 0.3, rel=1e-12)


def test_baxter_default_reading_is_the_one_the_audit_measured_and_the_pour_runs():
    """The readings of eqs. 3, 5, 6 and 13 measured in docs/baxter1997_audit.md:
    the contact-point arm, delta_F held at +-delta_max, the pair's damping mass
    is the default, and a pour runs it unless told otherwise. Changing the
    default changes every 1997 number of docs/papers.md: this test must fail then."""
    from jaxpile.protocols import pour

    default = (("lever_arm", "contact-point"), ("slip", "hold"), ("damping_mass", "pair"))
    assert baxter.law().options == default
    assert pour.make_simulator("baxter").law.options == default


def test_baxter_unknown_reading_is_an_input_error():
    with pytest.raises(InputError, match="lever_arm"):
        baxter.law(lever_arm="rim")
    with pytest.raises(InputError, match="slip"):
        baxter.law(slip="reset")
    with pytest.raises(InputError, match="damping_mass"):
        baxter.law(damping_mass="reduced")
    assert baxter.law(lever_arm="centre-distance") == baxter.law(lever_arm="centre-distance")  # compiles once


def test_eq14_hooke_equivalent_equal_work():
    k = baxter.hooke_equivalent(36.0, 1.2, 0.97)
    r = np.linspace(0.97, 1.2, 200_001)
    work = np.trapezoid(r**-37.0, r)
    assert 0.5 * k * 0.03**2 == pytest.approx(work, rel=1e-6)


@pytest.mark.parametrize("name", list(LAWS))
def test_newton_third_law_and_energy_bounded_without_damping(name):
    """Disks thrown about with damping and friction off: pair forces sum to zero
    and the total energy (kinetic + gravity + the law's potential) holds."""
    law, params = LAWS[name]
    undamped = {"hooke": dict(gamma_n=jnp.asarray(0.0), gamma_t=jnp.asarray(0.0), mu=jnp.asarray(0.0)),
                "lee-herrmann": dict(gamma_n=jnp.asarray(0.0), gamma_s=jnp.asarray(0.0), mu=jnp.asarray(0.0)),
                "liffman": dict(kd=jnp.asarray(0.0), k_slip=jnp.asarray(0.0), mu_roll=jnp.asarray(0.0),
                                mu_static=jnp.asarray(0.0)),
                "baxter": dict(damping_fraction=jnp.asarray(0.0), mu=jnp.asarray(0.0))}[name]
    params = params.set(**undamped)
    rng = np.random.default_rng(7)
    pos = lattice.equilateral_positions(4) * 1.05 + [0.5, 0.3]
    particles = jaxpile.make_particles(pos, 0.5, velocity=rng.normal(0, 0.5, pos.shape))
    sim = Simulator(law, dt=2e-4, chunk_steps=1000)
    state = sim.init(params, particles, jaxpile.make_boundaries(left=0.0, right=7.0))

    def energy(s):
        p = s.particles
        x, v = np.asarray(p.position), np.asarray(p.velocity)
        e = 0.5 * np.sum(v**2) + np.sum(x[:, 1])
        d = np.linalg.norm(x[:, None] - x[None], axis=-1)[np.triu_indices(len(x), 1)]
        walls = np.asarray(s.boundaries.wall_normal) @ x.T - np.asarray(s.boundaries.wall_offset)[:, None]
        walls = walls[np.asarray(s.boundaries.wall_active)].ravel()
        for sep, sigma in ((d, 1.0), (walls, 0.5)):
            if name in ("hooke", "liffman"):
                k = float(params.kn) if name == "hooke" else float(params.ks)
                e += 0.5 * k * np.sum(np.clip(sigma - sep, 0, None) ** 2)
            elif name == "lee-herrmann":
                e += 0.4 * float(params.kn) * np.sum(np.clip(sigma - sep, 0, None) ** 2.5)
            else:
                near = sep[sep < 1.2 * sigma]
                e += np.sum(sigma / 36.0 * ((sigma / near) ** 36 - (1 / 1.2) ** 36))
        return e

    e0 = energy(state)
    drift = 0.0
    for _ in range(5):
        state = sim.run(params, state, 1000, progress=False)
        drift = max(drift, abs(energy(state) - e0) / abs(e0))
        cf = sim.contact_forces(params, state)
        total = np.asarray(cf.pair.force).sum(axis=(0, 1))
        assert np.all(np.abs(total) < 1e-12 * max(1.0, np.abs(np.asarray(cf.pair.force)).sum()))
    # Baxter's force jumps by 1e-3 mg at the cut-off, so energy is only nearly conserved
    assert drift < (2e-3 if name != "baxter" else 2e-2)


@pytest.mark.parametrize("name", list(LAWS))
def test_lattice_pile_rests_with_base_force_equal_to_weight(name):
    law, params = LAWS[name]
    law = law.__class__(**{**law.__dict__, "rotation": False})
    if name == "liffman":
        pass  # its disk friction is viscous and vanishes at rest; the ground well holds the base
    elif name != "baxter":
        params = params.set(mu=jnp.asarray(0.0), wall_mu=jnp.asarray(1.0))  # the 1992 static setting
    else:
        # Baxter's long tail makes same-level neighbours push apart with ~mg, and
        # round disks without rolling resistance roll away on flat ground: the
        # lattice needs friction and no rotation to stand (the 1997 heaps are
        # poured onto a rough base of fixed disks instead)
        params = params.set(mu=jnp.asarray(1.0))
    particles, boundaries = lattice.equilateral_pile(5)
    sim = Simulator(law, dt=5e-4, schedule=gravity_ramp(4000), chunk_steps=2000)
    state = sim.init(params, particles, boundaries)
    state = sim.run(params, state, 4000, progress=False)
    state, info = sim.run_until_rest(params, state, speed_tolerance=1e-8, max_steps=200_000, progress=False)
    assert info.at_rest
    base = jaxpile.measure.analysis.base_forces(sim, params, state)
    assert len(base.x) == 5
    assert base.normal.sum() == pytest.approx(15.0, rel=1e-6)


# Gradients of each law through rollouts: tests/test_gradients.py (base profile vs
# central differences for mu, k_t / K_s, k_n and n).


def test_eq32_liffman_tangential_force_is_the_smaller_of_slip_and_roll():
    p = liffman.make_params(ks=1e4, kd=0.0, k_slip=100.0, mu_roll=0.1)
    fn = 1e4 * 0.01
    for v, expected in ((0.01, -1.0), (1.0, -0.1 * fn)):  # slow: slip (-K v); fast: roll (-mu_roll F_n)
        out = liffman.pair_force(p, _geometry((0.99, 0.0), v=(0.0, v)), jnp.zeros(2), 1e-3)
        assert float(out.force[1]) == pytest.approx(expected, rel=1e-12)
        assert float(out.torque) == pytest.approx(-0.5 * -100.0 * v, rel=1e-12)  # eq. 36 uses F_slip


def test_eq30_liffman_static_well_holds_then_breaks():
    """A disk on the ground pushed sideways: the well's spring (mu_s N / a) holds
    it until it has moved a, then releases it."""
    p = liffman.make_params(ks=1e4, kd=0.0, k_slip=0.0, mu_roll=0.0, mu_static=0.5, well_width=0.05)
    n_force = 1e4 * 1e-4
    g = lambda v: _geometry((0.5 - 1e-4, 0.0), v=(0.0, v), meff=1.0, rj=0.0)  # a wall partner
    history = jnp.zeros(2)
    out = liffman.pair_force(p, g(0.0), history, 1e-3)  # at rest: anchors
    assert float(out.history[0]) == 1.0
    history = out.history
    for _ in range(40):
        out = liffman.pair_force(p, g(1.0), history, 1e-3)
        history = out.history
    assert float(history[1]) == pytest.approx(0.04)
    assert float(out.force[1]) == pytest.approx(-0.5 * n_force / 0.05 * 0.04, rel=1e-10)
    for _ in range(20):
        out = liffman.pair_force(p, g(1.0), history, 1e-3)
        history = out.history
    assert float(history[0]) == 0.0 and float(out.force[1]) == 0.0  # moved past a: the well broke


HISTORY_LAWS = {
    "lee-herrmann": (lee_herrmann.law(), lee_herrmann.make_params(kn=1e5, ks=1.0, gamma_n=0.0, gamma_s=0.0, mu=1e6)),
    "baxter": (baxter.law(rotation=False), baxter.make_params(mu=1e3, damping_fraction=0.0)),
}


@pytest.mark.parametrize("name", list(HISTORY_LAWS))
def test_shear_history_survives_neighbor_rebuilds(name):
    """A disk sliding over a fixed disk: the accumulated shear displacement
    (delta_s of eq. 2b, delta_F of eq. 6) is the same whether or not the
    neighbour list was rebuilt on the way (skin 2.0: never; 0.05: several times)."""
    law, params = HISTORY_LAWS[name]
    histories = []
    for skin in (2.0, 0.05):
        top = 6.0 - (1e-5 ** (2 / 3) if name == "lee-herrmann" else 0.0)
        particles = jaxpile.make_particles([[5.0, 5.0], [5.0, top]], 0.5, velocity=[[0.0, 0.0], [0.3, 0.0]],
                                           fixed=[True, False])
        sim = Simulator(law, dt=1e-4, skin=skin, chunk_steps=500)
        state = sim.init(params, particles, jaxpile.make_boundaries().set(wall_active=NO_WALLS))
        reference = np.asarray(state.neighbors.reference_position).copy()
        state = sim.run(params, state, 2000, progress=False)
        rebuilt = not np.array_equal(np.asarray(state.neighbors.reference_position), reference)
        assert rebuilt == (skin < 1.0)
        entry = jaxpile.engine.pairs.pair_entry(state.contacts.pairs, 0, 1)
        histories.append(float(state.contacts.history[entry, 0]))
    assert abs(histories[0]) > 0.02
    assert histories[1] == pytest.approx(histories[0], rel=1e-10)


@pytest.mark.parametrize("name", list(LAWS))
def test_torque_on_j_is_what_the_law_gives_from_js_side(name):
    """The half pair list evaluates each pair once, from i, and hands j the
    reaction -F and the law's `torque_j` (hooke: -r_j n x F_t; liffman eq. 36,
    lee-herrmann eq. 2b, baxter eq. 13 with j's own lever arm). Evaluated from
    j's side (displacement, velocity and the two disks swapped), the same law
    must give exactly that force and torque."""
    law, params = LAWS[name]
    f = lambda x: jnp.asarray(x, jnp.float64)
    d, v, ri, rj, wi, wj = (0.7, 0.69), (0.3, -0.2), 0.45, 0.55, 1.5, -0.7
    history = jnp.zeros(law.history_size)
    from_i = law.pair_force(params, PairGeometry(f(d), f(ri), f(rj), f(v), f(wi), f(wj), f(0.5)), history, 0.0)
    from_j = law.pair_force(params, PairGeometry(-f(d), f(rj), f(ri), -f(v), f(wj), f(wi), f(0.5)), history, 0.0)
    assert bool(from_i.in_contact) and abs(float(from_i.torque)) > 1e-6
    np.testing.assert_allclose(from_j.force, -from_i.force, rtol=1e-12, atol=1e-15)
    assert float(from_j.torque) == pytest.approx(float(from_i.torque_j), rel=1e-12, abs=1e-15)
    assert float(from_j.torque_j) == pytest.approx(float(from_i.torque), rel=1e-12, abs=1e-15)
