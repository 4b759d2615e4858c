"""The `jaxpile` command.

  jaxpile pile --protocol lattice --layers 45 --law hooke --out DIR [--set NAME=VALUE ...]
  jaxpile pile --protocol sloped --slope 45 --n 360 --out DIR
  jaxpile pile --protocol drop | box | tilt | flux | pour [--n N] [--option NAME=VALUE ...] --out DIR
  jaxpile pile|sweep ... --checkpoint-every STEPS --out DIR;  jaxpile pile|sweep --resume DIR
  jaxpile show DIR [--out DIR2] [--checkpoint]   (a pile run, a checkpoint, a sweep or a fit)
  jaxpile compare DIR [DIR ...]
  jaxpile sweep --protocol box --law lee-herrmann --mu 0.05,0.1,0.2 --seeds 16 --out DIR
  jaxpile fit --target FILE|smid-novosad --protocol lattice|pour --law hooke --params mu,kt --out DIR
  jaxpile fit --protocol box|pour|drop|lattice|sloped|flux --params mu --truth mu=0.273 --set mu=0.19
              --ensemble 16 [--estimator central|smoothing|truncated] --out DIR   (ensemble fits; --resume)

Every protocol writes summary.json (the set-up and the protocol's measurements),
base_forces.csv, contacts.csv (the force network), state.npz, final.xyz
(extended XYZ), pile.png and profile.png; box and tilt add
energy.png (kinetic energy per disk, Lee & Herrmann 1993 Fig. 1(b)), flux adds
angles.png (Fig. 5) and pour adds heap_profile.png (the binned base force of
Baxter et al. 1997). A sweep writes sweep.csv (one row per member), sweep.png
(mean +- standard error against the varied parameter, theory overlaid) and
sweep.json (the set-up, timings and the per-value summaries). A fit writes
fit.json (the fitted values, the loss history, the profiles before and after)
and fit.png (loss curve; target, before and after); an ensemble fit adds the
95 % interval to fit.json, target.json (the target's statistics and piles)
and fit_checkpoint.json (the history, written every iteration).
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import importlib.util
import os
import sys
import time

import numpy as np

from jaxpile.cli.parsing import parse_options, parse_set
from jaxpile.io import plain


def _on_off(text: str) -> bool:
    if text.lower() in ("on", "true", "yes", "1"):
        return True
    if text.lower() in ("off", "false", "no", "0"):
        return False
    raise argparse.ArgumentTypeError(f"expected on or off, got {text!r}")


def _parse_hard_collisions(text):
    from jaxpile.engine.collisions import HardCollisions
    from jaxpile.errors import InputError

    if text is None:
        return None
    try:
        eps, mu = (float(v) for v in text.split(","))
    except ValueError:
        raise InputError(f"--hard-collisions takes EPS,MU (e.g. 0.5,0.3); got {text!r}.") from None
    hard = HardCollisions(restitution=eps, mu=mu)
    hard.check()
    return hard


def _entry(name: str):
    """The protocol's registry entry (`protocols.base.CommandLine`): its help,
    default law, the keyword `--n` sets, the generic flags it takes, its headline."""
    from jaxpile.protocols import entry

    return entry(name)


def _protocol_names() -> list[str]:
    from jaxpile.protocols import PROTOCOLS

    return list(PROTOCOLS)


DEFAULT_PROTOCOL = {"pile": "lattice", "sweep": "box", "fit": "lattice"}


def _command_and_protocol(argv: list[str]) -> tuple[str | None, str | None]:
    """The command and the protocol an argument list names (its default when
    it names none), read before the full parse: the protocol's own flags are
    added to the parser for it."""
    command = argv[0] if argv and not argv[0].startswith("-") else None
    protocol = None
    for k, a in enumerate(argv):
        if a == "--protocol" and k + 1 < len(argv):
            protocol = argv[k + 1]
        elif a.startswith("--protocol="):
            protocol = a.split("=", 1)[1]
    return command, protocol or DEFAULT_PROTOCOL.get(command)


def _protocol_flags(command: str, protocol: str) -> dict:
    """`{name: options.Option}`: the options of `protocol` that `command` takes
    as flags of their own: for `pile`, those of the protocol's `run` and set-up
    that no generic flag (`--seed`, `--max-steps`, ...) sets; for `sweep` and
    `fit`, the set-up options a batch takes. Options without a type the
    command line can give (a dict, no default and no range) stay `--option`'s."""
    from jaxpile import sweep
    from jaxpile.protocols import PROTOCOLS, options

    module = PROTOCOLS.get(protocol)
    if module is None or not hasattr(module, "run") or command not in DEFAULT_PROTOCOL:
        return {}
    if command == "pile":
        names = options.accepted(module) - set(module.CLI.flags.values()) - {"seed"}
    else:
        names = sweep.adapter(protocol).options & options.accepted(module)
    return {k: o for k, o in options.declared(module, names).items() if o.default is not None or o.range is not None}


def _add_protocol_flags(parser, command: str, protocol: str) -> None:
    """One `--NAME` flag per option of `protocol` (`_protocol_flags`), in a group
    of `--help` of their own, each with its docstring's help, range and default.
    A name the command already has a flag for keeps that flag."""
    flags = {k: o for k, o in _protocol_flags(command, protocol).items()
             if o.flag not in parser._option_string_actions}
    if not flags:
        return
    group = parser.add_argument_group(f"options of the {protocol} protocol (the same as --option NAME=VALUE)")
    for o in flags.values():
        words = [o.help or o.name.replace("_", " ")]
        if o.range is not None:
            words.append(f"[{o.range.describe()}]")
        if o.default is not None:
            words.append(f"(default {o.default})")
        kind = {bool: _on_off, int: int, float: float, str: str}[o.kind]
        group.add_argument(o.flag, dest=f"protocol_option__{o.name}", type=kind, default=None,
                           metavar={bool: "on|off", int: "N", float: "X", str: "TEXT"}[o.kind],
                           help=" ".join(words).replace("%", "%%"))


def _merge_protocol_flags(args) -> None:
    """The protocol's own flags given, appended to `args.option` as
    `NAME=VALUE` (one path from there on); a name given both ways is refused."""
    from jaxpile.errors import InputError

    given = {k.split("__", 1)[1]: v for k, v in vars(args).items()
             if k.startswith("protocol_option__") and v is not None}
    if not given:
        return
    twice = sorted(set(parse_options(args.option)) & set(given))
    if twice:
        raise InputError(f"{', '.join(twice)} given both as a flag and as --option: give it once.")
    text = {True: "on", False: "off"}
    args.option = list(args.option or []) + [
        f"{k}={text[v] if isinstance(v, bool) else v}" for k, v in given.items()]


def _output_args(parser, precision: bool = True) -> None:
    """The flags every run command shares: precision, progress bar, output folder."""
    if precision:
        parser.add_argument("--precision", choices=["float64", "float32"], default="float64")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    parser.add_argument("--out", required=True, help="output folder")


class _Parser(argparse.ArgumentParser):
    """argparse, with its errors in the same one-line form as every other refusal
    (argparse prints the whole usage block first)."""

    def error(self, message):
        self.exit(2, f"jaxpile: error: {message} (see `{self.prog} --help`)\n")


def _sweep_protocols() -> list[str]:
    """The registered protocols a sweep and an ensemble fit run (`sweep.adapters`)."""
    from jaxpile import sweep

    runs = sweep.adapters()
    return [name for name in _protocol_names() if name in runs]


def __getattr__(name):  # SWEEP_PROTOCOLS, read from the registry when asked for
    if name == "SWEEP_PROTOCOLS":
        return _sweep_protocols()
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def build_parser(argv: list[str] | None = None) -> argparse.ArgumentParser:
    """The parser; with `argv`, its command's parser also has the flags of the
    protocol `argv` names (`_add_protocol_flags`)."""
    parser = _Parser(prog="jaxpile", description="Differentiable 2D granular piles in JAX.")
    sub = parser.add_subparsers(dest="command", required=True)

    pile = sub.add_parser("pile", help="build a pile, relax it, measure its base forces and draw it")
    pile.add_argument("--protocol", default="lattice", choices=_protocol_names(),
                      help="how the pile is built: " + "; ".join(f"{k}: {_entry(k).help}" for k in _protocol_names()))
    pile.add_argument("--layers", type=int, default=None, help="layers of the lattice pile (default 45: 1035 disks)")
    pile.add_argument("--n", type=int, default=None,
                      help="disks (sloped, drop, box, tilt, pour) or insertions (flux); default: the paper's")
    pile.add_argument("--slope", type=float, default=None, metavar="DEG",
                      help="side angle of the sloped pile in degrees (< 60; default 30)")
    pile.add_argument("--option", action="append", metavar="NAME=VALUE",
                      help="a protocol option, e.g. width=4 (box), polydispersity=0.05 (pour) (repeatable)")
    pile.add_argument("--law", default=None,
                      help="contact law: hooke, liffman, lee-herrmann, baxter (default: the protocol's paper's law)")
    pile.add_argument("--set", action="append", metavar="NAME=VALUE", help="override a law parameter (repeatable)")
    pile.add_argument("--rotation", type=_on_off, default=None, metavar="on|off",
                      help="integrate spins (lattice default: off, as the 1992 static analysis)")
    pile.add_argument("--dt", type=float, default=None, help="time step (default: the protocol's)")
    pile.add_argument("--integrator", default="velocity_verlet",
                      choices=["velocity_verlet", "leapfrog", "gear", "implicit_midpoint"],
                      help="time integrator (leapfrog: Baxter et al. 1997 eqs. 9-12; gear: fifth-order "
                           "predictor-corrector, Lee & Herrmann 1993; implicit_midpoint: Liffman et al. 1992 eq. 24)")
    pile.add_argument("--hard-collisions", metavar="EPS,MU", default=None,
                      help="fast approaches collide impulsively with restitution EPS and friction MU "
                           "(Liffman et al. 1992 eqs. 1-22); default off")
    pile.add_argument("--seed", type=int, default=0, help="random seed (the lattice and sloped piles are deterministic)")
    pile.add_argument("--max-steps", type=int, default=None, help="step budget for loading and relaxing")
    pile.add_argument("--ramp-steps", type=int, default=None, help="steps over which gravity is switched on")
    pile.add_argument("--speed-tol", type=float, default=None, help="max disk speed that counts as at rest")
    pile.add_argument("--checkpoint-every", type=int, default=None, metavar="STEPS",
                      help="save the whole run to OUT/checkpoint.npz every STEPS steps (atomically)")
    pile.add_argument("--trajectory-every", type=int, default=None, metavar="STEPS",
                      help="append a frame to OUT/trajectory.xyz (extended XYZ: OVITO, ASE) every STEPS steps")
    pile.add_argument("--trajectory-format", choices=["xyz", "lammps"], default="xyz",
                      help="the trajectory's format: extended XYZ, or a LAMMPS dump (OUT/trajectory.lammpstrj: "
                           "OVITO, LAMMPS read_dump/rerun)")
    pile.add_argument("--resume", default=None, metavar="DIR",
                      help="continue the run saved in DIR/checkpoint.npz with its own settings "
                           "(`jaxpile pile --resume DIR`); ends as the uninterrupted run would")
    pile.add_argument("--dry-run", action="store_true",
                      help="print the set-up, the memory estimate and the steps it plans, then stop (runs nothing)")
    _output_args(pile)

    show = sub.add_parser("show", help="re-draw the figures of a finished or checkpointed pile run, a sweep or a "
                                       "fit (no re-run)")
    show.add_argument("dir")
    show.add_argument("--out", default=None, help="where to write the figures (default: DIR)")
    show.add_argument("--checkpoint", action="store_true", help="draw the last checkpoint even if the run finished")

    compare = sub.add_parser("compare", help="print the summaries of finished runs side by side")
    compare.add_argument("dirs", nargs="+")

    sweep = sub.add_parser("sweep", help="run a protocol over a grid of law parameters and seeds, batched")
    sweep.add_argument("--protocol", default="box", choices=_sweep_protocols(),
                       help="every registered protocol (lattice and sloped are deterministic: vary the law)")
    sweep.add_argument("--law", default=None, help="contact law (default: the protocol paper's)")
    sweep.add_argument("--mu", default=None, metavar="V1,V2,...", help="friction coefficients to sweep")
    sweep.add_argument("--vary", action="append", metavar="NAME=V1,V2,...",
                       help="another law parameter, or a set-up option of the protocol (--vary orifice=4,6,8 "
                            "for the hopper), to sweep (repeatable; the grid is the product)")
    sweep.add_argument("--seeds", type=int, default=4, help="random piles per grid point (seeds 0..N-1)")
    sweep.add_argument("--n", type=int, default=None, help="disks per pile (default: the protocol's)")
    sweep.add_argument("--option", action="append", metavar="NAME=VALUE", help="a set-up option (repeatable)")
    sweep.add_argument("--set", action="append", metavar="NAME=VALUE", help="a fixed law parameter (repeatable)")
    sweep.add_argument("--dt", type=float, default=None, help="time step (default: the protocol's)")
    sweep.add_argument("--max-steps", type=int, default=None, help="step budget per batch")
    sweep.add_argument("--batch-size", type=int, default=None, help="members per compiled batch (default: all)")
    sweep.add_argument("--checkpoint-every", type=int, default=None, metavar="STEPS",
                       help="save the running batch and the rows so far to OUT/checkpoint.npz every STEPS steps")
    sweep.add_argument("--resume", default=None, metavar="DIR",
                       help="continue the sweep saved in DIR (`jaxpile sweep --resume DIR`)")
    sweep.add_argument("--dry-run", action="store_true",
                       help="print the members, one member's set-up, the batch's memory estimate and the steps; "
                            "run nothing")
    _output_args(sweep)

    fitp = sub.add_parser("fit", help="fit law parameters to a target base-force profile or to an ensemble's "
                                      "statistics (gradients + optax, or Gauss-Newton on ensemble means)")
    fitp.add_argument("--target", default=None, metavar="FILE|smid-novosad",
                      help="a CSV (columns x/B, normal/max[, horizontal/max]) or the Smid-Novosad features (one "
                           "pile, pathwise gradients); or a target.json written by an ensemble fit; with "
                           "--estimator central|smoothing, smid-novosad is the central dip 0.25 as an ensemble "
                           "target (the drop's and the pour's central_dip column)")
    fitp.add_argument("--protocol", default="lattice", choices=_sweep_protocols(),
                      help="the pile; pathwise fits: lattice and pour; ensemble fits: every protocol")
    fitp.add_argument("--estimator", default=None, choices=["pathwise", "central", "smoothing", "truncated"],
                      help="the gradient: pathwise through one pile (default with a CSV target), or of the "
                           "ensemble-mean loss by central differences (default with --truth or a target.json), "
                           "Gaussian smoothing with antithetic pairs, or the pathwise gradient through the pour's "
                           "construction truncated to windows of --truncation-window steps (the base profile "
                           "alone; measured biased on 40-disk heaps: README's estimator study)")
    fitp.add_argument("--truncation-window", type=int, default=60, metavar="W",
                      help="--estimator truncated: steps each sensitivity is taken through (the study's 60)")
    fitp.add_argument("--ensemble", type=int, default=None, metavar="B",
                      help="ensemble fits: piles per ensemble (default 8; 1 for the deterministic lattice and sloped "
                           "piles)")
    fitp.add_argument("--difference-step", type=float, default=0.05, metavar="H",
                      help="ensemble fits: central differences at log-parameters +- H (a chaotic protocol such as "
                           "the pour needs a wide one, ~0.2)")
    fitp.add_argument("--truth", action="append", metavar="NAME=VALUE",
                      help="ensemble fits: make the target with jaxpile at these law values, from seeds the fit "
                           "never sees (a recovery test)")
    fitp.add_argument("--target-seeds", type=int, default=10_000, metavar="FIRST",
                      help="ensemble fits: the target's seeds are FIRST .. FIRST + B - 1 (the fit's: 0 .. B - 1)")
    fitp.add_argument("--statistics", default=None, metavar="COLUMN,COLUMN",
                      help="ensemble fits: the per-pile measurements compared (default: the protocol's); with "
                           "--bins, the base profile too")
    fitp.add_argument("--resume", action="store_true",
                      help="ensemble fits: continue the fit whose history is in OUT/fit_checkpoint.json")
    fitp.add_argument("--law", default=None, help="contact law (default: the protocol paper's)")
    fitp.add_argument("--params", required=True, metavar="NAME,NAME", help="the law parameters to fit")
    fitp.add_argument("--set", action="append", metavar="NAME=VALUE", help="a starting/fixed law parameter")
    fitp.add_argument("--layers", type=int, default=6, help="lattice: layers of the pile")
    fitp.add_argument("--n", type=int, default=None, help="disks (pathwise pour: default 60; ensembles: the "
                                                          "protocol's --n, default its own)")
    fitp.add_argument("--option", action="append", metavar="NAME=VALUE", help="pour: a set-up option")
    fitp.add_argument("--seed", type=int, default=0, help="pour: random seed")
    fitp.add_argument("--steps", type=int, default=None,
                      help="optimiser steps (default 40; ensemble fits: at most 6 Gauss-Newton iterations)")
    fitp.add_argument("--optimizer", default=None,
                      help="an optax optimiser by name: adam, sgd, lbfgs, ... (default adam), or gauss-newton "
                           "(ensemble fits with central differences: their default)")
    fitp.add_argument("--lr", type=float, default=0.05, help="learning rate (in log-parameter units)")
    fitp.add_argument("--bins", type=int, default=None, help="profile bins (default: layers, or 9 for pour)")
    fitp.add_argument("--window", type=int, default=2000,
                      help="pour: steps of relaxation from the poured heap that are differentiated")
    fitp.add_argument("--horizontal-weight", type=float, default=1.0,
                      help="weight of the horizontal profile in the loss (when the target has one)")
    fitp.add_argument("--dip-weight", type=float, default=0.0, help="weight of the central-dip feature")
    fitp.add_argument("--dry-run", action="store_true",
                      help="print the pile the fit builds, the parameters' starting values, the memory estimate "
                           "and the steps; run nothing")
    _output_args(fitp, precision=False)
    for name, command in (("pile", pile), ("sweep", sweep), ("fit", fitp)):
        for action in command._actions:
            if action.dest in FLAG_RANGES[name]:
                action.help = f"{action.help} [{FLAG_RANGES[name][action.dest].describe()}]"
    pile.epilog = _ranges_epilog()
    pile.formatter_class = argparse.RawDescriptionHelpFormatter
    command, protocol = _command_and_protocol(list(argv or []))
    if argv is not None and command in DEFAULT_PROTOCOL:
        _add_protocol_flags({"pile": pile, "sweep": sweep, "fit": fitp}[command], command, protocol)
    return parser


def _flag_ranges() -> dict:
    from jaxpile.ranges import DISKS, NON_NEGATIVE, POSITIVE, SEED, SPEED, STEPS, TIME_STEP, Range

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
                "horizontal_weight": NON_NEGATIVE, "dip_weight": NON_NEGATIVE},
    }


FLAG_RANGES = _flag_ranges()
"""Each numeric flag's valid range (`jaxpile.ranges`), by command: shown in `--help`
and checked before anything is set up."""


def _check_flags(args) -> None:
    """Every numeric flag given, against its range (one message format)."""
    for dest, range_ in FLAG_RANGES.get(args.command, {}).items():
        value = getattr(args, dest, None)
        if value is not None:
            range_.check("--" + dest.replace("_", "-"), value)


def ranges_markdown() -> str:
    """The README's table of valid ranges, from the same tables the checks use
    (tests/test_input_catalogue.py checks that the README holds it as it is)."""
    from jaxpile.laws import LAWS, get_law_module
    from jaxpile.protocols import PROTOCOLS
    from jaxpile.ranges import inline

    rows = ["| input | valid ranges |", "|---|---|"]
    rows += [f"| law `{name}` (`--set NAME=VALUE`) | {inline(get_law_module(name).RANGES)} |" for name in LAWS]
    rows += [f"| protocol `{name}` (`--option NAME=VALUE`) | {inline(module.OPTION_RANGES)} |"
             for name, module in PROTOCOLS.items() if getattr(module, "OPTION_RANGES", None)]
    rows += [f"| `jaxpile {command}` flags | "
             + "; ".join(f"--{dest.replace('_', '-')} {r.describe()}" for dest, r in FLAG_RANGES[command].items())
             + " |" for command in FLAG_RANGES]
    return "\n".join(rows)


def _ranges_epilog() -> str:
    """`jaxpile pile --help`'s list of every law parameter's and protocol option's range."""
    from jaxpile.laws import LAWS, get_law_module
    from jaxpile.protocols import PROTOCOLS
    from jaxpile.ranges import inline

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
    out += ["protocol options (--option NAME=VALUE, or a flag of its own: `jaxpile pile --protocol P --help`) "
            "and their valid ranges:"]
    out += [entry(name, module.OPTION_RANGES) for name, module in PROTOCOLS.items()
            if getattr(module, "OPTION_RANGES", None)]
    return "\n".join(out)


def _resume_argv(argv: list[str]) -> list[str]:
    """`pile|sweep --resume DIR [--no-progress]` -> the saved run's own command line
    plus `--resume DIR`: a resumed run takes every setting from its checkpoint."""
    from jaxpile.engine import checkpoint
    from jaxpile.errors import InputError

    rest = [a for a in argv[1:] if a != "--no-progress"]
    if len(rest) != 2 or rest[0] != "--resume":
        raise InputError(f"resume a run with `jaxpile {argv[0]} --resume DIR` alone (its settings come from the "
                         f"checkpoint; --no-progress may be added); got {' '.join(argv)!r}.")
    folder = rest[1]
    path = checkpoint.in_folder(folder)
    if path is None:
        raise InputError(f"no checkpoint to resume in {folder} (expected {os.path.join(folder, 'checkpoint.npz')}; "
                         "runs write it with --checkpoint-every STEPS).")
    saved = checkpoint.read_metadata(path)["extra"].get("argv")
    if not saved:
        raise InputError(f"{path} does not record the command that made it: it cannot be resumed from the CLI.")
    if saved[0] != argv[0]:
        raise InputError(f"{folder} holds a `jaxpile {saved[0]}` run: resume it with `jaxpile {saved[0]} --resume "
                         f"{folder}`.")
    return [*saved, "--resume", folder] + (["--no-progress"] if "--no-progress" in argv else [])


THREADED_PILE_DISKS = 2000
"""From this many disks one pile's kernels are large enough to split over XLA's
threads. Measured on 2 cores (benchmarks/scaling.py, settling box, float64,
one thread against two): 1000 disks 5.6e6 against 5.1e6 particle-steps/s,
3000 disks 5.8e6 against 6.5e6, 10000 6.1e6 against 8.9e6."""


def pile_disks(args) -> int | None:
    """The disk count a `pile` command asks for, read from its size flag before
    anything runs (None: the protocol's default size, the paper's)."""
    if getattr(args, "layers", None) is not None:
        from jaxpile.protocols.lattice import pile_count

        return pile_count(int(args.layers))
    return None if getattr(args, "n", None) is None else int(args.n)


def wants_xla_threads(args) -> bool:
    """Whether a command runs work whose kernels are large enough to split over
    XLA's threads: a sweep, an ensemble fit, a pile of `THREADED_PILE_DISKS` or more."""
    return (args.command == "sweep" or (args.command == "fit" and fit_runs_batches(args))
            or (args.command == "pile" and (pile_disks(args) or 0) >= THREADED_PILE_DISKS))


def _ensemble_target(args) -> bool:
    """Whether a `fit` aims at an ensemble target (--truth, a target.json, --resume)."""
    return bool(args.truth or (args.target or "").endswith(".json") or args.resume)


def fit_estimator(args) -> str:
    """The gradient a `fit` uses: `--estimator`, else central differences for an
    ensemble target and the pathwise gradient through one pile otherwise."""
    return args.estimator or ("central" if _ensemble_target(args) else "pathwise")


def fit_runs_batches(args) -> bool:
    """Whether a `fit` runs batches (an ensemble estimator), not the pathwise
    gradient through one pile. The pathwise gradient keeps one thread: on 2
    cores, 1000 steps of the 55-disk pile's checkpointed gradient take 72 ms
    with one thread against 112 ms with two (benchmarks/gradient_cost.py)."""
    return fit_estimator(args) != "pathwise"


def threads_for_batches() -> bool:
    """`sweep` and `fit` run batches, and `pile` may run a large pile: XLA's own
    thread count for them, where `import jaxpile` asked for one thread (see
    `jaxpile`'s docstring: a batch's kernels are large enough to split, one
    small pile's are not). Read when JAX makes its CPU client, so it only acts
    before JAX has run anything; threads do not change results. Returns whether
    it acted."""
    import jaxpile

    if not jaxpile._ONE_THREAD_BY_DEFAULT or os.environ.get("PJRT_NPROC") != "1":
        return False
    del os.environ["PJRT_NPROC"]
    jaxpile._ONE_THREAD_BY_DEFAULT = False
    return True


COMPILE_CACHE_ENV = "JAXPILE_COMPILE_CACHE"
COMPILE_CACHE_MAX_BYTES = 2 * 1024**3


def compile_cache_dir(environ, configured: str | None = None) -> str | None:
    """Where `use_compile_cache` keeps compiled programs: `$JAXPILE_COMPILE_CACHE`,
    else the folder JAX is already configured with (`JAX_COMPILATION_CACHE_DIR`),
    else `$XDG_CACHE_HOME/jaxpile/xla` (`~/.cache/jaxpile/xla`); None when
    `JAXPILE_COMPILE_CACHE` is off, 0, no or false."""
    setting = environ.get(COMPILE_CACHE_ENV, "")
    if setting.lower() in ("0", "off", "no", "false"):
        return None
    if setting:
        return setting
    if configured:
        return configured
    home = environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return os.path.join(home, "jaxpile", "xla")


def use_compile_cache() -> str | None:
    """Keeps XLA's compiled programs on disk between commands (JAX's
    persistent compilation cache), so a command that runs what an earlier one
    compiled starts at once: `jaxpile pile --protocol lattice --layers 12` took
    7.1 s, 2.7 of them compiling; run again, 1.9 s, 0.2 compiling.

    The folder is `compile_cache_dir`'s, at most `COMPILE_CACHE_MAX_BYTES`, the
    least recently used programs evicted first; `JAXPILE_COMPILE_CACHE=off`
    turns it off. Results do not depend on it. Returns the folder, or None
    (off, or not writable: the command runs without)."""
    import jax

    path = compile_cache_dir(os.environ, jax.config.jax_compilation_cache_dir)
    if path is None:
        return None
    if path == jax.config.jax_compilation_cache_dir:
        return path  # JAX's own setting (or the test suite's): as it was set
    try:
        os.makedirs(path, exist_ok=True)
    except OSError:
        return None
    if not os.access(path, os.W_OK | os.X_OK):
        return None
    jax.config.update("jax_compilation_cache_dir", path)
    if "JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS" not in os.environ:
        jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.5)  # the step loops, not small helpers
    if "JAX_COMPILATION_CACHE_MAX_SIZE" not in os.environ and importlib.util.find_spec("filelock"):
        jax.config.update("jax_compilation_cache_max_size", COMPILE_CACHE_MAX_BYTES)  # JAX locks with filelock
    return path


def _run_command(argv: list[str]) -> list[str]:
    """What a checkpoint records to resume from: the command without --resume DIR
    and --no-progress."""
    out, skip = [], False
    for a in argv:
        if skip or a == "--no-progress":
            skip = False
            continue
        if a == "--resume":
            skip = True
            continue
        out.append(a)
    return out


def _resume_point(args) -> tuple[str | None, int]:
    """For --resume DIR: the checkpoint file to hand to the run (DIR/checkpoint.npz;
    a tilt finds its box stage beside it) and the step it resumes at, announced.
    `(None, 0)` for a new run."""
    from jaxpile.engine import checkpoint
    from jaxpile.errors import InputError

    if args.resume is None:
        return None, 0
    saved = checkpoint.in_folder(args.resume)
    if saved is None:
        raise InputError(f"no checkpoint to resume in {args.resume}.")
    meta = checkpoint.read_metadata(saved)
    rows = meta["extra"].get("rows")
    print(f"jaxpile: resuming {args.resume} at step {meta['step']}"
          + ("" if rows is None else f" ({len(rows)} members measured)"), flush=True)
    return os.path.join(args.resume, "checkpoint.npz"), int(meta["step"])


def _trajectory(args, resumed_from: int):
    """The context that records OUT/trajectory.xyz with --trajectory-every (a
    resumed run drops the frames written after its checkpoint and goes on)."""
    import contextlib

    from jaxpile import export
    from jaxpile.errors import InputError

    if args.trajectory_every is None:
        return contextlib.nullcontext()
    if args.trajectory_every < 1:
        raise InputError(f"--trajectory-every must be >= 1 step; got {args.trajectory_every}.")
    os.makedirs(args.out, exist_ok=True)
    return export.trajectory(os.path.join(args.out, _trajectory_name(args)), args.trajectory_every,
                             resume_step=resumed_from if args.resume is not None else None)


def _trajectory_name(args) -> str:
    return "trajectory.lammpstrj" if args.trajectory_format == "lammps" else "trajectory.xyz"


def _checkpoint_spec(args):
    """`(path, every, extra)` for `Simulator.run(checkpoint=...)`, or None."""
    from jaxpile.errors import InputError

    if args.checkpoint_every is None:
        return None
    if args.checkpoint_every < 1:
        raise InputError(f"--checkpoint-every must be >= 1 step; got {args.checkpoint_every}.")
    path = os.path.join(args.out, "checkpoint.npz")
    if args.resume is None:  # a new run: an older run's checkpoints in OUT must not be taken for its own
        from jaxpile.engine import checkpoint

        args.stale_checkpoints = [stale for stale in [path, *checkpoint.stage_files(path)] if os.path.exists(stale)]
    return path, args.checkpoint_every, {"argv": args.argv}


@contextlib.contextmanager
def _replacing_earlier(args):
    """Removes an earlier run's checkpoints in OUT (found by `_checkpoint_spec`)
    when this run starts stepping (its first observed state), not before it: a
    command that fails while setting up leaves the earlier run as it was. A
    batched run is not observed; its end removes them."""
    from jaxpile.engine.simulate import observing

    stale = list(getattr(args, "stale_checkpoints", []))

    def drop(*_):
        while stale:
            path = stale.pop(0)
            if os.path.exists(path):
                print(f"jaxpile: removing {path} of an earlier run in {args.out}", flush=True)
                os.remove(path)

    with observing(drop):
        yield
    drop()


def check_out_folder(out: str, flag: str = "--out") -> None:
    """Refuses, before anything runs, an output folder that cannot be one: a
    path that is a file, lies inside a file, or is not writable. Creates and
    touches nothing: a refused command leaves no folder behind, and the run
    makes its folder when it first writes."""
    from jaxpile.errors import InputError

    path = os.path.abspath(out)
    if os.path.exists(path) and not os.path.isdir(path):
        raise InputError(f"{flag} {out} is a file, not a folder; give a folder (it is created if missing).")
    parent = path
    while not os.path.exists(parent):
        parent = os.path.dirname(parent)
    if not os.path.isdir(parent):
        raise InputError(f"{flag} {out} lies inside {parent}, which is a file; give a folder.")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise InputError(f"{flag} {out}: {parent} is not writable; give a folder you can write to.")


def main(argv=None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    os.environ.setdefault("MPLBACKEND", "Agg")  # figures go to files; never open a window
    from jaxpile.errors import InputError, SimulationError

    try:
        argv = [t for a in argv for t in (a.split("=", 1) if a.startswith("--resume=") else [a])]
        if argv[:1] in (["pile"], ["sweep"]) and "--resume" in argv:
            argv = _resume_argv(argv)
        args = build_parser(argv).parse_args(argv)
        _merge_protocol_flags(args)
        if args.command in ("pile", "sweep"):
            args.argv = _run_command(argv)
            if args.resume is not None:
                args.out = args.resume  # the run goes on where it is now, even if its folder was moved
        _check_flags(args)
        if wants_xla_threads(args):
            threads_for_batches()
        if args.command in ("pile", "sweep", "fit") and "JAXPILE_MULTI_OUTPUT_FUSION" not in os.environ:
            import jaxpile

            jaxpile.use_multi_output_fusion()  # each law once a step (fit's losses: no interp scatters)
        use_compile_cache()
        if getattr(args, "out", None) is not None:
            check_out_folder(args.out)
        if args.command == "pile":
            run_protocol(args)
        elif args.command == "show":
            from jaxpile.cli.show import show

            written = show(args.dir, args.out, checkpoint=args.checkpoint)
            print(f"jaxpile: wrote {args.out or args.dir}/" + ", ".join(written))
        elif args.command == "compare":
            print(compare_table(args.dirs))
        elif args.command == "sweep":
            run_sweep(args)
        elif args.command == "fit":
            run_fit(args)
    except (InputError, SimulationError) as err:
        print(f"jaxpile: error: {err}", file=sys.stderr)
        return 2
    except OSError as err:  # the file system said no mid-run (disk full, a folder removed): one line, not a traceback
        where = f"{err.filename}: " if err.filename else ""
        print(f"jaxpile: error: {where}{err.strerror or err}", file=sys.stderr)
        return 2
    return 0


def run_protocol(args) -> dict:
    """`jaxpile pile --protocol P`: runs the protocol's `run`, then writes the
    files every protocol gets (summary, base forces, contacts, state, XYZ, pile
    and profile figures) and the protocol's own figures."""
    import inspect

    import jax.numpy as jnp

    import jaxpile  # noqa: F401  (turns on float64)
    from jaxpile import export, io
    from jaxpile.measure import analysis
    from jaxpile.errors import InputError
    from jaxpile.laws import get_law_module
    from jaxpile.protocols import PROTOCOLS
    from jaxpile.protocols import options as protocol_options
    from jaxpile.engine.simulate import Simulator

    name = args.protocol
    module = PROTOCOLS[name]
    size_flag = "--layers" if _entry(name).size == "layers" else "--n"
    for flag in ("--n", "--layers"):  # one of them sets the protocol's size, the other is refused
        if flag != size_flag and getattr(args, flag[2:]) is not None:
            owners = [p for p in _protocol_names() if _entry(p).size == flag[2:]]
            raise InputError(f"{flag} is for the {owners[0]} protocol; the {name} protocol's size is {size_flag}."
                             if len(owners) == 1 else f"{flag} is not used by the {name} protocol (its size is "
                             f"{size_flag}).")
    if args.slope is not None and "alpha_degrees" not in inspect.signature(module.run).parameters:
        raise InputError(f"--slope is for the sloped protocol, not {name}.")
    lawmod = get_law_module(args.law or _entry(name).default_law)
    dtype = jnp.float64 if args.precision == "float64" else jnp.float32
    overrides = parse_set(args.set, lawmod.PARAM_NAMES)
    _, contact_law, params = module.law_and_params(lawmod.NAME, overrides, args.rotation, dtype=dtype)

    kwargs = dict(params=params, rotation=args.rotation, integrator=args.integrator, dtype=dtype,
                  progress=False if args.no_progress else None)
    if args.dt is not None:
        kwargs["dt"] = args.dt
    size = args.layers if size_flag == "--layers" else args.n
    if size is not None:
        kwargs[_entry(name).size] = size
    if args.slope is not None:
        kwargs["alpha_degrees"] = args.slope
    flags = {"ramp_steps": args.ramp_steps, "max_steps": args.max_steps, "speed_tol": args.speed_tol,
             "hard_collisions": _parse_hard_collisions(args.hard_collisions),
             "seed": args.seed if args.seed != 0 else None}
    for flag, value in flags.items():
        if value is None:
            continue
        if flag not in _entry(name).flags:
            raise InputError(f"--{flag.replace('_', '-')} is not used by the {name} protocol.")
        keyword, _, key = _entry(name).flags[flag].partition(".")  # "box_options.seed": a key of a dict argument
        if key:
            kwargs.setdefault(keyword, {})[key] = value
        else:
            kwargs[keyword] = value
    options = parse_options(args.option)
    known = protocol_options.accepted(module)
    unknown = set(options) - known
    if unknown:
        raise InputError(f"unknown --option {sorted(unknown)} for the {name} protocol; known: "
                         f"{', '.join(sorted(known))}.")
    kwargs.update(options)
    if args.dry_run:
        return _dry_run_protocol(args, module, kwargs, contact_law)
    kwargs["checkpoint"] = _checkpoint_spec(args)
    kwargs["resume"], resumed_from = _resume_point(args)

    print(f"jaxpile: {name} pile ({_entry(name).help}), law {contact_law.name} "
          f"(rotation {'on' if contact_law.rotation else 'off'}), {args.precision}", flush=True)
    if kwargs.get("hard_collisions") is not None:
        hard = kwargs["hard_collisions"]
        print(f"jaxpile: hard collisions on (restitution {hard.restitution:g}, mu {hard.mu:g})", flush=True)
    t0 = time.perf_counter()
    with _trajectory(args, resumed_from), _replacing_earlier(args):
        state, m = module.run(lawmod.NAME, **kwargs)
    total = time.perf_counter() - t0

    dt = args.dt if args.dt is not None else _protocol_dt(module, m)
    sim = Simulator(contact_law, dt)
    entry = _entry(name)
    base = (analysis.base_forces(sim, params, state) if entry.base_forces is None
            else entry.base_forces(sim, params, state, m))  # e.g. the fixed row a heap stands on
    network = analysis.contact_network(sim, params, state)
    p = state.particles
    active = np.asarray(p.active)
    run = m.get("run", m)
    steps, wall = int(run.get("steps", 0)), float(run.get("wall_seconds", 0.0))
    summary = {
        "protocol": name,
        "law": contact_law.name,
        "rotation": bool(contact_law.rotation),
        "params": {k: float(v) for k, v in vars(params).items() if v is not None},
        "dt": dt,
        "integrator": args.integrator,
        "precision": args.precision,
        "seed": args.seed,
        "options": options,
        "n_particles": int(active.sum()),
        "particle_steps_per_second": steps * int(active.sum()) / wall if wall > 0 else None,
        "cli_total_seconds": total,
        "resumed_from_step": resumed_from,
        # a protocol may give its own plain-number summary (pour: the rest are maps and arrays)
        **(plain(m) if entry.summary is None else entry.summary(m)),
    }
    summary["protocol"], summary["law"] = name, contact_law.name
    out = args.out
    os.makedirs(out, exist_ok=True)
    io.write_json(os.path.join(out, "summary.json"), summary)
    io.write_csv(os.path.join(out, "base_forces.csv"),
                 {"x": np.asarray(base.x), "normal": np.asarray(base.normal), "horizontal": np.asarray(base.horizontal)})
    io.save_state(os.path.join(out, "state.npz"), state, law=contact_law.name, params=summary["params"], dt=dt,
                  rotation=summary["rotation"], precision=args.precision, protocol=name)
    export.write_contacts(os.path.join(out, "contacts.csv"), sim, params, state)
    export.write_xyz(os.path.join(out, "final.xyz"), state, time=int(state.step) * dt)
    written = ["summary.json", "base_forces.csv", "contacts.csv", "state.npz", "final.xyz"]
    written += [_trajectory_name(args)] if args.trajectory_every else []
    written += _protocol_figures(name, m, state, base, network, contact_law.name, out)
    print(_headline(name, summary), flush=True)
    print(f"jaxpile: wrote {out}/" + ", ".join(written))
    return summary


_PHASE_STEPS = ("pour_steps", "ramp_steps", "max_steps", "max_settle_steps", "relax_steps")
"""Step counts that are phases of a run (summed for the --dry-run bound)."""


def _dry_run_protocol(args, module, kwargs, contact_law) -> dict:
    """`--dry-run` for a protocol: its set-up function (the box's for a tilt)
    called with the arguments it takes from the run's."""
    import inspect

    from jaxpile import ranges

    name = args.protocol
    # what `run` checks before anything else, every keyword of it (a tilt's rate too, not only its box's options)
    kwargs = ranges.check_all(getattr(module, "OPTION_RANGES", {}), kwargs, module.run)
    setup, extra = module.protocol, {}
    if _entry(name).dry_run_setup is not None:  # e.g. a tilt starts from a box pile: set that up
        setup, extra = _entry(name).dry_run_setup(kwargs)
    accepted = inspect.signature(setup).parameters
    given = {k: v for k, v in {**kwargs, **extra}.items() if k in accepted and k not in ("params", "progress")}
    if "law" in accepted:
        given["law"] = args.law or _entry(name).default_law
    p = setup(**given)
    definition = getattr(module, "DEFINITION", None)
    if getattr(definition, "check", None) is not None and setup is module.protocol:  # what a run refuses at its start
        given_run = {k: v for k, v in kwargs.items() if k in definition.run_options}
        definition.check(p, {**definition.run_options, **given_run})
    from jaxpile.engine.simulate import Simulator

    setting = getattr(module, "SETTING", None) or getattr(module, "PAPER_SETTING", {})
    dt = kwargs.get("dt") or p.info.get("dt") or setting.get("dt")
    if dt is not None:  # the law's parameters and the time step's stability, as the run would check them
        Simulator(contact_law, dt, integrator=args.integrator).check_params(kwargs["params"], p.particles)
    run_defaults = {k: v.default for k, v in inspect.signature(module.run).parameters.items()
                    if k.endswith("steps") and isinstance(v.default, int)}
    steps = {**run_defaults, **{k: v for k, v in kwargs.items() if k.endswith("steps") and isinstance(v, int)}}
    if _entry(name).budget is not None:  # a budget given as a time (max_time), in steps
        steps["max_steps"] = int(_entry(name).budget(kwargs, dict(p.info)))
    return _dry_run_report(f"a {name} pile", p.particles, dict(p.info), args.precision, steps)


def _dry_run_report(what: str, particles, info: dict, precision: str, steps: dict) -> dict:
    """`--dry-run`: the set-up, the memory estimate and the planned steps, printed;
    nothing is run or written."""
    import numpy as np

    from jaxpile import budget

    movable = int(np.sum(np.asarray(particles.active) & ~np.asarray(particles.fixed)))
    total = int(particles.count)
    planned = {k: int(v) for k, v in {**{k: v for k, v in info.items() if k.endswith("steps")}, **steps}.items()
               if isinstance(v, (int, float)) and not isinstance(v, bool)}
    # the phases run one after another; the other step facts (intervals, hold times) are rules inside them
    bound = sum(v for k, v in planned.items() if k in _PHASE_STEPS)
    print(f"jaxpile: dry run of {what}: {total:,} disks ({movable:,} movable at the start), {precision}")
    print(f"jaxpile: {budget.describe(total, precision)}")
    if planned:
        print("jaxpile: steps: " + ", ".join(f"{k} {v:,}" for k, v in planned.items())
              + (f"; at most {bound:,} steps = {bound * total:.3g} particle-steps (a run that comes to rest "
                 "stops sooner)" if bound else ""))
    budget.check(total, precision, what=what)
    return {"dry_run": True, "disks": total, "movable": movable, "estimate_bytes": budget.estimate(total, precision),
            "steps": planned, "particle_steps_bound": bound * total}


def _parse_values(name: str, text: str) -> list[float]:
    from jaxpile.errors import InputError

    parts = text.split(",")
    if parts and not parts[-1].strip():
        parts = parts[:-1]  # a trailing comma is harmless
    if parts and any(not v.strip() for v in parts):  # "0.1,,0.3": a value left out, not skipped in silence
        raise InputError(f"{name} has an empty value between its commas; got {text!r}.")
    try:
        values = [float(v) for v in parts]
    except ValueError:
        raise InputError(f"{name} takes comma-separated numbers (e.g. 0.1,0.2,0.3); got {text!r}.") from None
    if not values:
        raise InputError(f"{name} has no values.")
    return values


def run_sweep(args) -> dict:
    """`jaxpile sweep`: batched protocol runs over a parameter grid and seeds."""
    import jax.numpy as jnp

    import jaxpile  # noqa: F401  (turns on float64)
    from jaxpile import io
    from jaxpile import sweep as sw
    from jaxpile.errors import InputError
    from jaxpile.laws import get_law_module

    law = get_law_module(args.law or sw.adapter(args.protocol).default_law).NAME
    vary = {}
    if args.mu is not None:
        vary["mu"] = _parse_values("--mu", args.mu)
    for item in args.vary or []:
        if "=" not in item:
            raise InputError(f"--vary takes NAME=V1,V2,...; got {item!r}.")
        name, text = (part.strip() for part in item.split("=", 1))
        if name in vary:
            raise InputError(f"{name} is swept twice.")
        vary[name] = _parse_values(f"--vary {name}", text)
    if not vary:
        raise InputError("nothing to sweep: give --mu V1,V2,... or --vary NAME=V1,V2,...")
    if args.seeds < 1:
        raise InputError(f"--seeds must be >= 1; got {args.seeds}.")
    lawmod = get_law_module(law)
    fixed = parse_set(args.set, lawmod.PARAM_NAMES)
    options = parse_options(args.option)
    if args.n is not None:
        options["n"] = args.n
    dtype = jnp.float64 if args.precision == "float64" else jnp.float32
    members = args.seeds * int(np.prod([len(v) for v in vary.values()]))
    print(f"jaxpile: sweep of the {args.protocol} protocol, law {law}: "
          + ", ".join(f"{k} in {v}" for k, v in vary.items()) + f", {args.seeds} seeds: {members} members",
          flush=True)
    if args.dry_run:
        from jaxpile import budget

        a = sw.adapter(args.protocol)
        # every member's parameters and every batch's set-up, as the sweep checks them before it runs
        dt = sw.plan(args.protocol, law, vary=vary, seeds=args.seeds, params=fixed, options=options, dt=args.dt,
                     batch_size=args.batch_size, dtype=dtype).dt
        setup = a.setup(law, 0, dt, {**options, "dtype": dtype})
        batch = members if args.batch_size is None else min(int(args.batch_size), members)
        steps = a.max_steps(setup.info, options) if args.max_steps is None else int(args.max_steps)
        report = _dry_run_report(f"one {args.protocol} member", setup.particles, {}, args.precision,
                                 {"max_steps": steps})
        print(f"jaxpile: a batch of {batch} members: {budget.describe(setup.particles.count, args.precision, batch)}")
        budget.check(setup.particles.count, args.precision, batch=batch, what=f"a batch of the {args.protocol} sweep")
        return {**report, "members": members, "batch": batch}
    resume, _ = _resume_point(args)
    spec = _checkpoint_spec(args)
    with _replacing_earlier(args):
        result = sw.sweep(args.protocol, law, vary=vary, seeds=args.seeds, params=fixed, options=options,
                          dt=args.dt, max_steps=args.max_steps, batch_size=args.batch_size, dtype=dtype,
                          progress=False if args.no_progress else None, checkpoint=spec, resume=resume)
    out = args.out
    os.makedirs(out, exist_ok=True)
    sw.write_csv(os.path.join(out, "sweep.csv"), result)
    by = next(iter(vary))
    summaries = {name: sw.summarise(result, by, name) for name in result.info["angles"]}
    io.write_json(os.path.join(out, "sweep.json"), plain({**result.info, "precision": args.precision,
                                                          "summary_by": by, "summaries": summaries}))
    sw.figure(result, by, path=os.path.join(out, "sweep.png"))
    main_angle = result.info["angles"][0]
    s = summaries[main_angle]
    print(f"jaxpile: {main_angle} against {by} (mean +- standard error over seeds):")
    for x, m, e, c, miss in zip(s["x"], s["mean"], s["stderr"], s["count"], s["missing"]):
        unit = result.info.get("unit", "deg")
        # one pile has no standard error (a deterministic pile needs no more): no "+- nan"
        value = f"{m:.4g}" + (f" +- {e:.2g}" if c > 1 else "") + (f" {unit}" if unit else "")
        print(f"  {by} = {x:g}: {value}  ({c} pile{'s' if c != 1 else ''}"
              + (f", {miss} not measurable)" if miss else ")"))
    print(f"jaxpile: {result.info['members']} members x {result.info['n_particles']} disks, "
          f"{result.info['batch_steps']} batch steps in {result.info['run_seconds']:.1f} s "
          f"(+ {result.info['compile_seconds']:.1f} s compile): "
          f"{result.info['particle_steps_per_second']:.3g} particle-steps/s")
    print(f"jaxpile: wrote {out}/sweep.csv, sweep.json, sweep.png")
    return result.info


def _optimizer(name: str, lr: float):
    import optax

    from jaxpile.errors import InputError

    if not lr > 0:
        raise InputError(f"--lr must be positive; got {lr}.")
    if name == "lbfgs":
        return optax.lbfgs()
    make = getattr(optax, name, None)
    if not callable(make) or name.startswith("_"):
        raise InputError(f"--optimizer {name!r} is not an optax optimiser; try adam, sgd, adamw, rmsprop or lbfgs.")
    try:
        return make(lr)
    except TypeError:
        raise InputError(f"optax.{name} does not take a learning rate; try adam, sgd, adamw, rmsprop or lbfgs.") from None


def fit_problem(protocol: str, law: str, start: dict, *, layers: int = 6, n: int = 60, seed: int = 0,
                options: dict | None = None, bins: int | None = None, window: int = 2000, progress=None):
    """The pile a pathwise fit differentiates: `(sim, params, state, steps, setting, window, description)`,
    from the protocol module's `pathwise_problem` (the lattice: the whole
    quasi-static loading; the pour: `window` steps of relaxation of a heap
    poured with the starting parameters). A protocol without one is refused."""
    module = _pathwise(protocol)
    return module.pathwise_problem(law, start, size=layers if _entry(protocol).size == "layers" else n, seed=seed,
                                   options=options, bins=bins, window=window, progress=progress)


def _pathwise(protocol: str):
    """The protocol module, when it offers a pathwise fit (`pathwise_problem`)."""
    from jaxpile.errors import InputError
    from jaxpile.protocols import PROTOCOLS

    module = PROTOCOLS.get(protocol)
    if module is None or not callable(getattr(module, "pathwise_problem", None)):
        offered = [p for p, m in PROTOCOLS.items() if callable(getattr(m, "pathwise_problem", None))]
        raise InputError(f"pathwise fits run on the {', '.join(offered)} protocols; fit the {protocol} protocol "
                         "with --estimator central or smoothing (an ensemble target: --truth or a target.json).")
    return module


def _dry_run_fit(args, law: str, names: list, start: dict) -> dict:
    """`fit --dry-run`: the pile the fit builds (set up, not run), the parameters
    it fits from their starting values, the memory estimate and the steps."""
    module = _pathwise(args.protocol)
    size = args.layers if _entry(args.protocol).size == "layers" else args.n
    what, particles, params, build, per_step = module.pathwise_dry_run(law, start, size=size, seed=args.seed,
                                                                       options=parse_options(args.option),
                                                                       window=args.window)
    values = ", ".join(f"{n} = {float(getattr(params, n)):g}" for n in names)
    print(f"jaxpile: dry run of a fit of {values} ({law} law) on {what}: {args.steps} optimiser steps, each "
          f"differentiating {per_step:,} steps (a forward and a reverse pass)")
    report = _dry_run_report(what, particles, {}, "float64", build)
    total = args.steps * per_step * int(particles.count)
    print(f"jaxpile: the fit: {args.steps} x {per_step:,} steps = {total:.3g} particle-steps forward "
          "(a gradient costs ~7x its forward pass on a CPU: benchmarks/gradient_cost.py)")
    return {**report, "fit_particle_steps": total}


def run_fit(args) -> dict:
    """`jaxpile fit`: gradient-based fit of law parameters to a base-force
    profile (one pile, pathwise) or to an ensemble target (`ensemble_fit`)."""
    import jax

    from jaxpile.errors import InputError

    ensemble_target = _ensemble_target(args)
    estimator = fit_estimator(args)
    if estimator != "pathwise":
        from jaxpile.cli.ensemble_fit import run_ensemble_fit

        return run_ensemble_fit(args, estimator)
    if ensemble_target:
        raise InputError("--truth, --resume and a target.json are for ensemble fits: use --estimator central or "
                         "smoothing.")
    _pathwise(args.protocol)  # refused here when the protocol offers no pathwise fit
    if args.target is None:
        raise InputError("a pathwise fit needs --target FILE|smid-novosad.")
    args.optimizer = args.optimizer or "adam"
    args.n = 60 if args.n is None else args.n
    args.steps = 40 if args.steps is None else args.steps

    import jaxpile  # noqa: F401  (turns on float64)
    from jaxpile import fit, io
    from jaxpile.errors import InputError, SimulationError
    from jaxpile.laws import get_law_module

    law = get_law_module(args.law or _entry(args.protocol).default_law).NAME
    lawmod = get_law_module(law)
    names = [n.strip() for n in args.params.split(",") if n.strip()]
    if not names:
        raise InputError("--params needs at least one law parameter name (e.g. mu,kt).")
    unknown = set(names) - set(lawmod.PARAM_NAMES)
    if unknown:
        raise InputError(f"cannot fit {sorted(unknown)}: not {law} parameters ({', '.join(lawmod.PARAM_NAMES)}).")
    if args.steps < 0:
        raise InputError(f"--steps must be >= 0; got {args.steps}.")
    if args.target == "smid-novosad":
        target = fit.smid_novosad_target()
    elif os.path.exists(args.target):
        target = fit.load_profile_csv(args.target)  # a folder or unreadable file: one line from there
    else:
        raise InputError(f"--target {args.target!r} is neither smid-novosad nor an existing CSV file.")
    horizontal_weight = args.horizontal_weight if target.horizontal is not None else 0.0
    optimizer = _optimizer(args.optimizer, args.lr)
    start = parse_set(args.set, lawmod.PARAM_NAMES)
    progress = False if args.no_progress else None
    if args.dry_run:
        return _dry_run_fit(args, law, names, start)
    sim, params, state, steps, setting, window, described = fit_problem(
        args.protocol, law, start, layers=args.layers, n=args.n, seed=args.seed, options=parse_options(args.option),
        bins=args.bins, window=args.window, progress=progress)
    print(f"jaxpile: fitting {', '.join(names)} of the {law} law to {target.source or args.target}: {described}",
          flush=True)
    loss = fit.profile_objective(sim, state, steps, setting, target, window=window,
                                 horizontal_weight=horizontal_weight, dip_weight=args.dip_weight)
    profile = jax.jit(lambda p: fit.simulated_profile(sim, p, state, steps, setting, window=window))
    stopped = []

    def stable(record) -> bool:
        """Stops the fit before it steps where dt is above the law's stability limit
        (the rollout would blow up and its gradient turn NaN)."""
        try:
            sim.check_params(params.set(**{n: jnp.asarray(record[n]) for n in names}), state.particles)
        except InputError as err:
            stopped.append(f"stopped at step {record['step']}: {err}")
            return True
        return False

    import warnings

    import jax.numpy as jnp

    t0 = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # its message is in the result and printed below
        result = fit.fit(loss, params, names, optimizer=optimizer, steps=args.steps, progress=progress is None,
                         callback=stable)
    seconds = time.perf_counter() - t0
    if stopped:
        result = result._replace(message=stopped[0] + " Keeping the best parameters before it.")
    before, after = profile(params), profile(result.params)
    # the rollouts are pure (no re-allocation inside): make sure no contact was dropped
    from jaxpile.engine.neighbors import overflowed as lost_contacts

    overflowed = jax.jit(lambda p: lost_contacts(sim.rollout(p, state, steps)))
    for label, p in (("starting", params), ("fitted", result.params)):
        if bool(overflowed(p)):
            raise SimulationError(f"the neighbour list overflowed in the rollout with the {label} parameters, so "
                                  "contacts were missing from it; the fit is not valid. Give the pile more neighbour "
                                  "head-room (a larger capacity_multiplier) and fit again.")

    def values(p):
        return {n: float(getattr(p, n)) for n in names}

    def plain_profile(pr):
        return {"x_over_b": np.asarray(pr.x_over_b).tolist(), "normal": np.asarray(pr.normal).tolist(),
                "horizontal": np.asarray(pr.horizontal).tolist(), "central_dip": float(fit.central_dip(pr))}

    record = {
        "target": target.source or args.target, "protocol": args.protocol, "law": law, "fitted": names,
        "pile": described, "initial": values(params), "fitted_values": values(result.params),
        "initial_loss": result.history[0]["loss"] if result.history else None, "loss": result.loss,
        "best_step": result.best_step, "steps": result.steps, "converged": result.converged,
        "message": result.message, "optimizer": args.optimizer, "lr": args.lr, "fit_seconds": seconds,
        "target_central_dip": target.central_dip,
        "target_profile": {"x_over_b": np.asarray(target.x_over_b).tolist(), "normal": np.asarray(target.normal).tolist(),
                           "horizontal": None if target.horizontal is None else np.asarray(target.horizontal).tolist()},
        "profile_before": plain_profile(before),
        "profile_after": plain_profile(after), "history": result.history,
    }
    out = args.out
    os.makedirs(out, exist_ok=True)
    io.write_json(os.path.join(out, "fit.json"), plain(record))
    fit.fit_figure(result, target, before, after, path=os.path.join(out, "fit.png"))
    print("jaxpile: " + ", ".join(f"{k}: {record['initial'][k]:.4g} -> {v:.4g}" for k, v in
                                  record["fitted_values"].items())
          + f"; loss {record['initial_loss']:.3g} -> {result.loss:.3g} ({result.message})")
    print(f"jaxpile: central dip {record['profile_before']['central_dip']:.3f} -> "
          f"{record['profile_after']['central_dip']:.3f}"
          + (f" (target {target.central_dip:.3f})" if target.central_dip is not None else ""))
    print(f"jaxpile: wrote {out}/fit.json, fit.png")
    return record


def _protocol_dt(module, m) -> float:
    info = m.get("info") or {}
    if "dt" in info:
        return float(info["dt"])
    setting = getattr(module, "SETTING", None) or module.PAPER_SETTING
    return float(setting["dt"])


def _headline(name: str, summary: dict) -> str:
    parts = []
    for key in _entry(name).headline:
        v = summary
        for part in key.split("."):  # dotted keys reach into nested dicts
            v = v.get(part) if isinstance(v, dict) else None
        if v is not None:
            parts.append(f"{key} = {v:.4g}" if isinstance(v, float) else f"{key} = {v}")
    rate = summary.get("particle_steps_per_second")
    timing = f"{rate:.3g} particle-steps/s" if rate else ""
    return "  " + ", ".join(parts) + (f"\n  {timing}" if timing else "")


def _protocol_figures(name, m, state, base, network, law_name, out) -> list:
    """pile.png and profile.png for every protocol, and the protocol's own
    figures (its registry entry's `figures`, `profile_theory`, `length_unit`)."""
    from jaxpile import plot

    entry = _entry(name)
    p = state.particles
    title = f"{name} pile, {law_name} law, {int(np.asarray(p.active).sum())} disks"
    plot.pile_figure(p.position, p.radius, network, active=np.asarray(p.active), title=title,
                     length_unit="diameters" if entry.length_unit is None else entry.length_unit(law_name),
                     path=os.path.join(out, "pile.png"))
    theory_lines = None if entry.profile_theory is None else entry.profile_theory(m, base)
    th_n, th_h, label = theory_lines or (None, None, None)
    plot.base_profile_figure(base.x, base.normal, base.horizontal, theory_normal=th_n, theory_horizontal=th_h,
                             title=title + (f" vs {label}" if label else ""), path=os.path.join(out, "profile.png"))
    written = ["pile.png", "profile.png"]
    for figure in entry.figures:
        written += figure(m, title, out)
    return written


def compare_table(dirs) -> str:
    from jaxpile import io
    from jaxpile.errors import InputError

    rows = []
    for d in dirs:
        path = os.path.join(d, "summary.json")
        if not os.path.isfile(path):
            raise InputError(f"{path} not found: give folders written by 'jaxpile pile --out DIR'.")
        s = io.read_json(path, "a run's summary.json")
        if not isinstance(s, dict):
            raise InputError(f"{path} is not a run's summary (a JSON object).")
        rows.append((d, s))
    head = (f"{'run':32s} {'protocol':>8s} {'law':>12s} {'disks':>6s} {'mu':>5s} {'steps':>8s} {'p-steps/s':>10s}  "
            "result")
    lines = [head, "-" * len(head)]
    for d, s in rows:
        protocol = s.get("protocol", "lattice")  # summaries from before the protocol was recorded
        steps = s.get("steps", (s.get("run") or {}).get("steps", 0))
        rate = s.get("particle_steps_per_second") or 0.0
        mu = s.get("params", {}).get("mu")
        try:  # a summary.json from elsewhere, or cut down, lacks what its protocol's row reads
            entry = _entry(protocol) if isinstance(protocol, str) else None
            if entry is None:
                raise KeyError(f"protocol {protocol!r}")
            result = entry.compare(s) if entry.compare is not None else _headline(protocol, s).strip().splitlines()[0]
            lines.append(f"{d:32s} {protocol:>8s} {s['law']:>12s} {s['n_particles']:6d} "
                         f"{('%5.2f' % mu) if mu is not None else '    -'} {steps:8d} {rate:10.3g}  {result}")
        except (KeyError, TypeError, ValueError, IndexError) as err:
            raise InputError(f"{os.path.join(d, 'summary.json')} is not a finished {protocol} run's summary "
                             f"({type(err).__name__}: {err}); give folders written by 'jaxpile pile --out DIR'."
                             ) from None
    lines.append(
        "dev N, dev H (lattice): largest deviation of the ground forces from Liffman et al. 1992 eqs. 42 and 44.\n"
        "The analytic forces assume frictionless disks at rest; with disk-disk friction the base forces\n"
        "depend on how the pile was loaded (tangential springs lock in shear), so mu > 0 departs from them."
    )
    return "\n".join(lines)


if __name__ == "__main__":
    sys.exit(main())
