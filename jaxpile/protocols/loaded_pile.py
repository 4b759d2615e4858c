"""The run the 1992 static piles share (the lattice, Figs. 7-9, and the sloped
pile, Figs. 12-16): gravity ramped in over `ramp_steps`, then a run until the
fastest disk is below `speed_tolerance`, within `max_steps` in all (`relax`).
`spec_of` declares such a protocol once (`spec.ProtocolSpec`).

The piles are deterministic, so a sweep's seeds repeat the same pile and a
sweep varies the law (K_s, mu_roll, ...). Not a protocol itself (no `SPEC`).
Each pile's options carry the run options `ramp_steps`, `speed_tolerance`,
`max_steps` and `hard_collisions`, which the functions here read.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from jaxpile.protocols.base import Setting
from jaxpile.protocols.spec import ProtocolSpec


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


def execute(sim, params, p, o, *, progress=None, checkpoint=None, resume=None):
    """One pile: started (or resumed from `resume`) and `relax`ed."""
    from jaxpile.engine import checkpoint as ckpt

    state = sim.init(params, p.particles, p.boundaries, box=p.box)
    if resume is not None:
        state = ckpt.restore(resume, state, sim.law, params)
    state, info = relax(sim, params, state, ramp_steps=int(o.ramp_steps), speed_tolerance=float(o.speed_tolerance),
                        max_steps=int(o.max_steps), progress=progress, checkpoint=checkpoint)
    return state, info, None


def finished(p, o):
    """At rest: past the ramp, the fastest disk below `speed_tolerance`."""
    from jaxpile.engine.simulate import max_speed

    ramp, tolerance = int(o.ramp_steps), float(o.speed_tolerance)
    return lambda s: (s.step >= ramp) & (max_speed(s) < tolerance)


def budget(p, o) -> int:
    """`max_steps`, ramp included."""
    return int(o.max_steps)


# what `spec_of`'s measurement adds to the comparison with theory, last in a sweep row (`jaxpile.batches`)
OWN_COLUMNS = ("height", "at_rest", "max_speed")


def spec_of(name: str, *, options: type, setting: Setting, setup: Callable, compare: Callable, report: Callable,
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
      report: `(measured, setup, options, RunInfo, samples, seconds) -> dict`, one pile's output.
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
        return {**compare(sim, params, state, p), "height": height,
                "at_rest": bool(fastest < float(o.speed_tolerance)), "max_speed": fastest}

    return ProtocolSpec(
        name=name, options=options, setting=setting, setup=setup, simulator=simulator,
        finished=finished, budget=budget, measure=measure, size=size, execute=execute, report=report)


__all__ = ["OWN_COLUMNS", "budget", "execute", "finished", "relax", "spec_of"]
