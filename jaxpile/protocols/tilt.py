"""Tilting a settled pile until it moves (Lee & Herrmann 1993, sec. 4, Fig. 4).

The paper: "Starting from a pile like the one deployed in figure 1(c), we
rotate the whole box clockwise at a constant rate of 10^-3 deg/iteration.
Then, we record the angle at which the pile starts to move, which is defined
as the tilting angle theta_T." Rotating the box clockwise is rotating gravity
counter-clockwise in the box's frame (`boundaries.gravity_vector`): the walls,
the floor and its end at x = W stay put, and gravity gains a component along
+x, down the pile's slope.

Everything happens in the compiled loop: the `driver` sets gravity to
g (sin a, -cos a) with a = rate x (steps since the start) before every step,
and watches the pile's speed (`drivers.motion`: the mass-weighted rms speed by
default, the kinetic energy per disk of Fig. 1(b) as a speed):

* "starts to move", made precise: the speed exceeds `move_speed` (1 cm/s in
  the paper's units, about 7% of sqrt(g d), d the mean diameter). theta_T is
  the tilt at the *onset* of that motion: the last step at which the speed rose
  above `rest_speed` (0.1 cm/s, the paper's v_cut, which a pile at rest stays
  under) before it went on to exceed `move_speed` without dropping back. An
  avalanche takes a while to reach `move_speed`; timing it from its onset
  removes that delay (about a degree at the paper's rate) from theta_T.
* The run ends there (the paper's stopping rule); with `settle` the tilt is
  held where it is and the pile is run until it is at rest again.
* Disks that leave past the floor's end are taken out of play as in the box
  protocol (`geometry.take_out`).

The measurements are compared with the paper's theory (sec. 6):
theta_MS = arctan(3 mu) (eq. 3, `theory.marginal_stability_angle`), the
measured theta_R + theta_T against it (Fig. 7(a)), and theta_T from eq. 4
with the pile's own theta_R (method 3) and mu (`theory.tilting_angle`, Fig. 7(b)).
"""

from __future__ import annotations

import math
from typing import Any, NamedTuple

import jax.numpy as jnp
import numpy as np

from jaxpile import ranges
from jaxpile.measure import theory
from jaxpile.errors import InputError
from jaxpile.ranges import ANGLE, DISKS, FINITE, SIZE, SPAN, SPEED, STEPS, TIME_STEP
from jaxpile.protocols import box as boxes
from jaxpile.protocols import definition, outputs
from jaxpile.protocols.base import CommandLine, Setup
from jaxpile.engine.state import SimState
from jaxpile.measure.theory import marginal_stability_overlay
from jaxpile.protocols import paper1993
from jaxpile.protocols import geometry
from jaxpile.protocols import drivers

Array = Any

SETTING = {
    "rate_degrees": 1.0e-3,  # per step: "10^-3 deg/iteration" (sec. 4)
    "move_speed": 1.0,  # cm/s (paper units): the pile moves
    "rest_speed": boxes.PAPER_SETTING["rest_speed"],  # cm/s: the pile is at rest (v_cut)
    "rest_measure": boxes.PAPER_SETTING["rest_measure"],
    "hold_time": boxes.PAPER_SETTING["hold_time"],  # s: the final rest criterion
    "max_tilt_degrees": 45.0,  # give up tilting here
    "settle_time": 5.0,  # s: at most this long to come to rest after the pile moved
}


OPTION_RANGES = {
    "n": DISKS, "rate_degrees": SIZE, "move_speed": SIZE, "rest_speed": SPEED, "hold_time": SPAN,
    "max_tilt_degrees": ANGLE, "edge": FINITE, "dt": TIME_STEP, "settle_time": SPAN, "chunk_steps": STEPS,
}
"""Each option's valid range (`jaxpile.ranges`), checked first by the set-up and `run`."""


# How `jaxpile pile|sweep|fit` list and run this protocol (the registry entry).
CLI = CommandLine(
    order=4, help="a box pile tilted until it moves (1993 Fig. 4)", default_law="lee-herrmann",
    headline=("moved", "theta_t", "theta_t_theory", "theta_r", "theta_ms_theory"), flags={"seed": "box_options.seed"},
    length_unit=outputs.cm_for_lee_herrmann, figures=(outputs.energy_figure,),
    dry_run_setup=lambda kwargs: _box_setup(kwargs))


def _box_setup(kwargs: dict):
    """The box set-up a tilt run starts from, with the run's box options and n
    (`jaxpile pile --protocol tilt --dry-run`)."""
    extra = dict(kwargs.get("box_options") or {})
    if "n" in kwargs:
        extra["n"] = kwargs["n"]
    check_options(**{k: v for k, v in kwargs.items() if k != "n"})  # the tilt's own, before its pile
    return boxes.protocol, extra


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


def check_options(*, rate_degrees: float = SETTING["rate_degrees"], move_speed: float = SETTING["move_speed"],
                  rest_speed: float = SETTING["rest_speed"], rest_measure: str = SETTING["rest_measure"],
                  hold_time: float = SETTING["hold_time"], max_tilt_degrees: float = SETTING["max_tilt_degrees"],
                  edge: float | None = None, dt: float | None = None, **_) -> None:
    """Refuses the tilt's own options (`protocol`'s, less the pile) before a
    box pile is built for them: a run, a sweep or a dry run checks these first."""
    ranges.check_all(OPTION_RANGES, locals(), check_options)  # types, finiteness and ranges first: one message format
    for name, value in (("rate_degrees", rate_degrees), ("move_speed", move_speed), ("rest_speed", rest_speed),
                        ("hold_time", hold_time)) + ((("dt", dt),) if dt is not None else ()):
        boxes.check_positive(name, value)
    if not rest_speed < move_speed:
        raise InputError(f"rest_speed ({rest_speed:g}) must be below move_speed ({move_speed:g}).")
    if not 0 < max_tilt_degrees < 90:
        raise InputError(f"max_tilt_degrees must be in (0, 90); got {max_tilt_degrees!r}.")
    boxes.measure_flag(rest_measure)
    if edge is not None:
        boxes.check_positive("edge", edge)


def protocol(pile: SimState, *, law="lee-herrmann", rate_degrees: float = SETTING["rate_degrees"],
             move_speed: float = SETTING["move_speed"], rest_speed: float = SETTING["rest_speed"],
             rest_measure: str = SETTING["rest_measure"], hold_time: float = SETTING["hold_time"],
             max_tilt_degrees: float = SETTING["max_tilt_degrees"], edge: float | None = None,
             dt: float | None = None) -> Setup:
    """Tilting of a settled pile (Lee & Herrmann 1993, Fig. 4), ready to run with `driver`.

    Speeds and times are in the paper's units (cm/s, s), converted with
    `paper1993.units(law)`; the tilt rate is per step, as in the paper.

    Args:
      pile: the settled pile, e.g. the state `box.run` returns. Its particles,
        walls and gravity (untilted, pointing down) are the start. `run` and
        `execute(..., pile=...)` continue this state, keeping its contact history;
        starting from `Setup.particles` instead loses the tangential springs.
      law: the law the run will use (units and default dt).
      rate_degrees: tilt per step (1e-3 in the paper).
      move_speed: the pile moves when its speed exceeds this.
      rest_speed: the pile is at rest below this (also the onset threshold).
      rest_measure: `"rms"` (`drivers.rms_speed`) or `"max"` (`max_speed`).
      hold_time: how long the speed must stay below `rest_speed` at the end.
      max_tilt_degrees: tilting stops here if the pile has not moved.
      edge: x where the floor ends; default: the box pile's (`BoxState.edge`).
      dt: the run's time step (default the law's), for `hold_time`.

    Raises:
      InputError: on a bad rate, speed or angle, a pile whose gravity is
        already tilted, or a pile that is not a box pile when `edge` is missing.
    """
    check_options(rate_degrees=rate_degrees, move_speed=move_speed, rest_speed=rest_speed, rest_measure=rest_measure,
                  hold_time=hold_time, max_tilt_degrees=max_tilt_degrees, edge=edge, dt=dt)
    if not isinstance(pile, SimState):
        raise InputError("pile must be a SimState (a settled pile, e.g. from box.run).")
    u = paper1993.units(law)
    dt = float(paper1993.law_setting(law)["dt"]) if dt is None else float(dt)
    rate, move_speed, rest_speed, hold_time = (float(x) for x in (rate_degrees, move_speed, rest_speed, hold_time))
    gravity = np.asarray(pile.boundaries.gravity, dtype=np.float64)
    g = float(np.linalg.norm(gravity))
    if not (g > 0 and abs(gravity[0]) <= 1e-12 * g and gravity[1] < 0):
        raise InputError(f"the pile's gravity must point straight down (untilted); got {gravity.tolist()}.")
    p = pile.particles
    dtype = p.position.dtype
    before = pile.protocol_state
    if edge is None:
        if not hasattr(before, "edge"):
            raise InputError("give edge (the x where the floor ends) for a pile that is not a box pile.")
        edge = float(before.edge)
    edge = boxes.check_positive("edge", edge)
    if hasattr(before, "park"):
        park = np.asarray(before.park)
    else:
        r = np.asarray(p.radius)
        spacing = boxes.PARK_SPACING * 2.0 * float(r.max())
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
        use_max=jnp.asarray(boxes.measure_flag(rest_measure)),
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
        "law": boxes.law_name(law),
        "n": int(p.count),
        "rate_degrees": rate,
        "rate_degrees_per_time": rate / dt,
        "move_speed": move_speed * u.speed,
        "rest_speed": rest_speed * u.speed,
        "rest_measure": rest_measure,
        "hold_steps": hold,
        "max_tilt_degrees": float(max_tilt_degrees),
        "max_tilt_steps": int(math.ceil(max_tilt_degrees / rate)),
        "edge": edge,
        "dt": dt,
        "start_step": int(pile.step),
    }
    return Setup(particles=p, boundaries=pile.boundaries, driver=driver, protocol_state=state,
                    box=None if settings is None else settings.box, info=info)


def make_simulator(law="lee-herrmann", *, dt: float | None = None, rotation: bool | None = None,
                   integrator: str = "velocity_verlet", chunk_steps: int | None = None, **kwargs):
    """A `Simulator` running the tilt `driver` (see `box.make_simulator`)."""
    return boxes.make_simulator(law, dt=dt, rotation=rotation, integrator=integrator, chunk_steps=chunk_steps,
                                driver=driver, **kwargs)


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


law_and_params = boxes.law_and_params  # the 1993 setting, shared with `box`


def pile_facts(pile: SimState, p: Setup) -> dict:
    """The pile the tilt takes over: its angles of repose (three methods, at
    the floor's end `edge`) and whether its box run came to rest."""
    before = boxes.repose(pile, p.info["edge"])
    ps = pile.protocol_state
    return {"pile_repose": {k: v for k, v in before.items() if not k.startswith("surface")},
            "box_settled": bool(int(ps.settled_at) >= 0) if hasattr(ps, "settled_at") else None}


def _settle_steps(info, options) -> int:
    """With `settle`: `settle_time` paper seconds in steps (0 without)."""
    if not options["settle"]:
        return 0
    u = paper1993.units(info["law"])
    return int(round(boxes.check_positive("settle_time", options["settle_time"]) * u.time / info["dt"]))


def finished(info, options):
    """Moved; with `settle`, at rest again or `settle_time` after it moved;
    or the largest tilt passed without motion and its hold time after it: the
    run gives up. Traceable."""
    give_up = int(info["max_tilt_steps"])
    settle = _settle_steps(info, options)

    def done(s):
        ps = s.protocol_state
        gave_up = (ps.phase == 0) & (s.step - ps.start > give_up + ps.hold)
        if not options["settle"]:
            return (ps.phase >= 1) | gave_up
        return (ps.phase >= 2) | ((ps.phase == 1) & (s.step - ps.moved_at > settle)) | gave_up

    return done


def max_steps(info, options) -> int:
    """The tilt's budget from its start: the largest tilt, the hold after it,
    `settle_time` with `settle`, and room for `finished` to be seen at a
    chunk's end (it ends the run first)."""
    return int(info["max_tilt_steps"]) + 4 * int(info["hold_steps"]) + 10_000 + _settle_steps(info, options)


def measure(sim, params, state: SimState, p: Setup, options: dict) -> dict:
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
        **boxes.count_check(state),
    }
    if options["settle"] and out["at_rest"]:
        after = boxes.repose(state, p.info["edge"])
        out["after_repose_box_frame"] = {k: v for k, v in after.items() if not k.startswith("surface")}
    return out


DEFINITION = definition.Definition(
    "tilt", protocol, make_simulator, law_and_params, boxes.DEFINITION.default_dt, finished, max_steps, measure,
    row=("theta_t", "theta_r", "moved", "theta_r_plus_theta_t", "theta_ms_theory", "theta_t_theory", "box_settled",
         "tilt_held", "n_left"),
    run_options={"settle": False, "settle_time": SETTING["settle_time"]},
    sweep=dict(angles=("theta_t", "theta_r", "theta_r_plus_theta_t"), theory=marginal_stability_overlay,
               fit_statistics={"columns": ("theta_t", "theta_r")}),
    starts_from=boxes.DEFINITION, pile_facts=pile_facts, check_options=check_options)


def execute(sim, params, p: Setup, *, pile: SimState | None = None, settle: bool = False,
            settle_time: float = SETTING["settle_time"], progress=None, checkpoint=None, resume=None):
    """Tilts until the pile moves (or the largest tilt), then, with `settle`,
    until it is at rest again (`definition.continue_pile`).

    Args:
      pile: the state `p` was built from: continued as it is (contact history
        kept). None: start from `p.particles` with `sim.init` (fresh history).
      settle_time: at most this many paper seconds after the pile moved.
      checkpoint, resume: as in `box.execute` (a tilt checkpoint resumes on the
        same `pile`).

    Returns:
      (state, RunInfo, samples) as `runner.run_sampled`.
    """
    return definition.continue_pile(DEFINITION, sim, params, p, pile, progress=progress, checkpoint=checkpoint,
                                    resume=resume, run_options={"settle": settle, "settle_time": settle_time})


def run(law="lee-herrmann", n: int | None = None, *, pile: SimState | None = None, params=None,
        pile_params=None, rotation: bool | None = None, dt: float | None = None,
        integrator: str = "velocity_verlet", settle: bool = False, settle_time: float = SETTING["settle_time"],
        chunk_steps: int | None = None, progress=False, dtype=None, box_options: dict | None = None,
        checkpoint=None, resume=None, **options):
    """Builds a pile with the box protocol (or takes `pile`), tilts it at the
    paper's rate until it moves, and measures theta_T (`definition.run`).

    Args:
      law: `lee-herrmann` (the paper's, in cgs), `hooke`, `baxter` or `liffman`.
      n: disks of the box pile (when `pile` is None).
      pile: a settled pile to tilt (e.g. `box.run`'s state); its contact
        history is kept.
      params: the law's parameters for the tilt: None (`box.PAPER_SETTING`),
        a dict of overrides, or a params pytree.
      pile_params: the same for building the pile (default: `params`).
      settle: after the pile moved, run (tilt held) until it rests again; off
        by default: the paper stops at theta_T, and once the held tilt exceeds
        the floor's friction angle the disks slide off and never rest.
      box_options: for `box.run` (width, height, seed, max_time, ...).
      checkpoint: `(path, every[, extra])` as in `Simulator.run`: the tilt is
        saved to `path`; the box run that builds the pile (when `pile` is
        None) to `checkpoint.sibling(path, "box")` (`checkpoint.box.npz`),
        whose last save is the pile the tilt starts from.
      resume: a checkpoint of this same run: a tilt save (the pile it started
        from, named in it, is read back beside it), a box save (the box run
        is continued, then the tilt starts), or the tilt's fixed `path` before
        the tilt began (its box sibling is continued). Ends bit-identical to
        the uninterrupted run.
      **options: for `protocol` (rate_degrees, move_speed, rest_speed,
        rest_measure, hold_time, max_tilt_degrees, edge).

    Returns:
      `(state, measurements)`: `measure`'s dict, the kinetic energy per chunk,
      timings, `info`; `box` holds the box run's measurements when the pile
      was built here.
    """
    ranges.check_all(OPTION_RANGES, locals(), run)  # types, finiteness and ranges first: one message format
    if box_options:
        ranges.check_all(boxes.OPTION_RANGES, box_options, boxes.run)
    return definition.run(DEFINITION, law, n, params=params, rotation=rotation, dt=dt, integrator=integrator,
                          chunk_steps=chunk_steps, progress=progress, dtype=dtype, checkpoint=checkpoint, resume=resume,
                          run_options={"settle": settle, "settle_time": settle_time}, pile=pile,
                          pile_params=pile_params, pile_options=box_options, **options)


__all__ = [
    "DEFINITION",
    "check_options",
    "law_and_params",
    "SETTING",
    "TiltState",
    "compare_with_theory",
    "driver",
    "execute",
    "finished",
    "make_simulator",
    "max_steps",
    "measure",
    "pile_facts",
    "protocol",
    "run",
    "tilt_at",
]
