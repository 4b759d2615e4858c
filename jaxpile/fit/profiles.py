"""Base-force profiles as pure jnp functions of a state, and the features read
off a profile.

  state --`base_load`--> every base contact's x, normal and horizontal force
  (fixed shapes, padding masked out by a 0/1 `weight`)
  --`smooth_base_profile`--> a Gaussian-smoothed `Profile` over the base,
  normalised by its maximum (x/B, F/F_max: the papers' axes)
  --`dip_below_peak`, `central_slope`--> the features the papers report.

Every step is traceable, so `jax.grad` runs from a feature or a loss back
through the rollout that made the state.
"""

from __future__ import annotations

import math
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxpile.errors import InputError
from jaxpile.measure import analysis

Array = Any

BASES = analysis.BASES

# The traceable base loads live with the other measurements (`analysis`, where the
# host-side `base_forces` and `substrate_forces` are built on them).
BaseLoad = analysis.BaseLoad
base_load = analysis.base_load


def is_concrete(*values) -> bool:
    """Whether every leaf of `values` is a concrete value, not a tracer: a
    check on a value's range runs only then (under `jax.jit` it cannot)."""
    return not any(isinstance(v, jax.core.Tracer) for v in jax.tree.leaves(values))


# ---------------------------------------------------------- smooth profiles
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
    if is_concrete(x_left, x_right):
        if not (math.isfinite(float(x_left)) and math.isfinite(float(x_right)) and float(x_left) < float(x_right)):
            raise InputError(f"the base needs x_left < x_right (both finite); got ({x_left}, {x_right}).")
    if bandwidth is not None and is_concrete(bandwidth) and not (float(bandwidth) > 0 and
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
    if is_concrete(temperature) and not float(temperature) > 0:
        raise InputError(f"temperature must be > 0 (or None for the plain max); got {temperature!r}.")
    scale = jax.lax.stop_gradient(jnp.max(jnp.abs(profile)))
    scale = jnp.where(scale > 0, scale, 1.0) * temperature
    return scale * jax.nn.logsumexp(profile / scale)


def divide_by_peak(values, peak) -> Array:
    """`values / peak` where the peak is positive, zeros where it is not (with
    a finite gradient either way)."""
    positive = peak > 0
    return jnp.where(positive, values / jnp.where(positive, peak, 1.0), 0.0)


def normalise(profile, *, temperature: float | None = None) -> Array:
    """`profile / profile_peak(profile)` (the plain max by default, see
    `profile_peak` for why); zeros when the peak is not positive."""
    peak = profile_peak(profile, temperature=temperature)
    return divide_by_peak(profile, peak)


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
    return Profile(x_over_b=u, normal=divide_by_peak(normal, peak), horizontal=divide_by_peak(horizontal, peak),
                   peak=peak)


# ------------------------------------------------- reading a profile off
def profile_at(profile, u) -> tuple[Array, Array | None]:
    """A profile's normal and horizontal values at positions u (x/B): linear
    between its points, and 0 at x/B = 0 and 1 (the feet) when its points stop
    short of them, as a binned profile's centres do. The horizontal value is
    None for a profile without one."""
    xp = jnp.asarray(profile.x_over_b)

    def at(values):
        values = jnp.asarray(values)
        xs = jnp.concatenate([jnp.zeros(1, xp.dtype), xp, jnp.ones(1, xp.dtype)])
        first = jnp.where(xp[0] > 0, 0.0, values[0])
        last = jnp.where(xp[-1] < 1, 0.0, values[-1])
        fs = jnp.concatenate([first[None], values, last[None]])
        return interp_without_scatter(jnp.asarray(u), xs, fs)

    return at(profile.normal), None if profile.horizontal is None else at(profile.horizontal)


def interp_without_scatter(x, xp, fp) -> Array:
    """`jnp.interp(x, xp, fp)` (ends held constant) with each point's two
    neighbours picked by a select over xp instead of gathers: the gathers'
    derivative is a scatter-add whose multi-output fusion aborts XLA:CPU's
    newer emitters (see `jaxpile.configure`, and docs/
    choices.md, "Multi-output fusion"), and xp holds a few
    dozen points, so a [len(x), len(xp)] select costs nothing. Same formula as
    jnp.interp: the same values to round-off."""
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


def dip_below_peak(profile) -> Array:
    """Depth of the central minimum of the normal profile: 1 - N(x/B = 1/2) / max N
    (0.25 for a centre 25% below the maxima; negative for a peak at the centre).
    The centre value is interpolated linearly between points."""
    normal = jnp.asarray(profile.normal)
    centre, _ = profile_at(profile, jnp.asarray(0.5))
    return 1.0 - divide_by_peak(centre, jnp.max(normal))


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
    if is_concrete(count) and float(count) < 2:
        raise InputError(f"central_slope needs at least 2 points within {half_width} of x/B = 0.5; widen "
                         "half_width or use more bins.")
    mean_u = jnp.sum(inside * u) / count
    mean_h = jnp.sum(inside * h) / count
    return jnp.sum(inside * (u - mean_u) * (h - mean_h)) / jnp.sum(inside * (u - mean_u) ** 2)
