"""`jaxpile.laws.granular`'s single contacts against their closed forms (the
module docstring's equation labels), and its LAMMPS line read and written
(`parse`, `lammps_line`). The twins against LAMMPS are in
`test_granular_lammps.py`."""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxpile  # noqa: F401  (float64 on)
from jaxpile.errors import InputError
from jaxpile.laws import granular, hooke
from jaxpile.laws.base import PairGeometry

R1, R2, M1, M2 = 0.5, 0.4, 1.3, 0.7
MEFF, REFF = M1 * M2 / (M1 + M2), R1 * R2 / (R1 + R2)


def head_on(law, params, speed, dt, steps, kernel_mass=MEFF):
    """Two disks closing head-on at `speed`, their separation integrated by
    velocity Verlet with the kernel's force (`kernel_mass`: the effective mass
    the kernel is told): `(contact time, rebound speed)`."""
    kernel = law.pair_force

    def force(x, v):
        g = PairGeometry(displacement=jnp.stack([x, 0.0 * x]), radius_i=jnp.asarray(R1), radius_j=jnp.asarray(R2),
                         velocity=jnp.stack([v, 0.0 * v]), angular_velocity_i=0.0 * x, angular_velocity_j=0.0 * x,
                         effective_mass=jnp.asarray(kernel_mass))
        out = kernel(params, g, jnp.zeros(law.history_size), dt)
        return out.force[0], out.in_contact

    def step(carry, _):
        x, v, f, touched = carry
        v_half = v + 0.5 * dt * f / MEFF
        x = x + dt * v_half
        f, contact = force(x, v_half)
        v = v_half + 0.5 * dt * f / MEFF
        return (x, v, f, touched + contact.astype(x.dtype)), None

    x0 = jnp.asarray(R1 + R2)
    (x, v, _, touched), _ = jax.jit(lambda: jax.lax.scan(step, (x0, jnp.asarray(-speed), jnp.asarray(0.0), 0.0),
                                                         None, length=steps))()
    assert float(x) > R1 + R2, "still in contact: run longer"
    return float(touched) * dt, float(v)


def test_hertz_contact_time_of_two_disks_eq_N3():
    """Hertz 1882 (eq. N3 undamped): F = K delta^(3/2), K = 4/3 E_eff sqrt(R);
    a head-on contact at speed v lasts t_c = 2 I delta_max / v, delta_max =
    (5 m_eff v^2 / (4 K))^(2/5), I = (2/5) B(2/5, 1/2) = 1.4716 (Johnson,
    Contact Mechanics, sec. 11.4). Measured to 1e-4 at dt = t_c / 20 000."""
    model, params = granular.parse("hertz/material 1e5 0.0 0.3 damping velocity tangential linear_nohistory 0.0 0.0")
    law = granular.law(model)
    speed = 0.7
    k = 4.0 / 3.0 * 1e5 / (2 * (1 - 0.3 ** 2)) * math.sqrt(REFF)
    delta_max = (5 * MEFF * speed ** 2 / (4 * k)) ** 0.4
    integral = 0.4 * math.gamma(0.4) * math.gamma(0.5) / math.gamma(0.9)
    t_c = 2 * integral * delta_max / speed
    dt = t_c / 20_000
    time, rebound = head_on(law, params, speed, dt, 24_000)
    assert time == pytest.approx(t_c, rel=1e-4)
    assert rebound == pytest.approx(speed, rel=1e-6)  # undamped: elastic


@pytest.mark.parametrize("e", [0.3, 0.6, 0.9])
def test_tsuji_damping_on_a_hertz_contact_rebounds_at_one_speed_ratio_and_its_polynomial_reads_two_ways_eq_D4(e):
    """Tsuji, Tanaka & Ishida 1992 (eq. D4): eta_n = alpha(e) sqrt(m k) on a
    Hertzian contact (k = K delta^(1/2)) makes the coefficient of
    restitution independent of the speed (two speeds a factor 4 apart: the
    same to 1e-9). Their polynomial alpha(e) reads two ways: with m = m_eff,
    as LAMMPS has it (and jaxpile, to twin it), the rebound is weaker damped
    than e; with m = 2 m_eff (told to the kernel here) it is e within 0.2 %
    (measured: 0.44, 0.70, 0.93 for e = 0.3, 0.6, 0.9 the first way; within
    5e-4 of e the second)."""
    model, params = granular.parse(f"hertz/material 1e5 {e} 0.3 damping tsuji tangential linear_nohistory 0.0 0.0")
    law = granular.law(model)
    k = 4.0 / 3.0 * 1e5 / (2 * (1 - 0.3 ** 2)) * math.sqrt(REFF)

    def restitution(speed, mass):
        t_c = 2 * 1.4716 * (5 * MEFF * speed ** 2 / (4 * k)) ** 0.4 / speed
        _, rebound = head_on(law, params, speed, t_c / 5_000, 9_000, kernel_mass=mass)
        return rebound / speed

    as_lammps = [restitution(speed, MEFF) for speed in (0.2, 0.8)]
    assert as_lammps[1] == pytest.approx(as_lammps[0], rel=1e-9)
    assert as_lammps[0] > e * 1.02
    assert restitution(0.5, 2 * MEFF) == pytest.approx(e, rel=2e-3)


def test_mindlin_tangential_stiffness_under_load_eq_T3():
    """Mindlin 1949 (eq. T3): under a normal load with contact radius a, a
    small tangential displacement s gives F_t = -8 G_eff a s, G_eff = E /
    (4 (2 - nu)(1 + nu)) for two like materials (kt NULL); no sliding."""
    e_mod, nu = 2e5, 0.25
    model, params = granular.parse(f"hertz/material {e_mod} 0.0 {nu} damping velocity tangential mindlin NULL 0.0 0.9")
    law = granular.law(model)
    delta, s = 0.01, 1e-5
    g = PairGeometry(displacement=jnp.array([R1 + R2 - delta, 0.0]), radius_i=jnp.asarray(R1),
                     radius_j=jnp.asarray(R2), velocity=jnp.zeros(2), angular_velocity_i=jnp.asarray(0.0),
                     angular_velocity_j=jnp.asarray(0.0), effective_mass=jnp.asarray(MEFF))
    out = law.pair_force(params, g, jnp.array([0.0, s]), 0.0)
    a = math.sqrt(REFF * delta)
    g_eff = e_mod / (4 * (2 - nu) * (1 + nu))
    assert float(out.force[1]) == pytest.approx(-8 * g_eff * a * s, rel=1e-13)
    k = 4.0 / 3.0 * e_mod / (2 * (1 - nu ** 2)) * a
    assert float(out.force[0]) == pytest.approx(k * delta, rel=1e-13)


def pair_at(delta, velocity=(0.0, 0.0), radius_j=R2, mass=MEFF):
    """The geometry of a pair (a wall with radius_j = 0) at overlap `delta`
    along x, with relative velocity `velocity`."""
    return PairGeometry(displacement=jnp.stack([R1 + radius_j - delta, 0.0 * delta]), radius_i=jnp.asarray(R1),
                        radius_j=jnp.asarray(radius_j), velocity=jnp.asarray(velocity, float),
                        angular_velocity_i=jnp.asarray(0.0), angular_velocity_j=jnp.asarray(0.0),
                        effective_mass=jnp.asarray(mass))


def test_jkr_pull_off_force_is_3_pi_w_r_and_a_contact_holds_to_the_pull_off_overlap_eq_N5():
    """Johnson, Kendall & Roberts 1971 (eq. N5), w LAMMPS's `cohesion` (the
    surface energy; JKR's work of adhesion is 2 w): along the JKR curve the
    normal force is -8/9 of the pull-off force at first touch (delta = 0),
    and its least value, -3 pi w R, is reached at the pull-off overlap
    delta_c = a0^2 / R - 2 sqrt(pi w a0 / E_eff), a0 = (9 pi w R^2 / (4
    E_eff))^(1/3), where a touching contact breaks; an untouched pair beyond
    contact feels nothing."""
    e_mod, nu, w = 1e5, 0.3, 2.0
    model, params = granular.parse(f"jkr {e_mod} 0.0 {nu} {w} damping velocity tangential linear_nohistory 0.0 0.0")
    law = granular.law(model)
    touched = jnp.array([0.0, 0.0, 1.0])
    e_eff = e_mod / (2 * (1 - nu ** 2))
    a0 = (9 * math.pi * w * REFF ** 2 / (4 * e_eff)) ** (1 / 3)
    delta_c = a0 ** 2 / REFF - 2 * math.sqrt(math.pi * w * a0 / e_eff)
    pulloff = 3 * math.pi * w * REFF

    def normal(delta, history=touched):
        out = law.pair_force(params, pair_at(delta), history, 0.0)
        return float(out.normal), bool(out.in_contact)

    assert delta_c < 0
    assert normal(0.0)[0] == pytest.approx(-8 / 9 * pulloff, rel=1e-9)
    along = jax.jit(jax.vmap(lambda d: law.pair_force(params, pair_at(d), touched, 0.0)))(
        jnp.linspace(delta_c * (1 - 1e-9), 0.02, 4001))
    assert bool(np.all(along.in_contact))
    assert float(along.normal.min()) == pytest.approx(-pulloff, rel=1e-9)
    assert float(along.normal[0]) == pytest.approx(-pulloff, rel=1e-6)
    assert not normal(delta_c * (1 + 1e-6))[1]  # broken beyond the pull-off overlap
    assert not normal(0.5 * delta_c, jnp.zeros(3))[1]  # never touched: no reach beyond contact
    assert float(law.interaction_range(params, R1, R2)) == pytest.approx(R1 + R2 - delta_c, rel=1e-12)


def test_dmt_adds_a_constant_pull_off_force_4_pi_w_r_to_hertz_eq_N4():
    """Derjaguin, Muller & Toporov 1975 (eq. N4): F_ne = 4/3 E_eff a delta -
    4 pi w R in contact, nothing apart; its friction cap is mu |F_ne + 2
    F_pulloff| (LAMMPS's manual, granular's W3)."""
    e_mod, nu, w, mu = 1e5, 0.3, 2.0, 0.4
    model, params = granular.parse(f"dmt {e_mod} 1.0 {nu} {w} damping velocity tangential linear_nohistory 1e6 {mu}")
    law = granular.law(model)
    delta = 0.004
    a = math.sqrt(REFF * delta)
    fne = 4 / 3 * e_mod / (2 * (1 - nu ** 2)) * a * delta - 4 * math.pi * w * REFF
    out = law.pair_force(params, pair_at(delta, velocity=(0.0, 3.0)), jnp.zeros(2), 0.0)
    assert float(out.normal) == pytest.approx(fne, rel=1e-12)
    assert float(out.force[1]) == pytest.approx(-mu * abs(fne + 8 * math.pi * w * REFF), rel=1e-12)  # sliding
    assert not bool(law.pair_force(params, pair_at(-1e-9), jnp.zeros(2), 0.0).in_contact)


def test_mindlin_rescale_scales_the_spring_with_the_contact_radius_on_unloading_and_force_forms_match_at_constant_a():
    """mindlin_rescale (eq. T4): when the contact radius falls from a_last to
    a, the spring's displacement is scaled by a / a_last, so the force kt a s
    by (a / a_last)^2; loading leaves it. mindlin/force (eq. T5) carries the
    elastic force: at constant a, n steps of a tangential velocity give the
    force mindlin gives, -kt a v n dt, to round-off."""
    line = "hertz/material 2e5 0.0 0.25 damping velocity tangential {} 3e4 0.0 10.0"
    rescale = granular.law(granular.parse(line.format("mindlin_rescale"))[0])
    params = granular.parse(line.format("mindlin_rescale"))[1]
    a_of = lambda d: math.sqrt(REFF * d)  # noqa: E731
    s = 1e-4
    for before, after in ((0.01, 0.0025), (0.0025, 0.01)):  # unloading, then loading
        out = rescale.pair_force(params, pair_at(after), jnp.array([0.0, s, a_of(before)]), 0.0)
        scaled = min(1.0, a_of(after) / a_of(before))
        assert float(out.force[1]) == pytest.approx(-3e4 * a_of(after) * s * scaled, rel=1e-12)
        assert float(out.history[2]) == pytest.approx(a_of(after), rel=1e-15)
    forces = {}
    for form in ("mindlin", "mindlin/force"):
        model, p = granular.parse(line.format(form))
        law, history = granular.law(model), jnp.zeros(2)
        for _ in range(50):
            out = law.pair_force(p, pair_at(0.01, velocity=(0.0, 0.3)), history, 1e-4)
            history = out.history
        forces[form] = float(out.force[1])
    assert forces["mindlin/force"] == pytest.approx(forces["mindlin"], rel=1e-12)
    assert forces["mindlin"] == pytest.approx(-3e4 * a_of(0.01) * 0.3 * 50 * 1e-4, rel=1e-12)


def test_limit_damping_keeps_a_separating_contact_from_pulling():
    """`limit_damping`: a normal force the damping would make attractive (a
    fast separation) is zero; without it the contact pulls."""
    line = "hooke 1e4 50.0 damping mass_velocity tangential linear_history 1e3 0.5 0.4"
    geometry = pair_at(1e-4, velocity=(5.0, 0.0))
    pulls = granular.law(granular.parse(line)[0]).pair_force(granular.parse(line)[1], geometry, jnp.zeros(2), 0.0)
    model, params = granular.parse(line + " limit_damping")
    held = granular.law(model).pair_force(params, geometry, jnp.zeros(2), 0.0)
    assert float(pulls.normal) < 0 and float(held.normal) == 0.0


def test_walls_as_lammps_computes_them_or_with_the_pairs_formulas():
    """A wall contact (a partner of zero radius, R = r_i): by default as
    LAMMPS 29Sep2021's `fix wall/gran granular` (E_eff = E / (2 (1 - nu)),
    eq. W1; jkr's reach r_i + a0^2 / r_i - 2 sqrt(pi w a0 / E_eff) with a0 =
    (9 pi w r_i / (4 E_eff))^(1/3), eq. W4, which is a0^2 (1 / r_i - 4 / (3
    sqrt(r_i))): beyond contact for r_i < 9/16 in the length unit, within the
    overlap above); with walls="pair" the pair's E / (2 (1 - nu^2)) and
    pull-off overlap delta_c = -a0^2 / (3 R) < 0 at R = r_i."""
    e_mod, nu, w = 1e5, 0.3, 2.0
    model, params = granular.parse(f"jkr {e_mod} 0.0 {nu} {w} damping velocity tangential linear_nohistory 0.0 0.0")
    touched = jnp.array([0.0, 0.0, 1.0])
    lammps, pair = granular.law(model), granular.law(model, walls="pair")
    assert lammps != pair and granular.law(model, walls="lammps") == lammps
    wall = e_mod / (2 * (1 - nu))

    def on_wall(law, delta, radius):
        g = pair_at(delta, radius_j=0.0, mass=M1)._replace(radius_i=jnp.asarray(radius),
                                                            displacement=jnp.array([radius - delta, 0.0]))
        return law.pair_force(params, g, touched, 0.0)

    for law, e_eff in ((lammps, wall), (pair, e_mod / (2 * (1 - nu ** 2)))):  # the JKR curve at delta = 0
        assert float(on_wall(law, 0.0, R1).normal) == pytest.approx(-8 / 9 * 3 * math.pi * w * R1, rel=1e-9)
    for radius in (0.4, 0.7):  # either side of 9/16
        reach = float(granular.wall_pulloff_overlap(wall, w, radius))
        a0 = (9 * math.pi * w * radius / (4 * wall)) ** (1 / 3)
        assert reach == pytest.approx(a0 ** 2 * (1 / radius - 4 / (3 * math.sqrt(radius))), rel=1e-12)
        assert (reach > 0) == (radius < 9 / 16)
        assert bool(on_wall(lammps, -reach + 1e-6 * abs(reach), radius).in_contact)
        assert not bool(on_wall(lammps, -reach - 1e-6 * abs(reach), radius).in_contact)
        delta_c = float(granular.pulloff_overlap(e_mod / (2 * (1 - nu ** 2)), w, radius))
        assert bool(on_wall(pair, delta_c * (1 - 1e-6), radius).in_contact)
        assert not bool(on_wall(pair, delta_c * (1 + 1e-6), radius).in_contact)
    with pytest.raises(InputError, match="walls is one of"):
        granular.law(model, walls="lammps-2023")


def test_a_lammps_line_is_read_with_its_defaults_and_written_back():
    """`parse` reads a `pair_coeff` granular line (LAMMPS's default damping is
    viscoelastic; tsuji's coefficient is e; NULL is mindlin's 8 G_eff);
    `lammps_line` writes the line that reads back to the same law; what it
    cannot read is refused in one line."""
    model, p = granular.parse("hertz/material 1e8 0.5 0.3 damping tsuji tangential mindlin NULL 1.0 0.5 "
                              "rolling sds 1e3 50 0.1")
    assert model == granular.Model("hertz/material", "tsuji", "mindlin", "sds")
    assert (float(p.E), float(p.restitution), float(p.nu), p.kt, float(p.mu_roll)) == (1e8, 0.5, 0.3, None, 0.1)
    again, q = granular.parse(granular.lammps_line(model, p))
    assert again == model and jax.tree_util.tree_all(jax.tree_util.tree_map(lambda x, y: bool(x == y), p, q))
    default, _ = granular.parse("hooke 1e5 0.3 tangential linear_history 2e4 0.5 0.4")
    assert default.damping == "viscoelastic"
    for line, match in (("hooke 1e5 0.3", "needs a tangential model"),
                        ("hertz 1e5 0.3 tangential mindlin NULL 1.0 0.5", "only hertz/material, dmt, jkr give"),
                        ("hertz/mindlin 1e5 0.3 0.3 tangential linear_history 1 1 1", "starts with its normal model"),
                        ("jkr 1e5 0.3 0.3 tangential linear_history 1 1 1", "jkr takes 4 coefficients"),
                        ("jkr 1e5 0.3 0.3 1.0 tangential linear_history 1 1 1 limit_damping", "cannot be used with jkr"),
                        ("hooke 1e5 0.3 tangential linear_history 2e4 0.5 0.4 rolling spring 1 1 1", "unknown rolling"),
                        ("hooke 1e5 0.3 tangential linear_history 2e4 0.5", "takes 3 coefficients"),
                        ("hooke 1e5 0.3 tangential linear_history 2e4 0.5 0.4 twisting marshall", "twisting is 3D"),
                        ("hertz/material 1e5 0.3 0.6 tangential linear_history 2e4 0.5 0.4", "nu")):
        with pytest.raises(InputError, match=match):
            granular.parse(line)


def test_a_granular_law_is_the_same_object_for_the_same_model_and_its_gradient_in_e_is_finite():
    """Laws built alike are equal (a jit closing over them compiles once), and
    a base force is differentiable in E, nu, e and mu (the quantities a fit
    takes logs of)."""
    model, p = granular.parse("hertz/material 1e5 0.5 0.3 damping tsuji tangential mindlin NULL 1.0 0.5")
    assert granular.law(model) == granular.law(model)
    law = granular.law(model)
    g = PairGeometry(displacement=jnp.array([0.8, 0.1]), radius_i=jnp.asarray(R1), radius_j=jnp.asarray(R2),
                     velocity=jnp.array([-0.3, 0.2]), angular_velocity_i=jnp.asarray(1.0),
                     angular_velocity_j=jnp.asarray(-0.5), effective_mass=jnp.asarray(MEFF))

    def fx(values):
        return law.pair_force(p.set(**values), g, jnp.zeros(2), 1e-4).force[0]

    values = {"E": p.E, "nu": p.nu, "restitution": p.restitution, "mu": p.mu}
    grad = jax.grad(fx)(values)
    for name, value in values.items():
        h = 1e-6 * float(value)
        up, down = dict(values), dict(values)
        up[name], down[name] = value + h, value - h
        assert float(grad[name]) == pytest.approx((float(fx(up)) - float(fx(down))) / (2 * h), rel=1e-6, abs=1e-9), name
    assert np.all(np.isfinite(np.asarray(jax.tree_util.tree_leaves(grad))))


@pytest.mark.parametrize("rolling", [None, "sds"])
def test_hooke_is_the_composition_hooke_mass_velocity_linear_history_bit_for_bit(rolling):
    """`hooke kn gamma_n damping mass_velocity tangential linear_history kt
    xgamma_t mu` is the `hooke` law in its `granular` reading
    (`hooke.law(pair_style="granular")`, LAMMPS's pair_style granular) bit
    for bit, rolling sds too, where xgamma_t gamma_n is hooke's gamma_t
    exactly (LAMMPS's defaults: gamma_t = gamma_n / 2): 20 disks settling in a
    box with walls, every position, velocity, spin, force and torque at every
    dump over 1000 steps."""
    from lammps_twin import pile, run_jaxpile, walls

    roll = {} if rolling is None else dict(k_roll=5e3, gamma_roll=2.0, mu_roll=0.2)
    hp = hooke.make_params(kn=1e5, gamma_n=20.0, mu=0.4, **roll)
    model, gp = granular.parse(f"hooke 1e5 20.0 damping mass_velocity tangential linear_history {float(hp.kt)!r} "
                               f"0.5 0.4" + ("" if rolling is None else " rolling sds 5e3 2.0 0.2"))
    particles, wall_positions, _ = pile()
    case = dict(steps=1000, every=250, dt=2e-4)
    ours, _ = run_jaxpile(particles, walls(5.0, **wall_positions), law=granular.law(model), params=gp, **case)
    theirs, _ = run_jaxpile(particles, walls(5.0, **wall_positions), law=hooke.law(rolling=rolling, pair_style="granular"),
                            params=hp, **case)
    for step in theirs:
        for column in theirs[step]:
            np.testing.assert_array_equal(np.asarray(ours[step][column]), np.asarray(theirs[step][column]))
