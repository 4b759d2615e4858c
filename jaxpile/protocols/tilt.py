"""Tilting a settled pile until it moves (Lee & Herrmann 1993, sec. 4, Fig. 4).

The paper: "Starting from a pile like the one deployed in figure 1(c), we
rotate the whole box clockwise at a constant rate of 10^-3 deg/iteration.
Then, we record the angle at which the pile starts to move, which is defined
as the tilting angle theta_T." Rotating the box clockwise is rotating gravity
counter-clockwise in the box's frame (`boundaries.gravity_vector`): the walls,
the floor and its end at x = W stay put, and gravity gains a component along
+x, down the pile's slope.

In the compiled loop the `driver` sets gravity to g (sin a, -cos a), a = rate x
(steps since the start), before every step, and watches the pile's speed
(`drivers.motion`: by default the mass-weighted rms speed, Fig. 1(b)'s kinetic
energy per disk as a speed):

* "Starts to move": the speed exceeds `move_speed` (1 cm/s in the paper's units,
  about 7% of sqrt(g d)). theta_T is the tilt at the *onset* of that motion, the
  last step at which the speed rose above `rest_speed` (the paper's v_cut, 0.1
  cm/s) before it went on past `move_speed` without dropping back, so the time
  an avalanche takes to gather speed does not add to theta_T
  (docs/choices.md#the-tilting-angles-onset).
* The run ends there (the paper's stopping rule); with `settle` the tilt is held
  and the pile run until it is at rest again. Disks that leave past the floor's
  end are taken out of play as in the box protocol (`geometry.take_out`).

The measurements are compared with the paper's theory (sec. 6): theta_MS =
arctan(3 mu) (eq. 3, `theory.marginal_stability_angle`), the measured theta_R +
theta_T against it (Fig. 7(a)), and theta_T from eq. 4 with the pile's own
theta_R (method 3) and mu (`theory.tilting_angle`, Fig. 7(b)).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, NamedTuple

import jax.numpy as jnp
import numpy as np

from jaxpile import ranges
from jaxpile.engine.state import SimState
from jaxpile.errors import InputError
from jaxpile.measure import theory
from jaxpile.protocols import drivers, geometry, paper1993
from jaxpile.protocols.base import Setup
from jaxpile.protocols.spec import Options, ProtocolSpec, option
from jaxpile.protocols.stages import one_phase
from jaxpile.ranges import ANGLE, FINITE, SIZE, SPAN, SPEED

Array = Any

SETTING = {
    "rate_degrees": 1.0e-3,  # per step: "10^-3 deg/iteration" (sec. 4)
    "move_speed": 1.0,  # cm/s (paper units): the pile moves
    "rest_speed": paper1993.PAPER_SETTING["rest_speed"],  # cm/s: the pile is at rest (v_cut)
    "rest_measure": paper1993.PAPER_SETTING["rest_measure"],
    "hold_time": paper1993.PAPER_SETTING["hold_time"],  # s: the final rest criterion
    "max_tilt_degrees": 45.0,  # give up tilting here
    "settle_time": 5.0,  # s: at most this long to come to rest after the pile moved
}


@dataclass(frozen=True)
class TiltOptions(Options):
    """The tilt's options, in the paper's units (cm/s, s; the tilt rate per
    step, as in the paper), converted to the law's units by the set-up
    (`paper1993.units(law)`). The pile it tilts is the box run's (or given)."""

    settle: bool = option(False, help="after the pile moved, hold the tilt and run until it is at rest again "
                          "(the paper stops at theta_T)")
    settle_time: float = option(SETTING["settle_time"], range=SPAN, unit="s",
                                help="with settle: at most this long after the pile moved")
    rate_degrees: float = option(SETTING["rate_degrees"], range=SIZE, unit="deg/step",
                                 help="tilt per step (1e-3 in the paper)")
    move_speed: float = option(SETTING["move_speed"], range=SIZE, unit="cm/s",
                               help="the pile moves when its speed exceeds this")
    rest_speed: float = option(SETTING["rest_speed"], range=SPEED, unit="cm/s",
                               help="the pile is at rest below this (also the onset of its motion)")
    rest_measure: str = option(SETTING["rest_measure"], help="which speed: rms (the kinetic energy per disk as a "
                               "speed) or max (the fastest disk)")
    hold_time: float = option(SETTING["hold_time"], range=SPAN, unit="s",
                              help="how long the speed must stay below rest_speed at the end")
    max_tilt_degrees: float = option(SETTING["max_tilt_degrees"], range=ANGLE, unit="deg",
                                     help="tilting stops here if the pile has not moved")
    edge: float | None = option(None, range=FINITE, help="x where the floor ends, in the run's units; default: "
                                "the box pile's")

    def validate(self):
        for name in ("rate_degrees", "move_speed", "rest_speed", "hold_time"):
            geometry.check_positive(name, getattr(self, name))
        if not self.rest_speed < self.move_speed:
            raise InputError(f"rest_speed ({self.rest_speed:g}) must be below move_speed ({self.move_speed:g}).")
        paper1993.measure_flag(self.rest_measure)
        if self.edge is not None:
            geometry.check_positive("edge", self.edge)
        if self.settle:
            geometry.check_positive("settle_time", self.settle_time)


class TiltState(NamedTuple):
    """What the tilt driver carries (`SimState.protocol_state`); scalars unless said.

    Attributes:
      edge, park: as `box.BoxState` (the floor's end and the parking places).
      g: magnitude of gravity.
      rate: tilt per step (radians).
      start: the step at which tilting starts.
      max_tilt: the largest tilt (radians).
      move_speed: the pile moves when its speed exceeds this.
      rest_speed: ...and is at rest below this.
      use_max: the speed is `max_speed` (True) or `drivers.rms_speed` (False).
      hold, quiet, armed: the final rest detector (`drivers.rest_detector`).
      phase: 0 tilting, 1 moved (tilt held), 2 at rest again (int).
      onset: last step at which the speed rose above `rest_speed` (-1 while below).
      tilt: the tilt in force (radians).
      moved_at: step at which the speed passed `move_speed` (-1 before).
      theta_t: the tilt at `onset` of that motion (radians; -1 before).
      settled_at: step at which the pile was at rest again (-1 before).
      left: disks that left past the floor's end (int).
    """

    edge: Array
    park: Array
    g: Array
    rate: Array
    start: Array
    max_tilt: Array
    move_speed: Array
    rest_speed: Array
    use_max: Array
    hold: Array
    quiet: Array
    armed: Array
    phase: Array
    onset: Array
    tilt: Array
    moved_at: Array
    theta_t: Array
    settled_at: Array
    left: Array


def tilt_at(ps: TiltState, step) -> Array:
    """The tilt (radians) the schedule gives at `step`, capped at `max_tilt`."""
    elapsed = jnp.maximum(step - ps.start, 0).astype(ps.rate.dtype)
    return jnp.minimum(ps.rate * elapsed, ps.max_tilt)


def driver(state: SimState) -> SimState:
    """The tilt driver (before every step, inside the compiled loop)."""
    ps: TiltState = state.protocol_state
    state, gone = geometry.take_out(state, ps.edge, ps.park)
    speed = drivers.motion(state, ps.use_max)
    step = state.step
    tilting = ps.phase == 0
    above_rest = speed >= ps.rest_speed
    onset = jnp.where(above_rest, jnp.where(ps.onset < 0, step, ps.onset), -1)
    onset = jnp.where(tilting, onset, ps.onset)  # frozen once the pile moved
    moved = tilting & (speed > ps.move_speed)
    tilt = jnp.where(tilting, tilt_at(ps, step), ps.tilt)
    theta_t = jnp.where(moved, tilt_at(ps, onset), ps.theta_t)
    quiet, armed, rested = drivers.rest_detector(speed, ps.rest_speed, ps.quiet, ps.armed, ps.hold, 4 * ps.hold)
    settle = (ps.phase == 1) & rested
    phase = ps.phase + moved.astype(ps.phase.dtype) + settle.astype(ps.phase.dtype)
    reset = moved  # the rest detector starts afresh once the pile moved
    ps = ps._replace(
        onset=onset,
        tilt=tilt,
        phase=phase,
        moved_at=jnp.where(moved, step, ps.moved_at),
        theta_t=theta_t,
        quiet=jnp.where(reset, 0, quiet),
        armed=armed & ~reset,
        settled_at=jnp.where(settle, step, ps.settled_at),
        left=ps.left + gone,
    )
    gravity = ps.g * jnp.stack([jnp.sin(tilt), -jnp.cos(tilt)])
    b = state.boundaries.set(gravity=gravity.astype(state.boundaries.gravity.dtype))
    return state.set(boundaries=b, protocol_state=ps)


def setup(pile: SimState, o: TiltOptions, *, law, dt: float) -> Setup:
    """Tilting of a settled pile (Lee & Herrmann 1993, Fig. 4), ready to run with `driver`.

    Speeds and times are in the paper's units (cm/s, s), converted with
    `paper1993.units(law)`; the tilt rate is per step, as in the paper; `dt`
    turns `hold_time` into steps.

    Args:
      pile: the settled pile, e.g. the state `box.SPEC.run` returns. Its
        particles, walls and gravity (untilted, pointing down) are the start.
        `SPEC.run(..., pile=...)` and `running.run_setup` continue this
        state, keeping its contact history; starting from `Setup.particles`
        instead loses the tangential springs.
      o: the tilt's options; `edge` None takes the box pile's (`BoxState.edge`).

    Raises:
      InputError: on a pile that is not a state, a pile whose gravity is
        already tilted, or a pile that is not a box pile when `edge` is missing.
    """
    if not isinstance(pile, SimState):
        raise InputError("pile must be a SimState (a settled pile, e.g. from box.SPEC.run).")
    u = paper1993.units(law)
    dt = float(dt)
    rate, move_speed, rest_speed, hold_time = (float(x) for x in (o.rate_degrees, o.move_speed, o.rest_speed,
                                                                  o.hold_time))
    max_tilt_degrees = o.max_tilt_degrees
    gravity = np.asarray(pile.boundaries.gravity, dtype=np.float64)
    g = float(np.linalg.norm(gravity))
    if not (g > 0 and abs(gravity[0]) <= 1e-12 * g and gravity[1] < 0):
        raise InputError(f"the pile's gravity must point straight down (untilted); got {gravity.tolist()}.")
    p = pile.particles
    dtype = p.position.dtype
    before = pile.protocol_state
    edge = o.edge
    if edge is None:
        if not hasattr(before, "edge"):
            raise InputError("give edge (the x where the floor ends) for a pile that is not a box pile.")
        edge = float(before.edge)
    edge = geometry.check_positive("edge", edge)
    if hasattr(before, "park"):
        park = np.asarray(before.park)
    else:
        r = np.asarray(p.radius)
        spacing = geometry.PARK_SPACING * 2.0 * float(r.max())
        top = float(np.max(np.asarray(p.position)[:, 1] + r))
        park = geometry.parking_grid(p.count, spacing, top + 2 * spacing, spacing)
    left = int(before.left) if hasattr(before, "left") else 0
    hold = ranges.steps_of("hold_time", hold_time * u.time, dt)
    state = TiltState(
        edge=jnp.asarray(edge, dtype),
        park=jnp.asarray(park, dtype),
        g=jnp.asarray(g, dtype),
        rate=jnp.asarray(math.radians(rate), dtype),
        start=jnp.asarray(pile.step, jnp.int32),
        max_tilt=jnp.asarray(math.radians(max_tilt_degrees), dtype),
        move_speed=jnp.asarray(move_speed * u.speed, dtype),
        rest_speed=jnp.asarray(rest_speed * u.speed, dtype),
        use_max=jnp.asarray(paper1993.measure_flag(o.rest_measure)),
        hold=jnp.asarray(hold, jnp.int32),
        quiet=jnp.asarray(0, jnp.int32),
        armed=jnp.asarray(False),
        phase=jnp.asarray(0, jnp.int32),
        onset=jnp.asarray(-1, jnp.int32),
        tilt=jnp.asarray(0.0, dtype),
        moved_at=jnp.asarray(-1, jnp.int32),
        theta_t=jnp.asarray(-1.0, dtype),
        settled_at=jnp.asarray(-1, jnp.int32),
        left=jnp.asarray(left, jnp.int32),
    )
    settings = pile.neighbor_settings
    info = {
        "protocol": "tilt",
        "law": paper1993.law_name(law),
        "n": int(p.count),
        "rate_degrees": rate,
        "rate_degrees_per_time": rate / dt,
        "move_speed": move_speed * u.speed,
        "rest_speed": rest_speed * u.speed,
        "rest_measure": o.rest_measure,
        "hold_steps": hold,
        "max_tilt_degrees": float(max_tilt_degrees),
        "max_tilt_steps": math.ceil(max_tilt_degrees / rate),
        "edge": edge,
        "dt": dt,
        "start_step": int(pile.step),
    }
    return Setup(particles=p, boundaries=pile.boundaries, driver=driver, protocol_state=state,
                 box=None if settings is None else settings.box, info=info)


simulator = paper1993.simulator_running(driver)
"""The spec's simulator: the tilt `driver` with a law by name (`box.make_simulator`)."""


def compare_with_theory(theta_r_degrees: float, theta_t_degrees: float, mu: float | None) -> dict:
    """The measured angles against the paper's sec. 6: theta_MS = arctan(3 mu)
    (eq. 3) beside theta_R + theta_T (Fig. 7(a)), and theta_T from eq. 4 for the
    measured theta_R (Fig. 7(b)). NaN where the theory has no answer (no mu,
    theta_R above theta_MS, or theta_R + theta_T reaching 60 deg), with the
    reason under `theory_note`."""
    nan = float("nan")
    out = {"theta_ms_theory": nan, "theta_t_theory": nan, "theta_r_plus_theta_t": theta_r_degrees + theta_t_degrees}
    if mu is None:
        out["theory_note"] = "the law has no Coulomb mu between disks"
        return out
    out["theta_ms_theory"] = math.degrees(float(theory.marginal_stability_angle(mu)))
    if not (theta_r_degrees > 0 and math.isfinite(theta_r_degrees)):
        out["theory_note"] = f"theta_R = {theta_r_degrees!r} is not a positive angle"
        return out
    try:
        out["theta_t_theory"] = math.degrees(theory.tilting_angle(math.radians(theta_r_degrees), mu))
    except InputError as error:
        out["theory_note"] = str(error)
    return out


law_and_params = paper1993.law_and_params  # the 1993 setting, shared with `box`


def pile_facts(pile: SimState, p: Setup) -> dict:
    """The pile the tilt takes over: its angles of repose (three methods, at
    the floor's end `edge`) and whether its box run came to rest."""
    before = paper1993.repose(pile, p.info["edge"])
    ps = pile.protocol_state
    return {"pile_repose": {k: v for k, v in before.items() if not k.startswith("surface")},
            "box_settled": bool(int(ps.settled_at) >= 0) if hasattr(ps, "settled_at") else None}


def _settle_steps(p: Setup, o: TiltOptions) -> int:
    """With `settle`: `settle_time` paper seconds in steps (0 without)."""
    if not o.settle:
        return 0
    u = paper1993.units(p.info["law"])
    return round(geometry.check_positive("settle_time", o.settle_time) * u.time / p.info["dt"])


def finished(p: Setup, o: TiltOptions):
    """Moved; with `settle`, at rest again or `settle_time` after it moved;
    or the largest tilt passed without motion and its hold time after it: the
    run gives up. Traceable."""
    give_up = int(p.info["max_tilt_steps"])
    settle = _settle_steps(p, o)

    def done(s):
        ps = s.protocol_state
        gave_up = (ps.phase == 0) & (s.step - ps.start > give_up + ps.hold)
        if not o.settle:
            return (ps.phase >= 1) | gave_up
        return (ps.phase >= 2) | ((ps.phase == 1) & (s.step - ps.moved_at > settle)) | gave_up

    return done


def budget(p: Setup, o: TiltOptions) -> int:
    """The tilt's budget from its start: the largest tilt, the hold after it,
    `settle_time` with `settle`, and room for `finished` to be seen at a
    chunk's end (it ends the run first)."""
    return int(p.info["max_tilt_steps"]) + 4 * int(p.info["hold_steps"]) + 10_000 + _settle_steps(p, o)


def measure(sim, params, state: SimState, p: Setup, o: TiltOptions) -> dict:
    """theta_T (degrees, NaN if the pile never moved up to the largest tilt),
    the pile's theta_R (method 3) and all three methods, the theory of sec. 6
    (`compare_with_theory`), the steps of the onset and of the motion (from
    the tilt's start), the tilt held at the end, and the disk counts."""
    ps = state.protocol_state
    moved = int(ps.phase) >= 1
    theta_t = math.degrees(float(ps.theta_t)) if moved else float("nan")
    theta_r = p.info["pile_repose"]["repose_cumulative_parabola"]
    mu = paper1993.friction_coefficient(params)
    start = p.info["start_step"]
    out = {
        "law": p.info["law"],
        "mu": mu,
        "theta_t": theta_t,
        "theta_r": theta_r,
        "pile_repose": p.info["pile_repose"],
        **compare_with_theory(theta_r, theta_t, mu),
        "moved": moved,
        "onset_step": int(ps.onset) - start if moved else -1,
        "moved_step": int(ps.moved_at) - start if moved else -1,
        "tilt_held": math.degrees(float(ps.tilt)),
        "settled_step": int(ps.settled_at) - start if int(ps.settled_at) >= 0 else -1,
        "at_rest": int(ps.settled_at) >= 0,
        "box_settled": p.info["box_settled"],
        "n_left": int(ps.left),
        **paper1993.count_check(state),
    }
    if o.settle and out["at_rest"]:
        after = paper1993.repose(state, p.info["edge"])
        out["after_repose_box_frame"] = {k: v for k, v in after.items() if not k.startswith("surface")}
    return out


SPEC = ProtocolSpec(
    name="tilt", options=TiltOptions, setting=paper1993.LAW_SETTING, setup=setup, simulator=simulator,
    phases=one_phase(finished, budget, "tilt"), measure=measure, continues="box", pile_facts=pile_facts)
"""The tilt (Lee & Herrmann 1993, sec. 4): `SPEC.run("lee-herrmann", pile_options={"width": 1.6, "height": 1.6})`
builds a box pile (its seed is the run's `seed`; `pile=` a state tilts that one instead, contact history kept),
tilts it at the paper's rate until it moves, and measures theta_T; the box run's measurements are under "box"."""


__all__ = [
    "SETTING",
    "SPEC",
    "TiltOptions",
    "TiltState",
    "budget",
    "compare_with_theory",
    "driver",
    "finished",
    "law_and_params",
    "measure",
    "pile_facts",
    "setup",
    "simulator",
    "tilt_at",
]
