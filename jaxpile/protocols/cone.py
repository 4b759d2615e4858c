"""A conical heap of spheres poured onto a rough plate: the three-dimensional
experiment of Smid & Novosad (1981) that Liffman, Chan & Hughes 1992 call their
2D pile "a two dimensional analogue" of.

* The base: fixed spheres of diameter sigma on a triangular lattice `spacing`
  apart (1.1 sigma: a rough plate, as the 1997 pour's row), centres at
  z = sigma / 2, out to `base_radius` from the axis (default: room for a
  20-degree cone of the spheres poured); no wall is active, so a sphere that
  rolls off the plate falls and is taken out of play.
* The source: spheres released one every `interval` at x, y uniform over a disk
  of radius `source_radius` about the axis (a narrow funnel), at rest from
  `release_height` above the plate, appearing lower (`insert_height`, by
  default just above the steepest cone they could build) with the speed of
  that fall, as the 1997 pour's shortcut: they hit the heap as if released
  from there.
* Monodisperse, or diameters uniform in ((1 - delta) sigma, sigma); masses go as
  the volume (diameter sigma: mass 1).
* Then left to come to rest (every sphere slower than `speed_tolerance`).

The pouring driver is the 1997 pour's (`drivers.pouring`): every sphere exists
from the start, parked inactive on a grid above the source, and is released in
turn inside the compiled loop. Measurements: `jaxpile.measure.cone_heap` (the
azimuthally averaged surface and its angle of repose, the radial base pressure
p(r) and its central dip, the core's packing fraction).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import jax.numpy as jnp
import numpy as np

from jaxpile import budget, ranges
from jaxpile.engine.boundaries import make_boundaries, set_wall, GROUND, LEFT_WALL, RIGHT_WALL, FRONT_WALL, BACK_WALL
from jaxpile.engine.state import make_particles
from jaxpile.errors import InputError
from jaxpile.measure import cone_heap
from jaxpile.protocols import drivers, geometry
from jaxpile.protocols.base import Setting, Setup
from jaxpile.protocols.spec import Options, ProtocolSpec, option
from jaxpile.protocols.stages import Phase
from jaxpile.ranges import SIZE, SPAN, SPEED, SPHERES, STEPS, Range

PARK_SPACING = 2.5
"""Distance between parked spheres (sigma): beyond any law's reach plus skin."""

LOST_DEPTH = 1.5
"""A sphere whose centre falls this far (sigma) below the plate's centres has left the plate."""

MIN_RELEASE_GAP = 1.25
"""The least height (sigma) between a sphere just released and the one before (as the 1997 pour's)."""

PACKING = 0.6
"""The packing fraction the default plate and release height are sized with (a random loose packing)."""

SETTING = {
    "n": 1000,
    "spacing": 1.1,
    "source_radius": 1.0,
    "release_height": 30.0,
    "interval": 0.5,
    "dt": 5.0e-4,
    "speed_tolerance": 1.0e-3,
    "max_settle_steps": 400_000,
    "params": {
        # k_n = 2e4 mg / sigma (an overlap of 5e-5 sigma under one sphere's weight), gamma_n = 100 / time
        # (a quarter of critical for two equal spheres: restitution about 0.45), mu = 0.5, LAMMPS's
        # k_t = 2 k_n / 7 and gamma_t = gamma_n / 2; with rolling resistance a rolling spring of k_n / 4
        "hooke": {"kn": 2.0e4, "gamma_n": 100.0, "mu": 0.5},
    },
}


def cone_volume_radius(n: int, angle_degrees: float) -> float:
    """The base radius of a cone of n unit spheres at `angle_degrees` (packing `PACKING`)."""
    volume = n * (math.pi / 6.0) / PACKING
    return (3.0 * volume / (math.pi * math.tan(math.radians(angle_degrees)))) ** (1.0 / 3.0)


@dataclass(frozen=True)
class ConeOptions(Options):
    """The cone's options, in sigma (the largest diameter) and (sigma / g)^(1/2)."""

    n: int = option(SETTING["n"], range=SPHERES, help="spheres to pour")
    spacing: float = option(SETTING["spacing"], range=Range(low=1, high=2, high_open=True,
                                                            why="S >= one diameter, the gap narrower than a sphere"),
                            unit="sigma", help="the plate's spheres, centre to centre on a triangular lattice")
    base_radius: float | None = option(None, range=SIZE, unit="sigma",
                                       help="the plate's radius; default: room for a 20-degree cone plus 3 sigma")
    source_radius: float = option(SETTING["source_radius"], range=SPAN, unit="sigma",
                                  help="release x, y uniform over a disk this wide about the axis (the funnel)")
    release_height: float = option(SETTING["release_height"], range=SIZE, unit="sigma",
                                   help="where spheres start at rest, above the plate's centres")
    insert_height: float | None = option(None, range=SIZE, unit="sigma",
                                         help="a lower height where spheres appear at the free-fall speed from "
                                              "release_height; default and least: a 45-degree cone + 3 sigma")
    interval: float = option(SETTING["interval"], range=SIZE, unit="sqrt(sigma/g)", help="time between releases")
    polydispersity: float = option(0.0, range=Range(low=0, high=0.5, high_open=True, why="a fraction: 0.05 for 5%"),
                                   help="delta: diameters uniform in ((1 - delta) sigma, sigma)")
    speed_tolerance: float = option(SETTING["speed_tolerance"], range=SPEED, unit="sqrt(g sigma)",
                                    help="after pouring, at rest once every sphere is slower than this")
    max_settle_steps: int = option(SETTING["max_settle_steps"], range=STEPS, help="step budget of the settling")
    rings: int = option(10, range=Range(low=3, whole=True), help="annuli of the base pressure p(r)")

    def validate(self):
        if not (1.0 <= self.spacing < 2.0 - self.polydispersity):
            raise InputError(f"spacing must be at least one diameter and leave a gap narrower than the smallest "
                             f"sphere: 1 <= spacing < {2.0 - self.polydispersity:g}; got {self.spacing!r}.")


def steepest_cone_height(n: int) -> float:
    """The height of a 45-degree cone of n unit spheres: release starts above it."""
    return cone_volume_radius(n, 45.0)


def setup(o: ConeOptions, *, law, seed: int, dt: float, dtype=None) -> Setup:
    """The cone's set-up: the plate (fixed spheres `0 .. m-1`), then `o.n`
    spheres to pour in release order. The axis is x = y = 0; heights are
    measured from the plate's centres z = sigma / 2 (`info["base_z"]`).

    Raises:
      InputError: on heights below the steepest cone of n spheres, an interval
        too short for that dt, or a pile too big for the machine.
    """
    n = o.n
    budget.check(2 * n, dtype or "float64", what="a cone (with its plate)")
    interval_steps = ranges.steps_of("interval", o.interval, dt)
    lowest = steepest_cone_height(n) + 3.0
    if not o.release_height >= lowest:
        raise InputError(f"release_height must be at least {lowest:.1f} sigma for {n} spheres (a 45-degree cone "
                         f"plus 3 sigma); got {o.release_height!r}.")
    insert_height = lowest if o.insert_height is None else o.insert_height  # default: the fall's last part
    if not lowest <= insert_height <= o.release_height:
        raise InputError(f"insert_height must lie between {lowest:.1f} sigma (above a 45-degree cone of {n} spheres) "
                         f"and release_height = {o.release_height:g}; got {insert_height!r}.")
    speed = math.sqrt(2.0 * (o.release_height - insert_height))
    gap = speed * interval_steps * dt + 0.5 * (interval_steps * dt) ** 2
    if gap < MIN_RELEASE_GAP:
        raise InputError(f"interval {o.interval!r} is too short: when a sphere is released the previous one is only "
                         f"{gap:.2f} sigma below it and they could touch in the air; leave at least "
                         f"{MIN_RELEASE_GAP} sigma (a lower insert_height gives the spheres speed, and room).")
    radius = cone_volume_radius(n, 20.0) + 3.0 if o.base_radius is None else float(o.base_radius)
    base = geometry.plate(o.spacing, radius)
    rows = len(base)
    budget.check(n + rows, dtype or "float64", what="a cone with its plate")

    rng = np.random.default_rng(int(seed))
    diameter = 1.0 - o.polydispersity * rng.uniform(0.0, 1.0, n) if o.polydispersity > 0 else np.ones(n)
    base_z = 0.5
    angle = rng.uniform(0.0, 2.0 * math.pi, n)
    reach = float(o.source_radius) * np.sqrt(rng.uniform(0.0, 1.0, n))  # uniform over the disk
    drop = np.stack([reach * np.cos(angle), reach * np.sin(angle), np.full(n, base_z + insert_height)], 1)

    side = max(2, int(math.ceil(n ** (1.0 / 3.0))))
    k = np.arange(n)
    park = np.stack([PARK_SPACING * (k % side - 0.5 * (side - 1)), PARK_SPACING * ((k // side) % side - 0.5 * (side - 1)),
                     base_z + o.release_height + 2.0 * PARK_SPACING + PARK_SPACING * (k // (side * side))], 1)
    position = np.concatenate([np.concatenate([base, np.full((rows, 1), base_z)], 1), park])
    size = np.concatenate([np.full(rows, 0.5), 0.5 * diameter])
    fixed = np.arange(rows + n) < rows
    particles = make_particles(position, size, fixed=fixed, active=fixed, dtype=dtype)
    dtype = particles.position.dtype
    boundaries = make_boundaries(dim=3, dtype=dtype)
    for wall in (GROUND, LEFT_WALL, RIGHT_WALL, FRONT_WALL, BACK_WALL):
        boundaries = set_wall(boundaries, wall, active=False)
    release = np.concatenate([np.zeros((rows, 3)), drop])
    state = drivers.Pouring(
        poured=jnp.asarray(0, jnp.int32), total=jnp.asarray(n, jnp.int32), first=jnp.asarray(rows, jnp.int32),
        interval=jnp.asarray(interval_steps, jnp.int32), release_position=jnp.asarray(release, dtype),
        release_velocity=jnp.asarray([0.0, 0.0, -speed], dtype), park_position=jnp.asarray(position, dtype),
        lost=jnp.zeros(rows + n, bool), lost_below=jnp.asarray(base_z - LOST_DEPTH, dtype),
        ends=jnp.asarray((-math.inf, math.inf), dtype))
    info = {"protocol": "cone", "n_poured": n, "n_base": rows, "base_radius": radius, "spacing": float(o.spacing),
            "source_radius": float(o.source_radius), "base_z": base_z, "release_height": float(o.release_height),
            "insert_height": float(insert_height), "insert_speed": speed, "interval": interval_steps * dt,
            "interval_steps": interval_steps, "dt": float(dt), "pour_steps": n * interval_steps,
            "polydispersity": float(o.polydispersity), "seed": int(seed)}
    return Setup(particles=particles, boundaries=boundaries, driver=drivers.pouring, protocol_state=state, info=info)


LAW_SETTING = Setting(law="hooke", params=SETTING["params"], dt=SETTING["dt"])
"""The cone's laws: hooke (with or without rolling resistance); the paper laws are for disks."""
law_and_params = LAW_SETTING.law_and_params


def simulator(o: ConeOptions, *, law, dt: float, rotation=None, integrator=None, chunk_steps=None, law_options=None):
    """A `Simulator` running the pouring driver with `law` (velocity Verlet
    unless another integrator is given), each chunk on the spheres poured by
    its end (`drivers.poured_in_play`)."""
    from jaxpile.engine.simulate import Simulator
    from jaxpile.laws import get_law_module

    options = dict(law_options or {})
    if rotation is not None:
        options["rotation"] = rotation
    return Simulator(get_law_module(law).law(**options), dt, integrator=integrator or "velocity_verlet",
                     driver=drivers.pouring, in_play=drivers.poured_in_play,
                     chunk_steps=2000 if chunk_steps is None else chunk_steps)


def phases(p: Setup, o: ConeOptions) -> tuple[Phase, ...]:
    """Every sphere poured, then a run until the fastest is below `speed_tolerance`."""
    from jaxpile.engine.simulate import max_speed

    tolerance = float(o.speed_tolerance)
    return (Phase("pour", int(p.info["pour_steps"])),
            Phase("settle", int(o.max_settle_steps), lambda s: max_speed(s) < tolerance))


def measure(sim, params, state, p: Setup, o: ConeOptions) -> dict:
    """`cone_heap.measure` about the axis, with the options' rings."""
    return cone_heap.measure(sim, params, state, axis=(0.0, 0.0), rings=o.rings)


SPEC = ProtocolSpec(name="cone", options=ConeOptions, setting=LAW_SETTING, setup=setup, simulator=simulator,
                    phases=phases, measure=measure)
"""The cone: `SPEC.run("hooke", 1000)` pours spheres from a narrow source onto a rough plate, lets the heap rest,
and measures its angle of repose, base pressure p(r) and dip."""


__all__ = ["ConeOptions", "LAW_SETTING", "SETTING", "SPEC", "cone_volume_radius", "law_and_params", "measure",
           "phases", "setup", "simulator", "steepest_cone_height"]
