"""The hooke kernel against the LAMMPS gran/hooke/history formulas, one pair at a time."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxpile.laws import hooke
from jaxpile.laws.base import PairGeometry

P = hooke.make_params(kn=1000.0, kt=400.0, gamma_n=10.0, gamma_t=4.0, mu=0.5)


def geometry(d=(0.95, 0.0), v=(0.0, 0.0), wi=0.0, wj=0.0, ri=0.5, rj=0.5, meff=0.5):
    f = lambda x: jnp.asarray(x, jnp.float64)
    return PairGeometry(f(d), f(ri), f(rj), f(v), f(wi), f(wj), f(meff))


def test_normal_spring_and_dashpot():
    # overlap 0.05, approaching at v.n = -0.2: F_n = kn delta - meff gamma_n v.n
    out = hooke.pair_force(P, geometry(v=(-0.2, 0.0)), jnp.zeros(2), 0.0)
    assert out.in_contact
    np.testing.assert_allclose(out.normal, 1000 * 0.05 + 0.5 * 10 * 0.2, rtol=1e-12)
    np.testing.assert_allclose(out.force, [out.normal, 0.0], atol=1e-12)


def test_no_force_when_apart_and_history_cleared():
    out = hooke.pair_force(P, geometry(d=(1.01, 0.0), v=(0.0, 0.3)), jnp.array([0.0, 0.01]), 1e-3)
    assert not out.in_contact
    np.testing.assert_array_equal(out.force, 0.0)
    np.testing.assert_array_equal(out.history, 0.0)


def test_tangential_spring_grows_with_shear_then_saturates_at_mu_fn():
    """Cundall-Strack: F_t = -k_t s while |F_t| < mu F_n, then capped at mu F_n."""
    step = jax.jit(lambda s: hooke.pair_force(P, geometry(v=(0.0, 1.0)), s, 1e-3))
    shear = jnp.zeros(2)
    ft = []
    for _ in range(400):
        out = step(shear)
        shear = out.history
        ft.append(-out.force[1])
    ft = np.array(ft)
    fn = 1000 * 0.05
    cap = 0.5 * fn
    # growing part: k_t s + m_eff gamma_t v with s = (steps) v dt
    np.testing.assert_allclose(ft[:10], 400 * np.arange(1, 11) * 1e-3 + 0.5 * 4 * 1.0, rtol=1e-12)
    assert np.all(np.diff(ft) >= -1e-12)
    np.testing.assert_allclose(ft[-50:], cap, rtol=1e-12)
    # LAMMPS rescale: k_t s + m_eff gamma_t v_t sits exactly on the Coulomb circle
    np.testing.assert_allclose(400 * shear[1] + 0.5 * 4 * 1.0, cap, rtol=1e-12)


def test_coulomb_cap_uses_normal_force_with_damping():
    # separating fast: F_n = kn delta - meff gamma_n v_n is reduced by damping
    g = geometry(v=(0.5, 1.0))
    out = hooke.pair_force(P, g, jnp.array([0.0, 0.2]), 1e-3)
    fn = 1000 * 0.05 - 0.5 * 10 * 0.5
    np.testing.assert_allclose(out.normal, fn, rtol=1e-12)
    np.testing.assert_allclose(abs(out.force[1]), 0.5 * abs(fn), rtol=1e-12)


def test_spin_enters_contact_velocity_and_torque_opposes_it():
    # i spinning counter-clockwise touching j on its right (n = -x from j to i... d = x_i - x_j)
    g = geometry(d=(-0.95, 0.0), wi=2.0)  # i to the left of j; contact point of i is on its right
    out = hooke.pair_force(P, g, jnp.zeros(2), 1e-3)
    # contact point of i moves with omega x r = 2 * 0.5 upward (+y): friction on i points down
    assert out.force[1] < 0
    # and its torque slows the spin
    assert out.torque < 0


def test_wall_params_default_to_disk_values_and_override():
    p = hooke.make_params(kn=10.0, mu=0.3, wall_mu=0.9)
    w = hooke.wall_params(p)
    assert float(w.kn) == 10.0 and float(w.mu) == 0.9 and float(w.kt) == pytest.approx(20 / 7)
    # a gradient with respect to the disk kn flows into the wall's kn
    g = jax.grad(lambda q: hooke.wall_params(q).kn * 2.0)(p)
    assert float(g.kn) == 2.0
