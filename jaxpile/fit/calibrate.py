"""`calibrate`: a law fitted to a measurement from Python in one call, what
`jaxpile fit --target FILE` does (`fit.measured` reads the measurement;
`ensemble_fit.fit` fits the ensemble mean of the protocol's piles to it, its
record holds the first pass and the verdict; with `estimator="pathwise"`,
`pile_fit.fit_pile` fits one deterministic pile through its gradient)."""

from __future__ import annotations

import os
from typing import Sequence

import numpy as np

from jaxpile.batches import batch_of
from jaxpile.errors import InputError
from jaxpile.fit import ensemble_fit, pile_fit
from jaxpile.fit.measured import Measurement, load_measurement, statistics_of, target_of


def calibrate(protocol: str, measurement: str | os.PathLike | Measurement, params: Sequence[str] | str, *,
              law: str | None = None, start: dict | None = None, fixed: dict | None = None,
              options: dict | None = None, ensemble: int | None = None, rolling: str | None = None,
              rotation: bool | None = None, estimator: str = "central", step: float = 0.05, steps: int | None = None,
              optimizer: str | None = None, lr: float | None = None, normalised_by: str | None = None,
              identifiability: str = "refuse", checkpoint: str | None = None, resume: bool = False,
              progress=True) -> ensemble_fit.EnsembleFitResult | pile_fit.PileFit:
    """Fits the law parameters `params` so that the ensemble mean of
    `protocol`'s piles matches `measurement`.

    Args:
      protocol: the pile (`"pour"`, `"box"`, ...).
      measurement: a file (`fit.load_measurement`: a CSV profile, a JSON or
        TOML of scalars and a profile) or a `fit.Measurement`.
      params: the parameters to fit (names, or one comma-separated string).
      law: the contact law (default: the protocol's).
      start: starting values (default: the law's, as the protocol sets it).
      fixed: law parameters held at other values than the protocol's.
      options: the protocol's options (`{"n": 100}`).
      ensemble: piles per ensemble (default 8; 1 for a deterministic protocol).
      rolling, rotation: the law's rolling resistance (`"sds"`) and spins.
      estimator: how the gradient is taken: `"central"` differences of the
        ensemble mean (the default), `"smoothing"` or `"truncated"`
        (`ensemble_fit.Gradient`), or `"pathwise"`: jax.grad through one pile
        of a deterministic protocol (the lattice, the sloped pile) to a
        profile scaled by its maximum, without standard errors.
      step: central differences' step in log units (a chaotic pile needs
        a wide one, ~0.2-0.4: docs/calibrate.md).
      steps: iterations at most (default 6 Gauss-Newton steps of an ensemble
        fit, 40 optimiser steps of a pathwise one).
      optimizer, lr: the ensemble fit's optimiser (default `"gauss-newton"`;
        an optax one's rate default 0.1) or the pathwise fit's optax one
        (default `"adam"` at 0.05).
      normalised_by: a measured profile's scale where its file does not say.
      identifiability: `"refuse"` or `"warn"` (`ensemble_fit.fit`).
      checkpoint: a JSON path for the fit's history; `resume` continues it.
      progress: print the first pass, each iteration and the verdict.

    Returns:
      `EnsembleFitResult`: `values`, `interval`, and `record["verdict"]`,
      `record["first_pass"]`; for `estimator="pathwise"`, `pile_fit.PileFit`:
      `result` (`descend`'s: the fitted `params`, the loss path) and the
      pile's profile `before` and `after`.
    """
    from jaxpile import batches

    if resume and checkpoint is None:
        raise InputError("resume=True continues the fit saved at checkpoint=PATH: give the checkpoint.")
    spec = batches.spec_of(protocol)
    if not isinstance(measurement, Measurement):
        measurement = load_measurement(measurement, normalised_by)
    names = [n.strip() for n in params.split(",")] if isinstance(params, str) else list(params)
    law = law or spec.default_law
    if estimator == "pathwise":
        return _pathwise(spec, measurement, names, law, start, fixed, options, rolling, rotation, ensemble, steps,
                         optimizer, lr, checkpoint, progress)
    if estimator not in ensemble_fit.ESTIMATORS:
        raise InputError(f"estimator must be one of {', '.join(ensemble_fit.ESTIMATORS + ('pathwise',))}; "
                         f"got {estimator!r}.")
    law_options = {"rolling": rolling} if rolling else None
    _, contact_law, defaults = spec.law_and_params(law, dict(fixed or {}), rotation, None, law_options)
    given = dict(start or {})
    unset = [n for n in names if n not in given and getattr(defaults, n, None) is None]
    if unset:
        raise InputError(f"{law} has no default for {unset[0]}: give its start (start={{{unset[0]!r}: VALUE}}).")
    start = {n: float(given[n]) if n in given else float(np.asarray(getattr(defaults, n))) for n in names}
    statistics = statistics_of(measurement, spec)
    target = target_of(measurement, statistics)
    b = int(ensemble) if ensemble is not None else (1 if batch_of(spec).deterministic else 8)
    runner = ensemble_fit.Runner(protocol, law, params=dict(fixed) if fixed else None, options=options,
                                 law_options=law_options, rotation=rotation)
    return ensemble_fit.fit(runner, names, start, target, seeds=range(b), statistics=statistics, progress=progress,
                            identifiability=identifiability, optimizer=optimizer or "gauss-newton",
                            lr=0.1 if lr is None else lr,
                            gradient=ensemble_fit.Gradient(estimator=estimator, step=step),
                            stopping=ensemble_fit.Stopping(steps=6 if steps is None else steps),
                            saving=ensemble_fit.Saving(checkpoint=checkpoint, resume=checkpoint if resume else None))


def _pathwise(spec, measurement, names, law, start, fixed, options, rolling, rotation, ensemble, steps, optimizer,
              lr, checkpoint, progress) -> pile_fit.PileFit:
    """The pathwise fit of one pile of a deterministic protocol to the measured
    profile (`pile_fit.fit_pile`), each input it cannot take refused."""
    import optax

    from jaxpile.fit.problem import pathwise_of

    pathwise_of(spec.name, 'estimator="central" (the ensemble mean of its piles fitted to the measurement)')
    given = {"rolling": rolling, "rotation": rotation, "ensemble": ensemble, "checkpoint": checkpoint}
    given = [k for k, v in given.items() if v is not None]
    if given:
        raise InputError(f"a pathwise fit builds one pile with the protocol's own law readings and saves nothing: "
                         f"{', '.join(given)} are for the ensemble estimators.")
    if measurement.scalars or measurement.profile is None:
        raise InputError(f"a pathwise fit compares base profiles; {measurement.source} holds "
                         f"{'scalars ' + ', '.join(sorted(measurement.scalars)) if measurement.scalars else 'none'}: "
                         'fit it with estimator="central".')
    target = pile_fit.pathwise_target(measurement.profile, measurement.source)
    name = optimizer or "adam"
    make = getattr(optax, name, None)
    if name.startswith("_") or not callable(make):
        raise InputError(f"optimizer {name!r} is not an optax optimiser; try adam, sgd, adamw or rmsprop.")
    options = dict(options or {})
    size = options.pop(spec.size, None)
    values = {**(fixed or {}), **(start or {})}
    return pile_fit.fit_pile(spec.name, law, names, values, target, make(0.05 if lr is None else lr),
                             steps=40 if steps is None else steps, size=size, options=options,
                             progress=None if progress else False)


__all__ = ["calibrate"]
