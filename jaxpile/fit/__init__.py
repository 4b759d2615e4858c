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
(`Transform`), keeping the rest of the params pytree fixed.

The pieces live in one module each, and every name below is re-exported here:

- `profiles`: base loads, smooth and normalised profiles, and the features
  read off a profile (`dip_below_peak`, `central_slope`);
- `targets`: `ProfileTarget`, from a CSV file, Smid & Novosad's declared
  shape, or a computed profile;
- `losses`: a predicted profile against a target;
- `simulated`: the profile and the loss of a rollout (`ProfileSetting`, which
  says how the profile is read, lives in `jaxpile.measure.heap`);
- `problem`: the pile a pathwise fit differentiates (`FitProblem`), built
  from a protocol that offers one;
- `optimise`: the log-space `Transform`, forward or reverse gradients, the
  optax loop `descend` and its figure.

Fits to the ensembles that a protocol builds are in `ensemble_fit` (with
`estimators`, `construction`, `regression`, `stats`, `verdict`); a fit to a
measurement (`measured`: `Measurement`, `load_measurement`) in one call is
`calibrate` (also `jaxpile.calibrate`), what `jaxpile fit --target FILE` does.

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

Limits of the gradients: contacts switching on or off, a Coulomb cap switching
between sticking and sliding, and the plain maximum of `normalise` are
differentiable almost everywhere, not everywhere; a loss is smooth in a
parameter only as long as no such switch happens within the step the optimiser
takes.
"""

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
]
