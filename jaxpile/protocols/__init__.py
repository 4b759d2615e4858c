"""How piles are built. Each protocol module holds its physics (set-up,
driver, measurements) and one `SPEC` (`ProtocolSpec`): its options and how
it runs. `PROTOCOLS` is every registered spec by name;
`PROTOCOLS["box"].run("hooke", 72)` runs one pile. What the commands show of
a protocol (`jaxpile.cli.presentation`) and what a batch reads of it
(`jaxpile.batches`) are declared by name in the layers above."""

import importlib
import pkgutil

from jaxpile.protocols import drivers, geometry
from jaxpile.protocols.base import REGISTERED, Setting, Setup, registered
from jaxpile.protocols.running import PileRun, run, run_setup
from jaxpile.protocols.spec import Options, ProtocolSpec, option
from jaxpile.protocols.stages import Phase, one_phase


def _registered() -> dict:
    """`{name: ProtocolSpec}` of every module in this package that declares a
    `SPEC`, by name: a new protocol is registered by its own module, with no
    list here to edit."""
    found = {}
    for info in pkgutil.iter_modules(__path__):
        module = importlib.import_module(f"{__name__}.{info.name}")
        spec = getattr(module, "SPEC", None)
        if isinstance(spec, ProtocolSpec):
            found[spec.name] = spec
    return dict(sorted(found.items()))


PROTOCOLS = REGISTERED  # one dict: the spec of a continued protocol is looked up in it
PROTOCOLS.update(_registered())


def get(name: str) -> ProtocolSpec:
    """A registered protocol's spec by name, or `InputError` naming the known ones."""
    return registered(name)


from jaxpile.protocols import box, cone, drop, flux, hopper, lattice, lift, pour, sloped, tilt  # noqa: E402  (registered above)

__all__ = [
    # running one: `run` a registered protocol, or `run_setup` a set-up of your own through its phases
    "PROTOCOLS", "PileRun", "get", "run", "run_setup",
    # the protocols, one module each
    "box", "cone", "drop", "flux", "hopper", "lattice", "lift", "pour", "sloped", "tilt",
    # writing one (docs/extending.md): its declaration, options, phases, set-up, and the shared pieces
    "Options", "Phase", "ProtocolSpec", "Setting", "Setup", "drivers", "geometry", "one_phase", "option",
]
