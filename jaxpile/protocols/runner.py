"""Running a protocol's set-up to its end: the part every protocol shares.

`start` builds a `Setup`'s first state (or restores a checkpoint of the
same run), `run_sampled` runs it until a host predicate holds, sampling the
kinetic energy once per chunk and saving the samples with each checkpoint, and
`run_to_finish` is the two together with the budget check: a protocol whose
end its driver records (the box's final rest, the hopper's stop) is run by
`run_to_finish(sim, params, p, max_steps=..., finished=...)`. `run_record`
gives the steps and timings every protocol reports.
"""

from __future__ import annotations

import time

import jax
import jax.numpy as jnp

from jaxpile.errors import InputError
from jaxpile.protocols.base import Setup
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
    info.particles = state.particles.count
    if not (resumed and finished(state)):
        # the samples dict is written as it stands at each save: always up to date
        state = sim.run(params, state, int(max_steps), progress=progress, info=info, until=stop,
                        checkpoint=ckpt.with_facts(checkpoint, samples=samples))
    info.max_speed = float(max_speed(state))
    info.at_rest = bool(finished(state))
    return state, info, samples


def check_dt(sim, p: Setup) -> None:
    """InputError unless the simulator steps with the dt the protocol was set up for."""
    if abs(sim.dt - p.info["dt"]) > 1e-12 * p.info["dt"]:
        raise InputError(f"the protocol was set up for dt = {p.info['dt']:g} but the simulator uses "
                         f"dt = {sim.dt:g}; pass the same dt to both.")


def start(sim, params, p: Setup, resume=None) -> tuple[SimState, dict | None]:
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


def run_to_finish(sim, params, p: Setup, *, max_steps: int, finished, progress=None, checkpoint=None,
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


__all__ = ["check_dt", "restore_sampled", "run_record", "run_sampled", "run_to_finish", "start"]
