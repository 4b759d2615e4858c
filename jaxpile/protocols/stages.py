"""The one stage runner: a protocol's phases on one pile or on a batch of piles.

A protocol declares its run as phases (`ProtocolSpec.phases`): each takes at
most `steps` steps and ends early at the first chunk's end where its `until`
holds (the pour: every disk poured, then a run to rest; the box: one phase to
its driver's rest). `run_phases` runs them on a `Simulator` and one pile or an
`Ensemble` and a batch, with the same rule: each member starts a phase where
it ended the last, its `until` is checked after each chunk (and at the phase's
start only when resuming a save, where it was checked when saved), and a batch
freezes a finished member until the others are done. A single pile and a
member of a batch therefore stop at the same steps. Every save records where
the run stands (`Position`), so a resume continues the same phase, bit for bit.
"""

from __future__ import annotations

from typing import Callable, NamedTuple

import numpy as np

from jaxpile.engine.checkpoint import Checkpoint
from jaxpile.errors import InputError


class Phase(NamedTuple):
    """One phase of a protocol's run.

    Attributes:
      name: what it is ("pour", "settle"), for the run's record.
      steps: its most steps, counted from its start.
      until: a traceable `state -> bool` that ends it at a chunk's end, or
        None: it runs all its steps (a loading phase of fixed length).
    """

    name: str
    steps: int
    until: Callable | None = None


def one_phase(finished: Callable, budget: Callable, name: str = "run") -> Callable:
    """The `phases` of a protocol that runs until `finished(setup, options)`
    holds, within `budget(setup, options)` steps."""

    def phases(p, o) -> tuple[Phase, ...]:
        return (Phase(name, int(budget(p, o)), finished(p, o)),)

    return phases


def budget(phases) -> int:
    """The most steps the phases take in all."""
    return sum(int(phase.steps) for phase in phases)


class Position(NamedTuple):
    """Where a run of phases stands at a save (recorded with it).

    Attributes:
      phase: the name of the phase it is in.
      phase_starts: each member's step when that phase began.
      stage_starts: each member's step when the stage (its first phase) began.
      stage_steps: the batch steps of the stage's earlier phases (a cap on the
        stage's steps, `max_steps`, counts them).
      ended: each earlier phase's end, by name: each member's step.
    """

    phase: str
    phase_starts: list
    stage_starts: list
    stage_steps: int
    ended: dict

    def facts(self) -> dict:
        return {"phase": self.phase, "phase_starts": list(self.phase_starts), "stage_starts": list(self.stage_starts),
                "stage_steps": self.stage_steps, "phases_ended": dict(self.ended)}

    @classmethod
    def saved(cls, extra: dict, what: str) -> "Position":
        """The position recorded in a save's facts (`extra`)."""
        if not isinstance(extra.get("phase"), str) or "phase_starts" not in extra:
            raise InputError(f"{what} records no phase of its run (it was written by another version of "
                             "jaxpile): run it again from the start.")
        return cls(extra["phase"], [int(x) for x in extra["phase_starts"]], [int(x) for x in extra["stage_starts"]],
                   int(extra.get("stage_steps", 0)),
                   {k: [int(x) for x in v] for k, v in extra.get("phases_ended", {}).items()})


def member_steps(state, count: int | None) -> list[int]:
    """Each member's step: `[step]` of one pile (`count` None), else the first `count` members'."""
    if count is None:
        return [int(state.step)]
    return [int(x) for x in np.asarray(state.step)[:count]]


def run_phases(stepper, params, state, phases, *, count: int | None = None, max_steps: int | None = None,
               position: Position | None = None, progress=None, info=None, checkpoint=None,
               observe: Callable | None = None):
    """Runs `state` through `phases` (one stage of a protocol).

    Args:
      stepper: a `Simulator` (one pile, `count` None) or an `Ensemble` (a batch
        of `count` real members; padding members follow the last).
      params: the law's parameters (an `Ensemble.run`'s for a batch).
      phases: the stage's `Phase`s, in order.
      max_steps: at most this many batch steps in the stage (a sweep's cap), or None.
      position: where the restored `state` stands (a save's `Position.saved`),
        or None for the stage's start.
      info: a `RunInfo` that accumulates every phase's steps and timings.
      checkpoint: a `Checkpoint` (or tuple); each save records its `Position`.
      observe: one pile only: called on the stage's first state (not on a
        resumed one) and after each chunk (a run's samples).

    Returns:
      `(state, ends)`: `ends[phase name]` is each member's step at that phase's end.
    """
    checkpoint = Checkpoint.of(checkpoint)
    one = count is None
    if observe is not None and not one:
        raise InputError("observe is for one pile's run.")
    now = member_steps(state, count)
    names = [phase.name for phase in phases]
    if len(set(names)) != len(names):
        raise InputError(f"a stage's phases need names of their own; got {names}.")
    resuming = position is not None
    if position is None:
        position = Position(names[0], now, now, 0, {})
        if observe is not None:
            observe(state)
    elif position.phase not in names:
        raise InputError(f"the save is in a phase {position.phase!r} this run does not have ({', '.join(names)}).")
    at = names.index(position.phase)
    ends, done = dict(position.ended), 0
    for k, phase in enumerate(phases):
        if k < at:
            continue
        resumed = resuming and k == at
        if k > at:
            position = Position(phase.name, now, position.stage_starts, position.stage_steps + done, dict(ends))
        done = max(n - s for n, s in zip(now, position.phase_starts))
        left = int(phase.steps) - done
        if max_steps is not None:
            left = min(left, int(max_steps) - position.stage_steps - done)
        saves = None if checkpoint is None else checkpoint.with_facts(**position.facts())
        if left > 0 and not one:  # an Ensemble: `until` is vmapped over its members
            state = stepper.run(params, state, left, until=phase.until, progress=progress, info=info,
                                checkpoint=saves, resumed=resumed)
        elif left > 0 and not (resumed and phase.until is not None and bool(phase.until(state))):  # one pile
            state = stepper.run(params, state, left, progress=progress, info=info, checkpoint=saves,
                                until=_host_stop(phase.until, observe))
        now = member_steps(state, count)
        done = max(n - s for n, s in zip(now, position.phase_starts))
        ends[phase.name] = now
    return state, ends


def _host_stop(until, observe):
    """One pile's `Simulator.run(until=...)`: `observe` the chunk's end, then `until` on it."""

    def stop(s) -> bool:
        if observe is not None:
            observe(s)
        return until is not None and bool(until(s))

    return stop


__all__ = ["Phase", "Position", "budget", "member_steps", "one_phase", "run_phases"]
