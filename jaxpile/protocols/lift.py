"""The cylinder lift: the standard 3D calibration test of DEM users. A
cylinder standing on a rough plate is filled with spheres, the spheres settle,
the cylinder is raised, and the heap the spheres leave behind gives the angle
of repose, which is what a calibration of mu and mu_r reads.

* The plate: fixed spheres on a triangular lattice `spacing` apart out to
  `plate_radius` (default: room for the heap at 15 degrees), as the cone's.
* The cylinder: fixed spheres in rings, `cylinder_radius` from the axis to
  their centres, touching along each ring and stacked ring on ring up to the
  fill's height; rough inside, as a real tube's wall of grains is not, but
  every law's wall contact is a plane, and a ring of spheres needs no new one.
* The fill: `n` spheres on a jittered grid inside the cylinder, dropped from
  rest, settled until slower than `speed_tolerance` (phase "fill").
* The lift (phase "lift"): the driver raises the cylinder's spheres at
  `lift_speed`, moving them itself (fixed spheres are never integrated) and
  giving them that velocity, which their contacts see, until its bottom
  clears the highest sphere by a diameter (or `lift_height`).
* Then the heap settles (phase "settle"). Measured as the cone is
  (`jaxpile.measure.cone_heap`): the angle from the azimuthally averaged
  surface, atan(h / R), the base pressure and the packing fraction.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, NamedTuple

import jax.numpy as jnp
import numpy as np

from jaxpile import budget
from jaxpile.engine.boundaries import BACK_WALL, FRONT_WALL, GROUND, LEFT_WALL, RIGHT_WALL, make_boundaries, set_wall
from jaxpile.engine.state import SimState, make_particles
from jaxpile.errors import InputError
from jaxpile.measure import cone_heap
from jaxpile.protocols import geometry
from jaxpile.protocols.base import Setting, Setup
from jaxpile.protocols.spec import Options, ProtocolSpec, option
from jaxpile.protocols.stages import Phase
from jaxpile.ranges import SIZE, SPEED, SPHERES, STEPS, Range

Array = Any

SETTING = {
    "n": 500,
    "cylinder_radius": 4.0,
    "lift_speed": 0.2,
    "dt": 5.0e-4,
    "speed_tolerance": 1.0e-3,
    "max_fill_steps": 200_000,
    "max_settle_steps": 400_000,
    "params": {"hooke": {"kn": 2.0e4, "gamma_n": 100.0, "mu": 0.5}},  # the cone's
}

FILL_PACKING = 0.35
"""The loose packing of the jittered grid the fill starts from (its spheres 0.1 sigma apart at least)."""


@dataclass(frozen=True)
class LiftOptions(Options):
    """The lift's options, in sigma (the largest diameter) and (sigma / g)^(1/2)."""

    n: int = option(SETTING["n"], range=SPHERES, help="spheres to fill the cylinder with")
    cylinder_radius: float = option(SETTING["cylinder_radius"], range=Range(low=1.5, unit="sigma"),
                                    unit="sigma", help="from the axis to the centres of the cylinder's spheres")
    spacing: float = option(1.1, range=Range(low=1, high=2, high_open=True, why="S >= one diameter"), unit="sigma",
                            help="the plate's spheres, centre to centre on a triangular lattice")
    plate_radius: float | None = option(None, range=SIZE, unit="sigma",
                                        help="the plate's radius; default: room for the heap at 15 degrees")
    lift_speed: float = option(SETTING["lift_speed"], range=SPEED, unit="sqrt(g sigma)",
                               help="how fast the cylinder rises")
    lift_height: float | None = option(None, range=SIZE, unit="sigma",
                                       help="how far it rises; default: until its bottom clears the spheres by 1 sigma")
    polydispersity: float = option(0.0, range=Range(low=0, high=0.5, high_open=True, why="a fraction: 0.05 for 5%"),
                                   help="delta: diameters uniform in ((1 - delta) sigma, sigma)")
    speed_tolerance: float = option(SETTING["speed_tolerance"], range=SPEED, unit="sqrt(g sigma)",
                                    help="at rest once every sphere is slower than this (after the fill, at the end)")
    max_fill_steps: int = option(SETTING["max_fill_steps"], range=STEPS, help="step budget of the fill's settling")
    max_settle_steps: int = option(SETTING["max_settle_steps"], range=STEPS, help="step budget after the lift")
    rings: int = option(10, range=Range(low=3, whole=True), help="annuli of the base pressure p(r)")


class LiftState(NamedTuple):
    """What the lifting driver carries (`SimState.protocol_state`).

    Attributes:
      wall: `[n]` bool, the cylinder's spheres.
      tolerance: the fill is at rest once every sphere is slower than this.
      armed: bool, the fill has moved (faster than 10 tolerances): its rest is the settling's end, not the start.
      started_at: int, the step the lift began (-1 before).
      latest_start: int, the step the lift begins even if the fill never rests (its step budget).
      risen: how far the cylinder has risen; height: how far it rises at most
        (inf: until its bottom clears the highest sphere by a diameter).
      done: bool, the lift is over.
      step_rise: speed * dt; speed: the lift's speed.
      park_position: `[n, 3]` where a sphere that fell off the plate is parked.
      lost_below: the height below which a sphere has left the plate.
      poured: the spheres filled in (all, from the start); lost: `[n]` bool, those that fell off.
    """

    wall: Array
    tolerance: Array
    armed: Array
    started_at: Array
    latest_start: Array
    risen: Array
    height: Array
    done: Array
    step_rise: Array
    speed: Array
    park_position: Array
    lost_below: Array
    poured: Array
    lost: Array


def driver(state: SimState) -> SimState:
    """Once the fill has moved and come to rest (or its step budget is spent),
    raises the cylinder's spheres by `step_rise` a step, with the lift's
    velocity (their contacts see the wall move), until it has risen `height`;
    a sphere that falls off the plate is parked and counted lost."""
    ls: LiftState = state.protocol_state
    p = state.particles
    fell = p.active & ~p.fixed & (p.position[:, -1] < ls.lost_below)
    state = geometry.park_where(state, fell, ls.park_position)
    p = state.particles
    speed = jnp.max(jnp.where(p.movable, jnp.linalg.norm(p.velocity, axis=-1), 0.0), initial=0.0)
    armed = ls.armed | (speed > 10.0 * ls.tolerance)
    start = (ls.started_at < 0) & ((armed & (speed < ls.tolerance)) | (state.step >= ls.latest_start))
    started_at = jnp.where(start, state.step, ls.started_at)
    top = jnp.max(jnp.where(p.movable, p.position[:, -1] + p.radius, -jnp.inf), initial=-jnp.inf)
    cleared = ls.risen > top - ls.lost_below - 1.0  # lost_below + 2 is the wall's bottom at the start
    lifting = (started_at >= 0) & ~ls.done & (ls.risen < ls.height) & ~cleared
    rise = jnp.where(lifting, jnp.minimum(ls.step_rise, ls.height - ls.risen), 0.0)
    done = ls.done | ((started_at >= 0) & ~lifting)
    up = jnp.zeros(p.dim, p.position.dtype).at[-1].set(1.0)
    moving = ls.wall[:, None]
    p = p.set(position=jnp.where(moving, p.position + rise * up, p.position),
              velocity=jnp.where(moving, jnp.where(lifting, ls.speed, 0.0) * up, p.velocity))
    return state.set(particles=p, protocol_state=ls._replace(armed=armed, started_at=started_at, done=done,
                                                             risen=ls.risen + rise, lost=ls.lost | fell))


def cylinder(radius: float, bottom: float, height: float) -> np.ndarray:
    """`[m, 3]` unit spheres in touching rings `radius` from the axis, each ring
    turned half a sphere from the one below (no hole a sphere passes), stacked
    from `bottom` (the lowest centres) to `height`."""
    per_ring = max(6, int(math.floor(2.0 * math.pi * radius)))
    rings = max(1, int(math.ceil((height - bottom) / 0.9)) + 1)
    out = []
    for k in range(rings):
        phase = 0.5 * (k % 2) * 2.0 * math.pi / per_ring
        angle = phase + 2.0 * math.pi * np.arange(per_ring) / per_ring
        out.append(np.stack([radius * np.cos(angle), radius * np.sin(angle), np.full(per_ring, bottom + 0.9 * k)], 1))
    return np.concatenate(out)


def fill(n: int, radius: float, bottom: float, rng) -> np.ndarray:
    """`[n, 3]` centres on a jittered cubic grid within `radius` of the axis from `bottom` up."""
    a = ((math.pi / 6.0) / FILL_PACKING) ** (1.0 / 3.0)
    side = np.arange(-radius, radius + 1e-9, a)
    x, y = np.meshgrid(side, side, indexing="ij")
    layer = np.stack([x.ravel(), y.ravel()], 1)
    layer = layer[np.hypot(layer[:, 0], layer[:, 1]) <= radius]
    if not len(layer):
        raise InputError("the cylinder is too narrow to hold a sphere: give a cylinder_radius of at least 1.5.")
    levels = int(math.ceil(n / len(layer)))
    points = np.concatenate([np.concatenate([layer, np.full((len(layer), 1), bottom + a * k)], 1)
                             for k in range(levels)])[:n]
    return points + rng.uniform(-0.5, 0.5, points.shape) * (a - 1.0) * 0.8


def setup(o: LiftOptions, *, law, seed: int, dt: float, dtype=None) -> Setup:
    """The lift's set-up: the plate (fixed), the cylinder's rings (fixed,
    lifted by the driver), then `o.n` spheres inside it. The axis is x = y = 0;
    heights above the plate's centres z = sigma / 2.

    Raises:
      InputError: for a cylinder too narrow or a pile too big for the machine.
    """
    n = o.n
    budget.check(3 * n, dtype or "float64", what="a cylinder lift (with its plate and cylinder)")
    rng = np.random.default_rng(int(seed))
    base_z = 0.5
    inner = o.cylinder_radius - 1.0  # fill centres a diameter inside the wall's
    if inner < 0.5:
        raise InputError(f"cylinder_radius {o.cylinder_radius!r} leaves no room inside for a sphere; give >= 1.5.")
    diameter = 1.0 - o.polydispersity * rng.uniform(0.0, 1.0, n) if o.polydispersity > 0 else np.ones(n)
    inside = fill(n, inner, base_z + 1.1, rng)
    top = float(inside[:, 2].max()) + 1.0
    volume = n * (math.pi / 6.0) / 0.6
    radius = (3.0 * volume / (math.pi * math.tan(math.radians(15.0)))) ** (1.0 / 3.0) + 3.0
    radius = max(radius, o.cylinder_radius + 3.0) if o.plate_radius is None else float(o.plate_radius)
    base = geometry.plate(o.spacing, radius)
    tube = cylinder(o.cylinder_radius, base_z + 1.0, top)
    rows, walls = len(base), len(tube)
    budget.check(n + rows + walls, dtype or "float64", what="a cylinder lift")
    position = np.concatenate([np.concatenate([base, np.full((rows, 1), base_z)], 1), tube, inside])
    size = np.concatenate([np.full(rows + walls, 0.5), 0.5 * diameter])
    fixed = np.arange(len(size)) < rows + walls
    particles = make_particles(position, size, fixed=fixed, dtype=dtype)
    dtype = particles.position.dtype
    boundaries = make_boundaries(dim=3, dtype=dtype)
    for wall in (GROUND, LEFT_WALL, RIGHT_WALL, FRONT_WALL, BACK_WALL):
        boundaries = set_wall(boundaries, wall, active=False)
    height = math.inf if o.lift_height is None else float(o.lift_height)
    lift_steps = int(math.ceil((top + 2.0 - (base_z + 0.5) if o.lift_height is None else height) / (o.lift_speed * dt)))
    total = len(size)
    state = LiftState(
        wall=jnp.asarray((np.arange(total) >= rows) & (np.arange(total) < rows + walls)),
        tolerance=jnp.asarray(o.speed_tolerance, dtype), armed=jnp.asarray(False), started_at=jnp.asarray(-1, jnp.int32),
        latest_start=jnp.asarray(o.max_fill_steps, jnp.int32), risen=jnp.asarray(0.0, dtype),
        height=jnp.asarray(height, dtype), done=jnp.asarray(False), step_rise=jnp.asarray(o.lift_speed * dt, dtype),
        speed=jnp.asarray(o.lift_speed, dtype), park_position=jnp.asarray(position, dtype),
        lost_below=jnp.asarray(base_z - 1.5, dtype), poured=jnp.asarray(n, jnp.int32), lost=jnp.zeros(total, bool))
    info = {"protocol": "lift", "n_filled": n, "n_base": rows, "n_cylinder": walls, "plate_radius": radius,
            "cylinder_radius": float(o.cylinder_radius), "fill_top": top, "lift_height": o.lift_height,
            "lift_speed": float(o.lift_speed), "lift_steps": lift_steps, "base_z": base_z, "dt": float(dt),
            "polydispersity": float(o.polydispersity), "seed": int(seed)}
    return Setup(particles=particles, boundaries=boundaries, driver=driver, protocol_state=state, info=info)


LAW_SETTING = Setting(law="hooke", params=SETTING["params"], dt=SETTING["dt"])
"""The lift's laws: hooke, with or without rolling resistance (the cone's)."""
law_and_params = LAW_SETTING.law_and_params


def simulator(o: LiftOptions, *, law, dt: float, rotation=None, integrator=None, chunk_steps=None, law_options=None):
    """A `Simulator` running the lifting driver with `law` (velocity Verlet unless another integrator is given)."""
    from jaxpile.engine.simulate import Simulator
    from jaxpile.laws import get_law_module

    options = dict(law_options or {})
    if rotation is not None:
        options["rotation"] = rotation
    return Simulator(get_law_module(law).law(**options), dt, integrator=integrator or "velocity_verlet",
                     driver=driver, chunk_steps=2000 if chunk_steps is None else chunk_steps)


def phases(p: Setup, o: LiftOptions) -> tuple[Phase, ...]:
    """The fill settling and the lift (the driver starts it), until the
    cylinder has risen; then the heap, until the fastest sphere is below
    `speed_tolerance`."""
    from jaxpile.engine.simulate import max_speed

    tolerance = float(o.speed_tolerance)
    return (Phase("fill and lift", int(o.max_fill_steps) + int(p.info["lift_steps"]) + 1,
                  lambda s: s.protocol_state.done),
            Phase("settle", int(o.max_settle_steps), lambda s: max_speed(s) < tolerance))


def measure(sim, params, state, p: Setup, o: LiftOptions) -> dict:
    """`cone_heap.measure` about the axis, and the step the lift began (`lift_started_at`)."""
    return {**cone_heap.measure(sim, params, state, axis=(0.0, 0.0), rings=o.rings),
            "lift_started_at": int(state.protocol_state.started_at)}


SPEC = ProtocolSpec(name="lift", options=LiftOptions, setting=LAW_SETTING, setup=setup, simulator=simulator,
                    phases=phases, measure=measure)
"""The cylinder lift: `SPEC.run("hooke", 500)` fills a cylinder on a rough plate, lets it settle, raises the
cylinder and measures the heap left behind (its angle of repose, as DEM users calibrate mu and mu_r)."""


__all__ = ["LiftOptions", "LiftState", "SETTING", "SPEC", "cylinder", "driver", "fill", "law_and_params", "measure",
           "phases", "setup", "simulator"]
