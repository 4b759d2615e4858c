"""LAMMPS `pair_style granular` (29Sep2021) in 2D: a contact law composed of a
normal, a damping, a tangential and a rolling sub-model, each chosen by name
as in a `pair_coeff` line (`parse` reads one).

For a pair i, j with overlap delta = r_i + r_j - r, unit normal n = (x_i -
x_j)/r, R = r_i r_j / (r_i + r_j) (r_i against a wall), contact radius
a = sqrt(R delta), effective mass m_eff = m_i m_j / (m_i + m_j) (m_i against a
wall or a fixed disk), normal velocity v_n = (v_i - v_j) . n and the contact
points' relative velocity v_tr (spins included):

Normal, F_ne = k delta with                                        (N1-N3)

  hooke kn:              k = kn
  hertz kn:              k = kn a
  hertz/material E nu:   k = 4/3 E_eff a,  E_eff = E / (2 (1 - nu^2))

(Hertz 1882: F = 4/3 E_eff sqrt(R) delta^(3/2); E_eff of two like materials.)

With cohesion (the surface energy w, `cohesion`):                 (N4-N5)

  dmt E nu w:   F_ne = 4/3 E_eff a delta - 4 pi w R  (Derjaguin, Muller &
      Toporov 1975), in contact while delta > 0;
  jkr E nu w:   F_ne = 4/3 E_eff a^3 / R - 2 pi a^2 sqrt(4 w E_eff / (pi a))
      (Johnson, Kendall & Roberts 1971), a from delta = a^2 / R - 2 sqrt(pi w
      a / E_eff) (LAMMPS's closed-form root). A contact made at delta = 0
      (F_ne = -8/9 F_pulloff there) holds, a history entry remembering the
      touch, until delta falls to the pull-off overlap a0^2 / R - 2 sqrt(pi
      w a0 / E_eff) < 0, a0 = (9 pi w R^2 / (4 E_eff))^(1/3), where F_ne =
      -F_pulloff = -3 pi w R (JKR's 3/2 pi w' R, the work of adhesion w' =
      2 w).

Damping, F_n = F_ne - eta_n v_n with                               (D1-D4)

  velocity gamma_n:          eta_n = gamma_n
  mass_velocity gamma_n:     eta_n = gamma_n m_eff
  viscoelastic gamma_n:      eta_n = gamma_n a m_eff   (LAMMPS's default)
  tsuji e:                   eta_n = alpha(e) sqrt(m_eff k),
      alpha(e) = 1.2728 - 4.2783 e + 11.087 e^2 - 22.348 e^3 + 27.467 e^4
                 - 18.022 e^5 + 4.8218 e^6   (Tsuji, Tanaka & Ishida 1992)
      with m_eff as LAMMPS has it, so a head-on Hertzian contact rebounds
      faster than e; the polynomial gives e itself with the mass 2 m_eff
      (docs/lammps.md#the-traps).

Tangential, capped at mu F_crit (`jaxpile.laws.tangential`), F_crit = |F_n|,
or |F_ne + 2 F_pulloff| with cohesion (F_pulloff = 3 pi w R for jkr, 4 pi w R
for dmt: W3 below), damped with eta_t = xgamma_t eta_n (LAMMPS's tangential
damping is a ratio):                                               (T1-T5)

  linear_nohistory xgamma_t mu:   F_t = -eta_t v_tr
  linear_history kt xgamma_t mu:  F_t = -(kt s + eta_t v_tr)
  mindlin kt xgamma_t mu:         F_t = -(kt a s + eta_t v_tr); kt NULL
      (None) is 8 G_eff, G_eff = E / (4 (2 - nu)(1 + nu)) (Mindlin 1949)
  mindlin_rescale:                as mindlin, and s scaled by a / a_last when
      the contact radius shrinks (unloading: Walton & Braun 1986), a_last a
      history entry
  mindlin/force, mindlin_rescale/force: the history carries the elastic
      force f instead, turned as s is and incremented f <- f - kt a v_tr dt;
      F_t = f - eta_t v_tr (Thornton et al. 2013, eq. 18)

with the shear displacement s turned into the tangent plane keeping its
length, then s <- s + v_tr dt (`pair_style granular`'s frame). The torque on i
is -(r_i - delta/2) n x F_t, on j -(r_j - delta/2) n x F_t (the arm to the
contact point); against a wall r_i.

Rolling: `rolling sds k_roll gamma_roll mu_roll` (`jaxpile.laws.rolling`),
capped at mu_roll F_crit; or jaxpile's `constant`. `limit_damping` (a keyword
of the line): a normal force the damping would make attractive is zero
instead (not with dmt or jkr, as in LAMMPS).

Walls (`fix wall/gran granular` with the same model) are partners of zero
radius and infinite mass. LAMMPS's wall differs from its pair in three
formulas: E_eff = E / (2 (1 - nu)) for the material models (W1); the mindlin
models' kt NULL is E (2 - nu)(1 + nu) / 4 (W2); and jkr's pull-off is computed
with r_i where R^2 belongs and added to the reach, so that a touching wall
contact holds to r_i + a0^2 (1 / r_i - 4 / (3 sqrt(r_i))), a0 = (9 pi w r_i /
(4 E_eff))^(1/3) (W4, `wall_pulloff_overlap`). `law(..., walls="lammps")`, the
default, does as LAMMPS does, so that a LAMMPS input is reproduced;
`walls="pair"` takes the pair's formulas at R = r_i, as LAMMPS's manual
describes the wall (docs/lammps.md#the-traps).

dmt's F_crit (W3): jaxpile takes LAMMPS's manual's |F_ne + 2 F_pulloff|;
LAMMPS's `pair_style granular` computes dmt's F_pulloff from a variable it
sets only for jkr, which leaves its dmt friction cap undefined, so dmt is
twinned without friction (docs/lammps.md#the-traps).

A `pair_coeff` line is also a law's name: `jaxpile.laws.get_law_module` takes
its text where it takes `hooke` and gives a `Composition`, a law module whose
parameters default to the line's coefficients (`--law "hertz/material 1e7 0.3
0.3 damping tsuji tangential mindlin NULL 1.0 0.5"` on the command line).
Not in this module: twisting (a 3D torque), and LAMMPS's per-type coefficients
and `cutoff` (one material here).
"""

from __future__ import annotations

import dataclasses as std_dataclasses
import functools
import math
from typing import Any, NamedTuple

import jax.numpy as jnp
from jaxpile._jax_md import dataclasses

from jaxpile.errors import InputError
from jaxpile.laws import rolling as rolling_
from jaxpile.laws import tangential
from jaxpile.laws.base import (ContactLaw, PairForce, PairGeometry, contact_result, param_arrays, ranges_doc,
                               safe_sqrt, validate_ranges, with_set)
from jaxpile.ranges import NON_NEGATIVE, POSITIVE, Range

Array = Any
NAME = "granular"

NORMAL = ("hooke", "hertz", "hertz/material", "dmt", "jkr")
MATERIAL = ("hertz/material", "dmt", "jkr")
"""The normal models given by E and nu (mindlin's kt NULL needs one)."""
COHESIVE = ("dmt", "jkr")
DAMPING = ("velocity", "mass_velocity", "viscoelastic", "tsuji")
TANGENTIAL = ("linear_nohistory", "linear_history", "mindlin", "mindlin_rescale", "mindlin/force",
              "mindlin_rescale/force")
MINDLIN = TANGENTIAL[2:]
"""The tangential models whose stiffness is kt a (kt NULL: 8 G_eff)."""
ROLLING = (None,) + rolling_.MODES

PARAM_NAMES = ("kn", "E", "nu", "cohesion", "gamma_n", "restitution", "kt", "xgamma_t", "mu") + rolling_.PARAM_NAMES
RANGES = {"kn": POSITIVE, "E": POSITIVE,
          "nu": Range(low=-1, low_open=True, high=0.5, why="a Poisson's ratio"),
          "cohesion": NON_NEGATIVE, "gamma_n": NON_NEGATIVE,
          "restitution": Range(low=0, high=1, why="a coefficient of restitution"),
          "kt": NON_NEGATIVE, "xgamma_t": NON_NEGATIVE, "mu": NON_NEGATIVE, **rolling_.RANGES}
"""Each parameter's valid range (`jaxpile.ranges`)."""

TSUJI = (1.2728, -4.2783, 11.087, -22.348, 27.467, -18.022, 4.8218)
"""Tsuji, Tanaka & Ishida (1992)'s polynomial alpha(e), lowest order first, as LAMMPS has it."""

TYPICAL_OVERLAP = 0.02
"""The overlap, over the smallest radius, at which `stable_time_step` takes a
Hertzian contact's stiffness (it stiffens as it is pressed)."""


class Model(NamedTuple):
    """The sub-models of a `granular` law, LAMMPS's names (`parse` reads them
    from a `pair_coeff` line)."""

    normal: str = "hooke"
    damping: str = "viscoelastic"
    tangential: str = "linear_history"
    rolling: str | None = None
    limit_damping: bool = False

    def check(self) -> None:
        for kind, value, known in (("normal", self.normal, NORMAL), ("damping", self.damping, DAMPING),
                                   ("tangential", self.tangential, TANGENTIAL), ("rolling", self.rolling, ROLLING)):
            if value not in known:
                raise InputError(f"unknown {kind} model {value!r} for {NAME}; choose one of "
                                 f"{[k for k in known if k is not None]}.")
        if self.limit_damping and self.normal in COHESIVE:
            raise InputError(f"limit_damping cannot be used with {self.normal} (its force is attractive by design; "
                             "LAMMPS refuses it too).")

    def needs(self) -> tuple[str, ...]:
        """The parameters this composition reads (kt is optional for the mindlin models)."""
        normal = {"hertz/material": ("E", "nu"), "dmt": ("E", "nu", "cohesion"),
                  "jkr": ("E", "nu", "cohesion")}.get(self.normal, ("kn",))
        damping = ("restitution",) if self.damping == "tsuji" else ("gamma_n",)
        tangent = {"linear_nohistory": ("xgamma_t", "mu"), "linear_history": ("kt", "xgamma_t", "mu")}.get(
            self.tangential, ("xgamma_t", "mu"))
        return normal + damping + tangent + (() if self.rolling is None else
                                             rolling_.PARAM_NAMES if self.rolling == "sds" else ("mu_roll",))

    def reads(self) -> tuple[str, ...]:
        """Every parameter this composition reads: `needs`, and the mindlin models' optional kt."""
        return self.needs() + (("kt",) if self.tangential in MINDLIN else ())

    def history_layout(self) -> dict[str, int]:
        """Where each history entry sits: the shear spring's two components,
        then mindlin_rescale's last contact radius, the rolling entry, and
        jkr's touch flag, each only where the model has it."""
        names = ["sx", "sy"]
        names += ["a_last"] if self.tangential.startswith("mindlin_rescale") else []
        names += ["rolling"] if self.rolling is not None else []
        names += ["touched"] if self.normal == "jkr" else []
        return {name: k for k, name in enumerate(names)}


@with_set
@dataclasses.dataclass
class Params:
    """Parameters of a `granular` law (LAMMPS's meanings; what a composition
    does not read stays None).

    Attributes:
      kn: normal stiffness of `hooke` (force / length) and `hertz` (force /
        length^2).
      E, nu: Young's modulus and Poisson's ratio of `hertz/material`, `dmt`
        and `jkr` (and of the mindlin models' default kt).
      cohesion: `dmt`'s and `jkr`'s surface energy w (energy / length^2).
      gamma_n: the normal damping of `velocity`, `mass_velocity`,
        `viscoelastic`; restitution: `tsuji`'s coefficient of restitution e.
      kt: the tangential stiffness (`linear_history`: force / length;
        `mindlin`: times a; None there: 8 G_eff).
      xgamma_t: the tangential damping over the normal damping eta_n.
      mu: Coulomb friction coefficient.
    """

    kn: Array = None
    E: Array = None
    nu: Array = None
    cohesion: Array = None
    gamma_n: Array = None
    restitution: Array = None
    kt: Array = None
    xgamma_t: Array = None
    mu: Array = None
    k_roll: Array = None
    gamma_roll: Array = None
    mu_roll: Array = None


Params.__doc__ = (Params.__doc__ or "").rstrip() + "\n" + rolling_.DOC + ranges_doc(RANGES)


def make_params(model: Model = Model(), *, dtype=None, **values) -> Params:
    """`granular` parameters for `model`: every parameter it reads given
    (mindlin's kt may be left out: 8 G_eff), none it does not read."""
    model.check()
    unknown = sorted(set(values) - set(PARAM_NAMES))
    if unknown:
        raise InputError(f"unknown {NAME} parameter(s) {unknown}; known: {list(PARAM_NAMES)}.")
    needs = model.needs()
    missing = [n for n in needs if values.get(n) is None]
    if missing:
        raise InputError(f"the {NAME} model {describe(model)} needs {', '.join(missing)}.")
    unread = sorted(n for n, v in values.items() if v is not None and n not in model.reads())
    if unread:
        raise InputError(f"the {NAME} model {describe(model)} does not read {', '.join(unread)}.")
    if model.tangential in MINDLIN and values.get("kt") is None and model.normal not in MATERIAL:
        raise InputError(f"{model.tangential}'s kt NULL is 8 G_eff from E and nu, which only {', '.join(MATERIAL)} "
                         "give: give kt.")
    dtype = jnp.zeros(()).dtype if dtype is None else dtype
    params = Params(**param_arrays(NAME, values, RANGES, dtype, optional=PARAM_NAMES))
    validate_ranges(NAME, params, RANGES)
    return params


def alpha(e):
    """Tsuji et al.'s damping ratio alpha(e) (eq. D4), Horner's rule."""
    out = TSUJI[-1]
    for c in TSUJI[-2::-1]:
        out = out * e + c
    return out


def effective_modulus(p: Params):
    """E_eff = E / (2 (1 - nu^2)): two like materials (eq. N3)."""
    return p.E / (2.0 * (1.0 - p.nu * p.nu))


def wall_modulus(p: Params):
    """E_eff against a wall as LAMMPS 29Sep2021's `fix wall/gran granular`
    computes it, E / (2 (1 - nu)) (eq. W1; measured against `lmp`: not eq.
    N3's E / (2 (1 - nu^2)), which two like materials give)."""
    return p.E / (2.0 * (1.0 - p.nu))


def wall_pulloff_overlap(e_eff, cohesion, radius):
    """How far beyond contact a touching jkr wall contact holds, as LAMMPS
    29Sep2021's `fix wall/gran granular` computes it (eq. W4; measured
    against `lmp`): eq. N5's pull-off overlap with a0 = (9 pi w r_i / (4
    E_eff))^(1/3), the radius to the first power where the pair has R^2, and
    with the opposite sign; negative (a contact breaking while it overlaps)
    for r_i > 9/16."""
    a0 = _cbrt(9.0 * math.pi * cohesion * radius / (4.0 * e_eff))
    return a0 * a0 / radius - 2.0 * safe_sqrt(math.pi * cohesion * a0 / e_eff)


def wall_shear_stiffness(p: Params):
    """mindlin's kt NULL against a wall as LAMMPS 29Sep2021's `fix wall/gran
    granular` computes it, E (2 - nu)(1 + nu) / 4 (eq. W2; measured against
    `lmp` at nu = 0, 0.2, 0.3, 0.45: not eq. T3's 8 G_eff)."""
    return p.E * (2.0 - p.nu) * (1.0 + p.nu) / 4.0


def shear_modulus(p: Params):
    """G_eff = E / (4 (2 - nu)(1 + nu)): two like materials (eq. T3)."""
    return p.E / (4.0 * (2.0 - p.nu) * (1.0 + p.nu))


def _cbrt(x):
    """x^(1/3) of either sign as exp(log|x| / 3): XLA:CPU vectorises it, and
    not `jnp.cbrt` (docs/performance.md, "The contact models' step cost")."""
    m = jnp.abs(x)
    positive = m > 0
    return jnp.where(positive, jnp.sign(x) * jnp.exp(jnp.log(jnp.where(positive, m, 1.0)) / 3.0), 0.0)


def pulloff_overlap(e_eff, cohesion, R):
    """jkr's overlap at which a contact breaks, a0^2 / R - 2 sqrt(pi w a0 /
    E_eff) with a0 = (9 pi w R^2 / (4 E_eff))^(1/3) (eq. N5): below zero."""
    a0 = _cbrt(9.0 * math.pi * cohesion * R * R / (4.0 * e_eff))
    return a0 * a0 / R - 2.0 * safe_sqrt(math.pi * cohesion * a0 / e_eff)


def jkr_radius(e_eff, cohesion, R, dR):
    """The JKR contact radius a at delta R = `dR` (eq. N5's root, in LAMMPS's
    closed form; its max(0, .) guards included)."""
    t0 = cohesion * cohesion * R * R * R * R * e_eff
    t1 = 27.0 * math.pi ** 2 * t0
    t2 = 8.0 * dR * dR * dR * e_eff * e_eff * e_eff
    t3 = 4.0 * dR * dR * e_eff
    t4 = _cbrt(t1 + t2 + 3.0 * math.sqrt(3.0) * math.pi * safe_sqrt(t0 * (t1 + 2.0 * t2)))
    t5 = t3 / t4 + t4 / e_eff
    t6 = safe_sqrt(2.0 * dR + t5)
    return (t6 + safe_sqrt(4.0 * dR - t5 + 6.0 * math.sqrt(6.0) * cohesion * math.pi * R * R / (e_eff * t6))) \
        / math.sqrt(6.0)


WALLS = ("lammps", "pair")
"""How a wall contact is computed: as LAMMPS 29Sep2021's `fix wall/gran
granular` computes it (W1, W2, W4: the default, so that a LAMMPS input is
reproduced), or with the pair's own formulas at R = r_i (what LAMMPS's manual
describes)."""


def make_pair_force(model: Model, walls: str = "lammps"):
    """The kernel of one composition (see the module docstring)."""
    slot = model.history_layout()
    lammps_walls = walls == "lammps"
    material = model.normal in MATERIAL
    by_force = model.tangential.endswith("/force")

    def pair_force(p: Params, g: PairGeometry, history: Array, dt) -> PairForce:
        nx, ny, r, radsum, in_contact, vn, vtx, vty = tangential.frame(g)
        R = rolling_.effective_radius(g.radius_i, g.radius_j)
        pair = g.radius_j > 0
        if material:  # against a LAMMPS wall E_eff is its wall modulus (W1)
            e_eff = jnp.where(pair, effective_modulus(p), wall_modulus(p)) if lammps_walls else effective_modulus(p)
        if model.normal == "jkr":  # touching holds to the pull-off overlap (N5); a LAMMPS wall's (W4)
            R_safe = jnp.where(R > 0, R, 1.0)
            beyond = -pulloff_overlap(e_eff, p.cohesion, R_safe)
            if lammps_walls:
                beyond = jnp.where(pair, beyond, wall_pulloff_overlap(e_eff, p.cohesion, R_safe))
            reach = jnp.where(history[slot["touched"]] > 0, radsum + beyond, radsum)
            in_contact = (r > 0) & (r < reach)
        delta = jnp.where(in_contact, radsum - r, 0.0)

        if model.normal == "jkr":  # (N5); a padded slot takes dR = 1, finite and unselected
            dR = jnp.where(in_contact, delta * R_safe, 1.0)
            a = jkr_radius(e_eff, p.cohesion, R_safe, dR)
            k = 4.0 / 3.0 * e_eff * a
            fne = k * a * a / R_safe - 2.0 * math.pi * a * a * safe_sqrt(4.0 * p.cohesion * e_eff / (math.pi * a))
        else:
            a = safe_sqrt(R * delta)
            if model.normal == "hooke":  # (N1)
                k = p.kn
            elif model.normal == "hertz":  # (N2)
                k = p.kn * a
            else:  # (N3, N4)
                k = 4.0 / 3.0 * e_eff * a
            fne = k * delta
            if model.normal == "dmt":
                fne = fne - 4.0 * math.pi * p.cohesion * R
        meff = g.effective_mass
        # eta_n = gamma damp (D1-D4), as LAMMPS factors it; eta_t = (xgamma_t gamma) damp, so that
        # hooke's composition gives hooke's meff gamma_t bit for bit where xgamma_t gamma_n = gamma_t
        gamma = alpha(p.restitution) if model.damping == "tsuji" else p.gamma_n
        damp = {"velocity": 1.0, "mass_velocity": meff, "viscoelastic": a * meff}.get(model.damping)
        if damp is None:
            damp = safe_sqrt(meff * k)
        eta_n = gamma * damp

        fn = fne - eta_n * vn
        if model.limit_damping:
            fn = jnp.where(fn < 0.0, 0.0, fn)
        if model.normal == "jkr":  # F_crit = |F_ne + 2 F_pulloff| (T1)
            fncrit = jnp.abs(fne + 2.0 * 3.0 * math.pi * p.cohesion * R)
        elif model.normal == "dmt":  # |F_ne + 2 F_pulloff| as LAMMPS's manual has it (W3)
            fncrit = jnp.abs(fne + 2.0 * 4.0 * math.pi * p.cohesion * R)
        else:
            fncrit = jnp.abs(fn)

        eta_t, cap = p.xgamma_t * gamma * damp, p.mu * fncrit
        carried = {}
        if model.tangential == "linear_nohistory":  # (T1)
            ftx, fty = tangential.capped_dashpot(vtx, vty, eta_t, cap)
            sx, sy = jnp.zeros_like(ftx), jnp.zeros_like(fty)
        else:  # (T2-T5)
            kt = p.kt if model.tangential == "linear_history" else (
                (jnp.where(pair, 8.0 * shear_modulus(p), wall_shear_stiffness(p)) if lammps_walls
                 else 8.0 * shear_modulus(p)) if p.kt is None else p.kt) * a
            sx, sy = history[0], history[1]
            if "a_last" in slot:  # unloading: the spring scaled with the contact radius (T4)
                a_last = history[slot["a_last"]]
                shrinks = a < a_last
                factor = a / jnp.where(shrinks, a_last, 1.0)
                sx, sy = jnp.where(shrinks, sx * factor, sx), jnp.where(shrinks, sy * factor, sy)
                carried["a_last"] = a
            if by_force:  # (T5)
                ftx, fty, sx, sy = tangential.force_spring(sx, sy, nx, ny, vtx, vty, kt, eta_t, cap, dt)
            else:
                ftx, fty, sx, sy = tangential.spring(sx, sy, nx, ny, vtx, vty, kt, eta_t, cap, dt, True)
        carried["sx"], carried["sy"] = sx, sy

        n_cross_ft = nx * fty - ny * ftx
        half = 0.5 * delta
        torque = -jnp.where(pair, g.radius_i - half, g.radius_i) * n_cross_ft
        torque_j = -(g.radius_j - half) * n_cross_ft
        if model.rolling is not None:
            roll_i, roll_j, carried["rolling"] = rolling_.resist(
                model.rolling, p, fncrit, g.radius_i, g.radius_j, g.angular_velocity_i, g.angular_velocity_j, meff,
                history[slot["rolling"]], dt)
            torque, torque_j = torque + roll_i, torque_j + roll_j
        if "touched" in slot:
            carried["touched"] = jnp.ones_like(sx)
        return contact_result(in_contact, jnp.stack([fn * nx + ftx, fn * ny + fty]), torque,
                              jnp.stack([carried[name] for name in slot]), fn, torque_j)

    return pair_force


_KERNELS: dict = {}  # one kernel per composition: laws built alike are equal, and a jit closing over them compiles once


def interaction_range_for(model: Model):
    """`(params, radius_i, radius_j) -> distance`: disks interact when they
    overlap; jkr's touching pairs hold on to the pull-off overlap beyond (N5)."""

    def interaction_range(p: Params, radius_i, radius_j) -> float:
        if model.normal != "jkr":
            return radius_i + radius_j
        R = radius_i * radius_j / (radius_i + radius_j)
        return radius_i + radius_j - float(pulloff_overlap(float(effective_modulus(p)), float(p.cohesion), R))

    return interaction_range


def stable_time_step_for(model: Model):
    """`(params, min_mass, min_radius) -> dt`: the lattice estimate of `hooke`
    (omega^2 = 8 k / m, damping rate times dt < 1/2 over four contacts), with a
    Hertzian contact's stiffness dF/d delta = 3/2 k taken at an overlap of
    `TYPICAL_OVERLAP` of the smallest radius between two such disks."""

    def stable_time_step(p: Params, min_mass: float, min_radius: float = 0.5) -> float:
        a = math.sqrt(0.5 * min_radius * TYPICAL_OVERLAP * min_radius)
        if model.normal == "hooke":
            k = float(p.kn)
        elif model.normal == "hertz":
            k = 1.5 * float(p.kn) * a
        else:
            e_eff = float(p.E) / (2.0 * (1.0 - float(p.nu) ** 2))
            k = 1.5 * 4.0 / 3.0 * e_eff * a
        if model.tangential == "linear_history":
            k = max(k, float(p.kt))
        elif model.tangential in MINDLIN:
            kt = 8.0 * float(shear_modulus(p)) if p.kt is None else float(p.kt)
            k = max(k, kt * a)
        k_roll, gamma_roll = rolling_.time_step_limits(p)
        k = max(k, k_roll)
        if model.damping == "velocity":
            rate = float(p.gamma_n) / min_mass
        elif model.damping == "mass_velocity":
            rate = float(p.gamma_n)
        elif model.damping == "viscoelastic":
            rate = float(p.gamma_n) * a
        else:
            rate = float(alpha(float(p.restitution))) * math.sqrt(k / min_mass)
        rate = max(rate * (1.0 + float(p.xgamma_t)), gamma_roll / min_mass)
        omega = math.sqrt(8.0 * k / min_mass)
        limits = [2.0 / omega if omega > 0 else math.inf]
        if rate > 0:
            limits.append(2.0 / (4.0 * rate))
        return min(limits)

    return stable_time_step


def _validator(model: Model):
    def validate(p: Params) -> None:
        """Raises `InputError` on a value out of its range or a parameter the model needs left unset."""
        validate_ranges(NAME, p, RANGES)
        missing = [n for n in model.needs() if getattr(p, n) is None]
        if missing:
            raise InputError(f"the {NAME} model {describe(model)} needs {', '.join(missing)}.")
    return validate


def _walls_alike(p: Params) -> Params:
    """Walls take the pair's own values (`fix wall/gran granular` with the same model)."""
    return p


def law(model: Model = Model(), rotation: bool = True, walls: str = "lammps") -> ContactLaw:
    """The `granular` law of `model`'s sub-models; rotation False freezes
    spins; `walls` (`WALLS`): a wall contact as LAMMPS 29Sep2021's `fix
    wall/gran` computes it, or with the pair's formulas."""
    model = Model(*model)
    model.check()
    rolling_.check_mode(NAME, model.rolling, rotation)
    if walls not in WALLS:
        raise InputError(f"walls is one of {list(WALLS)}; got {walls!r}.")
    if (model, walls) not in _KERNELS:
        _KERNELS[model, walls] = (make_pair_force(model, walls), stable_time_step_for(model), _validator(model),
                                  interaction_range_for(model))
    kernel, stable, validate, reach = _KERNELS[model, walls]
    return ContactLaw(name=NAME, history_size=len(model.history_layout()), rotation=bool(rotation),
                      pair_force=kernel, wall_params=_walls_alike, interaction_range=reach,
                      stable_time_step=stable, validate=validate, params_type=Params,
                      options=(("model", tuple(model)),) + ((("walls", walls),) if walls != "lammps" else ()))


# ---------------------------------------------------------------- LAMMPS's line
_ARGS = {"hooke": ("kn", "gamma_n"), "hertz": ("kn", "gamma_n"), "hertz/material": ("E", "gamma_n", "nu"),
         "dmt": ("E", "gamma_n", "nu", "cohesion"), "jkr": ("E", "gamma_n", "nu", "cohesion"),
         "linear_nohistory": ("xgamma_t", "mu"), "linear_history": ("kt", "xgamma_t", "mu"),
         **{name: ("kt", "xgamma_t", "mu") for name in MINDLIN}, "sds": rolling_.PARAM_NAMES, "none": ()}


_KEYWORDS = {"damping", "tangential", "rolling", "twisting", "limit_damping", *NORMAL}


def _coefficient_names(keyword: str) -> list[str]:
    """The coefficients a keyword takes, as LAMMPS's manual names them (the
    normal model's second is its damping's: gamma_n, or e with tsuji)."""
    names = list(_ARGS[keyword])
    return ["gamma_n (or e with damping tsuji)" if n == "gamma_n" else n for n in names]


def parse(line: str, dtype=None) -> tuple[Model, Params]:
    """The model and parameters of a LAMMPS `pair_coeff * * ...` granular
    line (what follows the types), e.g. `"hertz/material 1e5 0.4 0.3 damping
    tsuji tangential mindlin NULL 1.0 0.5 rolling sds 1e3 50 0.1"`.

    The normal model comes first with its coefficients (its second is the
    damping's: gamma_n, or e for `damping tsuji`); then, in any order,
    `damping NAME`, `tangential NAME ...`, `rolling sds ...` (or `rolling
    none`), `limit_damping`. LAMMPS's defaults: `damping viscoelastic`;
    `tangential` is required; `NULL` for the mindlin models' kt is 8 G_eff."""
    model, values = read(line)
    return model, make_params(model, dtype=dtype, **values)


def read(line: str) -> tuple[Model, dict]:
    """`parse` without the params pytree: the model and the line's
    coefficients by name (`{"E": 1e7, ...}`; mindlin's NULL kt left out)."""
    words = line.split()
    if words[:1] == ["granular"]:
        words = words[1:]
    if not words or words[0] not in NORMAL:
        raise InputError(f"a granular line starts with its normal model, one of {list(NORMAL)}; got {line!r}.")
    values, found = {}, {"normal": words[0]}

    def take(keyword, at):
        names = _ARGS[keyword]
        numbers = words[at:at + len(names)]
        given = next((k for k, word in enumerate(numbers) if word in _KEYWORDS), len(numbers))
        if given < len(names):
            raise InputError(f"{keyword} takes {len(names)} coefficients ({', '.join(_coefficient_names(keyword))}); "
                             f"got {given}: {' '.join(numbers[:given]) or 'none'} (docs/lammps.md).")
        for name, word in zip(names, numbers):
            if word == "NULL" and name == "kt" and keyword in MINDLIN:
                continue
            try:
                values[name] = float(word)
            except ValueError:
                raise InputError(f"{keyword}'s {name} must be a number; got {word!r}.") from None
        return at + len(names)

    at = take(words[0], 1)
    while at < len(words):
        key = words[at]
        if key == "damping" and at + 1 < len(words):
            found["damping"], at = words[at + 1], at + 2
        elif key == "limit_damping":
            found["limit_damping"], at = True, at + 1
        elif key in ("tangential", "rolling") and at + 1 < len(words):
            known = TANGENTIAL if key == "tangential" else ("sds", "none")
            if words[at + 1] not in known:
                raise InputError(f"unknown {key} model {words[at + 1]!r}; choose one of {list(known)}.")
            found[key] = None if words[at + 1] == "none" else words[at + 1]
            at = take(words[at + 1], at + 2)
        else:
            raise InputError(f"cannot read {key!r} in the granular line {line!r}: expected damping, tangential, "
                             "rolling or limit_damping (twisting is 3D).")
    if "tangential" not in found:
        raise InputError("LAMMPS's pair granular needs a tangential model (e.g. `tangential linear_history kt "
                         "xgamma_t mu`).")
    model = Model(found["normal"], found.get("damping", "viscoelastic"), found["tangential"], found.get("rolling"),
                  found.get("limit_damping", False))
    model.check()
    if model.damping == "tsuji":
        values["restitution"] = values.pop("gamma_n")
    return model, values


def is_line(name) -> bool:
    """Whether a law name is a `pair_coeff` granular line (a normal model with
    its coefficients, `granular` in front or not), not a law's registry name."""
    words = name.split() if isinstance(name, str) else []
    if words[:1] == ["granular"]:
        words = words[1:]
    return len(words) > 1 and words[0] in NORMAL


@std_dataclasses.dataclass(frozen=True)
class Composition:
    """A granular `pair_coeff` line as a law module: what
    `jaxpile.laws.get_law_module` gives for the line's text, with the members
    a law module has (`NAME`, `PARAM_NAMES`, `RANGES`, `Params`,
    `make_params`, `law`), so that the protocols, sweeps and fits take it as
    they take `hooke`. Its parameters default to the line's coefficients.

    Attributes:
      NAME: the line, words separated by one space (the name the results,
        checkpoints and `show` record, and read back).
      model: its sub-models.
      values: `((name, value), ...)`, the line's coefficients.
    """

    NAME: str
    model: Model
    values: tuple

    Params = Params

    @property
    def PARAM_NAMES(self) -> tuple[str, ...]:
        """The parameters the composition reads (`--set`, `--vary`, `--params`)."""
        return self.model.reads()

    @property
    def RANGES(self) -> dict:
        return {name: RANGES[name] for name in self.PARAM_NAMES}

    def make_params(self, dtype=None, **values) -> Params:
        """The line's coefficients, `values` in their place where given."""
        unknown = sorted(set(values) - set(self.PARAM_NAMES))
        if unknown:
            raise InputError(f"the granular law {describe(self.model)} does not read {', '.join(unknown)}; "
                             f"it reads {', '.join(self.PARAM_NAMES)}.")
        return make_params(self.model, dtype=dtype, **{**dict(self.values), **values})

    def law(self, rotation: bool = True, rolling: str | None = None, walls: str = "lammps") -> ContactLaw:
        """The `ContactLaw`, named by the line; `rolling` (the `--rolling`
        flag) must be the line's own rolling model if given; `walls` as
        `granular.law`'s."""
        if rolling is not None and rolling != self.model.rolling:
            raise InputError(f"the granular line names its rolling model ({self.model.rolling or 'none'}): write "
                             "`rolling sds k_roll gamma_roll mu_roll` in the line instead of --rolling.")
        return std_dataclasses.replace(law(self.model, rotation, walls), name=self.NAME)


def line_at(law_name: str, values: dict) -> str | None:
    """The `pair_coeff` line of a law named by a line, with `values` (a
    parameter's name to its value: what a run used, what a fit found) in
    place of its coefficients, to take back to LAMMPS; None for another law."""
    if not is_line(law_name):
        return None
    module = composition(law_name)
    known = {n: float(v) for n, v in values.items() if n in module.PARAM_NAMES and v is not None}
    return lammps_line(module.model, module.make_params(**known))


def composition(line: str) -> Composition:
    """The `Composition` of a `pair_coeff` granular line (one object per line,
    its words one space apart and `granular` in front or not, so that the
    laws it builds are equal and compile once)."""
    words = line.split()
    return _composition(" ".join(words[1:] if words[:1] == ["granular"] else words))


@functools.lru_cache(maxsize=64)
def _composition(line: str) -> Composition:
    model, values = read(line)
    make_params(model, **values)  # refuses a missing or unread coefficient now, in the line's terms
    return Composition(NAME=line, model=model, values=tuple(sorted(values.items())))


def describe(model: Model) -> str:
    """The model as LAMMPS names it (`hertz/material damping tsuji tangential mindlin`)."""
    text = f"{model.normal} damping {model.damping} tangential {model.tangential}"
    text = text if model.rolling is None else f"{text} rolling {model.rolling}"
    return f"{text} limit_damping" if model.limit_damping else text


def lammps_line(model: Model, p: Params) -> str:
    """The `pair_coeff * *` granular text of `model` at `p` (`parse`'s reverse)."""
    def num(x):
        return repr(float(x))

    damping = p.restitution if model.damping == "tsuji" else p.gamma_n
    first = [damping if n == "gamma_n" else getattr(p, n) for n in _ARGS[model.normal]]
    parts = [model.normal, *map(num, first), "damping", model.damping, "tangential", model.tangential]
    tangent = [getattr(p, n) for n in _ARGS[model.tangential]]
    parts += ["NULL" if v is None else num(v) for v in tangent]
    if model.rolling == "sds":
        parts += ["rolling", "sds", *(num(getattr(p, n)) for n in rolling_.PARAM_NAMES)]
    elif model.rolling is not None:
        raise InputError(f"LAMMPS has no rolling {model.rolling!r} (jaxpile's own); it cannot be written as a line.")
    return " ".join(parts + (["limit_damping"] if model.limit_damping else []))


__all__ = ["Composition", "DAMPING", "Model", "NORMAL", "Params", "ROLLING", "TANGENTIAL", "alpha", "composition", "describe",
           "is_line", "law", "lammps_line", "line_at", "make_params", "parse", "read"]
