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

Written component by component (`jaxpile.laws.vec`, for disks and spheres
alike): vmapped over the slots every intermediate is an `[n, k]` array, which
XLA on CPU fuses with the rest of a kernel (benchmarks/profile_step.py).
`frame`, `spring` and `force_spring` are the disks' forms that `granular` uses.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import jax.numpy as jnp

from jaxpile.laws import vec

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


class ContactFrame(NamedTuple):
    """`Frame` for disks or spheres, its vectors as tuples of components
    (`jaxpile.laws.vec`): `n`, the distance, the radii's sum, contact, the
    normal velocity and `vt`, the contact points' relative velocity
    v - (v . n) n - (r_i w_i + r_j w_j) x n."""

    n: tuple
    r: Array
    radsum: Array
    in_contact: Array
    vn: Array
    vt: tuple


def contact_frame(g) -> ContactFrame:
    """The `ContactFrame` of a `PairGeometry` of either dimension, safe at zero
    distance (n = 0, r = 0: a padded slot's gradient stays finite)."""
    d = vec.components(g.displacement)
    r2 = vec.dot(d, d)
    positive = r2 > 0
    r = jnp.sqrt(jnp.where(positive, r2, 1.0))
    inv_r = jnp.where(positive, 1.0 / r, 0.0)
    n = tuple(c * inv_r for c in d)
    r = jnp.where(positive, r, 0.0)
    radsum = g.radius_i + g.radius_j
    in_contact = (r < radsum) & positive
    v = vec.components(g.velocity)
    vn = vec.dot(v, n)
    if len(n) == 2:
        spin = g.radius_i * g.angular_velocity_i + g.radius_j * g.angular_velocity_j
        # z x n = (-ny, nx)
        vt = (v[0] - vn * n[0] + spin * n[1], v[1] - vn * n[1] - spin * n[0])
    else:
        w_i, w_j = vec.components(g.angular_velocity_i), vec.components(g.angular_velocity_j)
        spin = tuple(g.radius_i * a + g.radius_j * b for a, b in zip(w_i, w_j))
        turn = vec.cross(spin, n)
        vt = tuple(vk - vn * nk - tk for vk, nk, tk in zip(v, n, turn))
    return ContactFrame(n, r, radsum, in_contact, vn, vt)


def frame(g) -> Frame:
    """The `Frame` of a disks' `PairGeometry` (`contact_frame` in 2D components)."""
    f = contact_frame(g)
    return Frame(f.n[0], f.n[1], f.r, f.radsum, f.in_contact, f.vn, f.vt[0], f.vt[1])


def spring_vec(s: tuple, n: tuple, vt: tuple, kt, damping, cap, dt, turn_in_plane: bool) -> tuple[tuple, tuple]:
    """One step of the spring for either dimension: `(F_t, s)`, the capped
    tangential force on i and the new shear displacement, each a tuple of
    components.

    Args:
      s: the shear displacement carried from the last step.
      n: the unit normal; vt: the contact points' relative velocity.
      kt: the spring's stiffness; damping: eta_t (force per velocity).
      cap: F_crit, the largest |F_t|.
      turn_in_plane: `pair_style granular`'s frame (True) or
        `gran/hooke/history`'s (False).
    """
    if turn_in_plane:
        s = turned(s, n, lambda sn: jnp.abs(sn) * kt > FRAME_EPSILON * cap)
        s = tuple(sk + vk * dt for sk, vk in zip(s, vt))
        s2 = vec.dot(s, s)
    else:
        s = tuple(sk + vk * dt for sk, vk in zip(s, vt))
        s2 = vec.dot(s, s)
        sn = vec.dot(s, n)
        s = tuple(sk - sn * nk for sk, nk in zip(s, n))  # rotate into the current tangent plane
    ft = tuple(-(kt * sk + damping * vk) for sk, vk in zip(s, vt))
    ft2 = vec.dot(ft, ft)
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
    s = tuple(jnp.where(rescale, jnp.where(has_kt, ratio * (sk + damping * vk * inv_kt) - damping * vk * inv_kt, 0.0),
                        sk) for sk, vk in zip(s, vt))
    keep = jnp.where(sliding & (s2 <= 0), 0.0, ratio)
    return tuple(keep * fk for fk in ft), s


def spring(sx, sy, nx, ny, vtx, vty, kt, damping, cap, dt, turn_in_plane: bool):
    """`spring_vec` for disks in components: `(ftx, fty, sx, sy)`."""
    (ftx, fty), (sx, sy) = spring_vec((sx, sy), (nx, ny), (vtx, vty), kt, damping, cap, dt, turn_in_plane)
    return ftx, fty, sx, sy


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


def turned(s: tuple, n: tuple, turns) -> tuple:
    """s turned into the tangent plane of n keeping its length, where
    `turns(s . n)` (LAMMPS's test), else as it was; either dimension."""
    sn = vec.dot(s, n)
    turn = turns(sn)
    length2 = vec.dot(s, s)
    projected = tuple(sk - sn * nk for sk, nk in zip(s, n))
    projected2 = vec.dot(projected, projected)
    keep_length = projected2 > 0
    scale = jnp.where(keep_length, jnp.sqrt(jnp.where(keep_length, length2, 1.0)
                                            / jnp.where(keep_length, projected2, 1.0)), 0.0)
    return tuple(jnp.where(turn, pk * scale, sk) for pk, sk in zip(projected, s))


def _turned(sx, sy, nx, ny, turns):
    """`turned` for disks in components."""
    return turned((sx, sy), (nx, ny), turns)


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


__all__ = ["FRAME_EPSILON", "ContactFrame", "Frame", "capped_dashpot", "contact_frame", "force_spring", "frame", "spring",
           "spring_vec", "turned"]
