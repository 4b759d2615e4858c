"""Contact laws: one module per law, each a pure per-pair kernel plus a params pytree."""

from __future__ import annotations

from jaxpile.errors import InputError
from jaxpile.laws import baxter, granular, hooke, lee_herrmann, liffman
from jaxpile.laws.base import ContactLaw, PairForce, PairGeometry

LAWS = {"hooke": hooke, "liffman": liffman, "lee-herrmann": lee_herrmann, "baxter": baxter}


def get_law_module(name: str):
    """The module of a law by its registry name (`hooke`, ...), or the
    `granular.Composition` of a LAMMPS `pair_coeff` granular line's text
    (`"hertz/material 1e7 0.3 0.3 tangential mindlin NULL 1.0 0.5"`)."""
    if name in LAWS:
        return LAWS[name]
    if granular.is_line(name):
        return granular.composition(name)
    raise InputError(f"unknown law {name!r}; known laws: {sorted(LAWS)}, or a LAMMPS pair_coeff granular line "
                     "such as 'hertz/material 1e7 0.3 0.3 tangential mindlin NULL 1.0 0.5' (docs/lammps.md).")


__all__ = ["ContactLaw", "PairForce", "PairGeometry", "LAWS", "baxter", "get_law_module", "granular", "hooke", "lee_herrmann", "liffman"]
