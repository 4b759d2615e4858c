"""A protocol declared once: `Definition` holds its set-up,
simulator, law and parameters, finish, step budget and measurements; `run`
takes one pile from set-up to its end (`runner.run_to_finish`: samples,
checkpoints, bit-identical resume) and `adapter` gives a sweep and an ensemble
fit the same set-up, finish, budget and measurements per member of a batch.
Every registered protocol is written this way: the box, the flux, the
hopper, the pour and the drop (the pour and the drop with their own `execute`
and `report`), the 1992 lattice and sloped piles (`loaded_pile.definition_of`),
and the tilt, which continues another protocol's pile (`starts_from`): one
run builds the pile, then continues it, each stage checkpointed and
resumable; a batch runs the two as stages. See README, "adding a protocol in
one file"."""

from __future__ import annotations

import inspect
import os
import time
from dataclasses import dataclass, field
from typing import Callable

from jaxpile.protocols.adapter import Adapter, Stage
from jaxpile.protocols.base import Setup
from jaxpile.protocols.options import option_names
from jaxpile.protocols.runner import run_record, run_to_finish


@dataclass(frozen=True)
class Definition:
    """A protocol as data plus functions: what one pile's `run`,
    a sweep's batch (`adapter`) and an ensemble fit all need, declared once.
    A protocol declares one and gets both from `run` and `adapter`.

    Attributes:
      name: the protocol's registered name.
      setup: the module's set-up, `setup(size, *, law?, seed?, dt?, dtype?, **options) -> Setup`
        (it gets `law`, `seed`, `dt` and `dtype` where it takes them; the size by its keyword).
      size: the set-up's size keyword (`n`, `insertions`, `layers`): a sweep's `--n`.
      simulator: `(law, *, dt, rotation, integrator, chunk_steps, **kwargs) -> Simulator`;
        one that takes `setup_options` gets the set-up's options (no seed),
        one that takes `run_options` the run options (the 1992 piles' ramp).
      law_and_params: the module's `(law, params, rotation, dtype) -> (module, law, params)`.
      default_dt: `law -> dt` when none is given.
      run_options: run keywords that are not set-up options, with their
        defaults (`max_time`): `finished`, `max_steps` and `measure` read them.
      finished: `(setup info, run options) -> (state -> bool)`, traceable.
      max_steps: `(setup info, run options) -> int`, the step budget.
      measure: `(sim, params, state, protocol, run options) -> dict`: what a run
        reports (plain numbers, lists for the figures).
      row: the keys of `measure` a sweep row carries, or `measured -> row`.
      sweep: the rest of the sweep's `Adapter` (angles, theory, unit,
        default_law, extent, fit_statistics, simulator_options, ...).
      execute: optional `(sim, params, p, run options, *, progress,
        checkpoint, resume) -> (state, RunInfo, samples or None)`: how one
        pile runs when its own stop rule is not `finished` checked at each
        chunk's end (the pour: a loading phase of fixed length, then a run to
        rest checked from there; a batch still uses `finished`).
      report: optional `(measured, protocol, run options, RunInfo, samples,
        seconds) -> dict`: one pile's whole output, when it is not the
        default `{"protocol", **measured, "kinetic_energy", **run_record, "info"}`.
      starts_from: the definition whose end state this protocol continues,
        contact history kept (the tilt: a box pile); `setup` then takes that
        state first, `setup(pile, *, law, dt, **options)`, and `run` builds
        the pile first unless it is given one. Such a protocol runs by
        `continue_pile` with the default output: no `execute` or `report`.
      check: optional `(set-up, run options) -> None`: raises `InputError`
        when the run options cannot work with this set-up, checked before a
        run or a batch starts (the pour: a voidage map too fine to fit in memory).
      pile_facts: with `starts_from`, optional `(pile state, set-up) -> dict`
        of what the pile was when this protocol took it over (the tilt: its
        angle of repose), merged into the set-up's `info`.
      check_options: with `starts_from`, optional `(**set-up options) -> None`:
        raises `InputError` on this protocol's own options, checked before
        the pile it continues is built (a run, each batch of a sweep), so a
        bad tilt rate is not found only after the box piles have run.
    """

    name: str
    setup: Callable
    simulator: Callable
    law_and_params: Callable
    default_dt: Callable
    finished: Callable
    max_steps: Callable
    measure: Callable
    row: tuple | Callable
    run_options: dict = field(default_factory=dict)
    size: str = "n"
    sweep: dict = field(default_factory=dict)
    execute: Callable | None = None
    report: Callable | None = None
    check: Callable | None = None
    starts_from: "Definition | None" = None
    pile_facts: Callable | None = None
    check_options: Callable | None = None

    def __post_init__(self):
        if self.starts_from is not None and (self.execute is not None or self.report is not None):
            raise TypeError(f"{self.name}: a protocol that continues another's pile runs by continue_pile; "
                            "it takes no execute or report hook.")

    def _setup(self, size, law, **kwargs) -> Setup:
        taken = inspect.signature(self.setup).parameters
        if "law" in taken:
            kwargs["law"] = law
        for name in ("seed", "dt", "dtype"):  # what the runner hands every set-up; a deterministic pile takes no seed
            if name not in taken:
                kwargs.pop(name, None)
        if self.size != "n" and self.size in kwargs:  # a sweep may name the size by the set-up's keyword (`layers`)
            if size is not None:
                from jaxpile.errors import InputError

                raise InputError(f"give the {self.name} pile's size once: n or {self.size}, not both.")
            size = kwargs.pop(self.size)
        return self.setup(**{self.size: size}, **kwargs) if size is not None else self.setup(**kwargs)


def run(definition: Definition, law, size=None, *, params=None, rotation: bool | None = None,
        dt: float | None = None, integrator: str = "velocity_verlet", chunk_steps: int | None = None,
        progress=False, dtype=None, checkpoint=None, resume=None, run_options: dict | None = None,
        simulator_options: dict | None = None, pile=None, pile_params=None, pile_options: dict | None = None,
        **options):
    """One pile of `definition` from set-up to its end (`run_to_finish`:
    samples, checkpoint, resume bit-identical; or the definition's own
    `execute`) and its measurements.

    A definition that `starts_from` another continues `pile` (a state), or
    first builds one with that definition (`size`, `pile_params` (default
    `params`), `pile_options`: its set-up and run options), saved beside
    `checkpoint` (`checkpoint.sibling(path, its name)`); `resume` then takes a
    save of either stage (`continued_stages`).

    Returns:
      `(state, measurements)`: `{"protocol": name, **measure(...),
      "kinetic_energy": samples, **run_record, "info": set-up info}`, or the
      definition's `report`; a continued protocol that built its pile adds
      the pile's measurements under the pile protocol's name.
    """
    d = definition
    if d.starts_from is not None:
        return _run_continued(d, law, size, params=params, pile=pile, pile_params=pile_params,
                              pile_options=pile_options, rotation=rotation, dt=dt, integrator=integrator,
                              chunk_steps=chunk_steps, progress=progress, dtype=dtype, checkpoint=checkpoint,
                              resume=resume, run_options=run_options, simulator_options=simulator_options,
                              options=options)
    if pile is not None or pile_params is not None or pile_options:
        from jaxpile.errors import InputError

        raise InputError(f"the {d.name} protocol builds its own pile: pile, pile_params and pile_options are for a "
                         "protocol that continues another's.")
    run_options = _run_options(d, run_options)
    _, _, params = d.law_and_params(law, params, rotation, dtype)
    p = d._setup(size, law, dt=dt, dtype=dtype, **options)
    if d.check is not None:
        d.check(p, run_options)
    sim_options = dict(simulator_options or {})
    if chunk_steps is not None:
        sim_options["chunk_steps"] = chunk_steps
    if _takes_setup_options(d):  # a simulator whose driver is built from the set-up's constants (the drop's)
        sim_options["setup_options"] = {k: v for k, v in options.items() if k != "seed"}
    if _takes(d.simulator, "run_options"):  # a schedule built from run options (the 1992 piles' gravity ramp)
        sim_options["run_options"] = run_options
    dt = p.info.get("dt", d.default_dt(law) if dt is None else dt)  # the set-up's, where it records one
    sim = d.simulator(law, dt=dt, rotation=rotation, integrator=integrator, **sim_options)
    t0 = time.perf_counter()
    if d.execute is None:
        state, info, samples = execute(d, sim, params, p, progress=progress, checkpoint=checkpoint, resume=resume,
                                       run_options=run_options)
    else:
        state, info, samples = d.execute(sim, params, p, run_options, progress=progress, checkpoint=checkpoint,
                                         resume=resume)
    seconds = time.perf_counter() - t0
    measured = d.measure(sim, params, state, p, run_options)
    if d.report is not None:
        return state, d.report(measured, p, run_options, info, samples, seconds)
    return state, {"protocol": d.name, **measured, "kinetic_energy": samples, **run_record(info, t0),
                   "info": dict(p.info)}


def execute(definition: Definition, sim, params, p: Setup, *, max_steps: int | None = None, progress=None,
            checkpoint=None, resume=None, run_options: dict | None = None):
    """Runs the set-up `p` until `definition.finished` (checked after each
    chunk) or its step budget (`max_steps`, default `definition.max_steps`).
    Returns `(state, RunInfo, samples)` as `run_sampled`."""
    run_options = _run_options(definition, run_options)
    done = definition.finished(p.info, run_options)
    budget = definition.max_steps(p.info, run_options) if max_steps is None else max_steps
    return run_to_finish(sim, params, p, max_steps=budget, finished=lambda s: bool(done(s)), progress=progress,
                         checkpoint=checkpoint, resume=resume)


def _run_continued(d: Definition, law, size, *, params, pile, pile_params, pile_options, rotation, dt, integrator,
                   chunk_steps, progress, dtype, checkpoint, resume, run_options, simulator_options, options):
    """`run` of a definition that continues another's pile (see `run`)."""
    from jaxpile.engine import checkpoint as ckpt

    base = d.starts_from
    run_options = _run_options(d, run_options)
    _, _, stage_params = d.law_and_params(law, params, rotation, dtype)
    if d.check_options is not None:  # before the pile is built
        d.check_options(**options, **({} if dt is None else {"dt": dt}))
    built = None
    if pile is None:
        pile_file = None if checkpoint is None else ckpt.sibling(checkpoint[0], base.name)
        pile_resume, resume = continued_stages(d, resume)
        given = dict(pile_options or {})
        pile, built = run(base, law, size, params=params if pile_params is None else pile_params, rotation=rotation,
                          dt=dt, integrator=integrator, chunk_steps=chunk_steps, progress=progress, dtype=dtype,
                          checkpoint=ckpt.with_facts(checkpoint, path=pile_file, stage=base.name),
                          resume=pile_resume, run_options={k: v for k, v in given.items() if k in base.run_options},
                          **{k: v for k, v in given.items() if k not in base.run_options})
        if checkpoint is not None:  # each save of this stage names the pile it started from (the last pile save)
            checkpoint = ckpt.with_facts(checkpoint, pile_checkpoint=os.path.basename(
                pile_file.replace("{step}", str(int(pile.step)))))
    p = on_pile(d, pile, law, dt, options, run_options)
    sim_options = dict(simulator_options or {})
    if chunk_steps is not None:
        sim_options["chunk_steps"] = chunk_steps
    if _takes(d.simulator, "run_options"):
        sim_options["run_options"] = run_options
    sim = d.simulator(law, dt=p.info["dt"], rotation=rotation, integrator=integrator, **sim_options)
    t0 = time.perf_counter()
    state, info, samples = continue_pile(d, sim, stage_params, p, pile, run_options=run_options, progress=progress,
                                         checkpoint=checkpoint, resume=resume)
    measured = d.measure(sim, stage_params, state, p, run_options)
    out = {"protocol": d.name, **measured, "kinetic_energy": samples, **run_record(info, t0), "info": dict(p.info)}
    if built is not None:
        out[base.name] = {k: v for k, v in built.items() if k != "kinetic_energy"}
    return state, out


def on_pile(d: Definition, pile, law, dt, options: dict, run_options: dict, *, facts: bool = True) -> Setup:
    """The set-up of `d` on the state `pile`, its run options checked (`check`),
    with the pile's facts (`pile_facts`) in its info unless `facts` is False
    (a batch adds them as its stage's `describe`)."""
    p = d.setup(pile, law=law, dt=dt, **options)
    if d.check is not None:
        d.check(p, run_options)
    return p if d.pile_facts is None or not facts else p._replace(info={**p.info, **d.pile_facts(pile, p)})


def continue_pile(d: Definition, sim, params, p: Setup, pile=None, *, run_options: dict | None = None,
                  progress=None, checkpoint=None, resume=None):
    """Runs the set-up `p` of a continued protocol from `pile`, the state it
    was built on (contact history kept; None: `p.particles` with a fresh
    history), until `d.finished` or its budget, counted from the pile's last
    step. Each save records `stage=d.name`; `resume` continues such a save.

    Returns:
      `(state, RunInfo, samples)` as `run_sampled`.
    """
    from jaxpile.protocols import runner
    from jaxpile.engine import checkpoint as ckpt
    from jaxpile.errors import InputError

    run_options = _run_options(d, run_options)
    runner.check_dt(sim, p)
    start = int(p.info["start_step"])
    if pile is None:
        state = sim.init(params, p.particles, p.boundaries, box=p.box, protocol_state=p.protocol_state)
    else:
        if int(pile.step) != start or pile.particles.count != p.info["n"]:
            raise InputError(f"pile is not the state this {d.name} protocol was built from.")
        state = pile.set(protocol_state=p.protocol_state)
    samples = None
    if resume is not None:
        state, samples = runner.restore_sampled(resume, state, sim, params)
    done = d.finished(p.info, run_options)
    budget = d.max_steps(p.info, run_options) - (int(state.step) - start)
    return runner.run_sampled(sim, params, state, max_steps=budget, finished=lambda s: bool(done(s)),
                              progress=progress, checkpoint=ckpt.with_facts(checkpoint, stage=d.name), samples=samples)


def continued_stages(d: Definition, resume) -> tuple[str | None, str | None]:
    """`(pile run's checkpoint, this stage's checkpoint)` to resume a continued
    protocol that builds its own pile from `resume`: a save of this stage
    (which names its pile's file), a save of the pile's run, or this stage's
    fixed path when the run stopped before the stage began (then only its
    `checkpoint.sibling(resume, pile name)` exists)."""
    from jaxpile.engine import checkpoint as ckpt
    from jaxpile.errors import InputError

    base = d.starts_from.name
    if resume is None:
        return None, None
    if not os.path.exists(resume):
        sibling = ckpt.sibling(resume, base)
        if not os.path.exists(sibling):
            raise InputError(f"resuming a {d.name} that builds its own pile needs the {base} run's checkpoint "
                             f"{sibling} (or the {d.name}'s {resume}); neither is there.")
        return sibling, None
    extra = ckpt.read_metadata(resume)["extra"]
    if extra.get("stage") == base:
        return resume, None
    pile = os.path.join(os.path.dirname(resume), extra.get("pile_checkpoint") or "")
    if not extra.get("pile_checkpoint") or not os.path.exists(pile):
        raise InputError(f"{resume} is a {d.name} checkpoint; resuming it needs the pile it started from, the "
                         f"{base} run's last save {pile or '(not recorded)'}, beside it.")
    return pile, resume


def adapter(definition: Definition):
    """The sweep's `Adapter` of `definition`: the same set-up, simulator,
    predicate, budget and measurements as `run`, per member of a batch."""
    d = definition
    if d.starts_from is not None:
        return _continued_adapter(d)

    def setup(law, seed, dt, options):
        kwargs = {k: v for k, v in options.items() if k not in d.run_options}
        size = kwargs.pop("n", None)  # a sweep's --n is the set-up's size, whatever its name
        p = d._setup(size, law, seed=seed, dt=dt, **kwargs)
        if d.check is not None:
            d.check(p, _run_options(d, options))
        if _takes_setup_options(d):  # the batch's simulator carries the driver, built from the same constants
            p = p._replace(driver=None)
        # the member's run options travel with its set-up, for its measurement (e.g. the hopper's beverloo_k)
        return p._replace(info={**p.info, "run_options": _run_options(d, options)})

    def row(sim, params, state, p):
        m = d.measure(sim, params, state, p, p.info["run_options"])
        return d.row(m) if callable(d.row) else {k: m[k] for k in d.row}

    def finished(info, options):
        return d.finished(info, _run_options(d, options))

    def max_steps(info, options):
        return d.max_steps(info, _run_options(d, options))

    extra = dict(d.sweep)
    # the options a sweep takes: the set-up's and the run options (a definition may name fewer)
    options = extra.pop("options", (option_names(d.setup, *d.run_options) - {d.size}) | {"n"})

    def simulator(law, dt, sim_options, setup_options):
        if _takes_setup_options(d):
            sim_options = {**sim_options, "setup_options": {k: v for k, v in setup_options.items()
                                                            if k not in d.run_options and k != "dtype"}}
        if _takes(d.simulator, "run_options"):
            sim_options = {**sim_options, "run_options": _run_options(d, setup_options)}
        return d.simulator(law, dt=dt, **sim_options)

    return Adapter(setup, simulator, finished, max_steps, row, d.law_and_params, d.default_dt, options=options,
                   columns=_columns(d), **extra)


def _continued_adapter(d: Definition):
    """A batch of a continued protocol: the pile's protocol (stage 0, as its
    own adapter), then this one from each member's end state (a `Stage`)."""
    base = adapter(d.starts_from)
    names = option_names(d.setup, *d.run_options) - {"pile", "edge"}  # the stage's; its pile is the member's state

    def setup(law, seed, dt, options):
        if d.check_options is not None:  # the stage's own options, before any member's pile is built
            d.check_options(**{k: v for k, v in options.items() if k in names and k not in d.run_options})
        return base.setup(law, seed, dt, {k: v for k, v in options.items() if k in base.options}
                          | {"dtype": options.get("dtype")})

    def start(law, dt, options, state, p):
        run_options = _run_options(d, options)
        p = on_pile(d, state, law, dt, {k: v for k, v in options.items() if k in names and k not in d.run_options},
                    run_options, facts=False)
        p = p._replace(info={**p.info, "run_options": run_options})  # for the member's measurement
        return state.set(protocol_state=p.protocol_state), p

    def describe(state, p):
        return {} if d.pile_facts is None else d.pile_facts(state, p)

    def row(sim, params, state, p):
        m = d.measure(sim, params, state, p, _run_options(d, p.info.get("run_options")))
        return d.row(m) if callable(d.row) else {k: m[k] for k in d.row}

    def simulator(law, dt, sim_options, setup_options):
        if _takes(d.simulator, "run_options"):
            sim_options = {**sim_options, "run_options": _run_options(d, setup_options)}
        return d.simulator(law, dt=dt, **sim_options)

    def finished(info, options):
        return d.finished(info, _run_options(d, options))

    def max_steps(info, options):
        return d.max_steps(info, _run_options(d, options))

    stage = Stage(simulator, start, finished, max_steps, describe)
    extra = dict(d.sweep)
    options = extra.pop("options", base.options | names)
    return Adapter(setup, base.simulator, base.finished, base.max_steps, row, d.law_and_params, base.default_dt,
                   options=frozenset(options), stages=(stage,), columns=_columns(d), **extra)


def _columns(d: Definition) -> frozenset | None:
    """A row's columns where the definition names them (None: its row is computed)."""
    return None if callable(d.row) else frozenset(d.row)


def _run_options(d: Definition, options: dict | None) -> dict:
    """The definition's run options, overridden by those of `options` (a
    sweep's options also hold set-up ones: those are left out)."""
    return {**d.run_options, **{k: v for k, v in (options or {}).items() if k in d.run_options}}


def _takes_setup_options(d: Definition) -> bool:
    return _takes(d.simulator, "setup_options")


def _takes(function, name: str) -> bool:
    return name in inspect.signature(function).parameters


__all__ = ["Definition", "adapter", "continue_pile", "continued_stages", "execute", "on_pile", "run"]
