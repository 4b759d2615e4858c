"""What a batch of piles needs from a protocol: `sweep` and the ensemble fit
run any protocol through its `Adapter` (`definition.adapter` builds one from
a protocol's `Definition`), and a protocol of several stages (the tilt after
the box) adds a `Stage` for each later one."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Callable


@dataclass(frozen=True)
class Stage:
    """A later stage of a protocol (the tilt after the box): it starts from
    each member's state at the end of the stage before it.

    Attributes:
      simulator: `(law, dt, sim_options, options) -> Simulator` for this stage.
      start: `(law, dt, options, state, protocol) -> (state, protocol)`, on the
        host, per member: the stage's start state (contact history kept) and
        its protocol. Structure only (it also builds a resume's template).
      finished: `(protocol info, options) -> (state -> bool)`, traceable.
      max_steps: `(protocol info, options) -> int`, this stage's budget.
      describe: optional `(state, protocol) -> dict` of plain numbers measured
        on the previous stage's end state (`protocol`: this stage's set-up on
        it), merged into the protocol's `info` (and
        saved with each checkpoint of this stage, for the measurement after a
        resume).
    """

    simulator: Callable
    start: Callable
    finished: Callable
    max_steps: Callable
    describe: Callable | None = None


@dataclass(frozen=True)
class Adapter:
    """What a sweep needs from a protocol.

    Attributes:
      setup: `(law, seed, dt, options) -> Setup` for one member.
      simulator: `(law, dt, options) -> Simulator` shared by the batch.
      finished: `(protocol info, options) -> (state -> bool)`, traceable, per member.
      max_steps: `(protocol info, options) -> int`, the step budget.
      measure: `(sim, params, state, protocol) -> dict` of plain numbers.
      law_and_params: the protocol module's `law_and_params`.
      default_dt: `(law) -> float`.
      angles: the angle columns to summarise and plot (the first is the headline).
      options: the set-up options a sweep accepts.
      theory: optional `(name, values) -> (label, degrees)` to overlay on angles.
      unit: of the `angles` columns, for the printed summary.
      default_law: the protocol paper's law.
      extent: optional `(protocol) -> (base, x_left, x_right)`: where the base
        profile of a member is read for fitting (`ensemble_fit`); the same
        for every member of a protocol's set-up, so profiles average.
      fit_statistics: what an ensemble fit compares by default:
        `{"columns": (...), "bins": b}` (`ensemble_fit.Statistics`).
      deterministic: every seed builds the same pile (the 1992 lattice and
        sloped piles): one seed is an ensemble.
      stages: later `Stage`s (stage-synchronous: every member of a batch
        finishes a stage before the next starts); `measure` then gets the
        last stage's simulator, state and protocol.
      simulator_options: the set-up options the simulator depends on (None:
        all of them); members whose set-ups differ only in other options share
        one compiled batch (the hopper's orifice).
      columns: the columns of a member's row, where they are known before a
        pile is measured (a protocol that declares its row as names); None
        where the row is computed. An ensemble fit refuses a column outside
        them before it runs.
    """

    setup: Callable
    simulator: Callable
    finished: Callable
    max_steps: Callable
    measure: Callable
    law_and_params: Callable
    default_dt: Callable
    angles: tuple
    options: frozenset
    theory: Callable | None = None
    unit: str = "deg"
    default_law: str = "lee-herrmann"
    extent: Callable | None = None
    fit_statistics: dict = dataclasses.field(default_factory=dict)
    stages: tuple = ()
    deterministic: bool = False
    simulator_options: frozenset | None = None
    columns: frozenset | None = None
