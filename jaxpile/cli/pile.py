"""`jaxpile pile --protocol P`: one pile of a registered protocol, from the
command line's flags to the protocol spec's run (or its `--dry-run`); the files it
writes are `pile_outputs`'."""

from __future__ import annotations

import time

from jaxpile.cli.dry_run import dry_run_report
from jaxpile.cli.parsing import hard_collisions_of, law_options_of, parse_options, parse_set
from jaxpile.cli.pile_outputs import trajectory, write_outputs
from jaxpile.cli.run_folder import checkpoint_spec, replacing_earlier, resume_point
from jaxpile.errors import InputError
from jaxpile.cli.presentation import listed, presentation
from jaxpile.protocols import PROTOCOLS


def run_protocol(args) -> dict:
    """`jaxpile pile --protocol P`: runs the protocol's spec, then writes the
    files every protocol gets (summary, base forces, contacts, state, XYZ, pile
    and profile figures) and the protocol's own figures."""
    import jax.numpy as jnp

    from jaxpile.laws import get_law_module

    name = args.protocol
    spec = PROTOCOLS[name]
    size_flag = _size_flag(args, spec)
    lawmod = get_law_module(args.law or spec.default_law)
    dtype = jnp.float64 if args.precision == "float64" else jnp.float32
    overrides = parse_set(args.set, lawmod.PARAM_NAMES)
    law_options = law_options_of(args)
    _, contact_law, params = spec.law_and_params(lawmod.NAME, overrides, args.rotation, dtype, law_options)
    kwargs = dict(params=params, rotation=args.rotation, integrator=args.integrator, dtype=dtype,
                  progress=False if args.no_progress else None, law_options=law_options)
    options = _run_keywords(args, spec, size_flag, kwargs)
    if args.dry_run:
        return _dry_run_protocol(args, spec, kwargs, contact_law)
    kwargs["checkpoint"] = checkpoint_spec(args)
    kwargs["resume"], resumed_from = resume_point(args)

    print(f"jaxpile: {name} pile ({presentation(name).help}), law {contact_law.name} "
          f"(rotation {'on' if contact_law.rotation else 'off'}), {args.precision}", flush=True)
    if kwargs.get("hard_collisions") is not None:
        hard = kwargs["hard_collisions"]
        print(f"jaxpile: hard collisions on (restitution {hard.restitution:g}, mu {hard.mu:g})", flush=True)
    t0 = time.perf_counter()
    with trajectory(args, resumed_from), replacing_earlier(args):
        state, m = spec.run(lawmod.NAME, **_split_stages(spec, kwargs))
    total = time.perf_counter() - t0
    return write_outputs(args, spec, state, m, contact_law, params, options, total, resumed_from)


def _size_flag(args, spec) -> str:
    """The flag that sets the protocol's size (`--layers` or `--n`); the other
    one, and `--slope` for a protocol without a slope, are refused."""
    name = args.protocol
    size_flag = "--layers" if spec.size == "layers" else "--n"
    for flag in ("--n", "--layers"):  # one of them sets the protocol's size, the other is refused
        if flag != size_flag and getattr(args, flag[2:]) is not None:
            owners = [p for p in listed(PROTOCOLS) if PROTOCOLS[p].size == flag[2:]]
            raise InputError(f"{flag} is for the {owners[0]} protocol; the {name} protocol's size is {size_flag}."
                             if len(owners) == 1 else f"{flag} is not used by the {name} protocol (its size is "
                             f"{size_flag}).")
    if args.slope is not None and "alpha_degrees" not in spec.options.names():
        raise InputError(f"--slope is for the sloped protocol, not {name}.")
    return size_flag


def _run_keywords(args, spec, size_flag: str, kwargs: dict) -> dict:
    """Adds to `kwargs` the keywords of the protocol's run that the flags set
    (its size, the slope, the time step, the generic flags the protocol's
    presentation maps, `--option`s); returns the `--option`s. A flag the
    protocol does not use, or an option it does not know, is refused."""
    from jaxpile.batches import option_names

    name = args.protocol
    if args.dt is not None:
        kwargs["dt"] = args.dt
    size = args.layers if size_flag == "--layers" else args.n
    if size is not None:
        kwargs[spec.chain()[0].size] = size
    if args.slope is not None:
        kwargs["alpha_degrees"] = args.slope
    flags = {"ramp_steps": args.ramp_steps, "max_steps": args.max_steps, "speed_tol": args.speed_tol,
             "hard_collisions": hard_collisions_of(args.hard_collisions),
             "seed": args.seed if args.seed != 0 else None}
    for flag, value in flags.items():
        if value is None:
            continue
        if flag not in presentation(spec.name).flags:
            raise InputError(f"--{flag.replace('_', '-')} is not used by the {name} protocol.")
        kwargs[presentation(spec.name).flags[flag]] = value
    options = parse_options(args.option)
    known = option_names(spec) - {"n"}
    unknown = set(options) - known
    if unknown:
        raise InputError(f"unknown --option {sorted(unknown)} for the {name} protocol; known: "
                         f"{', '.join(sorted(known))}.")
    kwargs.update(options)
    return options


_RUN_KEYWORDS = frozenset({"params", "rotation", "integrator", "dtype", "progress", "dt", "seed", "checkpoint",
                           "resume", "law_options"})


def _split_stages(spec, kwargs: dict) -> dict:
    """`spec.run`'s keywords: for a protocol that continues another's pile (the
    tilt), the options only the pile's protocol has go to `pile_options` (a
    name both have goes to both, as in a sweep)."""
    if spec.starts_from is None:
        return kwargs
    own = set(spec.options.names())
    base = set(spec.starts_from.options.names()) | {spec.starts_from.size}
    out = {k: v for k, v in kwargs.items() if k in _RUN_KEYWORDS or k in own}
    pile = {k: v for k, v in kwargs.items() if k in base and k not in _RUN_KEYWORDS}
    return {**out, "pile_options": pile} if pile else out


def _dry_run_protocol(args, spec, kwargs, contact_law) -> dict:
    """`--dry-run` for a protocol: the set-up of its first stage (the box's
    for a tilt), every stage's options checked, the law's parameters and the
    time step's stability checked, as the run would check them."""
    from jaxpile.engine.simulate import Simulator

    name = args.protocol
    law = args.law or spec.default_law
    split = _split_stages(spec, kwargs)
    given = {k: v for k, v in split.items() if k not in _RUN_KEYWORDS and k != "pile_options"}
    options = spec.make_options(given)  # a tilt's own options, before its pile is set up
    first = spec.chain()[0]
    first_options = first.make_options(split.get("pile_options", {})) if spec.starts_from is not None else options
    dt = kwargs.get("dt") or first.default_dt(law)
    p = first.setup(first_options, law=law, seed=kwargs.get("seed", 0), dt=dt, dtype=kwargs.get("dtype"))
    Simulator(contact_law, p.info.get("dt", dt), integrator=args.integrator).check_params(kwargs["params"],
                                                                                         p.particles)
    steps = {"max_steps": int(first.budget(p, first_options))}
    return dry_run_report(f"a {name} pile", p.particles, dict(p.info), args.precision, steps)
