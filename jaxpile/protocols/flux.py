"""A pile fed one disk at a time (Lee & Herrmann 1993, sec. 5, Fig. 5).

The paper: "Consider an empty box without a right wall and put one layer of
particles at the bottom. We monitor the maximum velocity of the particles. If
the maximum velocity is smaller than certain value v_cut, then we insert a new
particle at the upper left corner of the pile. Once the particle is added, we
then wait until the maximum velocity of the particles is again smaller than
v_cut, then add a new particle. [...] we show the angle of the pile just before
a new particle is inserted. Here mu = 0.2, W = H = 4.0 and v_cut = 0.1." The
angle rises from zero and then fluctuates; its largest values estimate the
angle of marginal stability theta_MS, above theta_R.

Design (everything inside the compiled loop, fixed shapes):

* The bottom layer: disks with the paper's Gaussian radii side by side on the
  floor from the left wall to x = W, *fixed* (our reading of "one layer of
  particles at the bottom": a rough floor the pile cannot push away;
  `fixed_base=False` makes them ordinary disks).
* A pool of disks waits parked and inactive above the box; disks that pass the
  floor's end (x > W) leave, as in `box`, and are parked back into the pool, so
  a long run needs only as many disks as are ever in play at once (`pool`).
* Insertion (`drivers.when`, a `lax.cond`): once the largest speed has been
  below v_cut (after the last inserted disk moved at all), the first waiting
  disk (`drivers.next_inactive`, `drivers.activate`) is put at rest `gap` above
  the highest disk under it, at a random distance between 0 and `spread` (one
  mean diameter) from the left wall, where the top of the pile is; dropped
  always touching the wall, the disks would stack into a tower against it.
* "The angle of the pile just before a new particle is inserted": just before
  each insertion the driver records the step and the surface h(x) (the highest
  active centre in each column one mean diameter wide, `analysis.surface_profile`)
  in fixed arrays of `FluxState`; the host turns each record into the three
  angles of sec. 3 afterwards (`angles`), so the loop stays free of fits.
* The run ends when every insertion is done and the pile is at rest again.

Units as in `box` (the paper's cm, s for lee-herrmann; reduced, Froude-scaled
units for the other laws). With `lee_herrmann.law(slip="literal")` and the
paper's gamma_s some disk keeps rocking faster than v_cut and the insertions
stop (docs/choices.md#sliding-in-the-1993-law).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxpile import budget, ranges
from jaxpile.engine.boundaries import RIGHT_WALL, make_boundaries, set_wall
from jaxpile.engine.state import SimState, make_particles
from jaxpile.errors import InputError
from jaxpile.measure import analysis
from jaxpile.protocols import drivers, geometry, paper1993
from jaxpile.protocols.base import Setup
from jaxpile.protocols.spec import Options, ProtocolSpec, option
from jaxpile.protocols.stages import one_phase
from jaxpile.ranges import DISKS, SIZE, SPAN, SPEED, Range

Array = Any

SETTING = {
    "width": 4.0,  # W (cm), sec. 5
    "v_cut": 0.1,  # cm/s, sec. 5 (0.01 and 0.001 gave "no essential difference")
    "rest_measure": "max",  # "We monitor the maximum velocity of the particles"
    "hold_time": 0.0,  # insert as soon as the speed is below v_cut
    "gap": 0.01,  # cm between the new disk and the disk below it (5% of a diameter)
    "insertions": 300,  # the paper's angle levels off after ~4e5 iterations (~80 disks here)
    "max_time": 60.0,  # s: give up
    "steepest_slope_degrees": 35.0,  # sizes the default pool
}


@dataclass(frozen=True)
class FluxOptions(Options):
    """The flux pile's options, in the paper's units (cm, cm/s, s), converted
    to the law's units by the set-up (`paper1993.units(law)`)."""

    insertions: int = option(SETTING["insertions"], range=Range(low=1, whole=True, unit="insertions"),
                             help="how many disks to insert")
    width: float = option(SETTING["width"], range=SIZE, unit="cm", help="W, the floor from the left wall to its end")
    pool: int | None = option(None, range=DISKS, help="disks that take turns, those that leave return to it; "
                              "default: min(insertions, pool_size(width))")
    fixed_base: bool = option(True, help="the bottom layer is fixed (off: free disks)")
    radius: dict | None = option(None, help="overrides of the radius distribution (mean, width, low, high)")
    v_cut: float = option(SETTING["v_cut"], range=SPEED, unit="cm/s",
                          help="insert when the speed is below this (0.1 cm/s in the paper)")
    rest_measure: str = option(SETTING["rest_measure"], help="which speed: max (the fastest disk, the paper's) or "
                               "rms (the kinetic energy per disk as a speed)")
    hold_time: float = option(SETTING["hold_time"], range=SPAN, unit="s",
                              help="how long the speed must stay below v_cut (0: one step)")
    gap: float = option(SETTING["gap"], range=SPAN, unit="cm", help="drop height of the new disk above the disk "
                        "under it")
    max_time: float = option(SETTING["max_time"], range=SIZE, unit="s", help="give up after this long")

    def validate(self):
        geometry.check_positive("gap", self.gap)
        paper1993.measure_flag(self.rest_measure)


class FluxState(NamedTuple):
    """What the flux driver carries (`SimState.protocol_state`); scalars unless said.

    Attributes:
      edge, park: the floor's end (W) and the `[n, 2]` parking places.
      v_cut: insertion threshold on the speed (`drivers.motion`).
      use_max: the speed is `max_speed` (True, the paper's) or `drivers.rms_speed`.
      hold: steps the speed must stay below `v_cut` (at least 1).
      fallback: steps after which a pile that never reached `v_cut` counts as at rest.
      quiet, armed: the rest detector (`drivers.rest_detector`).
      gap: height of the new disk's bottom above the disk below it.
      x_min, column_width: the surface columns (`[x_min, x_min + W]`).
      total: insertions to make (int).
      inserted: insertions made so far (int).
      due: an insertion happens at this step (set by the watcher).
      insert_step: `[total]` step of each insertion (-1 before).
      in_play: `[total]` disks in play (movable, active) just before each insertion.
      profile: `[total, c]` h(x) of each column just before each insertion
        (-inf for an empty column).
      left: disks that left past the floor's end (int).
      starved: steps at which an insertion was due but every pool disk was in play (int).
      settled_at: step at which the pile was at rest after the last insertion (-1 before).
    """

    edge: Array
    park: Array
    v_cut: Array
    use_max: Array
    hold: Array
    fallback: Array
    quiet: Array
    armed: Array
    gap: Array
    spread: Array
    key: Array
    x_min: Array
    column_width: Array
    total: Array
    inserted: Array
    due: Array
    insert_step: Array
    in_play: Array
    profile: Array
    left: Array
    starved: Array
    settled_at: Array


def column_heights(state: SimState, x_min, column_width, columns: int) -> Array:
    """`[columns]` the highest active centre in each column of `[x_min, x_min +
    columns * column_width)` (`analysis.surface_profile`'s h(x)), -inf if empty."""
    p = state.particles
    column = jnp.floor((p.position[:, 0] - x_min) / column_width).astype(jnp.int32)
    counted = p.active & (column >= 0) & (column < columns)
    height = jnp.where(counted, p.position[:, 1], -jnp.inf)
    return jax.ops.segment_max(height, jnp.where(counted, column, 0), num_segments=columns)


def _watch(state: SimState) -> SimState:
    """Outflow, the rest detector, and whether to insert now / whether the run is over."""
    ps: FluxState = state.protocol_state
    state, gone = geometry.take_out(state, ps.edge, ps.park)
    quiet, armed, rested = drivers.rest_detector(drivers.motion(state, ps.use_max), ps.v_cut, ps.quiet, ps.armed,
                                               ps.hold, ps.fallback)
    _, available = drivers.next_inactive(state)
    want = rested & (ps.inserted < ps.total)
    done = rested & (ps.inserted >= ps.total) & (ps.settled_at < 0)
    ps = ps._replace(quiet=quiet, armed=armed, due=want & available, left=ps.left + gone,
                     starved=ps.starved + (want & ~available).astype(ps.starved.dtype),
                     settled_at=jnp.where(done, state.step, ps.settled_at))
    return state.set(protocol_state=ps)


def _insert(state: SimState) -> SimState:
    """Records the surface, then puts the next waiting disk at the upper left of the pile."""
    ps: FluxState = state.protocol_state
    p = state.particles
    index, _ = drivers.next_inactive(state)
    k = jnp.minimum(ps.inserted, ps.total - 1)
    heights = column_heights(state, ps.x_min, ps.column_width, ps.profile.shape[1])
    r = p.radius[index]
    key, draw = jax.random.split(ps.key)
    x = ps.x_min + r * (1.0 + 1e-6) + ps.spread * jax.random.uniform(draw, (), r.dtype)
    under = p.active & (jnp.abs(p.position[:, 0] - x) < p.radius + r)
    top = jnp.max(jnp.where(under, p.position[:, 1] + p.radius, 0.0))
    y = top + ps.gap + r
    state = drivers.activate(state, index, jnp.stack([x, y]))
    p = state.particles
    hit = jnp.arange(p.count) == index
    # the first half kick of velocity Verlet is the free fall's
    p = p.set(force=jnp.where(hit[:, None], p.mass[:, None] * state.boundaries.gravity[None, :], p.force))
    in_play = jnp.sum(p.movable) - 1  # before this insertion
    record = jnp.arange(ps.insert_step.shape[0]) == k
    ps = ps._replace(
        key=key,
        inserted=ps.inserted + 1,
        # selects, not scatters: in a batch XLA:CPU fuses two scatters at the same index into one
        # multi-output fusion, which its emitters abort on (the commands turn that fusion on)
        insert_step=jnp.where(record, state.step, ps.insert_step),
        in_play=jnp.where(record, in_play.astype(ps.in_play.dtype), ps.in_play),
        profile=ps.profile.at[k].set(heights),
        quiet=jnp.zeros_like(ps.quiet),
        armed=jnp.zeros_like(ps.armed),
        due=jnp.zeros_like(ps.due),
    )
    return state.set(particles=p, protocol_state=ps)


driver = drivers.compose(_watch, drivers.when(lambda s: s.protocol_state.due, _insert))
"""The flux driver (before every step, inside the compiled loop): `_watch`, then
`_insert` under a `lax.cond` on the steps where an insertion is due."""


def pool_size(width: float, *, slope_degrees: float = SETTING["steepest_slope_degrees"],
              radius: dict | None = None, packing_fraction: float = 0.82) -> int:
    """Disks enough for a pile of slope `slope_degrees` on a floor of width W
    leaning on the left wall (triangle W^2 tan / 2 at `packing_fraction`), plus half
    again for disks rolling down and out (the paper's units)."""
    width = geometry.check_positive("width", width)
    if not 0 < slope_degrees < 90:
        raise InputError(f"slope_degrees must be in (0, 90); got {slope_degrees!r}.")
    area = 0.5 * width**2 * math.tan(math.radians(slope_degrees))
    disk = math.pi * paper1993.mean_square_radius(*paper1993.radius_law(radius))
    return math.ceil(1.5 * packing_fraction * area / disk) + 10


def base_layer(radius, width: float) -> np.ndarray:
    """`[m]` x of disks with the given radii laid side by side on the floor from
    x = 0, as many as fit in [0, width] (m <= len(radius))."""
    right, out = 0.0, []
    for r in np.asarray(radius, dtype=np.float64):
        centre = right + r
        if centre + r > width:
            break
        out.append(centre)
        right = centre + r
    return np.asarray(out)


def setup(o: FluxOptions, *, law, seed: int, dt: float, dtype=None) -> Setup:
    """The constant-flux pile of Lee & Herrmann 1993, Fig. 5, ready to run with `driver`.

    Lengths, speeds and times in the paper's units (cm, cm/s, s), converted with
    `paper1993.units(law)`; `dt` turns `hold_time` into steps and `seed` draws
    the radii and the drop positions.

    Returns:
      `Setup` with `driver` and a `FluxState`: the base layer first
      (`info["n_base"]` disks), then the pool, parked and inactive, then
      padding for the floor disks that did not fit (`info["spare"]`), parked,
      fixed and never used, so that the disk count (`info["n"]`) depends on
      the options alone, not on the seed; the right wall is off.

    Raises:
      InputError: on a floor narrower than the largest disk, or a pile too
        large for memory.
    """
    insertions, width, v_cut, gap, hold_time = o.insertions, o.width, o.v_cut, o.gap, o.hold_time
    fixed_base, radius, rest_measure = o.fixed_base, o.radius, o.rest_measure
    u = paper1993.units(law)
    mean, spread, low, high = paper1993.radius_law(radius)
    if 2 * high > width:
        raise InputError(f"the floor (W = {width:g}) is narrower than the largest disk ({2 * high:g}).")
    base_count = int(width / (2 * low)) + 2  # the fixed floor's disks, drawn before the row is laid
    budget.check(base_count, dtype or "float64", what="a flux pile's floor")
    pool = min(insertions, pool_size(width, radius=radius)) if o.pool is None else o.pool
    # each insertion keeps a record of the surface (a few hundred bytes): counted as one disk more
    budget.check(base_count + pool + insertions, dtype or "float64",
                 what="a flux pile's floor, pool and insertion records")

    rng = np.random.default_rng(int(seed))  # a whole float (0.0) passes the range check
    base_radius = paper1993.gaussian_radii(base_count, rng, mean=mean, width=spread, low=low, high=high)
    base_x = base_layer(base_radius, width)
    m = base_x.size
    pool_radius = paper1993.gaussian_radii(pool, rng, mean=mean, width=spread, low=low, high=high)
    # padding, last, parked, fixed and out of play, so that every seed's set-up holds base_count + pool
    # disks (a batch stacks its members' arrays); sized as the first floor disk, so the largest and
    # smallest radii, which size the neighbour lists, are the disks' in play
    spare = base_count - m

    s = u.scale
    radius_all = np.concatenate([base_radius[:m], pool_radius, np.full(spare, base_radius[0])]) * s
    base = np.stack([base_x, base_radius[:m]], axis=1) * s
    spacing = geometry.PARK_SPACING * 2.0 * high * s
    park = np.concatenate([base, geometry.parking_grid(pool + spare, spacing, (2.0 * width + 4.0 * high) * s,
                                                           spacing)])
    index = np.arange(base_count + pool)
    fixed = (index < m if fixed_base else np.zeros(index.size, bool)) | (index >= m + pool)
    active = index < m
    mass = None if u.sphere_density is None else 4.0 / 3.0 * math.pi * u.sphere_density * radius_all**3
    particles = make_particles(park, radius_all, mass=mass, fixed=fixed, active=active, dtype=dtype)
    dtype = particles.position.dtype
    boundaries = set_wall(make_boundaries(left=0.0, right=width * s, gravity=u.gravity, dtype=dtype),
                          RIGHT_WALL, active=False)

    # columns about a mean diameter wide, from the radius law (not the draws): the same for every seed
    columns = max(1, round(width / (2.0 * paper1993.mean_radius(mean, spread, low, high))))
    hold = ranges.steps_of("hold_time", hold_time * u.time, dt)
    fall_steps = ranges.steps_of("the fall through gap", math.sqrt(2.0 * gap * s / u.gravity), dt, rounding=math.ceil) if gap > 0 else 0
    state = FluxState(
        edge=jnp.asarray(width * s, dtype),
        park=jnp.asarray(park, dtype),
        v_cut=jnp.asarray(v_cut * u.speed, dtype),
        use_max=jnp.asarray(paper1993.measure_flag(rest_measure)),
        hold=jnp.asarray(hold, jnp.int32),
        # saturates at the step counter's limit: no run is longer, so "never" is the same there
        fallback=jnp.asarray(min(max(4 * hold, 10 * fall_steps), ranges.MAX_STEPS), jnp.int32),
        quiet=jnp.asarray(0, jnp.int32),
        armed=jnp.asarray(True),  # the bottom layer starts at rest: insert at once
        gap=jnp.asarray(gap * s, dtype),
        spread=jnp.asarray(2.0 * mean * s, dtype),
        key=jax.random.PRNGKey(int(seed)),
        x_min=jnp.asarray(0.0, dtype),
        column_width=jnp.asarray(width * s / columns, dtype),
        total=jnp.asarray(insertions, jnp.int32),
        inserted=jnp.asarray(0, jnp.int32),
        due=jnp.asarray(False),
        insert_step=jnp.full(insertions, -1, jnp.int32),
        in_play=jnp.zeros(insertions, jnp.int32),
        profile=jnp.full((insertions, columns), -jnp.inf, dtype),
        left=jnp.asarray(0, jnp.int32),
        starved=jnp.asarray(0, jnp.int32),
        settled_at=jnp.asarray(-1, jnp.int32),
    )
    info = {
        "protocol": "flux",
        "law": paper1993.law_name(law),
        "insertions": insertions,
        "n": int(base_count + pool),
        "n_base": int(m),
        "pool": pool,
        "spare": int(spare),
        "fixed_base": bool(fixed_base),
        "width": width * s,
        "length_scale": s,
        "gravity": u.gravity,
        "time_scale": u.time,
        "speed_scale": u.speed,
        "sphere_density": u.sphere_density,
        "v_cut": v_cut * u.speed,
        "rest_measure": rest_measure,
        "hold_steps": hold,
        "gap": gap * s,
        "columns": columns,
        "column_width": width * s / columns,
        "dt": dt,
        "seed": int(seed),
    }
    return Setup(particles=particles, boundaries=boundaries, driver=driver, protocol_state=state,
                 box=geometry.neighbor_box(park, radius_all), info=info)


angles = analysis.recorded_repose_angles  # the angles of each recorded surface (sec. 3's three methods)


simulator = paper1993.simulator_running(driver)
"""The spec's simulator: the flux `driver` with a law by name (`box.make_simulator`)."""


law_and_params = paper1993.law_and_params  # the 1993 setting, shared with `box`


def measure(sim, params, state: SimState, p: Setup, o: FluxOptions) -> dict:
    """Per insertion its `insert_step`, `in_play` and the angle by each method
    (`angle_*`); `steady_*`: the mean and standard deviation of the method-3
    angle over the second half of the insertions (the paper's level and the
    dotted lines of Fig. 5) and its largest value; the final pile's angles
    (`repose_*`) and counts."""
    from jaxpile.measure import theory

    ps = state.protocol_state
    done = int(ps.inserted)
    record = angles(float(ps.x_min), float(ps.column_width), np.asarray(ps.profile)[:done])
    late = np.asarray(record["cumulative_parabola"], dtype=float)[done // 2:]
    late = late[np.isfinite(late)]
    mu = paper1993.friction_coefficient(params)
    nan = float("nan")
    return {
        "law": p.info["law"],
        "mu": mu,
        "inserted": done,
        "insert_step": np.asarray(ps.insert_step)[:done].tolist(),
        "in_play": np.asarray(ps.in_play)[:done].tolist(),
        **{f"angle_{k}": v for k, v in record.items()},
        "steady_mean": float(np.mean(late)) if late.size else nan,
        "steady_std": float(np.std(late)) if late.size else nan,
        "steady_max": float(np.max(late)) if late.size else nan,
        "theta_ms_theory": nan if mu is None else math.degrees(float(theory.marginal_stability_angle(mu))),
        **paper1993.repose(state, p.info["width"]),
        "settled_step": int(ps.settled_at),
        "at_rest": int(ps.settled_at) >= 0,
        "n_left": int(ps.left),
        "starved_steps": int(ps.starved),
        **paper1993.count_check(state),
    }


SPEC = ProtocolSpec(
    name="flux", options=FluxOptions, setting=paper1993.LAW_SETTING, setup=setup, simulator=simulator,
    phases=one_phase(paper1993.settled, paper1993.max_time_budget), measure=measure, size="insertions")
"""The flux pile (Lee & Herrmann 1993, sec. 5): `SPEC.run("lee-herrmann", 300)` feeds the pile 300 disks at the
paper's rule, until it is at rest after the last, and measures the angle before each insertion (Fig. 5)."""


__all__ = [
    "SETTING",
    "SPEC",
    "FluxOptions",
    "FluxState",
    "angles",
    "base_layer",
    "column_heights",
    "driver",
    "law_and_params",
    "measure",
    "pool_size",
    "setup",
    "simulator",
]
