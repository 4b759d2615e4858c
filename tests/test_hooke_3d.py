"""The hooke law for spheres: its one kernel, given 3-vectors, against a
transcription of LAMMPS's `gran/hooke/history` and `pair granular` (29Sep2021,
rolling sds) in numpy, and against itself on disks: a pair in the plane z = 0
spinning about z is the disks' pair."""

import numpy as np
import pytest

import jax
import jax.numpy as jnp

from jaxpile.laws import hooke
from jaxpile.laws.base import PairGeometry

EPSILON = 1e-10


def _turn(h, n, test):
    """LAMMPS's frame update: h turned into the plane normal to n, its length kept, where `test(h . n)`."""
    hn = h @ n
    if not test(hn):
        return h
    projected = h - hn * n
    size = np.linalg.norm(projected)
    return projected * (np.linalg.norm(h) / size if size > 0 else 0.0)


def lammps_pair(p, x_i, x_j, v_i, v_j, w_i, w_j, r_i, r_j, m_eff, shear, roll, dt, granular, rolling):
    """One pair's force and torques on i and j and new histories, as LAMMPS computes them."""
    delta = x_i - x_j
    r = np.linalg.norm(delta)
    n = delta / r
    vr = v_i - v_j
    vn = vr @ n
    vt = vr - vn * n
    wr = r_i * w_i + r_j * w_j
    vtr = vt - np.cross(wr, n)
    overlap = r_i + r_j - r
    fn = p["kn"] * overlap - m_eff * p["gamma_n"] * vn
    damping = m_eff * p["gamma_t"]
    cap = p["mu"] * abs(fn)
    shear = shear.copy()
    if granular:
        shear = _turn(shear, n, lambda sn: abs(sn) * p["kt"] > EPSILON * cap)
        shear = shear + vtr * dt
        shrmag = np.linalg.norm(shear)
    else:
        shear = shear + vtr * dt
        shrmag = np.linalg.norm(shear)
        shear = shear - (shear @ n) * n
    fs = -(p["kt"] * shear + damping * vtr)
    size = np.linalg.norm(fs)
    if size > cap:
        if shrmag != 0.0:
            shear = (cap / size) * (shear + damping * vtr / p["kt"]) - damping * vtr / p["kt"]
            fs = fs * cap / size
        else:
            fs = 0.0 * fs
    force = fn * n + fs
    tor = np.cross(n, fs)
    arm_i, arm_j = (r_i - 0.5 * overlap, r_j - 0.5 * overlap) if granular else (r_i, r_j)
    torque_i, torque_j = -arm_i * tor, -arm_j * tor
    if rolling:
        r_eff = r_i * r_j / (r_i + r_j)
        v_roll = r_eff * np.cross(w_i - w_j, n)
        roll_cap = p["mu_roll"] * abs(fn)
        roll = _turn(roll.copy(), n, lambda rn: abs(rn) * p["k_roll"] > EPSILON * roll_cap)
        roll = roll + v_roll * dt
        fr = -p["k_roll"] * roll - p["gamma_roll"] * v_roll
        size = np.linalg.norm(fr)
        if size > roll_cap:
            if np.linalg.norm(roll) != 0.0:
                roll = -(roll_cap * fr / size + p["gamma_roll"] * v_roll) / p["k_roll"]
                fr = fr * roll_cap / size
            else:
                fr = 0.0 * fr
        torque_roll = r_eff * np.cross(n, fr)
        torque_i, torque_j = torque_i + torque_roll, torque_j - torque_roll
    return force, torque_i, torque_j, shear, roll


PARAMS = {"kn": 2.0e4, "kt": 6.0e3, "gamma_n": 30.0, "gamma_t": 12.0, "mu": 0.4,
          "k_roll": 800.0, "gamma_roll": 3.0, "mu_roll": 0.15}


def _random_pairs(rng, count):
    """Touching pairs with random motion and histories (some sliding, some sticking)."""
    out = []
    for _ in range(count):
        r_i, r_j = rng.uniform(0.4, 0.5, 2)
        n = rng.normal(size=3)
        n /= np.linalg.norm(n)
        x_j = rng.normal(size=3)
        x_i = x_j + n * (r_i + r_j) * (1.0 - rng.uniform(0.001, 0.02))
        out.append(dict(x_i=x_i, x_j=x_j, v_i=rng.normal(size=3), v_j=rng.normal(size=3), w_i=rng.normal(size=3),
                        w_j=rng.normal(size=3), r_i=r_i, r_j=r_j, m_eff=rng.uniform(0.2, 0.6),
                        shear=rng.normal(scale=rng.choice([1e-5, 1e-3]), size=3),
                        roll=rng.normal(scale=rng.choice([1e-5, 1e-3]), size=3)))
    return out


@pytest.mark.parametrize("granular, rolling", [(False, False), (True, False), (False, True), (True, True)])
def test_the_sphere_kernel_is_lammps_hooke_history_and_pair_granular_rolling_sds(granular, rolling):
    law = hooke.law(rolling="sds" if rolling else None, pair_style="granular" if granular else "gran/hooke/history")
    params = hooke.make_params(**{k: PARAMS[k] for k in ("kn", "kt", "gamma_n", "gamma_t", "mu")},
                               **({k: PARAMS[k] for k in ("k_roll", "gamma_roll", "mu_roll")} if rolling else {}))
    assert law.history_for(3) == (6 if rolling else 3)
    dt = 1e-3
    kernel = jax.jit(law.pair_force)
    for case in _random_pairs(np.random.default_rng(7), 40):
        g = PairGeometry(displacement=jnp.asarray(case["x_i"] - case["x_j"]), radius_i=jnp.asarray(case["r_i"]),
                         radius_j=jnp.asarray(case["r_j"]), velocity=jnp.asarray(case["v_i"] - case["v_j"]),
                         angular_velocity_i=jnp.asarray(case["w_i"]), angular_velocity_j=jnp.asarray(case["w_j"]),
                         effective_mass=jnp.asarray(case["m_eff"]))
        history = np.concatenate([case["shear"]] + ([case["roll"]] if rolling else []))
        out = kernel(params, g, jnp.asarray(history), dt)
        force, t_i, t_j, shear, roll = lammps_pair(PARAMS, **case, dt=dt, granular=granular, rolling=rolling)
        np.testing.assert_allclose(out.force, force, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(out.torque, t_i, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(out.torque_j, t_j, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(out.history[:3], shear, rtol=1e-12, atol=1e-15)
        if rolling:
            np.testing.assert_allclose(out.history[3:], roll, rtol=1e-12, atol=1e-15)
        assert bool(out.in_contact)


@pytest.mark.parametrize("rolling", [None, "sds", "constant"])
def test_a_sphere_pair_in_the_plane_spinning_about_z_is_the_disks_pair(rolling):
    """The same kernel on disks and on spheres confined to z = 0 with spins
    along z: the same force, torque and history, to round-off."""
    law = hooke.law(rolling=rolling)
    extra = {"sds": {"k_roll": 800.0, "gamma_roll": 3.0, "mu_roll": 0.15}, "constant": {"mu_roll": 0.15}}.get(rolling, {})
    params = hooke.make_params(kn=2.0e4, gamma_n=30.0, mu=0.4, **extra)
    kernel = jax.jit(law.pair_force)
    rng = np.random.default_rng(11)
    for case in _random_pairs(rng, 20):
        flat = {k: (np.array([v[0], v[1], 0.0]) if k in ("x_i", "x_j", "v_i", "v_j", "shear") else v)
                for k, v in case.items()}
        w_i, w_j = case["w_i"][2], case["w_j"][2]
        roll = case["roll"][0]
        d2 = PairGeometry(displacement=jnp.asarray((flat["x_i"] - flat["x_j"])[:2]), radius_i=jnp.asarray(case["r_i"]),
                          radius_j=jnp.asarray(case["r_j"]), velocity=jnp.asarray((flat["v_i"] - flat["v_j"])[:2]),
                          angular_velocity_i=jnp.asarray(w_i), angular_velocity_j=jnp.asarray(w_j),
                          effective_mass=jnp.asarray(case["m_eff"]))
        d3 = d2._replace(displacement=jnp.asarray(flat["x_i"] - flat["x_j"]),
                         velocity=jnp.asarray(flat["v_i"] - flat["v_j"]),
                         angular_velocity_i=jnp.asarray([0.0, 0.0, w_i]), angular_velocity_j=jnp.asarray([0.0, 0.0, w_j]))
        # the disks' rolling entry lies along t = z x n; the spheres' is that vector
        n2 = (flat["x_i"] - flat["x_j"])[:2] / np.linalg.norm((flat["x_i"] - flat["x_j"])[:2])
        t3 = np.array([-n2[1], n2[0], 0.0])
        h2 = np.concatenate([flat["shear"][:2]] + ([[roll]] if rolling else []))
        h3 = np.concatenate([flat["shear"]] + ([roll * t3] if rolling else []))
        a, b = kernel(params, d2, jnp.asarray(h2), 1e-3), kernel(params, d3, jnp.asarray(h3), 1e-3)
        np.testing.assert_allclose(b.force[:2], a.force, rtol=1e-12, atol=1e-13)
        assert abs(float(b.force[2])) < 1e-13
        np.testing.assert_allclose(b.torque, [0.0, 0.0, float(a.torque)], rtol=1e-12, atol=1e-13)
        np.testing.assert_allclose(b.torque_j, [0.0, 0.0, float(a.torque_j)], rtol=1e-12, atol=1e-13)
        np.testing.assert_allclose(b.history[:2], a.history[:2], rtol=1e-12, atol=1e-16)
        if rolling:
            np.testing.assert_allclose(b.history[3:], float(a.history[2]) * t3, rtol=1e-10, atol=1e-16)


@pytest.mark.parametrize("name", ["baxter", "lee-herrmann", "liffman",
                                  "hertz/material 1e7 0.3 0.3 tangential mindlin NULL 1.0 0.5"])
def test_the_paper_laws_and_pair_granular_refuse_spheres_in_one_line(name):
    from jaxpile.errors import InputError
    from jaxpile.laws import get_law_module

    law = get_law_module(name).law()
    assert law.history_for(2) == law.history_size
    with pytest.raises(InputError, match="for disks only"):
        law.history_for(3)
