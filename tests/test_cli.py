"""The `jaxpile pile` command writes everything it promises, at a small size."""

import json
import os
import signal
import socket
import subprocess

import numpy as np

from jaxpile.cli import main, run_folder
from jaxpile.io import load_arrays, read_csv


def test_pile_command_writes_summary_csv_state_and_figures(tmp_path, capsys):
    out = tmp_path / "run"
    rc = main(["pile", "--protocol", "lattice", "--layers", "5", "--law", "hooke", "--ramp-steps", "2000",
               "--max-steps", "60000", "--no-progress", "--set", "gamma_n=120", "--out", str(out)])
    assert rc == 0
    summary = json.loads((out / "summary.json").read_text())
    for key in ("n_particles", "steps", "wall_seconds", "compile_seconds", "particle_steps_per_second",
                "final_max_speed", "max_rel_dev_normal", "max_rel_dev_horizontal"):
        assert key in summary
    assert summary["n_particles"] == 15
    assert summary["params"]["gamma_n"] == 120.0 and summary["params"]["mu"] == 0.0
    assert summary["at_rest"] and summary["max_rel_dev_normal"] < 0.01
    table = read_csv(out / "base_forces.csv")
    assert set(table) == {"x", "normal", "horizontal"} and len(table["x"]) == 5
    np.testing.assert_allclose(table["normal"].sum(), 15.0, rtol=1e-4)
    state = load_arrays(out / "state.npz")
    assert state["particles.position"].shape == (15, 2)
    for name in ("pile.png", "profile.png"):
        assert (out / name).stat().st_size > 10_000
    assert main(["compare", str(out)]) == 0
    assert "dev N" in capsys.readouterr().out


def _lock_of(process, folder, command="jaxpile pile --protocol pour --out x"):
    """A lock in `folder` as a run in `process` (a child of the test) would have written it."""
    folder.mkdir(parents=True, exist_ok=True)
    record = {"pid": process.pid, "host": socket.gethostname(), "since": "2026-01-01 00:00:00", "command": command,
              "process_start": run_folder._process_start(process.pid)}
    (folder / run_folder.LOCK_NAME).write_text(json.dumps(record))
    return record


def test_a_folder_a_live_run_writes_is_refused_in_one_line_naming_that_run(tmp_path, capsys):
    """Two runs into one --out at once: the second is refused (pile, sweep, fit),
    naming the first's command and process, and the first's lock is left as it was."""
    live = subprocess.Popen(["sleep", "120"])
    try:
        out = tmp_path / "busy"
        record = _lock_of(live, out)
        for argv in (["pile", "--layers", "3"], ["sweep", "--protocol", "box", "--mu", "0.2", "--seeds", "1"],
                     ["fit", "--protocol", "box", "--params", "mu", "--truth", "mu=0.3", "--ensemble", "2"]):
            assert main([*argv, "--no-progress", "--out", str(out)]) == 2, argv
            err = capsys.readouterr().err
            assert len(err.strip().splitlines()) == 1, err
            assert f"in use by a running `{record['command']}` (process {live.pid}" in err, err
        assert json.loads((out / run_folder.LOCK_NAME).read_text()) == record
        assert sorted(p.name for p in out.iterdir()) == [run_folder.LOCK_NAME]  # nothing else written there
    finally:
        live.kill()
        live.wait()


def test_pile_command_with_gear_and_hard_collisions(tmp_path, capsys):
    """The 1992 law with the 1993 integrator and the 1992 hard-collision switch,
    from the CLI, into a folder a run killed with SIGKILL left locked: the lock
    is taken over with a note, held while the pile runs, and gone at the end."""
    out = tmp_path / "gear"
    killed = subprocess.Popen(["sleep", "120"])
    _lock_of(killed, out)
    os.kill(killed.pid, signal.SIGKILL)  # not reaped yet: a zombie, which is no live run either
    rc = main(["pile", "--layers", "3", "--law", "liffman", "--integrator", "gear", "--hard-collisions", "0.5,0.3",
               "--dt", "5e-4", "--ramp-steps", "4000", "--max-steps", "60000", "--no-progress", "--out", str(out)])
    killed.wait()
    assert rc == 0
    assert f"left locked by a run that did not end (process {killed.pid}" in capsys.readouterr().out
    assert not (out / run_folder.LOCK_NAME).exists()
    summary = json.loads((out / "summary.json").read_text())
    assert summary["integrator"] == "gear" and summary["hard_collisions"] == {"restitution": 0.5, "mu": 0.3}
    assert summary["at_rest"] and summary["max_rel_dev_normal"] < 0.01
    assert load_arrays(out / "state.npz")["integrator_state.position"].shape == (3, 6, 2)


def test_compile_cache_folder_follows_the_environment_and_can_be_turned_off(tmp_path):
    """`jaxpile.cli.compile_cache_dir`: JAXPILE_COMPILE_CACHE first (off turns
    the cache off), then JAX's own folder, then XDG_CACHE_HOME/jaxpile/xla."""
    import os

    from jaxpile.cli import compile_cache_dir

    assert compile_cache_dir({"JAXPILE_COMPILE_CACHE": "off"}, "/jax/dir") is None
    assert compile_cache_dir({"JAXPILE_COMPILE_CACHE": "0"}) is None
    assert compile_cache_dir({"JAXPILE_COMPILE_CACHE": str(tmp_path)}, "/jax/dir") == str(tmp_path)
    assert compile_cache_dir({"XDG_CACHE_HOME": "/x"}, "/jax/dir") == "/jax/dir"
    assert compile_cache_dir({"XDG_CACHE_HOME": "/x"}) == os.path.join("/x", "jaxpile", "xla")
    assert compile_cache_dir({}).endswith(os.path.join(".cache", "jaxpile", "xla"))


def test_a_sweep_names_the_law_s_n_apart_from_the_disk_count(tmp_path, capsys):
    """The pour's disk count (`--n`) and the baxter law's exponent n share a
    name: a bare `--vary n=` is refused with the spelling to use, and
    `--vary law.n=` sweeps the law's (a dry run, nothing built)."""
    common = ["sweep", "--protocol", "pour", "--n", "30", "--seeds", "1", "--dry-run", "--out", str(tmp_path / "s")]
    assert main([*common, "--vary", "n=36,144"]) == 2
    assert "--vary law.n=" in capsys.readouterr().err
    assert main([*common, "--vary", "law.n=36,144"]) == 0
    assert "n in [36.0, 144.0]" in capsys.readouterr().out
    assert main([*common, "--vary", "law.width=1,2"]) == 2
    assert "not a parameter of the law" in capsys.readouterr().err


def test_ctrl_c_leaves_one_line_saying_what_resumes_the_run(tmp_path, capsys, monkeypatch):
    """An interrupted command (KeyboardInterrupt mid-run) exits 130 with one line, no traceback, and
    says whether a checkpoint can resume it; the folder's lock is released."""
    import jaxpile.cli as cli

    def interrupted(args):
        raise KeyboardInterrupt

    monkeypatch.setattr(cli, "run_protocol", interrupted)
    out = tmp_path / "stopped"
    assert main(["pile", "--layers", "3", "--no-progress", "--out", str(out)]) == 130
    err = capsys.readouterr().err
    assert err.strip() == "jaxpile: interrupted; nothing was saved to resume (--checkpoint-every STEPS saves a run " \
                          "as it goes)", err
    assert not (out / run_folder.LOCK_NAME).exists()
