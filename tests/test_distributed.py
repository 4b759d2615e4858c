"""A sweep across processes (jaxpile.distributed): two CPU processes on this
host, joined by jax.distributed, each running its share of the batches."""

import csv
import json
import os
import pathlib
import shutil
import signal
import subprocess
import sys
import time

import pytest

from jaxpile import distributed
from jaxpile.errors import InputError

SWEEP = ["sweep", "--protocol", "box", "--law", "lee-herrmann", "--n", "20", "--width", "0.8", "--height", "0.8",
         "--mu", "0.1,0.3", "--seeds", "2", "--no-progress"]
COMMAND = "import sys; from jaxpile.cli import main; sys.exit(main(sys.argv[1:]))"


def _jaxpile(args, **env):
    return subprocess.Popen([sys.executable, "-c", COMMAND, *args], env={**os.environ, **env},
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def _rows(folder):
    with open(folder / "sweep.csv") as fh:
        return [{k: v for k, v in row.items() if k != "wall_seconds"} for row in csv.DictReader(fh)]


@pytest.fixture(scope="module")
def one_process(tmp_path_factory):
    """The sweep on one process in batches of 2: what the two processes run, one batch each."""
    out = tmp_path_factory.mktemp("one")
    one = _jaxpile([*SWEEP, "--batch-size", "2", "--out", str(out)])
    _, err = one.communicate(timeout=600)
    assert one.returncode == 0, err[-3000:]
    return _rows(out)


def _environment(process: int, coordinator: str) -> dict:
    return {distributed.COORDINATOR_ENV: coordinator, distributed.PROCESSES_ENV: "2",
            distributed.PROCESS_ID_ENV: str(process)}


def test_a_sweep_on_two_processes_gives_the_rows_one_process_gives_for_the_same_batches(tmp_path, one_process):
    """`jaxpile sweep --distributed` on 2 processes (the coordinator's address, the count and each one's id
    from the environment): each runs one batch of 2 members, process 0 writes every row, in member order;
    `jaxpile sweep --batch-size 2` on one process gives the same rows to the last digit (a member's numbers
    depend on its batch only, and the CSV holds each number's exact repr)."""
    coordinator = distributed.local_coordinator()
    procs = [_jaxpile([*SWEEP, "--distributed", "--out", str(tmp_path / f"p{k}")], **_environment(k, coordinator))
             for k in (0, 1)]
    outs = [p.communicate(timeout=600) for p in procs]
    for p, (out, err) in zip(procs, outs):
        assert p.returncode == 0, err[-3000:]
    assert "process 0 of 2" in outs[0][0] and "process 1 of 2" in outs[1][0]
    assert not (tmp_path / "p1").exists(), "only process 0 writes"
    both = _rows(tmp_path / "p0")
    assert [int(r["member"]) for r in both] == [0, 1, 2, 3]
    assert both == one_process
    record = json.loads((tmp_path / "p0" / "sweep.json").read_text())
    assert record["processes"] == 2 and record["batch_size"] == 2 and record["members"] == 4


@pytest.fixture(scope="module")
def killed(tmp_path_factory, one_process):
    """A distributed sweep that checkpoints every 1000 steps, each process into its own folder of the run's
    (OUT/process-K-of-2), killed once both have saved: process 1 first, mid-batch, then process 0 (the job
    lost). The tests resume copies of OUT. After the one-process sweep, as process 0 then finds most of its
    programs compiled and saves well before process 1 (which compiles its own) ends its batch."""
    out, coordinator = tmp_path_factory.mktemp("killed") / "run", distributed.local_coordinator()
    procs = [_jaxpile([*SWEEP, "--distributed", "--checkpoint-every", "1000", "--out", str(out)],
                      **_environment(k, coordinator)) for k in (0, 1)]
    saved = out / "process-1-of-2" / "checkpoint.npz"
    deadline = time.monotonic() + 600
    while not (saved.exists() and (out / "process-0-of-2" / "checkpoint.npz").exists()) \
            and procs[1].poll() is None and time.monotonic() < deadline:
        time.sleep(0.02)
    for p in (procs[1], procs[0]):
        p.send_signal(signal.SIGKILL)
        p.communicate(timeout=60)
    assert saved.exists() and (out / "process-0-of-2" / "checkpoint.npz").exists(), "a process saved nothing"
    return out


def test_a_distributed_sweep_killed_mid_run_resumes_on_two_processes_to_the_same_rows(tmp_path, one_process, killed):
    """Both processes checkpoint into their own folder of the run's (OUT/process-K-of-2); process 1 is
    killed mid-batch and then process 0 (the job lost), and `jaxpile sweep --resume OUT --distributed` on
    two processes ends with the rows of the uninterrupted run."""
    from jaxpile.engine import checkpoint

    out = tmp_path / "run"
    shutil.copytree(killed, out)
    saved = out / "process-1-of-2" / "checkpoint.npz"
    assert not (out / "sweep.csv").exists()
    last = max(int(r["steps"]) for r in one_process[2:])
    assert checkpoint.read_metadata(str(saved))["step"] < last, "process 1 was killed after its batch ended"

    coordinator = distributed.local_coordinator()
    procs = [_jaxpile(["sweep", "--resume", str(out), "--distributed", "--no-progress"], **_environment(k, coordinator))
             for k in (0, 1)]
    outs = [p.communicate(timeout=600) for p in procs]
    for p, (_, err) in zip(procs, outs):
        assert p.returncode == 0, err[-3000:]
    assert "resuming" in outs[1][0]
    assert _rows(out) == one_process


FIT = ["fit", "--protocol", "box", "--params", "mu", "--set", "mu=0.2", "--truth", "mu=0.35", "--ensemble", "2",
       "--difference-step", "0.5",  # mu = 0.12-0.33: the slope stands out of two boxes' spread on any CPU
       "--steps", "1", "--option", "width=1.2", "--option", "height=1.2", "--statistics", "repose_least_squares",
       "--batch-size", "2", "--no-progress"]


def test_an_ensemble_fit_on_two_processes_gives_the_values_of_one_process(tmp_path):
    """`jaxpile fit ... --distributed`: the target's piles and every iteration's ensembles shared over two
    processes in batches of two piles, each process taking the same Gauss-Newton step from the gathered
    statistics; process 0 writes fit.json, and it holds the history one process writes for the same
    batches, every number equal."""
    coordinator = distributed.local_coordinator()
    procs = [_jaxpile([*FIT, "--distributed", "--out", str(tmp_path / "both")], **_environment(k, coordinator))
             for k in (0, 1)]
    # one process after the two, not beside them: it loads what process 0 compiled from the compilation
    # cache instead of compiling it a third time at once on the suite's two cores
    for p in [*procs, _jaxpile([*FIT, "--out", str(tmp_path / "one")])]:
        _, err = p.communicate(timeout=600)
        assert p.returncode == 0, err[-3000:]
    both, one = (json.loads((tmp_path / name / "fit.json").read_text()) for name in ("both", "one"))
    untimed = [[{k: v for k, v in entry.items() if k != "seconds"} for entry in r["history"]] for r in (both, one)]
    assert both["values"] == one["values"] and untimed[0] == untimed[1] and len(untimed[0]) == 1
    assert both["values"]["mu"] > 0.2
    assert (tmp_path / "both" / "process-1-of-2" / "fit_checkpoint.json").exists()
    assert not (tmp_path / "both" / "process-1-of-2" / "fit.json").exists()


def test_a_process_whose_partner_never_joins_ends_after_the_timeout_instead_of_waiting():
    """Process 0 of 2 alone, with a join timeout of 5 s: it says what it waits for, and JAX's runtime ends
    it (an abort, with its own DEADLINE_EXCEEDED line) within the timeout and a margin: no hang."""
    start = time.monotonic()
    alone = _jaxpile([*SWEEP, "--distributed", "--out", "unused"], **_environment(0, distributed.local_coordinator()),
                     **{distributed.TIMEOUT_ENV: "5"})
    out, err = alone.communicate(timeout=120)
    assert alone.returncode != 0 and time.monotonic() - start < 90
    assert "process 0 of 2 joining at localhost:" in out and "waiting at most 5 s" in out
    assert "DEADLINE_EXCEEDED" in err or "Deadline Exceeded" in err


def test_a_refusal_on_one_process_is_raised_on_every_process_instead_of_a_wait(tmp_path, killed):
    """Process 1 resumes a checkpoint that is not its own (process 0's, copied over its folder): it refuses,
    and process 0, which runs its share, raises the same refusal, naming process 1, instead of waiting for
    rows that will not come."""
    out = tmp_path / "run"
    shutil.copytree(killed, out)
    (out / "process-1-of-2" / "checkpoint.npz").write_bytes((out / "process-0-of-2" / "checkpoint.npz").read_bytes())
    coordinator = distributed.local_coordinator()
    procs = [_jaxpile(["sweep", "--resume", str(out), "--distributed", "--no-progress"], **_environment(k, coordinator))
             for k in (0, 1)]
    errs = [p.communicate(timeout=300)[1] for p in procs]
    assert [p.returncode for p in procs] == [2, 2], errs
    assert "was saved by process 0 of 2, this is process 1 of 2" in errs[1].strip().splitlines()[-1]
    assert errs[0].strip().splitlines()[-1].startswith("jaxpile: error: process 1 of 2 failed: ")


def test_the_batches_are_shared_in_contiguous_runs_the_first_processes_taking_the_remainder():
    batches = [[k, k + 1] for k in range(7)]
    shares = [distributed.share(batches, 3, k) for k in range(3)]
    assert shares == [batches[0:3], batches[3:5], batches[5:7]]
    assert distributed.share(batches) == batches  # one process: all of them
    assert distributed.default_batch_size(7, 3) == 3 and distributed.default_batch_size(7) == 7
    assert distributed.gather([{"member": 1}]) == [{"member": 1}]


@pytest.mark.parametrize("given, message", [
    ({distributed.COORDINATOR_ENV: "localhost:1"}, "JAXPILE_PROCESSES, JAXPILE_PROCESS_ID not set"),
    ({distributed.COORDINATOR_ENV: "localhost:1", distributed.PROCESSES_ENV: "2", distributed.PROCESS_ID_ENV: "2"},
     "must be in 0 .. JAXPILE_PROCESSES - 1"),
    ({distributed.COORDINATOR_ENV: "localhost:1", distributed.PROCESSES_ENV: "two", distributed.PROCESS_ID_ENV: "0"},
     "whole numbers"),
])
def test_the_environment_of_a_distributed_run_is_checked_in_one_line(monkeypatch, given, message):
    for name in (distributed.COORDINATOR_ENV, distributed.PROCESSES_ENV, distributed.PROCESS_ID_ENV):
        monkeypatch.delenv(name, raising=False)
    for name, value in given.items():
        monkeypatch.setenv(name, value)
    with pytest.raises(InputError, match=message):
        distributed._from_environment()


def test_the_docs_page_runs_the_commands_this_test_runs():
    text = (pathlib.Path(__file__).resolve().parents[1] / "docs" / "distributed.md").read_text()
    assert f'SWEEP="{" ".join(SWEEP)}"' in text
    assert "jaxpile $SWEEP --distributed --out p0" in text and "jaxpile $SWEEP --batch-size 2 --out one" in text
    assert "jaxpile $SWEEP --distributed --checkpoint-every 1000 --out run" in text
    assert "jaxpile sweep --resume run --distributed" in text
