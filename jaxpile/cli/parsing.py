"""Flag text into values: the `NAME=VALUE` arguments every subcommand shares
(`--set`, `--option`) and the on/off switches."""

from __future__ import annotations

import argparse

from jaxpile.errors import InputError


def on_off(text: str) -> bool:
    """An on/off flag's value (on, true, yes, 1 / off, false, no, 0), as an argparse `type`."""
    if text.lower() in ("on", "true", "yes", "1"):
        return True
    if text.lower() in ("off", "false", "no", "0"):
        return False
    raise argparse.ArgumentTypeError(f"expected on or off, got {text!r}")


def parse_set(items, known) -> dict:
    """`--set NAME=VALUE` (repeated): law parameters by name, each a number; a
    name outside `known` is refused."""
    values = {}
    for item in items or []:
        if "=" not in item:
            raise InputError(f"--set takes NAME=VALUE; got {item!r}.")
        name, value = item.split("=", 1)
        name = name.strip()
        if name not in known:
            raise InputError(f"unknown parameter {name!r} in --set; known: {', '.join(known)}.")
        try:
            values[name] = float(value)
        except ValueError:
            raise InputError(f"--set {name}= needs a number; got {value!r}.") from None
    return values


def parse_options(items) -> dict:
    """`--option NAME=VALUE`: ints, floats, on/off, or text."""
    options = {}
    for item in items or []:
        if "=" not in item:
            raise InputError(f"--option takes NAME=VALUE; got {item!r}.")
        name, text = (part.strip() for part in item.split("=", 1))
        for convert in (int, float):
            try:
                value = convert(text)
                break
            except ValueError:
                continue
        else:
            lowered = text.lower()
            value = {"on": True, "true": True, "off": False, "false": False}.get(lowered, text)
        options[name.replace("-", "_")] = value
    return options


def hard_collisions_of(text):
    """`--hard-collisions EPS,MU` as a checked `HardCollisions`, or None."""
    from jaxpile.engine.collisions import HardCollisions

    if text is None:
        return None
    try:
        eps, mu = (float(v) for v in text.split(","))
    except ValueError:
        raise InputError(f"--hard-collisions takes EPS,MU (e.g. 0.5,0.3); got {text!r}.") from None
    hard = HardCollisions(restitution=eps, mu=mu)
    hard.check()
    return hard


def law_options_of(args) -> dict:
    """The law's readings the flags ask for (`--rolling`), for `law(...)`."""
    return {} if getattr(args, "rolling", None) is None else {"rolling": args.rolling}
