"""The hopper (a silo emptied through an orifice, Beverloo's law): the new
protocol that proves issue 18's interface. It lives in one module and runs,
sweeps, fits, resumes and exports through the commands every protocol uses."""

import json
import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from jaxpile import sweeps
from jaxpile.batches import runs
from jaxpile.cli import main
from jaxpile.errors import InputError
from jaxpile.protocols import PROTOCOLS, hopper
from jaxpile.protocols.spec import ranges_of

SMALL = dict(width=10.0, orifice=4.0, seed=0)  # 60 disks run out in ~45k steps


def test_the_hopper_registers_itself_for_every_command():
    assert PROTOCOLS["hopper"] is hopper.SPEC
    from jaxpile import batches, cli

    assert "hopper" in cli.sweep_protocols() and batches.spec_of("hopper").default_law == "hooke"


@pytest.mark.parametrize("orifice", [1.0, 2.5, 4.0, 5.3, 7.9])
def test_the_closed_floor_has_no_gap_a_disk_passes_and_the_open_one_is_the_orifice(orifice):
    x, gate, slots = hopper.floor(12.0, orifice)
    assert slots == 20 and x.size <= slots  # the same slots for every orifice of this width
    closed = np.sort(x)
    assert closed[0] == pytest.approx(0.5) and closed[-1] == pytest.approx(11.5)  # touching the walls
    assert np.max(np.diff(closed)) <= 1.0 + 1e-12  # edge gaps <= 0: no disk falls through
    open_ = np.sort(x[~gate])
    widest = np.max(np.diff(open_)) - 1.0  # between the edges of the disks beside the orifice
    assert widest == pytest.approx(orifice) and gate.sum() == math.ceil(orifice)
    assert (hopper.SPEC.set_up("hooke", 10, width=12.0, orifice=orifice).particles.count
            == hopper.SPEC.set_up("hooke", 10, width=12.0, orifice=2.0).particles.count)  # batchable over orifices


def test_an_orifice_that_leaves_no_floor_is_refused_in_one_line():
    with pytest.raises(InputError, match="must leave a floor disk on each side") as err:
        hopper.SPEC.set_up("hooke", 10, width=6.0, orifice=4.5)
    assert "\n" not in str(err.value)


def test_the_flow_rate_and_beverloo_fit_give_back_what_made_them():
    """Q = C n_A sqrt(g) (D - k)^(3/2) (Beverloo et al. 1961, for a slot)."""
    assert hopper.flow_rate(np.arange(200) / 4.0) == pytest.approx(4.0)
    assert math.isnan(hopper.flow_rate([1.0, 2.0, 3.0]))
    orifice = np.array([3.0, 4.0, 6.0, 8.0])
    fitted = hopper.beverloo_fit(orifice, 0.7 * 0.9 * (orifice - 1.3) ** 1.5, number_density=0.9)
    assert fitted["c"] == pytest.approx(0.7) and fitted["k"] == pytest.approx(1.3)
    with pytest.raises(InputError):
        hopper.beverloo_fit([4.0, 4.0], [1.0, 1.0], 0.9)


def test_dead_zone_angles_read_each_side_of_the_orifice_from_the_wall_to_its_edge():
    """A staircase beside each edge of a 4-wide orifice in a 10-wide silo: on
    the left, heights 3, 2, 1 above the floor over unit columns (45 deg); on the
    right 2, 1.5, 1 the other way (26.6 deg); a disk over the orifice is not read."""
    from types import SimpleNamespace

    floor = [(x, hopper.FLOOR_Y) for x in np.arange(0.5, 10.0, 1.0)]
    left = [(0.5, hopper.FLOOR_Y + 3), (1.5, hopper.FLOOR_Y + 2), (2.5, hopper.FLOOR_Y + 1)]
    right = [(7.5, hopper.FLOOR_Y + 1), (8.5, hopper.FLOOR_Y + 1.5), (9.5, hopper.FLOOR_Y + 2)]
    xy = np.array(floor + left + right + [(5.0, hopper.FLOOR_Y + 9)])
    particles = SimpleNamespace(position=xy, radius=np.full(len(xy), 0.5), active=np.ones(len(xy), bool))
    angles = hopper.dead_zone_angles(SimpleNamespace(particles=particles), {"width": 10.0, "orifice": 4.0})
    assert angles["dead_zone_left"] == pytest.approx(45.0)
    assert angles["dead_zone_right"] == pytest.approx(math.degrees(math.atan(0.5)))
    assert angles["dead_zone_angle"] == pytest.approx(0.5 * (45.0 + math.degrees(math.atan(0.5))))


@pytest.fixture(scope="module")
def narrow_and_wide():
    """Three silos of one width (one compiled simulator): D = 2.5 (which clogs:
    an arch of two or three disks), 4.5 and 7.5."""
    return {d: hopper.SPEC.run("hooke", 60, **{**SMALL, "orifice": d}) for d in (2.5, 4.5, 7.5)}


def test_the_silo_fills_opens_at_rest_and_every_disk_is_counted_once(narrow_and_wide):
    for state, m in narrow_and_wide.values():
        hs = state.protocol_state
        assert m["at_rest"] and 0 < m["opened_step"] < m["stopped_step"] <= m["steps"]
        assert m["discharged"] + m["remaining"] == 60 and m["discharged"] == int(np.sum(np.asarray(hs.out_step) >= 0))
        assert np.all(np.asarray(hs.out_step)[np.asarray(hs.out_step) >= 0] > m["opened_step"])  # none before
        assert not np.any(np.asarray(state.particles.active)[np.asarray(hs.gate)])  # the gate is gone
        assert m["discharge"]["count"][-1] == m["discharged"] and 0.6 < m["number_density"] < 1.2


def test_a_wider_orifice_flows_faster_as_beverloo_says(narrow_and_wide):
    """Beverloo's (D - k)^(3/2): D = 7.5 over D = 4.5 is 2.8x at k = 1.5 (2.6-2.8x
    measured over seeds 0-2); one small silo per orifice, so a factor 2 is asserted."""
    narrow, wide = (narrow_and_wide[d][1]["flow_rate"] for d in (4.5, 7.5))
    assert wide > 2.0 * narrow > 0
    assert 0.3 < narrow_and_wide[7.5][1]["beverloo_c"] < 3.0


def test_a_narrow_orifice_clogs_and_is_flagged(narrow_and_wide):
    """In 2D an orifice of a few diameters jams with an arch: the run stops after
    `clog_time` without flow, with disks over the orifice. At 2.5 diameters a
    2D silo clogs within a few disks on any seed (the mean avalanche grows
    exponentially with D; at 3.5 it is tens of disks, and one seed's clog is luck)."""
    state, m = narrow_and_wide[2.5]
    assert m["clogged"] and m["at_rest"] and m["discharged"] < 10 and math.isnan(m["flow_rate"])
    assert m["stopped_step"] - m["opened_step"] < 30_000  # not the whole budget
    assert not narrow_and_wide[7.5][1]["clogged"]


def test_pile_resume_show_sweep_and_fit_take_the_hopper(tmp_path, capsys):
    out = tmp_path / "silo"
    argv = ["pile", "--protocol", "hopper", "--n", "60", "--width", "10", "--orifice", "4", "--no-progress",
            "--checkpoint-every", "10000", "--out", str(out)]
    assert main(argv) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["protocol"] == "hopper" and summary["flow_rate"] > 0
    assert (out / "discharge.png").stat().st_size > 10_000
    final = np.load(out / "state.npz")["particles.position"]
    assert main(["pile", "--resume", str(out), "--no-progress"]) == 0  # bit-identical from the checkpoint
    np.testing.assert_array_equal(np.load(out / "state.npz")["particles.position"], final)
    assert main(["show", str(out), "--out", str(tmp_path / "redrawn")]) == 0
    assert (tmp_path / "redrawn" / "discharge.png").stat().st_size > 10_000

    # a sweep over a set-up option: one batch per orifice (Beverloo's law from the command line)
    assert main(["sweep", "--protocol", "hopper", "--vary", "orifice=4,7", "--seeds", "1", "--n", "60", "--width",
                 "10", "--beverloo-k", "2", "--no-progress", "--out", str(tmp_path / "sweep")]) == 0
    narrow, wide = sweeps.read(tmp_path / "sweep").rows
    # the simulator ignores the orifice (Adapter.simulator_options): both batches ran on one compiled ensemble
    assert len([key for key in runs._ENSEMBLES if key[0] == "hopper"]) == 1
    assert (narrow["orifice"], wide["orifice"]) == (4.0, 7.0)
    # a batch sums forces in another order, and a discharge is chaotic: a member
    # is a pile of its own (5.1 vs 3.5 disks / time measured at D = 4), not the single run
    for row in (narrow, wide):
        assert row["discharged"] + row["remaining"] == 60 and row["flow_rate"] > 0 and row["at_rest"]
        # a run option reaches each member's measurement: C at the given k = 2, not the default 1.5
        gap = row["orifice"] - 2.0
        assert row["beverloo_c"] == pytest.approx(row["flow_rate"] / (row["number_density"] * gap**1.5), rel=1e-12)
    assert wide["flow_rate"] > 2.0 * narrow["flow_rate"]
    capsys.readouterr()
    assert main(["fit", "--protocol", "hopper", "--params", "mu", "--truth", "mu=0.45", "--ensemble", "2",
                 "--dry-run", "--out", str(tmp_path / "fit")]) == 0
    assert "statistics ['flow_rate']" in capsys.readouterr().out


EDGES = [0, -1, 1e-300, 0.49999, 0.5, 1e300, math.nan, math.inf, -math.inf, 2**63, "abc", None, True, [1.0]]


@settings(database=None, deadline=None, suppress_health_check=list(HealthCheck), max_examples=60)
@given(data=st.data())
def test_every_set_up_option_at_its_edges_sets_up_or_refuses_in_one_line(data):
    """Issue 19's promise for the new protocol: a silo with one option drawn at
    or beyond its range is built, or refused with one InputError line (the
    options' ranges, and the set-up's dt and seed)."""
    from jaxpile.ranges import SEED, TIME_STEP

    option_ranges = {**ranges_of(hopper.HopperOptions), "dt": TIME_STEP, "seed": SEED}
    names = sorted(option_ranges)
    name = data.draw(st.sampled_from(names))
    r = option_ranges[name]
    bounds = [b for b in (r.low, r.high) if b is not None]
    value = data.draw(st.sampled_from(EDGES + bounds) | st.floats(-1e3, 1e3) | st.integers(-5, 50))
    if name == "n" and isinstance(value, (int, float)) and not isinstance(value, bool) and value > 40:
        value = 40  # a huge valid count is the memory check's (tests/test_budget.py)
    try:
        p = hopper.SPEC.set_up("hooke", **{"n": 20, "width": 8.0, "orifice": 3.0, name: value})
    except InputError as err:
        assert "\n" not in str(err).strip(), str(err)
    else:
        assert p.particles.count == p.info["n"] + math.ceil(p.info["width"]) + 8  # the floor's slots and the disks


def test_a_dry_run_bounds_the_run_by_its_max_time(tmp_path, capsys):
    """--dry-run turns the time budget into steps (the registry entry's `budget`) and runs nothing."""
    assert main(["pile", "--protocol", "hopper", "--n", "50", "--max-time", "200", "--dry-run",
                 "--out", str(tmp_path / "never")]) == 0
    text = capsys.readouterr().out
    assert "max_steps 200,000" in text and "at most 200,000 steps" in text
    assert not (tmp_path / "never").exists()
