"""How piles are built. Each protocol returns an initial state's particles and
boundaries (and, for later protocols, a schedule)."""

from jaxpile.protocols import lattice

PROTOCOLS = {"lattice": lattice}

__all__ = ["lattice", "PROTOCOLS"]
