"""Differentiable losses on base-force profiles, and optax fitting loops.

The chain a calibration differentiates, every piece a pure jnp function of the
law parameters (so `jax.grad` runs through a whole `Simulator.rollout`):

  state --`base_load`--> every base contact's x, normal and horizontal force
  (fixed shapes, padding masked out by a 0/1 `weight`, no boolean indexing)
  --`smooth_base_profile`--> a Gaussian-smoothed profile over the base,
  normalised by its maximum (x/B, F/F_max: the papers' axes)
  --`profile_loss` / `dip_loss` / `feature_loss`--> a scalar against a
  `ProfileTarget` (`load_profile_csv` for measured points, `smid_novosad_target`
  for the features Smid & Novosad's experiment is reported to show).

`fit` then runs an optax optimiser over chosen parameters in log space
(`Transform`), keeping the rest of the params pytree fixed.

Example:
  >>> import jax.numpy as jnp
  >>> import jaxpile
  >>> from jaxpile import fit
  >>> from jaxpile.laws import hooke
  >>> params = hooke.make_params(kn=1e4, mu=0.5)
  >>> loss = lambda p: (jnp.log(p.mu) - jnp.log(0.3)) ** 2
  >>> result = fit.fit(loss, params, ["mu"], steps=400)  # doctest: +SKIP
  >>> float(result.params.mu)  # doctest: +SKIP
  0.3...

Limits of the gradients: contacts switching on or off, a Coulomb cap switching
between sticking and sliding, and the plain maximum of `normalise` are
differentiable almost everywhere, not everywhere; a loss is smooth in a
parameter only as long as no such switch happens within the step the optimiser
takes.
"""

from __future__ import annotations

import csv
import dataclasses
import math
import os
import warnings
from collections.abc import Callable, Mapping, Sequence
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optax

from jaxpile.measure import analysis, theory
from jaxpile.measure.heap import ProfileSetting
from jaxpile.errors import InputError
from jaxpile.engine.state import SimState

Array = Any

BASES = analysis.BASES

# ------------------------------------------------------------- base contacts
# The traceable base loads live with the other measurements (`analysis`, where the
# host-side `base_forces` and `substrate_forces` are built on them).
BaseLoad = analysis.BaseLoad
base_load = analysis.base_load
force_unit = analysis.traced_force_unit


# ---------------------------------------------------------- smooth profiles
def _is_concrete(*values) -> bool:
    return not any(isinstance(v, jax.core.Tracer) for v in jax.tree.leaves(values))


def smooth_profile(x, values, weight, *, x_left, x_right, bins: int, bandwidth=None):
    """Spreads each contact's value over bins with a Gaussian kernel.

    Contact c puts the share softmax_b(-(x_c - centre_b)^2 / (2 h^2)) of
    `weight_c * values_c` into bin b: the shares of a contact add up to 1, so the
    total is conserved exactly, and the profile is smooth in both `values` and
    `x` (no hard binning). As h -> 0 every contact lands in the bin whose centre
    is nearest, i.e. the bin that holds it: the hard binning of
    `protocols.pour.base_profile`. A contact outside `[x_left, x_right]` lands,
    smoothly, in the end bins (choose the range to cover the base).

    Args:
      x: `[c]` contact positions.
      values: `[c]` what to spread (forces).
      weight: `[c]` 1 for a contact, 0 for padding (any weight in [0, 1] works).
      x_left, x_right: the ends of the base (B = x_right - x_left).
      bins: number of bins (a Python int).
      bandwidth: h, the kernel's standard deviation (length); default one bin
        width B / bins.

    Returns:
      `(centres, profile)`: `[bins]` bin centres as x/B in (0, 1), and `[bins]`
      the total value in each bin.

    Raises:
      InputError: on mismatched shapes, bins < 1, x_right <= x_left, or a
        bandwidth that is not positive.
    """
    if int(bins) != bins or bins < 1:
        raise InputError(f"bins must be a whole number >= 1; got {bins!r}.")
    bins = int(bins)
    x, values, weight = jnp.asarray(x), jnp.asarray(values), jnp.asarray(weight)
    if not jnp.issubdtype(x.dtype, jnp.floating):
        x = x.astype(jnp.zeros(()).dtype)
    if not (x.shape == values.shape == weight.shape) or x.ndim != 1:
        raise InputError(f"x, values and weight must be 1-D arrays of one length; got shapes {x.shape}, "
                         f"{values.shape}, {weight.shape}.")
    if _is_concrete(x_left, x_right):
        if not (math.isfinite(float(x_left)) and math.isfinite(float(x_right)) and float(x_left) < float(x_right)):
            raise InputError(f"the base needs x_left < x_right (both finite); got ({x_left}, {x_right}).")
    if bandwidth is not None and _is_concrete(bandwidth) and not (float(bandwidth) > 0 and
                                                                   math.isfinite(float(bandwidth))):
        raise InputError(f"bandwidth must be positive and finite (a length); got {bandwidth!r}.")
    width = x_right - x_left
    bin_width = width / bins
    centres = x_left + bin_width * (jnp.arange(bins, dtype=x.dtype) + 0.5)
    h = bin_width if bandwidth is None else bandwidth
    logits = -0.5 * ((x[:, None] - centres[None, :]) / h) ** 2  # [c, bins]
    share = jax.nn.softmax(logits, axis=-1)
    profile = jnp.sum((weight * values)[:, None] * share, axis=0)
    return (centres - x_left) / width, profile


def profile_peak(profile, *, temperature: float | None = None) -> Array:
    """The maximum of a profile: the plain max (default) or a smooth max.

    The plain max is what the papers divide by (F/F_max). Its gradient exists
    everywhere except where two bins tie for the top (then JAX splits it between
    them), which is enough for gradient descent (a.e., like the contact laws
    themselves). The smooth max, `temperature=T` > 0, is
    s T logsumexp(profile / (s T)) with s the (gradient-stopped) largest |value|:
    differentiable everywhere and mixing in the neighbours of the peak, at the
    cost of exceeding the true max by up to s T log(bins), so a normalised peak
    ends slightly below 1. Use it when ties between flank maxima make the fit
    chatter.
    """
    profile = jnp.asarray(profile)
    if temperature is None:
        return jnp.max(profile)
    if _is_concrete(temperature) and not float(temperature) > 0:
        raise InputError(f"temperature must be > 0 (or None for the plain max); got {temperature!r}.")
    scale = jax.lax.stop_gradient(jnp.max(jnp.abs(profile)))
    scale = jnp.where(scale > 0, scale, 1.0) * temperature
    return scale * jax.nn.logsumexp(profile / scale)


def normalise(profile, *, temperature: float | None = None) -> Array:
    """`profile / profile_peak(profile)` (the plain max by default, see
    `profile_peak` for why); zeros when the peak is not positive."""
    peak = profile_peak(profile, temperature=temperature)
    return _divide(profile, peak)


def _divide(values, peak):
    positive = peak > 0
    return jnp.where(positive, values / jnp.where(positive, peak, 1.0), 0.0)


class Profile(NamedTuple):
    """A base-force profile on the papers' axes.

    Attributes:
      x_over_b: `[b]` positions, x/B in [0, 1].
      normal: `[b]` normal force over the peak normal value (max 1).
      horizontal: `[b]` horizontal force over the same peak normal value, or
        None.
      peak: the normalising peak, in mg per bin (None for a target).
    """

    x_over_b: Array
    normal: Array
    horizontal: Array | None = None
    peak: Array | None = None


def smooth_base_profile(load: BaseLoad, *, x_left, x_right, bins: int, bandwidth=None,
                        temperature: float | None = None) -> Profile:
    """The normalised, smoothed base profile of a `BaseLoad`.

    Both the normal and the horizontal forces are spread with `smooth_profile`
    and divided by the peak of the normal profile (`profile_peak`), so the
    horizontal profile is in units of the largest normal load, as in the
    targets.

    Args:
      load: from `base_load`.
      x_left, x_right, bins, bandwidth: as in `smooth_profile`.
      temperature: None for the plain max, or the smooth max's temperature.
    """
    u, normal = smooth_profile(load.x, load.normal, load.weight, x_left=x_left, x_right=x_right, bins=bins,
                               bandwidth=bandwidth)
    _, horizontal = smooth_profile(load.x, load.horizontal, load.weight, x_left=x_left, x_right=x_right,
                                   bins=bins, bandwidth=bandwidth)
    peak = profile_peak(normal, temperature=temperature)
    return Profile(x_over_b=u, normal=_divide(normal, peak), horizontal=_divide(horizontal, peak), peak=peak)


# ------------------------------------------------------------------ targets
class ProfileTarget(NamedTuple):
    """A base-force profile to fit, with the features it is known to show.

    Attributes:
      x_over_b: `[m]` positions x/B in [0, 1], increasing.
      normal: `[m]` normal force over its maximum.
      horizontal: `[m]` horizontal force (the pile on the base, +x) over the
        maximum normal force, or None.
      angle_of_repose_degrees: the pile's reported angle of repose, or None.
      central_dip: the reported depth of the central minimum of the normal
        force, 1 - centre / max, or None.
      central_dip_range: `(low, high)`: the reported range of that depth, or None.
      source: where the target comes from (a file, a paper).
    """

    x_over_b: np.ndarray
    normal: np.ndarray
    horizontal: np.ndarray | None = None
    angle_of_repose_degrees: float | None = None
    central_dip: float | None = None
    central_dip_range: tuple[float, float] | None = None
    source: str = ""


_CSV_COLUMNS = {"x/b": "x", "x_over_b": "x", "normal/max": "normal", "normal": "normal",
                "horizontal/max": "horizontal", "horizontal": "horizontal"}
_CSV_HELP = "columns x/B, normal/max and optionally horizontal/max (or x_over_b, normal, horizontal)"


def load_profile_csv(path: str | os.PathLike) -> ProfileTarget:
    """A measured base profile from a CSV file.

    The file has a header row naming the columns `x/B` and `normal/max`, and
    optionally `horizontal/max` (also accepted: `x_over_b`, `normal`,
    `horizontal`; case and surrounding spaces do not matter), then at least 3
    rows of numbers. Lines starting with `#` and blank lines are skipped. x/B
    must lie in [0, 1] and increase strictly. The normal column is divided by
    its maximum (a no-op for a column already normalised) and the horizontal
    column by the same number.

    Raises:
      InputError: on a missing file, a missing, unknown or repeated column, a
        row of the wrong length, a value that is not a finite number, fewer than
        3 rows, x/B outside [0, 1] or not increasing, or a normal column whose
        maximum is not positive.
    """
    path = os.fspath(path)
    if os.path.isdir(path):
        raise InputError(f"profile file {path!r} is a folder; give the path of a CSV file with {_CSV_HELP}.")
    if not os.path.isfile(path):
        raise InputError(f"profile file {path!r} does not exist; give the path of a CSV file with {_CSV_HELP}.")
    try:
        with open(path, newline="", encoding="utf-8-sig") as f:
            numbered = [(k + 1, line) for k, line in enumerate(f)
                        if line.strip() and not line.lstrip().startswith("#")]
    except UnicodeDecodeError:
        raise InputError(f"profile file {path!r} is not text (UTF-8); it must be a CSV file with {_CSV_HELP}.") from None
    except OSError as e:
        raise InputError(f"profile file {path!r} cannot be read: {e.strerror}.") from None
    if not numbered:
        raise InputError(f"profile file {path!r} is empty; it needs a header row with {_CSV_HELP}.")
    rows = list(csv.reader([line for _, line in numbered]))
    line_numbers = [k for k, _ in numbered]
    header = [name.strip().lower() for name in rows[0]]
    if all(_is_number(name) for name in header):
        raise InputError(f"{path!r} line {line_numbers[0]} holds numbers; the file must start with a header row "
                         f"naming its {_CSV_HELP}.")
    unknown = [name for name in header if name not in _CSV_COLUMNS]
    if unknown:
        raise InputError(f"{path!r}: unknown column(s) {unknown}; the file needs {_CSV_HELP}.")
    canonical = [_CSV_COLUMNS[name] for name in header]
    repeated = sorted({c for c in canonical if canonical.count(c) > 1})
    if repeated:
        raise InputError(f"{path!r}: column(s) {repeated} given more than once (under one of their names); "
                         "keep one of each.")
    missing = [name for name, key in (("x/B", "x"), ("normal/max", "normal")) if key not in canonical]
    if missing:
        raise InputError(f"{path!r}: missing column(s) {missing}; the header has {rows[0]}, the file needs "
                         f"{_CSV_HELP}.")
    data = {key: [] for key in canonical}
    for line, row in zip(line_numbers[1:], rows[1:]):
        if len(row) != len(canonical):
            raise InputError(f"{path!r} line {line} has {len(row)} value(s) but the header names "
                             f"{len(canonical)} columns.")
        for key, name, cell in zip(canonical, rows[0], row):
            try:
                value = float(cell)
            except ValueError:
                raise InputError(f"{path!r} line {line}, column {name.strip()!r}: {cell.strip()!r} is not a "
                                 "number.") from None
            if not math.isfinite(value):
                raise InputError(f"{path!r} line {line}, column {name.strip()!r}: {cell.strip()!r} is not finite.")
            data[key].append(value)
    count = len(rows) - 1
    if count < 3:
        raise InputError(f"{path!r} has {count} data row(s); a profile needs at least 3.")
    x = np.asarray(data["x"])
    outside = np.flatnonzero((x < 0) | (x > 1))
    if outside.size:
        k = int(outside[0])
        raise InputError(f"{path!r} line {line_numbers[k + 1]}: x/B = {x[k]!r} is outside [0, 1]; positions "
                         "must be given as a fraction of the base width B.")
    steps = np.flatnonzero(np.diff(x) <= 0)
    if steps.size:
        k = int(steps[0])
        raise InputError(f"{path!r} lines {line_numbers[k + 1]}-{line_numbers[k + 2]}: x/B must increase strictly "
                         f"(got {x[k]!r} then {x[k + 1]!r}); sort the rows and merge repeated positions.")
    normal = np.asarray(data["normal"])
    peak = normal.max()
    if not peak > 0:
        raise InputError(f"{path!r}: the normal column's maximum is {peak!r}; it must be positive (the base "
                         "carries the pile).")
    horizontal = np.asarray(data["horizontal"]) / peak if "horizontal" in data else None
    return ProfileTarget(x_over_b=x, normal=normal / peak, horizontal=horizontal, source=path)


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


SMID_NOVOSAD_ANGLE_DEGREES = 32.6
"""Angle of repose of Smid & Novosad's largest pile (Liffman et al. 1992, text of Fig. 17)."""

SMID_NOVOSAD_DIP_RANGE = (0.2, 0.3)
"""The central minimum of the base normal stress, 20% (smallest piles) to 30%
(largest) below the maximum (Liffman et al. 1992, Introduction; Baxter et al.
1997 report their simulated heap's maxima "some 20-30% greater" than the centre
and cite the experiment as qualitatively very similar)."""


def smid_novosad_target(points: int = 41, *, dip: float = 0.25, peak_offset: float = 0.25) -> ProfileTarget:
    """A target built from the features of Smid & Novosad's experiment (1981) that
    the papers report in words. It is built from reported features, NOT from
    measured points: the papers print no table of the experiment's values (Liffman
    et al. 1992 plot them in Fig. 17, which we do not digitise), so the curves
    below are a declared shape that has those features, and nothing more.

    The features (Liffman, Chan & Hughes 1992, Introduction and text of Fig. 17;
    Baxter et al. 1997, sec. III, ref. 13):

    * angle of repose 32.6 degrees;
    * the base normal stress has a central minimum under the apex, 20-30% below
      its maximum (`dip` = 0.25, the middle, by default);
    * the shear stress is zero at the centre, by symmetry, and linear in the
      central region with the slope of eq. 57, which simulation and experiment
      share.

    How the curves are built, with u = x/B and s = |u - 1/2| (d = `peak_offset`):

    * normal (max 1): 1 - dip (1 - (s/d)^2)^2 for s <= d, and 1 - ((s - d)/(1/2 - d))^2
      for d < s <= 1/2: a smooth M, 1 - dip at the centre, maxima of exactly 1 at
      u = 1/2 +- d with zero slope there (C1), and 0 at the feet u = 0, 1 with a
      finite slope (the linear rise of eq. 54 near a foot). The position of the
      maxima is not reported; d = 0.25 is our choice.
    * horizontal: the continuum sloped pile's H(x) (eqs. 55, 57, 59, `theory.
      continuum_ground_horizontal_force`) at alpha = 32.6 degrees and B = 1,
      divided by its maximum normal force (eq. 56, the flat central value of
      `theory.continuum_ground_normal_force`). Zero at the centre, odd about it,
      slope 2/sqrt(3) per unit x/B for |u - 1/2| < 1/2 - x_c/B = 0.185 (eq. 57 over
      eq. 56; x_c from `theory.continuum_critical_distance`), and falling
      linearly to zero at the feet (eqs. 55, 59). The sign convention of
      `analysis.base_forces`: the pile pushes the base outwards, negative on the
      left half.

    Args:
      points: an odd number (>= 5) of equally spaced positions from x/B = 0 to
        1 (odd, so the centre is one of them).
      dip: depth of the central minimum, 1 - centre / max, in (0, 1).
      peak_offset: |x/B - 1/2| of the maxima, in (0, 1/2).

    Raises:
      InputError: on an even or too small `points`, or `dip`, `peak_offset`
        outside their ranges.
    """
    if int(points) != points or points < 5 or int(points) % 2 == 0:
        raise InputError(f"points must be an odd whole number >= 5 (so that x/B = 0.5 is one of them); "
                         f"got {points!r}.")
    if not 0.0 < dip < 1.0:
        raise InputError(f"dip must be in (0, 1) (1 - centre / max; the experiment: 0.2-0.3); got {dip!r}.")
    if not 0.0 < peak_offset < 0.5:
        raise InputError(f"peak_offset must be in (0, 0.5) (the maxima's |x/B - 0.5|); got {peak_offset!r}.")
    u = np.linspace(0.0, 1.0, int(points))
    s = np.abs(u - 0.5)
    inner = 1.0 - dip * (1.0 - (s / peak_offset) ** 2) ** 2
    outer = 1.0 - ((s - peak_offset) / (0.5 - peak_offset)) ** 2
    normal = np.where(s <= peak_offset, inner, outer)
    alpha = math.radians(SMID_NOVOSAD_ANGLE_DEGREES)
    n_max = float(theory.continuum_ground_normal_force(0.5, alpha, 1.0))
    horizontal = theory.continuum_ground_horizontal_force(u, alpha, 1.0) / n_max
    return ProfileTarget(
        x_over_b=u, normal=normal, horizontal=horizontal, angle_of_repose_degrees=SMID_NOVOSAD_ANGLE_DEGREES,
        central_dip=float(dip), central_dip_range=SMID_NOVOSAD_DIP_RANGE,
        source="Smid & Novosad 1981 as reported in words by Liffman, Chan & Hughes 1992 and Baxter et al. 1997: "
               "a declared shape with the reported features (32.6 deg repose, central dip 20-30%, shear linear "
               "through zero at the centre with the slope of eq. 57), not measured points")


# ------------------------------------------------------------------- losses
def _profile_at(profile, u):
    """A profile's normal and horizontal values at positions u (x/B): linear
    between its points, and 0 at x/B = 0 and 1 (the feet) when its points stop
    short of them, as a binned profile's centres do."""
    xp = jnp.asarray(profile.x_over_b)

    def at(values):
        values = jnp.asarray(values)
        xs = jnp.concatenate([jnp.zeros(1, xp.dtype), xp, jnp.ones(1, xp.dtype)])
        first = jnp.where(xp[0] > 0, 0.0, values[0])
        last = jnp.where(xp[-1] < 1, 0.0, values[-1])
        fs = jnp.concatenate([first[None], values, last[None]])
        return _interp_without_scatter(jnp.asarray(u), xs, fs)

    return at(profile.normal), None if profile.horizontal is None else at(profile.horizontal)


def _interp_without_scatter(x, xp, fp):
    """`jnp.interp(x, xp, fp)` (ends held constant) with each point's two
    neighbours picked by a select over xp instead of gathers: the gathers'
    derivative is a scatter-add whose multi-output fusion aborts XLA:CPU's
    newer emitters (jax 0.10.2; see `jaxpile.use_multi_output_fusion`), and
    xp holds a few dozen points, so a [len(x), len(xp)] select costs nothing.
    Same formula as jnp.interp: the same values to round-off."""
    i = jnp.clip(jnp.searchsorted(xp, x, side="right"), 1, xp.shape[0] - 1)
    slots = jnp.arange(xp.shape[0])

    def pick(values, at):  # values[at], a select and a sum (its derivative: a select, no scatter)
        return jnp.where(slots == at[..., None], values, jnp.zeros_like(values)).sum(axis=-1)

    f_lo, f_hi, x_lo, x_hi = pick(fp, i - 1), pick(fp, i), pick(xp, i - 1), pick(xp, i)
    dx = x_hi - x_lo
    dx0 = jnp.abs(dx) <= np.spacing(np.finfo(xp.dtype).eps)  # jnp.interp's guard against NaN gradients
    f = jnp.where(dx0, f_lo, f_lo + ((x - x_lo) / jnp.where(dx0, 1, dx)) * (f_hi - f_lo))
    f = jnp.where(x < xp[0], fp[0], f)
    return jnp.where(x > xp[-1], fp[-1], f)


def profile_loss(predicted: Profile, target: ProfileTarget, *, horizontal_weight: float = 0.0) -> Array:
    """Mean squared difference between normalised profiles at the target's points.

    loss = mean_m (N_pred(u_m) - N_target(u_m))^2
           + horizontal_weight * mean_m (H_pred(u_m) - H_target(u_m))^2,

    the predicted profile read at the target's x/B by linear interpolation
    between its bin centres, taken as 0 at the feet x/B = 0 and 1 (choose the
    base extent of `smooth_base_profile` at the feet of the pile).

    Args:
      predicted: a `Profile` (from `smooth_base_profile`), normalised.
      target: a `ProfileTarget` (or any `Profile`).
      horizontal_weight: weight of the horizontal term (0: normal only).

    Raises:
      InputError: on a negative weight, or a positive one when either side has
        no horizontal profile.
    """
    if not horizontal_weight >= 0:
        raise InputError(f"horizontal_weight must be >= 0; got {horizontal_weight!r}.")
    u = jnp.asarray(target.x_over_b)
    normal, horizontal = _profile_at(predicted, u)
    loss = jnp.mean((normal - jnp.asarray(target.normal)) ** 2)
    if horizontal_weight > 0:
        if horizontal is None or target.horizontal is None:
            raise InputError("horizontal_weight > 0 needs a horizontal profile in both the prediction and the "
                             "target; set horizontal_weight=0 or give a target with a horizontal column.")
        loss = loss + horizontal_weight * jnp.mean((horizontal - jnp.asarray(target.horizontal)) ** 2)
    return loss


def central_dip(profile) -> Array:
    """Depth of the central minimum of the normal profile: 1 - N(x/B = 1/2) / max N
    (0.25 for a centre 25% below the maxima; negative for a peak at the centre).
    The centre value is interpolated linearly between points."""
    normal = jnp.asarray(profile.normal)
    centre, _ = _profile_at(profile, jnp.asarray(0.5))
    return 1.0 - _divide(centre, jnp.max(normal))


def central_slope(profile, half_width: float = 0.1) -> Array:
    """Least-squares slope d(H/N_max)/d(x/B) of the horizontal profile over the
    points with |x/B - 1/2| <= `half_width` (eq. 57's linear central region:
    2/sqrt(3) in these units for the continuum pile)."""
    if profile.horizontal is None:
        raise InputError("central_slope needs a horizontal profile; this one has none.")
    u = jnp.asarray(profile.x_over_b)
    h = jnp.asarray(profile.horizontal)
    inside = (jnp.abs(u - 0.5) <= half_width).astype(h.dtype)
    count = jnp.sum(inside)
    if _is_concrete(count) and float(count) < 2:
        raise InputError(f"central_slope needs at least 2 points within {half_width} of x/B = 0.5; widen "
                         "half_width or use more bins.")
    mean_u = jnp.sum(inside * u) / count
    mean_h = jnp.sum(inside * h) / count
    return jnp.sum(inside * (u - mean_u) * (h - mean_h)) / jnp.sum(inside * (u - mean_u) ** 2)


def dip_loss(predicted, target_dip: float = 0.25) -> Array:
    """(central_dip(predicted) - target_dip)^2: the squared miss of the central
    minimum's depth (Smid & Novosad: 0.2-0.3, 0.25 in the middle)."""
    return (central_dip(predicted) - target_dip) ** 2


def feature_loss(predicted, target: ProfileTarget, *, dip_weight: float = 1.0, slope_weight: float = 0.0,
                 half_width: float = 0.1) -> Array:
    """Squared misses of a target's features, weighted:

    dip_weight (central_dip(pred) - target.central_dip)^2
    + slope_weight (central_slope(pred) - central_slope(target))^2,

    the slope over |x/B - 1/2| <= half_width (eq. 57's region, about 0.185 wide
    on each side at 32.6 degrees).

    Raises:
      InputError: on a negative weight, or a positive weight for a feature the
        target (or the prediction) does not have.
    """
    if not (dip_weight >= 0 and slope_weight >= 0):
        raise InputError(f"the feature weights must be >= 0; got dip_weight={dip_weight!r}, "
                         f"slope_weight={slope_weight!r}.")
    loss = jnp.zeros(())
    if dip_weight > 0:
        if target.central_dip is None:
            raise InputError("the target has no central_dip; set dip_weight=0 or give one.")
        loss = loss + dip_weight * dip_loss(predicted, target.central_dip)
    if slope_weight > 0:
        slope = central_slope(target, half_width)
        loss = loss + slope_weight * (central_slope(predicted, half_width) - slope) ** 2
    return loss


# ------------------------------------------------------------ transforms
LOWER_BOUNDS: dict[str, dict[str, float]] = {"baxter": {"r0": 1.0}}
"""Lower bounds other than 0, per law: baxter's cut-off r0 must exceed 1 (a
cut-off beyond contact). Every other fitted parameter must be > 0 (mu, kn, kt, ks,
baxter n, ...)."""


def _law_of(params) -> tuple[str | None, tuple[str, ...]]:
    """(law name, PARAM_NAMES) of a law params pytree, or (None, keys) of a mapping."""
    if isinstance(params, Mapping):
        return None, tuple(params)
    from jaxpile.laws import LAWS

    for name, module in LAWS.items():
        if isinstance(params, module.Params):
            return name, tuple(module.PARAM_NAMES)
    raise InputError(f"params must be a law's params pytree (one of the laws {sorted(LAWS)}) or a mapping of "
                     f"names to values; got {type(params).__name__}.")


def _get(params, name: str):
    return params[name] if isinstance(params, Mapping) else getattr(params, name)


def _with(params, values: Mapping[str, Array]):
    if isinstance(params, Mapping):
        return {**params, **values}
    return params.set(**values)


@dataclasses.dataclass(frozen=True)
class Transform:
    """Positive parameters in log space: u = log(value - lower), value = lower + exp(u).

    An optimiser then moves freely in u while every value stays above its lower
    bound (`LOWER_BOUNDS`: 0 for mu, kn, kt, ks, baxter n, ...; 1 for baxter r0).
    A value at its bound (mu = 0) has no image: start from a small positive
    value instead. Steps in u are relative steps in the value, which suits
    parameters spanning decades (stiffnesses).

    Attributes:
      names: the transformed parameters.
      lower: their lower bounds.
    """

    names: tuple[str, ...]
    lower: tuple[float, ...]

    @classmethod
    def of(cls, params, names: str | Sequence[str]) -> "Transform":
        """The transform of `names` for a law params pytree (names checked against
        the law's PARAM_NAMES) or a mapping (names checked against its keys).

        Raises:
          InputError: on no names, a repeated name or an unknown name.
        """
        names = (names,) if isinstance(names, str) else tuple(names)
        law, known = _law_of(params)
        if not names:
            raise InputError(f"name at least one parameter to transform; known: {list(known)}.")
        repeated = sorted({n for n in names if names.count(n) > 1})
        if repeated:
            raise InputError(f"parameter(s) {repeated} named more than once.")
        unknown = [n for n in names if n not in known]
        if unknown:
            what = f"the {law} law's parameters (PARAM_NAMES)" if law else "the mapping's keys"
            raise InputError(f"unknown parameter(s) {unknown}; {what}: {list(known)}.")
        bounds = LOWER_BOUNDS.get(law, {}) if law else {}
        return cls(names=names, lower=tuple(float(bounds.get(n, 0.0)) for n in names))

    def to_unconstrained(self, params) -> dict[str, Array]:
        """{name: log(value - lower)} for the transformed parameters.

        Raises:
          InputError: on a parameter that is None (a `wall_*` left to follow its
            disk value: set it to fit it), non-finite, or not above its bound.
        """
        out = {}
        for name, lower in zip(self.names, self.lower):
            value = _get(params, name)
            if value is None:
                raise InputError(f"parameter {name} is None (it follows its disk value); give it a value to "
                                 "fit it on its own.")
            value = jnp.asarray(value)
            dtype = value.dtype if jnp.issubdtype(value.dtype, jnp.floating) else jnp.zeros(()).dtype
            value = jnp.asarray(value, dtype=dtype)  # strongly typed, so optimiser steps never re-trace
            if _is_concrete(value):
                v = np.asarray(value)
                if not np.all(np.isfinite(v)) or np.any(v <= lower):
                    raise InputError(f"parameter {name} must be finite and > {lower:g} to be fitted in log space "
                                     f"(log({name} - {lower:g})); got {v.tolist()}. Start from a value above "
                                     "the bound.")
            out[name] = jnp.log(value - lower)
        return out

    def to_constrained(self, unconstrained: Mapping[str, Array], params):
        """`params` with each transformed parameter set to lower + exp(u).
        Traceable (used inside the fitted loss)."""
        missing = [n for n in self.names if n not in unconstrained]
        if missing:
            raise InputError(f"unconstrained values missing for {missing}.")
        return _with(params, {n: lower + jnp.exp(unconstrained[n]) for n, lower in zip(self.names, self.lower)})


def to_unconstrained(params, names: str | Sequence[str]) -> dict[str, Array]:
    """{name: log(value - lower)} for `names` of a law params pytree or a mapping
    (see `Transform`). Raises InputError on an unknown name (listing the law's
    PARAM_NAMES) or a value not above its lower bound."""
    return Transform.of(params, names).to_unconstrained(params)


def to_constrained(unconstrained: Mapping[str, Array], params):
    """`params` with each parameter named in `unconstrained` set to
    lower + exp(u): the inverse of `to_unconstrained`."""
    return Transform.of(params, tuple(unconstrained)).to_constrained(unconstrained, params)


# ---------------------------------------------------------------- fitting
class FitResult(NamedTuple):
    """What `fit` did.

    Attributes:
      params: the params pytree with the lowest loss seen.
      loss: that lowest loss.
      best_step: the step at which it was seen.
      initial_params: the params the fit started from.
      history: one dict per evaluated step: `step`, `loss`, each fitted
        parameter's value, and `grad_norm`, the gradient's global norm in the
        log space the optimiser moves in.
      converged: True when the loss stopped improving (see `fit`'s `patience`).
      steps: optimiser updates taken.
      message: why the fit stopped.
    """

    params: Any
    loss: float
    best_step: int
    initial_params: Any
    history: list[dict]
    converged: bool
    steps: int
    message: str


_tree_norm = getattr(getattr(optax, "tree", None), "norm", None) or optax.global_norm  # optax < 0.2.4: global_norm


def _scalar_or_list(value):
    v = np.asarray(value)
    return float(v) if v.ndim == 0 else v.tolist()


GRADIENT_MODES = ("auto", "reverse", "forward")
FORWARD_MODE_MAX = 4
"""`mode="auto"` takes forward-mode gradients up to this many fitted values.
Forward mode costs about one tangent pass per value, the checkpointed reverse
three passes (forward, recomputation, transpose) whatever the count; forward
mode's memory is also flat in the horizon. Measured side by side, XLA:CPU's
multi-output fusion off and on (benchmarks/forward_mode_threshold.py,
results/cpu/forward_mode_threshold.json; gradient time over forward time,
checkpointed reverse over 1 and 10 values against forward mode over 4 and 6):
off, 55 disks x 1000 steps: 5.4-6.9 against 5.7 and 7.8; 465 disks x 250
steps: 5.9-6.9 against 6.9 and 10.2. On (as `jaxpile fit` runs): 4.8-5.2
against 3.4 and 4.4; 465 disks: 5.0-5.3 against 4.6 and 6.0. So 4 values is
about where the two cost the same without the fusion and the most that forward
mode wins at 465 disks with it (at 55 disks with it, up to 6-8)."""


def _check_mode(mode: str) -> None:
    if mode not in GRADIENT_MODES:
        raise InputError(f"mode must be one of {GRADIENT_MODES}; got {mode!r}.")


def gradient_mode(size: int, mode: str = "auto") -> str:
    """`"forward"` or `"reverse"`: how `value_and_gradient` takes the gradient
    of `size` fitted values in `mode` (`"auto"`: forward up to
    `FORWARD_MODE_MAX`)."""
    _check_mode(mode)
    if mode == "auto":
        return "forward" if size <= FORWARD_MODE_MAX else "reverse"
    return mode


def value_and_gradient(objective: Callable, u, mode: str = "auto") -> Callable:
    """`(u, *args) -> (value, gradient like u)` of a scalar `objective(u, *args)`,
    compiled (`engine.compile.jit_derivative`): reverse mode, or forward mode
    (`jax.jvp` along each unit vector of the flattened u, in one batch)."""
    from jax.flatten_util import ravel_pytree

    from jaxpile.engine.compile import jit_derivative

    if gradient_mode(ravel_pytree(u)[0].size, mode) == "reverse":
        return jit_derivative(jax.value_and_grad(objective))

    def forward(u, *args):
        flat, unravel = ravel_pytree(u)
        values, slopes = jax.vmap(lambda e: jax.jvp(lambda x: objective(unravel(x), *args), (flat,), (e,)))(
            jnp.eye(flat.size, dtype=flat.dtype))
        if values.ndim != 1:  # as jax.grad says of a loss that is not a scalar
            raise TypeError(f"the gradient is only defined for a scalar loss; got shape {values.shape[1:]}.")
        return values[0], unravel(slopes)

    return jit_derivative(forward)


def fit(loss_fn: Callable[[Any], Array], params, names: str | Sequence[str], *,
        optimizer: optax.GradientTransformation | None = None, steps: int = 50, patience: int = 20,
        rtol: float = 1e-6, callback: Callable[[dict], Any] | None = None, progress: bool = False,
        mode: str = "auto") -> FitResult:
    """Minimises `loss_fn` over the parameters `names`, in log space, with optax.

    The fitted parameters move in u = log(value - lower) (`Transform`), so they
    stay above their bounds; every other leaf of `params` stays fixed. The loss
    and its gradient are compiled once (`jax.jit(jax.value_and_grad(...))`).
    Step k evaluates the loss at the current parameters, records it, then applies
    one optimiser update; the last evaluation follows the last update.

    Args:
      loss_fn: `params -> scalar`, traceable (e.g. a rollout, `base_load`,
        `smooth_base_profile` and `profile_loss`).
      params: a law params pytree, or a mapping of names to values.
      names: the parameters to fit (a law's PARAM_NAMES, or the mapping's keys).
      optimizer: an optax transformation; default `optax.adam(0.05)` (steps of
        about 5% in each value). Optimisers with a line search
        (`optax.lbfgs()`) get the loss function they need; for a smooth,
        deterministic loss (a quasi-statically loaded pile) L-BFGS converges in
        far fewer steps than adam.
      steps: the most optimiser updates.
      patience, rtol: stop (`converged=True`) when the best loss has not
        improved by more than `rtol` times its size for `patience` evaluations
        in a row. Adam at a constant rate overshoots and circles the minimum,
        with runs of tens of steps without a new best even on a quadratic: a
        stop then means "stalled at this rate", not "at the minimum". Raise
        `patience` or give the optimiser a decaying rate (`optax.adam(
        optax.exponential_decay(...))`) when that matters.
      callback: called with each history record; returning True stops the fit
        (after step 0, the point it stops at is not taken as the best: a
        callback can veto parameters, e.g. above a stability limit).
      progress: show a progress bar.
      mode: how the gradient is taken: `"reverse"` (`jax.value_and_grad`),
        `"forward"` (one `jax.jvp` per fitted value, batched: no stored
        trajectory, so no memory that grows with the rollout), or `"auto"`:
        forward for up to `FORWARD_MODE_MAX` fitted values, where it is the
        cheaper (benchmarks/forward_mode_threshold.py), else reverse.

    Returns:
      `FitResult` with the best params found.

    Raises:
      InputError: on bad names or settings, a loss that is not a scalar, or a
        loss or gradient that is not finite at the start. A loss or gradient
        that turns non-finite later stops the fit with a warning (the result
        keeps the best params so far and says why in `message`).
    """
    if int(steps) != steps or steps < 0:
        raise InputError(f"steps must be a whole number >= 0; got {steps!r}.")
    if int(patience) != patience or patience < 1:
        raise InputError(f"patience must be a whole number >= 1; got {patience!r}.")
    if not rtol >= 0:
        raise InputError(f"rtol must be >= 0; got {rtol!r}.")
    _check_mode(mode)  # before any work
    transform = Transform.of(params, names)
    unconstrained = transform.to_unconstrained(params)
    optimizer = optax.adam(0.05) if optimizer is None else optimizer

    def objective(u, fixed):
        return loss_fn(transform.to_constrained(u, fixed))

    value_and_grad = value_and_gradient(objective, unconstrained, mode)
    line_search = isinstance(optimizer, optax.GradientTransformationExtraArgs)

    @jax.jit  # once: the line search's loop traces the loss into the update
    def search_update(grad, opt_state, u, value, fixed):
        return optimizer.update(grad, opt_state, u, value=value, grad=grad, value_fn=lambda v: objective(v, fixed))

    opt_state = optimizer.init(unconstrained)

    from tqdm.auto import tqdm

    bar = tqdm(total=int(steps), disable=not progress, unit="step", leave=False, dynamic_ncols=True)
    history: list[dict] = []
    best_loss, best_u, best_step = math.inf, unconstrained, 0
    since_improvement = 0
    converged = False
    message = f"reached the step limit ({steps})."
    taken = 0
    try:
        for step in range(int(steps) + 1):
            try:
                loss, grad = value_and_grad(unconstrained, params)
            except TypeError as err:
                if step == 0:
                    raise InputError(f"loss_fn must return a real scalar: {err}") from None
                raise
            if step == 0 and jnp.shape(loss) != ():
                raise InputError(f"loss_fn must return a scalar; got shape {jnp.shape(loss)}.")
            loss_value = float(loss)
            grad_norm = float(_tree_norm(grad))
            values = transform.to_constrained(unconstrained, {})
            if not (math.isfinite(loss_value) and math.isfinite(grad_norm)):
                what = (f"the loss is {loss_value}" if not math.isfinite(loss_value)
                        else f"the gradient is not finite (global norm {grad_norm})")
                at = ", ".join(f"{n} = {_scalar_or_list(values[n])}" for n in transform.names)
                if step == 0:
                    raise InputError(f"{what} at the starting parameters ({at}); the fit needs a finite loss and "
                                     "gradient there: check loss_fn and the starting values.")
                message = (f"stopped at step {step}: {what} ({at}); keeping the best parameters, from step "
                           f"{best_step} (loss {best_loss:.6g}).")
                warnings.warn(message, RuntimeWarning, stacklevel=2)
                break
            record = {"step": step, "loss": loss_value,
                      **{n: _scalar_or_list(values[n]) for n in transform.names}, "grad_norm": grad_norm}
            history.append(record)
            if step > 0 and callback is not None and callback(record) is True:
                message = f"stopped by the callback at step {step}."  # this point is not taken as the best
                break
            if loss_value < best_loss - rtol * abs(best_loss) or step == 0:
                since_improvement = 0
            else:
                since_improvement += 1
            if loss_value < best_loss:
                best_loss, best_u, best_step = loss_value, unconstrained, step
            if progress:
                bar.set_postfix(loss=f"{loss_value:.4g}")
            if step == 0 and callback is not None and callback(record) is True:
                message = "stopped by the callback at step 0."
                break
            if since_improvement >= patience:
                converged = True
                message = (f"converged: the loss improved by less than rtol = {rtol:g} (relative) over the last "
                           f"{patience} steps.")
                break
            if step == steps:
                break
            if line_search:  # e.g. optax.lbfgs(): its line search evaluates the loss itself
                updates, opt_state = search_update(grad, opt_state, unconstrained, loss, params)
            else:
                updates, opt_state = optimizer.update(grad, opt_state, unconstrained)
            unconstrained = optax.apply_updates(unconstrained, updates)
            taken += 1
            bar.update(1)
    finally:
        bar.close()
    return FitResult(params=transform.to_constrained(best_u, params), loss=best_loss, best_step=best_step,
                     initial_params=params, history=history, converged=converged, steps=taken, message=message)


# ------------------------------------------------------------------ figure
def fit_figure(result: FitResult, target: ProfileTarget, before, after, path=None):
    """The loss against the step (log scale) and the normalised profiles: the
    target against the prediction before and after the fit (normal, and
    horizontal when the target has it).

    No backend is forced (notebooks draw inline; without a display matplotlib
    falls back to Agg).

    Args:
      result: from `fit`.
      target: the `ProfileTarget`.
      before, after: `Profile`s (from `smooth_base_profile`) at the initial and
        the fitted parameters.
      path: where to save the figure; then it is closed and the path returned.

    Returns:
      The figure, or `path` when given.
    """
    import matplotlib.pyplot as plt

    panels = 3 if target.horizontal is not None else 2
    fig, axes = plt.subplots(1, panels, figsize=(5.0 * panels, 4.0))
    ax = axes[0]
    steps = [r["step"] for r in result.history]
    losses = [r["loss"] for r in result.history]
    ax.plot(steps, losses, "-", color="C0", lw=1.2)
    if result.history:
        ax.plot([result.best_step], [result.loss], "o", color="C3", ms=5, label=f"best (step {result.best_step})")
        ax.legend(fontsize=8)
    if any(v > 0 for v in losses):
        ax.set_yscale("log")
    ax.set_xlabel("step")
    ax.set_ylabel("loss")
    ax.set_title(", ".join(f"{k} = {v:.4g}" for k, v in result.history[-1].items()
                           if k not in ("step", "loss", "grad_norm") and isinstance(v, float))
                 if result.history else "no steps", fontsize=9)
    ax.grid(alpha=0.3, which="both")
    fields = [("normal", "normal force / max")]
    if target.horizontal is not None:
        fields.append(("horizontal", "horizontal force / max normal"))
    for ax, (field, label) in zip(axes[1:], fields):
        ax.plot(target.x_over_b, getattr(target, field), "-", color="k", lw=2, label="target")
        for profile, name, style in ((before, "before", "--"), (after, "after", "-")):
            values = getattr(profile, field)
            if values is not None:
                ax.plot(np.asarray(profile.x_over_b), np.asarray(values), style, marker="o", ms=3,
                        label=name)
        ax.set_xlabel("x / B")
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    fig.tight_layout()
    if path is not None:
        fig.savefig(path, dpi=130)
        plt.close(fig)
        return path
    return fig


# ------------------------------------------------------ simulated piles
def simulated_profile(sim, params, state: SimState, steps: int, setting: ProfileSetting, *,
                      window: int | None = None, checkpoint: bool | int = True) -> Profile:
    """The smooth base profile after `steps` steps from `state` with `params`:
    differentiable in `params` through the whole rollout.

    Args:
      window: differentiate only the last `window` steps (the state before them
        held fixed with `stop_gradient`); None for the whole rollout. A pile
        that has settled responds smoothly to its parameters over a short
        relaxation, while through a long frictional flow the gradient grows
        without bound (benchmarks/gradient_cost.py); fitting a poured heap uses
        a window from the relaxed heap.
      checkpoint: `Simulator.rollout`'s reverse-pass memory setting.
    """
    if int(steps) != steps or steps < 1:
        raise InputError(f"steps must be a whole number >= 1; got {steps!r}.")
    if window is not None and not 1 <= int(window) <= steps:
        raise InputError(f"window must be between 1 and steps ({steps}); got {window!r}.")
    if window is not None and window < steps:
        state = jax.lax.stop_gradient(sim.rollout(params, state, int(steps - window)))
        steps = window
    final = sim.rollout(params, state, int(steps), checkpoint=checkpoint)
    load = base_load(sim, params, final, base=setting.base)
    return smooth_base_profile(load, x_left=setting.x_left, x_right=setting.x_right, bins=setting.bins,
                               bandwidth=setting.bandwidth)


def profile_objective(sim, state: SimState, steps: int, setting: ProfileSetting, target: ProfileTarget, *,
                      window: int | None = None, checkpoint: bool | int = True, horizontal_weight: float = 0.0,
                      dip_weight: float = 0.0) -> Callable[[Any], Array]:
    """`params -> loss`: `profile_loss` (plus `dip_weight` times the squared
    miss of the target's central dip, when it has one) of `simulated_profile`."""
    if dip_weight > 0 and target.central_dip is None:
        raise InputError("dip_weight > 0 needs a target with a central_dip (e.g. smid_novosad_target()).")

    def loss(params):
        predicted = simulated_profile(sim, params, state, steps, setting, window=window, checkpoint=checkpoint)
        value = profile_loss(predicted, target, horizontal_weight=horizontal_weight)
        if dip_weight > 0:
            value = value + dip_weight * dip_loss(predicted, target.central_dip)
        return value

    return loss


def target_from_profile(profile: Profile, source: str = "simulated") -> ProfileTarget:
    """A `ProfileTarget` from a computed `Profile` (e.g. to check that a fit
    recovers the parameters a profile was made with)."""
    return ProfileTarget(x_over_b=np.asarray(profile.x_over_b), normal=np.asarray(profile.normal),
                         horizontal=None if profile.horizontal is None else np.asarray(profile.horizontal),
                         central_dip=float(central_dip(profile)), source=source)


__all__ = [
    "BASES",
    "LOWER_BOUNDS",
    "SMID_NOVOSAD_ANGLE_DEGREES",
    "SMID_NOVOSAD_DIP_RANGE",
    "BaseLoad",
    "FORWARD_MODE_MAX",
    "FitResult",
    "GRADIENT_MODES",
    "Profile",
    "ProfileSetting",
    "ProfileTarget",
    "Transform",
    "base_load",
    "central_dip",
    "central_slope",
    "dip_loss",
    "feature_loss",
    "fit",
    "fit_figure",
    "force_unit",
    "gradient_mode",
    "load_profile_csv",
    "normalise",
    "profile_loss",
    "profile_objective",
    "profile_peak",
    "smid_novosad_target",
    "smooth_base_profile",
    "smooth_profile",
    "simulated_profile",
    "target_from_profile",
    "value_and_gradient",
]
