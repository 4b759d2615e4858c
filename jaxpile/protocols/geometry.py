"""Placing disks, parking the ones out of play and taking disks out: the
geometry the protocols share (the box, the flux, the tilt, the hopper)."""

from __future__ import annotations

import math
from typing import Any

import jax.numpy as jnp
import numpy as np

from jaxpile.errors import InputError
from jaxpile.engine.integrators import per_spin
from jaxpile.engine.state import SimState

Array = Any


PARK_SPACING = 2.5
"""Distance between parked disks, in largest diameters: beyond every law's reach plus skin."""


def check_positive(name: str, value) -> float:
    try:
        value = float(value)
    except (TypeError, ValueError):
        raise InputError(f"{name} must be a positive number; got {value!r}.") from None
    if not (value > 0 and math.isfinite(value)):
        raise InputError(f"{name} must be positive and finite; got {value!r}.")
    return value


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
    width, height = check_positive("width", width), check_positive("height", height)
    r_max = float(radius.max())
    if 2 * r_max > min(width, height):
        raise InputError(f"a disk of diameter {2 * r_max:g} does not fit in a {width:g} x {height:g} box.")
    cell = 2.0 * r_max * (1.0 + gap)
    nx, ny = max(1, int(width // cell)), max(1, int(height // cell))
    cx, cy = width / nx, height / ny
    grid: dict = {}
    placed: dict = {}  # disk -> (x, y, r) as Python floats: no numpy call per tried place (2x faster)
    scale = 1.0 + gap
    position = np.zeros((n, 2))

    def free(x, y, r, gx, gy) -> bool:  # no placed disk within the contact distance (+ gap) of (x, y)
        for ix in (gx - 1, gx, gx + 1):
            for iy in (gy - 1, gy, gy + 1):
                for j in grid.get((ix, iy), ()):
                    xj, yj, rj = placed[j]
                    if math.hypot(xj - x, yj - y) < (rj + r) * scale:
                        return False
        return True

    for i in np.argsort(-radius, kind="stable").tolist():
        r = float(radius[i])
        span_x, span_y = (width - r) - r, (height - r) - r
        for _ in range(int(attempts)):
            # rng.uniform((r, r), (width - r, height - r)) as numpy computes it (low + (high - low) * u, one
            # double per coordinate from the same stream) without its per-call checks of array bounds
            u, v = rng.random(2).tolist()
            x, y = r + span_x * u, r + span_y * v
            gx, gy = min(int(x // cx), nx - 1), min(int(y // cy), ny - 1)
            if free(x, y, r, gx, gy):
                position[i] = (x, y)
                placed[i] = (x, y, r)
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
    return park_where(state, out, park), jnp.sum(out).astype(jnp.int32)


def park_where(state: SimState, out, park) -> SimState:
    """The disks where `out` holds taken out of play: inactive, at rest, at
    their `park` place (`[n, 2]`); the others unchanged."""
    p = state.particles
    return state.set(particles=p.set(
        active=p.active & ~out,
        position=jnp.where(out[:, None], park, p.position),
        velocity=jnp.where(out[:, None], 0.0, p.velocity),
        angular_velocity=jnp.where(per_spin(out, p.angular_velocity), 0.0, p.angular_velocity),
        force=jnp.where(out[:, None], 0.0, p.force),
        torque=jnp.where(per_spin(out, p.torque), 0.0, p.torque),
    ))


def heap_extent(base: str, centre_key: str, count_key: str):
    """A random heap's profile range: its axis +- 1.6 sqrt(n) diameters, wider
    than a heap of n unit disks at 20 degrees (base 2.9 sqrt(n) at packing 0.82)."""
    def extent(protocol):
        half = 1.6 * math.sqrt(float(protocol.info[count_key]))
        centre = float(protocol.info[centre_key])
        return base, centre - half, centre + half
    return extent


def bottom_row_extent(protocol):
    """A deterministic pile on the ground: the bottom row's outer edges."""
    p = protocol.particles
    y, x, r = np.asarray(p.position[:, 1]), np.asarray(p.position[:, 0]), np.asarray(p.radius)
    row = np.abs(y - y.min()) < 0.25 * r.min()
    return "ground", float((x - r)[row].min()), float((x + r)[row].max())


def plate(spacing: float, radius: float) -> np.ndarray:
    """`[m, 2]` a triangular lattice `spacing` apart within `radius` of the origin: the rough plate of
    the cone and the cylinder lift."""
    rows = int(math.ceil(radius / (spacing * math.sqrt(3) / 2))) + 1
    cols = int(math.ceil(radius / spacing)) + 1
    j, i = np.meshgrid(np.arange(-rows, rows + 1), np.arange(-cols, cols + 1), indexing="ij")
    x = spacing * (i + 0.5 * (j % 2))
    y = spacing * math.sqrt(3) / 2 * j
    points = np.stack([x.ravel(), y.ravel()], 1)
    return points[np.hypot(points[:, 0], points[:, 1]) <= radius]
