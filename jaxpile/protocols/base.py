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

from collections.abc import Mapping
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


class Setting(NamedTuple):
    """The setting a protocol runs its laws in: its paper's law, each law's
    parameters, the time step and whether disks spin. `law_and_params` is the
    one way a run builds its law and parameters.

    Attributes:
      law: the paper's law, a protocol's default.
      params: `{law name: values}` (a law not named runs with its own
        defaults), or `law name -> values` (the 1993 setting's units per law).
      dt: the time step, or `law name -> dt`.
      rotation: integrate spins; None: each law's own default.
    """

    law: str
    params: Mapping | Callable
    dt: float | Callable
    rotation: bool | None = None

    def dt_of(self, law) -> float:
        """The time step `law` (a name) runs with in this setting."""
        return float(self.dt(law) if callable(self.dt) else self.dt)

    def params_of(self, name: str) -> dict:
        """The setting's parameter values for the law `name`."""
        return dict(self.params(name) if callable(self.params) else self.params.get(name, {}))

    def law_and_params(self, law, params=None, rotation=None, dtype=None, law_options: dict | None = None):
        """`(law module, ContactLaw, params)` for a run in this setting.

        Args:
          law: a law name (`hooke`, `liffman`, `lee-herrmann`, `baxter`, a LAMMPS
            granular line) or module.
          params: None (the setting's values for that law), a dict of overrides on
            top of them, or a ready params pytree of that law.
          rotation: integrate spins; None for the setting's `rotation`.
          law_options: the law's readings beyond rotation (`hooke.law(rolling="sds")`,
            baxter's `lever_arm`), passed to its `law(...)`.
        """
        from jaxpile.laws import get_law_module

        lawmod = get_law_module(law) if isinstance(law, str) else law
        if params is None or isinstance(params, dict):
            values = {**self.params_of(lawmod.NAME), **(params or {})}
            unknown = set(values) - set(lawmod.PARAM_NAMES)
            if unknown:
                raise InputError(f"unknown {lawmod.NAME} parameter(s) {sorted(unknown)}; "
                                 f"known: {list(lawmod.PARAM_NAMES)}.")
            params = lawmod.make_params(dtype=dtype, **values)
        elif not isinstance(params, lawmod.Params):
            raise InputError(f"params must be None, a dict of {lawmod.NAME} parameters, or "
                             f"{lawmod.NAME}.make_params(...); got {type(params).__name__}.")
        rotation = self.rotation if rotation is None else bool(rotation)
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


REGISTERED: dict = {}
"""Every registered spec by name: `jaxpile.protocols.PROTOCOLS`, filled when that
package imports the protocol modules; a spec finds the one it `continues` here."""


def registered(name: str):
    """A registered protocol's spec by name, or `InputError` naming the known ones."""
    if name not in REGISTERED:
        raise InputError(f"unknown protocol {name!r}; known: {', '.join(REGISTERED)}.")
    return REGISTERED[name]


__all__ = ["REGISTERED", "Setting", "Setup", "registered"]
