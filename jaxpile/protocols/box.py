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

Here, everything happens inside one compiled loop with fixed shapes: the
`driver` (run before every step) removes the right wall the first time the
filled box has come to rest (its speed below `rest_speed` for `hold`
consecutive steps, after the disks have first moved), records the step, then
detects the final rest the same way; the host only reads a flag between
chunks, and samples the kinetic energy per disk once per chunk (Fig. 1(b)).

Reading of the paper, and our choices:

* Radii: "drawn from a Gaussian distribution with a mean of 0.1 and a width of
  0.02, and the maximum (minimum) cut-off radius of a particle is 0.13 (0.07)"
  (sec. 4); `gaussian_radii` redraws values outside the cut-offs (width = the
  standard deviation).
* N: not printed for W = H = 4. The paper's "400 particle system" (sec. 3) is
  what fills a 4 x 4 box at the packing fraction of a random polydisperse
  packing, 0.82; the default N (`fill_count`) fills W x H that way ("they fill
  the box"). Disks that overlap cannot be placed that densely, so they are
  placed without overlap at random (random sequential addition) in the box
  made as tall as needed for an area fraction of `placement_fraction` = 0.4.
* "Move out of the box": the floor ends with the box, at x = W; a disk whose
  centre passes x = W has left (it falls off the edge). It is taken out of play
  (inactive) and parked on a grid above the box, and counted in
  `BoxState.left`; the total disk count never changes.
* Units. The paper's values are in its own units (energies "in erg": cgs). For
  the lee-herrmann law the run is in those units: lengths in cm (W = 4 cm,
  radii ~0.1 cm), g = 981 cm/s^2, and, as the paper gives no density, glass
  spheres (rho = 2.5 g/cm^3, m = 4 pi rho a^3 / 3: the law is the 3D Hertz
  contact). k_n = 1e6 then gives a 0.5% radius overlap under one disk's weight
  and a restitution of about 0.7. The other laws run in their reduced units:
  the paper's lengths times 5 (mean diameter 1), g = 1, a disk of diameter 1
  has mass 1; speeds and times given in the paper's units (rest speed, v_cut,
  hold time) are converted by Froude scaling (speed sqrt(g L), time sqrt(L / g)).
* Laws other than the paper's, with mu = 0.2 (the paper's) where the law has
  one and no rotation (the paper's disks do not rotate): hooke k_n = 1e4 mg/sigma
  (0.2% overlap under one weight), gamma_n = 50; baxter n = 36, r0 = 1.2 (its
  paper's law); liffman its paper values (disk friction is viscous, so its piles
  creep and come out flat).
* Rest: the mass-weighted rms speed (`rms_speed`, the kinetic energy per disk
  of Fig. 1(b) as a speed) below the paper's v_cut = 0.1 cm/s (sec. 5) for
  0.005 s. The largest speed (`rest_measure="max"`) is stricter than "no
  significant motion": a single rocking disk holds it up.

Sliding in the paper's law (measured with this protocol). Read literally, eq.
2b caps only the force and lets the shear displacement delta_s grow while a
contact slides; a contact rocking in the slip regime then gives back the work it
took, and with the paper's gamma_s = gamma_n / 100 (a 0.2% damping ratio for the
shear spring) piles never come to rest: with `lee_herrmann.law(slip="literal")`
the 409-disk W = H = 4 box still has an rms speed of 0.25 cm/s after 3 s
(150 000 steps) and its wall is never removed. The law's default lets the
spring slip at mu F_n / k_s (Cundall & Strack 1979, whose scheme the paper says
it uses); the same box then settles by step 64 000 with theta_R = 24.8 deg
(method 3; the paper: 17.9 +- 1.8 deg), and the 72-disk test box by step 47 000.
"""

from __future__ import annotations

import math
import time
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxpile import analysis, budget, ranges
from jaxpile.boundaries import RIGHT_WALL, make_boundaries
from jaxpile.errors import InputError
from jaxpile.ranges import DISKS, SEED, SIZE, SPAN, SPEED, STEPS, TIME_STEP, Range
from jaxpile.protocols import outputs
from jaxpile.protocols.base import CommandLine, Protocol
from jaxpile.protocols.base import law_and_params as base_law_and_params
from jaxpile.simulate import max_speed
from jaxpile.state import SimState, make_particles

Array = Any

PAPER_G = 981.0
"""g in the paper's units (cm / s^2), used to convert speeds and times."""

PARK_SPACING = 2.5
"""Distance between parked disks, in largest diameters: beyond every law's reach plus skin."""

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


# ------------------------------------------------------------------- units
OPTION_RANGES = {
    "n": DISKS, "width": SIZE, "height": SIZE,
    "packing_fraction": Range(low=0, high=0.91, low_open=True, high_open=True, why="a disk packing jams near 0.91"),
    "placement_fraction": Range(low=0, high=0.5, low_open=True, why="random placement jams near 0.55"),
    "rest_speed": SPEED, "hold_time": SPAN, "dt": TIME_STEP, "seed": SEED, "max_time": SIZE,
    "chunk_steps": STEPS,
}
"""Each option's valid range (`jaxpile.ranges`), checked first by the set-up and `run`."""


# How `jaxpile pile|sweep|fit` list and run this protocol (the registry entry).
CLI = CommandLine(
    order=3, help="a box filled, its right wall removed (1993 Fig. 1)", default_law="lee-herrmann",
    flags={"seed": "seed"},
    headline=("n_total", "n_in_play", "at_rest", "repose_endpoints", "repose_least_squares",
              "repose_cumulative_parabola", "theta_ms_theory"),
    length_unit=outputs.cm_for_lee_herrmann, figures=(outputs.energy_figure,))


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


def law_setting(law) -> dict:
    """`PAPER_SETTING["laws"][law]`: units, dt and parameters for one law."""
    return PAPER_SETTING["laws"][law_name(law)]


def units(law) -> Units:
    """The `Units` a law runs this paper's protocols in."""
    s = law_setting(law)
    scale, gravity = float(s["scale"]), float(s["gravity"])
    t = math.sqrt(scale * PAPER_G / gravity)
    return Units(scale=scale, gravity=gravity, time=t, speed=scale / t, sphere_density=s["sphere_density"])


def law_and_params(law, params=None, rotation: bool | None = None, dtype=None):
    """`(law module, ContactLaw, params)` for this paper's protocols.

    Args:
      law: a law name (`lee-herrmann`, `hooke`, `baxter`, `liffman`) or module.
      params: None (the setting's values), a dict of overrides on top of them,
        or a ready params pytree of that law.
      rotation: integrate spins; default off (the paper's disks do not rotate).
    """
    name = law_name(law)
    setting = {"params": {name: law_setting(name)["params"]}, "rotation": PAPER_SETTING["rotation"]}
    return base_law_and_params(name, params, rotation, setting=setting, dtype=dtype)


def friction_coefficient(params) -> float | None:
    """The disk-disk Coulomb mu of a params pytree, or None for a law without one (liffman)."""
    mu = getattr(params, "mu", None)
    return None if mu is None else float(mu)


# -------------------------------------------------------------- the disks
def _check_positive(name: str, value) -> float:
    try:
        value = float(value)
    except (TypeError, ValueError):
        raise InputError(f"{name} must be a positive number; got {value!r}.") from None
    if not (value > 0 and math.isfinite(value)):
        raise InputError(f"{name} must be positive and finite; got {value!r}.")
    return value


def _radius_law(radius: dict | None) -> tuple[float, float, float, float]:
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
    mean, width, low, high = _radius_law({"mean": mean, "width": width, "low": low, "high": high})
    out = np.empty(0)
    while out.size < n:
        draw = rng.normal(mean, width, max(16, 2 * (int(n) - out.size)))
        out = np.concatenate([out, draw[(draw >= low) & (draw <= high)]])
    return out[: int(n)]


def mean_square_radius(mean: float = 0.1, width: float = 0.02, low: float = 0.07, high: float = 0.13) -> float:
    """E[a^2] of the truncated Gaussian (exact), so pi E[a^2] is the mean disk area."""
    if width == 0:
        return mean * mean
    phi = lambda z: math.exp(-0.5 * z * z) / math.sqrt(2 * math.pi)
    cdf = lambda z: 0.5 * (1.0 + math.erf(z / math.sqrt(2.0)))
    a, b = (low - mean) / width, (high - mean) / width
    z = cdf(b) - cdf(a)
    shift = (phi(a) - phi(b)) / z
    var = width**2 * (1.0 + (a * phi(a) - b * phi(b)) / z - shift**2)
    m = mean + width * shift
    return var + m * m


def fill_count(width: float = 4.0, height: float = 4.0, *, packing_fraction: float = 0.82,
               radius: dict | None = None) -> int:
    """N disks that fill a W x H box (the paper's units) at `packing_fraction`:
    round(phi W H / (pi E[a^2])); 409 for the paper's 4 x 4 box (its
    "400 particle system", sec. 3)."""
    width, height = _check_positive("width", width), _check_positive("height", height)
    if not 0 < packing_fraction < 0.91:
        raise InputError(f"packing_fraction must be in (0, 0.91); got {packing_fraction!r}.")
    area = math.pi * mean_square_radius(*_radius_law(radius))
    return max(1, int(round(packing_fraction * width * height / area)))


def random_positions(radius, width: float, height: float, rng: np.random.Generator, *,
                     gap: float = 0.01, attempts: int = 20_000) -> np.ndarray:
    """`[n, 2]` centres of non-overlapping disks placed at random in
    [0, width] x [0, height] (random sequential addition, largest disks first):
    every disk inside the box and at least `gap` (a fraction of the contact
    distance) away from every other.

    Raises:
      InputError: when a disk finds no free place in `attempts` tries (the box
        is too full: make it taller or use fewer disks).
    """
    radius = np.asarray(radius, dtype=np.float64)
    n = radius.size
    if n == 0:
        return np.zeros((0, 2))
    width, height = _check_positive("width", width), _check_positive("height", height)
    r_max = float(radius.max())
    if 2 * r_max > min(width, height):
        raise InputError(f"a disk of diameter {2 * r_max:g} does not fit in a {width:g} x {height:g} box.")
    cell = 2.0 * r_max * (1.0 + gap)
    nx, ny = max(1, int(width // cell)), max(1, int(height // cell))
    cx, cy = width / nx, height / ny
    grid: dict = {}
    position = np.zeros((n, 2))
    for i in np.argsort(-radius, kind="stable"):
        r = radius[i]
        for _ in range(int(attempts)):
            p = rng.uniform((r, r), (width - r, height - r))
            gx, gy = min(int(p[0] // cx), nx - 1), min(int(p[1] // cy), ny - 1)
            near = [j for ix in (gx - 1, gx, gx + 1) for iy in (gy - 1, gy, gy + 1) for j in grid.get((ix, iy), ())]
            if near:
                d = np.linalg.norm(position[near] - p, axis=1)
                if np.any(d < (radius[near] + r) * (1.0 + gap)):
                    continue
            position[i] = p
            grid.setdefault((gx, gy), []).append(i)
            break
        else:
            raise InputError(f"could not place {n} disks without overlap in a {width:g} x {height:g} box "
                             f"({np.pi * np.sum(radius**2) / (width * height):.0%} of its area); "
                             "make it taller or use fewer disks.")
    return position


def parking_grid(n: int, x0: float, y0: float, spacing: float) -> np.ndarray:
    """`[n, 2]` places for disks out of play: a square-ish grid with its lower left
    corner at (x0, y0) and `spacing` between neighbours."""
    columns = max(1, int(math.ceil(math.sqrt(max(n, 1)))))
    k = np.arange(n)
    return np.stack([x0 + spacing * (k % columns), y0 + spacing * (k // columns)], axis=1).astype(np.float64)


def neighbor_box(position, radius) -> tuple[float, float]:
    """A cell-list box covering every position with a margin of two largest diameters."""
    position, radius = np.asarray(position), np.asarray(radius)
    margin = 4.0 * float(radius.max())
    top = position.max(axis=0) + margin
    return float(top[0]), float(top[1])


def take_out(state: SimState, edge, park) -> tuple[SimState, Array]:
    """Active, non-fixed disks whose centre passed x = `edge` (fell off the end
    of the floor) taken out of play: inactive, at rest, at their `park` place.

    Returns:
      (state, how many were taken out at this step).
    """
    p = state.particles
    out = p.active & ~p.fixed & (p.position[:, 0] > edge)
    p = p.set(
        active=p.active & ~out,
        position=jnp.where(out[:, None], park, p.position),
        velocity=jnp.where(out[:, None], 0.0, p.velocity),
        angular_velocity=jnp.where(out, 0.0, p.angular_velocity),
        force=jnp.where(out[:, None], 0.0, p.force),
        torque=jnp.where(out, 0.0, p.torque),
    )
    return state.set(particles=p), jnp.sum(out).astype(jnp.int32)


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


def rms_speed(state: SimState) -> Array:
    """sqrt(2 E / M): the mass-weighted rms speed of the movable disks, E their
    kinetic energy (translation and rotation) and M their mass; the kinetic
    energy per disk of Fig. 1(b) expressed as a speed."""
    p = state.particles
    movable = p.movable
    energy = p.mass * jnp.sum(p.velocity**2, -1) + p.inertia * p.angular_velocity**2
    total = jnp.sum(jnp.where(movable, energy, 0.0))
    mass = jnp.sum(jnp.where(movable, p.mass, 0.0))
    return jnp.sqrt(total / jnp.maximum(mass, jnp.finfo(p.mass.dtype).tiny))


def motion(state: SimState, use_max) -> Array:
    """The speed the rest criteria read: `max_speed` where `use_max`, else `rms_speed`."""
    return jnp.where(use_max, max_speed(state), rms_speed(state))


def _measure_flag(rest_measure: str) -> bool:
    if rest_measure not in ("rms", "max"):
        raise InputError(f"rest_measure must be 'rms' (mass-weighted rms speed) or 'max' (largest speed); "
                         f"got {rest_measure!r}.")
    return rest_measure == "max"


def rest_detector(speed, rest_speed, quiet, armed, hold, fallback):
    """One step of the rest detector shared by this paper's drivers.

    Returns:
      (quiet, armed, rested): `quiet` counts consecutive steps with `speed <
      rest_speed`, `armed` records that the speed reached `rest_speed` (so a
      pile that starts at rest is not taken as settled before it moved), and
      `rested` is true once armed and quiet for `hold` steps, or quiet for
      `fallback` steps without ever moving.
    """
    still = speed < rest_speed
    quiet = jnp.where(still, quiet + 1, 0)
    armed = armed | ~still
    rested = (quiet >= hold) & (armed | (quiet >= fallback))
    return quiet, armed, rested


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


def protocol(n: int | None = None, *, law="lee-herrmann", width: float = PAPER_SETTING["width"],
             height: float = PAPER_SETTING["height"], radius: dict | None = None,
             packing_fraction: float = PAPER_SETTING["packing_fraction"],
             placement_fraction: float = PAPER_SETTING["placement_fraction"],
             rest_speed: float = PAPER_SETTING["rest_speed"], hold_time: float = PAPER_SETTING["hold_time"],
             rest_measure: str = PAPER_SETTING["rest_measure"], dt: float | None = None, seed: int = 0,
             dtype=None) -> Protocol:
    """The box of Lee & Herrmann 1993, Fig. 1, ready to run with `driver`.

    Lengths, speeds and times are in the paper's units (cm, cm/s, s) and are
    converted to the law's units (`units(law)`).

    Args:
      n: number of disks; default `fill_count(width, height)` (409 for 4 x 4).
      law: the law the run will use (sets the units and dt).
      width, height: W and H of the box.
      radius: overrides of the radius distribution (`mean`, `width`, `low`, `high`).
      packing_fraction: for the default n.
      placement_fraction: the disks start at random, without overlap, in the
        box made tall enough for this area fraction (never lower than H).
      rest_speed, hold_time: the rest criterion (speed below `rest_speed`
        for `hold_time`), for removing the wall and for the end.
      rest_measure: which speed: `"rms"` (default, `rms_speed`: the kinetic
        energy per disk of Fig. 1(b)) or `"max"` (`max_speed`).
      dt: the time step the run will use (default: the law's setting); turns
        `hold_time` into steps.
      seed: draws the radii and the positions.
      dtype: float dtype (default float64).

    Returns:
      `Protocol` with `driver` and a `BoxState`; the right wall is on, the
      floor ends at x = W. `info` holds the set-up in simulation units.

    Raises:
      InputError: on a bad count, size, speed, time or fraction, or when the
        disks cannot be placed.
    """
    ranges.check_all(OPTION_RANGES, locals(), protocol)  # types, finiteness and ranges first: one message format
    u = units(law)
    dt = float(law_setting(law)["dt"]) if dt is None else _check_positive("dt", dt)
    width, height = _check_positive("width", width), _check_positive("height", height)
    rest_speed, hold_time = _check_positive("rest_speed", rest_speed), _check_positive("hold_time", hold_time)
    mean, spread, low, high = _radius_law(radius)
    if not 0 < placement_fraction <= 0.5:
        raise InputError(f"placement_fraction must be in (0, 0.5] (random placement jams near 0.55); "
                         f"got {placement_fraction!r}.")
    if n is None:
        n = fill_count(width, height, packing_fraction=packing_fraction, radius=radius)
    if int(n) != n or n < 1:
        raise InputError(f"n must be a positive whole number of disks; got {n!r}.")
    n = int(n)
    budget.check(n, dtype or "float64", what="a box")  # before any array is allocated
    rng = np.random.default_rng(int(seed))  # a whole float (0.0) passes the range check
    radius_paper = gaussian_radii(n, rng, mean=mean, width=spread, low=low, high=high)
    if 2 * high > width:
        raise InputError(f"the box (W = {width:g}) is narrower than the largest disk ({2 * high:g}).")
    area = math.pi * float(np.sum(radius_paper**2))
    place_height = max(height, area / (placement_fraction * width))
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
        use_max=jnp.asarray(_measure_flag(rest_measure)),
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
        "rest_measure": rest_measure,
        "seed": int(seed),
    }
    box = neighbor_box(np.concatenate([position, park]), r)
    return Protocol(particles=particles, boundaries=boundaries, driver=driver, protocol_state=state,
                    box=box, info=info)


# ----------------------------------------------------------------- measuring
def repose(state: SimState, width: float, *, x_min: float = 0.0) -> dict:
    """The angle of repose (degrees) of the active disks over [x_min, x_min + W]
    by the three methods of Lee & Herrmann 1993, sec. 3 (columns one mean
    diameter wide); NaN with the reason under `repose_error` when the surface
    cannot be measured (fewer than 3 columns, or an empty column inside)."""
    try:
        profile = analysis.surface_profile_of(state, x_min=x_min, width=width)
        angles = analysis.repose_angles(profile)
    except InputError as error:
        nan = float("nan")
        return {"repose_endpoints": nan, "repose_least_squares": nan, "repose_cumulative_parabola": nan,
                "repose_error": str(error)}
    return {"repose_endpoints": angles.endpoints, "repose_least_squares": angles.least_squares,
            "repose_cumulative_parabola": angles.cumulative_parabola,
            "surface_x": profile.x.tolist(), "surface_height": profile.height.tolist()}


def make_simulator(law="lee-herrmann", *, dt: float | None = None, rotation: bool | None = None,
                   integrator: str = "velocity_verlet", chunk_steps: int | None = None, driver=None, **kwargs):
    """A `Simulator` running a 1993 protocol's driver (default: the box `driver`)
    with a law by name (no rotation unless asked). One simulator serves every
    set-up of that protocol with this dt."""
    from jaxpile.simulate import Simulator

    _, contact_law, _ = law_and_params(law, {}, rotation)
    dt = float(law_setting(law)["dt"]) if dt is None else dt
    if chunk_steps is None:
        chunk_steps = max(1, int(round(PAPER_SETTING["chunk_time"] * units(law).time / dt)))
    return Simulator(contact_law, dt, integrator=integrator, driver=globals()["driver"] if driver is None else driver,
                     chunk_steps=chunk_steps, **kwargs)


def run_record(info, t0: float) -> dict:
    """Steps and timings of a run, for the measurements dict."""
    return {
        "steps": info.steps,
        "wall_seconds": info.wall_seconds,
        "compile_seconds": info.compile_seconds,
        "total_seconds": time.perf_counter() - t0,
        "neighbor_reallocations": info.reallocations,
    }


def max_steps_for(law, dt: float, max_time: float = PAPER_SETTING["max_time"]) -> int:
    """`max_time` (paper seconds) in steps of dt."""
    return ranges.steps_of("max_time", _check_positive("max_time", max_time) * units(law).time, dt)


def _sample(state: SimState):
    """(step, kinetic energy per movable disk, max_speed): `analysis.mean_kinetic_energy` on device."""
    p = state.particles
    energy = 0.5 * p.mass * jnp.sum(p.velocity**2, -1) + 0.5 * p.inertia * p.angular_velocity**2
    count = jnp.maximum(jnp.sum(p.movable), 1)
    return state.step, jnp.sum(jnp.where(p.movable, energy, 0.0)) / count, max_speed(state)


_sample_jit = jax.jit(_sample)


def run_sampled(sim, params, state: SimState, *, max_steps: int, finished, progress=None, checkpoint=None,
                samples: dict | None = None):
    """Runs `state` until the host predicate `finished(state)` holds (checked
    after each chunk) or `max_steps`, sampling once per chunk.

    Args:
      checkpoint: `(path, every[, extra])` as in `Simulator.run`; the samples so
        far are saved with each checkpoint (under `extra["samples"]`).
      samples: the samples of the run so far, when `state` is a resumed
        checkpoint (its `extra["samples"]`): continued, and nothing is run if
        the resumed state is already finished.

    Returns:
      (state, RunInfo, samples): samples is a dict of per-chunk lists `step`,
      `time`, `kinetic_energy` (per movable disk, `analysis.mean_kinetic_energy`;
      Fig. 1(b)) and `max_speed`, starting with the run's first state.
    """
    from jaxpile import checkpoint as ckpt
    from jaxpile.simulate import RunInfo

    if int(max_steps) != max_steps or max_steps < 0 or (max_steps == 0 and samples is None):
        raise InputError(f"max_steps must be a whole number >= 1; got {max_steps!r}.")
    resumed = samples is not None
    samples = {k: list(v) for k, v in samples.items()} if resumed else {
        "step": [], "time": [], "kinetic_energy": [], "max_speed": []}

    def sample(s: SimState) -> None:
        step, energy, speed = (x.item() for x in _sample_jit(s))
        samples["step"].append(int(step))
        samples["time"].append(int(step) * sim.dt)
        samples["kinetic_energy"].append(float(energy))
        samples["max_speed"].append(float(speed))

    def stop(s: SimState) -> bool:
        sample(s)
        return bool(finished(s))

    if not resumed:
        sample(state)
    info = RunInfo()
    info._n = state.particles.count
    if not (resumed and finished(state)):
        # the samples dict is written as it stands at each save: always up to date
        state = sim.run(params, state, int(max_steps), progress=progress, info=info, until=stop,
                        checkpoint=ckpt.with_facts(checkpoint, samples=samples))
    info.max_speed = float(max_speed(state))
    info.at_rest = bool(finished(state))
    return state, info, samples


def check_dt(sim, p: Protocol) -> None:
    """InputError unless the simulator steps with the dt the protocol was set up for."""
    if abs(sim.dt - p.info["dt"]) > 1e-12 * p.info["dt"]:
        raise InputError(f"the protocol was set up for dt = {p.info['dt']:g} but the simulator uses "
                         f"dt = {sim.dt:g}; pass the same dt to both.")


def start(sim, params, p: Protocol, resume=None) -> tuple[SimState, dict | None]:
    """The protocol's first state, or with `resume` (a checkpoint file of this
    same run) the state saved there, with the samples saved beside it."""
    check_dt(sim, p)
    state = sim.init(params, p.particles, p.boundaries, box=p.box, protocol_state=p.protocol_state)
    return (state, None) if resume is None else restore_sampled(resume, state, sim, params)


def restore_sampled(resume, template: SimState, sim, params) -> tuple[SimState, dict]:
    """The state a sampled run (`run_sampled`) saved in `resume`, rebuilt on
    `template` (`checkpoint.restore`), and the samples saved with it."""
    from jaxpile import checkpoint as ckpt

    state = ckpt.restore(resume, template, sim.law, params)
    samples = ckpt.read_metadata(resume)["extra"].get("samples")
    if samples is None:
        raise InputError(f"{resume} does not hold a sampled protocol run (no samples recorded with it).")
    return state, samples


def execute(sim, params, p: Protocol, *, max_steps: int, progress=None, checkpoint=None, resume=None):
    """Starts a box protocol and runs it until its driver records the final rest
    (`BoxState.settled_at`) or `max_steps`.

    Args:
      checkpoint: `(path, every[, extra])` as in `Simulator.run`.
      resume: a checkpoint file of this same run to continue from: the run
        ends bit-identical to the uninterrupted one, samples included.

    Returns:
      (state, RunInfo, samples) as `run_sampled`.
    """
    state, samples = start(sim, params, p, resume)
    if int(state.step) > max_steps:
        raise InputError(f"{resume} is at step {int(state.step)}, past this run's budget of {max_steps} steps: "
                         "resume with the budget (max_time) it was written with.")
    return run_sampled(sim, params, state, max_steps=max_steps - int(state.step), progress=progress,
                       finished=lambda s: int(s.protocol_state.settled_at) >= 0, checkpoint=checkpoint,
                       samples=samples)


def count_check(state: SimState) -> dict:
    """Where every disk is: in play (active, movable), fixed, or out of play."""
    p = state.particles
    active, fixed = np.asarray(p.active), np.asarray(p.fixed)
    return {"n_total": int(active.size), "n_in_play": int(np.sum(active & ~fixed)),
            "n_fixed": int(np.sum(fixed)), "n_out_of_play": int(np.sum(~active & ~fixed))}


def run(law="lee-herrmann", n: int | None = None, *, params=None, rotation: bool | None = None,
        dt: float | None = None, integrator: str = "velocity_verlet", max_time: float = PAPER_SETTING["max_time"],
        chunk_steps: int | None = None, progress=False, dtype=None, checkpoint=None, resume=None, **options):
    """Fills the box, removes the right wall at rest, lets the pile settle, and
    measures it (Lee & Herrmann 1993, sec. 3, Fig. 1).

    Args:
      law: `lee-herrmann` (the paper's, in cgs), `hooke`, `baxter` or `liffman`.
      n: number of disks (default: those that fill W x H, 409 for 4 x 4).
      params: None (`PAPER_SETTING`), a dict of overrides, or a params pytree.
      rotation, dt, integrator, chunk_steps: for the `Simulator`.
      max_time: give up after this many paper seconds.
      checkpoint, resume: see `execute` (save the run as it goes; continue a saved run).
      **options: for `protocol` (width, height, radius, packing_fraction,
        placement_fraction, rest_speed, hold_time, seed).

    Returns:
      `(state, measurements)`: the final state and a dict of plain numbers: the
      angle of repose by the three methods (degrees), the steps of the wall
      removal and of the final rest, disk counts, the kinetic energy per disk
      per chunk (Fig. 1(b)), timings, and `info` (the set-up).

    Example:
      >>> state, m = run("lee-herrmann", width=1.6, height=1.6)      # doctest: +SKIP
      >>> m["repose_cumulative_parabola"]                             # doctest: +SKIP
    """
    ranges.check_all(OPTION_RANGES, locals(), run)  # types, finiteness and ranges first: one message format
    from jaxpile import theory

    _, _, params = law_and_params(law, params, rotation, dtype)
    p = protocol(n, law=law, dt=dt, dtype=dtype, **options)
    sim = make_simulator(law, dt=p.info["dt"], rotation=rotation, integrator=integrator, chunk_steps=chunk_steps)
    t0 = time.perf_counter()
    state, info, samples = execute(sim, params, p, max_steps=max_steps_for(law, p.info["dt"], max_time),
                                   progress=progress, checkpoint=checkpoint, resume=resume)
    ps = state.protocol_state
    mu = friction_coefficient(params)
    out = {
        "protocol": "box",
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
        "kinetic_energy": samples,
        **run_record(info, t0),
        "info": dict(p.info),
    }
    return state, out


__all__ = [
    "PAPER_SETTING",
    "BoxState",
    "Units",
    "count_check",
    "driver",
    "check_dt",
    "execute",
    "fill_count",
    "friction_coefficient",
    "gaussian_radii",
    "law_and_params",
    "law_setting",
    "make_simulator",
    "max_steps_for",
    "mean_square_radius",
    "neighbor_box",
    "parking_grid",
    "protocol",
    "random_positions",
    "repose",
    "rest_detector",
    "restore_sampled",
    "rms_speed",
    "motion",
    "run",
    "run_sampled",
    "start",
    "take_out",
    "units",
]
