"""The papers' heap measurements on synthetic inputs with known answers:
Lee & Herrmann 1993 sec. 3 (surface h(x), three angle-of-repose methods), Baxter
et al. 1997 (flanks of a symmetric heap, voidage maps), Liffman, Chan & Hughes 1992
Figs. 10 and 16 (each disk's strongest and weakest contact)."""

import math

import jax
import numpy as np
import pytest

import jaxpile
from jaxpile import analysis
from jaxpile.engine.boundaries import GROUND, RIGHT_WALL
from jaxpile.errors import InputError
from jaxpile.engine.interactions import ContactForces
from jaxpile.laws.base import PairForce

HEX_FRACTION = math.pi / (2 * math.sqrt(3))  # 0.9069
SQUARE_FRACTION = math.pi / 4


# ------------------------------------------------------------------ builders
def stepped_heap(angle, columns=40, diameter=1.0, *, apex=None, rng=None, x_jitter=0.0, y_jitter=0.0):
    """Stacks of disks, one per column of width `diameter`, whose tops lie on a
    line falling to the right at `angle` degrees (or on both sides of `apex`, the
    column index of a symmetric heap's top). Disks go down from the top at one
    diameter spacing to the ground. Optional jitter of each disk's x and of the tops."""
    slope = math.tan(math.radians(angle))
    r = 0.5 * diameter
    xc = diameter * (np.arange(columns) + 0.5)
    run = xc if apex is None else np.abs(xc - xc[apex])
    tops = r + slope * (run.max() - run) + 0.3 * diameter
    pos = []
    for x, top in zip(xc, tops):
        if rng is not None:
            top = top + rng.uniform(-y_jitter, y_jitter)
        y = np.arange(top, r - 1e-9, -diameter)
        dx = rng.uniform(-x_jitter, x_jitter, len(y)) if rng is not None else np.zeros(len(y))
        pos.append(np.stack([x + dx, y], axis=1))
    return np.concatenate(pos), r


def hex_lattice(rows, per_row, diameter=1.0):
    """Close-packed touching disks: rows sqrt(3)/2 d apart, odd rows shifted by d/2."""
    y = np.arange(rows) * diameter * math.sqrt(3) / 2
    x = np.arange(per_row) * diameter
    pos = [np.stack([x + (0.5 * diameter if i % 2 else 0.0), np.full(per_row, yy)], 1) for i, yy in enumerate(y)]
    return np.concatenate(pos)


def square_lattice(rows, per_row, diameter=1.0):
    gx, gy = np.meshgrid(np.arange(per_row) * diameter, np.arange(rows) * diameter)
    return np.stack([gx.ravel(), gy.ravel()], 1)


# --------------------------------------------------------- surface profile
def test_surface_profile_finds_the_top_disk_of_each_column():
    pos = np.array([[0.5, 0.5], [0.5, 1.5], [1.5, 0.5], [2.4, 0.5], [2.6, 2.5], [9.0, 9.0]])
    active = np.array([True, True, True, True, True, False])  # the parked disk is ignored
    prof = analysis.surface_profile(pos, 0.5, active, x_min=0.0, width=3.0)
    np.testing.assert_allclose(prof.x, [0.5, 1.5, 2.5])
    np.testing.assert_allclose(prof.height, [1.5, 0.5, 2.5])
    np.testing.assert_array_equal(prof.count, [2, 1, 2])
    np.testing.assert_array_equal(prof.particle, [1, 2, 4])
    assert prof.column_width == pytest.approx(1.0)
    tops = analysis.surface_profile(pos, 0.5, active, x_min=0.0, width=3.0, top=True)
    np.testing.assert_allclose(tops.height, prof.height + 0.5)


def test_surface_profile_columns_are_one_mean_diameter_and_tile_the_range():
    pos, r = stepped_heap(30, columns=10, diameter=0.2)
    prof = analysis.surface_profile(pos, r, x_min=0.0, width=2.0)  # Lee & Herrmann's W = 2, d = 0.2
    assert len(prof.x) == 10 and prof.column_width == pytest.approx(0.2)
    prof = analysis.surface_profile(pos, r, x_min=0.0, width=2.09)  # 10.45 diameters -> 10 columns
    assert len(prof.x) == 10 and prof.column_width == pytest.approx(0.209)
    prof = analysis.surface_profile(pos, r, x_min=0.0, width=2.12)  # 10.6 diameters -> 11 columns
    assert len(prof.x) == 11 and prof.column_width == pytest.approx(2.12 / 11)
    # an empty column (here left of every disk) has NaN height, id -1 and count 0
    prof = analysis.surface_profile(pos, r, x_min=-0.4, width=2.4)
    assert np.isnan(prof.height[:2]).all() and (prof.particle[:2] == -1).all() and (prof.count[:2] == 0).all()


# ------------------------------------------------------------ angle of repose
@pytest.mark.parametrize("angle", [20.0, 30.0, 35.0])
def test_three_methods_give_the_angle_of_an_exact_straight_surface(angle):
    pos, r = stepped_heap(angle, columns=40)
    prof = analysis.surface_profile(pos, r, x_min=0.0, width=40.0)
    res = analysis.repose_angles(prof)
    for got in (res.endpoints, res.least_squares, res.cumulative_parabola):
        assert got == pytest.approx(angle, abs=1e-6)
    assert np.all(res.slopes < 0)  # falls to the right, the sign is kept
    assert len(res.x) == 40


@pytest.mark.parametrize("angle", [20.0, 30.0, 35.0])
def test_three_methods_agree_on_a_rough_polydisperse_surface(angle):
    rng = np.random.default_rng(int(angle))
    pos, _ = stepped_heap(angle, columns=60, rng=rng, x_jitter=0.3, y_jitter=0.1)
    radius = rng.uniform(0.4, 0.5, len(pos))
    prof = analysis.surface_profile(pos, radius, x_min=0.0, width=60.0, column_width=1.0)
    res = analysis.repose_angles(prof)
    angles = np.array([res.endpoints, res.least_squares, res.cumulative_parabola])
    assert np.ptp(angles) < 0.5, angles
    np.testing.assert_allclose(angles, angle, atol=0.5)


def test_an_empty_column_inside_a_straight_surface_is_refused_or_filled_with_its_neighbours_line():
    """Lee & Herrmann 1993 sec. 3's h(x) has no value in a cell that holds no disk centre: refused, or with
    `fill_gaps` (the box's reading) the line between its neighbours, which keeps a straight surface's angle
    exact by all three methods."""
    pos, r = stepped_heap(30.0, columns=20)
    hole = (pos[:, 0] > 7.0) & (pos[:, 0] < 8.0)  # every disk of the eighth column
    prof = analysis.surface_profile(pos[~hole], r, x_min=0.0, width=20.0)
    assert np.isnan(prof.height[7])
    with pytest.raises(jaxpile.InputError, match="empty column at x = 7.5"):
        analysis.repose_angles(prof)
    res = analysis.repose_angles(prof, fill_gaps=True)
    for got in (res.endpoints, res.least_squares, res.cumulative_parabola):
        assert got == pytest.approx(30.0, abs=1e-6)


def test_angle_of_a_close_packed_heap_cut_at_30_degrees():
    """A hexagonal packing cut by a 30 degree line: a staircase surface, not a straight one."""
    pos = hex_lattice(60, 80)
    keep = pos[:, 1] <= 0.5 + math.tan(math.radians(30)) * (80 - pos[:, 0])
    prof = analysis.surface_profile(pos[keep], 0.5, x_min=-0.5, width=80.0)
    res = analysis.repose_angles(prof)
    assert res.least_squares == pytest.approx(30, abs=0.5)
    assert res.cumulative_parabola == pytest.approx(30, abs=0.5)
    assert res.endpoints == pytest.approx(30, abs=1.5)  # two end columns carry the staircase error


def test_flanks_of_a_symmetric_heap_give_equal_angles():
    pos, r = stepped_heap(33, columns=41, apex=20)
    prof = analysis.surface_profile(pos, r, x_min=0.0, width=41.0)
    assert analysis.apex_x(prof) == pytest.approx(20.5)
    left = analysis.repose_angles(prof, flank="left")
    right = analysis.repose_angles(prof, flank="right")
    for a, b in zip(left[:3], right[:3]):
        assert a == pytest.approx(33, abs=1e-6) and b == pytest.approx(33, abs=1e-6)
    assert np.all(left.slopes > 0) and np.all(right.slopes < 0)
    assert left.x.max() == right.x.min() == pytest.approx(20.5)  # the apex column is in both
    # the whole heap seen as one slope is not a straight line: the methods then disagree
    both = analysis.repose_angles(prof)
    assert both.least_squares < 5


def test_flanks_of_a_rough_symmetric_heap_agree_within_half_a_degree():
    rng = np.random.default_rng(7)
    pos, _ = stepped_heap(28, columns=81, apex=40, rng=rng, x_jitter=0.3, y_jitter=0.1)
    prof = analysis.surface_profile(pos, 0.5, x_min=0.0, width=81.0)
    apex = analysis.apex_x(prof)
    left = analysis.repose_angles(prof, flank="left", x_range=(0, apex - 2))  # leave out the apex
    right = analysis.repose_angles(prof, flank="right", x_range=(apex + 2, 81))
    assert left.cumulative_parabola == pytest.approx(right.cumulative_parabola, abs=0.5)
    assert left.cumulative_parabola == pytest.approx(28, abs=0.5)


def test_mid_flank_angle_ignores_the_toe_and_the_rounded_apex():
    """A 30-degree flank with a 15-column toe one disk high and a flat top: the
    line through the columns between 20% and 80% of the apex height is the
    flank's own 30 degrees, where a line through the whole flank is flatter."""
    x = np.arange(60) + 0.5
    flank = np.tan(np.radians(30.0)) * (x - 15.0)
    h = np.clip(flank, 0.6, 0.9 * flank.max())  # toe at 0.6, top cut flat
    h = np.concatenate([h, h[::-1]])
    prof = analysis.SurfaceProfile(x=np.arange(120) + 0.5, height=h, count=np.ones(120, int),
                                   particle=np.arange(120), column_width=1.0)
    for side in ("left", "right"):
        assert analysis.mid_flank_angle(prof, flank=side, base=0.0) == pytest.approx(30.0, abs=1e-9)
        assert analysis.repose_angles(prof, flank=side).least_squares < 27.0
    assert analysis.mid_flank_angle(prof, flank="left", base=0.0, band=(0.995, 0.999)) is None  # < 3 columns
    with pytest.raises(InputError, match="band"):
        analysis.mid_flank_angle(prof, flank="left", base=0.0, band=(0.8, 0.2))
    with pytest.raises(InputError, match="flank"):
        analysis.mid_flank_angle(prof, flank="up", base=0.0)


def test_empty_columns_beyond_the_toe_are_dropped_but_a_gap_is_an_error():
    pos, r = stepped_heap(25, columns=30)
    prof = analysis.surface_profile(pos, r, x_min=0.0, width=40.0)  # 10 empty columns at the right
    assert np.isnan(prof.height[-10:]).all()
    assert analysis.repose_angles(prof).endpoints == pytest.approx(25, abs=1e-6)
    gap = pos[np.abs(pos[:, 0] - 10.5) > 0.1]  # remove column 10
    prof = analysis.surface_profile(gap, r, x_min=0.0, width=30.0)
    with pytest.raises(InputError, match="empty column at x = 10.5"):
        analysis.repose_angles(prof)
    assert analysis.repose_angles(prof, x_range=(11, 30)).least_squares == pytest.approx(25, abs=1e-6)


def test_disks_outside_the_box_do_not_change_the_surface():
    pos, r = stepped_heap(30, columns=20)
    spilled = np.concatenate([pos, [[20.7, 50.0], [-3.0, 40.0]]])
    a = analysis.surface_profile(pos, r, x_min=0.0, width=20.0)
    b = analysis.surface_profile(spilled, r, x_min=0.0, width=20.0)
    np.testing.assert_array_equal(a.height, b.height)


def test_surface_and_repose_reject_bad_inputs():
    pos, r = stepped_heap(30, columns=10)
    with pytest.raises(InputError, match="empty"):
        analysis.surface_profile(np.zeros((0, 2)), np.zeros(0))
    with pytest.raises(InputError, match="width W must be positive"):
        analysis.surface_profile(pos, r, x_min=0.0, width=0.0)
    with pytest.raises(InputError, match="width W must be positive"):
        analysis.surface_profile(pos, r, x_min=0.0, width=-4.0)
    with pytest.raises(InputError, match="column_width must be positive"):
        analysis.surface_profile(pos, r, column_width=0.0)
    with pytest.raises(InputError, match="no active disk"):
        analysis.surface_profile(pos, r, np.zeros(len(pos), bool))
    with pytest.raises(InputError, match="radii positive"):
        analysis.surface_profile(pos, -r)
    with pytest.raises(InputError, match="shape"):
        analysis.surface_profile(pos[:, :1], r)
    prof = analysis.surface_profile(pos, r, x_min=0.0, width=10.0)
    with pytest.raises(InputError, match="flank"):
        analysis.repose_angles(prof, flank="middle")
    with pytest.raises(InputError, match="at least 3"):
        analysis.repose_angles(prof, x_range=(0, 1.6))
    with pytest.raises(InputError, match="x_lo < x_hi"):
        analysis.repose_angles(prof, x_range=(5, 1))


# ---------------------------------------------------------------- voidage maps
def _chord_overlap(center, radius, x0, x1, y0, y1, samples=200_000):
    """Disk-rectangle area by the midpoint rule over vertical chords (reference)."""
    x = x0 + (np.arange(samples) + 0.5) * (x1 - x0) / samples
    half = np.sqrt(np.maximum(radius**2 - (x - center[0]) ** 2, 0.0))
    lo, hi = np.maximum(center[1] - half, y0), np.minimum(center[1] + half, y1)
    return np.sum(np.maximum(hi - lo, 0.0)) * (x1 - x0) / samples


def test_disk_rectangle_overlap_is_exact():
    rng = np.random.default_rng(3)
    for _ in range(40):
        c, r = rng.uniform(-1, 1, 2), rng.uniform(0.2, 1.0)
        x0, y0 = rng.uniform(-1.5, 0.5, 2)
        x1, y1 = x0 + rng.uniform(0.05, 2.0), y0 + rng.uniform(0.05, 2.0)
        got = analysis.disk_rectangle_overlap(c, r, x0, x1, y0, y1)
        assert got == pytest.approx(_chord_overlap(c, r, x0, x1, y0, y1), abs=1e-7)
    assert analysis.disk_rectangle_overlap([0, 0], 1.0, -2, 2, -2, 2) == pytest.approx(math.pi)
    assert analysis.disk_rectangle_overlap([0, 0], 1.0, 0, 2, -2, 2) == pytest.approx(math.pi / 2)
    assert analysis.disk_rectangle_overlap([0, 0], 1.0, 0, 2, 0, 2) == pytest.approx(math.pi / 4)
    assert analysis.disk_rectangle_overlap([0, 0], 1.0, 1.0, 2, -2, 2) == 0.0


def test_hexagonal_close_packing_fills_pi_over_2_sqrt3():
    pos = hex_lattice(30, 30)
    h = math.sqrt(3) / 2
    # any d x (sqrt(3)/2 d) brick tiles the plane with one disk per brick, so a
    # region of whole bricks at any offset holds exactly pi/(2 sqrt 3) of disk
    region = (5.37, 5.37 + 12, 4.11, 4.11 + 10 * h)
    assert analysis.packing_fraction(pos, 0.5, region) == pytest.approx(HEX_FRACTION, abs=1e-9)
    vm = analysis.voidage_map(pos, 0.5, 2.0, region=region)
    weighted = np.sum(vm.packing_fraction * vm.cell_area) / vm.cell_area.sum()
    assert weighted == pytest.approx(HEX_FRACTION, abs=1e-9)
    np.testing.assert_allclose(vm.voidage, 1 - vm.packing_fraction)
    # square cells of 4 diameters inside the packing: each within 1% of the ideal value
    vm = analysis.voidage_map(pos, 0.5, 4.0, region=(3.3, 23.3, 3.1, 19.1))
    assert vm.packing_fraction.shape == (4, 5)
    np.testing.assert_allclose(vm.packing_fraction, HEX_FRACTION, rtol=0.01)


def test_square_lattice_fills_pi_over_4_in_every_cell():
    pos = square_lattice(20, 20)
    # a d x d square at any offset is a fundamental domain: exactly one disk's area
    vm = analysis.voidage_map(pos, 0.5, 1.0, region=(2.23, 12.23, 3.71, 13.71))
    assert vm.packing_fraction.shape == (10, 10)
    np.testing.assert_allclose(vm.packing_fraction, SQUARE_FRACTION, atol=1e-12)
    vm = analysis.voidage_map(pos, 0.5, 3.0, region=(2.23, 14.23, 3.71, 15.71))
    np.testing.assert_allclose(vm.packing_fraction, SQUARE_FRACTION, atol=1e-12)


def test_voidage_map_cells_edges_and_empty_regions():
    pos = np.array([[1.0, 1.0], [3.6, 0.5]])
    vm = analysis.voidage_map(pos, 0.5, 2.0, region=(0.0, 5.0, 0.0, 2.0))
    np.testing.assert_allclose(vm.x_edges, [0, 2, 4, 5])
    np.testing.assert_allclose(vm.cell_area, [[4.0, 4.0, 2.0]])  # the last cell is cut at x = 5
    assert vm.packing_fraction[0, 0] == pytest.approx(math.pi * 0.25 / 4)  # one whole disk
    total = np.sum(vm.packing_fraction * vm.cell_area)
    assert total == pytest.approx(2 * math.pi * 0.25)  # nothing lost at cell borders
    # a disk half outside the region counts only its inside half
    half = analysis.voidage_map(np.array([[0.0, 1.0]]), 0.5, 2.0, region=(0.0, 2.0, 0.0, 2.0))
    assert half.packing_fraction[0, 0] == pytest.approx(math.pi * 0.25 / 2 / 4)
    # an empty region gives 0 (voidage 1) everywhere
    empty = analysis.voidage_map(pos, 0.5, 1.0, region=(10.0, 14.0, 10.0, 13.0))
    assert empty.packing_fraction.shape == (3, 4)
    assert np.all(empty.packing_fraction == 0) and np.all(empty.voidage == 1)
    assert analysis.packing_fraction(pos, 0.5, (10.0, 14.0, 10.0, 13.0)) == 0.0
    inactive = analysis.voidage_map(pos, 0.5, 1.0, np.zeros(2, bool), region=(0.0, 5.0, 0.0, 2.0))
    assert np.all(inactive.packing_fraction == 0)


def test_voidage_map_default_region_is_the_bounding_box():
    pos = square_lattice(4, 6)
    vm = analysis.voidage_map(pos, 0.5, 1.0)
    np.testing.assert_allclose(vm.x_edges[[0, -1]], [-0.5, 5.5])
    np.testing.assert_allclose(vm.y_edges[[0, -1]], [-0.5, 3.5])
    np.testing.assert_allclose(vm.packing_fraction, SQUARE_FRACTION)


def test_voidage_rejects_bad_inputs():
    pos = square_lattice(3, 3)
    for size in (0.0, -1.0, float("nan")):
        with pytest.raises(InputError, match="cell_size must be positive"):
            analysis.voidage_map(pos, 0.5, size)
    with pytest.raises(InputError, match="empty"):
        analysis.voidage_map(np.zeros((0, 2)), 0.5, 1.0)
    with pytest.raises(InputError, match="region"):
        analysis.voidage_map(pos, 0.5, 1.0, region=(2.0, 1.0, 0.0, 1.0))
    with pytest.raises(InputError, match="no active disk and no region"):
        analysis.voidage_map(pos, 0.5, 1.0, np.zeros(9, bool))
    for size in (1e-7, 5e-324):  # cells too fine for any memory: refused before the grid is allocated
        with pytest.raises(InputError, match="Use larger cells"):
            analysis.voidage_map(pos, 0.5, size)


# ---------------------------------------------------------------- force chains
def _pair_force(force, in_contact, normal=None):
    force = np.asarray(force, float)
    return PairForce(force=force, torque=np.zeros(force.shape[:-1]), history=np.zeros(force.shape),
                     normal=np.linalg.norm(force, axis=-1) if normal is None else np.asarray(normal, float),
                     in_contact=np.asarray(in_contact, bool))


def test_force_chains_pick_the_strongest_and_weakest_partners():
    n = 4  # disks 0..3, 3 neighbour slots, 3 walls (ground, left, right)
    idx = np.array([[1, 2, n], [0, 3, n], [3, n, n], [1, 2, n]])
    pair = np.zeros((n, 3, 2))
    contact = np.zeros((n, 3), bool)
    pair[0, 0], contact[0, 0] = (3.0, 4.0), True   # 0 <- 1: 5
    pair[0, 1], contact[0, 1] = (0.0, 1.0), True   # 0 <- 2: 1
    pair[0, 2], contact[0, 2] = (0.0, 99.), True   # empty slot: never a partner
    pair[1, 0], contact[1, 0] = (-3.0, -4.0), True  # 1 <- 0: 5
    pair[1, 1], contact[1, 1] = (0.0, 0.0), True   # touching, carrying nothing: not counted
    pair[2, 0], contact[2, 0] = (50.0, 0.0), False  # not in contact: not counted
    pair[3, 0], contact[3, 0] = (2.0, 0.0), True
    pair[3, 1], contact[3, 1] = (0.0, 2.0), True   # a tie: the first slot wins
    wall = np.zeros((n, 3, 2))
    wall_contact = np.zeros((n, 3), bool)
    wall[0, GROUND], wall_contact[0, GROUND] = (0.0, 2.0), True
    wall[1, RIGHT_WALL], wall_contact[1, RIGHT_WALL] = (-7.0, 0.0), True
    cf = ContactForces(pair=_pair_force(pair, contact), wall=_pair_force(wall, wall_contact),
                       force=np.zeros((n, 2)), torque=np.zeros(n))
    fc = analysis.force_chains(cf, idx)
    np.testing.assert_array_equal(fc.strongest, [1, analysis.wall_partner(RIGHT_WALL), n, 1])
    np.testing.assert_array_equal(fc.weakest, [2, 0, n, 1])
    np.testing.assert_allclose(fc.strongest_force, [5, 7, np.nan, 2])
    np.testing.assert_allclose(fc.weakest_force, [1, 5, np.nan, 2])
    np.testing.assert_array_equal(fc.contacts, [3, 2, 0, 2])
    assert analysis.wall_partner(GROUND) == -1 and analysis.wall_partner(RIGHT_WALL) == -3
    # forces in other units, a threshold, and the normal component instead of |F|
    fc = analysis.force_chains(cf, idx, unit=0.5, min_force=2.5)
    np.testing.assert_array_equal(fc.weakest, [-1, 0, n, 1])
    np.testing.assert_allclose(fc.weakest_force, [4, 10, np.nan, 4])
    normal = np.zeros((n, 3))
    normal[0, :2] = (0.5, 3.0)  # by normal force, disk 2 pushes 0 harder than disk 1
    cf = cf._replace(pair=_pair_force(pair, contact, normal))
    fc = analysis.force_chains(cf, idx, measure="normal")
    assert fc.strongest[0] == 2 and fc.weakest[0] == 1


def test_force_chains_reject_bad_inputs():
    cf = ContactForces(pair=_pair_force(np.zeros((2, 1, 2)), np.zeros((2, 1))),
                       wall=_pair_force(np.zeros((2, 3, 2)), np.zeros((2, 3))),
                       force=np.zeros((2, 2)), torque=np.zeros(2))
    with pytest.raises(InputError, match="measure"):
        analysis.force_chains(cf, np.array([[1], [0]]), measure="shear")
    with pytest.raises(InputError, match="do not match"):
        analysis.force_chains(cf, np.array([[1, 2], [0, 2]]))
    with pytest.raises(InputError, match="n > 0"):
        analysis.force_chains(cf, np.zeros((0, 1), int))


def test_force_chains_of_a_three_disk_stack_from_a_simulator():
    """Ground overlap 0.03 > lower pair 0.02 > upper pair 0.01: with a linear law
    the middle disk's strongest partner is the bottom one, its weakest the top one."""
    from jaxpile.laws import hooke

    pos = np.array([[0.0, 0.47], [0.0, 1.45], [0.0, 2.44]])
    particles = jaxpile.make_particles(pos, 0.5)
    boundaries = jaxpile.make_boundaries()
    params = hooke.make_params(kn=1e4, gamma_n=0.0, mu=0.0)
    sim = jaxpile.Simulator(hooke.law(rotation=False), dt=1e-4)
    state = sim.init(params, particles, boundaries)
    fc = analysis.force_chains_of(sim, params, state)
    np.testing.assert_array_equal(fc.strongest, [-1, 0, 1])
    np.testing.assert_array_equal(fc.weakest, [1, 2, 1])
    np.testing.assert_allclose(fc.strongest_force, [300, 200, 100], rtol=1e-9)  # kn * overlap, in mg = 1


# -------------------------------------------------------- energy and rest
def _state(velocity, angular_velocity=0.0, fixed=None):
    particles = jaxpile.make_particles(np.array([[0.0, 0.5], [2.0, 0.5], [4.0, 0.5]]), 0.5, mass=[1.0, 2.0, 3.0],
                                       velocity=velocity, angular_velocity=angular_velocity, fixed=fixed)
    return jaxpile.SimState(particles=particles, contacts=None, boundaries=None, neighbors=None,
                            step=np.int32(0), neighbor_settings=None)


def test_mean_kinetic_energy_per_movable_disk():
    v = np.array([[1.0, 0.0], [0.0, 2.0], [0.0, 0.0]])
    state = _state(v, angular_velocity=[0.0, 0.0, 4.0], fixed=[False, False, False])
    # 0.5 + 4 + rotation 0.5 * (3 * 0.25 / 2) * 16 = 4.5 + 3 = 7.5 over three disks
    assert analysis.mean_kinetic_energy(state) == pytest.approx(7.5 / 3)
    assert analysis.mean_kinetic_energy(state) * 3 == pytest.approx(analysis.kinetic_energy(state))
    still = _state(np.zeros((3, 2)), fixed=[False, False, True])
    assert analysis.mean_kinetic_energy(still) == 0.0


def test_kinetic_energy_series_from_a_list_or_a_stacked_rollout():
    base = np.array([[1.0, 0.0], [0.0, 2.0], [0.0, 0.0]])
    scales = [1.0, 0.5, 0.1, 0.0]
    states = [_state(s * base) for s in scales]
    series = analysis.kinetic_energy_series(states)
    np.testing.assert_allclose(series, 4.5 / 3 * np.array(scales) ** 2)
    stacked = jax.tree.map(lambda *xs: np.stack(xs), *states)
    np.testing.assert_allclose(analysis.kinetic_energy_series(stacked), series)
    assert analysis.rest_index(series, 0.05) == 2
    with pytest.raises(InputError, match="no states"):
        analysis.kinetic_energy_series([])
    with pytest.raises(InputError, match="leading time axis"):
        analysis.kinetic_energy_series(states[0])


def test_rest_index_is_where_the_series_stays_below_the_tolerance():
    assert analysis.rest_index([5, 3, 0.5, 2, 0.1, 0.05], 1.0) == 4
    assert analysis.rest_index([0.1, 0.2], 1.0) == 0
    assert analysis.rest_index([0.1, 2.0], 1.0) is None
    assert analysis.rest_index([0.1, np.nan, 0.1], 1.0) == 2  # NaN is not rest
    with pytest.raises(InputError, match="non-empty 1-D"):
        analysis.rest_index([], 1.0)
    with pytest.raises(InputError, match="tolerance must be positive"):
        analysis.rest_index([1.0], 0.0)
