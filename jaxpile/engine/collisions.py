"""Hard-disk (impulsive) collisions of Liffman, Chan & Hughes 1992, eqs. (1)-(22).

When two disks meet *fast* (see eq. (22)), the contact is not resolved by a
spring but by one instantaneous impulse `P` that changes velocities and spins
in a single step. `collide` is that operator for one touching pair: it
conserves linear momentum (eq. 1) and angular momentum of each disk about the
contact point Q (eqs. 2-3), restores the normal relative velocity with the
restitution coefficient epsilon (eq. 4), and picks the tangential impulse from
either Coulomb sliding (SLIP, eq. 7) or sticking (NOSLIP, eq. 8) by eq. (19).
`needs_soft_contact` is the eq. (22) test telling when the hard treatment has
to hand over to the soft (force-based) contact law, i.e. when a particle is
pushed into a surface so hard that within one time step it would go through.

`collide` is pure and works on a single pair (vmap it for a batch);
`check_collision_inputs` is the host-side guard. `HardCollisions` switches the
operator on in the time stepper (`Simulator(..., hard_collisions=...)`), see
`hard_collision_velocities` for how pairs are picked and handed over to the
soft law by eq. (22).

Sign conventions (Fig. 1 of the paper; all derived, see the report/tests):
  * `n = (x2 - x1) / |x2 - x1|` points from disk 1 to disk 2, `t = (-n_y, n_x)`
    so that `z = n x t` (eqs. 20-21); spins `w` are counter-clockwise (+z).
  * `r_i` in eqs. (2)-(3) and (9) is the vector from Q to the centre of disk i:
    `r_1 = -r1 n`, `r_2 = +r2 n`, so `r_i x w_i = -w_i (z x r_i)` and
    (eqs. 17-18) `(r_1 x w_1).t = r1 w1`, `(r_2 x w_2).t = -r2 w2`.
  * Contact-point relative velocity (eq. 9):
    `g = c1 - c2 + (r1 w1 + r2 w2) t`; the pair approaches when `g.n > 0`.
  * `P` is the impulse on disk 1 (eq. 6); `P_n = P.n < 0` for an approach.
  * Spins: `w1* = w1 + r1 P_t / I1` (eq. 13) and `w2* = w2 + r2 P_t / I2`.
    The printed second form of eq. (14), `w2 - r2 x P / I2`, has a sign slip:
    its first form `w2 + m2 r2 x (c2 - c2*) / I2` with `m2 (c2 - c2*) = P`
    (eq. 6) gives `w2 + r2 x P / I2 = w2 + r2 P_t / I2`; this is what is coded.

A wall or fixed body is a partner with `m2 = I2 = inf` (and any `r2 >= 0`):
the formulas use inverse masses, so it receives no velocity change.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxpile.engine.boundaries import wall_distance
from jaxpile.errors import InputError
from jaxpile.laws.base import safe_norm

Array = Any


class CollisionResult(NamedTuple):
    """Outcome of one hard collision.

    Attributes:
      c1, c2: `[2]` velocities after the collision, `c_i*`.
      w1, w2: `[]` counter-clockwise spins after the collision, `w_i*`.
      impulse: `[2]` impulse `P` on disk 1 (disk 2 receives `-P`), eq. (6).
      slipping: `[]` bool, True when the SLIP branch of eq. (19) was taken.
    """

    c1: Array
    c2: Array
    w1: Array
    w2: Array
    impulse: Array
    slipping: Array


def _safe_unit(d: Array) -> Array:
    """`d / |d|` for a `[2]` vector, 0 (with finite gradients) when `d = 0`."""
    d2 = d[0] * d[0] + d[1] * d[1]
    pos = d2 > 0
    return jnp.where(pos, d / jnp.sqrt(jnp.where(pos, d2, 1.0)), jnp.zeros_like(d))


def collide(m1, m2, I1, I2, r1, r2, x1, x2, c1, c2, w1, w2, restitution, mu) -> CollisionResult:
    """Post-collision state of two touching disks (Liffman, Chan & Hughes 1992).

    Steps, with `M = 1 / (1/m1 + 1/m2)` and `K = 1/m1 + 1/m2 + r1^2/I1 + r2^2/I2`:
      1. `n`, `t` from the centres (Fig. 1, eqs. 20-21) and the contact-point
         relative velocity `g` of eq. (9) with eqs. (17)-(18).
      2. Normal impulse, eq. (12): `P_n = -M (1 + eps) g.n`, which is eq. (4)
         `(c1* - c2*).n = -eps (c1 - c2).n` combined with eqs. (1), (5)-(6), (11).
      3. NOSLIP tangential impulse, eqs. (15)-(16): `P_t^NOSLIP = -g.t / K`,
         which makes `c*_12c . t = 0` (eq. 8). (Eq. 16 is this times m1/m1.)
      4. SLIP tangential impulse, eq. (7): `|P_t^SLIP| = mu |P_n|`, directed
         against the slip, i.e. with the sign of `P_t^NOSLIP` (= -sign(g.t)).
      5. Eq. (19): take the SLIP impulse when `|P_t^NOSLIP| > mu |P_n|`,
         else NOSLIP (the tangential impulse of smaller magnitude).
      6. `P = P_n n + P_t t` (eqs. 20-21); `c1* = c1 + P/m1`,
         `c2* = c2 - P/m2` (eq. 6); spins from eqs. (13)-(14).
    If the pair is not approaching (`g.n <= 0`) the inputs come back unchanged
    with `P = 0`. The lever arms are the radii: Q = x1 + r1 n, so the disks are
    assumed to touch (`|x2 - x1| = r1 + r2`).

    Args:
      m1, m2: `[]` masses (> 0; `inf` for a wall / fixed body).
      I1, I2: `[]` moments of inertia about the centres (> 0; a disk has
        `m r^2 / 2`; `inf` for a wall).
      r1, r2: `[]` radii (>= 0).
      x1, x2: `[2]` centres.
      c1, c2: `[2]` velocities before the collision.
      w1, w2: `[]` counter-clockwise spins before the collision.
      restitution: `[]` normal restitution coefficient epsilon in [0, 1] (eq. 4).
      mu: `[]` dynamic friction coefficient >= 0 (eq. 7).

    Returns:
      `CollisionResult` with `c1, c2` `[2]`, `w1, w2` `[]`, `impulse` `[2]`,
      `slipping` `[]` bool. Works in float32 and float64, under jit/vmap/grad.
    """
    x1, x2, c1, c2 = (jnp.asarray(a) for a in (x1, x2, c1, c2))
    n = _safe_unit(x2 - x1)
    t = jnp.stack([-n[1], n[0]])
    inv_m1, inv_m2 = 1.0 / m1, 1.0 / m2

    dc = c1 - c2
    gn = dc[0] * n[0] + dc[1] * n[1]                     # eq. (9) . n (spin terms are along t)
    gt = dc[0] * t[0] + dc[1] * t[1] + r1 * w1 + r2 * w2  # eq. (9) . t with eqs. (17)-(18)
    approaching = gn > 0

    pn = -(1.0 + restitution) * gn / (inv_m1 + inv_m2)   # eq. (12)
    k_t = inv_m1 + inv_m2 + r1 * r1 / I1 + r2 * r2 / I2
    pt_noslip = -gt / k_t                                # eqs. (15)-(16)
    pt_slip_mag = mu * jnp.abs(pn)                       # eq. (7), magnitude
    slipping = jnp.abs(pt_noslip) > pt_slip_mag          # eq. (19)
    pt = jnp.where(slipping, jnp.sign(pt_noslip) * pt_slip_mag, pt_noslip)

    pn = jnp.where(approaching, pn, jnp.zeros_like(pn))
    pt = jnp.where(approaching, pt, jnp.zeros_like(pt))
    p = pn * n + pt * t                                  # eqs. (20)-(21)

    return CollisionResult(
        c1=c1 + p * inv_m1,                              # eq. (6)
        c2=c2 - p * inv_m2,                              # eq. (6) / (10)
        w1=w1 + r1 * pt / I1,                            # eq. (13): -r_1 x P / I1
        w2=w2 + r2 * pt / I2,                            # eq. (14), sign-corrected form
        impulse=p,
        slipping=jnp.logical_and(approaching, slipping),
    )


def needs_soft_contact(v, force, mass, n, dt) -> Array:
    """Eq. (22): must the hard contact hand over to the soft (force) contact?

    `n` is the unit normal of the surface the particle touches, pointing from
    the surface to the particle ("up" in Fig. 2). The switch applies when the
    particle is not approaching the surface (`v.n >= 0`, so no impulsive
    collision is due), the resultant force pushes it into the surface
    (`F.n < 0`), and within one step that force would reverse its normal
    velocity, i.e. it would pass through the surface:

        dt > m |v.n| / |F.n|,   with v.n >= 0 and F.n < 0     (eq. 22)

    (equivalently `v.n + dt F.n / m < 0`). Evaluated as
    `dt |F.n| > m |v.n|`, so `v.n = 0` with `F.n < 0` gives True for any
    `dt > 0` (the resting-particle example of the paper), with no division.
    For disk 1 of a pair with `n_12` from 1 to 2, the surface normal is `-n_12`.

    Args:
      v: `[..., 2]` particle velocity (relative to the surface).
      force: `[..., 2]` resultant force on the particle.
      mass: `[...]` particle mass.
      n: `[..., 2]` unit surface normal, from the surface towards the particle.
      dt: `[]` time step.

    Returns:
      `[...]` bool, True where the soft treatment must take over.
    """
    v, force, n = jnp.asarray(v), jnp.asarray(force), jnp.asarray(n)
    vn = v[..., 0] * n[..., 0] + v[..., 1] * n[..., 1]
    fn = force[..., 0] * n[..., 0] + force[..., 1] * n[..., 1]
    return (vn >= 0) & (fn < 0) & (dt * jnp.abs(fn) > mass * jnp.abs(vn))


def check_collision_inputs(m1, m2, I1, I2, r1, r2, restitution, mu) -> None:
    """Host-side validation of concrete `collide` parameters (not for traced values).

    Raises:
      InputError: a mass or moment of inertia that is not > 0 (`inf` is allowed,
        for walls), a negative radius, restitution outside [0, 1], mu < 0, or NaN.
    """
    checks = (
        ("m1", m1, lambda a: a > 0, "> 0 (inf for a wall)"),
        ("m2", m2, lambda a: a > 0, "> 0 (inf for a wall)"),
        ("I1", I1, lambda a: a > 0, "> 0 (a disk has m r^2 / 2)"),
        ("I2", I2, lambda a: a > 0, "> 0 (a disk has m r^2 / 2)"),
        ("r1", r1, lambda a: a >= 0, ">= 0"),
        ("r2", r2, lambda a: a >= 0, ">= 0"),
        ("restitution", restitution, lambda a: (a >= 0) & (a <= 1), "in [0, 1]"),
        ("mu", mu, lambda a: (a >= 0) & np.isfinite(a), ">= 0 and finite"),
    )
    for name, value, ok, rule in checks:
        a = np.asarray(value, dtype=float)
        if not np.all(ok(a)):  # NaN fails every comparison
            raise InputError(f"{name} must be {rule}; got {value!r}.")


class HardCollisions(NamedTuple):
    """Settings of the hard-disk operator in the time stepper (Liffman et al.
    1992, sec. 2.1): restitution epsilon (eq. 4) and friction mu (eq. 7),
    the same for disk pairs and disk-wall pairs."""

    restitution: float = 0.5
    mu: float = 0.5

    def check(self) -> None:
        check_collision_inputs(1.0, 1.0, 1.0, 1.0, 0.5, 0.5, self.restitution, self.mu)


def hard_collision_velocities(particles, neighbor_idx, boundaries, dt, settings: HardCollisions,
                              rotation: bool):
    """Velocities and spins after the hard collisions due in the coming step.

    A pair (or a disk and a wall) collides hard when, all at once:
      * it is not in soft contact now (r >= r_i + r_j: a contact that is already
        soft stays soft until it opens),
      * it approaches, and moving ballistically it would touch within dt,
      * after the collision it would separate faster than the forces on the
        two can bring it back within dt. Otherwise eq. (22) holds for the
        post-collision motion (v.n >= 0 but dt |F.n| / m > |v.n|: the disk would
        be pushed through in one step) and the pair is left to the soft law.
        So a bouncing disk loses speed by epsilon per bounce, hard, until its
        rebound is slower than g dt, and then rests on the soft spring.
    The impulses of all colliding pairs are computed from the same
    pre-collision velocities and summed (a Jacobi sweep): exact for isolated
    binary collisions, the paper's situation; a disk hit by two partners in the
    same step gets both impulses at once. Walls are partners of infinite mass
    at the foot of the normal. With `rotation` off the spins are held (the
    disks collide as if their moment of inertia were infinite).

    Args:
      particles: `Particles` at the start of the step, `force` the total force.
      neighbor_idx: `[n, k]` neighbour slots (empty = n).
      boundaries: walls in force.
      dt: time step.
      settings: `HardCollisions`.
      rotation: whether spins take part.

    Returns:
      `(velocity [n, 2], angular_velocity [n], collided [n] bool)`.
    """
    p = particles
    n = p.count
    eps = jnp.asarray(settings.restitution, p.position.dtype)
    mu = jnp.asarray(settings.mu, p.position.dtype)
    inf = jnp.asarray(jnp.inf, p.position.dtype)
    mass = jnp.where(p.fixed, inf, p.mass)
    inertia = jnp.where(p.fixed | (not rotation), inf, p.inertia)
    accel = jnp.where(p.movable[:, None], p.force / p.mass[:, None], 0.0)
    omega = p.angular_velocity if rotation else jnp.zeros_like(p.angular_velocity)

    def one(m1, m2, i1, i2, r1, r2, x1, x2, c1, c2, w1, w2, a1, a2):
        d = x2 - x1
        gap_now = safe_norm(d) - (r1 + r2)
        touch = safe_norm(d + dt * (c2 - c1)) < r1 + r2  # ballistic over the step
        out = collide(m1, m2, i1, i2, r1, r2, x1, x2, c1, c2, w1, w2, eps, mu)
        # eq. (22) on the motion after the collision: disk 1 against the surface of
        # disk 2, whose normal points from 2 to 1 (-n), relative velocity and acceleration
        soft = needs_soft_contact(out.c1 - out.c2, a1 - a2, 1.0, -_safe_unit(d), dt)
        hard = (gap_now >= 0) & touch & (jnp.sum(out.impulse * out.impulse) > 0) & ~soft
        # the changes of disk 1's velocity (eq. 6) and spin (eq. 13) by this collision
        return jnp.where(hard, out.c1 - c1, 0.0), jnp.where(hard, out.w1 - w1, 0.0), hard

    valid = neighbor_idx < n
    j = jnp.where(valid, neighbor_idx, 0)
    both = valid & p.active[:, None] & p.active[j] & ~(p.fixed[:, None] & p.fixed[j]) & (j != jnp.arange(n)[:, None])
    per_slot = jax.vmap(jax.vmap(one, (None, 0, None, 0, None, 0, None, 0, None, 0, None, 0, None, 0)),
                        (0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0))
    dv, dw, hard = per_slot(mass, mass[j], inertia, inertia[j], p.radius, p.radius[j], p.position, p.position[j],
                            p.velocity, p.velocity[j], omega, omega[j], accel, accel[j])
    hard = hard & both

    # walls: the partner sits at the foot of the normal, at rest, infinitely heavy
    dist = wall_distance(boundaries, p.position)  # [n, w]
    foot = p.position[:, None, :] - dist[..., None] * boundaries.wall_normal[None]
    per_wall = jax.vmap(jax.vmap(one, (None, None, None, None, None, None, None, 0, None, None, None, None, None, None)),
                        (0, None, 0, None, 0, None, 0, 0, 0, None, 0, None, 0, None))
    zero = jnp.zeros((), p.position.dtype)
    w_dv, w_dw, w_hard = per_wall(mass, inf, inertia, inf, p.radius, zero, p.position, foot, p.velocity,
                                  jnp.zeros(2, p.position.dtype), omega, zero, accel, jnp.zeros(2, p.position.dtype))
    w_hard = w_hard & boundaries.wall_active[None, :] & p.movable[:, None]

    # impulses from the same pre-collision velocities, summed (Jacobi)
    movable = p.movable
    total_dv = jnp.where(hard[..., None], dv, 0.0).sum(1) + jnp.where(w_hard[..., None], w_dv, 0.0).sum(1)
    total_dw = jnp.where(hard, dw, 0.0).sum(1) + jnp.where(w_hard, w_dw, 0.0).sum(1)
    velocity = jnp.where(movable[:, None], p.velocity + total_dv, p.velocity)
    spin = p.angular_velocity
    if rotation:
        spin = jnp.where(movable, spin + total_dw, spin)
    collided = hard.any(1) | w_hard.any(1)
    return velocity, spin, collided
