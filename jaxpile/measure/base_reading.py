"""A pile's base profile read as an experimentalist reads a heap's: across the
pile's own base, foot to foot, at the points where a measurement was taken,
as a force density over a sensor's width, scaled by its largest reading or
by the pile's weight (host-side numpy: what an ensemble fit compares with a
measured profile, `jaxpile.fit.measured`)."""

from __future__ import annotations

import math

import numpy as np

from jaxpile.errors import InputError

CLUSTER_GAP = 4.0
"""Base contacts more than this many typical contact spacings apart belong to two
heaps: a stray disk that rolled away is not the heap's foot."""


def pile_base(x, normal, gap: float = CLUSTER_GAP) -> tuple[float, float, np.ndarray]:
    """`(x_left, x_right, members)`: the pile's base, foot to foot, from its
    base contacts `x` (sorted) and their normal forces: the run of contacts
    no more than `gap` typical spacings apart that carries the most load,
    widened by half a spacing at each end (so a row of contacts one spacing
    apart spans its row exactly); `members` is that run's mask."""
    x, normal = np.asarray(x, float), np.asarray(normal, float)
    if x.size < 2:
        raise InputError(f"the pile touches its base at {x.size} point(s): too few to read a profile across it "
                         "(a larger pile, or one that came to rest).")
    dx = np.diff(x)
    spacing = float(np.median(dx[dx > 0])) if np.any(dx > 0) else 1.0
    run = np.concatenate([[0], np.cumsum(dx > gap * spacing)])
    members = run == int(np.argmax(np.bincount(run, weights=normal)))
    inside = x[members]
    return float(inside[0] - 0.5 * spacing), float(inside[-1] + 0.5 * spacing), members


def profile_at_points(forces, at, *, bandwidth: float, normalised_by: str = "max", horizontal: bool = True
                      ) -> tuple[np.ndarray, np.ndarray | None]:
    """A pile's base profile at the x/B `at` of its own base (`pile_base`):
    the normal and horizontal force density there, smoothed by a Gaussian of
    standard deviation `bandwidth` B, over the largest normal reading
    (`"max"`) or times B over the pile's total normal load (`"weight"`: a
    profile whose integral over x/B is 1). `forces`: `jaxpile.base_forces`'s
    contacts, sorted by x."""
    x_left, x_right, members = pile_base(forces.x, forces.normal)
    width = x_right - x_left
    x, normal, shear = (np.asarray(a, float)[members] for a in (forces.x, forces.normal, forces.horizontal))
    h = float(bandwidth) * width
    points = x_left + width * np.asarray(at, float)
    kernel = np.exp(-0.5 * ((x[None, :] - points[:, None]) / h) ** 2) / (math.sqrt(2 * math.pi) * h)
    n_density, h_density = kernel @ normal, kernel @ shear
    scale = n_density.max() if normalised_by == "max" else normal.sum() / width
    if not scale > 0:
        raise InputError("the pile's base carries no load where the measurement was taken; nothing to compare.")
    return n_density / scale, (h_density / scale if horizontal else None)


__all__ = ["CLUSTER_GAP", "pile_base", "profile_at_points"]
