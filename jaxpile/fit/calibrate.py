"""`calibrate`: a law fitted to a measurement from Python in one call, what
`jaxpile fit --target FILE` does (`fit.measured` reads the measurement,
`ensemble_fit.fit` fits the ensemble mean of the protocol's piles to it, its
record holds the first pass and the verdict)."""

from __future__ import annotations

import os
from typing import Sequence

import numpy as np

from jaxpile.errors import InputError
from jaxpile.fit import ensemble_fit
from jaxpile.fit.measured import Measurement, load_measurement, statistics_of, target_of


def calibrate(protocol: str, measurement: str | os.PathLike | Measurement, params: Sequence[str] | str, *,
              law: str | None = None, start: dict | None = None, fixed: dict | None = None,
              options: dict | None = None, ensemble: int | None = None, rolling: str | None = None,
              rotation: bool | None = None, step: float = 0.05, steps: int = 6, normalised_by: str | None = None,
              identifiability: str = "refuse", checkpoint: str | None = None, resume: bool = False,
              progress=True) -> ensemble_fit.EnsembleFitResult:
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
      step: central differences' step in log units (a chaotic pile needs
        a wide one, ~0.2-0.4: docs/calibrate.md).
      steps: Gauss-Newton iterations at most.
      normalised_by: a measured profile's scale where its file does not say.
      identifiability: `"refuse"` or `"warn"` (`ensemble_fit.fit`).
      checkpoint: a JSON path for the fit's history; `resume` continues it.
      progress: print the first pass, each iteration and the verdict.

    Returns:
      `EnsembleFitResult`: `values`, `interval`, and `record["verdict"]`,
      `record["first_pass"]`.
    """
    from jaxpile import sweeps

    if resume and checkpoint is None:
        raise InputError("resume=True continues the fit saved at checkpoint=PATH: give the checkpoint.")
    spec = sweeps.spec_of(protocol)
    if not isinstance(measurement, Measurement):
        measurement = load_measurement(measurement, normalised_by)
    names = [n.strip() for n in params.split(",")] if isinstance(params, str) else list(params)
    law = law or spec.default_law
    law_options = {"rolling": rolling} if rolling else None
    _, contact_law, defaults = spec.law_and_params(law, dict(fixed or {}), rotation, None, law_options)
    given = dict(start or {})
    unset = [n for n in names if n not in given and getattr(defaults, n, None) is None]
    if unset:
        raise InputError(f"{law} has no default for {unset[0]}: give its start (start={{{unset[0]!r}: VALUE}}).")
    start = {n: float(given[n]) if n in given else float(np.asarray(getattr(defaults, n))) for n in names}
    statistics = statistics_of(measurement, spec)
    target = target_of(measurement, statistics)
    b = int(ensemble) if ensemble is not None else (1 if spec.batch.deterministic else 8)
    runner = ensemble_fit.Runner(protocol, law, params=dict(fixed) if fixed else None, options=options,
                                 law_options=law_options, rotation=rotation)
    return ensemble_fit.fit(runner, names, start, target, seeds=range(b), statistics=statistics, progress=progress,
                            identifiability=identifiability, gradient=ensemble_fit.Gradient(step=step),
                            stopping=ensemble_fit.Stopping(steps=steps),
                            saving=ensemble_fit.Saving(checkpoint=checkpoint, resume=checkpoint if resume else None))


__all__ = ["calibrate"]
