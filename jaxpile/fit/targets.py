"""Profiles to fit: measured points from a CSV file, the declared shape of Smid
& Novosad's experiment, or a computed profile (host-side numpy)."""

from __future__ import annotations

import csv
import math
import os
from typing import NamedTuple

import numpy as np

from jaxpile.errors import InputError
from jaxpile.fit.profiles import Profile, dip_below_peak
from jaxpile.measure import theory


class ProfileTarget(NamedTuple):
    """A base-force profile to fit, with the features it is known to show.

    Attributes:
      x_over_b: `[m]` positions x/B in [0, 1], increasing.
      normal: `[m]` normal force over its maximum.
      horizontal: `[m]` horizontal force (the pile on the base, +x) over the
        maximum normal force, or None.
      angle_of_repose_degrees: the pile's reported angle of repose, or None.
      central_dip: the reported depth of the central minimum of the normal
        force, 1 - centre / max, or None.
      central_dip_range: `(low, high)`: the reported range of that depth, or None.
      source: where the target comes from (a file, a paper).
      normal_stderr, horizontal_stderr: `[m]` the measurement's standard
        errors, on the same scale as the values, or None (not given).
      normalised_by: `"max"` (the values over the largest normal force) or
        `"weight"` (force per unit x/B over the pile's weight: n(x/B) B / W,
        whose integral over the base is 1).
    """

    x_over_b: np.ndarray
    normal: np.ndarray
    horizontal: np.ndarray | None = None
    angle_of_repose_degrees: float | None = None
    central_dip: float | None = None
    central_dip_range: tuple[float, float] | None = None
    source: str = ""
    normal_stderr: np.ndarray | None = None
    horizontal_stderr: np.ndarray | None = None
    normalised_by: str = "max"


# ------------------------------------------------------------ a CSV file
_CSV_COLUMNS = {"x/b": "x", "x_over_b": "x", "normal/max": "normal", "normal/weight": "normal", "normal": "normal",
                "horizontal/max": "horizontal", "horizontal/weight": "horizontal", "horizontal": "horizontal",
                "stderr": "normal_stderr", "normal_stderr": "normal_stderr", "horizontal_stderr": "horizontal_stderr"}
_CSV_HELP = ("columns x/B, normal/max (or normal/weight) and optionally stderr, horizontal/max and "
             "horizontal_stderr")
NORMALISATIONS = ("max", "weight")
"""How a measured profile is scaled: by its largest normal force, or per unit x/B by the pile's weight."""


def load_profile_csv(path: str | os.PathLike, normalised_by: str | None = None) -> ProfileTarget:
    """A measured base profile from a CSV file.

    The file has a header row naming the columns `x/B` and `normal/max` (the
    normal force over its largest value) or `normal/weight` (the normal force
    per unit x/B over the pile's weight, n B / W), optionally `stderr` (the
    normal values' standard errors, on their scale), `horizontal/max` (or
    `/weight`) and `horizontal_stderr`; also accepted: `x_over_b`, and plain
    `normal`, `horizontal`, scaled as `normalised_by` says (default by the
    maximum). Case and surrounding spaces do not matter. Then at least 3 rows
    of numbers; lines starting with `#` and blank lines are skipped. x/B must
    lie in [0, 1] and increase strictly, a standard error must be positive.
    A plain `normal` column scaled by the maximum has every column divided by
    its largest value; a `normal/max` column is taken as given (the mean of
    heaps each normalised by its own maximum peaks below 1, as the ensemble
    mean of piles read so does).

    Raises:
      InputError: on a missing file, a missing, unknown or repeated column, a
        row of the wrong length, a value that is not a finite number, fewer than
        3 rows, x/B outside [0, 1] or not increasing, a normal column whose
        maximum is not positive, a standard error that is not positive, or a
        scale the header and `normalised_by` give differently.
    """
    path = os.fspath(path)
    rows, line_numbers = _csv_rows(path)
    canonical = _csv_columns(path, rows[0], line_numbers[0])
    data = _csv_values(path, rows, line_numbers, canonical)
    count = len(rows) - 1
    if count < 3:
        raise InputError(f"{path!r} has {count} data row(s); a profile needs at least 3.")
    x = np.asarray(data["x"])
    outside = np.flatnonzero((x < 0) | (x > 1))
    if outside.size:
        k = int(outside[0])
        raise InputError(f"{path!r} line {line_numbers[k + 1]}: x/B = {x[k]!r} is outside [0, 1]; positions "
                         "must be given as a fraction of the base width B.")
    steps = np.flatnonzero(np.diff(x) <= 0)
    if steps.size:
        k = int(steps[0])
        raise InputError(f"{path!r} lines {line_numbers[k + 1]}-{line_numbers[k + 2]}: x/B must increase strictly "
                         f"(got {x[k]!r} then {x[k + 1]!r}); sort the rows and merge repeated positions.")
    normal = np.asarray(data["normal"])
    peak = normal.max()
    if not peak > 0:
        raise InputError(f"{path!r}: the normal column's maximum is {peak!r}; it must be positive (the base "
                         "carries the pile).")
    for key in ("normal_stderr", "horizontal_stderr"):
        if key in data and not np.all(np.asarray(data[key]) > 0):
            k = int(np.flatnonzero(np.asarray(data[key]) <= 0)[0])
            raise InputError(f"{path!r} line {line_numbers[k + 1]}: a standard error of {data[key][k]!r}; it must be "
                             "positive (leave the column out for a measurement without errors).")
    header = [name.strip().lower() for name in rows[0]]
    scale = _scale(path, header, normalised_by)
    divide = peak if scale == "max" and "normal/max" not in header else 1.0  # a normal/max column is as given
    column = {key: np.asarray(data[key]) / divide if key in data else None
              for key in ("horizontal", "normal_stderr", "horizontal_stderr")}
    return ProfileTarget(x_over_b=x, normal=normal / divide, horizontal=column["horizontal"], source=path,
                         normal_stderr=column["normal_stderr"], horizontal_stderr=column["horizontal_stderr"],
                         normalised_by=scale)


def _scale(path: str, header: list[str], normalised_by: str | None) -> str:
    """How the file's profile is scaled: its header's `/max` or `/weight`, or `normalised_by` (default max)."""
    if normalised_by is not None and normalised_by not in NORMALISATIONS:
        raise InputError(f"a profile is normalised by {' or '.join(NORMALISATIONS)}; got {normalised_by!r}.")
    declared = {name.split("/")[1] for name in header if name.split("/")[0] in ("normal", "horizontal") and "/" in name}
    if len(declared) > 1:
        raise InputError(f"{path!r}: the header scales columns both by max and by weight; use one scale.")
    if declared and normalised_by is not None and normalised_by not in declared:
        raise InputError(f"{path!r} is scaled by {declared.pop()} (its header), not by {normalised_by}: leave "
                         "the normalisation out or fix the header.")
    return declared.pop() if declared else (normalised_by or "max")


def _csv_rows(path: str) -> tuple[list[list[str]], list[int]]:
    """The file's rows (header first) with their line numbers, comments and
    blank lines left out."""
    if os.path.isdir(path):
        raise InputError(f"profile file {path!r} is a folder; give the path of a CSV file with {_CSV_HELP}.")
    if not os.path.isfile(path):
        raise InputError(f"profile file {path!r} does not exist; give the path of a CSV file with {_CSV_HELP}.")
    try:
        with open(path, newline="", encoding="utf-8-sig") as f:
            numbered = [(k + 1, line) for k, line in enumerate(f)
                        if line.strip() and not line.lstrip().startswith("#")]
    except UnicodeDecodeError:
        raise InputError(f"profile file {path!r} is not text (UTF-8); it must be a CSV file with {_CSV_HELP}.") from None
    except OSError as e:
        raise InputError(f"profile file {path!r} cannot be read: {e.strerror}.") from None
    if not numbered:
        raise InputError(f"profile file {path!r} is empty; it needs a header row with {_CSV_HELP}.")
    return list(csv.reader([line for _, line in numbered])), [k for k, _ in numbered]


def _csv_columns(path: str, names: list[str], line: int) -> list[str]:
    """The header's columns under their canonical names (`x`, `normal`,
    `horizontal`), each known, given once, and x and normal present."""
    header = [name.strip().lower() for name in names]
    if all(_is_number(name) for name in header):
        raise InputError(f"{path!r} line {line} holds numbers; the file must start with a header row "
                         f"naming its {_CSV_HELP}.")
    unknown = [name for name in header if name not in _CSV_COLUMNS]
    if unknown:
        raise InputError(f"{path!r}: unknown column(s) {unknown}; the file needs {_CSV_HELP}.")
    canonical = [_CSV_COLUMNS[name] for name in header]
    repeated = sorted({c for c in canonical if canonical.count(c) > 1})
    if repeated:
        raise InputError(f"{path!r}: column(s) {repeated} given more than once (under one of their names); "
                         "keep one of each.")
    missing = [name for name, key in (("x/B", "x"), ("normal/max", "normal")) if key not in canonical]
    if missing:
        raise InputError(f"{path!r}: missing column(s) {missing}; the header has {names}, the file needs "
                         f"{_CSV_HELP}.")
    return canonical


def _csv_values(path: str, rows: list[list[str]], line_numbers: list[int], canonical: list[str]
                ) -> dict[str, list[float]]:
    """`{column: values}` of the data rows, each a finite number."""
    data = {key: [] for key in canonical}
    for line, row in zip(line_numbers[1:], rows[1:]):
        if len(row) != len(canonical):
            raise InputError(f"{path!r} line {line} has {len(row)} value(s) but the header names "
                             f"{len(canonical)} columns.")
        for key, name, cell in zip(canonical, rows[0], row):
            try:
                value = float(cell)
            except ValueError:
                raise InputError(f"{path!r} line {line}, column {name.strip()!r}: {cell.strip()!r} is not a "
                                 "number.") from None
            if not math.isfinite(value):
                raise InputError(f"{path!r} line {line}, column {name.strip()!r}: {cell.strip()!r} is not finite.")
            data[key].append(value)
    return data


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


# ------------------------------------------------- Smid & Novosad (1981)
SMID_NOVOSAD_ANGLE_DEGREES = 32.6
"""Angle of repose of Smid & Novosad's largest pile (Liffman et al. 1992, text of Fig. 17)."""

SMID_NOVOSAD_DIP_RANGE = (0.2, 0.3)
"""The central minimum of the base normal stress, 20% (smallest piles) to 30%
(largest) below the maximum (Liffman et al. 1992, Introduction; Baxter et al.
1997 report their simulated heap's maxima "some 20-30% greater" than the centre
and cite the experiment as qualitatively very similar)."""


def smid_novosad_profile(points: int = 41, *, dip: float = 0.25, peak_offset: float = 0.25) -> ProfileTarget:
    """A target built from the reported features of Smid & Novosad's experiment (1981).

    It is built from reported features, NOT from measured points: the papers print
    no table of the experiment's values (Liffman et al. 1992 plot them in Fig. 17,
    not digitised here), so the curves are a declared shape with these features
    (Liffman, Chan & Hughes 1992, Introduction and Fig. 17; Baxter et al. 1997,
    sec. III, ref. 13): an angle of repose of 32.6 degrees; a central minimum of
    the base normal stress 20-30% below its maximum; a shear stress zero at the
    centre and linear around it with the slope of eq. 57.

    With u = x/B, s = |u - 1/2| and d = `peak_offset`, the normal curve is
    1 - dip (1 - (s/d)^2)^2 for s <= d and 1 - ((s - d)/(1/2 - d))^2 beyond: a
    smooth M with maxima of exactly 1 at s = d (their position is not reported)
    and 0 at the feet with a finite slope (eq. 54). The horizontal curve is the
    continuum sloped pile's H(x) (eqs. 55, 57, 59, `theory.continuum_ground_horizontal_force`)
    at alpha = 32.6 degrees over its central normal force (eq. 56): odd about
    the centre, slope 2/sqrt(3) per unit x/B for s < 1/2 - x_c/B = 0.185, then
    linear to zero at the feet, negative on the left half (`analysis.base_forces`).

    Args:
      points: an odd number (>= 5) of equally spaced positions from x/B = 0 to
        1 (odd, so the centre is one of them).
      dip: depth of the central minimum, 1 - centre / max, in (0, 1).
      peak_offset: |x/B - 1/2| of the maxima, in (0, 1/2).

    Raises:
      InputError: on an even or too small `points`, or `dip`, `peak_offset`
        outside their ranges.
    """
    if int(points) != points or points < 5 or int(points) % 2 == 0:
        raise InputError(f"points must be an odd whole number >= 5 (so that x/B = 0.5 is one of them); "
                         f"got {points!r}.")
    if not 0.0 < dip < 1.0:
        raise InputError(f"dip must be in (0, 1) (1 - centre / max; the experiment: 0.2-0.3); got {dip!r}.")
    if not 0.0 < peak_offset < 0.5:
        raise InputError(f"peak_offset must be in (0, 0.5) (the maxima's |x/B - 0.5|); got {peak_offset!r}.")
    u = np.linspace(0.0, 1.0, int(points))
    s = np.abs(u - 0.5)
    inner = 1.0 - dip * (1.0 - (s / peak_offset) ** 2) ** 2
    outer = 1.0 - ((s - peak_offset) / (0.5 - peak_offset)) ** 2
    normal = np.where(s <= peak_offset, inner, outer)
    alpha = math.radians(SMID_NOVOSAD_ANGLE_DEGREES)
    n_max = float(theory.continuum_ground_normal_force(0.5, alpha, 1.0))
    horizontal = theory.continuum_ground_horizontal_force(u, alpha, 1.0) / n_max
    return ProfileTarget(
        x_over_b=u, normal=normal, horizontal=horizontal, angle_of_repose_degrees=SMID_NOVOSAD_ANGLE_DEGREES,
        central_dip=float(dip), central_dip_range=SMID_NOVOSAD_DIP_RANGE,
        source="Smid & Novosad 1981 as reported in words by Liffman, Chan & Hughes 1992 and Baxter et al. 1997: "
               "a declared shape with the reported features (32.6 deg repose, central dip 20-30%, shear linear "
               "through zero at the centre with the slope of eq. 57), not measured points")


# ------------------------------------------------------ a computed profile
def target_from_profile(profile: Profile, source: str = "simulated") -> ProfileTarget:
    """A `ProfileTarget` from a computed `Profile` (e.g. to check that a fit
    recovers the parameters a profile was made with)."""
    return ProfileTarget(x_over_b=np.asarray(profile.x_over_b), normal=np.asarray(profile.normal),
                         horizontal=None if profile.horizontal is None else np.asarray(profile.horizontal),
                         central_dip=float(dip_below_peak(profile)), source=source)
