"""Calibrating to a measurement: the base every protocol stands on (`jaxpile.base_forces`)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxpile as jp
from jaxpile.errors import InputError
from jaxpile.measure import analysis


@pytest.fixture(scope="module")
def poured():
    """A 12-disk heap poured onto 15 fixed disks (the pour's CLI test pile)."""
    jp.configure()
    return jp.run("pour", "baxter", 12, release_height=8.0, substrate_disks=15, speed_tolerance=1e-3)


def test_base_forces_of_a_poured_heap_are_its_fixed_row_contacts(poured):
    base = jp.base_forces(poured.simulator, poured.params, poured.state)
    row = analysis.substrate_forces(poured.simulator, poured.params, poured.state)
    assert base.x.size == row.x.size > 0
    np.testing.assert_array_equal(base.particle, row.particle)
    np.testing.assert_allclose(base.normal, row.normal, rtol=1e-12)
    # at rest the row carries the heap's weight (its force balance), in mg
    assert abs(base.normal.sum() / poured.measurements["weight"] - 1.0) < 1e-2
    with pytest.raises(InputError, match="no active wall"):  # its floor wall is switched off: a reading of none
        jp.base_forces(poured.simulator, poured.params, poured.state, base="ground")


def test_base_forces_refuse_a_set_up_without_a_base():
    particles = jp.make_particles(np.array([[0.0, 2.0], [1.0, 2.0]]), np.array([0.5, 0.5]))
    boundaries = jp.set_wall(jp.make_boundaries(sides=False), 0, active=False)
    from jaxpile.laws import hooke

    sim = jp.Simulator(hooke.law(), dt=1e-4)
    params = hooke.make_params(kn=1e4)
    state = sim.init(params, particles, boundaries)
    with pytest.raises(InputError, match="neither an active floor wall nor fixed disks"):
        jp.base_forces(sim, params, state)


def test_grad_of_a_poured_heaps_base_force_matches_central_differences(poured):
    """On a deterministic window (200 steps of relaxation from the settled heap)."""
    sim, state = poured.simulator, poured.state

    def peak(mu):
        p = poured.params.set(mu=mu)
        return jp.base_forces(sim, p, sim.rollout(p, state, 200)).normal.max()

    mu, h = jnp.asarray(float(poured.params.mu)), 1e-5
    exact = float(jax.grad(peak)(mu))
    value = jax.jit(peak)
    central = float((value(mu + h) - value(mu - h)) / (2 * h))
    assert abs(exact - central) <= 1e-6 * max(abs(central), 1e-3)
    # the traced reading is the eager one with padding: the same largest force
    eager = jp.base_forces(sim, poured.params, sim.rollout(poured.params, state, 200))
    assert float(value(mu)) == pytest.approx(float(eager.normal.max()), rel=1e-12)
