"""How piles are built. Each protocol returns a `base.Protocol`: the particles
(parked, inactive ones included), boundaries, and what happens while it runs
(schedule, driver); each module also has a `run(...)` that takes it to its end
and returns the final state and the protocol's measurements."""

from jaxpile.protocols import box, drop, flux, lattice, pour, sloped, tilt

PROTOCOLS = {"lattice": lattice, "sloped": sloped, "drop": drop, "box": box, "tilt": tilt, "flux": flux, "pour": pour}


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
            taken = {k: r for k, r in module.OPTION_RANGES.items() if k in inspect.signature(function).parameters}
            if taken:
                function.__doc__ = (function.__doc__ or "").rstrip() + doc_section(
                    taken, "Valid ranges (checked first; `jaxpile.ranges`)")


_document_ranges()

__all__ = ["box", "drop", "flux", "lattice", "pour", "sloped", "tilt", "PROTOCOLS"]
