"""A sweep across processes and hosts, on JAX's own multi-controller runtime.

Every process runs the same command (or script). `initialize()` joins them
(`jax.distributed.initialize`); a sweep then plans its members and batches as
one process would, each process runs a contiguous share of the *batches* on
its own devices, and the finished rows are gathered once, at the end, to every
process (process 0 writes the outputs).

Why batches and not one global mesh: the batch is advanced with a decision
shared by its members at every step (the neighbour-list rebuild,
`jaxpile.engine.ensemble`), which over a mesh spanning hosts would be a
collective across the network at every step. Whole batches need none, and a
member's numbers depend only on its own batch: N processes give bit for bit
the rows one process gives for the same batches (`jaxpile sweep --batch-size`
with the same batch size), whatever the process count.

    JAXPILE_COORDINATOR=host0:12355 JAXPILE_PROCESSES=2 JAXPILE_PROCESS_ID=0 jaxpile sweep ... --distributed

Without those three variables `initialize()` leaves the coordinator, the
process count and the process's id to JAX's cluster detection (SLURM, Open
MPI). On a CPU the processes' collectives go over gloo. Each process saves
its own checkpoints (`folder_of`): a distributed sweep resumes on as many
processes, each from its own.
"""

from __future__ import annotations

import itertools
import math
import os
import pickle

import jax

from jaxpile.errors import InputError

COORDINATOR_ENV, PROCESSES_ENV, PROCESS_ID_ENV = "JAXPILE_COORDINATOR", "JAXPILE_PROCESSES", "JAXPILE_PROCESS_ID"
TIMEOUT_ENV = "JAXPILE_DISTRIBUTED_TIMEOUT"

HEARTBEAT_SECONDS = 90
"""How long the coordinator waits for a silent process before it ends the
others with an error, rather than let them wait for it for ever: long enough
for a process starved of CPU on a loaded host (30 s was missed on an
oversubscribed 2-core one), short beside any run worth several processes."""


def _from_environment() -> dict:
    values = {name: os.environ.get(name) for name in (COORDINATOR_ENV, PROCESSES_ENV, PROCESS_ID_ENV)}
    given = {k for k, v in values.items() if v}
    if not given:
        return {}
    if len(given) != 3:
        missing = sorted(set(values) - given)
        raise InputError(f"{', '.join(missing)} not set: a distributed run takes {COORDINATOR_ENV} (host:port of "
                         f"process 0), {PROCESSES_ENV} and {PROCESS_ID_ENV} together, or none of them (SLURM, Open MPI).")
    try:
        processes, process_id = int(values[PROCESSES_ENV]), int(values[PROCESS_ID_ENV])
    except ValueError:
        raise InputError(f"{PROCESSES_ENV} and {PROCESS_ID_ENV} must be whole numbers; got "
                         f"{values[PROCESSES_ENV]!r} and {values[PROCESS_ID_ENV]!r}.") from None
    if processes < 1 or not 0 <= process_id < processes:
        raise InputError(f"{PROCESS_ID_ENV} must be in 0 .. {PROCESSES_ENV} - 1; got {process_id} of {processes}.")
    return {"coordinator_address": values[COORDINATOR_ENV], "num_processes": processes, "process_id": process_id}


def initialize(timeout: int | None = None) -> tuple[int, int]:
    """Joins this process to the others of a distributed run, before anything
    uses JAX's backend. Reads `JAXPILE_COORDINATOR`, `JAXPILE_PROCESSES` and
    `JAXPILE_PROCESS_ID`, or, without them, lets JAX detect the cluster
    (SLURM, Open MPI). `timeout` (default `JAXPILE_DISTRIBUTED_TIMEOUT`, else
    300 s) bounds the wait for the others to join.

    Returns:
      `(process index, process count)`.
    """
    from jax._src import xla_bridge

    if jax.distributed.is_initialized():
        return jax.process_index(), jax.process_count()
    if xla_bridge.backends_are_initialized():
        raise InputError("a distributed run must join its processes before JAX computes anything: call "
                         "jaxpile.distributed.initialize() (or pass --distributed) first.")
    timeout = int(os.environ.get(TIMEOUT_ENV, 300)) if timeout is None else int(timeout)
    given = _from_environment()
    if given:  # said first: a process that waits in vain is ended by JAX's runtime, which prints its own error
        print(f"jaxpile: process {given['process_id']} of {given['num_processes']} joining at "
              f"{given['coordinator_address']} (waiting at most {timeout} s for the others)", flush=True)
    jax.config.update("jax_cpu_collectives_implementation", "gloo")  # CPU processes reach each other over gloo
    try:
        jax.distributed.initialize(**given, initialization_timeout=timeout,
                                   heartbeat_timeout_seconds=HEARTBEAT_SECONDS)
    except ValueError as error:  # nothing given and no cluster detected
        raise InputError(f"a distributed run needs {COORDINATOR_ENV}, {PROCESSES_ENV} and {PROCESS_ID_ENV} "
                         f"(or a SLURM or Open MPI job): {error}") from None
    return jax.process_index(), jax.process_count()


def local_coordinator() -> str:
    """`localhost:PORT` with a port free now: the coordinator of processes on
    this one host (a test, a benchmark)."""
    import socket

    with socket.socket() as s:
        s.bind(("localhost", 0))
        return f"localhost:{s.getsockname()[1]}"


def process_count() -> int:
    """The processes of this run (1 unless `initialize` joined others)."""
    return jax.process_count() if jax.distributed.is_initialized() else 1


def process_index() -> int:
    return jax.process_index() if jax.distributed.is_initialized() else 0


def share(batches: list, processes: int | None = None, index: int | None = None) -> list:
    """This process's batches: a contiguous share, the first processes taking
    one more when the count does not divide."""
    processes = process_count() if processes is None else processes
    index = process_index() if index is None else index
    size, extra = divmod(len(batches), processes)
    start = index * size + min(index, extra)
    return batches[start:start + size + (index < extra)]


def default_batch_size(members: int, processes: int | None = None) -> int:
    """The batch size of a sweep that names none: every member at once on one
    process, one batch a process on several."""
    return math.ceil(members / (process_count() if processes is None else processes))


def folder_of(out: str) -> str:
    """Where this process keeps what is its own in a run's folder (its
    checkpoints): `OUT/process-K-of-N`, or OUT itself on one process."""
    count = process_count()
    return out if count == 1 else os.path.join(out, f"process-{process_index()}-of-{count}")


GATHER_WAIT_MS = 7 * 24 * 3600 * 1000
"""How long a process waits for the others' rows: their shares may end hours
apart, and a process that dies ends the run through the heartbeat anyway."""

_gathers = itertools.count()  # every process gathers in the same order, so the n-th gathers meet


def gather(items: list) -> list:
    """Every process's `items` (picklable), concatenated in process order, on
    every process; `items` itself when the run is one process.

    Through the coordination service's key-value store, not a collective: a
    collective's first call waits only about 30 s for the processes to meet,
    and a process that ends its share early may wait for the others far
    longer (`GATHER_WAIT_MS`)."""
    if process_count() == 1:
        return list(items)
    from jax._src import distributed as runtime  # the client of `jax.distributed`; no public name for its store

    client = runtime.global_state.client
    key = f"jaxpile/gather/{next(_gathers)}"
    client.key_value_set_bytes(f"{key}/{process_index()}", pickle.dumps(list(items)))
    out = []
    for k in range(process_count()):
        out += pickle.loads(client.blocking_key_value_get_bytes(f"{key}/{k}", GATHER_WAIT_MS))
    return out


__all__ = ["GATHER_WAIT_MS", "HEARTBEAT_SECONDS", "default_batch_size", "folder_of", "gather", "local_coordinator", "initialize", "process_count", "process_index", "share"]
