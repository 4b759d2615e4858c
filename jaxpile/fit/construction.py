"""A protocol's construction as fixed-length rollouts of its B piles, for the
truncated pathwise estimator (`estimators.truncated_pathwise`: `advance`,
`statistics`, `start`, `steps`) in `ensemble_fit.fit(estimator="truncated")`
and `benchmarks/studies/fitting/estimator_study.py`.

A protocol whose piles a batch builds in one stage can be built this way: the
batch runs them as chunks of its step function (its driver reads the set-up
from the state), and a rollout of the construction's length is those chunks
without the host in between. Its statistics are the base profile over the
batch's extent; the angles of repose are fitted on the host and have no
tangent. A protocol that continues another's pile (the tilt) is two stages
and is refused.
"""

from __future__ import annotations

import json
from typing import Callable, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxpile import batches
from jaxpile.batches import batch_of
from jaxpile.engine import batch, ensemble
from jaxpile.engine import neighbors as nb
from jaxpile.engine import pairs as pair_list
from jaxpile.errors import InputError
from jaxpile.fit.profiles import smooth_base_profile
from jaxpile.measure import analysis
from jaxpile.protocols import PROTOCOLS, stages


def rolled_out() -> tuple[str, ...]:
    """The protocols whose construction can be rolled out: one stage, and a base to read."""
    return tuple(sorted(name for name, spec in PROTOCOLS.items()
                        if spec.starts_from is None and batch_of(spec).extent is not None))


def check(runner, statistics) -> None:
    """Raises `InputError` unless `runner`'s piles can be built as rollouts and
    `statistics` are traceable (before any pile runs)."""
    if runner.protocol not in rolled_out():
        spec = PROTOCOLS.get(runner.protocol)
        why = (f"continues the {spec.starts_from.name} pile (two stages)" if spec is not None and spec.starts_from
               else "has no base to read a profile on")
        raise InputError(f"the truncated pathwise estimator rolls out a construction of one stage and reads its "
                         f"base profile: the {runner.protocol} pile {why}; it runs for {', '.join(rolled_out())}: use --estimator "
                         "central or smoothing.")
    if statistics.columns or not statistics.bins:
        raise InputError("the truncated pathwise estimator differentiates the base profile alone (the angles "
                         "are fitted on the host, with no tangent): fit bins > 0 and no columns.")


class Construction:
    """The B piles of `seeds` built as `runner` builds them, as rollouts at the
    log-parameters `theta` of `names`.

    The piles are set up and simulated as a sweep builds them (the runner's
    options, fixed parameters, rotation and law options); a rollout carries
    every disk (it has no host blocks). A host run to the protocol's finish at theta gives the
    construction's length (the longest member's) and sizes the lists, with
    head-room (a rollout has no overflow handling); a rollout at theta that
    still overflows is refused. Every heap is rolled out to that length: one
    that finished earlier goes on resting (the sweep freezes it at its own
    finish), so it may creep a little further than the sweep's.

    Attributes:
      advance: `(theta, state, n) -> state`, n steps of every pile.
      statistics: `(theta, state) -> [B, k]` the base profile (normal, then
        horizontal if the statistics take it).
      start: the piles' first state; steps: the construction's length.
      particles: disks per pile (the rollouts carry them all).
    """

    def __init__(self, runner, seeds, statistics, names, theta):
        check(runner, statistics)
        names, seeds = list(names), [int(s) for s in seeds]
        law, spec = runner.law_name(), runner.spec()
        dt = spec.default_dt(law) if runner.dt is None else float(runner.dt)  # as the sweep's piles: the schedule too
        options = spec.make_options(runner.options or {})
        # set up and checked as the sweep's piles (e.g. a voidage map too fine for the memory)
        protocols = [spec.setup(options, law=law, seed=s, dt=dt, dtype=runner.dtype) for s in seeds]
        extent = tuple(batch_of(spec).extent(protocols[0]))
        pieces = _pieces(spec, law, dt, options, runner, tuple(names), extent, statistics)
        self.sim, self.advance, self.statistics = pieces.sim, pieces.advance, pieces.statistics
        p0 = pieces.params(jnp.asarray(theta))
        start = pieces.ensemble.init([p0] * len(protocols), protocols)
        end, _ = stages.run_phases(pieces.ensemble, [p0] * len(protocols), start, spec.phases(protocols[0], options),
                                   count=len(protocols), max_steps=runner.max_steps, progress=False)
        self.steps = max(int(m.step) for m in ensemble.members(end, len(protocols)))
        slots = int(end.neighbors.max_occupancy) + 8
        pairs = pair_list.aligned(int(1.5 * int(end.contacts.pairs.shape[-2])))
        self.start = batch.stack([batch.at_capacity(batch.member(start, i), slots, None, pairs)
                                  for i in range(len(protocols))])
        self.particles = int(self.start.particles.position.shape[1])
        final = pieces.rollout(jnp.asarray(theta), self.start, self.steps)
        if bool(np.any(np.asarray(nb.overflowed(final)))):
            raise InputError("a neighbour or contact list overflowed inside the construction's rollout at theta; "
                             "the truncated estimator cannot resize it there: use --estimator central.")

    def particle_steps(self) -> float:
        """Every pile's steps in the host run that sized the lists, the rollout
        that checked them, and the windows' rollout (its tangents not counted)."""
        return 3.0 * self.start.particles.position.shape[0] * self.particles * self.steps


class _Pieces(NamedTuple):
    sim: object
    ensemble: object
    params: Callable
    advance: Callable
    statistics: Callable
    rollout: Callable


_PIECES: dict = {}


def _pieces(spec, law: str, dt: float, options, runner, names: tuple, extent: tuple, statistics) -> _Pieces:
    """The simulator, its batch and the rollout functions of one construction's
    configuration, made once: a fit builds a new `Construction` at every
    iterate, and with the same functions its host run, its checking rollout
    and the estimator's windows (`estimators.truncated_pathwise`, keyed by
    `advance`) compile once for the whole fit. The batch is the sweep's own
    (`batches.ensemble_for`), so its host run compiles nothing a sweep at
    these settings has not."""
    bins, bandwidth, horizontal = int(statistics.bins), statistics.bandwidth, bool(statistics.horizontal)
    fixed, rotation, law_options = runner.params or {}, runner.rotation, runner.law_options
    key = (spec.name, law, float(dt), json.dumps([options.as_dict(), fixed, law_options, rotation], sort_keys=True,
                                                  default=repr), str(runner.dtype), names, extent, bins, bandwidth,
           horizontal)
    if key in _PIECES:
        return _PIECES[key]
    runs = batches.ensemble_for(spec, law, dt, rotation, options, law_options)
    sim = runs.sim
    base = spec.law_and_params(law, dict(fixed), rotation, runner.dtype, law_options)[2]
    base_name, x_left, x_right = extent

    def params(t):  # each value in its parameter's own dtype (a float32 pile stays float32)
        return base.set(**{n: jnp.exp(t[i]).astype(jnp.asarray(getattr(base, n)).dtype)
                           for i, n in enumerate(names)})

    def advance(t, state, k):
        return jax.vmap(lambda m: sim.rollout(params(t), m, k))(state)

    def stats(t, state):
        def one(m):
            load = analysis.base_load(sim, params(t), m, base=base_name)
            prof = smooth_base_profile(load, x_left=x_left, x_right=x_right, bins=bins, bandwidth=bandwidth)
            return jnp.concatenate([prof.normal, prof.horizontal]) if horizontal else prof.normal
        return jax.vmap(one)(state)

    if len(_PIECES) >= 4:  # a few configurations at a time: each holds compiled programs
        _PIECES.pop(next(iter(_PIECES)))
    _PIECES[key] = pieces = _Pieces(sim, runs, params, advance, stats,
                                    jax.jit(advance, static_argnums=2))
    return pieces
