"""A pile built by dropping disks one at a time (Liffman, Chan & Hughes 1992, Fig. 20).

"A particulate pile consisting of 968 particles, which have been assembled by
dropping one particle at a time from a height of two particle diameters above the
highest point in the pile" (Fig. 20 caption); "we can create a pile of 'soft'
particles by dropping one particle at a time ... other random piles that we have
created in a similar fashion show no depression in the middle of the normal force
distribution" (text below Fig. 17). The paper measures the base normal force
profile (Fig. 20(b)) and finds, in one pile, a slight central dip.

How this protocol reads it:

* Where: not printed. Every disk is dropped over the pile's axis, shifted by a
  random amount uniform in +-`jitter` (default 0.1 sigma) drawn from the seed:
  without it the disks would balance on one another on the axis (an unstable
  equilibrium that floating point keeps), and the paper's piles are random.
* How high: the disk's lowest point starts at rest `drop_height` = 2 sigma above
  the highest point of the disks already in (the ground for the first).
* When: each disk meets a pile that has (nearly) stopped. The next is inserted
  once every disk in has been slower than `settle_speed` (default 0.05
  sqrt(g sigma), 2.5% of the speed of a 2 sigma fall) for `quiet_time` in a row
  (default 0.25 sqrt(sigma/g)): longer than the settle_speed / g a released disk
  and the 2 settle_speed / g a bouncing one spend below the threshold, so
  neither counts as settled. A disk that never settles (a slow creep on the
  slope) does not stall the pile: after `max_interval` (default 10 sqrt(sigma/g),
  five fall times) the next goes in anyway. All of this runs in the driver,
  inside the compiled loop; disks not yet dropped are parked inactive above.
* After the last disk, the pile is relaxed to rest (`speed_tolerance`, within
  `relax_steps`).

Laws (`SETTING`): the lattice protocol's paper setting (`paper1992.PAPER_SETTING`),
disks that do not spin, on a frictional ground: hooke, lee-herrmann and baxter
(n = 36, r0 = 1.2) with frictionless disks (mu = 0, wall_mu = 1), and the
paper's own law (`liffman`, eq. 46's K_s; its viscous disk friction vanishes at
rest, and the ground's static well holds the base). On the flat ground a
spinning disk rolls without slip, which no law dissipates (liffman's eq. 29
acts on the slip too), and disks that cannot spin but hold each other by
Coulomb friction stack into a vertical tower; frictionless-at-rest disks on a
frictional ground, the 1992 analytic model's assumption, slide into pockets and
build a heap (docs/choices.md#the-dropped-pile). Pass `rotation=True` or
`params={"mu": ...}` to `SPEC.run` to try otherwise. A paper-size pile is an
accelerator's job (its cost: the same page); tests use 20 disks.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import Any, NamedTuple

import jax.numpy as jnp
import numpy as np

from jaxpile import budget, ranges
from jaxpile.engine.boundaries import GROUND, make_boundaries
from jaxpile.engine.state import SimState, make_particles
from jaxpile.errors import InputError
from jaxpile.measure.dropped_pile import measure
from jaxpile.protocols import paper1992
from jaxpile.protocols.base import Setting, Setup
from jaxpile.protocols.drivers import activate, next_inactive
from jaxpile.protocols.spec import Options, ProtocolSpec, option
from jaxpile.protocols.stages import Phase
from jaxpile.ranges import COUNT, DISKS, SIZE, SPAN, SPEED, STEPS, Range

Array = Any
SQRT3 = math.sqrt(3.0)

SETTING = {
    "n": 968,
    "rotation": False,
    "dt": 1.0e-3,
    "drop_height": 2.0,
    "jitter": 0.1,
    "settle_speed": 0.05,
    "quiet_time": 0.25,
    "max_interval": 10.0,
    "speed_tolerance": 1.0e-5,
    "relax_steps": 1_000_000,
    "params": {**paper1992.PAPER_SETTING["params"],
               "baxter": {"n": 36.0, "r0": 1.2, "mu": 0.0, "wall_mu": 1.0}},
}

PARK_SPACING = 2.5  # diameters between parked disks: beyond any law's cut-off plus the skin


# ------------------------------------------------------------------ options
@dataclass(frozen=True)
class DropOptions(Options):
    """The drop's options, in diameters sigma, sqrt(sigma/g) and sqrt(g sigma)."""

    n: int = option(SETTING["n"], range=DISKS, help="number of disks (968 in the paper)")
    drop_height: float = option(SETTING["drop_height"], range=SIZE, unit="sigma",
                                help="gap between a dropped disk's lowest point and the pile's highest (2 in the paper)")
    jitter: float = option(SETTING["jitter"], range=Range(low=0, high=1, high_open=True, why="diameters"),
                           unit="sigma", help="half-width of the uniform lateral offset of each drop")
    settle_speed: float = option(SETTING["settle_speed"], range=SPEED, unit="sqrt(g sigma)",
                                 help="the pile counts as settled once every disk is slower than this...")
    quiet_time: float = option(SETTING["quiet_time"], range=SIZE, unit="sqrt(sigma/g)", help="...for this long")
    max_interval: float = option(SETTING["max_interval"], range=SIZE, unit="sqrt(sigma/g)",
                                 help="the longest wait between two drops")
    diameter: float = option(1.0, range=SIZE, help="the disks' diameter")
    mass: float = option(1.0, range=SIZE, help="the disks' mass")
    speed_tolerance: float = option(SETTING["speed_tolerance"], range=SPEED, unit="sqrt(g sigma)",
                                    help="after the last drop, at rest once every disk is slower than this")
    relax_steps: int = option(SETTING["relax_steps"], range=STEPS, help="step budget of the final relaxation")
    bins: int = option(15, range=COUNT, help="bins of the base normal force profile")
    dip_threshold: float = option(0.05, range=SPAN, help="a central dip is reported when central_dip exceeds this")
    hard_collisions: Any = option(None, help="the simulator's hard collisions (`Simulator(hard_collisions=...)`)")

    def validate(self):
        if self.max_interval <= self.quiet_time:
            raise InputError(f"max_interval ({self.max_interval}) must be longer than quiet_time ({self.quiet_time}).")


class DropState(NamedTuple):
    """What the drop driver carries between steps (`SimState.protocol_state`).

    Attributes:
      drop_x: `[n]` the x each disk is dropped at (axis + jitter).
      last_insert: int scalar, the step of the last insertion.
      quiet_steps: int scalar, consecutive steps with every disk slower than
        `settle_speed` (reset by an insertion).
      inserted: int scalar, disks dropped so far.
      forced: int scalar, of those, the drops made at `max_interval` before the
        pile had settled.
    """

    drop_x: Array
    last_insert: Array
    quiet_steps: Array
    inserted: Array
    forced: Array


def _positive(name, value) -> float:
    value = float(value)
    if not (value > 0 and math.isfinite(value)):
        raise InputError(f"{name} must be positive and finite; got {value!r}.")
    return value


def _steps(name, time_value, dt) -> int:
    return ranges.steps_of(name, _positive(name, time_value), dt, rounding=lambda c: math.ceil(c - 1e-9))


def layout(n: int, diameter: float = 1.0, drop_height: float = 2.0):
    """Where the pile stands and where the waiting disks are parked.

    Returns:
      `(axis_x, parked, box)`: the x of the pile's axis, `[n, 2]` parked
      centres on a grid `PARK_SPACING` diameters apart, and the neighbour-list
      box `(width, height)`. The grid's lowest row is above the highest a pile
      of n close-packed disks can stand (a 60-deg triangle, with 50% head-room)
      plus the drop height, so a disk is never dropped into the parked ones.
    """
    columns = int(math.ceil(math.sqrt(n)))
    rows = int(math.ceil(n / columns))
    base_60 = math.sqrt(2.0 * SQRT3 * n / SQRT3)  # base of an n-disk 60-deg pile
    base_10 = math.sqrt(2.0 * SQRT3 * n / math.tan(math.radians(10.0)))  # a flat one
    top = 1.5 * (0.5 * SQRT3 * base_60) + drop_height + 2.0 + PARK_SPACING
    width = max(base_10, (columns - 1) * PARK_SPACING) + 10.0
    axis = 0.5 * width
    i = np.arange(n)
    parked = np.stack([axis + (i % columns - 0.5 * (columns - 1)) * PARK_SPACING,
                       top + (i // columns) * PARK_SPACING], axis=1)
    box = (width * diameter, (top + rows * PARK_SPACING + 5.0) * diameter)
    return axis * diameter, parked * diameter, box


@functools.lru_cache(maxsize=32)
def make_driver(*, drop_height: float, settle_speed: float, quiet_steps: int, max_interval_steps: int):
    """The insertion driver (a pure `state -> state`, see `drivers`).

    Each step: counts the steps in a row with every active disk slower than
    `settle_speed`; when `quiet_steps` are reached, or `max_interval_steps` have
    passed since the last insertion, activates the next parked disk at rest,
    its lowest point `drop_height` above the highest active disk's top (or the
    ground), at its `drop_x`. One function per set of constants (cached): the
    driver of a set-up is its simulator's, so a batch of set-ups with the same
    options runs on one simulator."""
    from jaxpile.engine.simulate import max_speed

    def driver(state: SimState) -> SimState:
        ps: DropState = state.protocol_state
        p = state.particles
        dtype = p.position.dtype
        quiet = jnp.where(max_speed(state) < settle_speed, ps.quiet_steps + 1, 0)
        since = state.step - ps.last_insert
        index, any_left = next_inactive(state)
        settled = quiet >= quiet_steps
        due = any_left & (settled | (since >= max_interval_steps))
        ground = state.boundaries.wall_offset[GROUND]
        top = jnp.maximum(jnp.max(jnp.where(p.active, p.position[:, 1] + p.radius, ground)), ground)
        position = jnp.stack([ps.drop_x[index], top + drop_height + p.radius[index]]).astype(dtype)
        state = activate(state, index, position, when=due)
        return state.set(protocol_state=DropState(
            drop_x=ps.drop_x,
            last_insert=jnp.where(due, state.step, ps.last_insert),
            quiet_steps=jnp.where(due, 0, quiet).astype(ps.quiet_steps.dtype),
            inserted=ps.inserted + due.astype(ps.inserted.dtype),
            forced=ps.forced + (due & ~settled).astype(ps.forced.dtype),
        ))

    return driver


def make_in_play(quiet_steps: int):
    """Host-side `(state, steps) -> m` for `Simulator(in_play=...)`: no disk past
    the first m can be in play during the next `steps` steps. Disks are dropped
    in index order (the first parked one next), at most one at once and then
    one every `quiet_steps` (the quiet count restarts at each drop, and the
    forced drops wait longer): the active ones plus 1 + (steps - 1) //
    quiet_steps. Each chunk then runs on the block of leading disks that holds
    them (`jaxpile.engine.blocks`)."""
    gap = max(int(quiet_steps), 1)

    def in_play(state: SimState, steps: int) -> int:
        active = int(np.asarray(state.particles.active).sum())
        return min(state.particles.count, active + 1 + (max(int(steps), 1) - 1) // gap)

    return in_play


def driver_setting(o: DropOptions, dt: float) -> dict:
    """The drop driver's constants (`make_driver`'s keywords) for the options
    `o` and the time step `dt`: the same for every seed and every n."""
    diameter, drop_height = float(o.diameter), float(o.drop_height)
    quiet_steps = _steps("quiet_time", o.quiet_time, dt)
    max_interval_steps = _steps("max_interval", o.max_interval, dt)
    if max_interval_steps <= quiet_steps:
        raise InputError(f"max_interval ({o.max_interval}) must be longer than quiet_time ({o.quiet_time}): "
                         f"at dt = {dt:g} both are {quiet_steps} steps.")
    return {"drop_height": drop_height * diameter, "settle_speed": float(o.settle_speed), "quiet_steps": quiet_steps,
            "max_interval_steps": max_interval_steps}


def setup(o: DropOptions, *, law, seed: int, dt: float, dtype=None) -> Setup:
    """The 1992 Fig. 20 drop pile: `o.n` equal disks dropped one by one on the ground.

    `seed` draws each disk's lateral offset, uniform in +-`jitter`; `dt`
    turns `quiet_time` and `max_interval` into steps. The set-up is the same
    for every law.

    Returns:
      `Setup` with every disk parked inactive, the drop driver and its
      `DropState`, the neighbour-list box and `info` (counts, axis, step rules, dt).
    """
    n = o.n
    budget.check(n, dtype or "float64", what="a drop")  # before any array is allocated
    rule = driver_setting(o, dt)
    diameter, drop_height = float(o.diameter), float(o.drop_height)
    jitter = float(o.jitter) + 0.0  # -0.0 (inside [0, 1)) as +0.0: numpy's uniform(0.0, -0.0) refuses "high < low"
    axis, parked, box = layout(n, diameter, drop_height)
    particles = make_particles(parked, 0.5 * diameter, mass=o.mass, active=np.zeros(n, bool), dtype=dtype)
    dtype = particles.position.dtype
    rng = np.random.default_rng(int(seed))  # a whole float (0.0) passes the range check
    drop_x = axis + diameter * rng.uniform(-jitter, jitter, n)
    state = DropState(
        drop_x=jnp.asarray(drop_x, dtype),
        last_insert=jnp.asarray(-rule["max_interval_steps"], jnp.int32),
        quiet_steps=jnp.asarray(rule["quiet_steps"], jnp.int32),  # the first disk drops at once
        inserted=jnp.asarray(0, jnp.int32),
        forced=jnp.asarray(0, jnp.int32),
    )
    info = {
        "n_particles": n,
        "axis_x": axis,
        "drop_height": drop_height,
        "jitter": jitter,
        "seed": int(seed),
        "settle_speed": rule["settle_speed"],
        "quiet_steps": rule["quiet_steps"],
        "max_interval_steps": rule["max_interval_steps"],
        "dt": float(dt),
    }
    return Setup(particles=particles, boundaries=make_boundaries(dtype=dtype), driver=make_driver(**rule),
                 protocol_state=state, box=box, info=info)


LAW_SETTING = Setting(law="liffman", params=SETTING["params"], dt=SETTING["dt"], rotation=SETTING["rotation"])
"""The drop's laws: the 1992 setting, disks that do not spin."""
law_and_params = LAW_SETTING.law_and_params


def simulator(o: DropOptions, *, law, dt: float, rotation=None, integrator=None, chunk_steps=None, law_options=None):
    """A `Simulator` running the drop driver of the options `o` (its constants
    are the same for every seed and every n), velocity Verlet unless another
    integrator is given, with the options' `hard_collisions`, each chunk on the
    block of disks dropped by its end."""
    from jaxpile.engine.simulate import Simulator

    _, contact_law, _ = law_and_params(law, None, rotation, law_options=law_options)
    rule = driver_setting(o, dt)
    extra = {} if chunk_steps is None else {"chunk_steps": chunk_steps}
    # the list is allocated with the disks parked apart and sized for the pile (`packed_lists`)
    return Simulator(contact_law, dt, driver=make_driver(**rule), integrator=integrator or "velocity_verlet",
                     hard_collisions=o.hard_collisions, in_play=make_in_play(rule["quiet_steps"]), **extra)


def measure_pile(sim, params, state: SimState, p: Setup, o: DropOptions) -> dict:
    """`measure` with the options' bins and threshold, and the pile's counts,
    seed and speed (a sweep row's too): `n_particles` dropped of `n_requested`,
    `forced_drops` released before the pile was quiet."""
    from jaxpile.engine.simulate import max_speed

    active = np.asarray(state.particles.active)
    return {"law": sim.law.name, "n_particles": int(active.sum()), "n_requested": int(p.info["n_particles"]),
            "all_inserted": bool(active.all()), "seed": p.info["seed"], "forced_drops": int(state.protocol_state.forced),
            "max_speed": float(max_speed(state)),
            **measure(sim, params, state, bins=o.bins, dip_threshold=o.dip_threshold)}


def phases(p: Setup, o: DropOptions) -> tuple[Phase, ...]:
    """The fill (until every disk is in, within every drop at its longest wait
    and a chunk's slack), then the relaxation until the fastest disk is below
    `speed_tolerance`, within `relax_steps`."""
    from jaxpile.engine.simulate import max_speed

    tolerance = float(o.speed_tolerance)
    fill = int(p.info["n_particles"]) * int(p.info["max_interval_steps"]) + 1000
    return (Phase("fill", fill, lambda s: jnp.all(s.particles.active)),
            Phase("relax", int(o.relax_steps), lambda s: max_speed(s) < tolerance))


ROW_COLUMNS = ("all_inserted", "max_speed", "base_contacts", "total_normal", "weight_balance", "total_horizontal",
               "height", "base_width", "centre_x", "central_dip", "has_central_dip", "repose_angle_left",
               "repose_angle_right")
"""Every key a `row` may hold (a pile too small for a base profile has no `base_width` to `has_central_dip`)."""


_NOT_IN_ROW = ("n_particles", "n_requested", "seed", "forced_drops")
"""The pile's counts and settings: a batch's member columns say them."""


def row(m: dict) -> dict:
    """A sweep row: the measurements' plain numbers and flags."""
    return {k: v for k, v in m.items() if np.ndim(v) == 0 and not isinstance(v, str) and k not in _NOT_IN_ROW}


SPEC = ProtocolSpec(
    name="drop", options=DropOptions, setting=LAW_SETTING, setup=setup, simulator=simulator,
    phases=phases, measure=measure_pile)
"""The drop (Liffman, Chan & Hughes 1992, Fig. 20): `SPEC.run("liffman", 968)` drops the disks one at a time,
relaxes the pile to rest and measures its base normal force profile, its central dip and its flanks."""


__all__ = ["PARK_SPACING", "ROW_COLUMNS", "SETTING", "SPEC", "DropOptions", "DropState", "driver_setting",
           "law_and_params", "layout", "make_driver", "make_in_play",
           "measure_pile", "phases", "row", "setup", "simulator"]
