"""The 1993 box pile (Lee & Herrmann 1993, sec. 3 and Fig. 1).

The paper's procedure: "We start by randomly putting N particles in a box of
width W and height H. The particles fall due to gravity, and lose their energy
due to dissipation. After a long time they fill the box with no significant
motion [...] Next, we remove the right wall, let the particles move out of the
box and wait until the system reaches a new equilibrium." The pile left leaning
on the left wall has a finite slope, the angle of repose theta_R, measured on
the surface h(x) (columns one mean diameter wide) by three methods (sec. 3;
`analysis.repose_angles`); the paper keeps method (3). Fig. 1(b) is the kinetic
energy per particle over the whole run.

Everything happens inside one compiled loop with fixed shapes: the `driver`
(run before every step) removes the right wall the first time the filled box
has come to rest (its speed below `rest_speed` for `hold` consecutive steps,
after the disks have first moved), records the step, then detects the final
rest the same way; the host reads a flag and samples the kinetic energy per
disk (Fig. 1(b)) once per chunk.

Reading of the paper, and our choices:

* Radii: Gaussian, mean 0.1, width 0.02, cut off at 0.07 and 0.13 (sec. 4);
  `gaussian_radii` redraws values outside the cut-offs (width = the standard
  deviation).
* N: not printed for W = H = 4. The default (`fill_count`) fills W x H at the
  packing fraction of a random polydisperse packing, 0.82 (the paper's "400
  particle system", "they fill the box"). Disks cannot be placed that densely
  without overlap, so they are placed at random without overlap in the box made
  as tall as an area fraction of `placement_fraction` = 0.4 needs.
* "Move out of the box": the floor ends with the box, at x = W; a disk whose
  centre passes x = W has left: it is taken out of play, parked above the box
  and counted in `BoxState.left` (the total disk count never changes).
* Units. For the lee-herrmann law the run is in the paper's cgs units (W = 4 cm,
  radii ~0.1 cm, g = 981 cm/s^2) with glass spheres (rho = 2.5 g/cm^3, m = 4 pi
  rho a^3 / 3, the law being the 3D Hertz contact), as the paper gives no
  density; k_n = 1e6 then gives a 0.5% overlap under one disk's weight and a
  restitution of about 0.7. The other laws run in reduced units (the paper's
  lengths times 5: mean diameter 1, g = 1, mass 1), the paper's speeds and
  times converted by Froude scaling (speed sqrt(g L), time sqrt(L / g)).
* Laws other than the paper's, with its mu = 0.2 where the law has one and no
  rotation (the paper's disks do not rotate): hooke k_n = 1e4 mg/sigma (0.2%
  overlap under one weight), gamma_n = 50; baxter n = 36, r0 = 1.2 (its paper's
  law); liffman its paper's values (viscous disk friction: its piles creep flat).
* Rest: the mass-weighted rms speed (`rms_speed`) below the paper's v_cut = 0.1
  cm/s (sec. 5) for 0.005 s. The largest speed (`rest_measure="max"`) is
  stricter than "no significant motion": a single rocking disk holds it up.

Sliding in the paper's law: eq. 2b read literally (`lee_herrmann.law(slip=
"literal")`) lets a contact rocking in the slip regime give back its work, and
with the paper's gamma_s = gamma_n / 100 the box never comes to rest; the law's
default slips the spring as Cundall & Strack 1979 do, whose scheme the paper
says it uses, and the box settles (docs/choices.md#sliding-in-the-1993-law).
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass
from typing import Any, NamedTuple

import jax.numpy as jnp
import numpy as np

from jaxpile import budget, ranges
from jaxpile.engine.boundaries import RIGHT_WALL, make_boundaries
from jaxpile.engine.state import SimState, make_particles
from jaxpile.errors import InputError
from jaxpile.protocols.base import Setup
from jaxpile.protocols.drivers import motion, rest_detector
from jaxpile.protocols.geometry import (
    PARK_SPACING,
    check_positive,
    neighbor_box,
    parking_grid,
    random_positions,
    take_out,
)
from jaxpile.protocols import paper1993
from jaxpile.protocols.paper1993 import (
    LAW_SETTING,
    PAPER_SETTING,
    count_check,
    fill_count,
    friction_coefficient,
    gaussian_radii,
    law_and_params,
    law_name,
    max_steps_for,
    max_time_budget,
    measure_flag,
    radius_law,
    repose,
    settled,
    simulator_running,
    units,
)
from jaxpile.protocols.spec import Options, ProtocolSpec, option
from jaxpile.protocols.stages import one_phase
from jaxpile.ranges import DISKS, SIZE, SPAN, SPEED, Range

Array = Any


SPARSE_FILL = 0.25
"""Below this fraction of the disks that fill the box, the pile is a layer or two
and its angle of repose means little: the set-up warns."""


# ------------------------------------------------------------------ options
@dataclass(frozen=True)
class BoxOptions(Options):
    """The box's options, in the paper's units (cm, cm/s, s), converted to the
    law's units by the set-up (`units(law)`)."""

    n: int | None = option(None, range=DISKS, help="number of disks; default: those that fill W x H at "
                           "packing_fraction (409 for 4 x 4)")
    width: float = option(PAPER_SETTING["width"], range=SIZE, unit="cm", help="W, the box's width")
    height: float = option(PAPER_SETTING["height"], range=SIZE, unit="cm", help="H, the box's height")
    radius: dict | None = option(None, help="overrides of the radius distribution (mean, width, low, high)")
    packing_fraction: float = option(PAPER_SETTING["packing_fraction"], range=Range(
        low=0, high=0.91, low_open=True, high_open=True, why="a disk packing jams near 0.91"),
        help="packing fraction of the default n")
    placement_fraction: float = option(PAPER_SETTING["placement_fraction"], range=Range(
        low=0, high=0.5, low_open=True, why="random placement jams near 0.55"),
        help="the disks start at random, without overlap, in the box made tall enough for this area fraction")
    rest_speed: float = option(PAPER_SETTING["rest_speed"], range=SPEED, unit="cm/s",
                               help="at rest below this speed (the paper's v_cut)...")
    hold_time: float = option(PAPER_SETTING["hold_time"], range=SPAN, unit="s", help="...held this long")
    rest_measure: str = option(PAPER_SETTING["rest_measure"], help="which speed: rms (the kinetic energy per disk "
                               "of Fig. 1(b)) or max (the fastest disk)")
    max_time: float = option(PAPER_SETTING["max_time"], range=SIZE, unit="s", help="give up after this long")

    def validate(self):
        measure_flag(self.rest_measure)


# -------------------------------------------------------------- the disks


# --------------------------------------------------------- the compiled run
class BoxState(NamedTuple):
    """What the box driver carries (`SimState.protocol_state`); scalars unless said.

    Attributes:
      edge: x where the floor ends (W): a disk whose centre passes it has left.
      park: `[n, 2]` where a disk that left is put, inactive.
      rest_speed: the pile is at rest when its speed stays below this...
      hold: ...for this many consecutive steps (int).
      use_max: the speed is `max_speed` (True) or `rms_speed` (False).
      phase: 0 filling the box, 1 after the right wall was removed, 2 at rest (int).
      quiet: consecutive steps below `rest_speed` so far (int).
      armed: some disk has moved faster than `rest_speed` in this phase.
      removed_at: step at which the right wall was removed (-1 before).
      settled_at: step at which the pile came to rest (-1 before).
      left: disks that have left the box (int).
      fill_height: highest disk top when the wall was removed.
    """

    edge: Array
    park: Array
    rest_speed: Array
    hold: Array
    use_max: Array
    phase: Array
    quiet: Array
    armed: Array
    removed_at: Array
    settled_at: Array
    left: Array
    fill_height: Array


def driver(state: SimState) -> SimState:
    """The box driver (before every step, inside the compiled loop): disks past
    the floor's end leave; the right wall goes when the filled box is at rest;
    the final rest is recorded. Reads everything from its `BoxState`."""
    ps: BoxState = state.protocol_state
    state, gone = take_out(state, ps.edge, ps.park)
    quiet, armed, rested = rest_detector(motion(state, ps.use_max), ps.rest_speed, ps.quiet, ps.armed, ps.hold,
                                         4 * ps.hold)
    remove = rested & (ps.phase == 0)
    settle = rested & (ps.phase == 1)
    changed = remove | settle
    p = state.particles
    top = jnp.max(jnp.where(p.active, p.position[:, 1] + p.radius, 0.0))
    b = state.boundaries
    b = b.set(wall_active=b.wall_active.at[RIGHT_WALL].set(b.wall_active[RIGHT_WALL] & ~remove))
    ps = ps._replace(
        phase=ps.phase + changed.astype(ps.phase.dtype),
        quiet=jnp.where(changed, 0, quiet),
        armed=armed & ~changed,
        removed_at=jnp.where(remove, state.step, ps.removed_at),
        settled_at=jnp.where(settle, state.step, ps.settled_at),
        left=ps.left + gone,
        fill_height=jnp.where(remove, top, ps.fill_height),
    )
    return state.set(boundaries=b, protocol_state=ps)


def setup(o: BoxOptions, *, law, seed: int, dt: float, dtype=None) -> Setup:
    """The box of Lee & Herrmann 1993, Fig. 1, ready to run with `driver`.

    Lengths, speeds and times are in the paper's units (cm, cm/s, s) and are
    converted to the law's units (`units(law)`); `dt` turns `hold_time` into
    steps and `seed` draws the radii and the positions.

    Returns:
      `Setup` with `driver` and a `BoxState`; the right wall is on, the
      floor ends at x = W. `info` holds the set-up in simulation units.

    Raises:
      InputError: on a bad count, size, speed, time or fraction, or when the
        disks cannot be placed.
    """
    u = units(law)
    width, height, rest_speed, hold_time = o.width, o.height, o.rest_speed, check_positive("hold_time", o.hold_time)
    mean, spread, low, high = radius_law(o.radius)
    fills = fill_count(width, height, packing_fraction=o.packing_fraction, radius=o.radius)
    n = fills if o.n is None else o.n
    if n < SPARSE_FILL * fills:
        warnings.warn(f"{n} disks fill the {width:g} x {height:g} box to {n / fills:.0%} of its height: a layer "
                      f"or two, too few to stand as a pile; the box takes {fills} (leave n out), or make it "
                      f"narrower and lower.", stacklevel=2)
    budget.check(n, dtype or "float64", what="a box")  # before any array is allocated
    rng = np.random.default_rng(int(seed))  # a whole float (0.0) passes the range check
    radius_paper = gaussian_radii(n, rng, mean=mean, width=spread, low=low, high=high)
    if 2 * high > width:
        raise InputError(f"the box (W = {width:g}) is narrower than the largest disk ({2 * high:g}).")
    area = math.pi * float(np.sum(radius_paper**2))
    place_height = max(height, area / (o.placement_fraction * width))
    position_paper = random_positions(radius_paper, width, place_height, rng)

    s = u.scale
    r = radius_paper * s
    position = position_paper * s
    spacing = PARK_SPACING * 2.0 * high * s
    park = parking_grid(n, 2.0 * high * s, (place_height + 4.0 * high) * s, spacing)
    mass = None if u.sphere_density is None else 4.0 / 3.0 * math.pi * u.sphere_density * r**3
    particles = make_particles(position, r, mass=mass, dtype=dtype)
    dtype = particles.position.dtype
    boundaries = make_boundaries(left=0.0, right=width * s, gravity=u.gravity, dtype=dtype)
    hold = ranges.steps_of("hold_time", hold_time * u.time, dt)
    state = BoxState(
        edge=jnp.asarray(width * s, dtype),
        park=jnp.asarray(park, dtype),
        rest_speed=jnp.asarray(rest_speed * u.speed, dtype),
        hold=jnp.asarray(hold, jnp.int32),
        use_max=jnp.asarray(measure_flag(o.rest_measure)),
        phase=jnp.asarray(0, jnp.int32),
        quiet=jnp.asarray(0, jnp.int32),
        armed=jnp.asarray(False),
        removed_at=jnp.asarray(-1, jnp.int32),
        settled_at=jnp.asarray(-1, jnp.int32),
        left=jnp.asarray(0, jnp.int32),
        fill_height=jnp.asarray(0.0, dtype),
    )
    info = {
        "protocol": "box",
        "law": law_name(law),
        "n": n,
        "width": width * s,
        "height": height * s,
        "placement_height": place_height * s,
        "length_scale": s,
        "gravity": u.gravity,
        "time_scale": u.time,
        "speed_scale": u.speed,
        "sphere_density": u.sphere_density,
        "mean_radius": float(np.mean(r)),
        "dt": dt,
        "rest_speed": rest_speed * u.speed,
        "hold_steps": hold,
        "rest_measure": o.rest_measure,
        "seed": int(seed),
    }
    box = neighbor_box(np.concatenate([position, park]), r)
    return Setup(particles=particles, boundaries=boundaries, driver=driver, protocol_state=state,
                    box=box, info=info)


# ----------------------------------------------------------------- measuring
def make_simulator(law="lee-herrmann", *, driver=None, **kwargs):
    """A `Simulator` running the box's `driver` (or `driver`), the rest as
    `paper1993.make_simulator`."""
    return paper1993.make_simulator(law, driver=globals()["driver"] if driver is None else driver, **kwargs)


def measure(sim, params, state: SimState, p: Setup, options: dict) -> dict:
    """The pile's angle of repose by the three methods (degrees), the steps of
    the wall removal and of the final rest, the fill height and disk counts."""
    from jaxpile.measure import theory

    ps = state.protocol_state
    mu = friction_coefficient(params)
    return {
        "law": p.info["law"],
        "mu": mu,
        **repose(state, p.info["width"]),
        "theta_ms_theory": None if mu is None else math.degrees(float(theory.marginal_stability_angle(mu))),
        "wall_removed_step": int(ps.removed_at),
        "settled_step": int(ps.settled_at),
        "at_rest": int(ps.settled_at) >= 0,
        "fill_height": float(ps.fill_height),
        "n_left": int(ps.left),
        **count_check(state),
    }


SPEC = ProtocolSpec(
    name="box", options=BoxOptions, setting=LAW_SETTING, setup=setup, simulator=simulator_running(driver),
    phases=one_phase(settled, max_time_budget), measure=measure)
"""The box (Lee & Herrmann 1993, sec. 3): `SPEC.run("lee-herrmann", width=1.6, height=1.6)` fills the box,
removes the right wall at rest, lets the pile settle and measures its angle of repose by the three methods."""


__all__ = ["PAPER_SETTING", "SPEC", "BoxOptions", "BoxState", "count_check", "driver", "law_and_params",
           "make_simulator", "max_steps_for", "max_time_budget", "repose", "settled", "setup", "simulator_running"]
