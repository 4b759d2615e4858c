"""What every protocol returns: the set-up, and what happens while it runs.

A protocol is a pure function of its arguments (and a seed) that returns a
`Setup`: particles (all of them, the ones not yet poured parked with
`active=False`), boundaries, the transient `schedule` (boundaries in force at a
step, e.g. a gravity ramp), the persistent `driver` (insertions, wall removal,
tilting, inside the compiled loop; see `jaxpile.protocols.drivers`) with its
carried `protocol_state`, and the neighbour-list `box`. Running it is
`Simulator(law, dt, schedule=p.schedule, driver=p.driver)`, then
`sim.init(params, p.particles, p.boundaries, box=p.box, protocol_state=p.protocol_state)`.
"""

from __future__ import annotations

from typing import Any, Callable, NamedTuple

from jaxpile.errors import InputError
from jaxpile.engine.state import Boundaries, Particles


class Setup(NamedTuple):
    """A protocol's set-up.

    Attributes:
      particles: every disk the run will ever hold (parked ones inactive).
      boundaries: walls and gravity at the start.
      schedule: optional `state -> Boundaries` in force at each step.
      driver: optional `state -> state` run before each step.
      protocol_state: the driver's carried data (a pytree) or None.
      box: `(width, height)` for the neighbour cell list, or None for the default.
      info: plain facts about the set-up for summaries (counts, sizes, angles).
    """

    particles: Particles
    boundaries: Boundaries
    schedule: Callable | None = None
    driver: Callable | None = None
    protocol_state: Any = None
    box: tuple | None = None
    info: dict = {}


class CommandLine(NamedTuple):
    """How a protocol appears on the command line: a protocol module that
    declares one as `CLI` is registered (`jaxpile.protocols.PROTOCOLS`) and
    `jaxpile pile|sweep|fit` take it, with no table elsewhere to edit.

    Attributes:
      order: its place in listings (the papers' order).
      help: one line for `--protocol`'s help.
      default_law: the law of its paper (`--law`'s default).
      size: the `run` keyword `--n` sets, or None (`--n` refused).
      flags: generic flag (`seed`, `max_steps`, `speed_tol`, `ramp_steps`,
        `hard_collisions`) -> the `run` keyword it sets; absent: refused.
      headline: summary keys `jaxpile pile` prints at its end (dotted keys
        reach into nested dicts).
      base_forces: `(sim, params, state, measured) -> BaseForces` written to
        base_forces.csv; None: the ground's (`analysis.base_forces`).
      summary: `measured -> dict` of plain numbers for summary.json; None:
        the measurements as they are, arrays as lists.
      length_unit: `law name -> unit` of pile.png's axes; None: diameters.
      profile_theory: `(measured, base) -> (N, H, label) | None`, drawn on
        profile.png.
      figures: `(measured, title, out) -> [files]`, the protocol's own
        figures (`jaxpile.protocols.outputs`).
      dry_run_setup: `run keywords -> (set-up function, its extra keywords)`
        for `--dry-run`, when the run starts from another protocol's set-up
        (the tilt from a box); None: the module's `protocol`.
      compare: `summary -> str`, the result column of `jaxpile compare`;
        None: the headline's first line.
      budget: `(run keywords, set-up info) -> steps`, the run's step budget
        when it is given as a time (`max_time`), for `--dry-run`'s bound.
    """

    order: int
    help: str
    default_law: str
    size: str | None = "n"
    flags: dict = {}
    headline: tuple = ()
    base_forces: Callable | None = None
    summary: Callable | None = None
    length_unit: Callable | None = None
    profile_theory: Callable | None = None
    figures: tuple = ()
    dry_run_setup: Callable | None = None
    compare: Callable | None = None
    budget: Callable | None = None


def law_and_params(law, params=None, rotation=None, *, setting: dict, dtype=None):
    """`(law module, ContactLaw, params)` for a protocol run.

    Args:
      law: a law name (`hooke`, `liffman`, `lee-herrmann`, `baxter`) or module.
      params: None (the setting's values for that law), a dict of overrides on
        top of them, or a ready params pytree of that law.
      rotation: integrate spins; None for `setting["rotation"]`.
      setting: a protocol setting with `"params"` (per law name) and
        `"rotation"` (None: the law's own default).
    """
    from jaxpile.laws import get_law_module

    lawmod = get_law_module(law) if isinstance(law, str) else law
    if params is None or isinstance(params, dict):
        values = {**setting["params"].get(lawmod.NAME, {}), **(params or {})}
        unknown = set(values) - set(lawmod.PARAM_NAMES)
        if unknown:
            raise InputError(f"unknown {lawmod.NAME} parameter(s) {sorted(unknown)}; "
                             f"known: {list(lawmod.PARAM_NAMES)}.")
        params = lawmod.make_params(dtype=dtype, **values)
    elif not isinstance(params, lawmod.Params):
        raise InputError(f"params must be None, a dict of {lawmod.NAME} parameters, or {lawmod.NAME}.make_params(...); "
                         f"got {type(params).__name__}.")
    rotation = setting["rotation"] if rotation is None else bool(rotation)
    return lawmod, lawmod.law() if rotation is None else lawmod.law(rotation=rotation), params
