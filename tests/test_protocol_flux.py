"""The constant-flux pile (Lee & Herrmann 1993, sec. 5, Fig. 5) at a small size:
disks inserted at the upper left inside the compiled loop whenever the pile is
at rest, the surface recorded before each insertion.

The lee-herrmann run uses the paper's parameters and its rest test (the
largest speed below v_cut)."""

import numpy as np
import pytest

from jaxpile import analysis
from jaxpile.engine.boundaries import RIGHT_WALL
from jaxpile.errors import InputError
from jaxpile.protocols import box, flux

WIDTH = 1.6  # the paper's units (cm): 8 columns


@pytest.fixture(scope="module")
def lh_flux():
    return flux.SPEC.run("lee-herrmann", 20, width=WIDTH, max_time=6.0)


@pytest.fixture(scope="module")
def hooke_flux():
    return flux.SPEC.run("hooke", 12, width=WIDTH, max_time=4.0)


def _check_counts(state, m):
    info = m["info"]
    counts = box.count_check(state)
    assert counts["n_total"] == info["n_base"] + info["pool"] + info["spare"]
    assert counts["n_fixed"] == info["n_base"] and counts["n_unused"] == info["spare"]
    # every disk inserted is either in play or has left over the floor's end
    assert m["inserted"] - m["n_left"] == counts["n_in_play"]
    assert counts["n_in_play"] + counts["n_out_of_play"] == info["pool"]
    p = state.particles
    x = np.asarray(p.position)[np.asarray(p.movable), 0]
    assert np.all((x >= 0) & (x <= info["width"]))
    assert not bool(state.boundaries.wall_active[RIGHT_WALL])


@pytest.mark.parametrize("which", ["lh_flux", "hooke_flux"])
def test_every_disk_is_inserted_one_at_a_time_and_the_pile_ends_at_rest(which, request):
    state, m = request.getfixturevalue(which)
    total = m["info"]["insertions"]
    _check_counts(state, m)
    assert m["inserted"] == total and m["at_rest"] and m["starved_steps"] == 0
    steps = np.asarray(m["insert_step"])
    assert steps[0] == 0 and np.all(np.diff(steps) > 0) and m["settled_step"] > steps[-1]
    # each insertion waited for the previous disk to land and stop: more than its fall
    assert np.min(np.diff(steps)) > 50
    # in play before each insertion: one more each time unless disks left
    in_play = np.asarray(m["in_play"])
    assert in_play[0] == 0 and np.all(np.diff(in_play) <= 1)


@pytest.mark.parametrize("which", ["lh_flux", "hooke_flux"])
def test_the_angle_starts_at_zero_and_grows_to_a_finite_slope(which, request):
    _, m = request.getfixturevalue(which)
    angle = np.asarray(m["angle_cumulative_parabola"])
    assert angle.shape == (m["inserted"],) and np.all(np.isfinite(angle))
    assert abs(angle[0]) < 5.0  # the bare bottom layer
    assert 10.0 < np.max(angle[len(angle) // 2:]) < 60.0
    assert 5.0 < m["repose_cumulative_parabola"] < 60.0
    for key in ("angle_endpoints", "angle_least_squares"):
        assert len(m[key]) == m["inserted"] and np.all(np.asarray(m[key]) < 75.0)


def test_recorded_surface_is_the_analysis_surface_and_the_disk_lands_upper_left():
    """The surface recorded in the loop before the first insertion is
    `analysis.surface_profile` of the bottom layer, and the first disk appears
    at the left wall, `gap` above the disk under it."""
    p = flux.SPEC.set_up("hooke", 3, width=WIDTH, seed=4)
    _, _, params = box.law_and_params("hooke")
    sim = flux.SPEC.simulator(flux.FluxOptions(insertions=3, width=WIDTH), law="hooke", dt=p.info["dt"], chunk_steps=10)
    state = sim.init(params, p.particles, p.boundaries, box=p.box, protocol_state=p.protocol_state)
    first = state
    state = sim.run(params, state, 1)
    ps = state.protocol_state
    assert int(ps.inserted) == 1 and int(ps.insert_step[0]) == 0
    profile = analysis.surface_profile_of(first, x_min=0.0, width=p.info["width"],
                                          column_width=p.info["column_width"])
    recorded = np.array(ps.profile[0])
    recorded[~np.isfinite(recorded)] = np.nan
    np.testing.assert_allclose(recorded, profile.height, equal_nan=True)
    new = p.info["n_base"]  # the first pool disk
    x, y = np.asarray(state.particles.position[new])
    r = float(state.particles.radius[new])
    assert bool(state.particles.active[new])
    assert r < x <= r + 2.0 * float(np.mean(np.asarray(p.particles.radius))) + 1e-9
    base = np.asarray(first.particles.position)[: p.info["n_base"]]
    base_r = np.asarray(first.particles.radius)[: p.info["n_base"]]
    under = np.abs(base[:, 0] - x) < base_r + r
    assert y - r == pytest.approx(np.max(base[under, 1] + base_r[under]) + p.info["gap"], abs=1e-6)


def test_disks_that_leave_return_to_the_pool():
    """A pool smaller than the number of insertions: disks that run off the
    floor's end are inserted again (15 insertions from 7 disks on a short
    floor). With a pool the pile can hold entirely, insertions wait."""
    state, m = flux.SPEC.run("hooke", 15, width=0.6, pool=7, max_time=3.0)
    _check_counts(state, m)
    assert m["inserted"] == 15 and m["n_left"] >= 8 and m["at_rest"] and m["starved_steps"] == 0
    state, m = flux.SPEC.run("hooke", 15, width=0.6, pool=3, max_time=0.3)
    _check_counts(state, m)
    assert m["inserted"] < 15 and m["starved_steps"] > 0 and not m["at_rest"]


def test_angles_of_synthetic_records():
    """The host turns recorded surfaces into the three angles of sec. 3: a
    straight 30 deg surface gives 30 deg by every method, empty inner columns
    are bridged, a flat one gives 0."""
    dx = 0.2
    x = dx * (np.arange(10) + 0.5)
    slope = -np.tan(np.radians(30.0))
    straight = 2.0 + slope * x
    gappy = straight.copy()
    gappy[4] = -np.inf
    out = flux.angles(0.0, dx, np.stack([straight, gappy, np.ones(10)]))
    for key in out:
        np.testing.assert_allclose(out[key], [30.0, 30.0, 0.0], atol=1e-9)


@pytest.mark.parametrize("kwargs, match", [
    ({"insertions": 0}, "insertions"),
    ({"pool": 0}, "pool"),
    ({"v_cut": -0.1}, "v_cut"),
    ({"gap": 0.0}, "gap"),
    ({"hold_time": -1.0}, "hold_time"),
    ({"width": 0.1}, "narrower"),
    ({"rest_measure": "median"}, "rest_measure"),
])
def test_bad_arguments_raise_input_error(kwargs, match):
    with pytest.raises(InputError, match=match):
        flux.SPEC.set_up("lee-herrmann", **{"insertions": 5, **kwargs})


def test_a_long_hold_time_sets_up_with_its_fallback_at_the_step_counters_limit():
    """hold_time = 10738 s is ~5.4e8 steps, within the 32-bit counter; the
    fallback (4x the hold) is not, and saturates at the counter's limit
    instead of overflowing (found by tests/test_input_properties.py)."""
    from jaxpile.ranges import MAX_STEPS

    p = flux.SPEC.set_up("lee-herrmann", insertions=3, hold_time=10738.0)
    assert int(p.protocol_state.fallback) == MAX_STEPS
    assert 0 < 4 * int(p.protocol_state.hold) > MAX_STEPS  # the hold itself is kept as asked
