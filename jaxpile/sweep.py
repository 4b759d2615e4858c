"""Parameter sweeps over seeds: a protocol run for every (parameters, seed)
member of a grid, as batched `Ensemble` runs, with tidy results.

`sweep("box", "lee-herrmann", vary={"mu": [0.1, 0.2]}, seeds=16)` builds one
box per seed (the same 16 packings for every mu: common random numbers, so
differences between mu values are not blurred by different packings), runs
all 32 members in batches of `batch_size` in one compiled loop each, and
measures each member as the protocol's own `run` does. The rows go to a CSV
(`write_csv`), and `summarise` gives mean and standard error per grid point.

Protocols (`ADAPTERS`): `box` (Lee & Herrmann 1993: angle of repose by the
three methods), `pour` (Baxter et al. 1997: flank angles, base-force M
ratio, force balance), `lattice` and `sloped` (Liffman et al. 1992: the
ground forces against eqs. 42-44 and 54-59, e.g. against K_s) and `drop`
(1992 Fig. 20: the base profile's central dip over seeds) and `flux`
(1993 Fig. 5: the steady angle under a flux of disks) and `tilt` (1993
Fig. 4: a box pile, then tilted until it moves: theta_T; two stages, each
member starting the second where it ended the first).
"""

from __future__ import annotations

import dataclasses
import itertools
import math
import time
from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np

import jax.numpy as jnp

from jaxpile import budget as memory
from jaxpile import ensemble
from jaxpile.errors import InputError
from jaxpile.simulate import RunInfo, max_speed


@dataclass(frozen=True)
class Stage:
    """A later stage of a protocol (the tilt after the box): it starts from
    each member's state at the end of the stage before it.

    Attributes:
      simulator: `(law, dt, sim_options, options) -> Simulator` for this stage.
      start: `(law, dt, options, state, protocol) -> (state, protocol)`, on the
        host, per member: the stage's start state (contact history kept) and
        its protocol. Structure only (it also builds a resume's template).
      finished: `(protocol info, options) -> (state -> bool)`, traceable.
      max_steps: `(protocol info, options) -> int`, this stage's budget.
      describe: optional `(state) -> dict` of plain numbers measured on the
        previous stage's end state, merged into the protocol's `info` (and
        saved with each checkpoint of this stage, for the measurement after a
        resume).
    """

    simulator: Callable
    start: Callable
    finished: Callable
    max_steps: Callable
    describe: Callable | None = None


@dataclass(frozen=True)
class Adapter:
    """What a sweep needs from a protocol.

    Attributes:
      setup: `(law, seed, dt, options) -> Protocol` for one member.
      simulator: `(law, dt, options) -> Simulator` shared by the batch.
      finished: `(protocol info, options) -> (state -> bool)`, traceable, per member.
      max_steps: `(protocol info, options) -> int`, the step budget.
      measure: `(sim, params, state, protocol) -> dict` of plain numbers.
      law_and_params: the protocol module's `law_and_params`.
      default_dt: `(law) -> float`.
      angles: the angle columns to summarise and plot (the first is the headline).
      options: the set-up options a sweep accepts.
      theory: optional `(name, values) -> (label, degrees)` to overlay on angles.
      unit: of the `angles` columns, for the printed summary.
      default_law: the protocol paper's law.
      extent: optional `(protocol) -> (base, x_left, x_right)`: where the base
        profile of a member is read for fitting (`ensemble_fit`); the same
        for every member of a protocol's set-up, so profiles average.
      fit_statistics: what an ensemble fit compares by default:
        `{"columns": (...), "bins": b}` (`ensemble_fit.Statistics`).
      deterministic: every seed builds the same pile (the 1992 lattice and
        sloped piles): one seed is an ensemble.
      stages: later `Stage`s (stage-synchronous: every member of a batch
        finishes a stage before the next starts); `measure` then gets the
        last stage's simulator, state and protocol.
    """

    setup: Callable
    simulator: Callable
    finished: Callable
    max_steps: Callable
    measure: Callable
    law_and_params: Callable
    default_dt: Callable
    angles: tuple
    options: frozenset
    theory: Callable | None = None
    unit: str = "deg"
    default_law: str = "lee-herrmann"
    extent: Callable | None = None
    fit_statistics: dict = dataclasses.field(default_factory=dict)
    stages: tuple = ()
    deterministic: bool = False


def _heap_extent(base: str, centre_key: str, count_key: str):
    """A random heap's profile range: its axis +- 1.6 sqrt(n) diameters, wider
    than a heap of n unit disks at 20 degrees (base 2.9 sqrt(n) at packing 0.82)."""
    def extent(protocol):
        half = 1.6 * math.sqrt(float(protocol.info[count_key]))
        centre = float(protocol.info[centre_key])
        return base, centre - half, centre + half
    return extent


def _bottom_row_extent(protocol):
    """A deterministic pile on the ground: the bottom row's outer edges."""
    p = protocol.particles
    y, x, r = np.asarray(p.position[:, 1]), np.asarray(p.position[:, 0]), np.asarray(p.radius)
    row = np.abs(y - y.min()) < 0.25 * r.min()
    return "ground", float((x - r)[row].min()), float((x + r)[row].max())


def _marginal_stability(name, values):
    from jaxpile import theory

    if name != "mu":
        return None
    return "theta_MS = arctan(3 mu) (1993 eq. 3)", np.degrees(theory.marginal_stability_angle(np.asarray(values)))


def _option_names(setup, *extra) -> frozenset:
    import inspect

    names = set(inspect.signature(setup).parameters) - {"law", "seed", "dt", "dtype"}
    return frozenset(names | set(extra))


# ------------------------------------------------------------------------ box
def _settled(info, options):
    """The 1993 family's end (box, flux): the driver's rest detector has fired."""
    return lambda s: s.protocol_state.settled_at >= 0


def _max_time_steps(default_max_time: float):
    """The 1993 family's budget: `max_time` (paper seconds) in steps of the member's dt."""
    from jaxpile.protocols import box

    return lambda info, options: box.max_steps_for(info["law"], info["dt"], options.get("max_time", default_max_time))


def _box_adapter() -> Adapter:
    from jaxpile.protocols import box

    def setup(law, seed, dt, options):
        return box.protocol(law=law, seed=seed, dt=dt, **{k: v for k, v in options.items() if k != "max_time"})

    def simulator(law, dt, options, setup_options):
        return box.make_simulator(law, dt=dt, **options)

    def measure(sim, params, state, protocol):
        ps = state.protocol_state
        angles = box.repose(state, protocol.info["width"])
        return {k: angles[k] for k in ("repose_endpoints", "repose_least_squares", "repose_cumulative_parabola")} | {
            "at_rest": int(ps.settled_at) >= 0, "wall_removed_step": int(ps.removed_at),
            "settled_step": int(ps.settled_at), "n_left": int(ps.left), "fill_height": float(ps.fill_height)}

    return Adapter(setup, simulator, _settled, _max_time_steps(box.PAPER_SETTING["max_time"]), measure,
                   box.law_and_params,
                   lambda law: float(box.law_setting(law)["dt"]),
                   ("repose_cumulative_parabola", "repose_least_squares", "repose_endpoints"),
                   _option_names(box.protocol, "max_time"), _marginal_stability,
                   extent=lambda protocol: ("ground", 0.0, float(protocol.info["width"])),
                   fit_statistics={"columns": ("repose_least_squares", "repose_cumulative_parabola")})


# ----------------------------------------------------------------------- pour
def _pour_adapter() -> Adapter:
    from jaxpile.protocols import pour

    def setup(law, seed, dt, options):
        options = {k: v for k, v in options.items() if k not in ("speed_tolerance", "max_settle_steps")}
        return pour.pour(seed=seed, dt=dt, **options)

    def simulator(law, dt, options, setup_options):
        return pour.make_simulator(law, dt=dt, **options)

    def finished(info, options):
        # as pour.execute: every disk poured, then at rest
        pour_steps = int(info["pour_steps"])
        tolerance = float(options.get("speed_tolerance", pour.PAPER_SETTING["speed_tolerance"]))
        return lambda s: (s.step >= pour_steps) & (max_speed(s) < tolerance)

    def max_steps(info, options):
        return int(info["pour_steps"]) + int(options.get("max_settle_steps", pour.PAPER_SETTING["max_settle_steps"]))

    def measure(sim, params, state, protocol):
        m = pour.summary(pour.measure(sim, params, state))
        out = {"in_play": m["counts"]["in_play"], "lost": m["counts"]["lost"], "force_balance": m["force_balance"]}
        for key in ("height", "base_width", "angle_height_base", "core_packing_fraction"):
            out[key] = m.get(key, float("nan"))
        for flank in ("left", "right"):
            a = (m.get("angle_of_repose") or {}).get(flank) or {}
            out[f"repose_{flank}"] = a.get("cumulative_parabola", float("nan"))
        out["repose_mean"] = 0.5 * (out["repose_left"] + out["repose_right"])
        ms = m.get("m_shape") or {}
        out["m_ratio"] = ms.get("ratio", float("nan"))
        out["m_shaped"] = bool(ms.get("m_shaped", False))
        return out

    return Adapter(setup, simulator, finished, max_steps, measure, pour.law_and_params,
                   lambda law: float(pour.PAPER_SETTING["dt"]), ("repose_mean", "angle_height_base"),
                   _option_names(pour.pour, "speed_tolerance", "max_settle_steps"), _marginal_stability,
                   default_law="baxter", extent=_heap_extent("substrate", "centre_x", "n_poured"),
                   fit_statistics={"columns": ("repose_mean",), "bins": 9})


# ------------------------------------------------------------ lattice, sloped
def _loaded_pile_adapter(name: str) -> Adapter:
    """The 1992 static piles: a gravity ramp, then a run to rest (as
    `lattice.relax`; the batch's predicate: past the ramp and every member's
    fastest disk below `speed_tolerance`). Deterministic piles: seeds repeat
    the same pile, so a sweep varies the law (K_s, mu_roll, ...)."""
    from jaxpile import analysis
    from jaxpile.protocols import lattice, sloped
    from jaxpile.protocols.base import Protocol, law_and_params as base_law_and_params
    from jaxpile.simulate import Simulator, gravity_ramp

    setting = lattice.PAPER_SETTING if name == "lattice" else sloped.SETTING
    run_options = ("ramp_steps", "speed_tolerance", "max_steps")

    def value(options, key):
        return options.get(key, setting[key])

    def setup(law, seed, dt, options):
        dtype = options.get("dtype")
        if name == "lattice":
            layers = int(options.get("layers", options.get("n", setting["layers"])))
            particles, boundaries = lattice.equilateral_pile(layers, dtype=dtype)
            info = {"layers": layers}
        else:
            kwargs = {k: v for k, v in options.items() if k not in run_options + ("dtype",)}
            p = sloped.protocol(kwargs.pop("alpha_degrees", setting["alpha_degrees"]), dtype=dtype, **kwargs)
            particles, boundaries, info = p.particles, p.boundaries, dict(p.info)
        return Protocol(particles=particles, boundaries=boundaries,
                        info={**info, "dt": dt, "speed_tolerance": float(value(options, "speed_tolerance"))})

    def simulator(law, dt, options, setup_options):
        _, contact_law, _ = law_and_params(law, None, options.get("rotation"))
        return Simulator(contact_law, dt, schedule=gravity_ramp(int(value(setup_options, "ramp_steps"))))

    def finished(info, options):
        ramp, tolerance = int(value(options, "ramp_steps")), float(value(options, "speed_tolerance"))
        return lambda s: (s.step >= ramp) & (max_speed(s) < tolerance)

    def max_steps(info, options):
        return int(value(options, "max_steps"))

    def measure(sim, params, state, protocol):
        base = analysis.base_forces(sim, params, state)
        if name == "lattice":
            m = lattice.compare_with_theory(base, protocol.info["layers"])
        else:
            n_in = int(np.asarray(state.particles.active).sum())
            m = sloped.compare_with_theory(base, protocol.info["alpha_degrees"], protocol.info["base"], n_particles=n_in)
        row = {k: v for k, v in m.items() if np.ndim(v) == 0 and not isinstance(v, str)}
        p = state.particles
        active = np.asarray(p.active)
        # the pile's top above the ground: it sinks by the contacts' compression, ~ weight / K_s
        height = float(np.max((np.asarray(p.position[:, 1]) + np.asarray(p.radius))[active]))
        return row | {"height": height, "at_rest": bool(max_speed(state) < protocol.info["speed_tolerance"]),
                      "max_speed": float(max_speed(state))}

    def law_and_params(law, params=None, rotation=None, dtype=None):
        if name == "sloped":
            return sloped.law_and_params(law, params, rotation, dtype=dtype)
        return base_law_and_params(law, params, rotation, setting=setting, dtype=dtype)

    headline = (("max_rel_dev_normal", "max_rel_dev_horizontal") if name == "lattice"
                else ("central_normal_rel_dev", "central_slope_horizontal"))
    names = {"layers"} if name == "lattice" else _option_names(sloped.protocol) - {"seed"}
    return Adapter(setup, simulator, finished, max_steps, measure, law_and_params, lambda law: float(setting["dt"]),
                   headline, frozenset(names | set(run_options) | {"n"}), None, unit="", default_law="hooke",
                   extent=_bottom_row_extent, fit_statistics={"bins": 9}, deterministic=True)


# ----------------------------------------------------------------------- drop
def _drop_adapter() -> Adapter:
    """Liffman et al. 1992 Fig. 20: disks dropped one at a time, then relaxed.
    The batch's predicate: every disk in, the last one in for `quiet_time`, and
    every member's fastest disk below `speed_tolerance` (a single run fills,
    then relaxes; the batch checks both at each chunk's end)."""
    from jaxpile.protocols import drop
    from jaxpile.simulate import Simulator

    setting = drop.SETTING
    run_options = ("speed_tolerance", "relax_steps", "bins", "dip_threshold")

    def setup_kwargs(options):
        return {k: v for k, v in options.items() if k not in run_options + ("dtype",)}

    def setup(law, seed, dt, options):
        p = drop.protocol(seed=seed, dt=dt, dtype=options.get("dtype"), **setup_kwargs(options))
        info = {**p.info, "bins": int(options.get("bins", 15)), "dip_threshold": float(options.get("dip_threshold", 0.05))}
        return p._replace(driver=None, info=info)  # the simulator's driver (the same constants for every member)

    def simulator(law, dt, options, setup_options):
        _, contact_law, _ = drop.law_and_params(law, None, options.get("rotation"))
        p = drop.protocol(seed=0, dt=dt, **setup_kwargs(setup_options))
        # each chunk on the block of disks dropped by its end, as `drop.run`
        return Simulator(contact_law, dt, driver=p.driver, capacity_multiplier=4.0,
                         in_play=drop.make_in_play(p.info["quiet_steps"]))

    def finished(info, options):
        quiet, tolerance = int(info["quiet_steps"]), float(options.get("speed_tolerance", setting["speed_tolerance"]))
        return lambda s: (jnp.all(s.particles.active) & (s.step - s.protocol_state.last_insert >= quiet)
                          & (max_speed(s) < tolerance))

    def max_steps(info, options):
        n = int(info["n_particles"])
        return n * int(info["max_interval_steps"]) + 1000 + int(options.get("relax_steps", setting["relax_steps"]))

    def measure(sim, params, state, protocol):
        m = drop.measure(sim, params, state, bins=protocol.info["bins"], dip_threshold=protocol.info["dip_threshold"])
        row = {k: v for k, v in m.items() if np.ndim(v) == 0 and not isinstance(v, str)}
        return row | {"all_inserted": bool(np.asarray(state.particles.active).all()),
                      "max_speed": float(max_speed(state))}

    return Adapter(setup, simulator, finished, max_steps, measure, drop.law_and_params,
                   lambda law: float(setting["dt"]), ("central_dip",),
                   _option_names(drop.protocol, *run_options), None, unit="", default_law="liffman",
                   extent=_heap_extent("ground", "axis_x", "n_particles"),
                   fit_statistics={"columns": ("central_dip",), "bins": 9})


# ----------------------------------------------------------------------- flux
def _flux_adapter() -> Adapter:
    """Lee & Herrmann 1993 Fig. 5: disks fed one at a time onto a fixed layer;
    per member the angle (method 3) before each insertion and its steady mean
    over the second half of the insertions (as `flux.run`)."""
    from jaxpile.protocols import box, flux

    def setup(law, seed, dt, options):
        kwargs = {k: v for k, v in options.items() if k not in ("max_time", "n")}
        return flux.protocol(int(options.get("n", flux.SETTING["insertions"])), law=law, seed=seed, dt=dt, **kwargs)

    def simulator(law, dt, options, setup_options):
        return flux.make_simulator(law, dt=dt, **options)

    def measure(sim, params, state, protocol):
        ps = state.protocol_state
        done = int(ps.inserted)
        record = flux.angles(float(ps.x_min), float(ps.column_width), np.asarray(ps.profile)[:done])
        main = np.asarray(record["cumulative_parabola"], dtype=float)
        late = main[done // 2:]
        late = late[np.isfinite(late)]
        nan = float("nan")
        final = box.repose(state, protocol.info["width"])
        return {"inserted": done, "steady_mean": float(np.mean(late)) if late.size else nan,
                "steady_std": float(np.std(late)) if late.size else nan,
                "repose_cumulative_parabola": final["repose_cumulative_parabola"],
                "at_rest": int(ps.settled_at) >= 0, "settled_step": int(ps.settled_at), "n_left": int(ps.left)}

    return Adapter(setup, simulator, _settled, _max_time_steps(flux.SETTING["max_time"]), measure, flux.law_and_params,
                   lambda law: float(box.law_setting(law)["dt"]), ("steady_mean", "repose_cumulative_parabola"),
                   _option_names(flux.protocol, "max_time", "n") - {"insertions"}, _marginal_stability,
                   fit_statistics={"columns": ("steady_mean",)})


# ----------------------------------------------------------------------- tilt
def _tilt_adapter() -> Adapter:
    """Lee & Herrmann 1993 Fig. 4: a box pile (stage 1, as `box`), then tilted
    at the paper's rate until it moves (stage 2, as `tilt.run` without
    `settle`): theta_T, the pile's theta_R and the theory of sec. 6."""
    from jaxpile.protocols import box, tilt

    base = _box_adapter()
    tilt_names = _option_names(tilt.protocol) - {"pile", "edge"}
    box_names = base.options

    def box_options(options):
        return {k: v for k, v in options.items() if k in box_names}

    def setup(law, seed, dt, options):
        return base.setup(law, seed, dt, box_options(options) | {"dtype": options.get("dtype")})

    def simulator(law, dt, options, setup_options):
        return tilt.make_simulator(law, dt=dt, **options)

    def start(law, dt, options, state, protocol):
        p = tilt.protocol(state, law=law, dt=dt, **{k: v for k, v in options.items() if k in tilt_names})
        return state.set(protocol_state=p.protocol_state), p

    def describe(state):
        pile = box.repose(state, float(state.protocol_state.edge))
        return {"pile_repose": {k: v for k, v in pile.items() if not k.startswith("surface")},
                "box_settled": int(state.protocol_state.settled_at) >= 0}

    def finished(info, options):
        give_up = int(info["max_tilt_steps"])  # as tilt.execute: moved, or the largest tilt passed without motion
        return lambda s: (s.protocol_state.phase >= 1) | (
            (s.protocol_state.phase == 0) & (s.step - s.protocol_state.start > give_up + s.protocol_state.hold))

    def max_steps(info, options):
        return int(info["max_tilt_steps"]) + 4 * int(info["hold_steps"]) + 10_000

    def measure(sim, params, state, protocol):
        ps = state.protocol_state
        moved = int(ps.phase) >= 1
        theta_t = math.degrees(float(ps.theta_t)) if moved else float("nan")
        theta_r = protocol.info["pile_repose"]["repose_cumulative_parabola"]
        mu = box.friction_coefficient(params)
        theory = tilt.compare_with_theory(theta_r, theta_t, mu)
        return {"theta_t": theta_t, "theta_r": theta_r, "moved": moved,
                "theta_r_plus_theta_t": theory["theta_r_plus_theta_t"], "theta_ms_theory": theory["theta_ms_theory"],
                "theta_t_theory": theory["theta_t_theory"], "box_settled": protocol.info["box_settled"],
                "tilt_held": math.degrees(float(ps.tilt)), "n_left": int(ps.left)}

    return Adapter(setup, base.simulator, base.finished, base.max_steps, measure, box.law_and_params, base.default_dt,
                   ("theta_t", "theta_r", "theta_r_plus_theta_t"), frozenset(box_names | tilt_names),
                   _marginal_stability, fit_statistics={"columns": ("theta_t", "theta_r")},
                   stages=(Stage(simulator, start, finished, max_steps, describe),))


ADAPTERS: dict[str, Callable[[], Adapter]] = {"flux": _flux_adapter, "tilt": _tilt_adapter,
    "box": _box_adapter, "pour": _pour_adapter, "lattice": lambda: _loaded_pile_adapter("lattice"),
    "sloped": lambda: _loaded_pile_adapter("sloped"), "drop": _drop_adapter}


def adapters() -> dict[str, Callable[[], Adapter]]:
    """Every protocol a sweep (and an ensemble fit) runs: the papers' seven
    (`ADAPTERS`), and any registered protocol whose module has a
    `sweep_adapter() -> Adapter` (a new protocol brings its own)."""
    from jaxpile.protocols import PROTOCOLS

    found = dict(ADAPTERS)
    for name, module in PROTOCOLS.items():
        if name not in found and callable(getattr(module, "sweep_adapter", None)):
            found[name] = module.sweep_adapter
    return found


def adapter(protocol: str) -> Adapter:
    known = adapters()
    if protocol not in known:
        raise InputError(f"sweeps run the protocols {sorted(known)}; got {protocol!r}.")
    return known[protocol]()


# ---------------------------------------------------------------------- sweep
@dataclass
class SweepResult:
    """Rows (one dict per member: the varied parameters, seed, measurements,
    steps) and the set-up and timings (`info`)."""

    rows: list
    info: dict

    def column(self, name: str) -> np.ndarray:
        return np.array([r.get(name, np.nan) for r in self.rows], dtype=float)


def grid(vary: dict, seeds) -> list[tuple[dict, int]]:
    """Every (parameter values, seed) member: the product of the varied values,
    each with every seed."""
    for name, values in vary.items():
        if len(values) == 0:
            raise InputError(f"the sweep over {name!r} has no values.")
    seeds = list(range(int(seeds))) if np.ndim(seeds) == 0 else [int(s) for s in seeds]
    if not seeds:
        raise InputError("a sweep needs at least one seed.")
    names = list(vary)
    points = [dict(zip(names, combo)) for combo in itertools.product(*(vary[n] for n in names))] or [{}]
    return [(point, seed) for point in points for seed in seeds]


_ENSEMBLES: dict = {}  # the last few batched simulators, so repeated sweeps (a fit's iterations) compile once


def _ensemble(protocol, stage, law, dt, sim_options, options, devices, build) -> ensemble.Ensemble:
    """The `Ensemble` for this protocol stage and set-up: reused when a sweep
    with the same law, dt, simulator and set-up options ran before (its
    compiled loops are kept per batch shape); built afresh otherwise."""
    try:
        key = (protocol, stage, law, float(dt), tuple(sorted(sim_options.items())),
               tuple(sorted(options.items())), None if devices is None else tuple(devices))
        hash(key)
    except TypeError:  # an option that is a dict or a list: no reuse
        return ensemble.Ensemble(build(), devices=devices)
    if key not in _ENSEMBLES:
        if len(_ENSEMBLES) >= 4:
            _ENSEMBLES.pop(next(iter(_ENSEMBLES)))
        _ENSEMBLES[key] = ensemble.Ensemble(build(), devices=devices)
    return _ENSEMBLES[key]


def sweep(protocol: str = "box", law: str | None = None, *, vary: dict[str, Sequence[float]] | None = None,
          seeds=4, params: dict | None = None, options: dict | None = None, dt: float | None = None,
          rotation: bool | None = None, max_steps: int | None = None, batch_size: int | None = None,
          devices=None, progress: bool | None = None, dtype=None, checkpoint: tuple | None = None,
          resume=None, points: Sequence[dict] | None = None, extra_measure: Callable | None = None) -> SweepResult:
    """Runs a protocol for every member of `grid(vary, seeds)`, batched.

    Args:
      protocol: a name in `ADAPTERS` (box, pour, lattice, sloped, drop, flux, tilt).
      law: the contact law (default: the protocol paper's).
      vary: law parameter name -> values, e.g. `{"mu": [0.1, 0.2, 0.3]}`.
      seeds: a count (seeds 0..n-1) or a list of seeds.
      params: fixed overrides of the protocol's law setting.
      options: for the protocol's set-up (e.g. `n`, `width`, `height`).
      dt, rotation: for the simulator (default: the protocol's).
      max_steps: step budget of the first stage (default: the protocol's;
        a later stage, e.g. the tilt, has its own).
      batch_size: members per compiled batch (default: all at once).
      devices: to shard each batch over (default: all `jax.devices()`).
      progress: progress bars (default: when stderr is a terminal).
      checkpoint: `(path, every[, extra])` as in `Simulator.run`: the running
        batch is saved every `every` steps, with the rows of the batches
        already measured, the batch it belongs to and the grid.
      resume: a checkpoint file of this same sweep: the batches it had
        measured are taken from it, its batch is continued from the saved
        state, and the sweep ends as the uninterrupted one would (rows equal).
      points: instead of `vary`'s product grid, these law-parameter points
        (dicts), each run with every seed (a fit's perturbed parameters).
      extra_measure: `(sim, params, state, protocol) -> dict` merged into each
        member's row (e.g. its base profile as an array).

    Returns:
      `SweepResult`.
    """
    a = adapter(protocol)
    law = law or a.default_law
    vary = {k: [float(v) for v in vals] for k, vals in (vary or {}).items()}
    options = dict(options or {})
    unknown = set(options) - a.options
    if unknown:
        raise InputError(f"unknown option(s) {sorted(unknown)} for a {protocol} sweep; known: {sorted(a.options)}.")
    if points is not None:
        if vary:
            raise InputError("give a sweep either `vary` (a grid) or `points`, not both.")
        points = [{k: float(v) for k, v in dict(point).items()} for point in points]
        if not points:
            raise InputError("a sweep over `points` needs at least one point.")
        members = [(point, seed) for point in points for _, seed in grid({}, seeds)]
    else:
        members = grid(vary, seeds)
    dt = a.default_dt(law) if dt is None else float(dt)
    member_params = []
    for point, _ in members:
        _, _, prm = a.law_and_params(law, {**(params or {}), **point}, rotation, dtype=dtype)  # checks the names
        member_params.append(prm)
    sim_options = {} if rotation is None else {"rotation": rotation}
    ens = _ensemble(protocol, 0, law, dt, sim_options, options, devices,
                    lambda: a.simulator(law, dt, sim_options, options))
    sim = ens.sim
    batch_size = len(members) if batch_size is None else int(batch_size)
    if batch_size < 1:
        raise InputError(f"batch_size must be >= 1; got {batch_size}.")

    from jaxpile import checkpoint as ckpt

    rows, info = [], RunInfo()
    plan = [[point, seed] for point, seed in members]
    first, saved = 0, {}
    if resume is not None:
        saved = ckpt.read_metadata(resume)["extra"]
        if saved.get("grid") != plan or saved.get("batch_size") != batch_size:
            raise InputError(f"{resume} was written by another sweep (other members or batch size); "
                             "resume it with the command that made it.")
        if saved.get("devices") != len(ens.devices):
            raise InputError(f"{resume} was written on {saved.get('devices')} device(s), this run has "
                             f"{len(ens.devices)}: the batch is padded to a multiple of the device count, so "
                             "resume it with as many devices.")
        rows, first = list(saved["rows"]), int(saved["batch_start"])
    t0 = time.perf_counter()
    for start in range(first, len(members), batch_size):
        chunk = members[start:start + batch_size]
        prms = member_params[start:start + batch_size]
        protocols = [a.setup(law, seed, dt, {**options, "dtype": dtype}) for _, seed in chunk]
        budget = max_steps if max_steps is not None else a.max_steps(protocols[0].info, options)
        memory.check(protocols[0].particles.count, dtype or "float64", batch=len(chunk),
                     what=f"a batch of the {protocol} sweep")  # before the batch is stacked and compiled
        state = ens.init(prms, protocols)
        resuming = resume is not None and start == first
        at_stage = int(saved.get("stage", 0)) if resuming else 0
        saved_params = ens._as_batch(prms, ensemble.batch_size(state))  # as `Ensemble.run` records them
        if at_stage == 0:
            if resuming:
                state = ens.shard(ckpt.restore(resume, state, sim.law, saved_params))
            # the rows list is written as it stands at each save: the batches measured so far
            spec = ckpt.with_facts(checkpoint, grid=plan, batch_size=batch_size, devices=len(ens.devices),
                                   batch_start=start, rows=rows, stage=0)
            state = ens.run(prms, state, max(int(budget) - ckpt.step_of(state), 0),
                            until=a.finished(protocols[0].info, options), progress=progress, info=info,
                            checkpoint=spec)
        last_sim = sim
        for k, stage in enumerate(a.stages, 1):  # every member starts the next stage from where it ended the last
            stage_ens = _ensemble(protocol, k, law, dt, sim_options, options, devices,
                                  lambda: stage.simulator(law, dt, sim_options, options))
            last_sim = stage_ens.sim
            if k < at_stage:  # a resume past this stage: its start only shapes the template
                started = [stage.start(law, dt, options, ensemble.member(state, i), p) for i, p in enumerate(protocols)]
                protocols = [p for _, p in started]
                state = ensemble.stack_states([s for s, _ in started])
                continue
            started = [stage.start(law, dt, options, ensemble.member(state, i), p) for i, p in enumerate(protocols)]
            if k == at_stage:  # the saved stage: its start steps and measured infos come from the file
                infos, starts = saved["stage_infos"], [int(x) for x in saved["stage_start_steps"]]
                protocols = [p._replace(info=info) for (_, p), info in zip(started, infos)]
                template = stage_ens.shard(ensemble.stack_states([s for s, _ in started]))
                state = stage_ens.shard(ckpt.restore(resume, template, last_sim.law, saved_params))
                steps = ensemble.members(state, len(chunk))
                done = max(int(m.step) - s0 for m, s0 in zip(steps, starts))
            else:
                described = [stage.describe(ensemble.member(state, i)) if stage.describe else {}
                             for i in range(len(chunk))]
                protocols = [p._replace(info={**p.info, **d}) for (_, p), d in zip(started, described)]
                starts = [int(s.step) for s, _ in started]
                state = stage_ens.shard(ensemble.stack_states([s for s, _ in started]))
                done = 0
            spec = ckpt.with_facts(checkpoint, grid=plan, batch_size=batch_size, devices=len(ens.devices),
                                   batch_start=start, rows=rows, stage=k, stage_start_steps=starts,
                                   stage_infos=[p.info for p in protocols])
            state = stage_ens.run(prms, state, max(stage.max_steps(protocols[0].info, options) - done, 0),
                                  until=stage.finished(protocols[0].info, options), progress=progress, info=info,
                                  checkpoint=spec)
        for k, ((point, seed), prm, p) in enumerate(zip(chunk, prms, protocols)):
            s = ensemble.member(state, k)
            row = {"member": start + k, **point, "seed": seed}
            row.update(a.measure(last_sim, prm, s, p))
            if extra_measure is not None:
                row.update(extra_measure(last_sim, prm, s, p))
            row["steps"] = int(s.step)
            rows.append(row)
    n_particles = int(state.particles.position.shape[1])
    record = {"protocol": protocol, "law": law, "vary": vary, "seeds": sorted({s for _, s in members}),
              "params": params or {}, "options": options, "dt": dt, "members": len(members),
              "batch_size": batch_size, "devices": len(ens.devices), "n_particles": n_particles,
              "batch_steps": info.steps, "compile_seconds": info.compile_seconds,
              "run_seconds": info.wall_seconds, "total_seconds": time.perf_counter() - t0,
              "neighbor_reallocations": info.reallocations,
              "particle_steps_per_second": len(members) * n_particles * info.steps / max(info.wall_seconds, 1e-12),
              "angles": list(a.angles), "unit": a.unit}
    if points is not None:
        record["points"] = points
    return SweepResult(rows, record)


def summarise(result: SweepResult, by: str, value: str) -> dict:
    """Mean, standard error and count of `value` at each value of `by` (NaNs,
    e.g. unmeasurable surfaces, left out and counted in `missing`)."""
    x, y = result.column(by), result.column(value)
    out = {"x": [], "mean": [], "stderr": [], "count": [], "missing": []}
    for v in sorted(set(x[np.isfinite(x)].tolist())):
        sel = y[x == v]
        ok = sel[np.isfinite(sel)]
        out["x"].append(v)
        out["mean"].append(float(ok.mean()) if ok.size else math.nan)
        out["stderr"].append(float(ok.std(ddof=1) / math.sqrt(ok.size)) if ok.size > 1 else math.nan)
        out["count"].append(int(ok.size))
        out["missing"].append(int(sel.size - ok.size))
    return out


def write_csv(path, result: SweepResult) -> None:
    """The rows as a tidy CSV (one row per member, one column per quantity)."""
    import csv

    columns = []
    for row in result.rows:
        for key in row:
            if key not in columns:
                columns.append(key)
    with open(path, "w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=columns)
        writer.writeheader()
        for row in result.rows:
            writer.writerow({k: row.get(k, "") for k in columns})


def _cell(text: str):
    """A CSV cell as written by `write_csv`: a number, a bool, empty (None) or text."""
    if text == "":
        return None
    if text in ("True", "False"):
        return text == "True"
    try:
        number = float(text)
    except ValueError:
        return text
    return int(number) if number.is_integer() and "." not in text and "e" not in text.lower() else number


def read(folder) -> SweepResult:
    """The `SweepResult` of a `jaxpile sweep` folder, from its `sweep.csv` and
    `sweep.json` (what `jaxpile show` redraws from)."""
    import csv
    import json
    import os

    paths = [os.path.join(folder, name) for name in ("sweep.csv", "sweep.json")]
    missing = [p for p in paths if not os.path.exists(p)]
    if missing:
        raise InputError(f"{folder} is not a finished `jaxpile sweep` folder ({', '.join(missing)} missing).")
    with open(paths[0], newline="") as fh:
        rows = [{k: _cell(v) for k, v in row.items()} for row in csv.DictReader(fh)]
    with open(paths[1]) as fh:
        info = json.load(fh)
    return SweepResult(rows, info)


def figure(result: SweepResult, by: str | None = None, path=None):
    """Mean +- standard error of the protocol's angles against the varied
    parameter `by` (default: the first varied one), with the theory overlaid
    where there is one (theta_MS = arctan 3 mu for friction)."""
    from jaxpile import plot

    by = by or next(iter(result.info["vary"]), None)
    if by is None:
        raise InputError("the sweep varied no parameter: nothing to plot against.")
    series = {name: summarise(result, by, name) for name in result.info["angles"]}
    a = adapter(result.info["protocol"])
    x = result.column(by)
    theory_x = np.linspace(np.nanmin(x), np.nanmax(x), 50)
    theory = a.theory(by, theory_x) if a.theory else None
    title = (f"{result.info['protocol']} / {result.info['law']}: {result.info['members']} members, "
             f"{len(result.info['seeds'])} seeds each")
    return plot.sweep_figure(series, by, theory=None if theory is None else (theory_x, *theory), title=title,
                             path=path)


__all__ = ["ADAPTERS", "Adapter", "SweepResult", "adapter", "figure", "grid", "read", "summarise", "sweep",
           "write_csv"]
