"""How piles are built. Each protocol module holds its physics (set-up,
driver, measurements) and one `SPEC` (`spec.ProtocolSpec`): its options, how
it runs, what a batch and the commands read. `PROTOCOLS` is every registered
spec by name; `PROTOCOLS["box"].run("hooke", 72)` runs one pile."""

import importlib
import pkgutil

from jaxpile.protocols.spec import ProtocolSpec


def _registered() -> dict:
    """`{name: ProtocolSpec}` of every module in this package that declares a
    `SPEC`, in the order its presentation gives: a new protocol is registered
    by its own module, with no list here to edit."""
    found = {}
    for info in pkgutil.iter_modules(__path__):
        module = importlib.import_module(f"{__name__}.{info.name}")
        spec = getattr(module, "SPEC", None)
        if isinstance(spec, ProtocolSpec):
            found[spec.name] = spec
    return dict(sorted(found.items(), key=lambda item: item[1].presentation.order))


PROTOCOLS = _registered()


def get(name: str) -> ProtocolSpec:
    """A registered protocol's spec by name, or `InputError` naming the known ones."""
    from jaxpile.errors import InputError

    if name not in PROTOCOLS:
        raise InputError(f"unknown protocol {name!r}; known: {', '.join(PROTOCOLS)}.")
    return PROTOCOLS[name]


def run(name: str, law: str | None = None, size: int | None = None, **kwargs):
    """One pile of the protocol `name`, set up, run to its end and measured:
    `get(name).run(law, size, **kwargs)` (`protocols.running.run`: `params`,
    `seed`, `dt`, `checkpoint`, `resume`, ... and the protocol's options).
    Returns a `PileRun` (`state`, `measurements`, `simulator`, `params`;
    unpacks as `(state, measurements)`)."""
    return get(name).run(law, size, **kwargs)


def presentation(name):
    """How the commands show a registered protocol (`spec.Presentation`), or None for an unknown name."""
    spec = PROTOCOLS.get(name)
    return None if spec is None else spec.presentation


__all__ = ["PROTOCOLS", "get", "presentation"]
