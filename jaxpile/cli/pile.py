"""`jaxpile pile --protocol P`: one pile of a registered protocol, from the
command line's flags to the protocol's `run` (or its `--dry-run`); the files it
writes are `pile_outputs`'."""

from __future__ import annotations

import time

from jaxpile.cli.dry_run import dry_run_report
from jaxpile.cli.parsing import parse_options, parse_set
from jaxpile.cli.pile_outputs import trajectory, write_outputs
from jaxpile.cli.run_folder import checkpoint_spec, replacing_earlier, resume_point
from jaxpile.errors import InputError
from jaxpile.protocols import PROTOCOLS, entry


def run_protocol(args) -> dict:
    """`jaxpile pile --protocol P`: runs the protocol's `run`, then writes the
    files every protocol gets (summary, base forces, contacts, state, XYZ, pile
    and profile figures) and the protocol's own figures."""
    import jax.numpy as jnp

    from jaxpile.laws import get_law_module

    name = args.protocol
    module = PROTOCOLS[name]
    size_flag = _size_flag(args, module)
    lawmod = get_law_module(args.law or entry(name).default_law)
    dtype = jnp.float64 if args.precision == "float64" else jnp.float32
    overrides = parse_set(args.set, lawmod.PARAM_NAMES)
    _, contact_law, params = module.law_and_params(lawmod.NAME, overrides, args.rotation, dtype=dtype)
    kwargs = dict(params=params, rotation=args.rotation, integrator=args.integrator, dtype=dtype,
                  progress=False if args.no_progress else None)
    options = _run_keywords(args, module, size_flag, kwargs)
    if args.dry_run:
        return _dry_run_protocol(args, module, kwargs, contact_law)
    kwargs["checkpoint"] = checkpoint_spec(args)
    kwargs["resume"], resumed_from = resume_point(args)

    print(f"jaxpile: {name} pile ({entry(name).help}), law {contact_law.name} "
          f"(rotation {'on' if contact_law.rotation else 'off'}), {args.precision}", flush=True)
    if kwargs.get("hard_collisions") is not None:
        hard = kwargs["hard_collisions"]
        print(f"jaxpile: hard collisions on (restitution {hard.restitution:g}, mu {hard.mu:g})", flush=True)
    t0 = time.perf_counter()
    with trajectory(args, resumed_from), replacing_earlier(args):
        state, m = module.run(lawmod.NAME, **kwargs)
    total = time.perf_counter() - t0
    return write_outputs(args, module, state, m, contact_law, params, options, total, resumed_from)


def _size_flag(args, module) -> str:
    """The flag that sets the protocol's size (`--layers` or `--n`); the other
    one, and `--slope` for a protocol without a slope, are refused."""
    import inspect

    name = args.protocol
    size_flag = "--layers" if entry(name).size == "layers" else "--n"
    for flag in ("--n", "--layers"):  # one of them sets the protocol's size, the other is refused
        if flag != size_flag and getattr(args, flag[2:]) is not None:
            owners = [p for p in PROTOCOLS if entry(p).size == flag[2:]]
            raise InputError(f"{flag} is for the {owners[0]} protocol; the {name} protocol's size is {size_flag}."
                             if len(owners) == 1 else f"{flag} is not used by the {name} protocol (its size is "
                             f"{size_flag}).")
    if args.slope is not None and "alpha_degrees" not in inspect.signature(module.run).parameters:
        raise InputError(f"--slope is for the sloped protocol, not {name}.")
    return size_flag


def _run_keywords(args, module, size_flag: str, kwargs: dict) -> dict:
    """Adds to `kwargs` the keywords of the protocol's `run` that the flags set
    (its size, the slope, the time step, the generic flags the protocol's
    registry entry maps, `--option`s); returns the `--option`s. A flag the
    protocol does not use, or an option it does not know, is refused."""
    from jaxpile.protocols import options as protocol_options

    name = args.protocol
    if args.dt is not None:
        kwargs["dt"] = args.dt
    size = args.layers if size_flag == "--layers" else args.n
    if size is not None:
        kwargs[entry(name).size] = size
    if args.slope is not None:
        kwargs["alpha_degrees"] = args.slope
    flags = {"ramp_steps": args.ramp_steps, "max_steps": args.max_steps, "speed_tol": args.speed_tol,
             "hard_collisions": _parse_hard_collisions(args.hard_collisions),
             "seed": args.seed if args.seed != 0 else None}
    for flag, value in flags.items():
        if value is None:
            continue
        if flag not in entry(name).flags:
            raise InputError(f"--{flag.replace('_', '-')} is not used by the {name} protocol.")
        keyword, _, key = entry(name).flags[flag].partition(".")  # "box_options.seed": a key of a dict argument
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
    return options


def _parse_hard_collisions(text):
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


def _dry_run_protocol(args, module, kwargs, contact_law) -> dict:
    """`--dry-run` for a protocol: its set-up function (the box's for a tilt)
    called with the arguments it takes from the run's."""
    import inspect

    from jaxpile import ranges
    from jaxpile.engine.simulate import Simulator

    name = args.protocol
    # what `run` checks before anything else, every keyword of it (a tilt's rate too, not only its box's options)
    kwargs = ranges.check_all(getattr(module, "OPTION_RANGES", {}), kwargs, module.run)
    setup, extra = module.protocol, {}
    if entry(name).dry_run_setup is not None:  # e.g. a tilt starts from a box pile: set that up
        setup, extra = entry(name).dry_run_setup(kwargs)
    accepted = inspect.signature(setup).parameters
    given = {k: v for k, v in {**kwargs, **extra}.items() if k in accepted and k not in ("params", "progress")}
    if "law" in accepted:
        given["law"] = args.law or entry(name).default_law
    p = setup(**given)
    definition = getattr(module, "DEFINITION", None)
    if getattr(definition, "check", None) is not None and setup is module.protocol:  # what a run refuses at its start
        given_run = {k: v for k, v in kwargs.items() if k in definition.run_options}
        definition.check(p, {**definition.run_options, **given_run})
    setting = getattr(module, "SETTING", None) or getattr(module, "PAPER_SETTING", {})
    dt = kwargs.get("dt") or p.info.get("dt") or setting.get("dt")
    if dt is not None:  # the law's parameters and the time step's stability, as the run would check them
        Simulator(contact_law, dt, integrator=args.integrator).check_params(kwargs["params"], p.particles)
    run_defaults = {k: v.default for k, v in inspect.signature(module.run).parameters.items()
                    if k.endswith("steps") and isinstance(v.default, int)}
    steps = {**run_defaults, **{k: v for k, v in kwargs.items() if k.endswith("steps") and isinstance(v, int)}}
    if entry(name).budget is not None:  # a budget given as a time (max_time), in steps
        steps["max_steps"] = int(entry(name).budget(kwargs, dict(p.info)))
    return dry_run_report(f"a {name} pile", p.particles, dict(p.info), args.precision, steps)
