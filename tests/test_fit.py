"""jaxpile.fit: traceable base loads against the host-side measurements, smooth
profiles, targets (CSV files and the Smid-Novosad features), log-space
transforms, the optax loop, and a gradient of a profile loss through a rollout
against central finite differences (float64)."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import optax
import pytest

import jaxpile  # noqa: F401  (float64 on)
from jaxpile import analysis, fit, theory
from jaxpile.engine.boundaries import make_boundaries
from jaxpile.errors import InputError
from jaxpile.laws import baxter, hooke
from jaxpile.protocols import lattice
from jaxpile.engine.simulate import Simulator
from jaxpile.engine.state import make_particles
from jaxpile.fit import profiles
from jaxpile.measure import heap

ROLLOUT_STEPS = 100
HEAP_RADIUS = 0.45
GRAVITY = 1.5


# ----------------------------------------------------------------- fixtures
@pytest.fixture(scope="module")
def sim():
    """One simulator for every pile here (its compiled functions are shared)."""
    return Simulator(hooke.law(rotation=False), dt=5e-4)


@pytest.fixture(scope="module")
def relaxed_scene(sim):
    """Two piles side by side, settled together (one compiled run): the 3-layer
    1992 pile on the ground (disks 0-5, x 1..3), and a 4-layer pile of 10 smaller
    disks (11-20, radius 0.45, so the contact point's split of the centre line
    matters) in the hollows of a row of 5 fixed disks 1.1 apart (6-10, x 6..10.4:
    the 1997 base). Frictionless disks, rough ground, g = 1.5 (so that mg is not m)."""
    r = HEAP_RADIUS
    first, rise = math.sqrt((0.5 + r) ** 2 - 0.55**2), math.sqrt((2 * r) ** 2 - 0.55**2)
    base = [[6.0 + 1.1 * i, 0.5] for i in range(5)]
    heap = [[6.0 + 1.1 * (i + 0.5 * layer), 0.5 + first + (layer - 1) * rise]
            for layer in range(1, 5) for i in range(5 - layer)]
    position = np.concatenate([lattice.equilateral_positions(3), base, heap])
    fixed = np.zeros(len(position), bool)
    fixed[6:11] = True
    radius = np.where(np.arange(len(position)) < 11, 0.5, r)
    particles = make_particles(position, radius, fixed=fixed)
    params = hooke.make_params(kn=1e4, gamma_n=50.0, mu=0.0, wall_mu=1.0)
    state = sim.run(params, sim.init(params, particles, make_boundaries(gravity=GRAVITY)), 3000, progress=False)
    return params, state


# ------------------------------------------------------------- base loads
def _contacts(load):
    w = np.asarray(load.weight)
    assert set(np.unique(w)) <= {0.0, 1.0}
    keep = w == 1.0
    x, n, h = (np.asarray(a)[keep] for a in (load.x, load.normal, load.horizontal))
    order = np.lexsort((n, x))
    return x[order], n[order], h[order]


def test_base_load_on_the_ground_matches_analysis_base_forces(sim, relaxed_scene):
    params, state = relaxed_scene
    ref = analysis.base_forces(sim, params, state, base="ground")
    load = fit.base_load(sim, params, state, base="ground")
    assert load.x.shape == (state.particles.count,)  # fixed shape: one entry per disk
    x, normal, horizontal = _contacts(load)
    assert len(x) == len(ref.x) == 3
    order = np.lexsort((ref.normal, ref.x))
    np.testing.assert_allclose(x, ref.x[order], rtol=0, atol=1e-12)
    np.testing.assert_allclose(normal, ref.normal[order], rtol=1e-12)
    np.testing.assert_allclose(horizontal, ref.horizontal[order], rtol=1e-12, atol=1e-12)
    # eqs. 42 and 44 for k = 3 in the lattice disks' own weight (so the signs, not only the
    # bookkeeping, are right); mg is the mean movable mass, the lighter heap's included, times g
    unit = float(analysis.traced_force_unit(state))
    assert unit == pytest.approx(analysis.force_unit(state), rel=1e-14)
    assert unit == pytest.approx(GRAVITY * (6 + 10 * (2 * HEAP_RADIUS) ** 2) / 16, rel=1e-12)
    lattice_weight = GRAVITY * 1.0
    np.testing.assert_allclose(normal * unit / lattice_weight, 2.0, rtol=2e-3)
    np.testing.assert_allclose(horizontal * unit / lattice_weight, [-1 / math.sqrt(3), 0.0, 1 / math.sqrt(3)],
                               atol=5e-3)


def test_base_load_on_a_substrate_matches_analysis_substrate_forces(sim, relaxed_scene):
    params, state = relaxed_scene
    ref = analysis.substrate_forces(sim, params, state)
    load = fit.base_load(sim, params, state, base="substrate")
    assert load.x.shape == (state.neighbors.idx.size,)  # one entry per neighbour slot
    x, normal, horizontal = _contacts(load)
    assert len(x) == len(ref.x) == 8  # the 4 bottom disks, each in a hollow between 2 base disks
    order = np.lexsort((ref.normal, ref.x))
    np.testing.assert_allclose(x, ref.x[order], rtol=0, atol=1e-12)
    np.testing.assert_allclose(normal, ref.normal[order], rtol=1e-12)
    np.testing.assert_allclose(horizontal, ref.horizontal[order], rtol=1e-12, atol=1e-12)
    assert np.abs(horizontal).max() > 0.1
    # the base carries its pile's 10 disks (the ground the other 6), in units of the mean movable mass
    mass = np.asarray(state.particles.mass)
    weight_mg = mass[11:].sum() / np.r_[mass[:6], mass[11:]].mean()
    assert weight_mg < 9.5  # (the heap's disks are lighter than the mean)
    assert float(jnp.sum(load.weight * load.normal)) == pytest.approx(weight_mg, rel=1e-2)


def test_base_forces_read_what_the_pile_stands_on_the_ground_and_the_fixed_disks(sim, relaxed_scene):
    """The default reading: the movable disks' contacts with the ground and with fixed disks, both."""
    params, state = relaxed_scene
    both = analysis.base_forces(sim, params, state)
    ground = analysis.base_forces(sim, params, state, base="ground")
    substrate = analysis.substrate_forces(sim, params, state)
    assert both.x.size == ground.x.size + substrate.x.size == 11
    order = np.lexsort((np.r_[ground.normal, substrate.normal], np.r_[ground.x, substrate.x]))
    np.testing.assert_allclose(np.sort(both.x), np.r_[ground.x, substrate.x][order], atol=1e-12)
    np.testing.assert_array_equal(np.sort(both.particle), np.sort(np.r_[ground.particle, substrate.particle]))
    mass = np.asarray(state.particles.mass)
    movable = np.r_[mass[:6], mass[11:]]
    assert both.normal.sum() == pytest.approx(movable.sum() / movable.mean(), rel=1e-2)  # all 16 disks' weight
    load = fit.base_load(sim, params, state, base="pile")
    assert load.x.shape == (state.particles.count + state.neighbors.idx.size,)


def test_base_load_refuses_an_unknown_base(sim, relaxed_scene):
    params, state = relaxed_scene
    with pytest.raises(InputError, match="base must be one of"):
        fit.base_load(sim, params, state, base="floor")


# --------------------------------------------------------- smooth profiles
def test_smooth_profile_conserves_the_total():
    rng = np.random.default_rng(0)
    x = rng.uniform(0.0, 10.0, 40)
    x[:2] = [0.01, 9.99]  # at the very ends
    values = rng.uniform(0.5, 2.0, 40)
    weight = (rng.uniform(size=40) > 0.3).astype(float)
    values[weight == 0] = 1e6  # padding must not count, whatever it holds
    for bandwidth in (None, 0.1, 3.0):
        u, profile = fit.smooth_profile(x, values, weight, x_left=0.0, x_right=10.0, bins=9, bandwidth=bandwidth)
        assert float(jnp.sum(profile)) == pytest.approx(float(np.sum(weight * values)), rel=1e-12)
    np.testing.assert_allclose(u, (np.arange(9) + 0.5) / 9)


def test_smooth_profile_with_a_tiny_bandwidth_is_pour_base_profile_binning():
    rng = np.random.default_rng(1)
    bins = 11
    cells = rng.integers(0, bins, 60)
    x = 2.0 + 5.0 * (cells + rng.uniform(0.1, 0.9, 60)) / bins  # base [2, 7], away from bin edges
    normal = rng.uniform(0.1, 3.0, 60)
    hard = heap.base_profile(analysis.BaseForces(x=x, normal=normal, horizontal=0 * x, particle=0 * x),
                             extent=(2.0, 7.0), bins=bins)
    u, smooth = fit.smooth_profile(x, normal, np.ones(60), x_left=2.0, x_right=7.0, bins=bins, bandwidth=1e-3)
    np.testing.assert_allclose(u, hard.x_over_b, rtol=1e-12)
    np.testing.assert_allclose(smooth, hard.force, rtol=1e-10)
    # the default bandwidth (one bin) smooths: the profiles differ
    _, wide = fit.smooth_profile(x, normal, np.ones(60), x_left=2.0, x_right=7.0, bins=bins)
    assert np.abs(np.asarray(wide) - hard.force).max() > 0.1


def test_smooth_profile_is_differentiable_in_x():
    x = jnp.array([1.0, 2.3, 3.1, 4.6])
    values = jnp.array([1.0, 2.0, 1.5, 0.5])
    w = jnp.linspace(-1.0, 1.0, 7)

    @jax.jit
    def f(x):
        _, profile = fit.smooth_profile(x, values, jnp.ones(4), x_left=0.5, x_right=5.0, bins=7)
        return jnp.sum(w * profile)

    g = np.asarray(jax.jit(jax.grad(f))(x))
    assert np.all(np.isfinite(g)) and np.all(np.abs(g) > 1e-3)
    h = 1e-6
    fd = [(f(x.at[i].add(h)) - f(x.at[i].add(-h))) / (2 * h) for i in range(4)]
    np.testing.assert_allclose(g, fd, rtol=1e-6)


@pytest.mark.parametrize("kwargs, match", [
    (dict(bins=0), "bins must be"),
    (dict(x_left=3.0, x_right=3.0), "x_left < x_right"),
    (dict(bandwidth=0.0), "bandwidth must be positive"),
    (dict(values=np.ones(4)), "one length"),
])
def test_smooth_profile_refuses_bad_input(kwargs, match):
    args = dict(x=np.ones(3), values=np.ones(3), weight=np.ones(3), x_left=0.0, x_right=5.0, bins=5)
    args.update(kwargs)
    with pytest.raises(InputError, match=match):
        fit.smooth_profile(args.pop("x"), args.pop("values"), args.pop("weight"), **args)


def test_normalise_by_the_plain_and_the_smooth_maximum():
    profile = jnp.array([0.2, 2.9, 3.0, 1.0])
    np.testing.assert_allclose(fit.normalise(profile), profile / 3.0)
    # the smooth max lies above the max by at most T log(bins) (relative): the peak ends just below 1
    soft = np.asarray(fit.normalise(profile, temperature=0.05))
    assert 1.0 / (1.0 + 0.05 * math.log(4)) <= soft.max() < 0.99
    g = jax.grad(lambda p: fit.normalise(p, temperature=0.05)[0])(profile)
    assert np.all(np.isfinite(np.asarray(g)))
    np.testing.assert_array_equal(fit.normalise(jnp.zeros(3)), np.zeros(3))  # no load: zeros, not NaN
    with pytest.raises(InputError, match="temperature"):
        fit.normalise(profile, temperature=0.0)


# ----------------------------------------------------------------- targets
def _write(tmp_path, text, name="profile.csv"):
    path = tmp_path / name
    path.write_text(text)
    return path


def test_load_profile_csv_round_trip(tmp_path):
    target = fit.smid_novosad_profile(points=21)  # samples the maxima, so normal/max is the file's own max
    lines = ["# digitised by hand", "x/B,normal/max,horizontal/max"]
    lines += [f"{float(u)!r},{float(n)!r},{float(h)!r}"
              for u, n, h in zip(target.x_over_b, target.normal, target.horizontal)]
    loaded = fit.load_profile_csv(_write(tmp_path, "\n".join(lines) + "\n"))
    np.testing.assert_array_equal(loaded.x_over_b, target.x_over_b)
    np.testing.assert_array_equal(loaded.normal, target.normal)
    np.testing.assert_array_equal(loaded.horizontal, target.horizontal)
    assert loaded.source.endswith("profile.csv")
    # the short names, any column order, no horizontal; a raw normal column is divided by its max
    other = fit.load_profile_csv(_write(tmp_path, " Normal , X_over_B\n2,0\n4,0.5\n1,1\n", "b.csv"))
    np.testing.assert_array_equal(other.x_over_b, [0.0, 0.5, 1.0])
    np.testing.assert_array_equal(other.normal, [0.5, 1.0, 0.25])
    assert other.horizontal is None


@pytest.mark.parametrize("text, match", [
    (None, "does not exist"),
    ("# only a comment\n\n", "is empty"),
    ("0,1\n0.5,1\n1,1\n", "header row"),
    ("x/B,horizontal/max\n0,0\n0.5,0\n1,0\n", r"missing column\(s\) \['normal/max'\]"),
    ("x/B,normal/max,shear\n0,1,0\n0.5,1,0\n1,1,0\n", r"unknown column\(s\) \['shear'\]"),
    ("x/B,normal,normal/max\n0,1,1\n0.5,1,1\n1,1,1\n", "more than once"),
    ("x/B,normal/max\n0,1\n0.5\n1,1\n", "line 3 has 1 value"),
    ("x/B,normal/max\n0,1\n0.5,high\n1,1\n", "line 3, column 'normal/max': 'high' is not a number"),
    ("x/B,normal/max\n0,1\n0.5,nan\n1,1\n", "is not finite"),
    ("x/B,normal/max\n0,1\n1,1\n", "2 data row"),
    ("x/B,normal/max\n0,1\n0.5,1\n1.2,1\n", "outside \\[0, 1\\]"),
    ("x/B,normal/max\n0,1\n0.6,1\n0.5,1\n", "increase strictly"),
    ("x/B,normal/max\n0,0\n0.5,0\n1,0\n", "must be positive"),
])
def test_load_profile_csv_refuses_bad_files(tmp_path, text, match):
    path = tmp_path / "missing.csv" if text is None else _write(tmp_path, text)
    with pytest.raises(InputError, match=match):
        fit.load_profile_csv(path)


def test_smid_novosad_target_has_the_reported_features():
    target = fit.smid_novosad_profile(points=41)
    u, normal, horizontal = target.x_over_b, target.normal, target.horizontal
    centre = int(np.flatnonzero(u == 0.5)[0])
    assert "not measured points" in target.source and "reported features" in fit.smid_novosad_profile.__doc__
    assert target.angle_of_repose_degrees == 32.6
    # the M: maximum 1, central minimum 25% below it (within the reported 20-30%)
    assert normal.max() == pytest.approx(1.0)
    dip = 1.0 - normal[centre] / normal.max()
    assert dip == pytest.approx(0.25) and target.central_dip == 0.25
    lo, hi = target.central_dip_range
    assert (lo, hi) == (0.2, 0.3) and lo <= dip <= hi
    assert float(fit.dip_below_peak(target)) == pytest.approx(0.25)
    peaks = u[np.flatnonzero(normal == normal.max())]
    assert np.all((np.abs(peaks - 0.5) >= 0.2) & (np.abs(peaks - 0.5) <= 0.3))
    assert normal[0] == normal[-1] == 0.0
    np.testing.assert_allclose(normal, normal[::-1], atol=1e-15)
    # shear: zero at the centre, odd about it, negative on the left (pushes outwards)
    assert horizontal[centre] == pytest.approx(0.0, abs=1e-15)
    np.testing.assert_allclose(horizontal, -horizontal[::-1], atol=1e-15)
    assert np.all(horizontal[1:centre] < 0)
    # central slope: eq. 57 over eq. 56, written out here
    a = math.radians(32.6)
    slope = (math.sin(a) / (math.sqrt(3) * math.sin(2 * math.pi / 3 - a))) / (
        math.sin(a) / (2 * math.sin(2 * math.pi / 3 - a)))
    assert float(fit.central_slope(target, half_width=0.15)) == pytest.approx(slope, rel=1e-12)
    xc = theory.continuum_critical_distance(a, 1.0)
    assert 0.15 < 0.5 - xc < 0.2  # the linear region reaches past the slope's window


@pytest.mark.parametrize("kwargs, match", [
    (dict(points=40), "odd"), (dict(points=3), "odd"), (dict(dip=1.2), "dip must be"),
    (dict(peak_offset=0.5), "peak_offset"),
])
def test_smid_novosad_target_refuses_bad_settings(kwargs, match):
    with pytest.raises(InputError, match=match):
        fit.smid_novosad_profile(**kwargs)


# ------------------------------------------------------------------ losses
def test_profile_loss_is_zero_on_the_target_and_grows_away_from_it():
    target = fit.smid_novosad_profile(points=21)
    same = fit.Profile(x_over_b=target.x_over_b, normal=target.normal, horizontal=target.horizontal)
    assert float(fit.profile_loss(same, target, horizontal_weight=1.0)) == pytest.approx(0.0, abs=1e-30)
    # a binned profile stops short of the feet; it is read as 0 there
    inner = fit.Profile(x_over_b=target.x_over_b[1:-1], normal=target.normal[1:-1],
                        horizontal=target.horizontal[1:-1])
    assert float(fit.profile_loss(inner, target, horizontal_weight=1.0)) == pytest.approx(0.0, abs=1e-30)
    flat = fit.Profile(x_over_b=target.x_over_b, normal=np.ones(21), horizontal=np.zeros(21))
    normal_only = float(fit.profile_loss(flat, target))
    assert normal_only == pytest.approx(np.mean((1.0 - target.normal) ** 2))
    both = float(fit.profile_loss(flat, target, horizontal_weight=2.0))
    assert both == pytest.approx(normal_only + 2.0 * np.mean(target.horizontal**2))
    with pytest.raises(InputError, match="horizontal"):
        fit.profile_loss(flat, target._replace(horizontal=None), horizontal_weight=1.0)


def test_profile_interpolation_is_jnp_interp_and_its_gradient_has_no_scatter():
    """profile_loss reads a profile between its points like jnp.interp, by a
    select instead of gathers: the gathers' derivative is a scatter-add, and
    XLA:CPU's multi-output fusion of two of them aborts the process in jax
    0.10.2 (jaxpile.configure turns it on)."""
    rng = np.random.default_rng(3)
    xp = np.concatenate([[0.0, 0.0], np.sort(rng.uniform(0, 1, 7)), [1.0]])  # a repeated point, as at a foot
    fp = rng.normal(size=xp.size)
    x = np.concatenate([rng.uniform(-0.2, 1.2, 40), xp])  # outside, inside and on the points
    got = profiles.interp_without_scatter(jnp.asarray(x), jnp.asarray(xp), jnp.asarray(fp))
    np.testing.assert_allclose(np.asarray(got), np.asarray(jnp.interp(x, xp, fp)), rtol=1e-14, atol=1e-15)
    assert float(profiles.interp_without_scatter(jnp.asarray(0.3), jnp.asarray(xp), jnp.asarray(fp))) == pytest.approx(
        float(jnp.interp(0.3, xp, fp)), rel=1e-14)

    def both(values):  # two reads of traced values: the pattern whose scatters XLA fused and aborted on
        return (profiles.interp_without_scatter(jnp.asarray(x), jnp.asarray(xp), values) ** 2).sum() + (
            profiles.interp_without_scatter(jnp.asarray(x[::-1]), jnp.asarray(xp), 2 * values) ** 3).sum()

    grad = jax.jit(jax.grad(both))
    assert "scatter" not in grad.lower(jnp.asarray(fp)).as_text()
    reference = jax.grad(lambda v: (jnp.interp(x, xp, v) ** 2).sum() + (jnp.interp(x[::-1], xp, 2 * v) ** 3).sum())
    np.testing.assert_allclose(np.asarray(grad(jnp.asarray(fp))), np.asarray(reference(jnp.asarray(fp))), rtol=1e-12)


def test_dip_and_feature_losses():
    target = fit.smid_novosad_profile()
    shallow = fit.smid_novosad_profile(dip=0.1)
    assert float(fit.dip_loss(target, 0.25)) == pytest.approx(0.0, abs=1e-24)
    assert float(fit.dip_loss(shallow, 0.25)) == pytest.approx(0.15**2)
    assert float(fit.feature_loss(shallow, target)) == pytest.approx(0.15**2)
    tilted = shallow._replace(horizontal=2.0 * shallow.horizontal)
    slope = float(fit.central_slope(target))
    assert float(fit.feature_loss(tilted, target, dip_weight=0.0, slope_weight=1.0)) == pytest.approx(slope**2)
    g = jax.grad(lambda n: fit.dip_loss(fit.Profile(target.x_over_b, n), 0.25))(jnp.asarray(shallow.normal))
    assert np.all(np.isfinite(np.asarray(g))) and np.abs(np.asarray(g)).max() > 0
    with pytest.raises(InputError, match="central_dip"):
        fit.feature_loss(shallow, target._replace(central_dip=None))


# -------------------------------------------------------------- transforms
def test_transforms_round_trip_and_respect_the_lower_bounds():
    params = hooke.make_params(kn=1e4, mu=0.3, gamma_n=50.0)
    u = fit.to_unconstrained(params, ["kn", "mu"])
    assert float(u["kn"]) == pytest.approx(math.log(1e4)) and float(u["mu"]) == pytest.approx(math.log(0.3))
    back = fit.to_constrained({k: v + 0.0 for k, v in u.items()}, params)
    assert float(back.kn) == pytest.approx(1e4, rel=1e-14) and float(back.mu) == pytest.approx(0.3, rel=1e-14)
    moved = fit.to_constrained({"mu": jnp.asarray(-50.0)}, params)
    assert 0.0 < float(moved.mu) < 1e-20 and float(moved.kn) == 1e4  # stays positive; the rest is untouched
    bax = baxter.make_params(n=36.0, r0=1.2)
    t = fit.Transform.of(bax, ["n", "r0"])
    assert t.lower == (0.0, 1.0)
    ub = t.to_unconstrained(bax)
    assert float(ub["r0"]) == pytest.approx(math.log(0.2))
    assert 1.0 < float(fit.to_constrained({"r0": jnp.asarray(-10.0)}, bax).r0) < 1.0 + 1e-4
    restored = t.to_constrained(ub, bax)
    assert float(restored.n) == pytest.approx(36.0, rel=1e-14) and float(restored.r0) == pytest.approx(1.2)
    mapping = fit.to_constrained(fit.to_unconstrained({"a": 2.0, "b": -1.0}, "a"), {"a": 2.0, "b": -1.0})
    assert float(mapping["a"]) == pytest.approx(2.0) and mapping["b"] == -1.0


def test_transforms_refuse_unknown_names_and_values_at_the_bound():
    params = hooke.make_params(kn=1e4, mu=0.0)
    with pytest.raises(InputError, match=r"unknown parameter\(s\) \['friction'\].*'kn', 'kt', 'gamma_n'"):
        fit.to_unconstrained(params, ["kn", "friction"])
    with pytest.raises(InputError, match="must be finite and > 0"):
        fit.to_unconstrained(params, "mu")
    with pytest.raises(InputError, match="must be finite and > 1"):
        fit.to_unconstrained(baxter.make_params(r0=1.0), "r0")
    with pytest.raises(InputError, match="wall_mu is None"):
        fit.to_unconstrained(params, "wall_mu")
    with pytest.raises(InputError, match="more than once"):
        fit.to_unconstrained(params, ["kn", "kn"])


# ------------------------------------------------------------------ fitting
def _toy_loss(p):
    """A closed-form stand-in for a simulation: the misfit of a smooth M whose
    dip is set by mu and whose flank width is set by kt / kn, with its optimum at
    mu = 0.3, kt = 2000 (kn = 1e4)."""
    u = jnp.linspace(0.0, 1.0, 21)

    def m(mu, ratio):
        return (1.0 - jnp.exp(-((u - 0.5) / (0.1 + ratio)) ** 2) * mu) * jnp.sin(jnp.pi * u)

    return jnp.mean((m(p.mu, p.kt / p.kn) - m(0.3, 0.2)) ** 2) * 1e3


def test_fit_recovers_a_toy_optimum_from_a_perturbed_start():
    start = hooke.make_params(kn=1e4, kt=3500.0, mu=0.45, gamma_n=50.0)
    seen = []
    result = fit.descend(_toy_loss, start, ["mu", "kt"], steps=400, patience=400, callback=seen.append)
    assert float(result.params.mu) == pytest.approx(0.3, rel=1e-3)
    assert float(result.params.kt) == pytest.approx(2000.0, rel=1e-3)
    assert float(result.params.kn) == 1e4 and float(result.params.gamma_n) == 50.0  # not fitted, unchanged
    assert result.initial_params is start
    assert result.loss < 1e-4 * result.history[0]["loss"]
    assert result.loss == min(r["loss"] for r in result.history) == result.history[result.best_step]["loss"]
    assert seen == result.history and set(seen[0]) == {"step", "loss", "mu", "kt", "grad_norm"}
    assert seen[0]["mu"] == pytest.approx(0.45) and seen[0]["grad_norm"] > 0


def test_forward_and_reverse_mode_give_one_gradient_and_one_fit():
    """`mode="forward"` (a jvp per fitted value) and `"reverse"` are the same
    derivative; `"auto"` takes forward mode for a few values, reverse for many."""
    u = {"a": jnp.asarray(0.3), "b": jnp.asarray([1.0, -2.0])}

    def objective(u, scale):
        return scale * (jnp.sin(u["a"]) * jnp.sum(u["b"] ** 3) + jnp.exp(u["b"][0] * u["a"]))

    forward = fit.value_and_gradient(objective, u, "forward")(u, 2.0)
    reverse = fit.value_and_gradient(objective, u, "reverse")(u, 2.0)
    assert float(forward[0]) == pytest.approx(float(reverse[0]), rel=1e-14)
    for key in u:
        np.testing.assert_allclose(forward[1][key], reverse[1][key], rtol=1e-12)
    np.testing.assert_allclose(reverse[1]["b"], 2.0 * (3 * np.sin(0.3) * np.array([1.0, 4.0])
                                                       + np.array([0.3 * np.exp(0.3), 0.0])), rtol=1e-12)
    start = hooke.make_params(kn=1e4, kt=3500.0, mu=0.45, gamma_n=50.0)
    runs = [fit.descend(_toy_loss, start, ["mu", "kt"], steps=30, mode=mode) for mode in ("forward", "reverse")]
    assert [r["loss"] for r in runs[0].history] == pytest.approx([r["loss"] for r in runs[1].history], rel=1e-9)
    with pytest.raises(InputError, match="mode"):
        fit.descend(_toy_loss, start, "mu", mode="sideways")


def test_auto_mode_takes_forward_mode_up_to_the_measured_count_and_explicit_modes_as_given():
    """`mode="auto"` switches to reverse mode above `FORWARD_MODE_MAX` values
    (benchmarks/forward_mode_threshold.py); explicit modes are kept whatever
    the count, and `value_and_gradient` refuses an unknown one."""
    most = fit.FORWARD_MODE_MAX
    assert most >= 1
    assert [fit.gradient_mode(k) for k in (1, most, most + 1, 50)] == ["forward", "forward", "reverse", "reverse"]
    assert fit.gradient_mode(1, "reverse") == "reverse" and fit.gradient_mode(50, "forward") == "forward"
    for bad in (lambda: fit.gradient_mode(3, "sideways"),
                lambda: fit.value_and_gradient(lambda u: u ** 2, jnp.asarray(1.0), "sideways")):
        with pytest.raises(InputError, match="mode"):
            bad()


def test_fit_stops_when_the_loss_stalls_and_with_an_explicit_optimizer():
    params = {"a": 1.0, "b": 2.0}
    result = fit.descend(lambda p: 1.0 + 0.0 * p["a"], params, "a", patience=5, steps=50)
    assert result.converged and result.steps == 5 and len(result.history) == 6
    assert "converged" in result.message
    traces = []

    def loss(p):
        traces.append(1)
        return (jnp.log(p["a"]) - 1.0) ** 2

    result = fit.descend(loss, params, "a", optimizer=optax.sgd(0.4), steps=60)
    assert float(result.params["a"]) == pytest.approx(math.e, rel=1e-6) and result.params["b"] == 2.0
    assert len(traces) == 1  # compiled once: optimiser steps never re-trace the loss


def test_fit_refuses_a_non_finite_start_and_stops_on_a_later_one():
    params = hooke.make_params(kn=1e4, mu=0.3)
    with pytest.raises(InputError, match="loss is nan at the starting parameters"):
        fit.descend(lambda p: jnp.nan * p.mu, params, "mu")
    with pytest.raises(InputError, match="gradient is not finite"):
        fit.descend(lambda p: jnp.sqrt(jnp.maximum(p.mu - 1.0, 0.0)), params, "mu")  # 0, with a NaN slope
    with pytest.raises(InputError, match="scalar"):
        fit.descend(lambda p: jnp.stack([p.mu, p.mu]), params, "mu")

    def blows_up(p):  # pulls mu up, and is NaN beyond mu = 0.4
        return jnp.where(p.mu > 0.4, jnp.nan, (p.mu - 1.0) ** 2)

    with pytest.warns(RuntimeWarning, match="keeping the best parameters"):
        result = fit.descend(blows_up, params, "mu", optimizer=optax.sgd(0.5), steps=50)
    assert not result.converged and "loss is nan" in result.message
    assert 0.3 < float(result.params.mu) <= 0.4
    assert result.loss == pytest.approx((float(result.params.mu) - 1.0) ** 2)


def test_fit_figure(tmp_path):
    import matplotlib.pyplot as plt

    target = fit.smid_novosad_profile(points=21)
    result = fit.descend(lambda p: (jnp.log(p["a"]) - 1.0) ** 2, {"a": 1.0}, "a", steps=5)
    before = fit.Profile(target.x_over_b, np.ones(21), np.zeros(21))
    after = fit.Profile(target.x_over_b, target.normal, target.horizontal)
    fig = fit.fit_figure(result, target, before, after)
    assert len(fig.axes) == 3 and fig.axes[0].get_yscale() == "log"
    assert len(fig.axes[1].lines) == 3  # target, before, after
    plt.close(fig)
    path = fit.fit_figure(result, target, before, after, path=tmp_path / "fit.png")
    assert path.stat().st_size > 1000


# ------------------------------------------------- gradient through a rollout
@pytest.fixture(scope="module")
def rollout_loss(sim):
    """Profile loss of the 3-layer pile after 100 steps of settling under full
    gravity (hooke law), against the Smid-Novosad target, normal and horizontal."""
    params = hooke.make_params(kn=1e4, gamma_n=50.0, mu=0.3)
    particles, boundaries = lattice.equilateral_pile(3)
    state = sim.init(params, particles, boundaries)
    target = fit.smid_novosad_profile()

    def loss(p):
        final = sim.rollout(p, state, ROLLOUT_STEPS)
        profile = fit.smooth_base_profile(fit.base_load(sim, p, final), x_left=0.5, x_right=3.5, bins=7)
        return fit.profile_loss(profile, target, horizontal_weight=1.0)

    return params, jax.jit(jax.value_and_grad(loss))  # one compilation serves the gradient and the differences


def test_gradient_of_a_profile_loss_through_a_rollout_matches_central_differences(rollout_loss):
    params, value_and_grad = rollout_loss
    value, grad = value_and_grad(params)
    g = float(grad.kn)
    kn = float(params.kn)
    h = 1e-6 * kn
    # params.kn + h keeps kn a strongly typed float64: no recompilation
    plus, _ = value_and_grad(params.set(kn=params.kn + h))
    minus, _ = value_and_grad(params.set(kn=params.kn - h))
    fd = (float(plus) - float(minus)) / (2 * h)
    assert abs(g) * kn > 1e-2 * float(value)  # kn really matters to the loss
    assert g == pytest.approx(fd, rel=1e-4)


LATTICE_TRUTH = {"kt": 3000.0, "mu": 0.15}


@pytest.fixture(scope="module")
def lattice_profile(tmp_path_factory):
    """`(profile, csv path)`: the base profile of the 4-layer hooke lattice at
    `LATTICE_TRUTH` (loaded by a gravity ramp), written as a measurement CSV."""
    problem = fit.problem("lattice", "hooke", LATTICE_TRUTH, size=4)
    made = jax.jit(problem.profile)(problem.params)
    target = tmp_path_factory.mktemp("lattice") / "target.csv"
    rows = zip(np.asarray(made.x_over_b), np.asarray(made.normal), np.asarray(made.horizontal))
    lines = [f"{float(x)!r},{float(n)!r},{float(h)!r}" for x, n, h in rows]
    target.write_text("x/B,normal/max,horizontal/max\n" + "\n".join(lines) + "\n")
    return made, target


def test_jaxpile_fit_recovers_kt_and_mu_from_a_profile_jaxpile_made(tmp_path, lattice_profile):
    """The issue's check: a base profile made by jaxpile (4-layer lattice pile,
    hooke law, kt = 3000, mu = 0.15, loaded by a gravity ramp) written as a
    target CSV; `jaxpile fit` from kt = 4000, mu = 0.2 recovers both within 2%."""
    import json

    from jaxpile import cli

    true = LATTICE_TRUTH
    made, shared = lattice_profile
    target = tmp_path / "target.csv"  # a copy: this test removes it
    target.write_text(shared.read_text())
    out = tmp_path / "fit"
    assert cli.main(["fit", "--target", str(target), "--protocol", "lattice", "--layers", "4", "--params", "kt,mu",
                     "--set", "kt=4000", "--set", "mu=0.2", "--steps", "150", "--horizontal-weight", "10",
                     "--no-progress", "--out", str(out)]) == 0
    record = json.loads((out / "fit.json").read_text())
    assert record["initial"] == {"kt": 4000.0, "mu": 0.2}
    for name, value in true.items():
        assert record["fitted_values"][name] == pytest.approx(value, rel=0.02), name
    assert record["loss"] < 1e-3 * record["initial_loss"]
    assert (out / "fit.png").stat().st_size > 10_000
    np.testing.assert_allclose(record["target_profile"]["normal"], np.asarray(made.normal), rtol=1e-12)
    # `jaxpile show` redraws the fit from fit.json alone, even once the target file is gone
    target.unlink()
    assert cli.main(["show", str(out), "--out", str(tmp_path / "redrawn")]) == 0
    assert (tmp_path / "redrawn" / "fit.png").stat().st_size > 10_000


def test_calibrate_with_the_pathwise_estimator_fits_one_lattice_pile_to_a_measured_profile(lattice_profile,
                                                                                            tmp_path):
    """`jaxpile.calibrate(..., estimator="pathwise")`: the gradient through one
    deterministic pile, as `jaxpile fit --estimator pathwise` takes it; mu from
    0.2 back to the profile's 0.15 (kt held at its truth). What it cannot take
    is refused in one line before a pile is built: a random protocol, an
    ensemble, scalars."""
    made, csv = lattice_profile
    done = jaxpile.calibrate("lattice", csv, "mu", estimator="pathwise", law="hooke", options={"layers": 4},
                             start={"kt": LATTICE_TRUTH["kt"], "mu": 0.2}, steps=60, progress=False)
    assert float(done.result.params.mu) == pytest.approx(LATTICE_TRUTH["mu"], rel=2e-3)
    assert done.result.loss < 1e-3 * done.result.history[0]["loss"]
    np.testing.assert_allclose(np.asarray(done.target.normal), np.asarray(made.normal), rtol=1e-12)
    scalars = tmp_path / "m.toml"
    scalars.write_text("[scalars]\nangle_of_repose = { value = 20.0, stderr = 1.0 }\n")
    for protocol, measured, more, match in (("pour", csv, {}, "builds random piles"),
                                            ("lattice", csv, {"ensemble": 4}, "ensemble are for the ensemble"),
                                            ("lattice", scalars, {}, "holds scalars angle_of_repose"),
                                            ("lattice", csv, {"estimator": "newton"}, "must be one of")):
        with pytest.raises(InputError, match=match):
            jaxpile.calibrate(protocol, measured, "mu", **{"estimator": "pathwise", **more}, progress=False)


def test_a_pathwise_dry_run_refuses_a_start_the_fit_cannot_take_the_log_of(tmp_path, capsys):
    """The hooke lattice's mu starts at 0, which a fit in log space cannot start
    from: the dry run says so in one line, as the run does, before a pile is built."""
    from jaxpile.cli import main

    argv = ["fit", "--protocol", "lattice", "--law", "hooke", "--params", "mu", "--target", "smid-novosad",
            "--layers", "3", "--steps", "1", "--dry-run", "--out", str(tmp_path / "fit")]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "mu must be finite and > 0 to be fitted in log space" in err
    assert main(argv[:-2] + ["--set", "mu=0.2", "--out", str(tmp_path / "fit2")]) == 0
