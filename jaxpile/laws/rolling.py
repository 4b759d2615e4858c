"""Rolling resistance any law can carry: pure per-pair kernels, called by a law's
`pair_force` once its normal force F_n is known (`hooke`, `lee_herrmann`,
`baxter` take them with `law(rolling=...)`).

Geometry and signs (2D): n = (x_i - x_j) / |x_i - x_j|, t = z x n
(`laws.base.perp`), spins counter-clockwise positive, R_eff = r_i r_j / (r_i +
r_j) between disks and R_eff = r_i against a wall (a partner of zero radius,
for which the formula would give 0; LAMMPS's `fix wall/gran` takes r_i for a
flat wall, `rwall = 0`).

Relative rolling velocity. LAMMPS (`src/GRANULAR/pair_granular.cpp`, 29Sep2021,
after Wang et al., Particuology 23, 49 (2015), eq. 31) uses, in 3D,
v_roll = R_eff (omega_i - omega_j) x n; with omega = omega z and z x n = t,

  v_roll = R_eff (omega_i - omega_j) t,                                 (1)

of which we carry the scalar v_r = R_eff (omega_i - omega_j).

`"sds"`: LAMMPS `rolling sds k_roll gamma_roll mu_roll` (type C of Ai et al.,
Powder Technol. 206, 269 (2011): a spring-dashpot-slider on the relative
rolling displacement psi). LAMMPS keeps psi as a 3-vector turned into the
current tangent plane keeping its length; in 2D that is the same scalar along
the new t, so psi is one history entry:

  psi <- psi + v_r dt
  f_r = -k_roll psi - gamma_roll v_r                                    (2)
  if |f_r| > mu_roll |F_n|:  f_r <- mu_roll |F_n| f_r / |f_r|,
                             psi <- -(f_r + gamma_roll v_r) / k_roll    (3)
                             (as LAMMPS: when psi = 0 there, f_r = 0)
  torque on i: R_eff n x (f_r t) = R_eff f_r;  on j: -R_eff f_r          (4)

|F_n| is the whole normal force, damping included (LAMMPS's `Fncrit`), so the
torque is capped at mu_roll |F_n| R_eff; gamma_roll is a force per velocity,
not scaled by the mass.

`"constant"`: the constant torque of Zhou et al., Physica A 269, 536 (1999)
(type A of Ai et al. 2011), M = -mu_roll R_eff |F_n| sign(omega_i - omega_j) on
i while the pair rolls (the pair's R_eff as the arm, not Zhou's own radius, so
the two torques cancel and the pair conserves angular momentum). An explicit
step cannot integrate the sign as such (the pile chatters) nor a smooth tanh
(the pile creeps) (docs/rolling_resistance.md#the-constant-torque-at-rest), so
the sign is regularised by a stiff slider: eqs. 2-4 with

  k = STIFFNESS m_eff / dt^2,  gamma = 2 DAMPING_RATIO sqrt(k m_eff),     (5)

stable for a relative rotation of omega dt <= ~0.3 (STIFFNESS = 0.05), damped
at 30% of critical. While the pair rolls the torque is exactly mu_roll R_eff
|F_n| against it; below the cap the spring holds the pair with a rolling
displacement of at most mu_roll |F_n| dt^2 / (0.05 m_eff), which vanishes as
dt -> 0 (the set-valued sign of rigid rolling friction). The history holds the
spring's force f_e, not the displacement, so a force evaluated without a step
(dt = 0: the start, the measurements) still gives the torque the spring holds:

  f_e <- f_e - k v_r dt,  f_r = f_e - gamma v_r,
  if |f_r| > mu_roll |F_n|:  f_r <- mu_roll |F_n| f_r / |f_r|,  f_e <- f_r + gamma v_r.   (6)
"""

from __future__ import annotations

from typing import Any

import jax.numpy as jnp

from jaxpile.errors import InputError
from jaxpile.ranges import NON_NEGATIVE

Array = Any

MODES = ("sds", "constant")
"""The rolling-resistance models (`law(rolling=...)`; None: no rolling resistance)."""

PARAM_NAMES = ("k_roll", "gamma_roll", "mu_roll")
RANGES = {"k_roll": NON_NEGATIVE, "gamma_roll": NON_NEGATIVE, "mu_roll": NON_NEGATIVE}
"""Each rolling parameter's range: k_roll (force / length), gamma_roll (force /
velocity) and mu_roll (dimensionless), all >= 0."""

NEEDS = {"sds": ("k_roll", "mu_roll"), "constant": ("mu_roll",)}
"""The parameters each model cannot do without (`"sds"`'s gamma_roll left None is 0)."""

UNUSED = {"sds": (), "constant": ("k_roll", "gamma_roll")}
"""The parameters a model refuses when set (`"constant"` sets its spring from dt)."""

HISTORY = {None: 0, "sds": 1, "constant": 1}
"""History entries each model adds after the law's own: psi (`"sds"`), f_e (`"constant"`)."""

STIFFNESS = 0.05
"""`"constant"`: its slider's spring is STIFFNESS m_eff / dt^2 (eq. 5)."""

DAMPING_RATIO = 0.3
"""`"constant"`: its slider's dashpot, as a fraction of critical (eq. 5)."""

DOC = """      k_roll, gamma_roll, mu_roll: rolling resistance with `law(rolling="sds")`
        (LAMMPS `rolling sds`): the spring (force / length) on the relative
        rolling displacement, its dashpot (force / velocity, not mass-scaled)
        and the torque cap mu_roll |F_n| R_eff; `rolling="constant"` takes
        mu_roll alone; None (the default) where the law has no rolling
        resistance. See `jaxpile.laws.rolling`."""


def check_mode(law_name: str, rolling, rotation: bool) -> None:
    """Raises `InputError` on an unknown model, or rolling resistance on disks that do not rotate."""
    if rolling is not None and rolling not in MODES:
        raise InputError(f"unknown rolling model {rolling!r} for {law_name}; choose one of {list(MODES)} or None.")
    if rolling is not None and not rotation:
        raise InputError(f"rolling={rolling!r} for {law_name} needs rotation=True: rolling resistance acts on spins.")


def validators(law_name: str, validate_law) -> dict:
    """`{model: validate}` for a law: its own `validate_law` followed by what the
    model needs and refuses (`validate`; no model refuses every rolling parameter).
    One function per model, so equal laws hash alike (a jit closing over them compiles once)."""

    def with_model(model):
        def check(p) -> None:
            validate_law(p)
            validate(law_name, p, model)
        return check

    return {model: with_model(model) for model in (None, *MODES)}


def validate(law_name: str, params, rolling) -> None:
    """Raises `InputError` when a parameter `rolling` needs is None, or one it
    does not use is set (without a model, every rolling parameter: set, it would
    act on nothing)."""
    if rolling is None:
        for name in PARAM_NAMES:
            if getattr(params, name, None) is not None:
                raise InputError(f"{law_name} parameter {name} is set, but the law has no rolling resistance, so it "
                                 "would act on nothing: choose a model (rolling='sds' or 'constant'; the command's "
                                 "--rolling) or leave it unset.")
        return
    for name in NEEDS[rolling]:
        if getattr(params, name) is None:
            raise InputError(f"{law_name} parameter {name} must be set for rolling={rolling!r} "
                             f"({RANGES[name].describe()}).")
    for name in UNUSED[rolling]:
        if getattr(params, name) is not None:
            raise InputError(f"{law_name} parameter {name} is not used by rolling={rolling!r} "
                             "(its spring is set from the time step); leave it unset.")


def effective_radius(radius_i, radius_j):
    """R_eff = r_i r_j / (r_i + r_j), and r_i against a wall (r_j = 0), as LAMMPS's
    `fix wall/gran` for a flat wall."""
    total = radius_i + radius_j
    wall = radius_j <= 0
    return jnp.where(wall, radius_i, radius_i * radius_j / jnp.where(wall, 1.0, total))


def sds(k_roll, gamma_roll, mu_roll, normal, r_eff, omega_i, omega_j, psi, dt):
    """Eqs. 1-4: the spring-dashpot-slider. Returns (f_r, new psi); the torque
    on i is r_eff * f_r, on j its negative.

    Args:
      k_roll, gamma_roll, mu_roll: the parameters (gamma_roll None: 0).
      normal: F_n (its magnitude caps the torque).
      r_eff: `effective_radius`.
      omega_i, omega_j: the spins.
      psi: the rolling displacement carried from the last step (along t).
      dt: the time step (0: evaluate without advancing psi's increment).
    """
    v_r = r_eff * (omega_i - omega_j)  # (1)
    psi = psi + v_r * dt
    damping = 0.0 if gamma_roll is None else gamma_roll
    f_r = -(k_roll * psi + damping * v_r)  # (2)
    cap = mu_roll * jnp.abs(normal)
    # (3): f_r is a number along t, so rescaling it to length cap is clipping it (no division
    # per pair: this kernel is evaluated for every contact at every step)
    capped = jnp.clip(f_r, -cap, cap)
    sliding = capped != f_r
    moved = psi != 0
    has_k = k_roll > 0
    inv_k = jnp.where(has_k, 1.0 / jnp.where(has_k, k_roll, 1.0), 0.0)
    psi = jnp.where(sliding & moved, -(capped + damping * v_r) * inv_k, psi)
    f_r = jnp.where(sliding & ~moved, 0.0, capped)
    return f_r, psi


def constant(mu_roll, normal, r_eff, effective_mass, omega_i, omega_j, f_e, dt):
    """Eqs. 5-6: the constant torque, its sign regularised by a stiff slider.
    Returns (f_r, new f_e); the torque on i is r_eff * f_r."""
    v_r = r_eff * (omega_i - omega_j)  # (1)
    stepping = dt > 0
    inv_dt = jnp.where(stepping, 1.0 / jnp.where(stepping, dt, 1.0), 0.0)
    k_dt = STIFFNESS * effective_mass * inv_dt  # k dt, 0 without a step
    damping = 2.0 * DAMPING_RATIO * effective_mass * (STIFFNESS ** 0.5) * inv_dt  # 2 zeta sqrt(k m_eff)
    f_e = f_e - k_dt * v_r
    f_r = f_e - damping * v_r
    cap = mu_roll * jnp.abs(normal)
    capped = jnp.clip(f_r, -cap, cap)  # the slider (as in `sds`)
    f_e = jnp.where(capped != f_r, capped + damping * v_r, f_e)
    return capped, f_e


def resist(rolling, params, normal, radius_i, radius_j, omega_i, omega_j, effective_mass, carried, dt, n=None):
    """The rolling model `rolling` of one pair: (torque on i, torque on j, new
    history entry); `carried` is the entry from the last step (psi for `"sds"`,
    f_e for `"constant"`). Disks' spins are numbers and these are eqs. 1-6;
    spheres' spins are `[3]` (then `n`, the unit normal as a tuple, is needed)
    and the history a `[3]` vector (`resist_3d`)."""
    r_eff = effective_radius(radius_i, radius_j)
    if n is not None and len(n) == 3:  # spheres
        return resist_3d(rolling, params, normal, r_eff, omega_i, omega_j, effective_mass, carried, dt, n)
    if rolling == "sds":
        f_r, carried = sds(params.k_roll, params.gamma_roll, params.mu_roll, normal, r_eff, omega_i, omega_j,
                           carried, dt)
    else:
        f_r, carried = constant(params.mu_roll, normal, r_eff, effective_mass, omega_i, omega_j, carried, dt)
    torque = r_eff * f_r  # (4)
    return torque, -torque, carried


def resist_3d(rolling, params, normal, r_eff, omega_i, omega_j, effective_mass, carried, dt, n: tuple):
    """Spheres: eqs. 1-6 with vectors, as LAMMPS `pair granular` (29Sep2021)
    has `rolling sds` in 3D. v_roll = R_eff (omega_i - omega_j) x n; the
    history vector (psi, or f_e for `"constant"`) is first turned into the
    current tangent plane keeping its length (when |h . n| k > 1e-10 times the
    cap, `tangential.turned`), then advanced; the cap rescales the vector
    f_r to length mu_roll |F_n| (psi then so that k psi + gamma v_roll stays on
    it; with psi = 0 there, f_r = 0); the torque on i is R_eff n x f_r, on j
    its negative. Returns (torque on i, on j, new history), each `[3]`."""
    from jaxpile.laws import tangential, vec

    relative = tuple(a - b for a, b in zip(vec.components(omega_i), vec.components(omega_j)))
    v_roll = vec.scale(r_eff, vec.cross(relative, n))  # (1)
    history = vec.components(carried)
    cap = mu_roll_cap = params.mu_roll * jnp.abs(normal)
    if rolling == "sds":
        k = params.k_roll
        damping = 0.0 if params.gamma_roll is None else params.gamma_roll
        history = tangential.turned(history, n, lambda hn: jnp.abs(hn) * k > tangential.FRAME_EPSILON * cap)
        history = tuple(h + v * dt for h, v in zip(history, v_roll))
        f_r = tuple(-(k * h + damping * v) for h, v in zip(history, v_roll))  # (2)
        moved = vec.dot(history, history) > 0
        has_k = k > 0
        inv_k = jnp.where(has_k, 1.0 / jnp.where(has_k, k, 1.0), 0.0)
    else:  # "constant": the stiff slider of eq. 5 on the spring's force f_e (eq. 6)
        stepping = dt > 0
        inv_dt = jnp.where(stepping, 1.0 / jnp.where(stepping, dt, 1.0), 0.0)
        k_dt = STIFFNESS * effective_mass * inv_dt
        damping = 2.0 * DAMPING_RATIO * effective_mass * (STIFFNESS ** 0.5) * inv_dt
        history = tangential.turned(history, n, lambda hn: jnp.abs(hn) > tangential.FRAME_EPSILON * cap)
        history = tuple(h - k_dt * v for h, v in zip(history, v_roll))
        f_r = tuple(h - damping * v for h, v in zip(history, v_roll))
    size2 = vec.dot(f_r, f_r)
    sliding = size2 > mu_roll_cap * mu_roll_cap  # (3)
    ratio = jnp.where(sliding, cap / jnp.where(sliding, jnp.sqrt(jnp.where(sliding, size2, 1.0)), 1.0), 1.0)
    capped = tuple(ratio * f for f in f_r)
    if rolling == "sds":
        history = tuple(jnp.where(sliding & moved, -(c + damping * v) * inv_k, h)
                        for c, v, h in zip(capped, v_roll, history))
        capped = tuple(jnp.where(sliding & ~moved, 0.0, c) for c in capped)
    else:
        history = tuple(jnp.where(sliding, c + damping * v, h) for c, v, h in zip(capped, v_roll, history))
    torque = jnp.stack(vec.scale(r_eff, vec.cross(n, capped)))  # (4)
    return torque, -torque, jnp.stack(history)


HISTORY_3D = {None: 0, "sds": 3, "constant": 3}
"""For spheres: the history vector each model adds after the law's own."""


def time_step_limits(params) -> tuple[float, float]:
    """(k_roll, 2 gamma_roll), each 0 where unset: what the rolling resistance
    adds to a law's stable step estimate, a stiffness and a damping rate times
    the mass (divide by the smallest mass). A disk (I = m r^2 / 2) on a wall
    (R_eff = r) turns in the rolling spring at omega^2 = k_roll R_eff^2 / I =
    2 k_roll / m, a quarter of what the laws' lattice factor 8 k / m allows a
    spring k, so k_roll enters their estimate as a stiffness beside k_n and k_t;
    its dashpot damps the spin at gamma_roll R_eff^2 / I = 2 gamma_roll / m."""
    k = 0.0 if params.k_roll is None else float(params.k_roll)
    damping = 0.0 if params.gamma_roll is None else 2.0 * float(params.gamma_roll)
    return k, damping
