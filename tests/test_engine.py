"""Engine invariants: Newton's third law, neighbour list == all pairs, history
carried across rebuilds and cleared on separation, overflow re-runs, purity."""

import functools
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxpile
from jaxpile.engine import interactions
from jaxpile.laws import hooke
from jaxpile.engine import neighbors as nb
from jaxpile.engine import pairs as pair_list
from jaxpile.engine import host_lists
from jaxpile.engine.pairs import carry_history, contacts_for, half_pairs, pair_capacity, pair_entry
from jaxpile.protocols import lattice
from jaxpile.engine.simulate import Simulator


PARAMS = hooke.make_params(kn=2000.0, gamma_n=20.0, mu=0.4)


@pytest.fixture(scope="module")
def agitated():
    """A squeezed 8-layer pile of unequal disks with random velocities and spins,
    after 300 steps (so many contacts carry shear history)."""
    rng = np.random.default_rng(2)
    pos = lattice.equilateral_positions(8) * 0.99 + rng.normal(0, 0.003, (36, 2))
    rad = rng.uniform(0.49, 0.5, 36)
    particles = jaxpile.make_particles(pos, rad, velocity=rng.normal(0, 0.3, pos.shape),
                                       angular_velocity=rng.normal(0, 1.0, len(rad)))
    boundaries = jaxpile.make_boundaries(left=0.0, right=10.0)
    sim = Simulator(hooke.law(), dt=2e-4, chunk_steps=100)
    state = sim.init(PARAMS, particles, boundaries)
    state = sim.run(PARAMS, state, 300, progress=False)
    return sim, state


def test_newton_third_law_pair_forces_sum_to_zero(agitated):
    sim, state = agitated
    cf = sim.contact_forces(PARAMS, state)
    assert int(cf.pair.in_contact.sum()) > 20
    total = np.asarray(cf.pair.force).sum(axis=(0, 1))
    scale = np.abs(np.asarray(cf.pair.force)).sum()
    assert np.all(np.abs(total) < 1e-13 * scale)


def test_torques_come_from_the_tangential_force_at_the_contact_point(agitated):
    """Angular momentum about the contact point: each disk's torque is
    (contact point - centre) x F, the contact point at distance r_i along -n; the
    two sides of a pair feel opposite forces at the same point, so
    tau_i / r_i == tau_j / r_j."""
    sim, state = agitated
    cf = sim.contact_forces(PARAMS, state)
    idx = np.asarray(state.neighbors.idx)
    pos = np.asarray(state.particles.position)
    r = np.asarray(state.particles.radius)
    tau, force = np.asarray(cf.pair.torque), np.asarray(cf.pair.force)
    pairs = list(zip(*np.nonzero(np.asarray(cf.pair.in_contact))))
    assert len(pairs) > 40
    for i, k in pairs:
        j = idx[i, k]
        n = (pos[i] - pos[j]) / np.linalg.norm(pos[i] - pos[j])
        lever = -r[i] * n
        assert tau[i, k] == pytest.approx(lever[0] * force[i, k, 1] - lever[1] * force[i, k, 0], abs=1e-12)
        kk = int(np.flatnonzero(idx[j] == i)[0])
        assert tau[i, k] / r[i] == pytest.approx(tau[j, kk] / r[j], rel=1e-10, abs=1e-12)
    assert np.abs(tau).max() > 1e-3  # the disks spin and slide: the torques are not trivially zero


def test_neighbor_list_forces_equal_all_pairs(agitated):
    sim, state = agitated
    p = state.particles
    n = p.count
    all_idx = jnp.asarray([[j for j in range(n) if j != i] for i in range(n)], jnp.int32)
    contacts = contacts_for(state.contacts, state.neighbors.idx, all_idx, pair_capacity(n, n - 1))  # room for all
    brute = interactions.evaluate(sim.law, PARAMS, p, contacts, state.boundaries, 0.0)
    listed = sim.contact_forces(PARAMS, state)
    np.testing.assert_allclose(listed.force, brute.force, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(listed.torque, brute.torque, rtol=1e-12, atol=1e-12)


def _within_reach(pos, reach):
    d = np.linalg.norm(pos[:, None] - pos[None], axis=-1)
    np.fill_diagonal(d, np.inf)
    return [set(np.flatnonzero(row < reach)) for row in d]


def test_cell_list_finds_every_pair_within_reach_inside_and_outside_its_box_and_flags_overflow():
    """`neighbors.allocate` and `rebuild` (the sorted cell list) against all
    pairs: 300 disks, two thirds of them outside the box (clamped into its
    border cells), then moved; then squeezed until the slots and the window
    overflow, which must raise the flag rather than drop a neighbour silently."""
    rng = np.random.default_rng(3)
    settings = nb.NeighborSettings((12.0, 9.0), 1.0, 0.2, 1.5)
    pos = rng.uniform(-1.0, 2.0, (300, 2)) * np.array(settings.box)
    nbrs = nb.allocate(settings, pos)
    assert not bool(nbrs.did_buffer_overflow)
    assert [set(r[r < 300]) for r in np.asarray(nbrs.idx)] == _within_reach(pos, 1.2)
    moved = pos + rng.normal(0.0, 0.3, pos.shape)
    again = nb.rebuild(nbrs, jnp.asarray(moved), settings)
    assert not bool(again.did_buffer_overflow)
    assert [set(r[r < 300]) for r in np.asarray(again.idx)] == _within_reach(moved, 1.2)
    squeezed = nb.rebuild(nbrs, jnp.asarray(0.2 * moved + 4.0), settings)
    assert bool(squeezed.did_buffer_overflow)


def test_cell_table_and_binary_search_find_the_same_sorted_rows_and_a_full_row_keeps_its_lowest(monkeypatch):
    """`_build` reads where each run of cells starts from a table of cells, or
    by binary search when the grid is far larger than its disks: both give the
    same list, each row the neighbours in increasing index order, on a clustered
    set with disks outside the box. A row with more neighbours than slots keeps
    its lowest indices (and the occupancy says it overflowed)."""
    rng = np.random.default_rng(5)
    settings = nb.NeighborSettings((15.0, 15.0), 1.0, 0.2, 1.5)
    pos = jnp.asarray(np.concatenate([rng.normal(7.5, 2.0, (150, 2)), rng.uniform(-3.0, 18.0, (50, 2))]))
    grid, reach = nb._grid(settings), 1.2
    table = nb._build(pos, grid, reach, 64, 40)
    monkeypatch.setattr(nb, "CELL_TABLE_PER_DISK", -1)
    monkeypatch.setattr(nb, "CELL_TABLE_MIN", 0)
    search = nb._build(pos, grid, reach, 64, 40)
    for a, b in zip(table, search):
        np.testing.assert_array_equal(a, b)
    idx = np.asarray(table[0])
    assert int(table[1]) <= 40 and not bool(table[2])
    assert [set(r[r < 200]) for r in idx] == _within_reach(np.asarray(pos), reach)
    assert all(np.all(np.diff(r) >= 0) for r in idx) and (idx < 200).sum() > 400
    short, occupancy, _ = nb._build(pos, grid, reach, 64, 2)
    assert int(occupancy) > 2
    np.testing.assert_array_equal(short, idx[:, :2])


def test_slot_picks_stop_at_the_fullest_row_and_list_as_before():
    """A sparse pile's rows hold fewer neighbours than its slots: the traced
    build picks only as many slots as its fullest row needs, and its list is
    the host build's (which fills every slot), the slots past the fullest row
    empty; its half pairs read by `sorted_half_pairs` are `half_pairs`'."""
    rng = np.random.default_rng(5)
    pos = rng.uniform(0.0, 15.0, (60, 2))
    grid, reach, slots = nb._grid(nb.NeighborSettings((15.0, 15.0), 1.0, 0.2, 1.5)), 1.2, 12
    idx, occupancy, _ = jax.jit(nb._build, static_argnums=(1, 2, 3, 4))(jnp.asarray(pos), grid, reach, 64, slots)
    assert 1 <= int(occupancy) < slots // 2
    np.testing.assert_array_equal(idx, host_lists.build(pos, grid, reach, 64, slots)[0])
    assert np.all(np.asarray(idx)[:, int(occupancy):] == 60)
    for capacity in (16, 64):
        np.testing.assert_array_equal(pair_list.sorted_half_pairs(idx, capacity), half_pairs(idx, capacity))


def test_half_pairs_hold_each_pair_once_and_history_follows_its_pair():
    # full lists of 4 disks (empty = 4): pairs (0,1) (0,3) (0,2)->gone (1,2) new ...
    old_idx = jnp.array([[3, 1, 2], [0, 4, 4], [0, 4, 4], [0, 4, 4]])
    new_idx = jnp.array([[1, 4, 3, 4], [2, 0, 4, 4], [4, 1, 4, 4], [0, 4, 4, 4]])
    old_pairs = half_pairs(old_idx)
    assert old_pairs.shape == (64, 2)  # ceil(4 * 3 / 2) = 6 pairs at most, rounded up to PAIR_ALIGN
    np.testing.assert_array_equal(old_pairs[:3], [[0, 3], [0, 1], [0, 2]])  # row-major slot order
    np.testing.assert_array_equal(old_pairs[3:], 4)  # empty entries
    old_hist = jnp.arange(12.0).reshape(6, 2)
    new_pairs = half_pairs(new_idx)
    np.testing.assert_array_equal(new_pairs[:3], [[0, 1], [0, 3], [1, 2]])
    new = carry_history(old_idx, old_hist, new_pairs)
    np.testing.assert_array_equal(new[0], old_hist[1])  # (0, 1) moved entry 1 -> 0
    np.testing.assert_array_equal(new[1], old_hist[0])  # (0, 3) moved entry 0 -> 1
    np.testing.assert_array_equal(new[2], 0.0)  # (1, 2) is new
    np.testing.assert_array_equal(new[3:], 0.0)  # empty entries
    assert pair_entry(new_pairs, 3, 0) == 1 and pair_entry(new_pairs, 0, 2) is None


def test_host_lists_equal_their_traced_twins(monkeypatch):
    """`host_lists` (numpy: set-up, re-allocation, checkpoints) and the traced
    list code of the step loop build the same lists (and `allocate` the same
    list either way, see `HOST_BUILD_MAX`): 200 clustered disks, some
    outside the box, with room (window 64, 40 slots: the row sort), with
    too few slots (6: the slot-by-slot picks) and too small a window; then the
    half pairs with too little room, their count, and history carried onto the
    pairs of the list after the disks moved, from an old list cut short."""
    rng = np.random.default_rng(11)
    settings = nb.NeighborSettings((15.0, 15.0), 1.0, 0.2, 1.5)
    pos = np.concatenate([rng.normal(7.5, 2.0, (150, 2)), rng.uniform(-3.0, 18.0, (50, 2))])
    moved = pos + rng.normal(0.0, 0.2, pos.shape)
    grid, reach = nb._grid(settings), 1.2
    traced = jax.jit(nb._build, static_argnums=(1, 2, 3, 4))
    seen = set()
    for window, slots in ((64, 40), (64, 6), (3, 40)):
        host = host_lists.build(pos, grid, reach, window, slots)
        twin = traced(jnp.asarray(pos), grid, reach, window, slots)
        np.testing.assert_array_equal(host[0], twin[0])
        assert host[0].dtype == np.int32 and host[1:] == (int(twin[1]), bool(twin[2]))
        seen.add((host[1] > slots, host[2]))
    assert seen == {(False, False), (True, False), (False, True)}  # each case happened
    on_host = nb.allocate(settings, pos)
    monkeypatch.setattr(nb, "HOST_BUILD_MAX", 0)
    compiled = nb.allocate(settings, pos)
    for a, b in zip(jax.tree.leaves(on_host), jax.tree.leaves(compiled)):
        np.testing.assert_array_equal(a, b)
    old = host_lists.build(pos, grid, reach, 64, 40)[0]
    new = host_lists.build(moved, grid, reach, 64, 40)[0]
    for idx in (old, new):
        assert host_lists.pair_count(idx) == int(pair_list.pair_count(jnp.asarray(idx))) > 100
        for capacity in (64, 512):
            pairs = host_lists.half_pairs(idx, capacity)
            np.testing.assert_array_equal(pairs, half_pairs(jnp.asarray(idx), capacity))
            np.testing.assert_array_equal(pairs, pair_list.sorted_half_pairs(jnp.asarray(idx), capacity))
            assert pairs.dtype == np.int32
    old_history = rng.normal(size=(64, 2))  # room for the first 64 of the old pairs only
    new_pairs = host_lists.half_pairs(new, 512)
    carried = host_lists.carry_history(old, old_history, new_pairs)
    np.testing.assert_array_equal(carried, carry_history(jnp.asarray(old), jnp.asarray(old_history),
                                                         jnp.asarray(new_pairs)))
    # and the step's carry, read from the old half pairs themselves (the first 64, as the history holds)
    np.testing.assert_array_equal(carried, pair_list.carry_history_from_pairs(
        jnp.asarray(host_lists.half_pairs(old, 64)), jnp.asarray(old_history), jnp.asarray(new_pairs), *old.shape))
    assert 0 < (carried[:, 0] != 0).sum() < host_lists.pair_count(new)  # some carried, some new or cut


def _sliding_pair(skin):
    """A disk sliding over the top of a fixed disk under gravity, with huge
    friction and a weak tangential spring: the shear keeps accumulating while
    the pair stays in contact."""
    pos = np.array([[5.0, 5.0], [5.0, 5.9999]])
    particles = jaxpile.make_particles(pos, 0.5, velocity=[[0.0, 0.0], [0.3, 0.0]], fixed=[True, False])
    boundaries = jaxpile.make_boundaries().set(wall_active=jnp.array([False, False, False]))
    params = hooke.make_params(kn=1e4, kt=1.0, gamma_n=0.0, gamma_t=0.0, mu=1e6)
    sim = Simulator(hooke.law(rotation=False), dt=1e-4, skin=skin, chunk_steps=50)
    return sim, params, sim.init(params, particles, boundaries)


def test_history_survives_neighbor_rebuilds_and_clears_on_separation():
    # skin 2.0: no rebuild during the slide; skin 0.05: rebuild every 0.025 of travel.
    results = {}
    for skin in (2.0, 0.05):
        sim, params, state = _sliding_pair(skin)
        ref0 = np.asarray(state.neighbors.reference_position).copy()
        state = sim.run(params, state, 2000, progress=False)
        rebuilt = not np.array_equal(np.asarray(state.neighbors.reference_position), ref0)
        entry = pair_entry(state.contacts.pairs, 0, 1)
        results[skin] = (rebuilt, np.asarray(state.contacts.history[entry]).copy(), state, sim, params)
    assert not results[2.0][0] and results[0.05][0]
    shear_a, shear_b = results[2.0][1], results[0.05][1]
    assert np.linalg.norm(shear_a) > 0.05  # accumulated displacement along the tangent
    np.testing.assert_allclose(shear_b, shear_a, rtol=1e-10)
    # pull the moving disk away: the contact opens and its history is cleared
    _, _, state, sim, params = results[0.05]
    p = state.particles
    state = state.set(particles=p.set(velocity=jnp.array([[0.0, 0.0], [0.0, 5.0]])))
    state = sim.run(params, state, 200, progress=False)
    assert float(jnp.abs(state.contacts.history).max()) == 0.0


@functools.lru_cache(maxsize=None)  # each heap is run once, shared by the tests below
def _falling_heap(capacity_multiplier, packed_lists=False):
    """Disks in loose rows (two neighbours each at allocation) that fall into a
    heap with four to six neighbours each."""
    grid = np.stack(np.meshgrid(np.arange(6) * 1.1, np.arange(5) * 1.6), -1).reshape(-1, 2)
    rng = np.random.default_rng(5)
    pos = grid + [1.0, 0.6] + rng.uniform(-0.02, 0.02, grid.shape)
    particles = jaxpile.make_particles(pos, 0.5)
    boundaries = jaxpile.make_boundaries(left=0.3, right=7.2)
    # packed_lists=False: lists sized by the multiplier alone (the tight one overflows)
    sim = Simulator(hooke.law(), dt=5e-4, capacity_multiplier=capacity_multiplier, chunk_steps=500,
                    packed_lists=packed_lists)
    state = sim.init(PARAMS, particles, boundaries)
    info = jaxpile.RunInfo()
    state = sim.run(PARAMS, state, 4000, progress=False, info=info)
    return state, info


def test_too_small_capacity_gives_the_same_result_as_ample_capacity():
    tight, info_tight = _falling_heap(1.0)
    ample, info_ample = _falling_heap(4.0)
    assert info_tight.reallocations > 0 and info_ample.reallocations == 0
    assert tight.neighbors.idx.shape[1] < ample.neighbors.idx.shape[1]
    np.testing.assert_allclose(tight.particles.position, ample.particles.position, rtol=0, atol=1e-9)
    np.testing.assert_allclose(tight.particles.velocity, ample.particles.velocity, rtol=0, atol=1e-7)


def test_packed_capacity_is_the_triangular_packing_of_the_smallest_disks():
    """Equal disks (diameter 1), reach 1.2: six lattice neighbours (the next
    shell is at sqrt(3)), times the multiplier; a run of three cells 1.2 wide
    holds at most 8 points of the packing. Smaller disks raise both; far
    smaller ones get the caps."""
    settings = nb.NeighborSettings((12.0, 12.0), 1.0, 0.2, 1.5)
    assert nb._grid(settings)[2:] == (1.2, 1.2)
    assert nb.packed_capacity(settings, 0.5) == (9, 8)
    assert nb.packed_capacity(settings._replace(capacity_multiplier=1.0), 0.5) == (6, 8)
    slots, window = nb.packed_capacity(settings, 0.3)  # spacing 0.6: 18 points within 1.2 (2 spacings)
    assert slots == nb.PACKED_SLOTS_MAX and 8 < window <= 2 * nb.PACKED_SLOTS_MAX
    assert nb.packed_capacity(settings, 0.01) == (nb.PACKED_SLOTS_MAX, 2 * nb.PACKED_SLOTS_MAX)
    assert nb.packed_capacity(settings, 0.0) == (1, 1)
    # a list allocated with disks far apart gets them; one that needs more keeps its own
    apart = jnp.asarray(np.stack(np.meshgrid(np.arange(5) * 2.0, np.arange(5) * 2.0), -1).reshape(-1, 2) + 1.0)
    loose = nb.allocate(settings, apart)
    packed = nb.allocate(settings, apart, packed_radius=0.5)
    assert loose.max_occupancy < 9 and loose.cell_list_capacity < 8
    assert (packed.max_occupancy, packed.cell_list_capacity) == (9, 8)
    np.testing.assert_array_equal(np.asarray(packed.idx)[:, :loose.max_occupancy], np.asarray(loose.idx))


def test_a_heap_that_falls_together_keeps_the_list_sized_for_it_packed():
    """Loose rows falling into a heap (two neighbours each at allocation, four
    to six at the end): sized for the packed heap from the start (the
    default), the list is never re-allocated, and the run ends where the
    re-allocated one does."""
    packed, info = _falling_heap(1.5, packed_lists=True)
    tight, info_tight = _falling_heap(1.0)
    assert info.reallocations == 0 and info_tight.reallocations > 0
    np.testing.assert_allclose(packed.particles.position, tight.particles.position, rtol=0, atol=1e-9)
    np.testing.assert_allclose(packed.particles.velocity, tight.particles.velocity, rtol=0, atol=1e-7)


@pytest.mark.skipif(jax.default_backend() != "cpu", reason="level 0 is for CPU programs only")
def test_one_off_programs_compile_at_level_0_for_small_piles_with_the_same_forces(agitated, monkeypatch):
    """The start and the measured contact forces of a small pile compile at
    LLVM level 0 (`engine.compile.ONE_OFF_MAX_DISKS`); a large pile, or a level
    the user set in XLA_FLAGS, keeps XLA's default. The two levels give the
    start's forces and the contact forces of a pile with shear history to
    round-off (not bit for bit: measured up to 6e-15 relative)."""
    from jaxpile.engine import compile as xc
    from jaxpile.engine.simulate import _evaluate, _evaluate_jit

    assert xc.one_off_options(36) == {"xla_backend_optimization_level": 0}
    assert xc.one_off_options(xc.ONE_OFF_MAX_DISKS + 1) is None
    with monkeypatch.context() as m:
        m.setenv("XLA_FLAGS", "--xla_backend_optimization_level=1")
        assert xc.one_off_options(36) is None
    sim, state = agitated
    # the engine's own start and contact forces take the two programs by size
    assert sim._start_jit.program(36, PARAMS, state) is not sim._start_jit.program(10**9, PARAMS, state)
    assert _evaluate_jit.program(36, sim.law, PARAMS, state) is not _evaluate_jit.program(10**9, sim.law, PARAMS, state)
    for fn, args, out in ((sim.start, (PARAMS, state), lambda s: (s.particles.force, s.particles.torque)),
                          (_evaluate, (sim.law, PARAMS, state), lambda cf: (cf.force, cf.torque, cf.pair.history))):
        pick = (xc.jit_one_off(fn, static_argnums=0) if fn is _evaluate else xc.jit_one_off(fn)).program
        small, large = pick(36, *args), pick(10**9, *args)
        assert small is not large
        inside = []  # under a trace (a gradient's, another jit's): XLA's default, options being top-level only
        jax.jit(lambda st: inside.append(pick(36, st)) or 0)(state)
        assert inside == [large]
        for a, b in zip(out(small(*args)), out(large(*args))):
            np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-12, atol=1e-12 * float(jnp.abs(b).max()))


def test_second_call_of_jitted_step_does_not_recompile(agitated):
    sim, state = agitated
    traces = []

    def counted(params, s):
        traces.append(1)
        return sim.step(params, s)

    step = jax.jit(counted)
    s1 = step(PARAMS, state)
    s2 = step(PARAMS, s1)
    # new parameter values do not recompile either: they are arguments, not constants
    step(PARAMS.set(mu=jnp.asarray(0.1, PARAMS.mu.dtype)), s2)
    assert len(traces) == 1


def test_a_pair_list_that_overflows_grows_by_a_quarter_or_to_its_demand_not_double():
    """Doubling the pair room put a 409-disk polydisperse box that had found 1290
    pairs in 1280 on 2560 entries: 217 us a step against 150-168 us on 1600
    (benchmarks/packed_lists_ab.py)."""
    from types import SimpleNamespace

    state = SimpleNamespace(contacts=SimpleNamespace(pairs=np.zeros((1280, 2), np.int32)))

    def after(demand):
        return SimpleNamespace(contacts=SimpleNamespace(demand=np.int32(demand)))

    assert nb.pairs_needed(state, after(1280)) == 1280  # enough room: unchanged
    assert nb.pairs_needed(state, after(1290)) == 1600  # nb.PAIR_GROWTH
    assert nb.pairs_needed(state, after(1600)) == math.ceil(nb.PAIR_HEADROOM * 1600)  # 1.1 times the demand


def test_a_slot_list_that_overflows_grows_to_the_neighbours_its_chunk_found():
    """Adding the old K on any overflow to what the chunk's start needs put a
    409-disk 1993 box whose pair room overflowed on 29 slots instead of its
    16 (a rebuild 1.3-1.6x dearer, benchmarks/packed_lists_ab.py): the slots
    now follow the most neighbours a rebuild found (Contacts.slot_demand)."""
    from types import SimpleNamespace
    from jaxpile._jax_md import partition

    PEC = partition.PEC

    state = SimpleNamespace(neighbors=SimpleNamespace(max_occupancy=16, cell_list_capacity=24))

    def after(slot_demand, code=0, pair_demand=0):
        return SimpleNamespace(contacts=SimpleNamespace(slot_demand=np.int32(slot_demand), demand=np.int32(pair_demand),
                                                        pairs=np.zeros((100, 2), np.int32)),
                               neighbors=SimpleNamespace(error=SimpleNamespace(code=np.uint8(code))))

    slot_flag, window_flag = int(PEC.NEIGHBOR_LIST_OVERFLOW), int(PEC.CELL_LIST_OVERFLOW)
    assert nb.slots_needed(state, after(12)) == 16  # room enough: unchanged
    assert nb.slots_needed(state, after(17, slot_flag)) == math.ceil(nb.SLOT_HEADROOM * 17) == 22
    assert nb.slots_needed(state, after(12, slot_flag, pair_demand=101)) == 16  # the pairs overflowed, not the slots
    assert nb.slots_needed(state, after(12, slot_flag)) == 32  # flagged outside any rebuild: grown as before
    assert nb.window_needed(state, after(17, slot_flag)) == 24
    assert nb.window_needed(state, after(12, window_flag)) == 24 + 16


def test_pair_capacity_overflow_reallocates_and_changes_nothing():
    """A half pair list too small for the pile (64 entries for 330 pairs) is
    flagged as an overflow on the first rebuild: the chunk is re-run with room
    for every pair, and the run ends exactly where one with ample room ends."""
    particles, boundaries = lattice.equilateral_pile(15)
    params = hooke.make_params(kn=1e4, gamma_n=50.0, mu=0.3, wall_mu=1.0)
    sim = Simulator(hooke.law(), dt=5e-4, chunk_steps=200, skin=0.02)  # thin skin: a rebuild within the chunk
    ample = sim.init(params, particles, boundaries)
    cramped = ample.set(contacts=contacts_for(ample.contacts, ample.neighbors.idx, ample.neighbors.idx, 64))
    info = jaxpile.RunInfo()
    out = sim.run(params, cramped, 400, progress=False, info=info)
    ref = sim.run(params, ample, 400, progress=False)
    assert int(ample.contacts.demand) > 64 and info.reallocations >= 1
    assert out.contacts.pairs.shape[0] >= int(ample.contacts.demand)
    np.testing.assert_allclose(out.particles.position, ref.particles.position, rtol=0, atol=1e-12)


def test_setting_up_a_pile_of_a_new_size_compiles_no_small_programs():
    """`jnp.asarray` of a numpy array, `jnp.zeros` and eager ops on concrete
    arrays compile a program for each new shape (~10-40 ms each with tracing):
    three small protocols compiled 78 programs besides their step loops and
    starts, 19 once the host code kept to numpy and `engine.transfer`
    (benchmarks/eager_compiles.py). Making the particles and walls of a new pile
    size, its lists and contacts, and reading its flags and movable disks on the
    host compile nothing; the values are those jnp would have made."""
    from jaxpile.engine.boundaries import LEFT_WALL, set_wall
    from jaxpile.engine import transfer

    compiled = []

    def listener(event, secs, **kw):
        if event == "/jax/core/compile/backend_compile_duration":
            compiled.append(kw.get("fun_name"))

    rng = np.random.default_rng(7)
    position = lattice.equilateral_positions(7)[:27] + rng.normal(0, 1e-3, (27, 2))  # a size no other test has
    jax.monitoring.register_event_duration_secs_listener(listener)
    try:
        particles = jaxpile.make_particles(position, rng.uniform(0.45, 0.5, 27))
        boundaries = set_wall(jaxpile.make_boundaries(left=-1.0, right=9.0), LEFT_WALL, active=False, position=-2.0)
        state = Simulator(hooke.law(), dt=1e-4).prepare(PARAMS, particles, boundaries)
        flags, movable = nb.overflowed(state), state.particles.movable
        host = np.arange(5.0)
        copied = transfer.to_device(host)
        host[0] = 9.0
    finally:
        jax.monitoring.unregister_event_duration_listener(listener)
    assert compiled == []
    assert not bool(flags) and bool(np.all(np.asarray(movable)))
    assert float(copied[0]) == 0.0  # a copy: the caller's array edited later never reaches the pile
    assert state.particles.mass.dtype == jnp.float64 and state.contacts.slot_demand.dtype == jnp.int32
    assert np.asarray(boundaries.wall_active).tolist() == [True, False, True]
    assert np.asarray(boundaries.wall_offset).tolist() == [0.0, -2.0, -9.0]
    np.testing.assert_array_equal(np.asarray(state.particles.inertia),
                                  0.5 * np.asarray(particles.mass) * np.asarray(particles.radius) ** 2)
