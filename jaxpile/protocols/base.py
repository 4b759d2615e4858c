"""What every protocol returns: the set-up, and what happens while it runs.

A protocol is a pure function of its arguments (and a seed) that returns a
`Protocol`: particles (all of them, the ones not yet poured parked with
`active=False`), boundaries, the transient `schedule` (boundaries in force at a
step, e.g. a gravity ramp), the persistent `driver` (insertions, wall removal,
tilting, inside the compiled loop; see `jaxpile.protocols.drivers`) with its
carried `protocol_state`, and the neighbour-list `box`. Running it is
`Simulator(law, dt, schedule=p.schedule, driver=p.driver)`, then
`sim.init(params, p.particles, p.boundaries, box=p.box, protocol_state=p.protocol_state)`.
"""

from __future__ import annotations

from typing import Any, Callable, NamedTuple

from jaxpile.state import Boundaries, Particles


class Protocol(NamedTuple):
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
