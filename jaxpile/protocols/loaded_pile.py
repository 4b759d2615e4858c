"""The run the 1992 static piles share (the lattice, Figs. 7-9, and the sloped
pile, Figs. 12-16): gravity ramped in over `ramp_steps`, then a run until the
fastest disk is below `speed_tolerance`, within `max_steps` in all
(`lattice.relax`). `definition_of` declares such a protocol once
(`definition.Definition`): its single run, its batch and its ensemble fit.

The piles are deterministic, so a sweep's seeds repeat the same pile and a
sweep varies the law (K_s, mu_roll, ...). Not a protocol itself (no `CLI`).
"""

from __future__ import annotations

import functools
from typing import Callable

import numpy as np

from jaxpile.protocols import definition
from jaxpile.protocols.geometry import bottom_row_extent

RUN_OPTIONS = ("ramp_steps", "speed_tolerance", "max_steps")


def relax(sim, params, state, *, ramp_steps: int, speed_tolerance: float, max_steps: int, progress=None,
          checkpoint=None):
    """Loads the pile (gravity ramped in by `sim.schedule`) and runs it to rest.

    Resumable from a checkpoint of the same run (`checkpoint` as in
    `Simulator.run`; see `simulate.load_then_settle`).

    Returns:
      (state, RunInfo) with the steps of both phases.
    """
    from jaxpile.engine.simulate import load_then_settle

    ramp = min(ramp_steps, max_steps)
    return load_then_settle(sim, params, state, load_steps=ramp, max_settle_steps=max_steps - ramp,
                            speed_tolerance=speed_tolerance, progress=progress, checkpoint=checkpoint)


def _execute(sim, params, p, options: dict, *, progress=None, checkpoint=None, resume=None):
    """One pile: started (or resumed from `resume`) and `relax`ed."""
    from jaxpile.engine import checkpoint as ckpt

    state = sim.init(params, p.particles, p.boundaries, box=p.box)
    if resume is not None:
        state = ckpt.restore(resume, state, sim.law, params)
    state, info = relax(sim, params, state, ramp_steps=int(options["ramp_steps"]),
                        speed_tolerance=float(options["speed_tolerance"]), max_steps=int(options["max_steps"]),
                        progress=progress, checkpoint=checkpoint)
    return state, info, None


def _finished(info, options):
    from jaxpile.engine.simulate import max_speed

    ramp, tolerance = int(options["ramp_steps"]), float(options["speed_tolerance"])
    return lambda s: (s.step >= ramp) & (max_speed(s) < tolerance)


def _row(measured: dict) -> dict:
    """A sweep row: the plain numbers of the comparison with theory, the
    height, whether the pile is at rest and its fastest disk."""
    return {k: v for k, v in measured.items() if np.ndim(v) == 0 and not isinstance(v, str)}


def definition_of(name: str, setup: Callable, law_and_params: Callable, setting: dict, compare: Callable,
                  report: Callable, headline: tuple, size: str = "n", options=None) -> definition.Definition:
    """A 1992 static pile declared once.

    Args:
      name: the protocol's registered name.
      setup: its set-up, `setup(size, *, ..., dtype) -> Setup`.
      law_and_params: its law lookup (the 1992 setting).
      setting: its defaults (`dt` and the `RUN_OPTIONS`).
      compare: `(sim, params, state, protocol) -> dict` against the paper's theory.
      report: `(measured, protocol, run options, RunInfo, seconds) -> dict`, one pile's output.
      headline: the sweep's summary columns.
      size: the set-up's size keyword (`layers` for the lattice).
      options: the options a sweep takes (default: the set-up's and the run options).
    """

    def simulator(law, *, dt, rotation=None, integrator="velocity_verlet", chunk_steps=None, run_options,
                  hard_collisions=None):
        from jaxpile.engine.simulate import Simulator, gravity_ramp

        _, contact_law, _ = law_and_params(law, None, rotation)
        kwargs = {} if chunk_steps is None else {"chunk_steps": chunk_steps}
        return Simulator(contact_law, dt, schedule=gravity_ramp(int(run_options["ramp_steps"])),
                         integrator=integrator, hard_collisions=hard_collisions, **kwargs)

    def measure(sim, params, state, p, options):
        from jaxpile.engine.simulate import max_speed

        particles = state.particles
        active = np.asarray(particles.active)
        # the pile's top above the ground: it sinks by the contacts' compression, ~ weight / K_s
        height = float(np.max((np.asarray(particles.position[:, 1]) + np.asarray(particles.radius))[active]))
        fastest = float(max_speed(state))
        return {**compare(sim, params, state, p), "height": height,
                "at_rest": bool(fastest < float(options["speed_tolerance"])), "max_speed": fastest}

    @functools.wraps(setup)
    def without_schedule(*args, **kwargs):
        return setup(*args, **kwargs)._replace(schedule=None)  # the ramp is the simulator's, from the run options

    sweep = dict(angles=headline, unit="", default_law="hooke", extent=bottom_row_extent,
                 fit_statistics={"bins": 9}, deterministic=True)
    if options is not None:
        sweep["options"] = frozenset(options)
    return definition.Definition(
        name, without_schedule, simulator, law_and_params, lambda law: float(setting["dt"]), _finished,
        lambda info, options: int(options["max_steps"]), measure, row=_row, size=size,
        run_options={k: setting[k] for k in RUN_OPTIONS}, execute=_execute,
        report=lambda measured, p, options, info, samples, seconds: report(measured, p, options, info, seconds),
        sweep=sweep)


__all__ = ["RUN_OPTIONS", "definition_of", "relax"]
