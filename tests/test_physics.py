"""Single- and few-body physics with known answers: integrator order, energy,
sinking under gravity, sticking/sliding/rolling on a tilted plane."""

import math

import jax.numpy as jnp
import numpy as np
import pytest

import jaxpile
from jaxpile.laws import hooke
from jaxpile.engine.simulate import Simulator

from conftest import random_disks


def _disk_on_ground(y, *, params, dt, tilt=0.0, rotation=True, integrator="velocity_verlet"):
    particles = jaxpile.make_particles([[3.0, y]], 0.5)
    boundaries = jaxpile.make_boundaries(tilt_degrees=tilt)
    sim = Simulator(hooke.law(rotation=rotation), dt=dt, chunk_steps=500, integrator=integrator)
    return sim, sim.init(params, particles, boundaries)


def test_disk_resting_on_ground_sinks_by_mg_over_kn():
    params = hooke.make_params(kn=1e4, gamma_n=80.0)
    sim, state = _disk_on_ground(0.5, params=params, dt=1e-3)
    state, info = sim.run_until_rest(params, state, speed_tolerance=1e-9, max_steps=20_000, progress=False)
    assert info.at_rest
    assert 0.5 - float(state.particles.position[0, 1]) == pytest.approx(1.0 / 1e4, rel=1e-6)


@pytest.mark.parametrize("integrator", ["velocity_verlet", "leapfrog"])
def test_integrator_error_shrinks_as_dt_squared(integrator):
    """A disk oscillating on the ground spring (never leaving it): y(t) = y_eq + A cos(w t).
    Velocity Verlet and the leapfrog of Baxter et al. 1997 (eqs. 9-12) are both second order."""
    kn = 1e4
    params = hooke.make_params(kn=kn, gamma_n=0.0, mu=0.0)
    y_eq = 0.5 - 1.0 / kn
    amplitude = 0.5 / kn
    t_end = 0.0512
    errors = []
    dts = [8e-4, 4e-4, 2e-4, 1e-4]
    for dt in dts:
        sim, state = _disk_on_ground(y_eq + amplitude, params=params, dt=dt, integrator=integrator)
        state = sim.run(params, state, int(round(t_end / dt)), progress=False)
        exact = y_eq + amplitude * math.cos(math.sqrt(kn) * t_end)
        errors.append(abs(float(state.particles.position[0, 1]) - exact))
    slope = np.polyfit(np.log(dts), np.log(errors), 1)[0]
    assert slope == pytest.approx(2.0, abs=0.15)


def _energy(state, kn):
    p = state.particles
    pos, r, m = np.asarray(p.position), np.asarray(p.radius), np.asarray(p.mass)
    kinetic = 0.5 * np.sum(m * np.sum(np.asarray(p.velocity) ** 2, 1)) + 0.5 * np.sum(
        np.asarray(p.inertia) * np.asarray(p.angular_velocity) ** 2)
    gravity = np.sum(m * pos[:, 1])
    d = np.linalg.norm(pos[:, None] - pos[None], axis=-1)
    overlap = np.clip(r[:, None] + r[None] - d, 0, None)
    np.fill_diagonal(overlap, 0.0)
    elastic = 0.25 * kn * np.sum(overlap**2)  # each pair counted twice
    b = state.boundaries
    dist = np.asarray(b.wall_normal) @ pos.T - np.asarray(b.wall_offset)[:, None]
    wall = np.clip(r[None] - dist, 0, None) * np.asarray(b.wall_active)[:, None]
    return kinetic + gravity + elastic + 0.5 * kn * np.sum(wall**2)


def test_energy_stays_bounded_without_damping():
    """Disks bouncing on the ground, off the walls and off each other, all
    damping and friction off: total energy (kinetic + gravity + springs) holds."""
    kn = 1e4
    params = hooke.make_params(kn=kn, gamma_n=0.0, mu=0.0)
    pos, rad = random_disks(12, seed=3, box=6.0, overlap=0.0)
    rng = np.random.default_rng(0)
    particles = jaxpile.make_particles(pos + [0.0, 0.5], rad, velocity=rng.normal(0, 1.0, pos.shape))
    sim = Simulator(hooke.law(), dt=2e-4, chunk_steps=1000)
    state = sim.init(params, particles, jaxpile.make_boundaries(left=0.0, right=6.0))
    e0 = _energy(state, kn)
    energies = []
    for _ in range(10):
        state = sim.run(params, state, 1000, progress=False)
        energies.append(_energy(state, kn))
    drift = np.max(np.abs(np.array(energies) - e0)) / e0
    assert drift < 2e-3
    assert float(jnp.max(jnp.abs(state.particles.velocity))) > 0.1  # still moving: it was a real test


@pytest.mark.parametrize("tilt_degrees, sticks", [(20.0, True), (35.0, False)])
def test_block_on_tilted_plane_sticks_below_and_slides_above_friction_angle(tilt_degrees, sticks):
    """Rotation off (a sliding block): sticks when tan(theta) < mu, else slides
    with a = g (sin(theta) - mu cos(theta))."""
    mu = 0.5
    params = hooke.make_params(kn=1e4, gamma_n=80.0, mu=mu)
    sim, state = _disk_on_ground(0.5 - 1e-4, params=params, dt=5e-4, tilt=tilt_degrees, rotation=False)
    x0 = float(state.particles.position[0, 0])
    # the acceleration from the velocity slope after the tangential spring has
    # loaded (the elastic pre-slip of the Cundall-Strack spring takes ~0.02)
    state = sim.run(params, state, 1000, progress=False)
    v1 = float(state.particles.velocity[0, 0])
    state = sim.run(params, state, 2000, progress=False)
    v2 = float(state.particles.velocity[0, 0])
    moved = float(state.particles.position[0, 0]) - x0
    theta = math.radians(tilt_degrees)
    if sticks:
        assert abs(moved) < 1e-3  # only the tangential spring's stretch, mg sin / kt ~ 1e-4
        assert float(jnp.linalg.norm(state.particles.velocity)) < 1e-4
    else:
        a = math.sin(theta) - mu * math.cos(theta)
        assert (v2 - v1) / (2000 * 5e-4) == pytest.approx(a, rel=1e-4)


def test_disk_rolls_down_tilted_plane_with_two_thirds_g_sin_theta():
    """Rotation on: a disk (I = m r^2 / 2) rolls without slipping when
    tan(theta) < 3 mu, accelerating at (2/3) g sin(theta)."""
    params = hooke.make_params(kn=1e4, gamma_n=80.0, mu=0.5)
    sim, state = _disk_on_ground(0.5 - 1e-4, params=params, dt=5e-4, tilt=20.0, rotation=True)
    state = sim.run(params, state, 1000, progress=False)
    v1 = float(state.particles.velocity[0, 0])
    state = sim.run(params, state, 2000, progress=False)
    v2 = float(state.particles.velocity[0, 0])
    a = 2.0 / 3.0 * math.sin(math.radians(20.0))
    assert (v2 - v1) / (2000 * 5e-4) == pytest.approx(a, rel=1e-3)
    v = float(state.particles.velocity[0, 0])
    w = float(state.particles.angular_velocity[0])
    assert v == pytest.approx(-w * 0.5, rel=1e-3)  # rolling: v = -omega r (clockwise spin)


def test_leapfrog_and_velocity_verlet_agree_on_a_settled_disk():
    """Both integrators bring a damped disk to the same rest height mg/kn below r."""
    params = hooke.make_params(kn=1e4, gamma_n=80.0)
    heights = []
    for integrator in ("velocity_verlet", "leapfrog"):
        sim, state = _disk_on_ground(0.5, params=params, dt=1e-3, integrator=integrator)
        state, info = sim.run_until_rest(params, state, speed_tolerance=1e-9, max_steps=20_000, progress=False)
        heights.append(float(state.particles.position[0, 1]))
    assert heights[0] == pytest.approx(heights[1], abs=1e-10)
    assert 0.5 - heights[0] == pytest.approx(1e-4, rel=1e-6)
