"""A sweep across processes (jaxpile.distributed): two CPU processes on this
host, joined by jax.distributed, each running its share of the batches."""

import csv
import json
import os
import pathlib
import socket
import subprocess
import sys

import pytest

from jaxpile import distributed
from jaxpile.errors import InputError

SWEEP = ["sweep", "--protocol", "box", "--law", "lee-herrmann", "--n", "40", "--width", "1.2", "--height", "1.2",
         "--mu", "0.1,0.3", "--seeds", "2", "--no-progress"]
COMMAND = "import sys; from jaxpile.cli import main; sys.exit(main(sys.argv[1:]))"


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("localhost", 0))
        return s.getsockname()[1]


def _jaxpile(args, **env):
    return subprocess.Popen([sys.executable, "-c", COMMAND, *args], env={**os.environ, **env},
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def _rows(folder):
    with open(folder / "sweep.csv") as fh:
        return [{k: v for k, v in row.items() if k != "wall_seconds"} for row in csv.DictReader(fh)]


def test_a_sweep_on_two_processes_gives_the_rows_one_process_gives_for_the_same_batches(tmp_path):
    """`jaxpile sweep --distributed` on 2 processes (the coordinator's address, the count and each one's id
    from the environment): each runs one batch of 2 members, process 0 writes every row, in member order;
    `jaxpile sweep --batch-size 2` on one process gives the same rows to the last digit (a member's numbers
    depend on its batch only, and the CSV holds each number's exact repr)."""
    port = _free_port()
    env = {distributed.COORDINATOR_ENV: f"localhost:{port}", distributed.PROCESSES_ENV: "2"}
    procs = [_jaxpile([*SWEEP, "--distributed", "--out", str(tmp_path / f"p{k}")],
                      **env, **{distributed.PROCESS_ID_ENV: str(k)}) for k in (0, 1)]
    outs = [p.communicate(timeout=600) for p in procs]
    for p, (out, err) in zip(procs, outs):
        assert p.returncode == 0, err[-3000:]
    assert "process 0 of 2" in outs[0][0] and "process 1 of 2" in outs[1][0]
    assert not (tmp_path / "p1").exists(), "only process 0 writes"
    one = _jaxpile([*SWEEP, "--batch-size", "2", "--out", str(tmp_path / "one")])
    out, err = one.communicate(timeout=600)
    assert one.returncode == 0, err[-3000:]
    both, alone = _rows(tmp_path / "p0"), _rows(tmp_path / "one")
    assert [int(r["member"]) for r in both] == [0, 1, 2, 3]
    assert both == alone
    record = json.loads((tmp_path / "p0" / "sweep.json").read_text())
    assert record["processes"] == 2 and record["batch_size"] == 2 and record["members"] == 4


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


def test_a_distributed_sweep_refuses_checkpoints_before_it_joins(tmp_path):
    done = subprocess.run([sys.executable, "-c", COMMAND, *SWEEP, "--distributed", "--checkpoint-every", "100",
                           "--out", str(tmp_path / "x")], capture_output=True, text=True, timeout=120)
    assert done.returncode == 2
    assert done.stderr.strip().splitlines()[-1].startswith("jaxpile: error: --checkpoint-every and --resume")


def test_the_docs_page_runs_the_commands_this_test_runs():
    text = (pathlib.Path(__file__).resolve().parents[1] / "docs" / "distributed.md").read_text()
    assert f'SWEEP="{" ".join(SWEEP)}"' in text
    assert "jaxpile $SWEEP --distributed --out p0" in text and "jaxpile $SWEEP --batch-size 2 --out one" in text
