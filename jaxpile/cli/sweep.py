"""`jaxpile sweep`: one protocol run in batches over a grid of law parameters
or set-up options and seeds; writes sweep.csv, sweep.json and sweep.png."""

from __future__ import annotations

import os

import numpy as np

from jaxpile.cli.dry_run import dry_run_report
from jaxpile.cli.parsing import law_options_of, parse_options, parse_set
from jaxpile.cli.run_folder import checkpoint_spec, replacing_earlier, resume_point
from jaxpile.errors import InputError
from jaxpile.io import plain


def run_sweep(args) -> dict:
    """`jaxpile sweep`: batched protocol runs over a parameter grid and seeds."""
    import jax.numpy as jnp

    from jaxpile import batches, distributed, io
    from jaxpile import sweeps as sw
    from jaxpile.laws import get_law_module

    law = get_law_module(args.law or batches.spec_of(args.protocol).default_law).NAME
    vary = _grid(args, get_law_module(law).PARAM_NAMES, batches.option_names(batches.spec_of(args.protocol)))
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
        return _dry_run_sweep(args, law, vary, fixed, options, dtype, members)
    resume, _ = resume_point(args)
    spec = checkpoint_spec(args)
    with replacing_earlier(args):
        result = sw.sweep(args.protocol, law, vary=vary, seeds=args.seeds, params=fixed, options=options,
                          dt=args.dt, max_steps=args.max_steps, batch_size=args.batch_size, dtype=dtype,
                          progress=False if args.no_progress else None, checkpoint=spec, resume=resume,
                          rotation=args.rotation, law_options=law_options_of(args))
    if distributed.process_index() != 0:
        return result.info  # process 0 writes the rows every process ran
    out = args.out
    os.makedirs(out, exist_ok=True)
    sw.write_csv(os.path.join(out, "sweep.csv"), result)
    by = next(iter(vary))
    summaries = {name: sw.summarise(result, by, name) for name in result.info["angles"]}
    io.write_json(os.path.join(out, "sweep.json"), plain({**result.info, "precision": args.precision,
                                                          "argv": getattr(args, "argv", None),
                                                          "summary_by": by, "summaries": summaries}))
    sw.figure(result, by, path=os.path.join(out, "sweep.png"))
    _print_summary(result, by, summaries)
    print(f"jaxpile: wrote {out}/sweep.csv, sweep.json, sweep.png")
    return result.info


def _grid(args, law_names=(), option_names=()) -> dict:
    """`{name: values}` swept: `--mu`, then each `--vary NAME=V1,V2,...`. A
    name that is both a law parameter and a set-up option (the baxter law's
    exponent n and a protocol's disk count n) is refused bare: `law.n` says
    which (a sweep varies the law's)."""
    vary = {}
    if args.mu is not None:
        vary["mu"] = _parse_values("--mu", args.mu)
    for item in args.vary or []:
        if "=" not in item:
            raise InputError(f"--vary takes NAME=V1,V2,...; got {item!r}.")
        name, text = (part.strip() for part in item.split("=", 1))
        if name.startswith("law."):
            name = name[len("law."):]
            if name not in law_names:
                raise InputError(f"--vary law.{name}: {name} is not a parameter of the law ({', '.join(law_names)}).")
        elif name in law_names and name in option_names:
            raise InputError(f"--vary {name} names both a law parameter and a set-up option ({name} is also the "
                             f"{args.protocol} protocol's, e.g. its disk count --n): write --vary law.{name}=... to "
                             "sweep the law's.")
        if name in vary:
            raise InputError(f"{name} is swept twice.")
        vary[name] = _parse_values(f"--vary {name}", text)
    if not vary:
        raise InputError("nothing to sweep: give --mu V1,V2,... or --vary NAME=V1,V2,...")
    return vary


def _parse_values(name: str, text: str) -> list[float]:
    """A comma-separated list of numbers (a trailing comma allowed, an empty value refused)."""
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


def _dry_run_sweep(args, law: str, vary: dict, fixed: dict, options: dict, dtype, members: int) -> dict:
    """`sweep --dry-run`: every member's parameters and every batch's set-up
    checked as the sweep checks them before it runs, one member set up, and
    the memory a batch needs."""
    from jaxpile import batches, budget
    from jaxpile.protocols import running

    spec = batches.spec_of(args.protocol)
    planned = batches.plan(args.protocol, law, vary=vary, seeds=args.seeds, params=fixed, options=options, dt=args.dt,
                      batch_size=args.batch_size, dtype=dtype, rotation=args.rotation,
                      law_options=law_options_of(args))
    dt = planned.dt
    first = running.stage_options(spec, options)[0]
    setup = spec.chain()[0].setup(first, law=law, seed=0, dt=dt, dtype=dtype)
    batch = min(planned.batch_size, members)  # of a --distributed sweep (joined by now): the members over the processes
    steps = spec.chain()[0].budget(setup, first) if args.max_steps is None else int(args.max_steps)
    report = dry_run_report(f"one {args.protocol} member", setup.particles, {}, args.precision,
                            {"max_steps": steps})
    print(f"jaxpile: a batch of {batch} members: {budget.describe(setup.particles.count, args.precision, batch)}")
    budget.check(setup.particles.count, args.precision, batch=batch, what=f"a batch of the {args.protocol} sweep")
    return {**report, "members": members, "batch": batch}


def _print_summary(result, by: str, summaries: dict) -> None:
    """The main angle against the first swept parameter, and the run's rate."""
    main_angle = result.info["angles"][0]
    s = summaries[main_angle]
    print(f"jaxpile: {main_angle} against {by} (mean +- standard error over seeds):")
    for x, m, e, c, miss in zip(s["x"], s["mean"], s["stderr"], s["count"], s["missing"]):
        unit = result.info.get("unit", "deg")
        # one pile has no standard error (a deterministic pile needs no more): no "+- nan"
        value = f"{m:.4g}" + (f" +- {e:.2g}" if c > 1 else "") + (f" {unit}" if unit else "")
        print(f"  {by} = {x:g}: {value}  ({c} pile{'s' if c != 1 else ''}"
              + (f", {miss} not measurable)" if miss else ")"))
    print(f"jaxpile: {result.info['members']} members x {result.info['n_particles']} particles, "
          f"{result.info['batch_steps']} batch steps in {result.info['run_seconds']:.1f} s "
          f"(+ {result.info['compile_seconds']:.1f} s compile): "
          f"{result.info['particle_steps_per_second']:.3g} particle-steps/s"
          + (f", since the resume at step {result.info['resumed']['step']}" if "resumed" in result.info else ""))
