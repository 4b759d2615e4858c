"""A flat-bottomed silo emptied through an orifice, against Beverloo's law.

None of the three papers has it; it shows that a new protocol is one module:
this file and its test, nothing to edit elsewhere (the registry finds its
`SPEC`, from which come its run, its batch in a sweep and an ensemble fit, and
its command line). Units: the mean diameter d = 1, g = 1, a unit disk of mass 1.

* A silo of width W between two walls, its floor a row of fixed, touching unit
  disks at y = `FLOOR_Y`. The floor disks across the middle width D (the
  orifice, between the edges of the floor disks beside it) are the gate, in
  place while the silo fills. Every orifice uses the same number of floor slots
  (the unused ones parked), so piles with different orifices share shapes.
* n disks of diameters uniform in d (1 +- `dispersity`) (polydisperse, so the 2D
  packing does not crystallise), placed at random without overlap above the
  floor (`geometry.random_positions`), fall and settle.
* One compiled `driver` runs the stages: 0 filling (the 1993 rest detector,
  `drivers.rest_detector`, on the rms speed); 1 discharging: the gate goes, and a
  disk more than `EXIT_DROP` below the floor's centres is taken out, its step
  logged; 2 stopped, when every disk is out or none has come out for
  `clog_time` (an arch over the orifice, or the dead zones a flat bottom keeps).

Measured: the discharge N(t) and its flow rate Q (disks per unit time, the
least-squares slope of N(t) between 10 % and 60 % of the disks that came out,
where the rate is steady), against Beverloo's law in 2D (Beverloo, Leniger &
van de Velde 1961, for a slot): Q = C n_A sqrt(g) (D - k d)^(3/2), n_A the disks
per unit area of the filled silo. `beverloo_c` is C at a given k; `beverloo_fit`
finds C and k from runs at several orifices. The dead zones beside the orifice
stand at an angle of repose (`dead_zone_angles`), which sees the disk friction
that Beverloo's law does not.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, NamedTuple

import jax.numpy as jnp
import numpy as np

from jaxpile import budget, ranges
from jaxpile.engine.boundaries import GROUND, make_boundaries, set_wall
from jaxpile.engine.state import SimState, make_particles
from jaxpile.errors import InputError
from jaxpile.protocols.base import Setting, Setup
from jaxpile.protocols.drivers import rest_detector, rms_speed
from jaxpile.protocols.geometry import (
    PARK_SPACING,
    neighbor_box,
    park_where,
    parking_grid,
    random_positions,
)
from jaxpile.protocols.spec import Options, ProtocolSpec, option
from jaxpile.protocols.stages import one_phase
from jaxpile.ranges import DISKS, SIZE, SPAN, SPEED, Range

Array = Any

SETTING = {
    "width": 20.0, "orifice": 5.0, "dispersity": 0.1, "placement_fraction": 0.4,
    "rest_speed": 0.01, "hold_time": 1.0,  # the fill is at rest: rms speed < 0.01 sqrt(g d) for 1 time unit
    "clog_time": 10.0, "max_time": 1000.0, "beverloo_k": 1.5, "dt": 1.0e-3, "chunk_steps": 1000,
    "params": {"hooke": {"kn": 1.0e4, "gamma_n": 50.0, "mu": 0.5},
               "baxter": {"n": 36.0, "r0": 1.2, "mu": 0.5}},  # other laws: their own defaults
    "rotation": True,
}
FLOOR_Y = 3.0
"""Height of the floor disks' centres: everything in play stays at y > 0."""
EXIT_DROP = 2.5
"""A disk this far below the floor's centres has left the silo."""


@dataclass(frozen=True)
class HopperOptions(Options):
    """The hopper's options, in units of the mean diameter d and g: the silo,
    its fill, when the gate opens and when the run stops, and the k of
    Beverloo's law its C is reported at."""

    n: int = option(400, range=DISKS, help="disks to fill the silo with")
    width: float = option(SETTING["width"], range=SIZE, unit="d", help="W, between the walls")
    orifice: float = option(SETTING["orifice"], range=Range(low=0, low_open=True, high=1e9,
                                                            why="diameters; < width - 2"),
                            help="D, between the edges of the floor disks beside it")
    dispersity: float = option(SETTING["dispersity"], range=Range(
        low=0, high=0.5, high_open=True, why="diameters 1 +- dispersity stay positive"),
        help="diameters are uniform in 1 +- this")
    placement_fraction: float = option(SETTING["placement_fraction"], range=Range(
        low=0, high=0.5, low_open=True, why="random placement jams near 0.55"),
        help="the disks start at random, without overlap, filling this fraction of the silo's area")
    rest_speed: float = option(SETTING["rest_speed"], range=SPEED, unit="sqrt(g d)",
                               help="the fill is at rest when the rms speed stays below this...")
    hold_time: float = option(SETTING["hold_time"], range=SPAN, unit="sqrt(d / g)",
                              help="...for this long; then the gate opens")
    clog_time: float = option(SETTING["clog_time"], range=Range(
        low=0, low_open=True, high=1e9, why="a stop with no wait would end every discharge at once"),
        unit="sqrt(d / g)", help="the discharge stops when no disk has come out for this long")
    max_time: float = option(SETTING["max_time"], range=SIZE, unit="sqrt(d / g)",
                             help="give up after this much simulated time")
    beverloo_k: float = option(SETTING["beverloo_k"], help="k of Beverloo's law at which beverloo_c is reported")


def budget_steps(max_time: float, dt: float) -> int:
    """The run's step budget: `max_time` (sqrt(d / g)) in steps of dt."""
    return ranges.steps_of("max_time", max_time, dt)


LAW_SETTING = Setting(law="hooke", params=SETTING["params"], dt=SETTING["dt"], rotation=SETTING["rotation"])
"""The hopper's laws: `SETTING["params"]` (other laws their own defaults), rotation on."""
law_and_params = LAW_SETTING.law_and_params


class HopperState(NamedTuple):
    """What the driver carries: the gate `[N]` (floor disks that close the
    orifice), `park [N, 2]` (where a disk that came out goes), the exit level,
    the fill's rest rule (`rest_speed` for `hold` steps; `quiet`, `armed` as in
    `drivers.rest_detector`), `clog_steps` without a disk out that stop the run,
    how many disks are `movable`, the `phase` (0 filling, 1 discharging, 2
    stopped), the steps the gate opened and the run stopped at (-1 before),
    the `last_out` step, `out_count`, each disk's `out_step [N]` (-1: still in)
    and the highest disk top when the gate opened (`fill_top`)."""

    gate: Array
    park: Array
    exit_level: Array
    rest_speed: Array
    hold: Array
    clog_steps: Array
    movable: Array
    phase: Array
    quiet: Array
    armed: Array
    opened_at: Array
    stopped_at: Array
    last_out: Array
    out_count: Array
    out_step: Array
    fill_top: Array


def driver(state: SimState) -> SimState:
    """Before every step: disks below the exit level leave and are logged; the
    gate goes when the filled silo is at rest; the stop is recorded."""
    hs: HopperState = state.protocol_state
    p = state.particles
    out = p.active & ~p.fixed & (p.position[:, 1] < hs.exit_level)
    state = park_where(state, out, hs.park)
    p = state.particles
    quiet, armed, rested = rest_detector(rms_speed(state), hs.rest_speed, hs.quiet, hs.armed, hs.hold,
                                             4 * hs.hold)
    opening = rested & (hs.phase == 0)
    count = hs.out_count + jnp.sum(out).astype(jnp.int32)
    last_out = jnp.where(jnp.any(out) | opening, state.step, hs.last_out)
    stopping = (hs.phase == 1) & ((count >= hs.movable) | (state.step - last_out >= hs.clog_steps))
    top = jnp.max(jnp.where(p.active & ~p.fixed, p.position[:, 1] + p.radius, 0.0))
    p = p.set(active=p.active & ~(hs.gate & opening))
    hs = hs._replace(
        phase=hs.phase + opening.astype(jnp.int32) + stopping.astype(jnp.int32),
        quiet=jnp.where(opening, 0, quiet), armed=armed & ~opening,
        opened_at=jnp.where(opening, state.step, hs.opened_at),
        stopped_at=jnp.where(stopping, state.step, hs.stopped_at),
        last_out=last_out, out_count=count, out_step=jnp.where(out, state.step, hs.out_step),
        fill_top=jnp.where(opening, top, hs.fill_top))
    return state.set(particles=p, protocol_state=hs)


def floor(width: float, orifice: float) -> tuple[np.ndarray, np.ndarray, int]:
    """Floor disk centres `[F]` (x), which of them are the gate, and F = the slots
    every orifice of this width uses (`width + 8`; unused slots are parked).

    The disks beside the orifice have their edges at W/2 -+ D/2; the floor goes
    out from them in steps of d to a disk touching each wall; the gate is
    ceil(D) disks spread evenly between them, so no gap in the closed floor is
    wider than the spacing (<= d)."""
    if not orifice < width - 2.0:
        raise InputError(f"the orifice ({orifice:g}) must leave a floor disk on each side: < width - 2 = "
                         f"{width - 2.0:g}.")
    left = width / 2 - orifice / 2 - 0.5
    side = np.arange(left, 0.5, -1.0)
    side = np.append(side, 0.5) if side[-1] > 0.5 + 1e-9 else side  # a disk touching the wall closes the gap
    gates = math.ceil(orifice)
    gate_x = left + (orifice + 1.0) * np.arange(1, gates + 1) / (gates + 1)
    x = np.concatenate([side, width - side, gate_x])
    gate = np.arange(x.size) >= 2 * side.size
    slots = math.ceil(width) + 8
    return x, gate, slots


def setup(o: HopperOptions, *, law, seed: int, dt: float, dtype=None) -> Setup:
    """The silo, filled at random, its gate closed, ready to run with `driver`:
    `seed` draws the diameters and the positions; `dt` turns `hold_time` and
    `clog_time` into steps."""
    n, dt = int(o.n), float(dt)
    width, orifice, dispersity, placement_fraction = o.width, o.orifice, o.dispersity, o.placement_fraction
    budget.check(n + math.ceil(width) + 8, dtype or "float64", what="a hopper")
    x_floor, gate, slots = floor(float(width), float(orifice))
    rng = np.random.default_rng(int(seed))
    diameter = rng.uniform(1.0 - dispersity, 1.0 + dispersity, n)
    area = math.pi * float(np.sum(diameter**2)) / 4
    fill = area / (placement_fraction * width)
    inside = random_positions(0.5 * diameter, width, fill, rng) + [0.0, FLOOR_Y + 0.5]
    park = parking_grid(n + slots, 1.0, FLOOR_Y + 0.5 + fill + 4.0, PARK_SPACING * (1.0 + dispersity))
    unused = slots - x_floor.size
    floor_xy = np.concatenate([np.stack([x_floor, np.full(x_floor.size, FLOOR_Y)], 1), park[n:n + unused]])
    particles = make_particles(np.concatenate([floor_xy, inside]),
                               np.concatenate([np.full(slots, 0.5), 0.5 * diameter]),
                               fixed=np.arange(slots + n) < slots,
                               active=(np.arange(slots + n) < x_floor.size) | (np.arange(slots + n) >= slots),
                               dtype=dtype)
    dtype = particles.position.dtype
    boundaries = set_wall(make_boundaries(left=0.0, right=float(width), dtype=dtype), GROUND, active=False)
    hold = ranges.steps_of("hold_time", o.hold_time, dt)
    as_int = lambda v: jnp.asarray(v, jnp.int32)
    state = HopperState(
        gate=jnp.asarray(np.concatenate([gate, np.zeros(unused + n, bool)])),
        park=jnp.asarray(np.concatenate([np.zeros((slots, 2)), park[:n]]), dtype),
        exit_level=jnp.asarray(FLOOR_Y - EXIT_DROP, dtype), rest_speed=jnp.asarray(o.rest_speed, dtype),
        hold=as_int(hold), clog_steps=as_int(ranges.steps_of("clog_time", o.clog_time, dt)), movable=as_int(n),
        phase=as_int(0), quiet=as_int(0), armed=jnp.asarray(False), opened_at=as_int(-1), stopped_at=as_int(-1),
        last_out=as_int(-1), out_count=as_int(0), out_step=jnp.full(slots + n, -1, jnp.int32),
        fill_top=jnp.asarray(0.0, dtype))
    info = {"protocol": "hopper", "n": n, "width": float(width), "orifice": float(orifice),
            "dispersity": float(dispersity), "floor_disks": int(x_floor.size), "gate_disks": int(gate.sum()),
            "floor_top": FLOOR_Y + 0.5, "dt": dt, "hold_steps": hold, "seed": int(seed)}
    return Setup(particles=particles, boundaries=boundaries, driver=driver, protocol_state=state,
                 box=neighbor_box(np.concatenate([floor_xy, inside, park]), particles.radius), info=info)


# ------------------------------------------------------------------ measuring
def flow_rate(times, low: float = 0.1, high: float = 0.6) -> float:
    """Disks per unit time: the least-squares slope of the count N against the
    sorted exit times, over the disks from `low` to `high` of those out (the
    steady part: after the start, before the heap runs low); NaN below 5."""
    t = np.sort(np.asarray(times, dtype=float))
    k = np.arange(1, t.size + 1)
    window = slice(int(low * t.size), math.ceil(high * t.size))
    if k[window].size < 5 or np.ptp(t[window]) == 0:
        return float("nan")
    return float(np.polyfit(t[window], k[window], 1)[0])


def beverloo_fit(orifice, rate, number_density: float, g: float = 1.0) -> dict:
    """C and k of Q = C n_A sqrt(g) (D - k)^(3/2) from rates at several orifices:
    Q^(2/3) is linear in D, its root is k and its slope (C n_A sqrt g)^(2/3)."""
    orifice, rate = np.asarray(orifice, float), np.asarray(rate, float)
    if orifice.size < 2 or np.ptp(orifice) == 0 or not np.all(rate > 0):
        raise InputError("a Beverloo fit needs positive rates at two or more orifices.")
    slope, intercept = np.polyfit(orifice, rate ** (2 / 3), 1)
    return {"c": float(slope**1.5 / (number_density * math.sqrt(g))), "k": float(-intercept / slope)}


def dead_zone_angles(state: SimState, info: dict) -> dict:
    """The slopes (degrees) of the dead zones a flat-bottomed silo keeps beside
    its orifice: on each side, the least-squares line through the surface h(x)
    (Lee & Herrmann 1993, sec. 3, method 2: `analysis.repose_angles`;
    `analysis.surface_profile`, unit columns, the floor disks included so a
    bare column reads the floor) from the wall to the orifice's edge. A dead
    zone stands at an angle of repose, so unlike the flow rate it moves with the
    disk friction. NaN for a side that cannot be read (an arch over the orifice
    leaves the silo full)."""
    from jaxpile.measure import analysis

    half = (info["width"] - info["orifice"]) / 2
    out = {}
    for side, x_min in (("left", 0.0), ("right", info["width"] - half)):
        try:
            profile = analysis.surface_profile_of(state, x_min=x_min, width=half, column_width=1.0)
            out[f"dead_zone_{side}"] = analysis.repose_angles(profile).least_squares
        except InputError:
            out[f"dead_zone_{side}"] = float("nan")
    out["dead_zone_angle"] = 0.5 * (out["dead_zone_left"] + out["dead_zone_right"])
    return out


def measure(sim, params, state: SimState, p: Setup, o: HopperOptions) -> dict:
    """Plain numbers of a run (the sweep's row) and the discharge N(t), with
    Beverloo's C at the options' `beverloo_k`."""
    info, beverloo_k = p.info, o.beverloo_k
    hs: HopperState = state.protocol_state
    p = state.particles
    dt, opened = info["dt"], int(hs.opened_at)
    steps = np.asarray(hs.out_step)
    times = np.sort(steps[steps >= 0] - opened) * dt
    rate = flow_rate(times)
    height = float(hs.fill_top) - info["floor_top"]
    density = info["n"] / (info["width"] * height) if opened >= 0 and height > 0 else float("nan")
    gap = info["orifice"] - beverloo_k
    in_play = np.asarray(p.active & ~p.fixed)
    x, y = np.asarray(p.position[:, 0]), np.asarray(p.position[:, 1])
    # an arch: a disk over the orifice's centre line, less than D above the floor (a drained silo
    # keeps only the dead zones beside the orifice, and nothing over its centre)
    r = np.asarray(p.radius)
    over = in_play & (np.abs(x - info["width"] / 2) < r) & (y < info["floor_top"] + info["orifice"])
    return {
        "opened_step": opened, "stopped_step": int(hs.stopped_at), "at_rest": int(hs.stopped_at) >= 0,
        "discharged": int(hs.out_count), "remaining": int(in_play.sum()), "clogged": bool(over.any()),
        "flow_rate": rate, "mass_flow_rate": rate * float(np.mean(np.asarray(p.mass)[~np.asarray(p.fixed)])),
        "number_density": density, "fill_height": height,
        "beverloo_c": rate / (density * gap**1.5) if gap > 0 else float("nan"), "beverloo_k": beverloo_k,
        **dead_zone_angles(state, info),
        "discharge": {"time": times.tolist(), "count": list(range(1, times.size + 1))},
    }


# ---------------------------------------------------------------- running it
def simulator(o: HopperOptions, *, law, dt, rotation=None, integrator=None, chunk_steps=None, law_options=None):
    """A `Simulator` running the hopper's `driver`. It reads no option: one
    serves every set-up with this dt (every orifice shares a compile)."""
    from jaxpile.engine.simulate import Simulator

    _, contact_law, _ = law_and_params(law, {}, rotation, law_options=law_options)
    return Simulator(contact_law, dt, integrator=integrator or "velocity_verlet", driver=driver,
                     chunk_steps=chunk_steps or SETTING["chunk_steps"])


def stopped(p: Setup, o: HopperOptions):
    """Finished when the driver has recorded the stop."""
    return lambda s: s.protocol_state.stopped_at >= 0


def max_time_budget(p: Setup, o: HopperOptions) -> int:
    """`max_time` in steps of the set-up's dt."""
    return budget_steps(o.max_time, p.info["dt"])


SPEC = ProtocolSpec(
    name="hopper", options=HopperOptions, setting=LAW_SETTING, setup=setup, simulator=simulator,
    phases=one_phase(stopped, max_time_budget), measure=measure)
"""The hopper: `SPEC.run("hooke", 60, width=10.0, orifice=4.0, seed=0)` fills the silo, opens the gate at rest,
lets it run out, and measures the flow rate against Beverloo's law."""


__all__ = ["EXIT_DROP", "FLOOR_Y", "SETTING", "SPEC", "HopperOptions", "HopperState", "beverloo_fit", "budget_steps",
           "dead_zone_angles", "driver", "floor", "flow_rate", "law_and_params",
           "max_time_budget", "measure", "setup", "simulator", "stopped"]
