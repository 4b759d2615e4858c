"""Liffman, Chan & Hughes 1992: linear spring with viscous sliding friction,
rolling friction and a static-friction well at the ground (soft contacts).

For disks 1, 2 with n = (x_1 - x_2) / r (Fig. 3) and t = z x n (eqs. 34-35):

  normal (eqs. 23-26):  F_n = K_s (a_1 + a_2 - r) - K_D V_norm,  V_norm = (v_1 - v_2) . n
  sliding (eqs. 27-28): F_slip = -K_slip v_tang,
                        v_tang = (v_1 - v_2) . t - r_1 w_1 - r_2 w_2
  rolling (eq. 29):     F_roll = -mu_roll |F_n| sign(v_tang)
  tangential (eq. 32):  F_t = the smaller in magnitude of F_slip and F_roll
  torque (eq. 36):      tau_1 = -r_1 F_slip (the paper's sigma F_slip / 2 with our
                        counter-clockwise sign convention)
  ground (eqs. 30, 33): F_t += -(mu_static N / a) (x - x_0) while |x - x_0| <= a,
                        N = max(F_n, 0), x_0 the disk's position when it came to rest
                        on the ground; beyond a the well breaks (no force) until
                        the disk rests again.

The paper's normal spring is time-discretised (eq. 24):
f_k = -[V(r_{k+1}) - V(r_k)] / (r_{k+1} - r_k) = K_s [sigma - (r_{k+1} + r_k) / 2],
solved implicitly. With the `implicit_midpoint` integrator the kernel receives
the displacements d_k, d_{k+1} and applies exactly that difference quotient
along (d_k + d_{k+1}) / (r_k + r_{k+1}), which makes the spring's work over a
step equal to minus the change of V (eq. 23): energy is conserved to the
solver's tolerance, contact entry and exit included. With the explicit
integrators it is the plain K_s (sigma - r).

The well is per-contact history of each disk against each wall:
`[anchored, x - x_0]`. A disk anchors when it touches the wall with a centre speed
along the wall below `rest_speed`. x - x_0 then integrates the centre's velocity
along the wall, not the contact point's. The paper has the well at the ground
only; here it acts at every wall, which is the same for its set-ups. Disk pairs
carry no history.

Only K_s is given in the paper (eq. 46: mg / (K_s sigma) = 1e-4). `paper_params`
takes our choices for the rest, and says so.
"""

from __future__ import annotations

import math
from typing import Any

import jax.numpy as jnp
from jaxpile._jax_md import dataclasses

from jaxpile.laws.base import (ContactLaw, PairForce, PairGeometry, contact_result, param_arrays, ranges_doc,
                               validate_ranges, with_set, dot2,
                               normal_and_distance, perp)
from jaxpile.ranges import NON_NEGATIVE, POSITIVE

Array = Any
NAME = "liffman"
PARAM_NAMES = ("ks", "kd", "k_slip", "mu_roll", "mu_static", "well_width", "rest_speed")
RANGES = {name: POSITIVE if name in ("ks", "well_width") else NON_NEGATIVE for name in PARAM_NAMES}
"""Each parameter's valid range (`jaxpile.ranges`): K_s and the well width > 0, the rest >= 0."""


@with_set
@dataclasses.dataclass
class Params:
    """Parameters of eqs. 25-33.

    Attributes:
      ks: K_s, normal spring constant (mg / sigma).
      kd: K_D, normal damping constant (force / velocity, not mass-scaled).
      k_slip: K_slip, viscous sliding friction constant (force / velocity).
      mu_roll: rolling friction coefficient.
      mu_static: static friction coefficient of the ground well.
      well_width: a, half-width of the well (sigma).
      rest_speed: a disk touching a wall anchors its well when its centre moves
        along the wall slower than this (sqrt(g sigma)).
    """

    ks: Array
    kd: Array
    k_slip: Array
    mu_roll: Array
    mu_static: Array
    well_width: Array
    rest_speed: Array


Params.__doc__ = (Params.__doc__ or "").rstrip() + ranges_doc(RANGES)


def make_params(ks=1.0e4, kd=50.0, k_slip=50.0, mu_roll=0.1, mu_static=1.0, well_width=0.05, rest_speed=1.0e-3,
                *, dtype=None) -> Params:
    dtype = jnp.zeros(()).dtype if dtype is None else dtype
    values = dict(ks=ks, kd=kd, k_slip=k_slip, mu_roll=mu_roll, mu_static=mu_static, well_width=well_width,
                  rest_speed=rest_speed)
    return Params(**param_arrays(NAME, values, RANGES, dtype))


def paper_params(dtype=None) -> Params:
    """K_s from eq. 46 (mg / (K_s sigma) = 1e-4). The paper gives no values for
    K_D, K_slip, mu_roll, mu_static or a: ours are K_D = K_slip = 50 mg/sqrt(g sigma)
    (about 0.35 of critical for a disk pair), mu_roll = 0.1, mu_static = 1 (the
    45-layer pile needs more than 0.55) and a = 0.05 sigma."""
    return make_params(dtype=dtype)


def wall_params(p: Params) -> Params:
    return p


def _time_averaged_spring(ks, sigma, d0, d1):
    """Eq. 24: the spring force vector -[V(r_1) - V(r_0)] / (r_1 - r_0) (d_0 + d_1) / (r_0 + r_1)
    for V = K_s (sigma - r)^2 / 2 inside contact (eq. 23), and whether either end
    is in contact. Both inside: K_s [sigma - (r_0 + r_1) / 2] exactly."""
    _, r0 = normal_and_distance(d0)
    _, r1 = normal_and_distance(d1)
    a0, a1 = jnp.maximum(sigma - r0, 0.0), jnp.maximum(sigma - r1, 0.0)
    both = (a0 > 0) & (a1 > 0)
    gap = r0 - r1  # nonzero whenever exactly one end is inside
    safe_gap = jnp.where(gap == 0, 1.0, gap)
    quotient = 0.5 * ks * jnp.where(both, a0 + a1, jnp.where(gap == 0, 0.0, (a1 * a1 - a0 * a0) / safe_gap))
    span = r0 + r1
    direction = (d0 + d1) / jnp.where(span > 0, span, 1.0)[..., None]
    return quotient * direction, (a0 > 0) | (a1 > 0)


def pair_force(p: Params, g: PairGeometry, history: Array, dt) -> PairForce:
    """Eqs. 24-33 for one pair; against a wall (radius_j = 0) with the well."""
    n, r = normal_and_distance(g.displacement)
    sigma = g.radius_i + g.radius_j
    t = perp(n)
    if g.step_displacements is None:
        spring = p.ks * (sigma - r) * n  # (25) with the explicit spring
        in_contact = (r < sigma) & (r > 0)
    else:
        spring, in_contact = _time_averaged_spring(p.ks, sigma, g.step_displacements[0], g.step_displacements[1])
        in_contact = in_contact & (r > 0)
    f_n = dot2(spring, n) - p.kd * dot2(g.velocity, n)  # (25)
    v_centre = dot2(g.velocity, t)
    v_tang = v_centre - g.radius_i * g.angular_velocity_i - g.radius_j * g.angular_velocity_j  # (28)
    f_slip = -p.k_slip * v_tang  # (27)
    f_roll = -p.mu_roll * jnp.abs(f_n) * jnp.sign(v_tang)  # (29)
    f_t = jnp.where(jnp.abs(f_slip) <= jnp.abs(f_roll), f_slip, f_roll)  # (32)

    # the static well (eqs. 30, 33), only against walls
    wall = g.radius_j == 0
    anchored = history[0] > 0.5
    anchored = anchored | (wall & in_contact & (jnp.abs(v_centre) < p.rest_speed))
    offset = jnp.where(anchored & (history[0] > 0.5), history[1] + v_centre * dt, 0.0)
    inside = wall & anchored & (jnp.abs(offset) <= p.well_width)
    f_static = jnp.where(inside, -p.mu_static * jnp.maximum(f_n, 0.0) / p.well_width * offset, 0.0)
    f_t = f_t + f_static  # (33)
    new_history = jnp.stack([jnp.where(inside, 1.0, 0.0), jnp.where(inside, offset, 0.0)])

    force = spring - p.kd * dot2(g.velocity, n) * n + f_t * t  # (34)-(35)
    torque = -g.radius_i * f_slip  # (36)
    torque_j = -g.radius_j * f_slip  # (36) for disk 2: its own radius, the same sense
    return contact_result(in_contact, force, torque, new_history, f_n, torque_j)


def interaction_range(p: Params, radius_i, radius_j) -> float:
    return radius_i + radius_j


def stable_time_step(p: Params, min_mass: float, min_radius: float = 0.5) -> float:
    """The hooke estimate with K_s, and K_D, K_slip as damping rates per unit mass."""
    omega = math.sqrt(8.0 * float(p.ks) / min_mass)
    gamma = max(float(p.kd), float(p.k_slip)) / min_mass
    limits = [2.0 / omega if omega > 0 else math.inf]  # a stiffness so small it underflows has no limit
    if gamma > 0:
        limits.append(2.0 / (4.0 * gamma))
    return min(limits)


def validate(p: Params) -> None:
    validate_ranges(NAME, p, RANGES)


def law(rotation: bool = True) -> ContactLaw:
    """The 1992 soft-contact law (two history values per contact: the well)."""
    return ContactLaw(name=NAME, history_size=2, rotation=bool(rotation), pair_force=pair_force,
                      wall_params=wall_params, interaction_range=interaction_range,
                      stable_time_step=stable_time_step, validate=validate, params_type=Params)


__all__ = ["NAME", "PARAM_NAMES", "Params", "law", "make_params", "paper_params", "pair_force"]
