"""Checkpoints: atomic, complete, and a resumed run is bit-identical to the
uninterrupted one (across a neighbour-list re-allocation and a kill -9)."""

import json
import os
import signal
import subprocess
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxpile.engine import checkpoint
from jaxpile.engine.boundaries import make_boundaries
from jaxpile.errors import InputError
from jaxpile.laws import hooke
from jaxpile.engine.simulate import RunInfo, Simulator
from jaxpile.engine.state import make_particles

CHUNK = 250
# the resumed run: its slots grow between steps 200 and 250 (K 1 -> 6: sized by the neighbours its
# rebuilds found) and its window later, so a resume from step 200 carries both re-allocations
RESUME_CHUNK, EVERY, TOTAL = 100, 200, 600


def falling_disks(n=36, seed=0, dtype=jnp.float64):
    """Disks on a sparse grid thrown about in a box: few neighbours each at the
    start (a small list), a packed heap later (the list must grow)."""
    rng = np.random.default_rng(seed)
    i = np.arange(n)
    position = np.stack([(i % 6) * 1.6 + 0.8, (i // 6) * 1.6 + 0.8], 1) + rng.uniform(-0.1, 0.1, (n, 2))
    particles = make_particles(position, 0.5 * rng.uniform(0.9, 1.1, n), velocity=rng.normal(0, 1.0, (n, 2)),
                               dtype=dtype)
    return particles, make_boundaries(left=0.0, right=9.6, dtype=dtype)


@pytest.fixture(scope="module")
def setting():
    params = hooke.make_params(kn=1e4, gamma_n=20.0, mu=0.4)
    # lists sized for the disks as they start, so the falling disks force a re-allocation
    sim = Simulator(hooke.law(rotation=True), 5e-4, chunk_steps=RESUME_CHUNK, capacity_multiplier=1.0,
                    packed_lists=False)
    return sim, params


def fresh(sim, params, **kw):
    return sim.init(params, *falling_disks(**kw))


def assert_identical(a, b):
    la, lb = jax.tree_util.tree_leaves(a), jax.tree_util.tree_leaves(b)
    assert jax.tree_util.tree_structure(a) == jax.tree_util.tree_structure(b)
    for x, y in zip(la, lb):
        assert np.array_equal(np.asarray(x), np.asarray(y)), "resumed run differs"


def test_resumed_run_is_bit_identical_across_a_reallocation(setting, tmp_path):
    sim, params = setting
    info = RunInfo()
    path = str(tmp_path / "ck-{step}.npz")
    whole = sim.run(params, fresh(sim, params), TOTAL, progress=False, info=info, checkpoint=(path, EVERY))
    saved = sorted(os.listdir(tmp_path))
    assert saved == [f"ck-{s}.npz" for s in (200, 400, 600)]
    first = checkpoint.read_metadata(tmp_path / "ck-200.npz")
    # the list grew after the first checkpoint: the resume must carry a re-allocation
    assert info.reallocations >= 2 and whole.neighbors.max_occupancy > first["neighbor_capacity"]
    assert whole.neighbors.cell_list_capacity > first["cell_capacity"]
    assert first["step"] == 200 and first["law"] == "hooke" and first["precision"] == "float64"

    resumed = checkpoint.restore(tmp_path / "ck-200.npz", fresh(sim, params), "hooke", params)
    assert int(resumed.step) == 200
    resumed = sim.run(params, resumed, TOTAL - EVERY, progress=False)
    assert_identical(resumed, whole)
    # a format-2 file (before Contacts.slot_demand) resumes the same run: the re-allocation ahead
    # is sized by what its chunk's rebuilds record, not by the value restored
    with np.load(tmp_path / "ck-200.npz") as z:
        arrays = {k: z[k] for k in z.files if k != "leaf:.contacts.slot_demand"}
    assert len(arrays) == len(z.files) - 1
    arrays["metadata"] = np.asarray(json.dumps({**json.loads(str(arrays["metadata"])), "format": 2}))
    np.savez(tmp_path / "format2.npz", **arrays)
    older = checkpoint.restore(tmp_path / "format2.npz", fresh(sim, params), "hooke", params)
    assert int(older.contacts.slot_demand) <= older.neighbors.max_occupancy
    from jaxpile.cli.show import state_from_checkpoint  # `jaxpile show` reads it too

    assert np.array_equal(state_from_checkpoint(tmp_path / "format2.npz")[0].contacts.slot_demand,
                          older.contacts.slot_demand)
    assert_identical(sim.run(params, older, TOTAL - EVERY, progress=False), whole)
    # and the last checkpoint is the end state itself
    assert_identical(checkpoint.restore(tmp_path / "ck-600.npz", fresh(sim, params), "hooke", params), whole)


def test_restore_refuses_another_law_parameters_precision_or_setup(setting, tmp_path):
    sim, params = setting
    path = tmp_path / "ck.npz"
    state = fresh(sim, params)
    checkpoint.save(path, state, "hooke", params, command="test")
    assert checkpoint.read_metadata(path)["extra"] == {"command": "test"}
    with pytest.raises(InputError, match="written with the hooke law"):
        checkpoint.restore(path, state, "baxter", params)
    with pytest.raises(InputError, match="mu differ"):
        checkpoint.restore(path, state, "hooke", hooke.make_params(kn=1e4, gamma_n=20.0, mu=0.3))
    single = hooke.make_params(kn=1e4, gamma_n=20.0, mu=0.4, dtype=jnp.float32)
    with pytest.raises(InputError, match="float64 run"):
        checkpoint.restore(path, fresh(Simulator(hooke.law(), 5e-4), single, dtype=jnp.float32), "hooke", params)
    with pytest.raises(InputError, match="holds 36 disks"):
        checkpoint.restore(path, fresh(sim, params, n=30), "hooke", params)
    # another box, cutoff or skin is another set-up; another capacity multiplier (it only sizes
    # new lists: the run resumes at its saved capacities) is not
    settings = state.neighbor_settings
    with pytest.raises(InputError, match="neighbour settings"):
        checkpoint.restore(path, state.set(neighbor_settings=settings._replace(skin=2 * settings.skin)), "hooke", params)
    other = checkpoint.restore(path, state.set(neighbor_settings=settings._replace(capacity_multiplier=4.0)),
                               "hooke", params)
    np.testing.assert_array_equal(np.asarray(other.particles.position), np.asarray(state.particles.position))
    (tmp_path / "junk.npz").write_bytes(b"not a checkpoint")
    with pytest.raises(InputError, match="not a readable jaxpile checkpoint"):
        checkpoint.restore(tmp_path / "junk.npz", state, "hooke", params)
    with pytest.raises(InputError, match="checkpoint must be"):
        sim.run(params, state, 10, progress=False, checkpoint=str(path))


def test_restore_refuses_another_reading_of_the_law(setting, tmp_path):
    """A checkpoint records the law's reading (rotation and options such as
    baxter's lever arm); resuming in another reading is refused, by name. A
    checkpoint that recorded no reading (a law given by name) still restores."""
    from jaxpile.laws import baxter

    sim, params = setting
    state = fresh(sim, params)
    path = tmp_path / "ck.npz"
    checkpoint.save(path, state, hooke.law(rotation=True), params)
    assert checkpoint.read_metadata(path)["law_reading"] == {"rotation": True}
    with pytest.raises(InputError, match="another reading .*rotation True there, False here"):
        checkpoint.restore(path, state, hooke.law(rotation=False), params)
    checkpoint.restore(path, state, hooke.law(rotation=True), params)
    checkpoint.restore(path, state, "hooke", params)
    bparams = baxter.make_params()
    checkpoint.save(path, state, baxter.law(), bparams)
    with pytest.raises(InputError, match="lever_arm 'contact-point' there, 'centre-distance' here"):
        checkpoint.restore(path, state, baxter.law(lever_arm="centre-distance"), bparams)
    checkpoint.save(path, state, "baxter", bparams)  # no reading recorded
    checkpoint.restore(path, state, baxter.law(lever_arm="centre-distance"), bparams)


def test_checkpoints_from_elsewhere_get_one_line_in_jaxpiles_words(setting, tmp_path):
    """Truncated, foreign, pickled, folder, newer or older format: an InputError
    whose message says what the file is, never numpy's own advice."""
    sim, params = setting
    state = fresh(sim, params)
    good = tmp_path / "good.npz"
    checkpoint.save(good, state, hooke.law(rotation=True), params)
    data = good.read_bytes()
    (tmp_path / "truncated.npz").write_bytes(data[: len(data) // 2])
    np.savez(tmp_path / "foreign.npz", x=np.arange(3))
    np.savez(tmp_path / "pickled.npz", metadata=np.array([{"format": 2}], dtype=object))
    np.savez(tmp_path / "list.npz", metadata=np.asarray(json.dumps([1, 2])))
    (tmp_path / "folder.npz").mkdir()
    cases = {"truncated.npz": "not a complete .npz", "foreign.npz": "without jaxpile's metadata",
             "pickled.npz": "holds Python objects", "list.npz": "metadata is not jaxpile's",
             "folder.npz": "it is a folder", "missing.npz": "no such file"}
    for name, words in cases.items():
        with pytest.raises(InputError, match=words) as err:
            checkpoint.restore(tmp_path / name, state, hooke.law(rotation=True), params)
        assert "allow_pickle" not in str(err.value) and "\n" not in str(err.value)
    newer = checkpoint.FORMAT + 1
    for version, words in ((newer, f"newer than this jaxpile's {checkpoint.FORMAT}: update jaxpile"),
                           (1, "older checkpoint format 1")):
        with np.load(good) as z:
            arrays = {k: z[k] for k in z.files}
        meta = json.loads(str(arrays["metadata"]))
        arrays["metadata"] = np.asarray(json.dumps({**meta, "format": version, "jaxpile_version": "9.9"}))
        np.savez(tmp_path / f"v{version}.npz", **arrays)
        with pytest.raises(InputError, match=words):
            checkpoint.restore(tmp_path / f"v{version}.npz", state, hooke.law(rotation=True), params)


WRITER = r"""
import sys
import jaxpile
jaxpile.configure()
from jaxpile.engine import checkpoint
from jaxpile.laws import hooke
sys.path.insert(0, sys.argv[2])
from test_checkpoint import falling_disks
from jaxpile.engine.simulate import Simulator
params = hooke.make_params(kn=1e4, gamma_n=20.0, mu=0.4)
sim = Simulator(hooke.law(rotation=True), 5e-4)
state = sim.init(params, *falling_disks(n=1500))
print("ready", flush=True)
while True:
    checkpoint.save(sys.argv[1], state, "hooke", params)
    state = state.set(step=state.step + 1)
"""


def test_a_kill_9_mid_write_leaves_the_last_complete_checkpoint(tmp_path):
    path = tmp_path / "ck.npz"
    proc = subprocess.Popen([sys.executable, "-c", WRITER, str(path), os.path.dirname(__file__)],
                            stdout=subprocess.PIPE, text=True)
    try:
        assert proc.stdout.readline().strip() == "ready"
        deadline = time.time() + 60
        while not path.exists() and time.time() < deadline:
            time.sleep(0.01)
        time.sleep(0.3)  # several writes in: the kill lands mid-write or between writes
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait()
    meta = checkpoint.read_metadata(path)  # complete and readable, never a torn file
    assert meta["n_particles"] == 1500 and meta["step"] >= 0
    with np.load(path) as data:
        assert data["leaf:.particles.position"].shape == (1500, 2)


def test_a_nan_mid_run_reports_step_and_particle_and_saves_the_last_good_state(tmp_path):
    from jaxpile.errors import SimulationError

    def poison(state):  # disk 5's velocity turns NaN at step 600
        v = state.particles.velocity
        return state.set(particles=state.particles.set(
            velocity=jnp.where(state.step == 600, v.at[5].set(jnp.nan), v)))

    params = hooke.make_params(kn=1e4, gamma_n=20.0, mu=0.4)
    sim = Simulator(hooke.law(rotation=True), 5e-4, chunk_steps=CHUNK, driver=poison)
    state = sim.init(params, *falling_disks())
    with pytest.raises(SimulationError, match="by step 750: first offending particle 5") as caught:
        sim.run(params, state, 2000, progress=False, checkpoint=(str(tmp_path / "ck.npz"), 1000))
    error = caught.value
    assert error.step == 750 and int(error.last_good_state.step) == 500
    assert error.saved_to == str(tmp_path / "ck.last-good.npz") and error.saved_to in str(error)
    meta = checkpoint.read_metadata(error.saved_to)
    assert meta["step"] == 500 and meta["extra"]["failed_at"] == 750
    good = checkpoint.restore(error.saved_to, sim.init(params, *falling_disks()), "hooke", params)
    assert np.isfinite(np.asarray(good.particles.velocity)).all()


def test_a_pour_resumed_mid_pour_ends_bit_identical(tmp_path):
    """The pour's two phases (pouring, settling) resume from the phase each save
    records: restored halfway through the pour, the run ends where the
    uninterrupted one did."""
    from jaxpile.protocols import pour, running

    sim = pour.make_simulator("hooke", chunk_steps=500)
    params = pour.law_params("hooke")
    o = pour.PourOptions(n=12, release_height=14.0, max_settle_steps=3000)
    protocol = pour.setup(o, law="hooke", seed=5, dt=sim.dt)
    steps = protocol.info["pour_steps"]
    every = 500 * max(1, steps // 1000)  # a checkpoint about halfway through the pour
    path = str(tmp_path / "pour-{step}.npz")
    whole, info, _ = running.run_setup(pour.SPEC, sim, params, protocol, o, checkpoint=(path, every))
    resumed, rest, _ = running.run_setup(pour.SPEC, sim, params, protocol, o, resume=path.format(step=every))
    assert int(resumed.step) == int(whole.step) and rest.steps == info.steps - every
    mid = checkpoint.restore(path.format(step=every), sim.init(params, protocol.particles, protocol.boundaries,
                                                               box=protocol.box, protocol_state=protocol.protocol_state),
                             "hooke", params)
    assert 0 < int(mid.protocol_state.poured) < 12  # the insertion counter is part of what is saved
    assert_identical(resumed, whole)


CLI = "import sys; from jaxpile.cli import main; sys.exit(main(sys.argv[1:]))"
LATTICE_RUN = ["pile", "--protocol", "lattice", "--layers", "6", "--ramp-steps", "1000", "--max-steps", "40000",
               "--speed-tol", "1e-12", "--checkpoint-every", "1000", "--trajectory-every", "1500", "--no-progress"]


def test_cli_run_killed_with_sigkill_and_resumed_ends_as_the_uninterrupted_run(tmp_path):
    from jaxpile import io
    from jaxpile.cli import main

    whole, cut = tmp_path / "whole", tmp_path / "cut"
    assert main(LATTICE_RUN + ["--out", str(whole)]) == 0

    proc = subprocess.Popen([sys.executable, "-c", CLI, *LATTICE_RUN, "--out", str(cut)],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        deadline, step = time.time() + 120, 0
        while step < 3000 and proc.poll() is None and time.time() < deadline:
            time.sleep(0.02)
            if (cut / "checkpoint.npz").exists():
                step = checkpoint.read_metadata(cut / "checkpoint.npz")["step"]
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait()
    assert step >= 3000 and proc.returncode == -signal.SIGKILL, "the run was not caught mid-way"
    assert not (cut / "summary.json").exists()

    assert main(["pile", "--resume", str(cut), "--no-progress"]) == 0
    a, b = io.load_arrays(whole / "state.npz"), io.load_arrays(cut / "state.npz")
    for key in a:
        if key != "metadata":
            np.testing.assert_array_equal(a[key], b[key], err_msg=key)
    assert (whole / "base_forces.csv").read_text() == (cut / "base_forces.csv").read_text()
    # the frames written after the checkpoint, before the kill, were dropped and written again
    assert (whole / "trajectory.xyz").read_text() == (cut / "trajectory.xyz").read_text()
    done, resumed = (json.loads((d / "summary.json").read_text()) for d in (whole, cut))
    assert resumed["steps"] == done["steps"] and resumed["resumed_from_step"] >= 3000


def test_cli_resume_errors_are_clear(tmp_path, capsys):
    from jaxpile.cli import main

    assert main(["pile", "--resume", str(tmp_path)]) == 2
    assert "no checkpoint to resume" in capsys.readouterr().err
    assert main(["pile", "--resume", str(tmp_path), "--layers", "4"]) == 2
    assert "--resume DIR` alone" in capsys.readouterr().err
    assert main(["pile", "--protocol", "box", "--n", "20", "--checkpoint-every", "0", "--out", str(tmp_path)]) == 2
    assert "--checkpoint-every must be >= 1" in capsys.readouterr().err


def test_a_new_cli_run_replaces_an_earlier_runs_checkpoints_in_its_folder(tmp_path, capsys):
    """A tilt stopped in its box stage is resumed from checkpoint.box.npz only if no
    checkpoint.npz is there: a new run must not leave an older run's files to be
    taken for its own."""
    from jaxpile.cli import main

    for name in ("checkpoint.npz", "checkpoint.box.npz"):
        (tmp_path / name).write_bytes(b"an earlier run")
    assert main(["pile", "--protocol", "lattice", "--layers", "3", "--ramp-steps", "500", "--max-steps", "1000",
                 "--checkpoint-every", "500", "--no-progress", "--out", str(tmp_path)]) == 0
    assert "removing" in capsys.readouterr().out
    assert not (tmp_path / "checkpoint.box.npz").exists()
    assert checkpoint.read_metadata(tmp_path / "checkpoint.npz")["extra"]["argv"][:3] == ["pile", "--protocol",
                                                                                        "lattice"]



def test_a_failing_cli_command_leaves_an_earlier_run_in_its_folder(tmp_path, capsys):
    """A command that fails while setting up (a disk count that cannot be) must
    not remove the earlier run's checkpoints: they go only once the new run steps."""
    from jaxpile.cli import main

    for name in ("checkpoint.npz", "checkpoint.box.npz", "summary.json"):
        (tmp_path / name).write_bytes(b"an earlier run")
    assert main(["pile", "--protocol", "pour", "--n", "-5", "--checkpoint-every", "500", "--no-progress",
                 "--out", str(tmp_path)]) == 2
    assert "error" in capsys.readouterr().err
    for name in ("checkpoint.npz", "checkpoint.box.npz", "summary.json"):
        assert (tmp_path / name).read_bytes() == b"an earlier run"


def test_output_paths_that_cannot_be_folders_are_refused_at_once(tmp_path, capsys):
    from jaxpile.cli import main

    a_file = tmp_path / "a_file"
    a_file.write_text("x")
    run = ["pile", "--protocol", "lattice", "--layers", "3", "--no-progress", "--out"]
    for out, words in ((a_file, "is a file, not a folder"), (a_file / "inner" / "deeper", "lies inside")):
        assert main([*run, str(out)]) == 2
        err = capsys.readouterr().err
        assert words in err and err.count("\n") == 1 and "Traceback" not in err
    assert main(["fit", "--target", str(tmp_path), "--protocol", "lattice", "--law", "hooke", "--params", "mu",
                 "--out", str(tmp_path / "fit")]) == 2
    assert "is a folder" in capsys.readouterr().err


def test_dry_run_prints_the_set_up_the_estimate_and_the_steps_and_runs_nothing(tmp_path, capsys):
    from jaxpile.cli import main

    out = tmp_path / "never"
    assert main(["pile", "--protocol", "pour", "--n", "50", "--dry-run", "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "dry run of a pour pile" in text and "memory: about" in text and "pour_steps 80,600" in text
    assert not out.exists()  # nothing written, not even the folder
    assert main(["pile", "--protocol", "lattice", "--layers", "30000", "--dry-run", "--out", str(out)]) == 2
    assert "would fit" in capsys.readouterr().err
    assert main(["pile", "--protocol", "cone", "--n", "40", "--dry-run", "--out", str(out)]) == 0
    first = capsys.readouterr().out.splitlines()[0]
    assert "dry run of a cone pile" in first and " spheres (" in first and "disks" not in first


def test_fit_dry_run_reports_the_pile_the_start_and_the_differentiated_steps(tmp_path, capsys):
    from jaxpile.cli import main

    out = tmp_path / "never"
    assert main(["fit", "--target", "smid-novosad", "--protocol", "lattice", "--params", "mu,kt", "--set", "mu=0.3",
                 "--layers", "5", "--steps", "7", "--dry-run", "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "mu = 0.3" in text and "5-layer lattice pile: 15 disks" in text and "memory: about" in text
    assert "7 x 1,200 steps = 1.26e+05 particle-steps" in text  # 2 x max(600, 100 x 5) steps, 15 disks
    assert not out.exists()
    # as the fit itself would refuse it: a start above the stability limit of the lattice's dt
    assert main(["fit", "--target", "smid-novosad", "--protocol", "lattice", "--params", "kt", "--set", "kn=1e12",
                 "--dry-run", "--out", str(out)]) == 2
    assert "above the stability limit" in capsys.readouterr().err and not out.exists()


def test_sweep_dry_run_reports_the_batch_and_runs_nothing(tmp_path, capsys):
    from jaxpile.cli import main

    out = tmp_path / "never"
    assert main(["sweep", "--protocol", "box", "--mu", "0.2,0.4", "--seeds", "3", "--n", "40", "--dry-run",
                 "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "6 members" in text and "dry run of one box member: 40 disks" in text and "a batch of 6 members" in text
    assert not out.exists()


def test_ctrl_c_saves_where_the_run_stood_and_the_resume_ends_as_the_uninterrupted_run(tmp_path, monkeypatch,
                                                                                     capsys):
    """KeyboardInterrupt in the chunk loop (Ctrl-C) saves the last chunk's end to the run's checkpoint, even
    long before its next periodic save, and the run resumed from it ends bit for bit as the whole one."""
    from jaxpile import io
    from jaxpile.cli import main
    from jaxpile.engine import loop

    run = ["pile", "--protocol", "lattice", "--layers", "4", "--ramp-steps", "1000", "--max-steps", "6000",
           "--speed-tol", "1e-12", "--checkpoint-every", "1000000", "--no-progress"]
    whole, cut = tmp_path / "whole", tmp_path / "cut"
    assert main(run + ["--out", str(whole)]) == 0
    chunk, calls = loop.chunk, []

    def interrupted(*args, **kwargs):
        calls.append(1)
        if len(calls) == 4:
            raise KeyboardInterrupt
        return chunk(*args, **kwargs)

    monkeypatch.setattr(loop, "chunk", interrupted)
    assert main(run + ["--out", str(cut)]) == 130
    assert "continues from its last checkpoint" in capsys.readouterr().err
    saved = checkpoint.read_metadata(cut / "checkpoint.npz")["step"]
    assert 0 < saved < 6000 and not (cut / "summary.json").exists()
    monkeypatch.setattr(loop, "chunk", chunk)
    assert main(["pile", "--resume", str(cut), "--no-progress"]) == 0
    a, b = io.load_arrays(whole / "state.npz"), io.load_arrays(cut / "state.npz")
    for key in a:
        if key != "metadata":
            np.testing.assert_array_equal(a[key], b[key], err_msg=key)
    assert json.loads((cut / "summary.json").read_text())["resumed_from_step"] == saved
