"""How piles are built. Each protocol returns a `base.Protocol`: the particles
(parked, inactive ones included), boundaries, and what happens while it runs
(schedule, driver); each module also has a `run(...)` that takes it to its end
and returns the final state and the protocol's measurements."""

from jaxpile.protocols import box, drop, flux, lattice, pour, sloped, tilt

PROTOCOLS = {"lattice": lattice, "sloped": sloped, "drop": drop, "box": box, "tilt": tilt, "flux": flux, "pour": pour}

__all__ = ["box", "drop", "flux", "lattice", "pour", "sloped", "tilt", "PROTOCOLS"]
