"""A heap's base-force profile: the base normal force binned over x / B and
its M shape, the flank maxima over the centre (Baxter et al. 1997, Figs. 3b,
5b and 7; the pour), and the profile about the centre of force with its
central dip (Liffman et al. 1992, Fig. 20; the dropped pile)."""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from jaxpile.errors import InputError


class BaseProfile(NamedTuple):
    """The base force binned along the heap's base (the papers' x/B, F/F_max).

    Attributes:
      x_over_b: `[b]` bin centres, (x - x_left) / B, in (0, 1).
      force: `[b]` total normal force in each bin (mg).
      normalised: `[b]` force / its maximum.
      x_left: left end of the base.
      width: B, the base length.
    """

    x_over_b: np.ndarray
    force: np.ndarray
    normalised: np.ndarray
    x_left: float
    width: float


def base_profile(forces, *, extent=None, bins: int | None = None, spacing: float = 1.1) -> BaseProfile:
    """Bins the base normal force over the heap's base.

    Args:
      forces: `SubstrateForces` (or any `x`, `normal` arrays).
      extent: `(x_left, x_right)` of the base; default: the span of the contacts.
      bins: number of bins, made odd so one bin sits under the middle; default
        about one bin per 4 substrate disks (at least 5).
      spacing: substrate spacing, for the default bin count.
    """
    x, f = np.asarray(forces.x, float), np.asarray(forces.normal, float)
    if x.size == 0:
        raise InputError("no base contacts: nothing rests on the substrate.")
    x_left, x_right = (float(x.min()), float(x.max())) if extent is None else (float(e) for e in extent)
    width = x_right - x_left
    if not width > 0:
        raise InputError(f"the base extent must have x_left < x_right; got ({x_left}, {x_right}).")
    if bins is None:
        bins = max(5, int(round(width / (4.0 * spacing))))
    if int(bins) != bins or bins < 3:
        raise InputError(f"bins must be a whole number >= 3; got {bins!r}.")
    bins = int(bins) | 1
    u = (x - x_left) / width
    inside = (u >= 0) & (u <= 1)
    which = np.minimum((u[inside] * bins).astype(int), bins - 1)
    total = np.bincount(which, weights=f[inside], minlength=bins)
    peak = total.max()
    return BaseProfile(x_over_b=(np.arange(bins) + 0.5) / bins, force=total,
                       normalised=total / peak if peak > 0 else np.zeros_like(total),
                       x_left=x_left, width=width)


class MShape(NamedTuple):
    """Flank maxima of the base force against its central value (1997 Fig. 3(b):
    maxima "some 20-30% greater than that in the centre").

    Attributes:
      left_ratio, right_ratio: the largest bin left (right) of the central bin
        over the central bin.
      ratio: their mean.
      m_shaped: both flank maxima exceed the centre by more than `threshold`.
    """

    left_ratio: float
    right_ratio: float
    ratio: float
    m_shaped: bool


def m_shape(profile: BaseProfile, threshold: float = 0.1) -> MShape:
    """Whether the binned base force has the M shape (a dip under the apex)."""
    f = np.asarray(profile.force, float)
    if f.size < 3 or f.size % 2 == 0:
        raise InputError(f"the M shape needs an odd number (>= 3) of bins; got {f.size}.")
    c = f.size // 2
    centre = f[c]
    with np.errstate(divide="ignore", invalid="ignore"):
        left, right = np.max(f[:c]) / centre, np.max(f[c + 1:]) / centre
    left, right = float(left), float(right)
    return MShape(left_ratio=left, right_ratio=right, ratio=0.5 * (left + right),
                  m_shaped=bool(left > 1.0 + threshold and right > 1.0 + threshold))


FLANK_WINDOWS = ((0.2, 0.4), (0.6, 0.8))
CENTRE_WINDOW = (0.4, 0.6)


def flank_over_centre(profile: BaseProfile, flanks=FLANK_WINDOWS, centre=CENTRE_WINDOW) -> float:
    """The M depth that noise cannot fake: the mean binned force over the bins
    centred in the flank windows (x/B in 0.2-0.4 and 0.6-0.8), averaged over the
    two flanks, over its mean in the centre window (0.4-0.6). Above 1 for an M
    (1997 Fig. 3b: maxima 20-30 % above the centre), below 1 when the centre
    carries the most. `m_shape`'s ratio and `central_dip` take maxima over noisy
    bins, which noise alone pushes towards an M. NaN when a window holds no bin
    or the centre carries nothing."""
    left, right, middle = _window_means(profile.x_over_b, profile.normalised, (*flanks, centre))
    return 0.5 * (left + right) / middle if middle > 0 else float("nan")


def _window_means(x_over_b, values, windows) -> list[float]:
    """The mean of `values` over the bins centred in each `(lo, hi)` window of x/B (NaN for an empty one)."""
    x, v = np.asarray(x_over_b, float), np.asarray(values, float)
    inside = [(x >= lo) & (x <= hi) for lo, hi in windows]
    return [float(v[w].mean()) if w.any() else float("nan") for w in inside]


DIP_BINS = 15
"""Bins of the profile `dip_below_flanks` reads: about two substrate spacings each under a 300-disk
poured heap, narrow enough that the centre bin holds the dip instead of averaging it with the flanks
(docs/rolling_resistance.md)."""
DIP_FLANK_WINDOWS = ((0.2, 0.35), (0.65, 0.8))
DIP_CENTRE_WINDOW = (0.45, 0.55)


def dip_below_flanks(profile: BaseProfile, flanks=DIP_FLANK_WINDOWS, centre=DIP_CENTRE_WINDOW) -> float:
    """1 - the centre's mean binned force over the flanks' (bins centred in
    `centre`, and in either window of `flanks`): Smid & Novosad's dip, 20-30 %
    below the maximum (as Liffman, Chan & Hughes 1992 report it, Introduction;
    no equation), read from one heap with windows fixed in advance.
    `central_dip` compares the centre with the largest bin on each side, which
    noise alone raises; `flank_over_centre`'s windows are a fifth of the base
    wide, which averages a narrow dip away. The flanks' force is the mean of
    the two windows' means, as in `flank_over_centre`. On a `DIP_BINS`-bin
    profile the centre window holds the middle bin alone (x/B 0.47-0.53) and the flank
    windows two bins each (x/B 0.20-0.33, 0.67-0.80), about where the declared
    maxima sit (`fit.smid_novosad_profile`, x/B = 0.25, 0.75). The flanks' mean
    lies a little below their maxima, so this reads no deeper than the
    reported dip. NaN when a window holds no bin or the flanks carry nothing."""
    left, right, middle = _window_means(profile.x_over_b, profile.force, (*flanks, centre))
    flank = 0.5 * (left + right)  # NaN when a window is empty
    return 1.0 - middle / flank if flank > 0 else float("nan")


class NormalProfile(NamedTuple):
    """The base normal force binned across the pile (Fig. 20(b)).

    Attributes:
      x: `[b]` bin centres relative to the pile's centre (x - x_mid), length.
      x_over_base: `[b]` the same over the base length B (contact span + one diameter).
      force: `[b]` total normal force in each bin, in mg.
      normalised: `[b]` force / its maximum.
      centre: x_mid, the centre of the normal force (the pile's centre of mass).
      base: B.
    """

    x: np.ndarray
    x_over_base: np.ndarray
    force: np.ndarray
    normalised: np.ndarray
    centre: float
    base: float


def normal_profile(base_forces, bins: int = 15, diameter: float = 1.0) -> NormalProfile:
    """Bins the ground's normal forces into `bins` equal bins (odd, so one is
    centred) spanning the base symmetrically about its centre of force. Bins
    are at least 2 diameters wide: fewer bins on a small pile."""
    if int(bins) != bins or bins < 1:
        raise InputError(f"bins must be a positive whole number; got {bins!r}.")
    x = np.asarray(base_forces.x, dtype=float)
    normal = np.asarray(base_forces.normal, dtype=float)
    if len(x) == 0 or normal.sum() <= 0:
        raise InputError("no disk presses on the ground: there is no base force profile.")
    centre = float(np.sum(x * normal) / np.sum(normal))
    half = float(np.max(np.abs(x - centre))) + 0.5 * diameter
    bins = max(1, min(int(bins), int(2 * half / (2.0 * diameter))))
    bins -= 1 - bins % 2  # odd
    edges = np.linspace(-half, half, bins + 1)
    force, _ = np.histogram(x - centre, bins=edges, weights=normal)
    mids = 0.5 * (edges[1:] + edges[:-1])
    base = float(x.max() - x.min()) + diameter
    return NormalProfile(x=mids, x_over_base=mids / base, force=force, normalised=force / force.max(),
                         centre=centre, base=base)


def central_dip(profile: NormalProfile | BaseProfile) -> float:
    """1 - F(centre bin) / min(max F left of it, max F right of it): > 0 when the
    centre carries less than the highest bins on both sides (a dip), <= 0 when
    the centre is the peak. NaN with fewer than 3 bins."""
    f = np.asarray(profile.force)
    if len(f) < 3:
        return float("nan")
    mid = len(f) // 2
    shoulder = min(f[:mid].max(), f[mid + 1:].max())
    return float(1.0 - f[mid] / shoulder) if shoulder > 0 else float("nan")


# the size of a heap of n disks (packing fraction 0.8), for setting up its pour
def substrate_size(n: int, spacing: float, min_angle: float = 15.0, margin: float = 5.0) -> int:
    """Disks in a row long enough for the heap of n disks at any angle above
    `min_angle` degrees: base B = 2 sqrt(A / tan(angle)) for a triangular heap of
    area A = n (pi/4) / 0.8 (packing fraction 0.8), plus `margin` sigma at each
    end. (`margin=0` and a steep `min_angle` make a row the heap spills over.)"""
    area = n * (math.pi / 4.0) / 0.8
    base = 2.0 * math.sqrt(area / math.tan(math.radians(min_angle))) + 2.0 * margin
    return int(math.ceil(base / spacing)) + 1


def steepest_heap_height(n: int) -> float:
    """Height of a 45-degree heap of n disks (packing fraction 0.8), the
    steepest these laws build: insertion must start above it."""
    return math.sqrt(n * (math.pi / 4.0) / 0.8)


class ProfileSetting(NamedTuple):
    """How a pile's base profile is read for fitting.

    Attributes:
      base: `"ground"` (a pile on the floor) or `"substrate"` (a heap on fixed disks).
      x_left, x_right: the feet of the pile (the profile's x/B = 0 and 1).
      bins: number of bins.
      bandwidth: the smoothing kernel's width (default one bin).
    """

    base: str
    x_left: float
    x_right: float
    bins: int
    bandwidth: float | None = None
