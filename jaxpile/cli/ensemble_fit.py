"""`jaxpile fit` with an ensemble target (a measurement, `--truth`, the
declared Smid-Novosad pile or a target.json): the command-line side of
`jaxpile.fit.ensemble_fit`."""

from __future__ import annotations

import os

import numpy as np

from jaxpile.batches import batch_of
from jaxpile.cli.parsing import law_options_of, parse_options, parse_set
from jaxpile.errors import InputError
from jaxpile.io import plain
from jaxpile.ranges import COUNT, POSITIVE


def _statistics(args, spec):
    from jaxpile.fit.ensemble_fit import Statistics

    default = batch_of(spec).fit_statistics
    if args.statistics is not None:
        columns = tuple(c.strip() for c in args.statistics.split(",") if c.strip())
        bins = args.bins or 0
    else:
        columns, bins = tuple(default.get("columns", ())), default.get("bins", 0) if args.bins is None else args.bins
    return Statistics(columns=columns, bins=int(bins))


def _chosen_statistics(args, spec, estimator: str, declared: bool):
    """The statistics the fit compares: the central dip for the declared
    Smid-Novosad target, the base profile alone for the truncated estimator (what
    it can differentiate), else `--statistics`/`--bins` or the protocol's."""
    from jaxpile.fit import ensemble_fit

    if declared and args.statistics is None and args.bins is None:
        return ensemble_fit.Statistics(columns=("central_dip",))
    if estimator == "truncated" and args.statistics is None:
        return ensemble_fit.Statistics(bins=int(args.bins if args.bins is not None
                                                else batch_of(spec).fit_statistics.get("bins") or 9))
    return _statistics(args, spec)


def _measurement(args):
    """The measurement `--target` names (`fit.measured.load_measurement`: a CSV
    profile, or a .json/.toml of scalars and a profile), or None for another
    target (smid-novosad, a target.json an ensemble fit wrote, none)."""
    from jaxpile import io
    from jaxpile.fit import measured

    path = args.target
    if not path or path == "smid-novosad":
        return None
    if not os.path.exists(path):
        raise InputError(f"--target {path!r} is neither smid-novosad nor an existing file (a measurement .csv, "
                         ".json or .toml, or the target.json of an ensemble fit).")
    if path.lower().endswith(".json") and os.path.isfile(path):
        record = io.read_json(path, "a target (a measurement, or the target.json or fit.json of an ensemble fit)")
        if isinstance(record, dict) and ("labels" in record or "target" in record):
            return None  # an ensemble fit's target
    return measured.load_measurement(path, args.normalised_by)


def _values(items, known, flag) -> dict:
    try:
        return parse_set(items, known)
    except InputError as err:
        raise InputError(str(err).replace("--set", flag)) from None


def _fit_inputs(args, spec) -> tuple:
    """`(law, names, start, fixed, options)`: the law, the parameters fitted and
    their starting values (`--set`, else the law's defaults), the law values
    held fixed, and the protocol's options, each checked."""
    from jaxpile import batches
    from jaxpile.laws import get_law_module

    law = get_law_module(args.law or spec.default_law).NAME
    lawmod = get_law_module(law)
    names = [n.strip() for n in args.params.split(",") if n.strip()]
    unknown = set(names) - set(lawmod.PARAM_NAMES)
    if not names or unknown:
        raise InputError(f"--params must name {law} parameters ({', '.join(lawmod.PARAM_NAMES)}); got {args.params!r}.")
    if len(set(names)) != len(names):
        raise InputError(f"--params names a parameter twice; got {args.params!r}.")
    given = _values(args.set, lawmod.PARAM_NAMES, "--set")
    _, _, defaults = spec.law_and_params(law, None, None, None)
    unset = [n for n in names if n not in given and getattr(defaults, n) is None]
    # the law as the flags build it judges every parameter fitted or held: one it does not use is refused
    trial = {**given, **{n: 1.0 for n in unset}}
    _, contact_law, trial_params = spec.law_and_params(law, trial, args.rotation, None, law_options_of(args) or None)
    contact_law.validate(trial_params)
    if unset:
        raise InputError(f"--params {unset[0]}: the {law} law has no default for it; give its start with "
                         f"--set {unset[0]}=VALUE.")
    start = {n: float(given[n]) if n in given else float(np.asarray(getattr(defaults, n))) for n in names}
    fixed = {k: v for k, v in given.items() if k not in names}
    options = parse_options(args.option)
    if args.n is not None:
        options["n"] = args.n
    known = batches.option_names(spec)
    if spec.size == "layers" and "layers" not in options:  # the protocols built in layers (the lattice)
        options["layers"] = args.layers
    unknown = set(options) - known
    if unknown:
        raise InputError(f"unknown option(s) {sorted(unknown)} for the {args.protocol} protocol; known: "
                         f"{sorted(known)}.")
    return law, names, start, fixed, options


def run_ensemble_fit(args, estimator: str) -> dict:
    """Builds the runner, the target (made here from `--truth`, or read from a
    target.json), fits, and writes fit.json, target.json and fit.png to OUT;
    the history goes to OUT/fit_checkpoint.json before the first iteration
    and after every one, the running batch to OUT/fit_batch.npz (a target's
    to OUT/target_batch.npz) every `--checkpoint-every` steps, and `--resume`
    continues from them."""
    from jaxpile import batches, distributed, io
    from jaxpile.fit import ensemble_fit, ensemble_runs
    from jaxpile.laws import get_law_module

    a = batches.spec_of(args.protocol)
    law, names, start, fixed, options = _fit_inputs(args, a)
    runner = ensemble_fit.Runner(args.protocol, law, params=fixed or None, options=options or None,
                                 law_options=law_options_of(args) or None, rotation=args.rotation,
                                 batch_size=args.batch_size)
    smid_novosad = args.target == "smid-novosad"
    declared = smid_novosad and not args.resume  # a resumed fit's target is the one it saved
    if declared and args.truth:
        raise InputError("--target smid-novosad and --truth are two targets: give one.")
    measurement = _measurement(args)
    if measurement is not None:  # it says what each pile must report: its scalars and its profile's points
        if args.truth:
            raise InputError("--target FILE (a measurement) and --truth are two targets: give one.")
        if args.statistics is not None or args.bins is not None:
            raise InputError(f"{args.target} says what is compared (its scalars and its profile's points): leave "
                             "--statistics and --bins out.")
        from jaxpile.fit import measured

        statistics = measured.statistics_of(measurement, a)
    else:  # a resumed fit to the declared pile compares what it compared when it began
        statistics = _chosen_statistics(args, a, estimator, smid_novosad)
    if declared:  # a statistic Smid & Novosad did not report is refused before any pile, dry runs too
        ensemble_fit.smid_novosad_target(statistics.labels())
    b = int(args.ensemble) if args.ensemble is not None else (1 if batch_of(a).deterministic else 8)
    seeds = list(range(b))
    steps = 6 if args.steps is None else int(args.steps)
    if args.checkpoint_every is not None:
        COUNT.check("--checkpoint-every", args.checkpoint_every, scalar=True)
        if args.distributed:
            raise InputError("--checkpoint-every saves one process's batch: a distributed fit resumes from its "
                             "histories, at the end of an iteration (leave --checkpoint-every out).")
    truth = _values(args.truth, get_law_module(law).PARAM_NAMES, "--truth") if args.truth else None
    if truth is not None and set(truth) - set(names):
        raise InputError(f"--truth gives {sorted(set(truth) - set(names))}, which this fit does not fit "
                         f"({', '.join(names)}): the target and the fit would differ in them. Fix them with --set.")
    target_seeds = list(range(args.target_seeds, args.target_seeds + b))
    if truth is not None and set(target_seeds) & set(seeds):
        raise InputError(f"--target-seeds {args.target_seeds} overlaps the fit's seeds 0..{b - 1}: a fit must not "
                         "see the piles its target was made from.")
    runner.check(statistics)
    if estimator == "truncated":
        from jaxpile.fit import construction

        construction.check(runner, statistics)
        COUNT.check("--truncation-window", args.truncation_window, scalar=True)
    # the start, the truth and the set-up, checked before any pile (the target's) is run, and by --dry-run
    for n in names:
        POSITIVE.check(f"the starting {n} (fitted in log space)", start[n], scalar=True)
    for values in (start, truth) if truth else (start,):  # a fitted parameter the law needs is in both
        batches.plan(args.protocol, law, points=[values], seeds=1, params=fixed, options=options,
                   rotation=runner.rotation, law_options=runner.law_options)
    # 8: the smoothing's 4 antithetic pairs; 3: the truncated estimator's host run and two rollouts
    per_iteration = {"central": 2 * len(names) + 1, "truncated": 3}.get(estimator, 8)
    if args.dry_run:
        setup = batches.first_setup(a, law, 0, a.default_dt(law), options)
        print(f"jaxpile: dry run of an ensemble fit of {start} ({law} law, {args.protocol}, "
              f"{setup.particles.count} {'spheres' if setup.particles.dim == 3 else 'disks'} a pile): {b} piles per ensemble, at most {steps} iterations of "
              f"{per_iteration} ensembles ({per_iteration * b} piles in one batch), statistics "
              f"{statistics.labels()}; runs nothing")
        return {"start": start, "statistics": statistics.labels(), "piles_per_iteration": per_iteration * b}
    writes = distributed.process_index() == 0  # of a distributed fit, process 0 writes OUT
    folder = distributed.folder_of(args.out)  # every process keeps its own history (all the same)
    os.makedirs(folder, exist_ok=True)
    checkpoint = os.path.join(folder, "fit_checkpoint.json")
    target_save, fit_save = (os.path.join(folder, f"{k}_batch.npz") for k in ("target", "fit"))
    every = args.checkpoint_every
    if args.resume and every is None:  # the batch a resumed fit left is continued, saved as often as it was
        every = next((b["every"] for b in map(ensemble_runs.saved_batch, (target_save, fit_save)) if b), None)
    if args.resume and truth is not None and not os.path.exists(checkpoint) and os.path.exists(target_save):
        args.resume = False  # stopped while making its target, before the fit began: continue the target
        print(f"jaxpile: resuming the target's piles in {args.out} (stopped before the fit began)", flush=True)
    elif not args.resume and os.path.exists(target_save):
        os.remove(target_save)  # another command's target, stopped: this one makes its own
    target = _target(args, runner, truth, fixed, target_seeds, statistics, declared, checkpoint,
                     None if every is None else (target_save, every), measurement)
    if writes:
        io.write_json(os.path.join(args.out, "target.json"), plain(target.to_json()))
    optimizer = args.optimizer or ("gauss-newton" if estimator == "central" else "adam")
    print(f"jaxpile: fitting {', '.join(names)} of the {law} law on {args.protocol} ensembles of {b} "
          f"({estimator}, {optimizer}) to {target.source}", flush=True)
    result = ensemble_fit.fit(runner, names, start, target, seeds=seeds, statistics=statistics, optimizer=optimizer,
                              lr=args.lr, progress=not args.no_progress,
                              identifiability="warn" if args.fit_anyway else "refuse",
                              gradient=ensemble_fit.Gradient(estimator=estimator, step=args.difference_step,
                                                             window=args.truncation_window),
                              stopping=ensemble_fit.Stopping(steps=steps),
                              saving=ensemble_fit.Saving(checkpoint=checkpoint,
                                                         resume=checkpoint if args.resume else None,
                                                         batch=None if every is None else (fit_save, every)))
    return _write_results(args, names, target, result) if writes else result.to_json()


def _target(args, runner, truth, fixed, target_seeds, statistics, declared: bool, checkpoint: str,
            target_batch=None, measurement=None):
    """The `EnsembleTarget`: the one saved in OUT/fit_checkpoint.json (`--resume`),
    made here at `--truth` from `target_seeds` (its batch saved to and
    continued from `target_batch`, `(path, every)`), the declared Smid-Novosad one,
    the `measurement`'s, or read from `--target target.json`."""
    from jaxpile import io
    from jaxpile.fit import ensemble_fit

    if args.resume:
        if not os.path.exists(checkpoint):
            raise InputError(f"--resume: {checkpoint} does not exist (no ensemble fit was saved in {args.out}).")
        saved = io.read_json(checkpoint, "an ensemble fit's checkpoint")
        history = saved.get("history") if isinstance(saved, dict) else None
        if isinstance(history, list):
            last = history[-1].get("values") if history and isinstance(history[-1], dict) else None
            done = f"after {len(history)} iteration(s)" + (f", last at {last}" if last else "") if history else \
                "before its first iteration ended"
            print(f"jaxpile: resuming the fit in {args.out} {done}", flush=True)
        return ensemble_fit.EnsembleTarget.from_json(saved.get("target") if isinstance(saved, dict) else None,
                                                     f"the target in {checkpoint}")
    if truth is not None:
        print(f"jaxpile: making the target: {len(target_seeds)} {args.protocol} piles at {truth} (seeds "
              f"{target_seeds[0]}..{target_seeds[-1]})", flush=True)
        return ensemble_fit.make_target(runner._replace(params={**fixed, **truth} if fixed else None), truth,
                                        target_seeds, statistics, progress=False, batch_checkpoint=target_batch)
    if declared:
        return ensemble_fit.smid_novosad_target(statistics.labels())
    if measurement is not None:
        from jaxpile.fit import measured

        return measured.target_of(measurement, statistics)
    if args.target and args.target.endswith(".json"):
        if not os.path.exists(args.target):
            raise InputError(f"--target {args.target}: no such file.")
        record = io.read_json(args.target, "a target (target.json or fit.json of an ensemble fit)")
        return ensemble_fit.EnsembleTarget.from_json(record.get("target", record) if isinstance(record, dict)
                                                     else record, args.target)
    raise InputError("an ensemble fit needs a target: --target FILE (a measurement: a CSV profile, or a .json/.toml "
                     "of scalars), --target smid-novosad, --target target.json, or --truth NAME=VALUE.")


def _write_results(args, names: list, target, result) -> dict:
    """Writes fit.json and fit.png to OUT and prints each fitted value with its
    95 % interval (and the regression through every ensemble, where there is one)."""
    from jaxpile import io
    from jaxpile.fit import ensemble_fit, verdict

    record = result.to_json()
    io.write_json(os.path.join(args.out, "target.json"), plain(result.target.to_json()))  # its errors measured
    if target.truth:
        record["truth_inside_interval"] = {n: bool(lo <= target.truth[n] <= hi)
                                           for n, (lo, hi) in result.interval.items() if n in target.truth}
    io.write_json(os.path.join(args.out, "fit.json"), plain(record))
    ensemble_fit.figure(result, path=os.path.join(args.out, "fit.png"))
    judged = result.record["verdict"]
    if args.no_progress:  # else the fit printed them as it went
        report = result.record["first_pass"].get("report")
        for line in verdict.first_pass_lines(report) if report else []:
            print(f"first pass: {line}")
        for line in verdict.verdict_lines(judged):
            print(f"verdict: {line}")
    trust = "" if judged["interval_trusted"] else " (not to be trusted: see the verdict)"
    for n in names:
        lo, hi = result.interval[n]
        truth = f" (truth {target.truth[n]:.5g})" if target.truth and n in target.truth else ""
        print(f"jaxpile: {n} = {result.values[n]:.5g}, 95% interval [{lo:.5g}, {hi:.5g}]{truth}{trust}")
    line = result.record.get("regression")
    if line is not None:  # in a chaotic protocol the honest one (jaxpile.fit.regression)
        print("jaxpile: through all " + f"{line['points']} ensembles: " + ", ".join(
            f"{n} = {line['values'][n]:.5g} [{line['interval'][n][0]:.5g}, {line['interval'][n][1]:.5g}]"
            for n in names))
    print(f"jaxpile: wrote {args.out}/fit.json, target.json, fit.png")
    return record
