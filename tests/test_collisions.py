"""Hard-disk collision operator (Liffman, Chan & Hughes 1992, eqs. 1-22).

The reference quantities here are computed independently of the kernel: cross
products in 3D with numpy from the position vectors r_i = x_i - Q of the paper,
and the printed eqs. (12) and (16) with eqs. (17)-(18).
"""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxpile  # noqa: F401  (float64 on)
from jaxpile.engine.collisions import CollisionResult, check_collision_inputs, collide, needs_soft_contact
from jaxpile.errors import InputError

collide_jit = jax.jit(collide)
collide_batch = jax.jit(jax.vmap(collide))
KEYS = ("m1", "m2", "I1", "I2", "r1", "r2", "x1", "x2", "c1", "c2", "w1", "w2", "restitution", "mu")


def random_pair(rng, restitution=None, mu=None, approaching=True):
    """A touching pair of unequal disks (any I), oblique impact, with spins."""
    m1, m2 = rng.uniform(0.5, 3.0, 2)
    r1, r2 = rng.uniform(0.3, 1.5, 2)
    I1, I2 = m1 * r1**2 / 2 * rng.uniform(0.5, 1.5), m2 * r2**2 / 2 * rng.uniform(0.5, 1.5)
    th = rng.uniform(0, 2 * np.pi)
    n = np.array([np.cos(th), np.sin(th)])
    x1 = rng.uniform(-2, 2, 2)
    x2 = x1 + (r1 + r2) * n
    c1, c2 = rng.uniform(-2, 2, 2), rng.uniform(-2, 2, 2)
    gn = (c1 - c2) @ n
    want = rng.uniform(0.1, 2.0) * (1 if approaching else -1)
    c1 = c1 + (want - gn) * n
    return dict(m1=m1, m2=m2, I1=I1, I2=I2, r1=r1, r2=r2, x1=x1, x2=x2, c1=c1, c2=c2,
                w1=rng.uniform(-3, 3), w2=rng.uniform(-3, 3),
                restitution=rng.uniform(0, 1) if restitution is None else restitution,
                mu=rng.uniform(0, 2) if mu is None else mu)


def run(case) -> CollisionResult:
    out = collide_jit(**case)
    return CollisionResult(*(np.asarray(a) for a in out))


def frame(case):
    x1, x2 = np.asarray(case["x1"]), np.asarray(case["x2"])
    n = (x2 - x1) / np.linalg.norm(x2 - x1)
    t = np.array([-n[1], n[0]])
    assert np.isclose(np.cross(np.r_[n, 0], np.r_[t, 0])[2], 1.0)  # z = n x t (Fig. 1)
    q = x1 + case["r1"] * n
    return n, t, q


def cross2(a, b):
    return a[0] * b[1] - a[1] * b[0]


def r_cross_w(r, w):
    """(r x w z) as a 2D vector, from the 3D cross product."""
    return np.cross(np.r_[r, 0.0], np.array([0.0, 0.0, w]))[:2]


def contact_velocity(case, c1, c2, w1, w2):
    """Eq. (9): c_12c = c1 + r1 x w1 - c2 - r2 x w2 with r_i = x_i - Q."""
    _, _, q = frame(case)
    return c1 + r_cross_w(case["x1"] - q, w1) - c2 - r_cross_w(case["x2"] - q, w2)


def kinetic_energy(case, c1, c2, w1, w2):
    return (0.5 * case["m1"] * c1 @ c1 + 0.5 * case["m2"] * c2 @ c2
            + 0.5 * case["I1"] * w1**2 + 0.5 * case["I2"] * w2**2)


CASES = [random_pair(np.random.default_rng(s)) for s in range(12)]
# both branches of eq. (19) among the cases
CASES += [random_pair(np.random.default_rng(100 + s), mu=0.05) for s in range(4)]
CASES += [random_pair(np.random.default_rng(200 + s), mu=10.0) for s in range(4)]


@pytest.mark.parametrize("case", CASES)
def test_eq1_linear_momentum_conserved(case):
    out = run(case)
    before = case["m1"] * case["c1"] + case["m2"] * case["c2"]
    after = case["m1"] * out.c1 + case["m2"] * out.c2
    np.testing.assert_allclose(after, before, rtol=1e-12, atol=1e-12 * np.abs(before).max())
    np.testing.assert_allclose(out.impulse, case["m1"] * (out.c1 - case["c1"]), rtol=1e-12, atol=1e-14)  # eq. (6)


@pytest.mark.parametrize("case", CASES)
def test_eq2_eq3_angular_momentum_about_contact_point(case):
    out = run(case)
    _, _, q = frame(case)
    for x, m, I, c, w, cs, ws, p in (
        (case["x1"], case["m1"], case["I1"], case["c1"], case["w1"], out.c1, out.w1, out.impulse),
        (case["x2"], case["m2"], case["I2"], case["c2"], case["w2"], out.c2, out.w2, -out.impulse),
    ):
        r = x - q
        # eqs. (2)/(3): m r x c + I w unchanged about Q
        np.testing.assert_allclose(m * cross2(r, cs) + I * ws, m * cross2(r, c) + I * w, rtol=1e-12, atol=1e-12)
        # torque impulse of P_i applied at Q about the centre: I dw = (Q - x) x P_i
        np.testing.assert_allclose(I * (ws - w), cross2(q - x, p), rtol=1e-12, atol=1e-12)
    # total angular momentum about the origin (touching disks)
    def total(c1, c2, w1, w2):
        return (case["m1"] * cross2(case["x1"], c1) + case["m2"] * cross2(case["x2"], c2)
                + case["I1"] * w1 + case["I2"] * w2)
    np.testing.assert_allclose(total(out.c1, out.c2, out.w1, out.w2),
                               total(case["c1"], case["c2"], case["w1"], case["w2"]), rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("eps", [0.0, 0.3, 0.8, 1.0])
def test_eq4_eq12_normal_impulse_gives_restitution(eps):
    for s in range(5):
        case = random_pair(np.random.default_rng(300 + s), restitution=eps)
        out = run(case)
        n, _, _ = frame(case)
        before = (case["c1"] - case["c2"]) @ n
        np.testing.assert_allclose((out.c1 - out.c2) @ n, -eps * before, rtol=1e-12, atol=1e-13)
        m1, m2 = case["m1"], case["m2"]
        pn_paper = m1 * m2 / (m1 + m2) * (1 + eps) * (case["c2"] - case["c1"]) @ n  # eq. (12)
        np.testing.assert_allclose(out.impulse @ n, pn_paper, rtol=1e-12)
        assert out.impulse @ n < 0  # disk 1 is pushed back, away from disk 2


def test_eq12_head_on_equal_masses_exchange_velocities():
    case = dict(m1=1.0, m2=1.0, I1=0.5, I2=0.5, r1=1.0, r2=1.0, x1=np.zeros(2), x2=np.array([2.0, 0.0]),
                c1=np.array([1.0, 0.0]), c2=np.array([-0.5, 0.0]), w1=0.0, w2=0.0, restitution=1.0, mu=0.5)
    out = run(case)
    np.testing.assert_allclose(out.c1, [-0.5, 0.0], atol=1e-15)
    np.testing.assert_allclose(out.c2, [1.0, 0.0], atol=1e-15)
    assert out.w1 == 0 and out.w2 == 0 and not out.slipping


@pytest.mark.parametrize("case", [random_pair(np.random.default_rng(400 + s), mu=50.0) for s in range(8)])
def test_eq8_eq16_noslip_zeroes_tangential_contact_velocity(case):
    out = run(case)
    n, t, q = frame(case)
    assert not out.slipping
    g_after = contact_velocity(case, out.c1, out.c2, out.w1, out.w2)
    g_before = contact_velocity(case, case["c1"], case["c2"], case["w1"], case["w2"])
    assert abs(g_after @ t) < 1e-12 * (1 + abs(g_before @ t))  # eq. (8)
    # eqs. (17)-(18) and the printed eq. (16)
    r1v, r2v = case["x1"] - q, case["x2"] - q
    np.testing.assert_allclose(r_cross_w(r2v, case["w2"]) @ t, -case["r2"] * case["w2"], atol=1e-14)
    np.testing.assert_allclose(r_cross_w(r1v, case["w1"]) @ t, case["r1"] * case["w1"], atol=1e-14)
    m1, m2, I1, I2, r1, r2 = (case[k] for k in ("m1", "m2", "I1", "I2", "r1", "r2"))
    num = m1 * (case["c2"] - case["c1"] + r_cross_w(r2v, case["w2"]) - r_cross_w(r1v, case["w1"])) @ t
    pt16 = num / (1 + m1 / m2 + m1 * r2**2 / I2 + m1 * r1**2 / I1)
    np.testing.assert_allclose(out.impulse @ t, pt16, rtol=1e-12, atol=1e-14)


@pytest.mark.parametrize("seed", range(6))
def test_eq7_slip_tangential_impulse_is_mu_times_normal(seed):
    case = random_pair(np.random.default_rng(500 + seed), mu=0.1)
    n, t, _ = frame(case)
    case["c1"] = case["c1"] + (5.0 if seed % 2 else -5.0) * t  # large tangential slip, either sign
    out = run(case)
    assert out.slipping
    pn, pt = out.impulse @ n, out.impulse @ t
    np.testing.assert_allclose(abs(pt), 0.1 * abs(pn), rtol=1e-12)
    gt0 = contact_velocity(case, case["c1"], case["c2"], case["w1"], case["w2"]) @ t
    gt1 = contact_velocity(case, out.c1, out.c2, out.w1, out.w2) @ t
    assert np.sign(pt) == -np.sign(gt0)  # friction opposes the slip
    assert np.sign(gt1) == np.sign(gt0) and abs(gt1) < abs(gt0)  # reduced, not reversed


def test_eq19_branch_switches_at_noslip_threshold():
    case = random_pair(np.random.default_rng(7), mu=1e6)
    n, t, _ = frame(case)
    stick = run(case)
    mu_star = abs(stick.impulse @ t) / abs(stick.impulse @ n)
    lo, hi = run({**case, "mu": 0.9 * mu_star}), run({**case, "mu": 1.1 * mu_star})
    assert lo.slipping and not hi.slipping
    np.testing.assert_allclose(lo.impulse @ t, 0.9 * stick.impulse @ t, rtol=1e-12)
    np.testing.assert_allclose(hi.impulse, stick.impulse, rtol=1e-13)


def batch(cases):
    return {k: jnp.asarray(np.stack([np.asarray(c[k], dtype=float) for c in cases])) for k in KEYS}


def test_energy_never_increases_random():
    rng = np.random.default_rng(2024)
    cases = [random_pair(rng) for _ in range(200)]
    out = collide_batch(**batch(cases))
    assert 0 < int(np.sum(out.slipping)) < 200  # both branches sampled
    for i, case in enumerate(cases):
        e0 = kinetic_energy(case, case["c1"], case["c2"], case["w1"], case["w2"])
        e1 = kinetic_energy(case, *(np.asarray(a[i]) for a in (out.c1, out.c2, out.w1, out.w2)))
        assert e1 <= e0 * (1 + 1e-12), (i, e0, e1)


def test_energy_conserved_elastic_frictionless():
    rng = np.random.default_rng(11)
    for _ in range(20):
        case = random_pair(rng, restitution=1.0, mu=0.0)
        out = run(case)
        e0 = kinetic_energy(case, case["c1"], case["c2"], case["w1"], case["w2"])
        np.testing.assert_allclose(kinetic_energy(case, out.c1, out.c2, out.w1, out.w2), e0, rtol=1e-12)
        assert out.w1 == case["w1"] and out.w2 == case["w2"]


@pytest.mark.parametrize("seed", range(5))
def test_separating_pair_unchanged(seed):
    case = random_pair(np.random.default_rng(600 + seed), approaching=False)
    out = run(case)
    np.testing.assert_array_equal(out.c1, case["c1"])
    np.testing.assert_array_equal(out.c2, case["c2"])
    assert out.w1 == case["w1"] and out.w2 == case["w2"]
    np.testing.assert_array_equal(out.impulse, 0.0)
    assert not out.slipping


def test_wall_partner_with_infinite_mass():
    """A disk rolling into a fixed wall (m2 = I2 = inf, r2 = 0) from the left."""
    case = dict(m1=2.0, m2=np.inf, I1=0.25, I2=np.inf, r1=0.5, r2=0.0, x1=np.zeros(2), x2=np.array([0.5, 0.0]),
                c1=np.array([1.0, 0.3]), c2=np.zeros(2), w1=1.0, w2=0.0, restitution=0.5, mu=10.0)
    out = run(case)
    np.testing.assert_allclose(out.c1[0], -0.5, rtol=1e-14)
    np.testing.assert_array_equal(out.c2, [0.0, 0.0])
    assert out.w2 == 0.0
    assert abs(out.c1[1] + case["r1"] * out.w1) < 1e-14  # contact point sticks: c_y + r w = 0


def test_vmap_matches_loop():
    cases = [random_pair(np.random.default_rng(700 + s)) for s in range(8)]
    cases.append(random_pair(np.random.default_rng(799), approaching=False))
    out = collide_batch(**batch(cases))
    for i, case in enumerate(cases):
        one = run(case)
        for a, b in zip(one, out):
            np.testing.assert_allclose(np.asarray(b[i]), a, rtol=1e-14, atol=1e-15)


@pytest.mark.parametrize("mu", [0.05, 50.0])
def test_grad_restitution_matches_finite_difference(mu):
    case = random_pair(np.random.default_rng(800), restitution=0.6, mu=mu)

    def f(eps):
        out = collide(**{**case, "restitution": eps})
        return out.c1[0] + 2.0 * out.c2[1] + out.w1

    g = jax.grad(f)(0.6)
    h = 1e-6
    fd = (f(0.6 + h) - f(0.6 - h)) / (2 * h)
    assert np.isfinite(g)
    np.testing.assert_allclose(g, fd, rtol=1e-7, atol=1e-9)


def test_grad_finite_with_zero_tangential_velocity():
    """Head-on, no spin: g.t = 0 exactly, where |.| and sign(.) have kinks."""
    case = dict(m1=1.0, m2=2.0, I1=0.5, I2=1.0, r1=1.0, r2=1.0, x1=np.zeros(2), x2=np.array([0.0, 2.0]),
                c1=np.array([0.0, 1.0]), c2=np.zeros(2), w1=0.0, w2=0.0, restitution=0.5, mu=0.3)

    def f(args):
        out = collide(**args)
        return jnp.sum(out.c1) + jnp.sum(out.c2) + out.w1 + out.w2 + jnp.sum(out.impulse)

    grads = jax.grad(f)({k: jnp.asarray(v, dtype=float) for k, v in case.items()})
    for k, v in grads.items():
        assert np.all(np.isfinite(np.asarray(v))), k


def test_float32_stays_float32():
    case = random_pair(np.random.default_rng(900))
    out = collide_jit(**{k: jnp.asarray(v, dtype=jnp.float32) for k, v in case.items()})
    ref = run(case)
    for a, b in zip(out[:5], ref[:5]):
        assert a.dtype == jnp.float32
        np.testing.assert_allclose(np.asarray(a), b, rtol=1e-5, atol=1e-5)


def test_eq22_needs_soft_contact_hand_made():
    up = np.array([0.0, 1.0])
    g = np.array([0.0, -9.81])  # weight of a unit mass
    dt = 1e-3
    assert needs_soft_contact(np.zeros(2), g, 1.0, up, dt)  # at rest on the ground: any dt > 0
    assert needs_soft_contact(np.array([0.3, 0.005]), g, 1.0, up, dt)  # 0.005 < g dt: goes through
    assert not needs_soft_contact(np.array([0.0, 0.5]), g, 1.0, up, dt)  # lifts off fast enough
    assert not needs_soft_contact(np.array([0.0, -1.0]), g, 1.0, up, dt)  # approaching: hard impulse
    assert not needs_soft_contact(np.zeros(2), -g, 1.0, up, dt)  # pulled away: F.n > 0
    assert not needs_soft_contact(np.zeros(2), np.array([1.0, 0.0]), 1.0, up, dt)  # F.n = 0
    # mass enters: dt > m |v.n| / |F.n|; strict inequality at the boundary
    v = np.array([0.0, 2.0])
    assert not needs_soft_contact(v, np.array([0.0, -4.0]), 1.0, up, 0.5)  # equal: 0.5 > 0.5 is false
    assert needs_soft_contact(v, np.array([0.0, -4.0]), 1.0, up, 0.51)
    assert not needs_soft_contact(v, np.array([0.0, -4.0]), 2.0, up, 0.51)  # heavier: needs dt > 1
    # batched, tilted normal
    nt = np.array([np.sqrt(0.5), np.sqrt(0.5)])
    vs = np.array([[0.0, 0.0], [1.0, 1.0], [-1.0, -1.0]])
    fs = np.array([[-1.0, -1.0], [-1.0, -1.0], [-1.0, -1.0]])
    np.testing.assert_array_equal(needs_soft_contact(vs, fs, np.ones(3), np.tile(nt, (3, 1)), 0.1),
                                  [True, False, False])


GOOD = dict(m1=1.0, m2=2.0, I1=0.5, I2=1.0, r1=1.0, r2=1.0, restitution=0.5, mu=0.3)


@pytest.mark.parametrize("bad", [
    {"m1": -1.0}, {"m2": 0.0}, {"I1": -0.1}, {"I2": 0.0}, {"r1": -0.5}, {"r2": -1e-9},
    {"restitution": 1.1}, {"restitution": -0.01}, {"mu": -0.1}, {"mu": np.nan}, {"m1": np.nan},
])
def test_bad_inputs_raise_input_error(bad):
    with pytest.raises(InputError):
        check_collision_inputs(**{**GOOD, **bad})


def test_good_inputs_pass_check():
    check_collision_inputs(**GOOD)
    check_collision_inputs(**{**GOOD, "m2": np.inf, "I2": np.inf, "r2": 0.0, "restitution": 1.0, "mu": 0.0})
    check_collision_inputs(**{**GOOD, "m1": np.array([1.0, 2.0])})


# ---------------------------------------------------------------- in the stepper
from jaxpile.engine.collisions import HardCollisions  # noqa: E402
from jaxpile.laws import liffman  # noqa: E402
from jaxpile.engine.simulate import Simulator  # noqa: E402

SOFT = liffman.make_params(ks=1e4, kd=20.0, k_slip=50.0, mu_roll=0.1)


def _drop(hard, *, height=1.0, vx=0.0, spin=0.0, steps=3000, every=10):
    """A disk dropped on the ground, stepped by the Simulator's own step; its
    height, v_x and spin recorded every `every` steps inside one compiled loop
    (a host round trip per record cost ~10 ms a call on 2 busy cores)."""
    particles = jaxpile.make_particles([[3.0, 0.5 + height]], 0.5, velocity=[[vx, 0.0]], angular_velocity=spin)
    sim = Simulator(liffman.law(), dt=1e-3, hard_collisions=hard)
    state = sim.init(SOFT, particles, jaxpile.make_boundaries())

    @jax.jit
    def track(params, state):
        def chunk(s, _):
            s = jax.lax.fori_loop(0, every, lambda _, s: sim.step(params, s), s)
            p = s.particles
            return s, jnp.stack([p.position[0, 1], p.velocity[0, 0], p.angular_velocity[0]])

        return jax.lax.scan(chunk, state, None, length=steps // every)

    state, rows = track(SOFT, state)
    return state, np.asarray(rows)


def test_eq4_eq22_hard_bounces_keep_epsilon_squared_of_the_height_then_rest_soft():
    """A disk dropped on the ground with hard collisions rebounds to eps^2 of its
    fall height, bounce after bounce (the soft law alone gives its own ~0.54),
    and when the rebound is slower than g dt, eq. 22 hands it to the soft spring:
    it ends at rest mg / K_s below its radius."""
    state, track = _drop(HardCollisions(restitution=0.3, mu=0.5), steps=6000)
    y = track[:, 0] - 0.5
    apex = [y[i] for i in range(1, len(y) - 1) if y[i] >= y[i - 1] and y[i] > y[i + 1] and y[i] > 1e-4]
    assert apex[0] == pytest.approx(0.09, rel=0.02)
    assert apex[1] / apex[0] == pytest.approx(0.09, rel=0.05)
    assert 0.5 - float(state.particles.position[0, 1]) == pytest.approx(1e-4, rel=1e-6)
    assert abs(float(state.particles.velocity[0, 1])) < 1e-9
    _, soft_only = _drop(None, steps=3000)
    ys = soft_only[:, 0] - 0.5
    first = max(ys[np.argmin(ys):][:900])
    assert first > 0.4  # the soft law's own restitution is far from 0.3


def test_eq19_oblique_bounce_on_the_ground_slip_and_noslip_in_the_stepper():
    """Falling with v_x = 1 and no spin: with mu = 1 the impact sticks (NOSLIP,
    contact point stops: v_x + w r = 0, v_x = 2/3 of 1 for I = m r^2 / 2); with
    mu = 0.05 it slides (SLIP, v_x drops by mu (1 + eps) |v_y|)."""
    v_impact = math.sqrt(2 * 1.0 * 0.5)
    for mu in (1.0, 0.05):
        _, track = _drop(HardCollisions(restitution=0.5, mu=mu), height=0.5, vx=1.0, steps=1100, every=1)
        k = int(np.argmax(track[:, 2] != 0))  # first step with spin: the impact
        vx, w = track[k, 1], track[k, 2]
        if mu == 1.0:
            assert vx + 0.5 * w == pytest.approx(0.0, abs=1e-12)
            assert vx == pytest.approx(2 / 3, rel=1e-12)
        else:
            assert vx == pytest.approx(1.0 - 0.05 * 1.5 * v_impact, rel=1e-3)


def test_eq1_pair_collision_in_the_stepper_conserves_momentum_with_restitution():
    """Unequal disks meeting head-on in free space: the soft spring never
    engages, the relative velocity is reversed and scaled by eps exactly, and
    the total momentum is unchanged."""
    particles = jaxpile.make_particles([[2.0, 5.0], [3.5, 5.0]], [0.5, 0.4], velocity=[[1.0, 0.0], [-0.5, 0.0]])
    sim = Simulator(liffman.law(), dt=1e-3, chunk_steps=100, hard_collisions=HardCollisions(0.6, 0.3))
    state = sim.init(SOFT, particles, jaxpile.make_boundaries(gravity=0.0, ground=-10.0))
    p0 = np.sum(np.asarray(particles.mass)[:, None] * np.asarray(particles.velocity), axis=0)
    state = sim.run(SOFT, state, 1000, progress=False)
    v = np.asarray(state.particles.velocity)
    assert v[0, 0] - v[1, 0] == pytest.approx(-0.6 * 1.5, rel=1e-12)
    np.testing.assert_allclose(np.sum(np.asarray(state.particles.mass)[:, None] * v, axis=0), p0, atol=1e-14)
    assert np.all(v[:, 1] == 0)


def test_eq22_a_disk_resting_on_the_ground_stays_soft():
    """Resting contacts never turn hard: with the operator on, a disk at rest on
    the ground evolves exactly as without it."""
    particles = jaxpile.make_particles([[3.0, 0.5 - 1e-4]], 0.5)
    out = []
    for hard in (None, HardCollisions(0.3, 0.5)):
        sim = Simulator(liffman.law(), dt=1e-3, chunk_steps=200, hard_collisions=hard)
        state = sim.init(SOFT, particles, jaxpile.make_boundaries())
        out.append(np.asarray(sim.run(SOFT, state, 200, progress=False).particles.position))
    np.testing.assert_array_equal(out[0], out[1])


def test_hard_collision_settings_are_checked():
    with pytest.raises(InputError, match="restitution"):
        Simulator(liffman.law(), dt=1e-3, hard_collisions=HardCollisions(restitution=1.5))
    with pytest.raises(InputError, match="mu"):
        Simulator(liffman.law(), dt=1e-3, hard_collisions=HardCollisions(mu=-0.1))
