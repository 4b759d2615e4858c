"""One pile of a protocol from its spec, set-up to measurements, and the
per-member steps a batch takes with the same spec.

`run(spec, law, size, **options)` builds the options (checked), the law's
parameters, the set-up and the simulator, runs the pile through the spec's
phases (`run_setup`: the one stage runner, `stages.run_phases`, with the
kinetic energy sampled once per chunk, checkpoints and bit-identical resume),
and measures it. A spec that `starts_from` another (the tilt from a box) first
builds that pile, unless it is given one, and continues it with its contact
history; each stage is checkpointed and resumable. A sweep and an ensemble fit
run the same phases on a batch, with the same functions per member
(`spec.setup`, `stage_start`).
"""

from __future__ import annotations

import dataclasses
import os
import time
from typing import Any

import jax
import jax.numpy as jnp

from jaxpile import ranges
from jaxpile.errors import InputError

from jaxpile.engine import checkpoint as ckpt
from jaxpile.protocols import stages
from jaxpile.protocols.base import Setup, registered


@dataclasses.dataclass(frozen=True, eq=False)
class PileRun:
    """One pile's run, as `ProtocolSpec.run` and `jaxpile.run` return it.

    Behaves as the pair `(state, measurements)` (unpacking, `run[1]`):

        state, measured = jaxpile.run("box", "lee-herrmann", 72, width=1.6, height=1.6)

    Attributes:
      state: the final `SimState`.
      measurements: the protocol's measurements (`{"protocol": name, ...}`).
      simulator: the `Simulator` that ran it: for a measurement of your own
        (`jaxpile.base_forces(run.simulator, run.params, run.state)`) or a
        rollout to differentiate (`run.simulator.rollout(params, run.state, steps)`).
      params: the law's parameters it ran with (a pytree; `params.set(mu=0.3)`).
    """

    state: Any
    measurements: dict
    simulator: Any
    params: Any

    def __iter__(self):
        return iter((self.state, self.measurements))

    def __getitem__(self, index):
        return (self.state, self.measurements)[index]

    def __len__(self) -> int:
        return 2


def run(protocol, law=None, size=None, *, params=None, rotation: bool | None = None, dt: float | None = None,
        integrator: str | None = None, chunk_steps: int | None = None, seed: int = 0, progress=False, dtype=None,
        checkpoint=None, resume=None, pile=None, pile_params=None, pile_options: dict | None = None,
        law_options: dict | None = None, **options):
    """One pile of `protocol` from set-up to its end, and its measurements.

    Args:
      protocol: the protocol's name (`"box"`) or its `ProtocolSpec`.
      law: a law name (default: the protocol's paper's).
      size: the protocol's size option (`spec.size`: disks, layers, insertions).
      params: None (the protocol's setting for the law), a dict of overrides,
        or a params pytree of that law.
      rotation, dt, integrator, chunk_steps: for the simulator (None: the protocol's).
      law_options: the law's readings beyond rotation, e.g. `{"rolling": "sds"}`
        (`hooke.law(rolling=...)`), or baxter's `lever_arm`; recorded in the
        set-up's `info` when given.
      seed: draws the pile (a deterministic pile takes none).
      progress: a progress bar (None: when stderr is a terminal).
      dtype: float dtype (default float64).
      checkpoint: `(path, every[, extra])` as in `Simulator.run`.
      resume: a checkpoint file of this same run: it ends bit-identical to the
        uninterrupted one, samples included.
      pile, pile_params, pile_options: for a protocol that `starts_from`
        another: the pile to continue (a state), or the parameters and options
        (a dict) of the run that builds it; that run is saved beside
        `checkpoint` (`checkpoint.sibling(path, its name)`), and `resume` takes
        a save of either stage.
      **options: the protocol's options (`spec.options`).

    Returns:
      a `PileRun` (unpacks as `(state, measurements)`); its measurements are
      `record`'s: `{"protocol": name, **measure(...), "kinetic_energy":
      samples, steps, phases, at_rest, final_max_speed, timings, "info": set-up
      info}`; a continued
      protocol that built its pile adds the pile's measurements under the pile
      protocol's name.
    """
    spec = registered(protocol) if isinstance(protocol, str) else protocol
    law = law or spec.default_law
    if size is not None and spec.starts_from is not None and spec.size not in spec.options.names():
        pile_options = {**(pile_options or {}), spec.starts_from.size: size}  # the size of the pile it builds
    elif size is not None:
        options[spec.size] = size
    o = spec.make_options(options)  # every option checked before anything is built
    dt = _check_run(dt, chunk_steps, seed)
    if spec.starts_from is not None:
        return _run_continued(spec, law, o, params=params, pile=pile, pile_params=pile_params,
                              pile_options=pile_options, rotation=rotation, dt=dt, integrator=integrator,
                              chunk_steps=chunk_steps, seed=seed, progress=progress, dtype=dtype,
                              checkpoint=checkpoint, resume=resume, law_options=law_options)
    if pile is not None or pile_params is not None or pile_options:
        raise InputError(f"the {spec.name} protocol builds its own pile: pile, pile_params and pile_options are "
                         "for a protocol that continues another's.")
    _, _, params = spec.law_and_params(law, params, rotation, dtype, law_options)
    p = _with_law_options(spec.setup(o, law=law, seed=seed, dt=spec.default_dt(law) if dt is None else dt,
                                     dtype=dtype), law_options)
    sim = spec.simulator(o, law=law, dt=p.info["dt"], rotation=rotation, integrator=integrator,
                         chunk_steps=chunk_steps, law_options=law_options)
    t0 = time.perf_counter()
    state, info, samples = run_setup(spec, sim, params, p, o, progress=progress, checkpoint=checkpoint,
                                     resume=resume)
    measured = spec.measure(sim, params, state, p, o)
    return PileRun(state, record(spec, measured, p, info, samples, t0), sim, params)


def _with_law_options(p: Setup, law_options: dict | None) -> Setup:
    """The set-up with the law's readings in its info, where a run was given any."""
    return p._replace(info={**p.info, "law_options": dict(law_options)}) if law_options else p


RUN_RANGES = {"seed": ranges.SEED, "dt": ranges.TIME_STEP, "chunk_steps": ranges.STEPS}
"""The ranges of a run's own numbers, the same for every protocol."""


def _check_run(dt, chunk_steps, seed):
    """The run's own numbers, against their ranges (one message format; None: the protocol's)."""
    ranges.SEED.check("seed", seed, scalar=True)
    checked = ranges.check_all(RUN_RANGES, {"dt": dt, "chunk_steps": chunk_steps})
    return checked["dt"]


def record(spec, measured: dict, p: Setup, info, samples, t0: float) -> dict:
    """One pile's output, the same for every protocol: `{"protocol", **measured,
    "kinetic_energy": samples, **run_record, "info": the set-up's info}`; a
    measurement keeps its own reading of a name the run also records (the
    tilt's `at_rest` is its pile's, not its phase's end)."""
    run_facts = run_record(info, t0, start=int(p.info.get("start_step", 0)))
    return {"protocol": spec.name, **measured, "kinetic_energy": samples,
            **{k: v for k, v in run_facts.items() if k not in measured}, "info": dict(p.info)}


def run_record(info, t0: float, start: int = 0) -> dict:
    """Steps, phases, rest and timings of a run, for the measurements dict:
    `steps` the protocol's from `start` to its end (a resumed run's are the
    uninterrupted one's), `steps_run` those this call ran, `phases` the step
    each phase ended at (`{"fill": 1200, "relax": 2000}`), `at_rest` whether
    the last phase's `until` held at the end."""
    return {
        "steps": max(info.phases.values(), default=start + info.steps) - start,
        "steps_run": info.steps,
        "phases": dict(info.phases),
        "at_rest": bool(info.at_rest),
        "final_max_speed": info.max_speed,
        "wall_seconds": info.wall_seconds,
        "compile_seconds": info.compile_seconds,
        "total_seconds": time.perf_counter() - t0,
        "neighbor_reallocations": info.reallocations,
    }


def check_dt(sim, p: Setup) -> None:
    """InputError unless the simulator steps with the dt the protocol was set up for."""
    if abs(sim.dt - p.info["dt"]) > 1e-12 * p.info["dt"]:
        raise InputError(f"the protocol was set up for dt = {p.info['dt']:g} but the simulator uses "
                         f"dt = {sim.dt:g}; pass the same dt to both.")


def _sample(state):
    """(step, kinetic energy per movable disk, max_speed): `analysis.mean_kinetic_energy` on device."""
    from jaxpile.engine.simulate import max_speed

    p = state.particles
    energy = 0.5 * p.mass * jnp.sum(p.velocity**2, -1) + 0.5 * p.inertia * p.spin_squared
    count = jnp.maximum(jnp.sum(p.movable), 1)
    return state.step, jnp.sum(jnp.where(p.movable, energy, 0.0)) / count, max_speed(state)


_sample_jit = jax.jit(_sample)


def run_setup(spec, sim, params, p: Setup, options, pile=None, *, progress=None, checkpoint=None, resume=None):
    """Runs the set-up `p` of `spec` through its phases (`stages.run_phases`),
    sampling the kinetic energy once per chunk.

    Args:
      pile: for a continued protocol, the state `p` was built on (contact
        history kept; None: `p.particles` with a fresh history). Its phases
        count from the pile's last step.
      checkpoint: a `Checkpoint` or `(path, every[, facts])`; each save
        records the samples so far, where the run stands and, for a continued
        protocol, `stage=spec.name`.
      resume: a checkpoint file of this same run: it ends bit-identical to the
        uninterrupted one, samples included.

    Returns:
      `(state, RunInfo, samples)`: samples is a dict of per-chunk lists `step`,
      `time`, `kinetic_energy` (per movable disk; Fig. 1(b) of 1993) and
      `max_speed`, from the run's first state; `RunInfo.at_rest` says whether
      the last phase's `until` held at the end.
    """
    from jaxpile.engine.simulate import RunInfo, max_speed

    check_dt(sim, p)
    if pile is None:
        state = sim.init(params, p.particles, p.boundaries, box=p.box, protocol_state=p.protocol_state)
    else:
        if int(pile.step) != int(p.info["start_step"]) or pile.particles.count != p.info["n"]:
            raise InputError(f"pile is not the state this {spec.name} protocol was built from.")
        state = pile.set(protocol_state=p.protocol_state)
    samples = {"step": [], "time": [], "kinetic_energy": [], "max_speed": []}
    position = None
    if resume is not None:
        state = ckpt.restore(resume, state, sim.law, params)
        extra = ckpt.read_metadata(resume)["extra"]
        if extra.get("samples") is None:
            raise InputError(f"{resume} does not hold a protocol's run (no samples recorded with it).")
        samples = {k: list(v) for k, v in extra["samples"].items()}
        position = stages.Position.saved(extra, resume)

    def sample(s) -> None:
        step, energy, speed = (x.item() for x in _sample_jit(s))
        samples["step"].append(int(step))
        samples["time"].append(int(step) * sim.dt)
        samples["kinetic_energy"].append(float(energy))
        samples["max_speed"].append(float(speed))

    phases = spec.phases(p, options)
    if checkpoint is not None:  # the samples dict is written as it stands at each save: always up to date
        checkpoint = ckpt.with_facts(checkpoint, samples=samples,
                                     **({} if spec.starts_from is None else {"stage": spec.name}))
    info = RunInfo()
    info.particles = state.particles.count
    state, ends = stages.run_phases(sim, params, state, phases, position=position, progress=progress, info=info,
                                    checkpoint=checkpoint, observe=sample)
    info.phases = {name: steps[0] for name, steps in ends.items()}
    info.max_speed = float(max_speed(state))
    info.at_rest = phases[-1].until is None or bool(phases[-1].until(state))
    return state, info, samples


def _run_continued(spec, law, o, *, params, pile, pile_params, pile_options, rotation, dt, integrator, chunk_steps,
                   seed, progress, dtype, checkpoint, resume, law_options):
    """`run` of a spec that continues another's pile (see `run`)."""
    base = spec.starts_from
    _, _, stage_params = spec.law_and_params(law, params, rotation, dtype, law_options)
    built = None
    if pile is None:
        pile_file = None if checkpoint is None else ckpt.sibling(checkpoint[0], base.name)
        pile_resume, resume = continued_stages(spec, resume)
        pile, built = run(base, law, params=params if pile_params is None else pile_params, rotation=rotation,
                          dt=dt, integrator=integrator, chunk_steps=chunk_steps, seed=seed, progress=progress,
                          dtype=dtype, checkpoint=ckpt.with_facts(checkpoint, path=pile_file, stage=base.name),
                          resume=pile_resume, law_options=law_options, **dict(pile_options or {}))
        if checkpoint is not None:  # each save of this stage names the pile it started from (the last pile save)
            checkpoint = ckpt.with_facts(checkpoint, pile_checkpoint=os.path.basename(
                pile_file.replace("{step}", str(int(pile.step)))))
    elif pile_params is not None or pile_options:
        raise InputError(f"the {spec.name} protocol continues the pile it is given: pile_params and pile_options "
                         "are for the run that builds one.")
    p = _with_law_options(on_pile(spec, pile, law, spec.default_dt(law) if dt is None else dt, o), law_options)
    sim = spec.simulator(o, law=law, dt=p.info["dt"], rotation=rotation, integrator=integrator,
                         chunk_steps=chunk_steps, law_options=law_options)
    t0 = time.perf_counter()
    state, info, samples = run_setup(spec, sim, stage_params, p, o, pile, progress=progress, checkpoint=checkpoint,
                                     resume=resume)
    measured = spec.measure(sim, stage_params, state, p, o)
    out = record(spec, measured, p, info, samples, t0)
    if built is not None:
        out[base.name] = {k: v for k, v in built.items() if k != "kinetic_energy"}
    return PileRun(state, out, sim, stage_params)


def on_pile(spec, pile, law, dt, options, *, facts: bool = True) -> Setup:
    """The set-up of `spec` on the state `pile`, with the pile's facts
    (`spec.pile_facts`) in its info unless `facts` is False (a batch adds them
    as its stage starts)."""
    p = spec.setup(pile, options, law=law, dt=dt)
    return p if spec.pile_facts is None or not facts else p._replace(info={**p.info, **spec.pile_facts(pile, p)})


def continued_stages(spec, resume) -> tuple[str | None, str | None]:
    """`(pile run's checkpoint, this stage's checkpoint)` to resume a continued
    protocol that builds its own pile from `resume`: a save of this stage
    (which names its pile's file), a save of the pile's run, or this stage's
    fixed path when the run stopped before the stage began (then only its
    `checkpoint.sibling(resume, pile name)` exists)."""
    base = spec.starts_from.name
    if resume is None:
        return None, None
    if not os.path.exists(resume):
        sibling = ckpt.sibling(resume, base)
        if not os.path.exists(sibling):
            raise InputError(f"resuming a {spec.name} that builds its own pile needs the {base} run's checkpoint "
                             f"{sibling} (or the {spec.name}'s {resume}); neither is there.")
        return sibling, None
    extra = ckpt.read_metadata(resume)["extra"]
    if extra.get("stage") == base:
        return resume, None
    pile = os.path.join(os.path.dirname(resume), extra.get("pile_checkpoint") or "")
    if not extra.get("pile_checkpoint") or not os.path.exists(pile):
        raise InputError(f"{resume} is a {spec.name} checkpoint; resuming it needs the pile it started from, the "
                         f"{base} run's last save {pile or '(not recorded)'}, beside it.")
    return pile, resume


# ---------------------------------------------------------------- a batch
def stage_options(spec, options: dict) -> list:
    """Each stage's options (`spec.chain()`, the pile's first) from one dict
    of a sweep's options: a name goes to every stage that has it; a name no
    stage has is refused."""
    chain = spec.chain()
    known = set().union(*(s.options.names() for s in chain)) | {s.size for s in chain} | {"n"}
    unknown = set(options) - known
    if unknown:
        raise InputError(f"unknown option(s) {sorted(unknown)} for a {spec.name} sweep; known: {sorted(known)}.")
    out = []
    for s in chain:
        names = set(s.options.names()) | ({"n"} if s.size != "n" else set())
        out.append(s.make_options({k: v for k, v in options.items() if k in names}))
    return out


def stage_start(spec, law, dt, options, pile):
    """A later stage's start for one member: `(state, setup)` on the member's
    end state `pile` of the stage before, contact history kept. Structure
    only (it also shapes a resume's template): the pile's facts are
    `stage_facts`'."""
    p = on_pile(spec, pile, law, dt, options, facts=False)
    return pile.set(protocol_state=p.protocol_state), p


def stage_facts(spec, pile, p: Setup) -> dict:
    """What the member's pile was when this stage took it over (`spec.pile_facts`), for its info."""
    return {} if spec.pile_facts is None else spec.pile_facts(pile, p)


__all__ = ["RUN_RANGES", "check_dt", "continued_stages", "on_pile", "run", "run_record", "run_setup",
           "stage_facts", "stage_options", "stage_start"]
