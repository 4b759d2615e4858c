"""Every protocol resumes bit-identically from a checkpoint of its own run: the
box-family runs (box, flux, tilt) with their per-chunk samples, the tilt across
its two stages (the box run that builds the pile, then the tilt), the drop
across its two phases (filling, relaxing), the sloped pile across its gravity
ramp; and a checkpoint saved where a phase ended resumes without a step."""

import glob
import os
import shutil

import jax
import numpy as np
import pytest

from jaxpile.engine import checkpoint
from jaxpile.protocols import drop, flux, sloped, tilt


def assert_identical(a, b):
    assert jax.tree_util.tree_structure(a) == jax.tree_util.tree_structure(b)
    for x, y in zip(jax.tree_util.tree_leaves(a), jax.tree_util.tree_leaves(b)):
        assert np.array_equal(np.asarray(x), np.asarray(y)), "the resumed run differs"


def saved_steps(folder, stage=""):
    """Steps of the `ck-{step}<stage>.npz` files in folder."""
    names = glob.glob(os.path.join(folder, f"ck-*{stage}.npz"))
    steps = [os.path.basename(f)[3:-len(stage) - 4] for f in names]
    return sorted(int(s) for s in steps if s.isdigit())


TILT = dict(rate_degrees=0.05, max_tilt_degrees=30.0, chunk_steps=500, seed=0,
            pile_options=dict(width=1.2, height=1.0, max_time=1.0))


@pytest.fixture(scope="module")
def tilted(tmp_path_factory):
    """A hooke tilt that builds its own box pile, checkpointed every 500 steps."""
    folder = tmp_path_factory.mktemp("tilt")
    state, m = tilt.SPEC.run("hooke", checkpoint=(str(folder / "ck-{step}.npz"), 500), **TILT)
    assert m["moved"] and m["box"]["at_rest"]
    return folder, state, m


def test_a_tilt_resumes_mid_tilt_from_its_save_and_the_pile_it_names(tilted):
    folder, whole, m = tilted
    start = m["info"]["start_step"]
    box_steps, tilt_steps = saved_steps(folder, ".box"), [s for s in saved_steps(folder) if s > start]
    assert box_steps[-1] == start and len(tilt_steps) >= 2
    mid = folder / f"ck-{tilt_steps[len(tilt_steps) // 2]}.npz"
    extra = checkpoint.read_metadata(mid)["extra"]
    assert extra["stage"] == "tilt" and extra["pile_checkpoint"] == f"ck-{start}.box.npz"
    resumed, r = tilt.SPEC.run("hooke", resume=str(mid), **TILT)
    assert_identical(resumed, whole)
    assert r["theta_t"] == m["theta_t"] and r["kinetic_energy"] == m["kinetic_energy"]
    assert r["steps_run"] < m["steps"] == r["steps"]


def test_a_tilt_killed_while_building_its_pile_resumes_the_box_run_then_tilts(tilted, tmp_path):
    folder, whole, m = tilted
    box_steps = saved_steps(folder, ".box")
    # what a kill during the box stage leaves in a run folder (fixed names): the box run's save alone
    shutil.copy(folder / f"ck-{box_steps[len(box_steps) // 2]}.box.npz", tmp_path / "checkpoint.box.npz")
    assert checkpoint.in_folder(tmp_path) == str(tmp_path / "checkpoint.box.npz")
    resumed, r = tilt.SPEC.run("hooke", resume=str(tmp_path / "checkpoint.npz"), **TILT)
    assert_identical(resumed, whole)
    assert r["box"]["settled_step"] == m["box"]["settled_step"] and r["theta_t"] == m["theta_t"]


def test_resuming_a_tilt_without_its_pile_checkpoint_is_a_clear_error(tmp_path):
    from jaxpile.errors import InputError

    with pytest.raises(InputError, match="box run's checkpoint"):
        tilt.SPEC.run("hooke", resume=str(tmp_path / "checkpoint.npz"), **TILT)


DROP = dict(seed=0, speed_tolerance=1e-6, relax_steps=200_000, chunk_steps=1000)


def test_a_drop_resumes_in_its_fill_phase_at_its_end_and_in_its_relax_phase(tmp_path):
    whole, m = drop.SPEC.run("hooke", 8, checkpoint=(str(tmp_path / "ck-{step}.npz"), 2000), **DROP)
    steps, fill = saved_steps(tmp_path), m["phases"]["fill"]
    assert fill in steps, "the fill phase's last chunk is saved"
    relax = [s for s in steps if s > fill]
    assert checkpoint.read_metadata(tmp_path / f"ck-{fill}.npz")["extra"]["phase"] == "fill"
    in_relax = checkpoint.read_metadata(tmp_path / f"ck-{relax[0]}.npz")["extra"]
    assert in_relax["phase"] == "relax" and in_relax["phase_starts"] == [fill] == in_relax["phases_ended"]["fill"]
    # mid-fill; the fill's end (all disks in: no more fill steps, the relax phase starts); mid-relax; the end
    for step in (steps[1], fill, relax[0], steps[-1]):
        resumed, r = drop.SPEC.run("hooke", 8, resume=str(tmp_path / f"ck-{step}.npz"), **DROP)
        assert_identical(resumed, whole)
        assert r["phases"]["fill"] == fill and r["central_dip"] == m["central_dip"]


def test_flux_resumes_with_its_insertion_record_and_a_finished_run_takes_no_step(tmp_path):
    kw = dict(width=0.6, pool=7, max_time=3.0, chunk_steps=500)
    whole, m = flux.SPEC.run("hooke", 8, checkpoint=(str(tmp_path / "ck-{step}.npz"), 1000), **kw)
    steps = saved_steps(tmp_path)
    resumed, r = flux.SPEC.run("hooke", 8, resume=str(tmp_path / f"ck-{steps[len(steps) // 2]}.npz"), **kw)
    assert_identical(resumed, whole)
    np.testing.assert_array_equal(r["angle_cumulative_parabola"], m["angle_cumulative_parabola"])
    assert r["insert_step"] == m["insert_step"] and r["kinetic_energy"] == m["kinetic_energy"]
    finished, f = flux.SPEC.run("hooke", 8, resume=str(tmp_path / f"ck-{steps[-1]}.npz"), **kw)
    assert_identical(finished, whole)
    assert f["steps_run"] == 0 and f["steps"] == m["steps"] and f["at_rest"]


def test_a_sloped_pile_resumes_on_its_gravity_ramp(tmp_path):
    kw = dict(n=20, ramp_steps=2000, speed_tolerance=1e-7, max_steps=100_000)
    whole, m = sloped.SPEC.run("hooke", alpha_degrees=30.0, checkpoint=(str(tmp_path / "ck-{step}.npz"), 1000), **kw)
    resumed, r = sloped.SPEC.run("hooke", alpha_degrees=30.0, resume=str(tmp_path / "ck-1000.npz"), **kw)
    assert_identical(resumed, whole)
    assert r["steps_run"] == m["steps"] - 1000 and r["steps"] == m["steps"] and r["central_slope_horizontal"] == m["central_slope_horizontal"]


def test_a_sweep_resumed_mid_batch_keeps_the_measured_rows_and_ends_with_the_same_rows(tmp_path):
    from jaxpile import sweeps

    kw = dict(vary={"mu": [0.2, 0.4]}, seeds=1, batch_size=1, progress=False, max_steps=4000,
              options={"n": 20, "width": 1.0, "height": 1.0, "max_time": 1.0})
    whole = sweeps.sweep("box", "hooke", checkpoint=(str(tmp_path / "ck-{step}.npz"), 1000), **kw)
    assert [r["mu"] for r in whole.rows] == [0.2, 0.4]
    # the second batch overwrote the first's files where it got to: take one of its mid-run saves
    second = [s for s in saved_steps(tmp_path)
              if checkpoint.read_metadata(tmp_path / f"ck-{s}.npz")["extra"]["batch_start"] == 1]
    mid = tmp_path / f"ck-{second[len(second) // 2]}.npz"
    extra = checkpoint.read_metadata(mid)["extra"]
    assert extra["rows"] == whole.rows[:1] and checkpoint.read_metadata(mid)["batch"] == 1
    resumed = sweeps.sweep("box", "hooke", resume=str(mid), **kw)
    assert resumed.rows == whole.rows
    # its record says its timings start at the checkpoint, not at step 0
    assert "resumed" not in whole.info
    assert resumed.info["resumed"] == {"checkpoint": str(mid), "step": checkpoint.read_metadata(mid)["step"],
                                       "batch_start": 1}
    # a sweep still running is not drawn as one pile: `jaxpile show` says what it holds
    from jaxpile.cli import main

    shutil.copy(mid, tmp_path / "checkpoint.npz")
    assert main(["show", str(tmp_path)]) == 2
    with pytest.raises(Exception, match="another sweep"):
        sweeps.sweep("box", "hooke", resume=str(mid), **{**kw, "seeds": 2})
