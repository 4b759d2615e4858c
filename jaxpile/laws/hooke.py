"""Linear spring-dashpot with a Cundall-Strack tangential spring: LAMMPS
`pair_style gran/hooke/history` (and `fix wall/gran hooke/history`), for disks
and spheres (one kernel: in 3D the spins, torques and the shear spring are
vectors, and z x n below is w x n).

For a pair i, j with overlap delta = r_i + r_j - r, unit normal n = (x_i - x_j)/r,
relative velocity of the contact points v_tr (including spins), effective mass
m_eff = m_i m_j / (m_i + m_j) (m_i against a wall or a fixed disk):

  normal:      F_n = k_n delta - m_eff gamma_n (v . n)               (along n)
  shear:       s <- s + v_tr dt, then projected onto the tangent plane
  tangential:  F_t = -(k_t s + m_eff gamma_t v_tr)
  Coulomb:     if |F_t| > mu |F_n|: F_t <- F_t mu|F_n|/|F_t| and s is rescaled so
               that k_t s + m_eff gamma_t v_tr matches (LAMMPS semantics: the cap
               uses |F_n| including its damping part)
  torque on i: -r_i (n x F_t), on j: -r_j (n x F_t)

The shear displacement s is the per-pair history (a 2-vector, zeroed when the
pair separates). Walls and the ground use `wall_kn, wall_kt, wall_gamma_n,
wall_gamma_t, wall_mu`, each defaulting to the disk value when left `None`.

Rolling resistance (`law(rolling="sds" | "constant")`, `jaxpile.laws.rolling`):
a torque R_eff f_r on i and -R_eff f_r on j once F_n is known, with `k_roll,
gamma_roll, mu_roll` (`"sds"`, LAMMPS `rolling sds`) or `mu_roll` alone
(`"constant"`), carried as a third history entry; walls use the same values.

`law(pair_style="granular")` reads the spring as LAMMPS's `pair_style granular
hooke kn gamma_n damping mass_velocity tangential linear_history kt
gamma_t/gamma_n mu` (29Sep2021) does, which a LAMMPS run with rolling
resistance needs (only that style has it). It differs from the default
`"gran/hooke/history"` in two places: before the step's increment the spring is
turned into the tangent plane keeping its length (when |s . n| k_t > 1e-10 mu
|F_n|), s <- (s - (s . n) n) |s| / |s - (s . n) n|; and the torque arm is the
distance to the contact point, r_i - delta/2 on i and r_j - delta/2 on j (r_i
against a wall, `fix wall/gran granular`).

The 1992 static-pile analysis (Liffman, Chan & Hughes, eqs. 42 and 44) assumes
only normal forces between disks at rest: with this law, disk-disk `mu = 0`,
rotation off, and enough ground friction (`wall_mu`).
"""

from __future__ import annotations

import math
from typing import Any

import jax.numpy as jnp
from jaxpile._jax_md import dataclasses

from jaxpile.errors import InputError
from jaxpile.laws import rolling as rolling_
from jaxpile.laws import tangential, vec
from jaxpile.laws.base import (ContactLaw, PairForce, PairGeometry, contact_result, param_arrays, ranges_doc,
                               validate_ranges, with_set)
from jaxpile.ranges import NON_NEGATIVE, POSITIVE

Array = Any
NAME = "hooke"
WALL_NAMES = ("wall_kn", "wall_kt", "wall_gamma_n", "wall_gamma_t", "wall_mu")
PARAM_NAMES = ("kn", "kt", "gamma_n", "gamma_t", "mu") + WALL_NAMES + rolling_.PARAM_NAMES
RANGES = {**{name: POSITIVE if name in ("kn", "wall_kn") else NON_NEGATIVE for name in PARAM_NAMES[:10]},
          **rolling_.RANGES}
"""Each parameter's valid range (`jaxpile.ranges`): the normal stiffness > 0, the rest >= 0."""
OPTIONAL = WALL_NAMES + rolling_.PARAM_NAMES
"""The parameters that may be None (unset)."""


@with_set
@dataclasses.dataclass
class Params:
    """Parameters of the `hooke` law (names as LAMMPS).

    Attributes:
      kn: normal stiffness (force / length), in mg / sigma.
      kt: tangential stiffness.
      gamma_n: normal damping rate (1 / time); force = m_eff gamma_n v_n.
      gamma_t: tangential damping rate.
      mu: Coulomb friction coefficient.
      wall_kn, wall_kt, wall_gamma_n, wall_gamma_t, wall_mu: the same against the
        ground and walls; `None` means "same as the disk value" (and then a
        gradient with respect to the disk value flows into the walls too).
    """

    kn: Array
    kt: Array
    gamma_n: Array
    gamma_t: Array
    mu: Array
    wall_kn: Array = None
    wall_kt: Array = None
    wall_gamma_n: Array = None
    wall_gamma_t: Array = None
    wall_mu: Array = None
    k_roll: Array = None
    gamma_roll: Array = None
    mu_roll: Array = None


Params.__doc__ = (Params.__doc__ or "").rstrip() + "\n" + rolling_.DOC + ranges_doc(RANGES)


def make_params(kn=2.0e5, kt=None, gamma_n=50.0, gamma_t=None, mu=0.5, *, k_roll=None, gamma_roll=None,
                mu_roll=None, dtype=None, **wall) -> Params:
    """`hooke` parameters with LAMMPS's defaults for what is left out:
    kt = 2/7 kn and gamma_t = gamma_n / 2; `wall_*` default to the disk values;
    the rolling parameters stay None (unset) unless given."""
    unknown = set(wall) - set(WALL_NAMES)
    if unknown:
        raise InputError(f"unknown hooke parameter(s) {sorted(unknown)}; known: {list(PARAM_NAMES)}.")
    dtype = jnp.zeros(()).dtype if dtype is None else dtype
    # arrays (and refused if not numbers) before the defaults are computed from them
    kn, gamma_n = param_arrays(NAME, dict(kn=kn, gamma_n=gamma_n), RANGES, dtype).values()
    kt = 2.0 / 7.0 * kn if kt is None else kt
    gamma_t = 0.5 * gamma_n if gamma_t is None else gamma_t
    values = dict(kn=kn, kt=kt, gamma_n=gamma_n, gamma_t=gamma_t, mu=mu, **wall, k_roll=k_roll,
                  gamma_roll=gamma_roll, mu_roll=mu_roll)
    return Params(**param_arrays(NAME, values, RANGES, dtype, optional=OPTIONAL))


def wall_params(p: Params) -> Params:
    """The parameters used against walls: each `wall_*` or, if None, its disk
    value; the rolling parameters as they are."""
    pick = lambda w, d: d if w is None else w
    return Params(
        kn=pick(p.wall_kn, p.kn), kt=pick(p.wall_kt, p.kt), gamma_n=pick(p.wall_gamma_n, p.gamma_n),
        gamma_t=pick(p.wall_gamma_t, p.gamma_t), mu=pick(p.wall_mu, p.mu),
        k_roll=p.k_roll, gamma_roll=p.gamma_roll, mu_roll=p.mu_roll,
    )


def make_pair_force(rolling=None, pair_style: str = "gran/hooke/history"):
    """The kernel in one reading: `rolling` (None, `"sds"`, `"constant"`) and the
    tangential spring's `pair_style` (see the module docstring)."""
    granular = pair_style == "granular"

    def pair_force(p: Params, g: PairGeometry, shear: Array, dt) -> PairForce:
        """One pair's force, torque and new shear history (see the module docstring),
        for disks or spheres (`shear` then `[d]` plus the rolling entries).

        Written component by component (`jaxpile.laws.vec`: x, y [, z] scalars
        rather than vectors): vmapped over the slots every intermediate is then
        an `[n, k]` array, and XLA on CPU computes the shared scalars (r, F_n,
        the Coulomb ratio) once instead of once per vector component
        (measured: see benchmarks/profile_step.py)."""
        f = tangential.contact_frame(g)
        d = len(f.n)

        fn = p.kn * (f.radsum - f.r) - g.effective_mass * p.gamma_n * f.vn

        # the spring in this reading's frame (`jaxpile.laws.tangential`), capped at mu |F_n|
        ft, s = tangential.spring_vec(tuple(shear[k] for k in range(d)), f.n, f.vt, p.kt,
                                      g.effective_mass * p.gamma_t, p.mu * jnp.abs(fn), dt, granular)

        force = tuple(fn * nk + fk for nk, fk in zip(f.n, ft))
        n_cross_ft = vec.cross(f.n, ft)
        if granular:  # the arm to the contact point (pair granular); a wall's is r_i (fix wall/gran granular)
            half_overlap = 0.5 * (f.radsum - f.r)
            torque = vec.scale(-jnp.where(g.radius_j > 0, g.radius_i - half_overlap, g.radius_i), n_cross_ft)
            torque_j = vec.scale(-(g.radius_j - half_overlap), n_cross_ft)
        else:
            torque = vec.scale(-g.radius_i, n_cross_ft)
            torque_j = vec.scale(-g.radius_j, n_cross_ft)  # (r_j n) x (-F_t)
        history = list(s)
        if rolling is not None:
            roll_i, roll_j, carried = rolling_.resist(rolling, p, fn, g.radius_i, g.radius_j, g.angular_velocity_i,
                                                      g.angular_velocity_j, g.effective_mass,
                                                      shear[d] if d == 2 else shear[d:d + 3], dt, f.n)
            torque = vec.pack(torque) + roll_i
            torque_j = vec.pack(torque_j) + roll_j
            history.extend(vec.components(carried) if d == 3 else [carried])
        return contact_result(f.in_contact, jnp.stack(force), vec.pack(torque), jnp.stack(history), fn,
                              vec.pack(torque_j))

    return pair_force


PAIR_STYLES = ("gran/hooke/history", "granular")
ROLLING = (None,) + rolling_.MODES
# one kernel object per reading, so that laws built with the same options are
# equal (hashable alike) and a jit that closes over them compiles once
_KERNELS = {(mode, style): make_pair_force(mode, style) for mode in ROLLING for style in PAIR_STYLES}
pair_force = _KERNELS[None, "gran/hooke/history"]


def interaction_range(p: Params, radius_i, radius_j) -> float:
    """Disks interact when they overlap."""
    return radius_i + radius_j


def stable_time_step(p: Params, min_mass: float, min_radius: float = 0.5) -> float:
    """Estimate of the largest stable velocity-Verlet step.

    The highest vibration frequency of a close-packed 2D lattice of springs k is
    omega^2 = 6 k / m (hexagonal lattice, M point); we take 8 k / m to cover a
    disk that also touches a wall. Damping adds the explicit-damping limit
    gamma dt < 2 with gamma summed over about four contacts. A rolling spring
    and dashpot, where set, count as one more stiffness and damping rate
    (`rolling.time_step_limits`).
    """
    w = wall_params(p)
    k_roll, gamma_roll = rolling_.time_step_limits(p)
    k = max(float(p.kn), float(p.kt), float(w.kn), float(w.kt), k_roll)
    gamma = max(float(p.gamma_n), float(p.gamma_t), float(w.gamma_n), float(w.gamma_t), gamma_roll / min_mass)
    omega = math.sqrt(8.0 * k / min_mass)
    limits = [2.0 / omega if omega > 0 else math.inf]  # a stiffness so small it underflows has no limit
    if gamma > 0:
        limits.append(2.0 / (4.0 * gamma))
    return min(limits)


def validate(p: Params) -> None:
    """Raises `InputError` on a negative or non-finite parameter, or a non-positive stiffness."""
    validate_ranges(NAME, p, RANGES)


_VALIDATORS = rolling_.validators(NAME, validate)


def law(rotation: bool = True, rolling: str | None = None, pair_style: str = "gran/hooke/history") -> ContactLaw:
    """The `hooke` law.

    Args:
      rotation: False freezes angular degrees of freedom.
      rolling: None (default), `"sds"` or `"constant"`: rolling resistance
        (`jaxpile.laws.rolling`); `"sds"` adds one history entry.
      pair_style: the tangential spring's reading, `"gran/hooke/history"`
        (default) or `"granular"` (LAMMPS `pair_style granular`; see the module
        docstring).

    Options other than the defaults are recorded in `ContactLaw.options` (and so
    in checkpoints); the defaults are not, so a run without them is recorded as
    before they existed.
    """
    rolling_.check_mode(NAME, rolling, rotation)
    if pair_style not in PAIR_STYLES:
        raise InputError(f"unknown pair_style {pair_style!r} for {NAME}; choose one of {list(PAIR_STYLES)}.")
    options = (() if rolling is None else (("rolling", rolling),)) + \
        (() if pair_style == PAIR_STYLES[0] else (("pair_style", pair_style),))
    return ContactLaw(
        name=NAME,
        history_size=2 + rolling_.HISTORY[rolling],
        rotation=bool(rotation),
        pair_force=_KERNELS[rolling, pair_style],
        wall_params=wall_params,
        interaction_range=interaction_range,
        stable_time_step=stable_time_step,
        validate=_VALIDATORS[rolling],
        params_type=Params,
        options=options,
        history_size_3d=3 + rolling_.HISTORY_3D[rolling],
    )
