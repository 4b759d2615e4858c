"""Heaps poured onto a rough base (Baxter, Tuzun, Burnell & Heyes 1997).

The paper's procedure (sec. II, last two paragraphs; sec. III), read line by
line in docs/baxter1997_audit.md#the-pour:

* the base is "a static substrate consisting of a row of equally spaced
  particles, interacting with the dynamic grains with the same interaction
  laws" (a flat floor gave no stable heap): fixed disks of diameter sigma,
  centres `spacing` = S = 1.1 sigma apart (where the paper's angle of repose
  reaches its plateau), standing on y = 0; no wall is active;
* the grains "fall under gravity in the y direction onto the substrate from an
  initial height of ~100 sigma with initial lateral x coordinates chosen from a
  uniform random distribution in an interval +-3 sigma": released at rest,
  `release_height` = 100 sigma above the row's centre line, x in its middle
  +-3 sigma;
* the rate, not printed, follows from Fig. 2's caption (869, 900, 931 and 1334
  disks at 1.40e3, 1.45e3, 1.50e3 and 2.15e3 time units need one disk every
  1.6117 to 1.6129): one every 1.612 time units, 1612 steps at the paper's dt =
  1e-3 (sigma/g)^(1/2). A disk is then g Delta^2 / 2 = 1.30 sigma below the next
  when that is released, beyond the law's reach (1.2 sigma): falling disks
  never meet;
* monodisperse, or diameters uniform in ((1 - delta) sigma, sigma) (delta = 5%,
  10% in the paper), masses following the area (the paper does not say);
* 1334 disks (Fig. 1; 1000 in Figs. 5-8), then left to come to rest.

Everything happens inside the compiled loop with fixed shapes: all disks exist
from the start, parked inactive on a grid above the release point (2.5 sigma
apart: they never interact); `driver` releases the
next every `interval` and takes a disk that falls off an end of the row out of
play (counted in `PourState.lost`), reading all it needs from
`SimState.protocol_state`, so one `Simulator` serves every pour. `insert_height`
(an option) shortens the 14-time-unit fall from 100 sigma exactly: disks appear
at that height moving down at the speed of the fall from `release_height`, so
each hits the heap as released from there (uniform gravity, no drag); only the
arrival times shift, all by the same amount.

`floor="flat"` pours onto the ground wall instead, under the row's span (its
disks stay, switched off, as markers), with the law's wall contact: the paper's
first attempt, "a flat smooth structureless surface", is baxter's with
`wall_mu=0`. A disk whose centre passes an end of that floor is lost.

Measurements (`measure`): the forces between heap and substrate (the paper's
base force F_B/mg of Figs. 3(b), 5(b), 7), their binned normalised profile
(x/B, F/F_max) and its M shape (flank maxima over the centre; the paper: 20-30%
above it for n = 36, r0 = 1.2 sigma), each flank's angle of repose by Lee &
Herrmann's three methods (the paper: 35 +- 5 deg), and the voidage map (Figs.
2, 5, 6, 8).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import jax.numpy as jnp
import numpy as np

from jaxpile import budget, ranges
from jaxpile.engine.boundaries import (
    GROUND,
    LEFT_WALL,
    RIGHT_WALL,
    make_boundaries,
    set_wall,
)
from jaxpile.engine.state import SimState, make_particles
from jaxpile.errors import InputError
from jaxpile.measure.heap import steepest_heap_height, substrate_size

# the heap's measurements, and the check of the options that read it (`jaxpile.measure.poured_heap`)
from jaxpile.measure.poured_heap import check_options, measure
from jaxpile.protocols import drivers
from jaxpile.protocols.base import Setting, Setup
from jaxpile.protocols.spec import Options, ProtocolSpec, option
from jaxpile.protocols.stages import Phase
from jaxpile.ranges import DISKS, SIZE, SPAN, SPEED, STEPS, Range

Array = Any

PARK_SPACING = 2.5
"""Distance between parked disks (sigma): more than any law's reach plus skin."""

LOST_DEPTH = 1.5
"""A disk whose centre falls this far (sigma) below the substrate's centres has
left the row and is taken out of play."""

MIN_RELEASE_GAP = 1.25
"""The least height (sigma) between a disk just released and the one released
before it: beyond the longest reach of the laws' pour settings (baxter: r0 sigma
= 1.2 sigma), so falling disks never meet in the air (their vertical separation
only grows). The paper's rate leaves g interval^2 / 2 = 1.30 sigma."""

# The paper's setting and, for the laws the paper does not use, our choices.
PAPER_SETTING = {
    "n": 1334,  # Fig. 1 (1000 in Figs. 5-8)
    "spacing": 1.1,  # S, sec. III: the plateau of the angle of repose
    "release_height": 100.0,  # "~100 sigma", sec. II
    "spread": 3.0,  # x uniform in +-3 sigma, sec. II
    "interval": 1.612,  # time units between releases, from Fig. 2's caption
    "dt": 1.0e-3,  # sec. II: "typically 0.001 sigma^(1/2) g^(-1/2)"
    "integrator": "leapfrog",  # eqs. 9-12
    "speed_tolerance": 1.0e-4,  # "near rest"; ours, (sigma g)^(1/2): the base then carries the weight to ~1e-6
    "max_settle_steps": 2_000_000,
    "params": {
        # the paper's law: n = 36, r0 = 1.2 sigma, alpha = 1.214, 50% of critical
        # damping (paper_params), mu = 0.5 in the middle of its 0.4-0.6
        "baxter": {"n": 36.0, "r0": 1.2, "mu": 0.5},
        # the paper's equivalent Hooke law (Fig. 5: k = 500 mg / sigma); dashpot at
        # the paper's 50% of 2 sqrt(m k) for a pair of equal disks: m_eff gamma_n =
        # sqrt(m k), m_eff = m / 2, so gamma_n = 2 sqrt(k / m) = 44.7; kt = 2 k / 7
        # and gamma_t = gamma_n / 2 (LAMMPS defaults); mu = 0.5 as for baxter
        "hooke": {"kn": 500.0, "gamma_n": 2.0 * math.sqrt(500.0), "mu": 0.5},
        # ours: k_n = 1e4 mg / sigma^(3/2) (0.2% sigma overlap under 1 mg, 2-3%
        # at the base of a 1334-disk heap), gamma_n = 50 / time (between 2/3 and
        # 1/3 of critical over those overlaps), the paper's k_s = k_n / 100 and
        # gamma_s = gamma_n / 100, and mu = 0.5 as for baxter; no rotation (the
        # law's default, as in Lee & Herrmann 1993)
        "lee-herrmann": {"kn": 1.0e4, "gamma_n": 50.0, "mu": 0.5},
        # Liffman et al.'s values (K_s from their eq. 46, the rest as in
        # liffman.paper_params); its disk-disk friction is viscous only, so its
        # heaps are flatter
        "liffman": {},
    },
}


FLOORS = ("row", "flat")
"""What a heap is poured on: the paper's row of fixed disks, or a flat wall of
the row's length (sec. II: "a flat smooth structureless surface" gave no stable
heap)."""


# ------------------------------------------------------------------ options
@dataclass(frozen=True)
class PourOptions(Options):
    """The pour's options, in sigma (the largest diameter) and (sigma / g)^(1/2)."""

    n: int = option(PAPER_SETTING["n"], range=DISKS, help="disks to pour (1334 in the paper's Fig. 1)")
    spacing: float = option(PAPER_SETTING["spacing"], range=Range(
        low=1, high=2, high_open=True, why="S >= one diameter, the gap narrower than a disk"), unit="sigma",
        help="S, centre-to-centre distance of the substrate disks (1.1 in the paper)")
    polydispersity: float = option(0.0, range=Range(low=0, high=0.5, high_open=True, why="a fraction: 0.05 for 5%"),
                                   help="delta (a fraction, 0.05 for the paper's 5%): diameters uniform in "
                                        "((1 - delta) sigma, sigma); 0: monodisperse")
    release_height: float = option(PAPER_SETTING["release_height"], range=SIZE, unit="sigma",
                                   help="where disks start at rest, above the substrate's centre line (100 in the paper)")
    insert_height: float | None = option(None, range=SIZE, unit="sigma",
                                         help="a lower height where disks appear at the free-fall speed from "
                                              "release_height (an exact shortcut); above a 45-degree heap + 3 sigma")
    spread: float = option(PAPER_SETTING["spread"], range=SPAN, unit="sigma",
                           help="release x uniform in +-spread around the middle of the row")
    interval: float = option(PAPER_SETTING["interval"], range=SIZE, unit="sqrt(sigma/g)",
                             help="time between releases (1.612, the paper's rate)")
    substrate_disks: int | None = option(None, range=Range(low=3, whole=True, unit="disks"),
                                         help="disks in the row; default: room for a 15-degree heap")
    speed_tolerance: float = option(PAPER_SETTING["speed_tolerance"], range=SPEED, unit="sqrt(g sigma)",
                                    help="after pouring, at rest once every disk is slower than this")
    max_settle_steps: int = option(PAPER_SETTING["max_settle_steps"], range=STEPS,
                                   help="step budget of the settling after the pour")
    bins: int | None = option(None, range=Range(low=3, whole=True),
                              help="bins of the base-force profile (made odd; default about one per 4 spacings)")
    voidage_cell: float = option(3.0, range=SIZE, unit="sigma", help="side of the voidage map's cells")
    floor: str = option("row", help="what the heap lands on: row (the paper's fixed disks) or flat (the ground "
                                    "wall under the row's span, the law's wall contact; smooth with baxter's "
                                    "wall_mu=0: the paper's first attempt)")

    def validate(self):
        if self.floor not in FLOORS:
            raise InputError(f"floor must be one of {list(FLOORS)}; got {self.floor!r}.")
        smallest = 1.0 - self.polydispersity
        if not (1.0 <= self.spacing < 1.0 + smallest):
            raise InputError(
                f"spacing S must be at least one diameter (1 sigma) and leave a gap narrower than the smallest "
                f"disk ({smallest:g} sigma), i.e. 1 <= S < {1.0 + smallest:g}; got {self.spacing!r}.")
        if self.substrate_disks is not None and self.substrate_disks * self.spacing < 2.0 * self.spread + 2.0:
            raise InputError(f"a row of {self.substrate_disks} disks ({self.substrate_disks * self.spacing:g} sigma) "
                             f"is narrower than the pouring interval +-{self.spread:g} sigma.")


PourState = drivers.Pouring
"""What the pouring driver carries (`drivers.Pouring`, shared with the cone)."""
driver = drivers.pouring
"""The pouring driver (`drivers.pouring`): releases the next disk every interval, loses those off the row."""
in_play = drivers.poured_in_play
"""How many leading disks can be in play during the next steps (`drivers.poured_in_play`)."""


def setup(o: PourOptions, *, law, seed: int, dt: float, dtype=None) -> Setup:
    """The 1997 pouring set-up: a fixed row of disks and `o.n` disks to pour onto it.

    Units: sigma (the largest diameter) = 1, g = 1, a disk of diameter sigma has
    mass 1; time in (sigma / g)^(1/2). Heights are measured from the substrate's
    centre line y = sigma / 2. The set-up is the same for every law; `dt` turns
    the release `interval` into steps (which must leave `MIN_RELEASE_GAP`
    between a disk just released and the previous one) and `seed` draws the
    radii and the release x (the set-up is a pure function of it). The default
    row, `substrate_size(n, spacing)`, has room for a 15-degree heap.

    Returns:
      `Setup` whose `protocol_state` is a `PourState`; the substrate is
      particles `0 .. m-1` (fixed), the poured disks `m .. m+n-1` in release
      order. `info` holds the set-up's numbers, including `pour_steps`
      (n x interval steps: the last disk has one interval to fall).

    Raises:
      InputError: on heights below the steepest heap of n disks, an interval
        too short for that dt, a pile too big for the machine, more bins
        than substrate disks or a voidage map too fine for its memory.
    """
    n, spacing, polydispersity, interval = o.n, o.spacing, o.polydispersity, o.interval
    release_height, insert_height, substrate_disks = o.release_height, o.insert_height, o.substrate_disks
    spread = float(o.spread) + 0.0  # -0.0 (inside its range) as +0.0: numpy's uniform(0.0, -0.0) refuses "high < low"
    budget.check(1.1 * n, dtype or "float64", what="a pour (with its substrate row)")  # and its substrate row
    interval_steps = ranges.steps_of("interval", interval, dt)
    lowest = steepest_heap_height(n) + 3.0
    if not release_height >= lowest:
        raise InputError(
            f"release_height must be at least {lowest:.1f} sigma for {n} disks (a 45-degree heap plus "
            f"3 sigma); got {release_height!r}.")
    if insert_height is None:
        insert_height = release_height
    if not lowest <= insert_height <= release_height:
        raise InputError(
            f"insert_height must lie between {lowest:.1f} sigma (above a 45-degree heap of {n} disks) and "
            f"release_height = {release_height:g}; got {insert_height!r}.")
    speed = math.sqrt(2.0 * (release_height - insert_height))
    gap = speed * interval_steps * dt + 0.5 * (interval_steps * dt) ** 2
    if gap < MIN_RELEASE_GAP:
        raise InputError(
            f"interval {interval!r} is too short: when a disk is released the previous one is only {gap:.2f} sigma "
            f"below it and they could touch in the air; the interval must leave at least {MIN_RELEASE_GAP} sigma "
            "(the paper's 1.612 leaves 1.30 sigma).")
    rows = int(substrate_size(n, spacing) if substrate_disks is None else substrate_disks)
    budget.check(n + rows, dtype or "float64", what="a pour with its substrate row")  # a row given too long
    check_options(o, n_substrate=rows, substrate_length=spacing * (rows - 1) + 1.0, n_poured=n)

    rng = np.random.default_rng(int(seed))  # a whole float (0.0) passes the range check
    diameter = 1.0 - polydispersity * rng.uniform(0.0, 1.0, n) if polydispersity > 0 else np.ones(n)
    base_y = 0.5
    x_substrate = spacing * np.arange(rows)
    middle = 0.5 * float(x_substrate[-1])
    drop_x = middle + rng.uniform(-spread, spread, n)

    columns = max(4, int(math.ceil(math.sqrt(n))))
    park_y0 = base_y + release_height + 2.0 * PARK_SPACING
    k = np.arange(n)
    park = np.stack([middle + PARK_SPACING * (k % columns - 0.5 * (columns - 1)),
                     park_y0 + PARK_SPACING * (k // columns)], axis=1)

    position = np.concatenate([np.stack([x_substrate, np.full(rows, base_y)], axis=1), park])
    radius = np.concatenate([np.full(rows, 0.5), 0.5 * diameter])
    fixed = np.arange(rows + n) < rows
    flat = o.floor == "flat"
    # on a flat floor the row stays, switched off, to mark its span and the columns the surface is read in
    particles = make_particles(position, radius, fixed=fixed, active=fixed & (not flat), dtype=dtype)
    dtype = particles.position.dtype

    boundaries = make_boundaries(dtype=dtype)  # the ground y = 0: where the row's disks stand
    for wall in (GROUND, LEFT_WALL, RIGHT_WALL) if not flat else (LEFT_WALL, RIGHT_WALL):
        boundaries = set_wall(boundaries, wall, active=False)
    ends = (float(x_substrate[0]) - 0.5, float(x_substrate[-1]) + 0.5) if flat else (-math.inf, math.inf)

    release = np.concatenate([np.zeros((rows, 2)),
                              np.stack([drop_x, np.full(n, base_y + insert_height)], axis=1)])
    state = PourState(
        poured=jnp.asarray(0, jnp.int32),
        total=jnp.asarray(n, jnp.int32),
        first=jnp.asarray(rows, jnp.int32),
        interval=jnp.asarray(interval_steps, jnp.int32),
        release_position=jnp.asarray(release, dtype),
        release_velocity=jnp.asarray([0.0, -speed], dtype),
        park_position=jnp.asarray(position, dtype),
        lost=jnp.zeros(rows + n, bool),
        lost_below=jnp.asarray(base_y - LOST_DEPTH, dtype),
        ends=jnp.asarray(ends, dtype),
    )
    info = {
        "protocol": "pour",
        "floor": o.floor,
        "n_poured": n,
        "n_substrate": rows,
        "spacing": float(spacing),
        "substrate_length": float(x_substrate[-1] + 1.0),
        "centre_x": middle,
        "base_y": base_y,
        "polydispersity": float(polydispersity),
        "release_height": float(release_height),
        "insert_height": float(insert_height),
        "insert_speed": speed,
        "spread": float(spread),
        "interval": interval_steps * dt,
        "interval_steps": interval_steps,
        "dt": float(dt),
        "pour_steps": n * interval_steps,
        "seed": int(seed),
    }
    return Setup(particles=particles, boundaries=boundaries, driver=driver, protocol_state=state, info=info)


# ----------------------------------------------------------------------- runs
def law_params(law: str, dtype=None, **overrides):
    """The pour setting's parameters of a law (`PAPER_SETTING["params"]`), with overrides."""
    return law_and_params(law, overrides, dtype=dtype)[2]


LAW_SETTING = Setting(law="baxter", params=PAPER_SETTING["params"], dt=PAPER_SETTING["dt"])
"""The pour's laws: the paper's values; rotation each law's own default."""
law_and_params = LAW_SETTING.law_and_params


def make_simulator(law: str = "baxter", *, dt: float = PAPER_SETTING["dt"], rotation: bool | None = None,
                   integrator: str = PAPER_SETTING["integrator"], chunk_steps: int = 2000,
                   law_options: dict | None = None, **kwargs):
    """A `Simulator` running the pouring driver with a law by name (its own
    default rotation unless given; `law_options` for the law's readings, e.g.
    baxter's `lever_arm`). One simulator serves every pour set-up (`setup`) with this dt
    (the driver reads the set-up from the state)."""
    from jaxpile.engine.simulate import Simulator
    from jaxpile.laws import get_law_module

    module = get_law_module(law)
    options = dict(law_options or {})
    if rotation is not None:
        options["rotation"] = rotation
    contact_law = module.law(**options)
    # The list is allocated while the disks to pour are parked far apart: the
    # Simulator sizes it for the packed heap (`packed_lists`), so the heap keeps it.
    kwargs.setdefault("in_play", in_play)  # each chunk runs on the disks poured by its end
    return Simulator(contact_law, dt, integrator=integrator, driver=driver, chunk_steps=chunk_steps, **kwargs)


def simulator(o: PourOptions, *, law, dt: float, rotation=None, integrator=None, chunk_steps=None, law_options=None):
    """The spec's simulator: `make_simulator` with the law's readings
    `law_options`, leapfrog (the paper's eqs. 9-12) unless another integrator
    is given, and chunks of 2000 steps unless given."""
    return make_simulator(law, dt=dt, rotation=rotation, integrator=integrator or PAPER_SETTING["integrator"],
                          law_options=law_options, **({} if chunk_steps is None else {"chunk_steps": chunk_steps}))


def phases(p: Setup, o: PourOptions) -> tuple[Phase, ...]:
    """Every disk poured (`info["pour_steps"]`), then a run until the fastest
    disk is below `speed_tolerance`, within `max_settle_steps`."""
    from jaxpile.engine.simulate import max_speed

    tolerance = float(o.speed_tolerance)
    return (Phase("pour", int(p.info["pour_steps"])),
            Phase("settle", int(o.max_settle_steps), lambda s: max_speed(s) < tolerance))


def measure_heap(sim, params, state: SimState, p: Setup, o: PourOptions) -> dict:
    """`measure` (`jaxpile.measure.poured_heap`) with the options' bins and voidage cell."""
    return measure(sim, params, state, bins=o.bins, voidage_cell=o.voidage_cell)


SPEC = ProtocolSpec(
    name="pour", options=PourOptions, setting=LAW_SETTING, setup=setup, simulator=simulator,
    phases=phases, measure=measure_heap)
"""The pour (Baxter et al. 1997): `SPEC.run("baxter", 1334)` pours the paper's heap at its rate onto a row of
fixed disks, lets it come to rest, and measures its base forces, flank angles and voidage."""


__all__ = ["LOST_DEPTH", "MIN_RELEASE_GAP", "PAPER_SETTING", "PARK_SPACING", "SPEC", "PourOptions", "PourState",
           "driver", "in_play", "law_and_params", "law_params", "make_simulator", "measure_heap", "phases",
           "setup", "simulator"]
