"""The host runner: re-allocation from almost empty lists, re-use of one
Simulator for different systems, schedules, inactive and fixed disks."""

import jax.numpy as jnp
import numpy as np
import pytest

import jaxpile
from jaxpile.laws import hooke
from jaxpile.engine.simulate import Simulator, gravity_ramp

PARAMS = hooke.make_params(kn=1e4, gamma_n=50.0, mu=0.3)
NO_WALLS = jnp.array([False, False, False])


def _converging_grid(spacing=1.5, speed=1.0):
    """16 disks 1.5 diameters apart (no neighbours at allocation) all moving
    towards the centre: the list must grow from almost nothing."""
    g = np.stack(np.meshgrid(np.arange(4), np.arange(4)), -1).reshape(-1, 2) * spacing + 3.0
    centre = g.mean(axis=0)
    v = speed * (centre - g) / (np.linalg.norm(centre - g, axis=1, keepdims=True) + 1e-12)
    particles = jaxpile.make_particles(g, 0.5, velocity=v)
    return particles, jaxpile.make_boundaries(gravity=0.0).set(wall_active=NO_WALLS)


def test_reallocation_grows_from_an_almost_empty_list_within_one_chunk():
    particles, boundaries = _converging_grid()
    # sized for the disks as they start (packed_lists=False), the list must grow
    sim = Simulator(hooke.law(), dt=5e-4, chunk_steps=2000, packed_lists=False)
    state = sim.init(PARAMS, particles, boundaries)
    info = jaxpile.RunInfo()
    state = sim.run(PARAMS, state, 2000, progress=False, info=info)
    assert info.reallocations >= 1
    # same answer as a list that was big enough from the start
    ample = Simulator(hooke.law(), dt=5e-4, chunk_steps=2000, capacity_multiplier=1.0)
    ref = ample.init(PARAMS, particles, boundaries)
    big = jaxpile.engine.neighbors.allocate(ref.neighbor_settings, ref.particles.position, extra_capacity=15)
    pairs = jaxpile.engine.pairs.half_pairs(big.idx)
    ref = ref.set(neighbors=big, contacts=ref.contacts.set(
        pairs=pairs, history=jnp.zeros((pairs.shape[0], 2), ref.particles.position.dtype)))
    ref = ample.run(PARAMS, ref, 2000, progress=False)
    np.testing.assert_allclose(state.particles.position, ref.particles.position, atol=1e-9)


def test_one_simulator_serves_two_different_systems():
    sim = Simulator(hooke.law(), dt=2e-4, chunk_steps=500)
    a_particles = jaxpile.make_particles([[2.0, 2.0], [2.99, 2.0]], 0.5, velocity=[[0.5, 0.0], [-0.5, 0.0]])
    b_particles = jaxpile.make_particles([[2.0, 2.0], [2.3, 2.0]], 0.1)
    boundaries = jaxpile.make_boundaries(gravity=0.0).set(wall_active=NO_WALLS)
    a = sim.init(PARAMS, a_particles, boundaries)
    sim.init(PARAMS, b_particles, boundaries)  # a different cutoff and box
    a = sim.run(PARAMS, a, 1000, progress=False)
    fresh = Simulator(hooke.law(), dt=2e-4, chunk_steps=500)
    ref = fresh.run(PARAMS, fresh.init(PARAMS, a_particles, boundaries), 1000, progress=False)
    np.testing.assert_allclose(a.particles.velocity, ref.particles.velocity, rtol=1e-12)
    assert float(jnp.abs(a.particles.velocity).max()) < 1.0  # they bounced, not passed through


def test_repeated_init_with_the_same_shapes_does_not_recompile():
    sim = Simulator(hooke.law(), dt=5e-4)
    particles, boundaries = _converging_grid(spacing=1.2, speed=0.0)
    for _ in range(3):
        state = sim.init(PARAMS, particles, boundaries)
        sim.run(PARAMS, state, 10, progress=False)
    assert len(sim._compiled) == 1


def test_initial_force_and_steps_follow_the_schedule():
    particles = jaxpile.make_particles([[3.0, 5.0]], 0.5)
    sim = Simulator(hooke.law(), dt=1e-3, schedule=gravity_ramp(100))
    state = sim.init(PARAMS, particles, jaxpile.make_boundaries())
    np.testing.assert_array_equal(state.particles.force, 0.0)  # gravity ramp starts at zero
    state = sim.run(PARAMS, state, 100, progress=False)
    np.testing.assert_allclose(state.particles.force, [[0.0, -1.0]])  # and is complete at step 100
    # free fall under the smoothstep ramp: v(T) = -g T / 2
    assert float(state.particles.velocity[0, 1]) == pytest.approx(-0.05, rel=1e-3)


def test_inactive_disks_neither_push_nor_move():
    particles = jaxpile.make_particles([[3.0, 0.5], [3.5, 0.6]], 0.5, active=[True, False])
    sim = Simulator(hooke.law(), dt=5e-4)
    state = sim.init(PARAMS, particles, jaxpile.make_boundaries())
    state = sim.run(PARAMS, state, 500, progress=False)
    np.testing.assert_array_equal(state.particles.position[1], [3.5, 0.6])
    assert abs(float(state.particles.position[0, 0]) - 3.0) < 1e-12  # not pushed sideways


def test_fixed_disk_is_an_infinitely_heavy_partner_like_the_ground():
    """A disk dropped on a fixed disk rebounds exactly as from the ground (m_eff = m
    for both), damping included."""
    params = hooke.make_params(kn=1e4, gamma_n=40.0, mu=0.0)
    # the gap (0.10003) is not a multiple of v dt: contact starts mid-step in both
    # cases, not on a step boundary where round-off would pick the step
    on_ground = jaxpile.make_particles([[3.0, 0.60003]], 0.5, velocity=[[0.0, -1.0]])
    sim = Simulator(hooke.law(), dt=2e-4)
    g = sim.run(params, sim.init(params, on_ground, jaxpile.make_boundaries(gravity=0.0)), 1000, progress=False)
    on_disk = jaxpile.make_particles([[3.0, 5.0], [3.0, 6.10003]], 0.5, velocity=[[0.0, 0.0], [0.0, -1.0]],
                                     fixed=[True, False])
    boundaries = jaxpile.make_boundaries(gravity=0.0).set(wall_active=NO_WALLS)
    d = sim.run(params, sim.init(params, on_disk, boundaries), 1000, progress=False)
    v_ground = float(g.particles.velocity[0, 1])
    assert 0.1 < v_ground < 1.0  # rebounded, with a restitution below one
    assert float(d.particles.velocity[1, 1]) == pytest.approx(v_ground, rel=1e-9)


def test_driver_pours_disks_and_removes_a_wall_inside_one_compiled_chunk():
    """A driver (persistent `state -> state` before every step) activates a
    parked disk every 200 steps above the first and switches the right wall off
    at step 500, all inside one compiled chunk: the active disks and the wall
    follow the driver, and parked disks stay where they were parked."""
    from jaxpile.protocols import drivers

    n = 4
    parked = np.stack([np.arange(n) * 3.0 + 20.0, np.full(n, 30.0)], axis=1)
    parked[0] = [3.0, 0.5]
    active = np.zeros(n, bool)
    active[0] = True
    particles = jaxpile.make_particles(parked, 0.5, active=active)
    boundaries = jaxpile.make_boundaries(left=0.0, right=6.0)

    def pour(state):
        index, any_left = drivers.next_inactive(state)
        due = (state.step % 200 == 0) & (state.step > 0) & any_left
        drop = jnp.stack([jnp.asarray(3.0), 0.6 + 1.2 * index])  # above the ones already in
        return drivers.activate(state, index, drop, when=due)

    sim = Simulator(hooke.law(), dt=5e-4, chunk_steps=1000,
                    driver=drivers.compose(pour, drivers.switch_wall_at(500, jaxpile.engine.boundaries.RIGHT_WALL)))
    state = sim.init(PARAMS, particles, boundaries, box=(40.0, 40.0))
    state = sim.run(PARAMS, state, 1000, progress=False)
    p = state.particles
    assert np.asarray(p.active).tolist() == [True, True, True, True]
    assert not bool(state.boundaries.wall_active[jaxpile.engine.boundaries.RIGHT_WALL])
    assert bool(state.boundaries.wall_active[jaxpile.engine.boundaries.LEFT_WALL])
    y = np.asarray(p.position)[:, 1]
    assert np.all(np.diff(y[:3]) < 1.3)  # the first three landed on one another
    assert float(p.velocity[3, 1]) < -0.1  # the last one, poured at step 600, is falling
    never_poured = drivers.activate(state, 0, jnp.zeros(2), when=False)
    np.testing.assert_array_equal(never_poured.particles.position, p.position)
