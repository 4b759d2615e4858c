"""The batch runner: a protocol run for every (parameters, seed) member of a
grid, in batches of `Ensemble` runs, each member measured as the protocol's
own run measures it.

`sweep("box", "lee-herrmann", vary={"mu": [0.1, 0.2]}, seeds=16)` builds one
box per seed (the same 16 packings for every mu: common random numbers, so
differences between mu values are not blurred by different packings), runs
all 32 members in batches of `batch_size` in one compiled loop each (each
batch through the protocol's stages and phases, `stages.run_phases`), and
returns one row per member. A sweep study (`jaxpile.sweeps`) and an ensemble
fit (`jaxpile.fit`) both run their piles here; a distributed run shares the
batches among its processes (`jaxpile.distributed`).
"""

from __future__ import annotations

import itertools
import numbers
import os
import time
from dataclasses import dataclass
from typing import Callable, NamedTuple, Sequence

import numpy as np

from jaxpile import budget as memory
from jaxpile import config
from jaxpile import distributed
from jaxpile.batches.reading import batch_of
from jaxpile.engine import ensemble
from jaxpile.errors import InputError, SimulationError
from jaxpile import ranges
from jaxpile.ranges import COUNT, SEED
from jaxpile.engine.simulate import RunInfo
from jaxpile.protocols import PROTOCOLS, running, stages
from jaxpile.protocols.spec import ProtocolSpec


MEMBER_COLUMNS = ("member", "seed", "steps")
"""What `sweep` adds to every row besides the protocol's measurement and the member's point."""


def spec_of(protocol: str | ProtocolSpec) -> ProtocolSpec:
    """The spec a sweep runs: a registered protocol's by name, or a spec itself."""
    if isinstance(protocol, ProtocolSpec):
        return protocol
    if protocol not in PROTOCOLS:
        raise InputError(f"sweeps run the protocols {sorted(PROTOCOLS)}; got {protocol!r}.")
    return PROTOCOLS[protocol]


def option_names(spec: ProtocolSpec) -> frozenset:
    """The options a sweep of `spec` takes: every stage's, and `n` for the size."""
    return frozenset(set().union(*(s.options.names() for s in spec.chain())) | {"n"})


def first_setup(spec: ProtocolSpec, law: str, seed: int, dt: float, options: dict, dtype=None):
    """The first stage's set-up of a member with these sweep options (what `plan` checks per batch)."""
    first = spec.chain()[0]
    return first.setup(running.stage_options(spec, options)[0], law=law, seed=seed, dt=dt, dtype=dtype)


# ---------------------------------------------------------------------- sweep
@dataclass
class SweepResult:
    """Rows (one dict per member: the varied parameters, seed, measurements,
    steps) and the set-up and timings (`info`)."""

    rows: list
    info: dict

    def column(self, name: str) -> np.ndarray:
        return np.array([r.get(name, np.nan) for r in self.rows], dtype=float)


def _check_vary(vary: dict) -> dict:
    """`vary` with each name's values as floats, or `InputError`: a list of finite numbers per name."""
    if not isinstance(vary, dict):
        raise InputError(f"vary must be a dict of name -> values; got {vary!r}.")
    for name, values in vary.items():
        if isinstance(values, (str, bytes)) or np.ndim(values) != 1:
            raise InputError(f"the sweep over {name!r} takes a list of numbers; got {values!r}.")
        if len(values) == 0:
            raise InputError(f"the sweep over {name!r} has no values.")
        for v in values:
            _number(f"a value of the sweep over {name!r}", v)
    return {name: [float(v) for v in values] for name, values in vary.items()}


def _number(name: str, value) -> float:
    """`value` as a float, or `InputError` when it is not one number (its range,
    finiteness included, is the law's or the set-up's, checked with them)."""
    if not ranges.is_number_like(value) or np.ndim(value) != 0:  # not None, text, a bool or a list
        raise InputError(f"{name} must be a number; got {value!r}.")
    return float(value)


def grid(vary: dict, seeds) -> list[tuple[dict, int]]:
    """Every (parameter values, seed) member: the product of the varied values,
    each with every seed."""
    _check_vary(vary)
    if isinstance(seeds, (str, bytes)) or np.ndim(seeds) > 1:
        raise InputError(f"seeds must be a count or a list of seeds; got {seeds!r}.")
    if np.ndim(seeds) == 0:
        if isinstance(seeds, numbers.Integral) and seeds < 1:
            raise InputError("a sweep needs at least one seed.")
        seeds = list(range(COUNT.check("the number of seeds", seeds, scalar=True)))
    else:
        seeds = [SEED.check("a seed", s, scalar=True) for s in seeds]
    if not seeds:
        raise InputError("a sweep needs at least one seed.")
    names = list(vary)
    points = [dict(zip(names, combo)) for combo in itertools.product(*(vary[n] for n in names))] or [{}]
    return [(point, seed) for point in points for seed in seeds]


_ENSEMBLES: dict = {}  # the last few batched simulators, so repeated sweeps (a fit's iterations) compile once


def ensemble_for(spec, law, dt, rotation, options, law_options=None, devices=None) -> ensemble.Ensemble:
    """The `Ensemble` for this protocol stage and its options: reused when a
    sweep with the same law, dt, rotation and the options its simulator reads
    ran before (its compiled loops are kept per batch shape); built afresh otherwise."""
    read = options.as_dict() if batch_of(spec).simulator_options is None else {
        k: v for k, v in options.as_dict().items() if k in batch_of(spec).simulator_options}

    def build():
        return spec.simulator(options, law=law, dt=dt, rotation=rotation, law_options=law_options)

    try:
        key = (spec.name, law, float(dt), rotation, tuple(sorted((law_options or {}).items())),
               tuple(sorted(read.items())), None if devices is None else tuple(devices))
        hash(key)
    except TypeError:  # an option that is a dict or a list: no reuse
        return ensemble.Ensemble(build(), devices=devices, sequential=batch_of(spec).sequential)
    if key not in _ENSEMBLES:
        if len(_ENSEMBLES) >= 4:
            _ENSEMBLES.pop(next(iter(_ENSEMBLES)))
        _ENSEMBLES[key] = ensemble.Ensemble(build(), devices=devices, sequential=batch_of(spec).sequential)
    return _ENSEMBLES[key]


class Plan(NamedTuple):
    """A sweep checked before it runs (`plan`)."""

    members: list  # (point, seed) per member
    member_params: list  # its law parameters
    batches: list  # [first, end) member ranges, one set-up each
    split: Callable  # point -> (law overrides, set-up options)
    dt: float
    vary: dict  # name -> values as floats
    points: list | None  # the law-parameter points as floats, or None
    batch_size: int


def plan(protocol, law: str | None = None, *, vary: dict | None = None, seeds=4, params: dict | None = None,
         options: dict | None = None, dt: float | None = None, rotation: bool | None = None,
         batch_size: int | None = None, dtype=None, points: Sequence[dict] | None = None,
         law_options: dict | None = None):
    """A sweep's members checked before anything runs (`sweep`, and `jaxpile
    sweep --dry-run`): every member's law parameters, and the set-up of one
    member of every batch (its options; a later stage's own options too), so
    a bad value anywhere in the grid fails at once, not after the batches
    before it have run. Arguments as `sweep`.

    Returns:
      `Plan`.
    """
    spec = spec_of(protocol)
    law = law or spec.default_law
    vary = _check_vary(vary or {})
    options = dict(options or {})
    known = option_names(spec)
    unknown = set(options) - known
    if unknown:
        raise InputError(f"unknown option(s) {sorted(unknown)} for a {spec.name} sweep; known: {sorted(known)}.")
    if points is not None:
        if vary:
            raise InputError("give a sweep either `vary` (a grid) or `points`, not both.")
        if any(not isinstance(point, dict) for point in points):
            raise InputError(f"points must be a list of dicts of law parameters; got {points!r}.")
        points = [{k: _number(f"{k} of a sweep point", v) for k, v in point.items()} for point in points]
        if not points:
            raise InputError("a sweep over `points` needs at least one point.")
        members = [(point, seed) for point in points for _, seed in grid({}, seeds)]
    else:
        members = grid(vary, seeds)
    dt = spec.default_dt(law) if dt is None else float(dt)
    law_names = set(spec.law_and_params(law, {}, rotation, dtype, law_options)[0].PARAM_NAMES)
    set_up = [k for k in vary if k in known and k not in law_names]  # varied set-up options

    def split(point):  # (law parameters, set-up options) of a member's point
        return ({k: v for k, v in point.items() if k not in set_up},
                {**options, **{k: v for k, v in point.items() if k in set_up}})

    member_params = []
    for point, _ in members:
        _, contact_law, prm = spec.law_and_params(law, {**(params or {}), **split(point)[0]}, rotation, dtype,
                                                  law_options)
        contact_law.validate(prm)  # names and values: a NaN mu in the last batch fails here, not after the first
        member_params.append(prm)
    batch_size = distributed.default_batch_size(len(members)) if batch_size is None else int(batch_size)
    if batch_size < 1:
        raise InputError(f"batch_size must be >= 1; got {batch_size}.")
    batches = []  # (first member, end): at most batch_size members, one set-up each
    for k, (point, _) in enumerate(members):
        if batches and batches[-1][1] - batches[-1][0] < batch_size and split(point)[1] == split(members[k - 1][0])[1]:
            batches[-1][1] += 1
        else:
            batches.append([k, k + 1])

    for start, end in batches:  # every batch's set-up and memory, before any batch runs (a bad value fails at once)
        p = first_setup(spec, law, members[start][1], dt, split(members[start][0])[1], dtype)
        memory.check(p.particles.count, dtype or "float64", batch=end - start, what=f"a batch of the {spec.name} sweep")
    return Plan(members, member_params, batches, split, dt, vary, points, batch_size)


def sweep(protocol="box", law: str | None = None, *, vary: dict[str, Sequence[float]] | None = None,
          seeds=4, params: dict | None = None, options: dict | None = None, dt: float | None = None,
          rotation: bool | None = None, max_steps: int | None = None, batch_size: int | None = None,
          devices=None, progress: bool | None = None, dtype=None, checkpoint: tuple | None = None,
          resume=None, points: Sequence[dict] | None = None, extra_measure: Callable | None = None,
          law_options: dict | None = None) -> SweepResult:
    """Runs a protocol for every member of `grid(vary, seeds)`, batched.

    Args:
      protocol: a registered protocol's name (`jaxpile.protocols.PROTOCOLS`) or a `ProtocolSpec`.
      law: the contact law (default: the protocol paper's).
      vary: name -> values, e.g. `{"mu": [0.1, 0.2, 0.3]}`: law parameters or protocol
        options (`{"orifice": [4, 6, 8]}`; a name that is both, as the pour's `n`, is the
        law's); members with different options run in batches of their own.
      seeds: a count (seeds 0..n-1) or a list of seeds.
      params: fixed overrides of the protocol's law setting.
      options: the protocol's options (e.g. `n`, `width`); each stage of a protocol of
        several (the tilt after the box) takes the names it has.
      dt, rotation: for the simulator (default: the protocol's).
      law_options: the law's readings beyond rotation, e.g. `{"rolling": "sds"}`.
      max_steps: step budget of the first stage (default: the protocol's; a later stage
        has its own).
      batch_size: members per compiled batch (default: all; in a distributed run, one
        batch a process).
      devices: to shard each batch over (default: this process's, `jax.local_devices()`).
      progress: progress bars (default: when stderr is a terminal).
      dtype: the piles' float dtype (default float64).
      checkpoint: `(path, every[, extra])` as in `Simulator.run`: the running batch saved
        every `every` steps, with the rows already measured, its batch and the grid.
      resume: a checkpoint file of this same sweep: its measured batches are kept, its batch
        continued from the saved state, and the rows end equal to the uninterrupted sweep's.
      points: instead of `vary`'s product grid, these law-parameter points (dicts), each
        run with every seed (a fit's perturbed parameters).
      extra_measure: `(sim, params, state, setup) -> dict` merged into each member's row
        (e.g. its base profile as an array).

    Returns:
      `SweepResult`.
    """
    spec = spec_of(protocol)
    law = law or spec.default_law
    checked = plan(spec, law, vary=vary, seeds=seeds, params=params, options=options, dt=dt, rotation=rotation,
                   batch_size=batch_size, dtype=dtype, points=points, law_options=law_options)
    members, split = checked.members, checked.split
    dt, vary, points, batch_size = checked.dt, checked.vary, checked.points, checked.batch_size
    options = dict(options or {})
    chain = spec.chain()
    run = _Batches(chain, law, dt, rotation, devices, dtype, max_steps, progress, law_options, extra_measure)
    devices_used = len(ensemble_for(chain[0], law, dt, rotation, running.stage_options(spec, split(members[0][0])[1])[0],
                                    law_options, devices).devices)
    rows, info = [], RunInfo()
    planned = [[point, seed] for point, seed in members]
    processes = distributed.process_count()
    first, saved = 0, {}
    t0 = time.perf_counter()
    n_particles, particle_steps, failure = 0, 0, None
    try:
        if resume is not None:
            saved = _resumed(resume, planned, batch_size, devices_used)
            rows, first = list(saved["rows"]), int(saved["batch_start"])
        n_particles, particle_steps = _run_share(run, checked, info, rows, first, devices_used, checkpoint,
                                                 saved, resume)
    except (InputError, SimulationError) as error:
        if processes == 1:
            raise
        failure = error
    if processes > 1:  # one gather: whether each share failed, its rows and its work
        gathering = time.perf_counter()
        shares = distributed.gather([(None if failure is None else (type(failure).__name__, str(failure)), rows,
                                      (n_particles, particle_steps, info.steps, info.wall_seconds,
                                       info.compile_seconds, info.reallocations))])
        gather_seconds = time.perf_counter() - gathering
        _raise_first_failure([share[0] for share in shares], failure)  # none waits for rows that will not come
        rows = sorted((row for share in shares for row in share[1]), key=lambda row: row["member"])
        work = [share[2] for share in shares]
        n_particles = max(w[0] for w in work)
        particle_steps, run_seconds = sum(w[1] for w in work), max(w[3] for w in work)
        steps, compile_seconds, reallocations = max(w[2] for w in work), max(w[4] for w in work), sum(w[5] for w in work)
    else:
        run_seconds, steps, compile_seconds, reallocations = (info.wall_seconds, info.steps, info.compile_seconds,
                                                              info.reallocations)
    record = {"protocol": spec.name, "law": law, "vary": vary, "seeds": sorted({s for _, s in members}),
              "params": params or {}, "options": options, "dt": dt, "members": len(members),
              "batch_size": batch_size, "devices": devices_used, "processes": processes, "n_particles": n_particles,
              "batch_steps": steps, "compile_seconds": compile_seconds,
              "run_seconds": run_seconds, "total_seconds": time.perf_counter() - t0,
              "neighbor_reallocations": reallocations,
              "particle_steps_per_second": particle_steps / max(run_seconds, 1e-12),
              "angles": list(batch_of(spec).angles), "unit": batch_of(spec).unit, "law_options": dict(law_options or {}),
              "settings": config.settings()}
    if processes > 1:
        record["gather_seconds"] = gather_seconds  # the rows' gather, waiting for the slowest process included
    if points is not None:
        record["points"] = points
    if resume is not None:  # the timings and batch steps above are this run's, from the checkpoint on
        from jaxpile.engine import checkpoint as ckpt

        record["resumed"] = {"checkpoint": os.fspath(resume), "step": int(ckpt.read_metadata(resume)["step"]),
                             "batch_start": int(saved.get("batch_start", 0))}
    return SweepResult(rows, record)


class _Batches(NamedTuple):
    """What every batch of one sweep runs with (`sweep`'s arguments)."""

    chain: tuple  # the protocol's stages, the pile's first
    law: str
    dt: float
    rotation: bool | None
    devices: object
    dtype: object
    max_steps: int | None
    progress: bool | None
    law_options: dict | None
    extra_measure: Callable | None


def _run_share(run: _Batches, checked: Plan, info, rows: list, first: int, devices_used: int, checkpoint, saved: dict,
               resume) -> tuple[int, int]:
    """Runs this process's batches of the plan (every batch on one process)
    from member `first` on, appending each member's row to `rows`. Returns the
    disks a pile and the particle-steps run."""
    n_particles, particle_steps = 0, 0
    last = run.chain[-1]
    planned = [[point, seed] for point, seed in checked.members]
    for start, end in distributed.share(checked.batches):  # all of them, unless other processes run some
        if start < first:
            continue
        chunk, prms = checked.members[start:end], checked.member_params[start:end]
        stage_options = running.stage_options(last, checked.split(chunk[0][0])[1])  # this batch's set-up
        facts = dict(grid=planned, batch_size=checked.batch_size, devices=devices_used, batch_start=start, rows=rows,
                     process=distributed.process_index(), processes=distributed.process_count())
        steps_before = info.steps
        state, setups, last_sim = _run_batch(run, stage_options, chunk, prms, info, checkpoint, facts,
                                             saved if resume is not None and start == first else None, resume)
        n_particles = int(state.particles.position.shape[1])
        particle_steps += len(chunk) * n_particles * (info.steps - steps_before)
        for k, ((point, seed), prm, p) in enumerate(zip(chunk, prms, setups)):
            s = ensemble.member(state, k)
            row = {"member": start + k, **point, "seed": seed}
            row.update(batch_of(last).member_row(last.measure(last_sim, prm, s, p, stage_options[-1])))
            if run.extra_measure is not None:
                row.update(run.extra_measure(last_sim, prm, s, p))
            row["steps"] = int(s.step)
            rows.append(row)
    return n_particles, particle_steps


def _raise_first_failure(failures: list, own: Exception | None) -> None:
    """Across processes, each share's failure (None: it ran) as gathered:
    every process raises the first, its own error as it is, another's named
    by its process."""
    for k, failure in enumerate(failures):
        if failure is not None:
            if own is not None:
                raise own
            kind = SimulationError if failure[0] == "SimulationError" else InputError
            raise kind(f"process {k} of {len(failures)} failed: {failure[1]}")


def _resumed(resume, planned: list, batch_size: int, devices: int) -> dict:
    """What a sweep's checkpoint recorded, when it was written by this same sweep."""
    from jaxpile.engine import checkpoint as ckpt

    saved = ckpt.read_metadata(resume)["extra"]
    if saved.get("grid") != planned or saved.get("batch_size") != batch_size:
        raise InputError(f"{resume} was written by another sweep (other members or batch size); "
                         "resume it with the command that made it.")
    here = (distributed.process_index(), distributed.process_count())
    if (saved.get("process", 0), saved.get("processes", 1)) != here:
        raise InputError(f"{resume} was saved by process {saved.get('process', 0)} of {saved.get('processes', 1)}, "
                         f"this is process {here[0]} of {here[1]}: each process resumes its own checkpoint, on "
                         "as many processes as the sweep started on.")
    if saved.get("devices") != devices:
        raise InputError(f"{resume} was written on {saved.get('devices')} device(s), this run has "
                         f"{devices}: the batch is padded to a multiple of the device count, so "
                         "resume it with as many devices.")
    return saved


def _run_batch(run: _Batches, stage_options: list, chunk: list, prms: list, info, checkpoint, facts: dict,
               saved: dict | None, resume):
    """One batch (`chunk`: its members' points and seeds, `prms`: their law
    parameters) through every stage of the protocol (stage-synchronous: each
    member starts the next stage from where it ended the last, contact
    history kept). `saved`: the checkpoint's record when this batch is the one
    it continues. Returns `(state, each member's last set-up, last simulator)`."""
    from jaxpile.engine import checkpoint as ckpt

    chain, law, dt, rotation, devices, law_options = run.chain, run.law, run.dt, run.rotation, run.devices, run.law_options
    first = chain[0]
    ens = ensemble_for(first, law, dt, rotation, stage_options[0], law_options, devices)
    setups = [first.setup(stage_options[0], law=law, seed=seed, dt=dt, dtype=run.dtype) for _, seed in chunk]
    state = ens.init(prms, setups)
    saved_params = ens.as_batch(prms, ensemble.batch_size(state))  # as `Ensemble.run` records them
    at_stage = int(saved.get("stage", 0)) if saved is not None else 0
    for k, (stage, options) in enumerate(zip(chain, stage_options)):
        stage_ens = ens if k == 0 else ensemble_for(stage, law, dt, rotation, options, law_options, devices)
        if k > 0:
            piles = [ensemble.member(state, i) for i in range(len(chunk))]
            started = [running.stage_start(stage, law, dt, options, pile) for pile in piles]
            setups = [p for _, p in started]
            state = stage_ens.shard(ensemble.stack_states([s for s, _ in started]))
        if k < at_stage:  # a resume past this stage: its start only shapes the template
            continue
        if k > 0 and k == at_stage:  # the saved stage: its members' measured infos come from the file
            setups = [p._replace(info=i) for p, i in zip(setups, saved["stage_infos"])]
        elif k > 0:
            setups = [p._replace(info={**p.info, **running.stage_facts(stage, pile, p)})
                      for pile, p in zip(piles, setups)]
        position = None
        if k == at_stage and saved is not None:
            state = stage_ens.shard(ckpt.restore(resume, state, stage_ens.sim.law, saved_params))
            position = stages.Position.saved(saved, resume)
        stage_facts = {} if k == 0 else dict(stage_infos=[p.info for p in setups])
        # the rows list is written as it stands at each save: the batches measured so far
        saves = ckpt.with_facts(checkpoint, **facts, stage=k, **stage_facts)
        state, _ = stages.run_phases(stage_ens, prms, state, stage.phases(setups[0], options), count=len(chunk),
                                     max_steps=run.max_steps if k == 0 else None, position=position,
                                     progress=run.progress, info=info, checkpoint=saves)
    return state, setups, stage_ens.sim


__all__ = ["MEMBER_COLUMNS", "Plan", "SweepResult", "ensemble_for", "first_setup", "grid", "option_names", "plan",
           "spec_of", "sweep"]
