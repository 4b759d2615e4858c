"""How piles are built. Each protocol returns a `base.Protocol`: the particles
(parked, inactive ones included), boundaries, and what happens while it runs
(schedule, driver); each module also has a `run(...)` that takes it to its end
and returns the final state and the protocol's measurements."""

from jaxpile.protocols import drop, lattice, pour, sloped

PROTOCOLS = {"lattice": lattice, "sloped": sloped, "drop": drop, "pour": pour}

__all__ = ["drop", "lattice", "pour", "sloped", "PROTOCOLS"]
