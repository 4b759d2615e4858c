"""A protocol declared once (issue 18): `Definition` holds its set-up,
simulator, law and parameters, finish, step budget and measurements; `run`
takes one pile from set-up to its end (`runner.run_to_finish`: samples,
checkpoints, bit-identical resume) and `adapter` gives a sweep and an ensemble
fit the same set-up, finish, budget and measurements per member of a batch.
The box, the flux, the hopper, the pour and the drop are written this way
(the pour and the drop with their own `execute` and `report`); see README,
"adding a protocol in one file"."""

from __future__ import annotations

import inspect
import time
from dataclasses import dataclass, field
from typing import Callable

from jaxpile.protocols.base import Protocol
from jaxpile.runner import run_record, run_to_finish


@dataclass(frozen=True)
class Definition:
    """A protocol as data plus functions (issue 18): what one pile's `run`,
    a sweep's batch (`adapter`) and an ensemble fit all need, declared once.
    A protocol declares one and gets both from `run` and `adapter`.

    Attributes:
      name: the protocol's registered name.
      setup: the module's set-up, `setup(size, *, law?, seed, dt, dtype, **options) -> Protocol`.
      size: the set-up's size keyword (`n`, `insertions`): a sweep's `--n`.
      simulator: `(law, *, dt, rotation, integrator, chunk_steps, **kwargs) -> Simulator`;
        one that takes `setup_options` gets the set-up's options (no seed).
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

    def _setup(self, size, law, **kwargs) -> Protocol:
        if "law" in inspect.signature(self.setup).parameters:
            kwargs["law"] = law
        return self.setup(size, **kwargs) if size is not None else self.setup(**kwargs)


def run(definition: Definition, law, size=None, *, params=None, rotation: bool | None = None,
        dt: float | None = None, integrator: str = "velocity_verlet", chunk_steps: int | None = None,
        progress=False, dtype=None, checkpoint=None, resume=None, run_options: dict | None = None,
        simulator_options: dict | None = None, **options):
    """One pile of `definition` from set-up to its end (`run_to_finish`:
    samples, checkpoint, resume bit-identical; or the definition's own
    `execute`) and its measurements.

    Returns:
      `(state, measurements)`: `{"protocol": name, **measure(...),
      "kinetic_energy": samples, **run_record, "info": set-up info}`, or the
      definition's `report`.
    """
    d = definition
    run_options = _run_options(d, run_options)
    _, _, params = d.law_and_params(law, params, rotation, dtype)
    p = d._setup(size, law, dt=dt, dtype=dtype, **options)
    sim_options = dict(simulator_options or {})
    if chunk_steps is not None:
        sim_options["chunk_steps"] = chunk_steps
    if _takes_setup_options(d):  # a simulator whose driver is built from the set-up's constants (the drop's)
        sim_options["setup_options"] = {k: v for k, v in options.items() if k != "seed"}
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


def execute(definition: Definition, sim, params, p: Protocol, *, max_steps: int | None = None, progress=None,
            checkpoint=None, resume=None, run_options: dict | None = None):
    """Runs the set-up `p` until `definition.finished` (checked after each
    chunk) or its step budget (`max_steps`, default `definition.max_steps`).
    Returns `(state, RunInfo, samples)` as `run_sampled`."""
    run_options = _run_options(definition, run_options)
    done = definition.finished(p.info, run_options)
    budget = definition.max_steps(p.info, run_options) if max_steps is None else max_steps
    return run_to_finish(sim, params, p, max_steps=budget, finished=lambda s: bool(done(s)), progress=progress,
                         checkpoint=checkpoint, resume=resume)


def adapter(definition: Definition):
    """The sweep's `Adapter` of `definition`: the same set-up, simulator,
    predicate, budget and measurements as `run`, per member of a batch."""
    from jaxpile.sweep import Adapter, option_names

    d = definition

    def setup(law, seed, dt, options):
        kwargs = {k: v for k, v in options.items() if k not in d.run_options}
        size = kwargs.pop("n", None)  # a sweep's --n is the set-up's size, whatever its name
        p = d._setup(size, law, seed=seed, dt=dt, **kwargs)
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
        return d.simulator(law, dt=dt, **sim_options)

    return Adapter(setup, simulator, finished, max_steps, row, d.law_and_params, d.default_dt, options=options,
                   **extra)


def _run_options(d: Definition, options: dict | None) -> dict:
    """The definition's run options, overridden by those of `options` (a
    sweep's options also hold set-up ones: those are left out)."""
    return {**d.run_options, **{k: v for k, v in (options or {}).items() if k in d.run_options}}


def _takes_setup_options(d: Definition) -> bool:
    return "setup_options" in inspect.signature(d.simulator).parameters


__all__ = ["Definition", "adapter", "execute", "run"]
