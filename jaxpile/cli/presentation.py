"""How the commands show each protocol (`jaxpile pile|sweep|fit|show|compare`),
keyed by the protocol's name: its place in listings, its help, the summary keys
`pile` prints, which generic flags it takes, its figures and `compare`'s column.

A protocol module holds physics alone; what a person reads of a run is here.
A protocol with no entry is shown plainly (`presentation`): its name as help,
listed after the papers', the generic flags refused.

Each figure function takes `(measured, title, out)` (the protocol's `run`
measurements, or the summary.json `jaxpile show` reads them back from; the
figure title; the output folder) and returns the files it wrote (none when
the run measured nothing to draw).
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True)
class Presentation:
    """How the commands show a protocol.

    Attributes:
      order: its place in listings (the papers' order).
      help: one line for `--protocol`'s help.
      headline: summary keys `jaxpile pile` prints at its end (dotted keys
        reach into nested dicts).
      flags: generic flag (`max_steps`, `speed_tol`, `ramp_steps`,
        `hard_collisions`) -> the option it sets; `seed` -> `seed` where the
        protocol takes a seed. Absent: the flag is refused.
      base_forces: `(sim, params, state, measured) -> BaseForces` written to
        base_forces.csv; None: the ground's (`analysis.base_forces`).
      summary: `measured -> dict` of plain numbers for summary.json; None:
        the measurements as they are, arrays as lists.
      length_unit: `law name -> unit` of pile.png's axes; None: diameters.
      profile_theory: `(measured, base) -> (N, H, label) | None`, drawn on profile.png.
      figures: `(measured, title, out) -> [files]`, the protocol's own figures.
      compare: `summary -> str`, the result column of `jaxpile compare`;
        None: the headline's first line.
    """

    order: int
    help: str
    headline: tuple = ()
    flags: dict = field(default_factory=dict)
    base_forces: Callable | None = None
    summary: Callable | None = None
    length_unit: Callable | None = None
    profile_theory: Callable | None = None
    figures: tuple = ()
    compare: Callable | None = None


# ---------------------------------------------------------------- figures and pieces


def energy_figure(measured: dict, title: str, out: str) -> list[str]:
    """energy.png: kinetic energy per disk against time (Lee & Herrmann 1993 Fig. 1b)."""
    from jaxpile import plot

    time, energy = energy_series(measured)
    if not len(time):
        return []
    plot.series_figure(time, {"kinetic energy per disk": energy}, xlabel="time", ylabel="E_kin per disk",
                       logy=True, title=title + " (Lee & Herrmann 1993 Fig. 1b)", path=os.path.join(out, "energy.png"))
    return ["energy.png"]


def energy_series(measured: dict) -> tuple[np.ndarray, np.ndarray]:
    """The kinetic energy per disk against time, the samples with energy > 0 alone
    (a log axis: the start at rest, E = 0, would stretch it to 1e-300)."""
    ke = measured.get("kinetic_energy") or {}
    time = np.asarray(ke.get("time", []), dtype=float)
    energy = np.asarray(ke.get("kinetic_energy", []), dtype=float)
    keep = np.isfinite(energy) & (energy > 0)
    return time[keep], energy[keep]


def angles_figure(measured: dict, title: str, out: str) -> list[str]:
    """angles.png: the pile's angle by the three methods after each insertion (1993 Fig. 5)."""
    from jaxpile import plot

    if not measured.get("inserted"):
        return []
    k = np.arange(1, measured["inserted"] + 1)
    series = {f"method {i}": measured[f"angle_{key}"] for i, key in
              enumerate(("endpoints", "least_squares", "cumulative_parabola"), start=1)}
    plot.series_figure(k, series, xlabel="insertion", ylabel="pile angle (deg)",
                       hlines={"theta_MS (eq. 3)": measured.get("theta_ms_theory"),
                               "steady mean": measured.get("steady_mean")},
                       title=title + " (Lee & Herrmann 1993 Fig. 5)", path=os.path.join(out, "angles.png"))
    return ["angles.png"]


def heap_profile_figure(measured: dict, title: str, out: str) -> list[str]:
    """heap_profile.png: the binned base normal force over x / B (Baxter et al. 1997)."""
    from jaxpile import plot

    prof = measured.get("base_profile")  # heap.BaseProfile, or its summary.json form
    if prof is None:
        return []
    x, f = (prof["x_over_b"], prof["normalised"]) if isinstance(prof, dict) else (prof.x_over_b, prof.normalised)
    plot.series_figure(x, {"F / F_max": f}, xlabel="x / B",
                       ylabel="binned base normal force / max", title=title + " (Baxter et al. 1997 Figs. 3b, 5b, 7)",
                       path=os.path.join(out, "heap_profile.png"))
    return ["heap_profile.png"]


def heap_summary(measured: dict) -> dict:
    """A poured heap's summary.json: its plain numbers (`poured_heap.summary`:
    the rest are maps and arrays), the run (`run`) and the set-up (`setup`)."""
    from jaxpile.measure import poured_heap

    run = {"steps": measured["steps"], "at_rest": measured["at_rest"], "max_speed": measured["final_max_speed"],
           **{k: measured[k] for k in ("wall_seconds", "compile_seconds", "total_seconds", "neighbor_reallocations")}}
    setup = {k: v for k, v in measured["info"].items() if k != "law_options"}
    return {**poured_heap.summary(measured), "run": run, "setup": setup}


def cone_figure(measured: dict, title: str, out: str) -> list[str]:
    """cone.png: the base pressure p(r) over the mean pressure (Smid & Novosad's
    measurement) and the azimuthally averaged surface h(r) with its angle."""
    from jaxpile import plot

    pressure, surface = measured.get("pressure"), measured.get("surface")
    if pressure is None or surface is None:
        return []
    read = lambda prof: (np.asarray(prof["r"] if isinstance(prof, dict) else prof.r, float),
                         np.asarray([np.nan if v is None else v for v in (prof["value"] if isinstance(prof, dict)
                                                                         else prof.value)], float))
    (r_p, p), (r_h, h) = read(pressure), read(surface)
    radius = float(measured.get("base_radius") or r_p[-1])
    angle = measured.get("angle")
    plot.series_figure(r_p / radius, {"p(r) / mean pressure": p}, xlabel="r / R",
                       ylabel="base pressure / mean", title=title + " (Smid & Novosad's p(r))",
                       path=os.path.join(out, "cone_pressure.png"))
    plot.series_figure(r_h, {"h(r)": h}, xlabel="r (diameters)", ylabel="surface height (diameters)",
                       title=title + ("" if angle is None else f": angle of repose {angle:.1f}°"),
                       path=os.path.join(out, "cone_surface.png"))
    return ["cone_pressure.png", "cone_surface.png"]


def cone_summary(measured: dict) -> dict:
    """A cone's summary.json: `cone_heap.summary`, the run and the set-up."""
    from jaxpile.measure import cone_heap

    run = {"steps": measured["steps"], "at_rest": measured["at_rest"], "max_speed": measured["final_max_speed"],
           **{k: measured[k] for k in ("wall_seconds", "compile_seconds", "total_seconds", "neighbor_reallocations")}}
    setup = {k: v for k, v in measured["info"].items() if k != "law_options"}
    return {**cone_heap.summary(measured), "run": run, "setup": setup}


def sloped_theory(measured: dict, base) -> tuple | None:
    """The continuum N(x), H(x) of Liffman et al. 1992 eqs. 54-59 at the base's x,
    for the profile figure, with its label."""
    from jaxpile.measure import theory

    if not len(base.x):
        return None
    alpha, width = math.radians(measured["alpha_degrees"]), measured["base"]
    x = np.asarray(base.x)
    return (theory.continuum_ground_normal_force(x, alpha, width),
            theory.continuum_ground_horizontal_force(x, alpha, width), "Liffman et al. 1992 eqs. 54-59")


def substrate_base(sim, params, state, measured):
    """The forces of the fixed layer the pile stands on (its base when it has no ground)."""
    from jaxpile.measure import analysis

    return analysis.substrate_forces(sim, params, state)


def cm_for_lee_herrmann(law_name: str) -> str:
    """The 1993 setting is in the paper's cm with its own law; other laws run in diameters."""
    return "cm" if law_name == "lee-herrmann" else "diameters"


def discharge_figure(measured: dict, title: str, out: str) -> list[str]:
    """discharge.png: disks out against time since the gate opened, with the flow rate."""
    from jaxpile import plot

    d = measured.get("discharge") or {}
    if not d.get("time"):
        return []
    t = np.asarray(d["time"])
    rate = measured.get("flow_rate", float("nan"))
    series = {"disks out": np.asarray(d["count"], float)}
    if math.isfinite(rate):
        middle = t.size // 3
        series[f"Q = {rate:.3g} disks / time"] = d["count"][middle] + rate * (t - t[middle])
    plot.series_figure(t, series, xlabel="time since the gate opened (sqrt(d / g))", ylabel="disks out",
                       title=title + " (Beverloo's law)", path=f"{out}/discharge.png")
    return ["discharge.png"]


def lattice_theory(measured: dict, base):
    """N = (k + 1)/2 and H of eq. 44 on profile.png, when every bottom disk is on the ground."""
    from jaxpile.measure import theory

    layers = measured.get("layers")
    if not (measured.get("pile_intact") and layers == len(base.x)):
        return None
    return (np.full(len(base.x), theory.lattice_ground_normal_force(layers)),
            theory.lattice_ground_horizontal_force(layers), "Liffman et al. 1992 eqs. 42, 44")


# ---------------------------------------------------------------- the registered protocols
_LOADED = {"ramp_steps": "ramp_steps", "max_steps": "max_steps", "speed_tol": "speed_tolerance",
           "hard_collisions": "hard_collisions"}
"""The 1992 loaded piles' generic flags (lattice, sloped)."""

PRESENTATIONS: dict[str, Presentation] = {
    "lattice": Presentation(
        order=0, help="the 1992 equilateral pile (--layers)", flags=_LOADED,
        headline=("layers", "n_particles", "at_rest", "final_max_speed", "max_rel_dev_normal",
                  "max_rel_dev_horizontal"),
        profile_theory=lattice_theory,
        compare=lambda s: f"dev N {s['max_rel_dev_normal']:.2%}, dev H {s['max_rel_dev_horizontal']:.2%}"),
    "sloped": Presentation(
        order=1, help="the 1992 close-packed pile with sides at --slope degrees (Figs. 12-16)",
        flags={**_LOADED, "seed": "seed"},  # --seed is taken and changes nothing: the pile is deterministic
        headline=("alpha_degrees", "n_particles", "at_rest", "central_normal_mean", "theory_central_normal",
                  "central_slope_horizontal", "theory_central_slope_horizontal", "central_slope_rel_dev"),
        profile_theory=sloped_theory),
    "drop": Presentation(
        order=2, help="disks dropped one at a time (1992 Fig. 20)",
        flags={"max_steps": "relax_steps", "speed_tol": "speed_tolerance", "hard_collisions": "hard_collisions",
               "seed": "seed"},
        headline=("n_particles", "all_inserted", "at_rest", "central_dip", "has_central_dip", "weight_balance")),
    "box": Presentation(
        order=3, help="a box filled, its right wall removed (1993 Fig. 1)", flags={"seed": "seed"},
        headline=("n_total", "n_in_play", "at_rest", "repose_endpoints", "repose_least_squares",
                  "repose_cumulative_parabola", "theta_ms_theory"),
        length_unit=cm_for_lee_herrmann, figures=(energy_figure,)),
    "tilt": Presentation(
        order=4, help="a box pile tilted until it moves (1993 Fig. 4)", flags={"seed": "seed"},
        headline=("moved", "theta_t", "theta_t_theory", "theta_r", "theta_ms_theory"),
        length_unit=cm_for_lee_herrmann, figures=(energy_figure,)),
    "flux": Presentation(
        order=5, help="disks fed at the upper left whenever the pile rests (1993 Fig. 5)", flags={"seed": "seed"},
        headline=("inserted", "at_rest", "steady_mean", "steady_std", "steady_max", "theta_ms_theory"),
        base_forces=substrate_base, length_unit=cm_for_lee_herrmann, figures=(angles_figure,)),
    "pour": Presentation(
        order=6, help="a heap poured onto a row of fixed disks (1997)",
        flags={"max_steps": "max_settle_steps", "speed_tol": "speed_tolerance", "seed": "seed"},
        headline=("counts.in_play", "run.at_rest", "height", "base_width", "angle_height_base",
                  "angle_mid_flank.left", "angle_mid_flank.right",
                  "angle_of_repose.left.cumulative_parabola", "angle_of_repose.right.cumulative_parabola",
                  "m_shape.ratio", "m_shape.m_shaped", "dip_below_flanks"),
        base_forces=lambda sim, params, state, measured: measured["substrate_forces"],
        summary=heap_summary, figures=(heap_profile_figure,)),
    "cone": Presentation(
        order=7, help="a conical heap of spheres poured onto a rough plate (Smid & Novosad's experiment, 3D)",
        flags={"max_steps": "max_settle_steps", "speed_tol": "speed_tolerance", "seed": "seed"},
        headline=("counts.in_play", "run.at_rest", "height", "base_radius", "angle", "angle_height_base",
                  "central_dip", "packing_fraction"),
        summary=cone_summary, figures=(cone_figure,)),
    "lift": Presentation(
        order=9, help="a cylinder of spheres on a rough plate, filled and lifted (the DEM calibration test, 3D)",
        flags={"max_steps": "max_settle_steps", "speed_tol": "speed_tolerance", "seed": "seed"},
        headline=("counts.in_play", "run.at_rest", "height", "base_radius", "angle", "angle_height_base",
                  "packing_fraction"),
        summary=cone_summary, figures=(cone_figure,)),
    "hopper": Presentation(
        order=8, help="a silo emptied through an orifice (Beverloo's law; not in the papers)", flags={"seed": "seed"},
        headline=("discharged", "remaining", "clogged", "flow_rate", "number_density", "beverloo_c"),
        base_forces=substrate_base, figures=(discharge_figure,)),
}


def presentation(name: str) -> Presentation:
    """How the commands show the protocol `name`; plainly where it has no entry."""
    return PRESENTATIONS.get(name) or Presentation(order=1_000, help=name)


def listed(names) -> list[str]:
    """`names` in the order the commands list them (the papers' order, then the rest by name)."""
    return sorted(names, key=lambda name: (presentation(name).order, name))


__all__ = ["PRESENTATIONS", "Presentation", "angles_figure", "cm_for_lee_herrmann", "discharge_figure",
           "energy_figure", "energy_series", "heap_profile_figure", "lattice_theory", "listed", "presentation",
           "sloped_theory", "substrate_base"]
