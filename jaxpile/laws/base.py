"""What every contact law provides, and the geometry of one pair handed to it.

A law is a *pure per-pair kernel*: it sees one pair's geometry and history and
returns the force on particle i, the torque on i and the new history. The
neighbour-slot axis and the batch axis are added by `vmap` around it (the habit
of jax-md's `energy.py`). Walls reuse the same kernel with a partner of zero
radius and infinite mass (Lee & Herrmann 1993, sec. 2).
"""

from __future__ import annotations

import dataclasses
import numbers
from typing import Any, Callable, NamedTuple

import jax.numpy as jnp

from jaxpile.errors import InputError
from jaxpile.ranges import doc_section, is_number_like

Array = Any


class PairGeometry(NamedTuple):
    """One pair (i, j) as seen from particle i (disks: d = 2, spheres: d = 3).

    Attributes:
      displacement: `[d]` x_i - x_j (for a wall: from the wall plane to x_i).
      radius_i, radius_j: radii (radius_j = 0 for a wall).
      velocity: `[d]` v_i - v_j.
      angular_velocity_i, angular_velocity_j: counter-clockwise spins (disks),
        `[3]` spin vectors (spheres).
      effective_mass: m_i m_j / (m_i + m_j), or m_i against a wall or fixed disk.
      step_displacements: `[2, 2]` the displacement at steps k and k + 1, given
        only by the implicit midpoint integrator (then `displacement` is their
        midpoint), for laws with a time-averaged spring (Liffman et al. 1992,
        eq. 24); None otherwise.
      partner_fixed: bool, True against a wall or when one disk of the pair is
        fixed (then `effective_mass` is the moving disk's own mass); None when
        the caller does not say (a law then treats the partner as free).
    """

    displacement: Array
    radius_i: Array
    radius_j: Array
    velocity: Array
    angular_velocity_i: Array
    angular_velocity_j: Array
    effective_mass: Array
    step_displacements: Array | None = None
    partner_fixed: Array | None = None


class PairForce(NamedTuple):
    """What a kernel returns for one pair.

    Attributes:
      force: `[d]` force on i.
      torque: torque on i (z component; `[3]` for spheres).
      history: `[h]` the pair's new history (zero when not in contact).
      normal: the normal force magnitude along +n (repulsive > 0), for analysis
        and for Coulomb caps.
      in_contact: bool.
      torque_j: torque on j (as `torque`). The pair loop evaluates each pair
        once, from its lower id i, and gives j the reaction -force and this
        torque (for a contact-point lever arm: torque * r_j / r_i, same sign).
    """

    force: Array
    torque: Array
    history: Array
    normal: Array
    in_contact: Array
    torque_j: Array = None


@dataclasses.dataclass(frozen=True)
class ContactLaw:
    """A contact law: static configuration plus pure functions (hashable, so a jit
    that closes over it compiles once).

    Attributes:
      name: registry name (`hooke`, ...).
      history_size: h, the length of the per-pair history vector.
      rotation: False freezes the angular degrees of freedom.
      pair_force: `(params, PairGeometry, history[h], dt) -> PairForce` (with
        `torque_j`, the torque on j, filled in).
      wall_params: `params -> params` used for walls (the `wall_*` values).
      interaction_range: `(params, radius_i, radius_j) -> float`, the distance
        below which a pair interacts (sizes the neighbour list).
      stable_time_step: `(params, min_mass, min_radius) -> float`, an estimate
        of the largest stable explicit time step.
      validate: `params -> None`, raises `InputError` on a bad value.
      params_type: the params pytree class (for `--set NAME=VALUE`).
      options: `((name, value), ...)`, the reading the law was built with
        beyond `rotation` (e.g. baxter's `lever_arm` and `slip`): recorded in
        checkpoints, so that a run is not resumed in another reading.
      history_size_3d: h for spheres; None for a law of disks only (its
        paper is 2D): `history_for(3)` refuses it.
    """

    name: str
    history_size: int
    rotation: bool
    pair_force: Callable[..., PairForce]
    wall_params: Callable[[Any], Any]
    interaction_range: Callable[..., float]
    stable_time_step: Callable[..., float]
    validate: Callable[[Any], None]
    params_type: type
    options: tuple = ()
    history_size_3d: int | None = None

    def history_for(self, dim: int) -> int:
        """The per-pair history length for disks (`dim` 2) or spheres (3).

        Raises:
          InputError: for spheres with a law of disks only.
        """
        if dim == 2:
            return self.history_size
        if self.history_size_3d is None:
            raise InputError(f"the {self.name} law is for disks only (its paper is two-dimensional); spheres "
                             "take hooke (with or without rolling resistance).")
        return self.history_size_3d


def with_set(params_class):
    """A law's `Params` with a documented `set` (jax-md's dataclasses give one
    without a docstring)."""

    def set(self, **values):
        """A copy with `values` changed and every other parameter kept; this
        one is unchanged (a pytree: traced values are welcome).

            params = hooke.make_params(kn=1e4, mu=0.2)
            stiffer = params.set(kn=2e4, mu=0.3)
            jax.grad(lambda mu: loss(params.set(mu=mu)))(0.2)
        """
        return dataclasses.replace(self, **values)

    params_class.set = set
    return params_class


def contact_result(in_contact, force, torque, history, normal, torque_j) -> PairForce:
    """A `PairForce` that is zero (and has zero history) outside contact."""
    return PairForce(
        force=jnp.where(in_contact, force, jnp.zeros_like(force)),
        torque=jnp.where(in_contact, torque, 0.0),
        history=jnp.where(in_contact, history, jnp.zeros_like(history)),
        normal=jnp.where(in_contact, normal, 0.0),
        in_contact=in_contact,
        torque_j=jnp.where(in_contact, torque_j, 0.0),
    )


def normal_and_distance(displacement):
    """Unit normal n = d/|d| and |d|, safe at d = 0 (returns n = 0, r = 0) so that
    padded slots give finite gradients (jax-md `safe_mask` habit)."""
    r2 = dot2(displacement, displacement)
    positive = r2 > 0
    r = jnp.sqrt(jnp.where(positive, r2, 1.0))
    n = jnp.where(positive, displacement / r, 0.0)
    return n, jnp.where(positive, r, 0.0)


def safe_norm(v):
    """|v| with a finite gradient at v = 0."""
    s = dot2(v, v)
    positive = s > 0
    return jnp.where(positive, jnp.sqrt(jnp.where(positive, s, 1.0)), 0.0)


def perp(n):
    """z x n: the unit tangent t with z = n x t (counter-clockwise of n)."""
    return jnp.stack([-n[..., 1], n[..., 0]], axis=-1)


def dot2(a, b):
    """a . b for 2-vectors, written out: inside vmap a `jnp.dot` becomes a batched
    dot_general that XLA on CPU does not fuse with the elementwise kernel."""
    return a[..., 0] * b[..., 0] + a[..., 1] * b[..., 1]


def safe_sqrt(x):
    """sqrt(max(x, 0)) with a zero (not infinite) gradient at x <= 0."""
    positive = x > 0
    return jnp.where(positive, jnp.sqrt(jnp.where(positive, x, 1.0)), 0.0)


def cross2(a, b):
    """z component of a x b."""
    return a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]


def param_arrays(law_name: str, values: dict, ranges: dict, dtype, optional=()) -> dict:
    """`values` as arrays of `dtype`, for a law's `make_params`; a value that is
    not a number (a string, None for a required parameter, a bool) is refused
    with its range. `optional` names may be None (the `wall_*` defaults)."""
    out = {}
    for name, value in values.items():
        if value is None and name in optional:
            out[name] = None
            continue
        if not is_number_like(value):
            raise InputError(f"{law_name} parameter {name} must be a number {ranges[name].describe()}; got {value!r}.")
        if isinstance(value, numbers.Integral):  # a Python int beyond int64 would not convert
            try:
                value = float(value)
            except OverflowError:
                raise InputError(f"{law_name} parameter {name} must be finite and {ranges[name].describe()}; "
                                 "got an integer beyond float range.") from None
        out[name] = jnp.asarray(value, dtype)
    return out


def validate_ranges(law_name: str, params, ranges: dict) -> None:
    """Raises `InputError` if a parameter lies outside its declared range
    (`jaxpile.ranges`; None values, the unset `wall_*`, are skipped)."""
    for name, range_ in ranges.items():
        value = getattr(params, name)
        if value is not None:
            range_.check(f"{law_name} parameter {name}", value)


def ranges_doc(ranges: dict) -> str:
    """The `Valid ranges` section appended to a law's `Params` docstring."""
    return doc_section(ranges, "Valid ranges (checked by `validate`; `jaxpile.ranges`)")
