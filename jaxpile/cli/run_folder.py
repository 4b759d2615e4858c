"""A run's output folder: refused before anything runs when it cannot be one
or another live run writes it, and the checkpoints `pile` and `sweep` keep
there: what they record, resuming from them, and an earlier run's removed when
a new one starts."""

from __future__ import annotations

import contextlib
import json
import os
import socket
import time

from jaxpile import distributed
from jaxpile.engine import checkpoint
from jaxpile.errors import InputError


def check_out_folder(out: str, flag: str = "--out") -> None:
    """Refuses, before anything runs, an output folder that cannot be one: a
    path that is a file, lies inside a file, or is not writable. Creates and
    touches nothing: a refused command leaves no folder behind, and the run
    makes its folder when it first writes."""
    path = os.path.abspath(out)
    if os.path.exists(path) and not os.path.isdir(path):
        raise InputError(f"{flag} {out} is a file, not a folder; give a folder (it is created if missing).")
    parent = path
    while not os.path.exists(parent):
        parent = os.path.dirname(parent)
    if not os.path.isdir(parent):
        raise InputError(f"{flag} {out} lies inside {parent}, which is a file; give a folder.")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise InputError(f"{flag} {out}: {parent} is not writable; give a folder you can write to.")


def recorded_command(argv: list[str]) -> list[str]:
    """What a checkpoint records to resume from: the command without --resume DIR
    and --no-progress."""
    out, skip = [], False
    for a in argv:
        if skip or a == "--no-progress":
            skip = False
            continue
        if a == "--resume":
            skip = True
            continue
        out.append(a)
    return out


def resume_argv(argv: list[str]) -> list[str]:
    """`pile|sweep --resume DIR [--no-progress]` -> the saved run's own command line
    plus `--resume DIR`: a resumed run takes every setting from its checkpoint."""
    rest = [a for a in argv[1:] if a not in ("--no-progress", "--distributed")]
    if len(rest) != 2 or rest[0] != "--resume":
        raise InputError(f"resume a run with `jaxpile {argv[0]} --resume DIR` alone (its settings come from the "
                         f"checkpoint; --no-progress and --distributed may be added); got {' '.join(argv)!r}.")
    folder = rest[1]
    spread = "--distributed" in argv
    # a distributed run's processes each saved their own, all recording the same command
    path = next(iter(_process_checkpoints(folder)), None) if spread else checkpoint.in_folder(folder)
    if path is None and not spread and _process_checkpoints(folder):
        raise InputError(f"{folder} holds a distributed sweep's checkpoints: resume it with `jaxpile {argv[0]} "
                         f"--resume {folder} --distributed` on as many processes.")
    if path is None:
        raise InputError(f"no checkpoint to resume in {folder} (expected {os.path.join(folder, 'checkpoint.npz')}; "
                         "runs write it with --checkpoint-every STEPS).")
    saved = checkpoint.read_metadata(path)["extra"].get("argv")
    if not saved:
        raise InputError(f"{path} does not record the command that made it: it cannot be resumed from the CLI.")
    if saved[0] != argv[0]:
        raise InputError(f"{folder} holds a `jaxpile {saved[0]}` run: resume it with `jaxpile {saved[0]} --resume "
                         f"{folder}`.")
    if spread and "--distributed" not in saved:
        raise InputError(f"{path} is a one-process run's: resume it without --distributed.")
    return [*saved, "--resume", folder] + (["--no-progress"] if "--no-progress" in argv else [])


def _process_checkpoints(folder: str) -> list[str]:
    """The checkpoints a distributed run's processes saved in `folder` (`distributed.folder_of`)."""
    import glob

    return sorted(glob.glob(os.path.join(glob.escape(folder), "process-*-of-*", "checkpoint.npz")))


def resume_point(args) -> tuple[str | None, int]:
    """For --resume DIR: the checkpoint file to hand to the run (DIR/checkpoint.npz;
    a tilt finds its box stage beside it) and the step it resumes at, announced.
    `(None, 0)` for a new run."""
    if args.resume is None:
        return None, 0
    folder = distributed.folder_of(args.resume)  # a process of a distributed run resumes its own
    saved = checkpoint.in_folder(folder)
    if saved is None and folder != args.resume:
        count = distributed.process_count()
        if not any(path.endswith(f"-of-{count}{os.sep}checkpoint.npz") for path in _process_checkpoints(args.resume)):
            raise InputError(f"no checkpoint of a sweep on {count} processes in {args.resume}: resume a "
                             "distributed sweep on as many processes as it started on.")
        # this process had saved nothing (no batch of its own, or stopped before its first save): its share anew
        print(f"jaxpile: process {distributed.process_index()} has no checkpoint in {args.resume}: it runs its "
              "share from the start", flush=True)
        return None, 0
    if saved is None:
        raise InputError(f"no checkpoint to resume in {folder}.")
    meta = checkpoint.read_metadata(saved)
    rows = meta["extra"].get("rows")
    print(f"jaxpile: resuming {args.resume} at step {meta['step']}"
          + ("" if rows is None else f" ({len(rows)} members measured)"), flush=True)
    return os.path.join(folder, "checkpoint.npz"), int(meta["step"])


def checkpoint_spec(args):
    """The run's `Checkpoint` (OUT/checkpoint.npz, every --checkpoint-every steps, the argv with each save), or None. A new
    run notes the checkpoints of an earlier run in OUT (`args.stale_checkpoints`)
    for `replacing_earlier` to remove: they must not be taken for its own."""
    if args.checkpoint_every is None:
        return None
    if args.checkpoint_every < 1:
        raise InputError(f"--checkpoint-every must be >= 1 step; got {args.checkpoint_every}.")
    folder = distributed.folder_of(args.out)  # a process of a distributed run saves its own
    os.makedirs(folder, exist_ok=True)
    path = os.path.join(folder, "checkpoint.npz")
    if args.resume is None:
        args.stale_checkpoints = [stale for stale in [path, *checkpoint.stage_files(path)] if os.path.exists(stale)]
    return checkpoint.Checkpoint(path, args.checkpoint_every, {"argv": args.argv})


@contextlib.contextmanager
def replacing_earlier(args):
    """Removes an earlier run's checkpoints in OUT (found by `checkpoint_spec`)
    when this run starts stepping (its first observed state), not before it: a
    command that fails while setting up leaves the earlier run as it was. A
    batched run is not observed; its end removes them."""
    from jaxpile.engine.simulate import observing

    stale = list(getattr(args, "stale_checkpoints", []))

    def drop(*_):
        while stale:
            path = stale.pop(0)
            if os.path.exists(path):
                print(f"jaxpile: removing {path} of an earlier run in {args.out}", flush=True)
                os.remove(path)

    with observing(drop):
        yield
    drop()


LOCK_NAME = ".jaxpile.lock"
"""The file a running `pile`, `sweep` or `fit` holds in its folder: its process, host and command."""


def _stat(pid: int) -> list[str] | None:
    """The fields of /proc/PID/stat after the command's name (the state first), or None."""
    try:
        with open(f"/proc/{pid}/stat") as fh:
            return fh.read().rsplit(")", 1)[1].split()
    except (OSError, IndexError):
        return None


def _process_start(pid: int) -> str | None:
    """This boot's id and the process's start (clock ticks since boot), which
    tell a live process from a later one given the same id; None where /proc
    does not say."""
    fields = _stat(pid)
    try:
        with open("/proc/sys/kernel/random/boot_id") as fh:
            return f"{fh.read().strip()}:{fields[19]}"  # field 22 of stat, the 20th after the name
    except (OSError, IndexError, TypeError):
        return None


def _alive(holder: dict) -> bool:
    """Whether the run that wrote a lock is still running: on this host, its
    process exists, is not a zombie (killed, not yet reaped) and is the one
    that wrote it; on another host this process cannot tell, so it is taken to be."""
    if holder.get("host") != socket.gethostname():
        return True
    pid = holder.get("pid")
    if not isinstance(pid, int) or pid <= 0:
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # another user's process: alive
        pass
    fields = _stat(pid)
    if fields and fields[0] == "Z":
        return False
    started = holder.get("process_start")
    return started is None or _process_start(pid) in (None, started)


def _read_lock(path: str) -> dict:
    try:
        with open(path) as fh:
            holder = json.load(fh)
        return holder if isinstance(holder, dict) else {}
    except (OSError, ValueError):  # half-written by a run killed as it started, or not ours: stale
        return {}


def _take(path: str, out: str, record: dict) -> None:
    """Creates the lock at `path` (atomically), taking over one a dead run left."""
    for _ in range(3):
        try:
            fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644)
        except FileExistsError:
            holder = _read_lock(path)
            if _alive(holder):
                where = "" if holder.get("host") == socket.gethostname() else \
                    f" (on another host: if that run has ended, remove {path})"
                raise InputError(f"{out} is in use by a running `{holder.get('command', 'jaxpile')}` (process "
                                 f"{holder.get('pid')} on {holder.get('host')}, since {holder.get('since')}){where}; "
                                 "wait for it to end or give another --out.")
            print(f"jaxpile: {out} was left locked by a run that did not end (process {holder.get('pid')} on "
                  f"{holder.get('host')}, since {holder.get('since')}): taking it over", flush=True)
            with contextlib.suppress(FileNotFoundError):
                os.remove(path)
            continue
        with os.fdopen(fd, "w") as fh:
            json.dump(record, fh)
        return
    raise InputError(f"{out} is being taken by another run at this moment; give another --out.")


@contextlib.contextmanager
def in_use(out: str, argv: list[str]):
    """Holds OUT for this run (`LOCK_NAME` in it) while the block runs: a second
    run into a folder a live run holds is refused in one line naming it, and a
    lock left by a run that was killed is taken over with a note. A process of
    a distributed run holds its own folder (`distributed.folder_of`), the
    first process OUT as well. A folder this created and the run left empty
    (a refusal) is removed again."""
    folders = [distributed.folder_of(out)]
    if folders[0] != out and distributed.process_index() == 0:
        folders.insert(0, out)
    pid = os.getpid()
    record = {"pid": pid, "host": socket.gethostname(), "process_start": _process_start(pid),
              "since": time.strftime("%Y-%m-%d %H:%M:%S"), "command": " ".join(["jaxpile", *argv])}
    held, made = [], []
    try:
        for folder in folders:
            missing = []
            parent = os.path.abspath(folder)
            while not os.path.exists(parent):
                missing.append(parent)
                parent = os.path.dirname(parent)
            os.makedirs(folder, exist_ok=True)
            made.extend(missing)
            path = os.path.join(folder, LOCK_NAME)
            _take(path, out, record)
            held.append(path)
        yield
    finally:
        for path in held:
            if _read_lock(path).get("pid") == pid:
                with contextlib.suppress(FileNotFoundError):
                    os.remove(path)
        for folder in sorted(made, key=len, reverse=True):  # the deepest first
            with contextlib.suppress(OSError):  # not empty: the run wrote there
                os.rmdir(folder)
