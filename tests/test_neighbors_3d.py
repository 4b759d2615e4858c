"""jaxpile's own neighbour lists in 3D (and 2D through the same generic path):
the host build (`neighbors.allocate`, `host_lists.build`) and the traced one
(`neighbors.rebuild`) against brute force, the rebuild trigger counting z,
and the packed capacities of an fcc pile."""

import itertools

import jax.numpy as jnp
import numpy as np
import pytest

import jaxpile

jaxpile.configure()

from jaxpile.engine import host_lists  # noqa: E402
from jaxpile.engine import neighbors as nb  # noqa: E402
from jaxpile.engine.cells import cell_grid, row_offsets  # noqa: E402


def _settings(position, radius, box=None):
    """Settings as `Simulator.neighbor_settings` makes them (a Hooke-like law:
    cutoff the largest diameter, skin 0.2 of it; box the disks' extent plus a
    reach each side), one box extent per axis."""
    r_max = float(radius.max())
    cutoff, skin = 2 * r_max, 0.2 * 2 * r_max
    if box is None:
        extent = position.max(axis=0) - np.minimum(position.min(axis=0), 0.0)
        box = tuple(float(e) + 2 * (cutoff + skin) for e in extent)
    return nb.NeighborSettings(tuple(float(b) for b in box), cutoff, skin, 1.5)


def _brute_pairs(position, reach):
    """Every pair i < j within `reach`, by all pairs in numpy."""
    delta = position[:, None, :] - position[None, :, :]
    squared = sum(delta[..., k] * delta[..., k] for k in range(position.shape[1]))
    i, j = np.nonzero(np.triu(squared < reach * reach, k=1))
    return set(zip(i.tolist(), j.tolist()))


def _list_pairs(idx):
    """The pairs of a full list (each must be in both rows), rows sorted."""
    idx = np.asarray(idx)
    n = idx.shape[0]
    assert all(np.all(np.diff(row) >= 0) for row in idx)  # each row in increasing index order
    full = {(i, int(j)) for i, row in enumerate(idx) for j in row if j < n}
    assert all((j, i) in full for i, j in full)  # symmetric
    return {(i, j) for i, j in full if i < j}


def _spheres(rng, n, extent, dimension=3):
    """`n` polydisperse particles (radii 0.35 .. 0.5), uniformly in a cube of
    `extent`, a tenth of them a little outside it (clamped to border cells)."""
    position = rng.uniform(0.0, extent, (n, dimension))
    position[: n // 10] += rng.choice([-1.0, 1.0], (n // 10, dimension)) * 0.6 * extent
    radius = rng.uniform(0.35, 0.5, n)
    return position, radius


def _check_lists(position, radius, box=None):
    settings = _settings(position, radius, box)
    reach = settings.cutoff + settings.skin
    expected = _brute_pairs(position, reach)
    assert len(expected) > 0
    allocated = nb.allocate(settings, position, packed_radius=float(radius.min()))  # on the host
    assert not bool(allocated.did_buffer_overflow)
    assert _list_pairs(allocated.idx) == expected
    rebuilt = nb.rebuild(allocated, jnp.asarray(position), settings)  # the traced build of the step loop
    assert not bool(rebuilt.did_buffer_overflow)
    assert _list_pairs(rebuilt.idx) == expected
    grid = cell_grid(settings.box, reach)
    window = int(allocated.cell_list_capacity)
    idx, occupancy, over = host_lists.build(position, grid, reach, window, position.shape[0] - 1)
    assert not over and _list_pairs(idx) == expected
    assert occupancy == max(np.bincount(np.array([p for pair in expected for p in pair]),
                                        minlength=position.shape[0]))
    # then moved (within the skin and beyond it), rebuilt in the loop
    moved = position + np.random.default_rng(1).normal(0.0, 0.3, position.shape)
    again = nb.rebuild(allocated, jnp.asarray(moved), settings)
    if not bool(again.did_buffer_overflow):
        assert _list_pairs(again.idx) == _brute_pairs(moved, reach)
    return expected, allocated


@pytest.mark.parametrize("extent", [5.0, 60.0], ids=["dense", "sparse"])
def test_3d_lists_hold_exactly_the_pairs_within_the_reach(extent):
    """200 polydisperse spheres, dense (~10 neighbours each; the cell table)
    and sparse (a box far larger than the spheres: the binary search)."""
    position, radius = _spheres(np.random.default_rng(7), 200, extent)
    expected, allocated = _check_lists(position, radius)
    if extent < 10:
        assert len(expected) > 3 * 200  # a dense set: many pairs, across all 9 rows of cells
    assert allocated.reference_position.shape == (200, 3)


def test_2d_lists_through_the_same_path_hold_exactly_the_pairs_within_the_reach():
    position, radius = _spheres(np.random.default_rng(8), 200, 9.0, dimension=2)
    expected, _ = _check_lists(position, radius)
    assert len(expected) > 200


def test_row_offsets_keep_the_2d_order_and_cover_the_3d_neighbourhood():
    assert row_offsets(2) == ((-1,), (0,), (1,))
    assert row_offsets(3) == tuple(itertools.product((-1, 0, 1), repeat=2)) and len(row_offsets(3)) == 9


def test_positions_of_another_dimension_than_the_box_are_refused():
    position, radius = _spheres(np.random.default_rng(9), 20, 5.0)
    settings_2d = _settings(position[:, :2], radius)
    with pytest.raises(ValueError, match="dimension|extents"):
        nb.allocate(settings_2d, position)


@pytest.mark.parametrize("axis", [2, 0])
def test_needs_rebuild_counts_every_axis_in_3d(axis):
    """One sphere moving just over skin / 2 along z alone (or x) triggers a
    rebuild; just under does not."""
    position, radius = _spheres(np.random.default_rng(10), 50, 6.0)
    settings = _settings(position, radius)
    nbrs = nb.allocate(settings, position)
    reference = jnp.asarray(position)
    assert not bool(nb.needs_rebuild(nbrs, reference, settings.skin))
    under = reference.at[17, axis].add(0.49 * settings.skin)
    over = reference.at[17, axis].add(0.51 * settings.skin)
    assert not bool(nb.needs_rebuild(nbrs, under, settings.skin))
    assert bool(nb.needs_rebuild(nbrs, over, settings.skin))
    diagonal = reference.at[17].add(0.3 * settings.skin)  # 0.3 sqrt(3) = 0.52 of the skin over three axes
    assert bool(nb.needs_rebuild(nbrs, diagonal, settings.skin))


def _fcc(cells, spacing=1.0):
    """An fcc block of `cells`^3 cubic cells (4 spheres each), nearest spacing `spacing`."""
    a = spacing * np.sqrt(2.0)
    basis = np.array([[0, 0, 0], [0, 0.5, 0.5], [0.5, 0, 0.5], [0.5, 0.5, 0]])
    corners = np.array(list(itertools.product(range(cells), repeat=3)), float)
    return ((corners[:, None, :] + basis[None]) * a).reshape(-1, 3)


def test_packed_capacity_in_3d_is_the_fcc_packing_of_the_smallest_spheres():
    """Equal spheres (diameter 1), reach 1.2: the 12 fcc neighbours (the next
    shell is at sqrt 2), times the multiplier; smaller spheres raise it to
    the 3D cap, which is above the 2D one. A list allocated with the spheres
    far apart but sized for their packing holds them packed, fcc, with no
    overflow, each interior sphere with its 12 neighbours."""
    settings = nb.NeighborSettings((16.0, 16.0, 16.0), 1.0, 0.2, 1.5)
    assert nb.packed_capacity(settings._replace(capacity_multiplier=1.0), 0.5)[0] == 12
    slots, window = nb.packed_capacity(settings, 0.5)
    assert slots == 18 and 8 <= window <= 2 * nb.packed_slots_max(3)
    small = nb.packed_capacity(settings, 0.2)
    assert small[0] == nb.packed_slots_max(3) > nb.PACKED_SLOTS_MAX and small[1] > window
    packed = _fcc(4) + 1.0
    apart = (packed - 1.0) * 2.5 + 1.0
    loose = nb.allocate(settings, apart)
    sized = nb.allocate(settings, apart, packed_radius=0.5)
    assert loose.max_occupancy < 12
    assert (sized.max_occupancy, sized.cell_list_capacity) == (slots, window)
    pressed = nb.rebuild(sized, jnp.asarray(packed), settings)
    assert not bool(pressed.did_buffer_overflow)
    assert _list_pairs(pressed.idx) == _brute_pairs(packed, 1.2)
    assert int(np.max(np.sum(np.asarray(pressed.idx) < len(packed), axis=1))) == 12
    assert nb.pair_capacity_for(np.asarray(pressed.idx), dimension=3) >= 6 * len(packed)
    assert nb.pair_capacity_for(np.asarray(pressed.idx)) >= 3 * len(packed)  # 2D default unchanged


def test_a_heap_about_the_origin_gets_the_grid_from_its_lowest_corner():
    """Spheres centred on x = y = 0 (the cone's plate) are not clamped into the
    border cells of a grid from 0: `Simulator.neighbor_settings` puts the grid's
    origin at the lowest position, so the list and its window are those of the
    same spheres moved to positive coordinates."""
    from jaxpile.engine import Simulator
    from jaxpile.engine.state import make_particles
    from jaxpile.laws import hooke

    rng = np.random.default_rng(11)
    position, radius = rng.uniform(0.0, 8.0, (300, 3)), rng.uniform(0.35, 0.5, 300)
    centred = position - np.array([4.0, 4.0, 0.0])
    sim = Simulator(hooke.law(), 1e-4)
    params = hooke.Params(kn=1e4, kt=2e4 / 7, gamma_n=10.0, gamma_t=5.0, mu=0.5)
    lists = {}
    for name, where in (("positive", position), ("centred", centred)):
        settings = sim.neighbor_settings(params, make_particles(where, radius))
        assert (settings.origin is None) == (name == "positive")
        lists[name] = nb.allocate(settings, where, packed_radius=float(radius.min()))
        reach = settings.cutoff + settings.skin
        assert _list_pairs(lists[name].idx) == _brute_pairs(where, reach)
        rebuilt = nb.rebuild(lists[name], jnp.asarray(where), settings)
        assert _list_pairs(rebuilt.idx) == _brute_pairs(where, reach)
    assert lists["centred"].cell_list_capacity == lists["positive"].cell_list_capacity
    assert np.array_equal(np.asarray(lists["centred"].idx), np.asarray(lists["positive"].idx))


def _fixed_base(rng, dimension):
    """A heap's set-up in miniature: a close layer of fixed particles (spacing
    0.95 of a diameter: each overlaps its neighbours) under two layers of free
    ones on the same sites, jittered, overlapping it and each other."""
    side = np.arange(8 if dimension == 3 else 24) * 0.95
    base = np.array(list(itertools.product(side, repeat=dimension - 1)), float)
    base = np.concatenate([base, np.zeros((len(base), 1))], axis=1)
    free = np.concatenate([base + np.eye(dimension)[-1] * height for height in (0.9, 1.8)])
    free += rng.uniform(-0.05, 0.05, free.shape)
    position = np.concatenate([base, free])
    fixed = np.arange(len(position)) < len(base)
    return position, np.full(len(position), 0.5), fixed


@pytest.mark.parametrize("dimension", [3, 2])
def test_two_fixed_particles_are_never_neighbours(dimension):
    """With `fixed` given, the host build, `allocate` and the traced rebuild
    all hold exactly the pairs within the reach less those of two fixed
    particles; the pair room is sized by the free particles only."""
    position, radius, fixed = _fixed_base(np.random.default_rng(12), dimension)
    settings = _settings(position, radius)
    reach = settings.cutoff + settings.skin
    everything = _brute_pairs(position, reach)
    expected = {(i, j) for i, j in everything if not (fixed[i] and fixed[j])}
    assert len(everything) - len(expected) >= int(fixed.sum()) - 1  # the base's own pairs are many
    allocated = nb.allocate(settings, position, fixed=fixed)
    assert _list_pairs(allocated.idx) == expected
    assert _list_pairs(nb.rebuild(allocated, jnp.asarray(position), settings, jnp.asarray(fixed)).idx) == expected
    idx = host_lists.build(position, cell_grid(settings.box, reach), reach, int(allocated.cell_list_capacity),
                           position.shape[0] - 1, fixed)[0]
    assert _list_pairs(idx) == expected
    assert _list_pairs(nb.allocate(settings, position).idx) == everything  # no `fixed`: every pair
    free = int((~fixed).sum())
    room = nb.pair_capacity_for(np.asarray(allocated.idx), dimension=dimension, fixed=fixed)
    assert nb.pairs_per_particle(dimension) * free <= room < nb.pairs_per_particle(dimension) * len(position)


@pytest.mark.parametrize("dimension", [3, 2])
def test_the_forces_are_the_same_bit_for_bit_without_the_pairs_of_two_fixed_particles(dimension):
    """Two fixed particles exert nothing on each other, so leaving their pairs
    out of the list changes no force and no torque, not by a rounding unit:
    the forces of `evaluate` on the list with them and without them."""
    from jaxpile.engine import Simulator, host_lists
    from jaxpile.engine.interactions import evaluate
    from jaxpile.engine.boundaries import make_boundaries
    from jaxpile.engine.state import make_particles
    from jaxpile.laws import hooke

    rng = np.random.default_rng(13)
    position, radius, fixed = _fixed_base(rng, dimension)
    spin = rng.normal(0.0, 1.0, (len(position),) + ((3,) if dimension == 3 else ()))
    velocity = np.where(fixed[:, None], 0.0, rng.normal(0.0, 0.5, position.shape))
    particles = make_particles(position, radius, velocity=velocity, fixed=fixed,
                               angular_velocity=np.where(fixed[(...,) + (None,) * (spin.ndim - 1)], 0.0, spin))
    params = hooke.Params(kn=1e4, kt=2e4 / 7, gamma_n=10.0, gamma_t=5.0, mu=0.5)
    sim = Simulator(hooke.law(), 1e-4, max_initial_overlap=0.3)
    state = sim.init(params, particles, make_boundaries(dim=dimension))
    every = nb.allocate(state.neighbor_settings, position)  # the list with the fixed particles' own pairs
    room = nb.pair_capacity_for(np.asarray(every.idx), dimension=dimension)
    with_them = host_lists.contacts_for(state.contacts, state.neighbors.idx, every.idx, room)
    assert int(with_them.demand) > int(state.contacts.demand)
    a = evaluate(sim.law, params, state.particles, state.contacts, state.boundaries, 1e-4)
    b = evaluate(sim.law, params, state.particles, with_them, state.boundaries, 1e-4)
    assert float(jnp.max(jnp.abs(a.force))) > 0 and float(jnp.max(jnp.abs(a.torque))) > 0
    np.testing.assert_array_equal(np.asarray(a.force), np.asarray(b.force))
    np.testing.assert_array_equal(np.asarray(a.torque), np.asarray(b.torque))
