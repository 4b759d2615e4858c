"""Baxter, Tuzun, Burnell & Heyes 1997: a continuous, long-tailed normal force
with an accumulated tangential displacement.

For disks i, j with mean diameter sigma_ij = a_i + a_j, centre distance r,
n = (x_i - x_j) / r and t = z x n:

  normal (eq. 3):  F^N = F_e^N(r) - C_N(r) (v . n),
                   F_e^N(r) = mg (sigma_ij / r)^{n+1} for r < r0 sigma_ij, else 0
  damping:         C_N = f 2 sqrt(m k(r)),  k(r) = -dF_e^N/dr = (n+1) F_e^N / r,
                   f = 0.5 (50% of critical)
  tangential (eqs. 4-5):
                   F^T = -sign(delta_F) mu F_e^N [1 - (1 - |delta_F|/delta_max)^{3/2}]
                         - C_T (v_t),
  displacement (eq. 6): delta_F = integral of the contact points' relative
                   tangential velocity since the pair engaged at r = r0 sigma_ij,
  delta_max = alpha mu delta_N, delta_N = r0 sigma_ij - r, alpha = 1.214;
                   at |delta_F| = delta_max the contact slides grossly:
                   F^T = mu F_e^N and delta_F is held at +-delta_max,
  stiffness (eq. 7): k_T = 3 mu F_e^N / (2 delta_max) (1 - |delta_F|/delta_max)^{1/2},
  damping (eq. 8): C_T = f 2 sqrt(m k_T).

Readings of the printed equations: where the text admits two, both are options
of `law(...)`, named after what they mean (docs/baxter1997_audit.md#the-law
reads each against the paper and measures it on poured heaps):
- The exponent's sign (one reading only): the printed form would give a force
  that grows with r; it must fall with r and equal mg at r = sigma, so that two
  disks stacked under gravity rest at exactly r = sigma.
- `lever_arm`, the arm in eqs. 6 and 13. `"contact-point"` (default): from each
  centre to the contact point, r a_i / (a_i + a_j), in both, so a pair turning
  rigidly does not strain its contact. `"centre-distance"`: the printed r_ij for
  both disks, so rolling without slip, and rigid turning, strain the contact.
- `slip`, delta_F at gross sliding (eq. 5 holds for |delta_F| <= delta_max,
  which shrinks as a pair separates). `"hold"` (default) clips delta_F to
  +-delta_max at every step; `"accumulate"` keeps integrating it and caps only
  the force, so a contact that slid far must be strained back as far.
- `damping_mass`, the m of C_c = 2 sqrt(m k) (eqs. 3 and 8). `"pair"` (default):
  2 m_i m_j / (m_i + m_j), the paper's m for two equal disks, and 2 m_i against
  a wall or a fixed disk; `"disk"`: the printed m against a fixed partner too,
  m_i (its substrate contacts damped sqrt(2) less).

Walls act as partners of zero radius: sigma_ij = a_i, so a disk rests on the
ground with its centre exactly a_i above it.

Rolling resistance (`law(rolling="sds" | "constant")`, `jaxpile.laws.rolling`;
not in the paper): a torque R_eff f_r on i and -R_eff f_r on j while the pair is
engaged (r < r0 sigma_ij), capped at mu_roll |F^N| R_eff with F^N of eq. 3
(damping included), carried as a second history entry. Walls use the same values.
"""

from __future__ import annotations

import math
from typing import Any

import jax.numpy as jnp
from jaxpile._jax_md import dataclasses

from jaxpile.errors import InputError
from jaxpile.laws import rolling as rolling_
from jaxpile.laws.base import (ContactLaw, PairForce, PairGeometry, contact_result, param_arrays, ranges_doc,
                               validate_ranges, with_set, dot2,
                               normal_and_distance, perp, safe_sqrt)
from jaxpile.ranges import NON_NEGATIVE, POSITIVE, Range

Array = Any
NAME = "baxter"
PARAM_NAMES = ("n", "r0", "mu", "alpha", "damping_fraction", "weight", "wall_mu") + rolling_.PARAM_NAMES
RANGES = {
    "n": Range(low=0, low_open=True, high=1000, why="beyond ~1000 the law is a hard disk: its stiffness overflows"),
    "r0": Range(low=1, low_open=True, high=3, why="a cut-off beyond contact; the neighbour list grows as r0^2"),
    "mu": NON_NEGATIVE, "alpha": NON_NEGATIVE, "damping_fraction": NON_NEGATIVE, "weight": POSITIVE,
    "wall_mu": NON_NEGATIVE, **rolling_.RANGES,
}
"""Each parameter's valid range (`jaxpile.ranges`); the paper uses n = 36 and 144, r0 = 1.047 and 1.2."""


@with_set
@dataclasses.dataclass
class Params:
    """Parameters of eqs. 3-8.

    Attributes:
      n: the force-law index (float, so it can be fitted): F ~ r^{-(n+1)}.
      r0: cut-off as a multiple of sigma_ij (1.2 in the paper; 1.047 with n = 144).
      mu: friction coefficient.
      alpha: delta_max = alpha mu delta_N (1.214 in the paper).
      damping_fraction: fraction f of critical damping (0.5 in the paper).
      weight: mg, the force at r = sigma_ij (1 in reduced units).
      wall_mu: friction against walls (`None` = mu).
    """

    n: Array
    r0: Array
    mu: Array
    alpha: Array
    damping_fraction: Array
    weight: Array
    wall_mu: Array = None
    k_roll: Array = None
    gamma_roll: Array = None
    mu_roll: Array = None


Params.__doc__ = (Params.__doc__ or "").rstrip() + "\n" + rolling_.DOC + ranges_doc(RANGES)


def make_params(n=36.0, r0=1.2, mu=0.5, alpha=1.214, damping_fraction=0.5, weight=1.0, *, wall_mu=None,
                k_roll=None, gamma_roll=None, mu_roll=None, dtype=None) -> Params:
    dtype = jnp.zeros(()).dtype if dtype is None else dtype
    values = dict(n=n, r0=r0, mu=mu, alpha=alpha, damping_fraction=damping_fraction, weight=weight, wall_mu=wall_mu,
                  k_roll=k_roll, gamma_roll=gamma_roll, mu_roll=mu_roll)
    return Params(**param_arrays(NAME, values, RANGES, dtype, optional=("wall_mu",) + rolling_.PARAM_NAMES))


def paper_params(n: float = 36.0, r0: float | None = None, mu: float = 0.5, dtype=None) -> Params:
    """The paper's settings: n = 36 with r0 = 1.2 sigma; for n = 144 the paper's
    short tail r0 = 1.047 sigma is the default (pass r0 = 1.2 for the long tail)."""
    if r0 is None:
        r0 = 1.047 if n == 144 else 1.2
    return make_params(n=n, r0=r0, mu=mu, dtype=dtype)


def wall_params(p: Params) -> Params:
    return p.set(mu=p.mu if p.wall_mu is None else p.wall_mu, wall_mu=None)


def normal_force(p: Params, r, sigma):
    """F_e^N(r) = mg (sigma / r)^{n+1} inside the cut-off, 0 beyond (eq. 3)."""
    inside = (r < p.r0 * sigma) & (r > 0)
    ratio = sigma / jnp.where(inside, r, sigma)
    return jnp.where(inside, p.weight * jnp.exp((p.n + 1.0) * jnp.log(ratio)), 0.0)


LEVER_ARMS = ("contact-point", "centre-distance")
SLIP_MODES = ("hold", "accumulate")
DAMPING_MASSES = ("pair", "disk")


def make_pair_force(lever_arm: str = "contact-point", slip: str = "hold", damping_mass: str = "pair",
                    rolling: str | None = None):
    """The eqs. 3-8 kernel in one reading (see the module docstring), with the
    rolling resistance `rolling` (None: none)."""
    centre = lever_arm == "centre-distance"
    hold = slip == "hold"
    own_mass = damping_mass == "disk"

    def pair_force(p: Params, g: PairGeometry, history: Array, dt) -> PairForce:
        """Eqs. 3-8 for one pair; `history[0]` is delta_F."""
        n_hat, r = normal_and_distance(g.displacement)
        sigma = g.radius_i + g.radius_j
        cutoff = p.r0 * sigma
        engaged = (r < cutoff) & (r > 0)
        t_hat = perp(n_hat)
        m_ref = 2.0 * g.effective_mass
        if own_mass and g.partner_fixed is not None:  # the printed m: the moving disk's own mass
            m_ref = jnp.where(g.partner_fixed, g.effective_mass, m_ref)

        f_elastic = normal_force(p, r, sigma)
        stiffness = (p.n + 1.0) * f_elastic / jnp.where(engaged, r, 1.0)
        v_n = dot2(g.velocity, n_hat)
        f_n = f_elastic - p.damping_fraction * 2.0 * safe_sqrt(m_ref * stiffness) * v_n  # (3)

        if centre:  # eqs. 6 and 13 as printed: the arm is r_ij for both disks
            lever_i = lever_j = r
        else:  # the contact point divides r in the ratio of the radii
            lever_i = r * g.radius_i / sigma
            lever_j = r * g.radius_j / sigma
        v_t = dot2(g.velocity, t_hat) - (g.angular_velocity_i * lever_i + g.angular_velocity_j * lever_j)  # (6)

        delta_max = p.alpha * p.mu * jnp.maximum(cutoff - r, 0.0)
        delta = history[0] + v_t * dt
        if hold:  # gross sliding holds it at delta_max
            delta = jnp.clip(delta, -delta_max, delta_max)
        safe_max = jnp.where(delta_max > 0, delta_max, 1.0)
        reserve = jnp.where(delta_max > 0, jnp.maximum(1.0 - jnp.abs(delta) / safe_max, 0.0), 0.0)
        mobilised = 1.0 - reserve * safe_sqrt(reserve)
        f_t_elastic = -jnp.sign(delta) * p.mu * f_elastic * mobilised  # (5)
        k_t = 1.5 * p.mu * f_elastic / safe_max * safe_sqrt(reserve)  # (7)
        f_t = f_t_elastic - p.damping_fraction * 2.0 * safe_sqrt(m_ref * k_t) * v_t  # (4), (8)

        force = f_n * n_hat + f_t * t_hat
        torque = -lever_i * f_t  # (-lever_i n) x (f_t t)
        torque_j = -lever_j * f_t  # (lever_j n) x (-f_t t)
        new_history = delta[None]
        if rolling is not None:
            roll_i, roll_j, carried = rolling_.resist(rolling, p, f_n, g.radius_i, g.radius_j, g.angular_velocity_i,
                                                      g.angular_velocity_j, g.effective_mass, history[1], dt)
            torque, torque_j = torque + roll_i, torque_j + roll_j
            new_history = jnp.stack([delta, carried])
        return contact_result(engaged, force, torque, new_history, f_n, torque_j)

    return pair_force


# one kernel object per reading, so that laws built with the same options are
# equal (hashable alike) and a jit that closes over them compiles once
ROLLING = (None,) + rolling_.MODES
_KERNELS = {(arm, slip, mass, mode): make_pair_force(arm, slip, mass, mode)
            for arm in LEVER_ARMS for slip in SLIP_MODES for mass in DAMPING_MASSES for mode in ROLLING}
pair_force = _KERNELS["contact-point", "hold", "pair", None]


def hooke_equivalent(n: float, r0: float, r_min: float, sigma: float = 1.0, weight: float = 1.0) -> float:
    """Eq. 14: the Hooke constant k doing the same work between r0 and the
    smallest separation r_min as F_e^N, 0.5 k (sigma - r_min)^2 = int_{r_min}^{r0} F_e^N dr.
    (The printed integral runs from r0 to r_i; the work is positive this way.)

    Args:
      n, r0: the law (r0 as a multiple of sigma).
      r_min: smallest separation observed (< sigma).
    """
    if not 0 < r_min < sigma:
        raise InputError(f"r_min must be between 0 and sigma = {sigma}; got {r_min}.")
    work = weight * sigma / n * ((sigma / r_min) ** n - (1.0 / r0) ** n)
    return 2.0 * work / (sigma - r_min) ** 2


def interaction_range(p: Params, radius_i, radius_j) -> float:
    return float(p.r0) * (radius_i + radius_j)


def stable_time_step(p: Params, min_mass: float, min_radius: float = 0.5) -> float:
    """Estimate with the force law's stiffness k(r) at r = 0.95 sigma (a deep
    overlap for n = 36) and the lattice factor 8 k / m; damping is at most
    critical, which the undamped limit already covers to within a factor 2. A
    rolling spring and dashpot, where set, as in the hooke law."""
    r = 0.95
    k_roll, gamma_roll = rolling_.time_step_limits(p)
    k = max((float(p.n) + 1.0) * float(p.weight) * r ** (-(float(p.n) + 2.0)) / (2.0 * min_radius), k_roll)
    omega = math.sqrt(8.0 * k / min_mass)
    limits = [1.0 / omega if omega > 0 else math.inf]  # a stiffness so small it underflows has no limit
    if gamma_roll > 0:
        limits.append(2.0 / (4.0 * gamma_roll / min_mass))
    return min(limits)


def validate(p: Params) -> None:
    """Raises `InputError` on a parameter outside `RANGES`."""
    validate_ranges(NAME, p, RANGES)


_VALIDATORS = rolling_.validators(NAME, validate)


def law(rotation: bool = True, lever_arm: str = "contact-point", slip: str = "hold",
        damping_mass: str = "pair", rolling: str | None = None) -> ContactLaw:
    """The Baxter et al. law (disks rotate, eqs. 10, 12, 13).

    Args:
      rotation: integrate the spins (the paper's disks rotate).
      lever_arm: `"contact-point"` (default) or `"centre-distance"` (eqs. 6 and
        13 as printed); see the module docstring.
      slip: `"hold"` (default: delta_F clipped to +-delta_max) or `"accumulate"`
        (delta_F integrated on, only the force capped).
      damping_mass: `"pair"` (default: 2 m_i m_j / (m_i + m_j), 2 m_i against a
        fixed partner) or `"disk"` (the printed m: m_i against a fixed partner).
      rolling: None (default), `"sds"` or `"constant"`: rolling resistance
        (`jaxpile.laws.rolling`), recorded in `options` when set.
    """
    if lever_arm not in LEVER_ARMS:
        raise InputError(f"unknown lever_arm {lever_arm!r} for {NAME}; choose one of {list(LEVER_ARMS)}.")
    if slip not in SLIP_MODES:
        raise InputError(f"unknown slip mode {slip!r} for {NAME}; choose one of {list(SLIP_MODES)}.")
    if damping_mass not in DAMPING_MASSES:
        raise InputError(f"unknown damping_mass {damping_mass!r} for {NAME}; choose one of {list(DAMPING_MASSES)}.")
    rolling_.check_mode(NAME, rolling, rotation)
    return ContactLaw(name=NAME, history_size=1 + rolling_.HISTORY[rolling], rotation=bool(rotation),
                      pair_force=_KERNELS[lever_arm, slip, damping_mass, rolling],
                      wall_params=wall_params, interaction_range=interaction_range,
                      stable_time_step=stable_time_step, validate=_VALIDATORS[rolling], params_type=Params,
                      options=(("lever_arm", lever_arm), ("slip", slip), ("damping_mass", damping_mass))
                      + (() if rolling is None else (("rolling", rolling),)))
