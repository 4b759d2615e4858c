"""How piles are built. Each protocol returns a `base.Setup`: the particles
(parked, inactive ones included), boundaries, and what happens while it runs
(schedule, driver); each module also has a `run(...)` that takes it to its end
and returns the final state and the protocol's measurements."""

import importlib
import pkgutil

from jaxpile.protocols.base import CommandLine


def _registered() -> dict:
    """`{name: module}` of every module in this package that declares a
    `CLI = CommandLine(...)`, in the order it declares: a new protocol is
    registered by its own module, with no list here to edit."""
    found = {}
    for info in pkgutil.iter_modules(__path__):
        module = importlib.import_module(f"{__name__}.{info.name}")
        if isinstance(getattr(module, "CLI", None), CommandLine):
            found[info.name] = module
    return dict(sorted(found.items(), key=lambda item: item[1].CLI.order))


PROTOCOLS = _registered()  # importing a submodule also binds it here: `protocols.pour` works without its own import


def entry(name) -> CommandLine | None:
    """A registered protocol's `CommandLine` entry by name, or None."""
    module = PROTOCOLS.get(name)
    return None if module is None else module.CLI


def _document_ranges() -> None:
    """Appends each set-up and run function's argument ranges (its module's
    `OPTION_RANGES`, which the function checks first) to its docstring, so that
    `help(pour.pour)` states them; one table, no copy to keep in step."""
    import inspect

    from jaxpile.ranges import doc_section

    seen = set()  # pour.protocol is pour.pour: its section once
    for module in PROTOCOLS.values():
        for name in ("protocol", "pour", "run", "equilateral_pile"):
            function = getattr(module, name, None)
            if function is None or function.__module__ != module.__name__ or function in seen:
                continue
            seen.add(function)
            taken = {k: r for k, r in getattr(module, "OPTION_RANGES", {}).items() if k in inspect.signature(function).parameters}
            if taken:
                function.__doc__ = (function.__doc__ or "").rstrip() + doc_section(
                    taken, "Valid ranges (checked first; `jaxpile.ranges`)")


_document_ranges()

__all__ = [*PROTOCOLS, "PROTOCOLS", "entry"]
