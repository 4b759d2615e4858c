"""Tilting a settled pile until it moves (Lee & Herrmann 1993, sec. 4, Fig. 4),
at a small size and a fast tilt (0.02 deg per step instead of the paper's 1e-3).

The pile is built by the box protocol with the lee-herrmann law at the paper's
parameters."""

import math

import jax.numpy as jnp
import numpy as np
import pytest

from jaxpile import theory
from jaxpile.errors import InputError
from jaxpile.protocols import box, drivers, running, tilt

RATE = 0.02  # degrees per step


@pytest.fixture(scope="module")
def pile():
    state, m = box.SPEC.run("lee-herrmann", width=2.0, height=1.4, seed=3, max_time=2.0)
    assert m["at_rest"]
    return state, m


@pytest.fixture(scope="module")
def frictional(pile):
    return tilt.SPEC.run("lee-herrmann", pile=pile[0], rate_degrees=RATE)


@pytest.fixture(scope="module")
def frictionless(pile):
    return tilt.SPEC.run("lee-herrmann", pile=pile[0], params={"mu": 0.0}, rate_degrees=RATE)


def _check_counts_and_gravity(pile_state, state, m):
    counts = box.count_check(state)
    assert counts["n_total"] == pile_state.particles.count
    assert counts["n_in_play"] + counts["n_out_of_play"] == counts["n_total"]
    assert counts["n_out_of_play"] == m["n_left"] >= int(pile_state.protocol_state.left)
    g = np.asarray(state.boundaries.gravity)
    g0 = np.asarray(pile_state.boundaries.gravity)
    assert np.linalg.norm(g) == pytest.approx(np.linalg.norm(g0), rel=1e-12)
    # gravity turned counter-clockwise (the box clockwise) by the tilt held at the end
    assert math.degrees(math.atan2(g[0], -g[1])) == pytest.approx(m["tilt_held"], abs=1e-9)
    assert m["tilt_held"] >= m["theta_t"]


def test_a_frictional_pile_holds_for_a_finite_tilt_then_moves(pile, frictional):
    state, m = frictional
    _check_counts_and_gravity(pile[0], state, m)
    assert m["moved"] and m["mu"] == pytest.approx(0.2)
    assert 0.5 < m["theta_t"] < 20.0
    assert m["theta_t"] == pytest.approx(RATE * m["onset_step"])
    assert 0 <= m["onset_step"] < m["moved_step"]
    # the motion that made it fail: well above the rest level at the end
    assert float(drivers.rms_speed(state)) > m["info"]["rest_speed"]
    # its own angle of repose and the theory of sec. 6
    assert m["theta_r"] == pytest.approx(pile[1]["repose_cumulative_parabola"])
    assert m["theta_ms_theory"] == pytest.approx(math.degrees(math.atan(0.6)))
    assert m["theta_r_plus_theta_t"] == pytest.approx(m["theta_r"] + m["theta_t"])
    expected = math.degrees(theory.tilting_angle(math.radians(m["theta_r"]), 0.2))
    assert m["theta_t_theory"] == pytest.approx(expected)


def test_a_frictionless_pile_moves_at_once(pile, frictional, frictionless):
    state, m = frictionless
    _check_counts_and_gravity(pile[0], state, m)
    assert m["moved"] and m["theta_t"] < 0.5
    assert m["moved_step"] < frictional[1]["moved_step"] / 3
    assert m["theta_t"] < frictional[1]["theta_t"] / 3
    # eq. 3: theta_MS = 0 without friction, and eq. 4 has no answer
    assert m["theta_ms_theory"] == 0.0 and math.isnan(m["theta_t_theory"]) and "theory_note" in m


def test_a_pile_tilted_less_than_its_tilting_angle_stays_put():
    """Another law (hooke, reduced units): with the tilt capped at 0.2 deg the
    frictional pile never moves; the run gives up and says so."""
    state, m = box.SPEC.run("hooke", width=1.6, height=1.2, seed=0, max_time=1.5)
    assert m["at_rest"]
    s2, t = tilt.SPEC.run("hooke", pile=state, rate_degrees=0.05, max_tilt_degrees=0.2)
    assert not t["moved"] and math.isnan(t["theta_t"])
    assert t["tilt_held"] == pytest.approx(0.2)
    g = np.asarray(s2.boundaries.gravity)
    assert math.degrees(math.atan2(g[0], -g[1])) == pytest.approx(0.2, abs=1e-9)
    np.testing.assert_array_equal(np.asarray(s2.particles.active), np.asarray(state.particles.active))
    assert float(drivers.rms_speed(s2)) < t["info"]["move_speed"]
    moved = np.linalg.norm(np.asarray(s2.particles.position - state.particles.position), axis=1)
    assert np.quantile(moved, 0.9) < 1e-3 and moved.max() < 0.1  # in mean diameters


def test_the_tilt_schedule_is_linear_in_steps_and_capped():
    ps = tilt.TiltState(*([None] * len(tilt.TiltState._fields)))._replace(
        rate=jnp.asarray(math.radians(1e-3)), start=jnp.asarray(100), max_tilt=jnp.asarray(math.radians(2.0)))
    assert float(tilt.tilt_at(ps, jnp.asarray(50))) == 0.0
    assert math.degrees(float(tilt.tilt_at(ps, jnp.asarray(1100)))) == pytest.approx(1.0)
    assert math.degrees(float(tilt.tilt_at(ps, jnp.asarray(10_000)))) == pytest.approx(2.0)


def test_bad_arguments_raise_input_error(pile):
    state = pile[0]
    with pytest.raises(InputError, match="SimState"):
        tilt.SPEC.set_up("lee-herrmann", pile=state.particles)
    with pytest.raises(InputError, match="rate_degrees"):
        tilt.SPEC.set_up("lee-herrmann", pile=state, rate_degrees=0.0)
    with pytest.raises(InputError, match="below move_speed"):
        tilt.SPEC.set_up("lee-herrmann", pile=state, rest_speed=2.0, move_speed=1.0)
    with pytest.raises(InputError, match="max_tilt_degrees"):
        tilt.SPEC.set_up("lee-herrmann", pile=state, max_tilt_degrees=95.0)
    tilted = state.set(boundaries=state.boundaries.set(gravity=jnp.asarray([1.0, -981.0])))
    with pytest.raises(InputError, match="straight down"):
        tilt.SPEC.set_up("lee-herrmann", pile=tilted)
    with pytest.raises(InputError, match="edge"):
        tilt.SPEC.set_up("lee-herrmann", pile=state.set(protocol_state=None))
    o = tilt.TiltOptions(rate_degrees=RATE)
    p = tilt.setup(state, o, law="lee-herrmann", dt=tilt.SPEC.default_dt("lee-herrmann"))
    sim = tilt.SPEC.simulator(o, law="lee-herrmann", dt=p.info["dt"])
    with pytest.raises(InputError, match="not the state"):
        running.run_setup(tilt.SPEC, sim, box.law_and_params("lee-herrmann")[2], p, o,
                          state.set(step=state.step + 1))


def test_with_settle_the_run_ends_settle_time_after_the_pile_moved(pile):
    """`settle_time` is "at most this many paper seconds after the pile moved":
    a frictionless pile, tilt held, slides off and does not rest, so the run
    ends that long after its motion (within a chunk), not at the tilt budget."""
    state, m = tilt.SPEC.run("lee-herrmann", pile=pile[0], params={"mu": 0.0}, rate_degrees=RATE, settle=True,
                             settle_time=0.02)
    assert m["moved"]
    settle_steps = round(0.02 / m["info"]["dt"])  # the paper's seconds (lee-herrmann: cgs)
    after_motion = int(state.step) - m["info"]["start_step"] - m["moved_step"]
    # `finished` is seen at a chunk's end
    chunk = tilt.SPEC.simulator(tilt.TiltOptions(), law="lee-herrmann", dt=m["info"]["dt"]).chunk_steps
    assert m["at_rest"] or settle_steps < after_motion <= settle_steps + chunk + 1


@pytest.mark.parametrize("options, match", [
    ({"rest_speed": 5.0, "move_speed": 1.0}, "below move_speed"),
    ({"hold_time": 0.0}, "hold_time"),
    ({"settle": True, "settle_time": 0.0}, "settle_time"),
    ({"rest_measure": "median"}, "rest_measure"),
])
def test_the_tilt_refuses_its_own_options_before_it_builds_its_box_pile(monkeypatch, options, match):
    built = running.run

    def no_box(spec, *args, **kwargs):
        if spec.name == "box":
            pytest.fail("the box pile was built before the tilt's options were checked")
        return built(spec, *args, **kwargs)

    monkeypatch.setattr(running, "run", no_box)
    with pytest.raises(InputError, match=match):
        tilt.SPEC.run("lee-herrmann", pile_options={"n": 20}, **options)
