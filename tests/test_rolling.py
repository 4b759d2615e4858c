"""Rolling resistance (`jaxpile.laws.rolling`, `law(rolling=...)` of hooke,
lee-herrmann and baxter): LAMMPS's 3D formulas reduced to 2D, closed forms,
the history's life, gradients, and rolling off changing nothing.
(The step-by-step twin against LAMMPS itself: tests/test_rolling_lammps.py.)"""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxpile
from jaxpile.engine import pairs
from jaxpile.engine.simulate import Simulator, gravity_ramp
from jaxpile.errors import InputError
from jaxpile.laws import baxter, hooke, lee_herrmann, rolling
from jaxpile.laws.base import ContactLaw, PairGeometry, perp
from jaxpile.protocols import lattice

f64 = lambda x: jnp.asarray(x, jnp.float64)
NO_WALLS = np.array([False])

ROLLING_PARAMS = {"sds": dict(k_roll=2e3, gamma_roll=3.0, mu_roll=0.2), "constant": dict(mu_roll=0.2)}
LAWS = {  # module, law keywords, parameters (a moving pile needs rotation: lee-herrmann's is off by default)
    "hooke": (hooke, {}, dict(kn=1e4, gamma_n=60.0, mu=0.5)),
    "lee-herrmann": (lee_herrmann, dict(rotation=True), dict(kn=1e5, gamma_n=60.0, mu=0.5)),
    "baxter": (baxter, {}, dict(n=36.0, r0=1.2, mu=0.5)),
}


def _law(name, mode, zero=False):
    module, keywords, values = LAWS[name]
    extra = {} if mode is None else {k: (0.0 if zero else v) for k, v in ROLLING_PARAMS[mode].items()}
    return module.law(**keywords, rolling=mode), module.make_params(**values, **extra)


# ----------------------------------------------------------- LAMMPS's formulas in 2D
def _lammps_sds_3d(k, gamma, mu, fn, radius_i, radius_j, omega_i, omega_j, n, history, dt):
    """LAMMPS 29Sep2021 pair_granular.cpp's `rolling sds` block, written in numpy
    in 3D from its formulas (Wang et al. 2015 eq. 31 for the rolling velocity):
    the history turned into the tangent plane keeping its length, the increment,
    the spring-dashpot force, the rescale at mu |F_n|, torque R_eff n x F_r on i."""
    r_eff = radius_i * radius_j / (radius_i + radius_j) if radius_j > 0 else radius_i
    n3 = np.array([n[0], n[1], 0.0])
    relrot = np.array([0.0, 0.0, omega_i - omega_j])
    v_roll = r_eff * np.cross(relrot, n3)
    h = np.asarray(history, float).copy()
    along_n = h @ n3
    if abs(along_n) * k > 1e-10 * mu * abs(fn):
        length = np.linalg.norm(h)
        h = h - along_n * n3
        h *= length / np.linalg.norm(h) if np.linalg.norm(h) > 0 else 0.0
    h = h + v_roll * dt
    fr = -k * h - gamma * v_roll
    cap = mu * abs(fn)
    if np.linalg.norm(fr) > cap:
        if np.linalg.norm(h) != 0:
            h = -(cap * fr / np.linalg.norm(fr) + gamma * v_roll) / k
            fr = fr * cap / np.linalg.norm(fr)
        else:
            fr = np.zeros(3)
    torque = r_eff * np.cross(n3, fr)
    return torque[2], -torque[2], h


@pytest.mark.parametrize("wall", [False, True])
def test_wang2015_eq31_lammps_3d_rolling_sds_reduces_to_the_2d_kernel(wall):
    """LAMMPS's 3D v_roll = R_eff (omega_i - omega_j) x n is R_eff (omega_i -
    omega_j) t in 2D (t = z x n), and its 3D spring-dashpot-slider, history a
    3-vector turned into each new tangent plane keeping its length, is the 2D
    kernel's scalar psi along t: torques and history agree over random steps,
    sliding and sticking, n turning between steps; R_eff = r_i against a wall."""
    rng = np.random.default_rng(7)
    k, gamma, mu = 800.0, 1.5, 0.3
    history3, psi = np.zeros(3), f64(0.0)
    angle = 0.3
    slid = stuck = 0
    for step in range(200):
        angle += rng.normal(0, 0.02)
        n = np.array([math.cos(angle), math.sin(angle)])
        ri, rj = 0.45, (0.0 if wall else 0.6)
        wi, wj = rng.normal(0, 1.5), (0.0 if wall else rng.normal(0, 1.5))
        fn = rng.uniform(0.5, 2.0)
        want_i, want_j, history3 = _lammps_sds_3d(k, gamma, mu, fn, ri, rj, wi, wj, n, history3, 1e-3)
        got_i, got_j, psi = rolling.resist("sds", hooke.make_params(k_roll=k, gamma_roll=gamma, mu_roll=mu),
                                           f64(fn), f64(ri), f64(rj), f64(wi), f64(wj), f64(1.0), psi, 1e-3)
        assert float(got_i) == pytest.approx(want_i, rel=1e-12, abs=1e-15)
        assert float(got_j) == pytest.approx(want_j, rel=1e-12, abs=1e-15)
        t = perp(n)
        np.testing.assert_allclose(float(psi) * np.array([t[0], t[1], 0.0]), history3, rtol=1e-12, atol=1e-15)
        r_eff = ri if wall else ri * rj / (ri + rj)
        capped = abs(abs(want_i) - mu * fn * r_eff) < 1e-12
        slid, stuck = slid + capped, stuck + (not capped)
    assert slid > 10 and stuck > 10  # both regimes exercised


@pytest.mark.parametrize("mode", rolling.MODES)
@pytest.mark.parametrize("name", list(LAWS))
def test_rolling_torques_conserve_angular_momentum_and_read_the_same_from_js_side(name, mode):
    """Eq. 4: the rolling torque on j is minus that on i (R_eff the same on both
    sides); evaluated from j's side (displacement, velocity, disks swapped) the
    law gives j exactly the torque it gave from i's side, rolling included."""
    law, params = _law(name, mode)
    plain, _ = _law(name, None)
    d, v, ri, rj, wi, wj = (0.7, 0.69), (0.3, -0.2), 0.45, 0.55, 1.5, -0.7
    from_i = law.pair_force(params, PairGeometry(f64(d), f64(ri), f64(rj), f64(v), f64(wi), f64(wj), f64(0.5)),
                            jnp.zeros(law.history_size), 1e-3)
    from_j = law.pair_force(params, PairGeometry(-f64(d), f64(rj), f64(ri), -f64(v), f64(wj), f64(wi), f64(0.5)),
                            jnp.zeros(law.history_size), 1e-3)
    base = plain.pair_force(params, PairGeometry(f64(d), f64(ri), f64(rj), f64(v), f64(wi), f64(wj), f64(0.5)),
                            jnp.zeros(plain.history_size), 1e-3)
    roll_i, roll_j = float(from_i.torque - base.torque), float(from_i.torque_j - base.torque_j)
    assert abs(roll_i) > 1e-3 and roll_j == pytest.approx(-roll_i, rel=1e-12)
    np.testing.assert_allclose(from_j.force, -from_i.force, rtol=1e-12, atol=1e-15)
    assert float(from_j.torque) == pytest.approx(float(from_i.torque_j), rel=1e-12, abs=1e-15)
    assert float(from_j.torque_j) == pytest.approx(float(from_i.torque), rel=1e-12, abs=1e-15)
    assert float(from_j.history[-1]) == pytest.approx(-float(from_i.history[-1]), rel=1e-12)


# -------------------------------------------------------------- rolling off
@pytest.mark.parametrize("name", list(LAWS))
def test_rolling_off_is_the_law_of_before_and_zero_coefficients_change_only_round_off(name):
    """rolling=None is the law without the option: the same kernel, history
    length and recorded options (and so today's runs bit for bit: checked once,
    when rolling was added, against the code before it, 1500 steps of a
    21-disk pile thrown with spin, bit-identical for each of the three laws).
    With rolling on and k_roll = gamma_roll = mu_roll = 0 a thrown pile moves as
    with rolling off to round-off (bit for bit with XLA's default CPU fusion; the
    suite's older fusion emitters fuse the longer kernel differently), the
    law's own history entries included."""
    module, keywords, _ = LAWS[name]
    assert module.law(**keywords, rolling=None) == module.law(**keywords)
    plain, params = _law(name, None)
    assert plain.history_size == (2 if name == "hooke" else 1) and "rolling" not in dict(plain.options)
    particles, boundaries = lattice.equilateral_pile(4)
    rng = np.random.default_rng(1)
    particles = particles.set(velocity=jnp.asarray(rng.normal(0, 0.3, (10, 2))),
                              angular_velocity=jnp.asarray(rng.normal(0, 2.0, 10)))
    states = []
    for mode in (None, "sds"):
        law, params = _law(name, mode, zero=True)
        sim = Simulator(law, dt=5e-4, schedule=gravity_ramp(200), chunk_steps=300)
        states.append(sim.run(params, sim.init(params, particles, boundaries), 600, progress=False))
    off, on = states
    assert float(np.abs(np.asarray(off.particles.angular_velocity)).max()) > 0.1  # turning: rolling would act
    for a, b in zip(jax.tree.leaves(off.particles), jax.tree.leaves(on.particles)):
        np.testing.assert_allclose(np.asarray(b), np.asarray(a), rtol=1e-12, atol=1e-14)
    h = plain.history_size
    np.testing.assert_allclose(np.asarray(on.contacts.history)[:, :h], np.asarray(off.contacts.history),
                               rtol=1e-10, atol=1e-14)
    np.testing.assert_allclose(np.asarray(on.contacts.wall_history)[..., :h], np.asarray(off.contacts.wall_history),
                               rtol=1e-10, atol=1e-14)


# ------------------------------------------------------------- closed forms
def _disk_on_floor(spin, mass=1.0, radius=0.5, kn=1e5, gravity=1.0):
    """One disk resting on the floor (its overlap m g / k_n), spinning."""
    y = radius - mass * gravity / kn
    particles = jaxpile.make_particles([[3.0, y]], radius, mass=mass, angular_velocity=[spin])
    return particles, jaxpile.make_boundaries(sides=False, gravity=gravity)


@pytest.mark.parametrize("mode", rolling.MODES)
def test_zhou1999_constant_torque_slows_a_spinning_disk_linearly_until_rest(mode):
    """A disk spun on a frictionless floor (mu = 0: no tangential force) feels
    only the rolling torque, capped at mu_roll F_n R_eff = mu_roll m g r
    (R_eff = r against a wall): omega(t) = omega_0 - (2 mu_roll g / r) (t - dt/2)
    (I = m r^2 / 2) exactly while it turns, then the disk stays at rest. Both
    models ("sds" slides at its cap while it turns). (- dt/2: at the start the
    history is zero and the torque too, as in LAMMPS's set-up, so velocity
    Verlet's first half kick has none.)"""
    mu_roll, radius, omega_0, dt = 0.2, 0.5, 2.0, 1e-3
    extra = ROLLING_PARAMS[mode] | dict(mu_roll=mu_roll)
    params = hooke.make_params(kn=1e5, gamma_n=50.0, mu=0.0, **extra)
    sim = Simulator(hooke.law(rolling=mode), dt=dt, chunk_steps=250)
    state = sim.init(params, *_disk_on_floor(omega_0, radius=radius))
    slowing = 2.0 * mu_roll / radius
    stop = omega_0 / slowing  # 2.5
    for k in range(1, 10):  # t = 0.25 ... 2.25, before the stop
        state = sim.run(params, state, 250, progress=False)
        t = k * 250 * dt
        assert float(state.particles.angular_velocity[0]) == pytest.approx(omega_0 - slowing * (t - dt / 2), rel=1e-9)
        assert float(state.particles.torque[0]) == pytest.approx(-mu_roll * radius * 1.0, rel=1e-9)
    state = sim.run(params, state, int(round((stop - 2.25) / dt)) + 500, progress=False)
    spins = []
    for _ in range(4):
        state = sim.run(params, state, 250, progress=False)
        spins.append(abs(float(state.particles.angular_velocity[0])))
    assert max(spins) < (1e-9 if mode == "constant" else 1e-3)  # "sds": its spring rings down (gamma_roll)


def test_lammps_sds_rolling_spring_oscillates_at_sqrt_k_roll_r2_over_i():
    """Small rolling of a disk on a frictionless floor, no dashpot, far below the
    cap: I theta'' = -k_roll R_eff^2 theta with R_eff = r, so omega(t) =
    omega_0 cos(Omega t), Omega = sqrt(k_roll r^2 / I) = sqrt(2 k_roll / m)."""
    k_roll, mass, radius, omega_0, dt = 50.0, 1.0, 0.5, 0.1, 1e-3
    params = hooke.make_params(kn=1e5, gamma_n=50.0, mu=0.0, k_roll=k_roll, gamma_roll=0.0, mu_roll=10.0)
    sim = Simulator(hooke.law(rolling="sds"), dt=dt, chunk_steps=50)
    state = sim.init(params, *_disk_on_floor(omega_0, mass=mass, radius=radius))
    inertia = 0.5 * mass * radius ** 2
    frequency = math.sqrt(k_roll * radius ** 2 / inertia)  # 10
    times, spins = [], []
    for k in range(1, 61):  # ~ 5 periods
        state = sim.run(params, state, 50, progress=False)
        times.append(k * 50 * dt)
        spins.append(float(state.particles.angular_velocity[0]))
    # velocity Verlet's phase error after 3 time units: (Omega dt)^2 / 24 * Omega t ~ 1e-4
    np.testing.assert_allclose(spins, omega_0 * np.cos(frequency * np.array(times)), atol=2e-5)


@pytest.mark.parametrize("partner", ["wall", "fixed disk"])
def test_lammps_sds_torque_is_capped_at_mu_roll_fn_reff_while_rolling(partner):
    """A disk turning fast on a frictionless partner: the slider holds the
    rolling torque at mu_roll |F_n| R_eff, with R_eff = r against a wall and
    r_1 r_2 / (r_1 + r_2) against a fixed disk of another radius."""
    mu_roll, r_top, r_base = 0.3, 0.5, 0.8
    params = hooke.make_params(kn=1e5, gamma_n=50.0, mu=0.0, k_roll=500.0, gamma_roll=1.0, mu_roll=mu_roll)
    law = hooke.law(rolling="sds")
    sim = Simulator(law, dt=1e-3, chunk_steps=100)
    if partner == "wall":
        particles, boundaries = _disk_on_floor(5.0, radius=r_top)
        r_eff = r_top
    else:
        particles = jaxpile.make_particles([[3.0, 3.0], [3.0, 3.0 + r_top + r_base - 1e-5]], [r_base, r_top],
                                           mass=[1.0, 1.0], angular_velocity=[0.0, 5.0], fixed=[True, False])
        boundaries = jaxpile.make_boundaries(sides=False).set(wall_active=NO_WALLS)
        r_eff = r_top * r_base / (r_top + r_base)
    state = sim.init(params, particles, boundaries)
    moving = particles.count - 1
    for _ in range(5):
        state = sim.run(params, state, 100, progress=False)
        cf = sim.contact_forces(params, state)
        normal = float(cf.wall.normal[moving, 0]) if partner == "wall" else float(jnp.sum(cf.pair.normal[moving]))
        assert normal == pytest.approx(1.0, rel=1e-3)
        assert float(state.particles.angular_velocity[moving]) > 1.0  # still turning: sliding
        assert float(state.particles.torque[moving]) == pytest.approx(-mu_roll * abs(normal) * r_eff, rel=1e-9)


# ------------------------------------------------------------ history's life
def _rolling_over_a_row(skin):
    """A disk (r 0.55) set down in the dip between two of a row of touching fixed
    disks (r 0.45), resting there under g = 4, rolling off forwards."""
    row = [[0.9 * k, 0.0] for k in range(12)]
    height = math.sqrt(1.0 - 0.45 ** 2)
    top = [1.35, height - 0.9 * 4.0 / (2 * 1e5 * height) / height]
    particles = jaxpile.make_particles(row + [top], np.array([0.45] * 12 + [0.55]),
                                       mass=np.array([1.0] * 12 + [0.9]), velocity=[[0.0, 0.0]] * 12 + [[0.6, 0.0]],
                                       angular_velocity=[0.0] * 12 + [-1.0], fixed=[True] * 12 + [False])
    boundaries = jaxpile.make_boundaries(sides=False, gravity=4.0).set(wall_active=NO_WALLS)
    params = hooke.make_params(kn=1e5, gamma_n=300.0, mu=0.5, k_roll=5e3, gamma_roll=2.0, mu_roll=0.2)
    sim = Simulator(hooke.law(rolling="sds"), dt=2e-4, skin=skin, chunk_steps=500)
    return sim, params, sim.init(params, particles, boundaries)


def test_rolling_history_is_carried_across_neighbour_rebuilds():
    """A disk rolling over a row of fixed disks: its rolling displacements (and
    the whole state) are the same whether the neighbour list was never rebuilt
    (skin 2) or rebuilt on the way (skin 0.05)."""
    finals = []
    for skin in (2.0, 0.05):
        sim, params, state = _rolling_over_a_row(skin)
        reference = np.asarray(state.neighbors.reference_position).copy()
        state = sim.run(params, state, 3000, progress=False)
        rebuilt = not np.array_equal(np.asarray(state.neighbors.reference_position), reference)
        assert rebuilt == (skin < 1.0)
        psi = {}
        for j in range(12):
            entry = pairs.pair_entry(state.contacts.pairs, j, 12)
            psi[j] = 0.0 if entry is None else float(state.contacts.history[entry, 2])
        finals.append((psi, np.asarray(state.particles.position[12]), float(state.particles.angular_velocity[12])))
    (psi_far, x_far, w_far), (psi_near, x_near, w_near) = finals
    loaded = {j: v for j, v in psi_far.items() if v != 0.0}
    assert loaded, "no rolling spring strained at the end: the case does not test the history"
    for j, v in loaded.items():
        assert psi_near[j] == pytest.approx(v, rel=1e-9)
    np.testing.assert_allclose(x_near, x_far, rtol=1e-12)
    assert w_near == pytest.approx(w_far, rel=1e-9)


def test_rolling_history_is_zeroed_when_a_pair_separates():
    """A disk spinning on the floor, strained, then lifted off by an upward kick:
    its wall history's rolling entry is zero once it has left the floor, and a
    disk pair's likewise once apart."""
    params = hooke.make_params(kn=1e5, gamma_n=50.0, mu=0.5, k_roll=500.0, gamma_roll=1.0, mu_roll=0.3)
    sim = Simulator(hooke.law(rolling="sds"), dt=1e-3, chunk_steps=100)
    state = sim.init(params, *_disk_on_floor(3.0))
    state = sim.run(params, state, 100, progress=False)
    assert float(state.contacts.wall_history[0, 0, 2]) != 0.0
    lifted = state.particles.set(velocity=state.particles.velocity.at[0, 1].set(2.0))
    state = sim.run(params, state.set(particles=lifted), 100, progress=False)
    assert float(state.particles.position[0, 1]) > 0.6  # in the air
    assert np.all(np.asarray(state.contacts.wall_history[0, 0]) == 0.0)

    particles = jaxpile.make_particles([[3.0, 3.0], [3.995, 3.0]], 0.5, velocity=[[0.0, 0.0], [0.0, 0.0]],
                                       angular_velocity=[2.0, -1.0])
    boundaries = jaxpile.make_boundaries(sides=False, gravity=0.0).set(wall_active=NO_WALLS)
    state = sim.init(params, particles, boundaries)
    state = sim.run(params, state, 1, progress=False)
    entry = pairs.pair_entry(state.contacts.pairs, 0, 1)
    assert float(state.contacts.history[entry, 2]) != 0.0  # the overlap pushes them apart
    state = sim.run(params, state, 200, progress=False)
    assert float(state.particles.position[1, 0] - state.particles.position[0, 0]) > 1.0
    assert np.all(np.asarray(state.contacts.history) == 0.0)


# ---------------------------------------------------------------- gradients
def test_grad_wrt_k_roll_gamma_roll_mu_roll_through_a_rollout_with_rebuilds_matches_central_differences():
    """d/d(k_roll, gamma_roll, mu_roll) of the spins and positions of a thrown
    3-layer pile after 150 steps (the neighbour list rebuilt inside the rollout,
    rolling springs sliding and sticking) against central differences, float64."""
    particles, boundaries = lattice.equilateral_pile(3)
    rng = np.random.default_rng(4)
    particles = particles.set(velocity=jnp.asarray(rng.normal(0, 0.3, (6, 2))),
                              angular_velocity=jnp.asarray(rng.normal(0, 2.0, 6)))
    params = hooke.make_params(kn=1e4, gamma_n=50.0, mu=0.3, k_roll=300.0, gamma_roll=0.5, mu_roll=0.1)
    sim = Simulator(hooke.law(rolling="sds"), dt=2e-4, skin=0.01)
    state = sim.init(params, particles, boundaries)
    steps = 150
    final = sim.rollout(params, state, steps)
    assert not np.array_equal(np.asarray(final.neighbors.reference_position),
                              np.asarray(state.neighbors.reference_position))  # rebuilt inside
    weights = jnp.asarray(np.random.default_rng(0).normal(size=(6, 3)))

    def loss(p):
        out = sim.rollout(p, state, steps).particles
        return jnp.sum(weights * jnp.concatenate([out.position, out.angular_velocity[:, None]], axis=1))

    value_and_grad = jax.jit(jax.value_and_grad(loss))
    _, grad = value_and_grad(params)
    for name in ("k_roll", "gamma_roll", "mu_roll"):
        x = float(getattr(params, name))
        h = 1e-6 * x
        dtype = getattr(params, name).dtype
        fd = (float(value_and_grad(params.set(**{name: jnp.asarray(x + h, dtype)}))[0])
              - float(value_and_grad(params.set(**{name: jnp.asarray(x - h, dtype)}))[0])) / (2 * h)
        g = float(getattr(grad, name))
        assert abs(g) * x > 1e-6, f"d/d{name} vanishes: the case does not exercise it"
        assert g == pytest.approx(fd, rel=1e-4, abs=1e-9 / x), name


# ------------------------------------------------------- the constant model
def _sign_law(omega_0=None):
    """hooke with Zhou's torque -0.1 R_eff |F_n| sign(omega_i - omega_j) on i, the
    sign plain (explicit) or smoothed as tanh(omega_rel / omega_0): what
    `"constant"` regularises otherwise, for comparison."""
    def pair_force(p, g, history, dt):
        out = hooke.pair_force(p, g, history, dt)
        r_eff = rolling.effective_radius(g.radius_i, g.radius_j)
        turning = g.angular_velocity_i - g.angular_velocity_j
        sign = jnp.sign(turning) if omega_0 is None else jnp.tanh(turning / omega_0)
        torque = jnp.where(out.in_contact, -0.1 * r_eff * jnp.abs(out.normal) * sign, 0.0)
        return out._replace(torque=out.torque + torque, torque_j=out.torque_j - torque)

    plain = hooke.law()
    return ContactLaw(**{**plain.__dict__, "pair_force": pair_force, "name": "hooke-sign"})


def test_zhou1999_constant_model_holds_a_pile_at_rest_where_a_plain_or_smooth_sign_cannot():
    """The 15-disk lattice pile rolls apart on a flat floor without rolling
    resistance (spins ~1.5). With `"constant"` (mu_roll = 0.1) it comes to rest
    and stays: spins fall below 1e-10 (measured 1e-13 at step 14000, 4e-16 at
    16000). With the same torque and a plain sign it never rests: its spins
    chatter at ~5e-4 for ever; with tanh(omega_rel / 0.01) it creeps at ~2e-2."""
    particles, boundaries = lattice.equilateral_pile(5)
    params = hooke.make_params(kn=1e4, gamma_n=60.0, mu=0.5, mu_roll=0.1)
    plain = hooke.make_params(kn=1e4, gamma_n=60.0, mu=0.5)
    spins = {}
    for name, law, p in (("constant", hooke.law(rolling="constant"), params), ("sign", _sign_law(), plain),
                         ("tanh", _sign_law(0.01), plain), ("none", hooke.law(), plain)):
        sim = Simulator(law, dt=5e-4, schedule=gravity_ramp(4000), chunk_steps=2000)
        state = sim.run(p, sim.init(p, particles, boundaries), 12000, progress=False)
        state = sim.run(p, state, 2000, progress=False)
        spins[name] = float(np.abs(np.asarray(state.particles.angular_velocity)).max())
    assert spins["constant"] < 1e-10
    assert spins["sign"] > 1e-4
    assert spins["tanh"] > 1e-3
    assert spins["none"] > 0.1  # rolled apart


# --------------------------------------------------------------- the options
def test_rolling_options_are_checked_and_recorded():
    """An unknown model, rolling without rotation, a model's missing or unused
    parameter: one-line InputErrors; the model is in `options` (checkpoints), its
    entry lengthens the history, and the rolling spring shortens the stable step."""
    with pytest.raises(InputError, match="unknown rolling model"):
        hooke.law(rolling="viscous")
    with pytest.raises(InputError, match="needs rotation=True"):
        lee_herrmann.law(rolling="sds")
    with pytest.raises(InputError, match="k_roll must be set"):
        hooke.law(rolling="sds").validate(hooke.make_params(mu_roll=0.1))
    with pytest.raises(InputError, match="k_roll is not used"):
        baxter.law(rolling="constant").validate(baxter.make_params(mu_roll=0.1, k_roll=1.0))
    with pytest.raises(InputError, match="mu_roll must be >= 0"):
        hooke.law(rolling="sds").validate(hooke.make_params(k_roll=1.0, mu_roll=-1.0))
    law = hooke.law(rolling="sds", pair_style="granular")
    assert dict(law.options) == {"rolling": "sds", "pair_style": "granular"} and law.history_size == 3
    assert dict(baxter.law(rolling="constant").options)["rolling"] == "constant"
    assert lee_herrmann.law(rotation=True, rolling="sds").history_size == 2
    p = hooke.make_params(kn=1e4)
    assert hooke.stable_time_step(p.set(k_roll=jnp.asarray(1e6)), 1.0) < hooke.stable_time_step(p, 1.0)
    assert hooke.wall_params(p.set(mu_roll=jnp.asarray(0.3))).mu_roll == 0.3
