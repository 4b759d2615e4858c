"""The run the 1992 static piles share (the lattice, Figs. 7-9, and the sloped
pile, Figs. 12-16): gravity ramped in over `ramp_steps`, then a run until the
fastest disk is below `speed_tolerance`, within `max_steps` in all (`phases`).
`spec_of` declares such a protocol once (`spec.ProtocolSpec`).

The piles are deterministic, so a sweep's seeds repeat the same pile and a
sweep varies the law (K_s, mu_roll, ...). Not a protocol itself (no `SPEC`).
Each pile's options carry the run options `ramp_steps`, `speed_tolerance`,
`max_steps` and `hard_collisions`, which the functions here read.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from jaxpile.protocols import stages
from jaxpile.protocols.base import Setting
from jaxpile.protocols.spec import ProtocolSpec
from jaxpile.protocols.stages import Phase


def load_and_settle(ramp_steps: int, speed_tolerance: float, max_steps: int) -> tuple[Phase, ...]:
    """The phases: the gravity ramp (`ramp_steps`, within `max_steps`), then a
    run until the fastest disk is below `speed_tolerance`, `max_steps` in all."""
    from jaxpile.engine.simulate import max_speed

    ramp, tolerance = min(int(ramp_steps), int(max_steps)), float(speed_tolerance)
    return (Phase("ramp", ramp), Phase("settle", int(max_steps) - ramp, lambda s: max_speed(s) < tolerance))


def phases(p, o) -> tuple[Phase, ...]:
    """A static pile's phases from its options (`load_and_settle`)."""
    return load_and_settle(o.ramp_steps, o.speed_tolerance, o.max_steps)


def relax(sim, params, state, *, ramp_steps: int, speed_tolerance: float, max_steps: int, progress=None,
          checkpoint=None):
    """Loads a fresh pile `state` (gravity ramped in by `sim.schedule`) and runs
    it to rest: `load_and_settle`'s phases (a protocol's run, `SPEC.run`, also
    resumes from its checkpoints).

    Returns:
      (state, RunInfo) with the steps of both phases; `at_rest` at the end.
    """
    from jaxpile.engine.simulate import RunInfo, max_speed

    info = RunInfo()
    state, _ = stages.run_phases(sim, params, state, load_and_settle(ramp_steps, speed_tolerance, max_steps),
                                 progress=progress, info=info, checkpoint=checkpoint)
    info.max_speed = float(max_speed(state))
    info.at_rest = info.max_speed < speed_tolerance
    info.particles = state.particles.count
    return state, info


# what `spec_of`'s measurement adds to the comparison with theory, last in a sweep row (`jaxpile.batches`)
OWN_COLUMNS = ("n_particles", "height", "at_rest", "max_speed")


def spec_of(name: str, *, options: type, setting: Setting, setup: Callable, compare: Callable,
            size: str = "n") -> ProtocolSpec:
    """A 1992 static pile declared once.

    Args:
      name: the protocol's registered name.
      options: its options (an `Options` with `ramp_steps`, `speed_tolerance`,
        `max_steps` and `hard_collisions` among its fields).
      setup: its set-up, `setup(options, *, law, seed, dt, dtype) -> Setup`
        (no schedule: the gravity ramp is the simulator's).
      setting: its laws, their parameters and dt (the 1992 setting).
      compare: `(sim, params, state, setup) -> dict` against the paper's theory.
      size: its size option (`layers` for the lattice).
    """

    def simulator(o, *, law, dt, rotation=None, integrator=None, chunk_steps=None, law_options=None):
        from jaxpile.engine.simulate import Simulator, gravity_ramp

        _, contact_law, _ = setting.law_and_params(law, None, rotation, law_options=law_options)
        kwargs = {} if chunk_steps is None else {"chunk_steps": chunk_steps}
        return Simulator(contact_law, dt, schedule=gravity_ramp(int(o.ramp_steps)),
                         integrator=integrator or "velocity_verlet", hard_collisions=o.hard_collisions, **kwargs)

    def measure(sim, params, state, p, o):
        from jaxpile.engine.simulate import max_speed

        particles = state.particles
        active = np.asarray(particles.active)
        # the pile's top above the ground: it sinks by the contacts' compression, ~ weight / K_s
        height = float(np.max((np.asarray(particles.position[:, 1]) + np.asarray(particles.radius))[active]))
        fastest = float(max_speed(state))
        return {**compare(sim, params, state, p), "n_particles": int(active.sum()), "height": height,
                "at_rest": bool(fastest < float(o.speed_tolerance)), "max_speed": fastest}

    return ProtocolSpec(
        name=name, options=options, setting=setting, setup=setup, simulator=simulator,
        phases=phases, measure=measure, size=size)


__all__ = ["OWN_COLUMNS", "load_and_settle", "phases", "relax", "spec_of"]
