"""The pile a pathwise fit differentiates, as one named record: `problem(...)`
builds it from a protocol that offers one (`PATHWISE`: the deterministic
lattice; random piles are fitted by their ensembles, `ensemble_fit`), and its
`profile` and `objective` are the differentiable profile and loss that `fit`
minimises."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple

from jaxpile.batches import BATCHES
from jaxpile.errors import InputError
from jaxpile.fit import pathwise_lattice
from jaxpile.fit.simulated import profile_objective, simulated_profile
from jaxpile.protocols import PROTOCOLS


class Pathwise(NamedTuple):
    """A protocol's pathwise fit (`jaxpile fit --estimator pathwise`).

    Attributes:
      problem: `(law, start, *, size, seed, options, bins, window, progress)
        -> (sim, params, state, steps, setting, window, description)`: the
        pile built with the starting parameters, and the steps differentiated from it.
      dry_run: `(law, start, *, size, seed, options, window) -> (what,
        particles, params, build steps, steps differentiated)`, set up and
        checked, not run.
      default_size: the pile's size when none is given.
    """

    problem: Callable
    dry_run: Callable
    default_size: int


PATHWISE: dict[str, Pathwise] = {
    "lattice": Pathwise(pathwise_lattice.pathwise_problem, pathwise_lattice.pathwise_dry_run, default_size=6),
}
"""The protocols that offer a pathwise fit, by name."""


class FitProblem(NamedTuple):
    """A pile to differentiate, set up and ready to roll out.

    Attributes:
      simulator: the `Simulator`.
      params: the law's parameters it was built with (the fit's start).
      state: the state the differentiated rollout starts from.
      steps: the rollout's length.
      setting: how the base profile is read (`ProfileSetting`).
      window: differentiate only the last `window` steps (None: all).
      description: what was built, in words.
    """

    simulator: Any
    params: Any
    state: Any
    steps: int
    setting: Any
    window: int | None
    description: str

    def profile(self, params=None):
        """The base profile after the rollout with `params` (default: the
        problem's), differentiable in them (`simulated_profile`)."""
        return simulated_profile(self.simulator, self.params if params is None else params, self.state, self.steps,
                                 self.setting, window=self.window)

    def objective(self, target, **weights):
        """`params -> loss` against `target` (`profile_objective`; `weights`:
        horizontal_weight, dip_weight)."""
        return profile_objective(self.simulator, self.state, self.steps, self.setting, target, window=self.window,
                                 **weights)


def pathwise_of(protocol: str, remedy: str = "an ensemble estimator (jaxpile.fit.ensemble_fit)"):
    """The protocol's pathwise fit (`PATHWISE`), or `InputError` naming the
    protocols that offer one and `remedy`."""
    if protocol not in PATHWISE:
        offered = [name for name in PATHWISE if name in PROTOCOLS]
        batch = BATCHES.get(protocol)
        why = ("" if protocol not in PROTOCOLS or batch is None or batch.deterministic else
               f"the {protocol} protocol builds random piles, and the gradient through one of them says how that "
               "packing relaxes, not how the protocol's piles depend on the parameters (docs/gradients.md); ")
        raise InputError(f"{why}pathwise fits run on the deterministic {', '.join(offered)} protocol(s); fit the "
                         f"{protocol} protocol with {remedy}.")
    return PATHWISE[protocol]


def problem(protocol: str, law: str | None = None, start: dict | None = None, *, size: int | None = None,
            seed: int = 0, options: dict | None = None, bins: int | None = None, window: int = 2000,
            progress=None) -> FitProblem:
    """The pile a pathwise fit of `protocol` differentiates (the lattice: the
    whole quasi-static loading of a `size`-layer pile).

    Args:
      protocol: a protocol whose spec offers a pathwise fit ("lattice").
      law: the law's name (default: the protocol's).
      start: the law parameters to build with, as a dict (default: the protocol's setting).
      size: the protocol's size (layers or disks; default its own).
      seed, options, bins, window, progress: as the protocol's `pathwise.problem` reads them.
    """
    pathwise = pathwise_of(protocol)
    size = pathwise.default_size if size is None else size
    return FitProblem(*pathwise.problem(law or PROTOCOLS[protocol].default_law, dict(start or {}), size=size, seed=seed,
                                             options=options, bins=bins, window=window, progress=progress))


__all__ = ["FitProblem", "PATHWISE", "Pathwise", "pathwise_of", "problem"]
