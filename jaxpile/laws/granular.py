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

Damping, F_n = F_ne - eta_n v_n with                               (D1-D4)

  velocity gamma_n:          eta_n = gamma_n
  mass_velocity gamma_n:     eta_n = gamma_n m_eff
  viscoelastic gamma_n:      eta_n = gamma_n a m_eff   (LAMMPS's default)
  tsuji e:                   eta_n = alpha(e) sqrt(m_eff k),
      alpha(e) = 1.2728 - 4.2783 e + 11.087 e^2 - 22.348 e^3 + 27.467 e^4
                 - 18.022 e^5 + 4.8218 e^6   (Tsuji, Tanaka & Ishida 1992)
      as LAMMPS has it: a head-on Hertzian contact then rebounds with more
      than e (0.44, 0.70, 0.93 at e = 0.3, 0.6, 0.9, whatever the speed);
      the polynomial gives e itself when the mass is 2 m_eff
      (tests/test_granular.py).

Tangential, capped at mu |F_n| (`jaxpile.laws.tangential`), damped with
eta_t = xgamma_t eta_n (LAMMPS's tangential damping is a ratio):  (T1-T3)

  linear_nohistory xgamma_t mu:   F_t = -eta_t v_tr
  linear_history kt xgamma_t mu:  F_t = -(kt s + eta_t v_tr)
  mindlin kt xgamma_t mu:         F_t = -(kt a s + eta_t v_tr); kt NULL
      (None) is 8 G_eff, G_eff = E / (4 (2 - nu)(1 + nu)) (Mindlin 1949)

with the shear displacement s turned into the tangent plane keeping its
length, then s <- s + v_tr dt (`pair_style granular`'s frame). The torque on i
is -(r_i - delta/2) n x F_t, on j -(r_j - delta/2) n x F_t (the arm to the
contact point); against a wall r_i.

Rolling: `rolling sds k_roll gamma_roll mu_roll` (`jaxpile.laws.rolling`),
capped at mu_roll |F_n|; or jaxpile's `constant`.

Walls (`fix wall/gran granular` with the same model) use the same values, a
wall being a partner of zero radius and infinite mass, with one difference
LAMMPS 29Sep2021 has: its wall takes E_eff = E / (2 (1 - nu)) for
hertz/material (W1), not E / (2 (1 - nu^2)), and mindlin's kt NULL is
E (2 - nu)(1 + nu) / 4 there (W2), not 8 G_eff; jaxpile does as LAMMPS does,
so that a LAMMPS input is reproduced (docs/lammps.md names these traps).

Not in this module yet: `dmt` and `jkr` (cohesion), `mindlin_rescale`, the
`/force` tangential forms, `limit_damping`, twisting (a 3D torque).
"""

from __future__ import annotations

import math
from typing import Any, NamedTuple

import jax.numpy as jnp
from jax_md import dataclasses

from jaxpile.errors import InputError
from jaxpile.laws import rolling as rolling_
from jaxpile.laws import tangential
from jaxpile.laws.base import (ContactLaw, PairForce, PairGeometry, contact_result, param_arrays, ranges_doc,
                               safe_sqrt, validate_ranges, with_set)
from jaxpile.ranges import NON_NEGATIVE, POSITIVE, Range

Array = Any
NAME = "granular"

NORMAL = ("hooke", "hertz", "hertz/material")
DAMPING = ("velocity", "mass_velocity", "viscoelastic", "tsuji")
TANGENTIAL = ("linear_nohistory", "linear_history", "mindlin")
ROLLING = (None,) + rolling_.MODES

PARAM_NAMES = ("kn", "E", "nu", "gamma_n", "restitution", "kt", "xgamma_t", "mu") + rolling_.PARAM_NAMES
RANGES = {"kn": POSITIVE, "E": POSITIVE,
          "nu": Range(low=-1, low_open=True, high=0.5, why="a Poisson's ratio"),
          "gamma_n": NON_NEGATIVE,
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

    def check(self) -> None:
        for kind, value, known in (("normal", self.normal, NORMAL), ("damping", self.damping, DAMPING),
                                   ("tangential", self.tangential, TANGENTIAL), ("rolling", self.rolling, ROLLING)):
            if value not in known:
                raise InputError(f"unknown {kind} model {value!r} for {NAME}; choose one of "
                                 f"{[k for k in known if k is not None]}.")

    def needs(self) -> tuple[str, ...]:
        """The parameters this composition reads (kt is optional for mindlin)."""
        normal = ("E", "nu") if self.normal == "hertz/material" else ("kn",)
        damping = ("restitution",) if self.damping == "tsuji" else ("gamma_n",)
        tangent = {"linear_nohistory": ("xgamma_t", "mu"), "linear_history": ("kt", "xgamma_t", "mu"),
                   "mindlin": ("xgamma_t", "mu")}[self.tangential]
        return normal + damping + tangent + (() if self.rolling is None else
                                             rolling_.PARAM_NAMES if self.rolling == "sds" else ("mu_roll",))


@with_set
@dataclasses.dataclass
class Params:
    """Parameters of a `granular` law (LAMMPS's meanings; what a composition
    does not read stays None).

    Attributes:
      kn: normal stiffness of `hooke` (force / length) and `hertz` (force /
        length^2).
      E, nu: Young's modulus and Poisson's ratio of `hertz/material` (and of
        `mindlin`'s default kt).
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
    unread = sorted(n for n, v in values.items() if v is not None and n not in needs
                    and not (n == "kt" and model.tangential == "mindlin"))
    if unread:
        raise InputError(f"the {NAME} model {describe(model)} does not read {', '.join(unread)}.")
    if model.tangential == "mindlin" and values.get("kt") is None and model.normal != "hertz/material":
        raise InputError("mindlin's kt NULL is 8 G_eff from E and nu, which only hertz/material gives: give kt.")
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


def wall_shear_stiffness(p: Params):
    """mindlin's kt NULL against a wall as LAMMPS 29Sep2021's `fix wall/gran
    granular` computes it, E (2 - nu)(1 + nu) / 4 (eq. W2; measured against
    `lmp` at nu = 0, 0.2, 0.3, 0.45: not eq. T3's 8 G_eff)."""
    return p.E * (2.0 - p.nu) * (1.0 + p.nu) / 4.0


def shear_modulus(p: Params):
    """G_eff = E / (4 (2 - nu)(1 + nu)): two like materials (eq. T3)."""
    return p.E / (4.0 * (2.0 - p.nu) * (1.0 + p.nu))


def make_pair_force(model: Model):
    """The kernel of one composition (see the module docstring)."""

    def pair_force(p: Params, g: PairGeometry, history: Array, dt) -> PairForce:
        nx, ny, r, radsum, in_contact, vn, vtx, vty = tangential.frame(g)
        delta = jnp.where(in_contact, radsum - r, 0.0)
        a = safe_sqrt(rolling_.effective_radius(g.radius_i, g.radius_j) * delta)

        if model.normal == "hooke":  # (N1)
            k = p.kn
        elif model.normal == "hertz":  # (N2)
            k = p.kn * a
        else:  # (N3); against a wall E_eff is LAMMPS's wall modulus (W1)
            k = 4.0 / 3.0 * jnp.where(g.radius_j > 0, effective_modulus(p), wall_modulus(p)) * a
        meff = g.effective_mass
        if model.damping == "velocity":  # (D1-D4)
            eta_n = p.gamma_n
        elif model.damping == "mass_velocity":
            eta_n = p.gamma_n * meff
        elif model.damping == "viscoelastic":
            eta_n = p.gamma_n * a * meff
        else:
            eta_n = alpha(p.restitution) * safe_sqrt(meff * k)

        fn = k * delta - eta_n * vn

        eta_t, cap = p.xgamma_t * eta_n, p.mu * jnp.abs(fn)
        if model.tangential == "linear_nohistory":  # (T1)
            ftx, fty = tangential.capped_dashpot(vtx, vty, eta_t, cap)
            sx, sy = jnp.zeros_like(ftx), jnp.zeros_like(fty)
        else:  # (T2, T3)
            kt = p.kt if model.tangential == "linear_history" else (
                jnp.where(g.radius_j > 0, 8.0 * shear_modulus(p), wall_shear_stiffness(p)) if p.kt is None
                else p.kt) * a
            ftx, fty, sx, sy = tangential.spring(history[0], history[1], nx, ny, vtx, vty, kt, eta_t, cap, dt, True)

        n_cross_ft = nx * fty - ny * ftx
        half = 0.5 * delta
        torque = -jnp.where(g.radius_j > 0, g.radius_i - half, g.radius_i) * n_cross_ft
        torque_j = -(g.radius_j - half) * n_cross_ft
        carried = [sx, sy]
        if model.rolling is not None:
            roll_i, roll_j, entry = rolling_.resist(model.rolling, p, fn, g.radius_i, g.radius_j,
                                                    g.angular_velocity_i, g.angular_velocity_j, meff, history[2], dt)
            torque, torque_j = torque + roll_i, torque_j + roll_j
            carried.append(entry)
        return contact_result(in_contact, jnp.stack([fn * nx + ftx, fn * ny + fty]), torque, jnp.stack(carried), fn,
                              torque_j)

    return pair_force


_KERNELS: dict = {}  # one kernel per composition: laws built alike are equal, and a jit closing over them compiles once


def interaction_range(p: Params, radius_i, radius_j) -> float:
    """Disks interact when they overlap."""
    return radius_i + radius_j


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
        elif model.tangential == "mindlin":
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


def law(model: Model = Model(), rotation: bool = True) -> ContactLaw:
    """The `granular` law of `model`'s sub-models; rotation False freezes spins."""
    model = Model(*model)
    model.check()
    rolling_.check_mode(NAME, model.rolling, rotation)
    if model not in _KERNELS:
        _KERNELS[model] = (make_pair_force(model), stable_time_step_for(model), _validator(model))
    kernel, stable, validate = _KERNELS[model]
    return ContactLaw(name=NAME, history_size=2 + rolling_.HISTORY[model.rolling], rotation=bool(rotation),
                      pair_force=kernel, wall_params=_walls_alike, interaction_range=interaction_range,
                      stable_time_step=stable, validate=validate, params_type=Params,
                      options=(("model", tuple(model)),))


# ---------------------------------------------------------------- LAMMPS's line
_ARGS = {"hooke": ("kn", "gamma_n"), "hertz": ("kn", "gamma_n"), "hertz/material": ("E", "gamma_n", "nu"),
         "linear_nohistory": ("xgamma_t", "mu"), "linear_history": ("kt", "xgamma_t", "mu"),
         "mindlin": ("kt", "xgamma_t", "mu"), "sds": rolling_.PARAM_NAMES}


def parse(line: str, dtype=None) -> tuple[Model, Params]:
    """The model and parameters of a LAMMPS `pair_coeff * * ...` granular
    line (what follows the types), e.g. `"hertz/material 1e5 0.4 0.3 damping
    tsuji tangential mindlin NULL 1.0 0.5 rolling sds 1e3 50 0.1"`.

    The normal model comes first with its coefficients (its second is the
    damping's: gamma_n, or e for `damping tsuji`); then, in any order,
    `damping NAME`, `tangential NAME ...`, `rolling sds ...`. LAMMPS's
    defaults: `damping viscoelastic`; `tangential` is required; `NULL` for
    mindlin's kt is 8 G_eff."""
    words = line.split()
    if not words or words[0] not in NORMAL:
        raise InputError(f"a granular line starts with its normal model, one of {list(NORMAL)}; got {line!r}.")
    values, found = {}, {"normal": words[0]}

    def take(keyword, at):
        names = _ARGS[keyword]
        numbers = words[at:at + len(names)]
        if len(numbers) < len(names):
            raise InputError(f"{keyword} takes {len(names)} coefficients ({', '.join(names)}); got {numbers}.")
        for name, word in zip(names, numbers):
            if word == "NULL" and name == "kt" and keyword == "mindlin":
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
        elif key in ("tangential", "rolling") and at + 1 < len(words):
            found[key] = words[at + 1]
            if words[at + 1] not in _ARGS:
                raise InputError(f"unknown {key} model {words[at + 1]!r}; choose one of "
                                 f"{list(TANGENTIAL if key == 'tangential' else rolling_.MODES[:1])}.")
            at = take(words[at + 1], at + 2)
        else:
            raise InputError(f"cannot read {key!r} in the granular line {line!r}: expected damping, tangential "
                             "or rolling (twisting is 3D).")
    if "tangential" not in found:
        raise InputError("LAMMPS's pair granular needs a tangential model (e.g. `tangential linear_history kt "
                         "xgamma_t mu`).")
    model = Model(found["normal"], found.get("damping", "viscoelastic"), found["tangential"], found.get("rolling"))
    model.check()
    if model.damping == "tsuji":
        values["restitution"] = values.pop("gamma_n")
    return model, make_params(model, dtype=dtype, **values)


def describe(model: Model) -> str:
    """The model as LAMMPS names it (`hertz/material damping tsuji tangential mindlin`)."""
    text = f"{model.normal} damping {model.damping} tangential {model.tangential}"
    return text if model.rolling is None else f"{text} rolling {model.rolling}"


def lammps_line(model: Model, p: Params) -> str:
    """The `pair_coeff * *` granular text of `model` at `p` (`parse`'s reverse)."""
    def num(x):
        return repr(float(x))

    damping = p.restitution if model.damping == "tsuji" else p.gamma_n
    first = (p.kn, damping) if model.normal != "hertz/material" else (p.E, damping, p.nu)
    parts = [model.normal, *map(num, first), "damping", model.damping, "tangential", model.tangential]
    tangent = [getattr(p, n) for n in _ARGS[model.tangential]]
    parts += ["NULL" if v is None else num(v) for v in tangent]
    if model.rolling == "sds":
        parts += ["rolling", "sds", *(num(getattr(p, n)) for n in rolling_.PARAM_NAMES)]
    elif model.rolling is not None:
        raise InputError(f"LAMMPS has no rolling {model.rolling!r} (jaxpile's own); it cannot be written as a line.")
    return " ".join(parts)


__all__ = ["DAMPING", "Model", "NORMAL", "Params", "ROLLING", "TANGENTIAL", "alpha", "describe", "law",
           "lammps_line", "make_params", "parse"]
