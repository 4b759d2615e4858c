"""The 1997 pouring protocol (Baxter, Tuzun, Burnell & Heyes): small heaps poured at
the paper's rate onto a row of fixed disks, with the baxter law and with hooke."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxpile
from jaxpile.errors import InputError
from jaxpile.cli.presentation import presentation
from jaxpile.protocols import pour, running
from jaxpile.measure import analysis, poured_heap
from jaxpile.measure import heap

N = 48  # disks per test heap (the paper: 1334)
RELEASE = 14.0  # sigma above the substrate (the paper: 100; the smallest allowed for N is 10.4)
TOLERANCE = 1.0e-4  # rest: every disk slower than this, (sigma g)^(1/2)


def _heap(law, polydispersity, seed):
    sim = pour.make_simulator(law)
    params = pour.law_params(law)
    o = pour.PourOptions(n=N, release_height=RELEASE, polydispersity=polydispersity, speed_tolerance=TOLERANCE,
                         max_settle_steps=150_000)
    protocol = pour.setup(o, law=law, seed=seed, dt=sim.dt)
    state, info, _ = running.run_setup(pour.SPEC, sim, params, protocol, o)
    return sim, params, protocol, state, info, poured_heap.measure(sim, params, state)


@pytest.fixture(scope="module")
def baxter_heap():
    """Monodisperse, the paper's law (n = 36, r0 = 1.2 sigma, mu = 0.5)."""
    return _heap("baxter", 0.0, seed=1)


@pytest.fixture(scope="module")
def hooke_heap():
    """10% polydisperse, the paper's equivalent Hooke law (k = 500 mg / sigma)."""
    return _heap("hooke", 0.1, seed=2)


# ----------------------------------------------------------------- the set-up
def test_setup_follows_the_paper():
    p = pour.SPEC.set_up("baxter", N, release_height=RELEASE, seed=3)
    info, ps, part = p.info, p.protocol_state, p.particles
    rows = info["n_substrate"]
    assert part.count == rows + N
    fixed, active = np.asarray(part.fixed), np.asarray(part.active)
    assert fixed[:rows].all() and active[:rows].all()  # the substrate: fixed, in play
    assert not fixed[rows:].any() and not active[rows:].any()  # the rest parked
    assert not np.asarray(p.boundaries.wall_active).any()  # the row is the only support
    pos = np.asarray(part.position)
    np.testing.assert_allclose(np.diff(pos[:rows, 0]), 1.1)  # S = 1.1 sigma
    np.testing.assert_allclose(pos[:rows, 1], 0.5)
    # parked disks far from each other and from the release point
    parked = pos[rows:]
    gaps = np.linalg.norm(parked[:, None] - parked[None], axis=-1) + 1e9 * np.eye(N)
    assert gaps.min() >= pour.PARK_SPACING - 1e-9
    release = np.asarray(ps.release_position)[rows:]
    assert parked[:, 1].min() > release[:, 1].max() + 4.0
    # released at rest at 14 sigma, x uniform in +-3 sigma about the row's middle
    np.testing.assert_allclose(release[:, 1], 0.5 + RELEASE)
    assert np.all(np.abs(release[:, 0] - info["centre_x"]) <= 3.0)
    assert np.ptp(release[:, 0]) > 4.0
    np.testing.assert_array_equal(np.asarray(ps.release_velocity), [0.0, 0.0])
    # the paper's rate: one disk every 1.612 time units = 1612 steps of 1e-3
    assert info["interval_steps"] == 1612 and int(ps.interval) == 1612
    # the row is long enough for a 15-degree heap
    assert info["substrate_length"] > 2 * math.sqrt(N * math.pi / 4 / 0.8 / math.tan(math.radians(15)))
    np.testing.assert_allclose(np.asarray(part.radius)[rows:], 0.5)  # monodisperse by default


def test_polydisperse_diameters_are_uniform_in_the_paper_range():
    """delta% polydisperse: diameters uniform in ((1 - delta) sigma, sigma)."""
    for delta in (0.05, 0.1):
        p = pour.SPEC.set_up("baxter", 400, release_height=40.0, polydispersity=delta, seed=4)
        d = 2 * np.asarray(p.particles.radius)[p.info["n_substrate"]:]
        assert d.min() >= 1 - delta and d.max() <= 1.0
        assert d.min() < 1 - 0.97 * delta and d.max() > 1 - 0.03 * delta  # fills the range
        assert abs(d.mean() - (1 - delta / 2)) < 0.1 * delta  # mean (1 - delta/2) sigma, as the paper says
        m = np.asarray(p.particles.mass)[p.info["n_substrate"]:]
        np.testing.assert_allclose(m, d**2)  # uniform areal density, sigma-disk of mass 1


def test_bad_arguments_raise_input_errors():
    with pytest.raises(InputError, match="n must be"):
        pour.SPEC.set_up("baxter", 0)
    with pytest.raises(InputError, match="polydispersity"):
        pour.SPEC.set_up("baxter", 10, release_height=20, polydispersity=5)  # 5 meant as 5%
    with pytest.raises(InputError, match="spacing"):
        pour.SPEC.set_up("baxter", 10, release_height=20, spacing=2.05)  # disks would fall through the gaps
    with pytest.raises(InputError, match="release_height"):
        pour.SPEC.set_up("baxter", 400, release_height=10)  # inside the heap
    with pytest.raises(InputError, match="insert_height"):
        pour.SPEC.set_up("baxter", 10, release_height=20, insert_height=30)
    with pytest.raises(InputError, match="interval"):
        pour.SPEC.set_up("baxter", 10, release_height=20, interval=0)
    with pytest.raises(InputError, match="touch in the air"):
        pour.SPEC.set_up("baxter", 10, release_height=20, interval=1.0)  # the previous disk only 0.5 sigma below
    with pytest.raises(InputError, match="substrate_disks"):
        pour.SPEC.set_up("baxter", 10, release_height=20, substrate_disks=2)
    with pytest.raises(InputError, match="narrower"):
        pour.SPEC.set_up("baxter", 10, release_height=20, substrate_disks=4, spread=3.0)
    with pytest.raises(InputError, match="substrate row.*would fit"):  # refused before the row is allocated
        pour.SPEC.set_up("baxter", 1, release_height=100, substrate_disks=1e300)
    # a voidage map too fine for the memory: refused before the pour (it used to fail after it, with a traceback)
    with pytest.raises(InputError, match="voidage_cell = 1e-06"):
        pour.SPEC.run("hooke", 6, release_height=10, voidage_cell=1e-6)
    with pytest.raises(InputError, match="bins .* at most the substrate"):  # 1e12 bins: the same, after the pour
        pour.SPEC.run("hooke", 6, release_height=10, bins=1e12)
    with pytest.raises(InputError, match="dt"):
        running.run_setup(pour.SPEC, pour.make_simulator("hooke", dt=5e-4), pour.law_params("hooke"),
                          pour.SPEC.set_up("hooke", 10, release_height=20), pour.PourOptions(n=10, release_height=20))
    with pytest.raises(InputError, match="unknown law"):
        pour.SPEC.run("sand", 10)


def test_the_spec_holds_the_run_options_and_its_simulator_reads_law_options():
    """The pour's options hold its run options (rest, settling budget, bins,
    voidage cell) beside the set-up's; its simulator runs leapfrog (the paper's
    eqs. 9-12) with the run's `law_options` (the law's readings, a keyword of
    every protocol's run, not an option of the pour), and a run records them in its info."""
    from jaxpile.engine.integrators import get_integrator
    from jaxpile.protocols import spec

    declared = spec.ranges_of(pour.PourOptions)
    assert {"n", "spacing", "insert_height", "speed_tolerance", "max_settle_steps", "bins", "voidage_cell"} <= set(
        declared)
    assert "law_options" not in pour.PourOptions.names()
    sim = pour.SPEC.simulator(pour.PourOptions(), law="baxter", dt=1e-3, law_options={"lever_arm": "centre-distance"})
    assert dict(sim.law.options)["lever_arm"] == "centre-distance"
    assert sim.integrator is get_integrator("leapfrog") and sim.chunk_steps == 2000
    _, m = pour.SPEC.run("hooke", 2, release_height=5.0, law_options={}, speed_tolerance=1e-2,
                         max_settle_steps=20_000)
    assert m["info"].get("law_options", {}) == {} and m["counts"]["poured"] == 2 and m["at_rest"]


# ------------------------------------------------------------- the poured heaps
def _check_heap(heap, angle_range):
    sim, params, protocol, state, info, m = heap
    counts = m["counts"]
    # every disk poured, none lost off the row's ends, none left behind: all on the heap
    assert counts["poured"] == N and counts["total"] == N
    assert counts["in_play"] == N and counts["lost"] == 0 and counts["parked"] == 0
    assert counts["strays"] == 0
    assert state.particles.count == protocol.particles.count
    np.testing.assert_array_equal(state.particles.fixed, protocol.particles.fixed)
    pos = np.asarray(state.particles.position)
    rows = protocol.info["n_substrate"]
    np.testing.assert_array_equal(pos[:rows], np.asarray(protocol.particles.position)[:rows])  # never moved
    assert pos[rows:, 1].min() > 0.5  # on top of the row, none wedged in it
    # at rest
    assert info.at_rest and float(jaxpile.max_speed(state)) < TOLERANCE
    assert info.steps >= protocol.info["pour_steps"]
    # the substrate carries the whole heap
    mass = np.asarray(state.particles.mass)[rows:]
    assert m["weight"] == pytest.approx(N)  # in mg, m the mean poured mass
    assert m["substrate_normal_total"] * mass.mean() == pytest.approx(mass.sum(), rel=1e-4)
    assert abs(m["force_balance"]) < 1e-4
    assert np.all(m["substrate_forces"].normal > -1e-6)  # the base only pushes
    # a heap, roughly symmetric about the pouring point
    width, height = m["base_width"], m["height"]
    assert 3.0 < height < width / 2
    assert abs(m["asymmetry"]["apex_offset"]) < width / 6
    assert abs(m["asymmetry"]["mass_centre_offset"]) < width / 10
    lo, hi = angle_range
    for flank in ("left", "right"):
        a = m["angles"][flank]
        assert lo < a.least_squares < hi and lo < a.cumulative_parabola < hi, (flank, a)
    left, right = m["angles"]["left"], m["angles"]["right"]
    assert abs(left.least_squares - right.least_squares) < 12.0
    assert lo < m["angle_height_base"] < hi
    assert m["angles"]["left"].slopes[1] > 0 > m["angles"]["right"].slopes[1]  # rising, then falling
    # the base profile: normalised, over (0, 1), and the voidage map of a dense heap
    prof = m["base_profile"]
    assert prof.normalised.max() == pytest.approx(1.0) and len(prof.force) % 2 == 1
    assert prof.force.sum() == pytest.approx(m["substrate_normal_total"], rel=1e-9)
    assert 0.0 < prof.x_over_b.min() and prof.x_over_b.max() < 1.0
    assert m["m_shape"].ratio > 0
    assert 0.75 < m["core_packing_fraction"] < 0.95
    vm = m["voidage"]
    assert vm.packing_fraction.max() < 1.0 and vm.packing_fraction.max() > 0.7
    return m


def test_baxter_heap_stands_at_rest_on_the_substrate(baxter_heap):
    """The paper's law: the paper's angle is 35 +- 5 deg; a 48-disk heap lies near it."""
    m = _check_heap(baxter_heap, (20.0, 45.0))
    s = poured_heap.summary(m)
    assert s["counts"]["in_play"] == N and isinstance(s["m_shape"]["m_shaped"], bool)


def test_hooke_polydisperse_heap_stands_at_rest_on_the_substrate(hooke_heap):
    m = _check_heap(hooke_heap, (10.0, 45.0))
    sim, params, protocol, state, info, _ = hooke_heap
    d = 2 * np.asarray(state.particles.radius)[protocol.info["n_substrate"]:]
    assert d.min() >= 0.9 and d.max() <= 1.0 and np.ptp(d) > 0.07


def test_substrate_forces_are_the_contacts_with_fixed_disks(baxter_heap):
    """Against a hand sum over the neighbour slots: each heap-substrate contact
    once, sorted by x, between its two centres; the horizontal forces balance
    (no net push along the base at rest)."""
    sim, params, protocol, state, info, m = baxter_heap
    f = m["substrate_forces"]
    rows = protocol.info["n_substrate"]
    assert np.all(np.diff(f.x) >= 0)
    assert np.all(f.substrate < rows) and np.all(f.particle >= rows)
    pairs = set(zip(f.particle.tolist(), f.substrate.tolist()))
    assert len(pairs) == len(f.x)
    pos = np.asarray(state.particles.position)
    assert np.all((f.x - pos[f.substrate, 0]) * (f.x - pos[f.particle, 0]) <= 1e-12)
    cf = sim.contact_forces(params, state)
    up = np.asarray(cf.force)[rows:, 1] + np.asarray(state.particles.mass)[rows:] * -1.0
    assert abs(up.sum()) < 1e-3  # net force on the heap ~ 0 at rest
    assert abs(f.horizontal.sum()) < 1e-3 * N


def test_release_rate_and_free_fall_shortcut(baxter_heap):
    """Disks are released every 1612 steps inside one compiled chunk, and the
    `insert_height` shortcut gives them the speed of the fall from `release_height`."""
    sim, params, _, _, _, _ = baxter_heap
    shortcut = pour.SPEC.set_up("baxter", N, release_height=RELEASE, insert_height=11.0, seed=1)
    assert shortcut.info["insert_speed"] == pytest.approx(math.sqrt(2 * (RELEASE - 11.0)))
    state = sim.init(params, shortcut.particles, shortcut.boundaries, protocol_state=shortcut.protocol_state)
    rows = shortcut.info["n_substrate"]
    state = sim.run(params, state, 1612 + 1, progress=False)
    active = np.asarray(state.particles.active)[rows:]
    assert active.sum() == 2 and active[:2].all() and int(state.protocol_state.poured) == 2
    # the first disk, 1613 steps after appearing at 11 sigma with the speed of a
    # fall from 14 sigma, is still falling, at the speed of a free fall from 14 sigma
    y = float(state.particles.position[rows, 1]) - 0.5
    v = -float(state.particles.velocity[rows, 1])
    assert 1.5 < y < 11.0 - 4.0
    assert v == pytest.approx(math.sqrt(2 * (RELEASE - y)), rel=2e-3)
    state = sim.run(params, state, 1612, progress=False)
    active = np.asarray(state.particles.active)[rows:]
    assert active.sum() == 3 and active[:3].all() and int(state.protocol_state.poured) == 3


def test_a_disk_that_leaves_the_row_is_counted_lost(baxter_heap):
    """A disk whose centre falls below the row is taken out of play, parked, and
    counted lost: poured = in play + lost, inside the compiled loop."""
    sim, params, protocol, state, _, _ = baxter_heap
    rows = protocol.info["n_substrate"]
    top = rows + int(np.argmax(np.asarray(state.particles.position)[rows:, 1]))
    p = state.particles
    state = state.set(particles=p.set(position=p.position.at[top].set(jnp.array([-20.0, -5.0]))))
    state = sim.run(params, state, 1, progress=False)
    m = poured_heap.measure(sim, params, state)
    assert m["counts"]["lost"] == 1 and m["counts"]["in_play"] == N - 1 and m["counts"]["poured"] == N
    assert not bool(state.particles.active[top]) and bool(state.protocol_state.lost[top])
    np.testing.assert_allclose(state.particles.position[top], protocol.particles.position[top])


def test_m_shape_and_base_profile_on_synthetic_forces():
    """The M-shape ratio is flank maximum over the central bin."""
    x = np.linspace(0.05, 9.95, 100)
    m_profile = 1.0 + 0.25 * np.sin(np.pi * x / 10) ** 2 - 0.25 * np.exp(-((x - 5) / 1.0) ** 2) * 2
    forces = analysis.SubstrateForces(x=x, normal=m_profile, horizontal=0 * x, particle=0 * x, substrate=0 * x)
    prof = heap.base_profile(forces, extent=(0.0, 10.0), bins=11)
    assert prof.width == 10.0 and len(prof.force) == 11
    np.testing.assert_allclose(prof.x_over_b, (np.arange(11) + 0.5) / 11)
    shape = heap.m_shape(prof)
    assert shape.m_shaped and shape.left_ratio > 1.2 and shape.right_ratio > 1.2
    flat = heap.base_profile(forces._replace(normal=np.ones_like(x)), extent=(0.0, 10.0), bins=10)
    assert len(flat.force) == 11  # made odd
    assert not heap.m_shape(flat).m_shaped
    tent = heap.base_profile(forces._replace(normal=5 - np.abs(x - 5)), extent=(0.0, 10.0), bins=11)
    assert heap.m_shape(tent).ratio < 1.0
    # the window ratio (flanks x/B 0.2-0.4, 0.6-0.8 over the centre 0.4-0.6): an M above 1, flat 1, a tent below
    assert heap.flank_over_centre(prof) > 1.1 and heap.flank_over_centre(tent) < 0.9
    # by hand on 5 bins at x/B 0.1 ... 0.9: flank windows hold 0.3 and 0.7, the centre 0.5
    def five(values):
        return heap.BaseProfile(np.arange(5) / 5 + 0.1, None, np.asarray(values, float), 0.0, 1.0)

    assert heap.flank_over_centre(five([0.2, 1.0, 0.5, 0.8, 0.1])) == pytest.approx(0.5 * (1.0 + 0.8) / 0.5)
    assert heap.flank_over_centre(five(np.ones(5))) == 1.0


def test_dip_below_flanks_reads_smid_novosad_dip_in_fixed_windows():
    """`heap.dip_below_flanks`: 1 - the centre over the flanks in windows fixed
    in advance (Smid & Novosad's dip, 20-30 % below the maximum, as Liffman et
    al. 1992 report it): by hand on 15 bins; the declared M of
    `fit.smid_novosad_profile` (dip 0.25) reads a little under 0.25 (the flanks'
    mean lies under their maxima); a narrow dip that the pour's default ~9 bins
    average away still reads; no dip, a tent, a flat base read <= 0."""
    from jaxpile import fit

    def fifteen(values):
        return heap.BaseProfile((np.arange(15) + 0.5) / 15, np.asarray(values, float), None, 0.0, 1.0)

    bins = np.ones(15)
    bins[[3, 4, 10, 11]] = [1.0, 1.2, 0.8, 1.0]  # the flank windows (x/B 0.20-0.33, 0.67-0.80): mean 1.0
    bins[7] = 0.7  # the centre window (x/B 0.47-0.53); bins 6 and 8 beside it are read by no window
    bins[[6, 8]] = [9.0, 9.0]
    assert heap.dip_below_flanks(fifteen(bins)) == pytest.approx(0.3)
    assert heap.dip_below_flanks(fifteen(np.ones(15))) == 0.0
    assert math.isnan(heap.dip_below_flanks(fifteen(np.where(np.isin(np.arange(15), [3, 4, 10, 11]), 0.0, 1.0))))
    assert math.isnan(heap.dip_below_flanks(heap.BaseProfile(np.array([0.1, 0.9]), np.ones(2), None, 0.0, 1.0)))
    one_flank = heap.BaseProfile(np.array([0.3, 0.5, 0.9]), np.ones(3), None, 0.0, 1.0)  # no bin at x/B 0.65-0.8
    assert math.isnan(heap.dip_below_flanks(one_flank))

    def forces(normal_of_u, points=2001):  # dense contacts along a base of length 10
        u = (np.arange(points) + 0.5) / points
        return analysis.SubstrateForces(x=10 * u, normal=normal_of_u(u), horizontal=0 * u, particle=0 * u,
                                        substrate=0 * u)

    target = fit.smid_novosad_profile(2001, dip=0.25)
    declared = heap.base_profile(forces(lambda u: np.interp(u, target.x_over_b, target.normal)), extent=(0.0, 10.0),
                                 bins=heap.DIP_BINS)
    assert 0.2 < heap.dip_below_flanks(declared) < 0.25
    narrow = forces(lambda u: 1.0 - 0.3 * np.exp(-(((u - 0.5) / 0.03) ** 2)))  # a dip a twentieth of the base wide
    assert heap.dip_below_flanks(heap.base_profile(narrow, extent=(0.0, 10.0), bins=heap.DIP_BINS)) > 0.2
    assert heap.central_dip(heap.base_profile(narrow, extent=(0.0, 10.0), bins=9)) < 0.15
    tent = forces(lambda u: 1.0 - np.abs(u - 0.5))
    assert heap.dip_below_flanks(heap.base_profile(tent, extent=(0.0, 10.0), bins=heap.DIP_BINS)) < -0.2


def test_a_poured_heap_reads_its_dip_below_flanks_when_its_base_is_wide_enough(baxter_heap, monkeypatch):
    """The pour reads `dip_below_flanks` on a `heap.DIP_BINS`-bin profile of its
    own base (summary, sweep row, headline) only when each bin is at least a
    substrate spacing wide: the 48-disk test heap's base is not on 40 bins, and reads NaN;
    on 5 bins it is, and the row holds 1 - the centre bin over its two neighbours."""
    sim, params, protocol, state, info, m = baxter_heap
    spacing = protocol.info["spacing"]
    # 40 bins a spacing wide are a base of 44 sigma, which 48 disks never spread over (on any CPU;
    # the default 15 lies a column or two from this heap's width)
    monkeypatch.setattr(poured_heap, "DIP_BINS", 40)
    narrow = poured_heap.measure(sim, params, state)
    assert narrow["base_width"] < 40 * spacing and "dip_profile" not in narrow
    assert math.isnan(poured_heap.sweep_row(narrow)["dip_below_flanks"])
    monkeypatch.setattr(poured_heap, "DIP_BINS", 5)
    wide = poured_heap.measure(sim, params, state)
    f = heap.base_profile(wide["substrate_forces"], extent=wide["extent"], bins=5).force
    expected = 1.0 - f[2] / (0.5 * (f[1] + f[3]))
    assert poured_heap.summary(wide)["dip_below_flanks"] == pytest.approx(expected, rel=1e-12)
    assert poured_heap.sweep_row(wide)["dip_below_flanks"] == pytest.approx(expected, rel=1e-12)
    assert "dip_below_flanks" in presentation("pour").headline
    # the row's columns, declared so that an ensemble fit refuses an unknown statistic before a heap is poured
    assert tuple(poured_heap.sweep_row(m)) == tuple(poured_heap.sweep_row(wide)) == poured_heap.ROW_COLUMNS


@pytest.mark.parametrize("law", ["lee-herrmann", "liffman"])
def test_pours_with_every_law(law):
    """The other two laws with their pour settings: disks are released, fall and
    land on the row with nothing lost or non-finite (a short pour)."""
    sim = pour.make_simulator(law)
    params = pour.law_params(law)
    protocol = pour.SPEC.set_up(law, 4, release_height=5.0)
    state = sim.init(params, protocol.particles, protocol.boundaries, protocol_state=protocol.protocol_state)
    state = sim.run(params, state, protocol.info["pour_steps"], progress=False)
    state, info = sim.run_until_rest(params, state, speed_tolerance=1e-2, max_steps=30_000, progress=False)
    assert info.at_rest
    m = poured_heap.measure(sim, params, state)
    assert m["counts"]["poured"] == 4 and m["counts"]["in_play"] == 4 and m["counts"]["lost"] == 0
    y = np.asarray(state.particles.position)[protocol.info["n_substrate"]:, 1]
    assert np.all(np.isfinite(y)) and y.max() < 4.0 and y.min() > 0.5  # landed, none through the row
    # each one rests on something: a contact with the row or another disk
    cf = sim.contact_forces(params, state)
    rows = protocol.info["n_substrate"]
    assert np.asarray(cf.pair.in_contact)[rows:].any(axis=1).all()
    assert m["substrate_normal_total"] > 0


def test_a_pour_run_on_blocks_of_its_poured_disks_is_bit_identical_to_the_full_run():
    """`Simulator(in_play=pour.in_play)` runs each chunk on the smallest block of
    leading disks holding those poured by its end (`jaxpile.engine.blocks`): here 64 of
    145 disks for two chunks, then all. Same arithmetic in the same order, so the
    same state bit for bit as carrying every parked disk from the start."""
    protocol = pour.SPEC.set_up("hooke", 100, insert_height=14.0, interval=0.15, seed=4)
    params = pour.law_params("hooke")
    states = {}
    for blocked in (True, False):
        sim = pour.make_simulator("hooke", chunk_steps=1000, **({} if blocked else {"in_play": None}))
        state = sim.init(params, protocol.particles, protocol.boundaries, protocol_state=protocol.protocol_state)
        if blocked:
            assert jaxpile.engine.blocks.block_size(pour.in_play(state, 1000), state.particles.count) == 64
        states[blocked] = sim.run(params, state, 4000, progress=False)
    a, b = states[True], states[False]
    assert int(a.protocol_state.poured) == 27 and a.particles.count == 145
    for x, y in zip(jax.tree.leaves(a.particles), jax.tree.leaves(b.particles)):
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))
    np.testing.assert_array_equal(a.contacts.pairs, b.contacts.pairs)
    np.testing.assert_array_equal(a.contacts.history, b.contacts.history)
    np.testing.assert_array_equal(a.neighbors.idx, b.neighbors.idx)


def test_block_sizes_step_by_two_then_finer_and_each_must_save_enough():
    """`blocks.block_size`: powers of two below FINE_BLOCK (a block leaving
    out half the disks), then 1.5x / 4/3x steps (leaving out an eighth): the
    1000-disk race's 1121 disks run on 768 with 513-768 in play, not on all."""
    size = jaxpile.engine.blocks.block_size
    assert [size(k, 1121) for k in (1, 65, 200, 300, 513, 768, 769)] == [64, 128, 256, 512, 768, 768, None]
    assert [size(k, 10**6) for k in (513, 769, 1025, 1537, 2049, 3073)] == [768, 1024, 1536, 2048, 3072, 4096]
    assert size(48, 83) is None and size(100, 145) is None  # 64 and 128 would save too little
    assert size(600, 800) is None and size(600, 878) == 768  # 768 <= 7/8 of the disks


def test_a_flat_floor_carries_the_disks_on_the_ground_and_loses_those_past_its_ends(baxter_heap):
    """Sec. II's first attempt, `floor="flat"`: the row switched off (its disks
    mark the span), the ground wall under it; a disk resting on it is carried
    (its base force is its weight), one whose centre passes an end is lost."""
    sim, params, row_setup, _, _, _ = baxter_heap
    o = pour.PourOptions(n=N, release_height=RELEASE, floor="flat")
    flat = pour.setup(o, law="baxter", seed=1, dt=sim.dt)
    rows = flat.info["n_substrate"]
    assert flat.info["floor"] == "flat" and row_setup.info["floor"] == "row"
    assert not np.asarray(flat.particles.active)[:rows].any() and np.asarray(flat.particles.fixed)[:rows].all()
    assert bool(flat.boundaries.wall_active[0]) and not bool(row_setup.boundaries.wall_active[0])
    ends = np.asarray(flat.protocol_state.ends)
    x_row = np.asarray(flat.particles.position)[:rows, 0]
    np.testing.assert_array_equal(ends, [x_row[0] - 0.5, x_row[-1] + 0.5])
    assert np.isinf(np.asarray(row_setup.protocol_state.ends)).all()

    state = sim.init(params, flat.particles, flat.boundaries, protocol_state=flat.protocol_state)
    rest, leaving = rows + N - 1, rows + N - 2  # two of the last disks to pour: released long after these steps
    p = state.particles
    middle = float(flat.info["centre_x"])
    p = p.set(position=p.position.at[rest].set(jnp.array([middle, 0.5])).at[leaving].set(jnp.array([ends[1] - 0.01, 0.5])),
              velocity=p.velocity.at[leaving].set(jnp.array([1.0, 0.0])),
              active=p.active.at[rest].set(True).at[leaving].set(True))
    state = sim.run(params, state.set(particles=p), 20, progress=False)
    m = poured_heap.measure(sim, params, state)
    assert m["counts"]["lost"] == 1 and bool(state.protocol_state.lost[leaving])
    on_floor = m["substrate_forces"]
    assert rest in on_floor.particle.tolist() and (on_floor.substrate == -1).all()
    np.testing.assert_allclose(on_floor.normal[on_floor.particle.tolist().index(rest)], 1.0, rtol=1e-9)
