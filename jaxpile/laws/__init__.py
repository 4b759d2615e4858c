"""Contact laws: one module per law, each a pure per-pair kernel plus a params pytree."""

from __future__ import annotations

from jaxpile.errors import InputError
from jaxpile.laws import baxter, hooke, lee_herrmann, liffman
from jaxpile.laws.base import ContactLaw, PairForce, PairGeometry

LAWS = {"hooke": hooke, "liffman": liffman, "lee-herrmann": lee_herrmann, "baxter": baxter}


def get_law_module(name: str):
    """The module of a law by its registry name (`hooke`, ...)."""
    try:
        return LAWS[name]
    except KeyError:
        raise InputError(f"unknown law {name!r}; known laws: {sorted(LAWS)}.") from None


__all__ = ["ContactLaw", "PairForce", "PairGeometry", "LAWS", "baxter", "get_law_module", "hooke", "lee_herrmann", "liffman"]
