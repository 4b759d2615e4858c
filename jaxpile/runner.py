"""Running a protocol's set-up to its end: the part every protocol shares.

`start` builds a `Protocol`'s first state (or restores a checkpoint of the
same run), `run_sampled` runs it until a host predicate holds, sampling the
kinetic energy once per chunk and saving the samples with each checkpoint, and
`run_to_finish` is the two together with the budget check: a protocol whose
end its driver records (the box's final rest, the hopper's stop) is run by
`run_to_finish(sim, params, p, max_steps=..., finished=...)`. `run_record`
gives the steps and timings every protocol reports.
"""

from __future__ import annotations

import inspect
import time
from dataclasses import dataclass, field
from typing import Callable

import jax
import jax.numpy as jnp

from jaxpile.errors import InputError
from jaxpile.protocols.base import Protocol
from jaxpile.engine.simulate import max_speed
from jaxpile.engine.state import SimState


def run_record(info, t0: float) -> dict:
    """Steps and timings of a run, for the measurements dict."""
    return {
        "steps": info.steps,
        "wall_seconds": info.wall_seconds,
        "compile_seconds": info.compile_seconds,
        "total_seconds": time.perf_counter() - t0,
        "neighbor_reallocations": info.reallocations,
    }


def _sample(state: SimState):
    """(step, kinetic energy per movable disk, max_speed): `analysis.mean_kinetic_energy` on device."""
    p = state.particles
    energy = 0.5 * p.mass * jnp.sum(p.velocity**2, -1) + 0.5 * p.inertia * p.angular_velocity**2
    count = jnp.maximum(jnp.sum(p.movable), 1)
    return state.step, jnp.sum(jnp.where(p.movable, energy, 0.0)) / count, max_speed(state)


_sample_jit = jax.jit(_sample)


def run_sampled(sim, params, state: SimState, *, max_steps: int, finished, progress=None, checkpoint=None,
                samples: dict | None = None):
    """Runs `state` until the host predicate `finished(state)` holds (checked
    after each chunk) or `max_steps`, sampling once per chunk.

    Args:
      checkpoint: `(path, every[, extra])` as in `Simulator.run`; the samples so
        far are saved with each checkpoint (under `extra["samples"]`).
      samples: the samples of the run so far, when `state` is a resumed
        checkpoint (its `extra["samples"]`): continued, and nothing is run if
        the resumed state is already finished.

    Returns:
      (state, RunInfo, samples): samples is a dict of per-chunk lists `step`,
      `time`, `kinetic_energy` (per movable disk, `analysis.mean_kinetic_energy`;
      Fig. 1(b)) and `max_speed`, starting with the run's first state.
    """
    from jaxpile.engine import checkpoint as ckpt
    from jaxpile.engine.simulate import RunInfo

    if int(max_steps) != max_steps or max_steps < 0 or (max_steps == 0 and samples is None):
        raise InputError(f"max_steps must be a whole number >= 1; got {max_steps!r}.")
    resumed = samples is not None
    samples = {k: list(v) for k, v in samples.items()} if resumed else {
        "step": [], "time": [], "kinetic_energy": [], "max_speed": []}

    def sample(s: SimState) -> None:
        step, energy, speed = (x.item() for x in _sample_jit(s))
        samples["step"].append(int(step))
        samples["time"].append(int(step) * sim.dt)
        samples["kinetic_energy"].append(float(energy))
        samples["max_speed"].append(float(speed))

    def stop(s: SimState) -> bool:
        sample(s)
        return bool(finished(s))

    if not resumed:
        sample(state)
    info = RunInfo()
    info._n = state.particles.count
    if not (resumed and finished(state)):
        # the samples dict is written as it stands at each save: always up to date
        state = sim.run(params, state, int(max_steps), progress=progress, info=info, until=stop,
                        checkpoint=ckpt.with_facts(checkpoint, samples=samples))
    info.max_speed = float(max_speed(state))
    info.at_rest = bool(finished(state))
    return state, info, samples


def check_dt(sim, p: Protocol) -> None:
    """InputError unless the simulator steps with the dt the protocol was set up for."""
    if abs(sim.dt - p.info["dt"]) > 1e-12 * p.info["dt"]:
        raise InputError(f"the protocol was set up for dt = {p.info['dt']:g} but the simulator uses "
                         f"dt = {sim.dt:g}; pass the same dt to both.")


def start(sim, params, p: Protocol, resume=None) -> tuple[SimState, dict | None]:
    """The protocol's first state, or with `resume` (a checkpoint file of this
    same run) the state saved there, with the samples saved beside it."""
    check_dt(sim, p)
    state = sim.init(params, p.particles, p.boundaries, box=p.box, protocol_state=p.protocol_state)
    return (state, None) if resume is None else restore_sampled(resume, state, sim, params)


def restore_sampled(resume, template: SimState, sim, params) -> tuple[SimState, dict]:
    """The state a sampled run (`run_sampled`) saved in `resume`, rebuilt on
    `template` (`checkpoint.restore`), and the samples saved with it."""
    from jaxpile.engine import checkpoint as ckpt

    state = ckpt.restore(resume, template, sim.law, params)
    samples = ckpt.read_metadata(resume)["extra"].get("samples")
    if samples is None:
        raise InputError(f"{resume} does not hold a sampled protocol run (no samples recorded with it).")
    return state, samples


def run_to_finish(sim, params, p: Protocol, *, max_steps: int, finished, progress=None, checkpoint=None,
                  resume=None, budget_name: str = "max_time"):
    """Starts `p` (or resumes it) and runs it until the host predicate
    `finished(state)` holds (checked after each chunk) or `max_steps` in all.

    Args:
      checkpoint: `(path, every[, extra])` as in `Simulator.run`.
      resume: a checkpoint file of this same run to continue from: the run
        ends bit-identical to the uninterrupted one, samples included.
      budget_name: the option that set `max_steps`, for the message when a
        resumed file is past it.

    Returns:
      (state, RunInfo, samples) as `run_sampled`.
    """
    state, samples = start(sim, params, p, resume)
    if int(state.step) > max_steps:
        raise InputError(f"{resume} is at step {int(state.step)}, past this run's budget of {max_steps} steps: "
                         f"resume with the budget ({budget_name}) it was written with.")
    return run_sampled(sim, params, state, max_steps=max_steps - int(state.step), progress=progress,
                       finished=finished, checkpoint=checkpoint, samples=samples)


# ------------------------------------------------------------ one definition
@dataclass(frozen=True)
class Definition:
    """A protocol as data plus functions (issue 18): what one pile's `run`,
    a sweep's batch (`adapter`) and an ensemble fit all need, declared once.
    A protocol whose run ends when a traceable predicate holds (the box, the
    flux, the hopper) declares one and gets both from `run` and `adapter`.

    Attributes:
      name: the protocol's registered name.
      setup: the module's set-up, `setup(size, *, law?, seed, dt, dtype, **options) -> Protocol`.
      size: the set-up's size keyword (`n`, `insertions`): a sweep's `--n`.
      simulator: `(law, *, dt, rotation, integrator, chunk_steps, **kwargs) -> Simulator`.
      law_and_params: the module's `(law, params, rotation, dtype) -> (module, law, params)`.
      default_dt: `law -> dt` when none is given.
      run_options: run keywords that are not set-up options, with their
        defaults (`max_time`): `finished`, `max_steps` and `measure` read them.
      finished: `(setup info, run options) -> (state -> bool)`, traceable.
      max_steps: `(setup info, run options) -> int`, the step budget.
      measure: `(sim, params, state, protocol, run options) -> dict`: what a run
        reports (plain numbers, lists for the figures).
      row: the keys of `measure` a sweep row carries.
      sweep: the rest of the sweep's `Adapter` (angles, theory, unit,
        default_law, extent, fit_statistics, simulator_options, ...).
    """

    name: str
    setup: Callable
    simulator: Callable
    law_and_params: Callable
    default_dt: Callable
    finished: Callable
    max_steps: Callable
    measure: Callable
    row: tuple
    run_options: dict = field(default_factory=dict)
    size: str = "n"
    sweep: dict = field(default_factory=dict)

    def _setup(self, size, law, **kwargs) -> Protocol:
        if "law" in inspect.signature(self.setup).parameters:
            kwargs["law"] = law
        return self.setup(size, **kwargs) if size is not None else self.setup(**kwargs)


def run(definition: Definition, law, size=None, *, params=None, rotation: bool | None = None,
        dt: float | None = None, integrator: str = "velocity_verlet", chunk_steps: int | None = None,
        progress=False, dtype=None, checkpoint=None, resume=None, run_options: dict | None = None, **options):
    """One pile of `definition` from set-up to its end (`run_to_finish`:
    samples, checkpoint, resume bit-identical) and its measurements.

    Returns:
      `(state, measurements)`: `{"protocol": name, **measure(...),
      "kinetic_energy": samples, **run_record, "info": set-up info}`.
    """
    run_options = {**definition.run_options, **(run_options or {})}
    _, _, params = definition.law_and_params(law, params, rotation, dtype)
    p = definition._setup(size, law, dt=dt, dtype=dtype, **options)
    sim = definition.simulator(law, dt=p.info["dt"], rotation=rotation, integrator=integrator, chunk_steps=chunk_steps)
    t0 = time.perf_counter()
    state, info, samples = execute(definition, sim, params, p, progress=progress, checkpoint=checkpoint,
                                   resume=resume, run_options=run_options)
    return state, {"protocol": definition.name, **definition.measure(sim, params, state, p, run_options),
                   "kinetic_energy": samples, **run_record(info, t0), "info": dict(p.info)}


def execute(definition: Definition, sim, params, p: Protocol, *, max_steps: int | None = None, progress=None,
            checkpoint=None, resume=None, run_options: dict | None = None):
    """Runs the set-up `p` until `definition.finished` (checked after each
    chunk) or its step budget (`max_steps`, default `definition.max_steps`).
    Returns `(state, RunInfo, samples)` as `run_sampled`."""
    run_options = {**definition.run_options, **(run_options or {})}
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
        return d._setup(size, law, seed=seed, dt=dt, **kwargs)

    def row(sim, params, state, p):
        m = d.measure(sim, params, state, p, dict(d.run_options))
        return {k: m[k] for k in d.row}

    def finished(info, options):
        return d.finished(info, {**d.run_options, **{k: v for k, v in options.items() if k in d.run_options}})

    def max_steps(info, options):
        return d.max_steps(info, {**d.run_options, **{k: v for k, v in options.items() if k in d.run_options}})

    options = (option_names(d.setup, *d.run_options) - {d.size}) | {"n"}
    return Adapter(setup, lambda law, dt, sim_options, setup_options: d.simulator(law, dt=dt, **sim_options),
                   finished, max_steps, row, d.law_and_params, d.default_dt, options=options, **d.sweep)


__all__ = ["Definition", "adapter", "check_dt", "execute", "restore_sampled", "run", "run_record", "run_sampled",
           "run_to_finish", "start"]
