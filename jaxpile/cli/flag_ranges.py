"""The valid range of every numeric flag (`jaxpile.ranges`), by command: shown
in `--help`, checked before anything is set up, and listed with the laws' and
protocols' ranges in `jaxpile pile --help` and the docs' table (docs/cli.md)."""

from __future__ import annotations

import dataclasses

from jaxpile.protocols.running import RUN_RANGES
from jaxpile.ranges import DISKS, NON_NEGATIVE, POSITIVE, SEED, SPEED, STEPS, TIME_STEP, Range, inline


def _flag_ranges() -> dict:
    layers = Range(low=1, whole=True, unit="layers")
    return {
        "pile": {"layers": layers, "n": DISKS, "slope": Range(low=1, high=60, why="degrees"),
                 "dt": TIME_STEP, "seed": SEED, "max_steps": STEPS,
                 "ramp_steps": dataclasses.replace(STEPS, why="steps of the gravity ramp; the step counter is 32-bit"),
                 "speed_tol": dataclasses.replace(SPEED, why="the speed_tolerance below which a pile is at rest"),
                 "checkpoint_every": STEPS, "trajectory_every": STEPS},
        "sweep": {"seeds": Range(low=1, whole=True, unit="seeds"), "n": DISKS, "dt": TIME_STEP, "max_steps": STEPS,
                  "batch_size": Range(low=1, whole=True, unit="members"), "checkpoint_every": STEPS},
        "fit": {"layers": layers, "n": DISKS, "seed": SEED, "steps": Range(low=0, whole=True, unit="optimiser steps"),
                "ensemble": Range(low=1, whole=True, unit="piles"), "target_seeds": SEED,
                "difference_step": Range(low=0, high=1, low_open=True, why="log units"),
                "lr": POSITIVE, "bins": Range(low=1, whole=True, unit="bins"), "window": STEPS,
                "horizontal_weight": NON_NEGATIVE, "dip_weight": NON_NEGATIVE,
                "batch_size": Range(low=1, whole=True, unit="piles")},
    }


FLAG_RANGES = _flag_ranges()
"""Each numeric flag's valid range (`jaxpile.ranges`), by command: shown in `--help`
and checked before anything is set up."""


def add_ranges_to_help(command: str, parser) -> None:
    """Appends each ranged flag's range to its help: `[>= 1 layers]`."""
    for action in parser._actions:
        if action.dest in FLAG_RANGES[command]:
            action.help = f"{action.help} [{FLAG_RANGES[command][action.dest].describe()}]"


def check_flags(args) -> None:
    """Every numeric flag given, against its range (one message format)."""
    for dest, range_ in FLAG_RANGES.get(args.command, {}).items():
        value = getattr(args, dest, None)
        if value is not None:
            range_.check("--" + dest.replace("_", "-"), value)


def ranges_markdown() -> str:
    """The table of valid ranges in docs/cli.md, from the same tables the checks use
    (tests/test_input_catalogue.py checks that docs/cli.md holds it as it is)."""
    from jaxpile.laws import LAWS, get_law_module, granular
    from jaxpile.cli.presentation import listed
    from jaxpile.protocols import PROTOCOLS
    from jaxpile.protocols.spec import ranges_of

    rows = ["| input | valid ranges |", "|---|---|"]
    rows += [f"| law `{name}` (`--set NAME=VALUE`) | {inline(get_law_module(name).RANGES)} |" for name in LAWS]
    rows += [f"| a LAMMPS granular line (`--law \"...\"`, `--set NAME=VALUE`) | {inline(granular.RANGES)} |"]
    rows += [f"| protocol `{name}` (`--option NAME=VALUE`) | {inline(ranges_of(PROTOCOLS[name].options))} |"
             for name in listed(PROTOCOLS) if ranges_of(PROTOCOLS[name].options)]
    rows += [f"| every protocol's run (`SPEC.run(..., seed=, dt=, chunk_steps=)`) | {inline(RUN_RANGES)} |"]
    rows += [f"| `jaxpile {command}` flags | "
             + "; ".join(f"--{dest.replace('_', '-')} {r.describe()}" for dest, r in FLAG_RANGES[command].items())
             + " |" for command in FLAG_RANGES]
    return "\n".join(rows)


def ranges_epilog() -> str:
    """`jaxpile pile --help`'s list of every law parameter's and protocol option's range."""
    from jaxpile.laws import LAWS, get_law_module, granular
    from jaxpile.cli.presentation import listed
    from jaxpile.protocols import PROTOCOLS
    from jaxpile.protocols.spec import ranges_of

    def entry(name, ranges_):  # wrapped between items only, never inside a range
        lines, line = [], f"  {name}:"
        for item in inline(ranges_).split("; "):
            if len(line) + len(item) > 98:
                lines.append(line + ";")
                line = "     "
            line += (" " if line.endswith(":") or not line.strip() else "; ") + item
        return "\n".join(lines + [line])

    out = ["law parameters (--set NAME=VALUE) and their valid ranges:"]
    out += [entry(name, get_law_module(name).RANGES) for name in LAWS]
    out += [entry("a LAMMPS granular line", granular.RANGES)]
    out += ["protocol options (--option NAME=VALUE, or a flag of its own: `jaxpile pile --protocol P --help`) "
            "and their valid ranges:"]
    out += [entry(name, ranges_of(PROTOCOLS[name].options)) for name in listed(PROTOCOLS)
            if ranges_of(PROTOCOLS[name].options)]
    return "\n".join(out)
