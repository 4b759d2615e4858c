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


def law_and_params(law, params=None, rotation=None, *, setting: dict, dtype=None, law_options: dict | None = None):
    """`(law module, ContactLaw, params)` for a protocol run.

    Args:
      law: a law name (`hooke`, `liffman`, `lee-herrmann`, `baxter`) or module.
      params: None (the setting's values for that law), a dict of overrides on
        top of them, or a ready params pytree of that law.
      rotation: integrate spins; None for `setting["rotation"]`.
      setting: a protocol setting with `"params"` (per law name) and
        `"rotation"` (None: the law's own default).
      law_options: the law's readings beyond rotation (`hooke.law(rolling="sds")`,
        baxter's `lever_arm`), passed to its `law(...)`.
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
    readings = dict(law_options or {})
    if "rotation" in readings:
        raise InputError("give rotation as rotation=..., not among the law's options.")
    if rotation is not None:
        readings["rotation"] = rotation
    try:
        contact_law = lawmod.law(**readings)
    except TypeError as error:
        raise InputError(f"the {lawmod.NAME} law does not take {sorted(law_options or {})} "
                         f"(law() says: {error}).") from None
    return lawmod, contact_law, params
