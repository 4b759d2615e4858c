"""A protocol's construction as fixed-length rollouts of its B piles, for the
truncated pathwise estimator (`estimators.truncated_pathwise`: `advance`,
`statistics`, `start`, `steps`) in `ensemble_fit.fit(estimator="truncated")`
and `benchmarks/studies/fitting/estimator_study.py`.

Only the pour is built this way: its construction is one stage whose every
step a rollout can carry (the release schedule is read from the state), and
its base profile is traceable. The angles of repose are fitted on the host and
have no tangent, so the statistics are the base profile alone.
"""

from __future__ import annotations

import json
from typing import Callable, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxpile.engine import batch, ensemble
from jaxpile.engine import neighbors as nb
from jaxpile.engine import pairs as pair_list
from jaxpile.errors import InputError
from jaxpile.fit.profiles import smooth_base_profile
from jaxpile.measure import analysis
from jaxpile.protocols import pour, running

PROTOCOLS = ("pour",)


def check(runner, statistics) -> None:
    """Raises `InputError` unless `runner`'s piles can be built as rollouts and
    `statistics` are traceable (before any pile runs)."""
    if runner.protocol not in PROTOCOLS:
        raise InputError(f"the truncated pathwise estimator runs a construction as rollouts, which only "
                         f"{', '.join(PROTOCOLS)} is built for; the {runner.protocol} pile: use --estimator "
                         "central or smoothing.")
    if statistics.columns or not statistics.bins:
        raise InputError("the truncated pathwise estimator differentiates the base profile alone (the angles "
                         "are fitted on the host, with no tangent): fit bins > 0 and no columns.")
    if runner.law_options:
        raise InputError(f"the truncated pathwise estimator builds its rollouts with the law's own readings; "
                         f"law options {sorted(runner.law_options)} (e.g. --rolling): use --estimator central or "
                         "smoothing.")


class Construction:
    """The B piles of `seeds` built as `runner` builds them, as rollouts at the
    log-parameters `theta` of `names`.

    The piles are set up as a sweep sets them up (the runner's options and
    fixed parameters), on a simulator that carries every disk (a rollout has
    no host blocks). A host run to the protocol's finish at theta gives the
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
        law = runner.law_name()
        spec = pour.SPEC
        dt = spec.default_dt(law) if runner.dt is None else float(runner.dt)  # as the sweep's piles: the schedule too
        options = spec.make_options(runner.options or {})
        # set up and checked as the sweep's piles (e.g. a voidage map too fine for the memory)
        protocols = [running.member_setup(spec, law, s, dt, options, runner.dtype) for s in seeds]
        extent = tuple(spec.batch.extent(protocols[0]))
        pieces = _pieces(law, dt, runner.dtype, runner.params, tuple(names), extent, statistics)
        self.sim, self.advance, self.statistics = pieces.sim, pieces.advance, pieces.statistics
        p0 = pieces.params(jnp.asarray(theta))
        start = pieces.ensemble.init([p0] * len(protocols), protocols)
        budget = runner.max_steps if runner.max_steps is not None else spec.budget(protocols[0], options)
        end = pieces.ensemble.run([p0] * len(protocols), start, int(budget),
                                  until=spec.finished(protocols[0], options), progress=False)
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


def _pieces(law: str, dt: float, dtype, fixed: dict | None, names: tuple, extent: tuple, statistics) -> _Pieces:
    """The simulator, its batch and the rollout functions of one construction's
    configuration, made once: a fit builds a new `Construction` at every
    iterate, and with the same functions its host run, its checking rollout
    and the estimator's windows (`estimators.truncated_pathwise`, keyed by
    `advance`) compile once for the whole fit."""
    bins, bandwidth, horizontal = int(statistics.bins), statistics.bandwidth, bool(statistics.horizontal)
    key = (law, float(dt), str(dtype), json.dumps(fixed or {}, sort_keys=True, default=repr), names, extent,
           bins, bandwidth, horizontal)
    if key in _PIECES:
        return _PIECES[key]
    sim = pour.make_simulator(law, dt=dt, in_play=None)
    base = pour.law_params(law, dtype=dtype, **(fixed or {}))
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
    runner = ensemble.Ensemble(sim, sequential=pour.SPEC.batch.sequential)
    _PIECES[key] = pieces = _Pieces(sim, runner, params, advance, stats,
                                    jax.jit(advance, static_argnums=2))
    return pieces
