"""The `jaxpile` argument parser: one sub-parser per command, the flags the
run commands share, and, when the command line names a protocol, that
protocol's own flags (`protocol_flags`)."""

from __future__ import annotations

import argparse

from jaxpile.cli.flag_ranges import add_ranges_to_help, ranges_epilog
from jaxpile.cli.parsing import on_off
from jaxpile.cli.protocol_flags import DEFAULT_PROTOCOL, add_protocol_flags, command_and_protocol
from jaxpile.cli.presentation import listed, presentation
from jaxpile.protocols import PROTOCOLS


class CommandParser(argparse.ArgumentParser):
    """argparse, with its errors in the same one-line form as every other refusal
    (argparse prints the whole usage block first)."""

    def error(self, message):
        self.exit(2, f"jaxpile: error: {message} (see `{self.prog} --help`)\n")


def sweep_protocols() -> list[str]:
    """The registered protocols a sweep and an ensemble fit run: every one."""
    return listed(PROTOCOLS)


def build_parser(argv: list[str] | None = None) -> argparse.ArgumentParser:
    """The parser; with `argv`, its command's parser also has the flags of the
    protocol `argv` names (`add_protocol_flags`)."""
    parser = CommandParser(prog="jaxpile", description="Differentiable 2D granular piles in JAX.")
    sub = parser.add_subparsers(dest="command", required=True)
    runs = {"pile": _pile_parser(sub)}
    _show_parser(sub)
    _compare_parser(sub)
    runs["sweep"] = _sweep_parser(sub)
    runs["fit"] = _fit_parser(sub)
    command, protocol = command_and_protocol(list(argv or []))
    if argv is not None and command in DEFAULT_PROTOCOL:
        add_protocol_flags(runs[command], command, protocol)
    return parser


def _rolling_arg(parser) -> None:
    """`--rolling MODEL`: rolling resistance for hooke, lee-herrmann and baxter
    (`law(rolling=...)`; its parameters by --set: k_roll, gamma_roll, mu_roll)."""
    parser.add_argument("--rolling", default=None, choices=["sds", "constant"],
                        help="rolling resistance (hooke, lee-herrmann, baxter; needs --rotation on where the "
                             "protocol's default is off): sds, LAMMPS's spring-dashpot-slider (--set "
                             "k_roll=... --set mu_roll=... [--set gamma_roll=...]), or constant, a torque "
                             "mu_roll R_eff |F_n| (--set mu_roll=...); docs/rolling_resistance.md")


def _output_args(parser, precision: bool = True) -> None:
    """The flags every run command shares: precision, progress bar, output folder."""
    if precision:
        parser.add_argument("--precision", choices=["float64", "float32"], default="float64")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    parser.add_argument("--out", required=True, help="output folder")


def _pile_parser(sub) -> argparse.ArgumentParser:
    """`jaxpile pile`: one protocol's pile, its size, law, integrator, run and output flags."""
    names = listed(PROTOCOLS)
    pile = sub.add_parser("pile", help="build a pile, relax it, measure its base forces and draw it")
    pile.add_argument("--protocol", default="lattice", choices=names,
                      help="how the pile is built: " + "; ".join(f"{k}: {presentation(k).help}" for k in names))
    pile.add_argument("--layers", type=int, default=None, help="layers of the lattice pile (default 45: 1035 disks)")
    pile.add_argument("--n", type=int, default=None,
                      help="disks (sloped, drop, box, tilt, pour) or insertions (flux); default: the paper's")
    pile.add_argument("--slope", type=float, default=None, metavar="DEG",
                      help="side angle of the sloped pile in degrees (< 60; default 30)")
    pile.add_argument("--option", action="append", metavar="NAME=VALUE",
                      help="a protocol option, e.g. width=4 (box), polydispersity=0.05 (pour) (repeatable)")
    pile.add_argument("--law", default=None,
                      help="contact law: hooke, liffman, lee-herrmann, baxter, or a LAMMPS pair_coeff granular line "
                           "in quotes, e.g. \"hertz/material 1e7 0.3 0.3 tangential mindlin NULL 1.0 0.5\" "
                           "(docs/lammps.md; default: the protocol's paper's law)")
    pile.add_argument("--set", action="append", metavar="NAME=VALUE", help="override a law parameter (repeatable)")
    pile.add_argument("--rotation", type=on_off, default=None, metavar="on|off",
                      help="integrate spins (lattice default: off, as the 1992 static analysis)")
    _rolling_arg(pile)
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
    add_ranges_to_help("pile", pile)
    pile.epilog = ranges_epilog()
    pile.formatter_class = argparse.RawDescriptionHelpFormatter
    return pile


def _show_parser(sub) -> argparse.ArgumentParser:
    show = sub.add_parser("show", help="re-draw the figures of a finished or checkpointed pile run, a sweep or a "
                                       "fit (no re-run)")
    show.add_argument("dir")
    show.add_argument("--out", default=None, help="where to write the figures (default: DIR/shown, beside the run's own)")
    show.add_argument("--checkpoint", action="store_true", help="draw the last checkpoint even if the run finished")
    return show


def _compare_parser(sub) -> argparse.ArgumentParser:
    compare = sub.add_parser("compare", help="print the summaries of finished runs side by side")
    compare.add_argument("dirs", nargs="+")
    return compare


def _sweep_parser(sub) -> argparse.ArgumentParser:
    """`jaxpile sweep`: the grid (--mu, --vary, --seeds), the set-up, batching and output flags."""
    sweep = sub.add_parser("sweep", help="run a protocol over a grid of law parameters and seeds, batched")
    sweep.add_argument("--protocol", default="box", choices=sweep_protocols(),
                       help="every registered protocol (lattice and sloped are deterministic: vary the law)")
    sweep.add_argument("--law", default=None, help="contact law, or a LAMMPS pair_coeff granular line in quotes "
                       "(default: the protocol paper's)")
    sweep.add_argument("--mu", default=None, metavar="V1,V2,...", help="friction coefficients to sweep")
    sweep.add_argument("--vary", action="append", metavar="NAME=V1,V2,...",
                       help="another law parameter, or a set-up option of the protocol (--vary orifice=4,6,8 "
                            "for the hopper), to sweep (repeatable; the grid is the product); law.NAME for a law "
                            "parameter that shares an option's name (the baxter law's n in a pour: law.n)")
    sweep.add_argument("--seeds", type=int, default=4, help="random piles per grid point (seeds 0..N-1)")
    sweep.add_argument("--n", type=int, default=None, help="disks per pile (default: the protocol's)")
    sweep.add_argument("--option", action="append", metavar="NAME=VALUE", help="a set-up option (repeatable)")
    sweep.add_argument("--set", action="append", metavar="NAME=VALUE", help="a fixed law parameter (repeatable)")
    sweep.add_argument("--rotation", type=on_off, default=None, metavar="on|off",
                       help="integrate spins (default: the protocol's)")
    _rolling_arg(sweep)
    sweep.add_argument("--dt", type=float, default=None, help="time step (default: the protocol's)")
    sweep.add_argument("--max-steps", type=int, default=None, help="step budget per batch")
    sweep.add_argument("--batch-size", type=int, default=None, help="members per compiled batch (default: all)")
    sweep.add_argument("--checkpoint-every", type=int, default=None, metavar="STEPS",
                       help="save the running batch and the rows so far to OUT/checkpoint.npz every STEPS steps")
    sweep.add_argument("--resume", default=None, metavar="DIR",
                       help="continue the sweep saved in DIR (`jaxpile sweep --resume DIR`)")
    sweep.add_argument("--distributed", action="store_true",
                       help="run as one of several processes (jax.distributed; JAXPILE_COORDINATOR, "
                            "JAXPILE_PROCESSES and JAXPILE_PROCESS_ID, or SLURM / Open MPI): each runs its share of "
                            "the batches (default batch: the members over the processes), process 0 writes OUT")
    sweep.add_argument("--dry-run", action="store_true",
                       help="print the members, one member's set-up, the batch's memory estimate and the steps; "
                            "run nothing")
    _output_args(sweep)
    add_ranges_to_help("sweep", sweep)
    return sweep


def _fit_parser(sub) -> argparse.ArgumentParser:
    """`jaxpile fit`: the target and estimator, the ensemble fits' flags (`_ensemble_fit_args`),
    the law and pile, the optimiser and the loss."""
    fitp = sub.add_parser("fit", help="fit law parameters to a target base-force profile or to an ensemble's "
                                      "statistics (gradients + optax, or Gauss-Newton on ensemble means)")
    fitp.add_argument("--target", default=None, metavar="FILE|smid-novosad",
                      help="what to fit to: a measurement (a CSV base profile: x/B, normal/max or normal/weight, "
                           "optionally stderr, horizontal/max, horizontal_stderr; or a .json/.toml of scalars "
                           "such as angle_of_repose with their errors, and a profile: docs/calibrate.md), whose "
                           "points the ensemble mean of the protocol's piles is read at; smid-novosad (the "
                           "declared dip 0.25, with --statistics dip_below_flanks,repose_mean the angle 32.6 deg "
                           "too); or a target.json written by an ensemble fit. On the deterministic lattice a CSV "
                           "or smid-novosad is fitted through one pile (pathwise) unless --estimator says otherwise")
    fitp.add_argument("--protocol", default="lattice", choices=sweep_protocols(),
                      help="the pile; pathwise fits: the deterministic lattice; ensemble fits: every protocol")
    fitp.add_argument("--estimator", default=None, choices=["pathwise", "central", "smoothing", "truncated"],
                      help="the gradient: pathwise through one pile (default on the lattice with a CSV or "
                           "smid-novosad), or of the ensemble-mean loss by central differences (the default "
                           "otherwise), "
                           "Gaussian smoothing with antithetic pairs, or the pathwise gradient through the pour's "
                           "construction truncated to windows of --truncation-window steps (the base profile "
                           "alone; measured biased on 40-disk heaps: docs/fitting.md)")
    _ensemble_fit_args(fitp)
    fitp.add_argument("--law", default=None, help="contact law, or a LAMMPS pair_coeff granular line in quotes "
                      "(default: the protocol paper's)")
    fitp.add_argument("--params", required=True, metavar="NAME,NAME", help="the law parameters to fit")
    fitp.add_argument("--set", action="append", metavar="NAME=VALUE", help="a starting/fixed law parameter")
    fitp.add_argument("--rotation", type=on_off, default=None, metavar="on|off",
                      help="ensemble fits: integrate spins (default: the protocol's)")
    _rolling_arg(fitp)
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
    add_ranges_to_help("fit", fitp)
    return fitp


def _ensemble_fit_args(fitp) -> None:
    """The flags of `jaxpile fit` that only the ensemble estimators read."""
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
    fitp.add_argument("--normalised-by", default=None, choices=["max", "weight"],
                      help="a measured profile's scale when its header says neither (normal/max, normal/weight): "
                           "by its largest value, or per unit x/B by the pile's weight")
    fitp.add_argument("--fit-anyway", action="store_true",
                      help="ensemble fits: fit even when the first pass finds a parameter the target cannot "
                           "identify at this size (said, not refused)")
    fitp.add_argument("--statistics", default=None, metavar="COLUMN,COLUMN",
                      help="ensemble fits: the per-pile measurements compared (default: the protocol's); with "
                           "--bins, the base profile too")
    fitp.add_argument("--resume", action="store_true",
                      help="ensemble fits: continue the fit whose history is in OUT/fit_checkpoint.json (and the "
                           "batch of piles in OUT/fit_batch.npz, where one was saved)")
    fitp.add_argument("--checkpoint-every", type=int, default=None, metavar="STEPS",
                      help="ensemble fits: save the running batch of piles to OUT/fit_batch.npz every STEPS steps, "
                           "so that --resume continues an iteration that did not finish")
    fitp.add_argument("--batch-size", type=int, default=None, metavar="PILES",
                      help="ensemble fits: piles per compiled batch (default: an iteration's piles at once; "
                           "--distributed: one batch a process)")
    fitp.add_argument("--distributed", action="store_true",
                      help="ensemble fits: run as one of several processes (jax.distributed, as `jaxpile sweep "
                           "--distributed`): each runs its share of an iteration's batches, process 0 writes OUT")
