"""The engine with spheres: one code path for d = 2 and d = 3. A pile of disks
is a pile of spheres confined to the plane z = 0 with spins about z; spheres
settle in a box of walls and carry their weight; a 3D run resumes bit for bit
from its checkpoint; a gradient through a 3D rollout matches central
differences."""

import numpy as np
import pytest

import jax
import jax.numpy as jnp

from jaxpile.engine import checkpoint
from jaxpile.engine.boundaries import make_boundaries
from jaxpile.engine.simulate import Simulator, max_speed
from jaxpile.engine.state import Boundaries, make_particles
from jaxpile.errors import InputError
from jaxpile.laws import baxter, hooke
from jaxpile.measure.forces import base_forces

PARAMS = dict(kn=2.0e4, gamma_n=30.0, mu=0.4, k_roll=500.0, gamma_roll=2.0, mu_roll=0.1)


def _disks(rng, n=24, columns=6):
    pos = np.stack([0.6 + 1.05 * (np.arange(n) % columns) + 0.1 * rng.uniform(size=n),
                    0.6 + 1.05 * (np.arange(n) // columns) + 0.1 * rng.uniform(size=n)], 1)
    return pos, 0.5 - 0.06 * rng.uniform(size=n), 0.3 * rng.normal(size=(n, 2)), 0.5 * rng.normal(size=n)


@pytest.fixture(scope="module")
def sim3():
    """One simulator for the sphere tests (hooke with its history and rolling sds)."""
    return Simulator(hooke.law(rolling="sds"), 1e-3), hooke.make_params(**PARAMS)


def _box_of_spheres(rng, n=40, side=4.6):
    g = np.stack(np.meshgrid(np.arange(4), np.arange(4), np.arange(3), indexing="ij"), -1).reshape(-1, 3)[:n]
    pos = 0.6 + 1.1 * g + 0.05 * rng.uniform(size=(n, 3))
    p = make_particles(pos, 0.5 - 0.05 * rng.uniform(size=n), velocity=0.3 * rng.normal(size=(n, 3)),
                       angular_velocity=rng.normal(size=(n, 3)))
    return p, make_boundaries(left=0.0, right=side, front=0.0, back=side, dim=3)


def test_spheres_get_volume_masses_sphere_inertia_and_spin_vectors():
    p = make_particles([[0.0, 0.0, 0.5], [2.0, 0.0, 0.5]], [0.5, 0.25])
    assert p.dim == 3 and p.angular_velocity.shape == (2, 3) and p.torque.shape == (2, 3)
    np.testing.assert_allclose(p.mass, [1.0, 0.125])  # diameter 1 has mass 1; mass goes as r^3
    np.testing.assert_allclose(p.inertia, 0.4 * np.asarray(p.mass) * np.asarray(p.radius) ** 2)
    with pytest.raises(InputError, match="must have shape"):
        make_particles([[0.0, 0.0, 0.5]], 0.5, angular_velocity=[1.0])
    b = make_boundaries(dim=3)
    np.testing.assert_allclose(b.gravity, [0.0, 0.0, -1.0])
    with pytest.raises(InputError, match="make_boundaries\\(dim=3\\)"):
        Simulator(hooke.law(), 1e-3).init(hooke.make_params(), p, make_boundaries())
    with pytest.raises(InputError, match="for disks only"):
        Simulator(baxter.law(), 1e-4).init(baxter.make_params(), p, b)


def test_a_disk_pile_is_a_sphere_pile_in_the_plane_z0_spinning_about_z():
    """The same law, integrator and walls on disks and on spheres confined to
    z = 0 (gravity along -y, spins along z, a disk's inertia): the same
    trajectory to round-off (the pair order differs: the sums round apart)."""
    pos, rad, vel, omega = _disks(np.random.default_rng(5))
    n = len(rad)
    law, params, dt = hooke.law(rolling="sds"), hooke.make_params(**PARAMS), 1e-3
    d2 = make_particles(pos, rad, velocity=vel, angular_velocity=omega)
    walls2 = make_boundaries(left=0.0, right=6.6)
    zero = np.zeros((n, 1))
    spin = np.concatenate([zero, zero, omega[:, None]], 1)
    d3 = make_particles(np.concatenate([pos, zero], 1), rad, mass=np.asarray(d2.mass),
                        velocity=np.concatenate([vel, zero], 1), angular_velocity=spin)
    d3 = d3.set(inertia=d2.inertia)
    pad = lambda a: jnp.concatenate([jnp.asarray(a), jnp.zeros(a.shape[:-1] + (1,), a.dtype)], -1)
    walls3 = Boundaries(gravity=pad(walls2.gravity), wall_normal=pad(walls2.wall_normal),
                        wall_offset=walls2.wall_offset, wall_active=walls2.wall_active)
    a = Simulator(law, dt).run(params, Simulator(law, dt).init(params, d2, walls2), 600, progress=False)
    sim = Simulator(law, dt)
    b = sim.run(params, sim.init(params, d3, walls3), 600, progress=False)
    pa, pb = a.particles, b.particles
    np.testing.assert_allclose(pb.position[:, :2], pa.position, atol=1e-10)
    np.testing.assert_allclose(pb.velocity[:, :2], pa.velocity, atol=1e-9)
    np.testing.assert_allclose(pb.angular_velocity[:, 2], pa.angular_velocity, atol=1e-8)
    np.testing.assert_array_equal(pb.position[:, 2], 0.0)
    np.testing.assert_array_equal(pb.angular_velocity[:, :2], 0.0)


def test_spheres_settle_in_a_box_and_floor_and_walls_carry_their_weight(sim3):
    sim, params = sim3
    p, b = _box_of_spheres(np.random.default_rng(0))
    state = sim.run(params, sim.init(params, p, b), 16_000, progress=False)
    x, r = np.asarray(state.particles.position), np.asarray(state.particles.radius)
    assert float(max_speed(state)) < 0.05
    # inside the box, the lowest resting on the floor with a small overlap
    assert (x[:, 0] - r > -0.02).all() and (x[:, 0] + r < 4.62).all() and (x[:, 1] - r > -0.02).all()
    assert (x[:, 2] - r > -0.01).all() and (x[:, 2] - r < 0.01).any()
    d = x[:, None] - x[None]
    gap = np.linalg.norm(d, axis=-1) - (r[:, None] + r[None])
    np.fill_diagonal(gap, 1.0)
    assert gap.min() > -0.02
    # the vertical load on the floor and the side walls' friction carry the weight (at near rest)
    cf = sim.contact_forces(params, state)
    vertical = float(np.asarray(cf.wall.force)[..., 2].sum())
    weight = float(np.asarray(state.particles.mass).sum())
    assert abs(vertical / weight - 1.0) < 0.02
    floor = base_forces(sim, params, state, base="ground")
    assert 0.8 < floor.normal.sum() * float(np.mean(np.asarray(state.particles.mass))) / weight <= 1.02


def test_a_sphere_run_resumes_bit_for_bit_from_its_checkpoint(sim3, tmp_path):
    sim, params = sim3
    p, b = _box_of_spheres(np.random.default_rng(1))
    start = sim.init(params, p, b)
    path = str(tmp_path / "ck-{step}.npz")
    whole = sim.run(params, start, 3000, progress=False, checkpoint=(path, 1000))
    resumed = checkpoint.restore(tmp_path / "ck-1000.npz", sim.init(params, p, b), "hooke", params)
    resumed = sim.run(params, resumed, 2000, progress=False)
    for u, v in zip(jax.tree_util.tree_leaves(resumed), jax.tree_util.tree_leaves(whole)):
        assert np.array_equal(np.asarray(u), np.asarray(v))


def test_the_gradient_through_a_sphere_rollout_matches_central_differences():
    """d(final height of the top sphere)/d(k_n) and d/d(mu) through 300 steps
    of two spheres in an oblique, spinning collision above a floor."""
    law = hooke.law()
    sim = Simulator(law, 1e-3)
    p = make_particles([[1.0, 1.0, 0.5], [1.35, 1.2, 1.35]], [0.5, 0.45], velocity=[[0.0, 0.0, 0.0], [0.2, 0.1, -0.6]],
                       angular_velocity=[[0.0, 0.0, 0.0], [1.0, -2.0, 0.5]])
    b = make_boundaries(dim=3)
    base = hooke.make_params(kn=5e3, gamma_n=10.0, mu=0.3)
    state = sim.init(base, p, b)

    def height(kn, mu):
        end = sim.rollout(base.set(kn=kn, mu=mu), state, 300)
        return end.particles.position[1, 2] + 0.1 * end.particles.angular_velocity[1, 0]

    kn, mu = jnp.asarray(5e3), jnp.asarray(0.3)
    g_kn, g_mu = jax.jit(jax.grad(height, argnums=(0, 1)))(kn, mu)
    f = jax.jit(height)
    h_kn, h_mu = 1.0, 1e-5
    fd_kn = (f(kn + h_kn, mu) - f(kn - h_kn, mu)) / (2 * h_kn)
    fd_mu = (f(kn, mu + h_mu) - f(kn, mu - h_mu)) / (2 * h_mu)
    assert abs(float(g_kn)) > 0 and abs(float(g_mu)) > 0
    np.testing.assert_allclose(g_kn, fd_kn, rtol=1e-5)
    np.testing.assert_allclose(g_mu, fd_mu, rtol=1e-5)
