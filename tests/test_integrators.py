"""The integrators of the three papers: Gear fifth-order predictor-corrector (Lee &
Herrmann 1993), the implicit energy-conserving scheme of Liffman et al. 1992
(eq. 24), against velocity Verlet and leapfrog (Baxter et al. 1997, eqs. 9-12)."""

import math

import jax.numpy as jnp
import numpy as np
import pytest

import jaxpile
from jaxpile.engine import integrators
from jaxpile.errors import InputError
from jaxpile.laws import hooke, liffman
from jaxpile.laws.base import PairGeometry
from jaxpile.engine.simulate import Simulator

KN = 25.0  # a soft ground spring: omega = 5 for the unit disk


def _oscillator_error(integrator, dt, gamma, t_end=2.0):
    """A unit disk bouncing on the ground spring without leaving it: y(t) of a
    (damped) harmonic oscillator about y_eq = r - mg / k_n."""
    params = hooke.make_params(kn=KN, gamma_n=gamma, mu=0.0)
    y_eq, amplitude = 0.5 - 1.0 / KN, 0.5 / KN
    particles = jaxpile.make_particles([[3.0, y_eq + amplitude]], 0.5)
    sim = Simulator(hooke.law(rotation=False), dt=dt, chunk_steps=1000, integrator=integrator)
    state = sim.init(params, particles, jaxpile.make_boundaries())
    state = sim.run(params, state, int(round(t_end / dt)), progress=False)
    w = math.sqrt(KN)
    wd = math.sqrt(w * w - gamma * gamma / 4)
    exact = y_eq + amplitude * math.exp(-gamma * t_end / 2) * (
        math.cos(wd * t_end) + gamma / (2 * wd) * math.sin(wd * t_end))
    return abs(float(state.particles.position[0, 1]) - exact)


def _order(integrator, dts, gamma):
    errors = [_oscillator_error(integrator, dt, gamma) for dt in dts]
    return np.polyfit(np.log(dts), np.log(errors), 1)[0]


@pytest.mark.parametrize("gamma", [0.0, 1.0])
def test_gear_fifth_order_error_falls_faster_than_dt4(gamma):
    """Gear's six-value predictor-corrector on a smooth oscillator, with and
    without velocity-dependent damping (r_3 started from the exact jerk):
    measured slopes 4.3 and 4.6 (velocity Verlet: 2)."""
    assert _order("gear", [0.01, 0.005, 0.0025, 0.00125], gamma) > 4.2


@pytest.mark.parametrize("gamma", [0.0, 1.0])
def test_implicit_midpoint_is_second_order(gamma):
    assert _order("implicit_midpoint", [0.04, 0.02, 0.01, 0.005], gamma) == pytest.approx(2.0, abs=0.1)


def test_gear_start_sets_r3_to_the_exact_jerk():
    """x''' = -(k/m) v - gamma a for the damped ground spring (disk above y_eq, moving)."""
    gamma, dt = 1.0, 1e-3
    params = hooke.make_params(kn=KN, gamma_n=gamma, mu=0.0)
    particles = jaxpile.make_particles([[3.0, 0.495]], 0.5, velocity=[[0.0, 0.01]])
    sim = Simulator(hooke.law(rotation=False), dt=dt, integrator="gear")
    state = sim.init(params, particles, jaxpile.make_boundaries())
    y, v = 0.495, 0.01
    a = KN * (0.5 - y) - gamma * v - 1.0
    jerk = -KN * v - gamma * a
    r3 = np.asarray(state.integrator_state.position)[0, 0, 1]
    assert r3 == pytest.approx(dt**3 / 6 * jerk, rel=1e-10)
    assert np.all(np.asarray(state.integrator_state.position)[1:] == 0)


def _three_disk_collision(integrator, dt):
    """Three disks meeting in free space, all dissipation off: the kinetic
    energy after they separate against before."""
    params = liffman.make_params(ks=1e4, kd=0.0, k_slip=0.0, mu_roll=0.0)
    particles = jaxpile.make_particles([[2.0, 5.0], [3.3, 5.3], [4.0, 3.8]], 0.5,
                                       velocity=[[1.0, 0.0], [-1.0, 0.0], [0.0, 1.0]])
    sim = Simulator(liffman.law(), dt=dt, chunk_steps=250, integrator=integrator)
    state = sim.init(params, particles, jaxpile.make_boundaries(gravity=0.0, ground=-10.0))

    def kinetic(s):
        p = s.particles
        return float(0.5 * jnp.sum(p.mass * jnp.sum(p.velocity**2, axis=1)))

    e0 = kinetic(state)
    state = sim.run(params, state, int(round(1.0 / dt)), progress=False)
    pos = np.asarray(state.particles.position)
    gaps = [np.linalg.norm(pos[i] - pos[j]) - 1.0 for i, j in ((0, 1), (0, 2), (1, 2))]
    assert min(gaps) > 0  # all apart again
    assert np.linalg.norm(np.asarray(state.particles.velocity)[0] - [1.0, 0.0]) > 0.1  # they did collide
    return kinetic(state) / e0 - 1.0


def test_eq24_time_averaged_spring_conserves_energy_through_collisions():
    """Liffman et al. 1992, eq. 24 with the implicit scheme: the spring does
    exactly -dV of work per step, so a collision returns the kinetic energy to
    round-off (20 sweeps), where velocity Verlet at the same dt misses by ~1e-3."""
    exact = _three_disk_collision(integrators.implicit_midpoint(relaxation=0.9, iterations=20), 2e-3)
    explicit = _three_disk_collision("velocity_verlet", 2e-3)
    assert abs(exact) < 1e-11
    assert abs(explicit) > 1e-4


def test_eq24_difference_quotient_at_contact_entry():
    """Entering contact within a step (r_k > sigma > r_{k+1}): f = K_s (sigma - r_{k+1})^2 / (2 (r_k - r_{k+1}))."""
    ks = 1e4
    params = liffman.make_params(ks=ks, kd=0.0, k_slip=0.0, mu_roll=0.0)
    d0, d1 = jnp.array([1.002, 0.0]), jnp.array([0.996, 0.0])
    g = PairGeometry(displacement=0.5 * (d0 + d1), radius_i=0.5, radius_j=0.5, velocity=jnp.zeros(2),
                     angular_velocity_i=0.0, angular_velocity_j=0.0, effective_mass=0.5,
                     step_displacements=jnp.stack([d0, d1]))
    out = liffman.pair_force(params, g, jnp.zeros(2), 1e-3)
    assert float(out.force[0]) == pytest.approx(ks * 0.004**2 / (2 * 0.006), rel=1e-12)
    both_in = g._replace(step_displacements=jnp.stack([jnp.array([0.999, 0.0]), d1]),
                         displacement=0.5 * (jnp.array([0.999, 0.0]) + d1))
    out = liffman.pair_force(params, both_in, jnp.zeros(2), 1e-3)
    assert float(out.force[0]) == pytest.approx(ks * (1.0 - (0.999 + 0.996) / 2), rel=1e-12)


@pytest.mark.parametrize("integrator", ["gear", "implicit_midpoint"])
def test_spinning_disk_dropped_on_the_ground_ends_rolling_at_rest_height(integrator):
    """Gear and the implicit scheme with rotation on: a disk dropped with spin w0
    comes to rest vertically mg/k_n below its radius and ends rolling without
    slip with v = -w0 r / 3 (angular momentum about the contact point, I = m r^2 / 2)."""
    params = hooke.make_params(kn=1e4, gamma_n=80.0, gamma_t=40.0, mu=0.5)
    particles = jaxpile.make_particles([[3.0, 0.55]], 0.5, angular_velocity=1.0)
    sim = Simulator(hooke.law(rotation=True), dt=2.5e-4, chunk_steps=10_000, integrator=integrator)
    state = sim.init(params, particles, jaxpile.make_boundaries())
    state = sim.run(params, state, 20_000, progress=False)
    p = state.particles
    assert 0.5 - float(p.position[0, 1]) == pytest.approx(1e-4, rel=1e-5)
    assert abs(float(p.velocity[0, 1])) < 1e-8
    assert float(p.velocity[0, 0]) == pytest.approx(-0.5 / 3, rel=1e-6)
    assert float(p.angular_velocity[0]) == pytest.approx(1 / 3, rel=1e-6)


def test_gear_time_step_limit_is_tighter_than_verlet():
    params = hooke.make_params(kn=1e4)
    particles = jaxpile.make_particles([[3.0, 0.6]], 0.5)
    boundaries = jaxpile.make_boundaries()
    Simulator(hooke.law(), dt=3e-3).check_params(params, particles)
    with pytest.raises(InputError, match="gear integrator"):
        Simulator(hooke.law(), dt=3e-3, integrator="gear").init(params, particles, boundaries)


def test_implicit_settings_are_checked():
    with pytest.raises(InputError, match="relaxation"):
        integrators.implicit_midpoint(relaxation=1.5)
    with pytest.raises(InputError, match="iterations"):
        integrators.implicit_midpoint(iterations=0)
