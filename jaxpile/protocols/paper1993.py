"""Lee & Herrmann 1993's setting, shared by its three protocols (box, tilt,
flux): the paper's units and how each law runs in them, its radius law, and
the pieces the three share: the simulator running a driver, the rest test and
the step budget, and the angle of repose by the paper's three methods.

The paper's values are in its own units (energies "in erg": cgs). For the
lee-herrmann law a run is in those units; the other laws run in reduced units
(the paper's lengths times 5, g = 1), with speeds and times converted by
Froude scaling (see `box`'s module notes).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from jaxpile import ranges
from jaxpile.engine.state import SimState
from jaxpile.errors import InputError
from jaxpile.measure import analysis
from jaxpile.protocols.base import Setting, Setup
from jaxpile.protocols.geometry import check_positive


PAPER_G = 981.0
"""g in the paper's units (cm / s^2), used to convert speeds and times."""


PAPER_SETTING = {
    # geometry, in the paper's units (cm)
    "width": 4.0,  # W = H = 4 for theta_R(mu), sec. 4
    "height": 4.0,
    "radius": {"mean": 0.1, "width": 0.02, "low": 0.07, "high": 0.13},  # sec. 4
    "packing_fraction": 0.82,  # random polydisperse packing: N = 400 fills 4 x 4 (sec. 3)
    "placement_fraction": 0.4,  # area fraction of the random, non-overlapping start
    # rest and timing, in the paper's units (cm/s, s)
    "rest_speed": 0.1,  # the paper's v_cut (sec. 5), here on the rms speed
    "rest_measure": "rms",  # "rms": mass-weighted rms speed (Fig. 1(b)'s energy); "max": max_speed
    "hold_time": 0.005,  # how long the largest speed must stay below rest_speed
    "max_time": 5.0,  # give up after this much simulated time
    "chunk_time": 0.01,  # kinetic energy sampled once per chunk (Fig. 1(b))
    "laws": {
        # the paper's own law and values (sec. 3), in cgs; glass spheres. With the
        # law's literal delta_s these piles do not settle (see the module notes)
        "lee-herrmann": {"scale": 1.0, "gravity": PAPER_G, "sphere_density": 2.5, "dt": 2.0e-5,
                         "params": {"kn": 1.0e6, "ks": 1.0e4, "gamma_n": 5.0e2, "gamma_s": 5.0, "mu": 0.2,
                                    "wall_kn": 2.0e6}},
        # ours, in reduced units (mean diameter 1, g = 1, diameter-1 disk of mass 1)
        "hooke": {"scale": 5.0, "gravity": 1.0, "sphere_density": None, "dt": 1.0e-3,
                  "params": {"kn": 1.0e4, "gamma_n": 50.0, "mu": 0.2}},
        "baxter": {"scale": 5.0, "gravity": 1.0, "sphere_density": None, "dt": 1.0e-3,
                   "params": {"n": 36.0, "r0": 1.2, "mu": 0.2}},
        "liffman": {"scale": 5.0, "gravity": 1.0, "sphere_density": None, "dt": 1.0e-3, "params": {}},
    },
    "rotation": False,  # "The rotation of the particles is not included" (sec. 2)
}


class Units(NamedTuple):
    """How the paper's units (cm, s, cm/s) map onto a law's simulation units.

    Attributes:
      scale: simulation length of 1 cm.
      gravity: g in simulation units.
      time: simulation time of 1 s (Froude scaling: sqrt(scale g_paper / g)).
      speed: simulation speed of 1 cm/s (scale / time).
      sphere_density: disks weigh as spheres of this density (simulation units);
        None: uniform areal density, a disk of diameter 1 has mass 1.
    """

    scale: float
    gravity: float
    time: float
    speed: float
    sphere_density: float | None


def law_name(law) -> str:
    """The registry name of a law given by name, module or `ContactLaw`."""
    from jaxpile.laws import get_law_module

    if isinstance(law, str):
        return get_law_module(law).NAME
    name = getattr(law, "NAME", None) or getattr(law, "name", None)
    if name is None:
        raise InputError(f"law must be a law name, module or ContactLaw; got {type(law).__name__}.")
    return get_law_module(name).NAME


REDUCED_UNITS = {**PAPER_SETTING["laws"]["hooke"], "params": {}}
"""How a law the paper's table does not name (a LAMMPS granular line) runs:
in the reduced units of `hooke`'s row, with the line's own parameters."""


def law_setting(law) -> dict:
    """`PAPER_SETTING["laws"][law]`: units, dt and parameters for one law
    (`REDUCED_UNITS` for a granular line)."""
    return PAPER_SETTING["laws"].get(law_name(law), REDUCED_UNITS)


def units(law) -> Units:
    """The `Units` a law runs this paper's protocols in."""
    s = law_setting(law)
    scale, gravity = float(s["scale"]), float(s["gravity"])
    t = math.sqrt(scale * PAPER_G / gravity)
    return Units(scale=scale, gravity=gravity, time=t, speed=scale / t, sphere_density=s["sphere_density"])


LAW_SETTING = Setting(law="lee-herrmann", params=lambda name: law_setting(name)["params"],
                      dt=lambda law: float(law_setting(law)["dt"]), rotation=PAPER_SETTING["rotation"])
"""The 1993 protocols' laws: each in its own units (`law_setting`), the paper's disks not spinning."""


def law_and_params(law, params=None, rotation: bool | None = None, dtype=None, law_options: dict | None = None):
    """`(law module, ContactLaw, params)` for this paper's protocols.

    Args:
      law: a law name (`lee-herrmann`, `hooke`, `baxter`, `liffman`) or module.
      params: None (the setting's values), a dict of overrides on top of them,
        or a ready params pytree of that law.
      rotation: integrate spins; default off (the paper's disks do not rotate).
      law_options: the law's readings beyond rotation (`base.Setting.law_and_params`).
    """
    return LAW_SETTING.law_and_params(law_name(law), params, rotation, dtype, law_options)


def friction_coefficient(params) -> float | None:
    """The disk-disk Coulomb mu of a params pytree, or None for a law without one (liffman)."""
    mu = getattr(params, "mu", None)
    return None if mu is None else float(mu)


def radius_law(radius: dict | None) -> tuple[float, float, float, float]:
    r = {**PAPER_SETTING["radius"], **(radius or {})}
    unknown = set(r) - {"mean", "width", "low", "high"}
    if unknown:
        raise InputError(f"unknown radius setting(s) {sorted(unknown)}; known: mean, width, low, high.")
    mean, width, low, high = (float(r[k]) for k in ("mean", "width", "low", "high"))
    if not (0 < low <= mean <= high and width >= 0 and all(map(math.isfinite, (mean, width, low, high)))):
        raise InputError(f"radii need 0 < low <= mean <= high and width >= 0; got {r}.")
    return mean, width, low, high


def gaussian_radii(n: int, rng: np.random.Generator, *, mean: float = 0.1, width: float = 0.02,
                   low: float = 0.07, high: float = 0.13) -> np.ndarray:
    """`[n]` radii from the Gaussian of Lee & Herrmann 1993, sec. 4 (mean 0.1,
    standard deviation 0.02, cut to [0.07, 0.13]); values outside the cut-offs
    are drawn again. In the paper's units: multiply by `Units.scale`."""
    if int(n) != n or n < 0:
        raise InputError(f"n must be a whole number >= 0; got {n!r}.")
    mean, width, low, high = radius_law({"mean": mean, "width": width, "low": low, "high": high})
    out = np.empty(0)
    while out.size < n:
        draw = rng.normal(mean, width, max(16, 2 * (int(n) - out.size)))
        out = np.concatenate([out, draw[(draw >= low) & (draw <= high)]])
    return out[: int(n)]


def _truncated_moments(mean: float, width: float, low: float, high: float) -> tuple[float, float]:
    """The mean and variance of the Gaussian (mean, width) cut to [low, high] (exact)."""
    if width == 0:
        return mean, 0.0
    phi = lambda z: math.exp(-0.5 * z * z) / math.sqrt(2 * math.pi)
    cdf = lambda z: 0.5 * (1.0 + math.erf(z / math.sqrt(2.0)))
    a, b = (low - mean) / width, (high - mean) / width
    z = cdf(b) - cdf(a)
    shift = (phi(a) - phi(b)) / z
    var = width**2 * (1.0 + (a * phi(a) - b * phi(b)) / z - shift**2)
    return mean + width * shift, var


def mean_radius(mean: float = 0.1, width: float = 0.02, low: float = 0.07, high: float = 0.13) -> float:
    """E[a] of the truncated Gaussian (exact): 0.1 for the paper's symmetric cut."""
    return _truncated_moments(mean, width, low, high)[0]


def mean_square_radius(mean: float = 0.1, width: float = 0.02, low: float = 0.07, high: float = 0.13) -> float:
    """E[a^2] of the truncated Gaussian (exact), so pi E[a^2] is the mean disk area."""
    m, var = _truncated_moments(mean, width, low, high)
    return var + m * m


def fill_count(width: float = 4.0, height: float = 4.0, *, packing_fraction: float = 0.82,
               radius: dict | None = None) -> int:
    """N disks that fill a W x H box (the paper's units) at `packing_fraction`:
    round(phi W H / (pi E[a^2])); 409 for the paper's 4 x 4 box (its
    "400 particle system", sec. 3)."""
    width, height = check_positive("width", width), check_positive("height", height)
    if not 0 < packing_fraction < 0.91:
        raise InputError(f"packing_fraction must be in (0, 0.91); got {packing_fraction!r}.")
    area = math.pi * mean_square_radius(*radius_law(radius))
    return max(1, int(round(packing_fraction * width * height / area)))


def measure_flag(rest_measure: str) -> bool:
    if rest_measure not in ("rms", "max"):
        raise InputError(f"rest_measure must be 'rms' (mass-weighted rms speed) or 'max' (largest speed); "
                         f"got {rest_measure!r}.")
    return rest_measure == "max"

# ------------------------------------------------- what the three protocols share
def default_dt(law) -> float:
    """The time step a law runs the 1993 setting with."""
    return LAW_SETTING.dt_of(law)


def repose(state: SimState, width: float, *, x_min: float = 0.0) -> dict:
    """The angle of repose (degrees) of the active disks over [x_min, x_min + W]
    by the three methods of Lee & Herrmann 1993, sec. 3 (columns one mean
    diameter wide; h(x) the highest disk centre in a column, an empty column
    between filled ones the line between its neighbours, as the flux's recorded
    surfaces, and counted in `surface_gaps`); NaN with the reason under
    `repose_error` when the surface cannot be measured (fewer than 3 columns)."""
    try:
        profile = analysis.surface_profile_of(state, x_min=x_min, width=width)
        angles = analysis.repose_angles(profile, fill_gaps=True)
    except InputError as error:
        nan = float("nan")
        return {"repose_endpoints": nan, "repose_least_squares": nan, "repose_cumulative_parabola": nan,
                "repose_error": str(error)}
    return {"repose_endpoints": angles.endpoints, "repose_least_squares": angles.least_squares,
            "repose_cumulative_parabola": angles.cumulative_parabola,
            "surface_gaps": int(np.isnan(profile.height[(angles.x[0] <= profile.x) & (profile.x <= angles.x[-1])]).sum()),
            "surface_x": profile.x.tolist(), "surface_height": profile.height.tolist()}


def make_simulator(law="lee-herrmann", *, driver, dt: float | None = None, rotation: bool | None = None,
                   integrator: str = "velocity_verlet", chunk_steps: int | None = None,
                   law_options: dict | None = None, **kwargs):
    """A `Simulator` running a 1993 protocol's `driver` with a law by name (no
    rotation unless asked). One simulator serves every set-up of that protocol
    with this dt."""
    from jaxpile.engine.simulate import Simulator

    _, contact_law, _ = law_and_params(law, {}, rotation, law_options=law_options)
    dt = float(law_setting(law)["dt"]) if dt is None else dt
    if chunk_steps is None:
        chunk_steps = max(1, int(round(PAPER_SETTING["chunk_time"] * units(law).time / dt)))
    return Simulator(contact_law, dt, integrator=integrator, driver=driver,
                     chunk_steps=chunk_steps, **kwargs)


def max_steps_for(law, dt: float, max_time: float = PAPER_SETTING["max_time"]) -> int:
    """`max_time` (paper seconds) in steps of dt."""
    return ranges.steps_of("max_time", check_positive("max_time", max_time) * units(law).time, dt)


def count_check(state: SimState) -> dict:
    """Where every disk is: in play (active, movable), fixed in play (a
    floor), out of play (waiting, or gone), or never used (fixed and out of
    play: a flux floor's spare draws)."""
    p = state.particles
    active, fixed = np.asarray(p.active), np.asarray(p.fixed)
    return {"n_total": int(active.size), "n_in_play": int(np.sum(active & ~fixed)),
            "n_fixed": int(np.sum(active & fixed)), "n_out_of_play": int(np.sum(~active & ~fixed)),
            "n_unused": int(np.sum(~active & fixed))}


def simulator_running(driver_function):
    """The spec's simulator of a 1993 protocol running `driver_function` (`make_simulator`)."""

    def simulator(options, *, law, dt, rotation=None, integrator=None, chunk_steps=None, law_options=None):
        return make_simulator(law, dt=dt, rotation=rotation, integrator=integrator or "velocity_verlet",
                              chunk_steps=chunk_steps, driver=driver_function, law_options=law_options)

    return simulator


def settled(p: Setup, options):
    """The 1993 family's end (box, flux): the driver's rest detector has fired."""
    return lambda s: s.protocol_state.settled_at >= 0


def max_time_budget(p: Setup, options) -> int:
    """The 1993 family's budget (box, flux): `max_time` (paper seconds) in steps of the set-up's dt."""
    return max_steps_for(p.info["law"], p.info["dt"], options.max_time)
