"""What `jaxpile pile` writes for a protocol beyond the files every protocol
gets: its own figures, its base, its summary and its length unit. A protocol
names the functions it uses in its spec's `Presentation`, so the CLI branches
on no protocol's name.

Each figure function takes `(measured, title, out)` (the protocol's `run`
measurements, or the summary.json `jaxpile show` reads them back from; the
figure title; the output folder) and returns the files it wrote (none when
the run measured nothing to draw).
"""

from __future__ import annotations

import math
import os

import numpy as np


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
