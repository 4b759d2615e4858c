"""Differentiable losses on base-force profiles, and optax fitting loops.

The chain a calibration differentiates, every piece a pure jnp function of the
law parameters (so `jax.grad` runs through a whole `Simulator.rollout`):

  state --`base_load`--> every base contact's x, normal and horizontal force
  (fixed shapes, padding masked out by a 0/1 `weight`, no boolean indexing)
  --`smooth_base_profile`--> a Gaussian-smoothed profile over the base,
  normalised by its maximum (x/B, F/F_max: the papers' axes)
  --`profile_loss` / `dip_loss` / `feature_loss`--> a scalar against a
  `ProfileTarget` (`load_profile_csv` for measured points, `smid_novosad_profile`
  for the features Smid & Novosad's experiment is reported to show).

`descend` then runs an optax optimiser over chosen parameters in log space
(`Transform`), keeping the rest of the params pytree fixed. Every name below is
re-exported here from its module: `profiles` (base loads, profiles and their
features), `targets` (`ProfileTarget`), `losses`, `simulated` (the profile and
loss of a rollout; `ProfileSetting` lives in `jaxpile.measure.heap`),
`problem` (`FitProblem`, the pile a pathwise fit differentiates) and
`optimise` (`Transform`, forward or reverse gradients, `descend`, its figure).
Fits to a protocol's ensembles are in `ensemble_fit` (with `estimators`,
`construction`, `regression`, `stats`, `verdict`); `calibrate` (also
`jaxpile.calibrate`) fits a measurement (`measured`) in one call, as
`jaxpile fit --target FILE` does.

Example:
  >>> import jax.numpy as jnp
  >>> import jaxpile
  >>> from jaxpile import fit
  >>> from jaxpile.laws import hooke
  >>> params = hooke.make_params(kn=1e4, mu=0.5)
  >>> loss = lambda p: (jnp.log(p.mu) - jnp.log(0.3)) ** 2
  >>> result = fit.descend(loss, params, ["mu"], steps=400)  # doctest: +SKIP
  >>> float(result.params.mu)  # doctest: +SKIP
  0.3...

A loss is smooth in a parameter only as long as no contact switches on or off,
no Coulomb cap switches between sticking and sliding and no maximum of
`normalise` changes hands within the optimiser's step: these are
differentiable almost everywhere, not everywhere (docs/gradients.md#what-works).
"""

from jaxpile.fit import (construction, ensemble_fit, ensemble_runs, ensemble_targets, estimators, regression, stats,
                         targets, verdict)
from jaxpile.fit.calibrate import calibrate
from jaxpile.fit.losses import dip_loss, feature_loss, profile_loss
from jaxpile.fit.measured import Measurement, load_measurement
from jaxpile.fit.optimise import (
    FORWARD_MODE_MAX,
    GRADIENT_MODES,
    LOWER_BOUNDS,
    UPPER_BOUNDS,
    FitResult,
    Transform,
    descend,
    fit_figure,
    gradient_mode,
    to_constrained,
    to_unconstrained,
    value_and_gradient,
)
from jaxpile.fit.profiles import (
    BASES,
    BaseLoad,
    Profile,
    base_load,
    dip_below_peak,
    central_slope,
    normalise,
    profile_peak,
    smooth_base_profile,
    smooth_profile,
)
from jaxpile.fit.problem import FitProblem, problem
from jaxpile.fit.simulated import profile_objective, simulated_profile
from jaxpile.fit.targets import (
    SMID_NOVOSAD_ANGLE_DEGREES,
    SMID_NOVOSAD_DIP_RANGE,
    ProfileTarget,
    load_profile_csv,
    smid_novosad_profile,
    target_from_profile,
)
from jaxpile.measure.heap import ProfileSetting

__all__ = [
    "BASES",
    "LOWER_BOUNDS",
    "UPPER_BOUNDS",
    "Measurement",
    "SMID_NOVOSAD_ANGLE_DEGREES",
    "SMID_NOVOSAD_DIP_RANGE",
    "BaseLoad",
    "FORWARD_MODE_MAX",
    "FitProblem",
    "FitResult",
    "GRADIENT_MODES",
    "Profile",
    "ProfileSetting",
    "ProfileTarget",
    "Transform",
    "base_load",
    "calibrate",
    "dip_below_peak",
    "central_slope",
    "dip_loss",
    "feature_loss",
    "descend",
    "fit_figure",
    "gradient_mode",
    "load_measurement",
    "load_profile_csv",
    "normalise",
    "profile_loss",
    "profile_objective",
    "problem",
    "profile_peak",
    "smid_novosad_profile",
    "smooth_base_profile",
    "smooth_profile",
    "simulated_profile",
    "target_from_profile",
    "to_constrained",
    "to_unconstrained",
    "value_and_gradient",
    # the ensemble fit's modules, public as modules
    "construction",
    "ensemble_fit",
    "ensemble_runs",
    "ensemble_targets",
    "estimators",
    "regression",
    "stats",
    "targets",
    "verdict",
]
