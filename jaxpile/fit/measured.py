"""A measurement to calibrate to: a base profile at the points where it was
taken and/or scalars (an angle of repose, a packing fraction, a flow rate),
each with its standard error where the measurement gives one.

`load_measurement` reads it (a CSV profile, or a JSON/TOML file of scalars
and a profile); `statistics_of` says what each simulated pile must report to
be compared with it, read as the measurement was: the pile's base forces
(`jaxpile.base_forces`, whatever the pile stands on) at the measured x/B of
the pile's own base, foot to foot, as a force density smoothed over
`bandwidth` (a sensor's width), scaled as the file is (by the largest
measured point, or per unit x/B by the pile's weight: `jaxpile.measure.
base_reading`); `target_of` makes the
`EnsembleTarget` the ensemble fit matches the ensemble mean to.

A measurement without standard errors is taken as one heap: each point's
error is one simulated pile's spread about the ensemble mean, measured at the
fit's start, and the fit says so.
"""

from __future__ import annotations

import json
import math
import os
import tomllib
from typing import NamedTuple

import numpy as np

from jaxpile.batches import batch_of
from jaxpile.errors import InputError
from jaxpile.fit.ensemble_runs import Statistics
from jaxpile.fit.ensemble_targets import EnsembleTarget
from jaxpile.fit.targets import NORMALISATIONS, ProfileTarget, load_profile_csv

READINGS = ("angle_of_repose", "packing_fraction", "flow_rate")
"""Measured quantities a file may name whatever a protocol calls them (its spec's `Batch.readings`)."""

class Measurement(NamedTuple):
    """What was measured.

    Attributes:
      profile: the base profile (`ProfileTarget`: x/B, values and standard
        errors, its scale), or None.
      scalars: `{name: (value, stderr or None)}`, names as a protocol's sweep
        row has them or one of `READINGS`.
      bandwidth: the profile reading's kernel width in x/B, or None (half the
        median spacing of the measured points).
      source: where it came from.
    """

    profile: ProfileTarget | None
    scalars: dict
    bandwidth: float | None
    source: str


def load_measurement(path: str | os.PathLike, normalised_by: str | None = None) -> Measurement:
    """A measurement from `path`: a CSV base profile (`fit.load_profile_csv`'s
    columns, with `stderr` for its errors), or a JSON or TOML file:

        source = "heap A"                  # optional
        profile = "profile.csv"            # optional: a CSV beside this file
        normalised_by = "max"              # optional: the profile's scale, if its header does not say
        bandwidth = 0.05                   # optional: the reading's width in x/B
        [scalars]                          # optional: value, or {value, stderr}, or [value, stderr]
        angle_of_repose = { value = 32.1, stderr = 0.8 }

    with a profile, scalars, or both. `normalised_by` overrides none of the
    file's own (a disagreement is refused)."""
    path = os.fspath(path)
    if path.lower().endswith(".csv"):
        return Measurement(load_profile_csv(path, normalised_by), {}, None, path)
    record = _read_record(path)
    known = {"source", "profile", "normalised_by", "bandwidth", "scalars"}
    unknown = sorted(set(record) - known)
    if unknown:
        raise InputError(f"{path}: unknown key(s) {unknown}; a measurement holds {', '.join(sorted(known))}.")
    scale = record.get("normalised_by", normalised_by)
    if normalised_by is not None and scale != normalised_by:
        raise InputError(f"{path} says normalised_by = {scale!r}, the command {normalised_by!r}: give one.")
    profile = None
    if record.get("profile") is not None:
        if not isinstance(record["profile"], str):
            raise InputError(f"{path}: profile is the path of a CSV file (beside {os.path.basename(path)}); got "
                             f"{record['profile']!r}.")
        profile = load_profile_csv(os.path.join(os.path.dirname(path), record["profile"]), scale)
    scalars = {name: _scalar(path, name, value) for name, value in (record.get("scalars") or {}).items()}
    if profile is None and not scalars:
        raise InputError(f"{path} holds no profile and no scalars: nothing to fit to.")
    bandwidth = record.get("bandwidth")
    if bandwidth is not None and not (isinstance(bandwidth, (int, float)) and 0 < bandwidth <= 0.5):
        raise InputError(f"{path}: bandwidth is a width in x/B in (0, 0.5]; got {bandwidth!r}.")
    return Measurement(profile, scalars, None if bandwidth is None else float(bandwidth),
                       str(record.get("source") or path))


def _read_record(path: str) -> dict:
    if not os.path.isfile(path):
        raise InputError(f"measurement file {path!r} does not exist (a .csv profile, or a .json or .toml file).")
    try:
        if path.lower().endswith(".toml"):
            with open(path, "rb") as fh:
                record = tomllib.load(fh)
        elif path.lower().endswith(".json"):
            with open(path, encoding="utf-8") as fh:
                record = json.load(fh)
        else:
            raise InputError(f"measurement file {path!r}: give a .csv profile, or a .json or .toml file.")
    except (ValueError, tomllib.TOMLDecodeError, UnicodeDecodeError) as err:
        raise InputError(f"measurement file {path!r} cannot be read: {err}.") from None
    if not isinstance(record, dict):
        raise InputError(f"measurement file {path!r} must hold a table of keys (source, profile, scalars, ...).")
    return record


def _scalar(path: str, name: str, value) -> tuple[float, float | None]:
    """`(value, stderr or None)` from a number, `[value, stderr]` or `{value, stderr}`."""
    if isinstance(value, dict):
        extra = set(value) - {"value", "stderr"}
        if extra or "value" not in value:
            raise InputError(f"{path}: scalar {name!r} is {{value, stderr}}; got keys {sorted(value)}.")
        value, stderr = value["value"], value.get("stderr")
    elif isinstance(value, (list, tuple)):
        if len(value) != 2:
            raise InputError(f"{path}: scalar {name!r} as a list is [value, stderr]; got {value!r}.")
        value, stderr = value
    else:
        stderr = None
    for what, v in (("value", value), ("stderr", stderr)):
        if v is not None and (isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v)):
            raise InputError(f"{path}: scalar {name!r} has {what} {v!r}; it must be a finite number.")
    if stderr is not None and not stderr > 0:
        raise InputError(f"{path}: scalar {name!r} has stderr {stderr!r}; it must be positive (leave it out "
                         "if the measurement gives none).")
    return float(value), None if stderr is None else float(stderr)


def default_bandwidth(x_over_b) -> float:
    """Half the median spacing of the measured points (x/B): each point reads the
    pile over about the stretch of base it stands for."""
    return 0.5 * float(np.median(np.diff(np.asarray(x_over_b, float))))


def statistics_of(measurement: Measurement, spec) -> Statistics:
    """What each pile of the protocol `spec` reports to be compared with the
    measurement: its columns for the scalars (a `READINGS` name through the
    spec's `Batch.readings`), and its base profile at the measured x/B."""
    readings = dict(batch_of(spec).readings or {})
    columns = []
    for name in measurement.scalars:
        if name in READINGS and name not in readings:
            has = ", ".join(sorted(readings)) or "none of them"
            raise InputError(f"the {spec.name} protocol measures no {name.replace('_', ' ')} (it reads {has}); "
                             "name one of its columns instead, or leave it out.")
        columns.append(readings.get(name, name))
    profile = measurement.profile
    if profile is None:
        return Statistics(columns=tuple(columns))
    bandwidth = measurement.bandwidth or default_bandwidth(profile.x_over_b)
    return Statistics(columns=tuple(columns), at=tuple(float(u) for u in profile.x_over_b),
                      horizontal=profile.horizontal is not None, bandwidth=bandwidth,
                      normalised_by=profile.normalised_by)


def target_of(measurement: Measurement, statistics: Statistics) -> EnsembleTarget:
    """The `EnsembleTarget` of a measurement, its statistics as `statistics_of`
    reads them: the measured values, and their standard errors as both the
    weights' spread and the target's own error (NaN where none is given: the
    fit fills them from its first piles)."""
    values, errors = [], []
    for value, stderr in measurement.scalars.values():
        values.append(value)
        errors.append(math.nan if stderr is None else stderr)
    p = measurement.profile
    if p is not None:
        for v, se in ((p.normal, p.normal_stderr), (p.horizontal, p.horizontal_stderr)):
            if v is None:
                continue
            values += list(map(float, v))
            errors += [math.nan] * len(v) if se is None else list(map(float, se))
    error = np.asarray(errors, float)
    return EnsembleTarget(statistics.labels(), np.asarray(values, float), error.copy(), None,
                          f"the measurement {measurement.source}", error=error)


__all__ = ["Measurement", "NORMALISATIONS", "READINGS", "default_bandwidth", "load_measurement", "statistics_of",
           "target_of"]
