"""The contact frame and the tangential spring with history that `hooke` and
`granular` share (`frame`, `spring`): the
shear displacement s of a pair, its force F_t = -(k_t s + eta_t v_tr), and the
Coulomb cap |F_t| <= F_crit with LAMMPS's rescale of s.

Two readings of the spring's frame, as the two LAMMPS pair styles have them:

- `gran/hooke/history`: s <- s + v_tr dt, then projected onto the current
  tangent plane (its length not kept).
- `pair_style granular` (29Sep2021): before the increment, when |s . n| k_t >
  1e-10 F_crit, s is turned into the current tangent plane keeping its length,
  s <- (s - (s . n) n) |s| / |s - (s . n) n|; then s <- s + v_tr dt.

Sliding (|F_t| > F_crit): F_t <- F_t F_crit / |F_t| and s <- -(F_t + eta_t
v_tr) / k_t, so that k_t s + eta_t v_tr stays on the Coulomb circle; with s = 0
there, F_t = 0 (LAMMPS semantics).

`force_spring` is the spring that carries its elastic force f instead of s
(`pair_style granular`'s `mindlin/force` forms; Thornton et al., Powder
Technol. 233, 30 (2013), eq. 18): f is turned as s is (when |f . n| > 1e-10
F_crit), then f <- f - k_t v_tr dt, F_t = f - eta_t v_tr; sliding, f <- F_t +
eta_t v_tr with F_t on the circle.

Written component by component (x, y scalars): vmapped over the slots every
intermediate is an `[n, k]` array, which XLA on CPU fuses with the rest of a
kernel (benchmarks/profile_step.py).
"""

from __future__ import annotations

from typing import Any, NamedTuple

import jax.numpy as jnp

Array = Any

FRAME_EPSILON = 1e-10
"""LAMMPS `pair_style granular`'s EPSILON: the shear spring is turned into the
tangent plane when |s . n| k_t exceeds this fraction of F_crit."""


class Frame(NamedTuple):
    """One pair's contact frame in components: the unit normal, the distance,
    the radii's sum, contact, the normal velocity and the contact points'
    relative velocity v - (v . n) n - (r_i w_i + r_j w_j)(z x n)."""

    nx: Array
    ny: Array
    r: Array
    radsum: Array
    in_contact: Array
    vn: Array
    vtx: Array
    vty: Array


def frame(g) -> Frame:
    """The `Frame` of a `PairGeometry`, safe at zero distance (n = 0, r = 0:
    a padded slot's gradient stays finite)."""
    dx, dy = g.displacement[0], g.displacement[1]
    r2 = dx * dx + dy * dy
    positive = r2 > 0
    r = jnp.sqrt(jnp.where(positive, r2, 1.0))
    inv_r = jnp.where(positive, 1.0 / r, 0.0)
    nx, ny = dx * inv_r, dy * inv_r
    r = jnp.where(positive, r, 0.0)
    radsum = g.radius_i + g.radius_j
    in_contact = (r < radsum) & positive
    vx, vy = g.velocity[0], g.velocity[1]
    vn = vx * nx + vy * ny
    spin = g.radius_i * g.angular_velocity_i + g.radius_j * g.angular_velocity_j
    # z x n = (-ny, nx)
    return Frame(nx, ny, r, radsum, in_contact, vn, vx - vn * nx + spin * ny, vy - vn * ny - spin * nx)


def spring(sx, sy, nx, ny, vtx, vty, kt, damping, cap, dt, turn_in_plane: bool):
    """One step of the spring: `(ftx, fty, sx, sy)`, the capped tangential force
    on i and the new shear displacement.

    Args:
      sx, sy: the shear displacement carried from the last step.
      nx, ny: the unit normal; vtx, vty: the contact points' relative velocity.
      kt: the spring's stiffness; damping: eta_t (force per velocity).
      cap: F_crit, the largest |F_t|.
      turn_in_plane: `pair_style granular`'s frame (True) or
        `gran/hooke/history`'s (False).
    """
    if turn_in_plane:
        sx, sy = _turned(sx, sy, nx, ny, lambda sn: jnp.abs(sn) * kt > FRAME_EPSILON * cap)
        sx, sy = sx + vtx * dt, sy + vty * dt
        s2 = sx * sx + sy * sy
    else:
        sx, sy = sx + vtx * dt, sy + vty * dt
        s2 = sx * sx + sy * sy
        sn = sx * nx + sy * ny
        sx, sy = sx - sn * nx, sy - sn * ny  # rotate into the current tangent plane
    ftx, fty = -(kt * sx + damping * vtx), -(kt * sy + damping * vty)
    ft2 = ftx * ftx + fty * fty
    sliding = ft2 > cap * cap
    # cap / |F_t| with a select between the divide and the sqrt: XLA rewrites
    # a / sqrt(b) into a * rsqrt(b), and XLA:CPU emits a float64 rsqrt as scalar
    # code, leaving the whole fusion around it unvectorised (benchmarks/profile_step.py).
    # The sqrt's own argument stays selected too: sqrt'(0) is infinite, and 0 * inf
    # in the unselected branch would make the gradient NaN where F_t = 0.
    ratio = _cap_ratio(sliding, cap, ft2)
    # Sliding: keep k_t s + eta_t v_tr on the Coulomb circle (LAMMPS rescale).
    has_kt = kt > 0
    inv_kt = jnp.where(has_kt, 1.0 / jnp.where(has_kt, kt, 1.0), 0.0)
    rescale = sliding & (s2 > 0)
    sx = jnp.where(rescale, jnp.where(has_kt, ratio * (sx + damping * vtx * inv_kt) - damping * vtx * inv_kt, 0.0), sx)
    sy = jnp.where(rescale, jnp.where(has_kt, ratio * (sy + damping * vty * inv_kt) - damping * vty * inv_kt, 0.0), sy)
    keep = jnp.where(sliding & (s2 <= 0), 0.0, ratio)
    return keep * ftx, keep * fty, sx, sy


def force_spring(fx, fy, nx, ny, vtx, vty, kt, damping, cap, dt):
    """One step of the spring that carries its elastic force (module notes):
    `(ftx, fty, fx, fy)`, the capped tangential force on i and the new elastic
    force; arguments as `spring`'s, with the force `fx, fy` in place of s."""
    fx, fy = _turned(fx, fy, nx, ny, lambda fn: jnp.abs(fn) > FRAME_EPSILON * cap)
    fx, fy = fx - kt * vtx * dt, fy - kt * vty * dt
    f2 = fx * fx + fy * fy
    ftx, fty = fx - damping * vtx, fy - damping * vty
    ft2 = ftx * ftx + fty * fty
    sliding = ft2 > cap * cap
    ratio = _cap_ratio(sliding, cap, ft2)
    rescale = sliding & (f2 > 0)
    fx = jnp.where(rescale, ratio * ftx + damping * vtx, fx)
    fy = jnp.where(rescale, ratio * fty + damping * vty, fy)
    keep = jnp.where(sliding & (f2 <= 0), 0.0, ratio)
    return keep * ftx, keep * fty, fx, fy


def _turned(sx, sy, nx, ny, turns):
    """(sx, sy) turned into the tangent plane of n keeping its length, where
    `turns(s . n)` (LAMMPS's test), else as it was."""
    sn = sx * nx + sy * ny
    turn = turns(sn)
    length2 = sx * sx + sy * sy
    px, py = sx - sn * nx, sy - sn * ny
    projected2 = px * px + py * py
    keep_length = projected2 > 0
    scale = jnp.where(keep_length, jnp.sqrt(jnp.where(keep_length, length2, 1.0)
                                            / jnp.where(keep_length, projected2, 1.0)), 0.0)
    return jnp.where(turn, px * scale, sx), jnp.where(turn, py * scale, sy)


def _cap_ratio(sliding, cap, ft2):
    """cap / |F_t| where sliding, else 1."""
    return jnp.where(sliding, cap / jnp.where(sliding, jnp.sqrt(jnp.where(sliding, ft2, 1.0)), 1.0), 1.0)


def capped_dashpot(vtx, vty, damping, cap):
    """The tangential force without a spring (LAMMPS `tangential
    linear_nohistory`): F_t = -eta_t v_tr, capped at F_crit."""
    ftx, fty = -damping * vtx, -damping * vty
    ft2 = ftx * ftx + fty * fty
    sliding = ft2 > cap * cap
    ratio = _cap_ratio(sliding, cap, ft2)
    return ratio * ftx, ratio * fty


__all__ = ["FRAME_EPSILON", "Frame", "capped_dashpot", "force_spring", "frame", "spring"]
