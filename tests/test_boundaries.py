"""Run-time boundaries: walls switched off/on, gravity tilted, float32 kept."""
import pytest

import jax
import jax.numpy as jnp
import numpy as np

import jaxpile
from jaxpile.engine.boundaries import RIGHT_WALL, set_wall
from jaxpile.laws import hooke
from jaxpile.protocols import lattice
from jaxpile.engine.simulate import Simulator

PARAMS = hooke.make_params(kn=1e4, gamma_n=50.0, mu=0.3)


def test_switching_a_wall_off_at_run_time_releases_the_disk_without_recompiling():
    particles = jaxpile.make_particles([[4.0, 0.5]], 0.5, velocity=[[1.0, 0.0]])
    boundaries = jaxpile.make_boundaries(left=0.0, right=5.0)
    sim = Simulator(hooke.law(), dt=5e-4, chunk_steps=500)
    state = sim.init(PARAMS, particles, boundaries)
    state = sim.run(PARAMS, state, 2000, progress=False)
    assert float(state.particles.position[0, 0]) < 5.0 - 0.5 + 1e-3  # bounced off the right wall
    compiled = len(sim._compiled)
    opened = state.set(boundaries=set_wall(state.boundaries, RIGHT_WALL, active=False))
    opened = opened.set(particles=opened.particles.set(velocity=jnp.array([[1.0, 0.0]])))
    opened = sim.run(PARAMS, opened, 4000, progress=False)
    assert float(opened.particles.position[0, 0]) > 5.0  # passed where the wall was
    assert len(sim._compiled) == compiled
    assert float(jnp.abs(opened.contacts.wall_history[:, RIGHT_WALL]).max()) == 0.0


def test_gravity_tilted_at_run_time_moves_a_frictionless_disk_downhill():
    params = PARAMS.set(mu=jnp.asarray(0.0))
    particles = jaxpile.make_particles([[5.0, 0.5 - 1e-4]], 0.5)
    sim = Simulator(hooke.law(), dt=5e-4)
    state = sim.init(params, particles, jaxpile.make_boundaries())
    state = sim.run(params, state, 200, progress=False)
    assert abs(float(state.particles.position[0, 0]) - 5.0) < 1e-12
    tilted = state.set(boundaries=state.boundaries.set(gravity=jaxpile.engine.boundaries.gravity_vector(1.0, -10.0)))
    tilted = sim.run(params, tilted, 2000, progress=False)
    assert float(tilted.particles.velocity[0, 0]) < -0.1  # tilted the other way: rolls left


def test_float32_states_stay_float32():
    particles, boundaries = lattice.equilateral_pile(4, dtype=jnp.float32)
    params = hooke.make_params(kn=1e4, gamma_n=50.0, mu=0.0, wall_mu=1.0, dtype=jnp.float32)
    sim = Simulator(hooke.law(rotation=False), dt=1e-3)
    state = sim.init(params, particles, boundaries)
    state = sim.run(params, state, 500, progress=False)
    dtypes = {x.dtype for x in jax.tree.leaves(state) if jnp.issubdtype(x.dtype, jnp.floating)}
    assert dtypes == {jnp.dtype(jnp.float32)}
    assert np.all(np.isfinite(np.asarray(state.particles.position)))


def test_ground_alone_has_one_wall_and_refuses_side_walls():
    from jaxpile.engine.boundaries import make_boundaries
    from jaxpile.errors import InputError

    ground = make_boundaries(sides=False, ground=0.5)
    assert ground.wall_normal.shape == (1, 2) and bool(ground.wall_active[0])
    assert float(ground.wall_offset[0]) == 0.5
    with pytest.raises(InputError, match="sides=False"):
        make_boundaries(sides=False, left=0.0)
    with pytest.raises(InputError, match="wall 2 does not exist"):
        set_wall(ground, RIGHT_WALL, active=True)  # would be clamped onto the ground by JAX
