"""`jaxpile fit`: which gradient a fit takes (`fit_estimator`), and the
pathwise fit, the gradient through one pile to a base-force profile (a CSV or
the Smid-Novosad features); writes fit.json and fit.png. The ensemble
estimators are `ensemble_fit`'s."""

from __future__ import annotations

import os

import numpy as np

from jaxpile import config
from jaxpile.cli.dry_run import dry_run_report
from jaxpile.cli.parsing import parse_options, parse_set
from jaxpile.errors import InputError
from jaxpile.io import plain
from jaxpile.protocols import PROTOCOLS


def _ensemble_target(args) -> bool:
    """Whether a `fit` aims at an ensemble target (--truth, a .json/.toml target
    or measurement, --resume)."""
    return bool(args.truth or (args.target or "").lower().endswith((".json", ".toml")) or args.resume)


def fit_estimator(args) -> str:
    """The gradient a `fit` uses: `--estimator`; else the pathwise gradient
    through one pile for a profile (a CSV, smid-novosad) on a protocol that
    offers one (its piles deterministic), and central differences of the
    ensemble mean otherwise."""
    spec = PROTOCOLS.get(args.protocol)
    from jaxpile.fit.problem import PATHWISE

    pathwise = spec is not None and args.protocol in PATHWISE and not _ensemble_target(args)
    return args.estimator or ("pathwise" if pathwise else "central")


def fit_runs_batches(args) -> bool:
    """Whether a `fit` runs batches (an ensemble estimator), not the pathwise
    gradient through one pile, which is faster on one XLA thread
    (docs/choices.md, "The command line")."""
    return fit_estimator(args) != "pathwise"


def run_fit(args) -> dict:
    """`jaxpile fit`: gradient-based fit of law parameters to a base-force
    profile (one pile, pathwise) or to an ensemble target (`ensemble_fit`)."""
    estimator = fit_estimator(args)
    if estimator != "pathwise":
        from jaxpile.cli.ensemble_fit import run_ensemble_fit

        return run_ensemble_fit(args, estimator)
    if _ensemble_target(args):
        raise InputError("--truth, --resume and a .json/.toml target are for ensemble fits: use --estimator "
                         "central or smoothing.")
    _pathwise(args.protocol)  # refused here when the protocol offers no pathwise fit
    if args.checkpoint_every is not None:
        raise InputError("--checkpoint-every saves an ensemble fit's batches of piles: a pathwise fit runs one pile "
                         "(use --estimator central or smoothing).")
    if args.fit_anyway:
        raise InputError("--fit-anyway overrides an ensemble fit's first pass: a pathwise fit has none.")
    if args.rolling is not None or args.rotation is not None:
        raise InputError("a pathwise fit builds its pile with the protocol's own law readings: --rolling and "
                         "--rotation are for ensemble fits (--estimator central or smoothing).")
    if args.target is None:
        raise InputError("a pathwise fit needs --target FILE|smid-novosad.")
    args.optimizer = args.optimizer or "adam"
    args.n = 60 if args.n is None else args.n
    args.steps = 40 if args.steps is None else args.steps
    law, names, target, optimizer, start = _pathwise_inputs(args)
    if args.dry_run:
        return _dry_run_fit(args, law, names, start)
    return _fit_one_pile(args, law, names, target, optimizer, start)


def _pathwise(protocol: str):
    """The protocol's pathwise fit, or the refusal that names the ensemble estimators' flags."""
    from jaxpile.fit.problem import pathwise_of

    return pathwise_of(protocol, f"jaxpile fit --protocol {protocol} --target FILE --estimator central "
                                 "--ensemble 8 (the ensemble mean of its piles fitted to the measurement)")


def _pathwise_inputs(args) -> tuple:
    """`(law, names, target, optimizer, start)` of a pathwise fit, each checked."""
    from jaxpile import fit
    from jaxpile.laws import get_law_module

    law = get_law_module(args.law or PROTOCOLS[args.protocol].default_law).NAME
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
        target = fit.smid_novosad_profile()
    elif os.path.exists(args.target):
        from jaxpile.fit.pile_fit import pathwise_target

        # a folder, an unreadable file: one line there
        target = pathwise_target(fit.load_profile_csv(args.target, args.normalised_by), args.target)
    else:
        raise InputError(f"--target {args.target!r} is neither smid-novosad nor an existing CSV file.")
    optimizer = _optimizer(args.optimizer, args.lr)
    start = parse_set(args.set, lawmod.PARAM_NAMES)
    # the starting values the fit takes logs of, checked before any pile is built (a dry run too)
    fit.to_unconstrained(PROTOCOLS[args.protocol].law_and_params(law, start)[2], names)
    return law, names, target, optimizer, start


def _optimizer(name: str, lr: float):
    """The optax optimiser `--optimizer` names, at learning rate `lr`."""
    import optax

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


def _dry_run_fit(args, law: str, names: list, start: dict) -> dict:
    """`fit --dry-run`: the pile the fit builds (set up, not run), the parameters
    it fits from their starting values, the memory estimate and the steps."""
    pathwise = _pathwise(args.protocol)
    size = args.layers if PROTOCOLS[args.protocol].size == "layers" else args.n
    what, particles, params, build, per_step = pathwise.dry_run(law, start, size=size, seed=args.seed,
                                                                options=parse_options(args.option),
                                                                window=args.window)
    values = ", ".join(f"{n} = {float(getattr(params, n)):g}" for n in names)
    print(f"jaxpile: dry run of a fit of {values} ({law} law) on {what}: {args.steps} optimiser steps, each "
          f"differentiating {per_step:,} steps (a forward and a reverse pass)")
    report = dry_run_report(what, particles, {}, "float64", build)
    total = args.steps * per_step * int(particles.count)
    print(f"jaxpile: the fit: {args.steps} x {per_step:,} steps = {total:.3g} particle-steps forward "
          "(a gradient costs ~7x its forward pass on a CPU: benchmarks/gradient_cost.py)")
    return {**report, "fit_particle_steps": total}


def _fit_one_pile(args, law: str, names: list, target, optimizer, start: dict) -> dict:
    """Builds the pile, fits `names` from `start` through it (`fit.pile_fit`),
    and writes fit.json and fit.png."""
    from jaxpile.fit.pile_fit import fit_pile

    def announce(described):
        print(f"jaxpile: fitting {', '.join(names)} of the {law} law to {target.source or args.target}: {described}",
              flush=True)

    size = args.layers if PROTOCOLS[args.protocol].size == "layers" else args.n
    done = fit_pile(args.protocol, law, names, start, target, optimizer, steps=args.steps, size=size,
                    seed=args.seed, options=parse_options(args.option), bins=args.bins, window=args.window,
                    horizontal_weight=args.horizontal_weight, dip_weight=args.dip_weight,
                    progress=False if args.no_progress else None, announce=announce)
    record = _fit_record(args, law, names, done.described, target, done.result.initial_params, done.result,
                         done.seconds, done.before, done.after)
    _write_fit(args.out, record, done.result, target, done.before, done.after)
    return record


def _fit_record(args, law, names, described, target, params, result, seconds, before, after) -> dict:
    """fit.json's record: the set-up, the values before and after, the history
    and the profiles (target, before, after)."""
    from jaxpile import fit
    from jaxpile.laws import granular

    def values(p):
        return {n: float(getattr(p, n)) for n in names}

    def plain_profile(pr):
        return {"x_over_b": np.asarray(pr.x_over_b).tolist(), "normal": np.asarray(pr.normal).tolist(),
                "horizontal": np.asarray(pr.horizontal).tolist(), "central_dip": float(fit.dip_below_peak(pr))}

    return {
        "target": target.source or args.target, "protocol": args.protocol, "law": law, "fitted": names,
        "pile": described, "initial": values(params), "fitted_values": values(result.params),
        "initial_loss": result.history[0]["loss"] if result.history else None, "loss": result.loss,
        "best_step": result.best_step, "steps": result.steps, "converged": result.converged,
        "message": result.message, "optimizer": args.optimizer, "lr": args.lr, "fit_seconds": seconds,
        "settings": config.settings(),  # float64 and XLA's (jaxpile.config)
        "target_central_dip": target.central_dip,
        "target_profile": {"x_over_b": np.asarray(target.x_over_b).tolist(), "normal": np.asarray(target.normal).tolist(),
                           "horizontal": None if target.horizontal is None else np.asarray(target.horizontal).tolist()},
        "profile_before": plain_profile(before),
        "profile_after": plain_profile(after), "history": result.history,
        **({"lammps_pair_coeff": line} if (line := granular.line_at(law, vars(result.params))) else {}),
    }


def _write_fit(out: str, record: dict, result, target, before, after) -> None:
    """Writes fit.json and fit.png to `out` and prints the fitted values, the loss and the central dip."""
    from jaxpile import fit, io

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
