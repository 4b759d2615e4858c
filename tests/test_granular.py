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
from jaxpile.laws import granular
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
                        ("hertz 1e5 0.3 tangential mindlin NULL 1.0 0.5", "only hertz/material gives"),
                        ("jkr 1e5 0.3 0.3 1.0 tangential linear_history 1 1 1", "starts with its normal model"),
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
