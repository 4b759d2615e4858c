"""The 1993 box pile (Lee & Herrmann, sec. 3, Fig. 1) at a small size: filled,
right wall removed inside the compiled loop, settled again, angle measured.

The lee-herrmann runs use the paper's parameters (gamma_s = gamma_n / 100) with
the law's default Cundall-Strack slip."""

import math

import jax.numpy as jnp
import numpy as np
import pytest

from jaxpile import theory
from jaxpile.engine.boundaries import LEFT_WALL, RIGHT_WALL
from jaxpile.errors import InputError
from jaxpile.protocols import box, drivers, geometry, paper1993, running

WIDTH, HEIGHT = 2.0, 1.4  # the paper's units (cm); about 72 disks


@pytest.fixture(scope="module")
def lh_box():
    return box.SPEC.run("lee-herrmann", width=WIDTH, height=HEIGHT, seed=0, max_time=2.0)


@pytest.fixture(scope="module")
def hooke_box_one_chunk():
    """The hooke law (reduced units) with the whole run in ONE compiled chunk:
    the wall removal and both rest detections happen inside it."""
    p = box.SPEC.set_up("hooke", width=WIDTH, height=HEIGHT, seed=1)
    _, _, params = box.law_and_params("hooke")
    o = box.BoxOptions(width=WIDTH, height=HEIGHT, max_time=1.2)
    steps = box.max_steps_for("hooke", p.info["dt"], 1.2)
    assert box.SPEC.budget(p, o) == steps
    sim = box.SPEC.simulator(o, law="hooke", dt=p.info["dt"], chunk_steps=steps)
    state, info, samples = running.run_setup(box.SPEC, sim, params, p, o)
    return p, state, info, samples


def _check_settled_pile(state, n, width):
    """Counts conserved, the disks in play inside the box and on or above the floor."""
    counts = box.count_check(state)
    assert counts["n_total"] == n
    assert counts["n_in_play"] + counts["n_out_of_play"] == n
    assert counts["n_out_of_play"] == int(state.protocol_state.left)
    p = state.particles
    inside = np.asarray(p.movable)
    x, y = np.asarray(p.position)[inside].T
    r = np.asarray(p.radius)[inside]
    assert np.all(x <= width) and np.all(x >= 0.9 * r)
    assert np.all(y >= 0.9 * r)
    # parked disks rest where they were parked, inactive
    parked = ~np.asarray(p.active)
    np.testing.assert_allclose(np.asarray(p.position)[parked], np.asarray(state.protocol_state.park)[parked])
    assert float(jnp.max(jnp.abs(p.velocity[parked]), initial=0.0)) == 0.0


def test_lee_herrmann_box_fills_loses_its_right_wall_and_settles_into_a_slope(lh_box):
    state, m = lh_box
    n = m["info"]["n"]
    assert n == paper1993.fill_count(WIDTH, HEIGHT) and 30 <= n <= 80
    assert m["at_rest"] and 0 < m["wall_removed_step"] < m["settled_step"] <= m["steps"]
    assert not bool(state.boundaries.wall_active[RIGHT_WALL]) and bool(state.boundaries.wall_active[LEFT_WALL])
    _check_settled_pile(state, n, m["info"]["width"])
    # the default n fills the box to about H before the wall goes
    assert 0.9 * HEIGHT < m["fill_height"] < 1.35 * HEIGHT
    # part of the pile ran out, part of it stays leaning on the left wall
    assert 0.2 * n < m["n_left"] < 0.8 * n
    assert float(drivers.rms_speed(state)) < m["info"]["rest_speed"]
    # a finite slope by each of the three methods, below vertical stacking
    for key in ("repose_endpoints", "repose_least_squares", "repose_cumulative_parabola"):
        assert 5.0 < m[key] < 45.0, (key, m[key])
    assert m["theta_ms_theory"] == pytest.approx(math.degrees(math.atan(0.6)))


def test_kinetic_energy_per_disk_follows_fig_1b(lh_box):
    """Rises as the disks fall, decays, rises again when the wall goes, decays."""
    _, m = lh_box
    ke = m["kinetic_energy"]
    step, energy = np.asarray(ke["step"]), np.asarray(ke["kinetic_energy"])
    assert step[0] == 0 and energy[0] == 0.0 and np.all(np.diff(step) > 0)
    assert step[-1] == m["steps"] and len(step) > 20
    fill = step <= m["wall_removed_step"]
    after = step > m["wall_removed_step"]
    peak = energy[fill].max()
    before = energy[fill][-1]
    assert before < 1e-3 * peak
    assert energy[after].max() > 100 * before
    assert energy[-1] < 1e-2 * energy[after].max()


def test_hooke_box_does_everything_inside_one_compiled_chunk(hooke_box_one_chunk):
    p, state, info, samples = hooke_box_one_chunk
    ps = state.protocol_state
    assert info.steps == samples["step"][-1] and len(samples["step"]) == 2  # one chunk
    assert 0 < int(ps.removed_at) < int(ps.settled_at) < info.steps
    assert not bool(state.boundaries.wall_active[RIGHT_WALL])
    _check_settled_pile(state, p.info["n"], p.info["width"])
    angles = box.repose(state, p.info["width"])
    for key in ("repose_endpoints", "repose_least_squares", "repose_cumulative_parabola"):
        assert 5.0 < angles[key] < 45.0, (key, angles[key])
    # reduced units: the paper's lengths times 5, mean diameter about 1
    assert np.mean(np.asarray(state.particles.radius)) == pytest.approx(0.5, rel=0.05)


def test_gaussian_radii_follow_the_1993_distribution():
    r = paper1993.gaussian_radii(50_000, np.random.default_rng(0))
    assert r.min() >= 0.07 and r.max() <= 0.13
    assert np.mean(r) == pytest.approx(0.1, abs=1e-3)
    assert np.mean(r**2) == pytest.approx(paper1993.mean_square_radius(), rel=2e-3)
    assert np.std(r) < 0.02  # the cut-offs narrow it
    assert paper1993.mean_radius() == pytest.approx(0.1, abs=1e-15)  # a symmetric cut keeps the mean
    lopsided = dict(mean=0.1, width=0.02, low=0.09, high=0.13)  # cut harder below: the mean moves up
    draws = paper1993.gaussian_radii(50_000, np.random.default_rng(1), **lopsided)
    assert paper1993.mean_radius(**lopsided) == pytest.approx(np.mean(draws), abs=3e-4) and np.mean(draws) > 0.105
    # the paper's "400 particle system" fills its 4 x 4 box
    assert 380 <= paper1993.fill_count(4.0, 4.0) <= 420


def test_random_start_has_no_overlap_and_stays_in_the_box():
    rng = np.random.default_rng(3)
    r = paper1993.gaussian_radii(120, rng)
    pos = geometry.random_positions(r, 2.0, 4.0, rng)
    d = np.linalg.norm(pos[:, None] - pos[None], axis=-1) + np.eye(len(r)) * 10
    assert np.all(d >= (r[:, None] + r[None]) * 1.0)
    assert np.all(pos - r[:, None] >= 0) and np.all(pos[:, 0] + r <= 2.0) and np.all(pos[:, 1] + r <= 4.0)
    with pytest.raises(InputError, match="could not place"):
        geometry.random_positions(paper1993.gaussian_radii(200, rng), 1.0, 1.0, rng, attempts=200)


def test_protocol_is_a_pure_function_of_its_seed():
    a = box.SPEC.set_up("lee-herrmann", 40, width=1.6, height=1.6, seed=7)
    b = box.SPEC.set_up("lee-herrmann", 40, width=1.6, height=1.6, seed=7)
    c = box.SPEC.set_up("lee-herrmann", 40, width=1.6, height=1.6, seed=8)
    np.testing.assert_array_equal(a.particles.position, b.particles.position)
    np.testing.assert_array_equal(a.particles.radius, b.particles.radius)
    assert not np.array_equal(a.particles.position, c.particles.position)
    assert a.info["n"] == 40 and bool(a.boundaries.wall_active[RIGHT_WALL])
    assert a.driver is box.driver and a.protocol_state.removed_at == -1


def test_a_box_a_layer_or_two_deep_warns_with_the_count_that_fills_it():
    """Below a quarter of the disks that fill the box (`box.SPARSE_FILL`) the pile is a layer or two and its
    angle means little: the set-up says so in one line, with the count that fills the box; at a quarter
    and above it is quiet."""
    import warnings

    fills = paper1993.fill_count(1.6, 1.6)
    sparse = math.ceil(box.SPARSE_FILL * fills) - 1
    with pytest.warns(UserWarning, match=rf"^{sparse} disks fill the 1.6 x 1.6 box .* too few to stand as a pile; "
                                         rf"the box takes {fills} \(leave n out\)"):
        box.SPEC.set_up("lee-herrmann", sparse, width=1.6, height=1.6, seed=0)
    with warnings.catch_warnings():
        warnings.filterwarnings("error", message=".*too few to stand as a pile", category=UserWarning)
        box.SPEC.set_up("lee-herrmann", sparse + 1, width=1.6, height=1.6, seed=0)


@pytest.mark.parametrize("kwargs, match", [
    ({"n": 0}, "n must be"),
    ({"n": 2.5}, "n must be"),
    ({"width": -1.0}, "width"),
    ({"width": 0.2}, "narrower"),
    ({"rest_speed": 0.0}, "rest_speed"),
    ({"rest_measure": "mean"}, "rest_measure"),
    ({"placement_fraction": 0.7}, "placement_fraction"),
    ({"radius": {"low": 0.2}}, "radii"),
    ({"law": "sticky"}, "unknown law"),
])
def test_bad_arguments_raise_input_error(kwargs, match):
    with pytest.raises(InputError, match=match):
        box.SPEC.set_up(**kwargs)


def test_params_of_the_wrong_law_raise_input_error():
    from jaxpile.laws import hooke

    with pytest.raises(InputError, match="params must be"):
        box.law_and_params("lee-herrmann", hooke.make_params())


def test_theory_reference_matches_eq_3():
    assert paper1993.friction_coefficient(box.law_and_params("lee-herrmann")[2]) == pytest.approx(0.2)
    assert paper1993.friction_coefficient(box.law_and_params("liffman")[2]) is None
    assert float(theory.marginal_stability_angle(0.2)) == pytest.approx(math.atan(0.6))


def test_a_box_far_too_sparse_to_stand_warns_with_the_count_that_fills_it():
    """60 disks in the paper's 4 x 4 box are one layer: the set-up says so and
    names the count that fills the box (409), instead of a silent 2.5-degree angle."""
    import warnings

    with pytest.warns(UserWarning, match=r"60 disks fill the 4 x 4 box .* the box takes 409"):
        box.SPEC.set_up("hooke", 60)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a third of the fill stands: no warning
        box.SPEC.set_up("hooke", 140)


def test_the_energy_figure_leaves_out_the_start_at_rest_and_the_headline_says_why_an_angle_is_nan():
    """Fig. 1(b) on a log axis: the first sample (at rest, E = 0) is left out, so
    the axis spans the run's energies; a NaN angle's reason is printed with the headline."""
    from jaxpile.cli.pile_outputs import headline
    from jaxpile.cli import presentation

    time, energy = presentation.energy_series({"kinetic_energy": {"time": [0.0, 0.5, 1.0], "kinetic_energy": [0.0, 2e-3, 1e-6]}})
    assert time.tolist() == [0.5, 1.0] and energy.tolist() == [2e-3, 1e-6]
    text = headline("box", {"repose_cumulative_parabola": float("nan"), "repose_error": "fewer than 3 columns"})
    assert "repose_error: fewer than 3 columns" in text
