"""The one host run loop: chunks of a compiled advance, with neighbour-list
overflow and re-allocation, NaN checks, blocks of leading disks, checkpoints
and progress. One pile (`Simulator.run`) and a batch of piles (`Ensemble.run`)
drive it with a different `Advance`: the loop never looks inside a step.

Between chunks the host checks what a compiled step cannot act on (jax-md's
habit: allocate outside jit, update inside, check overflow between chunks):
a list that overflowed is re-allocated and the chunk run again from its start,
so no contact is ever dropped, and a non-finite disk stops the run with the
last good state saved. Everything inside a chunk is the compiled step; a
chunk's arithmetic does not depend on where it is cut, so results are the
same bit for bit whatever the chunk length, checkpoints or resumes.
"""

from __future__ import annotations

import os
import sys
import time
from typing import Any, Callable, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxpile.engine import checkpoint
from jaxpile.engine import neighbors as nb
from jaxpile.engine.checkpoint import step_of
from jaxpile.engine.state import Particles, SimState
from jaxpile.errors import InputError, SimulationError

Array = Any

MAX_REALLOCATIONS = 20
"""Re-allocations one chunk may need before the run gives up (each grows the
list to what the chunk found, so a second is rare and twenty means a bug)."""


class Advance(NamedTuple):
    """What the loop drives: a compiled advance and the host steps around it.

    Attributes:
      compiled: `(params, state, frozen, info) -> fn`, the compiled advance for
        these shapes (`compiled_for`); `fn(params, state, frozen, n)` takes `n`
        steps (int32) of every member not `frozen` (None for one pile).
      reallocate: `(state, overflowed) -> state`: `state` (a chunk's start)
        with lists that have room for what the chunk ending in `overflowed` found.
      block: `(state, n, known) -> (size, room) | None`: the block of leading
        disks the next `n` steps can run on and its pair entries (`known`: the
        entries each block size has needed so far), or None for every disk.
      take: `(state, size, room) -> state`, the block of leading disks.
      put: `(state, block) -> state`, the block's end written back.
      check_finite: `(new, last_good) -> None`, raises `SimulationError` on a
        non-finite disk in a chunk's end `new`.
      name: what overflowed, for the message ("the neighbour list").
    """

    compiled: Callable
    reallocate: Callable
    block: Callable
    take: Callable
    put: Callable
    check_finite: Callable
    name: str = "the neighbour list"


def chunk(advance: Advance, params, state: SimState, frozen, n: int, info, known_pairs: dict) -> SimState:
    """`n` steps from `state`, on a block of its leading disks where
    `advance.block` allows (a pour pays for the disks poured so far); on
    overflow, the lists are re-allocated and the steps run again from `state`."""
    block = advance.block(state, n, known_pairs)
    start = state if block is None else advance.take(state, *block)
    for _ in range(MAX_REALLOCATIONS):
        fn = advance.compiled(params, start, frozen, info)
        t0 = time.perf_counter()
        new = fn(params, start, frozen, jnp.int32(n))
        jax.block_until_ready(new)
        info.wall_seconds += time.perf_counter() - t0
        if not bool(np.any(nb.overflowed(new))):
            break
        info.reallocations += 1
        start = advance.reallocate(start, new)
    else:
        raise SimulationError(f"{advance.name} kept overflowing after {MAX_REALLOCATIONS} re-allocations.", start)
    if block is None:
        return new
    known_pairs[block[0]] = max(block[1], int(new.contacts.pairs.shape[-2]))
    return advance.put(state, new)


def run_chunks(advance: Advance, params, state: SimState, n_steps: int, *, chunk_steps: int, info,
               status: Callable[[SimState], tuple[Any, bool]], start: tuple[Any, bool] = (None, False),
               save=None, progress: bool | None = None, observe: Callable[[SimState], None] | None = None,
               postfix: Callable[[Any], dict] | None = None, known_pairs: dict | None = None) -> SimState:
    """Runs `state` up to `n_steps` in chunks of `chunk_steps`.

    Args:
      advance: the compiled advance and its host steps.
      info: a `RunInfo` that accumulates steps, wall and compile time, re-allocations.
      status: `state -> (frozen, stop)` after each chunk: the members to hold
        still in the next chunk (None for one pile) and whether the run ends.
      start: `(frozen, stop)` before the first chunk (`stop`: run nothing).
      save: a `Checkpointer` (or None): called at each chunk's end, given
        the last good state when a chunk ends non-finite, and the last chunk's
        end when the run is interrupted (Ctrl-C).
      progress: a progress bar (default: when stderr is a terminal).
      observe: called on the start state and after each chunk.
      postfix: `frozen -> dict` shown on the progress bar after each chunk.
      known_pairs: the pair entries each block size has needed (kept by the
        caller across runs).
    """
    frozen, stop = start
    if stop:
        return state
    if observe is not None:
        observe(state)
    if progress is None:
        progress = sys.stderr.isatty()
    from tqdm.auto import tqdm

    known_pairs = {} if known_pairs is None else known_pairs
    bar = tqdm(total=int(n_steps), disable=not progress, unit="step", leave=False, dynamic_ncols=True)
    done = 0
    try:
        while done < n_steps:
            n = min(chunk_steps, int(n_steps) - done)
            new = chunk(advance, params, state, frozen, n, info, known_pairs)
            checked(lambda: advance.check_finite(new, state), state, new, save)
            state = new
            done += n
            info.steps += n
            bar.update(n)
            if observe is not None:
                observe(state)
            frozen, stop = status(state)
            if postfix is not None:
                bar.set_postfix(**postfix(frozen))
            if save is not None:
                save(state, done, final=stop or done >= n_steps)
            if stop:
                break
    except KeyboardInterrupt:
        if save is not None and done:  # the last chunk's end: a resume goes on from there
            save.interrupted(state)
        raise
    finally:
        bar.close()
    return state


def checked(check, state: SimState, new: SimState, save) -> None:
    """Runs `check()` on a chunk's end `new`; when it raises `SimulationError`
    and the run saves checkpoints, the last good `state` is saved beside them
    first (`<path stem>.last-good.npz`) and the message says where."""
    try:
        check()
    except SimulationError as error:
        if save is not None:
            error.saved_to = save.last_good(state, failed_at=step_of(new))
            error.args = (f"{error.args[0]} Saved to {error.saved_to}.",)
        raise


def compiled_for(cache: dict, jitted, args: tuple, info):
    """The compiled `jitted` for the shapes and structure of `args` (followed by
    an int32 step count), from `cache` or compiled now, with the compile time
    added to `info`: chunks of a run, and runs of the same shapes, share it."""
    leaves, treedef = jax.tree.flatten(args)
    key = (treedef, tuple((np.shape(x), getattr(x, "dtype", type(x))) for x in leaves))
    fn = cache.get(key)
    if fn is None:
        t0 = time.perf_counter()
        fn = jitted.lower(*args, jnp.int32(1)).compile()
        info.compile_seconds += time.perf_counter() - t0
        cache[key] = fn
    return fn


class Checkpointer:
    """Saves a run's state at chunk boundaries, every `every` steps of the
    absolute step count (so a resumed run saves where the uninterrupted one
    did), at the run's end, and the last good state when NaN/inf appears."""

    def __init__(self, path: str, every: int, extra: dict, law, params):
        self.path, self.every, self.extra, self.law, self.params = path, every, extra, law, params
        self.last = None  # multiple of `every` last saved

    def _save(self, target: str, state: SimState, **extra) -> str:
        checkpoint.save(target, state, self.law, self.params, **self.extra, **extra)
        return target

    def _path(self, state: SimState) -> str:
        return self.path.replace("{step}", str(step_of(state)))

    def __call__(self, state: SimState, done: int, final: bool) -> None:
        step = step_of(state)
        if self.last is None:
            self.last = (step - done) // self.every
        if final or step // self.every > self.last:
            self.last = step // self.every
            self._save(self._path(state), state)

    def interrupted(self, state: SimState) -> None:
        """Saves where an interrupted run stood (the last chunk's end), so that
        its resume loses none of the steps since the last periodic save."""
        self.last = step_of(state) // self.every
        self._save(self._path(state), state)

    def last_good(self, state: SimState, failed_at: int) -> str:
        """Saves the last finite state as `<path stem>.last-good.npz`; returns its path."""
        stem, suffix = os.path.splitext(self._path(state))
        return self._save(f"{stem}.last-good{suffix or '.npz'}", state, failed_at=failed_at)


@jax.jit
def non_finite_disks(p: Particles) -> Array:
    """`[n]` bool: disks with a non-finite position or velocity (one program, not op by op)."""
    spin = jnp.isfinite(p.angular_velocity)
    spin = spin.all(-1) if spin.ndim == p.position.ndim else spin  # a sphere's spin is a vector
    return ~(jnp.isfinite(p.position).all(-1) & jnp.isfinite(p.velocity).all(-1) & spin)


def non_finite_on_host(p: Particles) -> np.ndarray:
    """`non_finite_disks` as a numpy array; on a CPU computed by numpy on the
    arrays' zero-copy views (no program to compile per pile size), elsewhere
    by the compiled reduction (no copy of every position to the host)."""
    if jax.default_backend() != "cpu":
        return np.asarray(non_finite_disks(p))
    finite = np.isfinite(np.asarray(p.position)).all(-1) & np.isfinite(np.asarray(p.velocity)).all(-1)
    spin = np.isfinite(np.asarray(p.angular_velocity))
    return ~(finite & (spin.all(-1) if spin.ndim == np.ndim(p.position) else spin))


def check_finite(particles: Particles, *, step: int, last_good=None) -> None:
    """`InputError` (`last_good` None: the run's input) or `SimulationError` (a
    chunk's end, `last_good` its start) naming the first non-finite disk."""
    p = particles
    bad = non_finite_on_host(p)
    if bad.any():
        first = int(np.argmax(bad))
        if last_good is None:
            raise InputError(
                f"particle {first} has a non-finite position or velocity in the input "
                f"(position {np.asarray(p.position[first])}, velocity {np.asarray(p.velocity[first])})."
            )
        raise SimulationError(
            f"non-finite position or velocity by step {step}: first offending particle {first} "
            f"(position {np.asarray(p.position[first])}, velocity {np.asarray(p.velocity[first])}). "
            "The last good state is in this error's `last_good_state`.",
            last_good_state=last_good,
            step=step,
        )


__all__ = ["MAX_REALLOCATIONS", "Advance", "Checkpointer", "check_finite", "checked", "chunk", "compiled_for",
           "non_finite_disks", "non_finite_on_host", "run_chunks"]
