"""Lee & Herrmann 1993: Hertzian repulsion with Cundall-Strack static friction.

For disks i, j (radii a_i, a_j), r = R_i - R_j, n = r / |r|, s = n rotated by
pi/2 clockwise, relative velocity v = V_i - V_j and effective mass
m_e = m_i m_j / (m_i + m_j), the force on i is F = F_n n + F_s s (eq. 1) with

  F_n = k_n (a_i + a_j - r)^{3/2} - gamma_n m_e (v . n)                      (2a)
  F_s = -gamma_s m_e (v . s) - sign(delta_s) min(k_s |delta_s|, mu F_n)      (2b)

delta_s is the shear displacement since the contact formed (the integral of
v . s over the contact's life), removed when the contact breaks. The cap uses
max(F_n, 0): the paper does not say what happens when damping makes F_n < 0.

Sliding (`law(slip=...)`). The paper says it uses the scheme of Cundall & Strack
1979, in which the shear spring slips: while k_s |delta_s| exceeds mu F_n,
delta_s is set back to sign(delta_s) mu F_n / k_s, so a reversal of the motion
reverses the friction at once and sliding dissipates mu F_n |v_s| (the default,
`slip="cundall-strack"`). Eq. 2b read literally (`slip="literal"`) caps only the
force: delta_s keeps growing while the pair slides, so a contact rocking in the
slip regime returns the work it took, and with the paper's gamma_s = gamma_n /
100 piles never come to rest (docs/choices.md#sliding-in-the-1993-law).

Walls have the same form with a_j = 0 and m_j = infinity (m_e = m_i), with their
own stiffness (`wall_kn`, 2e6 in the paper). The paper's particles do not rotate:
`law()` freezes rotation by default; with `rotation=True` the spins enter the
contact velocity and F_s exerts a torque, as for the other laws. Rolling
resistance (`law(rolling="sds" | "constant")`, with rotation on, not in the
paper; `jaxpile.laws.rolling`): a torque R_eff f_r on i and -R_eff f_r on j once
F_n (eq. 2a) is known, capped at mu_roll |F_n| R_eff, carried as a second
history entry; walls use the same values.

Units: the paper's values (`paper_params`) are in its own units (cgs-like: radii
around 0.1). It gives neither g nor the density; the protocols using this preset
state their choice.
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
from jaxpile.ranges import NON_NEGATIVE, POSITIVE

Array = Any
NAME = "lee-herrmann"
WALL_NAMES = ("wall_kn", "wall_ks", "wall_gamma_n", "wall_gamma_s", "wall_mu")
PARAM_NAMES = ("kn", "ks", "gamma_n", "gamma_s", "mu") + WALL_NAMES + rolling_.PARAM_NAMES
RANGES = {**{name: POSITIVE if name in ("kn", "wall_kn") else NON_NEGATIVE for name in PARAM_NAMES[:10]},
          **rolling_.RANGES}
"""Each parameter's valid range (`jaxpile.ranges`): the normal stiffness > 0, the rest >= 0."""
OPTIONAL = WALL_NAMES + rolling_.PARAM_NAMES
"""The parameters that may be None (unset)."""


@with_set
@dataclasses.dataclass
class Params:
    """Parameters of eqs. 2a-2b.

    Attributes:
      kn: Hertzian stiffness (force / length^{3/2}).
      ks: shear spring stiffness (force / length).
      gamma_n, gamma_s: damping rates (1 / time), force = gamma m_e v.
      mu: Coulomb friction coefficient.
      wall_*: the same against walls; `None` = the disk value.
    """

    kn: Array
    ks: Array
    gamma_n: Array
    gamma_s: Array
    mu: Array
    wall_kn: Array = None
    wall_ks: Array = None
    wall_gamma_n: Array = None
    wall_gamma_s: Array = None
    wall_mu: Array = None
    k_roll: Array = None
    gamma_roll: Array = None
    mu_roll: Array = None


Params.__doc__ = (Params.__doc__ or "").rstrip() + "\n" + rolling_.DOC + ranges_doc(RANGES)


def make_params(kn=1.0e6, ks=None, gamma_n=5.0e2, gamma_s=None, mu=0.2, *, k_roll=None, gamma_roll=None,
                mu_roll=None, dtype=None, **wall) -> Params:
    """Parameters, with the paper's ratios for what is left out: k_s = k_n / 100
    and gamma_s = gamma_n / 100; the rolling parameters stay None unless given."""
    unknown = set(wall) - set(WALL_NAMES)
    if unknown:
        raise InputError(f"unknown {NAME} parameter(s) {sorted(unknown)}; known: {list(PARAM_NAMES)}.")
    dtype = jnp.zeros(()).dtype if dtype is None else dtype
    # arrays (and refused if not numbers) before the defaults are computed from them
    kn, gamma_n = param_arrays(NAME, dict(kn=kn, gamma_n=gamma_n), RANGES, dtype).values()
    values = dict(kn=kn, ks=kn / 100.0 if ks is None else ks, gamma_n=gamma_n,
                  gamma_s=gamma_n / 100.0 if gamma_s is None else gamma_s, mu=mu, **wall, k_roll=k_roll,
                  gamma_roll=gamma_roll, mu_roll=mu_roll)
    return Params(**param_arrays(NAME, values, RANGES, dtype, optional=OPTIONAL))


def paper_params(dtype=None) -> Params:
    """Lee & Herrmann 1993, sec. 3: k_n = 1e6, k_s = 1e4, gamma_n = 5e2,
    gamma_s = gamma_n / 100, mu = 0.2, walls k_n = 2e6 (paper units)."""
    return make_params(kn=1.0e6, ks=1.0e4, gamma_n=5.0e2, gamma_s=5.0, mu=0.2, wall_kn=2.0e6, dtype=dtype)


def wall_params(p: Params) -> Params:
    pick = lambda w, d: d if w is None else w
    return Params(kn=pick(p.wall_kn, p.kn), ks=pick(p.wall_ks, p.ks), gamma_n=pick(p.wall_gamma_n, p.gamma_n),
                  gamma_s=pick(p.wall_gamma_s, p.gamma_s), mu=pick(p.wall_mu, p.mu),
                  k_roll=p.k_roll, gamma_roll=p.gamma_roll, mu_roll=p.mu_roll)


def pair_force(p: Params, g: PairGeometry, history: Array, dt) -> PairForce:
    """Eqs. 1, 2a, 2b for one pair with the Cundall-Strack slip of the shear
    spring; `history[0]` is delta_s."""
    return _pair_force(p, g, history, dt, slip=True)


def pair_force_literal(p: Params, g: PairGeometry, history: Array, dt) -> PairForce:
    """Eqs. 1, 2a, 2b as written: delta_s keeps growing while the pair slides."""
    return _pair_force(p, g, history, dt, slip=False)


def _make_pair_force(slip: bool, rolling):
    def kernel(p: Params, g: PairGeometry, history: Array, dt) -> PairForce:
        """Eqs. 1, 2a, 2b with rolling resistance; `history[0]` is delta_s, `history[1]` the rolling entry."""
        return _pair_force(p, g, history, dt, slip=slip, rolling=rolling)
    return kernel


def _pair_force(p: Params, g: PairGeometry, history: Array, dt, slip: bool, rolling=None) -> PairForce:
    n, r = normal_and_distance(g.displacement)
    overlap = g.radius_i + g.radius_j - r
    in_contact = (overlap > 0) & (r > 0)
    s = -perp(n)  # n rotated by pi/2 clockwise
    spin = g.radius_i * g.angular_velocity_i + g.radius_j * g.angular_velocity_j
    v_n = dot2(g.velocity, n)
    v_s = dot2(g.velocity, s) + spin  # contact points' relative velocity along s

    compression = jnp.where(in_contact, overlap, 0.0)
    f_n = p.kn * compression * safe_sqrt(compression) - p.gamma_n * g.effective_mass * v_n  # (2a)
    delta_s = history[0] + v_s * dt
    static = jnp.minimum(p.ks * jnp.abs(delta_s), p.mu * jnp.maximum(f_n, 0.0))
    f_s = -p.gamma_s * g.effective_mass * v_s - jnp.sign(delta_s) * static  # (2b)
    if slip:  # the spring slips: keep k_s |delta_s| <= mu F_n (Cundall & Strack 1979)
        safe_ks = jnp.where(p.ks > 0, p.ks, 1.0)
        delta_s = jnp.where(p.ks > 0, jnp.sign(delta_s) * jnp.minimum(jnp.abs(delta_s), static / safe_ks), delta_s)

    force = f_n * n + f_s * s
    torque = g.radius_i * f_s  # (-a_i n) x (f_s s), z component
    torque_j = g.radius_j * f_s  # (a_j n) x (-f_s s)
    new_history = delta_s[None]
    if rolling is not None:
        roll_i, roll_j, carried = rolling_.resist(rolling, p, f_n, g.radius_i, g.radius_j, g.angular_velocity_i,
                                                  g.angular_velocity_j, g.effective_mass, history[1], dt)
        torque, torque_j = torque + roll_i, torque_j + roll_j
        new_history = jnp.stack([delta_s, carried])
    return contact_result(in_contact, force, torque, new_history, f_n, torque_j)


def interaction_range(p: Params, radius_i, radius_j) -> float:
    return radius_i + radius_j


def stable_time_step(p: Params, min_mass: float, min_radius: float = 0.5) -> float:
    """Velocity-Verlet limit estimated with the Hertz contact's tangent stiffness
    1.5 k_n sqrt(delta) at a deep overlap delta = 5% of the smallest radius, and
    the lattice factor 8 k / m of the hooke law; a rolling spring and dashpot,
    where set, as in the hooke law."""
    w = wall_params(p)
    delta = 0.05 * min_radius
    k_roll, gamma_roll = rolling_.time_step_limits(p)
    k = max(1.5 * max(float(p.kn), float(w.kn)) * math.sqrt(delta), float(p.ks), float(w.ks), k_roll)
    gamma = max(float(p.gamma_n), float(p.gamma_s), float(w.gamma_n), float(w.gamma_s), gamma_roll / min_mass)
    omega = math.sqrt(8.0 * k / min_mass)
    limits = [2.0 / omega if omega > 0 else math.inf]  # a stiffness so small it underflows has no limit
    if gamma > 0:
        limits.append(2.0 / (4.0 * gamma))
    return min(limits)


def validate(p: Params) -> None:
    """Raises `InputError` on a negative or non-finite parameter, or a non-positive stiffness."""
    validate_ranges(NAME, p, RANGES)


SLIP_MODES = {"cundall-strack": pair_force, "literal": pair_force_literal}
# one kernel object per reading (equal laws hash alike; a jit closing over them compiles once)
_KERNELS = {**{(slip, None): kernel for slip, kernel in SLIP_MODES.items()},
            **{(slip, mode): _make_pair_force(slip == "cundall-strack", mode)
               for slip in SLIP_MODES for mode in rolling_.MODES}}


_VALIDATORS = rolling_.validators(NAME, validate)


def law(rotation: bool = False, slip: str = "cundall-strack", rolling: str | None = None) -> ContactLaw:
    """The Lee-Herrmann law; the paper's disks do not rotate (default).

    Args:
      rotation: let the disks rotate (the paper's do not).
      slip: `"cundall-strack"` (default) lets the shear spring slip at mu F_n;
        `"literal"` caps only the force (see the module docstring).
      rolling: None (default), `"sds"` or `"constant"`: rolling resistance
        (`jaxpile.laws.rolling`; needs `rotation=True`), recorded in `options`
        when set.
    """
    if slip not in SLIP_MODES:
        raise InputError(f"unknown slip mode {slip!r} for {NAME}; choose one of {sorted(SLIP_MODES)}.")
    rolling_.check_mode(NAME, rolling, rotation)
    return ContactLaw(name=NAME, history_size=1 + rolling_.HISTORY[rolling], rotation=bool(rotation),
                      pair_force=_KERNELS[slip, rolling],
                      wall_params=wall_params, interaction_range=interaction_range,
                      stable_time_step=stable_time_step, validate=_VALIDATORS[rolling], params_type=Params,
                      options=(("slip", slip),) + (() if rolling is None else (("rolling", rolling),)))
